"""Bounds on what a light-tree cluster of VPLs brings to a receiver point, and the
spread of its one-representative estimate (Walter et al. 2005, sec. 4.1), for
lightcuts.py.

A cluster's error is at most
    flux_C / pi * max cos_x * max cos_y / max(min d^2, dmin^2) * 1
with the cosine maxima over the cluster's bounding sphere and normal cone and the
distance minimum over its bounding box, flux_C its largest channel (the receiver
is diffuse, so its albedo/pi cancels from both sides of the test). The sphere is
looser than the paper's rotated-box cosine bound but much cheaper in numpy. All
functions take the clusters' LightTree.bound_columns as float32 (k, m) columns.
"""
import numpy as np

# Smallest normal float32: a floor that keeps 1/x and x/y finite.
_TINY = np.float32(np.finfo(np.float32).tiny)


def cluster_deviation(t, P, N, G, min_distance2):
    """Error bound (m,) of each cluster and the standard deviation of its estimate
    over the choice of its representative (drawn by intensity, so unbiased):
    linearised where the cluster lies wholly in front of the point (positive lower
    bound), and at most half its range (Popoviciu) -- its bound where it may cross
    the horizon."""
    to_centre = centre_offset(t, P)
    upper, lower = cluster_range(t, P, N, G, min_distance2, to_centre)
    half_range = np.float32(0.5) * (upper - lower)
    linear = linear_deviation(t, P, N, min_distance2, to_centre)
    # lower <= 0: inf or NaN, and fmin takes the half range (also on overflow).
    with np.errstate(divide='ignore', invalid='ignore'):
        linear /= lower > 0
    return upper, np.fmin(linear, half_range)


def centre_offset(t, P):
    """v = cluster centre - P (3, m) and |v|^2, shared by the bounds and deviation."""
    v = t[0:3] - P
    return v, dot3(v, v)


def dot3(a, b):
    """Column-wise dot product of (3, m) arrays, summed in the order of .sum(0)."""
    out = a[0] * b[0]
    out += a[1] * b[1]
    out += a[2] * b[2]
    return out


def linear_deviation(t, P, N, min_distance2, to_centre=None):
    """sqrt(g^T C_y g + h^T C_n h) * flux/pi: the first-order standard deviation of
    f = cos_x cos_y / max(d^2, dmin^2) over a cluster whose VPL positions y and
    normals n have covariances C_y, C_n, with g, h the gradients of f in y and n at
    the cluster's centre and cone axis. float32 throughout."""
    d, dist2 = to_centre if to_centre is not None else centre_offset(t, P)
    dist2 = np.maximum(dist2, np.float32(1e-30))
    inv = 1 / np.sqrt(dist2)
    u = d * inv
    axis = t[10:13]
    cos_x = dot3(N, u)
    cos_y = -dot3(axis, u)
    scale = 1 / np.maximum(dist2, np.float32(min_distance2))
    # d/dy of cos_x cos_y is (cos_y N - cos_x n - 2 cos_x cos_y u) / d; 1/d^2 adds
    # -2 cos_x cos_y u / d where the clamp is off.
    pull = (dist2 > min_distance2) + np.float32(1)
    pull *= 2 * cos_x * cos_y
    g = cos_y * N - cos_x * axis - pull * u
    h = -cos_x * u
    variance = quadratic_form(g, t[17:23]) * (scale * inv) ** 2
    variance += quadratic_form(h, t[23:29]) * scale * scale
    return t[15] * t[16] * np.sqrt(np.maximum(variance, 0))


def quadratic_form(x, c):
    """x^T C x per column, C given as its 6 entries (xx, yy, zz, xy, xz, yz)."""
    cross = x[0] * x[1] * c[3] + x[0] * x[2] * c[4] + x[1] * x[2] * c[5]
    cross *= 2
    cross += x[0] * x[0] * c[0] + x[1] * x[1] * c[1] + x[2] * x[2] * c[2]
    return cross


def cluster_range(t, P, N, G, min_distance2, to_centre=None):
    """Upper and lower bounds (2 x (m,)) on what one VPL of cluster `nodes` brings
    per unit of the cluster's flux, times its largest channel of flux / pi, at points
    P with normals N and geometric normals G (float32 (3, m) columns):
        upper = flux/pi * max cos_x * max cos_y / max(min d^2, dmin^2)
        lower = flux/pi * min cos_x * min cos_y / max(max d^2, dmin^2)
    with the cosines over the node's bounding sphere and normal cone and the
    distances over its box (Walter 2005 sec. 4.1 for the upper bound); `t` holds
    the clusters' LightTree.bound_columns. The upper bound caps the cluster's error
    whatever its visibility; upper - lower caps it if the whole cluster is visible.
    Both are zero for single VPLs (traced exactly). No np.where (slow): masks
    multiply, and every term stays finite."""
    v, dist2 = to_centre if to_centre is not None else centre_offset(t, P)
    dist = np.sqrt(dist2)
    inside = dist <= t[3]
    inv = 1 / np.maximum(dist, _TINY)
    sin_a = np.minimum(t[3] * inv, np.float32(1))     # the sphere's angular radius
    cos_a = np.sqrt(1 - sin_a * sin_a)
    # cos_x: the receiver normal against directions into the sphere; the VPL must
    # also lie above the geometric normal's plane to count at all.
    cos_b = dot3(N, v) * inv
    sin_b = sine(cos_b)
    cos_x = cos_within(cos_b, sin_b, cos_a, sin_a)
    min_x = cos_beyond(cos_b, sin_b, cos_a, sin_a)
    cos_n = dot3(G, v) * inv
    min_x *= (cos_n * cos_a - sine(cos_n) * sin_a) > 0
    # cos_y: the cone (axis, half angle) widened by the sphere, against the
    # direction from the cluster to the point.
    cos_g = dot3(t[10:13], v) * -inv
    sin_g = sine(cos_g)
    cos_s = cos_a * t[13] - sin_a * t[14]
    sin_s = sin_a * t[13] + cos_a * t[14]
    cos_y = np.maximum(cos_within(cos_g, sin_g, cos_s, sin_s), sin_s < 0)
    min_y = cos_beyond(cos_g, sin_g, cos_s, sin_s)
    min_y *= cos_s > 0
    near2, far2 = box_distances2(t, P, min_distance2)
    scale = t[15] * t[16]
    upper = np.maximum(cos_x * cos_y, inside)
    upper *= scale
    upper /= near2
    lower = min_x * min_y
    lower *= ~inside
    lower *= scale
    lower /= far2
    return upper, lower


def sine(cos):
    """sqrt(1 - cos^2), 0 where round-off pushes |cos| past 1."""
    return np.sqrt(np.maximum(1 - cos * cos, np.float32(0)))


def box_distances2(t, P, min_distance2):
    """Smallest and largest squared distance (clamped at dmin^2, and above 0) from
    P to the box."""
    near2 = far2 = 0
    for k in range(3):
        below, above = t[4 + k] - P[k], P[k] - t[7 + k]
        near = np.maximum(np.maximum(below, above), np.float32(0))
        far = np.maximum(np.abs(below), np.abs(above))
        near2, far2 = near2 + near * near, far2 + far * far
    floor = np.float32(max(min_distance2, _TINY))
    return np.maximum(near2, floor), np.maximum(far2, floor)


def cos_beyond(cos_angle, sin_angle, cos_spread, sin_spread):
    """Smallest cos(angle + x) for 0 <= x <= spread (spread <= pi/2), clamped at 0."""
    out = cos_angle * cos_spread - sin_angle * sin_spread
    return np.maximum(out, np.float32(0), out=out)


def cos_within(cos_angle, sin_angle, cos_spread, sin_spread):
    """Largest cos(angle - x) for 0 <= x <= spread, clamped at 0: 1 inside the
    spread, else cos(angle - spread)."""
    out = cos_angle * cos_spread + sin_angle * sin_spread
    np.maximum(out, np.float32(0), out=out)
    return np.maximum(out, cos_angle >= cos_spread, out=out)

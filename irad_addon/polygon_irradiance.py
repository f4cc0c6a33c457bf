"""Closed-form irradiance from a one-sided Lambertian rectangle light, ignoring
occlusion (Lambert's polygon formula; Arvo 1995), for direct light's visible-share
estimator (direct_light.py). Compiled: one pass per batch of points, on both cores."""
import numpy as np
from numba import njit

from . import rays


def rectangle_irradiance_factor(P, N, G, center, axis_u, axis_v, light_normal):
    """(n,): the integral of cos_l cos_x / d^2 over a one-sided rectangle light (half-
    extents axis_u, axis_v) seen from points P with shading normals N, over the part
    above both N's and the geometric normal G's tangent planes: the expectation of
    _patch_sample's factor (unoccluded irradiance = radiance * factor), in closed form
    by Lambert's polygon formula (Arvo 1995, "Applications of irradiance tensors",
    eq. 1): integral of cos_x dw = 1/2 sum_k Theta_k (Gamma_k . N) over the edges of the
    rectangle clipped to the hemisphere."""
    out = np.empty(len(P))
    arrays = (np.ascontiguousarray(P, np.float64), np.ascontiguousarray(N, np.float64),
              np.ascontiguousarray(G, np.float64), np.asarray(center, np.float64),
              np.asarray(axis_u, np.float64), np.asarray(axis_v, np.float64),
              np.asarray(light_normal, np.float64), out)
    # ~150 ns a point (atan2s): both cores, the kernel runs without the GIL.
    rays.parallel_map(lambda first, stop: _rectangle_factor(*arrays, first, stop),
                      rays.split_ranges(len(P), rays.worker_count(), minimum=4096))
    return out


@njit(cache=True, nogil=True)
def _rectangle_factor(P, N, G, center, axis_u, axis_v, light_normal, out, first, stop):
    corners = np.empty((4, 3))
    for k in range(4):   # counter-clockwise: (-1, -1), (1, -1), (1, 1), (-1, 1)
        a = 1.0 if k == 1 or k == 2 else -1.0
        b = 1.0 if k >= 2 else -1.0
        for c in range(3):
            corners[k, c] = center[c] + a * axis_u[c] + b * axis_v[c]
    polygon, clipped = np.empty((8, 3)), np.empty((8, 3))
    for i in range(first, stop):
        out[i] = 0.0
        side = 0.0
        for c in range(3):
            side += (P[i, c] - center[c]) * light_normal[c]
        if side <= 0:   # behind the light's emitting side
            continue
        for k in range(4):
            for c in range(3):
                polygon[k, c] = corners[k, c] - P[i, c]
        count = 4
        if _below(polygon, count, N, i) or _below(polygon, count, G, i):
            count = _clip(polygon, count, N, i, clipped)
            count = _clip(clipped, count, G, i, polygon)
        if count >= 3:
            out[i] = _projected_solid_angle(polygon, count, N, i)


@njit(cache=True, inline='always')
def _below(polygon, count, normal, i):
    """Whether a vertex of the polygon (relative to point i) lies below normal[i]'s
    plane: only then does it need clipping."""
    for k in range(count):
        if polygon[k, 0] * normal[i, 0] + polygon[k, 1] * normal[i, 1] + \
                polygon[k, 2] * normal[i, 2] < 0:
            return True
    return False


@njit(cache=True, inline='always')
def _clip(polygon, count, normal, i, out):
    """Sutherland-Hodgman: the part of the convex polygon (count vertices, relative to
    point i) on the side normal[i] points to, into out; returns its vertex count."""
    kept = 0
    for k in range(count):
        j = (k + 1) % count
        h_k = h_j = 0.0
        for c in range(3):
            h_k += polygon[k, c] * normal[i, c]
            h_j += polygon[j, c] * normal[i, c]
        if h_k >= 0:
            for c in range(3):
                out[kept, c] = polygon[k, c]
            kept += 1
        if (h_k >= 0) != (h_j >= 0):
            t = h_k / (h_k - h_j)
            for c in range(3):
                out[kept, c] = polygon[k, c] + t * (polygon[j, c] - polygon[k, c])
            kept += 1
    return kept


@njit(cache=True, inline='always')
def _angle(sine, cosine):
    """atan2(sine, cosine) for sine > 0, to ~1e-7 relative: Cephes' atanf polynomial
    after reduction to |z| <= tan(pi/8), ~3x faster than libm's atan2 here."""
    a, b = abs(cosine), sine
    ratio = min(a, b) / max(a, b)
    base = 0.0
    if ratio > 0.41421356237309503:   # atan(r) = pi/4 + atan((r - 1) / (r + 1))
        base, ratio = np.pi / 4, (ratio - 1.0) / (ratio + 1.0)
    z = ratio * ratio
    angle = base + ((((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z
                     - 3.33329491539e-1) * z * ratio + ratio)
    if b > a:
        angle = np.pi / 2 - angle
    return np.pi - angle if cosine < 0 else angle


@njit(cache=True, inline='always')
def _projected_solid_angle(polygon, count, N, i):
    """|1/2 sum_k Theta_k (Gamma_k . N)| over the polygon's edges, from unit vectors to
    its vertices (normalised in place); Theta_k / |w_k x w_k+1| taken by atan2, exact
    for short edges."""
    for k in range(count):
        length = np.sqrt(polygon[k, 0] * polygon[k, 0] + polygon[k, 1] * polygon[k, 1]
                         + polygon[k, 2] * polygon[k, 2])
        scale = 1.0 / length if length > 0 else 0.0
        for c in range(3):
            polygon[k, c] *= scale
    total = 0.0
    for k in range(count):
        j = k + 1 if k + 1 < count else 0
        ax, ay, az = polygon[k, 0], polygon[k, 1], polygon[k, 2]
        bx, by, bz = polygon[j, 0], polygon[j, 1], polygon[j, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        sine = np.sqrt(cx * cx + cy * cy + cz * cz)
        cosine = ax * bx + ay * by + az * bz
        theta_over_sine = _angle(sine, cosine) / sine if sine > 1e-12 else 1.0
        total += theta_over_sine * (cx * N[i, 0] + cy * N[i, 1] + cz * N[i, 2])
    return 0.5 * abs(total)

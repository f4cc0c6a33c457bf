"""Triangle quantities shared by the tracer's users: normals, areas, hit points."""
import numpy as np
from numba import njit

from . import sampling


def triangle_areas(triangles):
    return 0.5 * _cross_and_length(triangles)[1]


def geometric_normals(triangles):
    cross, length = _cross_and_length(triangles)
    return cross / np.where(length > 0, length, 1.0)[:, None]


def nondegenerate(triangles, extent):
    """Mask of triangles with a usable area and normal: finite, and not slivers whose
    cross product underflows relative to the scene size."""
    finite = np.isfinite(triangles).all(axis=(1, 2))
    return finite & (_cross_and_length(triangles)[1] > (1e-12 * extent) ** 2)


def _cross_and_length(triangles):
    """((v1 - v0) x (v2 - v0) in float64 (T, 3): twice the area times the geometric
    normal, and its lengths (T,)) in one compiled pass: numpy's would
    copy the triangles to float64 and make a temporary per step (a million triangles:
    ~0.1 s a call instead of ~5 ms)."""
    triangles = np.ascontiguousarray(triangles).reshape(-1, 3, 3)
    cross, length = np.empty((len(triangles), 3)), np.empty(len(triangles))
    _triangle_cross(triangles, cross, length)
    return cross, length


@njit(cache=True, nogil=True)
def _triangle_cross(triangles, cross, length):
    for i in range(len(triangles)):
        ax = np.float64(triangles[i, 1, 0]) - np.float64(triangles[i, 0, 0])
        ay = np.float64(triangles[i, 1, 1]) - np.float64(triangles[i, 0, 1])
        az = np.float64(triangles[i, 1, 2]) - np.float64(triangles[i, 0, 2])
        bx = np.float64(triangles[i, 2, 0]) - np.float64(triangles[i, 0, 0])
        by = np.float64(triangles[i, 2, 1]) - np.float64(triangles[i, 0, 1])
        bz = np.float64(triangles[i, 2, 2]) - np.float64(triangles[i, 0, 2])
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        cross[i, 0], cross[i, 1], cross[i, 2] = cx, cy, cz
        length[i] = np.sqrt(cx * cx + cy * cy + cz * cz)


def coordinate_bounds(points):
    """(lowest, highest) float64 (3,) corners of the box around points (..., 3), in one
    compiled pass (numpy's min and max along the short axis take ~0.1 s each for a
    million triangles). Non-finite coordinates are left out."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    _bounds(np.ascontiguousarray(points).reshape(-1, 3), lo, hi)
    return lo, hi


@njit(cache=True, nogil=True)
def _bounds(points, lo, hi):
    for i in range(len(points)):
        for c in range(3):
            v = np.float64(points[i, c])
            if not np.isfinite(v):
                continue
            if v < lo[c]:
                lo[c] = v
            if v > hi[c]:
                hi[c] = v


def surface_hits(frame, triangle, barycentric, incoming, hit=None, smooth=True):
    """Position, geometric normal, shading normal, albedo and emission (n, 3) of ray
    hits on triangles `triangle` at `barycentric` (u, v), for rays along `incoming`;
    zeros where `hit` is False. Surfaces are two-sided: both normals face the side the
    ray came from, the shading normal (the corner normals interpolated, smooth=False:
    the geometric one) turned to the geometric one's side. Positions come from barycentrics, more precise
    than origin + t * direction: the offset within the triangle is float32 (its error
    scales with the triangle, not with its distance from the origin), the corner it is
    added to float64. One compiled pass: numpy would make a dozen over the hits."""
    n = len(triangle)
    out = [np.empty((n, 3)) for _ in range(5)]
    _surface_hits(frame.triangles, frame.geo_normals, frame.corner_normals, frame.albedo,
                  frame.emission, np.asarray(triangle),
                  np.ascontiguousarray(barycentric, np.float32),
                  np.ascontiguousarray(incoming, np.float64),
                  np.ones(n, bool) if hit is None else hit, smooth, *out)
    return out


@njit(cache=True, nogil=True)
def _surface_hits(triangles, geo_normals, corner_normals, albedo_table, emission_table,
                  triangle, barycentric, incoming, hit, smooth, position, geo, shading, albedo,
                  emission):
    f32 = np.float32
    for i in range(len(triangle)):
        # Element by element: row slices would allocate views.
        if not hit[i]:
            for c in range(3):
                position[i, c] = geo[i, c] = shading[i, c] = albedo[i, c] = emission[i, c] = 0.0
            continue
        t = triangle[i]
        for c in range(3):
            albedo[i, c], emission[i, c] = albedo_table[t, c], emission_table[t, c]
        u, v = barycentric[i, 0], barycentric[i, 1]
        facing = 0.0
        for c in range(3):
            corner = triangles[t, 0, c]
            within = u * f32(triangles[t, 1, c] - corner) + v * f32(triangles[t, 2, c] - corner)
            position[i, c] = np.float64(corner) + np.float64(within)
            facing -= geo_normals[t, c] * incoming[i, c]
        sign = -1.0 if facing < 0 else 1.0
        for c in range(3):
            geo[i, c] = sign * geo_normals[t, c]
        if not smooth:
            for c in range(3):
                shading[i, c] = geo[i, c]
            continue
        wu, wv = np.float64(u), np.float64(v)
        length2, towards = 0.0, 0.0
        for c in range(3):
            s = ((1.0 - wu - wv) * corner_normals[t, 0, c] + wu * corner_normals[t, 1, c]
                 + wv * corner_normals[t, 2, c])
            shading[i, c] = s
            length2 += s * s
            towards += s * geo[i, c]
        length = np.sqrt(length2)
        if not (length > 1e-8 and np.isfinite(length)):   # degenerate: the geometric one
            for c in range(3):
                shading[i, c] = geo[i, c]
            continue
        sign = -1.0 / length if towards < 0 else 1.0 / length
        for c in range(3):
            shading[i, c] *= sign


def bounding_sphere(triangles):
    """Centre and radius of a sphere around all triangles (the AABB's)."""
    if len(triangles) == 0:
        return np.zeros(3), 1.0
    lo, hi = coordinate_bounds(triangles)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)


def dot_rows(a, b):
    """Row-wise dot products of (n, 3) arrays."""
    return np.einsum('ij,ij->i', a, b)


def unit_rows(v):
    """(unit vectors, lengths) of the vectors v (..., 3); zero vectors stay zero."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0), n[..., 0]


def patch_area(axis_u, axis_v, ellipse):
    """Area of a rectangle or ellipse with half-extent vectors axis_u, axis_v."""
    return np.where(ellipse, np.pi, 4.0) * np.linalg.norm(axis_u, axis=-1) * \
        np.linalg.norm(axis_v, axis=-1)


def patch_points(center, axis_u, axis_v, ellipse, u):
    """Uniform points on rectangles / ellipses (per row or one for all) from u (n, 2)."""
    ellipse = np.asarray(ellipse)
    if ellipse.ndim == 0:   # one shape for all: map only to it
        uv = sampling.square_to_disk(u) if ellipse else 2.0 * u - 1.0
    else:
        uv = np.where(ellipse[..., None], sampling.square_to_disk(u), 2.0 * u - 1.0)
    return center + uv[:, :1] * axis_u + uv[:, 1:2] * axis_v

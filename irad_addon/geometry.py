"""Triangle quantities shared by the tracer's users: normals, areas, hit points."""
import numpy as np


def triangle_cross(triangles):
    """(v1 - v0) x (v2 - v0): twice the area times the geometric normal."""
    t = triangles.astype(np.float64)
    return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])


def triangle_areas(triangles):
    return 0.5 * np.linalg.norm(triangle_cross(triangles), axis=1)


def geometric_normals(triangles):
    c = triangle_cross(triangles)
    length = np.linalg.norm(c, axis=1, keepdims=True)
    return c / np.where(length > 0, length, 1.0)


def nondegenerate(triangles, extent):
    """Mask of triangles with a usable area and normal: finite, and not slivers whose
    cross product underflows relative to the scene size."""
    finite = np.isfinite(triangles).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], triangles, 0.0)
    cross = np.linalg.norm(triangle_cross(safe), axis=1)
    return finite & (cross > (1e-12 * extent) ** 2)


def surface_points(triangles, triangle, barycentric):
    """World positions from barycentrics: more precise than origin + t * direction.
    The offset within the triangle is float32 (its error scales with the triangle,
    not with its distance from the origin); the corner it is added to is float64."""
    t = triangles[triangle]
    u, v = barycentric[:, :1], barycentric[:, 1:2]
    within = u * (t[:, 1] - t[:, 0]) + v * (t[:, 2] - t[:, 0])
    return t[:, 0].astype(np.float64) + within


def shading_normals(corner_normals, triangle, barycentric, fallback):
    """Interpolated corner normals, unit length; `fallback` where they degenerate."""
    n = corner_normals[triangle].astype(np.float64)
    u = barycentric[:, :1].astype(np.float64)
    v = barycentric[:, 1:2].astype(np.float64)
    s = (1.0 - u - v) * n[:, 0] + u * n[:, 1] + v * n[:, 2]
    length = np.linalg.norm(s, axis=1, keepdims=True)
    ok = (length > 1e-8) & np.isfinite(length)
    return np.where(ok, s / np.where(ok, length, 1.0), fallback)


def face_forward(normal, direction):
    """Flip normals to the side that `direction` points to (sign of the dot product)."""
    sign = np.where(np.einsum('ij,ij->i', normal, direction) < 0, -1.0, 1.0)
    return normal * sign[:, None]


def bounding_sphere(triangles):
    """Centre and radius of a sphere around all triangles (the AABB's)."""
    if len(triangles) == 0:
        return np.zeros(3), 1.0
    flat = triangles.reshape(-1, 3).astype(np.float64)
    lo, hi = flat.min(0), flat.max(0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)

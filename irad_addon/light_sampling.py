"""Compiled incident-light sampling for direct light, the renderer's densest loop over
lights (every shading sample times every light sample): one pass per batch instead of
a dozen numpy temporaries. The estimators are the emitters' own (lights.py)."""
import numpy as np
from numba import njit


def patch_incident(points, normals, u, center, axis_u, axis_v, light_normal, ellipse, area):
    """Uniform area samples of a rectangle or ellipse (half-extents axis_u, axis_v)
    from u (n, 2), seen from `points`: unit directions (n, 3), distances (n,) and the
    geometry factor cos_l cos_x A / d^2 (n,) of the one-sided light facing
    light_normal (irradiance = radiance * factor)."""
    n = len(points)
    direction, distance, factor = np.empty((n, 3)), np.empty(n), np.empty(n)
    _patch_incident(np.ascontiguousarray(points, np.float64),
                    np.ascontiguousarray(normals, np.float64),
                    np.ascontiguousarray(u, np.float64), np.asarray(center, np.float64),
                    np.asarray(axis_u, np.float64), np.asarray(axis_v, np.float64),
                    np.asarray(light_normal, np.float64), bool(ellipse), float(area),
                    direction, distance, factor)
    return direction, distance, factor


@njit(cache=True, nogil=True)
def _patch_incident(points, normals, u, center, axis_u, axis_v, light_normal, ellipse, area,
                    direction, distance, factor):
    for i in range(len(points)):
        distance[i], factor[i] = _patch_sample(points, normals, i, u[i, 0], u[i, 1], center,
                                               axis_u, axis_v, light_normal, ellipse, area,
                                               direction, i)


@njit(cache=True, inline='always')
def _patch_sample(points, normals, i, u0, u1, center, axis_u, axis_v, light_normal, ellipse,
                  area, direction, row):
    """One uniform sample of the patch seen from points[i]: its unit direction into
    direction[row]; returns (distance, cos_l cos_x A / d^2)."""
    a, b = 2.0 * u0 - 1.0, 2.0 * u1 - 1.0
    if ellipse:   # concentric map onto the disk (sampling.square_to_disk)
        if abs(a) > abs(b):
            r, phi = a, (np.pi / 4) * (b / a)
        else:
            r, phi = b, np.pi / 2 - (np.pi / 4) * (a / (b if b != 0 else 1.0))
        a, b = r * np.cos(phi), r * np.sin(phi)
    dist2 = 0.0
    for c in range(3):
        d = center[c] + a * axis_u[c] + b * axis_v[c] - points[i, c]
        direction[row, c] = d
        dist2 += d * d
    dist = np.sqrt(dist2)
    scale = 1.0 / dist if dist > 0 else 1.0
    cos_l = cos_x = 0.0
    for c in range(3):
        direction[row, c] *= scale
        cos_l -= direction[row, c] * light_normal[c]
        cos_x += direction[row, c] * normals[i, c]
    return dist, max(cos_l, 0.0) * max(cos_x, 0.0) / max(dist2, 1e-30) * area


def patch_segments(P, N, G, pattern, center, axis_u, axis_v, light_normal, ellipse, area,
                   radiance, eps, origin, segment, tfar, point, energy):
    """shadow_segments of every sample of `pattern` (count, n, 2) on a patch light at
    once (patch_incident's samples, without the intermediate arrays). Returns the rows."""
    return _patch_segments(P, N, G, np.ascontiguousarray(pattern, np.float64),
                           np.asarray(center, np.float64), np.asarray(axis_u, np.float64),
                           np.asarray(axis_v, np.float64),
                           np.asarray(light_normal, np.float64), bool(ellipse), float(area),
                           np.asarray(radiance, np.float64), eps, origin, segment, tfar,
                           point, energy)


@njit(cache=True, nogil=True)
def _patch_segments(P, N, G, pattern, center, axis_u, axis_v, light_normal, ellipse, area,
                    radiance, eps, origin, segment, tfar, point, energy):
    count = 0
    if max(radiance[0], radiance[1], radiance[2]) <= 0:
        return count
    for k in range(pattern.shape[0]):
        for i in range(len(P)):
            dist, factor = _patch_sample(P, N, i, pattern[k, i, 0], pattern[k, i, 1], center,
                                         axis_u, axis_v, light_normal, ellipse, area,
                                         segment, count)
            if factor > 0 and _above(segment, count, G, i):
                for c in range(3):
                    energy[count, c] = radiance[c] * factor
                count = _lift(P, G, i, dist, eps, origin, tfar, point, count)
    return count


@njit(cache=True, inline='always')
def _above(direction, row, G, i):
    """Whether direction[row] leaves above point i's geometric surface (no light comes
    through a surface)."""
    return (direction[row, 0] * G[i, 0] + direction[row, 1] * G[i, 1]
            + direction[row, 2] * G[i, 2]) > 0


@njit(cache=True, inline='always')
def _lift(P, G, i, distance, eps, origin, tfar, which, row):
    """Segment row `row` starts at point i lifted by eps along G and ends 2 eps short of
    the light; `which` records the point. Returns row + 1."""
    for c in range(3):
        origin[row, c] = P[i, c] + G[i, c] * eps
    tfar[row] = distance * (1 - 1e-5) - 2 * eps
    which[row] = i
    return row + 1


@njit(cache=True, nogil=True)
def shadow_segments(P, G, direction, distance, e, eps, origin, segment, tfar, which, start):
    """Append, from row `start` of the outputs, the shadow segment of every light
    sample that brings light (e > 0) from above the geometric surface: origin lifted
    by eps along G, unit direction, length short of the light by 2 eps; `which` gets
    the sample's row. Returns the next free row."""
    count = start
    for i in range(len(P)):
        if max(e[i, 0], e[i, 1], e[i, 2]) > 0 and _above(direction, i, G, i):
            for c in range(3):
                segment[count, c] = direction[i, c]
            count = _lift(P, G, i, distance[i], eps, origin, tfar, which, count)
    return count


def light_sums(point, energy, lit, points):
    """(seen (points, 3), sampled (points,)): per point, the energies of its light
    samples that reach it, and the sum over channels of all its samples' energies."""
    seen, sampled = np.zeros((points, 3)), np.zeros(points)
    _light_sums(point, energy, lit, seen, sampled)
    return seen, sampled


@njit(cache=True, nogil=True)
def _light_sums(point, energy, lit, seen, sampled):
    for k in range(len(point)):
        i = point[k]
        sampled[i] += energy[k, 0] + energy[k, 1] + energy[k, 2]
        if lit[k]:
            for c in range(3):
                seen[i, c] += energy[k, c]


def shifted_pattern(pattern, shift):
    """(len(pattern), len(shift), 2): every point of `pattern` shifted by each row of
    `shift`, wrapped into [0, 1)^2 (a Cranley-Patterson rotation per shift)."""
    out = np.empty((len(pattern), len(shift), 2))
    _shifted_pattern(np.ascontiguousarray(pattern, np.float64),
                     np.ascontiguousarray(shift, np.float64), out)
    return out


@njit(cache=True, nogil=True)
def _shifted_pattern(pattern, shift, out):
    for k in range(len(pattern)):
        for i in range(len(shift)):
            for c in range(2):
                v = pattern[k, c] + shift[i, c]
                out[k, i, c] = v - np.floor(v)

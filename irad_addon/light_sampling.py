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
    dx = center[0] + a * axis_u[0] + b * axis_v[0] - points[i, 0]
    dy = center[1] + a * axis_u[1] + b * axis_v[1] - points[i, 1]
    dz = center[2] + a * axis_u[2] + b * axis_v[2] - points[i, 2]
    dist2 = dx * dx + dy * dy + dz * dz
    dist = np.sqrt(dist2)
    scale = 1.0 / dist if dist > 0 else 1.0
    dx, dy, dz = dx * scale, dy * scale, dz * scale
    direction[row, 0], direction[row, 1], direction[row, 2] = dx, dy, dz
    cos_l = -(dx * light_normal[0] + dy * light_normal[1] + dz * light_normal[2])
    cos_x = dx * normals[i, 0] + dy * normals[i, 1] + dz * normals[i, 2]
    return dist, max(cos_l, 0.0) * max(cos_x, 0.0) / max(dist2, 1e-30) * area


def patch_segments(P, N, G, pattern, center, axis_u, axis_v, light_normal, ellipse, area,
                   radiance, eps, centre, segments):
    """shadow_segments of every sample of `pattern` (count, n, 2) on a patch light at
    once (patch_incident's samples, without the intermediate arrays). Returns the rows."""
    return _patch_segments(P, N, G, np.ascontiguousarray(pattern, np.float64),
                           np.asarray(center, np.float64), np.asarray(axis_u, np.float64),
                           np.asarray(axis_v, np.float64),
                           np.asarray(light_normal, np.float64), bool(ellipse), float(area),
                           np.asarray(radiance, np.float64), eps, centre, *segments.arrays)


@njit(cache=True, nogil=True)
def _patch_segments(P, N, G, pattern, center, axis_u, axis_v, light_normal, ellipse, area,
                    radiance, eps, centre, origin, segment, tfar, point, energy):
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
                count = _lift(P, G, i, dist, eps, centre, origin, tfar, point, count)
    return count


@njit(cache=True, inline='always')
def _above(direction, row, G, i):
    """Whether direction[row] leaves above point i's geometric surface (no light comes
    through a surface)."""
    return (direction[row, 0] * G[i, 0] + direction[row, 1] * G[i, 1]
            + direction[row, 2] * G[i, 2]) > 0


@njit(cache=True, inline='always')
def _lift(P, G, i, distance, eps, centre, origin, tfar, which, row):
    """Segment row `row` starts at point i lifted by eps along G (in the tracer's frame:
    minus its centre) and ends 2 eps short of the light; `which` records the point.
    Returns row + 1."""
    for c in range(3):
        origin[row, c] = P[i, c] + G[i, c] * eps - centre[c]
    tfar[row] = distance * (1 - 1e-5) - 2 * eps
    which[row] = i
    return row + 1


def shadow_segments(P, G, direction, distance, e, eps, centre, segments, start):
    """Append, from row `start` of `segments` (a ShadowSegments), the shadow segment of
    every light sample that brings light (e > 0) from above the geometric surface:
    origin lifted by eps along G, unit direction, length short of the light by 2 eps,
    energy e; the segment's point is the sample's row. Returns the next free row."""
    return _shadow_segments(P, G, np.ascontiguousarray(direction, np.float64),
                            np.ascontiguousarray(distance, np.float64),
                            np.ascontiguousarray(e, np.float64), eps, centre,
                            *segments.arrays, start)


@njit(cache=True, nogil=True)
def _shadow_segments(P, G, direction, distance, e, eps, centre, origin, segment, tfar, which,
                     energy, start):
    count = start
    for i in range(len(P)):
        if max(e[i, 0], e[i, 1], e[i, 2]) > 0 and _above(direction, i, G, i):
            for c in range(3):
                segment[count, c] = direction[i, c]
                energy[count, c] = e[i, c]
            count = _lift(P, G, i, distance[i], eps, centre, origin, tfar, which, count)
    return count


class ShadowSegments:
    """Room for `rows` shadow segments in the tracer's frame (float32, what Embree
    takes as is): origin, direction, length; and the point each belongs to and the
    energy it brings if unoccluded."""

    def __init__(self, rows):
        self.origin, self.segment = np.empty((rows, 3), np.float32), np.empty((rows, 3), np.float32)
        self.tfar, self.point = np.empty(rows, np.float32), np.empty(rows, np.int64)
        self.energy = np.empty((rows, 3))

    @property
    def arrays(self):
        return self.origin, self.segment, self.tfar, self.point, self.energy


def light_sums(point, energy, lit, seen, sampled, tally):
    """Add, per point, the energies of its light samples that reach it to seen
    (points, 3), the sum over channels of all its samples' energies to sampled
    (points,), and its segments and unoccluded segments to tally (points, 2)."""
    _light_sums(point, energy, lit, seen, sampled, tally)


@njit(cache=True, nogil=True)
def _light_sums(point, energy, lit, seen, sampled, tally):
    for k in range(len(point)):
        i = point[k]
        sampled[i] += energy[k, 0] + energy[k, 1] + energy[k, 2]
        tally[i, 0] += 1
        if lit[k]:
            tally[i, 1] += 1
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

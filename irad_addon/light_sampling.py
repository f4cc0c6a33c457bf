"""Compiled incident-light sampling for direct light, the renderer's densest loop over
lights (every shading sample times every light sample): one pass per batch instead of
a dozen numpy temporaries. The estimators are the emitters' own (lights.py)."""
import numpy as np
from numba import njit

from . import rays


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

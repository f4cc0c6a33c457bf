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
        a, b = 2.0 * u[i, 0] - 1.0, 2.0 * u[i, 1] - 1.0
        if ellipse:   # concentric map onto the disk (sampling.square_to_disk)
            if abs(a) > abs(b):
                r, phi = a, (np.pi / 4) * (b / a)
            else:
                r, phi = b, np.pi / 2 - (np.pi / 4) * (a / (b if b != 0 else 1.0))
            a, b = r * np.cos(phi), r * np.sin(phi)
        dist2 = 0.0
        for c in range(3):
            d = center[c] + a * axis_u[c] + b * axis_v[c] - points[i, c]
            direction[i, c] = d
            dist2 += d * d
        dist = np.sqrt(dist2)
        scale = 1.0 / dist if dist > 0 else 1.0
        cos_l = cos_x = 0.0
        for c in range(3):
            direction[i, c] *= scale
            cos_l -= direction[i, c] * light_normal[c]
            cos_x += direction[i, c] * normals[i, c]
        distance[i] = dist
        factor[i] = max(cos_l, 0.0) * max(cos_x, 0.0) / max(dist2, 1e-30) * area


@njit(cache=True, nogil=True)
def shadow_segments(P, G, direction, distance, e, eps, origin, segment, tfar, which, start):
    """Append, from row `start` of the outputs, the shadow segment of every light
    sample that brings light (e > 0) from above the geometric surface: origin lifted
    by eps along G, unit direction, length short of the light by 2 eps; `which` gets
    the sample's row. Returns the next free row."""
    count = start
    for i in range(len(P)):
        if max(e[i, 0], e[i, 1], e[i, 2]) <= 0:
            continue
        if (direction[i, 0] * G[i, 0] + direction[i, 1] * G[i, 1]
                + direction[i, 2] * G[i, 2]) <= 0:   # no light through the surface
            continue
        for c in range(3):
            origin[count, c] = P[i, c] + G[i, c] * eps
            segment[count, c] = direction[i, c]
        tfar[count] = distance[i] * (1 - 1e-5) - 2 * eps
        which[count] = i
        count += 1
    return count


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

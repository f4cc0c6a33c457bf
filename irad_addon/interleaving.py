"""Interleaved sampling with a discontinuity buffer (Keller & Heidrich 2001).

Each pixel of a k x k tile (and each anti-aliasing sample in it) gathers a different
interleaved subset of the VPLs; the discontinuity buffer then averages irradiance over
the k x k neighbourhood among pixels whose depth and normal are continuous with the
centre, so every pixel sees all subsets where the surface is smooth and edges stay sharp.
"""
import numpy as np
from numba import njit

from . import rays

# Continuity thresholds of the discontinuity buffer: relative depth and normal cosine.
DEPTH_TOLERANCE = 0.05
NORMAL_COSINE = 0.9


def subset_count(interleave, samples):
    """Number of VPL subsets: one per tile position and anti-aliasing sample."""
    return max(1, interleave) ** 2 * max(1, samples)


def sample_subsets(width, rows, samples, interleave):
    """Subset index of every G-buffer sample of image rows (first, stop), sample-major
    as camera.pixel_samples; tiles are anchored to the whole image."""
    k = max(1, interleave)
    y, x = np.mgrid[rows[0]:rows[1], 0:width]
    tile = ((x % k) + k * (y % k)).ravel()
    return (tile[None, :] * samples + np.arange(samples)[:, None]).ravel()


# Filter window in tiles: 2 x 2 tiles contain every tile position exactly four times,
# so pixels next to an edge, with half their neighbours cut off, still see all subsets.
WINDOW_TILES = 2


def window_offsets(k):
    """Offsets of a (WINDOW_TILES k)^2 window around a pixel, every tile position
    equally often (the window is a whole number of tiles)."""
    size = WINDOW_TILES * k
    r = np.arange(size) - (size - 1) // 2
    return [(dy, dx) for dy in r for dx in r]


def discontinuity_filter(irradiance, depth, normal, hit, k):
    """Average irradiance (..., H, W, 3) over k x k neighbours that continue the
    centre's surface: |depth - depth_c| <= tol * depth_c and normal . normal_c >=
    NORMAL_COSINE. Leading axes (the anti-aliasing layers) are filtered separately.
    One compiled pass over the pixels and their window (numba)."""
    if k <= 1:
        return irradiance
    h, w = depth.shape[-2:]

    def layers(a, dtype, *channels):
        return np.ascontiguousarray(a, dtype).reshape((-1, h, w, *channels))

    out = np.empty(irradiance.shape)
    inputs = (layers(irradiance, np.float64, 3), layers(depth, np.float64),
              layers(normal, np.float64, 3), layers(hit, bool),
              np.array(window_offsets(k), np.int64), DEPTH_TOLERANCE, NORMAL_COSINE,
              out.reshape((-1, h, w, 3)))
    # Bands of rows on the thread pool: the kernel runs without the GIL.
    rays.parallel_map(lambda first, stop: _filter(*inputs, first, stop),
                      rays.split_ranges(h, rays.worker_count(), minimum=16))
    return out


@njit(cache=True, nogil=True)
def _filter(E, depth, normal, hit, offsets, depth_tolerance, normal_cosine, out, first, stop):
    """out for rows first .. stop - 1 of every layer."""
    layers, h, w = depth.shape
    for layer in range(layers):
        for y in range(first, stop):
            for x in range(w):
                red = green = blue = 0.0   # scalars: row slices would allocate views
                count = 0
                if hit[layer, y, x]:
                    z, limit = depth[layer, y, x], depth_tolerance * depth[layer, y, x]
                    for o in range(len(offsets)):
                        v, u = y + offsets[o, 0], x + offsets[o, 1]
                        if v < 0 or v >= h or u < 0 or u >= w or not hit[layer, v, u]:
                            continue
                        if abs(depth[layer, v, u] - z) > limit:
                            continue
                        cosine = (normal[layer, v, u, 0] * normal[layer, y, x, 0]
                                  + normal[layer, v, u, 1] * normal[layer, y, x, 1]
                                  + normal[layer, v, u, 2] * normal[layer, y, x, 2])
                        if cosine < normal_cosine:
                            continue
                        red += E[layer, v, u, 0]
                        green += E[layer, v, u, 1]
                        blue += E[layer, v, u, 2]
                        count += 1
                if count:
                    out[layer, y, x, 0] = red / count
                    out[layer, y, x, 1] = green / count
                    out[layer, y, x, 2] = blue / count
                else:
                    out[layer, y, x, 0] = E[layer, y, x, 0]
                    out[layer, y, x, 1] = E[layer, y, x, 1]
                    out[layer, y, x, 2] = E[layer, y, x, 2]


def filter_sample_layers(irradiance, gb, k):
    """Run the discontinuity buffer on each anti-aliasing sample's image separately
    (each layer holds every tile position once), per-sample irradiance in and out."""
    if k <= 1:
        return irradiance
    layer = lambda a: a.reshape((gb.samples, gb.height, gb.width) + a.shape[1:])  # noqa: E731
    out = discontinuity_filter(layer(irradiance), layer(gb.depth), layer(gb.normal),
                               layer(gb.hit), k)
    return out.reshape(irradiance.shape)

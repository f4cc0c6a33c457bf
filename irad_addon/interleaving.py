"""Interleaved sampling with a discontinuity buffer (Keller & Heidrich 2001).

Each pixel of a k x k tile (and each anti-aliasing sample in it) gathers a different
interleaved subset of the VPLs; the discontinuity buffer then averages irradiance over
the k x k neighbourhood among pixels whose depth and normal are continuous with the
centre, so every pixel sees all subsets where the surface is smooth and edges stay sharp.
"""
import numpy as np

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


def _padded(image, pad, fill, channels):
    """image (..., H, W[, C]) with `pad` pixels of `fill` around H and W."""
    lead = image.ndim - 2 - channels
    width = [(0, 0)] * lead + [(pad, pad), (pad, pad)] + [(0, 0)] * channels
    return np.pad(image, width, constant_values=fill)


def discontinuity_filter(irradiance, depth, normal, hit, k, weights=None):
    """Average irradiance (..., H, W, 3) over k x k neighbours that continue the
    centre's surface: |depth - depth_c| < tol * depth_c and normal . normal_c >
    NORMAL_COSINE. Leading axes (the anti-aliasing layers) are filtered separately.
    weights: discontinuity_weights of these depths, normals and hits, if already made."""
    if k <= 1:
        return irradiance
    pad = WINDOW_TILES * k
    h, w = depth.shape[-2:]
    neighbours, count = weights or discontinuity_weights(depth, normal, hit, k)
    # float32 planes with the channel axis first: every window is a cheap strided view.
    planes = np.moveaxis(irradiance, -1, 0).astype(np.float32)
    E = _padded(planes, pad, 0.0, 0)
    total = np.zeros(planes.shape, np.float32)
    for (dy, dx), same in zip(window_offsets(k), neighbours):
        total += E[..., pad + dy:pad + dy + h, pad + dx:pad + dx + w] * same
    filtered = np.where(count > 0, total / np.maximum(count, 1), planes)
    return np.moveaxis(filtered, 0, -1).astype(np.float64)


def discontinuity_weights(depth, normal, hit, k):
    """Which neighbours of each window offset continue the centre's surface (bool
    masks, one per window_offsets(k) entry), and how many do: the filter's weights,
    which depend on the G-buffer only (a still camera keeps them)."""
    f32 = np.float32
    h, w = depth.shape[-2:]
    pad = WINDOW_TILES * k
    planes = lambda a: np.moveaxis(a, -1, 0).astype(f32)   # noqa: E731
    N = _padded(planes(normal), pad, 0.0, 0)
    Z, H = _padded(depth.astype(f32), pad, np.inf, 0), _padded(hit, pad, False, 0)
    centre_normal, centre_depth = planes(normal), depth.astype(f32)
    tolerance = (DEPTH_TOLERANCE * depth).astype(f32)
    neighbours, count = [], np.zeros(depth.shape, f32)
    for dy, dx in window_offsets(k):
        window = (Ellipsis, slice(pad + dy, pad + dy + h), slice(pad + dx, pad + dx + w))
        n = N[window]
        cosine = n[0] * centre_normal[0]
        cosine += n[1] * centre_normal[1]
        cosine += n[2] * centre_normal[2]
        same = H[window] & hit
        same &= np.abs(Z[window] - centre_depth) <= tolerance
        same &= cosine >= NORMAL_COSINE
        neighbours.append(same)
        count += same
    return neighbours, count


def _layers(gb):
    """Per-sample arrays (S, ...) -> (samples, H, W, ...) anti-aliasing layers."""
    return lambda a: a.reshape((gb.samples, gb.height, gb.width) + a.shape[1:])


def filter_sample_layers(irradiance, gb, k, weights=None):
    """Run the discontinuity buffer on each anti-aliasing sample's image separately
    (each layer holds every tile position once), per-sample irradiance in and out.
    weights: layer_filter_weights(gb, k), if already made."""
    if k <= 1:
        return irradiance
    layer = _layers(gb)
    out = discontinuity_filter(layer(irradiance), layer(gb.depth), layer(gb.normal),
                               layer(gb.hit), k, weights)
    return out.reshape(irradiance.shape)


def layer_filter_weights(gb, k):
    """filter_sample_layers' discontinuity_weights for G-buffer `gb`."""
    layer = _layers(gb)
    return discontinuity_weights(layer(gb.depth), layer(gb.normal), layer(gb.hit), k)

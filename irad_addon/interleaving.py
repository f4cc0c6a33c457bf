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


def _shifted(image, dy, dx, fill):
    """image[y + dy, x + dx], `fill` outside."""
    h, w = image.shape[:2]
    out = np.full_like(image, fill)
    ys, yd = slice(max(dy, 0), h + min(dy, 0)), slice(max(-dy, 0), h + min(-dy, 0))
    xs, xd = slice(max(dx, 0), w + min(dx, 0)), slice(max(-dx, 0), w + min(-dx, 0))
    out[yd, xd] = image[ys, xs]
    return out


def discontinuity_filter(irradiance, depth, normal, hit, k):
    """Average irradiance (H, W, 3) over k x k neighbours that continue the centre's
    surface: |depth - depth_c| < tol * depth_c and normal . normal_c > NORMAL_COSINE."""
    if k <= 1:
        return irradiance
    total = np.zeros_like(irradiance)
    weight = np.zeros(depth.shape)
    for dy, dx in window_offsets(k):
        e = _shifted(irradiance, dy, dx, 0.0)
        z = _shifted(depth, dy, dx, np.inf)
        n = _shifted(normal, dy, dx, 0.0)
        h = _shifted(hit, dy, dx, False)
        same = (h & hit & (np.abs(z - depth) <= DEPTH_TOLERANCE * depth)
                & (np.einsum('ijk,ijk->ij', n, normal) >= NORMAL_COSINE))
        total += e * same[..., None]
        weight += same
    return np.where(weight[..., None] > 0, total / np.maximum(weight, 1)[..., None], irradiance)


def filter_sample_layers(irradiance, gb, k):
    """Run the discontinuity buffer on each anti-aliasing sample's image separately
    (each layer holds every tile position once), per-sample irradiance in and out."""
    if k <= 1:
        return irradiance
    h, w, s = gb.height, gb.width, gb.samples
    layer = lambda a: a.reshape((s, h, w) + a.shape[1:])
    E, Z, N, H = layer(irradiance), layer(gb.depth), layer(gb.normal), layer(gb.hit)
    out = np.stack([discontinuity_filter(E[i], Z[i], N[i], H[i], k) for i in range(s)])
    return out.reshape(irradiance.shape)

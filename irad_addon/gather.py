"""The deferred shading pass: irradiance at every G-buffer sample from the lights
(shadow rays to light samples) and from the VPLs (one shadow ray per VPL)."""
import threading
from concurrent.futures import as_completed

import numpy as np

from . import rays, sampling

# Pixel-VPL pairs per gather task: bounds the float32 temporaries (~10 arrays of
# this many elements per thread) while keeping each Embree call large.
PAIRS_PER_TASK = 1 << 20


def light_sample_pattern(count, points, rng):
    """`count` 2D samples per point: a Hammersley set, toroidally shifted per point
    (Cranley-Patterson), so every point gets a stratified but different pattern."""
    base = sampling.hammersley(count, 2)
    shift = rng.random((points, 2))
    return (base[:, None, :] + shift[None]) % 1.0


def direct_irradiance(frame, gb, light_samples, rng, cancel=None):
    """Irradiance (S, 3) from every emitter, with shadow rays."""
    E = np.zeros((len(gb.hit), 3))
    idx = np.flatnonzero(gb.hit)
    if len(idx) == 0:
        return E
    P, N, G = gb.position[idx], gb.normal[idx], gb.geo_normal[idx]
    eps = frame.offset()
    origins = P + G * eps
    for emitter in frame.emitters:
        count = 1 if emitter.delta else light_samples
        pattern = light_sample_pattern(count, len(idx), rng)
        for u in pattern:
            if cancel and cancel():
                return E
            direction, dist, e = emitter.incident(P, N, u)
            # Light must arrive above the geometric surface too (no light through it).
            ok = (e.max(1) > 0) & (np.einsum('ij,ij->i', direction, G) > 0)
            sel = np.flatnonzero(ok)
            tfar = dist[sel] * (1 - 1e-5) - 2 * eps
            blocked = frame.tracer.occluded(origins[sel], direction[sel], tfar)
            lit = sel[~blocked]
            E[idx[lit]] += e[lit] / count
    return E


def vpl_subsets(vpls, subsets):
    """Interleave the VPLs into `subsets` groups (j mod subsets); each group's flux is
    scaled by `subsets` so that the groups' average is the full estimate."""
    return [(vpls.subset(slice(k, None, subsets)), float(subsets)) for k in range(subsets)]


def vpl_irradiance_chunk(P, N, G, vpl_position, vpl_normal, vpl_flux, min_distance2,
                         tracer, eps):
    """Irradiance at points P from VPLs: sum_j flux_j/pi cos_x cos_y / max(d^2, dmin^2) V.
    The VPL emits with a cosine lobe (Keller 1997, eq. 5); float32 for speed."""
    f32 = np.float32
    dx = vpl_position[None, :, 0].astype(f32) - P[:, None, 0].astype(f32)
    dy = vpl_position[None, :, 1].astype(f32) - P[:, None, 1].astype(f32)
    dz = vpl_position[None, :, 2].astype(f32) - P[:, None, 2].astype(f32)
    dist2 = dx * dx + dy * dy + dz * dz
    inv = 1.0 / np.sqrt(np.maximum(dist2, f32(1e-30)))
    Nf, Gf, Vn = N.astype(f32), G.astype(f32), vpl_normal.astype(f32)
    cos_x = (dx * Nf[:, None, 0] + dy * Nf[:, None, 1] + dz * Nf[:, None, 2]) * inv
    cos_y = -(dx * Vn[None, :, 0] + dy * Vn[None, :, 1] + dz * Vn[None, :, 2]) * inv
    above = dx * Gf[:, None, 0] + dy * Gf[:, None, 1] + dz * Gf[:, None, 2]
    valid = (cos_x > 0) & (cos_y > 0) & (above > 0)
    pi_, vi = np.nonzero(valid)
    weight = np.zeros_like(dist2)
    if len(pi_):
        d = np.sqrt(dist2[pi_, vi])
        direction = np.stack([dx[pi_, vi], dy[pi_, vi], dz[pi_, vi]], -1) / d[:, None]
        origin = (P[pi_] + G[pi_] * eps).astype(f32)
        blocked = tracer.occluded(origin, direction, d * f32(1 - 1e-5) - f32(2 * eps),
                                  threads=False)
        keep = ~blocked
        pi_, vi = pi_[keep], vi[keep]
        weight[pi_, vi] = (cos_x[pi_, vi] * cos_y[pi_, vi] /
                           np.maximum(dist2[pi_, vi], f32(min_distance2)))
    return (weight @ vpl_flux.astype(f32)).astype(np.float64) / np.pi


def indirect_irradiance(frame, gb, vpls, min_distance, cancel=None, progress=None):
    """Irradiance (S, 3) from all VPLs. Camera sample k of each pixel gathers the k-th
    interleaved VPL subset, so anti-aliasing costs no extra shadow rays."""
    E = np.zeros((len(gb.hit), 3))
    if vpls.count == 0 or not gb.hit.any():
        return E
    subsets = min(gb.samples, vpls.count)
    tasks = []
    for k, (subset, scale) in enumerate(vpl_subsets(vpls, subsets)):
        idx = np.flatnonzero(gb.hit & (gb.sample % subsets == k))
        step = max(1, PAIRS_PER_TASK // max(subset.count, 1))
        tasks += [(idx[a:a + step], subset, scale) for a in range(0, len(idx), step)]
    eps = frame.offset()
    stop = threading.Event()

    def run(task):
        idx, subset, scale = task
        if stop.is_set():
            return
        E[idx] = scale * vpl_irradiance_chunk(
            gb.position[idx], gb.normal[idx], gb.geo_normal[idx], subset.position,
            subset.normal, subset.flux, min_distance ** 2, frame.tracer, eps)

    # Workers only compute; progress and cancel stay on the calling (Blender) thread.
    futures = [rays.thread_pool().submit(run, t) for t in tasks]
    for done, future in enumerate(as_completed(futures), 1):
        future.result()
        if cancel and cancel():
            stop.set()
        if progress:
            progress(done / len(futures))
    return E

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
    The VPL emits with a cosine lobe (Keller 1997, eq. 5). float32 and flat indices
    keep the numpy work per pair below Embree's own cost."""
    f32 = np.float32
    Pf = P.astype(f32)
    Nf, Gf = N.astype(f32), G.astype(f32)
    Vp, Vn = vpl_position.astype(f32), vpl_normal.astype(f32)
    dx = Vp[None, :, 0] - Pf[:, None, 0]
    dy = Vp[None, :, 1] - Pf[:, None, 1]
    dz = Vp[None, :, 2] - Pf[:, None, 2]
    dist2 = np.maximum(dx * dx + dy * dy + dz * dz, f32(1e-30))
    inv = 1.0 / np.sqrt(dist2)
    cos_x = (dx * Nf[:, None, 0] + dy * Nf[:, None, 1] + dz * Nf[:, None, 2]) * inv
    cos_y = (dx * Vn[None, :, 0] + dy * Vn[None, :, 1] + dz * Vn[None, :, 2]) * -inv
    above = dx * Gf[:, None, 0] + dy * Gf[:, None, 1] + dz * Gf[:, None, 2]
    valid = (cos_x > 0) & (cos_y > 0) & (above > 0)
    weight = np.where(valid, cos_x * cos_y / np.maximum(dist2, f32(min_distance2)), f32(0))
    pairs = np.flatnonzero(valid)
    if len(pairs):
        # Unnormalised directions: the segment is t in [0, 1), shortened at the VPL's
        # end by the offset (more at grazing angles) so its own surface does not block it.
        direction = np.empty((len(pairs), 3), f32)
        direction[:, 0] = dx.ravel()[pairs]
        direction[:, 1] = dy.ravel()[pairs]
        direction[:, 2] = dz.ravel()[pairs]
        origin = (Pf + Gf * f32(eps))[pairs // dx.shape[1]]
        tfar = f32(1 - 1e-5) - f32(2 * eps) * inv.ravel()[pairs] / np.maximum(
            cos_y.ravel()[pairs], f32(1e-2))
        blocked = tracer.occluded(origin, direction, tfar, threads=False)
        weight.ravel()[pairs[blocked]] = 0
    return (weight @ vpl_flux.astype(f32)).astype(np.float64) / np.pi


def indirect_irradiance(frame, gb, vpls, min_distance, subset_of_sample, subsets,
                        cancel=None, progress=None):
    """Irradiance (S, 3) from the VPLs. Sample i gathers only the interleaved subset
    subset_of_sample[i] of `subsets` (Keller & Heidrich 2001), its flux scaled up."""
    E = np.zeros((len(gb.hit), 3))
    if vpls.count == 0 or not gb.hit.any():
        return E
    tasks = []
    for k, (subset, scale) in enumerate(vpl_subsets(vpls, subsets)):
        idx = np.flatnonzero(gb.hit & (subset_of_sample == k))
        if subset.count == 0 or len(idx) == 0:
            continue
        step = max(1, PAIRS_PER_TASK // subset.count)
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

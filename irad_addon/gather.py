"""The deferred shading pass: irradiance at every G-buffer sample from the lights
(shadow rays to light samples) and from the VPLs (one shadow ray per VPL)."""
import threading
from concurrent.futures import as_completed
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import light_tree, rays, sampling
from . import lightcuts as lightcuts_module

# Pixel-VPL pairs per gather task: bounds the float32 temporaries (~10 arrays of
# this many elements per thread) while keeping each Embree call large.
PAIRS_PER_TASK = 1 << 18


def light_sample_pattern(count, points, rng):
    """`count` 2D samples per point: a Hammersley set, toroidally shifted per point
    (Cranley-Patterson), so every point gets a stratified but different pattern."""
    base = sampling.hammersley(count, 2)
    shift = rng.random((points, 2))
    return (base[:, None, :] + shift[None]) % 1.0


def direct_irradiance(frame, gb, light_samples, rng, cancel=None, visible=None):
    """Irradiance (S, 3) from every emitter, with shadow rays. `visible(origins,
    directions, tfar)` replaces the plain shadow-ray test (mirrors.py uses it)."""
    E = np.zeros((len(gb.hit), 3))
    idx = np.flatnonzero(gb.hit)
    if len(idx) == 0:
        return E
    P, N, G = gb.position[idx], gb.normal[idx], gb.geo_normal[idx]
    eps = frame.offset()
    origins = P + G * eps
    if visible is None:
        visible = lambda o, d, t: ~frame.tracer.occluded(o, d, t)
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
            lit = sel[visible(origins[sel], direction[sel], tfar)]
            E[idx[lit]] += e[lit] / count
    return E


def vpl_subsets(vpls, subsets):
    """Interleave the VPLs into `subsets` groups (j mod subsets), each group's flux
    scaled by N / (its size): every group alone estimates the whole set's light, so a
    pixel that sees only a few groups (next to an edge, where the discontinuity buffer
    has few neighbours) is not brighter or darker for the sizes of the groups it sees.
    With fewer VPLs than groups, group k holds VPL k mod N."""
    count = vpls.count
    if count < subsets:
        return [(vpls.subset(slice(k % count, k % count + 1)), float(count))
                for k in range(subsets)] if count else []
    return [(vpls.subset(slice(k, None, subsets)), count / len(range(k, count, subsets)))
            for k in range(subsets)]


def vpl_irradiance_chunk(P, N, G, vpl_position, vpl_normal, vpl_flux, min_distance2,
                         tracer, eps, visible=None):
    """Irradiance at points P from VPLs: sum_j flux_j/pi cos_x cos_y / max(d^2, dmin^2) V.
    The VPL emits with a cosine lobe (Keller 1997, eq. 5)."""
    transfer = vpl_transfer(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps,
                            visible)
    return (transfer @ vpl_flux.astype(np.float32)).astype(np.float64) / np.pi


def vpl_transfer(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps,
                 visible=None):
    """float32 (points, VPLs): cos_x cos_y / max(d^2, dmin^2) V per pair, what each
    VPL's flux / pi becomes at each point (the flux-free part of the gather).

    Every pairwise dot product is one small matrix product (n.(y - x) = n.y - n.x),
    so numpy makes a handful of passes over the (points x VPLs) arrays; coordinates
    are taken relative to the chunk's centre to keep float32 exact enough."""
    f32 = np.float32
    centre = P.mean(0)
    X, Y = (P - centre).astype(f32), (vpl_position - centre).astype(f32)
    Nf, Gf, Vn = N.astype(f32), G.astype(f32), vpl_normal.astype(f32)
    # n_x . d, -n_y . d and g_x . d, with d = y - x, as (points, VPLs) arrays.
    cos_x = Nf @ Y.T - np.einsum('ij,ij->i', Nf, X)[:, None]
    cos_y = X @ Vn.T - np.einsum('ij,ij->i', Vn, Y)[None, :]
    above = Gf @ Y.T - np.einsum('ij,ij->i', Gf, X)[:, None]
    dist2 = np.einsum('ij,ij->i', X, X)[:, None] + np.einsum('ij,ij->i', Y, Y)[None, :]
    dist2 -= 2 * (X @ Y.T)
    np.maximum(dist2, f32(1e-30), out=dist2)
    valid = (cos_x > 0) & (cos_y > 0) & (above > 0)
    # cos_x cos_y / d^2 with the un-normalised dots, then the clamped 1 / d^2.
    weight = cos_x * cos_y
    weight /= dist2
    weight /= np.maximum(dist2, f32(min_distance2))
    weight[~valid] = 0
    pairs = np.flatnonzero(valid)
    if len(pairs):
        # Pairs are sorted by point: repeat each point's row instead of gathering it.
        per_point = valid.sum(1)
        light = pairs % Y.shape[0]
        # Ray ends in the tracer's float32 frame (exact far from the world origin).
        origin = np.repeat(tracer.to_local(P + G * eps), per_point, axis=0)
        # Unnormalised directions: the segment is t in [0, 1), shortened at the VPL's
        # end by the offset (more at grazing angles) so its own surface does not block it.
        direction = np.take(tracer.to_local(vpl_position), light, axis=0)
        direction -= origin
        d = np.sqrt(dist2.ravel()[pairs])
        tfar = segment_end(d, cos_y.ravel()[pairs] / d, eps)
        if visible is None:
            blocked = tracer.occluded(origin, direction, tfar, threads=False, local=True)
        else:
            blocked = ~visible(origin + tracer.center, direction, tfar)   # world frame
        weight.ravel()[pairs[blocked]] = 0
    return weight


def segment_end(distance, cos_vpl, eps):
    """tfar of a shadow segment from a point to a VPL given as the unnormalised
    direction (t in [0, 1)): shortened at the VPL's end by the offset, more at grazing
    angles, so that the VPL's own surface does not block it."""
    f32 = np.float32
    return f32(1 - 1e-5) - f32(2 * eps) / (distance * np.maximum(cos_vpl, f32(1e-2)))


def pair_transfer(points, lights, gb, vpls, min_distance2, tracer, eps):
    """float32 (n,): vpl_transfer's term for n (G-buffer sample, VPL) index pairs, for
    sparse pair lists (transfer_reuse.py's new VPLs, a few per point). One compiled
    pass makes the weights and the shadow segments of the pairs that need one."""
    weight = np.empty(len(points), np.float32)
    origin = np.empty((len(points), 3), np.float32)
    direction = np.empty((len(points), 3), np.float32)
    distance = np.empty(len(points), np.float32)
    cos_vpl = np.empty(len(points), np.float32)
    pairs = np.empty(len(points), np.int64)
    count = _pair_terms(points, lights, gb.position, gb.normal, gb.geo_normal, vpls.position,
                        vpls.normal, min_distance2, eps, tracer.center, weight, origin,
                        direction, distance, cos_vpl, pairs)
    if count:
        tfar = segment_end(distance[:count], cos_vpl[:count], eps)
        blocked = tracer.occluded(origin[:count], direction[:count], tfar, threads=False,
                                  local=True)
        weight[pairs[:count][blocked]] = 0
    return weight


@njit(cache=True)
def _pair_terms(points, lights, P, N, G, Y, NY, min_distance2, eps, centre, weight, origin,
                direction, distance, cos_vpl, pairs):
    """vpl_transfer's term per pair before visibility, and the shadow segments (in the
    tracer's frame, relative to `centre`) of the pairs with a positive term, packed
    first; returns their number."""
    count = 0
    for i in range(len(points)):
        p, v = points[i], lights[i]
        dx, dy, dz = Y[v, 0] - P[p, 0], Y[v, 1] - P[p, 1], Y[v, 2] - P[p, 2]
        dist2 = max(dx * dx + dy * dy + dz * dz, 1e-30)
        cos_x = N[p, 0] * dx + N[p, 1] * dy + N[p, 2] * dz
        cos_y = -(NY[v, 0] * dx + NY[v, 1] * dy + NY[v, 2] * dz)
        above = G[p, 0] * dx + G[p, 1] * dy + G[p, 2] * dz
        if cos_x <= 0 or cos_y <= 0 or above <= 0:
            weight[i] = 0
            continue
        weight[i] = cos_x * cos_y / dist2 / max(dist2, min_distance2)
        for c in range(3):
            start = P[p, c] + G[p, c] * eps - centre[c]
            origin[count, c] = start
            direction[count, c] = (Y[v, c] - centre[c]) - np.float32(start)
        distance[count] = np.sqrt(dist2)
        cos_vpl[count] = cos_y / np.sqrt(dist2)
        pairs[count] = i
        count += 1
    return count


@dataclass
class Lightcuts:
    """Settings of the lightcut gather (Walter et al. 2005)."""
    error: float = 0.02          # refine until every cluster's bound < error x estimate
    max_cut: int = 1000          # most clusters (shadow rays) per point
    points_per_task: int = 4096


def subset_light_tree(vpls, subsets, k, subset):
    """The light tree of interleaved subset k, built once per VPL set (vpls.derived)."""
    key = ("light_tree", subsets, k)
    if key not in vpls.derived:
        tree = light_tree.build_light_tree(subset.position, subset.normal, subset.flux)
        tree.bound_columns   # filled lazily: fill it here, not in the worker threads
        vpls.derived[key] = tree
    return vpls.derived[key]


def facing_points(vpls, points):
    """VPLs whose emitting side faces at least part of the box around `points`: the
    others light none of them (cos_y <= 0 at every corner) and cost no work."""
    lo, hi = points.min(0), points.max(0)
    corners = np.array([[(lo, hi)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
    reach = np.einsum('mk,ck->mc', vpls.normal, corners) - np.einsum(
        'mk,mk->m', vpls.normal, vpls.position)[:, None]
    return reach.max(1) > 0


def _gather_tasks(gb, vpls, subset_of_sample, subsets, lightcuts):
    """(sample indices, VPL subset, flux scale, light tree or None) per worker task."""
    tasks = []
    # The hit samples of each subset, from one sort instead of a pass per subset.
    hits = np.flatnonzero(gb.hit)
    hits = hits[np.argsort(subset_of_sample[hits], kind='stable')]
    bounds = np.searchsorted(subset_of_sample[hits], np.arange(subsets + 1))
    for k, (subset, scale) in enumerate(vpl_subsets(vpls, subsets)):
        idx = hits[bounds[k]:bounds[k + 1]]
        if subset.count == 0 or len(idx) == 0:
            continue
        tree = None
        if lightcuts:
            tree = subset_light_tree(vpls, subsets, k, subset)
            step = lightcuts.points_per_task
        else:
            subset = subset.subset(facing_points(subset, gb.position[idx]))
            if subset.count == 0:
                continue
            step = max(1, PAIRS_PER_TASK // subset.count)
        tasks += [(idx[a:a + step], subset, scale, tree) for a in range(0, len(idx), step)]
    return tasks


def indirect_irradiance(frame, gb, vpls, min_distance, subset_of_sample, subsets,
                        cancel=None, progress=None, lightcuts=None, stats=None, visible=None):
    """Irradiance (S, 3) from the VPLs. Sample i gathers only the interleaved subset
    subset_of_sample[i] of `subsets` (Keller & Heidrich 2001), its flux scaled up;
    with `lightcuts` (a Lightcuts) each point gathers a cut of a light tree instead of
    every VPL. `stats` (a dict) receives the shadow rays per point."""
    E = np.zeros((len(gb.hit), 3))
    if vpls.count == 0 or not gb.hit.any():
        return E
    tasks = _gather_tasks(gb, vpls, subset_of_sample, subsets, lightcuts)
    eps = frame.offset()
    stop = threading.Event()
    rays_per_point = np.zeros(len(gb.hit))

    def run(task):
        idx, subset, scale, tree = task
        if stop.is_set():
            return
        P, N, G = gb.position[idx], gb.normal[idx], gb.geo_normal[idx]
        if tree is None:
            E[idx] = scale * vpl_irradiance_chunk(P, N, G, subset.position, subset.normal,
                                                  subset.flux, min_distance ** 2,
                                                  frame.tracer, eps, visible)
            rays_per_point[idx] = subset.count
        else:
            E_cut, cut_size = lightcuts_module.lightcut_irradiance(
                P, N, G, tree, lightcuts.error, lightcuts.max_cut, min_distance ** 2,
                frame.tracer, eps)
            E[idx] = scale * E_cut
            rays_per_point[idx] = cut_size

    # Workers only compute; progress and cancel stay on the calling (Blender) thread.
    futures = [rays.thread_pool().submit(run, t) for t in tasks]
    for done, future in enumerate(as_completed(futures), 1):
        future.result()
        if cancel and cancel():
            stop.set()
        if progress:
            progress(done / len(futures))
    if stats is not None:
        stats["shadow_rays_per_point"] = float(rays_per_point[gb.hit].mean())
    return E

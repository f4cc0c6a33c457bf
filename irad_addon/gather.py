"""The deferred shading pass's indirect light: irradiance at every G-buffer sample from
the VPLs (one shadow ray per VPL; direct light is direct_light.py's)."""
import hashlib
import threading
from concurrent.futures import as_completed
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import light_tree, rays
from . import lightcuts as lightcuts_module

# Pixel-VPL pairs per gather task: bounds the float32 temporaries (~10 arrays of
# this many elements per thread) while keeping each Embree call large.
PAIRS_PER_TASK = 1 << 18
# Gather tasks of a band at least, enough to share the cores. Not from the thread
# count: each task's first sample bounds its roulette by its own sum, so the split
# shows in the image, which must not depend on the threads that made it.
TASKS_AT_LEAST = 16


@dataclass
class GroupedVPLs:
    """The VPLs listed by interleaved group: group k is order[start[k]:stop[k]], its
    flux scaled by scale[k] (vpl_subsets)."""
    order: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    scale: np.ndarray


def grouped_vpls(ids, subsets):
    """GroupedVPLs of the VPLs with `ids` (VPLs.ids) in `subsets` groups, as
    vpl_subsets groups them."""
    count = len(ids)
    if count < subsets:
        first = np.arange(subsets)
        return GroupedVPLs(first % max(count, 1), first, first + 1,
                           np.full(subsets, float(count)))
    group = ids % subsets
    sizes = np.bincount(group, minlength=subsets)
    stop = np.cumsum(sizes)
    return GroupedVPLs(np.argsort(group, kind='stable'), stop - sizes, stop, count / sizes)


def vpl_subsets(vpls, subsets):
    """Interleave the VPLs into `subsets` groups (id mod subsets), each group's flux
    scaled by N / (its size): every group alone estimates the whole set's light, so a
    pixel that sees only a few groups (next to an edge, where the discontinuity buffer
    has few neighbours) is not brighter or darker for the sizes of the groups it sees.
    With fewer VPLs than groups, group k holds VPL k mod N."""
    if vpls.count == 0:
        return []
    g = grouped_vpls(vpls.ids, subsets)
    return [(vpls.subset(g.order[a:b]), float(scale))
            for a, b, scale in zip(g.start, g.stop, g.scale)]


def vpl_irradiance_chunk(P, N, G, vpl_position, vpl_normal, vpl_flux, min_distance2,
                         tracer, eps, visible=None):
    """Irradiance at points P from VPLs: sum_j flux_j/pi cos_x cos_y / max(d^2, dmin^2) V.
    The VPL emits with a cosine lobe (Keller 1997, eq. 5)."""
    transfer = vpl_transfer(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps,
                            visible)
    return (transfer @ vpl_flux.astype(np.float32)).astype(np.float64) / np.pi


def vpl_transfer(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps,
                 visible=None, flux_weight=None, budget=0.0, key=0):
    """float32 (points, VPLs): cos_x cos_y / max(d^2, dmin^2) V per pair, what each
    VPL's flux / pi becomes at each point (the flux-free part of the gather). One
    compiled pass (numba, without the GIL) makes every pair's term and the shadow
    segments of the pairs with a positive one; Embree then tests those segments.
    `visible(origins, directions, tfar)` (world frame) replaces the plain test.
    budget > 0: shadow-ray roulette (_group_terms) by the VPLs' `flux_weight`."""
    n, m = len(P), len(vpl_position)
    weight, segments = np.empty(n * m, np.float32), _segments(n * m)
    # One group holding every VPL: pair p * m + v.
    lists = (np.arange(n), np.zeros(n, np.int64), np.zeros(1, np.int64),
             np.full(1, m, np.int64), np.arange(m))
    flux_weight = np.zeros(m) if flux_weight is None else flux_weight
    count = _group_terms(*lists, *_contiguous(P, N, G, vpl_position, vpl_normal),
                         min_distance2, eps, tracer.center, weight, *segments,
                         np.ascontiguousarray(flux_weight, np.float64), budget, key)
    _shadow_test(weight, segments, count, tracer, eps, visible)
    return weight.reshape(n, m)


def sparse_transfer(points, lights, gb, vpls, min_distance2, tracer, eps, bounds=None,
                    key=0):
    """float32 (n,): vpl_transfer's term for n (G-buffer sample, VPL) index pairs, for
    sparse pair lists (transfer_reuse.py's new VPLs, a few per point). bounds: per
    G-buffer sample, the contribution (term times the VPL's mean flux) below which a
    pair's shadow ray is played by roulette (_group_terms); None: every ray."""
    weight, segments = np.empty(len(points), np.float32), _segments(len(points))
    bounds = np.zeros(len(gb.hit)) if bounds is None else bounds
    count = _listed_terms(points, lights, *_contiguous(gb.position, gb.normal, gb.geo_normal,
                                                       vpls.position, vpls.normal),
                          min_distance2, eps, tracer.center, weight, *segments,
                          np.ascontiguousarray(vpls.flux.mean(1), np.float64),
                          np.ascontiguousarray(bounds, np.float64), key)
    _shadow_test(weight, segments, count, tracer, eps)
    return weight


def segment_end(distance, cos_vpl, eps):
    """tfar of a shadow segment from a point to a VPL given as the unnormalised
    direction (t in [0, 1)): shortened at the VPL's end by the offset, more at grazing
    angles, so that the VPL's own surface does not block it."""
    f32 = np.float32
    return f32(1 - 1e-5) - f32(2 * eps) / (distance * np.maximum(cos_vpl, f32(1e-2)))


def _contiguous(*arrays):
    return [np.ascontiguousarray(a, np.float64) for a in arrays]


def _segments(count):
    """Room for `count` shadow segments: origin and unnormalised direction (float32,
    the tracer's frame), length, cosine at the VPL and the pair they belong to."""
    return (np.empty((count, 3), np.float32), np.empty((count, 3), np.float32),
            np.empty(count, np.float32), np.empty(count, np.float32),
            np.empty(count, np.int64))


def _shadow_test(weight, segments, count, tracer, eps, visible=None):
    """Zero the weights of the first `count` segments' pairs that something blocks."""
    if count == 0:
        return
    origin, direction, distance, cos_vpl, pair = (a[:count] for a in segments)
    tfar = segment_end(distance, cos_vpl, eps)
    if visible is None:
        blocked = tracer.occluded(origin, direction, tfar, threads=False, local=True)
    else:
        blocked = ~visible(origin + tracer.center, direction, tfar)   # world frame
    weight[pair[blocked]] = 0


@njit(cache=True, nogil=True)
def _listed_terms(points, lights, P, N, G, Y, NY, min_distance2, eps, centre, weight, origin,
                  direction, distance, cos_vpl, pair, flux_weight, bounds, seed):
    """_pair_weight and _segment for the listed (point, VPL) pairs, with shadow-ray
    roulette below bounds[point] (_group_terms)."""
    count = 0
    for i in range(len(points)):
        s, v = points[i], lights[i]
        w = _pair_weight(P, N, G, Y, NY, s, v, min_distance2)
        w = _roulette(w, w * flux_weight[v], bounds[s], s, v, seed)
        weight[i] = w
        if w > 0:
            count = _segment(P[s], G[s], Y[v], NY[v], i, eps, centre, origin, direction,
                             distance, cos_vpl, pair, count)
    return count


@njit(cache=True, nogil=True)
def _group_terms(samples, group_of_sample, start, stop, order, P, N, G, Y, NY,
                 min_distance2, eps, centre, weight, origin, direction, distance, cos_vpl,
                 pair, flux_weight, budget, seed):
    """_pair_weight and, for a positive one, _segment for every sample and each VPL of
    its group, pair by pair (pair i of weight), with shadow-ray roulette (Arvo & Kirk
    1990's Russian roulette on shadow rays, as Ward 1991 skips the tests of weak
    lights): a pair whose unoccluded contribution c is below S / budget (S: the
    sample's sum) keeps its ray with probability p = c budget / S and is weighted by
    1 / p. The pairs are drawn by systematic sampling (one uniform per sample, hashed
    from it: pair j is kept where the running sum of p crosses it), so each pair keeps
    its probability while a sample's ray count varies by at most one: unbiased, at
    most `budget` rays per sample in expectation, and less noise than independent
    draws for as many rays. S is the previous sample's of the same group (a
    neighbouring pixel), the first one's own. The group's VPLs are copied into flat
    arrays once per group, so that every sample's terms are one vectorised loop
    (_kept_terms)."""
    size = 1
    for k in range(len(start)):
        size = max(size, stop[k] - start[k])
    columns = np.empty((7, size))   # the group's VPL x, y, z, normal x, y, z, flux weight
    w, keep, chosen = np.empty(size), np.empty(size), np.empty(size, np.int64)
    i = count = 0
    group, bound, m = -1, 0.0, 0
    for s in samples:
        k = group_of_sample[s]
        if k != group:
            m = stop[k] - start[k]
            for j in range(m):
                v = order[start[k] + j]
                for c in range(3):
                    columns[c, j] = Y[v, c]
                    columns[3 + c, j] = NY[v, c]
                columns[6, j] = flux_weight[v]
            if budget > 0:   # the group's first sample: its own sum
                bound = _kept_terms(P[s], N[s], G[s], columns, m, min_distance2, 0.0, w,
                                    keep) / budget
        group = k
        # inv_bound 0: no roulette, every positive term keeps its ray.
        total = _kept_terms(P[s], N[s], G[s], columns, m, min_distance2,
                            1.0 / bound if bound > 0 else 0.0, w, keep)
        mark, n = _uniform(s, 0, seed), 0
        for j in range(m):   # branch-free: the kept pairs' indices into `chosen`
            mark -= keep[j]
            kept = mark < 0.0
            mark += 1.0 if kept else 0.0
            weight[i + j] = w[j] / keep[j] if kept else 0.0
            chosen[n] = j
            n += 1 if kept else 0
        for q in range(n):
            j = chosen[q]
            count = _segment(P[s], G[s], columns[:3, j], columns[3:6, j], i + j, eps,
                             centre, origin, direction, distance, cos_vpl, pair, count)
        i += m
        bound = total / budget if budget > 0 else 0.0
    return count


@njit(cache=True, nogil=True, fastmath=True)
def _kept_terms(p, n, g, columns, m, min_distance2, inv_bound, out, keep):
    """_pair_weight of the point (position p, shading normal n, geometric normal g)
    with the first m VPLs of `columns` (_group_terms) into out[:m], and each pair's
    probability to keep its shadow ray, min(1, term x flux weight x inv_bound) (1
    where inv_bound is 0: no roulette), into keep[:m] (0 for a zero term); returns the
    sum of the terms times the flux weights. Branch-free, so it runs in SIMD lanes."""
    total = 0.0
    for j in range(m):
        dx, dy, dz = columns[0, j] - p[0], columns[1, j] - p[1], columns[2, j] - p[2]
        dist2 = max(dx * dx + dy * dy + dz * dz, 1e-30)
        cos_x = n[0] * dx + n[1] * dy + n[2] * dz
        cos_y = -(columns[3, j] * dx + columns[4, j] * dy + columns[5, j] * dz)
        above = g[0] * dx + g[1] * dy + g[2] * dz
        term = cos_x * cos_y / dist2 / max(dist2, min_distance2)
        term = term if (cos_x > 0) & (cos_y > 0) & (above > 0) else 0.0
        out[j] = term
        contribution = term * columns[6, j]
        total += contribution
        chance = min(contribution * inv_bound, 1.0) if inv_bound > 0 else 1.0
        keep[j] = chance if term > 0 else 0.0
    return total


@njit(cache=True, inline='always')
def _roulette(w, contribution, bound, s, v, seed):
    """A pair's weight after shadow-ray roulette: kept with probability contribution /
    bound (below the bound) and then divided by it, else 0."""
    if w <= 0 or contribution >= bound:
        return w
    keep = contribution / bound
    return w / keep if _uniform(s, v, seed) < keep else 0.0


@njit(cache=True, inline='always')
def _uniform(a, b, seed):
    """A uniform number in [0, 1) hashed from two indices and a seed (splitmix64)."""
    z = np.uint64(a) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(b) + np.uint64(seed)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, nogil=True)
def _group_sums(samples, group_of_sample, start, stop, order, scale, weight, flux, E):
    """E[s] = scale / pi sum over the group's VPLs of weight * flux, in _group_terms'
    pair order."""
    i = 0
    for s in samples:
        k = group_of_sample[s]
        red = green = blue = 0.0
        for j in range(start[k], stop[k]):
            v = order[j]
            red += weight[i] * flux[v, 0]
            green += weight[i] * flux[v, 1]
            blue += weight[i] * flux[v, 2]
            i += 1
        f = scale[k] / np.pi
        E[s, 0], E[s, 1], E[s, 2] = red * f, green * f, blue * f


@njit(cache=True, inline='always')
def _pair_weight(P, N, G, Y, NY, p, v, min_distance2):
    """Point p's term from VPL v before visibility,
    cos_x cos_y / d^2 / max(d^2, dmin^2) with unnormalised cosines (Keller 1997, eq. 5,
    the VPL's cosine lobe); 0 where either faces away or v is below p's surface."""
    dx, dy, dz = Y[v, 0] - P[p, 0], Y[v, 1] - P[p, 1], Y[v, 2] - P[p, 2]
    dist2 = max(dx * dx + dy * dy + dz * dz, 1e-30)
    cos_x = N[p, 0] * dx + N[p, 1] * dy + N[p, 2] * dz
    cos_y = -(NY[v, 0] * dx + NY[v, 1] * dy + NY[v, 2] * dz)
    above = G[p, 0] * dx + G[p, 1] * dy + G[p, 2] * dz
    if cos_x <= 0 or cos_y <= 0 or above <= 0:
        return 0.0
    return cos_x * cos_y / dist2 / max(dist2, min_distance2)


@njit(cache=True, inline='always')
def _segment(p, g, y, ny, i, eps, centre, origin, direction, distance, cos_vpl, pair,
             count):
    """Shadow segment `count` of pair i, from point p (geometric normal g) lifted off
    its surface by eps to the VPL at y (normal ny), in the tracer's frame (relative to
    `centre`). Returns count + 1."""
    dist2 = cos_y = 0.0
    for c in range(3):
        start = np.float32(p[c] + g[c] * eps - centre[c])
        origin[count, c] = start
        direction[count, c] = np.float32(y[c] - centre[c]) - start
        gap = y[c] - p[c]
        dist2 += gap * gap
        cos_y -= ny[c] * gap
    length = np.sqrt(max(dist2, 1e-30))
    distance[count], cos_vpl[count], pair[count] = length, cos_y / length, i
    return count + 1


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


def grouped_tasks(gb, vpls, subset_of_sample, subsets):
    """(GroupedVPLs, tasks): the hit samples sorted by interleaved group and split into
    (samples, pairs) tasks of about PAIRS_PER_TASK pairs, TASKS_AT_LEAST at least.
    VPLs facing away from every sample are left out of the groups (no work)."""
    hits = np.flatnonzero(gb.hit)
    hits = hits[np.argsort(subset_of_sample[hits], kind='stable')]
    g = grouped_vpls(vpls.ids, subsets)
    kept = facing_points(vpls, gb.position[hits])[g.order]
    ends = np.concatenate([[0], np.cumsum(kept)])
    g = GroupedVPLs(g.order[kept], ends[g.start], ends[g.stop], g.scale)
    pairs = np.cumsum((g.stop - g.start)[subset_of_sample[hits]])
    total = int(pairs[-1])
    pieces = max(-(-total // PAIRS_PER_TASK), TASKS_AT_LEAST)
    cuts = np.searchsorted(pairs, total * np.arange(1, pieces) / pieces, side='right')
    bounds = np.unique(np.concatenate([[0], cuts, [len(hits)]]))
    before = np.concatenate([[0], pairs])
    return g, [(hits[a:b], int(before[b] - before[a])) for a, b in zip(bounds[:-1], bounds[1:])]


def group_irradiance(samples, pairs, subset_of_sample, groups, gb, vpls, min_distance2,
                     tracer, eps, E, visible=None, budget=0.0, key=0):
    """E[samples] from the VPLs of each sample's interleaved group (`pairs` in all):
    vpl_irradiance_chunk's sum, over pairs listed group by group, with shadow-ray
    roulette to about `budget` rays per sample (_group_terms; `key` seeds its hash).
    Returns the shadow rays traced."""
    weight, segments = np.empty(pairs, np.float32), _segments(pairs)
    arrays = _contiguous(gb.position, gb.normal, gb.geo_normal, vpls.position, vpls.normal)
    lists = (samples, subset_of_sample, groups.start, groups.stop, groups.order)
    count = _group_terms(*lists, *arrays, min_distance2, eps, tracer.center, weight, *segments,
                         np.ascontiguousarray(vpls.flux.mean(1), np.float64), budget, key)
    _shadow_test(weight, segments, count, tracer, eps, visible)
    _group_sums(*lists, groups.scale, weight, np.ascontiguousarray(vpls.flux, np.float64), E)
    return count


def hash_seed(seed):
    """A 63-bit key for _uniform from an int or a tuple of ints."""
    return int.from_bytes(hashlib.blake2b(repr(seed).encode(), digest_size=8).digest(),
                          'little') >> 1


def _lightcut_tasks(gb, vpls, subset_of_sample, subsets, lightcuts):
    """(sample indices, VPL subset, flux scale, light tree) per worker task."""
    tasks = []
    # The hit samples of each subset, from one sort instead of a pass per subset.
    hits = np.flatnonzero(gb.hit)
    hits = hits[np.argsort(subset_of_sample[hits], kind='stable')]
    bounds = np.searchsorted(subset_of_sample[hits], np.arange(subsets + 1))
    for k, (subset, scale) in enumerate(vpl_subsets(vpls, subsets)):
        idx = hits[bounds[k]:bounds[k + 1]]
        if subset.count == 0 or len(idx) == 0:
            continue
        tree = subset_light_tree(vpls, subsets, k, subset)
        step = lightcuts.points_per_task
        tasks += [(idx[a:a + step], subset, scale, tree) for a in range(0, len(idx), step)]
    return tasks


def indirect_irradiance(frame, gb, vpls, min_distance, subset_of_sample, subsets,
                        cancel=None, progress=None, lightcuts=None, stats=None,
                        shadow_ray_budget=0.0, seed=0, visible=None):
    """Irradiance (S, 3) from the VPLs. Sample i gathers only the interleaved subset
    subset_of_sample[i] of `subsets` (Keller & Heidrich 2001), its flux scaled up;
    with `lightcuts` (a Lightcuts) each point gathers a cut of a light tree instead of
    every VPL. `shadow_ray_budget` > 0: shadow-ray roulette (_group_terms), its random
    numbers hashed from `seed` (ints). `stats` (a dict) receives the shadow rays per
    point."""
    return start_indirect(frame, gb, vpls, min_distance, subset_of_sample, subsets,
                          lightcuts, shadow_ray_budget, seed, visible).wait(cancel, progress,
                                                                           stats)


class PendingIrradiance:
    """indirect_irradiance's tasks running on the thread pool; wait() returns E. The
    caller may work meanwhile (on its own thread: rays.on_calling_thread).
    run(pending, task) does a task; rays_per_point(pending) tells the rays it traced."""

    def __init__(self, E, tasks, run, rays_per_point):
        self.E, self.rays_per_point = E, rays_per_point
        self.traced, self.stop = [], threading.Event()
        # The workers are busy, or the user asked for one thread: run here, now.
        here = rays.on_calling_thread_now() or rays.worker_count() < 2
        start = (lambda t: rays.run_now(run, self, t)) if here else (
            lambda t: rays.thread_pool().submit(run, self, t))
        self.jobs = [rays.Job(start(t), run, self, t) for t in tasks]

    def running(self):
        """Whether any task is still queued or running."""
        return not all(job.done() for job in self.jobs)

    def wait(self, cancel=None, progress=None, stats=None):
        """E (S, 3) once every task is done; `cancel()` is polled and stops the rest.
        Tasks no worker has started yet run here, last first (the workers take the
        first first), so this thread helps instead of idling. Workers only compute;
        progress and cancel stay on the calling (Blender) thread."""
        count = len(self.jobs)

        def finished(done, future):
            future.result()   # a task's error is raised here
            if cancel and cancel():
                self.stop.set()
            if progress:
                progress(done / count)
        taken = []
        with rays.on_calling_thread():
            for job in reversed(self.jobs):   # a task already run or running stops it
                if self.stop.is_set() or not job.take():
                    break
                taken.append(job)
                finished(len(taken), job.future)
        rest = [job.future for job in self.jobs[:count - len(taken)]]
        for done, future in enumerate(as_completed(rest), len(taken) + 1):
            finished(done, future)
        if stats is not None:
            stats["shadow_rays_per_point"] = self.rays_per_point(self)
        return self.E


def start_indirect(frame, gb, vpls, min_distance, subset_of_sample, subsets, lightcuts=None,
                   shadow_ray_budget=0.0, seed=0, visible=None):
    """indirect_irradiance's work started on the thread pool: a PendingIrradiance."""
    E = np.zeros((len(gb.hit), 3))
    if vpls.count == 0 or not gb.hit.any():
        return _done(E)
    eps = frame.offset()
    if lightcuts is None:
        groups, tasks = grouped_tasks(gb, vpls, subset_of_sample, subsets)
        key = hash_seed(seed)

        def run(pending, task):
            if not pending.stop.is_set():
                pending.traced.append(group_irradiance(
                    *task, subset_of_sample, groups, gb, vpls, min_distance ** 2,
                    frame.tracer, eps, E, visible, shadow_ray_budget, key))
        points = np.count_nonzero(gb.hit)
        return PendingIrradiance(E, tasks, run, lambda pending: sum(pending.traced) / points)
    tasks = _lightcut_tasks(gb, vpls, subset_of_sample, subsets, lightcuts)
    cut_sizes = np.zeros(len(gb.hit))

    def run(pending, task):
        idx, subset, scale, tree = task
        if pending.stop.is_set():
            return
        E_cut, cut_size = lightcuts_module.lightcut_irradiance(
            gb.position[idx], gb.normal[idx], gb.geo_normal[idx], tree,
            lightcuts.error, lightcuts.max_cut, min_distance ** 2, frame.tracer, eps)
        E[idx] = scale * E_cut
        cut_sizes[idx] = cut_size
    return PendingIrradiance(E, tasks, run, lambda pending: float(cut_sizes[gb.hit].mean()))


def _done(E):
    """A PendingIrradiance with nothing to do."""
    return PendingIrradiance(E, [], None, lambda pending: 0.0)

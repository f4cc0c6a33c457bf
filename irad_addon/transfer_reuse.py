"""Reusing each VPL's light transfer to the camera's samples across frames.

Incremental IR keeps most VPLs from one frame to the next (Laine et al. 2007). What
makes that pay in their renderer is that a kept VPL keeps its shadow map: only the new
VPLs cost visibility work. The equivalent here: while the camera, the geometry and the
settings stay (a light moving in a still shot, or being placed interactively), the
G-buffers stay, and so does every kept VPL's transfer to each sample,
cos_x cos_y / max(d^2, dmin^2) V (gather.vpl_transfer). Only the new VPLs' columns
are traced; a frame's indirect light is then one matrix product per interleaved group
with the VPLs' new flux (their Voronoi powers change every frame).

VPLs are matched by their persistent id (incremental.LightSites.vpl_ids) and checked
to be at the same place; each goes to an interleaved group by a hash of its id, so it
keeps its group whatever the other VPLs do, and each group's flux is scaled by
N / (its size) as in gather.vpl_subsets.
"""
from dataclasses import dataclass, field, replace

import numpy as np

from . import gather, rays
from .gather import PAIRS_PER_TASK

# Most bytes what is kept may take; beyond it the frame is gathered as usual. Besides
# its transfer, a shading sample keeps about this many bytes (measured: its G-buffer
# row, its share of the coverage samples' map and passes).
MAX_BYTES = 1 << 30
GBUFFER_BYTES = 600
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)   # Fibonacci hashing (Knuth, TAOCP 6.4)


def interleaved_group(ids, subsets):
    """Interleaved group of each VPL, from a multiplicative hash of its id."""
    mixed = (ids.astype(np.uint64) * _GOLDEN) >> np.uint64(32)
    return (mixed % np.uint64(subsets)).astype(np.int64)


@dataclass
class GroupTransfer:
    """The kept columns of one interleaved group: VPL ids (ascending), where each VPL
    was (to check a match) and the float32 (samples, VPLs) transfer."""
    ids: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    transfer: np.ndarray


@dataclass
class BandTransfer:
    """A band's G-buffers, the random state after them, its groups' transfer, and what
    else depends on the G-buffers only: the antialiasing.CoverageMap and
    render.still_passes."""
    gbuffers: tuple
    rng_state: dict
    groups: dict = field(default_factory=dict)
    coverage: object = None
    still: dict = None
    # (S,): each sample's last VPL light, sum of transfer x mean flux: the bound of
    # the shadow-ray roulette of its new VPLs (gather.sparse_transfer)
    totals: np.ndarray = None


class TransferCache:
    """Transfer kept between the frames of one render job; begin() empties it when
    the camera, geometry or settings differ from the last frame's."""

    def __init__(self):
        self.key = None
        self.min_distance = 0.0
        self.bands = {}

    def begin(self, key, min_distance):
        """Start a frame; returns the clamping distance to use: the one the kept
        transfer was computed with (it varies slightly with the VPL count)."""
        if key != self.key:
            self.key, self.min_distance, self.bands = key, min_distance, {}
        return self.min_distance


def film_only(gb):
    """The G-buffer without its per-sample surfaces, for compose_passes once the still
    passes are made: it reads only the pixels and the mirror terms."""
    return replace(gb, **{name: None for name in (
        "sample", "hit", "position", "normal", "geo_normal", "albedo", "emission", "depth",
        "object_index", "holdout")})


def fits(samples, vpls, subsets):
    """Whether the G-buffers and transfer of `samples` camera samples and `vpls` VPLs
    in `subsets` groups stay within MAX_BYTES."""
    return samples * (GBUFFER_BYTES + 4.0 * vpls / max(subsets, 1)) <= MAX_BYTES


def reused_indirect_irradiance(frame, gb, vpls, ids, min_distance, subset_of_sample, subsets,
                               band, cancel=None, budget=0.0, seed=0):
    """Irradiance (S, 3) from the VPLs like gather.indirect_irradiance, with the kept
    VPLs' transfer from `band` (a BandTransfer, updated in place) and new columns traced
    only for the VPLs not seen before, with the shadow-ray roulette of `budget`, its
    random numbers hashed from `seed` (ints) as in gather.indirect_irradiance (its
    decisions are kept with the columns: unbiased in every frame). Returns E and the
    new VPLs gathered per point."""
    E = np.zeros((len(gb.hit), 3))
    hits = np.flatnonzero(gb.hit)
    if vpls.count == 0 or len(hits) == 0:
        band.groups = {}
        return E, 0.0
    hits = hits[np.argsort(subset_of_sample[hits], kind='stable')]
    bounds = np.searchsorted(subset_of_sample[hits], np.arange(subsets + 1))
    group = interleaved_group(ids, subsets)
    order = np.lexsort((ids, group))
    members = np.split(order, np.searchsorted(group[order], np.arange(1, subsets)))
    plans, point, light, dense = [], [], [], []
    for k in range(subsets):
        idx, mine = hits[bounds[k]:bounds[k + 1]], members[k]
        kept, columns = _match(band.groups.get(k), ids[mine], vpls.position[mine],
                               vpls.normal[mine])
        plans.append((k, idx, mine, kept, columns))
        if not kept.any():   # all new (a first frame): the dense gather's block
            dense.append((k, idx, mine))
            continue
        new = mine[~kept]
        point.append(np.repeat(idx, len(new)))   # the group's (sample, new VPL) pairs
        light.append(np.tile(new, len(idx)))
    bounds = (band.totals / budget if budget > 0 and band.totals is not None else None)
    traced = _trace(frame, gb, vpls, dense, np.concatenate(point) if point else [],
                    np.concatenate(light) if light else [], min_distance, cancel, bounds,
                    budget, gather.hash_seed(seed))
    if traced is None:
        return E, 0.0
    blocks, new_transfer = traced

    groups, new_per_point, start = {}, np.zeros(len(gb.hit)), 0
    band.totals, flux_weight = np.zeros(len(gb.hit)), vpls.flux.mean(1).astype(np.float32)
    for k, idx, mine, kept, columns in plans:
        if k in blocks:
            transfer = blocks[k]
        else:
            transfer = np.empty((len(idx), len(mine)), np.float32)
            if kept.any():
                transfer[:, kept] = band.groups[k].transfer[:, columns]
            fresh = len(idx) * int((~kept).sum())
            transfer[:, ~kept] = new_transfer[start:start + fresh].reshape(len(idx), -1)
            start += fresh
        scale = vpls.count / len(mine) if len(mine) else 0.0
        E[idx] = scale * (transfer @ vpls.flux[mine].astype(np.float32)) / np.pi
        band.totals[idx] = transfer @ flux_weight[mine]
        new_per_point[idx] = (~kept).sum()
        groups[k] = GroupTransfer(ids[mine], vpls.position[mine], vpls.normal[mine], transfer)
    band.groups = groups
    return E, float(new_per_point[gb.hit].mean())


def _trace(frame, gb, vpls, dense, point, light, min_distance, cancel, bounds, budget, key):
    """The new transfer, traced over the thread pool: {group: (samples, VPLs) block}
    for the `dense` groups (group, samples, VPLs), gather.vpl_transfer in chunks with
    the roulette of `budget`, and gather.sparse_transfer of the (sample, VPL) pairs
    `point`, `light` with the roulette `bounds`. None when cancelled."""
    eps = frame.offset()
    d2 = min_distance ** 2

    def block(k, idx, mine):
        return k, gather.vpl_transfer(gb.position[idx], gb.normal[idx], gb.geo_normal[idx],
                                      vpls.position[mine], vpls.normal[mine], d2,
                                      frame.tracer, eps, None, vpls.flux[mine].mean(1),
                                      budget, key)

    def pairs(a, b):
        return None, gather.sparse_transfer(point[a:b], light[a:b], gb, vpls, d2,
                                            frame.tracer, eps, bounds, key)

    tasks = []
    for k, idx, mine in dense:
        step = max(1, PAIRS_PER_TASK // max(len(mine), 1))
        tasks += [(block, (k, idx[a:a + step], mine)) for a in range(0, len(idx), step)]
    tasks += [(pairs, r) for r in
              rays.split_ranges(len(point), 2 * rays.worker_count(), PAIRS_PER_TASK // 8)]
    # Workers only compute; cancel stays on the calling (Blender) thread.
    futures = [rays.thread_pool().submit(task, *args) for task, args in tasks]
    blocks, parts = {}, []
    for future in futures:
        k, transfer = future.result()
        if k is None:
            parts.append(transfer)
        else:
            blocks.setdefault(k, []).append(transfer)
        if cancel and cancel():
            return None
    return ({k: np.concatenate(b) for k, b in blocks.items()},
            np.concatenate(parts) if parts else np.zeros(0, np.float32))


def _match(kept, ids, position, normal):
    """Which VPLs (ids ascending) have a kept column, and its index: the same id at the
    same place facing the same way."""
    if kept is None or len(kept.ids) == 0 or len(ids) == 0:
        return np.zeros(len(ids), bool), np.zeros(0, np.int64)
    at = np.minimum(np.searchsorted(kept.ids, ids), len(kept.ids) - 1)
    same = ((kept.ids[at] == ids) & (kept.position[at] == position).all(1)
            & (kept.normal[at] == normal).all(1))
    return same, at[same]

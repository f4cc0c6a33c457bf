"""Decoupled antialiasing: many cheap coverage samples per pixel, few shaded ones.

Edges need many camera rays per pixel (the box filter integrates coverage and albedo),
irradiance does not: it varies smoothly along a surface. So the G-buffer is traced
twice: `aa_samples` shading samples per pixel gather light, and `coverage_samples`
camera rays per pixel each take the mean irradiance of the shading samples on the
same surface, in their own pixel or else a neighbour (the split of coverage and
shading of MSAA and of decoupled sampling, Ragan-Kelley et al. 2011). Coverage rays
are traced only in pixels an edge may cross; the others keep their shading samples.

Irradiance is smooth except across a hard shadow's edge (a small light, a sun):
carried from a few shading samples, such an edge across a flat surface is resolved by
their few random positions only. So the pixels a hard shadow edge crosses get coverage
rays too, and these compute their own direct light (render.render_band; indirect light
is still carried). A hard edge is told by visibility (HardShadowEdges): for one
emitter, a shading sample whose shadow rays all pass and one whose rays are all
blocked, in the same pixel or in two neighbouring ones (8 neighbours, both flagged:
comparing every sample, not only the first as edge_pixels does, catches ~15% more of
the sun-lit room's edge variance), where that emitter gives the lit one at least
HARD_EDGE_SHARE of the pixel's mean direct light. A big area light's penumbra spreads
over pixels, its samples partly lit: rarely flagged.
"""
from dataclasses import dataclass, fields

import numpy as np
from numba import njit

from .gbuffer import GBuffer, build_gbuffer

# Two samples lie on the same surface when their geometric normals agree within ~25
# degrees and each is within this fraction of its depth of the other's tangent plane.
SAME_SURFACE_COS = 0.9
PLANE_TOLERANCE = 0.01

# Neighbouring pixels searched when no shading sample of the own pixel matches.
NEIGHBOURS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]

# Each pair of 8-neighbours once, as (dy, dx) from the first of them.
NEIGHBOUR_PAIRS = ((0, 1), (1, -1), (1, 0), (1, 1))

# A hard shadow edge is resolved per coverage sample where the emitter casting it gives
# at least this share of the pixel's mean direct irradiance (luminance).
HARD_EDGE_SHARE = 0.1
# Coverage rays on a hard shadow edge, per coverage sample elsewhere: the edge splits
# the pixel into a lit and a dark part whose areas only coverage measures (the sun-lit
# room: direct variance 2.1e-3 at 16 rays, 7e-4 at 64, which cost 4% of its pixels).
SHADOW_EDGE_RAYS = 4
# Emitters wider than this angle (radians) seen from the median shading sample cast
# penumbrae the shading samples resolve: their edges are not looked for (the search
# cost ~6 ms on the 96 x 96 Cornell box, whose 0.5 m ceiling light spans ~0.4 rad, and
# flagged 0.3% of its pixels).
SOFT_LIGHT_ANGLE = 0.1


def candidate_samples(gb, pixels, offsets):
    """Indices (n, len(offsets) * gb.samples) of the shading samples of the pixels at
    `offsets` (dy, dx) from `pixels`; -1 outside the G-buffer's rows."""
    count = gb.width * gb.height
    y, x = np.divmod(pixels, gb.width)
    columns = []
    for dy, dx in offsets:
        ny, nx = y + dy, x + dx
        inside = (ny >= 0) & (ny < gb.height) & (nx >= 0) & (nx < gb.width)
        neighbour = ny * gb.width + nx
        for s in range(gb.samples):
            columns.append(np.where(inside, s * count + neighbour, -1))
    return np.stack(columns, -1)


def surface_mismatch(cov, gb, index, candidates, strict=True):
    """Squared distances (n, K) from coverage samples `index` to their candidate
    shading samples; inf where a candidate is not on the same surface (strict) or,
    not strict, merely does not face the same way."""
    safe = np.maximum(candidates, 0)
    x_c, n_c = cov.position[index][:, None, :], cov.geo_normal[index][:, None, :]
    x_s, n_s = gb.position[safe], gb.geo_normal[safe]
    same = (candidates >= 0) & gb.hit[safe] & ~gb.holdout[safe]
    if strict:
        same &= same_surface(cov, np.repeat(index, candidates.shape[1]), gb,
                             safe.ravel()).reshape(same.shape)
    else:
        same &= np.einsum('...c,...c->...', n_c, n_s) > 0
    gap = x_c - x_s
    return np.where(same, np.einsum('nkc,nkc->nk', gap, gap), np.inf)


def surface_weights(cov, gb, index, offsets, strict=True):
    """For coverage samples `index`: (candidates (n, K), weights (n, K)) over the
    shading samples of the pixels at `offsets`: equal weights over those on the same
    surface (all of them for an interior pixel, so that the pixel's estimate is the
    plain mean of its shading samples), or, not strict, the nearest one facing the
    same way. Rows without a match have zero weights."""
    candidates = candidate_samples(gb, cov.pixel[index], offsets)
    cost = surface_mismatch(cov, gb, index, candidates, strict)
    if strict:
        weights = np.isfinite(cost).astype(np.float64)
    else:
        rows = np.arange(len(index))
        best = np.argmin(cost, axis=1)
        weights = np.zeros(cost.shape)
        weights[rows, best] = np.isfinite(cost[rows, best])
    total = weights.sum(1, keepdims=True)
    return candidates, weights / np.where(total > 0, total, 1.0)


def same_surface(a, index_a, b, index_b):
    """bool (n,): whether samples a[index_a] and b[index_b] of G-buffers a and b (hit
    samples) lie on the same surface: geometric normals within SAME_SURFACE_COS, each
    within PLANE_TOLERANCE of its depth of the other's tangent plane."""
    out = np.empty(len(index_a), bool)
    _same_surface(a.position, a.geo_normal, a.depth, np.asarray(index_a), b.position,
                  b.geo_normal, b.depth, np.asarray(index_b), SAME_SURFACE_COS,
                  PLANE_TOLERANCE, out)
    return out


@njit(cache=True, nogil=True)
def _same_surface(position_a, normal_a, depth_a, index_a, position_b, normal_b, depth_b,
                  index_b, cosine, tolerance, out):
    for k in range(len(index_a)):
        i, j = index_a[k], index_b[k]
        facing = gap_a = gap_b = 0.0
        for c in range(3):
            gap = position_a[i, c] - position_b[j, c]
            facing += normal_a[i, c] * normal_b[j, c]
            gap_a += gap * normal_a[i, c]
            gap_b += gap * normal_b[j, c]
        limit = tolerance * min(depth_a[i], depth_b[j])
        out[k] = facing > cosine and abs(gap_a) <= limit and abs(gap_b) <= limit


def uniform_pixels(gb):
    """bool (pixels,): every shading sample of the pixel hits one and the same surface,
    so a coverage sample on it takes the pixel's mean irradiance (most pixels)."""
    count = gb.width * gb.height
    lit = (gb.hit & ~gb.holdout).reshape(gb.samples, count)
    uniform = lit.all(0)
    first = np.arange(count)
    for s in range(1, gb.samples):
        uniform &= same_surface(gb, first, gb, s * count + first)
    return uniform


def surface_class(gb):
    """int8 (S,): what a camera sample sees, 0 background, 1 holdout, 2 a surface,
    + 3 if a light is seen (emission, or an area light in a mirror on the way),
    + 6 if seen in a mirror."""
    bright = gb.emission.max(1) > 0
    mirrored = np.zeros(len(gb.hit), bool)
    if gb.throughput is not None:
        bright |= gb.mirrored_light.max(1) > 0
        mirrored = (gb.throughput != 1.0).any(1)
    base = np.where(gb.hit, np.where(gb.holdout, 1, 2), 0)
    return (base + 3 * bright + 6 * mirrored).astype(np.int8)


def edge_pixels(gb, uniform):
    """bool (pixels,): pixels an edge may cross, where coverage rays are traced: their
    shading samples differ (in class, object or surface: `uniform`, uniform_pixels),
    or the first one differs from a neighbour's first (8 neighbours: an edge that misses
    every shading sample of a pixel shows between the pixel and the one across it)."""
    count = gb.width * gb.height
    kind = surface_class(gb).reshape(gb.samples, count)
    obj = gb.object_index.reshape(gb.samples, count)
    surface = (kind % 3) == 2
    edge = ((kind != kind[0]) | (obj != obj[0])).any(0)
    edge |= surface[0] & ~uniform
    for a, b in neighbour_pairs(gb.width, gb.height):
        differ = (kind[0, a] != kind[0, b]) | (obj[0, a] != obj[0, b])
        both = np.flatnonzero(~differ & surface[0, a])
        differ[both] = ~same_surface(gb, a[both], gb, b[both])
        edge[a[differ]] = True
        edge[b[differ]] = True
    return edge


def neighbour_pairs(width, height):
    """[(a, b)] per NEIGHBOUR_PAIRS: the pixel indices of every pair of 8-neighbours."""
    y, x = np.divmod(np.arange(width * height), width)
    pairs = []
    for dy, dx in NEIGHBOUR_PAIRS:
        a = np.flatnonzero((y + dy < height) & (x + dx >= 0) & (x + dx < width))
        pairs.append((a, a + dy * width + dx))
    return pairs


class HardShadowEdges:
    """Finds the pixels a hard shadow edge crosses, emitter by emitter, as
    direct_light.direct_irradiance computes them (its `shadow_edges`), in memory O(pixels):
    per pixel the largest irradiance an emitter gives a fully lit sample with a fully
    shadowed one in the same or a neighbouring pixel (`contrast`), compared with the
    pixel's total when all emitters are done (pixels)."""

    def __init__(self, gb, edges):
        self.gb = gb
        self.contrast = np.zeros(gb.width * gb.height)
        # Only where every neighbour's first sample lies on the same surface (edges: the
        # film's surface_edges): across a geometric edge the coverage rays and the
        # CoverageMap already part the sides, and a sample right in a concave corner
        # may find its shadow ray blocked by the other face.
        self.interior = ~edges[1]
        self.pairs = []
        for a, b in neighbour_pairs(gb.width, gb.height):
            keep = np.flatnonzero(self.interior[a] & self.interior[b])
            self.pairs.append((a[keep], b[keep]))

    def looks_at(self, emitter):
        """Whether the emitter may cast hard shadows here (SOFT_LIGHT_ANGLE): delta
        lights and emitters that do not tell their angular size always may."""
        if emitter.delta or not hasattr(emitter, "angular_diameter"):
            return True
        seen = self.gb.position[self.gb.hit][::16]   # a median needs few samples
        return len(seen) == 0 or emitter.angular_diameter(seen) < SOFT_LIGHT_ANGLE

    def add(self, idx, tally, E):
        """One emitter's shadow segments: tally (len(idx), 2) counts, per sample of idx,
        its segments and the unoccluded ones; E (len(idx), 3) its irradiance there."""
        gb, count = self.gb, self.gb.width * self.gb.height
        segments, passed = tally[:, 0], tally[:, 1]
        state = np.zeros(len(gb.hit), np.int8)    # +1 fully lit, -1 fully shadowed
        state[idx] = np.where(segments == 0, 0, np.where(passed == segments, 1,
                                                          np.where(passed == 0, -1, 0)))
        strength = np.zeros(len(gb.hit))
        strength[idx] = E.mean(1)
        state = state.reshape(gb.samples, count)
        lit_any = (state == 1).any(0) & self.interior
        dark_any = (state == -1).any(0) & self.interior
        strength = np.where(state == 1, strength.reshape(gb.samples, count), 0.0).max(0)
        both = np.flatnonzero(lit_any & dark_any)
        self._raise(both, strength[both])
        for a, b in self.pairs:
            across = (lit_any[a] & dark_any[b]) | (dark_any[a] & lit_any[b])
            a, b = a[across], b[across]
            value = np.maximum(strength[a], strength[b])
            self._raise(a, value)
            self._raise(b, value)

    def _raise(self, pixels, value):
        """contrast[pixels] = max(contrast[pixels], value) (each pixel listed once)."""
        self.contrast[pixels] = np.maximum(self.contrast[pixels], value)

    def pixels(self, E):
        """bool (pixels,): where an edge's contrast is at least HARD_EDGE_SHARE of the
        pixel's mean direct irradiance E (S, 3)."""
        total = E.mean(1).reshape(self.gb.samples, -1).mean(0)
        return (self.contrast > 0) & (self.contrast >= HARD_EDGE_SHARE * total)


def surface_edges(gb):
    """(uniform_pixels, edge_pixels) of the shading samples gb."""
    uniform = uniform_pixels(gb)
    return uniform, edge_pixels(gb, uniform)


def film_gbuffer(frame, cam, gb, samples, rng, rows, shadow_edges=None, edges=None):
    """The samples the image is averaged from, and the CoverageMap that carries the
    shading samples' irradiance to them: `samples` coverage rays in each edge pixel,
    SHADOW_EDGE_RAYS times as many in the pixels `shadow_edges` (bool,
    HardShadowEdges.pixels), the shading
    samples themselves in every other pixel (most of them: one surface, nothing to
    resolve). Coverage samples have smooth normals: on shadow edges they gather light.
    edges: gb's surface_edges if already known."""
    uniform, edge = edges if edges is not None else surface_edges(gb)
    shadow = shadow_edges if shadow_edges is not None else np.zeros_like(edge)
    own = np.flatnonzero(~(edge | shadow)[gb.pixel])
    traced = [build_gbuffer(frame, cam, samples, rng, rows,
                            pixels=np.flatnonzero(edge & ~shadow)),
              build_gbuffer(frame, cam, SHADOW_EDGE_RAYS * samples, rng, rows,
                            pixels=np.flatnonzero(shadow))]
    joined = {}
    for name, a in sample_arrays(gb).items():
        # The shading samples kept go straight into the joined array: one copy.
        tail = [getattr(part, name) for part in traced]
        out = np.empty((len(own) + sum(len(t) for t in tail),) + a.shape[1:], a.dtype)
        np.take(a, own, axis=0, out=out[:len(own)])
        out[len(own):] = np.concatenate(tail)
        joined[name] = out
    film = GBuffer(gb.width, gb.height, gb.row_start, samples, **joined)
    film.counts = np.bincount(film.pixel, minlength=gb.width * gb.height)
    return film, coverage_map(film, gb, own, uniform)


def shadow_edge_samples(film, coverage, shadow_edges):
    """Indices of the film's coverage samples in the pixels `shadow_edges`."""
    first = len(coverage.own)
    return first + np.flatnonzero(shadow_edges[film.pixel[first:]])


def sample_arrays(gb):
    """{name: array} of the G-buffer's per-sample arrays (not the per-pixel counts,
    not the mirror arrays of a scene without mirrors)."""
    return {f.name: getattr(gb, f.name) for f in fields(GBuffer)
            if isinstance(getattr(gb, f.name), np.ndarray) and f.name != "counts"}


def take_samples(gb, index):
    """The G-buffer of samples `index` of gb (per-sample arrays only, for a gather)."""
    arrays = {name: a[index] for name, a in sample_arrays(gb).items()}
    return GBuffer(gb.width, gb.height, gb.row_start, gb.samples, **arrays)


@dataclass
class CoverageMap:
    """Where each film sample takes its irradiance from: the shading sample itself for
    `own`, the pixel mean for `quick` (pixels on one surface), else weights over
    candidates per stage. It depends on the G-buffers only, so a still camera keeps
    it across frames."""
    count: int            # film samples
    samples: int          # shading samples per pixel
    own: np.ndarray       # the shading samples that are film samples 0 .. len(own) - 1
    quick: np.ndarray     # film samples that take their pixel's mean
    quick_pixel: np.ndarray
    stages: list          # [(film samples, candidates (n, K), weights (n, K))]

    def carry(self, E):
        """(S, 3) shading-sample irradiance -> (film samples, 3)."""
        out = np.zeros((self.count, 3))
        out[:len(self.own)] = E[self.own]
        pixel_mean = E.reshape(self.samples, -1, 3).mean(0)
        out[self.quick] = pixel_mean[self.quick_pixel]
        for todo, candidates, weights in self.stages:
            out[todo] = np.einsum('nk,nkc->nc', weights, E[candidates])
        return out


def coverage_map(cov, gb, own, uniform):
    """The CoverageMap of samples `cov` over the shading samples `gb` (`uniform`: its
    uniform_pixels), the first of them the shading samples `own` (a film_gbuffer).
    The others take the mean over the shading samples on the same surface in their own
    pixel, else in the neighbouring pixels; a sub-pixel sliver no shading sample lies
    on takes the nearest one facing the same way; misses and holdouts get zero."""
    todo = len(own) + np.flatnonzero((cov.hit & ~cov.holdout)[len(own):])
    # Fast path: a pixel whose shading samples share one surface, and coverage samples
    # on that surface (the first shading sample stands for it).
    pixel = cov.pixel[todo]
    quick = uniform[pixel]
    quick[quick] = same_surface(cov, todo[quick], gb, pixel[quick])
    result = CoverageMap(len(cov.hit), gb.samples, own, todo[quick], pixel[quick], [])
    todo = todo[~quick]
    all_pixels = [(0, 0)] + NEIGHBOURS
    for offsets, strict in (([(0, 0)], True), (NEIGHBOURS, True), (all_pixels, False)):
        if len(todo) == 0:
            break
        candidates, weights = surface_weights(cov, gb, todo, offsets, strict)
        result.stages.append((todo, np.maximum(candidates, 0), weights))
        todo = todo[weights.sum(1) == 0]
    return result

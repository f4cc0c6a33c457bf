"""Guided emission for the sun: where its particles enter what the camera sees.

A sun's particles start on a disc that covers the whole scene (lights.SunEmitter.emit),
so in a room lit through a window most of them land on the roof and the outer walls:
in the sun-lit room of the benchmarks 4% enter, and its few VPLs inside make the image
noisy. Cycles' light portals say where light enters (portals.Portals); without them a
pilot finds it. Pilot particles cover the disc; one is useful when its first hit sees
a point the camera sees (shadow rays to a few camera pilot points). The disc is then
sampled from a piecewise-constant density over its square of primary samples: high in
the cells whose pilots were useful, with a defensive share everywhere (Hesterberg 1995),
each particle's flux divided by its density. That is unbiased whatever the pilot found
(its random numbers are its own): a spatial histogram as in path guiding (Vorba et al.
2014), over the light's primary sample space.
"""
import copy
from dataclasses import dataclass, replace

import numpy as np

from . import geometry, sampling
from .lights import SunEmitter
from .variant_choice import camera_pilot

# Cells per side of the disc's square of primary samples, and pilot particles per cell.
CELLS = 32
PILOTS_PER_CELL = 4
# Camera pilot points, and shadow rays from each pilot particle's first hit to them.
CAMERA_POINTS = 256
TRIES = 4
# A cell next to useful ones gets at least this share of their density: a window's
# edge cell whose few pilots all missed the opening still gets particles.
NEIGHBOUR_SHARE = 0.5
# Share of particles spread uniformly whatever the pilot found.
DEFENSIVE = 0.1


@dataclass
class EmissionGuide:
    """Piecewise-constant density over [0,1)^2 in cells x cells cells (mean 1), drawn
    by inverting its marginal in v, then its conditional in u (Pharr et al., pbrt-v4,
    PiecewiseConstant2D): nearby primary samples stay nearby, so the Halton points keep
    their stratification within the cells."""
    density: np.ndarray           # (cells_v, cells_u)

    def __post_init__(self):
        rows = self.density.sum(1)
        self.marginal = _cdf(rows)
        self.conditional = np.array([_cdf(r) for r in self.density])

    def warp(self, u):
        """(n, 2) primary samples -> (warped samples (n, 2), their density (n,))."""
        cells_v, cells_u = self.density.shape
        row, v = _invert(self.marginal, u[:, 1])
        col, s = _invert(self.conditional[row], u[:, 0])
        warped = np.stack([(col + s) / cells_u, (row + v) / cells_v], -1)
        return np.minimum(warped, 1.0 - 2.0 ** -53), self.density[row, col]


def _cdf(weights):
    total = weights.sum()
    cdf = np.concatenate([[0.0], np.cumsum(weights)]) / (total if total > 0 else 1.0)
    cdf[-1] = 1.0
    return cdf


def _invert(cdf, u):
    """Cell (n,) and position within it [0, 1) of u under the piecewise-constant cdf
    (one cdf, or one per sample); empty cells are never chosen."""
    cdf = np.broadcast_to(cdf, (len(u), cdf.shape[-1])) if cdf.ndim == 1 else cdf
    cell = (cdf[:, 1:] <= u[:, None]).sum(1)
    cell = np.minimum(cell, cdf.shape[1] - 2)
    lo, hi = cdf[np.arange(len(u)), cell], cdf[np.arange(len(u)), cell + 1]
    return cell, np.clip((u - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)


def guide_from_pilot(u, useful, cells=CELLS):
    """The EmissionGuide of pilot samples u (n, 2) and whether each was useful, or None
    when none was: density in proportion to each cell's useful share, widened by one
    cell (NEIGHBOUR_SHARE), plus DEFENSIVE."""
    cell = np.minimum((u * cells).astype(np.int64), cells - 1)
    flat = cell[:, 1] * cells + cell[:, 0]
    total = np.bincount(flat, minlength=cells * cells)
    share = np.bincount(flat, useful.astype(np.float64), cells * cells) / np.maximum(total, 1)
    share = share.reshape(cells, cells)
    if share.max() <= 0:
        return None
    padded = np.pad(share, 1)
    around = np.max([padded[1 + dy:1 + dy + cells, 1 + dx:1 + dx + cells]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    widened = np.maximum(share, NEIGHBOUR_SHARE * around)
    density = (1 - DEFENSIVE) * widened / widened.mean() + DEFENSIVE
    return EmissionGuide(density)


def sees_camera(frame, pilot, position, normal, geo_normal, rng, tries=TRIES):
    """bool (n,): whether each surface point (normals on its lit side) sees at least one
    of `tries` random camera pilot points, both facing each other and unoccluded."""
    n = len(position)
    if pilot.count == 0 or n == 0:
        return np.zeros(n, bool)
    target = rng.integers(0, pilot.count, (n, tries)).ravel()
    point = np.repeat(np.arange(n), tries)
    d = pilot.position[target] - position[point]
    facing = (np.einsum('ij,ij->i', d, normal[point]) > 0) & \
             (np.einsum('ij,ij->i', d, pilot.normal[target]) < 0)
    rows = np.flatnonzero(facing)
    eps = frame.offset()
    origin = position[point[rows]] + geo_normal[point[rows]] * eps
    segment = pilot.position[target[rows]] + pilot.geo_normal[target[rows]] * eps - origin
    seen = np.zeros(n * tries, bool)
    seen[rows] = ~frame.tracer.occluded(origin, segment, 1.0 - 1e-4)
    return seen.reshape(n, tries).any(1)


def sun_guide(frame, emitter, pilot, seed):
    """The EmissionGuide of a SunEmitter without portals for this camera pilot, or None
    when no pilot particle was useful."""
    count = CELLS * CELLS * PILOTS_PER_CELL
    u = sampling.halton(count, 6, seed=seed + 0x5A7, start=1)
    origin, travel, _ = emitter.emit(u)
    hits = frame.tracer.intersect(origin, travel)
    useful = np.zeros(count, bool)
    index = np.flatnonzero(hits.hit)
    position, geo, shading, _, _ = geometry.surface_hits(
        frame, hits.triangle[index], hits.barycentric[index], travel[index])
    rng = np.random.default_rng([seed, 0x5A7])
    useful[index] = sees_camera(frame, pilot, position, shading, geo, rng)
    return guide_from_pilot(u[:, 0:2], useful)


def guidable(frame):
    """The sun emitters that start their particles around the whole scene."""
    return [e for e in frame.emitters if isinstance(e, SunEmitter) and e.portals is None]


def guided_frame(frame, gb, seed):
    """`frame` with each sun that has no portals guided toward what the pilot G-buffer
    `gb` sees (the other emitters unchanged)."""
    suns = guidable(frame)
    if not suns:
        return frame
    pilot = camera_pilot(gb, CAMERA_POINTS, np.random.default_rng([seed, 0xCA]))
    emitters = []
    for emitter in frame.emitters:
        if emitter in suns:
            guide = sun_guide(frame, emitter, pilot, seed)
            if guide is not None:
                emitter = copy.copy(emitter)
                emitter.guide = guide
        emitters.append(emitter)
    return replace(frame, emitters=emitters)

"""Direct light at G-buffer samples: shadow rays to samples of every emitter, and for
rectangular area lights their closed-form unoccluded irradiance scaled by the share of
the samples' light that gets through."""
import threading

import numpy as np

from . import light_sampling, rays, sampling


def light_sample_pattern(count, gb, idx, rng):
    """(count, len(idx), 2) light samples for the points idx of gb. Camera samples of
    one pixel share one scrambled (0,2)-sequence (sampling.scrambled_02), sample s
    taking its points s * count .. (s + 1) * count - 1: each sample's `count` are
    stratified, and so are the pixel's samples * count together (the area-lit Cornell
    box: direct light's variance 9.3e-4 -> 7.3e-4 against a pattern per sample). Points
    without pixels (compensation hits) get a Hammersley set, toroidally shifted per
    point (Cranley-Patterson)."""
    if getattr(gb, "sample", None) is None:
        return light_sampling.shifted_pattern(sampling.hammersley(count, 2),
                                              rng.random((len(idx), 2)))
    scramble = rng.integers(0, 1 << 32, (gb.width * gb.height, 2), dtype=np.uint32)
    return sampling.scrambled_02(gb.sample[idx] * count, count, scramble[gb.pixel[idx]])


# Points per task of direct_irradiance: each thread writes its tasks' shadow segments
# (~60 bytes per light sample) into one buffer of its own, reused task after task.
POINTS_PER_TASK = 1 << 13


def direct_irradiance(frame, gb, light_samples, rng, cancel=None, visible=None,
                      shadow_edges=None):
    """Irradiance (S, 3) from every emitter, with shadow rays. `visible(origins,
    directions, tfar)` (world frame) replaces the plain shadow-ray test (mirrors.py
    uses it). shadow_edges: an antialiasing.HardShadowEdges shown each emitter's
    shadow rays. Tasks of points run here and on a worker that is free meanwhile
    (rays.shared_map); the image does not depend on which thread ran what."""
    E = np.zeros((len(gb.hit), 3))
    idx = np.flatnonzero(gb.hit)
    if len(idx) == 0 or not frame.emitters:
        return E
    P, N, G = (np.ascontiguousarray(a, np.float64)
               for a in (gb.position[idx], gb.normal[idx], gb.geo_normal[idx]))
    eps, centre = frame.offset(), frame.tracer.center
    most = max(1 if emitter.delta else light_samples for emitter in frame.emitters)
    rows = most * min(len(idx), POINTS_PER_TASK)
    buffers = {}   # thread -> its light_sampling.ShadowSegments
    parts = [slice(first, first + POINTS_PER_TASK)
             for first in range(0, len(idx), POINTS_PER_TASK)]
    for emitter in frame.emitters:
        if cancel and cancel():
            return E
        count = 1 if emitter.delta else light_samples
        pattern = light_sample_pattern(count, gb, idx, rng)
        seen, sampled = np.zeros((len(idx), 3)), np.zeros(len(idx))
        tally = np.zeros((len(idx), 2), np.int64)   # per point: segments, unoccluded ones

        def light_task(task):
            part = parts[task]
            thread = threading.get_ident()
            if thread not in buffers:
                buffers[thread] = light_sampling.ShadowSegments(rows)
            segments = buffers[thread]
            n = emitter_segments(emitter, P[part], N[part], G[part], pattern[:, part], eps,
                                 centre, segments)
            origin, segment, tfar, point, energy = (a[:n] for a in segments.arrays)
            lit = (~frame.tracer.occluded(origin, segment, tfar, local=True)
                   if visible is None else visible(origin + centre, segment, tfar))
            light_sampling.light_sums(point, energy, lit, seen[part], sampled[part],
                                      tally[part])
        rays.shared_map(light_task, len(parts))
        unoccluded = (emitter.unoccluded_irradiance(P, N, G) if visible is None
                      and hasattr(emitter, "unoccluded_irradiance") else None)
        E_emitter = (seen / count if unoccluded is None
                     else _visible_share(unoccluded, seen, sampled, count))
        E[idx] += E_emitter
        if shadow_edges is not None and shadow_edges.looks_at(emitter):
            shadow_edges.add(idx, tally, E_emitter)
    return E


def emitter_segments(emitter, P, N, G, pattern, eps, centre, segments):
    """The shadow segments of light samples `pattern` (count, n, 2) of the emitter at
    points P, into `segments` (light_sampling.ShadowSegments); returns their number."""
    if hasattr(emitter, "shadow_segments"):   # a compiled pass for the whole pattern
        return emitter.shadow_segments(P, N, G, pattern, eps, centre, segments)
    rows = 0
    for u in pattern:
        direction, dist, e = emitter.incident(P, N, u)
        rows = light_sampling.shadow_segments(P, G, direction, dist, e, eps, centre,
                                              segments, rows)
    return rows


def _visible_share(unoccluded, seen, sampled, count):
    """Direct light as the closed-form unoccluded irradiance times the share of the
    light samples' energy that reaches the point (the ratio estimator of Heitz et al.
    2018, "Combining analytic direct illumination and stochastic shadows", eq. 5):
    exact wherever the light is wholly seen or wholly hidden, so noise is left only in
    penumbrae; consistent, its bias O(1/light samples) where the samples' energies
    and visibility correlate. seen, sampled: light_sampling.light_sums of `count`
    samples per point; where no sample brought energy, the plain estimate."""
    out = seen / count
    some = sampled > 0
    out[some] = unoccluded[some] * (seen[some].sum(1) / sampled[some])[:, None]
    return out

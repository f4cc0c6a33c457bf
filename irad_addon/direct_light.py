"""Direct light at G-buffer samples: shadow rays to samples of every emitter, and for
rectangular area lights their closed-form unoccluded irradiance scaled by the share of
the samples' light that gets through."""
import numpy as np

from . import light_sampling, sampling


def light_sample_pattern(count, points, rng):
    """`count` 2D samples per point: a Hammersley set, toroidally shifted per point
    (Cranley-Patterson), so every point gets a stratified but different pattern."""
    return light_sampling.shifted_pattern(sampling.hammersley(count, 2),
                                          rng.random((points, 2)))


def direct_irradiance(frame, gb, light_samples, rng, cancel=None, visible=None,
                      shadow_edges=None):
    """Irradiance (S, 3) from every emitter, with shadow rays. `visible(origins,
    directions, tfar)` replaces the plain shadow-ray test (mirrors.py uses it).
    shadow_edges: an antialiasing.HardShadowEdges shown each emitter's shadow rays."""
    E = np.zeros((len(gb.hit), 3))
    idx = np.flatnonzero(gb.hit)
    if len(idx) == 0:
        return E
    P, N, G = (np.ascontiguousarray(a, np.float64)
               for a in (gb.position[idx], gb.normal[idx], gb.geo_normal[idx]))
    eps = frame.offset()
    own_shadow_rays = visible is None
    if visible is None:
        visible = lambda o, d, t: ~frame.tracer.occluded(o, d, t)
    for emitter in frame.emitters:
        if cancel and cancel():
            return E
        # Every light sample's segment first, then one shadow-ray batch per emitter.
        count = 1 if emitter.delta else light_samples
        rows = count * len(idx)
        origin, segment, tfar = np.empty((rows, 3)), np.empty((rows, 3)), np.empty(rows)
        point, energy = np.empty(rows, np.int64), np.empty((rows, 3))
        pattern = light_sample_pattern(count, len(idx), rng)
        if hasattr(emitter, "shadow_segments"):   # a compiled pass for the whole pattern
            rows = emitter.shadow_segments(P, N, G, pattern, eps, origin, segment, tfar, point,
                                           energy)
        else:
            rows = 0
            for u in pattern:
                direction, dist, e = emitter.incident(P, N, u)
                start = rows
                rows = light_sampling.shadow_segments(P, G, direction, dist, e, eps, origin,
                                                      segment, tfar, point, start)
                energy[start:rows] = e[point[start:rows]]
        lit = visible(origin[:rows], segment[:rows], tfar[:rows])
        seen, sampled = light_sampling.light_sums(point[:rows], energy[:rows], lit, len(idx))
        unoccluded = (emitter.unoccluded_irradiance(P, N, G) if own_shadow_rays
                      and hasattr(emitter, "unoccluded_irradiance") else None)
        E_emitter = (seen / count if unoccluded is None
                     else _visible_share(unoccluded, seen, sampled, count))
        E[idx] += E_emitter
        if shadow_edges is not None and shadow_edges.looks_at(emitter):
            shadow_edges.add(idx, point[:rows], lit, E_emitter)
    return E


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

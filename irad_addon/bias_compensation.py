"""Bias compensation for VPL clamping (Kollig & Keller 2004, "Illumination in the
presence of weak singularities").

Clamping replaces the geometry term G by G min(1, d^2 / b^2) for VPLs closer than b.
The energy it removes is, in solid angle about a receiver x,
    integral of f_x L_o(y) cos_x max(0, 1 - d^2 / b^2) dw,
which a cosine-distributed ray from the receiver estimates as
    rho_x L_o(y) max(0, 1 - d^2 / b^2),
where y is the ray's hit within distance b and L_o(y) the light y reflects, itself
computed with the (clamped) VPLs and the direct light. Only rays that hit within b
cost anything more than the ray itself: compensation is cheap away from corners.
"""
import numpy as np

from . import direct_light, gather, sampling
from .gbuffer import take_points, trace_surfaces

# Compensation rays per pixel: at clamp 3 much of a corner's light is
# the compensation's; 2 rays have ~5% less relMSE than 1 on the Cornell box at no wall
# time (they run beside the gather, render.start_compensation); 4 take 3% more off
# for ~4 ms.
RAYS_PER_PIXEL = 2
# The light leaving a ray's hit is a small part of the pixel's: it takes a quarter of
# the light samples, and gathers a quarter of the pixel's interleaved VPL group (one of
# HIT_GROUP_SPLIT parts at random, scaled up; the filter's window sees every part).
# Area-lit Cornell box at one shading sample: the same relMSE for 8-14% less time.
HIT_LIGHT_SHARE = 0.25
HIT_GROUP_SPLIT = 4


def clamp_residual_irradiance(frame, gb, vpls, clamp_distance, subset_of_sample, subsets,
                              light_samples, rng, cancel=None, shadow_ray_budget=0.0, seed=0):
    """Irradiance (S, 3) that, added to the clamped VPL irradiance, restores the
    energy clamping removed (one bounce of it; deeper bounces are left clamped).
    shadow_ray_budget, seed: the VPL gather's at the rays' hits (its shadow-ray
    roulette, gather.indirect_irradiance)."""
    E = np.zeros((len(gb.hit), 3))
    if clamp_distance <= 0 or vpls.count == 0:
        return E
    # RAYS_PER_PIXEL compensation rays per pixel, from its first shading samples (each
    # shooting several when the pixel has fewer), weighted by the samples per pixel
    # over the rays: unbiased, and the discontinuity buffer spreads them.
    shooters = min(RAYS_PER_PIXEL, gb.samples)
    repeats = max(1, RAYS_PER_PIXEL // shooters)
    rays_per_pixel = shooters * repeats
    idx = np.repeat(np.flatnonzero(gb.hit & (gb.sample < shooters)), repeats)
    direction = sampling.to_world(sampling.square_to_cosine_hemisphere(rng.random((len(idx), 2))),
                                  gb.normal[idx])
    above = np.einsum('ij,ij->i', direction, gb.geo_normal[idx]) > 0
    idx, direction = idx[above], direction[above]
    origin = gb.position[idx] + gb.geo_normal[idx] * frame.offset()
    nearby = trace_surfaces(frame, origin, direction, np.full(len(idx), clamp_distance))
    near = np.flatnonzero(nearby.hit)
    if len(near) == 0:
        return E
    y = take_points(nearby, near)
    weight = np.maximum(0.0, 1.0 - (y.distance.astype(np.float64) / clamp_distance) ** 2)
    # Light leaving y: reflected direct and VPL light (its emission is direct light at x).
    # Group g of the pixel's `subsets` holds the VPLs g + subsets r of subsets * split.
    # Without interleaving every gather sees every VPL, as the user asked.
    split = HIT_GROUP_SPLIT if subsets > 1 else 1
    part = subset_of_sample[idx[near]] + subsets * rng.integers(split, size=len(near))
    E_y = (direct_light.direct_irradiance(frame, y, max(1, int(light_samples * HIT_LIGHT_SHARE)),
                                          rng, cancel)
           + gather.indirect_irradiance(frame, y, vpls, clamp_distance, part, subsets * split,
                                        cancel, shadow_ray_budget=shadow_ray_budget, seed=seed))
    radiance_y = y.albedo / np.pi * E_y
    np.add.at(E, idx[near], gb.samples / rays_per_pixel * np.pi * radiance_y * weight[:, None])
    return E

"""The camera pilot (a few hundred G-buffer samples standing for what the camera sees)
and the automatic choice of a VPL placement variant from a cheap pilot pass.

The pilot is shared by the camera-aware variants: bidirectional IR weighs and resamples
VPL candidates by the power they bring to it (Segovia et al. 2006, sec. 4), Metropolis
IR uses it as the target function of its chain (Segovia et al. 2007, sec. 3).
"""
from dataclasses import dataclass

import numpy as np

from . import vpl

# Pair budget per block of the pilot x points matrix (float64 temporaries).
_PAIRS_PER_BLOCK = 1 << 19
# Auto: below this share of light-path VPL power seen by the camera, classic IR wastes
# most of its VPLs; below the second, even reverse paths get noisy incident light.
REACH_CLASSIC = 0.33
REACH_METROPOLIS = 0.02
PILOT_PARTICLES = 512
PILOT_CAMERA_POINTS = 128


@dataclass
class CameraPilot:
    position: np.ndarray     # (K, 3) camera-visible points
    normal: np.ndarray       # (K, 3) shading normals, facing the camera
    geo_normal: np.ndarray   # (K, 3)
    albedo: np.ndarray       # (K, 3)
    share: float             # fraction of all camera samples that hit visible geometry

    @property
    def count(self):
        return len(self.position)


def camera_pilot(gb, count, rng):
    """`count` camera samples drawn uniformly among those that see (non-holdout) geometry."""
    idx = np.flatnonzero(gb.hit & ~gb.holdout)
    if len(idx) > count:
        idx = np.sort(rng.choice(idx, count, replace=False))
    share = float(len(np.flatnonzero(gb.hit & ~gb.holdout))) / max(len(gb.hit), 1)
    return CameraPilot(gb.position[idx], gb.normal[idx], gb.geo_normal[idx], gb.albedo[idx],
                       share)


def luminance(rgb):
    return np.asarray(rgb, np.float64).mean(-1)


def pair_transfer(frame, pilot, points, normals, min_distance2=0.0):
    """(K, C) matrix cos_x cos_y / max(d^2, dmin^2) * V(x, y) between the pilot points x
    and surface points y whose `normals` face their lit side (the geometry term of
    Keller 1997, eq. 5, as gather.vpl_irradiance_chunk weighs a VPL)."""
    K, C = pilot.count, len(points)
    out = np.zeros((K, C))
    if K == 0 or C == 0:
        return out
    eps = frame.offset()
    step = max(1, _PAIRS_PER_BLOCK // K)
    for a in range(0, C, step):
        out[:, a:a + step] = _transfer_block(frame, pilot, points[a:a + step],
                                             normals[a:a + step], min_distance2, eps)
    return out


def _transfer_block(frame, pilot, points, normals, min_distance2, eps):
    # Every dot product with d = y - x as a matrix product (n.d = n.y - n.x), relative
    # to the block's centre: no (K, C, 3) arrays (as gather.vpl_irradiance_chunk).
    centre = points.mean(0)
    X, Y = pilot.position - centre, points - centre
    cross = X @ Y.T
    dist2 = np.maximum(np.einsum('ij,ij->i', X, X)[:, None]
                       + np.einsum('ij,ij->i', Y, Y)[None, :] - 2 * cross, 1e-30)
    inv = 1.0 / np.sqrt(dist2)
    cos_x = (pilot.normal @ Y.T - np.einsum('ij,ij->i', pilot.normal, X)[:, None]) * inv
    cos_y = (X @ normals.T - np.einsum('ij,ij->i', normals, Y)[None, :]) * inv
    above = pilot.geo_normal @ Y.T - np.einsum('ij,ij->i', pilot.geo_normal, X)[:, None]
    valid = (cos_x > 0) & (cos_y > 0) & (above > 0)
    weight = np.where(valid, cos_x * cos_y / np.maximum(dist2, min_distance2), 0.0)
    pairs = np.flatnonzero(valid)
    if len(pairs):
        # Pairs run row by row (pilot point k): repeat each ray origin, in the tracer's
        # float32 frame, instead of gathering it per pair.
        tracer = frame.tracer
        origin = np.repeat(tracer.to_local(pilot.position + pilot.geo_normal * eps),
                           valid.sum(1), axis=0)
        direction = np.take(tracer.to_local(points), pairs % len(points), axis=0)
        direction -= origin
        tfar = ((1 - 1e-5) - 2 * eps * inv.ravel()[pairs]
                / np.maximum(cos_y.ravel()[pairs], 1e-2)).astype(np.float32)
        blocked = tracer.occluded(origin, direction, tfar, local=True)
        weight.ravel()[pairs[blocked]] = 0.0
    return weight


def camera_importance(pilot, transfer, flux):
    """Luminance each VPL (flux (C, 3)) sends to the pilot points as reflected radiance:
    sum_x rho(x)/pi * flux/pi * G(x, y) V (the VPL's power 'brought to the camera')."""
    return (luminance(pilot.albedo) @ transfer) * luminance(flux) / np.pi ** 2


def light_reach(frame, gb, max_bounces, seed, rng):
    """Mean over pilot camera points of the share of light-path VPL power each one sees:
    near 1 when light paths land in view, near 0 when most never reach it."""
    pilot = camera_pilot(gb, PILOT_CAMERA_POINTS, rng)
    light = vpl.trace_vpls(frame, PILOT_PARTICLES, max_bounces, seed=seed + 7919)
    power = luminance(light.flux)
    if pilot.count == 0 or power.sum() <= 0:
        return 0.0, light.count
    seen = pair_transfer(frame, pilot, light.position, light.normal) > 0
    return float((seen @ power).mean() / power.sum()), light.count


def choose_variant(frame, gb, settings, animated, rng):
    """Auto (issue 5): (variant, reason). Skip what the scene does not need: classic
    where light paths already land in view, reverse paths where they mostly do not, a
    Metropolis chain only where even those would starve; incremental for animations
    whose geometry stays and whose lights move."""
    if animated:
        return 'INCREMENTAL', ("Incremental: the geometry is unchanged since the last "
                               "frame and the lights moved, so most VPLs stay valid")
    if settings.max_bounces < 1 or not frame.emitters:
        return 'CLASSIC', "Classic: no indirect light to place"
    reach, count = light_reach(frame, gb, settings.max_bounces, settings.seed, rng)
    pct = f"{100 * reach:.1f}% of the power of {count} pilot VPLs"
    if reach >= REACH_CLASSIC:
        return 'CLASSIC', f"Classic: {pct} reaches what the camera sees"
    if reach >= REACH_METROPOLIS:
        return 'BIDIRECTIONAL', (f"Bidirectional: only {pct} reaches what the camera sees; "
                                 "reverse paths from the camera place the VPLs")
    return 'METROPOLIS', (f"Metropolis: only {pct} reaches what the camera sees; a "
                          "Markov chain searches for the rare paths that do")

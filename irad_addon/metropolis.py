"""Metropolis Instant Radiosity (Segovia, Iehl, Peroche 2007).

A state is a light path in primary sample space: u in [0,1)^D picks the emitter, the
particle's start and every bounce. Its k-th VPL has f(u, k) = the power it brings to
the camera pilot points, each weighted by the share of its radiance that is indirect
(relative_pilot), plus a small share of its own power (so that no VPL that lights the
image has f = 0); the path has f(u) = sum_k f(u, k). Parallel Metropolis-Hastings
chains (or multiple-try ones, Liu, Liang & Wong 2000: TRIES) draw paths with density
f(u) / b, b = P_c estimated first from uniformly sampled (bootstrap) paths; the chains
start from seeds resampled from that set in proportion to f, so they start near
equilibrium. The n VPLs are drawn from a pool of the chain states' VPLs, the k-th of a
state weighted f(u, k) / f(u) (no budget goes to the VPLs the camera never sees), mixed
with the bootstrap paths' VPLs weighted f(u, k) / (N b); each of the n re-emits
Phi_k b / (n f(u, k)), i.e. P_c / (n P') as in Segovia 2007 sec. 3.2.
"""
from dataclasses import replace

import numpy as np

from . import direct_light, sampling, vpl
from .light_tree import morton_codes
from .variant_choice import camera_importance, camera_pilot, luminance, pair_transfer

# Measured on two rooms (tests/test_variants.py, 128 particles), mean relMSE over seeds
# 1-3: 64 -> 256 pilot points 0.049 -> 0.039; 8 -> 2-4 steps per chain 0.049 -> 0.033
# (fresh seeds beat long correlated chains); 1024 -> 4096 bootstrap paths: b's std
# 8% -> 4%; 3 tries (the multiple-try default) or 1 try with 3x the states: relMSE
# 0.031 vs 0.029 (seeds 1-3), equal on seeds 4-6, ~20% more time.
PILOT_CAMERA_POINTS = 256
TRIES = 3                 # multiple-try Metropolis (the default); 1 = plain Metropolis-Hastings
LARGE_STEP = 0.5          # probability of an independent (uniform) proposal
SMALL_STEP = 0.02         # std. dev. of the wrapped Gaussian perturbation
STEPS_PER_CHAIN = 4
THINNING = 1              # chain states recorded per VPL kept (PathStore.vpls)
# Share of the VPL pool drawn from the chain states; the rest comes from the bootstrap
# paths, already traced and weighted (PathStore.pool_weights). Two rooms, 128 particles,
# mean relMSE over seeds 1-48: chains only 0.0345 (worst 0.0498), 0.5 -> 0.0316, 0.25 ->
# 0.0302 (worst 0.0473). THINNING 2 (more states, curve-subsampled): 0.0323, +40% time.
CHAIN_SHARE = 0.25
DEFENSIVE = 0.05          # share of f given by the path's own power
# f clamps distances at this many mean VPL spacings: a smooth target whose ratio to
# the VPL's true contribution to any pixel stays bounded.
TARGET_CLAMP = 1.2
# Uniform bootstrap paths: per path of the budget, and at least BOOTSTRAP_MIN, since
# b's error (which scales the whole image) depends on their number, not on the budget.
BOOTSTRAP = 8
BOOTSTRAP_MIN = 4096
SCOUT = 512               # uniform paths that estimate the pilot's mean indirect radiance
SCOUT_LIGHT_SAMPLES = 16  # light samples per pilot point for its direct radiance
_EMIT_DIMS = 6
_BOUNCE_DIMS = 3


class PathSpace:
    """The map from primary samples u (n, D) to VPLs, and the target function f."""

    def __init__(self, frame, pilot, max_bounces, cap):
        self.frame, self.pilot, self.cap = frame, pilot, cap
        self.max_bounces = max_bounces
        self.dims = 1 + _EMIT_DIMS + _BOUNCE_DIMS * max_bounces
        power = np.array([luminance(e.power()) for e in frame.emitters])
        self.pick = power / power.sum()
        self.cdf = np.cumsum(self.pick)
        self.cdf[-1] = 1.0
        self.defensive_scale = 0.0

    def trace(self, u):
        """VPLs of single-particle paths (flux = Phi_1, the whole light's power through
        one particle) and the path index of each VPL."""
        n = len(u)
        which = np.minimum(np.searchsorted(self.cdf, u[:, 0], side='right'), len(self.cdf) - 1)
        origin, direction, flux = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        for e, emitter in enumerate(self.frame.emitters):
            rows = np.flatnonzero(which == e)
            if len(rows) == 0:
                continue
            o, d, f = emitter.emit(u[rows, 1:1 + _EMIT_DIMS])
            origin[rows], direction[rows] = o, d
            # emit() spreads the power over len(rows) particles; one sample carries it all.
            flux[rows] = np.asarray(f) * len(rows) / self.pick[e]
        return vpl.follow_paths(self.frame, origin, direction, flux, u[:, 1 + _EMIT_DIMS:],
                            self.max_bounces)

    def vpl_target(self, vpls):
        """f per VPL: the power it brings to the pilot + a defensive share of its own."""
        transfer = np.minimum(pair_transfer(self.frame, self.pilot, vpls.position, vpls.normal),
                              self.cap)
        seen = camera_importance(self.pilot, transfer, vpls.flux)
        return seen + self.defensive_scale * luminance(vpls.flux)

    def evaluate(self, u):
        """(f per path, f per VPL, VPLs, owner): a path's f is the sum of its VPLs' f."""
        vpls, owner = self.trace(u)
        f_vpl = self.vpl_target(vpls)
        return np.bincount(owner, f_vpl, minlength=len(u)), f_vpl, vpls, owner


def mutate(u, rng):
    """Symmetric proposal: a uniform large step, or a wrapped Gaussian small step."""
    large = rng.random(len(u)) < LARGE_STEP
    small = (u + SMALL_STEP * rng.standard_normal(u.shape)) % 1.0
    return np.where(large[:, None], rng.random(u.shape), small)


class PathStore:
    """Every evaluated path's f, and its VPLs with their own f, under a global path id."""

    def __init__(self):
        self.batches, self.f, self.count = [], [], 0

    def add(self, f, f_vpl, vpls, owner):
        ids = self.count + np.arange(len(f))
        self.batches.append((vpls, owner + self.count, f_vpl))
        self.f.append(f)
        self.count += len(f)
        return ids

    def rows(self):
        """(VPLs, owner path id, f per VPL) of every evaluated path, sorted by path id."""
        owner = np.concatenate([b[1] for b in self.batches])
        order = np.argsort(owner, kind='stable')
        f_vpl = np.concatenate([b[2] for b in self.batches])[order]
        return vpl.VPLs.concatenate([b[0] for b in self.batches]).subset(order), owner[order], f_vpl

    def pool_weights(self, owner, f_vpl, recorded, boot_paths, normalisation):
        """Weight of every VPL (u, k) in the pool, summing to 1, with expectation
        f(u, k) / b per unit of path space: CHAIN_SHARE from the m recorded chain states
        (density f(u) / b: weight 1/m per visit, split over the path's VPLs as
        f(u, k) / f(u), the expected value of drawing one of them), the rest from the N
        uniform bootstrap paths (importance weight f(u, k) / (N b)). Each part alone is
        an unbiased estimate of the same measure, so their convex mix is too."""
        f_path = np.concatenate(self.f)
        visits = np.bincount(recorded, minlength=self.count)[owner]
        weight = np.zeros(len(owner))
        seen = visits > 0
        weight[seen] = (CHAIN_SHARE / len(recorded) * visits[seen] * f_vpl[seen]
                        / f_path[owner[seen]])
        boot = owner < boot_paths
        weight[boot] += (1 - CHAIN_SHARE) * f_vpl[boot] / (boot_paths * normalisation)
        return weight

    def vpls(self, recorded, boot_paths, normalisation, count, rng):
        """`count` draws from the pool (pool_weights) by systematic resampling along a
        space-filling curve (spread out, not clumped; repeats merge). A VPL drawn t
        times re-emits t Phi_k b / (count f(u, k)) (Segovia 2007 sec. 3.2: each draw
        brings P_c / count to the camera), so the expected flux is the pool's."""
        vpls, owner, f_vpl = self.rows()
        weight = self.pool_weights(owner, f_vpl, recorded, boot_paths, normalisation)
        rows = np.flatnonzero(weight > 0)
        rows = rows[np.argsort(morton_codes(vpls.position[rows]), kind='stable')]
        drawn, times = sampling.systematic_draws(weight[rows], count, rng)
        index = rows[drawn]
        vpls = vpls.subset(index)
        vpls.flux = vpls.flux * (times * normalisation / (count * f_vpl[index]))[:, None]
        return vpls


def run_chains(space, state, f_state, state_id, steps, store, rng, tries):
    """Multiple-try Metropolis (Liu, Liang & Wong 2000, symmetric proposals; tries = 1 is
    plain Metropolis-Hastings) on all chains at once. Returns the path id of every
    chain's state after every step."""
    chains = len(state)
    recorded = []
    for _ in range(steps):
        proposals = np.concatenate([mutate(state, rng) for _ in range(tries)])
        f_prop, *path = space.evaluate(proposals)
        prop_id = store.add(f_prop, *path)
        f_try = f_prop.reshape(tries, chains)
        total = f_try.sum(0)
        # Pick one try per chain with probability f(y_j) / sum_j f(y_j).
        pick = (rng.random(chains) * total < np.cumsum(f_try, 0)).argmax(0)
        chosen = pick * chains + np.arange(chains)
        reference_total = f_state.copy()
        if tries > 1:
            references = np.concatenate([mutate(proposals[chosen], rng)
                                         for _ in range(tries - 1)])
            reference_total += space.evaluate(references)[0].reshape(tries - 1, chains).sum(0)
        accept = (total > 0) & (rng.random(chains) * reference_total < total)
        state = np.where(accept[:, None], proposals[chosen], state)
        f_state = np.where(accept, f_prop[chosen], f_state)
        state_id = np.where(accept, prop_id[chosen], state_id)
        recorded.append(state_id)
    return np.concatenate(recorded)


def relative_pilot(frame, pilot, max_bounces, cap, rng):
    """The pilot with each point's albedo weighted by Lbar / (L_direct + Lbar): f then
    counts the power a VPL brings relative to the radiance already there (the image's
    relative error), so points lit directly do not draw the VPLs away from those that
    only VPLs light. Lbar = mean indirect radiance over the pilot, from SCOUT paths
    (any positive weight keeps the estimate unbiased)."""
    from .bidirectional import surface_buffer
    points = surface_buffer(pilot.position, pilot.normal, pilot.geo_normal, pilot.albedo)
    E = direct_light.direct_irradiance(frame, points, SCOUT_LIGHT_SAMPLES, rng)
    direct = luminance(pilot.albedo * E) / np.pi
    space = PathSpace(frame, pilot, max_bounces, cap)
    indirect = space.evaluate(rng.random((SCOUT, space.dims)))[0].mean() / pilot.count
    if indirect <= 0:   # the scout missed the rare paths: keep absolute power
        return pilot
    weight = indirect / np.maximum(direct + indirect, 1e-300)
    return replace(pilot, albedo=pilot.albedo * weight[:, None])


def place_metropolis(frame, gb, settings, rng):
    """(VPLs, info): as many VPLs as `settings.particles` classic particles leave, drawn
    by the chains."""
    from .render import clamp_distance  # render dispatches to us: import at call time
    pilot = camera_pilot(gb, PILOT_CAMERA_POINTS, rng)
    n = max(1, settings.particles)
    if pilot.count == 0:
        return vpl.trace_vpls(frame, n, settings.max_bounces, seed=settings.seed), {}
    typical = vpl.VPLs.empty()
    typical.position = np.zeros((3 * n, 3))   # only its count sets the clamp scale
    cap = 1.0 / max(TARGET_CLAMP * clamp_distance(frame, typical, 1.0), 1e-6) ** 2
    pilot = relative_pilot(frame, pilot, settings.max_bounces, cap, rng)
    space = PathSpace(frame, pilot, settings.max_bounces, cap)
    store = PathStore()
    # Bootstrap: uniform paths estimate b = P_c and provide the chains' seeds.
    boot = rng.random((max(BOOTSTRAP * n, BOOTSTRAP_MIN), space.dims))
    f_boot, f_vpl, vpls, owner = space.evaluate(boot)
    own_vpl = luminance(vpls.flux)
    own = np.bincount(owner, own_vpl, minlength=len(boot))
    if f_boot.sum() <= 0:
        return vpl.trace_vpls(frame, n, settings.max_bounces, seed=settings.seed), {
            'metropolis': "no light path reaches the camera pilot: classic VPLs"}
    space.defensive_scale = DEFENSIVE * f_boot.mean() / max(own.mean(), 1e-300)
    f_boot = f_boot + space.defensive_scale * own
    boot_id = store.add(f_boot, f_vpl + space.defensive_scale * own_vpl, vpls, owner)
    normalisation = f_boot.mean()                         # b = integral of f over [0,1)^D
    # As many VPLs as classic IR would place: one per drawn path.
    n = max(1, int(round(n * len(owner) / len(boot))))
    states = int(np.ceil(THINNING * n))
    chains = max(1, -(-states // STEPS_PER_CHAIN))
    cdf = np.cumsum(f_boot) / f_boot.sum()   # seeds: systematic resampling by f
    seeds = np.minimum(np.searchsorted(cdf, (rng.random() + np.arange(chains)) / chains,
                                       side='right'), len(boot) - 1)
    recorded = run_chains(space, boot[seeds], f_boot[seeds], boot_id[seeds],
                          -(-states // chains), store, rng, TRIES)[:states]
    vpls = store.vpls(recorded, len(boot), normalisation, n, rng)
    return vpls, {'chains': chains, 'paths': int(len(recorded)),
                  'acceptance': float(np.mean(recorded[chains:] != recorded[:-chains]))
                  if len(recorded) > chains else 0.0}

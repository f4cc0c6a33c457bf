"""Metropolis Instant Radiosity (Segovia, Iehl, Peroche 2007).

A state is a light path in primary sample space: u in [0,1)^D picks the emitter, the
particle's start and every bounce. f(u) = P'(u), the power its VPLs bring to the camera
pilot points (plus a small share of its own power, so that no path that lights the
image has f = 0). Parallel Metropolis-Hastings chains, multiple-try by default (Liu,
Liang & Wong 2000), draw n paths with density f / b; every VPL of a drawn path re-emits
Phi_1 * b / (n f(u)), i.e. P_c / (n P') as in Segovia 2007 sec. 3.2, with b = P_c
estimated first from uniformly sampled (bootstrap) paths. The chains start from seeds
resampled from the bootstrap set in proportion to f, so they start near equilibrium.
"""
import numpy as np

from . import vpl
from .variant_choice import camera_importance, camera_pilot, luminance, pair_transfer

PILOT_CAMERA_POINTS = 64
TRIES = 3                 # multiple-try Metropolis; 1 = plain Metropolis-Hastings
LARGE_STEP = 0.5          # probability of an independent (uniform) proposal
SMALL_STEP = 0.02         # std. dev. of the wrapped Gaussian perturbation
STEPS_PER_CHAIN = 8
DEFENSIVE = 0.05          # share of f given by the path's own power
# f clamps distances at this many mean VPL spacings: a smooth target whose ratio to
# the VPL's true contribution to any pixel stays bounded.
TARGET_CLAMP = 2.0
BOOTSTRAP = 8             # uniform bootstrap paths per path of the budget
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

    def evaluate(self, u):
        """(f per path, VPLs, owner): f = P'(u) + defensive share of the path's power."""
        vpls, owner = self.trace(u)
        transfer = np.minimum(pair_transfer(self.frame, self.pilot, vpls.position, vpls.normal),
                              self.cap)
        seen = camera_importance(self.pilot, transfer, vpls.flux)
        own = luminance(vpls.flux)
        f = np.bincount(owner, seen + self.defensive_scale * own, minlength=len(u))
        return f, vpls, owner


def mutate(u, rng):
    """Symmetric proposal: a uniform large step, or a wrapped Gaussian small step."""
    large = rng.random(len(u)) < LARGE_STEP
    small = (u + SMALL_STEP * rng.standard_normal(u.shape)) % 1.0
    return np.where(large[:, None], rng.random(u.shape), small)


class PathStore:
    """Every evaluated path's f and VPLs, under a global path id."""

    def __init__(self):
        self.batches, self.f, self.count = [], [], 0

    def add(self, f, vpls, owner):
        ids = self.count + np.arange(len(f))
        self.batches.append((vpls, owner + self.count))
        self.f.append(f)
        self.count += len(f)
        return ids

    def vpls(self, recorded, normalisation):
        """VPLs of the recorded path ids: flux Phi_1 * times * b / (n f), n = len(recorded)
        (Segovia 2007: each drawn path brings P_c / n to the camera)."""
        times = np.bincount(recorded, minlength=self.count)
        f = np.concatenate(self.f)
        scale = np.where(times > 0, times * normalisation / (len(recorded) * np.maximum(f, 1e-300)),
                         0.0)
        vpls = vpl.VPLs(*[np.concatenate([b[0].__dict__[name] for b in self.batches])
                          for name in ('position', 'normal', 'flux', 'bounce')])
        owner = np.concatenate([b[1] for b in self.batches])
        keep = scale[owner] > 0
        vpls = vpls.subset(keep)
        vpls.flux = vpls.flux * scale[owner[keep], None]
        return vpls


def run_chains(space, state, f_state, state_id, steps, store, rng, tries=TRIES):
    """Multiple-try Metropolis (Liu, Liang & Wong 2000, symmetric proposals; tries = 1 is
    plain Metropolis-Hastings) on all chains at once. Returns the path id of every
    chain's state after every step."""
    chains = len(state)
    recorded = []
    for _ in range(steps):
        proposals = np.concatenate([mutate(state, rng) for _ in range(tries)])
        f_prop, vpls, owner = space.evaluate(proposals)
        prop_id = store.add(f_prop, vpls, owner)
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


def place_metropolis(frame, gb, settings, rng):
    """(VPLs, info): `settings.particles` paths drawn by the chains."""
    from .render import clamp_distance  # render dispatches to us: import at call time
    pilot = camera_pilot(gb, PILOT_CAMERA_POINTS, rng)
    n = max(1, settings.particles)
    if pilot.count == 0:
        return vpl.trace_vpls(frame, n, settings.max_bounces, seed=settings.seed), {}
    typical = vpl.VPLs.empty()
    typical.position = np.zeros((3 * n, 3))   # only its count sets the clamp scale
    cap = 1.0 / max(TARGET_CLAMP * clamp_distance(frame, typical, 1.0), 1e-6) ** 2
    space = PathSpace(frame, pilot, settings.max_bounces, cap)
    store = PathStore()
    # Bootstrap: uniform paths estimate b = P_c and provide the chains' seeds.
    boot = rng.random((BOOTSTRAP * n, space.dims))
    f_boot, vpls, owner = space.evaluate(boot)
    own = np.bincount(owner, luminance(vpls.flux), minlength=len(boot))
    if f_boot.sum() <= 0:
        return vpl.trace_vpls(frame, n, settings.max_bounces, seed=settings.seed), {
            'metropolis': "no light path reaches the camera pilot: classic VPLs"}
    space.defensive_scale = DEFENSIVE * f_boot.mean() / max(own.mean(), 1e-300)
    f_boot = f_boot + space.defensive_scale * own
    boot_id = store.add(f_boot, vpls, owner)
    normalisation = f_boot.mean()                         # b = integral of f over [0,1)^D
    # As many VPLs as classic IR would place: n paths of the chain's mean length.
    per_path = np.bincount(owner, minlength=len(boot))
    n = max(1, int(round(n * per_path.mean() / max((f_boot @ per_path) / f_boot.sum(), 1e-9))))
    chains = max(1, -(-n // STEPS_PER_CHAIN))
    cdf = np.cumsum(f_boot) / f_boot.sum()
    seeds = np.minimum(np.searchsorted(cdf, rng.random(chains), side='right'), len(boot) - 1)
    recorded = run_chains(space, boot[seeds], f_boot[seeds], boot_id[seeds],
                          -(-n // chains), store, rng)
    vpls = store.vpls(recorded, normalisation)
    return vpls, {'chains': chains, 'paths': int(len(recorded)),
                  'acceptance': float(np.mean(recorded[chains:] != recorded[:-chains]))
                  if len(recorded) > chains else 0.0}

"""One entry point for every way of placing VPLs (issue 5): classic, bidirectional,
Metropolis, incremental and Auto. All return the same vpl.VPLs, so the gather and the
bake use them unchanged."""
import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from . import bidirectional, emission_guide, metropolis, vpl
from .gbuffer import build_gbuffer
from .incremental import IncrementalVPLs
from .transfer_reuse import TransferCache
from .variant_choice import choose_variant

VARIANTS = ('CLASSIC', 'BIDIRECTIONAL', 'METROPOLIS', 'INCREMENTAL', 'AUTO')
VARIANT_NAMES = {'CLASSIC': "Classic", 'BIDIRECTIONAL': "Bidirectional",
                 'METROPOLIS': "Metropolis", 'INCREMENTAL': "Incremental", 'AUTO': "Auto"}


@dataclass
class VariantState:
    """What persists between the frames of one render job (animation or viewport)."""
    incremental: IncrementalVPLs = field(default_factory=IncrementalVPLs)
    transfer: TransferCache = field(default_factory=TransferCache)   # incremental's gather
    geometry_key: bytes = b''
    lights_key: bytes = b''
    frames: int = 0

    def observe(self, frame):
        """Record this frame; True when the geometry stayed and the lights changed."""
        geometry_key = frame.tracer.fingerprint
        lights = [*frame.scene.lights, *frame.scene.portals]
        lights_key = hashlib.blake2b(repr(lights).encode(), digest_size=16).digest()
        animated = (self.frames > 0 and geometry_key == self.geometry_key
                    and lights_key != self.lights_key)
        self.geometry_key, self.lights_key = geometry_key, lights_key
        self.frames += 1
        return animated


# Longest side of the small camera G-buffer the camera-aware variants look through.
PILOT_RESOLUTION = 128


def pilot_gbuffer(frame, rng):
    """One sample per pixel of a small copy of the camera: where the camera looks,
    enough for the variants, at a fixed cost whatever the render resolution."""
    cam = frame.scene.camera
    scale = min(1.0, PILOT_RESOLUTION / max(cam.width, cam.height))
    small = replace(cam, width=max(1, round(cam.width * scale)),
                    height=max(1, round(cam.height * scale)))
    return build_gbuffer(frame, small, 1, rng)


def vpls_for_frame(frame, settings, state=None, cancel=None, batch=0):
    """The VPLs of this frame for `settings.variant`, and the info dict of place_vpls:
    the one call site for the renderer and the bake. `batch`: classic IR's batch of
    paths in a walkthrough (temporal.PathWindow)."""
    guide = bool(emission_guide.guidable(frame)) and frame.scene.camera is not None
    # Classic needs no camera pass, unless a sun is guided toward what the camera sees.
    gb = (pilot_gbuffer(frame, np.random.default_rng([settings.seed, 0x9B]))
          if guide or settings.variant != 'CLASSIC' else None)
    if guide:
        frame = emission_guide.guided_frame(frame, gb, settings.seed)
    if settings.variant == 'CLASSIC':
        return (vpl.trace_vpls(frame, settings.particles, settings.max_bounces,
                               seed=settings.seed, cancel=cancel, sequence=settings.sequence,
                               batch=batch),
                {'variant': 'CLASSIC', 'reason': "Classic: chosen in the render settings"})
    return place_vpls(frame, gb, settings, state)


def place_vpls(frame, gb, settings, state=None):
    """(VPLs, info): the VPLs of `settings.variant` for this frame and a dict with the
    variant used ('variant'), why ('reason') and variant-specific counters."""
    state = state if state is not None else VariantState()
    animated = state.observe(frame)
    variant = settings.variant if settings.variant in VARIANTS else 'CLASSIC'
    rng = np.random.default_rng([settings.seed, 0x1BAD])
    reason = f"{VARIANT_NAMES[variant]}: chosen in the render settings"
    if variant == 'AUTO':
        variant, reason = choose_variant(frame, gb, settings, animated, rng)
    if settings.max_bounces < 1 or not frame.emitters or len(frame.triangles) == 0:
        return vpl.VPLs.empty(), {'variant': variant, 'reason': reason}
    if variant == 'BIDIRECTIONAL':
        vpls, info = bidirectional.place_bidirectional(frame, gb, settings, rng)
    elif variant == 'METROPOLIS':
        vpls, info = metropolis.place_metropolis(frame, gb, settings, rng)
    elif variant == 'INCREMENTAL':
        vpls, info = state.incremental.update(frame, settings)
    else:
        vpls, info = vpl.trace_vpls(frame, settings.particles, settings.max_bounces,
                                    seed=settings.seed, sequence=settings.sequence), {}
    return vpls, {'variant': variant, 'reason': reason, **info}

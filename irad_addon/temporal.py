"""Temporal reuse for walkthroughs (Keller 1997, sec. 4.3): while geometry, lights and
the particle settings stay the same, the VPLs do not depend on the camera, so frames
of a camera fly-through reuse one VPL set (and its light trees) instead of tracing
new particles: less work per frame and no flicker between frames."""
import hashlib

import numpy as np

from .vpl import VPLs


# RenderSettings fields that change the VPL set.
_VPL_SETTINGS = ("particles", "max_bounces", "seed", "variant", "sequence")
# Variants that place VPLs where the camera looks: their VPLs follow the camera.
_CAMERA_DEPENDENT = ("BIDIRECTIONAL", "METROPOLIS", "AUTO")


def light_setup_key(scene, settings, surfaces_key):
    """A digest of everything the VPLs depend on except the camera; surfaces_key is
    the frame's Frame.surfaces_key (triangles, shading normals, materials)."""
    h = hashlib.blake2b(surfaces_key, digest_size=16)
    h.update(np.ascontiguousarray(scene.world_radiance).tobytes())
    h.update(repr([(type(light).__name__, sorted(vars(light).items(), key=str))
                   for light in [*scene.lights, *scene.portals]]).encode())
    h.update(repr([getattr(settings, name) for name in _VPL_SETTINGS]).encode())
    if settings.variant in _CAMERA_DEPENDENT and scene.camera is not None:
        h.update(repr(sorted(vars(scene.camera).items(), key=str)).encode())
    return h.digest()


def still_camera_key(frame, settings):
    """A digest of what the G-buffers and the VPLs' transfer to them depend on: the
    surfaces, the camera and the settings (transfer_reuse.py keeps them while it stays)."""
    h = hashlib.blake2b(frame.surfaces_key, digest_size=16)
    h.update(repr(sorted(vars(frame.scene.camera).items(), key=str)).encode())
    h.update(repr(settings).encode())
    return h.digest()


def emitters_fingerprint(emitters):
    """16 bytes that change whenever any emitter's data changes (type, arrays, numbers,
    portals): equal fingerprints with the same seed and counts give the same particles."""
    digest = hashlib.blake2b(digest_size=16)

    def add(value):
        if isinstance(value, np.ndarray):
            digest.update(f"{value.dtype.str}{value.shape}".encode())
            digest.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, (list, tuple)):
            digest.update(b"[")
            for item in value:
                add(item)
            digest.update(b"]")
        elif hasattr(value, "__dict__"):
            digest.update(type(value).__name__.encode())
            for name, item in sorted(vars(value).items()):
                digest.update(name.encode())
                add(item)
        else:
            digest.update(repr(value).encode())

    add(list(emitters))
    return digest.digest()


# Identity of VPL j of batch b: b * BATCH_IDS + j. A power of two, so that the
# interleaved group (identity mod k^2 samples) of a kept VPL never changes.
BATCH_IDS = 1 << 32


def scaled_union(batches, numbers):
    """One VPL set of all batches, each batch's flux over their number (each batch
    alone estimates the whole light transport). Each VPL's identity is its batch's
    `number` and its index there, so that it keeps its interleaved group while the
    window slides: each pixel keeps gathering the kept batches' same VPLs."""
    union = VPLs.concatenate(batches)
    union.flux /= len(batches)
    union.identity = np.concatenate([number * BATCH_IDS + np.arange(batch.count)
                                     for number, batch in zip(numbers, batches)])
    return union


def path_settings_key(settings):
    """What a batch of paths depends on among the settings, except the seed (an animated
    seed gives each frame's batch its own): a change starts the window anew."""
    return repr([getattr(settings, name) for name in _VPL_SETTINGS if name != "seed"]
                + [settings.temporal_frames])


class PathWindow:
    """The paths of the last N frames (Keller 1997 sec. 4.3). Each frame whose light
    setup differs from a batch in the window traces a new batch of particles, which
    continues the low-discrepancy sequence, and drops the oldest batch beyond N. The
    frame gathers from the union, each batch's flux over the number of batches: a
    walkthrough reaches N frames' particles at one frame's tracing cost, and under
    moving lights or objects the bounce light follows them smoothly (temporal
    anti-aliasing, at the price of lagging by up to N frames). Once the window is full
    and every batch has the frame's setup (the camera alone moves), or the same frame
    is rendered again unchanged, the union is handed out again untouched: no tracing
    and no flicker. With N = 1 this is plain VPL reuse."""

    def __init__(self):
        self._batches = []          # (light setup key, batch number, VPLs), oldest first
        self._union = None
        self._settings = None
        self._frame = None
        self._shot = None
        self._next_batch = 0
        self.reused = 0

    def lookup(self, setup_key, settings, frames, frame_number=None, shot=None):
        """The union to render with, or None: then trace batch `next_batch` and store
        it. `frames` is N; `frame_number` the scene frame (None: taken as the next);
        `shot` names the animation (the engine: .blend file and scene), so that another
        scene's paths are never kept."""
        if shot != self._shot:
            self._shot, self._settings = shot, None
        same_frame = frame_number is not None and frame_number == self._frame
        successive = (frame_number is None or self._frame is None
                      or frame_number == self._frame + 1)
        settled = all(key == setup_key for key, _, _ in self._batches)
        # New particle settings, a jump in time, or an edit re-rendered on the same
        # frame: the kept paths belong to another scene. With N = 1 any change does.
        if (path_settings_key(settings) != self._settings
                or (frames > 1 and not (successive or same_frame))
                or (not settled and (same_frame or frames <= 1))):
            self._start(settings)
            settled = True
        self._frame = frame_number
        if self._batches and settled and len(self._batches) >= frames:
            self.reused += 1
            return self._union
        return None

    @property
    def next_batch(self):
        return self._next_batch

    @property
    def batches(self):
        return len(self._batches)

    def store(self, setup_key, vpls, frames):
        """Add the batch just traced, drop the oldest beyond `frames`; the union."""
        self._batches = [*self._batches, (setup_key, self._next_batch, vpls)][-max(1, frames):]
        self._next_batch += 1
        self._union = (vpls if len(self._batches) == 1 else
                       scaled_union([b for _, _, b in self._batches],
                                    [number for _, number, _ in self._batches]))
        return self._union

    def _start(self, settings):
        self._batches, self._union = [], None
        self._settings = path_settings_key(settings)
        self._next_batch = 0

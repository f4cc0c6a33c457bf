"""Temporal reuse for walkthroughs (Keller 1997, sec. 4.3): while geometry, lights and
the particle settings stay the same, the VPLs do not depend on the camera, so frames
of a camera fly-through reuse one VPL set (and its light trees) instead of tracing
new particles: less work per frame and no flicker between frames."""
import hashlib

import numpy as np


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


class VplCache:
    """The last frame's VPLs, handed out again while their light setup is unchanged."""

    def __init__(self):
        self._key = None
        self._vpls = None
        self.reused = 0

    def lookup(self, key):
        if self._key is not None and key == self._key:
            self.reused += 1
            return self._vpls
        return None

    def store(self, key, vpls):
        self._key, self._vpls = key, vpls

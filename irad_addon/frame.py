"""One frame's scene, prepared for tracing: clean triangles, per-triangle shading
data, the ray tracer (reused while geometry is unchanged) and the emitters."""
import hashlib
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import geometry, lights
from .rays import RayTracerCache, array_bytes
from .scene_data import SceneData


class InvalidScene(ValueError):
    """The scene cannot be rendered; the message says why, for the user."""


@dataclass
class Frame:
    scene: SceneData
    triangles: np.ndarray        # float32 (T, 3, 3), degenerate triangles removed
    corner_normals: np.ndarray   # float32 (T, 3, 3)
    geo_normals: np.ndarray      # float64 (T, 3)
    albedo: np.ndarray           # float64 (T, 3)
    emission: np.ndarray         # float64 (T, 3)
    object_index: np.ndarray     # int32 (T,)
    holdout: np.ndarray          # bool (T,)
    tracer: object
    emitters: list
    bounds: tuple                # (centre, radius) of the geometry's bounding sphere
    dropped_triangles: int = 0
    mirror: np.ndarray | None = None   # float64 (T, 3) mirror reflectance; None: no mirrors

    @property
    def is_mirror(self):
        """bool (T,): triangles of perfect mirrors."""
        if self.mirror is None:
            return np.zeros(len(self.triangles), bool)
        return self.mirror.max(1) > 0

    @property
    def extent(self):
        return self.tracer.extent

    @cached_property
    def surfaces_key(self):
        """A digest of the surfaces: the triangles (the tracer's fingerprint), their
        shading normals, materials and holdout flags: what the VPL paths and the
        G-buffers depend on in the scene."""
        h = hashlib.sha1(self.tracer.fingerprint)
        mats = self.scene.materials
        for array in (self.corner_normals, self.scene.mesh.material_index, self.holdout,
                      mats.albedo, mats.emission, mats.mirror):
            h.update(b'-' if array is None else array_bytes(array))
        return h.digest()

    def offset(self):
        return self.tracer.offset_scale()


def _clean_colors(values, count):
    values = np.asarray(values, np.float64).reshape(-1, 3) if len(values) else np.zeros((0, 3))
    values = np.where(np.isfinite(values), values, 0.0)
    return values if len(values) else np.zeros((count, 3))


def prepare_frame(scene: SceneData, tracer_cache: RayTracerCache | None = None) -> Frame:
    mesh, mats = scene.mesh, scene.materials
    tris = np.asarray(mesh.triangles, np.float32).reshape(-1, 3, 3)
    extent = scene.extent() if np.isfinite(tris).all() else 1.0
    keep = geometry.nondegenerate(tris, extent)
    tris = np.ascontiguousarray(tris[keep])
    material = np.asarray(mesh.material_index, np.int64)[keep]
    albedo_table = np.clip(_clean_colors(mats.albedo, 1), 0.0, 1.0)
    emission_table = np.maximum(_clean_colors(mats.emission, len(albedo_table)), 0.0)
    material = np.clip(material, 0, max(len(albedo_table) - 1, 0))
    corner = np.asarray(mesh.corner_normals, np.float32).reshape(-1, 3, 3)[keep]
    geo = geometry.geometric_normals(tris)
    corner = np.where(np.isfinite(corner), corner, geo[:, None, :].astype(np.float32))
    object_index = np.asarray(mesh.object_index, np.int32)[keep]
    holdout_table = np.asarray(mesh.object_holdout, bool)
    holdout = (holdout_table[object_index] if len(holdout_table)
               else np.zeros(len(tris), bool))
    cache = tracer_cache or RayTracerCache()
    tracer = cache.get(tris)
    bounds = geometry.bounding_sphere(tris)
    emission = emission_table[material]
    emitters = lights.build_emitters(scene.lights, tris, emission, scene.world_radiance,
                                     bounds, tracer.offset_scale(), scene.portals)
    mirror = None
    if mats.mirror is not None and np.any(mats.mirror):
        mirror = np.clip(_clean_colors(mats.mirror, len(albedo_table)), 0.0, 1.0)[material]
        mirror = mirror if mirror.any() else None
    return Frame(scene, tris, corner, geo, albedo_table[material], emission,
                 object_index, holdout, tracer, emitters, bounds, int((~keep).sum()), mirror)


def check_renderable(scene: SceneData):
    """Raise InvalidScene with a message a user can act on."""
    if scene.camera is None:
        raise InvalidScene("The scene has no active camera: add one and set it as the "
                           "scene camera")
    if scene.camera.width < 1 or scene.camera.height < 1:
        raise InvalidScene("The render resolution is zero")
    cam = scene.camera
    numbers = [cam.lens, cam.sensor_width, cam.sensor_height, cam.ortho_scale, cam.shift_x,
               cam.shift_y, cam.clip_start, cam.clip_end]
    if not (np.isfinite(cam.matrix_world).all() and np.isfinite(numbers).all()):
        raise InvalidScene("The camera's transform or lens settings are not finite numbers "
                           "(NaN or infinity): fix the camera object or its drivers")

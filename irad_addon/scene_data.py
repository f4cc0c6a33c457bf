"""The scene as the core sees it: plain numpy arrays in world space, Blender units.

Extraction (``extract.py``) fills these from the evaluated depsgraph; everything
else in ``irad_addon`` reads them and never touches bpy. Lights keep Blender's own
parameters (power, size, blend, ...); ``lights.py`` turns them into radiometry.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geometry import coordinate_bounds


@dataclass
class Mesh:
    """All visible triangles of the scene, flattened over objects and instances."""
    triangles: np.ndarray        # float32 (T, 3, 3): world-space corner positions
    corner_normals: np.ndarray   # float32 (T, 3, 3): unit shading normals (smooth or flat)
    material_index: np.ndarray   # int32 (T,): index into Materials
    object_index: np.ndarray     # int32 (T,): index into object_names (the object id pass)
    object_names: list = field(default_factory=list)
    object_holdout: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (O,)

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])


@dataclass
class Materials:
    """Per-material constants of the diffuse model."""
    albedo: np.ndarray           # float32 (M, 3): diffuse reflectance, linear RGB in [0, 1]
    emission: np.ndarray         # float32 (M, 3): emitted radiance [W / (m^2 sr)], two-sided
    names: list = field(default_factory=list)
    # float32 (M, 3): reflectance of perfect (roughness 0) mirrors, zeros for diffuse
    # materials; None when no material is a mirror.
    mirror: np.ndarray | None = None


@dataclass
class PointLight:
    position: np.ndarray         # (3,)
    color: np.ndarray            # (3,) linear RGB (temperature already applied)
    power: float                 # Blender "Power" [W], exposure already applied
    radius: float                # Blender "Radius" (shadow_soft_size)
    soft_falloff: bool = True    # Blender "Soft Falloff" (use_soft_falloff)


@dataclass
class SpotLight:
    position: np.ndarray         # (3,)
    direction: np.ndarray        # (3,) unit, the cone axis (the light's -Z)
    color: np.ndarray
    power: float
    radius: float
    spot_size: float             # full cone angle [rad]
    spot_blend: float            # [0, 1]
    soft_falloff: bool = True


@dataclass
class AreaLight:
    center: np.ndarray           # (3,)
    axis_u: np.ndarray           # (3,) half-extent vector along the light's local X (world, scaled)
    axis_v: np.ndarray           # (3,) half-extent vector along local Y
    normal: np.ndarray           # (3,) unit, the emitting side (the light's -Z)
    color: np.ndarray
    power: float                 # [W]; the whole light's power as Blender's "Power" means it
    shape: str                   # 'RECTANGLE' (also square) or 'ELLIPSE' (also disk)


@dataclass
class SunLight:
    direction: np.ndarray        # (3,) unit, from the scene towards the sun (the light's +Z)
    color: np.ndarray
    strength: float              # Blender "Strength": irradiance [W/m^2] at normal incidence
    angle: float                 # full angular diameter [rad]


@dataclass
class Portal:
    """A Cycles light portal (an area light with ``cycles.is_portal``): an opening, such
    as a window, through which sun and world light enter. It neither emits nor blocks."""
    center: np.ndarray           # (3,)
    axis_u: np.ndarray           # (3,) half-extent vector along the light's local X
    axis_v: np.ndarray           # (3,) half-extent vector along local Y
    normal: np.ndarray           # (3,) unit, the way light passes in (the light's -Z)
    shape: str                   # 'RECTANGLE' or 'ELLIPSE', as AreaLight


@dataclass
class Camera:
    matrix_world: np.ndarray     # float64 (4, 4): camera to world, looks down its -Z
    projection: str              # 'PERSP' or 'ORTHO'
    lens: float                  # focal length [mm]
    sensor_width: float          # [mm]
    sensor_height: float         # [mm]
    sensor_fit: str              # 'AUTO', 'HORIZONTAL' or 'VERTICAL'
    ortho_scale: float
    shift_x: float
    shift_y: float
    clip_start: float
    clip_end: float
    width: int                   # final pixel resolution (percentage applied)
    height: int
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0


@dataclass
class SceneData:
    mesh: Mesh
    materials: Materials
    lights: list                 # PointLight | SpotLight | AreaLight | SunLight
    world_radiance: np.ndarray   # (3,) constant background radiance, zeros if none
    camera: Camera | None
    warnings: list = field(default_factory=list)   # one-time messages for the user
    portals: list = field(default_factory=list)    # Portal: where sun and world light enter

    def __post_init__(self):
        # Extraction reads portals from light objects: move any found among the lights.
        found = [light for light in self.lights if isinstance(light, Portal)]
        if found:
            self.lights = [light for light in self.lights if not isinstance(light, Portal)]
            self.portals = list(self.portals) + found

    def extent(self) -> float:
        """Diagonal of the geometry's bounding box: the scene's length scale."""
        if self.mesh.triangle_count == 0:
            return 1.0
        lo, hi = coordinate_bounds(self.mesh.triangles)
        return float(np.linalg.norm(hi - lo)) or 1.0


def empty_mesh() -> Mesh:
    return Mesh(np.zeros((0, 3, 3), np.float32), np.zeros((0, 3, 3), np.float32),
                np.zeros(0, np.int32), np.zeros(0, np.int32), [])

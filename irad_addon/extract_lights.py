"""Light objects -> ``scene_data`` lights, with Cycles' power conventions."""
from __future__ import annotations

import math

import numpy as np

from .scene_data import AreaLight, PointLight, Portal, SpotLight, SunLight


def is_baked(ob):
    """True for a light marked ``irad_baked`` (on the evaluated or original object)."""
    for o in (ob, ob.original):
        try:
            if o.get("irad_baked"):
                return True
        except Exception:
            pass
    return False


def _soft_falloff(light):
    return bool(getattr(light, "use_soft_falloff", True))


def _light_color(light):
    color = np.array(tuple(light.color)[:3], np.float64)
    if getattr(light, "use_temperature", False):
        color *= np.array(tuple(light.temperature_color)[:3], np.float64)
    return color


def _unit(v):
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def is_portal(light):
    """A Cycles light portal: an area light with ``cycles.is_portal``."""
    cycles = getattr(light, "cycles", None)      # present once Cycles is loaded
    return light.type == "AREA" and bool(getattr(cycles, "is_portal", False))


def area_shape(light, m):
    """(axis_u, axis_v, shape) of an area light: half-extent vectors in world space
    (object scale included) and 'RECTANGLE' or 'ELLIPSE'."""
    size = float(light.size)
    size_y = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else size
    shape = "RECTANGLE" if light.shape in ("SQUARE", "RECTANGLE") else "ELLIPSE"
    return m[:3, 0] * size / 2, m[:3, 1] * size_y / 2, shape


def light_from(ob, matrix, warn):
    """A scene_data light (or Portal) for an evaluated light object, or None
    (unsupported). SceneData keeps the portals apart from the lights."""
    light = ob.data
    m = np.asarray(matrix, np.float64)
    position = m[:3, 3].copy()
    down = _unit(-m[:3, 2])                     # a light points down its local -Z
    if is_portal(light):                        # light passes in along the portal's -Z
        axis_u, axis_v, shape = area_shape(light, m)
        return Portal(position, axis_u, axis_v, down, shape)
    color = _light_color(light)
    power = float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0))
    normalize = bool(getattr(light, "normalize", True))
    if light.type == "POINT":
        r = float(light.shadow_soft_size)
        if not normalize and r > 0:              # unnormalised: sphere radiance P / pi
            power *= 4 * math.pi * r * r
        return PointLight(position, color, power, r, _soft_falloff(light))
    if light.type == "SPOT":
        r = float(light.shadow_soft_size)
        if not normalize and r > 0:
            power *= 4 * math.pi * r * r
        return SpotLight(position, down, color, power, r,
                         float(light.spot_size), float(light.spot_blend), _soft_falloff(light))
    if light.type == "AREA":
        axis_u, axis_v, shape = area_shape(light, m)
        if not normalize:                       # unnormalised: Power is per unit area
            area = 4 * np.linalg.norm(axis_u) * np.linalg.norm(axis_v)
            power *= area * (math.pi / 4 if shape == "ELLIPSE" else 1.0)
        if float(getattr(light, "spread", math.pi)) < math.pi - 1e-6:
            warn(f"Light '{ob.name}': area light spread below 180 degrees is ignored")
        return AreaLight(position, axis_u, axis_v, down, color, power, shape)
    if light.type == "SUN":
        angle = float(light.angle)
        if not normalize and angle > 0:         # unnormalised: strength is radiance
            power *= math.pi * math.sin(angle / 2) ** 2
        return SunLight(_unit(m[:3, 2]), color, power, angle)
    warn(f"Light '{ob.name}': unsupported type {light.type}")
    return None

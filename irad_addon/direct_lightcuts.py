"""Direct light through lightcuts (Walter et al. 2005, sec. 3): area lights and
emissive meshes become many point lights on their surfaces, gathered with the same
light trees and per-point cuts as the VPLs.

A patch dA of a Lambertian emitter with radiance L lights x with
    L dA cos_l cos_x / d^2 = (flux / pi) cos_l cos_x / d^2,   flux = pi L dA,
exactly a VPL's term (Keller 1997, eq. 5), so the VPL gather serves unchanged (no
clamping beyond NEAREST: these points are the light itself). Point, spot and sun
lights and the world keep their own shadow rays (direct_light.direct_irradiance).
"""
from dataclasses import replace

import numpy as np

from . import direct_light, gather
from .lights import AreaEmitter, EmissiveMeshEmitter
from .vpl import VPLs

# Points per area light or emissive mesh: enough that a point's cut, not the
# placement of the points, sets the error of soft shadows.
POINTS_PER_LIGHT = 4096
# Closest distance to a light point, in units of the scene's size: keeps the cuts'
# error bounds finite on the light's own surface at no visible cost.
NEAREST = 1e-4


def light_points(frame, count=POINTS_PER_LIGHT):
    """(VPLs standing in for the frame's area lights and emissive meshes, the frame
    with the other emitters only) -- or (None, frame) when it has neither."""
    points, rest = [], []
    for emitter in frame.emitters:
        if isinstance(emitter, (AreaEmitter, EmissiveMeshEmitter)):
            points.append(emitter.point_lights(count))
        else:
            rest.append(emitter)
    if not points:
        return None, frame
    position, normal, flux = (np.concatenate(column) for column in zip(*points))
    vpls = VPLs(position, normal, flux, np.zeros(len(position), np.int32))
    return vpls, replace(frame, emitters=rest)


def direct_irradiance(frame, points, others, gb, light_samples, rng, lightcuts,
                      cancel=None, stats=None):
    """Irradiance (S, 3) from every emitter: the light points `points` (light_points)
    through lightcuts, the `others` frame's emitters with shadow rays."""
    E = direct_light.direct_irradiance(others, gb, light_samples, rng, cancel)
    if points is not None:
        everyone = np.zeros(len(gb.hit), np.int64)   # no interleaving: the light itself
        E += gather.indirect_irradiance(frame, gb, points, NEAREST * frame.extent, everyone,
                                        1, cancel, lightcuts=lightcuts, stats=stats)
    return E

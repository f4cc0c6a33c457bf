"""Light that reaches a point through a perfect planar mirror (Keller 1997, sec. 4.2).

A mirror plane doubles every light and VPL: its image behind the plane shines through
the mirror polygon. Rather than building the images we reflect the receivers: the
light a point x gets from the image of a source equals what its mirror image x' gets
from the source itself, with the same cosines and distances. What differs is
visibility: the segment must cross the plane inside the mirror (the first thing the
real ray from x meets is the mirror) and the rest of the way must be free."""
from dataclasses import dataclass, replace

import numpy as np

from . import direct_light, gather


@dataclass
class MirrorPlane:
    normal: np.ndarray       # (3,) unit
    offset: float            # points p of the plane satisfy normal . p = offset
    triangles: np.ndarray    # bool (T,): the mirror triangles on this plane
    reflectance: np.ndarray  # (3,) mean mirror colour of those triangles

    def reflect_points(self, p):
        return p - 2 * (p @ self.normal - self.offset)[:, None] * self.normal

    def reflect_vectors(self, v):
        return v - 2 * (v @ self.normal)[:, None] * self.normal


def mirror_planes(frame):
    """Mirror triangles grouped by the plane they lie in."""
    if frame.mirror is None:
        return []
    index = np.flatnonzero(frame.is_mirror)
    normal = frame.geo_normals[index]
    # One orientation per plane: the normal's largest component positive.
    flip = np.take_along_axis(normal, np.abs(normal).argmax(1)[:, None], 1)[:, 0] < 0
    normal = np.where(flip[:, None], -normal, normal)
    offset = np.einsum('ij,ij->i', normal, frame.triangles[index, 0].astype(np.float64))
    key = np.column_stack([np.round(normal, 3), np.round(offset / (1e-4 * frame.extent))])
    _, group = np.unique(key, axis=0, return_inverse=True)
    planes = []
    for g in range(group.max() + 1):
        members = index[group.ravel() == g]
        n = normal[group.ravel() == g].mean(0)
        n /= np.linalg.norm(n)
        mask = np.zeros(len(frame.triangles), bool)
        mask[members] = True
        planes.append(MirrorPlane(n, float(offset[group.ravel() == g].mean()), mask,
                                  frame.mirror[members].mean(0)))
    return planes


def visible_through(frame, plane, origin, direction, tfar, eps, threads=True):
    """For segments origin + t direction, 0 < t < tfar, given in the reflected space
    (origin is a receiver's mirror image): True where the real path, receiver -> the
    plane -> the end, meets the mirror first and is otherwise unblocked."""
    origin = origin.astype(np.float64)
    direction = direction.astype(np.float64)
    tfar = np.asarray(tfar, np.float64)
    denom = direction @ plane.normal
    safe = np.where(np.abs(denom) > 1e-30, denom, 1e-30)
    t_plane = (plane.offset - origin @ plane.normal) / safe
    crosses = (t_plane > 0) & (t_plane < tfar)
    visible = np.zeros(len(origin), bool)
    idx = np.flatnonzero(crosses)
    if len(idx) == 0:
        return visible
    on_plane = origin[idx] + t_plane[idx, None] * direction[idx]
    receiver = plane.reflect_points(origin[idx])
    # The real first segment must hit this mirror (and nothing before it).
    first = frame.tracer.intersect(receiver, on_plane - receiver, np.full(len(idx), 1 + 1e-3),
                                   threads=threads)
    hit_mirror = first.hit & plane.triangles[np.maximum(first.triangle, 0)] & (
        first.distance > 1 - 1e-3)
    # The rest, from the mirror on towards the end, must be free.
    side = np.sign(receiver @ plane.normal - plane.offset)[:, None] * plane.normal
    start = on_plane + side * eps
    remaining = np.where(np.isfinite(tfar[idx]), tfar[idx] - t_plane[idx], 1e30)
    blocked = frame.tracer.occluded(start, direction[idx], remaining, threads=threads)
    visible[idx] = hit_mirror & ~blocked
    return visible


def reflected_view(gb, plane):
    """The G-buffer's points as their mirror images (same hits, reflected geometry)."""
    return replace(gb, position=plane.reflect_points(gb.position),
                   normal=plane.reflect_vectors(gb.normal),
                   geo_normal=plane.reflect_vectors(gb.geo_normal))


def mirrored_irradiance(frame, gb, vpls, min_distance, subset_of_sample, subsets,
                        light_samples, rng, cancel=None):
    """(direct, indirect) irradiance (S, 3) that arrives through the scene's mirrors:
    from the lights' and the VPLs' images, each times its mirror's reflectance."""
    E_direct = np.zeros((len(gb.hit), 3))
    E_indirect = np.zeros((len(gb.hit), 3))
    eps = frame.offset()
    for plane in mirror_planes(frame):
        view = reflected_view(gb, plane)

        def through(o, d, t, threads=True, plane=plane):
            return visible_through(frame, plane, o, d, t, eps, threads)

        E_direct += plane.reflectance * direct_light.direct_irradiance(
            frame, view, light_samples, rng, cancel, visible=through)
        E_indirect += plane.reflectance * gather.indirect_irradiance(
            frame, view, vpls, min_distance, subset_of_sample, subsets, cancel,
            visible=lambda o, d, t, through=through: through(o, d, t, threads=False))
    return E_direct, E_indirect

"""Baked bounce lights from VPLs, as plain arrays (no bpy).

A VPL of flux F on a diffuse surface emits the radiant intensity I(theta) = F cos(theta)/pi
about its normal (Keller 1997, eq. 5). A one-sided Blender area light of power P and area
A has radiance P / (pi A) (docs/radiometry.md), hence the intensity P cos(theta) / pi:
a disk light of power F facing along the VPL normal emits exactly the VPL's lobe.

Its finite radius r also does what clamping does in the gather: on its axis a disk gives
the irradiance F / (pi (d^2 + r^2)) instead of the VPL's singular F / (pi d^2), so with
r = the clamp distance the peak next to the light equals the clamped one (1 / dmin^2).
"""
from dataclasses import dataclass

import numpy as np

# A disk sits this far (times the scene radius) off its surface, so that the surface it
# lies on does not shadow it at grazing angles.
SURFACE_OFFSET = 1e-3
# Smallest disk radius (times the scene radius) when clamping is off: no singular light.
MIN_RADIUS = 1e-4
# In-plane rays per disk when fitting it into free space, and the share of the free
# distance a disk may fill: the gap left to a wall also bounds the Monte Carlo spikes
# when a renderer samples the disk from a point on that wall (0.8 measured best of
# 0.5 / 0.8 / 0.95 on the Cornell box against Cycles).
FIT_PROBES = 12
FIT_MARGIN = 0.8


@dataclass
class BakedLights:
    """One disk light per row, in Blender's conventions (power in W, size = diameter)."""
    location: np.ndarray     # float64 (L, 3)
    rotation: np.ndarray     # float64 (L, 4): quaternion (w, x, y, z), local -Z = normal
    energy: np.ndarray       # float64 (L,): power [W]
    color: np.ndarray        # float64 (L, 3): max component 1
    size: np.ndarray         # float64 (L,): disk diameter
    source_count: int = 0    # VPLs behind these lights
    relative_error: float = 0.0  # flux-weighted estimated clustering error (0: none)

    @property
    def count(self):
        return len(self.energy)

    @staticmethod
    def empty():
        return BakedLights(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0),
                           np.zeros((0, 3)), np.zeros(0))


def quaternion_down_to(normal):
    """Unit quaternions (w, x, y, z) turning the local -Z axis onto each normal:
    the shortest arc q = (1 + a.b, a x b) normalised, with a = -Z, b = normal."""
    n = np.asarray(normal, np.float64).reshape(-1, 3)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    a = np.array([0.0, 0.0, -1.0])
    w = 1.0 + n @ a
    xyz = np.cross(a, n)
    q = np.concatenate([w[:, None], xyz], 1)
    opposite = w < 1e-9                # normal = +Z: half a turn about X
    q[opposite] = (0.0, 1.0, 0.0, 0.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def rotate_down_axis(quaternion):
    """Where each rotation sends local -Z (the direction a Blender light faces)."""
    w, x, y, z = np.asarray(quaternion, np.float64).reshape(-1, 4).T
    # Third column of the rotation matrix of (w, x, y, z), negated.
    return -np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], 1)


def split_power(flux):
    """Blender light power and colour from an RGB flux: energy = max(F), colour = F / max."""
    flux = np.maximum(np.nan_to_num(np.asarray(flux, np.float64).reshape(-1, 3)), 0.0)
    energy = flux.max(1)
    color = flux / np.where(energy > 0, energy, 1.0)[:, None]
    return energy, color


def disk_lights(position, normal, flux, radius, scene_radius, tracer=None):
    """One disk light per emitter with power = flux (see the module docstring).
    `radius` is a scalar or per-light array; emitters without flux are dropped. With a
    `tracer` the disks are fitted into free space (fit_disks)."""
    energy, color = split_power(flux)
    keep = energy > 0
    normal = np.asarray(normal, np.float64).reshape(-1, 3)[keep]
    position = np.asarray(position, np.float64).reshape(-1, 3)[keep]
    radius = np.broadcast_to(np.asarray(radius, np.float64), keep.shape)[keep]
    radius = np.maximum(radius, MIN_RADIUS * scene_radius)
    location = position + normal * (SURFACE_OFFSET * scene_radius)
    if tracer is not None:
        location, radius = fit_disks(tracer, location, normal, radius,
                                     MIN_RADIUS * scene_radius)
    return BakedLights(location, quaternion_down_to(normal), energy[keep], color[keep],
                       2.0 * radius, source_count=len(keep))


def in_plane_directions(normal, count):
    """(L, count, 3) unit directions evenly spread around each normal, in its plane."""
    n = np.asarray(normal, np.float64).reshape(-1, 3)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t = np.cross(n, helper)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    phi = 2 * np.pi * np.arange(count) / count
    return (np.cos(phi)[None, :, None] * t[:, None, :]
            + np.sin(phi)[None, :, None] * b[:, None, :])


def _free_distance(tracer, centre, directions, reach):
    """Distance to the first surface along each in-plane probe, capped at `reach`."""
    count, probes = directions.shape[:2]
    origins = np.repeat(centre, probes, axis=0)
    hits = tracer.intersect(origins, directions.reshape(-1, 3), np.repeat(reach, probes))
    return np.minimum(hits.distance.reshape(count, probes), reach[:, None])


def fit_disks(tracer, centre, normal, radius, min_radius, probes=FIT_PROBES, passes=2):
    """Keep disks from cutting through nearby surfaces: a disk crossing a wall lights it
    from zero distance (a singular hot spot, which the VPL clamp exists to avoid).
    Each pass slides the centre in the disk's plane away from the deepest intrusion
    seen by `probes` rays; then the radius shrinks to the free distance left."""
    directions = in_plane_directions(normal, probes)
    centre = np.array(centre, np.float64)
    rows = np.arange(len(centre))
    reach = radius / FIT_MARGIN                    # keep a small gap to every wall
    for _ in range(passes):
        free = _free_distance(tracer, centre, directions, reach)
        deepest = np.argmin(free, axis=1)
        depth = reach - free[rows, deepest]
        centre -= directions[rows, deepest] * depth[:, None]
    free = _free_distance(tracer, centre, directions, reach).min(1)
    return centre, np.maximum(np.minimum(radius, FIT_MARGIN * free), min_radius)


def cluster_radius(position, flux, labels, centre, count):
    """Radius of a uniform disk with the flux-weighted spread of each cluster's VPLs:
    a disk of radius R has E[r^2] = R^2 / 2, so R = sqrt(2 * weighted mean |p - c|^2)."""
    weight = np.maximum(np.asarray(flux, np.float64).reshape(-1, 3).mean(1), 0.0)
    d2 = ((position - centre[labels]) ** 2).sum(1)
    total = np.bincount(labels, weight, count)
    spread = np.bincount(labels, weight * d2, count) / np.where(total > 0, total, 1.0)
    return np.sqrt(2.0 * spread)


def nearest_member(position, labels, centre, count):
    """Index of each cluster's VPL closest to the cluster centre (a point on a surface:
    a flux-weighted centre can lie inside an object, where its light would be shadowed)."""
    d2 = ((position - centre[labels]) ** 2).sum(1)
    order = np.lexsort((d2, labels))               # by cluster, then by distance
    first = np.ones(len(order), bool)
    first[1:] = labels[order][1:] != labels[order][:-1]
    nearest = np.full(count, -1, np.int64)
    nearest[labels[order][first]] = order[first]
    return nearest


def clustered_disk_lights(vpl_position, vpl_normal, vpl_flux, clusters, radius,
                          scene_radius, tracer=None):
    """One disk light per cluster (Walter 2005): the cluster's total flux, placed at the
    member VPL closest to its centre, facing along the cluster's mean normal, and as
    wide as the cluster's spread (at least `radius`, the clamp distance)."""
    count = len(clusters.flux)
    labels = np.asarray(clusters.labels, np.int64)
    position = np.asarray(vpl_position, np.float64)
    anchor = nearest_member(position, labels, clusters.position, count)
    spread = cluster_radius(position, vpl_flux, labels, clusters.position, count)
    lights = disk_lights(position[anchor], clusters.normal, clusters.flux,
                         np.maximum(spread, radius), scene_radius, tracer)
    lights.source_count = len(position)
    lights.relative_error = flux_weighted_mean(clusters.relative_error, clusters.flux)
    return lights


def flux_weighted_mean(values, flux):
    weight = np.maximum(np.asarray(flux, np.float64).reshape(-1, 3).mean(1), 0.0)
    total = weight.sum()
    return float((np.asarray(values) * weight).sum() / total) if total > 0 else 0.0


def display_colors(flux):
    """Overlay colours (RGBA float32) for VPLs: hue from the flux, brightness
    m / (m + median m) with m = max(flux), so typical VPLs sit mid-range and bright
    ones saturate instead of hiding the rest."""
    energy, color = split_power(flux)
    median = float(np.median(energy)) if len(energy) else 0.0
    brightness = energy / (energy + (median if median > 0 else 1.0))
    rgba = np.ones((len(energy), 4), np.float32)
    rgba[:, :3] = color * brightness[:, None]
    return rgba


def pad_frames(frames):
    """Stack per-frame BakedLights into (F, L, ...) arrays with L = the largest count;
    the missing lights of a frame get zero power at the origin."""
    total = max((f.count for f in frames), default=0)
    shape = len(frames), total
    out = {"location": np.zeros(shape + (3,)), "rotation": np.tile([1.0, 0, 0, 0], shape + (1,)),
           "energy": np.zeros(shape), "color": np.ones(shape + (3,)),
           "size": np.full(shape, 0.0)}
    for i, lights in enumerate(frames):
        n = lights.count
        for name in out:
            out[name][i, :n] = getattr(lights, name)
        if 0 < n < total:
            out["size"][i, n:] = lights.size.min()
    out["size"] = np.where(out["size"] > 0, out["size"], 1e-3)
    return out

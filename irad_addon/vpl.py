"""Classic Instant Radiosity (Keller 1997, sec. 2): particles leave the lights in
proportion to their power and leave a virtual point light at every diffuse bounce."""
from dataclasses import dataclass, field

import numpy as np

from . import geometry, sampling

# Halton dimensions: 6 for the particle's start on its light, 3 per bounce.
_EMIT_DIMS = 6
_BOUNCE_DIMS = 3


@dataclass
class VPLs:
    position: np.ndarray   # float64 (M, 3)
    normal: np.ndarray     # float64 (M, 3), unit, on the side the light arrived from
    flux: np.ndarray       # float64 (M, 3): power the VPL re-emits [W], albedo applied
    bounce: np.ndarray     # int32 (M,): 1 for the first diffuse hit
    # int64 (M,) or None: who each VPL is across the frames of a walkthrough
    # (temporal.PathWindow); its interleaved group follows it.
    identity: np.ndarray = field(default=None, repr=False, compare=False)
    # Structures derived from these VPLs (interleaved subsets, light trees), built once
    # per VPL set and shared by every band and every frame that reuses the set.
    derived: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def count(self):
        return len(self.position)

    @staticmethod
    def empty():
        return VPLs(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int32))

    @staticmethod
    def concatenate(parts):
        """One VPL set of all of `parts` (None and empty sets skipped), in order."""
        parts = [p for p in parts if p is not None and p.count]
        if not parts:
            return VPLs.empty()
        return VPLs(*[np.concatenate([getattr(p, name) for p in parts])
                      for name in ('position', 'normal', 'flux', 'bounce')])

    @property
    def ids(self):
        """Each VPL's identity: `identity`, or by default its index in the set."""
        return self.identity if self.identity is not None else np.arange(self.count)

    def subset(self, mask_or_index):
        return VPLs(self.position[mask_or_index], self.normal[mask_or_index],
                    self.flux[mask_or_index], self.bounce[mask_or_index],
                    None if self.identity is None else self.identity[mask_or_index])


def particles_per_emitter(emitters, particles):
    """Particle counts proportional to each emitter's power, at least one each, so
    that every light's power is estimated by its own particles (unbiased)."""
    power = np.array([e.power().mean() for e in emitters], np.float64)
    share = power / power.sum()
    return np.maximum(1, np.round(share * particles)).astype(np.int64)


def emit_particles(emitters, counts, points):
    """Origins, directions and flux of all particles; `points` are their Halton rows."""
    origins, directions, fluxes = [], [], []
    start = 0
    for emitter, n in zip(emitters, counts):
        o, d, f = emitter.emit(points[start:start + n, :_EMIT_DIMS])
        origins.append(np.asarray(o, np.float64))
        directions.append(np.asarray(d, np.float64))
        fluxes.append(np.asarray(f, np.float64))
        start += n
    return np.concatenate(origins), np.concatenate(directions), np.concatenate(fluxes)


def russian_roulette_survival(albedo):
    """Survival probability at a bounce: the surface's largest reflectivity (as pbrt
    plays roulette on the path's largest channel), so that a survivor's flux, divided
    by it, grows in no channel. Keller 1997's mean albedo boosts the survivors of a
    red wall (0.63, 0.065, 0.05) 2.5x in red: bright, sparse VPLs. Against the mean,
    relMSE falls 12-16% on the Cornell boxes and the sun-lit room for ~15% more VPLs
    (16-20 seeds each, one process)."""
    return np.clip(albedo.max(1), 0.0, 1.0)


def first_bounce_survival(albedo):
    """Every first hit that reflects any light continues: roulette there thins the
    second bounce's VPLs, whose light is most of the VPL set's noise (on the area-lit
    Cornell box, the first bounce's VPLs alone vary 8x less across seeds than all;
    this lowers the whole image's relMSE by a further 2-16% for ~25% more VPLs)."""
    return (albedo.max(1) > 0).astype(np.float64)


def trace_vpls(frame, particles, max_bounces, seed=0, cancel=None, sequence='HALTON',
               batch=0):
    """Shoot `particles` light paths and return their diffuse hits as VPLs. Each
    light's particles get their own block of the low-discrepancy `sequence`; `batch`
    b continues it after b earlier batches (temporal.PathWindow)."""
    if max_bounces < 1 or not frame.emitters or len(frame.triangles) == 0:
        return VPLs.empty()
    dims = _EMIT_DIMS + _BOUNCE_DIMS * max_bounces
    counts = particles_per_emitter(frame.emitters, particles)
    seeds = [seed + 7919 * i for i in range(len(counts))]
    points = np.concatenate([sampling.particle_points(sequence, int(n), _EMIT_DIMS, s, batch)
                             for n, s in zip(counts, seeds)])
    origin, direction, flux = emit_particles(frame.emitters, counts, points)
    bounce_u = sampling.ParticleColumns(sequence, counts, seeds, _EMIT_DIMS, dims, batch)
    return follow_paths(frame, origin, direction, flux, bounce_u, max_bounces, cancel)[0]


def follow_paths(frame, origin, direction, flux, bounce_u, max_bounces, cancel=None):
    """Trace particles (origin, direction, flux) through up to `max_bounces` bounces
    (Keller 1997: a VPL at every diffuse hit, Russian roulette on the albedo, cosine
    bounce; perfect mirrors reflect). bounce_u (n, 3 * max_bounces) holds each path's
    random numbers. Returns the VPLs and the index of the path each came from."""
    path = np.arange(len(origin))
    eps = frame.offset()
    found, owner = [], []
    for bounce in range(1, max_bounces + 1):
        if len(path) == 0 or (cancel and cancel()):
            break
        hits = frame.tracer.intersect(origin, direction)
        keep = hits.hit
        tri, bary = hits.triangle[keep], hits.barycentric[keep]
        path, flux, incoming = path[keep], flux[keep], direction[keep]
        # Surfaces are two-sided: normals face the side the particle came from.
        position, geo, shading, albedo, _ = geometry.surface_hits(frame, tri, bary, incoming)
        vpl_flux = flux * albedo
        stored = vpl_flux.max(1) > 0
        found.append(VPLs(position[stored], shading[stored], vpl_flux[stored],
                          np.full(int(stored.sum()), bounce, np.int32)))
        owner.append(path[stored])
        # Russian roulette, then a cosine-weighted bounce about the shading normal.
        u = bounce_u[path, _BOUNCE_DIMS * (bounce - 1):_BOUNCE_DIMS * bounce]
        q = (first_bounce_survival if bounce == 1 else russian_roulette_survival)(albedo)
        survive = u[:, 0] < q
        local = sampling.square_to_cosine_hemisphere(u[survive, 1:3])
        new_dir = sampling.to_world(local, shading[survive])
        above = np.einsum('ij,ij->i', new_dir, geo[survive]) > 0
        idx = np.flatnonzero(survive)[above]
        new_flux = vpl_flux[idx] / q[idx, None]
        new_dir = new_dir[above]
        if frame.mirror is not None:
            # Perfect mirrors leave no VPL: the particle reflects, its flux times the
            # mirror's reflectance (Keller 1997 sec. 4.2).
            mirror = np.flatnonzero(frame.is_mirror[tri])
            d = incoming[mirror]
            reflected = d - 2 * np.einsum('ij,ij->i', d, geo[mirror])[:, None] * geo[mirror]
            new_dir = np.concatenate([new_dir, reflected])
            new_flux = np.concatenate([new_flux, flux[mirror] * frame.mirror[tri[mirror]]])
            idx = np.concatenate([idx, mirror])
        path, flux, direction = path[idx], new_flux, new_dir
        origin = position[idx] + geo[idx] * eps
    if not found:
        return VPLs.empty(), np.zeros(0, np.int64)
    return VPLs.concatenate(found), np.concatenate(owner)

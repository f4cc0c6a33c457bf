"""Bidirectional Instant Radiosity (Segovia, Iehl, Mitanchey, Peroche 2006).

Candidates come from both ends:
- light-path VPLs: classic IR from half the particles (Keller 1997);
- reverse VPLs: the second vertex y of length-two camera paths (a pilot camera point
  x_k, a cosine-distributed direction, the first hit). Each carries the light y
  reflects: rho(y) E(y) / (M p(y)) (Segovia 2006, sec. 3.2), with p(y) its area density,
  averaged over all pilot points: p(y) = 1/K sum_k cos_k cos_y / (pi d^2) V, and E(y)
  its irradiance: direct light with shadow rays, indirect light path traced from y.
  (Segovia gathers E(y) from the light-path VPLs; where few light paths enter the
  camera's room, that one shared set made every reverse VPL too bright or too dark
  together: in two rooms the image's level varied by +-6% between seeds.)
Both kinds estimate the same last bounce, so they are blended with weights that sum to
one at every surface point (a partition of unity keeps the sum unbiased, Veach 1997
sec. 9.2): reverse VPLs take over where the camera paths are dense. Then N' VPLs are
drawn with probability proportional to the power each brings to the camera and
rescaled by 1 / (N' P_j) (sampling-resampling, Segovia 2006 sec. 3.3), so the
expected flux equals the candidates'.
"""
import numpy as np

from . import direct_light, geometry, sampling, vpl
from .gbuffer import GBuffer, follow_mirrors, take_points, trace_surfaces
from .light_tree import morton_codes
from .variant_choice import camera_importance, camera_pilot, luminance, pair_transfer

PILOT_CAMERA_POINTS = 256
# Reverse VPLs yield to light-path VPLs where their density M p(y) drops below this
# share of the light-path VPLs' mean density N_L / area.
LIGHT_DENSITY_SHARE = 0.3
# Share of the resampling drawn in proportion to the candidates' own power (defensive
# mixture: a VPL no pilot point sees still has a chance, so no pixel loses its light).
DEFENSIVE = 0.1
# Light paths traced per particle of the budget (candidates).
LIGHT_PATHS_PER_PARTICLE = 4
# Reverse vertices per VPL of the budget: a richer pool to resample from (two rooms,
# 128 particles, mean relMSE over seeds 1-16: 2 -> 8 gives 0.032 -> 0.029).
REVERSE_SHARE = 8.0
# Light samples per reverse VPL for its direct light (cheap: M points, not pixels).
REVERSE_LIGHT_SAMPLES = 16
# Indirect part of E(y): paths traced from each reverse VPL, light samples per vertex.
INCIDENT_PATHS = 4
PATH_LIGHT_SAMPLES = 4


def surface_buffer(position, normal, geo_normal, albedo):
    """A G-buffer made of arbitrary surface points, for the gather functions."""
    n = len(position)
    return GBuffer(width=n, height=1, row_start=0, samples=1, pixel=np.arange(n),
                   sample=np.zeros(n, np.int64), hit=np.ones(n, bool), position=position,
                   normal=normal, geo_normal=geo_normal, albedo=albedo,
                   emission=np.zeros((n, 3)), depth=np.zeros(n),
                   object_index=np.zeros(n, np.int32), holdout=np.zeros(n, bool))


def reverse_vertices(frame, pilot, per_point, rng):
    """Second vertices of length-two camera paths: from every pilot point, `per_point`
    cosine-distributed directions about its geometric normal, traced to the first hit.
    Returns the hit surface buffer, the source pilot index and cos_k cos_y / d^2 of the
    own segment (its density term, known without a shadow ray)."""
    source = np.repeat(np.arange(pilot.count), per_point)
    local = sampling.square_to_cosine_hemisphere(rng.random((len(source), 2)))
    direction = sampling.to_world(local, pilot.geo_normal[source])
    origin = pilot.position[source] + pilot.geo_normal[source] * frame.offset()
    hits = frame.tracer.intersect(origin, direction)
    keep = hits.hit
    tri, bary = hits.triangle[keep], hits.barycentric[keep]
    incoming = direction[keep]
    position, geo, shading, albedo, _ = geometry.surface_hits(frame, tri, bary, incoming)
    dist2 = np.maximum(((position - pilot.position[source[keep]]) ** 2).sum(1), 1e-30)
    own = local[keep, 2] * np.abs(np.einsum('ij,ij->i', incoming, geo)) / dist2
    buffer = surface_buffer(position, shading, geo, albedo)
    return buffer, source[keep], own


def incident_irradiance(frame, points, settings, rng):
    """E(y): direct light with shadow rays, plus indirect light path traced from y."""
    samples = max(settings.light_samples, REVERSE_LIGHT_SAMPLES)
    return (direct_light.direct_irradiance(frame, points, samples, rng)
            + path_traced_irradiance(frame, points, INCIDENT_PATHS, settings.max_bounces, rng))


def path_traced_irradiance(frame, points, paths, max_bounces, rng):
    """Indirect irradiance (S, 3) at surface points by path tracing with next-event
    estimation: a cosine-sampled ray estimates E = pi L_in (Kajiya 1986), and at each
    hit z, L_o(z) = rho(z) / pi (E_direct(z) + E_indirect(z)) recurses with Russian
    roulette on rho. Every point gets its own paths, so the errors of the E(y) of
    different reverse VPLs are independent: they average out over the image instead
    of shifting it all, as errors of one shared set of light-path VPLs would (that
    set carries all the light of the rooms few light paths enter)."""
    E = np.zeros((len(points.position), 3))
    owner = np.repeat(np.arange(len(points.position)), paths)
    weight = np.full((len(owner), 3), 1.0 / paths)
    position, normal, geo = (points.position[owner], points.normal[owner],
                             points.geo_normal[owner])
    for _ in range(max_bounces):
        direction = sampling.to_world(
            sampling.square_to_cosine_hemisphere(rng.random((len(owner), 2))), normal)
        up = np.einsum('ij,ij->i', direction, geo) > 0
        owner, weight, direction = owner[up], weight[up], direction[up]
        z = trace_surfaces(frame, position[up] + geo[up] * frame.offset(), direction)
        if frame.mirror is not None:   # perfect mirrors: follow them, lights seen in them
            mirrored, _, seen = follow_mirrors(frame, z, direction, z.distance)
            np.add.at(E, owner, weight * np.pi * seen)
            weight = weight * mirrored
        hit = np.flatnonzero(z.hit)
        z, owner, weight = take_points(z, hit), owner[hit], weight[hit] * z.albedo[hit]
        np.add.at(E, owner, weight * direct_light.direct_irradiance(frame, z, PATH_LIGHT_SAMPLES, rng))
        survive = vpl.russian_roulette_survival(z.albedo)
        live = rng.random(len(owner)) < survive
        owner, weight = owner[live], weight[live] / survive[live, None]
        position, normal, geo = z.position[live], z.normal[live], z.geo_normal[live]
        if len(owner) == 0:
            break
    return E


def resample(flux, importance, count, rng, defensive=DEFENSIVE):
    """Systematic resampling of `count` draws with P_j = (1 - a) q_j / sum q +
    a |flux_j| / sum |flux| (Segovia 2006 sec. 3.3, plus a defensive share a).
    Returns the drawn indices (unique, in random order: sampling.systematic_draws) and
    their flux rescaled by n_j / (count P_j), whose expectation is the candidates' flux."""
    power = luminance(flux)
    p = defensive * power / power.sum()
    if importance.sum() > 0:
        p += (1 - defensive) * importance / importance.sum()
    else:
        p = power / power.sum()
    index, times = sampling.systematic_draws(p, count, rng)
    return index, flux[index] * (times / (count * p[index]))[:, None]


def place_bidirectional(frame, gb, settings, rng):
    """(VPLs, info) for bidirectional IR with `settings.particles` particles' worth of
    VPLs: half from the lights, as many reverse VPLs, N' = all candidates redrawn."""
    pilot = camera_pilot(gb, PILOT_CAMERA_POINTS, rng)
    light = vpl.trace_vpls(frame, LIGHT_PATHS_PER_PARTICLE * settings.particles,
                           settings.max_bounces, seed=settings.seed)
    budget = max(1, light.count // LIGHT_PATHS_PER_PARTICLE)   # classic IR's VPL count
    if pilot.count == 0 or light.count == 0:
        return light, {'reverse_vpls': 0, 'candidates': light.count}
    per_point = max(1, -(-int(REVERSE_SHARE * budget) // pilot.count))
    rev, source, own = reverse_vertices(frame, pilot, per_point, rng)
    M = pilot.count * per_point
    points = np.concatenate([light.position, rev.position])
    normals = np.concatenate([light.normal, rev.geo_normal])
    geo_pilot = camera_pilot_with_geo_normals(pilot)
    transfer = pair_transfer(frame, geo_pilot, points, normals)
    transfer[source, light.count + np.arange(rev.width)] = own
    density = transfer.mean(0) / np.pi                 # p(y), per unit area
    area = float(geometry.triangle_areas(frame.triangles).sum())
    light_density = LIGHT_DENSITY_SHARE * light.count / max(area, 1e-30)
    reverse_weight = M * density / (M * density + light_density)
    E = incident_irradiance(frame, rev, settings, rng)
    reverse_flux = rev.albedo * E / (M * density[light.count:] + light_density)[:, None]
    flux = np.concatenate([light.flux * (1 - reverse_weight[:light.count, None]), reverse_flux])
    candidates = vpl.VPLs(points, np.concatenate([light.normal, rev.normal]), flux,
                          np.concatenate([light.bounce, np.ones(rev.width, np.int32)]))
    # Useful candidates along a space-filling curve: systematic resampling then
    # stratifies the drawn VPLs in space (no clumps and holes left by chance).
    useful = np.flatnonzero(luminance(flux) > 0)
    useful = useful[np.argsort(morton_codes(points[useful]), kind='stable')]
    candidates, transfer = candidates.subset(useful), transfer[:, useful]
    if candidates.count == 0:
        return vpl.VPLs.empty(), {'reverse_vpls': int(rev.width), 'candidates': 0}
    from .render import clamp_distance
    cap = 1.0 / max(clamp_distance(frame, candidates, settings.clamp), 1e-3 * frame.extent) ** 2
    importance = camera_importance(pilot, np.minimum(transfer, cap), candidates.flux)
    index, flux = resample(candidates.flux, importance, budget, rng)
    chosen = candidates.subset(index)
    chosen.flux = flux
    return chosen, {'reverse_vpls': int(rev.width), 'candidates': int(candidates.count)}


def camera_pilot_with_geo_normals(pilot):
    """The pilot with geometric normals: the density of a cosine-sampled direction is
    measured against the normal it was sampled about."""
    from dataclasses import replace
    return replace(pilot, normal=pilot.geo_normal)

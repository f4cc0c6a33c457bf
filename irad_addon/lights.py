"""Light emission in Blender's units, as Cycles renders them (docs/radiometry.md).

Each emitter answers three questions, vectorised over samples:
  power()                        total emitted flux [W], RGB: how many particles it gets
  emit(u)                        particle origins, directions and flux (Keller 1997, sec. 2)
  incident(points, normals, u)   shadow-ray directions, distances and the irradiance
                                 each sample contributes (receiver cosine included)
Area lights also build direct light's shadow segments for all their samples in one
compiled pass (shadow_segments), the same estimator as incident.

Sun and world particles enter the scene through its light portals (portals.py) when it has any
(Cycles' portals: area lights with is_portal, e.g. in windows), otherwise through a
disc or sphere around the whole scene. Portals change only where particles start,
never the light: they do not emit, block or change the direct light.
"""
import numpy as np

from . import geometry, light_sampling, polygon_irradiance, sampling
from .geometry import dot_rows, patch_area, patch_points, unit_rows
from .portals import usable_portals
from .scene_data import AreaLight, PointLight, SpotLight, SunLight

INF_DISTANCE = np.float32(1e30)


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class PointEmitter:
    """Point light: radiant intensity I = P / (4 pi) (a sphere of radius r when r > 0)."""
    delta = True

    def __init__(self, light: PointLight):
        self.position = np.asarray(light.position, np.float64)
        self.intensity = np.asarray(light.color, np.float64) * light.power / (4 * np.pi)
        self.radius = max(float(light.radius), 0.0)
        self.soft_falloff = bool(light.soft_falloff)
        self.delta = self.radius == 0.0

    def attenuation(self, direction_from_light):
        return np.ones(len(direction_from_light))

    def power(self):
        return self.intensity * 4 * np.pi

    def emit(self, u):
        n = len(u)
        direction = sampling.square_to_sphere(u[:, 2:4])
        origin = np.broadcast_to(self.position, (n, 3))
        if self.radius > 0:
            normal = sampling.square_to_sphere(u[:, 0:2])
            origin = origin + normal * self.radius
            direction = sampling.to_world(sampling.square_to_cosine_hemisphere(u[:, 2:4]), normal)
        flux = np.broadcast_to(self.power() / n, (n, 3)) * self.attenuation(direction)[:, None]
        return origin, direction, flux

    def incident(self, points, normals, u):
        to_center, dist = unit_rows(self.position - points)
        if self.radius == 0:
            cos_x = np.maximum(dot_rows(normals, to_center), 0.0)
            e = self.intensity * (cos_x / np.maximum(dist * dist, 1e-30) *
                                  self.attenuation(-to_center))[:, None]
            return to_center, dist, e
        if self.soft_falloff:
            return self._incident_soft(points, normals, u, to_center)
        # Sphere light: uniform sampling of the cone it subtends (pbrt-v4 SphereLight),
        # radiance L = I / (pi r^2) so that it still has intensity I seen from afar.
        radiance = self.intensity / (np.pi * self.radius ** 2)
        sin2 = np.minimum((self.radius / np.maximum(dist, 1e-30)) ** 2, 1.0)
        cos_max = np.sqrt(1.0 - sin2)
        local = sampling.square_to_cone(u, cos_max)
        direction = sampling.to_world(local, to_center)
        solid_angle = 2 * np.pi * (1.0 - cos_max)
        cos_a = local[:, 2]
        # Distance to the near side of the sphere along the sampled direction.
        disc = np.maximum(self.radius ** 2 - (dist ** 2) * (1.0 - cos_a ** 2), 0.0)
        distance = np.maximum(dist * cos_a - np.sqrt(disc), 0.0)
        cos_x = np.maximum(dot_rows(normals, direction), 0.0)
        e = radiance * (cos_x * solid_angle * self.attenuation(-to_center))[:, None]
        return direction, distance, e

    def _incident_soft(self, points, normals, u, to_center):
        """Blender's soft falloff: a disc of radius r at the light that always faces
        the receiver, radiance I / (pi r^2); near the light the irradiance goes
        as 1 / (d^2 + r^2) instead of 1 / d^2 (measured, docs/radiometry.md)."""
        radiance = self.intensity / (np.pi * self.radius ** 2)
        t, s = sampling.orthonormal_basis(to_center)
        disc = sampling.square_to_disk(u) * self.radius
        sample = self.position + disc[:, :1] * t + disc[:, 1:2] * s
        direction, dist = unit_rows(sample - points)
        cos_disc = np.maximum(dot_rows(direction, to_center), 0.0)
        cos_x = np.maximum(dot_rows(normals, direction), 0.0)
        g = cos_disc * cos_x / np.maximum(dist * dist, 1e-30) * np.pi * self.radius ** 2
        return direction, dist, radiance * (g * self.attenuation(-direction))[:, None]


class SpotEmitter(PointEmitter):
    """Spot light: I(theta) = P / (4 pi) * smoothstep(t), no renormalisation to the cone."""

    def __init__(self, light: SpotLight):
        super().__init__(PointLight(light.position, light.color, light.power, light.radius,
                                    light.soft_falloff))
        self.axis, _ = unit_rows(np.asarray(light.direction, np.float64))
        self.cos_half = float(np.cos(min(light.spot_size, np.pi) / 2))
        self.smooth = (1.0 - self.cos_half) * float(light.spot_blend)

    def spot_falloff(self, cos_t):
        if self.smooth <= 0:
            return (cos_t > self.cos_half).astype(np.float64)
        return np.where(cos_t > self.cos_half, smoothstep((cos_t - self.cos_half) / self.smooth), 0.0)

    def attenuation(self, direction_from_light):
        return self.spot_falloff(direction_from_light @ self.axis)

    def power(self):
        # Integrate I(theta) over the cone: a 1D quadrature in cos(theta).
        c = np.linspace(self.cos_half, 1.0, 4097)
        return self.intensity * 2 * np.pi * np.trapz(self.spot_falloff(c), c)

    def emit(self, u):
        n = len(u)
        local = sampling.square_to_cone(u[:, 2:4], self.cos_half)
        direction = sampling.to_world(local, np.broadcast_to(self.axis, (n, 3)))
        pdf = 1.0 / (2 * np.pi * (1.0 - self.cos_half))
        flux = self.intensity * (self.attenuation(direction) / pdf / n)[:, None]
        return np.broadcast_to(self.position, (n, 3)), direction, flux


class AreaEmitter:
    """One-sided Lambertian area light: radiance L = P / (pi A)."""
    delta = False

    def __init__(self, light: AreaLight):
        self.center = np.asarray(light.center, np.float64)
        self.axis_u = np.asarray(light.axis_u, np.float64)
        self.axis_v = np.asarray(light.axis_v, np.float64)
        self.normal, _ = unit_rows(np.asarray(light.normal, np.float64))
        self.ellipse = light.shape == 'ELLIPSE'
        self.area = float(patch_area(self.axis_u, self.axis_v, self.ellipse))
        self.flux = np.asarray(light.color, np.float64) * light.power
        self.radiance = self.flux / (np.pi * self.area) if self.area > 0 else np.zeros(3)

    def power(self):
        return self.flux if self.area > 0 else np.zeros(3)

    def _points(self, u):
        return patch_points(self.center, self.axis_u, self.axis_v, self.ellipse, u)

    def emit(self, u):
        n = len(u)
        origin = self._points(u[:, 0:2])
        direction = sampling.to_world(sampling.square_to_cosine_hemisphere(u[:, 2:4]),
                                      np.broadcast_to(self.normal, (n, 3)))
        return origin, direction, np.broadcast_to(self.power() / n, (n, 3))

    def point_lights(self, count):
        """(positions, normals, flux) of `count` stratified points standing in for the
        light (direct_lightcuts.py), each with 1/count of its flux."""
        position = self._points(sampling.hammersley(count, 2))
        normal = np.tile(self.normal, (count, 1))
        return position, normal, np.tile(self.power() / count, (count, 1))

    def shadow_segments(self, P, N, G, pattern, eps, centre, segments):
        """direct_light.direct_irradiance's segments of every sample at once (compiled)."""
        return light_sampling.patch_segments(P, N, G, pattern, self.center, self.axis_u,
                                             self.axis_v, self.normal, self.ellipse,
                                             self.area, self.radiance, eps, centre, segments)

    def angular_diameter(self, points):
        """The light's angular size (radians, ~ its diagonal over the distance) seen
        from the median of `points`."""
        distance = np.median(np.linalg.norm(points - self.center, axis=1))
        diagonal = 2 * np.sqrt(self.axis_u @ self.axis_u + self.axis_v @ self.axis_v)
        return float(diagonal / max(distance, 1e-30))

    def unoccluded_irradiance(self, P, N, G):
        """(n, 3) irradiance at points P from the whole light, ignoring occlusion, in
        closed form for rectangles (the expectation of shadow_segments' energies);
        None for ellipses."""
        if self.ellipse:
            return None
        factor = polygon_irradiance.rectangle_irradiance_factor(
            P, N, G, self.center, self.axis_u, self.axis_v, self.normal)
        return factor[:, None] * self.radiance

    def incident(self, points, normals, u):
        direction, dist, g = light_sampling.patch_incident(
            points, normals, u, self.center, self.axis_u, self.axis_v, self.normal,
            self.ellipse, self.area)
        return direction, dist, self.radiance * g[:, None]


class SunEmitter:
    """Distant light: irradiance S at normal incidence from a cone of angle `angle`,
    i.e. radiance L = S / (pi sin^2(angle / 2)) (docs/radiometry.md)."""

    def __init__(self, light: SunLight, bounds, portals=None):
        self.direction, _ = unit_rows(np.asarray(light.direction, np.float64))
        self.irradiance = np.asarray(light.color, np.float64) * light.strength
        self.half_angle = min(float(light.angle), np.pi) / 2
        self.cos_half = float(np.cos(self.half_angle))
        self.delta = self.cos_half >= 1.0
        self.center, self.radius = bounds
        self.portals = portals
        self.guide = None   # an emission_guide.EmissionGuide over the disc, if any

    def _directions(self, u):
        if self.delta:
            return np.broadcast_to(self.direction, (len(u), 3)).copy()
        local = sampling.square_to_cone(u, self.cos_half)
        return sampling.to_world(local, np.broadcast_to(self.direction, (len(u), 3)))

    def cone_gain(self):
        """L * solid angle / S for uniform cone sampling: 2 pi (1 - c) / (pi (1 - c^2))
        = 2 / (1 + c); each sampled direction carries S times this (1 for angle 0)."""
        return 1.0 if self.delta else 2.0 / (1.0 + self.cos_half)

    def portal_weights(self):
        """(K,) A cos(theta) of each portal for the cone's best direction, theta from
        its inward normal to the sun's travel: 0 only if no sun direction passes in."""
        cos = np.clip(-(self.portals.normal @ self.direction), -1.0, 1.0)
        best = np.cos(np.maximum(np.arccos(cos) - self.half_angle, 0.0))
        return self.portals.area * np.maximum(best, 0.0)

    def portal_flux(self):
        """(K, 3) flux through each portal: S A E[g max(cos, 0)] over the cone (a
        32 x 32 midpoint quadrature), = S A cos(theta) unless the cone straddles it."""
        if self.delta:
            cos = -(self.portals.normal @ self.direction)
            return self.portals.area[:, None] * np.maximum(cos, 0.0)[:, None] * self.irradiance
        grid = (np.stack(np.meshgrid(np.arange(32), np.arange(32)), -1).reshape(-1, 2) + 0.5) / 32
        cos = -(self._directions(grid) @ self.portals.normal.T)          # (1024, K)
        mean = self.cone_gain() * np.maximum(cos, 0.0).mean(0)
        return (self.portals.area * mean)[:, None] * self.irradiance

    def power(self):
        if self.portals is not None:
            return self.portal_flux().sum(0)
        return self.irradiance * self.cone_gain() * np.pi * self.radius ** 2

    def emit(self, u):
        if self.portals is not None:
            return self._emit_through_portals(u)
        # Particles enter through a disc facing the sun that covers the scene's bounding
        # sphere, so each carries the flux through its share of the disc (divided by
        # the guide's density where one draws the disc: emission_guide.py).
        n = len(u)
        to_sun = self._directions(u[:, 2:4])
        t, s = sampling.orthonormal_basis(to_sun)
        square, share = u[:, 0:2], np.ones(n)
        if self.guide is not None:
            square, density = self.guide.warp(square)
            share = 1.0 / density
        disc = sampling.square_to_disk(square) * self.radius
        origin = self.center + to_sun * (1.01 * self.radius) + disc[:, :1] * t + disc[:, 1:2] * s
        return origin, -to_sun, (self.power() / n) * share[:, None]

    def _emit_through_portals(self, u):
        """Uniform points on portals chosen by projected area, the sun's directions:
        flux L dw A cos / (p_portal n), shared among portals crossed (Portals.lines)."""
        n = len(u)
        weights = self.portal_weights()
        travel = -self._directions(u[:, 2:4])
        origin, travel, index, prob, share = self.portals.lines(weights, u, lambda i: travel)
        cos = np.maximum(dot_rows(travel, self.portals.normal[index]), 0.0)
        carried = self.cone_gain() * self.portals.area[index] * cos * share / (prob * n)
        return origin, travel, self.irradiance * carried[:, None]

    def incident(self, points, normals, u):
        direction = self._directions(u)
        cos_x = np.maximum(dot_rows(normals, direction), 0.0)
        return direction, np.full(len(points), INF_DISTANCE), \
            self.irradiance * (self.cone_gain() * cos_x)[:, None]


class WorldEmitter:
    """Constant background radiance C from every direction."""
    delta = False

    def __init__(self, radiance, bounds, portals=None):
        self.radiance = np.asarray(radiance, np.float64)
        self.center, self.radius = bounds
        self.portals = portals

    def power(self):
        if self.portals is not None:      # L pi A through each portal's inward hemisphere
            return self.radiance * np.pi * self.portals.area.sum()
        # L times the bounding sphere's projected area pi R^2 times 4 pi steradians.
        return self.radiance * 4 * np.pi ** 2 * self.radius ** 2

    def emit(self, u):
        if self.portals is not None:
            return self._emit_through_portals(u)
        n = len(u)
        travel = sampling.square_to_sphere(u[:, 2:4])
        t, s = sampling.orthonormal_basis(travel)
        disc = sampling.square_to_disk(u[:, 0:2]) * self.radius
        origin = self.center - travel * (1.01 * self.radius) + disc[:, :1] * t + disc[:, 1:2] * s
        return origin, travel, np.broadcast_to(self.power() / n, (n, 3))

    def _emit_through_portals(self, u):
        """Portals chosen by area, uniform points, cosine-weighted inward directions:
        L cos dA dw / ((A_k / A) (1 / A_k) (cos / pi)) = L pi A per particle."""
        n = len(u)
        local = sampling.square_to_cosine_hemisphere(u[:, 2:4])
        origin, travel, index, prob, share = self.portals.lines(
            self.portals.area, u, lambda i: sampling.to_world(local, self.portals.normal[i]))
        return origin, travel, self.power() * (share / n)[:, None]

    def incident(self, points, normals, u):
        # Cosine-weighted sampling: L cos / (cos / pi) = pi L per sample.
        direction = sampling.to_world(sampling.square_to_cosine_hemisphere(u), normals)
        return direction, np.full(len(points), INF_DISTANCE), np.broadcast_to(
            np.pi * self.radiance, (len(points), 3))


class EmissiveMeshEmitter:
    """All emissive triangles as one light, sampled in proportion to their power.
    Emission shaders on meshes emit radiance L from both sides."""
    delta = False
    sides = 2.0

    def __init__(self, triangles, radiance, surface_offset=0.0):
        self.triangles = triangles.astype(np.float64)
        self.surface_offset = surface_offset
        self.radiance = np.asarray(radiance, np.float64)
        self.normals = geometry.geometric_normals(self.triangles)
        self.areas = geometry.triangle_areas(self.triangles)
        self.tri_power = self.sides * np.pi * self.areas[:, None] * self.radiance
        weight = self.tri_power.mean(1)
        total = weight.sum()
        self.pick = weight / total if total > 0 else np.full(len(weight), 1.0 / max(len(weight), 1))
        self.cdf = np.cumsum(self.pick)
        self.cdf[-1] = 1.0

    def power(self):
        return self.tri_power.sum(0)

    def _choose(self, u):
        """Pick triangles with the first coordinate and stretch it back to [0, 1)."""
        index = np.minimum(np.searchsorted(self.cdf, u[:, 0], side='right'), len(self.cdf) - 1)
        lo = self.cdf[index] - self.pick[index]
        reused = np.clip((u[:, 0] - lo) / np.maximum(self.pick[index], 1e-30), 0.0, 1.0 - 1e-12)
        return index, np.stack([reused, u[:, 1]], -1)

    def _point(self, index, u):
        b = sampling.square_to_triangle(u)
        t = self.triangles[index]
        return t[:, 0] + b[:, :1] * (t[:, 1] - t[:, 0]) + b[:, 1:2] * (t[:, 2] - t[:, 0])

    def emit(self, u):
        n = len(u)
        index, uv = self._choose(u[:, 0:2])
        origin = self._point(index, uv)
        side = np.where(u[:, 4] < 0.5, 1.0, -1.0)[:, None]
        normal = self.normals[index] * side
        direction = sampling.to_world(sampling.square_to_cosine_hemisphere(u[:, 2:4]), normal)
        flux = self.tri_power[index] / (self.pick[index, None] * n)
        return origin, direction, flux

    def point_lights(self, count):
        """(positions, normals, flux) of 2 x `count` points standing in for the
        triangles (picked by power, stratified), one per side: each side emits half."""
        index, uv = self._choose(sampling.hammersley(count, 2))
        position = self._point(index, uv)
        flux = self.tri_power[index] / (self.pick[index, None] * count) / self.sides
        normal = self.normals[index]
        return (np.concatenate([position, position]), np.concatenate([normal, -normal]),
                np.concatenate([flux, flux]))

    def incident(self, points, normals, u):
        index, uv = self._choose(u)
        direction, dist = unit_rows(self._point(index, uv) - points)
        cos_l = np.abs(dot_rows(self.normals[index], direction))
        cos_x = np.maximum(dot_rows(normals, direction), 0.0)
        pdf_area = self.pick[index] / np.maximum(self.areas[index], 1e-300)
        g = cos_l * cos_x / np.maximum(dist * dist, 1e-30) / pdf_area
        # The emitter is geometry too: stop the shadow ray before its surface, further
        # at grazing angles where the ray runs close to it.
        dist = dist - 2 * self.surface_offset / np.maximum(cos_l, 1e-2)
        return direction, dist, self.radiance[index] * g[:, None]


def build_emitters(scene_lights, triangles, emission, world_radiance, bounds,
                   surface_offset=0.0, portals=()):
    """Emitters for every light with non-zero power, the emissive triangles
    (per-triangle radiance `emission`) and the world. `surface_offset` is the
    tracer's ray offset, for shadow rays that end on emissive geometry. Sun and world
    particles enter through `portals` (scene_data.Portal) when there are any."""
    openings = usable_portals(portals, bounds)
    emitters = []
    for light in scene_lights:
        if isinstance(light, SpotLight):
            e = SpotEmitter(light)
        elif isinstance(light, PointLight):
            e = PointEmitter(light)
        elif isinstance(light, AreaLight):
            e = AreaEmitter(light)
        elif isinstance(light, SunLight):
            e = SunEmitter(light, bounds, openings)
        else:
            continue
        if np.all(np.isfinite(e.power())) and e.power().max() > 0:
            emitters.append(e)
    lit = emission.max(1) > 0 if len(emission) else np.zeros(0, bool)
    if lit.any():
        emitters.append(EmissiveMeshEmitter(triangles[lit], emission[lit], surface_offset))
    world = np.asarray(world_radiance, np.float64)
    if np.all(np.isfinite(world)) and world.max() > 0:
        emitters.append(WorldEmitter(world, bounds, openings))
    return emitters

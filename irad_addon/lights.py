"""Light emission in Blender's units, as Cycles renders them (docs/radiometry.md).

Each emitter answers three questions, vectorised over samples:
  power()                        total emitted flux [W], RGB: how many particles it gets
  emit(u)                        particle origins, directions and flux (Keller 1997, sec. 2)
  incident(points, normals, u)   shadow-ray directions, distances and the irradiance
                                 each sample contributes (receiver cosine included)
"""
import numpy as np

from . import geometry, sampling
from .scene_data import AreaLight, PointLight, SpotLight, SunLight

INF_DISTANCE = np.float32(1e30)


def _dot(a, b):
    return np.einsum('ij,ij->i', a, b)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0), n[..., 0]


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
        to_center, dist = _unit(self.position - points)
        if self.radius == 0:
            cos_x = np.maximum(_dot(normals, to_center), 0.0)
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
        cos_x = np.maximum(_dot(normals, direction), 0.0)
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
        direction, dist = _unit(sample - points)
        cos_disc = np.maximum(_dot(direction, to_center), 0.0)
        cos_x = np.maximum(_dot(normals, direction), 0.0)
        g = cos_disc * cos_x / np.maximum(dist * dist, 1e-30) * np.pi * self.radius ** 2
        return direction, dist, radiance * (g * self.attenuation(-direction))[:, None]


class SpotEmitter(PointEmitter):
    """Spot light: I(theta) = P / (4 pi) * smoothstep(t), no renormalisation to the cone."""

    def __init__(self, light: SpotLight):
        super().__init__(PointLight(light.position, light.color, light.power, light.radius,
                                    light.soft_falloff))
        self.axis, _ = _unit(np.asarray(light.direction, np.float64))
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
        self.normal, _ = _unit(np.asarray(light.normal, np.float64))
        self.ellipse = light.shape == 'ELLIPSE'
        half_u, half_v = np.linalg.norm(self.axis_u), np.linalg.norm(self.axis_v)
        self.area = (np.pi if self.ellipse else 4.0) * half_u * half_v
        self.flux = np.asarray(light.color, np.float64) * light.power
        self.radiance = self.flux / (np.pi * self.area) if self.area > 0 else np.zeros(3)

    def power(self):
        return self.flux if self.area > 0 else np.zeros(3)

    def _points(self, u):
        uv = sampling.square_to_disk(u) if self.ellipse else 2.0 * u - 1.0
        return self.center + uv[:, :1] * self.axis_u + uv[:, 1:2] * self.axis_v

    def emit(self, u):
        n = len(u)
        origin = self._points(u[:, 0:2])
        direction = sampling.to_world(sampling.square_to_cosine_hemisphere(u[:, 2:4]),
                                      np.broadcast_to(self.normal, (n, 3)))
        return origin, direction, np.broadcast_to(self.power() / n, (n, 3))

    def incident(self, points, normals, u):
        direction, dist = _unit(self._points(u) - points)
        cos_l = np.maximum(-(direction @ self.normal), 0.0)
        cos_x = np.maximum(_dot(normals, direction), 0.0)
        g = cos_l * cos_x / np.maximum(dist * dist, 1e-30) * self.area
        return direction, dist, self.radiance * g[:, None]


class SunEmitter:
    """Distant light: irradiance S at normal incidence from a cone of angle `angle`."""

    def __init__(self, light: SunLight, bounds):
        self.direction, _ = _unit(np.asarray(light.direction, np.float64))
        self.irradiance = np.asarray(light.color, np.float64) * light.strength
        self.cos_half = float(np.cos(min(light.angle, np.pi) / 2))
        self.delta = self.cos_half >= 1.0
        self.center, self.radius = bounds

    def _directions(self, u):
        if self.delta:
            return np.broadcast_to(self.direction, (len(u), 3)).copy()
        local = sampling.square_to_cone(u, self.cos_half)
        return sampling.to_world(local, np.broadcast_to(self.direction, (len(u), 3)))

    def power(self):
        return self.irradiance * np.pi * self.radius ** 2

    def emit(self, u):
        # Particles enter through a disc facing the sun that covers the scene's bounding
        # sphere, so each carries the flux through its share of the disc.
        n = len(u)
        to_sun = self._directions(u[:, 2:4])
        t, s = sampling.orthonormal_basis(to_sun)
        disc = sampling.square_to_disk(u[:, 0:2]) * self.radius
        origin = self.center + to_sun * (1.01 * self.radius) + disc[:, :1] * t + disc[:, 1:2] * s
        return origin, -to_sun, np.broadcast_to(self.power() / n, (n, 3))

    def incident(self, points, normals, u):
        direction = self._directions(u)
        cos_x = np.maximum(_dot(normals, direction), 0.0)
        return direction, np.full(len(points), INF_DISTANCE), self.irradiance * cos_x[:, None]


class WorldEmitter:
    """Constant background radiance C from every direction."""
    delta = False

    def __init__(self, radiance, bounds):
        self.radiance = np.asarray(radiance, np.float64)
        self.center, self.radius = bounds

    def power(self):
        return self.radiance * 4 * np.pi ** 2 * self.radius ** 2

    def emit(self, u):
        n = len(u)
        travel = sampling.square_to_sphere(u[:, 2:4])
        t, s = sampling.orthonormal_basis(travel)
        disc = sampling.square_to_disk(u[:, 0:2]) * self.radius
        origin = self.center - travel * (1.01 * self.radius) + disc[:, :1] * t + disc[:, 1:2] * s
        return origin, travel, np.broadcast_to(self.power() / n, (n, 3))

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

    def incident(self, points, normals, u):
        index, uv = self._choose(u)
        direction, dist = _unit(self._point(index, uv) - points)
        cos_l = np.abs(_dot(self.normals[index], direction))
        cos_x = np.maximum(_dot(normals, direction), 0.0)
        pdf_area = self.pick[index] / np.maximum(self.areas[index], 1e-300)
        g = cos_l * cos_x / np.maximum(dist * dist, 1e-30) / pdf_area
        # The emitter is geometry too: stop the shadow ray before its surface, further
        # at grazing angles where the ray runs close to it.
        dist = dist - 2 * self.surface_offset / np.maximum(cos_l, 1e-2)
        return direction, dist, self.radiance[index] * g[:, None]


def build_emitters(scene_lights, triangles, emission, world_radiance, bounds,
                   surface_offset=0.0):
    """Emitters for every light with non-zero power, the emissive triangles
    (per-triangle radiance `emission`) and the world. `surface_offset` is the
    tracer's ray offset, for shadow rays that end on emissive geometry."""
    emitters = []
    for light in scene_lights:
        if isinstance(light, SpotLight):
            e = SpotEmitter(light)
        elif isinstance(light, PointLight):
            e = PointEmitter(light)
        elif isinstance(light, AreaLight):
            e = AreaEmitter(light)
        elif isinstance(light, SunLight):
            e = SunEmitter(light, bounds)
        else:
            continue
        if np.all(np.isfinite(e.power())) and e.power().max() > 0:
            emitters.append(e)
    lit = emission.max(1) > 0 if len(emission) else np.zeros(0, bool)
    if lit.any():
        emitters.append(EmissiveMeshEmitter(triangles[lit], emission[lit], surface_offset))
    world = np.asarray(world_radiance, np.float64)
    if np.all(np.isfinite(world)) and world.max() > 0:
        emitters.append(WorldEmitter(world, bounds))
    return emitters

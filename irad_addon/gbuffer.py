"""The G-buffer: what every camera sample sees (deferred shading's first pass)."""
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import camera as camera_rays_module
from . import geometry
from .lights import AreaEmitter


@dataclass
class GBuffer:
    width: int
    height: int                  # rows in this G-buffer (a band of the image)
    row_start: int               # the band's first image row
    samples: int                 # camera samples per pixel
    pixel: np.ndarray            # int64 (S,): pixel index (row-major, row 0 = top)
    sample: np.ndarray           # int64 (S,): sample index within the pixel
    hit: np.ndarray              # bool (S,)
    position: np.ndarray         # float64 (S, 3)
    normal: np.ndarray           # float64 (S, 3): shading normal, facing the camera
    geo_normal: np.ndarray       # float64 (S, 3): geometric normal, facing the camera
    albedo: np.ndarray           # float64 (S, 3)
    emission: np.ndarray         # float64 (S, 3): radiance emitted towards the camera
    depth: np.ndarray            # float64 (S,): Z depth along the view axis, 1e10 on misses
    object_index: np.ndarray     # int32 (S,), -1 on misses
    holdout: np.ndarray          # bool (S,)
    # float64 (S, 3): product of the mirror reflectances on the way; None: no mirrors seen
    throughput: np.ndarray | None = None
    # float64 (S, 3): radiance of the lights seen in mirrors on the way, each times the
    # reflectances before it; None: no mirrors seen
    mirrored_light: np.ndarray | None = None
    # int64 (pixels,): samples per pixel where pixels have different counts (the film
    # of antialiasing.film_gbuffer); None: `samples` in every pixel
    counts: np.ndarray | None = None

    def pixel_mean(self, values):
        """Average per-sample values (S, C) into (height, width, C) pixels (a box filter)."""
        values = np.ascontiguousarray(values, np.float64).reshape(len(self.pixel), -1)
        out = np.zeros((self.width * self.height, values.shape[1]))
        _add_to_pixels(values, self.pixel, out)
        count = self.samples if self.counts is None else np.maximum(self.counts, 1)[:, None]
        return (out / count).reshape(self.height, self.width, -1)


@njit(cache=True, nogil=True)
def _add_to_pixels(values, pixel, out):
    """out[pixel[i]] += values[i]: every channel in one pass (np.bincount takes one)."""
    for i in range(len(pixel)):
        for c in range(values.shape[1]):   # scalars: a row slice would allocate a view
            out[pixel[i], c] += values[i, c]


@dataclass
class SurfacePoints:
    """Where rays hit: the shading inputs of a deferred pass (misses are zeros)."""
    hit: np.ndarray              # bool (n,)
    triangle: np.ndarray         # int (n,), 0 on misses
    distance: np.ndarray         # float32 (n,), inf on misses
    position: np.ndarray         # float64 (n, 3)
    normal: np.ndarray           # float64 (n, 3): shading normal, facing the ray's origin
    geo_normal: np.ndarray       # float64 (n, 3): geometric normal, facing the ray's origin
    albedo: np.ndarray           # float64 (n, 3)
    emission: np.ndarray         # float64 (n, 3)


def trace_surfaces(frame, origins, directions, tfar=None, smooth_normals=True):
    """Closest hits of rays, with everything shading needs at them (smooth_normals=False:
    the geometric normal stands in for the interpolated one, for coverage samples)."""
    hits = frame.tracer.intersect(origins, directions, tfar)
    hit = hits.hit
    tri = np.where(hit, hits.triangle, 0)   # misses on triangle 0 (zeros for them)
    if len(frame.triangles) == 0:
        zeros = [np.zeros((len(hit), 3)) for _ in range(5)]
        return SurfacePoints(hit, tri, hits.distance, *zeros)
    position, geo, normal, albedo, emission = geometry.surface_hits(
        frame, tri, hits.barycentric, directions, hit, smooth_normals)
    return SurfacePoints(hit, tri, hits.distance, position, normal, geo, albedo, emission)


def build_gbuffer(frame, cam, samples, rng, rows=None, smooth_normals=True, pixels=None):
    """G-buffer of image rows rows = (first, stop), the whole image by default; only
    of `pixels` (indices within the rows) if given."""
    rows = rows or (0, cam.height)
    px, py, pixel, sample = camera_rays_module.pixel_samples(cam.width, rows, samples, rng,
                                                            pixels)
    origins, directions, cos_axis = camera_rays_module.camera_rays(cam, px, py)
    # Clip planes are distances along the view axis (cos_axis is 1 for orthographic).
    near = cam.clip_start / cos_axis
    far = cam.clip_end / cos_axis
    s = trace_surfaces(frame, origins + directions * near[:, None], directions,
                       np.maximum(far - near, 0), smooth_normals)
    length = s.distance + near
    throughput = mirrored_light = None
    if frame.mirror is not None:
        throughput, length, mirrored_light = follow_mirrors(frame, s, directions, length)
    depth = np.where(s.hit, length * cos_axis, 1e10)
    obj = np.full(len(s.hit), -1, np.int32)
    holdout = np.zeros(len(s.hit), bool)
    obj[s.hit] = frame.object_index[s.triangle[s.hit]]
    holdout[s.hit] = frame.holdout[s.triangle[s.hit]]
    return GBuffer(cam.width, rows[1] - rows[0], rows[0], samples, pixel, sample, s.hit,
                   s.position, s.normal, s.geo_normal, s.albedo, s.emission, depth, obj,
                   holdout, throughput, mirrored_light)


# Mirror reflections a camera ray follows before it is cut off (black).
MAX_MIRROR_BOUNCES = 8


def follow_mirrors(frame, points, directions, length):
    """Continue rays that hit perfect mirrors along their reflection (Keller 1997
    sec. 4.2 handles the light side; the camera side is a specular chain): `points`
    are updated in place to the first non-mirror hit. Returns the throughput (n, 3)
    (product of mirror reflectances), the path length (n,) and the radiance (n, 3) of
    the lights seen in the mirrors, each times the reflectances before it."""
    throughput = np.ones((len(points.hit), 3))
    length = np.asarray(length, np.float64).copy()
    directions = np.array(directions, np.float64)
    seen = np.zeros((len(points.hit), 3))   # lights in the mirrors, times the throughput
    is_mirror = frame.is_mirror
    for _ in range(MAX_MIRROR_BOUNCES + 1):
        on_mirror = np.flatnonzero(points.hit & is_mirror[points.triangle])
        if len(on_mirror) == 0:
            break
        if _ == MAX_MIRROR_BOUNCES:   # still between mirrors: give up, black
            throughput[on_mirror] = 0.0
            break
        n = points.geo_normal[on_mirror]
        d = directions[on_mirror]
        reflected = d - 2 * np.einsum('ij,ij->i', d, n)[:, None] * n
        throughput[on_mirror] *= frame.mirror[points.triangle[on_mirror]]
        origin = points.position[on_mirror] + n * frame.offset()
        after = trace_surfaces(frame, origin, reflected)
        seen[on_mirror] += throughput[on_mirror] * light_radiance_along(
            frame.emitters, origin, reflected, after.distance)
        length[on_mirror] += after.distance
        for name in SurfacePoints.__dataclass_fields__:
            getattr(points, name)[on_mirror] = getattr(after, name)
        directions[on_mirror] = reflected
    return throughput, length, seen


def light_radiance_along(emitters, origins, directions, tfar):
    """Radiance (n, 3) of the area lights that rays origin + t direction, 0 < t < tfar,
    pass through from their emitting side. Lights do not block rays: Cycles adds a
    light's radiance to what lies behind it (docs/radiometry.md); camera rays do not
    see lights, rays reflected by mirrors do (the lights' glossy visibility)."""
    L = np.zeros((len(origins), 3))
    for emitter in emitters:
        if isinstance(emitter, AreaEmitter) and emitter.area > 0:
            L[area_light_hit(emitter, origins, directions, tfar)] += emitter.radiance
    return L


def area_light_hit(light, origins, directions, tfar):
    """bool (n,): rays that cross the front of a rectangle or ellipse area light."""
    facing = directions @ light.normal
    safe = np.where(facing < 0, facing, -1.0)
    t = (light.center - origins) @ light.normal / safe
    offset = origins + t[:, None] * directions - light.center
    # Coordinates along the half-extent axes, in [-1, 1] on the light.
    a = offset @ light.axis_u / (light.axis_u @ light.axis_u)
    b = offset @ light.axis_v / (light.axis_v @ light.axis_v)
    inside = (a * a + b * b <= 1) if light.ellipse else (np.abs(a) <= 1) & (np.abs(b) <= 1)
    return (facing < 0) & (t > 0) & (t < tfar) & inside


def take_points(points, index):
    """The rows `index` of a SurfacePoints."""
    return SurfacePoints(*[getattr(points, f)[index] for f in SurfacePoints.__dataclass_fields__])

"""The G-buffer: what every camera sample sees (deferred shading's first pass)."""
from dataclasses import dataclass

import numpy as np

from . import camera as camera_rays_module
from . import geometry


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

    def pixel_mean(self, values):
        """Average per-sample values (S, C) into (height, width, C) pixels (a box filter)."""
        values = values.reshape(len(self.pixel), -1)
        count = self.width * self.height
        out = np.stack([np.bincount(self.pixel, weights=values[:, c], minlength=count)
                        for c in range(values.shape[1])], -1)
        return (out / self.samples).reshape(self.height, self.width, -1)


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


def trace_surfaces(frame, origins, directions, tfar=None):
    """Closest hits of rays, with everything shading needs at them."""
    hits = frame.tracer.intersect(origins, directions, tfar)
    hit = hits.hit
    n = len(hit)
    tri = np.where(hit, hits.triangle, 0)
    points = SurfacePoints(hit, tri, hits.distance, *[np.zeros((n, 3)) for _ in range(5)])
    if hit.any():
        t, bary = tri[hit], hits.barycentric[hit]
        geo = geometry.face_forward(frame.geo_normals[t], -np.asarray(directions)[hit])
        points.geo_normal[hit] = geo
        points.position[hit] = geometry.surface_points(frame.triangles, t, bary)
        points.normal[hit] = geometry.face_forward(
            geometry.shading_normals(frame.corner_normals, t, bary, geo), geo)
        points.albedo[hit] = frame.albedo[t]
        points.emission[hit] = frame.emission[t]
    return points


def build_gbuffer(frame, cam, samples, rng, rows=None):
    """G-buffer of image rows rows = (first, stop), the whole image by default."""
    rows = rows or (0, cam.height)
    px, py, pixel, sample = camera_rays_module.pixel_samples(cam.width, rows, samples, rng)
    origins, directions, cos_axis = camera_rays_module.camera_rays(cam, px, py)
    # Clip planes are distances along the view axis (cos_axis is 1 for orthographic).
    near = cam.clip_start / cos_axis
    far = cam.clip_end / cos_axis
    s = trace_surfaces(frame, origins + directions * near[:, None], directions,
                       np.maximum(far - near, 0))
    depth = np.where(s.hit, (s.distance + near) * cos_axis, 1e10)
    obj = np.full(len(s.hit), -1, np.int32)
    holdout = np.zeros(len(s.hit), bool)
    obj[s.hit] = frame.object_index[s.triangle[s.hit]]
    holdout[s.hit] = frame.holdout[s.triangle[s.hit]]
    return GBuffer(cam.width, rows[1] - rows[0], rows[0], samples, pixel, sample, s.hit,
                   s.position, s.normal, s.geo_normal, s.albedo, s.emission, depth, obj,
                   holdout)


def take_points(points, index):
    """The rows `index` of a SurfacePoints."""
    return SurfacePoints(*[getattr(points, f)[index] for f in SurfacePoints.__dataclass_fields__])

"""The G-buffer: what every camera sample sees (deferred shading's first pass)."""
from dataclasses import dataclass

import numpy as np

from . import camera as camera_rays_module
from . import geometry


@dataclass
class GBuffer:
    width: int
    height: int
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


def build_gbuffer(frame, cam, samples, rng):
    px, py, pixel, sample = camera_rays_module.pixel_samples(cam.width, cam.height, samples, rng)
    origins, directions, cos_axis = camera_rays_module.camera_rays(cam, px, py)
    # Clip planes are distances along the view axis (cos_axis is 1 for orthographic).
    near = cam.clip_start / cos_axis
    far = cam.clip_end / cos_axis
    start = origins + directions * near[:, None]
    hits = frame.tracer.intersect(start, directions, np.maximum(far - near, 0))
    hit = hits.hit
    n = len(px)
    tri = np.where(hit, hits.triangle, 0)
    position = np.zeros((n, 3))
    normal = np.zeros((n, 3))
    geo = np.zeros((n, 3))
    albedo = np.zeros((n, 3))
    emission = np.zeros((n, 3))
    depth = np.full(n, 1e10)
    obj = np.full(n, -1, np.int32)
    holdout = np.zeros(n, bool)
    if hit.any():
        t, bary = tri[hit], hits.barycentric[hit]
        to_camera = -directions[hit]
        position[hit] = geometry.surface_points(frame.triangles, t, bary)
        geo[hit] = geometry.face_forward(frame.geo_normals[t], to_camera)
        normal[hit] = geometry.face_forward(
            geometry.shading_normals(frame.corner_normals, t, bary, geo[hit]), geo[hit])
        albedo[hit] = frame.albedo[t]
        emission[hit] = frame.emission[t]
        depth[hit] = (hits.distance[hit] + near[hit]) * cos_axis[hit]
        obj[hit] = frame.object_index[t]
        holdout[hit] = frame.holdout[t]
    return GBuffer(cam.width, cam.height, samples, pixel, sample, hit, position, normal, geo,
                   albedo, emission, depth, obj, holdout)

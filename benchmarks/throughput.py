"""Throughput ceiling: our VPL gather against raw Embree occlusion queries on the very
same shadow rays, both measured in one run.

The gather (irad_addon.gather.start_indirect, which render.render_frame starts on the
worker threads for every image band) is instrumented from outside: start_indirect is
wrapped to run each band's gather to its end before the render goes on, so it runs
alone on the pool and its wall time is the gather's; group_irradiance is wrapped to
count pixel-VPL pairs, and the frame's RayTracer.occluded to record every shadow-ray
batch traced meanwhile. The clamp compensation, which gathers VPLs at its own points
beside the render thread's other work, is off here. The recorded batches are then
replayed through a bare embreex scene built from the same triangles (no numpy work, no
wrapper): once on one thread, once on a pool with one thread per core, as the gather
uses.
"""
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import bpy
import numpy as np

from benchmarks import scenes

RESOLUTION = 96
TARGET_RAYS = 4_000_000      # shadow rays per measured gather (~112 MB recorded)
QUICK_TARGET_RAYS = 1_000_000
REPEATS = 3
MOST_PARTICLES = 1 << 20
# Core RenderSettings per configuration; one whose field does not exist yet is skipped.
# A missing field set to False is fine: a feature that does not exist is off.
# The exhaustive gather traces every pair's ray; the default shadow-ray budget skips most
# (its pairs cost their term without a ray, so its rays/s count those terms too).
CONFIGS = {"exhaustive gather": {"use_lightcuts": False, "shadow_ray_budget": 0.0},
           "gather, default shadow-ray budget": {"use_lightcuts": False},
           "lightcuts": {"use_lightcuts": True}}
# Every configuration: the gather alone (bias_compensation's own gather is left out).
COMMON = {"bias_compensation": False}


class GatherProbe:
    """Wraps the core's gather and the tracer's occlusion queries while installed."""

    def __init__(self, core):
        self.core = core
        self.gather_seconds = []
        self.pairs = []
        self.recording = False
        self.batches = []
        self._in_gather = False
        self._lock = threading.Lock()

    def __enter__(self):
        gather = self.core.gather
        self._start, self._groups = gather.start_indirect, gather.group_irradiance
        probe = self

        def start(*args, **kwargs):   # once per image band: its gather, run to the end
            probe._in_gather = True
            t = time.perf_counter()
            try:
                pending = probe._start(*args, **kwargs)
                pending.wait()   # done now; the render's own wait returns at once
                return pending
            finally:
                probe.gather_seconds[-1] += time.perf_counter() - t
                probe._in_gather = False

        def groups(samples, pairs, *rest, **kwargs):
            if probe._in_gather:
                with probe._lock:
                    probe.pairs[-1] += pairs
            return probe._groups(samples, pairs, *rest, **kwargs)

        gather.start_indirect, gather.group_irradiance = start, groups
        return self

    def __exit__(self, *exc):
        self.core.gather.start_indirect = self._start
        self.core.gather.group_irradiance = self._groups

    def wrap_tracer(self, tracer):
        original = type(tracer).occluded.__get__(tracer)

        def occluded(origins, directions, tfar, threads=True, local=False):
            if self.recording and self._in_gather:
                # Recorded in the tracer's local frame, as Embree sees them.
                start = (np.array(origins, np.float32) if local
                         else tracer.to_local(origins))
                batch = (start, np.array(directions, np.float32),
                         np.broadcast_to(np.asarray(tfar, np.float32), (len(origins),)).copy())
                with self._lock:
                    self.batches.append(batch)
            return original(origins, directions, tfar, threads=threads, local=local)

        tracer.occluded = occluded

    def render(self, data, settings, cache):
        """One frame; its gather time and pair count are summed over all bands."""
        self.pairs.append(0)
        self.gather_seconds.append(0.0)
        return self.core.render.render_frame(data, settings, tracer_cache=cache)


def raw_embree_seconds(triangles, batches, threads):
    """Wall time of OCCLUDED queries on the recorded batches through bare embreex."""
    from embreex import mesh_construction, rtcore_scene
    scene = rtcore_scene.EmbreeScene(robust=True)   # the same traversal mode as rays.py
    mesh_construction.TriangleMesh(scene, np.ascontiguousarray(triangles, np.float32))
    scene.run(batches[0][0][:16], batches[0][1][:16], dists=batches[0][2][:16].copy(),
              query='OCCLUDED')   # builds the BVH lazily on the first query
    jobs = [(o, d, t.copy()) for o, d, t in batches]

    def one(job):
        return scene.run(job[0], job[1], dists=job[2], query='OCCLUDED')

    started = time.perf_counter()
    if threads == 1:
        blocked = [one(job) for job in jobs]
    else:
        with ThreadPoolExecutor(threads) as pool:
            blocked = list(pool.map(one, jobs))
    seconds = time.perf_counter() - started
    return seconds, int(sum(int((b >= 0).sum()) for b in blocked))


def measure_config(core, data, name, fields, target_rays):
    defaults = core.render.RenderSettings()
    missing = [k for k, v in fields.items() if not hasattr(defaults, k) and v is not False]
    if missing:
        return {"config": name, "skipped": missing}
    fields = {k: v for k, v in {**COMMON, **fields}.items() if hasattr(defaults, k)}
    cache = core.rays.RayTracerCache()
    with GatherProbe(core) as probe:
        pilot = probe.render(data, core.render.RenderSettings(**fields, particles=256), cache)
        pairs_per_vpl = probe.pairs[-1] / max(pilot.stats["vpls"], 1)
        # The pilot's shadow rays (per shading sample, as the render counts them) set
        # the particle count that traces about target_rays.
        pilot_rays = (pilot.stats.get("shadow_rays_per_point", 0.0) * defaults.aa_samples
                      * data.camera.width * data.camera.height)
        particles = min(MOST_PARTICLES, max(16, int(256 * target_rays / max(pilot_rays, 1))))
        settings = core.render.RenderSettings(**fields, particles=particles)
        probe.wrap_tracer(cache._tracer)
        probe.recording = True
        result = probe.render(data, settings, cache)
        probe.recording = False
        batches = probe.batches
        if not batches:
            return {"config": name, "skipped": ["the gather traced no rays through "
                                                "gather.start_indirect"]}
        for _ in range(REPEATS):   # timed without recording
            probe.render(data, settings, cache)
        gather_seconds = min(probe.gather_seconds[-REPEATS:])
        pairs = probe.pairs[-1]
    rays = sum(len(b[0]) for b in batches)
    tracer = cache._tracer
    triangles = tracer.to_local(tracer.triangles.reshape(-1, 3)).reshape(tracer.triangles.shape)
    workers = core.rays.worker_count()
    raw1 = min(raw_embree_seconds(triangles, batches, 1)[0] for _ in range(REPEATS))
    raws = [raw_embree_seconds(triangles, batches, workers) for _ in range(REPEATS)]
    raw_n = min(s for s, _ in raws)
    return {"config": name, "particles": particles, "vpls": result.stats["vpls"],
            "pixels": int(data.camera.width * data.camera.height), "pairs": int(pairs),
            "pairs_per_vpl": pairs_per_vpl, "shadow_rays": int(rays), "batches": len(batches),
            "blocked_fraction": raws[0][1] / max(rays, 1), "workers": workers,
            "gather_seconds": gather_seconds, "raw_seconds_1_thread": raw1,
            "raw_seconds": raw_n,
            "gather_rays_per_second": rays / gather_seconds,
            "gather_pairs_per_second": pairs / gather_seconds,
            "raw_rays_per_second_1_thread": rays / raw1,
            "raw_rays_per_second": rays / raw_n,
            "ratio": raw_n / gather_seconds}


def run(addon, quick=False):
    core = addon.irad_addon
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = scenes.cornell_box("AREA", RESOLUTION)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    target = QUICK_TARGET_RAYS if quick else TARGET_RAYS
    out = []
    for name, fields in CONFIGS.items():
        row = measure_config(core, data, name, fields, target)
        out.append(row)
        if "skipped" in row:
            print(f"  throughput {name}: skipped ({row['skipped']})", flush=True)
        else:
            print(f"  throughput {name}: {row['shadow_rays']} rays, gather "
                  f"{row['gather_rays_per_second'] / 1e6:.2f} Mrays/s, raw Embree "
                  f"{row['raw_rays_per_second'] / 1e6:.2f} Mrays/s ({row['workers']} threads),"
                  f" ratio {row['ratio']:.2f}", flush=True)
    return {"scene": f"cornell_box AREA {RESOLUTION} x {RESOLUTION}", "cpu_count": os.cpu_count(),
            "configs": out}

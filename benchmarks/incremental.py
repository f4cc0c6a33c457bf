"""Incremental IR (Laine 2007) against rebuilding every VPL, per animation frame.

A point light circles for 30 frames; each frame both place their VPLs for the new
light position through variants.place_vpls (what the engine calls), interleaved frame
by frame so both see the same machine load: incremental IR with its state carried
across frames, classic IR with the scene's fixed seed (the default) and with a new seed
per frame (Animated Seed). Frame 0 (incremental builds everything) is left out.
Reported per scene and particle count: median wall and CPU time per frame and the rays
traced per frame, and their ratios classic / incremental.

Whole frames: the same animations rendered end to end (render.render_frame, the camera
still), where incremental IR also keeps its VPLs' transfer to the camera's samples
(transfer_reuse.py) and traces shadow rays only for its new VPLs; every ray of a frame
is counted (camera, lights, placement, gather, clamp compensation).
"""
import math
import time
from dataclasses import replace

import bpy
import numpy as np

from benchmarks import scenes

FRAMES = 30
PARTICLES = (1024, 2048, 4096)
QUICK_PARTICLES = (1024,)
RENDER_PARTICLES = (2048, 8192)   # whole frames (the default is 2048)
QUICK_RENDER_PARTICLES = (2048,)
KINDS = (("incremental", 'INCREMENTAL', None), ("classic", 'CLASSIC', 0),
         ("classic, animated seed", 'CLASSIC', "frame"))


def point_lit(build, position):
    """A scene of `build()` lit only by one point light (no other lights, black world)."""
    def make():
        scene = build()
        for ob in [o for o in scene.objects if o.type == 'LIGHT']:
            bpy.data.objects.remove(ob)
        scenes.world(scene, (0.0, 0.0, 0.0), 0.0)
        scenes.light(scene, "POINT", 100.0, position)
        return scene
    return make


SCENES = (
    ("Cornell box, point light (34 triangles)", lambda: scenes.cornell_box("POINT", 64),
     0.3, 0.8),
    ("room with a window (interior)", point_lit(lambda: scenes.sunlit_room(48), (0.0, 0.0, 1.8)),
     1.0, 1.8),
    ("high-poly: floor and 4 spheres (1M triangles)",
     point_lit(lambda: scenes.high_poly(1_000_000), (0.0, -1.0, 2.0)), 1.0, 2.0),
)


def orbit(light, radius, height, frame):
    """The light's position at `frame`: a circle of `radius` at `height`."""
    t = 0.03 * frame
    return replace(light, position=np.array([radius * math.cos(t), radius * math.sin(t),
                                             height]))


def measure(core, data, radius, height, particles):
    """Per-frame wall seconds, CPU seconds and rays of each kind."""
    cache = core.rays.RayTracerCache()
    light = data.lights[0]
    state = core.variants.VariantState()
    out = {label: {"wall": [], "cpu": [], "rays": []} for label, _, _ in KINDS}
    for i in range(FRAMES):
        frame = core.frame.prepare_frame(
            replace(data, lights=[orbit(light, radius, height, i)]), cache)
        for label, variant, seed in KINDS:
            counting = core.rays.CountingTracer(frame.tracer)
            settings = core.render.RenderSettings(
                particles=particles, variant=variant, seed=i if seed == "frame" else 0)
            wall, cpu = time.perf_counter(), time.process_time()
            core.variants.place_vpls(replace(frame, tracer=counting), None, settings,
                                     state if variant == 'INCREMENTAL' else None)
            out[label]["wall"].append(time.perf_counter() - wall)
            out[label]["cpu"].append(time.process_time() - cpu)
            out[label]["rays"].append(counting.rays)
    return {"triangles": len(frame.triangles),
            **{label: {key: float(np.median(values[1:])) for key, values in series.items()}
               for label, series in out.items()}}


def measure_frames(core, data, radius, height, particles):
    """Whole frames: per-frame wall seconds and rays of each kind, and the mean of each
    kind's indirect pass over the frames relative to classic's (both unbiased)."""
    out = {}
    for label, variant, seed in KINDS:
        tracers, state = core.rays.CountingTracerCache(), core.variants.VariantState()
        wall, frame_rays, level = [], [], []
        for i in range(FRAMES):
            settings = core.render.RenderSettings(
                particles=particles, variant=variant, seed=i if seed == "frame" else 0)
            start = time.perf_counter()
            result = core.render.render_frame(
                replace(data, lights=[orbit(data.lights[0], radius, height, i)]), settings,
                tracer_cache=tracers, variant_state=state)
            wall.append(time.perf_counter() - start)
            frame_rays.append(tracers.tracer.rays)
            level.append(float(result.passes["IRAD Indirect"].mean()))
        out[label] = {"wall": float(np.median(wall[1:])), "rays": float(np.median(frame_rays[1:])),
                      "first": wall[0], "indirect": float(np.mean(level))}
    classic = out["classic"]["indirect"]
    for label in out:
        out[label]["indirect"] /= classic
    return out


def run(addon, quick=False):
    core = addon.irad_addon
    rows, frame_rows = [], []
    for title, build, radius, height in SCENES[:1] if quick else SCENES:
        bpy.ops.wm.read_homefile(use_empty=True)
        build()
        data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
        for particles in QUICK_PARTICLES if quick else PARTICLES:
            print(f"  incremental: {title}, {particles} particles", flush=True)
            result = measure(core, data, radius, height, particles)
            rows.append({"scene": title, "particles": particles, **result})
        if title.startswith("high-poly"):
            continue   # whole frames: the two interiors (the 1M-triangle scene is slow)
        cam = data.camera
        for particles in QUICK_RENDER_PARTICLES if quick else RENDER_PARTICLES:
            print(f"  incremental, whole frames: {title}, {particles} particles", flush=True)
            frame_rows.append({"scene": title, "particles": particles,
                               "resolution": f"{cam.width}x{cam.height}",
                               **measure_frames(core, data, radius, height, particles)})
    return {"frames": FRAMES, "rows": rows, "frame_rows": frame_rows}

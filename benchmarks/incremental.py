"""Incremental IR (Laine 2007) against rebuilding every VPL, per animation frame.

A point light circles for 30 frames; each frame both place their VPLs for the new
light position through variants.place_vpls (what the engine calls), interleaved frame
by frame so both see the same machine load: incremental IR with its state carried
across frames, classic IR with the scene's fixed seed (the default) and with a new seed
per frame (Animated Seed). Frame 0 (incremental builds everything) is left out.
Reported per scene and particle count: median wall and CPU time per frame and the rays
traced per frame, and their ratios classic / incremental.
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


def run(addon, quick=False):
    core = addon.irad_addon
    rows = []
    for title, build, radius, height in SCENES[:1] if quick else SCENES:
        bpy.ops.wm.read_homefile(use_empty=True)
        build()
        data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
        for particles in QUICK_PARTICLES if quick else PARTICLES:
            print(f"  incremental: {title}, {particles} particles", flush=True)
            result = measure(core, data, radius, height, particles)
            rows.append({"scene": title, "particles": particles, **result})
    return {"frames": FRAMES, "rows": rows}

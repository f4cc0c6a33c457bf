"""Path frames (Keller 1997 sec. 4.3): what gathering the paths of the last N frames
buys a walkthrough, against the Cycles reference of the area-lit Cornell box.

For each window size N and shadow-ray budget, frames 0..N+1 of a still camera are
rendered in one process through render.render_frame with a temporal.PathWindow (what
the engine keeps between the frames of an animation). Reported, as means over SEEDS:
- relMSE of frame N (the window just full) against the cached Cycles reference;
- median time of the frames filling the window, and of the frames after (reused);
- flicker with an animated seed (the window slides every frame): RMS of the change of
  the indirect pass between consecutive full-window frames over the RMS of the pass.

    .venv/bin/python benchmarks/walkthrough.py     # writes benchmarks/report/walkthrough.md
"""
import os
import sys
import time
from dataclasses import replace

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from benchmarks import addon_install  # noqa: E402

addon_install.prepare_user_resources()   # before `import bpy`

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import error_vs_time, metrics  # noqa: E402

SCENE = "cornell_area"
WINDOWS = (1, 2, 4, 8)
BUDGET_FACTORS = (1, 4)   # the default shadow-ray budget, and 4x it
SEEDS = (0, 1, 2, 3)


def walk(core, data, settings, frames, animated_seed=False):
    """Results of frames 0..frames-1 rendered with one path window."""
    window, results = core.temporal.PathWindow(), []
    for number in range(frames):
        step = replace(settings, seed=settings.seed + number) if animated_seed else settings
        start = time.perf_counter()
        result = core.render.render_frame(data, step, path_window=window,
                                          frame_number=number)
        result.seconds = time.perf_counter() - start
        results.append(result)
    return results


def flicker(results):
    """RMS change of the indirect pass between consecutive frames over its RMS."""
    indirect = np.array([r.passes["IRAD Indirect"] for r in results])
    return float(np.sqrt(np.mean(np.diff(indirect, axis=0) ** 2) / np.mean(indirect ** 2)))


def measure(core, data, reference, settings, frames_kept):
    errors, filling, full, flickers, vpls = [], [], [], [], 0
    for seed in SEEDS:
        base = replace(settings, seed=seed, temporal_frames=frames_kept)
        results = walk(core, data, base, frames_kept + 2)
        errors.append(metrics.relmse(results[frames_kept - 1].passes["Combined"][..., :3],
                                     reference))
        filling += [r.seconds for r in results[:frames_kept]]
        full += [r.seconds for r in results[frames_kept:]]
        vpls = results[frames_kept - 1].stats["vpls"]
        sliding = walk(core, data, replace(base, seed=100 * seed), frames_kept + 3, True)
        flickers.append(flicker(sliding[frames_kept - 1:]))
    return {"relmse": float(np.mean(errors)), "filling": float(np.median(filling)),
            "full": float(np.median(full)), "flicker": float(np.mean(flickers)),
            "vpls": vpls}


def main():
    addon = addon_install.enable_extension()
    core = addon.irad_addon
    bench = next(s for s in error_vs_time.SCENES if s.name == SCENE)
    reference, _ = error_vs_time.scene_reference(bench)
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bench.build()
    scene.render.engine = error_vs_time.ENGINE
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    settings = core.engine.render_settings(scene)
    lines = [f"# Path frames: {bench.title}", "",
             f"Still camera, default settings but for the budget; means over seeds "
             f"{list(SEEDS)}; `benchmarks/walkthrough.py`.", "",
             "| path frames N | shadow-ray budget | VPLs | relMSE at frame N "
             "| s per frame, filling | s per frame, full | flicker, animated seed |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for budget in (factor * settings.shadow_ray_budget for factor in BUDGET_FACTORS):
        for frames_kept in WINDOWS:
            row = measure(core, data, reference, replace(settings, shadow_ray_budget=budget),
                          frames_kept)
            lines.append(f"| {frames_kept} | {budget:.0f} | {row['vpls']} | "
                         f"{row['relmse']:.2e} | {row['filling']:.3f} | {row['full']:.3f} | "
                         f"{row['flicker']:.3f} |")
            print(lines[-1], flush=True)
    path = os.path.join(ROOT, "benchmarks", "report", "walkthrough.md")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

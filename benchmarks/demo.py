"""`make demo`: render the Cornell box with Instant Radiosity and with Cycles, compare.

One bpy process: enables the checkout as the extension (benchmarks/addon_install.py),
renders scenes.cornell_box("AREA", 192) with our engine at its default settings,
loads (or, on the first run, renders: a few minutes) a Cycles reference of
2 x 1024 spp cached under .cache/references/, and times Cycles at low sample counts.

Writes out/demo.png (ours), out/demo_cycles.png (reference), out/demo_side_by_side.png
(ours | Cycles | relative error) and out/demo_report.md, which is printed too.
PNGs use Blender's 'Standard' view transform: linear -> sRGB, clipped to [0, 1].
"""
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)  # for `from benchmarks import ...`; the add-on comes from bl_ext only

from benchmarks import addon_install  # noqa: E402

addon_install.prepare_user_resources()  # before `import bpy`

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import metrics, reference, scenes  # noqa: E402
from benchmarks.error_vs_time import fresh_bvh  # noqa: E402

OUT = os.path.join(ROOT, "out")
RESOLUTION = 192
REF_SPP = 1024           # per seed; the reference is the mean of two seeds (2048 spp)
REF_SEEDS = (0, 1)
CYCLES_RUNS = [          # (label, spp, denoise)
    ("1 spp + OpenImageDenoise", 1, True),
    ("16 spp", 16, False),
    ("64 spp", 64, False),
]


def build_scene():
    bpy.ops.wm.read_homefile(use_empty=True)
    return scenes.cornell_box("AREA", RESOLUTION)


# ------------------------------------------------------------------ our engine
def render_ours(addon):
    """Render with INSTANT_RADIOSITY at default settings; (image, seconds, stats)."""
    scene = build_scene()
    scene.render.engine = addon_install.ENGINE
    reference._neutral_colour(scene)  # same film / colour settings as the Cycles renders
    settings = {name: getattr(scene.irad, name) for name in
                ("variant", "particles", "max_bounces", "clamp", "aa_samples", "coverage_samples",
                 "light_samples", "shadow_ray_budget", "seed")}
    # The engine shows its stats (VPL count) only in the render window; record them
    # by wrapping the core's render_frame, which engine.py calls as render.render_frame.
    core = addon.irad_addon.render
    captured = []
    original = core.render_frame

    def recording(*args, **kwargs):
        result = original(*args, **kwargs)
        captured.append(dict(result.stats))
        return result

    core.render_frame = recording
    fresh_bvh(addon)   # the warm-up's BVH and VPLs (same box, same settings) are not reused
    try:
        image, seconds = reference.timed_render(scene)
    finally:
        core.render_frame = original
    if captured:
        stats = captured[-1]
    else:  # engine.py no longer goes through the module attribute: run the core again
        data = addon.irad_addon.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
        stats = dict(original(data, addon.irad_addon.engine.render_settings(scene)).stats)
    return image, seconds, settings, stats


def warm_up(addon):
    """One small render with each engine first, as `make bench` does: a process's first
    render loads compiled kernels (numba's, Cycles') and starts thread pools."""
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = scenes.cornell_box("AREA", 16)
    scene.render.engine = addon_install.ENGINE
    reference.timed_render(scene)
    render_cycles(1, True)


# ---------------------------------------------------------------------- Cycles
def cycles_reference():
    """Mean of two cached references and the estimated relMSE of that mean."""
    images = []
    for seed in REF_SEEDS:
        scene = build_scene()
        t0 = time.perf_counter()
        images.append(reference.cycles_reference(scene, REF_SPP, seed=seed))
        seconds = time.perf_counter() - t0
        if seconds > 5:
            print(f"rendered Cycles reference seed {seed} ({REF_SPP} spp) in {seconds:.0f} s",
                  flush=True)
    ref = np.mean(images, axis=0, dtype=np.float64).astype(np.float32)
    return ref, metrics.reference_relmse(*images)


def render_cycles(spp, denoise):
    scene = build_scene()
    reference.configure_cycles(scene, spp, seed=0, denoise=denoise)
    if denoise:
        scene.cycles.denoiser = 'OPENIMAGEDENOISE'
    return reference.timed_render(scene)


# ---------------------------------------------------------------------- images
def to_srgb(linear):
    """Blender's 'Standard' view transform for an sRGB display: clip, sRGB OETF."""
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def luminance(image):
    return np.asarray(image, np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def save_png(path, linear):
    import matplotlib.pyplot as plt
    plt.imsave(path, to_srgb(linear).astype(np.float32))


def save_side_by_side(path, ours, ref, ours_label, ref_label):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    lum_ref = luminance(ref)
    rel = (luminance(ours) - lum_ref) / np.maximum(lum_ref, 1e-3)
    fig, axes = plt.subplots(1, 3, figsize=(12.6, 4.6),
                             gridspec_kw={"width_ratios": [1, 1, 1.1]})
    axes[0].imshow(to_srgb(ours))
    axes[0].set_title(ours_label, fontsize=10)
    axes[1].imshow(to_srgb(ref))
    axes[1].set_title(ref_label, fontsize=10)
    im = axes[2].imshow(rel, cmap="RdBu_r", vmin=-0.5, vmax=0.5)
    axes[2].set_title("relative error (ours - Cycles) / Cycles, luminance", fontsize=10)
    from matplotlib.ticker import PercentFormatter
    fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.03, format=PercentFormatter(1.0))
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ---------------------------------------------------------------------- report
def fmt(x, spec):
    return "-" if x is None else format(x, spec)


def report_markdown(rows, ours_seconds, ref_relmse, stats, scene_desc):
    lines = [
        "# Instant Radiosity demo",
        "",
        f"Scene: {scene_desc}. Machine: {os.cpu_count()} CPU threads, "
        f"Blender (bpy) {bpy.app.version_string}, Cycles on CPU.",
        f"Reference: Cycles {len(REF_SEEDS)} x {REF_SPP} spp (box filter, no clamping, "
        f"32 bounces), estimated relMSE of the reference itself {ref_relmse:.1e}.",
        "Errors are against that reference; time is the wall clock of "
        "bpy.ops.render.render (including writing the EXR), after one warm-up render of "
        "each engine.",
        "",
        "| engine | settings | time [s] | VPLs | relMSE | RMSE | rel. bias | "
        "time ours / this |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        ratio = None if r["seconds"] is None else ours_seconds / r["seconds"]
        lines.append("| {} | {} | {} | {} | {} | {} | {} | {} |".format(
            r["engine"], r["settings"], fmt(r["seconds"], ".2f"),
            r.get("vpls", "-"), fmt(r["relmse"], ".4f"), fmt(r["rmse"], ".4f"),
            fmt(r["bias"], "+.2%"), fmt(ratio, ".2f")))
    lines += [
        "",
        "Instant Radiosity internal timings [s]: " + ", ".join(
            f"{k[5:]} {v:.2f}" for k, v in stats.items() if k.startswith("time_"))
        + f" (total {stats['time']:.2f}); {stats['triangles']} triangles, "
        f"clamp distance {stats['clamp_distance']:.3f}.",
        "",
    ]
    return "\n".join(lines)


def main():
    t_start = time.perf_counter()
    os.makedirs(OUT, exist_ok=True)
    addon = addon_install.enable_extension()

    warm_up(addon)
    ours, ours_seconds, settings, stats = render_ours(addon)
    ref, ref_relmse = cycles_reference()
    rows = [dict(engine="Instant Radiosity",
                 settings="defaults: " + ", ".join(f"{k} {v:g}" if isinstance(v, float)
                                                   else f"{k} {v}"
                                                   for k, v in settings.items()),
                 seconds=ours_seconds, vpls=stats["vpls"], **metrics.summary(ours, ref))]
    for label, spp, denoise in CYCLES_RUNS:
        image, seconds = render_cycles(spp, denoise)
        rows.append(dict(engine="Cycles", settings=label, seconds=seconds,
                         **metrics.summary(image, ref)))
    rows.append(dict(engine="Cycles (reference)",
                     settings=f"{len(REF_SEEDS)} x {REF_SPP} spp, cached",
                     seconds=None, relmse=ref_relmse, rmse=None, bias=None))

    save_png(os.path.join(OUT, "demo.png"), ours)
    save_png(os.path.join(OUT, "demo_cycles.png"), ref)
    ours_row = rows[0]
    save_side_by_side(
        os.path.join(OUT, "demo_side_by_side.png"), ours, ref,
        f"Instant Radiosity, defaults ({ours_seconds:.1f} s, {stats['vpls']} VPLs)\n"
        f"relMSE {ours_row['relmse']:.4f}, bias {ours_row['bias']:+.1%}",
        f"Cycles reference ({len(REF_SEEDS) * REF_SPP} spp)\n")

    text = report_markdown(rows, ours_seconds, ref_relmse, stats,
                           f'benchmarks.scenes.cornell_box("AREA", {RESOLUTION}), '
                           f'{RESOLUTION} x {RESOLUTION} px')
    with open(os.path.join(OUT, "demo_report.md"), "w") as fh:
        fh.write(text)
    print()
    print(text)
    print(f"wrote out/demo.png, out/demo_cycles.png, out/demo_side_by_side.png, "
          f"out/demo_report.md ({time.perf_counter() - t_start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

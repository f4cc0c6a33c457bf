"""The benchmark report: Markdown tables and matplotlib PNG plots from the results of
benchmarks/run_all.py (results.json in the report folder).

    python benchmarks/report.py [report_dir]   # re-render README.md and plots from JSON
"""
import json
import math
import os
import sys

import numpy as np

TARGETS = (0.01, 0.003)
HEADLINE_SCENE = "cornell_area"
DEFAULT_METHOD = "ours: default"
CYCLES, OIDN = "Cycles", "Cycles + OIDN"


# ------------------------------------------------------------------ analysis
def curve(runs, method):
    """(seconds, relMSE) of one method's runs in ladder order (particles or spp).
    Load from other processes only ever slows a run down, and a rung never costs more
    than a bigger rung of the same ladder, so each time is replaced by the smallest time
    at or above its rung (a running minimum from the top): spikes cannot fold the curve."""
    rows = sorted((r.get("particles", r.get("spp", 0)), r["seconds"], r["relmse"])
                  for r in runs if r["method"] == method)
    points = np.array([row[1:] for row in rows], dtype=np.float64).reshape(-1, 2)
    points[:, 0] = np.minimum.accumulate(points[::-1, 0])[::-1]
    return points


def time_to_reach(points, target):
    """Time a method needs for relMSE <= target, interpolated linearly on the log-log
    curve between the last point above and the first point below the target (the
    first crossing along the ladder).
    Returns (seconds, note): note '<=' when the cheapest run is already below (the
    time is then that run's: an upper bound), None and 'not reached' when no run is."""
    for i, (t, e) in enumerate(points):
        if e <= target:
            if i == 0:
                return t, "<="
            t0, e0 = points[i - 1]
            f = (math.log(target) - math.log(e0)) / (math.log(e) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t) - math.log(t0))), ""
    return None, "not reached"


def methods(runs):
    seen = []
    for r in runs:
        if r["method"] not in seen:
            seen.append(r["method"])
    return seen


def ours_at_default(scene_result):
    """Our default configuration at the default particle count (the run users get): the
    median time of its repeated runs (error_vs_time.DEFAULT_REPEATS; the same image each
    time), then taken as `curve` takes every time, the competitor's too: the least of
    its own and the bigger rungs' (a load spike on one run cannot set the ratio)."""
    rows = [r for r in scene_result["runs"] if r["method"] == DEFAULT_METHOD]
    default = scene_result.get("default_particles")
    exact = [r for r in rows if r.get("particles") == default]
    if not exact:
        return None
    median = float(np.median([r["seconds"] for r in exact]))   # the repeated runs'
    bigger = [r["seconds"] for r in rows if r.get("particles", 0) > default]
    return {**exact[0], "seconds": min([median] + bigger), "raw_seconds": median,
            "repeats": len(exact)}


def equal_error_ratio(scene_result, competitor=OIDN):
    """time(ours, default settings) / time(competitor to reach the same relMSE)."""
    ours = ours_at_default(scene_result)
    if ours is None:
        return None
    points = curve(scene_result["runs"], competitor)
    t, note = time_to_reach(points, ours["relmse"])
    out = {"relmse": ours["relmse"], "ours": ours["seconds"], "raw": ours["raw_seconds"],
           "repeats": ours.get("repeats", 1), "competitor": t, "note": note,
           "ratio": None if t is None else ours["seconds"] / t}
    if t is None and len(points):
        # The competitor's last rung is still above our relMSE: it needs longer than
        # that rung took, so the ratio is below ours / that time.
        out["competitor_floor"], out["competitor_floor_relmse"] = points[-1]
        out["ratio_bound"] = ours["seconds"] / points[-1][0]
    return out


def fmt_competitor(eq):
    """Cycles + OIDN's time to our relMSE, or what its last rung shows when none reaches it."""
    if "ratio_bound" in eq:
        return (f"more than {eq['competitor_floor']:.2f} s (its last rung is still at relMSE "
                f"{eq['competitor_floor_relmse']:.4f})")
    return fmt_time((eq["competitor"], eq["note"]))


def fmt_equal_error_ratio(eq):
    if "ratio_bound" in eq:
        return f"< {eq['ratio_bound']:.2f}"
    return fmt(eq["ratio"], ".2f")


def target_table(scene_result):
    """{method: {target: (seconds, note)}} for every method of a scene."""
    runs = scene_result["runs"]
    return {m: {target: time_to_reach(curve(runs, m), target) for target in TARGETS}
            for m in methods(runs)}


# ------------------------------------------------------------------ formatting
def fmt_time(value):
    seconds, note = value
    if seconds is None:
        return note
    return ("≤ " if note == "<=" else "") + f"{seconds:.2f} s"


def fmt_ratio(a, b):
    if a[0] is None or b[0] is None:
        return "–"
    bound = " (bound)" if "<=" in (a[1], b[1]) else ""
    return f"{a[0] / b[0]:.2f}{bound}"


def fmt(x, spec, empty="–"):
    return empty if x is None else format(x, spec)


# ------------------------------------------------------------------ plots
def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_error_vs_time(scene_result, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.6))
    runs = scene_result["runs"]
    for method in methods(runs):
        pts = curve(runs, method)
        style = "s--" if method.startswith("Cycles") else "o-"
        ax.loglog(pts[:, 0], pts[:, 1], style, label=method, markersize=4)
    for target in TARGETS:
        ax.axhline(target, color="grey", lw=0.8, ls=":")
        ax.text(ax.get_xlim()[0], target, f" {target:g}", va="bottom", fontsize=8, color="grey")
    ax.set_xlabel("wall time of the render call [s]")
    ax.set_ylabel("relMSE against the reference")
    ax.set_title(scene_result["title"], fontsize=10)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def to_srgb(linear):
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def save_image_strip(path, labelled_images):
    """Side by side, Blender's 'Standard' view transform (clipped sRGB)."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(labelled_images), figsize=(3 * len(labelled_images), 3.7))
    for ax, (label, image) in zip(np.atleast_1d(axes), labelled_images):
        ax.imshow(to_srgb(image), interpolation="nearest")
        ax.set_title(label, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_scaling(points, x_key, x_label, path, title, series_key=None):
    """Render time, BVH build time and peak RSS against x (log-log)."""
    plt = _plt()
    fig, (ax, ax_mem) = plt.subplots(1, 2, figsize=(10, 4))
    groups = points if isinstance(points, dict) else {"render": points}
    for name, rows in groups.items():
        rows = [r for r in rows if "seconds" in r]
        if not rows:
            continue
        x = [r[x_key] for r in rows]
        ax.loglog(x, [r["seconds"] for r in rows], "o-", label=f"render ({name})")
        if x_key == "triangles":
            ax.loglog(x, [r["bvh_seconds"] for r in rows], "s--", label="BVH build alone")
            ax.loglog(x, [r["extract_seconds"] for r in rows], "^:", label="extraction alone")
        ax_mem.semilogx(x, [r["peak_rss_mb"] for r in rows], "o-", label=f"peak RSS ({name})")
        ax_mem.semilogx(x, [r["rss_before_render_mb"] for r in rows], "x:",
                        label=f"RSS before render ({name})")
    for a, ylabel in ((ax, "seconds"), (ax_mem, "MB")):
        a.set_xlabel(x_label)
        a.set_ylabel(ylabel)
        a.grid(True, which="both", alpha=0.25)
        a.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ------------------------------------------------------------------ markdown
def headline(results):
    lines = ["## Headline", ""]
    scene = next((s for s in results.get("error_vs_time", [])
                  if s["scene"] == HEADLINE_SCENE), None)
    if scene is not None:
        table = target_table(scene)
        ours = table.get(DEFAULT_METHOD)
        lines.append(f"{scene['title']}, time to reach relMSE 0.01 (wall time of the render "
                     "call, interpolated on the log-log error curve, all measured in this run):")
        lines.append("")
        for m in (DEFAULT_METHOD, CYCLES, OIDN):
            if m in table:
                lines.append(f"- {m}: **{fmt_time(table[m][0.01])}**")
        if ours:
            lines.append(f"- ours / Cycles: **{fmt_ratio(ours[0.01], table[CYCLES][0.01])}**, "
                         f"ours / (Cycles + OIDN): **{fmt_ratio(ours[0.01], table[OIDN][0.01])}**")
        eq = equal_error_ratio(scene)
        if eq:
            lines.append(f"- At default settings ours reaches relMSE {eq['relmse']:.4f} in "
                         f"{eq['ours']:.2f} s; Cycles + OIDN needs "
                         f"{fmt_competitor(eq)} for the same relMSE: "
                         f"ratio **{fmt_equal_error_ratio(eq)}** (the project's headline "
                         "figure, target ≤ 0.5)")
    tp = [c for c in results.get("throughput", {}).get("configs", []) if "ratio" in c]
    for c in tp:
        lines.append(f"- Gather throughput ({c['config']}): "
                     f"{c['gather_rays_per_second'] / 1e6:.2f} M shadow rays/s vs raw Embree "
                     f"{c['raw_rays_per_second'] / 1e6:.2f} M rays/s on the same rays: "
                     f"**{100 * c['ratio']:.0f}%** of the ray tracer's own speed")
    return lines + [""]


def error_section(results):
    lines = ["## Error against time", "",
             "Each point is one render of the scene; time is the wall clock of "
             "`bpy.ops.render.render` (scene translation, BVH build, rendering, writing the "
             "EXR) for every engine: our engine's BVH cache is cleared before each run. "
             "Cycles: CPU, no clamping, no light threshold, 32 bounces, box filter, "
             "adaptive sampling off, ladder seed independent of the reference seeds. "
             "Cycles + OIDN: OpenImageDenoise with albedo and normal passes, prefilter "
             "Accurate. Our engine: `scene.irad` defaults with the named settings, particle "
             "count varied. relMSE = mean((x - ref)² / (ref² + 0.01)), bias = Σx / Σref - 1.",
             "Times to a target are interpolated on the log-log curve (each run's time "
             "replaced by the least time of the same or a bigger rung of its ladder, so a "
             "load spike cannot fold the curve; the table of all runs shows raw times); "
             "'≤' marks a method "
             "whose cheapest run already beats the target (its time is an upper bound), "
             "'not reached' one whose best run does not.", ""]
    for scene in results.get("error_vs_time", []):
        lines += _scene_section(scene)
    return lines


def _scene_section(scene):
    name = scene["scene"]
    oidn = scene["oidn"]
    lines = [f"### {scene['title']}", "",
             f"![error vs time](error_vs_time_{name}.png)", "",
             f"Reference: Cycles, mean of 2 seeds, {scene['reference_spp']} spp in total; its "
             f"own relMSE (estimated from the two halves) {scene['reference_relmse']:.1e}"
             + ("" if scene["reference_relmse"] < 1e-4 else " (**above the 1e-4 goal**)") + ". "
             f"OIDN check at 1 spp: relMSE {oidn['relmse_1spp']:.3g} raw, "
             f"{oidn['relmse_1spp_oidn']:.3g} denoised ("
             + ("denoiser verified active" if oidn["denoised"] else "**denoiser had no effect**")
             + ").", ""]
    if os.path.exists(scene.get("strip_path", "")):
        lines += [f"![images]({os.path.basename(scene['strip_path'])})", ""]
    table = target_table(scene)
    lines += ["| method | time to relMSE 0.01 | time to relMSE 0.003 | ours/Cycles @0.01 | "
              "ours/(Cycles+OIDN) @0.01 | ours/Cycles @0.003 | ours/(Cycles+OIDN) @0.003 |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for m, row in table.items():
        cells = [fmt_time(row[0.01]), fmt_time(row[0.003])]
        if m.startswith("ours"):
            for target in TARGETS:
                cells += [fmt_ratio(row[target], table[CYCLES][target]),
                          fmt_ratio(row[target], table[OIDN][target])]
        else:
            cells += ["", "", "", ""]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    eq = equal_error_ratio(scene)
    if eq:
        lines += ["", f"At default settings ours: relMSE {eq['relmse']:.4f} in {eq['ours']:.2f} s"
                  f" (its {eq['repeats']} runs' median: {eq['raw']:.2f} s; as every time here, the"
                  f" least of its rung and the bigger ones); Cycles + OIDN to the same relMSE: "
                  f"{fmt_competitor(eq)}; ratio {fmt_equal_error_ratio(eq)}."]
    for skip in scene.get("skipped_configs", []):
        lines.append(f"- skipped configuration '{skip['config']}': this build has no "
                     f"`scene.irad` setting {', '.join(skip['missing'])}")
    for m in scene.get("cut_by_time_limit", []):
        lines.append(f"- {m}: ladder stopped where the next rung would pass the per-run "
                     "time limit (BENCH_TIME_LIMIT)")
    lines += ["", "<details><summary>all runs</summary>", "",
              "| method | particles / spp | VPLs | time [s] | relMSE | RMSE | bias |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for r in sorted(scene["runs"], key=lambda r: (r["method"], r["seconds"])):
        knob = r.get("particles", r.get("spp"))
        lines.append(f"| {r['method']} | {knob} | {r.get('vpls') or ''} | {r['seconds']:.2f} | "
                     f"{r['relmse']:.2e} | {r['rmse']:.4f} | {r['bias']:+.2%} |")
    return lines + ["", "</details>", ""]


def scaling_section(results):
    sc = results.get("scaling")
    if not sc:
        return []
    lines = ["## Scaling", "",
             "Each point is a separate process (peak RSS = VmHWM, the high-water resident set of "
             "that process, which includes bpy itself and the scene's Blender data; 'before' "
             "is the RSS just before the render call). Render time is the whole render call "
             "at default settings; BVH build = `irad_addon.rays.RayTracer(triangles)` alone; "
             "extraction = depsgraph → SceneData alone.", ""]
    parts = [("triangles", "triangles", "triangle count (high_poly, 64 x 64)",
              "scaling_triangles.png"),
             ("vpls", "vpls", "VPL count (Cornell box, area light, 64 x 64)",
              "scaling_vpls.png"),
             ("resolution", "pixels", "pixels (Cornell box, area light, default settings)",
              "scaling_resolution.png")]
    for key, x_key, label, png in parts:
        data = sc.get(key)
        if not data:
            continue
        lines += [f"### Time against {label}", "", f"![{key}]({png})", "",
                  "| config | triangles | VPLs | pixels | render [s] | BVH build [s] | "
                  "extraction [s] | RSS before [MB] | peak RSS [MB] |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        groups = data if isinstance(data, dict) else {"default": data}
        for name, rows in groups.items():
            for r in rows:
                if "seconds" not in r:
                    why = r.get("error") or f"skipped: no setting {', '.join(r['skipped'])}"
                    lines.append(f"| {name} | | | | {why[:120]} | | | | |")
                    continue
                lines.append(f"| {name} | {r['triangles']} | {r['vpls']} | {r['pixels']} | "
                             f"{r['seconds']:.2f} | {r['bvh_seconds']:.3f} | "
                             f"{r['extract_seconds']:.3f} | {r['rss_before_render_mb']:.0f} | "
                             f"{r['peak_rss_mb']:.0f} |")
        lines.append("")
    return lines


def throughput_section(results):
    tp = results.get("throughput")
    if not tp:
        return []
    lines = ["## Throughput ceiling", "",
             f"Scene: {tp['scene']}. The gather's shadow rays were recorded batch by batch "
             "and replayed through a bare embreex scene (same triangles, robust traversal) "
             "with the same batches: on one thread and on one thread per core (as the gather "
             f"runs). Best of several repeats each, same run. {tp['cpu_count']} CPU threads. "
             "Each band's gather (`gather.start_indirect`) runs to its end alone on the "
             "pool before the render goes on, and the clamp compensation (whose own gather "
             "runs beside the render thread's other work) is off, so the gather's wall time "
             "and rays are its own. "
             "Pairs are the pixel-VPL pairs `gather.group_irradiance` evaluates (the "
             "exhaustive gather; a lightcut evaluates cut nodes through its own code). "
             "Particles are chosen per configuration for a few million shadow rays.", "",
             "| config | VPLs | pixel-VPL pairs | shadow rays | gather [s] | gather Mpairs/s | "
             "gather Mrays/s | raw Embree 1 thread Mrays/s | raw Embree Mrays/s | "
             "gather / raw |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for c in tp["configs"]:
        if "skipped" in c:
            lines.append(f"| {c['config']} | skipped: {', '.join(c['skipped'])} "
                         "| | | | | | | | |")
            continue
        lines.append(f"| {c['config']} | {c['vpls']} | {c['pairs']} | {c['shadow_rays']} | "
                     f"{c['gather_seconds']:.2f} | {c['gather_pairs_per_second'] / 1e6:.2f} | "
                     f"{c['gather_rays_per_second'] / 1e6:.2f} | "
                     f"{c['raw_rays_per_second_1_thread'] / 1e6:.2f} | "
                     f"{c['raw_rays_per_second'] / 1e6:.2f} | {100 * c['ratio']:.0f}% |")
    return lines + [""]


def incremental_section(results):
    inc = results.get("incremental")
    if not inc:
        return []
    lines = ["## Incremental IR per animation frame", "",
             f"benchmarks/incremental.py: a point light circles for {inc['frames']} frames; "
             "each frame, variants.place_vpls places the VPLs for the new light position: "
             "incremental IR (Laine 2007, its sites carried across frames) and classic IR "
             "rebuilding every VPL with the fixed seed (the default) or a new seed per frame "
             "(Animated Seed), interleaved frame by frame. Median per frame, frame 0 left "
             "out; CPU time includes the ray tracer's threads.", "",
             "| scene | particles | incremental ms | classic ms | animated seed ms | "
             "classic / incremental (wall) | (CPU) | rays per frame: incremental / classic "
             "| ratio |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in inc["rows"]:
        i, c, a = r["incremental"], r["classic"], r["classic, animated seed"]
        lines.append(
            f"| {r['scene']} | {r['particles']} | {1e3 * i['wall']:.1f} | "
            f"{1e3 * c['wall']:.1f} | {1e3 * a['wall']:.1f} | **{c['wall'] / i['wall']:.2f}** "
            f"| {c['cpu'] / i['cpu']:.2f} | {i['rays']:.0f} / {c['rays']:.0f} | "
            f"{c['rays'] / max(i['rays'], 1):.1f} |")
    lines += [""] + frames_table(inc.get("frame_rows", []))
    return lines + [""]


def frames_table(rows):
    """The whole-frame rows of the incremental section."""
    if not rows:
        return []
    lines = ["Whole frames (render.render_frame, camera still, default settings): incremental "
             "IR also keeps its VPLs' transfer to the camera's samples and traces shadow rays "
             "only for its new VPLs (transfer_reuse.py). Median per frame, frame 0 left out "
             "(its time in the last column); rays: every ray of the frame; indirect level: "
             "mean of the indirect pass over the 30 frames relative to classic's.", "",
             "| scene | resolution | particles | incremental ms | classic ms | animated seed ms "
             "| classic / incremental (wall) | rays per frame: incremental / classic | ratio "
             "| indirect level (incremental) | first frame ms (incremental / classic) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        i, c, a = r["incremental"], r["classic"], r["classic, animated seed"]
        lines.append(
            f"| {r['scene']} | {r['resolution']} | {r['particles']} | {1e3 * i['wall']:.0f} | "
            f"{1e3 * c['wall']:.0f} | {1e3 * a['wall']:.0f} | **{c['wall'] / i['wall']:.2f}** | "
            f"{i['rays']:.0f} / {c['rays']:.0f} | {c['rays'] / max(i['rays'], 1):.1f} | "
            f"{i['indirect']:.3f} | {1e3 * i['first']:.0f} / {1e3 * c['first']:.0f} |")
    return lines


def stolen_note(machine):
    """'; N% of the CPU time stolen by the hypervisor' when the run measured it."""
    stolen = machine.get("stolen")
    return "" if stolen is None else f"; {100 * stolen:.0f}% of the CPU time stolen by the host"


def write(results, out_dir):
    """README.md and the plots; returns the README path."""
    for scene in results.get("error_vs_time", []):
        plot_error_vs_time(scene, os.path.join(out_dir, f"error_vs_time_{scene['scene']}.png"))
    sc = results.get("scaling") or {}
    for key, x_key, label in (("triangles", "triangles", "triangles"),
                              ("vpls", "vpls", "VPLs"), ("resolution", "pixels", "pixels")):
        if sc.get(key):
            plot_scaling(sc[key], x_key, label, os.path.join(out_dir, f"scaling_{key}.png"),
                         f"Scaling against {label}")
    m = results["machine"]
    lines = ["# Instant Radiosity benchmarks", "",
             f"Generated by `make bench` ({results['mode']} run) on {m['date']}: "
             f"{m['cpu_count']} CPU threads, Blender (bpy) {m['blender']}, "
             f"code {m['commit']}. This run: {results['seconds'] / 60:.1f} min.", "",
             f"> **Machine load caveat.** This 2-core machine is a shared virtual machine "
             f"(load average {m['load_start']} at the start, {m['load_end']} at the end, "
             f"this run's own renders included{stolen_note(m)}), so absolute timings are "
             "noisy. Compare ratios measured in this same run (runs of all methods are "
             "interleaved round-robin per scene), not absolute seconds.", ""]
    kept = results.get("kept_sections")
    if kept:
        lines += ["Sections kept from earlier runs (`BENCH_SECTIONS` reran the others): "
                  + "; ".join(f"{k} from the run of {r['date']} ({r['minutes']:.1f} min, load "
                              f"average {r['load']})" for k, r in kept.items())
                  + f". The other sections are from this run ({m['date']}).", ""]
    lines += headline(results) + error_section(results) + scaling_section(results)
    lines += throughput_section(results) + incremental_section(results)
    path = os.path.join(out_dir, "README.md")
    with open(path, "w") as fh:
        fh.write("\n".join(lines))
    return path


if __name__ == "__main__":
    folder = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "report")
    with open(os.path.join(folder, "results.json")) as fh:
        print(write(json.load(fh), folder))

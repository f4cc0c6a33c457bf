"""`make bench`: error against time, scaling and throughput; writes the report.

Environment:
  BENCH_QUICK=1        smoke run (< 5 min once references are cached): Cornell box only,
                       short ladders; writes out/bench-quick/ unless BENCH_OUT is set
  BENCH_OUT=dir        report folder (default benchmarks/report)
  BENCH_SECTIONS=...   comma list of error,scaling,throughput,incremental (default
                       all); the sections not run are kept from the folder's last
                       results.json
  BENCH_SCENES=...     comma list of error_vs_time.SCENES names (default all; quick:
                       cornell_area)
  BENCH_TIME_LIMIT=s   a ladder stops before a rung predicted (linearly) to take longer
                       than this (default 60 s)

References are Cycles renders cached under .cache/references/: the first full run
renders them (about an hour on 2 cores); later runs take ~30 minutes.
"""
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from benchmarks import addon_install  # noqa: E402

addon_install.prepare_user_resources()   # before `import bpy`

import bpy  # noqa: E402

from benchmarks import error_vs_time, incremental, report, scaling, throughput  # noqa: E402


SECTIONS = ("error", "scaling", "throughput", "incremental")
SECTION_KEYS = {"error_vs_time": "error", "scaling": "scaling", "throughput": "throughput",
                "incremental": "incremental"}


def options():
    quick = os.environ.get("BENCH_QUICK") == "1"
    out = os.environ.get("BENCH_OUT") or (os.path.join(ROOT, "out", "bench-quick") if quick
                                           else os.path.join(ROOT, "benchmarks", "report"))
    sections = os.environ.get("BENCH_SECTIONS", ",".join(SECTIONS)).split(",")
    default_scenes = "cornell_area" if quick else ",".join(s.name for s in error_vs_time.SCENES)
    names = os.environ.get("BENCH_SCENES", default_scenes).split(",")
    unknown = set(names) - {s.name for s in error_vs_time.SCENES}
    if unknown:
        sys.exit(f"unknown BENCH_SCENES {sorted(unknown)}; known: "
                 f"{[s.name for s in error_vs_time.SCENES]}")
    return {"quick": quick, "out": out, "sections": [s.strip() for s in sections],
            "scenes": [s for s in error_vs_time.SCENES if s.name in names],
            "time_limit": float(os.environ.get("BENCH_TIME_LIMIT", "60"))}


def machine():
    def git(*args):
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                                  timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""
    dirty = git("status", "--porcelain", "--", "irad_addon")
    return {"date": time.strftime("%Y-%m-%d %H:%M"), "cpu_count": os.cpu_count(),
            "blender": bpy.app.version_string,
            "commit": (git("rev-parse", "--short", "HEAD") or "unknown")
            + (" + uncommitted changes in irad_addon/" if dirty else ""),
            "load_start": "%.1f" % os.getloadavg()[0], "cpu_ticks_start": cpu_ticks()}


def cpu_ticks():
    """(all, stolen) CPU clock ticks since boot from /proc/stat (Linux; else None):
    'steal' is time the hypervisor gave this VM's virtual CPUs to others."""
    try:
        with open("/proc/stat") as fh:
            fields = [int(v) for v in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    return [sum(fields), fields[7] if len(fields) > 7 else 0]


def stolen_share(start, end):
    """The share of CPU time stolen between two cpu_ticks() readings, or None."""
    if not start or not end or end[0] <= start[0]:
        return None
    return (end[1] - start[1]) / (end[0] - start[0])


def error_section(addon, opts, results):
    results["error_vs_time"] = []
    default_particles = addon.irad_addon.render.RenderSettings().particles
    for bench in opts["scenes"]:
        print(f"error vs time: {bench.title}", flush=True)
        scene, images = error_vs_time.bench_scene(addon, bench, opts["quick"],
                                                  opts["time_limit"])
        scene["default_particles"] = default_particles
        scene["strip_path"] = os.path.join(opts["out"], f"images_{bench.name}.png")
        report.save_image_strip(scene["strip_path"], strip(images, scene, default_particles))
        results["error_vs_time"].append(scene)


def strip(images, scene, default_particles):
    """Reference, ours at defaults, and the Cycles runs closest to ours in time."""
    key = f"{report.DEFAULT_METHOD} | particles {default_particles}"
    picked = [("Cycles reference", images["reference"])]
    ours = next((r for r in scene["runs"] if r["method"] == report.DEFAULT_METHOD
                 and r.get("particles") == default_particles), None)
    if ours is None:
        return picked
    picked.append((f"ours, defaults: {ours['seconds']:.2f} s\nrelMSE {ours['relmse']:.4f}",
                   images[key]))
    for method in (report.CYCLES, report.OIDN):
        rows = [r for r in scene["runs"] if r["method"] == method]
        best = min(rows, key=lambda r: abs(r["seconds"] - ours["seconds"]))
        picked.append((f"{method} {best['spp']} spp: {best['seconds']:.2f} s\n"
                       f"relMSE {best['relmse']:.4f}",
                       images[f"{method} | spp {best['spp']}"]))
    return picked


def main():
    opts = options()
    os.makedirs(opts["out"], exist_ok=True)
    started = time.perf_counter()
    addon = addon_install.enable_extension()
    results = {"mode": "quick" if opts["quick"] else "full", "machine": machine()}
    previous = os.path.join(opts["out"], "results.json")
    if set(opts["sections"]) != set(SECTIONS) and os.path.exists(previous):
        # A partial run keeps the other sections of the last run (marked in the report).
        with open(previous) as fh:
            kept = json.load(fh)
        run_of_kept = {"date": kept["machine"]["date"], "minutes": kept["seconds"] / 60,
                       "load": f"{kept['machine']['load_start']} → {kept['machine']['load_end']}"}
        results["kept_sections"] = {
            k: kept.get("kept_sections", {}).get(k, run_of_kept) for k in SECTION_KEYS
            if k in kept and SECTION_KEYS[k] not in opts["sections"]}
        results.update({k: kept[k] for k in results["kept_sections"]})
    if "error" in opts["sections"]:
        error_section(addon, opts, results)
    if "throughput" in opts["sections"]:
        print("throughput ceiling", flush=True)
        results["throughput"] = throughput.run(addon, opts["quick"])
    if "incremental" in opts["sections"]:
        print("incremental IR per frame", flush=True)
        results["incremental"] = incremental.run(addon, opts["quick"])
    if "scaling" in opts["sections"]:
        print("scaling (one process per point)", flush=True)
        results["scaling"] = scaling.run(opts["quick"], opts["time_limit"] * 2)
    results["machine"]["load_end"] = "%.1f" % os.getloadavg()[0]
    results["machine"]["stolen"] = stolen_share(results["machine"].pop("cpu_ticks_start"),
                                                cpu_ticks())
    results["seconds"] = time.perf_counter() - started
    with open(os.path.join(opts["out"], "results.json"), "w") as fh:
        json.dump(results, fh, indent=1, default=float)
    path = report.write(results, opts["out"])
    print(f"wrote {path} ({results['seconds'] / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

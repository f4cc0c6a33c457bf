"""Scaling: render time and peak memory against triangle count, VPL count and
resolution; BVH build time on its own.

Every point runs in its own process (`python benchmarks/scaling.py --point JSON`), so
its peak resident memory (VmHWM) belongs to that point alone. The child
renders once through the engine (timed like error_vs_time: the whole render call),
then times extraction and the Embree BVH build (irad_addon.rays.RayTracer) separately.
"""
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

TRIANGLES = (10_000, 100_000, 500_000, 1_000_000, 2_000_000)
VPL_TARGETS = (64, 256, 1_000, 4_000, 16_000, 100_000)
RESOLUTIONS = (32, 64, 128, 256, 512)
QUICK = {"triangles": (10_000, 200_000), "vpls": (64, 1_000, 4_000),
         "resolutions": (32, 96)}
VPL_RESOLUTION = 64
TRIANGLE_RESOLUTION = 64
# Configurations of the VPL sweep (names map to scene.irad settings, as in
# error_vs_time.CONFIGS); one whose setting does not exist yet is skipped.
VPL_CONFIGS = {"gather, default shadow-ray budget": {"use_lightcuts": False},
               "lightcuts": {"use_lightcuts": True}}
RESULT_TAG = "SCALING_RESULT "


# ------------------------------------------------------------------ child process
def _status_mb(field):
    """VmRSS (now) or VmHWM (peak) of this process. getrusage's ru_maxrss would not do:
    Linux carries the parent's peak over fork + exec into the child's."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _build(point):
    from benchmarks import scenes
    kind = point["kind"]
    if kind == "triangles":
        return scenes.high_poly(point["triangles"], TRIANGLE_RESOLUTION)
    if kind == "vpls":
        return scenes.cornell_box("AREA", VPL_RESOLUTION)
    if kind == "resolution":
        return scenes.cornell_box("AREA", point["resolution"])
    raise ValueError(kind)


def measure_point(point):
    """Runs in the child: build, render, then time extraction and the BVH alone."""
    sys.path.insert(0, ROOT)
    from benchmarks import addon_install
    addon_install.prepare_user_resources()
    import bpy
    addon = addon_install.enable_extension()
    from benchmarks import error_vs_time as evt
    core = addon.irad_addon

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = _build(point)
    settings = dict(point.get("settings", {}))
    missing = evt.missing_settings(scene, settings)
    if missing:
        return {**point, "skipped": missing}
    rss_before = _status_mb("VmRSS")
    image, seconds, stats = evt.render_ours(addon, scene, settings)
    peak = _status_mb("VmHWM")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    t = time.perf_counter()
    data = core.extract.extract_scene(depsgraph)
    extract_seconds = time.perf_counter() - t
    triangles = core.frame.prepare_frame(data).triangles
    t = time.perf_counter()
    core.rays.RayTracer(triangles)
    bvh_seconds = time.perf_counter() - t
    return {**point, "seconds": seconds, "vpls": stats.get("vpls"),
            "triangles": int(len(triangles)), "pixels": int(image.shape[0] * image.shape[1]),
            "stats": stats, "rss_before_render_mb": rss_before, "peak_rss_mb": peak,
            "extract_seconds": extract_seconds, "bvh_seconds": bvh_seconds}


# ------------------------------------------------------------------ parent
def run_point(point, timeout):
    """One child process; returns its result dict (or an 'error' entry)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--point", json.dumps(point)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {**point, "error": f"timed out after {timeout} s"}
    for line in done.stdout.splitlines():
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG):])
    return {**point, "error": (done.stderr or done.stdout).strip()[-800:]}


def _log(result):
    if "error" in result or "skipped" in result:
        print(f"  scaling {result['kind']}: {result.get('error') or result.get('skipped')}",
              flush=True)
        return
    print(f"  scaling {result['kind']:10s} {result.get('config', ''):18s} "
          f"tris {result['triangles']:8d} vpls {result['vpls']!s:7s} px {result['pixels']:7d} "
          f"{result['seconds']:7.2f} s, BVH {result['bvh_seconds']:.2f} s, "
          f"peak {result['peak_rss_mb']:.0f} MB", flush=True)


def _ladder(points, time_limit, timeout):
    """Run points in order; stop once one takes longer than time_limit."""
    results = []
    for point in points:
        result = run_point(point, timeout)
        _log(result)
        results.append(result)
        if result.get("seconds", 0) > time_limit or "error" in result:
            break
    return results


def run(quick=False, time_limit=120.0, timeout=900):
    sizes = QUICK if quick else {"triangles": TRIANGLES, "vpls": VPL_TARGETS,
                                 "resolutions": RESOLUTIONS}
    out = {"triangles": _ladder([{"kind": "triangles", "triangles": n}
                                 for n in sizes["triangles"]], time_limit, timeout),
           "resolution": _ladder([{"kind": "resolution", "resolution": r}
                                  for r in sizes["resolutions"]], time_limit, timeout),
           "vpls": {}}
    for name, settings in VPL_CONFIGS.items():
        out["vpls"][name] = _vpl_ladder(name, settings, sizes["vpls"], time_limit, timeout)
    return out


def _vpl_ladder(name, settings, targets, time_limit, timeout):
    """Particle counts chosen so the VPL counts hit `targets`: the VPLs per particle
    of this scene are measured by the first point."""
    per_particle = None
    results = []
    for target in targets:
        particles = max(1, round(target / per_particle)) if per_particle else target
        point = {"kind": "vpls", "config": name, "target_vpls": target,
                 "settings": {**settings, "particles": particles}}
        result = run_point(point, timeout)
        _log(result)
        results.append(result)
        if "error" in result or "skipped" in result or result["seconds"] > time_limit:
            break
        per_particle = per_particle or max(result["vpls"], 1) / particles
    return results


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--point":
        print(RESULT_TAG + json.dumps(measure_point(json.loads(sys.argv[2]))), flush=True)
    else:
        sys.path.insert(0, ROOT)
        print(json.dumps(run(quick=os.environ.get("BENCH_QUICK") == "1"), indent=1))

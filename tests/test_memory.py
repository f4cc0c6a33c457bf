"""Full-HD renders keep memory bounded: the G-buffer is built in bands of rows and the
gather in tasks of bounded size, whatever the resolution and VPL count."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Runs in a fresh interpreter so that its peak RSS is this render's alone.
_SCRIPT = textwrap.dedent("""
    import json, resource, sys
    sys.path[:0] = [sys.argv[1], sys.argv[1] + "/tests"]
    import numpy as np
    import synthetic
    from irad_addon import render, scene_data as sd
    # A closed box with the light inside, seen from afar (a few per cent of the frame):
    # every pixel gets G-buffer storage, the box's pixels gather the VPLs inside it
    # (shadow rays that the walls block).
    cam = np.eye(4)
    cam[:3, 3] = [0.0, 0.0, 30.0]
    camera = synthetic.camera(sd, size=1920)
    camera.matrix_world, camera.height, camera.lens = cam, 1080, 50.0
    light = sd.PointLight(np.array([0.1, 0.2, 0.3]), np.ones(3), 2000.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(4), [0.7] * 3, lights=[light],
                           camera=camera)
    result = render.render_frame(data, render.RenderSettings(
        particles=7000, aa_samples=1, interleave=8))
    image = result.passes["Combined"]
    print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "vpls": result.stats["vpls"], "bands": result.stats["bands"],
                      "stats": {k: v for k, v in result.stats.items() if k.startswith("time")},
                      "shape": list(image.shape), "finite": bool(np.isfinite(image).all())}))
""")


def test_full_hd_with_20k_vpls_stays_under_2_gb(tmp_path):
    # The checkout imported as `irad_addon`, not as the add-on's bl_ext module: numba's
    # compiled-code cache, which names the module, must not be shared with the others.
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    proc = subprocess.run([sys.executable, "-c", _SCRIPT, str(ROOT)], capture_output=True,
                          text=True, timeout=900, env=env)
    assert proc.returncode == 0, proc.stderr
    stats = json.loads(proc.stdout.strip().splitlines()[-1])
    assert stats["shape"] == [1080, 1920, 4] and stats["finite"]
    assert stats["vpls"] >= 20000
    assert stats["bands"] > 1
    assert stats["peak_rss_mb"] < 2048, stats

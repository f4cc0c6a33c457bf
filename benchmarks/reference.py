"""Fair Cycles reference renders, EXR read-back and a disk cache.

Images are float32 arrays (H, W, 3) of linear radiance, row 0 = TOP of the image,
column 0 = left. Pixel (row r, col c) has its centre at image coordinates
(x = c + 0.5, y = H - r - 0.5) with y measured up from the bottom edge.
"""
import hashlib
import os
import tempfile
import time

import bpy
import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CACHE_DIR = os.path.join(REPO, ".cache", "references")


def configure_cycles(scene, samples, seed=0, direct_only=False,
                     pixel_filter="BOX", denoise=False):
    """Set up Cycles for an unbiased, deterministic reference (see docs/radiometry.md)."""
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = int(samples)
    c.seed = int(seed)
    c.use_animated_seed = False
    c.sample_offset = 0
    c.use_sample_subset = False
    c.use_adaptive_sampling = False
    c.use_denoising = bool(denoise)
    for vl in scene.view_layers:
        vl.cycles.use_denoising = bool(denoise)
    # Defaults that bias a reference: indirect clamp 10, light threshold 0.01, glossy blur.
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.blur_glossy = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.use_guiding = False
    c.use_fast_gi = False
    c.use_camera_cull = False
    c.use_distance_cull = False
    c.min_light_bounces = 0
    c.min_transparent_bounces = 0
    c.film_exposure = 1.0  # a multiplier, 1 = neutral
    nb = 0 if direct_only else 32
    # max_bounces = 0: camera ray + next-event estimation at the first hit only.
    c.max_bounces = nb
    c.diffuse_bounces = nb
    c.glossy_bounces = nb
    c.transmission_bounces = nb
    c.volume_bounces = nb
    c.transparent_max_bounces = 32
    if pixel_filter == "CENTER":
        # A Gaussian this narrow puts every sample at the pixel centre.
        c.pixel_filter_type = "GAUSSIAN"
        c.filter_width = 0.01
    elif pixel_filter == "BOX":
        c.pixel_filter_type = "BOX"  # always 1 px wide, filter_width ignored
    else:
        raise ValueError(pixel_filter)
    _neutral_colour(scene)
    return scene


def _neutral_colour(scene):
    v = scene.view_settings
    v.view_transform = "Standard"
    v.look = "None"
    v.exposure = 0.0
    v.gamma = 1.0
    v.use_curve_mapping = False
    scene.render.dither_intensity = 0.0
    scene.render.film_transparent = False
    scene.render.use_compositing = False
    scene.render.use_sequencer = False


def _render(scene):
    """Render with the scene's engine, return (image, seconds of the render call)."""
    r = scene.render
    saved = (r.filepath, r.image_settings.file_format, r.image_settings.color_depth,
             r.image_settings.color_mode, r.image_settings.exr_codec,
             r.use_file_extension)
    with tempfile.TemporaryDirectory(prefix="irad_ref_") as tmp:
        r.filepath = os.path.join(tmp, "render")
        r.use_file_extension = True
        r.image_settings.file_format = "OPEN_EXR"
        r.image_settings.color_depth = "32"
        r.image_settings.color_mode = "RGBA"
        r.image_settings.exr_codec = "ZIP"  # lossless
        t0 = time.perf_counter()
        # The Render Result's pixels are not readable from Python; the EXR is.
        bpy.ops.render.render(write_still=True, scene=scene.name)
        seconds = time.perf_counter() - t0
        try:
            # Stills are written without a frame number; take whatever EXR appeared.
            (name,) = [f for f in os.listdir(tmp) if f.endswith(".exr")]
            path = os.path.join(tmp, name)
            img = bpy.data.images.load(path, check_existing=False)
            try:
                w, h = img.size
                buf = np.empty(w * h * img.channels, dtype=np.float32)
                img.pixels.foreach_get(buf)
                chans = img.channels
            finally:
                bpy.data.images.remove(img)
        finally:
            (r.filepath, r.image_settings.file_format, r.image_settings.color_depth,
             r.image_settings.color_mode, r.image_settings.exr_codec,
             r.use_file_extension) = saved
    # Blender stores rows bottom-up; flip so row 0 is the top.
    image = buf.reshape(h, w, chans)[::-1, :, :3]
    return np.ascontiguousarray(image, dtype=np.float32), seconds


def render_image(scene):
    """Render with whatever engine is set; (H, W, 3) float32 linear, row 0 = top."""
    return _render(scene)[0]


# A pause before each timed render, so that none pays for the CPU its predecessor
# used: on this VM our render measured ~20% slower right after a Cycles + OIDN render
# (both cores busy) than after a pause of 50 ms or more, while Cycles' time did not
# depend on what ran before it (out/cold4.py, cold5.py in session 10's notes).
SETTLE_SECONDS = 0.3


def timed_render(scene):
    """(image, seconds) after a SETTLE_SECONDS pause; seconds covers
    bpy.ops.render.render incl. writing the EXR."""
    time.sleep(SETTLE_SECONDS)
    return _render(scene)


def reference_key(scene, samples, direct_only, pixel_filter, seed):
    r = scene.render
    res = (r.resolution_x * r.resolution_percentage // 100,
           r.resolution_y * r.resolution_percentage // 100)
    return "|".join(str(p) for p in (
        scene.get("irad_scene_key", scene.name), res, samples, direct_only,
        pixel_filter, seed, bpy.app.version_string))


def cycles_reference(scene, samples, direct_only=False, pixel_filter="BOX", seed=0):
    """Cycles reference image, cached in .cache/references/<sha1 of key>.npy."""
    if "irad_scene_key" not in scene:
        raise KeyError("scene has no irad_scene_key; build it with benchmarks.scenes")
    key = reference_key(scene, samples, direct_only, pixel_filter, seed)
    path = os.path.join(CACHE_DIR, hashlib.sha1(key.encode()).hexdigest() + ".npy")
    if os.path.exists(path):
        return np.load(path)
    engine = scene.render.engine
    try:
        configure_cycles(scene, samples, seed=seed, direct_only=direct_only,
                         pixel_filter=pixel_filter)
        image = render_image(scene)
    finally:
        scene.render.engine = engine
    os.makedirs(CACHE_DIR, exist_ok=True)
    tmp = path + ".%d.tmp.npy" % os.getpid()
    np.save(tmp, image)
    os.replace(tmp, path)  # atomic: parallel test runs never see half a file
    return image


def _timing_table():
    """python -m benchmarks.reference: Cycles cost and own noise on this machine."""
    from benchmarks import metrics, scenes
    cases = [("cornell_box AREA 128", lambda: scenes.cornell_box("AREA", 128), False,
              (64, 256, 1024)),
             ("plane_with_light AREA_SQUARE 64", lambda: scenes.plane_with_light("AREA_SQUARE", 64),
              True, (64, 256)),
             ("plane_with_light POINT_RADIUS 64",
              lambda: scenes.plane_with_light("POINT_RADIUS", 64), True, (64, 256)),
             ("plane_with_light SUN_ANGLE 64", lambda: scenes.plane_with_light("SUN_ANGLE", 64),
              True, (64, 256)),
             ("plane_with_light WORLD 64", lambda: scenes.plane_with_light("WORLD", 64),
              True, (64, 256))]
    print("%-34s %6s %8s %12s" % ("scene", "spp", "seconds", "relMSE(1 run)"))
    for name, build, direct, spps in cases:
        for spp in spps:
            imgs, secs = [], []
            for seed in (0, 1):
                bpy.ops.wm.read_homefile(use_empty=True)
                scene = build()
                configure_cycles(scene, spp, seed=seed, direct_only=direct)
                img, sec = timed_render(scene)
                imgs.append(img)
                secs.append(sec)
            # reference_relmse estimates the 2-run mean; one run has twice the error.
            err = 2 * metrics.reference_relmse(*imgs)
            print("%-34s %6d %8.1f %12.2e" % (name, spp, min(secs), err), flush=True)


if __name__ == "__main__":
    _timing_table()

"""The render engine on real Blender scenes: passes, bad input, progress and cancel."""
import math

import bpy
import numpy as np
import pytest

from benchmarks import reference, scenes

ENGINE = "INSTANT_RADIOSITY"


def engine_class():
    return next(c for c in bpy.types.RenderEngine.__subclasses__()
                if getattr(c, "bl_idname", None) == ENGINE and c.is_registered)


def small_scene(scene, light=True, camera=True, geometry=True):
    scene.render.resolution_x = scene.render.resolution_y = 24
    scene.render.engine = ENGINE
    if geometry:
        scenes.grid_plane(scene, "floor", 10.0, scenes.diffuse("floor", (0.8, 0.8, 0.8)))
        scenes.box(scene, "cube", (1, 1, 1), scenes.diffuse("cube", (0.8, 0.2, 0.2)), (0, 0, 0.5))
    if light:
        scenes.light(scene, "POINT", 200.0, (1, -1, 3), shadow_soft_size=0.0)
    if camera:
        scenes.camera(scene, (0, -6, 4), (math.radians(55), 0, 0), lens_deg=50)
    scene.irad.particles = 64
    return scene


def test_render_writes_every_pass(scene):
    small_scene(scene)
    image = reference.render_image(scene)
    written = engine_class().last_render["passes"]
    for name in ("Combined", "IRAD Direct", "IRAD Indirect", "Depth", "Normal", "Albedo"):
        assert name in written
    assert np.isfinite(image).all() and image.max() > 0
    assert engine_class().last_render["stats"]["vpls"] > 0


def test_passes_add_up_and_depth_is_camera_z(addon):
    core = addon.irad_addon
    sd = core.scene_data
    import synthetic
    light = sd.PointLight(np.array([0.0, 0.0, 0.5]), np.ones(3), 100.0, 0.0)
    cam = synthetic.camera(sd, size=8)
    data = synthetic.scene(sd, synthetic.closed_box(2), [0.6] * 3, lights=[light], camera=cam)
    passes = core.render.render_frame(data, core.render.RenderSettings(particles=64)).passes
    combined = passes["Combined"][..., :3]
    assert np.allclose(combined, passes["IRAD Direct"] + passes["IRAD Indirect"], atol=1e-6)
    # The camera at the origin looks down -Z at the face z = -1 of the box.
    assert np.allclose(passes["Depth"], 1.0, atol=1e-4)
    assert np.allclose(passes["Normal"], [0, 0, 1], atol=1e-5)
    assert np.allclose(passes["Albedo"], 0.6, atol=1e-6)


def test_no_camera_is_refused_with_a_message(scene):
    small_scene(scene, camera=False)
    with pytest.raises(RuntimeError, match="no camera"):
        bpy.ops.render.render()


@pytest.mark.parametrize("case", ["no lights", "no geometry", "zero power", "zero area",
                                  "degenerate triangles"])
def test_bad_input_renders_finite_with_a_clear_report(scene, capfd, case):
    small_scene(scene, light=case not in ("no lights", "zero power", "zero area"),
                geometry=case != "no geometry")
    if case == "zero power":
        scenes.light(scene, "POINT", 0.0, (0, 0, 3))
    if case == "zero area":
        scenes.light(scene, "AREA", 100.0, (0, 0, 3), size=0.0)
    if case == "degenerate triangles":
        mesh = bpy.data.meshes.new("sliver")
        mesh.from_pydata([(0, 0, 1), (0, 0, 1), (1, 1, 1), (2, 2, 1)], [], [(0, 1, 2), (0, 2, 3)])
        scene.collection.objects.link(bpy.data.objects.new("sliver", mesh))
    image = reference.render_image(scene)
    assert np.isfinite(image).all() and image.min() >= 0
    out = capfd.readouterr().out
    if case in ("no lights", "zero power", "zero area"):
        assert "no light with non-zero power" in out
        assert image.max() == 0
    if case == "degenerate triangles":
        assert "degenerate triangles" in out
        assert image.max() > 0


def test_cancel_stops_within_a_second_and_progress_rises(addon):
    import time

    import synthetic
    core = addon.irad_addon
    sd = core.scene_data
    light = sd.PointLight(np.array([0.0, 0.0, 0.5]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(8), [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=256))
    # Tens of seconds uncancelled: every pixel gathers every VPL.
    settings = core.render.RenderSettings(particles=20000, interleave=1)
    fractions = []
    cancel_at = [None]

    def progress(fraction, message):
        fractions.append(fraction)
        if fraction > 0.25 and cancel_at[0] is None:
            cancel_at[0] = time.perf_counter()   # the user presses Esc mid-gather

    with pytest.raises(core.render.Cancelled):
        core.render.render_frame(data, settings, cancel=lambda: cancel_at[0] is not None,
                                 progress=progress)
    assert cancel_at[0] is not None
    assert time.perf_counter() - cancel_at[0] < 1.0
    assert fractions == sorted(fractions)


def test_cache_preference_switches_bvh_reuse_off(scene, addon):
    small_scene(scene)
    scene.objects["cube"].location.x += 0.123   # geometry no earlier test has rendered
    prefs = bpy.context.preferences.addons[addon.__name__].preferences
    cache = engine_class().tracer_cache
    before = cache.builds
    reference.render_image(scene)
    builds = cache.builds
    assert builds == before + 1              # a new scene: one BVH built, kept in the cache
    reference.render_image(scene)            # same geometry: the cached BVH is reused
    assert cache.builds == builds
    prefs.use_cache = False
    try:
        reference.render_image(scene)
        assert cache.builds == builds        # the engine did not use (or fill) the cache
    finally:
        prefs.use_cache = True


@pytest.mark.parametrize("variant", ["BIDIRECTIONAL", "METROPOLIS", "INCREMENTAL", "AUTO"])
def test_every_variant_renders_through_the_engine(scene, variant):
    s = scenes.two_rooms(24)
    s.render.engine = ENGINE
    s.irad.variant, s.irad.particles, s.irad.aa_samples = variant, 64, 1
    image = reference.render_image(s)
    stats = engine_class().last_render["stats"]
    assert np.isfinite(image).all() and image.max() > 0 and stats["vpls"] > 0
    if variant == "AUTO":   # light in the other room: a camera-aware variant, and why
        assert stats["variant"] in ("BIDIRECTIONAL", "METROPOLIS"), stats["variant_reason"]
    else:
        assert stats["variant"] == variant
    assert stats["variant_reason"]


def test_animation_render_keeps_incremental_vpls_across_frames(scene, addon, record,
                                                               tmp_path):
    # One render job over three frames of a moving light: the engine's VariantState
    # lets incremental IR (Laine et al. 2007) keep the VPLs the light still sees.
    core = addon.irad_addon
    s = scenes.cornell_box("POINT", 16)
    light = next(o for o in s.objects if o.type == 'LIGHT')
    s.frame_start, s.frame_end = 1, 3
    for frame, location in ((1, (-0.6, -0.2, 0.7)), (10, (0.6, 0.4, -0.3))):
        light.location = location
        light.keyframe_insert("location", frame=frame)
    s.render.engine = ENGINE
    s.render.filepath = str(tmp_path / "frame_")
    s.irad.variant, s.irad.particles, s.irad.aa_samples = 'INCREMENTAL', 256, 1
    frames = record(core.render, "render_frame")
    bpy.ops.render.render(animation=True)
    assert len(frames) == 3
    assert all(f.stats["variant"] == "INCREMENTAL" for f in frames)
    for a, b in zip(frames, frames[1:]):
        seen = {tuple(p) for p in np.round(a.vpls.position, 9)}
        kept = np.mean([tuple(p) in seen for p in np.round(b.vpls.position, 9)])
        assert kept > 0.5, kept


def test_animation_render_gathers_the_last_frames_paths(scene, addon, record, tmp_path):
    # A camera fly-through rendered as an animation with Path Frames 3: the engine's
    # path window adds a batch of particles per frame until it holds three.
    core = addon.irad_addon
    s = scenes.cornell_box("POINT", 16)
    s.frame_start, s.frame_end = 1, 4
    camera = s.camera
    for frame, x in ((1, -0.1), (4, 0.1)):
        camera.location.x = x
        camera.keyframe_insert("location", frame=frame)
    s.render.engine = ENGINE
    s.render.filepath = str(tmp_path / "frame_")
    s.irad.particles, s.irad.aa_samples, s.irad.temporal_frames = 128, 1, 3
    frames = record(core.render, "render_frame")
    bpy.ops.render.render(animation=True)
    assert [f.stats["path_frames"] for f in frames] == [1, 2, 3, 3]
    assert frames[3].vpls is frames[2].vpls        # full and unchanged: reused
    assert frames[2].vpls.count > 2.5 * frames[0].vpls.count

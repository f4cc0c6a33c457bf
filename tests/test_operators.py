"""The irad.* operators on real scenes from a background script: bake, clear, re-bake,
animation, cancel, bad input; the overlay, preferences, sidebar and (un)registration."""
import dataclasses
import types

import addon_utils
import bpy
import numpy as np
import pytest

from benchmarks import metrics, reference, scenes

ADDON_MODULE = "bl_ext.user_default.instant_radiosity"
ID_COLLECTIONS = ("objects", "meshes", "lights", "materials", "collections", "cameras",
                  "worlds", "actions", "scenes", "images", "node_groups")


@pytest.fixture
def core(addon):
    return addon.irad_addon


def snapshot():
    """Every datablock name, object transform, light setting and collection membership."""
    data = {attr: sorted(idb.name_full for idb in getattr(bpy.data, attr))
            for attr in ID_COLLECTIONS}
    data["transforms"] = {ob.name_full: (tuple(ob.location), tuple(ob.rotation_euler),
                                         tuple(ob.rotation_quaternion), tuple(ob.scale),
                                         ob.rotation_mode, ob.parent and ob.parent.name)
                          for ob in bpy.data.objects}
    data["lights"] = {ld.name_full: (ld.type, ld.energy, tuple(ld.color))
                      for ld in bpy.data.lights}
    data["members"] = {c.name_full: (sorted(o.name for o in c.objects),
                                     sorted(ch.name for ch in c.children))
                       for c in list(bpy.data.collections)
                       + [s.collection for s in bpy.data.scenes]}
    data["frames"] = [s.frame_current for s in bpy.data.scenes]
    return data


def small_cornell(resolution=24, particles=256, budget=16):
    scene = scenes.cornell_box("POINT", resolution)
    scene.irad.particles = particles
    scene.irad.light_budget = budget
    return scene


def light_state(core, scene):
    """(location, power) of every baked light, sorted, as evaluated now."""
    rows = [(*ob.matrix_world.translation, ob.data.energy)
            for ob in core.bake.baked_objects(scene)]
    return np.array(sorted(rows))


# ------------------------------------------------------------------ bake and clear

def test_bake_creates_tagged_disk_lights_that_face_the_vpls(scene, core):
    assert bpy.app.background                     # scripts in batch mode call bpy.ops
    scene = small_cornell(budget=4096)
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    traced = core.bake.remembered(scene)
    objects = core.bake.baked_objects(scene)
    assert len(objects) == traced.vpls.count == scene.irad.bake_light_count > 100
    coll = bpy.data.collections[core.bake.COLLECTION_NAME]
    assert coll.get("irad_baked") and set(coll.objects) == set(objects)
    assert all(ob.get("irad_baked") and ob.data.get("irad_baked") for ob in objects)
    assert {(ob.data.type, ob.data.shape) for ob in objects} == {('AREA', 'DISK')}
    power = np.array([np.array(ob.data.color) * ob.data.energy for ob in objects])
    assert np.allclose(power.sum(0), traced.vpls.flux.sum(0), rtol=1e-5)
    # Lights are numbered in VPL order; each faces (local -Z) along its VPL's normal.
    objects.sort(key=lambda ob: ob.name)
    facing = np.array([-np.array(ob.matrix_world)[:3, 2] for ob in objects])
    assert np.allclose(facing, traced.vpls.normal, atol=1e-5)


def test_clear_removes_exactly_the_baked_lights(scene, core):
    scene = small_cornell()
    before = snapshot()
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    assert len(core.bake.baked_objects(scene)) == 16
    # The user renames our collection: clear still finds everything by its tag.
    bpy.data.collections[core.bake.COLLECTION_NAME].name = "My bounce lights"
    assert bpy.ops.irad.clear_lights() == {'FINISHED'}
    assert snapshot() == before
    assert scene.irad.bake_light_count == 0
    with pytest.raises(RuntimeError, match="Nothing to clear"):
        bpy.ops.irad.clear_lights()
    assert snapshot() == before


def test_clear_keeps_what_the_user_put_in_our_collection(scene, core):
    scene = small_cornell()
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    coll = core.bake.baked_collections(scene)[0]
    baked = core.bake.baked_objects(scene)
    # The user moves their own light into our collection and reuses our light data.
    user_light = bpy.data.objects["Light"]
    coll.objects.link(user_light)
    reused = bpy.data.objects.new("Reuse", baked[0].data)
    scene.collection.objects.link(reused)
    kept_data = baked[0].data.name
    assert bpy.ops.irad.clear_lights() == {'FINISHED'}
    assert core.bake.baked_objects(scene) == []
    assert "Light" in bpy.data.objects and "Reuse" in bpy.data.objects
    assert kept_data in bpy.data.lights                 # still used by the user's object
    assert coll.name in bpy.data.collections             # holds the user's light


def test_rebake_after_moving_the_light_replaces_the_lights(scene, core):
    scene = small_cornell()
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    first_vpls = core.bake.remembered(scene).vpls
    first = light_state(core, scene)
    # Baking again unchanged: the baked lights are not traced, so the same VPLs appear.
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    again = core.bake.remembered(scene).vpls
    assert np.array_equal(again.flux, first_vpls.flux)
    assert np.array_equal(again.position, first_vpls.position)
    assert np.allclose(light_state(core, scene), first)
    assert len(bpy.data.lights) == 1 + 16 and len(bpy.data.collections) == 1

    bpy.data.objects["Light"].location = (0.6, 0.5, -0.2)
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    moved = light_state(core, scene)
    assert moved.shape == first.shape and not np.allclose(moved, first)
    assert len(core.bake.baked_objects(scene)) == 16 and len(bpy.data.lights) == 1 + 16
    # The VPLs' total flux is the user's light's share only (the baked lights would add
    # about as much again if they were traced).
    flux = core.bake.remembered(scene).vpls.flux.sum()
    assert flux == pytest.approx(first_vpls.flux.sum(), rel=0.35)


# ---------------------------------------------------------------------- animation

def animated_cornell():
    scene = small_cornell(resolution=24, particles=1024, budget=64)
    light = bpy.data.objects["Light"]
    scene.frame_start, scene.frame_end = 1, 10
    for frame, location in ((1, (-0.6, -0.2, 0.7)), (10, (0.6, 0.4, -0.3))):
        light.location = location
        light.keyframe_insert("location", frame=frame)
    scene.frame_set(1)
    return scene


def test_animation_bake_keyframes_lights_that_render_each_frame(scene, core):
    scene = animated_cornell()
    # References first: rendered after the bake they would include the baked lights.
    full_gi = {}
    for frame in (1, 10):
        scene.frame_set(frame)
        scene["irad_scene_key"] = f"cornell_box:POINT:animated:frame{frame}"
        full_gi[frame] = reference.cycles_reference(scene, 256)
    scene.frame_set(1)
    assert bpy.ops.irad.bake_animation() == {'FINISHED'}
    assert scene.frame_current == 1
    objects = core.bake.baked_objects(scene)
    assert 0 < len(objects) <= 64
    curves = {(c.data_path, c.array_index): c for c in core.bake._fcurves(objects[0])}
    curves.update({(c.data_path, c.array_index): c for c in core.bake._fcurves(objects[0].data)})
    for key in (("location", 0), ("rotation_quaternion", 3), ("energy", 0), ("color", 1),
                ("size", 0)):
        assert [p.co[0] for p in curves[key].keyframe_points] == list(range(1, 11))
    assert all(a.get("irad_baked") for a in bpy.data.actions if a.users and
               any(ob.animation_data and ob.animation_data.action == a for ob in objects))

    images, states = {}, {}
    for frame in (1, 10):
        scene.frame_set(frame)
        states[frame] = light_state(core, scene)
        reference.configure_cycles(scene, 64, direct_only=True)
        images[frame] = reference.render_image(scene)
        error = metrics.relmse(images[frame], full_gi[frame])
        print(f"frame {frame}: relMSE {error:.4f}")
        assert error < 0.1
    assert not np.allclose(states[1], states[10])
    assert metrics.relmse(images[1], images[10]) > 0.1

    # Playback shows what a single-frame bake at that frame makes.
    animated = states[10]
    scene.frame_set(10)
    assert bpy.ops.irad.bake_lights() == {'FINISHED'}
    static = light_state(core, scene)
    lit = animated[animated[:, 3] > 0]
    assert lit.shape == static.shape and np.allclose(lit, static, rtol=1e-5, atol=1e-6)
    # The static bake replaced the animated lights and their actions.
    assert not any(a.get("irad_baked") for a in bpy.data.actions)


def shared_positions(a, b):
    """Fraction of the VPLs of set b at exactly the position of one of set a."""
    seen = {tuple(p) for p in np.round(a.position, 9)}
    return np.mean([tuple(p) in seen for p in np.round(b.position, 9)])


@pytest.mark.parametrize("variant", ["INCREMENTAL", "CLASSIC"])
def test_incremental_animation_bake_keeps_its_vpls_across_frames(scene, core, record,
                                                                  variant):
    scene = animated_cornell()
    scene.frame_end = 4
    scene.irad.variant = variant
    traced = record(core.bake, "trace")
    assert bpy.ops.irad.bake_animation() == {'FINISHED'}
    assert len(traced) == 4
    shared = [shared_positions(a.vpls, b.vpls) for a, b in zip(traced, traced[1:])]
    if variant == "INCREMENTAL":   # Laine et al. 2007: VPLs persist while the light moves
        assert min(shared) > 0.5, shared
    else:                          # a new VPL set every frame
        assert max(shared) < 0.05, shared


def test_cancelling_an_animation_bake_changes_nothing(scene, core, addon):
    """Esc closes the step generator mid-way: no lights, frame restored."""
    scene = animated_cornell()
    scene.frame_set(4)
    before = snapshot()
    op = addon.operators.bake.IRAD_OT_bake_animation
    fake = types.SimpleNamespace(use_scene_range=True, report=lambda kind, message: None)
    fake.frame_range = lambda s: op.frame_range(fake, s)
    steps = op.steps(fake, scene)
    for _ in range(3):
        next(steps)
    assert scene.frame_current != 4           # it is walking the frames
    steps.close()
    assert snapshot() == before and scene.frame_current == 4


# -------------------------------------------------------------------- bad input

def _no_light():
    scene = small_cornell()
    bpy.data.objects.remove(bpy.data.objects["Light"])
    return "no light with non-zero power"


def _no_mesh():
    scene = bpy.context.scene
    scenes.camera(scene, (0, -4, 0), scenes.LOOK_Y, lens_deg=40)
    scenes.light(scene, "POINT", 100.0, (0, 0, 1))
    return "no mesh"


def _no_camera():
    small_cornell()
    bpy.data.objects.remove(bpy.data.objects["Camera"])
    return "no active camera"


@pytest.mark.parametrize("build", [_no_light, _no_mesh, _no_camera])
@pytest.mark.parametrize("operator", ["compute_vpls", "bake_lights", "bake_animation",
                                      "clear_lights"])
def test_every_operator_reports_bad_scenes_and_changes_nothing(scene, build, operator):
    message = build()
    scene.frame_start, scene.frame_end = 1, 3
    if operator == "clear_lights":
        message = "Nothing to clear"
    before = snapshot()
    with pytest.raises(RuntimeError, match=message):
        getattr(bpy.ops.irad, operator)()
    assert snapshot() == before


def test_max_bounces_zero_is_refused(scene):
    scene = small_cornell()
    scene.irad.max_bounces = 0
    with pytest.raises(RuntimeError, match="Max Bounces is 0"):
        bpy.ops.irad.bake_lights()


# ---------------------------------------------------- VPLs, overlay, preferences

def test_compute_vpls_keeps_them_for_the_overlay(scene, core):
    scene = small_cornell()
    before = snapshot()
    assert bpy.ops.irad.compute_vpls() == {'FINISHED'}
    assert snapshot() == before                      # computing changes no datablock
    traced = core.bake.remembered(scene)
    assert traced.vpls.count == scene.irad.bake_vpl_count > 0
    colors = core.bake_math.display_colors(traced.vpls.flux)
    assert colors.shape == (traced.vpls.count, 4) and colors.dtype == np.float32
    assert 0 <= colors.min() and colors[:, :3].max() <= 1
    assert not core.overlay.is_installed()
    scene.irad.show_vpl_overlay = True
    assert core.overlay.is_installed()
    scene.irad.show_vpl_overlay = False
    assert not core.overlay.is_installed()


def test_preferences_register_under_the_extension(addon, core):
    prefs = bpy.context.preferences.addons[ADDON_MODULE].preferences
    assert type(prefs).bl_idname == ADDON_MODULE == core.preferences.ADDON_PACKAGE
    import os
    prefs.threads = 0
    assert core.preferences.thread_count() == max(1, os.cpu_count() or 1)
    prefs.threads = 1
    try:
        assert core.preferences.thread_count() == 1
        # The ray tracer's pool follows the preference.
        assert core.rays.worker_count() == 1
        assert core.rays.thread_pool()._max_workers == 1
    finally:
        prefs.threads = 0
    assert core.rays.worker_count() == max(1, os.cpu_count() or 1)
    assert core.preferences.use_cache() is True


class _Layout:
    """Records what a panel draws and checks each property and operator exists."""

    def __init__(self):
        self.props, self.operators = [], []
        self.use_property_split = self.use_property_decorate = False

    def column(self, **_):
        return self

    row = column

    def separator(self, **_):
        pass

    def label(self, text="", **_):
        assert text

    def prop(self, data, name, **_):
        assert name in data.bl_rna.properties, name
        assert data.bl_rna.properties[name].description or name in ("frame_start", "frame_end")
        self.props.append(name)

    def operator(self, idname, **_):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        getattr(getattr(bpy.ops, module), name).get_rna_type()
        self.operators.append(idname)


def test_sidebar_panels_draw_every_setting_and_button(scene, addon):
    sidebar = addon.panels.sidebar
    layout = _Layout()
    for cls in sidebar.classes:
        assert cls.is_registered and cls.bl_space_type == 'VIEW_3D'
        panel = types.SimpleNamespace(layout=layout)
        cls.draw(panel, bpy.context)
    for name in ("variant", "particles", "max_bounces", "light_budget", "clamp", "seed",
                 "show_vpl_overlay"):
        assert name in layout.props
    assert set(layout.operators) == {"irad.bake_lights", "irad.clear_lights",
                                     "irad.bake_animation", "irad.compute_vpls"}


def test_render_panels_draw_every_render_setting(scene, addon):
    # Every setting the engine reads (engine.render_settings) is in a Render Properties
    # panel or sub-panel header, each with its tooltip.
    layout = _Layout()
    for cls in addon.panels.render.classes:
        assert cls.is_registered and cls.bl_context == "render"
        panel = types.SimpleNamespace(layout=layout, properties=cls.properties)
        if hasattr(cls, "draw_header"):
            cls.draw_header(panel, bpy.context)
        cls.draw(panel, bpy.context)
    settings = addon.irad_addon.engine.render_settings(bpy.context.scene)
    read = {f.name for f in dataclasses.fields(settings)} - {"film_transparent"}
    assert read <= set(layout.props), read - set(layout.props)
    assert "temporal_frames" in layout.props and "temporal_reuse" in layout.props


def test_register_unregister_cleanly(addon):
    names = ("compute_vpls", "bake_lights", "clear_lights", "bake_animation")
    panel_names = [cls.__name__ for cls in addon.panels.sidebar.classes]
    addon_utils.disable(ADDON_MODULE, default_set=True)
    try:
        for name in names:
            assert not hasattr(bpy.ops.irad, name) or not _operator_exists(name)
        for name in panel_names:
            assert not hasattr(bpy.types, name)
        assert not hasattr(bpy.types.Scene, "irad")
        assert ADDON_MODULE not in bpy.context.preferences.addons
    finally:
        addon_utils.enable(ADDON_MODULE, default_set=True)
    for name in names:
        assert _operator_exists(name)
    for name in panel_names:
        assert hasattr(bpy.types, name)
    assert ADDON_MODULE in bpy.context.preferences.addons


def _operator_exists(name):
    try:
        getattr(bpy.ops.irad, name).get_rna_type()
        return True
    except KeyError:
        return False

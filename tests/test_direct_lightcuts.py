"""Direct light through lightcuts (direct_lightcuts.py): area lights and emissive
meshes as many point lights in the light tree, against Cycles."""
import bpy
import numpy as np
import pytest

from benchmarks import metrics, reference, scenes

ENGINE = "INSTANT_RADIOSITY"


def engine_class():
    return next(c for c in bpy.types.RenderEngine.__subclasses__()
                if getattr(c, "bl_idname", None) == ENGINE and c.is_registered)


@pytest.mark.parametrize("kind", ["AREA_SQUARE", "AREA_DISK", "EMISSIVE_MESH"])
def test_lightcut_direct_light_matches_cycles(scene, kind):
    s = scenes.plane_with_light(kind, 64)
    ref = reference.cycles_reference(s, 256, direct_only=True)
    s.render.engine = ENGINE
    s.irad.max_bounces, s.irad.aa_samples = 0, 16
    s.irad.use_lightcuts = True
    ours = reference.render_image(s)
    stats = engine_class().last_render["stats"]
    # Shadow rays went to cuts of the light's 4096 points, not to each of them.
    assert 0 < stats["direct_shadow_rays_per_point"] < 1000
    assert metrics.relmse(ours, ref) < 1e-3
    assert abs(metrics.relative_bias(ours, ref)) < 0.01


def test_lightcut_direct_light_matches_shadow_rays(addon):
    # The same light seen two ways: its 4096 points through cuts, or sampled with
    # shadow rays; the Cornell box's area light under its occluding boxes.
    core = addon.irad_addon
    bpy.ops.wm.read_homefile(use_empty=True)
    scenes.cornell_box("AREA", 32)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    common = dict(max_bounces=0, aa_samples=16, light_samples=16)
    sampled = core.render.render_frame(data, core.render.RenderSettings(**common))
    cut = core.render.render_frame(data, core.render.RenderSettings(use_lightcuts=True,
                                                                    **common))
    a, b = sampled.passes["IRAD Direct"], cut.passes["IRAD Direct"]
    assert abs(b.mean() / a.mean() - 1) < 0.01
    assert np.abs(b - a).mean() < 0.03 * a.mean()

"""Decoupled antialiasing (antialiasing.py): many coverage samples per pixel take the
irradiance of few shading samples on the same surface."""
import bpy
import numpy as np
import pytest

import synthetic
from benchmarks import metrics, reference, scenes


def box_with_a_panel(core, size=32):
    """A closed box lit by a point light, with a tilted panel floating in front of the
    camera: its silhouette and shadow are sharp edges across many pixels."""
    sd = core.scene_data
    panel = synthetic.grid_quad(1, 0.5).astype(np.float64)
    c, s = np.cos(0.5), np.sin(0.5)
    panel = panel @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T + [0.1, -0.05, -0.9]
    tris = np.concatenate([synthetic.closed_box(4), panel.astype(np.float32)])
    light = sd.PointLight(np.array([0.3, 0.4, 0.6]), np.ones(3), 100.0, 0.0)
    cam = synthetic.camera(sd, size=size, lens=14)
    cam.matrix_world[:3, 3] = [0.0, 0.0, 0.8]
    return synthetic.scene(sd, tris, [0.6] * 3, lights=[light], camera=cam)


def direct_pass(core, data, **settings):
    s = core.render.RenderSettings(particles=64, bias_compensation=False, **settings)
    return core.render.render_frame(data, s).passes["IRAD Direct"]


def test_edge_samples_antialias_like_many_shaded_samples(addon):
    # A point light's direct light has no noise: only pixel coverage differs, so the
    # box-filtered image with 64 shaded samples per pixel is the answer.
    core = addon.irad_addon
    data = box_with_a_panel(core)
    truth = direct_pass(core, data, aa_samples=64, coverage_samples=0)
    one = direct_pass(core, data, aa_samples=1, coverage_samples=0)
    decoupled = direct_pass(core, data, aa_samples=1, coverage_samples=64)
    error = lambda image: np.mean((image - truth) ** 2)   # noqa: E731
    edges = (np.abs(one - truth) > 0.05 * truth + 1e-3 * truth.max()).any(-1)
    assert edges.mean() > 0.02                 # the scene has edges to resolve
    assert error(decoupled) < 0.25 * error(one), (error(decoupled), error(one))
    # Inside surfaces every coverage sample takes its pixel's shading: nothing moves
    # (measured 96% of the pixels away from edges identical, the rest border them).
    unchanged = np.abs(decoupled - one).max(-1) <= 1e-6 * truth.max()
    assert unchanged[~edges].mean() > 0.9


def test_coverage_rays_only_in_pixels_edges_cross(addon):
    # Where 64 samples per pixel see another normal than 4 do, a geometric edge
    # crosses the pixel: coverage rays must be traced there, and only near such pixels
    # (both sides of an edge that runs between two pixels' samples: measured 3.5x the
    # pixels an edge crosses).
    core = addon.irad_addon
    data = box_with_a_panel(core, 48)
    normals = {n: core.render.render_frame(data, core.render.RenderSettings(
        particles=64, aa_samples=n, coverage_samples=0)).passes["Normal"] for n in (4, 64)}
    edges = np.abs(normals[64] - normals[4]).max(-1) > 0.05
    frame = core.frame.prepare_frame(data)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 4, np.random.default_rng(0))
    aa = core.antialiasing
    traced = aa.edge_pixels(gb, aa.uniform_pixels(gb)).reshape(edges.shape)
    assert edges.mean() > 0.02
    assert traced[edges].mean() > 0.97, traced[edges].mean()
    assert traced.mean() < 4 * edges.mean(), (traced.mean(), edges.mean())


def test_edge_samples_keep_silhouettes_against_the_background(addon):
    core = addon.irad_addon
    data = box_with_a_panel(core)
    data.mesh.triangles = data.mesh.triangles[-2:]       # only the panel, in the void
    data.mesh.corner_normals = data.mesh.corner_normals[-2:]
    data.mesh.material_index = data.mesh.material_index[-2:]
    data.mesh.object_index = data.mesh.object_index[-2:]
    coverage = core.render.render_frame(data, core.render.RenderSettings(
        particles=64, aa_samples=1, coverage_samples=64)).passes["Combined"]
    many = core.render.render_frame(data, core.render.RenderSettings(
        particles=64, aa_samples=64, coverage_samples=0)).passes["Combined"]
    # Alpha (coverage of the panel) and the lit silhouette match the 64-sample render.
    assert np.abs(coverage[..., 3] - many[..., 3]).max() < 0.3
    assert np.abs(coverage[..., 3].mean() - many[..., 3].mean()) < 0.01
    assert abs(coverage[..., :3].sum() / many[..., :3].sum() - 1) < 0.05


def test_edge_samples_lower_the_error_against_cycles(scene, addon):
    core = addon.irad_addon
    s = scenes.cornell_box("AREA", 48)
    ref = reference.cycles_reference(s, 1024)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    errors = {}
    for coverage in (0, 16):
        settings = core.render.RenderSettings(particles=2048, coverage_samples=coverage)
        image = core.render.render_frame(data, settings).passes["Combined"][..., :3]
        errors[coverage] = metrics.relmse(image, ref)
    assert errors[16] < 0.8 * errors[0], errors


def shadow_edge_render(core, data, seed, **settings):
    """(direct pass, share of pixels whose coverage samples gathered their own light)."""
    s = core.render.RenderSettings(particles=64, bias_compensation=False, seed=seed,
                                   **settings)
    result = core.render.render_frame(data, s)
    return result.passes["IRAD Direct"], result.stats.get("shadow_edge_pixels", 0.0)


def test_hard_shadow_edges_gather_light_per_coverage_sample(addon, monkeypatch):
    # The panel's shadow from a point light of radius 0 is a hard edge across flat
    # walls: carried from 4 shading samples it moves with their random positions (no
    # geometric edge there, so no coverage rays before). Direct light has no other
    # noise, so 64 shaded samples per pixel are the answer.
    core = addon.irad_addon
    aa = core.antialiasing
    data = box_with_a_panel(core)
    truth = direct_pass(core, data, aa_samples=64, coverage_samples=0)
    flagged, pixels = [], aa.HardShadowEdges.pixels
    monkeypatch.setattr(aa.HardShadowEdges, "pixels",
                        lambda self, E: flagged.append(pixels(self, E)) or flagged[-1])
    refined = [shadow_edge_render(core, data, seed) for seed in range(4)]
    with monkeypatch.context() as m:   # the shadow edges carried, as before
        m.setattr(aa.HardShadowEdges, "pixels", lambda self, E: np.zeros_like(pixels(self, E)))
        carried = [shadow_edge_render(core, data, seed)[0] for seed in range(4)]
    shares = [share for _, share in refined]
    assert min(shares) > 0.01, shares            # the shadow's edge, a line of pixels
    assert max(shares) < 0.1, shares
    edge = np.any(flagged, 0).reshape(truth.shape[:2])
    error = lambda image: np.mean((image - truth)[edge] ** 2)   # noqa: E731
    ours, before = np.mean([error(i) for i, _ in refined]), np.mean([error(i) for i in carried])
    assert ours < 0.5 * before, (ours, before)   # measured 0.20x on the edge's pixels


def test_soft_penumbrae_are_not_taken_for_hard_edges(addon):
    # A spherical light of radius 0.3 casts a penumbra many pixels wide: its samples
    # are partly lit, and its edge needs no coverage samples (measured 0.1% of the
    # pixels flagged, against ~3% for the point light's).
    core = addon.irad_addon
    data = box_with_a_panel(core)
    hard = np.mean([shadow_edge_render(core, data, seed)[1] for seed in range(2)])
    data.lights[0].radius = 0.3
    soft = np.mean([shadow_edge_render(core, data, seed)[1] for seed in range(2)])
    assert soft < 0.25 * hard, (soft, hard)


@pytest.mark.parametrize("half_size, searched", [(0.01, True), (0.3, False)])
def test_hard_edges_are_looked_for_only_under_small_lights(addon, monkeypatch, half_size,
                                                           searched):
    # A square light 2 cm wide casts the panel's hard shadow edge, which gets coverage
    # samples as the point light's does; one 60 cm wide (~0.6 rad from the walls) casts
    # penumbrae the shading samples resolve, and its edge search is skipped.
    core = addon.irad_addon
    data = box_with_a_panel(core)
    data.lights[0] = core.scene_data.AreaLight(
        np.array([0.3, 0.4, 0.6]), np.array([half_size, 0, 0]), np.array([0, half_size, 0]),
        np.array([0.0, 0.0, -1.0]), np.ones(3), 100.0, "RECTANGLE")
    added = []
    add = core.antialiasing.HardShadowEdges.add
    monkeypatch.setattr(core.antialiasing.HardShadowEdges, "add",
                        lambda self, *args: added.append(1) or add(self, *args))
    share = shadow_edge_render(core, data, 0)[1]
    assert bool(added) == searched
    assert (share > 0.01) == searched, share

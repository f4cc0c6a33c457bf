"""VPL placement variants (issue 5): bidirectional, Metropolis, incremental and Auto,
rendered through the core (extract -> frame -> G-buffer -> variants.place_vpls ->
render.render_frame with those VPLs) against Cycles and converged classic IR."""
import importlib

import bpy
import numpy as np
import pytest

import synthetic
from benchmarks import metrics, reference, scenes


@pytest.fixture
def core(addon):
    for name in ("variants", "variant_choice"):
        importlib.import_module(f"{addon.irad_addon.__name__}.{name}")
    return addon.irad_addon


def render_with_variant(core, data, state=None, **settings):
    """render.render_frame with the VPLs of settings.variant (same G-buffer and rng
    stream as render_frame builds); returns (image, vpls, info)."""
    s = core.render.RenderSettings(**settings)
    cache = core.rays.RayTracerCache()
    frame = core.frame.prepare_frame(data, cache)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, s.aa_samples,
                                    np.random.default_rng(s.seed))
    vpls, info = core.variants.place_vpls(frame, gb, s, state)
    result = core.render.render_frame(data, s, tracer_cache=cache, vpls=vpls)
    return result.passes["Combined"][..., :3], vpls, info


def mean_relmse(core, data, ref, variant, seeds=(1, 2, 3), **settings):
    errors, counts, infos = [], [], []
    for seed in seeds:
        image, vpls, info = render_with_variant(core, data, variant=variant, seed=seed,
                                                **settings)
        errors.append(metrics.relmse(image, ref))
        counts.append(vpls.count)
        infos.append(info)
    return float(np.mean(errors)), float(np.mean(counts)), infos


def test_two_rooms_camera_aware_variants_beat_classic_and_auto_picks_one(scene, core):
    # Light in one room, camera in the other: classic IR leaves most VPLs out of view.
    s = scenes.two_rooms(48)
    # 4096 spp: the reference's own relMSE is ~1e-3 (two seeds measured), well below
    # the errors compared here (classic ~0.16, bidirectional ~0.03).
    ref = reference.cycles_reference(s, 4096)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    # Placement compared at one gather, clamp 1 (the engine's default until the clamp
    # went to 3). A wider clamp with its bias compensation smooths classic's few VPLs in
    # view a lot: at clamp 3, classic 0.048, bidirectional 0.019, Metropolis 0.025.
    common = dict(particles=128, max_bounces=32, aa_samples=16, clamp=1.0)
    classic, classic_count, _ = mean_relmse(core, data, ref, 'CLASSIC', **common)
    bidir, bidir_count, _ = mean_relmse(core, data, ref, 'BIDIRECTIONAL', **common)
    metro, metro_count, _ = mean_relmse(core, data, ref, 'METROPOLIS', **common)
    assert bidir_count <= 1.05 * classic_count and metro_count <= 1.05 * classic_count
    assert bidir * 5 < classic, (bidir, classic)
    assert metro * 5 < classic, (metro, classic)
    _, _, infos = mean_relmse(core, data, ref, 'AUTO', seeds=(1,), **common)
    assert infos[0]['variant'] in ('BIDIRECTIONAL', 'METROPOLIS'), infos[0]
    assert "reaches what the camera sees" in infos[0]['reason']


@pytest.mark.parametrize("variant", ['CLASSIC', 'BIDIRECTIONAL', 'METROPOLIS', 'AUTO'])
def test_cornell_box_every_variant_converges_to_cycles(scene, core, variant):
    s = scenes.cornell_box("AREA", 48)
    ref = reference.cycles_reference(s, 1024)
    data = core.extract.extract_scene(bpy.context.evaluated_depsgraph_get())
    error, _, infos = mean_relmse(core, data, ref, variant, seeds=(1,), particles=2048,
                                  max_bounces=32, aa_samples=4)
    assert error < 0.02, (variant, error, infos[0].get('variant'))
    if variant == 'AUTO':   # light paths land in view in a Cornell box
        assert infos[0]['variant'] == 'CLASSIC', infos[0]


def closed_box_with_light(core, light_position=(0.3, 0.2, 0.5), albedo=0.6, size=16):
    sd = core.scene_data
    light = sd.PointLight(np.array(light_position, np.float64), np.ones(3), 100.0, 0.0)
    cam = synthetic.camera(sd, size=size)
    cam.matrix_world[:3, 3] = [0.05, 0.03, 0.5]
    return synthetic.scene(sd, synthetic.closed_box(3), [albedo] * 3, lights=[light], camera=cam)


def indirect_radiance(core, frame, gb, vpls, min_distance=0.2):
    """Reflected indirect radiance per G-buffer sample, with a FIXED clamp distance so
    that every estimator targets the same quantity."""
    E = core.gather.indirect_irradiance(frame, gb, vpls, min_distance,
                                        np.zeros(len(gb.hit), np.int64), 1)
    return E.mean(1) * gb.albedo.mean(1) / np.pi


def test_metropolis_mean_over_seeds_matches_converged_classic(core):
    data = closed_box_with_light(core)
    frame = core.frame.prepare_frame(data)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
    truth = [indirect_radiance(
        core, frame, gb, core.vpl.trace_vpls(frame, 20000, 16, seed=s)).mean()
             for s in range(2)]
    values = []
    for seed in range(12):
        settings = core.render.RenderSettings(particles=256, seed=seed, variant='METROPOLIS',
                                              max_bounces=16)
        vpls, info = core.variants.place_vpls(frame, gb, settings)
        assert info['variant'] == 'METROPOLIS' and info['paths'] > 0
        values.append(indirect_radiance(core, frame, gb, vpls).mean())
    mean, standard_error = np.mean(values), np.std(values, ddof=1) / np.sqrt(len(values))
    assert standard_error < 0.02 * mean          # the test can resolve a 6% normalisation error
    assert abs(mean - np.mean(truth)) < 3 * np.hypot(standard_error, np.std(truth)), (
        mean, standard_error, truth)


def test_incremental_is_cheaper_steadier_and_close_to_classic(core):
    from dataclasses import replace
    cache = core.rays.RayTracerCache()
    state = core.variants.VariantState()
    images = {'INCREMENTAL': [], 'CLASSIC': [], 'REFERENCE': []}
    rays = {'INCREMENTAL': [], 'CLASSIC': []}
    compared = []         # direction pairs the incremental update compared, per frame
    for i in range(30):   # a point light circling under the ceiling
        t = 0.03 * i
        data = closed_box_with_light(core, (0.5 * np.cos(t), 0.5 * np.sin(t), 0.3), 0.8)
        frame = core.frame.prepare_frame(data, cache)
        gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
        for kind in images:
            counting = core.rays.CountingTracer(frame.tracer)
            settings = core.render.RenderSettings(
                particles=16384 if kind == 'REFERENCE' else 1024, max_bounces=16,
                variant='CLASSIC' if kind == 'REFERENCE' else kind,
                seed=i if kind == 'CLASSIC' else 0)   # classic: a new seed per frame
            vpls, info = core.variants.place_vpls(replace(frame, tracer=counting), gb,
                                                  settings, state if kind == 'INCREMENTAL' else None)
            if kind in rays:
                rays[kind].append(counting.rays)
            if kind == 'INCREMENTAL':
                compared.append(info['compared'])
            images[kind].append(indirect_radiance(core, frame, gb, vpls, 0.1))
    assert cache.builds == 1
    # Issue 5: per-frame cost at least 3x lower than rebuilding all VPLs. Frame 0 builds
    # everything; afterwards count the work, not the wall clock: rays traced, and the
    # direction pairs the Voronoi-cell and largest-empty-circle searches compare.
    assert 3 * np.mean(rays['INCREMENTAL'][1:]) <= np.mean(rays['CLASSIC'][1:]), rays
    # Near-linear in the quadrature directions and sites: comparing every quadrature
    # direction with every site would be ~2000 pairs per direction or site.
    linear = len(state.incremental.quadrature) + 1024
    assert np.mean(compared[1:]) < 32 * linear, (np.mean(compared[1:]), linear)
    inc, cla, ref = (np.array(images[k]) for k in ('INCREMENTAL', 'CLASSIC', 'REFERENCE'))
    # Flicker: mean absolute frame-to-frame change per pixel (the camera is static).
    assert np.abs(np.diff(inc, axis=0)).mean() < np.abs(np.diff(cla, axis=0)).mean()
    # Error per frame within 1.5x classic's at the same VPL count: on average, and on
    # every frame against classic's mean (classic's own frames scatter by +-30%).
    error = ((inc - ref) ** 2).mean(1) / (ref ** 2).mean(1)
    classic_error = max(np.mean(((cla - ref) ** 2).mean(1) / (ref ** 2).mean(1)), 1e-6)
    assert error.mean() < 1.5 * classic_error, (error.mean(), classic_error)
    assert error.max() < 1.5 * classic_error, (error.max(), classic_error)


def test_incremental_recovers_at_once_when_the_light_jumps_behind_a_wall(core):
    # Two rooms split by a wall: the light jumps from one to the other, so every VPL
    # it had becomes invalid (Laine 2007 sec. 3.1). The next frame must not be left
    # with the 5% per-frame budget: it rebuilds the whole set.
    sd = core.scene_data
    wall = synthetic.grid_quad(2).astype(np.float64) @ np.array(
        [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]).T * [0, 1, 1]   # the plane x = 0
    tris = np.concatenate([synthetic.closed_box(3), wall.astype(np.float32)])
    state = core.variants.VariantState()
    settings = core.render.RenderSettings(particles=1024, max_bounces=8,
                                          variant='INCREMENTAL')
    counts, infos = [], []
    for x in (-0.5, -0.45, 0.5):
        light = sd.PointLight(np.array([x, 0.1, 0.3]), np.ones(3), 100.0, 0.0)
        cam = synthetic.camera(sd, size=8)
        data = synthetic.scene(sd, tris, [0.8] * 3, lights=[light], camera=cam)
        frame = core.frame.prepare_frame(data)
        vpls, info = core.variants.place_vpls(frame, None, settings, state)
        counts.append(vpls.count)
        infos.append(info)
    # Every site is lost, those on the wall's far side too: the light sees the wall,
    # not the side the VPL was lit from.
    assert infos[2]['removed'] == infos[0]['added'], infos
    assert (vpls.position[:, 0] > -1e-6).all()   # all in the room the light entered
    assert counts[2] > 0.8 * counts[0], counts


def test_path_traced_incident_light_of_reverse_vpls_matches_converged_classic(core):
    # Bidirectional IR's reverse VPLs get their indirect incident light E(y) by path
    # tracing; its mean over surface points must match a converged light-path estimate.
    data = closed_box_with_light(core)
    frame = core.frame.prepare_frame(data)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
    traced = core.bidirectional.path_traced_irradiance(frame, gb, 64, 16,
                                                       np.random.default_rng(1))[gb.hit]
    vpls = core.vpl.trace_vpls(frame, 20000, 16, seed=0)
    converged = core.gather.indirect_irradiance(frame, gb, vpls, 0.05,
                                                np.zeros(len(gb.hit), np.int64), 1)[gb.hit]
    assert abs(traced.mean() / converged.mean() - 1) < 0.03, (traced.mean(), converged.mean())

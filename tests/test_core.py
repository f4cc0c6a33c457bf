"""Core maths on scenes made of arrays: furnace energy, determinism, robustness."""
import contextlib
import time
import threading

import numpy as np
import pytest

import synthetic


@pytest.fixture
def core(addon):
    return addon.irad_addon


def render(core, data, **settings):
    from_settings = core.render.RenderSettings(**settings)
    return core.render.render_frame(data, from_settings)


@contextlib.contextmanager
def one_thread(core):
    """The user's preference at one thread within the block, then one per CPU core
    again, as the other tests run."""
    core.rays.set_worker_count(1)
    try:
        yield
    finally:
        core.rays.set_worker_count(0)


def ceiling_light(sd, half_size):
    """A square area light of side 2 half_size, 0.9 up, facing down."""
    return sd.AreaLight(np.array([0.0, 0.0, 0.9]), np.array([half_size, 0, 0]),
                        np.array([0, half_size, 0]), np.array([0.0, 0.0, -1.0]), np.ones(3),
                        50.0, "RECTANGLE")


@pytest.mark.parametrize("albedo", [0.5, 0.8])
def test_furnace_radiance_is_emission_over_one_minus_albedo(core, albedo):
    # A closed box that emits 1 everywhere and reflects `albedo`: L = 1 / (1 - albedo).
    data = synthetic.scene(core.scene_data, synthetic.closed_box(4), [albedo] * 3,
                           emission=(1, 1, 1), camera=synthetic.camera(core.scene_data, size=16))
    result = render(core, data, particles=32768, max_bounces=200, clamp=0.0,
                    aa_samples=1, light_samples=64)
    image = result.passes["Combined"][..., :3]
    assert np.isfinite(image).all()
    assert image.mean() == pytest.approx(1.0 / (1.0 - albedo), rel=0.01)


def test_particle_roulette_keeps_every_first_bounce_and_never_brightens_a_channel(core):
    # A closed red box: every particle hits it, and every first hit goes on (no roulette
    # there); later survivors are divided by the largest albedo (0.6), so no VPL of a
    # particle carries more red than the particle brought (the mean, 0.23, would make
    # them 2.6x brighter per bounce). Bounce 3 keeps about 0.6 of bounce 2.
    sd = core.scene_data
    light = sd.PointLight(np.array([0.1, 0.2, 0.0]), np.ones(3), 100.0, 0.0)
    albedo = [0.6, 0.05, 0.05]
    data = synthetic.scene(sd, synthetic.closed_box(3), albedo, lights=[light],
                           camera=synthetic.camera(sd, size=8))
    frame = core.frame.prepare_frame(data)
    n = 4096
    vpls = core.vpl.trace_vpls(frame, n, 8, seed=0)
    per_bounce = np.bincount(vpls.bounce, minlength=4)
    assert per_bounce[1] == n
    assert per_bounce[2] >= 0.98 * n    # all but those leaving below the surface
    assert per_bounce[3] == pytest.approx(0.6 * per_bounce[2], rel=0.05)
    first = vpls.flux[vpls.bounce == 1, 0].max()
    assert vpls.flux[:, 0].max() <= first * (1 + 1e-9)
    # Unbiased: each bounce carries albedo times the one before, in every channel.
    carried = np.array([vpls.flux[vpls.bounce == b].sum(0) for b in (1, 2, 3)])
    assert np.allclose(carried[1] / carried[0], albedo, rtol=0.05)
    assert np.allclose(carried[2, 0] / carried[1, 0], albedo[0], rtol=0.08)


def test_a_pixels_light_samples_are_one_scrambled_02_net(core):
    # Four camera samples of a pixel, four light samples each: each sample's four are a
    # (0,2,2)-net, the pixel's sixteen a (0,4,2)-net (one point in every elementary
    # interval of area 1/16), under each pixel's own random scramble.
    import types
    count, samples, pixels = 4, 4, 3
    gb = types.SimpleNamespace(width=pixels, height=1, samples=samples,
                               pixel=np.tile(np.arange(pixels), samples),
                               sample=np.repeat(np.arange(samples), pixels))
    idx = np.arange(samples * pixels)
    pattern = core.direct_light.light_sample_pattern(count, gb, idx,
                                                     np.random.default_rng(5))
    assert pattern.shape == (count, len(idx), 2)

    def net(points, k):
        return all(len({(int(x * 2 ** a), int(y * 2 ** (k - a))) for x, y in points})
                   == 2 ** k for a in range(k + 1))
    for q in range(pixels):
        mine = gb.pixel == q
        assert net(pattern[:, mine].reshape(-1, 2), 4)
        for s in range(samples):
            assert net(pattern[:, mine & (gb.sample == s)].reshape(-1, 2), 2)
    assert not np.allclose(pattern[:, 0], pattern[:, 1])   # pixels scrambled apart


def test_halton_is_stratified_and_scrambling_keeps_it(core):
    s = core.sampling
    for seed in (0, 7):
        points = s.halton(1024, 3, seed=seed, start=0)
        for d in range(3):
            base = int(s.primes(3)[d])
            strata = base ** int(np.log(1024) / np.log(base))
            # + 1e-9: k / 3^n is not exact in binary floating point.
            cell = np.floor(points[:strata, d] * strata + 1e-9).astype(int)
            counts = np.bincount(cell, minlength=strata)
            assert (counts == 1).all(), (seed, d)
    assert not np.allclose(s.halton(64, 2, seed=1), s.halton(64, 2, seed=2))


def test_compiled_halton_is_the_radical_inverse(core):
    # The compiled points are the definition's (to rounding: they sum the digits in
    # another order), plain and scrambled, in every dimension a path uses (bases 2..547).
    s = core.sampling
    dims, start = 101, 5
    for seed in (0, 3):
        points = s.halton(300, dims, seed=seed, start=start)
        index = np.arange(start, start + 300)
        for d, (base, perms) in enumerate(zip(s.primes(dims), s.scrambling(seed, dims))):
            np.testing.assert_allclose(points[:, d],
                                       s.radical_inverse(int(base), index, perms),
                                       rtol=1e-14, atol=1e-16)


@pytest.mark.parametrize("sequence", ["HALTON", "HAMMERSLEY", "JITTERED"])
def test_particle_columns_are_particle_points_drawn_on_demand(core, sequence):
    # Two lights' blocks of particles: the rows a path asks for, bounce by bounce, hold
    # the numbers particle_points gives each block up front.
    s = core.sampling
    counts, seeds, dims = [40, 25], [3, 3 + 7919], 23
    for batch in (0, 2):      # a walkthrough's third batch of paths too
        full = np.concatenate([s.particle_points(sequence, n, dims, seed, batch)
                               for n, seed in zip(counts, seeds)])
        columns = s.ParticleColumns(sequence, counts, seeds, 5, dims, batch)
        rows = np.array([64, 0, 39, 40, 41, 7])
        for a in range(0, dims - 5, 3):
            np.testing.assert_array_equal(columns[rows, a:a + 3], full[rows, 5 + a:8 + a])


def test_halton_batches_continue_one_sequence(core):
    # Batches 0..2 of 64 particles are the Halton points 1..192 of one shot of 192.
    s = core.sampling
    batches = np.concatenate([s.particle_points("HALTON", 64, 9, 4, b) for b in range(3)])
    np.testing.assert_array_equal(batches, s.particle_points("HALTON", 192, 9, 4))


def test_same_seed_same_image_other_seed_other_noise(core):
    sd = core.scene_data
    light = sd.PointLight(np.array([0.0, 0.0, 0.5]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(2), [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=16))
    a = render(core, data, particles=64, seed=3).passes["Combined"]
    b = render(core, data, particles=64, seed=3).passes["Combined"]
    c = render(core, data, particles=64, seed=4).passes["Combined"]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)



def test_work_beside_the_background_gather_changes_nothing(core, monkeypatch):
    # render_band gathers VPL light, then compensates the clamp, on the pool's workers
    # while its own thread traces direct light and the film (rays.on_calling_thread):
    # the image must be the one of the same work done one stage after another.
    sd = core.scene_data
    block = synthetic.closed_box(1, 0.2) + np.array([0.2, 0.0, -0.6], np.float32)
    light = sd.AreaLight(np.array([0.0, 0.0, 0.95]), np.array([0.2, 0, 0]),
                         np.array([0, 0.2, 0]), np.array([0.0, 0.0, -1.0]), np.ones(3), 50.0,
                         "RECTANGLE")
    data = synthetic.scene(sd, np.concatenate([synthetic.closed_box(3), block]), [0.7] * 3,
                           lights=[light], camera=synthetic.camera(sd, size=24))
    settings = dict(particles=512, seed=3)
    beside = []
    parallel_map, group_irradiance = core.rays.parallel_map, core.gather.group_irradiance
    mirrored_light = core.render.mirrored_light
    band_done = threading.Event()

    def spy(function, ranges):
        beside.append(core.rays.on_calling_thread_now())
        return parallel_map(function, ranges)

    def slow_gather(*args, **kwargs):   # the workers' tasks wait for the band's thread
        if threading.current_thread() is not threading.main_thread():
            band_done.wait(timeout=30)
        return group_irradiance(*args, **kwargs)

    def then_release(*args, **kwargs):   # the last of the band's work beside the gather
        try:
            return mirrored_light(*args, **kwargs)
        finally:
            band_done.set()

    monkeypatch.setattr(core.rays, "parallel_map", spy)
    monkeypatch.setattr(core.gather, "group_irradiance", slow_gather)
    monkeypatch.setattr(core.render, "mirrored_light", then_release)
    overlapped = render(core, data, **settings).passes
    assert any(beside)   # some of the band's rays were traced beside the gather
    monkeypatch.setattr(core.rays, "on_calling_thread",
                        lambda busy=None: contextlib.nullcontext())
    beside.clear()
    in_turn = render(core, data, **settings).passes
    assert not any(beside)
    for name in ("Combined", "IRAD Direct", "IRAD Indirect"):
        assert np.array_equal(overlapped[name], in_turn[name]), name
    assert overlapped["IRAD Indirect"].max() > 0


@pytest.mark.parametrize("variant", ["CLASSIC", "BIDIRECTIONAL"])
def test_vpls_traced_beside_the_camera_rays_change_nothing(core, monkeypatch, variant):
    # render_frame traces these variants' VPLs on a worker while its own thread traces
    # the first band's camera rays: the image must be the one of one after the other.
    sd = core.scene_data
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(3), [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=24))
    traced_on = []
    vpls_for_frame = core.variants.vpls_for_frame

    def spy(*args):
        traced_on.append(threading.current_thread() is threading.main_thread())
        return vpls_for_frame(*args)

    monkeypatch.setattr(core.variants, "vpls_for_frame", spy)
    beside = render(core, data, particles=256, seed=2, variant=variant).passes
    monkeypatch.setattr(core.render, "BESIDE_CAMERA_RAYS", ())
    in_turn = render(core, data, particles=256, seed=2, variant=variant).passes
    assert traced_on == [False, True]
    for name in ("Combined", "IRAD Direct", "IRAD Indirect"):
        assert np.array_equal(beside[name], in_turn[name]), name
    assert beside["IRAD Indirect"].max() > 0


def test_one_thread_preference_keeps_the_gather_and_vpls_on_the_render_thread(core,
                                                                            monkeypatch):
    # With the user's preference at one thread, nothing runs beside the render thread:
    # the gather, the compensation and the VPLs wait their turn.
    sd = core.scene_data
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(3), [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=16))
    threads = set()
    group_irradiance, vpls_for_frame = core.gather.group_irradiance, core.variants.vpls_for_frame

    def spy(function):
        def run(*args, **kwargs):
            threads.add(threading.current_thread())
            return function(*args, **kwargs)
        return run

    monkeypatch.setattr(core.gather, "group_irradiance", spy(group_irradiance))
    monkeypatch.setattr(core.variants, "vpls_for_frame", spy(vpls_for_frame))
    with one_thread(core):
        image = render(core, data, particles=128, seed=1).passes["IRAD Indirect"]
    assert threads == {threading.current_thread()}
    assert image.max() > 0

def test_shared_map_takes_a_free_workers_help_and_never_waits_on_a_busy_one(core):
    rays = core.rays
    done_by, took = {}, {True: threading.Event(), False: threading.Event()}
    here = threading.current_thread()

    def task(i):
        # Each thread's first task waits (a while at most) until the other has one.
        mine = threading.current_thread() is here
        took[mine].set()
        took[not mine].wait(5.0)
        done_by[i] = threading.current_thread()
        return i * i

    assert rays.shared_map(task, 12) == [i * i for i in range(12)]
    helpers = {t for t in done_by.values() if t is not here}
    assert len(helpers) == 1 and here in done_by.values()   # both took tasks
    # Workers held by queued work: everything runs here, and the idle helper is
    # withdrawn instead of waited for.
    release = threading.Event()
    held = [rays.thread_pool().submit(release.wait) for _ in range(rays.worker_count())]
    try:
        done_by.clear()
        took[False].set()   # no waiting now: nobody can help
        started = time.perf_counter()
        assert rays.shared_map(task, 6) == [i * i for i in range(6)]
        assert set(done_by.values()) == {here}
        assert time.perf_counter() - started < 1.0
    finally:
        release.set()
        for future in held:
            future.result()
    with pytest.raises(ZeroDivisionError):
        rays.shared_map(lambda i: 1 // (i - 3), 6)


def test_a_queued_job_runs_on_the_thread_that_waits_for_it(core):
    # Workers held by other work: waiting for a job still queued does it here, and
    # the gather's queued tasks likewise, instead of idling behind the queue.
    rays = core.rays
    here = threading.current_thread()
    release = threading.Event()
    held = [rays.thread_pool().submit(release.wait) for _ in range(rays.worker_count())]
    try:
        job = rays.submit_whole(lambda: threading.current_thread())
        assert job.result() is here
        sd = core.scene_data
        light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
        data = synthetic.scene(sd, synthetic.closed_box(3), [0.7] * 3, lights=[light],
                               camera=synthetic.camera(sd, size=32))
        frame = core.frame.prepare_frame(data)
        gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
        vpls = core.vpl.trace_vpls(frame, 256, 8, seed=0)
        everyone = np.zeros(len(gb.hit), np.int64)
        pending = core.gather.start_indirect(frame, gb, vpls, 0.05, everyone, 1)
        assert len(pending.jobs) > 1
        E = pending.wait()
    finally:
        release.set()
        for future in held:
            future.result()
    free = core.gather.indirect_irradiance(frame, gb, vpls, 0.05, everyone, 1)
    assert np.array_equal(E, free) and E.max() > 0


def test_the_image_does_not_depend_on_the_thread_count(core):
    # VPLs, gather, compensation and direct light run on workers beside the render
    # thread, in tasks of their own: the same image as on one thread.
    sd = core.scene_data
    light = ceiling_light(sd, 0.3)
    panel = synthetic.grid_quad(2, 0.4).astype(np.float64) + [0.0, 0.0, -0.3]
    triangles = np.concatenate([synthetic.closed_box(3), panel.astype(np.float32)])
    data = synthetic.scene(sd, triangles, [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=48))
    shared = render(core, data, particles=256, seed=2).passes["Combined"]
    with one_thread(core):
        alone = render(core, data, particles=256, seed=2).passes["Combined"]
    assert np.array_equal(shared, alone) and shared.max() > 0


def test_direct_light_does_not_depend_on_the_thread_that_ran_it(core):
    # direct_irradiance's tasks of points may run on a worker: the same light either way.
    sd = core.scene_data
    light = ceiling_light(sd, 0.2)
    data = synthetic.scene(sd, synthetic.closed_box(3), [0.7] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=64))
    frame = core.frame.prepare_frame(data)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 4, np.random.default_rng(0))
    assert gb.hit.sum() >= 2 * core.direct_light.POINTS_PER_TASK   # several tasks
    shared = core.direct_light.direct_irradiance(frame, gb, 4, np.random.default_rng(1))
    with one_thread(core):
        alone = core.direct_light.direct_irradiance(frame, gb, 4, np.random.default_rng(1))
    assert np.array_equal(shared, alone) and shared.max() > 0


def test_compiled_triangle_quantities_match_numpy(core):
    g = core.geometry
    rng = np.random.default_rng(3)
    tris = rng.normal(size=(500, 3, 3)) * [1, 2, 3] + 1000.0   # far from the origin
    tris[7, 2] = tris[7, 1]                                      # a degenerate one
    for t in (tris, tris.astype(np.float32)):
        d = t.astype(np.float64)
        cross = np.cross(d[:, 1] - d[:, 0], d[:, 2] - d[:, 0])
        areas, normals = g.triangle_areas(t), g.geometric_normals(t)
        np.testing.assert_allclose(areas, 0.5 * np.linalg.norm(cross, axis=1),
                                   rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(2 * areas[:, None] * normals, cross, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(normals[np.arange(500) != 7], axis=1), 1.0)
        assert np.all(normals[7] == 0)
        lo, hi = g.coordinate_bounds(t)
        np.testing.assert_array_equal(lo, d.reshape(-1, 3).min(0))
        np.testing.assert_array_equal(hi, d.reshape(-1, 3).max(0))
    bad = tris.copy()
    bad[3, 0, 1] = np.nan
    bad[4, 2, 2] = np.inf
    keep = g.nondegenerate(bad, 10.0)
    assert not keep[[3, 4, 7]].any() and keep.sum() == 497
    lo, hi = g.coordinate_bounds(bad)   # non-finite coordinates are left out
    assert np.isfinite(lo).all() and np.isfinite(hi).all()


def test_degenerate_and_nan_triangles_are_skipped_without_nan(core):
    sd = core.scene_data
    box = synthetic.closed_box(2)
    bad = np.array([[[0, 0, 0], [0, 0, 0], [0, 0, 0]],          # a point
                    [[0, 0, 0], [1, 1, 1], [2, 2, 2]],          # collinear
                    [[np.nan, 0, 0], [1, 0, 0], [0, 1, 0]]],    # NaN
                   np.float32)
    tris = np.concatenate([box, bad])
    normals = np.concatenate([synthetic.flat_normals(box), np.full((3, 3, 3), np.nan, np.float32)])
    light = sd.PointLight(np.array([0.0, 0.0, 0.0]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, tris, [0.5] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=16), normals=normals)
    result = render(core, data, particles=64)
    for image in result.passes.values():
        assert np.isfinite(image).all()
    assert result.passes["Combined"][..., :3].min() >= 0
    assert any("3 degenerate triangles" in w for w in result.warnings)


def test_zero_power_and_zero_area_lights_give_black_not_nan(core):
    sd = core.scene_data
    lights = [sd.PointLight(np.zeros(3), np.ones(3), 0.0, 0.0),
              sd.AreaLight(np.zeros(3), np.zeros(3), np.zeros(3), np.array([0, 0, -1.0]),
                           np.ones(3), 100.0, 'RECTANGLE'),
              sd.SpotLight(np.zeros(3), np.array([0, 0, -1.0]), np.ones(3), 100.0, 0.0, 0.0, 0.0)]
    data = synthetic.scene(sd, synthetic.closed_box(2), [0.5] * 3, lights=lights,
                           camera=synthetic.camera(sd, size=16))
    result = render(core, data, particles=64)
    assert np.isfinite(result.passes["Combined"]).all()
    assert result.passes["Combined"][..., :3].max() == 0
    assert any("no light with non-zero power" in w for w in result.warnings)


def test_bvh_reused_while_geometry_is_unchanged(core):
    sd = core.scene_data
    cache = core.rays.RayTracerCache()
    light = sd.PointLight(np.array([0.0, 0.0, 0.5]), np.ones(3), 100.0, 0.0)
    box = synthetic.closed_box(2)
    settings = core.render.RenderSettings(particles=16, aa_samples=1)
    for position in ([0, 0, 0.5], [0.2, 0, 0.5]):   # the light moves, geometry does not
        light.position = np.array(position)
        data = synthetic.scene(sd, box, [0.5] * 3, lights=[light], camera=synthetic.camera(sd, size=8))
        core.render.render_frame(data, settings, tracer_cache=cache)
    assert cache.builds == 1
    data = synthetic.scene(sd, box * 1.5, [0.5] * 3, lights=[light], camera=synthetic.camera(sd, size=8))
    core.render.render_frame(data, settings, tracer_cache=cache)
    assert cache.builds == 2


@pytest.mark.parametrize("scale", [1e-3, 1e4])
def test_scene_scale_does_not_change_the_image(core, scale):
    # The same closed room at another scale, with the light's power scaled by scale^2 so
    # irradiance is unchanged: no acne, no leaks, the same picture.
    sd = core.scene_data

    def room(s):
        light = sd.PointLight(np.array([0.3, 0.2, 0.6]) * s, np.ones(3), 100.0 * s * s, 0.0)
        cam = synthetic.camera(sd, size=24)
        cam.matrix_world = np.diag([1.0, 1.0, 1.0, 1.0])
        # Off the box's axis: a pixel ray exactly along a concave edge is a measure-zero
        # case where the hit lies on both walls at once.
        cam.matrix_world[:3, 3] = [0.05 * s, 0.03 * s, 0.5 * s]
        cam.clip_start, cam.clip_end = 1e-3 * s, 1e4 * s
        return synthetic.scene(sd, synthetic.closed_box(3) * np.float32(s), [0.6] * 3,
                               lights=[light], camera=cam)

    settings = dict(particles=256, aa_samples=1, seed=1)
    base = render(core, room(1.0), **settings).passes["Combined"][..., :3]
    scaled = render(core, room(scale), **settings).passes["Combined"][..., :3]
    assert np.isfinite(scaled).all()
    assert np.abs(scaled - base).max() <= 1e-3 * base.max()


@pytest.mark.parametrize("aa_samples", [1, 4])
def test_bias_compensation_restores_what_the_clamp_removes(core, aa_samples):
    # Furnace (albedo 0.5): a wide clamp darkens the image; compensation (Kollig & Keller
    # 2004) brings back most of the lost energy with the same VPLs. Its two rays per
    # pixel leave one shading sample twice, or two samples once.
    data = synthetic.scene(core.scene_data, synthetic.closed_box(4), [0.5] * 3,
                           emission=(1, 1, 1), camera=synthetic.camera(core.scene_data, size=16))

    def mean(clamp, compensate):
        return render(core, data, particles=8192, max_bounces=100, clamp=clamp,
                      bias_compensation=compensate, aa_samples=aa_samples, interleave=1,
                      light_samples=16, seed=0).passes["Combined"][..., :3].mean()

    unclamped, clamped, compensated = mean(0.0, False), mean(8.0, False), mean(8.0, True)
    lost = unclamped - clamped
    assert lost > 0.005
    assert abs(unclamped - compensated) < 0.3 * lost


@pytest.mark.parametrize("sequence", ["HALTON", "HAMMERSLEY", "JITTERED"])
def test_every_particle_sequence_converges_in_the_furnace(core, sequence):
    points = core.sampling.particle_points(sequence, 1024, 4, seed=5)
    assert points.min() >= 0 and points.max() < 1
    counts = np.bincount((points[:, 0] * 8).astype(int), minlength=8)
    assert (counts == 128).all()   # the first dimension is stratified for all three
    data = synthetic.scene(core.scene_data, synthetic.closed_box(4), [0.5] * 3,
                           emission=(1, 1, 1), camera=synthetic.camera(core.scene_data, size=16))
    image = render(core, data, particles=32768, max_bounces=200, clamp=0.0, aa_samples=1,
                   interleave=1, light_samples=64, sequence=sequence).passes["Combined"]
    assert image[..., :3].mean() == pytest.approx(2.0, rel=0.01)


@pytest.mark.parametrize("shape", ["RECTANGLE", "ELLIPSE"])
def test_compiled_area_light_segments_are_the_emitters_estimator(core, shape):
    # direct_light.direct_irradiance takes an area light's shadow segments from one compiled
    # pass; they must be what incident() gives, sample by sample.
    rng = np.random.default_rng(4)
    light = core.lights.AreaEmitter(core.scene_data.AreaLight(
        np.array([0.1, 0.2, 1.0]), np.array([0.4, 0.1, 0.0]), np.array([-0.05, 0.2, 0.0]),
        np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.8, 0.6]), 50.0, shape))
    P = rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.5]
    N = rng.normal(size=(200, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    G = N + rng.normal(size=(200, 3))   # some light comes through the surface: refused
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    pattern = rng.random((3, 200, 2))
    centre = np.array([0.3, -0.2, 0.1])   # segments are in the tracer's frame
    fused = core.light_sampling.ShadowSegments(600)
    rows = light.shadow_segments(P, N, G, pattern, 1e-4, centre, fused)
    reference, start = core.light_sampling.ShadowSegments(600), 0
    for u in pattern:
        direction, dist, e = light.incident(P, N, u)
        start = core.light_sampling.shadow_segments(P, G, direction, dist, e, 1e-4, centre,
                                                    reference, start)
    assert rows == start and rows > 50
    for a, b in zip(fused.arrays, reference.arrays):
        np.testing.assert_allclose(a[:rows], b[:rows], rtol=1e-6, atol=1e-6)
    point = fused.point[:rows]
    np.testing.assert_allclose(fused.origin[:rows] + centre, P[point] + 1e-4 * G[point],
                               rtol=1e-6, atol=1e-6)


def test_closed_form_rectangle_irradiance_is_the_samples_expectation(core):
    # The unoccluded irradiance direct light scales by its visible share must be the
    # mean of the sampled estimator, clipped to both normals' hemispheres (many points
    # see the light cross their horizon).
    rng = np.random.default_rng(7)
    light = core.lights.AreaEmitter(core.scene_data.AreaLight(
        np.array([0.1, 0.2, 1.0]), np.array([0.4, 0.1, 0.0]), np.array([-0.05, 0.2, 0.0]),
        np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.8, 0.6]), 50.0, "RECTANGLE"))
    n = 400
    P = rng.uniform(-1.5, 1.5, (n, 3)) * [1, 1, 0.5] - [0, 0, 0.25]   # 0.5+ below it
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    G = N + 0.4 * rng.normal(size=(n, 3))
    G /= np.linalg.norm(G, axis=1, keepdims=True)
    exact = light.unoccluded_irradiance(P, N, G)[:, 0]
    m = 4096
    pattern = rng.random((m, n, 2))
    rows = m * n
    out = core.light_sampling.ShadowSegments(rows)
    rows = light.shadow_segments(P, N, G, pattern, 1e-4, np.zeros(3), out)
    point, energy = out.point[:rows], out.energy[:rows, 0]
    mean = np.bincount(point, energy, n) / m
    sd = np.sqrt(np.maximum(np.bincount(point, energy ** 2, n) / m - mean ** 2, 0) / m)
    clipped = ((N @ np.array([0, 0, 1.0])) < 0.9).sum()
    assert (exact > 0).sum() > 100 and clipped > 100
    assert np.all(np.abs(mean - exact) <= 5 * sd + 1e-6 * exact.max()), \
        np.abs(mean - exact).max()
    assert np.all(exact[mean == 0] < 1e-3 * exact.max())   # nothing where no sample lands
    assert light.unoccluded_irradiance(P, N, G).shape == (n, 3)
    ellipse = core.lights.AreaEmitter(core.scene_data.AreaLight(
        light.center, light.axis_u, light.axis_v, light.normal, np.ones(3), 50.0, "ELLIPSE"))
    assert ellipse.unoccluded_irradiance(P, N, G) is None   # sampled as before


def test_direct_light_is_noise_free_where_the_whole_area_light_is_seen(core):
    # A square light over a plane with a small occluder: pixels that see the whole light
    # get its closed-form irradiance whatever the seed; the penumbra keeps sampled
    # noise, and its mean over seeds is the plain estimator's.
    plane = synthetic.grid_quad(8, 2.0) * [1, 1, 0]
    blocker = synthetic.grid_quad(1, 0.2) * [1, 1, 0] + [0.5, 0.0, 0.6]
    light = core.scene_data.AreaLight(np.array([0.0, 0.0, 1.5]), np.array([0.3, 0, 0]),
                                      np.array([0, 0.3, 0]), np.array([0.0, 0.0, -1.0]),
                                      np.ones(3), 100.0, "RECTANGLE")
    cam = synthetic.camera(core.scene_data, np.array(
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3.0], [0, 0, 0, 1]]), size=24)
    data = synthetic.scene(core.scene_data, np.concatenate([plane, blocker]), [0.8] * 3,
                           lights=[light], camera=cam)

    def direct(seed):
        result = render(core, data, particles=64, max_bounces=0, aa_samples=1,
                        coverage_samples=0, interleave=1, light_samples=4, seed=seed)
        return result.passes["IRAD Direct"][..., 0].astype(np.float64)

    images = np.array([direct(seed) for seed in range(24)])
    spread = images.std(0) / images.mean(0).max()
    assert np.isfinite(images).all()
    lit = images.mean(0) > 0
    noise_free = (spread < 1e-6)[lit].mean()
    assert 0.7 < noise_free < 0.99, noise_free   # most pixels; the penumbra is noisy
    assert spread.max() > 0.01
    # The noise-free pixels are exactly the analytic irradiance rho/pi * L * factor.
    frame = core.frame.prepare_frame(data, core.rays.RayTracerCache())
    gb = core.gbuffer.build_gbuffer(frame, cam, 1, np.random.default_rng(0))
    E = core.direct_light.direct_irradiance(frame, gb, 4, np.random.default_rng(0))
    exact = frame.emitters[0].unoccluded_irradiance(gb.position, gb.normal, gb.geo_normal)
    visible_all = np.isclose(E[:, 0], exact[:, 0], rtol=1e-9)
    assert visible_all.mean() > 0.5
    # The penumbra's mean converges to the plain (unbiased) estimator's.
    plain = [core.direct_light.direct_irradiance(frame, gb, 64, np.random.default_rng(s))
             for s in range(8)]
    ours = [core.direct_light.direct_irradiance(frame, gb, 4, np.random.default_rng(100 + s))
            for s in range(64)]
    shaded = ~visible_all & (exact[:, 0] > 0)
    rel = np.abs(np.mean(ours, 0) - np.mean(plain, 0))[shaded, 0].mean() / exact[:, 0].max()
    assert shaded.sum() > 10 and rel < 0.01, rel

"""Temporal reuse for walkthroughs: camera-only animation reuses the VPL set."""
from dataclasses import replace

import numpy as np

import synthetic


def test_camera_fly_through_reuses_vpls_and_a_moving_light_does_not(addon):
    core = addon.irad_addon
    sd = core.scene_data
    cache = core.temporal.PathWindow()
    settings = core.render.RenderSettings(particles=256, use_lightcuts=True)
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)

    def frame(camera_x, light_x=0.2):
        cam = synthetic.camera(sd, size=16)
        cam.matrix_world[:3, 3] = [camera_x, 0.0, 0.3]
        light.position = np.array([light_x, 0.1, 0.6])
        data = synthetic.scene(sd, synthetic.closed_box(3), [0.6] * 3, lights=[light], camera=cam)
        result = core.render.render_frame(data, settings, path_window=cache)
        result.scene_data = data
        return result

    first = frame(0.0)
    second = frame(0.3)                      # only the camera moved
    assert cache.reused == 1 and second.vpls is first.vpls
    # The light trees built for the first frame are reused too.
    assert any(key[0] == "light_tree" for key in first.vpls.derived)
    # Reusing is exact: the same picture as tracing the same seed's particles anew.
    fresh = core.render.render_frame(second.scene_data, settings)
    assert np.array_equal(fresh.passes["Combined"], second.passes["Combined"])
    third = frame(0.3, light_x=-0.2)         # the light moved: new VPLs
    assert cache.reused == 1 and third.vpls is not second.vpls
    assert not np.allclose(third.passes["IRAD Indirect"], second.passes["IRAD Indirect"])


def test_smoothed_normals_give_new_vpls(addon):
    # The same triangles shaded smooth instead of flat: particles bounce about other
    # normals, so the last frame's VPLs must not be reused.
    core = addon.irad_addon
    sd = core.scene_data
    cache = core.temporal.PathWindow()
    settings = core.render.RenderSettings(particles=256)
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
    box = synthetic.closed_box(3)
    flat = synthetic.scene(sd, box, [0.6] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=16))
    centred = box.astype(np.float64)   # normals pointing away from the centre
    smooth = synthetic.scene(sd, box, [0.6] * 3, lights=[light],
                             camera=synthetic.camera(sd, size=16),
                             normals=(centred / np.linalg.norm(centred, axis=2,
                                                               keepdims=True)).astype(np.float32))
    first = core.render.render_frame(flat, settings, path_window=cache)
    second = core.render.render_frame(smooth, settings, path_window=cache)
    assert cache.reused == 0 and second.vpls is not first.vpls


def _box_frames(core, settings, window, lights, cameras, frames=None):
    """Render a closed box once per (light position, camera x); the results."""
    sd = core.scene_data
    results = []
    for number, (light_at, camera_x) in enumerate(zip(lights, cameras)):
        cam = synthetic.camera(sd, size=16)
        cam.matrix_world[:3, 3] = [camera_x, 0.0, 0.3]
        light = sd.PointLight(np.array(light_at, float), np.ones(3), 100.0, 0.0)
        data = synthetic.scene(sd, synthetic.closed_box(3), [0.6] * 3, lights=[light],
                               camera=cam)
        step = settings(number) if callable(settings) else settings
        result = core.render.render_frame(
            data, step, path_window=window,
            frame_number=None if frames is None else frames[number])
        result.scene_data = data
        results.append(result)
    return results


def _sorted_vpls(vpls):
    order = np.lexsort(np.round(vpls.position, 9).T)
    return vpls.position[order], vpls.flux[order]


def test_walkthrough_gathers_the_last_frames_paths(addon):
    # A camera fly-through with a window of 8 frames: each of the first eight frames
    # traces one more batch of 256 particles; from then on all eight are reused. The
    # union is exactly one shot of 2048 particles (the batches continue the Halton
    # sequence), so the fly-through converges as far as 8x the particles.
    core = addon.irad_addon
    window = core.temporal.PathWindow()
    # Every VPL gathered by every pixel sample (no shadow-ray roulette, no interleaved
    # groups): the image depends on the VPL set, not on its order.
    settings = core.render.RenderSettings(particles=256, temporal_frames=8, aa_samples=1,
                                          shadow_ray_budget=1e9, interleave=1)
    frames = _box_frames(core, settings, window, [[0.2, 0.1, 0.6]] * 10,
                         np.linspace(0, 0.3, 10))
    assert [f.stats["path_frames"] for f in frames] == [1, 2, 3, 4, 5, 6, 7, 8, 8, 8]
    assert window.reused == 2 and frames[9].vpls is frames[8].vpls is frames[7].vpls
    data = frames[0].scene_data
    one_shot = core.vpl.trace_vpls(core.frame.prepare_frame(data), 2048,
                                   settings.max_bounces, seed=settings.seed)
    for ours, theirs in zip(_sorted_vpls(frames[7].vpls), _sorted_vpls(one_shot)):
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-15)
    # At the first frame's camera: the eighth frame's picture is that of one shot of
    # 2048 particles, and much closer to many particles' than the first frame's.
    def indirect(**kwargs):
        return core.render.render_frame(data, **kwargs).passes["IRAD Indirect"]

    truth = indirect(settings=replace(settings, particles=32768))
    first, eighth = indirect(settings=settings), indirect(settings=settings,
                                                          vpls=frames[7].vpls)
    np.testing.assert_allclose(eighth, indirect(settings=replace(settings, particles=2048)),
                               rtol=1e-4, atol=1e-6)
    error = lambda image: np.mean((image - truth) ** 2) / np.mean(truth ** 2)
    assert error(eighth) < 0.6 * error(first), (error(eighth), error(first))


def test_window_smooths_bounce_light_over_frames(addon):
    # Temporal anti-aliasing: with a new seed each frame (an animated seed), every
    # frame's own paths flicker; a window of 4 frames shares 3 of 4 batches with the
    # frame before, so the frame-to-frame change of the bounce light falls, ideally N
    # times for N frames (measured: 1.3x at 2, 1.9x at 4, 3x at 8; the clamp distance
    # follows the union's size). Each frame's VPLs are gathered with the same camera
    # samples, so only they differ.
    core = addon.irad_addon
    light, cameras = [[0.2, 0.1, 0.6]] * 10, [0.0] * 10

    def flicker(frames_kept):
        settings = lambda n: core.render.RenderSettings(particles=256, seed=n,
                                                         temporal_frames=frames_kept)
        frames = _box_frames(core, settings, core.temporal.PathWindow(), light, cameras)
        assert frames[-1].stats["path_frames"] == frames_kept
        indirect = np.array([core.render.render_frame(
            frames[0].scene_data, settings(0), vpls=f.vpls).passes["IRAD Indirect"]
            for f in frames[5:]])
        return np.sqrt(np.mean(np.diff(indirect, axis=0) ** 2))

    by_window = {n: flicker(n) for n in (1, 2, 4, 8)}
    assert by_window[8] < by_window[4] < by_window[2] < by_window[1], by_window
    assert by_window[4] < 0.6 * by_window[1] and by_window[8] < 0.4 * by_window[1], by_window


def test_window_starts_anew_on_a_jump_an_edit_or_new_settings(addon):
    core = addon.irad_addon
    window = core.temporal.PathWindow()
    settings = core.render.RenderSettings(particles=256, temporal_frames=3)
    a, b = [0.2, 0.1, 0.6], [-0.2, 0.1, 0.6]
    kept = lambda lights, frames, s=settings: [
        f.stats["path_frames"] for f in _box_frames(core, s, window, lights, [0.0] * len(
            lights), frames)]
    # A light moving every frame: the window slides, it never reuses.
    assert kept([a, b, a, b], [1, 2, 3, 4]) == [1, 2, 3, 3] and window.reused == 0
    assert kept([a], [9]) == [1]                      # a jump in time
    assert kept([a, b], [10, 10]) == [2, 1]           # an edit re-rendered on frame 10
    assert kept([b], [11], core.render.RenderSettings(particles=512,
                                                      temporal_frames=3)) == [1]
    # Another shot (the engine: another scene or .blend) on the next frame number.
    window.lookup(b"a", settings, 3, 12, shot="scene A")
    window.store(b"a", core.vpl.VPLs.empty(), 3)
    assert window.lookup(b"b", settings, 3, 13, shot="scene B") is None
    assert window.next_batch == 0 and window.batches == 0
    # Bidirectional paths follow the camera: the window keeps one frame's.
    bidir = core.render.RenderSettings(particles=256, temporal_frames=3,
                                       variant='BIDIRECTIONAL')
    assert kept([a, a], [1, 2], bidir) == [1, 1]

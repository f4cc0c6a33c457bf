"""Temporal reuse for walkthroughs: camera-only animation reuses the VPL set."""
import numpy as np

import synthetic


def test_camera_fly_through_reuses_vpls_and_a_moving_light_does_not(addon):
    core = addon.irad_addon
    sd = core.scene_data
    cache = core.temporal.VplCache()
    settings = core.render.RenderSettings(particles=256, use_lightcuts=True)
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)

    def frame(camera_x, light_x=0.2):
        cam = synthetic.camera(sd, size=16)
        cam.matrix_world[:3, 3] = [camera_x, 0.0, 0.3]
        light.position = np.array([light_x, 0.1, 0.6])
        data = synthetic.scene(sd, synthetic.closed_box(3), [0.6] * 3, lights=[light], camera=cam)
        result = core.render.render_frame(data, settings, vpl_cache=cache)
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
    cache = core.temporal.VplCache()
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
    first = core.render.render_frame(flat, settings, vpl_cache=cache)
    second = core.render.render_frame(smooth, settings, vpl_cache=cache)
    assert cache.reused == 0 and second.vpls is not first.vpls

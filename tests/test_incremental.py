"""Incremental IR beside other lights: the classic VPLs of the lights it does not
handle are traced again only when those lights (or the geometry) change."""
from dataclasses import replace

import numpy as np

import synthetic


def box_with_lights(core, point_position, area_power):
    sd = core.scene_data
    point = sd.PointLight(np.array(point_position, np.float64), np.ones(3), 100.0, 0.0)
    area = sd.AreaLight(np.array([0.0, 0.0, 0.95]), np.array([0.2, 0.0, 0.0]),
                        np.array([0.0, 0.2, 0.0]), np.array([0.0, 0.0, -1.0]), np.ones(3),
                        area_power, 'RECTANGLE')
    return synthetic.scene(sd, synthetic.closed_box(3), [0.6] * 3, lights=[point, area],
                           camera=synthetic.camera(sd, size=8))


def test_other_lights_keep_their_vpls_while_they_stay(addon):
    core = addon.irad_addon
    cache = core.rays.RayTracerCache()
    state = core.variants.VariantState()
    settings = core.render.RenderSettings(particles=512, max_bounces=8, variant='INCREMENTAL')

    def frame_vpls(point_position, area_power):
        frame = core.frame.prepare_frame(box_with_lights(core, point_position, area_power),
                                         cache)
        counting = core.rays.CountingTracer(frame.tracer)
        vpls, info = core.variants.place_vpls(replace(frame, tracer=counting), None,
                                              settings, state)
        area = vpls.subset(slice(info['incremental_vpls'], None))   # after the point light's
        return area, info, counting.rays

    area0, info, rays0 = frame_vpls((0.3, 0.0, 0.2), 40.0)
    area1, info, rays1 = frame_vpls((0.31, 0.02, 0.2), 40.0)   # the point light moves
    sites = sum(len(s.direction) for s in state.incremental.sites)
    # Its sites are checked (a ray each) and a few refilled; the area light's particles
    # (a third of the 512, ~2.5 rays each) are not traced again.
    assert rays1 < sites + 0.25 * (rays0 - sites), (rays1, rays0, sites)
    assert np.array_equal(area0.position, area1.position)      # the area light's VPLs stay
    assert np.array_equal(area0.flux, area1.flux)
    area2, _, _ = frame_vpls((0.32, 0.04, 0.2), 80.0)          # the area light brightens
    # Traced again for the new power: in the closed box every particle hits a wall, so
    # the first bounces carry the light's power times the albedo.
    first = lambda v: v.flux[v.bounce == 1].sum(0)   # noqa: E731
    assert np.allclose(first(area1), 0.6 * 40.0, rtol=1e-6)
    assert np.allclose(first(area2), 0.6 * 80.0, rtol=1e-6)

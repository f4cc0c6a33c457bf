"""Lightcuts (Walter et al. 2005) against the exhaustive VPL gather, on synthetic scenes."""
import importlib

import numpy as np
import pytest

import synthetic


@pytest.fixture(scope="module")
def core(addon):
    modules = {name: importlib.import_module(f"{addon.__name__}.irad_addon.{name}")
               for name in ("light_tree", "lightcuts", "cluster_bounds", "gather", "vpl",
                            "frame", "gbuffer", "render", "scene_data")}
    return type("Core", (), modules)


def box_scene(core, occluder, size, particles):
    """A closed box lit by a point light, seen from inside; optionally a flat slab
    between the light and the floor, so that visibility matters. Returns the frame,
    the VPLs, the G-buffer points (P, N, G) and the clamp distance squared."""
    sd = core.scene_data
    tris = synthetic.closed_box(4)
    if occluder:
        slab = synthetic.closed_box(2, 0.35) * np.float32([1.4, 1.4, 0.2]) + np.float32([0.1, 0, 0.1])
        tris = np.concatenate([tris, slab.astype(np.float32)])
    eye = np.eye(4)
    eye[:3, 3] = [0, 0, 0.95]
    light = sd.PointLight(np.array([0.3, 0.2, 0.6]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, tris, [0.7, 0.6, 0.5], lights=[light],
                           camera=synthetic.camera(sd, eye, size=size))
    frame = core.frame.prepare_frame(data)
    vpls = core.vpl.trace_vpls(frame, particles, 8, seed=1)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
    hit = np.flatnonzero(gb.hit)
    dmin2 = core.render.clamp_distance(frame, vpls, 1.0) ** 2
    return frame, vpls, (gb.position[hit], gb.normal[hit], gb.geo_normal[hit]), dmin2


def exhaustive(core, frame, vpls, points, dmin2):
    P, N, G = points
    step = max(1, (1 << 20) // vpls.count)
    return np.concatenate([core.gather.vpl_irradiance_chunk(
        P[a:a + step], N[a:a + step], G[a:a + step], vpls.position, vpls.normal, vpls.flux,
        dmin2, frame.tracer, frame.offset()) for a in range(0, len(P), step)])


def lightcut(core, frame, vpls, points, dmin2, error=0.02, max_cut=1000):
    tree = core.light_tree.build_light_tree(vpls.position, vpls.normal, vpls.flux)
    return core.lightcuts.lightcut_irradiance(*points, tree, error, max_cut, dmin2,
                                              frame.tracer, frame.offset())


def relative_difference(E, reference):
    """Per point, the largest channel difference over the reference's mean; points
    that get almost nothing (box edges: E ~ 1e-8) are measured against a floor."""
    level = reference.mean(1)
    return np.abs(E - reference).max(1) / np.maximum(level, 1e-3 * np.median(level))


@pytest.mark.parametrize("occluder", [False, True], ids=["box", "occluder"])
def test_lightcuts_match_the_exhaustive_gather(core, occluder):
    frame, vpls, points, dmin2 = box_scene(core, occluder, 32, 1000)
    reference = exhaustive(core, frame, vpls, points, dmin2)
    diff, cut = {}, {}
    for error in (0.05, 0.02):
        E, cut[error] = lightcut(core, frame, vpls, points, dmin2, error=error)
        diff[error] = relative_difference(E, reference)
        # Issue 6: the per-pixel relative difference is within the error bound on at
        # least 99% of pixels. Measured p99: 2.5% / 3.0% at 0.05, 1.4% / 1.7% at 0.02
        # (box / occluder), with cuts of 320 / 460 and 480 / 690 of 2454 VPLs.
        assert np.quantile(diff[error], 0.99) <= error, (error, np.quantile(diff[error], 0.99))
        assert abs(E.sum() / reference.sum() - 1) < 0.01
        assert cut[error].mean() < vpls.count / 3
    # The error parameter controls it: a smaller error, a closer result, more rays.
    assert np.median(diff[0.02]) < 0.7 * np.median(diff[0.05])
    assert cut[0.02].mean() > cut[0.05].mean()


def test_zero_error_refines_to_the_exact_gather(core):
    frame, vpls, points, dmin2 = box_scene(core, True, 12, 120)
    reference = exhaustive(core, frame, vpls, points, dmin2)
    E, cut = lightcut(core, frame, vpls, points, dmin2, error=0.0, max_cut=10 * vpls.count)
    # Only clusters whose bound is exactly zero (facing away: they add nothing) stay whole.
    np.testing.assert_allclose(E, reference, rtol=1e-4, atol=1e-6 * reference.max())
    assert cut.max() <= vpls.count


def test_cut_size_grows_sublinearly_with_the_vpl_count(core):
    cuts = {}
    for particles in (400, 40000):
        frame, vpls, points, dmin2 = box_scene(core, True, 16, particles)
        # max_cut far above the cuts, so that it does not hide their growth.
        E, cut = lightcut(core, frame, vpls, points, dmin2, max_cut=20000)
        assert np.isfinite(E).all() and (E >= 0).all()
        cuts[vpls.count] = cut.mean()
    small, large = sorted(cuts)
    assert large > 80 * small                  # ~1k and ~100k VPLs
    # One shadow ray per cut node: 100x the VPLs must cost at most 10x the rays
    # (measured: ~440 -> ~2140 rays per point; with the default max_cut 1000,
    # 440 -> 996).
    assert cuts[large] <= 10 * cuts[small], cuts


def test_max_cut_limits_the_shadow_rays(core):
    frame, vpls, points, dmin2 = box_scene(core, False, 12, 400)
    E, cut = lightcut(core, frame, vpls, points, dmin2, error=0.0, max_cut=40)
    assert cut.max() == 40 and cut.min() >= 1
    reference = exhaustive(core, frame, vpls, points, dmin2)
    assert abs(E.sum() / reference.sum() - 1) < 0.05   # coarse but unbiased


def test_no_vpls_or_no_points_give_zero(core):
    lt, lc = core.light_tree, core.lightcuts
    empty = lt.build_light_tree(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    P = np.zeros((5, 3))
    E, cut = lc.lightcut_irradiance(P, P + [0, 0, 1], P + [0, 0, 1], empty, 0.02, 1000, 0.0,
                                    None, 1e-5)
    assert (E == 0).all() and (cut == 0).all()
    one = lt.build_light_tree([[0, 0, 1.0]], [[0, 0, -1.0]], [[np.pi, np.pi, np.pi]])
    E, cut = lc.lightcut_irradiance(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), one,
                                    0.02, 1000, 0.0, None, 1e-5)
    assert E.shape == (0, 3) and cut.shape == (0,)


def vpl_terms(vpls, members, P, N, G, dmin2):
    """cos_x cos_y / max(d^2, dmin^2) of each member VPL at point P, 0 where it does
    not light P (the exact per-VPL term of gather.vpl_irradiance_chunk, no shadow)."""
    d = vpls.position[members] - P
    d2 = (d * d).sum(1)
    cos_x = d @ N / np.sqrt(d2)
    cos_y = -(d * vpls.normal[members]).sum(1) / np.sqrt(d2)
    lit = (cos_x > 0) & (cos_y > 0) & (d @ G > 0)
    return np.where(lit, cos_x * cos_y / np.maximum(d2, dmin2), 0.0)


def test_cluster_bounds_hold_for_every_vpl(core):
    lt, lc = core.light_tree, core.cluster_bounds
    frame, vpls, (P, N, G), dmin2 = box_scene(core, True, 16, 1000)
    tree = lt.build_light_tree(vpls.position, vpls.normal, vpls.flux)
    rng = np.random.default_rng(0)
    inner = np.flatnonzero(tree.left >= 0)
    point = rng.integers(len(P), size=2000)
    node = rng.choice(inner, 2000)
    columns = (x[point].T.astype(np.float32) for x in (P, N, G))
    Pc, Nc, Gc = columns
    t = np.take(tree.bound_columns, node, axis=1)
    upper, lower = lc.cluster_range(t, Pc, Nc, Gc, dmin2)
    bound, deviation = lc.cluster_deviation(t, Pc, Nc, Gc, dmin2)
    np.testing.assert_array_equal(bound, upper)
    ratio = []
    for i, (p, k) in enumerate(zip(point, node)):
        members = tree.order[tree.start[k]:tree.start[k] + tree.count[k]]
        f = vpl_terms(vpls, members, P[p], N[p], G[p], dmin2)
        scale = tree.flux[k].max() / np.pi
        # Every channel of the unshadowed cluster, and of any representative's
        # estimate, lies in [lower, upper]: a bound below the true value is a bug.
        exact = vpls.flux[members].T @ f / np.pi
        assert exact.max() <= upper[i] * (1 + 1e-5) + 1e-12, (p, k)
        assert scale * f.max() <= upper[i] * (1 + 1e-5) + 1e-12, (p, k)
        assert scale * f.min() >= lower[i] * (1 - 1e-5) - 1e-12, (p, k)
        assert 0 <= deviation[i] <= 0.5 * (upper[i] - lower[i]) * (1 + 1e-5) + 1e-12
        # The deviation estimates the standard deviation of scale * f(representative)
        # with the representative drawn by intensity.
        weight = tree.intensity[members] / tree.intensity[k]
        spread = scale * np.sqrt(max(weight @ f ** 2 - (weight @ f) ** 2, 0))
        if lower[i] > 0 and spread > 0:
            ratio.append(deviation[i] / spread)
    assert len(ratio) > 100
    assert 0.7 < np.median(ratio) < 2 and np.quantile(ratio, 0.1) > 0.4, np.quantile(ratio, [0.1, 0.5, 0.9])


def test_tree_covariances_are_those_of_the_members(core):
    lt = core.light_tree
    rng = np.random.default_rng(4)
    position = rng.random((500, 3)) * [3, 2, 1]
    normal = rng.normal(size=(500, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    flux = rng.random((500, 3)) + 0.1
    tree = lt.build_light_tree(position, normal, flux)
    pick = [0, 7, 13, 420, 700, 950, tree.root]
    for k in pick:
        members = tree.order[tree.start[k]:tree.start[k] + tree.count[k]]
        w = flux[members].mean(1)
        for x, cov in ((position, tree.position_covariance), (normal, tree.normal_covariance)):
            c = np.cov(x[members].T, aweights=w, bias=True) if len(members) > 1 else np.zeros((3, 3))
            expected = [c[0, 0], c[1, 1], c[2, 2], c[0, 1], c[0, 2], c[1, 2]]
            np.testing.assert_allclose(cov[k], expected, rtol=1e-9, atol=1e-12)


def test_lightcuts_in_the_renderer_match_the_exhaustive_gather(addon):
    # The whole frame through render_frame: the lightcut image agrees with the exhaustive
    # one and traces far fewer shadow rays per pixel.
    core = addon.irad_addon
    sd = core.scene_data
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(4), [0.6] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=24, lens=14))
    common = dict(particles=8000, aa_samples=1, interleave=1, seed=3)
    full = core.render.render_frame(data, core.render.RenderSettings(shadow_ray_budget=0.0,
                                                                     **common))
    cut = core.render.render_frame(data, core.render.RenderSettings(use_lightcuts=True, **common))
    a, b = full.passes["IRAD Indirect"], cut.passes["IRAD Indirect"]
    assert abs(b.mean() / a.mean() - 1) < 0.01
    assert np.median(np.abs(b - a) / (a + 1e-3)) < 0.03
    assert cut.stats["shadow_rays_per_point"] < full.stats["shadow_rays_per_point"] / 5

"""Interleaved sampling and the discontinuity buffer (Keller & Heidrich 2001)."""
import numpy as np
import pytest

import synthetic


@pytest.fixture
def il(addon):
    return addon.irad_addon.interleaving


def test_every_window_sees_every_subset_equally(il):
    k, samples, w, h = 4, 3, 20, 12
    subsets = il.sample_subsets(w, (0, h), samples, k).reshape(samples, h, w)
    assert set(np.unique(subsets)) == set(range(il.subset_count(k, samples)))
    offsets = il.window_offsets(k)
    for s in range(samples):
        window = [subsets[s, 6 + dy, 9 + dx] for dy, dx in offsets]
        counts = np.bincount(window, minlength=subsets.max() + 1)
        seen = counts[counts > 0]
        assert len(seen) == k * k and (seen == seen[0]).all()


def test_filter_never_crosses_a_depth_or_normal_edge(il):
    h, w, k = 16, 16, 4
    rng = np.random.default_rng(0)
    irradiance = np.empty((h, w, 3))
    irradiance[:, :8] = 1.0 + 0.5 * rng.random((h, 8, 1))     # near wall: noisy around 1.25
    irradiance[:, 8:] = 10.0 + 5 * rng.random((h, 8, 1))     # far wall: noisy around 12.5
    depth = np.where(np.arange(w) < 8, 1.0, 3.0)[None, :].repeat(h, 0)
    normal = np.zeros((h, w, 3))
    normal[..., 2] = 1.0
    hit = np.ones((h, w), bool)
    out = il.discontinuity_filter(irradiance, depth, normal, hit, k)
    assert out[:, :8].max() <= irradiance[:, :8].max() and out[:, 8:].min() >= irradiance[:, 8:].min()
    assert out[:, :8].std() < irradiance[:, :8].std() / 2      # it does filter within a side
    # A normal edge at equal depth: a floor meeting a wall.
    normal[:, 8:] = [1.0, 0.0, 0.0]
    out = il.discontinuity_filter(irradiance, np.ones((h, w)), normal, hit, k)
    assert out[:, :8].max() <= irradiance[:, :8].max()
    # Misses (background) are never averaged in.
    hit[:, 8:] = False
    out = il.discontinuity_filter(irradiance, np.ones((h, w)), np.tile([0, 0, 1.0], (h, w, 1)), hit, k)
    assert out[:, :8].max() <= irradiance[:, :8].max()


def test_interleaving_keeps_the_mean(addon):
    # Same VPLs, interleaved 4x4 (16x fewer shadow rays) or not: the same picture.
    # Every shadow ray traced, so that only the interleaving differs.
    core = addon.irad_addon
    sd = core.scene_data
    light = sd.PointLight(np.array([0.2, 0.1, 0.6]), np.ones(3), 100.0, 0.0)
    data = synthetic.scene(sd, synthetic.closed_box(4), [0.6] * 3, lights=[light],
                           camera=synthetic.camera(sd, size=32, lens=14))
    full = core.render.render_frame(data, core.render.RenderSettings(
        particles=4096, aa_samples=1, interleave=1, seed=2, shadow_ray_budget=0.0)
    ).passes["IRAD Indirect"]
    inter = core.render.render_frame(data, core.render.RenderSettings(
        particles=4096, aa_samples=1, interleave=4, seed=2, shadow_ray_budget=0.0)
    ).passes["IRAD Indirect"]
    assert inter.mean() == pytest.approx(full.mean(), rel=0.02)
    assert np.abs(inter - full).mean() < 0.1 * full.mean()


def test_vpls_facing_away_from_every_visible_point_are_not_gathered(addon):
    gather = addon.irad_addon.gather
    vpl = addon.irad_addon.vpl
    points = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    position = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 1.0], [3.0, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    normal = np.array([[0, 0, -1.0], [0, 0, 1.0], [1.0, 0, 0], [1.0, 0, 0]])
    vpls = vpl.VPLs(position, normal, np.ones((4, 3)), np.ones(4, np.int32))
    # Faces down onto the points: kept; faces up, or away beyond x = 3: culled; the
    # last faces +x from x = -0.5 towards the points: kept.
    assert gather.facing_points(vpls, points).tolist() == [True, False, False, True]


def test_each_interleaved_group_alone_estimates_the_whole_set(addon):
    # 370 VPLs in 256 groups: 114 groups hold two, 142 hold one. A pixel next to an
    # edge sees only a few groups, so each must estimate all the light by itself.
    core = addon.irad_addon
    rng = np.random.default_rng(3)
    count, groups = 370, 256
    flux = rng.uniform(0.5, 1.5, size=(count, 3))
    vpls = core.vpl.VPLs(rng.random((count, 3)), np.tile([0, 0, 1.0], (count, 1)), flux,
                         np.ones(count, np.int32))
    pieces = core.gather.vpl_subsets(vpls, groups)
    sizes = np.array([subset.count for subset, _ in pieces])
    estimates = np.array([scale * subset.flux.sum() for subset, scale in pieces])
    total = flux.sum()
    assert sorted(set(sizes)) == [1, 2]
    for size in (1, 2):   # equal in expectation whatever the group's size
        assert estimates[sizes == size].mean() == pytest.approx(total, rel=0.1)
    assert estimates.mean() == pytest.approx(total, rel=0.05)
    # Fewer VPLs than groups: every group still holds one, scaled to the whole set.
    few = core.gather.vpl_subsets(vpls.subset(slice(0, 10)), 16)
    assert all(subset.count == 1 and scale == 10 for subset, scale in few)

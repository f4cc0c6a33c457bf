"""Shadow-ray roulette in the VPL gather (gather._group_terms): weak VPLs keep their
shadow ray with a probability in proportion to their light, weighted by its inverse."""
import numpy as np
import pytest

import synthetic

BUDGET = 16.0
SEEDS = range(32)


@pytest.fixture(scope="module")
def gathered(addon):
    """A closed box lit by a point light, a panel inside casting shadows; one camera
    sample per pixel gathers every one of ~5000 VPLs (no interleaving), exhaustively
    and with the budget under 32 seeds."""
    core = addon.irad_addon
    sd = core.scene_data
    panel = synthetic.grid_quad(2, 0.35).astype(np.float64) - [0.1, 0.0, 0.8]
    triangles = np.concatenate([synthetic.closed_box(3), panel.astype(np.float32)])
    light = sd.PointLight(np.array([0.3, 0.2, 0.5]), np.ones(3), 100.0, 0.0)
    cam = synthetic.camera(sd, size=16)
    cam.matrix_world[:3, 3] = [0.05, 0.03, 0.5]
    data = synthetic.scene(sd, triangles, [0.6] * 3, lights=[light], camera=cam)
    frame = core.frame.prepare_frame(data)
    gb = core.gbuffer.build_gbuffer(frame, data.camera, 1, np.random.default_rng(0))
    vpls = core.vpl.trace_vpls(frame, 4096, 16, seed=0)
    everyone = np.zeros(len(gb.hit), np.int64)

    def gather(budget, seed=0, visible=None):
        stats = {}
        E = core.gather.indirect_irradiance(frame, gb, vpls, 0.05, everyone, 1, stats=stats,
                                            shadow_ray_budget=budget, seed=seed,
                                            visible=visible)
        return E[gb.hit].mean(1), stats["shadow_rays_per_point"]

    exact, exact_rays = gather(0.0)
    unoccluded, _ = gather(0.0, visible=lambda o, d, t: np.ones(len(o), bool))
    runs = [gather(BUDGET, seed) for seed in SEEDS]
    return (exact, exact_rays, np.array([E for E, _ in runs]),
            np.array([rays for _, rays in runs]), vpls.count, unoccluded)


def test_the_budget_is_unbiased(gathered):
    exact, _, budgeted, _, _, _ = gathered
    mean = budgeted.mean(0)
    # The image's mean, and each sample's mean over the seeds within its own spread.
    assert mean.mean() == pytest.approx(exact.mean(), rel=0.005)
    spread = budgeted.std(0) / np.sqrt(len(budgeted)) + 1e-6 * exact.max()
    assert (np.abs(mean - exact) < 5 * spread).mean() > 0.99


def test_the_budget_bounds_rays_and_noise(gathered):
    exact, exact_rays, budgeted, rays, vpl_count, unoccluded = gathered
    assert vpl_count > 3000 and exact_rays > 1000     # every sample sees many VPLs
    assert rays.max() < 1.25 * BUDGET, rays.max()     # ~the budget, not thousands
    # Each sample's noise is below 1/sqrt(budget) of its unoccluded VPL light S. The
    # bound holds with S itself; a neighbour's S stands in for it, and 32 seeds
    # estimate a standard deviation to ~13%: slack for the worst samples only.
    lit = unoccluded > 1e-3 * unoccluded.max()
    relative = budgeted.std(0)[lit] / unoccluded[lit]
    assert np.median(relative) < 1 / np.sqrt(BUDGET), np.median(relative)
    assert np.percentile(relative, 99) < 1.4 / np.sqrt(BUDGET), np.percentile(relative, 99)


def test_systematic_draw_keeps_the_ray_count(addon):
    """The pairs are drawn by systematic sampling: a sample keeps floor or ceil of the
    sum of its pairs' probabilities, never more, and each pair's share over many
    draws is its probability."""
    g = addon.irad_addon.gather
    rng = np.random.default_rng(3)
    m, budget = 400, 8.0
    Y = rng.uniform(-1, 1, (m, 3)) + [0, 0, 2]
    NY = np.tile([0.0, 0.0, -1.0], (m, 1))
    P, N = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    flux_weight = rng.uniform(0.1, 1.0, m)
    terms, keep = np.empty(m), np.empty(m)
    total = g._kept_terms(P[0], N[0], N[0], np.vstack([Y.T, NY.T, flux_weight]), m, 0.0,
                          0.0, terms, keep)
    probability = np.minimum(1.0, terms * flux_weight * budget / total)
    lists = (np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64),
             np.full(1, m, np.int64), np.arange(m))
    counts, kept = [], np.zeros(m)
    for seed in range(2000):
        weight, segments = np.empty(m, np.float32), g._segments(m)
        counts.append(g._group_terms(*lists, P, N, N, Y, NY, 0.0, 0.0, np.zeros(3), weight,
                                     *segments, flux_weight, budget, seed))
        kept += weight > 0
        # A kept pair's weight is its term over its probability.
        assert np.allclose(weight[weight > 0], (terms / probability)[weight > 0], rtol=1e-4)
    expected = probability.sum()
    assert expected <= budget + 1e-9
    assert set(counts) <= {np.floor(expected), np.ceil(expected)}, (set(counts), expected)
    assert np.mean(counts) == pytest.approx(expected, rel=0.01)
    assert np.abs(kept / 2000 - probability).max() < 0.05

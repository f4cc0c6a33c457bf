"""The light tree (Walter et al. 2005) and the budget clustering used by the bake."""
import importlib

import numpy as np
import pytest


@pytest.fixture
def lt(addon):
    return importlib.import_module(addon.__name__ + '.irad_addon.light_tree')


def random_vpls(count, seed=0):
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(count, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return rng.random((count, 3)) * [4, 2, 1], normal, rng.random((count, 3)) * [1, 0.5, 2]


def two_rooms(count, seed=0):
    """VPLs on the inner faces of two unit boxes either side of the wall x = 0:
    random positions, normals pointing into their room."""
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 6, count)
    axis, sign = face // 2, np.where(face % 2, 1.0, -1.0)
    local = rng.random((count, 3)) * 2 - 1
    local[np.arange(count), axis] = sign
    normal = np.zeros((count, 3))
    normal[np.arange(count), axis] = -sign
    side = np.where(rng.random(count) < 0.5, -1.0, 1.0)
    position = local + np.stack([side * 1.05, np.zeros(count), np.zeros(count)], 1)
    return position, normal, rng.random((count, 3)) + 0.1, side


def test_tree_nodes_bound_their_children(lt):
    position, normal, flux = random_vpls(3000)
    tree = lt.build_light_tree(position, normal, flux)
    m = len(position)
    assert tree.size == 2 * m - 1 and tree.count[tree.root] == m
    inner = np.flatnonzero(tree.left >= 0)
    assert len(inner) == m - 1
    for child in (tree.left[inner], tree.right[inner]):
        assert (child < inner).all()
        assert (tree.lo[inner] <= tree.lo[child]).all()
        assert (tree.hi[inner] >= tree.hi[child]).all()
        # Cone containment: angle(parent axis, child axis) + child half <= parent half.
        a, b = tree.axis[inner], tree.axis[child]
        angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), (a * b).sum(1))
        whole = tree.half_angle[inner] >= np.pi  # a full sphere holds everything
        assert (whole | (angle + tree.half_angle[child] <= tree.half_angle[inner] + 1e-9)).all()
    np.testing.assert_allclose(tree.flux[inner], tree.flux[tree.left[inner]]
                               + tree.flux[tree.right[inner]], rtol=1e-12)
    np.testing.assert_allclose(tree.flux[tree.root], flux.sum(0), rtol=1e-12)
    # Leaves are the VPLs themselves; every VPL sits under exactly one leaf range.
    np.testing.assert_array_equal(tree.lo[:m], position)
    np.testing.assert_allclose(tree.axis[:m], normal, rtol=1e-12, atol=1e-15)
    assert (tree.half_angle[:m] == 0).all()
    np.testing.assert_array_equal(np.sort(tree.order), np.arange(m))
    # The representative is one of the children's and lies under the node.
    rep = tree.representative[inner]
    assert ((rep == tree.representative[tree.left[inner]])
            | (rep == tree.representative[tree.right[inner]])).all()
    where = np.argsort(tree.order)[rep]
    assert ((where >= tree.start[inner]) & (where < tree.start[inner] + tree.count[inner])).all()


def test_representative_is_drawn_in_proportion_to_flux(lt):
    position = np.array([[0.0, 0, 0], [1, 0, 0]])
    normal = np.array([[0.0, 0, 1], [0, 0, 1]])
    flux = np.array([[1.0, 1, 1], [3, 3, 3]])
    picks = [lt.build_light_tree(position, normal, flux, seed=s).representative[-1]
             for s in range(800)]
    # Binomial(800, 0.75): standard deviation 12.2, so +-50 is 4 sigma.
    assert abs(np.sum(picks) - 600) < 50


def test_tree_of_zero_one_and_duplicate_vpls(lt):
    empty = lt.build_light_tree(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.size == 0
    one = lt.build_light_tree([[1, 2, 3]], [[0, 0, 1]], [[1, 1, 1]])
    assert one.size == 1 and one.root == 0
    same = lt.build_light_tree(np.ones((50, 3)), np.tile([0, 0, 1.0], (50, 1)), np.zeros((50, 3)))
    assert same.count[same.root] == 50 and np.isfinite(same.half_angle).all()


def test_build_is_fast_enough_for_100k_vpls(lt):
    # Not a timing test: a per-VPL Python loop would take minutes, numpy takes ~1 s.
    import time
    position, normal, flux = random_vpls(100_000, seed=1)
    start = time.perf_counter()
    tree = lt.build_light_tree(position, normal, flux)
    assert time.perf_counter() - start < 20
    assert tree.count[tree.root] == 100_000


@pytest.mark.parametrize("budget", [1, 7, 64, 5000])
def test_cluster_by_budget_partitions_vpls_and_conserves_flux(lt, budget):
    position, normal, flux = random_vpls(2000, seed=2)
    clusters = lt.cluster_by_budget(position, normal, flux, budget)
    k = min(budget, 2000)
    assert len(clusters.flux) == k == len(clusters.position) == len(clusters.normal)
    assert clusters.labels.shape == (2000,)
    np.testing.assert_array_equal(np.bincount(clusters.labels, minlength=k) > 0, True)
    for ch in range(3):
        np.testing.assert_allclose(clusters.flux[:, ch],
                                   np.bincount(clusters.labels, flux[:, ch], k), rtol=1e-12)
    np.testing.assert_allclose(clusters.flux.sum(0), flux.sum(0), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(clusters.normal, axis=1), 1.0, rtol=1e-9)
    assert np.isfinite(clusters.relative_error).all() and (clusters.relative_error >= 0).all()
    # Centres are flux-weighted means of their members.
    w = flux.mean(1)
    centre = np.stack([np.bincount(clusters.labels, w * position[:, a], k) for a in range(3)], 1)
    np.testing.assert_allclose(clusters.position,
                               centre / np.bincount(clusters.labels, w, k)[:, None], rtol=1e-9)
    if budget >= 2000:
        assert (clusters.relative_error == 0).all()


def test_clusters_stay_on_one_side_of_a_wall(lt):
    position, normal, flux, side = two_rooms(4000, seed=3)
    clusters = lt.cluster_by_budget(position, normal, flux, 64)
    spans = np.bincount(clusters.labels[side < 0], minlength=64).astype(bool) & \
        np.bincount(clusters.labels[side > 0], minlength=64).astype(bool)
    random_labels = np.random.default_rng(0).integers(0, 64, len(side))
    random_spans = np.bincount(random_labels[side < 0], minlength=64).astype(bool) & \
        np.bincount(random_labels[side > 0], minlength=64).astype(bool)
    assert spans.sum() <= 1 < 60 <= random_spans.sum()
    # Clusters are compact in orientation too: most hold VPLs of a single face.
    face = np.argmax(np.abs(normal), 1) * 2 + (normal.sum(1) > 0) + 6 * (side > 0)
    faces_per_cluster = [len(np.unique(face[clusters.labels == k])) for k in range(64)]
    assert np.mean(np.array(faces_per_cluster) == 1) > 0.6
    # More clusters and errors shrink.
    finer = lt.cluster_by_budget(position, normal, flux, 512)
    assert finer.relative_error.mean() < clusters.relative_error.mean()


def test_bad_budget_is_a_clear_error(lt):
    with pytest.raises(ValueError, match="at least 1"):
        lt.cluster_by_budget(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)), 0)

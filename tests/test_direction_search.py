"""Nearest-direction searches behind incremental IR's Voronoi cells and largest empty
circles (irad_addon/direction_search.py), against brute force."""
import importlib

import numpy as np
import pytest


@pytest.fixture
def ds(addon):
    return importlib.import_module(addon.__name__ + '.irad_addon.direction_search')


def directions(count, seed, clustered=False):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(count, 3))
    if clustered:   # most in one cap: large empty regions elsewhere
        d[: count * 3 // 4] += [0.0, 0.0, 2.5]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def fibonacci(count):
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


@pytest.mark.parametrize("clustered", [False, True])
@pytest.mark.parametrize("cell_factor", [0.5, 0.8, 1.0])
def test_nearest_sites_of_every_domain_direction_is_exact(ds, clustered, cell_factor):
    domain, sites = fibonacci(4096), directions(500, 1, clustered)
    grid = ds.DirectionGrid(domain, cell_factor * ds.site_spacing(4 * np.pi, len(sites)))
    index, cosine, compared = ds.nearest_sites(grid, sites)
    brute = domain @ sites.T
    assert np.allclose(cosine, brute.max(1))
    assert np.allclose(brute[np.arange(len(domain)), index], brute.max(1))
    assert compared < 0.5 * brute.size   # far fewer pairs than brute force


def test_nearest_point_skips_itself(ds):
    points = directions(800, 2)
    grid = ds.DirectionGrid(points, ds.site_spacing(4 * np.pi, len(points)))
    index, cosine, _ = ds.nearest_point(grid, points, skip_self=True)
    brute = points @ points.T
    np.fill_diagonal(brute, -2.0)
    assert np.allclose(cosine, brute.max(1)) and np.all(index != np.arange(len(points)))


@pytest.mark.parametrize("clustered", [False, True])
def test_largest_empty_circles_match_one_at_a_time_greedy(ds, clustered):
    """The rounds insert exactly the sites (and in the order) the one-at-a-time greedy of
    Laine 2007 sec. 3.2 would, and leave the exact Voronoi cells."""
    domain, sites = fibonacci(4096), directions(300, 3, clustered)
    grid = ds.DirectionGrid(domain, 0.8 * ds.site_spacing(4 * np.pi, 400))
    cell, best, _ = ds.nearest_sites(grid, sites)
    chosen, new_cell, _ = ds.largest_empty_circles(grid, best, cell, 100, len(sites))
    greedy, b = [], best.copy()
    for _ in range(100):
        i = int(np.argmin(b))
        greedy.append(i)
        b = np.maximum(b, domain @ domain[i])
    assert chosen.tolist() == greedy
    everything = np.concatenate([sites, domain[chosen]])
    assert np.array_equal(new_cell, (domain @ everything.T).argmax(1))

"""Nearest-neighbour searches among unit directions, for incremental IR's sites.

A grid of cubes over [-1, 1]^3 (DirectionGrid) bins the directions, so a search
compares each query only with the directions in the cubes around its own: the cost
grows with the number of directions and queries, not with their product. The searches
are compiled loops (numba): a frame's few thousand queries each visit a few dozen
cubes, which as numpy passes cost far more in per-call overhead than in arithmetic.
Every search counts the direction pairs it compared.
"""
import numpy as np
from numba import njit


class DirectionGrid:
    """Unit directions binned into cubes of side `cell` over [-1, 1]^3: every direction
    within chord distance ring * cell of a query lies in the (2 ring + 1)^3 cubes around
    the query's own, so a search compares only those instead of every direction."""

    def __init__(self, points, cell):
        self.points = np.ascontiguousarray(points, np.float64)
        self.cell = float(cell)
        self.n = int(np.ceil(2.0 / self.cell)) + 3      # cubes per axis, 1 of padding a side
        # Points of cube k: order[first[k]:first[k + 1]], their directions binned[...]
        # (contiguous: a search reads them in order).
        self.order, self.first = _bin(self.points, self.cell, self.n)
        self.binned = self.points[self.order]


def site_spacing(domain_area, count):
    """Mean distance between `count` evenly spread sites on a domain of that area."""
    return float(np.sqrt(domain_area / max(count, 1)))


def chord(cosine):
    """Straight-line distance between unit vectors with this cosine."""
    return np.sqrt(np.maximum(2.0 - 2.0 * cosine, 0.0))


def nearest_point(grid, queries, skip_self=False, exact=True):
    """(index, cosine) of each query's nearest grid point, and the number of direction
    pairs compared. A query searches rings of cubes outwards until its best lies within
    the rings searched, or compares all points once the rings hold more cubes than there
    are points; with exact=False it stops after one ring and keeps cosine -2 when that
    ring holds nothing (nothing within a cube side). skip_self: the queries are the
    grid's points, each excluding itself."""
    queries = np.ascontiguousarray(queries, np.float64)
    index = np.zeros(len(queries), np.int64)
    best = np.full(len(queries), -2.0)
    if len(grid.points) == 0:
        return index, best, 0
    compared = _nearest(grid.binned, grid.order, grid.first, grid.n, grid.cell, queries,
                        skip_self, 1 if not exact else grid.n, index, best)
    return index, best, int(compared)


def nearest_sites(domain_grid, sites):
    """(index, cosine) of the nearest of `sites` for every point of `domain_grid`, and the
    pairs compared. Searched from the sites' side (far fewer than the domain's points):
    each site offers itself to the domain points in the cubes around its own, exact
    where a site lies within one cube side; the domain points left search the sites."""
    domain = domain_grid.points
    index = np.zeros(len(domain), np.int64)
    best = np.full(len(domain), -2.0)
    if len(sites) == 0:
        return index, best, 0
    sites = np.ascontiguousarray(sites, np.float64)
    # Searched in the domain grid's binned order, then put back in the domain's.
    order = domain_grid.order
    compared = int(_offer_sites(domain_grid.binned, domain_grid.first, domain_grid.n,
                                domain_grid.cell, sites, index, best))
    index[order], best[order] = index.copy(), best.copy()
    left = np.flatnonzero(chord(best) > domain_grid.cell)
    if len(left):
        index[left], best[left], more = nearest_point(
            DirectionGrid(sites, domain_grid.cell), domain[left])
        compared += more
    return index, best, compared


def largest_empty_circles(domain_grid, best, cell, count, first):
    """Greedy farthest-point insertion over the domain's directions: each new site goes
    to the centre of the largest empty circle left (Laine 2007 sec. 3.2), one at a time.
    best, cell: cosine to and index of each domain direction's nearest site. A new site
    becomes the nearest of the directions inside its circle: its radius is the largest
    distance from any direction to its nearest site, so only the cubes within it are
    searched. Returns the chosen indices, the Voronoi cells with the new sites (numbered
    from `first`) and the number of direction pairs compared."""
    # Searched in the domain grid's binned order, then put back in the domain's.
    order = domain_grid.order
    best = np.ascontiguousarray(best[order], np.float64)
    binned_cell = np.ascontiguousarray(cell[order], np.int64)
    chosen = np.zeros(min(count, len(order)), np.int64)
    compared = _insert_sites(domain_grid.binned, domain_grid.first, domain_grid.n,
                             domain_grid.cell, best, binned_cell, chosen, first)
    cell = np.empty_like(binned_cell)
    cell[order] = binned_cell
    return order[chosen], cell, int(compared)


@njit(cache=True, inline='always')
def _cube(value, cell, n):
    return min(max(int(np.floor((value + 1.0) / cell)) + 1, 1), n - 2)


@njit(cache=True)
def _bin(points, cell, n):
    """Counting sort of the points by cube: (order, first) as DirectionGrid keeps them."""
    keys = np.empty(len(points), np.int64)
    first = np.zeros(n * n * n + 1, np.int64)
    for i in range(len(points)):
        key = ((_cube(points[i, 0], cell, n) * n + _cube(points[i, 1], cell, n)) * n
               + _cube(points[i, 2], cell, n))
        keys[i] = key
        first[key + 1] += 1
    for k in range(n * n * n):
        first[k + 1] += first[k]
    fill = first[:-1].copy()
    order = np.empty(len(points), np.int64)
    for i in range(len(points)):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return order, first


@njit(cache=True)
def _nearest(points, order, first, n, cell, queries, skip_self, max_ring, index, best):
    compared = 0
    for q in range(len(queries)):
        x, y, z = queries[q, 0], queries[q, 1], queries[q, 2]
        cx, cy, cz = _cube(x, cell, n), _cube(y, cell, n), _cube(z, cell, n)
        top, top_index = -2.0, 0
        ring = 0
        while True:
            ring += 1
            if (2 * ring + 1) ** 3 > len(points) and max_ring > 1:
                # More cubes than points: comparing every point is cheaper.
                top, top_index, c = _closest(points, order, 0, len(points), x, y, z,
                                             skip_self, q, -2.0, 0)
                compared += c
                break
            k0, k1 = max(cz - ring, 1), min(cz + ring, n - 2)
            for i in range(max(cx - ring, 1), min(cx + ring, n - 2) + 1):
                for j in range(max(cy - ring, 1), min(cy + ring, n - 2) + 1):
                    row = (i * n + j) * n
                    if ring > 1 and abs(i - cx) < ring and abs(j - cy) < ring:
                        # Inside the inner rings' columns: only the two end cubes are new.
                        ends = (cz - ring, cz + ring)
                        for k in ends:
                            if 1 <= k <= n - 2:
                                top, top_index, c = _closest(
                                    points, order, first[row + k], first[row + k + 1],
                                    x, y, z, skip_self, q, top, top_index)
                                compared += c
                    else:   # a run of cubes along z is one run of points
                        top, top_index, c = _closest(
                            points, order, first[row + k0], first[row + k1 + 1],
                            x, y, z, skip_self, q, top, top_index)
                        compared += c
            # Exact once the best is within the rings searched.
            if np.sqrt(max(2.0 - 2.0 * top, 0.0)) <= ring * cell or ring >= max_ring:
                break
        index[q], best[q] = top_index, top
    return compared


@njit(cache=True, inline='always')
def _closest(binned, order, start, stop, x, y, z, skip_self, q, top, top_index):
    """The best of (top, top_index) and the points order[start:stop] (directions
    binned[start:stop]), and how many were compared."""
    compared = 0
    for s in range(start, stop):
        p = order[s]
        if skip_self and p == q:
            continue
        c = x * binned[s, 0] + y * binned[s, 1] + z * binned[s, 2]
        compared += 1
        if c > top:
            top, top_index = c, p
    return top, top_index, compared


@njit(cache=True)
def _offer_sites(binned, first, n, cell_size, sites, index, best):
    """Each site becomes the nearest of the domain points in its own and the adjacent
    cubes that have no nearer site (index and best in binned order)."""
    compared = 0
    for s in range(len(sites)):
        x, y, z = sites[s, 0], sites[s, 1], sites[s, 2]
        cx, cy, cz = _cube(x, cell_size, n), _cube(y, cell_size, n), _cube(z, cell_size, n)
        k0, k1 = max(cz - 1, 1), min(cz + 1, n - 2)
        for i in range(max(cx - 1, 1), min(cx + 1, n - 2) + 1):
            for j in range(max(cy - 1, 1), min(cy + 1, n - 2) + 1):
                row = (i * n + j) * n
                for t in range(first[row + k0], first[row + k1 + 1]):
                    c = x * binned[t, 0] + y * binned[t, 1] + z * binned[t, 2]
                    compared += 1
                    if c > best[t]:
                        best[t], index[t] = c, s
    return compared


@njit(cache=True)
def _insert_sites(binned, first, n, cell_size, best, cell, chosen, first_site):
    """The greedy insertion, in the grid's binned order (best, cell and chosen)."""
    compared = 0
    candidates, beyond = _lowest(best, 2 * len(chosen))
    for s in range(len(chosen)):
        # The lowest cosine to its nearest site: the largest circle. Cosines only grow,
        # so while the candidates' lowest is below every other direction's, it is the
        # lowest of all (ties go to the first in binned order).
        a = candidates[np.argmin(best[candidates])]
        if best[a] > beyond:
            candidates, beyond = _lowest(best, 2 * (len(chosen) - s))
            a = candidates[np.argmin(best[candidates])]
        chosen[s] = a
        ring = max(int(np.ceil(np.sqrt(max(2.0 - 2.0 * best[a], 0.0)) / cell_size)), 1)
        x, y, z = binned[a, 0], binned[a, 1], binned[a, 2]
        cx, cy, cz = _cube(x, cell_size, n), _cube(y, cell_size, n), _cube(z, cell_size, n)
        k0, k1 = max(cz - ring, 1), min(cz + ring, n - 2)
        for i in range(max(cx - ring, 1), min(cx + ring, n - 2) + 1):
            for j in range(max(cy - ring, 1), min(cy + ring, n - 2) + 1):
                row = (i * n + j) * n
                for t in range(first[row + k0], first[row + k1 + 1]):
                    c = x * binned[t, 0] + y * binned[t, 1] + z * binned[t, 2]
                    compared += 1
                    if c > best[t]:
                        best[t], cell[t] = c, first_site + s
    return compared


@njit(cache=True)
def _lowest(values, count):
    """Indices (ascending) of the values at or below the `count`-th lowest, and that
    value (inf when all are taken): every other value is higher."""
    if count >= len(values):
        return np.arange(len(values)), np.inf
    threshold = np.partition(values.copy(), count)[count]
    return np.flatnonzero(values <= threshold), threshold

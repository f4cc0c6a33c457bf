"""Nearest-neighbour searches among unit directions, for incremental IR's sites.

A grid of cubes over [-1, 1]^3 (DirectionGrid) bins the directions, so a search
compares each query only with the directions in the cubes around its own: the cost
grows with the number of directions and queries, not with their product. Every search
counts the direction pairs it compared.
"""
import numpy as np


class DirectionGrid:
    """Unit directions binned into cubes of side `cell` over [-1, 1]^3: every direction
    within chord distance ring * cell of a query lies in the (2 ring + 1)^3 cubes around
    the query's own, so a search compares only those instead of every direction."""

    def __init__(self, points, cell):
        self.points = points
        self.columns = np.ascontiguousarray(points.T)   # x, y, z rows: fast gathers
        self.cell = float(cell)
        self.n = int(np.ceil(2.0 / self.cell)) + 3      # cubes per axis, 1 of padding a side
        keys = self.key(points)
        self.order = np.argsort(keys, kind='stable')
        # Points of cube k: order[first[k]:first[k] + count[k]].
        self.count = np.bincount(keys, minlength=self.n ** 3)
        self.first = np.concatenate([[0], np.cumsum(self.count)])

    def key(self, directions):
        cube = np.clip(np.floor((directions + 1.0) / self.cell).astype(np.int64) + 1,
                       1, self.n - 2)
        return (cube[:, 0] * self.n + cube[:, 1]) * self.n + cube[:, 2]

    def candidates(self, directions, ring=1):
        """(query, point) index pairs, queries ascending: every point in the cubes within
        `ring` cubes of each query direction's cube (a ring beyond the padding wraps to
        other cubes: extra candidates, never missing ones)."""
        r = np.arange(-ring, ring + 1)
        offsets = ((r[:, None, None] * self.n + r[None, :, None]) * self.n
                   + r[None, None, :]).ravel()
        key = (self.key(directions)[:, None] + offsets).ravel()
        if ring > 1:
            key = np.clip(key, 0, self.n ** 3 - 1)
        occupied = np.flatnonzero(self.count[key])
        query, key = occupied // len(offsets), key[occupied]
        count = self.count[key]
        position = (np.repeat(self.first[key] - np.cumsum(count) + count, count)
                    + np.arange(count.sum()))
        return np.repeat(query, count), self.order[position]


def site_spacing(domain_area, count):
    """Mean distance between `count` evenly spread sites on a domain of that area."""
    return float(np.sqrt(domain_area / max(count, 1)))


def chord(cosine):
    """Straight-line distance between unit vectors with this cosine."""
    return np.sqrt(np.maximum(2.0 - 2.0 * cosine, 0.0))


def pair_cosines(a, i, b, j):
    """Cosines between directions a[:, i] and b[:, j] (x, y, z rows), pair by pair."""
    return a[0][i] * b[0][j] + a[1][i] * b[1][j] + a[2][i] * b[2][j]


def nearest_point(grid, queries, skip_self=False, exact=True):
    """(index, cosine) of each query's nearest grid point, and the number of direction
    pairs compared. A query compares the points of the cubes around its own: one ring
    of cubes is exact when the best lies within one cube side, two rings within two;
    the few queries left (large empty regions) compare all points, or with exact=False
    keep cosine -2 (nothing within a cube side). skip_self: the queries are the grid's
    points, each excluding itself."""
    best = np.full(len(queries), -2.0)
    index = np.zeros(len(queries), np.int64)
    columns = np.ascontiguousarray(queries.T)
    todo, compared = np.arange(len(queries)), 0
    for ring in (1, 2) if exact else (1,):
        query, point = grid.candidates(queries[todo], ring)
        query = todo[query]
        cosine = pair_cosines(columns, query, grid.columns, point)
        if skip_self:
            cosine[query == point] = -2.0
        np.maximum.at(best, query, cosine)
        won = cosine == best[query]
        index[query[won]] = point[won]
        compared += len(query)
        todo = todo[chord(best[todo]) > ring * grid.cell]
    if exact and len(todo) and len(grid.points):
        cosine = queries[todo] @ grid.points.T
        if skip_self:
            cosine[np.arange(len(todo)), todo] = -2.0
        index[todo], best[todo] = cosine.argmax(1), cosine.max(1)
        compared += len(todo) * len(grid.points)
    return index, best, compared


def nearest_sites(domain_grid, sites):
    """(index, cosine) of the nearest of `sites` for every point of `domain_grid`, and the
    pairs compared. Searched from the sites' side: each site visits the domain points in
    the cubes around its own (far fewer cubes than there are domain points), exact where
    a site lies within one cube side; the domain points left search the sites' grid."""
    domain = domain_grid.points
    best = np.full(len(domain), -2.0)
    index = np.zeros(len(domain), np.int64)
    if len(sites) == 0:
        return index, best, 0
    site, point = domain_grid.candidates(sites, 1)
    cosine = pair_cosines(domain_grid.columns, point, np.ascontiguousarray(sites.T), site)
    np.maximum.at(best, point, cosine)
    won = cosine == best[point]
    index[point[won]] = site[won]
    left = np.flatnonzero(chord(best) > domain_grid.cell)
    compared = len(site)
    if len(left):
        index[left], best[left], more = nearest_point(
            DirectionGrid(sites, domain_grid.cell), domain[left])
        compared += more
    return index, best, compared


def largest_empty_circles(domain_grid, best, cell, count, first):
    """Greedy farthest-point insertion over the domain's directions: each new site goes
    to the centre of the largest empty circle left (Laine 2007 sec. 3.2). best, cell:
    cosine to and index of each domain direction's nearest site. In rounds, to keep it
    vectorised: a round takes the directions with the largest empty circles, and inserts
    among them exactly as the one-at-a-time greedy would (shrinking their circles as it
    goes) while the largest left beats every direction outside them; then a new site
    becomes the nearest of the directions inside its circle, found through the domain's
    grid. Returns the chosen indices, the Voronoi cells with the new sites (numbered from
    `first`) and the number of direction pairs compared."""
    domain, spacing = domain_grid.points, domain_grid.cell
    best, cell = best.copy(), cell.copy()
    chosen, compared = [], 0
    count = min(count, len(domain))
    while len(chosen) < count:
        wanted = count - len(chosen)
        # Circles compared by the cosine to their nearest site: the lower, the larger.
        top, beyond = _smallest(best, 2 * wanted)
        cosine_between = domain[top] @ domain[top].T
        shrunk = best[top]
        taken = []
        while len(taken) < wanted:
            a = int(np.argmin(shrunk))
            if taken and (shrunk[a] > beyond or shrunk[a] >= 1.0):
                break
            taken.append(a)
            shrunk = np.maximum(shrunk, cosine_between[a])
        new = top[taken]
        radius = chord(best)
        compared += len(top) ** 2
        rank = np.zeros(len(domain), np.int64)
        rank[new] = first + len(chosen) + np.arange(len(new))
        for ring in np.unique(np.ceil(radius[new] / spacing).astype(np.int64)):
            group = new[np.ceil(radius[new] / spacing) == ring]
            site, near = domain_grid.candidates(domain[group], max(int(ring), 1))
            cosine = pair_cosines(domain_grid.columns, near, domain_grid.columns, group[site])
            closer = cosine > best[near]
            # Among new sites covering one direction, the nearest wins.
            np.maximum.at(best, near[closer], cosine[closer])
            won = closer & (cosine == best[near])
            cell[near[won]] = rank[group[site[won]]]
            compared += len(near)
        chosen.extend(new.tolist())
    return np.array(chosen, np.int64), cell, compared


def _smallest(values, count):
    """Indices of the `count` smallest values, and the smallest value of the rest (inf
    when none is left)."""
    if count >= len(values):
        return np.arange(len(values)), np.inf
    part = np.argpartition(values, count)
    return part[:count], values[part[count]]

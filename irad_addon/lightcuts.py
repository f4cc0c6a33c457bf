"""Lightcuts (Walter et al. 2005): irradiance from a light tree of VPLs through a
per-point cut, refined from the root until the cut's error is below `error` times
the point's estimate on (about) 99% of points.

A cluster C stands in for its VPLs with its representative j (Walter 2005, eq. 2):
    E_C(x) = flux_C / pi * cos_x(j) cos_y(j) / max(d_j^2, dmin^2) * V(j),
the same VPL term as gather.vpl_irradiance_chunk; cluster_bounds.py bounds its error.

Walter's criterion (every cluster's bound under the threshold) lets tens of
clusters each err by up to the threshold, so a point's error was often 2-3x it.
The representative is drawn by intensity, so each cluster's estimate is unbiased
and the cut's error is a sum of independent zero-mean terms: a cut is refined
also until _DEVIATIONS standard deviations of that sum are under the threshold.
A cluster's deviation is f's gradient against the covariance of its VPLs'
positions and normals (first order), capped by half its range (upper - lower
bound); near a shadow boundary, where the representative's visibility may not be
the cluster's, it is half its bound (see visibility_edge).

All points of a chunk refine together, one numpy step at a time: each step every
unfinished point replaces its cut nodes with the largest bound or deviation by
their children, and with them every other node within a factor 2 (a bucketed
priority queue: same stopping rule, ~log as many numpy steps). One child keeps the
parent's representative (and its already-traced visibility), so each refined node
costs one shadow ray. A step costs one scan of the chunk's cut table (float32
cutoffs per row) plus work per refined node, done in cache-sized blocks.
"""
import numpy as np

from .cluster_bounds import dot3, cluster_deviation

# Cut entries (points x cut size) held per chunk: 17 bytes each (_Cuts).
_CUT_ENTRIES = 1 << 22
# Nodes refined per block of numpy work (its temporaries stay in cache).
_BLOCK = 1 << 14
# Bound tables larger than this are gathered a node record at a time (_Table.gather),
# transposed in pieces of _TRANSPOSE nodes.
_CACHE_BYTES = 1 << 20
_TRANSPOSE = 2048
# Finished points leave the chunk's tables once this share of them is done.
_RETIRE = 0.125
# Each step refines, per point, the nodes within this factor of its largest bound.
_BUCKET = 0.5
# Standard deviations of a cut's total error kept under the error threshold:
# 99% of a normal distribution lies within 2.58 of them.
_DEVIATIONS = 2.58
# Splits below a visibility disagreement for which clusters count as possibly
# partly lit (measured on the occluder test scene: 1 leaves the 99th percentile
# at 1.5x the error, 4 brings it under; more costs rays for little).
_EDGE_GENERATIONS = 4


def vpl_weight(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps, origin):
    """cos_x cos_y / max(d^2, dmin^2) * V for point-VPL pairs, all (3, m) columns, with
    the shadow segment of gather.vpl_irradiance_chunk (offset origin, unnormalised
    direction, shortened at the VPL's end); `origin` (m, 3): the offset origins in
    the tracer's local frame (_Points)."""
    d = vpl_position - P
    dist2 = np.maximum(dot3(d, d), np.float32(1e-30))
    inv = 1 / np.sqrt(dist2)
    cos_x = dot3(d, N) * inv
    cos_y = dot3(d, vpl_normal) * -inv
    valid = (cos_x > 0) & (cos_y > 0) & (dot3(d, G) > 0)
    weight = cos_x * cos_y
    weight /= np.maximum(dist2, np.float32(min_distance2))
    weight *= valid
    pairs = np.flatnonzero(valid)
    if len(pairs):
        tfar = (1 - 1e-5) - 2 * eps * inv[pairs] / np.maximum(cos_y[pairs], np.float32(1e-2))
        blocked = tracer.occluded(np.take(origin, pairs, axis=0),
                                  np.ascontiguousarray(d[:, pairs].T), tfar,
                                  threads=False, local=True)
        weight[pairs[blocked]] = 0
    return weight


class _Cuts:
    """The cuts of a chunk's live points, one row each: row r's nodes fill its first
    size[r] columns in the order they joined (a refined node's slot takes one child,
    the other is appended), then FILL. `bound` is a node's error bound, `deviation`
    the standard deviation of its estimate, `variance` (float64) a row's sum of them
    squared."""
    FILL = {'node': -1, 'weight': 0, 'bound': -1, 'deviation': 0, 'edge': 0}
    DTYPE = {'node': np.int32, 'weight': np.float32, 'bound': np.float32,
             'deviation': np.float32, 'edge': np.int8}

    def __init__(self, rows, capacity):
        # Allocated once, unwritten (so untouched by the OS) past the columns in use.
        for name in self.FILL:
            setattr(self, name, np.empty((rows, capacity), self.DTYPE[name]))
        self.filled = 0                    # columns holding FILL or nodes
        self.reserve(1)
        self.size = np.ones(rows, np.int64)
        self.variance = np.zeros(rows)

    @property
    def width(self):                       # columns in use by the longest cut
        return int(self.size.max())

    def reserve(self, columns):
        """Fill columns up to `columns` with FILL."""
        if columns > self.filled:
            for name, fill in self.FILL.items():
                getattr(self, name)[:, self.filled:columns] = fill
            self.filled = columns

    def keep(self, live):
        """Drop the rows where `live` is False (the rest move up, in order)."""
        rows, width = int(live.sum()), self.width
        for name in self.FILL:
            array = getattr(self, name)
            array[:rows, :width] = array[live, :width]
            setattr(self, name, array[:rows])
        self.size, self.variance = self.size[live], self.variance[live]


def lightcut_irradiance(P, N, G, tree, error, max_cut, min_distance2, tracer, eps,
                        baseline=None):
    """Irradiance (n, 3) at points P (shading normals N, geometric normals G) from
    the VPLs of `tree`, and the cut size (n,) = shadow rays per point.
    `baseline` (n,), optional: irradiance the point already gets from elsewhere
    (direct light, mean over RGB); the error is then relative to the total, as in
    Walter 2005 where one tree holds every light."""
    n = len(P)
    E = np.zeros((n, 3))
    cut_size = np.zeros(n, np.int64)
    if n == 0 or tree.size == 0:
        return E, cut_size
    max_cut = max(1, int(max_cut))
    # A cut holds at most every VPL: the cut tables need no more columns.
    chunk = max(64, _CUT_ENTRIES // min(max_cut, (tree.size + 1) // 2))
    P, N, G = (np.asarray(x, np.float64) for x in (P, N, G))
    baseline = np.zeros(n) if baseline is None else np.asarray(baseline, np.float64)
    table = _Table(tree, min_distance2, tracer, eps)
    for a in range(0, n, chunk):
        part = slice(a, a + chunk)
        points = _Points(P[part], N[part], G[part], tracer, eps)
        E[part], cut_size[part] = _refine_chunk(points, baseline[part], table, error, max_cut)
    return E, cut_size


def float32_at_least(x, strict=False):
    """The smallest float32 >= x (> x if strict), per entry of float64 x: comparing
    float32 arrays against it decides as comparing them against x."""
    with np.errstate(over='ignore'):
        y = x.astype(np.float32)
    short = (y <= x) if strict else (y < x)
    return np.where(short, np.nextafter(y, np.float32(np.inf)), y)


def refine_cutoffs(cuts, width, threshold):
    """Per row, the float32 bound and deviation from which a node is refined this
    step. Walter 2005: every cluster's bound under the threshold, largest first in
    factor-2 buckets. And the cut's total error, a sum of independent zero-mean
    errors (unbiased representatives): while _DEVIATIONS standard deviations of it
    exceed the threshold, the deviations of at least half the row's largest."""
    largest = cuts.bound[:, :width].max(1)
    bucket = np.maximum(threshold, _BUCKET * largest)
    bound_cutoff = np.where(bucket > threshold, float32_at_least(bucket),
                            float32_at_least(threshold, strict=True))
    widest = cuts.deviation[:, :width].max(1)
    smallest = np.float32(np.finfo(np.float32).smallest_subnormal)
    spread = _DEVIATIONS * np.sqrt(np.maximum(cuts.variance, 0)) > threshold
    deviation_cutoff = np.where(spread, np.maximum(np.float32(_BUCKET) * widest, smallest),
                                np.float32(np.inf))
    return bound_cutoff, deviation_cutoff


def _worst_nodes(cuts, threshold, room):
    """The nodes to refine this step (refine_cutoffs), at most `room` per row (what
    is left of max_cut), the first columns first.
    Returns the row, column and rank within its row of each, and counts per row."""
    width = cuts.width
    bound_cutoff, deviation_cutoff = refine_cutoffs(cuts, width, threshold)
    mask = cuts.bound[:, :width] >= bound_cutoff[:, None]
    mask |= cuts.deviation[:, :width] >= deviation_cutoff[:, None]
    # 2D nonzero is ~3x slower than flat indices split into row and column.
    flat = np.flatnonzero(mask)
    row = flat // width
    slot = flat - row * width
    count = np.bincount(row, minlength=len(threshold))
    rank = np.arange(len(row)) - (np.cumsum(count) - count)[row]
    if (count > room).any():
        keep = rank < room[row]
        row, slot, rank = row[keep], slot[keep], rank[keep]
        count = np.minimum(count, room)
    return row, slot, rank, count


class _Points:
    """The points of a chunk as float32 (3, n) columns (the exhaustive gather's
    precision), so that per-pair gathers are contiguous, and their shadow-ray
    origins (offset along G) as float32 (n, 3) rows in the tracer's local frame."""

    def __init__(self, P, N, G, tracer, eps):
        self.P, self.N, self.G = (np.ascontiguousarray(x.T, np.float32) for x in (P, N, G))
        self.origin = tracer.to_local((self.P + self.G * eps).T)

    def keep(self, live):
        for name in ('P', 'N', 'G'):
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[:, live]))
        self.origin = self.origin[live]

    def columns(self, rows):
        """P, N, G of `rows` (float32 (3, m)) and their ray origins (m, 3)."""
        return (*(np.stack([np.take(c, rows) for c in x]) for x in (self.P, self.N, self.G)),
                np.take(self.origin, rows, axis=0))


def _refine_chunk(points, baseline, table, error, max_cut):
    n = points.P.shape[1]
    E = np.zeros((n, 3))
    cut_size = np.zeros(n, np.int64)
    rows = np.arange(n)                    # original point of each live row
    root = np.full(n, table.root)
    weight = table.weight(root, *points.columns(rows))
    estimate = table.flux[:, root].T * weight[:, None].astype(np.float64)
    cuts = _Cuts(n, min(max_cut, table.leaves))
    cuts.node[:, 0], cuts.weight[:, 0] = root, weight
    bound, deviation = table.bounds(root, points.P, points.N, points.G)
    cuts.bound[:, 0], cuts.deviation[:, 0] = bound, deviation
    cuts.variance += np.square(deviation, dtype=np.float64)
    while len(rows):
        threshold = error * (estimate.mean(1) + baseline)
        row, slot, rank, count = _worst_nodes(cuts, threshold, max_cut - cuts.size)
        done = count == 0
        if done.all() or done.mean() > _RETIRE:
            # Retire finished rows (a finished row stays finished); the rest go on.
            E[rows[done]], cut_size[rows[done]] = estimate[done], cuts.size[done]
            live = ~done
            rows, estimate, baseline = rows[live], estimate[live], baseline[live]
            cuts.keep(live)
            points.keep(live)
            if not len(rows):
                break
            renumber = np.cumsum(live) - 1
            row, count = renumber[row], count[live]
        cuts.reserve(int((cuts.size + count).max()))
        _refine_nodes(table, cuts, row, slot, cuts.size[row] + rank, estimate, points)
        cuts.size += count
    return E, cut_size


class _Table:
    """What refinement reads per node: bound data, the children (the one keeping
    the node's representative first), flux / pi and the representative VPL."""

    def __init__(self, tree, min_distance2, tracer, eps):
        self.columns = tree.bound_columns
        self.root = tree.root
        self.representative = tree.representative
        self.flux = np.ascontiguousarray((tree.flux / np.pi).T)   # (3, K)
        left, right = np.maximum(tree.left, 0), np.maximum(tree.right, 0)
        keeps = tree.representative[left] == tree.representative
        self.same, self.other = np.where(keeps, left, right), np.where(keeps, right, left)
        self.leaves = (tree.size + 1) // 2
        self.vpl_position, self.vpl_normal = (np.ascontiguousarray(x[:self.leaves].T, np.float32)
                                              for x in (tree.lo, tree.axis))
        self.min_distance2, self.tracer, self.eps = min_distance2, tracer, eps
        self._buffer = np.empty((len(self.columns), 0), np.float32)
        self.records = None
        if self.columns.nbytes > _CACHE_BYTES:
            rows = np.ascontiguousarray(self.columns.T)
            self.records = rows.view(np.dtype((np.void, rows.strides[0]))).ravel()

    def weight(self, nodes, P, N, G, origin):
        rep = self.representative[nodes]
        return vpl_weight(P, N, G, np.take(self.vpl_position, rep, axis=1),
                          np.take(self.vpl_normal, rep, axis=1), self.min_distance2,
                          self.tracer, self.eps, origin)

    def bounds(self, nodes, P, N, G):
        """Error bound and standard deviation per node (cluster_deviation)."""
        return cluster_deviation(self.gather(nodes), P, N, G, self.min_distance2)

    def gather(self, nodes):
        """The bound columns (29, m) of `nodes`, into a reused buffer (fresh large
        arrays cost page faults; take buffers `out` unless mode is not 'raise').
        A table bigger than the cache is read a node (one 116-byte record) at a
        time, then transposed in cache-sized pieces: a column-wise take would miss
        the cache once per column."""
        m = len(nodes)
        if self._buffer.shape[1] < m:
            self._buffer = np.empty((len(self.columns), m), np.float32)
        out = self._buffer[:, :m]
        if self.records is None:
            return np.take(self.columns, nodes, axis=1, out=out, mode='clip')
        rows = np.take(self.records, nodes, mode='clip').view(np.float32).reshape(m, -1)
        for a in range(0, m, _TRANSPOSE):
            np.copyto(out[:, a:a + _TRANSPOSE], rows[a:a + _TRANSPOSE].T)
        return out


def visibility_edge(w_same, w_other, parent_edge):
    """Generations left for which the children of a split stay flagged as possibly
    partly lit: _EDGE_GENERATIONS where the two representatives disagree on being
    lit (a shadow boundary runs through the parent), else one fewer than the
    parent's (a boundary seen a few splits up may still cross the child)."""
    disagree = (w_same > 0) != (w_other > 0)
    return np.where(disagree, _EDGE_GENERATIONS, np.maximum(parent_edge - 1, 0)).astype(np.int8)


def child_bounds(table, nodes, edge, P, N, G):
    """Bound and deviation of refined-in nodes (zero for single VPLs: their flux
    column is 0): near a visibility edge a cluster may be partly lit, its estimate then
    anywhere in [0, bound], a deviation of up to bound / 2 (Popoviciu)."""
    bound, deviation = table.bounds(nodes, P, N, G)
    near_edge = edge > 0
    deviation *= ~near_edge
    deviation += np.float32(0.5) * bound * near_edge
    return bound, deviation


def _refine_nodes(table, cuts, row, slot, column, estimate, points):
    """Replace the node at (row, slot) by its children: the child sharing the
    parent's representative takes the slot and the parent's weight, the other goes
    to (row, column) with one new shadow ray. In blocks of _BLOCK nodes, so that
    the temporaries stay in cache."""
    for a in range(0, len(row), _BLOCK):
        part = slice(a, a + _BLOCK)
        _refine_block(table, cuts, row[part], slot[part], column[part], estimate,
                      points.columns(row[part]))


def _refine_block(table, cuts, row, slot, column, estimate, columns):
    P, N, G, origin = columns
    capacity = cuts.node.shape[1]
    at_slot, at_column = row * capacity + slot, row * capacity + column
    parent = cuts.node.ravel()[at_slot]
    same, other = table.same[parent], table.other[parent]
    w_same = cuts.weight.ravel()[at_slot]
    w_other = table.weight(other, P, N, G, origin)
    # flux(parent) = flux(same) + flux(other), and `same` keeps the parent's weight.
    change = w_other - w_same.astype(np.float64)
    for channel, flux in enumerate(table.flux):
        estimate[:, channel] += np.bincount(row, np.take(flux, other) * change, len(estimate))
    edge = visibility_edge(w_same, w_other, cuts.edge.ravel()[at_slot])
    old = cuts.deviation.ravel()[at_slot]
    # Both children in one batch: at_slot gets `same`, at_column `other`.
    at, nodes, edge = (np.concatenate(x) for x in ((at_slot, at_column), (same, other),
                                                    (edge, edge)))
    bound, deviation = child_bounds(table, nodes, edge, *(np.concatenate((x, x), 1)
                                                          for x in (P, N, G)))
    cuts.node.ravel()[at] = nodes
    cuts.edge.ravel()[at] = edge
    cuts.bound.ravel()[at] = bound
    cuts.deviation.ravel()[at] = deviation
    cuts.weight.ravel()[at_column] = w_other
    # The rows' summed variance: the children's replace the parent's.
    added = np.square(deviation, dtype=np.float64)
    added = added[:len(row)] + added[len(row):] - np.square(old, dtype=np.float64)
    cuts.variance += np.bincount(row, added, len(estimate))

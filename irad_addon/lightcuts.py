"""Lightcuts (Walter et al. 2005): irradiance from a light tree of VPLs through a
per-point cut, refined from the root until the cut's error is below `error` times
the point's estimate on (about) 99% of points.

A cluster C stands in for its VPLs with its representative j (Walter 2005, eq. 2):
    E_C(x) = flux_C / pi * cos_x(j) cos_y(j) / max(d_j^2, dmin^2) * V(j),
the same VPL term as gather.vpl_irradiance_chunk. Its error is at most
    flux_C / pi * max cos_x * max cos_y / max(min d^2, dmin^2) * 1       (sec. 4.1)
with the cosine maxima over the cluster's bounding sphere and normal cone and the
distance minimum over its bounding box, flux_C its largest channel (the receiver
is diffuse, so its albedo/pi cancels from both sides of the test). The sphere is
looser than the paper's rotated-box cosine bound but much cheaper in numpy.

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
costs one shadow ray; a step's rays go to Embree in one call.
"""
import numpy as np

# Cut entries (points x cut size) held per chunk: 17 bytes each (_Cuts).
_CUT_ENTRIES = 1 << 22
_FIRST_CAPACITY = 32
# Each step refines, per point, the nodes within this factor of its largest bound.
_BUCKET = 0.5
# Standard deviations of a cut's total error kept under the error threshold:
# 99% of a normal distribution lies within 2.58 of them.
_DEVIATIONS = 2.58
# Splits below a visibility disagreement for which clusters count as possibly
# partly lit (measured on the occluder test scene: 1 leaves the 99th percentile
# at 1.5x the error, 4 brings it under; more costs rays for little).
_EDGE_GENERATIONS = 4


def cluster_bound(table, nodes, P, N, min_distance2):
    """Error bounds (m,) of clusters `nodes` at points P with normals N (float32
    (3, m) columns): the upper bound of `cluster_range`."""
    return cluster_range(np.take(table, nodes, axis=1), P, N, N, min_distance2)[0]


def cluster_deviation(table, nodes, P, N, G, min_distance2):
    """Error bound (m,) of each cluster and the standard deviation of its estimate
    over the choice of its representative (drawn by intensity, so unbiased):
    linearised where the cluster lies wholly in front of the point (positive lower
    bound), and at most half its range (Popoviciu) -- its bound where it may cross
    the horizon."""
    t = np.take(table, nodes, axis=1)
    upper, lower = cluster_range(t, P, N, G, min_distance2)
    half_range = 0.5 * (upper - lower)
    linear = linear_deviation(t, P, N, min_distance2)
    return upper, np.where(lower > 0, np.minimum(linear, half_range), half_range)


def linear_deviation(t, P, N, min_distance2):
    """sqrt(g^T C_y g + h^T C_n h) * flux/pi: the first-order standard deviation of
    f = cos_x cos_y / max(d^2, dmin^2) over a cluster whose VPL positions y and
    normals n have covariances C_y, C_n, with g, h the gradients of f in y and n at
    the cluster's centre and cone axis."""
    d = t[0:3] - P
    dist2 = np.maximum((d * d).sum(0), np.float32(1e-30))
    dist = np.sqrt(dist2)
    u = d / dist
    cos_x = (N * u).sum(0)
    cos_y = -(t[10:13] * u).sum(0)
    scale = 1.0 / np.maximum(dist2, min_distance2)
    # d/dy of cos_x cos_y is (cos_y N - cos_x n - 2 cos_x cos_y u) / d; 1/d^2 adds
    # -2 cos_x cos_y u / d where the clamp is off.
    pull = np.where(dist2 > min_distance2, 4.0, 2.0) * cos_x * cos_y
    g = scale / dist * (cos_y * N - cos_x * t[10:13] - pull * u)
    h = -(scale * cos_x) * u
    variance = quadratic_form(g, t[17:23]) + quadratic_form(h, t[23:29])
    return t[15] * t[16] * np.sqrt(np.maximum(variance, 0.0))


def quadratic_form(x, c):
    """x^T C x per column, C given as its 6 entries (xx, yy, zz, xy, xz, yz)."""
    return (x[0] * x[0] * c[0] + x[1] * x[1] * c[1] + x[2] * x[2] * c[2]
            + 2 * (x[0] * x[1] * c[3] + x[0] * x[2] * c[4] + x[1] * x[2] * c[5]))


def cluster_range(t, P, N, G, min_distance2):
    """Upper and lower bounds (2 x (m,)) on what one VPL of cluster `nodes` brings
    per unit of the cluster's flux, times its largest channel of flux / pi, at points
    P with normals N and geometric normals G (float32 (3, m) columns):
        upper = flux/pi * max cos_x * max cos_y / max(min d^2, dmin^2)
        lower = flux/pi * min cos_x * min cos_y / max(max d^2, dmin^2)
    with the cosines over the node's bounding sphere and normal cone and the
    distances over its box (Walter 2005 sec. 4.1 for the upper bound); `t` holds
    the clusters' LightTree.bound_columns. The upper bound caps the cluster's error
    whatever its visibility; upper - lower caps it if the whole cluster is visible.
    Both are zero for single VPLs (traced exactly)."""
    v = t[0:3] - P                                   # to the cluster's centre
    dist = np.sqrt((v * v).sum(0))
    inside = dist <= t[3]
    inv = 1.0 / np.where(inside, 1.0, dist)
    sin_a = np.where(inside, 1.0, t[3] * inv)         # the sphere's angular radius
    cos_a = np.sqrt(1.0 - sin_a * sin_a)
    # cos_x: the receiver normal against directions into the sphere; the VPL must
    # also lie above the geometric normal's plane to count at all.
    cos_b = (N * v).sum(0) * inv
    cos_x = cos_within(cos_b, cos_a, sin_a)
    min_x = cos_beyond(cos_b, cos_a, sin_a) * (cos_beyond((G * v).sum(0) * inv, cos_a, sin_a) > 0)
    # cos_y: the cone (axis, half angle) widened by the sphere, against the
    # direction from the cluster to the point.
    cos_g = -(t[10:13] * v).sum(0) * inv
    cos_s = cos_a * t[13] - sin_a * t[14]
    sin_s = sin_a * t[13] + cos_a * t[14]
    cos_y = np.where(sin_s < 0, 1.0, cos_within(cos_g, cos_s, sin_s))
    min_y = np.where(cos_s > 0, cos_beyond(cos_g, cos_s, sin_s), 0.0)
    near = np.maximum(np.maximum(t[4:7] - P, P - t[7:10]), 0.0)
    far = np.maximum(np.abs(t[4:7] - P), np.abs(P - t[7:10]))
    near2 = np.maximum((near * near).sum(0), min_distance2)
    far2 = np.maximum((far * far).sum(0), min_distance2)
    scale = t[15] * t[16]
    upper = scale * np.where(inside, 1.0, cos_x * cos_y)
    lower = scale * np.where(inside, 0.0, min_x * min_y)
    with np.errstate(divide='ignore', invalid='ignore'):
        upper = np.where(upper > 0, upper / near2, 0.0)
        lower = np.where(lower > 0, lower / far2, 0.0)
    return upper.astype(np.float32), lower.astype(np.float32)


def cos_beyond(cos_angle, cos_spread, sin_spread):
    """Smallest cos(angle + x) for 0 <= x <= spread (spread <= pi/2), clamped at 0."""
    sin_angle = np.sqrt(np.maximum(1.0 - cos_angle * cos_angle, 0.0))
    return np.maximum(cos_angle * cos_spread - sin_angle * sin_spread, 0.0)


def cos_within(cos_angle, cos_spread, sin_spread):
    """Largest cos(angle - x) for 0 <= x <= spread, clamped at 0: 1 inside the
    spread, else cos(angle - spread)."""
    sin_angle = np.sqrt(np.maximum(1.0 - cos_angle * cos_angle, 0.0))
    outside = cos_angle * cos_spread + sin_angle * sin_spread
    return np.where(cos_angle >= cos_spread, 1.0, np.maximum(outside, 0.0))


def vpl_weight(P, N, G, vpl_position, vpl_normal, min_distance2, tracer, eps):
    """cos_x cos_y / max(d^2, dmin^2) * V for point-VPL pairs, all (3, m) columns, with the shadow segment of gather.vpl_irradiance_chunk (offset origin,
    unnormalised direction, shortened at the VPL's end)."""
    d = vpl_position - P
    dist2 = np.maximum((d * d).sum(0), np.float32(1e-30))
    inv = 1 / np.sqrt(dist2)
    cos_x = (d * N).sum(0) * inv
    cos_y = -(d * vpl_normal).sum(0) * inv
    valid = (cos_x > 0) & (cos_y > 0) & ((d * G).sum(0) > 0)
    weight = np.where(valid, cos_x * cos_y / np.maximum(dist2, np.float32(min_distance2)), 0)
    pairs = np.flatnonzero(valid)
    if len(pairs):
        tfar = (1 - 1e-5) - 2 * eps * inv[pairs] / np.maximum(cos_y[pairs], np.float32(1e-2))
        origin = (P[:, pairs] + G[:, pairs] * eps).T
        blocked = tracer.occluded(origin, d[:, pairs].T, tfar, threads=False)
        weight[pairs[blocked]] = 0.0
    return weight


class _Cuts:
    """The cuts of a batch of points, one row each. Refined nodes are appended as
    new columns; a row that refines fewer nodes than others leaves holes (node -1,
    bound -1, deviation 0, weight 0), squeezed out when they pile up. `bound` is a
    node's error bound, `deviation` the standard deviation of its estimate."""
    FILL = {'node': -1, 'weight': 0, 'bound': -1, 'deviation': 0, 'edge': 0}

    def __init__(self, rows, capacity):
        self.node = np.full((rows, capacity), -1, np.int32)
        for name in ('weight', 'bound', 'deviation'):
            setattr(self, name, np.full((rows, capacity), self.FILL[name], np.float32))
        self.edge = np.zeros((rows, capacity), np.int8)
        self.width = 1                     # columns in use

    @property
    def capacity(self):
        return self.node.shape[1]

    def reserve(self, columns):
        rows, old = self.node.shape
        if columns <= old:
            return
        capacity = max(columns, 2 * old)
        for name, fill in self.FILL.items():
            array = getattr(self, name)
            bigger = np.full((rows, capacity), fill, array.dtype)
            bigger[:, :old] = array
            setattr(self, name, bigger)

    def keep(self, rows):
        for name in self.FILL:
            setattr(self, name, getattr(self, name)[rows])

    def squeeze(self, size):
        """Move every row's nodes to its first columns (stable), dropping the holes."""
        order = np.argsort(self.node[:, :self.width] < 0, axis=1, kind='stable')
        for name in self.FILL:
            array = getattr(self, name)
            array[:, :self.width] = np.take_along_axis(array[:, :self.width], order, 1)
        self.width = max(int(size.max()), 1)


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
    chunk = max(64, _CUT_ENTRIES // max_cut)
    P, N, G = (np.asarray(x, np.float64) for x in (P, N, G))
    baseline = np.zeros(n) if baseline is None else np.asarray(baseline, np.float64)
    for a in range(0, n, chunk):
        part = slice(a, a + chunk)
        E[part], cut_size[part] = _refine_chunk(P[part], N[part], G[part], baseline[part],
                                                tree, error, max_cut, min_distance2,
                                                tracer, eps)
    return E, cut_size


def _worst_nodes(cuts, threshold, room):
    """The nodes to refine this step: in each row, those whose bound exceeds the
    row's threshold and at least half the row's largest bound (largest bounds
    first, in factor-2 buckets), and, while the row's total deviation is too large,
    those with at least half its largest deviation; at most `room` (what is left
    of max_cut).
    Returns the row, column and rank within its row of each, and counts per row."""
    bound = cuts.bound[:, :cuts.width]
    deviation = cuts.deviation[:, :cuts.width]
    # Walter 2005: every cluster's bound under the threshold.
    cutoff = np.maximum(threshold, _BUCKET * bound.max(1))[:, None]
    mask = (bound >= cutoff) & (bound > threshold[:, None])
    # And the cut's total error, a sum of independent zero-mean errors (unbiased
    # representatives): refine the largest deviations while _DEVIATIONS standard
    # deviations of the sum exceed the threshold.
    total = _DEVIATIONS * np.sqrt((deviation * deviation).sum(1))
    widest = (deviation >= _BUCKET * deviation.max(1)[:, None]) & (deviation > 0)
    mask |= widest & (total > threshold)[:, None]
    count = mask.sum(1)
    over = np.flatnonzero(count > room)
    if len(over):
        mask[over] &= np.cumsum(mask[over], 1) <= room[over, None]
        count[over] = room[over]
    row, slot = np.nonzero(mask)
    rank = np.arange(len(row)) - (np.cumsum(count) - count)[row]
    return row, slot, rank, count


class _Points:
    """The points of a chunk as float32 (3, n) columns (the exhaustive gather's
    precision), so that per-pair gathers are contiguous."""

    def __init__(self, P, N, G):
        self.P, self.N, self.G = (np.ascontiguousarray(x.T, np.float32) for x in (P, N, G))


def _refine_chunk(P, N, G, baseline, tree, error, max_cut, min_distance2, tracer, eps):
    n = len(P)
    E = np.zeros((n, 3))
    cut_size = np.zeros(n, np.int64)
    points = _Points(P, N, G)
    table = _Table(tree, min_distance2, tracer, eps)
    rows = np.arange(n)                    # original point of each live row
    root = np.full(n, tree.root)
    weight = table.weight(root, points.P, points.N, points.G)
    estimate = tree.flux[root] / np.pi * weight[:, None]
    cuts = _Cuts(n, min(max_cut, _FIRST_CAPACITY))
    cuts.node[:, 0], cuts.weight[:, 0] = root, weight
    cuts.bound[:, 0], cuts.deviation[:, 0] = table.bounds(root, points.P, points.N, points.G)
    size = np.ones(n, np.int64)
    while len(rows):
        threshold = error * (estimate.mean(1) + baseline)
        row, slot, rank, count = _worst_nodes(cuts, threshold, max_cut - size)
        done = count == 0
        if done.all() or done.mean() > 0.25:
            # Retire finished rows; live rows keep being refined.
            E[rows[done]], cut_size[rows[done]] = estimate[done], size[done]
            live = ~done
            rows, estimate, size, baseline = rows[live], estimate[live], size[live], baseline[live]
            cuts.keep(live)
            if not len(rows):
                break
            renumber = np.cumsum(live) - 1
            keep = live[row]
            row, slot, rank, count = renumber[row[keep]], slot[keep], rank[keep], count[live]
        if cuts.width > 2 * size.max() + 64:
            cuts.squeeze(size)
            continue
        new_columns = int(count.max())
        cuts.reserve(cuts.width + new_columns)
        at = rows[row]
        _refine_nodes(tree, table, cuts, row, slot, cuts.width + rank, estimate,
                      points.P[:, at], points.N[:, at], points.G[:, at])
        size += count
        cuts.width += new_columns
    return E, cut_size


class _Table:
    """What refinement reads per node: bound data and the representative VPL."""

    def __init__(self, tree, min_distance2, tracer, eps):
        self.columns = tree.bound_columns
        self.representative = tree.representative
        leaves = (tree.size + 1) // 2
        self.vpl_position, self.vpl_normal = (np.ascontiguousarray(x[:leaves].T, np.float32)
                                              for x in (tree.lo, tree.axis))
        self.min_distance2, self.tracer, self.eps = min_distance2, tracer, eps

    def weight(self, nodes, P, N, G):
        rep = self.representative[nodes]
        return vpl_weight(P, N, G, self.vpl_position[:, rep], self.vpl_normal[:, rep],
                          self.min_distance2, self.tracer, self.eps)

    def bounds(self, nodes, P, N, G):
        """Error bound and standard deviation per node (cluster_deviation)."""
        return cluster_deviation(self.columns, nodes, P, N, G, self.min_distance2)


def visibility_edge(w_same, w_other, parent_edge):
    """Generations left for which the children of a split stay flagged as possibly
    partly lit: _EDGE_GENERATIONS where the two representatives disagree on being
    lit (a shadow boundary runs through the parent), else one fewer than the
    parent's (a boundary seen a few splits up may still cross the child)."""
    disagree = (w_same > 0) != (w_other > 0)
    return np.where(disagree, _EDGE_GENERATIONS, np.maximum(parent_edge - 1, 0)).astype(np.int8)


def _refine_nodes(tree, table, cuts, row, slot, column, estimate, P, N, G):
    """Replace the node at (row, slot) by its children: the child sharing the
    parent's representative takes the slot and the parent's weight, the other goes
    to (row, column) with one new shadow ray. P, N, G: the rows' point columns."""
    at_slot = row * cuts.capacity + slot
    at_column = row * cuts.capacity + column
    parent = cuts.node.ravel()[at_slot]
    left, right = tree.left[parent], tree.right[parent]
    keeps = table.representative[left] == table.representative[parent]
    same, other = np.where(keeps, left, right), np.where(keeps, right, left)
    w_same = cuts.weight.ravel()[at_slot].astype(np.float64)
    w_other = table.weight(other, P, N, G)
    # flux(parent) = flux(same) + flux(other), and `same` keeps the parent's weight.
    change = tree.flux[other] / np.pi * (w_other - w_same)[:, None]
    for channel in range(3):
        estimate[:, channel] += np.bincount(row, change[:, channel], len(estimate))
    edge = visibility_edge(w_same, w_other, cuts.edge.ravel()[at_slot])
    for at, node in ((at_slot, same), (at_column, other)):
        cuts.edge.ravel()[at] = edge
        bound, deviation = table.bounds(node, P, N, G)
        cuts.node.ravel()[at] = node
        cuts.bound.ravel()[at] = bound
        # Near a visibility edge a cluster may be partly lit: its estimate then
        # lies anywhere in [0, bound], a deviation of up to bound / 2 (Popoviciu).
        cuts.deviation.ravel()[at] = np.where(edge > 0, 0.5 * bound, deviation)
    cuts.weight.ravel()[at_column] = w_other

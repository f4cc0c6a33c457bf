"""A binary light tree over VPLs (Walter et al. 2005, "Lightcuts", sec. 4) and the
budget cut that turns it into a fixed number of clusters (for baking lights).

Clustering follows the paper's metric: merging lights costs
    I * (diag^2 + c^2 (1 - cos half)^2)                      (Walter 2005, sec. 4.1)
with I the cluster's intensity, diag its bounding-box diagonal, half the half angle
of its normal cone and c the diagonal of all VPLs' bounds. Instead of the paper's
greedy global heap (a Python loop per merge) the tree is built by parallel
locally-ordered clustering (Walter et al. 2008, "Fast agglomerative clustering for
rendering"; Meister & Bittner 2018, "PLOC"): clusters sorted on a Morton curve
each look for their cheapest merge among `_SEARCH_RADIUS` neighbours on either
side, and all mutually-best pairs merge at once. Every round is one batch of numpy
work, and the number of rounds grows with log(M).
"""
import heapq
from dataclasses import dataclass
from functools import cached_property

import numpy as np

_SEARCH_RADIUS = 8
_MORTON_BITS = 10


@dataclass
class LightTree:
    """Nodes 0..M-1 are the leaves (leaf j is VPL j); internal nodes follow in
    creation order, so children always have smaller indices than their parent and
    the root is the last node. `order[start[k]:start[k] + count[k]]` are the VPLs
    under node k."""
    left: np.ndarray        # int32 (K,), -1 for leaves
    right: np.ndarray       # int32 (K,), -1 for leaves
    flux: np.ndarray        # float64 (K, 3): total RGB flux [W]
    intensity: np.ndarray   # float64 (K,): scalar flux (mean of RGB) used for bounds
    representative: np.ndarray  # int32 (K,): VPL index standing for the node
    lo: np.ndarray          # float64 (K, 3): bounding box
    hi: np.ndarray          # float64 (K, 3)
    axis: np.ndarray        # float64 (K, 3): unit normal-cone axis
    half_angle: np.ndarray  # float64 (K,): normal-cone half angle [rad], in [0, pi]
    start: np.ndarray       # int64 (K,)
    count: np.ndarray       # int64 (K,)
    order: np.ndarray       # int64 (M,)
    scene_diagonal: float   # the metric's c
    # Intensity-weighted covariances of the VPLs' positions and normals under each
    # node (xx, yy, zz, xy, xz, yz): the spread of what a random representative sees.
    position_covariance: np.ndarray  # float64 (K, 6)
    normal_covariance: np.ndarray    # float64 (K, 6)

    @property
    def size(self):
        return len(self.left)

    @property
    def root(self):
        return self.size - 1

    @cached_property
    def bound_columns(self):
        """float32 (29, K) node data for batched bound evaluation (lightcuts): rows
        are centre xyz, radius, lo xyz, hi xyz, axis xyz, cos half, sin half,
        largest channel of flux / pi, (as 0/1) is-inner, then the position and
        normal covariances. Row-major so a gather is contiguous."""
        centre = 0.5 * (self.lo + self.hi)
        radius = 0.5 * np.linalg.norm(self.hi - self.lo, axis=1)
        return np.ascontiguousarray(np.concatenate([
            centre.T, radius[None], self.lo.T, self.hi.T, self.axis.T,
            np.cos(self.half_angle)[None], np.sin(self.half_angle)[None],
            self.flux.max(1)[None] / np.pi, (self.left >= 0)[None],
            self.position_covariance.T, self.normal_covariance.T]).astype(np.float32))

    def metric(self, nodes=slice(None)):
        """The cluster metric of Walter 2005 sec. 4.1 (zero for single VPLs)."""
        return self.intensity[nodes] * spread2(self.lo[nodes], self.hi[nodes],
                                               self.half_angle[nodes], self.scene_diagonal)


def spread2(lo, hi, half_angle, c):
    """diag^2 + c^2 (1 - cos half)^2: the squared size of a cluster in space and angle."""
    diag2 = ((hi - lo) ** 2).sum(-1)
    return diag2 + c * c * (1.0 - np.cos(half_angle)) ** 2


def morton_codes(position):
    """30-bit Morton codes of positions quantised in their bounding box."""
    lo, hi = position.min(0), position.max(0)
    scale = ((1 << _MORTON_BITS) - 1) / np.maximum(hi - lo, 1e-30)
    q = ((position - lo) * scale).astype(np.uint64)
    code = np.zeros(len(position), np.uint64)
    for axis in range(3):
        v = q[:, axis]
        # Spread the 10 bits of v to every third bit.
        v = (v | (v << np.uint64(16))) & np.uint64(0x030000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x0300F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x030C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x09249249)
        code |= v << np.uint64(axis)
    return code


def cone_union(a1, t1, a2, t2):
    """Smallest cone (axis, half angle) holding cones (a1, t1) and (a2, t2)
    (the bounding-cone merge used for Lightcuts' orientation bounds)."""
    cos_phi = np.clip((a1 * a2).sum(-1), -1.0, 1.0)
    phi = np.arctan2(np.linalg.norm(np.cross(a1, a2), axis=-1), cos_phi)  # exact near 0
    first = phi + t2 <= t1
    second = phi + t1 <= t2
    half = np.minimum(0.5 * (t1 + phi + t2), np.pi)
    # Rotate a1 towards a2 by (half - t1) in their common plane.
    perp = a2 - cos_phi[:, None] * a1
    norm = np.linalg.norm(perp, axis=-1)
    degenerate = norm < 1e-12
    if degenerate.any():  # opposite axes: every great circle through a1 reaches a2
        helper = np.where(np.abs(a1[degenerate, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        perp[degenerate] = np.cross(a1[degenerate], helper)
        norm[degenerate] = np.linalg.norm(perp[degenerate], axis=-1)
    perp /= norm[:, None]
    turn = (half - t1)[:, None]
    axis = np.cos(turn) * a1 + np.sin(turn) * perp
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    axis = np.where(first[:, None], a1, np.where(second[:, None], a2, axis))
    half = np.where(first, t1, np.where(second, t2, half))
    return axis, half


class _Nodes:
    """Growable node arrays while the tree is built."""

    def __init__(self, position, normal, flux):
        m = len(position)
        k = max(2 * m - 1, 0)
        self.left = np.full(k, -1, np.int32)
        self.right = np.full(k, -1, np.int32)
        self.flux = np.zeros((k, 3))
        self.flux[:m] = flux
        self.intensity = self.flux.mean(1)
        self.representative = np.zeros(k, np.int32)
        self.representative[:m] = np.arange(m)
        # Component-major (3, K): each coordinate is contiguous for the neighbour search.
        self.lo = np.zeros((3, k))
        self.hi = np.zeros((3, k))
        self.lo[:, :m] = self.hi[:, :m] = position.T
        self.axis = np.zeros((3, k))
        self.axis[:, :m] = normal.T
        self.half = np.zeros(k)
        self.used = m

    def merge(self, a, b, rng):
        """Append parents of node pairs (a, b); returns their indices."""
        axis, half = cone_union(self.axis[:, a].T, self.half[a], self.axis[:, b].T, self.half[b])
        new = np.arange(self.used, self.used + len(a))
        self.used += len(a)
        self.left[new], self.right[new] = a, b
        self.lo[:, new] = np.minimum(self.lo[:, a], self.lo[:, b])
        self.hi[:, new] = np.maximum(self.hi[:, a], self.hi[:, b])
        self.axis[:, new], self.half[new] = axis.T, half
        self.flux[new] = self.flux[a] + self.flux[b]
        self.intensity[new] = self.intensity[a] + self.intensity[b]
        # Representative drawn among the children in proportion to intensity
        # (Walter 2005 sec. 4), so a cluster's estimate is unbiased.
        total = self.intensity[new]
        p_left = np.where(total > 0, self.intensity[a] / np.where(total > 0, total, 1), 0.5)
        pick_left = rng.random(len(a)) < p_left
        self.representative[new] = np.where(pick_left, self.representative[a],
                                            self.representative[b])
        return new


def merge_cost(p, q, c):
    """The cluster metric of the union of clusters p and q, each given as the
    component arrays (lo xyz, hi xyz, axis xyz, half angle, intensity)."""
    dot = p[6] * q[6] + p[7] * q[7] + p[8] * q[8]
    phi = np.arccos(np.clip(dot, -1.0, 1.0))
    half = np.minimum(np.maximum(np.maximum(p[9], q[9]), 0.5 * (p[9] + phi + q[9])), np.pi)
    diag2 = sum((np.maximum(p[3 + k], q[3 + k]) - np.minimum(p[k], q[k])) ** 2
                for k in range(3))
    return (p[10] + q[10]) * (diag2 + c * c * (1.0 - np.cos(half)) ** 2)


def _best_neighbours(nodes, cur, c):
    """For each cluster in Morton order, the index (into cur) of its cheapest merge
    partner among _SEARCH_RADIUS neighbours on each side."""
    n = len(cur)
    radius = min(_SEARCH_RADIUS, n - 1)
    props = [np.take(x, cur) for x in (*nodes.lo, *nodes.hi, *nodes.axis,
                                        nodes.half, nodes.intensity)]
    forward = np.full((n, radius), np.inf)
    for d in range(1, radius + 1):
        forward[:n - d, d - 1] = merge_cost([x[:n - d] for x in props],
                                            [x[d:] for x in props], c)
    backward = np.full((n, radius), np.inf)
    for d in range(1, radius + 1):
        backward[d:, d - 1] = forward[:n - d, d - 1]
    cost = np.concatenate([forward, backward], 1)
    choice = np.argmin(cost, 1)
    offset = np.where(choice < radius, choice + 1, -(choice - radius + 1))
    return np.arange(n) + offset


def _agglomerate(nodes, order, c, rng):
    """PLOC rounds until one cluster is left; returns the id ranges of each round."""
    cur = order.astype(np.int64)
    rounds = []
    while len(cur) > 1:
        nb = _best_neighbours(nodes, cur, c)
        i = np.arange(len(cur))
        merge = (nb[nb] == i) & (i < nb)
        if not merge.any():  # cost ties can break mutuality: pair up neighbours instead
            merge = (i % 2 == 0) & (i + 1 < len(cur))
            nb = i + 1
        first = np.flatnonzero(merge)
        new = nodes.merge(cur[first], cur[nb[first]], rng)
        rounds.append((int(new[0]), int(new[-1]) + 1))
        cur[first] = new
        keep = np.ones(len(cur), bool)
        keep[nb[first]] = False
        cur = cur[keep]
    return rounds


def _leaf_ranges(left, right, m, rounds):
    """VPL ranges per node: counts bottom-up, starts top-down, one numpy step per round."""
    k = len(left)
    count = np.ones(k, np.int64)
    for a, b in rounds:
        count[a:b] = count[left[a:b]] + count[right[a:b]]
    start = np.zeros(k, np.int64)
    for a, b in reversed(rounds):
        start[left[a:b]] = start[a:b]
        start[right[a:b]] = start[a:b] + count[left[a:b]]
    order = np.empty(m, np.int64)
    order[start[:m]] = np.arange(m)
    return start, count, order


def _outer6(x):
    """The 6 distinct entries (xx, yy, zz, xy, xz, yz) of x x^T per row of x (n, 3)."""
    return np.stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2,
                     x[:, 0] * x[:, 1], x[:, 0] * x[:, 2], x[:, 1] * x[:, 2]], 1)


def weighted_covariance(x, weight, left, right, rounds):
    """Per node, the covariance (K, 6) of the rows x (M, 3) of its leaves weighted
    by `weight` (K,) (node weight = sum of its leaves'), from moments summed
    bottom-up round by round; about the mean of all x so float cancellation
    stays small. Zero where a node weighs nothing."""
    m = len(x)
    x = x - x.mean(0) if m else x
    first = np.zeros((len(left), 3))
    second = np.zeros((len(left), 6))
    first[:m] = weight[:m, None] * x
    second[:m] = weight[:m, None] * _outer6(x)
    for a, b in rounds:
        first[a:b] = first[left[a:b]] + first[right[a:b]]
        second[a:b] = second[left[a:b]] + second[right[a:b]]
    total = np.where(weight > 0, weight, 1.0)[:, None]
    covariance = second / total - _outer6(first / total)
    covariance[:, :3] = np.maximum(covariance[:, :3], 0.0)
    return np.where(weight[:, None] > 0, covariance, 0.0)


def build_light_tree(position, normal, flux, seed=0):
    """The light tree over M VPLs (arrays (M, 3)); `seed` drives the choice of
    representatives. M = 0 gives an empty tree."""
    position = np.asarray(position, np.float64).reshape(-1, 3)
    normal = np.nan_to_num(np.asarray(normal, np.float64).reshape(-1, 3))
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 1e-12, normal / np.maximum(length, 1e-12), [0.0, 0.0, 1.0])
    flux = np.maximum(np.nan_to_num(np.asarray(flux, np.float64).reshape(-1, 3)), 0.0)
    m = len(position)
    nodes = _Nodes(position, normal, flux)
    c = float(np.linalg.norm(position.max(0) - position.min(0))) if m else 0.0
    rounds = []
    if m > 1:
        order = np.argsort(morton_codes(position), kind='stable')
        rounds = _agglomerate(nodes, order, c, np.random.default_rng(seed))
    start, count, order = _leaf_ranges(nodes.left, nodes.right, m, rounds)
    position_covariance, normal_covariance = (
        weighted_covariance(x, nodes.intensity, nodes.left, nodes.right, rounds)
        for x in (position, normal))
    return LightTree(nodes.left, nodes.right, nodes.flux, nodes.intensity,
                     nodes.representative, np.ascontiguousarray(nodes.lo.T),
                     np.ascontiguousarray(nodes.hi.T), np.ascontiguousarray(nodes.axis.T),
                     nodes.half,
                     start, count, order, c, position_covariance, normal_covariance)


@dataclass
class Clusters:
    position: np.ndarray        # float64 (K, 3): flux-weighted centre
    normal: np.ndarray          # float64 (K, 3): flux-weighted unit mean normal
    flux: np.ndarray            # float64 (K, 3): summed flux [W]
    labels: np.ndarray          # int64 (M,): cluster of each VPL
    relative_error: np.ndarray  # float64 (K,): estimated relative error per cluster


def budget_cut(tree, budget):
    """Nodes of the cut with `budget` clusters: from the root, repeatedly split the
    node with the largest cluster metric (a loop per split, at most `budget`)."""
    if tree.size == 0:
        return np.zeros(0, np.int64)
    metric = tree.metric()
    heap = [(-metric[tree.root], 0, tree.root)]
    leaves = []
    while heap and len(heap) + len(leaves) < budget:
        _, _, node = heapq.heappop(heap)
        for child in (tree.left[node], tree.right[node]):
            if tree.left[child] < 0:
                leaves.append(int(child))
            else:
                heapq.heappush(heap, (-metric[child], 0, int(child)))
    return np.array(sorted([node for _, _, node in heap] + leaves), np.int64)


def cluster_relative_error(tree, nodes):
    """sqrt(diag^2 + c^2 (1 - cos half)^2) / c: the cluster's spread in space and
    angle relative to the scene size, i.e. the first-order relative change of the
    1/d^2 and cosine terms over the cluster as seen from a receiver at scene scale."""
    c = tree.scene_diagonal
    if c <= 0:
        return np.zeros(len(nodes))
    return np.sqrt(spread2(tree.lo[nodes], tree.hi[nodes], tree.half_angle[nodes], c)) / c


def cluster_by_budget(position, normal, flux, budget) -> Clusters:
    """Cluster VPLs into at most `budget` lights (Walter 2005 light tree, cut by
    largest metric). Every VPL gets one label; cluster flux sums its VPLs' flux."""
    budget = int(budget)
    if budget < 1:
        raise ValueError(f"The light budget must be at least 1, got {budget}")
    position = np.asarray(position, np.float64).reshape(-1, 3)
    normal = np.asarray(normal, np.float64).reshape(-1, 3)
    flux = np.asarray(flux, np.float64).reshape(-1, 3)
    tree = build_light_tree(position, normal, flux)
    nodes = budget_cut(tree, budget)
    k = len(nodes)
    labels = np.empty(len(position), np.int64)
    vpls = _ranges(tree.start[nodes], tree.count[nodes])
    labels[tree.order[vpls]] = np.repeat(np.arange(k), tree.count[nodes])
    cluster_flux = np.stack([np.bincount(labels, flux[:, ch], k) for ch in range(3)], 1)
    weight = np.maximum(flux.mean(1), 0.0)
    total = np.bincount(labels, weight, k)
    weight = np.where((total > 0)[labels], weight, 1.0)  # zero-flux clusters: plain mean
    total = np.bincount(labels, weight, k)
    centre = np.stack([np.bincount(labels, weight * position[:, a], k) for a in range(3)], 1)
    mean_normal = np.stack([np.bincount(labels, weight * normal[:, a], k) for a in range(3)], 1)
    length = np.linalg.norm(mean_normal, axis=1, keepdims=True)
    mean_normal = np.where(length > 1e-9, mean_normal / np.maximum(length, 1e-30),
                           tree.axis[nodes])
    return Clusters(centre / total[:, None], mean_normal, cluster_flux, labels,
                    cluster_relative_error(tree, nodes))


def _ranges(starts, counts):
    """Concatenation of arange(s, s + c) for all (s, c), without a Python loop."""
    total = int(counts.sum())
    offsets = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    return np.arange(total) + offsets

"""Low-discrepancy sequences and the warps that map them onto lights and hemispheres.

Keller 1997 draws particles from the Halton sequence; we scramble its digits with
one random permutation per digit and dimension (random digit scrambling), which
keeps the stratification and decorrelates the high dimensions and the frames.
"""
import functools

import numpy as np
from numba import njit

_PRIMES = None


def primes(count):
    """The first `count` primes."""
    global _PRIMES
    if _PRIMES is None or len(_PRIMES) < count:
        limit = max(64, int(count * (np.log(count + 2) + np.log(np.log(count + 3))) + 10))
        sieve = np.ones(limit + 1, bool)
        sieve[:2] = False
        for i in range(2, int(limit ** 0.5) + 1):
            if sieve[i]:
                sieve[i * i::i] = False
        _PRIMES = np.flatnonzero(sieve)
    return _PRIMES[:count]


def radical_inverse(base, indices, permutations=None):
    """Van der Corput radical inverse of `indices` in `base` (the definition that the
    compiled halton_at follows; tests compare them), digits optionally
    permuted (permutations: (digits, base) int array, one permutation per digit)."""
    indices = np.asarray(indices, np.int64).copy()
    digits = int(np.ceil(32 * np.log(2) / np.log(base)))
    result = np.zeros(indices.shape, np.float64)
    scale = 1.0 / base
    for k in range(digits):
        digit = indices % base
        if permutations is not None:
            digit = permutations[k][digit]
        result += digit * scale
        indices //= base
        scale /= base
    return np.minimum(result, 1.0 - 2.0 ** -53)


def _digit_permutations(base, rng):
    digits = int(np.ceil(32 * np.log(2) / np.log(base)))
    return np.array([rng.permutation(base) for _ in range(digits)])


@functools.lru_cache(maxsize=16)
def scrambling(seed, dims):
    """The digit permutations of each dimension for `seed` (None for seed 0): drawn once
    per seed, as drawing them costs more than a few hundred points."""
    if not seed:
        return (None,) * dims
    rng = np.random.default_rng(seed)
    tables = tuple(_digit_permutations(int(base), rng) for base in primes(dims))
    for table in tables:   # shared by every later call: read-only
        table.flags.writeable = False
    return tables


@functools.lru_cache(maxsize=16)
def _packed_scrambling(seed, dims):
    """scrambling(seed, dims) flattened for _halton_points: digits per dimension, each
    dimension's offset into the tables, all tables end to end, and per dimension and
    digit k the value of digits k.. once the index has run out of digits (each a
    permuted 0: `tail`, digits + 1 entries per dimension). Empty tables for seed 0."""
    bases = primes(dims).astype(np.int64)
    digits = np.ceil(32 * np.log(2) / np.log(bases)).astype(np.int64)
    tables = scrambling(seed, dims)
    tail_offsets = np.concatenate([[0], np.cumsum(digits + 1)[:-1]])
    if tables[0] is None:
        return digits, np.zeros(dims, np.int64), np.zeros(0, np.int64), \
            tail_offsets, np.zeros(int((digits + 1).sum()))
    sizes = np.array([t.size for t in tables], np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    tails = []
    for base, table in zip(bases, tables):
        zeros = table[:, 0] * float(base) ** -np.arange(1.0, len(table) + 1)
        tails.append(np.concatenate([np.cumsum(zeros[::-1])[::-1], [0.0]]))
    return (digits, offsets, np.concatenate([t.ravel() for t in tables]).astype(np.int64),
            tail_offsets, np.concatenate(tails))


def halton(count, dims, seed=0, start=0):
    """(count, dims) points of the Halton sequence, indices start..start+count-1.
    seed 0 is the plain sequence; other seeds scramble the digits."""
    return halton_at(np.arange(start, start + count, dtype=np.int64), 0, dims, dims, seed)


def halton_at(index, first, count, dims, seed=0):
    """(len(index), count) Halton points at `index`, dimensions first..first+count-1 of
    a `dims`-dimensional sequence (its scrambling). Compiled: radical_inverse per
    dimension, to rounding."""
    out = np.empty((len(index), count), np.float64)
    digits, offsets, table, tail_offsets, tail = _packed_scrambling(seed, dims)
    chosen = slice(first, first + count)
    _halton_points(np.asarray(index, np.int64), primes(dims)[chosen].astype(np.int64),
                   digits[chosen], offsets[chosen], table, tail_offsets[chosen], tail, out)
    return out


@njit(cache=True, nogil=True)
def _halton_points(index, bases, digits, offsets, table, tail_offsets, tail, out):
    scrambled = len(table) > 0
    for d in range(len(bases)):
        base = bases[d]
        inverse = 1.0 / base
        for i in range(len(index)):
            n, result, scale, k = index[i], 0.0, inverse, 0
            while n > 0 and k < digits[d]:   # the index's own digits
                rest = n // base
                digit = n - rest * base
                if scrambled:
                    digit = table[offsets[d] + k * base + digit]
                result += digit * scale
                n = rest
                scale *= inverse
                k += 1
            if scrambled:                    # the permuted zeros after them
                result += tail[tail_offsets[d] + k]
            out[i, d] = min(result, 1.0 - 2.0 ** -53)


def systematic_draws(weights, count, rng):
    """`count` draws in proportion to `weights` by systematic resampling (one uniform
    offset shared by all draws: every weight w gets floor or ceil of count w / sum w).
    Returns the distinct indices drawn and how often each, in random order: VPL lists
    are split into interleaved groups by position (gather.vpl_subsets), and each group
    must not take one stretch of whatever order the weights came in."""
    cdf = np.cumsum(weights)
    cdf = cdf / cdf[-1]
    drawn = np.searchsorted(cdf, (rng.random() + np.arange(count)) / count, side='right')
    index, times = np.unique(np.minimum(drawn, len(weights) - 1), return_counts=True)
    order = rng.permutation(len(index))
    return index[order], times[order]


def hammersley(count, dims, seed=0):
    """Hammersley points: i/count in the first dimension, Halton in the rest,
    shifted by a Cranley-Patterson rotation when seed != 0."""
    out = np.empty((count, dims), np.float64)
    out[:, 0] = (np.arange(count) + 0.5) / count
    if dims > 1:
        out[:, 1:] = halton(count, dims - 1)
    if seed:
        out = cranley_patterson(out, seed)
    return out


SEQUENCES = ('HALTON', 'HAMMERSLEY', 'JITTERED')


def particle_points(sequence, count, dims, seed, batch=0):
    """`count` points in [0,1)^dims for one light's particles (Keller 1997 sec. 3):
    HALTON, scrambled Halton; HAMMERSLEY, i/count in the first dimension (needs the
    count up front); JITTERED, Hammersley with the first dimension jittered inside its
    stratum (Keller's jittered low-discrepancy sampling). Batch b of a walkthrough's
    paths continues the Halton indices after batches 0..b-1 (and shifts the first
    dimension of the others anew), so batches 0..N-1 are one N * count point set."""
    start = 1 + batch * count
    if sequence == 'HALTON':
        return halton(count, dims, seed=seed + 1, start=start)
    rng = np.random.default_rng([seed, batch] if batch else seed)
    out = np.empty((count, dims))
    jitter = rng.random(count) if sequence == 'JITTERED' else 0.5
    out[:, 0] = (np.arange(count) + jitter) / count
    if dims > 1:
        out[:, 1:] = halton(count, dims - 1, seed=seed + 1, start=start)
    if sequence == 'HAMMERSLEY':
        out[:, 0] = (out[:, 0] + rng.random()) % 1.0   # Cranley-Patterson in dimension 0
    return out


class ParticleColumns:
    """Columns first.. of the particle_points of consecutive blocks of particles (one
    per light: counts, seeds), computed only for the rows asked: a path draws its
    bounce dimensions only while it lives (most die after a few bounces)."""

    def __init__(self, sequence, counts, seeds, first, dims, batch=0):
        self.starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.first_index = 1 + batch * np.asarray(counts, np.int64)   # per block
        self.seeds = list(seeds)
        # particle_points' dimension d is Halton dimension d, or d - 1 where the first
        # dimension is i/count (Hammersley, jittered).
        self.first = first - (0 if sequence == 'HALTON' else 1)
        self.dims = dims - (0 if sequence == 'HALTON' else 1)

    def __getitem__(self, key):
        rows, columns = key
        rows = np.asarray(rows, np.int64)
        start, stop, _ = columns.indices(self.dims - self.first)
        out = np.empty((len(rows), stop - start))
        block = np.searchsorted(self.starts, rows, side='right') - 1
        for b in np.unique(block):
            mine = np.flatnonzero(block == b)
            # particle_points draws Halton indices from 1 + batch * count, with seed + 1.
            out[mine] = halton_at(rows[mine] - self.starts[b] + self.first_index[b],
                                  self.first + start,
                                  stop - start, self.dims, self.seeds[b] + 1)
        return out


def cranley_patterson(points, seed):
    """Toroidal shift of every dimension by one random offset (Cranley & Patterson 1976)."""
    shift = np.random.default_rng(seed).random(points.shape[-1])
    return (points + shift) % 1.0


def scrambled_02(first, count, scramble):
    """(count, n, 2): for each of n points, points first[i] .. first[i] + count - 1 of
    the (0,2)-sequence in base 2 (van der Corput and Sobol's second dimension; Kollig &
    Keller 2002, "Efficient multidimensional sampling"), XOR-scrambled by the point's
    row of `scramble` (uint32 (n, 2)): a random digital shift, so that every aligned
    block of 2^k points stays a (0,k,2)-net, stratified in every elementary interval."""
    first = np.ascontiguousarray(first, np.uint32)
    out = np.empty((count, len(first), 2))
    _scrambled_02(first, np.ascontiguousarray(scramble, np.uint32), out)
    return out


@njit(cache=True, nogil=True)
def _scrambled_02(first, scramble, out):
    scale = 1.0 / 4294967296.0
    for i in range(len(first)):
        for j in range(out.shape[0]):
            n = first[i] + np.uint32(j)
            x = np.uint32(0)      # van der Corput: the bits of n reversed
            y = np.uint32(0)      # Sobol' 2: v runs through 1 << 31 xor-shifted
            v = np.uint32(1 << 31)
            bit = np.uint32(1 << 31)
            while n:
                if n & 1:
                    x ^= bit
                    y ^= v
                n >>= 1
                bit >>= np.uint32(1)
                v = np.uint32(v ^ (v >> np.uint32(1)))
            out[j, i, 0] = (x ^ scramble[i, 0]) * scale
            out[j, i, 1] = (y ^ scramble[i, 1]) * scale


def jittered_2d(count, rng):
    """Stratified (jittered) samples in [0,1)^2: a sqrt(count)^2 grid, one sample a cell,
    the remainder uniform."""
    side = int(np.sqrt(count))
    cells = side * side
    out = rng.random((count, 2))
    if side > 0:
        grid = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing='ij'), -1)
        out[:cells] = (grid.reshape(-1, 2) + out[:cells]) / side
    return out


# -- warps ------------------------------------------------------------------

def square_to_disk(u):
    """Concentric map of [0,1)^2 onto the unit disk (Shirley & Chiu 1997), (n, 2)."""
    a = 2.0 * u[..., 0] - 1.0
    b = 2.0 * u[..., 1] - 1.0
    first = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    r = np.where(first, a, b)
    phi = np.where(first, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    return np.stack([r * np.cos(phi), r * np.sin(phi)], -1)


def square_to_cosine_hemisphere(u):
    """Cosine-weighted directions about +Z (Malley's method), pdf = cos / pi."""
    d = square_to_disk(u)
    z = np.sqrt(np.maximum(0.0, 1.0 - (d * d).sum(-1)))
    return np.concatenate([d, z[..., None]], -1)


def square_to_sphere(u):
    """Uniform directions on the unit sphere, pdf = 1 / (4 pi)."""
    z = 1.0 - 2.0 * u[..., 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[..., 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def square_to_cone(u, cos_max):
    """Uniform directions in the cone about +Z with half-angle acos(cos_max),
    pdf = 1 / (2 pi (1 - cos_max))."""
    z = 1.0 - u[..., 0] * (1.0 - cos_max)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[..., 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def square_to_triangle(u):
    """Uniform barycentrics (b1, b2) on a triangle (Heitz 2019 low-distortion map)."""
    b0 = u[..., 0] / 2
    b1 = u[..., 1] / 2
    offset = b1 - b0
    shift_b0 = offset > 0
    b1 = np.where(shift_b0, b1 + offset, b1)
    b0 = np.where(shift_b0, b0, b0 - offset)
    return np.stack([b0, b1], -1)


def orthonormal_basis(n):
    """Tangent frames (t, b) for unit normals n (n, 3), branchless (Duff et al. 2017)."""
    sign = np.where(n[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    t = np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], -1)
    s = np.stack([b, sign + n[..., 1] ** 2 * a, -n[..., 1]], -1)
    return t, s


def to_world(local, n):
    """Rotate local directions (about +Z) into the frame of normals n."""
    t, s = orthonormal_basis(n)
    return local[..., :1] * t + local[..., 1:2] * s + local[..., 2:3] * n

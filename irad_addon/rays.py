"""Batched ray queries against one Embree scene per frame (embreex, Embree 4).

All queries take and return numpy arrays; big batches are split over a thread pool
because embreex releases the GIL inside `run`, so both cores trace at once.
"""
import hashlib
import itertools
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .geometry import coordinate_bounds

# Rays per thread task: big enough to amortise the Python call, small enough to balance.
_TASK_RAYS = 1 << 16
_pool = None
_workers = None   # the user's thread count (preferences); None = one per CPU core


def worker_count():
    return _workers or max(1, os.cpu_count() or 1)


def set_worker_count(count):
    """Use `count` worker threads from now on (0 or None: one per CPU core)."""
    global _pool, _workers
    _workers = count or None
    if _pool is not None and _pool._max_workers != worker_count():
        _pool.shutdown(wait=True)
        _pool = None


def thread_pool():
    global _pool
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=worker_count(), thread_name_prefix="irad")
    return _pool


_calling_thread = threading.local()


@contextmanager
def on_calling_thread(busy=lambda: True):
    """Within this block, while busy() is true, parallel_map runs on the calling thread:
    for work that overlaps a background job holding the pool's workers
    (render.render_band), whose queue it would otherwise wait behind."""
    before = getattr(_calling_thread, "busy", None)
    _calling_thread.busy = busy
    try:
        yield
    finally:
        _calling_thread.busy = before


def on_calling_thread_now():
    """Whether parallel_map runs on this thread now (on_calling_thread)."""
    busy = getattr(_calling_thread, "busy", None)
    return busy is not None and busy()


def run_now(function, *args):
    """A finished Future of function(*args), run on this thread."""
    future = Future()
    try:
        future.set_result(function(*args))
    except BaseException as error:   # re-raised by result(), as a pool task's would be
        future.set_exception(error)
    return future


def submit_whole(function, *args):
    """function(*args) as one task on the pool, its own rays on the worker's thread
    (on_calling_thread): a worker never waits for tasks queued behind it. With one
    thread (the user's preference) it runs here and now: one thread works at a time.
    Returns a Job: its result() runs the task on the waiting thread if no worker
    has started it yet."""
    if worker_count() < 2:
        return Job(run_now(function, *args), function, *args)

    def whole():
        with on_calling_thread():
            return function(*args)
    return Job(thread_pool().submit(whole), whole)


class Job:
    """A pool task whose waiter does it itself while it is still queued, instead of
    idling until a worker comes free."""

    def __init__(self, future, function, *args):
        self.future, self.function, self.args = future, function, args

    def take(self):
        """Run the task here if no worker has started it; True if it was run."""
        if not self.future.cancel():
            return False
        self.future = run_now(self.function, *self.args)
        return True

    def done(self):
        return self.future.done()

    def result(self, take=True):
        """The task's result; with `take`, run here first if it is still queued."""
        if take:
            self.take()
        return self.future.result()


def shared_map(function, count):
    """[function(i) for i in range(count)], run on this thread and on one pool worker
    if one comes free meanwhile: both take the next i from one counter, so a worker
    idle beside this thread's serial work shares it, and one busy with queued work (the
    VPL gather) leaves it all here; a helper not started by the end is withdrawn. Each
    call's rays run on its own thread (on_calling_thread)."""
    results, order, stop = [None] * count, itertools.count(), threading.Event()

    def drain():
        with on_calling_thread():
            for i in order:
                if i >= count or stop.is_set():
                    return
                results[i] = function(i)
    helper = (thread_pool().submit(drain) if count > 1 and worker_count() > 1 else None)
    try:
        drain()
    finally:
        stop.set()
        if helper is not None and not helper.cancel():
            helper.result()
    return results


def parallel_map(function, ranges):
    """Run function(start, stop) over ranges in the pool, results in order."""
    if len(ranges) == 1 or on_calling_thread_now():
        return [function(*r) for r in ranges]
    return list(thread_pool().map(lambda r: function(*r), ranges))


def split_ranges(count, pieces, minimum=_TASK_RAYS):
    pieces = max(1, min(pieces, -(-count // minimum)))
    if pieces == 1:   # most calls: skip building edges for one range
        return [(0, int(count))] if count > 0 else []
    edges = np.linspace(0, count, pieces + 1).astype(np.int64)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def triangle_fingerprint(triangles):
    """A cheap key for 'did the geometry change': SHA-1 of the vertex bytes."""
    return hashlib.sha1(array_bytes(triangles)).digest()


def array_bytes(array):
    """An array's bytes for hashing, read in place (a copy of a million triangles
    would cost more than the hash)."""
    return np.ascontiguousarray(array).reshape(-1).view(np.uint8)


@dataclass
class Hits:
    distance: np.ndarray     # float32 (n,), inf where the ray missed
    triangle: np.ndarray     # int32 (n,), -1 where the ray missed
    barycentric: np.ndarray  # float32 (n, 2): (u, v) of the hit within its triangle

    @property
    def hit(self):
        return self.triangle >= 0


class RayTracer:
    """Closest-hit and any-hit queries over a fixed set of world-space triangles.
    threads=False keeps a query on the calling thread (for callers that already run
    in the pool).

    Embree works in float32, so the tracer holds the triangles relative to the centre
    of their bounds and moves every ray origin there in float64 first: a scene far from
    the world origin traces exactly like the same scene at the origin (callers keep
    float64 world positions; distances and barycentrics do not depend on the frame)."""

    def __init__(self, triangles):
        from embreex import mesh_construction, rtcore_scene
        self.triangles = np.ascontiguousarray(triangles, np.float32)
        self.fingerprint = triangle_fingerprint(self.triangles)
        self.empty = len(self.triangles) == 0
        lo, hi = coordinate_bounds(self.triangles) if not self.empty else (np.zeros(3),) * 2
        self.extent = float(np.linalg.norm(hi - lo)) if not self.empty else 1.0
        self.center = 0.5 * (lo + hi)
        if not self.empty:
            local = self.to_local(self.triangles.reshape(-1, 3)).reshape(self.triangles.shape)
            # The largest coordinate in the local frame: half the box's widest side.
            self.magnitude = float(np.max(np.maximum(hi - self.center, self.center - lo)))
            # Robust (watertight) traversal: rays through shared edges never slip through.
            self._scene = rtcore_scene.EmbreeScene(robust=True)
            mesh_construction.TriangleMesh(self._scene, local)
        else:
            self.magnitude = 0.0

    def to_local(self, points):
        """float32 coordinates relative to the scene's centre (subtracted in float64):
        what `local=True` queries take as origins."""
        return np.ascontiguousarray(np.asarray(points, np.float64) - self.center, np.float32)

    def offset_scale(self):
        """Ray-origin offset that stays above float32 round-off at any scene scale:
        a small fraction of the scene size plus ~8 float32 ulps of its largest
        coordinate in the tracer's local frame."""
        return 1e-5 * self.extent + 1e-6 * self.magnitude

    def intersect(self, origins, directions, tfar=None, threads=True, local=False):
        n = len(origins)
        if self.empty or n == 0:
            return Hits(np.full(n, np.inf, np.float32), np.full(n, -1, np.int32),
                        np.zeros((n, 2), np.float32))
        parts = self._run(origins, directions, tfar, threads, local, output=1)
        prim = np.concatenate([p['primID'] for p in parts]).astype(np.int32)
        dist = np.concatenate([p['tfar'] for p in parts])
        bary = np.stack([np.concatenate([p['u'] for p in parts]),
                         np.concatenate([p['v'] for p in parts])], -1)
        dist[prim < 0] = np.inf
        return Hits(dist, prim, bary)

    def occluded(self, origins, directions, tfar, threads=True, local=False):
        """True where something blocks the segment origin + t*direction, 0 < t < tfar.
        local=True: origins are already float32 in the tracer's frame (`to_local`)."""
        n = len(origins)
        if self.empty or n == 0:
            return np.zeros(n, bool)
        return np.concatenate(self._run(origins, directions, tfar, threads, local,
                                        query='OCCLUDED')) >= 0

    def _run(self, origins, directions, tfar, threads, local, **query):
        """embreex `run` over the batch, split into pool tasks; a list of their results."""
        n = len(origins)
        origins = (np.ascontiguousarray(origins, np.float32) if local
                   else self.to_local(origins))
        directions = np.ascontiguousarray(directions, np.float32)
        tfar = self._tfar(tfar, n)
        return parallel_map(
            lambda a, b: self._scene.run(origins[a:b], directions[a:b], dists=tfar[a:b].copy(),
                                         **query),
            split_ranges(n, 4 * worker_count() if threads else 1))

    @staticmethod
    def _tfar(tfar, n):
        if tfar is None:
            return np.full(n, 1e30, np.float32)
        tfar = np.broadcast_to(np.asarray(tfar, np.float32), (n,))
        return np.ascontiguousarray(np.minimum(tfar, 1e30))


class CountingTracer:
    """A RayTracer that counts the rays asked of it (`rays`): for cost measurements.
    Everything else is the tracer's own."""

    def __init__(self, tracer):
        self.tracer, self.rays = tracer, 0

    def __getattr__(self, name):
        return getattr(self.tracer, name)

    def intersect(self, origins, *args, **kwargs):
        self.rays += len(origins)
        return self.tracer.intersect(origins, *args, **kwargs)

    def occluded(self, origins, *args, **kwargs):
        self.rays += len(origins)
        return self.tracer.occluded(origins, *args, **kwargs)


class RayTracerCache:
    """Keeps the last frame's RayTracer and reuses it while the triangles are unchanged."""

    def __init__(self):
        self._tracer = None
        self.builds = 0

    def get(self, triangles):
        key = triangle_fingerprint(np.ascontiguousarray(triangles, np.float32))
        if self._tracer is None or self._tracer.fingerprint != key:
            self._tracer = RayTracer(triangles)
            self.builds += 1
        return self._tracer


class CountingTracerCache(RayTracerCache):
    """A RayTracerCache whose frames count their rays: `tracer.rays` is the last
    frame's (a CountingTracer per frame, over the one kept RayTracer)."""

    def __init__(self):
        super().__init__()
        self.tracer = None

    def get(self, triangles):
        self.tracer = CountingTracer(super().get(triangles))
        return self.tracer

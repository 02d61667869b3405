"""Running independent view-pair tasks: threads of this process, or any ``map``.

View pairs, and then their consistency checks, are independent tasks; in this process
they run on one thread per core (the numba LSM kernels release the GIL and run
single-threaded in each), or on any ``map_func`` (a Dask executor's).  A task carries a
:class:`ViewRef` (a lazily loading image sequence and an index) instead of pixels, so an
image is in memory only while a task uses it.  Results do not depend on the thread
count: every kernel works per point.

A stop (Ctrl-C, SIGTERM raised in the main thread) acts at once: the tasks run off
the main thread even with one worker, so the main thread waits where a signal can
interrupt it (not inside a minutes-long numba call); the queued tasks are cancelled, and
the map's own stop flag is set, which its running tasks (and the maps they started)
check between their LSM rounds and steps (:func:`check_stop`) and end on.  The flag
belongs to one map: an interrupted map leaves no state behind for the next run in the
same process.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

__all__ = ["ViewRef", "load_image", "thread_map", "default_workers", "Stopped",
           "check_stop"]

# numba's OpenMP workers sleep between kernels instead of spinning (GNU OpenMP reads this
# when numba first loads it, at the first parallel kernel; a value already set is kept).
# The kernels run for milliseconds to seconds, so the wake-up costs nothing, while the
# spinning costs CPU: 56 873 recorded temple windows on 2 numba threads took a mean 2.61
# CPU-s spinning and 2.46 sleeping, against 2.25 on one thread, on a loaded machine
# (docs/decisions/acquire-profile.md, "Both cores, measured per thread").
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


class Stopped(Exception):
    """A task ended early because its map (or a map it runs in) was interrupted."""


def check_stop() -> None:
    """Raise :class:`Stopped` when the map running this task was interrupted (a few
    microseconds: call it between LSM rounds, pairs and the steps of a task).

    Also the point where a task of :func:`thread_map` takes the cores its map leaves
    idle: once no task waits in the queue, the running ones share every worker's core
    among them for their next numba kernels (the last view pair of a map no longer runs
    on one core while the other idles)."""
    if any(flag.is_set() for flag in getattr(_LOCAL, "stops", ())):
        raise Stopped("interrupted")
    share = getattr(_LOCAL, "share", None)
    if share is not None:
        share.rebalance()


_LOCAL = threading.local()


class _CoreShare:
    """The cores of one :func:`thread_map` call, shared by its running tasks."""

    def __init__(self, workers: int, tasks: int):
        self.lock = threading.Lock()
        self.workers, self.unstarted, self.running = workers, tasks, 0

    def enter(self) -> None:
        with self.lock:
            self.unstarted -= 1
            self.running += 1
        _LOCAL.share = self
        self._threads(1)

    def leave(self) -> None:
        _LOCAL.share = None
        with self.lock:
            self.running -= 1

    def rebalance(self) -> None:
        with self.lock:
            threads = self.workers // max(1, self.running) if self.unstarted <= 0 else 1
        self._threads(max(1, threads))

    @staticmethod
    def _threads(n: int) -> None:
        import numba

        n = min(n, numba.config.NUMBA_NUM_THREADS)
        if numba.get_num_threads() != n:
            numba.set_num_threads(n)


@dataclass(frozen=True)
class ViewRef:
    """One view's image, read on use from a lazily loading image sequence.

    Tasks carry this (the sequence names files; it pickles small) instead of the pixels,
    so that an image is in memory only while a task uses it.
    """

    images: Sequence
    index: int

    def load(self) -> np.ndarray:
        return np.asarray(self.images[self.index])


def load_image(ref) -> np.ndarray:
    return ref.load() if isinstance(ref, ViewRef) else ref


def kernels_release_gil() -> bool:
    """True when the LSM and second-order numba kernels are compiled with ``nogil=True``."""
    from matching import lsm, second_order

    kernels = [getattr(lsm, "_lsm_batch", None),
               getattr(second_order, "_second_order_kernel", None)]
    return all(getattr(k, "targetoptions", {}).get("nogil", False) for k in kernels)


def thread_map(workers: int) -> Callable:
    """``map(func, items)`` on ``workers`` threads of this process, results in order.

    View pairs are independent and much of a pair's time is serial (SIFT, SGBM,
    rectification, numpy), so two pairs at once keep two cores busy where one pair's
    numba ``prange`` kernels alone leave them half idle.  When the kernels release the
    GIL each thread runs them on one numba thread (``numba.set_num_threads`` is
    per thread) while tasks wait in the queue, and on a share of the idle cores once
    none does (:func:`check_stop`); else they keep numba's default and the other threads
    overlap them with GIL-free OpenCV/numpy work.  Results do not depend on the thread
    count (every kernel works per point).
    """
    def run(func, items):
        items = list(items)
        if not items:
            return []
        if workers <= 1 or len(items) < 2:
            if threading.current_thread() is not threading.main_thread():
                return [func(item) for item in items]
            # one worker thread, so that the main thread waits interruptibly
            return map_without_waiting(func, items, 1)
        if not kernels_release_gil():
            return map_without_waiting(func, items, min(workers, len(items)))
        share = _CoreShare(min(workers, len(items)), len(items))

        def call(item):
            share.enter()  # one numba thread while others wait (check_stop rebalances)
            try:
                return func(item)
            finally:
                share.leave()

        return map_without_waiting(call, items, share.workers)
    return run


def map_without_waiting(func: Callable, items: list, workers: int) -> list:
    """``list(pool.map(func, items))`` on a pool of ``workers`` threads; when the wait is
    interrupted (Ctrl-C, SIGTERM raised in the main thread, a task's error) the queued
    tasks are cancelled, this map's stop flag is set and the running ones are not waited
    for, so the interruption acts at once (the CLI then ends the process;
    ``pipeline.cli``).  A task sees the flags of its own map and of the maps around it
    (:func:`check_stop`); no other thread does."""
    stop = threading.Event()
    stops = (*getattr(_LOCAL, "stops", ()), stop)

    def call(item):
        _LOCAL.stops = stops
        try:
            return func(item)
        finally:
            _LOCAL.stops = ()

    pool = ThreadPoolExecutor(workers)
    try:
        results = list(pool.map(call, items))
    except BaseException:
        stop.set()  # the running tasks end at their next check_stop
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown(wait=True)
    return results


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)

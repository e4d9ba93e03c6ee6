"""Per-source work of the fill on threads.

The fill repeats the same work for every source (sample it through its match,
convert to Lab, compare); OpenCV and NumPy release the GIL in that work, so two
sources run at once on a 2-core machine. Each call writes only its own source's
slots, so the results do not depend on the order (outputs byte-identical to a
sequential loop).
"""

from __future__ import annotations

import functools
import os
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import cv2
import numba
import numpy as np

T = TypeVar("T")


@numba.njit(cache=True, parallel=True)
def _probe(a):
    for i in numba.prange(a.shape[0]):
        a[i] = i


@functools.lru_cache(maxsize=1)
def numba_threads_safe() -> bool:
    """Whether several Python threads may launch numba's parallel kernels at once.

    Not with numba's "workqueue" threading layer: the only one numba guarantees,
    and the one a machine gets without OpenMP or TBB (numba's pip wheels on
    macOS, a container without libgomp, ``NUMBA_THREADING_LAYER=workqueue``); it
    aborts the whole process on concurrent launches (``SIGABRT``: 2 runs of 3 on
    DAVIS camel, inside ``colour.delta_e`` on the fill's threads). numba picks
    its layer at the first parallel launch, which this makes (a cached 2-element
    kernel). Then the per-source work runs in turn (the same results).
    """
    if numba.config.DISABLE_JIT:
        return True
    _probe(np.zeros(2))
    return numba.threading_layer() != "workqueue"


# set in a child process forked from one whose numba kernels ran on the OpenMP layer
_FORKED_FROM_OMP = False


def _note_fork_in_child() -> None:
    global _FORKED_FROM_OMP
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel ran before the fork: nothing to fear
        return
    _FORKED_FROM_OMP = layer == "omp"


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_note_fork_in_child)


def check_fork_safe() -> None:
    """RuntimeError in a process forked from one that had run numba's OpenMP layer.

    GNU OpenMP (libgomp, numba's "omp" threading layer on Linux) is not fork-safe:
    numba terminates a forked child at its first parallel kernel ("Terminating:
    fork() called from a process already using GNU OpenMP"), and a
    ``multiprocessing.Pool`` whose workers die so waits forever (a fresh-user
    trial: one call in the notebook, then a pool of the default "fork" start
    method, hung). This says what to do instead, before any kernel runs.
    """
    if _FORKED_FROM_OMP:
        raise RuntimeError(
            "this process was forked from one that had already run dynremove "
            "(multiprocessing's 'fork' start method, the default on Linux): numba's "
            "OpenMP threading layer is not fork-safe and would end it. Start the "
            "worker processes with multiprocessing.get_context('spawn') or "
            "'forkserver' (ProcessPoolExecutor(mp_context=...)), or run dynremove "
            "in the parent only after the pool has started")


def for_each_source(fn: Callable[[int], T], n: int, *,
                    on_done: Callable[[int], None] | None = None) -> list[T]:
    """``[fn(k) for k in range(n)]``, on threads when OpenCV may use more than one
    (not inside an ``eval --jobs`` worker) and numba's parallel kernels may be
    launched from threads at once (``numba_threads_safe``). ``fn`` must write only its own
    source's slots; exceptions propagate (the sources not yet started are
    cancelled). ``on_done(k)`` is called on the calling thread as each result
    arrives, in source order (progress).

    The standard library's thread pool, one per call: a call costs ~0.3 ms.
    (joblib's threading backend cost 17-21 ms a call, a pool of its own and a
    result loop that polls every 10 ms, ~0.2 s a run at 7 × 854×480.)
    """
    workers = min(n, os.cpu_count() or 1)
    if n <= 1 or cv2.getNumThreads() <= 1 or workers <= 1 or not numba_threads_safe():
        out = []
        for k in range(n):
            out.append(fn(k))
            if on_done is not None:
                on_done(k)
        return out
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="dynremove-source")
    try:
        futures = [pool.submit(fn, k) for k in range(n)]
        out = []
        for k, f in enumerate(futures):
            out.append(f.result())
            if on_done is not None:
                on_done(k)
        return out
    finally:
        # on an exception (or Ctrl-C) the sources not yet started do not run
        pool.shutdown(wait=True, cancel_futures=True)


def one_thread_per_worker() -> None:
    """In a worker process of ``eval --jobs`` or ``batch --jobs`` (the parallelism
    comes from the processes): OpenCV and numba on one thread each, so that two
    workers do not run four threads on two cores (the scan's row pipeline, whose
    threads wait for each other's rows, loses the most to that)."""
    cv2.setNumThreads(1)
    numba.set_num_threads(1)


def quiet_worker_restarts() -> None:
    """Silence joblib's "A worker stopped while some jobs were given to the executor
    ... memory leak" warning in this (the parent) process.

    Its process pool (loky) restarts a worker whose memory grew by more than 300 MB
    over a task, as a guard against leaks; one set of photos takes more than that by
    itself, so with ``--jobs 2`` every run printed the warning, and a fresh-user
    trial read it as a crash. The restart is harmless (the task is done, the next one
    runs in a fresh worker, and the outputs are those of ``--jobs 1``, byte for
    byte); only its message goes. Call before ``joblib.Parallel`` with processes.
    """
    warnings.filterwarnings("ignore", message="A worker stopped while some jobs were given",
                            category=UserWarning)


__all__ = ["for_each_source", "numba_threads_safe", "one_thread_per_worker",
           "quiet_worker_restarts"]

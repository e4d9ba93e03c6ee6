"""Per-source work of the fill on threads.

The fill repeats the same work for every source (sample it through its match,
convert to Lab, compare); OpenCV and NumPy release the GIL in that work, so two
sources run at once on a 2-core machine. Each call writes only its own source's
slots, so the results do not depend on the order (outputs byte-identical to a
sequential loop).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeVar

import cv2
import joblib
import numba

T = TypeVar("T")


def for_each_source(fn: Callable[[int], T], n: int, *,
                    on_done: Callable[[int], None] | None = None) -> list[T]:
    """``[fn(k) for k in range(n)]``, on threads (joblib) when OpenCV may use more
    than one (not inside an ``eval --jobs`` worker). ``fn`` must write only its
    own source's slots; exceptions propagate. ``on_done(k)`` is called on the
    calling thread as each result arrives, in source order (progress)."""
    if n > 1 and cv2.getNumThreads() > 1 and (os.cpu_count() or 1) > 1:
        results = joblib.Parallel(n_jobs=min(n, os.cpu_count() or 1), prefer="threads",
                                  return_as="generator")(joblib.delayed(fn)(k) for k in range(n))
    else:
        results = (fn(k) for k in range(n))
    out = []
    for k, r in enumerate(results):
        out.append(r)
        if on_done is not None:
            on_done(k)
    return out

def one_thread_per_worker() -> None:
    """In a worker process of ``eval --jobs`` or ``batch --jobs`` (the parallelism
    comes from the processes): OpenCV and numba on one thread each, so that two
    workers do not run four threads on two cores (the scan's waves, whose threads
    meet at a barrier a few thousand times a pass, lose the most to that)."""
    cv2.setNumThreads(1)
    numba.set_num_threads(1)


__all__ = ["for_each_source", "one_thread_per_worker"]

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

T = TypeVar("T")


def for_each_source(fn: Callable[[int], T], n: int) -> list[T]:
    """``[fn(k) for k in range(n)]``, on threads (joblib) when OpenCV may use more
    than one (not inside an ``eval --jobs`` worker). ``fn`` must write only its
    own source's slots; exceptions propagate."""
    if n > 1 and cv2.getNumThreads() > 1 and (os.cpu_count() or 1) > 1:
        return joblib.Parallel(n_jobs=min(n, os.cpu_count() or 1), prefer="threads")(
            joblib.delayed(fn)(k) for k in range(n))
    return [fn(k) for k in range(n)]


__all__ = ["for_each_source"]

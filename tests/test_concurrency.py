"""The fill's per-source threads: results in source order, errors raised, one thread
where OpenCV was told to use one (an ``eval --jobs`` worker)."""

import threading

import cv2
import numpy as np
import pytest

from dynremove.refine.colour import delta_e, pairwise_delta_e
from dynremove.refine.concurrency import for_each_source


def test_results_in_source_order_and_delta_e_off_the_main_thread():
    rng = np.random.default_rng(0)
    a = rng.random((5, 64, 64, 3), dtype=np.float32) * 100
    b = rng.random((64, 64, 3), dtype=np.float32) * 100
    out = for_each_source(lambda k: (k, delta_e(a[k], b), pairwise_delta_e(a[:, k])), 5)
    assert [k for k, _, _ in out] == list(range(5))
    np.testing.assert_array_equal(np.stack([d for _, d, _ in out]),
                                  np.linalg.norm(a - b, axis=-1))
    for k, _, pw in out:
        np.testing.assert_array_equal(pw, np.linalg.norm(a[:, k][:, None] - a[:, k][None], axis=-1))


def test_an_error_in_one_source_is_raised():
    def fn(k):
        if k == 2:
            raise ValueError("source 2 failed")
        return k
    with pytest.raises(ValueError, match="source 2 failed"):
        for_each_source(fn, 4)


def test_one_thread_when_opencv_has_one():
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        names = for_each_source(lambda k: threading.current_thread().name, 3)
    finally:
        cv2.setNumThreads(before)
    assert names == [threading.main_thread().name] * 3


def test_after_an_error_the_sources_not_yet_started_do_not_run():
    import time
    ran = []

    def fn(k):
        ran.append(k)
        if k == 0:
            raise ValueError("source 0 failed")
        time.sleep(0.2)
        return k
    with pytest.raises(ValueError, match="source 0 failed"):
        for_each_source(fn, 8)
    assert len(ran) < 8, ran  # 2 workers: source 0 fails at once, the rest are cancelled

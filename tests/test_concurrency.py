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


def test_numba_s_workqueue_layer_runs_the_sources_in_turn_with_the_same_result(tmp_path):
    """numba's "workqueue" threading layer (pip wheels without OpenMP or TBB, e.g. on
    macOS) aborts the process when two threads launch parallel kernels at once: a
    run on DAVIS camel died with SIGABRT in 2 of 3 tries, in ``colour.delta_e`` on
    the fill's threads. With that layer the per-source work runs in turn: the run
    ends normally and writes what the default layer writes, byte for byte."""
    import os
    import subprocess
    import sys

    from dynremove.evaluation import synth

    scene = synth.make_scene(seed=3, n_views=5, size=(120, 160))
    synth.write_scene(scene, tmp_path / "set")
    outs = {}
    for layer in ("default", "workqueue"):
        env = dict(os.environ, NUMBA_THREADING_LAYER=layer)
        out = tmp_path / layer
        r = subprocess.run([sys.executable, "-m", "dynremove", "run",
                            str(tmp_path / "set" / "frames"), "--out", str(out), "--quiet"],
                           env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        outs[layer] = [cv2.imread(str(out / n), cv2.IMREAD_UNCHANGED)
                       for n in ("clean.png", "dynamic_mask.png")]
    probe = ("import numba; from dynremove.refine.concurrency import numba_threads_safe as s;"
             " print(s(), numba.threading_layer())")
    said = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=dict(os.environ, NUMBA_THREADING_LAYER="workqueue"), timeout=300)
    assert said.stdout.split() == ["False", "workqueue"], said.stderr[-2000:]
    for a, b in zip(outs["default"], outs["workqueue"]):
        np.testing.assert_array_equal(a, b)


def test_joblibs_worker_restart_warning_is_silenced_and_nothing_else():
    """A fresh-user trial read loky's "A worker stopped while some jobs were given to
    the executor ... memory leak" (printed by every `batch --jobs 2` run: the pool
    restarts a worker that grew by 300 MB, which one set does) as a crash. The
    restart is harmless; only that message goes, other warnings still show."""
    import warnings

    from dynremove.refine.concurrency import quiet_worker_restarts

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        quiet_worker_restarts()
        warnings.warn("A worker stopped while some jobs were given to the executor. This "
                      "can be caused by a too short worker timeout or by a memory leak.",
                      UserWarning)
        warnings.warn("a note of the run", UserWarning)
    assert [str(w.message) for w in caught] == ["a note of the run"]

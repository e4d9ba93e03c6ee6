"""The compiled scan equals the readable reference: labels, pixels, N, C, events."""

from __future__ import annotations

import numpy as np
import pytest

from dynremove import MemorySink, preset
from dynremove.events import replay_replacements
from dynremove.pipeline import prepare
from dynremove.method.scan.driver import run_scans


def _both(scene, params, **kw):
    st, _ = prepare(scene.images, scene.ref_index, params)
    out = {}
    for kernel in ("numba", "reference"):
        s = st.copy()
        sink = MemorySink()
        L, Ms, summ = run_scans(s, params, sink=sink, kernel=kernel, **kw)
        out[kernel] = (s, L, Ms, summ, sink)
    return st, out


@pytest.mark.parametrize("variant", [
    {},
    {"write": "pixel"},
    {"update": False, "use_hog": False},
    {"dbscan_min_pts": 3, "use_epipolar": False},
])
def test_kernel_equals_reference(small_scene, variant):
    scene = small_scene
    sub = type(scene)(**{**scene.__dict__,
                         "images": [im[8:40, 10:58].copy() for im in scene.images]})
    params = preset("paper").replace(max_scans=2, t_r=0.45, **variant)
    probe = np.zeros(sub.images[0].shape[:2], bool)
    probe[5, 7] = True
    st0, out = _both(sub, params, probe=probe, sample_static=0.05, chunk_rows=7)
    a, b = out["numba"], out["reference"]
    assert a[3][0]["n_dynamic"] > 0, "the scene must exercise the removal path"
    np.testing.assert_array_equal(a[1], b[1])  # L
    np.testing.assert_array_equal(a[0].img, b[0].img)
    np.testing.assert_array_equal(a[0].N, b[0].N)
    np.testing.assert_array_equal(a[0].C, b[0].C)
    np.testing.assert_array_equal(a[0].fg_r, b[0].fg_r)
    for ma, mb in zip(a[2], b[2]):
        np.testing.assert_allclose(ma, mb, rtol=0, atol=1e-6, equal_nan=True)
    for name in ("decisions", "replacements", "updates"):
        ea, eb = getattr(a[4], name), getattr(b[4], name)
        assert ea.dtype == eb.dtype and len(ea) == len(eb)
        for f in ea.dtype.names:
            np.testing.assert_allclose(ea[f].astype(float), eb[f].astype(float), rtol=0,
                                       atol=1e-6, equal_nan=True, err_msg=f"{name}.{f}")
    dec = a[4].decisions
    assert ((dec["why"] & 2) != 0).sum() == len(a[3]), "the probe pixel is recorded in every scan"
    assert ((dec["why"] & 4) != 0).any(), "a sample of static decisions is recorded"
    # the events alone rebuild the output
    srcs = [st0.src_img[s] for s in range(st0.src_img.shape[0])]
    rebuilt = replay_replacements(st0.img, srcs, a[4].replacements,
                                  patch_size=params.patch_size, write=params.write)
    np.testing.assert_array_equal(rebuilt, a[0].img)


def test_steps_are_unique_and_ordered(small_scene):
    params = preset("paper").replace(max_scans=2)
    st, _ = prepare(small_scene.images, small_scene.ref_index, params)
    sink = MemorySink()
    run_scans(st, params, sink=sink, sample_static=0.1)
    steps = sink.decisions["step"]
    assert len(np.unique(steps)) == len(steps)
    assert np.all(np.diff(steps) > 0)

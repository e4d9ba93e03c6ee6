"""The compiled scan equals the readable reference: labels, pixels, N, C, events.

The reference reads its parameters from ``Params`` by name, the kernel from the
arrays of ``driver.pack_params``, so a swapped index there fails here. The
crop carries real fundamental matrices (those of the full scene, moved to the
crop's coordinates) for all sources but one, so the epipolar branches (S_f in
C, H and q*; the Sampson choice of update case 3) and their no-F fallbacks are
compared on every variant. Every float parameter is distinct, so no swap of
two of them can go unnoticed.
"""

from __future__ import annotations

import numpy as np
import pytest

from dynremove import MemorySink, preset
from dynremove.events import replay_replacements
from dynremove.method.scan import _kernels as kn
from dynremove.method.scan import reference
from dynremove.method.scan.driver import pack_params, run_scans
from dynremove.pipeline import prepare

Y0, Y1, X0, X1 = 8, 40, 10, 58  # the crop of the small scene
NO_F = 1  # this source gets no F (a set with too few matches with it)

# the paper preset with every float parameter distinct (a swap shows)
DISTINCT = dict(lambda1=0.16, lambda2=0.41, lambda3=0.43, lambda6=0.11, lambda7=0.37,
                lambda8=0.05, sigma_c=4.7, sigma_g=0.26, sigma_e=0.19, sigma_h=5.3,
                hog_scale=9.0, coord_scale_px=7.0, tie_tol=2e-3, sift_scale=0.21,
                dbscan_eps=0.52, t_r=0.45, max_scans=2)


@pytest.fixture(scope="module")
def crop_with_F(small_scene):
    """ScanInputs of a 32×48 crop with the full scene's F (crop coordinates)."""
    params = preset("paper").replace(**DISTINCT)
    _, views = prepare(small_scene.images, small_scene.ref_index, params)
    images = [im[Y0:Y1, X0:X1].copy() for im in small_scene.images]
    st, _ = prepare(images, small_scene.ref_index, params)
    T = np.array([[1.0, 0, X0], [0, 1, Y0], [0, 0, 1]])  # x_full = T x_crop, in both views
    for k, v in enumerate(views):
        assert v.F is not None, "the full scene has enough matches for every F"
        st.F[k] = T.T @ v.F @ T
        st.hasF[k] = k != NO_F
    st.C = reference.similarity_map(st.N, st.fc_r, st.fg_r, st.fc_s, st.fg_s, st.F, st.hasF,
                                    params, st.sift_unit)
    return st


def test_similarity_map_equals_reference(crop_with_F):
    st = crop_with_F
    for variant in ({}, {"use_epipolar": False}):
        params = preset("paper").replace(**DISTINCT, **variant)
        want = reference.similarity_map(st.N, st.fc_r, st.fg_r, st.fc_s, st.fg_s, st.F,
                                        st.hasF, params, st.sift_unit)
        pf, pi = pack_params(params, sift_unit=st.sift_unit)
        got = kn._similarity_map(st.N, st.fc_r, st.fg_r, st.fc_s, st.fg_s, st.F, st.hasF,
                                 pf, pi)
        np.testing.assert_array_equal(got, want)
    assert (want[NO_F] > 0).any()


def _both(st0, params, **kw):
    out = {}
    for kernel in ("numba", "reference"):
        s = st0.copy()
        sink = MemorySink()
        L, Ms, summ = run_scans(s, params, sink=sink, kernel=kernel, **kw)
        out[kernel] = (s, L, Ms, summ, sink)
    return out


@pytest.mark.parametrize("variant", [
    {},
    {"candidate_set": False},
    {"write": "pixel"},
    {"update": False},
    {"use_epipolar": False},
    {"use_hog": False, "dbscan_min_pts": 3},
    {"write": "pixel", "use_epipolar": False, "use_hog": False, "candidate_set": False},
], ids=lambda v: ",".join(f"{k}={v[k]}" for k in v) or "paper")
def test_kernel_equals_reference(crop_with_F, variant):
    st0 = crop_with_F
    params = preset("paper").replace(**DISTINCT, **variant)
    H, W = st0.shape
    probe = np.zeros((H, W), bool)
    probe[5, 7] = True
    out = _both(st0, params, probe=probe, sample_static=0.05, chunk_rows=7)
    a, b = out["numba"], out["reference"]
    assert a[3][0]["n_dynamic"] > 0, "the scene must exercise the removal path"
    np.testing.assert_array_equal(a[1], b[1])  # L
    np.testing.assert_array_equal(a[0].img, b[0].img)
    np.testing.assert_array_equal(a[0].N, b[0].N)
    np.testing.assert_array_equal(a[0].C, b[0].C)
    np.testing.assert_array_equal(a[0].fg_r, b[0].fg_r)
    for ma, mb in zip(a[2], b[2]):
        np.testing.assert_allclose(ma, mb, rtol=0, atol=1e-6, equal_nan=True)
    # the per-pixel decision maps (|P|, k, |A_m|, sources of A_m; b_m)
    assert len(a[4].cluster_maps) == len(b[4].cluster_maps) == len(a[3])
    for ka, kb in zip(a[4].cluster_maps, b[4].cluster_maps):
        np.testing.assert_array_equal(ka, kb)
        assert (ka[..., 2] <= ka[..., 0]).all() and (ka[..., 3] > 0).any()
    for ba, bb in zip(a[4].b_m_maps, b[4].b_m_maps):
        np.testing.assert_allclose(ba, bb, rtol=0, atol=1e-5)
    # they agree with the recorded decisions at the recorded pixels
    d0 = a[4].decisions
    d0 = d0[d0["scan"] == 0]
    k0 = a[4].cluster_maps[0][d0["y"], d0["x"]]
    np.testing.assert_array_equal(k0[:, 0], d0["n_cand"])
    np.testing.assert_array_equal(k0[:, 1], d0["n_clusters"])
    np.testing.assert_allclose(a[4].b_m_maps[0][d0["y"], d0["x"]], d0["win_weight"], atol=1e-6)
    for name in ("decisions", "replacements", "updates"):
        ea, eb = getattr(a[4], name), getattr(b[4], name)
        assert ea.dtype == eb.dtype and len(ea) == len(eb)
        for f in ea.dtype.names:
            np.testing.assert_allclose(ea[f].astype(float), eb[f].astype(float), rtol=0,
                                       atol=1e-6, equal_nan=True, err_msg=f"{name}.{f}")
    # the branches this test exists for were taken
    rep, upd = a[4].replacements, a[4].updates
    assert (rep["src"] != NO_F).any() and (rep["src"] == NO_F).any(), \
        "patches from sources with and without F"
    assert rep["tie_break"].any(), "some near-ties were broken by the consensus"
    if params.update:
        assert set(np.unique(upd["case"])) >= {1, 2, 3}, "all three update cases"
        assert ((upd["case"] == 3) & (upd["src"] != NO_F)).any(), "case 3 with F (Sampson)"
        assert ((upd["case"] == 3) & (upd["src"] == NO_F)).any(), "case 3 without F"
    dec = a[4].decisions
    assert ((dec["why"] & 2) != 0).sum() == len(a[3]), "the probe pixel is recorded in every scan"
    assert ((dec["why"] & 4) != 0).any(), "a sample of static decisions is recorded"
    # the events alone rebuild the output
    srcs = [st0.src_img[s] for s in range(st0.src_img.shape[0])]
    rebuilt = replay_replacements(st0.img, srcs, a[4].replacements,
                                  patch_size=params.patch_size, write=params.write)
    np.testing.assert_array_equal(rebuilt, a[0].img)


def test_candidate_set_changes_the_scan(crop_with_F):
    """The switch is live: P as a set gives fewer candidates than the multiset."""
    runs = {}
    for as_set in (True, False):
        params = preset("paper").replace(**{**DISTINCT, "max_scans": 1}, candidate_set=as_set)
        sink = MemorySink()
        run_scans(crop_with_F.copy(), params, sink=sink, sample_static=1.0)
        runs[as_set] = sink.decisions
    assert runs[True]["n_cand"].sum() < runs[False]["n_cand"].sum()


def test_steps_are_unique_and_ordered(small_scene):
    params = preset("paper").replace(max_scans=2)
    st, _ = prepare(small_scene.images, small_scene.ref_index, params)
    sink = MemorySink()
    run_scans(st, params, sink=sink, sample_static=0.1)
    steps = sink.decisions["step"]
    assert len(steps) > 0
    assert len(np.unique(steps)) == len(steps)
    assert np.all(np.diff(steps) > 0)


@pytest.mark.parametrize("name,variant", [
    ("default", {}),
    ("paper", {"max_scans": 2}),
    ("paper", {"write": "pixel", "max_scans": 2}),
    ("default", {"update": False, "candidate_set": False}),
])
def test_the_scan_on_all_cores_equals_the_sequential_scan(name, variant):
    """Unrecorded, the scan visits its rows in a pipeline on all cores
    (``_kernels._scan``, each row R px behind the one above); the state it
    leaves is the sequential scan's (the recorded one) byte for byte: L, the
    reference's pixels and features, N, C, the M maps and the counts."""
    import numba

    from dynremove.evaluation import synth
    from dynremove.events import NullSink

    if numba.get_num_threads() < 2:
        pytest.skip("one thread: the scan runs sequentially anyway")
    scene = synth.make_scene(seed=1, n_views=5, size=(120, 200))
    params = preset(name).replace(**variant)
    st0, _ = prepare(scene.images, scene.ref_index, params)
    runs = {}
    for sink in (NullSink(), MemorySink()):  # the pipeline; one pixel at a time
        st = st0.copy()
        L, Ms, summ = run_scans(st, params, sink=sink)
        runs[type(sink).__name__] = (st, L, Ms, summ)
    (a, La, Ma, sa), (b, Lb, Mb, sb) = runs["NullSink"], runs["MemorySink"]
    assert sb[0]["n_dynamic"] > 200, "the scene must exercise the removal path"
    np.testing.assert_array_equal(La, Lb)
    for f in ("img", "lab", "gray", "fc_r", "fg_r", "N", "C"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert len(Ma) == len(Mb)
    for ma, mb in zip(Ma, Mb):
        np.testing.assert_array_equal(ma, mb)
    for x, y in zip(sa, sb):
        for f in ("n_dynamic", "n_replaced", "n_undecided"):
            assert x[f] == y[f], f


def _skewed_scan(reach_less: int):
    """A stand-in for ``_kernels._scan`` that visits a scan's rows pixel by pixel in
    the most skewed order the row pipeline allows: each pixel as early as its wait
    lets it, row i's pixel x before row i − 1's pixel x + R + 1 (sorted by x + (R +
    1)·i, the lower row first on ties), with R = ``_reach`` − ``reach_less``."""
    def scan(*a):
        (img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s, N, C, F, hasF, L,
         Mmap, Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s, use_pre, preM, preB, preK, dirty,
         pf, pi, scan, direction, r0, r1, rec, pipeline, dec_i, dec_f, dec_cs, dec_cxy,
         dec_cB, dec_ccl, rep_i, rep_f, upd_i, upd_f, counts, stats) = a
        W = gray.shape[1]
        g_in, g_out = kn._edge_bounds(pf)
        scratch = kn._scan_scratch(pi, N.shape[0], fg_r.shape[2])
        T = kn._reach(pi) - reach_less + 1
        for _, _, i, xi in sorted((xi + T * i, -i, i, xi) for i in range(r1 - r0)
                                  for xi in range(W)):
            kn._scan_span(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s,
                          N, C, F, hasF, L, Mmap, Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s,
                          use_pre, preM, preB, preK, dirty, pf, pi, g_in, g_out, scan,
                          direction, r0 + i, xi, xi + 1, rec, dec_i, dec_f, dec_cs, dec_cxy,
                          dec_cB, dec_ccl, rep_i, rep_f, upd_i, upd_f, counts, stats[0],
                          scratch, stats[0], 0, -1)
    return scan


@pytest.mark.parametrize("name,variant,too_short", [
    ("default", {}, 2),
    ("paper", {"write": "pixel", "max_scans": 2, "t_r": 0.9}, 1),
])
def test_the_pipeline_s_most_skewed_order_leaves_the_sequential_state(
        monkeypatch, name, variant, too_short):
    """Whatever the threads' timing, the row pipeline visits in an order no more
    skewed than this one; run deterministically, it leaves the sequential scan's
    state byte for byte. With a reach ``too_short`` px shorter than ``_reach`` the
    same order changes the state: the test tells a reach that is too short (a
    threaded test with a reach 1 px short passed, timing-dependent)."""
    from dynremove.evaluation import synth
    from dynremove.events import NullSink

    scene = synth.make_scene(seed=1, n_views=5, size=(96, 128))
    params = preset(name).replace(**variant)
    st0, _ = prepare(scene.images, scene.ref_index, params)

    def run(scan=None):
        st = st0.copy()
        if scan is not None:
            monkeypatch.setattr(kn, "_scan", scan)
        L, Ms, _ = run_scans(st, params, sink=NullSink(), chunk_rows=st0.shape[0])
        monkeypatch.undo()
        return [L, st.img, st.N, st.C, st.fg_r, *Ms]

    seq = run()
    assert seq[0].sum() > 1000, "the scene must exercise the removal path"
    for a, b in zip(seq, run(_skewed_scan(0))):
        np.testing.assert_array_equal(a, b)
    short = run(_skewed_scan(too_short))
    assert any(not np.array_equal(a, b) for a, b in zip(seq, short))


def test_perf_map_names_the_compiled_functions(tmp_path):
    """examples/perf_kernels.py maps numba's compiled code for ``perf``: each
    function of a module, at the address numba runs it from."""
    import importlib.util
    import pathlib
    import types

    import numba

    spec = importlib.util.spec_from_file_location(
        "perf_kernels", pathlib.Path(__file__).parents[1] / "examples" / "perf_kernels.py")
    perf_kernels = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(perf_kernels)
    mod = types.ModuleType("perf_map_probe")

    def triple_sum(a):
        return 3 * a.sum()

    mod.triple_sum = numba.njit(triple_sum)  # compiled here, not loaded from a cache
    assert mod.triple_sum(np.arange(4)) == 18
    path = tmp_path / "perf.map"
    n = perf_kernels.write_perf_map([mod], str(path))
    rows = [line.split(" ", 2) for line in path.read_text().splitlines()]
    assert n == len(rows) >= 1
    starts = [int(a, 16) for a, _, _ in rows]
    assert starts == sorted(starts) and all(int(s, 16) > 0 for _, s, _ in rows)
    named = [r for r in rows if "triple_sum" in r[2]]
    assert named, [r[2] for r in rows]
    lib = next(iter(mod.triple_sum.overloads.values())).library
    fn = next(f.name for f in lib._final_module.functions
              if not f.is_declaration and "triple_sum" in f.name and "cpython" not in f.name)
    assert int(next(a for a, _, name in rows if name == fn), 16) == \
        lib._codegen._engine.get_function_address(fn)


def _atan2_bins(gray: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """The HoG bin and magnitude of every pixel as the reference computes them
    (central differences clamped at the border; atan2 + π cut into nb bins)."""
    g = gray.astype(np.float64)
    H, W = g.shape
    gx = (g[:, np.minimum(np.arange(W) + 1, W - 1)] - g[:, np.maximum(np.arange(W) - 1, 0)]) * 0.5
    gy = (g[np.minimum(np.arange(H) + 1, H - 1)] - g[np.maximum(np.arange(H) - 1, 0)]) * 0.5
    m = np.sqrt(gx * gx + gy * gy)
    b = np.minimum(((np.arctan2(gy, gx) + np.pi) * nb / (2.0 * np.pi)).astype(np.int64), nb - 1)
    return np.where(m > 0, b, -1), m


@pytest.mark.parametrize("nb", [8, 6])
def test_gradient_bins_equal_the_atan2_bins(nb):
    """The compiled bins (for nb = 8 read from the octant, without atan2) are the
    reference's atan2 bins, on noise and on gradients on and next to the octants'
    edges (g_x = ±g_y to the last float32 step, g_x = 0, g_y = 0)."""
    rng = np.random.default_rng(11)
    noise = (rng.random((64, 80)) * 255).astype(np.float32)
    # ramps whose two gradient components are equal, or one float32 step apart
    y, x = np.mgrid[0:64, 0:80].astype(np.float32)
    diag = (x + y) * np.float32(1.7)
    near = diag.copy()
    near[::3] = np.nextafter(near[::3], np.float32(np.inf))
    near[1::3] = np.nextafter(near[1::3], np.float32(-np.inf))
    anti = (x - y) * np.float32(0.37) + 100
    flat_rows = np.repeat(rng.random((64, 1)).astype(np.float32) * 255, 80, axis=1)
    steps = np.where(rng.random((64, 80)) < 0.5, np.float32(10), np.float32(10.5))
    for gray in (noise, diag, near, anti, flat_rows, steps, np.float32(1e-3) * noise):
        want_b, want_m = _atan2_bins(gray, nb)
        got_b, got_m = kn._gradient_bins(np.ascontiguousarray(gray), nb)
        np.testing.assert_array_equal(got_b, want_b)
        np.testing.assert_array_equal(got_m, want_m)
    assert (want_b >= 0).any()

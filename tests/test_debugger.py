"""The debugger's promises (issue 13), checked by reading recordings back.

* ``inspect --pixel`` answers "why?" for any pixel, probed or not, in at most five
  lines of words, with values equal to what the core emitted (MemorySink);
* a decision instance keeps meaning the same pixel at every step, or is cleared;
* the errors overlay never marks a pixel the current scan has not visited yet;
* classes, reasons and sources have names, values are rounded.
"""

from __future__ import annotations

import dataclasses
import os
import re
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader  # noqa: E402
from test_viewer_e2e import Tee  # noqa: E402
from test_viewer_fixtures import fabricate_run, gt_for  # noqa: E402
from lingering import paste_at_same_spot  # noqa: E402

from dynremove import MemorySink, preset, remove_dynamic  # noqa: E402
from dynremove.cli import main  # noqa: E402
from dynremove.errors import InputError  # noqa: E402
from dynremove.evaluation import synth  # noqa: E402
from dynremove.evaluation.metrics import jaccard  # noqa: E402
from viewer import RerunSink  # noqa: E402
from viewer import inspect as vi  # noqa: E402
from viewer import verdict as vd  # noqa: E402
from viewer import paths as P  # noqa: E402
from viewer._images import REASON_NAMES, visit_step  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("DYNREMOVE_DATA", REPO.parent / "shared" / "data"))
H, W, S = 48, 64, 3


def _table(path, contents, index="step"):
    return RrdReader(str(path)).stream().collect().reader(
        index=index, contents=contents).to_arrow_table()


# -- runs ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fabricated(tmp_path_factory):
    """3 scans (top-down, bottom-up, top-down) with ground truth, every 5 rows."""
    path = tmp_path_factory.mktemp("fab") / "run.rrd"
    gt, bg = gt_for(H, W, S)
    sink = RerunSink(path, record_every_rows=5, gt_mask=gt, gt_background=bg)
    info, result, truth = fabricate_run([sink], H=H, W=W, S=S, n_scans=3)
    return dict(path=path, truth=truth, gt=gt, info=info)


def _camel(scale: int = 4):
    """The camel set of ../shared/data at 1/scale, or None."""
    root = DATA / "davis" / "camel"
    frames = sorted((root / "frames").glob("*.jpg"))
    if len(frames) < 3:
        return None
    imgs = [cv2.imread(str(f)) for f in frames]
    h, w = imgs[0].shape[:2]
    size = (w // scale, h // scale)
    imgs = [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in imgs]
    ref = len(imgs) // 2
    mask = cv2.imread(str(root / "masks" / (frames[ref].stem + ".png")), cv2.IMREAD_GRAYSCALE)
    gt = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST) > 127
    return imgs, ref, gt


@pytest.fixture(scope="module", params=["real", "synthetic"])
def method_run(request, tmp_path_factory):
    """A run of the method (default preset) recorded with ground truth, plus the
    MemorySink that saw the same events. ``real``: camel from DYNREMOVE_DATA."""
    if request.param == "real":
        got = _camel()
        if got is None:
            pytest.skip(f"no real set: {DATA}/davis/camel is absent (set DYNREMOVE_DATA)")
        imgs, ref, gt = got
    else:
        scene = synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)
        imgs, ref, gt = scene.images, scene.ref_index, scene.masks[scene.ref_index]
    params = preset("default")
    path = tmp_path_factory.mktemp(request.param) / "run.rrd"
    mem = MemorySink()
    rsink = RerunSink(path, gt_mask=gt)
    res = remove_dynamic(imgs, ref=ref, params=params, sink=Tee(mem, rsink))
    return dict(path=path, mem=mem, res=res, gt=np.asarray(gt, bool), params=params,
                kind=request.param)


def test_m_splits_into_its_colour_and_sift_terms(method_run):
    """A fresh-user trial: the history gave only the SIFT distance, where a teacher
    needed to say the colour term was about 0. M = λ4 S_e(colour) + λ5 S_e(SIFT):
    from the recorded squared SIFT distance the SIFT term is exact, and the rest,
    the colour term, lies in [0, λ4] for every decision of the run."""
    p = method_run["params"]
    lam4, lam5 = p.lambda4, p.lambda5
    d = method_run["mem"].decisions
    d = d[np.isfinite(d["M"]) & np.isfinite(d["consensus_dist"])]
    assert len(d) > 10
    sift = lam5 * np.exp(-d["consensus_dist"].astype(np.float64) / (2 * p.sigma_g ** 2))
    colour = d["M"].astype(np.float64) - sift
    assert colour.min() >= -1e-5 and colour.max() <= lam4 + 1e-5
    # ... and the history says so, term by term
    i = int(np.argmax(d["dynamic"]))
    h = vi.pixel_history(method_run["path"], int(d[i]["x"]), int(d[i]["y"]))
    terms = [e["m_terms"] for e in h["decisions"] if e["step"] == int(d[i]["step"])][0]
    assert terms[0] == pytest.approx(max(colour[i], 0.0), abs=1e-5)
    assert terms[1] == pytest.approx(sift[i], abs=1e-5)
    assert terms[2:] == pytest.approx((lam4, lam5))
    assert "colour term" in vd.format_pixel_history(h, max_lines=200)


def _naive_overwritten(mem, scan, x, y, half, H, W):
    """Patches centred elsewhere covering (x, y) written before the scan reached it."""
    own = visit_step(scan, x, y, H, W, direction=mem.scans_started[scan][1])
    r = mem.replacements
    r = r[r["scan"] == scan]
    near = (np.abs(r["x"] - x) <= half) & (np.abs(r["y"] - y) <= half)
    near &= ~((r["x"] == x) & (r["y"] == y))
    return int((near & (r["step"] < own)).sum())


# -- 1. every pixel explainable --------------------------------------------------------
@pytest.mark.parametrize("kind", ["FN", "FP"])
def test_verdict_of_a_failure_pixel_matches_the_core(method_run, kind):
    res, gt, mem = method_run["res"], method_run["gt"], method_run["mem"]
    L = np.asarray(res.dynamic, bool)
    mask = (gt & ~L) if kind == "FN" else (~gt & L)
    if not mask.any():
        pytest.skip(f"this run has no {kind} pixel")
    # a pixel where no decision event was recorded, when there is one: the answer
    # then comes from the per-scan maps alone, without a re-run with --probe
    d = mem.decisions
    recorded = np.zeros_like(mask)
    recorded[d["y"], d["x"]] = True
    pick = mask & ~recorded if (mask & ~recorded).any() else mask
    y, x = map(int, np.argwhere(pick)[len(np.argwhere(pick)) // 2])
    h = vi.pixel_history(method_run["path"], x, y)
    assert not h["decisions"] or not (mask & ~recorded).any()
    Hh, Ww = L.shape
    assert len(h["scans"]) == len(mem.M_maps) == len(mem.cluster_maps) == len(mem.b_m_maps)
    names = h["source_names"]
    for sc, K, B in zip(h["scans"], mem.cluster_maps, mem.b_m_maps):  # exactly the core's
        n, k, size, bits = (int(v) for v in K[y, x])
        assert (sc["n_candidates"], sc["n_clusters"], sc["win_size"]) == (n, k, size)
        assert sc["win_sources"] == [names[s] for s in range(len(names)) if bits >> s & 1]
        assert bits < 1 << len(names)
        assert sc["b_m"] == float(B[y, x])
    maps = vi.read_scan_maps(method_run["path"])
    for m, K, B in zip(maps, mem.cluster_maps, mem.b_m_maps):  # every pixel, losslessly
        for c, name in enumerate(("n_candidates", "n_clusters", "win_size", "win_sources")):
            np.testing.assert_array_equal(m[name], K[..., c])
        np.testing.assert_array_equal(m["b_m"], B)
    # the undecided pixels, drawn over the lossless M (whose 65535 the colour map put
    # at the top, as M = 1): exactly those without M
    und = vi._image_rows(vi.load_store(method_run["path"]), "/scan_maps/undecided",
                         "SegmentationImage")
    assert len(und) == len(maps)
    for (_, u), m in zip(und, maps):
        np.testing.assert_array_equal(u.astype(bool), np.isnan(m["M"]))
    half = method_run["params"].patch_size // 2 if method_run["params"].write == "patch" else 0
    for sc, M in zip(h["scans"], mem.M_maps):
        want = float(M[y, x])
        if np.isnan(want):
            assert np.isnan(sc["M"]) and sc["verdict"] == "undecided"
        else:
            assert sc["M"] == pytest.approx(want, abs=1e-4)
            t_r = method_run["params"].t_r
            assert sc["verdict"] == ("dynamic" if want <= t_r else "static")
        assert sc["overwritten_before"] == _naive_overwritten(mem, sc["scan"], x, y, half,
                                                              Hh, Ww)
    assert h["final_dynamic"] is bool(L[y, x]) and h["gt"] is bool(gt[y, x])
    # the sentence for non-experts: no symbols, and the outcome the mask has
    plain = vd.plain_words(h)
    assert plain and not re.search(r"\bM\b|t_r|A_m|b_m|B_l|Sec\.", plain), plain
    sel = h.get("selection") or {}
    k = sel.get("source", 0)
    if L[y, x]:
        assert re.search("moved|moving", plain) and "stays as the" not in plain, plain
    elif k > 0 and not sel.get("inpainted"):  # the fill's margin: written, not counted
        assert f"blends in {names[k - 1]}'s view of the spot" in plain, plain
    else:
        assert "stays as the photo shows it" in plain, plain
    if L[y, x] and k > 0 and not sel.get("inpainted"):
        assert f"{names[k - 1]}'s view of the spot" in plain, plain
    if any(sc["verdict"] == "dynamic" for sc in h["scans"]) and not sel.get("lingering"):
        assert "something that moved" in plain, plain
    win = next((sc["win_sources"] for sc in h["scans"] if sc.get("win_sources")), None)
    if not L[y, x] and not any(sc["verdict"] == "dynamic" for sc in h["scans"]) and win \
            and k == 0 and not sel.get("explained"):
        # how many photos the trusted matches come from, not "the other photos"
        assert f"{len(win)} of the {len(names)} other photos ({', '.join(win)})" in plain
    verdict = vd.verdict_lines(h)
    assert 1 <= len(verdict) <= 5
    words = " ".join(verdict)
    assert "t_r" in words and ("FALSE NEGATIVE" if kind == "FN" else "FALSE POSITIVE") in words
    m0 = h["scans"][0]["M"]
    if m0 == m0:
        assert f"{m0:.2f}" in words
    if h["scans"][0]["overwritten_before"]:
        assert f"overwritten by {h['scans'][0]['overwritten_before']} neighbouring" in words
    key = next((sc for sc in h["scans"] if sc["verdict"] == "dynamic"), h["scans"][0])
    if key["win_size"]:  # the winning cluster's size, sources and b_m, in words
        assert (f"{key['win_size']} of {key['n_candidates']} candidates from "
                f"{len(key['win_sources'])} of {len(names)} sources") in words
        assert all(name in words for name in key["win_sources"])
        assert f"b_m = Σ B_l = {key['b_m']:.2f}" in words
    else:
        assert "no cluster" in words or "no candidate" in words
    assert "re-run with --probe" not in words
    text = vd.format_pixel_history(h)
    assert len(text.splitlines()) <= 30
    assert text.splitlines()[0].startswith(f"pixel ({x}, {y}): ")
    if kind == "FP":  # dynamic decisions are always recorded: the cluster is told
        assert "winning cluster" in words or "fill" in words


def test_neighbours_writes_do_not_enter_M(small_scene):
    """What the legend's "Overwritten" says (``verdict.LEGEND``): a neighbouring
    patch's write changes the working copy's pixels, not the f_c and f_g that M
    compares (Sec. 3.2.2 updates them at the replaced pixel only). At every static
    pixel that neighbouring patches overwrote before its turn, M recomputed from the
    photo's own features and the recorded winning cluster is the recorded M. (The
    README of session 45 had said the scans judged the sanitizer's cap on the wall
    the patches wrote there; ``inspect`` said so too.)"""
    from dynremove.method.scan.driver import run_scans
    from dynremove.method.scan.reference import S_e
    from dynremove.pipeline import prepare

    params = preset("default").replace(max_scans=1)
    st0, _ = prepare(small_scene.images, small_scene.ref_index, params)
    st = st0.copy()
    mem = MemorySink()
    run_scans(st, params, sink=mem, sample_static=1.0)  # every decision recorded
    d, r = mem.decisions, mem.replacements
    half = params.patch_size // 2
    u = st0.sift_unit
    checked = changed = 0
    for e in d[~d["dynamic"] & (d["win_cluster"] >= 0)]:
        x, y = int(e["x"]), int(e["y"])
        near = ((np.abs(r["x"] - x) <= half) & (np.abs(r["y"] - y) <= half)
                & ((r["x"] != x) | (r["y"] != y)) & (r["step"] < e["step"]))
        if not near.any():
            continue
        win = [(int(s), int(cx), int(cy), float(b)) for s, (cx, cy), b, c in
               zip(e["cand_src"], e["cand_xy"], e["cand_B"], e["cand_cluster"])
               if s >= 0 and c == e["win_cluster"]]
        w = np.array([b for *_, b in win])
        w = w / w.sum() if w.sum() > 0 else np.full(len(win), 1.0 / len(win))
        fc = sum(wi * st0.fc_s[s, cy, cx].astype(np.float64) for wi, (s, cx, cy, _) in zip(w, win))
        fg = sum(wi * st0.fg_s[s, cy, cx].astype(np.float64) * u
                 for wi, (s, cx, cy, _) in zip(w, win))
        dc = float(((st0.fc_r[y, x].astype(np.float64) - fc) ** 2).sum())
        dg = float(((st0.fg_r[y, x].astype(np.float64) * u - fg) ** 2).sum())
        M = params.lambda4 * S_e(dc, params.sigma_c) + params.lambda5 * S_e(dg, params.sigma_g)
        assert M == pytest.approx(float(e["M"]), abs=1e-5), (x, y)
        np.testing.assert_array_equal(st.fc_r[y, x], st0.fc_r[y, x])
        checked += 1
        changed += bool((st.img[y, x] != st0.img[y, x]).any())
    assert checked >= 20 and changed >= 10, (checked, changed)
    assert "do not enter its M" in vd.LEGEND


def test_the_fill_is_told(method_run):
    sel = vi.read_selection(method_run["path"])
    if "source" not in sel:
        pytest.skip("no fill by selection in this run")
    ys, xs = np.nonzero(sel["source"] > 0)
    if len(xs):
        h = vi.pixel_history(method_run["path"], int(xs[0]), int(ys[0]))
        k = int(sel["source"][ys[0], xs[0]])
        assert f"filled from source {h['source_names'][k - 1]}" in " ".join(vd.verdict_lines(h))


def test_the_blends_offset_is_recorded_and_told(method_run):
    """What the blend added to the chosen source (``Selection.offset``): recorded to
    the level, and said by inspect at the filled pixel where it is largest."""
    run_sel = method_run["res"].selection
    if run_sel is None:
        pytest.skip("no fill by selection in this run")
    rec = vi.read_selection(method_run["path"])
    from dynremove.refine.select import MISFIT_KEPT

    filled = np.isfinite(run_sel.offset).all(-1)
    # (a region that keeps the reference because its fill did not fit the photo around
    # it keeps the offset the blend would have added: the debugger shows why)
    misfit = run_sel.completed == MISFIT_KEPT
    assert filled.any() and not np.isfinite(run_sel.offset[(run_sel.label <= 0) & ~misfit]).any()
    want = np.clip(np.round(np.nan_to_num(run_sel.offset)), -128, 127).astype(np.int16)
    np.testing.assert_array_equal(rec["offset"], want)
    mag = np.where(filled, np.abs(want).max(-1), -1)
    y, x = np.unravel_index(int(np.argmax(mag)), mag.shape)
    h = vi.pixel_history(method_run["path"], int(x), int(y))
    assert h["selection"]["offset"] == [int(c) for c in want[y, x]]
    if method_run["res"].dynamic[y, x] and run_sel.label[y, x] > 0:  # what the headline reads
        assert h["clean_input"][0] == [int(c) for c in method_run["res"].clean[y, x]]
    words = " ".join(vd.verdict_lines(h))
    told = "the blend added B/G/R " + "/".join(f"{int(c):+d}" for c in want[y, x])
    assert (told in words) == (mag[y, x] >= 1)
    # a large correction is not called light (a trial read -115 levels as light)
    assert ("a large correction" in words) == (mag[y, x] >= 40)
    light = f"({vd._LIGHT_OR_REST})"
    assert (light in words) == (1 <= mag[y, x] < 40)


def test_the_seam_blend_is_recorded_and_told(method_run):
    """The part of the blend's offset that removed a step of light at a seam between
    two sources (``Selection.seam_offset``): recorded to the level, and said by inspect
    at the pixel where it is largest."""
    run_sel = method_run["res"].selection
    if run_sel is None or run_sel.seam_offset is None:
        pytest.skip("no seam blended in this run")
    rec = vi.read_selection(method_run["path"])
    want = np.clip(np.round(run_sel.seam_offset), -128, 127).astype(np.int16)
    np.testing.assert_array_equal(rec["seam_blend"], want)
    off = np.clip(np.round(np.nan_to_num(run_sel.offset)), -128, 127).astype(np.int16)
    mag = np.where(np.abs(off).max(-1) >= 1, np.abs(want).max(-1), -1)
    y, x = np.unravel_index(int(np.argmax(mag)), mag.shape)
    assert mag[y, x] >= 1
    words = " ".join(vd.verdict_lines(vi.pixel_history(method_run["path"], int(x), int(y))))
    told = ", of which " + "/".join(f"{int(c):+d}" for c in want[y, x]) + " blend the seam"
    assert told in words and "--select-seam-levels" in words


def test_a_lingering_mover_is_logged_and_told(tmp_path):
    """A mover that stands still in 3 of the 5 sources: the recording holds the
    lingering map, and inspect says which source filled a pixel of it and why the
    sources still showing the mover were rejected."""
    sc = synth.make_scene(seed=3, n_views=6, size=(240, 432), n_objects=1)
    ref = sc.ref_index
    ims = paste_at_same_spot(sc, ref, [k for k in range(6) if k not in (ref, 0, 1)])
    path = tmp_path / "linger.rrd"
    with pytest.warns(UserWarning, match="a mover that lingered"):
        remove_dynamic(ims, ref=ref, sink=RerunSink(path, gt_mask=sc.masks[ref]))
    sel = vi.read_selection(path)
    assert sel["lingering"].astype(bool).sum() >= 0.4 * sc.masks[ref].sum()  # (as in test_select)
    ys, xs = np.nonzero(sel["lingering"].astype(bool) & (sel["source"] > 0))
    i = len(ys) // 2
    h = vi.pixel_history(path, int(xs[i]), int(ys[i]))
    words = " ".join(vd.verdict_lines(h))
    assert "a mover that lingered" in words
    assert "still shows what the reference shows here: the mover that lingered" in words
    # a source of a dynamic scan's winning cluster that the fill turned down as showing
    # the mover: the two places in it are told apart (a trial read a contradiction);
    # not where the scans called the pixel static (there the lingering sources agreed)
    for j in np.linspace(0, len(ys) - 1, 5).astype(int):
        h = vi.pixel_history(path, int(xs[j]), int(ys[j]))
        words = " ".join(vd.verdict_lines(h))
        dyn = {n for sc in h["scans"] if sc["verdict"] == "dynamic"
               for n in (sc["win_sources"] or ())}
        turned = {n for n, r in h["selection"].get("reasons", {}).items()
                  if r.startswith("still shows")}
        assert ("in the scan's winning cluster above: its candidate there" in words) == bool(
            dyn & turned), (dyn, turned, words)
    # the same pixel as a scan that called it dynamic with that source in A_m would tell
    name = sorted(turned)[0]
    h["scans"] = [dict(h["scans"][0], verdict="dynamic",
                       win_sources=[name, *(h["scans"][0]["win_sources"] or [])])]
    words = " ".join(vd.verdict_lines(h))
    clause = words.split("; ")[-1]
    assert name in clause and "in the scan's winning cluster above: its candidate there" \
        in clause, words


def test_the_region_rule_is_logged_and_told(tmp_path):
    """Where ``--select-complete`` overruled the graph cut, the recording holds it
    (1: replaced with its region of L, 2: kept with it), and inspect says why. (Four
    views of seed 0: with six of seed 3, session 52's colour rules left no region of
    static structure for the rule to keep, so its code 2 was gone.)"""
    sc = synth.make_scene(seed=0, n_views=4, size=(360, 640), n_objects=1)
    path = tmp_path / "complete.rrd"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = remove_dynamic(sc.images, ref=sc.ref_index, sink=RerunSink(path))
    # a value logged in another type than the run's params (a trial saw Rerun's
    # "Type for 'select_complete_px' changed" printed as a note of the run)
    assert not [w for w in caught if "changed from" in str(w.message)], \
        [str(w.message) for w in caught]
    sel = vi.read_selection(path)
    np.testing.assert_array_equal(sel["completed"], r.selection.completed)
    for code, filled, words in ((1, True, "a piece of the same mover"),
                                (2, False, "kept the reference on the rest of its region")):
        at = sel["completed"] == code
        assert at.any() and ((sel["source"][at] > 0) == filled).all()
        # (a pixel of L's core: in the fill's margin a kept pixel only continued it)
        ys, xs = np.nonzero(at & ~np.isnan(r.selection.region_share))
        h = vi.pixel_history(path, int(xs[0]), int(ys[0]))
        told = " ".join(vd.verdict_lines(h))
        assert words in told and "--select-complete" in told
        # the share that decided it, as the core measured it, against the run's 0.7
        f = float(r.selection.region_share[ys[0], xs[0]])
        assert (f >= 0.7) if code == 1 else (f < 0.3)
        assert f"replaced {100 * f:.0f} % of its region of L" in told, told
    # the share map: the core's, quantised; NaN (none) outside the regions of L
    q = sel["region_share"]
    none = q == P.DE_NONE
    np.testing.assert_array_equal(none, np.isnan(r.selection.region_share))
    np.testing.assert_allclose(q[~none] / P.P_SCALE, r.selection.region_share[~none],
                               atol=0.5 / P.P_SCALE)
    assert sel["region_rule"]["select_complete"] == [0.7]
    # what the cut weighed: the core's maps, quantised (none outside the fill's region)
    for key, names in (("data_cost", ("reference", "best_source")),
                       ("support", ("reference", "sources"))):
        for name, core in zip(names, getattr(r.selection, key)):
            q = sel[key][name]
            none = q == P.DE_NONE
            np.testing.assert_array_equal(none, np.isnan(core), err_msg=f"{key}/{name}")
            np.testing.assert_allclose(q[~none] / P.DE_SCALE, core[~none],
                                       atol=0.5 / P.DE_SCALE, err_msg=f"{key}/{name}")
    assert (~np.isnan(r.selection.data_cost[0])).sum() > 1000


def test_pixel_outside_the_image(fabricated, capsys):
    with pytest.raises(InputError, match="outside"):
        vi.pixel_history(fabricated["path"], 9999, 9999)
    assert main(["inspect", str(fabricated["path"]), "--pixel", "9999,9999"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the 64x48 image" in err[0]


# -- 2. stable identity ----------------------------------------------------------------
def test_decision_instances_never_retarget(fabricated):
    t = _table(fabricated["path"], "/reference/decisions/**")
    steps = t.column("step").to_pylist()
    ents = sorted({n.split(":")[0] for n in t.column_names if n.startswith("/reference/")})
    assert len(ents) > 3
    truth = fabricated["truth"].decisions
    for e in ents:
        xs, ys, st = (t.column(f"{e}:{k}").to_pylist() for k in ("x", "y", "step"))
        first = None
        for s, x, y, dstep in zip(steps, xs, ys, st):
            if x is None:
                continue  # nothing logged at this step: latest-at keeps the same batch
            triple = list(zip(x, y, dstep))
            if first is None:
                if triple:  # (a scan-start clear may come before the batch)
                    first = triple
                continue
            assert triple in (first, []), f"{e} re-targeted at step {s}"
        # every instance is the core's decision at that (x, y, step)
        for x, y, dstep in first:
            row = truth[truth["step"] == dstep]
            assert len(row) == 1 and (int(row["x"][0]), int(row["y"][0])) == (x, y)
    # the previous scan's decisions are cleared when the next scan starts
    scan0 = [e for e in ents if "/scan0/" in e]
    cleared = [s for s, v in zip(steps, t.column(f"{scan0[0]}:x").to_pylist()) if v == []]
    assert H * W in cleared


# -- 3. overlays true at every step ----------------------------------------------------
@pytest.mark.parametrize("scan", [0, 1], ids=["top-down", "bottom-up"])
def test_errors_only_where_the_scan_has_been(fabricated, scan):
    rows = vi._image_rows(vi.load_store(fabricated["path"]), "/errors/labels",
                          "SegmentationImage")
    lo, hi = scan * H * W, (scan + 1) * H * W
    mid = [(s, a) for s, a in rows if lo <= s < hi - 1]
    assert len(mid) >= 3
    yy, xx = np.mgrid[0:H, 0:W]
    idx = (yy * W + xx) if scan % 2 == 0 else ((H - 1 - yy) * W + (W - 1 - xx))
    marked_any = False
    for s, a in mid:
        unvisited = (lo + idx) > s
        assert not a[unvisited].any(), f"scan {scan} step {s}: errors on unvisited pixels"
        marked_any |= bool(a.any())
    assert marked_any  # the overlay does show errors where the scan has been


def test_current_marker_for_every_recorded_decision(fabricated):
    t = _table(fabricated["path"], "/reference/current")
    pos = dict(zip(t.column("step").to_pylist(),
                   t.column("/reference/current:Points2D:positions").to_pylist()))
    d = fabricated["truth"].decisions
    static = d[~d["dynamic"]]
    assert len(static)
    for dstep in static["step"][:50].tolist():
        assert pos.get(dstep), f"no current marker for the static decision at step {dstep}"


def test_stages_follow_the_last_scan_step(method_run):
    res, path = method_run["res"], method_run["path"]
    t = _table(path, "/reference/dynamic", index="stage")
    stages = [s for s in t.column("stage").to_pylist() if s is not None]
    assert stages == list(range(len(res.stages) + 1))  # each stage, then the output
    t = _table(path, "/log")
    text = " ".join(v[0] for v in t.column("/log:TextLog:text").to_pylist() if v)
    last = len(res.scans) * res.dynamic.size - 1
    for i, name in enumerate(res.stages):
        assert f"stage {i} '{name}' at step {last + 1 + i}" in text
    # the final J is labelled with the size it is measured at (a trial read 0.829 in the
    # recording against the 0.823 of report.json, at the photo's size)
    Hh, Ww = res.dynamic.shape
    assert (f"Jaccard {jaccard(res.dynamic, method_run['gt']):.3f} at the {Ww}x{Hh} "
            "analysed size") in text
    # the plots follow the stages too: |L| and J of each stage's map at its step (a
    # trial saw J jump at the end, and no plot said which stage bought it)
    gt = method_run["gt"]
    for stat, value in (("dynamic_px", lambda m: float(m.sum())),
                        ("jaccard", lambda m: jaccard(m, gt))):
        t = _table(path, f"/stats/{stat}")
        got = dict(zip(t.column("step").to_pylist(),
                       (v[0] for v in t.column(f"/stats/{stat}:Scalars:scalars").to_pylist())))
        for i, (name, m) in enumerate(res.stages.items()):
            assert got[last + 1 + i] == pytest.approx(value(np.asarray(m, bool))), (stat, name)


# -- 4. words and legends --------------------------------------------------------------
def test_the_fills_maps_name_their_classes_and_let_the_photo_show(method_run):
    """Seen in a headless viewer (session 65): over the clean photo, the region rule's
    map tinted the whole photo (its class 0 had no entry), and the static-structure
    map showed nothing to tell it by (its 1 fell to the root's classes). Each map of
    the fill has its own classes: 0 see-through, the others named and visible."""
    res = method_run["res"]
    if res.selection is None:
        pytest.skip("no fill by selection in this run")
    names = [res.geometry[k]["source"] for k in range(len(res.geometry))]
    ents = [P.RESULT_EXPLAINED, P.RESULT_INPAINTED, P.RESULT_COMPLETED, P.scan_map("undecided"),
            *[f"{P.RESULT_MOVERS}/{n}" for n in P.entity_names(names)]]
    for ent in ents:
        t = _table(method_run["path"], "/" + ent, index=None)
        ctx = t.column(f"/{ent}:AnnotationContext:context")[0].as_py()[0]
        classes = {c["class_id"]: c["class_description"]["info"] for c in ctx}
        assert classes[0]["color"] & 0xFF == 0, ent  # alpha 0: see-through
        assert classes[1]["label"] and classes[1]["color"] & 0xFF > 0, ent


def test_annotation_context_names_and_text_attributes(fabricated):
    t = _table(fabricated["path"], "/**", index=None)
    ctx = t.column("/:AnnotationContext:context")[0].as_py()[0]
    labels = {c["class_description"]["info"]["label"] for c in ctx}
    assert {"dynamic", "false positive", "false negative", "true positive"} <= labels
    keypoints = {k["label"] for c in ctx for k in c["class_description"]["keypoint_annotations"]}
    assert set(REASON_NAMES.values()) <= keypoints
    t = _table(fabricated["path"], "/reference/decisions/**")
    names = set(fabricated["info"].names) | set(P.entity_names(
        [fabricated["info"].names[i] for i in fabricated["info"].source_indices])) | {"-"}
    e = next(n.split(":")[0] for n in t.column_names if n.endswith(":verdict"))
    verdicts = next(v for v in t.column(f"{e}:verdict").to_pylist() if v)
    assert all(isinstance(v, str) and ("dynamic" in v or "static" in v) for v in verdicts)
    chosen = next(v for v in t.column(f"{e}:chosen_source").to_pylist() if v)
    assert all(c in names for c in chosen)
    reasons = next(v for v in t.column(f"{e}:reason").to_pylist() if v)
    assert all(isinstance(r, str) and r for r in reasons)
    m = next(v for v in t.column(f"{e}:M").to_pylist() if v)
    assert all(v != v or round(v, 3) == v for v in m)  # rounded, no float32 noise
    t_r = next(v for v in t.column(f"{e}:t_r").to_pylist() if v)
    assert t_r[0] == 0.3


# -- 5. command-line edges ---------------------------------------------------------------
def test_view_without_display_says_so(fabricated, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", str(fabricated["path"])]) == 2
    err = capsys.readouterr().err
    assert "--web" in err and len(err.strip().splitlines()) == 1


def test_view_of_a_cut_recording_says_so(fabricated, monkeypatch, capsys, tmp_path):
    """``view`` said nothing of a recording cut short (``inspect`` and ``export`` do):
    the same note, from the file's framing, before the viewer opens."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    data = Path(fabricated["path"]).read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[:len(data) * 2 // 3])
    assert main(["view", str(cut)]) == 2  # (no display here)
    err = capsys.readouterr().err
    assert f"note: {cut}: damaged or cut short after " in err and f" of {len(data) * 2 // 3} " \
        "bytes" in err, err


def test_view_web_on_a_busy_port_names_it(fabricated, capsys):
    """A second `view --web` while another viewer holds the port: one line that names
    the port and the flag, exit 2, and no viewer started."""
    import socket

    from test_viewer import _free_port

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        taken = busy.getsockname()[1]
        code = main(["view", str(fabricated["path"]), "--web", "--port", str(_free_port()),
                     "--web-port", str(taken)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert str(taken) in err[0] and "--web-port" in err[0] and "display" not in err[0]


@pytest.mark.parametrize("fps, delay, said", [("100", 20, "20 ms a frame, 50.0 fps"),
                                               ("30", 30, "30 ms a frame, 33.3 fps"),
                                               ("10", 100, None)])
def test_a_gif_rate_it_cannot_hold_is_said(fabricated, tmp_path, capsys, fps, delay, said):
    """A GIF holds its frame delay in whole hundredths of a second, 20 ms at least:
    a trial's --fps 100 played at 50 fps and --fps 30 at 33.3, with no word. The
    delay written is the one said; a rate it holds is not remarked on."""
    from PIL import Image

    out = tmp_path / "x.gif"
    assert main(["export", str(fabricated["path"]), "--gif", str(out), "--fps", fps,
                 "--max-side", "64"]) == 0
    line = capsys.readouterr().out
    with Image.open(out) as im:
        assert im.info["duration"] == delay
    if said:
        assert said in line and f"not --fps {fps}" in line
    else:
        assert "ms a frame" not in line


def test_export_refuses_other_suffixes(fabricated, tmp_path, capsys):
    assert main(["export", str(fabricated["path"]), "--gif", str(tmp_path / "x.txt")]) == 2
    assert not (tmp_path / "x.txt").exists()
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("flag", [["--fps", "0"], ["--fps", "-1"], ["--fps=nan"],
                                  ["--max-side", "5"]])
def test_export_refuses_bad_rates_and_sizes_and_keeps_the_old_file(fabricated, tmp_path,
                                                                    capsys, flag):
    """A bad --fps or --max-side is a one-line error (exit 2) before any drawing, and
    the file already at the output path is left as it was."""
    old = tmp_path / "keep.gif"
    old.write_bytes(b"GIF89a not touched")
    with pytest.raises(SystemExit) as e:
        main(["export", str(fabricated["path"]), "--gif", str(old)] + flag)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag[0].split("=")[0] in err[0]
    assert old.read_bytes() == b"GIF89a not touched"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.gif"]


def test_export_checks_its_output_and_input_before_drawing(fabricated, tmp_path, capsys,
                                                          monkeypatch):
    """A fresh-user trial: --out /proc/x.gif drew every frame, then failed as an
    internal error naming the temporary file; a text file as the recording was
    "drawn" before it was found not to be one. Both are one-line input errors
    (exit 2) before any drawing."""
    from viewer import export

    def drawn(*a, **k):
        raise AssertionError("drew frames")

    monkeypatch.setattr(export, "render_frames", drawn)
    assert main(["export", str(fabricated["path"]), "--gif", "/proc/x.gif"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/proc/x.gif" in err[0] and "cannot create" in err[0], err
    text = tmp_path / "notes.rrd"
    text.write_text("not a recording")
    assert main(["export", str(text), "--gif", str(tmp_path / "x.gif")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a Rerun recording" in err[0] and "drawing" not in err[0]
    assert not (tmp_path / "x.gif").exists()


def test_another_tools_recording_is_named_as_such(tmp_path, capsys):
    """A fresh-user trial: a recording made by another Rerun application was "the
    run recorded no scan (cut before the first one)" to inspect, and "cut short" to
    export. Both say it is not a dynremove recording, naming its application."""
    import rerun as rr

    path = tmp_path / "other.rrd"
    rec = rr.RecordingStream("other_tool", recording_id="other-1")
    rec.save(str(path))
    rec.log("points", rr.Points2D([[1.0, 2.0]]))
    rec.flush()
    rec.disconnect()
    for cmd in (["inspect", str(path), "--pixel", "1,1"],
                ["export", str(path), "--gif", str(tmp_path / "x.gif")]):
        assert main(cmd) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not a dynremove recording" in err[0], err
        assert "other_tool" in err[0] and "cut" not in err[0], err


def test_failures_print_steps_to_jump_to(fabricated):
    items = vi.failures(fabricated["path"], top=3)
    assert items and all(len(e["steps"]) == 3 for e in items)
    x, y = items[0]["pixel"]
    assert items[0]["steps"][1] == visit_step(1, x, y, H, W)
    assert "steps " in vd.format_failures(items)


def test_web_prints_one_url_and_binds_loopback(fabricated, tmp_path, capsys):
    from test_viewer import _free_port, cli_env

    from viewer import serve

    port, web_port = _free_port(), _free_port()
    assert serve.view_command("x.rrd", port=port)[1:3] == ["--bind", "127.0.0.1"]
    # without a display it serves the page and opens no browser (a trial's headless
    # host got a chromium left as a zombie); with one, rerun opens the browser too
    assert serve.view_command("x.rrd", web=True)[1] == "--serve-web"
    assert serve.view_command("x.rrd", web=True, open_browser=True)[1] == "--web-viewer"
    proc = serve.view(fabricated["path"], web=True, port=port, web_port=web_port,
                      wait=False, env=cli_env(tmp_path))
    try:
        out = capsys.readouterr().out.strip().splitlines()
        assert out == [serve.web_url(port=port, web_port=web_port)]
    finally:
        serve.stop(proc)


def test_help_describes_view_and_export(capsys):
    for cmd in ("view", "export"):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        text = capsys.readouterr().out
        assert "127.0.0.1" in text if cmd == "view" else "GIF" in text


def test_probe_pixel_has_a_scrubbable_story(fabricated):
    t = _table(fabricated["path"], "/probes/**")
    col = next(n for n in t.column_names if n.endswith("TextLog:text"))
    texts = [v[0] for v in t.column(col).to_pylist() if v]
    assert len(texts) == 3 and all(s.startswith("(10,7) scan") for s in texts)


def test_export_captions_name_the_post_scan_steps(method_run):
    """The GIF's last frames are the post-scan steps and the written image, not
    "scan 0 step N" (a trial read the final frame as part of the scan)."""
    from viewer import export

    res, path = method_run["res"], method_run["path"]
    captions: list[str] = []
    frames = export.render_frames(path, max_side=200, captions=captions)
    assert len(captions) == len(frames)
    assert captions[-1] == (f"final: the written clean image   |L| = {int(res.dynamic.sum())} "
                            "analysis px")
    stage_caps = [c for c in captions if c.startswith("after the scans: ")]
    assert [c.split(": ")[1].split()[0] for c in stage_caps] == list(res.stages)
    assert captions[0].startswith("scan 0   step ")


def _line_words(de: float, at: str = "") -> str:
    """How inspect gives an epipolar search's best ΔE (its cap, 30: "nothing alike")."""
    from dynremove.refine.parallax import SEARCH_CAP_DE

    if de >= SEARCH_CAP_DE - 0.05:
        return f"ΔE ≥ {SEARCH_CAP_DE:.0f}, nothing alike{at}"
    return f"ΔE {de:.1f}{at}"


def test_where_the_fill_sampled_its_source_is_told(method_run):
    """A fresh-user trial (session 52) could not check a filled pixel's colour: inspect
    named the source, not where in it the fill sampled. The recording keeps that
    position (``paths.RESULT_FILL_MATCH``: the chosen source's field at each replaced
    pixel) and the fill line says "at (x, y) in it", as the fill's own fields say."""
    res, path = method_run["res"], method_run["path"]
    sel = res.selection
    rec = vi.read_selection(path)
    filled = (sel.label > 0) & ~sel.no_source
    assert filled.any() and "fill_x" in rec and "fill_y" in rec
    fx, fy = rec["fill_x"].astype(np.float64), rec["fill_y"].astype(np.float64)
    assert (fx[~filled] == P.DE_NONE).all()
    ys, xs = np.nonzero(filled)
    i = len(ys) // 2
    x, y = int(xs[i]), int(ys[i])
    want = sel.fields[int(sel.label[y, x]) - 1][y, x]
    np.testing.assert_allclose([fx[y, x] / P.XY_SCALE, fy[y, x] / P.XY_SCALE], want,
                               atol=0.5 / P.XY_SCALE + 1e-6)
    text = vd.format_pixel_history(vi.pixel_history(path, x, y))
    got = re.search(r"fill: filled from source \S+ at \(([\d.]+), ([\d.]+)\) in it \(where", text)
    assert got, text
    np.testing.assert_allclose([float(got[1]), float(got[2])], want, atol=0.1)


def test_the_static_test_is_told(method_run):
    """Inside L, inspect says why a pixel was or was not kept as static 3-D structure:
    how many sources had to show the reference's content, which did (the flow match,
    or the epipolar search with its ΔE) and why the others did not, as the fill's own
    arrays say (the question a user asks of a static pixel that was replaced)."""
    res, path = method_run["res"], method_run["path"]
    sel = res.selection
    assert sel is not None and sel.static_evidence is not None
    rec = vi.read_selection(path)
    names = list(rec["evidence"])
    assert len(names) == len(res.source_indices)
    for k, n in enumerate(names):  # recorded as computed
        np.testing.assert_array_equal(rec["evidence"][n], sel.static_evidence[k])
        got = rec["line_de"][n].astype(np.float64)
        searched = np.isfinite(sel.line_de[k])
        assert ((got == P.DE_NONE) == ~searched).all()
        np.testing.assert_allclose(got[searched] / P.DE_SCALE, sel.line_de[k][searched],
                                   atol=0.006)
    np.testing.assert_array_equal(rec["static_need"], sel.static_need)
    L = sel.static_need > 0
    counted = np.isin(sel.static_evidence, (1, 2)).sum(0)
    # what the fill kept as static had enough sources showing it, in a colour not the
    # movers' (or, in a flat set, at least two of them whatever the colour)
    colour_ok = (sel.ref_mover_p < 0.5) | ((sel.consensus_mode == "scan") & (counted >= 2))
    assert not (sel.explained & ~((counted >= sel.static_need) & colour_ok)).any()
    assert not (sel.explained & ~L).any()
    assert not (sel.explained & (sel.label > 0)).any()  # what the test kept stays the reference's
    picks = [np.nonzero(L & sel.explained), np.nonzero(L & ~sel.explained)]
    told = 0
    for ys, xs in picks:
        if not len(ys):
            continue
        i = len(ys) // 2
        x, y = int(xs[i]), int(ys[i])
        h = vi.pixel_history(path, x, y)
        line = vd.static_test_line(h)
        need = int(sel.static_need[y, x])
        filled = bool(res.dynamic[y, x]) and sel.label[y, x] > 0
        # the test's verdict, told against what became of the pixel
        head = {(True, False): "kept as static: ", (True, True): "passed (",
                (False, True): "not passed: ", (False, False): "not passed ("}[
            (bool(sel.explained[y, x]), filled)]
        c = int(counted[y, x])
        assert line.startswith("static 3-D structure test: " + head
                               + f"{c} source{'s count' if c != 1 else ' counts'} as showing the "
                               f"reference's content here, {need} needed"), line
        if filled:
            assert h["source_names"][sel.label[y, x] - 1] in line
        for k, n in enumerate(names):
            if sel.static_evidence[k, y, x]:
                assert n in line, (n, line)
            if sel.static_evidence[k, y, x] in (2, 3, 5) and np.isfinite(sel.line_de[k, y, x]):
                assert f"{n} ({_line_words(sel.line_de[k, y, x])})" in line, line
        if sel.ref_mover_p[y, x] >= 0.5:
            assert "the reference's colour is the movers'" in line
            assert ("count whatever the colour" in line) == bool(sel.explained[y, x])
        assert line in vd.format_pixel_history(vi.pixel_history(path, x, y))
        told += 1
    assert told >= 1
    off = np.nonzero(~L)
    assert vd.static_test_line(vi.pixel_history(path, int(off[1][0]), int(off[0][0]))) is None


def test_inspect_says_where_on_the_epipolar_line_the_match_lies(tmp_path):
    """Where the set is 3-D, the static test searches each source's epipolar line;
    inspect gives the best match's ΔE and where it lies in the source, so that the
    user can look there. Recorded as computed (to 1/8 px), on the source's
    epipolar line of the pixel, and told in the verdict. (The synthetic scene is
    flat: --select-parallax-px 0 treats it as 3-D; ``test_parallax`` checks that
    the point is the true match's.)"""
    sc = synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)
    params = dataclasses.replace(preset("default"), select_parallax_px=0.0)
    path = tmp_path / "run.rrd"
    rsink = RerunSink(path, gt_mask=sc.masks[sc.ref_index])
    res = remove_dynamic(sc.images, ref=sc.ref_index, params=params, sink=rsink)
    sel = res.selection
    assert sel.consensus_mode == "parallax" and sel.line_xy is not None
    rec = vi.read_selection(path)
    names = list(rec["line_de"])
    told = 0
    for k, n in enumerate(names):
        xy = sel.line_xy[k]
        have = np.isfinite(xy).all(-1)
        got = np.stack([rec["line_x"][n], rec["line_y"][n]], -1).astype(np.float64)
        kept = (got != P.DE_NONE).all(-1)
        assert (kept == have & (xy >= 0).all(-1)).all()
        np.testing.assert_allclose(got[kept] / P.XY_SCALE, xy[kept], atol=1 / P.XY_SCALE)
        ys, xs = np.nonzero(kept)
        assert len(ys)
        y, x = int(ys[len(ys) // 2]), int(xs[len(xs) // 2])
        line = vd.static_test_line(vi.pixel_history(path, x, y))
        if line is not None and sel.static_evidence[k, y, x] in (2, 3, 5):
            gx, gy = got[y, x] / P.XY_SCALE  # (as recorded: to 1/8 px)
            words = _line_words(sel.line_de[k, y, x], f" at ({gx:.0f}, {gy:.0f}) in it")
            assert f"{n} ({words})" in line, line
            told += 1
    assert told >= 1


def test_the_followed_movers_are_recorded(method_run):
    """Each source's map of where the flow followed the reference's mover into it (the
    sources that never fill there) is in the recording, over that source's image, as
    the fill computed it; a source where nothing was followed has none."""
    res, path = method_run["res"], method_run["path"]
    sel = res.selection
    got = vi.read_selection(path)
    rec = got.get("followed", {})
    names = list(got["reasons"])  # the sources' entity names, in order
    assert sel.followed.shape == (len(names),) + res.dynamic.shape
    if method_run["kind"] == "real":  # camel: every source shows its own camel, and at
        # this size the flow follows it into five of the six or all of them
        assert len(rec) >= len(names) - 1
    for k, n in enumerate(names):
        if sel.followed[k].any():
            np.testing.assert_array_equal(rec[n], sel.followed[k])
        else:
            assert n not in rec
    # a source ruled out there never fills a pixel it was ruled out at
    from dynremove.refine.select import FOLLOWED
    assert not ((sel.reasons == FOLLOWED) & (sel.label[None] == np.arange(1, len(names) + 1)[
        :, None, None]) & ~sel.no_source[None]).any()


@pytest.mark.parametrize("argv, words", [
    (["--port", "70000"], "argument --port: a port is 1..65535, got 70000"),
    (["--port", "-5"], "argument --port: a port is 1..65535, got -5"),
    (["--web-port", "0"], "argument --web-port: a port is 1..65535, got 0"),
    (["--port", "9999", "--web-port", "9999"], "--port and --web-port are both 9999"),
])
def test_view_ports_out_of_range_or_alike_are_one_line(fabricated, capsys, argv, words):
    """A trial's --port 70000 was an internal OverflowError, --web-port 0 printed a URL
    with port 0, and one port for both servers ended in "the viewer exited with code
    1" after the URL was printed."""
    try:
        code = main(["view", str(fabricated["path"]), "--web", *argv])
    except SystemExit as e:  # (argparse's own exit for a flag's value)
        code = e.code
    out, err = capsys.readouterr()
    assert code == 2 and words in err and "internal error" not in err and "http" not in out


def test_a_ctrl_c_stops_the_viewer_and_exits_130(fabricated, monkeypatch, capsys):
    """``view --web`` stopped by Ctrl-C exited 0 without a word, where every other
    command says "interrupted" and exits 130; the viewer process is stopped."""
    from viewer import serve

    stopped = []

    class Proc:
        returncode = None

        def wait(self):
            raise KeyboardInterrupt

        def poll(self):
            return None

    monkeypatch.setattr(serve.subprocess, "Popen", lambda *a, **k: Proc())
    monkeypatch.setattr(serve, "stop", lambda p: stopped.append(p))
    monkeypatch.setattr(serve, "rerun_binary", lambda: "rerun")
    from test_viewer import _free_port

    code = main(["view", str(fabricated["path"]), "--web", "--port", str(_free_port()),
                 "--web-port", str(_free_port())])
    err = capsys.readouterr().err
    assert code == 130 and "dynremove: interrupted" in err and len(stopped) == 1


def test_a_missing_package_is_not_read_as_a_cut_recording():
    """Without datafusion (rerun-sdk[catalog]'s), every read of a recording failed and
    was taken for an absent entity: a trial's intact recording was "cut short". The
    missing package is named instead."""
    from dynremove.errors import InputError
    from viewer.inspect import _arrow

    class Store:
        def reader(self, **kw):
            raise ModuleNotFoundError("No module named 'datafusion'", name="datafusion")

    with pytest.raises(InputError, match=r"needs datafusion, which is not installed: "
                                         r"pip install 'rerun-sdk\[catalog\]"):
        _arrow(Store(), "/result/clean")

    class Empty:
        def reader(self, **kw):
            raise ValueError("no such entity")

    assert _arrow(Empty(), "/result/clean") is None  # absent: None, as before


def test_the_planes_of_the_fields_across_L_are_recorded_and_told(method_run):
    """Which field each pixel of the hole was sampled through (``Selection.planes``,
    ``--select-planes``): the membrane, or a plane of the ring around its region. The
    recording holds it as computed (none where no plane was chosen), and inspect names
    the plane at a filled pixel that took one."""
    sel, path = method_run["res"].selection, method_run["path"]
    rec = vi.read_selection(path)
    if sel.planes is None:
        assert "planes" not in rec
        return
    want = np.clip(sel.planes.astype(np.int32) + 1, 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(rec["planes"], want)
    ys, xs = np.nonzero((sel.planes > 0) & (sel.label > 0) & ~sel.no_source
                        & method_run["res"].dynamic)
    if len(ys):
        y, x = int(ys[len(ys) // 2]), int(xs[len(xs) // 2])
        words = " ".join(vd.verdict_lines(vi.pixel_history(path, x, y)))
        assert f"plane {int(sel.planes[y, x])} of the ring around its region" in words, words


def test_the_fill_line_names_the_plane_only_where_one_was_chosen():
    """The fill line says which plane of the ring gave the field at the pixel (the
    recorded map holds 1 + the plane, 1 for the membrane, 0 outside the hole)."""
    h = {"final_dynamic": True, "source_names": ["a.png", "b.png"], "x": 1, "y": 1,
         "t_r": 0.3, "decisions": [], "replacements": [], "gt": None,
         "selection": {"source": 2, "inpainted": 0, "fill_x": 10.0, "fill_y": 20.0,
                       "planes": 3}}
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")]
    assert len(fill) == 1 and "at (10.0, 20.0) in it" in fill[0], fill
    assert "plane 2 of the ring around its region" in fill[0] and "--select-planes" in fill[0]
    for membrane in (1, 0):
        h["selection"]["planes"] = membrane
        fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")]
        assert "at (10.0, 20.0) in it" in fill[0] and "plane" not in fill[0], fill

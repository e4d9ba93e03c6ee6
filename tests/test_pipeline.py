"""End to end on synthetic scenes with ground truth, and the CLI."""

from __future__ import annotations

import io as _pyio
import json
import re

import cv2
import numpy as np
import pytest

from dynremove import MemorySink, NullSink, preset, remove_dynamic
from dynremove.evaluation import synth
from dynremove.cli import main
from dynremove.evaluation.metrics import jaccard, psnr_in_mask
from dynremove.params import DEFAULT
from dynremove.progress import ProgressBar


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=0, n_views=6, size=(360, 640))


@pytest.fixture(scope="module")
def result(scene):
    return remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"))


def test_default_detects_and_removes(scene, result):
    """The demo scene (`dynremove demo`).

    Issue 2's floor was J >= 0.9 and 30 dB inside the mask, met by the median of
    all sources (31.4 dB). The fill by selection (issue 10) copies the free
    sources that agree with the chosen one instead: 29.4 dB here, for no ghost
    and no damage on sparse and parallax sets (README "Fill by selection").
    """
    gt = scene.masks[scene.ref_index]
    assert jaccard(result.dynamic, gt) >= 0.9
    assert psnr_in_mask(result.clean, scene.background, gt) >= 29.0
    # the whole photo: nothing that was right in the reference is damaged
    lab = [cv2.cvtColor(cv2.GaussianBlur(im, (0, 0), 1.0).astype(np.float32) / 255,
                        cv2.COLOR_BGR2Lab) for im in (scene.images[scene.ref_index],
                                                     result.clean, scene.background)]
    right_in = np.linalg.norm(lab[0] - lab[2], axis=-1) <= 10
    wrong_out = np.linalg.norm(lab[1] - lab[2], axis=-1) > 10
    outside = ~cv2.dilate(gt.astype(np.uint8), np.ones((11, 11), np.uint8)).astype(bool)
    assert (outside & right_in & wrong_out).mean() <= 0.005
    before = psnr_in_mask(scene.images[scene.ref_index], scene.background, gt)
    assert before < 12.0


def test_sinks_do_not_change_results(scene, result):
    mem = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                         sink=MemorySink(), sample_static=0.01)
    null = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                          sink=NullSink())
    for r in (mem, null):
        np.testing.assert_array_equal(r.clean, result.clean)
        np.testing.assert_array_equal(r.dynamic, result.dynamic)


def test_identical_images_change_nothing(scene):
    ims = [scene.background.copy() for _ in range(4)]
    for name in ("paper", "default"):
        r = remove_dynamic(ims, ref=1, params=preset(name))
        assert not r.dynamic.any()
        np.testing.assert_array_equal(r.clean, ims[1])


def test_cli_run_end_to_end(tmp_path, scene):
    synth.write_scene(scene, tmp_path / "set")
    out = tmp_path / "out"
    code = main(["run", str(tmp_path / "set" / "frames"), "--out", str(out), "--quiet",
                 "--gt", str(tmp_path / "set" / "masks" / scene.names[scene.ref_index])])
    assert code == 0
    mask = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_UNCHANGED)
    clean = cv2.imread(str(out / "clean.png"))
    assert mask.dtype == np.uint8 and mask.shape == scene.masks[0].shape
    assert set(np.unique(mask)) <= {0, 255}
    assert clean.shape == scene.images[0].shape
    rep = json.loads((out / "report.json").read_text())
    assert rep["reference"]["index"] == scene.ref_index
    assert rep["scans"] and all(k in rep["seconds"] for k in ("features", "scans", "total"))
    assert rep["jaccard_vs_gt"] == pytest.approx(jaccard(mask > 0, scene.masks[scene.ref_index]))
    assert not list(out.glob("*.tmp"))


def test_cli_bad_input_exit_code(tmp_path, capsys):
    (tmp_path / "a.png").write_bytes(b"")
    code = main(["run", str(tmp_path / "a.png"), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "need at least 2 images" in err and "Traceback" not in err


def test_default_on_other_synthetic_scenes():
    """Not just the demo's seed: seeds 1-3 (measured J .889/.929/.931, 28.1/31.0/29.1 dB)."""
    js, ps = [], []
    for seed in (1, 2, 3):
        sc = synth.make_scene(seed=seed, n_views=6, size=(360, 640))
        r = remove_dynamic(sc.images, ref=sc.ref_index, params=preset("default"))
        gt = sc.masks[sc.ref_index]
        js.append(jaccard(r.dynamic, gt))
        ps.append(psnr_in_mask(r.clean, sc.background, gt))
    assert min(js) >= 0.8 and np.mean(js) >= 0.88
    assert min(ps) >= 25.0 and np.mean(ps) >= 28.5


# --- what the run reports: coverage, notes, stage times -----------------------------------
def test_coverage_png_and_report_say_what_was_inpainted(tmp_path):
    """coverage.png is 0 inside the mask exactly where the fill inpainted (no source
    showed the background free), and report.json's ``uncovered_dynamic_px`` is the
    count the note gives (seed 3: 3 px; it said 518 when the coverage was the
    scans' agreement with the reference, and coverage.png was black on all 518).
    No source sees the left part of the mover: its frames are transparent there."""
    sc = synth.make_scene(seed=3, n_views=6, size=(360, 640))
    synth.write_scene(sc, tmp_path / "set")
    gt = sc.masks[sc.ref_index]
    xs = np.flatnonzero(gt.any(0))
    blind = np.zeros(gt.shape, bool)
    blind[:, xs[0] - 8:xs[0] + (xs[-1] - xs[0]) // 3] = True
    valid = []
    for i, name in enumerate(sc.names):
        valid.append(~blind if i != sc.ref_index else np.ones(gt.shape, bool))
        if i != sc.ref_index:  # alpha 0 = no content (dynremove.validity)
            rgba = np.dstack([sc.images[i], np.where(blind, 0, 255).astype(np.uint8)])
            cv2.imwrite(str(tmp_path / "set" / "frames" / name), rgba)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "set" / "frames"), "--out", str(out), "--quiet"]) == 0
    rep = json.loads((out / "report.json").read_text())
    mask = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_UNCHANGED) > 0
    cov = cv2.imread(str(out / "coverage.png"), cv2.IMREAD_UNCHANGED)
    notes = [n for n in rep["notes"] if "seen free by no source: inpainted" in n]
    assert len(notes) == 1, rep["notes"]
    n = int(re.match(r"(\d+) px ", notes[0]).group(1))
    assert n > 0 and rep["uncovered_dynamic_px"] == n == int((mask & (cov == 0)).sum())
    with pytest.warns(UserWarning, match=f"{n} px .* seen free by no source"):
        r = remove_dynamic(sc.images, ref=sc.ref_index, valid_masks=valid)  # the same run
    np.testing.assert_array_equal(mask & (cov == 0), r.selection.no_source & r.dynamic)


def test_coverage_in_the_mask_counts_the_sources_the_output_was_made_from(scene, result):
    """Inside the replaced region: the sources the fill combined (the chosen one and the
    free ones agreeing with it), at least 1 where nothing was inpainted; outside, the
    count the scans left (sources agreeing with the reference)."""
    sel, dyn, cov = result.selection, result.dynamic, result.coverage
    assert dyn.any() and not (sel.no_source & dyn).any()
    assert not any("inpainted" in w for w in result.warnings)
    np.testing.assert_array_equal(cov[dyn], sel.members.sum(0)[dyn])
    assert cov[dyn].min() >= 1  # nothing inpainted: no black inside the mask
    assert int(cov.max()) <= len(scene.images) - 1
    paper = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("paper"))
    assert paper.selection is None and paper.coverage.shape == dyn.shape


def test_few_matches_are_one_note_given_with_the_geometry():
    """Sources with too few keypoint matches: one note naming them all (as io's per-file
    notes), warned when the geometry is known, before the correspondences."""
    rng = np.random.default_rng(5)
    ims = [cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (0, 0), 3)
           for _ in range(4)]
    events = []
    with pytest.warns(UserWarning) as caught:
        def progress(stage, frac):
            events.append((stage, frac, [str(w.message) for w in caught]))

        remove_dynamic(ims, ref=1, names=["a.png", "b.png", "c.png", "d.png"],
                       progress=progress)
    few = [str(w.message) for w in caught if "keypoint match" in str(w.message)]
    assert len(few) == 1, few
    assert few[0].startswith("a.png, c.png, d.png: only ") and "each with the reference" in few[0]
    first_corr = next(seen for stage, _, seen in events if stage == "correspondence")
    assert few[0] in first_corr
    assert any("3 of 3 sources could not be aligned" in m for m in first_corr)


def test_few_matches_note_forms():
    from dynremove.pipeline import _few_matches_note

    assert _few_matches_note([("a.jpg", 1, 0)]) == (
        "a.jpg: only 1 keypoint match with the reference; no epipolar term and no "
        "homography pre-warp for it")
    assert _few_matches_note([(f"s{i}.jpg", 9 + i, 0) for i in range(5)]).startswith(
        "5 images (s0.jpg, ..., s4.jpg): only 9 to 13 keypoint matches each")
    # a source with more matches than an aligned one may have: what leaves it out is
    # that they agree on no homography, and the note says so
    assert _few_matches_note([("b.jpg", 32, 5)]).startswith(
        "b.jpg: only 32 keypoint matches (fewer than 8 of them on one homography) with "
        "the reference; ")


def test_the_little_removed_note_counts_what_the_fill_kept_and_added_apart():
    """The fill keeps pixels of L and adds others beside them: a trial read "the fill
    kept -1536 of those" (the difference of the two counts) where it had added 1536
    and kept none. Each count is now its own, and both add up to the final mask."""
    from dynremove.pipeline import _little_removed_note

    pre = np.zeros((100, 100), bool)
    pre[10:20, 10:20] = True  # L before the fill: 100 px
    dyn = np.zeros_like(pre)
    dyn[10:20, 10:15] = True  # 50 of them replaced, 50 kept
    dyn[30:40, 30:50] = True  # 200 px added
    note = _little_removed_note(5000, pre, dyn, np.zeros_like(pre))
    assert "little was removed: 250 px (" in note
    assert ("left 100 px, and the fill kept 50 of those as the reference shows them and "
            "added 200 px beside them: 'dynremove inspect'") in note, note
    assert "-" not in note.split("left")[1].split(":")[0]
    note = _little_removed_note(5000, pre, dyn & pre, pre & ~dyn)
    assert ("the fill kept 50 of those as the reference shows them (50 px as static 3-D "
            "structure") in note and "added" not in note, note


def test_small_3d_structure_in_a_flat_set_is_told():
    """The 90th percentile of the parallax on the plane, the 95th over the limit
    (entry-P10's columns, 8-16 % of its matches): far out (over
    --select-parallax-p95-px) the set is treated as 3-D, and the run names the switch
    that treats it as flat; nearer, it stays flat, and the run names the switch that
    treats it as 3-D. Nothing is said where both percentiles agree."""
    from dynremove.method.geometry import TwoView
    from dynremove.pipeline import _knee_note
    from dynremove.refine.select import treated_as_3d

    def tv(p90, p95):
        return TwoView(F=np.eye(3), H=np.eye(3), n_matches=800, n_inliers_F=700,
                       n_inliers_H=500, parallax_px=p90, parallax_p95_px=p95)

    P = DEFAULT
    far = [tv(192.0, 325.6), tv(2.6, 226.0), tv(3.5, 143.6)]  # median 95th 226 px
    assert treated_as_3d(far, P)
    note = _knee_note(far, P)
    assert note.startswith("the set was treated as 3-D: 5 % of the matches depart from one "
                           "plane by 226 px or more (over the 150 px of "
                           "--select-parallax-p95-px), though the median parallax is 3.5 px")
    assert note.endswith("--select-parallax-p95-px 0 treats the set as flat")
    # the same set with the far test off, or a mover's matches only 40 px out: flat
    for views, p in ((far, P.replace(select_parallax_p95_px=0.0)),
                     ([tv(192.0, 325.6), tv(2.6, 40.0), tv(3.5, 30.0)], P)):
        assert not treated_as_3d(views, p)
        note = _knee_note(views, p)
        assert note.startswith("the set was treated as flat (median parallax 3.5 px, not over "
                               "the 8 px of --select-parallax-px), though 5 % of the matches "
                               "depart from one plane by")
        assert note.endswith("--select-parallax-px 0 treats the set as 3-D")
    assert _knee_note([tv(1.0, 2.0), tv(1.5, 3.0)], P) == ""  # flat by both
    assert not treated_as_3d([tv(1.0, 2.0), tv(1.5, 3.0)], P)
    assert _knee_note([tv(12.0, 30.0), tv(9.0, 20.0)], P) == ""  # 3-D by both
    assert treated_as_3d([tv(12.0, 30.0), tv(9.0, 20.0)], P)
    assert _knee_note([], P) == ""


def test_a_set_near_the_parallax_limit_is_told_which_way_it_went():
    """A median parallax within 25 % of --select-parallax-px (8 px) that decided alone
    gets a note naming the value that takes the set the other way, and that value
    does (a trial's shaky_desk6 with its last photo as the reference: 3-D at 8.2 px,
    nothing said). Far from the limit, or 3-D by the far matches as well, no note."""
    from dynremove.method.geometry import TwoView
    from dynremove.pipeline import _knee_note
    from dynremove.refine.select import treated_as_3d

    def tv(p90, p95):
        return TwoView(F=np.eye(3), H=np.eye(3), n_matches=800, n_inliers_F=700,
                       n_inliers_H=500, parallax_px=p90, parallax_p95_px=p95)

    P = DEFAULT
    for p90, way, other in ((8.16, "3-D", "flat"), (9.9, "3-D", "flat"), (7.3, "flat", "3-D"),
                            (7.0, "flat", "3-D"), (6.5, "flat", "3-D")):
        views = [tv(p90, 14.7 if way == "3-D" else 7.9)] * 3  # (flat, 95th over 8 px: above)
        assert treated_as_3d(views, P) == (way == "3-D")
        note = _knee_note(views, P)
        assert note.startswith(f"the set was treated as {way} by a narrow margin: its median "
                               f"parallax, {p90:.1f} px, is just ")
        value = float(re.search(r"--select-parallax-px ([0-9.]+) treats the set as", note)[1])
        assert note.endswith(f"--select-parallax-px {value:g} treats the set as {other}")
        assert treated_as_3d(views, P.replace(select_parallax_px=value)) == (other == "3-D")
    for views in ([tv(6.3, 7.0)] * 3, [tv(10.1, 14.7)] * 3, [tv(8.5, 200.0)] * 3):
        assert _knee_note(views, P) == ""
    assert _knee_note([tv(8.5, 14.7)] * 3, P.replace(select_parallax_px=0.0)) == ""


def test_a_weak_reference_is_named_as_the_cause():
    """The sanitizer burst with its reference re-saved as a JPEG of quality 15: every
    source matches it poorly (17-45 matches), one is not aligned, and the note on that
    one pointed at the source. The reference's own note says that its neighbours
    match their other neighbours far better; the burst as shot gets none, and
    neither does the compressed photo as a source (the first photo the reference)."""
    from conftest import data_dir

    from dynremove.method import geometry
    from dynremove.pipeline import _weak_reference_note

    d = data_dir() / "bursts" / "sanitizer" / "frames"
    if not d.is_dir():
        pytest.skip(f"real data not found at {d} (set DYNREMOVE_DATA to the shared data folder)")
    names = sorted(p.name for p in d.glob("*.jpg"))
    ims = [cv2.imread(str(d / n)) for n in names]
    ref = 3

    def note(images, ref=ref):
        srcs = [i for i in range(len(images)) if i != ref]
        g = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in images]
        views = geometry.geometry_for_sources(g[ref], [g[s] for s in srcs])
        weak = [k for k, v in enumerate(views) if not geometry.aligned(v)]
        return _weak_reference_note(images, ref, srcs, views, names, weak)

    assert note(ims) is None
    low = list(ims)
    low[ref] = cv2.imdecode(cv2.imencode(".jpg", ims[ref], [cv2.IMWRITE_JPEG_QUALITY, 15])[1], 1)
    said = note(low)
    assert said is not None and "--ref auto" in said
    assert "sanitizer2.jpg–sanitizer3.jpg and sanitizer6.jpg–sanitizer5.jpg" in said, said
    assert note(low, ref=0) is None


def test_progress_lines_are_the_report_stages(scene):
    """A line for every stage of ``timings`` (the scans: one per scan), each as long as
    the stage, and together the run's total."""
    stream = _pyio.StringIO()  # not a terminal: one line per finished stage
    bar = ProgressBar(stream=stream)
    r = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                       progress=bar)
    bar.close()
    shown: dict[str, float] = {}
    for ln in stream.getvalue().splitlines():
        m = re.match(r"(.+?)\s+\[[#-]+\]\s+100\.0 %\s+([\d.]+) s$", ln)
        assert m, ln
        key = "scans" if m.group(1).startswith("scan ") else m.group(1)
        shown[key] = shown.get(key, 0.0) + float(m.group(2))
    stages = {k: v for k, v in r.timings.items() if k != "total"}
    assert set(shown) == set(stages) >= {"features", "geometry", "correspondence",
                                         "similarity", "scans", "refine", "fusion"}
    for k, v in stages.items():
        assert abs(shown[k] - v) <= 0.08 * (len(r.scans) if k == "scans" else 1), (k, shown, v)
    assert abs(sum(stages.values()) - r.timings["total"]) <= 0.05
    assert abs(sum(shown.values()) - r.timings["total"]) <= 0.06 * len(shown)


class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_progress_clock_starts_with_the_stage(monkeypatch):
    """A stage is timed from its (stage, 0.0) call, or from the end of the stage before
    it when its first call comes later (a scan's first rows); one line per stage."""
    from dynremove import progress

    clock = _Clock()
    monkeypatch.setattr(progress.time, "perf_counter", clock)
    stream = _pyio.StringIO()
    bar = ProgressBar(stream=stream)
    for t, stage, frac in [(0, "a", 0.0), (1, "a", 0.5), (2, "a", 1.0), (2.5, "a", 1.0),
                           (5, "b", 0.3), (6, "b", 1.0)]:
        clock.t = t
        bar(stage, frac)
    bar.close()
    clock.t = 10
    bar("c", 0.2)
    clock.t = 11
    bar("c", 1.0)
    secs = [(ln.split("[")[0].strip(), float(ln.split()[-2]))
            for ln in stream.getvalue().splitlines()]
    assert secs == [("a", 2.0), ("b", 4.0), ("c", 1.0)]
    # a stage that says it starts (0.0) after a gap is timed from then, as report.json
    # times it: the gap (a recording's logging between two stages) is in no line
    clock.t = 15
    bar("d", 0.0)
    clock.t = 16.5
    bar("d", 1.0)
    assert stream.getvalue().splitlines()[-1].split()[-2] == "1.5"


class _Tty(_pyio.StringIO):
    """A stream that says it is a terminal (the bar then redraws one line)."""

    def isatty(self):
        return True


def test_a_failing_command_erases_its_unfinished_bar_line():
    """On a terminal, an input error left "load [----] 0.0 %" above it (a trial); the
    unfinished stage's line is now erased. A finished stage's line stays."""
    stream = _Tty()
    bar = ProgressBar(stream=stream)
    bar("load", 1.0)
    bar("features", 0.0)
    bar.close(failed=True)
    text = stream.getvalue()
    assert text.endswith("\r\033[K") and "load" in text.split("\n")[0]
    stream = _Tty()
    bar = ProgressBar(stream=stream)
    bar("load", 0.0)
    bar.close()  # a run that ends well ends the line, as before
    assert stream.getvalue().endswith("\n")


def test_progress_note_ends_the_bar_line():
    stream = _Tty()
    bar = ProgressBar(stream=stream)
    bar("features", 0.5)
    bar.note("dynremove: note: something")
    bar("features", 1.0)
    bar.close()
    lines = stream.getvalue().split("\n")
    assert lines[1] == "dynremove: note: something"
    assert lines[0].startswith("\rfeatures") and lines[2].startswith("\rfeatures")
    assert lines[3] == ""


def test_dropping_sources_drops_every_per_source_array():
    """A near-copy dropped from the sources takes all its per-source arrays with it,
    the fill's flow matches included (they were left whole, so the fill sampled
    each remaining source through another source's flow)."""
    import dataclasses

    from dynremove.method.scan.driver import ScanInputs
    from dynremove.pipeline import _keep_sources

    S, H, W = 4, 3, 5
    per = lambda *shape: np.arange(S * int(np.prod(shape)), dtype=np.float32).reshape(S, *shape)  # noqa: E731
    st = ScanInputs(img=np.zeros((H, W, 3), np.uint8), lab=np.zeros((H, W, 3), np.float32),
                    gray=np.zeros((H, W), np.float32), fc_r=np.zeros((H, W, 3), np.float32),
                    fg_r=np.zeros((H, W, 128), np.uint8), src_img=per(H, W, 3),
                    src_lab=per(H, W, 3), src_gray=per(H, W), fc_s=per(H, W, 3),
                    fg_s=per(H, W, 128), N=per(H, W, 2), C=per(H, W), F=per(3, 3),
                    hasF=np.ones(S, bool), sift_unit=1.0, Nf=per(H, W, 2), Nf_flow=per(H, W, 2))
    keep = np.array([0, 2, 3])
    out = _keep_sources(st, keep)
    for f in dataclasses.fields(ScanInputs):
        a, b = getattr(st, f.name), getattr(out, f.name)
        if isinstance(a, np.ndarray) and a.shape[:1] == (S,) and a.ndim > 1 or f.name == "hasF":
            np.testing.assert_array_equal(b, a[keep], err_msg=f.name)


def test_share_of_the_reference_seen_by_fewer_than_two_sources():
    """The note for sets shot while panning far (a trial's 3 tennis frames 20 apart:
    53 % of the reference seen by one source only, and nothing removed, silently)."""
    from dynremove.method.geometry import TwoView
    from dynremove.pipeline import _seen_by_fewer_than_two

    H, W = 80, 100

    def shifted(dx):
        Hm = np.eye(3)
        Hm[0, 2] = dx  # reference x -> source x + dx
        return TwoView(F=None, H=Hm, n_matches=0, n_inliers_F=0, n_inliers_H=0)

    assert _seen_by_fewer_than_two([shifted(0), shifted(0)], H, W) == 0.0
    # the second source sees the reference's x < 40 only (x + 60 <= 99)
    assert _seen_by_fewer_than_two([shifted(0), shifted(60)], H, W) == pytest.approx(0.6, abs=0.05)
    assert _seen_by_fewer_than_two([shifted(-200), shifted(200)], H, W) == 1.0


def test_the_api_takes_ref_and_params_as_the_cli_does():
    """A trial called remove_dynamic(ref=-1), ref="auto", params=None and a dict and
    got bare tracebacks (AttributeError, ValueError): the API now takes what the
    CLI takes, and refuses the rest with InputError (a params of another type too: the
    README says bad input raises InputError)."""
    import warnings

    from dynremove import InputError, Params, remove_dynamic
    from dynremove.pipeline import api_params, api_ref

    assert api_params(None) == Params() == api_params("default")
    assert api_params("paper").max_scans == 4
    assert api_params({"t_r": 0.25}) == Params(t_r=0.25)
    for bad in ({"bogus": 1}, {"t_r": -1}, "nope"):
        with pytest.raises(InputError, match="params"):
            api_params(bad)
    with pytest.raises(InputError, match=r"^params must be a dynremove.Params, .* got int$"):
        api_params(3)
    names = ["a.jpg", "b.jpg", "c.jpg", "d.jpg"]
    assert [api_ref(r, [], names) for r in (-1, -4, 0, None, "b.jpg", "c")] == [3, 0, 0, 2, 1, 2]
    for bad in (4, -5, "x", 1.5, True):
        with pytest.raises(InputError):
            api_ref(bad, [], names)
    sc = synth.make_scene(seed=0, n_views=4, size=(96, 128))
    res = remove_dynamic(sc.images, ref=-1, params={"t_r": 0.3})
    assert res.ref_index == 3 and res.params["t_r"] == 0.3
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        res = remove_dynamic(sc.images, ref="auto", params=None)
    assert any(str(m.message).startswith("--ref auto: ") for m in w)
    assert 0 <= res.ref_index < 4


def test_a_black_and_white_reference_is_filled_in_gray():
    """A B&W reference among colour photos: the others are used in gray (with a
    note), so the fill adds no colour and the colours the reference cannot show do
    not flag the static scene (a fresh-user trial: a brown patch in a B&W photo,
    and twice the mask)."""
    from dynremove.evaluation.metrics import jaccard
    from dynremove.pipeline import gray_like_reference, is_gray

    sc = synth.make_scene(seed=0, n_views=5, size=(180, 320), n_objects=1)
    ref = sc.ref_index
    gray = [cv2.cvtColor(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
            for im in sc.images]
    ims = list(sc.images)
    ims[ref] = gray[ref]
    assert is_gray(ims[ref]) and not any(is_gray(im) for im in sc.images)
    with pytest.warns(UserWarning, match="black and white"):
        r = remove_dynamic(ims, ref=ref)
    assert r.dynamic.sum() > 100
    spread = r.clean.max(axis=2).astype(int) - r.clean.min(axis=2)
    assert spread.max() <= 1, "colour written into the black-and-white photo"
    all_gray = remove_dynamic(gray, ref=ref)
    assert np.array_equal(r.dynamic, all_gray.dynamic)
    assert r.gray_sources and not all_gray.gray_sources
    # every photo black and white: a note of its own (a trial's gray sanitizer set
    # lost the bottle's cap only, and nothing said why); a colour set has none
    from dynremove.pipeline import ALL_GRAY_NOTE
    assert ALL_GRAY_NOTE in all_gray.warnings and ALL_GRAY_NOTE not in r.warnings
    assert not any("black and white" in str(w) for w in remove_dynamic(sc.images,
                                                                        ref=ref).warnings)
    # at full resolution the sources are used in gray as well
    from dynremove.pipeline import full_resolution_output

    big = [cv2.resize(im, (640, 360), interpolation=cv2.INTER_CUBIC) for im in ims]
    clean_full, _ = full_resolution_output(r, big)
    assert clean_full.shape == (360, 640, 3)
    assert (clean_full.max(axis=2).astype(int) - clean_full.min(axis=2)).max() <= 1
    assert jaccard(r.dynamic, sc.masks[ref]) > 0.7
    # a colour reference, or a set already all gray, is left alone (no note)
    assert gray_like_reference(sc.images, ref)[1] is None
    assert gray_like_reference(gray, ref)[1] is None


def test_a_scan_that_decides_little_of_the_reference_says_so():
    """Two photos of ``bursts/tim6`` (tim2, tim4) in which the cup moved 150 px: the
    first scan formed no cluster of candidates at 84 % of the reference, so it flags
    little and the cup stays; the run says that it could not decide most of the
    photo, and why (a fresh-user trial had only "nothing was found moving")."""
    from conftest import data_dir

    from dynremove.pipeline import _undecided_note

    # the note itself: from half of the photo up, worded by the number of sources
    sm = [{"n_undecided": 600}]
    assert _undecided_note(sm, 1000, 1).startswith("the scans could not decide 60 % ")
    assert "with 2 photos" in _undecided_note(sm, 1000, 1)
    assert "more photos" in _undecided_note(sm, 1000, 3)
    assert _undecided_note([{"n_undecided": 400}], 1000, 3) == ""
    assert _undecided_note([], 1000, 3) == ""
    d = data_dir() / "bursts" / "tim6" / "frames"
    if not d.is_dir():
        pytest.skip(f"real data not found at {d} (set DYNREMOVE_DATA to the shared data folder)")
    ims = [cv2.imread(str(d / f"{n}.jpg")) for n in ("tim2", "tim4")]
    with pytest.warns(UserWarning) as rec:
        r = remove_dynamic(ims, ref=1)
    said = [str(w.message) for w in rec if "could not decide" in str(w.message)]
    assert len(said) == 1 and "with 2 photos" in said[0], [str(w.message) for w in rec]
    undecided = int(r.scans[0]["n_undecided"]) / r.dynamic.size
    assert undecided > 0.5 and f"{100 * undecided:.0f} %" in said[0]
    assert not r.dynamic.any()  # (with two photos it is said only then)


def test_photos_that_are_all_copies_of_the_reference_are_told():
    """Three copies of one photo (a trial gave the same file three times): nothing can
    differ, and the run says why nothing was found, instead of only "nothing was
    found moving"."""
    sc = synth.make_scene(seed=0, n_views=3, size=(120, 200), n_objects=1)
    for n in (4, 3, 2):
        ims = [sc.images[0].copy() for _ in range(n)]
        with pytest.warns(UserWarning) as rec:
            r = remove_dynamic(ims, ref=1)
        said = [str(w.message) for w in rec]
        assert any(m.startswith("every other photo is a near-copy of the reference (") and
                   "100.0 % alike" in m for m in said), (n, said)
        # that note says it all: a trial's four copies were also told of "near-copies
        # among the sources" and of "only 2 photos"
        assert not any(m.startswith(("near-copies among", "only 2")) for m in said), said
        assert not r.dynamic.any()

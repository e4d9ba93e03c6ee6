"""`dynremove inspect` on the recordings a new user made (trial report, items 1, 2, 4, 5).

* a ``--compare`` recording holds two runs: without ``--root`` (or with a root it
  does not hold) inspect names them and exits 2, instead of explaining nothing;
* an interrupted run is judged on what its recording holds (did a scan record
  anything?), not on how it ended: Ctrl-C and SIGTERM between the sink's
  ``start`` and the first scan both give exit 2 "nothing to inspect";
* ``--pixel`` counts in the analysis image; a photo pixel given by mistake is
  refused with the analysis pixel it means, when the recording knows the photos'
  size;
* ``--failures`` without ground truth names the command that records it.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from test_viewer_fixtures import fabricate_run, make_info  # noqa: E402

from dynremove import commands, errors  # noqa: E402
from dynremove.cli import main  # noqa: E402
from dynremove.evaluation import synth  # noqa: E402
from viewer import RerunSink, make_compare_blueprint  # noqa: E402
from viewer import inspect as vi  # noqa: E402
from viewer import verdict as vd  # noqa: E402
from viewer._images import visit_step  # noqa: E402

H, W, S = 48, 64, 3


def _inspect(capsys, path, *args: str) -> tuple[int, str, list[str]]:
    rc = main(["inspect", str(path), *args])
    out, err = capsys.readouterr()
    return rc, out, err.strip().splitlines()


# -- 1. --compare recordings and --root ---------------------------------------------------
@pytest.fixture(scope="module")
def compare_rrd(tmp_path_factory):
    """Two fabricated runs in one recording under the roots `run --compare` uses."""
    path = tmp_path_factory.mktemp("cmp") / "cmp.rrd"
    names = [f"src {s:02d}.jpg" for s in range(S)]
    roots = ["runs/main", "runs/compare"]
    rec = rr.RecordingStream("dynremove", recording_id="compare")
    rec.save(path, default_blueprint=make_compare_blueprint(names, roots))
    a = RerunSink(None, rec=rec, root=roots[0], record_every_rows=8)
    b = RerunSink(None, rec=rec, root=roots[1], record_every_rows=8)
    fabricate_run([a], H=H, W=W, S=S, n_scans=2)
    fabricate_run([b], H=H, W=W, S=S, n_scans=1, seed=3)
    rec.disconnect()
    return path


def test_compare_recording_without_root_names_both_runs(compare_rrd, capsys):
    assert vi.runs_in(vi.load_store(compare_rrd)) == ["runs/main", "runs/compare"]
    for args in (["--pixel", "5,5"], ["--failures"]):
        rc, out, err = _inspect(capsys, compare_rrd, *args)
        assert rc == 2 and out == "", out
        assert err == [f"dynremove: error: {compare_rrd} holds two runs, runs/main and "
                       "runs/compare: pass --root runs/main or --root runs/compare"], err


def test_export_of_a_compare_recording_asks_for_the_run_before_drawing(compare_rrd, capsys,
                                                                      tmp_path):
    """A trial's export without --root printed "drawing a frame per snapshot" and then
    failed: the one error line now comes first, and nothing is drawn or written."""
    rc = main(["export", str(compare_rrd), "--gif", str(tmp_path / "c.gif")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err == [f"dynremove: error: {compare_rrd} holds two runs, runs/main "
                               "and runs/compare: pass --root runs/main or --root "
                               "runs/compare"], err
    assert not (tmp_path / "c.gif").exists()


@pytest.mark.parametrize("root", ["bogus", "runs/other", "runs"])
def test_compare_recording_with_an_unknown_root(compare_rrd, capsys, root):
    rc, out, err = _inspect(capsys, compare_rrd, "--pixel", "5,5", "--root", root)
    assert rc == 2 and out == ""
    assert err == [f"dynremove: error: no run under --root {root}; {compare_rrd} holds: "
                   "runs/main, runs/compare"], err


@pytest.mark.parametrize("root, want", [("runs/main", "runs/main"), ("/runs/compare/",
                                                                       "runs/compare"),
                                        ("compare", "runs/compare"), ("main", "runs/main")])
def test_compare_recording_with_its_roots(compare_rrd, capsys, root, want):
    assert vi.resolve_root(compare_rrd, root) == want
    rc, out, err = _inspect(capsys, compare_rrd, "--pixel", "5,5", "--root", root)
    assert rc == 0 and err == [], err
    first, plain, second = out.splitlines()[:3]
    assert first == "pixel (5, 5): kept (not in the final mask)", out
    assert plain.startswith("  in plain words: ") and "M =" not in plain, out
    assert second.startswith("  the scans: static in ") and first.count("pixel (") == 1, out
    n_scans = 2 if want == "runs/main" else 1
    assert f"scan {n_scans - 1} step" in out  # the run of that root, not the other


def test_a_plain_recording_ignores_no_root_and_refuses_another(tmp_path, capsys):
    path = tmp_path / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8)], H=H, W=W, S=S, n_scans=1)
    assert vi.resolve_root(path, "") == ""
    rc, _, err = _inspect(capsys, path, "--pixel", "5,5", "--root", "runs/main")
    assert rc == 2 and err == [f"dynremove: error: no run under --root runs/main; {path} "
                               "holds: one run at the top level (no --root)"], err


def test_no_doubled_pixel_prefix():
    h = dict(x=3, y=4, t_r=0.3, decisions=[], scans=[], replacements=[], covered_by=[],
             updates=[], source_names=[], final_dynamic=None, gt=None, stages={},
             size=(H, W))
    text = vd.format_pixel_history(h)
    assert text == "pixel (3, 4): no scan of this recording reached it", text


def test_a_failure_region_says_what_made_most_of_it_so():
    """``--failures`` tags each region with its cause (a trial could not find the
    regions a rule had kept): a missed region that the fill by selection kept
    because its fill did not fit, one never flagged, one the clean-up dropped, and a
    false positive the border votes added, each by the most of its pixels."""
    import numpy as np

    from viewer import inspect as vi

    H_, W_ = 8, 8
    region = np.zeros((H_, W_), bool)
    region[2:6, 2:6] = True  # 16 px
    st = {n: np.zeros((H_, W_), bool) for n in vi.STAGE_ORDER}
    for n in ("scan", "clean", "votes", "snap"):
        st[n][region] = True
    comp = np.zeros((H_, W_), np.uint8)
    comp[2:6, 2:5] = 3  # 12 of the 16 kept by the misfit rule
    why, share = vi.failure_cause("FN", region, st, {"completed": comp})
    assert (why, share) == ("misfit", 0.75)
    words = vd.failure_words(why, share)
    assert words.startswith("75 % of it kept: its fill did not fit") and \
        "--select-misfit-levels" in words, words
    assert vi.failure_cause("FN", region, {n: np.zeros((H_, W_), bool)
                                           for n in vi.STAGE_ORDER}, {}) == ("never", 1.0)
    st2 = {n: np.zeros((H_, W_), bool) for n in vi.STAGE_ORDER}
    st2["scan"][region] = True
    why, share = vi.failure_cause("FN", region, st2, {})
    assert (why, share) == ("dropped:clean", 1.0)
    assert vd.failure_words(why, share) == "dropped by the L clean-up"
    st3 = {n: np.zeros((H_, W_), bool) for n in vi.STAGE_ORDER}
    for n in ("votes", "snap", "select"):
        st3[n][region] = True
    assert vi.failure_cause("FP", region, st3, {}) == ("added:votes", 1.0)
    assert vi.failure_cause("FP", region, {}, {}) == (None, 0.0)


def test_a_failure_region_lists_its_causes_and_shows_the_first():
    """A region made by two causes names both with their shares, largest first (a
    trial read "38 % of it never flagged" as the whole story), and the pixel it
    offers to explain has the cause named first (the trial's pixel had been dropped
    by the clean-up, the line said "never flagged")."""
    import numpy as np

    from viewer import inspect as vi

    H_, W_ = 12, 20
    region = np.zeros((H_, W_), bool)
    region[2:10, 2:18] = True  # 128 px
    st = {n: np.zeros((H_, W_), bool) for n in vi.STAGE_ORDER}
    st["scan"][2:10, 2:7] = True  # 40 px the clean-up dropped, the other 88 never flagged
    shares, per_px = vi.failure_causes("FN", region, st, {})
    assert shares == [("never", 88 / 128), ("dropped:clean", 40 / 128)]
    assert per_px.shape == (128,) and (per_px == "dropped:clean").sum() == 40
    e = dict(kind="FN", area=128, bbox=(2, 2, 16, 8), pixel=(4, 5), n_decisions=0,
             worst=None, steps=[], why=shares[0][0], why_share=shares[0][1],
             why_more=shares[1:])
    line = vd.format_failures([e]).splitlines()[1]
    assert line.endswith("; 69 % of it never flagged (the scans and the steps after them "
                         "left it); 31 % of it dropped by the L clean-up"), line


def test_a_patch_write_names_its_ties_not_its_candidates():
    """``n_patches`` of a write counts A_m's patches tied at the best score; a trial
    read "(the only candidate patch)" beside "4 of 12 candidates" as a contradiction.
    One patch at the best score is "the best of A_m's patches"; several, a tie-break."""
    w = dict(scan=0, step=7, x=3, y=4, src=1, src_name="b.png", src_x=5, src_y=6,
             score=0.66, tie_break=False, n_patches=1)
    h = dict(x=3, y=4, t_r=0.3, decisions=[], scans=[], replacements=[w], covered_by=[],
             updates=[], source_names=["a.png", "b.png"], final_dynamic=None, gt=None,
             stages={}, size=(H, W))
    text = vd.format_pixel_history(h)
    assert "(the best of A_m's patches)" in text and "only candidate" not in text, text
    w.update(tie_break=True, n_patches=3)
    text = vd.format_pixel_history(h)
    assert "a tie-break among the 3 patches of A_m with that score" in text, text


# -- 2. interrupted recordings: decided on what they hold ---------------------------------
def _run_cut_at(step, sig, tmp_path, capsys, monkeypatch, code):
    """``dynremove run --record`` on a small synthetic set, interrupted by ``sig`` raised
    where the pipeline calls ``step``; checks the exit code, returns the recording."""
    import cv2

    from dynremove import pipeline

    scene = synth.make_scene(seed=0, n_views=4, size=(48, 64))
    folder = tmp_path / "set"
    folder.mkdir()
    for name, im in zip(scene.names, scene.images):
        cv2.imwrite(str(folder / name), im)

    def cut(*a, **k):
        raise sig()

    monkeypatch.setattr(pipeline, step, cut)
    rrd = tmp_path / "run.rrd"
    rc = main(["run", str(folder), "--out", str(tmp_path / "out"), "--record", str(rrd),
               "--quiet"])
    capsys.readouterr()
    assert rc == code
    return rrd


@pytest.mark.parametrize("sig, code", [(KeyboardInterrupt, 130), (errors.Terminated, 143)])
def test_cut_between_start_and_the_first_scan_is_nothing_to_inspect(
        tmp_path, capsys, monkeypatch, sig, code):
    """Ctrl-C and SIGTERM after the sink's start (its step-0 snapshot is logged) but
    before the first scan: the same recording, the same exit 2 "nothing to inspect".
    (The trial saw exit 0 and "no scan ... final L = ?" when Ctrl-C landed there.)"""
    rrd = _run_cut_at("run_scans", sig, tmp_path, capsys, monkeypatch, code)
    msg = vi.interruption(vi.RrdReader(str(rrd)).stream().collect())  # as the CLI said
    assert msg.startswith("interrupted before the scans began (") and "during scan" not in msg
    for args in (["--pixel", "5,5"], ["--failures"]):
        rc, out, err = _inspect(capsys, rrd, *args)
        assert (rc, out) == (2, ""), out
        assert err == [f"dynremove: error: {rrd}: the run was {msg}: nothing to inspect"], err


def _cut_sink(path, *, scan: int, after_chunks: int) -> RerunSink:
    """A RerunSink whose run is interrupted (as the CLI does: ``interrupted()``) after
    ``after_chunks`` chunks of scan ``scan``."""

    class Cut(Exception):
        pass

    class CutSink(RerunSink):
        n = 0

        def chunk(self, events, state):
            super().chunk(events, state)
            if events.scan == scan:
                self.n += 1
                if self.n == after_chunks:
                    raise Cut()

    sink = CutSink(path, record_every_rows=4)
    with pytest.raises(Cut):
        fabricate_run([sink], H=H, W=W, S=S, n_scans=3, rows_per_chunk=4)
    sink.interrupted()
    return sink


def test_sink_start_then_interrupted_is_nothing_to_inspect(tmp_path, capsys):
    rrd = tmp_path / "run.rrd"
    sink = RerunSink(rrd)
    info, _, _ = make_info(H, W, S)
    sink.start(info)  # logs the step-0 snapshot of the reference
    sink.interrupted("after correspondence")
    rc, out, err = _inspect(capsys, rrd, "--pixel", "5,5")
    assert (rc, out) == (2, "")
    assert err == [f"dynremove: error: {rrd}: the run was interrupted before the scans "
                   "began (after correspondence): nothing to inspect"], err


def test_cut_mid_scan_says_whether_the_scan_had_reached_the_pixel(tmp_path, capsys):
    rrd = tmp_path / "mid.rrd"
    _cut_sink(rrd, scan=0, after_chunks=3)  # rows 0..11 of scan 0 visited
    msg = vi.interruption(vi.load_store(rrd))
    step = int(msg.rsplit(" ", 1)[1])
    assert msg.startswith("interrupted at scan 0, step ") and step == 12 * W - 1
    note = f"dynremove: note: {rrd.resolve()}: the run was {msg}: read what was recorded"

    rc, out, err = _inspect(capsys, rrd, "--pixel", "5,40")  # row 40: not reached
    assert rc == 0 and err == [note], err
    assert out.strip() == (f"pixel (5, 40): not reached: the run was {msg}, before scan 0 "
                           f"came to this pixel (its step would have been "
                           f"{visit_step(0, 5, 40, H, W)})")
    rc, out, err = _inspect(capsys, rrd, "--pixel", "1,1")  # visited, nothing recorded
    assert rc == 0 and out.startswith(f"pixel (1, 1): visited by scan 0 at step {W + 1}, "
                                      f"but the run was {msg}"), out
    assert "final L = ?" not in out and "history" not in out and len(out.splitlines()) == 1


def test_cut_in_the_second_scan_answers_from_the_first(tmp_path, capsys):
    """The per-scan maps of the finished scans are read although there is no final L."""
    rrd = tmp_path / "second.rrd"
    _cut_sink(rrd, scan=1, after_chunks=2)
    rc, out, err = _inspect(capsys, rrd, "--pixel", "1,1")
    assert rc == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("pixel (1, 1): static in scan 0 (step "), out
    assert lines[-1].startswith("  no final L: the run was interrupted at scan 1, step "), out
    assert "final L = ?" not in out


# -- 4. photo pixels vs analysis pixels ---------------------------------------------------
@pytest.fixture(scope="module")
def downscaled(tmp_path_factory):
    """A run whose 256x192 photos were analysed at 64x48 (the sink knows both)."""
    path = tmp_path_factory.mktemp("photo") / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8, photo_size=(4 * W, 4 * H))],
                  H=H, W=W, S=S, n_scans=1)
    return path


def test_run_info_records_the_photo_size(downscaled, tmp_path):
    info = vi.read_run_info(downscaled)
    assert (info["photo_width"], info["photo_height"]) == (4 * W, 4 * H)
    assert (info["width"], info["height"]) == (W, H)
    early = tmp_path / "early.rrd"  # begin() only (interrupted during the features)
    sink = RerunSink(early, photo_size=(4 * W, 4 * H))
    sink.begin(["a.png", "b.png", "c.png"], (H, W), ref=1)
    sink.interrupted("during features")
    info = vi._static_values(vi.RrdReader(str(early)).stream().collect(), "/run/info")
    assert info["photo_width"] == [4 * W] and info["photo_height"] == [4 * H]


def test_a_photo_pixel_is_refused_with_the_analysis_pixel_it_means(downscaled, capsys):
    rc, out, err = _inspect(capsys, downscaled, "--pixel", "200,150")
    assert (rc, out) == (2, "")
    # as `run --probe 200,150` scales it: round((200.5)·64/256 − 0.5), round(150.5·48/192 − 0.5)
    assert err == ["dynremove: error: pixel (200, 150) is outside the 64x48 analysis image "
                   "(x in 0..63, y in 0..47): --pixel counts in the image the run analysed, "
                   "as the viewer and --failures do; the photos are 256x192 (analysed at "
                   "×0.25): photo pixel (200, 150) is --pixel 50,37"], err
    rc, _, err = _inspect(capsys, downscaled, "--pixel", "300,150")  # outside the photo too
    assert rc == 2 and err[0].endswith("the photos are 256x192 (analysed at ×0.25)"), err
    rc, out, _ = _inspect(capsys, downscaled, "--pixel", "50,37")
    assert rc == 0 and out.splitlines()[-1] == (
        "  (pixels of the 64x48 analysis image; the photos are 256x192, analysed at ×0.25)")


def test_photo_pixel_explains_the_analysis_pixel_it_falls_in(downscaled, capsys):
    """--photo-pixel counts as clean.png at full size, --probe and --gt do. The first
    line names the photo pixel asked for (a fresh-user trial: --photo-pixel 485,315
    was echoed as photo pixel (484, 315), the centre of its analysis pixel)."""
    rc, out, err = _inspect(capsys, downscaled, "--photo-pixel", "200,150")
    assert rc == 0, err
    rc2, out2, _ = _inspect(capsys, downscaled, "--pixel", "50,37")  # as --probe scales it
    assert rc2 == 0 and out.splitlines()[1:] == out2.splitlines()[1:]
    assert out.splitlines()[0] == ("photo pixel (200, 150) of the 256x192 photos is pixel "
                                   "(50, 37) of the 64x48 analysis image")
    first = out2.splitlines()[0]
    assert first == ("pixel (50, 37) of the 64x48 analysis image = photo pixel (202, 150) "
                     "of the 256x192 photos (the one nearest its centre; it covers photo "
                     "pixels x 200–203, y 148–151)"), first
    rc, out, err = _inspect(capsys, downscaled, "--photo-pixel", "256,10")
    assert (rc, out) == (2, "") and err == [
        "dynremove: error: --photo-pixel 256,10: outside the 256x192 photos (x in 0..255, "
        "y in 0..191)"], err
    # both in one call (the glossary once): each pixel's verdict, in that order
    rc, out3, err = _inspect(capsys, downscaled, "--pixel", "50,37", "--photo-pixel", "200,150")
    assert rc == 0, err
    _, photo_out, _ = _inspect(capsys, downscaled, "--photo-pixel", "200,150")
    blocks = out3.split("\n\n")
    assert len(blocks) == 2 and blocks[0] + "\n" == out2, out3
    assert vd.LEGEND in photo_out and blocks[1] == photo_out.replace(
        "  " + vd.LEGEND + "\n", ""), out3


def test_without_a_photo_size_the_message_is_unchanged(tmp_path, capsys):
    path = tmp_path / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8)], H=H, W=W, S=S, n_scans=1)
    rc, out, err = _inspect(capsys, path, "--pixel", "200,150")
    assert rc == 2 and err == ["dynremove: error: pixel (200, 150) is outside the 64x48 "
                               "image (x in 0..63, y in 0..47)"], err
    rc, out, _ = _inspect(capsys, path, "--pixel", "5,5")
    assert rc == 0 and "analysis image" not in out


# -- 5. --failures without ground truth ---------------------------------------------------
def test_failures_without_ground_truth_names_the_fix(downscaled, capsys):
    rc, out, err = _inspect(capsys, downscaled, "--failures")
    assert (rc, out) == (2, "") and len(err) == 1, err
    assert "recorded without one (no --gt)" in err[0]
    assert "`dynremove run IMAGES --gt MASK --record FILE.rrd`" in err[0], err


def test_failures_of_an_interrupted_run_say_where_it_ended(tmp_path, capsys):
    rrd = tmp_path / "mid.rrd"
    _cut_sink(rrd, scan=1, after_chunks=2)
    rc, _, err = _inspect(capsys, rrd, "--failures")
    assert rc == 2 and "did not finish (interrupted at scan 1, step " in err[-1], err
    assert "--gt MASK --record" in err[-1]


def test_not_reached_and_photo_helpers():
    info = dict(width=W, height=H, photo_width=4 * W, photo_height=4 * H)
    assert vi.photo_size(info) == (4 * W, 4 * H)
    assert vi.photo_size(dict(width=W, height=H, photo_width=W, photo_height=H)) is None
    assert vi.photo_to_analysis(info, 4 * W - 1, 4 * H - 1) == (W - 1, H - 1)
    assert vi.photo_to_analysis(info, 0, 0) == (0, 0)


# -- trial 18, item 1: candidates, clusters and DBSCAN noise told consistently ------------
def _cand(src, name, cluster, B=0.5):
    return dict(slot=src, src=src, src_name=name, x=10 + src, y=20, B=B, cluster=cluster)


def _camel_decision():
    """The decision camel.rrd recorded at (300, 187): 6 candidates, DBSCAN found one
    cluster (label 0, two members) and called the other four noise (label −1)."""
    names = ["00014", "00024", "00034", "00054", "00064", "00074"]
    cands = [_cand(s, n, -1) for s, n in enumerate(names[:4])]
    cands += [_cand(4, names[4], 0, 0.87), _cand(5, names[5], 0, 0.99)]
    return names, dict(scan=0, step=119980, M=0.11, t_r=0.3, dynamic=True, why=["dynamic"],
                       n_cand=6, n_clusters=1, win_cluster=0, win_weight=1.86,
                       consensus_dist=0.26, chosen_src=5, candidates=cands)


def test_noise_candidates_are_not_counted_in_the_cluster():
    names, d = _camel_decision()
    assert vd.candidate_counts(d) == (
        "6 candidates: 2 in the winner cluster 0 (b_m 1.86: 00064 (14,20) B_l 0.87, "
        "00074 (15,20) B_l 0.99), 4 noise")
    assert vd.cluster_words(None, d, 6) == (
        "winning cluster A_m (cluster 0): 2 of 6 candidates from 2 of 6 sources (00064, "
        "00074); the other 4 DBSCAN noise; b_m = Σ B_l = 1.86; k = 1 cluster")
    # the per-scan maps (any pixel) say |P| 6, k 1, |A_m| 2: the other 4 are noise
    sc = dict(n_candidates=6, n_clusters=1, win_size=2, win_sources=names[4:], b_m=1.86)
    assert "the other 4 DBSCAN noise" in vd.cluster_words(sc, d, 6)
    assert "2 of 6 candidates from 2 of 6 sources, the other 4 DBSCAN noise, b_m 1.86, k 1" \
        in vd.cluster_words(sc, None, 6, short=True)
    # k = 2 without the decision's labels: the split is not known, and not invented
    sc2 = dict(sc, n_clusters=2)
    assert "the other 4 in the 1 other cluster or DBSCAN noise" in vd.cluster_words(sc2, None, 6)
    h = dict(x=300, y=187, t_r=0.3, decisions=[d], scans=[], replacements=[], covered_by=[],
             updates=[], source_names=names, final_dynamic=True, gt=None, stages={},
             size=(360, 640))
    text = vd.format_pixel_history(h)
    assert "6 candidates in 1 cluster" not in text
    assert "step 119980: M 0.11 ≤ t_r 0.30 → DYNAMIC [dynamic]; 6 candidates: 2 in the " \
           "winner cluster 0" in text, text
    all_noise = dict(d, n_clusters=0, win_cluster=-1,
                     candidates=[dict(c, cluster=-1) for c in d["candidates"]])
    # no cluster: where the candidates were is all there is to read (session 54's
    # trial probed an undecided pixel and read only "2 candidates: all noise")
    told = vd.candidate_counts(all_noise)
    assert told.startswith("6 candidates: all noise (") and all(
        f"{c['src_name']} ({c['x']},{c['y']}) B_l {c['B']:.2f}" in told
        for c in d["candidates"]), told
    # a pixel the border votes added gets their meaning in one line (a fresh-user
    # trial found "static in scan 0 … added by the border votes" puzzling)
    h_votes = dict(h, stages={"scan": False, "clean": False, "votes": True, "snap": True})
    text = vd.format_pixel_history(h_votes)
    assert "added by the border votes" in text and vd.VOTES_LEGEND in text, text
    assert vd.VOTES_LEGEND not in vd.format_pixel_history(h)
    # the clean-up step that dropped it is named where no later step put it back
    dropped = dict(h, stages={"scan": True, "clean": False, "votes": False, "snap": False},
                   clean_rule="opening", clean_params={"patch_size": 13, "min_region_px": 64})
    text = vd.format_pixel_history(dropped)
    assert "dropped by the L clean-up (its opening, a disc of 3 px radius: --patch-size " \
           "13 // 4" in text, text
    small = dict(dropped, clean_rule="small")
    assert ("(its region was under --min-region-px 64 px after the opening; a smaller "
            "--min-region-px keeps such regions)") in vd.format_pixel_history(small)
    assert "--no-clean-mask keeps the scans' map as it is" in vd.format_pixel_history(dropped)
    readded = dict(dropped, stages={"scan": True, "clean": False, "votes": False,
                                    "snap": True})
    text = vd.format_pixel_history(readded)
    assert "dropped by the L clean-up; added by GrabCut" in text and "its opening" not in text


def test_history_of_a_recorded_decision_counts_each_dbscan_label(tmp_path, capsys):
    """The fabricated decisions label their candidates 0, 1, 2, 0, … (at odd steps
    the last one −1, noise), the winner cluster 1: every count said matches."""
    path = tmp_path / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8)], H=H, W=W, S=S, n_scans=1)
    h = vi.pixel_history(path, 23, 0)  # step 23: a sampled decision, recorded
    d = h["decisions"][0]
    labels = [c["cluster"] for c in d["candidates"]]
    assert d["win_cluster"] == 1 and labels.count(-1) == 1, labels
    n, win, noise = len(labels), labels.count(1), labels.count(-1)
    rc, out, _ = _inspect(capsys, path, "--pixel", "23,0")
    assert rc == 0
    others = ", ".join(f"{labels.count(c)} in cluster {c}" for c in (0, 2) if c in labels)
    line = next(ln for ln in out.splitlines() if "step " in ln and "candidates:" in ln)
    assert f"{n} candidates: {win} in the winner cluster 1 (b_m " in line, line
    assert line.split("), ", 1)[1].startswith(f"{others}, {noise} noise"), line
    assert (f"{win} of {n} candidates from {win} of {S} sources" in out
            and f"the other {n - win}: {n - win - noise} in 2 other clusters, {noise} "
                "DBSCAN noise" in out), out


# -- trial 18, item 2: --failures says its pixels are the analysis image's ----------------
def test_failures_of_a_downscaled_run_name_the_analysis_image_and_the_photo_pixel(
        tmp_path, capsys):
    from test_viewer_fixtures import gt_for

    gt, _ = gt_for(H, W, S)
    path = tmp_path / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8, gt_mask=gt,
                             photo_size=(4 * W, 4 * H))], H=H, W=W, S=S, n_scans=1)
    rc, out, err = _inspect(capsys, path, "--failures", "--top", "3")
    assert rc == 0 and err == [], err
    # --top without --failures is said to be unused (a trial's went unnoticed)
    rc, _, err2 = _inspect(capsys, path, "--pixel", "1,1", "--top", "3")
    assert rc == 0 and err2 == [
        "dynremove: note: --top counts the failures of --failures: without it, not used"], err2
    items = vi.failures(path, top=3)
    lines = out.splitlines()
    assert len(items) >= 2 and len(lines) == len(items) + 3, out
    info = vi.read_run_info(path)
    for e, line in zip(items, lines[1:]):
        (qx, qy), (px, py) = e["pixel"], e["photo_pixel"]
        assert f"pixel {qx},{qy} (photo {px},{py})  steps " in line, line
        assert (0 <= px < 4 * W and 0 <= py < 4 * H
                and vi.photo_to_analysis(info, px, py) == (qx, qy))  # the same pixel
    assert lines[-2] == ("(pixels of the 64x48 analysis image; the photos are 256x192, "
                         "analysed at ×0.25: --pixel takes these; \"photo X,Y\" is the same "
                         "pixel in the photo)")
    # as --pixel says it
    rc, out, _ = _inspect(capsys, path, "--pixel", "{},{}".format(*items[0]["pixel"]))
    assert out.splitlines()[-1].startswith(
        "  (pixels of the 64x48 analysis image; the photos are 256x192, analysed at ×0.25")


def test_failures_at_the_photos_size_add_no_note(tmp_path, capsys):
    from test_viewer_fixtures import gt_for

    gt, _ = gt_for(H, W, S)
    path = tmp_path / "run.rrd"
    fabricate_run([RerunSink(path, record_every_rows=8, gt_mask=gt)], H=H, W=W, S=S,
                  n_scans=1)
    rc, out, _ = _inspect(capsys, path, "--failures")
    assert rc == 0 and "photo" not in out and "analysis image" not in out, out
    assert all(e["photo_pixel"] is None for e in vi.failures(path))


# -- trial 18, item 3: interrupted after the scans is not "at scan S, step N" -------------
@pytest.mark.parametrize("sig, code", [(KeyboardInterrupt, 130), (errors.Terminated, 143)])
def test_cut_during_the_refinement_is_after_the_scans(tmp_path, capsys, monkeypatch, sig,
                                                      code):
    """A real run (one scan) interrupted in the refinement, after the scan's summary
    was recorded: the trial saw "interrupted at scan 0, step 691199" there."""
    rrd = _run_cut_at("refine_mask", sig, tmp_path, capsys, monkeypatch, code)
    msg = "interrupted after the scans (during the refinement)"
    store = vi.load_store(rrd)
    assert vi.interruption(store) == msg and vi._scan_summary(store, "", 0) is not None
    rc, out, err = _inspect(capsys, rrd, "--pixel", "5,5")
    assert rc == 0 and err == [f"dynremove: note: {rrd.resolve()}: the run was {msg}: "
                               "read what was recorded"], err
    assert out.splitlines()[0].startswith("pixel (5, 5): ") and "step 3071" not in out
    assert out.splitlines()[-1] == f"  no final L: the run was {msg}", out
    rc, _, err = _inspect(capsys, rrd, "--failures")
    assert rc == 2 and f"did not finish ({msg})" in err[-1], err


def test_before_the_scans_a_starting_scan_is_not_said_to_run():
    assert vd.before_scans_message("during scan 0") == \
        "interrupted before the scans began (as scan 0 was starting)"
    assert vd.before_scans_message("after correspondence") == \
        "interrupted before the scans began (after correspondence)"
    assert vd.before_scans_message() == "interrupted before the scans began"


@pytest.mark.parametrize("scans_done, where, said", [
    (1, "after scan 0", "interrupted after scan 0, before scan 1 began"),
    (3, "during fill by selection", "interrupted after the scans (during the fill by selection)"),
])
def test_cut_between_two_scans_and_after_the_last(tmp_path, scans_done, where, said):
    """The sink: a run stopped after scan 0 finished, with more scans to come (the
    fabricated run allows 3 and finds dynamic pixels), then after all three."""
    path = tmp_path / "cut.rrd"
    sink = RerunSink(path, record_every_rows=8)
    fabricate_run([sink], H=H, W=W, S=S, n_scans=3, stop_after_scans=scans_done)
    sink.interrupted(where)
    assert vi.interruption(vi.load_store(path)) == said


def test_recording_of_an_older_sink_cut_after_the_scans(tmp_path):
    """Recordings made before the fix say "interrupted at scan 2, step N" after the
    last scan finished; its summary is recorded, so the reader tells it right."""
    path = tmp_path / "old.rrd"
    sink = RerunSink(path, record_every_rows=8)
    fabricate_run([sink], H=H, W=W, S=S, n_scans=3, stop_after_scans=3)
    step = 3 * H * W - 1
    sink.rec.log(sink.p(vi.P.RUN_INTERRUPTED), rr.AnyValues(
        message=f"interrupted at scan 2, step {step}", scan=2, step=step, scans_began=True),
        static=True)
    sink.close()
    store = vi.load_store(path)
    assert vi.interruption(store) == "interrupted after the scans"
    assert vi._where_cut(store, "", 1, 1, H, W)["message"] == "interrupted after the scans"


def _cut_copies(tmp_path, fractions):
    """(fraction, path) of copies of a fabricated 2-scan recording cut at each
    fraction of its bytes (a full disk, a copy stopped midway)."""
    full = tmp_path / "full.rrd"
    fabricate_run([RerunSink(full, record_every_rows=8)], H=H, W=W, S=S, n_scans=2)
    data = full.read_bytes()
    for frac in fractions:
        cut = tmp_path / f"cut{frac:.2f}.rrd"
        cut.write_bytes(data[:int(frac * len(data))])
        yield frac, cut


def test_a_recording_cut_anywhere_is_read_without_an_internal_error(tmp_path, capsys):
    """A file cut short at any byte (a full disk, a copy stopped midway): inspect reads
    the complete messages and answers, or says there is nothing to inspect (trial:
    a cut before the run info's K broke the decisions' reshape with an internal
    error). Where t_r is not recorded yet, the verdict does not compare with NaN."""
    answered = 0
    for frac, cut in _cut_copies(tmp_path, np.linspace(0.05, 0.95, 19)):
        rc, out, err = _inspect(capsys, cut, "--pixel", "10,10")
        assert rc in (0, 2), (frac, rc, err)
        assert not any("internal error" in e for e in err), (frac, err)
        assert "t_r nan" not in out and "of 0 sources" not in out, (frac, out)
        # a cut inside a scan is said (a trial read "no scan reached it" above the
        # pixel's own history of patches)
        assert "no scan of this recording reached it" not in out, (frac, out)
        answered += rc == 0
    assert answered > 0  # some cuts hold the scans' events


def test_a_recording_cut_anywhere_exports_what_it_holds_or_says_it_is_cut(tmp_path, capsys):
    """export of a file cut short: the GIF of the snapshots it holds, or, where the cut
    lies before any, that the recording is cut short (a trial read "no reference
    snapshots recorded" of a copy stopped midway)."""
    exported = 0
    for frac, cut in _cut_copies(tmp_path, np.linspace(0.1, 0.9, 9)):
        rc = main(["export", str(cut), "--gif", str(tmp_path / "o.gif")])
        err = capsys.readouterr().err
        assert rc in (0, 2) and "internal error" not in err, (frac, err)
        assert "no reference snapshots recorded" not in err, (frac, err)
        if rc == 2 and "snapshots" in err:
            assert "cut short" in err, (frac, err)
        exported += rc == 0
    assert exported > 0


def test_a_kept_pixel_next_to_L_says_the_full_size_fill_may_reach_it(downscaled, capsys):
    """A trial asked about a photo pixel the full-size fill had changed (one analysis
    pixel beyond L) and read "kept". Such pixels now get a line saying so; a kept
    pixel away from L does not."""
    L = vi.read_final_dynamic(downscaled)
    assert L is not None and L.any() and not L.all()
    near = cv2.dilate(L.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~L
    far = ~cv2.dilate(L.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    line = "the fill reaches about one analysis pixel beyond it"
    for where, want in ((near, True), (far, False)):
        ys, xs = np.nonzero(where)
        rc, out, err = _inspect(capsys, downscaled, "--pixel", f"{xs[0]},{ys[0]}")
        assert rc == 0 and (line in out) == want, (where is near, out)
        if want:  # before the verdict that it qualifies (a second trial read past it)
            assert out.index(line) < out.index("not in the final mask"), out
    rc, out, _ = _inspect(capsys, downscaled, "--pixel", f"{np.nonzero(L)[1][0]},"
                                                         f"{np.nonzero(L)[0][0]}")
    assert rc == 0 and line not in out  # in L: removed, explained as such


def test_an_inpainted_pixel_is_not_called_filled_from_a_source():
    """The fill inpaints where no source is free (and the band no source reaches);
    the label map keeps a neighbouring source's label there for the full-size
    output, so the verdict must read the inpainted map, not the label."""
    h = {"final_dynamic": True, "source_names": ["a.png", "b.png"],
         "selection": {"source": 2, "inpainted": 1}}
    assert "inpainted" in vd.outcome_line(h) and "b.png" not in vd.outcome_line(h)
    h["selection"]["inpainted"] = 0
    assert vd.outcome_line(h) == "removed (in the final mask), filled from b.png"


def test_a_pixel_inpainted_because_its_source_was_misplaced_says_so():
    """A piece of the fill whose source did not continue the photo around it
    (``select.misplaced_pieces``) is inpainted although that source showed the pixel
    free: the verdict names the source and why, not "no source shows the
    background"; the reason is not repeated among the other sources'."""
    from dynremove.refine.select import MISPLACED, REASONS

    h = {"final_dynamic": True, "source_names": ["a.png", "b.png"], "x": 1, "y": 1,
         "t_r": 0.3, "decisions": [], "replacements": [], "gt": None,
         "selection": {"source": 2, "inpainted": 1,
                       "reasons": {"a.png": REASONS[5], "b.png": REASONS[MISPLACED]}}}
    assert vd.outcome_line(h) == ("removed (in the final mask), inpainted: b.png's view "
                                  "of it was misplaced")
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")]
    assert len(fill) == 1 and "b.png's view, chosen here, does not continue" in fill[0]
    assert "no source shows" not in fill[0] and "a.png: disagrees" in fill[0]
    assert fill[0].count("misplaced-de") == 1, fill
    plain = vd.plain_words({**h, "decisions": [{"dynamic": True}]})  # scanned dynamic
    assert plain and "b.png shows this spot free, but its view of it does not line up" in plain
    h["selection"]["reasons"]["b.png"] = REASONS[5]  # no source free: as before
    assert "no source shows the background" in vd.outcome_line(h)


def test_a_margin_pixel_written_from_a_source_is_not_called_kept():
    """The fill may write the pixels within --select-margin-px of L; where its value
    stays within --select-tau of the reference's, the pixel is not in the final mask.
    A session-36 trial read "kept (not in the final mask)" and then "filled from
    tim2" for such a pixel: both lines now say it was written, outside the mask."""
    h = {"final_dynamic": False, "source_names": ["a.png", "b.png"],
         "selection": {"source": 2, "inpainted": 0}, "replacements": [], "gt": None}
    first = vd.outcome_line(h)
    assert "written from b.png" in first and "kept" not in first, first
    h.update(x=1, y=1, t_r=0.3, decisions=[])
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")]
    assert len(fill) == 1 and "b.png" in fill[0] and "outside the final mask" in fill[0], fill
    h["final_dynamic"] = True  # in the mask: no such remark
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")]
    assert "outside the final mask" not in fill[0] and "b.png" in fill[0], fill
    h["final_dynamic"] = False
    h["selection"]["source"] = 0
    assert vd.outcome_line(h) == "kept (not in the final mask)"


def test_the_region_rule_is_told_with_its_share_or_as_a_margin_pixel():
    """Code 2 of the region rule inside L gives the region's share against the run's
    --select-complete; on a margin pixel outside L (no region, no share) it says the
    pixel only continued a region kept whole."""
    h = {"final_dynamic": False, "source_names": ["a.png", "b.png"], "replacements": [],
         "gt": None, "x": 1, "y": 1, "t_r": 0.3, "decisions": [],
         "selection": {"source": 0, "completed": 2, "region_share": 0.25,
                       "region_rule": {"select_complete": 0.7, "select_complete_px": 6}}}
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")][0]
    assert "replaced 25 % of its region of L" in fill and "under 30 %" in fill, fill
    h["selection"]["region_share"] = None
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")][0]
    assert "margin outside L" in fill and "%" not in fill, fill
    # a kept pixel of a region replaced mostly, beyond the reach: the reach is named
    h["selection"].update(completed=0, region_share=0.8)
    assert "--select-complete-px 6 px" in vd.region_words(h["selection"])


def test_a_region_kept_because_its_fill_did_not_fit_is_told_so():
    """Code 3 of ``completed`` (``select.misfit_regions``): the fill line says the
    reference was kept because the blend would have shifted the fill by more than
    light does, with what it would have added, and the static test line agrees."""
    h = {"final_dynamic": False, "source_names": ["a.png", "b.png"], "replacements": [],
         "gt": None, "x": 1, "y": 1, "t_r": 0.3, "decisions": [],
         "selection": {"source": 0, "completed": 3, "offset": [43, 33, 35],
                       "evidence": {"a.png": 0, "b.png": 0}, "static_need": 2,
                       "explained": 0, "ref_mover_p": 0.8}}
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")][0]
    assert fill.startswith("fill: reference kept") and "--select-misfit-levels" in fill \
        and "+43/+33/+35" in fill and "mean P(mover) under 0.6" in fill, fill
    static = vd.static_test_line(h)
    assert "the fill did not fit the photo around its region" in static, static
    assert vd.outcome_line(h) == "kept (not in the final mask)"


def test_a_relit_pixel_s_fill_line_says_it_was_relit_not_kept():
    """A pixel of the faint shade beside a removed mover (``refine.shade``): the first
    line says it was relit, and so does the fill line (a trial read "relit" above
    and "fill: reference kept" below as a contradiction)."""
    h = {"final_dynamic": False, "source_names": ["a.png", "b.png"], "replacements": [],
         "gt": None, "x": 1, "y": 1, "t_r": 0.3, "decisions": [],
         "selection": {"source": 0, "relit": 1, "relight_l": 6.5}}
    assert vd.outcome_line(h).startswith("kept (not in the final mask), relit")
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")][0]
    assert "relit" in fill and "+6.5 CIE L*" in fill and "reference kept" not in fill, fill
    assert "changed by under --select-tau" in fill, fill


def test_a_mover_kept_whole_because_only_part_of_it_could_go_is_told_so():
    """Code 4 of ``completed`` (``select.partial_movers``): the fill line, the static
    test line, the region's share and ``--failures`` say that the reference was kept
    with the rest of a mover that the fill could replace only in part."""
    import numpy as np

    from viewer import inspect as vi

    h = {"final_dynamic": False, "source_names": ["a.png", "b.png"], "replacements": [],
         "gt": None, "x": 1, "y": 1, "t_r": 0.3, "decisions": [],
         "selection": {"source": 0, "completed": 4, "region_share": 0.46,
                       "region_rule": {"select_complete": 0.7, "select_complete_px": 6},
                       "evidence": {"a.png": 0, "b.png": 0}, "static_need": 2,
                       "explained": 0, "ref_mover_p": 0.8}}
    fill = [ln for ln in vd.verdict_lines(h) if ln.startswith("fill:")][0]
    assert fill.startswith("fill: reference kept") and "--select-keep-partial" in fill \
        and "replaced 46 % of its region of L" in fill and "rest of a mover" in fill, fill
    # (said once: a trial found the rule's reason three times in one answer)
    assert fill.count("--select-keep-partial") == 1, fill
    static = vd.static_test_line(h)
    assert "rest of its mover" in static and "--select-keep-partial" not in static, static
    region = np.ones((4, 4), bool)
    st = {n: np.zeros((4, 4), bool) for n in vi.STAGE_ORDER}
    for n in ("scan", "clean", "votes", "snap"):
        st[n][:] = True
    comp = np.full((4, 4), 4, np.uint8)
    why, share = vi.failure_cause("FN", region, st, {"completed": comp})
    assert (why, share) == ("partial", 1.0)
    assert "--select-keep-partial" in vd.failure_words(why, share)


def test_what_the_cut_weighed_is_told_with_the_consensus_or_the_suspect():
    """Where the photomontage kept the reference as the cheapest label, inspect gives
    the two data costs and, where the reference took part in the fill's colour
    consensus, the two supports that set them (a trial asked why the reference won)."""
    sel = {"data_cost": {"reference": 0.0, "best_source": 42.6},
           "support": {"reference": 3.24, "sources": 1.71}}
    w = vd.weighed_words(sel)
    assert "reference 0.0" in w and "cheapest source 42.6" in w and "3.24" in w \
        and "1.71" in w, w
    # in plain words, as the trial of session 54 asked; the three-photo tie said so
    assert "in short: the other photos do not agree with one another" in w \
        and "three photos" not in w, w
    assert "two sources that disagree with each other cannot outvote" in \
        vd.weighed_words(sel, 2)
    assert "in short" not in vd.weighed_words(
        {**sel, "support": {"reference": 0.5, "sources": 2.0}})
    assert "most backing" in w and "ties" not in w, w
    # a tie, as printed (1.49 against 1.49: a trial read "the most backing" there)
    tie = vd.weighed_words({**sel, "support": {"reference": 1.4912, "sources": 1.4876}})
    assert "ties with the best-supported source, and a tie keeps the reference" in tie \
        and "most backing" not in tie, tie
    sel["support"] = {}
    w = vd.weighed_words(sel)
    assert "--select-ref-cost" in w and "here nothing" in w, w  # a three-photo rule set it to 0
    sel["data_cost"] = {"reference": 30.0}
    assert "here nothing" not in vd.weighed_words(sel)
    assert "no source may fill it" in vd.weighed_words(sel)
    assert vd.weighed_words({}) is None


def test_a_reference_kept_against_a_cheaper_source_is_told_as_the_seams_doing():
    """Where the reference's data cost is the higher one and the cut kept it anyway,
    inspect does not call it "the cheapest label" (a fresh-user trial: 24.8 against
    7.2 and "the cheapest label here"); where it is the lower, it does."""
    h = dict(x=1, y=1, final_dynamic=False, source_names=["a", "b"],
             selection=dict(evidence={"a": 1}, static_need=1, explained=0, ref_mover_p=0.7,
                            source=0, completed=0,
                            data_cost={"reference": 24.8, "best_source": 7.2},
                            support={"reference": 0.57, "sources": 0.94}))
    text = vd.static_test_line(h)
    assert "cheapest label" not in text and "--select-beta" in text, text
    h["selection"]["data_cost"] = {"reference": 3.0, "best_source": 7.2}
    assert "it was the cheapest label here" in vd.static_test_line(h)


def test_one_source_s_epipolar_evidence_is_told_when_it_counted_alone():
    """Session 52: the epipolar search's evidence counts from one source where no
    other source contradicts it. Inspect says so where it did (one source found it
    on its line, the other's match differs in the movers' colours), and not where two
    sources found it (the rule of two)."""
    def line(evidence):
        h = dict(x=1, y=1, final_dynamic=False, source_names=list(evidence),
                 selection=dict(evidence=evidence, static_need=1, explained=1,
                                ref_mover_p=0.3, source=0, completed=0))
        return vd.static_test_line(h)

    alone = line({"a": 2, "b": 5})
    assert "kept as static" in alone and "counts from one source here" in alone, alone
    # (not "no other source contradicts it" beside b's "nothing alike": the rule)
    assert "a copy of the mover in that photo" in alone and "contradicts it" not in alone, alone
    # (an assumption, said as one: a trial found the man in one photo only, and the
    # words had told of "its own copy of the mover" in another)
    assert "it assumes one" in alone, alone
    assert "counts from one source" not in line({"a": 2, "b": 2})
    # with --select-search-against-de recorded, the excuse names it, and so does the
    # contradiction where it held (b found nothing near the content on its line)
    def line_at(evidence, explained):
        h = dict(x=1, y=1, final_dynamic=False, source_names=list(evidence),
                 selection=dict(evidence=evidence, static_need=1, explained=explained,
                                ref_mover_p=0.3, source=0, completed=0,
                                thresholds={"select_search_de": 8.0,
                                            "select_search_against_de": 16.0}))
        return vd.static_test_line(h)

    assert "something within ΔE 16.0 on its epipolar line" in line_at({"a": 2, "b": 5}, 1)
    against = line_at({"a": 3, "b": 5}, 0)
    assert "nothing within ΔE 16.0 on its line" in against, against


def test_a_pixel_the_fill_added_names_the_rule_that_did():
    """A fresh-user trial read three rules offered for one pixel ("--select-grow-px,
    --select-complete, or at the frame's edge"). The region rule is named from the
    recorded ``completed`` map; the edge only within a patch of the frame's edge."""
    def line_for(x, y, completed):
        h = {"final_dynamic": True, "source_names": ["a.png", "b.png"], "replacements": [],
             "gt": None, "x": x, "y": y, "t_r": 0.3, "decisions": [], "size": (100, 200),
             "patch_size": 13,
             "stages": {"scan": False, "clean": False, "votes": False, "snap": False,
                        "select": True},
             "selection": {"source": 1, "inpainted": 0, "completed": completed}}
        return next(ln for ln in vd.verdict_lines(h) if ln.startswith("after the scans"))
    inner = line_for(100, 50, 0)
    assert "--select-grow-px" in inner and "--select-complete" not in inner, inner
    assert "frame's edge" not in inner, inner
    region = line_for(100, 50, 1)
    assert "--select-complete" in region and "--select-grow-px" not in region, region
    edge = line_for(3, 50, 0)
    assert "frame's edge" in edge and "--select-grow-px" in edge, edge


def test_a_pixel_the_fill_put_back_says_so():
    """A fresh-user trial read "dropped by GrabCut (snap to edges); in the final mask:
    yes" as a contradiction: the fill by selection had put the pixel back. The line
    now names that step, and the lingering mover when it was one."""
    h = {"final_dynamic": True, "source_names": ["a.png", "b.png"], "replacements": [],
         "gt": None, "x": 1, "y": 1, "t_r": 0.3, "decisions": [],
         "stages": {"scan": True, "clean": True, "votes": True, "snap": False,
                    "select": True},
         "selection": {"source": 1, "inpainted": 0}}
    line = next(ln for ln in vd.verdict_lines(h) if ln.startswith("after the scans"))
    assert "dropped by GrabCut" in line and "added back by the fill by selection" in line
    assert "--select-grow-px" in line and line.endswith("in the final mask: yes"), line
    h["selection"]["lingering"] = 1
    line = next(ln for ln in vd.verdict_lines(h) if ln.startswith("after the scans"))
    assert "lingered" in line and "--select-grow-px" not in line, line
    h.update(final_dynamic=False, stages={"scan": True, "clean": True, "votes": True,
                                          "snap": True, "select": False},
             selection={"source": 0, "inpainted": 0})
    line = next(ln for ln in vd.verdict_lines(h) if ln.startswith("after the scans"))
    assert "left out by the fill by selection" in line and line.endswith("no"), line
    h["stages"] = {"scan": True, "clean": True, "votes": True, "snap": True, "select": True}
    line = next(ln for ln in vd.verdict_lines(h) if ln.startswith("after the scans"))
    assert "fill by selection" not in line, line  # unchanged by the fill: not named


def test_long_lines_are_wrapped_for_a_terminal_and_whole_when_piped(monkeypatch):
    """inspect's reasons run to 500 characters: on a terminal they wrap at words, each
    continuation indented under its line; piped (grep), the lines stay whole."""
    line = "  source 3: " + "agrees with the fill's colour consensus " * 8
    text = "pixel (5, 7): static\n" + line + "\nend"
    wrapped = commands.for_terminal(text, 60).split("\n")
    assert wrapped[0] == "pixel (5, 7): static" and wrapped[-1] == "end"
    body = wrapped[1:-1]
    assert len(body) > 4 and all(len(w) <= 60 for w in body)
    assert body[0].startswith("  source 3: ") and all(w.startswith("    ") for w in body[1:])
    assert " ".join(w.strip() for w in body) == line.strip()  # no word cut, none lost
    monkeypatch.setattr("sys.stdout.isatty", lambda: False)
    assert commands.for_terminal(text) == text


# -- session 50 trial, items 3 and 4: the paper preset's patch writes and its scan cap -----
@pytest.fixture(scope="module")
def paper_rrd(tmp_path_factory):
    """The paper preset (patch writes are the output) on a small synthetic scene,
    recorded, with two scans."""
    from dynremove import remove_dynamic
    from dynremove.params import preset

    scene = synth.make_scene(seed=2, n_views=4, size=(72, 96))
    path = tmp_path_factory.mktemp("paper") / "paper.rrd"
    with pytest.warns(UserWarning):
        res = remove_dynamic(scene.images, ref=scene.ref_index, sink=RerunSink(path),
                             params=preset("paper").replace(max_scans=2))
    return scene, res, path


def test_the_fill_line_of_a_patch_write_names_the_last_write_and_its_pixel(paper_rrd):
    """Where later patches covered a pixel, the clean photo shows the last one's
    source pixel, and the "fill:" line names that write and that pixel (a trial
    read the first write at the pixel, from another source)."""
    scene, res, path = paper_rrd
    srcs = [i for i in range(len(scene.images)) if i != scene.ref_index]
    ys, xs = np.nonzero(res.dynamic)
    checked = 0
    for y, x in list(zip(ys, xs))[:: max(1, len(ys) // 25)]:
        h = vi.pixel_history(path, int(x), int(y))
        writes = h["replacements"] + h["covered_by"]
        if len(writes) < 2:
            continue
        last = max(writes, key=lambda r: r["step"])
        sx, sy = last["src_x"] + x - last["x"], last["src_y"] + y - last["y"]
        fill = next(ln for ln in vd.verdict_lines(h) if ln.startswith("fill:"))
        assert f"{last['src_name']}'s pixel ({sx},{sy})" in fill, fill
        assert f"step {last['step']}" in fill and f"last of {len(writes)} writes" in fill, fill
        # what the clean photo shows is that source's pixel (the set's exposures match)
        np.testing.assert_array_equal(res.clean[y, x], scene.images[srcs[last["src"]]][sy, sx])
        checked += 1
    assert checked >= 5, "the scene must have pixels that several patches wrote"


def test_the_paper_preset_says_when_its_scans_stop_at_the_cap(paper_rrd):
    """The paper's scans alternate until one calls no pixel dynamic; where
    --max-scans stops them first, a note says so with the last scan's count."""
    _, res, _ = paper_rrd
    last = int(res.scans[-1]["n_dynamic"])
    assert len(res.scans) == 2 and last > 0, "the scene must still flag pixels in scan 2"
    note = next(w for w in res.warnings if w.startswith("the scans stopped"))
    assert f"--max-scans 2 while the last still called {last} px dynamic" in note, note


def test_offsets_at_the_recording_s_clip_are_not_read_as_measurements():
    """The recording holds the blend's offsets as 128 + levels clipped to 0..255: a
    trial read "-128/-128/-128" as a measured value; at the clip the words say ≤ / ≥."""
    from viewer.verdict import levels_words

    assert levels_words([-128, 5, 127]) == "≤ -128/+5/≥ +127"
    assert levels_words([-3, 0, 12]) == "-3/+0/+12"


def test_a_fill_the_blend_took_back_to_the_mover_is_said_so():
    """A fresh-user trial (tim1, tim3, tim5; tim3 the reference) read "removed (in the
    final mask), filled from tim1" at a pixel still the cup's red: the source's sample
    was table wood, and the blend's offset, asked for by a ring lying on the cup's
    kept parts, took it back to red. The headline now says so; an exposure offset
    (a few levels) or a fill far from the input adds nothing."""
    def head(clean, ref, offset):
        h = {"final_dynamic": True, "source_names": ["tim1.jpg", "tim5.jpg"],
             "selection": {"source": 1, "inpainted": 0, "offset": offset},
             "clean_input": (clean, ref)}
        return vd.outcome_line(h)
    back = head([67, 70, 160], [43, 44, 148], [-49, -72, -18])
    assert back.startswith("removed (in the final mask), filled from tim1.jpg, but the "
                           "blend's correction took it back near what the reference showed"), back
    assert "ΔE 10.8 from the input" in back, back
    # table wood written over the cup, with an exposure offset: removed, no more
    assert head([118, 143, 180], [43, 44, 148], [3, 2, 3]) == \
        "removed (in the final mask), filled from tim1.jpg"
    # a recording without the images (cut short): the headline as before
    h = {"final_dynamic": True, "source_names": ["a", "b"],
         "selection": {"source": 2, "inpainted": 0, "offset": [-49, -72, -18]}}
    assert vd.outcome_line(h) == "removed (in the final mask), filled from b"


def test_a_pixel_no_other_photo_sees_is_not_said_to_disagree():
    """At the frame's edge a pixel's matches fall outside the other photos: the scans
    leave it undecided with no candidate, or one. A trial read "its matches in the
    other photos agree on nothing" there, where nothing was compared; the plain
    words now say that no other photo (or only one match) sees the spot, and keep
    the old words for matches that do disagree."""
    def history(n):
        return {"final_dynamic": False, "source_names": ["a.png", "b.png", "c.png"],
                "replacements": [], "gt": None, "x": 0, "y": 0, "t_r": 0.3,
                "decisions": [], "selection": {"source": 0},
                "scans": [dict(verdict="undecided", win_sources=None, n_candidates=n,
                               n_clusters=0, win_size=0, b_m=0.0)]}

    none = vd.plain_words(history(0))
    assert none.startswith("no other photo sees this spot") and "agree" not in none, none
    one = vd.plain_words(history(1))
    assert one.startswith("only one of its matches falls inside another photo"), one
    assert vd.plain_words(history(5)).startswith(
        "its matches in the other photos agree on nothing")


def test_photo_pixel_reads_the_written_mask_of_the_runs_output_folder(tmp_path, capsys):
    """A trial's `inspect --photo-pixel` said "kept" for a photo pixel that the
    written dynamic_mask.png holds (the mask is refined on the full-size photo's
    edges). The recording names the run's output folder; where its mask and the
    analysis verdict differ, inspect says what the written mask holds. Once the
    folder holds another run's outputs, it is not read (the hedged note stays)."""
    sc = synth.make_scene(seed=0, n_views=4, size=(192, 256), n_objects=1)
    d = tmp_path / "s"
    d.mkdir()
    for i, im in enumerate(sc.images):
        assert cv2.imwrite(str(d / f"v{i}.png"), im)
    out, rec = tmp_path / "out", tmp_path / "run.rrd"
    assert main(["run", str(d), "--max-side", "128", "--max-scans", "1", "--out", str(out),
                 "--record", str(rec), "-q"]) == 0
    capsys.readouterr()
    info = vi.read_run_info(rec)
    assert info["output_dir"] == str(out.resolve())
    written = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    L = vi.read_final_dynamic(rec)
    ys, xs = np.mgrid[:written.shape[0], :written.shape[1]]
    ax = [vi.photo_to_analysis(info, int(x), int(y)) for x, y in zip(xs.ravel(), ys.ravel())]
    analysis = np.array([L[a[1], a[0]] for a in ax]).reshape(written.shape)
    diff = np.argwhere(written & ~analysis)
    assert len(diff), "the full-size mask adds no pixel here: pick another scene"
    y, x = map(int, diff[0])
    rc, text, err = _inspect(capsys, rec, "--photo-pixel", f"{x},{y}")
    assert rc == 0, err
    assert (f"NOTE: {out.resolve()}/dynamic_mask.png holds this photo pixel: at full size it "
            "is replaced in clean.png") in text and "kept (not in the final mask)" in text, text
    same = np.argwhere(written & analysis)
    y2, x2 = map(int, same[len(same) // 2])
    rc, text, _ = _inspect(capsys, rec, "--photo-pixel", f"{x2},{y2}")
    assert rc == 0 and "NOTE:" not in text, text
    # another run's outputs in the folder: not read (the analysis image's hedge instead)
    rep = out / "report.json"
    report = json.loads(rep.read_text())
    report["recording"] = str(tmp_path / "other.rrd")
    rep.write_text(json.dumps(report))
    rc, text, _ = _inspect(capsys, rec, "--photo-pixel", f"{x},{y}")
    assert rc == 0 and "dynamic_mask.png holds" not in text, text

"""Tests of the viewer package against fabricated runs (no algorithm needed)."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from test_viewer_fixtures import ROOT, fabricate_run, gt_for  # noqa: E402

from dynremove import events as ev  # noqa: E402
from viewer import RerunSink, make_blueprint, make_compare_blueprint  # noqa: E402
from viewer.sink import STEP_GRID  # noqa: E402
from viewer import export, serve  # noqa: E402
from viewer import inspect as vi  # noqa: E402
from viewer import verdict as vd  # noqa: E402
from viewer import paths as P  # noqa: E402

H, W, S = 48, 64, 3
KINDS = ("decisions", "replacements", "updates")


def cli_env(tmp: Path) -> dict[str, str]:
    """Environment for the rerun CLI: private HOME, analytics off."""
    home = tmp / "home"
    home.mkdir(exist_ok=True)
    env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
           "XDG_DATA_HOME": str(home / ".local/share"), "XDG_CACHE_HOME": str(home / ".cache")}
    subprocess.run([serve.rerun_binary(), "analytics", "disable"], env=env,
                   capture_output=True, timeout=60)
    return env


def counts_of(mem: ev.MemorySink) -> dict[int, dict[str, int]]:
    out: dict[int, dict[str, int]] = {}
    for kind in KINDS:
        arr = getattr(mem, kind)
        for s in np.unique(arr["scan"]).tolist():
            out.setdefault(s, dict.fromkeys(KINDS, 0))[kind] = int((arr["scan"] == s).sum())
    return dict(sorted(out.items()))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One fabricated run with ground truth, recorded every 5 rows."""
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    gt, bg = gt_for(H, W, S)
    sink = RerunSink(path, record_every_rows=5, gt_mask=gt, gt_background=bg,
                     recording_id="test-run")
    info, result, truth = fabricate_run([sink], H=H, W=W, S=S, n_scans=3)
    return dict(path=path, info=info, result=result, truth=truth, sink=sink, gt=gt)


@pytest.fixture(scope="module")
def run_full(tmp_path_factory):
    """The same fabricated run at ``detail="full"``."""
    path = tmp_path_factory.mktemp("rec") / "full.rrd"
    gt, bg = gt_for(H, W, S)
    sink = RerunSink(path, record_every_rows=5, gt_mask=gt, gt_background=bg,
                     recording_id="test-run-full", detail="full")
    info, result, truth = fabricate_run([sink], H=H, W=W, S=S, n_scans=3)
    return dict(path=path, info=info, result=result, truth=truth, sink=sink, gt=gt)


def _source_overlay_steps(d: np.ndarray, detail: str) -> set[int]:
    """Steps whose decision gets candidates and q* in the source views: all at
    "full"; at "default" the probes, sampled static ones and the dynamic ones at
    x, y multiples of STEP_GRID (written out here, not taken from the sink)."""
    if detail == "full":
        return set(d["step"].tolist())
    g = STEP_GRID
    keep = [int(e["step"]) for e in d
            if (int(e["why"]) & (ev.WHY_PROBE | ev.WHY_SAMPLE)) or not e["dynamic"]
            or (int(e["x"]) % g == 0 and int(e["y"]) % g == 0)]
    return set(keep)


# -- contents ----------------------------------------------------------------------
def test_file_written_and_counts_match(run):
    assert run["path"].stat().st_size > 0
    assert vi.read_counts(run["path"]) == counts_of(run["truth"])
    assert len(run["truth"].decisions) > 200  # the fabricated run is not trivial


@pytest.mark.parametrize("kind", KINDS)
def test_events_round_trip_exactly(run, kind):
    got = vi.read_events(run["path"], kind)
    want = getattr(run["truth"], kind)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


def test_replay_reproduces_final_image(run):
    info = run["info"]
    final = vi.read_final_image(run["path"])
    assert final is not None
    np.testing.assert_array_equal(final, run["result"].clean)
    replayed = ev.replay_replacements(info.images[info.ref_index],
                                      [info.images[i] for i in info.source_indices],
                                      vi.read_replacements(run["path"]),
                                      patch_size=3, write="patch")
    np.testing.assert_array_equal(replayed, final)
    assert (replayed != info.images[info.ref_index]).any()
    np.testing.assert_array_equal(vi.read_final_dynamic(run["path"]), run["result"].dynamic)


def test_run_info_is_static(run):
    info = vi.read_run_info(run["path"])
    assert info["K"] == 2 * S and (info["height"], info["width"]) == (H, W)
    assert info["names"] == run["info"].names
    assert info["source_names"] == P.entity_names(run["info"].names[1:])
    assert info["params"]["t_r"] == pytest.approx(0.3)
    assert info["record_every_rows"] == 5


def test_buffered_columns_round_trip_with_one_row_chunks(tmp_path):
    path = tmp_path / "rows.rrd"
    sink = RerunSink(path, record_every_rows=7)
    sink.MAX_PENDING_EVENTS = 10  # also exercise the early flush
    _, _, truth = fabricate_run([sink], H=H, W=W, S=S, n_scans=2, rows_per_chunk=1)
    for kind in KINDS:
        np.testing.assert_array_equal(vi.read_events(path, kind), getattr(truth, kind))


def test_rrd_verify_accepts_file(run, tmp_path):
    r = subprocess.run([serve.rerun_binary(), "rrd", "verify", str(run["path"])],
                       env=cli_env(tmp_path), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("every", [1, 3])
def test_a_run_snapshots_every_n_rows_as_asked(tmp_path, every):
    """A run recorded with ``record_every_rows`` 1 (the teaching demo's) or 3: one
    reference snapshot per that many rows, at their steps (a trial found one every 2-3
    rows for 1: the scan's chunks of H // 50 rows set the cadence)."""
    from dynremove import remove_dynamic
    from dynremove.evaluation import synth

    sc = synth.make_scene(seed=1, n_views=4, size=(120, 160), n_objects=1)
    path = tmp_path / "e.rrd"
    remove_dynamic(sc.images, ref=sc.ref_index, params="paper",
                   sink=RerunSink(path, record_every_rows=every, skip_unchanged_images=False),
                   names=sc.names)
    steps = [st for st, _ in vi.read_snapshots(path)["image"]]
    H, W = 120, 160
    first_scan = [st for st in steps if 0 < st < H * W]
    assert first_scan == [r * W - 1 for r in range(every, H + 1, every)], first_scan[:8]


def test_snapshot_cadence(tmp_path):
    every = 6
    path = tmp_path / "cadence.rrd"
    sink = RerunSink(path, record_every_rows=every, skip_unchanged_images=False)
    n_scans = 2
    fabricate_run([sink], H=H, W=W, S=S, n_scans=n_scans, rows_per_chunk=2)
    snaps = vi.read_snapshots(path)
    per_scan = H // every  # one snapshot per `every` rows; the last one is the scan's end
    # + the initial image at step 0 and the final result
    assert len(snaps["image"]) == n_scans * per_scan + 2
    # M: also one at each scan start
    assert len(snaps["M"]) == n_scans * (per_scan + 1)
    steps = [s for s, _ in snaps["image"]]
    assert steps == sorted(steps) and len(set(steps)) == len(steps)
    # default: unchanged reference images are skipped, M keeps the cadence
    path2 = tmp_path / "cadence2.rrd"
    fabricate_run([RerunSink(path2, record_every_rows=every)], H=H, W=W, S=S,
                  n_scans=n_scans, rows_per_chunk=2)
    snaps2 = vi.read_snapshots(path2)
    assert 2 < len(snaps2["image"]) < len(snaps["image"])
    assert len(snaps2["M"]) == len(snaps["M"])


def test_default_cadence_is_about_50_per_scan(tmp_path):
    path = tmp_path / "c.rrd"
    sink = RerunSink(path, skip_unchanged_images=False)
    fabricate_run([sink], H=200, W=24, S=2, n_scans=1, rows_per_chunk=3, sample_every=97)
    assert sink.every == 4
    assert 45 <= len(vi.read_snapshots(path)["M"]) <= 55


def _latest_at(path, entity: str, column: str, steps) -> list[list]:
    """What the viewer shows at each of ``steps`` (latest row at or before it)."""
    from rerun.chunk import RrdReader

    t = RrdReader(str(path)).stream().collect().reader(
        index="step", contents=entity).to_arrow_table()
    rows = sorted((s, v) for s, v in zip(t.column("step").to_pylist(),
                                          t.column(f"{entity}:{column}").to_pylist())
                  if s is not None and v is not None)
    at = np.searchsorted([s for s, _ in rows], steps, side="right") - 1
    return [rows[i][1] if i >= 0 else [] for i in at]


@pytest.mark.parametrize("detail", ["default", "full"])
def test_per_source_overlays_show_exactly_the_current_step(run, run_full, detail):
    """Per-source candidates and q* boxes have rows only where they change, yet at
    every step they show that step's data, or nothing: at every recorded decision
    ("full"), or at the probes, sampled static and grid dynamic ones ("default")."""
    run = run_full if detail == "full" else run
    d, r = run["truth"].decisions, run["truth"].replacements
    shown = _source_overlay_steps(d, detail)
    assert 0 < len(shown) <= len(d) and (len(shown) < len(d)) == (detail == "default")
    steps = np.arange(3 * H * W)
    names = P.entity_names([run["info"].names[i] for i in run["info"].source_indices])
    for s, name in enumerate(names):
        cand = _latest_at(run["path"], f"/sources/{name}/candidates", "Points2D:positions",
                          steps)
        want = {}
        for e in d:
            m = e["cand_src"] == s
            if m.any() and int(e["step"]) in shown:
                want[int(e["step"])] = (e["cand_xy"][m] + 0.5).tolist()
        assert want
        for t in steps.tolist():
            assert cand[t] == want.get(t, []), f"{name} candidates at step {t}"
        boxes = _latest_at(run["path"], f"/sources/{name}/chosen_patch", "Boxes2D:centers",
                           steps)
        want = {int(e["step"]): [[e["src_x"] + 0.5, e["src_y"] + 0.5]] for e in r
                if e["src"] == s and int(e["step"]) in shown}
        assert want
        for t in steps.tolist():
            assert boxes[t] == want.get(t, []), f"{name} q* at step {t}"
        n_rows = len(_table_steps(run["path"], f"/sources/{name}/chosen_patch"))
        assert n_rows <= 2 * len(want)  # only where it changes


@pytest.mark.parametrize("detail", ["default", "full"])
def test_reference_overlays_at_every_recorded_decision(run, run_full, detail):
    """The current marker and the chosen patch on the reference follow every
    recorded decision and replacement at both details, and nothing in between."""
    run = run_full if detail == "full" else run
    d, r = run["truth"].decisions, run["truth"].replacements
    steps = np.arange(3 * H * W)
    cur = _latest_at(run["path"], "/reference/current", "Points2D:positions", steps)
    want = {int(e["step"]): [[e["x"] + 0.5, e["y"] + 0.5]] for e in d}
    for t in steps.tolist():
        assert cur[t] == want.get(t, []), f"current marker at step {t}"
    box = _latest_at(run["path"], "/reference/chosen_patch", "Boxes2D:centers", steps)
    want = {int(e["step"]): [[e["x"] + 0.5, e["y"] + 0.5]] for e in r}
    for t in steps.tolist():
        assert box[t] == want.get(t, []), f"chosen patch at step {t}"


def _table_steps(path, entity: str) -> list[int]:
    from rerun.chunk import RrdReader

    t = RrdReader(str(path)).stream().collect().reader(
        index="step", contents=entity).to_arrow_table()
    return [s for s in t.column("step").to_pylist() if s is not None]


# -- pixel history, failures --------------------------------------------------------
def test_pixel_history_of_dynamic_pixel(run):
    d = run["truth"].decisions
    dyn = d[d["dynamic"]][7]
    x, y = int(dyn["x"]), int(dyn["y"])
    h = vi.pixel_history(run["path"], x, y)
    want = d[(d["x"] == x) & (d["y"] == y)]
    assert [e["step"] for e in h["decisions"]] == want["step"].tolist()
    first = h["decisions"][0]
    assert first["dynamic"] and first["M"] == pytest.approx(float(dyn["M"]))
    assert len(first["candidates"]) == int((dyn["cand_src"] >= 0).sum())
    assert h["replacements"] and h["replacements"][0]["step"] == int(dyn["step"])
    assert len(h["updates"]) == S * len(h["replacements"])
    assert h["final_dynamic"] is True
    text = vd.format_pixel_history(h)
    assert f"step {int(dyn['step'])}" in text and "→ DYNAMIC" in text
    assert "the scan wrote the patch of" in text and "winner cluster" in text
    assert text.splitlines()[0] == f"pixel ({x}, {y}): removed (in the final mask)"
    assert text.splitlines()[1].startswith("  in plain words: the photos whose matches the scans")
    assert text.splitlines()[2].startswith("  the scans: dynamic in scan 0")
    assert vd.LEGEND in text  # the symbols it uses, in words


def test_pixel_history_of_probe(run):
    h = vi.pixel_history(run["path"], 10, 7)
    assert len(h["decisions"]) == 3  # one per scan
    assert all("probe" in e["why"] and not e["dynamic"] for e in h["decisions"])
    assert "static" in vd.format_pixel_history(h)
    empty = vi.pixel_history(run["path"], 0, 1)
    text = vd.format_pixel_history(empty)  # never recorded: answered from the scan maps
    assert "not recorded at this pixel" in text and "--probe 0,1" in text
    # a recording without the core's cluster maps (older cores, fabricated runs)
    assert empty["scans"] and all(sc[k] is None for sc in empty["scans"] for k in (
        "n_candidates", "n_clusters", "win_size", "win_sources", "b_m"))
    assert all(m["b_m"] is None for m in vi.read_scan_maps(run["path"]))
    assert text.splitlines()[0] == "pixel (0, 1): kept (not in the final mask)"
    assert text.splitlines()[1].startswith("  in plain words: ")
    assert text.splitlines()[2].startswith("  the scans: static in every scan")


def test_failures_against_ground_truth(run):
    items = vi.failures(run["path"], top=5)
    L, gt = run["result"].dynamic, run["gt"]
    assert {e["kind"] for e in items} == {"FP", "FN"}
    assert sum(e["area"] for e in items) == int((L != gt).sum())
    for e in items:
        x, y = e["pixel"]
        assert L[y, x] == (e["kind"] == "FP") and gt[y, x] == (e["kind"] == "FN")
    assert "FP" in vd.format_failures(items)
    # the region's most wrongly confident M is read from every scan's M map, which
    # holds every pixel, not from the recorded decisions (mostly the dynamic ones:
    # a trial's missed region read "highest M 0.29" where its pixels had up to 0.95)
    maps = vi.read_scan_maps(run["path"])
    assert maps
    for e in items:
        wrong = (L & ~gt) if e["kind"] == "FP" else (~L & gt)
        lab = cv2.connectedComponents(wrong.astype(np.uint8), connectivity=8)[1]
        region = lab == lab[e["pixel"][1], e["pixel"][0]]
        vals = np.concatenate([m["M"][region] for m in maps])
        vals = vals[np.isfinite(vals)]
        if e["worst"] is None:
            assert len(vals) == 0
            continue
        want = vals.min() if e["kind"] == "FP" else vals.max()
        assert e["worst"]["M"] == pytest.approx(float(want), abs=1e-6)


# -- robustness ----------------------------------------------------------------------
class _Scribbler:
    """Forwards to a sink, then overwrites the caller's buffers (aliasing check)."""

    enabled = True

    def __init__(self, inner):
        self.inner, self.kept = inner, []

    def start(self, info):
        self.inner.start(info)

    def scan_started(self, scan, direction, state):
        self.inner.scan_started(scan, direction, state)

    def chunk(self, events, state):
        self.inner.chunk(events, state)
        self.kept.append(copy.deepcopy(events))
        for arr in (events.decisions, events.replacements, events.updates):
            arr["step"] = -7
            arr["x"] = 0

    def scan_finished(self, summary, state):
        self.inner.scan_finished(summary, state)

    def finish(self, result):
        self.inner.finish(result)


def test_buffers_reused_after_chunk_do_not_corrupt_recording(tmp_path):
    path = tmp_path / "alias.rrd"
    scribbler = _Scribbler(RerunSink(path, record_every_rows=8))
    fabricate_run([scribbler], H=H, W=W, S=S, n_scans=2)
    for kind in KINDS:
        want = np.concatenate([getattr(b, kind) for b in scribbler.kept])
        np.testing.assert_array_equal(vi.read_events(path, kind), want)


_KILLED_WRITER = """
import os, sys
sys.path[:0] = [{tests!r}, {root!r}]
import test_viewer_fixtures as fx
from viewer import RerunSink
sink = RerunSink({path!r}, record_every_rows=5)
def boom(scan):
    if scan == 1:
        os._exit(1)  # killed after two flushed scans, before finish()
fx.fabricate_run([sink], H={H}, W={W}, S={S}, n_scans=3, on_scan_done=boom)
"""


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_killed_writer_leaves_readable_file(tmp_path):
    path = tmp_path / "killed.rrd"
    code = _KILLED_WRITER.format(tests=str(ROOT / "tests"), root=str(ROOT), path=str(path),
                                 H=H, W=W, S=S)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, env={**os.environ, "HOME": str(tmp_path)})
    assert r.returncode == 1, r.stderr
    from rerun.chunk import RrdReader
    RrdReader(str(path)).stream().collect()  # raises if the file cannot be read back
    _, _, truth = fabricate_run([], H=H, W=W, S=S, n_scans=3, stop_after_scans=2)
    assert vi.read_counts(path) == counts_of(truth)
    assert vi.read_final_image(path) is None


def test_close_is_idempotent(tmp_path):
    path = tmp_path / "close.rrd"
    sink = RerunSink(path)
    sink.close()  # before start: nothing to do
    fabricate_run([sink], H=H, W=W, S=S, n_scans=1)
    sink.close()
    sink.close()
    assert vi.read_counts(path)
    from rerun.chunk import RrdReader
    RrdReader(str(path)).store()  # needs the footer: the stream was disconnected


def test_two_runs_side_by_side(tmp_path):
    path = tmp_path / "compare.rrd"
    names = [f"src {s:02d}.jpg" for s in range(S)]
    rec = rr.RecordingStream("dynremove", recording_id="compare")
    rec.save(path, default_blueprint=make_compare_blueprint(names, ["runs/a", "runs/b"]))
    a = RerunSink(None, rec=rec, root="runs/a", record_every_rows=8)
    b = RerunSink(None, rec=rec, root="runs/b", record_every_rows=8)
    _, _, truth_a = fabricate_run([a], H=H, W=W, S=S, n_scans=2)
    _, _, truth_b = fabricate_run([b], H=H, W=W, S=S, n_scans=1, seed=3)
    rec.disconnect()
    assert vi.read_counts(path, root="runs/a") == counts_of(truth_a)
    assert vi.read_counts(path, root="runs/b") == counts_of(truth_b)
    assert vi.read_counts(path) == {}


def test_blueprint_serializes(tmp_path):
    bp = make_blueprint(["a/0001.jpg", "b/0001.jpg", "c 2.png"])
    bp.save("dynremove", tmp_path / "layout.rbl")
    assert (tmp_path / "layout.rbl").stat().st_size > 0
    assert P.Paths("runs/x")(P.source("s", P.IMAGE)) == "/runs/x/sources/s/image"


def test_sink_rejects_bad_ground_truth(tmp_path):
    sink = RerunSink(tmp_path / "bad.rrd", gt_mask=np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="gt_mask"):
        fabricate_run([sink], H=H, W=W, S=S, n_scans=1)
    sink.close()
    with pytest.raises(ValueError, match="detail"):
        RerunSink(tmp_path / "bad2.rrd", detail="most")


# -- export, serve -------------------------------------------------------------------
def test_export_gif_and_mp4(run, tmp_path):
    import cv2

    gif = export.export_gif(run["path"], tmp_path / "removal.gif", fps=5, max_side=200)
    data = gif.read_bytes()
    assert data[:6] == b"GIF89a" and data[-1:] == b";"
    frames = export.render_frames(run["path"], max_side=200)
    assert len(frames) >= 3 and max(frames[0].shape[:2]) <= 200
    decoded = gif_frames(gif)
    assert len(decoded) == len(frames)
    err = np.abs(decoded[-1].astype(int) - frames[-1]).mean()
    assert err < 12  # palette quantization only
    mp4 = export.export_gif(run["path"], tmp_path / "removal.mp4", fps=5, max_side=200)
    cap = cv2.VideoCapture(str(mp4))
    assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(frames)
    cap.release()
    # an odd --max-side: the frames' sides are even and at most it (a trial's 101 gave
    # 102 px frames: the MP4 writer padded them)
    odd = export.render_frames(run["path"], max_side=101)
    assert max(odd[0].shape[:2]) <= 101 and all(v % 2 == 0 for v in odd[0].shape[:2])
    # the caption bar counts in the height (a trial's --max-side 16 gave 16x36 frames,
    # 50 gave 50x58); from 104 px up the frames have it
    for side in (16, 50, 104):
        small = export.render_frames(run["path"], max_side=side)
        assert max(small[0].shape[:2]) <= side, (side, small[0].shape)
    assert (small[0][:export.CAPTION_ROWS] == 32).mean() > 0.5  # the bar's gray
    mp4 = export.export_gif(run["path"], tmp_path / "odd.mp4", fps=5, max_side=101)
    cap = cv2.VideoCapture(str(mp4))
    assert int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) <= 101
    cap.release()


def test_failed_export_keeps_the_file_that_was_there(run, tmp_path, monkeypatch):
    """The export is written under a temporary name and renamed: when writing fails
    halfway, the old file is intact and no temporary file is left behind."""
    out = tmp_path / "removal.gif"
    out.write_bytes(b"an earlier export")

    def half_then_fail(frames, path, *, fps=10):
        Path(path).write_bytes(b"GIF89a half")
        raise OSError("disk full")

    monkeypatch.setattr(export, "write_gif", half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        export.export_gif(run["path"], out, fps=5, max_side=120)
    assert out.read_bytes() == b"an earlier export"
    assert [p.name for p in tmp_path.iterdir()] == ["removal.gif"]
    with pytest.raises(ValueError, match="fps"):
        export.export_gif(run["path"], out, fps=0, max_side=120)
    assert out.read_bytes() == b"an earlier export"


def test_export_png_frames_into_a_folder(run, tmp_path, capsys, monkeypatch):
    """A folder for --out takes the frames as numbered PNGs (a trial asked for frames
    for slides): the same frames as the GIF's, byte for byte as drawn. A folder of an
    earlier export's frames is replaced whole (none of its extra frames stay); one
    with other files is refused before drawing; a failed export leaves what was
    there and no temporary folder."""
    import cv2

    from dynremove.cli import main

    frames = export.render_frames(run["path"], max_side=200)
    out = tmp_path / "frames"
    assert main(["export", str(run["path"]), "--out", str(out), "--max-side", "200"]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"wrote {len(frames)} frames to {out} (frame_0000.png ... "), said
    names = sorted(q.name for q in out.iterdir())
    assert names == [f"frame_{i:04d}.png" for i in range(len(frames))]
    # the folder follows the umask, as every output (it came out 0700: a trial)
    import os
    import stat

    from dynremove.io import current_umask
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o777 & ~current_umask()
    for i, f in enumerate(frames):
        assert np.array_equal(cv2.imread(str(out / names[i])), f)
    (out / "frame_9999.png").write_bytes(b"x")  # an earlier, longer export's
    written = export.export_frames(run["path"], out, max_side=120)
    assert sorted(q.name for q in out.iterdir()) == [q.name for q in written] == names
    (out / "notes.txt").write_text("mine")
    assert main(["export", str(run["path"]), "--out", str(out)]) == 2
    assert "holds other files than frames (notes.txt)" in capsys.readouterr().err
    (out / "notes.txt").unlink()
    before = {q.name: q.read_bytes() for q in out.iterdir()}
    monkeypatch.setattr(export.cv2, "imwrite", lambda *a, **k: False)
    with pytest.raises(OSError, match="could not write"):
        export.export_frames(run["path"], out, max_side=200)
    assert {q.name: q.read_bytes() for q in out.iterdir()} == before
    assert sorted(q.name for q in tmp_path.iterdir()) == ["frames"]


def gif_frames(path) -> list[np.ndarray]:
    """Every frame of a GIF as (H, W, 3) uint8 BGR, decoded by Pillow (a declared
    dependency; not every OpenCV build reads GIF animations)."""
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        return [np.ascontiguousarray(np.asarray(f.convert("RGB"))[..., ::-1])
                for f in ImageSequence.Iterator(im)]


def test_gif_is_lossless_on_palette_images(tmp_path):
    rng = np.random.default_rng(0)
    colours = rng.integers(0, 256, (200, 3), dtype=np.uint8)
    frames = [colours[rng.integers(0, 200, (130, 170))] for _ in range(3)]
    export.write_gif(frames, tmp_path / "noise.gif")
    decoded = gif_frames(tmp_path / "noise.gif")
    assert len(decoded) == len(frames)
    for f, g in zip(frames, decoded):
        np.testing.assert_array_equal(g, f)


def test_gif_of_many_colours_is_close(tmp_path):
    import cv2

    rng = np.random.default_rng(1)
    base = cv2.GaussianBlur(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8), (0, 0), 3)
    frames = [np.roll(base, 7 * k, axis=1) for k in range(3)]
    export.write_gif(frames, tmp_path / "smooth.gif", fps=4)
    decoded = gif_frames(tmp_path / "smooth.gif")
    assert len(decoded) == len(frames)
    for f, g in zip(frames, decoded):
        assert np.abs(g.astype(int) - f).mean() < 6  # palette quantization only


def test_web_url_and_command():
    url = serve.web_url()
    assert url == ("http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876"
                   "%2Fproxy")
    cmd = serve.view_command("x.rrd", web=True, port=9999, web_port=9998)
    assert cmd[1:5] == ["--serve-web", "--bind", "127.0.0.1", "--port"]
    assert not cmd[0].endswith(os.path.join("bin", "rerun"))  # the real binary


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_web_server_on_loopback(run, tmp_path):
    port, web_port = _free_port(), _free_port()
    proc = serve.view(run["path"], web=True, port=port, web_port=web_port, wait=False,
                      env=cli_env(tmp_path), stdout=subprocess.DEVNULL,
                      stderr=subprocess.DEVNULL)
    try:
        deadline, body = time.time() + 30, b""
        while time.time() < deadline and not body:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=2) as r:
                    body = r.read()
            except OSError:
                time.sleep(0.3)
        assert b"<html" in body.lower() or b"<!doctype" in body.lower()
    finally:
        serve.stop(proc)
    assert proc.poll() is not None


def test_m_prints_the_same_from_a_decision_and_from_the_map():
    """The verdict reads M from the per-scan map (M · 10⁴ as uint16), the history from
    the decision (float32): both print the map's figure, so that they never disagree at
    the rounding boundary (a fresh-user trial saw "M = 0.25" against "M 0.24")."""
    for M in (0.24503, 0.24496, 0.2449, 0.30001, 0.12345678):
        q = float(np.uint16(round(M * P.M_SCALE))) / P.M_SCALE
        assert vd.m_text(np.float32(M)) == vd.m_text(q) == f"{q:.2f}"


def _view_names(container) -> list[str]:
    """The names of a blueprint's containers and views, depth first."""
    out = [getattr(container, "name", None)]
    for c in getattr(container, "contents", None) or []:
        if hasattr(c, "name"):
            out += _view_names(c)
    return out


def test_without_ground_truth_the_layout_has_no_empty_error_views():
    """The "errors" map and the "Jaccard" plot read the ground truth (``run --gt``):
    a recording without one had them empty (a fresh user's trial, session 65). They
    are laid out only with it, in the plain and the --compare layouts alike."""
    names = ["a/0001.jpg", "b/0001.jpg"]
    with_gt = _view_names(make_blueprint(names).root_container)
    without = _view_names(make_blueprint(names, jaccard=False).root_container)
    assert "errors" in with_gt and "Jaccard" in with_gt
    assert "errors" not in without and "Jaccard" not in without
    assert set(with_gt) - set(without) == {"errors", "Jaccard"}
    cmp = _view_names(make_compare_blueprint(names, ["runs/a", "runs/b"],
                                             jaccard=False).root_container)
    assert "errors" not in cmp and "Jaccard" not in cmp and "runs/a" in cmp


def test_the_sink_lays_out_error_views_only_with_ground_truth(tmp_path, monkeypatch):
    """The sink passes whether it has a ground-truth mask to the layout it saves."""
    import viewer.sink as vs

    seen = []
    real = vs.make_blueprint

    def spy(*a, **k):
        seen.append(k.get("jaccard", True))
        return real(*a, **k)

    monkeypatch.setattr(vs, "make_blueprint", spy)
    for gt in (None, np.zeros((H, W), bool)):
        seen.clear()
        sink = RerunSink(tmp_path / f"gt{gt is not None}.rrd", gt_mask=gt,
                         record_every_rows=8)
        fabricate_run([sink], H=H, W=W, S=S, n_scans=1)
        assert seen and set(seen) == {gt is not None}, (gt is not None, seen)


def test_the_gif_palette_lists_the_frames_own_colours_in_order():
    """Up to 256 colours, the palette is the frames' colours sorted as ``np.unique``
    sorts BGR rows (the flags over packed values that replaced it, 10x faster, give
    the same palette byte for byte), and the GIF is lossless."""
    from viewer import export

    rng = np.random.default_rng(0)
    colours = rng.integers(0, 256, (40, 3), dtype=np.uint8)
    frames = [colours[rng.integers(0, 40, (12, 16))] for _ in range(5)]
    pal = np.array(export.gif_palette(frames).getpalette()[:3 * 40], np.uint8).reshape(-1, 3)
    want = np.unique(np.concatenate([f.reshape(-1, 3) for f in frames]), axis=0)[:, ::-1]
    assert np.array_equal(pal[:len(want)], want)

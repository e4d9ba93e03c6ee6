"""The recording layer on real runs of the method (not fabricated events)."""

from __future__ import annotations

import json
import subprocess

import cv2
import numpy as np
import pytest

pytest.importorskip("rerun")

from test_viewer import cli_env, counts_of  # noqa: E402

from dynremove import MemorySink, NullSink, preset, remove_dynamic  # noqa: E402
from dynremove.evaluation import synth  # noqa: E402
from dynremove.evaluation.metrics import jaccard  # noqa: E402
from dynremove.cli import main  # noqa: E402
from dynremove.events import replay_replacements  # noqa: E402
from viewer import RerunSink, serve  # noqa: E402
from viewer import inspect as vi  # noqa: E402
from viewer import verdict as vd  # noqa: E402


class Tee:
    """Forward every event to several sinks (one run, two observers)."""

    enabled = True

    def __init__(self, *sinks):
        self.sinks = sinks

    def __getattr__(self, name):
        return lambda *a: [getattr(s, name)(*a) for s in self.sinks]


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)


@pytest.mark.parametrize("name", ["paper", "default"])
def test_recording_replays_and_counts(scene, tmp_path, name):
    params = preset(name).replace(max_scans=2)
    path = tmp_path / "run.rrd"
    mem = MemorySink()
    rsink = RerunSink(path, record_every_rows=8, gt_mask=scene.masks[scene.ref_index])
    res = remove_dynamic(scene.images, ref=scene.ref_index, params=params,
                         sink=Tee(mem, rsink), probes=[(20, 30)], sample_static=0.01)
    assert len(mem.replacements) > 0
    # counts read back from the file equal what the core emitted
    assert vi.read_counts(path) == counts_of(mem)
    # the recorded Replacement events alone rebuild the scans' image, read from the file
    srcs = [scene.images[i] for i in range(len(scene.images)) if i != scene.ref_index]
    rebuilt = replay_replacements(scene.images[scene.ref_index], srcs, vi.read_replacements(path),
                                  patch_size=params.patch_size, write=params.write)
    np.testing.assert_array_equal(rebuilt, vi.read_final_image(path, scan=True))
    np.testing.assert_array_equal(rebuilt, res.clean_scan)
    np.testing.assert_array_equal(vi.read_final_image(path), res.clean)
    # the map after each post-scan step: what the run had, in order, ending at L
    stages = vi.read_stages(path)
    assert list(stages) == list(res.stages)
    assert list(stages) == (["scan"] if name == "paper"
                            else ["scan", "clean", "votes", "snap", "select"])
    for k in stages:
        np.testing.assert_array_equal(stages[k], res.stages[k])
    np.testing.assert_array_equal(stages[list(stages)[-1]], res.dynamic)
    np.testing.assert_array_equal(stages["scan"], res.dynamic_raw)
    x, y = map(int, np.argwhere(res.dynamic)[0][::-1]) if res.dynamic.any() else (0, 0)
    hist = vi.pixel_history(path, x, y)
    assert hist["stages"] == {k: bool(v[y, x]) for k, v in res.stages.items()}
    assert "L after each step: scan" in vd.format_pixel_history(hist)
    # results do not depend on the sink
    null = remove_dynamic(scene.images, ref=scene.ref_index, params=params, sink=NullSink())
    np.testing.assert_array_equal(null.clean, res.clean)
    np.testing.assert_array_equal(null.dynamic, res.dynamic)
    # the probe pixel's history is there in every scan
    hist = vi.pixel_history(path, 20, 30)
    assert len(hist["decisions"]) == len(res.scans)


def test_cli_recordings_verify_and_inspect(scene, tmp_path, capsys):
    synth.write_scene(scene, tmp_path / "set")
    rec = tmp_path / "r.rrd"
    mask = tmp_path / "set" / "masks" / scene.names[scene.ref_index]
    code = main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o"),
                 "--record", str(rec), "--probe", "10,12", "--gt", str(mask), "--quiet"])
    assert code == 0 and rec.stat().st_size > 0
    assert vi.read_run_info(rec)["record_detail"] == "default"
    r = subprocess.run([serve.rerun_binary(), "rrd", "verify", str(rec)],
                       env=cli_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    capsys.readouterr()
    assert main(["inspect", str(rec), "--pixel", "10,12"]) == 0
    out = capsys.readouterr().out
    assert "pixel (10, 12)" in out and "scan 0" in out
    assert out.count(vd.LEGEND) == 1  # the probe's decisions have M
    # several pixels in one call (the same twice, and as a photo pixel): each verdict,
    # each glossary once (it repeated at every pixel of a teaching session)
    assert main(["inspect", str(rec), "--pixel", "10,12", "--pixel", "11,12",
                 "--photo-pixel", "10,12"]) == 0
    many = capsys.readouterr().out
    assert many.count("pixel (10, 12): ") == 2 and many.count("pixel (11, 12): ") == 1
    assert many.count(vd.LEGEND) == 1
    assert many.index(vd.LEGEND) < many.index("pixel (11, 12): ")  # where first needed
    assert main(["inspect", str(rec), "--failures", "--top", "3"]) == 0
    assert main(["export", str(rec), "--gif", str(tmp_path / "a.gif")]) == 0
    assert (tmp_path / "a.gif").read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert main(["inspect", str(tmp_path / "missing.rrd"), "--pixel", "1,1"]) == 2


def test_compare_logs_two_runs_side_by_side(scene, tmp_path, capsys):
    synth.write_scene(scene, tmp_path / "set")
    rec = tmp_path / "cmp.rrd"
    code = main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o"),
                 "--record", str(rec), "--compare", "paper", "--quiet"])
    assert code == 0
    main_counts = vi.read_counts(rec, root="runs/main")
    cmp_counts = vi.read_counts(rec, root="runs/compare")
    assert main_counts and cmp_counts and main_counts != cmp_counts
    assert vi.read_run_info(rec, root="runs/compare")["params"]["t_r"] == preset("paper").t_r
    # the compare run's figures are in report.json and on the terminal too, its J
    # with --gt (a trial found it only in the recording's log)
    gt = tmp_path / "gt.png"
    cv2.imwrite(str(gt), scene.masks[scene.ref_index].astype(np.uint8) * 255)
    capsys.readouterr()
    assert main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o3"),
                 "--record", str(tmp_path / "cmp3.rrd"), "--compare", "paper",
                 "--gt", str(gt)]) == 0
    out = capsys.readouterr()
    rep = json.loads((tmp_path / "o3" / "report.json").read_text())["compare"]
    cmp_mask = vi.read_final_dynamic(tmp_path / "cmp3.rrd", root="runs/compare")
    assert rep["dynamic_fraction"] == pytest.approx(float(cmp_mask.mean()))
    assert rep["jaccard_vs_gt"] == pytest.approx(
        jaccard(cmp_mask, scene.masks[scene.ref_index].astype(bool)))
    assert rep["params"]["t_r"] == preset("paper").t_r
    assert f"J {rep['jaccard_vs_gt']:.3f}" in out.out + out.err
    assert main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o2"),
                 "--compare", "no_such_field=1", "--record", str(tmp_path / "x.rrd")]) == 2


def test_the_compare_runs_notes_are_labelled(scene, tmp_path, capsys):
    """A fresh-user trial: --compare printed the second run's notes as the main run's,
    so the same note came twice and two "inpainted" counts could not be told apart.
    Two photos: each run notes it, the compare run's note says whose it is."""
    d = tmp_path / "two"
    d.mkdir()
    for i in (scene.ref_index - 1, scene.ref_index):
        cv2.imwrite(str(d / f"view{i}.png"), scene.images[i])
    code = main(["run", str(d), "--out", str(tmp_path / "o"), "--record",
                 str(tmp_path / "c.rrd"), "--compare", "paper"])
    assert code == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "only 2 photos" in ln]
    assert [ln.startswith("dynremove: note: only 2 photos") for ln in notes] == [True, False]
    assert notes[1].startswith("dynremove: note: compare run: only 2 photos")


def test_a_large_recording_says_its_size_and_why(scene, tmp_path, capsys, monkeypatch):
    """A fresh-user trial: --compare paper wrote a 470 MB recording without a word.
    The last line gives the recording's size; above the threshold (lowered here to
    0 MiB) a note says what makes it large, for both runs."""
    from dynremove import commands
    synth.write_scene(scene, tmp_path / "set")
    rec = tmp_path / "cmp.rrd"
    monkeypatch.setattr(commands, "_BIG_RECORDING_MIB", 0)
    assert main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o"),
                 "--record", str(rec), "--compare", "paper"]) == 0
    cap = capsys.readouterr()
    err = cap.err
    size = rec.stat().st_size / 2 ** 20
    assert f"and {rec} ({size:.0f} MiB)" in cap.out + err
    note = next(ln for ln in err.splitlines() if "the recording is" in ln)
    assert f"{size:.0f} MiB" in note and "the compare run makes most of it" in note
    assert "--record-every-rows" in note


def _rows_by_entity(path) -> dict[str, int]:
    """Rows per step-indexed entity, read back with the dataframe API."""
    from rerun.chunk import RrdReader

    store = RrdReader(str(path)).stream().collect()
    out = {}
    for ent in sorted(str(e) for e in store.schema().entity_paths()):
        t = store.reader(index="step", contents=ent).to_arrow_table()
        n = sum(1 for s in t.column("step").to_pylist() if s is not None) if t.num_rows else 0
        if n:
            out[ent] = n
    return out


def test_default_detail_has_far_fewer_step_rows_and_the_same_maps(scene, tmp_path):
    """One run of the method, recorded at both details: the default's source views
    get candidates and q* at far fewer steps, while the per-scan decision maps, the
    raw events and what inspect says about a pixel are identical."""
    paths = {k: tmp_path / f"{k}.rrd" for k in ("default", "full")}
    sinks = [RerunSink(paths[k], record_every_rows=8, gt_mask=scene.masks[scene.ref_index],
                       detail=k) for k in paths]
    remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                   sink=Tee(*sinks), probes=[(20, 30)])
    rows = {k: _rows_by_entity(p) for k, p in paths.items()}

    def total(k, prefix="", leaves=("",)):
        return sum(n for e, n in rows[k].items() if e.startswith(prefix) and e.endswith(leaves))

    # candidates and q* in the source views: 1 in 16 dynamic decisions, + probes
    src = {k: total(k, "/sources/", ("/candidates", "/chosen_patch")) for k in rows}
    assert src["full"] > 1000 and src["default"] * 6 < src["full"], src
    assert total("default") * 2 < total("full"), (total("default"), total("full"))
    # the reference's per-step overlays follow every recorded decision in both
    for ent in ("/reference/current", "/reference/chosen_patch"):
        assert rows["default"][ent] == rows["full"][ent] > 0
    # the per-scan decision maps: identical tables, identical arrays
    from rerun.chunk import RrdReader

    tables = {k: RrdReader(str(p)).stream().collect().reader(
        index="step", contents="/scan_maps/**").to_arrow_table() for k, p in paths.items()}
    cols = sorted(c for c in tables["full"].column_names if c.startswith("/scan_maps/"))
    assert len(cols) >= 10 and cols == sorted(c for c in tables["default"].column_names
                                              if c.startswith("/scan_maps/"))
    for c in cols + ["step"]:
        assert tables["default"].column(c).equals(tables["full"].column(c)), c
    maps = {k: vi.read_scan_maps(p) for k, p in paths.items()}
    assert len(maps["default"]) == len(maps["full"]) > 0
    for a, b in zip(maps["default"], maps["full"]):
        assert a.keys() == b.keys() and a["b_m"] is not None
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for kind in ("decisions", "replacements", "updates"):
        np.testing.assert_array_equal(vi.read_events(paths["default"], kind),
                                      vi.read_events(paths["full"], kind))
    for x, y in ((20, 30), (0, 0), (64, 48)):
        texts = [vd.format_pixel_history(vi.pixel_history(p, x, y)) for p in paths.values()]
        assert texts[0] == texts[1]
    assert vi.read_run_info(paths["default"])["record_detail"] == "default"


def test_cli_record_detail_full(scene, tmp_path):
    synth.write_scene(scene, tmp_path / "set")
    rec = tmp_path / "full.rrd"
    assert main(["run", str(tmp_path / "set" / "frames"), "--out", str(tmp_path / "o"),
                 "--record", str(rec), "--record-detail", "full", "--quiet"]) == 0
    info = vi.read_run_info(rec)
    assert info["record_detail"] == "full" and info["step_grid"] == 1
    with pytest.raises(SystemExit):
        main(["run", str(tmp_path / "set" / "frames"), "--record-detail", "most"])

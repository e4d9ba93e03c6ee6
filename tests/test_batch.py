"""``dynremove batch``: every set below a folder, resumable, parallel, failures kept."""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove import batch
from dynremove.cli import main
from dynremove.evaluation import synth

FAST = ["--max-scans", "1", "--quiet"]


def write_set(folder: Path, images) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i, im in enumerate(images):
        p = folder / f"view{i}.png"
        assert cv2.imwrite(str(p), im)
        out.append(p)
    return out


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """a/ (images directly), davis/b/frames + masks/ (eval layout), bad/ (sizes differ)."""
    r = tmp_path_factory.mktemp("root")
    s1 = synth.make_scene(seed=1, n_views=4, size=(64, 80), n_objects=1)
    s2 = synth.make_scene(seed=2, n_views=4, size=(64, 80), n_objects=1)
    write_set(r / "a", s1.images)
    write_set(r / "davis" / "b" / "frames", s2.images)
    m = r / "davis" / "b" / "masks"
    m.mkdir()
    for i, mk in enumerate(s2.masks):
        cv2.imwrite(str(m / f"view{i}.png"), mk.astype(np.uint8) * 255)
    write_set(r / "bad", [s1.images[0], cv2.resize(s1.images[1], (40, 64))])
    (r / "README.txt").write_text("not a set")
    return r


def summary_rows(out: Path) -> dict[str, dict]:
    with open(out / "summary.csv") as f:
        return {r["set"]: r for r in csv.DictReader(f)}


def test_find_sets(root):
    sets = batch.find_sets(root)
    assert [s.name for s in sets] == ["a", "bad", "davis/b"]
    b = sets[2]
    assert b.gt == root / "davis" / "b" / "masks" and len(b.inputs) == 4
    assert batch.find_sets(root / "a")[0].inputs == sets[0].inputs  # ROOT itself a set
    # ROOT itself a set in a generic folder is named after its parent, as `run` names
    # its output folder (a trial's `batch .` inside tim6/frames wrote X/frames)
    only = batch.find_sets(root / "davis" / "b" / "frames")
    assert [s.name for s in only] == ["b"] and len(only[0].inputs) == 4


def test_batch_runs_resumes_and_reports_failures(tmp_path, root, capsys):
    out = tmp_path / "out"
    rc = main(["batch", str(root), "--out", str(out), *FAST])
    cap = capsys.readouterr()
    assert rc == 1  # one set failed: exit 1 at the end, after the others ran
    assert "Traceback" not in cap.err
    rows = summary_rows(out)
    assert {k: r["status"] for k, r in rows.items()} == {"a": "ok", "bad": "error",
                                                        "davis/b": "ok"}
    assert "same size" in rows["bad"]["error"]
    assert float(rows["davis/b"]["jaccard_vs_gt"]) > 0.3  # masks/ found and used
    for s in ("a", "davis/b"):
        for f in batch.OUTPUT_FILES:
            assert (out / s / f).is_file()
    js = json.loads((out / "summary.json").read_text())
    assert (js["n_ok"], js["n_failed"], js["n_skipped"]) == (2, 1, 0)
    mask_a = (out / "a" / "dynamic_mask.png").read_bytes()

    # same parameters and inputs: skipped; the failing set is tried again
    rc = main(["batch", str(root), "--out", str(out), *FAST])
    capsys.readouterr()
    rows = summary_rows(out)
    assert rc == 1
    # not re-run, but the earlier outcome is kept
    assert rows["a"]["status"] == rows["davis/b"]["status"] == "ok"
    assert rows["a"]["skipped"] == rows["davis/b"]["skipped"] == "True"
    assert rows["bad"]["status"] == "error" and rows["bad"]["skipped"] == "False"
    assert rows["a"]["dynamic_fraction"] not in ("", None)
    js = json.loads((out / "summary.json").read_text())
    assert (js["n_ok"], js["n_failed"], js["n_skipped"]) == (0, 1, 2)
    assert (out / "a" / "dynamic_mask.png").read_bytes() == mask_a

    # other parameters: run again
    rc = main(["batch", str(root), "--out", str(out), "--max-scans", "1", "--t-r", "0.35",
               "--quiet"])
    capsys.readouterr()
    assert summary_rows(out)["a"]["status"] == "ok"
    assert summary_rows(out)["a"]["skipped"] == "False"


UNALIGNED = "sources could not be aligned to the reference: the result is unreliable…"


@pytest.fixture
def blurry_root(tmp_path, root):
    """x/: the set a/ with its middle view (the default reference) blurred: notes on the
    blurry reference, each source's few matches and the unreliable alignment."""
    r = tmp_path / "r"
    imgs = [cv2.imread(str(p)) for p in sorted((root / "a").iterdir())]
    imgs[len(imgs) // 2] = cv2.GaussianBlur(imgs[len(imgs) // 2], (0, 0), 3)
    write_set(r / "x", imgs)
    return r


def test_notes_are_in_the_progress_line_and_the_summaries(tmp_path, blurry_root, capsys):
    out = tmp_path / "out"
    assert main(["batch", str(blurry_root), "--out", str(out), "--max-scans", "1"]) == 0
    err = capsys.readouterr().err
    notes = json.loads((out / "x" / "report.json").read_text())["notes"]
    n = len(notes)
    assert n >= 2 and any("much blurrier" in m for m in notes)
    line = next(ln for ln in err.splitlines() if ln.startswith("[1/1] x: ok"))
    assert f" s), {n} notes: " in line and UNALIGNED in line  # the one that matters
    assert line.endswith(f"; {n - 1} more in report.json")
    assert "misaligned fill" not in line  # shortened to its first clause
    assert summary_rows(out)["x"]["notes"] == " | ".join(notes)
    js = json.loads((out / "summary.json").read_text())
    assert js["sets"][0]["notes"] == notes


def test_skipped_set_keeps_its_earlier_outcome_time_and_notes(tmp_path, blurry_root, capsys):
    out = tmp_path / "out"
    assert main(["batch", str(blurry_root), "--out", str(out), "--max-scans", "1"]) == 0
    capsys.readouterr()
    first = json.loads((out / "summary.json").read_text())["sets"][0]
    assert first["status"] == "ok" and first["skipped"] is False and first["seconds"] > 0.02
    assert first["notes"]

    assert main(["batch", str(blurry_root), "--out", str(out), "--max-scans", "1"]) == 0
    err = capsys.readouterr().err
    again = json.loads((out / "summary.json").read_text())["sets"][0]
    assert again["skipped"] is True
    assert {k: again[k] for k in again if k != "skipped"} == {
        k: first[k] for k in first if k != "skipped"}  # outcome, figures, seconds, notes
    assert summary_rows(out)["x"]["seconds"] == str(first["seconds"])
    line = next(ln for ln in err.splitlines() if ln.startswith("[1/1] x:"))
    assert line.startswith("[1/1] x: skipped (done before, same parameters and inputs): ok, ")
    assert f"({first['seconds']:.1f} s), {len(first['notes'])} notes: " in line
    assert UNALIGNED in line

    # batch interrupted before the summary was written: report.json has the figures
    (out / "summary.json").unlink()
    assert main(["batch", str(blurry_root), "--out", str(out), "--max-scans", "1",
                 "--quiet"]) == 0
    resumed = json.loads((out / "summary.json").read_text())["sets"][0]
    assert resumed["status"] == "ok" and resumed["skipped"] is True
    assert resumed["notes"] == first["notes"]
    assert resumed["dynamic_fraction"] == first["dynamic_fraction"]
    assert 0.02 < resumed["seconds"] <= first["seconds"]  # up to writing the outputs


def test_notes_phrase_shortens_and_prefers_a_note_about_the_whole_set():
    notes = ["s1.jpg: only 9 keypoint matches with the reference; no epipolar term",
             "s2.jpg: only 6 keypoint matches with the reference; no epipolar term",
             "2 of 3 sources could not be aligned to the reference: the result is unreliable "
             "(misaligned fill, missed or false detections). Photos of more overlap give "
             "more matches"]
    assert batch.notes_phrase(notes) == (
        "3 notes: 2 of 3 sources could not be aligned to the reference: the result is "
        "unreliable…; 2 more in report.json")
    assert batch.notes_phrase(notes[:1]) == ("1 note: s1.jpg: only 9 keypoint matches with "
                                             "the reference…")
    assert batch.notes_phrase(["short one"]) == "1 note: short one"
    assert batch.notes_phrase([]) == ""
    long = batch.notes_phrase(["word " * 60])
    assert long.endswith("…") and len(long) < 110


def test_changed_input_is_run_again(tmp_path, root, capsys):
    r = tmp_path / "r"
    paths = write_set(r / "x", [cv2.imread(str(p)) for p in sorted((root / "a").iterdir())])
    out = tmp_path / "out"
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    img = cv2.imread(str(paths[0]))
    img[:4, :4] = 0
    cv2.imwrite(str(paths[0]), img)
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    capsys.readouterr()
    assert summary_rows(out)["x"]["status"] == "ok"


def test_jobs_2_gives_the_same_masks_as_jobs_1(tmp_path, root, capsys):
    o1, o2 = tmp_path / "j1", tmp_path / "j2"
    main(["batch", str(root), "--out", str(o1), *FAST])
    main(["batch", str(root), "--out", str(o2), "--jobs", "2", *FAST])
    capsys.readouterr()
    for s in ("a", "davis/b"):
        m1 = cv2.imread(str(o1 / s / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE)
        m2 = cv2.imread(str(o2 / s / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(m1, m2)


def test_no_sets_is_an_input_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    for arg in (tmp_path / "empty", tmp_path / "missing"):
        rc = main(["batch", str(arg), "--out", str(tmp_path / "o"), "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("dynremove: error:") == 1 and "Traceback" not in err


def test_out_inside_root_is_not_a_set(tmp_path, root, capsys):
    r = tmp_path / "r"
    write_set(r / "x", [cv2.imread(str(p)) for p in sorted((root / "a").iterdir())])
    assert main(["batch", str(r), "--out", str(r / "results"), *FAST]) == 0
    assert main(["batch", str(r), "--out", str(r / "results"), *FAST]) == 0
    capsys.readouterr()
    assert list(summary_rows(r / "results")) == ["x"]
    # --out ROOT itself: said so (it used to find "no sets": the search skips --out)
    rc = main(["batch", str(r), "--out", str(r), *FAST])
    err = capsys.readouterr().err
    assert rc == 2 and "is ROOT itself" in err and "no sets found" not in err


def test_dask_scheduler_without_the_extra_or_cluster(tmp_path, root, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)
    rc = main(["batch", str(root), "--out", str(tmp_path / "o"), "--scheduler",
               "tcp://127.0.0.1:1", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "dynremove[dask]" in err and "Traceback" not in err
    # a set-up error before any set ran leaves no --out behind, and an earlier batch's
    # summary as it was (a fresh-user trial found it rewritten: "interrupted", every
    # finished set noted as cut short)
    assert not (tmp_path / "o").exists()
    done = tmp_path / "done"
    done.mkdir()
    (done / "summary.json").write_text('{"sets": []}')
    (done / "summary.csv").write_text("set\n")
    rc = main(["batch", str(root), "--out", str(done), "--scheduler", "tcp://127.0.0.1:1",
               "--quiet"])
    capsys.readouterr()
    assert rc == 2 and (done / "summary.json").read_text() == '{"sets": []}'
    assert (done / "summary.csv").read_text() == "set\n"


def test_dask_local_cluster_gives_the_same_masks_as_jobs_1(tmp_path, root, capsys):
    """``--scheduler`` on a ``distributed.LocalCluster`` of 2 worker processes bound
    to 127.0.0.1 (CI installs the ``[dask]`` extra, so this runs there)."""
    try:
        from distributed import LocalCluster
    except ImportError:
        pytest.skip("distributed is not installed (pip install 'dynremove[dask]')")
    o1, od = tmp_path / "j1", tmp_path / "dask"
    assert main(["batch", str(root), "--out", str(o1), *FAST]) == 1  # 'bad' fails
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        addr = cluster.scheduler_address
        assert addr.startswith("tcp://127.0.0.1:")
        rc = main(["batch", str(root), "--out", str(od), "--scheduler", addr, *FAST])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err, err  # the failing set is reported, as with joblib
    rows = summary_rows(od)
    assert {k: r["status"] for k, r in rows.items()} == {"a": "ok", "bad": "error",
                                                        "davis/b": "ok"}
    assert rows["bad"]["error"] == summary_rows(o1)["bad"]["error"]
    for s in ("a", "davis/b"):
        assert ((od / s / "dynamic_mask.png").read_bytes()
                == (o1 / s / "dynamic_mask.png").read_bytes()), s
        assert ((od / s / "clean.png").read_bytes() == (o1 / s / "clean.png").read_bytes()), s
    js = json.loads((od / "summary.json").read_text())
    assert js["scheduler"] == addr and js["jobs"] is None and js["workers"] == 2
    assert (js["n_ok"], js["n_failed"]) == (2, 1)


def test_dask_scheduler_without_workers_is_an_input_error(tmp_path, root, capsys,
                                                         monkeypatch):
    try:
        from distributed import LocalCluster
    except ImportError:
        pytest.skip("distributed is not installed (pip install 'dynremove[dask]')")
    monkeypatch.setattr(batch, "DASK_CONNECT_TIMEOUT_S", 1)
    with LocalCluster(n_workers=0, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        rc = main(["batch", str(root), "--out", str(tmp_path / "o"), "--scheduler",
                   cluster.scheduler_address, "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "no worker joined within 1 s" in err and "Traceback" not in err, err


def test_what_the_search_does_not_run_is_said(tmp_path, capsys):
    """A trial put two photos beside its set folders: batch ran those two as the only
    set and skipped the folders without a word; a folder of one photo vanished too."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    write_set(r, s.images[:2])  # stray photos at the top
    write_set(r / "trip", s.images)
    notes: list[str] = []
    assert [x.name for x in batch.find_sets(r, notes=notes)] == ["root"]
    assert notes == ["root: its 2 photos are one set, so its subfolders are not searched: "
                     "trip (move the photos into a subfolder of their own)"]
    r2 = tmp_path / "root2"
    write_set(r2 / "trip", s.images)
    write_set(r2 / "lonely", s.images[:1])
    (r2 / "void").mkdir()
    notes = []
    assert [x.name for x in batch.find_sets(r2, notes=notes)] == ["trip"]
    assert notes == ["lonely: one photo only (view0.png): not a set",
                     "void: an empty folder: not a set"]
    (r2 / "void").rmdir()
    notes = []
    assert [x.name for x in batch.find_sets(r2, notes=notes)] == ["trip"]
    out = tmp_path / "out"
    assert main(["batch", str(r2), "--out", str(out), "--max-scans", "1"]) == 0
    o, err = capsys.readouterr()
    assert "dynremove: note: lonely: one photo only (view0.png): not a set" in err
    assert o.startswith("1 set: 1 done")
    assert json.loads((out / "summary.json").read_text())["notes"] == notes
    # files of a set's folder that are not images: said, as ``run`` on the folder says
    (r2 / "trip" / "notes.txt").write_text("x")
    (r2 / "trip" / "Thumbs.db").write_bytes(b"\0")
    notes = []
    assert [len(x.inputs) for x in batch.find_sets(r2, notes=notes)] == [3]
    assert notes == ["lonely: one photo only (view0.png): not a set",
                     "trip: skipped 2 non-image file(s): Thumbs.db, notes.txt"]
    # a file named as a video that is not one (a trial's text file named fake.mp4): a
    # set that fails, in the summary and the exit code (a later trial found the note
    # alone too easy to miss among many videos)
    (r2 / "fake.mp4").write_text("not a video")
    assert [x.name for x in batch.find_sets(r2)] == ["fake", "trip"]
    out2 = tmp_path / "out2"
    assert main(["batch", str(r2), "--out", str(out2), *FAST]) == 1
    rows = summary_rows(out2)
    assert rows["fake"]["status"] == "error" and "named as a video" in rows["fake"]["error"]
    assert rows["trip"]["status"] == "ok"
    assert "dynremove: error: fake: " in capsys.readouterr().err


def test_a_set_that_fails_after_an_earlier_run_says_its_outputs_are_old(tmp_path, capsys):
    """A trial broke a set that had run before: its error row sat next to the old
    clean.png without a word. The old outputs stay (nothing is lost); the error says
    they are an earlier run's."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    paths = write_set(r / "trip", s.images)
    out = tmp_path / "out"
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    old = (out / "trip" / "clean.png").read_bytes()
    assert cv2.imwrite(str(paths[1]), cv2.resize(s.images[1], (40, 64)))
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 1
    capsys.readouterr()
    err = summary_rows(out)["trip"]["error"]
    assert "same size" in err and "still holds an earlier run's outputs" in err, err
    assert (out / "trip" / "clean.png").read_bytes() == old


def test_a_bad_max_side_is_refused_once_before_any_set(tmp_path, root, capsys):
    """A fresh-user trial: --max-side 5 was checked inside each set, one identical
    error per set (and exit 1). It is refused once, before anything runs: exit 2."""
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:  # (argparse's exit, as the program gives it)
        main(["batch", str(root), "--out", str(out), "--max-side", "5"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--max-side: 5: must be 0" in err and "16 px" in err, err
    assert not out.exists()


def test_root_may_be_one_video_and_a_file_that_is_not_is_refused(tmp_path, capsys):
    """The help says ROOT may be one video; a trial found `batch clip.mp4` refused as
    "no such folder" (a file that is there), as was a text file. The video is one set;
    another file is one line, exit 2, and no --out folder is left behind."""
    s = synth.make_scene(seed=1, n_views=4, size=(64, 80), n_objects=1)
    clip = tmp_path / "clip.avi"
    vw = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 5, (80, 64))
    for im in s.images:
        vw.write(im)
    vw.release()
    out = tmp_path / "out"
    assert main(["batch", str(clip), "--out", str(out), *FAST]) == 0
    assert list(summary_rows(out)) == ["clip"] and (out / "clip" / "clean.png").is_file()
    capsys.readouterr()
    fake = tmp_path / "fake.mp4"
    fake.write_text("not a video")
    assert main(["batch", str(fake), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a file, and not a video" in err, err
    assert not (tmp_path / "o2").exists()
    assert main(["batch", str(tmp_path / "nothing"), "--out", str(tmp_path / "o3")]) == 2
    assert "no such folder" in capsys.readouterr().err and not (tmp_path / "o3").exists()


def test_sets_named_alike_write_to_their_own_folders(tmp_path, capsys):
    """A fresh-user trial's ROOT held camel/ (photos), camel.mp4 and camel.avi: all three
    wrote to out/camel, two results were lost, the summary had three rows of one set and
    a resume re-ran all three every time. A video named as another set keeps its suffix."""
    s = synth.make_scene(seed=1, n_views=4, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    write_set(r / "camel", s.images)
    for name in ("camel.avi", "camel.mkv"):
        vw = cv2.VideoWriter(str(r / name), cv2.VideoWriter_fourcc(*"MJPG"), 5, (80, 64))
        for im in s.images:
            vw.write(im)
        vw.release()
    (r / "walk.avi").write_bytes((r / "camel.avi").read_bytes())  # no clash: its stem
    assert [x.name for x in batch.find_sets(r)] == ["camel", "camel.avi", "camel.mkv", "walk"]
    out = tmp_path / "out"
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    rows = summary_rows(out)
    assert set(rows) == {"camel", "camel.avi", "camel.mkv", "walk"}
    assert all((out / n / "report.json").is_file() for n in rows)
    # and a resume skips all four
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    assert all(row["skipped"] == "True" for row in summary_rows(out).values())
    capsys.readouterr()


def test_an_earlier_runs_outputs_inside_root_are_not_a_set(tmp_path, capsys):
    """A trial ran ``batch root --out root/x``, then ``batch root --out b``: the second
    batch ran each of x's sets (clean.png, dynamic_mask.png, coverage.png) as three
    photos. An earlier batch's --out (its summaries) is not searched, and a run's
    outputs beside its report.json are not photos, as ``run`` on the folder says."""
    s = synth.make_scene(seed=1, n_views=4, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    write_set(r / "trip", s.images)
    assert main(["batch", str(r), "--out", str(r / "x"), *FAST]) == 0
    assert main(["run", str(r / "trip"), "--out", str(r / "one"), *FAST]) == 0
    notes: list[str] = []
    assert [x.name for x in batch.find_sets(r, notes=notes)] == ["trip"]
    assert notes == ["one: the outputs of an earlier dynremove run (clean.png, coverage.png, "
                     "dynamic_mask.png beside its report.json): not a set",
                     "x: an earlier dynremove batch's outputs (its summary.json and "
                     "summary.csv): not searched"], notes
    # beside the photos of a set, they are not photos of it
    for n in ("clean.png", "dynamic_mask.png", "coverage.png", "report.json"):
        (r / "trip" / n).write_bytes((r / "one" / n).read_bytes())
    notes = []
    assert [len(x.inputs) for x in batch.find_sets(r, notes=notes)] == [4]
    assert "trip: skipped clean.png, coverage.png, dynamic_mask.png: the outputs of an " \
           "earlier dynremove run (its report.json is beside them)" in notes, notes
    assert not any("non-image" in n for n in notes), notes
    capsys.readouterr()


def test_frames_applies_to_the_video_sets_of_a_mixed_root(tmp_path, capsys):
    """A trial's ROOT held videos and photo folders: `--frames 4` failed every photo
    set ("--frames and --span take frames from a video"). They are the video sets'."""
    s = synth.make_scene(seed=1, n_views=6, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    write_set(r / "photos", s.images[:4])
    vw = cv2.VideoWriter(str(r / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 5, (80, 64))
    for im in s.images:
        vw.write(im)
    vw.release()
    out = tmp_path / "out"
    assert main(["batch", str(r), "--out", str(out), "--frames", "4", *FAST]) == 0
    rows = summary_rows(out)
    assert set(rows) == {"clip", "photos"}
    assert all(row["status"] == "ok" for row in rows.values()), rows
    assert rows["clip"]["inputs"] == "1"
    assert len(json.loads((out / "clip" / "report.json").read_text())["inputs"]) == 4


def test_span_is_checked_first_and_ignored_without_a_video(tmp_path, capsys):
    """A trial's ``batch --span 9:3`` ran the photo sets before failing at the video
    set, and ``--span abc`` over folders of photos ran them all without a word (and a
    changed span ran them again on resume). The span's form is checked before any set
    runs; without a video among the sets, ``--frames``/``--span`` are said to be
    ignored and are no part of the sets' options (a resume skips them)."""
    s = synth.make_scene(seed=1, n_views=4, size=(64, 80), n_objects=1)
    r = tmp_path / "root"
    write_set(r / "photos", s.images)
    out = tmp_path / "out"
    for bad, said in (("9:3", "END must be greater than START"), ("abc", "expected START:END")):
        assert main(["batch", str(r), "--out", str(out), "--span", bad, *FAST]) == 2
        err = capsys.readouterr().err
        assert f"--span {bad}: {said}" in err and "Traceback" not in err
        assert not out.exists()
    assert main(["batch", str(r), "--out", str(out), "--span", "0:3", "--frames", "3"]) == 0
    err = capsys.readouterr().err
    said = ("--frames and --span: they take frames from a video, and no set here is one: "
            "ignored")
    assert said in err and said in json.loads((out / "summary.json").read_text())["notes"]
    assert main(["batch", str(r), "--out", str(out), "--span", "1:3"]) == 0
    assert summary_rows(out)["photos"]["skipped"] in ("True", "true", "1")
    capsys.readouterr()


def test_batch_scores_at_the_size_written(tmp_path, root, capsys):
    """Fresh-user trial: with --max-side below the photos' size, batch read the true
    mask at the analysis size and enlarged it again, so the same mask scored J 0.570
    in batch and 0.586 in `run --gt` (which scores at the size written)."""
    import shutil

    from dynremove.evaluation.metrics import jaccard

    sub = tmp_path / "r"
    shutil.copytree(root / "davis" / "b", sub / "davis" / "b")
    out = tmp_path / "out"
    assert main(["batch", str(sub), "--out", str(out), "--max-side", "48", *FAST]) == 0
    capsys.readouterr()
    row = summary_rows(out)["davis/b"]
    frames = sorted((sub / "davis" / "b" / "frames").iterdir())
    gt = cv2.imread(str(sub / "davis" / "b" / "masks" / (frames[len(frames) // 2].stem
                                                          + ".png")), 0) > 127
    mask = cv2.imread(str(out / "davis" / "b" / "dynamic_mask.png"), 0) > 127
    assert mask.shape == gt.shape == (64, 80)
    assert float(row["jaccard_vs_gt"]) == pytest.approx(jaccard(mask, gt), abs=1e-4)


def test_a_cut_batch_lists_what_finished_and_says_how_to_resume(tmp_path, root, capsys,
                                                                monkeypatch):
    """Ctrl-C after the first set: exit 130, summary.csv lists the finished set (and
    summary.json says the batch was cut short), the message says how to resume, and
    the same command again runs only the rest (a fresh-user trial: no summary and no
    hint)."""
    from dynremove.cli import main

    real = batch.run_set
    calls = []

    def cut_after_one(bs, *a, **k):
        calls.append(bs.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(bs, *a, **k)

    monkeypatch.setattr(batch, "run_set", cut_after_one)
    out = tmp_path / "out"
    rc = main(["batch", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 130
    assert "batch cut short: 1 of 3 sets finished (" in err, err  # (none failed)
    assert "run the same command again to resume" in err
    assert list(summary_rows(out)) == ["a"]
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and s["n_not_run"] == 2
    monkeypatch.setattr(batch, "run_set", real)
    assert main(["batch", str(root), "--out", str(out), "--quiet"]) == 1  # bad/ fails
    rows = summary_rows(out)
    assert list(rows) == ["a", "bad", "davis/b"]
    assert rows["a"]["skipped"] in ("True", "1", "true") and rows["davis/b"]["status"] == "ok"


def test_a_ctrl_c_inside_a_compiled_call_stops_the_batch(tmp_path, root, capsys, monkeypatch):
    """A Ctrl-C that lands inside a numba call surfaces as a SystemError ("returned a
    result with an exception set") around the KeyboardInterrupt. A fresh-user trial
    saw it recorded as the set's failure, exit 1, and the batch go on to the next
    sets; it is an interruption: exit 130, the set not listed as failed, no other set
    started."""
    from dynremove.cli import main

    started = []

    def interrupted_in_a_kernel(images, *a, **k):
        started.append(len(images))
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function _assemble_sift>) returned a result "
                              "with an exception set") from None

    monkeypatch.setattr(batch, "remove_dynamic", interrupted_in_a_kernel)
    out = tmp_path / "out"
    rc = main(["batch", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 130, err
    assert len(started) == 1 and "SystemError" not in err and "failed" not in err, err
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and s["n_failed"] == 0 and s["n_not_run"] == 3


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="reads /proc (Linux)")
def test_a_cut_parallel_batch_leaves_no_worker_running(tmp_path):
    """--jobs 2, interrupted in the main process between two finished sets (as a
    SIGINT to the main PID alone lands): the workers still running their sets are
    stopped with it. A fresh-user trial saw two workers outlive the command and write
    a set 16 s after it had exited 130."""
    import os
    import time

    from dynremove.params import preset

    root = tmp_path / "root"
    for i in range(4):
        sc = synth.make_scene(seed=i, n_views=5, size=(240, 320), n_objects=1)
        write_set(root / f"s{i}", sc.images)

    def workers() -> list[str]:  # this process's children, but joblib's trackers
        out = []
        for p in Path("/proc").iterdir():
            try:
                if p.name.isdigit() and int((p / "stat").read_text().split()[3]) == os.getpid():
                    cmd = (p / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                    if "resource_tracker" not in cmd:
                        out.append(cmd)
            except (OSError, ValueError, IndexError):
                pass
        return out

    def cut(k, n, row):
        raise KeyboardInterrupt

    out = tmp_path / "out"
    held = None
    try:
        batch.run_batch(root, out, params=preset("default"), preset_name="default", jobs=2,
                        on_done=cut)
    except KeyboardInterrupt as e:
        # its frames kept, as they are while the CLI reports the cut and exits (so
        # joblib's generator is not garbage-collected, which would abort it too)
        held = e.__traceback__
    assert held is not None
    finished = {p.name for p in out.iterdir() if p.is_dir()}
    assert 1 <= len(finished) < 4
    time.sleep(3)  # (a set takes about 2 s here)
    assert workers() == []
    assert {p.name for p in out.iterdir() if p.is_dir()} == finished  # none written since
    del held


def test_a_cut_rerun_keeps_the_rows_of_the_sets_it_did_not_reach(tmp_path, root, capsys,
                                                                  monkeypatch):
    """A finished batch, then the same command cut short at its first set: the
    summary still lists the sets finished before whose outputs are unchanged on disk,
    noted as the earlier run's (a fresh-user trial: summary.csv was left with its
    header only until the batch was resumed)."""
    from dynremove.cli import main

    out = tmp_path / "out"
    assert main(["batch", str(root), "--out", str(out), "--quiet"]) == 1  # bad/ fails
    before = summary_rows(out)
    assert before["a"]["status"] == before["davis/b"]["status"] == "ok"

    def cut(bs, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "run_set", cut)
    assert main(["batch", str(root), "--out", str(out), "--quiet"]) == 130
    capsys.readouterr()
    rows = summary_rows(out)
    assert list(rows) == ["a", "davis/b"]  # (bad/ failed: it has no earlier outputs)
    for name in rows:
        assert rows[name]["dynamic_fraction"] == before[name]["dynamic_fraction"]
        assert "this batch was cut short before the set" in rows[name]["notes"]
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and s["n_not_run"] == 3


def test_a_photo_given_twice_does_not_move_the_middle_reference(tmp_path):
    """Five distinct photos plus a copy of the last under another name: the
    reference is still the middle one of the five (a fresh-user trial: desk6.jpg and
    DESK6.JPG moved it from desk4 to desk5)."""
    from dynremove import io

    s = synth.make_scene(seed=1, n_views=5, size=(48, 64))
    paths = write_set(tmp_path / "set", s.images)
    (tmp_path / "set" / "zz_copy.png").write_bytes(paths[-1].read_bytes())
    iset = io.load_image_set([tmp_path / "set"])
    assert len(iset.images) == 6
    assert batch.distinct_images(iset.images) == [0, 1, 2, 3, 4]
    i, info, _ = batch.choose_reference(None, iset)
    assert iset.names[i] == paths[2].name and info["chosen_by"] == "middle"
    from dynremove.commands import reference_note

    assert reference_note(None, i, info, iset.names).endswith(
        "(index 2 of 0..5, the middle image of the 5 that are no exact copy of another)")
    # 4 distinct photos and a copy: the later middle one, the other named by its index
    (tmp_path / "set" / paths[0].name).unlink()
    iset = io.load_image_set([tmp_path / "set"])
    i, info, _ = batch.choose_reference(None, iset)
    assert iset.names[i] == paths[3].name
    assert reference_note(None, i, info, iset.names).endswith(
        "the later of the two middle images of the 4 that are no exact copy of another; "
        "--ref 1 for the other)")
    # one photo under three names: said so (a trial read "the middle image of the 1
    # distinct ones")
    assert reference_note(None, 0, {"n_distinct": 1, "chosen_by": "middle"},
                          ["a.jpg", "b.jpg", "c.jpg"]).endswith(
        "(index 0 of 0..2, all 3 files are the same photo)")


def test_a_line_says_which_set_is_running(tmp_path, root, capsys):
    """A batch ran for minutes with nothing on the screen between two sets' lines (a
    fresh-user trial). One at a time, a line names the set as its pipeline starts
    (not on a terminal: once, just before the set's own line; a set skipped as done
    before gets none); with --jobs 2, one line says how many run at a time."""
    out = tmp_path / "out"
    main(["batch", str(root), "--out", str(out), "--max-scans", "1"])
    lines = capsys.readouterr().err.splitlines()
    for k, name in ((1, "a"), (3, "davis/b")):
        at = lines.index(f"[{k}/3] {name}: running")
        assert lines[at + 1].startswith(f"[{k}/3] {name}: ok"), lines
    assert not any(ln.startswith("[2/3] bad: running") for ln in lines)  # failed reading
    main(["batch", str(root), "--out", str(out), "--max-scans", "1"])
    assert ": running" not in capsys.readouterr().err  # skipped: done before
    main(["batch", str(root), "--out", str(tmp_path / "j2"), "--max-scans", "1",
          "--jobs", "2"])
    err = capsys.readouterr().err
    assert "3 sets, 2 at a time: a line as each one finishes" in err
    assert ": running" not in err  # (the workers' pipelines report to no one)


def test_the_running_set_is_one_line_redrawn_on_a_terminal():
    """SetProgress on a terminal: one line, redrawn (carriage return, erase), with the
    set, the stage's label and its share; ``clear`` erases it for the set's own line."""
    import io as _io

    from dynremove.progress import SetProgress

    class Tty(_io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    bar = SetProgress("[2/5] tim6:", stream=out, labels={"fusion": "fill by selection"})
    bar("features", 0.0)
    bar("fusion", 1.0)  # a stage's end is always drawn
    text = out.getvalue()
    assert "\n" not in text and text.count("\r\033[K") == 2
    assert text.endswith("[2/5] tim6: fill by selection 100 %  (0 s)")
    bar.clear()
    assert out.getvalue().endswith("\r\033[K") and not bar.drawn



def test_a_set_whose_output_folder_cannot_be_written_fails_before_its_analysis(
        tmp_path, root, monkeypatch, capsys):
    """A fresh-user trial's read-only set folder gave the row "PermissionError: [Errno
    13] Permission denied: '.../.clean.png.fl_0ho4r.tmp'", after the whole analysis. The
    set's folder (or the nearest one above it) is checked first, as `run` checks --out,
    and the row says what is wrong in one line; the other sets run on. (os.access is
    replaced: the tests may run as root, who may write anywhere.)"""
    out = tmp_path / "out"
    (out / "a").mkdir(parents=True)
    (out / "bad").write_text("a file where the set's folder goes")
    real_access = batch.os.access
    monkeypatch.setattr(batch.os, "access",
                        lambda p, mode: Path(p) != out / "a" and real_access(p, mode))
    analysed = []
    real_run = batch.remove_dynamic
    monkeypatch.setattr(batch, "remove_dynamic",
                        lambda images, **kw: analysed.append(len(images)) or real_run(images, **kw))
    assert main(["batch", str(root), "--out", str(out), *FAST]) == 1
    rows = summary_rows(out)
    assert rows["a"]["status"] == "error" and rows["a"]["error"] == f"{out / 'a'}: not writable"
    assert rows["bad"]["status"] == "error" and "is a file, not a folder" in rows["bad"]["error"]
    assert rows["davis/b"]["status"] == "ok"
    assert analysed == [4]  # davis/b only: neither failing set was analysed
    capsys.readouterr()


def test_a_set_written_whole_as_the_batch_is_cut_counts_as_finished(tmp_path, root, capsys,
                                                                    monkeypatch):
    """A fresh-user trial's --jobs 2 batch, cut by Ctrl-C, said "2 of 8 sets finished"
    and listed two sets in summary.json, while a third set's folder held its complete
    outputs, written by a worker as the interruption landed (a resume skipped it, as
    it should). Such a set is listed as finished: outputs of this batch (its key),
    written since it started."""
    from dynremove.cli import main

    real = batch.run_set

    def cut_after_writing(bs, *a, **k):
        row = real(bs, *a, **k)
        if bs.name == "davis/b":  # its outputs are on disk, its row never comes back
            raise KeyboardInterrupt
        return row

    monkeypatch.setattr(batch, "run_set", cut_after_writing)
    out = tmp_path / "out"
    rc = main(["batch", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 130
    rows = summary_rows(out)
    assert list(rows) == ["a", "bad", "davis/b"], rows
    assert rows["davis/b"]["status"] == "ok" and rows["davis/b"]["skipped"] == "False"
    assert float(rows["davis/b"]["jaccard_vs_gt"]) > 0
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and s["n_not_run"] == 0 and s["n_failed"] == 1
    assert s["workers"] == 1  # as a finished batch of --jobs 1 says (it said null)
    assert "2 of 3 sets finished" in err, err
    # outputs written before this batch started, or by a batch of other options, are
    # not this batch's
    b = {bs.name: bs for bs in batch.find_sets(root)}["davis/b"]
    opts = s["options"]
    assert batch._finished_on_disk(b, out, opts, since=0.0)["status"] == "ok"
    assert batch._finished_on_disk(b, out, opts, since=time.time() + 60) is None
    assert batch._finished_on_disk(b, out, {**opts, "max_side": 64}, since=0.0) is None


def test_links_are_searched_once_and_never_out_of_root(tmp_path):
    """A trial's link back up (``x/loop -> ..``) made batch run one set 41 times under
    ever longer names, and a link out of ROOT searched the folders above it. Each
    real folder is searched once, under its own name (links after the real folders),
    and a link that leaves ROOT is not followed: both said in a note."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "r"
    write_set(r / "trip", s.images)
    (r / "x").mkdir()
    (r / "x" / "loop").symlink_to("..")
    (r / "a").mkdir()
    (r / "a" / "alias").symlink_to("../trip")  # met before trip/ in name order
    write_set(tmp_path / "elsewhere", s.images)
    (r / "up").symlink_to("../elsewhere")
    notes: list[str] = []
    sets = batch.find_sets(r, notes=notes)
    assert [x.name for x in sets] == ["trip"]
    real = r.resolve()
    assert sorted(notes) == sorted([
        f"a/alias: a link to a folder searched already ({real / 'trip'}): not searched again",
        f"up: a link to a folder outside {r} ({(tmp_path / 'elsewhere').resolve()}): "
        "not searched",
        f"x/loop: a link to a folder searched already ({real}): not searched again"])
    # a link to a folder no other path reaches is searched, under the link's name
    write_set(r / "x" / "deep" / "real", s.images[:2])
    (r / "shortcut").symlink_to("x/deep")
    names = [x.name for x in batch.find_sets(r)]
    assert names == ["trip", "x/deep/real"]


def test_out_in_a_set_folder_is_refused_before_anything_is_written(tmp_path, capsys):
    """A trial's ``batch photos --out photos/trip1`` dropped trip1 from this batch and
    every later one, and wrote its summary among trip1's photos."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "photos"
    write_set(r / "trip1", s.images)
    write_set(r / "trip2" / "frames", s.images)
    before = sorted(p.name for p in (r / "trip1").iterdir())
    for out, where in ((r / "trip1", "is the folder"),
                       (r / "trip1" / "res", "is inside the folder"),
                       (r / "trip2", "is the folder")):
        assert main(["batch", str(r), "--out", str(out), *FAST]) == 2
        err = capsys.readouterr().err
        assert f"--out {out}: {where} of the set" in err and "Traceback" not in err
    assert sorted(p.name for p in (r / "trip1").iterdir()) == before
    assert not (r / "trip1" / "res").exists()
    assert main(["batch", str(r), "--out", str(r / "results"), *FAST]) == 0
    assert list(summary_rows(r / "results")) == ["trip1", "trip2"]


def test_a_video_beside_photos_or_named_as_a_photo_is_said_once(tmp_path, capsys):
    """A trial's clip.mp4 beside a set's photos was neither run nor named; a video
    named clip.jpg was "one photo only: not a set" and then a failing set."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "r"
    write_set(r / "mixed", s.images)
    clip = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10, (80, 64))
    for im in s.images * 3:
        w.write(im)
    w.release()
    (r / "mixed" / "clip.avi").write_bytes(clip.read_bytes())
    (r / "wrongext").mkdir()
    (r / "wrongext" / "clip.jpg").write_bytes(clip.read_bytes())
    notes: list[str] = []
    sets = batch.find_sets(r, notes=notes)
    assert [x.name for x in sets] == ["mixed", "wrongext/clip"]
    assert notes == ["mixed: skipped 1 video(s) beside its photos: clip.avi (a video is run "
                     "as a set of its own where its folder holds no set of photos)"]


def test_video_options_do_not_rerun_photo_sets_and_a_replaced_run_is_said(tmp_path, capsys):
    """A trial's second batch with another --span ran its photo sets again; one with
    another --ref replaced the outputs without a word (``run`` says it)."""
    s = synth.make_scene(seed=1, n_views=3, size=(64, 80), n_objects=1)
    r = tmp_path / "r"
    write_set(r / "trip", s.images)
    bs = batch.find_sets(r)[0]
    o = {"params": {}, "preset": "default", "max_side": None, "ref": None, "frames": None,
         "span": None, "pick": "sharpest"}
    assert batch.batch_key(bs, o) == batch.batch_key(bs, {**o, "span": "0:25", "frames": 5})
    assert batch.batch_key(bs, o) != batch.batch_key(bs, {**o, "ref": "view0.png"})
    out = tmp_path / "out"
    assert main(["batch", str(r), "--out", str(out), *FAST]) == 0
    capsys.readouterr()
    assert main(["batch", str(r), "--out", str(out), "--ref", "view0.png",
                 "--max-scans", "1"]) == 0
    row = json.loads((out / "summary.json").read_text())["sets"][0]
    said = [n for n in row["notes"] if "held the outputs of an earlier run" in n]
    assert not row["skipped"] and len(said) == 1
    assert said[0] in json.loads((out / "trip" / "report.json").read_text())["notes"]


def test_jobs_beyond_the_sets_starts_no_more_workers(tmp_path, root, capsys, monkeypatch):
    """``--jobs 16`` on one set started 16 worker processes (6.4 s against 1.5 s)."""
    import joblib
    made = []
    orig = joblib.Parallel.__init__

    def init(self, *a, **k):
        made.append(k.get("n_jobs"))
        orig(self, *a, **k)

    monkeypatch.setattr(joblib.Parallel, "__init__", init)
    import numba

    threads = numba.get_num_threads()
    assert main(["batch", str(root / "a"), "--out", str(tmp_path / "o"), "--jobs", "16",
                 *FAST]) == 0
    err = capsys.readouterr().err
    # run here, on all this process's threads (a pool of one ran it on one thread)
    assert made == [] and numba.get_num_threads() == threads
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["workers"] == 1
    assert "more sets at a time than" not in err

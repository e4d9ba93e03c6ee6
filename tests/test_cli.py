"""What ``dynremove run`` tells the user on the terminal: the reference it took and
how (middle, given, auto), the score against ``--gt`` on the summary line, the
progress stages named by what runs, and the help of ``--ref`` / ``--gt``.
(Refused inputs, ``--gt`` of another size among them: ``test_bad_input.py``.)"""

from __future__ import annotations

import dataclasses
import io as _pyio
import json
import os
import re
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove import io, pipeline
from dynremove.cli import build_parser, main
from dynremove.errors import InputError
from dynremove.progress import stage_labels
from dynremove.evaluation import synth
from dynremove.params import Params
from dynremove.progress import ProgressBar

FAST = ["--max-side", "64", "--max-scans", "1"]


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=1, n_views=4, size=(48, 64))


@pytest.fixture
def folder(tmp_path, scene) -> Path:
    d = tmp_path / "s"
    d.mkdir()
    for i, im in enumerate(scene.images):
        assert cv2.imwrite(str(d / f"view{i}.png"), im)
    return d


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main(["run", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def help_of(capsys, cmd: str) -> str:
    """``dynremove CMD --help`` on one line (the wrapping depends on the terminal)."""
    with pytest.raises(SystemExit):
        main([cmd, "--help"])
    return " ".join(capsys.readouterr().out.split())


# --- the score against --gt -----------------------------------------------------------
def test_gt_score_on_the_summary_line(tmp_path, capsys, scene, folder):
    gt = tmp_path / "gt.png"
    assert cv2.imwrite(str(gt), scene.masks[scene.ref_index].astype(np.uint8) * 255)
    out = tmp_path / "out"
    rc, stdout, err = run_cli(capsys, folder, "--gt", gt, "--out", out, *FAST)
    assert rc == 0, err
    J = json.loads((out / "report.json").read_text())["jaccard_vs_gt"]
    assert J > 0.3
    lines = stdout.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"wrote {out}/clean.png"), stdout
    assert f"J {J:.3f} against the given mask" in lines[0], stdout


def test_gt_at_the_analysis_size_is_scaled_to_the_photos(tmp_path, capsys):
    """A trial scored a run written with --output-size working and gave --gt at the
    size of the files written: refused, as of another size. A mask of the analysis
    size is now scaled up to the reference's (nearest pixel), with a note, and scores
    as the full-size mask does."""
    sc = synth.make_scene(seed=1, n_views=4, size=(96, 128))
    folder = tmp_path / "s"
    folder.mkdir()
    for i, im in enumerate(sc.images):
        assert cv2.imwrite(str(folder / f"view{i}.png"), im)
    mask = sc.masks[sc.ref_index].astype(np.uint8) * 255
    full = tmp_path / "gt_full.png"
    assert cv2.imwrite(str(full), mask)
    small = tmp_path / "gt_small.png"
    assert cv2.imwrite(str(small), cv2.resize(mask, (64, 48), interpolation=cv2.INTER_NEAREST))
    J = {}
    for gt in (full, small):
        out = tmp_path / gt.stem
        rc, _, err = run_cli(capsys, folder, "--gt", gt, "--max-side", 64, "--max-scans", 1,
                             "--output-size", "working", "--out", out)
        assert rc == 0, err
        assert cv2.imread(str(out / "dynamic_mask.png")).shape[:2] == (48, 64)
        J[gt] = json.loads((out / "report.json").read_text())["jaccard_vs_gt"]
        said = f"--gt {gt}: 64x48, the analysis size: scaled to the reference's 128x96"
        assert (said in err) == (gt == small), err
    assert J[full] > 0.3 and abs(J[small] - J[full]) < 0.03, J


def test_no_score_without_gt(tmp_path, capsys, folder):
    rc, stdout, err = run_cli(capsys, folder, "--out", tmp_path / "out", *FAST)
    assert rc == 0, err
    assert "wrote" in stdout and "against the given mask" not in stdout


def test_gt_help_says_it_is_scored(capsys):
    text = help_of(capsys, "run")
    assert "scored against it" in text and "jaccard_vs_gt" in text


@pytest.mark.parametrize("cmd", ["batch", "demo", "bench", "eval"])
def test_method_flags_are_listed_by_run_only(capsys, cmd):
    """The commands that pass the method's flags through take every one of them, and
    their help points at 'run --help' instead of listing sixty flags under their own
    options (a fresh-user trial lost bench's and eval's options that way)."""
    text = help_of(capsys, cmd)
    assert "--select-tau" in text and "'dynremove run --help' lists them" in text, text
    assert "--select-tau FLOAT" not in text and "--patch-size INT" not in text
    assert "--select-tau FLOAT" in help_of(capsys, "run")
    head = {"batch": ["root", "--out", "o"], "demo": [], "bench": [],
            "eval": ["data"]}[cmd]
    args = build_parser().parse_args([cmd, *head, "--select-tau", "7.5", "--no-snap"])
    assert args.p_select_tau == 7.5 and args.p_snap is False


@pytest.mark.parametrize("name", ["default", "paper"])
def test_bench_passes_its_parameters_to_the_run_it_times(name):
    """``bench --max-side`` times ``dynremove run`` in its own process with the
    bench's parameters: ``param_argv`` gives the flags that the run's parser turns
    back into the same Params (a bool either way, an int, a float, a choice)."""
    import dataclasses

    from dynremove.cli import build_parser
    from dynremove.commands import params_from_args
    from dynremove.evaluation.bench import param_argv
    from dynremove.params import preset

    base = preset(name)
    changed = dataclasses.replace(base, snap=not base.snap, patch_size=base.patch_size + 2,
                                  select_tau=base.select_tau + 0.1,
                                  flow_preset="fast" if base.flow_preset != "fast" else "medium")
    for p in (base, changed):
        argv = param_argv(p, name)
        assert params_from_args(build_parser().parse_args(["run", "x", *argv])) == p, argv
    assert param_argv(base, name) == ["--preset", name]


def test_bench_checks_its_json_before_the_bench_and_runs_small_views(tmp_path, capsys):
    """A trial's read-only folder ran the whole bench, then gave an internal error
    writing out/bench.json: the --json file is checked first (exit 2, at once). And a
    small --size that the bench accepts (200x150) cut an empty crop for its kernel
    comparison: an internal error after the whole bench."""
    import time

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    t = time.perf_counter()
    rc = main(["bench", "--json", str(blocker / "bench.json"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "cannot create its folder" in err and "a_file is a file" in err, err
    assert time.perf_counter() - t < 5.0  # (the bench itself takes tens of seconds)
    rc = main(["bench", "--size", "200x150", "--views", "3", "-q", "--json",
               str(tmp_path / "b.json")])
    assert rc == 0, capsys.readouterr().err
    assert json.loads((tmp_path / "b.json").read_text())["kernel_vs_reference"]["numba_s"] > 0


# --- the reference: named at the start, 0-based, negative from the end ----------------
@pytest.mark.parametrize("ref, line", [
    (None, "reference: view2.png (index 2 of 0..3, the later of the two middle images; "
           "--ref 1 for the other)"),
    ("0", "reference: view0.png (index 0 of 0..3, given by --ref 0)"),
    ("-1", "reference: view3.png (index 3 of 0..3, given by --ref -1)"),
    ("view1", "reference: view1.png (index 1 of 0..3, given by --ref view1)"),
    ("auto", "chosen by --ref auto"),
], ids=["middle", "index", "negative", "name", "auto"])
def test_the_run_names_its_reference(tmp_path, capsys, folder, ref, line):
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, folder, "--out", out, *FAST,
                         *(["--ref", ref] if ref is not None else []))
    assert rc == 0, err
    named = [ln for ln in err.splitlines() if "reference: " in ln]
    assert len(named) == 1, err
    assert named[0].startswith("dynremove: note: ") and line in named[0], named[0]
    # before any progress line, and the file the report names
    assert err.splitlines().index(named[0]) < err.splitlines().index(
        next(ln for ln in err.splitlines() if ln.startswith("features")))
    rep = json.loads((out / "report.json").read_text())
    assert f"reference: {rep['reference']['name']} (index {rep['reference']['index']} " \
        in named[0]


def test_quiet_names_nothing(tmp_path, capsys, folder):
    rc, stdout, err = run_cli(capsys, folder, "--out", tmp_path / "out", "--quiet", *FAST)
    assert rc == 0 and stdout == "" and "reference" not in err, err


@pytest.mark.parametrize("cmd", ["run", "batch", "eval"])
def test_ref_help_says_0_based_and_negative_from_the_end(capsys, cmd):
    text = help_of(capsys, cmd)
    ref = text[text.index("--ref REF "):]
    assert "0-based" in ref[:200] and "negative counts from the end" in ref[:200], ref[:200]


# --- progress stages named by what runs -----------------------------------------------
def test_progress_names_the_fill_that_runs():
    assert stage_labels(Params()) == {"fusion": "fill by selection"}
    assert stage_labels(Params(fill="median")) == {"fusion": "fused fill"}
    stream = _pyio.StringIO()  # not a terminal: one line per finished stage
    bar = ProgressBar(stream=stream, labels=stage_labels(Params()))
    bar("features", 1.0)
    bar("fusion", 1.0)
    bar.close()
    lines = stream.getvalue().splitlines()
    assert [ln.split("[")[0].strip() for ln in lines] == ["features", "fill by selection"]


@pytest.mark.parametrize("fill, label", [("select", "fill by selection"),
                                         ("median", "fused fill")])
def test_run_progress_and_report_keys(tmp_path, capsys, folder, fill, label):
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, folder, "--out", out, "--fill", fill, *FAST)
    assert rc == 0, err
    stages = [ln.split("[")[0].strip() for ln in err.splitlines() if "[" in ln]
    assert label in stages and "fusion" not in stages, err
    # report.json keeps the pipeline's key
    assert "fusion" in json.loads((out / "report.json").read_text())["seconds"]


def test_version(capsys):
    from dynremove import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"dynremove {__version__}"


# --- what a new user ran into ----------------------------------------------------------
def test_folder_order_counts_numbers_by_value(tmp_path, scene):
    """f8 before f10, as file managers order them (the middle image is then the middle one)."""
    d = tmp_path / "n"
    d.mkdir()
    names = ["f8.png", "f10.png", "F9.png", "f11.png"]
    for n, im in zip(names, scene.images):
        assert cv2.imwrite(str(d / n), im)
    paths, _ = io.list_inputs([d])
    assert [p.name for p in paths] == ["f8.png", "F9.png", "f10.png", "f11.png"]


def test_flags_of_a_stage_that_does_not_run_are_told(tmp_path, capsys, folder):
    """A trial ran ``--preset paper --fill median --select-tau 5``: accepted, written
    to report.json, and no word that the paper preset has no fill stage."""
    out = str(tmp_path / "o")
    rc, _, err = run_cli(capsys, folder, "--out", out, "--preset", "paper", "--fill",
                         "median", "--select-tau", "5", *FAST)
    assert rc == 0
    assert ("note: --fill, --select-tau: no effect with these settings (the fill stage "
            "is off: --no-fuse, as in the paper preset)") in err
    rc, _, err = run_cli(capsys, folder, "--out", out, "--no-snap", "--snap-iters", "2",
                         "--select-tau", "5", *FAST)
    assert rc == 0 and "note: --snap-iters: no effect with these settings (--no-snap)" in err


def test_the_same_file_twice_is_used_once(tmp_path, capsys, folder):
    files = sorted(folder.iterdir())
    paths, notes = io.list_inputs([files[0], *files, str(files[1])])
    assert paths == files
    assert len(notes) == 2 and all("given twice" in n and "used once" in n for n in notes)
    # one file three times: one note that says so, and the error lists it once
    _, notes = io.list_inputs([files[0], files[1], files[0], files[0]])
    assert notes == [f"{files[0]} is given 3 times: used once"]
    with pytest.raises(InputError) as e:
        io.list_inputs([files[0]] * 3)
    assert str(e.value).count(str(files[0])) == 2  # the listing and the note


def test_per_file_notes_are_grouped(tmp_path, capsys, scene):
    d = tmp_path / "g"
    d.mkdir()
    for i, im in enumerate(scene.images):
        assert cv2.imwrite(str(d / f"v{i}.png"), cv2.cvtColor(im, cv2.COLOR_BGR2GRAY))
    iset = io.load_image_set([d])
    grey = [n for n in iset.notes if "grayscale" in n]
    assert grey == ["v0.png, v1.png, v2.png, v3.png: grayscale image expanded to 3 channels"]


def test_probe_is_a_photo_pixel_scaled_to_the_analysis_image(tmp_path, capsys, folder):
    out = tmp_path / "out"
    rec = tmp_path / "run.rrd"
    rc, _, err = run_cli(capsys, folder, "--out", out, "--max-side", "32", "--max-scans",
                         "1", "--probe", "40,30", "--record", rec)
    assert rc == 0, err
    assert "--probe 40,30: pixel (20, 15) of the 32x24 analysis image" in err
    # report.json holds the lines printed (with -q, its notes are all a user gets: a
    # trial found neither the reference's line nor the probe's there)
    notes = json.loads((out / "report.json").read_text())["notes"]
    assert any(n.startswith("reference: ") for n in notes) and any(
        n.startswith("--probe 40,30: pixel (20, 15) of the 32x24") for n in notes), notes
    rc, _, err = run_cli(capsys, folder, "--out", out, "--probe", "64,10", "--record", rec,
                         *FAST)
    assert rc == 2 and "--probe 64,10: outside the 64x48 photo" in err
    # refused as soon as the photos are read: before the reference's note (a trial)
    assert "reference:" not in err, err
    # without a recording a probe does nothing: refused, as --compare is
    rc, _, err = run_cli(capsys, folder, "--out", out, "--probe", "40,30", *FAST)
    assert rc == 2 and "--probe needs --record" in err
    # nor do the recording's other flags (a trial's run took them and said nothing)
    rc, _, err = run_cli(capsys, folder, "--out", out, "--record-every-rows", "5",
                         "--record-detail", "full", *FAST)
    assert rc == 2 and "--record-every-rows, --record-detail need --record" in err
    rc, _, err = run_cli(capsys, folder, "--out", out, "--sample-static", "0.5", *FAST)
    assert rc == 2 and "--sample-static needs --record" in err


def test_flag_values_out_of_range_are_usage_errors(tmp_path, capsys, folder):
    """Fresh-user trial: --record-every-rows 0 was an internal error (exit 1) and
    --sample-static 2 was accepted; a file name that starts with '-' gets a hint."""
    out = tmp_path / "out"
    for flag, value, words in [("--record-every-rows", "0", "must be at least 1"),
                               ("--sample-static", "2", "fraction in [0, 1]"),
                               ("--sample-static", "-1", "fraction in [0, 1]"),
                               ("--ref", "-5.jpg", "write --ref=-5.jpg")]:
        with pytest.raises(SystemExit) as e:
            run_cli(capsys, folder, "--out", out, flag, value, *FAST)
        err = capsys.readouterr().err
        assert e.value.code == 2 and words in err and "Traceback" not in err, (flag, err)
    with pytest.raises(SystemExit) as e:
        main(["inspect", str(tmp_path / "x.rrd"), "--failures", "--top", "-3"])
    assert e.value.code == 2 and "must be at least 1" in capsys.readouterr().err
    # session 56's trial: composite --seed -5 was an internal error, bench --repeat 0
    # ran once without a word
    for argv, words in [(["composite", str(tmp_path), str(tmp_path), "--out", str(out),
                          "--seed", "-5"], "--seed: must be 0 or more, got -5"),
                        (["bench", "--repeat", "0"], "--repeat: must be at least 1, got 0")]:
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and words in err and err.count("\n") == 1, err
    # the smallest --max-side these 64x48 photos allow is named
    rc, _, err = run_cli(capsys, folder, "--out", out, "--max-side", "16")
    assert rc == 2 and "give at least --max-side 22" in err, err


def test_a_set_folder_names_its_image_subfolder(tmp_path, capsys, folder):
    """`run davis/dance-twirl` (a set folder, photos in frames/) said only 'found 0'."""
    (tmp_path / "set").mkdir()
    folder.rename(tmp_path / "set" / "frames")
    rc, _, err = run_cli(capsys, tmp_path / "set", "--out", tmp_path / "out", *FAST)
    assert rc == 2 and f"such as {tmp_path / 'set' / 'frames'} (4 images)" in err, err


def test_a_run_that_finds_nothing_says_so(tmp_path, capsys, scene):
    d = tmp_path / "still"
    d.mkdir()
    for i in range(3):  # the same static view three times, with a little noise
        noisy = np.clip(scene.background.astype(int) + i, 0, 255).astype(np.uint8)
        assert cv2.imwrite(str(d / f"v{i}.png"), noisy)
    rc, _, err = run_cli(capsys, d, "--out", tmp_path / "out", *FAST)
    assert rc == 0, err
    assert "nothing was found moving in the reference" in err


def test_gt_that_is_not_a_mask_gets_a_note(tmp_path, capsys, scene, folder):
    out = tmp_path / "out"
    photo = tmp_path / "photo.png"
    assert cv2.imwrite(str(photo), scene.images[scene.ref_index])
    rc, _, err = run_cli(capsys, folder, "--gt", photo, "--out", out, *FAST)
    assert rc == 0, err
    assert "are neither black nor white: is it a mask" in err
    gt = tmp_path / "gt.png"
    assert cv2.imwrite(str(gt), scene.masks[scene.ref_index].astype(np.uint8) * 255)
    rc, _, err = run_cli(capsys, folder, "--gt", gt, "--out", out, *FAST)
    assert rc == 0 and "neither black nor white" not in err


def test_an_analysis_too_large_for_the_memory_is_refused(tmp_path, capsys, folder,
                                                         monkeypatch):
    """The estimate scales with views × analysed pixels; over the machine's memory it is
    a one-line error, before any work, naming what would lower it: --max-side where
    the photos are larger than its default (a trial's 960-px frames were told to use
    it, which changes nothing there), else fewer or smaller photos."""
    monkeypatch.setattr(pipeline, "MEMORY_BYTES_PER_PX", 1e6)  # 4 views × 64×48 → ~12 GB
    monkeypatch.setattr(pipeline, "physical_memory", lambda: 8e9)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, folder, "--out", out, *FAST)
    assert rc == 2 and "more than this machine's 8 GB: use fewer or smaller photos" in err, err
    assert "--max-side" not in err and not out.exists()
    big = tmp_path / "big"
    big.mkdir()
    for i in range(3):
        assert cv2.imwrite(str(big / f"p{i}.png"),
                           np.random.default_rng(i).integers(40, 200, (20, 1400, 3), np.uint8))
    monkeypatch.setattr(pipeline, "MEMORY_BYTES_PER_PX", 1e5)  # 3 × 1400×20 → ~8.4 GB
    rc, _, err = run_cli(capsys, big, "--max-side", "0", "--out", out, "--max-scans", "1")
    assert rc == 2 and "more than this machine's 8 GB: use --max-side 1280" in err, err
    assert not out.exists()
    monkeypatch.setattr(pipeline, "MEMORY_BYTES_PER_PX", 1e6)
    monkeypatch.setattr(pipeline, "physical_memory", lambda: 64e9)
    rc, _, err = run_cli(capsys, folder, "--out", out, *FAST)
    assert rc == 0 and "needs about 13 GB of memory (this machine has 64 GB)" in err, err


def test_a_closed_pipe_is_not_an_error(tmp_path):
    """`dynremove ... | head -1`: the reader goes away; exit 141 (as a process killed by
    SIGPIPE), nothing on stderr, no traceback."""
    import subprocess
    import sys

    code = ("import sys\nfrom dynremove import cli\n"
            "def fn(args):\n    for _ in range(20000):\n        print('x' * 100)\n    return 0\n"
            "cli.cmd_inspect = fn  # a command with much output\n"
            "sys.exit(cli.main(['inspect', 'nothing.rrd']))\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, cwd=tmp_path)
    p.stdout.read(10)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait() == 141 and err == "", err


@pytest.mark.parametrize("record", [False, True])
def test_the_compile_note_follows_numbas_own_cache(tmp_path, record):
    """kernels_cached asks numba's index (a hash of the source's content) for the
    kernel that the run calls (recorded or not): a copy of the package with its
    cache is cached; an edited kernel file, or no cache, is not."""
    import shutil
    import subprocess
    import sys

    import dynremove
    from dynremove.method.scan.driver import compiled_kernels

    pkg = Path(dynremove.__file__).parent
    for k in compiled_kernels(record):
        if not list((pkg / "method" / "scan" / "__pycache__").glob(f"_kernels.{k.__name__}-*.nbi")):
            pytest.skip(f"the scan kernel {k.__name__} has not been compiled in this tree yet")
    shutil.copytree(pkg, tmp_path / "dynremove")
    probe = [sys.executable, "-c", "from dynremove.commands import kernels_cached as k; "
             f"print(k({record}))"]

    def cached() -> str:
        return subprocess.run(probe, cwd=tmp_path, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(tmp_path)}).stdout.strip()

    assert cached() == "True"
    with open(tmp_path / "dynremove" / "method" / "scan" / "_kernels.py", "a") as f:
        f.write("\n# edited\n")
    assert cached() == "False"


@pytest.mark.parametrize("record", [False, True])
def test_the_kernels_the_compile_note_waits_for_are_called_by_every_run(monkeypatch, record):
    """``compiled_kernels`` lists only kernels that a run of the default preset calls,
    even one that stops after its first scan (the default's usual run): a kernel
    listed but never called is never cached, and every run then said "compiling the
    scan kernels (once per install, about 30-60 s ...)" (a fresh-user trial)."""
    from dynremove.events import MemorySink, NullSink
    from dynremove.evaluation import synth
    from dynremove.method.scan import _kernels as kn
    from dynremove.method.scan.driver import compiled_kernels
    from dynremove.pipeline import remove_dynamic

    listed = {k.__name__ for k in compiled_kernels(record)}
    called = set()
    for name in ("_scan", "_decide_all"):
        real = getattr(kn, name)

        def spy(*a, _real=real, _name=name, **k):
            called.add(_name)
            return _real(*a, **k)

        monkeypatch.setattr(kn, name, spy)
    scene = synth.make_scene(seed=0, n_views=4, size=(96, 128))
    res = remove_dynamic(scene.images, ref=scene.ref_index,
                         sink=MemorySink() if record else NullSink())
    assert len(res.scans) == 1  # the case: one scan
    assert listed <= called, (listed, called)


def test_an_empty_ref_is_an_error_not_the_default(capsys, folder):
    with pytest.raises(SystemExit) as e:
        main(["run", str(folder), "--ref", ""])
    assert e.value.code == 2 and "--ref '': give an index" in capsys.readouterr().err


@pytest.mark.parametrize("args,line", [
    (["--ref", "3", "--ref", "2"], "--ref 3 and --ref 2 both given: give --ref once"),
    (["--patch-size=9", "--patch-size", "11"],
     "--patch-size=9 and --patch-size 11 both given: give --patch-size once"),
    (["--snap", "--no-snap"], "--snap and --no-snap both given: give one of them"),
])
def test_a_flag_given_twice_with_two_values_is_an_error(capsys, folder, args, line):
    """argparse keeps the last value silently; a user who wrote two meant one of them."""
    with pytest.raises(SystemExit) as e:
        main(["run", str(folder), *args])
    assert e.value.code == 2 and line in capsys.readouterr().err


def test_a_flag_given_twice_with_one_value_is_accepted():
    ns = build_parser().parse_args(["run", "a.jpg", "b.jpg", "--ref", "1", "--ref=1"])
    assert ns.ref == "1"


def test_two_videos_are_named_as_videos(tmp_path, folder):
    """Frames come from one video given alone; two videos (or a video among images) get
    a line that says so, not 'not a readable image'."""
    vids = []
    for name in ("a.mp4", "b.mp4"):
        w = cv2.VideoWriter(str(tmp_path / name), cv2.VideoWriter_fourcc(*"mp4v"), 5, (64, 48))
        if not w.isOpened():
            pytest.skip("OpenCV cannot write MP4 here")
        for _ in range(3):
            w.write(np.zeros((48, 64, 3), np.uint8))
        w.release()
        vids.append(tmp_path / name)
    with pytest.raises(InputError, match="a.mp4: is a video; give one video alone"):
        io.list_inputs(vids)


# --- a fresh user's second round ---------------------------------------------------------
def two_folders_with_the_same_name(tmp_path, scene) -> list[Path]:
    """a/x.png, b/x.png and c/other.png: two inputs named x.png."""
    paths = []
    for sub, name, im in zip("abc", ["x.png", "x.png", "other.png"], scene.images):
        (tmp_path / sub).mkdir()
        assert cv2.imwrite(str(tmp_path / sub / name), im)
        paths.append(tmp_path / sub / name)
    return paths


def test_ref_as_a_path_picks_exactly_that_file(tmp_path, capsys, scene, monkeypatch):
    paths = two_folders_with_the_same_name(tmp_path, scene)
    monkeypatch.chdir(tmp_path)
    for ref, index in [(paths[1], 1), (paths[0], 0), ("b/x.png", 1), ("./a/x.png", 0)]:
        out = tmp_path / f"out{index}"
        rc, _, err = run_cli(capsys, *paths, "--ref", ref, "--out", out, *FAST)
        assert rc == 0, err
        rep = json.loads((out / "report.json").read_text())["reference"]
        assert rep["index"] == index and rep["chosen_by"] == "given", (ref, rep)
        assert f"(index {index} of 0..2, given by --ref {ref})" in err


@pytest.mark.parametrize("how", ["missing", "another-folder"])
def test_ref_path_that_is_not_an_input_is_an_error(tmp_path, capsys, folder, how):
    """Before: matched by its file name (FOLDER/view1.png taken, exit 0)."""
    other = tmp_path / "elsewhere"
    if how == "another-folder":
        other.mkdir()
        (other / "view1.png").write_bytes((folder / "view1.png").read_bytes())
    ref = other / "view1.png"
    out = tmp_path / "out"
    rc, stdout, err = run_cli(capsys, folder, "--ref", ref, "--out", out, *FAST)
    assert rc == 2 and stdout == "", err
    lines = err.strip().splitlines()
    assert lines[-1].startswith(f"dynremove: error: --ref {ref}: is not one of the input "
                                "images"), err
    assert ("no such file" in lines[-1]) == (how == "missing")
    assert "Traceback" not in err and not out.exists()


def test_ref_name_that_several_inputs_have_is_an_error(tmp_path, capsys, scene):
    paths = two_folders_with_the_same_name(tmp_path, scene)
    for ref in ("x.png", "x"):
        rc, _, err = run_cli(capsys, *paths, "--ref", ref, "--out", tmp_path / "out", *FAST)
        assert rc == 2, err
        line = err.strip().splitlines()[-1]
        assert line.startswith(f"dynremove: error: --ref {ref}: 2 input images have this "
                               "name"), err
        assert f"{paths[0]} (index 0), {paths[1]} (index 1)" in line, line
    # a name only one input has still works
    rc, _, err = run_cli(capsys, *paths, "--ref", "other", "--out", tmp_path / "out", *FAST)
    assert rc == 0 and "reference: other.png (index 2 of 0..2, given by --ref other)" in err


@pytest.mark.parametrize("cmd", ["batch", "eval"])
def test_ref_of_every_set_refuses_a_path(tmp_path, capsys, folder, cmd):
    argv = [cmd, str(folder), "--ref", str(folder / "view1.png")]
    with pytest.raises(SystemExit) as e:
        main(argv + (["--out", str(tmp_path / "o")] if cmd == "batch" else []))
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert "not a path (e.g. --ref view1.png)" in err


@pytest.mark.parametrize("flag, value, line", [
    ("--t-r", "5", "dynremove: error: --t-r 5.0: must be in [0, 1]"),
    ("--select-tau", "-1", "dynremove: error: --select-tau -1.0: must be > 0"),
    ("--patch-size", "4", "dynremove: error: --patch-size 4: must be odd and >= 3"),
    ("--dbscan-min-pts", "0", "dynremove: error: --dbscan-min-pts 0: must be >= 1"),
    ("--correspondence", "magic", "dynremove: error: --correspondence magic: must be "
                                  "homography+flow, homography, flow or gated"),
    ("--refine-tau", "-1", "dynremove: error: --refine-tau must be >= 0 and "
                           "--refine-shrink-frac in (0, 1]"),
])
def test_parameter_errors_name_the_flag(tmp_path, capsys, folder, flag, value, line):
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, folder, flag, value, "--out", out)
    assert rc == 2 and err.startswith(line) and err.count("\n") == 1, err
    assert not out.exists()


def test_parameter_error_messages_use_flags_for_every_field():
    from dynremove.commands import flag_message

    assert flag_message("t_r must be in [0, 1], got 5.0") == "--t-r 5.0: must be in [0, 1]"
    assert (flag_message("fill must be select or median, got 'x'")
            == "--fill x: must be select or median")
    for f in dataclasses.fields(Params):
        msg = flag_message(f"{f.name} must be > 0, got -1")
        assert msg == f"--{f.name.replace('_', '-')} -1: must be > 0", msg


def test_composite_help_gives_every_option_a_help_and_its_default(capsys):
    text = help_of(capsys, "composite")
    opts = text[text.index("options:"):]
    helps = {}
    for flag, nxt in [("--out DIR", "--seed"), ("--seed SEED", "--n-views"),
                      ("--n-views N", "--objects"), ("--objects K", "--n-sets"),
                      ("--n-sets N", None)]:
        start = opts.index(flag) + len(flag)
        helps[flag] = opts[start:opts.index(nxt, start) if nxt else None].strip()
        assert len(helps[flag]) > 10, (flag, helps[flag])
    assert "required" in helps["--out DIR"]
    for flag, default in [("--seed SEED", "default 0"), ("--n-views N", "default 6"),
                          ("--objects K", "default 1"), ("--n-sets N", "default 0")]:
        assert default in helps[flag], (flag, helps[flag])


def test_inspect_a_folder_says_it_is_a_folder(tmp_path, capsys):
    d = tmp_path / "run.rrd"
    d.mkdir()
    for cmd in (["inspect", str(d), "--pixel", "1,1"],
                ["export", str(d), "--out", str(tmp_path / "x.gif")]):
        assert main(cmd) == 2
        err = capsys.readouterr().err
        assert err == f"dynremove: error: {d}: is a folder, not a recording\n", err
    assert main(["inspect", str(tmp_path / "none.rrd"), "--pixel", "1,1"]) == 2
    assert "none.rrd: no such recording" in capsys.readouterr().err


def test_the_report_says_whether_the_set_was_treated_as_flat_or_3d(tmp_path, capsys, folder):
    """Several default steps switch on the set's median parallax (the clean-up's
    majority filter, GrabCut's veto, the epipolar search, the fill's consensus):
    report.json says which way the run went; the paper preset has none of them."""
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, folder, "--out", out, *FAST)
    assert rc == 0, err
    sc = json.loads((out / "report.json").read_text())["scene"]
    assert sc["parallax_threshold_px"] == Params().select_parallax_px
    assert sc["parallax_p95_threshold_px"] == Params().select_parallax_p95_px
    flat = (sc["median_parallax_px"] <= sc["parallax_threshold_px"]
            and sc["median_parallax_p95_px"] <= sc["parallax_p95_threshold_px"])
    assert sc["treated_as"] == ("flat" if flat else "3-D")
    rc, _, err = run_cli(capsys, folder, "--out", tmp_path / "p", *FAST,
                         "--select-parallax-px", "0")
    assert rc == 0, err
    sc0 = json.loads((tmp_path / "p" / "report.json").read_text())["scene"]
    assert sc0["parallax_threshold_px"] == 0.0
    assert sc0["treated_as"] == ("3-D" if sc0["median_parallax_px"] > 0 else "flat")
    rc, _, err = run_cli(capsys, folder, "--out", tmp_path / "paper", *FAST,
                         "--preset", "paper")
    assert rc == 0, err
    assert "scene" not in json.loads((tmp_path / "paper" / "report.json").read_text())


def test_without_out_each_scene_gets_its_own_folder(tmp_path, monkeypatch, capsys, scene):
    """A run without --out writes to out/<the input's name>: a fresh-user trial lost
    the first scene's outputs to the second run (both went to out/run). A folder
    named ``frames`` is named by its parent."""
    from dynremove.io import default_out_dir

    for name in ("alpha", "beta"):
        d = tmp_path / name / "frames"
        d.mkdir(parents=True)
        for i, im in enumerate(scene.images):
            assert cv2.imwrite(str(d / f"v{i}.png"), im)
    monkeypatch.chdir(tmp_path)
    for name in ("alpha", "beta"):
        rc, out, _ = run_cli(capsys, tmp_path / name / "frames", "-q")
        assert rc == 0
    for name in ("alpha", "beta"):
        assert (tmp_path / "out" / name / "clean.png").is_file(), name
    assert not (tmp_path / "out" / "run").exists()
    assert default_out_dir([tmp_path / "alpha" / "frames" / "v0.png",
                            tmp_path / "alpha" / "frames" / "v1.png"]) == Path("out/alpha")
    assert default_out_dir(["clips/street walk.mp4"]) == Path("out/street_walk")
    assert default_out_dir([tmp_path / "alpha" / "frames" / "v0.png",
                            tmp_path / "beta" / "frames" / "v1.png"]) == Path("out/run")


def test_a_stop_raised_inside_a_destructor_prints_no_traceback():
    """A Ctrl-C that lands while numba compiles is raised inside llvmlite's ``__del__``:
    Python printed it as "Exception ignored ... Traceback" next to the command's one
    line (a fresh clone's CI caught it once). The command's hook keeps it quiet (the
    stop is kept and raised again by the run); any other such error still goes to
    the previous hook, which prints it."""
    from dynremove.cli import _quiet_stops
    from dynremove.errors import Terminated

    class Freed:
        def __init__(self, exc):
            self.exc = exc

        def __del__(self):
            raise self.exc

    passed_on = []
    old = sys.unraisablehook
    sys.unraisablehook = _quiet_stops(passed_on.append)
    try:
        for exc in (KeyboardInterrupt(), Terminated(), ValueError("a real error")):
            obj = Freed(exc)
            del obj
    finally:
        sys.unraisablehook = old
    assert [type(u.exc_value) for u in passed_on] == [ValueError]


@pytest.mark.parametrize("cached, record, says", [
    ({False: True, True: True}, True, None),
    ({False: True, True: False}, True, "a recorded run adds (once per install, a few seconds"),
    ({False: False, True: False}, True, "once per install, about 30-60 s"),
    ({False: False, True: False}, False, "once per install, about 30-60 s")])
def test_the_compile_note_says_what_this_run_compiles(monkeypatch, capsys, cached, record,
                                                      says):
    """A recorded run after plain runs compiles only the recorded scan's kernels: its
    note does not promise 30-60 s again (a fresh-user trial)."""
    import argparse

    from dynremove import commands

    monkeypatch.setattr(commands, "kernels_cached", lambda rec=False: cached[bool(rec)])
    commands._note_compile(argparse.Namespace(record="x.rrd" if record else None,
                                              quiet=False))
    err = capsys.readouterr().err
    assert (says in err) if says else err == "", err


def test_a_run_into_an_earlier_runs_folder_says_it_replaces_it(folder, tmp_path, capsys):
    """A fresh-user trial: an existing --out folder was overwritten without a word.
    The first run into a folder says nothing of it; the second notes the replacement
    (and, as a later trial read "replaces them" before an error, that only a run that
    gets its results replaces them)."""
    out = tmp_path / "o"
    rc, _, err = run_cli(capsys, folder, "--out", out)
    assert rc == 0 and "earlier run's outputs" not in err
    rc, _, err = run_cli(capsys, folder, "--out", out)
    assert rc == 0
    assert f"note: {out} holds an earlier run's outputs (its report.json): this run " \
           "replaces them once it has its own (a run that fails leaves them)" in err


def test_compare_is_checked_before_the_photos_are_read(tmp_path, capsys, monkeypatch):
    """--compare without --record, or with an unknown field, failed only after the
    photos were loaded (a trial): both are refused before any reading."""
    from dynremove import commands
    monkeypatch.setattr(commands, "load_for_reference",
                        lambda *a, **k: pytest.fail("the photos were read"))
    d = tmp_path / "never"
    for argv, words in ((["--compare", "paper"], "--compare needs --record"),
                        (["--compare", "t_r=0.5,foo=1", "--record", str(tmp_path / "r.rrd")],
                         "foo")):
        rc, _, err = run_cli(capsys, d, "--out", tmp_path / "o", *argv)
        assert rc == 2 and words in err, err
    assert not (tmp_path / "o").exists()


def test_a_failed_run_leaves_no_empty_default_out_folder(tmp_path, capsys, monkeypatch):
    """With the default --out, a run that fails left an empty out/ (a trial): the
    folders the run created are removed again, out/ included, not the ones it found."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene").mkdir()
    rc, _, err = run_cli(capsys, tmp_path / "scene")  # no images: exit 2
    assert rc == 2 and not (tmp_path / "out").exists(), err
    (tmp_path / "out").mkdir()
    rc, _, _ = run_cli(capsys, tmp_path / "scene")
    assert rc == 2 and (tmp_path / "out").is_dir() and not (tmp_path / "out" / "scene").exists()


def test_a_users_file_named_as_an_output_is_noted_before_it_is_replaced(folder, tmp_path,
                                                                        capsys):
    """A trial's own clean.png in --out (no report.json beside it) was replaced in
    silence; the run now says which of its files it replaces."""
    out = tmp_path / "mine"
    out.mkdir()
    cv2.imwrite(str(out / "clean.png"), np.zeros((4, 4, 3), np.uint8))
    rc, _, err = run_cli(capsys, folder, "--out", out)
    assert rc == 0
    assert f"{out} holds clean.png, not from a dynremove run (no report.json beside): " \
           "this run replaces it" in err


def test_run_help_opens_with_the_few_flags_that_matter(capsys):
    """``run --help`` opened with a 50-line synopsis of every method flag (a fresh-user
    trial could not find --ref, --out or --max-side). Its usage is two lines naming
    those, and the description says the method parameters are the last group."""
    with pytest.raises(SystemExit) as e:
        main(["run", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    usage = text.split("\n\n")[0]
    assert usage.startswith("usage: dynremove run [-h] [--ref REF] [--out OUT] [--max-side PX]")
    assert len(usage.splitlines()) == 2 and "--patch-size" not in usage
    groups = [ln for ln in text.splitlines() if ln and not ln.startswith(" ") and ln.endswith(":")]
    assert groups[-1].startswith("method parameters")  # the last group, as the text says
    assert "the method parameters (the last group below)" in " ".join(text.split())


@pytest.mark.parametrize("cmd", ["batch", "eval"])
@pytest.mark.parametrize("jobs", ["0", "-5"])
def test_jobs_is_a_count_or_all_cores(tmp_path, capsys, cmd, jobs):
    """``--jobs -5`` ran (joblib: all cores but four, one at a time here) and was
    recorded as -5 while the help names only -1 (a fresh-user trial): refused, as 0 is,
    in one line and with exit code 2, before any work."""
    args = [cmd, str(tmp_path), "--jobs", jobs] + (["--out", str(tmp_path / "o")]
                                                    if cmd == "batch" else [])
    with pytest.raises(SystemExit) as e:
        main(args)
    err = capsys.readouterr().err
    assert e.value.code == 2 and "Traceback" not in err
    assert f"--jobs must be a count of at least 1, or -1 for all cores, got {jobs}" in err
    assert not (tmp_path / "o").exists()


def test_the_demo_scores_itself_and_says_what_to_try_next(tmp_path, capsys):
    """`make demo` runs this: the synthetic scene's truth scores the run, the outputs
    and the recording are written, and the last lines name the commands to try next
    on that recording (a trial found the demo said nothing of what to do after it)."""
    out, rec = tmp_path / "demo", tmp_path / "demo.rrd"
    assert main(["demo", "--out", str(out), "--record", str(rec)]) == 0
    text = capsys.readouterr().out
    J = float(re.search(r"Jaccard \(dynamic mask vs truth\): +([0-9.]+)", text).group(1))
    assert J > 0.8, text
    assert all((out / n).is_file() for n in ("clean.png", "gt_mask.png")) and rec.is_file()
    tail = text.splitlines()[-4:]
    assert tail[0] == "next:" and tail[1].startswith(f"  dynremove view {rec} ") \
        and tail[2].startswith(f"  dynremove inspect {rec} --failures ") \
        and tail[3].startswith("  dynremove run YOUR_PHOTOS/"), text
    assert main(["inspect", str(rec), "--failures"]) == 0  # the line it offers works


def test_the_commands_offered_next_are_ones_the_shell_finds(tmp_path, monkeypatch):
    """After `make demo` the venv is not on the PATH: the demo's "next:" lines name
    the script that ran (a trial typed `dynremove view …` and got "command not
    found"), and plain `dynremove` where the shell finds that same script."""
    from dynremove import commands

    script = tmp_path / ".venv" / "bin" / "dynremove"
    script.parent.mkdir(parents=True)
    script.write_text("#!/bin/sh\n")
    script.chmod(0o755)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", [str(script), "demo"])
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    assert commands._program_name() == os.path.join(".venv", "bin", "dynremove")
    monkeypatch.setenv("PATH", str(script.parent) + os.pathsep + "/usr/bin:/bin")
    assert commands._program_name() == "dynremove"
    monkeypatch.setattr(sys, "argv", ["/x/dynremove/__main__.py"])  # python -m dynremove
    assert commands._program_name() == "dynremove"


def test_a_users_viewer_py_shadowing_the_debugger_is_named(tmp_path, folder):
    """A ``viewer.py`` of the user's in the folder ``python -m dynremove`` runs from
    shadows the debugger's top-level package: "internal error: No module named
    'viewer.sink'" (a fresh-user trial's notebook folder). Now one line naming the
    file, exit 2, before anything is written."""
    import subprocess
    import sys

    work = tmp_path / "notebooks"
    work.mkdir()
    (work / "viewer.py").write_text("x = 1\n")
    p = subprocess.run([sys.executable, "-m", "dynremove", "run", str(folder), "--out",
                        str(tmp_path / "out"), "--record", str(tmp_path / "r.rrd"), "-q"],
                       cwd=work, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip() == (f"dynremove: error: the debugger's package 'viewer' is "
                                f"shadowed by {work / 'viewer.py'}: rename that file (or "
                                "folder), or run from another folder"), p.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "r.rrd").exists()


def test_a_photo_left_out_that_moved_the_middle_is_said(tmp_path, capsys):
    """A trial added a photo of another scene to dance-twirl's seven: it was left out,
    but the default reference, the middle of the photos given, had moved to the next
    frame, and --gt scored it against the wrong one. The note names the middle of
    the photos used."""
    sc = synth.make_scene(seed=3, n_views=5, size=(240, 320), n_objects=1)
    d = tmp_path / "set"
    d.mkdir()
    for i, im in enumerate(sc.images):
        cv2.imwrite(str(d / f"view{i}.png"), im)
    rng = np.random.default_rng(1)
    t = cv2.GaussianBlur(rng.uniform(0, 255, sc.images[0].shape).astype(np.float32),
                         (0, 0), 2.0)
    cv2.imwrite(str(d / "view9.png"), np.clip((t - t.mean()) * 4 + 128, 0, 255))
    rc, _, err = run_cli(capsys, d, "--out", tmp_path / "o", "--max-scans", "1")
    assert rc == 0, err
    assert "left out, no homography with the reference: view9.png" in err
    assert ("the reference is the middle of the photos given; of the 5 used, the middle "
            "is view2.png: --ref view2.png to take it") in err
    notes = json.loads((tmp_path / "o" / "report.json").read_text())["notes"]
    assert any(n.startswith("the reference is the middle of the photos given") for n in notes)

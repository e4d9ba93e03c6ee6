"""What ``dynremove run`` tells the user on the terminal: the reference it took and
how (middle, given, auto), the score against ``--gt`` on the summary line, the
progress stages named by what runs, and the help of ``--ref`` / ``--gt``.
(Refused inputs, ``--gt`` of another size among them: ``test_bad_input.py``.)"""

from __future__ import annotations

import io as _pyio
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove.cli import main
from dynremove.commands import stage_labels
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


def test_no_score_without_gt(tmp_path, capsys, folder):
    rc, stdout, err = run_cli(capsys, folder, "--out", tmp_path / "out", *FAST)
    assert rc == 0, err
    assert "wrote" in stdout and "against the given mask" not in stdout


def test_gt_help_says_it_is_scored(capsys):
    text = help_of(capsys, "run")
    assert "scored against it" in text and "jaccard_vs_gt" in text


# --- the reference: named at the start, 0-based, negative from the end ----------------
@pytest.mark.parametrize("ref, line", [
    (None, "reference: view2.png (index 2 of 0..3, the middle image)"),
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

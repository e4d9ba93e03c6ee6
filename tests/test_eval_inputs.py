"""`eval` finds frames by content, as `run` and `batch` do (issue 12, item 2)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from dynremove.cli import main
from dynremove.evaluation import synth
from dynremove.evaluation.evaluate import find_sets, image_files


@pytest.fixture(scope="module")
def odd_set(tmp_path_factory) -> Path:
    """An eval set whose frames are .avif (if OpenCV writes it), suffix-less, .dat;
    frames/ also holds a text file and masks/ the true masks (found by stem)."""
    root = tmp_path_factory.mktemp("data")
    scene = synth.make_scene(seed=1, n_views=4, size=(72, 96), n_objects=1)
    synth.write_scene(scene, root / "odd")
    fr = root / "odd" / "frames"
    names = sorted(p.name for p in fr.iterdir())
    assert len(names) == 4
    avif = cv2.haveImageWriter("x.avif")
    if avif:  # re-encode one frame as AVIF: not in io.IMAGE_EXTS
        im = cv2.imread(str(fr / names[0]))
        assert cv2.imwrite(str(fr / (Path(names[0]).stem + ".avif")), im)
        (fr / names[0]).unlink()
    (fr / names[1]).rename(fr / Path(names[1]).stem)  # no suffix at all
    (fr / names[3]).rename(fr / (Path(names[3]).stem + ".dat"))  # an odd one
    (fr / "notes.txt").write_text("not an image\n")
    (fr / "empty.png.part").write_bytes(b"")
    return root


def test_frames_found_by_content(odd_set):
    fr = odd_set / "odd" / "frames"
    found = [p.name for p in image_files(fr)]
    assert "notes.txt" not in found and "empty.png.part" not in found
    assert len(found) == 4, found
    if cv2.haveImageWriter("x.avif"):
        assert any(n.endswith(".avif") for n in found)
    assert any("." not in n for n in found) and any(n.endswith(".dat") for n in found)
    (s,) = find_sets(odd_set)
    assert [p.name for p in s.frames] == found
    assert all(s.mask_path(p) is not None for p in s.frames)  # masks/<stem>.png


def test_eval_runs_on_frames_found_by_content(odd_set, tmp_path, capsys):
    out = tmp_path / "e.json"
    rc = main(["eval", str(odd_set), "--methods", "dynremove", "--max-scans", "1",
               "--json", str(out), "--quiet"])
    capsys.readouterr()
    assert rc == 0
    (row,) = json.loads(out.read_text())["sets"]
    assert row["set"] == "odd" and row["jaccard"] is not None and row["jaccard"] > 0.3

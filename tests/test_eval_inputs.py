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


@pytest.mark.parametrize("truth", ["mask", "background", "free"])
def test_truth_of_another_size_is_refused_not_resized(tmp_path, capsys, truth):
    """A fresh-user trial gave eval camel's masks at 300x500 (the frames 854x480): they
    were stretched into place and scored (J 0.316, exit 0), where `run --gt` refuses
    the same file. A mask, background or free map that is not the frames' own size is
    now the set's error (exit 1, the file and both sizes named); the right size scores."""
    import numpy as np

    scene = synth.make_scene(seed=1, n_views=3, size=(72, 96), n_objects=1)
    synth.write_scene(scene, tmp_path / "data" / "s")
    d = tmp_path / "data" / "s"
    assert (d / "background.png").is_file()  # (written by write_scene)
    assert cv2.imwrite(str(d / "free.png"), np.full((72, 96), 255, np.uint8))
    assert main(["eval", str(tmp_path / "data"), "--methods", "median", "--quiet"]) == 0
    capsys.readouterr()
    f = {"mask": sorted((d / "masks").iterdir())[1], "background": d / "background.png",
         "free": d / "free.png"}[truth]
    im = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    assert cv2.imwrite(str(f), cv2.resize(im, (50, 90), interpolation=cv2.INTER_NEAREST))
    assert main(["eval", str(tmp_path / "data"), "--methods", "median", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert f"{f}: is 50x90 but the frames are 96x72; it must have their size" in err, err


def test_eval_that_scores_nothing_exits_1(tmp_path, capsys):
    """A trial's frames without masks/ or background.png: a table of dashes, a JSON of
    nulls, and exit 0 for a script to read as success. Nothing scored is exit 1."""
    import shutil

    scene = synth.make_scene(seed=1, n_views=3, size=(72, 96), n_objects=1)
    synth.write_scene(scene, tmp_path / "data" / "s")
    d = tmp_path / "data" / "s"
    for extra in ("masks", "background.png", "free.png"):
        p = d / extra
        shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    assert main(["eval", str(tmp_path / "data"), "--methods", "median", "--quiet"]) == 1
    out, err = capsys.readouterr()
    assert "nothing was scored" in err and err.count("\n") == 1, err
    assert "mean J" not in out, out  # no table of dashes before the error


def test_eval_names_the_reference_mask_it_wanted(tmp_path, capsys):
    """A trial's set held the mask of one photo, not of the reference (the middle
    one): the error named no file. It now names the mask it wanted, for which
    reference, and the flag that picks another."""
    scene = synth.make_scene(seed=1, n_views=3, size=(72, 96), n_objects=1)
    synth.write_scene(scene, tmp_path / "data" / "s")
    d = tmp_path / "data" / "s"
    for extra in ("background.png", "free.png"):
        (d / extra).unlink(missing_ok=True)
    frames = sorted((d / "frames").iterdir())
    ref = frames[len(frames) // 2]
    (d / "masks" / f"{ref.stem}.png").unlink()
    assert (d / "masks" / f"{frames[0].stem}.png").exists()
    assert main(["eval", str(tmp_path / "data"), "--methods", "median", "--quiet"]) == 1
    out, err = capsys.readouterr()
    assert (f"nothing was scored: no set has its reference's mask or a background.png (s: "
            f"masks/{ref.stem}.png for its reference {ref.name}; --ref picks another "
            "reference)") in err and err.count("\n") == 1, err
    assert "mean J" not in out, out


def test_an_index_out_of_range_in_every_set_is_one_error(tmp_path, capsys):
    """A trial's ``eval DATA --ref 99``: an error row, a progress line and an error line
    per set, for one typo. It is one usage error now, before any run; an index that
    some set has, or a name, stays each set's own matter."""
    for k in range(2):
        synth.write_scene(synth.make_scene(seed=k, n_views=3, size=(72, 96), n_objects=1),
                          tmp_path / "data" / f"s{k}")
    assert main(["eval", str(tmp_path / "data"), "--methods", "median", "--quiet",
                 "--ref", "99"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--ref 99: out of range in every set (the largest " \
        "has 3 frames: 0..2)" in err, err


def test_a_file_given_as_the_data_folder_says_so(tmp_path, capsys):
    """``eval results.json`` was "no such folder" for a file that is there."""
    f = tmp_path / "results.json"
    f.write_text("{}")
    assert main(["eval", str(f), "--quiet"]) == 2
    assert f"{f}: is a file, not a folder" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nothing"), "--quiet"]) == 2
    assert "nothing: no such folder" in capsys.readouterr().err


def test_sets_reached_through_symbolic_links_are_found(odd_set, tmp_path):
    """A folder of links to sets (a fresh-user trial linked two DAVIS sets into one
    folder: ``eval`` said "no set with a frames/ folder" while ``batch`` ran both, and
    ``composite`` said the same of it). Each real folder is searched once: a second
    link to it, or a link back to an ancestor, adds nothing."""
    import shutil

    shutil.copytree(odd_set / "odd", tmp_path / "odd2")
    links = tmp_path / "links"
    links.mkdir()
    (links / "a").symlink_to(odd_set / "odd", target_is_directory=True)
    (links / "b").symlink_to(tmp_path / "odd2", target_is_directory=True)
    (links / "c").symlink_to(odd_set / "odd", target_is_directory=True)  # "a" again
    (links / "loop").symlink_to(links, target_is_directory=True)
    sets = find_sets(links)
    assert [s.name for s in sets] == ["a", "b"]
    assert [p.name for p in sets[0].frames] == [p.name for p in find_sets(odd_set)[0].frames]
    assert [s.name for s in find_sets(links, "b")] == ["b"]


def test_a_sets_pattern_that_matches_nothing_is_an_error(odd_set, capsys):
    """``--sets odd,odx``: the typo was dropped without a word and only ``odd`` scored
    (a fresh-user trial); now nothing runs and the message names the pattern and the
    sets there are."""
    rc = main(["eval", str(odd_set), "--methods", "median", "--sets", "odd,odx", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert f"--sets: 'odx' matches no set (the sets below {odd_set}: odd)" in err

"""Bad input, through the CLI and (where it means something) the Python API.

Every rejected input must give exit code 2, one ``dynremove: error: ...`` line that
names the input and the problem, no traceback, and nothing half-written in --out.
Inputs that can be processed (grey, RGBA, palette, 16-bit, EXIF-rotated, huge, ...)
must run with a note and exit 0.
"""

from __future__ import annotations

import json
import os
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove import io, preset, remove_dynamic
from dynremove.evaluation import synth
from dynremove.evaluation.metrics import jaccard
from dynremove.cli import main
from dynremove.params import Params
from dynremove.errors import InputError

H, W = 48, 64
FAST = ["--max-side", "64", "--max-scans", "2"]  # keep full runs tiny


# --- helpers ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=1, n_views=4, size=(H, W))


def write_set(folder: Path, images, ext: str = ".png") -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        p = folder / f"view{i}{ext}"
        assert cv2.imwrite(str(p), im)
        paths.append(p)
    return paths


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    rc = main(["run", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def files_under(p: Path) -> list[Path]:
    return [q for q in p.rglob("*") if q.is_file()] if p.exists() else []


def assert_input_error(rc: int, err: str, *words: str, out: Path | None = None) -> str:
    """Exit 2, one error line (after any notes) containing every word, no traceback."""
    assert rc == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()
             and not re.match(r"^\S.* \[[#-]+\] +[\d.]+ % +[\d.]+ s$", ln)]  # progress
    errors = [ln for ln in lines if ln.startswith("dynremove: error: ")]
    assert len(errors) == 1, err
    assert lines[-1] == errors[0], err
    assert all(ln.startswith("dynremove: note: ") for ln in lines[:-1]), err
    for w in words:
        assert w in errors[0], (w, errors[0])
    if out is not None:
        assert files_under(out) == [], f"partial outputs left in {out}: {files_under(out)}"
    return errors[0]


def assert_ok_run(rc: int, err: str, out: Path) -> dict:
    assert rc == 0, err
    assert "Traceback" not in err
    for name in ("clean.png", "dynamic_mask.png", "coverage.png", "report.json"):
        assert (out / name).is_file(), name
    return json.loads((out / "report.json").read_text())


def notes_of(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("dynremove: note: ")]


def palette_png(path: Path, bgr: np.ndarray) -> np.ndarray:
    """Write ``bgr`` (at most 256 colours) as an 8-bit palette PNG by hand; return it."""
    h, w = bgr.shape[:2]
    colours, idx = np.unique(bgr.reshape(-1, 3), axis=0, return_inverse=True)
    assert len(colours) <= 256
    idx = idx.reshape(h, w).astype(np.uint8)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0)  # 8-bit, colour type 3 = palette
    plte = colours[:, ::-1].astype(np.uint8).tobytes()  # RGB triples
    raw = b"".join(b"\x00" + idx[y].tobytes() for y in range(h))  # filter 0 per row
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"PLTE", plte)
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    return bgr


def exif_app1(orientation: int) -> bytes:
    """A minimal APP1 Exif segment holding only the Orientation tag (0x0112)."""
    ifd = (struct.pack("<H", 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0)
           + struct.pack("<I", 0))
    payload = b"Exif\x00\x00" + b"II*\x00" + struct.pack("<I", 8) + ifd
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def jpeg_bytes(img: np.ndarray, orientation: int | None = None) -> bytes:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    b = buf.tobytes()
    return b if orientation is None else b[:2] + exif_app1(orientation) + b[2:]


# --- no images, one image, mixed folders ------------------------------------------
def test_no_images(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, empty, "--out", out)
    assert_input_error(rc, err, str(empty), "need at least 2 images", "found 0", out=out)
    with pytest.raises(SystemExit) as e:  # no argument at all: argparse's usage error
        main(["run"])
    assert e.value.code == 2
    capsys.readouterr()
    with pytest.raises(InputError, match="at least 2"):
        io.load_image_set([empty])
    with pytest.raises(InputError, match="at least 2"):
        remove_dynamic([])


def test_a_folder_of_sets_points_at_its_sets_and_at_batch(tmp_path, capsys, scene):
    """A folder whose images are two levels down (DAVIS's <set>/frames/): the
    error names the sets' frame folders (not their masks) and 'dynremove batch'."""
    root = tmp_path / "sets"
    for name in ("alpha", "beta"):
        write_set(root / name / "frames", scene.images[:2])
        write_set(root / name / "masks", scene.images[:2])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, root, "--out", out)
    assert_input_error(rc, err, "found 0", str(root / "alpha" / "frames"),
                       str(root / "beta" / "frames"), f"dynremove batch {root}", out=out)
    assert "masks" not in err


def test_one_image(tmp_path, capsys, scene):
    (p,) = write_set(tmp_path / "one", scene.images[:1])
    out = tmp_path / "out"
    for arg in (tmp_path / "one", p):
        rc, _, err = run_cli(capsys, arg, "--out", out)
        assert_input_error(rc, err, str(arg), "need at least 2 images", "found 1", out=out)
    with pytest.raises(InputError, match="at least 2"):
        remove_dynamic([scene.images[0]])


def test_missing_path(tmp_path, capsys, scene):
    (p, _) = write_set(tmp_path / "s", scene.images[:2])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, p, tmp_path / "nope.png", "--out", out)
    assert_input_error(rc, err, "nope.png", "no such file", out=out)


def test_non_image_files_are_skipped_with_a_note(tmp_path, capsys, scene):
    d = tmp_path / "mixed"
    write_set(d, scene.images[:3])
    (d / "notes.txt").write_text("not an image")
    (d / "Thumbs.db").write_bytes(b"\x00" * 32)
    (d / ".DS_Store").write_bytes(b"\x00" * 32)
    (d / "sub").mkdir()
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
    report = assert_ok_run(rc, err, out)
    assert report["inputs"] == [str(d / f"view{i}.png") for i in range(3)]
    (note,) = [n for n in notes_of(err) if "non-image" in n]
    assert "notes.txt" in note and "Thumbs.db" in note and "skipped 2" in note


def test_out_named_like_a_photo_is_refused(tmp_path, capsys, scene):
    """``--out out/clean.jpg`` made a folder of that name, silently (a trial): --out is
    the folder of the outputs; a new name with a photo's or video's suffix is refused,
    with the folder to give instead, and nothing is created."""
    d = tmp_path / "set"
    write_set(d, scene.images[:3])
    for name in ("clean.jpg", "result.PNG", "out.mp4"):
        out = tmp_path / "res" / name
        rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
        assert_input_error(rc, err, f"--out {out}", "names a folder",
                           f"--out {out.with_suffix('')}")
        assert not (tmp_path / "res").exists()
    # an existing folder of that name is used as it is
    out = tmp_path / "old.png"
    out.mkdir()
    rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
    assert_ok_run(rc, err, out)


def test_out_in_the_input_folder_or_over_an_input_is_refused(tmp_path, capsys, scene):
    """The outputs would become photos of the next run there, or replace an input."""
    d = tmp_path / "set"
    paths = write_set(d, scene.images[:3])
    before = sorted(files_under(d))
    rc, _, err = run_cli(capsys, d, "--out", d, *FAST)
    assert_input_error(rc, err, str(d), "is the folder of the input photos")
    assert sorted(files_under(d)) == before  # nothing written, nothing replaced
    clean = tmp_path / "res" / "clean.png"
    clean.parent.mkdir()
    clean.write_bytes(paths[0].read_bytes())  # a photo that happens to sit there
    rc, _, err = run_cli(capsys, clean, *paths[1:], "--out", clean.parent, *FAST)
    assert_input_error(rc, err, "would overwrite the input", str(clean))
    assert clean.read_bytes() == paths[0].read_bytes()


def test_no_output_replaces_an_input_or_another_output(tmp_path, capsys, scene):
    """Fresh-user trial: a mistyped --record replaced a photo with a recording, an
    --out folder holding the --gt mask as dynamic_mask.png replaced the mask with
    the run's own, and --record OUT/clean.png lost the recording under the clean
    photo. Each is refused before anything is written; symbolic links count."""
    d = tmp_path / "set"
    paths = write_set(d, scene.images[:3])
    gt_dir = tmp_path / "gt"
    gt_dir.mkdir()
    gt = gt_dir / "dynamic_mask.png"
    assert cv2.imwrite(str(gt), scene.masks[scene.ref_index].astype(np.uint8) * 255)
    link = tmp_path / "link.jpg"
    link.symlink_to(paths[1])
    files = {p: p.read_bytes() for p in [*paths, gt]}
    out = tmp_path / "out"
    cases = [
        (["--record", paths[2]], "--record", "would overwrite the input"),
        (["--record", link], "--record", "would overwrite the input"),
        (["--record", gt, "--gt", gt], "--record", "(the --gt file)"),
        (["--gt", gt], f"--out {gt_dir} (its dynamic_mask.png)", "(the --gt file)"),
        (["--record", out / "clean.png"], f"--out {out} (its clean.png)",
         "is written there too"),
        (["--record", out / "report.json"], "report.json", "is written there too"),
    ]
    for extra, *words in cases:
        o = gt_dir if extra == ["--gt", gt] else out
        rc, _, err = run_cli(capsys, d, "--out", o, *extra, *FAST)
        assert_input_error(rc, err, *map(str, words))
        assert {p: p.read_bytes() for p in files} == files, extra
        assert not out.exists(), extra  # refused before the folder was made


def test_an_earlier_runs_outputs_are_not_read_as_photos(tmp_path, capsys, scene):
    """A folder that holds an earlier run's outputs beside its report.json (copied
    there with the photos): they are skipped with a note, not read as photos."""
    d = tmp_path / "set"
    write_set(d, scene.images[:3])
    first = tmp_path / "first"
    rc, _, err = run_cli(capsys, d, "--out", first, *FAST)
    assert_ok_run(rc, err, first)
    for name in ("clean.png", "dynamic_mask.png", "coverage.png", "report.json"):
        (d / name).write_bytes((first / name).read_bytes())
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
    report = assert_ok_run(rc, err, out)
    assert report["inputs"] == [str(d / f"view{i}.png") for i in range(3)]
    (note,) = [n for n in notes_of(err) if "earlier dynremove run" in n]
    assert "clean.png" in note and "coverage.png" in note and "dynamic_mask.png" in note


def test_an_earlier_runs_output_folder_among_the_photos_is_skipped(tmp_path, capsys, scene):
    """`run inp/*` where an earlier run wrote --out inp/res: a trial's run stopped at
    "inp/res: is a folder with no images in it", though it held that run's outputs,
    skipped on purpose. Such a folder is now skipped with the note; a folder with
    nothing in it still stops the run."""
    d = tmp_path / "inp"
    write_set(d, scene.images[:3])
    photos = sorted(d.iterdir())
    res = d / "res"
    rc, _, err = run_cli(capsys, d, "--out", res, *FAST)
    assert_ok_run(rc, err, res)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *photos, res, "--out", out, *FAST)
    report = assert_ok_run(rc, err, out)
    assert report["inputs"] == [str(p) for p in photos]
    (note,) = [n for n in notes_of(err) if "earlier dynremove run" in n]
    assert f"{res}: skipped clean.png, coverage.png, dynamic_mask.png: the outputs" in note, note
    empty = tmp_path / "empty"
    empty.mkdir()
    rc, _, err = run_cli(capsys, *photos, empty, "--out", tmp_path / "o2", *FAST)
    assert_input_error(rc, err, f"{empty}: is a folder with no images in it",
                       out=tmp_path / "o2")


def test_too_few_images_left_after_skipping(tmp_path, capsys, scene):
    d = tmp_path / "mixed"
    write_set(d, scene.images[:1])
    (d / "notes.txt").write_text("x")
    (d / "data.csv").write_text("1,2")
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out)
    msg = assert_input_error(rc, err, str(d), "need at least 2 images", "found 1", out=out)
    assert "notes.txt" in msg  # says what was skipped, so the user sees why


# --- unreadable files ---------------------------------------------------------------
@pytest.mark.parametrize("kind", ["truncated", "garbage", "zero-byte", "text-as-jpeg"])
def test_unreadable_file_in_the_set(tmp_path, capsys, scene, kind):
    paths = write_set(tmp_path / "s", scene.images[:3])
    bad = tmp_path / "s" / "bad.jpg"
    good = jpeg_bytes(scene.images[3])
    bad.write_bytes({"truncated": good[: len(good) // 2],
                     "garbage": b"\xff\xd8\xff\xe0" + bytes(range(256)) * 8,
                     "zero-byte": b"",
                     "text-as-jpeg": b"<html>not found</html>"}[kind])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *paths, bad, "--out", out)
    problem = {"zero-byte": "empty file", "truncated": "cut short"}.get(kind,
                                                                      "not a readable image")
    assert_input_error(rc, err, str(bad), problem, out=out)
    with pytest.raises(InputError, match=problem):
        io.read_image(bad)
    # the same file inside a folder: it has an image extension, so it is read and refused
    rc, _, err = run_cli(capsys, tmp_path / "s", "--out", out)
    assert_input_error(rc, err, "bad.jpg", problem, out=out)


def test_a_jpeg_cut_short_is_named_as_cut_short(tmp_path, capsys, scene):
    """A JPEG cut short (a copy interrupted): OpenCV returns nothing and says nothing,
    Pillow says the file is truncated; the error says so, not "corrupt or unsupported
    format" (a fresh-user trial's photo cut at 87 % of its bytes)."""
    paths = write_set(tmp_path / "s", scene.images[:3])
    b = jpeg_bytes(scene.images[3])
    bad = tmp_path / "s" / "cut.jpg"
    bad.write_bytes(b[:int(len(b) * 0.87)])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *paths, bad, "--out", out, *FAST)
    msg = assert_input_error(rc, err, str(bad), "cut short", out=out)
    assert "truncated" in msg and "unsupported format" not in msg
    # two bad inputs: both named in the one error (a trial fixed the first, ran
    # again, and only then learnt of the second)
    junk = tmp_path / "s" / "zz.jpg"
    junk.write_bytes(b"not an image at all")
    rc, _, err = run_cli(capsys, *paths, bad, junk, "--out", out, *FAST)
    msg = assert_input_error(rc, err, str(bad), "cut short", out=out)
    assert "2 of the 5 inputs cannot be read" in msg and str(junk) in msg \
        and "not a readable image" in msg, msg


def test_a_missing_gt_is_no_such_file(tmp_path, capsys, scene):
    paths = write_set(tmp_path / "s", scene.images[:3])
    rc, _, err = run_cli(capsys, *paths, "--gt", tmp_path / "none.png", "--out",
                         tmp_path / "out", *FAST)
    assert_input_error(rc, err, "--gt", "none.png: no such file", out=tmp_path / "out")


def test_corrupt_jpeg_body_is_refused_by_name(tmp_path, capsys, scene):
    """Damage inside the entropy-coded data: libjpeg decodes what it can and fills
    the rest with grey, warning on stderr without naming the file. Such a photo is
    refused (exit 2, naming it and libjpeg's reason): a fresh-user trial's zeroed
    bytes made a grey-banded, shifted reference that the run cleaned with exit 0."""
    paths = write_set(tmp_path / "s", scene.images[:3])
    # (a larger picture, so that the zeroed run lies inside its entropy-coded data)
    b = bytearray(jpeg_bytes(cv2.resize(scene.images[3], (640, 480))))
    mid = len(b) // 2
    b[mid:mid + 2000] = b"\x00" * 2000
    bad = tmp_path / "s" / "corrupt.jpg"
    bad.write_bytes(bytes(b))
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *paths, bad, "--out", out, *FAST)
    msg = assert_input_error(rc, err, str(bad), "corrupt JPEG", out=out)
    assert "libjpeg" in msg and "Corrupt JPEG data" not in err.replace(msg, "")
    with pytest.raises(InputError, match="corrupt JPEG"):
        io.read_image(bad)
    io.read_image(paths[0])  # and the capture leaves the others' reading alone


def test_folder_in_a_list_of_files(tmp_path, capsys, scene):
    paths = write_set(tmp_path / "s", scene.images[:3])
    sub = tmp_path / "s" / "fake.png"  # a folder whose name looks like an image
    sub.mkdir()
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, paths[0], sub, paths[1], "--out", out)
    assert_input_error(rc, err, str(sub), "folder", out=out)
    with pytest.raises(InputError, match="folder"):
        io.read_image(sub)


def test_unreadable_permissions(tmp_path, capsys, scene):
    paths = write_set(tmp_path / "s", scene.images[:3])
    os.chmod(paths[1], 0)
    try:
        if os.access(paths[1], os.R_OK):
            pytest.skip("chmod 0 does not stop this user from reading (root)")
        out = tmp_path / "out"
        rc, _, err = run_cli(capsys, *paths, "--out", out)
        assert_input_error(rc, err, str(paths[1]), "permission denied", out=out)
    finally:
        os.chmod(paths[1], 0o644)


def test_permission_error_is_an_input_error(tmp_path, capsys, scene, monkeypatch):
    """The same path as above, forced (it works when running as root too)."""
    paths = write_set(tmp_path / "s", scene.images[:3])
    real = np.fromfile

    def fromfile(f, *a, **k):
        if str(f) == str(paths[1]):
            raise PermissionError(13, "Permission denied", str(f))
        return real(f, *a, **k)

    monkeypatch.setattr(np, "fromfile", fromfile)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *paths, "--out", out)
    assert_input_error(rc, err, str(paths[1]), "permission denied", out=out)


# --- the reference ------------------------------------------------------------------
@pytest.mark.parametrize("ref, words", [("3", ["--ref 3", "out of range"]),
                                        ("-4", ["--ref -4", "out of range"]),
                                        ("missing.png", ["--ref missing.png", "names no input"])])
def test_bad_ref(tmp_path, capsys, scene, ref, words):
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--ref", ref, "--out", out)
    assert_input_error(rc, err, *words, out=out)


def test_ref_api(scene):
    with pytest.raises(InputError, match="out of range"):
        remove_dynamic(scene.images[:3], ref=3)
    with pytest.raises(InputError, match="out of range"):
        remove_dynamic(scene.images[:3], ref=-4)  # -1 is the last one, as with --ref
    assert io.resolve_ref("view1", ["view0.png", "view1.png"]) == 1
    assert io.resolve_ref("-1", ["a.png", "b.png", "c.png"]) == 2


# --- sizes ----------------------------------------------------------------------------
@pytest.mark.parametrize("other", [(W, H), (H, W // 2)], ids=["turned", "framing"])
def test_different_sizes(tmp_path, capsys, scene, other):
    paths = write_set(tmp_path / "s", scene.images[:3])
    odd = cv2.resize(scene.images[3], (other[1], other[0]), interpolation=cv2.INTER_AREA)
    bad = tmp_path / "s" / "view3.png"
    cv2.imwrite(str(bad), odd)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, *paths, bad, "--out", out)
    hint = "turned by 90°" if other == (W, H) else "another camera"
    assert_input_error(rc, err, str(bad), f"{other[1]}x{other[0]}", f"{W}x{H}", "same size",
                       hint, out=out)
    with pytest.raises(InputError, match="same size"):
        remove_dynamic(list(scene.images[:3]) + [odd], ref=0)


@pytest.mark.parametrize("cut", [(0, 4), (3, 0), (-2, -2)], ids=["narrower", "shorter", "larger"])
def test_a_photo_a_few_pixels_off_is_centred_on_the_set(tmp_path, capsys, cut):
    """Fresh-user trial: a phone's crop (716x960 among 720x960) was refused. A photo a
    few pixels off is centred on the set's frame (what it lacks counts as no
    content) with a note; the clean photo keeps the set's size."""
    sc = synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)
    d = tmp_path / "s"
    paths = write_set(d, sc.images)
    dy, dx = cut
    im = sc.images[1]
    odd = (im[dy // 2: im.shape[0] - (dy - dy // 2), dx // 2: im.shape[1] - (dx - dx // 2)]
           if dy >= 0 and dx >= 0 else cv2.copyMakeBorder(im, 1, 1, 1, 1, cv2.BORDER_REFLECT))
    assert cv2.imwrite(str(paths[1]), odd)
    iset = io.load_image_set([d])
    assert all(x.shape == (96, 128, 3) for x in iset.images)
    (note,) = [n for n in iset.notes if "view1.png" in n]
    assert f": {odd.shape[1]}x{odd.shape[0]}, the set 128x96" in note
    if dy > 0 or dx > 0:  # the border it lacks has no content
        assert iset.valid[1] is not None and not iset.valid[1].all()
        assert iset.valid[1][48, 64]
    # content where it has some: its pixels, where they fall on the set's frame
    if dy >= 0 and dx >= 0:
        y, x = dy // 2, dx // 2
        assert np.array_equal(iset.images[1][y:y + odd.shape[0], x:x + odd.shape[1]], odd)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, "--max-scans", "2")
    report = assert_ok_run(rc, err, out)
    assert cv2.imread(str(out / "clean.png")).shape == (96, 128, 3)
    assert any("view1.png" in n for n in report["notes"])


def test_a_cropped_reference_keeps_its_own_size(tmp_path, capsys):
    """Fresh-user trial: with the cropped photo as the reference, clean.png came out
    at the others' size with black bars where the reference had no pixels, and its
    own 715x955 --gt mask was refused. The set is brought to the reference's size."""
    sc = synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)
    d = tmp_path / "s"
    paths = write_set(d, sc.images)
    odd = sc.images[2][2:-1, 1:-2]  # 125x93
    assert cv2.imwrite(str(paths[2]), odd)
    gt = tmp_path / "gt.png"
    assert cv2.imwrite(str(gt), sc.masks[2][2:-1, 1:-2].astype(np.uint8) * 255)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--ref", "view2.png", "--gt", gt, "--out", out,
                         "--max-scans", "2")
    report = assert_ok_run(rc, err, out)
    clean = cv2.imread(str(out / "clean.png"))
    assert clean.shape == odd.shape
    mask = cv2.imread(str(out / "dynamic_mask.png"), 0) > 127
    black = (clean.max(-1) == 0) & (odd.max(-1) > 0)
    assert not black.any()  # no bar where the others' frame had no pixels
    changed = np.abs(clean.astype(int) - odd).max(-1) > 0
    assert changed[~mask].mean() < 0.02  # outside the mask: the fill's margin only
    assert "jaccard_vs_gt" in report
    assert "the set 125x93" in err


def test_a_photo_at_another_resolution_is_resized_to_the_set(tmp_path, capsys):
    """The same frame at twice the resolution (another phone mode) is resized, and at
    full output size it is read and resized the same way again."""
    sc = synth.make_scene(seed=2, n_views=5, size=(96, 128), n_objects=1)
    d = tmp_path / "s"
    paths = write_set(d, sc.images)
    assert cv2.imwrite(str(paths[3]), cv2.resize(sc.images[3], (256, 192),
                                                 interpolation=cv2.INTER_CUBIC))
    iset = io.load_image_set([d])
    assert iset.images[3].shape == (96, 128, 3) and iset.conformed[3] == {"kind": "resize"}
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, "--max-side", "64", "--max-scans", "2")
    assert_ok_run(rc, err, out)
    assert "resized to 128x96" in err
    assert cv2.imread(str(out / "clean.png")).shape == (96, 128, 3)
    # two photos of that resolution: one note naming both (a fresh-user trial: one
    # line per photo)
    assert cv2.imwrite(str(paths[1]), cv2.resize(sc.images[1], (256, 192),
                                                 interpolation=cv2.INTER_CUBIC))
    notes = [n for n in io.load_image_set([d]).notes if "resized to 128x96" in n]
    assert notes == [f"{paths[1].name}, {paths[3].name}: 256x192, the set 128x96 (the "
                     "same shape: another resolution, or a crop or zoom): resized to "
                     "128x96; the alignment takes up a crop or zoom"], notes


def test_tiny_images_api():
    with pytest.raises(InputError, match="too small"):
        remove_dynamic([np.zeros((6, 6, 3), np.uint8)] * 3, ref=0)
    with pytest.raises(InputError, match="uint8"):
        remove_dynamic([np.zeros((H, W), np.uint8)] * 3, ref=0)


def _bad_images(scene):
    """Each way an API user's images go wrong, with the words that must name the fix."""
    from PIL import Image

    im = scene.images[0]
    return {
        "failed imread": ([im, None, im], "image 1 is None (cv2.imread returns None"),
        "not arrays": ([1, 2, 3], "image 0 is of type int, not an array"),
        "PIL": ([Image.fromarray(im[..., ::-1])] * 3, "np.asarray(img.convert('RGB'))[..., ::-1]"),
        "float 0-1": ([im.astype(np.float32) / 255] * 3, "(img * 255).round().astype(np.uint8)"),
        "float 0-255": ([im.astype(np.float64)] * 3, "img.clip(0, 255).round().astype(np.uint8)"),
        "gray": ([im[..., 1]] * 3, "cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)"),
        "BGRA": ([np.dstack([im, im[..., :1]])] * 3, "img[..., :3]"),
        "16-bit": ([im.astype(np.uint16) << 8] * 3, "16-bit; pass (img >> 8).astype(np.uint8)"),
        # 12-bit data in 16 bits (a trial's: ">> 8" left it at 0-15): the set's depth
        "12-bit in 16": ([im.astype(np.uint16) << 4, im.astype(np.uint16) << 3] * 2,
                         "16-bit holding 12-bit values (none above 4095); pass "
                         "(img >> 4).astype(np.uint8), the same shift for every photo"),
        "one image": (im, f"images is one array of shape {im.shape}: pass a list of photos"),
        "a dict": ({"a": im, "b": im}, "images is a mapping: pass a list of photos, e.g. "
                                       "list(images.values())"),
        "paths": (["a.jpg", "b.jpg", "c.jpg"],
                  "image 0 is a path ('a.jpg'), not an image: read the photos with "
                  "dynremove.io.load_image_set(paths, max_side=1280) and pass the set "
                  "itself"),
        "channels first": ([np.moveaxis(im, -1, 0)] * 3,
                           "channels first; pass np.ascontiguousarray(np.moveaxis(img, 0, -1))"),
    }


@pytest.mark.parametrize("case", ["failed imread", "not arrays", "PIL", "float 0-1",
                                  "float 0-255", "gray", "BGRA", "16-bit", "12-bit in 16",
                                  "one image", "a dict", "paths", "channels first"])
def test_an_api_image_of_the_wrong_kind_is_told_how_to_convert_it(scene, case):
    images, words = _bad_images(scene)[case]
    with pytest.raises(InputError) as e:
        remove_dynamic(images)
    assert words in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_api_arguments_are_checked_before_the_run(scene, monkeypatch):
    """names of another length, an unknown kernel, a params value of the wrong type:
    one-line InputErrors, raised before any work (a names list one short failed with
    an IndexError after the whole run, while writing a note)."""
    from dynremove import pipeline

    monkeypatch.setattr(pipeline, "_prepare", lambda *a, **k: pytest.fail("the run started"))
    three = scene.images[:3]
    with pytest.raises(InputError, match=r"^names: 1 given for 3 images"):
        remove_dynamic(three, names=["a"])
    # the API's words for the reference: ref=, and names= where none were given
    with pytest.raises(InputError, match=r"^ref='tim4.jpg': names no input image \(have "
                                         r"image0, image1, image2\); pass names=\[...\]"):
        remove_dynamic(three, ref="tim4.jpg")
    with pytest.raises(InputError, match=r"^ref='x': names no input image \(have a, b, c\)$"):
        remove_dynamic(three, ref="x", names=["a", "b", "c"])
    with pytest.raises(InputError, match=r"^kernel must be 'numba' or 'reference', got 'cuda'"):
        remove_dynamic(three, kernel="cuda")
    with pytest.raises(InputError, match=r"^params: t_r must be a number, got 'abc' \(str\)"):
        remove_dynamic(three, params={"t_r": "abc"})
    with pytest.raises(InputError, match=r"^params: patch_size must be an int, got 13.5"):
        remove_dynamic(three, params={"patch_size": 13.5})
    with pytest.raises(InputError, match=r"^params: snap must be True or False, got 1 "):
        remove_dynamic(three, params={"snap": 1})
    with pytest.raises(InputError, match=r"^params: unknown field\(s\) select_minorty \(did "
                                         r"you mean select_minority\? the fields of"):
        remove_dynamic(three, params={"select_minorty": 0})
    with pytest.raises(InputError, match=r"^params: unknown field\(s\) zzz \(the fields of"):
        remove_dynamic(three, params={"zzz": 0})


@pytest.mark.parametrize("kw, words", [
    ({"probes": [(10.5, 20.2)]}, r"^probe \(10.5, 20.2\): give an \(x, y\) pair of int"),
    ({"probes": [(1, 2, 3)]}, r"^probe \(1, 2, 3\): give an \(x, y\) pair"),
    ({"probes": 5}, r"^probes=5: give a sequence of \(x, y\) pixels"),
    ({"probes": [(W, 0)]}, rf"^probe pixel \({W}, 0\) is outside the {W}x{H} image"),
    ({"sample_static": 2.0}, r"^sample_static=2.0: give a fraction in \[0, 1\]"),
    ({"sample_static": -1}, r"^sample_static=-1: give a fraction"),
    ({"chunk_rows": 0}, r"^chunk_rows=0: give an int of 1 or more"),
    ({"chunk_rows": 2.5}, r"^chunk_rows=2.5: give an int of 1 or more"),
    ({"valid_masks": [np.ones((10, 10), bool)] * 3},
     rf"^valid_masks\[0\]: shape \(10, 10\), the images are {W}x{H}"),
    ({"valid_masks": [np.ones((H, W), bool)] * 2}, r"^valid_masks: 2 given for 3 images"),
    ({"valid_masks": 5}, r"^valid_masks: give one .* got int"),
    ({"true_background": np.zeros((10, 10, 3), np.uint8)},
     rf"^true_background: shape \(10, 10, 3\) uint8, the images are {W}x{H}: give an"),
    ({"true_background": np.zeros((H, W, 3), np.float32)},
     rf"^true_background: shape \({H}, {W}, 3\) float32, the images are {W}x{H}"),
    ({"ref": "2", "names": ["2", "1", "0"]},
     r"^ref='2': both the index of 0 and the name of 2 \(index 0\): give the int 0 for "
     r"'2', or the int 2 for '0'$"),
], ids=["float probe", "triple", "bare int", "outside", "sample 2", "sample -1", "chunk 0",
        "chunk float", "mask size", "mask count", "masks int", "background size",
        "background float", "ref both"])
def test_api_probes_fractions_and_masks_are_checked_before_the_run(scene, monkeypatch, kw,
                                                                   words):
    """Each a one-line InputError before any work (a trial's probes, valid_masks and
    fractions leaked IndexError, ValueError and TypeError, or ran unchecked; a name
    that is also an index was told to give that name again)."""
    from dynremove import pipeline

    monkeypatch.setattr(pipeline, "_prepare", lambda *a, **k: pytest.fail("the run started"))
    with pytest.raises(InputError, match=words):
        remove_dynamic(scene.images[:3], **kw)


def test_the_api_s_notes_name_the_auto_reference_and_the_preset(scene, monkeypatch):
    """``ref="auto"``'s choice is in ``Result.warnings`` (it was only warned), and a
    preset named in ``params`` (in any case) is the one a recording reports."""
    import warnings as w

    from dynremove import pipeline

    seen = {}
    real = pipeline._prepare

    def spy(images, ref, params, *a, **k):
        seen["ref"] = ref
        return real(images, ref, params, *a, **k)

    monkeypatch.setattr(pipeline, "_prepare", spy)
    started = []
    sink = type("Sink", (), {"enabled": True, "start": lambda self, info: started.append(info),
                             "chunk": lambda self, *a: None,
                             "scan_started": lambda self, *a: None,
                             "scan_finished": lambda self, *a: None,
                             "finish": lambda self, *a, **k: None})()
    with w.catch_warnings():
        w.simplefilter("ignore")
        res = remove_dynamic(scene.images, ref="auto", params="Default", sink=sink)
    assert res.warnings[0].startswith(f"--ref auto: image{seen['ref']} (sharpness")
    assert started[0].preset == "default"


def test_api_takes_a_generator_or_a_stacked_array(scene):
    """Any iterable of images runs, and as the list of them does."""
    three = list(scene.images[:3])
    p = {"max_scans": 1}
    a = remove_dynamic(three, params=p)
    b = remove_dynamic((im for im in three), params=p)
    c = remove_dynamic(np.stack(three), params=p)
    assert np.array_equal(a.clean, b.clean) and np.array_equal(a.clean, c.clean)
    assert np.array_equal(a.dynamic, c.dynamic)


@pytest.mark.parametrize("max_side", ["-5", "4"])
def test_bad_max_side(tmp_path, capsys, scene, max_side):
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    # refused by the parser: one line, exit 2, nothing written
    with pytest.raises(SystemExit) as e:
        run_cli(capsys, tmp_path / "s", "--max-side", max_side, "--out", out)
    err = capsys.readouterr().err
    assert e.value.code == 2 and not out.exists()
    assert err.count("\n") == 1 and f"argument --max-side: {max_side}: must be 0" in err, err
    assert err.count("--max-side") == 1, err  # the flag named once


def test_a_mistyped_flag_value_is_one_line(capsys):
    """argparse errors are one line and a pointer to --help, not the ~50-flag usage."""
    with pytest.raises(SystemExit) as e:
        main(["run", "x", "--output-size", "half"])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.count("\n") == 1 and "invalid choice: 'half'" in err
    assert "see 'dynremove run --help'" in err
    # an unknown flag is the sub-command's too: its hint names that command's help
    for cmd in ("run", "eval"):
        with pytest.raises(SystemExit) as e:
            main([cmd, "x", "--bogus"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1
        assert "unrecognized arguments: --bogus" in err and f"see 'dynremove {cmd} --help'" in err


def test_record_path_that_is_a_folder_is_bad_input(tmp_path, capsys, scene):
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    (tmp_path / "rec").mkdir()
    rc, _, err = run_cli(capsys, tmp_path / "s", "--record", tmp_path / "rec", "--out", out)
    assert_input_error(rc, err, "--record", out=out)
    assert "is a folder" in err


def test_record_name_that_is_not_an_rrd_is_bad_input(tmp_path, capsys, scene):
    """A trial's --record x.txt wrote a recording under that name, which the viewer
    does not offer to open: refused before any work, nothing written."""
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--record", tmp_path / "x.txt", "--out", out)
    line = assert_input_error(rc, err, "--record", out=out)
    assert "give a name ending in .rrd" in line, line
    assert not (tmp_path / "x.txt").exists()


def test_record_below_a_file_names_the_file(tmp_path, capsys, scene):
    """Before: "cannot create its folder (File exists)"."""
    write_set(tmp_path / "s", scene.images[:3])
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    out = tmp_path / "out"
    for rec in (afile / "x.rrd", afile / "deeper" / "x.rrd"):
        rc, _, err = run_cli(capsys, tmp_path / "s", "--record", rec, "--out", out)
        line = assert_input_error(rc, err, out=out)
        assert line == (f"dynremove: error: --record {rec}: cannot create its folder: "
                        f"{afile} is a file, not a folder"), line
    assert afile.read_text() == "keep me"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_record_where_no_file_can_be_created(tmp_path, capsys, scene):
    """/proc: os.access says writable to root, but no file can be created there. Refused
    before any work (no output folder, no reading), one line, exit 2."""
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--record", "/proc/x.rrd", "--out", out)
    line = assert_input_error(rc, err, out=out)
    assert line.startswith("dynremove: error: --record /proc/x.rrd: cannot create the file ("
                           ), line
    assert not out.exists() and notes_of(err) == []  # before the images were read
    with pytest.raises(InputError, match="cannot create the file"):
        io.check_out_file("/proc/x.rrd", "--record")
    io.check_out_file(tmp_path / "ok" / "x.rrd", "--record")  # a writable place passes
    assert list((tmp_path / "ok").iterdir()) == []  # and the trial file is gone


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_subprocess_rerun_failing_to_create_the_recording(tmp_path, scene):
    """Should the check pass and Rerun still fail to create the file (RuntimeError): one
    line naming --record, exit 2, and no Rerun log line ("WARN re_sdk::log_sink: Dropping
    data in MemorySink", in colour) on the terminal; the same with --compare."""
    pytest.importorskip("rerun")
    write_set(tmp_path / "s", scene.images[:3])
    for extra in ([], ["--compare", "paper"]):
        argv = ["run", str(tmp_path / "s"), "--record", "/proc/x.rrd", "--out",
                str(tmp_path / "out"), "--max-scans", "1", "--quiet", *extra]
        code = ("import sys\nfrom dynremove import cli, io\n"
                "io.check_out_file = lambda p, flag: p  # as if the check had passed\n"
                f"sys.exit(cli.main({argv!r}))\n")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=300, env={**os.environ, "DYNREMOVE_DEBUG": ""})
        assert r.returncode == 2, r.stderr
        assert r.stderr == ("dynremove: error: --record /proc/x.rrd: cannot create the file "
                            "(No such file or directory (os error 2))\n"), r.stderr
        assert files_under(tmp_path / "out") == []


# --- the true mask (--gt) ---------------------------------------------------------------
def write_mask(path: Path, mask: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), mask.astype(np.uint8) * 255)
    return path


@pytest.mark.parametrize("size", [(W - 4, H), (2 * W, 2 * H + 2), (854, 480)],
                         ids=["size", "aspect", "davis"])
def test_gt_of_another_size(tmp_path, capsys, scene, size):
    """A mask that is not the reference's size is refused (it used to be resized
    silently and scored), before any work, leaving no output folder."""
    write_set(tmp_path / "s", scene.images[:3])
    gt = write_mask(tmp_path / "gt.png", cv2.resize(scene.masks[1].astype(np.uint8), size,
                                                    interpolation=cv2.INTER_NEAREST))
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--gt", gt, "--out", out, *FAST)
    assert_input_error(rc, err, f"--gt {gt}", f"{size[0]}x{size[1]}", "view1.png",
                       f"{W}x{H}", "reference's size", out=out)
    assert not out.exists()


def test_gt_turned_without_exif_is_refused(tmp_path, capsys, scene):
    write_set(tmp_path / "s", scene.images[:3])
    gt = write_mask(tmp_path / "gt.png", scene.masks[1].T)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--gt", gt, "--out", out, *FAST)
    assert_input_error(rc, err, f"--gt {gt}", f"{H}x{W}", "turned", "EXIF orientation",
                       out=out)


def test_gt_at_full_size_when_the_run_analyses_smaller(tmp_path, capsys, scene):
    """--max-side below the photo's size: the full-size mask is accepted and scored
    at the size of the output (full, or the analysis size with --output-size working)."""
    write_set(tmp_path / "s", scene.images)
    ref = scene.ref_index  # the middle of 4
    gt = write_mask(tmp_path / "gt.png", scene.masks[ref])
    for extra in ([], ["--output-size", "working"]):
        out = tmp_path / f"out{len(extra)}"
        rc, _, err = run_cli(capsys, tmp_path / "s", "--gt", gt, "--out", out,
                             "--max-side", "32", "--max-scans", "1", *extra)
        report = assert_ok_run(rc, err, out)
        w = W if not extra else 32
        assert report["size"]["working_width"] == 32 and report["size"]["width"] == w
        dyn = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE) > 127
        truth = cv2.resize(scene.masks[ref].astype(np.uint8), dyn.shape[::-1],
                           interpolation=cv2.INTER_NEAREST) > 0
        assert report["jaccard_vs_gt"] == pytest.approx(jaccard(dyn, truth))


def test_gt_drawn_on_the_stored_pixels_of_an_exif_rotated_photo(tmp_path, capsys, scene):
    """Photos stored landscape and tagged "rotate 90° CW" are processed upright; a
    mask drawn on the stored (landscape) pixels is turned the same way, with a note,
    and scores as the upright mask does."""
    d = tmp_path / "s"
    d.mkdir()
    for i, im in enumerate(scene.images):
        (d / f"view{i}.jpg").write_bytes(jpeg_bytes(im, orientation=6))
    truth = scene.masks[scene.ref_index]  # the middle of 4
    stored = write_mask(tmp_path / "stored.png", truth)  # W x H, as stored
    upright = write_mask(tmp_path / "upright.png",
                         cv2.rotate(truth.astype(np.uint8), cv2.ROTATE_90_CLOCKWISE))
    scores = []
    for gt in (stored, upright):
        out = tmp_path / gt.stem
        rc, _, err = run_cli(capsys, d, "--gt", gt, "--out", out, *FAST)
        report = assert_ok_run(rc, err, out)
        turned = [n for n in notes_of(err) if f"--gt {gt}" in n]
        assert bool(turned) == (gt == stored), err
        if turned:
            assert "EXIF orientation" in turned[0] and f"{W}x{H}" in turned[0]
        scores.append(report["jaccard_vs_gt"])
    assert scores[0] == scores[1] and scores[0] > 0.3, scores


# --- formats that are converted, with a note --------------------------------------
@pytest.mark.parametrize("kind", ["gray", "rgba", "palette", "16bit", "16bit-gray"])
def test_converted_formats_run_with_a_note(tmp_path, capsys, scene, kind):
    d = tmp_path / "s"
    paths = write_set(d, scene.images[:3])
    p = d / "view1.png"
    src = scene.images[1]
    if kind == "gray":
        g = cv2.cvtColor(src, cv2.COLOR_BGR2GRAY)
        cv2.imwrite(str(p), g)
        expect, note = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), "grayscale"
    elif kind == "rgba":
        a = np.dstack([src, np.full((H, W), 77, np.uint8)])
        cv2.imwrite(str(p), a)
        # (a trial's note said "no transparent pixels" for such a band)
        expect, note = src, f"alpha channel dropped ({H * W} semi-transparent px"
    elif kind == "palette":
        expect, note = palette_png(p, (src // 64) * 64 + 32), None  # lossless: no note needed
    elif kind == "16bit":
        cv2.imwrite(str(p), src.astype(np.uint16) * 257)
        expect, note = src, "16-bit"
    else:
        g = cv2.cvtColor(src, cv2.COLOR_BGR2GRAY)
        cv2.imwrite(str(p), g.astype(np.uint16) * 257)
        expect, note = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), "16-bit"
    iset = io.load_image_set(paths)
    assert all(im.shape == (H, W, 3) and im.dtype == np.uint8 for im in iset.images)
    np.testing.assert_array_equal(iset.images[1], expect)
    if note:
        assert any(note in n and "view1.png" in n for n in iset.notes), iset.notes
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
    report = assert_ok_run(rc, err, out)
    if note:
        assert any(note in n for n in notes_of(err)), err
        assert any(note in n for n in report["notes"])


def test_16_bit_pngs_of_12_bit_data_are_scaled_by_their_depth(tmp_path, scene):
    """Machine-vision and raw-converter PNGs store 12-bit values in 16 bits unscaled:
    a trial's set came out black (values 0-15) with "nothing was found moving". They
    are read as 12-bit data, with a note; a darker photo of the set (no value above
    1023) takes the set's depth, not 10 bits; a full 16-bit photo among them keeps
    its own (a trial's set went black when it set the depth); an alpha channel
    scales from 16 bits."""
    d = tmp_path / "s"
    d.mkdir()
    ims = scene.images[:3]
    dark = ims[2] // 8  # every value under 32: x 16 stays under 1024
    for i, im in enumerate([ims[0], ims[1], dark]):
        cv2.imwrite(str(d / f"view{i}.png"), im.astype(np.uint16) * 16)
    iset = io.load_image_set([d])
    np.testing.assert_array_equal(iset.images[0], ims[0])
    np.testing.assert_array_equal(iset.images[2], dark)  # not x 4 brighter
    assert any("view0.png, view1.png, view2.png: 16-bit image holding 12-bit values" in n
               for n in iset.notes), iset.notes
    # one full 16-bit photo among 12-bit ones keeps its own depth, and they theirs
    cv2.imwrite(str(d / "view1.png"), ims[1].astype(np.uint16) * 257)
    cv2.imwrite(str(d / "view3.png"), scene.images[3].astype(np.uint16) * 16)
    iset = io.load_image_set([d])
    for got, want in zip(iset.images, [ims[0], ims[1], dark, scene.images[3]]):
        np.testing.assert_array_equal(got, want)
    alpha = np.dstack([ims[0].astype(np.uint16) * 16, np.full((H, W), 65535, np.uint16)])
    cv2.imwrite(str(tmp_path / "a.png"), alpha)
    img, valid, notes = io.read_image_valid(tmp_path / "a.png")
    np.testing.assert_array_equal(img, ims[0])
    assert valid is None and "12-bit" in notes[0]


def test_16_bit_pngs_of_8_bit_values_are_read_as_they_are(tmp_path, scene):
    """An 8-bit photo saved in a 16-bit container (values 0-255, as Pillow's
    ``convert('I;16')`` writes it) was read as 10-bit data: 4× darker, and the run
    on such a DAVIS set flagged 0.7 % of the photo against 10 % from its 8-bit
    copy. It is read as it is, with a note; the Python API's hint says so too."""
    d = tmp_path / "s"
    d.mkdir()
    ims = scene.images[:3]
    for i, im in enumerate(ims):
        cv2.imwrite(str(d / f"view{i}.png"), im.astype(np.uint16))
    iset = io.load_image_set([d])
    for got, want in zip(iset.images, ims):
        np.testing.assert_array_equal(got, want)
    assert any("16-bit image holding 8-bit values (none above 255): read as they are" in n
               for n in iset.notes), iset.notes
    with pytest.raises(InputError, match=r"8-bit values \(none above 255\); pass "
                                         r"img\.astype\(np\.uint8\), as"):
        remove_dynamic([im.astype(np.uint16) for im in ims], ref=1)


def test_exif_rotated_jpegs(tmp_path, capsys, scene):
    """Orientation 6 (rotate 90° clockwise to display) is applied on load, and a set
    mixing tagged landscape files with an untagged portrait file loads consistently."""
    d = tmp_path / "s"
    d.mkdir()
    raw = []
    for i, im in enumerate(scene.images[:3]):
        if i == 1:  # stored already upright (portrait pixels), no tag
            (d / f"view{i}.jpg").write_bytes(jpeg_bytes(cv2.rotate(im, cv2.ROTATE_90_CLOCKWISE)))
        else:  # stored landscape, tagged "rotate 90° CW"
            (d / f"view{i}.jpg").write_bytes(jpeg_bytes(im, orientation=6))
        raw.append(cv2.imdecode(np.fromfile(str(d / f"view{i}.jpg"), np.uint8),
                                cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION))
    img0, _ = io.read_image(d / "view0.jpg")
    assert img0.shape == (W, H, 3)
    np.testing.assert_array_equal(img0, cv2.rotate(raw[0], cv2.ROTATE_90_CLOCKWISE))
    iset = io.load_image_set([d])
    assert [im.shape for im in iset.images] == [(W, H, 3)] * 3
    # all upright: the tagged and the physically rotated views show the same content
    for im in iset.images:
        diff = np.abs(im.astype(int) - iset.images[1].astype(int)).mean()
        assert diff < 40, diff  # same scene, small camera motion (wrong way round: ~60+)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, *FAST)
    report = assert_ok_run(rc, err, out)
    assert (report["size"]["width"], report["size"]["height"]) == (H, W)


def test_huge_images_are_downscaled(tmp_path, capsys):
    big = np.empty((6000, 8000, 3), np.uint8)
    big[:] = (90, 120, 150)
    big[1000:2500, 1500:4000] = (30, 200, 60)
    big[3000:5200, 5000:7000] = (220, 40, 40)
    ok, buf = cv2.imencode(".png", big, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    d = tmp_path / "big"
    d.mkdir()
    for i in range(2):
        (d / f"big{i}.png").write_bytes(buf.tobytes())
    del big
    iset = io.load_image_set([d])
    assert iset.original_size == (8000, 6000)
    assert max(iset.images[0].shape[:2]) == io.AUTO_MAX_SIDE
    assert iset.images[0].shape == (960, 1280, 3)
    assert any("downscaled" in n and "8000x6000" in n for n in iset.notes), iset.notes
    del iset
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out, "--max-side", "64", "--max-scans", "1")
    report = assert_ok_run(rc, err, out)
    # analysed at 64 px, written at the input's full size (--output-size full)
    assert report["size"]["working_width"] == 64 and report["size"]["working_height"] == 48
    assert report["size"]["width"] == 8000 and report["size"]["height"] == 6000
    assert report["size"]["original_width"] == 8000
    assert report["size"]["scale"] == pytest.approx(64 / 8000)


# --- degenerate content ---------------------------------------------------------------
@pytest.mark.parametrize("name", ["paper", "default"])
def test_identical_images_have_nothing_dynamic(scene, name):
    ref = scene.images[0]
    res = remove_dynamic([ref.copy() for _ in range(4)], ref=1, params=preset(name))
    assert not res.dynamic.any() and not res.dynamic_raw.any()
    np.testing.assert_array_equal(res.clean, ref)


def test_identical_images_cli(tmp_path, capsys):
    bg = synth.make_scene(seed=5, n_views=3, size=(48, 64)).background
    d = tmp_path / "same"
    write_set(d, [bg] * 3)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out)
    report = assert_ok_run(rc, err, out)
    np.testing.assert_array_equal(cv2.imread(str(out / "clean.png")), bg)
    assert not cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE).any()
    assert report["dynamic_fraction"] == 0.0


def test_textureless_scene(tmp_path, capsys):
    """Flat grey: a fallback with a note (exit 0, nothing dynamic), never a crash.

    Valid input with nothing to match: the epipolar terms are off (a note says so)
    and nothing is flagged, so it is not an input error."""
    d = tmp_path / "flat"
    write_set(d, [np.full((H, W, 3), 128, np.uint8)] * 4)
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, d, "--out", out)
    assert "Traceback" not in err
    assert_ok_run(rc, err, out)
    assert notes_of(err), "a texture-less scene must come with a note"
    assert not cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE).any()


# --- output folder and parameters ------------------------------------------------------
def test_out_is_a_file(tmp_path, capsys, scene):
    write_set(tmp_path / "s", scene.images[:3])
    f = tmp_path / "taken"
    f.write_text("keep me")
    rc, _, err = run_cli(capsys, tmp_path / "s", "--out", f)
    assert_input_error(rc, err, str(f), "not a folder")
    assert f.read_text() == "keep me"
    rc, _, err = run_cli(capsys, tmp_path / "s", "--out", f / "sub")
    assert_input_error(rc, err, str(f / "sub"), "cannot create",
                       f"{f} is a file, not a folder")
    assert f.read_text() == "keep me"


def test_an_empty_out_is_refused(tmp_path, capsys, scene, monkeypatch):
    """A fresh-user trial's --out '' wrote clean.png, the masks and report.json into
    the current folder without a word: it is a one-line error, nothing written."""
    write_set(tmp_path / "s", scene.images[:3])
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    for out in ("", "  "):
        rc, _, err = run_cli(capsys, tmp_path / "s", "--out", out)
        assert_input_error(rc, err, "--out is empty")
    assert not any(here.iterdir())


def test_a_folder_in_the_place_of_an_output_is_refused_before_the_run(tmp_path, capsys,
                                                                      scene):
    """A fresh-user trial: a folder named report.json in --out failed after the whole
    run, as an internal error (exit 1), with clean.png and the masks written and no
    report. Now it is a one-line error before anything is computed or written."""
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "o"
    (out / "report.json").mkdir(parents=True)
    rc, _, err = run_cli(capsys, tmp_path / "s", "--out", out)
    assert_input_error(rc, err, str(out / "report.json"), "is a folder")
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]


def test_out_not_writable(tmp_path, capsys, scene):
    write_set(tmp_path / "s", scene.images[:3])
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("chmod 0500 does not stop this user from writing (root)")
        rc, _, err = run_cli(capsys, tmp_path / "s", "--out", ro)
        assert_input_error(rc, err, str(ro), "not writable", out=ro)
        rc, _, err = run_cli(capsys, tmp_path / "s", "--out", ro / "sub")
        assert_input_error(rc, err, str(ro / "sub"), "cannot create")
    finally:
        os.chmod(ro, 0o700)


@pytest.mark.parametrize("flag, value, words", [
    ("--patch-size", "4", ["--patch-size 4: must be odd"]),
    ("--dbscan-eps", "-1", ["--dbscan-eps -1.0: must be > 0"]),
    ("--t-r", "1.5", ["--t-r 1.5: must be in [0, 1]"]),
    ("--correspondence", "magic", ["--correspondence magic: must be homography+flow,"]),
])
def test_bad_parameters(tmp_path, capsys, scene, flag, value, words):
    write_set(tmp_path / "s", scene.images[:3])
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, tmp_path / "s", flag, value, "--out", out)
    assert_input_error(rc, err, *words)
    assert not out.exists()  # refused before anything was created


def test_bad_parameters_api():
    with pytest.raises(ValueError, match="patch_size"):
        Params(patch_size=4)
    with pytest.raises(ValueError, match="dbscan_eps"):
        preset("paper").replace(dbscan_eps=-1)
    with pytest.raises(ValueError, match="unknown preset"):
        preset("fastest")
    # NaN passes every range comparison; infinities are no parameter values either
    for name in ("select_kappa", "select_minority", "t_r", "flow_gate"):
        for bad in (float("nan"), float("inf")):
            with pytest.raises(ValueError, match=f"{name} must be a finite number"):
                preset("default").replace(**{name: bad})
    with pytest.raises(ValueError, match="select_minority must be 0"):
        preset("default").replace(select_minority=0.5)


# --- a few through a real process (exit status, C-level stderr) --------------------------
@pytest.mark.parametrize("case", ["empty", "truncated-png", "out-is-file"])
def test_subprocess_exit_codes(tmp_path, scene, case):
    d = tmp_path / "s"
    d.mkdir()
    out = tmp_path / "out"
    if case == "empty":
        args = [d]
    elif case == "truncated-png":
        paths = write_set(d, scene.images[:2])
        data = paths[1].read_bytes()
        paths[1].write_bytes(data[: len(data) // 2])
        args = [d]
    else:
        write_set(d, scene.images[:2])
        out.write_text("x")
        args = [d]
    r = subprocess.run([sys.executable, "-m", "dynremove.cli", "run", *map(str, args),
                        "--out", str(out)], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "DYNREMOVE_DEBUG": ""})
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("dynremove: error: "), r.stderr
    if case != "out-is-file":
        assert files_under(out) == []


def test_subprocess_gt_of_another_size(tmp_path, scene):
    """The trial's case in a real process: a mask of another photo's size."""
    write_set(tmp_path / "s", scene.images[:3])
    gt = tmp_path / "gt.png"
    assert cv2.imwrite(str(gt), np.zeros((480, 854), np.uint8))
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "dynremove.cli", "run", str(tmp_path / "s"),
                        "--gt", str(gt), "--out", str(out)], capture_output=True, text=True,
                       timeout=120, env={**os.environ, "DYNREMOVE_DEBUG": ""})
    assert_input_error(r.returncode, r.stderr, "854x480", f"{W}x{H}", out=out)
    assert r.stdout == ""


def test_cli_bad_flags_exit_2_and_leave_no_folder(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--scene-seed", "-1", "--no-record", "--quiet", "--out", str(out)]) == 2
    assert main(["bench", "--views", "1", "--quiet"]) == 2
    assert not out.exists()
    assert "error:" in capsys.readouterr().err


def test_cli_other_exceptions_are_internal_errors(tmp_path, monkeypatch, capsys):
    import dynremove.commands as commands

    def broken(*a, **k):
        raise ValueError("a bug, not the user's input")

    monkeypatch.setattr(commands, "remove_dynamic", broken)
    monkeypatch.delenv("DYNREMOVE_DEBUG", raising=False)
    assert main(["demo", "--no-record", "--quiet", "--out", str(tmp_path / "d")]) == 1
    err = capsys.readouterr().err
    assert "internal error: ValueError" in err and len(err.strip().splitlines()) == 1


def test_views_without_any_motion_between_them_run():
    """A tripod set: no camera motion at all (and the reference's mover copied into
    three views). OpenCV's MAGSAC rejects the fundamental matrix of such matches
    with an assertion; the run goes on without F instead of an internal error."""
    from dynremove import remove_dynamic
    from dynremove.evaluation import synth

    sc = synth.make_scene(seed=0, n_views=6, n_objects=1, parallax=0, camera_shake_px=0,
                          size=(360, 640))
    ref, m = sc.ref_index, sc.masks[sc.ref_index]
    ims = [im.copy() for im in sc.images]
    for i in (0, 1, 2):
        ims[i][m] = sc.images[ref][m]
    r = remove_dynamic(ims, ref=ref)
    assert r.clean.shape == ims[ref].shape and r.dynamic.any()

"""Full-resolution output (issue 11): size, orientation, untouched pixels, metadata."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image

from dynremove.cli import main
from dynremove.evaluation import synth


def _write_photos(folder, images, *, orientation=None, icc=None, make="dynremove-test"):
    """JPEGs as a phone writes them: stored sideways with an EXIF Orientation tag."""
    folder.mkdir(parents=True)
    paths = []
    for i, im in enumerate(images):
        rgb = Image.fromarray(np.ascontiguousarray(im[..., ::-1]))
        exif = Image.Exif()
        exif[0x010F] = make  # Make
        if orientation == 6:  # displayed = stored rotated 90° clockwise
            rgb = rgb.transpose(Image.Transpose.ROTATE_90)
            exif[0x0112] = 6
        p = folder / f"IMG_{i:04d}.jpg"
        kw = {"icc_profile": icc} if icc else {}
        rgb.save(p, quality=97, exif=exif.tobytes(), **kw)
        paths.append(p)
    return paths


def test_full_resolution_output(tmp_path):
    sc = synth.make_scene(seed=0, n_views=5, size=(480, 640))
    _write_photos(tmp_path / "set", sc.images)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "set"), "--out", str(out), "--quiet",
                 "--max-side", "320"]) == 0
    clean = cv2.imread(str(out / "clean.png"))
    mask = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    ref_in = cv2.imread(str(tmp_path / "set" / "IMG_0002.jpg"))
    assert clean.shape == ref_in.shape == (480, 640, 3)
    assert mask.shape == (480, 640) and mask.any()
    # outside the replaced region (the mask and its blend ring) the input, byte for byte
    region = cv2.dilate(mask.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    np.testing.assert_array_equal(clean[~region], ref_in[~region])
    # and the mask holds every pixel the fill changed visibly (a trial found the
    # full-size fill's rim, one working pixel wide, changed outside it)
    lab_c, lab_i = (cv2.cvtColor(x.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)
                    for x in (clean, ref_in))
    changed = np.linalg.norm(lab_c - lab_i, axis=-1) >= 10
    assert changed.any() and not (changed & ~mask).any()
    # the mover is gone: the fill is near the true background
    gt = sc.masks[sc.ref_index]
    err = np.abs(clean.astype(int) - sc.background).mean(-1)[gt].mean()
    err_in = np.abs(ref_in.astype(int) - sc.background).mean(-1)[gt].mean()
    assert err < 0.25 * err_in
    # --output-size working: the analysis size
    out_w = tmp_path / "out_w"
    assert main(["run", str(tmp_path / "set"), "--out", str(out_w), "--quiet",
                 "--max-side", "320", "--output-size", "working"]) == 0
    assert cv2.imread(str(out_w / "clean.png")).shape == (240, 320, 3)


def test_a_relit_shade_at_full_size(tmp_path):
    """A faint cast shadow relit by the analysis (``refine.shade``) is relit at the
    photos' own size too: a run on photos larger than --max-side failed with an
    internal error counting it (the working-size map against the full-size mask).
    Outside the mask and the relit shade (upsampled) the input, byte for byte."""
    from lingering import with_faint_shadow

    sc = synth.make_scene(seed=0, n_views=6, size=(360, 640))
    ims, s, core = with_faint_shadow(sc)
    big = [cv2.resize(im, (1280, 720), interpolation=cv2.INTER_CUBIC) for im in ims]
    d = tmp_path / "set"
    d.mkdir()
    for i, im in enumerate(big):
        cv2.imwrite(str(d / f"view{i}.png"), im)
    out = tmp_path / "out"
    assert main(["run", str(d), "--out", str(out), "--quiet", "--max-side", "640",
                 "--ref", str(sc.ref_index)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["relit_px"] > 0.5 * core.sum(), report["relit_px"]
    clean = cv2.imread(str(out / "clean.png"))
    mask = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    ref_in = big[sc.ref_index]
    bg = cv2.resize(sc.background, (1280, 720), interpolation=cv2.INTER_CUBIC)
    core_f = cv2.resize(core.view(np.uint8), (1280, 720), interpolation=cv2.INTER_NEAREST) > 0
    core_f &= ~mask

    def L(im):
        return cv2.cvtColor(im.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)[..., 0]
    before = np.abs(L(ref_in) - L(bg))[core_f].mean()
    after = np.abs(L(clean) - L(bg))[core_f].mean()
    assert after < 0.5 * before, (before, after)
    # the mask holds every pixel changed by ΔE 10 or more, the relit ones too (a
    # trial's 1440×1920 photos had 466 relit pixels outside it moved by ΔE 10–13.7:
    # the full-size mask was completed before the shade was relit)
    lab_c, lab_i = (cv2.cvtColor(x.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)
                    for x in (clean, ref_in))
    changed = np.linalg.norm(lab_c - lab_i, axis=-1) >= 10
    assert not (changed & ~mask).any(), int((changed & ~mask).sum())
    # untouched: away from the mask and the shade (both upsampled, with the blend's ring)
    s_f = cv2.resize(s.view(np.uint8), (1280, 720), interpolation=cv2.INTER_NEAREST) > 0
    region = cv2.dilate((mask | s_f).astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
    np.testing.assert_array_equal(clean[~region], ref_in[~region])


def test_orientation_exif_and_icc_are_carried(tmp_path):
    sc = synth.make_scene(seed=1, n_views=4, size=(360, 480))
    icc = b"\x00\x00\x02\x0cfake-icc-profile-for-the-test" + bytes(64)
    _write_photos(tmp_path / "set", sc.images, orientation=6, icc=icc)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "set"), "--out", str(out), "--quiet",
                 "--max-side", "240"]) == 0
    with Image.open(out / "clean.png") as im:
        assert im.size == (480, 360)  # displayed size: the rotation applied
        exif = im.getexif()
        assert exif.get(0x0112) == 1  # orientation reset
        assert exif.get(0x010F) == "dynremove-test"  # the other fields carried
        assert im.info.get("icc_profile") == icc


def test_run_help_shows_the_values_a_plain_run_uses(capsys):
    import pytest

    from dynremove.params import DEFAULT, PAPER

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert DEFAULT.patch_size != PAPER.patch_size
    assert "--patch-size INT p : patch side" in out and "--t-r FLOAT" in out
    assert "paper preset" not in out  # the paper's value is said once, by "(default …; paper …)"
    assert f"(default {DEFAULT.patch_size}; paper {PAPER.patch_size})" in out
    assert f"(default {DEFAULT.snap}; paper {PAPER.snap})" in out
    assert "--write {patch,pixel}" in out
    assert "--correspondence {homography+flow,homography,flow,gated}" in out
    assert "λ8" in out and "σ_c" in out  # the paper's symbols


def test_bench_times_the_large_photo_path_not_a_full_size_analysis():
    """``bench --max-side`` times what users run: analysis at max_side, the clean
    photo at full size (12 MP analysed at full size would need > 20 GB)."""
    from dynremove.evaluation.bench import run_bench

    from dynremove.params import DEFAULT

    out = run_bench(size=(320, 240), views=3, max_side=160, reference=False,
                    json_path=None, quiet=True)
    assert out["analysis_size"] == [160, 120] and out["full_output_size"] == [320, 240]
    # the JSON says how it was made (a trial: it had no params, size limit or version)
    assert out["params"] == DEFAULT.to_dict() and out["max_side"] == 160
    assert out["repeat"] == 1 and set(out["versions"]) >= {"dynremove", "numpy", "opencv"}
    assert out["full_output_end_to_end_s"] == out["end_to_end_s"]
    # the scan's rate is over the analysed pixels
    s = out["scans"][0]
    assert s["px_per_s"] == pytest.approx(160 * 120 / s["seconds"], rel=1e-6)
    # and ``dynremove run`` itself, in its own process: the peak RSS is that
    # process's alone (the bench's synthetic scene held in memory is not counted)
    u = out["user_run"]
    assert u["clean_size"] == [320, 240] and u["seconds"] > 0 and u["analysis_s"] > 0
    # ru_maxrss is in KiB on Linux: a process that imported NumPy, OpenCV and numba
    # holds over 50 MiB, and a 320x240 run far less than 4 GiB
    assert 50 < u["peak_rss_mb"] < 4096
    assert u["command"].startswith("dynremove run <views> --ref ")
    assert "--max-side 160" in u["command"]
    # the README's speed table is made from such JSON (examples/speed_table.py)
    import importlib.util
    import pathlib

    spec = importlib.util.spec_from_file_location(
        "speed_table", pathlib.Path(__file__).parents[1] / "examples" / "speed_table.py")
    speed_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed_table)
    text = speed_table.table([out, out], ["a", "b"])
    assert "| stage (s; 3 × 320×240) | a | b |" in text
    assert f"| **end to end** | **{out['end_to_end_s']:.2f}** | **{out['end_to_end_s']:.2f}** |" \
        in text
    assert f"| `dynremove run`, own process: peak RSS, MiB | {u['peak_rss_mb']:.0f} |" in text
    assert f"| fill by selection | {out['stages_s']['fusion']:.2f} |" in text


@pytest.mark.skipif(not os.path.exists("/proc/self/status"),
                    reason="the process's own peak (VmHWM) is read from Linux's /proc")
def test_report_peak_rss_is_the_runs_own_not_its_parents(tmp_path):
    """report.json's peak RSS is the run's own, also when a large process starts it
    (``bench``, a notebook): getrusage's ru_maxrss carries the parent's peak over
    the fork and exec into the child, and a 12 MP run started by the bench reported
    the bench's 4062 MiB for its own 2711."""
    sc = synth.make_scene(seed=0, n_views=3, size=(120, 160))
    _write_photos(tmp_path / "set", sc.images)
    big = np.ones(768 * 2 ** 20, np.uint8)  # 768 MiB resident in this (the parent) process
    out = tmp_path / "out"
    subprocess.run([sys.executable, "-m", "dynremove", "run", str(tmp_path / "set"),
                    "--out", str(out), "--quiet"], check=True)
    peak = json.loads((out / "report.json").read_text())["throughput"]["peak_rss_mb"]
    assert big[-1] == 1
    # the run alone: its libraries and a 160x120 set hold a few hundred MiB
    assert 50 < peak < 600, peak


def test_full_resolution_equals_the_dense_computation():
    """The sparse full-size step gives the bytes the dense one gives
    (``tests/naive.py``), blend and inpainting included, at a scale that is not
    an integer."""
    import dataclasses

    import naive

    from dynremove.pipeline import remove_dynamic
    from dynremove.refine.upsample import full_resolution

    sc = synth.make_scene(seed=0, n_views=4, size=(360, 480))
    work = [cv2.resize(im, (210, 158), interpolation=cv2.INTER_AREA) for im in sc.images]
    res = remove_dynamic(work, ref=sc.ref_index)
    sel = res.selection
    assert sel is not None and len(np.unique(sel.label[sel.label >= 1])) >= 2
    ref = sc.images[res.ref_index]
    srcs = [sc.images[i] for i in res.source_indices]
    no_source = sel.no_source | (sel.label >= 1) & (np.arange(210) < 105)[None]
    for s in (sel, dataclasses.replace(sel, no_source=no_source)):
        clean, dyn = full_resolution(ref, srcs, res.clean, res.dynamic, s)
        clean_d, dyn_d = naive.full_resolution(ref, srcs, res.clean, res.dynamic, s)
        np.testing.assert_array_equal(dyn, dyn_d)
        np.testing.assert_array_equal(clean, clean_d)
        assert (clean != ref).any()


def test_a_mover_s_kept_parts_do_not_darken_the_full_size_fill():
    """As ``test_a_mover_s_kept_parts_are_not_light_for_the_blend`` at working size:
    a dark mover on a pale wall, its body replaced (a source showing the wall), its
    head and legs kept. At full size (×2) the blend's band lies on the kept parts too;
    the pixels of L (``Selection.mask``) are no evidence of light there, so the body
    comes out as the wall; without them, a dark smear. Both equal the dense form."""
    import dataclasses

    import naive

    from dynremove.refine.select import Selection
    from dynremove.refine.upsample import full_resolution

    rng = np.random.default_rng(0)
    h = w = 160  # the working-size test's scene, written at twice its size
    wall = cv2.GaussianBlur(rng.integers(185, 215, (2 * h, 2 * w, 3)).astype(np.uint8),
                            (0, 0), 1.5)
    body = np.zeros((h, w), bool)
    body[60:100, 50:110] = True
    kept = np.zeros((h, w), bool)
    kept[15:60, 62:98] = True  # the head
    kept[100:155, 55:105] = True  # the legs
    up = lambda m: cv2.resize(m.astype(np.uint8), (2 * w, 2 * h),  # noqa: E731
                              interpolation=cv2.INTER_NEAREST) > 0
    ref = wall.copy()
    ref[up(body | kept)] = (40, 35, 30)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    label = np.where(body, 1, np.where(cv2.dilate(body.view(np.uint8), np.ones((9, 9))) > 0,
                                       0, -1)).astype(np.int16)
    none = np.zeros((h, w), bool)
    sel = Selection(clean=cv2.resize(ref, (w, h)), replaced=body, label=label,
                    explained=kept, movers=none[None], no_source=none, seams=none,
                    parallax_px=0.0, consensus_mode="scan", fields=[np.stack([gx, gy], -1)],
                    members=body[None], mask=body | kept)
    small = cv2.resize(ref, (w, h), interpolation=cv2.INTER_AREA)
    for s, ok in ((sel, True), (dataclasses.replace(sel, mask=None), False)):
        clean, dyn = full_resolution(ref, [wall], small, body, s)
        clean_d, dyn_d = naive.full_resolution(ref, [wall], small, body, s)
        np.testing.assert_array_equal(clean, clean_d)
        np.testing.assert_array_equal(dyn, dyn_d)
        err = np.abs(clean.astype(int) - wall).max(2)[up(body)]
        assert (np.median(err) <= 3) if ok else (np.median(err) >= 20), np.median(err)


def test_the_full_size_fill_takes_one_working_pixel_more():
    """grow_replaced: the replaced labels grow ``px`` pixels into the kept reference
    (label 0), never into pixels outside the fill region (−1), taking a neighbour's
    source: a rim one working pixel wide next to the mover is filled at full size."""
    from dynremove.refine.upsample import grow_replaced

    label = np.zeros((9, 12), np.int16)
    label[:, :1] = -1  # outside the fill region
    label[3:6, 4:7] = 2
    out = grow_replaced(label, 2)
    ys, xs = np.nonzero(out >= 1)
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (1, 7, 2, 8)
    assert set(np.unique(out[out >= 1])) == {2}
    assert (out[:, :1] == -1).all() and (out[label == 2] == 2).all()
    assert np.array_equal(grow_replaced(label, 0), label)


def test_a_replaced_region_as_wide_as_the_photo_leaves_the_inputs_alone():
    """When the replaced region's box spans the photo's whole width, its rows are one
    contiguous block: the ring's colour differences then wrote every source's samples
    into the caller's reference (np.ascontiguousarray returned it, not a copy), and the
    offsets were measured against those (a trial saw white blocks in a sky). The
    inputs stay as given, and the result is the one for a reference held as a
    view into a wider array (never contiguous, so copied even before the fix)."""
    import dataclasses

    from dynremove.pipeline import remove_dynamic
    from dynremove.refine.upsample import full_resolution

    sc = synth.make_scene(seed=0, n_views=4, size=(360, 480))
    work = [cv2.resize(im, (240, 180), interpolation=cv2.INTER_AREA) for im in sc.images]
    res = remove_dynamic(work, ref=sc.ref_index)
    sel = res.selection
    label = sel.label.copy()
    label[40:52, :] = 1  # a band from the left edge to the right edge, from source 0
    no_source = np.zeros_like(sel.no_source)
    no_source[44:48, :] = True  # and the inpainting, across the whole width too
    ref = sc.images[res.ref_index].copy()
    srcs = [sc.images[i].copy() for i in res.source_indices]
    kept = [ref.copy()] + [s.copy() for s in srcs]
    wider = np.zeros((ref.shape[0], ref.shape[1] + 7, 3), np.uint8)
    wider[:, :ref.shape[1]] = ref
    view = wider[:, :ref.shape[1]]
    assert not view.flags.c_contiguous
    for ns in (sel.no_source, no_source):
        band = dataclasses.replace(sel, label=label, no_source=ns)
        clean, dyn = full_resolution(ref, srcs, res.clean, res.dynamic, band)
        for a, b in zip([ref] + srcs, kept):
            np.testing.assert_array_equal(a, b)
        clean_v, dyn_v = full_resolution(view, srcs, res.clean, res.dynamic, band)
        np.testing.assert_array_equal(clean, clean_v)
        np.testing.assert_array_equal(dyn, dyn_v)
        assert (clean[80:104] != ref[80:104]).any()  # the band was filled


def test_full_resolution_output_checks_its_images():
    """A trial gave full_resolution_output turned, wrong-sized, too few, grey and float
    images: silent wrong sizes or bare IndexError/ValueError. Now one InputError line."""
    from dynremove import InputError
    from dynremove.pipeline import full_resolution_output, remove_dynamic

    sc = synth.make_scene(seed=0, n_views=4, size=(120, 160))
    work = [cv2.resize(im, (80, 60), interpolation=cv2.INTER_AREA) for im in sc.images]
    res = remove_dynamic(work, ref=1)
    clean, dyn = full_resolution_output(res, sc.images)
    assert clean.shape == (120, 160, 3) and dyn.shape == (120, 160)
    bad = {"turned": [np.ascontiguousarray(im.swapaxes(0, 1)) for im in sc.images],
           "cropped": [im[:, :150] for im in sc.images],
           "too few": sc.images[:2],
           "grey": [im[..., 0] for im in sc.images],
           "float": [im.astype(np.float32) for im in sc.images]}
    for what, ims in bad.items():
        with pytest.raises(InputError, match="full_images"):
            full_resolution_output(res, ims)


def test_full_size_coverage_counts_the_fill_where_the_mask_grew(tmp_path):
    """The full-size mask holds the pixels the full-size fill changed beyond L (its
    seams, one analysis pixel more); their coverage is the fill's source count, not
    the outside's (0 where no source agreed with the reference), so report.json's
    uncovered_dynamic_px and coverage.png's zeros in the mask keep meaning
    "inpainted" (a trial: 10,232 px reported against 33 analysis px inpainted)."""
    import dataclasses

    from dynremove import io
    from dynremove.batch import at_output_size
    from dynremove.pipeline import remove_dynamic

    sc = synth.make_scene(seed=0, n_views=5, size=(480, 640))
    paths = _write_photos(tmp_path / "set", sc.images)
    iset = io.load_image_set(paths, max_side=320)
    res = remove_dynamic(iset.images)
    # the outside's count at its worst: no source agreeing anywhere off L
    res = dataclasses.replace(res, coverage=np.where(res.dynamic, res.coverage, 0).astype(
        res.coverage.dtype))
    full = at_output_size(res, iset)
    Hf, Wf = full.dynamic.shape
    grew = full.dynamic & ~cv2.resize(res.dynamic.view(np.uint8), (Wf, Hf),
                                      interpolation=cv2.INTER_NEAREST).astype(bool)
    assert grew.sum() > 20  # the case: the full-size mask reaches beyond L
    n_work = int((res.dynamic & (res.coverage == 0)).sum())
    n_full = int((full.dynamic & (full.coverage == 0)).sum())
    assert n_full <= 4 * n_work, (n_full, n_work)


def test_the_full_size_stage_counts_the_reading_of_the_originals(tmp_path, monkeypatch):
    """report.json's ``full_resolution`` seconds include reading the originals again,
    as the terminal's "full-size output" line does (a fresh-user trial read 7.0 s on
    the line against 5.5 s in report.json for 12 MP photos)."""
    import time

    from dynremove import batch, io

    sc = synth.make_scene(seed=0, n_views=3, size=(240, 320))
    _write_photos(tmp_path / "set", sc.images)
    real = io.read_image
    slow = {"n": 0}

    def read_slowly(p):
        slow["n"] += 1
        time.sleep(0.2)
        return real(p)

    monkeypatch.setattr(batch.io, "read_image", read_slowly)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "set"), "--out", str(out), "--quiet",
                 "--max-side", "160"]) == 0
    secs = json.loads((out / "report.json").read_text())["seconds"]
    assert slow["n"] >= 3  # the originals read again for the full-size fill
    assert secs["full_resolution"] >= 0.2 * slow["n"]


def test_a_soft_reference_gets_a_fill_as_soft_as_it():
    """A reference softer than the other photos (camera shake, focus): a visual trial
    saw the bottle's outline as crisp wood grain inside a soft photo. The fill is
    blurred to the reference's sharpness (``select.reference_blur``: σ 2 found for a
    reference blurred by σ 2; none for the plain set), at the working size and at
    full size: inside the replaced region it is as sharp as the truth blurred the
    same way, far less than the sharp truth."""
    from dynremove.pipeline import full_resolution_output, remove_dynamic
    from dynremove.refine.morphology import dilate_disc

    def energy(im, where):
        g = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY).astype(np.float32)
        gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
        return float((gx * gx + gy * gy)[where].mean())

    sc = synth.make_scene(seed=0, n_views=5, size=(240, 320), n_objects=1)
    ref = sc.ref_index
    assert not remove_dynamic(sc.images, ref=ref).selection.blur_sigma.any()
    ims = list(sc.images)
    ims[ref] = cv2.GaussianBlur(ims[ref], (0, 0), 2.0)
    soft_truth = cv2.GaussianBlur(sc.background, (0, 0), 2.0)
    r = remove_dynamic(ims, ref=ref)
    used = np.unique(r.selection.label[r.selection.label >= 1]) - 1
    assert any(w.startswith("the reference is softer than image") and "blurred to match it"
               in w for w in r.warnings), r.warnings
    assert (r.selection.blur_sigma[used] >= 1.4).all(), r.selection.blur_sigma
    inner = r.dynamic & ~dilate_disc(~r.dynamic, 4)
    assert inner.sum() > 500
    e = energy(r.clean, inner)
    assert 0.5 < e / energy(soft_truth, inner) < 2.0 and e < 0.4 * energy(sc.background, inner)
    # at full size: the same run on photos analysed at half their size
    work = [cv2.resize(im, (160, 120), interpolation=cv2.INTER_AREA) for im in ims]
    res = remove_dynamic(work, ref=ref)
    assert res.selection.blur_sigma[np.unique(res.selection.label[
        res.selection.label >= 1]) - 1].min() > 0
    clean, dyn = full_resolution_output(res, ims)
    inner = dyn & ~dilate_disc(~dyn, 8)
    e = energy(clean, inner)
    assert 0.5 < e / energy(soft_truth, inner) < 2.0 and e < 0.4 * energy(sc.background, inner)

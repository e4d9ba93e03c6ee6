"""Whole-photo measures (issue 10, item 1): whole-image PSNR/SSIM, damage %, leftover %.

The hand-built case: a flat 200x200 background, a 60x60 mover pasted at
rows/cols 20..79 of the reference, and outputs with square patches. With
``blur_sigma=0`` the percentages are exact patch areas. With the default
``blur_sigma=1`` the ΔE > 10 boundary of a patch moves by at most one pixel:
a Gaussian of sigma 1 gives the first pixel outside an edge about
Phi(-0.5) = 0.31 of the patch colour and the second Phi(-1.5) = 0.067, while the
first pixel inside keeps >= 0.69 (>= 0.47 at a corner). The patch colours are
~60-110 ΔE from the background, so the second ring stays below 10 ΔE and the
inner ring above it: an s x s patch counts between (s-2)^2 and (s+2)^2 pixels
(the tolerance used below; it is a one-pixel ring each way).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove.evaluation import composite, synth
from dynremove.evaluation.evaluate import SCORE_KEYS, find_sets, format_table, run_eval
from dynremove.evaluation.metrics import psnr_in_mask, ssim_in_mask
from dynremove.evaluation.whole_photo import (damage_percent, delta_e76, kept_by_step,
                                              leftover_percent, leftover_split,
                                              misplaced_fill_percent,
                                              own_mover_fill_percent, psnr, ssim)

N = 200
BG = (120, 130, 140)
MOVER = (20, 200, 240)
DAMAGE = (200, 40, 40)
MASK = (slice(20, 80), slice(20, 80))  # 60 x 60 = 3600 px
DAMAGED = (slice(120, 180), slice(120, 180))  # 60 x 60, far from the mask
LEFT = (slice(30, 50), slice(25, 45))  # 20 x 20 inside the mask's left half


def ring_bounds(s: int, total: int) -> tuple[float, float]:
    """Percent bounds of an s x s patch whose edge may move by one pixel."""
    return 100.0 * (s - 2) ** 2 / total, 100.0 * (s + 2) ** 2 / total


@pytest.fixture
def case():
    bg = np.empty((N, N, 3), np.uint8)
    bg[:] = BG
    mask = np.zeros((N, N), bool)
    mask[MASK] = True
    ref = bg.copy()
    ref[mask] = MOVER
    out = bg.copy()
    out[DAMAGED] = DAMAGE
    out[LEFT] = MOVER
    return bg, ref, out, mask


def test_patch_colours_are_far_from_the_background(case):
    bg, ref, out, _ = case
    de = delta_e76(out, bg, blur_sigma=0)
    assert 50 < de[DAMAGED].min() < 150 and 50 < de[LEFT].min() < 150
    assert delta_e76(ref, bg, blur_sigma=0)[MASK].min() > 50


def test_damage_exact_without_blur_and_within_a_ring_with_it(case):
    bg, ref, out, mask = case
    assert damage_percent(ref, out, bg, mask, blur_sigma=0) == 100.0 * 60 * 60 / N**2  # 9 %
    lo, hi = ring_bounds(60, N * N)
    d = damage_percent(ref, out, bg, mask)
    assert lo <= d <= hi
    # the leftover patch inside the mask is not damage; neither is the mask's guard band
    out2 = bg.copy()
    out2[LEFT] = MOVER
    k = np.zeros((N, N), bool)
    k[18:82, 18:82] = True  # 2 px outside the mask: inside the 5 px band
    out2[k & ~mask] = DAMAGE
    assert damage_percent(ref, out2, bg, mask) == 0.0
    # ...but the same ring 8 px out is
    out3 = bg.copy()
    out3[10:90, 10:90] = DAMAGE
    out3[13:87, 13:87] = BG
    ring = 80 * 80 - 74 * 74
    assert damage_percent(ref, out3, bg, mask, blur_sigma=0) == pytest.approx(100 * ring / N**2)


def test_damage_needs_the_pixel_right_in_the_input(case):
    bg, ref, out, mask = case
    ref2 = ref.copy()
    ref2[DAMAGED] = DAMAGE  # already wrong in the input (an unannotated mover, say)
    assert damage_percent(ref2, out, bg, mask) == 0.0


def test_leftover_whole_mask(case):
    bg, _, out, mask = case
    left, unrec = leftover_percent(out, bg, mask, blur_sigma=0)
    assert left == pytest.approx(100 * 400 / 3600) and unrec is None
    left, unrec = leftover_percent(out, bg, mask)
    lo, hi = ring_bounds(20, 3600)
    assert lo <= left <= hi and unrec is None


def test_leftover_with_a_recoverable_map(case):
    bg, ref, _, mask = case
    free = np.zeros((N, N), bool)
    free[:, :50] = True  # mask columns 20..49 recoverable, 50..79 not (1800 px each)
    out = bg.copy()
    out[LEFT] = MOVER
    out[20:80, 50:80] = MOVER  # the unrecoverable half left as is
    left, unrec = leftover_percent(out, bg, mask, free, blur_sigma=0)
    assert unrec == 50.0 and left == pytest.approx(100 * 400 / 1800)
    left, unrec = leftover_percent(out, bg, mask, free)
    assert unrec == 50.0  # a property of the masks only: no tolerance
    # the kept half can bleed one column (60 px) into the recoverable half
    assert 100 * 18**2 / 1800 <= left <= 100 * (22**2 + 60) / 1800
    # nothing recoverable: leftover undefined, all of it unrecoverable
    assert leftover_percent(out, bg, mask, np.zeros((N, N), bool)) == (None, 100.0)


@pytest.mark.parametrize("sigma", [0.0, 1.0])
def test_leftover_split_tells_a_missed_mover_from_a_wrong_fill(case, sigma):
    bg, ref, _, mask = case
    out = bg.copy()
    out[LEFT] = MOVER  # 20 x 20 left as the input showed it
    out[60:80, 20:80] = DAMAGE  # 20 x 60 changed, but not into the background
    left, _ = leftover_percent(out, bg, mask, blur_sigma=sigma)
    kept, refilled = leftover_split(out, ref, bg, mask, blur_sigma=sigma)
    assert kept + refilled == pytest.approx(left)
    if sigma == 0:
        assert (kept, refilled) == (pytest.approx(100 * 400 / 3600),
                                    pytest.approx(100 * 1200 / 3600))
    else:  # blurred, the restored pixels next to either patch mix in its colour: up
        # to 4 rows above the wrong fill, a 2 px ring around the mover (neither is
        # the input's colour, so both count as refilled)
        assert ring_bounds(20, 3600)[0] <= kept <= ring_bounds(20, 3600)[1]
        assert 100 * 19 * 60 / 3600 <= refilled <= 100 * (24 * 60 + 24**2 - 20**2) / 3600
    # a method that returns its input kept all of it; one that paints it over, none
    assert leftover_split(ref, ref, bg, mask, blur_sigma=sigma) == (100.0, 0.0)
    painted = bg.copy()
    painted[mask] = DAMAGE
    assert leftover_split(painted, ref, bg, mask, blur_sigma=sigma) == (0.0, 100.0)
    # with a recoverable map, over the same pixels as the leftover; none: undefined
    free = np.zeros((N, N), bool)
    free[:, :50] = True
    left, _ = leftover_percent(out, bg, mask, free, blur_sigma=sigma)
    assert sum(leftover_split(out, ref, bg, mask, free, blur_sigma=sigma)) == pytest.approx(left)
    assert leftover_split(out, ref, bg, mask, np.zeros((N, N), bool)) == (None, None)
    with pytest.raises(ValueError):
        leftover_split(out, ref[:10], bg, mask)


def test_kept_by_step_names_the_step_that_left_each_kept_pixel(case):
    """The mover's 60 x 60 square in four 15-row bands: the left half of each left
    as the input showed it by a different step, the right half restored. A kept
    pixel counts for the first step that applies: replaced, then the fill's map,
    then the scans' map, else missed."""
    bg, ref, _, mask = case
    out = ref.copy()
    out[20:80, 50:80] = bg[20:80, 50:80]  # the right 30 columns restored
    band = [np.zeros((N, N), bool) for _ in range(4)]
    for i, b in enumerate(band):
        b[20 + 15 * i:35 + 15 * i, 20:80] = True
    # band 0 never scanned; band 1 scanned, dropped before the fill; band 2 in the
    # fill's map, kept; band 3 replaced (and in both maps), still alike the input
    scanned = band[1] | band[2] | band[3]
    fill_input = band[2] | band[3]
    replaced = band[3] | (mask & (np.arange(N) >= 50)[None])
    split = kept_by_step(out, ref, bg, mask, scanned=scanned, fill_input=fill_input,
                         replaced=replaced, blur_sigma=0)
    # each band's left 30 columns are kept (450 px of the 3600 of the mask)
    assert split == {k: pytest.approx(100 * 450 / 3600)
                     for k in ("missed", "refinement", "fill", "replaced")}
    kept, _ = leftover_split(out, ref, bg, mask, blur_sigma=0)
    assert sum(split.values()) == pytest.approx(kept)
    # a map that covers a band moves it to a later step only through precedence:
    # the scans' map over everything moves the missed band to "refinement"
    more = kept_by_step(out, ref, bg, mask, scanned=np.ones((N, N), bool),
                        fill_input=fill_input, replaced=replaced, blur_sigma=0)
    assert more["missed"] == 0.0 and more["refinement"] == pytest.approx(100 * 900 / 3600)
    # blurred, the parts still add up to the kept leftover
    blurred = kept_by_step(out, ref, bg, mask, scanned=scanned, fill_input=fill_input,
                           replaced=replaced)
    assert sum(blurred.values()) == pytest.approx(leftover_split(out, ref, bg, mask)[0])
    assert kept_by_step(out, ref, bg, mask, np.zeros((N, N), bool), scanned=scanned,
                        fill_input=fill_input, replaced=replaced) is None
    with pytest.raises(ValueError, match="scanned"):
        kept_by_step(out, ref, bg, mask, scanned=scanned[:10], fill_input=fill_input,
                     replaced=replaced)


def test_eval_splits_dynremoves_kept_leftover_by_step(tmp_path):
    # three photos of two movers: some of each mover is left (a quarter of the
    # mask, kept as the input showed it by more than one step)
    synth.write_scene(synth.make_scene(seed=1, n_views=3, size=(96, 128), n_objects=2),
                      tmp_path / "syn")
    rep = run_eval(tmp_path, methods=["dynremove", "paper", "median"], progress=False)
    by = {r["method"]: r for r in rep["sets"]}
    for m in ("dynremove", "paper"):
        r = by[m]
        parts = [r[f"kept_{k}"] for k in ("missed", "refinement", "fill", "replaced")]
        assert all(p is not None and 0 <= p <= 100 for p in parts), r
        assert sum(parts) == pytest.approx(r["leftover_kept"])
    assert by["dynremove"]["leftover_kept"] > 5
    assert sum(by["dynremove"][f"kept_{k}"] > 0 for k in ("missed", "refinement", "fill")) >= 2
    # the paper preset has no refinement and no fill of its own
    assert by["paper"]["kept_refinement"] == 0.0 and by["paper"]["kept_fill"] == 0.0
    # a baseline has no steps to name
    assert by["median"]["kept_missed"] is None and by["median"]["leftover_kept"] is not None
    assert "kept by the fill %" in format_table(rep)


@pytest.mark.parametrize("sigma", [0.0, 1.0])
def test_misplaced_fill_is_the_right_content_a_few_pixels_off(sigma):
    """A background of columns in 16 random colours (seeded); three 20 x 20 fills of a
    mover, each scored alone: the background 2 px to the side (the right content,
    misplaced: every wrong pixel of it is found within the 2 px tried), 6 px to the
    side (beyond them: few of its wrong pixels match a column within 2 px by chance)
    and a flat grey (other content: none)."""
    rng = np.random.default_rng(0)
    palette = rng.integers(0, 256, (16, 3)).astype(np.uint8)
    bg = np.ascontiguousarray(np.broadcast_to(palette[np.arange(120) % 16], (60, 120, 3)))
    boxes = [(slice(20, 40), slice(10, 30)), (slice(20, 40), slice(50, 70)),
             (slice(20, 40), slice(90, 110))]
    mask = np.zeros((60, 120), bool)
    for b in boxes:
        mask[b] = True
    ref = bg.copy()
    ref[mask] = MOVER
    out = bg.copy()
    out[boxes[0]] = bg[20:40, 12:32]
    out[boxes[1]] = bg[20:40, 56:76]
    out[boxes[2]] = 128

    def scores(b):
        m = np.zeros_like(mask)
        m[b] = True
        kept, refilled = leftover_split(out, ref, bg, m, blur_sigma=sigma)
        return kept, refilled, misplaced_fill_percent(out, ref, bg, m, blur_sigma=sigma)

    kept, refilled, mis = scores(boxes[0])
    assert kept == 0.0 and refilled > 50
    if sigma == 0:
        assert mis == pytest.approx(refilled)
    else:  # blurred, the box's rim mixes the fill with the photo around it, which no
        # shift of the background shows (a 1 px rim: 76 of its 400 px)
        assert refilled - 100 * 76 / 400 <= mis < refilled
    kept, refilled, mis = scores(boxes[1])
    assert kept == 0.0 and refilled > 50 and mis < 0.5 * refilled
    kept, refilled, mis = scores(boxes[2])
    # (blurred, only its rim, grey mixed with the photo around it, may happen to match)
    assert kept == 0.0 and refilled > 50 and mis <= (0.0 if sigma == 0 else 100 * 76 / 400)
    # over the whole mask: never more than the wrong fill; nothing with no shift tried
    # or with the output as the input (nothing refilled)
    _, refilled = leftover_split(out, ref, bg, mask, blur_sigma=sigma)
    assert 0.0 < misplaced_fill_percent(out, ref, bg, mask, blur_sigma=sigma) < refilled
    assert misplaced_fill_percent(out, ref, bg, mask, shift_px=0, blur_sigma=sigma) == 0.0
    assert misplaced_fill_percent(ref, ref, bg, mask, blur_sigma=sigma) == 0.0
    # the leftover's recoverable map: nothing recoverable, undefined
    assert misplaced_fill_percent(out, ref, bg, mask, np.zeros_like(mask)) is None
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError):
            misplaced_fill_percent(out, ref, bg, mask, shift_px=bad)
    with pytest.raises(ValueError):
        misplaced_fill_percent(out, ref[:10], bg, mask)

@pytest.mark.parametrize("sigma", [0.0, 1.0])
def test_planted_bugs(case, sigma):
    bg, ref, _, mask = case
    # a "method" that returns its input: no damage, the whole mover left over
    assert damage_percent(ref, ref, bg, mask, blur_sigma=sigma) == 0.0
    assert leftover_percent(ref, bg, mask, blur_sigma=sigma) == (100.0, None)
    # a perfect method
    assert damage_percent(ref, bg, bg, mask, blur_sigma=sigma) == 0.0
    assert leftover_percent(bg, bg, mask, blur_sigma=sigma) == (0.0, None)
    # damage counts over ALL pixels: a fully broken photo is ~100 % minus the mask band
    broken = np.empty_like(bg)
    broken[:] = DAMAGE
    band = cv2.dilate(mask.astype(np.uint8),
                      cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (11, 11))).sum()
    assert damage_percent(ref, broken, bg, mask, blur_sigma=sigma) == pytest.approx(
        100 * (N * N - band) / N**2, abs=0.05)


def test_whole_image_psnr_ssim_match_the_masked_ones(case):
    bg, _, out, _ = case
    ones = np.ones((N, N), bool)
    assert psnr(out, bg) == psnr_in_mask(out, bg, ones)
    assert ssim(out, bg) == ssim_in_mask(out, bg, ones)


def test_bad_inputs(case):
    bg, ref, out, mask = case
    with pytest.raises(ValueError):
        damage_percent(ref[..., 0], out[..., 0], bg[..., 0], mask)
    with pytest.raises(ValueError):
        damage_percent(ref, out, bg, mask[:-1])
    with pytest.raises(ValueError):
        damage_percent(ref, out, bg, mask, dilate_px=-1)
    with pytest.raises(ValueError):
        leftover_percent(out, bg, mask, blur_sigma=-1)
    with pytest.raises(ValueError):
        leftover_percent(out, bg, mask, np.ones((3, 3), bool))


# --------------------------------------------------------------------------- composite
def test_free_map_convention():
    """H_k maps reference -> view k; outside view k's frame is not free."""
    Hh, Ww = 64, 64
    masks = [np.zeros((Hh, Ww), bool) for _ in range(3)]
    ref = 1
    masks[0][10:20, 10:20] = True  # sq1
    masks[0][10:20, 40:50] = True  # sq2
    masks[0][30:40, 20:30] = True  # sq3
    masks[2][10:20, 40:50] = True  # view 2 cols 40..49 = reference cols 10..19 (sq1)
    T = np.array([[1, 0, 30], [0, 1, 0]], float)
    Hs = [np.eye(3), np.eye(3), np.vstack([T, [0, 0, 1]])]
    free = composite.free_map(masks, Hs, ref)
    expected = np.ones((Hh, Ww), bool)
    expected[10:20, 10:20] = False  # covered in view 0 and (shifted) in view 2
    expected[10:20, 40:50] = False  # covered in view 0, outside view 2's frame
    np.testing.assert_array_equal(free, expected)  # sq3: seen free by view 2
    assert not composite.free_map(masks[:1], Hs[:1], 0).any()  # no other view


def _static_set(folder: Path, n: int = 5, size: tuple[int, int] = (160, 220)) -> None:
    rng = np.random.default_rng(0)
    H, W = size
    base = cv2.GaussianBlur(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), (0, 0), 2)
    folder.mkdir(parents=True)
    for i in range(n):
        M = np.float32([[1, 0, 3 * i], [0, 1, i]])
        cv2.imwrite(str(folder / f"{i:04d}.png"),
                    cv2.warpAffine(base, M, (W, H), borderMode=cv2.BORDER_REFLECT))


@pytest.fixture(scope="module")
def comp_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("wp")
    _static_set(root / "static")
    synth.write_scene(synth.make_scene(seed=4, n_views=5, size=(120, 160), n_objects=1),
                      root / "objects" / "walker")
    out = root / "data" / "comp"
    info = composite.make_composite(root / "static", root / "objects", out, seed=3, n_views=5)
    return root, out, info


def test_composite_writes_free_consistent_with_masks(comp_dir):
    root, out, info = comp_dir
    free = cv2.imread(str(out / "free.png"), cv2.IMREAD_GRAYSCALE)
    frames = sorted((out / "frames").iterdir())
    H, W = cv2.imread(str(frames[0])).shape[:2]
    assert free.shape == (H, W) and set(np.unique(free)) <= {0, 255}
    free = free > 0
    masks = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 0
             for p in sorted((out / "masks").iterdir())]
    ref = len(masks) // 2
    # the static views are translations: reference pixel q is q + (3 (k - ref), k - ref)
    # in view k. Shift each other view's mask back, up to the homography's sub-pixel error.
    seen_free = np.zeros((H, W), bool)
    surely_covered = np.ones((H, W), bool)
    for k, m in enumerate(masks):
        if k == ref:
            continue
        dx, dy = 3 * (k - ref), k - ref
        M = np.float32([[1, 0, -dx], [0, 1, -dy]])
        back = cv2.warpAffine(m.astype(np.uint8), M, (W, H), flags=cv2.INTER_NEAREST,
                              borderValue=1) > 0
        ker = np.ones((5, 5), np.uint8)
        seen_free |= cv2.dilate(back.astype(np.uint8), ker) == 0  # free with a margin
        surely_covered &= cv2.erode(back.astype(np.uint8), ker) > 0
    assert free[seen_free].all()
    assert not free[surely_covered].any()
    # the reference's own mask does not matter: its pixels away from the others' objects are free
    assert masks[ref].any() and free[masks[ref] & seen_free].all()
    assert info["ref_mask_recoverable"] == pytest.approx(free[masks[ref]].mean(), abs=1e-4)


def test_free_png_does_not_change_the_other_files(comp_dir, tmp_path):
    root, out, _ = comp_dir
    again = tmp_path / "again"
    composite.make_composite(root / "static", root / "objects", again, seed=3, n_views=5)
    for sub in ("frames", "masks"):
        for p in sorted((out / sub).iterdir()):
            assert p.read_bytes() == (again / sub / p.name).read_bytes()
    for name in ("background.png", "free.png"):
        assert (out / name).read_bytes() == (again / name).read_bytes()


def test_eval_reports_whole_photo_keys(comp_dir, tmp_path):
    root, out, _ = comp_dir
    # a copy without free.png: leftover over the whole mask, unrecoverable unknown
    import shutil

    nofree = root / "data" / "comp-nofree"
    if not nofree.exists():
        shutil.copytree(out, nofree)
        (nofree / "free.png").unlink()
    rep = run_eval(root / "data", methods=["median", "telea"], progress=False)
    json.dumps(rep)
    by = {(r["set"], r["method"]): r for r in rep["sets"]}
    for (s, m), r in by.items():
        assert set(SCORE_KEYS) <= set(r), r
        assert r["psnr_whole"] > 10 and 0 < r["ssim_whole"] <= 1
        assert 0 <= r["damage"] <= 100 and 0 <= r["leftover"] <= 100
        if s == "comp":
            assert r["unrecoverable"] is not None and 0 <= r["unrecoverable"] <= 100
        else:
            assert r["unrecoverable"] is None
    assert by[("comp", "telea")]["damage"] == 0.0  # Telea only touches the true mask
    info = {i["set"]: i for i in rep["set_info"]}
    assert info["comp"]["has_free"] and not info["comp-nofree"]["has_free"]
    for m in ("median", "telea"):
        for k in ("psnr_whole", "ssim_whole", "damage", "leftover"):
            assert rep["summary"][m][k] is not None
    text = format_table(rep)
    assert "whole photo" in text and "mean damage %" in text and "mean leftover %" in text


def test_eval_on_synthetic_scenes_without_free(tmp_path):
    synth.write_scene(synth.make_scene(seed=1, n_views=4, size=(72, 96), n_objects=1),
                      tmp_path / "syn")
    rep = run_eval(tmp_path, methods=["telea"], progress=False)
    (r,) = rep["sets"]
    assert r["damage"] == 0.0 and r["leftover"] is not None and r["unrecoverable"] is None


def _own_case():
    """Two sources over a 40x60 reference; the fill replaced rows 10..29, cols 10..49
    (800 px). Source 0's field is the identity, source 1's is shifted 20 px right.
    Source 0's own mover covers its cols 10..29; source 1's its cols 40..59, which
    the shifted field reaches from the reference's cols 20..39."""
    H, W = 40, 60
    replaced = np.zeros((H, W), bool)
    replaced[10:30, 10:50] = True
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    fields = np.stack([np.stack([gx, gy], -1), np.stack([gx + 20, gy], -1)])
    m0 = np.zeros((H, W), bool)
    m0[:, 10:30] = True
    m1 = np.zeros((H, W), bool)
    m1[:, 40:60] = True
    return replaced, fields, [m0, m1]


def test_own_mover_fill_counts_the_members_on_their_own_movers():
    replaced, fields, masks = _own_case()
    members = np.zeros((2,) + replaced.shape, bool)
    members[0] = replaced  # source 0 alone: its mover under cols 10..29 = half of 40 cols
    assert own_mover_fill_percent(replaced, members, fields, masks) == 50.0
    members[1] = replaced  # both: ghosted where at least one of the two is on its mover
    # cols 10..19: source 0 on its mover (1 of 2); 20..29: both; 30..39: source 1
    # (x + 20 in 50..59); 40..49: source 1 lands outside its frame (not a mover)
    assert own_mover_fill_percent(replaced, members, fields, masks) == 75.0
    members[0] = False  # source 1 alone: cols 20..39 of the 40
    assert own_mover_fill_percent(replaced, members, fields, masks) == 50.0


def test_own_mover_fill_undefined_and_bad_inputs():
    replaced, fields, masks = _own_case()
    members = np.zeros((2,) + replaced.shape, bool)
    assert own_mover_fill_percent(replaced, members, fields, masks) is None  # nothing filled
    members[1] = replaced
    assert own_mover_fill_percent(replaced, members, fields, [masks[0], None]) is None
    # a source without a mask that is not a member does not matter
    assert own_mover_fill_percent(replaced, members, fields, [None, masks[1]]) == 50.0
    with pytest.raises(ValueError):
        own_mover_fill_percent(replaced, members[:1], fields, masks)
    with pytest.raises(ValueError):
        own_mover_fill_percent(replaced, members, fields[..., :1], masks)


def test_eval_reports_the_own_mover_fill_of_the_default_preset(tmp_path):
    # a synthetic scene: every view has its true mask, so the fill's sources can be judged
    from dynremove.evaluation.evaluate import load_set, own_mover_fill
    from dynremove.pipeline import remove_dynamic

    synth.write_scene(synth.make_scene(seed=2, n_views=5, size=(120, 160), n_objects=2),
                      tmp_path / "syn")
    rep = run_eval(tmp_path, methods=["dynremove", "median"], progress=False)
    by = {r["method"]: r for r in rep["sets"]}
    assert by["median"]["own_mover"] is None  # no fill by selection
    (es,) = find_sets(tmp_path)
    ls = load_set(es)
    assert ls.masks is not None and all(m is not None for m in ls.masks)
    res = remove_dynamic(ls.images, ref=ls.ref, names=ls.names)
    sel = res.selection
    direct = own_mover_fill_percent(sel.replaced, sel.members, np.stack(sel.fields),
                                    [ls.masks[i] for i in res.source_indices])
    assert own_mover_fill(ls, res) == direct == by["dynremove"]["own_mover"]
    assert direct is not None and 0.0 <= direct <= 100.0
    assert "mean own-mover fill %" in format_table(rep)


DATA = Path(os.environ.get("DYNREMOVE_DATA", Path(__file__).resolve().parents[2] / "shared/data"))


@pytest.mark.skipif(not (DATA / "static/fountain-P11").is_dir()
                    or not (DATA / "davis/camel").is_dir(),
                    reason="needs shared/data (static/fountain-P11 and davis/camel); "
                           "set DYNREMOVE_DATA")
def test_three_view_composite_on_real_data(tmp_path):
    objs = find_sets(DATA / "davis", "camel")
    info = composite.make_composite(DATA / "static/fountain-P11", DATA / "davis",
                                    tmp_path / "c", seed=0, n_views=3, object_sets=objs)
    assert info["n_views"] == 3 and len(list((tmp_path / "c" / "frames").iterdir())) == 3
    free = cv2.imread(str(tmp_path / "c" / "free.png"), cv2.IMREAD_GRAYSCALE)
    assert free.shape == (info["size"][1], info["size"][0])
    assert info["ref_mask_recoverable"] is not None and info["ref_mask_recoverable"] > 0.5

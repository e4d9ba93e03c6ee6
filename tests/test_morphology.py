"""clean_mask (default preset): opening, closing, small components, holes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynremove.params import DEFAULT
from dynremove.refine import morphology
from dynremove.refine.morphology import clean_mask, clean_mask_drops, dilate_disc


def _square():
    L = np.zeros((80, 80), bool)
    L[20:60, 20:60] = True
    return L


def test_clean_mask_keeps_a_solid_object():
    out = clean_mask(_square(), DEFAULT)
    # the opening by a disc rounds the corners, and only the corners
    assert out[24:56, 20:60].all() and out[20:60, 24:56].all()
    assert not (out & ~_square()).any()
    assert 0 < (_square() & ~out).sum() <= 4 * 8


def test_clean_mask_drops_specks_and_fills_holes():
    L = _square()
    L[5, 5] = True  # a speck: removed by the opening
    L[38:42, 38:42] = False  # a hole: filled (by the closing, or the hole filling)
    L[2:5, 70:73] = True  # 3×3: smaller than the disc, opened away
    np.testing.assert_array_equal(clean_mask(L, DEFAULT), clean_mask(_square(), DEFAULT))


def test_clean_mask_fills_a_large_hole():
    L = _square()
    L[30:50, 30:50] = False  # 20×20: too large for the closing, filled as a hole
    np.testing.assert_array_equal(clean_mask(L, DEFAULT), clean_mask(_square(), DEFAULT))


def test_clean_mask_drops_regions_below_min_region_px():
    L = _square()
    L[2:14, 66:78] = True  # 12×12: survives the opening (disc radius 3), ~140 px
    kept = clean_mask(L, DEFAULT)[2:14, 66:78].sum()
    assert DEFAULT.min_region_px < kept <= 144
    out = clean_mask(L, DEFAULT.replace(min_region_px=200))
    np.testing.assert_array_equal(out, clean_mask(_square(), DEFAULT))


def test_clean_mask_closes_a_thin_gap():
    L = _square()
    L[20:60, 40] = False  # a 1 px cut through the object: the opening splits it,
    out = clean_mask(L, DEFAULT)  # the closing joins the halves again
    assert out[25:55, 40].all()
    assert not (out & ~_square()).any()


def test_majority_keeps_a_holed_mesh_that_hangs_on_a_solid_part():
    """A slow mover's scan map is dense but holed (its patches matched the mover
    itself where the sources still show it). The opening alone erased the
    holed part; the majority filter keeps it where it holds a solid part of
    the mover, and drops a holed region with none (hysteresis) and specks."""
    rng = np.random.default_rng(0)
    mover = _square()
    L = mover & (rng.random((80, 80)) < 0.7)  # 30 % holes ...
    L[20:60, 20:32] = True  # ... but for a solid part
    lone = np.zeros_like(L)
    lone[64:78, 2:40] = True
    L |= lone & (rng.random((80, 80)) < 0.7)  # a holed region with no solid part
    specks = ~dilate_disc(mover | lone, 8) & (rng.random((80, 80)) < 0.15)
    L |= specks
    plain = clean_mask(L, DEFAULT)
    kept = clean_mask(L, DEFAULT, majority=True)
    assert (plain & mover).sum() < 0.5 * mover.sum()  # the holed part erased
    assert kept[24:56, 24:56].all()  # all but a rim of the window's radius
    assert (kept & mover).sum() >= 0.8 * mover.sum()
    assert not (kept & ~dilate_disc(mover, 2)).any()  # no lone mesh, no speck, no growth
    # a lone holed region alone: nothing
    assert not clean_mask(lone & (rng.random((80, 80)) < 0.7), DEFAULT, majority=True).any()
    # a solid object loses only its corners (the median rounds them a little more)
    solid = clean_mask(_square(), DEFAULT, majority=True)
    assert not (solid & ~_square()).any()
    assert solid[24:56, 20:60].all() and solid[20:60, 24:56].all()


def test_clean_mask_drops_tells_the_opening_from_the_small_region_rule():
    """A holed mesh (every other pixel) is erased by the opening; a solid 9x9 block
    survives it but is under min_region_px; a solid 30x30 block is kept. The codes
    agree with what ``clean_mask`` keeps (the debugger's replay of it)."""
    L = np.zeros((120, 160), bool)
    L[10:60:2, 10:60] = True  # a mesh of 1 px rows
    L[80:89, 20:29] = True  # 81 px
    L[70:100, 100:130] = True  # 900 px
    params = DEFAULT.replace(patch_size=13, min_region_px=200)
    why = clean_mask_drops(L, params.patch_size, params.min_region_px)
    kept = clean_mask(L, params)
    assert (why[10:60:2, 10:60] == 1).all()
    assert (why[81:88, 21:28] == 2).all()  # (its corners are rounded off by the disc)
    assert (why[73:97, 103:127] == 0).all() and kept[73:97, 103:127].all()
    assert not (kept & (why > 0)).any()  # what is dropped is not kept
    assert (why[~L] == 0).all()


@pytest.mark.parametrize("r", [1, 7, 10, 13, 40, 80])
def test_dilate_disc_equals_opencv_at_every_radius(r):
    """The dilation by the disc's rows (large radii) is OpenCV's, pixel for pixel:
    shapes, specks, pixels on the frame's edge and a mask wider than the disc."""
    rng = np.random.default_rng(r)
    m = np.zeros((150, 230), np.uint8)
    cv2.circle(m, (90, 70), 30, 1, -1)
    cv2.rectangle(m, (180, 5), (200, 140), 1, -1)
    m[rng.random(m.shape) < 0.002] = 1
    m[0, 3] = m[149, 229] = m[75, 0] = 1
    want = cv2.dilate(m, morphology.disc(r)).astype(bool)
    np.testing.assert_array_equal(morphology.dilate_disc(m.astype(bool), r), want)
    np.testing.assert_array_equal(morphology.dilate_disc(np.zeros((9, 5), bool), r),
                                  np.zeros((9, 5), bool))

"""clean_mask (default preset): opening, closing, small components, holes."""

from __future__ import annotations

import numpy as np

from dynremove.params import DEFAULT
from dynremove.refine.morphology import clean_mask


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

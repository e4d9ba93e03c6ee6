"""Tests of dynremove.metrics: hand-checked values, a naive SSIM oracle, invariants."""

from __future__ import annotations

import doctest
import math

import cv2
import numpy as np
import numpy.testing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st



from dynremove.evaluation import metrics  # noqa: E402


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def _box(shape, y0, y1, x0, x1) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def test_docstring_examples():
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    tests = finder.find(metrics, metrics.__name__)
    assert sum(len(t.examples) for t in tests) >= 5
    for t in tests:
        runner.run(t)
    assert runner.summarize(verbose=False).failed == 0


# --------------------------------------------------------------------------- jaccard


def test_jaccard_hand_values():
    gt = _box((10, 10), 0, 4, 0, 4)  # 16 px
    pred = _box((10, 10), 2, 6, 2, 6)  # 16 px, overlap 2x2 = 4
    assert metrics.jaccard(pred, gt) == pytest.approx(4 / 28)
    assert metrics.jaccard(gt, gt) == 1.0
    assert metrics.jaccard(gt, ~gt) == 0.0


def test_jaccard_empty_cases():
    z = np.zeros((4, 5), bool)
    assert metrics.jaccard(z, z) == 1.0
    assert metrics.jaccard(z, _box((4, 5), 0, 1, 0, 1)) == 0.0


def test_jaccard_accepts_0_255_and_int_masks():
    gt = _box((6, 6), 1, 3, 1, 3)
    assert metrics.jaccard(gt.astype(np.uint8) * 255, gt.astype(int)) == 1.0


def test_jaccard_shape_mismatch_raises():
    with pytest.raises(ValueError, match="same shape"):
        metrics.jaccard(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="2-D"):
        metrics.jaccard(np.zeros(4), np.zeros(4))


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_jaccard_properties(seed):
    r = np.random.default_rng(seed)
    a = r.random((7, 9)) < r.random()
    b = r.random((7, 9)) < r.random()
    j = metrics.jaccard(a, b)
    assert 0.0 <= j <= 1.0
    assert j == metrics.jaccard(b, a)
    p, rec = metrics.precision_recall(a, b)
    assert 0.0 <= p <= 1.0 and 0.0 <= rec <= 1.0
    if a.any() and b.any():  # J = 1 / (1/p + 1/r - 1) when p, r > 0
        if p > 0 and rec > 0:
            assert j == pytest.approx(1.0 / (1.0 / p + 1.0 / rec - 1.0))
        else:
            assert j == 0.0


# --------------------------------------------------------------------------- P / R


def test_precision_recall_hand_values():
    gt = _box((10, 10), 0, 4, 0, 4)  # 16 px
    pred = _box((10, 10), 0, 4, 0, 2) | _box((10, 10), 8, 10, 8, 10)  # 8 TP + 4 FP
    p, r = metrics.precision_recall(pred, gt)
    assert p == pytest.approx(8 / 12)
    assert r == pytest.approx(8 / 16)


def test_precision_recall_empty_conventions():
    z = np.zeros((3, 3), bool)
    one = _box((3, 3), 1, 2, 1, 2)
    assert metrics.precision_recall(z, z) == (1.0, 1.0)
    assert metrics.precision_recall(z, one) == (1.0, 0.0)  # nothing predicted
    assert metrics.precision_recall(one, z) == (0.0, 1.0)  # nothing to find


# --------------------------------------------------------------------------- PNG masks


def test_mask_from_png_threshold_is_127():
    arr = np.array([[0, 127, 128, 255]], np.uint8)
    npt.assert_array_equal(metrics.mask_from_png(arr), [[False, False, True, True]])
    assert metrics.mask_from_png(arr[..., None]).shape == (1, 4)


def test_mask_from_png_rejects_colour():
    with pytest.raises(ValueError, match="IMREAD_GRAYSCALE"):
        metrics.mask_from_png(np.zeros((4, 4, 3), np.uint8))


# --------------------------------------------------------------------------- PSNR


@pytest.mark.parametrize("err", [1, 5, 10, 51])
def test_psnr_constant_error(err, rng):
    ref = rng.integers(60, 190, (12, 14, 3)).astype(np.uint8)
    img = ref.astype(int)
    mask = _box((12, 14), 2, 9, 3, 11)
    img[mask] += err * np.array([1, -1, 1])  # |error| = err on every channel
    img[~mask] = 0  # errors outside the mask must not count
    got = metrics.psnr_in_mask(img.astype(np.uint8), ref, mask)
    assert got == pytest.approx(20 * math.log10(255 / err))


def test_psnr_identical_is_inf_and_data_range():
    a = np.full((5, 5), 0.5)
    mask = np.ones((5, 5), bool)
    assert metrics.psnr_in_mask(a, a, mask) == math.inf
    b = a + 0.1  # MSE 0.01 with data range 1 -> 20 dB
    assert metrics.psnr_in_mask(b, a, mask, data_range=1.0) == pytest.approx(20.0)


def test_psnr_validation():
    a = np.zeros((5, 5, 3), np.uint8)
    with pytest.raises(ValueError, match="empty"):
        metrics.psnr_in_mask(a, a, np.zeros((5, 5), bool))
    with pytest.raises(ValueError, match="same shape"):
        metrics.psnr_in_mask(a, a[:, :4], np.ones((5, 5), bool))
    with pytest.raises(ValueError, match="mask must have"):
        metrics.psnr_in_mask(a, a, np.ones((5, 4), bool))
    with pytest.raises(ValueError, match="data_range"):
        metrics.psnr_in_mask(a, a, np.ones((5, 5), bool), data_range=0)
    f = np.zeros((5, 5))
    g = f.copy()
    g[2, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        metrics.psnr_in_mask(g, f, np.ones((5, 5), bool))
    # NaN outside the mask is ignored
    m = np.ones((5, 5), bool)
    m[2, 2] = False
    assert metrics.psnr_in_mask(g, f, m) == math.inf


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_psnr_never_nan(seed):
    r = np.random.default_rng(seed)
    a = r.integers(0, 256, (6, 7, 3)).astype(np.uint8)
    b = np.where(r.random((6, 7, 3)) < 0.5, a, r.integers(0, 256, (6, 7, 3))).astype(
        np.uint8
    )
    mask = r.random((6, 7)) < 0.5
    mask[0, 0] = True
    v = metrics.psnr_in_mask(a, b, mask)
    assert not math.isnan(v)
    mse = ((a.astype(float) - b.astype(float))[mask] ** 2).mean()
    assert v == pytest.approx(10 * math.log10(255.0 ** 2 / mse))


# --------------------------------------------------------------------------- SSIM


def _ssim_naive_at(a, b, y, x, L=255.0):
    """SSIM at one pixel by explicit sums (Gaussian 11x11, sigma 1.5, reflect-101)."""
    r = 5
    g1 = np.exp(-((np.arange(11) - r) ** 2) / (2 * 1.5**2))
    g1 /= g1.sum()
    w = np.outer(g1, g1)
    pa = np.pad(a, r, mode="reflect")[y : y + 11, x : x + 11]  # numpy reflect = 101
    pb = np.pad(b, r, mode="reflect")[y : y + 11, x : x + 11]
    mu_a = (w * pa).sum()
    mu_b = (w * pb).sum()
    va = (w * (pa - mu_a) ** 2).sum()
    vb = (w * (pb - mu_b) ** 2).sum()
    cov = (w * (pa - mu_a) * (pb - mu_b)).sum()
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / (
        (mu_a**2 + mu_b**2 + c1) * (va + vb + c2)
    )


def test_ssim_matches_naive_oracle_pixelwise(rng):
    a = rng.integers(0, 256, (16, 19)).astype(np.float64)
    b = np.clip(a + rng.normal(0, 25, a.shape), 0, 255)
    for y, x in [(0, 0), (3, 7), (8, 9), (15, 18), (10, 1)]:
        mask = np.zeros(a.shape, bool)
        mask[y, x] = True
        got = metrics.ssim_in_mask(a, b, mask)
        assert got == pytest.approx(_ssim_naive_at(a, b, y, x), abs=1e-9)
    # the mask average is the mean of the per-pixel values
    mask = _box(a.shape, 2, 6, 4, 9)
    expect = np.mean([_ssim_naive_at(a, b, y, x) for y, x in zip(*np.nonzero(mask))])
    assert metrics.ssim_in_mask(a, b, mask) == pytest.approx(expect, abs=1e-9)


def test_ssim_flat_images_hand_value():
    a = np.full((9, 9, 3), 100, np.uint8)
    b = np.full((9, 9, 3), 110, np.uint8)
    c1 = (0.01 * 255) ** 2
    expect = (2 * 100 * 110 + c1) / (100**2 + 110**2 + c1)  # variances are 0
    assert metrics.ssim_in_mask(a, b, np.ones((9, 9), bool)) == pytest.approx(expect)


def test_ssim_identical_is_one(rng):
    a = rng.integers(0, 256, (20, 24, 3)).astype(np.uint8)
    assert metrics.ssim_in_mask(a, a, _box((20, 24), 3, 10, 2, 20)) == 1.0


def test_ssim_mean_shift_and_noise_lower_it(rng):
    noise = rng.integers(0, 200, (32, 32)).astype(np.float64)
    base = cv2.GaussianBlur(noise, (0, 0), 1)
    mask = _box((32, 32), 4, 28, 4, 28)
    s_small = metrics.ssim_in_mask(base + 10, base, mask)
    s_big = metrics.ssim_in_mask(base + 40, base, mask)
    assert 1.0 > s_small > s_big
    noisy = base + rng.normal(0, 20, base.shape)
    assert metrics.ssim_in_mask(noisy, base, mask) < 0.9
    assert metrics.ssim_in_mask(noisy, base, mask) == pytest.approx(
        metrics.ssim_in_mask(base, noisy, mask)
    )


def test_ssim_colour_is_mean_over_channels(rng):
    a = rng.integers(0, 256, (14, 15, 3)).astype(np.uint8)
    b = a.copy()
    b[..., 2] = np.clip(b[..., 2].astype(int) + rng.integers(-40, 40, (14, 15)), 0, 255)
    mask = _box((14, 15), 2, 12, 3, 13)
    per_channel = [metrics.ssim_in_mask(a[..., c], b[..., c], mask) for c in range(3)]
    assert metrics.ssim_in_mask(a, b, mask) == pytest.approx(np.mean(per_channel))
    assert per_channel[0] == per_channel[1] == 1.0 > per_channel[2]


def test_ssim_validation():
    a = np.zeros((6, 6), np.uint8)
    with pytest.raises(ValueError, match="empty"):
        metrics.ssim_in_mask(a, a, np.zeros((6, 6)))
    with pytest.raises(ValueError, match="same shape"):
        metrics.ssim_in_mask(a, np.zeros((6, 7)), np.ones((6, 6)))
    f = np.zeros((6, 6))
    f[0, 0] = np.inf
    m = np.zeros((6, 6), bool)
    m[5, 5] = True
    with pytest.raises(ValueError, match="finite"):
        metrics.ssim_in_mask(f, a, m)  # inf outside the mask still enters the window

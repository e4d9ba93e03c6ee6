"""The blend's sparse computation equals the dense one (``tests/naive.py``)."""

from __future__ import annotations

import cv2
import naive
import numpy as np
import pytest

from dynremove.refine.fields import harmonic_fill, interpolate_field, mask_boxes
from dynremove.refine.montage import offset_blend
from dynremove.refine.select import member_median


def _blobs(rng, H, W, n):
    m = np.zeros((H, W), np.uint8)
    for _ in range(n):
        centre = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        axes = (int(rng.integers(3, W // 3 + 4)), int(rng.integers(3, H // 3 + 4)))
        cv2.ellipse(m, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    return m.astype(bool)


@pytest.mark.parametrize("seed", range(6))
def test_harmonic_fill_equals_the_dense_solve_where_needed(seed):
    """Bit for bit at ``need`` (everywhere without it), except below float32's
    normal range: 0.25·x of a subnormal x rounds, and filter2D's vector and
    scalar paths round it apart."""
    rng = np.random.default_rng(seed)
    H, W = (int(v) for v in rng.integers(30, 400, 2))
    C = 1 + seed % 3
    rep = _blobs(rng, H, W, 1 + seed % 4)
    r = 2 + seed
    ring = cv2.dilate(rep.astype(np.uint8), np.ones((2 * r + 1,) * 2, np.uint8)) > 0
    good = ring & ~rep & (rng.random((H, W)) < 0.9)
    field = np.zeros((H, W, C), np.float32)
    field[good] = rng.normal(size=(int(good.sum()), C)) * 10 + np.arange(C)
    need = rep & (rng.random((H, W)) < 0.7) if seed % 2 else rep
    ref = naive.harmonic_fill(field, ~good)
    out = harmonic_fill(field, ~good, need=need)
    np.testing.assert_allclose(out[need], ref[need], rtol=0, atol=1e-30)
    np.testing.assert_allclose(harmonic_fill(field, ~good), ref, rtol=0, atol=1e-30)


@pytest.mark.parametrize("seed", range(8))
def test_offset_blend_equals_the_dense_blend(seed):
    rng = np.random.default_rng(seed)
    H, W = (int(v) for v in rng.integers(40, 200, 2))
    L = 2 + seed % 3
    bg = cv2.GaussianBlur(rng.integers(0, 256, (H, W, 3)).astype(np.uint8), (0, 0), 2)
    cand = np.stack([np.clip(bg.astype(int) + rng.integers(-40, 40, 3)
                             + rng.integers(-5, 5, (H, W, 3)), 0, 255).astype(np.uint8)
                     for _ in range(L)])
    rep = np.zeros((H, W), np.uint8)
    for _ in range(1 + seed % 3):
        cv2.circle(rep, (int(rng.integers(0, W)), int(rng.integers(0, H))),
                   int(rng.integers(2, 40)), 1, -1)
    rep = rep.astype(bool)
    labels = np.where(rep, rng.integers(1, L, (H, W)) if seed % 3 else 1, 0)
    usable = rng.random((L, H, W)) < 0.95
    # Lab values whose ring differences spread around an offset per candidate
    labs = (rng.normal(size=(L, H, W, 3)) * (6 if seed == 5 else 12)
            + rng.normal(size=(L, 1, 1, 3)) * 20).astype(np.float32)
    ring_px = 2 + seed % 4
    np.testing.assert_array_equal(
        offset_blend(cand[0], cand, labels, rep, usable, labs, ring_px=ring_px),
        naive.offset_blend(cand[0], cand, labels, rep, usable, labs, ring_px=ring_px))


def test_mask_boxes_keep_every_pixel_once_and_far_from_their_edges():
    rng = np.random.default_rng(3)
    need = _blobs(rng, 300, 500, 5) & (rng.random((300, 500)) < 0.5)
    bounds = (5, 290, 0, 500)
    need[:bounds[0]] = need[bounds[1]:] = False
    margin = 23
    kept = np.zeros(need.shape, int)
    for (y0, y1, x0, x1), keep in mask_boxes(need, margin, bounds):
        assert bounds[0] <= y0 < y1 <= bounds[1] and bounds[2] <= x0 < x1 <= bounds[3]
        ys, xs = np.nonzero(keep)
        for lo, hi, v, edge in ((y0, y1, ys + y0, bounds[:2]), (x0, x1, xs + x0, bounds[2:])):
            if lo != edge[0]:
                assert (v - lo >= margin).all()
            if hi != edge[1]:
                assert (hi - 1 - v >= margin).all()
        kept[y0:y1, x0:x1] += keep
    np.testing.assert_array_equal(kept, need.astype(int))
    assert mask_boxes(np.zeros((10, 10), bool), 3, (0, 10, 0, 10)) == []


def test_member_median_equals_the_nan_median():
    rng = np.random.default_rng(0)
    values = rng.integers(0, 256, (5, 4000, 3)).astype(np.uint8)
    member = rng.random((5, 4000)) < 0.5
    member[rng.integers(0, 5, 4000), np.arange(4000)] = True
    np.testing.assert_array_equal(member_median(values, member),
                                  naive.member_median(values, member))


@pytest.mark.parametrize("shape", [(7, 5), (38, 50), (90, 31)])
def test_interpolate_field_equals_its_gaussian_blur_form(shape):
    """The normalised convolution with the Gaussian's taps cut to the image
    (``fields._gaussian_taps``) equals the ``cv2.GaussianBlur`` form it replaced,
    bit for bit: sparse valid pixels, so that the widest blurs (σ 128 px) run."""
    rng = np.random.default_rng(shape[0])
    field = rng.normal(size=shape + (3,)).astype(np.float32)
    hole = rng.random(shape) > 0.03
    hole[0, 0] = False
    np.testing.assert_array_equal(interpolate_field(field, hole),
                                  naive.interpolate_field(field, hole))


@pytest.mark.parametrize("start", ["cheapest", "given"])
def test_alpha_expansion_on_the_movable_pixels_equals_the_whole_grid(rng, start):
    """The expansion's moves keep to the pixels with two allowed labels or more (and
    the edges touching them): the same labelling, bit for bit, as the graph over the
    whole grid, with labels forbidden on most of it (as on the fill's box), a
    started labelling that puts pixels on a forbidden label, and 5 labels."""
    from dynremove.refine.montage import expansion_labels

    nl, H, W = 5, 40, 56
    D = rng.uniform(0, 30, (nl, H, W))
    allowed = np.zeros((nl, H, W), bool)
    allowed[0] = True
    allowed[1:, 10:30, 12:40] = rng.uniform(size=(nl - 1, 20, 28)) < 0.8
    forbidden = 1e6
    D[~allowed] = forbidden
    D[0, 15:25, 20:30] += 40  # the reference costly inside: the sources take it
    # alike photos (seams cheap where they agree), one source off in a patch
    colours = (rng.uniform(0, 100, (1, H, W, 3)) + rng.normal(0, 2, (nl, H, W, 3))
               ).astype(np.float32)
    colours[2, 10:20, 12:25] += 30
    init = None
    if start == "given":
        init = np.argmin(D, 0)
        init[12, 14] = 4 if not allowed[4, 12, 14] else init[12, 14]
        init[2, 2] = 3  # outside every source: on a forbidden label
    fast = expansion_labels(D, colours, beta=0.7, cycles=2, init=init, forbidden=forbidden)
    want = naive.expansion_labels(D, colours, beta=0.7, cycles=2, init=init,
                                  forbidden=forbidden)
    assert np.array_equal(fast, want)
    assert (fast != 0).sum() > 50  # the sources took part of it: not a trivial labelling
    assert allowed[fast, np.arange(H)[:, None], np.arange(W)[None]].all()


def test_light_like_keeps_light_and_drops_a_hue_carried_in_from_the_ring():
    """``montage.light_like``: a change of exposure and white balance (gains 1.2 ×
    1.06 / 1.00 / 0.94 on B / G / R) is kept byte for byte; an offset that turns a
    brown table green (+19 / +32 / -35 levels, measured on tim1-tim4 of
    ``bursts/tim6``) keeps only its change of brightness, so the pixel stays brown;
    between the two spreads the hue change is kept in part."""
    from dynremove.refine.montage import CONTENT_SPREAD, LIGHT_FLOOR, LIGHT_SPREAD, light_like

    brown = np.array([[94, 117, 136], [101, 121, 138]], np.uint8)
    lit = np.clip(np.round(brown * np.array([1.2 * 1.06, 1.2, 1.2 * 0.94])), 0, 255
                  ).astype(np.uint8)
    np.testing.assert_array_equal(light_like(brown, lit), lit)
    green = np.clip(brown.astype(int) + [19, 32, -35], 0, 255).astype(np.uint8)
    out = light_like(brown, green).astype(int)
    assert (out[:, 2] > out[:, 1]).all() and (out[:, 1] > out[:, 0]).all(), out  # R > G > B
    gain = lambda a, b: np.log((b.astype(float) + LIGHT_FLOOR) / (a + LIGHT_FLOOR))  # noqa: E731
    spread = np.ptp(gain(brown, out), axis=1)
    assert (spread < 0.02).all(), spread  # one gain: brightness only
    np.testing.assert_allclose(gain(brown, out).mean(1), gain(brown, green).mean(1), atol=0.01)
    # half-way between the spreads: half the departure kept
    lg = np.array([[0.0, 0.0, -(LIGHT_SPREAD + CONTENT_SPREAD) / 2]])
    s = np.array([[120, 120, 120]], np.uint8)
    mid = np.clip((s + LIGHT_FLOOR) * np.exp(lg) - LIGHT_FLOOR + 0.5, 0, 255).astype(np.uint8)
    half = np.ptp(gain(s, light_like(s, mid)), axis=1)
    assert 0.35 * np.ptp(gain(s, mid)) < half[0] < 0.65 * np.ptp(gain(s, mid)), half


def _two_sources_meeting(step):
    """A 100×140 scene of smooth texture; a replaced region (rows 20-79, columns
    20-119) filled by source 1 on its left half and source 2 on its right, which
    shows the same texture ``step`` B/G/R levels brighter (its light not matched)."""
    rng = np.random.default_rng(5)
    tex = cv2.GaussianBlur(rng.uniform(60, 190, (100, 140, 3)).astype(np.float32), (0, 0), 3)
    region = np.zeros((100, 140), bool)
    region[20:80, 20:120] = True
    labels = np.zeros((100, 140), np.intp)
    labels[region] = 1
    labels[20:80, 70:120] = 2
    raw = np.stack([tex, tex, tex + step]).clip(0, 255).astype(np.uint8)
    out = raw[0].copy()
    out[labels == 2] = raw[2][labels == 2]
    return tex, raw, out, labels, region


def test_seam_steps_remove_a_step_of_light_and_keep_a_step_of_content():
    """``montage.seam_steps``: a seam where two sources differ by 20 levels of light is
    blended away (the fill then follows the texture across it), nothing outside the
    region changes, the correction fades to 0 at the region's edge; a step of 80
    levels (over ``max_step`` 50) is content and is kept as it is."""
    from dynremove.refine.montage import add_offset, seam_steps

    tex, raw, out, labels, region = _two_sources_meeting(20.0)
    corr = seam_steps(out, raw, labels, region, max_step=50.0)
    assert not corr[~region].any()
    fixed = out.copy()
    fixed[region] = add_offset(out[region], corr[region])
    truth_step = tex[20:80, 70] - tex[20:80, 69]
    before = np.abs(out[20:80, 70].astype(float) - out[20:80, 69] - truth_step).mean()
    after = np.abs(fixed[20:80, 70].astype(float) - fixed[20:80, 69] - truth_step).mean()
    assert before > 19 and after < 2, (before, after)
    # the correction is smooth: half the step each side at the seam, ~0 at the edge
    assert 7 < -corr[50, 70].mean() < 13 and 7 < corr[50, 69].mean() < 13
    assert np.abs(corr[50, [20, 119]]).max() < 2.5
    # a step of 80 levels: content, kept
    _, raw, out, labels, region = _two_sources_meeting(80.0)
    assert not seam_steps(out, raw, labels, region, max_step=50.0).any()

"""Each equation of Sec. 3 on hand-checked values: S_e, S_f, Sampson, C_s, B, M."""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.testing as npt
import pytest

from dynremove.method import geometry
from dynremove.method.scan import _kernels as kn
from dynremove.method.scan import reference as R
from dynremove.method.scan.driver import pack_params
from dynremove.params import PAPER

# F of a pure x-translation: epipolar lines are the rows, x_sᵀ F x_r = y_r − y_s
F_TX = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def test_S_e_hand_values():
    assert kn._se(0.0, 4.8) == 1.0
    assert math.isclose(kn._se(4.8 ** 2, 4.8), math.exp(-0.5))
    assert math.isclose(R.S_e(2 * 0.25 ** 2, 0.25), math.exp(-1.0))


def test_sampson_hand_values():
    # 2 px off the epipolar line: e = −2, ‖(F x_r)_12‖² + ‖(Fᵀ x_s)_12‖² = 1 + 1
    assert geometry.sampson_sq(F_TX, [10, 5], [20, 7]) == pytest.approx(2.0)
    assert geometry.sampson_sq(F_TX, [10, 5], [99, 5]) == pytest.approx(0.0)
    F = np.stack([F_TX])
    assert kn._sampson(F, 0, 10.0, 5.0, 20.0, 7.0) == pytest.approx(2.0)
    assert R.sampson_sq(F_TX, 10, 5, 20, 7) == pytest.approx(2.0)


def test_sampson_convention_x_s_F_x_r_against_opencv(rng):
    """A general (rank-2, non-symmetric) F pins x_sᵀ F x_r = 0: cv2.sampsonDistance
    (pt1, pt2, F) is (pt2ᵀ F pt1)² / (…), so pt1 = x_r and pt2 = x_s. With F
    transposed, or the points swapped, the values differ."""
    U, _, Vt = np.linalg.svd(rng.normal(size=(3, 3)))
    F = U @ np.diag([3.0, 1.0, 0.0]) @ Vt  # rank 2
    F /= F[2, 2]
    assert not np.allclose(F, F.T)
    xr = rng.uniform(0, 100, size=(40, 2))
    xs = xr + rng.normal(scale=3.0, size=(40, 2))
    want = np.array([cv2.sampsonDistance(np.r_[a, 1.0], np.r_[b, 1.0], F)
                     for a, b in zip(xr, xs)])
    swapped = np.array([cv2.sampsonDistance(np.r_[b, 1.0], np.r_[a, 1.0], F)
                        for a, b in zip(xr, xs)])
    assert not np.allclose(want, swapped, rtol=1e-3)  # the test can tell the two apart
    npt.assert_allclose(geometry.sampson_sq(F, xr, xs), want, rtol=1e-9)
    npt.assert_allclose([kn._sampson(F[None], 0, *a, *b) for a, b in zip(xr, xs)], want,
                        rtol=1e-9)
    npt.assert_allclose([R.sampson_sq(F, *a, *b) for a, b in zip(xr, xs)], want, rtol=1e-9)


def test_sampson_vectorised_matches_scalar(rng):
    F = rng.normal(size=(3, 3))
    xr = rng.uniform(0, 100, size=(50, 2))
    xs = rng.uniform(0, 100, size=(50, 2))
    vec = geometry.sampson_sq(F, xr, xs)
    one = [kn._sampson(F[None], 0, *a, *b) for a, b in zip(xr, xs)]
    npt.assert_allclose(vec, one, rtol=1e-12)


def _tiny_features():
    """Reference and one source of 3×3 pixels with hand-set features."""
    fc_r = np.zeros((3, 3, 3), np.float32)
    fg_r = np.zeros((3, 3, 128), np.uint8)
    fc_s = np.zeros((1, 3, 3, 3), np.float32)
    fg_s = np.zeros((1, 3, 3, 128), np.uint8)
    fc_r[1, 1] = (50, 0, 0)
    fc_s[0, 1, 2] = (50, 4.8, 0)  # Lab distance σ_c
    fg_r[1, 1, 0] = 10
    fg_s[0, 1, 2, 0] = 20  # SIFT distance 10 units before scaling
    return fc_r, fg_r, fc_s, fg_s


def test_C_s_equation_1():
    p = PAPER.replace(sift_scale=1.0, coord_scale_px=1.0)
    u = 0.025  # SIFT unit: distance 10 → 0.25 = σ_g
    pf, pi = pack_params(p, sift_unit=u)
    fc_r, fg_r, fc_s, fg_s = _tiny_features()
    F = np.stack([F_TX])
    hasF = np.array([True])
    # match of (1, 1) is (2, 1): on the epipolar line → S_f = 1
    got = kn._sim_H(fc_r, fg_r, 1, 1, fc_s, fg_s, 0, 2, 1, F, hasF, pf, pi)
    want = 0.15 * math.exp(-0.5) + 0.40 * math.exp(-0.5) + 0.45 * 1.0
    assert got == pytest.approx(want, rel=1e-7)  # Lab is stored as float32
    # one row off: d_s = 0.5 px² → S_f = exp(−0.5 / (2·0.17²))
    N = np.zeros((1, 3, 3, 2), np.int32)
    N[0, 1, 1] = (2, 0)
    C = kn._similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi)
    sf = math.exp(-0.5 / (2 * 0.17 ** 2))
    sc = math.exp(-(50 ** 2) / (2 * 4.8 ** 2))  # (2, 0) has Lab (0, 0, 0)
    sg = math.exp(-(10 * u) ** 2 / (2 * 0.25 ** 2))
    assert C[0, 1, 1] == pytest.approx(0.15 * sc + 0.40 * sg + 0.45 * sf, rel=1e-6)
    Cr = R.similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, p, u)  # Params by name
    assert Cr[0, 1, 1] == pytest.approx(0.15 * sc + 0.40 * sg + 0.45 * sf, rel=1e-6)
    # a match outside the source gets C = 0
    N[0, 0, 0] = (-1, 0)
    assert kn._similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi)[0, 0, 0] == 0.0


@pytest.mark.parametrize("use_epipolar, hasF", [(False, True), (True, False)])
def test_C_s_without_epipolar_keeps_total_weight(use_epipolar, hasF):
    """Epipolar term off, or no F for the source: λ1 and λ2 are scaled by
    (λ1+λ2+λ3)/(λ1+λ2), so a perfect match still scores λ1+λ2+λ3 = 1."""
    p = PAPER.replace(use_epipolar=use_epipolar)
    u = 0.025
    pf, pi = pack_params(p, sift_unit=u)
    fc_r, fg_r, fc_s, fg_s = _tiny_features()
    F = np.stack([F_TX])
    hasF = np.array([hasF])
    # a perfect match, 2 rows off its epipolar line (S_f ≈ 0 if it were used)
    fc_s[0, 2, 1] = fc_r[1, 1]
    fg_s[0, 2, 1] = fg_r[1, 1]
    N = np.zeros((1, 3, 3, 2), np.int32)
    N[0, 1, 1] = (1, 2)
    got = kn._similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi)[0, 1, 1]
    assert got == pytest.approx(1.0)
    assert R.similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, p, u)[0, 1, 1] == \
        pytest.approx(1.0)
    # colour σ_c away: (λ1 e^-½ + λ2)·(λ1+λ2+λ3)/(λ1+λ2)
    fc_s[0, 2, 1] = (50, 4.8, 0)
    want = (0.15 * math.exp(-0.5) + 0.40) * 1.0 / 0.55
    got = kn._similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi)[0, 1, 1]
    assert got == pytest.approx(want, rel=1e-6)
    assert R.similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, p, u)[0, 1, 1] == \
        pytest.approx(want, rel=1e-6)


def test_B_and_M_on_a_hand_made_pixel():
    """Three candidates: two agree (one cluster), one is far (noise / own cluster)."""
    p = PAPER.replace(dbscan_eps=0.5, dbscan_min_pts=1, sift_scale=1.0)
    u = 0.025
    ctx = R._Ctx(p, u, np.zeros((1, 3, 3)), np.array([False]))
    fc_s = np.zeros((1, 1, 3, 3), np.float32)
    fg_s = np.zeros((1, 1, 3, 128), np.uint8)
    fc_s[0, 0, 0] = (40, 0, 0)
    fc_s[0, 0, 1] = (40, 4.8, 0)
    fc_s[0, 0, 2] = (90, 40, 40)
    fg_s[0, 0, 2, :] = 200
    P = [(0, 0, 0, 0.6, 0), (0, 1, 0, 0.2, 1), (0, 2, 0, 0.9, 2)]
    labels = R.cluster(P, fc_s, fg_s, ctx)
    lam4, lam5 = 0.15 / 0.55, 0.40 / 0.55
    B01 = 1 - lam4 * math.exp(-0.5) - lam5 * 1.0  # 0.1072 ≤ ε → one cluster
    assert B01 < 0.5
    assert labels[0] == labels[1] != labels[2]
    # b_k: {0.6 + 0.2, 0.9} → the far candidate wins on summed confidence
    fc_r = np.zeros((1, 3, 3), np.float32)
    fg_r = np.zeros((1, 3, 128), np.uint8)
    fc_r[0, 0] = (90, 40, 40)
    fg_r[0, 0, :] = 200
    m, bm, fhat_c, fhat_g, M, _ = R.decide(P, labels, fc_r, fg_r, fc_s, fg_s, 0, 0, ctx)
    assert m == labels[2] and bm == pytest.approx(0.9)
    assert M == pytest.approx(lam4 + lam5)  # identical features → M = 1
    # same pixel with the near candidates' weights raised: consensus = weighted mean
    P2 = [(0, 0, 0, 0.6, 0), (0, 1, 0, 0.6, 1), (0, 2, 0, 0.9, 2)]
    m, bm, fhat_c, _, M, _ = R.decide(P2, labels, fc_r, fg_r, fc_s, fg_s, 0, 0, ctx)
    npt.assert_allclose(fhat_c, [40, 2.4, 0])
    dc = (90 - 40) ** 2 + (40 - 2.4) ** 2 + 40 ** 2
    dg = 128 * (200 * u) ** 2
    want = lam4 * math.exp(-dc / (2 * 4.8 ** 2)) + lam5 * math.exp(-dg / (2 * 0.25 ** 2))
    assert M == pytest.approx(want)


def test_hog_is_rotation_invariant():
    nb = 8
    h = np.zeros(nb)
    h[3], h[4] = 2.0, 1.0
    g = np.zeros(nb)
    g[6], g[7] = 2.0, 1.0
    kn._hog_finish(h, nb, 1.0)
    kn._hog_finish(g, nb, 1.0)
    npt.assert_allclose(h, g)
    assert h[0] == pytest.approx(2 / math.sqrt(5))


def test_sampson_compiled_equals_its_numpy_form(rng):
    """``geometry.sampson_sq`` (compiled) against the formula written in NumPy, bit for
    bit, on a float32 grid of (H, W, 2) pairs as the fill passes them, and broadcast."""
    F = rng.normal(size=(3, 3))
    xr = rng.uniform(-10, 900, size=(30, 40, 2)).astype(np.float32)
    xs = (xr + rng.normal(scale=4.0, size=xr.shape)).astype(np.float32)
    r, s = xr.astype(np.float64), xs.astype(np.float64)
    a = F[0, 0] * r[..., 0] + F[0, 1] * r[..., 1] + F[0, 2]
    b = F[1, 0] * r[..., 0] + F[1, 1] * r[..., 1] + F[1, 2]
    c = F[2, 0] * r[..., 0] + F[2, 1] * r[..., 1] + F[2, 2]
    ta = F[0, 0] * s[..., 0] + F[1, 0] * s[..., 1] + F[2, 0]
    tb = F[0, 1] * s[..., 0] + F[1, 1] * s[..., 1] + F[2, 1]
    e = s[..., 0] * a + s[..., 1] * b + c
    want = e * e / np.maximum(a * a + b * b + ta * ta + tb * tb, 1e-300)
    npt.assert_array_equal(geometry.sampson_sq(F, xr, xs), want)
    one = np.repeat(np.repeat(xr[:1, :1], 30, 0), 40, 1)  # one point against every x_s
    npt.assert_array_equal(geometry.sampson_sq(F, xr[0, 0], xs),
                           geometry.sampson_sq(F, one, xs))
    assert geometry.sampson_sq(F, xr, xs).shape == (30, 40)

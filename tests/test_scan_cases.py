"""The removal and update steps of Sec. 3.2 on hand-computed values.

Tiny 7×7 images with constant colours (so the HoG of every overlap is zero and
its S_e is 1) and hand-set features; F_TX is a pure x-translation, so the
epipolar lines are the rows and d_s(x_r, x_s) = (y_s − y_r)² / 2. Each test
runs the compiled kernel (parameters packed by ``pack_params``) and the
reference (parameters by name) against the same hand values.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynremove.method.scan import _kernels as kn
from dynremove.method.scan import reference as R
from dynremove.method.scan.driver import ScanInputs, _Buffers, pack_params
from dynremove.params import PAPER

F_TX = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
U = 0.025  # SIFT unit
P3 = PAPER.replace(patch_size=3, coord_scale_px=1.0)
L1, L2, L3 = P3.lambda1, P3.lambda2, P3.lambda3
L6, L7, L8 = P3.lambda6, P3.lambda7, P3.lambda8
SIG_C, SIG_E = P3.sigma_c, P3.sigma_e
X, Y = 3, 3  # x_r; scan top-left → bottom-right: neighbours (2, 3) and (3, 2)
NBR = (-1, 0, 0, -1)


def S_f_rows(dy: float) -> float:
    """S_f under F_TX for a match dy rows off x_r (coord unit 1 px)."""
    return math.exp(-(dy * dy / 2.0) / (2 * SIG_E ** 2))


def _images(S, src_lab_vals):
    lab = np.zeros((7, 7, 3), np.float32)
    lab[:] = (50, 0, 0)
    gray = np.full((7, 7), 100, np.float32)
    src_lab = np.zeros((S, 7, 7, 3), np.float32)
    for s, v in enumerate(src_lab_vals):
        src_lab[s] = v
    src_gray = np.full((S, 7, 7), 100, np.float32)
    return lab, gray, src_lab, src_gray


def _arrays(P, labels):
    cs = np.array([p[0] for p in P], np.int64)
    cx = np.array([p[1] for p in P], np.int64)
    cy = np.array([p[2] for p in P], np.int64)
    return cs, cx, cy, np.asarray(labels, np.int64)


def _choose_both(P, labels, m, params, F, hasF, src_lab_vals, fc_s, fg_s, fhat_c, fhat_g):
    """(index, best score, n tied) from the kernel and from the reference."""
    S = len(src_lab_vals)
    lab, gray, src_lab, src_gray = _images(S, src_lab_vals)
    pf, pi = pack_params(params, sift_unit=U)
    cs, cx, cy, lab_ = _arrays(P, labels)
    K = len(P)
    nb = params.hog_bins
    hb_s, hm_s = (np.stack(a) for a in zip(*(kn._gradient_bins(g, nb) for g in src_gray)))
    got_k = kn._choose_patch(lab, *kn._gradient_bins(gray, nb), src_lab, hb_s, hm_s, fc_s, fg_s,
                             F, hasF, pf, pi, X, Y,
                             *NBR, K, cs, cx, cy, lab_, m, fhat_c, fhat_g, np.empty(K),
                             np.empty(3), np.empty(3), np.empty(nb), np.empty(nb))
    ctx = R._Ctx(params, U, F, hasF)
    got_r = R.choose_patch([(*p, 0.5, 0) for p in P], lab_, m, fhat_c, fhat_g,
                           (None, lab, gray, src_lab, src_gray, fc_s, fg_s), X, Y, 1, ctx)
    return got_k, got_r


def _features(S):
    fc_s = np.zeros((S, 7, 7, 3), np.float32)
    fg_s = np.zeros((S, 7, 7, 128), np.uint8)
    return fc_s, fg_s


# sources: 0 and 1 with F (1's colour is σ_c away in a*), 2 without F
SRC_LAB = [(50, 0, 0), (50, SIG_C, 0), (50, 0, 0)]
F3 = np.stack([F_TX, F_TX, np.zeros((3, 3))])
HASF3 = np.array([True, True, False])


@pytest.mark.parametrize("cand, want", [
    ((0, 5, 3), 2 * (L6 + L7) + L8),  # same colour, on the epipolar line
    ((1, 5, 3), 2 * (L6 * math.exp(-0.5) + L7) + L8),  # colour σ_c away: Lab term e^-½
    ((0, 5, 5), 2 * (L6 + L7) + L8 * S_f_rows(2)),  # 2 rows off the line
    ((2, 4, 4), 2 * (L6 + L7) + L8),  # no F: overlap terms × (2(λ6+λ7)+λ8)/(2(λ6+λ7))
])
def test_q_star_score_hand_values(cand, want):
    fc_s, fg_s = _features(3)
    (ik, sk, nk), (ir, sr, nr) = _choose_both([cand], [0], 0, P3, F3, HASF3, SRC_LAB,
                                              fc_s, fg_s, np.zeros(3), np.zeros(128))
    assert (ik, nk) == (ir, nr) == (0, 1)
    assert sk == pytest.approx(want, rel=1e-7)
    assert sr == pytest.approx(want, rel=1e-7)


def test_q_star_picks_the_best_and_drops_lambda8_without_epipolar():
    fc_s, fg_s = _features(3)
    P = [(1, 5, 3), (0, 5, 5), (0, 5, 3)]
    for (i, best, n) in _choose_both(P, [0, 0, 0], 0, P3, F3, HASF3, SRC_LAB, fc_s, fg_s,
                                     np.zeros(3), np.zeros(128)):
        assert (i, n) == (2, 1)
        assert best == pytest.approx(2 * (L6 + L7) + L8)
    # epipolar term off: every candidate's overlap terms are rescaled alike, so the
    # on-line and the off-line patch of source 0 tie (λ8 no longer separates them)
    p = P3.replace(use_epipolar=False)
    for (i, best, n) in _choose_both(P, [0, 0, 0], 0, p, F3, HASF3, SRC_LAB, fc_s, fg_s,
                                     np.zeros(3), np.zeros(128)):
        assert n == 2 and i in (1, 2)
        assert best == pytest.approx(2 * (L6 + L7) + L8)


@pytest.mark.parametrize("closer, want", [(0, 0), (1, 1)])
def test_tie_break_goes_to_the_consensus(closer, want):
    """Source 0 on its line (S_f = 1) and source 2 without F (rescaled) tie at
    2(λ6+λ7)+λ8; q̂ is the one whose features are nearest to (f̂_c, f̂_g)."""
    fc_s, fg_s = _features(3)
    P = [(0, 5, 3), (2, 4, 4)]
    fc_s[0, 3, 5] = (50, 0, 0)
    fc_s[2, 4, 4] = (60, 0, 0)
    fhat_c = np.array([50.0, 0, 0]) if closer == 0 else np.array([59.0, 0, 0])
    for (i, best, n) in _choose_both(P, [0, 0], 0, P3, F3, HASF3, SRC_LAB, fc_s, fg_s,
                                     fhat_c, np.zeros(128)):
        assert n == 2
        assert i == want
        assert best == pytest.approx(2 * (L6 + L7) + L8)


def test_q_star_ignores_candidates_outside_A_m():
    fc_s, fg_s = _features(3)
    P = [(0, 5, 3), (1, 5, 3)]  # the better patch is in cluster 1, not A_m = 0
    for (i, best, n) in _choose_both(P, [1, 0], 0, P3, F3, HASF3, SRC_LAB, fc_s, fg_s,
                                     np.zeros(3), np.zeros(128)):
        assert (i, n) == (1, 1)
        assert best == pytest.approx(2 * (L6 * math.exp(-0.5) + L7) + L8)


# ---- update of N and C: the three cases -----------------------------------------------


def _update_scene():
    """4 sources; x_r = (3, 3) with f_c = (50, 0, 0), f_g = e_0·10.

    s0 (F): both candidates in A_m (case 2): (4, 3) on the line, colour σ_c off;
        (4, 4) one row off, same features.
    s1 (F): one candidate in A_m (case 1): (2, 3), same features.
    s2 (F): none in A_m (case 3): candidates (1, 5), (1, 1) are 2 rows off; the
        left neighbour's own match (0, 3) is on the line and wins.
    s3 (no F): none in A_m (case 3 without geometry): the first of X, (6, 0).
    """
    S = 4
    fc_r = np.zeros((7, 7, 3), np.float32)
    fg_r = np.zeros((7, 7, 128), np.uint8)
    fc_r[Y, X] = (50, 0, 0)
    fg_r[Y, X, 0] = 10
    fc_s, fg_s = _features(S)
    same = [(0, 4, 4), (1, 2, 3), (2, 0, 3)]
    for s, x, y in same:
        fc_s[s, y, x] = (50, 0, 0)
        fg_s[s, y, x, 0] = 10
    fc_s[0, 3, 4] = (50, SIG_C, 0)
    fg_s[0, 3, 4, 0] = 10
    fc_s[3, 0, 6] = (50, SIG_C, 0)
    fg_s[3, 0, 6, 0] = 10
    N = np.full((S, 7, 7, 2), 3, np.int32)
    N[2, 3, 2] = (0, 3)  # the left neighbour's own match in s2
    N[3, 3, 2] = (6, 6)
    C = np.zeros((S, 7, 7), np.float32)
    F = np.stack([F_TX, F_TX, F_TX, np.zeros((3, 3))])
    hasF = np.array([True, True, True, False])
    P = [(0, 4, 3), (0, 4, 4), (1, 2, 3), (1, 5, 5), (2, 1, 5), (2, 1, 1), (3, 6, 0), (3, 6, 6)]
    labels = [0, 0, 0, 1, 1, 1, -1, 1]
    return fc_r, fg_r, fc_s, fg_s, N, C, F, hasF, P, labels


H_SIGMA_C_OFF = L1 * math.exp(-0.5) + L2  # H's appearance part, colour σ_c off
WANT_UPDATES = [
    (0, 2, 4, 3, H_SIGMA_C_OFF + L3),  # beats (4, 4): L1 + L2 + L3·S_f(1 row)
    (1, 1, 2, 3, L1 + L2 + L3),
    (2, 3, 0, 3, L1 + L2 + L3),
    (3, 3, 6, 0, H_SIGMA_C_OFF * (L1 + L2 + L3) / (L1 + L2)),  # no F: λ3 rescaled
]


def test_three_update_cases_hand_values():
    assert H_SIGMA_C_OFF + L3 > L1 + L2 + L3 * S_f_rows(1)  # case 2 is decided by H
    # kernel
    fc_r, fg_r, fc_s, fg_s, N, C, F, hasF, P, labels = _update_scene()
    pf, pi = pack_params(P3, sift_unit=U)
    cs, cx, cy, lab_ = _arrays(P, labels)
    upd_i = np.zeros((8, kn.N_UI), np.int64)
    upd_f = np.zeros(8, np.float32)
    counts = np.zeros(3, np.int64)
    kn._update_correspondences(N, C, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi, X, Y, len(P),
                               cs, cx, cy, lab_, 0, np.array([2, 3]), np.array([3, 2]), 2,
                               0, 0, True, upd_i, upd_f, counts)
    assert counts[2] == 4
    for e, (s, case, nx, ny, h) in enumerate(WANT_UPDATES):
        assert tuple(upd_i[e, [kn.U_SRC, kn.U_CASE, kn.U_NX, kn.U_NY]]) == (s, case, nx, ny)
        assert tuple(N[s, Y, X]) == (nx, ny)
        assert C[s, Y, X] == pytest.approx(h, rel=1e-6)
    # reference
    fc_r, fg_r, fc_s, fg_s, N, C, F, hasF, P, labels = _update_scene()
    ctx = R._Ctx(P3, U, F, hasF)
    nbrs = [(2, 3, 1, 0), (3, 2, 0, 1)]
    out = R.update_correspondences([(*p, 0.5, 0) for p in P], np.array(labels), 0, nbrs, N, C,
                                   fc_r, fg_r, fc_s, fg_s, X, Y, ctx)
    assert [o[:4] for o in out] == [w[:4] for w in WANT_UPDATES]
    for o, w in zip(out, WANT_UPDATES):
        assert o[4] == pytest.approx(w[4], rel=1e-6)


# ---- the candidate set P ---------------------------------------------------------------


def test_candidates_as_set_and_multiset():
    """Left (2, 3) → (4, 3) and up (3, 2) → (5, 2) both propagate to (5, 3)."""
    N = np.zeros((2, 7, 7, 2), np.int32)
    C = np.zeros((2, 7, 7), np.float32)
    N[:, 3, 2] = (4, 3)
    N[:, 2, 3] = (5, 2)
    N[1, 2, 3] = (0, 0)  # source 1: distinct candidates (5, 3) and (0, 1)
    C[:, 3, 2] = 0.7
    C[:, 2, 3] = 0.4
    want = {True: [(0, 5, 3, 0.7, 0), (1, 5, 3, 0.7, 2), (1, 0, 1, 0.4, 3)],
            False: [(0, 5, 3, 0.7, 0), (0, 5, 3, 0.4, 1), (1, 5, 3, 0.7, 2), (1, 0, 1, 0.4, 3)]}
    for as_set in (True, False):
        P, _ = R.candidates(N, C, X, Y, 1, 7, 7, as_set=as_set)
        assert [(s, x, y, pytest.approx(b), a) for s, x, y, b, a in P] == want[as_set]
        bufs = [np.empty(4, np.int64) for _ in range(3)]
        cB, slot = np.empty(4), np.empty(4, np.int64)
        nb = [np.empty(2, np.int64) for _ in range(4)]
        n, nn = kn._candidates(N, C, X, Y, *NBR, as_set, *bufs, cB, slot, *nb)
        assert nn == 2 and n == len(want[as_set])
        got = [(int(bufs[0][i]), int(bufs[1][i]), int(bufs[2][i]), float(cB[i]), int(slot[i]))
               for i in range(n)]
        assert [(s, x, y, pytest.approx(b), a) for s, x, y, b, a in got] == want[as_set]


def test_a_repeated_candidate_doubles_its_weight_only_in_the_multiset():
    """b_k of the cluster holding (5, 3): 0.7 as a set, 0.7 + 0.4 as a multiset."""
    N = np.zeros((1, 7, 7, 2), np.int32)
    C = np.zeros((1, 7, 7), np.float32)
    N[0, 3, 2] = (4, 3)
    N[0, 2, 3] = (5, 2)
    C[0, 3, 2], C[0, 2, 3] = 0.7, 0.4
    fc_r = np.zeros((7, 7, 3), np.float32)
    fg_r = np.zeros((7, 7, 128), np.uint8)
    fc_s, fg_s = _features(1)
    for as_set, want in ((True, 0.7), (False, 1.1)):
        p = PAPER.replace(candidate_set=as_set, dbscan_min_pts=1)
        ctx = R._Ctx(p, U, np.zeros((1, 3, 3)), np.array([False]))
        P, _ = R.candidates(N, C, X, Y, 1, 7, 7, as_set=p.candidate_set)
        labels = R.cluster(P, fc_s, fg_s, ctx)
        _, bm, *_ = R.decide(P, labels, fc_r, fg_r, fc_s, fg_s, X, Y, ctx)
        assert bm == pytest.approx(want, rel=1e-6)


# ---- event buffers ---------------------------------------------------------------------


def test_event_buffer_overflow_is_detected():
    """The kernel keeps counting past capacity, writes nothing past it, and
    ``take`` raises instead of returning a truncated batch."""
    rng = np.random.default_rng(0)
    H, W, S = 6, 8, 2
    img = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    st = ScanInputs(
        img=img, lab=rng.uniform(0, 100, (H, W, 3)).astype(np.float32),
        gray=rng.uniform(0, 255, (H, W)).astype(np.float32),
        fc_r=np.full((H, W, 3), 100, np.float32), fg_r=np.full((H, W, 128), 200, np.uint8),
        src_img=rng.integers(0, 255, (S, H, W, 3), dtype=np.uint8),
        src_lab=rng.uniform(0, 100, (S, H, W, 3)).astype(np.float32),
        src_gray=rng.uniform(0, 255, (S, H, W)).astype(np.float32),
        fc_s=np.zeros((S, H, W, 3), np.float32), fg_s=np.zeros((S, H, W, 128), np.uint8),
        N=np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1)[None].repeat(S, 0)
        .astype(np.int32),
        C=np.ones((S, H, W), np.float32), F=np.zeros((S, 3, 3)), hasF=np.zeros(S, bool),
        sift_unit=U)
    pf, pi = pack_params(PAPER, sift_unit=U)
    bufs = _Buffers(1, 2, S, True)  # room for 2 decisions; every pixel is dynamic
    sentinel = bufs.dec_i.copy()
    stats = np.zeros((1, 3), np.int64)
    L = np.zeros((H, W), np.uint8)
    kn._scan(st.img, st.lab, st.gray, st.fc_r, st.fg_r, st.src_img, st.src_lab,
             st.src_gray, st.fc_s, st.fg_s, st.N, st.C, st.F, st.hasF, L,
             np.zeros((H, W), np.float32), np.zeros((H, W, 4), np.int32),
             np.zeros((H, W), np.float32), np.zeros((H, W), bool),
             *kn._gradient_bins(st.gray, 8),
             *(a[None].repeat(S, 0) for a in kn._gradient_bins(st.src_gray[0], 8)),
             False, np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1, 4), np.int32),
             np.zeros((H, W), np.uint8), pf, pi, 0, 1, 0, H,
             True, False, *bufs.args(), stats)
    stats = stats[0]
    assert stats[0] == H * W
    assert bufs.counts[0] == H * W and bufs.counts[1] == H * W and bufs.counts[2] == H * W * S
    assert not np.array_equal(bufs.dec_i, sentinel)  # the first events were written
    with pytest.raises(RuntimeError, match="overflow"):
        bufs.take(0, (0, H - 1), (0, H * W))

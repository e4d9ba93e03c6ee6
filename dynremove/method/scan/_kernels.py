"""Compiled kernels of the scan (Sec. 3.2, Algorithm 1). @njit only.

No I/O, no logging, no globals. Parameters come packed in two arrays (``pf``
floats, ``pi`` ints; indices below) built by ``driver.pack_params``. Events are
written into preallocated struct-of-arrays buffers with counters that keep
counting past capacity, so overflow is detectable (the driver sizes buffers
for the worst case of a chunk, so it does not happen).

One function per step of the paper, named like the readable reference
(``reference.py``), which reads ``Params`` by name instead of ``pf``/``pi``:

==============================  =====================================
kernel                          reference
==============================  =====================================
``_sim_H``, ``_similarity_map``  ``_Ctx.H``, ``similarity_map`` (Eq. 1, H)
``_candidates``                 ``candidates`` (P, B; Sec. 3.2.1)
``_cluster``, ``_dbscan``       ``cluster`` (𝓑, Eq. DB_cost)
``_decide``, ``_consensus_g``   ``decide`` (b_k, f̂, M; Eq. decision)
``_choose_patch``               ``choose_patch`` (q*, q̂; Sec. 3.2.2)
``_write_patch``                ``write_patch``
``_update_correspondences``     ``update_correspondences`` (Sec. 3.2.3)
``_scan``                       ``scan_rows`` (Algorithm 1; also on all cores)
==============================  =====================================

Shapes: reference (H, W); S sources of the same size; K = 2·S candidate slots.
Points are (x, y); arrays are indexed [y, x].
"""

import math

import numba
import numpy as np

from dynremove.method.scan._atomics import cpu_yield, fetch_add, load_acquire, store_release

# --- indices into pf (float64) ------------------------------------------------
LAM1, LAM2, LAM3, LAM4, LAM5, LAM6, LAM7, LAM8 = 0, 1, 2, 3, 4, 5, 6, 7
SIG_C, SIG_G, SIG_E, SIG_H, T_R, EPS, SIFT_UNIT = 8, 9, 10, 11, 12, 13, 14
HOG_SCALE, COORD_SCALE, TIE_TOL, SAMPLE_RATE = 15, 16, 17, 18
N_PF = 19
# --- indices into pi (int64) ----------------------------------------------------
P, MIN_PTS, HOG_BINS, WRITE_PATCH, UPDATE, USE_EPI, USE_HOG, CAND_SET = range(8)
N_PI = 8

# columns of the integer event buffers
D_SCAN, D_STEP, D_X, D_Y, D_WHY, D_NCAND, D_WIN, D_NCL, D_CHOSEN, D_DYN = range(10)
N_DI = 10
R_SCAN, R_STEP, R_X, R_Y, R_SRC, R_SX, R_SY, R_TIE, R_NP = range(9)
N_RI = 9
U_SCAN, U_STEP, U_X, U_Y, U_SRC, U_CASE, U_NX, U_NY = range(8)
N_UI = 8


@numba.njit(cache=True, nogil=True, inline="always")
def _se(d2, sigma):
    """S_e = exp(−‖·‖² / 2σ²) given the squared distance."""
    return math.exp(-d2 / (2.0 * sigma * sigma))


@numba.njit(cache=True, nogil=True)
def _sampson(F, s, xr, yr, xs, ys):
    """Squared Sampson distance (px²) of x_r ↔ x_s under F[s] (x_sᵀ F x_r = 0)."""
    a = F[s, 0, 0] * xr + F[s, 0, 1] * yr + F[s, 0, 2]
    b = F[s, 1, 0] * xr + F[s, 1, 1] * yr + F[s, 1, 2]
    c = F[s, 2, 0] * xr + F[s, 2, 1] * yr + F[s, 2, 2]
    ta = F[s, 0, 0] * xs + F[s, 1, 0] * ys + F[s, 2, 0]
    tb = F[s, 0, 1] * xs + F[s, 1, 1] * ys + F[s, 2, 1]
    e = xs * a + ys * b + c
    den = a * a + b * b + ta * ta + tb * tb
    if den < 1e-300:
        den = 1e-300
    return e * e / den


@numba.njit(cache=True, nogil=True)
def _sf(F, hasF, s, xr, yr, xs, ys, pf):
    """S_f = exp(−d_s / 2σ_e²), d_s in coordinate units (px / coord_scale)²."""
    if not hasF[s]:
        return 0.0
    cs = pf[COORD_SCALE]
    d = _sampson(F, s, xr, yr, xs, ys) / (cs * cs)
    return math.exp(-d / (2.0 * pf[SIG_E] * pf[SIG_E]))


# The distances of the decision read the descriptors in place, by index, and the
# decision's steps are inlined into its callers (``inline="always"``). A slice
# such as fg_s[s, y, x] is a new array that numba reference-counts, and so is
# every array passed to a function that is not inlined: an atomic increment and
# decrement each, on counters that both cores share. In the decision, made for
# every pixel of a scan, they took about a quarter of its time (``perf``; the
# default's scan at 7 × 854×480: 0.47-0.52 -> 0.36-0.38 s on two cores, the
# same bytes). The indices are cast to uint64, which spares numba's test for a
# negative index, so the loop over a descriptor vectorises (pmaddwd) as it did
# through a slice.


@numba.njit(cache=True, nogil=True, inline="always")
def _lab_d2_rs(fc_r, y, x, fc_s, s, ys, xs):
    """‖fc_r[y, x] − fc_s[s, ys, xs]‖² in float64 (the reference's f_c (H, W, 3)
    against source s's (S, H, W, 3), float32)."""
    d = 0.0
    for c in range(3):
        t = np.float64(fc_r[y, x, c]) - np.float64(fc_s[s, ys, xs, c])
        d += t * t
    return d


@numba.njit(cache=True, nogil=True, inline="always")
def _lab_d2_ss(fc_s, s1, y1, x1, s2, y2, x2):
    """‖fc_s[s1, y1, x1] − fc_s[s2, y2, x2]‖² in float64 (two sources' f_c)."""
    d = 0.0
    for c in range(3):
        t = np.float64(fc_s[s1, y1, x1, c]) - np.float64(fc_s[s2, y2, x2, c])
        d += t * t
    return d


@numba.njit(cache=True, nogil=True, inline="always")
def _sift_d2_rs(fg_r, y, x, fg_s, s, ys, xs):
    """Squared distance of the reference's descriptor fg_r[y, x] ((H, W, G) uint8)
    and source s's fg_s[s, ys, xs] ((S, H, W, G) uint8) as an exact integer.

    Every step is cast back to int32 (numba would widen int32 arithmetic to
    int64), so the loop compiles to 16-bit differences and pmaddwd; exact, since
    128 · 255² < 2³¹.
    """
    yr, xr = np.uint64(y), np.uint64(x)
    su, yu, xu = np.uint64(s), np.uint64(ys), np.uint64(xs)
    d = np.int32(0)
    for k in range(np.uint64(fg_r.shape[2])):
        t = np.int32(fg_r[yr, xr, k]) - np.int32(fg_s[su, yu, xu, k])
        d = np.int32(d + np.int32(t * t))
    return np.int64(d)


@numba.njit(cache=True, nogil=True, inline="always")
def _sift_d2_ss(fg_s, s1, y1, x1, s2, y2, x2):
    """``_sift_d2_rs`` of two sources' descriptors fg_s[s1, y1, x1], fg_s[s2, y2, x2]."""
    a1, b1, c1 = np.uint64(s1), np.uint64(y1), np.uint64(x1)
    a2, b2, c2 = np.uint64(s2), np.uint64(y2), np.uint64(x2)
    d = np.int32(0)
    for k in range(np.uint64(fg_s.shape[3])):
        t = np.int32(fg_s[a1, b1, c1, k]) - np.int32(fg_s[a2, b2, c2, k])
        d = np.int32(d + np.int32(t * t))
    return np.int64(d)


@numba.njit(cache=True, nogil=True, inline="always")
def _sim_H(fc_r, fg_r, x, y, fc_s, fg_s, s, xs, ys, F, hasF, pf, pi):
    """H(x_r, x, F_s) of Sec. 3.2.3 (= C_s of Eq. 1 at the match).

    Without the epipolar term (switched off, or no F for this source) the two
    appearance terms are rescaled to the same total weight λ1+λ2+λ3.
    """
    lam1, lam2, lam3 = pf[LAM1], pf[LAM2], pf[LAM3]
    u = pf[SIFT_UNIT]
    sc = _se(_lab_d2_rs(fc_r, y, x, fc_s, s, ys, xs), pf[SIG_C])
    sg = _se(float(_sift_d2_rs(fg_r, y, x, fg_s, s, ys, xs)) * u * u, pf[SIG_G])
    if pi[USE_EPI] != 0 and hasF[s]:
        return lam1 * sc + lam2 * sg + lam3 * _sf(F, hasF, s, x, y, xs, ys, pf)
    return (lam1 * sc + lam2 * sg) * (lam1 + lam2 + lam3) / (lam1 + lam2)


@numba.njit(cache=True, nogil=True, parallel=True)
def _similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi):
    """C_s (Eq. 1) for every pixel and source. N (S, H, W, 2) int32 → (S, H, W) float32.

    Matches outside the source get C = 0.
    """
    S, H, W = N.shape[0], N.shape[1], N.shape[2]
    C = np.zeros((S, H, W), np.float32)
    for y in numba.prange(H):
        for s in range(S):
            for x in range(W):
                xs = N[s, y, x, 0]
                ys = N[s, y, x, 1]
                if 0 <= xs < W and 0 <= ys < H:
                    C[s, y, x] = _sim_H(fc_r, fg_r, x, y, fc_s, fg_s, s, xs, ys, F, hasF, pf, pi)
    return C


@numba.njit(cache=True, nogil=True, parallel=True)
def _appearance_support(N, fc_r, fg_r, fc_s, fg_s, pf):
    """Number of sources whose match agrees with the reference's features.

    Agreement is the decision test of Eq. (M) applied to a single match:
    λ4 S_e(f_c) + λ5 S_e(f_g) > t_r. Returns (H, W) uint8.
    """
    S, H, W = N.shape[0], N.shape[1], N.shape[2]
    out = np.zeros((H, W), np.uint8)
    u = pf[SIFT_UNIT]
    for y in numba.prange(H):
        for x in range(W):
            n = 0
            for s in range(S):
                xs = N[s, y, x, 0]
                ys = N[s, y, x, 1]
                if 0 <= xs < W and 0 <= ys < H:
                    m = pf[LAM4] * _se(_lab_d2_rs(fc_r, y, x, fc_s, s, ys, xs), pf[SIG_C]) + \
                        pf[LAM5] * _se(float(_sift_d2_rs(fg_r, y, x, fg_s, s, ys, xs)) * u * u,
                                       pf[SIG_G])
                    if m > pf[T_R]:
                        n += 1
            out[y, x] = n
    return out


@numba.njit(cache=True, nogil=True)
def _dbscan(D, n, eps, min_pts, labels, is_core, stack):
    """DBSCAN on the precomputed (n, n) distance D, exactly as scikit-learn does.

    Neighbourhoods are ``D[i, j] <= eps`` (the point itself included); the
    clustering is ``_dbscan_adj`` on that graph. Writes labels (−1 = noise) and
    returns the cluster count.
    """
    A = np.empty((n, n), np.bool_)
    for i in range(n):
        for j in range(n):
            A[i, j] = D[i, j] <= eps
    return _dbscan_adj(A, n, min_pts, labels, is_core, stack)


@numba.njit(cache=True, nogil=True, inline="always")
def _dbscan_adj(A, n, min_pts, labels, is_core, stack):
    """DBSCAN on the ε-neighbour graph A (n, n) bool, exactly as scikit-learn does.

    Neighbourhoods are the rows of A (the point itself included) in index
    order; core points have at least ``min_pts`` neighbours; clusters grow by a
    depth-first search from each unlabelled core point in index order (a stack,
    neighbours pushed in index order), so border points join the first cluster
    that pops them. Writes labels (−1 = noise) and returns the cluster count.
    """
    for i in range(n):
        labels[i] = -1
        c = 0
        for j in range(n):
            if A[i, j]:
                c += 1
        is_core[i] = c >= min_pts
    k = 0
    for i0 in range(n):
        if labels[i0] != -1 or not is_core[i0]:
            continue
        top = 0
        i = i0
        while True:
            if labels[i] == -1:
                labels[i] = k
                if is_core[i]:
                    for v in range(n):
                        if A[i, v] and labels[v] == -1:
                            stack[top] = v
                            top += 1
            if top == 0:
                break
            top -= 1
            i = stack[top]
        k += 1
    return k


@numba.njit(cache=True, nogil=True)
def _region_sum(lab, hb, hm, x0, y0, x1, y1, H1, W1, ulo, uhi, vlo, vhi, nb, gc, gh):
    """Σ Lab and the HoG histogram (Σ magnitude per bin) of one image over an overlap region.

    The region is the window offsets u ∈ [ulo, uhi], v ∈ [vlo, vhi] around (x0, y0)
    in this image (lab (H, W, 3) float32, its gradient bins hb, hm of
    ``_gradient_bins``); an offset is skipped where (x0 + u, y0 + v) falls
    outside this image or (x1 + u, y1 + v) outside the other one's (H1, W1), so
    both images of a region sum the same pixels. Sums in row-major offset order
    into gc (3,) and gh (nb,) float64 (zeroed here); returns the pixel count.
    """
    H0, W0 = hb.shape
    # the Lab sums in locals: gc could alias lab for all the compiler knows, so
    # as array elements they would be stored and reloaded at every pixel
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    for b in range(nb):
        gh[b] = 0.0
    cnt = 0
    for v in range(vlo, vhi + 1):
        ya = y0 + v
        yb = y1 + v
        if ya < 0 or ya >= H0 or yb < 0 or yb >= H1:
            continue
        for u in range(ulo, uhi + 1):
            xa = x0 + u
            xb = x1 + u
            if xa < 0 or xa >= W0 or xb < 0 or xb >= W1:
                continue
            cnt += 1
            c0 += lab[ya, xa, 0]
            c1 += lab[ya, xa, 1]
            c2 += lab[ya, xa, 2]
            if hb[ya, xa] >= 0:
                gh[hb[ya, xa]] += hm[ya, xa]
    gc[0] = c0
    gc[1] = c1
    gc[2] = c2
    return cnt


@numba.njit(cache=True, nogil=True)
def _region_mean(gc, gh, cnt, nb, hog_scale):
    """g_c = Σ Lab / count and g_h = ``_hog_finish`` of a ``_region_sum`` (cnt > 0)."""
    for c in range(3):
        gc[c] /= cnt
    _hog_finish(gh, nb, hog_scale)


@numba.njit(cache=True, nogil=True)
def _region_stats(lab, hb, hm, x0, y0, lab2, hb2, hm2, x1, y1, ulo, uhi, vlo, vhi,
                  nb, hog_scale, gc0, gh0, gc1, gh1):
    """Lab mean g_c and rotation-invariant HoG g_h of one overlap region in two images.

    The region is the window offsets u ∈ [ulo, uhi], v ∈ [vlo, vhi] around (x0, y0)
    in image 0 and (x1, y1) in image 1; pixels outside either image are skipped
    in both, so the two descriptors always cover the same pixels. Each image comes
    as its Lab and its gradient bins (hb, hm) of ``_gradient_bins``. Returns the
    pixel count (0: no overlap).
    """
    H0, W0 = hb.shape
    H1, W1 = hb2.shape
    cnt = _region_sum(lab, hb, hm, x0, y0, x1, y1, H1, W1, ulo, uhi, vlo, vhi, nb, gc0, gh0)
    _region_sum(lab2, hb2, hm2, x1, y1, x0, y0, H0, W0, ulo, uhi, vlo, vhi, nb, gc1, gh1)
    if cnt > 0:
        _region_mean(gc0, gh0, cnt, nb, hog_scale)
        _region_mean(gc1, gh1, cnt, nb, hog_scale)
    return cnt


@numba.njit(cache=True, nogil=True)
def _window_sums(lab, hb, hm, x0, y0, x1, y1, H1, W1, h, rg, nb, gc, gh, cnt):
    """``_region_sum`` of both overlap regions of the window around (x0, y0), in one pass.

    rg (2, 4) int64: region t's offsets (ulo, uhi, vlo, vhi) within the window
    [−h, h]² (uhi < ulo: no region). Writes gc (2, 3), gh (2, nb) float64 and
    cnt (2,) int64. Each region's sums take its pixels in the same row-major
    order as ``_region_sum``, so they are the same; the two regions share the
    loads and their additions interleave (independent chains).

    The offsets inside both images are cut once, and each row's span of each
    region, so the loop body tests no bounds and counts no pixels: counters
    incremented per pixel were kept in memory, and their chain of
    load-add-store was the loop's critical path (a window 10–25 % faster).
    Indices are uint64, which numba does not wrap (the note before
    ``_lab_d2_rs``).
    """
    H0, W0 = hb.shape
    # the offsets whose pixel lies inside both images, then each region's
    lo_u = max(-h, -x0, -x1)
    hi_u = min(h, W0 - 1 - x0, W1 - 1 - x1)
    lo_v = max(-h, -y0, -y1)
    hi_v = min(h, H0 - 1 - y0, H1 - 1 - y1)
    lo0, hi0 = max(rg[0, 0], lo_u), min(rg[0, 1], hi_u)
    lo1, hi1 = max(rg[1, 0], lo_u), min(rg[1, 1], hi_u)
    va0, vb0 = rg[0, 2], rg[0, 3]
    va1, vb1 = rg[1, 2], rg[1, 3]
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    b0 = 0.0
    b1 = 0.0
    b2 = 0.0
    na = 0
    nb_ = 0
    for t in range(2):
        for b in range(nb):
            gh[t, b] = 0.0
    g0 = gh[0]
    g1 = gh[1]
    c0, c1, c2 = np.uint64(0), np.uint64(1), np.uint64(2)
    for v in range(lo_v, hi_v + 1):
        ra = va0 <= v <= vb0 and lo0 <= hi0
        rb = va1 <= v <= vb1 and lo1 <= hi1
        if not (ra or rb):
            continue
        # this row's span of each region: [s0, e0] and [s1, e1] (empty: e < s)
        s0, e0 = (lo0, hi0) if ra else (1, 0)
        s1, e1 = (lo1, hi1) if rb else (1, 0)
        na += e0 - s0 + 1
        nb_ += e1 - s1 + 1
        yu = np.uint64(y0 + v)
        for u in range(min(s0, s1), max(e0, e1) + 1):
            xu = np.uint64(x0 + u)
            l0 = lab[yu, xu, c0]
            l1 = lab[yu, xu, c1]
            l2 = lab[yu, xu, c2]
            bin_ = hb[yu, xu]
            mag = hm[yu, xu]
            if s0 <= u <= e0:
                a0 += l0
                a1 += l1
                a2 += l2
                if bin_ >= 0:
                    g0[np.uint64(bin_)] += mag
            if s1 <= u <= e1:
                b0 += l0
                b1 += l1
                b2 += l2
                if bin_ >= 0:
                    g1[np.uint64(bin_)] += mag
    gc[0, 0] = a0
    gc[0, 1] = a1
    gc[0, 2] = a2
    gc[1, 0] = b0
    gc[1, 1] = b1
    gc[1, 2] = b2
    cnt[0] = na
    cnt[1] = nb_


@numba.njit(cache=True, nogil=True, inline="always")
def _octant(gx, gy):
    """The bin of ``_hog_bin`` for nb = 8 without atan2, or −1 where it needs it.

    With a = atan2(gy, gx) + π, bin b = ⌊a / (π/4)⌋ is the octant, read from the
    signs of gx, gy and which of |gx|, |gy| is larger. Only on an octant's edge
    (gx = 0, gy = 0 or |gx| = |gy|) can atan2's rounding decide, so there it
    returns −1 and the caller takes atan2. Elsewhere the two agree: gx and gy
    are differences of float32 values, so off an edge the angle is farther from
    it than atan2's rounding error by many orders of magnitude (checked against
    the atan2 bin on 1.3·10⁸ gradients, near-diagonal ones included, none
    different). atan2 was most of the cost of refreshing a patch's bins.
    """
    ax = abs(gx)
    ay = abs(gy)
    if gx == 0.0 or gy == 0.0 or ax == ay:
        return -1
    steep = ay > ax
    if gy < 0.0:
        if gx < 0.0:
            return 1 if steep else 0
        return 2 if steep else 3
    if gx > 0.0:
        return 5 if steep else 4
    return 6 if steep else 7


@numba.njit(cache=True, nogil=True, inline="always")
def _hog_bin(gray, x, y, nb):
    """HoG bin (−1: zero gradient) and magnitude of pixel (x, y): central
    differences, clamped at the border; the angle atan2 + π cut into nb bins
    (for nb = 8 by ``_octant``, the same bins, where it can)."""
    H, W = gray.shape
    gx = (np.float64(gray[y, min(x + 1, W - 1)]) - np.float64(gray[y, max(x - 1, 0)])) * 0.5
    gy = (np.float64(gray[min(y + 1, H - 1), x]) - np.float64(gray[max(y - 1, 0), x])) * 0.5
    m = math.sqrt(gx * gx + gy * gy)
    if m > 0.0:
        if nb == 8:
            b = _octant(gx, gy)
            if b >= 0:
                return b, m
        a = math.atan2(gy, gx) + math.pi
        b = int(a * nb / (2.0 * math.pi))
        if b >= nb:
            b = nb - 1
        return b, m
    return -1, 0.0


@numba.njit(cache=True, nogil=True)
def _refresh_written(gray, nb, hb, hm, hb_s, hm_s, s, qx, qy, x, y, half, chg, box):
    """The gradient bins after a patch write: exactly those of ``_gradient_bins``
    on the box of half + 1 around (x, y) (the pixels whose bin can change),
    computing few of them.

    A pixel's bin reads only its four (clamped) neighbours' gray values, so it is
    kept where none of them changed (chg of ``_write_patch``: offset (v, w) at
    chg[v + half + 2, w + half + 2], with a ring of zeros around the changes'
    box, so a neighbour's lookup needs no bounds test); where all four
    are copies of the source's, unclamped on both sides (the window's interior,
    away from both images' borders), it is the source's bin at the copied pixel
    (hb_s, hm_s of source s, the same function of the same four values);
    elsewhere it is recomputed. box: the changes' bounding box from
    ``_write_patch``; only pixels within one of it can need anything.
    """
    H, W = gray.shape
    c = half + 2  # chg's index of offset 0
    v0, v1, w0, w1 = box
    for ry in range(max(y + v0 - 1, 0), min(y + v1 + 1, H - 1) + 1):
        i = np.uint64(ry - y + c)
        # the rows of the neighbours above and below, clamped at the image's border
        iu = i - np.uint64(1) if ry > 0 else i
        id_ = i + np.uint64(1) if ry < H - 1 else i
        for rx in range(max(x + w0 - 1, 0), min(x + w1 + 1, W - 1) + 1):
            j = np.uint64(rx - x + c)
            jl = j - np.uint64(1) if rx > 0 else j
            jr = j + np.uint64(1) if rx < W - 1 else j
            if (chg[i, jl] | chg[i, jr] | chg[iu, j] | chg[id_, j]) == 0:
                continue
            v = ry - y
            w_ = rx - x
            sx = qx + w_
            sy = qy + v
            if (-half < v < half and -half < w_ < half and 0 < rx < W - 1 and 0 < ry < H - 1
                    and 0 < sx < W - 1 and 0 < sy < H - 1):
                hb[ry, rx] = hb_s[s, sy, sx]
                hm[ry, rx] = hm_s[s, sy, sx]
            else:
                b, m = _hog_bin(gray, rx, ry, nb)
                hb[ry, rx] = b
                hm[ry, rx] = m


@numba.njit(cache=True, nogil=True, parallel=True)
def _gradient_bins(gray, nb):
    """Every pixel's HoG bin and magnitude (``_hog_bin``): the per-pixel part of
    g_h, computed once so that a window's HoG is a sum. gray (H, W) float32 →
    hb (H, W) int8 (−1: zero gradient), hm (H, W) float64."""
    H, W = gray.shape
    hb = np.empty((H, W), np.int8)
    hm = np.empty((H, W), np.float64)
    for y in numba.prange(H):
        for x in range(W):
            b, m = _hog_bin(gray, x, y, nb)
            hb[y, x] = b
            hm[y, x] = m
    return hb, hm


@numba.njit(cache=True, nogil=True)
def _hog_finish(h, nb, scale):
    """Rotate so the dominant bin comes first (rotation invariance), L2 → ×scale.

    The rotation is done in place (three reversals), so no temporary is allocated.
    """
    best = 0
    for b in range(1, nb):
        if h[b] > h[best]:
            best = b
    if best > 0:
        _reverse(h, 0, best)
        _reverse(h, best, nb)
        _reverse(h, 0, nb)
    n = 0.0
    for b in range(nb):
        n += h[b] * h[b]
    n = math.sqrt(n)
    for b in range(nb):
        h[b] = h[b] / n * scale if n > 0.0 else 0.0


@numba.njit(cache=True, nogil=True, inline="always")
def _reverse(h, lo, hi):
    """Reverse h[lo:hi] in place."""
    i = lo
    j = hi - 1
    while i < j:
        t = h[i]
        h[i] = h[j]
        h[j] = t
        i += 1
        j -= 1


# --- Sec. 3.2.1: candidates P, B ----------------------------------------------------


@numba.njit(cache=True, nogil=True, inline="always")
def _candidates(N, C, x, y, ndx0, ndy0, ndx1, ndy1, as_set, cs, cx, cy, cB, slot,
                nx_, ny_, ox_, oy_):
    """P and B (Sec. 3.2.1) at x_r = (x, y); mirrors ``reference.candidates``.

    Each source's matches of the two scan neighbours (x+ndx0, y+ndy0) and
    (x+ndx1, y+ndy1), moved by one pixel towards x_r, with the neighbours'
    confidences C as B_l. Neighbours outside the image are skipped; the first
    pixel of a scan (no neighbour) uses its own match. Candidates outside the
    source are dropped. With ``as_set`` a candidate equal in (s, x, y) to an
    earlier one of the same source is dropped (P is a union of sets, the first
    copy keeps its own C as B_l); otherwise P is a multiset.

    Writes the n candidates into cs, cx, cy (int64), cB (float64), slot (int64,
    2·s + a, the column in the decision events) and the nn existing neighbours
    into nx_, ny_ (position) and ox_, oy_ (the shift towards x_r).
    Returns (n, nn).
    """
    H, W = N.shape[1], N.shape[2]
    S = N.shape[0]
    nn = 0
    xa, ya = x + ndx0, y + ndy0
    if 0 <= xa < W and 0 <= ya < H:
        nx_[nn] = xa
        ny_[nn] = ya
        ox_[nn] = -ndx0
        oy_[nn] = -ndy0
        nn += 1
    xa, ya = x + ndx1, y + ndy1
    if 0 <= xa < W and 0 <= ya < H:
        nx_[nn] = xa
        ny_[nn] = ya
        ox_[nn] = -ndx1
        oy_[nn] = -ndy1
        nn += 1
    n = 0
    for s in range(S):
        if nn == 0:  # first pixel of a scan: no neighbour, use its own match
            mx = N[s, y, x, 0]
            my = N[s, y, x, 1]
            if 0 <= mx < W and 0 <= my < H:
                cs[n] = s
                cx[n] = mx
                cy[n] = my
                cB[n] = C[s, y, x]
                slot[n] = 2 * s
                n += 1
        for a in range(nn):
            mx = N[s, ny_[a], nx_[a], 0] + ox_[a]
            my = N[s, ny_[a], nx_[a], 1] + oy_[a]
            if not (0 <= mx < W and 0 <= my < H):
                continue
            if as_set and n > 0 and cs[n - 1] == s and cx[n - 1] == mx and cy[n - 1] == my:
                continue  # same (s, x, y) as this source's previous candidate
            cs[n] = s
            cx[n] = mx
            cy[n] = my
            cB[n] = C[s, ny_[a], nx_[a]]
            slot[n] = 2 * s + a
            n += 1
    return n, nn


# --- Sec. 3.2.1: DBSCAN on 𝓑, b_k, consensus, M ------------------------------------


@numba.njit(cache=True, nogil=True)
def _edge_bounds(pf):
    """SIFT distances that settle an edge 𝓑 ≤ ε of the DBSCAN graph without f_c.

    𝓑 = (1 − λ4 e_c) − λ5 e_g is computed left to right, with e_c = S_e(f_c),
    e_g = S_e(f_g) in [0, 1]. Rounding is monotone, so 𝓑 ≤ 1 − λ5 e_g and
    𝓑 ≥ (1 − λ4) − λ5 e_g, both evaluated with the same operations; e_g falls
    as the integer SIFT distance g grows. Returns (g_in, g_out): g ≤ g_in ⇒
    𝓑 ≤ ε (the upper bound is already ≤ ε) and g ≥ g_out ⇒ 𝓑 > ε (the lower
    bound is already > ε), whatever f_c, so ``_cluster`` skips the Lab term and
    both exponentials there: the same graph as from 𝓑 itself. Found by
    bisection on the exact expressions, then moved 16 inwards, so no
    one-ulp wobble of exp next to a threshold can matter.
    """
    lam4, lam5, eps, u = pf[LAM4], pf[LAM5], pf[EPS], pf[SIFT_UNIT]
    gmax = np.int64(128 * 255 * 255)
    lo, hi = np.int64(-1), gmax + 1  # g_in: the last g with 1 − λ5 e_g ≤ ε
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if 1.0 - lam5 * _se(float(mid) * u * u, pf[SIG_G]) <= eps:
            lo = mid
        else:
            hi = mid
    g_in = lo - 16
    lo, hi = np.int64(-1), gmax + 1  # g_out: the first g with (1 − λ4) − λ5 e_g > ε
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if (1.0 - lam4) - lam5 * _se(float(mid) * u * u, pf[SIG_G]) > eps:
            hi = mid
        else:
            lo = mid
    return g_in, hi + 16


@numba.njit(cache=True, nogil=True, inline="always")
def _cluster(fc_s, fg_s, n, cs, cx, cy, pf, pi, g_in, g_out, A, Gd, labels, is_core, stack):
    """DBSCAN of P on 𝓑(x1, x2) = 1 − λ4 S_e(f_c) − λ5 S_e(f_g), Eq. (DB_cost).

    Mirrors ``reference.cluster``. DBSCAN reads 𝓑 only as 𝓑 ≤ ε, so A (n × n
    bool) gets that; 𝓑 itself is computed only where the SIFT distance alone
    does not settle it (``_edge_bounds`` gives g_in, g_out), which is exact.
    Fills A, Gd (n × n int64: the candidates' squared SIFT distances, in
    descriptor units, for ``_decide``) and labels (−1 = noise); returns the
    number of clusters k.
    """
    if n == 0:
        return 0
    lam4, lam5, eps = pf[LAM4], pf[LAM5], pf[EPS]
    u = pf[SIFT_UNIT]
    for i in range(n):
        A[i, i] = 1.0 - lam4 - lam5 <= eps
        for j in range(i + 1, n):
            g = _sift_d2_ss(fg_s, cs[i], cy[i], cx[i], cs[j], cy[j], cx[j])
            Gd[i, j] = g
            Gd[j, i] = g
            if g <= g_in:
                e = True
            elif g >= g_out:
                e = False
            else:
                dc = _lab_d2_ss(fc_s, cs[i], cy[i], cx[i], cs[j], cy[j], cx[j])
                d = 1.0 - lam4 * _se(dc, pf[SIG_C]) - lam5 * _se(float(g) * u * u, pf[SIG_G])
                e = d <= eps
            A[i, j] = e
            A[j, i] = e
    return _dbscan_adj(A, n, pi[MIN_PTS], labels, is_core, stack)


@numba.njit(cache=True, nogil=True, inline="always")
def _member_weight(cB, i, bm, cnt):
    """w_l of candidate i in the consensus f̂: B_l / b_m, or 1 / |A_m| when b_m = 0."""
    return cB[i] / bm if bm > 0.0 else 1.0 / cnt


@numba.njit(cache=True, nogil=True, inline="always")
def _decide(fc_r, fg_r, fc_s, fg_s, x, y, n, cs, cx, cy, cB, labels, k, pf, bk, Gd,
            fhat_c):
    """Winning cluster A_m, consensus f̂_c and M(x_r) (Sec. 3.2.1).

    Mirrors ``reference.decide``. b_k = Σ B_l over cluster k; m = argmax b_k
    (first on ties); f̂ = Σ_{A_m} w_l f(x_l), w_l = B_l / b_m (uniform if
    b_m = 0); M = λ4 S_e(f_c(x_r), f̂_c) + λ5 S_e(f_g(x_r), f̂_g). Requires k > 0.
    Fills fhat_c; returns (m, b_m, M, ‖f_g(x_r) − f̂_g‖², |A_m|).

    f̂_g itself (128 numbers) is not formed here, only its distance, from the
    candidates' own: with Σ w_l = 1, ‖r − Σ w_l x_l‖² = Σ w_l ‖r − x_l‖² −
    Σ_{l<l'} w_l w_l' ‖x_l − x_l'‖² (the weighted variance's decomposition),
    whose ‖x_l − x_l'‖² ``_cluster`` has left in Gd and whose ‖r − x_l‖² are
    integer distances. It is the same number up to rounding (the scans' float32
    M maps came out the same as when f̂_g was formed, on the synthetic scenes of
    README's session 81; the reference, which forms it, agrees within
    ``test_kernel``'s 1e-6), at a fraction of the cost of 128 weighted sums per
    member: the decision is most of a static pixel's visit.
    ``_consensus_g`` forms f̂_g where a removal needs it.
    """
    u = pf[SIFT_UNIT]
    for c in range(k):
        bk[c] = 0.0
    for i in range(n):
        if labels[i] >= 0:
            bk[labels[i]] += cB[i]
    m = 0
    for c in range(1, k):
        if bk[c] > bk[m]:
            m = c
    bm = bk[m]
    cnt = 0
    for i in range(n):
        if labels[i] == m:
            cnt += 1
    for c in range(3):
        fhat_c[c] = 0.0
    sr = 0.0  # Σ w_l ‖r − x_l‖²
    sp = 0.0  # Σ_{l<l'} w_l w_l' ‖x_l − x_l'‖²
    for i in range(n):
        if labels[i] != m:
            continue
        w = _member_weight(cB, i, bm, cnt)
        for c in range(3):
            fhat_c[c] += w * fc_s[cs[i], cy[i], cx[i], c]
        sr += w * float(_sift_d2_rs(fg_r, y, x, fg_s, cs[i], cy[i], cx[i]))
        for j in range(i + 1, n):
            if labels[j] == m:
                sp += w * _member_weight(cB, j, bm, cnt) * float(Gd[i, j])
    dc = 0.0
    for c in range(3):
        t = fc_r[y, x, c] - fhat_c[c]
        dc += t * t
    dg = max(sr - sp, 0.0) * u * u
    M = pf[LAM4] * _se(dc, pf[SIG_C]) + pf[LAM5] * _se(dg, pf[SIG_G])
    return m, bm, M, dg, cnt


@numba.njit(cache=True, nogil=True, inline="always")
def _consensus_g(fg_s, n, cs, cx, cy, cB, labels, m, bm, cnt, u, fhat_g):
    """f̂_g = Σ_{A_m} w_l f_g(x_l) · u (``_decide``'s weights; fhat_g (G,) float64)."""
    G = fhat_g.shape[0]
    for j in range(G):
        fhat_g[j] = 0.0
    for i in range(n):
        if labels[i] != m:
            continue
        w = _member_weight(cB, i, bm, cnt)
        # read in place, by uint64 indices (the note before ``_lab_d2_rs``): it vectorises
        si, yi, xi = np.uint64(cs[i]), np.uint64(cy[i]), np.uint64(cx[i])
        for j in range(np.uint64(G)):
            fhat_g[j] += w * (fg_s[si, yi, xi, j] * u)


# --- Sec. 3.2.2: removal ----------------------------------------------------------


@numba.njit(cache=True, nogil=True)
def _patch_scratch(nb):
    """The work arrays of ``_choose_patch_in``: the overlaps' offsets rg (2, 4), the
    reference's g_c, g_h, count (2, 3), (2, nb), (2,) and q's (the same shapes)."""
    return (np.empty((2, 4), np.int64), np.empty((2, 3)), np.empty((2, nb)),
            np.empty(2, np.int64), np.empty((2, 3)), np.empty((2, nb)), np.empty(2, np.int64))


@numba.njit(cache=True, nogil=True)
def _choose_patch(lab, hb_r, hm_r, src_lab, hb_s, hm_s, fc_s, fg_s, F, hasF, pf, pi, x, y,
                  ndx0, ndy0, ndx1, ndy1, n, cs, cx, cy, labels, m, fhat_c, fhat_g,
                  score, gc0, gc1, gh0, gh1):
    """``_choose_patch_in`` with work arrays of its own."""
    return _choose_patch_in(lab, hb_r, hm_r, src_lab, hb_s, hm_s, fc_s, fg_s, F, hasF, pf, pi,
                            x, y, ndx0, ndy0, ndx1, ndy1, n, cs, cx, cy, labels, m, fhat_c,
                            fhat_g, score, gc0, gc1, gh0, gh1, _patch_scratch(pi[HOG_BINS]))


@numba.njit(cache=True, nogil=True)
def _choose_patch_in(lab, hb_r, hm_r, src_lab, hb_s, hm_s, fc_s, fg_s, F, hasF, pf, pi, x, y,
                     ndx0, ndy0, ndx1, ndy1, n, cs, cx, cy, labels, m, fhat_c, fhat_g,
                     score, gc0, gc1, gh0, gh1, bufs):
    """q* (Sec. 3.2.2) among the candidates of A_m; mirrors ``reference.choose_patch``.

    score(q) = Σ_i [λ6 S_e(g_c(w_q^i), g_c(w_r^i), σ_c) + λ7 S_e(g_h(…), g_h(…), σ_h)]
    + λ8 S_f(x_r, x_q, F_q), over the overlaps i with the existing left/up
    (right/down) neighbour patches. Where S_f is unavailable (epipolar term off,
    or no F for q's source) the appearance sum is rescaled by (W + λ8) / W,
    W = its attainable maximum, as λ3 is in H: the top score stays the same.
    Patches within ``tie_tol`` of the best tie; the tie goes to the smallest
    λ4‖f̂_c − f_c‖² + λ5‖f̂_g − f_g‖² (q̂), first in candidate order.
    Fills score[:n]; returns (index of q*, best score, number tied). ``bufs``
    from ``_patch_scratch`` (no allocation per pixel: none can fail inside the
    scan's row pipeline, where a failing row would leave the next one waiting).

    The reference's side of an overlap depends on q only through which pixels
    fall outside q's source; for a q whose window lies inside its source it is
    the same for every q, so it is computed once, and q's side of both
    overlaps in one pass over its window (``_window_sums``; the same sums in
    the same order: exact).
    """
    H, W = hb_r.shape
    Hs, Ws = hb_s.shape[1], hb_s.shape[2]
    h = pi[P] // 2
    nb = pi[HOG_BINS]
    u = pf[SIFT_UNIT]
    hog_scale = pf[HOG_SCALE]
    use_epi = pi[USE_EPI] != 0
    use_hog = pi[USE_HOG] != 0
    # overlap t with the neighbour patch t: window offsets (ulo, uhi, vlo, vhi),
    # empty (uhi < ulo) where the neighbour is outside the image
    rg, ref_c, ref_h, ref_n, q_c, q_h, q_n = bufs
    for t in range(2):
        dxn = ndx0 if t == 0 else ndx1
        dyn = ndy0 if t == 0 else ndy1
        rg[t, 0] = max(-h, dxn - h)
        rg[t, 1] = min(h, dxn + h)
        rg[t, 2] = max(-h, dyn - h)
        rg[t, 3] = min(h, dyn + h)
        if not (0 <= x + dxn < W and 0 <= y + dyn < H):
            rg[t, 1] = rg[t, 0] - 1
    # g_c, g_h and count per overlap: the reference's (for q inside its source), q's
    _window_sums(lab, hb_r, hm_r, x, y, x, y, H, W, h, rg, nb, ref_c, ref_h, ref_n)
    for t in range(2):
        if ref_n[t] > 0:
            _region_mean(ref_c[t], ref_h[t], ref_n[t], nb, hog_scale)
    best = -1.0e300
    for i in range(n):
        score[i] = -1.0e300
        if labels[i] != m:
            continue
        s = cs[i]
        inside = 0 <= cx[i] - h and cx[i] + h < Ws and 0 <= cy[i] - h and cy[i] + h < Hs
        if inside:
            _window_sums(src_lab[s], hb_s[s], hm_s[s], cx[i], cy[i], x, y, H, W, h, rg, nb,
                         q_c, q_h, q_n)
        sc = 0.0
        wsum = 0.0
        for t in range(2):
            if rg[t, 1] < rg[t, 0]:
                continue  # the neighbour patch does not exist at the border
            if inside:
                cnt = q_n[t]
                gq_c = q_c[t]
                gq_h = q_h[t]
                if cnt > 0:
                    _region_mean(gq_c, gq_h, cnt, nb, hog_scale)
                rc = ref_c[t]
                rh = ref_h[t]
            else:
                cnt = _region_stats(src_lab[s], hb_s[s], hm_s[s], cx[i], cy[i], lab, hb_r,
                                    hm_r, x, y, rg[t, 0], rg[t, 1], rg[t, 2], rg[t, 3], nb,
                                    hog_scale, gc0, gh0, gc1, gh1)
                gq_c = gc0
                gq_h = gh0
                rc = gc1
                rh = gh1
            if cnt == 0:
                continue
            d = 0.0
            for c in range(3):
                d += (gq_c[c] - rc[c]) ** 2
            sc += pf[LAM6] * _se(d, pf[SIG_C])
            wsum += pf[LAM6]
            if use_hog:
                d = 0.0
                for b in range(nb):
                    d += (gq_h[b] - rh[b]) ** 2
                sc += pf[LAM7] * _se(d, pf[SIG_H])
                wsum += pf[LAM7]
        if use_epi and hasF[s]:
            sc += pf[LAM8] * _sf(F, hasF, s, x, y, cx[i], cy[i], pf)
        elif wsum > 0.0:
            sc = sc * ((wsum + pf[LAM8]) / wsum)
        score[i] = sc
        if sc > best:
            best = sc
    ntie = 0
    for i in range(n):
        if labels[i] == m and score[i] >= best - pf[TIE_TOL]:
            ntie += 1
    ibest = -1
    bestd = 1.0e300
    for i in range(n):
        if labels[i] != m or score[i] < best - pf[TIE_TOL]:
            continue
        if ntie == 1:
            ibest = i
            break
        dc = 0.0
        for c in range(3):
            dc += (fhat_c[c] - fc_s[cs[i], cy[i], cx[i], c]) ** 2
        dg = 0.0
        for j in range(fhat_g.shape[0]):
            dg += (fhat_g[j] - fg_s[cs[i], cy[i], cx[i], j] * u) ** 2
        d = pf[LAM4] * dc + pf[LAM5] * dg
        if d < bestd:
            bestd = d
            ibest = i
    return ibest, best, ntie


@numba.njit(cache=True, nogil=True)
def _write_patch(img, lab, gray, src_img, src_lab, src_gray, s, qx, qy, x, y, half, chg):
    """Copy the (2·half+1)² window of source s at (qx, qy) onto the reference at (x, y).

    Mirrors ``reference.write_patch``; half = p // 2 (patch write) or 0 (pixel).
    Pixels outside either image are skipped. For ``_refresh_written``, in the
    same pass: chg (2·half + 5)² uint8, centred at (x, y), gets 1 where the
    gray value changes, else 0 (offset (v, w) at chg[v + half + 2, w + half + 2];
    two rings of zeros around the patch). Returns the bounding box of the changes
    as window offsets (v0, v1, w0, w1); v0 > v1 when none. The span of offsets
    inside both images is cut once per patch, so the copy tests no bounds.
    """
    H, W = gray.shape
    c = half + 2  # chg's index of offset 0
    for i in range(2 * c + 1):
        for j in range(2 * c + 1):
            chg[i, j] = 0
    o = half + 1
    v0, v1, w0, w1 = o, -o, o, -o
    wlo = max(-half, -x, -qx)
    whi = min(half, W - 1 - x, W - 1 - qx)
    su = np.uint64(s)
    for v in range(max(-half, -y, -qy), min(half, H - 1 - y, H - 1 - qy) + 1):
        ry = np.uint64(y + v)
        sy = np.uint64(qy + v)
        for w_ in range(wlo, whi + 1):
            rx = np.uint64(x + w_)
            sx = np.uint64(qx + w_)
            if gray[ry, rx] != src_gray[su, sy, sx]:
                chg[np.uint64(v + c), np.uint64(w_ + c)] = 1
                v0 = min(v0, v)
                v1 = max(v1, v)
                w0 = min(w0, w_)
                w1 = max(w1, w_)
            for k in range(np.uint64(3)):
                img[ry, rx, k] = src_img[su, sy, sx, k]
                lab[ry, rx, k] = src_lab[su, sy, sx, k]
            gray[ry, rx] = src_gray[su, sy, sx]
    return v0, v1, w0, w1


# --- Sec. 3.2.3: update of N and C ----------------------------------------------------


@numba.njit(cache=True, nogil=True)
def _update_correspondences(N, C, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi, x, y, n, cs,
                            cx, cy, labels, m, nx_, ny_, nn, scan, step, rec, upd_i,
                            upd_f, counts):
    """N_{r→s}(x_r) and C_s(x_r) for every source, the three cases of Sec. 3.2.3.

    Mirrors ``reference.update_correspondences``. Case 1: one candidate of s in
    A_m; case 2: several, the one with the largest H wins (first on ties);
    case 3: none, x* = argmin of the squared Sampson distance (= argmax S_f)
    over X = s's candidates + the neighbours' own matches. Without F_s there is
    no geometry: case 3 takes the first of X (the first neighbour's match moved
    by one pixel, plain propagation). C_s(x_r) = H(x_r, x*, F_s) in every case.
    A source with no candidate and no in-image neighbour match is left as is.
    Records one CorrespondenceUpdate per source changed (when ``rec``).
    """
    H, W = fc_r.shape[0], fc_r.shape[1]
    S = N.shape[0]
    for t in range(S):
        nin = 0
        bi = -1
        bh = -1.0e300
        for i in range(n):
            if cs[i] == t and labels[i] == m:
                nin += 1
                hv = _sim_H(fc_r, fg_r, x, y, fc_s, fg_s, t, cx[i], cy[i], F, hasF, pf, pi)
                if hv > bh:
                    bh = hv
                    bi = i
        if nin > 0:
            nxs = cx[bi]
            nys = cy[bi]
            case = 1 if nin == 1 else 2
        else:
            # case 3: geometry only, over X = this source's candidates + the
            # neighbours' matches; the smallest Sampson distance wins.
            bd = 1.0e300
            nxs = -1
            nys = -1
            for i in range(n):
                if cs[i] == t:
                    d = _sampson(F, t, x, y, cx[i], cy[i]) if hasF[t] else 0.0
                    if d < bd:
                        bd = d
                        nxs = cx[i]
                        nys = cy[i]
            for a in range(nn):
                mx = N[t, ny_[a], nx_[a], 0]
                my = N[t, ny_[a], nx_[a], 1]
                if 0 <= mx < W and 0 <= my < H:
                    d = _sampson(F, t, x, y, mx, my) if hasF[t] else 0.0
                    if d < bd:
                        bd = d
                        nxs = mx
                        nys = my
            if nxs < 0:
                continue
            case = 3
            bh = _sim_H(fc_r, fg_r, x, y, fc_s, fg_s, t, nxs, nys, F, hasF, pf, pi)
        N[t, y, x, 0] = nxs
        N[t, y, x, 1] = nys
        C[t, y, x] = bh
        if rec:
            e = counts[2]
            if e < upd_i.shape[0]:
                upd_i[e, U_SCAN] = scan
                upd_i[e, U_STEP] = step
                upd_i[e, U_X] = x
                upd_i[e, U_Y] = y
                upd_i[e, U_SRC] = t
                upd_i[e, U_CASE] = case
                upd_i[e, U_NX] = nxs
                upd_i[e, U_NY] = nys
                upd_f[e] = bh
            counts[2] = e + 1


# --- one pixel's decision, shared by the scan and its precompute ---------------------


@numba.njit(cache=True, nogil=True)
def _work_arrays(K, G):
    """Per-pixel work arrays of a decision: candidates (cs, cx, cy, cB, slot),
    DBSCAN (A, the ε-graph; Gd, the SIFT distances; labels, is_core, stack), b_k
    and f̂ (bk, fhat_c, fhat_g; G = the SIFT length), and the scan neighbours
    (nx_, ny_, ox_, oy_)."""
    return (np.empty(K, np.int64), np.empty(K, np.int64), np.empty(K, np.int64),
            np.empty(K, np.float64), np.empty(K, np.int64), np.empty((K, K), np.bool_),
            np.empty((K, K), np.int64),
            np.empty(K, np.int64), np.empty(K, np.bool_), np.empty(K * K + 1, np.int64),
            np.empty(K + 1, np.float64), np.empty(3, np.float64), np.empty(G, np.float64),
            np.empty(2, np.int64), np.empty(2, np.int64), np.empty(2, np.int64),
            np.empty(2, np.int64))


@numba.njit(cache=True, nogil=True, inline="always")
def _scan_neighbours(direction):
    """(ndx0, ndy0, ndx1, ndy1): the offsets of the two scan neighbours of a pixel
    (left and up for direction +1, right and down for −1)."""
    if direction > 0:
        return -1, 0, 0, -1
    return 1, 0, 0, 1


@numba.njit(cache=True, nogil=True, inline="always")
def _decision(N, C, fc_r, fg_r, fc_s, fg_s, pf, pi, g_in, g_out, x, y, direction,
              cs, cx, cy, cB, slot, A, Gd, labels, is_core, stack, bk, fhat_c,
              nx_, ny_, ox_, oy_):
    """``_candidates`` → ``_cluster`` → ``_decide`` at (x, y), in a scan of
    ``direction``; g_in, g_out from ``_edge_bounds(pf)``; the work arrays of
    ``_work_arrays``, one by one.

    Returns (n, nn, k, m, b_m, M, ‖f_g(x_r) − f̂_g‖², |A_m|, the bitmask of
    A_m's sources); m = −1 and M = NaN when no cluster formed. The candidates,
    labels and f̂_c stay in the work arrays (f̂_g: ``_consensus_g``);
    ``_store_decision`` writes the maps.

    The work arrays come one by one, not as the tuple that ``_work_arrays``
    returns: inlined, unpacking the tuple at every pixel took a reference
    count on each array, 11 atomic pairs a pixel (the note before ``_lab_d2_rs``); and no more
    than 30 arguments, or CPython passes them as ``*args``, which numba does
    not inline.
    """
    ndx0, ndy0, ndx1, ndy1 = _scan_neighbours(direction)
    n, nn = _candidates(N, C, x, y, ndx0, ndy0, ndx1, ndy1, pi[CAND_SET] != 0, cs, cx, cy,
                        cB, slot, nx_, ny_, ox_, oy_)
    k = _cluster(fc_s, fg_s, n, cs, cx, cy, pf, pi, g_in, g_out, A, Gd, labels, is_core,
                 stack)
    M = np.nan
    m = -1
    bm = 0.0
    cdist = np.nan
    wsize = 0
    if k > 0:
        m, bm, M, cdist, wsize = _decide(fc_r, fg_r, fc_s, fg_s, x, y, n, cs, cx, cy, cB,
                                         labels, k, pf, bk, Gd, fhat_c)
    wsrc = 0
    for i in range(n):
        if k > 0 and labels[i] == m:
            wsrc |= 1 << cs[i]
    return n, nn, k, m, bm, M, cdist, wsize, wsrc


@numba.njit(cache=True, nogil=True, inline="always")
def _store_decision(Mmap, Bmap, Kmap, x, y, M, bm, n, k, wsize, wsrc):
    """A decision's M, b_m and (|P|, k, |A_m|, sources of A_m) into Mmap (H, W),
    Bmap (H, W) and Kmap (H, W, 4) at (y, x)."""
    Mmap[y, x] = M
    Bmap[y, x] = bm
    Kmap[y, x, 0] = n
    Kmap[y, x, 1] = k
    Kmap[y, x, 2] = wsize
    Kmap[y, x, 3] = wsrc


# --- the decisions of a scan, precomputed on all cores (exact) ----------------------


@numba.njit(cache=True, nogil=True, parallel=True)
def _decide_all(N, C, fc_r, fg_r, fc_s, fg_s, pf, pi, direction, preM, preB, preK):
    """Every pixel's decision from the state at the start of a scan, in parallel.

    The decision at x_r reads N and C at its two scan neighbours and f(x_r) only;
    during a scan they change only at dynamic pixels (the update of Sec. 3.2.3
    and the write of f at the pixel itself). So wherever neither neighbour has
    been updated yet in the scan, this precomputed decision is exactly the one
    the sequential scan would make (``_scan`` checks and recomputes the
    others). Fills preM (H, W) float64 (NaN: undecided), preB (H, W) float64 b_m
    and preK (H, W, 4) int32 as Kmap.
    """
    S, H, W = N.shape[0], N.shape[1], N.shape[2]
    K = 2 * S
    g_in, g_out = _edge_bounds(pf)
    for y in numba.prange(H):
        (cs, cx, cy, cB, slot, A, Gd, labels, is_core, stack, bk, fhat_c, fhat_g,
         nx_, ny_, ox_, oy_) = _work_arrays(K, fg_r.shape[2])
        for x in range(W):
            n, _, k, _, bm, M, _, wsize, wsrc = _decision(
                N, C, fc_r, fg_r, fc_s, fg_s, pf, pi, g_in, g_out, x, y, direction, cs, cx,
                cy, cB, slot, A, Gd, labels, is_core, stack, bk, fhat_c, nx_, ny_, ox_,
                oy_)
            _store_decision(preM, preB, preK, x, y, M, bm, n, k, wsize, wsrc)


# --- Algorithm 1: one chunk of rows of a scan ------------------------------------------


@numba.njit(cache=True, nogil=True)
def _scan_scratch(pi, S, G):
    """The work arrays of one visiting thread: those of ``_work_arrays`` (K = 2·S
    candidate slots, G = the SIFT length), the patch scores (K,), g_c and g_h of
    two overlaps (3,), (nb,) ×2, ``_write_patch``'s change map and those of
    ``_choose_patch_in`` (``_patch_scratch``)."""
    K = 2 * S
    nb = pi[HOG_BINS]
    half = pi[P] // 2 if pi[WRITE_PATCH] != 0 else 0
    return (_work_arrays(K, G), np.empty(K, np.float64), np.empty(3), np.empty(3),
            np.empty(nb), np.empty(nb), np.empty((2 * half + 5, 2 * half + 5), np.uint8),
            _patch_scratch(nb))


@numba.njit(cache=True, nogil=True)
def _scan_span(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s,
               N, C, F, hasF, L, Mmap, Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s,
               use_pre, preM, preB, preK, dirty, pf, pi, g_in, g_out, scan, direction,
               vi, xi0, xi1, rec, dec_i, dec_f, dec_cs, dec_cxy, dec_cB, dec_ccl,
               rep_i, rep_f, upd_i, upd_f, counts, stats, scratch, done, row, R):
    """Visit the pixels xi0..xi1−1 of row vi (in visiting order: row vi counts from
    the top in a forward scan, from the bottom in a backward one, and so do the
    columns): the body of ``_scan``, which see for the state and events.
    ``scratch`` from ``_scan_scratch``; g_in, g_out from ``_edge_bounds(pf)``.

    In ``_scan``'s row pipeline (R ≥ 0): this is row ``row`` of ``done`` (int64,
    the pixels visited of each row); pixel xi waits until the row above is done
    beyond xi + R, and how far this row has got is published every ``_SPAN`` px
    and at the end. R < 0: no waiting (``done`` and ``row`` unused)."""
    H, W = gray.shape
    S = N.shape[0]
    K = 2 * S
    nb = pi[HOG_BINS]
    half = pi[P] // 2 if pi[WRITE_PATCH] != 0 else 0
    work, score, gc0, gc1, gh0, gh1, chg, pbufs = scratch
    (cs, cx, cy, cB, slot, A, Gd, labels, is_core, stack, bk, fhat_c, fhat_g,
     nx_, ny_, ox_, oy_) = work
    # the two scan neighbours (x + dx, y + dy): left/up, or right/down
    ndx0, ndy0, ndx1, ndy1 = _scan_neighbours(direction)
    y = vi if direction > 0 else H - 1 - vi
    wait = R >= 0
    lim = W if (not wait or row == 0) else -1  # columns below lim may be visited
    pub = xi0
    for xi in range(xi0, xi1):
        if wait:
            while xi >= lim:  # the row above: done beyond xi + R (or whole)
                prev = load_acquire(done, row - 1)
                lim = W if prev >= W else prev - R
                if xi >= lim:
                    cpu_yield()
            if xi - pub >= _SPAN:
                store_release(done, row, xi)
                pub = xi
        x = xi if direction > 0 else W - 1 - xi
        step = np.int64(scan) * H * W + np.int64(vi) * W + xi
        if use_pre:
            # the precomputed decision holds unless a neighbour was updated
            # in this scan; static ones are taken as they are (unless recorded)
            pM = preM[y, x]
            ok = not (pM <= pf[T_R])
            for t in range(2):
                xa = x + (ndx0 if t == 0 else ndx1)
                ya = y + (ndy0 if t == 0 else ndy1)
                if 0 <= xa < W and 0 <= ya < H and dirty[ya, xa] != 0:
                    ok = False
            if ok and rec:
                if probe[y, x]:
                    ok = False
                elif pf[SAMPLE_RATE] > 0.0:
                    hsh = (np.uint64(x) * np.uint64(73856093)) ^ \
                        (np.uint64(y) * np.uint64(19349663)) ^ \
                        (np.uint64(scan) * np.uint64(83492791))
                    if float(hsh % np.uint64(1000003)) < pf[SAMPLE_RATE] * 1000003.0:
                        ok = False
            if ok:
                Mmap[y, x] = pM
                Bmap[y, x] = preB[y, x]
                for c in range(4):
                    Kmap[y, x, c] = preK[y, x, c]
                if preK[y, x, 1] == 0:
                    stats[2] += 1
                continue
        # ---- decision (Sec. 3.2.1) --------------------------------------------
        n, nn, k, m, bm, M, cdist, wsize, wsrc = _decision(
            N, C, fc_r, fg_r, fc_s, fg_s, pf, pi, g_in, g_out, x, y, direction, cs, cx, cy,
            cB, slot, A, Gd, labels, is_core, stack, bk, fhat_c, nx_, ny_, ox_, oy_)
        _store_decision(Mmap, Bmap, Kmap, x, y, M, bm, n, k, wsize, wsrc)
        dynamic = k > 0 and M <= pf[T_R]
        if k == 0:
            stats[2] += 1
        chosen = -1
        if dynamic:
            stats[0] += 1
            L[y, x] = 1
            # ---- removal (Sec. 3.2.2) -----------------------------------------
            _consensus_g(fg_s, n, cs, cx, cy, cB, labels, m, bm, wsize, pf[SIFT_UNIT], fhat_g)
            ib, best, ntie = _choose_patch_in(lab, hb_r, hm_r, src_lab, hb_s, hm_s, fc_s,
                                              fg_s, F, hasF, pf, pi, x, y, ndx0, ndy0, ndx1,
                                              ndy1, n, cs, cx, cy, labels, m, fhat_c, fhat_g,
                                              score, gc0, gc1, gh0, gh1, pbufs)
            s = cs[ib]
            qx = cx[ib]
            qy = cy[ib]
            box = _write_patch(img, lab, gray, src_img, src_lab, src_gray, s, qx, qy, x,
                               y, half, chg)
            _refresh_written(gray, nb, hb_r, hm_r, hb_s, hm_s, s, qx, qy, x, y, half, chg,
                             box)
            for c in range(3):
                fc_r[y, x, c] = fc_s[s, qy, qx, c]
            for j in range(fg_r.shape[2]):
                fg_r[y, x, j] = fg_s[s, qy, qx, j]
            chosen = s
            stats[1] += 1
            if rec:
                e = counts[1]
                if e < rep_i.shape[0]:
                    rep_i[e, R_SCAN] = scan
                    rep_i[e, R_STEP] = step
                    rep_i[e, R_X] = x
                    rep_i[e, R_Y] = y
                    rep_i[e, R_SRC] = s
                    rep_i[e, R_SX] = qx
                    rep_i[e, R_SY] = qy
                    rep_i[e, R_TIE] = 1 if ntie > 1 else 0
                    rep_i[e, R_NP] = ntie
                    rep_f[e] = best
                counts[1] = e + 1
            # ---- update (Sec. 3.2.3) ------------------------------------------
            if pi[UPDATE] != 0:
                dirty[y, x] = 1
                _update_correspondences(N, C, fc_r, fg_r, fc_s, fg_s, F, hasF, pf, pi,
                                        x, y, n, cs, cx, cy, labels, m, nx_, ny_, nn,
                                        scan, step, rec, upd_i, upd_f, counts)
        # ---- record the decision ----------------------------------------------
        if rec:
            why = 0
            if dynamic:
                why |= 1
            if probe[y, x]:
                why |= 2
            if why == 0 and pf[SAMPLE_RATE] > 0.0:
                hsh = (np.uint64(x) * np.uint64(73856093)) ^ \
                    (np.uint64(y) * np.uint64(19349663)) ^ \
                    (np.uint64(scan) * np.uint64(83492791))
                if float(hsh % np.uint64(1000003)) < pf[SAMPLE_RATE] * 1000003.0:
                    why |= 4
            if why != 0:
                e = counts[0]
                if e < dec_i.shape[0]:
                    dec_i[e, D_SCAN] = scan
                    dec_i[e, D_STEP] = step
                    dec_i[e, D_X] = x
                    dec_i[e, D_Y] = y
                    dec_i[e, D_WHY] = why
                    dec_i[e, D_NCAND] = n
                    dec_i[e, D_WIN] = m
                    dec_i[e, D_NCL] = k
                    dec_i[e, D_CHOSEN] = chosen
                    dec_i[e, D_DYN] = 1 if dynamic else 0
                    dec_f[e, 0] = M
                    dec_f[e, 1] = bm
                    dec_f[e, 2] = cdist
                    for q in range(K):
                        dec_cs[e, q] = -1
                        dec_cxy[e, q, 0] = -1
                        dec_cxy[e, q, 1] = -1
                        dec_cB[e, q] = 0.0
                        dec_ccl[e, q] = -1
                    for i in range(n):
                        q = slot[i]
                        dec_cs[e, q] = cs[i]
                        dec_cxy[e, q, 0] = cx[i]
                        dec_cxy[e, q, 1] = cy[i]
                        dec_cB[e, q] = cB[i]
                        dec_ccl[e, q] = labels[i]
                counts[0] = e + 1
    if wait:
        store_release(done, row, xi1)


# --- the same scan on all cores: a pipeline of rows (exact) ----------------------


# pixels a row of the pipeline visits between two publications of its progress
_SPAN = 8


@numba.njit(cache=True, nogil=True)
def _reach(pi):
    """R: two visits farther apart than R px (in x or in y) touch no common state.

    A visit reads N and C at its scan neighbours (1 px), the reference's Lab and
    gradient bins within h = p // 2 (``_choose_patch``), and writes the pixels
    within ``half`` (``_write_patch``; p // 2, or 0 for pixel writes) and the
    gradient bins within half + 1, reading gray within half + 2
    (``_refresh_written``)."""
    h = pi[P] // 2
    half = h if pi[WRITE_PATCH] != 0 else 0
    return max(half + 1 + h, 2 * half + 2, 1)


@numba.njit(cache=True, nogil=True, parallel=True)
def _scan(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s,
          N, C, F, hasF, L, Mmap, Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s,
          use_pre, preM, preB, preK, dirty, pf, pi, scan, direction, r0, r1, rec, pipeline,
          dec_i, dec_f, dec_cs, dec_cxy, dec_cB, dec_ccl, rep_i, rep_f, upd_i, upd_f,
          counts, stats):
    """Visit rows r0..r1−1 (in visiting order) of one scan; mutate the state in place.
    The driver's one compiled entry (Algorithm 1), for recorded and unrecorded
    runs alike.

    State: img (H, W, 3) uint8, lab (H, W, 3) float32 and gray (H, W) float32 of
    the current reference; fc_r (H, W, 3) float32 and fg_r (H, W, 128) uint8 its
    features; sources src_img/src_lab/src_gray/fc_s/fg_s with a leading S axis;
    N (S, H, W, 2) int32, C (S, H, W) float32; F (S, 3, 3) float64, hasF (S,) bool;
    L (H, W) uint8 (1 = dynamic in some scan); Mmap (H, W) float32 of this scan;
    Kmap (H, W, 4) int32 of this scan: |P|, k (clusters), |A_m| (the winning
    cluster's size) and a bitmask of the sources in A_m (bit s); Bmap (H, W)
    float32: b_m (the winning cluster's weight, Σ B_l); probe (H, W) bool;
    hb_r, hm_r (H, W) and hb_s, hm_s (S, H, W): the gradient bins of the reference
    (kept up to date after each write) and of the sources (``_gradient_bins``);
    with ``use_pre``, preM/preB/preK from ``_decide_all`` at the scan's start are
    taken for static pixels whose neighbours are not ``dirty`` (dirty (H, W)
    uint8: updated in this scan, set here), so the result is the same.
    direction +1: top-left → bottom-right, −1: the reverse.

    Per pixel: ``_decision`` (``_candidates`` → ``_cluster`` → ``_decide``); if dynamic,
    ``_choose_patch`` → ``_write_patch`` (+ f_c, f_g of q*) →
    ``_update_correspondences``. Mirrors ``reference.scan_rows``.

    Events (when ``rec``): decisions for dynamic, probe and sampled static pixels;
    every replacement; every correspondence update. ``counts`` = [decisions,
    replacements, updates] written (may exceed capacity: overflow). ``stats`` (G, 3)
    int64: row g += [dynamic, replaced, undecided] of thread g (row 0 when not
    ``pipeline``).

    Without ``pipeline``: one pixel at a time, in the visiting order (events when
    ``rec``), on one thread. With ``pipeline`` (and not ``rec``: no events), on all
    cores, the same state byte for byte, as a pipeline of rows: each thread claims
    the next visiting row (``_atomics.fetch_add``) and visits it in one
    ``_scan_span`` call (a call costs about 0.7 µs of reference counting),
    publishing every ``_SPAN`` px how far it has got (``store_release``); pixel x
    of row i waits (``cpu_yield``) until row i − 1 is done as far as x + R
    (``_reach``, read with ``load_acquire``). A visit allocates nothing, so no
    row can fail and leave the next one waiting. So each visit's predecessors
    in the sequential order that it depends on are done before it: its left
    neighbour, and the row above as far as R px to its right (the rows further up
    are further ahead still). A visit of row i − 1 that runs after one of row i at
    x is more than R px to its right, so the two touch no common state. Rows are
    claimed in order, so the lowest unfinished row never waits and a thread that
    runs alone (the others busy elsewhere) visits the rows in turn: no deadlock.
    Where a mover makes a row expensive, the next row follows R px behind on
    the other core instead of waiting at a barrier.
    """
    H, W = gray.shape
    S = N.shape[0]
    g_in, g_out = _edge_bounds(pf)
    nrow = r1 - r0
    # one visit loop for both, so that the visits compile once (each parallel loop
    # compiles its calls anew): without the pipeline (or recorded: the events come
    # in the visiting order) one thread claims the rows in turn and never waits
    on_all = pipeline and not rec
    G = stats.shape[0] if on_all else 1
    R = _reach(pi) if on_all else -1
    done = np.zeros(nrow, np.int64)  # pixels visited of each row, in visiting order
    claim = np.zeros(1, np.int64)  # the next row to claim
    for g in numba.prange(G):
        scratch = _scan_scratch(pi, S, fg_r.shape[2])
        while True:
            i = fetch_add(claim, 0, 1)
            if i >= nrow:
                break
            _scan_span(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s,
                       fg_s, N, C, F, hasF, L, Mmap, Kmap, Bmap, probe, hb_r, hm_r,
                       hb_s, hm_s, use_pre, preM, preB, preK, dirty, pf, pi, g_in, g_out,
                       scan, direction, r0 + i, 0, W, rec, dec_i, dec_f, dec_cs,
                       dec_cxy, dec_cB, dec_ccl, rep_i, rep_f, upd_i, upd_f, counts,
                       stats[g], scratch, done, i, R)

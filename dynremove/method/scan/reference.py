"""Readable reference of the scan (Sec. 3.2), one function per paragraph.

Slow (pure Python + numpy + ``sklearn.cluster.DBSCAN(metric="precomputed")``)
and meant for small images: tests assert that the compiled kernel
(``_kernels._scan``) gives the same labels, pixels, N, C and events.
``scan_rows`` takes the kernel's state arrays and buffers, but reads every
parameter from ``Params`` by name, never from the kernel's packed ``pf``/``pi``
arrays: a wrong index in ``driver.pack_params`` makes the two disagree.

The functions are named like the kernel's (``candidates`` ↔ ``_candidates``,
``choose_patch`` ↔ ``_choose_patch``, …); README "Where each equation lives"
maps them to the paper.
"""

from __future__ import annotations

import math

import numpy as np
from sklearn.cluster import DBSCAN

from dynremove.params import Params


def S_e(d2: float, sigma: float) -> float:
    """S_e(f1, f2, σ) = exp(−‖f1 − f2‖² / 2σ²), from the squared distance.

    Examples
    --------
    >>> S_e(0.0, 4.8)
    1.0
    >>> round(S_e(2 * 0.25 ** 2, 0.25), 6)  # ‖·‖² = 2σ² → e⁻¹
    0.367879
    """
    return math.exp(-d2 / (2.0 * sigma * sigma))


def sampson_sq(F: np.ndarray, xr: float, yr: float, xs: float, ys: float) -> float:
    """Squared Sampson distance (px²) with x_sᵀ F x_r = 0.

    Examples
    --------
    >>> F = np.array([[0., 0, 0], [0, 0, -1], [0, 1, 0]])  # x-translation: rows
    >>> float(sampson_sq(F, 10, 5, 20, 7))  # 2 px off the line: 2² / (1 + 1)
    2.0
    """
    a = F[0, 0] * xr + F[0, 1] * yr + F[0, 2]  # F x_r
    b = F[1, 0] * xr + F[1, 1] * yr + F[1, 2]
    c = F[2, 0] * xr + F[2, 1] * yr + F[2, 2]
    ta = F[0, 0] * xs + F[1, 0] * ys + F[2, 0]  # Fᵀ x_s
    tb = F[0, 1] * xs + F[1, 1] * ys + F[2, 1]
    e = xs * a + ys * b + c
    return e * e / max(a * a + b * b + ta * ta + tb * tb, 1e-300)


class _Ctx:
    """Params (by name), the SIFT unit and the fundamental matrices of one run."""

    def __init__(self, params: Params, sift_unit: float, F: np.ndarray, hasF: np.ndarray):
        self.p, self.u, self.F, self.hasF = params, float(sift_unit), F, hasF

    def S_f(self, s, xr, yr, xs, ys):
        """S_f = exp(−d_s / 2σ_e²), Sampson distance in units of coord_scale_px."""
        if not self.hasF[s]:
            return 0.0
        cs, se = self.p.coord_scale_px, self.p.sigma_e
        d = sampson_sq(self.F[s], xr, yr, xs, ys) / (cs * cs)
        return math.exp(-d / (2.0 * se * se))

    def has_epipolar(self, s) -> bool:
        return bool(self.p.use_epipolar and self.hasF[s])

    def sift_d2(self, a, b):
        return float(np.sum((a.astype(np.int64) - b.astype(np.int64)) ** 2)) * self.u * self.u

    def H(self, fc_r, fg_r, x, y, fc_s, fg_s, s, xs, ys):
        """H(x_r, x, F_s): λ1 S_e(f_c) + λ2 S_e(f_g) + λ3 S_f (Sec. 3.2.3; = C_s, Eq. 1).

        Without S_f (epipolar term off, or no F_s) λ1 and λ2 are scaled by
        (λ1+λ2+λ3)/(λ1+λ2), so the top value stays λ1+λ2+λ3.
        """
        l1, l2, l3 = self.p.lambda1, self.p.lambda2, self.p.lambda3
        sc = S_e(_d2(fc_r[y, x], fc_s[s, ys, xs]), self.p.sigma_c)
        sg = S_e(self.sift_d2(fg_r[y, x], fg_s[s, ys, xs]), self.p.sigma_g)
        if self.has_epipolar(s):
            return l1 * sc + l2 * sg + l3 * self.S_f(s, x, y, xs, ys)
        return (l1 * sc + l2 * sg) * (l1 + l2 + l3) / (l1 + l2)


def _d2(a, b) -> float:
    t = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return float(np.sum(t * t))  # sequential for short vectors, as the kernel sums


def similarity_map(N, fc_r, fg_r, fc_s, fg_s, F, hasF, params: Params, sift_unit: float):
    """C_s(x_r) = H(x_r, N_{r→s}(x_r), F_s) for every pixel (Eq. 1); 0 off the source."""
    ctx = _Ctx(params, sift_unit, F, hasF)
    S, H, W = N.shape[:3]
    C = np.zeros((S, H, W), np.float32)
    for s in range(S):
        for y in range(H):
            for x in range(W):
                xs, ys = (int(v) for v in N[s, y, x])
                if 0 <= xs < W and 0 <= ys < H:
                    C[s, y, x] = ctx.H(fc_r, fg_r, x, y, fc_s, fg_s, s, xs, ys)
    return C


def candidates(N, C, x, y, direction, H, W, *, as_set=False):
    """P and B (Sec. 3.2.1): each source's matches of the left/up (right/down)
    neighbours moved by one pixel towards x_r, with the neighbours' confidences.

    With ``as_set`` P is a set, as the paper writes it: a candidate equal in
    (s, x, y) to one already in P is left out (the first keeps its own C as B_l).
    Returns a list of (s, xs, ys, B, slot) and the neighbours used.
    """
    off = [(-1, 0), (0, -1)] if direction > 0 else [(1, 0), (0, 1)]
    nbrs = [(x + dx, y + dy, -dx, -dy) for dx, dy in off if 0 <= x + dx < W and 0 <= y + dy < H]
    P = []
    seen = set()
    for s in range(N.shape[0]):
        if not nbrs:  # first pixel of a scan: its own match
            mx, my = N[s, y, x]
            if 0 <= mx < W and 0 <= my < H:
                P.append((s, int(mx), int(my), float(C[s, y, x]), 2 * s))
        for a, (nx, ny, ox, oy) in enumerate(nbrs):
            mx, my = N[s, ny, nx, 0] + ox, N[s, ny, nx, 1] + oy
            if not (0 <= mx < W and 0 <= my < H):
                continue
            if as_set and (s, int(mx), int(my)) in seen:
                continue
            seen.add((s, int(mx), int(my)))
            P.append((s, int(mx), int(my), float(C[s, ny, nx]), 2 * s + a))
    return P, nbrs


def cluster(P, fc_s, fg_s, ctx):
    """DBSCAN on the distance 𝓑(x1, x2) of Eq. (DB_cost); labels (−1 = noise)."""
    p = ctx.p
    n = len(P)
    D = np.zeros((n, n))
    for i in range(n):
        D[i, i] = 1.0 - p.lambda4 - p.lambda5
        for j in range(i + 1, n):
            si, xi, yi = P[i][:3]
            sj, xj, yj = P[j][:3]
            d = (1.0 - p.lambda4 * S_e(_d2(fc_s[si, yi, xi], fc_s[sj, yj, xj]), p.sigma_c)
                 - p.lambda5 * S_e(ctx.sift_d2(fg_s[si, yi, xi], fg_s[sj, yj, xj]), p.sigma_g))
            D[i, j] = D[j, i] = d
    db = DBSCAN(eps=p.dbscan_eps, min_samples=p.dbscan_min_pts, metric="precomputed")
    return db.fit(D).labels_


def decide(P, labels, fc_r, fg_r, fc_s, fg_s, x, y, ctx):
    """Winning cluster A_m (largest b_k = Σ B), consensus (f̂_c, f̂_g) and M(x_r), Eq. (M)."""
    p = ctx.p
    k = int(labels.max()) + 1 if len(labels) else 0
    if k == 0:
        return -1, 0.0, None, None, float("nan"), float("nan")
    B = np.array([q[3] for q in P])
    b = np.zeros(k)
    for i, c in enumerate(labels):  # b_k = Σ B over the cluster, summed in candidate order
        if c >= 0:
            b[c] += B[i]
    m = int(np.argmax(b))
    members = np.flatnonzero(labels == m)
    w = B[members] / b[m] if b[m] > 0 else np.full(len(members), 1.0 / len(members))
    fhat_c = np.zeros(3)
    fhat_g = np.zeros(fg_s.shape[-1])
    for wi, i in zip(w, members):
        s, xs, ys = P[i][:3]
        fhat_c += wi * fc_s[s, ys, xs].astype(np.float64)
        fhat_g += wi * (fg_s[s, ys, xs].astype(np.float64) * ctx.u)
    dc = _d2(fc_r[y, x], fhat_c)
    dg = _d2(fg_r[y, x].astype(np.float64) * ctx.u, fhat_g)
    M = p.lambda4 * S_e(dc, p.sigma_c) + p.lambda5 * S_e(dg, p.sigma_g)
    return m, float(b[m]), fhat_c, fhat_g, M, dg


def overlap_descriptors(lab_a, gray_a, xa, ya, lab_b, gray_b, xb, yb, region, nb, hog_scale):
    """g_c (Lab mean) and g_h (rotation-invariant HoG) of one overlap region, in two
    images; pixels outside either image are left out of both."""
    (ulo, uhi), (vlo, vhi) = region
    Ha, Wa = gray_a.shape
    Hb, Wb = gray_b.shape
    pix = [(u, v) for v in range(vlo, vhi + 1) for u in range(ulo, uhi + 1)
           if 0 <= xa + u < Wa and 0 <= ya + v < Ha and 0 <= xb + u < Wb and 0 <= yb + v < Hb]
    if not pix:
        return None

    def hog(gray, x0, y0):
        Hh, Ww = gray.shape
        h = np.zeros(nb)
        for u, v in pix:
            x, y = x0 + u, y0 + v
            gx = (float(gray[y, min(x + 1, Ww - 1)]) - float(gray[y, max(x - 1, 0)])) * 0.5
            gy = (float(gray[min(y + 1, Hh - 1), x]) - float(gray[max(y - 1, 0), x])) * 0.5
            mag = math.sqrt(gx * gx + gy * gy)
            if mag > 0:
                h[min(int((math.atan2(gy, gx) + math.pi) * nb / (2 * math.pi)), nb - 1)] += mag
        h = np.roll(h, -int(np.argmax(h)))  # dominant orientation first
        n = math.sqrt(float(h @ h))
        return h / n * hog_scale if n > 0 else h

    gc_a = np.mean([lab_a[ya + v, xa + u].astype(np.float64) for u, v in pix], axis=0)
    gc_b = np.mean([lab_b[yb + v, xb + u].astype(np.float64) for u, v in pix], axis=0)
    return gc_a, hog(gray_a, xa, ya), gc_b, hog(gray_b, xb, yb)


def choose_patch(P, labels, m, fhat_c, fhat_g, st, x, y, direction, ctx):
    """q* (Sec. 3.2.2): overlap with the left/up (right/down) neighbour patches in
    Lab mean (λ6) and HoG (λ7), plus the epipolar term (λ8). Where S_f is
    unavailable (epipolar term off, or no F for the source) the overlap terms
    are scaled by (W + λ8) / W, W their attainable maximum, as λ3 is in H.
    Near-ties (within tie_tol) go to the candidate whose features are closest to
    the consensus (q̂). Returns (index, score, n_tied)."""
    p = ctx.p
    img, lab, gray, src_lab, src_gray, fc_s, fg_s = st
    H, W = gray.shape
    h = p.patch_size // 2
    nbr_off = [(-1, 0), (0, -1)] if direction > 0 else [(1, 0), (0, 1)]
    scores = {}
    for i, (s, xs, ys, _, _) in enumerate(P):
        if labels[i] != m:
            continue
        sc = 0.0
        wsum = 0.0
        for dx, dy in nbr_off:
            if not (0 <= x + dx < W and 0 <= y + dy < H):
                continue
            region = ((max(-h, dx - h), min(h, dx + h)), (max(-h, dy - h), min(h, dy + h)))
            r = overlap_descriptors(src_lab[s], src_gray[s], xs, ys, lab, gray, x, y, region,
                                    p.hog_bins, p.hog_scale)
            if r is None:
                continue
            gcq, ghq, gcr, ghr = r
            sc += p.lambda6 * S_e(_d2(gcq, gcr), p.sigma_c)
            wsum += p.lambda6
            if p.use_hog:
                sc += p.lambda7 * S_e(_d2(ghq, ghr), p.sigma_h)
                wsum += p.lambda7
        if ctx.has_epipolar(s):
            sc += p.lambda8 * ctx.S_f(s, x, y, xs, ys)
        elif wsum > 0:
            sc = sc * ((wsum + p.lambda8) / wsum)
        scores[i] = sc
    best = max(scores.values())
    tied = [i for i in sorted(scores) if scores[i] >= best - p.tie_tol]
    if len(tied) == 1:
        return tied[0], best, 1

    def dist(i):
        s, xs, ys = P[i][:3]
        return (p.lambda4 * _d2(fhat_c, fc_s[s, ys, xs])
                + p.lambda5 * _d2(fhat_g, fg_s[s, ys, xs].astype(np.float64) * ctx.u))

    d = [dist(i) for i in tied]
    return tied[int(np.argmin(d))], best, len(tied)


def write_patch(img, lab, gray, src_img, src_lab, src_gray, s, qx, qy, x, y, half):
    """Copy the (2·half+1)² window of source s at (qx, qy) onto the reference at (x, y)."""
    H, W = gray.shape
    for v in range(-half, half + 1):
        for u in range(-half, half + 1):
            if 0 <= y + v < H and 0 <= x + u < W and 0 <= qy + v < H and 0 <= qx + u < W:
                img[y + v, x + u] = src_img[s, qy + v, qx + u]
                lab[y + v, x + u] = src_lab[s, qy + v, qx + u]
                gray[y + v, x + u] = src_gray[s, qy + v, qx + u]


def update_correspondences(P, labels, m, nbrs, N, C, fc_r, fg_r, fc_s, fg_s, x, y, ctx):
    """N_{r→s}(x_r) and C_s(x_r) in the three cases of Sec. 3.2.3.

    Case 1: one candidate of s in A_m. Case 2: several; the largest H wins.
    Case 3: none; the smallest Sampson distance (largest S_f) over X = s's
    candidates + the neighbours' own matches. Without F_s there is no geometry
    to choose by: the first of X is taken (the first neighbour's match moved by
    one pixel, i.e. plain propagation). C_s(x_r) = H(x_r, x*, F_s).
    Returns a list of (s, case, new_x, new_y, new_C)."""
    H, W = fc_r.shape[:2]
    out = []
    for s in range(N.shape[0]):
        inA = [q for i, q in enumerate(P) if q[0] == s and labels[i] == m]
        if inA:
            hs = [ctx.H(fc_r, fg_r, x, y, fc_s, fg_s, s, q[1], q[2]) for q in inA]
            j = int(np.argmax(hs))
            new, hv, case = inA[j][1:3], hs[j], (1 if len(inA) == 1 else 2)
        else:
            X = [q[1:3] for q in P if q[0] == s]
            X += [tuple(int(v) for v in N[s, ny, nx]) for nx, ny, _, _ in nbrs
                  if 0 <= N[s, ny, nx, 0] < W and 0 <= N[s, ny, nx, 1] < H]
            if not X:
                continue
            if ctx.hasF[s]:
                new = X[int(np.argmin([sampson_sq(ctx.F[s], x, y, xs, ys) for xs, ys in X]))]
            else:
                new = X[0]
            hv, case = ctx.H(fc_r, fg_r, x, y, fc_s, fg_s, s, new[0], new[1]), 3
        N[s, y, x] = new
        C[s, y, x] = hv
        out.append((s, case, int(new[0]), int(new[1]), float(np.float32(hv))))
    return out


def scan_rows(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s,
              N, C, F, hasF, L, Mmap, Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s,
              use_pre, preM, preB, preK, dirty, params: Params, scan, direction, r0, r1, rec,
              dec_i, dec_f, dec_cs, dec_cxy, dec_cB, dec_ccl,
              rep_i, rep_f, upd_i, upd_f, counts, stats, *, sift_unit, sample_rate=0.0):
    """Rows r0..r1−1 of one scan, Algorithm 1; the kernel's state, buffers and
    events, with the parameters read from ``params`` by name. The kernel's cached
    gradient bins (hb_*, hm_*) and precomputed decisions (use_pre, pre*, dirty)
    are ignored: every pixel is computed here, the HoG from ``gray``."""
    ctx = _Ctx(params, sift_unit, F, hasF)
    H, W = gray.shape
    for vi in range(r0, r1):
        y = vi if direction > 0 else H - 1 - vi
        for xi in range(W):
            x = xi if direction > 0 else W - 1 - xi
            step = scan * H * W + vi * W + xi
            P, nbrs = candidates(N, C, x, y, direction, H, W, as_set=params.candidate_set)
            labels = cluster(P, fc_s, fg_s, ctx) if P else np.zeros(0, int)
            m, bm, fhat_c, fhat_g, M, cdist = decide(P, labels, fc_r, fg_r, fc_s, fg_s, x, y, ctx)
            if m < 0:
                stats[2] += 1
            Mmap[y, x] = M
            Bmap[y, x] = bm
            win = [P[i][0] for i in range(len(P)) if m >= 0 and labels[i] == m]
            Kmap[y, x] = (len(P), int(labels.max()) + 1 if len(P) else 0, len(win),
                          sum(1 << s for s in set(win)))
            dynamic = m >= 0 and M <= params.t_r
            chosen = -1
            if dynamic:
                stats[0] += 1
                L[y, x] = 1
                i, score, ntie = choose_patch(P, labels, m, fhat_c, fhat_g,
                                              (img, lab, gray, src_lab, src_gray, fc_s, fg_s),
                                              x, y, direction, ctx)
                s, qx, qy = P[i][:3]
                chosen = s
                half = params.patch_size // 2 if params.write == "patch" else 0
                write_patch(img, lab, gray, src_img, src_lab, src_gray, s, qx, qy, x, y, half)
                fc_r[y, x] = fc_s[s, qy, qx]
                fg_r[y, x] = fg_s[s, qy, qx]
                stats[1] += 1
                if rec:
                    e = counts[1]
                    rep_i[e] = (scan, step, x, y, s, qx, qy, int(ntie > 1), ntie)
                    rep_f[e] = score
                    counts[1] = e + 1
                if params.update:
                    for (t, case, nx, ny, hv) in update_correspondences(
                            P, labels, m, nbrs, N, C, fc_r, fg_r, fc_s, fg_s, x, y, ctx):
                        if rec:
                            e = counts[2]
                            upd_i[e] = (scan, step, x, y, t, case, nx, ny)
                            upd_f[e] = hv
                            counts[2] = e + 1
            if rec:
                why = (1 if dynamic else 0) | (2 if probe[y, x] else 0)
                if why == 0 and sample_rate > 0:
                    hsh = ((x * 73856093) ^ (y * 19349663) ^ (scan * 83492791)) % (2 ** 64)
                    if float(hsh % 1000003) < sample_rate * 1000003.0:
                        why |= 4
                if why:
                    e = counts[0]
                    k = int(labels.max()) + 1 if len(P) else 0
                    dec_i[e] = (scan, step, x, y, why, len(P), m, k, chosen, int(dynamic))
                    dec_f[e] = (M, bm, cdist)
                    dec_cs[e], dec_cxy[e], dec_cB[e], dec_ccl[e] = -1, -1, 0.0, -1
                    for i, (s, xs, ys, b, slot) in enumerate(P):
                        dec_cs[e, slot], dec_cxy[e, slot] = s, (xs, ys)
                        dec_cB[e, slot], dec_ccl[e, slot] = b, labels[i]
                    counts[0] = e + 1

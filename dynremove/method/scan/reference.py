"""Readable reference of the scan (Sec. 3.2), one function per paragraph.

Slow (pure Python + numpy + ``sklearn.cluster.DBSCAN(metric="precomputed")``)
and meant for small images: tests assert that the compiled kernel
(``_kernels._scan_rows``) gives the same labels, pixels, N, C and events.
``scan_rows`` has the kernel's signature so the driver can call either.
"""

from __future__ import annotations

import math

import numpy as np
from sklearn.cluster import DBSCAN

from dynremove.method.scan import _kernels as kn


def S_e(d2: float, sigma: float) -> float:
    """S_e(f1, f2, σ) = exp(−‖f1 − f2‖² / 2σ²), from the squared distance."""
    return math.exp(-d2 / (2.0 * sigma * sigma))


def sampson_sq(F: np.ndarray, xr: float, yr: float, xs: float, ys: float) -> float:
    """Squared Sampson distance (px²) with x_sᵀ F x_r = 0."""
    a = F[0, 0] * xr + F[0, 1] * yr + F[0, 2]  # F x_r
    b = F[1, 0] * xr + F[1, 1] * yr + F[1, 2]
    c = F[2, 0] * xr + F[2, 1] * yr + F[2, 2]
    ta = F[0, 0] * xs + F[1, 0] * ys + F[2, 0]  # Fᵀ x_s
    tb = F[0, 1] * xs + F[1, 1] * ys + F[2, 1]
    e = xs * a + ys * b + c
    return e * e / max(a * a + b * b + ta * ta + tb * tb, 1e-300)


class _Ctx:
    """The kernel's packed arguments under readable names."""

    def __init__(self, pf, pi, F, hasF):
        self.pf, self.pi, self.F, self.hasF = pf, pi, F, hasF
        self.lam = {k: pf[getattr(kn, f"LAM{k}")] for k in range(1, 9)}
        self.u = pf[kn.SIFT_UNIT]

    def S_f(self, s, xr, yr, xs, ys):
        """S_f = exp(−d_s / 2σ_e²), Sampson distance in coordinate units."""
        if not self.hasF[s]:
            return 0.0
        cs, se = self.pf[kn.COORD_SCALE], self.pf[kn.SIG_E]
        d = sampson_sq(self.F[s], xr, yr, xs, ys) / (cs * cs)
        return math.exp(-d / (2.0 * se * se))

    def sift_d2(self, a, b):
        return float(np.sum((a.astype(np.int64) - b.astype(np.int64)) ** 2)) * self.u * self.u

    def H(self, fc_r, fg_r, x, y, fc_s, fg_s, s, xs, ys):
        """H(x_r, x, F_s): λ1 S_e(f_c) + λ2 S_e(f_g) + λ3 S_f (Sec. 3.2.3)."""
        l1, l2, l3 = self.lam[1], self.lam[2], self.lam[3]
        sc = S_e(_d2(fc_r[y, x], fc_s[s, ys, xs]), self.pf[kn.SIG_C])
        sg = S_e(self.sift_d2(fg_r[y, x], fg_s[s, ys, xs]), self.pf[kn.SIG_G])
        if self.pi[kn.USE_EPI] and self.hasF[s]:
            return l1 * sc + l2 * sg + l3 * self.S_f(s, x, y, xs, ys)
        return (l1 * sc + l2 * sg) * (l1 + l2 + l3) / (l1 + l2)


def _d2(a, b) -> float:
    t = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return float(np.sum(t * t))  # sequential for short vectors, as the kernel sums


def candidates(N, C, x, y, direction, H, W):
    """P and B (Sec. 3.2.1): each source's matches of the left/up (right/down)
    neighbours moved by one pixel towards x_r, with the neighbours' confidences.

    Returns a list of (s, xs, ys, B, slot) and the neighbours used.
    """
    off = [(-1, 0), (0, -1)] if direction > 0 else [(1, 0), (0, 1)]
    nbrs = [(x + dx, y + dy, -dx, -dy) for dx, dy in off if 0 <= x + dx < W and 0 <= y + dy < H]
    P = []
    for s in range(N.shape[0]):
        if not nbrs:  # first pixel of a scan: its own match
            mx, my = N[s, y, x]
            if 0 <= mx < W and 0 <= my < H:
                P.append((s, int(mx), int(my), float(C[s, y, x]), 2 * s))
        for a, (nx, ny, ox, oy) in enumerate(nbrs):
            mx, my = N[s, ny, nx, 0] + ox, N[s, ny, nx, 1] + oy
            if 0 <= mx < W and 0 <= my < H:
                P.append((s, int(mx), int(my), float(C[s, ny, nx]), 2 * s + a))
    return P, nbrs


def cluster(P, fc_s, fg_s, ctx):
    """DBSCAN on the distance B(x1, x2) of Eq. (DB_cost); labels (−1 = noise)."""
    n = len(P)
    D = np.zeros((n, n))
    for i in range(n):
        D[i, i] = 1.0 - ctx.pf[kn.LAM4] - ctx.pf[kn.LAM5]
        for j in range(i + 1, n):
            si, xi, yi = P[i][:3]
            sj, xj, yj = P[j][:3]
            d = (1.0 - ctx.pf[kn.LAM4] * S_e(_d2(fc_s[si, yi, xi], fc_s[sj, yj, xj]), ctx.pf[kn.SIG_C])
                 - ctx.pf[kn.LAM5] * S_e(ctx.sift_d2(fg_s[si, yi, xi], fg_s[sj, yj, xj]), ctx.pf[kn.SIG_G]))
            D[i, j] = D[j, i] = d
    db = DBSCAN(eps=ctx.pf[kn.EPS], min_samples=int(ctx.pi[kn.MIN_PTS]), metric="precomputed")
    return db.fit(D).labels_


def decide(P, labels, fc_r, fg_r, fc_s, fg_s, x, y, ctx):
    """Winning cluster A_m (largest Σ B), consensus (f̂_c, f̂_g) and M(x_r), Eq. (M)."""
    k = int(labels.max()) + 1 if len(labels) else 0
    if k == 0:
        return -1, 0.0, None, None, float("nan"), float("nan")
    B = np.array([p[3] for p in P])
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
    M = ctx.pf[kn.LAM4] * S_e(dc, ctx.pf[kn.SIG_C]) + ctx.pf[kn.LAM5] * S_e(dg, ctx.pf[kn.SIG_G])
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
    Lab mean and HoG, plus the epipolar term; near-ties go to the candidate whose
    features are closest to the consensus. Returns (index, score, n_tied)."""
    img, lab, gray, src_lab, src_gray, fc_s, fg_s = st
    H, W = gray.shape
    h = int(ctx.pi[kn.P]) // 2
    nb = int(ctx.pi[kn.HOG_BINS])
    nbr_off = [(-1, 0), (0, -1)] if direction > 0 else [(1, 0), (0, 1)]
    scores = {}
    for i, (s, xs, ys, _, _) in enumerate(P):
        if labels[i] != m:
            continue
        sc = 0.0
        for dx, dy in nbr_off:
            if not (0 <= x + dx < W and 0 <= y + dy < H):
                continue
            region = ((max(-h, dx - h), min(h, dx + h)), (max(-h, dy - h), min(h, dy + h)))
            r = overlap_descriptors(src_lab[s], src_gray[s], xs, ys, lab, gray, x, y, region,
                                    nb, ctx.pf[kn.HOG_SCALE])
            if r is None:
                continue
            gcq, ghq, gcr, ghr = r
            sc += ctx.lam[6] * S_e(_d2(gcq, gcr), ctx.pf[kn.SIG_C])
            if ctx.pi[kn.USE_HOG]:
                sc += ctx.lam[7] * S_e(_d2(ghq, ghr), ctx.pf[kn.SIG_H])
        if ctx.pi[kn.USE_EPI]:
            sc += ctx.lam[8] * ctx.S_f(s, x, y, xs, ys)
        scores[i] = sc
    best = max(scores.values())
    tied = [i for i in sorted(scores) if scores[i] >= best - ctx.pf[kn.TIE_TOL]]
    if len(tied) == 1:
        return tied[0], best, 1

    def dist(i):
        s, xs, ys = P[i][:3]
        return (ctx.pf[kn.LAM4] * _d2(fhat_c, fc_s[s, ys, xs])
                + ctx.pf[kn.LAM5] * _d2(fhat_g, fg_s[s, ys, xs].astype(np.float64) * ctx.u))

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

    Returns a list of (s, case, new_x, new_y, new_C)."""
    H, W = fc_r.shape[:2]
    out = []
    for s in range(N.shape[0]):
        inA = [p for i, p in enumerate(P) if p[0] == s and labels[i] == m]
        if inA:
            hs = [ctx.H(fc_r, fg_r, x, y, fc_s, fg_s, s, p[1], p[2]) for p in inA]
            j = int(np.argmax(hs))
            new, hv, case = inA[j][1:3], hs[j], (1 if len(inA) == 1 else 2)
        else:
            X = [p[1:3] for p in P if p[0] == s]
            X += [tuple(int(v) for v in N[s, ny, nx]) for nx, ny, _, _ in nbrs
                  if 0 <= N[s, ny, nx, 0] < W and 0 <= N[s, ny, nx, 1] < H]
            if not X:
                continue
            d = [sampson_sq(ctx.F[s], x, y, xs, ys) if ctx.hasF[s] else 0.0 for xs, ys in X]
            new = X[int(np.argmin(d))]
            hv, case = ctx.H(fc_r, fg_r, x, y, fc_s, fg_s, s, new[0], new[1]), 3
        N[s, y, x] = new
        C[s, y, x] = hv
        out.append((s, case, int(new[0]), int(new[1]), float(np.float32(hv))))
    return out


def scan_rows(img, lab, gray, fc_r, fg_r, src_img, src_lab, src_gray, fc_s, fg_s,
              N, C, F, hasF, L, Mmap, probe, pf, pi, scan, direction, r0, r1, rec,
              dec_i, dec_f, dec_cs, dec_cxy, dec_cB, dec_ccl,
              rep_i, rep_f, upd_i, upd_f, counts, stats):
    """Rows r0..r1−1 of one scan, Algorithm 1; same contract as the kernel."""
    ctx = _Ctx(pf, pi, F, hasF)
    H, W = gray.shape
    K = 2 * N.shape[0]
    for vi in range(r0, r1):
        y = vi if direction > 0 else H - 1 - vi
        for xi in range(W):
            x = xi if direction > 0 else W - 1 - xi
            step = scan * H * W + vi * W + xi
            P, nbrs = candidates(N, C, x, y, direction, H, W)
            labels = cluster(P, fc_s, fg_s, ctx) if P else np.zeros(0, int)
            m, bm, fhat_c, fhat_g, M, cdist = decide(P, labels, fc_r, fg_r, fc_s, fg_s, x, y, ctx)
            if m < 0:
                stats[2] += 1
            Mmap[y, x] = M
            dynamic = m >= 0 and M <= pf[kn.T_R]
            chosen = -1
            if dynamic:
                stats[0] += 1
                L[y, x] = 1
                i, score, ntie = choose_patch(P, labels, m, fhat_c, fhat_g,
                                              (img, lab, gray, src_lab, src_gray, fc_s, fg_s),
                                              x, y, direction, ctx)
                s, qx, qy = P[i][:3]
                chosen = s
                half = int(pi[kn.P]) // 2 if pi[kn.WRITE_PATCH] else 0
                write_patch(img, lab, gray, src_img, src_lab, src_gray, s, qx, qy, x, y, half)
                fc_r[y, x] = fc_s[s, qy, qx]
                fg_r[y, x] = fg_s[s, qy, qx]
                stats[1] += 1
                if rec:
                    e = counts[1]
                    rep_i[e] = (scan, step, x, y, s, qx, qy, int(ntie > 1), ntie)
                    rep_f[e] = score
                    counts[1] = e + 1
                if pi[kn.UPDATE]:
                    for (t, case, nx, ny, hv) in update_correspondences(
                            P, labels, m, nbrs, N, C, fc_r, fg_r, fc_s, fg_s, x, y, ctx):
                        if rec:
                            e = counts[2]
                            upd_i[e] = (scan, step, x, y, t, case, nx, ny)
                            upd_f[e] = hv
                            counts[2] = e + 1
            if rec:
                why = (1 if dynamic else 0) | (2 if probe[y, x] else 0)
                if why == 0 and pf[kn.SAMPLE_RATE] > 0:
                    hsh = ((x * 73856093) ^ (y * 19349663) ^ (scan * 83492791)) % (2 ** 64)
                    if float(hsh % 1000003) < pf[kn.SAMPLE_RATE] * 1000003.0:
                        why |= 4
                if why:
                    e = counts[0]
                    dec_i[e] = (scan, step, x, y, why, len(P), m, (labels.max() + 1) if len(P) else 0,
                                chosen, int(dynamic))
                    dec_f[e] = (M, bm, cdist)
                    dec_cs[e], dec_cxy[e], dec_cB[e], dec_ccl[e] = -1, -1, 0.0, -1
                    for i, (s, xs, ys, b, slot) in enumerate(P):
                        dec_cs[e, slot], dec_cxy[e, slot] = s, (xs, ys)
                        dec_cB[e, slot], dec_ccl[e, slot] = b, labels[i]
                    counts[0] = e + 1
    assert K == dec_cs.shape[1] or not rec

"""The hidden background's matches by a plane + parallax sweep (default preset).

Inside L the reference shows the mover, so its matches in the sources cannot
be measured there. ``fields.background_field`` interpolates them across L as a
membrane, which is right for a plane and wrong for 3-D structure hidden behind
the mover (a balcony in front of a wall lands tens of pixels off, and the fill
is doubled). This module recovers it from the sources themselves:

1. **Plane + parallax** (Irani & Anandan, *Parallax geometry of pairs of
   points*, 1996; Sawhney, *3D geometry from planar parallax*, CVPR 1994). In
   source s a reference pixel x_r matches on its epipolar line l_s = F_s x̃_r,
   at h_s(x_r) (the homography H_s's point moved onto l_s) plus a parallax
   t_s along the line. For a static point t_s = k_s γ(x_r) + a_s x + b_s y + c_s:
   one scalar γ per pixel (its depth relative to a plane) shared by every
   source, up to each source's scale k_s and an affine term (each H_s may be
   induced by a different plane). k_s, a_s, b_s, c_s are fitted robustly on
   the visible pixels' flow matches, with γ measured in the source of widest
   parallax.
2. **Sweep** (plane sweep, Collins, CVPR 1996). For each γ of a range, every
   source is sampled at its match and the cost is the mean CIE76 distance
   (capped) of the sources to their per-channel median: the right depth is
   where the sources agree. Costs are computed at half resolution.
3. **Semi-global matching** (Hirschmüller, *Stereo processing by semiglobal
   matching and mutual information*, PAMI 2008) over 4 paths regularises γ,
   which is then upsampled. Pixels where the sources never agree keep the
   membrane field.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np
import numpy.typing as npt

from dynremove.method.geometry import TwoView, sampson_sq
from dynremove.refine.colour import delta_e
from dynremove.refine.fields import remap_points

_CAP = 30.0  # ΔE cap of one source's distance to the median in the sweep cost
SEARCH_CAP_DE = _CAP  # ... and of ``epipolar_search``'s cost: "nothing alike"


@dataclass(frozen=True)
class ParallaxModel:
    """Per-source μ_s = k γ + a x/W + b y/H + c, with x_s ~ H_s x̃_r + μ_s ẽ_s."""

    coef: npt.NDArray[np.float64]  # (S, 4): k, a, b, c; rows of NaN where not fitted
    anchor: int  # the source whose μ defines γ
    mad_px: npt.NDArray[np.float64]  # (S,) median reprojection residual of the fit (px)
    gamma_range: tuple[float, float]  # γ over the visible pixels (0.5, 99.5 percentiles)


def epipole(F: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The epipole ẽ_s in the source (F_sᵀ ẽ_s = 0), unit norm, (3,) float64."""
    _, _, vt = np.linalg.svd(F.T)
    e = vt[-1]
    return e / np.linalg.norm(e)


def project(Hm, e, mu, gx, gy):
    """x_s = π(H x̃ + μ ẽ) for reference pixel coordinates gx, gy: (x, y) float32 each."""
    px = Hm[0, 0] * gx + Hm[0, 1] * gy + Hm[0, 2] + mu * e[0]
    py = Hm[1, 0] * gx + Hm[1, 1] * gy + Hm[1, 2] + mu * e[1]
    pw = Hm[2, 0] * gx + Hm[2, 1] * gy + Hm[2, 2] + mu * e[2]
    pw = np.where(np.abs(pw) < 1e-9, 1e-9, pw)
    return (px / pw).astype(np.float32), (py / pw).astype(np.float32)


def line_points(view: TwoView, mu: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """Where ``epipolar_search``'s best μ lands in the source: x_s = π(H x̃ + μ ẽ).

    Parameters
    ----------
    view : TwoView
        With F (the epipole ẽ) and H; without F every point is NaN.
    mu : (H, W) float32 ndarray
        ``epipolar_search``'s μ (NaN where not searched).

    Returns
    -------
    (H, W, 2) float32 ndarray
        (x, y) in the source's pixels, NaN where ``mu`` is.
    """
    out = np.full(mu.shape + (2,), np.nan, np.float32)
    ok = np.isfinite(mu)
    if view.F is None or not ok.any():
        return out
    ys, xs = np.nonzero(ok)
    px, py = project(view.H, epipole(view.F), mu[ok].astype(np.float64),
                     xs.astype(np.float64), ys.astype(np.float64))
    out[ys, xs, 0], out[ys, xs, 1] = px, py
    return out


@numba.njit(cache=True, nogil=True)
def _project_steps(Hm, e, mu, gx, gy):
    """``project(Hm, e, mu[:, None], gx[None], gy[None])`` compiled: (k, n) float32
    x and y for k values of μ (float64) at n points (float64), the same arithmetic
    in the same order (bit for bit: ``test_parallax``), without its (k, n)
    float64 temporaries."""
    k, n = mu.shape[0], gx.shape[0]
    fx = np.empty((k, n), np.float32)
    fy = np.empty((k, n), np.float32)
    for j in range(n):
        bx = Hm[0, 0] * gx[j] + Hm[0, 1] * gy[j] + Hm[0, 2]
        by = Hm[1, 0] * gx[j] + Hm[1, 1] * gy[j] + Hm[1, 2]
        bw = Hm[2, 0] * gx[j] + Hm[2, 1] * gy[j] + Hm[2, 2]
        for i in range(k):
            px = bx + mu[i] * e[0]
            py = by + mu[i] * e[1]
            pw = bw + mu[i] * e[2]
            if abs(pw) < 1e-9:
                pw = 1e-9
            fx[i, j] = np.float32(px / pw)
            fy[i, j] = np.float32(py / pw)
    return fx, fy


def _mu_of(Hm, e, gx, gy, xs, ys):
    """μ with x̃_s × (H x̃ + μ ẽ) = 0 in the least-squares sense (closed form)."""
    p = np.stack([Hm[0, 0] * gx + Hm[0, 1] * gy + Hm[0, 2],
                  Hm[1, 0] * gx + Hm[1, 1] * gy + Hm[1, 2],
                  Hm[2, 0] * gx + Hm[2, 1] * gy + Hm[2, 2]], -1)
    xt = np.stack([xs, ys, np.ones_like(xs)], -1).astype(np.float64)
    a = np.cross(xt, p)
    b = np.cross(xt, np.broadcast_to(e, xt.shape))
    return -(a * b).sum(-1) / np.maximum((b * b).sum(-1), 1e-18)


def fit_parallax(fields: list[np.ndarray], views: list[TwoView], visible: np.ndarray, *,
                 line_px: float = 1.5, max_samples: int = 40000, seed: int = 0,
                 min_depth_px: float = 3.0) -> ParallaxModel | None:
    """Fit each source's parallax to a common γ on the visible pixels.

    fields: per source (H, W, 2) float32 flow matches; views: the TwoView per
    source (H_s, F_s); visible (H, W) bool: pixels whose matches are trusted
    (outside L). A match counts only within ``line_px`` (Sampson) of its epipolar
    line. μ_s of every match is solved in closed form; γ is the μ of the source
    of widest parallax (the 90th percentile of its matches' distance from the
    homography); k, a, b, c by iteratively reweighted least squares.
    The residual is measured in pixels, by reprojection. None when fewer than
    two sources have F, or when the visible parallax departs from a plane's by
    less than ``min_depth_px`` (90th percentile, in the anchor source): then
    k_s cannot be told from the affine term.
    """
    S = len(fields)
    Hh, Ww = visible.shape
    rng = np.random.default_rng(seed)
    ys, xs = np.nonzero(visible)
    if len(ys) > max_samples:
        pick = np.sort(rng.choice(len(ys), max_samples, replace=False))
        ys, xs = ys[pick], xs[pick]
    gx, gy = xs.astype(np.float64), ys.astype(np.float64)
    mu, ok, spread = {}, {}, {}
    for k in range(S):
        v = views[k]
        if v.F is None:
            continue
        e = epipole(v.F)
        m = fields[k][ys, xs].astype(np.float64)
        good = sampson_sq(v.F, np.stack([gx, gy], -1), m) <= line_px ** 2
        if good.sum() < 500:
            continue
        ok[k] = good
        mu[k] = _mu_of(v.H, e, gx, gy, m[:, 0], m[:, 1])
        hx, hy = project(v.H, e, 0.0, gx, gy)
        # a high percentile: the median sits on the dominant plane (where the
        # homography holds) for every source, so there it measures noise
        spread[k] = float(np.percentile(np.hypot(m[:, 0] - hx, m[:, 1] - hy)[good], 90))
    if len(mu) < 2:
        return None
    anchor = max(mu, key=lambda k: spread[k])
    G = mu[anchor]
    coef = np.full((S, 4), np.nan)
    mad = np.full(S, np.inf)
    for k in mu:
        sel = ok[k] & ok[anchor]
        if sel.sum() < 500:
            continue
        A = np.c_[G[sel], xs[sel] / Ww, ys[sel] / Hh, np.ones(int(sel.sum()))]
        y = mu[k][sel]
        w = np.ones(len(y))
        for _ in range(5):
            c = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
            r = y - A @ c
            sc = 1.4826 * np.median(np.abs(r)) + 1e-12
            w = 1.0 / np.maximum(1.0, np.abs(r) / (2.0 * sc))
        coef[k] = c
        px, py = project(views[k].H, epipole(views[k].F), A @ c, gx[sel], gy[sel])
        m = fields[k][ys[sel], xs[sel]]
        mad[k] = float(np.median(np.hypot(px - m[:, 0], py - m[:, 1])))
    # identifiability: the anchor's γ must depart from an affine function of
    # (x, y), or k_s cannot be told from the affine term (a plane's γ is affine)
    sa = ok[anchor]
    A = np.c_[xs[sa] / Ww, ys[sa] / Hh, np.ones(int(sa.sum()))]
    ca = np.linalg.lstsq(A, G[sa], rcond=None)[0]
    e_a = epipole(views[anchor].F)
    p0 = project(views[anchor].H, e_a, A @ ca, gx[sa], gy[sa])
    p1 = project(views[anchor].H, e_a, G[sa], gx[sa], gy[sa])
    if np.percentile(np.hypot(p1[0] - p0[0], p1[1] - p0[1]), 90) < min_depth_px:
        return None
    lo, hi = np.percentile(G[ok[anchor]], [0.5, 99.5])
    return ParallaxModel(coef=coef, anchor=anchor, mad_px=mad, gamma_range=(float(lo), float(hi)))


@numba.njit(cache=True, nogil=True)
def sgm(cost, P1, P2):
    """Semi-global matching over 4 paths (Hirschmüller 2008).

    cost (h, w, D) float32 → aggregated (h, w, D) float32; the argmin over D is
    the regularised label. P1: penalty of a ±1 label change, P2 of a larger one.
    """
    h, w, D = cost.shape
    agg = np.zeros((h, w, D), np.float32)
    Lr = np.empty(D, np.float32)
    prev = np.empty(D, np.float32)
    for path in range(4):
        if path < 2:
            n_lines, n_len = h, w
        else:
            n_lines, n_len = w, h
        for line in range(n_lines):
            for i in range(n_len):
                j = i if path % 2 == 0 else n_len - 1 - i
                if path < 2:
                    y, x = line, j
                else:
                    y, x = j, line
                if i == 0:
                    for d in range(D):
                        Lr[d] = cost[y, x, d]
                else:
                    mp = prev[0]
                    for d in range(1, D):
                        if prev[d] < mp:
                            mp = prev[d]
                    for d in range(D):
                        v = prev[d]
                        if d > 0 and prev[d - 1] + P1 < v:
                            v = prev[d - 1] + P1
                        if d < D - 1 and prev[d + 1] + P1 < v:
                            v = prev[d + 1] + P1
                        if mp + P2 < v:
                            v = mp + P2
                        Lr[d] = cost[y, x, d] + v - mp
                for d in range(D):
                    agg[y, x, d] += Lr[d]
                    prev[d] = Lr[d]
    return agg


def sweep_fields(src_labs: list[np.ndarray], views: list[TwoView], model: ParallaxModel,
                 hole: np.ndarray, base: list[np.ndarray], *, step_px: float = 1.0,
                 scale: float = 0.5, P1: float = 1.0, P2: float = 8.0,
                 box: int = 3, prior: float = 2.0, prior_px: float = 8.0,
                 margin: float = 1.0, max_mad_px: float = 2.0, max_steps: int = 256
                 ) -> tuple[list[np.ndarray], np.ndarray]:
    """Fields of the hidden background inside ``hole`` by the sweep + SGM.

    src_labs: per source (H, W, 3) float32 Lab; views: TwoView per source; base:
    per source (H, W, 2) float32, the fields to start from (kept outside ``hole``,
    and for sources without a model or whose model's median residual exceeds
    ``max_mad_px``). γ is swept in steps of about ``step_px`` of the anchor
    source's image, over the visible range widened by 10 % each side.
    Where the colours cannot tell depths apart (flat or repetitive texture),
    the base field wins: a cost of ``prior`` · min(|Δ| / ``prior_px``, 1), Δ the
    anchor's displacement from the base field's γ, and the sweep's γ is used
    only where its colour cost (7×7 window of the coarse grid) beats the base
    field's by more than ``margin`` (ΔE).
    Returns (fields, gamma): the new fields and γ (H, W) float32 (NaN outside
    the hole or where the base field was kept). Costs at ``scale`` of the hole's box.
    """
    Hh, Ww = hole.shape
    S = len(base)
    use = [k for k in range(S) if views[k].F is not None and np.isfinite(model.coef[k, 0])
           and model.mad_px[k] <= max_mad_px]
    gamma = np.full((Hh, Ww), np.nan, np.float32)
    a = model.anchor
    if len(use) < 2 or a not in use or not hole.any():
        return [b.copy() for b in base], gamma
    ys, xs = np.nonzero(hole)
    y0, y1 = int(ys.min()), int(ys.max()) + 1
    x0, x1 = int(xs.min()), int(xs.max()) + 1
    hh, ww = max(1, int(round((y1 - y0) * scale))), max(1, int(round((x1 - x0) * scale)))
    cy = y0 + (np.arange(hh) + 0.5) * (y1 - y0) / hh - 0.5
    cx = x0 + (np.arange(ww) + 0.5) * (x1 - x0) / ww - 0.5
    CX, CY = (g.astype(np.float64) for g in np.meshgrid(cx, cy))
    eps = {k: epipole(views[k].F) for k in use}
    lo, hi = model.gamma_range
    span = max(hi - lo, 1e-9)
    lo, hi = lo - 0.1 * span, hi + 0.1 * span
    # γ → px of the anchor, at the hole's centre
    xc, yc = np.array([(x0 + x1) / 2.0]), np.array([(y0 + y1) / 2.0])
    pa = project(views[a].H, eps[a], np.array([lo, hi]), xc, yc)
    span_px = float(np.hypot(pa[0][1] - pa[0][0], pa[1][1] - pa[1][0]))
    n_steps = int(np.clip(np.ceil(span_px / step_px) + 1, 2, max_steps))
    steps = np.linspace(lo, hi, n_steps)
    px_per_gamma = span_px / (hi - lo)
    bx = cv2.remap(base[a], CX.astype(np.float32), CY.astype(np.float32), cv2.INTER_LINEAR,
                   borderMode=cv2.BORDER_REPLICATE)
    g_base = _mu_of(views[a].H, eps[a], CX, CY, bx[..., 0].astype(np.float64),
                    bx[..., 1].astype(np.float64))
    n = len(use)
    aff = [model.coef[k, 1] * CX / Ww + model.coef[k, 2] * CY / Hh + model.coef[k, 3]
           for k in use]
    cost = np.empty((hh, ww, n_steps), np.float32)
    labs = np.empty((n, hh, ww, 3), np.float32)
    inside = np.empty((n, hh, ww), bool)
    pen = np.empty((hh, ww), np.float32)
    for i, g in enumerate(steps):
        for j, k in enumerate(use):
            fx, fy = project(views[k].H, eps[k], model.coef[k, 0] * g + aff[j], CX, CY)
            labs[j] = cv2.remap(src_labs[k], fx, fy, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
            inside[j] = (fx >= 0) & (fx <= Ww - 1) & (fy >= 0) & (fy <= Hh - 1)
        med = np.median(labs, axis=0)
        dE = np.minimum(delta_e(labs, med), _CAP)
        c = np.where(inside, dE, _CAP).mean(0)
        pen[:] = prior * np.minimum(np.abs(g - g_base) * px_per_gamma / prior_px, 1.0)
        c += pen
        cost[..., i] = cv2.boxFilter(c, -1, (box, box)) if box > 1 else c
    agg = sgm(cost, np.float32(P1), np.float32(P2))
    ib = np.argmin(agg, axis=-1)
    best = steps[ib]
    keep_base = np.zeros((hh, ww), bool)
    if margin > 0:
        i0 = np.clip(np.rint((g_base - lo) / (hi - lo) * (n_steps - 1)), 0, n_steps - 1
                     ).astype(np.intp)
        c_best = np.take_along_axis(cost, ib[..., None], -1)[..., 0]
        c_base = np.take_along_axis(cost, i0[..., None], -1)[..., 0]
        keep_base = cv2.boxFilter(c_base - c_best, -1, (7, 7)) <= margin
    # back to full size on the hole's box (γ and where the base field is kept)
    gb = cv2.resize(best.astype(np.float32), (x1 - x0, y1 - y0),
                    interpolation=cv2.INTER_LINEAR)
    kb = cv2.resize(keep_base.astype(np.uint8), (x1 - x0, y1 - y0),
                    interpolation=cv2.INTER_NEAREST).astype(bool)
    sub = hole[y0:y1, x0:x1] & ~kb
    gamma[y0:y1, x0:x1][sub] = gb[sub]
    gxf, gyf = (g.astype(np.float64) for g in np.meshgrid(np.arange(x0, x1), np.arange(y0, y1)))
    out = []
    for k in range(S):
        f = base[k].copy()
        if k in use and sub.any():
            c = model.coef[k]
            mu = c[0] * gb + c[1] * gxf / Ww + c[2] * gyf / Hh + c[3]
            fx, fy = project(views[k].H, eps[k], mu, gxf, gyf)
            f[y0:y1, x0:x1, 0][sub] = fx[sub]
            f[y0:y1, x0:x1, 1][sub] = fy[sub]
        out.append(f)
    return out, gamma


def flow_mu_range(view: TwoView, field: np.ndarray, visible: np.ndarray, *,
                  line_px: float = 1.5) -> tuple[float, float] | None:
    """The range of μ that ``epipolar_search`` sweeps: the μ of the visible flow
    matches within ``line_px`` (Sampson) of their epipolar lines, 1st–99th
    percentile, widened by 10 % of its span on each side.

    field : (H, W, 2) float32 flow matches; visible : (H, W) bool (at most 40 000
    of its pixels are sampled). None without F or with fewer than 200 such matches.
    """
    if view.F is None:
        return None
    e = epipole(view.F)
    ys, xs = np.nonzero(visible)
    if len(ys) > 40000:
        pick = np.random.default_rng(0).choice(len(ys), 40000, replace=False)
        ys, xs = ys[pick], xs[pick]
    gx, gy = xs.astype(np.float64), ys.astype(np.float64)
    m = field[ys, xs].astype(np.float64)
    good = sampson_sq(view.F, np.stack([gx, gy], -1), m) <= line_px ** 2
    if good.sum() < 200:
        return None
    mus = _mu_of(view.H, e, gx[good], gy[good], m[good, 0], m[good, 1])
    lo, hi = np.percentile(mus, [1, 99])
    span = max(hi - lo, 1e-9)
    return float(lo - 0.1 * span), float(hi + 0.1 * span)


def keypoint_windows(mu: np.ndarray, lo: float, hi: float, *, min_keypoints: int = 2,
                     floor: float = 4.0, frac: float = 0.1) -> list[tuple[float, float]]:
    """The stretches of μ around keypoints beyond the flow's range [lo, hi].

    mu : (n,) float64, the keypoints' μ, all outside [lo, hi]. Each keypoint's
    window is its μ ± max(``floor``, ``frac`` × its distance from the range); a
    window counts where at least ``min_keypoints`` keypoints lie in it (one
    keypoint matched wrongly, anywhere on its epipolar line, opens none);
    overlapping windows are merged. Returns sorted (lo, hi) pairs.
    """
    mu = np.sort(np.asarray(mu, np.float64))
    half = np.maximum(floor, frac * np.where(mu < lo, lo - mu, mu - hi))
    wins = [(m - w, m + w) for m, w in zip(mu, half)
            if np.count_nonzero(np.abs(mu - m) <= w) >= min_keypoints]
    merged: list[list[float]] = []
    for a, b in sorted(wins):
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    return [(float(a), float(b)) for a, b in merged]


def search_beyond(lab_r: np.ndarray, lab_s: np.ndarray, view: TwoView, field: np.ndarray,
                  visible: np.ndarray, region: np.ndarray, *, ring_px: int,
                  min_keypoints: int = 2, support_de: float = 0.0,
                  line_px: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """``epipolar_search`` beyond the flow's range of μ, where the keypoints
    around a region show that the scene reaches there.

    The dense flow does not follow parallax of hundreds of pixels (a bollard or
    a sign near the camera), so ``flow_mu_range`` leaves such depths out of the
    search and static structure there is found on no line. The keypoint matches
    that are inliers of F (``TwoView.inlier_xy_r``, ``inlier_xy_s``) measure
    them. For each connected part of ``region`` (parts within 16 px of each other
    joined), the μ of the inliers beyond the flow's range that lie in ``visible``
    within ``ring_px`` of the part are taken, and the line is searched in the
    windows around them that at least ``min_keypoints`` of them share
    (``keypoint_windows``). Only there: a sweep of the whole stretch out to the
    keypoints found the reference's own mover, in another photo, far along the
    line (a goat kept whole in a composite never used to choose anything).

    lab_r, lab_s : (H, W, 3) float32 Lab; view : TwoView; field : (H, W, 2)
    float32 flow matches; visible, region : (H, W) bool; ring_px : px.

    Returns
    -------
    cost : (H, W) float32
        The best window cost (ΔE, as ``epipolar_search``'s) beyond the flow's
        range, at each pixel of a part of ``region`` that such keypoints
        surround (inf elsewhere).
    mu : (H, W) float32
        Its μ (NaN elsewhere).
    """
    Hh, Ww = region.shape
    cost = np.full((Hh, Ww), np.inf, np.float32)
    best_mu = np.full((Hh, Ww), np.nan, np.float32)
    if view.F is None or view.inlier_xy_r is None or not region.any():
        return cost, best_mu
    rng = flow_mu_range(view, field, visible, line_px=line_px)
    if rng is None:
        return cost, best_mu
    lo, hi = rng
    a = view.inlier_xy_r.astype(np.float64)
    b = view.inlier_xy_s.astype(np.float64)
    mus = _mu_of(view.H, epipole(view.F), a[:, 0], a[:, 1], b[:, 0], b[:, 1])
    ix = np.clip(np.round(a[:, 0]).astype(np.intp), 0, Ww - 1)
    iy = np.clip(np.round(a[:, 1]).astype(np.intp), 0, Hh - 1)
    keep = visible[iy, ix] & ((mus < lo) | (mus > hi))
    mus, ix, iy = mus[keep], ix[keep], iy[keep]
    if len(mus) < min_keypoints:
        return cost, best_mu
    join = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (17, 17))
    n, parts, boxes, _ = cv2.connectedComponentsWithStats(
        cv2.dilate(region.astype(np.uint8), join), connectivity=8)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1, 2 * ring_px + 1))
    for c in range(1, n):
        # the keypoints within ring_px of the part (its disc dilation, computed on
        # the part's box widened by ring_px: the same as on the whole photo)
        bx, by, bw, bh = (int(v) for v in boxes[c, :4])
        x0, y0 = max(bx - ring_px, 0), max(by - ring_px, 0)
        x1, y1 = min(bx + bw + ring_px, Ww), min(by + bh + ring_px, Hh)
        near = (ix >= x0) & (ix < x1) & (iy >= y0) & (iy < y1)
        if near.sum() < min_keypoints:
            continue
        sub = region[y0:y1, x0:x1] & (parts[y0:y1, x0:x1] == c)
        if not sub.any():
            continue
        ring = cv2.dilate(sub.astype(np.uint8), disc) > 0
        part = np.zeros((Hh, Ww), bool)
        part[y0:y1, x0:x1] = sub
        m = mus[near][ring[iy[near] - y0, ix[near] - x0]]
        for span in keypoint_windows(m, lo, hi, min_keypoints=min_keypoints):
            c_s, m_s = epipolar_search(lab_r, lab_s, view, field, visible, part,
                                       support_de=support_de, line_px=line_px,
                                       mu_span=span)[:2]
            better = part & (c_s < cost)
            cost[better] = c_s[better]
            best_mu[better] = m_s[better]
    return cost, best_mu


def epipolar_search(lab_r: np.ndarray, lab_s: np.ndarray, view: TwoView, field: np.ndarray,
                    visible: np.ndarray, region: np.ndarray, *, scale: float = 0.5,
                    box: int = 5, step_px: float = 1.0, line_px: float = 1.5,
                    max_steps: int = 256, support_de: float = 0.0, unique_px: float = 0.0,
                    mu_span: tuple[float, float] | None = None
                    ) -> tuple[np.ndarray, ...]:
    """Best colour match of each ``region`` pixel along its epipolar line in one source.

    A static reference point lies, in the source, on its epipolar line at
    x_s(μ) = π(H x̃ + μ ẽ) for some μ within the range the visible scene shows
    (the μ of the visible flow matches on their lines, 1st–99th percentile,
    widened by 10 %). For each μ of that range (steps of about ``step_px`` in
    the source), the cost is the CIE76 distance between the reference and the
    source sampled there (both Lab, already blurred), capped at 30 and
    averaged over a ``box`` × ``box`` window of a coarse grid (``scale`` of the
    image; only the region's cells are sampled). This is a plane sweep in one
    source (Collins, CVPR 1996), without the cross-source γ of ``sweep_fields``,
    so it needs no parallax model.

    With ``support_de`` > 0 the window's cells are weighted by their colour's
    likeness to the centre cell's in the reference, exp(−ΔE / ``support_de``)
    (adaptive support weights: Yoon & Kweon, *Adaptive support-weight approach
    for correspondence search*, PAMI 2006): a window on a thin structure (a
    bollard, a chimney against the sky) then compares that structure, not the
    background around it, whose parallax differs.

    With ``unique_px`` > 0 the search also returns the cost of the best match
    farther than ``unique_px`` (source pixels, along the line) from the best one:
    the second minimum of the ratio test (Lowe, IJCV 2004, on the line's cost
    curve; the uniqueness test of stereo matching, Scharstein & Szeliski, IJCV
    2002). A plain colour (a dark shirt) matches all along a plain stretch of
    the line (a dark screen): its second minimum is as low as its best.

    With ``mu_span`` (lo, hi) the search sweeps that range of μ instead of the
    flow's (``search_beyond``).

    lab_r, lab_s : (H, W, 3) float32 Lab; view : TwoView with F; field : (H, W, 2)
    float32 flow matches; visible, region : (H, W) bool.

    Returns
    -------
    cost : (H, W) float32
        The best window cost (ΔE) at each pixel of ``region`` (inf elsewhere, or
        where the source has no F or too few visible matches on their lines).
    mu : (H, W) float32
        The μ of that best match (NaN elsewhere).
    second : (H, W) float32
        Only with ``unique_px`` > 0: the best cost farther than ``unique_px``
        from the best match (capped at 30 ΔE, inf where ``cost`` is inf).
    """
    Hh, Ww = region.shape
    cost = np.full((Hh, Ww), np.inf, np.float32)
    best_mu = np.full((Hh, Ww), np.nan, np.float32)
    second = np.full((Hh, Ww), np.inf, np.float32)
    out = (cost, best_mu, second) if unique_px > 0 else (cost, best_mu)
    if view.F is None or not region.any():
        return out
    e = epipole(view.F)
    rng = flow_mu_range(view, field, visible, line_px=line_px) if mu_span is None else mu_span
    if rng is None:
        return out
    lo, hi = rng
    # the coarse grid over the whole image; only the region's cells (and their
    # windows) are sampled
    hh, ww = max(1, int(round(Hh * scale))), max(1, int(round(Ww * scale)))
    rc = cv2.resize(region.astype(np.float32), (ww, hh), interpolation=cv2.INTER_AREA) > 0
    # cells whose cost is needed (the region's, and one ring for the bilinear
    # upsampling), and the cells their windows read
    rc = cv2.dilate(rc.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    win = cv2.dilate(rc.astype(np.uint8), np.ones((box, box), np.uint8)) > 0
    py, px = np.nonzero(win)
    qy, qx = np.nonzero(rc)
    CX = (px + 0.5) * Ww / ww - 0.5
    CY = (py + 0.5) * Hh / hh - 0.5
    ref_coarse = cv2.resize(lab_r, (ww, hh), interpolation=cv2.INTER_AREA)
    ref_c = ref_coarse[py, px]
    ry, rx = np.nonzero(region)
    pa = project(view.H, e, np.array([lo, hi]), np.array([rx.mean()]), np.array([ry.mean()]))
    span_px = float(np.hypot(pa[0][1] - pa[0][0], pa[1][1] - pa[1][0]))
    n_steps = int(np.clip(np.ceil(span_px / step_px) + 1, 2, max_steps))
    Hs, Ws = lab_s.shape[:2]
    c_best = np.full(len(qy), np.inf, np.float32)
    m_best = np.full(len(qy), np.nan, np.float32)
    steps = np.linspace(lo, hi, n_steps)
    # every step's window cost, kept for the second minimum (n cells × n_steps)
    curve = np.empty((len(qy), n_steps), np.float32) if unique_px > 0 else None
    chunk = 32  # steps per pass: the window sums run on one image of
    # `chunk` channels, over the box of the sampled cells (box // 2 wider, so that
    # the sums at the region's cells read what the whole image's would)
    r = box // 2
    by0, by1 = max(int(py.min()) - r, 0), min(int(py.max()) + r + 1, hh)
    bx0, bx1 = max(int(px.min()) - r, 0), min(int(px.max()) + r + 1, ww)
    bh, bw = by1 - by0, bx1 - bx0
    py_b, px_b, qy_b, qx_b = py - by0, px - bx0, qy - by0, qx - bx0
    buf = np.full((bh, bw, chunk), _CAP, np.float32)
    weights = None
    if support_de > 0:
        weights = _support_weights(ref_coarse[by0:by1, bx0:bx1], qy_b, qx_b, box, support_de)
    for i0 in range(0, n_steps, chunk):
        gs = steps[i0:i0 + chunk]
        k = len(gs)
        fx, fy = _project_steps(view.H, e, gs, CX, CY)  # (k, n)
        smp = remap_points(lab_s, fx.ravel(), fy.ravel(), borderMode=cv2.BORDER_REPLICATE)
        _step_costs(smp, ref_c, fx, fy, Ws, Hs, _CAP, buf, py_b, px_b)
        if weights is None:
            bf = cv2.boxFilter(buf[..., :k], -1, (box, box)).reshape(bh, bw, k)[qy_b, qx_b]
        else:
            bf = _weighted_window(buf[..., :k], qy_b, qx_b, weights, box)
        if curve is not None:
            curve[:, i0:i0 + k] = bf
        j = np.argmin(bf, axis=1)  # the first of equal costs, as a sequential sweep
        c = bf[np.arange(len(qy)), j]
        better = c < c_best
        c_best[better] = c[better]
        m_best[better] = gs[j[better]]
    cimg = np.full((hh, ww), _CAP, np.float32)
    cimg[qy, qx] = c_best
    mimg = np.full((hh, ww), np.nan, np.float32)
    mimg[qy, qx] = m_best
    cu = cv2.resize(cimg, (Ww, Hh), interpolation=cv2.INTER_LINEAR)
    mu_u = cv2.resize(mimg, (Ww, Hh), interpolation=cv2.INTER_NEAREST)
    cost[region] = cu[region]
    best_mu[region] = mu_u[region]
    if curve is not None:
        # the steps within unique_px of each cell's best one (the same first-of-equal
        # best as above) are left out; the rest's minimum is the second
        j_best = np.argmin(curve, axis=1)
        near = int(np.ceil(unique_px * (n_steps - 1) / max(span_px, 1e-9)))
        idx = np.arange(n_steps)
        far = np.abs(idx[None] - j_best[:, None]) > near
        c2 = np.where(far, curve, _CAP).min(axis=1) if n_steps > 1 else np.full(len(qy), _CAP)
        c2img = np.full((hh, ww), _CAP, np.float32)
        c2img[qy, qx] = np.minimum(c2, _CAP)
        second[region] = cv2.resize(c2img, (Ww, Hh), interpolation=cv2.INTER_LINEAR)[region]
    return out


@numba.njit(cache=True, nogil=True)
def _step_costs(smp, ref_c, fx, fy, Ws, Hs, cap, buf, py, px):
    """One chunk of ``epipolar_search``'s steps into its window buffer: ``buf[py[j],
    px[j], i]`` = min(ΔE(smp[i·n + j], ref_c[j]), cap) where step i's point (fx,
    fy)[i, j] lies in the source (Ws × Hs), else cap. smp (k·n, 3), ref_c (n, 3),
    fx, fy (k, n) float32; buf (h, w, ≥ k) float32. The NumPy form's values, bit for
    bit (``colour.delta_e``'s order; ``test_parallax``), in one pass."""
    k, n = fx.shape
    c32 = np.float32(cap)
    for i in range(k):
        for j in range(n):
            x = fx[i, j]
            y = fy[i, j]
            if x >= 0 and x <= Ws - 1 and y >= 0 and y <= Hs - 1:
                a = smp[i * n + j, 0] - ref_c[j, 0]
                b = smp[i * n + j, 1] - ref_c[j, 1]
                c = smp[i * n + j, 2] - ref_c[j, 2]
                d = np.sqrt((a * a + b * b) + c * c)
                buf[py[j], px[j], i] = c32 if d > c32 else d
            else:
                buf[py[j], px[j], i] = c32


def _support_weights(ref: np.ndarray, qy: np.ndarray, qx: np.ndarray, box: int,
                     support_de: float) -> np.ndarray:
    """Adaptive support weights of ``epipolar_search``'s windows (Yoon & Kweon, 2006).

    ref (h, w, 3) float32: the reference's Lab on the search's coarse grid, cropped
    to the box of the sampled cells; qy, qx (n,) are the query cells in that crop.
    Returns (n, box²) float32: exp(−ΔE / support_de) between each query cell and
    each cell of its box × box window (row-major offsets), 0 for window cells
    outside the crop, normalised to sum 1.
    """
    d = _window_delta_e(np.ascontiguousarray(ref, np.float32), qy, qx, box)
    w = np.where(np.isfinite(d), np.exp(-d / support_de), 0.0).astype(np.float32)
    return w / np.maximum(w.sum(1, keepdims=True), 1e-12)


@numba.njit(cache=True, nogil=True)
def _window_delta_e(ref, qy, qx, box):
    """(n, box²) float32: CIE76 ΔE between each query cell of ``ref`` (h, w, 3)
    float32 and each cell of its box × box window (row-major offsets), as
    ``colour.delta_e`` computes it; NaN for window cells outside ``ref``."""
    h, w = ref.shape[:2]
    r = box // 2
    n = qy.shape[0]
    out = np.empty((n, box * box), np.float32)
    for q in range(n):
        cy, cx = qy[q], qx[q]
        for i in range(box * box):
            y = cy + i // box - r
            x = cx + i % box - r
            if y < 0 or y >= h or x < 0 or x >= w:
                out[q, i] = np.nan
                continue
            a = ref[y, x, 0] - ref[cy, cx, 0]
            b = ref[y, x, 1] - ref[cy, cx, 1]
            c = ref[y, x, 2] - ref[cy, cx, 2]
            out[q, i] = np.sqrt((a * a + b * b) + c * c)
    return out


@numba.njit(cache=True, nogil=True, parallel=True)
def _weighted_window(buf: np.ndarray, qy: np.ndarray, qx: np.ndarray, weights: np.ndarray,
                     box: int) -> np.ndarray:
    """Σ over the box × box window of ``weights`` · ``buf`` at the query cells.

    buf (h, w, k) float32 costs; qy, qx (n,) int cells; weights (n, box²) float32
    from ``_support_weights``. Window cells outside ``buf`` have weight 0 and are
    skipped. Returns (n, k) float32, summed over the offsets in row-major order.
    """
    h, w, k = buf.shape
    r = box // 2
    n = len(qy)
    out = np.zeros((n, k), np.float32)
    for q in numba.prange(n):
        for i in range(box * box):
            y = qy[q] + i // box - r
            x = qx[q] + i % box - r
            if y < 0 or y >= h or x < 0 or x >= w:
                continue
            wq = weights[q, i]
            for j in range(k):
                out[q, j] += wq * buf[y, x, j]
    return out


__all__ = ["SEARCH_CAP_DE", "ParallaxModel", "epipolar_search", "epipole", "fit_parallax",
           "line_points", "project", "sgm", "sweep_fields"]

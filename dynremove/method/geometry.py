"""Two-view geometry: keypoint matches, fundamental matrix, Sampson distance.

SIFT keypoints with Lowe's ratio test; F_s by USAC/MAGSAC (seeded, so runs are
reproducible); a homography H_s (reference → source) for the pre-warp of the
dense correspondences, refitted on keypoints spread over the photo where the
plain fit explains only a compact patch of it (a textured mover). The
conventions are ``x_sᵀ F_s x_r = 0`` and ``x_s ~ H_s x_r``: every homography in
dynremove maps *reference* pixels to *source* pixels (the baselines and the
composites use the same functions and the same direction).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numba
import numpy as np
import numpy.typing as npt

MIN_MATCHES = 15  # fewer matches than this: no reliable F for that source
# a source with fewer matches than this is matched again with keypoints of low
# contrast (SIFT's contrast threshold 0.01 instead of OpenCV's 0.04): a wall and a
# table analysed at 360x480 gave 6-14 matches for 4 sources, 387-589 with the retry
RETRY_BELOW = MIN_MATCHES
ALIGNED_MIN_INLIERS = 8  # a source is aligned with a homography on this many inliers
LOW_CONTRAST = 0.01
RETRY_MIN_INLIERS = 2 * MIN_MATCHES  # the F of a retry is kept from this many inliers
SPREAD_GRID = 8  # keypoint bucketing of the homography's fit: an 8 x 8 grid
SPREAD_GAIN = 0.15  # the spread fit is kept where it covers this much more of the grid


@dataclass(frozen=True)
class TwoView:
    """Geometry between the reference and one source."""

    F: npt.NDArray[np.float64] | None  # (3, 3), x_sᵀ F x_r = 0; None if not estimable
    H: npt.NDArray[np.float64]  # (3, 3) reference → source homography (identity fallback)
    n_matches: int
    n_inliers_F: int
    n_inliers_H: int
    # 90th percentile of |x_s - H x_r| over the F inliers (px): how far the static
    # scene departs from the homography (parallax); inf when F or H is unknown
    parallax_px: float = float("inf")
    # the 95th percentile of the same distances (px): where 3-D structure holds
    # 5-10 % of the matches (columns before a facade), the 90th percentile falls on
    # the knee between the plane's few pixels and the structure's tens to hundreds;
    # a run says so when only the 95th is over ``Params.select_parallax_px``
    parallax_p95_px: float = float("inf")
    # the F inliers' keypoints, (n, 2) float32 (x, y) in the reference and in the
    # source (None without F): the depths the scene shows where the dense flow may
    # not follow it (a bollard near the camera, 200 px of parallax; read by
    # ``parallax.search_beyond``)
    inlier_xy_r: npt.NDArray[np.float32] | None = field(default=None, compare=False, repr=False)
    inlier_xy_s: npt.NDArray[np.float32] | None = field(default=None, compare=False, repr=False)


def detect(gray_u8: npt.NDArray[np.uint8], *, max_features: int = 4000,
           contrast_threshold: float = 0.04):
    """SIFT keypoints and descriptors of a (H, W) uint8 image (the ``max_features``
    strongest; ``contrast_threshold`` as OpenCV's, whose default is 0.04)."""
    sift = cv2.SIFT_create(nfeatures=max_features, contrastThreshold=contrast_threshold)
    kp, desc = sift.detectAndCompute(gray_u8, None)
    xy = np.array([k.pt for k in kp], np.float32).reshape(-1, 2)
    return xy, desc


def match(desc_a, desc_b, *, ratio: float = 0.75) -> npt.NDArray[np.int64]:
    """Lowe's ratio-test matches of ``desc_a``'s descriptors in ``desc_b``.

    Brute-force L2 (deterministic, unlike FLANN). Returns (M, 2) index pairs
    (index in a, index in b), in the order of a.
    """
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), np.int64)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_a, desc_b, k=2)
    pairs = [(m[0].queryIdx, m[0].trainIdx) for m in knn
             if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    return np.array(pairs, np.int64).reshape(-1, 2)


def estimate_two_view(xy_r: npt.NDArray[np.float32], xy_s: npt.NDArray[np.float32], *,
                      seed: int = 0) -> TwoView:
    """F (USAC_MAGSAC) and H (USAC_MAGSAC, ``spread_homography``) from matched
    points (M, 2) each.

    With fewer than ``MIN_MATCHES`` matches, F is None and H the identity; F is
    None too where OpenCV finds none or rejects the set as degenerate (views
    without any motion between them make MAGSAC's model empty). A homography
    that folds or collapses the matched region (``plausible_homography``) is
    not kept either: H is then the identity with 0 inliers.
    """
    n = len(xy_r)
    F = None
    inl_F = None
    H = np.eye(3)
    nF = nH = 0
    parallax = parallax_p95 = float("inf")
    if n >= MIN_MATCHES:
        cv2.setRNGSeed(int(seed))
        try:
            F_est, inl = cv2.findFundamentalMat(xy_r, xy_s, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
        except cv2.error:  # a degenerate set (e.g. views without any motion): no F
            F_est, inl = None, None
        inl_F = None
        if F_est is not None and F_est.shape == (3, 3) and inl is not None:
            nF = int(inl.sum())
            if nF >= 8:
                F = F_est.astype(np.float64)
                inl_F = inl.ravel().astype(bool)
        H_est, n_inl = spread_homography(xy_r, xy_s, seed=seed)
        if H_est is not None and n_inl >= 8 and plausible_homography(
                H_est, _inliers(H_est, xy_r, xy_s)):
            nH = n_inl
            H = H_est
            if inl_F is not None:
                a, b = xy_r[inl_F].astype(np.float64), xy_s[inl_F].astype(np.float64)
                q = np.c_[a, np.ones(len(a))] @ H.T
                q = q[:, :2] / np.where(np.abs(q[:, 2:]) < 1e-12, 1e-12, q[:, 2:])
                parallax, parallax_p95 = (float(v) for v in np.percentile(
                    np.hypot(*(b - q).T), [90, 95]))
    kp_r = kp_s = None
    if F is not None and inl_F is not None:
        kp_r = np.ascontiguousarray(xy_r[inl_F], np.float32)
        kp_s = np.ascontiguousarray(xy_s[inl_F], np.float32)
    return TwoView(F=F, H=H, n_matches=n, n_inliers_F=nF, n_inliers_H=nH,
                   parallax_px=parallax, parallax_p95_px=parallax_p95,
                   inlier_xy_r=kp_r, inlier_xy_s=kp_s)


def _grid_cells(xy: npt.NDArray[np.float32], grid: int) -> npt.NDArray[np.intp]:
    """The cell of each point (M, 2) in a ``grid`` × ``grid`` division of the points'
    bounding box, (M,) intp in [0, grid²)."""
    lo = xy.min(axis=0).astype(np.float64)
    span = np.maximum(xy.max(axis=0).astype(np.float64) - lo, 1e-9)
    c = np.minimum(((xy - lo) / span * grid).astype(np.intp), grid - 1)
    return c[:, 1] * grid + c[:, 0]


def spread_subset(xy: npt.NDArray[np.float32], *, grid: int = SPREAD_GRID, seed: int = 0
                  ) -> npt.NDArray[np.bool_]:
    """A subset of the points (M, 2) with at most twice the mean count in any cell of a
    ``grid`` × ``grid`` division of their bounding box (at least 4): keypoint
    bucketing (as in ORB-SLAM, Mur-Artal et al., T-RO 2015), so that a densely
    textured patch does not outvote the rest of the photo. Which points of a full
    cell are kept is drawn with ``seed``. (M,) bool."""
    cell = _grid_cells(xy, grid)
    cap = max(4, int(np.ceil(2 * len(xy) / grid ** 2)))
    order = np.random.default_rng(seed).permutation(len(xy))
    # the rank of each point within its cell, in the drawn order
    srt = order[np.argsort(cell[order], kind="stable")]
    first = np.searchsorted(cell[srt], cell[srt], side="left")
    keep = np.zeros(len(xy), bool)
    keep[srt] = np.arange(len(srt)) - first < cap
    return keep


def coverage(xy: npt.NDArray[np.float32], inliers: npt.NDArray[np.bool_], *,
             grid: int = SPREAD_GRID) -> float:
    """The share of the grid cells holding a match (``_grid_cells``) that hold an
    inlier: how much of the photo a model explains, whatever the density of keypoints."""
    cell = _grid_cells(xy, grid)
    return len(np.unique(cell[inliers])) / max(1, len(np.unique(cell)))


def spread_homography(xy_r: npt.NDArray[np.float32], xy_s: npt.NDArray[np.float32], *,
                      seed: int = 0) -> tuple[npt.NDArray[np.float64] | None, int]:
    """``fit_homography`` on all matches, unless a fit on a spread subset
    (``spread_subset``) explains a clearly larger part of the photo.

    MAGSAC maximises the number of inliers, and a compact, densely textured mover
    (a cup's lettering: 87 of 93 inliers inside it in tim6) can hold more keypoints
    than the whole background; that homography then follows the mover, the
    flow's pre-warp brings the mover's copy in each source onto it, and the mover
    counts as static. The fit on the spread subset is kept when its inliers (among
    all matches) cover at least ``SPREAD_GAIN`` more of the grid cells holding a
    match (``coverage``). Returns ``(H, n_inliers)`` over all matches, as
    ``fit_homography``.
    """
    H, n = fit_homography(xy_r, xy_s, seed=seed)
    if len(xy_r) < 2 * MIN_MATCHES:
        return H, n
    sub = spread_subset(xy_r, seed=seed)
    Hb, _ = fit_homography(xy_r[sub], xy_s[sub], seed=seed)
    if Hb is None:
        return H, n
    in_b = _inlier_mask(Hb, xy_r, xy_s)
    if H is None:
        return Hb, int(in_b.sum())
    gain = coverage(xy_r, in_b) - coverage(xy_r, _inlier_mask(H, xy_r, xy_s))
    return (Hb, int(in_b.sum())) if gain >= SPREAD_GAIN else (H, n)


def _inlier_mask(Hm: npt.NDArray[np.float64], xy_r: npt.NDArray[np.float32],
                 xy_s: npt.NDArray[np.float32], threshold_px: float = 3.0
                 ) -> npt.NDArray[np.bool_]:
    """Which matches ``Hm`` maps within ``threshold_px`` of their match
    (``fit_homography``'s threshold); (M,) bool."""
    xo, yo, _ = project_homography(Hm, xy_r[:, 0].astype(np.float64),
                                   xy_r[:, 1].astype(np.float64))
    return np.hypot(xo - xy_s[:, 0], yo - xy_s[:, 1]) <= threshold_px


def _inliers(Hm: npt.NDArray[np.float64], xy_r: npt.NDArray[np.float32],
             xy_s: npt.NDArray[np.float32], threshold_px: float = 3.0) -> npt.NDArray[np.float32]:
    """The points of ``xy_r`` that ``Hm`` maps within ``threshold_px`` of their match
    (``fit_homography``'s threshold); (K, 2) float32."""
    return xy_r[_inlier_mask(Hm, xy_r, xy_s, threshold_px)]


def plausible_homography(Hm: npt.NDArray[np.float64], xy: npt.NDArray[np.float32], *,
                         max_scale: float = 20.0) -> bool:
    """Whether ``Hm`` maps the bounding box of the points ``xy`` (M, 2; its inliers) as
    a camera can.

    The box's corners must stay in front (w > 0), the mapped quadrilateral convex
    and of the same orientation (no mirror image, no fold), and its area between
    1/``max_scale`` and ``max_scale`` times the box's (a zoom of up to about 4.5×).
    MAGSAC can return a homography on 8 or more inliers that does none of this: a
    photo blurred by σ 4 px gave 21 inliers of 47 matches and det(H) 2e-29 (the
    source collapsed to a line, and inverting H failed).
    """
    if not np.isfinite(Hm).all() or len(xy) == 0:
        return False
    x0, y0 = np.min(xy, axis=0).astype(np.float64)
    x1, y1 = np.max(xy, axis=0).astype(np.float64)
    box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    area = (x1 - x0) * (y1 - y0)
    if area <= 0:
        return False
    q = np.c_[box, np.ones(4)] @ np.asarray(Hm, np.float64).T
    if (q[:, 2] * np.sign(Hm[2, 2] or 1.0) <= 1e-12 * np.abs(q[:, :2]).max(axis=1)).any():
        return False
    p = q[:, :2] / q[:, 2:]
    e = np.roll(p, -1, axis=0) - p
    turn = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not (turn > 0).all():  # the box's corners run clockwise in image coordinates
        return False
    mapped = 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    return 1.0 / max_scale <= mapped / area <= max_scale


def aligned(view: TwoView) -> bool:
    """Whether a source is aligned to the reference: a homography on 8 or more
    inliers (the pre-warp of its dense correspondences). An F alone does not
    count: MAGSAC fits an F to 8-10 of 16-40 matches between photos of different
    scenes, and to 28 of 53 between a photo and its copy blurred by σ 4 px,
    whose homography collapsed (``plausible_homography``). Such an F is still
    used for the epipolar terms (dropping the Fs on 8-14 inliers moved the DAVIS
    J by +0.21 on drift-straight and -0.32 on motocross-jump_s3)."""
    return view.n_inliers_H >= ALIGNED_MIN_INLIERS


def fit_homography(xy_a: npt.NDArray[np.float32], xy_b: npt.NDArray[np.float32], *,
                   seed: int = 0, threshold_px: float = 3.0, max_iters: int = 10000,
                   confidence: float = 0.999
                   ) -> tuple[npt.NDArray[np.float64] | None, int]:
    """Homography ``x_b ~ H x_a`` by USAC/MAGSAC++ from matched points (M, 2) each.

    OpenCV's RNG is seeded with ``seed`` first, so the fit is reproducible.
    Returns ``(H, n_inliers)``; ``(None, 0)`` when OpenCV finds none.
    """
    cv2.setRNGSeed(int(seed))
    try:
        H, inl = cv2.findHomography(xy_a, xy_b, cv2.USAC_MAGSAC, threshold_px,
                                    maxIters=max_iters, confidence=confidence)
    except cv2.error:  # a degenerate set: as when OpenCV finds none
        return None, 0
    if H is None or inl is None or H.shape != (3, 3):
        return None, 0
    return H.astype(np.float64), int(inl.sum())


def project_homography(Hm: npt.NDArray[np.float64], xs: npt.ArrayLike, ys: npt.ArrayLike
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map points (x, y) by a 3×3 homography; float64 (x', y', w).

    ``w`` is the projective depth (a point with ``w <= 0`` is behind the
    camera); where ``|w| < 1e-12`` the division uses 1e-12, so x', y' are
    finite (and huge).
    """
    w = Hm[2, 0] * xs + Hm[2, 1] * ys + Hm[2, 2]
    den = np.where(np.abs(w) < 1e-12, 1e-12, w)
    xo = (Hm[0, 0] * xs + Hm[0, 1] * ys + Hm[0, 2]) / den
    yo = (Hm[1, 0] * xs + Hm[1, 1] * ys + Hm[1, 2]) / den
    return xo, yo, w


def apply_homography(Hm: npt.NDArray[np.float64], xs: np.ndarray, ys: np.ndarray
                     ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Map points (x, y) by a 3×3 homography; returns float32 (x', y').

    ``project_homography``'s values rounded to float32, bit for bit; two float
    arrays of one shape go through one compiled pass without float64
    temporaries (0.004 s instead of 0.026 s on an 854×480 grid)."""
    xs, ys = np.asarray(xs), np.asarray(ys)
    if xs.shape == ys.shape and xs.dtype == ys.dtype and xs.dtype in (np.float32, np.float64):
        xo = np.empty(xs.shape, np.float32)
        yo = np.empty(xs.shape, np.float32)
        _apply_homography(np.asarray(Hm, np.float64), xs.reshape(-1), ys.reshape(-1),
                          xo.reshape(-1), yo.reshape(-1))
        return xo, yo
    xo, yo, _ = project_homography(Hm, xs, ys)
    return xo.astype(np.float32), yo.astype(np.float32)


@numba.njit(cache=True, nogil=True)
def _apply_homography(Hm, xs, ys, xo, yo):
    """``project_homography`` of (N,) points into float32 xo, yo (N,): each point's
    arithmetic in float64 in the NumPy form's order (bit for bit: ``test_correspondence``)."""
    for i in range(xs.shape[0]):
        x = np.float64(xs[i])
        y = np.float64(ys[i])
        w = Hm[2, 0] * x + Hm[2, 1] * y + Hm[2, 2]
        den = 1e-12 if abs(w) < 1e-12 else w
        xo[i] = np.float32((Hm[0, 0] * x + Hm[0, 1] * y + Hm[0, 2]) / den)
        yo[i] = np.float32((Hm[1, 0] * x + Hm[1, 1] * y + Hm[1, 2]) / den)


def sampson_sq(F: npt.NDArray[np.float64], xy_r: npt.ArrayLike,
               xy_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Squared Sampson distance d_s(x_r, x_s, F) of point pairs (px²).

    .. math:: d_s = \\frac{(x_s^T F x_r)^2}{(F x_r)_1^2 + (F x_r)_2^2
              + (F^T x_s)_1^2 + (F^T x_s)_2^2}

    Parameters
    ----------
    F : (3, 3) float64 ndarray
    xy_r, xy_s : (..., 2) array
        Points in the reference and the source, pixel coordinates (x, y).

    Returns
    -------
    d : (...) float64 ndarray

    References
    ----------
    Hartley & Zisserman, Multiple View Geometry, Eq. (11.9).

    Examples
    --------
    >>> F = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # pure x-translation
    >>> float(sampson_sq(F, [10, 5], [20, 7]))  # 2 px off the epipolar line y = 5
    2.0
    """
    xr, xs = np.broadcast_arrays(np.asarray(xy_r), np.asarray(xy_s))
    shape = xr.shape[:-1]
    return _sampson_sq(np.asarray(F, np.float64),
                       np.ascontiguousarray(xr, np.float64).reshape(-1, 2),
                       np.ascontiguousarray(xs, np.float64).reshape(-1, 2)).reshape(shape)


@numba.njit(cache=True, nogil=True)
def _sampson_sq(F, xr, xs):
    """``sampson_sq`` of (M, 2) float64 point pairs, compiled: one pass, no
    temporaries, each pair's arithmetic in the order of the formula's NumPy form
    (bit for bit: ``test_correspondence``)."""
    out = np.empty(xr.shape[0])
    for i in range(xr.shape[0]):
        x, y, u, v = xr[i, 0], xr[i, 1], xs[i, 0], xs[i, 1]
        a = F[0, 0] * x + F[0, 1] * y + F[0, 2]
        b = F[1, 0] * x + F[1, 1] * y + F[1, 2]
        c = F[2, 0] * x + F[2, 1] * y + F[2, 2]
        ta = F[0, 0] * u + F[1, 0] * v + F[2, 0]
        tb = F[0, 1] * u + F[1, 1] * v + F[2, 1]
        e = u * a + v * b + c
        den = a * a + b * b + ta * ta + tb * tb
        if den < 1e-300:  # (NaN stays NaN, as np.maximum)
            den = 1e-300
        out[i] = e * e / den
    return out


def peer_matches(gray_a: npt.NDArray[np.uint8], gray_b: npt.NDArray[np.uint8]) -> int:
    """Keypoint matches between two photos (``detect`` + ``match``): how well two
    sources match each other, to compare with how well they match the reference."""
    return len(match(detect(gray_a)[1], detect(gray_b)[1]))


def geometry_for_sources(ref_gray: npt.NDArray[np.uint8], src_grays: list[npt.NDArray[np.uint8]],
                         *, seed: int = 0, workers: int | None = None) -> list[TwoView]:
    """Match the reference to each source and estimate F_s and H_s.

    Detection and matching run on ``workers`` threads (default: the CPU count;
    OpenCV releases the GIL), the estimation in order (OpenCV's RNG is global):
    the result does not depend on ``workers``. A source with fewer than
    ``RETRY_BELOW`` matches is matched again on keypoints of low contrast
    (``LOW_CONTRAST``: walls, tables, sky; small analysis sizes); that geometry
    is kept when its F has at least ``RETRY_MIN_INLIERS`` inliers, more than before.
    """
    workers = workers or os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=workers) as pool:
        feats = list(pool.map(detect, [ref_gray, *src_grays]))
        xy_r, d_r = feats[0]
        matches = list(pool.map(lambda f: match(d_r, f[1]), feats[1:]))
        weak = [k for k, m in enumerate(matches) if len(m) < RETRY_BELOW]
        if weak:
            def low(g):
                return detect(g, contrast_threshold=LOW_CONTRAST)
            low_feats = list(pool.map(low, [ref_gray, *[src_grays[k] for k in weak]]))
            xy_r2, d_r2 = low_feats[0]
            low_matches = dict(zip(weak, pool.map(lambda f: match(d_r2, f[1]), low_feats[1:])))
            low_xy = dict(zip(weak, (f[0] for f in low_feats[1:])))
    views = [estimate_two_view(xy_r[m[:, 0]], f[0][m[:, 1]], seed=seed)
             for f, m in zip(feats[1:], matches)]
    for k in weak:
        m = low_matches[k]
        if len(m) <= len(matches[k]):
            continue
        v = estimate_two_view(xy_r2[m[:, 0]], low_xy[k][m[:, 1]], seed=seed)
        # kept only as a geometry the first match lacked: an F on RETRY_MIN_INLIERS
        # or more (faint matches on a mover gave an F of 11 inliers of 37; on
        # motocross-jump, Fs of 15-18 inliers misaligned every source and the
        # whole photo was refilled)
        if v.F is not None and v.n_inliers_F >= RETRY_MIN_INLIERS and v.n_inliers_F > (
                views[k].n_inliers_F if views[k].F is not None else 0):
            views[k] = v
    return views

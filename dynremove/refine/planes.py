"""Fields across L from the planes around it, chosen where the sources agree.

A field interpolated across L as a membrane (``fields.harmonic_fill``) is right
where the hidden background continues one surface, and wrong where L hides an
edge between two depths (a table's edge behind a cup, a balcony before a
façade, a pillar's foot on its steps): there it blends the two, and the fill
comes out doubled or bent. The ring of static pixels around each region of the
hole shows the surfaces that meet there. Each sector of the ring proposes the
plane its static flow matches fit (an affine map by RANSAC: locally, so that no
fit bends across two surfaces), and so does each homography that RANSAC finds
on the whole ring one after the other (sequential RANSAC, Vincent & Laganière,
*Detecting planar homographies in an image pair*, ISPA 2001); proposals shared
by most of their pixels are merged, and each plane is refitted in every source
as a homography on its ring pixels (multi-model fitting from proposals, in the
spirit of J-linkage, Toldo & Fusiello, ECCV 2008). Inside the region each pixel
takes the plane at which the sources that see the background there agree best
(the plane sweep's photo-consistency, Collins, *A space-sweep approach to true
multi-image matching*, CVPR 1996, over these few planes only), and keeps the
membrane unless a plane is clearly better. No global depth model is fitted: the
parallax sweep that needs one (``parallax.sweep_fields``) was measured worse,
its model fitted badly (README, session 77).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.geometry import apply_homography, project_homography
from dynremove.refine.colour import delta_e
from dynremove.refine.morphology import dilate_disc

# a pixel is decided where every hypothesis has at least this much pair weight (a
# pair of witnesses weighs (1 - P(mover)) of each: 0.1, two of P 0.68)
_HAVE_MIN = 0.1
_CAP = 30.0  # CIE76 ΔE: a pair of samples disagreeing by more counts this much


def _sector_proposals(base: list[np.ndarray], pr: np.ndarray, iy: np.ndarray, ix: np.ndarray,
                      trusted: np.ndarray, centre: tuple[float, float], *, sectors: int,
                      thresh_px: float, min_inliers: int, seed: int) -> list[np.ndarray]:
    """Local proposals: in each source, each of ``sectors`` equal angles of the ring
    around ``centre`` fits an affine map to its trusted matches (RANSAC); its plane
    is every trusted match of the ring within ``thresh_px`` of it ((n,) bool each)."""
    ang = np.arctan2(pr[:, 1] - centre[1], pr[:, 0] - centre[0])
    sector = np.minimum(((ang + np.pi) / (2 * np.pi) * sectors).astype(np.intp), sectors - 1)
    min_fit = max(6, min_inliers // 3)
    out = []
    for k in range(len(base)):
        ps = base[k][iy, ix]
        for q in range(sectors):
            sq = np.flatnonzero(trusted[k] & (sector == q))
            if len(sq) < min_fit:
                continue
            cv2.setRNGSeed(seed)
            A, inl = cv2.estimateAffine2D(pr[sq], ps[sq], method=cv2.RANSAC,
                                          ransacReprojThreshold=thresh_px, maxIters=200)
            if A is None or inl is None or int(inl.sum()) < min_fit:
                continue
            pred = pr @ A[:, :2].T.astype(np.float32) + A[:, 2].astype(np.float32)
            m = trusted[k] & (np.hypot(*(pred - ps).T) <= thresh_px)
            if m.sum() >= min_inliers:
                out.append(m)
    return out


def _sequential_proposals(base: list[np.ndarray], pr: np.ndarray, iy: np.ndarray,
                          ix: np.ndarray, trusted: np.ndarray, *, per_source: int,
                          thresh_px: float, min_inliers: int, seed: int) -> list[np.ndarray]:
    """Global proposals: in each source, up to ``per_source`` homographies fitted one
    after the other (RANSAC) on the trusted matches the ones before left; each
    proposes its inliers ((n,) bool each)."""
    out = []
    for k in range(len(base)):
        left = np.flatnonzero(trusted[k])
        for _ in range(per_source):
            if len(left) < min_inliers:
                break
            cv2.setRNGSeed(seed)
            Hm, inl = cv2.findHomography(pr[left], base[k][iy[left], ix[left]], cv2.RANSAC,
                                         thresh_px, maxIters=500, confidence=0.99)
            if Hm is None or inl is None or int(inl.sum()) < min_inliers:
                break
            inl = inl.ravel().astype(bool)
            m = np.zeros(len(pr), bool)
            m[left[inl]] = True
            out.append(m)
            left = left[~inl]
    return out


def ring_planes(base: list[np.ndarray], pr: np.ndarray, trusted: np.ndarray,
                centre: tuple[float, float], *, thresh_px: float, min_inliers: int,
                max_planes: int, seed: int, sectors: int = 8, per_source: int = 3
                ) -> list[list[np.ndarray | None]]:
    """The planes of a ring, each as one homography per source.

    base: per source (H, W, 2) float32 matches; pr (n, 2) float32: the ring's
    pixels (x, y); trusted (S, n) bool: where each source's match is static
    evidence; centre (x, y): the region's centre. Proposals come two ways:
    local (``_sector_proposals``: a sector's affine fit never bends across two
    surfaces, where a homography fitted on a thin ring at once may fit its two
    halves each in part, with more inliers than either: seen on two translated
    planes) and global (``_sequential_proposals``: a surface seen round most of
    the ring, its perspective included). A proposal mostly shared (70 % of the
    smaller) with a larger one is the same plane; the ``max_planes`` largest are
    kept, each refitted in every source on its trusted pixels (a homography,
    RANSAC): None for a source with fewer than ``min_inliers``; a plane that fewer
    than two sources fit is dropped. Fewer than two proposals: no plane (empty).
    """
    S = len(base)
    iy = np.rint(pr[:, 1]).astype(np.intp)
    ix = np.rint(pr[:, 0]).astype(np.intp)
    props = (_sector_proposals(base, pr, iy, ix, trusted, centre, sectors=sectors,
                               thresh_px=thresh_px, min_inliers=min_inliers, seed=seed)
             + _sequential_proposals(base, pr, iy, ix, trusted, per_source=per_source,
                                     thresh_px=thresh_px, min_inliers=min_inliers, seed=seed))
    props.sort(key=lambda m: -int(m.sum()))
    segs: list[np.ndarray] = []
    for m in props:
        if all((m & t).sum() < 0.7 * min(m.sum(), t.sum()) for t in segs):
            segs.append(m)
        if len(segs) == max_planes:
            break
    if len(segs) < 2:
        return []  # one surface or none: the caller keeps the membrane (no refit needed)
    planes = []
    for m in segs:
        Hs: list[np.ndarray | None] = []
        for k in range(S):
            mk = m & trusted[k]
            Hm = None
            if mk.sum() >= min_inliers:
                cv2.setRNGSeed(seed)
                Hm, inl = cv2.findHomography(pr[mk], base[k][iy[mk], ix[mk]], cv2.RANSAC,
                                             thresh_px)
                if inl is None or int(inl.sum()) < min_inliers:
                    Hm = None
            Hs.append(Hm)
        if sum(h is not None for h in Hs) >= 2:
            planes.append(Hs)
    return planes


def plane_fields(src_labs: list[np.ndarray], base: list[np.ndarray],
                 fields: list[np.ndarray], hole: npt.NDArray[np.bool_],
                 visible: npt.NDArray[np.bool_], exclude: npt.NDArray[np.bool_], *,
                 static: npt.NDArray[np.bool_] | None = None,
                 ring_px: int = 24, thresh_px: float = 1.5, min_inliers: int = 30,
                 max_planes: int = 8, max_points: int = 400, min_area: int = 400,
                 scale: float = 0.5, box: int = 9, margin: float = 2.0, seed: int = 0,
                 mover_p: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> tuple[list[np.ndarray], np.ndarray]:
    """The fields inside ``hole`` re-chosen among the planes around each of its regions.

    Parameters
    ----------
    src_labs : list of S (H, W, 3) float32 ndarray
        The sources' CIE Lab (blurred, exposure matched to the reference).
    base : list of S (H, W, 2) float32 ndarray
        Each source's flow matches (x, y), in source pixels.
    fields : list of S (H, W, 2) float32 ndarray
        The fields to start from (the membrane across the hole): kept outside
        ``hole``, and inside it wherever no plane is clearly better.
    hole : (H, W) bool ndarray
        Where the fields are re-chosen, region by region (8-connected); a region
        under ``min_area`` px keeps its membrane.
    visible : (H, W) bool ndarray
        Pixels whose matches may fit the planes (outside L and a margin).
    exclude : (S, H, W) bool ndarray
        Where a source shows a mover of its own (reference frame): its sample
        there is no witness.
    static : (S, H, W) bool ndarray, optional
        Where each source's match is static evidence (on its epipolar line, within
        the parallax bound, the reference's colour): the planes are fitted on these
        only, so that a mover's own motion in the ring (a part of it L missed)
        makes no plane. None: every match of ``visible``.
    ring_px : int
        Width (px) of the ring of ``visible`` pixels around a region that the
        planes are fitted on; at most ``max_points`` of its pixels, evenly thinned.
    thresh_px : float
        RANSAC's inlier distance (px, in the source).
    min_inliers : int
        Matches a plane needs in a source.
    max_planes : int
        Planes kept per region (the largest; ``ring_planes``).
    scale, box : float, int
        The choice is made on the region's box at ``scale``, each hypothesis's
        disagreement averaged over a ``box`` × ``box`` window there.
    margin : float
        CIE76 ΔE by which a plane's mean pairwise disagreement between the sources
        must beat the membrane's to replace it (where texture cannot tell, it does not).
    seed : int
        OpenCV's RNG seed for RANSAC (the result is reproducible).
    mover_p : callable, optional
        P(mover) of Lab samples ((..., 3) float32 → (...)): a pair of samples
        counts (1 − P) of each, so that sources agreeing on their own copies of a
        mover (a plane that follows it) do not choose. None: every pair counts 1.

    Returns
    -------
    fields : list of S (H, W, 2) float32 ndarray
    label : (H, W) int16 ndarray
        The plane chosen at each pixel of the hole, numbered per region from 1
        (0: the membrane kept; -1 outside the hole).

    A region whose ring shows one surface only keeps its membrane, which
    continues that surface. Where a plane is chosen, a source that fits no
    homography for it keeps its membrane field there.
    """
    H, W = hole.shape
    S = len(base)
    out = [f.copy() for f in fields]
    label = np.full((H, W), -1, np.int16)
    label[hole] = 0
    if S < 2 or not hole.any():
        return out, label
    n, comp, stats, _ = cv2.connectedComponentsWithStats(hole.astype(np.uint8), connectivity=8)
    for c in range(1, n):
        x, y, w, h, area = (int(v) for v in stats[c])
        if area < min_area:
            continue
        pad = ring_px + 2
        x0, y0 = max(x - pad, 0), max(y - pad, 0)
        x1, y1 = min(x + w + pad, W), min(y + h + pad, H)
        ring = (dilate_disc(comp[y0:y1, x0:x1] == c, ring_px) & ~hole[y0:y1, x0:x1]
                & visible[y0:y1, x0:x1])
        ry, rx = np.nonzero(ring)
        if len(ry) < 2 * min_inliers:
            continue
        if len(ry) > max_points:  # evenly thinned: RANSAC's time grows with the points
            keep = np.linspace(0, len(ry) - 1, max_points).astype(np.intp)
            ry, rx = ry[keep], rx[keep]
        ry, rx = ry + y0, rx + x0
        pr = np.stack([rx, ry], -1).astype(np.float32)
        trusted = np.ones((S, len(ry)), bool) if static is None else static[:, ry, rx]
        planes = ring_planes(base, pr, trusted, (x + w / 2.0, y + h / 2.0), thresh_px=thresh_px,
                             min_inliers=min_inliers, max_planes=max_planes, seed=seed)
        if len(planes) < 2:
            continue  # one surface around the region: the membrane continues it
        # the region's box at ``scale``: each hypothesis's disagreement between sources
        hh, ww = max(1, int(round(h * scale))), max(1, int(round(w * scale)))
        cy = (y + (np.arange(hh) + 0.5) * h / hh - 0.5).astype(np.float32)
        cx = (x + (np.arange(ww) + 0.5) * w / ww - 0.5).astype(np.float32)
        CX, CY = np.meshgrid(cx, cy)
        ex = exclude[:, np.clip(np.rint(CY).astype(np.intp), 0, H - 1),
                     np.clip(np.rint(CX).astype(np.intp), 0, W - 1)]
        agg, have = [], np.ones((hh, ww), bool)
        for hyp in range(len(planes) + 1):
            labs = np.zeros((S, hh, ww, 3), np.float32)
            ok = np.zeros((S, hh, ww), bool)
            wt = np.ones((S, hh, ww), np.float32)
            for k in range(S):
                if hyp == 0:
                    fx = cv2.remap(fields[k][..., 0], CX, CY, cv2.INTER_LINEAR)
                    fy = cv2.remap(fields[k][..., 1], CX, CY, cv2.INTER_LINEAR)
                elif planes[hyp - 1][k] is None:
                    continue
                else:
                    fx, fy = apply_homography(planes[hyp - 1][k], CX, CY)
                labs[k] = cv2.remap(src_labs[k], fx, fy, cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE)
                ok[k] = (fx >= 0) & (fx <= W - 1) & (fy >= 0) & (fy <= H - 1) & ~ex[k]
                if mover_p is not None:
                    wt[k] = 1.0 - mover_p(labs[k])
            num = np.zeros((hh, ww), np.float32)
            cnt = np.zeros((hh, ww), np.float32)
            for a in range(S):
                for b in range(a + 1, S):
                    pair = ok[a] & ok[b]
                    both = np.where(pair, wt[a] * wt[b], 0.0)
                    num += np.where(pair, both * np.minimum(delta_e(labs[a], labs[b]), _CAP),
                                    0.0)
                    cnt += both
            # a pixel is decided where every hypothesis has a pair of witnesses; its
            # cost: the pairs' ΔE over the window, a mean weighted by the pairs' weights
            have &= cnt > _HAVE_MIN
            agg.append(cv2.boxFilter(num, -1, (box, box), normalize=False)
                       / np.maximum(cv2.boxFilter(cnt, -1, (box, box), normalize=False), 1e-6))
        agg = np.stack(agg)
        best = np.argmin(agg, 0)
        c_best = np.take_along_axis(agg, best[None], 0)[0]
        choose = have & (best > 0) & (agg[0] - c_best > margin)
        lab_box = cv2.resize(np.where(choose, best, 0).astype(np.uint8), (w, h),
                             interpolation=cv2.INTER_NEAREST)
        in_c = comp[y:y + h, x:x + w] == c
        label[y:y + h, x:x + w][in_c] = lab_box[in_c]
        gx, gy = np.meshgrid(np.arange(x, x + w, dtype=np.float64),
                             np.arange(y, y + h, dtype=np.float64))
        for hyp in range(1, len(planes) + 1):
            sel = in_c & (lab_box == hyp)
            if not sel.any():
                continue
            for k in range(S):
                if planes[hyp - 1][k] is not None:
                    fx, fy, _ = project_homography(planes[hyp - 1][k], gx[sel], gy[sel])
                    out[k][y:y + h, x:x + w, 0][sel] = fx
                    out[k][y:y + h, x:x + w, 1][sel] = fy
    return out, label


__all__ = ["plane_fields", "ring_planes"]

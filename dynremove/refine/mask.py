"""Border refinement of the dynamic map L (default preset only).

Two steps after the scans, each a ``Params`` switch: pixel votes of the
sources at L's border (``refine_mask``, ``Params.refine_tau``) and a graph cut
of the border onto colour edges (``snap_to_edges``, ``Params.snap``), whose
growth the sources' votes may veto where the set has parallax
(``veto_agreed``, ``Params.snap_veto``).
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.params import Params
from dynremove.refine.fields import source_votes
from dynremove.refine.morphology import clean_mask, dilate_disc, disc, drop_small, fill_holes


def _votes(reference: np.ndarray, sources: np.ndarray, Nf: np.ndarray,
           hole: npt.NDArray[np.bool_], params: Params):
    """The sources' pixel votes (``fields.source_votes``, matches re-interpolated
    across ``hole``): per pixel, (H, W) ints, how many agree with the reference
    (CIE Lab distance < ``refine_tau``), how many see it, and how many agreeing
    drop a pixel (``refine_shrink_frac`` of those that see it, at least 1)."""
    D = source_votes(reference, sources, Nf, hole)
    valid = np.isfinite(D).sum(0)
    agree = (D < params.refine_tau).sum(0)
    need = np.maximum(1, np.ceil(params.refine_shrink_frac * valid - 1e-6))
    return agree, valid, need


def refine_mask(reference: np.ndarray, sources: np.ndarray, Nf: np.ndarray,
                mask: npt.NDArray[np.bool_], params: Params, *, majority: bool = False
                ) -> npt.NDArray[np.bool_]:
    """Pixel-level correction of the borders of a dynamic map (default preset).

    The scan decides on p×p patches, so L overshoots every object by up to
    p/2 pixels and can stop short of a part whose patches looked static. Near
    the border of the map, the pixel itself is put to the sources' vote
    (``fields.source_votes``: Lab distance to each source through the
    background field): a pixel of the inner rim (``refine_rim_px`` wide) is
    dropped when at least ``refine_shrink_frac`` of the sources agree with it
    (distance < ``refine_tau``), and a pixel of the outer ring
    (``refine_ring_px`` wide) is added when *no* source agrees with it. Deep
    inside the map nothing changes: a slow object still covers its own
    background in some sources, and a pixel vote there would erase it.
    Repeated ``refine_iters`` times (the ring moves with the map), each pass
    followed by ``morphology.clean_mask`` (with ``majority`` as given).
    """
    m = mask.copy()
    for _ in range(params.refine_iters):
        mu = m.astype(np.uint8)
        ring = dilate_disc(m, params.refine_ring_px) & ~m
        rim = m & ~cv2.erode(mu, disc(params.refine_rim_px)).astype(bool)
        hole = cv2.dilate((m | ring).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        agree, valid, need = _votes(reference, sources, Nf, hole, params)
        new = m.copy()
        new[rim & (agree >= need)] = False
        new[ring & (agree == 0) & (valid > 0)] = True
        if params.clean_mask:
            new = clean_mask(new, params, majority=majority)
        if np.array_equal(new, m):
            break
        m = new
    return m


def snap_to_edges(image: np.ndarray, mask: npt.NDArray[np.bool_], params: Params
                  ) -> npt.NDArray[np.bool_]:
    """Move the border of a dynamic map onto the object's edges (graph cut).

    Every region of the map, with a margin, goes to OpenCV's GrabCut (colour
    mixture models and a min-cut, Rother et al. 2004): pixels deeper than
    ``snap_inner_px`` inside the map are sure object, the rest of the map is
    probable object, a ring ``snap_outer_px`` wide around it is probable
    background and everything farther is sure background. The cut then follows
    the colour edge, which the scan's p×p patches and the pixel votes can only
    approximate. Regions without a sure-object core are left as they are.
    """
    if not mask.any():
        return mask.copy()
    H, W = mask.shape
    outer = dilate_disc(mask, params.snap_outer_px)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(outer.astype(np.uint8), connectivity=8)
    out = mask.copy()
    margin = params.snap_outer_px + 8
    # GrabCut's colour models start from k-means, which draws from OpenCV's RNG of
    # the calling thread: seeded here, the cut does not depend on what ran before
    cv2.setRNGSeed(int(params.seed))
    for i in range(1, n):
        x, y, w, h = stats[i, :4]
        x0, y0 = max(x - margin, 0), max(y - margin, 0)
        x1, y1 = min(x + w + margin, W), min(y + h + margin, H)
        sub = mask[y0:y1, x0:x1]
        comp = lab[y0:y1, x0:x1] == i
        gc = np.full(sub.shape, cv2.GC_BGD, np.uint8)
        gc[dilate_disc(sub, params.snap_outer_px)] = cv2.GC_PR_BGD
        gc[sub] = cv2.GC_PR_FGD
        core = sub & ~dilate_disc(~sub, params.snap_inner_px)
        gc[core] = cv2.GC_FGD
        if not core.any() or not (gc == cv2.GC_BGD).any():
            continue
        bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
        try:
            cv2.grabCut(np.ascontiguousarray(image[y0:y1, x0:x1]), gc, None, bgd, fgd,
                        params.snap_iters, cv2.GC_INIT_WITH_MASK)
        except cv2.error:  # too few pixels of a class for its colour model: keep the region
            continue
        res = (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)
        out[y0:y1, x0:x1][comp] = res[comp]
    if params.min_region_px > 0:
        out = drop_small(out, params.min_region_px).astype(bool)
    return fill_holes(out.astype(np.uint8)).astype(bool)


def veto_agreed(reference: np.ndarray, sources: np.ndarray, Nf: np.ndarray,
                before: npt.NDArray[np.bool_], after: npt.NDArray[np.bool_], params: Params
                ) -> npt.NDArray[np.bool_]:
    """``after`` without the pixels it added to ``before`` that the sources vouch for.

    A graph cut that moves L's border onto colour edges (``snap_to_edges``) also
    grows it around a false positive of the scans: static 3-D structure that the
    parallax of a wide-baseline set made look dynamic. An added pixel is dropped
    where at least ``refine_shrink_frac`` of the sources that see it agree with
    the reference (CIE Lab distance under ``refine_tau`` through the background
    field, matches re-interpolated across ``before``: ``fields.source_votes``),
    the rule by which ``refine_mask`` drops a pixel of L's rim.

    reference (H, W, 3) uint8; sources (S, H, W, 3) uint8; Nf (S, H, W, 2)
    float32 matches; before, after (H, W) bool. Returns (H, W) bool, a subset of
    ``after`` that contains ``after & before``.
    """
    added = after & ~before
    if not added.any():
        return after.copy()
    hole = cv2.dilate(before.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    agree, _, need = _votes(reference, sources, Nf, hole, params)
    return after & ~(added & (agree >= need))


__all__ = ["refine_mask", "snap_to_edges", "veto_agreed"]

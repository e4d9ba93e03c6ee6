"""Morphology of binary maps: discs, small components, holes, the clean-up of L.

The scans label pixels one at a time, so L has isolated false positives and
pin holes. Morphological opening then closing (a disc of ~p/2), dropping
components smaller than ``min_region_px`` and filling enclosed holes give a
map that matches how objects look (measured: README "Results"). Default
preset only (``Params.clean_mask``).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np
import numpy.typing as npt

from dynremove.params import Params


def disc(r: int) -> np.ndarray:
    """Disc structuring element of radius ``r`` ((2r+1)², uint8)."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def dilate_disc(m: np.ndarray, r: int) -> npt.NDArray[np.bool_]:
    """``m`` (H, W) bool dilated by ``disc(r)``; a copy when ``r`` <= 0.

    Exactly ``cv2.dilate(m, disc(r))``. From ``_ROWS_FROM_R`` px up (the fill's
    rings of 40-80 px), by the disc's rows: OpenCV's time grows with the disc's
    area (130 ms at r = 80 on 854×480), the rows' with its height (8 ms).
    """
    if r <= 0:
        return np.asarray(m, bool).copy()
    if r < _ROWS_FROM_R:
        return cv2.dilate(np.asarray(m, np.uint8), disc(r)).astype(bool)
    half = ((disc(r).sum(1) - 1) // 2).astype(np.int32)
    return _dilate_by_rows(np.ascontiguousarray(m, np.uint8), half).view(bool)


_ROWS_FROM_R = 10  # px: where the rows' dilation is the faster (measured: equal at 8)


@numba.njit(cache=True, nogil=True)
def _dilate_by_rows(m, half):
    """Dilation of ``m`` (H, W) uint8 by a symmetric element whose row ``i`` spans
    ``half[i]`` px either side of the centre column (``half`` (2r+1,) int32).

    Each row's distance to its nearest set pixel (two passes); a pixel is set
    when, for some row offset dy, the row dy away has a set pixel within
    ``half[dy + r]`` (pixels outside the image count as unset, as OpenCV's
    default border for dilation). Returns (H, W) uint8 0/1.
    """
    H, W = m.shape
    r = (half.shape[0] - 1) // 2
    far = W + 1
    dist = np.empty((H, W), np.int32)
    has = np.zeros(H, np.bool_)
    for y in range(H):
        d = far
        for x in range(W):
            if m[y, x]:
                d = 0
                has[y] = True
            elif d < far:
                d += 1
            dist[y, x] = d
        d = far
        for x in range(W - 1, -1, -1):
            if m[y, x]:
                d = 0
            elif d < far:
                d += 1
            if d < dist[y, x]:
                dist[y, x] = d
    out = np.zeros((H, W), np.uint8)
    for yy in range(H):
        if has[yy]:
            for y in range(max(yy - r, 0), min(yy + r + 1, H)):
                _or_within(dist[yy], half[yy - y + r], out[y])
    return out


@numba.njit(cache=True, nogil=True)
def _or_within(dist, w, out):
    """out |= dist <= w, on one row (a function of its own: the loop vectorises)."""
    for x in range(dist.shape[0]):
        out[x] |= dist[x] <= w


def _open_close(m: np.ndarray, patch_size: int) -> np.ndarray:
    """The clean-up's opening then closing of a (H, W) uint8 map, by a disc of
    ``patch_size // 4`` px (at least 1)."""
    k = disc(max(1, patch_size // 4))
    return cv2.morphologyEx(cv2.morphologyEx(m, cv2.MORPH_OPEN, k), cv2.MORPH_CLOSE, k)


def clean_mask(L: npt.NDArray[np.bool_], params: Params, *, majority: bool = False
               ) -> npt.NDArray[np.bool_]:
    """Open, close, drop small components and fill holes of a (H, W) bool map.

    With ``majority``, a binary median filter (a pixel is set when more than
    half of the (2r+1)² window around it is, r = ``patch_size // 4``, the
    opening's radius) before the same steps gives the *weak* map, the steps
    alone the *strong* one; the result is the strong map plus every weak
    region that holds some of it (hysteresis, as Canny's edges). A slow
    mover's scan map is dense but holed (its patches matched the mover itself
    where the sources still show it): the opening alone erased such meshes (a
    dog's flank, a cow's back), the median keeps them as long as they hang on
    a solid part of the mover. A mesh with no solid part anywhere (motion
    blur, a misaligned patch, where another photo's mover stood) goes as
    before: kept, the fill replaced it with that photo's mover (measured, the
    README's "majority clean-up"). The pipeline asks for it where the set is
    flat (``Params.clean_majority``).
    """
    m = L.astype(np.uint8)
    r = max(1, params.patch_size // 4)

    def opened(m):
        m = _open_close(m, params.patch_size)
        if params.min_region_px > 0:
            m = drop_small(m, params.min_region_px)
        return m

    if majority:
        # hysteresis: the majority's regions are kept where they hold what the
        # opening alone keeps (a mover's solid part); a mesh with no solid part
        # anywhere (a blurred or misaligned patch of background) goes as before
        strong = opened(m)
        weak = opened(cv2.medianBlur(m * np.uint8(255), 2 * r + 1) // np.uint8(255))
        n, lab = cv2.connectedComponents(weak, connectivity=8)
        keep = np.zeros(n, bool)
        keep[np.unique(lab[(strong > 0) & (weak > 0)])] = True  # (never label 0)
        m = (keep[lab] | (strong > 0)).astype(np.uint8)
    else:
        m = opened(m)
    m = fill_holes(m)
    return m.astype(bool)


def clean_mask_drops(L: npt.NDArray[np.bool_], patch_size: int, min_region_px: int
                     ) -> npt.NDArray[np.uint8]:
    """Why ``clean_mask`` (without ``majority``) drops each pixel of L (H, W) bool:
    (H, W) uint8, 1 where the opening (a disc of ``patch_size // 4`` px) erased it,
    2 where its region after the opening and closing is under ``min_region_px``,
    0 where it is kept or not in L. For the debugger (``inspect --pixel``)."""
    opened = _open_close(L.astype(np.uint8), patch_size)
    kept = drop_small(opened, min_region_px) if min_region_px > 0 else opened
    out = np.zeros(L.shape, np.uint8)
    out[L & (opened == 0)] = 1
    out[L & (opened > 0) & (kept == 0)] = 2
    return out


def drop_small(m: np.ndarray, min_px: int) -> np.ndarray:
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_px
    return keep[lab].astype(np.uint8)


def fill_holes(m: np.ndarray) -> np.ndarray:
    """Fill background regions not connected to the image border."""
    inv = (m == 0).astype(np.uint8)
    n, lab = cv2.connectedComponents(inv, connectivity=4)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    hole = (lab > 0) & ~np.isin(lab, border)
    out = m.copy()
    out[hole] = 1
    return out


def grow_replaced(label: npt.NDArray[np.int16], px: int) -> npt.NDArray[np.int16]:
    """The replaced region of a fill's label map (label >= 1: the source) grown by
    ``px`` pixels into the kept reference (label 0), each new pixel taking a
    neighbouring source's label (3×3 grey dilation, ``px`` times); label −1 (outside
    the fill region) never changes. (H, W) int16 in and out.

    Used by the full-size fill, which takes one working pixel more (a kept working
    pixel next to a replaced one is a blend of both, a rim that shows as a thin line at
    full size: seen on a bottle's rim in 12 MP phone photos), and by the fill by
    selection, whose inpainted band takes its neighbours' labels.
    """
    out = label.copy()
    kernel = np.ones((3, 3), np.uint8)
    for _ in range(px):
        grown = cv2.dilate(out, kernel)
        take = (out == 0) & (grown >= 1)
        if not take.any():
            break
        out[take] = grown[take]
    return out


__all__ = ["disc", "dilate_disc", "clean_mask", "drop_small", "fill_holes", "grow_replaced"]

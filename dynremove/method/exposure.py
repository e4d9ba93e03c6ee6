"""Exposure and white balance of the sources, matched to the reference's.

The scans compare colours (f_c is a patch's mean Lab, Sec. 3.1), so a source
shot brighter or darker than the reference disagrees with it everywhere: a
darker reference among brighter photos came out 28 % "dynamic", patched with
the brighter photos' content (a fresh-user trial, shaky_desk6 with one photo at
65 % of its brightness). Each source is therefore mapped, per channel, to the
reference's level before the detection compares them, and the fill uses them
so mapped (given the sources as shot, the fill's own colour tests failed on a
reference at 65 %: 24 % of the movers left).

The map is a gain per channel: the median ratio reference / source over the
pixels that the source's dense matches (homography + flow) bring into register,
where neither is clipped. This is the gain compensation of panorama stitching
(Brown & Lowe, *Automatic Panoramic Image Stitching using Invariant Features*,
IJCV 2007, Sec. 6) made robust: a median instead of the overlaps' mean
intensities, so that the movers and the misregistered parallax do not count.
Where the gain darkens a source, its clipped highlights (a sky at 255) take the
reference's median level at those pixels instead of 255 × gain. A per-level
curve (histogram matching, or the median reference level of each source level)
was tried and dropped: on a wide-baseline set whose sky changes with the view
(SceauxCastle) it bent the curves by up to ×1.9. Only clear differences are
corrected (``min_change``): the photos of one burst differ by a few percent,
which the method absorbs.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

# sampled on a grid of about this many pixels on the long side
_SIDE = 320
# levels counted as unclipped (a clipped channel's ratio is not the gain)
_LO, _HI = 8, 247


def exposure_curves(reference: npt.NDArray[np.uint8], sources: list[npt.NDArray[np.uint8]],
                    fields: list[npt.NDArray[np.float32] | None], *,
                    min_change: float = 0.10, min_px: int = 2000,
                    min_clipped: int = 8) -> npt.NDArray[np.uint8]:
    """Per-channel tone curves that bring each source to the reference's exposure.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
        BGR.
    sources : list of S (H, W, 3) uint8 ndarrays
        BGR, the reference's size.
    fields : list of S (H, W, 2) float32 ndarrays or None
        Each reference pixel's match in the source (x, y), e.g. the homography +
        flow of ``correspondence.dense_correspondence``; None: not matched.
    min_change : float
        A source's curves are kept only when, in some channel, the median over
        its matched pixels of |curve(v) − v| / v is this fraction or more (a
        gain of 1.1 or 0.9 at the default); otherwise all three are the identity.
    min_px : int
        At least this many matched pixels unclipped in both photos, or the curves
        are the identity.
    min_clipped : int
        The clipped highlights' rule needs at least this many matched pixels
        clipped in the source.

    Returns
    -------
    curves : (S, 3, 256) uint8 ndarray
        B, G, R look-up tables: ``curves[s, c][source]`` has the reference's
        level. Each is the gain ``exp(median(log ref − log source))`` over the
        matched pixels where neither photo is clipped (levels 8–247 in all three
        channels; on a grid of about 320 px on the long side). Where the gain
        darkens, the levels from 247 up ramp to the reference's median level at
        the source's clipped pixels, when that is higher (a sky at 255 in the
        brighter photo stays sky, not grey).
    """
    H, W = reference.shape[:2]
    step = max(1, int(np.ceil(max(H, W) / _SIDE)))
    ref = np.ascontiguousarray(reference[::step, ::step])
    ident = np.arange(256, dtype=np.uint8)
    levels = np.arange(256, dtype=np.float64)
    curves = np.tile(ident, (len(sources), 3, 1))
    for k, (src, fk) in enumerate(zip(sources, fields)):
        if fk is None:
            continue
        f = np.ascontiguousarray(fk[::step, ::step], np.float32)
        warped = cv2.remap(src, np.ascontiguousarray(f[..., 0]), np.ascontiguousarray(f[..., 1]),
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        inside = ((f[..., 0] >= 0) & (f[..., 0] <= src.shape[1] - 1)
                  & (f[..., 1] >= 0) & (f[..., 1] <= src.shape[0] - 1))
        if inside.sum() < min_px:
            continue
        change = 0.0
        cur = np.empty((3, 256), np.uint8)
        sw = warped[inside].astype(np.float64)
        rw = ref[inside].astype(np.float64)
        # the gain of each channel: the median ratio where neither photo is clipped
        ok = ((sw >= _LO) & (sw <= _HI) & (rw >= _LO) & (rw <= _HI)).all(-1)
        if ok.sum() < min_px:
            continue
        gain = np.exp(np.median(np.log(rw[ok]) - np.log(sw[ok]), axis=0))
        for c in range(3):
            curve = levels * gain[c]
            # the source's clipped highlights: their true level is unknown, so they
            # take the reference's median level at those pixels where that is
            # higher (a sky at 255 in the brighter photo stays sky, not grey), the
            # levels from _HI up ramping to it
            top = sw[:, c] > _HI
            if gain[c] < 1.0 and top.sum() >= min_clipped:
                m = float(np.median(rw[top, c]))
                if m > curve[255]:
                    t = (levels[_HI:] - _HI) / (255 - _HI)
                    curve[_HI:] = np.maximum(curve[_HI:], curve[_HI] + t * (m - curve[_HI]))
            curve = np.clip(curve, 0, 255)
            cur[c] = np.round(curve).astype(np.uint8)
            sv = sw[:, c].astype(np.intp)
            change = max(change, float(np.median(np.abs(curve[sv] - sv) / np.maximum(sv, 1))))
        if change >= min_change:
            curves[k] = cur
    return curves


def changed(curves: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Which of the (..., 3, 256) ``curves`` change a level: (...) bool, False where
    all three channels are the identity."""
    return (np.asarray(curves) != np.arange(256)).any((-2, -1))


def apply_curves(image: npt.NDArray[np.uint8], curves: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """``image`` (H, W, 3) uint8 BGR through the per-channel look-up tables ``curves``
    (3, 256) uint8 (``cv2.LUT``); the image itself when they are the identity."""
    lut = np.asarray(curves, np.uint8)
    if not changed(lut):
        return image
    return cv2.LUT(image, np.ascontiguousarray(lut.T.reshape(256, 1, 3)))


def mean_gain(curves: npt.ArrayLike, image: npt.NDArray[np.uint8]) -> npt.NDArray[np.float64]:
    """The curves' B, G, R gains at the median level of ``image``'s channels (3,)
    float64: how much brighter (> 1) or darker they make it there (for notes)."""
    lut = np.asarray(curves, np.float64)
    med = np.median(image.reshape(-1, 3)[::97], axis=0).astype(np.intp).clip(1, 255)
    return np.array([lut[c, med[c]] / med[c] for c in range(3)])


__all__ = ["apply_curves", "changed", "exposure_curves", "mean_gain"]

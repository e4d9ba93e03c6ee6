"""The clean photo at the input's full resolution (the analysis ran smaller).

The method runs at a working size (``--max-side``, 1280 px by default); phone
photos are 12 MP. Only the replaced pixels are computed again at full size:

* the label map of the fill by selection (``select.Selection.label``) is
  upsampled (nearest), the replaced region with it;
* each source's field (working-size coordinates) is upsampled to full-size
  coordinates, ``x_full = (x_work + 0.5) · s − 0.5``, and the *full-resolution*
  source is sampled through it, so the fill has the sources' own detail;
* each replaced pixel takes the per-channel median of the sources the
  selection combined there (``Selection.members``, upsampled), then the
  exposure-matching offset of ``montage.offset_blend`` at full size;
* every other pixel is the input's, byte for byte.

Without a selection (the paper preset, or ``fill="median"``), the working-size
clean image is upsampled inside the dynamic region only.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.refine.fields import blurred_lab
from dynremove.refine.montage import offset_blend
from dynremove.refine.morphology import dilate_disc
from dynremove.refine.select import Selection, member_median


def _resize_nearest(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    return cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)


def upsample_mask(mask: npt.NDArray[np.bool_], size: tuple[int, int]) -> npt.NDArray[np.bool_]:
    """(h, w) bool → (H, W) bool at ``size`` = (W, H), smooth edges (linear, ≥ 0.5)."""
    return cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_LINEAR) >= 0.5


def full_resolution(reference: npt.NDArray[np.uint8], sources: list[npt.NDArray[np.uint8]],
                    clean_working: npt.NDArray[np.uint8], dynamic: npt.NDArray[np.bool_],
                    selection: Selection | None) -> tuple[npt.NDArray[np.uint8],
                                                          npt.NDArray[np.bool_]]:
    """The clean reference and dynamic map at the full size of ``reference``.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
        The full-resolution reference, as read (EXIF rotation applied).
    sources : list of (H, W, 3) uint8 ndarrays
        The full-resolution sources, in the order of the run's sources (the
        reference left out, near-copies dropped as the run dropped them).
    clean_working, dynamic : (h, w, 3) uint8 and (h, w) bool ndarrays
        The run's outputs at the working size.
    selection : Selection or None
        ``Result.selection`` of the run.

    Returns
    -------
    clean : (H, W, 3) uint8 ndarray
        Equal to ``reference`` outside the replaced region.
    dynamic : (H, W) bool ndarray
    """
    Hf, Wf = reference.shape[:2]
    h, w = dynamic.shape
    size = (Wf, Hf)
    dyn_full = upsample_mask(dynamic, size)
    clean = reference.copy()
    if selection is None or not (selection.label >= 1).any() or not selection.fields:
        if dyn_full.any():
            up = cv2.resize(clean_working, size, interpolation=cv2.INTER_CUBIC)
            clean[dyn_full] = up[dyn_full]
        return clean, dyn_full
    sx, sy = Wf / w, Hf / h
    label = _resize_nearest(selection.label.astype(np.int16), size).astype(np.intp)
    rep = label >= 1
    ring_px = max(3, int(round(3 * max(sx, sy))))
    ys, xs = np.nonzero(dilate_disc(rep, ring_px + 1))
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    roi = (slice(y0, y1), slice(x0, x1))
    gx, gy = np.meshgrid(np.arange(x0, x1, dtype=np.float32),
                         np.arange(y0, y1, dtype=np.float32))
    wx, wy = (gx + 0.5) / sx - 0.5, (gy + 0.5) / sy - 0.5  # working-size coordinates
    S = len(sources)
    cand = np.empty((S + 1, y1 - y0, x1 - x0, 3), np.uint8)
    cand[0] = reference[roi]
    usable = np.ones((S + 1, y1 - y0, x1 - x0), bool)
    members = np.zeros((S, y1 - y0, x1 - x0), bool)
    for k in range(S):
        f = selection.fields[k]
        fx = cv2.remap(np.ascontiguousarray(f[..., 0]), wx, wy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        fy = cv2.remap(np.ascontiguousarray(f[..., 1]), wx, wy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        mx, my = (fx + 0.5) * sx - 0.5, (fy + 0.5) * sy - 0.5
        Hs, Ws = sources[k].shape[:2]
        cand[k + 1] = cv2.remap(sources[k], mx, my, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
        usable[k + 1] = (mx >= 0) & (mx <= Ws - 1) & (my >= 0) & (my <= Hs - 1)
        if selection.members is not None:
            members[k] = cv2.remap(selection.members[k].astype(np.uint8), wx, wy,
                                   cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=0) > 0
    lab = label[roi]
    rep_roi = rep[roi]
    py, px = np.nonzero(rep_roi)
    chosen = lab[py, px]
    member = members[:, py, px] & usable[1:, py, px]
    member[chosen - 1, np.arange(len(py))] = True
    cand[chosen, py, px] = member_median(cand[1:, py, px], member)
    labs = np.stack([blurred_lab(c, max(sx, sy)) for c in cand])
    d_ref = np.linalg.norm(labs - labs[0][None], axis=-1)
    out = offset_blend(reference[roi], cand, lab, rep_roi, usable, d_ref, ring_px=ring_px)
    no_src = _resize_nearest(selection.no_source.astype(np.uint8), size)[roi] > 0
    if no_src.any():
        out = cv2.inpaint(np.ascontiguousarray(out), (no_src & rep_roi).astype(np.uint8),
                          int(5 * max(sx, sy)), cv2.INPAINT_TELEA)
    clean[roi][rep_roi] = out[rep_roi]
    return clean, dyn_full


__all__ = ["full_resolution", "upsample_mask"]

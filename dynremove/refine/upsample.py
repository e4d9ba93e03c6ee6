"""The clean photo at the input's full resolution (the analysis ran smaller).

The method runs at a working size (``--max-side``, 1280 px by default); phone
photos are 12 MP. Only the replaced pixels are computed again at full size:

* the label map of the fill by selection (``select.Selection.label``) is
  upsampled (nearest), the replaced region with it;
* each source's field (working-size coordinates) is upsampled to full-size
  coordinates, ``x_full = (x_work + 0.5) · s − 0.5``, and the *full-resolution*
  source is sampled through it, so the fill has the sources' own detail;
* each replaced pixel takes the per-channel median of the sources the
  selection combined there (``Selection.members``, upsampled), at the chosen
  source's level (``select.mixture_detail``), then the exposure-matching offset
  of ``montage.offset_blend`` at full size;
* a faint shade the working size relit (``shade.relight_shade``) takes its Lab
  offset, upsampled;
* every other pixel is the input's, byte for byte.

Without a selection (the paper preset, or ``fill="median"``), the working-size
clean image is upsampled inside the dynamic region only.

The replaced region is a small part of its bounding box (7 % on the bench's
12 MP scene), so everything is computed on pixel lists: the sources are sampled
only at the replaced pixels and the band around them that the blend reads
(the ring, widened by the Lab blur), the Lab distance only on the ring, and
the offset's membrane only around the pixels that take it
(``montage.ring_offset``). The result is the one the same steps give on the
whole bounding box, bit for bit.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.refine.colour import delta_e
from dynremove.refine.fields import mask_boxes, remap_points
from dynremove.refine.montage import (BAND_PX, BAND_SIGMA_PX, DECAY_PX, LIGHT_DECAY_PX,
                                      LIGHT_SCALE_PX, LIGHT_SIGMA_PX, PLATEAU_PX, add_offset,
                                      band_around, band_light, component_offsets, ring_agrees,
                                      ring_offset)
from dynremove.refine.morphology import dilate_disc, grow_replaced
from dynremove.refine.select import Selection, member_median, mixture_detail
from dynremove.refine.shade import apply_offset

# offset_blend's max_de: ring pixels departing farther (CIE76) from the ring's
# median difference do not set the offset
_MAX_DE = 15.0


def _resize_nearest(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    return cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)


def upsample_mask(mask: npt.NDArray[np.bool_], size: tuple[int, int]) -> npt.NDArray[np.bool_]:
    """(h, w) bool → (H, W) bool at ``size`` = (W, H), smooth edges (linear, ≥ 0.5)."""
    return cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_LINEAR) >= 0.5


def _lab(pixels: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
    """CIE Lab of (N, 3) BGR uint8 pixels (``fields.blurred_lab``'s conversion)."""
    f = pixels.reshape(-1, 1, 3).astype(np.float32) / 255.0
    return cv2.cvtColor(f, cv2.COLOR_BGR2Lab).reshape(-1, 3)


def full_resolution(reference: npt.NDArray[np.uint8], sources: list[npt.NDArray[np.uint8]],
                    clean_working: npt.NDArray[np.uint8], dynamic: npt.NDArray[np.bool_],
                    selection: Selection | None, *, tau: float = 10.0
                    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
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
    tau : float
        CIE76 ΔE from which a recomputed pixel counts as changed (``select_tau``).

    Returns
    -------
    clean : (H, W, 3) uint8 ndarray
        Equal to ``reference`` outside the replaced region and the relit shade
        (``Selection.relit``, upsampled).
    dynamic : (H, W) bool ndarray
        ``dynamic`` upsampled, plus every recomputed pixel whose colour moved by
        ``tau`` or more (the full-size fill reaches one working pixel further, and
        its seams may run outside ``dynamic``): as at the working size, a pixel
        outside it differs from the reference by less than ``tau``.
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
    blur = max(sx, sy)  # the Lab blur of the blend's distance, one working pixel
    label = grow_replaced(_resize_nearest(selection.label.astype(np.int16), size),
                          math.ceil(blur))
    rep = label >= 1
    rows, cols = np.flatnonzero(rep.any(1)), np.flatnonzero(rep.any(0))
    if not len(rows):
        return clean, dyn_full
    ring_px = max(3, int(round(3 * blur)))
    band_px = (int(round(BAND_PX[0] * blur)), int(round(BAND_PX[1] * blur)))
    # the bounding box of the replaced region dilated by the band's outer radius + 1
    # (a disc reaches as far as a square along the axes)
    m = max(ring_px, band_px[1]) + 1
    y0, y1 = max(rows[0] - m, 0), min(rows[-1] + m + 1, Hf)
    x0, x1 = max(cols[0] - m, 0), min(cols[-1] + m + 1, Wf)
    lab = np.ascontiguousarray(label[y0:y1, x0:x1])
    del label, rep
    rep = lab >= 1
    shape = rep.shape
    ring = dilate_disc(rep, ring_px) & ~rep
    band = band_around(rep, band_px)
    if selection.mask is not None:  # L is no evidence of light (``offset_blend``)
        band &= ~(_resize_nearest(selection.mask.view(np.uint8), size)[y0:y1, x0:x1] > 0)
    # the pixels sampled: the replaced ones and those the blurred ring and band read
    reach = m - 1 + math.ceil(4 * blur) + 1
    near = cv2.dilate(rep.view(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8))
    py, px = np.nonzero(near)
    del near
    index = np.full(shape, -1, np.int32)
    index[py, px] = np.arange(len(py), dtype=np.int32)
    ry, rx = np.nonzero(ring)
    by, bx = np.nonzero(band)
    qy, qx = np.nonzero(rep)  # the replaced pixels (row-major)
    ring_i, band_i, rep_i = index[ry, rx], index[by, bx], index[qy, qx]
    del index
    cand, usable, members = _sample_sources(reference, sources, selection, py + y0, px + x0,
                                            rep_i, (sx, sy))
    # the chosen source of each replaced pixel: the median of the sources combined there
    chosen = lab[qy, qx].astype(np.intp)
    member = members & usable[1:, rep_i]
    member[chosen - 1, np.arange(len(qy))] = True
    cand[chosen, rep_i] = mixture_detail(cand[chosen, rep_i],
                                         member_median(cand[1:, rep_i], member), rep,
                                         LIGHT_SIGMA_PX * blur)
    del members, member
    # the ring's and the band's differences in one pass of blurs (their boxes overlap)
    both = ring | band
    del band
    at = np.full(shape, -1, np.int32)
    at[both] = np.arange(int(np.count_nonzero(both)), dtype=np.int32)
    diff_all = _ring_difference(reference[y0:y1, x0:x1], cand, (py, px), both, blur)
    diff, diff_band = diff_all[:, at[ry, rx]], diff_all[:, at[by, bx]]
    del both, at, diff_all
    # each source plus its offset to the reference, measured on the ring
    ref_ring = reference[ry + y0, rx + x0]
    out = np.empty((len(qy), 3), np.uint8)
    rep_index = np.full(shape, -1, np.int32)  # a replaced pixel's row in ``out``
    rep_index[qy, qx] = np.arange(len(qy), dtype=np.int32)
    for lbl in np.unique(chosen):
        local = band_light(diff_band[lbl], usable[lbl, band_i], (by, bx), (ry, rx),
                           BAND_SIGMA_PX * blur, _MAX_DE)
        good = ring_agrees(diff[lbl], usable[lbl, ring_i], _MAX_DE, local=local)
        mine = chosen == lbl
        sel = rep & (lab == lbl)
        scaled = dict(plateau_px=PLATEAU_PX * blur, decay_px=DECAY_PX * blur,
                      light_sigma_px=LIGHT_SIGMA_PX * blur,
                      light_scale_px=LIGHT_SCALE_PX * blur,
                      light_decay_px=LIGHT_DECAY_PX * blur)
        off = ring_offset(ref_ring, cand[lbl, ring_i], good, (ry, rx), sel, **scaled)
        out[mine] = add_offset(cand[lbl, rep_i[mine]], off)
        for cy, cx, coff in component_offsets(ref_ring, cand[lbl, ring_i], diff[lbl],
                                              usable[lbl, ring_i], ring, sel, rep,
                                              ring_px=ring_px, max_de=_MAX_DE, **scaled):
            at = rep_index[cy, cx]
            out[at] = add_offset(cand[lbl, rep_i[at]], coff)
    if selection.seam_offset is not None:  # the steps of light at the seams removed
        out = add_offset(out, seam_offset_at(selection, qy + y0, qx + x0, chosen, size))
    no_src = _resize_nearest(selection.no_source.view(np.uint8), size)[y0:y1, x0:x1] > 0
    no_src &= rep
    if no_src.any():
        _inpaint(out, reference[y0:y1, x0:x1], rep, no_src, int(5 * blur))
    clean[qy + y0, qx + x0] = out
    cy, cx = qy + y0, qx + x0
    if selection.relit is not None and selection.relight is not None:
        # the relit shade, beside the fill and over part of it: its pixels are
        # judged after it, as at the working size (a trial's 1440×1920 photos had
        # 466 relit px outside the mask moved by ΔE 10–13.7)
        ly, lx = _relight(clean, selection)
        if len(ly):
            # (those not replaced: ``rep`` covers the replaced pixels' box)
            extra = np.ones(len(ly), bool)
            inb = (ly >= y0) & (ly < y1) & (lx >= x0) & (lx < x1)
            extra[inb] = ~rep[ly[inb] - y0, lx[inb] - x0]
            cy, cx = np.concatenate([cy, ly[extra]]), np.concatenate([cx, lx[extra]])
    moved = delta_e(_lab(clean[cy, cx]), _lab(reference[cy, cx])) >= tau
    dyn_full[cy[moved], cx[moved]] = True
    return clean, dyn_full


def seam_offset_at(selection: Selection, ys: npt.NDArray[np.intp], xs: npt.NDArray[np.intp],
                   chosen: npt.NDArray[np.intp], size: tuple[int, int]
                   ) -> npt.NDArray[np.float32]:
    """``Selection.seam_offset`` at the full-size pixels (``ys``, ``xs``) whose labels
    are ``chosen``: (N, 3) float32 B/G/R levels. Bilinear within each label
    (normalised by the label's own working pixels under the kernel): the correction
    steps at a seam, so a pixel takes none of the other label's side; 0 where no
    working pixel of its label is under the kernel. ``size`` = (W, H) full size."""
    Wf, Hf = size
    h, w = selection.label.shape
    mx = ((xs + 0.5) * w / Wf - 0.5).astype(np.float32)
    my = ((ys + 0.5) * h / Hf - 0.5).astype(np.float32)
    out = np.zeros((len(ys), 3), np.float32)
    for lbl in np.unique(chosen):
        at = np.flatnonzero(chosen == lbl)
        mine = (selection.label == lbl).astype(np.float32)
        num = remap_points(selection.seam_offset * mine[..., None], mx[at], my[at],
                           borderMode=cv2.BORDER_REPLICATE)
        den = remap_points(mine, mx[at], my[at], borderMode=cv2.BORDER_REPLICATE)
        out[at] = np.where((den > 1e-6)[:, None], num / np.maximum(den, 1e-6)[:, None], 0)
    return out


def _relight(clean: np.ndarray, selection: Selection
             ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """The working size's relit shade (``shade.relight_shade``) at full size, in place:
    its Lab offset upsampled (bilinear: it is smooth) and added at its pixels,
    upsampled (inside the replaced region too, where the fill was relit). Returns
    those pixels' rows and columns (full size; empty where nothing was relit)."""
    Hf, Wf = clean.shape[:2]
    h, w = selection.relit.shape
    relit = upsample_mask(selection.relit, (Wf, Hf))
    if not relit.any():
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    rows, cols = np.flatnonzero(relit.any(1)), np.flatnonzero(relit.any(0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    # the box's rows and columns in working coordinates (pixel centres), sampled
    ys = ((np.arange(y0, y1) + 0.5) * h / Hf - 0.5).astype(np.float32)
    xs = ((np.arange(x0, x1) + 0.5) * w / Wf - 0.5).astype(np.float32)
    mx, my = np.meshgrid(xs, ys)
    off = cv2.remap(selection.relight, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    box = (slice(y0, y1), slice(x0, x1))
    clean[box] = apply_offset(clean[box], off, relit[box])
    ly, lx = np.nonzero(relit[box])
    return ly + y0, lx + x0


def _sample_sources(reference: np.ndarray, sources: list[np.ndarray], selection: Selection,
                    ys: np.ndarray, xs: np.ndarray, rep_i: np.ndarray,
                    scale: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every source sampled at the full-size pixels (``ys``, ``xs``) through its
    upsampled field, one source at a time.

    Returns ``cand`` (S + 1, N, 3) uint8 (the reference first), ``usable``
    (S + 1, N) bool (the sample inside its source) and ``members`` (S, len(rep_i))
    bool (``Selection.members`` at the points ``rep_i``).
    """
    sx, sy = scale
    wx = xs.astype(np.float32)  # working-size coordinates
    wx += 0.5
    wx /= sx
    wx -= 0.5
    wy = ys.astype(np.float32)
    wy += 0.5
    wy /= sy
    wy -= 0.5
    S, n = len(sources), len(ys)
    cand = np.empty((S + 1, n, 3), np.uint8)
    cand[0] = reference[ys, xs]
    usable = np.ones((S + 1, n), bool)
    members = np.zeros((S, len(rep_i)), bool)
    for k in range(S):
        f = selection.fields[k]
        mx = remap_points(np.ascontiguousarray(f[..., 0]), wx, wy, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        my = remap_points(np.ascontiguousarray(f[..., 1]), wx, wy, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        mx = (mx + 0.5) * sx - 0.5  # full-size coordinates
        my = (my + 0.5) * sy - 0.5
        Hs, Ws = sources[k].shape[:2]
        src = sources[k]
        if selection.blur_sigma is not None and selection.blur_sigma[k] > 0:
            # a reference softer than this source: its fill blurred to match, as at
            # the working size (``select.reference_blur``), σ scaled to full size
            src = cv2.GaussianBlur(src, (0, 0), float(selection.blur_sigma[k]) * max(sx, sy))
        cand[k + 1] = remap_points(src, mx, my, cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_REPLICATE)
        usable[k + 1] = (mx >= 0) & (mx <= Ws - 1) & (my >= 0) & (my <= Hs - 1)
        if selection.members is not None:
            members[k] = remap_points(selection.members[k].view(np.uint8), wx[rep_i],
                                       wy[rep_i], cv2.INTER_NEAREST,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    return cand, usable, members


def _ring_difference(reference: np.ndarray, cand: np.ndarray, points: tuple[np.ndarray, ...],
                     ring: np.ndarray, blur: float) -> np.ndarray:
    """The reference's Lab minus every candidate's on the ring (S + 1, R, 3) float32,
    both blurred (``fields.blurred_lab``), the blur run on boxes around the ring.

    ``reference``: the box's reference; ``cand`` (S + 1, N, 3): the candidates at
    ``points`` (the box's pixels the blurred ring reads).
    """
    # a copy, always: the candidates are written into it (np.ascontiguousarray would
    # return the caller's reference itself when the box spans its whole width, and
    # the writes below then overwrote the input photo and the ring read after)
    img = np.array(reference, order="C", copy=True)
    ry, rx = np.nonzero(ring)
    ring_index = np.zeros(ring.shape, np.int32)
    ring_index[ry, rx] = np.arange(len(ry), dtype=np.int32)
    H, W = ring.shape
    boxes = [(b, ring_index[b[0]:b[1], b[2]:b[3]][keep], keep)
             for b, keep in mask_boxes(ring, math.ceil(4 * blur) + 1, (0, H, 0, W))]
    lab_ring = np.empty((len(cand), len(ry), 3), np.float32)
    for k in range(len(cand)):
        if k:
            img[points] = cand[k]
        for (b0, b1, c0, c1), i, keep in boxes:
            box = cv2.GaussianBlur(np.ascontiguousarray(img[b0:b1, c0:c1]), (0, 0), blur)
            lab_ring[k, i] = _lab(box[keep])
    return lab_ring[0][None] - lab_ring


def _inpaint(out: np.ndarray, reference: np.ndarray, rep: np.ndarray, hole: np.ndarray,
             radius: int) -> None:
    """Telea-inpaint ``hole`` of the image ``reference`` with ``out`` at ``rep``
    (written back into ``out``), on the box around ``hole`` that decides it."""
    H, W = hole.shape
    ys, xs = np.nonzero(hole)
    m = 2 * radius + 2
    y0, y1 = max(ys.min() - m, 0), min(ys.max() + m + 1, H)
    x0, x1 = max(xs.min() - m, 0), min(xs.max() + m + 1, W)
    box = np.array(reference[y0:y1, x0:x1], order="C", copy=True)  # written below
    qy, qx = np.nonzero(rep)
    inside = (qy >= y0) & (qy < y1) & (qx >= x0) & (qx < x1)
    box[qy[inside] - y0, qx[inside] - x0] = out[inside]
    box = cv2.inpaint(box, hole[y0:y1, x0:x1].view(np.uint8), radius, cv2.INPAINT_TELEA)
    out[inside] = box[qy[inside] - y0, qx[inside] - x0]


__all__ = ["full_resolution", "grow_replaced", "upsample_mask"]

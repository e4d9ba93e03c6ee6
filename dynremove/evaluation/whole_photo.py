"""Whole-photo measures: what a removal did to the whole image, not just the mover.

PSNR / SSIM of the whole image, :func:`delta_e76` (CIE76 colour difference),
:func:`damage_percent` (good pixels the method broke) and
:func:`leftover_percent` (mover pixels it could have removed but did not) and
:func:`leftover_split` (of those, the ones left as the input showed them and
the ones changed, but wrongly) and :func:`own_mover_fill_percent` (filled pixels
taken from the other photos' own movers: the ghosts).
Pure functions on plain arrays, like :mod:`dynremove.evaluation.metrics`
(masks ``(H, W)`` indexed ``[y, x]``, images ``(H, W)`` or ``(H, W, C)``).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.evaluation.metrics import _as_mask, _check_same_shape, psnr_in_mask, ssim_in_mask

__all__ = [
    "psnr",
    "ssim",
    "delta_e76",
    "damage_percent",
    "leftover_percent",
    "leftover_split",
    "kept_by_step",
    "misplaced_fill_percent",
    "own_mover_fill_percent",
    "DAMAGE_DILATE_PX",
    "DE_MAX",
    "DE_BLUR_SIGMA",
    "MISPLACED_SHIFT_PX",
]

#: Guard band (pixels) around the true mask excluded from :func:`damage_percent`.
DAMAGE_DILATE_PX: int = 5
#: CIE76 colour difference above which a pixel is "wrong" (L in 0..100).
DE_MAX: float = 10.0
#: Gaussian blur (pixels) applied to both images before the colour comparison.
DE_BLUR_SIGMA: float = 1.0
#: Shift (pixels, each axis) within which :func:`misplaced_fill_percent` finds the
#: true background again: a wrong fill that is the right content, a little misplaced.
MISPLACED_SHIFT_PX: int = 2


def psnr(img: npt.ArrayLike, ref: npt.ArrayLike, *, data_range: float = 255) -> float:
    """Peak signal-to-noise ratio over the whole image.

    Same as :func:`psnr_in_mask` with an all-true mask.

    Parameters
    ----------
    img : (H, W) or (H, W, C) ndarray
        Image to evaluate (e.g. the cleaned reference).
    ref : (H, W) or (H, W, C) ndarray
        Ground truth (e.g. the true background), same shape as ``img``.
    data_range : float, optional
        Peak value ``L`` (255 for 8-bit images).

    Returns
    -------
    psnr : float
        PSNR in dB over every pixel and channel; ``inf`` for identical images.

    Examples
    --------
    >>> import numpy as np
    >>> ref = np.full((4, 4), 100, np.uint8)
    >>> round(psnr(ref + np.uint8(10), ref), 4)
    28.1308
    """
    a = np.asarray(img)
    return psnr_in_mask(a, ref, np.ones(a.shape[:2], bool), data_range=data_range)


def ssim(img: npt.ArrayLike, ref: npt.ArrayLike, *, data_range: float = 255) -> float:
    """Mean SSIM over the whole image (colour: per channel, then averaged).

    Same as :func:`ssim_in_mask` with an all-true mask.

    Parameters
    ----------
    img : (H, W) or (H, W, C) ndarray
        Image to evaluate.
    ref : (H, W) or (H, W, C) ndarray
        Ground truth, same shape as ``img``.
    data_range : float, optional
        Dynamic range ``L`` of the images (255 for 8-bit).

    Returns
    -------
    ssim : float
        Mean SSIM in ``[-1, 1]``; ``1.0`` for identical images.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.full((5, 5), 100.0)
    >>> ssim(a, a)
    1.0
    """
    a = np.asarray(img)
    return ssim_in_mask(a, ref, np.ones(a.shape[:2], bool), data_range=data_range)


def _bgr(img: npt.ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{name} must be an (H, W, 3) BGR image, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got {a.dtype}")
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite (found NaN/inf)")
    return a


def _lab(img: np.ndarray, blur_sigma: float) -> np.ndarray:
    """Blurred float32 BGR (0..255) -> Lab with L in 0..100."""
    x = img / np.float32(255.0)
    if blur_sigma > 0:
        x = cv2.GaussianBlur(x, (0, 0), float(blur_sigma), sigmaY=float(blur_sigma),
                             borderType=cv2.BORDER_REFLECT_101)
    return cv2.cvtColor(x, cv2.COLOR_BGR2Lab)


def _check_sigma(blur_sigma: float) -> float:
    s = float(blur_sigma)
    if not (math.isfinite(s) and s >= 0):
        raise ValueError(f"blur_sigma must be a finite number >= 0, got {blur_sigma}")
    return s


def delta_e76(a: npt.ArrayLike, b: npt.ArrayLike, *,
              blur_sigma: float = DE_BLUR_SIGMA) -> npt.NDArray[np.float32]:
    """Per-pixel CIE76 colour difference of two BGR images, after a light blur.

    Both images are scaled to ``[0, 1]`` (``float32 / 255``), blurred with a
    Gaussian of standard deviation ``blur_sigma`` pixels (``cv2.GaussianBlur``,
    borders reflected; no blur when 0), converted with
    ``cv2.cvtColor(..., cv2.COLOR_BGR2Lab)`` (L in 0..100, a and b about
    -127..127) and compared as ``||Lab_a - Lab_b||_2``. The blur makes the
    measure tolerant of sub-pixel misalignment and noise.

    Parameters
    ----------
    a, b : (H, W, 3) ndarray
        BGR images with values in 0..255 (uint8 or float), same shape.
    blur_sigma : float, optional
        Gaussian sigma in pixels (default 1).

    Returns
    -------
    de : (H, W) float32 ndarray
        ΔE*ab (CIE76), 0 where the (blurred) colours agree; ~2.3 is a just
        noticeable difference.

    Raises
    ------
    ValueError
        On non-colour images, mismatched shapes, non-finite values or a negative
        ``blur_sigma``.

    Examples
    --------
    >>> import numpy as np
    >>> a = np.zeros((3, 3, 3), np.uint8); b = a.copy(); b[...] = 255
    >>> float(delta_e76(a, a).max()), round(float(delta_e76(a, b).mean()), 1)
    (0.0, 100.0)
    """
    s = _check_sigma(blur_sigma)
    x, y = _bgr(a, "a"), _bgr(b, "b")
    _check_same_shape(x, y, "a", "b")
    return np.linalg.norm(_lab(x, s) - _lab(y, s), axis=2).astype(np.float32)


def _disc(r: int) -> np.ndarray:
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return (xx * xx + yy * yy <= r * r).astype(np.uint8)


def damage_percent(
    reference: npt.ArrayLike,
    output: npt.ArrayLike,
    background: npt.ArrayLike,
    true_mask: npt.ArrayLike,
    *,
    dilate_px: int = DAMAGE_DILATE_PX,
    de_max: float = DE_MAX,
    blur_sigma: float = DE_BLUR_SIGMA,
) -> float:
    """Percent of the photo that was right in the input and is wrong in the output.

    A pixel counts as *damaged* when all three hold:

    1. it lies outside the true mask dilated by a disc of radius ``dilate_px``
       (the pixels ``(dx, dy)`` with ``dx² + dy² <= dilate_px²``), so the
       feathered rim of the mover and the region the method is meant to change
       are left out;
    2. it was right in the input: ``ΔE(reference, background) <= de_max``;
    3. it is wrong in the output: ``ΔE(output, background) > de_max``;

    with ΔE the CIE76 difference of :func:`delta_e76` (both images blurred with
    a Gaussian of ``blur_sigma`` px before the Lab conversion). The count is
    divided by **all** ``H * W`` pixels of the image, so the figure reads
    "percent of the photo broken".

    Parameters
    ----------
    reference : (H, W, 3) ndarray
        The input reference view (with the movers), BGR 0..255.
    output : (H, W, 3) ndarray
        The method's cleaned reference, BGR 0..255.
    background : (H, W, 3) ndarray
        The true clean reference, BGR 0..255.
    true_mask : (H, W) bool-like ndarray
        True dynamic mask of the reference; nonzero means ``True``.
    dilate_px : int, optional
        Guard band around the true mask, pixels (default 5; 0 = none).
    de_max : float, optional
        ΔE threshold (default 10).
    blur_sigma : float, optional
        Gaussian sigma in pixels applied before the colour conversion
        (default 1; 0 = no blur).

    Returns
    -------
    damage : float
        Percent in ``[0, 100]`` of all image pixels.

    Raises
    ------
    ValueError
        On mismatched shapes, non-colour images, a negative ``dilate_px`` or
        ``blur_sigma``, or a non-positive ``de_max``.

    Examples
    --------
    A 10x10 image, a mover in the top-left corner, and an output that is the
    background except for a 2x2 patch in the bottom-right corner (4 % of the
    photo):

    >>> import numpy as np
    >>> bg = np.full((10, 10, 3), 128, np.uint8)
    >>> mask = np.zeros((10, 10), bool); mask[:2, :2] = True
    >>> ref = bg.copy(); ref[mask] = (0, 0, 255)
    >>> out = bg.copy(); out[8:, 8:] = (255, 0, 0)
    >>> damage_percent(ref, out, bg, mask, dilate_px=2, blur_sigma=0)
    4.0
    >>> damage_percent(ref, bg, bg, mask)
    0.0
    """
    dm = float(de_max)
    if not (math.isfinite(dm) and dm > 0):
        raise ValueError(f"de_max must be a finite positive number, got {de_max}")
    r = int(dilate_px)
    if r < 0 or r != dilate_px:
        raise ValueError(f"dilate_px must be an integer >= 0, got {dilate_px}")
    s = _check_sigma(blur_sigma)
    ref_, out_, bg_ = _bgr(reference, "reference"), _bgr(output, "output"), \
        _bgr(background, "background")
    _check_same_shape(ref_, bg_, "reference", "background")
    _check_same_shape(out_, bg_, "output", "background")
    m = _as_mask(true_mask, "true_mask")
    if m.shape != bg_.shape[:2]:
        raise ValueError(f"true_mask must have the image's (H, W) = {bg_.shape[:2]}, "
                         f"got {m.shape}")
    near = m.astype(np.uint8)
    if r > 0:
        near = cv2.dilate(near, _disc(r), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    lab_bg = _lab(bg_, s)
    right_in = np.linalg.norm(_lab(ref_, s) - lab_bg, axis=2) <= dm
    wrong_out = np.linalg.norm(_lab(out_, s) - lab_bg, axis=2) > dm
    n = int(np.count_nonzero((near == 0) & right_in & wrong_out))
    return 100.0 * n / m.size


def leftover_percent(
    output: npt.ArrayLike,
    background: npt.ArrayLike,
    true_mask: npt.ArrayLike,
    recoverable: npt.ArrayLike | None = None,
    *,
    de_max: float = DE_MAX,
    blur_sigma: float = DE_BLUR_SIGMA,
) -> tuple[float | None, float | None]:
    """Percent of the removable mover still wrong in the output, and what was not removable.

    *Leftover* is the percent of the true-mask pixels that are recoverable
    (``recoverable`` true: some other view saw the background there free of
    movers) whose output colour is still wrong, ``ΔE(output, background) >
    de_max`` (CIE76 after a ``blur_sigma`` px Gaussian blur, see
    :func:`delta_e76`). *Unrecoverable* is the percent of the true mask that no
    other view saw free; those pixels are left out of the leftover figure
    since no method working from the views could restore them.

    Parameters
    ----------
    output : (H, W, 3) ndarray
        The method's cleaned reference, BGR 0..255.
    background : (H, W, 3) ndarray
        The true clean reference, BGR 0..255.
    true_mask : (H, W) bool-like ndarray
        True dynamic mask of the reference; nonzero means ``True``.
    recoverable : (H, W) bool-like ndarray or None, optional
        Pixels seen free of movers by at least one other view (e.g.
        ``free.png`` of ``dynremove composite``). ``None``: unknown, the whole
        true mask is counted and ``unrecoverable`` is ``None``.
    de_max : float, optional
        ΔE threshold (default 10).
    blur_sigma : float, optional
        Gaussian sigma in pixels (default 1; 0 = no blur).

    Returns
    -------
    leftover : float or None
        Percent in ``[0, 100]`` of the recoverable true-mask pixels still
        wrong; ``None`` when there is no such pixel (empty mask, or nothing
        recoverable).
    unrecoverable : float or None
        Percent in ``[0, 100]`` of the true mask not recoverable; ``None`` when
        ``recoverable`` is ``None`` or the true mask is empty.

    Raises
    ------
    ValueError
        On mismatched shapes, non-colour images, a negative ``blur_sigma`` or a
        non-positive ``de_max``.

    Examples
    --------
    A 4x4 mover whose right half no other view saw; the output fixed only the
    top-left quarter of it:

    >>> import numpy as np
    >>> bg = np.full((8, 8, 3), 128, np.uint8)
    >>> mask = np.zeros((8, 8), bool); mask[2:6, 2:6] = True
    >>> free = np.zeros((8, 8), bool); free[:, :4] = True
    >>> out = bg.copy(); out[mask] = (0, 0, 255); out[2:4, 2:4] = 128
    >>> leftover_percent(out, bg, mask, free, blur_sigma=0)
    (50.0, 50.0)
    >>> leftover_percent(out, bg, mask, blur_sigma=0)
    (75.0, None)
    """
    count, unrec, wrong, _ = _leftover_pixels(output, background, true_mask, recoverable,
                                              de_max, blur_sigma)
    n = int(np.count_nonzero(count))
    if n == 0:
        return None, unrec
    return 100.0 * int(np.count_nonzero(wrong & count)) / n, unrec


def _leftover_pixels(output, background, true_mask, recoverable, de_max, blur_sigma):
    """The checks and pixels behind :func:`leftover_percent`: ``(count, unrec, wrong,
    lab_out)``: the recoverable true mask, the unrecoverable percent, where the
    output is wrong (None when ``count`` is empty) and the output's Lab."""
    dm = float(de_max)
    if not (math.isfinite(dm) and dm > 0):
        raise ValueError(f"de_max must be a finite positive number, got {de_max}")
    s = _check_sigma(blur_sigma)
    out_, bg_ = _bgr(output, "output"), _bgr(background, "background")
    _check_same_shape(out_, bg_, "output", "background")
    m = _as_mask(true_mask, "true_mask")
    if m.shape != bg_.shape[:2]:
        raise ValueError(f"true_mask must have the image's (H, W) = {bg_.shape[:2]}, "
                         f"got {m.shape}")
    n_mask = int(np.count_nonzero(m))
    unrec: float | None = None
    count = m
    if recoverable is not None:
        rec = _as_mask(recoverable, "recoverable")
        _check_same_shape(rec, m, "recoverable", "true_mask")
        count = m & rec
        if n_mask:
            unrec = 100.0 * (n_mask - int(np.count_nonzero(count))) / n_mask
    if not count.any():
        return count, unrec, None, None
    lab_out = _lab(out_, s)
    wrong = np.linalg.norm(lab_out - _lab(bg_, s), axis=2) > dm
    return count, unrec, wrong, lab_out


def _as_input(lab_out: np.ndarray, reference: npt.ArrayLike, de_max: float,
              blur_sigma: float) -> np.ndarray:
    """(H, W) bool: where the output (its blurred Lab ``lab_out``) still matches the
    input reference (ΔE <= ``de_max``, the reference blurred alike): what
    :func:`leftover_split` counts as kept. ValueError when the shapes differ."""
    ref_ = _bgr(reference, "reference")
    _check_same_shape(lab_out, ref_, "output", "reference")
    return (np.linalg.norm(lab_out - _lab(ref_, _check_sigma(blur_sigma)), axis=2)
            <= float(de_max))


def leftover_split(
    output: npt.ArrayLike,
    reference: npt.ArrayLike,
    background: npt.ArrayLike,
    true_mask: npt.ArrayLike,
    recoverable: npt.ArrayLike | None = None,
    *,
    de_max: float = DE_MAX,
    blur_sigma: float = DE_BLUR_SIGMA,
) -> tuple[float | None, float | None]:
    """The leftover of :func:`leftover_percent` split by cause: kept and refilled.

    Of the recoverable true-mask pixels still wrong in the output (``ΔE(output,
    background) > de_max``), *kept* counts those whose output still matches the
    input reference (``ΔE(output, reference) <= de_max``: the method left the
    mover there, a miss of its detection) and *refilled* those it changed but
    not into the background (a wrong fill). Both are percents of the same
    recoverable true mask, so they add up to the leftover. The split needs no
    mask from the method, so it applies to every method alike.

    Parameters
    ----------
    output, reference, background : (H, W, 3) ndarray
        The method's cleaned reference, the input reference and the true clean
        reference, BGR 0..255.
    true_mask, recoverable, de_max, blur_sigma
        As in :func:`leftover_percent`.

    Returns
    -------
    kept, refilled : float or None
        Percents in ``[0, 100]``; ``None`` where :func:`leftover_percent` gives
        ``None`` (no recoverable true-mask pixel).

    Raises
    ------
    ValueError
        As :func:`leftover_percent`, and when ``reference`` is not the output's shape.

    Examples
    --------
    A 4x4 mover: the output restored its top row, left its second row as the
    input had it and filled its bottom half with a wrong colour:

    >>> import numpy as np
    >>> bg = np.full((8, 8, 3), 128, np.uint8)
    >>> mask = np.zeros((8, 8), bool); mask[2:6, 2:6] = True
    >>> ref = bg.copy(); ref[mask] = (0, 0, 255)
    >>> out = ref.copy(); out[2, 2:6] = 128; out[4:6, 2:6] = (255, 0, 0)
    >>> leftover_split(out, ref, bg, mask, blur_sigma=0)
    (25.0, 50.0)
    """
    count, _, wrong, lab_out = _leftover_pixels(output, background, true_mask, recoverable,
                                                de_max, blur_sigma)
    if wrong is None:
        return None, None
    as_input = _as_input(lab_out, reference, de_max, blur_sigma)
    n = int(np.count_nonzero(count))
    kept = 100.0 * int(np.count_nonzero(wrong & as_input & count)) / n
    refilled = 100.0 * int(np.count_nonzero(wrong & ~as_input & count)) / n
    return kept, refilled


def kept_by_step(
    output: npt.ArrayLike,
    reference: npt.ArrayLike,
    background: npt.ArrayLike,
    true_mask: npt.ArrayLike,
    recoverable: npt.ArrayLike | None = None,
    *,
    scanned: npt.ArrayLike,
    fill_input: npt.ArrayLike,
    replaced: npt.ArrayLike,
    de_max: float = DE_MAX,
    blur_sigma: float = DE_BLUR_SIGMA,
) -> dict[str, float] | None:
    """The *kept* leftover of :func:`leftover_split`, split by the step that left it.

    Each kept pixel (recoverable, true mask, still wrong, the output as the input)
    counts once, for the first that applies:

    - ``replaced``: the method replaced it, yet the output shows what the input did
      (a source's own copy of the mover, or a blend that took the fill back);
    - ``fill``: in the dynamic map the fill started from, which kept the reference
      there (dynremove's fill by selection: its consensus, graph cut or region rules);
    - ``refinement``: in the scans' map, dropped before the fill (the clean-up, the
      border votes, the snap to edges);
    - ``missed``: never in the scans' map.

    They add up to :func:`leftover_split`'s kept part, in percents of the same
    recoverable true mask: where work on the detection, on the refinement or on
    the fill would pay off.

    Parameters
    ----------
    output, reference, background, true_mask, recoverable, de_max, blur_sigma
        As in :func:`leftover_split`.
    scanned, fill_input, replaced : (H, W) bool array_like
        The scans' map, the map the fill took, and the pixels the method replaced
        (for a method without a refinement or a fill of its own, the same map may be
        given twice or three times).

    Returns
    -------
    dict or None
        ``{"missed", "refinement", "fill", "replaced"}`` percents in ``[0, 100]``;
        None where :func:`leftover_percent` gives None.

    Raises
    ------
    ValueError
        As :func:`leftover_split`, and when a map is not the image's (H, W).

    Examples
    --------
    A 4x4 mover, output as the input on rows 2 to 4: row 2 never scanned, row 3
    scanned but dropped, row 4 in the fill's map and kept; row 5 restored.

    >>> import numpy as np
    >>> bg = np.full((8, 8, 3), 128, np.uint8)
    >>> mask = np.zeros((8, 8), bool); mask[2:6, 2:6] = True
    >>> ref = bg.copy(); ref[mask] = (0, 0, 255)
    >>> out = ref.copy(); out[5, 2:6] = 128
    >>> scan = np.zeros((8, 8), bool); scan[3:6, 2:6] = True
    >>> fill_in = np.zeros((8, 8), bool); fill_in[4:6, 2:6] = True
    >>> rep = np.zeros((8, 8), bool); rep[5, 2:6] = True
    >>> kept_by_step(out, ref, bg, mask, scanned=scan, fill_input=fill_in,
    ...              replaced=rep, blur_sigma=0)
    {'missed': 25.0, 'refinement': 25.0, 'fill': 25.0, 'replaced': 0.0}
    """
    count, _, wrong, lab_out = _leftover_pixels(output, background, true_mask, recoverable,
                                                de_max, blur_sigma)
    if wrong is None:
        return None
    maps = {}
    for name, m in (("scanned", scanned), ("fill_input", fill_input), ("replaced", replaced)):
        maps[name] = _as_mask(m, name)
        _check_same_shape(maps[name], count, name, "true_mask")
    kept = wrong & _as_input(lab_out, reference, de_max, blur_sigma) & count
    rep = kept & maps["replaced"]
    fill = kept & ~rep & maps["fill_input"]
    refinement = kept & ~rep & ~fill & maps["scanned"]
    missed = kept & ~rep & ~fill & ~refinement
    n = int(np.count_nonzero(count))
    return {k: 100.0 * int(np.count_nonzero(v)) / n
            for k, v in (("missed", missed), ("refinement", refinement), ("fill", fill),
                         ("replaced", rep))}


def misplaced_fill_percent(
    output: npt.ArrayLike,
    reference: npt.ArrayLike,
    background: npt.ArrayLike,
    true_mask: npt.ArrayLike,
    recoverable: npt.ArrayLike | None = None,
    *,
    shift_px: int = MISPLACED_SHIFT_PX,
    de_max: float = DE_MAX,
    blur_sigma: float = DE_BLUR_SIGMA,
) -> float | None:
    """The part of :func:`leftover_split`'s *refilled* that is the right content misplaced.

    A refilled pixel (wrong in the output, changed from the input) counts as
    *misplaced* where the true background, shifted by at most ``shift_px`` pixels
    along each axis, matches the output there (CIE76 ΔE ≤ ``de_max``, both blurred
    as in :func:`leftover_percent`; the background's border replicated). Such a
    fill shows the hidden scene a pixel or two off (its geometry), which a viewer
    who never saw the truth does not see; the rest of *refilled* is other content
    (a ghost, a blob of inpainting). An edge smeared across a pixel or two also
    counts (its mixed colours match the edge a little to the side). Percent of the
    same recoverable true mask, so ``misplaced <= refilled``.

    Parameters
    ----------
    output, reference, background, true_mask, recoverable, de_max, blur_sigma
        As in :func:`leftover_split`.
    shift_px : int
        The largest shift tried along each axis (>= 0; 0 counts nothing).

    Returns
    -------
    float or None
        Percent in ``[0, 100]``; ``None`` where :func:`leftover_percent` gives ``None``.

    Raises
    ------
    ValueError
        As :func:`leftover_split`, and for a negative ``shift_px``.

    Examples
    --------
    A striped 6x6 patch filled one pixel to the right (misplaced), and a second
    patch filled with a flat grey (other content):

    >>> import numpy as np
    >>> bg = np.zeros((12, 24, 3), np.uint8); bg[:, ::2] = 255
    >>> mask = np.zeros((12, 24), bool); mask[3:9, 3:9] = mask[3:9, 15:21] = True
    >>> ref = bg.copy(); ref[mask] = (0, 0, 255)
    >>> out = bg.copy(); out[3:9, 3:9] = bg[3:9, 4:10]; out[3:9, 15:21] = 128
    >>> leftover_split(out, ref, bg, mask, blur_sigma=0)
    (0.0, 100.0)
    >>> misplaced_fill_percent(out, ref, bg, mask, blur_sigma=0)
    50.0
    """
    if isinstance(shift_px, bool) or not isinstance(shift_px, (int, np.integer)) or shift_px < 0:
        raise ValueError(f"shift_px must be an integer >= 0, got {shift_px!r}")
    count, _, wrong, lab_out = _leftover_pixels(output, background, true_mask, recoverable,
                                                de_max, blur_sigma)
    if wrong is None:
        return None
    sigma = _check_sigma(blur_sigma)
    refilled = wrong & count & ~_as_input(lab_out, reference, de_max, blur_sigma)
    ys, xs = np.nonzero(refilled)
    n = int(np.count_nonzero(count))
    if shift_px == 0 or not len(ys):
        return 0.0
    s = int(shift_px)
    lab_bg = np.pad(_lab(_bgr(background, "background"), sigma), ((s, s), (s, s), (0, 0)),
                    mode="edge")
    v = lab_out[ys, xs]
    near = np.zeros(len(ys), bool)
    for dy in range(-s, s + 1):
        for dx in range(-s, s + 1):
            near |= np.linalg.norm(v - lab_bg[ys + s + dy, xs + s + dx], axis=1) <= float(de_max)
    return 100.0 * int(np.count_nonzero(near)) / n


def own_mover_fill_percent(
    replaced: npt.ArrayLike,
    members: npt.ArrayLike,
    fields: npt.ArrayLike,
    source_masks: list[npt.ArrayLike | None],
) -> float | None:
    """Percent of the filled pixels whose fill came mostly from the sources' own movers.

    Issue 10: "a source's own mover must never enter the fill". A replaced
    pixel is *ghosted* when at least half of the sources combined there
    (``members``) sample it, through their field, inside their *own* true
    mover mask (each source's annotated mask, in its own frame; nearest pixel).
    A member sampled outside its frame counts as not on a mover.

    Parameters
    ----------
    replaced : (H, W) bool-like ndarray
        The pixels the fill replaced (reference frame).
    members : (S, H, W) bool-like ndarray
        The sources combined at each replaced pixel (``Selection.members``).
    fields : (S, H, W, 2) float ndarray
        Each source's match (x, y) in its own pixels (``Selection.fields``).
    source_masks : list of S (H, W) bool-like ndarrays or None
        Each source's true mover mask; ``None`` where a source has none.

    Returns
    -------
    float or None
        Percent in ``[0, 100]`` of the replaced pixels with at least one member;
        ``None`` when there is no such pixel or some member source has no mask.

    Raises
    ------
    ValueError
        Shapes that do not agree.
    """
    rep = _as_mask(replaced, "replaced")
    mem = np.asarray(members, bool)
    f = np.asarray(fields)
    S = len(source_masks)
    if mem.shape != (S,) + rep.shape or f.shape[:3] != mem.shape or f.shape[3:] != (2,):
        raise ValueError(f"members {mem.shape}, fields {f.shape} and {S} source masks do "
                         f"not agree with replaced {rep.shape}")
    ys, xs = np.nonzero(rep & mem.any(0))
    if len(ys) == 0:
        return None
    n_mem = np.zeros(len(ys), np.int64)
    n_own = np.zeros(len(ys), np.int64)
    for k in range(S):
        mk = mem[k, ys, xs]
        if not mk.any():
            continue
        if source_masks[k] is None:
            return None
        sm = _as_mask(source_masks[k], "source mask")
        h, w = sm.shape
        u = np.rint(f[k, ys, xs, 0]).astype(np.int64)
        v = np.rint(f[k, ys, xs, 1]).astype(np.int64)
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        own = np.zeros(len(ys), bool)
        own[inside] = sm[v[inside], u[inside]]
        n_mem += mk
        n_own += mk & own
    return float(100.0 * np.count_nonzero(2 * n_own >= n_mem) / len(ys))

"""Evaluation metrics: mask overlap, image quality inside a mask or over the whole photo.

Pure functions on plain arrays (no I/O, no other dynremove imports), used by the
evaluation protocol of DESIGN.md section 6: detection Jaccard (IoU) against a
ground-truth dynamic mask, removal PSNR / SSIM restricted to the true
dynamic region, and the whole-photo measures: PSNR / SSIM of the whole image,
:func:`damage_percent` (good pixels the method broke) and
:func:`leftover_percent` (mover pixels it could have removed but did not).

Masks are ``(H, W)`` arrays indexed ``[y, x]``; any nonzero value counts as
``True`` unless stated otherwise (use :func:`mask_from_png` for masks loaded
from 8-bit PNG files). Images are ``(H, W)`` or ``(H, W, C)``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "jaccard",
    "precision_recall",
    "psnr_in_mask",
    "ssim_in_mask",
    "mask_from_png",
    "psnr",
    "ssim",
    "delta_e76",
    "damage_percent",
    "leftover_percent",
    "DAMAGE_DILATE_PX",
    "DE_MAX",
    "DE_BLUR_SIGMA",
    "SSIM_WINDOW",
    "SSIM_SIGMA",
    "SSIM_K1",
    "SSIM_K2",
]

#: SSIM Gaussian window side (pixels), Wang et al. 2004.
SSIM_WINDOW: int = 11
#: SSIM Gaussian window standard deviation (pixels).
SSIM_SIGMA: float = 1.5
#: SSIM stabilising constant for the luminance term, ``C1 = (K1 L)^2``.
SSIM_K1: float = 0.01
#: SSIM stabilising constant for the contrast-structure term, ``C2 = (K2 L)^2``.
SSIM_K2: float = 0.03
#: Guard band (pixels) around the true mask excluded from :func:`damage_percent`.
DAMAGE_DILATE_PX: int = 5
#: CIE76 colour difference above which a pixel is "wrong" (L in 0..100).
DE_MAX: float = 10.0
#: Gaussian blur (pixels) applied to both images before the colour comparison.
DE_BLUR_SIGMA: float = 1.0


# --------------------------------------------------------------------------- helpers


def _as_mask(mask: npt.ArrayLike, name: str) -> npt.NDArray[np.bool_]:
    """Return ``mask != 0`` as a 2-D bool array, or raise naming ``name``."""
    arr = np.asarray(mask)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (H, W) mask, got shape {arr.shape}")
    if arr.dtype == np.bool_:
        return arr
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be a boolean or numeric mask, got {arr.dtype}")
    return arr != 0


def _check_same_shape(a: np.ndarray, b: np.ndarray, name_a: str, name_b: str) -> None:
    if a.shape != b.shape:
        raise ValueError(
            f"{name_a} and {name_b} must have the same shape, "
            f"got {a.shape} and {b.shape}"
        )


def _image_pair_and_mask(
    img: npt.ArrayLike, ref: npt.ArrayLike, mask: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray, npt.NDArray[np.bool_]]:
    """Validate ``img``/``ref``/``mask`` and return float64 images + bool mask."""
    a = np.asarray(img)
    b = np.asarray(ref)
    if a.ndim not in (2, 3):
        raise ValueError(f"img must be (H, W) or (H, W, C), got shape {a.shape}")
    _check_same_shape(a, b, "img", "ref")
    m = _as_mask(mask, "mask")
    if m.shape != a.shape[:2]:
        raise ValueError(
            f"mask must have the image's (H, W) = {a.shape[:2]}, got {m.shape}"
        )
    if not m.any():
        raise ValueError("mask is empty: the metric is undefined over zero pixels")
    a = a.astype(np.float64, copy=False)
    b = b.astype(np.float64, copy=False)
    if not (np.isfinite(a[m]).all() and np.isfinite(b[m]).all()):
        raise ValueError("img and ref must be finite inside the mask (found NaN/inf)")
    return a, b, m


def _check_data_range(data_range: float) -> float:
    dr = float(data_range)
    if not (math.isfinite(dr) and dr > 0):
        raise ValueError(
            f"data_range must be a finite positive number, got {data_range}"
        )
    return dr


# --------------------------------------------------------------------------- masks


def jaccard(pred: npt.ArrayLike, gt: npt.ArrayLike) -> float:
    """Jaccard index (intersection over union) of two binary masks.

    Parameters
    ----------
    pred : (H, W) bool-like ndarray
        Predicted mask; nonzero means ``True``.
    gt : (H, W) bool-like ndarray
        Ground-truth mask; nonzero means ``True``.

    Returns
    -------
    j : float
        ``|pred & gt| / |pred | gt|`` in ``[0, 1]``; ``1.0`` when both masks are
        empty (the prediction is exactly right).

    Raises
    ------
    ValueError
        If a mask is not 2-D or the shapes differ.

    Examples
    --------
    >>> import numpy as np
    >>> gt = np.zeros((5, 5), bool); gt[1:3, 1:3] = True     # 4 pixels
    >>> pred = np.zeros((5, 5), bool); pred[1:3, 1:4] = True  # 6 pixels, 4 shared
    >>> jaccard(pred, gt)
    0.6666666666666666
    >>> jaccard(np.zeros((5, 5)), np.zeros((5, 5)))
    1.0
    """
    p = _as_mask(pred, "pred")
    g = _as_mask(gt, "gt")
    _check_same_shape(p, g, "pred", "gt")
    union = int(np.count_nonzero(p | g))
    if union == 0:
        return 1.0
    return int(np.count_nonzero(p & g)) / union


def precision_recall(pred: npt.ArrayLike, gt: npt.ArrayLike) -> tuple[float, float]:
    """Pixel precision and recall of a predicted mask.

    Parameters
    ----------
    pred : (H, W) bool-like ndarray
        Predicted mask; nonzero means ``True``.
    gt : (H, W) bool-like ndarray
        Ground-truth mask; nonzero means ``True``.

    Returns
    -------
    precision : float
        ``TP / (TP + FP)``; ``1.0`` when ``pred`` is empty (no false positive).
    recall : float
        ``TP / (TP + FN)``; ``1.0`` when ``gt`` is empty (nothing to find).

    Raises
    ------
    ValueError
        If a mask is not 2-D or the shapes differ.

    Examples
    --------
    >>> import numpy as np
    >>> gt = np.zeros((5, 5), bool); gt[1:3, 1:3] = True     # 4 pixels
    >>> pred = np.zeros((5, 5), bool); pred[1:3, 1:4] = True  # 6 pixels, 4 shared
    >>> precision_recall(pred, gt)
    (0.6666666666666666, 1.0)
    """
    p = _as_mask(pred, "pred")
    g = _as_mask(gt, "gt")
    _check_same_shape(p, g, "pred", "gt")
    tp = int(np.count_nonzero(p & g))
    n_pred = int(np.count_nonzero(p))
    n_gt = int(np.count_nonzero(g))
    precision = tp / n_pred if n_pred else 1.0
    recall = tp / n_gt if n_gt else 1.0
    return precision, recall


def mask_from_png(arr: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Binarise an 8-bit grayscale mask as loaded from a PNG file.

    Parameters
    ----------
    arr : (H, W) or (H, W, 1) uint8 ndarray
        Mask loaded with ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``
        (e.g. DAVIS annotations, 0 = background, 255 = object).

    Returns
    -------
    mask : (H, W) bool ndarray
        ``arr > 127``.

    Raises
    ------
    ValueError
        If ``arr`` is not a single-channel 2-D array (load colour PNGs with
        ``cv2.IMREAD_GRAYSCALE``).

    Examples
    --------
    >>> import numpy as np
    >>> arr = np.zeros((5, 5), np.uint8); arr[2, 1:4] = 255; arr[0, 0] = 100
    >>> mask_from_png(arr).astype(int)
    array([[0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0],
           [0, 1, 1, 1, 0],
           [0, 0, 0, 0, 0],
           [0, 0, 0, 0, 0]])
    """
    a = np.asarray(arr)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim != 2:
        raise ValueError(
            f"arr must be a single-channel (H, W) mask, got shape {a.shape}; "
            "load PNG masks with cv2.IMREAD_GRAYSCALE"
        )
    if not np.issubdtype(a.dtype, np.number) and a.dtype != np.bool_:
        raise ValueError(f"arr must be numeric, got {a.dtype}")
    return a > 127


# --------------------------------------------------------------------------- images


def psnr_in_mask(
    img: npt.ArrayLike,
    ref: npt.ArrayLike,
    mask: npt.ArrayLike,
    *,
    data_range: float = 255,
) -> float:
    """Peak signal-to-noise ratio over the pixels of a mask.

    .. math:: \\mathrm{PSNR} = 10 \\log_{10} \\frac{L^2}{\\mathrm{MSE}},

    where the mean squared error runs over every channel of every masked pixel.

    Parameters
    ----------
    img : (H, W) or (H, W, C) ndarray
        Image to evaluate (e.g. the cleaned reference).
    ref : (H, W) or (H, W, C) ndarray
        Ground truth, same shape as ``img``.
    mask : (H, W) bool-like ndarray
        Pixels to evaluate (e.g. the true dynamic region); nonzero means ``True``.
    data_range : float, optional
        Peak value ``L`` (255 for 8-bit images, 1 for images in ``[0, 1]``).

    Returns
    -------
    psnr : float
        PSNR in dB; ``inf`` when the images agree exactly inside the mask.
        Never NaN.

    Raises
    ------
    ValueError
        On an empty mask, mismatched shapes, a non-positive ``data_range`` or
        non-finite values inside the mask.

    Examples
    --------
    A constant error of 10 grey levels gives ``20 log10(255 / 10)``:

    >>> import numpy as np
    >>> ref = np.full((5, 5), 100, np.uint8)
    >>> img = ref.copy(); img[1:4, 1:4] = 110
    >>> mask = np.zeros((5, 5), bool); mask[1:4, 1:4] = True
    >>> round(psnr_in_mask(img, ref, mask), 4)
    28.1308
    >>> psnr_in_mask(ref, ref, mask)
    inf
    """
    dr = _check_data_range(data_range)
    a, b, m = _image_pair_and_mask(img, ref, mask)
    mse = float(np.mean((a[m] - b[m]) ** 2))
    if mse == 0.0:
        return math.inf
    return 10.0 * math.log10(dr * dr / mse)


def _ssim_map(a: np.ndarray, b: np.ndarray, data_range: float) -> np.ndarray:
    """Per-pixel SSIM of two single-channel float64 images (Wang et al. 2004)."""
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    ksize = (SSIM_WINDOW, SSIM_WINDOW)

    def blur(x: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(
            x, ksize, SSIM_SIGMA, sigmaY=SSIM_SIGMA, borderType=cv2.BORDER_REFLECT_101
        )

    mu_a = blur(a)
    mu_b = blur(b)
    # Gaussian-weighted (biased) moments, as in the authors' reference code.
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    num = (2.0 * mu_a * mu_b + c1) * (2.0 * cov + c2)
    den = (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2)
    return num / den


def ssim_in_mask(
    img: npt.ArrayLike,
    ref: npt.ArrayLike,
    mask: npt.ArrayLike,
    *,
    data_range: float = 255,
) -> float:
    """Mean structural similarity (SSIM) over the pixels of a mask.

    The SSIM map of Wang et al. [1]_ is computed on the whole image,

    .. math::
        \\mathrm{SSIM}(x) = \\frac{(2\\mu_a\\mu_b + C_1)(2\\sigma_{ab} + C_2)}
        {(\\mu_a^2 + \\mu_b^2 + C_1)(\\sigma_a^2 + \\sigma_b^2 + C_2)},

    with local statistics from an 11x11 Gaussian window (sigma 1.5,
    ``cv2.GaussianBlur``, borders reflected as ``cv2.BORDER_REFLECT_101``),
    Gaussian-weighted (biased) variances, ``C1 = (0.01 L)^2`` and
    ``C2 = (0.03 L)^2``. It is then averaged over the masked pixels. Colour
    images are handled **per channel**: the SSIM map of each channel is computed
    separately and the maps are averaged over channels (as scikit-image does with
    ``channel_axis``), so a chroma error that keeps the luminance still counts.
    The statistics near the mask border use the surrounding (unmasked) pixels too.

    Parameters
    ----------
    img : (H, W) or (H, W, C) ndarray
        Image to evaluate.
    ref : (H, W) or (H, W, C) ndarray
        Ground truth, same shape as ``img``.
    mask : (H, W) bool-like ndarray
        Pixels over which the SSIM map is averaged; nonzero means ``True``.
    data_range : float, optional
        Dynamic range ``L`` of the images (255 for 8-bit).

    Returns
    -------
    ssim : float
        Mean SSIM in ``[-1, 1]``; ``1.0`` for identical images.

    Raises
    ------
    ValueError
        On an empty mask, mismatched shapes, a non-positive ``data_range`` or
        non-finite values inside the mask.

    References
    ----------
    .. [1] Z. Wang, A. C. Bovik, H. R. Sheikh, E. P. Simoncelli, "Image quality
       assessment: from error visibility to structural similarity", IEEE TIP
       13(4), 2004.

    Examples
    --------
    Two flat images at 100 and 110: only the luminance term is left,
    ``(2 * 100 * 110 + C1) / (100**2 + 110**2 + C1)``:

    >>> import numpy as np
    >>> a = np.full((5, 5), 100.0); b = np.full((5, 5), 110.0)
    >>> mask = np.ones((5, 5), bool)
    >>> round(ssim_in_mask(a, b, mask), 6)
    0.995476
    >>> ssim_in_mask(a, a, mask)
    1.0
    """
    dr = _check_data_range(data_range)
    a, b, m = _image_pair_and_mask(img, ref, mask)
    if a.ndim == 2:
        a = a[:, :, None]
        b = b[:, :, None]
    # Non-finite values outside the mask would leak through the window.
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("img and ref must be finite everywhere (found NaN/inf)")
    chans = range(a.shape[2])
    maps = [_ssim_map(a[:, :, c].copy(), b[:, :, c].copy(), dr) for c in chans]
    ssim = np.mean(maps, axis=0)
    return float(np.mean(ssim[m]))


# --------------------------------------------------------------------------- whole photo


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
    n = int(np.count_nonzero(count))
    if n == 0:
        return None, unrec
    wrong = np.linalg.norm(_lab(out_, s) - _lab(bg_, s), axis=2) > dm
    return 100.0 * int(np.count_nonzero(wrong & count)) / n, unrec

"""Evaluation metrics: mask overlap and image quality inside a mask.

Pure functions on plain arrays (no I/O, no other dynremove imports), used by the
evaluation protocol (README, Results): detection Jaccard (IoU) against a
ground-truth dynamic mask and removal PSNR / SSIM restricted to the true
dynamic region. The whole-photo measures (PSNR / SSIM of the whole image,
``damage_percent``, ``leftover_percent``) are in
:mod:`dynremove.evaluation.whole_photo`.

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

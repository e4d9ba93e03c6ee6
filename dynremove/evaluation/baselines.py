"""Baselines the method is compared against (README, Results).

Built the way a careful user would build them with OpenCV:

* **Median stack** ("tourist removal"): every source view is aligned to the
  reference, by a SIFT + MAGSAC homography (:func:`align_homography`) or by a
  homography followed by DIS optical flow (:func:`align_homography_flow`); the
  per-pixel median over all views (reference included) that see the pixel is the
  background estimate (:func:`median_stack`). Dynamic pixels are those whose
  CIE Lab colour differs from that background by more than one global threshold
  (:func:`median_detect`, :data:`MEDIAN_THRESHOLD_LAB`), and they are replaced by
  the background (:func:`median_baseline`).
* **Telea inpainting** given the *true* dynamic mask (:func:`telea_inpaint`): a
  single-image method with an unfair advantage (it is told where the object is).

Images are BGR ``uint8`` arrays ``(H, W, 3)`` indexed ``[y, x]``; points are
``(x, y)``. Keypoints, matching, the robust homography fit and its application
are the method's own (:mod:`dynremove.method.geometry`), and so is the
convention: a homography maps *reference* pixels to *source* pixels.

Homography fallback
-------------------
When a source has fewer than :data:`MIN_GOOD_MATCHES` SIFT matches passing the
ratio test, or the robust fit fails, the alignment falls back to the identity:
the returned ``valid`` mask is all ``True``, the homography is ``np.eye(3)`` and
a :class:`AlignmentFallbackWarning` is emitted (no extra return value, so both
aligners keep the same ``(warped, valid, H)`` signature). Callers that want to
count fallbacks record the warnings (``warnings.catch_warnings(record=True)``).
"""

from __future__ import annotations

import types
import warnings
from collections.abc import Mapping, Sequence
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import pixel_grid
from dynremove.method.geometry import detect, fit_homography, match, project_homography

__all__ = [
    "AlignmentFallbackWarning",
    "ALIGN_MODES",
    "MEDIAN_THRESHOLD_LAB",
    "MIN_GOOD_MATCHES",
    "estimate_homography",
    "align_homography",
    "align_homography_flow",
    "median_stack",
    "median_detect",
    "median_baseline",
    "telea_inpaint",
]

AlignMode = Literal["homography", "homography+flow"]

#: Supported alignment modes of the median stack.
ALIGN_MODES: tuple[str, ...] = ("homography", "homography+flow")

#: Global Lab colour-difference threshold of :func:`median_detect`, one value per
#: alignment mode, each chosen once to maximise the mean Jaccard over the 19
#: shared DAVIS sets (reference = middle frame; grid 3, 4, 5, 6, 8, 10, 12, 15,
#: 18, 22, 26, 30; ``examples/median_threshold_study.py``, seed 0):
#: homography 15 -> mean J 0.366; homography + DIS flow 8 -> mean J 0.243 (flat
#: from 8 to 12: the flow also aligns slow objects, so smaller differences
#: remain). Read-only mapping.
MEDIAN_THRESHOLD_LAB: Mapping[str, float] = types.MappingProxyType(
    {"homography": 15.0, "homography+flow": 8.0}
)

#: Below this many ratio-test matches the homography falls back to identity.
MIN_GOOD_MATCHES: int = 8

_MAGSAC_THRESHOLD_PX = 3.0  # reprojection threshold (max sigma) of MAGSAC++
_MAGSAC_MAX_ITERS = 5000
_MAGSAC_CONFIDENCE = 0.999
_DETECT_BLUR_SIGMA = 1.0  # Gaussian blur of both images before the Lab difference


class AlignmentFallbackWarning(UserWarning):
    """A homography could not be estimated; the identity was used instead."""


# --------------------------------------------------------------------------- checks


def _check_bgr(img: npt.ArrayLike, name: str) -> npt.NDArray[np.uint8]:
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(
            f"{name} must be an (H, W, 3) BGR image, got shape {arr.shape}"
        )
    if arr.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8, got {arr.dtype}")
    if arr.shape[0] < 2 or arr.shape[1] < 2:
        raise ValueError(f"{name} must be at least 2x2 pixels, got {arr.shape[:2]}")
    return np.ascontiguousarray(arr)


def _check_pair(
    ref_bgr: npt.ArrayLike, src_bgr: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    ref = _check_bgr(ref_bgr, "ref_bgr")
    src = _check_bgr(src_bgr, "src_bgr")
    if ref.shape != src.shape:
        raise ValueError(
            f"ref_bgr and src_bgr must have the same shape, got {ref.shape} and "
            f"{src.shape}"
        )
    return ref, src


def _check_mask(mask: npt.ArrayLike, shape: tuple[int, int], name: str) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (H, W) mask, got shape {m.shape}")
    if m.shape != shape:
        raise ValueError(
            f"{name} must have the image's (H, W) = {shape}, got {m.shape}"
        )
    return m.astype(bool) if m.dtype != np.bool_ else m


def _check_images(
    images: Sequence[npt.ArrayLike], ref_index: int
) -> tuple[list[np.ndarray], int]:
    imgs = [_check_bgr(im, f"images[{i}]") for i, im in enumerate(images)]
    if len(imgs) < 2:
        raise ValueError(f"images must hold at least 2 views, got {len(imgs)}")
    shape = imgs[0].shape
    for i, im in enumerate(imgs):
        if im.shape != shape:
            raise ValueError(
                f"all images must have the same shape: images[0] is {shape}, "
                f"images[{i}] is {im.shape}"
            )
    if isinstance(ref_index, bool) or not isinstance(ref_index, (int, np.integer)):
        raise TypeError(f"ref_index must be an int, got {type(ref_index).__name__}")
    if not -len(imgs) <= ref_index < len(imgs):
        raise ValueError(f"ref_index {ref_index} out of range for {len(imgs)} images")
    return imgs, int(ref_index) % len(imgs)


def _check_align(align: str) -> str:
    if align not in ALIGN_MODES:
        raise ValueError(f"align must be one of {ALIGN_MODES}, got {align!r}")
    return align


# --------------------------------------------------------------------------- alignment


def _features(bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """SIFT keypoints ``(N, 2)`` ``(x, y)`` and descriptors of a BGR image."""
    return detect(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))


def estimate_homography(
    feat_a: tuple[np.ndarray, np.ndarray | None],
    feat_b: tuple[np.ndarray, np.ndarray | None],
    seed: int,
) -> np.ndarray | None:
    """Homography mapping image a's ``(x, y)`` to image b's ``(x, y)``, or None.

    a's keypoints are matched in b (Lowe's ratio test,
    :func:`~dynremove.method.geometry.match`) and the homography is fitted with
    MAGSAC++ after seeding OpenCV's RNG
    (:func:`~dynremove.method.geometry.fit_homography`); a degenerate fit is
    rejected and the result is scaled so that ``H[2, 2] = 1``.
    ``feat_a``/``feat_b``: ``(xy, descriptors)`` from
    :func:`~dynremove.method.geometry.detect`.
    """
    xy_a, desc_a = feat_a
    xy_b, desc_b = feat_b
    pairs = match(desc_a, desc_b)
    if len(pairs) < MIN_GOOD_MATCHES:
        return None
    H, _ = fit_homography(
        xy_a[pairs[:, 0]],
        xy_b[pairs[:, 1]],
        seed=seed,
        threshold_px=_MAGSAC_THRESHOLD_PX,
        max_iters=_MAGSAC_MAX_ITERS,
        confidence=_MAGSAC_CONFIDENCE,
    )
    if H is None or not np.isfinite(H).all():
        return None
    if abs(np.linalg.det(H)) < 1e-8:
        return None
    return H / H[2, 2] if H[2, 2] != 0 else H


def _homography_or_identity(
    ref_feat: tuple[np.ndarray, np.ndarray | None],
    src_feat: tuple[np.ndarray, np.ndarray | None],
    seed: int,
) -> tuple[np.ndarray, bool]:
    # fitted source -> reference (the source's keypoints matched in the reference),
    # then inverted: every homography here maps reference pixels to source pixels
    H_sr = estimate_homography(src_feat, ref_feat, seed)
    if H_sr is None:
        warnings.warn(
            f"homography estimation failed (fewer than {MIN_GOOD_MATCHES} good SIFT "
            "matches or no robust fit); falling back to the identity with all "
            "pixels valid",
            AlignmentFallbackWarning,
            stacklevel=3,
        )
        return np.eye(3), True
    return np.linalg.inv(H_sr), False


def _inside(u: np.ndarray, v: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``(u, v)`` falls inside an image of ``shape`` (bilinear needs no outside px)."""
    h, w = shape
    eps = 1e-3
    return (
        np.isfinite(u)
        & np.isfinite(v)
        & (u >= -eps)
        & (u <= w - 1 + eps)
        & (v >= -eps)
        & (v <= h - 1 + eps)
    )


def _sample(src: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear lookup ``src[map_y, map_x]`` with replicated borders."""
    return cv2.remap(
        src,
        np.nan_to_num(map_x, nan=-1.0, posinf=-1.0, neginf=-1.0).astype(np.float32),
        np.nan_to_num(map_y, nan=-1.0, posinf=-1.0, neginf=-1.0).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )


def _warp_with_homography(
    ref_shape: tuple[int, int], src: np.ndarray, H: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Source sampled in the reference frame through ``H`` (reference -> source)."""
    x, y = pixel_grid(*ref_shape)
    map_x, map_y, w = project_homography(H, x, y)
    valid = _inside(map_x, map_y, src.shape[:2]) & (w > 0)
    warped = _sample(src, map_x, map_y)
    warped[~valid] = 0
    return warped, valid


def _align_homography_feat(
    ref: np.ndarray, src: np.ndarray, ref_feat: tuple, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    H, fell_back = _homography_or_identity(ref_feat, _features(src), seed)
    if fell_back:
        return src.copy(), np.ones(ref.shape[:2], bool), H, True
    warped, valid = _warp_with_homography(ref.shape[:2], src, H)
    return warped, valid, H, False


def _align_flow_feat(
    ref: np.ndarray, src: np.ndarray, ref_feat: tuple, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    H, fell_back = _homography_or_identity(ref_feat, _features(src), seed)
    shape = ref.shape[:2]
    x, y = pixel_grid(*shape)
    # Pre-warp with replicated borders so the flow does not chase a black frame.
    pre_x, pre_y, _ = project_homography(H, x, y)
    prewarp = _sample(src, pre_x, pre_y)
    ref_gray = cv2.cvtColor(ref, cv2.COLOR_BGR2GRAY)
    pre_gray = cv2.cvtColor(prewarp, cv2.COLOR_BGR2GRAY)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    flow = dis.calc(ref_gray, pre_gray, None)  # ref(p) ~ prewarp(p + flow(p))
    # Compose: reference pixel -> pre-warped frame -> source, then sample the source
    # once (a single bilinear interpolation instead of two).
    map_x, map_y, w = project_homography(H, x + flow[..., 0], y + flow[..., 1])
    valid = _inside(map_x, map_y, src.shape[:2]) & (w > 0)
    if fell_back:
        valid = np.ones(shape, bool)
    warped = _sample(src, map_x, map_y)
    warped[~valid] = 0
    return warped, valid, H


def align_homography(
    ref_bgr: npt.ArrayLike, src_bgr: npt.ArrayLike, *, seed: int = 0
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Align a source view to the reference with one SIFT + MAGSAC++ homography.

    SIFT keypoints (up to 4000 per image, grayscale) are matched by brute force
    with Lowe's ratio test (0.75); ``cv2.findHomography(..., cv2.USAC_MAGSAC)``
    (threshold 3 px) fits the homography after ``cv2.setRNGSeed(seed)``, and the
    source is warped into the reference frame (bilinear).

    Parameters
    ----------
    ref_bgr : (H, W, 3) uint8 ndarray
        Reference image (BGR).
    src_bgr : (H, W, 3) uint8 ndarray
        Source image (BGR), same shape as the reference.
    seed : int, optional
        Seed of OpenCV's RNG for MAGSAC++ (results are deterministic for a seed).

    Returns
    -------
    warped : (H, W, 3) uint8 ndarray
        Source resampled in the reference frame; 0 where not ``valid``.
    valid : (H, W) bool ndarray
        Reference pixels whose pre-image falls inside the source image.
    H : (3, 3) float64 ndarray
        Homography mapping reference ``(x, y)`` to source ``(x, y)`` (the
        convention of :mod:`dynremove.method.geometry`).

    Warns
    -----
    AlignmentFallbackWarning
        With fewer than :data:`MIN_GOOD_MATCHES` good matches or no robust fit;
        then ``warped`` is the unmodified source, ``valid`` is all ``True`` and
        ``H`` is the identity.
    """
    ref, src = _check_pair(ref_bgr, src_bgr)
    ref_feat = _features(ref)
    warped, valid, H, _ = _align_homography_feat(ref, src, ref_feat, seed)
    return warped, valid, H


def align_homography_flow(
    ref_bgr: npt.ArrayLike, src_bgr: npt.ArrayLike, *, seed: int = 0
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """Align a source view to the reference per pixel: homography, then DIS flow.

    The source is pre-warped with :func:`align_homography`'s homography; DIS
    optical flow (``DISOPTICAL_FLOW_PRESET_MEDIUM``, grayscale) from the
    reference to the pre-warped source gives, for each reference pixel ``p``,
    the matching point ``p + flow(p)``; that point is mapped back through the
    homography and the source sampled there (a single bilinear interpolation).

    Parameters
    ----------
    ref_bgr : (H, W, 3) uint8 ndarray
        Reference image (BGR).
    src_bgr : (H, W, 3) uint8 ndarray
        Source image (BGR), same shape as the reference.
    seed : int, optional
        Seed of OpenCV's RNG for MAGSAC++.

    Returns
    -------
    warped : (H, W, 3) uint8 ndarray
        Source resampled per pixel in the reference frame; 0 where not ``valid``.
    valid : (H, W) bool ndarray
        Reference pixels whose flow-displaced pre-image falls inside the source.
    H : (3, 3) float64 ndarray
        The pre-warp homography (reference ``(x, y)`` to source ``(x, y)``).

    Warns
    -----
    AlignmentFallbackWarning
        When the homography falls back to the identity (the flow still runs on
        the unwarped source, and ``valid`` is all ``True``).
    """
    ref, src = _check_pair(ref_bgr, src_bgr)
    ref_feat = _features(ref)
    return _align_flow_feat(ref, src, ref_feat, seed)


# --------------------------------------------------------------------------- median


def _masked_median(
    stack: np.ndarray, valid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel median over the valid views of a ``(V, H, W, 3)`` uint8 stack.

    Invalid entries are set above any uint8 value, the view axis is sorted, and
    the middle of the first ``count`` entries is picked (mean of the two middle
    ones, rounded half to even, for an even count). Every pixel needs
    ``count >= 1``.
    """
    s = stack.astype(np.int16)
    s[~valid] = np.iinfo(np.int16).max
    s.sort(axis=0)
    count = valid.sum(axis=0)  # (H, W)
    lo = ((count - 1) // 2)[None, :, :, None]
    hi = (count // 2)[None, :, :, None]
    a = np.take_along_axis(s, np.broadcast_to(lo, (1,) + s.shape[1:]), axis=0)[0]
    b = np.take_along_axis(s, np.broadcast_to(hi, (1,) + s.shape[1:]), axis=0)[0]
    med = np.rint((a.astype(np.float32) + b) / 2.0).astype(np.uint8)
    return med, count


def median_stack(
    images: Sequence[npt.ArrayLike],
    ref_index: int,
    *,
    align: AlignMode = "homography",
    seed: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.intp]]:
    """Background of the reference view as the per-pixel median of aligned views.

    Every other view is aligned to the reference (:func:`align_homography` or
    :func:`align_homography_flow`); at each pixel the median is taken per
    channel over all views that see it, **the reference included** (the
    classic "tourist removal" stack). Reference SIFT features are computed once.

    Parameters
    ----------
    images : sequence of V (H, W, 3) uint8 ndarray
        The views (BGR), V >= 2, all the same shape.
    ref_index : int
        Index of the reference view in ``images``.
    align : {"homography", "homography+flow"}, optional
        Alignment of the sources to the reference.
    seed : int, optional
        Seed for MAGSAC++ (see :func:`align_homography`).

    Returns
    -------
    background : (H, W, 3) uint8 ndarray
        Median background in the reference frame.
    stack_valid_count : (H, W) int ndarray
        Number of views (1..V, reference included) valid at each pixel.

    Warns
    -----
    AlignmentFallbackWarning
        Once per source whose homography falls back to the identity.

    Notes
    -----
    The median over invalid-masked views is computed by sorting the view axis
    with invalid entries set above 255 and picking the middle of the valid
    count, O(V log V) per pixel without NaN arithmetic.
    """
    imgs, r = _check_images(images, ref_index)
    _check_align(align)
    ref = imgs[r]
    ref_feat = _features(ref)
    V = len(imgs)
    stack = np.empty((V,) + ref.shape, np.uint8)
    valid = np.empty((V,) + ref.shape[:2], bool)
    for i, src in enumerate(imgs):
        if i == r:
            stack[i], valid[i] = ref, True
        elif align == "homography":
            stack[i], valid[i], _, _ = _align_homography_feat(ref, src, ref_feat, seed)
        else:
            stack[i], valid[i], _ = _align_flow_feat(ref, src, ref_feat, seed)
    return _masked_median(stack, valid)


def _lab_distance(a_bgr: np.ndarray, b_bgr: np.ndarray) -> np.ndarray:
    """Euclidean CIE Lab distance after a Gaussian blur (sigma 1) of both images."""

    def lab(img: np.ndarray) -> np.ndarray:
        f = img.astype(np.float32) / 255.0
        f = cv2.GaussianBlur(f, (0, 0), _DETECT_BLUR_SIGMA)
        return cv2.cvtColor(f, cv2.COLOR_BGR2Lab)

    d = lab(a_bgr) - lab(b_bgr)
    return np.sqrt(np.sum(d * d, axis=2))


def median_detect(
    ref_bgr: npt.ArrayLike, background_bgr: npt.ArrayLike, *, threshold: float
) -> npt.NDArray[np.bool_]:
    """Dynamic mask: reference pixels whose colour differs from the background.

    Both images are converted to float in ``[0, 1]``, blurred with a Gaussian
    (sigma 1 px), converted to CIE Lab (``L`` in 0..100); a pixel is dynamic
    when the Euclidean Lab distance exceeds ``threshold``. The mask is then
    cleaned by a morphological opening with a 3x3 square.

    Parameters
    ----------
    ref_bgr : (H, W, 3) uint8 ndarray
        Reference image (BGR).
    background_bgr : (H, W, 3) uint8 ndarray
        Background estimate in the reference frame (e.g. :func:`median_stack`).
    threshold : float
        Lab distance (Delta E 1976 units) above which a pixel is dynamic;
        see :data:`MEDIAN_THRESHOLD_LAB`.

    Returns
    -------
    dynamic : (H, W) bool ndarray
        Detected dynamic pixels.

    Examples
    --------
    A light-grey 3x3 object on grey: after the blur its rim straddles the
    threshold, and the opening keeps the 3x3 core only.

    >>> import numpy as np
    >>> bg = np.full((5, 5, 3), 128, np.uint8)
    >>> ref = bg.copy(); ref[1:4, 1:4] = 160
    >>> median_detect(ref, bg, threshold=6.0).astype(int)
    array([[0, 0, 0, 0, 0],
           [0, 1, 1, 1, 0],
           [0, 1, 1, 1, 0],
           [0, 1, 1, 1, 0],
           [0, 0, 0, 0, 0]])
    """
    ref = _check_bgr(ref_bgr, "ref_bgr")
    bg = _check_bgr(background_bgr, "background_bgr")
    if ref.shape != bg.shape:
        raise ValueError(
            f"ref_bgr and background_bgr must have the same shape, got {ref.shape} "
            f"and {bg.shape}"
        )
    thr = float(threshold)
    if not np.isfinite(thr) or thr < 0:
        raise ValueError(f"threshold must be a finite number >= 0, got {threshold}")
    dynamic = (_lab_distance(ref, bg) > thr).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    dynamic = cv2.morphologyEx(dynamic, cv2.MORPH_OPEN, kernel)
    return dynamic.astype(bool)


def median_baseline(
    images: Sequence[npt.ArrayLike],
    ref_index: int,
    *,
    align: AlignMode = "homography",
    threshold: float | None = None,
    seed: int = 0,
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """Median-stack baseline: detect dynamic pixels and replace them.

    Runs :func:`median_stack` then :func:`median_detect`; the clean image is
    the reference with the detected pixels replaced by the median background.

    Parameters
    ----------
    images : sequence of V (H, W, 3) uint8 ndarray
        The views (BGR), V >= 2, all the same shape.
    ref_index : int
        Index of the reference view.
    align : {"homography", "homography+flow"}, optional
        Alignment of the sources to the reference.
    threshold : float, optional
        Lab detection threshold; ``None`` (default) uses the measured global
        value ``MEDIAN_THRESHOLD_LAB[align]``.
    seed : int, optional
        Seed for MAGSAC++.

    Returns
    -------
    clean : (H, W, 3) uint8 ndarray
        Reference with dynamic pixels replaced by the background.
    dynamic : (H, W) bool ndarray
        Detected dynamic pixels of the reference.
    """
    _check_align(align)
    thr = MEDIAN_THRESHOLD_LAB[align] if threshold is None else threshold
    imgs, r = _check_images(images, ref_index)
    background, _ = median_stack(imgs, r, align=align, seed=seed)
    dynamic = median_detect(imgs[r], background, threshold=thr)
    clean = imgs[r].copy()
    clean[dynamic] = background[dynamic]
    return clean, dynamic


# --------------------------------------------------------------------------- inpainting


def telea_inpaint(
    ref_bgr: npt.ArrayLike,
    mask: npt.ArrayLike,
    *,
    radius: float = 5,
    dilate_px: int = 2,
) -> npt.NDArray[np.uint8]:
    """Fill a masked region of one image with OpenCV's Telea inpainting.

    The (true) dynamic mask is first dilated by ``dilate_px`` pixels (a disc of
    that radius) so that the object's anti-aliased / blurred rim is inpainted
    too instead of being propagated inwards; pixels outside the dilated mask
    are returned unchanged.

    Parameters
    ----------
    ref_bgr : (H, W, 3) uint8 ndarray
        Image to fill (BGR).
    mask : (H, W) bool-like ndarray
        Region to fill; nonzero means ``True``.
    radius : float, optional
        Neighbourhood radius of ``cv2.inpaint`` (pixels).
    dilate_px : int, optional
        Dilation of ``mask`` before inpainting (pixels, >= 0).

    Returns
    -------
    filled : (H, W, 3) uint8 ndarray
        Inpainted image.

    References
    ----------
    A. Telea, "An image inpainting technique based on the fast marching
    method", Journal of Graphics Tools 9(1), 2004.
    """
    ref = _check_bgr(ref_bgr, "ref_bgr")
    m = _check_mask(mask, ref.shape[:2], "mask")
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a positive number, got {radius}")
    if isinstance(dilate_px, bool) or int(dilate_px) != dilate_px or dilate_px < 0:
        raise ValueError(f"dilate_px must be an integer >= 0, got {dilate_px}")
    m8 = m.astype(np.uint8) * 255
    if dilate_px > 0:
        k = 2 * int(dilate_px) + 1
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
        m8 = cv2.dilate(m8, disc)
    if not m8.any():
        return ref.copy()
    filled = cv2.inpaint(ref, m8, float(radius), cv2.INPAINT_TELEA)
    out = ref.copy()
    sel = m8 > 0
    out[sel] = filled[sel]
    return out

"""Per-pixel features of Sec. 3.1: dense SIFT f_g and the CIE Lab mean f_c.

Both describe the p×p patch centred at every pixel. Dense SIFT is computed the
vectorised way (as VLFeat's ``dsift``): gradient orientations are soft-binned
into 8 maps, each map is pooled over the 4×4 spatial cells with a separable
triangular window, and the 128 values at a pixel are read at the 16 cell
centres, Gaussian-weighted, normalised, clamped at 0.2 and renormalised. The
descriptor is stored as uint8 (×512, as SIFT implementations do), which keeps
7 images × 854×480 at 52 MB each and makes squared distances exact integers.
The paper's "normalise by the maximum over the set" is applied as a scalar in
the distance (``sift_unit``), so stored descriptors never change.
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np
import numpy.typing as npt


def to_gray(bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
    """(H, W, 3) uint8 BGR → (H, W) float32 gray in [0, 255]."""
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)


def to_lab(bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
    """(H, W, 3) uint8 BGR → (H, W, 3) float32 CIE Lab (L in [0, 100])."""
    return cv2.cvtColor(bgr.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)


def lab_mean(bgr: npt.NDArray[np.uint8], *, patch_size: int) -> npt.NDArray[np.float32]:
    """CIE Lab mean over the p×p patch at every pixel, f_c (Sec. 3.1).

    Parameters
    ----------
    bgr : (H, W, 3) uint8 ndarray
    patch_size : int
        p, odd.

    Returns
    -------
    f_c : (H, W, 3) float32 ndarray
        Mean L, a, b over the patch (mirror-reflected at the borders).

    Examples
    --------
    >>> img = np.full((5, 5, 3), 128, np.uint8)
    >>> bool(np.allclose(lab_mean(img, patch_size=3), to_lab(img), atol=1e-4))
    True
    """
    return patch_mean(to_lab(bgr), patch_size=patch_size)


def patch_mean(img: npt.NDArray[np.float32], *, patch_size: int) -> npt.NDArray[np.float32]:
    """Mean over the p×p patch at every pixel (mirror-reflected borders)."""
    return cv2.blur(img, (patch_size, patch_size), borderType=cv2.BORDER_REFLECT_101)


def sift_bin_px(patch_size: int) -> int:
    """Side of one of the 4×4 SIFT cells so the descriptor spans about p×p."""
    return max(1, int(round(patch_size / 4.0)))


def dense_sift(gray: npt.NDArray[np.float32], *, patch_size: int) -> npt.NDArray[np.uint8]:
    """128-d SIFT descriptor of the p×p patch at every pixel, f_g (Sec. 3.1).

    Parameters
    ----------
    gray : (H, W) float32 ndarray
        Gray image, [0, 255].
    patch_size : int
        p: the 4×4 cells are ``round(p/4)`` px wide.

    Returns
    -------
    f_g : (H, W, 128) uint8 ndarray
        Layout ``(cell_y * 4 + cell_x) * 8 + orientation``; unit-norm descriptor
        clamped at 0.2, renormalised and scaled by 512 (saturating at 255).
    """
    gray = np.ascontiguousarray(gray, dtype=np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE) * 0.5
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=1, borderType=cv2.BORDER_REPLICATE) * 0.5
    mag, ang = cv2.cartToPolar(gx, gy)
    b = sift_bin_px(patch_size)
    # triangular pooling window of half-width b (VLFeat's bilinear spatial binning)
    tri = np.array([b - abs(i) for i in range(-b + 1, b)], np.float32)
    tri /= tri.sum()
    o = ang * (8.0 / (2.0 * math.pi))
    o0 = np.floor(o)
    w1 = o - o0
    o0 = o0.astype(np.int32) % 8
    pooled = np.empty((8,) + gray.shape, np.float32)
    for k in range(8):
        m = np.where(o0 == k, mag * (1.0 - w1), 0.0) + np.where((o0 + 1) % 8 == k, mag * w1, 0.0)
        pooled[k] = cv2.sepFilter2D(m.astype(np.float32), -1, tri, tri,
                                    borderType=cv2.BORDER_REFLECT_101)
    offs = np.array([int(math.floor((i - 1.5) * b + 0.5)) for i in range(4)], np.int64)
    sigma = 2.0 * b  # Gaussian over cells: half the descriptor width, as in SIFT
    cw = np.exp(-((offs[:, None] ** 2 + offs[None, :] ** 2) / (2.0 * sigma * sigma)))
    return _assemble_sift(pooled, offs, cw.astype(np.float32))


@numba.njit(cache=True, parallel=True, nogil=True)
def _assemble_sift(pooled, offs, cw):
    """pooled (8, H, W) float32, offs (4,) int64, cw (4, 4) float32 → (H, W, 128) uint8."""
    _, H, W = pooled.shape
    out = np.empty((H, W, 128), np.uint8)
    for y in numba.prange(H):
        d = np.empty(128, np.float32)
        for x in range(W):
            k = 0
            for cy in range(4):
                yy = min(max(y + offs[cy], 0), H - 1)
                for cx in range(4):
                    xx = min(max(x + offs[cx], 0), W - 1)
                    w = cw[cy, cx]
                    for o in range(8):
                        d[k] = pooled[o, yy, xx] * w
                        k += 1
            n = 0.0
            for i in range(128):
                n += d[i] * d[i]
            n = math.sqrt(n) + 1e-12
            n2 = 0.0
            for i in range(128):
                v = min(d[i] / n, 0.2)
                d[i] = v
                n2 += v * v
            n2 = math.sqrt(n2) + 1e-12
            for i in range(128):
                v = d[i] / n2 * 512.0
                out[y, x, i] = np.uint8(min(v + 0.5, 255.0))
    return out


def sift_unit(descriptors: list[npt.NDArray[np.uint8]], *, sift_scale: float) -> float:
    """Factor turning stored uint8 SIFT into the paper's units.

    The paper divides SIFT by its maximum over the image set; ``sift_scale`` then
    sets the unit that σ_g is measured in (the paper leaves it open).
    """
    vmax = max(int(d.max()) for d in descriptors)
    return float(sift_scale) / float(max(vmax, 1))

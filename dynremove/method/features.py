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


def to_lab(bgr: npt.NDArray[np.uint8], *, out: npt.NDArray[np.float32] | None = None
           ) -> npt.NDArray[np.float32]:
    """(H, W, 3) uint8 BGR → (H, W, 3) float32 CIE Lab (L in [0, 100]); written into
    ``out`` (C-contiguous (H, W, 3) float32: one photo's slot of a stack) if given."""
    x = bgr.astype(np.float32)
    np.divide(x, np.float32(255.0), out=x)
    return _into(cv2.cvtColor(x, cv2.COLOR_BGR2Lab, dst=out), out)


def _into(result: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """``out`` holding ``result`` (OpenCV writes into a ``dst`` of the right size and
    type; this guards the rest), or ``result`` when there is no ``out``."""
    if out is None or result is out:
        return result
    out[...] = result
    return out


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


def patch_mean(img: npt.NDArray[np.float32], *, patch_size: int,
               out: npt.NDArray[np.float32] | None = None) -> npt.NDArray[np.float32]:
    """Mean over the p×p patch at every pixel (mirror-reflected borders); written into
    ``out`` (C-contiguous, img's shape and type) if given."""
    return _into(cv2.blur(img, (patch_size, patch_size), dst=out,
                          borderType=cv2.BORDER_REFLECT_101), out)


def sift_bin_px(patch_size: int) -> int:
    """Side of one of the 4×4 SIFT cells so the descriptor spans about p×p."""
    return max(1, int(round(patch_size / 4.0)))


def dense_sift(gray: npt.NDArray[np.float32], *, patch_size: int,
               out: npt.NDArray[np.uint8] | None = None) -> npt.NDArray[np.uint8]:
    """128-d SIFT descriptor of the p×p patch at every pixel, f_g (Sec. 3.1).

    Parameters
    ----------
    gray : (H, W) float32 ndarray
        Gray image, [0, 255].
    patch_size : int
        p: the 4×4 cells are ``round(p/4)`` px wide.
    out : (H, W, 128) uint8 C-contiguous ndarray, optional
        Written in place and returned (e.g. one view of the stacked sources'
        array: no second copy of ~50 MB per photo at 854×480).

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
    pooled = _orientation_planes(mag, ang)
    for k in range(8):
        pooled[k] = cv2.sepFilter2D(pooled[k], -1, tri, tri, borderType=cv2.BORDER_REFLECT_101)
    offs = np.array([int(math.floor((i - 1.5) * b + 0.5)) for i in range(4)], np.int64)
    sigma = 2.0 * b  # Gaussian over cells: half the descriptor width, as in SIFT
    cw = np.exp(-((offs[:, None] ** 2 + offs[None, :] ** 2) / (2.0 * sigma * sigma)))
    if out is None:
        out = np.empty(gray.shape + (128,), np.uint8)
    elif out.shape != gray.shape + (128,) or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous uint8 array of shape "
                         f"{gray.shape + (128,)}, got {out.dtype} {out.shape}")
    _assemble_sift(pooled, offs, cw.astype(np.float32), out)
    return out


@numba.njit(cache=True, nogil=True)
def _orientation_planes(mag, ang):
    """The gradient's magnitude split between its two nearest of 8 orientation
    bins (linear in the angle): (8, H, W) float32 from mag, ang (H, W) float32
    (``cv2.cartToPolar``, radians). Bin o = ⌊8·ang / 2π⌋ mod 8 takes mag·(1 − w),
    bin o + 1 (mod 8) takes mag·w, w the fraction; in float32, as the NumPy
    form first written (``test_features``)."""
    H, W = mag.shape
    out = np.zeros((8, H, W), np.float32)
    scale = np.float32(8.0 / (2.0 * math.pi))
    one = np.float32(1.0)
    for y in range(H):
        for x in range(W):
            o = ang[y, x] * scale
            f = np.floor(o)
            w1 = o - f
            o0 = int(f) % 8
            out[o0, y, x] = mag[y, x] * (one - w1)
            out[(o0 + 1) % 8, y, x] = mag[y, x] * w1
    return out


@numba.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def _assemble_sift(pooled, offs, cw, out):
    """pooled (8, H, W) float32, offs (4,) int64 ascending, cw (4, 4) float32 → out (H, W,
    128) uint8 (written).

    Per pixel, all in float32: d = the 16 cells' 8 pooled values × the cell
    weight, n = √Σ d² + 1e-12, d ← min(d · (1 / n), 0.2), then
    d · (512 / (√Σ d² + 1e-12)) + 0.5, saturated at 255 and truncated. The sums
    run over the 128 values in order, each pixel on its own; a row is done B
    pixels at a time with the pixel as the inner loop, so the reciprocals and
    the B sums vectorise across pixels while every pixel's arithmetic stays
    the same, bit for bit. error_model="numpy" drops the ZeroDivisionError
    check that stops vectorisation (the divisors are ≥ 1e-12). (Float64 sums
    and two divisions per value, as first written, took 1.6× the time at
    854×480 and changed 22 of its 52 million bytes, each by 1.)
    """
    _, H, W = pooled.shape
    B = 32
    one, tiny, clamp = np.float32(1.0), np.float32(1e-12), np.float32(0.2)
    scale, half, top = np.float32(512.0), np.float32(0.5), np.float32(255.0)
    for y in numba.prange(H):
        d = np.empty((128, B), np.float32)
        q = np.empty((128, B), np.uint8)
        n = np.empty(B, np.float32)
        n2 = np.empty(B, np.float32)
        for x0 in range(0, W, B):
            nbk = min(B, W - x0)
            inner = x0 + offs[0] >= 0 and x0 + nbk - 1 + offs[3] <= W - 1  # no clamping
            k = 0
            for cy in range(4):
                yy = min(max(y + offs[cy], 0), H - 1)
                for cx in range(4):
                    w = cw[cy, cx]
                    for o in range(8):
                        row = pooled[o, yy]
                        dk = d[k]
                        if inner:
                            base = x0 + offs[cx]
                            for p in range(nbk):
                                dk[p] = row[base + p] * w
                        else:
                            for p in range(nbk):
                                dk[p] = row[min(max(x0 + p + offs[cx], 0), W - 1)] * w
                        k += 1
            for p in range(nbk):
                n[p] = 0.0
            for i in range(128):
                di = d[i]
                for p in range(nbk):
                    n[p] += di[p] * di[p]
            for p in range(nbk):
                n[p] = one / (np.sqrt(n[p]) + tiny)
                n2[p] = 0.0
            for i in range(128):
                di = d[i]
                for p in range(nbk):
                    t = di[p] * n[p]
                    v = clamp if clamp < t else t  # min(t, 0.2) without a branch
                    di[p] = v
                    n2[p] += v * v
            for p in range(nbk):
                n2[p] = scale / (np.sqrt(n2[p]) + tiny)
            for i in range(128):
                di = d[i]
                qi = q[i]
                for p in range(nbk):
                    t = di[p] * n2[p] + half
                    qi[p] = np.uint8(top if top < t else t)
            for p in range(nbk):
                op = out[y, x0 + p]
                for i in range(128):
                    op[i] = q[i, p]
    return out


def sift_unit(descriptors: list[npt.NDArray[np.uint8]], *, sift_scale: float) -> float:
    """Factor turning stored uint8 SIFT into the paper's units.

    The paper divides SIFT by its maximum over the image set; ``sift_scale`` then
    sets the unit that σ_g is measured in (the paper leaves it open).
    """
    vmax = max(int(d.max()) for d in descriptors)
    return float(sift_scale) / float(max(vmax, 1))

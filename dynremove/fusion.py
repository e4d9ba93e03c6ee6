"""Background fusion inside the dynamic map (engineered step of the default preset).

The scan fills a dynamic pixel with a whole-pixel patch found by propagation,
so the fill drifts by a pixel here and there. Here, once L is known, each
source's sub-pixel correspondence field is *re-interpolated* across L from the
static pixels around it (normalised Gaussian convolution at growing scales:
inside a moving object the correspondences followed the object, outside it they
follow the background), every source is sampled there (bilinear), and the
medoid of the sources' colours — the sample closest to their per-channel
median — is written. The medoid is robust to the object still covering the
spot in a minority of sources and never invents a colour.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import numpy.typing as npt


def interpolate_field(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                      ) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole`` from the valid pixels around it."""
    out = field.copy()
    valid = (~hole).astype(np.float32)
    todo = hole.copy()
    if not valid.any():
        return out
    for sigma in (2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0):
        if not todo.any():
            break
        k = int(6 * sigma) | 1
        w = cv2.GaussianBlur(valid, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
        ok = todo & (w > 1e-3)
        if not ok.any():
            continue
        for c in range(field.shape[2]):
            num = cv2.GaussianBlur(field[..., c] * valid, (k, k), sigma,
                                   borderType=cv2.BORDER_CONSTANT)
            out[..., c][ok] = num[ok] / w[ok]
        todo &= ~ok
    return out


def fuse_background(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                    Nf: npt.NDArray[np.float32], mask: npt.NDArray[np.bool_], *,
                    margin_px: int = 2, fill: npt.NDArray[np.bool_] | None = None
                    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """Replace ``mask`` (dilated by ``margin_px``) with the fused background.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
        The input reference (pixels outside the region are returned unchanged).
    sources : (S, H, W, 3) uint8 ndarray
    Nf : (S, H, W, 2) float32 ndarray
        Sub-pixel matches reference → source (x, y).
    mask : (H, W) bool ndarray
        Final dynamic map.
    fill : (H, W) bool ndarray, optional
        Pixels to write (default: ``mask`` dilated by ``margin_px``); the
        correspondences are still re-interpolated inside ``mask`` only.

    Returns
    -------
    clean : (H, W, 3) uint8 ndarray
    n_valid : (H, W) uint8 ndarray
        Sources that were sampled inside their image at each pixel of the region.
    """
    H, W = mask.shape
    out = reference.copy()
    n_valid = np.zeros((H, W), np.uint8)
    if not mask.any() and fill is None:
        return out, n_valid
    r = max(0, int(margin_px))
    region = mask
    if r:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        region = cv2.dilate(mask.astype(np.uint8), k).astype(bool)
    # the field is interpolated over a slightly larger hole: flow at object edges bleeds
    hole = cv2.dilate(region.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    if fill is not None:
        region = fill
    ys, xs = np.nonzero(region)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    grid = np.stack([gx, gy], axis=-1)
    samples = np.zeros((len(sources), len(ys), 3), np.float32)
    ok = np.zeros((len(sources), len(ys)), bool)
    for s in range(len(sources)):
        # interpolate the displacement (smooth), not the absolute position
        f = interpolate_field(Nf[s] - grid, hole) + grid
        mx, my = np.ascontiguousarray(f[..., 0]), np.ascontiguousarray(f[..., 1])
        warped = cv2.remap(sources[s], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        inside = (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
        samples[s] = warped[ys, xs]
        ok[s] = inside[ys, xs]
    n_valid[ys, xs] = ok.sum(0)
    masked = np.where(ok[..., None], samples, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN where no source is valid
        med = np.nanmedian(masked, axis=0)  # (P, 3)
    d = np.where(ok, ((samples - np.nan_to_num(med)[None]) ** 2).sum(-1), np.inf)
    best = np.argmin(d, axis=0)
    fill = samples[best, np.arange(len(ys))]
    have = ok.any(0)
    out[ys[have], xs[have]] = np.clip(fill[have] + 0.5, 0, 255).astype(np.uint8)
    return out, n_valid


def lab_difference(a: npt.NDArray[np.uint8], b: npt.NDArray[np.uint8], *,
                   blur_sigma: float = 1.0) -> npt.NDArray[np.float32]:
    """Per-pixel CIE Lab distance of two (H, W, 3) uint8 BGR images, lightly blurred."""
    la = cv2.cvtColor(cv2.GaussianBlur(a, (0, 0), blur_sigma).astype(np.float32) / 255.0,
                      cv2.COLOR_BGR2Lab)
    lb = cv2.cvtColor(cv2.GaussianBlur(b, (0, 0), blur_sigma).astype(np.float32) / 255.0,
                      cv2.COLOR_BGR2Lab)
    return np.sqrt(((la - lb) ** 2).sum(-1))

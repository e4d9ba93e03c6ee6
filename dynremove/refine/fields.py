"""Background displacement fields across L, sampling through them, source votes.

Inside a moving object the correspondences followed the object; outside it
they follow the background. Each source's sub-pixel displacement field is
re-interpolated across L from the static pixels around it as a *membrane*
(harmonic) surface, solved coarse to fine (``harmonic_fill``). A plane's
displacement is locally close to linear, and a harmonic fill reproduces a
linear field exactly, where a normalised Gaussian blur (``interpolate_field``)
leans towards the side with more valid pixels (measured in the README: +0.8 dB
inside the mask).

``source_votes`` gives, at each pixel, the Lab distance between the reference
and every source sampled through the interpolated field; the mask refinement
(``mask.refine_mask``) reads them.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import pixel_grid


def interpolate_field(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                      ) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole``: normalised Gaussian convolution.

    A quick, smooth, but biased estimate; ``harmonic_fill`` uses it as the
    coarsest level.
    """
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


_CROSS = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)


def harmonic_fill(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                  iters: int = 40) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole`` with the membrane (Laplace) solution.

    Coarse to fine: the field is area-averaged over its valid pixels to half
    size (a coarse pixel is a hole if any of its fine pixels is), solved there,
    upsampled as the starting point, and relaxed by ``iters`` Jacobi sweeps.
    Valid pixels are never changed.
    """
    H, W = hole.shape
    if not hole.any() or hole.all():
        return field.copy()
    if min(H, W) < 24:
        return interpolate_field(field, hole)
    valid = (~hole).astype(np.float32)
    h2, w2 = (H + 1) // 2, (W + 1) // 2
    cvalid = cv2.resize(valid, (w2, h2), interpolation=cv2.INTER_AREA)
    chole = cvalid < 0.999
    if chole.all():
        return interpolate_field(field, hole)
    cfield = np.empty((h2, w2, field.shape[2]), np.float32)
    for c in range(field.shape[2]):
        cfield[..., c] = cv2.resize(field[..., c] * valid, (w2, h2),
                                    interpolation=cv2.INTER_AREA) / np.maximum(cvalid, 1e-6)
    coarse = harmonic_fill(np.where(chole[..., None], 0, cfield).astype(np.float32), chole,
                           iters=iters)
    up = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_LINEAR).reshape(H, W, -1)
    out = np.where(hole[..., None], up, field).astype(np.float32)
    # relax only inside the holes' bounding box
    ys, xs = np.nonzero(hole)
    y0, y1 = max(ys.min() - 1, 0), min(ys.max() + 2, H)
    x0, x1 = max(xs.min() - 1, 0), min(xs.max() + 2, W)
    sub_hole = hole[y0:y1, x0:x1]
    for c in range(out.shape[2]):
        sub = np.ascontiguousarray(out[y0:y1, x0:x1, c])
        for _ in range(iters):
            sm = cv2.filter2D(sub, -1, _CROSS, borderType=cv2.BORDER_REPLICATE)
            sub[sub_hole] = sm[sub_hole]
        out[y0:y1, x0:x1, c] = sub
    return out


def background_field(Nf: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                     ) -> npt.NDArray[np.float32]:
    """Matches (H, W, 2) with the *displacement* re-interpolated across ``hole``."""
    grid = np.stack(pixel_grid(*hole.shape), axis=-1)
    return harmonic_fill(Nf - grid, hole) + grid


def sample_bilinear(src: npt.NDArray[np.uint8], field: npt.NDArray[np.float32]):
    """Bilinear sample of ``src`` at ``field``; returns (image, inside)."""
    H, W = src.shape[:2]
    mx, my = np.ascontiguousarray(field[..., 0]), np.ascontiguousarray(field[..., 1])
    warped = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
    return warped, inside


def blurred_lab(img: npt.NDArray[np.uint8], blur_sigma: float) -> npt.NDArray[np.float32]:
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    return cv2.cvtColor(img.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)


def source_votes(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                 Nf: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                 blur_sigma: float = 1.0) -> npt.NDArray[np.float32]:
    """Per-source Lab distance to the reference through the background field.

    Returns
    -------
    D : (S, H, W) float32 ndarray
        CIE Lab distance (both images blurred by ``blur_sigma`` px) between the
        reference and source ``s`` sampled at its match, the matches being
        re-interpolated across ``hole``; ``inf`` where the match falls outside
        the source.
    """
    lab_r = blurred_lab(reference, blur_sigma)
    D = np.empty((len(sources),) + hole.shape, np.float32)
    for s in range(len(sources)):
        warped, inside = sample_bilinear(sources[s], background_field(Nf[s], hole))
        d = np.sqrt(((blurred_lab(warped, blur_sigma) - lab_r) ** 2).sum(-1))
        D[s] = np.where(inside, d, np.inf)
    return D


__all__ = ["interpolate_field", "harmonic_fill", "background_field", "sample_bilinear",
           "blurred_lab", "source_votes"]

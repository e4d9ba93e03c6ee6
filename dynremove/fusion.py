"""Background fusion and pixel-level votes (engineered steps of the default preset).

The scan fills a dynamic pixel with a whole-pixel patch found by propagation,
so the fill drifts by a pixel here and there, and its p×p patches make L a few
pixels too wide around every object. Once L is known, three steps use all the
sources at once:

* **Field interpolation.** Inside a moving object the correspondences followed
  the object; outside it they follow the background. Each source's sub-pixel
  displacement field is re-interpolated across L from the static pixels around
  it as a *membrane* (harmonic) surface, solved coarse to fine. A plane's
  displacement is locally close to linear, and a harmonic fill reproduces a
  linear field exactly, where a normalised Gaussian blur leans towards the side
  with more valid pixels (measured in the README: +0.8 dB inside the mask).
* **Votes** (``source_votes``). At each pixel, the Lab distance between the
  reference and every source sampled through the interpolated field. The mask
  refinement (``postprocess.refine_mask``) reads them.
* **Fusion** (``fuse_background``). Every source is sampled through the
  interpolated field and the per-channel median of the samples is written.
  Then ``realign`` passes re-measure the correspondences where the object was:
  DIS flow from the *cleaned* reference (no object in it any more) to each
  source tracks the background itself, so the hidden surface is copied with
  the sub-pixel accuracy of a flow instead of that of an interpolation.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import numpy.typing as npt

from dynremove import correspondence
from dynremove.postprocess import dilate_disc


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


def _grid(H: int, W: int) -> npt.NDArray[np.float32]:
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    return np.stack([gx, gy], axis=-1)


def background_field(Nf: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                     ) -> npt.NDArray[np.float32]:
    """Matches (H, W, 2) with the *displacement* re-interpolated across ``hole``."""
    grid = _grid(*hole.shape)
    return harmonic_fill(Nf - grid, hole) + grid


def _sample(src: npt.NDArray[np.uint8], field: npt.NDArray[np.float32]):
    """Bilinear sample of ``src`` at ``field``; returns (image, inside)."""
    H, W = src.shape[:2]
    mx, my = np.ascontiguousarray(field[..., 0]), np.ascontiguousarray(field[..., 1])
    warped = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
    return warped, inside


def _lab(img: npt.NDArray[np.uint8], blur_sigma: float) -> npt.NDArray[np.float32]:
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
    lab_r = _lab(reference, blur_sigma)
    D = np.empty((len(sources),) + hole.shape, np.float32)
    for s in range(len(sources)):
        warped, inside = _sample(sources[s], background_field(Nf[s], hole))
        d = np.sqrt(((_lab(warped, blur_sigma) - lab_r) ** 2).sum(-1))
        D[s] = np.where(inside, d, np.inf)
    return D


def fuse_background(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                    Nf: npt.NDArray[np.float32], mask: npt.NDArray[np.bool_], *,
                    margin_px: int = 2, combine: str = "median", realign: int = 0,
                    homographies: list[np.ndarray] | None = None,
                    flow_preset: str = "medium", realign_max_px: float = np.inf
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
    combine : {"median", "medoid"}
        Per-channel median of the sources' samples, or the sample closest to it.
    realign : int
        Passes of re-measured correspondences (module docstring); 0 = off.
    homographies : list of (3, 3) ndarray
        Reference → source homographies (the flow's pre-warp); needed when
        ``realign`` > 0.

    Returns
    -------
    clean : (H, W, 3) uint8 ndarray
    n_valid : (H, W) uint8 ndarray
        Sources that were sampled inside their image at each pixel of the region.
    """
    if combine not in ("median", "medoid"):
        raise ValueError(f"combine must be 'median' or 'medoid', got {combine!r}")
    H, W = mask.shape
    n_valid = np.zeros((H, W), np.uint8)
    if not mask.any():
        return reference.copy(), n_valid
    region = dilate_disc(mask, int(margin_px))
    # the field is interpolated over a slightly larger hole: flow at object edges bleeds
    hole = cv2.dilate(region.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    fields = [background_field(Nf[s], hole) for s in range(len(sources))]
    clean = _fuse(reference, sources, fields, region, combine, n_valid)
    if realign > 0 and homographies is None:
        raise ValueError("realign needs the homographies")
    grays = [cv2.cvtColor(src, cv2.COLOR_BGR2GRAY) for src in sources] if realign > 0 else []
    for _ in range(max(0, int(realign))):
        fields = _realign(clean, grays, fields, hole, homographies, flow_preset,
                          realign_max_px)
        clean = _fuse(reference, sources, fields, region, combine, n_valid)
    return clean, n_valid


def _fuse(reference, sources, fields, region, combine, n_valid):
    ys, xs = np.nonzero(region)
    samples = np.zeros((len(sources), len(ys), 3), np.float32)
    ok = np.zeros((len(sources), len(ys)), bool)
    for s in range(len(sources)):
        warped, inside = _sample(sources[s], fields[s])
        samples[s] = warped[ys, xs]
        ok[s] = inside[ys, xs]
    n_valid[ys, xs] = ok.sum(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN where no source is valid
        med = np.nanmedian(np.where(ok[..., None], samples, np.nan), axis=0)  # (P, 3)
    if combine == "median":
        fill = np.nan_to_num(med)
    else:
        d = np.where(ok, ((samples - np.nan_to_num(med)[None]) ** 2).sum(-1), np.inf)
        fill = samples[np.argmin(d, axis=0), np.arange(len(ys))]
    out = reference.copy()
    have = ok.any(0)
    out[ys[have], xs[have]] = np.clip(fill[have] + 0.5, 0, 255).astype(np.uint8)
    return out


def _realign(clean, src_grays, fields, hole, homographies, flow_preset, max_px):
    """Matches inside ``hole`` re-measured by flow from the cleaned reference.

    Only the bounding box of the hole (plus a margin for the flow's context)
    is matched; a re-measured match further than ``max_px`` from the current
    one is not trusted.
    """
    H, W = hole.shape
    ys, xs = np.nonzero(hole)
    pad = 32
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, H)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, W)
    shift = np.array([[1.0, 0.0, x0], [0.0, 1.0, y0], [0.0, 0.0, 1.0]])
    g_clean = cv2.cvtColor(np.ascontiguousarray(clean[y0:y1, x0:x1]), cv2.COLOR_BGR2GRAY)
    sub_hole = hole[y0:y1, x0:x1]
    out = []
    for s, g_src in enumerate(src_grays):
        n2 = correspondence.dense_correspondence(g_clean, g_src, homographies[s] @ shift,
                                                 method="homography+flow",
                                                 flow_preset=flow_preset)
        f = fields[s].copy()
        cur = f[y0:y1, x0:x1]
        use = sub_hole & (np.linalg.norm(n2 - cur, axis=-1) <= max_px)
        cur[use] = n2[use]
        out.append(f)
    return out

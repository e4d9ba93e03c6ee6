"""Fill of the dynamic region from all sources (default preset only).

``fuse_background`` samples every source through its background field
(``fields.background_field``: the displacement re-interpolated across L) and
writes the per-channel median of the samples. Then ``realign`` passes
re-measure the correspondences where the object was: DIS flow from the
*cleaned* reference (no object in it any more) to each source tracks the
background itself, so the hidden surface is copied with the sub-pixel accuracy
of a flow instead of that of an interpolation.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import dense_correspondence
from dynremove.refine.concurrency import for_each_source
from dynremove.refine.fields import background_fields, sample_bilinear
from dynremove.refine.morphology import dilate_disc


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
    fields = background_fields(Nf, hole)
    clean, n_valid = median_fill(reference, sources, fields, region, combine=combine)
    if realign > 0 and homographies is None:
        raise ValueError("realign needs the homographies")
    grays = [cv2.cvtColor(src, cv2.COLOR_BGR2GRAY) for src in sources] if realign > 0 else []
    for _ in range(max(0, int(realign))):
        fields = realign_fields(clean, grays, fields, hole, homographies, flow_preset,
                                realign_max_px)
        clean, n_valid = median_fill(reference, sources, fields, region, combine=combine)
    return clean, n_valid


def median_fill(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                fields: list[npt.NDArray[np.float32]], region: npt.NDArray[np.bool_], *,
                combine: str = "median", exclude: npt.NDArray[np.bool_] | None = None
                ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """``reference`` with ``region`` replaced by the median (or medoid) of the sources.

    ``fields``: per source, (H, W, 2) float32 matches reference → source.
    ``exclude``: (S, H, W) bool, optional: where a source's sample must not count
    (it shows a mover); a pixel that no source may fill keeps the reference.
    Returns the image and, per pixel, how many sources were inside their frame
    (and not excluded).
    """
    n_valid = np.zeros(region.shape, np.uint8)
    ys, xs = np.nonzero(region)
    samples = np.zeros((len(sources), len(ys), 3), np.float32)
    ok = np.zeros((len(sources), len(ys)), bool)
    for s in range(len(sources)):
        warped, inside = sample_bilinear(sources[s], fields[s])
        samples[s] = warped[ys, xs]
        ok[s] = inside[ys, xs]
        if exclude is not None:
            ok[s] &= ~exclude[s, ys, xs]
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
    return out, n_valid


def realign_fields(clean, src_grays, fields, hole, homographies, flow_preset, max_px):
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

    def one(s):
        n2 = dense_correspondence(g_clean, src_grays[s], homographies[s] @ shift,
                                  method="homography+flow", flow_preset=flow_preset)
        f = fields[s].copy()
        cur = f[y0:y1, x0:x1]
        use = sub_hole & (np.linalg.norm(n2 - cur, axis=-1) <= max_px)
        cur[use] = n2[use]
        return f

    return for_each_source(one, len(src_grays))


__all__ = ["fuse_background", "median_fill", "realign_fields"]

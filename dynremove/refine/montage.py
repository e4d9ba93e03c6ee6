"""Photomontage: one source per pixel by graph cut, then an exposure-matching blend.

Agarwala et al., *Interactive Digital Photomontage*, SIGGRAPH 2004: every pixel
takes its value from one of several aligned images (labels); the labelling
minimises a data cost plus a seam cost

.. math:: E(l) = \\sum_p D_p(l_p) + \\beta \\sum_{(p,q)} V_{pq}(l_p, l_q),\\quad
          V_{pq}(a, b) = \\lVert I_a(p) - I_b(p) \\rVert + \\lVert I_a(q) - I_b(q) \\rVert

(0 when a = b), so seams run where the two images agree. V is a metric, so
alpha-expansion (Boykov, Veksler & Zabih, PAMI 2001) applies: each move is a
binary min-cut, solved by PyMaxflow (Boykov-Kolmogorov max-flow); the move's
pairwise terms are written into the graph by the standard construction of
Kolmogorov & Zabih (PAMI 2004).

The blend replaces the paper's Poisson step by its low-frequency part: each
chosen source gets a smooth offset, the membrane (harmonic) interpolation of
``reference - source`` measured on a thin ring around the replaced region.
Ring pixels where the two disagree (a mover, a misalignment) are left out of
the interpolation, so nothing bleeds inwards, which a plain Poisson solve with
the ring as boundary does (measured: README "Fill by selection").
"""

from __future__ import annotations

import maxflow
import numpy as np
import numpy.typing as npt

from dynremove.refine.fields import harmonic_fill
from dynremove.refine.morphology import dilate_disc


def pairwise_distance(colours: np.ndarray) -> np.ndarray:
    """(L, L, H, W) float32: |I_a(p) - I_b(p)| for every label pair (0 on the diagonal)."""
    nl = len(colours)
    out = np.zeros((nl, nl) + colours.shape[1:3], np.float32)
    for a in range(nl):
        for b in range(a + 1, nl):
            d = colours[a] - colours[b]
            out[a, b] = out[b, a] = np.sqrt(np.einsum("...c,...c->...", d, d))
    return out


def expansion_labels(D: npt.NDArray[np.float64], colours: npt.NDArray[np.float32], *,
                     beta: float, cycles: int = 2,
                     init: npt.NDArray[np.intp] | None = None,
                     distance: npt.NDArray[np.float32] | None = None) -> npt.NDArray[np.intp]:
    """Alpha-expansion of the photomontage energy on a 4-connected grid.

    Parameters
    ----------
    D : (L, H, W) float64 ndarray
        Data cost of each label at each pixel (use a large finite value, not
        ``inf``, for a forbidden label).
    colours : (L, H, W, 3) float32 ndarray
        Each label's image (e.g. CIE Lab), for the seam cost ``V``.
    beta : float
        Weight of the seam cost.
    cycles : int
        Passes over all labels (stops earlier when a pass changes nothing).
    init : (H, W) int ndarray, optional
        Starting labelling (default: the cheapest label per pixel).
    distance : (L, L, H, W) float32 ndarray, optional
        ``pairwise_distance(colours)`` if the caller has it already.

    Returns
    -------
    labels : (H, W) intp ndarray
    """
    nl, H, W = D.shape
    lab = np.argmin(D, 0) if init is None else init.astype(np.intp).copy()
    # V(a, b) at each pixel; an edge sums it over both its pixels
    pair = beta * (pairwise_distance(colours) if distance is None else distance)
    yy, xx = np.mgrid[0:H, 0:W]
    for _ in range(cycles):
        changed = False
        for a in range(nl):
            cost1 = D[a].astype(np.float64).copy()  # x_p = 1: p takes label a
            cost0 = np.take_along_axis(D, lab[None], 0)[0].astype(np.float64)
            g = maxflow.Graph[float]()
            nodes = g.add_grid_nodes((H, W))
            for axis in (0, 1):
                if (H, W)[axis] < 2:
                    continue
                sp = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
                sq = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
                lp, lq = lab[sp], lab[sq]
                yp, xp, yq, xq = yy[sp], xx[sp], yy[sq], xx[sq]

                def V(u, v):  # seam cost of labels u at p and v at q (per edge)
                    return pair[u, v, yp, xp] + pair[u, v, yq, xq]

                A, B, C = V(lp, lq), V(lp, a), V(a, lq)
                # E(x_p, x_q) = A + (C - A) x_p - C x_q + (B + C - A)(1 - x_p) x_q
                w = np.zeros((H, W))
                w[sp] = np.maximum(B + C - A, 0.0)
                cost1[sp] += C - A
                cost1[sq] -= C
                st = np.zeros((3, 3))
                st[1 + (axis == 0), 1 + (axis == 1)] = 1
                g.add_grid_edges(nodes, weights=w, structure=st, symmetric=False)
            m = np.minimum(cost0, cost1)
            g.add_grid_tedges(nodes, cost1 - m, cost0 - m)
            g.maxflow()
            take = g.get_grid_segments(nodes) & (lab != a)
            if take.any():
                changed = True
                lab[take] = a
        if not changed:
            break
    return lab


def offset_blend(reference: npt.NDArray[np.uint8], candidates: npt.NDArray[np.uint8],
                 labels: npt.NDArray[np.intp], replaced: npt.NDArray[np.bool_],
                 usable: npt.NDArray[np.bool_], distance_to_ref: npt.NDArray[np.float32], *,
                 ring_px: int = 3, max_de: float = 15.0) -> npt.NDArray[np.uint8]:
    """Write each chosen source plus a smooth offset that matches the reference.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
    candidates : (L, H, W, 3) uint8 ndarray
        Label 0 is the reference; label k > 0 a source aligned to it.
    labels : (H, W) int ndarray
    replaced : (H, W) bool ndarray
        Pixels whose label is not 0.
    usable : (L, H, W) bool ndarray
        Where each candidate is inside its image.
    distance_to_ref : (L, H, W) float32 ndarray
        CIE76 distance of each candidate to the reference; ring pixels with
        more than ``max_de`` are not used to measure the offset.

    Returns
    -------
    out : (H, W, 3) uint8 ndarray
        ``reference`` outside ``replaced``.
    """
    out = reference.astype(np.float32)
    ring = dilate_disc(replaced, ring_px) & ~replaced
    for lbl in np.unique(labels[replaced]):
        if lbl == 0:
            continue
        src = candidates[lbl].astype(np.float32)
        d = reference.astype(np.float32) - src
        good = ring & usable[lbl] & (distance_to_ref[lbl] < max_de)
        sel = replaced & (labels == lbl)
        if good.sum() < 20:  # too little ring: one global offset (or none)
            off = np.zeros_like(d)
            if good.any():
                off[:] = np.median(d[good], axis=0)
        else:
            off = harmonic_fill(np.where(good[..., None], d, 0).astype(np.float32), ~good)
        out[sel] = src[sel] + off[sel]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


__all__ = ["expansion_labels", "offset_blend", "pairwise_distance"]

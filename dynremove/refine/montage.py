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
chosen source gets a smooth offset from ``reference - source`` measured on a
thin ring around the replaced region: the ring's median (the photos' exposure
and white balance) everywhere, plus the membrane (harmonic) interpolation of
each ring pixel's departure from it (``ring_offset``), in two parts: its local
mean (light that changes across the photo: a glare on a glossy table seen from
elsewhere, vignetting) fading over tens of pixels, the rest (content: an edge a
pixel off) within a few pixels of the ring. Ring pixels where the two disagree
(a mover, a misalignment) are left out, so nothing bleeds inwards, which a
plain Poisson solve with the ring as boundary does (measured: README "Fill by
selection"); a ring pixel far from the ring's median difference still counts
when the band a little further out shows the same difference (light, not the
mover's halo: ``band_light``).
"""

from __future__ import annotations

import math

import cv2
import maxflow
import numpy as np
import numpy.typing as npt

from dynremove.refine.colour import delta_e, pairwise_delta_e
from dynremove.refine.concurrency import for_each_source
from dynremove.refine.fields import harmonic_fill
from dynremove.refine.morphology import dilate_disc

# the ring's departure from its median offset is kept within PLATEAU_PX of the
# ring and fades over DECAY_PX beyond (``ring_offset``; chosen on the composites)
PLATEAU_PX = 4.0
DECAY_PX = 3.0
# a ring pixel's departure sets the offset only when it is within
# DEPARTURE_MAX_DEV (levels of 0-255, any channel) of its neighbours', weighted
# by a Gaussian of σ LIGHT_SIGMA_PX (``consistent_departures``)
DEPARTURE_MAX_DEV = 6.0
LIGHT_SIGMA_PX = 4.0
# the light part of the departure: its normalised Gaussian mean of σ LIGHT_SCALE_PX
# along the ring, faded over LIGHT_DECAY_PX beyond the plateau (``ring_offset``)
LIGHT_SCALE_PX = 8.0
LIGHT_DECAY_PX = 30.0
# the band where light is told from content (``band_light``): BAND_PX[0] to
# BAND_PX[1] px out of the replaced region, beyond the mover's halo; its local
# mean of σ BAND_SIGMA_PX; a ring pixel within BAND_AGREE × max_de (ΔE) of it agrees
BAND_PX = (6, 20)
BAND_SIGMA_PX = 8.0
BAND_AGREE = 0.5


def pairwise_distance(colours: np.ndarray) -> np.ndarray:
    """(L, L, H, W) float32: |I_a(p) - I_b(p)| for every label pair (0 on the diagonal)."""
    return pairwise_delta_e(colours).astype(np.float32, copy=False)


def expansion_labels(D: npt.NDArray[np.float64], colours: npt.NDArray[np.float32], *,
                     beta: float, cycles: int = 2,
                     init: npt.NDArray[np.intp] | None = None,
                     distance: npt.NDArray[np.float32] | None = None,
                     forbidden: float | None = None) -> npt.NDArray[np.intp]:
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
    forbidden : float, optional
        A data cost at or above it marks the label as not allowed at that pixel.
        Such pixels keep their label in that label's move, so they are left out
        of its graph and their seam terms with the pixels that may move become
        data terms (the same energy, a smaller min-cut). It must exceed any
        sum of seam costs, as a cost that forbids a label does.

    Returns
    -------
    labels : (H, W) intp ndarray
    """
    nl, H, W = D.shape
    n = H * W
    lab = (np.argmin(D, 0) if init is None else init.astype(np.intp).copy()).ravel()
    # V(a, b) at each pixel; an edge sums it over both its pixels
    dist = (pairwise_distance(colours) if distance is None else distance).reshape(nl * nl, n)
    Df = D.reshape(nl, n)
    idx = np.arange(n).reshape(H, W)
    ep = np.concatenate([idx[:-1].ravel(), idx[:, :-1].ravel()])  # p of each edge
    eq = np.concatenate([idx[1:].ravel(), idx[:, 1:].ravel()])  # its neighbour q
    # Only a pixel with two allowed labels or more can ever move, and only an edge
    # touching one can carry a term: every move works on those pixels (``act``,
    # in pixel order) and edges (in their order), numbered compactly. The graphs,
    # their nodes' and edges' order and every sum are those of the whole grid:
    # the same labelling (on the fill's box, most pixels allow the reference only)
    act = (np.flatnonzero((Df < forbidden).sum(0) >= 2) if forbidden is not None
           else np.arange(n))
    if init is not None and forbidden is not None:
        # a pixel started on a forbidden label may move to its one allowed label
        act = np.union1d(act, np.flatnonzero(Df[lab, np.arange(n)] >= forbidden))
    compact = np.full(n, -1, np.intp)
    compact[act] = np.arange(len(act))
    e = (compact[ep] >= 0) | (compact[eq] >= 0)
    ep, eq = ep[e], eq[e]
    cp, cq = compact[ep], compact[eq]
    na = len(act)

    def V(u, v, p, q):  # seam cost of labels u at p and v at q, per edge (p, q)
        k = u * nl + v
        # (β times the distance at each pixel, as one product over all of them gave)
        return beta * dist[k, p] + beta * dist[k, q]

    for _ in range(cycles):
        changed = False
        for a in range(nl):
            # p may move to a (x_p = 1) unless a is forbidden there or p has it already
            free_a = lab[act] != a
            if forbidden is not None:
                free_a &= Df[a, act] < forbidden
            if not free_a.any():
                continue
            nf = int(free_a.sum())
            node = np.full(na, -1, np.intp)
            node[free_a] = np.arange(nf)
            cost1 = Df[a, act].astype(np.float64)  # x_p = 1: p takes label a
            cost0 = Df[lab[act], act].astype(np.float64)
            # only edges touching a pixel that may move carry a term
            fp, fq = (cp >= 0), (cq >= 0)
            fp[fp] = free_a[cp[fp]]
            fq[fq] = free_a[cq[fq]]
            e = fp | fq
            p, q = ep[e], eq[e]
            fp, fq = fp[e], fq[e]
            lp, lq = lab[p], lab[q]
            A, B, C = V(lp, lq, p, q), V(lp, a, p, q), V(a, lq, p, q)
            # E(x_p, x_q) = A + (C - A) x_p - C x_q + (B + C - A)(1 - x_p) x_q;
            # a fixed pixel has x = 0
            both = fp & fq
            only_q = fq & ~fp
            pc, qc = cp[e], cq[e]
            cost1 += np.bincount(pc[fp], (C - A)[fp], na)
            cost1 -= np.bincount(qc[both], C[both], na)
            cost1 += np.bincount(qc[only_q], (B - A)[only_q], na)
            g = maxflow.Graph[float]()
            g.add_nodes(nf)
            g.add_edges(node[pc[both]], node[qc[both]],
                        np.maximum(B + C - A, 0.0)[both], np.zeros(int(both.sum())))
            c1, c0 = cost1[free_a], cost0[free_a]
            m = np.minimum(c0, c1)
            g.add_grid_tedges(np.arange(len(c1)), c1 - m, c0 - m)
            g.maxflow()
            take = g.get_grid_segments(np.arange(len(c1)))
            if take.any():
                changed = True
                lab[act[free_a][take]] = a
        if not changed:
            break
    return lab.reshape(H, W)


def offset_blend(reference: npt.NDArray[np.uint8], candidates: npt.NDArray[np.uint8],
                 labels: npt.NDArray[np.intp], replaced: npt.NDArray[np.bool_],
                 usable: npt.NDArray[np.bool_], labs: npt.NDArray[np.float32], *,
                 ring_px: int = 3, max_de: float = 15.0,
                 suspect: npt.NDArray[np.bool_] | None = None) -> npt.NDArray[np.uint8]:
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
    labs : (L, H, W, 3) float32 ndarray
        Each candidate in CIE Lab (blurred, ``fields.blurred_lab``); on the
        ring they decide which pixels set the offset (``ring_agrees``).
    suspect : (H, W) bool ndarray, optional
        Pixels that may show a mover (L): they are no evidence of light in the
        band beyond the ring (``band_light``). A mover's kept parts (its head
        and legs, dark on the dark scene behind them) otherwise read as light
        that reaches across the fill: on tim6 with tim3.jpg the man's replaced
        body, white wall in the source, came out a dark smear (offset −45 levels
        on average, −143 at the 10th percentile; −5 without them).

    Returns
    -------
    out : (H, W, 3) uint8 ndarray
        ``reference`` outside ``replaced``.

    Notes
    -----
    Only the ring and the replaced pixels are read, and the offset is solved
    only where it decides the replaced pixels (``ring_offset``).
    """
    out = reference.copy()
    ring = dilate_disc(replaced, ring_px) & ~replaced
    ry, rx = np.nonzero(ring)
    band = band_around(replaced, BAND_PX)
    if suspect is not None:
        band &= ~suspect
    by, bx = np.nonzero(band)
    ref_ring = reference[ry, rx]

    def blend(lbl):
        sel = replaced & (labels == lbl)
        diff = labs[0, ry, rx] - labs[lbl, ry, rx]
        local = band_light(labs[0, by, bx] - labs[lbl, by, bx], usable[lbl, by, bx],
                           (by, bx), (ry, rx), BAND_SIGMA_PX, max_de)
        good = ring_agrees(diff, usable[lbl, ry, rx], max_de, local=local)
        sy, sx = np.nonzero(sel)
        off = ring_offset(ref_ring, candidates[lbl, ry, rx], good, (ry, rx), sel)
        writes = [(sy, sx, add_offset(candidates[lbl, sy, sx], off))]
        for cy, cx, coff in component_offsets(ref_ring, candidates[lbl, ry, rx], diff,
                                              usable[lbl, ry, rx], ring, sel, replaced,
                                              ring_px=ring_px, max_de=max_de):
            writes.append((cy, cx, add_offset(candidates[lbl, cy, cx], coff)))
        return writes

    # each source's part on a thread (each reads the inputs only); written in
    # label order, as a loop would
    lbls = [int(v) for v in np.unique(labels[replaced]) if v != 0]
    for writes in for_each_source(lambda i: blend(lbls[i]), len(lbls)):
        for wy, wx, val in writes:
            out[wy, wx] = val
    return out


def band_around(replaced: npt.NDArray[np.bool_], band_px: tuple[int, int]
                ) -> npt.NDArray[np.bool_]:
    """The pixels ``band_px[0]`` (excluded) to ``band_px[1]`` px (Euclidean discs) out of
    ``replaced`` (H, W) bool: where ``band_light`` measures the light."""
    return dilate_disc(replaced, band_px[1]) & ~dilate_disc(replaced, band_px[0])


def gaussian_mean_at(ys: npt.NDArray[np.intp], xs: npt.NDArray[np.intp],
                     values: npt.NDArray[np.float32], qy: npt.NDArray[np.intp],
                     qx: npt.NDArray[np.intp], sigma_px: float, *, min_weight: float = 1e-3
                     ) -> npt.NDArray[np.float32]:
    """The normalised Gaussian mean (Knutsson & Westin 1993) of scattered samples,
    read at query points.

    Parameters
    ----------
    ys, xs : (N,) int ndarrays
        The samples' pixels (any origin: only relative positions count).
    values : (N, C) float32 ndarray
    qy, qx : (Q,) int ndarrays
        The query pixels, in the samples' frame.
    sigma_px : float
        σ in pixels. From 8 px up the sums are taken per cell of ⌊σ / 4⌋² pixels
        and blurred with σ / ⌊σ / 4⌋ (the full-size output of large photos), at
        the cost of the working size's.
    min_weight : float
        Below this sum of the Gaussian's weights (the samples near the query),
        NaN (0: never).

    Returns
    -------
    mean : (Q, C) float32 ndarray
        NaN where no sample lies within about 3σ of the query.
    """
    C = values.shape[1]
    if len(ys) == 0:
        return np.full((len(qy), C), np.nan, np.float32)
    step = max(1, int(sigma_px // 4))
    sigma = sigma_px / step
    r = int(math.ceil(3 * sigma))
    oy0, ox0 = min(ys.min(), qy.min(initial=ys.min())), min(xs.min(), qx.min(initial=xs.min()))
    sy, sx = (ys - oy0) // step + r, (xs - ox0) // step + r
    ty, tx = (qy - oy0) // step + r, (qx - ox0) // step + r
    shape = (int(max(sy.max(), ty.max(initial=0))) + r + 1,
             int(max(sx.max(), tx.max(initial=0))) + r + 1)
    k = 2 * r + 1
    # the sums per cell (one pixel each at step 1), in float32 as the blur reads them
    cell = sy * shape[1] + sx
    n = shape[0] * shape[1]
    w = np.bincount(cell, minlength=n).astype(np.float32).reshape(shape)
    v = values.astype(np.float32)
    f = np.stack([np.bincount(cell, v[:, c].astype(np.float64), n).astype(np.float32)
                  for c in range(C)], axis=-1).reshape(shape + (C,))
    ws = cv2.GaussianBlur(w, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)[ty, tx]
    fs = cv2.GaussianBlur(f, (k, k), sigma, borderType=cv2.BORDER_CONSTANT)
    fs = fs.reshape(shape + (C,))[ty, tx]
    out = fs / np.maximum(ws, 1e-6)[:, None]
    if min_weight > 0:
        out[ws < min_weight] = np.nan
    return out


def band_light(difference: npt.NDArray[np.float32], usable: npt.NDArray[np.bool_],
               band: tuple[np.ndarray, np.ndarray], at: tuple[np.ndarray, np.ndarray],
               sigma_px: float, max_de: float, *, passes: int = 2
               ) -> npt.NDArray[np.float32]:
    """The light difference between the reference and a source near each ring pixel,
    measured in a band further out.

    Light that differs between two photos (a glare seen from one viewpoint only,
    vignetting, shade) spreads over the photo; the reference's mover (its halo,
    the part the mask missed) is confined to the replaced region's edge. So a
    ring pixel whose difference is far from the ring's median is still light when
    the band ``BAND_PX`` beyond it shows the same difference (``ring_agrees``).
    The band's local mean is robust: ``passes`` rounds, each keeping the band
    pixels within ``BAND_AGREE × max_de`` (CIE76) of the mean of those kept
    before (the first over all usable ones), as in ``consistent_departures``.

    Parameters
    ----------
    difference : (B, 3) float32 ndarray
        The reference's Lab minus the source's at the B band pixels (blurred,
        ``fields.blurred_lab``).
    usable : (B,) bool ndarray
        Where the source has content.
    band, at : (ys, xs) int ndarrays
        The band's pixels and the ring's (the same frame).
    sigma_px : float
        σ of the local mean (``gaussian_mean_at``).
    max_de : float
        ``ring_agrees``' tolerance.

    Returns
    -------
    local : (R, 3) float32 ndarray
        At the ring pixels ``at``; NaN where no band pixel is near.
    """
    by, bx = band[0][usable], band[1][usable]
    d = difference[usable]
    keep = np.ones(len(by), bool)
    for _ in range(passes):
        if not keep.any():
            break
        loc = gaussian_mean_at(by[keep], bx[keep], d[keep], by, bx, sigma_px)
        with np.errstate(invalid="ignore"):
            keep = delta_e(d, loc) < BAND_AGREE * max_de
    return gaussian_mean_at(by[keep], bx[keep], d[keep], at[0], at[1], sigma_px)


def component_offsets(ref_ring: npt.NDArray[np.uint8], src_ring: npt.NDArray[np.uint8],
                      difference: npt.NDArray[np.float32], usable: npt.NDArray[np.bool_],
                      ring: npt.NDArray[np.bool_], sel: npt.NDArray[np.bool_],
                      replaced: npt.NDArray[np.bool_], *, ring_px: int, max_de: float = 15.0,
                      plateau_px: float = PLATEAU_PX, decay_px: float = DECAY_PX,
                      light_sigma_px: float = LIGHT_SIGMA_PX,
                      light_scale_px: float = LIGHT_SCALE_PX,
                      light_decay_px: float = LIGHT_DECAY_PX):
    """The offsets of the small regions that take one source, each from its own ring.

    One offset per source (``ring_offset`` over the ring of everything the source
    fills) is right for the photos' exposure and white balance, but light that
    changes across the photo (a glossy table seen from elsewhere, vignetting)
    leaves a small refilled region brighter or darker than its surroundings.
    A connected component of ``sel`` (8-connected) takes its own offset, measured
    on its own ring (the pixels within ``ring_px`` of it outside ``replaced``),
    when that ring is at least half of its band and at least half its area (a
    small region, mostly surrounded by the photo; a large one, the mover itself,
    keeps the source's offset, whose ring is larger). Each is solved on a box
    ``ring_px + 2`` px around it.

    Parameters
    ----------
    ref_ring, src_ring : (R, 3) uint8 ndarrays
        The reference and the source at the ``R`` pixels of ``ring`` (row-major).
    difference : (R, 3) float32 ndarray
        Their blurred Lab difference there (``ring_agrees``); usable : (R,) bool.
    ring, sel, replaced : (H, W) bool ndarrays
        The ring of the whole replaced region, the pixels taking this source, and
        the replaced region.

    Returns
    -------
    list of (ys, xs, offset)
        Per component taken: its pixels (row-major) and their (M, 3) float32 offset.
    """
    H, W = sel.shape
    n, cc, stats, _ = cv2.connectedComponentsWithStats(sel.view(np.uint8), connectivity=8)
    if n <= 2:  # one region: the source's own ring is its ring
        return []
    ring_index = np.full((H, W), -1, np.int32)
    gy, gx = np.nonzero(ring)
    ring_index[gy, gx] = np.arange(len(gy), dtype=np.int32)
    m = ring_px + 2
    out = []
    for i in range(1, n):
        x, y, w, h, area = (int(v) for v in stats[i])
        y0, y1, x0, x1 = max(y - m, 0), min(y + h + m, H), max(x - m, 0), min(x + w + m, W)
        comp = cc[y0:y1, x0:x1] == i
        band = dilate_disc(comp, ring_px) & ~comp
        own = band & ~replaced[y0:y1, x0:x1]
        n_own = int(np.count_nonzero(own))
        n_band = int(np.count_nonzero(band))
        # against its area, the ring counts as if the photo went on past its border
        # (a region at the border is no less surrounded by the photo: tim6's pale
        # patch below the tube, 614 px against a 265-px ring, kept the source's offset)
        padded = np.pad(comp, ring_px)
        n_full = int(np.count_nonzero(dilate_disc(padded, ring_px) & ~padded))
        if n_own < max(20, 0.5 * n_band, 0.5 * area * n_band / max(n_full, 1)):
            continue
        cy, cx = np.nonzero(own)
        idx = ring_index[cy + y0, cx + x0]
        good = ring_agrees(difference[idx], usable[idx], max_de)
        off = ring_offset(ref_ring[idx], src_ring[idx], good, (cy, cx), comp,
                          plateau_px=plateau_px, decay_px=decay_px,
                          light_sigma_px=light_sigma_px, light_scale_px=light_scale_px,
                          light_decay_px=light_decay_px)
        qy, qx = np.nonzero(comp)
        out.append((qy + y0, qx + x0, off))
    return out


def ring_agrees(difference: npt.NDArray[np.float32], usable: npt.NDArray[np.bool_],
                max_de: float = 15.0, *, local: npt.NDArray[np.float32] | None = None
                ) -> npt.NDArray[np.bool_]:
    """Ring pixels whose reference − source difference may set the source's offset.

    difference : (R, 3) float32, the reference's Lab minus the source's at the R
    ring pixels (CIE76 units); usable : (R,) bool, where the source has content.
    A pixel agrees when its difference lies within ``max_de`` of the usable
    ring's median difference: the median is the photos' exposure and
    white-balance offset (a darker reference, a glare that covers the ring), and
    what departs from it is content (a misaligned edge, another mover). With
    ``local`` (R, 3), the light measured beyond the ring (``band_light``; NaN: none),
    a pixel within ``BAND_AGREE × max_de`` of it agrees too: light that changes
    across the photo (a glare on part of the ring only), not content.
    Returns (R,) bool.
    """
    if not usable.any():
        return usable.copy()
    med = np.median(difference[usable], axis=0)
    good = usable & (delta_e(difference, med) < max_de)
    if local is not None:
        with np.errstate(invalid="ignore"):
            good |= usable & (delta_e(difference, local) < BAND_AGREE * max_de)
    return good


# ``light_like``: the spread (natural log) of the B, G and R gains that a fill's
# offset keeps in full, and the one from which it keeps only their mean (white
# balance of ±6 % spans 0.12); the levels added to both sides of a gain (dark
# pixels' noise is no hue)
LIGHT_SPREAD, CONTENT_SPREAD, LIGHT_FLOOR = 0.15, 0.3, 32.0


def light_like(source: npt.NDArray[np.uint8], written: npt.NDArray[np.uint8], *,
               light: float = LIGHT_SPREAD, content: float = CONTENT_SPREAD,
               floor: float = LIGHT_FLOOR) -> npt.NDArray[np.uint8]:
    """``written`` with the change from ``source`` kept to what light does.

    Light (exposure, white balance, shade, glare) scales the three channels
    alike; an offset that raises one channel and lowers another by tens of
    levels is content carried in from the ring around the region (the ring
    showed a source's own mover there, and the band beyond confirmed it as
    light): it turned a brown table green (tim1-tim4 of ``bursts/tim6``, tim2 the
    reference: +19/+32/-35 levels). Per pixel, the B/G/R gains ``(written +
    floor) / (source + floor)`` are taken in logs; their departures from their
    mean are kept in full where they spread by at most ``light``, not at all
    from ``content`` up (the mean, the change of brightness, is kept), and in
    proportion between. Pixels within ``light`` are returned as written.

    Parameters
    ----------
    source, written : (N, 3) uint8 ndarrays
        A value before and after the change, at N pixels (B, G, R levels).

    Returns
    -------
    (N, 3) uint8 ndarray
    """
    s = source.astype(np.float32) + floor
    lg = np.log((written.astype(np.float32) + floor) / s)
    spread = lg.max(1) - lg.min(1)
    over = spread > light
    out = written.copy()
    if over.any():
        g = lg[over]
        mean = g.mean(1, keepdims=True)
        keep = np.clip((content - spread[over]) / (content - light), 0.0, 1.0)
        v = s[over] * np.exp(mean + (g - mean) * keep[:, None]) - floor + 0.5
        out[over] = np.clip(v, 0, 255).astype(np.uint8)
    return out


def light_only(src: npt.NDArray[np.uint8], med: npt.NDArray[np.float32],
               light: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """The ring's departures' light part (``ring_offset``), kept to what light does.

    ``src`` (R, 3) uint8 the source at R ring pixels, ``med`` (3,) the ring's median
    offset (the photos' exposure and white balance, taken as given), ``light``
    (R, 3) float32 the departure's light part there (levels). Judged by
    ``light_like`` against the source plus the median offset, where it changes
    the hue the hue change is dropped: the light part spreads 30 px into the fill
    (``LIGHT_DECAY_PX``), and a hue carried in from a ring that shows a source's
    own mover painted colours no photo shows (tim1-tim4 of ``bursts/tim6``: a
    brown table green). Returns (R, 3) float32; ``light`` where it was light-like.
    """
    base = np.clip(src.astype(np.float32) + med + 0.5, 0, 255).astype(np.uint8)
    written = np.clip(base.astype(np.float32) + light + 0.5, 0, 255).astype(np.uint8)
    kept = light_like(base, written)
    changed = (kept != written).any(1)
    out = np.array(light, np.float32, copy=True)
    out[changed] = kept[changed].astype(np.float32) - base[changed]
    return out


def add_offset(source: npt.NDArray[np.uint8], offset: npt.NDArray[np.float32]
               ) -> npt.NDArray[np.uint8]:
    """``source + offset`` rounded to uint8 (``(N, 3)`` arrays), as ``offset_blend`` writes."""
    v = source.astype(np.float32) + offset
    v += 0.5
    return np.clip(v, 0, 255, out=v).astype(np.uint8)


def ring_offset(ref_ring: npt.NDArray[np.uint8], src_ring: npt.NDArray[np.uint8],
                good: npt.NDArray[np.bool_], ring: tuple[np.ndarray, np.ndarray],
                sel: npt.NDArray[np.bool_], *, min_ring_px: int = 20,
                plateau_px: float = PLATEAU_PX, decay_px: float = DECAY_PX,
                light_sigma_px: float = LIGHT_SIGMA_PX, light_scale_px: float = LIGHT_SCALE_PX,
                light_decay_px: float = LIGHT_DECAY_PX) -> npt.NDArray[np.float32]:
    """The offset ``reference - source`` at the pixels of ``sel``, from the ring.

    Parameters
    ----------
    ref_ring, src_ring : (R, 3) ndarrays
        The reference and the source at the ``R`` ring pixels.
    good : (R,) bool ndarray
        Ring pixels where the source agrees with the reference (the others do
        not set the offset).
    ring : (ys, xs) of the ring pixels, row-major, in the image of ``sel``.
    sel : (H, W) bool ndarray
        Pixels that take the source.
    plateau_px, decay_px : float
        The ring's local departure from its median offset is kept in full
        within ``plateau_px`` of the good ring and fades as
        ``exp(-(d - plateau_px) / decay_px)`` beyond (pixels of ``sel``'s grid).
    light_sigma_px : float
        The ring pixels whose departure is not within ``DEPARTURE_MAX_DEV`` of
        their neighbours' (a Gaussian of this σ) set none
        (``consistent_departures``).
    light_scale_px, light_decay_px : float
        The departure's light part, its normalised Gaussian mean along the ring
        (σ ``light_scale_px``, ``gaussian_mean_at``), fades over
        ``light_decay_px`` instead of ``decay_px``.

    Returns
    -------
    offset : (M, 3) float32 ndarray
        At the ``M`` pixels of ``sel`` (row-major): the good ring's median
        ``reference - source`` (the photos' exposure and white-balance
        difference) plus the membrane (harmonic) interpolation of each ring
        pixel's departure from it (``fields.harmonic_fill``), faded with the
        distance to the ring (its light part slowly, the rest fast; the light
        part kept to what light does, ``light_only``); the median alone (0
        without any) when fewer than ``min_ring_px`` ring pixels are good.

    Notes
    -----
    The departures are mostly content, not light: a source a few pixels off
    along a textured edge. Carried by the membrane across the whole fill they
    tinted it (measured on the 12 composites: leftover 23.6 % of the true mask
    with the full membrane, 22.1 % with the fade, damage 0.58 → 0.59 %); kept
    near the ring they still hide the seam. A ring pixel whose departure is not
    its neighbours' (the reference still showing the mover's halo, a
    misaligned edge) drew a ghost of the mover's outline even so, and is left
    out (``consistent_departures``).
    """
    d = ref_ring[good].astype(np.float32) - src_ring[good].astype(np.float32)
    m = int(np.count_nonzero(sel))
    if len(d) < min_ring_px:  # too little ring: one global offset (or none)
        off = np.median(d, axis=0) if len(d) else np.zeros(d.shape[1:], np.float32)
        return np.broadcast_to(off.astype(np.float32), (m,) + d.shape[1:])
    med = np.median(d, axis=0)
    gy, gx = ring[0][good], ring[1][good]
    ok = consistent_departures(gy, gx, d - med, light_sigma_px)
    C = d.shape[1]
    dep = (d - med)[ok]
    light = gaussian_mean_at(gy[ok], gx[ok], dep, gy[ok], gx[ok], light_scale_px)
    light = light_only(src_ring[good][ok], med, light)
    field = np.zeros(sel.shape + (2 * C,), np.float32)
    field[gy[ok], gx[ok], :C] = light
    field[gy[ok], gx[ok], C:] = dep - light
    known = np.zeros(sel.shape, bool)
    known[gy[ok], gx[ok]] = True
    f = harmonic_fill(field, ~known, need=sel)[sel]
    fade_light, fade = ring_fade(known, sel, plateau_px, (light_decay_px, decay_px))
    return (med + f[:, :C] * fade_light[:, None] + f[:, C:] * fade[:, None]).astype(np.float32)


def consistent_departures(ys: npt.NDArray[np.intp], xs: npt.NDArray[np.intp],
                          departure: npt.NDArray[np.float32], sigma_px: float, *,
                          max_dev: float = DEPARTURE_MAX_DEV, passes: int = 2
                          ) -> npt.NDArray[np.bool_]:
    """Ring pixels whose departure from the median offset is light, not content.

    Light that changes across the photo changes the offset slowly along the
    ring; a pixel whose departure differs from its neighbours' is content: the
    mover's own halo or edge where the replaced region hugs it (the reference
    still shows the mover there), or a source a few pixels off along an edge.
    Carried into the fill by the membrane, such a pixel drew a lighter or
    darker ghost of the mover's outline (measured on the 12 composites:
    leftover 18.3 -> 17.1 % of the true mask). A pixel is kept when every
    channel of its departure is within ``max_dev`` of the normalised Gaussian
    mean (σ ``sigma_px``) of the kept ring pixels' around it; ``passes``
    rounds, the first over all of them (a robust local mean by iterated
    rejection, as in Huber, *Robust Statistics*, 1981).

    Parameters
    ----------
    ys, xs : (R,) int ndarrays
        The ring pixels (any origin: only their relative positions count, so
        a crop and the whole image give the same answer).
    departure : (R, C) float32 ndarray
        Reference minus source, minus the ring's median (levels of 0-255).
    sigma_px : float
        σ of the neighbourhood, in pixels. From 8 px up (the full-size output
        of large photos) the sums are taken per cell of ⌊σ / 4⌋² pixels and
        blurred with σ / ⌊σ / 4⌋, at the cost of the working size's.

    Returns
    -------
    keep : (R,) bool ndarray
    """
    keep = np.ones(len(ys), bool)
    if len(ys) == 0:
        return keep
    dep = departure.astype(np.float32)
    for _ in range(passes):
        # (no kept pixel near: the mean is 0, a departure within max_dev of none)
        loc = (gaussian_mean_at(ys[keep], xs[keep], dep[keep], ys, xs, sigma_px, min_weight=0)
               if keep.any() else np.zeros_like(dep))
        keep = np.abs(dep - loc).max(axis=1) < max_dev
    return keep


def ring_fade(known: npt.NDArray[np.bool_], sel: npt.NDArray[np.bool_], plateau_px: float,
              decay_px: float | tuple[float, ...]):
    """``exp(-max(d - plateau_px, 0) / decay_px)`` at the pixels of ``sel`` (row-major),
    d the Euclidean distance (px) to the nearest pixel of ``known`` (both (H, W) bool):
    (M,) float32, or a tuple of them for a tuple of ``decay_px``."""
    dist = cv2.distanceTransform((~known).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[sel]
    beyond = np.maximum(dist - plateau_px, 0.0)
    if isinstance(decay_px, tuple):
        return tuple(np.exp(-beyond / d).astype(np.float32) for d in decay_px)
    return np.exp(-beyond / decay_px).astype(np.float32)


# the seam blend's reach (px): farther from every seam, the blend's value is kept
SEAM_BAND_PX = 64
# ... and the σ (px) along a seam over which its steps are averaged: light is steady
# along a seam, two sources' misalignment is not
SEAM_ALONG_PX = 4.0


def seam_steps(out: npt.NDArray[np.uint8], raw: npt.NDArray[np.uint8],
               labels: npt.NDArray[np.intp], region: npt.NDArray[np.bool_], *,
               max_step: float, band_px: int = SEAM_BAND_PX,
               along_px: float = SEAM_ALONG_PX) -> npt.NDArray[np.float32]:
    """The correction that removes the steps of light the fill leaves at its seams.

    Two sources that meet at a seam inside the replaced region were each brought
    to the reference's level on the ring around the region (``offset_blend``);
    where one of them barely reaches the ring, or the light changes across the
    region, they still differ by some levels and the seam shows as an edge (on
    ``bursts/tim6``, patches of table 10-30 levels apart where the tube was).
    Poisson image editing (Pérez, Gangnet & Blake, *Poisson image editing*,
    SIGGRAPH 2003), as Photomontage blends its seams (Agarwala et al. 2004), on
    the pixels of ``region`` within ``band_px`` of a seam: the guidance is the
    blended fill's own gradient, except across a seam, where it is the mean of
    the two sources' own gradients there (``raw``). The region's edge and the
    band's are held, so the correction fades to 0 there and nothing outside the
    region changes. A step larger than ``max_step`` levels (any channel) is
    kept: the two sources show different content there (the sky beside a roof),
    which no light explains, and smoothing it would spread a haze. What each
    seam edge asks is averaged over the edges between the same two labels within
    ``along_px`` (a normalised Gaussian of that σ along the seam): light is
    steady along a seam, and the part of the step that is not, two sources'
    texture a pixel or two apart, stays. Solved by conjugate gradients
    (``scipy.sparse.linalg.cg``).

    Parameters
    ----------
    out : (H, W, 3) uint8 ndarray
        The blended fill.
    raw : (L, H, W, 3) uint8 ndarray
        Each label's source as sampled, before any combination or offset.
    labels : (H, W) int ndarray
        The label of each pixel (a seam: two 4-neighbours of ``region`` with
        different labels).
    region : (H, W) bool ndarray
        The pixels that may change: those a source filled.
    max_step : float
        B/G/R levels.
    band_px : int
    along_px : float
        σ along the seam, px (0: each edge as it is).

    Returns
    -------
    (H, W, 3) float32 ndarray
        To add to ``out`` (``add_offset``); 0 outside the band and the region.
    """
    import scipy.sparse as sp  # (scikit-learn's own dependency)
    import scipy.sparse.linalg as spl

    H, W = region.shape
    corr = np.zeros((H, W, 3), np.float32)
    edges = []  # (ys, xs, yq, xq, d): d what the difference across edge p -> q must change by
    for dy, dx in ((0, 1), (1, 0)):
        p = (slice(0, H - dy), slice(0, W - dx))
        q = (slice(dy, H), slice(dx, W))
        ys, xs = np.nonzero(region[p] & region[q] & (labels[p] != labels[q]))
        yq, xq = ys + dy, xs + dx
        step = out[ys, xs].astype(np.float64) - out[yq, xq]
        light = np.abs(step).max(1) <= max_step
        ys, xs, yq, xq, step = ys[light], xs[light], yq[light], xq[light], step[light]
        lp, lq = labels[ys, xs], labels[yq, xq]
        guide = 0.5 * ((raw[lp, ys, xs].astype(np.float64) - raw[lp, yq, xq])
                       + (raw[lq, ys, xs].astype(np.float64) - raw[lq, yq, xq]))
        edges.append((ys, xs, yq, xq, guide - step))
    ys, xs, yq, xq, d = (np.concatenate([e[i] for e in edges]) for i in range(5))
    if not len(ys):
        return corr
    if along_px > 0:
        # light changes slowly along a seam, a misalignment's steps do not: each edge
        # takes the mean of d over the edges between the same two labels within
        # ~along_px (normalised Gaussian), so that only the steady part is removed
        lo = np.minimum(labels[ys, xs], labels[yq, xq])
        hi = np.maximum(labels[ys, xs], labels[yq, xq])
        sign = np.where(labels[ys, xs] == lo, 1.0, -1.0)[:, None]
        pair = lo * (int(labels.max()) + 1) + hi
        smooth = np.empty_like(d)
        for k in np.unique(pair):
            at = np.flatnonzero(pair == k)
            smooth[at] = gaussian_mean_at(ys[at], xs[at], (d[at] * sign[at]).astype(np.float32),
                                          ys[at], xs[at], along_px) * sign[at]
        d = smooth
    b = np.zeros((H, W, 3), np.float64)
    np.add.at(b, (ys, xs), d)
    np.add.at(b, (yq, xq), -d)
    at_seam = np.zeros((H, W), bool)
    at_seam[ys, xs] = at_seam[yq, xq] = True
    far = cv2.distanceTransform((~at_seam).view(np.uint8), cv2.DIST_L2, 3)
    ys, xs = np.nonzero(region & (far <= band_px))
    n = len(ys)
    index = np.full((H, W), -1, np.int64)
    index[ys, xs] = np.arange(n)
    # the 5-point Laplacian on the band; a neighbour outside it is held (0)
    diag = np.zeros(n)
    rows, cols = [np.arange(n)], [np.arange(n)]
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
        yy, xx = ys + dy, xs + dx
        inside = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
        diag += inside
        j = np.full(n, -1, np.int64)
        j[inside] = index[yy[inside], xx[inside]]
        rows.append(np.flatnonzero(j >= 0))
        cols.append(j[j >= 0])
    vals = np.concatenate([diag, -np.ones(sum(len(r) for r in rows[1:]))])
    A = sp.csr_matrix((vals, (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    for c in range(3):
        x, _ = spl.cg(A, b[ys, xs, c], rtol=1e-4, atol=1e-3, maxiter=8 * band_px)
        corr[ys, xs, c] = x
    return corr


__all__ = ["SEAM_BAND_PX", "add_offset", "band_around", "band_light", "component_offsets",
           "consistent_departures", "expansion_labels", "gaussian_mean_at", "offset_blend",
           "pairwise_distance", "ring_agrees", "ring_fade", "ring_offset", "seam_steps"]

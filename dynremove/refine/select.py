"""Fill by selection: keep the reference where it is right, copy one free source elsewhere.

The default preset's last step (not in the paper). It replaces the per-channel
median of all sources (``fill.fuse_background``), which averages every
source's *own* mover into the fill as a ghost and refills static 3-D structure
that the scan flagged with doubled content.

1. **Evidence that the reference is static** (geometry). Each source is
   matched to the reference by homography + DIS flow, without the scan's gate.
   A flow match *explains* a reference pixel when it agrees in colour (CIE76
   ΔE < ``tau``), lies within ``select_epipolar_px`` of its epipolar line, and
   departs from the homography by no more than the parallax the static scene
   shows between the two views (``TwoView.parallax_px``, measured on the F
   inliers; a rotation or a planar scene allows ~1 px, a wide baseline tens).
   Pixels of L explained by at least half of the sources are static 3-D
   structure that the scan's homography-gated matches could not follow.
   Where the set has parallax, a pixel whose flow match failed (thin
   structure against the sky, far off the plane) may instead be found by a
   search along its epipolar line (``parallax.epipolar_search``); that weaker
   evidence counts where at least two sources, and half of them, explain it.
2. **Background candidates.** Every source is sampled through its field,
   re-interpolated across the rest of L (``fields.background_field``); where
   the set has parallax, found instead by a plane + parallax sweep for the
   depth at which the sources agree (``parallax.sweep_fields``); then
   re-aligned by flow from the filled reference (``fill.realign_fields``).
3. **Consensus with independent, weighted witnesses.** A colour model of the
   movers (histogram of L against a ring around it, as GrabCut's) gives each
   candidate a mover probability; a witness counts ``1 - p``, so a source
   showing its own mover (or a near-copy of the reference) carries no weight.
   The consensus at a pixel is the candidate with the most weighted support.
4. **Graph cut** (``montage.expansion_labels``, photomontage). Labels: the
   reference and every source. The data cost is the distance to the
   consensus, plus a preference for the reference outside L and a cost for
   keeping it inside L (unless explained); the seam cost puts seams where
   the sources agree. Where the sets' parallax is large (median
   ``parallax_px`` > ``select_parallax_px``), the consensus may also keep the
   reference inside L: the scan's flags there are mostly 3-D structure.
5. **Blend** (``montage.offset_blend``): exposure and white-balance
   differences leave no edge. Pixels of L that no source shows free are
   inpainted (OpenCV Telea) and reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import apply_homography, dense_correspondence, pixel_grid
from dynremove.method.geometry import TwoView, sampson_sq
from dynremove.params import Params
from dynremove.refine.fields import background_field, blurred_lab, sample_bilinear
from dynremove.refine.fill import median_fill, realign_fields
from dynremove.refine.parallax import epipolar_search, fit_parallax, sweep_fields
from dynremove.refine.montage import expansion_labels, offset_blend, pairwise_distance
from dynremove.refine.morphology import dilate_disc

_FORBIDDEN = 1e6  # data cost of a label that may not be used
_DE_CAP = 40.0  # colour distances are capped here in the data cost


@dataclass
class Selection:
    """What the fill by selection decided (all (H, W) unless said)."""

    clean: npt.NDArray[np.uint8]  # (H, W, 3) the clean reference
    replaced: npt.NDArray[np.bool_]  # the final dynamic map: pixels of L taken from a source,
    # and pixels near L whose source differs from the reference (ΔE >= tau)
    label: npt.NDArray[np.int16]  # -1 not considered, 0 reference kept, k+1 source k
    explained: npt.NDArray[np.bool_]  # pixels of L kept as static 3-D structure
    movers: npt.NDArray[np.bool_]  # (S, H, W) where source k's candidate shows a mover
    no_source: npt.NDArray[np.bool_]  # replaced pixels no source showed free (inpainted)
    seams: npt.NDArray[np.bool_]  # boundaries between labels inside the region
    parallax_px: float  # median measured parallax of the set (px)
    consensus_mode: str  # "scan" (trust L) or "parallax" (colour consensus inside L)
    # for the full-resolution output (refine.upsample): each source's field, and per
    # replaced pixel which sources' samples were combined (S, H, W)
    fields: list = field(default_factory=list)
    members: npt.NDArray[np.bool_] | None = None
    # (S, H, W) uint8, why each source did or did not fill each pixel of the region:
    # REASONS[code]; 0 outside the region
    reasons: npt.NDArray[np.uint8] | None = None


REASONS = {0: "not considered", 1: "chosen", 2: "combined (agrees with the chosen one)",
           3: "its own mover", 4: "outside its frame or no content",
           5: "disagrees with the consensus", 6: "agrees, not chosen"}


def _mover_probability(lab_ref: np.ndarray, L: np.ndarray, values: np.ndarray,
                       bins: int = 12) -> np.ndarray:
    """P(mover | colour): histograms of L's core against a ring around L (Lab)."""
    core = cv2.erode(L.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    ring = dilate_disc(L, 30) & ~dilate_disc(L, 4)
    if not core.any() or not ring.any():
        return np.zeros(values.shape[:-1], np.float32)

    def q(x):
        lum = np.clip(x[..., 0] / 100 * bins, 0, bins - 1).astype(np.intp)
        a = np.clip((x[..., 1] + 64) / 128 * bins, 0, bins - 1).astype(np.intp)
        b = np.clip((x[..., 2] + 64) / 128 * bins, 0, bins - 1).astype(np.intp)
        return (lum * bins + a) * bins + b

    def hist(m):
        h = np.bincount(q(lab_ref[m]), minlength=bins ** 3).astype(np.float64)
        h = cv2.GaussianBlur(h.reshape(bins, bins * bins), (3, 3), 0.7).ravel()
        return h / max(h.sum(), 1e-9)

    hf, hb = hist(core), hist(ring)
    post = (hf + 1e-4) / (hf + hb + 2e-4)
    return post[q(values)].astype(np.float32)


def _valid_at(valid: np.ndarray, field: np.ndarray) -> np.ndarray:
    """``valid`` (H, W) bool looked up at the nearest pixel of ``field`` (H, W, 2)."""
    m = cv2.remap(valid.astype(np.uint8), np.ascontiguousarray(field[..., 0]),
                  np.ascontiguousarray(field[..., 1]), cv2.INTER_NEAREST,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return m.astype(bool)


def _consensus_growth(lab_r, sources, base, mask, valid, P):
    """Pixels near L that the reference alone shows differently (a cast shadow, a
    part of the mover the scan missed): at least ``max(2, S/2)`` sources, sampled
    through their geometry-bounded matches, agree with one another and the
    reference disagrees with all of them (ΔE >= ``select_tau``). Only components
    touching L are kept, so the consensus never acts far from a detected mover."""
    S = len(sources)
    near = dilate_disc(mask, P.select_grow_px) & ~mask
    if S < 2 or not near.any():
        return np.zeros(mask.shape, bool)
    ring = dilate_disc(mask, 2 * P.select_grow_px) & ~mask
    # only the box of the ring (which holds ``near``) is sampled, 8 px wider so
    # that the 1 px blur there equals the whole image's
    ry, rx = np.nonzero(ring | near)
    y0, y1 = max(ry.min() - 8, 0), min(ry.max() + 9, mask.shape[0])
    x0, x1 = max(rx.min() - 8, 0), min(rx.max() + 9, mask.shape[1])
    box = (slice(y0, y1), slice(x0, x1))
    ys, xs = np.nonzero(near[box])
    ring_b = ring[box]
    lab_rb = lab_r[box]
    labs, ok = [], []
    for k in range(S):
        f = np.ascontiguousarray(base[k][box])
        warped, ins = sample_bilinear(sources[k], f)
        if valid is not None:
            ins &= _valid_at(valid[k], f)
        lab_k = blurred_lab(warped, 1.0)
        # exposure and white balance: the source's median Lab offset to the
        # reference around L, so a darker reference is not a "difference"
        around = ring_b & ins
        if around.sum() > 50:
            lab_k = lab_k + np.median(lab_rb[around] - lab_k[around], axis=0)
        labs.append(lab_k[ys, xs])
        ok.append(ins[ys, xs])
    labs, ok = np.stack(labs), np.stack(ok)  # (S, n, 3), (S, n)
    tau = P.select_tau
    d = np.linalg.norm(labs[:, None] - labs[None], axis=-1)  # (S, S, n)
    agree = (d < tau) & ok[:, None] & ok[None]
    count = agree.sum(1)  # sources agreeing with source k (itself included)
    best = np.argmax(count, 0)
    n_best = count[best, np.arange(len(ys))]
    cons = labs[best, np.arange(len(ys))]
    d_ref = np.linalg.norm(lab_rb[ys, xs] - cons, axis=-1)
    need = max(2, int(np.ceil(0.5 * S - 1e-6)))
    hit = np.zeros(mask.shape, np.uint8)
    hit[ys + y0, xs + x0] = (n_best >= need) & (d_ref >= tau)
    hit = cv2.morphologyEx(hit, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab = cv2.connectedComponents((hit | mask).astype(np.uint8), connectivity=8)
    # a component grows by at most its own detected area (a shadow is no larger
    # than its mover; a small false alarm must not seed a large region)
    a_mask = np.bincount(lab[mask], minlength=n)
    a_hit = np.bincount(lab[(hit > 0) & ~mask], minlength=n)
    ok = (a_mask > 0) & (a_hit <= a_mask)
    ok[0] = False
    return ok[lab] & (hit > 0)


def member_median(values: npt.NDArray[np.uint8], member: npt.NDArray[np.bool_]
                  ) -> npt.NDArray[np.uint8]:
    """Per-channel median of ``values`` (S, n, 3) uint8 over the sources ``member``
    (S, n) marks (at least one per column), as uint8 (n, 3): of an even count,
    the middle pair's mean rounded half up. Computed in integers (sorting, no
    NaN median)."""
    v = np.where(member[..., None], values, np.uint16(512)).astype(np.uint16)
    v.sort(axis=0)
    m = member.sum(0)
    i = np.arange(values.shape[1])
    lo, hi = v[(m - 1) // 2, i], v[m // 2, i]
    return ((lo + hi + 1) // 2).astype(np.uint8)


def _cluster_median(cand_img, labs, lab, rep, free, tau):
    """Each replaced pixel's chosen source, replaced by the per-channel median of the
    free sources that agree with it (ΔE < ``tau``): the chosen region keeps one
    source's content while its noise and sub-pixel misalignment average out."""
    out = cand_img.copy()
    ys, xs = np.nonzero(rep)
    chosen = lab[ys, xs]
    lab_c = labs[chosen, ys, xs]  # (n, 3)
    tau = np.broadcast_to(tau, rep.shape)[ys, xs]
    member = free[:, ys, xs] & (np.linalg.norm(labs[1:, ys, xs] - lab_c[None], axis=-1) < tau)
    member[chosen - 1, np.arange(len(ys))] = True
    out[chosen, ys, xs] = member_median(cand_img[1:, ys, xs], member)
    members = np.zeros((len(cand_img) - 1,) + rep.shape, bool)
    members[:, ys, xs] = member
    return out, members


def select_fill(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                views: list[TwoView], mask: npt.NDArray[np.bool_], params: Params, *,
                valid: npt.NDArray[np.bool_] | None = None,
                flows: npt.NDArray[np.float32] | None = None) -> Selection:
    """Fill ``mask`` by selecting, per region, one source that is free there.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
    sources : (S, H, W, 3) uint8 ndarray
    views : list of TwoView
        The reference → source geometry (H, F, measured parallax) per source.
    mask : (H, W) bool ndarray
        The dynamic map L after the refinement steps.
    params : Params
        ``select_*`` fields (see ``Params``).
    valid : (S, H, W) bool ndarray, optional
        Where each *source* has content (False: a transparent or empty border of
        a pre-aligned frame). Sampling a source where it is not valid counts as
        outside its frame: never evidence, never fill.
    flows : (S, H, W, 2) float32 ndarray, optional
        Each source's homography + flow matches (``dense_correspondence(...,
        method="homography+flow")`` of the gray images), if the caller has them
        (the pipeline keeps them from its correspondence stage); computed here
        otherwise.

    Returns
    -------
    Selection
        ``clean`` equals ``reference`` outside ``mask`` dilated by
        ``select_margin_px``.
    """
    H, W = mask.shape
    S = len(sources)
    P = params
    par = float(np.median([v.parallax_px if np.isfinite(v.parallax_px) else 0.0
                           for v in views])) if views else 0.0
    mode = "parallax" if par > P.select_parallax_px else "scan"
    empty = Selection(clean=reference.copy(), replaced=np.zeros((H, W), bool),
                      label=np.full((H, W), -1, np.int16), explained=np.zeros((H, W), bool),
                      movers=np.zeros((S, H, W), bool), no_source=np.zeros((H, W), bool),
                      seams=np.zeros((H, W), bool), parallax_px=par, consensus_mode=mode)
    region = dilate_disc(mask, P.select_margin_px)
    if not mask.any() or S == 0:
        return empty
    mask = mask.copy()
    tau = P.select_tau
    lab_r = blurred_lab(reference, 1.0)
    g_r = cv2.cvtColor(reference, cv2.COLOR_BGR2GRAY)
    src_gray = [cv2.cvtColor(s, cv2.COLOR_BGR2GRAY) for s in sources]
    gx, gy = pixel_grid(H, W)
    grid = np.stack([gx, gy], -1)

    # 1. flow matches and the pixels of L they explain
    votes = np.zeros((S, H, W), np.float32)
    matched = np.zeros((S, H, W), bool)  # explained by the flow match
    searched = np.zeros((S, H, W), bool)  # in L, found by the epipolar search instead
    base = []
    for k in range(S):
        v = views[k]
        nf = (flows[k] if flows is not None else
              dense_correspondence(g_r, src_gray[k], v.H, method="homography+flow",
                                   flow_preset=P.flow_preset))
        hx, hy = apply_homography(v.H, gx, gy)
        bound = (v.parallax_px if np.isfinite(v.parallax_px) else 0.0) + 2.0
        off_h = np.hypot(nf[..., 0] - hx, nf[..., 1] - hy)
        within = off_h <= bound
        # the fill's field keeps flow as far as the scan's gate allows
        keep = off_h <= max(bound, P.flow_gate * max(H, W))
        base.append(np.where(keep[..., None], nf, np.stack([hx, hy], -1)).astype(np.float32))
        warped, inside = sample_bilinear(sources[k], nf)
        if valid is not None:
            inside &= _valid_at(valid[k], nf)
        lab_w = blurred_lab(warped, 1.0)
        ok = inside & within & (np.linalg.norm(lab_w - lab_r, axis=-1) < tau)
        if v.F is not None and P.select_epipolar_px > 0:
            ok &= sampson_sq(v.F, grid, nf) <= P.select_epipolar_px ** 2
        votes[k] = ok * (1.0 - _mover_probability(lab_r, mask, lab_w))
        if mode == "parallax" and P.select_search_de > 0:
            # static 3-D structure whose flow match failed (thin, or far off the
            # plane): its best match along the epipolar line in this source
            cost, _ = epipolar_search(lab_r, blurred_lab(sources[k], 1.0), v, nf,
                                      ~dilate_disc(mask, 4), mask & ~ok)
            matched[k], searched[k] = ok, cost < P.select_search_de
    grown = np.zeros((H, W), bool)
    if P.select_grow_px > 0:
        grown = _consensus_growth(lab_r, sources, base, mask, valid, P)
        mask = mask | grown
        region = dilate_disc(mask, P.select_margin_px)
    p_ref = _mover_probability(lab_r, mask, lab_r)
    need = max(1, int(np.ceil(0.5 * S - 1e-6)))
    if searched.any():
        # the epipolar search is weaker evidence (any colour on the line may
        # match): it counts where at least two sources, and half of them, agree
        found = searched & ((matched | searched).sum(0) >= max(2, need))[None]
        votes = np.maximum(votes, found.astype(np.float32))
    explained = mask & ((votes > 0.5).sum(0) >= need) & (p_ref < 0.5)
    core = mask & ~explained

    # 2. background candidates through the fields, re-aligned
    hole = cv2.dilate(dilate_disc(core, 2).astype(np.uint8), np.ones((7, 7), np.uint8)
                      ).astype(bool)
    fields = [background_field(base[k], hole) for k in range(S)]
    if P.select_sweep and mode == "parallax" and core.any():
        # hidden 3-D structure: the depth at which the sources agree, not a membrane
        model = fit_parallax(base, views, ~dilate_disc(mask, 4), seed=P.seed)
        if model is not None:
            fields, _ = sweep_fields([blurred_lab(s, 0.0) for s in sources], views, model,
                                     hole, fields)
    if P.fuse_realign > 0 and core.any():
        for _ in range(P.fuse_realign):
            first, _ = median_fill(reference, sources, fields, dilate_disc(core, 2))
            fields = realign_fields(first, src_gray, fields, hole, [v.H for v in views],
                                    P.flow_preset, P.fuse_realign_max_px)

    ys, xs = np.nonzero(region)
    y0, y1 = max(ys.min() - 2, 0), min(ys.max() + 3, H)
    x0, x1 = max(xs.min() - 2, 0), min(xs.max() + 3, W)
    roi = (slice(y0, y1), slice(x0, x1))
    reg, in_core, in_mask = region[roi], core[roi], mask[roi]
    cand = [reference[roi]]
    inside = [np.ones(reg.shape, bool)]
    for k in range(S):
        warped, ins = sample_bilinear(sources[k], fields[k])
        if valid is not None:
            ins &= _valid_at(valid[k], fields[k])
        cand.append(warped[roi])
        inside.append(ins[roi])
    cand_img = np.stack(cand)
    usable = np.stack(inside)
    labs = np.stack([blurred_lab(c, 1.0) for c in cand_img])

    # 3. weighted consensus
    p_mover = _mover_probability(lab_r, mask, labs)
    weight = (1.0 - p_mover) * usable
    weight[0] = 1.0  # outside L the reference is a trusted witness
    weight[0][in_mask] = 1.0 - p_mover[0][in_mask]
    dist = pairwise_distance(labs)  # (S+1, S+1, h, w)
    agree = (dist < tau) & usable[:, None] & usable[None]
    support = (agree * weight[None]).sum(1)
    v_roi = votes[:, y0:y1, x0:x1]
    support[0] = weight[0] + np.maximum(agree[0, 1:] * weight[1:], v_roi).sum(0)

    def consensus(sup, first):
        best = first + np.argmax(sup + 1e-3 * (np.arange(len(sup)) == 0)[:, None, None], 0)
        c = np.take_along_axis(labs, best[None, ..., None].repeat(3, -1), 0)[0]
        return np.minimum(np.linalg.norm(labs - c[None], axis=-1), _DE_CAP), c

    D, cons = consensus(support, 0)
    if mode == "scan":
        # inside L the reference is the suspect: the sources' own consensus decides
        Ds, cons_s = consensus(support[1:], 1)
        D = np.where(in_core[None], Ds, D)
        ref_cost = P.select_ref_cost
        if S == 1:  # two photos: which one shows the mover is not known; the colour
            # model must say the reference does and the source does not
            ref_cost = np.where((p_mover[0] > 0.5) & (p_mover[1] < 0.5), ref_cost, 0.0)
        D[0] = np.where(in_core, ref_cost, D[0])
        cons = np.where(in_core[..., None], cons_s, cons)
    D[1:] += P.select_kappa + P.select_gamma * p_mover[1:]
    D[~usable] = _FORBIDDEN
    D[1:, ~reg] = _FORBIDDEN
    D[0, ~reg] = 0.0

    # 4. graph cut, 5. blend
    lab = expansion_labels(D.astype(np.float64), labs, beta=P.select_beta, cycles=2,
                           distance=dist, forbidden=_FORBIDDEN)
    rep = lab != 0
    movers = np.zeros((S, H, W), bool)
    mv = usable[1:] & (p_mover[1:] > 0.5) & (np.linalg.norm(labs[1:] - cons[None], axis=-1) > tau)
    movers[:, y0:y1, x0:x1] = mv & reg[None]
    free = usable[1:] & ~mv
    no_src = rep & in_core & ~free.any(0)
    clean = reference.copy()
    members = np.zeros((S, H, W), bool)
    if rep.any():
        if P.select_cluster_median:
            # where the scan is trusted, every free source is a witness of the
            # hidden background, not only those agreeing with the chosen one
            cand_img, mem = _cluster_median(
                cand_img, labs, lab, rep, free,
                np.where(in_core, np.inf, tau) if mode == "scan" else tau)
            members[:, y0:y1, x0:x1] = mem
        else:
            ly, lx = np.nonzero(rep)
            members[lab[ly, lx] - 1, ly + y0, lx + x0] = True
        clean[roi] = offset_blend(reference[roi], cand_img, lab, rep, usable, labs)
    if no_src.any():
        sub = np.ascontiguousarray(clean[roi])
        clean[roi] = cv2.inpaint(sub, no_src.astype(np.uint8), 5, cv2.INPAINT_TELEA)
    why = np.where(np.linalg.norm(labs[1:] - cons[None], axis=-1) < tau, 6, 5).astype(np.uint8)
    why[members[:, y0:y1, x0:x1]] = 2
    why[mv] = 3
    why[~usable[1:]] = 4
    why[lab[None] == np.arange(1, S + 1)[:, None, None]] = 1
    reasons = np.zeros((S, H, W), np.uint8)
    reasons[:, y0:y1, x0:x1] = np.where(reg[None], why, 0)
    label = np.full((H, W), -1, np.int16)
    label[roi] = np.where(reg, lab, -1)
    seams = np.zeros((H, W), bool)
    seams[roi] = reg & ((np.diff(lab, axis=0, prepend=lab[:1]) != 0)
                        | (np.diff(lab, axis=1, prepend=lab[:, :1]) != 0))
    # the dynamic map: replaced pixels of L, and those outside it where the
    # reference differed from what replaced it (not mere seam placement)
    d_chosen = np.take_along_axis(np.linalg.norm(labs - labs[0][None], axis=-1), lab[None], 0)[0]
    replaced = np.zeros((H, W), bool)
    replaced[roi] = rep & (in_mask | (d_chosen >= tau))
    nos = np.zeros((H, W), bool)
    nos[roi] = no_src
    return Selection(clean=clean, replaced=replaced, label=label, explained=explained,
                     movers=movers, no_source=nos, seams=seams, parallax_px=par,
                     consensus_mode=mode, fields=fields, members=members, reasons=reasons)


__all__ = ["REASONS", "Selection", "member_median", "select_fill"]

"""Readable references the fast code is tested against (stumpy's ``tests/naive.py``).

Each computes on every pixel of the box, densely, as the code did before it
was made sparse; the fast version must give the same bytes.
"""

from __future__ import annotations

import math

import cv2
import maxflow
import numpy as np
import numpy.typing as npt

from dynremove.refine.fields import blurred_lab
from dynremove.refine.montage import (BAND_AGREE, BAND_PX, BAND_SIGMA_PX, DECAY_PX,
                                      LIGHT_DECAY_PX, LIGHT_SCALE_PX, LIGHT_SIGMA_PX, PLATEAU_PX,
                                      band_light, component_offsets, consistent_departures,
                                      gaussian_mean_at, light_only, pairwise_distance)
from dynremove.refine.morphology import dilate_disc
from dynremove.refine.select import mixture_detail
from dynremove.refine.upsample import grow_replaced


# the membrane fill as it was written before it was made sparse (dense, every pixel)
def interpolate_field(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                      ) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole``: normalised Gaussian convolution (dense).

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


def member_median(values, member):
    """The per-channel median as first written: NaN median of the members, + 0.5."""
    vals = np.where(member[..., None], values.astype(np.float32), np.nan)
    return np.clip(np.nanmedian(vals, axis=0) + 0.5, 0, 255).astype(np.uint8)


def _distance(known):
    """Euclidean distance (px) from every pixel to the nearest True of ``known``, by brute force."""
    ky, kx = np.nonzero(known)
    gy, gx = np.mgrid[0:known.shape[0], 0:known.shape[1]]
    d2 = (gy[..., None] - ky) ** 2 + (gx[..., None] - kx) ** 2
    return np.sqrt(d2.min(-1))


def offset_blend(reference, candidates, labels, replaced, usable, labs, *,
                 ring_px=3, max_de=15.0, plateau_px=PLATEAU_PX, decay_px=DECAY_PX,
                 light_sigma_px=LIGHT_SIGMA_PX, light_scale_px=LIGHT_SCALE_PX,
                 light_decay_px=LIGHT_DECAY_PX, band_px=BAND_PX, band_sigma_px=BAND_SIGMA_PX,
                 suspect=None):
    """``montage.offset_blend`` on whole images."""
    out = reference.astype(np.float32)
    ring = dilate_disc(replaced, ring_px) & ~replaced
    band = dilate_disc(replaced, band_px[1]) & ~dilate_disc(replaced, band_px[0])
    if suspect is not None:
        band &= ~suspect
    by, bx = np.nonzero(band)
    ry, rx = np.nonzero(ring)
    for lbl in np.unique(labels[replaced]):
        if lbl == 0:
            continue
        src = candidates[lbl].astype(np.float32)
        d = reference.astype(np.float32) - src
        diff = labs[0] - labs[lbl]
        on = ring & usable[lbl]
        med = np.median(diff[on], axis=0) if on.any() else np.zeros(3, np.float32)
        # the light measured in the band beyond the ring, at the ring's pixels
        local = np.full(diff.shape, np.nan, np.float32)
        local[ry, rx] = band_light(diff[by, bx], usable[lbl][by, bx], (by, bx), (ry, rx),
                                   band_sigma_px, max_de)
        with np.errstate(invalid="ignore"):
            good = on & ((np.linalg.norm(diff - med, axis=-1) < max_de)
                         | (np.linalg.norm(diff - local, axis=-1) < BAND_AGREE * max_de))
        sel = replaced & (labels == lbl)
        if good.sum() < 20:
            off = np.zeros_like(d)
            if good.any():
                off[:] = np.median(d[good], axis=0)
        else:
            m = np.median(d[good], axis=0)
            gy, gx = np.nonzero(good)
            ok = consistent_departures(gy, gx, (d - m)[gy, gx], light_sigma_px)
            gy, gx = gy[ok], gx[ok]
            good = np.zeros_like(good)
            good[gy, gx] = True
            # the departure's light part (its mean along the ring) and the rest
            dep = (d - m)[gy, gx]
            light = gaussian_mean_at(gy, gx, dep, gy, gx, light_scale_px)
            light = light_only(src[gy, gx], m, light)
            field = np.zeros(d.shape[:2] + (6,), np.float32)
            field[gy, gx, :3] = light
            field[gy, gx, 3:] = dep - light
            f = harmonic_fill(field, ~good)
            beyond = np.maximum(_distance(good).astype(np.float32) - plateau_px, 0.0)
            fade_light = np.exp(-beyond / light_decay_px).astype(np.float32)
            fade = np.exp(-beyond / decay_px).astype(np.float32)
            off = m + f[..., :3] * fade_light[..., None] + f[..., 3:] * fade[..., None]
        out[sel] = src[sel] + off[sel]
        # the small regions' own offsets: the same function as the fast code's
        # (its ring pixels handed over densely, row-major)
        for cy, cx, coff in component_offsets(
                reference[ry, rx], candidates[lbl][ry, rx], diff[ry, rx], usable[lbl][ry, rx],
                ring, sel, replaced, ring_px=ring_px, max_de=max_de,
                plateau_px=plateau_px, decay_px=decay_px, light_sigma_px=light_sigma_px,
                light_scale_px=light_scale_px, light_decay_px=light_decay_px):
            out[cy, cx] = src[cy, cx] + coff
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def full_resolution(reference, sources, clean_working, dynamic, selection, tau=10.0):
    """``upsample.full_resolution`` on the whole bounding box of the replaced region."""
    Hf, Wf = reference.shape[:2]
    h, w = dynamic.shape
    size = (Wf, Hf)
    dyn_full = cv2.resize(dynamic.astype(np.float32), size,
                          interpolation=cv2.INTER_LINEAR) >= 0.5
    clean = reference.copy()
    if selection is None or not (selection.label >= 1).any() or not selection.fields:
        if dyn_full.any():
            up = cv2.resize(clean_working, size, interpolation=cv2.INTER_CUBIC)
            clean[dyn_full] = up[dyn_full]
        return clean, dyn_full
    sx, sy = Wf / w, Hf / h
    label = grow_replaced(cv2.resize(selection.label.astype(np.int16), size,
                                     interpolation=cv2.INTER_NEAREST),
                          math.ceil(max(Wf / w, Hf / h))).astype(np.intp)
    rep = label >= 1
    ring_px = max(3, int(round(3 * max(sx, sy))))
    band_px = (int(round(BAND_PX[0] * max(sx, sy))), int(round(BAND_PX[1] * max(sx, sy))))
    ys, xs = np.nonzero(dilate_disc(rep, max(ring_px, band_px[1]) + 1))
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    roi = (slice(y0, y1), slice(x0, x1))
    gx, gy = np.meshgrid(np.arange(x0, x1, dtype=np.float32),
                         np.arange(y0, y1, dtype=np.float32))
    wx, wy = (gx + 0.5) / sx - 0.5, (gy + 0.5) / sy - 0.5
    S = len(sources)
    cand = np.empty((S + 1, y1 - y0, x1 - x0, 3), np.uint8)
    cand[0] = reference[roi]
    usable = np.ones((S + 1, y1 - y0, x1 - x0), bool)
    members = np.zeros((S, y1 - y0, x1 - x0), bool)
    for k in range(S):
        f = selection.fields[k]
        fx = cv2.remap(np.ascontiguousarray(f[..., 0]), wx, wy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        fy = cv2.remap(np.ascontiguousarray(f[..., 1]), wx, wy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        mx, my = (fx + 0.5) * sx - 0.5, (fy + 0.5) * sy - 0.5
        Hs, Ws = sources[k].shape[:2]
        cand[k + 1] = cv2.remap(sources[k], mx, my, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
        usable[k + 1] = (mx >= 0) & (mx <= Ws - 1) & (my >= 0) & (my <= Hs - 1)
        if selection.members is not None:
            members[k] = cv2.remap(selection.members[k].astype(np.uint8), wx, wy,
                                   cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=0) > 0
    lab = label[roi]
    rep_roi = rep[roi]
    py, px = np.nonzero(rep_roi)
    chosen = lab[py, px]
    member = members[:, py, px] & usable[1:, py, px]
    member[chosen - 1, np.arange(len(py))] = True
    cand[chosen, py, px] = mixture_detail(cand[chosen, py, px],
                                          member_median(cand[1:, py, px], member), rep_roi,
                                          LIGHT_SIGMA_PX * max(sx, sy))
    labs = np.stack([blurred_lab(c, max(sx, sy)) for c in cand])
    scale = max(sx, sy)  # the fade's distances are full-size pixels
    out = offset_blend(reference[roi], cand, lab, rep_roi, usable, labs, ring_px=ring_px,
                       plateau_px=PLATEAU_PX * scale, decay_px=DECAY_PX * scale,
                       light_sigma_px=LIGHT_SIGMA_PX * scale,
                       light_scale_px=LIGHT_SCALE_PX * scale,
                       light_decay_px=LIGHT_DECAY_PX * scale, band_px=band_px,
                       band_sigma_px=BAND_SIGMA_PX * scale,
                       suspect=None if selection.mask is None else cv2.resize(
                           selection.mask.astype(np.uint8), size,
                           interpolation=cv2.INTER_NEAREST)[roi] > 0)
    if selection.seam_offset is not None:
        # per label, bilinear over that label's own working pixels (normalised)
        corr = np.zeros(out.shape, np.float32)
        for lbl in np.unique(chosen):
            mine = (selection.label == lbl).astype(np.float32)
            num = cv2.remap(selection.seam_offset * mine[..., None], wx, wy, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
            den = cv2.remap(mine, wx, wy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            at = rep_roi & (lab == lbl)
            corr[at] = np.where((den[at] > 1e-6)[:, None],
                                num[at] / np.maximum(den[at], 1e-6)[:, None], 0)
        v = out.astype(np.float32) + corr
        v += 0.5
        out = np.where(rep_roi[..., None], np.clip(v, 0, 255).astype(np.uint8), out)
    no_src = cv2.resize(selection.no_source.astype(np.uint8), size,
                        interpolation=cv2.INTER_NEAREST)[roi] > 0
    if no_src.any():
        out = cv2.inpaint(np.ascontiguousarray(out), (no_src & rep_roi).astype(np.uint8),
                          int(5 * max(sx, sy)), cv2.INPAINT_TELEA)
    clean[roi][rep_roi] = out[rep_roi]
    # every replaced pixel whose colour moved by tau or more is in the dynamic map
    lab_o = cv2.cvtColor(clean.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)
    lab_r = cv2.cvtColor(reference.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)
    moved = np.zeros_like(dyn_full)
    moved[roi] = rep_roi
    dyn_full |= moved & (np.linalg.norm(lab_o - lab_r, axis=-1) >= tau)
    return clean, dyn_full


# the photomontage's alpha-expansion as it was written before it kept to the movable pixels
def expansion_labels(D: npt.NDArray[np.float64], colours: npt.NDArray[np.float32], *,
                     beta: float, cycles: int = 2,
                     init: npt.NDArray[np.intp] | None = None,
                     distance: npt.NDArray[np.float32] | None = None,
                     forbidden: float | None = None) -> npt.NDArray[np.intp]:
    """``montage.expansion_labels`` on the whole grid: every pixel a node of every move's
    graph, every edge looked at (as written before the moves kept to the pixels that
    can move)."""
    nl, H, W = D.shape
    lab = (np.argmin(D, 0) if init is None else init.astype(np.intp).copy()).ravel()
    # V(a, b) at each pixel; an edge sums it over both its pixels
    pair = beta * (pairwise_distance(colours) if distance is None else distance)
    pair = pair.reshape(nl * nl, H * W)
    Df = D.reshape(nl, H * W)
    idx = np.arange(H * W).reshape(H, W)
    ep = np.concatenate([idx[:-1].ravel(), idx[:, :-1].ravel()])  # p of each edge
    eq = np.concatenate([idx[1:].ravel(), idx[:, 1:].ravel()])  # its neighbour q

    def V(u, v, p, q):  # seam cost of labels u at p and v at q, per edge (p, q)
        k = u * nl + v
        return pair[k, p] + pair[k, q]

    for _ in range(cycles):
        changed = False
        for a in range(nl):
            # p may move to a (x_p = 1) unless a is forbidden there or p has it already
            free = lab != a
            if forbidden is not None:
                free &= Df[a] < forbidden
            if not free.any():
                continue
            node = np.full(H * W, -1, np.intp)
            node[free] = np.arange(int(free.sum()))
            cost1 = Df[a].astype(np.float64)  # x_p = 1: p takes label a
            cost0 = Df[lab, np.arange(H * W)].astype(np.float64)
            # only edges touching a pixel that may move carry a term
            e = free[ep] | free[eq]
            p, q = ep[e], eq[e]
            lp, lq = lab[p], lab[q]
            A, B, C = V(lp, lq, p, q), V(lp, a, p, q), V(a, lq, p, q)
            # E(x_p, x_q) = A + (C - A) x_p - C x_q + (B + C - A)(1 - x_p) x_q;
            # a fixed pixel has x = 0
            fp, fq = free[p], free[q]
            both = fp & fq
            only_q = fq & ~fp
            n = H * W
            cost1 += np.bincount(p[fp], (C - A)[fp], n)
            cost1 -= np.bincount(q[both], C[both], n)
            cost1 += np.bincount(q[only_q], (B - A)[only_q], n)
            g = maxflow.Graph[float]()
            g.add_nodes(int(free.sum()))
            g.add_edges(node[p[both]], node[q[both]],
                        np.maximum(B + C - A, 0.0)[both], np.zeros(int(both.sum())))
            c1, c0 = cost1[free], cost0[free]
            m = np.minimum(c0, c1)
            g.add_grid_tedges(np.arange(len(c1)), c1 - m, c0 - m)
            g.maxflow()
            take = g.get_grid_segments(np.arange(len(c1)))
            if take.any():
                changed = True
                lab[np.flatnonzero(free)[take]] = a
        if not changed:
            break
    return lab.reshape(H, W)

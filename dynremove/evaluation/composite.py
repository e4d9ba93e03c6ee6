"""Composites: real moving objects pasted into real static multi-view sets.

A static set (e.g. Strecha's fountain-P11) has no moving object, so its
reference view *is* the true clean background. Objects cut out of DAVIS-style
sets with their true masks are pasted into ``n_views`` consecutive views of it,
each object moving along a straight path **in the scene**: its position in the
reference is ``p``; in view ``k`` it is ``H_k(p + (k - ref) d)``, with ``H_k``
the homography reference → view ``k`` of the static images (SIFT + MAGSAC++,
identity if it fails), so the camera's own motion does not carry the object
along. The step ``|d|`` is 0.6–0.85 × the object's extent along ``d``, so the
reference's object region is uncovered in most other views (checked; a
placement that leaves it covered in more than half of them is redrawn).

Objects take successive annotated frames of their sequence (so they move their
limbs), frames whose mask touches the image border being avoided: the views run
through that pool in order from a random start, *wrapping around* at its end, so
a pool shorter than the views repeats frames (and jumps from the clip's end to
its start), and a pool of one frame (one annotated frame clear of the border, or
none: then the largest; DAVIS kite-surf) pastes the same frame in every view.
``composite.json`` lists each object's frames. They are scaled so their area in
the reference is 8–15 % of the image, capped so the object fits (0.7 × the
height, 0.45 × the width): a tall or wide object can come out smaller
(``ref_mask_fraction`` in ``composite.json``; a kite-surf set under 1 %). An
object may leave the frame in the outer views.
Edges are feathered: the object's binary mask is blurred with a
Gaussian (sigma = ``feather_px / 2``, i.e. a ~2 px ramp) to give the alpha, and
the true mask written is ``alpha >= 0.5`` (union over objects, later objects on
top). Everything is drawn from ``numpy.random.default_rng(seed)``: the same
seed gives byte-identical files.

With ``light``, every view but the reference is also *relit*, as hand-held photos
are by auto-exposure, white balance and light that depends on the viewpoint (a
glare on a glossy table, vignetting): the view is multiplied by a per-channel
gain (exposure × white balance, ``LIGHT_EXPOSURE`` and ``LIGHT_WB``) and by a
smooth gain field, 1 plus one to three broad Gaussian blobs (amplitude
``LIGHT_BLOB_GAIN``, σ ``LIGHT_BLOB_SIGMA`` × the longer side) at random
places. The reference is not relit, so its static view stays the truth. The
draws come from a generator of their own (``(seed, 1)``): a set built with and
without ``light`` has the same objects on the same paths.

Output (the layout ``dynremove eval`` reads)::

    DIR/frames/NN_<static stem>.png   composited views
    DIR/masks/NN_<static stem>.png    true dynamic masks, 0/255
    DIR/background.png                the static reference view (no objects)
    DIR/free.png                      0/255: reference pixels some OTHER view shows
                                      free of every pasted object (see free_map)
    DIR/composite.json                provenance: sources, frames, scale, path, seed
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from dynremove import io
from dynremove.errors import InputError
from dynremove.evaluation.baselines import estimate_homography
from dynremove.evaluation.evaluate import find_sets, image_files
from dynremove.method.geometry import detect, project_homography

MAX_SIDE = 854  # static views are resized so the longer side is at most this
AREA_RANGE = (0.08, 0.15)  # object area in the reference, fraction of the image
STEP_RANGE = (0.6, 0.85)  # path step, in units of the object's extent along it
MAX_ANGLE_DEG = 25.0  # path direction within this of the horizontal
FEATHER_PX = 2.0  # width of the alpha ramp (Gaussian sigma = FEATHER_PX / 2)
MIN_OBJECT_FRACTION = 0.003  # object frames with less mask than this are ignored
_ATTEMPTS = 30
# ``light``: the relighting of the other views (``relight``)
LIGHT_EXPOSURE = (0.85, 1.15)  # a view's gain, common to the three channels
LIGHT_WB = 0.06  # and each channel's, 1 ± this (white balance)
LIGHT_BLOBS = (1, 3)  # how many smooth blobs of light or shade, inclusive
LIGHT_BLOB_GAIN = (-0.3, 0.35)  # each blob's gain at its centre, added to 1
LIGHT_BLOB_SIGMA = (0.08, 0.25)  # each blob's σ, fraction of the longer side


@dataclass
class Composite:
    """A composited set in memory (what :func:`write_composite` writes)."""

    images: list[np.ndarray]  # (H, W, 3) uint8 BGR
    masks: list[np.ndarray]  # (H, W) bool: alpha >= 0.5
    alphas: list[np.ndarray]  # (H, W) float32 in [0, 1], union of the objects' alphas
    background: np.ndarray  # the static reference view
    statics: list[np.ndarray]  # the static views (resized), without objects
    ref_index: int
    names: list[str]
    info: dict = field(default_factory=dict)
    free: np.ndarray | None = None  # (H, W) bool, reference-sized: see free_map


@dataclass
class _Cut:
    frame: str
    img: np.ndarray  # padded crop, uint8 BGR
    mask: np.ndarray  # padded crop, float32 0/1
    area: int  # mask pixels
    complete: bool  # mask does not touch the frame border


# --------------------------------------------------------------------------- inputs
def _read_static(static_dir: str | os.PathLike, n_views: int, max_side: int
                 ) -> tuple[list[np.ndarray], list[str], list[Path]]:

    paths, _ = io.list_inputs([static_dir])
    if len(paths) < n_views:
        raise InputError(f"--n-views {n_views} needs {n_views} images; {static_dir} has "
                         f"{len(paths)}")
    start = min(max(0, len(paths) // 2 - n_views // 2), len(paths) - n_views)
    paths = paths[start:start + n_views]
    imgs = [io.read_image(p)[0] for p in paths]
    H0, W0 = imgs[0].shape[:2]
    s = min(1.0, max_side / max(H0, W0)) if max_side else 1.0
    size = (max(8, round(W0 * s)), max(8, round(H0 * s)))
    imgs = [im if im.shape[1::-1] == size else
            cv2.resize(im, size, interpolation=cv2.INTER_AREA if im.shape[1] > size[0]
                       else cv2.INTER_LINEAR) for im in imgs]
    return imgs, [p.stem for p in paths], paths


def _object_sets(objects_dir: str | os.PathLike) -> list:

    sets = [s for s in find_sets(objects_dir) if any(s.mask_path(f) for f in s.frames)]
    if not sets:
        raise InputError(f"{objects_dir}: no set with frames/ and masks/")
    return sets


def _cutouts(es: Any, pad: int) -> list[_Cut]:
    """Every annotated frame of a set, cropped to its mask's box plus ``pad`` px."""

    cuts = []
    for f in es.frames:
        mp = es.mask_path(f)
        if mp is None:
            continue
        img, _ = io.read_image(f)
        H, W = img.shape[:2]
        m = io.read_mask(mp, (W, H))
        area = int(m.sum())
        if area < MIN_OBJECT_FRACTION * H * W:
            continue
        ys, xs = np.nonzero(m)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        complete = y0 > 1 and x0 > 1 and y1 < H - 1 and x1 < W - 1
        y0, x0 = max(0, y0 - pad), max(0, x0 - pad)
        y1, x1 = min(H, y1 + pad), min(W, x1 + pad)
        cuts.append(_Cut(frame=f.name, img=img[y0:y1, x0:x1].copy(),
                         mask=m[y0:y1, x0:x1].astype(np.float32), area=area,
                         complete=complete))
    return cuts


def _homographies(statics: Sequence[np.ndarray], ref: int, seed: int
                  ) -> tuple[list[np.ndarray], list[str]]:
    """H_k: reference pixel -> view k pixel (identity for the reference / on failure)."""
    feats = [detect(cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)) for im in statics]
    Hs, failed = [], []
    for k in range(len(statics)):
        if k == ref:
            Hs.append(np.eye(3))
            continue
        H = estimate_homography(feats[ref], feats[k], seed)
        if H is None:
            failed.append(k)
            H = np.eye(3)
        Hs.append(H)
    return Hs, [str(k) for k in failed]


def _apply_h(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    x, y, w = project_homography(H, float(p[0]), float(p[1]))
    return np.array([x, y]) if abs(w) > 1e-12 else np.array([np.inf, np.inf])


# --------------------------------------------------------------------------- pasting
def _scaled(cut: _Cut, s: float) -> tuple[np.ndarray, np.ndarray]:
    h, w = cut.mask.shape
    size = (max(1, round(w * s)), max(1, round(h * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    img = cv2.resize(cut.img, size, interpolation=interp)
    m = cv2.resize(cut.mask, size, interpolation=interp)
    return img, (m >= 0.5).astype(np.float32)


def _paste_layer(shape: tuple[int, int], img: np.ndarray, binary: np.ndarray,
                 center: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Full-size object colour and feathered alpha with the crop centred at ``center``."""
    H, W = shape
    colour = np.zeros((H, W, 3), np.float32)
    B = np.zeros((H, W), np.float32)
    h, w = binary.shape
    if not np.all(np.isfinite(center)):
        return colour, B
    x0 = int(round(center[0] - w / 2))
    y0 = int(round(center[1] - h / 2))
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(W, x0 + w), min(H, y0 + h)
    if ax1 <= ax0 or ay1 <= ay0:
        return colour, B
    sl = (slice(ay0 - y0, ay1 - y0), slice(ax0 - x0, ax1 - x0))
    colour[ay0:ay1, ax0:ax1] = img[sl]
    B[ay0:ay1, ax0:ax1] = binary[sl]
    alpha = cv2.GaussianBlur(B, (0, 0), sigma) if sigma > 0 else B
    return colour, np.clip(alpha, 0.0, 1.0)


def _blend(statics: Sequence[np.ndarray], layers: list[list[tuple[np.ndarray, np.ndarray]]]
           ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    images, alphas = [], []
    for k, st in enumerate(statics):
        out = st.astype(np.float32)
        keep = np.ones(st.shape[:2], np.float32)  # prod(1 - alpha_j)
        for colour, a in layers[k]:
            out = out * (1.0 - a[..., None]) + colour * a[..., None]
            keep *= 1.0 - a
        images.append(np.clip(np.rint(out), 0, 255).astype(np.uint8))
        alphas.append((1.0 - keep).astype(np.float32))
    return images, alphas


def _covered_in(mask_k: np.ndarray, H_k: np.ndarray, ref_mask: np.ndarray) -> float:
    """Fraction of the reference's mask still hidden by objects in view k."""
    Hh, Ww = ref_mask.shape
    back = cv2.warpPerspective(mask_k.astype(np.uint8), H_k, (Ww, Hh),
                               flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    return float((back.astype(bool) & ref_mask).sum() / max(1, ref_mask.sum()))


def free_map(masks: Sequence[np.ndarray], Hs: Sequence[np.ndarray], ref: int) -> np.ndarray:
    """Reference pixels that at least one OTHER view shows free of every pasted object.

    View ``k``'s mask is brought into the reference with the homography
    ``H_k`` (reference pixel -> view ``k`` pixel), as :func:`_covered_in` does:
    ``cv2.warpPerspective(mask_k, H_k, (W, H), INTER_NEAREST | WARP_INVERSE_MAP,
    borderValue=1)``, so a reference pixel that falls outside view ``k``'s frame
    counts as not free in that view. A pixel is free when some ``k != ref``
    leaves it uncovered. (A view whose homography estimation failed uses the
    identity, like the pasting does.)

    Returns an ``(H, W)`` bool array (all False with a single view).
    """
    Hh, Ww = masks[ref].shape
    free = np.zeros((Hh, Ww), bool)
    for k, (m, H) in enumerate(zip(masks, Hs)):
        if k == ref:
            continue
        back = cv2.warpPerspective(m.astype(np.uint8), np.asarray(H, np.float64), (Ww, Hh),
                                   flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=1)
        free |= back == 0
    return free


# --------------------------------------------------------------------------- compose
def compose(statics: Sequence[np.ndarray], static_names: Sequence[str], object_sets: Sequence,
            *, seed: int = 0, n_objects: int = 1, feather_px: float = FEATHER_PX,
            area_range: tuple[float, float] = AREA_RANGE, light: bool = False) -> Composite:
    """Paste ``n_objects`` objects from ``object_sets`` (EvalSet, with masks) into ``statics``.

    The reference is the middle view (``len(statics) // 2``). Deterministic in ``seed``.
    With ``light`` the other views are relit (``relight``; the module's docstring).
    """

    if n_objects < 1:
        raise InputError(f"--objects must be >= 1, got {n_objects}")
    V = len(statics)
    if V < 2:
        raise InputError(f"need at least 2 static views, got {V}")
    rng = np.random.default_rng(seed)
    ref = V // 2
    Hh, Ww = statics[0].shape[:2]
    sigma = feather_px / 2.0
    pad = int(math.ceil(3 * sigma)) + 2
    Hs, failed = _homographies(statics, ref, seed)

    # choose the objects: sets in a seeded order, preferring enough complete frames
    order = list(rng.permutation(len(object_sets)))
    cands = []
    for i in order:
        cuts = _cutouts(object_sets[i], pad)
        if cuts:
            n_complete = sum(c.complete for c in cuts)
            cands.append((n_complete >= min(V, 3), i, cuts))
    if not cands:
        raise InputError("no object set has a usable mask (all masks empty or tiny)")
    cands.sort(key=lambda c: not c[0])  # stable: seeded order within each group
    chosen = [cands[j % len(cands)] for j in range(n_objects)]

    objects = []
    for _, i, cuts in chosen:
        pool = [c for c in cuts if c.complete] or sorted(cuts, key=lambda c: -c.area)[:1]
        start = int(rng.integers(len(pool)))
        seq = [pool[(start + k - ref) % len(pool)] for k in range(V)]
        objects.append((object_sets[i], seq))

    best = None
    for attempt in range(_ATTEMPTS):
        layers: list[list] = [[] for _ in range(V)]
        meta, ref_boxes = [], []
        for es, seq in objects:
            f = float(rng.uniform(*area_range))
            s = math.sqrt(f * Hh * Ww / seq[ref].area)
            h0, w0 = seq[ref].mask.shape
            s = min(s, 0.7 * Hh / max(1, h0 - 2 * pad), 0.45 * Ww / max(1, w0 - 2 * pad))
            ang = math.radians(float(rng.uniform(-MAX_ANGLE_DEG, MAX_ANGLE_DEG)))
            sign = 1.0 if rng.random() < 0.5 else -1.0
            u = np.array([sign * math.cos(ang), math.sin(ang)])
            _, b_ref = _scaled(seq[ref], s)
            ys, xs = np.nonzero(b_ref)
            bw, bh = (np.ptp(xs) + 1, np.ptp(ys) + 1) if len(xs) else (1, 1)
            extent = abs(u[0]) * bw + abs(u[1]) * bh
            d = u * extent * float(rng.uniform(*STEP_RANGE))
            offs = np.arange(V) - ref
            c = np.array([Ww / 2, Hh * float(rng.uniform(0.45, 0.65))]) - d * offs.mean()
            c += rng.uniform(-0.12, 0.12, 2) * (Ww, Hh)
            hw, hh = b_ref.shape[1] / 2, b_ref.shape[0] / 2
            c[0] = np.clip(c[0], hw + 1, max(hw + 1, Ww - hw - 1))
            c[1] = np.clip(c[1], hh + 1, max(hh + 1, Hh - hh - 1))
            centers = []
            for k in range(V):
                img_k, b_k = _scaled(seq[k], s)
                p_k = _apply_h(Hs[k], c + offs[k] * d)
                centers.append([float(p_k[0]), float(p_k[1])])
                layers[k].append(_paste_layer((Hh, Ww), img_k, b_k, p_k, sigma))
            ref_boxes.append((c, hw, hh))
            meta.append({"set": es.name, "frames": [q.frame for q in seq],
                         "scale": round(s, 4), "direction_deg": round(
                             math.degrees(math.atan2(u[1], u[0])), 2),
                         "step_px": round(float(np.hypot(*d)), 2),
                         "ref_center": [round(float(c[0]), 2), round(float(c[1]), 2)],
                         "centers": [[round(x, 2), round(y, 2)] for x, y in centers]})
        images, alphas = _blend(statics, layers)
        masks = [a >= 0.5 for a in alphas]
        covered = [None if k == ref else round(_covered_in(masks[k], Hs[k], masks[ref]), 4)
                   for k in range(V)]
        n_bad = sum(1 for x in covered if x is not None and x > 0.5)
        # objects should not hide one another in the reference
        overlap = 0.0
        for j, (cj, wj, hj) in enumerate(ref_boxes):
            for ci, wi, hi in ref_boxes[:j]:
                ix = max(0.0, min(cj[0] + wj, ci[0] + wi) - max(cj[0] - wj, ci[0] - wi))
                iy = max(0.0, min(cj[1] + hj, ci[1] + hi) - max(cj[1] - hj, ci[1] - hi))
                overlap = max(overlap, ix * iy / (4 * min(wj * hj, wi * hi)))
        ok = masks[ref].any() and n_bad <= (V - 1) // 2 and overlap < 0.25
        cand = (images, alphas, masks, meta, covered, attempt)
        if best is None or (ok and not best[0]):
            best = (ok, cand)
        if ok:
            break
    ok, (images, alphas, masks, meta, covered, attempt) = best
    free = free_map(masks, Hs, ref)
    lights: list = [None] * V
    if light:
        lrng = np.random.default_rng([seed, 1])
        for k in range(V):
            if k != ref:
                images[k], lights[k] = relight(images[k], lrng)
    names = [f"{k:02d}_{n}.png" for k, n in enumerate(static_names)]
    info = {
        "seed": int(seed), "n_views": V, "ref": names[ref], "ref_index": ref, "size": [Ww, Hh],
        "static_images": list(static_names), "objects": meta,
        "feather_sigma_px": sigma, "area_range": list(area_range),
        "ref_mask_fraction": float(masks[ref].mean()),
        "mask_fraction": [round(float(m.mean()), 4) for m in masks],
        "ref_region_covered": covered, "placement_ok": bool(ok),
        "placement_attempts": attempt + 1, "homography_failed_views": failed,
        "ref_mask_recoverable": round(float(free[masks[ref]].mean()), 4)
        if masks[ref].any() else None,
    }
    if light:
        info["light"] = {
            "model": "view = plain view x gain_bgr (exposure x white balance, per B/G/R "
                     "channel) x (1 + sum over blobs of gain x exp(-|p - center|^2 / "
                     "(2 sigma_px^2))), p and center = (x, y) in px; gain a fraction "
                     "(-0.3 = 30 % darker at the centre); the reference is not relit",
            "views": {names[k]: lights[k] for k in range(V)}}
    return Composite(images=images, masks=masks, alphas=alphas,
                     background=statics[ref].copy(), statics=list(statics), ref_index=ref,
                     names=names, info=info, free=free)


def relight(img: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """``img`` (H, W, 3) uint8 BGR under other light: × a per-channel gain and × a
    smooth gain field (1 + Σ Gaussian blobs), rounded and clipped to uint8.

    Draws from ``rng``: the exposure (``LIGHT_EXPOSURE``), each channel's white
    balance (1 ± ``LIGHT_WB``), and ``LIGHT_BLOBS`` blobs (centre anywhere in the
    image, gain ``LIGHT_BLOB_GAIN``, σ ``LIGHT_BLOB_SIGMA`` × the longer side).
    Returns the relit image and what was drawn (gains, blobs in pixels).
    """
    H, W = img.shape[:2]
    exposure = float(rng.uniform(*LIGHT_EXPOSURE))
    gain = exposure * (1.0 + rng.uniform(-LIGHT_WB, LIGHT_WB, 3))
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    field = np.ones((H, W), np.float32)
    blobs = []
    for _ in range(int(rng.integers(LIGHT_BLOBS[0], LIGHT_BLOBS[1] + 1))):
        cx, cy = float(rng.uniform(0, W)), float(rng.uniform(0, H))
        amp = float(rng.uniform(*LIGHT_BLOB_GAIN))
        sigma = float(rng.uniform(*LIGHT_BLOB_SIGMA)) * max(H, W)
        field += amp * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma * sigma))
        blobs.append({"center": [round(cx, 1), round(cy, 1)], "gain": round(amp, 4),
                      "sigma_px": round(sigma, 1)})
    out = img.astype(np.float32) * field[..., None] * gain.astype(np.float32)
    out = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    return out, {"gain_bgr": [round(float(g), 4) for g in gain], "blobs": blobs}


def write_composite(comp: Composite, out_dir: str | os.PathLike) -> Path:
    """Write frames/, masks/ (0/255), background.png, free.png (0/255, when
    ``comp.free`` is set) and composite.json atomically.

    A folder written before by this function is overwritten (its old frames and
    masks removed); any other non-empty ``frames/`` is refused.
    """

    out = io.prepare_out_dir(out_dir)
    for sub in ("frames", "masks"):
        d = out / sub
        if d.is_dir() and any(d.iterdir()):
            if not (out / "composite.json").is_file():
                raise InputError(f"{d}: not empty and not written by 'dynremove composite'")
            for q in d.iterdir():
                if q.is_file() and q.suffix.lower() == ".png":
                    q.unlink()
    for name, img, m in zip(comp.names, comp.images, comp.masks):
        io.write_image(out / "frames" / name, img)
        io.write_image(out / "masks" / name, m.astype(np.uint8) * np.uint8(255))
    io.write_image(out / "background.png", comp.background)
    if comp.free is not None:
        io.write_image(out / "free.png", comp.free.astype(np.uint8) * np.uint8(255))
    elif (out / "free.png").is_file():
        (out / "free.png").unlink()  # a stale map would mislead eval
    io.write_json(out / "composite.json", comp.info)
    return out


def make_composite(static_dir: str | os.PathLike, objects_dir: str | os.PathLike,
                   out_dir: str | os.PathLike, *, seed: int = 0, n_views: int = 6,
                   n_objects: int = 1, max_side: int = MAX_SIDE,
                   object_sets: Sequence | None = None, light: bool = False) -> dict:
    """One composite set from a static folder and a DAVIS-style objects folder.

    ``object_sets`` restricts the objects to these sets (EvalSet) of ``objects_dir``.
    Returns the provenance dict (also written as ``composite.json``).
    """

    if n_views < 2:
        raise InputError(f"--n-views must be >= 2, got {n_views}")
    statics, stems, paths = _read_static(static_dir, n_views, max_side)
    sets = list(object_sets) if object_sets is not None else _object_sets(objects_dir)
    comp = compose(statics, stems, sets, seed=seed, n_objects=n_objects, light=light)
    comp.info["static_dir"] = str(static_dir)
    comp.info["objects_dir"] = str(objects_dir)
    write_composite(comp, out_dir)
    return comp.info


def static_sets(static_root: Path, n_views: int) -> list[Path]:
    """``static_root`` and its sub-folders that hold at least ``n_views`` images."""
    dirs = [static_root] + sorted(p for p in static_root.iterdir() if p.is_dir())
    return [d for d in dirs if len(image_files(d)) >= n_views]


def make_composites(static_root: str | os.PathLike, objects_root: str | os.PathLike,
                    out_root: str | os.PathLike, *, n_sets: int = 6, seed: int = 0,
                    n_views: int = 6, n_objects: int = 1, max_side: int = MAX_SIDE,
                    light: bool = False) -> list[Path]:
    """``n_sets`` composites under ``out_root``: static sets in turn × distinct objects.

    Set ``i`` uses static set ``i mod (number of static sets)`` and the next
    ``n_objects`` object sets of a seeded permutation (so objects differ between
    sets while there are enough), with seed derived from ``(seed, i)``. Each is
    written to ``out_root/<static>+<object>[+<object>...]``.
    """

    if n_sets < 1:
        # (0, the CLI's default, is one set from STATIC_DIR itself: handled by the
        # caller; a trial read ">= 1" against the help's "default 0")
        raise InputError(f"--n-sets must be at least 1, or 0 (the default: one set from "
                         f"STATIC_DIR itself), got {n_sets}")
    root = Path(static_root)
    io.require_folder(root)
    statics = static_sets(root, n_views)
    if not statics:
        raise InputError(f"{root}: no folder with at least {n_views} images")
    objs = _object_sets(objects_root)
    rng = np.random.default_rng(seed)
    perm = [objs[i] for i in rng.permutation(len(objs))]
    outs = []
    for i in range(n_sets):
        st = statics[i % len(statics)]
        chosen = [perm[(i * n_objects + j) % len(perm)] for j in range(n_objects)]
        name = st.name + "+" + "+".join(o.path.name for o in chosen)
        set_seed = int(np.random.default_rng([seed, i]).integers(2**31 - 1))
        out = Path(out_root) / name
        make_composite(st, objects_root, out, seed=set_seed, n_views=n_views,
                       n_objects=n_objects, max_side=max_side, object_sets=chosen,
                       light=light)
        outs.append(out)
    return outs


__all__ = ["Composite", "compose", "free_map", "write_composite", "make_composite",
           "make_composites", "relight", "static_sets", "MAX_SIDE", "AREA_RANGE", "FEATHER_PX"]

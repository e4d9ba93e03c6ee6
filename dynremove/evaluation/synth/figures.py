"""Moving figures (people, animals) of the synthetic scenes and their placement."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dynremove.evaluation.synth.camera import CAMERA_HEIGHT
from dynremove.evaluation.synth.textures import fbm, hsv

_MAX_ATTEMPTS = 200  # object placements tried before giving up


_SKIN = np.array([[60, 80, 120], [90, 130, 190], [120, 160, 220], [40, 60, 90]],
                 np.float32)
_FUR = np.array([[40, 110, 200], [30, 30, 35], [225, 228, 230], [70, 160, 215],
                 [60, 60, 160]], np.float32)
_UNIT_SIZE = {"person": (0.24, 0.45), "animal": (0.5, 1.4)}  # area/h^2, width/h


def _parts(kind, phase, facing):
    """Ellipses ``(x, y, ax, ay, angle_deg, part)`` in units of object height.

    The anchor (0, 0) is between the feet; y points down (up is negative).
    Parts: 0 main (shirt / fur), 1 secondary (trousers / spots), 2 skin / head,
    3 hair / dark details.
    """
    out = []

    def limb(hip_x, hip_y, length, thick, ang, part):
        cx = hip_x + 0.5 * length * np.sin(ang)
        cy = hip_y + 0.5 * length * np.cos(ang)
        out.append((cx, cy, thick, 0.5 * length, -np.degrees(ang), part))

    if kind == "person":
        sw = 0.35 * np.sin(phase)
        limb(-0.045, -0.47, 0.47, 0.06, sw, 1)
        limb(0.045, -0.47, 0.47, 0.06, -sw, 1)
        out.append((0.0, -0.63, 0.15, 0.2, 0.0, 0))
        limb(-0.14, -0.78, 0.4, 0.045, -sw, 0)
        limb(0.14, -0.78, 0.4, 0.045, sw, 0)
        out.append((0.0, -0.895, 0.085, 0.09, 0.0, 2))
        out.append((0.0, -0.94, 0.088, 0.05, 0.0, 3))
    else:  # quadruped facing +x
        for k, hx in enumerate((-0.32, -0.2, 0.2, 0.32)):
            limb(hx, -0.45, 0.45, 0.05, 0.3 * np.sin(phase + 1.6 * k), 1 + k % 2 * 2)
        out.append((0.0, -0.56, 0.44, 0.18, 0.0, 0))
        out.append((0.5, -0.82, 0.15, 0.14, 0.0, 2))
        out.append((0.64, -0.77, 0.1, 0.06, 10.0, 2))
        out.append((0.42, -0.96, 0.04, 0.08, -20.0, 3))
        out.append((-0.52, -0.72, 0.18, 0.035, -35.0, 3))
    if facing < 0:
        out = [(-x, y, ax, ay, -a, p) for x, y, ax, ay, a, p in out]
    return out


def _draw_labels(parts, hgt, canvas, anchor_xy):
    """Draw part labels (1 + part) hard-edged into ``canvas`` (uint8)."""
    sh = 16.0
    for x, y, ax, ay, ang, part in parts:
        c = (int(round((anchor_xy[0] + x * hgt) * sh)),
             int(round((anchor_xy[1] + y * hgt) * sh)))
        a = (max(int(round(ax * hgt * sh)), 8), max(int(round(ay * hgt * sh)), 8))
        cv2.ellipse(canvas, c, a, float(ang), 0, 360, int(part) + 1, -1,
                    cv2.LINE_8, 4)


@dataclass
class _Object:
    kind: str
    hgt: float  # object height in pixels
    facing: float
    phase0: float
    z: float  # depth (world), feet on the ground
    x_ref: float  # world x in the reference view
    velocity: float  # world x per view
    colors: np.ndarray  # (5, 3) float32 BGR per label (index 0 unused)
    shade: np.ndarray  # (S, S) float32 texture in object coordinates
    half: int  # shade is centred on the anchor: S = 2 * half


def _sample_object(rng, geo, *, step_x, x_center, k_mid, n_views, area_px):
    """One object whose image path over the views is centred on ``x_center``.

    It moves by 0.8-1 of its width per view, less if the whole path would not
    fit in the frame, and is shifted to lie inside the reference view.
    """
    kind = "person" if rng.random() < 0.6 else "animal"
    unit_area, unit_width = _UNIT_SIZE[kind]
    y_feet = rng.uniform(0.8, 0.96) * geo.H
    hgt = min(np.sqrt(area_px / unit_area), 0.95 * (y_feet - 2),
              0.9 * geo.W / unit_width)
    width = unit_width * hgt
    delta = min(rng.uniform(0.8, 1.0) * width,  # image motion per view
                0.9 * (geo.W - 0.1 * width) / max(n_views - 1, 1))
    facing = rng.choice([-1.0, 1.0])
    z = geo.depth_of_ground_row(y_feet)
    margin = 0.55 * width + 2
    x_img = np.clip(x_center - facing * delta * k_mid, margin, geo.W - margin)
    x_ref = (x_img - geo.cx) * z / geo.f
    velocity = step_x + facing * delta * z / geo.f
    if kind == "person":
        shirt = hsv(rng.uniform(0, 360), rng.uniform(0.6, 0.95),
                     rng.uniform(0.5, 0.95))
        trousers = hsv(rng.uniform(0, 360), rng.uniform(0.4, 0.9),
                        rng.uniform(0.25, 0.7))
        skin = _SKIN[rng.integers(len(_SKIN))]
        hair = hsv(rng.uniform(0, 40), 0.5, rng.uniform(0.05, 0.3))
    else:
        fur = _FUR[rng.integers(len(_FUR))]
        shirt, trousers = fur, fur * rng.uniform(0.4, 0.8)
        skin, hair = fur * 0.9, np.float32([25, 25, 30])
    colors = np.stack([np.zeros(3, np.float32), shirt, trousers, skin, hair])
    half = int(np.ceil(hgt)) + 2
    shade = 0.6 + 0.8 * fbm(rng, 2 * half, 2 * half, cell=max(2.0, 0.12 * hgt),
                             octaves=4)
    if kind == "person" and rng.random() < 0.5:  # striped shirt
        period = rng.uniform(0.05, 0.1) * hgt
        ys = np.arange(2 * half, dtype=np.float32)[:, None]
        shade = shade * (0.75 + 0.25 * np.sign(np.sin(2 * np.pi * ys / period)))
    return _Object(kind, hgt, facing, rng.uniform(0, 2 * np.pi), z, x_ref,
                   velocity, colors, shade.astype(np.float32), half)


def _object_anchor(geo, obj, R, C, k):
    """Image position (x, y) of the feet of ``obj`` in a view, k views from ref."""
    X = np.array([obj.x_ref + obj.velocity * k, CAMERA_HEIGHT, obj.z])
    q = geo.K @ R @ (X - C)
    return q[:2] / q[2]


def _draw_object(geo, obj, anchor_xy, k, img, mask):
    """Draw ``obj`` hard-edged into ``img`` / ``mask`` (in place)."""
    H, W = geo.H, geo.W
    ax, ay = int(round(anchor_xy[0])), int(round(anchor_xy[1]))
    x0, y0 = max(ax - obj.half, 0), max(ay - obj.half, 0)
    x1, y1 = min(ax + obj.half, W), min(ay + obj.half, H)
    if x1 <= x0 or y1 <= y0:
        return
    canvas = np.zeros((y1 - y0, x1 - x0), np.uint8)
    parts = _parts(obj.kind, obj.phase0 + 1.9 * k, obj.facing)
    _draw_labels(parts, obj.hgt, canvas,
                 (anchor_xy[0] - x0, anchor_xy[1] - y0))
    sel = canvas > 0
    sy, sx = y0 - (ay - obj.half), x0 - (ax - obj.half)
    shade = obj.shade[sy:sy + (y1 - y0), sx:sx + (x1 - x0)]
    col = obj.colors[canvas] * shade[..., None]
    img[y0:y1, x0:x1][sel] = np.clip(col[sel] + 0.5, 0, 255).astype(np.uint8)
    mask[y0:y1, x0:x1] |= sel


def place_objects(rng, geo, rotations, centers, statics, ref, n_objects):
    """Sample objects until the scene meets its contract; draw all views."""
    n_views = len(statics)
    H, W = geo.H, geo.W
    step_x = (centers[-1, 0] - centers[0, 0]) / max(n_views - 1, 1)
    k_mid = (n_views - 1) / 2 - ref  # middle of the path, in views from ref
    order = [ref] + [i for i in range(n_views) if i != ref]
    for _ in range(_MAX_ATTEMPTS):
        total = rng.uniform(0.045, 0.09) * H * W
        weights = rng.dirichlet(np.full(n_objects, 4.0))
        slots = rng.permutation(n_objects)  # spread the paths across the frame
        objs = [_sample_object(
                    rng, geo, step_x=step_x, k_mid=k_mid, n_views=n_views,
                    area_px=total * wgt,
                    x_center=W * (0.5 + (slot + rng.uniform(-0.2, 1.2))
                                  / n_objects) / 2)
                for wgt, slot in zip(weights, slots)]
        objs.sort(key=lambda o: -o.z)  # far to near
        images, masks = [None] * n_views, [None] * n_views
        for i in order:
            img, mask = statics[i].copy(), np.zeros((H, W), bool)
            singles = []
            for obj in objs:
                anchor = _object_anchor(geo, obj, rotations[i], centers[i], i - ref)
                single = np.zeros((H, W), bool)
                _draw_object(geo, obj, anchor, i - ref, img, single)
                singles.append(single)
                mask |= single
            images[i], masks[i] = img, mask
            if i == ref and not _ref_ok(singles, mask, img, statics[ref]):
                break
            if not mask.any():
                break
        else:
            if _uncovered_ok(masks, ref):
                return images, masks
    raise RuntimeError("could not place the moving objects; try another seed")


def _ref_ok(singles, mask, image, background):
    """Objects lie inside the reference, apart, cover 3-12 %, stand out."""
    for single in singles:
        if single[0].any() or single[-1].any() or single[:, 0].any() \
                or single[:, -1].any():
            return False
    if sum(int(m.sum()) for m in singles) != int(mask.sum()):
        return False  # the objects overlap in the reference
    if not 0.03 <= mask.mean() <= 0.12:
        return False
    diff = np.abs(image.astype(np.int16) - background.astype(np.int16))
    return bool(diff[mask].mean() > 25.0)


def _uncovered_ok(masks, ref):
    """At most one other view covers half of the reference object region."""
    m_ref = masks[ref]
    n_ref = m_ref.sum()
    covered = [(m_ref & m).sum() >= 0.5 * n_ref
               for i, m in enumerate(masks) if i != ref]
    return sum(covered) <= 1

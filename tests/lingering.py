"""Synthetic scenes where a mover stands still in some views (a "lingering" mover).

Built from ``evaluation.synth`` scenes: a view's mover is warped into other
views by the homography of the scene layer it stands on, so that it shows on the
same scene spot there. Used by tests/test_select.py and tests/test_debugger.py.
"""

from __future__ import annotations

import cv2
import numpy as np


def _foot_layer(sc, view):
    """The scene layer under the lowest point of ``view``'s mover (where it stands)."""
    m = sc.masks[view]
    ys, xs = np.nonzero(m)
    foot = np.float32([[[np.median(xs[ys >= ys.max() - 3]), min(ys.max() + 3, m.shape[0] - 1)]]])
    for layer, h in enumerate(sc.layer_homographies[view]):
        x, y = cv2.perspectiveTransform(foot, np.linalg.inv(h))[0, 0]  # in the reference
        if 0 <= y < m.shape[0] and 0 <= x < m.shape[1] and sc.layer_ids[int(y), int(x)] == layer:
            return layer
    raise AssertionError(f"no layer under view {view}'s mover")


def warp_mover(sc, frm, to):
    """View ``frm``'s mover (image, mask) as it shows in view ``to`` if it stood still."""
    layer = _foot_layer(sc, frm)
    Hs = sc.layer_homographies
    h_ft = Hs[to, layer] @ np.linalg.inv(Hs[frm, layer])
    size = sc.masks[frm].shape[::-1]
    mask = cv2.warpPerspective(sc.masks[frm].astype(np.uint8) * 255, h_ft, size) > 127
    return cv2.warpPerspective(sc.images[frm], h_ft, size), mask


def paste_at_same_spot(sc, frm, to, *, dx=0):
    """The scene's images with view ``frm``'s mover standing still in the views ``to``
    (or, with ``dx``, moved by that many pixels to the right there: one that barely
    moved)."""
    out = [im.copy() for im in sc.images]
    shift = np.float32([[1, 0, dx], [0, 1, 0]])
    for k in to:
        img, mask = warp_mover(sc, frm, k)
        if dx:
            size = mask.shape[::-1]
            img = cv2.warpAffine(img, shift, size)
            mask = cv2.warpAffine(mask.astype(np.uint8), shift, size) > 0
        out[k][mask] = img[mask]
    return out


def with_cast_shadow(sc, linger, *, dx=30, dy=20, factor=0.7):
    """The reference's mover standing still in the views ``linger``, casting a shadow
    there and in the reference: its mask shifted by (dx, dy) px darkens the scene by
    ``factor`` (moved into each view by the homography of the layer it stands on).
    Returns the images and the shadow's mask in the reference (outside the mover)."""
    ref = sc.ref_index
    m = sc.masks[ref]
    shadow = np.zeros_like(m)
    shadow[dy:, dx:] = m[:-dy, :-dx]
    shadow = cv2.erode(shadow.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~m
    out = paste_at_same_spot(sc, ref, linger)
    layer = _foot_layer(sc, ref)
    Hs = sc.layer_homographies
    for k in [ref, *linger]:
        h = Hs[k, layer] @ np.linalg.inv(Hs[ref, layer])
        s = cv2.warpPerspective(shadow.astype(np.uint8) * 255, h, m.shape[::-1]) > 127
        s &= ~(m if k == ref else warp_mover(sc, ref, k)[1])
        out[k][s] = (out[k][s] * factor).astype(np.uint8)
    return out, shadow


def with_faint_shadow(sc, *, darken=0.12, dx=30, dy=20):
    """The reference's mover casts a soft shadow on the ground beside it, in the
    reference only: its mask shifted by (dx, dy) px, blurred (σ 2 px), darkens the
    ground by ``darken`` at its core (12 %: about 4-6 CIE L* on the scene's ground,
    under select_tau). Returns the images, the shadow's mask and its core (where
    the blurred mask is over 0.9)."""
    ref = sc.ref_index
    m = sc.masks[ref]
    s = np.zeros_like(m)
    s[dy:, dx:] = m[:-dy, :-dx]
    s = cv2.erode(s.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~m
    soft = cv2.GaussianBlur(s.astype(np.float32), (0, 0), 2.0)
    ims = [im.copy() for im in sc.images]
    gain = 1.0 - darken * soft
    ims[ref] = np.clip(ims[ref] * gain[..., None] + 0.5, 0, 255).astype(np.uint8)
    return ims, s, s & (soft > 0.9)

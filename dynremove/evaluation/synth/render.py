"""Planar textured layers of the synthetic scenes and their rendering into views."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.evaluation.synth.camera import CAMERA_HEIGHT, SceneGeometry, plane_extent, rays
from dynremove.evaluation.synth.textures import (Uint8Image, backdrop_texture, box_texture,
                                                 ground_texture, sky_texture)

_SUPERSAMPLE = 2  # static layers are rendered at this many samples per pixel side
_PSF_SIGMA = 0.5  # lens blur (Gaussian sigma, pixels) of the static render


@dataclass(frozen=True)
class Layer:
    """A textured planar patch: texel ``(u, v)`` sits at ``P0 + u a + v b``.

    For ``at_infinity`` layers ``P0 + u a + v b`` is a direction.
    """

    name: str
    texture: np.ndarray  # (h, w, 3) uint8
    alpha: np.ndarray | None  # (h, w) uint8, None = opaque
    p0: np.ndarray  # (3,)
    a: np.ndarray  # (3,) world step per texel column
    b: np.ndarray  # (3,) world step per texel row
    full_frame: bool = False  # covers every view: warp the whole frame
    at_infinity: bool = False
    # True: mirror texture and alpha past the edges (only for layers whose
    # texel coordinates stay bounded: no horizon in view). False: replicate
    # the texture, alpha 0 outside.
    reflect: bool = False


def plane_to_image(layer: Layer, geo: SceneGeometry, R, C) -> np.ndarray:
    """Homography from texel ``(u, v, 1)`` of ``layer`` to a view's pixels."""
    origin = layer.p0 if layer.at_infinity else layer.p0 - C
    return geo.K @ R @ np.column_stack([layer.a, layer.b, origin])


def build_layers(rng, geo, rotations, centers) -> list[Layer]:
    """Sky, backdrop, ground and boxes, far to near."""
    f, d, h, s = geo.f, geo.d_far, CAMERA_HEIGHT, geo.scale
    pad = 6
    kinv = np.linalg.inv(geo.K)
    layers = []

    # sky: plane at infinity, one texel per reference pixel
    a_sky, b_sky = kinv[:, 0], kinv[:, 1]
    u0, v0, u1, v1 = plane_extent(geo, rotations, centers, kinv[:, 2], a_sky,
                                   b_sky, at_infinity=True)
    u0, v0 = np.floor(u0) - pad, np.floor(v0) - pad
    sw, sh = int(np.ceil(u1 - u0)) + pad, int(np.ceil(v1 - v0)) + pad
    p0 = kinv @ np.array([u0, v0, 1.0])
    layers.append(Layer("sky", sky_texture(rng, sh, sw, geo, v0), None, p0, a_sky,
                         b_sky, full_frame=True, at_infinity=True, reflect=True))

    # backdrop: plane z = d, 1:1 in the reference
    st = d / f
    a_bd, b_bd = np.array([st, 0.0, 0.0]), np.array([0.0, st, 0.0])
    u0, v0, u1, v1 = plane_extent(geo, rotations, centers, np.array([0, 0, d]),
                                   a_bd, b_bd)
    v1 = min(v1, h / st + 3 * pad)  # below the ground line it is never seen
    u0, v0 = np.floor(u0) - pad, np.floor(v0) - pad
    bw, bh = int(np.ceil(u1 - u0)) + pad, int(np.ceil(v1 - v0)) + pad
    p0 = np.array([u0 * st, v0 * st, d])
    ground_row = (h - p0[1]) / st  # texel row of the ground line
    tex, alpha = backdrop_texture(rng, bh, bw, s, ground_row)
    layers.append(Layer("backdrop", tex, alpha, p0, a_bd, b_bd, full_frame=True,
                         reflect=True))

    # ground: plane y = h, texel size matched at the geometric mean depth
    z_bottom = geo.depth_of_ground_row(geo.H - 1)
    sg = np.sqrt(z_bottom * d) / f
    x_lo = (u0 * st) - 2 * sg * pad
    x_hi = (u0 + bw) * st + 2 * sg * pad
    bottom = np.array([[0, geo.H - 1], [(geo.W - 1) / 2, geo.H - 1],
                       [geo.W - 1, geo.H - 1]], float)
    z_min = np.inf
    for R, C in zip(rotations, centers):
        origin, dirs = rays(geo, R, C, bottom)
        lam = (h - origin[1]) / dirs[:, 1]
        z_min = min(z_min, float((origin[2] + lam * dirs[:, 2]).min()))
    z_far = d + pad * sg
    gw = int(np.ceil((x_hi - x_lo) / sg))
    gh = int(np.ceil((z_far - (z_min - pad * sg)) / sg))
    p0 = np.array([x_lo, h, z_far])
    a_g, b_g = np.array([sg, 0.0, 0.0]), np.array([0.0, 0.0, -sg])
    z_rows = z_far - sg * np.arange(gh)
    g_alpha = np.clip((d - z_rows) / sg + 0.5, 0.0, 1.0)
    g_alpha = np.repeat((255 * g_alpha).astype(np.uint8)[:, None], gw, axis=1)
    minify = z_rows / (sg * f)  # texels per pixel
    tex = ground_texture(rng, gh, gw, s * (sg * f) / d, minify)
    # alpha 0 outside: above the horizon the homography hits the ground
    # behind the camera
    layers.append(Layer("ground", tex, g_alpha, p0, a_g, b_g, full_frame=True))

    # boxes / pillars on the ground, nearer than the backdrop, behind objects
    z_lo = geo.depth_of_ground_row(0.8 * geo.H) + 0.05 * d
    z_hi = 0.8 * d
    n_boxes = int(rng.integers(2, 5))
    slots = np.linspace(z_lo, z_hi, n_boxes + 1)
    c_max = np.abs(centers[:, 0]).max() + 0.05 * d
    boxes = []
    for k in range(n_boxes):
        zf = rng.uniform(slots[k], slots[k] + 0.3 * (slots[k + 1] - slots[k]))
        depth = rng.uniform(0.3, 0.65) * (slots[k + 1] - zf)
        width_w = rng.uniform(0.07, 0.18) * geo.W * zf / f
        xc = (rng.uniform(0.05, 0.95) * geo.W - geo.cx) * zf / f
        tall = rng.random() < 0.5
        height_w = h * (rng.uniform(1.3, 2.4) if tall else rng.uniform(0.3, 0.7))
        boxes.append((zf, depth, xc, width_w, height_w, tall, k))
    for zf, depth, xc, width_w, height_w, tall, k in sorted(boxes, reverse=True):
        layers.extend(_box_layers(rng, geo, zf, depth, xc, width_w, height_w,
                                  tall, c_max, f"box{k}"))
    return layers


def _box_layers(rng, geo, zf, depth, xc, width_w, height_w, tall, c_max, name):
    """Visible faces (top, side, front) of a box standing on the ground."""
    h = CAMERA_HEIGHT
    st = zf / geo.f
    xl, xr, y_top = xc - width_w / 2, xc + width_w / 2, h - height_w
    nw, nh, nd = (max(2, int(round(v / st))) for v in (width_w, height_w, depth))
    style = "crate" if (not tall and rng.random() < 0.7) else "concrete"
    palette_seed = int(rng.integers(1 << 31))
    out = []
    if height_w < h - 0.2:  # camera looks down on the top face
        tex = box_texture(np.random.default_rng(palette_seed), nd, nw, style, 1.15,
                       geo.scale)
        out.append(Layer(f"{name}.top", tex, _opaque(nd, nw),
                          np.array([xl, y_top, zf + depth]),
                          np.array([st, 0, 0.0]), np.array([0, 0, -st])))
    if abs(xc) - width_w / 2 > c_max:  # a side face stays visible in all views
        x_side = xl if xc > 0 else xr
        tex = box_texture(np.random.default_rng(palette_seed + 1), nh, nd, style,
                       0.7, geo.scale)
        sign = 1.0 if xc > 0 else -1.0
        p0 = np.array([x_side, y_top, zf if sign > 0 else zf + depth])
        out.append(Layer(f"{name}.side", tex, _opaque(nh, nd), p0,
                          np.array([0, 0, sign * st]), np.array([0, st, 0.0])))
    tex = box_texture(np.random.default_rng(palette_seed), nh, nw, style, 1.0,
                   geo.scale)
    out.append(Layer(f"{name}.front", tex, _opaque(nh, nw),
                      np.array([xl, y_top, zf]), np.array([st, 0, 0.0]),
                      np.array([0, st, 0.0])))
    return out


def _opaque(h, w):
    return np.full((h, w), 255, np.uint8)


def render_static(layers, geo, R, C, *, ids=None) -> Uint8Image:
    """One view of the static layers, as a camera records it.

    A sensor pixel integrates the light over its area and the lens blurs a
    little: the layers are composited at ``_SUPERSAMPLE``× resolution,
    area-averaged down and blurred by a ``_PSF_SIGMA`` px Gaussian. Without
    this, each view point-samples the textures at different sub-pixel phases
    and the views disagree by aliasing alone (measured: the background copied
    through the exact correspondences reaches 27-29 dB PSNR instead of 31-35).
    """
    s = _SUPERSAMPLE
    if s == 1:
        return np.clip(composite_layers(layers, geo, R, C, ids=ids) + 0.5, 0, 255).astype(np.uint8)
    # pixel x of the view covers samples s x .. s x + s - 1, centred at s x + (s - 1) / 2
    A = np.array([[s, 0.0, (s - 1) / 2.0], [0.0, s, (s - 1) / 2.0], [0.0, 0.0, 1.0]])
    fine = SceneGeometry(geo.H * s, geo.W * s, geo.f * s, A @ geo.K, geo.d_far, geo.scale)
    fine_ids = None if ids is None else np.zeros((fine.H, fine.W), np.uint8)
    acc = composite_layers(layers, fine, R, C, ids=fine_ids)
    acc = cv2.resize(acc, (geo.W, geo.H), interpolation=cv2.INTER_AREA)
    if _PSF_SIGMA > 0:
        acc = cv2.GaussianBlur(acc, (0, 0), _PSF_SIGMA, borderType=cv2.BORDER_REFLECT)
    if ids is not None:
        ids[...] = fine_ids[s // 2::s, s // 2::s]
    return np.clip(acc + 0.5, 0, 255).astype(np.uint8)


def composite_layers(layers, geo, R, C, *, ids=None) -> npt.NDArray[np.float32]:
    """Composite the static layers far to near at ``geo``'s resolution, float32."""
    H, W = geo.H, geo.W
    acc = np.zeros((H, W, 3), np.float32)
    flags = cv2.INTER_LINEAR
    for lid, lay in enumerate(layers):
        G = plane_to_image(lay, geo, R, C)
        if lay.full_frame:
            x0, y0, x1, y1 = 0, 0, W, H
        else:
            th, tw = lay.texture.shape[:2]
            q = G @ np.array([[0, tw, tw, 0], [0, 0, th, th], [1, 1, 1, 1.0]])
            q = q[:2] / q[2]
            x0 = max(int(np.floor(q[0].min())) - 1, 0)
            y0 = max(int(np.floor(q[1].min())) - 1, 0)
            x1 = min(int(np.ceil(q[0].max())) + 2, W)
            y1 = min(int(np.ceil(q[1].max())) + 2, H)
            if x1 <= x0 or y1 <= y0:
                continue
        border = cv2.BORDER_REFLECT if lay.reflect else cv2.BORDER_REPLICATE
        M = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]]) @ G
        dsize = (x1 - x0, y1 - y0)
        # optics: band-limit the texture (σ 0.8 texel) so that every view samples
        # the same continuous surface; without it bilinear resampling of
        # texel-level grain differs from view to view (≈ 25 dB between views)
        tex = cv2.warpPerspective(cv2.GaussianBlur(lay.texture, (0, 0), 0.8), M, dsize,
                                  flags=flags, borderMode=border).astype(np.float32)
        view = acc[y0:y1, x0:x1]
        if lay.alpha is None:
            view[...] = tex
            if ids is not None:
                ids[y0:y1, x0:x1] = lid
            continue
        a_border = border if lay.reflect else cv2.BORDER_CONSTANT
        alpha = cv2.warpPerspective(lay.alpha, M, dsize, flags=flags,
                                    borderMode=a_border, borderValue=0)
        view += (tex - view) * (alpha.astype(np.float32) * (1.0 / 255.0))[..., None]
        if ids is not None:
            ids[y0:y1, x0:x1][alpha >= 128] = lid
    return acc

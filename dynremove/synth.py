"""Synthetic hand-held multi-view scenes with exact ground truth.

Scene model
-----------
A pinhole camera (focal length ``f = 0.85 max(H, W)`` pixels, principal point
at the image centre) photographs a static outdoor scene ``V`` times, while one
to three "people" or "animals" walk through it. World coordinates are the
camera coordinates of the reference view: ``x`` right, ``y`` down, ``z``
forward. View ``i`` has rotation ``R_i`` and centre ``C_i`` and projects a
world point ``X`` to ``x ~ K R_i (X - C_i)``; the reference view has
``R = I``, ``C = 0``.

The static scene is a set of textured planar layers, composited far to near
(painter's order, antialiased alpha):

0. ``sky``: a plane at infinity (gradient and clouds), moves by ``K R_i K^-1``;
1. ``backdrop``: a fronto-parallel plane at depth ``d`` (a street of buildings
   or a hillside) with an irregular skyline;
2. ``ground``: the plane ``y = h`` below the camera (gravel or paving), seen
   in perspective, meeting the backdrop at depth ``d``;
3. ``box<k>.<face>``: two to four crates / pillars standing on the ground,
   nearer than the backdrop; each visible face is its own plane.

Every planar layer maps the reference image to view ``i`` by its
plane-induced homography. For a plane ``n^T X = d`` (reference frame),

.. math:: H_i = K R_i (I - C_i n^T / d) K^{-1} = K (R_i + t_i n^T / d) K^{-1},

with ``t_i = -R_i C_i``. The near layers therefore move differently from the
far ones (real parallax) and no single homography aligns a whole view. Each
layer is rendered from a texture larger than the union of all view frusta, so
no view has an empty border.

The camera walks sideways with hand-held jitter: the backdrop moves by about
4 px per view at 640 px width from translation, plus ``camera_shake_px`` of
rotation shake; the ground near the image bottom moves about three times as
much. ``parallax`` scales the translation (``0`` gives a pure rotation).

Each view of the static layers is rendered as a camera records it: at 2×
resolution, area-averaged to the pixel grid (a sensor pixel integrates light
over its area) and blurred by a σ 0.5 px lens, so that the views sample one
continuous, band-limited scene instead of aliasing differently.

Moving objects are drawn last, hard-edged (no antialiasing), so the
ground-truth mask of a view is exactly the set of pixels they cover. Each
walks along the ground at a constant image speed of 0.8 to 1 of its own width
per view, so the background it hides in the reference is uncovered in other
views. A scene is resampled (from the same generator) until every view shows an
object, the objects cover 3-12 % of the reference and lie fully inside it, and
at most one non-reference view covers half of the reference object region.

Textures are procedural: multi-octave value noise coloured through random
palettes, plus irregular bricks, windows, stones, planks, posters and cracks, so
keypoint detectors find hundreds of non-periodic features.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

__all__ = ["Scene", "make_scene", "write_scene", "reference_flow"]

_CAMERA_HEIGHT = 1.5  # h : camera height above the ground plane (world units)
_FOCAL_FACTOR = 0.85  # f = _FOCAL_FACTOR * max(H, W) pixels (about 60 deg FOV)
_STEP_FACTOR = 0.009  # sideways camera step per view, as a fraction of d
_SHAKE_REF_PX = 640.0  # camera_shake_px is given for this image size
_MAX_ATTEMPTS = 200  # object placements tried before giving up
_SUPERSAMPLE = 2  # static layers are rendered at this many samples per pixel side
_PSF_SIGMA = 0.5  # lens blur (Gaussian sigma, pixels) of the static render

Uint8Image = npt.NDArray[np.uint8]


@dataclass(frozen=True, eq=False)
class Scene:
    """A synthetic multi-view image set with ground truth.

    Attributes
    ----------
    images : list of (H, W, 3) uint8 ndarray
        The ``V`` views, BGR.
    masks : list of (H, W) bool ndarray
        Ground-truth dynamic masks: True where a moving object is drawn.
    background : (H, W, 3) uint8 ndarray
        The reference view rendered without moving objects. It equals
        ``images[ref_index]`` wherever ``masks[ref_index]`` is False.
    ref_index : int
        Index of the reference view.
    names : list of str
        File names, ``["view0.png", ...]``.
    seed : int
        Seed the scene was generated from.
    layer_ids : (H, W) uint8 ndarray or None
        Static layer visible at each pixel of ``background`` (an index into
        ``layer_names``; moving objects are not included, see ``masks``).
    layer_names : tuple of str
        Names of the static layers, far to near (``"sky"``, ``"backdrop"``,
        ``"ground"``, ``"box0.front"``, ...).
    layer_homographies : (V, L, 3, 3) float64 ndarray or None
        ``layer_homographies[i, l]`` maps a reference pixel ``(x, y, 1)`` of
        layer ``l`` to its position in view ``i`` (identity for the reference).
    K : (3, 3) float64 ndarray or None
        Camera intrinsics (shared by all views).
    rotations : (V, 3, 3) float64 ndarray or None
        World-to-camera rotations ``R_i``; world = reference camera frame.
    centers : (V, 3) float64 ndarray or None
        Camera centres ``C_i``; a point projects to ``K R_i (X - C_i)``.
    """

    images: list[Uint8Image]
    masks: list[npt.NDArray[np.bool_]]
    background: Uint8Image
    ref_index: int
    names: list[str]
    seed: int
    layer_ids: Uint8Image | None = None
    layer_names: tuple[str, ...] = ()
    layer_homographies: npt.NDArray[np.float64] | None = None
    K: npt.NDArray[np.float64] | None = None
    rotations: npt.NDArray[np.float64] | None = None
    centers: npt.NDArray[np.float64] | None = None


# --------------------------------------------------------------------------- #
# public API
# --------------------------------------------------------------------------- #
def make_scene(
    *,
    seed: int = 0,
    n_views: int = 6,
    size: tuple[int, int] = (360, 640),
    n_objects: int = 2,
    ref_index: int | None = None,
    parallax: float = 1.0,
    camera_shake_px: float = 12.0,
) -> Scene:
    """Render a synthetic hand-held image set with moving objects.

    Parameters
    ----------
    seed : int, optional
        Seed of the generator; the same seed gives byte-identical images.
    n_views : int, optional
        Number of views ``V`` (>= 2).
    size : (int, int), optional
        Image size ``(H, W)``, at least ``(48, 64)``.
    n_objects : int, optional
        Number of moving objects, 1 to 3.
    ref_index : int or None, optional
        Index of the reference view; ``None`` means ``V // 2``.
    parallax : float, optional
        Scale of the camera translation (>= 0). ``1`` moves the backdrop by
        about 4 px per view (at 640 px width) and the near ground by about
        three times as much; ``0`` gives a pure rotation.
    camera_shake_px : float, optional
        Amplitude of the rotational hand shake, as an image shift in pixels
        for a 640 px image (scaled with ``max(H, W) / 640``), >= 0.

    Returns
    -------
    Scene
        Images, exact dynamic masks, the clean reference and the camera and
        layer ground truth.

    Raises
    ------
    ValueError
        If an argument is out of range.

    Examples
    --------
    >>> scene = make_scene(seed=1, n_views=5, size=(96, 128))
    >>> len(scene.images), scene.images[0].shape, scene.masks[0].dtype
    (5, (96, 128, 3), dtype('bool'))
    >>> ref = scene.ref_index
    >>> bool((scene.background == scene.images[ref])[~scene.masks[ref]].all())
    True
    """
    height, width, ref = _validate(
        seed, n_views, size, n_objects, ref_index, parallax, camera_shake_px
    )
    rng = np.random.default_rng(seed)
    geo = _Geometry.sample(rng, height, width)
    rotations, centers = _sample_cameras(
        rng, geo, n_views, ref, parallax=parallax, shake_px=camera_shake_px
    )
    layers = _build_layers(rng, geo, rotations, centers)
    statics = []
    layer_ids = np.zeros((height, width), np.uint8)
    for i in range(n_views):
        img = _render_static(layers, geo, rotations[i], centers[i],
                             ids=layer_ids if i == ref else None)
        statics.append(img)
    homs = np.stack([
        np.stack([_plane_to_image(lay, geo, rotations[i], centers[i])
                  @ np.linalg.inv(_plane_to_image(lay, geo, rotations[ref],
                                                  centers[ref]))
                  for lay in layers])
        for i in range(n_views)
    ])
    homs /= homs[:, :, 2:3, 2:3]
    images, masks = _place_objects(rng, geo, rotations, centers, statics, ref,
                                   n_objects)
    return Scene(
        images=images,
        masks=masks,
        background=statics[ref],
        ref_index=ref,
        names=[f"view{i}.png" for i in range(n_views)],
        seed=int(seed),
        layer_ids=layer_ids,
        layer_names=tuple(lay.name for lay in layers),
        layer_homographies=homs,
        K=geo.K.copy(),
        rotations=rotations,
        centers=centers,
    )


def write_scene(scene: Scene, out_dir: Path) -> None:
    """Write a scene in the evaluation layout.

    Writes ``out_dir/frames/<name>``, ``out_dir/masks/<stem>.png`` (uint8,
    0 or 255) and ``out_dir/background.png`` (the clean reference view).

    Parameters
    ----------
    scene : Scene
        Scene from :func:`make_scene`.
    out_dir : Path
        Output directory, created if missing.

    Raises
    ------
    OSError
        If an image cannot be written.
    """
    out_dir = Path(out_dir)
    (out_dir / "frames").mkdir(parents=True, exist_ok=True)
    (out_dir / "masks").mkdir(parents=True, exist_ok=True)
    files = [(out_dir / "background.png", scene.background)]
    for name, img, mask in zip(scene.names, scene.images, scene.masks):
        files.append((out_dir / "frames" / name, img))
        mask_u8 = mask.astype(np.uint8) * np.uint8(255)
        files.append((out_dir / "masks" / (Path(name).stem + ".png"), mask_u8))
    for path, img in files:
        if not cv2.imwrite(str(path), img):
            raise OSError(f"could not write {path}")


def reference_flow(scene: Scene, view: int) -> npt.NDArray[np.float32]:
    """Positions in ``view`` of the static surface seen at each reference pixel.

    Uses ``layer_ids`` and ``layer_homographies``, so it is also defined under
    the moving objects (for the background they hide). It ignores occlusion
    in ``view``.

    Parameters
    ----------
    scene : Scene
        Scene from :func:`make_scene`.
    view : int
        Target view index, ``0 <= view < V``.

    Returns
    -------
    (H, W, 2) float32 ndarray
        ``(x, y)`` in ``view`` of reference pixel ``[y, x]``.
    """
    if scene.layer_ids is None or scene.layer_homographies is None:
        raise ValueError("scene has no layer ground truth (layer_ids is None)")
    n_views = scene.layer_homographies.shape[0]
    if not 0 <= view < n_views:
        raise ValueError(f"view must be in [0, {n_views}), got {view}")
    height, width = scene.layer_ids.shape
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    pts = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    out = np.empty((height, width, 2), np.float32)
    for lid in np.unique(scene.layer_ids):
        sel = scene.layer_ids == lid
        q = pts[sel] @ scene.layer_homographies[view, lid].T
        out[sel] = q[:, :2] / q[:, 2:3]
    return out


# --------------------------------------------------------------------------- #
# validation, geometry, cameras
# --------------------------------------------------------------------------- #
def _validate(seed, n_views, size, n_objects, ref_index, parallax, shake):
    """Check ``make_scene`` arguments; return ``(H, W, ref)``."""
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    if not isinstance(n_views, (int, np.integer)) or n_views < 2:
        raise ValueError(f"n_views must be an int >= 2, got {n_views!r}")
    if not isinstance(n_objects, (int, np.integer)) or not 1 <= n_objects <= 3:
        raise ValueError(f"n_objects must be an int in [1, 3], got {n_objects!r}")
    try:
        height, width = (int(s) for s in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (H, W), got {size!r}") from None
    if height < 48 or width < 64:
        raise ValueError(f"size (H, W) must be at least (48, 64), got {size!r}")
    ref = n_views // 2 if ref_index is None else ref_index
    if not isinstance(ref, (int, np.integer)) or not 0 <= ref < n_views:
        raise ValueError(f"ref_index must be in [0, {n_views}), got {ref_index!r}")
    if not np.isfinite(parallax) or parallax < 0:
        raise ValueError(f"parallax must be finite and >= 0, got {parallax!r}")
    if not np.isfinite(shake) or shake < 0:
        raise ValueError(f"camera_shake_px must be finite and >= 0, got {shake!r}")
    return height, width, int(ref)


@dataclass(frozen=True)
class _Geometry:
    """Image size, intrinsics and the depths that lay out the scene."""

    H: int
    W: int
    f: float
    K: np.ndarray  # (3, 3)
    d_far: float  # depth of the backdrop plane
    scale: float  # max(H, W) / 640: pixel sizes of texture features

    @staticmethod
    def sample(rng: np.random.Generator, height: int, width: int) -> _Geometry:
        f = _FOCAL_FACTOR * max(height, width)
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        y_ground = rng.uniform(0.6, 0.7) * height  # backdrop meets the ground
        d_far = f * _CAMERA_HEIGHT / (y_ground - cy)
        return _Geometry(height, width, f, K, d_far, max(height, width) / 640.0)

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def depth_of_ground_row(self, row: float) -> float:
        """Depth of the ground plane seen at image row ``row`` (reference)."""
        return self.f * _CAMERA_HEIGHT / (row - self.cy)


def _sample_cameras(rng, geo, n_views, ref, *, parallax, shake_px):
    """Sideways walk with hand-held jitter; ``(V, 3, 3)`` R and ``(V, 3)`` C.

    A view is redrawn (same generator) while its backdrop motion at the image
    centre is below ``0.4 (shake + step)``, so no view is a near-duplicate.
    """
    step = parallax * _STEP_FACTOR * geo.d_far
    direction = rng.choice([-1.0, 1.0])
    ang = shake_px * geo.scale / geo.f  # rotation giving ``shake`` px shift
    roll = 0.3 * shake_px * geo.scale / (0.5 * max(geo.H, geo.W))
    min_motion = 0.4 * (shake_px * geo.scale + geo.f * step / geo.d_far)
    centre = np.array([geo.cx, geo.cy, 1.0])
    rotations = np.tile(np.eye(3), (n_views, 1, 1))
    centers = np.zeros((n_views, 3))
    for i in range(n_views):
        if i == ref:
            continue
        for _ in range(50):
            jitter = rng.uniform(-1, 1, 3) * np.array([0.3, 0.2, 0.5])
            omega = rng.uniform(-1, 1, 3) * np.array([ang, ang, roll])
            C = step * (np.array([direction * (i - ref), 0.0, 0.0]) + jitter)
            R = cv2.Rodrigues(omega.reshape(3, 1))[0]
            q = _plane_homography(geo, R, C, np.array([0, 0, 1.0]), geo.d_far) @ centre
            if np.hypot(*(q[:2] / q[2] - centre[:2])) >= min_motion:
                break
        rotations[i], centers[i] = R, C
    return rotations, centers


def _plane_homography(geo, R, C, normal, dist):
    """Reference-to-view homography of the plane ``normal . X = dist``.

    ``H = K R (I - C n^T / d) K^-1``, equivalently ``K (R + t n^T / d) K^-1``
    with ``t = -R C``.
    """
    kinv = np.linalg.inv(geo.K)
    return geo.K @ R @ (np.eye(3) - np.outer(C, normal) / dist) @ kinv


# --------------------------------------------------------------------------- #
# planar layers
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class _Layer:
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


def _plane_to_image(layer: _Layer, geo: _Geometry, R, C) -> np.ndarray:
    """Homography from texel ``(u, v, 1)`` of ``layer`` to a view's pixels."""
    origin = layer.p0 if layer.at_infinity else layer.p0 - C
    return geo.K @ R @ np.column_stack([layer.a, layer.b, origin])


def _rays(geo, R, C, pts_xy):
    """World rays (origin, directions (N, 3)) through pixels of a view."""
    pix = np.column_stack([pts_xy, np.ones(len(pts_xy))])
    dirs = (R.T @ np.linalg.inv(geo.K) @ pix.T).T
    return C, dirs


def _plane_extent(geo, rotations, centers, p0, a, b, *, at_infinity=False):
    """Bounding box ``(u0, v0, u1, v1)`` in texels of what the views see.

    Only for planes with no horizon in view (the preimage of the image
    rectangle is then the quadrilateral of its corners' preimages).
    """
    w, h = geo.W - 1, geo.H - 1
    pts_xy = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    uv = []
    for R, C in zip(rotations, centers):
        origin, dirs = _rays(geo, R, C, pts_xy)
        rhs = -p0 if at_infinity else origin - p0
        for d in dirs:
            sol = np.linalg.solve(np.column_stack([a, b, -d]), rhs)
            uv.append(sol[:2])
    uv = np.array(uv)
    return uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()


def _build_layers(rng, geo, rotations, centers) -> list[_Layer]:
    """Sky, backdrop, ground and boxes, far to near."""
    f, d, h, s = geo.f, geo.d_far, _CAMERA_HEIGHT, geo.scale
    pad = 6
    kinv = np.linalg.inv(geo.K)
    layers = []

    # sky: plane at infinity, one texel per reference pixel
    a_sky, b_sky = kinv[:, 0], kinv[:, 1]
    u0, v0, u1, v1 = _plane_extent(geo, rotations, centers, kinv[:, 2], a_sky,
                                   b_sky, at_infinity=True)
    u0, v0 = np.floor(u0) - pad, np.floor(v0) - pad
    sw, sh = int(np.ceil(u1 - u0)) + pad, int(np.ceil(v1 - v0)) + pad
    p0 = kinv @ np.array([u0, v0, 1.0])
    layers.append(_Layer("sky", _tex_sky(rng, sh, sw, geo, v0), None, p0, a_sky,
                         b_sky, full_frame=True, at_infinity=True, reflect=True))

    # backdrop: plane z = d, 1:1 in the reference
    st = d / f
    a_bd, b_bd = np.array([st, 0.0, 0.0]), np.array([0.0, st, 0.0])
    u0, v0, u1, v1 = _plane_extent(geo, rotations, centers, np.array([0, 0, d]),
                                   a_bd, b_bd)
    v1 = min(v1, h / st + 3 * pad)  # below the ground line it is never seen
    u0, v0 = np.floor(u0) - pad, np.floor(v0) - pad
    bw, bh = int(np.ceil(u1 - u0)) + pad, int(np.ceil(v1 - v0)) + pad
    p0 = np.array([u0 * st, v0 * st, d])
    ground_row = (h - p0[1]) / st  # texel row of the ground line
    tex, alpha = _tex_backdrop(rng, bh, bw, s, ground_row)
    layers.append(_Layer("backdrop", tex, alpha, p0, a_bd, b_bd, full_frame=True,
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
        origin, dirs = _rays(geo, R, C, bottom)
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
    tex = _tex_ground(rng, gh, gw, s * (sg * f) / d, minify)
    # alpha 0 outside: above the horizon the homography hits the ground
    # behind the camera
    layers.append(_Layer("ground", tex, g_alpha, p0, a_g, b_g, full_frame=True))

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
    h = _CAMERA_HEIGHT
    st = zf / geo.f
    xl, xr, y_top = xc - width_w / 2, xc + width_w / 2, h - height_w
    nw, nh, nd = (max(2, int(round(v / st))) for v in (width_w, height_w, depth))
    style = "crate" if (not tall and rng.random() < 0.7) else "concrete"
    palette_seed = int(rng.integers(1 << 31))
    out = []
    if height_w < h - 0.2:  # camera looks down on the top face
        tex = _tex_box(np.random.default_rng(palette_seed), nd, nw, style, 1.15,
                       geo.scale)
        out.append(_Layer(f"{name}.top", tex, _opaque(nd, nw),
                          np.array([xl, y_top, zf + depth]),
                          np.array([st, 0, 0.0]), np.array([0, 0, -st])))
    if abs(xc) - width_w / 2 > c_max:  # a side face stays visible in all views
        x_side = xl if xc > 0 else xr
        tex = _tex_box(np.random.default_rng(palette_seed + 1), nh, nd, style,
                       0.7, geo.scale)
        sign = 1.0 if xc > 0 else -1.0
        p0 = np.array([x_side, y_top, zf if sign > 0 else zf + depth])
        out.append(_Layer(f"{name}.side", tex, _opaque(nh, nd), p0,
                          np.array([0, 0, sign * st]), np.array([0, st, 0.0])))
    tex = _tex_box(np.random.default_rng(palette_seed), nh, nw, style, 1.0,
                   geo.scale)
    out.append(_Layer(f"{name}.front", tex, _opaque(nh, nw),
                      np.array([xl, y_top, zf]), np.array([st, 0, 0.0]),
                      np.array([0, st, 0.0])))
    return out


def _opaque(h, w):
    return np.full((h, w), 255, np.uint8)


def _render_static(layers, geo, R, C, *, ids=None) -> Uint8Image:
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
        return np.clip(_composite(layers, geo, R, C, ids=ids) + 0.5, 0, 255).astype(np.uint8)
    # pixel x of the view covers samples s x .. s x + s - 1, centred at s x + (s - 1) / 2
    A = np.array([[s, 0.0, (s - 1) / 2.0], [0.0, s, (s - 1) / 2.0], [0.0, 0.0, 1.0]])
    fine = _Geometry(geo.H * s, geo.W * s, geo.f * s, A @ geo.K, geo.d_far, geo.scale)
    fine_ids = None if ids is None else np.zeros((fine.H, fine.W), np.uint8)
    acc = _composite(layers, fine, R, C, ids=fine_ids)
    acc = cv2.resize(acc, (geo.W, geo.H), interpolation=cv2.INTER_AREA)
    if _PSF_SIGMA > 0:
        acc = cv2.GaussianBlur(acc, (0, 0), _PSF_SIGMA, borderType=cv2.BORDER_REFLECT)
    if ids is not None:
        ids[...] = fine_ids[s // 2::s, s // 2::s]
    return np.clip(acc + 0.5, 0, 255).astype(np.uint8)


def _composite(layers, geo, R, C, *, ids=None) -> npt.NDArray[np.float32]:
    """Composite the static layers far to near at ``geo``'s resolution, float32."""
    H, W = geo.H, geo.W
    acc = np.zeros((H, W, 3), np.float32)
    flags = cv2.INTER_LINEAR
    for lid, lay in enumerate(layers):
        G = _plane_to_image(lay, geo, R, C)
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


# --------------------------------------------------------------------------- #
# procedural textures (float32 BGR in [0, 255] unless stated)
# --------------------------------------------------------------------------- #
def _fbm(rng, h, w, *, cell, octaves=5, persistence=0.55, min_cell=1.5):
    """Multi-octave value noise, ``(h, w)`` float32, roughly in ``[0, 1]``."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for _ in range(octaves):
        gh = int(np.ceil(h / cell)) + 2
        gw = int(np.ceil(w / cell)) + 2
        grid = rng.random((gh, gw), dtype=np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
        cell = max(cell / 2.0, min_cell)
    out -= out.mean()
    out *= 0.2 / (out.std() + 1e-6)
    return np.clip(out + 0.5, 0.0, 1.0)


def _hsv(h, s, v):
    """One BGR colour (float32, 0..255) from hue in degrees, s and v in [0, 1]."""
    px = np.array([[[(h % 360) / 2, s * 255, v * 255]]], np.float32)
    px = np.clip(px, 0, [179, 255, 255]).astype(np.uint8)
    return cv2.cvtColor(px, cv2.COLOR_HSV2BGR)[0, 0].astype(np.float32)


def _palette(rng, n, *, hue, hue_spread, sat, val):
    """``n`` colours ordered dark to light around ``hue``; ``(n, 3)`` float32."""
    vals = np.sort(rng.uniform(*val, n))
    return np.stack([_hsv(hue + rng.uniform(-hue_spread, hue_spread),
                          rng.uniform(*sat), v) for v in vals])


def _colorize(field, stops):
    """Map a ``[0, 1]`` field through colour stops; ``(h, w, 3)`` float32."""
    xs = np.linspace(0.0, 1.0, len(stops))
    t = np.linspace(0.0, 1.0, 256)
    lut = np.stack([np.interp(t, xs, stops[:, c]) for c in range(3)], axis=1)
    idx = np.clip(field * 255 + 0.5, 0, 255).astype(np.uint8)
    return lut.astype(np.float32)[idx]


def _shade(img, field, amount):
    """Multiply by ``1 + amount (field - 0.5)``."""
    return img * (1.0 + amount * (field - 0.5))[..., None]


def _bricks(rng, h, w, *, row_h, length, jitter=0.15):
    """Irregular running bond: ``(labels (h, w) int64, joint distance (h, w))``."""
    heights = []
    while sum(heights) < h + row_h:
        heights.append(row_h * rng.uniform(1 - jitter, 1 + jitter))
    edges_y = np.concatenate([[0.0], np.cumsum(heights)]) - rng.uniform(0, row_h)
    ys = np.arange(h) + 0.5
    row = np.searchsorted(edges_y, ys, side="right") - 1
    dy = np.minimum(ys - edges_y[row], edges_y[row + 1] - ys)
    xs = np.arange(w) + 0.5
    n_rows = len(heights)
    max_cols = int(w / (row_h * length[0])) + 3
    col = np.zeros((n_rows, w), np.int64)
    dx = np.zeros((n_rows, w), np.float32)
    for r in range(n_rows):
        widths = row_h * rng.uniform(*length, max_cols)
        ex = np.concatenate([[0.0], np.cumsum(widths)]) - rng.uniform(0, widths[0])
        c = np.searchsorted(ex, xs, side="right") - 1
        col[r] = c
        dx[r] = np.minimum(xs - ex[c], ex[c + 1] - xs)
    labels = row[:, None] * (max_cols + 1) + col[row]
    dist = np.minimum(dx[row], dy[:, None].astype(np.float32))
    return labels, dist


def _per_label(rng, labels):
    """One random value in ``[0, 1)`` per label, gathered to ``labels`` shape."""
    return rng.random(int(labels.max()) + 1, dtype=np.float32)[labels]


def _tex_sky(rng, h, w, geo, v0) -> Uint8Image:
    """Vertical gradient with soft clouds (reference-pixel texels)."""
    overcast = rng.random() < 0.3
    hue = rng.uniform(200, 225)
    top = _hsv(hue, 0.05 if overcast else rng.uniform(0.45, 0.7), 0.75)
    horizon = _hsv(hue, 0.03 if overcast else 0.2, 0.95)
    t = np.clip((np.arange(h) + v0) / max(geo.cy, 1.0), 0.0, 1.0)[:, None, None]
    img = top * (1 - t) + horizon * t
    small = (max(h // 4, 2), max(w // 4, 2))
    clouds = _fbm(rng, *small, cell=40 * geo.scale / 4, octaves=4)
    clouds = cv2.resize(clouds, (w, h), interpolation=cv2.INTER_LINEAR)
    cover = np.clip((clouds - rng.uniform(0.45, 0.6)) * 4.0, 0.0, 1.0)[..., None]
    img = img * (1 - cover) + np.float32(245.0) * cover
    return np.clip(img, 0, 255).astype(np.uint8)


def _tex_backdrop(rng, h, w, s, ground_row):
    """Street facade or hillside with a skyline; ``(texture, alpha)``."""
    fine = _fbm(rng, h, w, cell=6 * s, octaves=3)
    large = _fbm(rng, h, w, cell=90 * s, octaves=3)
    horizon = ground_row - rng.uniform(0.3, 0.55) * h  # mean skyline row
    if rng.random() < 0.6:  # town
        img = np.zeros((h, w, 3), np.float32)
        skyline = np.zeros(w, np.float32)
        x = 0
        while x < w:
            bw = int(rng.uniform(0.15, 0.45) * w) + 4
            sl = slice(x, min(x + bw, w))
            skyline[sl] = horizon + rng.uniform(-0.18, 0.12) * h
            img[:, sl] = _facade(rng, h, sl.stop - sl.start, s, skyline[x],
                                 ground_row, fine[:, sl])
            x += bw
    else:  # hillside
        prof = _fbm(rng, 8, w, cell=120 * s, octaves=4)[4]
        skyline = horizon + (prof - 0.5) * 0.35 * h
        stops = _palette(rng, 4, hue=rng.uniform(60, 110), hue_spread=25,
                         sat=(0.25, 0.55), val=(0.2, 0.65))
        img = _colorize(0.6 * large + 0.4 * fine, stops)
        n = int(h * w / (np.pi * (8 * s + 1) * (5.5 * s + 1))) + 1  # cover ~1x
        for _ in range(n):  # bushes and rocks
            c = (int(rng.integers(w)), int(rng.integers(h)))
            ax = (int(rng.uniform(2, 14) * s) + 1, int(rng.uniform(2, 9) * s) + 1)
            col = stops[rng.integers(len(stops))] * rng.uniform(0.6, 1.25)
            cv2.ellipse(img, c, ax, rng.uniform(0, 180), 0, 360,
                        col.tolist(), -1, cv2.LINE_AA)
        img = _shade(img, fine, 0.6)
    img = _shade(img, large, 0.35)
    rows = np.arange(h, dtype=np.float32)[:, None]
    alpha = np.clip(rows - skyline[None, :] + 0.5, 0.0, 1.0)
    tex = np.clip(img, 0, 255).astype(np.uint8)
    return tex, (255 * alpha + 0.5).astype(np.uint8)


def _facade(rng, h, w, s, top, ground_row, fine):
    """One building: bricks or plaster, irregular windows."""
    hue = rng.uniform(0, 50)
    if rng.random() < 0.5:
        labels, dist = _bricks(rng, h, w, row_h=max(3.0, rng.uniform(7, 11) * s),
                               length=(1.6, 3.2))
        stops = _palette(rng, 3, hue=hue, hue_spread=8, sat=(0.3, 0.6),
                         val=(0.35, 0.75))
        img = _colorize(0.55 * _per_label(rng, labels) + 0.45 * fine, stops)
        mortar = _hsv(hue, 0.08, rng.uniform(0.55, 0.8))
        t = np.clip(dist - 0.6 * max(s, 0.5), 0.0, 1.0)[..., None]
        img = img * t + mortar * (1 - t)
    else:
        stops = _palette(rng, 3, hue=hue + 20, hue_spread=15, sat=(0.05, 0.35),
                         val=(0.5, 0.9))
        img = _colorize(fine, stops)
    # windows on a jittered, irregular grid
    ww, wh = rng.uniform(10, 22) * s, rng.uniform(14, 28) * s
    frame = _hsv(rng.uniform(0, 360), rng.uniform(0, 0.3), rng.uniform(0.7, 0.95))
    y = top + rng.uniform(0.5, 1.5) * wh
    while y + wh < ground_row - 0.5 * wh:
        x = rng.uniform(0.2, 1.0) * ww
        while x + ww < w - 0.2 * ww:
            if rng.random() < 0.8:
                glass = _hsv(rng.uniform(180, 240), rng.uniform(0.1, 0.5),
                             rng.uniform(0.1, 0.45))
                if rng.random() < 0.15:
                    glass = _hsv(rng.uniform(35, 55), 0.5, 0.9)  # lit window
                p0 = (int(x), int(y))
                p1 = (int(x + ww * rng.uniform(0.8, 1.2)), int(y + wh))
                cv2.rectangle(img, p0, p1, frame.tolist(), -1)
                m = max(1, int(2 * s))
                cv2.rectangle(img, (p0[0] + m, p0[1] + m), (p1[0] - m, p1[1] - m),
                              glass.tolist(), -1)
            x += ww * rng.uniform(1.6, 2.6)
        y += wh * rng.uniform(1.6, 2.2)
    return img


def _tex_ground(rng, h, w, s, minify) -> Uint8Image:
    """Gravel or paving; rows far away are prefiltered (``minify`` per row)."""
    fine = _fbm(rng, h, w, cell=5 * s, octaves=3)
    large = _fbm(rng, h, w, cell=80 * s, octaves=3)
    hue = rng.uniform(20, 60)
    stops = _palette(rng, 4, hue=hue, hue_spread=15, sat=(0.1, 0.4),
                     val=(0.3, 0.75))
    if rng.random() < 0.5:  # gravel and pebbles
        img = _colorize(0.5 * large + 0.5 * fine, stops)
        n = int(0.32 * h * w / (np.pi * (4.25 * s + 1) * (3.25 * s + 1))) + 1
        cols = _palette(rng, 6, hue=hue, hue_spread=30, sat=(0.0, 0.3),
                        val=(0.3, 0.95))
        for _ in range(n):
            c = (int(rng.integers(w)), int(rng.integers(h)))
            ax = (int(rng.uniform(1.5, 7) * s) + 1, int(rng.uniform(1.5, 5) * s) + 1)
            ang = rng.uniform(0, 180)
            col = cols[rng.integers(len(cols))]
            cv2.ellipse(img, c, ax, ang, 0, 360, (col * 0.55).tolist(), -1)
            cv2.ellipse(img, c, (max(ax[0] - 1, 1), max(ax[1] - 1, 1)), ang, 0,
                        360, col.tolist(), -1)
        img = _shade(img, fine, 0.5)
    else:  # irregular flagstones
        labels, dist = _bricks(rng, h, w, row_h=max(4.0, rng.uniform(18, 30) * s),
                               length=(0.8, 2.0), jitter=0.3)
        img = _colorize(0.5 * _per_label(rng, labels) + 0.5 * fine, stops)
        gap = _hsv(rng.uniform(60, 100), rng.uniform(0.2, 0.5), rng.uniform(0.15, 0.35))
        t = np.clip(dist - 1.0 * max(s, 0.5), 0.0, 1.0)[..., None]
        img = img * t + gap * (1 - t)
        img = _shade(img, fine, 0.4)
    img = _shade(img, large, 0.4)
    # prefilter the far rows (one texel covers less than a pixel there)
    blurred = cv2.GaussianBlur(img, (0, 0), 1.2)
    wgt = np.clip(minify - 1.0, 0.0, 1.0).astype(np.float32)[:, None, None]
    img = img * (1 - wgt) + blurred * wgt
    return np.clip(img, 0, 255).astype(np.uint8)


def _tex_box(rng, h, w, style, light, s) -> Uint8Image:
    """Planked crate or concrete pillar with posters; ``light`` shades a face."""
    fine = _fbm(rng, h, w, cell=4 * s, octaves=3)
    if style == "crate":
        hue = rng.uniform(20, 45)
        stops = _palette(rng, 3, hue=hue, hue_spread=6, sat=(0.35, 0.6),
                         val=(0.35, 0.8))
        vertical = rng.random() < 0.5
        n_along = w if vertical else h
        plank = max(3.0, rng.uniform(7, 14) * s)
        edges = np.cumsum(plank * rng.uniform(0.7, 1.4, int(n_along / plank) + 3))
        idx = np.searchsorted(edges, np.arange(n_along) + 0.5)
        dist = np.minimum(np.arange(n_along) + 0.5 - np.r_[0, edges][idx],
                          edges[idx] - np.arange(n_along) - 0.5)
        grain_shape = (h, max(2, w // 10)) if not vertical else (max(2, h // 10), w)
        grain = cv2.resize(_fbm(rng, *grain_shape, cell=3, octaves=3), (w, h))
        shade = rng.random(len(edges) + 1).astype(np.float32)[idx]
        if vertical:
            shade, dist = shade[None, :], dist[None, :]
        else:
            shade, dist = shade[:, None], dist[:, None]
        img = _colorize(np.clip(0.4 * shade + 0.6 * grain, 0, 1), stops)
        gap = np.clip(dist - 0.7, 0.0, 1.0).astype(np.float32)
        img *= (0.35 + 0.65 * gap)[..., None]
        b = max(1, int(3 * s))  # dark frame
        img[:b] *= 0.6
        img[-b:] *= 0.6
        img[:, :b] *= 0.6
        img[:, -b:] *= 0.6
    else:
        stops = _palette(rng, 3, hue=rng.uniform(0, 360), hue_spread=10,
                         sat=(0.0, 0.15), val=(0.4, 0.8))
        stains = _fbm(rng, h, w, cell=30 * s, octaves=3)
        img = _colorize(0.5 * fine + 0.5 * stains, stops)
        for _ in range(int(rng.integers(1, 4))):  # posters
            pw, ph = (max(2, int(rng.uniform(0.25, 0.7) * w)),
                      max(2, int(rng.uniform(0.1, 0.3) * h)))
            x0 = int(rng.integers(0, max(1, w - pw)))
            y0 = int(rng.integers(0, max(1, h - ph)))
            col = _hsv(rng.uniform(0, 360), rng.uniform(0.3, 0.8),
                       rng.uniform(0.4, 0.95))
            pf = _fbm(rng, ph, pw, cell=max(2.0, 8 * s), octaves=2)
            img[y0:y0 + ph, x0:x0 + pw] = _colorize(
                pf, np.stack([col * 0.5, col, np.minimum(col * 1.4, 255)]))
        for _ in range(int(rng.integers(2, 6))):  # cracks
            pts = np.cumsum(rng.normal(0, 6 * s, (6, 2)), axis=0)
            pts += [rng.integers(w), rng.integers(h)]
            cv2.polylines(img, [pts.astype(np.int32)], False, (40, 40, 40), 1)
    img = _shade(img, fine, 0.3) * light
    return np.clip(img, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- #
# moving objects
# --------------------------------------------------------------------------- #
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
        shirt = _hsv(rng.uniform(0, 360), rng.uniform(0.6, 0.95),
                     rng.uniform(0.5, 0.95))
        trousers = _hsv(rng.uniform(0, 360), rng.uniform(0.4, 0.9),
                        rng.uniform(0.25, 0.7))
        skin = _SKIN[rng.integers(len(_SKIN))]
        hair = _hsv(rng.uniform(0, 40), 0.5, rng.uniform(0.05, 0.3))
    else:
        fur = _FUR[rng.integers(len(_FUR))]
        shirt, trousers = fur, fur * rng.uniform(0.4, 0.8)
        skin, hair = fur * 0.9, np.float32([25, 25, 30])
    colors = np.stack([np.zeros(3, np.float32), shirt, trousers, skin, hair])
    half = int(np.ceil(hgt)) + 2
    shade = 0.6 + 0.8 * _fbm(rng, 2 * half, 2 * half, cell=max(2.0, 0.12 * hgt),
                             octaves=4)
    if kind == "person" and rng.random() < 0.5:  # striped shirt
        period = rng.uniform(0.05, 0.1) * hgt
        ys = np.arange(2 * half, dtype=np.float32)[:, None]
        shade = shade * (0.75 + 0.25 * np.sign(np.sin(2 * np.pi * ys / period)))
    return _Object(kind, hgt, facing, rng.uniform(0, 2 * np.pi), z, x_ref,
                   velocity, colors, shade.astype(np.float32), half)


def _object_anchor(geo, obj, R, C, k):
    """Image position (x, y) of the feet of ``obj`` in a view, k views from ref."""
    X = np.array([obj.x_ref + obj.velocity * k, _CAMERA_HEIGHT, obj.z])
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


def _place_objects(rng, geo, rotations, centers, statics, ref, n_objects):
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

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

from dynremove.evaluation.synth.camera import SceneGeometry, sample_cameras
from dynremove.evaluation.synth.figures import place_objects
from dynremove.evaluation.synth.render import build_layers, plane_to_image, render_static
from dynremove.evaluation.synth.textures import Uint8Image

__all__ = ["Scene", "make_scene", "write_scene", "reference_flow"]

_SHAKE_REF_PX = 640.0  # camera_shake_px is given for this image size


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
    geo = SceneGeometry.sample(rng, height, width)
    rotations, centers = sample_cameras(
        rng, geo, n_views, ref, parallax=parallax, shake_px=camera_shake_px
    )
    layers = build_layers(rng, geo, rotations, centers)
    statics = []
    layer_ids = np.zeros((height, width), np.uint8)
    for i in range(n_views):
        img = render_static(layers, geo, rotations[i], centers[i],
                             ids=layer_ids if i == ref else None)
        statics.append(img)
    homs = np.stack([
        np.stack([plane_to_image(lay, geo, rotations[i], centers[i])
                  @ np.linalg.inv(plane_to_image(lay, geo, rotations[ref],
                                                  centers[ref]))
                  for lay in layers])
        for i in range(n_views)
    ])
    homs /= homs[:, :, 2:3, 2:3]
    images, masks = place_objects(rng, geo, rotations, centers, statics, ref,
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

"""Tests of dynremove.baselines on synthetic hand-held sets with known answers."""

from __future__ import annotations

import doctest
import os
import warnings
from pathlib import Path

import cv2
import numpy as np
import numpy.testing as npt
import pytest



from dynremove.evaluation import baselines  # noqa: E402
from dynremove.evaluation import metrics  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _data_root() -> Path:
    env = os.environ.get("DYNREMOVE_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


# --------------------------------------------------------------------------- scene

H, W, PAD = 160, 224, 16
#: per-view offset (x, y) of the view window on the canvas; view 3 is the ref
OFFSETS_XY = [(-5.0, -3.0), (-3.5, 2.0), (-1.5, -1.0), (0.0, 0.0), (2.5, 1.5),
              (4.0, -2.5), (6.0, 3.0)]
REF = 3
SQ = 28
OBJECT_BGR = (30, 20, 240)  # saturated red; the texture palette has R < 110


def _texture(rng: np.random.Generator, h: int, w: int, n: int = 500) -> np.ndarray:
    """Dead-leaves texture (discs and squares), rich in SIFT corners, no reds."""

    def colour() -> tuple[int, int, int]:
        return (int(rng.integers(40, 230)), int(rng.integers(40, 230)),
                int(rng.integers(0, 110)))

    img = np.empty((h, w, 3), np.uint8)
    img[:] = colour()
    for _ in range(n):
        c = colour()
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        r = int(rng.integers(3, 14))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), r, c, -1, lineType=cv2.LINE_AA)
        else:
            cv2.rectangle(img, (x - r, y - r), (x + r, y + r), c, -1)
    img = np.clip(img + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)
    return cv2.GaussianBlur(img, (0, 0), 0.8)


def _view(canvas: np.ndarray, off_xy: tuple[float, float]) -> np.ndarray:
    """Window of the canvas: ``view(p) = canvas(p + PAD + off)`` (bilinear)."""
    M = np.float32([[1, 0, -(PAD + off_xy[0])], [0, 1, -(PAD + off_xy[1])]])
    return cv2.warpAffine(canvas, M, (W, H), flags=cv2.INTER_LINEAR)


def _square_xy(v: int) -> tuple[int, int]:
    """Top-left (x, y) of the moving square in view v (never overlapping)."""
    return 6 + 30 * v, 60 + 12 * (v % 2)


def make_scene(seed: int = 0, *, moving: bool = True):
    """Hand-held translating views of a planar texture plus a moving square.

    Returns ``(views, background_ref, gt_mask_ref)``.
    """
    canvas = _texture(np.random.default_rng(seed), H + 2 * PAD, W + 2 * PAD)
    views, bg_ref = [], None
    for v, off in enumerate(OFFSETS_XY):
        img = _view(canvas, off)
        if v == REF:
            bg_ref = img.copy()
        if moving:
            x0, y0 = _square_xy(v)
            img[y0 : y0 + SQ, x0 : x0 + SQ] = OBJECT_BGR
        views.append(img)
    gt = np.zeros((H, W), bool)
    if moving:
        x0, y0 = _square_xy(REF)
        gt[y0 : y0 + SQ, x0 : x0 + SQ] = True
    return views, bg_ref, gt


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture(scope="module")
def scene():
    return make_scene(0)


def _max_corner_error(Hm: np.ndarray, t_xy: np.ndarray) -> float:
    """Max distance between ``Hm p`` and ``p + t`` over the image corners/centre."""
    pts = np.float64([[0, 0], [W - 1, 0], [0, H - 1], [W - 1, H - 1], [W / 2, H / 2]])
    ph = np.c_[pts, np.ones(len(pts))] @ Hm.T
    proj = ph[:, :2] / ph[:, 2:]
    return float(np.abs(proj - (pts + t_xy)).max())


# --------------------------------------------------------------------------- docs


def test_docstring_examples():
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    for t in finder.find(baselines, baselines.__name__):
        runner.run(t)
    assert runner.summarize(verbose=False).failed == 0


def test_thresholds_cover_align_modes():
    assert set(baselines.MEDIAN_THRESHOLD_LAB) == set(baselines.ALIGN_MODES)
    assert all(v > 0 for v in baselines.MEDIAN_THRESHOLD_LAB.values())
    with pytest.raises(TypeError):
        baselines.MEDIAN_THRESHOLD_LAB["homography"] = 1.0  # read-only


# --------------------------------------------------------------------------- alignment


@pytest.mark.parametrize("v", [0, 4, 5, 6])
def test_align_homography_recovers_translation(scene, v):
    views, _, _ = scene
    warped, valid, Hm = baselines.align_homography(views[REF], views[v], seed=0)
    # src point p is canvas p + off_v, i.e. ref point p + off_v - off_ref; Hm maps
    # reference to source (the convention of dynremove.method.geometry): q -> q - t
    t = np.subtract(OFFSETS_XY[v], OFFSETS_XY[REF])
    assert Hm.shape == (3, 3)
    assert _max_corner_error(Hm, -t) < 0.5
    assert warped.shape == (H, W, 3) and warped.dtype == np.uint8
    assert valid.shape == (H, W) and valid.dtype == bool
    # valid = the ref pixels whose pre-image p - t lies inside the source
    x = np.arange(W)
    y = np.arange(H)
    inside = ((y[:, None] - t[1] >= 0.5) & (y[:, None] - t[1] <= H - 1.5)
              & (x[None, :] - t[0] >= 0.5) & (x[None, :] - t[0] <= W - 1.5))
    outside = ((y[:, None] - t[1] < -0.5) | (y[:, None] - t[1] > H - 0.5)
               | (x[None, :] - t[0] < -0.5) | (x[None, :] - t[0] > W - 0.5))
    assert valid[inside].all() and not valid[outside].any()
    assert (warped[~valid] == 0).all()
    # the warped source matches the reference away from the moving squares
    static = valid & ~_square_union_mask()
    err = np.abs(warped.astype(int) - views[REF])[static]
    assert np.median(err) <= 2 and np.mean(err) < 4


def _square_union_mask() -> np.ndarray:
    m = np.zeros((H, W), bool)
    for v in range(len(OFFSETS_XY)):
        x0, y0 = _square_xy(v)
        m[max(y0 - 8, 0) : y0 + SQ + 8, max(x0 - 8, 0) : x0 + SQ + 8] = True
    return m


def test_align_homography_is_deterministic(scene):
    views, _, _ = scene
    _, _, h1 = baselines.align_homography(views[REF], views[6], seed=3)
    _, _, h2 = baselines.align_homography(views[REF], views[6], seed=3)
    npt.assert_array_equal(h1, h2)


def test_align_homography_fallback_warns_identity():
    flat = np.full((40, 50, 3), 120, np.uint8)
    src = flat.copy()
    src[10:20, 10:20] = 30
    with pytest.warns(baselines.AlignmentFallbackWarning, match="identity"):
        warped, valid, Hm = baselines.align_homography(flat, src)
    npt.assert_array_equal(Hm, np.eye(3))
    assert valid.all()
    npt.assert_array_equal(warped, src)


def test_align_homography_flow_static_scene():
    views, _, _ = make_scene(1, moving=False)
    warped, valid, Hm = baselines.align_homography_flow(views[REF], views[6])
    t = np.subtract(OFFSETS_XY[6], OFFSETS_XY[REF])
    assert _max_corner_error(Hm, -t) < 0.5  # reference -> source
    assert warped.shape == (H, W, 3) and warped.dtype == np.uint8
    assert valid.dtype == bool and 0.85 < valid.mean() < 1.0
    interior = valid.copy()
    interior[:8] = interior[-8:] = False
    interior[:, :8] = interior[:, -8:] = False
    assert metrics.psnr_in_mask(warped, views[REF], interior) > 30


def test_align_validation():
    a = np.zeros((20, 20, 3), np.uint8)
    with pytest.raises(ValueError, match="same shape"):
        baselines.align_homography(a, np.zeros((20, 21, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        baselines.align_homography(a, a.astype(np.float32))
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        baselines.align_homography_flow(a[..., 0], a[..., 0])


# --------------------------------------------------------------------------- median


def test_masked_median_matches_nanmedian(rng):
    r = rng
    for V in (2, 3, 6, 7):
        stack = r.integers(0, 256, (V, 9, 11, 3)).astype(np.uint8)
        valid = r.random((V, 9, 11)) < 0.6
        valid[r.integers(0, V)] = True  # at least one valid view per pixel
        med, count = baselines._masked_median(stack, valid)
        f = stack.astype(float)
        f[~valid] = np.nan
        expect = np.rint(np.nanmedian(f, axis=0)).astype(np.uint8)
        npt.assert_array_equal(med, expect)
        npt.assert_array_equal(count, valid.sum(0))


def test_median_stack_static_scene_returns_background():
    views, bg, _ = make_scene(2, moving=False)
    background, count = baselines.median_stack(views, REF, align="homography")
    assert background.shape == (H, W, 3) and background.dtype == np.uint8
    assert count.shape == (H, W)
    assert count.min() >= 1 and count.max() == len(views)
    assert count[H // 2, W // 2] == len(views)
    assert metrics.psnr_in_mask(background, bg, np.ones((H, W), bool)) > 35


def test_median_baseline_homography_recovers_background(scene):
    views, bg, gt = scene
    clean, dynamic = baselines.median_baseline(views, REF, align="homography")
    assert clean.shape == (H, W, 3) and clean.dtype == np.uint8
    assert dynamic.shape == (H, W) and dynamic.dtype == bool
    assert metrics.jaccard(dynamic, gt) >= 0.8
    assert metrics.psnr_in_mask(clean, bg, gt) >= 25
    assert metrics.ssim_in_mask(clean, bg, gt) > 0.9
    # pixels not detected are the reference's own
    npt.assert_array_equal(clean[~dynamic], views[REF][~dynamic])


def test_median_baseline_flow_runs(scene):
    # Dense flow partly follows the moving square, so only
    # the detection is checked loosely here.
    views, _, gt = scene
    clean, dynamic = baselines.median_baseline(views, REF, align="homography+flow")
    assert clean.shape == (H, W, 3) and dynamic.shape == (H, W)
    assert metrics.jaccard(dynamic, gt) >= 0.6


def test_median_baseline_negative_ref_index_and_threshold(scene):
    views, _, gt = scene
    _, d1 = baselines.median_baseline(views, REF - len(views), threshold=15.0)
    _, d2 = baselines.median_baseline(views, REF, threshold=15.0)
    npt.assert_array_equal(d1, d2)
    _, loose = baselines.median_baseline(views, REF, threshold=200.0)
    assert not loose.any()


def test_median_detect_no_difference_is_empty(rng):
    img = rng.integers(0, 256, (30, 40, 3)).astype(np.uint8)
    assert not baselines.median_detect(img, img, threshold=1.0).any()


def test_median_validation(scene):
    views, _, _ = scene
    with pytest.raises(ValueError, match="align"):
        baselines.median_stack(views, REF, align="flow")
    with pytest.raises(ValueError, match="out of range"):
        baselines.median_stack(views, 7)
    with pytest.raises(ValueError, match="at least 2"):
        baselines.median_stack(views[:1], 0)
    with pytest.raises(ValueError, match=r"images\[2\]"):
        baselines.median_stack(views[:2] + [views[2][:, :-1]], 0)
    with pytest.raises(ValueError, match="threshold"):
        baselines.median_detect(views[0], views[1], threshold=-1)


# --------------------------------------------------------------------------- Telea


def test_telea_fills_only_the_dilated_mask(scene):
    views, bg, gt = scene
    ref = views[REF]
    out = baselines.telea_inpaint(ref, gt, radius=5)
    assert out.shape == ref.shape and out.dtype == np.uint8
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    dilated = cv2.dilate(gt.astype(np.uint8), disc).astype(bool)
    npt.assert_array_equal(out[~dilated], ref[~dilated])
    # the red square is gone: no pixel inside is close to the object colour
    d = np.abs(out[gt].astype(int) - OBJECT_BGR).sum(axis=1)
    assert d.min() > 60
    # with no dilation only the mask itself may change
    out0 = baselines.telea_inpaint(ref, gt, dilate_px=0)
    npt.assert_array_equal(out0[~gt], ref[~gt])


def test_telea_empty_mask_and_validation():
    img = np.full((10, 10, 3), 7, np.uint8)
    npt.assert_array_equal(baselines.telea_inpaint(img, np.zeros((10, 10))), img)
    with pytest.raises(ValueError, match="mask must have"):
        baselines.telea_inpaint(img, np.zeros((10, 9)))
    with pytest.raises(ValueError, match="radius"):
        baselines.telea_inpaint(img, np.zeros((10, 10)), radius=0)


# --------------------------------------------------------------------------- real data


def test_median_baseline_on_davis_set():
    set_dir = _data_root() / "davis" / "dance-twirl"
    if not (set_dir / "frames").is_dir():
        pytest.skip(f"shared data not found at {set_dir} (set DYNREMOVE_DATA)")
    frames = sorted((set_dir / "frames").glob("*.jpg"))
    images = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in frames]
    ref = len(images) // 2
    mask_path = set_dir / "masks" / f"{frames[ref].stem}.png"
    gt = metrics.mask_from_png(cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE))
    with warnings.catch_warnings():
        warnings.simplefilter("error", baselines.AlignmentFallbackWarning)
        clean, dynamic = baselines.median_baseline(images, ref, align="homography")
    # measured 0.666 at the global threshold (examples/median_threshold_study.py)
    assert metrics.jaccard(dynamic, gt) > 0.6

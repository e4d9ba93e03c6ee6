"""Dense correspondences N_{r→s} and the two-view geometry, on images with known motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynremove.method import correspondence as corr
from dynremove.method import geometry

H_, W_ = 96, 128
T = (4.0, 3.0)  # background translation reference → source (px)
# F = [t]_x of a camera translating along (4, 3, 0): the epipolar lines run along T
F_T = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, -4.0], [-3.0, 4.0, 0.0]])


def _texture(rng, h, w):
    t = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 2.0)
    t = (t - t.min()) / (t.max() - t.min()) * 255
    return t.astype(np.uint8)


def _pair(rng, obj_shift):
    """Reference and source: the background moves by T, a 24×24 object by T + obj_shift."""
    bg = _texture(rng, H_ + 40, W_ + 40)
    obj = 255 - _texture(rng, 24, 24)
    ref = bg[20:20 + H_, 20:20 + W_].copy()
    src = bg[20 - int(T[1]):20 - int(T[1]) + H_, 20 - int(T[0]):20 - int(T[0]) + W_].copy()
    y0, x0 = 40, 50
    ref[y0:y0 + 24, x0:x0 + 24] = obj
    ys, xs = y0 + int(T[1] + obj_shift[1]), x0 + int(T[0] + obj_shift[0])
    src[ys:ys + 24, xs:xs + 24] = obj
    Hm = np.array([[1.0, 0, T[0]], [0, 1, T[1]], [0, 0, 1]])
    obj_mask = np.zeros((H_, W_), bool)
    obj_mask[y0 + 6:y0 + 18, x0 + 6:x0 + 18] = True  # the object's inside
    bg_mask = np.ones((H_, W_), bool)
    bg_mask[y0 - 16:y0 + 40, x0 - 16:x0 + 50] = False
    bg_mask[:10], bg_mask[-10:], bg_mask[:, :10], bg_mask[:, -10:] = False, False, False, False
    return ref, src, Hm, obj_mask, bg_mask


def _err(N, mask, shift):
    xs, ys = corr.pixel_grid(H_, W_)
    return np.hypot(N[..., 0] - xs - shift[0], N[..., 1] - ys - shift[1])[mask]


def test_homography_method_is_the_homography():
    Hm = np.array([[1.01, 0.02, 3.0], [-0.01, 0.99, -2.0], [1e-4, 0, 1]])
    g = np.zeros((H_, W_), np.uint8)
    N = corr.dense_correspondence(g, g, Hm, method="homography")
    xs, ys = corr.pixel_grid(H_, W_)
    hx, hy = geometry.apply_homography(Hm, xs, ys)
    np.testing.assert_array_equal(N[..., 0], hx)
    np.testing.assert_array_equal(N[..., 1], hy)


def test_flow_follows_the_object_and_gated_does_not(rng):
    """Flow (after the pre-warp) tracks the moving object; "gated" replaces the
    flow that strays more than gate_px from the homography by the homography."""
    d = (0.0, 7.0)  # the object moves 7 px down, across the epipolar lines of F_T
    ref, src, Hm, obj, bg = _pair(rng, d)
    full = corr.dense_correspondence(ref, src, Hm, method="homography+flow")
    gated = corr.dense_correspondence(ref, src, Hm, method="gated", gate_px=2.0)
    obj_motion = (T[0] + d[0], T[1] + d[1])
    assert np.median(_err(full, bg, T)) < 0.5  # background: the homography's match
    assert np.median(_err(gated, bg, T)) < 0.5
    assert np.median(_err(full, obj, obj_motion)) < 1.0  # flow follows the object …
    assert np.median(_err(gated, obj, T)) < 1e-3  # … the gate puts it back on H
    far = _err(full, np.ones_like(obj), T) > 2.0
    assert far.sum() > 0.5 * obj.sum()
    # with F, flow along an epipolar line is parallax and kept; across it, it is not
    across = corr.dense_correspondence(ref, src, Hm, method="gated", gate_px=2.0, F=F_T,
                                       epipolar_px=1.0)
    assert np.median(_err(across, obj, T)) < 1e-3


def test_gated_keeps_flow_along_the_epipolar_line(rng):
    d = (8.0, 6.0)  # along T: on the epipolar lines of F_T
    ref, src, Hm, obj, bg = _pair(rng, d)
    along = corr.dense_correspondence(ref, src, Hm, method="gated", gate_px=2.0, F=F_T,
                                      epipolar_px=1.0)
    plain = corr.dense_correspondence(ref, src, Hm, method="gated", gate_px=2.0)
    obj_motion = (T[0] + d[0], T[1] + d[1])
    assert np.median(_err(along, obj, obj_motion)) < 1.0
    assert np.median(_err(plain, obj, T)) < 1e-3


def test_round_matches_is_the_nearest_pixel():
    Nf = np.array([[[1.4, 2.6], [-0.6, 1e9]]], np.float32)
    N = corr.round_matches(Nf)
    assert N.dtype == np.int32
    assert N.tolist() == [[[1, 3], [-1, 1 << 20]]]


# ---- geometry ----------------------------------------------------------------------


def test_too_few_matches_fall_back_to_no_F_and_the_identity(rng):
    xy_r = rng.uniform(0, 100, (geometry.MIN_MATCHES - 1, 2)).astype(np.float32)
    tv = geometry.estimate_two_view(xy_r, xy_r + 5, seed=0)
    assert tv.F is None and tv.n_inliers_F == 0
    np.testing.assert_array_equal(tv.H, np.eye(3))
    assert tv.n_matches == geometry.MIN_MATCHES - 1
    # a blank source: no keypoints at all
    g = _texture(rng, H_, W_)
    (tv,) = geometry.geometry_for_sources(g, [np.zeros_like(g)])
    assert tv.F is None and tv.n_matches == 0
    np.testing.assert_array_equal(tv.H, np.eye(3))


def test_enough_matches_give_F_and_H(rng):
    g = _texture(rng, 200, 260)
    src = np.roll(g, (3, 4), axis=(0, 1))
    (tv,) = geometry.geometry_for_sources(g, [src])
    assert tv.n_matches >= geometry.MIN_MATCHES and tv.F is not None
    np.testing.assert_allclose(tv.H / tv.H[2, 2], [[1, 0, 4], [0, 1, 3], [0, 0, 1]], atol=0.05)
    pts = np.array([[50.0, 60.0], [120.0, 90.0]])
    assert geometry.sampson_sq(tv.F, pts, pts + (4, 3)).max() < 0.5


def _project(Hm, xy):
    q = np.c_[xy, np.ones(len(xy))] @ Hm.T
    return (q[:, :2] / q[:, 2:]).astype(np.float32)


def _mover_and_background(rng, n_bg=60, n_mover=150):
    """Keypoint matches of a 640×480 photo: ``n_bg`` spread over the background,
    which moves by a homography, and ``n_mover`` packed in an 80×100 box (a cup's
    lettering), which moves otherwise: the box holds more matches than the rest."""
    H_bg = np.array([[1.01, 0.02, 12.0], [-0.015, 0.99, -5.0], [2e-5, 1e-5, 1.0]])
    H_mv = np.array([[1.0, 0.0, 80.0], [0.0, 1.0, 10.0], [0.0, 0.0, 1.0]])
    bg = rng.uniform((0, 0), (640, 480), (n_bg, 2))
    mv = rng.uniform((300, 200), (380, 300), (n_mover, 2))
    xy_r = np.r_[bg, mv].astype(np.float32)
    xy_s = np.r_[_project(H_bg, bg), _project(H_mv, mv)]
    xy_s += rng.normal(0, 0.3, xy_s.shape).astype(np.float32)
    return xy_r, xy_s, H_bg, n_bg


def test_a_compact_textured_mover_does_not_set_the_homography(rng):
    """tim6 with tim3.jpg as the reference: the cup's lettering held 87 of the 93
    inliers of MAGSAC's homography to tim4.jpg, where the cup had moved. The
    flow's pre-warp then brought tim4's cup onto the reference's, and the cup
    was left in the clean photo. The homography refitted on keypoints spread over
    the photo (``geometry.spread_homography``) is the background's."""
    xy_r, xy_s, H_bg, n_bg = _mover_and_background(rng)
    plain, _ = geometry.fit_homography(xy_r, xy_s, seed=0)
    # the failure: the plain fit takes the mover (more matches than the background)
    assert np.abs(_project(plain, xy_r[:n_bg]) - xy_s[:n_bg]).max() > 10
    Hm, n = geometry.spread_homography(xy_r, xy_s, seed=0)
    err = np.hypot(*(_project(Hm, xy_r[:n_bg]) - xy_s[:n_bg]).T)
    assert np.median(err) < 1.0 and (err < 3.0).mean() > 0.9
    assert n >= 0.9 * n_bg  # its inliers are counted over all the matches
    tv = geometry.estimate_two_view(xy_r, xy_s, seed=0)
    np.testing.assert_allclose(tv.H, Hm)


def test_the_spread_fit_leaves_a_homography_that_covers_the_photo(rng):
    """Where the plain fit's inliers already cover the photo, its homography is kept as
    it is (the spread subset draws other RANSAC samples, and a homography a little
    different moved single composites' leftover by up to 8 points)."""
    xy_r, xy_s, H_bg, n_bg = _mover_and_background(rng, n_bg=300, n_mover=60)
    plain, n_plain = geometry.fit_homography(xy_r, xy_s, seed=0)
    Hm, n = geometry.spread_homography(xy_r, xy_s, seed=0)
    np.testing.assert_array_equal(Hm, plain)
    assert n == n_plain
    sub = geometry.spread_subset(xy_r, seed=0)
    assert sub[n_bg:].sum() < 0.5 * (len(xy_r) - n_bg)  # the packed box is thinned
    assert sub[:n_bg].mean() > 0.9  # the spread points are kept


def test_a_low_contrast_pair_is_matched_again_on_faint_keypoints(rng):
    """A wall or a table analysed small: OpenCV's default SIFT contrast finds no
    match, the retry on faint keypoints (geometry.LOW_CONTRAST) finds the motion."""
    t = _texture(rng, 200, 260).astype(np.float32)
    g = np.clip(128 + (t - 128) * 0.15 + 0.5, 0, 255).astype(np.uint8)
    src = np.roll(g, (3, 4), axis=(0, 1))
    first = geometry.match(geometry.detect(g)[1], geometry.detect(src)[1])
    assert len(first) < geometry.MIN_MATCHES  # the default detection fails here
    (tv,) = geometry.geometry_for_sources(g, [src])
    assert tv.F is not None and tv.n_inliers_F >= 100
    np.testing.assert_allclose(tv.H / tv.H[2, 2], [[1, 0, 4], [0, 1, 3], [0, 0, 1]], atol=0.05)


def test_prepare_without_F_for_one_source(small_scene):
    """A blank source gets hasF False and the scan still has finite similarities."""
    from dynremove import preset
    from dynremove.pipeline import prepare

    images = [im.copy() for im in small_scene.images]
    blank = 0 if small_scene.ref_index != 0 else 1
    images[blank][:] = 128
    st, views = prepare(images, small_scene.ref_index, preset("paper"))
    k = blank if blank < small_scene.ref_index else blank - 1
    assert views[k].F is None and not st.hasF[k]
    assert st.hasF.sum() == len(views) - 1
    assert np.isfinite(st.C).all() and (st.C[k] <= 1.0 + 1e-6).all()


def _facade_and_columns(rng, share, n=600):
    """Keypoint matches of a facade (depth 10) with columns before it (depth 6) that
    hold ``share`` of the matches, between two views 0.6 units apart (854×480,
    f = 700 px), with 0.2 px of noise."""
    K = np.array([[700.0, 0, 427], [0, 700.0, 240], [0, 0, 1]])
    a = np.deg2rad(2.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    xy = rng.uniform((0, 0), (854, 480), (n, 2))
    Z = np.where(np.arange(n) < int(share * n), 6.0, 10.0)
    X = (np.linalg.inv(K) @ np.c_[xy, np.ones(n)].T) * Z
    q = K @ (R @ X + np.array([-0.6, 0.05, 0.1])[:, None])
    xs = (q[:2] / q[2]).T + rng.normal(0, 0.2, (n, 2))
    return xy.astype(np.float32), xs.astype(np.float32)


@pytest.mark.parametrize("share", [0.0, 0.08, 0.2])
def test_the_parallax_percentiles_of_a_facade_with_columns(rng, share):
    """Columns before a facade holding 8 % of the matches: the 90th percentile of the
    distance from the homography sees the facade only (under 2 px), the 95th the
    columns (tens of px); at 20 % both see them, and a plain facade neither."""
    xy_r, xy_s = _facade_and_columns(rng, share)
    tv = geometry.estimate_two_view(xy_r, xy_s, seed=0)
    assert tv.F is not None and tv.n_inliers_F >= 0.95 * len(xy_r)
    assert tv.parallax_px <= tv.parallax_p95_px
    assert (tv.parallax_px > 8.0) == (share > 0.1)
    assert (tv.parallax_p95_px > 8.0) == (share > 0.0)


def test_compiled_homography_map_equals_its_numpy_form(rng):
    """``apply_homography``'s compiled pass gives ``project_homography``'s values
    rounded to float32, bit for bit: float32 and float64 points, a homography with
    perspective, and one whose w vanishes (the 1e-12 floor); the sampling grid it
    usually maps is shared and read-only."""
    xs, ys = corr.pixel_grid(H_, W_)
    assert corr.pixel_grid(H_, W_)[0] is xs
    with pytest.raises(ValueError):
        xs[0, 0] = 1.0
    flat = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-13]])
    for Hm in [np.eye(3) + rng.normal(0, 1, (3, 3)) * [[0.05, 0.05, 20], [0.05, 0.05, 20],
                                                        [1e-3, 1e-3, 0.01]] for _ in range(5)
               ] + [flat]:
        for px, py in [(xs, ys), (xs + rng.normal(0, 3, xs.shape).astype(np.float32), ys),
                       (xs.astype(np.float64) + 0.3, ys.astype(np.float64) - 7.1)]:
            mx, my, _ = geometry.project_homography(Hm, px, py)
            gx, gy = geometry.apply_homography(Hm, px, py)
            assert gx.dtype == gy.dtype == np.float32 and gx.shape == px.shape
            assert np.array_equal(gx.view(np.int32), mx.astype(np.float32).view(np.int32))
            assert np.array_equal(gy.view(np.int32), my.astype(np.float32).view(np.int32))


def test_compiled_sampson_distance_equals_its_numpy_form(rng):
    """``sampson_sq`` (compiled) equals Hartley & Zisserman's Eq. (11.9) written in
    NumPy in the same order of operations, bit for bit."""
    F = rng.normal(0, 1, (3, 3))
    xr = rng.uniform(0, 800, (500, 2))
    xs = xr + rng.normal(0, 5, (500, 2))
    x, y, u, v = xr[:, 0], xr[:, 1], xs[:, 0], xs[:, 1]
    a = F[0, 0] * x + F[0, 1] * y + F[0, 2]
    b = F[1, 0] * x + F[1, 1] * y + F[1, 2]
    c = F[2, 0] * x + F[2, 1] * y + F[2, 2]
    ta = F[0, 0] * u + F[1, 0] * v + F[2, 0]
    tb = F[0, 1] * u + F[1, 1] * v + F[2, 1]
    e = u * a + v * b + c
    want = e * e / np.maximum(a * a + b * b + ta * ta + tb * tb, 1e-300)
    assert np.array_equal(geometry.sampson_sq(F, xr, xs), want)

"""Tests of the synthetic scene generator ``dynremove.evaluation.synth``."""

from __future__ import annotations

from pathlib import Path


import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dynremove.evaluation import synth


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=0)


def _furthest_view(scene):
    return 0 if scene.ref_index >= len(scene.images) / 2 else len(scene.images) - 1


def _near_layers(scene):
    return [i for i, n in enumerate(scene.layer_names)
            if n == "ground" or n.startswith("box")]


# --------------------------------------------------------------------------- #
# determinism, shapes
# --------------------------------------------------------------------------- #
def test_same_seed_is_byte_identical():
    a = synth.make_scene(seed=7, n_views=4, size=(96, 128))
    b = synth.make_scene(seed=7, n_views=4, size=(96, 128))
    for x, y in zip(a.images + a.masks + [a.background],
                    b.images + b.masks + [b.background]):
        assert x.tobytes() == y.tobytes()
    np.testing.assert_array_equal(a.layer_homographies, b.layer_homographies)


def test_other_seed_differs():
    a = synth.make_scene(seed=7, n_views=4, size=(96, 128))
    b = synth.make_scene(seed=8, n_views=4, size=(96, 128))
    assert not np.array_equal(a.background, b.background)
    assert np.abs(a.images[0].astype(int) - b.images[0].astype(int)).mean() > 10


def test_shapes_and_dtypes(scene):
    V, (H, W) = 6, (360, 640)
    assert scene.ref_index == V // 2
    assert scene.names == [f"view{i}.png" for i in range(V)]
    assert len(scene.images) == len(scene.masks) == V
    for img, mask in zip(scene.images, scene.masks):
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        assert mask.shape == (H, W) and mask.dtype == bool
    assert scene.background.shape == (H, W, 3)
    assert scene.background.dtype == np.uint8
    assert scene.layer_ids.shape == (H, W) and scene.layer_ids.dtype == np.uint8
    assert scene.layer_homographies.shape == (V, len(scene.layer_names), 3, 3)
    assert scene.K.shape == (3, 3)
    assert scene.rotations.shape == (V, 3, 3) and scene.centers.shape == (V, 3)
    assert scene.seed == 0


@pytest.mark.parametrize("kwargs", [
    dict(size=(48, 64), n_views=2),
    dict(size=(480, 854), n_views=7, n_objects=3),
    dict(size=(200, 120), n_objects=1, ref_index=0),  # portrait
    dict(n_views=5, ref_index=4, parallax=0.0, camera_shake_px=0.0),
])
def test_other_configurations(kwargs):
    sc = synth.make_scene(seed=1, **kwargs)
    H, W = kwargs["size"] if "size" in kwargs else (360, 640)
    assert len(sc.images) == kwargs.get("n_views", 6)
    assert sc.images[0].shape == (H, W, 3)
    ref = sc.ref_index
    assert ref == kwargs.get("ref_index", len(sc.images) // 2)
    assert np.array_equal(sc.background[~sc.masks[ref]],
                          sc.images[ref][~sc.masks[ref]])
    assert all(m.any() for m in sc.masks)


# --------------------------------------------------------------------------- #
# ground truth
# --------------------------------------------------------------------------- #
def test_masks_nonempty_and_reference_area(scene):
    assert all(m.any() for m in scene.masks)
    frac = scene.masks[scene.ref_index].mean()
    assert 0.02 <= frac <= 0.15


def test_objects_fully_inside_reference(scene):
    m = scene.masks[scene.ref_index]
    assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())


def test_background_equals_reference_outside_mask(scene):
    ref = scene.ref_index
    m = scene.masks[ref]
    np.testing.assert_array_equal(scene.background[~m], scene.images[ref][~m])
    diff = np.abs(scene.background.astype(int) - scene.images[ref].astype(int))
    assert diff[m].mean() > 20


def test_masks_are_exactly_the_changed_pixels_in_reference(scene):
    # hard-edged objects: every changed pixel is masked (the converse may fail
    # only where an object pixel happens to equal the background)
    ref = scene.ref_index
    changed = (scene.background != scene.images[ref]).any(axis=-1)
    assert not (changed & ~scene.masks[ref]).any()
    assert changed[scene.masks[ref]].mean() > 0.95


def test_hidden_background_is_revealed(scene):
    ref = scene.ref_index
    m_ref = scene.masks[ref]
    overlap = [(m_ref & m).sum() / m_ref.sum()
               for i, m in enumerate(scene.masks) if i != ref]
    assert sum(o < 0.5 for o in overlap) >= len(scene.images) - 2


def test_no_empty_borders(scene):
    for img in scene.images:
        for edge in (img[0], img[-1], img[:, 0], img[:, -1]):
            assert (edge.max(axis=-1) > 0).all()
            assert edge.mean() > 20


# --------------------------------------------------------------------------- #
# geometry
# --------------------------------------------------------------------------- #
def test_layer_homographies_obey_epipolar_geometry(scene):
    K, ref = scene.K, scene.ref_index
    assert np.allclose(scene.rotations[ref], np.eye(3))
    assert np.allclose(scene.centers[ref], 0)
    H, W = scene.layer_ids.shape
    kinv = np.linalg.inv(K)
    rng = np.random.default_rng(0)
    x_ref = np.column_stack([rng.uniform(0, W, 50), rng.uniform(0, H, 50),
                             np.ones(50)])
    for i, (R, C) in enumerate(zip(scene.rotations, scene.centers)):
        t = -R @ C
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        F = kinv.T @ tx @ R @ kinv
        for lid in range(len(scene.layer_names)):
            x_i = x_ref @ scene.layer_homographies[i, lid].T
            lines = x_ref @ F.T
            dist = np.abs((x_i * lines).sum(1)) / (
                np.linalg.norm(lines[:, :2], axis=1) * x_i[:, 2] + 1e-12)
            assert dist.max() < 1e-6 * max(1.0, np.abs(x_i[:, :2] / x_i[:, 2:]).max())
        # the sky is the plane at infinity: pure rotation
        H_sky = K @ R @ kinv
        np.testing.assert_allclose(scene.layer_homographies[i, 0],
                                   H_sky / H_sky[2, 2], atol=1e-9)


def test_images_agree_with_reference_flow(scene):
    ref = scene.ref_index
    H, W = scene.layer_ids.shape
    for i in range(len(scene.images)):
        flow = synth.reference_flow(scene, i)
        warped = cv2.remap(scene.images[i], flow[..., 0], flow[..., 1],
                           cv2.INTER_LINEAR)
        ok = (~scene.masks[ref] & (flow[..., 0] >= 0) & (flow[..., 0] <= W - 1)
              & (flow[..., 1] >= 0) & (flow[..., 1] <= H - 1))
        err = np.abs(warped.astype(int) - scene.background.astype(int)).mean(-1)
        assert np.median(err[ok]) < 3.0


def test_background_moves_between_views(scene):
    H, W = scene.layer_ids.shape
    ys, xs = np.mgrid[0:H, 0:W]
    for i in range(len(scene.images)):
        if i == scene.ref_index:
            continue
        flow = synth.reference_flow(scene, i)
        motion = np.hypot(flow[..., 0] - xs, flow[..., 1] - ys)
        assert 3.0 < np.median(motion) < 60.0


def test_true_parallax_between_layers(scene):
    # near layers (ground, boxes) move >= 3 px differently from the backdrop
    i = _furthest_view(scene)
    H, W = scene.layer_ids.shape
    ys, xs = np.mgrid[0:H, 0:W]
    pts = np.stack([xs, ys], -1).reshape(-1, 1, 2).astype(np.float32)
    backdrop = scene.layer_names.index("backdrop")
    by_backdrop = cv2.perspectiveTransform(
        pts, scene.layer_homographies[i, backdrop]).reshape(H, W, 2)
    dev = np.linalg.norm(by_backdrop - synth.reference_flow(scene, i), axis=-1)
    near = np.isin(scene.layer_ids, _near_layers(scene))
    assert near.mean() > 0.1
    assert np.median(dev[near]) >= 3.0


def test_one_homography_cannot_align_the_frame(scene):
    # estimate one homography from ORB matches on the background (as a method
    # would) and measure it against the true flow
    ref, i = scene.ref_index, _furthest_view(scene)
    gray = [cv2.cvtColor(scene.images[k], cv2.COLOR_BGR2GRAY) for k in (ref, i)]
    orb = cv2.ORB_create(3000)
    (k0, d0), (k1, d1) = (orb.detectAndCompute(g, None) for g in gray)
    assert len(k0) >= 300 and len(k1) >= 300  # textures are rich
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d0, d1)
    p = np.float32([k0[m.queryIdx].pt for m in matches])
    q = np.float32([k1[m.trainIdx].pt for m in matches])
    pr, qr = np.round(p).astype(int), np.round(q).astype(int)
    bg = ~scene.masks[ref][pr[:, 1], pr[:, 0]] & ~scene.masks[i][qr[:, 1], qr[:, 0]]
    p, q, pr = p[bg], q[bg], pr[bg]
    flow = synth.reference_flow(scene, i)
    correct = np.linalg.norm(flow[pr[:, 1], pr[:, 0]] - q, axis=1) < 3.0
    assert correct.sum() >= 200  # and they match
    hom, _ = cv2.findHomography(p, q, cv2.RANSAC, 3.0)
    H, W = scene.layer_ids.shape
    ys, xs = np.mgrid[0:H, 0:W]
    pts = np.stack([xs, ys], -1).reshape(-1, 1, 2).astype(np.float32)
    res = np.linalg.norm(cv2.perspectiveTransform(pts, hom).reshape(H, W, 2) - flow,
                         axis=-1)[~scene.masks[ref]]
    assert np.percentile(res, 90) > 3.0


def test_zero_parallax_is_a_pure_rotation():
    sc = synth.make_scene(seed=2, size=(96, 128), parallax=0.0)
    homs = sc.layer_homographies
    np.testing.assert_allclose(homs, np.broadcast_to(homs[:, :1], homs.shape),
                               atol=1e-9)


# --------------------------------------------------------------------------- #
# properties on small scenes
# --------------------------------------------------------------------------- #
@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_views=st.integers(2, 7),
       n_objects=st.integers(1, 3), h=st.integers(48, 120),
       w=st.integers(64, 160))
def test_invariants_hold_for_any_seed(seed, n_views, n_objects, h, w):
    sc = synth.make_scene(seed=seed, n_views=n_views, n_objects=n_objects,
                          size=(h, w))
    ref = sc.ref_index
    m = sc.masks[ref]
    assert np.array_equal(sc.background[~m], sc.images[ref][~m])
    assert all(mask.any() for mask in sc.masks)
    assert 0.02 <= m.mean() <= 0.15
    overlap = [(m & mi).sum() / m.sum() for i, mi in enumerate(sc.masks) if i != ref]
    assert sum(o < 0.5 for o in overlap) >= n_views - 2


# --------------------------------------------------------------------------- #
# I/O and validation
# --------------------------------------------------------------------------- #
def test_write_scene_layout(tmp_path):
    sc = synth.make_scene(seed=3, n_views=3, size=(64, 96))
    synth.write_scene(sc, tmp_path / "set")
    root = tmp_path / "set"
    bg = cv2.imread(str(root / "background.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(bg, sc.background)
    for name, img, mask in zip(sc.names, sc.images, sc.masks):
        frame = cv2.imread(str(root / "frames" / name), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(frame, img)
        m = cv2.imread(str(root / "masks" / (Path(name).stem + ".png")),
                       cv2.IMREAD_UNCHANGED)
        assert m.dtype == np.uint8 and m.shape == img.shape[:2]
        assert set(np.unique(m)) <= {0, 255}
        np.testing.assert_array_equal(m == 255, mask)
    assert sorted(p.name for p in (root / "frames").iterdir()) == sorted(sc.names)


@pytest.mark.parametrize("kwargs, word", [
    (dict(n_views=1), "n_views"),
    (dict(n_objects=0), "n_objects"),
    (dict(n_objects=4), "n_objects"),
    (dict(size=(47, 64)), "size"),
    (dict(size=(48, 63)), "size"),
    (dict(size=(48,)), "size"),
    (dict(ref_index=6), "ref_index"),
    (dict(ref_index=-1), "ref_index"),
    (dict(parallax=-1.0), "parallax"),
    (dict(camera_shake_px=float("nan")), "camera_shake_px"),
    (dict(seed=-1), "seed"),
])
def test_invalid_arguments_raise(kwargs, word):
    with pytest.raises(ValueError, match=word):
        synth.make_scene(**kwargs)


def test_options_are_keyword_only():
    with pytest.raises(TypeError):
        synth.make_scene(0)  # type: ignore[misc]


def test_reference_flow_checks_view(scene):
    with pytest.raises(ValueError, match="view"):
        synth.reference_flow(scene, len(scene.images))

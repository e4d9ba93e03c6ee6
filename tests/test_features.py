"""Dense SIFT f_g and the Lab mean f_c (Sec. 3.1) on images with known answers."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from dynremove.method import features

P = 9


def _orientation_energy(desc: np.ndarray) -> np.ndarray:
    """(..., 128) → (..., 8): energy per orientation summed over the 4×4 cells."""
    return desc.reshape(desc.shape[:-1] + (16, 8)).astype(np.float64).sum(-2)


def test_dense_sift_shape_and_flat_image():
    f = features.dense_sift(np.full((20, 30), 77, np.float32), patch_size=P)
    assert f.shape == (20, 30, 128) and f.dtype == np.uint8
    assert not f.any(), "no gradient, no descriptor"


@pytest.mark.parametrize("direction, bin_", [("+x", 0), ("+y", 2), ("-x", 4), ("-y", 6)])
def test_dense_sift_orientation_of_a_step_edge(direction, bin_):
    """A step edge whose gradient points along +x (angle 0) fills orientation bin 0;
    +y (angle π/2, y down) bin 2; the reversed edges bins 4 and 6."""
    g = np.zeros((40, 40), np.float32)
    if direction[1] == "x":
        g[:, 20:] = 200
    else:
        g[20:, :] = 200
    if direction[0] == "-":
        g = 200 - g
    f = features.dense_sift(g, patch_size=P)
    e = _orientation_energy(f[20, 20])
    assert int(np.argmax(e)) == bin_
    assert e[bin_] > 0.9 * e.sum()


def test_dense_sift_is_translation_equivariant(rng):
    g = cv2.GaussianBlur(rng.uniform(0, 255, (60, 80)).astype(np.float32), (0, 0), 1.5)
    f = features.dense_sift(g, patch_size=P)
    f2 = features.dense_sift(np.roll(g, (3, 5), axis=(0, 1)), patch_size=P)
    np.testing.assert_array_equal(f2[20:50, 20:70], f[17:47, 15:65])


def test_dense_sift_separates_different_patches(rng):
    """Same patch → distance 0; a different texture → far; normalised to ≤ 255."""
    g = cv2.GaussianBlur(rng.uniform(0, 255, (60, 80)).astype(np.float32), (0, 0), 1.5)
    f = features.dense_sift(g, patch_size=P).astype(np.int64)
    same = ((f[30, 30] - f[30, 30]) ** 2).sum()
    near = ((f[30, 30] - f[30, 31]) ** 2).sum()
    far = ((f[30, 30] - f[10, 60]) ** 2).sum()
    assert same == 0 and near < far
    norms = np.sqrt((f[10:50, 10:70] ** 2).sum(-1))
    assert 300 < norms.mean() < 600  # unit vector × 512, clamped at 0.2, saturating at 255


def test_sift_unit_divides_by_the_set_max():
    a = np.zeros((2, 2, 128), np.uint8)
    b = np.zeros((2, 2, 128), np.uint8)
    b[1, 1, 5] = 200
    assert features.sift_unit([a, b], sift_scale=0.2) == pytest.approx(0.2 / 200)


def test_lab_mean_is_the_patch_average():
    img = np.zeros((9, 9, 3), np.uint8)
    img[:, 5:] = 255  # white right of column 5
    lab = features.to_lab(img)
    fc = features.lab_mean(img, patch_size=3)
    np.testing.assert_allclose(fc[4, 4], (2 * lab[4, 0] + lab[4, 8]) / 3, atol=1e-3)
    np.testing.assert_allclose(fc[4, 1], lab[4, 0], atol=1e-4)


def test_orientation_planes_equal_their_numpy_form(rng):
    """The compiled split of the gradient between its two orientation bins equals
    the NumPy form first written, bit for bit (angles of exactly 0 and 2π too)."""
    gray = rng.uniform(0, 255, (60, 90)).astype(np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1) * 0.5
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=1) * 0.5
    mag, ang = cv2.cartToPolar(gx, gy)
    ang[0, :3] = (0.0, np.float32(2 * np.pi), np.nextafter(np.float32(2 * np.pi), 0))
    o = ang * (8.0 / (2.0 * math.pi))
    o0 = np.floor(o)
    w1 = o - o0
    o0 = o0.astype(np.int32) % 8
    lo, hi = mag * (1.0 - w1), mag * w1
    o1 = (o0 + 1) % 8
    want = np.stack([np.where(o0 == k, lo, 0.0) + np.where(o1 == k, hi, 0.0)
                     for k in range(8)]).astype(np.float32)
    np.testing.assert_array_equal(features._orientation_planes(mag, ang), want)

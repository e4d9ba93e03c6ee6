"""Pinhole cameras of the synthetic scenes: intrinsics, hand-held poses, plane homographies."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

CAMERA_HEIGHT = 1.5  # h : camera height above the ground plane (world units)
_FOCAL_FACTOR = 0.85  # f = _FOCAL_FACTOR * max(H, W) pixels (about 60 deg FOV)
_STEP_FACTOR = 0.009  # sideways camera step per view, as a fraction of d


@dataclass(frozen=True)
class SceneGeometry:
    """Image size, intrinsics and the depths that lay out the scene."""

    H: int
    W: int
    f: float
    K: np.ndarray  # (3, 3)
    d_far: float  # depth of the backdrop plane
    scale: float  # max(H, W) / 640: pixel sizes of texture features

    @staticmethod
    def sample(rng: np.random.Generator, height: int, width: int) -> SceneGeometry:
        f = _FOCAL_FACTOR * max(height, width)
        cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        y_ground = rng.uniform(0.6, 0.7) * height  # backdrop meets the ground
        d_far = f * CAMERA_HEIGHT / (y_ground - cy)
        return SceneGeometry(height, width, f, K, d_far, max(height, width) / 640.0)

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def depth_of_ground_row(self, row: float) -> float:
        """Depth of the ground plane seen at image row ``row`` (reference)."""
        return self.f * CAMERA_HEIGHT / (row - self.cy)


def sample_cameras(rng, geo, n_views, ref, *, parallax, shake_px):
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
            q = plane_homography(geo, R, C, np.array([0, 0, 1.0]), geo.d_far) @ centre
            if np.hypot(*(q[:2] / q[2] - centre[:2])) >= min_motion:
                break
        rotations[i], centers[i] = R, C
    return rotations, centers


def plane_homography(geo, R, C, normal, dist):
    """Reference-to-view homography of the plane ``normal . X = dist``.

    ``H = K R (I - C n^T / d) K^-1``, equivalently ``K (R + t n^T / d) K^-1``
    with ``t = -R C``.
    """
    kinv = np.linalg.inv(geo.K)
    return geo.K @ R @ (np.eye(3) - np.outer(C, normal) / dist) @ kinv


def rays(geo, R, C, pts_xy):
    """World rays (origin, directions (N, 3)) through pixels of a view."""
    pix = np.column_stack([pts_xy, np.ones(len(pts_xy))])
    dirs = (R.T @ np.linalg.inv(geo.K) @ pix.T).T
    return C, dirs


def plane_extent(geo, rotations, centers, p0, a, b, *, at_infinity=False):
    """Bounding box ``(u0, v0, u1, v1)`` in texels of what the views see.

    Only for planes with no horizon in view (the preimage of the image
    rectangle is then the quadrilateral of its corners' preimages).
    """
    w, h = geo.W - 1, geo.H - 1
    pts_xy = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    uv = []
    for R, C in zip(rotations, centers):
        origin, dirs = rays(geo, R, C, pts_xy)
        rhs = -p0 if at_infinity else origin - p0
        for d in dirs:
            sol = np.linalg.solve(np.column_stack([a, b, -d]), rhs)
            uv.append(sol[:2])
    uv = np.array(uv)
    return uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()

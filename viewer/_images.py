"""Small image helpers shared by the sink and the exporter (no rerun here)."""

from __future__ import annotations

import cv2
import numpy as np

# Colours (RGB) of the class ids in viewer.paths; alpha for overlays.
CLASS_COLORS = {
    0: ("background", (0, 0, 0, 0)),
    1: ("dynamic", (255, 40, 40, 120)),
    2: ("false positive", (255, 220, 0, 170)),
    3: ("false negative", (40, 120, 255, 170)),
    4: ("true positive", (40, 220, 80, 110)),
    5: ("static", (120, 220, 255, 255)),
    6: ("probe", (255, 0, 255, 255)),
}

# Candidate colours by DBSCAN cluster id (RGB); noise (−1) is grey.
CLUSTER_PALETTE = np.array([
    (230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48),
    (145, 30, 180), (70, 240, 240), (240, 50, 230), (210, 245, 60), (250, 190, 212),
], dtype=np.uint8)
NOISE_COLOR = np.array((150, 150, 150), dtype=np.uint8)
NAN_COLOR_BGR = (60, 60, 60)


def cluster_colors(cluster: np.ndarray) -> np.ndarray:
    """(N,) int cluster ids → (N, 3) uint8 RGB (noise grey)."""
    cluster = np.asarray(cluster)
    out = CLUSTER_PALETTE[np.mod(cluster, len(CLUSTER_PALETTE))]
    out[cluster < 0] = NOISE_COLOR
    return out


def encode_jpeg(bgr: np.ndarray, quality: int = 90) -> bytes:
    """(H, W, 3) uint8 BGR → JPEG bytes (a fresh copy, safe to log)."""
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def encode_png(img: np.ndarray) -> bytes:
    """Lossless PNG bytes (fast compression level)."""
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img),
                           [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def colormap(values: np.ndarray, *, vmin: float = 0.0, vmax: float = 1.0,
             cmap: int = cv2.COLORMAP_VIRIDIS) -> np.ndarray:
    """Map a float map to BGR with a FIXED range, so colours never flicker.

    NaN becomes dark grey. Values outside ``[vmin, vmax]`` are clipped.
    About 1.2 ms for 854×480 (cv2 saturating casts, no boolean indexing).
    """
    scale = 255.0 / max(vmax - vmin, 1e-12)
    f = np.asarray(values, dtype=np.float32) * np.float32(scale)
    if vmin:
        f -= np.float32(vmin * scale)
    nan = (f != f).view(np.uint8)
    np.maximum(f, 0, out=f)  # NaN stays NaN (masked below)
    bgr = cv2.applyColorMap(cv2.convertScaleAbs(f), cmap)  # rounds, saturates at 255
    cv2.copyTo(np.full_like(bgr, NAN_COLOR_BGR[0]), nan, bgr)
    return bgr


def error_labels(dynamic: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) uint8: 4 = TP, 2 = FP, 3 = FN, 0 = TN (class ids of viewer.paths)."""
    d = np.asarray(dynamic, bool)
    g = np.asarray(gt, bool)
    out = np.zeros(d.shape, np.uint8)
    out[d & g] = 4
    out[d & ~g] = 2
    out[~d & g] = 3
    return out


def overlay(bgr: np.ndarray, mask: np.ndarray, color=(40, 40, 255),
            alpha: float = 0.5) -> np.ndarray:
    """Blend ``color`` (BGR) into ``bgr`` where ``mask`` is true (new array)."""
    out = bgr.copy()
    m = np.asarray(mask, bool)
    if m.any():
        out[m] = (out[m] * (1 - alpha) + np.array(color) * alpha).astype(np.uint8)
    return out

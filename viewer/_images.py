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
    5: ("static (sampled decision)", (120, 220, 255, 255)),
    6: ("probe (static decision)", (255, 0, 255, 255)),
    7: ("undecided (no cluster)", (160, 160, 160, 200)),
}
# Why a decision was recorded (Decision["why"] bit flags), named.
REASON_NAMES = {1: "dynamic: M ≤ t_r", 2: "probe pixel (--probe)", 4: "sampled static"}
# Classes of the per-scan verdict map (scan_maps/verdict).
VERDICT_NAMES = {0: "not visited", 1: "static (M > t_r)", 2: "dynamic (M ≤ t_r)",
                 3: "undecided (no cluster)"}
VERDICT_COLORS = {0: (0, 0, 0, 0), 1: (60, 140, 255, 110), 2: (255, 40, 40, 140),
                  3: (160, 160, 160, 160)}


def ramp_rgba(values, vmax: float, *, cmap: int = cv2.COLORMAP_VIRIDIS,
              alpha: int = 255) -> list[tuple[int, int, int, int]]:
    """RGBA of ``values`` on a fixed colour ramp ``0 → vmax`` (clipped)."""
    v = np.clip(np.asarray(values, np.float64) / max(float(vmax), 1e-12), 0, 1)
    bgr = cv2.applyColorMap(np.rint(v * 255).astype(np.uint8).reshape(-1, 1), cmap)
    return [(int(c[0, 2]), int(c[0, 1]), int(c[0, 0]), int(alpha)) for c in bgr]


def count_classes(vmax: int, label: str, zero: str, *, ramp_max: int | None = None,
                  cmap: int = cv2.COLORMAP_VIRIDIS) -> list[tuple[int, str, tuple]]:
    """AnnotationContext entries of a small count map (``scan_maps/n_candidates`` …).

    Value v in 1..vmax is labelled ``label.format(v)`` and coloured on a fixed ramp
    0 → ``ramp_max`` (default ``vmax``); 0 is ``zero``, transparent. The colours
    never depend on the data, so two scans or two runs read alike.
    """
    vals = np.arange(1, int(vmax) + 1)
    cols = ramp_rgba(vals, ramp_max or vmax, cmap=cmap)
    return [(0, zero, (0, 0, 0, 0))] + [(int(v), label.format(int(v)), c)
                                        for v, c in zip(vals, cols)]


def source_set_classes(names: list[str]) -> list[tuple[int, str, tuple]]:
    """AnnotationContext entries of the bitmask map ``scan_maps/win_sources``.

    Bit s = source s (``names[s]``); each mask is labelled with the sources of
    the winning cluster A_m and coloured by how many of the S sources they are
    (fixed ramp 0 → S). 0: no winning cluster. Only for S ≤ 10 (2^S entries).
    """
    S = len(names)
    masks = np.arange(1, 1 << S)
    pop = np.array([bin(int(m)).count("1") for m in masks])
    cols = ramp_rgba(pop, S, cmap=cv2.COLORMAP_PLASMA)
    out = [(0, "no winning cluster (undecided)", (0, 0, 0, 0))]
    for m, k, c in zip(masks.tolist(), pop.tolist(), cols):
        srcs = ", ".join(n for s, n in enumerate(names) if m >> s & 1)
        out.append((m, f"A_m from {k} of {S} sources: {srcs}", c))
    return out


def mask_sources(mask: int, names: list[str]) -> list[str]:
    """The source names of bitmask ``mask`` (bit s = ``names[s]``), in order.

    >>> mask_sources(0b101, ["a", "b", "c"]), mask_sources(0b1001, ["a", "b"])
    (['a', 'c'], ['a', 'source 3'])
    """
    m = int(mask)
    return [names[s] if s < len(names) else f"source {s}"
            for s in range(m.bit_length()) if m >> s & 1]


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


LEGEND_ROWS = 28  # height of the legend strip drawn under a colour-mapped map


def legend_strip(width: int, *, vmin: float = 0.0, vmax: float = 1.0,
                 cmap: int = cv2.COLORMAP_VIRIDIS, title: str = "M",
                 marks: tuple[tuple[float, str], ...] = ()) -> np.ndarray:
    """(LEGEND_ROWS, width, 3) BGR colour bar with its range and marks written on it.

    Drawn under a colour-mapped map (same image, so overlays keep their pixel
    coordinates): ``title vmin ▮▮▮ vmax``, grey = NaN, plus ``marks`` such as t_r.
    """
    strip = np.full((LEGEND_ROWS, width, 3), 24, np.uint8)
    x0, x1 = min(width // 6 + 40, width // 3), max(width - 50, width // 3 + 10)
    ramp = np.linspace(0, 255, max(1, x1 - x0)).astype(np.uint8)[None, :]
    bar = cv2.applyColorMap(np.repeat(ramp, 12, 0), cmap)
    strip[4:16, x0:x1] = bar
    font, sc = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    cv2.putText(strip, f"{title} {vmin:g}", (3, 15), font, sc, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(strip, f"{vmax:g}", (x1 + 4, 15), font, sc, (255, 255, 255), 1, cv2.LINE_AA)
    for v, name in marks:
        if vmin <= v <= vmax:
            xm = int(round(x0 + (x1 - x0 - 1) * (v - vmin) / max(vmax - vmin, 1e-12)))
            cv2.line(strip, (xm, 2), (xm, 18), (255, 255, 255), 1)
            cv2.putText(strip, f"{name}", (max(0, xm - 12), 26), font, 0.33,
                        (255, 255, 255), 1, cv2.LINE_AA)
    cv2.rectangle(strip, (3, 19), (11, 26), NAN_COLOR_BGR, -1)
    cv2.putText(strip, "undecided", (14, 26), font, 0.33, (220, 220, 220), 1, cv2.LINE_AA)
    return strip


def colormap_with_legend(values: np.ndarray, *, vmin: float = 0.0, vmax: float = 1.0,
                         title: str = "M", marks: tuple[tuple[float, str], ...] = ()
                         ) -> np.ndarray:
    """:func:`colormap` of ``values`` with a :func:`legend_strip` appended below."""
    top = colormap(values, vmin=vmin, vmax=vmax)
    return np.concatenate([top, legend_strip(top.shape[1], vmin=vmin, vmax=vmax,
                                             title=title, marks=marks)], 0)


def visited_mask(H: int, W: int, rows_done: int, direction: int) -> np.ndarray:
    """(H, W) bool: pixels a scan has visited after ``rows_done`` whole rows.

    Top-down scans (``direction`` +1) visit rows 0, 1, …; bottom-up scans (−1)
    visit H−1, H−2, …
    """
    m = np.zeros((H, W), bool)
    k = int(np.clip(rows_done, 0, H))
    if direction >= 0:
        m[:k] = True
    elif k:
        m[H - k:] = True
    return m


def overwritten_maps(H: int, W: int, reps: np.ndarray, *, scan: int, direction: int,
                     half: int) -> tuple[np.ndarray, np.ndarray]:
    """What neighbours' patch writes did to each pixel before its own turn, in one scan.

    Parameters
    ----------
    reps : structured array with fields ``x, y, step`` (the scan's Replacements).
    half : p // 2 for patch writes (0 for pixel writes).

    Returns
    -------
    before : (H, W) uint16, how many patches centred elsewhere overwrote the pixel
        before the scan reached it (its content, hence f at x_r, had changed).
    first : (H, W) int64, the step of the first such write (−1: none).
    """
    before = np.zeros(H * W, np.int64)
    first = np.full(H * W, np.iinfo(np.int64).max, np.int64)
    if len(reps) and half > 0:
        base = np.int64(scan) * H * W
        rx = reps["x"].astype(np.int64)
        ry = reps["y"].astype(np.int64)
        rs = reps["step"].astype(np.int64)
        for dy in range(-half, half + 1):
            for dx in range(-half, half + 1):
                if dx == 0 and dy == 0:
                    continue
                qx, qy = rx + dx, ry + dy
                ok = (qx >= 0) & (qx < W) & (qy >= 0) & (qy < H)
                qx, qy, s = qx[ok], qy[ok], rs[ok]
                if direction >= 0:
                    own = base + qy * W + qx
                else:
                    own = base + (H - 1 - qy) * W + (W - 1 - qx)
                hit = s < own
                flat = qy[hit] * W + qx[hit]
                np.add.at(before, flat, 1)
                np.minimum.at(first, flat, s[hit])
    first[first == np.iinfo(np.int64).max] = -1
    return (np.minimum(before, 65535).astype(np.uint16).reshape(H, W),
            first.reshape(H, W))


def visit_step(scan: int, x: int, y: int, H: int, W: int, *,
               direction: int | None = None) -> int:
    """Global ``step`` at which scan ``scan`` visits pixel ``(x, y)``.

    Scans alternate (``direction`` None): even scans run top-left → bottom-right,
    odd ones the reverse.

    >>> visit_step(0, 2, 1, 4, 5), visit_step(1, 4, 3, 4, 5)
    (7, 20)
    """
    if direction is None:
        direction = 1 if scan % 2 == 0 else -1
    idx = y * W + x if direction >= 0 else (H - 1 - y) * W + (W - 1 - x)
    return int(scan) * H * W + int(idx)

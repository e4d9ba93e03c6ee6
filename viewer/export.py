"""Render a recording's progressive removal to a GIF or MP4, without a viewer.

Frames are built from the recorded snapshots (``reference/image`` JPEGs and
``reference/dynamic`` label maps, latest-at by ``step``): left, the input
reference with L overlaid in red; right, the rewritten reference.

GIF: a small encoder written here (global k-means palette + LZW compiled with
numba), so there is no Pillow dependency. MP4: ``cv2.VideoWriter`` ('mp4v').
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numba
import numpy as np

from viewer import inspect as vi
from viewer import paths as P
from viewer._images import overlay


# -- frames ------------------------------------------------------------------------
def render_frames(path_rrd: str | Path, *, max_side: int = 480,
                  root: str = "") -> list[np.ndarray]:
    """Montage frames (BGR uint8), one per recorded snapshot step."""
    store = vi.load_store(path_rrd)
    p = P.Paths(root)
    snaps = vi.read_snapshots(path_rrd, root=root)
    info = vi.read_run_info(path_rrd, root=root)
    H, W = int(info.get("height", 0)), int(info.get("width", 0))
    inp = vi._blob_rows(store, p(P.REFERENCE_INPUT), index=None)
    images = snaps["image"]
    if not images:
        raise ValueError(f"{path_rrd}: no reference snapshots recorded")
    ref_in = vi.decode(inp[0][1]) if inp else vi.decode(images[0][1])
    H, W = ref_in.shape[:2] if not (H and W) else (H, W)
    # every step at which something visible changed: image or L
    steps = sorted({s for s, _ in images} | {s for s, _ in snaps["dynamic"]})
    img_steps = np.array([s for s, _ in images])
    dyn_steps = np.array([s for s, _ in snaps["dynamic"]])
    W2 = 2 * W + 8
    scale = min(1.0, max_side / max(W2, H + 24))
    out_w, out_h = max(2, int(round(W2 * scale))), max(2, int(round((H + 24) * scale)))
    scan_of = {}
    t = vi._arrow(store, p(P.REFERENCE_IMAGE))
    if t is not None:
        scan_of = dict(zip(t.column("step").to_pylist(), t.column("scan").to_pylist()))
    frames = []
    cache: dict[int, np.ndarray] = {}
    for step in steps:
        i = int(np.searchsorted(img_steps, step, side="right")) - 1
        if i < 0:
            continue
        if i not in cache:
            cache.clear()
            cache[i] = vi.decode(images[i][1])
        cur = cache[i]
        j = int(np.searchsorted(dyn_steps, step, side="right")) - 1
        L = snaps["dynamic"][j][1] if j >= 0 else np.zeros((H, W), bool)
        canvas = np.full((H + 24, W2, 3), 32, np.uint8)
        canvas[24:, :W] = overlay(ref_in, L, color=(40, 40, 255), alpha=0.55)
        canvas[24:, W + 8:] = cur
        scan = scan_of.get(images[i][0], "?")
        cv2.putText(canvas, f"scan {scan}  step {step}  |L|={int(L.sum())}", (6, 17),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        frames.append(cv2.resize(canvas, (out_w, out_h), interpolation=cv2.INTER_AREA))
    return frames


def export_gif(path_rrd: str | Path, out_path: str | Path, *, fps: float = 10,
               max_side: int = 480, root: str = "") -> Path:
    """Write the progressive removal as an animated GIF (or MP4 if ``.mp4``).

    Parameters
    ----------
    path_rrd : path of the recording.
    out_path : ``.gif`` or ``.mp4`` output.
    fps : frames per second (one frame per recorded snapshot).
    max_side : longest side of the output, in pixels.
    """
    out_path = Path(out_path)
    frames = render_frames(path_rrd, max_side=max_side, root=root)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    if out_path.suffix.lower() == ".mp4":
        write_mp4(frames, out_path, fps=fps)
    else:
        write_gif(frames, out_path, fps=fps)
    return out_path


def write_mp4(frames: list[np.ndarray], out_path: str | Path, *, fps: float = 10) -> None:
    """Frames (BGR, same size) → MP4 ('mp4v'); sizes are padded to even numbers."""
    h, w = frames[0].shape[:2]
    H2, W2 = h + h % 2, w + w % 2
    vw = cv2.VideoWriter(str(out_path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W2, H2))
    if not vw.isOpened():
        raise RuntimeError(f"cv2.VideoWriter could not open {out_path}")
    try:
        for f in frames:
            vw.write(cv2.copyMakeBorder(f, 0, H2 - h, 0, W2 - w, cv2.BORDER_REPLICATE))
    finally:
        vw.release()


# -- GIF encoder -------------------------------------------------------------------
def _palette(frames: list[np.ndarray], n_colors: int = 256,
             seed: int = 0) -> np.ndarray:
    """Global palette (n_colors, 3) BGR uint8 by k-means on a pixel sample."""
    rng = np.random.default_rng(seed)
    pix = np.concatenate([f.reshape(-1, 3) for f in frames[:: max(1, len(frames) // 16)]])
    sample = pix[rng.choice(len(pix), size=min(len(pix), 40000), replace=False)]
    uniq = np.unique(sample, axis=0)
    if len(uniq) <= n_colors:
        pal = uniq
    else:
        cv2.setRNGSeed(seed)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 8, 1.0)
        _, _, centers = cv2.kmeans(sample.astype(np.float32), n_colors, None, crit, 1,
                                   cv2.KMEANS_PP_CENTERS)
        pal = np.clip(np.rint(centers), 0, 255).astype(np.uint8)
    out = np.zeros((n_colors, 3), np.uint8)
    out[:len(pal)] = pal
    return out


def _lut(palette: np.ndarray) -> np.ndarray:
    """(32, 32, 32) uint8: nearest palette index of each 5-bit BGR cell centre."""
    g = (np.arange(32) * 8 + 4).astype(np.float32)
    cells = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pal = palette.astype(np.float32)
    idx = np.empty(len(cells), np.uint8)
    for a in range(0, len(cells), 4096):
        d = ((cells[a:a + 4096, None, :] - pal[None]) ** 2).sum(-1)
        idx[a:a + 4096] = np.argmin(d, axis=1)
    return idx.reshape(32, 32, 32)


@numba.njit(cache=True, nogil=True)
def _lzw(indices, min_code_size, out):
    """GIF LZW of a 1-D uint8 index array into ``out`` (bytes); returns its length."""
    clear = 1 << min_code_size
    eoi = clear + 1
    table = np.full((4096, 256), -1, np.int16)
    next_code = eoi + 1
    code_size = min_code_size + 1
    acc = 0
    nbits = 0
    n = 0
    # emit clear
    acc |= clear << nbits
    nbits += code_size
    while nbits >= 8:
        out[n] = acc & 255
        n += 1
        acc >>= 8
        nbits -= 8
    prefix = np.int64(indices[0])
    for i in range(1, indices.shape[0]):
        k = indices[i]
        c = table[prefix, k]
        if c >= 0:
            prefix = np.int64(c)
            continue
        acc |= prefix << nbits
        nbits += code_size
        while nbits >= 8:
            out[n] = acc & 255
            n += 1
            acc >>= 8
            nbits -= 8
        table[prefix, k] = next_code
        next_code += 1
        if next_code > (1 << code_size) and code_size < 12:
            code_size += 1
        if next_code == 4096:  # table full: clear (sent at 12 bits)
            acc |= clear << nbits
            nbits += code_size
            while nbits >= 8:
                out[n] = acc & 255
                n += 1
                acc >>= 8
                nbits -= 8
            table[:, :] = -1
            next_code = eoi + 1
            code_size = min_code_size + 1
        prefix = np.int64(k)
    for code in (prefix, np.int64(eoi)):
        acc |= code << nbits
        nbits += code_size
        while nbits >= 8:
            out[n] = acc & 255
            n += 1
            acc >>= 8
            nbits -= 8
    if nbits > 0:
        out[n] = acc & 255
        n += 1
    return n


def _sub_blocks(data: bytes) -> bytes:
    parts = [bytes([len(data[i:i + 255])]) + data[i:i + 255] for i in range(0, len(data), 255)]
    return b"".join(parts) + b"\x00"


def write_gif(frames: list[np.ndarray], out_path: str | Path, *, fps: float = 10,
              loop: int = 0) -> None:
    """Frames (BGR uint8, same size) → animated GIF89a with one global palette."""
    if not frames:
        raise ValueError("no frames to write")
    h, w = frames[0].shape[:2]
    pal = _palette(frames)
    lut = _lut(pal)
    delay = max(2, int(round(100 / max(fps, 1e-3))))
    rgb_table = pal[:, ::-1].tobytes()  # GIF stores RGB
    out = bytearray(b"GIF89a")
    out += np.array([w, h], "<u2").tobytes() + bytes([0xF7, 0, 0]) + rgb_table
    out += b"\x21\xFF\x0BNETSCAPE2.0\x03\x01" + np.array([loop], "<u2").tobytes() + b"\x00"
    buf = np.empty(w * h * 2 + 1024, np.uint8)
    for f in frames:
        if f.shape[:2] != (h, w):
            raise ValueError("all frames must have the same size")
        q = f >> 3
        idx = np.ascontiguousarray(lut[q[..., 0], q[..., 1], q[..., 2]].reshape(-1))
        n = _lzw(idx, 8, buf)
        out += b"\x21\xF9\x04\x04" + np.array([delay], "<u2").tobytes() + b"\x00\x00"
        out += b"\x2C" + np.array([0, 0, w, h], "<u2").tobytes() + b"\x00"
        out += b"\x08" + _sub_blocks(buf[:n].tobytes())
    out += b"\x3B"
    Path(out_path).write_bytes(bytes(out))

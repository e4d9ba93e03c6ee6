"""Render a recording's progressive removal to a GIF, an MP4 or PNG frames, without a
viewer.

Frames are built from the recorded snapshots (``reference/image`` JPEGs and
``reference/dynamic`` label maps, latest-at by ``step``): left, the input
reference with L overlaid in red; right, the rewritten reference.

GIF: Pillow, with one global palette (the frames' own colours when there are at
most 256 of them, else Pillow's median cut over a sample of the frames).
MP4: ``cv2.VideoWriter`` ('mp4v').
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from dynremove.errors import InputError
from dynremove.io import atomic_path, current_umask
from viewer import inspect as vi
from viewer import paths as P
from viewer._images import overlay


# -- frames ------------------------------------------------------------------------
def render_frames(path_rrd: str | Path, *, max_side: int = 480,
                  root: str = "", captions: list[str] | None = None) -> list[np.ndarray]:
    """Montage frames (BGR uint8), one per recorded snapshot step; ``captions`` (a
    list) receives each frame's caption text."""
    store = vi.load_store(path_rrd)
    root = vi.resolve_root(path_rrd, root)  # a --compare recording: which of its runs
    p = P.Paths(root)
    snaps = vi.read_snapshots(path_rrd, root=root)
    info = vi.read_run_info(path_rrd, root=root)
    H, W = int(info.get("height", 0)), int(info.get("width", 0))
    inp = vi._blob_rows(store, p(P.REFERENCE_INPUT), index=None)
    images = snaps["image"]
    if not images:
        if vi.read_final_dynamic(path_rrd, root=root) is None:
            # a file cut short: Rerun writes a scan's snapshots in chunks, which may all
            # lie beyond the cut (a fresh-user trial's head -c copy)
            raise InputError(f"{path_rrd}: no reference snapshots in what could be read: "
                             "the recording ends before the run finished (cut short); "
                             "'dynremove inspect' still reads the decisions it holds")
        raise InputError(f"{path_rrd}: no reference snapshots recorded")
    ref_in = vi.decode(inp[0][1]) if inp else vi.decode(images[0][1])
    H, W = ref_in.shape[:2] if not (H and W) else (H, W)
    # every step at which something visible changed: image or L
    steps = sorted({s for s, _ in images} | {s for s, _ in snaps["dynamic"]})
    img_steps = np.array([s for s, _ in images])
    dyn_steps = np.array([s for s, _ in snaps["dynamic"]])
    W2 = 2 * W + 8
    # the caption bar counts in the frame's height (a fresh-user trial's --max-side 16
    # gave 16x36 frames); under a quarter of the frame it is left out
    cap_rows = CAPTION_ROWS if max_side >= 4 * CAPTION_ROWS else 0
    scale = min(1.0, max_side / W2, (max_side - cap_rows) / H)
    # even sides, at most max_side: MP4's codecs need even ones (padding them made
    # --max-side 101 give 102 px frames: a fresh-user trial)
    out_w, out_h = (max(2, int(v * scale) // 2 * 2) for v in (W2, H))
    scan_of = {}
    t = vi._arrow(store, p(P.REFERENCE_IMAGE))
    if t is not None:
        scan_of = dict(zip(t.column("step").to_pylist(), t.column("scan").to_pylist()))
    # a finished run logs L after each post-scan step (clean-up, votes, snap, fill)
    # at the steps just before its last image, the written clean image
    stage_names = list(vi.read_stages(path_rrd, root=root))
    final_step = int(img_steps.max()) if stage_names else None
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
        canvas = np.full((H, W2, 3), 32, np.uint8)
        canvas[:, :W] = overlay(ref_in, L, color=(40, 40, 255), alpha=0.55)
        canvas[:, W + 8:] = cur
        scan = scan_of.get(images[i][0], "?")
        small = cv2.resize(canvas, (out_w, out_h), interpolation=cv2.INTER_AREA)
        where = f"scan {scan}   step {step}"
        if final_step is not None and step == final_step:
            where = "final: the written clean image"
        elif final_step is not None and final_step - len(stage_names) <= step < final_step:
            where = f"after the scans: {stage_names[step - final_step + len(stage_names)]}"
        text = f"{where}   |L| = {int(L.sum())} analysis px"
        if captions is not None:
            captions.append(text)
        frames.append(np.concatenate([_caption(out_w, text), small], 0) if cap_rows
                      else small)
    return frames


CAPTION_ROWS = 26


def _caption(width: int, text: str) -> np.ndarray:
    """A caption bar drawn at the OUTPUT size (so it stays readable: ~13 px text)."""
    bar = np.full((CAPTION_ROWS, width, 3), 32, np.uint8)
    scale = 0.55 if width >= 360 else 0.4
    cv2.putText(bar, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)
    return bar


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
    suffix = out_path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"{out_path}: the output must end in .gif or .mp4")
    _check_fps(fps)
    frames = render_frames(path_rrd, max_side=max_side, root=root)
    # written under a temporary name beside it, then renamed: a failed or cut
    # export leaves the file that was there (the suffix picks OpenCV's container)
    with atomic_path(out_path, suffix=suffix) as tmp:
        if suffix == ".mp4":
            write_mp4(frames, tmp, fps=fps)
        else:
            write_gif(frames, tmp, fps=fps)
    return out_path


FRAME_NAME = "frame_{:04d}.png"


def export_frames(path_rrd: str | Path, out_dir: str | Path, *, max_side: int = 480,
                  root: str = "") -> list[Path]:
    """Write the progressive removal as numbered PNG frames (``frame_0000.png``, ...;
    slides, or a video tool of one's own) into ``out_dir``.

    The frames are drawn into a temporary folder beside ``out_dir``, which then
    takes its place: a failed or cut export leaves what was there. ``out_dir``
    must not exist, or hold only frames of an earlier export (``frame_*.png``):
    ValueError otherwise, before any drawing. Returns the frames' paths in order.
    """
    out_dir = Path(out_dir)
    check_frames_dir(out_dir)
    frames = render_frames(path_rrd, max_side=max_side, root=root)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    old = None
    try:
        # mkdtemp makes 0700; the folder follows the umask as every output does (a
        # trial's frames folder, and the 0755 one it replaced, came out private)
        os.chmod(tmp, 0o777 & ~current_umask())
        for i, f in enumerate(frames):
            if not cv2.imwrite(str(tmp / FRAME_NAME.format(i)), f):
                raise OSError(f"could not write {tmp / FRAME_NAME.format(i)}")
        if out_dir.exists():
            old = out_dir.parent / f"{tmp.name}.old"
            out_dir.rename(old)
        tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and not out_dir.exists():
            old.rename(out_dir)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return [out_dir / FRAME_NAME.format(i) for i in range(len(frames))]


def check_frames_dir(out_dir: Path) -> None:
    """ValueError unless ``out_dir`` is absent, or a folder of an earlier export's
    frames only (``export_frames`` replaces it whole)."""
    if not out_dir.exists():
        return
    if not out_dir.is_dir():
        raise ValueError(f"{out_dir}: is a file, not a folder for the frames")
    other = [q.name for q in out_dir.iterdir()
             if not (q.is_file() and q.name.startswith("frame_") and q.suffix == ".png")]
    if other:
        raise ValueError(f"{out_dir}: holds other files than frames ({', '.join(sorted(other)[:3])}"
                         f"{', ...' if len(other) > 3 else ''}): give a new folder, or one "
                         "of an earlier export's frames, which are replaced")


def _check_fps(fps: float) -> None:
    """ValueError unless ``fps`` is a finite number of frames per second in (0, 100]."""
    if not (math.isfinite(fps) and 0.0 < fps <= 100.0):
        raise ValueError(f"fps must be a number in (0, 100], got {fps}")


def write_mp4(frames: list[np.ndarray], out_path: str | Path, *, fps: float = 10) -> None:
    """Frames (BGR, same size) → MP4 ('mp4v'); sizes are padded to even numbers.
    ValueError for ``fps`` outside (0, 100]."""
    _check_fps(fps)
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


# -- GIF ---------------------------------------------------------------------------
def gif_palette(frames: list[np.ndarray], n_colors: int = 256) -> Image.Image:
    """One palette ("P" image) for all frames (BGR uint8).

    The frames' own colours when there are at most ``n_colors`` of them (the GIF
    is then lossless), else Pillow's median cut over every k-th frame.
    """
    sample = np.concatenate([f.reshape(-1, 3) for f in frames[:: max(1, len(frames) // 16)]])
    # the colours present, as flags over the 2^24 packed BGR values (one pass per
    # frame; ``np.unique(axis=0)`` on every pixel took 4.7 s of a 6 s export, in C,
    # where a Ctrl-C waited for it)
    seen = np.zeros(1 << 24, bool)
    for f in frames:
        c = f.reshape(-1, 3).astype(np.uint32)
        seen[(c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]] = True
    packed = np.flatnonzero(seen)
    uniq = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], -1
                    ).astype(np.uint8)
    if len(uniq) <= n_colors:
        pal = Image.new("P", (1, 1))
        rgb = np.zeros((256, 3), np.uint8)
        rgb[:len(uniq)] = uniq[:, ::-1]
        pal.putpalette(rgb.tobytes())
        return pal
    montage = Image.fromarray(np.ascontiguousarray(sample[None, :, ::-1]), "RGB")
    return montage.quantize(colors=n_colors, method=Image.Quantize.MEDIANCUT,
                            dither=Image.Dither.NONE)


def gif_delay_ms(fps: float) -> int:
    """The frame delay a GIF holds for ``fps``: whole hundredths of a second, at least
    2 (browsers show shorter delays as 100 ms), so 30 fps is written as 30 ms (33.3 fps)
    and 100 fps as 20 ms (50 fps)."""
    return 10 * max(2, int(round(100 / max(fps, 1e-3))))


def write_gif(frames: list[np.ndarray], out_path: str | Path, *, fps: float = 10,
              loop: int = 0) -> None:
    """Frames (BGR uint8, same size) → animated GIF89a with one global palette.
    ValueError for no frames, frames of different sizes, or ``fps`` outside (0, 100]."""
    _check_fps(fps)
    if not frames:
        raise ValueError("no frames to write")
    h, w = frames[0].shape[:2]
    if any(f.shape[:2] != (h, w) for f in frames):
        raise ValueError("all frames must have the same size")
    pal = gif_palette(frames)
    images = [Image.fromarray(np.ascontiguousarray(f[..., ::-1]), "RGB")
              .quantize(palette=pal, dither=Image.Dither.NONE) for f in frames]
    delay_ms = gif_delay_ms(fps)
    images[0].save(out_path, format="GIF", save_all=True, append_images=images[1:],
                   duration=delay_ms, loop=loop, optimize=False)

"""Loading, validating and writing: the only module that touches disk.

Inputs are read once and never modified. Outputs are written to a temporary
name in the target folder and renamed, so a crash or Ctrl-C never leaves a
half-written file under the final name.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from dynremove.errors import InputError

# Files with these suffixes are images (a file that then fails to decode is an
# error); any other file is an image when OpenCV or Pillow recognise its content
# (AVIF, HEIC/HEIF with the ``heic`` extra, GIF, ...), and is skipped with a note
# otherwise.
IMAGE_EXTS = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".jp2", ".ppm",
              ".pgm", ".pnm"}
AUTO_MAX_SIDE = 1280  # larger inputs are downscaled unless --max-side says otherwise
MIN_MAX_SIDE = 16  # smallest --max-side accepted (dense flow needs a side of >= 12 px)
HEIF_BRANDS = {b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"mif1", b"msf1"}
AVIF_BRANDS = {b"avif", b"avis"}
HEIC_EXTRA = "pip install 'dynremove[heic]'"
BORDER_MIN_FRACTION = 0.001  # black borders smaller than this (of the frame) are ignored
VIDEO_FRAMES = 7  # frames taken from a video by default


@dataclass
class ImageSet:
    """Images as processed (BGR uint8, same size), with their names and notes."""

    paths: list[Path]
    images: list[np.ndarray]
    original_size: tuple[int, int]  # (W, H) as read
    scale: float  # processed / original
    notes: list[str] = field(default_factory=list)
    # per image: (H, W) bool, True where the frame has content (alpha > 0, not a
    # black border, --valid-mask); None = content everywhere
    valid: list[np.ndarray | None] = field(default_factory=list)
    video: dict | None = None  # {"path", "frames": chosen frame numbers, ...} for a clip

    @property
    def valid_masks(self) -> list[np.ndarray] | None:
        """Every image's validity mask (all True where none), or None if all valid."""
        if not any(v is not None for v in self.valid):
            return None
        H, W = self.images[0].shape[:2]
        return [np.ones((H, W), bool) if v is None else v for v in self.valid]

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.paths]


def _head(path: Path, n: int = 64) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError:
        return b""


def _ftyp_brands(head: bytes) -> set[bytes]:
    """Major and compatible brands of an ISO-BMFF ``ftyp`` box (MP4, MOV, HEIF, AVIF)."""
    if len(head) < 12 or head[4:8] != b"ftyp":
        return set()
    size = int.from_bytes(head[:4], "big")
    end = min(len(head), size if size >= 16 else 16)
    brands = {head[8:12]}
    brands.update(head[i:i + 4] for i in range(16, end - 3, 4))
    return brands


def is_heif(head: bytes) -> bool:
    """HEIC/HEIF (not AVIF) by its ``ftyp`` brands."""
    b = _ftyp_brands(head)
    return bool(b & HEIF_BRANDS) and not (b & AVIF_BRANDS) and head[8:12] not in AVIF_BRANDS


def is_video_file(path: Path) -> bool:
    """A video container by content: MP4/MOV/3GP, AVI, Matroska/WebM, MPEG-TS/PS, FLV."""
    head = _head(path, 64)
    b = _ftyp_brands(head)
    if b:
        return not (b & (HEIF_BRANDS | AVIF_BRANDS))
    return (head[:4] == b"RIFF" and head[8:12] == b"AVI "
            or head[:4] == b"\x1a\x45\xdf\xa3"  # EBML: mkv, webm
            or head[:3] == b"FLV"
            or head[:4] == b"\x00\x00\x01\xba"  # MPEG program stream
            or (len(head) > 0 and head[0] == 0x47 and _head(path, 189)[188:189] == b"\x47"))


def is_image_file(path: Path) -> bool:
    """Whether OpenCV or Pillow recognises the file's content as an image (headers only)."""
    head = _head(path, 64)
    if not head:
        return False
    if is_heif(head):
        return True
    try:
        if cv2.haveImageReader(str(path)):
            return True
    except cv2.error:
        pass
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.format is not None
    except Exception:  # noqa: BLE001 - Pillow raises many kinds for "not mine"
        return False


def _listing(names: list[str], n: int = 5) -> str:
    return ", ".join(names[:n]) + (" …" if len(names) > n else "")


def list_inputs(args: Sequence[str | os.PathLike]) -> tuple[list[Path], list[str]]:
    """Expand folders and files; return image paths and notes.

    In a folder, a file is an image when its suffix is a common image suffix
    (``IMAGE_EXTS``; it must then decode) or when OpenCV or Pillow recognise its
    content; other files are skipped with a note that names them. Files given
    one by one are always read as images.
    """
    paths: list[Path] = []
    notes: list[str] = []
    for a in args:
        p = Path(a)
        if p.is_dir():
            try:
                entries = list(p.iterdir())
            except OSError as e:
                raise InputError(f"{p}: cannot list folder ({e.strerror or e})") from None
            files = sorted(q for q in entries if q.is_file() and not q.name.startswith("."))
            imgs, videos, skipped = [], [], []
            for q in files:
                if q.suffix.lower() in IMAGE_EXTS or is_image_file(q):
                    imgs.append(q)
                elif is_video_file(q):
                    videos.append(q.name)
                else:
                    skipped.append(q.name)
            if skipped:
                notes.append(f"{p}: skipped {len(skipped)} non-image file(s): "
                             + _listing(skipped))
            if videos:
                notes.append(f"{p}: skipped {len(videos)} video(s): {_listing(videos)} "
                             "(give a video alone to take frames from it)")
            if not imgs and len(args) > 1:
                raise InputError(f"{p}: is a folder with no images in it "
                                 "(pass image files, or one folder of images)")
            paths.extend(imgs)
        elif p.exists():
            paths.append(p)
        else:
            raise InputError(f"{p}: no such file or folder")
    if len(paths) < 2:
        raise InputError(f"need at least 2 images, found {len(paths)}"
                         + (f" in {', '.join(str(a) for a in args)}" if args else "")
                         + (f" ({'; '.join(notes)})" if notes else ""))
    return paths, notes


def read_image(path: Path) -> tuple[np.ndarray, list[str]]:
    """Read one image as (H, W, 3) uint8 BGR, EXIF orientation applied.

    Grayscale is expanded to 3 channels, alpha is dropped and 16-bit is scaled
    to 8 bits, each with a note. Unreadable files raise InputError.
    See :func:`read_image_valid` for the alpha channel as a validity mask.
    """
    img, _, notes = read_image_valid(path)
    return img, notes


def read_image_valid(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """Read one image as (H, W, 3) uint8 BGR and where it has content.

    Returns ``(image, valid, notes)``: ``valid`` is (H, W) bool, False where the
    alpha channel is 0 or where the frame is exactly black (0, 0, 0) in a region
    connected to its border (the empty border of a pre-aligned frame), None when
    the whole frame has content. Decoded by OpenCV, else Pillow (HEIC/HEIF
    through pillow-heif, the ``heic`` extra).
    """
    path = Path(path)
    notes: list[str] = []
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not an image")
    try:
        data = np.fromfile(str(path), np.uint8)
    except PermissionError:
        raise InputError(f"{path}: permission denied") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    if data.size == 0:
        raise InputError(f"{path}: empty file")
    head = data[:64].tobytes()
    img = None if is_heif(head) else cv2.imdecode(
        data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is not None and img.ndim == 3 and img.shape[2] == 3 and _png_has_alpha(data):
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)  # ANYCOLOR dropped the alpha
        if img is not None and img.ndim == 2:  # grey + alpha comes back grey: no alpha
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img is None:
        img = _read_with_pillow(path, head)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
        notes.append(f"{path.name}: 16-bit image scaled to 8 bits")
    elif img.dtype != np.uint8:
        notes.append(f"{path.name}: {img.dtype} image rescaled to 8 bits")
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    alpha = None
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        notes.append(f"{path.name}: grayscale image expanded to 3 channels")
    elif img.shape[2] == 4:
        alpha = img[:, :, 3]
        img = np.ascontiguousarray(img[:, :, :3])
    elif img.shape[2] == 2:  # grey + alpha (Pillow "LA")
        alpha = img[:, :, 1]
        img = cv2.cvtColor(np.ascontiguousarray(img[:, :, 0]), cv2.COLOR_GRAY2BGR)
    valid = content_mask(img, alpha)
    if alpha is not None and valid is None:
        notes.append(f"{path.name}: alpha channel dropped (no transparent pixels)")
    elif valid is not None:
        how = "transparent (alpha 0) or black border" if alpha is not None else "black border"
        notes.append(f"{path.name}: {100 * (1 - valid.mean()):.1f} % without content "
                     f"({how}): never flagged, never used as fill")
    return img, valid, notes


def _read_with_pillow(path: Path, head: bytes) -> np.ndarray:
    """Decode what OpenCV cannot (HEIC/HEIF with pillow-heif, GIF, ...) as BGR(A)."""
    if is_heif(head):
        try:
            import pillow_heif
        except ImportError:
            raise InputError(f"{path}: HEIC/HEIF image; reading it needs the optional "
                             f"extra: {HEIC_EXTRA}") from None
        pillow_heif.register_heif_opener()
    try:
        from PIL import Image, ImageOps

        with Image.open(path) as im:
            im = ImageOps.exif_transpose(im)
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im).astype(np.uint16)
            elif im.mode in ("LA", "PA", "RGBA") or "transparency" in im.info:
                arr = np.asarray(im.convert("RGBA"))
                arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGRA)
            elif im.mode in ("L", "1"):
                arr = np.asarray(im.convert("L"))
            else:
                arr = cv2.cvtColor(np.asarray(im.convert("RGB")), cv2.COLOR_RGB2BGR)
    except InputError:
        raise
    except Exception:  # noqa: BLE001 - any decoder failure is "not readable"
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)"
                         ) from None
    return np.ascontiguousarray(arr)


def content_mask(img: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray | None:
    """Where a frame has content: (H, W) bool, or None when it has content everywhere.

    No content: alpha 0 anywhere, or exactly black (0, 0, 0, or alpha 0) in a
    region connected to the frame's border -- the empty border that alignment
    tools leave. Black borders smaller than ``BORDER_MIN_FRACTION`` of the frame
    are ignored (a few clipped dark pixels are not a border).

    Examples
    --------
    >>> im = np.full((5, 5, 3), 9, np.uint8); im[:, :2] = 0
    >>> content_mask(im).sum(axis=1).tolist()
    [3, 3, 3, 3, 3]
    """
    H, W = img.shape[:2]
    empty = ~img.any(axis=2)
    if alpha is not None:
        empty |= alpha == 0
    if not (empty[0].any() or empty[-1].any() or empty[:, 0].any() or empty[:, -1].any()):
        border = np.zeros((H, W), bool)
    else:
        n, lab = cv2.connectedComponents(empty.astype(np.uint8), connectivity=4)
        touch = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        touch = touch[touch > 0]
        border = np.isin(lab, touch)
    if border.sum() < BORDER_MIN_FRACTION * H * W:
        border[:] = False
    invalid = border if alpha is None else border | (alpha == 0)
    return ~invalid if invalid.any() else None


def _png_has_alpha(data: np.ndarray) -> bool:
    """PNG colour type 4 (grey + alpha) or 6 (RGBA), read from the IHDR chunk."""
    return (data.size > 25 and data[:8].tobytes() == b"\x89PNG\r\n\x1a\n"
            and data[12:16].tobytes() == b"IHDR" and int(data[25]) in (4, 6))


def read_valid_masks(spec: str | os.PathLike, paths: Sequence[Path],
                     sizes: Sequence[tuple[int, int]]) -> list[np.ndarray | None]:
    """``--valid-mask``: one PNG for every image, or a folder of ``<image stem>.png``.

    White (> 127) = content, black = no content. In a folder, an image without a
    mask of its own has content everywhere. ``sizes`` are the images' (W, H).
    """
    p = Path(spec)
    out: list[np.ndarray | None] = []
    if p.is_dir():
        for q, size in zip(paths, sizes):
            m = p / (Path(q.name.split("#")[0]).stem + ".png")
            out.append(_valid_mask_file(m, size) if m.is_file() else None)
        if not any(m is not None for m in out):
            raise InputError(f"--valid-mask {p}: holds no <image name>.png for any input "
                             f"(e.g. {Path(paths[0].name).stem}.png)")
        return out
    if not p.is_file():
        raise InputError(f"--valid-mask {p}: no such file or folder")
    return [_valid_mask_file(p, size) for size in sizes]


def _valid_mask_file(p: Path, size: tuple[int, int]) -> np.ndarray:
    m = cv2.imdecode(np.fromfile(str(p), np.uint8), cv2.IMREAD_UNCHANGED) \
        if p.stat().st_size else None
    if m is None:
        raise InputError(f"--valid-mask {p}: not a readable mask image")
    if m.ndim == 3:
        m = m[:, :, 3] if m.shape[2] == 4 else m.max(axis=2)
    if (m.shape[1], m.shape[0]) != tuple(size):
        raise InputError(f"--valid-mask {p}: is {m.shape[1]}x{m.shape[0]}, the image is "
                         f"{size[0]}x{size[1]}")
    return m > (127 if m.dtype == np.uint8 else 32767)


def load_image_set(args: Sequence[str | os.PathLike], *, max_side: int | None = None,
                   valid_mask: str | os.PathLike | None = None,
                   frames: int | None = None, span: str | None = None,
                   pick: str = "sharpest") -> ImageSet:
    """Read and validate a set: same size for all, downscaled to ``max_side``.

    ``max_side=None`` downscales only images larger than AUTO_MAX_SIDE (with a note);
    ``max_side=0`` never downscales. One video file instead of images: ``frames``
    frames are taken from ``span`` (see :func:`read_video`). ``valid_mask``: see
    :func:`read_valid_masks`; it is combined with the alpha channel and black borders.
    """
    if max_side is not None and max_side != 0 and max_side < MIN_MAX_SIDE:
        raise InputError(f"--max-side {max_side}: must be 0 (keep the full size) or at "
                         f"least {MIN_MAX_SIDE} px")
    video = None
    if (len(args) == 1 and Path(args[0]).is_file() and is_video_file(Path(args[0]))
            and Path(args[0]).suffix.lower() not in IMAGE_EXTS):
        images, idx, notes = read_video(args[0], frames=frames, span=span, pick=pick)
        vp = Path(args[0])
        paths = [Path(f"{vp}#{i}") for i in idx]
        valids = [content_mask(im) for im in images]
        video = {"path": str(vp), "frames": idx, "pick": pick}
    else:
        if frames is not None or span is not None:
            raise InputError("--frames and --span take frames from a video; the inputs are "
                             "images")
        paths, notes = list_inputs(args)
        images, valids = [], []
        for p in paths:
            img, v, n = read_image_valid(p)
            images.append(img)
            valids.append(v)
            notes.extend(n)
    H0, W0 = images[0].shape[:2]
    for p, im in zip(paths, images):
        if im.shape[:2] != (H0, W0):
            raise InputError(f"{p}: is {im.shape[1]}x{im.shape[0]} but {paths[0].name} is "
                             f"{W0}x{H0}; all images must have the same size")
    if valid_mask is not None:
        given = read_valid_masks(valid_mask, paths, [(W0, H0)] * len(paths))
        valids = [g if v is None else (v if g is None else v & g)
                  for v, g in zip(valids, given)]
        n_in = sum(g is not None for g in given)
        notes.append(f"--valid-mask: masks for {n_in} of {len(paths)} images")
    side = max(H0, W0)
    target = max_side
    if max_side is None and side > AUTO_MAX_SIDE:
        target = AUTO_MAX_SIDE
        notes.append(f"images are {W0}x{H0}: downscaled to at most {AUTO_MAX_SIDE} px "
                     "(use --max-side to choose, 0 to keep the full size)")
    scale = 1.0
    if target and side > target:
        scale = target / side
        size = (max(8, round(W0 * scale)), max(8, round(H0 * scale)))
        images = [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in images]
        # a pixel has content when all it was averaged from had content
        valids = [None if v is None else
                  cv2.resize(v.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
                  for v in valids]
    for i, v in enumerate(valids):
        if v is not None and v.mean() < 0.05:
            raise InputError(f"{paths[i]}: has content in only {100 * v.mean():.1f} % of "
                             "the frame (alpha 0, black border or --valid-mask)")
    return ImageSet(paths=paths, images=images, original_size=(W0, H0), scale=scale,
                    notes=notes, valid=valids, video=video)


# --- video --------------------------------------------------------------------------
def parse_span(span: str | None, n_total: int) -> tuple[int, int]:
    """``START:END`` frame numbers (END excluded; either may be empty) -> (start, end)."""
    if not span:
        return 0, n_total
    a, sep, b = span.partition(":")
    try:
        start = int(a) if a.strip() else 0
        end = int(b) if b.strip() else n_total
    except ValueError:
        start = end = -1
    if not sep or start < 0 or end < 0:
        raise InputError(f"--span {span}: expected START:END, frame numbers >= 0 "
                         "(either may be empty)")
    end = min(end, n_total)
    if start >= end:
        raise InputError(f"--span {span}: no frames (the clip has {n_total}: 0..{n_total - 1})")
    return start, end


def sharpness(img: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Variance of the Laplacian of the grey image (at most 640 px), over ``valid``."""
    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    f = min(1.0, 640.0 / max(g.shape))
    if f < 1.0:
        size = (max(1, round(g.shape[1] * f)), max(1, round(g.shape[0] * f)))
        g = cv2.resize(g, size, interpolation=cv2.INTER_AREA)
        if valid is not None:
            valid = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    lap = cv2.Laplacian(g, cv2.CV_32F, ksize=3)
    if valid is not None:
        inner = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        lap = lap[inner] if inner.any() else lap
    return float(lap.var())


def read_video(path: str | os.PathLike, *, frames: int | None = None,
               span: str | None = None, pick: str = "sharpest"
               ) -> tuple[list[np.ndarray], list[int], list[str]]:
    """Take ``frames`` frames (default 7) from a clip, one per even window of ``span``.

    ``pick="sharpest"``: the frame of each window with the largest variance of the
    Laplacian; ``"even"``: the window's centre. Returns images (BGR uint8), their
    frame numbers (0-based) and notes. Read with OpenCV (FFmpeg) in one pass.
    """
    p = Path(path)
    n_want = VIDEO_FRAMES if frames is None else int(frames)
    if n_want < 2:
        raise InputError(f"--frames {n_want}: need at least 2")
    if pick not in ("sharpest", "even"):
        raise InputError(f"--pick {pick}: expected 'sharpest' or 'even'")
    cap = cv2.VideoCapture(str(p))
    try:
        if not cap.isOpened():
            raise InputError(f"{p}: a video OpenCV cannot open (damaged, or a codec "
                             "this OpenCV build lacks)")
        n_total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if n_total <= 0:  # some containers do not say: count
            n_total = 0
            while cap.grab():
                n_total += 1
            cap.release()
            cap = cv2.VideoCapture(str(p))
        start, end = parse_span(span, n_total)
        n = min(n_want, end - start)
        if n < 2:
            raise InputError(f"{p}: need at least 2 frames, the span has {end - start}")
        notes = []
        if n < n_want:
            notes.append(f"{p.name}: only {n} frames in the span, all taken")
        edges = [start + round(k * (end - start) / n) for k in range(n + 1)]
        centres = [(edges[k] + edges[k + 1] - 1) // 2 for k in range(n)]
        best: list[tuple[float, int, np.ndarray | None]] = [(-1.0, -1, None)] * n
        if start:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        i, k = start, 0
        last = centres[-1] if pick == "even" else end - 1
        while i <= last:
            ok = cap.grab()
            if not ok:
                break
            while k + 1 < n and i >= edges[k + 1]:
                k += 1
            if pick == "even":
                if i == centres[k]:
                    ok, fr = cap.retrieve()
                    if ok:
                        best[k] = (0.0, i, fr)
            else:
                ok, fr = cap.retrieve()
                if ok:
                    s = sharpness(fr)
                    if s > best[k][0]:
                        best[k] = (s, i, fr)
            i += 1
    finally:
        cap.release()
    got = [(idx, fr) for _, idx, fr in best if fr is not None]
    if len(got) < 2:
        raise InputError(f"{p}: could read {len(got)} frame(s) of the span "
                         f"{start}:{end} (truncated or unsupported video)")
    if len(got) < n:
        notes.append(f"{p.name}: {n - len(got)} window(s) had no readable frame")
    notes.append(f"{p.name}: {len(got)} frames of {n_total} taken ({pick}, span "
                 f"{start}:{end}): " + ", ".join(str(idx) for idx, _ in got))
    return [fr for _, fr in got], [idx for idx, _ in got], notes


# --- the reference ------------------------------------------------------------------
def keypoint_matches(images: Sequence[np.ndarray], *, max_side: int = 640,
                     n_features: int = 1500) -> np.ndarray:
    """(V, V) int: SIFT matches passing Lowe's ratio test (0.75) between every pair."""
    sift = cv2.SIFT_create(nfeatures=n_features)
    desc = []
    for im in images:
        g = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
        f = min(1.0, max_side / max(g.shape))
        if f < 1.0:
            g = cv2.resize(g, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
        desc.append(sift.detectAndCompute(g, None)[1])
    V = len(images)
    M = np.zeros((V, V), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    for i in range(V):
        for j in range(i + 1, V):
            if desc[i] is None or desc[j] is None or len(desc[i]) < 2 or len(desc[j]) < 2:
                continue
            pairs = bf.knnMatch(desc[i], desc[j], k=2)
            M[i, j] = M[j, i] = sum(1 for m in pairs
                                    if len(m) == 2 and m[0].distance < 0.75 * m[1].distance)
    return M


def auto_reference(images: Sequence[np.ndarray], names: Sequence[str],
                   valid: Sequence[np.ndarray | None] | None = None
                   ) -> tuple[int, str, dict]:
    """``--ref auto``: the frame with the most keypoint matches among the sharp ones.

    Sharp: variance of the Laplacian at least half the sharpest frame's. Returns
    the index, a one-line note and the figures (for the report).
    """
    valid = list(valid) if valid else [None] * len(images)
    sharp = [sharpness(im, v) for im, v in zip(images, valid)]
    M = keypoint_matches(images)
    matches = M.sum(axis=1)
    cands = [i for i in range(len(images)) if sharp[i] >= 0.5 * max(sharp)]
    best = max(cands, key=lambda i: (matches[i], sharp[i]))
    mid = len(images) // 2
    note = (f"--ref auto: {names[best]} (sharpness {sharp[best]:.0f}, {int(matches[best])} "
            f"keypoint matches with the others; the middle frame {names[mid]}: "
            f"{sharp[mid]:.0f}, {int(matches[mid])})")
    info = {"sharpness": [round(s, 1) for s in sharp], "matches": matches.tolist()}
    return best, note, info


def blurry_reference_note(images: Sequence[np.ndarray], ref: int, names: Sequence[str],
                          valid: Sequence[np.ndarray | None] | None = None,
                          *, ratio: float = 0.5) -> str | None:
    """A note suggesting ``--ref auto`` when the reference is much blurrier than the
    others (variance of the Laplacian below ``ratio`` x the others' median)."""
    valid = list(valid) if valid else [None] * len(images)
    sharp = [sharpness(im, v) for im, v in zip(images, valid)]
    others = [s for i, s in enumerate(sharp) if i != ref]
    med = float(np.median(others)) if others else 0.0
    if med <= 0 or sharp[ref] >= ratio * med:
        return None
    return (f"the reference {names[ref]} is much blurrier than the others (variance of "
            f"the Laplacian {sharp[ref]:.0f} vs a median of {med:.0f}): try --ref auto")


def resolve_ref(ref: str | int | None, names: Sequence[str]) -> int:
    """Reference by index (negative counts from the end) or by file name; default middle."""
    if ref is None or ref == "":
        return len(names) // 2
    if isinstance(ref, int) or (isinstance(ref, str) and ref.lstrip("-").isdigit()):
        i = int(ref)
        if not -len(names) <= i < len(names):
            raise InputError(f"--ref {ref}: out of range, there are {len(names)} images "
                             f"(0..{len(names) - 1})")
        return i % len(names)
    matches = [i for i, n in enumerate(names) if n == ref or Path(n).stem == ref
               or Path(str(ref)).name == n]
    if not matches:
        raise InputError(f"--ref {ref}: names no input image (have {', '.join(names[:8])}"
                         + (" …" if len(names) > 8 else "") + ")")
    return matches[0]


def read_mask(path: str | os.PathLike, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read a 0/255 mask as (H, W) bool, resized (nearest) to ``size`` = (W, H)."""
    p = Path(path)
    m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if m is None:
        raise InputError(f"{p}: not a readable mask image")
    if size is not None and (m.shape[1], m.shape[0]) != tuple(size):
        m = cv2.resize(m, tuple(size), interpolation=cv2.INTER_NEAREST)
    return m > 127


def prepare_out_dir(out: str | os.PathLike) -> Path:
    """Create the output folder; InputError if it is a file or not writable."""
    p = Path(out)
    if p.exists() and not p.is_dir():
        raise InputError(f"--out {p}: exists and is not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {p}: cannot create ({e.strerror or e})") from None
    if not os.access(p, os.W_OK):
        raise InputError(f"--out {p}: not writable")
    return p


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs follow the umask
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_image(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an image atomically (format from the suffix)."""
    p = Path(path)
    ok, buf = cv2.imencode(p.suffix or ".png", img)
    if not ok:
        raise OSError(f"could not encode {p}")
    _atomic_write_bytes(p, buf.tobytes())


def photo_metadata(path: str | os.PathLike) -> dict:
    """EXIF (orientation reset to 1: pixels are read upright) and ICC profile of a photo.

    Returns the keyword arguments for Pillow's ``Image.save`` (``exif``,
    ``icc_profile``), empty when the file has neither or Pillow cannot open it.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            out: dict = {}
            exif = im.getexif()
            if exif:
                exif[0x0112] = 1  # Orientation: the written pixels are already upright
                out["exif"] = exif.tobytes()
            icc = im.info.get("icc_profile")
            if icc:
                out["icc_profile"] = icc
            return out
    except (OSError, UnidentifiedImageError, ValueError):
        return {}


def write_photo(path: str | os.PathLike, img: np.ndarray, *, like: str | os.PathLike | None
                ) -> None:
    """Write a BGR image atomically, carrying ``like``'s EXIF and ICC profile (Pillow)."""
    meta = photo_metadata(like) if like is not None else {}
    if not meta:
        write_image(path, img)
        return
    import io as _io

    from PIL import Image

    p = Path(path)
    buf = _io.BytesIO()
    fmt = {".jpg": "JPEG", ".jpeg": "JPEG", ".png": "PNG", ".tif": "TIFF",
           ".tiff": "TIFF"}.get(p.suffix.lower(), "PNG")
    extra = {"quality": 95} if fmt == "JPEG" else {}
    Image.fromarray(np.ascontiguousarray(img[..., ::-1])).save(buf, format=fmt, **meta, **extra)
    _atomic_write_bytes(p, buf.getvalue())


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write JSON atomically (numpy scalars and arrays converted)."""
    _atomic_write_bytes(Path(path), (json.dumps(obj, indent=2, default=_jsonable) + "\n").encode())


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")

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

IMAGE_EXTS = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".jp2", ".ppm",
              ".pgm", ".pnm"}
AUTO_MAX_SIDE = 1280  # larger inputs are downscaled unless --max-side says otherwise
MIN_MAX_SIDE = 16  # smallest --max-side accepted (dense flow needs a side of >= 12 px)


@dataclass
class ImageSet:
    """Images as processed (BGR uint8, same size), with their names and notes."""

    paths: list[Path]
    images: list[np.ndarray]
    original_size: tuple[int, int]  # (W, H) as read
    scale: float  # processed / original
    notes: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.paths]


def list_inputs(args: Sequence[str | os.PathLike]) -> tuple[list[Path], list[str]]:
    """Expand folders (image files sorted by name) and files; return paths and notes."""
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
            imgs = [q for q in files if q.suffix.lower() in IMAGE_EXTS]
            skipped = [q.name for q in files if q.suffix.lower() not in IMAGE_EXTS]
            if skipped:
                notes.append(f"{p}: skipped {len(skipped)} non-image file(s): "
                             + ", ".join(skipped[:5]) + (" …" if len(skipped) > 5 else ""))
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
    """
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
    img = cv2.imdecode(data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None:
        raise InputError(f"{path}: not a readable image (corrupt or unsupported format)")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
        notes.append(f"{path.name}: 16-bit image scaled to 8 bits")
    elif img.dtype != np.uint8:
        notes.append(f"{path.name}: {img.dtype} image rescaled to 8 bits")
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        notes.append(f"{path.name}: grayscale image expanded to 3 channels")
    elif img.shape[2] == 4:
        img = np.ascontiguousarray(img[:, :, :3])
        notes.append(f"{path.name}: alpha channel dropped")
    elif _png_has_alpha(data):  # IMREAD_ANYCOLOR already dropped it: say so
        notes.append(f"{path.name}: alpha channel dropped")
    return img, notes


def _png_has_alpha(data: np.ndarray) -> bool:
    """PNG colour type 4 (grey + alpha) or 6 (RGBA), read from the IHDR chunk."""
    return (data.size > 25 and data[:8].tobytes() == b"\x89PNG\r\n\x1a\n"
            and data[12:16].tobytes() == b"IHDR" and int(data[25]) in (4, 6))


def load_image_set(args: Sequence[str | os.PathLike], *, max_side: int | None = None) -> ImageSet:
    """Read and validate a set: same size for all, downscaled to ``max_side``.

    ``max_side=None`` downscales only images larger than AUTO_MAX_SIDE (with a note);
    ``max_side=0`` never downscales.
    """
    if max_side is not None and max_side != 0 and max_side < MIN_MAX_SIDE:
        raise InputError(f"--max-side {max_side}: must be 0 (keep the full size) or at "
                         f"least {MIN_MAX_SIDE} px")
    paths, notes = list_inputs(args)
    images = []
    for p in paths:
        img, n = read_image(p)
        images.append(img)
        notes.extend(n)
    H0, W0 = images[0].shape[:2]
    for p, im in zip(paths, images):
        if im.shape[:2] != (H0, W0):
            raise InputError(f"{p}: is {im.shape[1]}x{im.shape[0]} but {paths[0].name} is "
                             f"{W0}x{H0}; all images must have the same size")
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
    return ImageSet(paths=paths, images=images, original_size=(W0, H0), scale=scale, notes=notes)


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

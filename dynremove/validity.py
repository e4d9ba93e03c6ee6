"""Where a frame has content: alpha 0 and black alignment borders, and ``--valid-mask``.

Pixels without content are never flagged and never used as fill.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from dynremove.errors import InputError

BORDER_MIN_FRACTION = 0.001  # black borders smaller than this (of the frame) are ignored


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
    empty = _black(img)
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


def _black(img: np.ndarray) -> np.ndarray:
    """Where every channel of ``img`` (H, W, C) is 0: (H, W) bool. By ``cv2.inRange``
    for 8- and 16-bit images of 1 to 4 channels: 8 against 130-150 ms for NumPy's
    ``~img.any(axis=2)`` on a 12 MP photo, read twice per photo by ``dynremove run``
    (session 62: 1.5 s of a 15-18 s run on five 12 MP JPEGs)."""
    if img.ndim == 3 and 1 <= img.shape[2] <= 4 and img.dtype in (np.uint8, np.uint16):
        zero = (0,) * img.shape[2]
        return cv2.inRange(img, zero, zero) > 0
    return ~img.any(axis=2)


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

"""Side-by-side panel of the real hand-held bursts: reference | default | median stack.

Usage::

    python examples/burst_panel.py [DATA_DIR] [--out examples/bursts_panel.jpg]
    python examples/burst_panel.py --views 1,3,4 --out examples/bursts_three_panel.jpg

DATA_DIR defaults to ``$DYNREMOVE_DATA`` or ``../shared/data``; the bursts are the
``bursts/<set>/frames`` folders below it (reference: the middle frame of those
used). ``--views`` keeps only those frames of each burst (0-based, in name order):
three photos, the sparse hand-held case. Each row is one burst, scaled to 360 px high.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np

from dynremove import io, remove_dynamic
from dynremove.evaluation.baselines import median_baseline


REPO = Path(__file__).resolve().parents[1]


def _label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.rectangle(out, (0, 0), (out.shape[1], 26), (0, 0, 0), -1)
    # the font shrinks to fit the tile (a long name ran under the next tile)
    (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
    scale = min(0.6, 0.6 * (out.shape[1] - 12) / max(tw, 1))
    cv2.putText(out, text, (6, 19), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?",
                    default=os.environ.get("DYNREMOVE_DATA", str(REPO.parent / "shared" / "data")),
                    help="the data folder, which holds bursts/<set>/frames/*.jpg (default "
                         "$DYNREMOVE_DATA, else ../shared/data beside the project: "
                         "%(default)s)")
    ap.add_argument("--out", default=str(REPO / "examples" / "bursts_panel.jpg"),
                    help="the panel image, .png or .jpg (default: the README's, "
                         "examples/bursts_panel.jpg in the project)")
    ap.add_argument("--height", type=int, default=360, help="row height (px)")
    ap.add_argument("--views", default=None,
                    help="only these frames of each burst, 0-based, e.g. 1,3,4 (default: all)")
    args = ap.parse_args(argv)
    try:
        keep = None if args.views is None else [int(v) for v in args.views.split(",")]
    except ValueError:
        print(f"--views {args.views!r}: give frame numbers, e.g. 1,3,4", file=sys.stderr)
        return 2
    if not cv2.haveImageWriter(args.out):  # (before 20 s of runs, not after them)
        print(f"--out {args.out}: not an image format OpenCV writes (use .png or .jpg)",
              file=sys.stderr)
        return 2
    root = Path(args.data) / "bursts"
    sets = sorted(p.parent for p in root.glob("*/frames"))
    if not sets:
        print(f"no bursts under {root}", file=sys.stderr)
        return 2
    rows = []
    for s in sets:
        iset = io.load_image_set([s / "frames"])
        images, names = iset.images, iset.names
        if keep is not None:
            if max(keep) >= len(images) or min(keep) < 0:
                print(f"{s.name}: --views {args.views} outside 0..{len(images) - 1}",
                      file=sys.stderr)
                return 2
            images, names = [images[k] for k in keep], [names[k] for k in keep]
        ref = len(images) // 2
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = remove_dynamic(images, ref=ref, names=names)
            med, _ = median_baseline(images, ref, align="homography")
        h = args.height
        tiles = []
        for img, text in ((images[ref], f"{s.name}: reference {names[ref]}"),
                          (res.clean, "dynremove (default)"), (med, "median stack")):
            w = round(img.shape[1] * h / img.shape[0])
            tiles.append(_label(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA), text))
        rows.append(np.hstack(tiles))
        print(f"{s.name}: {int(res.dynamic.sum())} px replaced", file=sys.stderr)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    io.write_image(Path(args.out), np.vstack(rows))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

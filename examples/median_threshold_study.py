"""Choose the global Lab threshold of the median-stack baseline.

For each alignment mode ("homography", "homography+flow") and each DAVIS set
(reference = middle image of the sorted frames), the median background is
computed once, then :func:`dynremove.evaluation.baselines.median_detect` is run for every
candidate threshold and scored by Jaccard against the reference's GT mask. The
threshold with the best MEAN Jaccard over all sets is reported per mode, with the
per-set Jaccard at that value and the run time of the baseline per set.

Usage::

    python examples/median_threshold_study.py [--data PATH] [--jobs 2]

``--data`` defaults to ``$DYNREMOVE_DATA`` or ``<repo>/../shared/data``. Nothing
is written to disk.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from dynremove.evaluation import baselines, metrics

REPO = Path(__file__).resolve().parents[1]
DEFAULT_THRESHOLDS = (6, 8, 10, 12, 15, 18, 22, 26, 30)


def default_data() -> Path:
    env = os.environ.get("DYNREMOVE_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def load_set(set_dir: Path) -> tuple[list[np.ndarray], int, np.ndarray]:
    """Frames (BGR), reference index (middle) and the reference GT mask."""
    frames = sorted((set_dir / "frames").glob("*.jpg"))
    if not frames:
        raise FileNotFoundError(f"no frames in {set_dir / 'frames'}")
    images = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in frames]
    ref = len(frames) // 2
    mask_path = set_dir / "masks" / (frames[ref].stem + ".png")
    gt = metrics.mask_from_png(cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE))
    return images, ref, gt


def study_set(set_dir: Path, align: str, thresholds, seed: int) -> dict:
    """Jaccard per threshold for one set and one alignment mode."""
    cv2.setNumThreads(1)  # parallelism comes from joblib
    images, ref, gt = load_set(set_dir)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", baselines.AlignmentFallbackWarning)
        t0 = time.perf_counter()
        background, count = baselines.median_stack(images, ref, align=align, seed=seed)
        t_stack = time.perf_counter() - t0
    fallbacks = sum(
        issubclass(w.category, baselines.AlignmentFallbackWarning) for w in caught
    )
    jac, t_detect = [], []
    for thr in thresholds:
        t0 = time.perf_counter()
        dyn = baselines.median_detect(images[ref], background, threshold=thr)
        t_detect.append(time.perf_counter() - t0)
        jac.append(metrics.jaccard(dyn, gt))
    return {
        "set": set_dir.name,
        "align": align,
        "jaccard": np.array(jac),
        "seconds": t_stack + float(np.mean(t_detect)),
        "fallbacks": fallbacks,
        "mean_count": float(count.mean()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=default_data(),
                    help="shared data root holding davis/ (default: %(default)s)")
    ap.add_argument("--collection", default="davis",
                    help="sub-directory of --data with <set>/frames, <set>/masks")
    ap.add_argument("--thresholds", type=float, nargs="+",
                    default=list(DEFAULT_THRESHOLDS), help="Lab thresholds to try")
    ap.add_argument("--align", nargs="+", default=list(baselines.ALIGN_MODES),
                    choices=baselines.ALIGN_MODES)
    ap.add_argument("--jobs", type=int, default=2, help="joblib workers")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    root = args.data / args.collection
    sets = []
    if root.is_dir():
        sets = sorted(p for p in root.iterdir() if (p / "masks").is_dir())
    if not sets:
        ap.error(f"no <set>/masks directories under {root}")
    thresholds = [float(t) for t in args.thresholds]

    from joblib import Parallel, delayed

    jobs = [(s, a) for a in args.align for s in sets]
    results = Parallel(n_jobs=args.jobs)(
        delayed(study_set)(s, a, thresholds, args.seed) for s, a in jobs
    )

    for align in args.align:
        rows = [r for r in results if r["align"] == align]
        J = np.stack([r["jaccard"] for r in rows])  # (n_sets, n_thresholds)
        mean = J.mean(axis=0)
        best = int(np.argmax(mean))
        print(f"\n== align = {align}  ({len(rows)} sets) ==")
        print("threshold  " + " ".join(f"{t:6.1f}" for t in thresholds))
        print("mean J     " + " ".join(f"{m:6.3f}" for m in mean))
        print("median J   " + " ".join(f"{m:6.3f}" for m in np.median(J, axis=0)))
        print(f"best threshold {thresholds[best]:g}: mean J {mean[best]:.3f}")
        print(f"{'set':22s} {'J@best':>7s} {'J_max':>6s} {'thr*':>5s} "
              f"{'sec':>6s} {'fallbk':>6s} {'views':>5s}")
        for r in rows:
            j = r["jaccard"]
            print(f"{r['set']:22s} {j[best]:7.3f} {j.max():6.3f} "
                  f"{thresholds[int(np.argmax(j))]:5.0f} {r['seconds']:6.2f} "
                  f"{r['fallbacks']:6d} {r['mean_count']:5.2f}")
        secs = [r["seconds"] for r in rows]
        print(f"median_baseline time per set: mean {np.mean(secs):.2f} s, "
              f"max {np.max(secs):.2f} s (1 OpenCV thread, {args.jobs} jobs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

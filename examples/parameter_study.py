"""Parameter study: one setting for all sets, fitted on half, checked on the other.

Sets (``<set>/frames`` + ``<set>/masks``) are sorted by name; even indices are
the *fit* half, odd indices the *check* half. Each grid point is one Params
(a preset with changes); the table gives the mean Jaccard of the reference's
dynamic map on each half and overall. Choose on "fit", report "check".

    python examples/parameter_study.py ../shared/data/davis \\
        --grid "t_r=0.25,0.3,0.35 patch_size=9,13" --preset default --jobs 2

The README's parameter choices were made with this script (see "Results").
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import time
from pathlib import Path

import numpy as np
from joblib import Parallel, delayed

from dynremove.evaluation.evaluate import find_sets, load_set
from dynremove.evaluation.metrics import jaccard
from dynremove.params import PRESETS, Params, preset
from dynremove.pipeline import remove_dynamic


def parse_grid(spec: str) -> list[dict]:
    """"a=1,2 b=x,y" → the product [{a: 1, b: "x"}, ...], typed by Params' fields."""
    types = {f.name: str(f.type) for f in dataclasses.fields(Params)}
    axes = []
    for part in spec.split():
        key, _, vals = part.partition("=")
        if key not in types:
            raise SystemExit(f"--grid: {key!r} is not a Params field")
        conv = {"int": int, "float": float, "bool": lambda v: v.lower() in ("1", "true")}
        axes.append([(key, conv.get(types[key], str)(v)) for v in vals.split(",")])
    return [dict(c) for c in itertools.product(*axes)] if axes else [{}]


def _one(es, base: str, grid: list[dict], max_side: int | None) -> list[float]:
    import warnings

    import cv2

    cv2.setNumThreads(1)
    ls = load_set(es, max_side=max_side)
    out = []
    for changes in grid:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = remove_dynamic(ls.images, ref=ls.ref, params=preset(base).replace(**changes))
        out.append(jaccard(r.dynamic, ls.gt) if ls.gt is not None else float("nan"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    data = Path(os.environ.get("DYNREMOVE_DATA",
                               str(Path(__file__).resolve().parents[2] / "shared" / "data")))
    ap.add_argument("data", nargs="?", default=str(data / "davis"),
                    help="the sets to score: folders with frames/ and masks/ (default "
                         "$DYNREMOVE_DATA/davis, else ../shared/data/davis beside the "
                         "project: %(default)s)")
    ap.add_argument("--grid", default="t_r=0.25,0.3,0.35",
                    help='Params fields and their values, e.g. "t_r=0.3,0.4 patch_size=9,13" '
                         "(default %(default)s)")
    ap.add_argument("--preset", default="default", choices=sorted(PRESETS),
                    help="the preset the grid changes (default %(default)s)")
    ap.add_argument("--max-side", type=int, default=None, help="downscale sets (px)")
    ap.add_argument("--jobs", type=int, default=2,
                    help="sets run in parallel (default %(default)s)")
    ap.add_argument("--json", default=None, help="write every figure here")
    args = ap.parse_args()
    sets = find_sets(args.data)
    grid = parse_grid(args.grid)
    t0 = time.time()
    J = np.array(Parallel(n_jobs=args.jobs)(delayed(_one)(s, args.preset, grid, args.max_side)
                                           for s in sets))  # (sets, grid)
    fit, check = J[0::2], J[1::2]
    print(f"{len(sets)} sets ({len(fit)} fit / {len(check)} check), preset {args.preset}, "
          f"{time.time() - t0:.0f} s")
    print(f"{'setting':<48}{'fit':>7}{'check':>7}{'all':>7}")
    best = int(np.nanargmax(np.nanmean(fit, 0)))
    for g, changes in enumerate(grid):
        mark = "  <- best on fit" if g == best else ""
        print(f"{json.dumps(changes):<48}{np.nanmean(fit[:, g]):>7.3f}{np.nanmean(check[:, g]):>7.3f}"
              f"{np.nanmean(J[:, g]):>7.3f}{mark}")
    if args.json:
        Path(args.json).write_text(json.dumps({
            "sets": [s.name for s in sets], "grid": grid, "jaccard": J.tolist(),
            "fit": [s.name for s in sets[0::2]], "best": grid[best]}, indent=2))


if __name__ == "__main__":
    main()

"""Teaching demo: a 160×120 synthetic scene where every pixel step is recorded.

    python examples/teaching_demo.py            # -> recordings/teaching.rrd
    dynremove view recordings/teaching.rrd

Every decision (static ones included) is recorded and the reference is
snapshot after every row, so scrubbing the ``step`` timeline replays the paper's
scan pixel by pixel. See recordings/README.md for what to look at.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from dynremove import preset, remove_dynamic
from dynremove.errors import InputError
from dynremove.io import check_out_file
from dynremove.params import PRESETS
from dynremove.evaluation import synth
from dynremove.evaluation.metrics import jaccard
from viewer import RerunSink

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "recordings" / "teaching.rrd"),
                    help="the recording to write, a .rrd file (default recordings/teaching.rrd)")
    ap.add_argument("--preset", default="paper", choices=sorted(PRESETS),
                    help="paper (default) or default")
    ap.add_argument("--seed", type=int, default=1, help="the synthetic scene's seed")
    args = ap.parse_args()
    if Path(args.out).suffix.lower() != ".rrd":  # (as run --record: a trial's x.txt)
        ap.error(f"--out {args.out}: a recording is an .rrd file (the viewer and "
                 "`dynremove inspect` open .rrd files): give a name ending in .rrd")
    try:  # (a folder, or a place that cannot be written: one line, before the run)
        check_out_file(args.out, "--out")
    except InputError as e:
        ap.error(str(e))
    scene = synth.make_scene(seed=args.seed, n_views=5, size=(120, 160), n_objects=1)
    r = scene.ref_index
    sink = RerunSink(args.out, record_every_rows=1, gt_mask=scene.masks[r],
                     gt_background=scene.background, skip_unchanged_images=False,
                     detail="full")  # candidates in the sources at every step
    with warnings.catch_warnings():  # (the run's notes are in res.warnings)
        warnings.simplefilter("ignore")
        res = remove_dynamic(scene.images, ref=r, params=preset(args.preset), sink=sink,
                             sample_static=1.0, probes=[(80, 60)], names=scene.names,
                             preset_name=args.preset)
    for w in res.warnings:
        print(f"note: {w}")
    print(f"wrote {args.out}: {len(res.scans)} scan{'s' if len(res.scans) != 1 else ''}, Jaccard {jaccard(res.dynamic, scene.masks[r]):.3f}")


if __name__ == "__main__":
    main()

"""The README's speed table from ``dynremove bench`` JSON files, one column per file.

Usage::

    dynremove bench --no-reference --json out/bench-now.json
    python examples/speed_table.py out/bench-before.json out/bench-now.json \
        [--labels before,now]

Prints a Markdown table: the seconds of every stage the runs reported (in the
order of the first file that has it; the fill by selection under its bar name),
the scan's Mpx/s, end to end, the median stack timed in the same run and the
ratio, the peak RSS of the timed runs, and, for a bench with ``--max-side``, the
full-size path and ``dynremove run`` in its own process (seconds, peak RSS). A
figure a file does not have is left empty. The files must come from the same
machine for their columns to compare: each bench's ratio to its own median
stack is the figure that travels.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dynremove.params import Params
from dynremove.progress import stage_labels


def _fmt(v: float | None, digits: int = 2) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def table(benches: list[dict], labels: list[str]) -> str:
    """Markdown table (str) of ``benches`` (parsed bench JSON dicts), headed ``labels``."""
    stages: list[str] = []
    for b in benches:
        stages += [k for k in b.get("stages_s", {}) if k != "total" and k not in stages]
    names = stage_labels(Params(fill=benches[0].get("fill", "select")))
    size = {f"{b['views']} × {b['size'][0]}×{b['size'][1]}" for b in benches}
    rows = [f"| stage (s; {', '.join(sorted(size))}) | " + " | ".join(labels) + " |",
            "|---|" + "---|" * len(benches)]

    def row(name: str, cells: list[str]) -> None:
        rows.append(f"| {name} | " + " | ".join(cells) + " |")

    for k in stages:
        row(names.get(k, k), [_fmt(b.get("stages_s", {}).get(k)) for b in benches])
    row("scan (first pass), Mpx/s",
        [_fmt(b["scans"][0]["px_per_s"] / 1e6) if b.get("scans") else "" for b in benches])
    row("**end to end**", [f"**{_fmt(b.get('end_to_end_s'))}**" for b in benches])
    row("median stack (same views, same run)", [_fmt(b.get("median_stack_s")) for b in benches])
    row("ratio to the median stack",
        [f"×{b['ratio_vs_median_stack']:.1f}" if "ratio_vs_median_stack" in b else ""
         for b in benches])
    row("peak RSS of the timed runs, MiB",
        [_fmt((b.get("peak_rss_mb_by_part") or {}).get("timed runs"), 0) for b in benches])
    if any("full_output_size" in b for b in benches):
        row("written at full size, +s", [_fmt(b.get("full_resolution_s")) for b in benches])
    if any("user_run" in b for b in benches):
        row("`dynremove run`, own process: s",
            [_fmt(b["user_run"]["seconds"]) if "user_run" in b else "" for b in benches])
        row("`dynremove run`, own process: peak RSS, MiB",
            [_fmt(b["user_run"]["peak_rss_mb"], 0) if "user_run" in b else ""
             for b in benches])
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", help="bench JSON files (dynremove bench --json)")
    ap.add_argument("--labels", default=None,
                    help="column heads, comma-separated (default: the files' names)")
    args = ap.parse_args(argv)
    labels = (args.labels.split(",") if args.labels else [Path(f).stem for f in args.files])
    if len(labels) != len(args.files):
        print(f"speed_table: {len(labels)} labels for {len(args.files)} files", file=sys.stderr)
        return 2
    try:
        benches = [json.loads(Path(f).read_text()) for f in args.files]
    except (OSError, json.JSONDecodeError) as e:
        print(f"speed_table: {e}", file=sys.stderr)
        return 2
    for f, b in zip(args.files, benches):  # (a trial's eval JSON gave a KeyError)
        if not (isinstance(b, dict) and {"views", "size", "stages_s"} <= set(b)):
            print(f"speed_table: {f}: not a bench JSON (dynremove bench --json FILE writes "
                  "one)", file=sys.stderr)
            return 2
    print(table(benches, labels))
    return 0


if __name__ == "__main__":
    sys.exit(main())

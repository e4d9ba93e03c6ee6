"""Command line: ``dynremove run | batch | demo | bench | eval | composite | view | inspect | export``.

The parser and ``main`` are here; the sub-commands are in :mod:`dynremove.commands`.
Exit codes: 0 ok, 2 bad input (``InputError``, including flags that ``Params``
rejects), 1 internal error (any other exception), 130 interrupted (SIGINT),
143 terminated (SIGTERM). Errors are one line on
stderr; set DYNREMOVE_DEBUG=1 for a traceback. ``viewer`` (Rerun) is imported
lazily, only by the commands and options that need it; an import error there
is an internal error like any other, never a missing sub-command.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import signal
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2

from dynremove.commands import (EXIT_INPUT, EXIT_INTERNAL, SAMPLE_STATIC, clear_stop,
                                request_stop, cmd_batch, cmd_bench,
                                cmd_composite, cmd_demo, cmd_eval, cmd_export, cmd_inspect,
                                cmd_run, cmd_view)
from dynremove.errors import InputError, Terminated, interruption
from dynremove.io import MIN_MAX_SIDE
from dynremove.evaluation.composite import MAX_SIDE as COMPOSITE_MAX_SIDE
from dynremove.evaluation.evaluate import ABLATIONS, DIAGNOSTICS, METHODS
from dynremove.params import DEFAULT, FIELD_CHOICES, PAPER, PRESETS, Params, field_docs


# --- parameters as flags --------------------------------------------------------------
def add_param_flags(ap: argparse.ArgumentParser, *, listed: bool = True) -> None:
    """--preset and one flag per Params field. ``listed=False`` (the commands that
    take the method's flags through to runs: batch, demo, bench, eval): the flags
    work but their help is one line pointing at ``run --help``, which lists them,
    so that the command's own options are not lost under sixty method flags."""
    title = "method parameters (default: the chosen preset's values)"
    if listed:
        g = ap.add_argument_group(title, description=(
            "lengths are in analysis px: pixels of the photos as analysed, their "
            "longer side scaled down to --max-side when larger (on a 4032 px photo "
            "at --max-side 1280, 1 analysis px is about 3 photo px)"))
    else:
        g = ap.add_argument_group(title, description=(
            "every method flag of 'dynremove run' is taken here too (--patch-size, "
            "--select-tau, ...; 'dynremove run --help' lists them with their units and "
            "defaults)").replace("%", "%%"))
    g.add_argument("--preset", choices=sorted(PRESETS), default="default",
                   help="'default' (best measured) or 'paper' (the method as written)")
    docs = field_docs()
    for f in dataclasses.fields(Params):
        flag = "--" + f.name.replace("_", "-")
        d, pp = getattr(DEFAULT, f.name), getattr(PAPER, f.name)
        used = f"(default {d})" if d == pp else f"(default {d}; paper {pp})"
        # the paper preset's value is in ``used``: not again from the comment
        doc = re.sub(r"\s*\(paper preset [^()]*\)|;\s*paper preset [^;()]*(?=\))", "",
                     docs.get(f.name, ""))
        help_ = (doc + " " + used).strip().replace("%", "%%") if listed else argparse.SUPPRESS
        if f.type in ("bool", bool):
            g.add_argument(flag, dest=f"p_{f.name}", action=argparse.BooleanOptionalAction,
                           default=None, help=help_)
        elif f.name in FIELD_CHOICES:  # listed; checked by Params (one-line error, exit 2)
            g.add_argument(flag, dest=f"p_{f.name}", default=None, help=help_,
                           metavar="{" + ",".join(FIELD_CHOICES[f.name]) + "}")
        else:
            typ = {"int": int, "float": float, "str": str}.get(str(f.type), str)
            g.add_argument(flag, dest=f"p_{f.name}", type=typ, default=None,
                           metavar={int: "INT", float: "FLOAT"}.get(typ, "V"), help=help_)


def parse_xy(s: str) -> tuple[int, int]:
    try:
        x, y = (int(v) for v in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y (two integers), got {s!r}") from None
    return x, y


def _integer(s: str) -> int:
    try:
        return int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {s!r}") from None


def parse_positive(s: str) -> int:
    """An integer of at least 1 (rows, counts)."""
    v = _integer(s)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def parse_port(s: str) -> int:
    """A TCP port of 1..65535 (0, "any free port", would leave the printed address
    without its port: a trial got http://127.0.0.1:0/)."""
    v = _integer(s)
    if not 1 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"a port is 1..65535, got {v}")
    return v


def parse_nonnegative(s: str) -> int:
    """An integer of at least 0 (seeds)."""
    v = _integer(s)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {v}")
    return v


def _number(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {s!r}") from None


def parse_fps(s: str) -> float:
    """Frames per second: a finite number in (0, 100] (a GIF stores 10 ms steps)."""
    v = _number(s)
    if not (math.isfinite(v) and 0.0 < v <= 100.0):
        raise argparse.ArgumentTypeError(f"must be a number of frames per second in (0, 100], "
                                         f"got {s}")
    return v


def _integer_at_least(s: str, lo: int, *, unit: str = "", flag: str = "") -> int:
    """An integer of at least ``lo`` (the error: "[flag ]must be at least lo[ unit], got v")."""
    v = _integer(s)
    if v < lo:
        raise argparse.ArgumentTypeError(f"{flag + ' ' if flag else ''}must be at least "
                                         f"{lo}{' ' + unit if unit else ''}, got {v}")
    return v


def parse_side(s: str) -> int:
    """A side in pixels, at least 16."""
    return _integer_at_least(s, 16, unit="px")


def parse_fraction(s: str) -> float:
    """A fraction in [0, 1]."""
    v = _number(s)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {s}")
    return v


def parse_max_side(s: str) -> int | None:
    """``none``/``0`` = full size; ``auto`` = io's default; else pixels."""
    t = s.strip().lower()
    if t in ("none", "0", "full"):
        return 0
    if t == "auto":
        return None
    try:
        v = int(t)
    except ValueError:
        # (argparse names the flag: "argument --max-side: ...")
        raise argparse.ArgumentTypeError(f"{s!r}: expected pixels, 0, 'none' or "
                                         "'auto'") from None
    if v < 0 or 0 < v < MIN_MAX_SIDE:
        # (here, so that batch and eval refuse it once, not once per set)
        raise argparse.ArgumentTypeError(f"{v}: must be 0 (keep the full size) or at "
                                         f"least {MIN_MAX_SIDE} px")
    return v


def parse_ref(s: str) -> str:
    """``--ref``: kept as given (resolved once the images are known); empty is an error,
    not the default."""
    if not s.strip():
        raise argparse.ArgumentTypeError("--ref '': give an index, a file name or 'auto' "
                                         "(leave --ref out for the middle image)")
    return s


def parse_set_ref(s: str) -> str:
    """``batch`` / ``eval --ref``: the reference of every set, so an index, a bare file name
    or 'auto'; a path names one file of one set."""
    from dynremove.io import is_path_ref

    s = parse_ref(s)
    if is_path_ref(s):
        raise argparse.ArgumentTypeError(
            f"--ref {s}: the reference of every set is an index, a file name or 'auto', "
            f"not a path (e.g. --ref {Path(s).name})")
    return s


def parse_jobs(s: str) -> int:
    v = _integer(s)
    if v == 0 or v < -1:
        # (joblib reads -5 as "all cores but 4", one at a time on 2 cores: a trial's
        # --jobs -5 ran and was recorded as such, the help saying only "-1 = all cores")
        raise argparse.ArgumentTypeError(f"--jobs must be a count of at least 1, or -1 for "
                                         f"all cores, got {v}")
    return v


def parse_frames(s: str) -> int:
    return _integer_at_least(s, 2, flag="--frames")


def add_input_flags(ap: argparse.ArgumentParser, *, valid_mask: bool = True) -> None:
    g = ap.add_argument_group("inputs")
    g.add_argument("--frames", type=parse_frames, default=None, metavar="N",
                   help="video: how many frames to take (default 7)")
    g.add_argument("--span", default=None, metavar="START:END",
                   help="video: frame numbers to take them from (END excluded; default: "
                        "the whole clip)")
    g.add_argument("--pick", choices=("sharpest", "even"), default="sharpest",
                   help="video: the sharpest frame of each of N even windows (variance of "
                        "the Laplacian), or the windows' centres (default: sharpest)")
    if valid_mask:
        g.add_argument("--valid-mask", default=None, metavar="PNG|DIR",
                       help="where the frames have content (white) and none (black): one "
                            "PNG for every image, or a folder of <image stem>.png; "
                            "combined with alpha 0 and black borders, found anyway")


# --- parser --------------------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: a mistyped flag or value is one line and a hint,
    not the whole usage block (the sub-commands have ~50 flags)."""

    def error(self, message: str):  # type: ignore[override]
        m = re.fullmatch(r"argument (--[\w-]+)(?:/[\w-]+)*: expected one argument", message)
        argv = _Parser.parsing
        after = [argv[i + 1] for i, a in enumerate(argv[:-1]) if m and a == m[1]]
        if after and after[0].startswith("-"):
            # argparse took a value that starts with '-' (a file -5.jpg) for a flag
            message += (f" ({after[0]} is read as a flag: write {m[1]}={after[0]})")
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")

    parsing: list[str] = []  # the arguments being parsed (read by the sub-commands' error)

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        _Parser.parsing = [str(a) for a in (sys.argv[1:] if args is None else args)]
        # an unknown flag is the sub-command's error, so the hint names its help
        ns, extra = self.parse_known_args(args, namespace)
        subs = getattr(self, "subcommands", {})
        sub = subs.get(getattr(ns, "cmd", None), self)
        if extra:
            sub.error("unrecognized arguments: " + " ".join(extra))
        twice = _given_twice(sub, _Parser.parsing)
        if twice:
            sub.error(twice)
        return ns


def _given_twice(parser: argparse.ArgumentParser, argv: Sequence[str]) -> str | None:
    """The first flag of ``parser`` that takes one value and was given two different
    ones (``--ref 3 --ref 2``, ``--snap --no-snap``), as an error message; None if
    none was. argparse keeps the last silently, and a user who wrote both meant one
    of them. The same value twice is not an error."""
    single = {o: a for a in parser._actions  # noqa: SLF001 - no public list of them
              if isinstance(a, (argparse._StoreAction, argparse.BooleanOptionalAction))
              and a.nargs in (None, 0) for o in a.option_strings}
    seen: dict[str, tuple[str, str]] = {}  # dest -> (as written, value)
    i = 0
    while i < len(argv) and argv[i] != "--":
        flag, eq, value = argv[i].partition("=")
        a = single.get(flag) if flag.startswith("-") else None
        i += 1
        if a is None:
            continue
        written = argv[i - 1]
        if isinstance(a, argparse.BooleanOptionalAction):
            value = flag.startswith("--no-")
        elif not eq and i < len(argv):
            value, written = argv[i], f"{flag} {argv[i]}"
            i += 1
        if a.dest in seen and seen[a.dest][1] != value:
            what = ("one of them" if isinstance(a, argparse.BooleanOptionalAction)
                    else f"{a.option_strings[-1]} once")
            return f"{seen[a.dest][0]} and {written} both given: give {what}"
        seen.setdefault(a.dest, (written, value))
    return None


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(
        prog="dynremove",
        description="Detect moving objects in a set of hand-held photos of a scene and "
                    "replace them with the background they hide (Kanojia & Raman, WACV).")
    from dynremove import __version__

    ap.add_argument("--version", action="version", version=f"dynremove {__version__}")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    ap.subcommands = sub.choices  # name -> its parser, for ``_Parser.parse_args``

    r = sub.add_parser("run", help="remove dynamic objects from a reference image",
                       usage="dynremove run [-h] [--ref REF] [--out OUT] [--max-side PX] "
                             "[--record FILE.rrd]\n"
                             "                     [OPTION ...] [METHOD PARAMETER ...] "
                             "images [images ...]",
                       description="Remove the moving objects from the reference image of a "
                                   "multi-view set. Writes clean.png, dynamic_mask.png, "
                                   "coverage.png and report.json to --out. Most runs need "
                                   "only the photos, --ref and --out; the method parameters "
                                   "(the last group below) are for experiments.")
    r.add_argument("images", nargs="+",
                   help="a folder of images (in name order, numbers by value: f8 before "
                        "f10), image files, or one video")
    r.add_argument("--ref", default=None, type=parse_ref,
                   help="reference photo (default: the middle one; the run names it): "
                        "an index (0-based, in input order; negative counts from the end, "
                        "-1 = the last), a file name or "
                        "stem (any case), a path, or 'auto' (the sharpest with the most "
                        "keypoint matches). Digits are the file they name (0002 is "
                        "0002.jpg) or the photo's number (0003 or 3 is IMG_0003.JPG); "
                        "where they name one file and index another, the run stops and "
                        "says how to give either; with leading zeros they are no index")
    r.add_argument("--out", default=None,
                   help="output folder (default: out/<the input's name>: out/tim6 for "
                        "tim6/frames, so that runs on other scenes keep theirs)")
    r.add_argument("--max-side", type=parse_max_side, default=None, metavar="PX",
                   help="analyse a copy whose longer side is at most PX (default, or 'auto': "
                        "only above 1280 px; 0 or 'none' = never); clean.png keeps the full size "
                        "unless --output-size working")
    r.add_argument("--output-size", choices=("full", "working"), default="full",
                   help="clean.png at the input's full resolution (default; only the "
                        "replaced pixels are recomputed) or at the analysis size")
    r.add_argument("--record", default=None, metavar="FILE.rrd",
                   help="write a Rerun recording of the scans")
    r.add_argument("--record-every-rows", type=parse_positive, default=None, metavar="N",
                   help="snapshot the reference every N rows (default: ~50 per scan)")
    r.add_argument("--record-detail", choices=("default", "full"), default="default",
                   help="candidates and q* box in the source views at probes, sampled "
                        "static and 1 in 16 dynamic decisions (default; a smaller file) "
                        "or at every recorded decision (full)")
    r.add_argument("--probe", type=parse_xy, action="append", metavar="X,Y",
                   help="record every decision at this pixel of the photo (repeatable; "
                        "scaled to the analysis image when the photos are downscaled)")
    r.add_argument("--sample-static", type=parse_fraction, default=SAMPLE_STATIC, metavar="F",
                   help=f"fraction of static decisions recorded (default {SAMPLE_STATIC})")
    r.add_argument("--gt", default=None, metavar="MASK",
                   help="true mask of the reference (0/255, white = moving) at the "
                        "photo's full size: the result is scored against it (Jaccard, "
                        "printed and in report.json as jaccard_vs_gt) and a --record shows "
                        "the errors")
    r.add_argument("--compare", default=None, metavar="PARAMS",
                   help="also run with other parameters (a preset name or field=value,...) "
                        "and log both side by side in the --record file")
    r.add_argument("-q", "--quiet", action="store_true",
                   help="print nothing but errors (no progress bars, notes or summary line; "
                        "the notes, warnings included, are in report.json)")
    add_input_flags(r)
    add_param_flags(r)
    r.set_defaults(fn=cmd_run)

    bt = sub.add_parser(
        "batch", help="run every set below a folder (resumable, parallel)",
        description="Run every set found below ROOT: a folder holding images directly, a "
                    "folder with frames/ (the eval layout; masks/ gives the Jaccard), or a "
                    "video. Writes DIR/<set>/ (the outputs of 'run'), DIR/summary.csv and "
                    "DIR/summary.json. A set whose outputs exist with the same parameters "
                    "and inputs is skipped; a failing set is recorded in the summary and "
                    "the command exits 1 at the end.")
    bt.add_argument("root", metavar="ROOT",
                    help="folder searched for sets (itself included), or one video")
    bt.add_argument("--out", required=True, metavar="DIR", help="output folder")
    bt.add_argument("--jobs", type=parse_jobs, default=1, metavar="N",
                    help="sets in parallel (joblib; -1 = all cores; default 1)")
    bt.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="run the sets on this Dask cluster (extra dynremove[dask])")
    bt.add_argument("--ref", default=None, type=parse_set_ref,
                    help="reference of every set: index (0-based; negative counts from the "
                         "end), file name or 'auto' (default: middle)")
    bt.add_argument("--max-side", type=parse_max_side, default=None, metavar="PX",
                    help="downscale to at most PX (0 or 'none' = full size; default, or "
                         "'auto': only above 1280 px)")
    bt.add_argument("-q", "--quiet", action="store_true", help="no per-set lines on stderr")
    add_input_flags(bt, valid_mask=False)
    add_param_flags(bt, listed=False)
    bt.set_defaults(fn=cmd_batch)

    d = sub.add_parser(
        "demo", help="run on the built-in synthetic scene and print metrics",
        description="Run the method (the default preset, or --preset) on the built-in "
                    "synthetic scene (6 views "
                    "640x360 with moving objects and a known background), write its "
                    "outputs and a recording, and print the Jaccard of the mask and the "
                    "PSNR inside the true mask.")
    d.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    d.add_argument("--scene-seed", type=int, default=0, metavar="N",
                   help="seed of the synthetic scene (default 0)")
    d.add_argument("--record", default="recordings/demo.rrd", metavar="FILE.rrd",
                   help="recording to write (default: recordings/demo.rrd)")
    d.add_argument("--no-record", action="store_true", help="do not write a recording")
    d.add_argument("--record-detail", choices=("default", "full"), default="default",
                   help="'full': candidates in the source views at every recorded "
                        "decision (see run --record-detail)")
    d.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_param_flags(d, listed=False)
    d.set_defaults(fn=cmd_demo, probe=None, sample_static=SAMPLE_STATIC, compare=None)

    b = sub.add_parser(
        "bench", help="stage timings, throughput and peak memory",
        description="Time the method on a synthetic scene (seed 0) after a warm-up that "
                    "compiles the kernels: seconds per stage, each scan's Mpx/s, peak RSS, "
                    "the median stack's time on the same views (and the ratio), the cost "
                    "of a Rerun recording and the numba kernel against the readable "
                    "reference. Prints a table and writes every figure to --json. Figures "
                    "are ratios against baselines measured in the same run: the machine "
                    "may be busy.")
    b.add_argument("--size", default="854x480", help="image size WxH (default 854x480)")
    b.add_argument("--views", type=int, default=7, help="number of images (default 7)")
    b.add_argument("--json", default="out/bench.json", metavar="FILE",
                   help="where to write the JSON (default out/bench.json)")
    b.add_argument("--repeat", type=parse_positive, default=1, metavar="N",
                   help="timed runs after the warm-up; the fastest is reported (default 1)")
    b.add_argument("--max-side", type=int, default=None, metavar="PX",
                   help="also time large photos as users run them: analysis at PX, the "
                        "clean photo at full size (e.g. --size 4032x3024 --views 5 "
                        "--max-side 1280)")
    b.add_argument("--no-reference", action="store_true",
                   help="skip the numba/reference speed ratio")
    b.add_argument("-q", "--quiet", action="store_true", help="only the table, no progress lines")
    add_param_flags(b, listed=False)
    b.set_defaults(fn=cmd_bench)

    e = sub.add_parser(
        "eval", help="Jaccard / PSNR / SSIM of the method and baselines on sets with truth",
        description="Evaluate on every <set>/frames/ below DATA_DIR (masks/<stem>.png and "
                    "background.png optional): the method, the paper preset, the median "
                    "baselines, Telea inpainting with the true mask and the single-scan "
                    "ablation. Prints a table; --json writes every figure. Sets with a "
                    "background.png also get whole-photo figures: PSNR/SSIM of the whole "
                    "image, damage % (pixels outside the true mask + 5 px that were right "
                    "in the input and are wrong in the output, CIE76 dE > 10) and leftover "
                    "% (recoverable true-mask pixels still wrong; free.png gives the "
                    "recoverable part, the rest is reported as unrecoverable %), split "
                    "into kept as input and refilled wrong, and of the refilled the "
                    "misplaced part (the true background shifted up to 2 px on each axis "
                    "matches it), each a percent of the recoverable true mask (JSON: "
                    "leftover_kept, leftover_refilled, leftover_misplaced); for "
                    "dynremove's runs the kept part by the step that left it: never "
                    "detected, dropped after the scans, kept by the fill, replaced but "
                    "alike (JSON: kept_missed, kept_refinement, kept_fill, "
                    "kept_replaced). "
                    "--preset and the method flags set the 'dynremove' column (its head "
                    "stays 'dynremove') and the 'true-fields' one; 'paper' is always the "
                    "paper preset as written, and 'single-scan' the paper's with one scan "
                    "and no update of the matches (Sec. 3.2.3). 'true-fields' (run only "
                    "where --methods names it; sets with a background.png) is a "
                    "diagnostic, not a method a user can run: the 'dynremove' column's "
                    "run whose fill samples the other photos across the mask through the "
                    "true background's own matches in them instead of the fields it "
                    "estimates, so its figures against 'dynremove' tell how much of the "
                    "wrong fill better fields could take away (mostly the refilled-wrong "
                    "part; its J moves too, as the dynamic map is what the fill replaced).")
    e.add_argument("data_dir", metavar="DATA_DIR",
                   help="a folder whose sets (<set>/frames/, below it at any depth) are "
                        "scored: ../shared/data/davis, or what 'dynremove composite' wrote")
    e.add_argument("--sets", default=None, metavar="GLOB",
                   help="only sets whose name matches (comma-separated globs)")
    e.add_argument("--jobs", type=parse_jobs, default=1, metavar="N",
                   help="sets in parallel (joblib; -1 = all cores; default 1)")
    e.add_argument("--json", default=None, metavar="FILE", help="write the report here")
    e.add_argument("--max-side", type=parse_max_side, default=None, metavar="PX",
                   help="downscale to at most PX (0 or 'none' = full size; default, or "
                        "'auto': only above 1280 px)")
    e.add_argument("--ref", default=None, type=parse_set_ref,
                   help="reference of every set: index (0-based; negative counts from the "
                        "end), file name or 'auto' (as run --ref auto; its mask must exist "
                        "in masks/) (default: the middle frame)")
    e.add_argument("--methods", default=",".join(METHODS), metavar="LIST",
                   help=f"comma-separated subset of {','.join(METHODS)} (default: all of "
                        "them; a set of 7 photos of 854x480 takes about 10 s for the "
                        "default preset, 8 s for the paper's, 1-4 s for each median stack "
                        "and under 1 s for telea, on 2 cores with --jobs 2); also "
                        f"{','.join(DIAGNOSTICS)}, only where named (the diagnostic "
                        "described above)")
    e.add_argument("--ablation", action="store_true",
                   help="instead of the methods: variants of the preset, each one setting "
                        "changed (listed under --variants); prints mean J / PSNR per variant")
    e.add_argument("--variants", default=None, metavar="LIST",
                   help=f"with --ablation: comma-separated subset of {','.join(ABLATIONS)} "
                        "(default: all of them)")
    e.add_argument("-q", "--quiet", action="store_true", help="no per-set progress on stderr")
    add_param_flags(e, listed=False)
    e.set_defaults(fn=cmd_eval)

    c = sub.add_parser(
        "composite", help="paste real moving objects into a static multi-view set",
        description="Cut objects out of a DAVIS-style folder (<set>/frames, <set>/masks) "
                    "and paste them, moving, into consecutive views of a static set "
                    "(successive annotated frames, wrapping around a short clip; "
                    "composite.json lists the frames and the size each object got). "
                    "Writes DIR/frames/, DIR/masks/ (0/255), DIR/background.png, "
                    "DIR/free.png (0/255: reference pixels some other view shows free of "
                    "the objects) and DIR/composite.json: the layout 'dynremove eval' reads. "
                    f"Static views are resized so that their longer side is at most "
                    f"{COMPOSITE_MAX_SIDE} px (the DAVIS frames' size).")
    c.add_argument("static_dir", metavar="STATIC_DIR",
                   help="folder of static images (with --n-sets: a folder of such folders)")
    c.add_argument("objects_dir", metavar="OBJECTS_DIR",
                   help="DAVIS-style sets with masks (e.g. shared/data/davis)")
    c.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (required; with --n-sets, one sub-folder per set)")
    c.add_argument("--seed", type=parse_nonnegative, default=0,
                   help="seed of the random choices: the objects, their size and path (same "
                        "seed, same sets; default 0)")
    c.add_argument("--n-views", type=int, default=6, metavar="N",
                   help="views per set, the middle N images of the static folder; the "
                        "middle view is the reference (view N//2 counting from 0: with an "
                        "even N, the later of the two middle ones; at least 2; default 6)")
    c.add_argument("--objects", type=int, default=1, metavar="K",
                   help="moving objects pasted into each set (default 1)")
    c.add_argument("--n-sets", type=int, default=0, metavar="N",
                   help="write N sets under DIR (one per static set x objects), "
                        "STATIC_DIR being a folder of static sets (default 0: one set "
                        "from STATIC_DIR itself)")
    c.add_argument("--light", action="store_true",
                   help="relight every view but the reference, as hand-held photos are: "
                        "exposure x0.85-1.15, white balance +-6 %% per channel, and 1-3 "
                        "smooth blobs of light or shade (-30 to +35 %%, sigma 8-25 %% of "
                        "the longer side); the reference stays the truth (default off)")
    c.set_defaults(fn=cmd_composite)

    v = sub.add_parser("view", help="open a recording in the Rerun viewer (with its layout)",
                       description="Open a .rrd recording in Rerun's native viewer, with "
                                   "the layout it was recorded with. Without a display, "
                                   "use --web: the web viewer is served on 127.0.0.1 only "
                                   "and its URL printed (one line). Every server binds "
                                   "127.0.0.1.")
    v.add_argument("recording", help="a .rrd file")
    v.add_argument("--web", action="store_true",
                   help="serve the web viewer on 127.0.0.1 only and print the URL")
    v.add_argument("--port", type=parse_port, default=9876,
                   help="gRPC port, 1..65535 (default 9876)")
    v.add_argument("--web-port", type=parse_port, default=9090,
                   help="web viewer port, 1..65535, not --port (default 9090)")
    v.set_defaults(fn=cmd_view)

    i = sub.add_parser("inspect", help="explain a pixel or list failures from a recording",
                       description="Read a recording back. --pixel X,Y opens with a "
                                   "verdict in words (M vs t_r, what neighbouring patches "
                                   "had done before its turn, the winning cluster, the "
                                   "post-scan steps, the fill), then the steps that "
                                   "changed it. --failures lists the worst false "
                                   "positives/negatives (run --gt) and the steps to jump "
                                   "to in the viewer.")
    i.add_argument("recording", help="a .rrd file")
    i.add_argument("--pixel", type=parse_xy, metavar="X,Y", action="append",
                   help="pixel to explain, in the image the run analysed (as the viewer and "
                        "--failures count); give it again for more pixels (each glossary "
                        "is printed once)")
    i.add_argument("--photo-pixel", type=parse_xy, metavar="X,Y", action="append",
                   help="pixel to explain, in the photos as read (as clean.png at full size, "
                        "--probe and --gt count); the same as --pixel when the run analysed "
                        "the photos at their own size; may be given again, and with --pixel")
    i.add_argument("--failures", action="store_true", help="list the worst FP/FN regions")
    i.add_argument("--top", type=parse_positive, default=None,
                   help="how many failures --failures lists (default 10)")
    i.add_argument("--root", default="",
                   help="which run of a --compare recording: runs/main or runs/compare (or "
                        "main / compare); a plain recording has none")
    i.set_defaults(fn=cmd_inspect)

    x = sub.add_parser("export", help="render the progressive removal to a GIF, an MP4 or "
                                      "PNG frames",
                       description="Render a recording's snapshots, without a viewer, to "
                                   "an animated GIF (Pillow, one palette), an MP4 "
                                   "(OpenCV's MPEG-4 Part 2, 'mp4v': VLC and ffmpeg play "
                                   "it, some browsers do not; the GIF plays everywhere) or "
                                   "numbered PNG frames in a folder (slides): "
                                   "left the input with L in red, right the rewritten "
                                   "reference, a caption with scan, step and |L|.")
    x.add_argument("recording", help="a .rrd file")
    x.add_argument("--out", "--gif", dest="out", required=True, metavar="OUT",
                   help="output .gif or .mp4, or a folder (no suffix) for PNG frames "
                        "frame_0000.png, ... (a new folder, or one of an earlier export's "
                        "frames, replaced whole); --gif is the same flag")
    x.add_argument("--fps", type=parse_fps, default=10.0,
                   help="frames per second, in (0, 100] (default 10); a GIF holds its "
                        "frame delay in whole hundredths of a second, 20 ms at least, so it "
                        "gets the nearest it can (30 -> 33.3 fps, 100 -> 50 fps), and says so")
    x.add_argument("--max-side", type=parse_side, default=480, metavar="PX",
                   help="longest side of the frames in px, their caption bar included "
                        "(left out under 104 px), at least 16 (default 480)")
    x.add_argument("--root", default="",
                   help="which run of a --compare recording: runs/main or runs/compare (or "
                        "main / compare); a plain recording has none")
    x.set_defaults(fn=cmd_export)
    return ap


def _quiet_opencv() -> None:
    """OpenCV's own warnings (e.g. "PNG input buffer is incomplete") would add lines to
    stderr next to ours, which already name the file and the problem."""
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _on_sigterm(signum: int, frame: Any) -> None:
    request_stop(Terminated)


def _on_sigint(signum: int, frame: Any) -> None:
    request_stop(KeyboardInterrupt)


def _quiet_stops(previous: Callable[[Any], None]) -> Callable[[Any], None]:
    """A ``sys.unraisablehook`` that says nothing of a stop a signal raised inside a
    ``__del__`` (llvmlite frees compiled objects so while numba compiles): Python
    would print it as "Exception ignored ... Traceback", where the command's one
    line is all a stop may print; ``request_stop`` has kept it, and the run raises
    it again at its next stage (``commands.check_stop``). Anything else goes to
    ``previous``."""
    def hook(unraisable: Any) -> None:
        if not isinstance(unraisable.exc_value, (KeyboardInterrupt, Terminated)):
            previous(unraisable)
    return hook


def viewer_module(name: str):
    """``viewer.<name>``, imported on first use (it needs Rerun).

    The one door from ``dynremove`` to ``viewer``: commands get it as
    ``args.viewer`` and never import the viewer themselves.
    """
    import importlib
    import importlib.util

    try:
        return importlib.import_module(f"viewer.{name}")
    except ImportError:
        # a viewer.py (or viewer/ folder) of the user's, first on sys.path (the folder
        # a script or ``python -m`` runs from), shadows the debugger's package: a
        # fresh-user trial got "internal error: No module named 'viewer.sink'"
        spec = importlib.util.find_spec("viewer")
        origin = getattr(spec, "origin", None) or ""
        ours = Path(__file__).resolve().parents[1] / "viewer"
        if spec is not None and not Path(origin).resolve().is_relative_to(ours):
            raise InputError(f"the debugger's package 'viewer' is shadowed by {origin}: "
                             "rename that file (or folder), or run from another folder"
                             ) from None
        raise


def main(argv: Sequence[str] | None = None) -> int:
    """The ``dynremove`` command; returns its exit status.

    Run as the program (``argv`` None), an interruption (130, 143) ends the
    process at once with ``os._exit`` once the outputs are settled: native worker
    threads (OpenCV, numba) still busy at interpreter shutdown would otherwise
    abort it ("terminate called without an active exception", SIGABRT).
    """
    rc = _main(argv)
    if argv is None and rc in (130, 143):
        for f in (sys.stdout, sys.stderr):
            try:
                f.flush()
            except (OSError, ValueError):
                pass
        os._exit(rc)
    return rc


def _main(argv: Sequence[str] | None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    args.viewer = viewer_module
    debug = bool(os.environ.get("DYNREMOVE_DEBUG"))

    _quiet_opencv()
    clear_stop()
    old = signal.signal(signal.SIGTERM, _on_sigterm)
    old_int = (signal.signal(signal.SIGINT, _on_sigint)
               if signal.getsignal(signal.SIGINT) is signal.default_int_handler else None)
    old_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_stops(old_hook)
    try:
        rc = int(args.fn(args) or 0)
        sys.stdout.flush()  # here, so that a closed pipe is caught below, not at exit
        return rc
    except BrokenPipeError:
        # the reader of our output went away (`inspect ... | head`): not an error; the
        # exit status a process killed by SIGPIPE has, as git's, and nothing printed
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:
        print("dynremove: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("dynremove: terminated", file=sys.stderr)
        return 143
    except InputError as e:
        if debug:
            raise
        print(f"dynremove: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_INPUT
    except Exception as e:  # noqa: BLE001 - one line, not a traceback
        stop = interruption(e)  # a Ctrl-C that surfaced as another exception
        if stop is not None:
            terminated = isinstance(stop, Terminated)
            print(f"dynremove: {'terminated' if terminated else 'interrupted'}",
                  file=sys.stderr)
            return 143 if terminated else 130
        if debug:
            raise
        print(f"dynremove: internal error: {type(e).__name__}: {_one_line(e)} "
              "(set DYNREMOVE_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        clear_stop()
        sys.unraisablehook = old_hook
        if argv is None:
            # the program: its outcome is settled and its outputs written, so a
            # Ctrl-C from here on (the interpreter's exit joins OpenCV's and numba's
            # threads) is ignored; a fresh-user trial's late Ctrl-C turned a finished
            # run, "wrote .../clean.png", into exit 130 with nothing said
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        else:
            signal.signal(signal.SIGTERM, old)
            if old_int is not None:
                signal.signal(signal.SIGINT, old_int)


if __name__ == "__main__":
    sys.exit(main())

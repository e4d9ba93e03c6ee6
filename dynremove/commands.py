"""The sub-commands of ``dynremove``: ``cmd_<name>(args) -> exit code``, one per command.

``dynremove.cli`` builds the parser and dispatches here. The viewer (Rerun) is
never imported here: commands that need it call ``args.viewer(name)``, which
``dynremove.cli`` sets (it imports ``viewer.<name>`` on first use).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import gc
import json
import re
import shutil
import signal
import subprocess
import sys
import os
import tempfile
import textwrap
import time
import traceback
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from dynremove import io
from dynremove.method.scan import _kernels
from dynremove.method.scan.driver import compiled_kernels
from dynremove.batch import at_output_size, load_for_reference, write_outputs
from dynremove.errors import InputError, interruption
from dynremove.evaluation import composite, synth
from dynremove.evaluation.bench import run_bench
from dynremove.evaluation.evaluate import (METHODS, find_sets, format_ablation, format_table,
                                          image_files, run_ablation, run_eval)
from dynremove.evaluation.metrics import jaccard, psnr_in_mask
from dynremove.params import PRESETS, Params, preset
from dynremove import pipeline
from dynremove.pipeline import remove_dynamic, versions
from dynremove.progress import ProgressBar, SetProgress, stage_labels

EXIT_OK, EXIT_INTERNAL, EXIT_INPUT = 0, 1, 2


# The stop (KeyboardInterrupt or Terminated) a signal asked for, until it is seen
# to propagate: an exception raised by a signal handler while a ``__del__`` runs
# (llvmlite frees compiled objects so) is printed as "Exception ignored" and
# dropped, and the run would go on to exit 0. The run checks it at each stage.
_PENDING_STOP: list[type[BaseException]] = []


def request_stop(kind: type[BaseException]) -> None:
    """A signal handler's: remember the stop, then raise it."""
    _PENDING_STOP[:] = [kind]
    raise kind()


def check_stop() -> None:
    """Raise a stop that a signal asked for and that was lost on its way up."""
    if _PENDING_STOP:
        raise _PENDING_STOP.pop()()


def clear_stop() -> None:
    """The stop reached the command's handler (or a new command starts)."""
    _PENDING_STOP.clear()


# --- parameters as flags -------------------------------------------------------------
def params_from_args(args: argparse.Namespace) -> Params:
    """The preset named by ``--preset`` with the flags' changes; InputError if rejected."""
    base = preset(args.preset)
    changes = {k[2:]: v for k, v in vars(args).items() if k.startswith("p_") and v is not None}
    try:
        params = dataclasses.replace(base, **changes) if changes else base
    except (TypeError, ValueError) as e:  # Params.__post_init__ validates the values
        raise InputError(flag_message(str(e))) from None
    unused = unused_fields(changes, params)
    if unused:  # accepted (and in report.json), but say they change nothing
        _note(args, f"{', '.join(_flag(f) for f in unused)}: no effect with these "
                    f"settings ({unused_reason(params, unused[0])})")
    return params


def unused_fields(changes: dict, params: Params) -> list[str]:
    """The fields of ``changes`` whose stage ``params`` does not run: the fill's
    (``fuse``, ``fill``, ``select_*``) without ``fuse``, ``select_*`` with another
    ``fill``, ``snap_*`` without ``snap``, the clean-up's without ``clean_mask``."""
    def off(f: str) -> bool:
        if f.startswith("select_"):
            return not params.fuse or params.fill != "select"
        if f == "fill" or f.startswith("fuse_"):
            return not params.fuse
        if f.startswith("snap_"):
            return not params.snap
        if f in ("min_region_px", "clean_majority"):
            return not params.clean_mask
        return False
    return [f for f in changes if off(f)]


def unused_reason(params: Params, field: str) -> str:
    """Why ``field`` has no effect under ``params`` (see ``unused_fields``)."""
    if field.startswith(("select_", "fuse_")) or field == "fill":
        return ("the fill stage is off: --no-fuse, as in the paper preset" if not params.fuse
                else f"--fill {params.fill} does not select")
    if field.startswith("snap_"):
        return "--no-snap"
    return "--no-clean-mask"


SAMPLE_STATIC = 0.002  # run --sample-static's default: the share of static decisions recorded

_PARAM_FIELDS = frozenset(f.name for f in dataclasses.fields(Params))


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def flag_message(msg: str) -> str:
    """A ``Params`` validation message in terms of the flags the user typed:
    ``t_r must be in [0, 1], got 5.0`` -> ``--t-r 5.0: must be in [0, 1]``; any other
    field name in it (outside quotes) becomes its flag too."""
    def flags(text: str) -> str:
        return re.sub(r"(?<![\w'\"-])([a-z][a-z0-9]*(?:_[a-z0-9]+)*)(?![\w'\"])",
                      lambda m: _flag(m[1]) if m[1] in _PARAM_FIELDS else m[1], text)

    m = re.fullmatch(r"([a-z][a-z0-9_]*) (must .*), got (.*)", msg, flags=re.S)
    if m and m[1] in _PARAM_FIELDS:
        value = m[3].strip()
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
            value = value[1:-1]  # a string's repr: as typed
        return f"{_flag(m[1])} {value}: {flags(m[2])}"
    return flags(msg)


# --- commands -----------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    params = params_from_args(args)
    if args.probe and not args.record:
        raise InputError("--probe needs --record FILE.rrd (a probe's decisions are recorded "
                         "there, for the viewer and `dynremove inspect --pixel`)")
    if not args.record:  # the recording's own flags do nothing without one
        given = [f for f, v in (("--record-every-rows", args.record_every_rows is not None),
                                ("--record-detail", args.record_detail != "default"),
                                ("--sample-static", args.sample_static != SAMPLE_STATIC)
                                ) if v]
        if given:
            raise InputError(f"{', '.join(given)} need{'s' if len(given) == 1 else ''} "
                             "--record FILE.rrd (they set what the recording holds)")
    if args.compare and not args.record:
        raise InputError("--compare needs --record FILE.rrd (the two runs go into one "
                         "recording)")
    if args.compare:
        parse_compare(args.compare, params)  # a bad spec fails before the photos are read
    if args.out is None:
        args.out = str(io.default_out_dir(args.images))
    # nothing a run writes may replace what it reads, or another of its outputs
    writes = [(f"--out {args.out} (its {n})", Path(args.out) / n)
              for n in (*io.RUN_OUTPUTS, "report.json")]
    if args.record:
        writes.insert(0, (f"--record {args.record}", Path(args.record)))
    io.check_writes(writes, io.run_reads(args.images, gt=args.gt,
                                         valid_mask=getattr(args, "valid_mask", None)))
    if (args.record and Path(args.record).suffix.lower() != ".rrd"
            and not Path(args.record).is_dir()):  # (a folder: told so below)
        # (a trial's --record x.txt wrote a recording under that name, silently)
        raise InputError(f"--record {args.record}: a recording is an .rrd file (the viewer "
                         "and `dynremove inspect` open .rrd files): give a name ending in .rrd")
    # the folders this run creates (the default out/<name> may create out/ too)
    created = [q for q in (Path(args.out), *Path(args.out).parents) if not q.exists()]
    try:
        out = io.prepare_out_dir(args.out, args.images)
        if args.record:
            io.check_out_file(args.record, "--record")
        if (out / "report.json").is_file():
            # (replaced only when this run writes: a run that fails leaves them)
            _note(args, f"{out} holds an earlier run's outputs (its report.json): this run "
                  "replaces them once it has its own (a run that fails leaves them)")
        else:
            there = [n for n in (*io.RUN_OUTPUTS, "report.json") if (out / n).is_file()]
            if there:
                it = "it" if len(there) == 1 else "them"
                _note(args, f"{out} holds {', '.join(there)}, not from a dynremove run (no "
                      f"report.json beside): this run replaces {it} once it has its own (a "
                      f"run that fails leaves {it})")
        return _run(args, params, out)
    except BaseException as e:
        for q in created:  # bad input or interrupted: leave no empty folder behind
            try:
                q.rmdir()  # only if still empty
            except OSError:
                break
        if interruption(e) is not None and not getattr(args, "_wrote", False):
            _note(args, f"nothing was written to {args.out}"
                  + (" (its earlier outputs are as they were)"
                     if (Path(args.out) / "report.json").is_file() else ""))
        elif interruption(e) is not None:
            # (a trial's Ctrl-C during "writing" got "interrupted" alone, with all four
            # outputs written; report.json is written last: where it is this run's,
            # all four are)
            rep = Path(args.out) / "report.json"
            done = rep.is_file() and rep.stat().st_mtime >= getattr(args, "_t_write", 0.0)
            _note(args, f"the outputs in {args.out} were all written before the "
                  "interruption" if done else
                  f"interrupted while writing to {args.out}: each file there is whole "
                  "(written atomically), but this run may not have replaced them all "
                  "(its report.json is written last)")
        raise


def _run(args: argparse.Namespace, params: Params, out: Path) -> int:
    t0 = time.perf_counter()
    # the progress bar, and where the run is for an interruption
    where = _Where(_bar(args, params))
    iset: io.ImageSet | None = None
    ref: int | None = None
    rec = sink = sink_b = extra = None
    try:
        where.bar("load", 0.0)

        def loaded(s: io.ImageSet) -> None:
            nonlocal iset
            iset = s  # (named in the recording of an interruption)
            _check_memory(args, s)
            _check_probes(args, s)  # (a trial's was refused after the reference's note)
            where.stage = "while choosing the reference"

        iset, ref, ref_info, ref_notes = load_for_reference(
            args.images, args.ref, on_loaded=loaded, max_side=args.max_side,
            valid_mask=args.valid_mask, frames=args.frames, span=args.span, pick=args.pick)
        t_load = time.perf_counter() - t0
        where.bar("load", 1.0)
        # (report.json's notes are the lines printed, in order: a trial with -q found
        # the reference's line and the probes' in neither)
        iset.notes[:] = [*iset.notes, reference_note(args.ref, ref, ref_info, iset.names),
                         *ref_notes]
        for n in iset.notes:
            _note(args, n, where.bar)
        gt_full = gt = None
        if args.gt:
            where.stage = "while reading the ground truth"
            gt_full, gt_note = read_gt(args.gt, iset, ref)
            if gt_note:
                _note(args, gt_note)
                iset.notes.append(gt_note)
            gt = _resized_mask(gt_full, iset.images[0].shape[:2])  # the analysis size
        probes = _probes_at_analysis_size(args, iset)
        compare = parse_compare(args.compare, params) if args.compare else None
        if args.record:
            where.stage = "while opening the recording"
        if compare is not None:
            with record_errors(args.record):
                rec = args.viewer("sink").open_compare_stream(
                    args.record, [n for i, n in enumerate(iset.names) if i != ref],
                    roots=["runs/main", "runs/compare"], jaccard=gt is not None)
        sink = _make_sink(args, iset, gt, rec=rec, root="runs/main" if rec else "",
                          output_dir=out)
        _note_compile(args)
        where.stage = "during features"
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            # each note as soon as the pipeline knows it, between the stages' lines
            warnings.showwarning = lambda message, *a, **k: _note(args, str(message), where.bar)
            res = remove_dynamic(iset.images, ref=ref, params=params, sink=sink,
                                 probes=probes, sample_static=args.sample_static,
                                 names=iset.names, preset_name=args.preset, progress=where,
                                 valid_masks=iset.valid_masks)
            if compare is not None:
                sink_b = _make_sink(args, iset, gt, rec=rec, root="runs/compare")
                # its stage lines follow the main run's: say whose they are
                _line(args, f"compare run (--compare {args.compare}), into the same "
                      "recording:", where.bar)
                where.stage = "during features"
                # the compare run's notes are told apart from the main run's
                warnings.showwarning = lambda message, *a, **k: _note(
                    args, f"compare run: {message}", where.bar)
                res_b = remove_dynamic(iset.images, ref=ref, params=compare, sink=sink_b,
                                       probes=probes,
                                       sample_static=args.sample_static, names=iset.names,
                                       preset_name="compare", progress=where,
                                       valid_masks=iset.valid_masks)
                # both runs' figures at the analysis size, on the terminal and in
                # report.json (a trial found the compare run's J only in the recording's
                # log; the main run's own jaccard_vs_gt is at the output's size)
                fig = {"spec": args.compare, "params": compare.to_dict(),
                       "analysis_size": {"width": int(res_b.dynamic.shape[1]),
                                         "height": int(res_b.dynamic.shape[0])},
                       "dynamic_fraction": float(res_b.dynamic.mean()),
                       "main_dynamic_fraction": float(res.dynamic.mean())}
                if gt is not None:
                    fig["jaccard_vs_gt"] = jaccard(res_b.dynamic, gt)
                    fig["main_jaccard_vs_gt"] = jaccard(res.dynamic, gt)
                j_b = (f", J {fig['jaccard_vs_gt']:.3f} against the given mask"
                       if gt is not None else "")
                j_a = f", J {fig['main_jaccard_vs_gt']:.3f}" if gt is not None else ""
                _line(args, f"compare run: {100 * fig['dynamic_fraction']:.1f} % dynamic at "
                      f"the analysis size{j_b} (main: {100 * fig['main_dynamic_fraction']:.1f}"
                      f" %{j_a}), both in {args.record}", where.bar)
                extra = {"compare": fig}
    except BaseException as e:
        stop = interruption(e)
        if stop is None:
            raise
        _record_interruption(args, where.stage, iset, ref, rec, [sink, sink_b])
        if stop is e:
            raise
        raise stop from e
    finally:
        where.close(failed=sys.exc_info()[0] is not None)
        if hasattr(sink, "close"):
            sink.close()
        if rec is not None:
            rec.flush()
            rec.disconnect()
    res.timings = {"load": t_load, **res.timings}  # first, as on the terminal
    kept = sorted([ref, *res.source_indices])
    if (ref_info.get("chosen_by") == "middle" and len(kept) < len(iset.names)
            and any(str(w).startswith(pipeline.STRAYS_NOTE) for w in res.warnings)):
        # photos left out moved the middle (a trial's photo of another scene, left
        # out, made 00054 the reference of dance-twirl instead of 00044)
        mid = kept[len(kept) // 2]
        if mid != ref:
            msg = (f"the reference is the middle of the photos given; of the "
                   f"{len(kept)} used, the middle is {iset.names[mid]}: --ref "
                   f"{iset.names[mid]} to take it")
            _note(args, msg)
            res.warnings.append(msg)
    bar = _bar(args, params)  # the steps after the pipeline's, on the same bar
    if args.output_size == "full" and iset.scale < 1.0:
        bar("full-size output", 0.0)
        h, w = res.clean.shape[:2]
        res = at_output_size(res, iset, args.output_size)
        bar("full-size output", 1.0)
        if any(re.search(r"\d px\b", str(n)) for n in res.warnings):
            # (a trial read "2 px ... inpainted" against report.json's 18: two sizes;
            # another looked for a note's "x 428–635, y 1083–1237" in clean.png)
            H1, W1 = res.clean.shape[:2]
            where = any(re.search(r"\bx \d+–\d+, y \d+–\d+", str(n)) for n in res.warnings)
            msg = (f"the notes count pixels of the {w}x{h} analysed copy"
                   + (f" and give their x, y in it (× {W1 / w:.3g} in clean.png, as "
                      "inspect --pixel counts; --photo-pixel takes the photo's)"
                      if where else "")
                   + f"; clean.png, dynamic_mask.png and report.json's *_px are at {W1}x{H1}")
            _note(args, msg)
            res.warnings.append(msg)  # (and in report.json)
    if gt_full is not None:
        gt = _resized_mask(gt_full, res.dynamic.shape)  # the output's size
    check_stop()  # a Ctrl-C lost in the last stage: nothing is written
    bar("writing", 0.0)
    args._wrote = True  # (an interruption from here on may have written some outputs)
    args._t_write = time.time() - 0.01  # (the clock of file times, as report.json's)
    report = write_outputs(out, res, iset=iset, ref=ref, preset_name=args.preset, gt=gt,
                           record=args.record, reference=ref_info, extra=extra)
    bar("writing", 1.0)
    bar.close()
    score = (f"J {report['jaccard_vs_gt']:.3f} against the given mask, "
             if "jaccard_vs_gt" in report else "")
    rrd_mb = _file_mib(args.record) if args.record else None
    if rrd_mb is not None and rrd_mb > _BIG_RECORDING_MIB:
        if compare is not None:
            a, b = 100 * res.dynamic.mean(), 100 * res_b.dynamic.mean()
            big = "the compare run" if b > a else "the main run"
            share = (f"the main run {a:.1f} % of the reference, the compare run {b:.1f} %: "
                     f"{big} makes most of it")
        else:
            share = f"{100 * res.dynamic.mean():.1f} % of the reference"
        _note(args, f"the recording is {rrd_mb:.0f} MiB: its events grow with the pixels "
              f"the scans call dynamic, in every scan ({share}), and with the snapshots "
              "(--record-every-rows N: fewer with a larger N)", None)
    _say(args, f"wrote {out}/clean.png, dynamic_mask.png, coverage.png, report.json"
         + (f" and {args.record} ({rrd_mb:.0f} MiB)" if rrd_mb is not None else
            f" and {args.record}" if args.record else "")
         + f"  ({100 * res.dynamic.mean():.1f} % of the reference dynamic, {score}"
         f"{time.perf_counter() - t0:.1f} s from reading to writing)")
    return EXIT_OK


def _written_mask_at(info: dict, path: Path, x: int, y: int) -> bool | None:
    """Whether the run's written ``dynamic_mask.png`` holds photo pixel (x, y): read
    from the output folder the recording names (``run/info``'s ``output_dir``) when
    it still holds this run's outputs (its report.json names a recording of this
    file's name, the same photos and reference) and the mask has the photos' size;
    None otherwise."""
    out = info.get("output_dir")
    if not out:
        return None
    try:
        report = json.loads((Path(out) / "report.json").read_text(encoding="utf-8"))
        rec = report.get("recording")
        same = (rec is not None and Path(rec).name == Path(path).name
                and [Path(p).name for p in report.get("inputs", [])] == list(info["names"])
                and int(report["reference"]["index"]) == int(info.get("ref_index", -1)))
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not same:
        return None
    m = cv2.imread(str(Path(out) / "dynamic_mask.png"), cv2.IMREAD_GRAYSCALE)
    if m is None or m.shape != (int(info["photo_height"]), int(info["photo_width"])):
        return None
    return bool(m[y, x] > 127)


def _check_probes(args: argparse.Namespace, iset: io.ImageSet) -> None:
    """InputError for a ``--probe`` pixel outside the photos (as soon as they are read)."""
    W0, H0 = iset.original_size
    for x, y in args.probe or ():
        if not (0 <= x < W0 and 0 <= y < H0):
            raise InputError(f"--probe {x},{y}: outside the {W0}x{H0} photo (x in "
                             f"0..{W0 - 1}, y in 0..{H0 - 1})")


def _probes_at_analysis_size(args: argparse.Namespace, iset: io.ImageSet
                             ) -> list[tuple[int, int]]:
    """``--probe`` pixels are the photo's (as ``--gt``); the scan runs on the analysis
    image, so they are scaled to it, with a note. InputError when outside the photo."""
    W0, H0 = iset.original_size
    _check_probes(args, iset)
    out = []
    for x, y in args.probe or ():
        if iset.scale == 1.0:
            out.append((x, y))
            continue
        H, W = iset.images[0].shape[:2]
        xa, ya = io.photo_to_analysis(x, y, (W0, H0), (W, H))
        msg = (f"--probe {x},{y}: pixel ({xa}, {ya}) of the {W}x{H} analysis image (the "
               "recording's and `inspect --pixel`'s coordinates)")
        _note(args, msg)
        iset.notes.append(msg)  # (and in report.json)
        out.append((xa, ya))
    return out


def _check_memory(args: argparse.Namespace, iset: io.ImageSet) -> None:
    """A note when the analysis will need several GB, and an InputError when it needs
    more than the machine has (``--max-side 0`` on phone photos)."""
    H, W = iset.images[0].shape[:2]
    n = len(iset.images)
    need = pipeline.memory_needed(n, H, W)  # (the estimate remove_dynamic refuses by)
    if need < 4e9:
        return
    have = pipeline.physical_memory()
    what = (f"analysing {n} images of {W}x{H} ({W * H / 1e6:.1f} MP) needs about "
            f"{need / 1e9:.0f} GB of memory")
    # what would lower it: a smaller analysis copy where the images are larger than
    # the default's, fewer images where there are many (a trial's 30-frame clip of
    # 960 px photos was told to use --max-side 1280, which changes nothing there)
    hints = []
    if max(H, W) > io.AUTO_MAX_SIDE:
        hints.append(f"--max-side {io.AUTO_MAX_SIDE} (the default) analyses a smaller copy "
                     "and still writes the clean photo at full size")
    if iset.video is not None:
        hints.append("fewer frames (--frames 7, the default, takes 7)")
    elif n > 10:
        hints.append("fewer photos (3 to 10 are what the method is made for)")
    hint = " or ".join(hints) or "fewer or smaller photos"
    if have is not None and need > have:
        raise InputError(f"{what}, more than this machine's {have / 1e9:.0f} GB: use {hint}")
    _note(args, f"{what}" + (f" (this machine has {have / 1e9:.0f} GB)" if have else "")
          + f"; {hint}")


def reference_note(ref_arg: str | None, ref: int, info: dict, names: list[str]) -> str:
    """One line naming the reference and how it was chosen (middle, given, auto)."""
    n = int(info.get("n_distinct", len(names)))  # a photo given twice counts once
    other = info.get("other_middle", ref - 1)
    # ("exact": a trial's clip of repeated frames read "25 distinct ones" beside the
    # near-copy notes, which count the frames that are alike, not identical)
    dup = f" of the {n} that are no exact copy of another" if n < len(names) else ""
    middle = (f"all {len(names)} files are the same photo" if n == 1 < len(names) else
              f"the middle image{dup}" if n % 2 else
              f"the later of the two middle images{dup}; --ref {other} for the other"
              if n > 2 else f"the second{dup}; --ref {other} for the first")
    how = {"middle": middle, "auto": "chosen by --ref auto"}.get(
        info.get("chosen_by", ""), f"given by --ref {ref_arg}")
    return f"reference: {names[ref]} (index {ref} of 0..{len(names) - 1}, {how})"


# PIL's transposition for each EXIF orientation that turns the frame by 90° (as
# ImageOps.exif_transpose; OpenCV applies the same on reading)
_EXIF_TURNS = {5: "TRANSPOSE", 6: "ROTATE_270", 7: "TRANSVERSE", 8: "ROTATE_90"}


def read_gt(path: str, iset: io.ImageSet, ref: int) -> tuple[np.ndarray, str | None]:
    """``--gt``: the reference's true mask at the reference's full (displayed) size.

    Returns ``(mask, note)``: mask is (H0, W0) bool, ``iset.original_size`` being
    (W0, H0). A mask of the transposed size, for a reference whose EXIF
    orientation turns it by 90°, was drawn on the stored pixels: it is turned
    the same way, with a note; one of the analysis size (``--output-size working``
    writes it) is scaled up, with a note. Any other size is an InputError: scoring
    it would compare different framings.
    """
    try:
        m = io.read_mask(path)
    except InputError as e:
        raise InputError(f"--gt {e}") from None
    W0, H0 = iset.original_size
    h, w = m.shape
    raw = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    grey = float(((raw > 16) & (raw < 240)).mean()) if raw is not None else 0.0
    odd = (f"--gt {path}: {100 * grey:.0f} % of its pixels are neither black nor white: "
           "is it a mask (0 = static, 255 = moving)? Scored as pixels > 127"
           if grey > 0.05 else None)
    if (w, h) == (W0, H0):
        return m, odd
    name = iset.names[ref]
    Ha, Wa = iset.images[ref].shape[:2]
    if (w, h) == (Wa, Ha):
        # (a trial's mask at the size --output-size working writes was refused)
        up = cv2.resize(m.astype(np.uint8), (W0, H0), interpolation=cv2.INTER_NEAREST) > 0
        return up, "; ".join(x for x in (odd, (
            f"--gt {path}: {w}x{h}, the analysis size: scaled to the reference's "
            f"{W0}x{H0} (nearest pixel)")) if x)
    if (w, h) == (H0, W0):
        orientation = None if iset.video else _exif_orientation(iset.paths[ref])
        if orientation in _EXIF_TURNS:
            from PIL import Image

            how = getattr(Image.Transpose, _EXIF_TURNS[orientation])
            turned = np.asarray(Image.fromarray(m.astype(np.uint8) * 255).transpose(how))
            return turned > 127, (f"--gt {path}: {w}x{h}, turned as the EXIF orientation "
                                  f"of {name} says (the mask was drawn on its stored "
                                  "pixels)")
        raise InputError(f"--gt {path}: is {w}x{h}, turned against the reference {name} "
                         f"({W0}x{H0}) and {name} has no EXIF orientation to turn it back "
                         "by; give the mask upright")
    raise InputError(f"--gt {path}: is {w}x{h} but the reference {name} is {W0}x{H0}; "
                     "the mask must have the reference's size")


def _exif_orientation(path: Path) -> int | None:
    """The EXIF orientation tag of an image file, None if it has none or is unreadable."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.getexif().get(0x0112)
    except Exception:  # noqa: BLE001 - no tag to apply
        return None


def _resized_mask(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``mask`` at (H, W) = ``shape[:2]`` (nearest), itself when already that size."""
    H, W = shape[:2]
    if mask.shape == (H, W):
        return mask
    return cv2.resize(mask.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0


class _Where:
    """The progress callback of a run: draws the bar and keeps where the run is
    ("during features", "after correspondence", ...) for an interruption."""

    def __init__(self, bar: ProgressBar) -> None:
        self.bar = bar
        self.stage = "while loading the images"

    def __call__(self, stage: str, frac: float) -> None:
        check_stop()
        label = self.bar.label(stage)
        self.stage = f"during {label}" if frac < 1.0 else f"after {label}"
        self.bar(stage, frac)

    def close(self, *, failed: bool = False) -> None:
        self.bar.close(failed=failed)


def _record_interruption(args: argparse.Namespace, stage: str, iset: io.ImageSet | None,
                         ref: int | None, rec: Any, sinks: list[Any]) -> None:
    """Ctrl-C / SIGTERM during ``run --record``: end the recording with "interrupted ...".

    The sinks log "interrupted at scan S, step N" (or "before the scans began
    (``stage``)") and write the footer. Interrupted before the sink existed
    (loading the images, choosing the reference), a recording is written that
    says so, with the names, size and reference when they are known. Further
    SIGINT / SIGTERM are ignored meanwhile so that the file is not cut
    mid-message; if the recording cannot be written, the interruption is still
    what the command reports.
    """
    if not getattr(args, "record", None):
        return
    held = _hold_signals()
    try:
        live = [s for s in sinks if s is not None and hasattr(s, "interrupted")]
        if not live:
            sink = _make_sink(args, iset, None, rec=rec, root="runs/main" if rec else "")
            if iset is not None and sink is not None:
                H, W = iset.images[0].shape[:2]
                sink.begin(iset.names, (H, W), images=iset.images, ref=ref)
            live = [sink]
        for s in live:
            if s is not None:
                s.interrupted(stage)
                kept = getattr(s, "partial_path", None)
                if kept is not None:
                    print(f"dynremove: note: {args.record} from before is kept; this run's "
                          f"recording, cut short, is {kept}", file=sys.stderr)
                elif s is live[0]:
                    _note(args, f"the recording, cut short, is {args.record} "
                          "('dynremove inspect' reads it)")
    except Exception as e:  # noqa: BLE001 - e.g. disk full: exit as interrupted anyway
        print(f"dynremove: note: {args.record}: could not record the interruption "
              f"({type(e).__name__}: {' '.join(str(e).split())})", file=sys.stderr)
    finally:
        _release_signals(held)


def _hold_signals() -> dict[int, Any]:
    """Ignore SIGINT and SIGTERM (main thread only); the previous handlers."""
    held: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            held[sig] = signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):  # not the main thread
            pass
    return held


def _release_signals(held: dict[int, Any]) -> None:
    for sig, handler in held.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def cmd_demo(args: argparse.Namespace) -> int:
    params = params_from_args(args)
    if args.scene_seed < 0:
        raise InputError(f"--scene-seed must be >= 0, got {args.scene_seed}")
    out = io.prepare_out_dir(args.out)
    if not args.no_record:
        io.check_out_file(args.record, "--record")
    scene = synth.make_scene(seed=args.scene_seed, n_views=6, size=(360, 640))
    synth.write_scene(scene, out / "scene")
    iset = io.ImageSet(paths=[out / "scene" / "frames" / n for n in scene.names],
                       images=list(scene.images), original_size=(640, 360), scale=1.0)
    gt = scene.masks[scene.ref_index]
    record = None if args.no_record else args.record
    if record:
        args.record = record
        args.record_every_rows = None
    sink = _make_sink(args, iset, gt, gt_background=scene.background) if record else None
    bar = _bar(args, params)
    _note_compile(args)
    try:
        res = remove_dynamic(scene.images, ref=scene.ref_index, params=params, sink=sink,
                             names=scene.names, preset_name=args.preset, progress=bar)
    finally:
        bar.close()
        if sink is not None and hasattr(sink, "close"):
            sink.close()
    write_outputs(out, res, iset=iset, ref=scene.ref_index, preset_name=args.preset, gt=gt,
                  record=record)
    io.write_image(out / "gt_mask.png", gt.astype(np.uint8) * 255)
    io.write_image(out / "gt_background.png", scene.background)
    J = jaccard(res.dynamic, gt)
    psnr = psnr_in_mask(res.clean, scene.background, gt)
    psnr_in = psnr_in_mask(scene.images[scene.ref_index], scene.background, gt)
    print(f"demo: synthetic scene seed {args.scene_seed}, {len(scene.images)} views "
          f"{scene.images[0].shape[1]}x{scene.images[0].shape[0]}, reference {scene.ref_index}")
    print(f"  Jaccard (dynamic mask vs truth):   {J:.3f}")
    print(f"  PSNR inside the true mask:         {psnr:.2f} dB (input reference: {psnr_in:.2f} dB)")
    print(f"  time: {res.timings['total']:.1f} s  -> {out}/" + (f" and {record}" if record else ""))
    if not getattr(args, "quiet", False):  # (a trial: the demo said nothing of what next)
        prog = _program_name()
        steps = ([(f"{prog} view {record}", "scrub the removal, step by step"),
                  (f"{prog} inspect {record} --failures",
                   "the worst misses against the truth, and why")] if record else [])
        steps.append((f"{prog} run YOUR_PHOTOS/ --out out/mine",
                      "your own photos (README, Usage)"))
        width = max(len(c) for c, _ in steps)
        print("next:\n" + "\n".join(f"  {c.ljust(width)}   # {w}" for c, w in steps))
    return EXIT_OK


def _program_name() -> str:
    """How to call this program again from here: ``dynremove`` where that is what the
    shell finds, else the path of the script that runs (``.venv/bin/dynremove`` after
    ``make demo``, whose venv is not on the PATH: a trial typed the printed
    ``dynremove view …`` and got "command not found")."""
    me = sys.argv[0] if sys.argv and sys.argv[0] else ""
    if os.path.basename(me) != "dynremove":  # (python -m dynremove, a notebook)
        return "dynremove"
    found = shutil.which("dynremove")
    if found and os.path.realpath(found) == os.path.realpath(me):
        return "dynremove"
    rel = os.path.relpath(os.path.abspath(me))
    return rel if not rel.startswith("..") else os.path.abspath(me)


def cmd_bench(args: argparse.Namespace) -> int:
    try:
        W, H = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WxH, got {args.size!r}") from None
    if W < 64 or H < 48 or args.views < 2:
        raise InputError(f"bench needs --size of at least 64x48 and --views >= 2, got "
                         f"{args.size} and {args.views}")
    RerunSink = args.viewer("sink").RerunSink
    if args.json:
        # before the bench: a trial's read-only folder ran the whole bench, then gave an
        # internal error writing out/bench.json
        io.check_out_file(args.json, "--json")

    with warnings.catch_warnings():
        # the synthetic scene's run notes (a few pixels inpainted) are not what a
        # bench reports, and would print once per timed run
        warnings.simplefilter("ignore")
        run_bench(params=params_from_args(args), preset_name=args.preset, size=(W, H),
                  max_side=args.max_side,
                  views=args.views, repeat=args.repeat, reference=not args.no_reference,
                  json_path=args.json or None, quiet=args.quiet,
                  recording_sink=lambda path, gt: RerunSink(path, gt_mask=gt))
    return EXIT_OK


def _check_true_fields(args: argparse.Namespace, methods: list[str]) -> None:
    """``--methods true-fields`` scores only sets with a background.png: an error when it
    is the only method and no set has one, a note when some sets lack it (a trial's
    run on such sets printed a column of '-' and exit 0, with no word)."""
    found = find_sets(args.data_dir, args.sets)
    lacking = [es.name for es in found if es.background is None]
    if not found or not lacking:
        return  # (no set at all: run_eval says so)
    if len(lacking) == len(found) and methods == ["true-fields"]:
        raise InputError(f"--methods true-fields: none of the {len(found)} set(s) under "
                         f"{args.data_dir} has a background.png (what 'dynremove composite' "
                         "and the synthetic scenes write): nothing to score")
    few = ", ".join(lacking[:3]) + (f" and {len(lacking) - 3} more" if len(lacking) > 3 else "")
    _note(args, f"true-fields: {len(lacking)} of {len(found)} set(s) have no background.png "
                f"({few}): no true-fields figures there ('-')")


def cmd_eval(args: argparse.Namespace) -> int:
    params = params_from_args(args)
    # each once, in the order given (a trial's dynremove,dynremove counted one set twice)
    methods = list(dict.fromkeys(m.strip() for m in args.methods.split(",") if m.strip()))
    if not methods:
        raise InputError("--methods: empty list")
    if args.variants and not args.ablation:
        _note(args, "--variants is used with --ablation only: ignored")
    if args.json:
        # before any scoring: a trial's unwritable --json failed after five minutes of it
        io.check_out_file(args.json, "--json")
    base = preset(args.preset).to_dict()
    changed = {k: v for k, v in params.to_dict().items() if v != base[k]}
    if (not args.ablation and (changed or args.preset != "default")
            and not {"dynremove", "true-fields"} & set(methods)):
        # (a trial's --t-r 0.5 with --methods paper,median changed nothing, silently)
        _note(args, "the method flags (--preset " + args.preset + "".join(
            f", --{k.replace('_', '-')} {v}" for k, v in changed.items()) + ") apply to the "
            "'dynremove' and 'true-fields' methods only, which --methods does not list: not "
            "used ('paper' and 'single-scan' are the paper's method as written)")
    if "true-fields" in methods and not args.ablation:
        _check_true_fields(args, methods)
    progress = not args.quiet
    if args.ablation or any(m not in ("median", "median-flow", "telea") for m in methods):
        _note_compile(args)  # (each set's seconds leave the compilation out)
    if args.ablation:
        if args.methods != ",".join(METHODS):
            _note(args, "--methods is not used with --ablation: it varies the "
                        f"{args.preset} preset's method (--variants picks the variants)")
        names = [n.strip() for n in (args.variants or "").split(",") if n.strip()] or None
        report = run_ablation(args.data_dir, base=params, names=names, sets=args.sets,
                              jobs=args.jobs, max_side=args.max_side, ref=args.ref,
                              progress=progress, preset_name=args.preset)
        print(format_ablation(report))
    else:
        try:
            report = run_eval(args.data_dir, sets=args.sets, params=params,
                              preset_name=args.preset, methods=methods, jobs=args.jobs,
                              max_side=args.max_side, ref=args.ref, progress=progress)
        except BaseException as e:
            partial = getattr(e, "partial_report", None)
            if interruption(e) is not None and partial:
                _keep_partial_eval(args, partial, changed)
            raise
        if not _nothing_scored(report):  # (else a table of dashes before the error)
            print(format_table(report))
            if "dynremove" in methods and (changed or args.preset != "default"):
                # (two variants' tables looked alike: a trial told them apart by the JSON)
                print(f"dynremove = the {args.preset} preset"
                      + (" with " + ", ".join(f"{k}={v}" for k, v in changed.items())
                         if changed else ""))
    report["provenance"] = _provenance(args, changed)
    n_sets = len({r["set"] for r in report["sets"]})
    if args.json:
        io.write_json(args.json, report)
    print(f"{n_sets} set{'' if n_sets == 1 else 's'}, wall {report['wall_s']:.1f} s (jobs {args.jobs})"
          + (f" -> {args.json}" if args.json else ""))
    info = report.get("set_info", [])
    errors = {i["set"]: i["error"] for i in info if "error" in i}
    if _nothing_scored(report):
        # (a trial's frames without masks/ gave a table of dashes and exit 0; a later
        # one's set had a mask, of another photo than the reference: named now)
        wanted = ", ".join(f"{i['set']}: masks/{Path(str(i['ref'])).stem}.png for its "
                           f"reference {i['ref']}" if i.get("ref") else i["set"]
                           for i in sorted(info, key=lambda i: i["set"]))
        print(f"dynremove: error: nothing was scored: no set has its reference's mask or "
              f"a background.png ({wanted}; --ref picks another reference)", file=sys.stderr)
        return 1
    if errors:  # the others are in the table; the exit code says not all ran
        # (each named with its error here: under --quiet no line above says it)
        for name in sorted(errors):
            print(f"dynremove: error: {name}: {errors[name]}", file=sys.stderr)
        print(f"dynremove: error: {len(errors)} set{'' if len(errors) == 1 else 's'} could "
              f"not be run: {', '.join(sorted(errors))}", file=sys.stderr)
        return 1
    return EXIT_OK


def _provenance(args: argparse.Namespace, changed: dict) -> dict:
    """What made an eval's figures (a trial: "a figure cannot be tied to the code")."""
    return {"command": ["dynremove", *sys.argv[1:]] if sys.argv[1:] else None,
            "data_dir": str(Path(args.data_dir).resolve()), "preset": args.preset,
            "params_changed": changed, "versions": versions(), "commit": source_commit(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def _keep_partial_eval(args: argparse.Namespace, report: dict, changed: dict) -> None:
    """Ctrl-C / SIGTERM during ``eval``: the table of the sets already scored, and the
    JSON of them (``"interrupted": true``), written with further signals held (a
    trial's Ctrl-C threw away the two of six sets done)."""
    held = _hold_signals()
    try:
        n_done = len({r["set"] for r in report["sets"]})
        if not _nothing_scored(report):
            print(format_table(report))
        report["provenance"] = _provenance(args, changed)
        if args.json:
            io.write_json(args.json, report)
        print(f"interrupted after {n_done} of {report['n_sets_found']} sets: the table holds "
              "those" + (f"; {args.json} too (\"interrupted\": true)" if args.json else ""))
    except Exception as e:  # noqa: BLE001 - the interruption is what the command reports
        print(f"dynremove: note: the sets scored before the interruption could not be "
              f"kept ({e})", file=sys.stderr)
    finally:
        _release_signals(held)


def source_commit() -> str | None:
    """The git commit of the source tree this package runs from (an editable install or
    a checkout), with "+changes" where it differs from that commit; None elsewhere."""
    root = Path(__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"],
                              capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def _composite_ref(folder: Path) -> str:
    """The reference's file name that ``composite.json`` under ``folder`` records."""
    return json.loads((Path(folder) / "composite.json").read_text())["ref"]


def cmd_composite(args: argparse.Namespace) -> int:
    if args.n_sets:
        outs = composite.make_composites(args.static_dir, args.objects_dir, args.out,
                                         n_sets=args.n_sets, seed=args.seed,
                                         n_views=args.n_views, n_objects=args.objects,
                                         light=args.light)
        for o in outs:
            print(f"{o}  (reference {_composite_ref(o)})")
        print(f"wrote {len(outs)} composite set{'s' if len(outs) != 1 else ''} under "
              f"{args.out}")
        # sets an earlier run wrote there stay, and 'eval DIR' would score them too
        stale = sorted(d.name for d in Path(args.out).iterdir()
                       if d.is_dir() and (d / "composite.json").is_file()
                       and d.resolve() not in {o.resolve() for o in outs})
        if stale:
            print(f"dynremove: note: {len(stale)} other composite set"
                  f"{'s' if len(stale) != 1 else ''} under {args.out} from an earlier run "
                  f"({', '.join(stale[:3])}{', …' if len(stale) > 3 else ''}): "
                  "'dynremove eval' on the folder scores them too", file=sys.stderr)
    else:
        root = Path(args.static_dir)
        if args.n_views >= 2 and root.is_dir() and len(image_files(root)) < 2:
            # a folder of static sets given without --n-sets: say how to use it
            sets = [d for d in composite.static_sets(root, args.n_views) if d != root]
            if sets:
                raise InputError(
                    f"{root}: no images of its own, but {len(sets)} static set"
                    f"{'s' if len(sets) != 1 else ''} of {args.n_views} or more images in "
                    f"its folders ({', '.join(d.name for d in sets[:3])}"
                    f"{', ...' if len(sets) > 3 else ''}): add --n-sets N to make N "
                    "composites from them, or give one of them")
        info = composite.make_composite(args.static_dir, args.objects_dir, args.out,
                                        seed=args.seed, n_views=args.n_views,
                                        n_objects=args.objects, light=args.light)
        print(f"wrote {args.out}: {info['n_views']} views {info['size'][0]}x"
              f"{info['size'][1]}, reference {info['ref']} (view {info['ref_index']} "
              f"of 0-{info['n_views'] - 1}), objects "
              + ", ".join(o["set"] for o in info["objects"])
              + f", reference mask {100 * info['ref_mask_fraction']:.1f} %")
    return EXIT_OK


def cmd_batch(args: argparse.Namespace) -> int:
    from dynremove.batch import run_batch, stderr_progress

    params = params_from_args(args)
    finished = [0, 0, 0]  # sets finished, sets in all, of the finished those that failed
    running: list[SetProgress] = []  # the set running now (one at a time: --jobs 1)

    def on_start(k: int, n: int, bs) -> SetProgress | None:
        if args.quiet:
            return None
        running[:] = [SetProgress(f"[{k}/{n}] {bs.name}:", labels=stage_labels(params))]
        return running[0]

    def on_done(k: int, n: int, row: dict) -> None:
        finished[:] = [k, n, finished[2] + (row.get("status") == "error")]
        for bar in running:
            bar.clear()
        if not args.quiet:
            stderr_progress(k, n, row)

    try:
        s = run_batch(args.root, args.out, params=params, preset_name=args.preset,
                      jobs=args.jobs, max_side=args.max_side, ref=args.ref,
                      frames=args.frames, span=args.span, pick=args.pick,
                      scheduler=args.scheduler, on_done=on_done,
                      on_note=lambda n: _note(args, n), on_start=on_start)
    except BaseException as e:
        for bar in running:
            bar.clear()
        if interruption(e) is not None and (Path(args.out) / "summary.csv").is_file():
            k, n, failed = finished
            how = f", {failed} of them failed" if failed > 1 else (
                f", {'that one' if k == 1 else 'one of them'} failed" if failed else "")
            done = (f"{k} of {n} sets finished{how} ({args.out}/summary.csv lists "
                    f"{'it' if k == 1 else 'them'})" if k else "no set had finished")
            print(f"dynremove: batch cut short: {done}; run the same command again to "
                  "resume (finished sets are skipped)", file=sys.stderr)
        raise
    n_sets = len(s["sets"])
    print(f"{n_sets} set{'s' if n_sets != 1 else ''}: {s['n_ok']} done, {s['n_skipped']} skipped (already "
          f"done), {s['n_failed']} failed; wall {s['wall_s']:.1f} s -> {args.out}/summary.csv")
    for r in s["sets"]:
        if r["status"] == "error":
            print(f"dynremove: error: {r['set']}: {r['error']}", file=sys.stderr)
    return EXIT_INTERNAL if s["n_failed"] else EXIT_OK


# --- commands that read recordings (``args.viewer``: see dynremove.cli) ------------------
def _recording(path: str) -> Path:
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a folder, not a recording")
    if not p.is_file():
        raise InputError(f"{p}: no such recording")
    try:
        with open(p, "rb") as f:
            head = f.read(4)
    except OSError as e:
        raise InputError(f"{p}: cannot read it ({e.strerror or e})") from None
    if head != b"RRF2":  # (before any work: export drew frames of a text file first)
        raise InputError(f"{p}: not a Rerun recording (.rrd)")
    return p


def _port_in_use(port: int) -> bool:
    """True when a server already listens on 127.0.0.1:``port``."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def cmd_view(args: argparse.Namespace) -> int:
    rec = _recording(args.recording)
    if args.web:  # (the native viewer sends to a viewer already listening: no check)
        if args.port == args.web_port:  # (a trial's viewer then exited with code 1)
            raise InputError(f"--port and --web-port are both {args.port}: the web viewer "
                             "and its data server need a port each")
        for flag, port in (("--port", args.port), ("--web-port", args.web_port)):
            if _port_in_use(port):
                raise InputError(f"port {port} on 127.0.0.1 is in use (another viewer "
                                 f"still running?): choose another with {flag}")
    damage = args.viewer("inspect").damage_note(rec)
    if damage:  # (as inspect and export say: a trial's cut recording was served silently)
        print(f"dynremove: note: {rec}: {damage}", file=sys.stderr)
    proc = args.viewer("serve").view(rec, web=args.web, port=args.port,
                                     web_port=args.web_port)
    if proc.returncode is not None and proc.returncode > 0:
        hint = ("" if args.web else "; without a display, try --web")
        print(f"dynremove: the viewer exited with code {proc.returncode}{hint}",
              file=sys.stderr)
        return EXIT_INTERNAL
    return EXIT_OK


def cmd_inspect(args: argparse.Namespace) -> int:
    ins, vd = args.viewer("inspect"), args.viewer("verdict")
    path = _recording(args.recording)
    pixels = [(xy, None) for xy in (args.pixel or [])]
    pixels += [(None, xy) for xy in (getattr(args, "photo_pixel", None) or [])]
    if not pixels and not args.failures:
        raise InputError("inspect: give --pixel X,Y, --photo-pixel X,Y or --failures")
    if args.top is not None and not args.failures:  # (a trial's --top went unnoticed)
        _note(args, "--top counts the failures of --failures: without it, not used")
    if pixels:
        info = ins.read_run_info(path, root=ins.resolve_root(path, args.root))
        size = ins.photo_size(info)
        for _, photo in pixels:  # every pixel checked before any is explained
            if photo is not None and size is not None and not (
                    0 <= photo[0] < size[0] and 0 <= photo[1] < size[1]):
                raise InputError(f"--photo-pixel {photo[0]},{photo[1]}: outside the "
                                 f"{size[0]}x{size[1]} photos (x in 0..{size[0] - 1}, y in "
                                 f"0..{size[1] - 1})")
        # each glossary once, where it is first needed (a trial: it repeated at every
        # pixel of a teaching session)
        seen: set[str] = set()
        for i, (analysed, photo) in enumerate(pixels):
            if i:
                print()
            _inspect_pixel(args, ins, vd, path, info, size, analysed, photo, seen)
    if args.failures:
        print(for_terminal(vd.format_failures(ins.failures(path, top=args.top or 10,
                                                            root=args.root))))
    return EXIT_OK


def _inspect_pixel(args: argparse.Namespace, ins: Any, vd: Any, path: Path, info: dict,
                   size: tuple[int, int] | None, analysed: tuple[int, int] | None,
                   photo: tuple[int, int] | None, seen: set[str]) -> None:
    """``inspect --pixel`` / ``--photo-pixel``: one pixel's verdict and history."""
    if photo is not None:
        x, y = ins.photo_to_analysis(info, photo[0], photo[1]) or photo
    else:
        x, y = analysed
    if size is not None and 0 <= x < int(info["width"]) and 0 <= y < int(info["height"]):
        # the run analysed smaller images: say which photo pixel this is (the one
        # asked for: an analysis pixel covers several, the centre one is named
        # only when the analysis pixel was asked for)
        if photo is not None:
            print(f"photo pixel ({photo[0]}, {photo[1]}) of the {size[0]}x{size[1]} "
                  f"photos is pixel ({x}, {y}) of the {info['width']}x{info['height']} "
                  "analysis image")
        else:
            qx, qy = ins.analysis_to_photo(info, x, y)
            # (and the photo pixels it covers: a trial's --photo-pixel 1000,2160 gave
            # analysis pixel (400, 864), whose centre is photo pixel (1001, 2161))
            (x0, x1), (y0, y1) = ins.photo_span(info, x, y)
            print(f"pixel ({x}, {y}) of the {info['width']}x{info['height']} analysis "
                  f"image = photo pixel ({qx}, {qy}) of the {size[0]}x{size[1]} photos "
                  f"(the one nearest its centre; it covers photo pixels x {x0}–{x1}, "
                  f"y {y0}–{y1})")
    hist = ins.pixel_history(path, x, y, root=args.root)
    written = (None if photo is None or size is None else
               _written_mask_at(info, path, photo[0], photo[1]))
    if written is not None:
        # (a trial: "kept" for a photo pixel that dynamic_mask.png holds; the run's
        # own output folder, when the recording names it and it still holds this
        # run's outputs, settles it)
        fin = bool(hist.get("final_dynamic"))
        out_dir = info["output_dir"]
        if written != fin:
            print(for_terminal(
                f"NOTE: {out_dir}/dynamic_mask.png {'holds' if written else 'leaves out'} "
                f"this photo pixel: at full size it is {'' if written else 'not '}"
                "replaced in clean.png (the mask is refined on the photo's edges), where "
                f"the verdict below, the analysis image's, has it "
                f"{'in' if fin else 'out of'} the final mask"))
    elif size is not None and hist.get("final_dynamic") is False:
        # (before the verdict, whose "not in the final mask" is the analysis
        # image's: a fresh-user trial read it as the photo's, at a border pixel
        # that dynamic_mask.png holds)
        L = ins.read_final_dynamic(path, root=ins.resolve_root(path, args.root))
        # (3 px: the full-size refinement adds specks that far out: a trial's
        # speck 3 analysis px from the border had no note)
        if L is not None and L[max(y - 3, 0):y + 4, max(x - 3, 0):x + 4].any():
            print(for_terminal(
                "NOTE: within 3 analysis pixels of the final mask's border. The verdict "
                "below is the analysis image's; at full size the mask is refined on the "
                "photo's edges and the fill reaches about one analysis pixel beyond it, "
                "so this photo pixel may be in dynamic_mask.png and changed in clean.png "
                "(it is there if it changed by ΔE 10 or more)"))
    print(for_terminal(vd.format_pixel_history(hist, seen_legends=seen)))


def _nothing_scored(report: dict) -> bool:
    """Whether an eval report scored no set: every set ran, and none has its
    reference's mask or a background (ablation reports too)."""
    info = report.get("set_info", [])
    return bool(info) and all("error" not in i and not (i.get("has_mask", True)
                                                        or i.get("has_background", True))
                              for i in info)


def for_terminal(text: str, width: int | None = None) -> str:
    """``text`` with its long lines wrapped at word boundaries to ``width`` columns (the
    terminal's, at most 100), each continuation indented two spaces past the line's
    own indent, when standard output is a terminal (``width`` None); as it is when
    piped, so that ``grep`` sees whole lines. ``inspect``'s reasons run to 500
    characters, which a terminal breaks mid-word."""
    if width is None:
        if not sys.stdout.isatty():
            return text
        width = min(shutil.get_terminal_size((100, 24)).columns, 100)
    out = []
    for line in text.split("\n"):
        indent = line[:len(line) - len(line.lstrip())]
        if len(line) <= width or len(indent) > width // 2:
            out.append(line)
            continue
        out.append(textwrap.fill(line.strip(), width, initial_indent=indent,
                                 subsequent_indent=indent + "  ", break_long_words=False,
                                 break_on_hyphens=False))
    return "\n".join(out)


def cmd_export(args: argparse.Namespace) -> int:
    ex = args.viewer("export")
    export_gif = ex.export_gif
    suffix = Path(args.out).suffix.lower()
    # a folder (no suffix, or one that exists) takes PNG frames (a trial asked for them)
    frames_dir = Path(args.out).is_dir() or (suffix == "" and not Path(args.out).is_file())
    if not frames_dir and suffix not in (".gif", ".mp4"):
        raise InputError(f"export: {args.out} must end in .gif or .mp4, or be a folder "
                         "(for PNG frames)")
    rec = _recording(args.recording)
    # before the drawing (a trial's --out /proc/x.gif failed after it, as an internal
    # error naming the temporary file)
    if frames_dir:
        try:
            ex.check_frames_dir(Path(args.out))
        except ValueError as e:
            raise InputError(f"--out {e}") from None
        io.check_out_file(Path(args.out) / ex.FRAME_NAME.format(0), "--out")
    else:
        io.check_out_file(args.out, "--out")
    # (and which run, in a --compare recording: a trial's missing --root failed after
    # the note that the drawing had begun)
    args.viewer("inspect").resolve_root(rec, args.root or "")
    _note(args, f"drawing a frame per snapshot of {rec} (a minute for a long run)")
    t0 = time.perf_counter()
    if frames_dir:
        written = ex.export_frames(rec, args.out, max_side=args.max_side, root=args.root)
        print(f"wrote {len(written)} frames to {args.out} ({ex.FRAME_NAME.format(0)} ... "
              f"{written[-1].name if written else '-'}; drawn in "
              f"{time.perf_counter() - t0:.0f} s; --fps is not used)")
        return EXIT_OK
    out = export_gif(rec, args.out, fps=args.fps, max_side=args.max_side, root=args.root)
    rate = ""
    if str(out).lower().endswith(".gif"):
        delay = args.viewer("export").gif_delay_ms(args.fps)
        if abs(1000.0 / delay - args.fps) > 0.05:  # (a trial's --fps 100 played at 50)
            rate = (f"; {delay} ms a frame, {1000.0 / delay:.1f} fps: a GIF holds whole "
                    f"hundredths of a second, 20 ms at least, not --fps {args.fps:g}")
    print(f"wrote {out} (drawn in {time.perf_counter() - t0:.0f} s{rate})")
    return EXIT_OK


# --- sinks and messages -------------------------------------------------------------------
_BIG_RECORDING_MIB = 100  # a recording above this gets a note saying what makes it large


def _file_mib(path) -> float | None:
    """The size of ``path`` in MiB, None if it cannot be read."""
    try:
        return Path(path).stat().st_size / 2 ** 20
    except OSError:
        return None


def parse_compare(spec: str, base: Params) -> Params:
    """``--compare``: a preset name, or ``field=value,...`` changes to the run's params."""
    if spec in PRESETS:
        return preset(spec)
    changes: dict[str, Any] = {}
    types = {f.name: f.type for f in dataclasses.fields(Params)}
    for item in spec.split(","):
        key, _, val = item.partition("=")
        key = key.strip().replace("-", "_")
        if key not in types or not _:
            raise InputError(f"--compare {spec!r}: expected a preset ({', '.join(PRESETS)}) "
                             f"or field=value pairs of Params, got {item!r}")
        t = str(types[key])
        try:
            changes[key] = (val.lower() in ("1", "true", "yes", "on") if t == "bool" else
                            int(val) if t == "int" else float(val) if t == "float" else val)
        except ValueError:
            raise InputError(f"--compare {spec!r}: {key} takes a {t}, got {val!r}") from None
    try:
        return dataclasses.replace(base, **changes)
    except (TypeError, ValueError) as e:
        raise InputError(f"--compare {spec!r}: {e}") from None


def _make_sink(args: argparse.Namespace, iset: Any, gt: np.ndarray | None, *,
               gt_background: np.ndarray | None = None, rec: Any = None, root: str = "",
               output_dir: Path | None = None):
    if not getattr(args, "record", None):
        return None
    Path(args.record).parent.mkdir(parents=True, exist_ok=True)
    sink = args.viewer("sink").RerunSink(None if rec is not None else args.record,
                     record_every_rows=getattr(args, "record_every_rows", None),
                     detail=getattr(args, "record_detail", "default"),
                     gt_mask=gt, gt_background=gt_background, rec=rec, root=root,
                     photo_size=None if iset is None else tuple(iset.original_size),
                     output_dir=output_dir)
    if rec is None:  # the sink creates the file when the run begins (inside the pipeline)
        begin, path = sink.begin, args.record

        def begin_or_input_error(*a: Any, **k: Any) -> None:
            with record_errors(path, sink):
                begin(*a, **k)

        sink.begin = begin_or_input_error
    return sink


@contextlib.contextmanager
def _native_stderr_silenced():
    """File descriptor 2 to /dev/null: Rerun's Rust side logs there itself (a coloured
    "WARN re_sdk::log_sink: Dropping data in MemorySink" when a stream that could not
    open its file is dropped), past ``sys.stderr``."""
    try:
        sys.stderr.flush()
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:
        yield
        return
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


@contextlib.contextmanager
def record_errors(path: str, sink: Any = None):
    """Rerun failing to create the ``--record`` file (RuntimeError "Failed to create
    file ...", e.g. a folder where no file can be created) is bad input: InputError
    naming --record; the half-made stream is dropped without Rerun's log line."""
    try:
        yield
    except RuntimeError as e:
        if sink is not None and getattr(sink, "_opened", False):
            raise  # the file was created: a failure while logging, not bad input
        reason = re.sub(r"^Failed to create file:\s*|,\s*path: .*$", "",
                        " ".join(str(e).split())) or type(e).__name__
        with _native_stderr_silenced():
            stream = getattr(sink, "rec", None)
            if sink is not None:
                sink.rec = None  # nothing to close: the file was never opened
            if stream is not None:
                with contextlib.suppress(Exception):
                    stream.disconnect()
            traceback.clear_frames(e.__traceback__)  # open_compare_stream's holds one
            del stream, e
            gc.collect()
        raise InputError(f"--record {path}: cannot create the file ({reason})") from None


def _bar(args: argparse.Namespace, params: Params | None = None) -> ProgressBar:
    return ProgressBar(enabled=not getattr(args, "quiet", False),
                       labels=stage_labels(params) if params is not None else None)


def _note(args: argparse.Namespace, msg: str, bar: ProgressBar | None = None) -> None:
    """``dynremove: note: msg`` on stderr (not with --quiet); with ``bar``, on a line
    of its own between the bar's stage lines."""
    if getattr(args, "quiet", False):
        return
    if bar is not None and bar.enabled:
        bar.note(f"dynremove: note: {msg}")
    else:
        print(f"dynremove: note: {msg}", file=sys.stderr)


def kernels_cached(record: bool = False) -> bool:
    """Whether numba's on-disk cache holds the scan kernels that a run (recorded or
    not: ``driver.compiled_kernels``) calls, for this source.

    Asks numba's own index (its source stamp is a hash of the file's content, so a
    checkout that only touches the file's time keeps the cache); on a numba whose
    internals differ, falls back to comparing the cache's and the source's times."""
    try:
        return all(bool(k._cache._cache_file._load_index()) for k in compiled_kernels(record))
    except Exception:  # noqa: BLE001 - numba internals: the fallback below
        pass
    src = Path(_kernels.__file__)
    cache = list((src.parent / "__pycache__").glob(src.stem + ".*.nbi"))
    return bool(cache) and max(c.stat().st_mtime for c in cache) >= src.stat().st_mtime


def _note_compile(args: argparse.Namespace) -> None:
    """Say so when this run will compile the kernels (a fresh install: ~35 s, once)."""
    record = bool(getattr(args, "record", None))
    if kernels_cached(record):
        return
    # where the cache goes (a trial on a read-only install saw "once per install" once
    # per user, and after each reboot where it fell back to the temporary folder)
    import dynremove

    cache = os.environ.get("NUMBA_CACHE_DIR")
    where = f"numba's cache in {cache}" if cache else "numba's cache"
    ours = dynremove._cache  # the folder dynremove chose, None where numba's or the user's
    temp = ours is not None and Path(ours).resolve().is_relative_to(
        Path(tempfile.gettempdir()).resolve())
    if record and kernels_cached(False):  # only the recorded scan's own kernels
        _note(args, "compiling the scan kernels a recorded run adds (once per install, a "
                    f"few seconds; later recorded runs reuse {where})")
    else:
        _note(args, "compiling the scan kernels (once per install, about 30-60 s; later "
                    f"runs reuse {where}"
                    + (", a temporary folder: your home's cache folder could not be used"
                       if temp else "") + ")")


def _line(args: argparse.Namespace, msg: str, bar: ProgressBar | None) -> None:
    """``msg`` as a line of its own (not with --quiet): between the bar's stage lines
    on a terminal (a line printed on stdout was glued to the bar's), else on stdout."""
    if getattr(args, "quiet", False):
        return
    if bar is not None and bar.enabled:
        bar.note(msg)
    else:
        print(msg)


def _say(args: argparse.Namespace, msg: str) -> None:
    if not getattr(args, "quiet", False):
        print(msg)


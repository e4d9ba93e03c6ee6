"""Command line: ``dynremove run | demo | bench | view | inspect | export | eval``.

Exit codes: 0 ok, 2 bad input, 1 internal error, 130 interrupted (SIGINT),
143 terminated (SIGTERM). Errors are one line on stderr; set DYNREMOVE_DEBUG=1
for a traceback. ``viewer`` (Rerun) is imported lazily, only when asked for.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from dynremove.params import PRESETS, Params, preset

EXIT_OK, EXIT_INTERNAL, EXIT_INPUT = 0, 1, 2


class Terminated(BaseException):
    """SIGTERM, raised in the main thread between chunks of work."""


# --- parameters as flags --------------------------------------------------------------
def add_param_flags(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group("method parameters (default: the chosen preset's values)")
    g.add_argument("--preset", choices=sorted(PRESETS), default="default",
                   help="'default' (best measured) or 'paper' (the method as written)")
    for f in dataclasses.fields(Params):
        flag = "--" + f.name.replace("_", "-")
        if f.type in ("bool", bool):
            g.add_argument(flag, dest=f"p_{f.name}", action=argparse.BooleanOptionalAction,
                           default=None, help=f"(default {f.default})")
        else:
            typ = {"int": int, "float": float, "str": str}.get(str(f.type), str)
            g.add_argument(flag, dest=f"p_{f.name}", type=typ, default=None, metavar="V",
                           help=f"(default {f.default})")


def params_from_args(args: argparse.Namespace) -> Params:
    base = preset(args.preset)
    changes = {k[2:]: v for k, v in vars(args).items() if k.startswith("p_") and v is not None}
    return dataclasses.replace(base, **changes) if changes else base


def parse_xy(s: str) -> tuple[int, int]:
    try:
        x, y = (int(v) for v in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y (two integers), got {s!r}") from None
    return x, y


# --- commands -----------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    from dynremove import io

    params = params_from_args(args)
    created = not Path(args.out).exists()
    out = io.prepare_out_dir(args.out)
    try:
        return _run(args, params, out)
    except BaseException:
        if created:  # bad input or interrupted: leave no empty folder behind
            try:
                out.rmdir()  # only if still empty
            except OSError:
                pass
        raise


def _run(args: argparse.Namespace, params: Params, out: Path) -> int:
    from dynremove import io
    from dynremove.pipeline import remove_dynamic

    t0 = time.perf_counter()
    iset = io.load_image_set(args.images, max_side=args.max_side)
    t_load = time.perf_counter() - t0
    ref = io.resolve_ref(args.ref, iset.names)
    for n in iset.notes:
        _note(args, n)
    gt = None
    if args.gt:
        H, W = iset.images[0].shape[:2]
        gt = io.read_mask(args.gt, (W, H))
    compare = parse_compare(args.compare, params) if args.compare else None
    if compare is not None and not args.record:
        raise ValueError("--compare needs --record FILE.rrd (the two runs go into one recording)")
    rec = None
    if compare is not None:
        from viewer.sink import open_compare_stream

        rec = open_compare_stream(args.record, [n for i, n in enumerate(iset.names) if i != ref],
                                  roots=["runs/main", "runs/compare"])
    sink = _make_sink(args, iset, gt, rec=rec, root="runs/main" if rec else "")
    bar = _bar(args)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = remove_dynamic(iset.images, ref=ref, params=params, sink=sink,
                                 probes=args.probe or (), sample_static=args.sample_static,
                                 names=iset.names, preset_name=args.preset, progress=bar)
            if compare is not None:
                sink_b = _make_sink(args, iset, gt, rec=rec, root="runs/compare")
                res_b = remove_dynamic(iset.images, ref=ref, params=compare, sink=sink_b,
                                       probes=args.probe or (),
                                       sample_static=args.sample_static, names=iset.names,
                                       preset_name="compare", progress=bar)
                _say(args, f"compare run: {100 * res_b.dynamic.mean():.1f} % dynamic "
                     f"(main: {100 * res.dynamic.mean():.1f} %), both in {args.record}")
        for w in caught:
            _note(args, str(w.message))
    finally:
        bar.close()
        if hasattr(sink, "close"):
            sink.close()
        if rec is not None:
            rec.flush()
            rec.disconnect()
    res.timings["load"] = t_load
    write_outputs(out, res, iset=iset, ref=ref, preset_name=args.preset, gt=gt,
                  record=args.record)
    _say(args, f"wrote {out}/clean.png, dynamic_mask.png, coverage.png, report.json"
         + (f" and {args.record}" if args.record else "")
         + f"  ({100 * res.dynamic.mean():.1f} % of the reference dynamic, "
         f"{res.timings['total'] + t_load:.1f} s)")
    return EXIT_OK


def write_outputs(out: Path, res: Any, *, iset: Any, ref: int, preset_name: str,
                  gt: np.ndarray | None = None, record: str | None = None) -> dict:
    """clean.png, dynamic_mask.png (0/255), coverage.png and report.json, atomically."""
    from dynremove import io
    from dynremove.metrics import jaccard

    io.write_image(out / "clean.png", res.clean)
    io.write_image(out / "dynamic_mask.png", res.dynamic.astype(np.uint8) * 255)
    n_src = max(1, len(iset.images) - 1)
    io.write_image(out / "coverage.png",
                   (res.coverage.astype(np.float32) * (255.0 / n_src)).astype(np.uint8))
    H, W = res.clean.shape[:2]
    report = {
        "inputs": [str(p) for p in iset.paths],
        "reference": {"index": ref, "name": iset.names[ref]},
        "size": {"width": W, "height": H, "original_width": iset.original_size[0],
                 "original_height": iset.original_size[1], "scale": iset.scale},
        "preset": preset_name,
        "params": res.params,
        "scans": [{"scan": int(s["scan"]), "direction": int(s["direction"]),
                   "dynamic_px": int(s["n_dynamic"]), "replaced_px": int(s["n_replaced"]),
                   "undecided_px": int(s["n_undecided"]), "seconds": float(s["seconds"])}
                  for s in res.scans],
        "dynamic_fraction": float(res.dynamic.mean()),
        "uncovered_dynamic_px": int((res.dynamic & (res.coverage == 0)).sum()),
        "geometry": res.geometry,
        "seconds": {k: round(float(v), 4) for k, v in res.timings.items()},
        "notes": list(iset.notes) + list(res.warnings),
        "recording": str(record) if record else None,
    }
    if gt is not None:
        report["jaccard_vs_gt"] = jaccard(res.dynamic, gt)
    io.write_json(out / "report.json", report)
    return report


def cmd_demo(args: argparse.Namespace) -> int:
    from dynremove import io, synth
    from dynremove.metrics import jaccard, psnr_in_mask
    from dynremove.pipeline import remove_dynamic

    params = params_from_args(args)
    out = io.prepare_out_dir(args.out)
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
    bar = _bar(args)
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
    return EXIT_OK


def cmd_bench(args: argparse.Namespace) -> int:
    from dynremove.bench import run_bench

    try:
        from viewer.sink import RerunSink
    except ImportError:  # pragma: no cover - rerun is a dependency
        return run_bench(args)
    return run_bench(args, recording_sink=lambda path, gt: RerunSink(path, gt_mask=gt))


# --- sinks and messages -------------------------------------------------------------------
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
            raise ValueError(f"--compare {spec!r}: expected a preset ({', '.join(PRESETS)}) "
                             f"or field=value pairs of Params, got {item!r}")
        t = str(types[key])
        changes[key] = (val.lower() in ("1", "true", "yes", "on") if t == "bool" else
                        int(val) if t == "int" else float(val) if t == "float" else val)
    return dataclasses.replace(base, **changes)


def _make_sink(args: argparse.Namespace, iset: Any, gt: np.ndarray | None, *,
               gt_background: np.ndarray | None = None, rec: Any = None, root: str = ""):
    if not getattr(args, "record", None):
        return None
    try:
        from viewer.sink import RerunSink
    except ImportError as e:  # pragma: no cover - rerun is a dependency
        raise RuntimeError(f"recording needs the viewer package and rerun-sdk ({e})") from None
    Path(args.record).parent.mkdir(parents=True, exist_ok=True)
    return RerunSink(None if rec is not None else args.record,
                     record_every_rows=getattr(args, "record_every_rows", None),
                     gt_mask=gt, gt_background=gt_background, rec=rec, root=root)


def _bar(args: argparse.Namespace):
    from dynremove.progress import ProgressBar

    return ProgressBar(enabled=not getattr(args, "quiet", False))


def _note(args: argparse.Namespace, msg: str) -> None:
    if not getattr(args, "quiet", False):
        print(f"dynremove: note: {msg}", file=sys.stderr)


def _say(args: argparse.Namespace, msg: str) -> None:
    if not getattr(args, "quiet", False):
        print(msg)


# --- parser --------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="dynremove",
        description="Detect moving objects in a set of hand-held photos of a scene and "
                    "replace them with the background they hide (Kanojia & Raman, WACV).")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="remove dynamic objects from a reference image",
                       description="Remove the moving objects from the reference image of a "
                                   "multi-view set. Writes clean.png, dynamic_mask.png, "
                                   "coverage.png and report.json to --out.")
    r.add_argument("images", nargs="+", help="a folder of images (sorted by name) or image files")
    r.add_argument("--ref", default=None, help="reference: index or file name (default: middle)")
    r.add_argument("--out", default="out/run", help="output folder (default: out/run)")
    r.add_argument("--max-side", type=int, default=None, metavar="PX",
                   help=f"downscale so the longer side is at most PX (default: only above "
                        f"1280 px; 0 = never)")
    r.add_argument("--record", default=None, metavar="FILE.rrd",
                   help="write a Rerun recording of the scans")
    r.add_argument("--record-every-rows", type=int, default=None, metavar="N",
                   help="snapshot the reference every N rows (default: ~50 per scan)")
    r.add_argument("--probe", type=parse_xy, action="append", metavar="X,Y",
                   help="record every decision at this pixel (repeatable)")
    r.add_argument("--sample-static", type=float, default=0.002, metavar="F",
                   help="fraction of static decisions recorded (default 0.002)")
    r.add_argument("--gt", default=None, metavar="MASK",
                   help="ground-truth mask of the reference (0/255) for error overlays")
    r.add_argument("--compare", default=None, metavar="PARAMS",
                   help="also run with other parameters (a preset name or field=value,...) "
                        "and log both side by side in the --record file")
    r.add_argument("--quiet", action="store_true", help="no progress bars or notes")
    add_param_flags(r)
    r.set_defaults(fn=cmd_run)

    d = sub.add_parser("demo", help="run on the built-in synthetic scene and print metrics")
    d.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    d.add_argument("--scene-seed", type=int, default=0, help="seed of the synthetic scene (default 0)")
    d.add_argument("--record", default="recordings/demo.rrd", metavar="FILE.rrd",
                   help="recording to write (default: recordings/demo.rrd)")
    d.add_argument("--no-record", action="store_true", help="do not write a recording")
    d.add_argument("--quiet", action="store_true")
    add_param_flags(d)
    d.set_defaults(fn=cmd_demo, probe=None, sample_static=0.002, compare=None)

    b = sub.add_parser("bench", help="stage timings, throughput and peak memory")
    b.add_argument("--size", default="854x480", help="image size WxH (default 854x480)")
    b.add_argument("--views", type=int, default=7, help="number of images (default 7)")
    b.add_argument("--json", default="out/bench.json", help="where to write the JSON")
    b.add_argument("--repeat", type=int, default=1, help="timed runs after a warm-up")
    b.add_argument("--no-reference", action="store_true",
                   help="skip the numba/reference speed ratio")
    b.add_argument("--quiet", action="store_true")
    add_param_flags(b)
    b.set_defaults(fn=cmd_bench)

    _add_viewer_commands(sub)
    _add_eval_commands(sub)
    return ap


def _add_viewer_commands(sub: Any) -> None:
    try:
        from viewer.commands import add_commands
    except ImportError:
        return
    add_commands(sub)


def _add_eval_commands(sub: Any) -> None:
    try:
        from dynremove.evaluate import add_commands
    except ImportError:
        return
    add_commands(sub, add_param_flags=add_param_flags, params_from_args=params_from_args)


def _quiet_opencv() -> None:
    """OpenCV's own warnings (e.g. "PNG input buffer is incomplete") would add lines to
    stderr next to ours, which already name the file and the problem."""
    try:
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except Exception:  # noqa: BLE001 - cosmetic only
        pass


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def _on_sigterm(signum: int, frame: Any) -> None:
    raise Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    debug = bool(os.environ.get("DYNREMOVE_DEBUG"))
    from dynremove.geometry import GeometryError
    from dynremove.pipeline import InputError

    _quiet_opencv()
    old = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return int(args.fn(args) or 0)
    except KeyboardInterrupt:
        print("dynremove: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("dynremove: terminated", file=sys.stderr)
        return 143
    except (InputError, GeometryError, ValueError, FileNotFoundError) as e:
        if debug:
            raise
        print(f"dynremove: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_INPUT
    except Exception as e:  # noqa: BLE001 - one line, not a traceback
        if debug:
            raise
        print(f"dynremove: internal error: {type(e).__name__}: {_one_line(e)} "
              "(set DYNREMOVE_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        signal.signal(signal.SIGTERM, old)


if __name__ == "__main__":
    sys.exit(main())

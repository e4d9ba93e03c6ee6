"""CLI subcommands that need Rerun: ``view``, ``inspect``, ``export``.

Registered by ``dynremove.cli`` (imported lazily there, so the core never
depends on Rerun).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def _recording(path: str) -> Path:
    p = Path(path)
    if not p.is_file():
        from dynremove.pipeline import InputError

        raise InputError(f"{p}: no such recording")
    return p


def cmd_view(args: argparse.Namespace) -> int:
    from viewer.serve import view

    view(_recording(args.recording), web=args.web, port=args.port, web_port=args.web_port)
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    from viewer import inspect as ins

    path = _recording(args.recording)
    if args.pixel is None and not args.failures:
        from dynremove.pipeline import InputError

        raise InputError("inspect: give --pixel X,Y or --failures")
    if args.pixel is not None:
        x, y = args.pixel
        print(ins.format_pixel_history(ins.pixel_history(path, x, y, root=args.root)))
    if args.failures:
        items = ins.failures(path, top=args.top, root=args.root)
        print(ins.format_failures(items))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from viewer.export import export_gif

    out = export_gif(_recording(args.recording), args.out, fps=args.fps,
                     max_side=args.max_side, root=args.root)
    print(f"wrote {out}")
    return 0


def add_commands(sub: Any) -> None:
    from dynremove.cli import parse_xy

    v = sub.add_parser("view", help="open a recording in the Rerun viewer (with its layout)")
    v.add_argument("recording", help="a .rrd file")
    v.add_argument("--web", action="store_true",
                   help="serve the web viewer on 127.0.0.1 only and print the URL")
    v.add_argument("--port", type=int, default=9876, help="gRPC port (default 9876)")
    v.add_argument("--web-port", type=int, default=9090, help="web viewer port (default 9090)")
    v.set_defaults(fn=cmd_view)

    i = sub.add_parser("inspect", help="explain a pixel or list failures from a recording",
                       description="Read a recording back: every decision, candidate "
                                   "cluster, replacement and correspondence update at a "
                                   "pixel, or the worst false positives/negatives when "
                                   "ground truth was recorded (run --gt).")
    i.add_argument("recording", help="a .rrd file")
    i.add_argument("--pixel", type=parse_xy, metavar="X,Y", help="pixel to explain")
    i.add_argument("--failures", action="store_true", help="list the worst FP/FN regions")
    i.add_argument("--top", type=int, default=10, help="how many failures (default 10)")
    i.add_argument("--root", default="", help="entity root of the run (--compare recordings)")
    i.set_defaults(fn=cmd_inspect)

    e = sub.add_parser("export", help="render the progressive removal to a GIF or MP4")
    e.add_argument("recording", help="a .rrd file")
    e.add_argument("--gif", "--out", dest="out", required=True, metavar="OUT",
                   help="output .gif or .mp4")
    e.add_argument("--fps", type=float, default=10.0, help="frames per second (default 10)")
    e.add_argument("--max-side", type=int, default=480, help="longest side in px (default 480)")
    e.add_argument("--root", default="", help="entity root of the run")
    e.set_defaults(fn=cmd_export)

"""``dynremove bench``: per-stage seconds, scan throughput, peak memory, and the
speed ratio of the compiled scan against the readable reference (same run)."""

from __future__ import annotations

import argparse
import resource
import sys
import time
import warnings


from dynremove import io, synth
from dynremove.events import MemorySink, NullSink
from dynremove.pipeline import prepare, remove_dynamic
from dynremove.scan.driver import run_scans


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_bench(args: argparse.Namespace, *, recording_sink=None) -> int:
    """``recording_sink(path, gt_mask)`` makes the sink whose cost is measured
    (the CLI passes viewer.RerunSink; the core never imports the viewer)."""
    from dynremove.cli import params_from_args

    params = params_from_args(args)
    try:
        W, H = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must be WxH, got {args.size!r}") from None
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    scene = synth.make_scene(seed=0, n_views=args.views, size=(H, W))
    ref = scene.ref_index
    say(f"bench: {args.views} synthetic views {W}x{H}, preset {args.preset}; warm-up (JIT) ...")
    t = time.perf_counter()
    small = [im[: min(H, 64), : min(W, 96)].copy() for im in scene.images]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 96x64 crop has few keypoints
        remove_dynamic(small, ref=ref, params=params)  # compiles (or loads the cache)
    warm = time.perf_counter() - t
    runs = []
    for i in range(max(1, args.repeat)):
        t = time.perf_counter()
        res = remove_dynamic(scene.images, ref=ref, params=params)
        wall = time.perf_counter() - t
        runs.append((wall, res))
        say(f"  run {i + 1}: {wall:.2f} s")
    wall, res = min(runs, key=lambda r: r[0])
    px = H * W
    per_scan = [{"scan": int(s["scan"]), "seconds": float(s["seconds"]),
                 "px_per_s": px / max(float(s["seconds"]), 1e-9),
                 "dynamic_px": int(s["n_dynamic"])} for s in res.scans]
    # recording cost with an in-memory sink (events only, no Rerun)
    t = time.perf_counter()
    remove_dynamic(scene.images, ref=ref, params=params, sink=MemorySink(), sample_static=0.002)
    wall_mem = time.perf_counter() - t
    rec = _recording_cost(scene, params, recording_sink) if recording_sink else {}
    out = {
        "size": [W, H], "views": args.views, "preset": args.preset,
        "warmup_s": warm, "end_to_end_s": wall, "end_to_end_all_s": [r[0] for r in runs],
        "stages_s": {k: float(v) for k, v in res.timings.items()},
        "scans": per_scan, "peak_rss_mb": _peak_rss_mb(),
        "memory_sink_end_to_end_s": wall_mem,
        **rec,
    }
    if not args.no_reference:
        out["kernel_vs_reference"] = _kernel_ratio(scene, params)
    _print_table(out)
    if args.json:
        io.write_json(args.json, out)
        print(f"wrote {args.json}")
    return 0


def _recording_cost(scene, params, make_sink) -> dict:
    """End-to-end seconds and .rrd size with a recording at the default cadence."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.rrd"
        t = time.perf_counter()
        remove_dynamic(scene.images, ref=scene.ref_index, params=params,
                       sink=make_sink(path, scene.masks[scene.ref_index]),
                       sample_static=0.002)
        return {"rerun_end_to_end_s": time.perf_counter() - t,
                "rrd_mb": path.stat().st_size / 2 ** 20}


def _kernel_ratio(scene, params) -> dict:
    """Seconds of one scan on a 40×32 crop, compiled vs readable reference."""
    crop = [im[100:132, 200:240].copy() for im in scene.images]
    p = params.replace(max_scans=1)
    st, _ = prepare(crop, scene.ref_index, p)
    t = time.perf_counter()
    run_scans(st.copy(), p, sink=NullSink(), kernel="numba")
    t_numba = time.perf_counter() - t
    t = time.perf_counter()
    run_scans(st.copy(), p, sink=NullSink(), kernel="reference")
    t_ref = time.perf_counter() - t
    return {"crop_px": 40 * 32, "numba_s": t_numba, "reference_s": t_ref,
            "speedup": t_ref / max(t_numba, 1e-9)}


def _print_table(out: dict) -> None:
    W, H = out["size"]
    print(f"\n{out['views']} views {W}x{H}, preset {out['preset']}")
    print(f"{'stage':<16}{'seconds':>10}")
    for k, v in out["stages_s"].items():
        print(f"{k:<16}{v:>10.2f}")
    print(f"{'end to end':<16}{out['end_to_end_s']:>10.2f}")
    print(f"\n{'scan':<6}{'seconds':>9}{'Mpx/s':>9}{'dynamic px':>12}")
    for s in out["scans"]:
        print(f"{s['scan']:<6}{s['seconds']:>9.2f}{s['px_per_s'] / 1e6:>9.2f}{s['dynamic_px']:>12}")
    print(f"\npeak RSS {out['peak_rss_mb']:.0f} MB; JIT warm-up {out['warmup_s']:.1f} s; "
          f"with MemorySink {out['memory_sink_end_to_end_s']:.2f} s")
    if "rerun_end_to_end_s" in out:
        print(f"with a Rerun recording {out['rerun_end_to_end_s']:.2f} s "
              f"(x{out['rerun_end_to_end_s'] / out['end_to_end_s']:.2f}), "
              f".rrd {out['rrd_mb']:.1f} MB")
    if "kernel_vs_reference" in out:
        k = out["kernel_vs_reference"]
        print(f"scan on a {k['crop_px']} px crop: numba {k['numba_s'] * 1e3:.1f} ms, "
              f"reference {k['reference_s']:.2f} s -> {k['speedup']:.0f}x")

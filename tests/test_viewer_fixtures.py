"""Fabricated runs for the viewer tests (no algorithm needed).

``fabricate_run`` builds a RunInfo and drives any number of sinks through
start → scan_started → chunk… → scan_finished → finish with events of the exact
dtypes of ``dynremove.events``: a coloured square in the reference is flagged
dynamic and replaced, scan after scan, by patches from the sources (which show
the background, shifted by a known offset), so that replaying the Replacement
events rebuilds the final image exactly.
"""

from __future__ import annotations

import importlib
import sys
import types
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def ensure_dynremove_importable() -> None:
    """Import ``dynremove.events`` even while ``dynremove.pipeline`` is missing.

    ``dynremove/__init__.py`` imports the pipeline, which may not exist yet; in
    that case register the package without running its ``__init__``.
    """
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    try:
        importlib.import_module("dynremove")
    except ModuleNotFoundError as e:
        if not (e.name or "").startswith("dynremove."):
            raise
        pkg = types.ModuleType("dynremove")
        pkg.__path__ = [str(ROOT / "dynremove")]
        sys.modules["dynremove"] = pkg
    importlib.import_module("dynremove.events")


ensure_dynremove_importable()

from dynremove import events as ev  # noqa: E402

SHIFTS = [(2, 1), (-1, 2), (1, -2), (-2, -1), (3, 0), (0, 3)]  # (dx, dy) per source


def _texture(H: int, W: int, rng: np.random.Generator) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    base = np.stack([128 + 60 * np.sin(xx / 7 + k) * np.cos(yy / 9 - k) for k in range(3)], -1)
    return np.clip(base + rng.normal(0, 12, (H, W, 3)), 0, 255).astype(np.uint8)


def make_info(H: int = 48, W: int = 64, S: int = 3, *, patch_size: int = 3,
              write: str = "patch", seed: int = 0, probes=((10, 7),),
              side: int | None = None) -> tuple:
    """RunInfo of a fabricated scene, plus the (x0, y0, side) of the object."""
    rng = np.random.default_rng(seed)
    bg = _texture(H + 8, W + 8, rng)
    side = side or max(4, min(H, W) // 5)
    x0, y0 = W // 3, H // 3
    ref = bg[4:4 + H, 4:4 + W].copy()
    ref[y0:y0 + side, x0:x0 + side] = (20, 20, 230)
    images = [ref]
    for s in range(S):
        dx, dy = SHIFTS[s % len(SHIFTS)]
        img = bg[4 + dy:4 + dy + H, 4 + dx:4 + dx + W].copy()  # img[y, x] = ref bg[y+dy, x+dx]
        ox = (x0 + (s + 1) * side + 2) % max(1, W - side)
        img[2:2 + side // 2, ox:ox + side // 2] = (230, 60, 20)  # the object elsewhere
        images.append(img)
    names = ["ref_00.jpg"] + [f"src {s:02d}.jpg" for s in range(S)]
    N0 = np.zeros((S, H, W, 2), np.int32)
    yy, xx = np.mgrid[0:H, 0:W]
    for s in range(S):
        dx, dy = SHIFTS[s % len(SHIFTS)]
        N0[s, ..., 0] = xx - dx
        N0[s, ..., 1] = yy - dy
    params = dict(patch_size=patch_size, write=write, t_r=0.3, seed=seed, max_scans=3)
    info = ev.RunInfo(
        names=names, ref_index=0, source_indices=list(range(1, S + 1)), images=images,
        params=params, preset="fabricated", versions={"numpy": np.__version__},
        size=(H, W), N0=N0, C0=rng.random((S, H, W)).astype(np.float32),
        coverage=np.full((H, W), S, np.uint8), probes=[tuple(q) for q in probes])
    bg_ref = bg[4:4 + H, 4:4 + W].copy()
    return info, (x0, y0, side), bg_ref


def _visit_order(H: int, W: int, direction: int):
    ys = range(H) if direction > 0 else range(H - 1, -1, -1)
    for y in ys:
        yield y


def fabricate_run(sinks, *, H: int = 48, W: int = 64, S: int = 3, n_scans: int = 3,
                  rows_per_chunk: int = 4, patch_size: int = 3, write: str = "patch",
                  sample_every: int = 23, seed: int = 0, side: int | None = None,
                  stop_after_scans: int | None = None,
                  on_scan_done=None):
    """Drive ``sinks`` through a fabricated run; return (info, result, truth).

    ``truth`` is a MemorySink that saw exactly the same calls.
    """
    truth = ev.MemorySink()
    sinks = [truth, *sinks]
    info, (x0, y0, side), bg_ref = make_info(H, W, S, patch_size=patch_size, write=write,
                                             seed=seed, side=side)
    rng = np.random.default_rng(seed + 1)
    K = 2 * S
    dt = ev.decision_dtype(K)
    image = info.images[0].copy()
    L = np.zeros((H, W), bool)
    N = info.N0.copy()
    C = info.C0.copy()
    probes = set(info.probes)
    summaries = []
    for sink in sinks:
        sink.start(info)
    for scan in range(n_scans):
        direction = 1 if scan % 2 == 0 else -1
        M = np.full((H, W), np.nan, np.float32)
        state = ev.ScanState(image=image, dynamic=L, M=M, N=N, C=C, scan=scan,
                             direction=direction)
        for sink in sinks:
            sink.scan_started(scan, direction, state)
        shrink = scan  # the object shrinks scan by scan: fewer dynamic pixels
        dyn = np.zeros((H, W), bool)
        dyn[y0 + shrink:y0 + side - shrink, x0 + shrink:x0 + side - shrink] = True
        n_dyn = n_rep = 0
        rows = list(_visit_order(H, W, direction))
        for c0 in range(0, H, rows_per_chunk):
            chunk_rows = rows[c0:c0 + rows_per_chunk]
            dec, rep, upd = [], [], []
            for y in chunk_rows:
                xs = range(W) if direction > 0 else range(W - 1, -1, -1)
                for x in xs:
                    idx = (y * W + x) if direction > 0 else ((H - 1 - y) * W + (W - 1 - x))
                    step = scan * H * W + idx
                    is_dyn = bool(dyn[y, x])
                    m = float(rng.uniform(0, 0.25) if is_dyn else rng.uniform(0.35, 1.0))
                    M[y, x] = m
                    why = (ev.WHY_DYNAMIC if is_dyn else 0) | \
                          (ev.WHY_PROBE if (x, y) in probes else 0) | \
                          (ev.WHY_SAMPLE if step % sample_every == 0 else 0)
                    if not why:
                        continue
                    d = np.zeros((), dt)
                    d["scan"], d["step"], d["x"], d["y"] = scan, step, x, y
                    d["M"], d["dynamic"], d["why"] = m, is_dyn, why
                    n_c = K - 1 - (step % 2)
                    d["n_cand"] = n_c
                    d["cand_src"][:] = -1
                    d["cand_src"][:n_c] = np.arange(n_c) % S
                    for k in range(n_c):
                        s = k % S
                        d["cand_xy"][k] = N[s, y, x] + (k // S)
                    d["cand_B"][:n_c] = rng.random(n_c).astype(np.float32)
                    d["cand_cluster"][:] = -1
                    d["cand_cluster"][:n_c] = np.arange(n_c) % 3 - (np.arange(n_c) == n_c - 1)
                    d["win_cluster"] = 1
                    d["win_weight"] = float(d["cand_B"][d["cand_cluster"] == 1].sum())
                    d["n_clusters"] = 3
                    d["consensus_dist"] = rng.random()
                    d["chosen_src"] = -1
                    if is_dyn:
                        s = (x + y + scan) % S
                        d["chosen_src"] = s
                        dx, dy = SHIFTS[s % len(SHIFTS)]
                        r = np.zeros((), ev.REPLACEMENT_DTYPE)
                        r["scan"], r["step"], r["x"], r["y"] = scan, step, x, y
                        r["src"], r["src_x"], r["src_y"] = s, x - dx, y - dy
                        r["score"], r["tie_break"], r["n_patches"] = 0.5 + 0.4 * m, m < 0.02, 4
                        rep.append(r)
                        one = np.array([r], ev.REPLACEMENT_DTYPE)
                        image[...] = ev.replay_replacements(image, info.images[1:], one,
                                                            patch_size=patch_size, write=write)
                        L[y, x] = True
                        for t in range(S):
                            u = np.zeros((), ev.CORRESPONDENCE_UPDATE_DTYPE)
                            u["scan"], u["step"], u["x"], u["y"] = scan, step, x, y
                            u["src"], u["case"] = t, 1 + (t + x) % 3
                            u["new_x"], u["new_y"] = N[t, y, x]
                            u["new_C"] = rng.random()
                            upd.append(u)
                        n_dyn += 1
                        n_rep += 1
                    dec.append(d)
            first_row, last_row = chunk_rows[0], chunk_rows[-1]
            i0 = c0 * W
            i1 = (c0 + len(chunk_rows)) * W
            batch = ev.EventBatch(
                scan=scan, rows=(first_row, last_row),
                step_range=(scan * H * W + i0, scan * H * W + i1),
                decisions=np.array(dec, dt) if dec else np.zeros(0, dt),
                replacements=np.array(rep, ev.REPLACEMENT_DTYPE) if rep
                else np.zeros(0, ev.REPLACEMENT_DTYPE),
                updates=np.array(upd, ev.CORRESPONDENCE_UPDATE_DTYPE) if upd
                else np.zeros(0, ev.CORRESPONDENCE_UPDATE_DTYPE))
            for sink in sinks:
                sink.chunk(batch, state)
        summ = np.zeros(1, ev.SCAN_SUMMARY_DTYPE)
        summ["scan"], summ["direction"] = scan, direction
        summ["n_dynamic"], summ["n_replaced"], summ["seconds"] = n_dyn, n_rep, 0.1 * (scan + 1)
        summaries.append(summ[0])
        for sink in sinks:
            sink.scan_finished(summ.copy(), state)
        if on_scan_done is not None:
            on_scan_done(scan)
        if stop_after_scans is not None and scan + 1 >= stop_after_scans:
            return info, None, truth
    result = SimpleNamespace(
        clean=image.copy(), dynamic=L.copy(), scans=np.array(summaries, ev.SCAN_SUMMARY_DTYPE),
        timings={"scan": 0.6, "features": 0.2}, coverage=info.coverage.copy(),
        params=dict(info.params))
    for sink in sinks:
        sink.finish(result)
    gt = np.zeros((H, W), bool)
    gt[y0 - 1:y0 + side - 1, x0:x0 + side] = True  # off by one row: some FP and FN
    truth.gt_mask = gt
    truth.gt_background = bg_ref
    return info, result, truth


def gt_for(H: int = 48, W: int = 64, S: int = 3, seed: int = 0):
    """Ground truth consistent with fabricate_run (same geometry)."""
    info, (x0, y0, side), bg_ref = make_info(H, W, S, seed=seed)
    gt = np.zeros((H, W), bool)
    gt[y0 - 1:y0 + side - 1, x0:x0 + side] = True
    return gt, bg_ref

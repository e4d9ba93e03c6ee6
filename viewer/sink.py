"""RerunSink: stream a run's events into a Rerun recording (.rrd).

The sink turns the core's structured event arrays (``dynremove.events``) into
entities (``viewer.paths``) on two sequence timelines: ``scan`` and ``step``
(the global, unique visit counter). Rules kept here (RERUN_NOTES.md):

* an explicit ``rr.RecordingStream``, never the global recording;
* O(chunks) calls, never one per pixel: per-step overlays go through one
  ``send_columns`` per entity and chunk, partitioned by step with ``pa.ListArray``;
* every array handed to rerun is freshly built (the batcher keeps references);
* images are JPEG (cv2) except label maps (uint8, compressed by the file's LZ4)
  and the final clean image (PNG, lossless, so a replay can be checked);
* raw events are also logged losslessly under ``events/*`` (one row per step,
  one list entry per event) so that ``viewer.inspect`` can read them back;
* ``rec.flush()`` once per scan, so a killed run leaves readable data.
"""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pandas  # noqa: F401  (pre-import: pyarrow would import it lazily, ~0.4 s)
import pyarrow as pa
import rerun as rr

from dynremove.evaluation.metrics import jaccard
from dynremove.events import EventBatch, RunInfo, ScanState, WHY_PROBE
from viewer import paths as P
from viewer._images import (CLASS_COLORS, cluster_colors, colormap, encode_jpeg,
                            encode_png, error_labels)
from viewer.blueprint import make_blueprint, make_compare_blueprint

_DIRECTION = {1: "top-left → bottom-right", -1: "bottom-right → top-left"}
_STAT_STYLE = {  # name: (RGB, label)
    "n_dynamic": ((230, 40, 40), "dynamic pixels (scan)"),
    "n_replaced": ((40, 160, 230), "replaced pixels (scan)"),
    "n_undecided": ((160, 160, 160), "undecided pixels (scan)"),
    "seconds": ((240, 160, 30), "seconds (scan)"),
    "dynamic_px": ((255, 90, 160), "|L| (running)"),
    "jaccard": ((40, 200, 90), "Jaccard vs ground truth"),
}


def _offsets(lengths: np.ndarray) -> pa.Array:
    return pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32))


def _list_column(values: np.ndarray, offsets: pa.Array) -> pa.ListArray:
    return pa.ListArray.from_arrays(offsets, pa.array(np.ascontiguousarray(values)))


def _summary_record(summary: np.ndarray) -> np.void:
    return np.asarray(summary).reshape(-1)[0]


class RerunSink:
    """EventSink writing a Rerun recording.

    Parameters
    ----------
    path : str or Path or None
        The ``.rrd`` file. Ignored when ``rec`` is given (the caller owns it).
    application_id, recording_id : str
        Rerun ids (``recording_id`` defaults to a fresh unique id).
    record_every_rows : int, optional
        Snapshot cadence of reference image, L and M in rows; default about 50
        snapshots per scan (``max(1, H // 50)``).
    gt_mask : (H, W) bool ndarray, optional
        Ground-truth dynamic mask of the reference: TP/FP/FN overlays, Jaccard.
    gt_background : (H, W, 3) uint8 BGR ndarray, optional
        Ground-truth clean reference: error image and PSNR at the end.
    root : str
        Prefix of every entity (two runs side by side: ``runs/a``, ``runs/b``).
    rec : rr.RecordingStream, optional
        Log into this stream (already saved/connected by the caller, who also
        disconnects it); otherwise the sink opens and owns one.
    jpeg_quality : int
        Quality of the JPEG snapshots.
    skip_unchanged_images : bool
        Skip the reference JPEG of a snapshot when no Replacement happened since
        the previous one (the viewer shows the latest image anyway). L is only
        logged when it changed; M, stats and errors follow the cadence exactly.
    """

    enabled = True
    MAX_PENDING_EVENTS = 200_000  # flush buffered columns earlier than the cadence

    def __init__(self, path: str | Path | None, *, application_id: str = "dynremove",
                 recording_id: str | None = None, record_every_rows: int | None = None,
                 gt_mask: np.ndarray | None = None,
                 gt_background: np.ndarray | None = None, root: str = "",
                 rec: rr.RecordingStream | None = None, jpeg_quality: int = 90,
                 skip_unchanged_images: bool = True) -> None:
        if rec is None and path is None:
            raise ValueError("path is required unless rec is given")
        if record_every_rows is not None and record_every_rows < 1:
            raise ValueError(f"record_every_rows must be >= 1, got {record_every_rows}")
        self.path = None if path is None else Path(path)
        self.application_id = application_id
        self.recording_id = recording_id or f"dynremove-{uuid.uuid4().hex[:12]}"
        self.record_every_rows = record_every_rows
        self.gt_mask = None if gt_mask is None else np.asarray(gt_mask, bool).copy()
        self.gt_background = None if gt_background is None else np.array(gt_background)
        self.p = P.Paths(root)
        self.rec = rec
        self._owns_rec = rec is None
        self.jpeg_quality = jpeg_quality
        self.skip_unchanged_images = skip_unchanged_images
        self._closed = False
        self.timing: dict[str, list[float]] = {}  # method: [calls, seconds]
        self.snapshots = 0

    # -- EventSink -------------------------------------------------------------
    def start(self, info: RunInfo) -> None:
        t0 = time.perf_counter()
        H, W = info.size
        self.info = info
        self.H, self.W = int(H), int(W)
        self.S = len(info.source_indices)
        self.K = 2 * self.S
        self.every = self.record_every_rows or max(1, self.H // 50)
        self.src_names = P.entity_names([info.names[i] for i in info.source_indices])
        params = dict(info.params)
        self.t_r = float(params.get("t_r", np.nan))
        self.patch_size = int(params.get("patch_size", 1))
        self.write = str(params.get("write", "patch"))
        if self.gt_mask is not None and self.gt_mask.shape != (self.H, self.W):
            raise ValueError(f"gt_mask has shape {self.gt_mask.shape}, expected {(self.H, self.W)}")
        if self.gt_background is not None and self.gt_background.shape[:2] != (self.H, self.W):
            raise ValueError(f"gt_background has shape {self.gt_background.shape}, "
                             f"expected {(self.H, self.W)}+")
        if self._owns_rec:
            self.rec = rr.RecordingStream(self.application_id, recording_id=self.recording_id)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(self.path, default_blueprint=make_blueprint(self.src_names,
                                                                      root=self.p.root))
        self._scan = 0
        self._last_step = 0
        self._rows_done = 0
        self._snap_step = -1
        self._last_L: np.ndarray | None = None
        self._image_dirty = False
        self._decisions_shown = False
        self._matches_shown = [False] * self.S
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_n = 0
        self._pending_scan = 0
        self._log_static(info, params)
        self._tick("start", t0)

    def scan_started(self, scan: int, direction: int, state: ScanState) -> None:
        t0 = time.perf_counter()
        self._scan = int(scan)
        self._rows_done = 0
        step = self._scan * self.H * self.W
        self._set_time(self._scan, step)
        self.rec.log(self.p(P.LOG), rr.TextLog(
            f"scan {scan} started ({_DIRECTION.get(int(direction), direction)})",
            level=rr.TextLogLevel.INFO))
        self.rec.log(self.p(P.REFERENCE_M), self._jpeg(colormap(state.M)))
        self._tick("scan_started", t0)

    def chunk(self, events: EventBatch, state: ScanState) -> None:
        t0 = time.perf_counter()
        scan = int(events.scan)
        first, end = int(events.step_range[0]), int(events.step_range[1])
        last = max(first, end - 1)
        self._scan, self._last_step = scan, last
        d, r, u = events.decisions, events.replacements, events.updates
        if d.dtype.names and d.dtype["cand_src"].shape[0] != self.K:  # K ≠ 2·S: record it
            self.K = int(d.dtype["cand_src"].shape[0])
            self.rec.log(self.p(P.RUN_INFO), rr.AnyValues(K=self.K), static=True)
        self._image_dirty |= len(r) > 0
        if self._pending and self._pending_scan != scan:
            self._flush_pending()
        if len(d) or len(r) or len(u):  # copies: the driver may reuse its buffers
            self._pending.append((d.copy(), r.copy(), u.copy()))
            self._pending_n += len(d) + len(r) + len(u)
            self._pending_scan = scan
        self._set_time(scan, last)
        self._log_decisions(d)
        self._log_matches(u)
        y = float(events.rows[1]) + 0.5
        self.rec.log(self.p(P.REFERENCE_SCANLINE), rr.LineStrips2D(
            [[[0.0, y], [float(self.W), y]]], colors=[(255, 255, 0)],
            radii=rr.Radius.ui_points(1.0)))
        rows = abs(int(events.rows[1]) - int(events.rows[0])) + 1
        before = self._rows_done // self.every
        self._rows_done += rows
        if self._rows_done // self.every > before:
            self._flush_pending()
            self._snapshot(state, scan, last)
        elif self._pending_n > self.MAX_PENDING_EVENTS:
            self._flush_pending()
        self._tick("chunk", t0)

    def scan_finished(self, summary: np.ndarray, state: ScanState) -> None:
        t0 = time.perf_counter()
        s = _summary_record(summary)
        scan = int(s["scan"])
        step = max(self._last_step, (scan + 1) * self.H * self.W - 1)
        self._last_step = step
        self._flush_pending()
        if self._snap_step != step:
            self._snapshot(state, scan, step)
        self._set_time(scan, step)
        for s_i, name in enumerate(self.src_names):
            self.rec.log(self.p(P.similarity(name)), self._jpeg(colormap(state.C[s_i])))
        for name in ("n_dynamic", "n_replaced", "n_undecided", "seconds"):
            self.rec.log(self.p(P.stat(name)), rr.Scalars(float(s[name])))
        self.rec.log(self.p(P.LOG), rr.TextLog(
            f"scan {scan} done: {int(s['n_dynamic'])} dynamic, {int(s['n_replaced'])} "
            f"replaced, {int(s['n_undecided'])} undecided, {float(s['seconds']):.2f} s",
            level=rr.TextLogLevel.INFO))
        self.rec.flush()
        self._tick("scan_finished", t0)

    def finish(self, result: Any) -> None:
        t0 = time.perf_counter()
        step = self._last_step + 1
        self._set_time(self._scan, step)
        clean = np.asarray(result.clean)
        L = np.asarray(result.dynamic, bool)
        self.rec.log(self.p(P.REFERENCE_IMAGE), self._jpeg(clean))
        self.rec.log(self.p(P.REFERENCE_DYNAMIC), rr.SegmentationImage(L.astype(np.uint8)))
        self.rec.log(self.p(P.RESULT_CLEAN), rr.EncodedImage(
            contents=encode_png(clean), media_type="image/png"), static=True)
        self.rec.log(self.p(P.RESULT_DYNAMIC), rr.SegmentationImage(L.astype(np.uint8)),
                     static=True)
        for name, stage in (getattr(result, "stages", None) or {}).items():
            self.rec.log(self.p(f"{P.RESULT_STAGES}/{name}"),
                         rr.SegmentationImage(np.asarray(stage, np.uint8)), static=True)
        sel = getattr(result, "selection", None)
        if sel is not None:  # the fill by selection (default preset)
            src_names = list(getattr(self, "src_names", []))
            self.rec.log(self.p(P.RESULT_SOURCE), rr.SegmentationImage(
                np.clip(np.asarray(sel.label, np.int32), 0, 255).astype(np.uint8)), static=True)
            self.rec.log(self.p(P.RESULT_SEAMS), rr.SegmentationImage(
                np.asarray(sel.seams, np.uint8)), static=True)
            self.rec.log(self.p(P.RESULT_EXPLAINED), rr.SegmentationImage(
                np.asarray(sel.explained, np.uint8)), static=True)
            for k, mv in enumerate(np.asarray(sel.movers, bool)):
                name = src_names[k] if k < len(src_names) else f"source{k}"
                self.rec.log(self.p(f"{P.RESULT_MOVERS}/{name}"),
                             rr.SegmentationImage(mv.astype(np.uint8)), static=True)
        clean_scan = getattr(result, "clean_scan", None)
        if clean_scan is not None:  # what the Replacement events rebuild
            self.rec.log(self.p(P.RESULT_CLEAN_SCAN), rr.EncodedImage(
                contents=encode_png(np.asarray(clean_scan)), media_type="image/png"),
                static=True)
        lines = [f"finished: |L| = {int(L.sum())} px"]
        self.rec.log(self.p(P.stat("dynamic_px")), rr.Scalars(float(L.sum())))
        if self.gt_mask is not None:
            self.rec.log(self.p(P.ERRORS_LABELS),
                         rr.SegmentationImage(error_labels(L, self.gt_mask)))
            j = jaccard(L, self.gt_mask)
            self.rec.log(self.p(P.stat("jaccard")), rr.Scalars(j))
            lines.append(f"Jaccard {j:.3f}")
        if self.gt_background is not None:
            diff = np.abs(clean.astype(np.int16) - self.gt_background.astype(np.int16))
            err = diff.max(axis=2).astype(np.float32)
            self.rec.log(self.p(P.ERRORS_BACKGROUND),
                         self._jpeg(colormap(err, vmin=0, vmax=64)), static=True)
            region = self.gt_mask if self.gt_mask is not None else np.ones_like(L)
            mse = float((diff[region] ** 2).mean()) if region.any() else 0.0
            psnr = 99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)
            lines.append(f"PSNR in ground-truth region {psnr:.2f} dB")
        timings = dict(getattr(result, "timings", {}) or {})
        if timings:
            lines.append("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
        sink_s = sum(v[1] for v in self.timing.values())
        lines.append(f"recording: {self.snapshots} snapshots, {sink_s:.2f} s in the sink")
        self.rec.log(self.p(P.LOG), rr.TextLog("; ".join(lines), level=rr.TextLogLevel.INFO))
        self._tick("finish", t0)
        self.close()

    def close(self) -> None:
        """Flush and, when the sink owns the stream, write the footer. Idempotent."""
        if self._closed or self.rec is None:  # never started: nothing to close
            return
        self._closed = True
        try:
            self._flush_pending()
            self.rec.flush()
        finally:
            if self._owns_rec:
                self.rec.disconnect()

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- static content --------------------------------------------------------
    def _log_static(self, info: RunInfo, params: dict) -> None:
        rec, p = self.rec, self.p
        rec.log(p(), rr.AnnotationContext(
            [(i, label, color) for i, (label, color) in CLASS_COLORS.items()]), static=True)
        ref = info.images[info.ref_index]
        md = [f"# dynremove run `{self.recording_id}`", "",
              f"* preset: **{info.preset}**, size {self.W}×{self.H}, seed {params.get('seed')}",
              f"* reference: `{info.names[info.ref_index]}` (index {info.ref_index})",
              "* sources: " + ", ".join(f"s={s} `{info.names[i]}`"
                                        for s, i in enumerate(info.source_indices)),
              f"* probes: {info.probes or 'none'}",
              f"* snapshots every {self.every} rows", "", "| parameter | value |", "|---|---|"]
        md += [f"| {k} | {v} |" for k, v in params.items()]
        md += ["", "| package | version |", "|---|---|"]
        md += [f"| {k} | {v} |" for k, v in info.versions.items()]
        rec.log(p(P.RUN_INFO), rr.TextDocument("\n".join(md), media_type="text/markdown"),
                rr.AnyValues(K=self.K, height=self.H, width=self.W, ref_index=info.ref_index,
                             names=list(info.names), source_names=self.src_names,
                             source_indices=list(info.source_indices),
                             preset=info.preset, recording_id=self.recording_id,
                             record_every_rows=self.every,
                             versions=json.dumps(info.versions),
                             params=json.dumps(params, default=str),
                             probes=json.dumps([list(map(int, q)) for q in info.probes])),
                static=True)
        rec.log(p(P.RUN_PARAMS), rr.AnyValues(**{
            k: (v if isinstance(v, (bool, int, float, str)) else str(v))
            for k, v in params.items()}), static=True)
        for s, name in enumerate(self.src_names):
            img = info.images[info.source_indices[s]]
            rec.log(p(P.source(name, P.IMAGE)), self._jpeg(img), static=True)
            rec.log(p(P.source(name, P.CANDIDATES)), rr.Points2D.from_fields(
                radii=rr.Radius.ui_points(3.0)), static=True)
        rec.log(p(P.REFERENCE_INPUT), self._jpeg(ref), static=True)
        cov = np.asarray(info.coverage, np.uint8)
        rec.log(p(P.COVERAGE), self._jpeg(colormap(cov.astype(np.float32), vmin=0,
                                                   vmax=max(1, self.S))), static=True)
        rec.log(p(P.RUN_COVERAGE), rr.SegmentationImage(cov.copy()), static=True)
        for name, (rgb, label) in _STAT_STYLE.items():
            rec.log(p(P.stat(name)), rr.SeriesLines(colors=[rgb], names=[label], widths=[2]),
                    rr.SeriesPoints(colors=[rgb], names=[label], markers=["circle"],
                                    marker_sizes=[3]), static=True)
        if self.gt_mask is not None:
            rec.log(p(P.GT_MASK), rr.SegmentationImage(self.gt_mask.astype(np.uint8)),
                    static=True)
        if self.gt_background is not None:
            rec.log(p(P.GT_BACKGROUND), self._jpeg(self.gt_background), static=True)
        # Initial state, at the first step of scan 0.
        self._set_time(0, 0)
        rec.log(p(P.REFERENCE_IMAGE), self._jpeg(ref))
        L0 = np.zeros((self.H, self.W), np.uint8)
        rec.log(p(P.REFERENCE_DYNAMIC), rr.SegmentationImage(L0))
        self._last_L = L0.astype(bool)
        for s, name in enumerate(self.src_names):
            rec.log(p(P.similarity(name)), self._jpeg(colormap(info.C0[s])))
        rec.log(p(P.LOG), rr.TextLog(
            f"run {self.recording_id}: {len(info.names)} images, reference "
            f"{info.names[info.ref_index]}, {self.S} sources, {self.W}x{self.H}, "
            f"preset {info.preset}", level=rr.TextLogLevel.INFO))

    # -- per chunk -------------------------------------------------------------
    def _flush_pending(self) -> None:
        """Send the buffered step-indexed columns (raw events, per-step overlays).

        They carry their own ``step`` index, so sending them once per snapshot
        interval instead of once per chunk changes nothing in the recording but
        the number of Arrow chunks (each costs ~0.5 KB of schema in the file).
        """
        if not self._pending:
            return
        d, r, u = (np.concatenate(parts) for parts in zip(*self._pending))
        self._pending, self._pending_n = [], 0
        scan = self._pending_scan
        self._log_table(P.EVENTS_DECISIONS, d, scan)
        self._log_table(P.EVENTS_REPLACEMENTS, r, scan)
        self._log_table(P.EVENTS_UPDATES, u, scan)
        self._log_per_step(d, r, scan)

    def _log_table(self, rel: str, arr: np.ndarray, scan: int) -> None:
        """Log structured records losslessly: one row per step, a list per field."""
        if len(arr) == 0:
            return
        order = np.argsort(arr["step"], kind="stable")
        steps, counts = np.unique(arr["step"][order], return_counts=True)
        cols = {}
        for name in arr.dtype.names:
            vals = arr[name][order]
            width = int(np.prod(vals.shape[1:], dtype=np.int64))
            cols[name] = _list_column(vals.reshape(-1), _offsets(counts * width))
        self.rec.send_columns(
            self.p(rel),
            indexes=[rr.TimeColumn("scan", sequence=np.full(len(steps), scan, np.int64)),
                     rr.TimeColumn("step", sequence=steps.astype(np.int64))],
            columns=rr.AnyValues.columns(**cols))

    def _log_decisions(self, d: np.ndarray) -> None:
        """All recorded decisions of the chunk, one log call (at the chunk's last step)."""
        path = self.p(P.REFERENCE_DECISIONS)
        if len(d) == 0:
            if self._decisions_shown:
                self.rec.log(path, rr.Clear(recursive=False))
                self._decisions_shown = False
            return
        cls = np.where(d["dynamic"], P.CLASS_DYNAMIC,
                       np.where(d["why"] & WHY_PROBE, P.CLASS_PROBE, P.CLASS_STATIC))
        self.rec.log(path,
                     rr.Points2D(np.stack([d["x"], d["y"]], 1).astype(np.float32) + 0.5,
                                 class_ids=cls.astype(np.uint16), show_labels=False,
                                 radii=rr.Radius.ui_points(2.5)),
                     rr.AnyValues(M=d["M"].copy(), t_r=np.full(len(d), self.t_r, np.float32),
                                  step=d["step"].copy(), win_cluster=d["win_cluster"].copy(),
                                  win_weight=d["win_weight"].copy(),
                                  chosen_src=d["chosen_src"].copy(),
                                  n_clusters=d["n_clusters"].copy(),
                                  n_cand=d["n_cand"].copy(), dynamic=d["dynamic"].copy(),
                                  why=d["why"].copy()))
        self._decisions_shown = True

    def _log_per_step(self, d: np.ndarray, r: np.ndarray, scan: int) -> None:
        """Overlays that explain one step: current decision, candidates, chosen patch.

        Logged partitioned by step; an empty partition at ``step + 1`` clears them.
        """
        shown = d[d["dynamic"] | ((d["why"] & WHY_PROBE) != 0)]
        if len(shown) == 0 and len(r) == 0:
            return
        ev = np.unique(np.concatenate([shown["step"], r["step"]]).astype(np.int64))
        steps = np.union1d(ev, ev + 1)
        n = len(steps)
        idx = [rr.TimeColumn("scan", sequence=np.full(n, scan, np.int64)),
               rr.TimeColumn("step", sequence=steps.copy())]

        def lengths_of(ev_steps: np.ndarray) -> np.ndarray:
            return np.bincount(np.searchsorted(steps, ev_steps), minlength=n)

        def ordered(a: np.ndarray) -> np.ndarray:
            return a[np.argsort(a["step"], kind="stable")]

        if len(shown):
            c = ordered(shown)
            lab = [f"M={m:.2f} → {'DYNAMIC' if dy else 'static'}"
                   for m, dy in zip(c["M"].tolist(), c["dynamic"].tolist())]
            lens = lengths_of(c["step"])
            off = _offsets(lens)
            self.rec.send_columns(self.p(P.REFERENCE_CURRENT), indexes=idx, columns=[
                *rr.Points2D.columns(
                    positions=np.stack([c["x"], c["y"]], 1).astype(np.float32) + 0.5,
                    labels=lab, colors=np.tile(np.array([[255, 0, 255]], np.uint8),
                                               (len(c), 1)),
                    radii=np.full(len(c), -6.0, np.float32)).partition(lens),
                *rr.AnyValues.columns(M=_list_column(c["M"], off),
                                      dynamic=_list_column(c["dynamic"], off),
                                      n_clusters=_list_column(c["n_clusters"], off),
                                      win_weight=_list_column(c["win_weight"], off))])
            # candidates, per source: flatten the K slots
            src = c["cand_src"].reshape(-1)
            cxy = c["cand_xy"].reshape(-1, 2)
            ccl = c["cand_cluster"].reshape(-1)
            cB = c["cand_B"].reshape(-1)
            cstep = np.repeat(c["step"], c["cand_src"].shape[1])
            win = ccl == np.repeat(c["win_cluster"], c["cand_src"].shape[1])
            win &= ccl >= 0
            rxy = np.repeat(np.stack([c["x"], c["y"]], 1), c["cand_src"].shape[1], axis=0)
            for s, name in enumerate(self.src_names):
                m = src == s
                if not m.any():
                    continue
                lens = lengths_of(cstep[m])
                off = _offsets(lens)
                self.rec.send_columns(self.p(P.source(name, P.CANDIDATES)), indexes=idx,
                                      columns=[
                    *rr.Points2D.columns(
                        positions=cxy[m].astype(np.float32) + 0.5,
                        colors=cluster_colors(ccl[m]),
                        radii=np.where(win[m], -5.0, -3.0).astype(np.float32)
                    ).partition(lens),
                    *rr.AnyValues.columns(cluster=_list_column(ccl[m], off),
                                          B=_list_column(cB[m], off),
                                          winner=_list_column(win[m], off),
                                          ref_x=_list_column(rxy[m, 0], off),
                                          ref_y=_list_column(rxy[m, 1], off))])
        if len(r):
            c = ordered(r)
            half = np.full((len(c), 2), self.patch_size / 2, np.float32)
            lens = lengths_of(c["step"])
            names = [self.src_names[int(s)] if 0 <= s < self.S else str(s)
                     for s in c["src"].tolist()]
            self.rec.send_columns(self.p(P.REFERENCE_CHOSEN_PATCH), indexes=idx, columns=[
                *rr.Boxes2D.columns(
                    centers=np.stack([c["x"], c["y"]], 1).astype(np.float32) + 0.5,
                    half_sizes=half, colors=np.tile(np.array([[0, 255, 0]], np.uint8), (len(c), 1)),
                    labels=[f"from {n} ({sx},{sy}) score {sc:.2f}" for n, sx, sy, sc in
                            zip(names, c["src_x"].tolist(), c["src_y"].tolist(),
                                c["score"].tolist())]).partition(lens)])
            for s, name in enumerate(self.src_names):
                m = c["src"] == s
                if not m.any():
                    continue
                cs = c[m]
                self.rec.send_columns(self.p(P.source(name, P.CHOSEN_PATCH)), indexes=idx,
                                      columns=[*rr.Boxes2D.columns(
                    centers=np.stack([cs["src_x"], cs["src_y"]], 1).astype(np.float32) + 0.5,
                    half_sizes=half[m].copy(),
                    colors=np.tile(np.array([[0, 255, 0]], np.uint8), (len(cs), 1)),
                    labels=[f"q* score {sc:.2f}" + (" (tie)" if t else "") for sc, t in
                            zip(cs["score"].tolist(), cs["tie_break"].tolist())]
                ).partition(lengths_of(cs["step"]))])

    def _log_matches(self, u: np.ndarray) -> None:
        """Correspondences updated in this chunk, in each source's own image space."""
        case_rgb = np.array([[0, 0, 0], [0, 200, 255], [255, 160, 0], [200, 0, 255]],
                            np.uint8)
        for s, name in enumerate(self.src_names):
            path = self.p(P.source(name, P.MATCHES))
            m = u["src"] == s if len(u) else np.zeros(0, bool)
            if not m.any():
                if self._matches_shown[s]:
                    self.rec.log(path, rr.Clear(recursive=False))
                    self._matches_shown[s] = False
                continue
            us = u[m]
            self.rec.log(path, rr.Points2D(
                np.stack([us["new_x"], us["new_y"]], 1).astype(np.float32) + 0.5,
                colors=case_rgb[np.clip(us["case"], 0, 3)], radii=rr.Radius.ui_points(2.0)),
                rr.AnyValues(case=us["case"].copy(), new_C=us["new_C"].copy(),
                             ref_x=us["x"].copy(), ref_y=us["y"].copy(),
                             step=us["step"].copy()))
            self._matches_shown[s] = True

    def _snapshot(self, state: ScanState, scan: int, step: int) -> None:
        """Reference image (JPEG), L (if changed), M, errors and running stats."""
        self._set_time(scan, step)
        rec, p = self.rec, self.p
        if self._image_dirty or not self.skip_unchanged_images:
            rec.log(p(P.REFERENCE_IMAGE), self._jpeg(state.image))
            self._image_dirty = False
        L = np.asarray(state.dynamic, bool)
        if self._last_L is None or not np.array_equal(L, self._last_L):
            self._last_L = L.copy()
            rec.log(p(P.REFERENCE_DYNAMIC), rr.SegmentationImage(L.astype(np.uint8)))
            if self.gt_mask is not None:
                rec.log(p(P.ERRORS_LABELS), rr.SegmentationImage(error_labels(L, self.gt_mask)))
        rec.log(p(P.REFERENCE_M), self._jpeg(colormap(state.M)))
        rec.log(p(P.stat("dynamic_px")), rr.Scalars(float(np.count_nonzero(L))))
        if self.gt_mask is not None:
            rec.log(p(P.stat("jaccard")), rr.Scalars(jaccard(L, self.gt_mask)))
        self._snap_step = step
        self.snapshots += 1

    # -- helpers ---------------------------------------------------------------
    def _set_time(self, scan: int, step: int) -> None:
        self.rec.set_time("scan", sequence=int(scan))
        self.rec.set_time("step", sequence=int(step))

    def _jpeg(self, bgr: np.ndarray) -> rr.EncodedImage:
        return rr.EncodedImage(contents=encode_jpeg(bgr, self.jpeg_quality),
                               media_type="image/jpeg")

    def _tick(self, name: str, t0: float) -> None:
        entry = self.timing.setdefault(name, [0, 0.0])
        entry[0] += 1
        entry[1] += time.perf_counter() - t0


def open_compare_stream(path: str | Path, source_names: list[str], *, roots: list[str],
                        application_id: str = "dynremove") -> rr.RecordingStream:
    """One recording for several runs logged under ``roots`` (``run --compare``).

    The caller passes it as ``rec`` to one RerunSink per run and disconnects it.
    """
    rec = rr.RecordingStream(application_id, recording_id=f"dynremove-{uuid.uuid4().hex[:12]}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rec.save(Path(path), default_blueprint=make_compare_blueprint(source_names, roots))
    return rec

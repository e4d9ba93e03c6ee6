"""RerunSink: stream a run's events into a Rerun recording (.rrd).

The sink turns the core's structured event arrays (``dynremove.events``) into
entities (``viewer.paths``) on two sequence timelines: ``scan`` and ``step``
(the global, unique visit counter). Rules kept here (RERUN_NOTES.md):

* an explicit ``rr.RecordingStream``, never the global recording;
* O(chunks) calls, never one per pixel: per-step overlays go through one
  ``send_columns`` per entity and scan, partitioned by step with ``pa.ListArray``;
* every array handed to rerun is freshly built (the batcher keeps references);
* images are JPEG (cv2) except label maps (uint8, compressed by the file's LZ4)
  and the final clean image (PNG, lossless, so a replay can be checked);
* raw events are also logged losslessly under ``events/*`` (one row per flush,
  one list entry per event, each with its own ``step``) so that
  ``viewer.inspect`` can read them back (those columns are built in
  ``viewer.sink_columns``);
* every recorded decision gets its per-step overlays on the reference (current
  marker with its attributes, verdict label, chosen patch); a *detail* level
  sets which also get them in the source views (candidates, q* boxes):
  ``"full"`` every one, ``"default"`` the probes, the sampled static decisions
  and the dynamic decisions on a grid of pixels (:data:`STEP_GRID`), so that the
  web viewer loads a 7 × 854×480 recording well under a minute
  (recordings/README.md); every decision stays in ``events/*``, the chunk
  entities and ``scan_maps/*`` either way;
* step-indexed columns are sent once per scan (few, large Arrow chunks: the
  web viewer's load time grows with the number of chunks) and ``rec.flush()``
  follows once per scan, so a killed run leaves readable data.
"""

from __future__ import annotations

import datetime
import json
import os
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pandas  # noqa: F401  (pre-import: pyarrow would import it lazily, ~0.4 s)
import rerun as rr

from dynremove.evaluation.metrics import jaccard
from dynremove.events import EventBatch, RunInfo, ScanState
from dynremove.refine.select import EVIDENCE, REASONS
from viewer import paths as P
from viewer._images import (CLASS_COLORS, REASON_NAMES, VERDICT_COLORS, VERDICT_NAMES,
                            cluster_colors, colormap, colormap_with_legend, count_classes,
                            encode_jpeg, encode_png, error_labels, overwritten_maps,
                            source_set_classes, visited_mask)
from viewer.blueprint import make_blueprint, make_compare_blueprint
from viewer.sink_columns import StepColumns
from viewer.verdict import after_scan_message, before_scans_message, more_scans

_REASON_COLOURS = {0: (0, 0, 0, 0), 1: (40, 200, 60, 160), 2: (150, 230, 150, 120),
                   3: (230, 40, 40, 160), 4: (120, 120, 120, 120), 5: (240, 150, 30, 140),
                   6: (60, 120, 230, 120), 7: (200, 40, 200, 160), 8: (250, 110, 40, 160),
                   9: (90, 210, 190, 150), 10: (240, 200, 40, 160)}

# the static 3-D structure test (EVIDENCE): green where a source counts for "static"
_EVIDENCE_COLOURS = {0: (0, 0, 0, 0), 1: (40, 200, 60, 160), 2: (150, 230, 150, 140),
                     3: (240, 200, 40, 140), 4: (200, 40, 200, 150), 5: (230, 40, 40, 160),
                     6: (120, 120, 120, 120), 7: (240, 120, 40, 150), 8: (90, 210, 190, 150)}


def _fill_match(sel: Any, c: int) -> np.ndarray:
    """Coordinate ``c`` (0: x, 1: y) of where the fill sampled its chosen source at
    each pixel (``Selection.fields`` of ``Selection.label``), in that source's pixels;
    (H, W) float32, NaN where the reference was kept, the pixel inpainted, or the
    sample off the source's frame (``paths.RESULT_FILL_MATCH``)."""
    label = np.asarray(sel.label)
    if sel.no_source is not None:
        label = np.where(np.asarray(sel.no_source, bool), 0, label)
    out = np.full(label.shape, np.nan, np.float32)
    for k, f in enumerate(sel.fields):
        at = label == k + 1
        out[at] = np.asarray(f)[..., c][at]
    return np.where(out >= 0, out, np.nan)


def _quantised(x: np.ndarray, scale: int) -> np.ndarray:
    """(H, W) float → uint16 round(x · scale), P.DE_NONE where NaN (clipped below it)."""
    x = np.asarray(x, np.float32)
    q = np.clip(np.round(np.nan_to_num(x, nan=0.0) * scale), 0, P.DE_NONE - 1)
    return np.where(np.isnan(x), P.DE_NONE, q).astype(np.uint16)


_DIRECTION = {1: "top-left → bottom-right", -1: "bottom-right → top-left"}
_STAT_STYLE = {  # name: (RGB, label)
    "n_dynamic": ((230, 40, 40), "dynamic pixels (scan)"),
    "n_replaced": ((40, 160, 230), "replaced pixels (scan)"),
    "n_undecided": ((160, 160, 160), "undecided pixels (scan)"),
    "seconds": ((240, 160, 30), "seconds (scan)"),
    "dynamic_px": ((255, 90, 160), "|L| (running)"),
    "jaccard": ((40, 200, 90), "Jaccard vs ground truth"),
}


DETAIL_LEVELS = ("default", "full")
STEP_GRID = 4  # default detail: source overlays for dynamic decisions at x, y % 4 == 0


def _summary_record(summary: np.ndarray) -> np.void:
    return np.asarray(summary).reshape(-1)[0]


_M_DOC = """# How to read M

M is the similarity of the reference pixel's features to the **winning cluster**
of candidate matches (the cluster with the largest summed weight b_m = Σ B_l).

* colour bar under the map: **M 0 (dark violet) → 1 (yellow)**, fixed range; the
  white tick marks **t_r**; dark grey = undecided (no cluster formed).
* **M ≤ t_r → dynamic** (the pixel disagrees with what the sources see there);
  M > t_r → static.
* B_l is a candidate's weight (the C value of the neighbour it came from);
  𝓑 is the DBSCAN distance between two candidates.
* Lossless per-scan values: `scan_maps/M` (M·10⁴), `scan_maps/verdict`, and the
  decision of every pixel: `n_candidates` |P|, `n_clusters` k, `win_size` |A_m|,
  `win_sources` (the sources of A_m; hover a pixel for their names) and `b_m`
  (tab "more maps → per scan"); `dynremove inspect REC --pixel X,Y` explains any
  pixel in words from them, probed or not.
"""


class RerunSink(StepColumns):
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
        Prefix of every entity (two runs side by side: ``runs/main``, ``runs/compare``).
    rec : rr.RecordingStream, optional
        Log into this stream (already saved/connected by the caller, who also
        disconnects it); otherwise the sink opens and owns one.
    jpeg_quality : int
        Quality of the JPEG snapshots.
    skip_unchanged_images : bool
        Skip the reference JPEG of a snapshot when no Replacement happened since
        the previous one (the viewer shows the latest image anyway). L is only
        logged when it changed; M, stats and errors follow the cadence exactly.
    detail : {"default", "full"}
        Which recorded decisions also get the per-step overlays of the source
        views (``sources/<name>/candidates`` and ``chosen_patch``; those on the
        reference, ``reference/current``, its label and
        ``reference/chosen_patch``, are logged for every one). ``"full"``: every
        one (teaching demos, small scenes). ``"default"``: probes, sampled static
        decisions and the dynamic decisions at pixels with
        ``x % STEP_GRID == 0 and y % STEP_GRID == 0``. Either way every recorded
        decision, replacement and update is in ``events/*`` and on its chunk's
        ``reference/decisions/...`` entity, and every pixel's decision in
        ``scan_maps/*``: ``inspect`` answers the same.
    photo_size : (W, H), optional
        Size of the photos as read, when they were analysed downscaled
        (``--max-side``): logged in ``run/info`` as ``photo_width`` and
        ``photo_height``, so that ``inspect --pixel`` can turn a photo pixel it is
        given by mistake into the analysis pixel it means.
    output_dir : path, optional
        Where ``dynremove run`` writes the clean photo and the mask: logged in
        ``run/info`` as ``output_dir`` (absolute), so that ``inspect
        --photo-pixel`` can read the written ``dynamic_mask.png`` at full size.
    """

    enabled = True
    MAX_PENDING_EVENTS = 200_000  # send buffered columns before the scan ends (memory)
    # log() rows are batched into one Arrow chunk per entity until rec.flush() (once
    # per scan) or 64 MiB, not every 200 ms (rerun's default): fewer, larger chunks
    BATCHER = dict(flush_tick=datetime.timedelta(seconds=30), flush_num_bytes=64 << 20)

    def __init__(self, path: str | Path | None, *, application_id: str = "dynremove",
                 recording_id: str | None = None, record_every_rows: int | None = None,
                 gt_mask: np.ndarray | None = None,
                 gt_background: np.ndarray | None = None, root: str = "",
                 rec: rr.RecordingStream | None = None, jpeg_quality: int = 90,
                 skip_unchanged_images: bool = True, detail: str = "default",
                 photo_size: tuple[int, int] | None = None,
                 output_dir: str | Path | None = None) -> None:
        if rec is None and path is None:
            raise ValueError("path is required unless rec is given")
        if detail not in DETAIL_LEVELS:
            raise ValueError(f"detail must be one of {DETAIL_LEVELS}, got {detail!r}")
        self.detail = detail
        self.info_extra = ({} if photo_size is None else
                           {"photo_width": int(photo_size[0]),
                            "photo_height": int(photo_size[1])})
        if output_dir is not None:
            self.info_extra["output_dir"] = str(Path(output_dir).resolve())
        self.step_grid = STEP_GRID if detail == "default" else 1
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
        self._done = False  # finish() ran: the recording is whole
        # a file an earlier run left at ``path``: this run writes beside it and replaces
        # it only when whole; cut short, it is kept and this run's is ``partial_path``
        self._earlier: Path | None = None
        self.partial_path: Path | None = None
        self._opened = False  # the file is open (begin() or start())
        self._scans_began = False
        self._seen = (0, 0)  # (scan, step) last seen, for interrupted()
        self._finished: tuple[int, float] | None = None  # (scan, n_dynamic) of the last
        # scan, when it has finished and no other has started
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_n = 0
        self.timing: dict[str, list[float]] = {}  # method: [calls, seconds]
        self.snapshots = 0

    # -- EventSink -------------------------------------------------------------
    def begin(self, names: list[str], size: tuple[int, int], *,
              images: list[np.ndarray] | None = None, ref: int | None = None) -> None:
        """Open the recording before features are computed (optional hook).

        A Ctrl-C during features, geometry or correspondences then still leaves a
        readable recording (names, size and the reference image); ``start``
        completes the setup.
        """
        t0 = time.perf_counter()
        H, W = int(size[0]), int(size[1])
        src = [n for i, n in enumerate(names) if i != ref]
        self._open(P.entity_names(src), (H, W))
        if self.rec is None:
            return
        p = self.p
        extra = dict(self.info_extra, **({} if ref is None else {"ref_index": int(ref)}))
        self.rec.log(p(P.RUN_INFO), rr.AnyValues(height=H, width=W, names=list(names), **extra),
                     static=True)
        if images is not None and ref is not None:
            self.rec.log(p(P.REFERENCE_INPUT), self._jpeg(np.asarray(images[ref])), static=True)
        self._set_time(0, 0)
        self.rec.log(p(P.LOG), rr.TextLog(
            f"run {self.recording_id}: {len(names)} images ({', '.join(names)}), {W}x{H}"
            + (f", reference {names[ref]}" if ref is not None else "")
            + ": computing features and correspondences", level=rr.TextLogLevel.INFO))
        self.rec.flush()
        self._tick("begin", t0)

    def interrupted(self, stage: str | None = None) -> None:
        """Log "interrupted at scan S, step N" (or before the scans) and close the file.

        Called by the CLI on Ctrl-C / SIGTERM. The recording keeps everything
        logged so far and gets its footer, so it reads back like a finished one.
        ``stage``: where the run was, said when the scans had not begun
        ("interrupted before the scans began (during features)") or had all
        finished ("interrupted after the scans (during the refinement)"); between
        two scans: "interrupted after scan 0, before scan 1 began".
        """
        if self._closed:
            return
        if self.rec is None:  # interrupted before begin(): an (almost) empty recording
            self._open(None, None)
            if self.rec is None:
                return
        try:
            self._flush_pending()
        except Exception:  # noqa: BLE001 - the interruption may have cut a chunk short
            self._pending, self._pending_n = [], 0
        scan, step = self._seen
        if not self._scans_began:
            msg = before_scans_message(stage)
        elif self._finished is not None:
            done, n_dyn = self._finished
            params = getattr(getattr(self, "info", None), "params", None) or {}
            msg = after_scan_message(done, more_scans(done, n_dyn, params), stage)
        else:
            msg = f"interrupted at scan {scan}, step {step}"
        self._set_time(scan, step)
        self.rec.log(self.p(P.LOG), rr.TextLog(msg, level=rr.TextLogLevel.WARN))
        self.rec.log(self.p(P.RUN_INTERRUPTED), rr.AnyValues(
            message=msg, scan=int(scan), step=int(step), scans_began=self._scans_began),
            static=True)
        self.close()

    def _open(self, src_names: list[str] | None, size: tuple[int, int] | None) -> None:
        """Create the stream and its file (once), when the sink owns it."""
        if self._opened or not self._owns_rec:
            self._opened = True
            return
        self.rec = rr.RecordingStream(self.application_id, recording_id=self.recording_id,
                                      batcher_config=rr.ChunkBatcherConfig(**self.BATCHER))
        self.path.parent.mkdir(parents=True, exist_ok=True)
        bp = None if src_names is None else make_blueprint(
            src_names, root=self.p.root, size=size, jaccard=self.gt_mask is not None)
        if self.path.exists():
            self._earlier = self.path
            self.path = self.path.with_name(f".{self.path.name}.{uuid.uuid4().hex[:8]}.tmp")
        self.rec.save(self.path, default_blueprint=bp)
        self._bp_sources = src_names
        self._opened = True

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
        if not self._opened:
            self._open(self.src_names, (self.H, self.W))
        elif self._owns_rec and getattr(self, "_bp_sources", None) != self.src_names:
            # begin() guessed the sources; some were dropped since (near-copies)
            self.rec.send_blueprint(make_blueprint(self.src_names, root=self.p.root,
                                                   size=(self.H, self.W),
                                                   jaccard=self.gt_mask is not None))
        self._scan = 0
        self._direction = 1
        self._last_step = 0
        self._rows_done = 0
        self._scan_reps: list[np.ndarray] = []
        self._chosen: list[np.ndarray] = []
        self._snap_step = -1
        self._last_L: np.ndarray | None = None
        self._image_dirty = False
        self._matches_shown = [False] * self.S
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_n = 0
        self._pending_scan = 0
        self._cluster_legends = False
        self._log_static(info, params)
        self._tick("start", t0)

    def scan_started(self, scan: int, direction: int, state: ScanState) -> None:
        t0 = time.perf_counter()
        self._scan = int(scan)
        self._scans_began = True
        self._finished = None
        self._seen = (self._scan, self._scan * self.H * self.W)
        self._direction = 1 if int(direction) >= 0 else -1
        self._rows_done = 0
        self._scan_reps = []
        self._chosen = []
        step = self._scan * self.H * self.W
        self._set_time(self._scan, step)
        self.rec.log(self.p(P.LOG), rr.TextLog(
            f"scan {scan} started ({_DIRECTION.get(int(direction), direction)}) at step "
            f"{step}", level=rr.TextLogLevel.INFO))
        if self._scan > 0:  # the previous scan's decisions: cleared, never re-targeted
            self.rec.log(self.p(P.REFERENCE_DECISIONS), rr.Clear(recursive=True))
        self.rec.log(self.p(P.REFERENCE_M), self._m_image(state.M))
        if self.gt_mask is not None:  # nothing visited yet in this scan: no errors
            self.rec.log(self.p(P.ERRORS_LABELS),
                         rr.SegmentationImage(np.zeros((self.H, self.W), np.uint8)))
        self._tick("scan_started", t0)

    def chunk(self, events: EventBatch, state: ScanState) -> None:
        t0 = time.perf_counter()
        scan = int(events.scan)
        first, end = int(events.step_range[0]), int(events.step_range[1])
        last = max(first, end - 1)
        self._scan, self._last_step = scan, last
        self._seen = (scan, last)
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
        if len(r):
            self._scan_reps.append(r[["x", "y", "step"]].copy())
            self._chosen.append(r[["x", "y", "src"]].copy())
        self._set_time(scan, last)
        vrows = (int(events.rows[0]), int(events.rows[1]))  # visiting order
        img_rows = tuple(v if self._direction > 0 else self.H - 1 - v for v in vrows)
        self._log_decisions(d, scan, img_rows)
        self._log_matches(u, img_rows)
        # the scan line sits on the edge between visited and not yet visited rows
        y = float(img_rows[1] + 1) if self._direction > 0 else float(img_rows[1])
        self.rec.log(self.p(P.REFERENCE_SCANLINE), rr.LineStrips2D(
            [[[0.0, y], [float(self.W), y]]], colors=[(255, 255, 255)],
            radii=rr.Radius.ui_points(1.5), labels=[f"scan {scan}, row {img_rows[1]}"],
            show_labels=False))
        rows = abs(int(events.rows[1]) - int(events.rows[0])) + 1
        before = self._rows_done // self.every
        self._rows_done += rows
        if self._rows_done // self.every > before:
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
        self._seen = (scan, step)
        self._flush_pending()
        self._rows_done = self.H
        if self._snap_step != step:
            self._snapshot(state, scan, step)
        self._set_time(scan, step)
        self._log_scan_maps(state, scan)
        for s_i, name in enumerate(self.src_names):
            self.rec.log(self.p(P.similarity(name)), self._jpeg(colormap(state.C[s_i])))
        for name in ("n_dynamic", "n_replaced", "n_undecided", "seconds"):
            self.rec.log(self.p(P.stat(name)), rr.Scalars(float(s[name])))
        self.rec.log(self.p(P.LOG), rr.TextLog(
            f"scan {scan} done: {int(s['n_dynamic'])} dynamic, {int(s['n_replaced'])} "
            f"replaced, {int(s['n_undecided'])} undecided, {float(s['seconds']):.2f} s",
            level=rr.TextLogLevel.INFO))
        self.rec.flush()
        self._finished = (scan, float(s["n_dynamic"]))
        self._tick("scan_finished", t0)

    def finish(self, result: Any) -> None:
        t0 = time.perf_counter()
        clean = np.asarray(result.clean)
        L = np.asarray(result.dynamic, bool)
        step = self._log_stages(result, clean, L)
        self._set_time(self._scan, step)
        self.rec.log(self.p(P.RESULT_CLEAN), rr.EncodedImage(
            contents=encode_png(clean), media_type="image/png"), static=True)
        self.rec.log(self.p(P.RESULT_DYNAMIC), rr.SegmentationImage(L.astype(np.uint8)),
                     static=True)
        for name, stage in (getattr(result, "stages", None) or {}).items():
            self.rec.log(self.p(f"{P.RESULT_STAGES}/{name}"),
                         rr.SegmentationImage(np.asarray(stage, np.uint8)), static=True)
        sel = getattr(result, "selection", None)
        if sel is not None:  # the fill by selection (default preset)
            params = dict(getattr(result, "params", {}) or {})
            src_names = list(getattr(self, "src_names", []))
            self.rec.log(self.p(P.RESULT_SOURCE), rr.AnnotationContext(
                [(0, "reference kept", (0, 0, 0, 0))]
                + [(k + 1, f"filled from {n}", tuple(int(v) for v in cluster_colors(
                    np.array([k]))[0]) + (150,)) for k, n in enumerate(src_names)]),
                rr.SegmentationImage(
                np.clip(np.asarray(sel.label, np.int32), 0, 255).astype(np.uint8)), static=True)
            self.rec.log(self.p(P.RESULT_SEAMS), rr.SegmentationImage(
                np.asarray(sel.seams, np.uint8)), static=True)
            if getattr(sel, "planes", None) is not None:
                pl = np.clip(np.asarray(sel.planes, np.int32) + 1, 0, 255).astype(np.uint8)
                self.rec.log(self.p(P.RESULT_PLANES), rr.AnnotationContext(
                    [(0, "", (0, 0, 0, 0)),
                     (1, "the field across L: the membrane, interpolated from around it",
                      (128, 128, 128, 60))]
                    + [(1 + k, f"the field across L: plane {k} of the ring around its "
                        "region, where the sources agree best", tuple(int(v) for v in
                        cluster_colors(np.array([k + 8]))[0]) + (150,))
                       for k in range(1, int(pl.max()))]),
                    rr.SegmentationImage(pl), static=True)
            # each with its own classes, 0 see-through (under the root's classes their
            # 1 read as "dynamic", and a view of them over the clean photo showed nothing
            # to tell them by: seen in a headless viewer, session 65)
            self.rec.log(self.p(P.RESULT_EXPLAINED), rr.AnnotationContext(
                [(0, "", (0, 0, 0, 0)),
                 (1, "in L, kept as static 3-D structure", (0, 220, 120, 150))]),
                rr.SegmentationImage(np.asarray(sel.explained, np.uint8)), static=True)
            if getattr(sel, "lingering", None) is not None:
                self.rec.log(self.p(P.RESULT_LINGERING), rr.AnnotationContext(
                    [(0, "", (0, 0, 0, 0)),
                     (1, "a mover that lingered, seen free by two sources or more",
                      (255, 200, 0, 150))]),
                    rr.SegmentationImage(np.asarray(sel.lingering, np.uint8)), static=True)
            if getattr(sel, "completed", None) is not None:
                self.rec.log(self.p(P.RESULT_COMPLETED), rr.AnnotationContext(
                    [(0, "", (0, 0, 0, 0)),
                     (1, "replaced with its region of L", (255, 140, 0, 160)),
                     (2, "kept with its region of L", (0, 160, 255, 160)),
                     (3, "kept: its fill did not fit the photo around it",
                      (160, 0, 255, 160)),
                     (4, "kept whole: only part of a mover could be replaced",
                      (255, 0, 160, 160))]),
                    rr.SegmentationImage(np.asarray(sel.completed, np.uint8)), static=True)
            if getattr(sel, "region_share", None) is not None:
                self.rec.log(self.p(P.RESULT_REGION_SHARE), rr.DepthImage(
                    _quantised(sel.region_share, P.P_SCALE), meter=float(P.P_SCALE),
                    colormap="viridis", depth_range=(0.0, float(P.P_SCALE))),
                    # (each value in the type the run's params are logged with: Rerun
                    # gives a component one type per recording)
                    rr.AnyValues(select_complete=float(params.get("select_complete",
                                                                  float("nan"))),
                                 select_complete_px=int(params.get("select_complete_px", -1))),
                    static=True)
            for rel, arr, names in ((P.RESULT_DATA_COST, getattr(sel, "data_cost", None),
                                     ("reference", "best_source")),
                                    (P.RESULT_SUPPORT, getattr(sel, "support", None),
                                     ("reference", "sources"))):
                if arr is None:
                    continue
                for name, a in zip(names, arr):
                    self.rec.log(self.p(f"{rel}/{name}"), rr.DepthImage(
                        _quantised(a, P.DE_SCALE), meter=float(P.DE_SCALE),
                        colormap="viridis"), static=True)
            self.rec.log(self.p(P.RESULT_INPAINTED), rr.AnnotationContext(
                [(0, "", (0, 0, 0, 0)),
                 (1, "no source free: inpainted (OpenCV Telea)", (255, 0, 255, 170))]),
                rr.SegmentationImage(
                (np.asarray(sel.no_source, bool) & np.asarray(result.dynamic, bool)
                 ).astype(np.uint8)), static=True)
            if getattr(sel, "relit", None) is not None:
                relit = np.asarray(sel.relit, bool)
                self.rec.log(self.p(P.RESULT_RELIT), rr.AnnotationContext(
                    [(0, "", (0, 0, 0, 0)),
                     (1, "a faint shade relit to the other photos' light", (255, 230, 120, 150))]),
                    rr.SegmentationImage(relit.astype(np.uint8)), static=True)
                gain = np.where(relit, np.asarray(sel.relight, np.float32)[..., 0], np.nan)
                self.rec.log(self.p(P.RESULT_RELIGHT_L), rr.DepthImage(
                    _quantised(gain, P.DE_SCALE), meter=float(P.DE_SCALE),
                    colormap="viridis", depth_range=(0.0, 15.0 * P.DE_SCALE)), static=True)
            # what the blend added to the chosen source, and the part of it that
            # blended the seams between sources: B/G/R levels as RGB around grey
            for name, path in (("offset", P.RESULT_OFFSET),
                               ("seam_offset", P.RESULT_SEAM_BLEND)):
                if getattr(sel, name, None) is not None:
                    off = np.nan_to_num(np.asarray(getattr(sel, name), np.float32)[..., ::-1],
                                        nan=0.0)
                    self.rec.log(self.p(path), rr.Image(
                        np.clip(np.round(off) + P.OFFSET_ZERO, 0, 255).astype(np.uint8)),
                        static=True)
            if getattr(sel, "fields", None) is not None and getattr(sel, "label", None) is not None:
                for c, axis in enumerate("xy"):
                    self.rec.log(self.p(f"{P.RESULT_FILL_MATCH}/{axis}"), rr.DepthImage(
                        _quantised(_fill_match(sel, c), P.XY_SCALE),
                        meter=float(P.XY_SCALE)), static=True)
            for k, mv in enumerate(np.asarray(sel.movers, bool)):
                name = src_names[k] if k < len(src_names) else f"source{k}"
                if getattr(sel, "followed", None) is not None and sel.followed[k].any():
                    self.rec.log(self.p(P.source(name, P.FOLLOWED_MOVER)),
                                 rr.AnnotationContext([(1, "the reference's mover, followed "
                                                       "here by the flow", (250, 110, 40, 110))]),
                                 rr.SegmentationImage(sel.followed[k].astype(np.uint8)),
                                 static=True)
                self.rec.log(self.p(f"{P.RESULT_MOVERS}/{name}"), rr.AnnotationContext(
                    [(0, "", (0, 0, 0, 0)),
                     (1, f"{name} shows a mover here: it may not fill", (255, 40, 40, 150))]),
                    rr.SegmentationImage(mv.astype(np.uint8)), static=True)
                if getattr(sel, "reasons", None) is not None:
                    self.rec.log(self.p(f"{P.RESULT_REASONS}/{name}"), rr.AnnotationContext(
                        [(c, w, _REASON_COLOURS[c]) for c, w in REASONS.items()]),
                        rr.SegmentationImage(np.asarray(sel.reasons[k], np.uint8)),
                        static=True)
                if getattr(sel, "static_evidence", None) is not None:
                    self.rec.log(self.p(f"{P.RESULT_EVIDENCE}/{name}"), rr.AnnotationContext(
                        [(c, w, _EVIDENCE_COLOURS[c]) for c, w in EVIDENCE.items()]),
                        rr.SegmentationImage(np.asarray(sel.static_evidence[k], np.uint8)),
                        static=True)
                    self.rec.log(self.p(f"{P.RESULT_LINE_DE}/{name}"), rr.DepthImage(
                        _quantised(sel.line_de[k], P.DE_SCALE), meter=float(P.DE_SCALE),
                        colormap="viridis", depth_range=(0.0, 30.0 * P.DE_SCALE)),
                        static=True)
                if getattr(sel, "line_xy", None) is not None:
                    xy = sel.line_xy[k]
                    inside = np.all((xy >= 0) & (xy * P.XY_SCALE < P.DE_NONE - 1), -1)
                    for c, axis in enumerate("xy"):
                        self.rec.log(self.p(f"{P.RESULT_LINE_MATCH}/{name}/{axis}"),
                                     rr.DepthImage(_quantised(np.where(inside, xy[..., c], np.nan),
                                                              P.XY_SCALE),
                                                   meter=float(P.XY_SCALE)), static=True)
            if getattr(sel, "static_need", None) is not None:
                self.rec.log(self.p(P.RESULT_STATIC_NEED),
                             rr.SegmentationImage(np.asarray(sel.static_need, np.uint8)),
                             rr.AnyValues(select_search_de=float(params.get("select_search_de",
                                                                             float("nan"))),
                                          select_tau=float(params.get("select_tau",
                                                                      float("nan"))),
                                          select_search_against_de=float(params.get(
                                              "select_search_against_de", float("nan")))),
                             static=True)
                self.rec.log(self.p(P.RESULT_REF_MOVER_P), rr.DepthImage(
                    _quantised(sel.ref_mover_p, P.P_SCALE), meter=float(P.P_SCALE),
                    colormap="magma", depth_range=(0.0, float(P.P_SCALE))), static=True)
        clean_scan = getattr(result, "clean_scan", None)
        if clean_scan is not None:  # what the Replacement events rebuild
            self.rec.log(self.p(P.RESULT_CLEAN_SCAN), rr.EncodedImage(
                contents=encode_png(np.asarray(clean_scan)), media_type="image/png"),
                static=True)
        lines = [f"finished: |L| = {int(L.sum())} px"]
        self.rec.log(self.p(P.stat("dynamic_px")), rr.Scalars(float(L.sum())))
        if self.gt_mask is not None:
            j = jaccard(L, self.gt_mask)
            self.rec.log(self.p(P.stat("jaccard")), rr.Scalars(j))
            # (at the analysed size: a trial read 0.829 here against the 0.823 that the
            # terminal and report.json give at the photo's size)
            lines.append(f"Jaccard {j:.3f} at the {self.W}x{self.H} analysed size")
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
        self.rec.disable_timeline(P.STAGE_TIMELINE)
        self._tick("finish", t0)
        self._done = True
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
                self._settle()

    def _settle(self) -> None:
        """Put the closed file in place: over an earlier run's file when this recording
        is whole, else beside it as ``<name>.partial.rrd`` (the earlier one is kept)."""
        if self._earlier is None or not self.path.exists():
            return
        if self._done:
            os.replace(self.path, self._earlier)
            self.path = self._earlier
        else:
            self.partial_path = self._earlier.with_name(
                f"{self._earlier.stem}.partial{self._earlier.suffix}")
            os.replace(self.path, self.partial_path)
            self.path = self.partial_path

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- static content --------------------------------------------------------
    def _log_static(self, info: RunInfo, params: dict) -> None:
        rec, p = self.rec, self.p
        rec.log(p(), rr.AnnotationContext(
            [rr.ClassDescription(info=(i, label, color)) for i, (label, color)
             in CLASS_COLORS.items()]
            + [rr.ClassDescription(info=(P.CLASS_DECISION, "decision reason"),
                                   keypoint_annotations=[(bit, name) for bit, name
                                                         in REASON_NAMES.items()])]),
            static=True)
        rec.log(p(P.scan_map("verdict")), rr.AnnotationContext(
            [(i, VERDICT_NAMES[i], VERDICT_COLORS[i]) for i in VERDICT_NAMES]), static=True)
        rec.log(p(P.scan_map("undecided")), rr.AnnotationContext(
            [(0, "", (0, 0, 0, 0)),
             (1, "undecided: no cluster formed, so no M", (90, 90, 90, 255))]), static=True)
        rec.log(p(P.scan_map("chosen_source")), rr.AnnotationContext(
            [(0, "not replaced", (0, 0, 0, 0))]
            + [(k + 1, f"patch from {n}", tuple(int(v) for v in cluster_colors(
                np.array([k]))[0]) + (200,)) for k, n in enumerate(self.src_names)]),
            static=True)
        rec.log(p(P.REFERENCE_M_LEGEND), rr.TextDocument(_M_DOC, media_type="text/markdown"),
                static=True)
        legend = [(P.CLASS_FP, "false positive: called dynamic, static in ground truth"),
                  (P.CLASS_FN, "false negative: missed mover"),
                  (P.CLASS_TP, "true positive")]
        if self.gt_mask is not None:  # a legend under the errors map, in its own space
            rec.log(p(P.ERRORS_LEGEND), rr.Points2D(
                [[4.0 + i * self.W / 3.0, self.H + 8.0] for i in range(len(legend))],
                class_ids=[c for c, _ in legend], labels=[t for _, t in legend],
                radii=rr.Radius.ui_points(6.0), show_labels=True), static=True)
        ref = info.images[info.ref_index]
        md = [f"# dynremove run `{self.recording_id}`", "",
              f"* preset: **{info.preset}**, size {self.W}×{self.H}, seed {params.get('seed')}",
              f"* reference: `{info.names[info.ref_index]}` (index {info.ref_index})",
              "* sources: " + ", ".join(f"s={s} `{info.names[i]}`"
                                        for s, i in enumerate(info.source_indices)),
              f"* probes: {info.probes or 'none'}",
              f"* snapshots every {self.every} rows",
              f"* detail: **{self.detail}** (" + (
                  "candidates and q* in the sources at every recorded decision"
                  if self.detail == "full" else
                  "candidates and q* in the sources at probes, sampled static decisions "
                  f"and dynamic decisions at x, y multiples of {self.step_grid}; "
                  "`--record-detail full` for every one") + ")",
              "", "| parameter | value |", "|---|---|"]
        md += [f"| {k} | {v} |" for k, v in params.items()]
        md += ["", "| package | version |", "|---|---|"]
        md += [f"| {k} | {v} |" for k, v in info.versions.items()]
        rec.log(p(P.RUN_INFO), rr.TextDocument("\n".join(md), media_type="text/markdown"),
                rr.AnyValues(K=self.K, height=self.H, width=self.W, ref_index=info.ref_index,
                             names=list(info.names), source_names=self.src_names,
                             source_indices=list(info.source_indices),
                             preset=info.preset, recording_id=self.recording_id,
                             record_every_rows=self.every, record_detail=self.detail,
                             step_grid=self.step_grid,
                             versions=json.dumps(info.versions),
                             params=json.dumps(params, default=str),
                             probes=json.dumps([list(map(int, q)) for q in info.probes]),
                             **self.info_extra),
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

        They carry their own ``step`` index, so sending them once per scan (or
        every ``MAX_PENDING_EVENTS`` events) instead of once per chunk changes
        nothing in the recording but the number of Arrow chunks. That number is
        what the web viewer's load time grows with most: camel's recording with
        the columns sent at every snapshot (~50 per scan) had 1,235 chunks and
        loaded in 102–149 s; sent once per scan (and ``log()`` rows batched until
        the scan's ``rec.flush()``, :attr:`BATCHER`), 178 chunks, 23–37 s
        (recordings/README.md). A run killed mid-scan loses that scan's columns
        and batched rows; Ctrl-C / SIGTERM send them (``interrupted``).
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
        self._log_probe_stories(d, r, scan)

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
        if self.gt_mask is not None:  # only where this scan has already been
            err = error_labels(L, self.gt_mask)
            err[~visited_mask(self.H, self.W, self._rows_done, self._direction)] = 0
            rec.log(p(P.ERRORS_LABELS), rr.SegmentationImage(err))
        rec.log(p(P.REFERENCE_M), self._m_image(state.M))
        rec.log(p(P.stat("dynamic_px")), rr.Scalars(float(np.count_nonzero(L))))
        if self.gt_mask is not None:
            rec.log(p(P.stat("jaccard")), rr.Scalars(jaccard(L, self.gt_mask)))
        self._snap_step = step
        self.snapshots += 1

    def _log_scan_maps(self, state: ScanState, scan: int) -> None:
        """Per-pixel maps of the scan just finished, lossless, at its last step.

        ``M`` comes from the core (M·10⁴ as uint16, 65535 = undecided); the rest is
        derived here from the scan's Replacement events: ``verdict`` (1 static,
        2 dynamic, 3 undecided), ``chosen_source`` (k + 1 = patch from source k),
        ``overwritten_before`` (patches centred elsewhere that overwrote the pixel
        before the scan reached it) and ``first_overwritten`` (step of the first
        of them − the scan's first step + 1; 0 = never). The core's cluster maps
        follow (:meth:`_log_cluster_maps`) when the state carries them.
        """
        H, W = self.H, self.W
        M = np.asarray(state.M, np.float32)
        nan = np.isnan(M)
        Mq = np.where(nan, P.M_UNDECIDED,
                      np.clip(np.rint(np.nan_to_num(M) * P.M_SCALE), 0, P.M_UNDECIDED - 1)
                      ).astype(np.uint16)
        verdict = np.where(nan, 3, np.where(M <= self.t_r, 2, 1)).astype(np.uint8)
        reps = (np.concatenate(self._scan_reps) if self._scan_reps
                else np.zeros(0, [("x", np.int32), ("y", np.int32), ("step", np.int64)]))
        half = self.patch_size // 2 if self.write == "patch" else 0
        before, first = overwritten_maps(H, W, reps, scan=scan, direction=self._direction,
                                         half=half)
        chosen = np.zeros((H, W), np.uint8)
        for part in self._chosen:
            chosen[part["y"], part["x"]] = np.clip(part["src"] + 1, 0, 255)
        base = scan * H * W
        first_rel = np.where(first >= 0, first - base + 1, 0).astype(np.uint32)
        rec, p = self.rec, self.p
        rec.log(p(P.scan_map("M")), rr.DepthImage(Mq, meter=float(P.M_SCALE),
                                                  colormap="viridis",
                                                  depth_range=(0.0, float(P.M_SCALE))),
                rr.AnyValues(scan=scan, direction=self._direction, t_r=round(self.t_r, 3),
                             scale=P.M_SCALE, undecided=P.M_UNDECIDED))
        rec.log(p(P.scan_map("verdict")), rr.SegmentationImage(verdict))
        # over M's view: the undecided pixels, whose 65535 the colour map draws at
        # the top, as M = 1 would be (seen in a headless viewer, session 65)
        rec.log(p(P.scan_map("undecided")), rr.SegmentationImage(
            (verdict == 3).astype(np.uint8), opacity=1.0, draw_order=1.0))
        rec.log(p(P.scan_map("chosen_source")), rr.SegmentationImage(chosen))
        rec.log(p(P.scan_map("overwritten_before")), rr.DepthImage(
            before, meter=1.0, colormap="magma",
            depth_range=(0.0, float(max(1, (2 * half + 1) ** 2 - 1)))))
        rec.log(p(P.scan_map("first_overwritten")), rr.DepthImage(
            first_rel, meter=1.0, colormap="turbo", depth_range=(0.0, float(H * W))))
        self._chosen = []
        if getattr(state, "clusters", None) is not None and state.b_m is not None:
            self._log_cluster_maps(state, scan)  # absent from fabricated/older cores

    def _log_cluster_maps(self, state: ScanState, scan: int) -> None:
        """The core's decision maps of the scan (Sec. 3.2.1), lossless, at its last step.

        ``n_candidates`` |P|, ``n_clusters`` k, ``win_size`` |A_m| (uint8
        SegmentationImages, each value named and coloured on a fixed ramp),
        ``win_sources`` (bitmask of the sources in A_m, bit s = source s: uint16,
        every combination named by its sources; uint32 above 16 sources) and
        ``b_m`` = Σ_{l ∈ A_m} B_l (float32 DepthImage, exact; 0 = no winning
        cluster). About 2 MiB per scan of 854×480 in the file, 1.6 MiB of it b_m
        (float32 hardly compresses; the small integer maps do).
        """
        rec, p = self.rec, self.p
        cl = np.asarray(state.clusters)  # (H, W, 4): |P|, k, |A_m|, sources of A_m
        if not self._cluster_legends:  # static: K is final once the first chunk came
            kmax = max(1, self.K)
            min_pts = max(1, int(dict(self.info.params).get("dbscan_min_pts", 2)))
            for name, label, zero, ramp in (
                    ("n_candidates", "|P| = {} candidates", "no candidate", kmax),
                    ("n_clusters", "k = {} clusters", "no cluster (undecided)",
                     max(1, kmax // min_pts)),
                    ("win_size", "|A_m| = {} candidates", "no winning cluster", kmax)):
                rec.log(p(P.scan_map(name)), rr.AnnotationContext(
                    count_classes(min(255, kmax), label, zero, ramp_max=ramp)), static=True)
            if self.S <= 10:  # 2^S named combinations
                rec.log(p(P.scan_map("win_sources")), rr.AnnotationContext(
                    source_set_classes(list(self.src_names))), static=True)
            self._cluster_legends = True
        for c, name in enumerate(("n_candidates", "n_clusters", "win_size")):
            rec.log(p(P.scan_map(name)),
                    rr.SegmentationImage(np.clip(cl[..., c], 0, 255).astype(np.uint8)),
                    rr.AnyValues(scan=scan, direction=self._direction))
        bits = np.uint16 if self.S <= 16 else np.uint32
        rec.log(p(P.scan_map("win_sources")),
                rr.SegmentationImage(cl[..., 3].astype(bits)),
                rr.AnyValues(scan=scan, direction=self._direction,
                             bit_order=", ".join(f"bit {s} = {n}"
                                                 for s, n in enumerate(self.src_names))))
        rec.log(p(P.scan_map("b_m")), rr.DepthImage(
            np.array(state.b_m, np.float32), meter=1.0, colormap="plasma",
            depth_range=(0.0, float(max(1, self.K)))),
            rr.AnyValues(scan=scan, direction=self._direction,
                         meaning="b_m = Σ B_l over the winning cluster A_m (B_l: a "
                                 "candidate's weight, its C value); 0 = no winning cluster"))

    def _log_stages(self, result: Any, clean: np.ndarray, L: np.ndarray) -> int:
        """The post-scan steps on the timeline, after the last scan step.

        Stage i (``scan``, ``clean``, ``votes``, ``snap``, ``select`` …) takes step
        ``last + 1 + i`` and ``stage`` = i; ``reference/dynamic`` shows its map.
        Returns the step of the final image (the written ``clean.png``).
        """
        step = self._last_step + 1
        stages = dict(getattr(result, "stages", None) or {})
        rec, p = self.rec, self.p
        for i, (name, stage) in enumerate(stages.items()):
            self._set_time(self._scan, step)
            rec.set_time(P.STAGE_TIMELINE, sequence=i)
            Ls = np.asarray(stage, bool)
            rec.log(p(P.REFERENCE_DYNAMIC), rr.SegmentationImage(Ls.astype(np.uint8)))
            if self.gt_mask is not None:
                rec.log(p(P.ERRORS_LABELS), rr.SegmentationImage(error_labels(Ls, self.gt_mask)))
            # the plots too (a trial saw J jump from 0.61 to 0.85 at the end with
            # nothing to say which stage bought it)
            rec.log(p(P.stat("dynamic_px")), rr.Scalars(float(Ls.sum())))
            j_txt = ""
            if self.gt_mask is not None:
                j = jaccard(Ls, self.gt_mask)
                rec.log(p(P.stat("jaccard")), rr.Scalars(j))
                j_txt = f", Jaccard {j:.3f}"
            rec.log(p(P.LOG), rr.TextLog(f"stage {i} '{name}' at step {step}: |L| = "
                                         f"{int(Ls.sum())} px{j_txt}",
                                         level=rr.TextLogLevel.INFO))
            step += 1
        self._set_time(self._scan, step)
        rec.set_time(P.STAGE_TIMELINE, sequence=len(stages))
        rec.log(p(P.REFERENCE_IMAGE), self._jpeg(clean))
        rec.log(p(P.REFERENCE_DYNAMIC), rr.SegmentationImage(L.astype(np.uint8)))
        if self.gt_mask is not None:
            rec.log(p(P.ERRORS_LABELS), rr.SegmentationImage(error_labels(L, self.gt_mask)))
        rec.log(p(P.LOG), rr.TextLog(f"stage {len(stages)} 'output' at step {step}: the "
                                     "written clean image", level=rr.TextLogLevel.INFO))
        self._last_step = step
        return step

    def _m_image(self, M: np.ndarray) -> rr.EncodedImage:
        """Colour-mapped M (fixed range [0, 1]) with its colour bar and t_r below."""
        return self._jpeg(colormap_with_legend(M, marks=((self.t_r, "t_r"),)))

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
                        application_id: str = "dynremove",
                        jaccard: bool = True) -> rr.RecordingStream:
    """One recording for several runs logged under ``roots`` (``run --compare``).

    The caller passes it as ``rec`` to one RerunSink per run and disconnects it.
    ``jaccard``: whether the runs have a ground-truth mask (the "Jaccard" plots).
    """
    rec = rr.RecordingStream(application_id, recording_id=f"dynremove-{uuid.uuid4().hex[:12]}",
                             batcher_config=rr.ChunkBatcherConfig(**RerunSink.BATCHER))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rec.save(Path(path), default_blueprint=make_compare_blueprint(source_names, roots,
                                                                  jaccard=jaccard))
    return rec

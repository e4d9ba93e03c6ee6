"""Python driver of the scans: owns the state and the event buffers, calls the sink.

The compiled kernel visits a chunk of rows at a time; between chunks the driver
turns the raw buffers into the structured events of ``dynremove.events`` and
hands them to the sink with a read-only view of the state. Python overhead is
O(rows), never O(pixels).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numba
import numpy as np

from dynremove.events import (
    CORRESPONDENCE_UPDATE_DTYPE,
    REPLACEMENT_DTYPE,
    SCAN_SUMMARY_DTYPE,
    EventBatch,
    EventSink,
    ScanState,
    decision_dtype,
)
from dynremove.method.scan import _kernels as kn
from dynremove.params import Params


@dataclass
class ScanInputs:
    """Everything the scan reads and writes. Reference arrays are mutated in place.

    img (H, W, 3) uint8, lab (H, W, 3) float32, gray (H, W) float32, fc_r (H, W, 3)
    float32, fg_r (H, W, 128) uint8; sources with a leading S axis; N (S, H, W, 2)
    int32; C (S, H, W) float32; F (S, 3, 3) float64; hasF (S,) bool.
    ``pipeline.remove_dynamic`` sets fg_r and fg_s to None once the scans and the
    coverage map are done (their last readers): 0.8 GB at 5 photos of 1280×960.
    """

    img: np.ndarray
    lab: np.ndarray
    gray: np.ndarray
    fc_r: np.ndarray
    fg_r: np.ndarray
    src_img: np.ndarray
    src_lab: np.ndarray
    src_gray: np.ndarray
    fc_s: np.ndarray
    fg_s: np.ndarray
    N: np.ndarray
    C: np.ndarray
    F: np.ndarray
    hasF: np.ndarray
    sift_unit: float
    Nf: np.ndarray | None = None  # (S, H, W, 2) float32 sub-pixel initial matches (not scanned)
    Nf_flow: np.ndarray | None = None  # (S, H, W, 2) float32 the same before the gate (the fill's)
    curves: np.ndarray | None = None  # (S, 3, 256) uint8 B, G, R tone curves applied to the sources

    @property
    def shape(self) -> tuple[int, int]:
        return self.gray.shape

    def copy(self) -> "ScanInputs":
        return ScanInputs(**{k: (v.copy() if isinstance(v, np.ndarray) else v)
                             for k, v in self.__dict__.items()})


def pack_params(params: Params, *, sift_unit: float, sample_rate: float = 0.0):
    """Unpack Params to the kernel's scalar arrays (pf float64, pi int64).

    Only the compiled kernel reads these; the reference reads ``Params`` by name,
    so a wrong index here makes the kernel-vs-reference test fail.
    """
    pf = np.zeros(kn.N_PF, np.float64)
    pf[kn.LAM1], pf[kn.LAM2], pf[kn.LAM3] = params.lambda1, params.lambda2, params.lambda3
    pf[kn.LAM4], pf[kn.LAM5] = params.lambda4, params.lambda5
    pf[kn.LAM6], pf[kn.LAM7], pf[kn.LAM8] = params.lambda6, params.lambda7, params.lambda8
    pf[kn.SIG_C], pf[kn.SIG_G] = params.sigma_c, params.sigma_g
    pf[kn.SIG_E], pf[kn.SIG_H] = params.sigma_e, params.sigma_h
    pf[kn.T_R], pf[kn.EPS], pf[kn.SIFT_UNIT] = params.t_r, params.dbscan_eps, sift_unit
    pf[kn.HOG_SCALE], pf[kn.COORD_SCALE] = params.hog_scale, params.coord_scale_px
    pf[kn.TIE_TOL], pf[kn.SAMPLE_RATE] = params.tie_tol, sample_rate
    pi = np.zeros(kn.N_PI, np.int64)
    pi[kn.P], pi[kn.MIN_PTS] = params.patch_size, params.dbscan_min_pts
    pi[kn.HOG_BINS] = params.hog_bins
    pi[kn.WRITE_PATCH] = params.write == "patch"
    pi[kn.UPDATE] = params.update
    pi[kn.USE_EPI] = params.use_epipolar
    pi[kn.USE_HOG] = params.use_hog
    pi[kn.CAND_SET] = params.candidate_set
    return pf, pi


class _Buffers:
    """Preallocated struct-of-arrays event buffers sized for the worst chunk."""

    def __init__(self, rows: int, W: int, S: int, record: bool) -> None:
        K = 2 * S
        cap = rows * W if record else 1
        self.K = K
        self.dec_i = np.zeros((cap, kn.N_DI), np.int64)
        self.dec_f = np.zeros((cap, 3), np.float32)
        self.dec_cs = np.zeros((cap, K), np.int8)
        self.dec_cxy = np.zeros((cap, K, 2), np.int32)
        self.dec_cB = np.zeros((cap, K), np.float32)
        self.dec_ccl = np.zeros((cap, K), np.int16)
        self.rep_i = np.zeros((cap, kn.N_RI), np.int64)
        self.rep_f = np.zeros(cap, np.float32)
        self.upd_i = np.zeros((cap * S, kn.N_UI), np.int64)
        self.upd_f = np.zeros(cap * S, np.float32)
        self.counts = np.zeros(3, np.int64)

    def args(self):
        return (self.dec_i, self.dec_f, self.dec_cs, self.dec_cxy, self.dec_cB, self.dec_ccl,
                self.rep_i, self.rep_f, self.upd_i, self.upd_f, self.counts)

    def take(self, scan: int, rows: tuple[int, int], steps: tuple[int, int]) -> EventBatch:
        """Copy the filled part of the buffers into owned structured arrays."""
        nd, nr, nu = (int(c) for c in self.counts)
        if nd > len(self.dec_i) or nr > len(self.rep_i) or nu > len(self.upd_i):
            raise RuntimeError("event buffer overflow "
                               "(a bug: buffers are sized for the worst case)")
        d = np.zeros(nd, decision_dtype(self.K))
        di = self.dec_i[:nd]
        d["scan"], d["step"] = di[:, kn.D_SCAN], di[:, kn.D_STEP]
        d["x"], d["y"] = di[:, kn.D_X], di[:, kn.D_Y]
        d["M"], d["win_weight"], d["consensus_dist"] = (self.dec_f[:nd, 0], self.dec_f[:nd, 1],
                                                        self.dec_f[:nd, 2])
        d["dynamic"] = di[:, kn.D_DYN] != 0
        d["why"], d["n_cand"] = di[:, kn.D_WHY], di[:, kn.D_NCAND]
        d["win_cluster"], d["n_clusters"], d["chosen_src"] = (di[:, kn.D_WIN], di[:, kn.D_NCL],
                                                              di[:, kn.D_CHOSEN])
        d["cand_src"], d["cand_xy"] = self.dec_cs[:nd], self.dec_cxy[:nd]
        d["cand_B"], d["cand_cluster"] = self.dec_cB[:nd], self.dec_ccl[:nd]
        r = np.zeros(nr, REPLACEMENT_DTYPE)
        ri = self.rep_i[:nr]
        for name, col in (("scan", kn.R_SCAN), ("step", kn.R_STEP), ("x", kn.R_X), ("y", kn.R_Y),
                          ("src", kn.R_SRC), ("src_x", kn.R_SX), ("src_y", kn.R_SY),
                          ("n_patches", kn.R_NP)):
            r[name] = ri[:, col]
        r["tie_break"] = ri[:, kn.R_TIE] != 0
        r["score"] = self.rep_f[:nr]
        u = np.zeros(nu, CORRESPONDENCE_UPDATE_DTYPE)
        ui = self.upd_i[:nu]
        for name, col in (("scan", kn.U_SCAN), ("step", kn.U_STEP), ("x", kn.U_X), ("y", kn.U_Y),
                          ("src", kn.U_SRC), ("case", kn.U_CASE), ("new_x", kn.U_NX),
                          ("new_y", kn.U_NY)):
            u[name] = ui[:, col]
        u["new_C"] = self.upd_f[:nu]
        self.counts[:] = 0
        return EventBatch(scan=scan, rows=rows, step_range=steps, decisions=d,
                          replacements=r, updates=u)


# precompute the scan's decisions on all cores (exact; off only to measure it)
PRECOMPUTE = True
# an unrecorded scan visits on all cores, in a pipeline of rows (exact; off only
# to measure it): ``_kernels._scan``
PIPELINE = True


def scan_on_all_cores(record: bool) -> bool:
    """Whether a run's scan visits its rows in a pipeline on all cores (the same
    result): when it is not recorded and numba, compiling, has more than one thread. A
    recorded one visits one pixel at a time, so that its events come in the
    visiting order."""
    return (PIPELINE and not record and numba.get_num_threads() > 1
            and not numba.config.DISABLE_JIT)  # (its atomics exist only compiled)


def compiled_kernels(record: bool) -> list:
    """The compiled scan kernels every run calls (recorded or not): the scan itself
    (``_kernels._scan``, the same entry for both), and the decisions precomputed on
    all cores (``_kernels._decide_all``) where the first scan takes them (one not
    in the pipeline: recorded, or on one thread). A pipelined run takes them only
    from its second scan on, which the default's one scan never reaches: were they
    listed for it, its cache would never be complete and every run would say it
    compiles (a fresh-user trial: "compiling the scan kernels" at every run)."""
    pre = PRECOMPUTE and not scan_on_all_cores(record)
    return [kn._scan] + ([kn._decide_all] if pre else [])


def _readonly(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def run_scans(st: ScanInputs, params: Params, *, sink: EventSink, probe: np.ndarray | None = None,
              sample_static: float = 0.0, chunk_rows: int | None = None,
              kernel: str = "numba",
              progress: Callable[[int, int, int], None] | None = None):
    """Alternate scans until one labels no pixel dynamic, or ``max_scans``.

    Returns ``(L, M_maps, summaries)``: L (H, W) bool (dynamic in any scan), the
    M map of every scan, and the SCAN_SUMMARY records. ``progress(scan, rows_done,
    H)`` is called after each chunk.
    """
    H, W = st.shape
    S = st.N.shape[0]
    record = bool(getattr(sink, "enabled", False))
    if chunk_rows is None:
        chunk_rows = max(1, H // 50) if record else max(8, H // 16)
    chunk_rows = max(1, min(int(chunk_rows), H))
    if probe is None:
        probe = np.zeros((H, W), np.bool_)
    pf, pi = pack_params(params, sift_unit=st.sift_unit, sample_rate=sample_static)
    bufs = _Buffers(chunk_rows, W, S, record)
    L = np.zeros((H, W), np.uint8)
    # the per-pixel part of g_h (Sec. 3.2.2), once; the kernel keeps the reference's
    # current after each write, so a patch's HoG is a sum, not 2·p² atan2
    nb = params.hog_bins
    hb_r, hm_r = kn._gradient_bins(st.gray, nb)
    hb_s = np.empty(st.src_gray.shape, np.int8)
    hm_s = np.empty(st.src_gray.shape, np.float64)
    for s in range(S):
        hb_s[s], hm_s[s] = kn._gradient_bins(st.src_gray[s], nb)
    M_maps: list[np.ndarray] = []
    summaries: list[np.ndarray] = []
    pipeline = kernel == "numba" and scan_on_all_cores(record)
    if kernel == "numba":
        def scan_fn(*state, scan, direction, r0, r1, stats):
            per_thread = np.zeros((numba.get_num_threads() if pipeline else 1, 3), np.int64)
            kn._scan(*state, pf, pi, scan, direction, r0, r1, record, pipeline, *bufs.args(),
                     per_thread)
            stats += per_thread.sum(0)
    elif kernel == "reference":
        # lazy on purpose: the reference scan needs sklearn.cluster (~1.5 s to import),
        # and only tests and bench use it. It reads Params by name, not pf/pi.
        from dynremove.method.scan import reference

        def scan_fn(*state, scan, direction, r0, r1, stats):
            reference.scan_rows(*state, params, scan, direction, r0, r1, record,
                                *bufs.args(), stats, sift_unit=st.sift_unit,
                                sample_rate=sample_static)
    else:
        raise ValueError(f"kernel must be 'numba' or 'reference', got {kernel!r}")
    for scan in range(params.max_scans):
        direction = 1 if scan % 2 == 0 else -1
        Mmap = np.full((H, W), np.nan, np.float32)
        Kmap = np.zeros((H, W, 4), np.int32)
        Bmap = np.zeros((H, W), np.float32)
        stats = np.zeros(3, np.int64)

        def state() -> ScanState:
            return ScanState(image=_readonly(st.img), dynamic=_readonly(L.astype(bool)),
                             M=_readonly(Mmap), N=_readonly(st.N), C=_readonly(st.C),
                             scan=scan, direction=direction, clusters=_readonly(Kmap),
                             b_m=_readonly(Bmap))

        t0 = time.perf_counter()
        # every decision from the scan's starting state, on all cores; the scan
        # then recomputes only what its own updates invalidate (exact). The pipeline
        # takes them too: its rows then cost what the movers cost, and the
        # precompute balances the static pixels' share perfectly (row by row;
        # the paper preset's 4 scans at 7 × 854×480 went from 2.7 to 1.9 s). Not
        # for the pipeline's first scan: it finds most of the movers, whose work
        # is the critical path, and the static pixels' decisions fit beside it on
        # the other core, while the precompute decides the movers' pixels twice
        # (the default's one scan at 7 × 854×480: 0.64 -> 0.58 s; every DAVIS set
        # as fast or faster, by up to 11 %; the paper's later scans, few movers
        # each, still gain: 0.37 -> 0.30 s). A scan on one thread (recorded)
        # always takes it.
        use_pre = kernel == "numba" and PRECOMPUTE and (scan > 0 or not pipeline)
        preM = np.empty((H, W), np.float64) if use_pre else np.empty((1, 1), np.float64)
        preB = np.empty((H, W), np.float64) if use_pre else np.empty((1, 1), np.float64)
        preK = np.empty((H, W, 4), np.int32) if use_pre else np.empty((1, 1, 4), np.int32)
        if use_pre:
            kn._decide_all(st.N, st.C, st.fc_r, st.fg_r, st.fc_s, st.fg_s, pf, pi, direction,
                           preM, preB, preK)
        dirty = np.zeros((H, W), np.uint8)
        if record:
            sink.scan_started(scan, direction, state())

        def summarise() -> np.ndarray:
            summary = np.zeros((), SCAN_SUMMARY_DTYPE)
            summary["scan"], summary["direction"] = scan, direction
            summary["n_dynamic"], summary["n_replaced"], summary["n_undecided"] = stats
            summary["seconds"] = time.perf_counter() - t0
            return summary

        visited = whole = False  # every row of this scan visited (known / certain)
        try:
            for r0 in range(0, H, chunk_rows):
                r1 = min(H, r0 + chunk_rows)
                # (a compiled call is not cut by a signal: a stop raised in it
                # surfaces once it has returned, its rows done)
                whole = r1 == H and kernel == "numba"
                scan_fn(st.img, st.lab, st.gray, st.fc_r, st.fg_r, st.src_img, st.src_lab,
                        st.src_gray, st.fc_s, st.fg_s, st.N, st.C, st.F, st.hasF, L, Mmap,
                        Kmap, Bmap, probe, hb_r, hm_r, hb_s, hm_s, use_pre, preM, preB, preK,
                        dirty, scan=scan, direction=direction,
                        r0=r0, r1=r1, stats=stats)
                visited = r1 == H
                if record:
                    base = scan * H * W
                    batch = bufs.take(scan, (r0, r1 - 1), (base + r0 * W, base + r1 * W))
                    sink.chunk(batch, state())
                if progress is not None and r1 < H:
                    progress(scan, r1, H)
        except BaseException as e:
            # a Ctrl-C (or SIGTERM) that lands once the scan has visited its last row,
            # while its last rows are being recorded: the scan is whole, so the
            # recording keeps its maps (a trial's Ctrl-C there lost them)
            if record and (visited or (whole and not isinstance(e, Exception))):
                try:
                    sink.scan_finished(summarise(), state())
                except Exception:  # noqa: BLE001 - the interruption is what is raised
                    pass
            raise
        summary = summarise()
        summaries.append(summary)
        M_maps.append(Mmap)
        if record:
            sink.scan_finished(summary, state())
        # the scan's end is told after its maps are recorded: a stop that the progress
        # callback raises there (the command line's) keeps the whole scan's maps
        if progress is not None:
            progress(scan, H, H)
        if stats[0] == 0:
            break
    return L.astype(bool), M_maps, summaries

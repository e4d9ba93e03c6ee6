"""Events: the contract between the algorithm core and any observer.

The compiled scan writes fixed-size records into preallocated buffers; the
driver turns them into the structured arrays below once per chunk of rows and
hands them to an :class:`EventSink` together with a read-only view of the state.
Events carry data, not drawing: colours and entity paths belong to the viewer.

``K = 2·(V−1)`` candidate slots per decision (two per source). Points are
``(x, y)``; arrays are indexed ``[y, x]``. ``step`` is a global visit counter:
``scan·H·W + index of the pixel in that scan's visiting order``. It is unique
per Decision and per Replacement; the CorrespondenceUpdates of one visit (one
per source) share their pixel's step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

# Reasons a decision was recorded (bit flags in Decision["why"]).
WHY_DYNAMIC = 1
WHY_PROBE = 2
WHY_SAMPLE = 4

# Update cases of Sec. 3.2.3 (CorrespondenceUpdate["case"]).
CASE_ONE_IN_CLUSTER = 1
CASE_BOTH_IN_CLUSTER = 2
CASE_GEOMETRY = 3


def decision_dtype(K: int) -> np.dtype:
    """Structured dtype of a Decision with ``K`` candidate slots.

    Fields: ``scan, step, x, y`` (int), ``M`` (float32, NaN when no cluster),
    ``dynamic`` (bool), ``why`` (uint8 flags), ``n_cand``, candidate arrays
    ``cand_src (K,) int8`` (−1 = empty slot), ``cand_xy (K, 2) int32`` (in the
    source), ``cand_B (K,) float32`` (neighbour confidence, entry of B),
    ``cand_cluster (K,) int16`` (DBSCAN label, −1 = noise), ``win_cluster``,
    ``win_weight`` (b_m), ``n_clusters``, ``consensus_dist`` (squared SIFT
    distance ‖f_g(x_r) − f̂_g‖² to the winning cluster's weighted mean f̂_g, the
    paper's consensus), ``chosen_src`` (−1 when static).
    """
    return np.dtype([
        ("scan", np.int32), ("step", np.int64), ("x", np.int32), ("y", np.int32),
        ("M", np.float32), ("dynamic", np.bool_), ("why", np.uint8),
        ("n_cand", np.int16),
        ("cand_src", np.int8, (K,)), ("cand_xy", np.int32, (K, 2)),
        ("cand_B", np.float32, (K,)), ("cand_cluster", np.int16, (K,)),
        ("win_cluster", np.int16), ("win_weight", np.float32),
        ("n_clusters", np.int16), ("consensus_dist", np.float32),
        ("chosen_src", np.int16),
    ])


REPLACEMENT_DTYPE = np.dtype([
    ("scan", np.int32), ("step", np.int64), ("x", np.int32), ("y", np.int32),
    ("src", np.int16), ("src_x", np.int32), ("src_y", np.int32),
    ("score", np.float32), ("tie_break", np.bool_), ("n_patches", np.int16),
])

CORRESPONDENCE_UPDATE_DTYPE = np.dtype([
    ("scan", np.int32), ("step", np.int64), ("x", np.int32), ("y", np.int32),
    ("src", np.int16), ("case", np.uint8), ("new_x", np.int32), ("new_y", np.int32),
    ("new_C", np.float32),
])

SCAN_SUMMARY_DTYPE = np.dtype([
    ("scan", np.int32), ("direction", np.int8), ("n_dynamic", np.int64),
    ("n_replaced", np.int64), ("n_undecided", np.int64), ("seconds", np.float64),
])


@dataclass(frozen=True)
class EventBatch:
    """Events of one chunk of rows of one scan (structured arrays, owned)."""

    scan: int
    rows: tuple[int, int]  # [first, last] row visited in this chunk, visiting order
    step_range: tuple[int, int]  # steps [first, last) covered by this chunk
    decisions: np.ndarray  # decision_dtype(K)
    replacements: np.ndarray  # REPLACEMENT_DTYPE
    updates: np.ndarray  # CORRESPONDENCE_UPDATE_DTYPE


@dataclass(frozen=True)
class ScanState:
    """Read-only view of the scan's state at a moment of the run.

    ``image``: (H, W, 3) uint8 BGR, the reference as currently rewritten;
    ``dynamic``: (H, W) bool, L (dynamic in any scan so far); ``M``: (H, W)
    float32 of the current scan (NaN where not visited yet or undecided);
    ``N``: (S, H, W, 2) int32 correspondences (x, y) per source; ``C``: (S, H, W)
    float32 similarity maps. Views are not writeable: copy what you keep.

    Per-pixel decision maps of the current scan (Sec. 3.2.1; zero where not
    visited yet): ``clusters`` (H, W, 4) int32 = |P| (candidates), k (DBSCAN
    clusters), |A_m| (size of the winning cluster) and a bitmask of the sources
    in A_m (bit s = source s); ``b_m`` (H, W) float32, the winning cluster's
    weight Σ_{l ∈ A_m} B_l (0 when undecided).
    """

    image: np.ndarray
    dynamic: np.ndarray
    M: np.ndarray
    N: np.ndarray
    C: np.ndarray
    scan: int
    direction: int  # +1: top-left → bottom-right, −1: bottom-right → top-left
    clusters: np.ndarray | None = None
    b_m: np.ndarray | None = None


@dataclass(frozen=True)
class RunInfo:
    """What is known before the scans start (logged once, statically)."""

    names: list[str]  # every input image name, reference included
    ref_index: int
    source_indices: list[int]  # indices into ``names`` of the sources, in order s=0..S-1
    images: list[np.ndarray]  # (H, W, 3) uint8 BGR, as processed (after resize)
    params: dict[str, Any]
    preset: str
    versions: dict[str, str]
    size: tuple[int, int]  # (H, W)
    N0: np.ndarray  # (S, H, W, 2) int32 initial correspondences
    C0: np.ndarray  # (S, H, W) float32 initial similarity
    coverage: np.ndarray  # (H, W) uint8: in how many sources the background was seen
    probes: list[tuple[int, int]] = field(default_factory=list)


@runtime_checkable
class EventSink(Protocol):
    """Observer of a run. ``enabled=False`` lets the kernel skip recording."""

    enabled: bool

    def start(self, info: RunInfo) -> None: ...

    def scan_started(self, scan: int, direction: int, state: ScanState) -> None: ...

    def chunk(self, events: EventBatch, state: ScanState) -> None: ...

    def scan_finished(self, summary: np.ndarray, state: ScanState) -> None: ...

    def finish(self, result: Any) -> None: ...


class NullSink:
    """Records nothing; the kernel runs with recording off (the default)."""

    enabled = False

    def start(self, info: RunInfo) -> None:
        pass

    def scan_started(self, scan: int, direction: int, state: ScanState) -> None:
        pass

    def chunk(self, events: EventBatch, state: ScanState) -> None:
        pass

    def scan_finished(self, summary: np.ndarray, state: ScanState) -> None:
        pass

    def finish(self, result: Any) -> None:
        pass


class MemorySink:
    """Keeps every event in memory (tests, notebooks).

    ``snapshots=True`` also keeps a copy of the reference image after every
    chunk (costly on big images).
    """

    enabled = True

    def __init__(self, *, snapshots: bool = False) -> None:
        self.info: RunInfo | None = None
        self.batches: list[EventBatch] = []
        self.summaries: list[np.ndarray] = []
        self.M_maps: list[np.ndarray] = []
        self.cluster_maps: list[np.ndarray] = []  # (H, W, 4) int32 per scan, see ScanState
        self.b_m_maps: list[np.ndarray] = []
        self.snapshots: list[np.ndarray] | None = [] if snapshots else None
        self.result: Any = None
        self.scans_started: list[tuple[int, int]] = []

    def start(self, info: RunInfo) -> None:
        self.info = info

    def scan_started(self, scan: int, direction: int, state: ScanState) -> None:
        self.scans_started.append((scan, direction))

    def chunk(self, events: EventBatch, state: ScanState) -> None:
        self.batches.append(events)
        if self.snapshots is not None:
            self.snapshots.append(state.image.copy())

    def scan_finished(self, summary: np.ndarray, state: ScanState) -> None:
        self.summaries.append(summary.copy())
        self.M_maps.append(state.M.copy())
        if state.clusters is not None:
            self.cluster_maps.append(state.clusters.copy())
            self.b_m_maps.append(state.b_m.copy())

    def finish(self, result: Any) -> None:
        self.result = result

    # -- convenience -----------------------------------------------------------
    def _cat(self, name: str) -> np.ndarray:
        arrays = [getattr(b, name) for b in self.batches]
        if not arrays:
            return np.zeros(0)
        return np.concatenate(arrays)

    @property
    def decisions(self) -> np.ndarray:
        return self._cat("decisions")

    @property
    def replacements(self) -> np.ndarray:
        return self._cat("replacements")

    @property
    def updates(self) -> np.ndarray:
        return self._cat("updates")


def replay_replacements(
    reference: npt.NDArray[np.uint8],
    sources: list[npt.NDArray[np.uint8]],
    replacements: np.ndarray,
    *,
    patch_size: int,
    write: str,
) -> npt.NDArray[np.uint8]:
    """Apply recorded Replacement events, in step order, to the input reference.

    This is the debugger's core promise: the events alone rebuild the output.
    ``sources[s]`` is the image of source ``s`` (the ``src`` field). A patch write
    copies the p×p window around ``(src_x, src_y)`` to the window around
    ``(x, y)``, clipped to both images, exactly as the kernel does.
    """
    out = reference.copy()
    H, W = out.shape[:2]
    h = patch_size // 2 if write == "patch" else 0
    order = np.argsort(replacements["step"], kind="stable")
    for ev in replacements[order]:
        src = sources[int(ev["src"])]
        Hs, Ws = src.shape[:2]
        x, y, sx, sy = int(ev["x"]), int(ev["y"]), int(ev["src_x"]), int(ev["src_y"])
        for dy in range(-h, h + 1):
            ry, qy = y + dy, sy + dy
            if not (0 <= ry < H and 0 <= qy < Hs):
                continue
            for dx in range(-h, h + 1):
                rx, qx = x + dx, sx + dx
                if 0 <= rx < W and 0 <= qx < Ws:
                    out[ry, rx] = src[qy, qx]
    return out

"""Read a dynremove recording back: raw events, pixel histories, failures.

Uses ``RrdReader(path).stream().collect()`` (works on files without a footer,
e.g. a killed run) and the dataframe API, with rows keyed by the unique
``step`` index (RERUN_NOTES.md §6). The raw events come from the lossless
``events/*`` columns the sink writes (one row per step, one list entry per
event), so they round-trip exactly to the structured dtypes of
``dynremove.events``. The words (verdict lines, the printed history and
failure list) are in :mod:`viewer.verdict`.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rerun.chunk import RrdReader

from dynremove import io
from dynremove.errors import InputError
from dynremove.events import (CORRESPONDENCE_UPDATE_DTYPE, REPLACEMENT_DTYPE,
                              WHY_DYNAMIC, WHY_PROBE, WHY_SAMPLE, decision_dtype)
from dynremove.refine.morphology import clean_mask_drops
from dynremove.refine.select import REASONS
from viewer import paths as P
from viewer._images import mask_sources, visit_step
from viewer.verdict import after_scan_message, more_scans

_KINDS = {"decisions": P.EVENTS_DECISIONS, "replacements": P.EVENTS_REPLACEMENTS,
          "updates": P.EVENTS_UPDATES}


# -- low level -----------------------------------------------------------------
@lru_cache(maxsize=4)
def _store_cached(path: str, mtime_ns: int, size: int):
    return read_rrd_tolerant(path)


def complete_messages(f, size: int) -> tuple[int, int]:
    """(bytes, count) of the complete messages at the start of an .rrd file of
    ``size`` bytes, open as ``f`` (a file or a ``BytesIO``): its framing only, the
    messages' headers read, nothing decoded. A recording cut short or damaged has
    bytes after them."""
    import struct

    pos = 12  # FourCC, version, options; then (kind u64, length u64, payload)*
    n = 0
    while pos + 16 <= size:
        f.seek(pos + 8)
        length = struct.unpack("<Q", f.read(8))[0]
        if pos + 16 + length > size:
            break
        pos, n = pos + 16 + length, n + 1
    return min(pos, size), n


def damage_note(path: str | Path) -> str | None:
    """What ``read_rrd_tolerant`` would say of a recording cut short or damaged (the
    bytes after its last complete message), from its framing alone (a recording may
    be GBs); None when the file ends with a complete message."""
    size = Path(path).stat().st_size
    with open(path, "rb") as f:
        f.seek(max(size - 12, 0))
        end = size - 32 if f.read(8) == b"RRF2FOOT" else size  # closed properly: a footer
        pos, _ = complete_messages(f, size)
    if pos >= end:
        return None
    # ("what it can read": a trial's file cut at 100 kB held 65 complete messages of
    # which `export` and `inspect` could read nothing, where this said the viewer
    # shows what was recorded)
    return (f"damaged or cut short after {pos} of {size} bytes: the viewer shows what it "
            "can read of the part before the damage ('dynremove inspect' on the file says "
            "whether any of it can be read)")


def read_rrd_tolerant(path: str):
    """Read a recording, or as much of a damaged one as can be read, with one note.

    A file without footer (interrupted run) or cut short (disk full, killed) is
    read up to the last complete message, and one line on stderr says so. A file
    that is not a recording, or holds no complete message, raises InputError.
    Rerun's own warnings are not shown.
    """
    from io import BytesIO
    import os
    import sys
    import tempfile
    import warnings

    from dynremove.errors import InputError

    def note(msg: str) -> None:
        print(f"dynremove: note: {path}: {msg}", file=sys.stderr)

    def has_scan(store) -> None:
        _not_foreign(store, path)
        if not any(scans_recorded(store, r) for r in runs_in(store) or [""]):
            raise InputError(f"{path}: recording cut before the first scan recorded "
                             "anything: nothing to inspect")

    with open(path, "rb") as f:
        data = f.read()
    if data[:4] != b"RRF2":
        raise InputError(f"{path}: not a Rerun recording (.rrd)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            store = RrdReader(path).stream().collect()
        except Exception:  # noqa: BLE001 - damaged: read the complete messages below
            store = None
        if store is not None:  # (the checks below raise InputError: not "damaged")
            _not_foreign(store, path)
            footer = any("footer" in str(w.message) for w in caught)
            if _interrupted_note(store, path, note):
                return store
            if footer:
                has_scan(store)
                note("no footer (the run was interrupted or the file cut): read what "
                     "was recorded")
            return store
        pos, n = complete_messages(BytesIO(data), len(data))
        if n < 2:
            raise InputError(f"{path}: damaged recording, nothing readable "
                             f"({len(data)} bytes)")
        fd, tmp = tempfile.mkstemp(suffix=".rrd")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data[:pos])
            store = RrdReader(tmp).stream().collect()
        except Exception:  # noqa: BLE001
            raise InputError(f"{path}: damaged recording, nothing readable") from None
        finally:
            os.unlink(tmp)
    if _interrupted_note(store, path, note):
        return store
    has_scan(store)
    note(f"damaged or cut short after {pos} of {len(data)} bytes: read the "
         f"{n} complete messages before the damage")
    return store


def _not_foreign(store, path) -> None:
    """InputError where ``store`` holds no dynremove run (no ``run/info`` nor
    ``run/interrupted`` under any root) and its application id is not dynremove's:
    another tool's recording (a trial's was called "cut before the first scan")."""
    from dynremove.errors import InputError

    if runs_in(store):
        return
    try:
        apps = sorted({r.application_id for r in RrdReader(str(path)).recordings()})
    except Exception:  # noqa: BLE001 - no footer or manifest: the content decides alone
        apps = []
    if apps and "dynremove" not in apps:
        raise InputError(f"{path}: not a dynremove recording (a Rerun recording of "
                         f"application {', '.join(apps)}): 'dynremove inspect' and "
                         "'export' read recordings of 'dynremove run --record'")


def runs_in(store) -> list[str]:
    """The roots of the runs a recording holds: ``[""]`` for a plain run,
    ``["runs/main", "runs/compare"]`` for ``run --compare`` (each run logs
    ``<root>/run/info``, or at least ``<root>/run/interrupted``); a root named
    ``main`` first, the others sorted."""
    roots = set()
    for ent in store.schema().entity_paths():
        ent = "/" + str(ent).strip("/")
        for leaf in (P.RUN_INFO, P.RUN_INTERRUPTED):
            if ent.endswith("/" + leaf):
                roots.add(ent[:-len(leaf) - 1].strip("/"))
    return sorted(roots, key=lambda r: (r.rsplit("/", 1)[-1] != "main", r))


# Entities only a scan writes: its chunks (the scan line), its events, its maps.
_SCAN_ENTITIES = (P.REFERENCE_SCANLINE, P.EVENTS_DECISIONS, P.EVENTS_REPLACEMENTS,
                  P.EVENTS_UPDATES, P.scan_map("M"))


def scans_recorded(store, root: str = "") -> bool:
    """Whether the run under ``root`` recorded anything of a scan (a chunk of one:
    the scan line, events, or a scan's maps). The snapshot that ``start`` logs at
    step 0, before the scans, does not count: a run interrupted between ``start``
    and the first scan has nothing to inspect, however it was stopped."""
    p = P.Paths(root)
    want = {p(e) for e in _SCAN_ENTITIES}
    return any("/" + str(e).strip("/") in want for e in store.schema().entity_paths())


def _interruption_values(store, root: str = "") -> dict[str, Any]:
    """The ``run/interrupted`` values (message, scan, step, scans_began). A run that
    older sinks said was "interrupted at scan S, step N" although scan S had
    finished (its summary, ``stats/n_dynamic``, is recorded: the refinement or the
    fill was running) gets the message today's sink logs for it."""
    p = P.Paths(root)
    vals = {k: v[0] for k, v in _static_values(store, p(P.RUN_INTERRUPTED)).items() if v}
    msg = str(vals.get("message") or "")
    if vals.get("scans_began") and msg.startswith("interrupted at scan "):
        scan = int(vals.get("scan", 0))
        n_dyn = _scan_summary(store, root, scan)
        if n_dyn is not None:
            params = _static_values(store, p(P.RUN_INFO)).get("params")
            params = json.loads(params[0]) if params else {}
            vals["message"] = after_scan_message(scan, more_scans(scan, n_dyn, params))
    return vals


def _scan_summary(store, root: str, scan: int) -> float | None:
    """n_dynamic of scan ``scan``'s summary (logged when the scan finished), or None."""
    entity = P.Paths(root)(P.stat("n_dynamic"))
    t = _arrow(store, entity, index="scan")
    col = None if t is None else _column(t, f"{entity}:Scalars:scalars")
    if col is None:
        return None
    for s, v in zip(t.column("scan").to_pylist(), col.to_pylist()):
        if s == scan and v:
            return float(v[0])
    return None


def interruption(store, root: str | None = None) -> str | None:
    """"interrupted at scan S, step N" (or "... before the scans began", "... after
    the scans") when the recording is of an interrupted run (``RerunSink.interrupted``), else None.
    ``root`` None: the first interrupted run of the recording, whatever its root."""
    for r in runs_in(store) if root is None else [root.strip("/")]:
        msg = _interruption_values(store, r).get("message")
        if msg:
            return str(msg)
    return None


def _interrupted_note(store, path: str, note) -> bool:
    """One note per interrupted run saying where it ends; InputError when nothing of
    a scan was recorded (decided on what the recording holds, not on how it ended).
    False: no interrupted run."""
    roots = runs_in(store)
    cut = [(r, m) for r in roots if (m := interruption(store, r))]
    if not cut:
        return False
    if not any(scans_recorded(store, r) for r in roots):
        raise InputError(f"{path}: the run was {cut[0][1]}: nothing to inspect")
    for r, msg in cut:
        run = f"the run under {r}" if r else "the run"
        note(f"{run} was {msg}: " + ("read what was recorded" if scans_recorded(store, r)
                                     else "nothing to inspect there"))
    return True


def _some_runs(roots: list[str]) -> str:
    names = [r or "the top level (no --root)" for r in roots]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def resolve_root(path: str | Path, root: str = "") -> str:
    """The root of the run to read, checked against the runs the recording holds.

    ``root`` as given (``runs/main``, ``/runs/main/``), or its last part when that
    names one run (``main``); empty: the recording's only run. A ``--compare``
    recording holds two runs (``runs/main``, ``runs/compare``): without ``root``
    it raises InputError naming them, as it does for a root it does not hold.
    """
    roots = runs_in(load_store(path))
    want = root.strip("/")
    if not roots or want in roots:
        return want
    if not want:
        if len(roots) == 1:
            return roots[0]
        n = {2: "two", 3: "three"}.get(len(roots), str(len(roots)))
        raise InputError(f"{path} holds {n} runs, {_some_runs(roots)}: pass "
                         + " or ".join(f"--root {r}" for r in roots))
    tail = [r for r in roots if r.rsplit("/", 1)[-1] == want]
    if len(tail) == 1:
        return tail[0]
    raise InputError(f"no run under --root {root}; {path} holds: " + ", ".join(
        r or "one run at the top level (no --root)" for r in roots)
        + (f" (pass --root {roots[0]})" if len(roots) == 1 and roots[0] else ""))


def check_scans(path: str | Path, root: str = "") -> None:
    """InputError "nothing to inspect" when the run under ``root`` recorded no scan."""
    store = load_store(path)
    if scans_recorded(store, root):
        return
    msg = interruption(store, root)
    run = f"the run under {root}" if root else "the run"
    raise InputError(f"{path}: {run} was {msg}: nothing to inspect" if msg else
                     f"{path}: {run} recorded no scan (cut before the first one): "
                     "nothing to inspect")


def load_store(path: str | Path):
    """The recording as an in-memory ChunkStore (cached per file version)."""
    st = Path(path).stat()
    return _store_cached(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


def _arrow(store, entity: str, *, index: str | None = "step"):
    try:
        t = store.reader(index=index, contents=entity).to_arrow_table()
    except ImportError as e:
        # a missing package is not a missing entity (a trial without datafusion was
        # told its intact recording had been cut short)
        raise InputError(f"reading recordings needs {e.name or 'a package'}, which is not "
                         "installed: pip install 'rerun-sdk[catalog]==0.41.*'") from None
    except Exception:  # entity absent from this recording
        return None
    if index is not None and t.num_rows:
        t = t.sort_by(index)
    return t


def _column(t, name: str):
    return t.column(name).combine_chunks() if name in t.column_names else None


def _static_values(store, entity: str) -> dict[str, Any]:
    """Static AnyValues of ``entity`` as {name: list}."""
    t = _arrow(store, entity, index=None)
    out: dict[str, Any] = {}
    if t is None or t.num_rows == 0:
        return out
    prefix = entity + ":"
    for name in t.column_names:
        if name.startswith(prefix) and name.count(":") == 1:
            v = t.column(name)[0].as_py()
            if v is not None:
                out[name[len(prefix):]] = v
    return out


# rerun's ChannelDatatype enum values (0.41) → numpy dtypes
_CHANNEL_DTYPES = {6: np.uint8, 7: np.int8, 8: np.uint16, 9: np.int16, 10: np.uint32,
                   11: np.int32, 12: np.uint64, 13: np.int64, 33: np.float16,
                   34: np.float32, 35: np.float64}


def _image_rows(store, entity: str, archetype: str, *, index: str | None = "step"):
    """[(step | None, ndarray)] of a raw image entity (SegmentationImage, Image,
    DepthImage), the buffer viewed as its channel datatype (uint8 when unset);
    (H, W) or (H, W, C) by the buffer's size."""
    t = _arrow(store, entity, index=index)
    if t is None or t.num_rows == 0:
        return []
    buf = _column(t, f"{entity}:{archetype}:buffer")
    fmt = _column(t, f"{entity}:{archetype}:format")
    if buf is None or fmt is None:
        return []
    steps = t.column(index).to_pylist() if index else [None] * t.num_rows
    out = []
    for i in range(t.num_rows):
        if not buf[i].is_valid or not fmt[i].is_valid:
            continue
        f = fmt[i].as_py()[0]
        raw = buf[i].values[0].values.to_numpy(zero_copy_only=False)
        dtype = _CHANNEL_DTYPES.get(f.get("channel_datatype") or 6, np.uint8)
        data = np.frombuffer(raw.tobytes(), dtype)
        shape = (f["height"], f["width"])
        if data.size != shape[0] * shape[1]:
            shape = shape + (data.size // (shape[0] * shape[1]),)
        out.append((steps[i], data.reshape(shape).copy()))
    return out


def _blob_rows(store, entity: str, *, index: str | None = "step"):
    """[(step | None, bytes)] of an EncodedImage entity."""
    t = _arrow(store, entity, index=index)
    if t is None or t.num_rows == 0:
        return []
    blob = _column(t, f"{entity}:EncodedImage:blob")
    if blob is None:
        return []
    steps = t.column(index).to_pylist() if index else [None] * t.num_rows
    return [(steps[i], blob[i].values[0].values.to_numpy(zero_copy_only=False).tobytes())
            for i in range(t.num_rows) if blob[i].is_valid]


def decode(data: bytes) -> np.ndarray:
    """Decode JPEG/PNG bytes to an (H, W, 3) BGR array."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError("could not decode image blob")
    return img


# -- public readers --------------------------------------------------------------
def read_run_info(path: str | Path, *, root: str = "") -> dict[str, Any]:
    """Static run description: K, height, width, names, source_names, params…"""
    store = load_store(path)
    info = _static_values(store, P.Paths(root)(P.RUN_INFO))
    out: dict[str, Any] = {}
    for k, v in info.items():
        if k in ("names", "source_names", "source_indices"):
            out[k] = list(v)
        elif k in ("versions", "params", "probes"):
            out[k] = json.loads(v[0])
        else:
            out[k] = v[0] if len(v) == 1 else list(v)
    return out


def read_events(path: str | Path, kind: str, *, root: str = "") -> np.ndarray:
    """All events of ``kind`` ("decisions", "replacements", "updates"), in step order.

    Returns the structured dtype of ``dynremove.events`` (decisions:
    ``decision_dtype(K)`` with K from the run info).
    """
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {sorted(_KINDS)}, got {kind!r}")
    K = None
    if kind == "decisions":
        K = read_run_info(path, root=root).get("K")
        dtype = decision_dtype(0 if K is None else int(K))
    elif kind == "replacements":
        dtype = REPLACEMENT_DTYPE
    else:
        dtype = CORRESPONDENCE_UPDATE_DTYPE
    entity = P.Paths(root)(_KINDS[kind])
    t = _arrow(load_store(path), entity)
    first = None if t is None else _column(t, f"{entity}:{dtype.names[0]}")
    if first is None:
        return np.zeros(0, dtype)
    n = len(first.flatten())
    if kind == "decisions" and K is None and n:
        # a recording cut short before the run info's K: the candidate slots per row
        slots = _column(t, f"{entity}:cand_src")
        dtype = decision_dtype(0 if slots is None else len(slots.flatten()) // n)
    out = np.zeros(n, dtype)
    for name in dtype.names:
        col = _column(t, f"{entity}:{name}")
        flat = col.flatten().to_numpy(zero_copy_only=False)
        out[name] = flat.reshape((n,) + dtype[name].shape)
    return out


def read_replacements(path: str | Path, *, root: str = "") -> np.ndarray:
    """Every Replacement of the run (REPLACEMENT_DTYPE), in step order."""
    return read_events(path, "replacements", root=root)


def read_counts(path: str | Path, *, root: str = "") -> dict[int, dict[str, int]]:
    """{scan: {"decisions": n, "replacements": n, "updates": n}}."""
    out: dict[int, dict[str, int]] = {}
    for kind in _KINDS:
        ev = read_events(path, kind, root=root)
        scans, counts = np.unique(ev["scan"], return_counts=True)
        for s, c in zip(scans.tolist(), counts.tolist()):
            out.setdefault(s, dict.fromkeys(_KINDS, 0))[kind] = c
    return dict(sorted(out.items()))


def read_final_image(path: str | Path, *, root: str = "", scan: bool = False
                     ) -> np.ndarray | None:
    """The lossless final clean image (BGR), or None (run not finished).

    ``scan=True``: the image as the scans left it, before the default preset's
    fusion (what the Replacement events rebuild); falls back to the final one.
    """
    store = load_store(path)
    rows = _blob_rows(store, P.Paths(root)(P.RESULT_CLEAN_SCAN), index=None) if scan else []
    rows = rows or _blob_rows(store, P.Paths(root)(P.RESULT_CLEAN), index=None)
    return decode(rows[0][1]) if rows else None


def read_input_reference(path: str | Path, *, root: str = "") -> np.ndarray | None:
    """The reference as the run was given it (BGR; the recording's JPEG), or None."""
    rows = _blob_rows(load_store(path), P.Paths(root)(P.REFERENCE_INPUT), index=None)
    return decode(rows[0][1]) if rows else None


def clean_and_input(path: str | Path, x: int, y: int, *, root: str = ""
                    ) -> tuple[list[int], list[int]] | None:
    """The clean photo's and the input reference's B, G, R at analysis pixel (x, y)
    (the input as the recording's JPEG holds it, so within a few levels), or None
    where the recording lacks either image."""
    out, ref = read_final_image(path, root=root), read_input_reference(path, root=root)
    if out is None or ref is None or out.shape[:2] != ref.shape[:2] or out.ndim != 3 \
            or ref.ndim != 3:
        return None
    return [int(c) for c in out[y, x, :3]], [int(c) for c in ref[y, x, :3]]


def read_final_dynamic(path: str | Path, *, root: str = "") -> np.ndarray | None:
    """Final L as an (H, W) bool array, or None (run not finished)."""
    rows = _image_rows(load_store(path), P.Paths(root)(P.RESULT_DYNAMIC),
                       "SegmentationImage", index=None)
    return rows[0][1].astype(bool) if rows else None


STAGE_ORDER = ("scan", "clean", "votes", "snap", "select")  # pipeline.remove_dynamic's order


def read_stages(path: str | Path, *, root: str = "") -> dict[str, np.ndarray]:
    """L after each post-scan step ({"scan": ..., "clean": ..., ...}), in run order."""
    store, p = load_store(path), P.Paths(root)
    out = {}
    for name in STAGE_ORDER:
        rows = _image_rows(store, p(f"{P.RESULT_STAGES}/{name}"), "SegmentationImage",
                           index=None)
        if rows:
            out[name] = rows[0][1].astype(bool)
    return out


def read_gt_mask(path: str | Path, *, root: str = "") -> np.ndarray | None:
    """Ground-truth mask logged with the run, or None."""
    rows = _image_rows(load_store(path), P.Paths(root)(P.GT_MASK), "SegmentationImage",
                       index=None)
    return rows[0][1].astype(bool) if rows else None


def read_snapshots(path: str | Path, *, root: str = "") -> dict[str, list]:
    """Time-stamped snapshots: {"image": [(step, jpeg bytes)], "dynamic": [(step, L)],
    "M": [(step, jpeg bytes)]} in step order."""
    store, p = load_store(path), P.Paths(root)
    return {"image": _blob_rows(store, p(P.REFERENCE_IMAGE)),
            "dynamic": [(s, a.astype(bool)) for s, a in
                        _image_rows(store, p(P.REFERENCE_DYNAMIC), "SegmentationImage")],
            "M": _blob_rows(store, p(P.REFERENCE_M))}


def read_scan_maps(path: str | Path, *, root: str = "") -> list[dict[str, Any]]:
    """The per-scan maps the sink records at each scan's last step, in scan order.

    Each entry: ``scan``, ``step`` (the scan's last step), ``direction``, ``M``
    (H, W) float32 (NaN = undecided), ``verdict`` (0 not visited, 1 static,
    2 dynamic, 3 undecided), ``chosen_source`` (−1 = no patch written, else the
    source), ``overwritten_before`` (patches centred elsewhere that overwrote the
    pixel before the scan reached it) and ``first_overwritten`` (global step of
    the first of them, −1 = none). Empty for recordings made before these maps.

    The core's decision maps (Sec. 3.2.1), None in recordings made before them:
    ``n_candidates`` |P|, ``n_clusters`` k, ``win_size`` |A_m| (uint8),
    ``win_sources`` (bitmask of the sources in A_m, bit s = source s of the run
    info's ``source_names``) and ``b_m`` (float32, Σ B_l over A_m; 0 = none).
    """
    store, p = load_store(path), P.Paths(root)
    m_rows = _image_rows(store, p(P.scan_map("M")), "DepthImage")
    if not m_rows:
        return []
    ent = p(P.scan_map("M"))
    t = _arrow(store, ent)
    scans = _column(t, f"{ent}:scan")
    dirs = _column(t, f"{ent}:direction")
    by_step = {k: dict(_image_rows(store, p(P.scan_map(k)), arch))
               for k, arch in (("verdict", "SegmentationImage"),
                               ("chosen_source", "SegmentationImage"),
                               ("overwritten_before", "DepthImage"),
                               ("first_overwritten", "DepthImage"),
                               ("n_candidates", "SegmentationImage"),
                               ("n_clusters", "SegmentationImage"),
                               ("win_size", "SegmentationImage"),
                               ("win_sources", "SegmentationImage"),
                               ("b_m", "DepthImage"))}
    out = []
    for i, (step, Mq) in enumerate(m_rows):
        scan = int(scans[i].as_py()[0]) if scans is not None else i
        H, W = Mq.shape
        M = np.where(Mq == P.M_UNDECIDED, np.nan, Mq.astype(np.float32) / P.M_SCALE)
        first = by_step["first_overwritten"].get(step)
        out.append(dict(
            scan=scan, step=int(step),
            direction=int(dirs[i].as_py()[0]) if dirs is not None else
            (1 if scan % 2 == 0 else -1),
            M=M.astype(np.float32), verdict=by_step["verdict"].get(step),
            chosen_source=(by_step["chosen_source"][step].astype(np.int32) - 1
                           if step in by_step["chosen_source"] else None),
            overwritten_before=by_step["overwritten_before"].get(step),
            first_overwritten=(np.where(first > 0, first.astype(np.int64) - 1
                                        + scan * H * W, -1) if first is not None else None),
            **{k: by_step[k].get(step) for k in P.CLUSTER_MAP_NAMES}))
    return out


def read_selection(path: str | Path, *, root: str = "") -> dict[str, np.ndarray]:
    """The fill by selection's maps: ``source`` (0 = reference kept, k = source k−1),
    ``explained`` (L kept as static 3-D structure), ``seams``, ``lingering`` (a mover
    that most photos show, found by two or more sources that saw the background),
    ``completed`` (1: kept by the graph cut, replaced because its region of L was
    replaced almost whole; 2: the reverse; 3: kept, as its region's fill did not fit the
    photo around it, ``select.misfit_regions``; 4: kept whole with a mover replaced only
    in part, ``select.partial_movers``), ``region_share`` (uint16: the share of
    the pixel's region of L the graph cut replaced × P_SCALE, DE_NONE outside; with
    ``region_rule``, the run's --select-complete and --select-complete-px),
    ``line_de``, ``line_x``, ``line_y`` (per source, uint16: the epipolar search's
    best ΔE × DE_SCALE and where it lies in the source × XY_SCALE, DE_NONE where not
    searched), ``data_cost`` and ``support`` (dicts of uint16 maps × DE_SCALE: what the graph
    cut weighed, ``Selection.data_cost`` and ``Selection.support``),
    ``inpainted`` (no source free there: OpenCV Telea), ``planes`` (the field across L
    each pixel was sampled through: 1 the membrane, 1 + k plane k of the ring around its
    region, 0 outside the hole; ``paths.RESULT_PLANES``), ``relit`` and ``relight_l`` (a
    faint shade beside the movers relit to the other photos' light, and the L* it
    gained × DE_SCALE, DE_NONE elsewhere: ``shade.relight_shade``), ``followed`` (per source, in
    its own frame: where the flow followed the reference's mover into it), ``offset``
    ((H, W, 3) int16, B/G/R levels the blend added to the chosen source, 0 where it
    added none or no source filled; ``paths.RESULT_OFFSET``), ``seam_blend`` (the same, the
    part that blended the steps of light at the seams between sources;
    ``paths.RESULT_SEAM_BLEND``), ``fill_x``, ``fill_y``
    (uint16, where the chosen source was sampled, in its pixels × XY_SCALE, DE_NONE
    where no source filled; ``paths.RESULT_FILL_MATCH``); absent
    keys when the run had no selection step (or, for ``inpainted``, was recorded
    before it was logged)."""
    store, p = load_store(path), P.Paths(root)
    out = {}
    for key, rel in (("source", P.RESULT_SOURCE), ("explained", P.RESULT_EXPLAINED),
                     ("seams", P.RESULT_SEAMS), ("lingering", P.RESULT_LINGERING),
                     ("completed", P.RESULT_COMPLETED), ("inpainted", P.RESULT_INPAINTED),
                     ("relit", P.RESULT_RELIT), ("planes", P.RESULT_PLANES)):
        rows = _image_rows(store, p(rel), "SegmentationImage", index=None)
        if rows:
            out[key] = rows[0][1]
    entities = sorted(str(e).strip("/") for e in store.schema().entity_paths())
    # per source: <rel>/<source>, or sources/<source>/<leaf>
    for key, head, tail, arch in (
            ("reasons", p(P.RESULT_REASONS), "", "SegmentationImage"),
            ("evidence", p(P.RESULT_EVIDENCE), "", "SegmentationImage"),
            ("line_de", p(P.RESULT_LINE_DE), "", "DepthImage"),
            ("line_x", p(P.RESULT_LINE_MATCH), "/x", "DepthImage"),
            ("line_y", p(P.RESULT_LINE_MATCH), "/y", "DepthImage"),
            ("followed", p(P.SOURCES), "/" + P.FOLLOWED_MOVER, "SegmentationImage")):
        per_source = {}
        prefix = head.strip("/") + "/"
        for ent in entities:
            name = ent[len(prefix):len(ent) - len(tail)]
            if ent.startswith(prefix) and ent.endswith(tail) and name and "/" not in name:
                rows = _image_rows(store, "/" + ent, arch, index=None)
                if rows:
                    per_source[name] = rows[0][1]
        if per_source:
            out[key] = per_source
    if "followed" in out:
        out["followed"] = {n: a.astype(bool) for n, a in out["followed"].items()}
    rows = _image_rows(store, p(P.RESULT_STATIC_NEED), "SegmentationImage", index=None)
    if rows:
        out["static_need"] = rows[0][1]
        out["thresholds"] = _static_values(store, p(P.RESULT_STATIC_NEED))
    rows = _image_rows(store, p(P.RESULT_REF_MOVER_P), "DepthImage", index=None)
    if rows:
        out["ref_mover_p"] = rows[0][1]
    rows = _image_rows(store, p(P.RESULT_RELIGHT_L), "DepthImage", index=None)
    if rows:
        out["relight_l"] = rows[0][1]
    for key, rel, names in (("data_cost", P.RESULT_DATA_COST, ("reference", "best_source")),
                            ("support", P.RESULT_SUPPORT, ("reference", "sources"))):
        got = {n: rows[0][1] for n in names
               if (rows := _image_rows(store, p(f"{rel}/{n}"), "DepthImage", index=None))}
        if got:
            out[key] = got
    rows = _image_rows(store, p(P.RESULT_REGION_SHARE), "DepthImage", index=None)
    if rows:
        out["region_share"] = rows[0][1]
        out["region_rule"] = _static_values(store, p(P.RESULT_REGION_SHARE))
    for axis in "xy":
        rows = _image_rows(store, p(f"{P.RESULT_FILL_MATCH}/{axis}"), "DepthImage", index=None)
        if rows:
            out[f"fill_{axis}"] = rows[0][1]
    for key, path in (("offset", P.RESULT_OFFSET), ("seam_blend", P.RESULT_SEAM_BLEND)):
        rows = _image_rows(store, p(path), "Image", index=None)
        if rows and rows[0][1].ndim == 3:
            out[key] = rows[0][1][..., ::-1].astype(np.int16) - P.OFFSET_ZERO  # RGB -> BGR
    return out


# -- pixel history -----------------------------------------------------------------
def _why_names(why: int) -> list[str]:
    return [n for bit, n in ((WHY_DYNAMIC, "dynamic"), (WHY_PROBE, "probe"),
                             (WHY_SAMPLE, "sample")) if why & bit]


def m_terms(M: float, dg: float, params: dict[str, Any]
            ) -> tuple[float, float, float, float] | None:
    """M's two terms (Sec. 3.2.1) and their weights: (λ4 S_e(‖f_c − f̂_c‖², σ_c),
    λ5 S_e(‖f_g − f̂_g‖², σ_g), λ4, λ5), the SIFT term from the recorded squared
    SIFT distance ``dg``, the colour term as M minus it; λ4 = λ1 / (λ1 + λ2), λ5 =
    λ2 / (λ1 + λ2). None without the parameters or a finite M and dg."""
    try:
        l1, l2, sg = (float(params[k]) for k in ("lambda1", "lambda2", "sigma_g"))
    except (KeyError, TypeError, ValueError):
        return None
    if not (M == M and dg == dg) or l1 + l2 <= 0 or sg <= 0:
        return None
    lam4, lam5 = l1 / (l1 + l2), l2 / (l1 + l2)
    sift = lam5 * float(np.exp(-dg / (2.0 * sg * sg)))
    return max(M - sift, 0.0), sift, lam4, lam5


def _decision_dict(d: np.void, t_r: float, names: list[str],
                   params: dict[str, Any] | None = None) -> dict[str, Any]:
    cands = []
    for k in range(len(d["cand_src"])):
        s = int(d["cand_src"][k])
        if s < 0:
            continue
        cands.append(dict(slot=k, src=s, src_name=names[s] if s < len(names) else f"source {s}",
                          x=int(d["cand_xy"][k, 0]), y=int(d["cand_xy"][k, 1]),
                          B=float(d["cand_B"][k]), cluster=int(d["cand_cluster"][k])))
    clusters: dict[int, dict[str, float]] = {}
    for c in cands:
        e = clusters.setdefault(c["cluster"], {"n": 0, "sum_B": 0.0})
        e["n"] += 1
        e["sum_B"] += c["B"]
    return dict(scan=int(d["scan"]), step=int(d["step"]), M=float(d["M"]), t_r=t_r,
                dynamic=bool(d["dynamic"]), why=_why_names(int(d["why"])),
                n_cand=int(d["n_cand"]), n_clusters=int(d["n_clusters"]),
                win_cluster=int(d["win_cluster"]), win_weight=float(d["win_weight"]),
                consensus_dist=float(d["consensus_dist"]),
                m_terms=m_terms(float(d["M"]), float(d["consensus_dist"]), params or {}),
                chosen_src=int(d["chosen_src"]), candidates=cands,
                clusters=dict(sorted(clusters.items())))


def _cluster_at(m: dict[str, Any], x: int, y: int, names: list[str]) -> dict[str, Any]:
    """The decision maps of one scan at (x, y): |P|, k, |A_m|, A_m's sources, b_m
    (each None when the recording has no such map)."""
    def at(k):
        a = m.get(k)
        return None if a is None else a[y, x]

    n, k, w, bits, bm = (at(k) for k in P.CLUSTER_MAP_NAMES)
    return dict(n_candidates=None if n is None else int(n),
                n_clusters=None if k is None else int(k),
                win_size=None if w is None else int(w),
                win_sources=None if bits is None else mask_sources(int(bits), names),
                b_m=None if bm is None else float(bm))


def pixel_history(path: str | Path, x: int, y: int, *, root: str = "") -> dict[str, Any]:
    """Everything the recording knows about reference pixel ``(x, y)``.

    Returns
    -------
    dict with ``x, y``, ``decisions`` (every recorded decision at the pixel with
    its candidates and clusters), ``replacements`` (written at the pixel),
    ``covered_by`` (patch writes centred elsewhere that overwrote it), ``updates``
    (correspondence updates at the pixel), ``final_dynamic`` and ``gt`` (bool or
    None), plus ``source_names``. Only decisions the core recorded are present:
    dynamic ones, probes (``--probe``) and sampled static ones. ``scans`` holds,
    for every scan and every pixel, what the per-scan maps say: ``M``,
    ``verdict``, ``overwritten_before``…, and the winning cluster's
    ``n_candidates`` |P|, ``n_clusters`` k, ``win_size`` |A_m|, ``win_sources``
    (source names) and ``b_m`` (None in recordings made before these maps).
    """
    root = resolve_root(path, root)
    info = read_run_info(path, root=root)
    H, W = int(info.get("height", 0) or 0), int(info.get("width", 0) or 0)
    if H and W and not (0 <= x < W and 0 <= y < H):
        raise InputError(outside_message(info, x, y))
    check_scans(path, root)
    names = info.get("source_names", [])
    params = info.get("params", {})
    t_r = float(params.get("t_r", np.nan))
    p = int(params.get("patch_size", 1)) if params.get("write", "patch") == "patch" else 1
    h = p // 2
    dec = read_events(path, "decisions", root=root)
    rep = read_events(path, "replacements", root=root)
    upd = read_events(path, "updates", root=root)
    at = (dec["x"] == x) & (dec["y"] == y)
    here = (rep["x"] == x) & (rep["y"] == y)
    cover = (np.abs(rep["x"] - x) <= h) & (np.abs(rep["y"] - y) <= h) & ~here
    L = read_final_dynamic(path, root=root)
    gt = read_gt_mask(path, root=root)
    if not (H and W) and L is not None:
        H, W = L.shape
    # the per-scan maps and the selection are read for an interrupted run too
    inside = 0 <= y < H and 0 <= x < W
    stage_maps = read_stages(path, root=root) if inside else {}
    stages = {k: bool(v[y, x]) for k, v in stage_maps.items()}
    clean_rule = None
    if stages.get("scan") and stages.get("clean") is False:
        # which step of the clean-up dropped it, replayed on the scans' map
        why = int(clean_mask_drops(stage_maps["scan"], int(params.get("patch_size", 1)),
                                   int(params.get("min_region_px", 0)))[y, x])
        clean_rule = {1: "opening", 2: "small"}.get(why)

    def rep_dict(r: np.void) -> dict[str, Any]:
        s = int(r["src"])
        return dict(scan=int(r["scan"]), step=int(r["step"]), x=int(r["x"]), y=int(r["y"]),
                    src=s, src_name=names[s] if 0 <= s < len(names) else f"source {s}",
                    src_x=int(r["src_x"]), src_y=int(r["src_y"]), score=float(r["score"]),
                    tie_break=bool(r["tie_break"]), n_patches=int(r["n_patches"]))

    scans = []
    for m in read_scan_maps(path, root=root) if inside else []:
        def at_(a):
            return None if a is None else a[y, x]
        v = at_(m["verdict"])
        scans.append(dict(
            scan=m["scan"], step=visit_step(m["scan"], x, y, H, W, direction=m["direction"]),
            direction=m["direction"], M=float(m["M"][y, x]),
            verdict={0: "not visited", 1: "static", 2: "dynamic",
                     3: "undecided"}.get(int(v), "?") if v is not None else "?",
            chosen_source=None if m["chosen_source"] is None else int(m["chosen_source"][y, x]),
            overwritten_before=None if m["overwritten_before"] is None
            else int(m["overwritten_before"][y, x]),
            first_overwritten=None if m["first_overwritten"] is None
            else int(m["first_overwritten"][y, x]),
            **_cluster_at(m, x, y, names)))
    sel = {}
    for k, v in (read_selection(path, root=root).items() if inside else ()):
        if k == "reasons":  # per source: why it did or did not fill this pixel
            sel[k] = {n: REASONS.get(int(a[y, x]), "?") for n, a in v.items()
                      if int(a[y, x]) > 0}
        elif k == "evidence":  # per source: EVIDENCE code of the static 3-D test (in L)
            sel[k] = {n: int(a[y, x]) for n, a in v.items() if int(a[y, x]) > 0}
        elif k == "line_de":  # per source: the best ΔE on its epipolar line
            sel[k] = {n: float(a[y, x]) / P.DE_SCALE for n, a in v.items()
                      if int(a[y, x]) != P.DE_NONE}
        elif k in ("line_x", "line_y"):  # per source: where on the line (source px)
            sel[k] = {n: float(a[y, x]) / P.XY_SCALE for n, a in v.items()
                      if int(a[y, x]) != P.DE_NONE}
        elif k == "followed":  # in the sources' frames: told at (x, y) by the reasons
            continue
        elif k in ("data_cost", "support"):  # {name: ΔE or support} where defined
            sel[k] = {n: float(a[y, x]) / P.DE_SCALE for n, a in v.items()
                      if int(a[y, x]) != P.DE_NONE}
        elif k in ("ref_mover_p", "region_share"):
            sel[k] = None if int(v[y, x]) == P.DE_NONE else float(v[y, x]) / P.P_SCALE
        elif k in ("thresholds", "region_rule"):
            sel[k] = {n: (a[0] if isinstance(a, list) and a else a) for n, a in v.items()}
        elif k == "relight_l":  # the CIE L* the relit shade gained here
            sel[k] = None if int(v[y, x]) == P.DE_NONE else float(v[y, x]) / P.DE_SCALE
        elif k in ("fill_x", "fill_y"):  # where the chosen source was sampled
            sel[k] = None if int(v[y, x]) == P.DE_NONE else float(v[y, x]) / P.XY_SCALE
        elif k in ("offset", "seam_blend"):  # B/G/R levels the blend added (and its seams' part)
            sel[k] = [int(c) for c in v[y, x]]
        else:
            sel[k] = int(v[y, x])
    return dict(
        x=int(x), y=int(y), source_names=names, t_r=t_r, size=(H, W), scans=scans,
        selection=sel, patch_size=p,
        decisions=[_decision_dict(d, t_r, names, params) for d in dec[at]],
        replacements=[rep_dict(r) for r in rep[here]],
        covered_by=[rep_dict(r) for r in rep[cover]],
        updates=[dict(scan=int(u["scan"]), step=int(u["step"]), src=int(u["src"]),
                      case=int(u["case"]), new_x=int(u["new_x"]), new_y=int(u["new_y"]),
                      new_C=float(u["new_C"])) for u in upd[(upd["x"] == x) & (upd["y"] == y)]],
        final_dynamic=bool(L[y, x]) if L is not None and inside else None,
        # the recording holds no final L: it ends before the run finished
        ended_early=L is None,
        stages=stages, clean_rule=clean_rule,
        clean_params={k: params.get(k) for k in ("patch_size", "min_region_px")},
        gt=bool(gt[y, x]) if gt is not None and inside else None,
        # the scans' writes are refilled after them (--fill select or median), or
        # are the output (the paper preset); None in recordings without the params
        refill=(str(params.get("fuse_combine", "median")) if params.get("fuse") else "")
        if "fuse" in params else None,
        interrupted=_where_cut(load_store(path), root, x, y, H, W),
        photo=photo_size(info),
        # how far the clean photo is from the input here: where the fill replaced the
        # pixel, the blend's correction may bring the reference's colour back (a trial
        # read "removed, filled from tim1" on a pixel still the cup's red)
        clean_input=(clean_and_input(path, x, y, root=root)
                     if inside and L is not None and L[y, x] and sel.get("source", 0) > 0
                     else None),
    )


def _where_cut(store, root: str, x: int, y: int, H: int, W: int) -> dict[str, Any] | None:
    """Where an interrupted run ended, and whether its last scan had reached the pixel:
    ``message``, ``scan``, ``step``, ``scans_began``, ``visit_step`` (when the last
    scan would have visited the pixel) and ``reached``; None for a finished run."""
    v = _interruption_values(store, root)
    if not v.get("message"):
        return None
    out = dict(message=str(v["message"]), scan=int(v.get("scan", 0)),
               step=int(v.get("step", 0)), scans_began=bool(v.get("scans_began", False)))
    if out["scans_began"] and H and W:
        out["visit_step"] = visit_step(out["scan"], x, y, H, W)
        out["reached"] = out["visit_step"] <= out["step"]
    return out


def photo_size(info: dict[str, Any]) -> tuple[int, int] | None:
    """(W, H) of the photos as read, when the run recorded them and analysed the
    photos at another size (``--max-side``); else None."""
    W0, H0 = int(info.get("photo_width", 0) or 0), int(info.get("photo_height", 0) or 0)
    W, H = int(info.get("width", 0) or 0), int(info.get("height", 0) or 0)
    return (W0, H0) if W0 and H0 and W and H and (W0, H0) != (W, H) else None


def photo_to_analysis(info: dict[str, Any], x: int, y: int) -> tuple[int, int] | None:
    """The analysis-image pixel of photo pixel (x, y) (as ``run --probe`` scales it),
    or None."""
    ph = photo_size(info)
    if ph is None:
        return None
    return io.photo_to_analysis(x, y, ph, (int(info["width"]), int(info["height"])))


def analysis_to_photo(info: dict[str, Any], x: int, y: int) -> tuple[int, int] | None:
    """The photo pixel whose centre analysis pixel (x, y)'s centre falls on (the
    inverse of :func:`photo_to_analysis`), or None when the run analysed the photos
    at their own size."""
    ph = photo_size(info)
    if ph is None:
        return None
    (W0, H0), W, H = ph, int(info["width"]), int(info["height"])
    return (min(W0 - 1, max(0, int(round((x + 0.5) * W0 / W - 0.5)))),
            min(H0 - 1, max(0, int(round((y + 0.5) * H0 / H - 0.5)))))


def photo_span(info: dict[str, Any], x: int, y: int
               ) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """The photo pixels that :func:`photo_to_analysis` maps to analysis pixel (x, y):
    ((x0, x1), (y0, y1)), both inclusive; None when the run analysed the photos at
    their own size."""
    c = analysis_to_photo(info, x, y)
    if c is None:
        return None
    size = photo_size(info)
    span = max(size[0] // int(info["width"]), size[1] // int(info["height"])) + 2
    xs = [p for p in range(max(0, c[0] - span), min(size[0], c[0] + span + 1))
          if photo_to_analysis(info, p, 0)[0] == x]
    ys = [p for p in range(max(0, c[1] - span), min(size[1], c[1] + span + 1))
          if photo_to_analysis(info, 0, p)[1] == y]
    return (xs[0], xs[-1]), (ys[0], ys[-1])


def outside_message(info: dict[str, Any], x: int, y: int) -> str:
    """Why ``--pixel x,y`` is refused: outside the image the run analysed. When the
    photos were larger and (x, y) lies inside them, the pixel it most likely means."""
    W, H = int(info["width"]), int(info["height"])
    msg = (f"pixel ({x}, {y}) is outside the {W}x{H} image (x in 0..{W - 1}, "
           f"y in 0..{H - 1})")
    ph = photo_size(info)
    if ph is None:
        return msg
    W0, H0 = ph
    msg = (f"pixel ({x}, {y}) is outside the {W}x{H} analysis image (x in 0..{W - 1}, "
           f"y in 0..{H - 1}): --pixel counts in the image the run analysed, as the "
           f"viewer and --failures do; the photos are {W0}x{H0} (analysed at "
           f"×{W / W0:.3g})")
    if 0 <= x < W0 and 0 <= y < H0:
        qx, qy = photo_to_analysis(info, x, y)
        msg += f": photo pixel ({x}, {y}) is --pixel {qx},{qy}"
    return msg


def failure_cause(kind: str, region: np.ndarray, stages: dict[str, np.ndarray],
                  sel: dict[str, np.ndarray]) -> tuple[str | None, float]:
    """The largest of ``failure_causes``: (its key, its share); (None, 0.0) without
    stages."""
    shares, _ = failure_causes(kind, region, stages, sel)
    return shares[0] if shares else (None, 0.0)


def failure_causes(kind: str, region: np.ndarray, stages: dict[str, np.ndarray],
                   sel: dict[str, np.ndarray]
                   ) -> tuple[list[tuple[str, float]], np.ndarray | None]:
    """Why a failure region of ``failures`` is what it is, by the most of its pixels.

    For a missed region ("FN"): never flagged, dropped by the step after the last
    one that had it (``STAGE_ORDER``), or, where the fill by selection dropped it,
    kept as static 3-D structure, kept because its fill did not fit
    (``completed`` 3), kept with its region of L (``completed`` 2), or kept whole
    with a mover the fill could replace only in part (``completed`` 4). For a false
    positive ("FP"): flagged by the scans, or added by the first step that had it
    (a mover that lingered, where the fill by selection added it so).
    Returns ``[(cause, share), ...]``, largest share first (a cause: a key of
    ``verdict.FAILURE_CAUSES``, or "dropped:<stage>" / "added:<stage>"; its share of
    the region's pixels), and each pixel's cause ((n,) object array over
    ``region``'s pixels, row-major); ``([], None)`` without stages.
    """
    names = [n for n in STAGE_ORDER if n in stages]
    if not names or not region.any():
        return [], None
    have = np.stack([stages[n][region] for n in names])  # (stages, n px)
    if kind == "FN":
        # dropped by the step after the last one that had it
        last = len(names) - 1 - np.argmax(have[::-1], axis=0)
        dropped = np.array(["dropped:" + n for n in names])
        causes = dropped[np.minimum(last + 1, len(names) - 1)].astype(object)
        causes[~have.any(0)] = "never"
        by_sel = causes == "dropped:select"
        comp, expl = sel.get("completed"), sel.get("explained")
        if expl is not None:
            causes[by_sel & expl[region].astype(bool)] = "explained"
        if comp is not None:
            causes[by_sel & (comp[region] == 3)] = "misfit"
            causes[by_sel & (comp[region] == 2)] = "region"
            causes[by_sel & (comp[region] == 4)] = "partial"
    else:
        # added by the first step that had it (all have it at the end)
        added = np.array(["scan"] + ["added:" + n for n in names[1:]])
        causes = added[np.argmax(have, axis=0)].astype(object)
        ling = sel.get("lingering")
        if ling is not None:
            causes[(causes == "added:select") & ling[region].astype(bool)] = "lingering"
    keys, counts = np.unique(causes.astype(str), return_counts=True)
    order = np.argsort(-counts, kind="stable")
    return ([(str(keys[j]), float(counts[j] / len(causes))) for j in order],
            causes.astype(str))


def failures(path: str | Path, top: int = 10, *, root: str = "") -> list[dict[str, Any]]:
    """Worst false-positive / false-negative regions of the final L vs ground truth.

    Connected components of FP (dynamic, not in ground truth) and FN (missed)
    pixels, largest first. Each entry: ``kind`` ("FP"/"FN"), ``area``, ``bbox``
    (x, y, w, h), ``centroid``, ``pixel`` (the most interior pixel, a good
    ``--probe``), ``n_decisions`` (recorded decisions inside) and ``worst``
    (the pixel inside whose M was most confidently wrong, over every scan's M map,
    which holds every pixel; from the recorded decisions in recordings without
    those maps; None where no pixel inside was decided),
    ``why`` and ``why_share`` (``failure_cause``: the cause of the largest share of
    it; ``pixel`` is then the most interior pixel of that share), ``why_more`` (the
    other causes holding 5 % of it or more, as ``[(cause, share), ...]``);
    all in pixels of the analysis image, of size ``size`` (H, W); when the photos
    were analysed at another size, ``photo`` (W, H) and ``photo_pixel`` (``pixel``
    in the photo), else None.
    Needs ``gt_mask`` given to the sink and a finished run.
    """
    root = resolve_root(path, root)
    info = read_run_info(path, root=root)
    L = read_final_dynamic(path, root=root)
    gt = read_gt_mask(path, root=root)
    fix = ("record one with `dynremove run IMAGES --gt MASK --record FILE.rrd` (MASK: the "
           "reference's ground-truth mask, white = moving)")
    if L is None:
        cut = interruption(load_store(path), root)
        raise InputError(f"{path}: the run did not finish (" + (cut or "no final mask")
                         + "); --failures needs a finished run recorded with a "
                         "ground-truth mask: " + fix)
    if gt is None:
        raise InputError(f"{path}: --failures compares the final mask with a ground-truth "
                         "mask, and this run was recorded without one (no --gt): " + fix)
    dec = read_events(path, "decisions", root=root)
    stages = read_stages(path, root=root)
    sel = read_selection(path, root=root)
    H, W = L.shape
    maps = read_scan_maps(path, root=root)
    scan_dirs = [(m["scan"], m["direction"]) for m in maps] or \
        [(int(s), 1 if s % 2 == 0 else -1) for s in np.unique(dec["scan"]).tolist()] or [(0, 1)]
    found = []  # (kind, area, bbox, labels, label, centroid): cheap, for the sort
    for kind, mask in (("FP", L & ~gt), ("FN", ~L & gt)):
        n, lab, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8), 8)
        for i in range(1, n):
            x0, y0, w, hh, area = (int(v) for v in stats[i])
            found.append((kind, area, (x0, y0, w, hh), lab, i,
                          (float(cents[i][0]), float(cents[i][1]))))
    found.sort(key=lambda f: -f[1])
    out = []
    for kind, area, (x0, y0, w, hh), lab, i, centroid in found[:top]:
        # (only the regions returned are read further: a run may have hundreds)
        region = lab == i
        inside = ((dec["x"] >= x0) & (dec["x"] < x0 + w) & (dec["y"] >= y0)
                  & (dec["y"] < y0 + hh))
        d_in = dec[inside]
        d_in = d_in[lab[d_in["y"], d_in["x"]] == i]
        worst = None
        finite = d_in[np.isfinite(d_in["M"])]
        if maps:
            # from every scan's M map, which holds every pixel (the recorded decisions
            # are mostly the dynamic ones: a missed region's "highest M" read from them
            # was a dynamic pixel's, 0.29, where most of the region had M 0.84)
            best = None
            for m in maps:
                Mr = np.where(region, m["M"], np.nan)
                if not np.isfinite(Mr).any():
                    continue
                j = int(np.nanargmin(Mr) if kind == "FP" else np.nanargmax(Mr))
                y, x = divmod(j, W)
                v = float(Mr[y, x])
                if best is None or (v < best[0] if kind == "FP" else v > best[0]):
                    best = (v, x, y, m["scan"], m["direction"])
            if best is not None:
                v, x, y, sc, dr = best
                worst = dict(x=x, y=y, M=v, scan=int(sc),
                             step=int(visit_step(sc, x, y, H, W, direction=dr)))
        elif len(finite):
            j = int(np.argmin(finite["M"]) if kind == "FP" else np.argmax(finite["M"]))
            worst = dict(x=int(finite[j]["x"]), y=int(finite[j]["y"]),
                         M=float(finite[j]["M"]), scan=int(finite[j]["scan"]),
                         step=int(finite[j]["step"]))
        shares, per_px = failure_causes(kind, region, stages, sel)
        why, why_share = shares[0] if shares else (None, 0.0)
        # the pixel to explain: the most interior one of the share named first (a
        # trial's pixel was dropped by the clean-up where the line said "never flagged")
        mine = region
        if shares and why_share < 0.995:
            mine = np.zeros(region.shape, bool)
            mine[region] = per_px == why
        sub = mine[y0:y0 + hh, x0:x0 + w].astype(np.uint8)
        dist = cv2.distanceTransform(np.pad(sub, 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        py, px = np.unravel_index(int(np.argmax(dist)), dist.shape)
        qx, qy = x0 + int(px), y0 + int(py)
        out.append(dict(kind=kind, area=area, bbox=(x0, y0, w, hh), centroid=centroid,
                        pixel=(qx, qy), n_decisions=len(d_in), worst=worst,
                        size=(H, W), photo=photo_size(info),
                        photo_pixel=analysis_to_photo(info, qx, qy),
                        steps=[visit_step(sc, qx, qy, H, W, direction=dr)
                               for sc, dr in scan_dirs],
                        why=why, why_share=why_share,
                        why_more=[(c, f) for c, f in shares[1:] if f >= 0.05]))
    return out

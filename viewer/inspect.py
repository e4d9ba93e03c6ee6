"""Read a dynremove recording back: raw events, pixel histories, failures.

Uses ``RrdReader(path).stream().collect()`` (works on files without a footer,
e.g. a killed run) and the dataframe API, with rows keyed by the unique
``step`` index (RERUN_NOTES.md §6). The raw events come from the lossless
``events/*`` columns the sink writes (one row per step, one list entry per
event), so they round-trip exactly to the structured dtypes of
``dynremove.events``.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rerun.chunk import RrdReader

from dynremove.events import (CORRESPONDENCE_UPDATE_DTYPE, REPLACEMENT_DTYPE,
                              WHY_DYNAMIC, WHY_PROBE, WHY_SAMPLE, decision_dtype)
from viewer import paths as P

_KINDS = {"decisions": P.EVENTS_DECISIONS, "replacements": P.EVENTS_REPLACEMENTS,
          "updates": P.EVENTS_UPDATES}


# -- low level -----------------------------------------------------------------
@lru_cache(maxsize=4)
def _store_cached(path: str, mtime_ns: int, size: int):
    return RrdReader(path).stream().collect()


def load_store(path: str | Path):
    """The recording as an in-memory ChunkStore (cached per file version)."""
    st = Path(path).stat()
    return _store_cached(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


def _arrow(store, entity: str, *, index: str | None = "step"):
    try:
        t = store.reader(index=index, contents=entity).to_arrow_table()
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


def _image_rows(store, entity: str, archetype: str, *, index: str | None = "step"):
    """[(step | None, ndarray)] of a raw image entity (SegmentationImage/Image)."""
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
        if not buf[i].is_valid:
            continue
        f = fmt[i].as_py()[0]
        data = buf[i].values[0].values.to_numpy(zero_copy_only=False)
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
    if kind == "decisions":
        dtype = decision_dtype(int(read_run_info(path, root=root).get("K", 0)))
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


# -- pixel history -----------------------------------------------------------------
def _why_names(why: int) -> list[str]:
    return [n for bit, n in ((WHY_DYNAMIC, "dynamic"), (WHY_PROBE, "probe"),
                             (WHY_SAMPLE, "sample")) if why & bit]


def _decision_dict(d: np.void, t_r: float, names: list[str]) -> dict[str, Any]:
    cands = []
    for k in range(len(d["cand_src"])):
        s = int(d["cand_src"][k])
        if s < 0:
            continue
        cands.append(dict(slot=k, src=s, src_name=names[s] if s < len(names) else str(s),
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
                chosen_src=int(d["chosen_src"]), candidates=cands,
                clusters=dict(sorted(clusters.items())))


def pixel_history(path: str | Path, x: int, y: int, *, root: str = "") -> dict[str, Any]:
    """Everything the recording knows about reference pixel ``(x, y)``.

    Returns
    -------
    dict with ``x, y``, ``decisions`` (every recorded decision at the pixel with
    its candidates and clusters), ``replacements`` (written at the pixel),
    ``covered_by`` (patch writes centred elsewhere that overwrote it), ``updates``
    (correspondence updates at the pixel), ``final_dynamic`` and ``gt`` (bool or
    None), plus ``source_names``. Only decisions the core recorded are present:
    dynamic ones, probes (``--probe``) and sampled static ones.
    """
    info = read_run_info(path, root=root)
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
    inside = L is not None and 0 <= y < L.shape[0] and 0 <= x < L.shape[1]
    stages = {k: bool(v[y, x]) for k, v in read_stages(path, root=root).items()} \
        if inside else {}

    def rep_dict(r: np.void) -> dict[str, Any]:
        s = int(r["src"])
        return dict(scan=int(r["scan"]), step=int(r["step"]), x=int(r["x"]), y=int(r["y"]),
                    src=s, src_name=names[s] if 0 <= s < len(names) else str(s),
                    src_x=int(r["src_x"]), src_y=int(r["src_y"]), score=float(r["score"]),
                    tie_break=bool(r["tie_break"]), n_patches=int(r["n_patches"]))

    return dict(
        x=int(x), y=int(y), source_names=names, t_r=t_r,
        decisions=[_decision_dict(d, t_r, names) for d in dec[at]],
        replacements=[rep_dict(r) for r in rep[here]],
        covered_by=[rep_dict(r) for r in rep[cover]],
        updates=[dict(scan=int(u["scan"]), step=int(u["step"]), src=int(u["src"]),
                      case=int(u["case"]), new_x=int(u["new_x"]), new_y=int(u["new_y"]),
                      new_C=float(u["new_C"])) for u in upd[(upd["x"] == x) & (upd["y"] == y)]],
        final_dynamic=bool(L[y, x]) if inside else None,
        stages=stages,
        gt=bool(gt[y, x]) if gt is not None and inside else None,
    )


def format_pixel_history(h: dict[str, Any]) -> str:
    """Human-readable pixel history (one block per recorded step)."""
    def label(v: bool | None) -> str:
        return "?" if v is None else ("dynamic" if v else "static")

    lines = [f"pixel ({h['x']}, {h['y']}): {len(h['decisions'])} recorded decisions, "
             f"{len(h['replacements'])} replacements, {len(h['covered_by'])} overlapping "
             f"patch writes, {len(h['updates'])} correspondence updates; final L = "
             f"{label(h['final_dynamic'])}" +
             (f", ground truth = {label(h['gt'])}" if h.get("gt") is not None else "")]
    if h.get("stages"):
        lines.append("  L after each step: " + " → ".join(
            f"{k} {label(v)}" for k, v in h["stages"].items()))
    if not h["decisions"]:
        lines.append("  (no decision recorded here: static pixels are only recorded when "
                     "probed (--probe x,y) or sampled)")
    by_step: dict[int, list[str]] = {}
    for d in h["decisions"]:
        if np.isnan(d["M"]):
            verdict = f"M=nan (no cluster) → {'DYNAMIC' if d['dynamic'] else 'undecided'}"
        else:
            op = "≤" if d["M"] <= d["t_r"] else ">"
            verdict = (f"M={d['M']:.2f} {op} t_r={d['t_r']:.2f} → "
                       f"{'DYNAMIC' if d['dynamic'] else 'static'}")
        win = [c for c in d["candidates"] if c["cluster"] == d["win_cluster"]
               and c["cluster"] >= 0]
        wtxt = ", ".join(f"src {c['src']} ({c['x']},{c['y']}) B={c['B']:.2f}" for c in win)
        others = [f"{cid} ({e['n']} cand, ΣB {e['sum_B']:.2f})" if cid >= 0
                  else f"noise ({e['n']})" for cid, e in d["clusters"].items()
                  if cid != d["win_cluster"]]
        s = (f"scan {d['scan']} step {d['step']}: {verdict} [{'+'.join(d['why'])}]; "
             f"{len(d['candidates'])} candidates in {d['n_clusters']} clusters; winner "
             f"cluster {d['win_cluster']} weight {d['win_weight']:.2f} "
             f"({len(win)} candidates: {wtxt})")
        if others:
            s += "; other clusters: " + ", ".join(others)
        s += f"; consensus distance {d['consensus_dist']:.3f}"
        by_step.setdefault(d["step"], []).append(s)
    for r in h["replacements"]:
        by_step.setdefault(r["step"], []).append(
            f"    replaced from source {r['src']} ({r['src_name']}) at ({r['src_x']},"
            f"{r['src_y']}) score {r['score']:.2f}" + (" (tie-break)" if r["tie_break"]
                                                       else "")
            + f" among {r['n_patches']} patches")
    for r in h["covered_by"]:
        by_step.setdefault(r["step"], []).append(
            f"scan {r['scan']} step {r['step']}: overwritten by the patch written at "
            f"({r['x']},{r['y']}) from source {r['src']} ({r['src_name']}) "
            f"score {r['score']:.2f}")
    for u in h["updates"]:
        by_step.setdefault(u["step"], []).append(
            f"    N updated (case {u['case']}): source {u['src']} → ({u['new_x']},"
            f"{u['new_y']}) C={u['new_C']:.2f}")
    for step in sorted(by_step):
        lines.extend(by_step[step])
    return "\n".join(lines)


# -- failures ----------------------------------------------------------------------
def failures(path: str | Path, top: int = 10, *, root: str = "") -> list[dict[str, Any]]:
    """Worst false-positive / false-negative regions of the final L vs ground truth.

    Connected components of FP (dynamic, not in ground truth) and FN (missed)
    pixels, largest first. Each entry: ``kind`` ("FP"/"FN"), ``area``, ``bbox``
    (x, y, w, h), ``centroid``, ``pixel`` (the most interior pixel, a good
    ``--probe``), ``n_decisions`` (recorded decisions inside) and ``worst``
    (the recorded decision inside whose M was most confidently wrong, or None).
    Needs ``gt_mask`` given to the sink and a finished run.
    """
    L = read_final_dynamic(path, root=root)
    gt = read_gt_mask(path, root=root)
    if L is None or gt is None:
        raise ValueError(f"{path}: needs a finished run recorded with a ground-truth mask")
    dec = read_events(path, "decisions", root=root)
    out = []
    for kind, mask in (("FP", L & ~gt), ("FN", ~L & gt)):
        n, lab, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8), 8)
        for i in range(1, n):
            x0, y0, w, hh, area = (int(v) for v in stats[i])
            comp = (lab[y0:y0 + hh, x0:x0 + w] == i).astype(np.uint8)
            dist = cv2.distanceTransform(np.pad(comp, 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
            py, px = np.unravel_index(int(np.argmax(dist)), dist.shape)
            inside = ((dec["x"] >= x0) & (dec["x"] < x0 + w) & (dec["y"] >= y0)
                      & (dec["y"] < y0 + hh))
            d_in = dec[inside]
            d_in = d_in[lab[d_in["y"], d_in["x"]] == i]
            worst = None
            finite = d_in[np.isfinite(d_in["M"])]
            if len(finite):
                j = int(np.argmin(finite["M"]) if kind == "FP" else np.argmax(finite["M"]))
                worst = dict(x=int(finite[j]["x"]), y=int(finite[j]["y"]),
                             M=float(finite[j]["M"]), scan=int(finite[j]["scan"]),
                             step=int(finite[j]["step"]))
            out.append(dict(kind=kind, area=area, bbox=(x0, y0, w, hh),
                            centroid=(float(cents[i][0]), float(cents[i][1])),
                            pixel=(x0 + int(px), y0 + int(py)), n_decisions=len(d_in),
                            worst=worst))
    out.sort(key=lambda e: -e["area"])
    return out[:top]


def format_failures(items: list[dict[str, Any]]) -> str:
    """One line per failure region."""
    lines = []
    for e in items:
        x0, y0, w, h = e["bbox"]
        s = (f"{e['kind']} {e['area']:6d} px  bbox ({x0},{y0}) {w}x{h}  probe "
             f"{e['pixel'][0]},{e['pixel'][1]}  {e['n_decisions']} recorded decisions")
        if e["worst"]:
            s += f"; worst M={e['worst']['M']:.2f} at ({e['worst']['x']},{e['worst']['y']})"
        lines.append(s)
    return "\n".join(lines)

"""The step-indexed columns of ``RerunSink``: raw events and per-step overlays.

Mixed into :class:`viewer.sink.RerunSink`. Every method sends whole columns
(``send_columns``, one call per entity and flush, partitioned by step with
``pa.ListArray``), never one call per pixel: the lossless ``events/*`` tables
that ``viewer.inspect`` reads back (one row per flush), the per-step decisions
and replacements (every recorded one, or the subset the sink's ``detail``
selects: :meth:`StepColumns._overlay_mask`), the matches of correspondence
updates and the probe pixels' stories.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr

from dynremove.events import WHY_PROBE, WHY_SAMPLE
from viewer import paths as P
from viewer._images import REASON_NAMES, cluster_colors


def _offsets(lengths: np.ndarray) -> pa.Array:
    return pa.array(np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32))


def _list_column(values: np.ndarray, offsets: pa.Array) -> pa.ListArray:
    return pa.ListArray.from_arrays(offsets, pa.array(np.ascontiguousarray(values)))


def _text_column(values: list[str], offsets: pa.Array) -> pa.ListArray:
    return pa.ListArray.from_arrays(offsets, pa.array(list(values), pa.string()))



def _rounded(a: np.ndarray, digits: int = 3) -> np.ndarray:
    """float64 copy rounded for display (no 0.300000011920929 in the Selection panel)."""
    return np.round(np.asarray(a, np.float64), digits)


def _reason_text(why: int) -> str:
    return ", ".join(name for bit, name in REASON_NAMES.items() if why & bit) or "-"


class StepColumns:
    """Mixin of :class:`viewer.sink.RerunSink`: the step-indexed columns it sends."""

    def _log_probe_stories(self, d: np.ndarray, r: np.ndarray, scan: int) -> None:
        """``probes/x<X>_y<Y>``: each probe pixel's decisions as text, one per step."""
        pr = d[(d["why"] & WHY_PROBE) != 0]
        if len(pr) == 0:
            return
        attrs = self._decision_attrs(pr)
        for (x, y) in {(int(a), int(b)) for a, b in zip(pr["x"], pr["y"])}:
            m = (pr["x"] == x) & (pr["y"] == y)
            texts = []
            for i in np.nonzero(m)[0].tolist():
                t = (f"({x},{y}) scan {scan} step {int(pr['step'][i])}: "
                     f"{attrs['verdict'][i]}; ")
                if np.isfinite(pr["M"][i]):
                    t += (f"winning cluster {int(attrs['winning_cluster_size'][i])} of "
                          f"{int(attrs['n_candidates'][i])} candidates from "
                          f"{attrs['winning_cluster_sources'][i]}; b_m {attrs['b_m'][i]:.2f}")
                else:  # (a trial read "winning cluster 0 of 0 candidates from -")
                    t += (f"no cluster formed among its {int(attrs['n_candidates'][i])} "
                          "candidates")
                if pr["dynamic"][i]:
                    t += f"; patch from {attrs['chosen_source'][i]}"
                texts.append(t)
            steps = pr["step"][m].astype(np.int64)
            self.rec.send_columns(
                self.p(f"probes/x{x}_y{y}"),
                indexes=[rr.TimeColumn("scan", sequence=np.full(len(steps), scan, np.int64)),
                         rr.TimeColumn("step", sequence=steps.copy())],
                columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)))

    def _log_table(self, rel: str, arr: np.ndarray, scan: int) -> None:
        """Log structured records losslessly: ONE row per flush, a list per field.

        Each record keeps its own ``step`` field; the row sits at the last of
        them (flushes cover disjoint step ranges, so rows never share a step).
        One row per step held the same data in 40k rows per table on camel,
        which the web viewer has to index; ``viewer.inspect`` reads either
        layout (it flattens the lists in step order).
        """
        if len(arr) == 0:
            return
        arr = arr[np.argsort(arr["step"], kind="stable")]
        cols = {}
        for name in arr.dtype.names:
            vals = arr[name].copy()  # a fresh, aligned array (a field view may not be)
            width = int(np.prod(vals.shape[1:], dtype=np.int64))
            cols[name] = _list_column(vals.reshape(-1), _offsets(np.array([len(arr) * width])))
        self.rec.send_columns(
            self.p(rel),
            indexes=[rr.TimeColumn("scan", sequence=np.array([scan], np.int64)),
                     rr.TimeColumn("step", sequence=np.array([arr["step"][-1]], np.int64))],
            columns=rr.AnyValues.columns(**cols))

    def _decision_attrs(self, d: np.ndarray) -> dict[str, Any]:
        """Per-decision attributes in words and rounded values (Selection panel)."""
        cl, src = d["cand_cluster"], d["cand_src"]
        in_win = (cl == d["win_cluster"][:, None]) & (cl >= 0) & (src >= 0)
        n_win = in_win.sum(1)
        names = self.src_names

        def name_of(s: int) -> str:
            return names[s] if 0 <= s < len(names) else "-"

        win_src = [", ".join(sorted({name_of(int(v)) for v in row[m]})) or "-"
                   for row, m in zip(src, in_win)]
        verdict = []
        for m, dy in zip(d["M"].tolist(), d["dynamic"].tolist()):
            if m != m:
                verdict.append("dynamic (no cluster)" if dy else "undecided (no cluster)")
            else:
                op = "≤" if m <= self.t_r else ">"
                verdict.append(f"{'dynamic' if dy else 'static'}: M {m:.2f} {op} t_r "
                               f"{self.t_r:.2f}")
        return dict(verdict=verdict, reason=[_reason_text(int(w)) for w in d["why"]],
                    M=_rounded(d["M"]), t_r=np.full(len(d), round(self.t_r, 3)),
                    b_m=_rounded(d["win_weight"]), winning_cluster_size=n_win.astype(np.int32),
                    winning_cluster_sources=win_src, n_clusters=d["n_clusters"].astype(np.int32),
                    n_candidates=d["n_cand"].astype(np.int32),
                    chosen_source=[name_of(int(c)) for c in d["chosen_src"]],
                    step=d["step"].astype(np.int64), x=d["x"].astype(np.int32),
                    y=d["y"].astype(np.int32))

    def _log_decisions(self, d: np.ndarray, scan: int, img_rows: tuple[int, int]) -> None:
        """The chunk's recorded decisions, logged ONCE on an entity of their own.

        ``reference/decisions/scan<k>/rows_<a>_<b>`` is written at the chunk's last
        step and cleared (recursively, with the whole scan) when the next scan
        starts, so an instance index keeps meaning the same decision for as long as
        it is shown: a selection is never silently re-targeted by a time change.
        """
        if len(d) == 0:
            return
        cls = np.where(np.isnan(d["M"]) & ~d["dynamic"], P.CLASS_UNDECIDED,
                       np.where(d["dynamic"], P.CLASS_DYNAMIC,
                                np.where(d["why"] & WHY_PROBE, P.CLASS_PROBE, P.CLASS_STATIC)))
        attrs = self._decision_attrs(d)
        self.rec.log(self.p(P.decisions_chunk(scan, img_rows)),
                     rr.Points2D(np.stack([d["x"], d["y"]], 1).astype(np.float32) + 0.5,
                                 class_ids=cls.astype(np.uint16), labels=attrs["verdict"],
                                 show_labels=False, radii=rr.Radius.ui_points(2.5)),
                     rr.AnyValues(**attrs))

    def _overlay_mask(self, d: np.ndarray) -> np.ndarray:
        """Which recorded decisions get the per-source overlays (the sink's ``detail``):
        their candidates and q* box in every source view.

        ``"full"`` (``step_grid`` 1): all. ``"default"``: every decision that is
        not (only) dynamic, i.e. probes and sampled static ones, plus the dynamic
        ones at pixels with ``x % step_grid == 0 and y % step_grid == 0``: a
        fixed grid, the same pixels in every scan and direction.
        """
        g = int(self.step_grid)
        if g <= 1:
            return np.ones(len(d), bool)
        return (((d["why"] & (WHY_PROBE | WHY_SAMPLE)) != 0) | ~d["dynamic"]
                | ((d["x"] % g == 0) & (d["y"] % g == 0)))

    def _log_per_step(self, d: np.ndarray, r: np.ndarray, scan: int) -> None:
        """Overlays that explain one step: current decision, candidates, chosen patch.

        Logged partitioned by step; an empty partition at ``step + 1`` clears them.
        On the reference (the current marker with its attributes, its verdict
        label, the chosen patch): every recorded decision and replacement. In the
        source views (candidates, q* boxes), only at the steps of the decisions
        :meth:`_overlay_mask` selects; those entities get rows only where they
        change (``own_rows``).
        """
        shown = d  # every recorded decision gets its marker: dynamic, probe, sampled
        if len(shown) == 0 and len(r) == 0:
            return
        ev = np.unique(np.concatenate([shown["step"], r["step"]]).astype(np.int64))
        steps = np.union1d(ev, ev + 1)
        n = len(steps)
        idx = [rr.TimeColumn("scan", sequence=np.full(n, scan, np.int64)),
               rr.TimeColumn("step", sequence=steps.copy())]

        def lengths_of(ev_steps: np.ndarray) -> np.ndarray:
            return np.bincount(np.searchsorted(steps, ev_steps), minlength=n)

        def own_rows(ev_steps: np.ndarray) -> tuple[list, np.ndarray]:
            """Index and partition lengths of an entity with data at ``ev_steps``
            (sorted) only: a row at each of them and an empty one at the step after,
            unless data follows there. Latest-at then shows exactly what rows at
            every step of ``steps`` would show, with far fewer rows for the
            per-source entities (a patch comes from one source at a step), which is
            what the web viewer's load time grows with."""
            u = np.unique(ev_steps.astype(np.int64))
            own = np.union1d(u, u + 1)
            index = [rr.TimeColumn("scan", sequence=np.full(len(own), scan, np.int64)),
                     rr.TimeColumn("step", sequence=own.copy())]
            return index, np.bincount(np.searchsorted(own, ev_steps), minlength=len(own))

        def ordered(a: np.ndarray) -> np.ndarray:
            return a[np.argsort(a["step"], kind="stable")]

        if len(shown):
            c = ordered(shown)
            attrs = self._decision_attrs(c)
            lens = lengths_of(c["step"])
            off = _offsets(lens)
            xy = np.stack([c["x"], c["y"]], 1).astype(np.float32) + 0.5
            self.rec.send_columns(self.p(P.REFERENCE_CURRENT), indexes=idx, columns=[
                *rr.Points2D.columns(
                    positions=xy, colors=np.tile(np.array([[255, 0, 255]], np.uint8),
                                                 (len(c), 1)),
                    radii=np.full(len(c), -6.0, np.float32)).partition(lens),
                *rr.AnyValues.columns(**{k: _list_column(v, off) if isinstance(v, np.ndarray)
                                         else _text_column(v, off)
                                         for k, v in attrs.items()})])
            # the verdict in words on a box around the pixel: the label sits above
            # the box, beside the pixel, never on it
            half = np.full((len(c), 2), max(self.patch_size / 2, 3.0) + 1, np.float32)
            self.rec.send_columns(self.p(P.REFERENCE_CURRENT_LABEL), indexes=idx, columns=[
                *rr.Boxes2D.columns(
                    centers=xy, half_sizes=half,
                    colors=np.tile(np.array([[255, 0, 255]], np.uint8), (len(c), 1)),
                    labels=[f"({x},{y}) {v}" for x, y, v in zip(
                        c["x"].tolist(), c["y"].tolist(), attrs["verdict"])]
                ).partition(lens)])
            # candidates, per source: flatten the K slots (of the selected decisions)
            c = c[self._overlay_mask(c)]
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
                own_idx, lens = own_rows(cstep[m])
                off = _offsets(lens)
                self.rec.send_columns(self.p(P.source(name, P.CANDIDATES)), indexes=own_idx,
                                      columns=[
                    *rr.Points2D.columns(
                        positions=cxy[m].astype(np.float32) + 0.5,
                        colors=cluster_colors(ccl[m]),
                        radii=np.where(win[m], -5.0, -3.0).astype(np.float32)
                    ).partition(lens),
                    *rr.AnyValues.columns(cluster=_list_column(ccl[m], off),
                                          B_l=_list_column(_rounded(cB[m]), off),
                                          winner=_list_column(win[m], off),
                                          source=_text_column([name] * int(m.sum()), off),
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
            if self.step_grid > 1:  # q* in the sources: at the selected decisions only
                sel = np.isin(c["step"], shown["step"][self._overlay_mask(shown)])
            else:
                sel = np.ones(len(c), bool)
            for s, name in enumerate(self.src_names):
                m = (c["src"] == s) & sel
                if not m.any():
                    continue
                cs = c[m]
                own_idx, lens = own_rows(cs["step"])
                self.rec.send_columns(self.p(P.source(name, P.CHOSEN_PATCH)), indexes=own_idx,
                                      columns=[*rr.Boxes2D.columns(
                    centers=np.stack([cs["src_x"], cs["src_y"]], 1).astype(np.float32) + 0.5,
                    half_sizes=half[m].copy(),
                    colors=np.tile(np.array([[0, 255, 0]], np.uint8), (len(cs), 1)),
                    labels=[f"q* score {sc:.2f}" + (" (tie)" if t else "") for sc, t in
                            zip(cs["score"].tolist(), cs["tie_break"].tolist())]
                ).partition(lens)])

    def _log_matches(self, u: np.ndarray, img_rows: tuple[int, int]) -> None:
        """Correspondences updated in this chunk, dim, in each source's own image space.

        Logged at the chunk's last step on ``sources/<name>/chunk_matches``, a layer
        apart from the current step's candidates (shown while the next chunk runs).
        """
        case_rgba = np.array([[0, 0, 0, 0], [0, 200, 255, 90], [255, 160, 0, 90],
                              [200, 0, 255, 90]], np.uint8)
        case_name = np.array(["-", "case 1: one candidate in the cluster",
                              "case 2: both candidates in the cluster",
                              "case 3: geometry (epipolar line)"], object)
        a, b = sorted(img_rows)
        for s, name in enumerate(self.src_names):
            path = self.p(P.source(name, P.MATCHES))
            m = u["src"] == s if len(u) else np.zeros(0, bool)
            if not m.any():
                if self._matches_shown[s]:
                    self.rec.log(path, rr.Clear(recursive=False))
                    self._matches_shown[s] = False
                continue
            us = u[m]
            case = np.clip(us["case"], 0, 3)
            self.rec.log(path, rr.Points2D(
                np.stack([us["new_x"], us["new_y"]], 1).astype(np.float32) + 0.5,
                colors=case_rgba[case], radii=rr.Radius.ui_points(1.5),
                labels=[f"rows {a}-{b}"] * len(us), show_labels=False),
                rr.AnyValues(case=case_name[case].tolist(), new_C=_rounded(us["new_C"]),
                             ref_x=us["x"].copy(), ref_y=us["y"].copy(),
                             step=us["step"].copy()))
            self._matches_shown[s] = True

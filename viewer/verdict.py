"""A pixel's history in words: the verdict lines and the text of ``dynremove inspect``.

:mod:`viewer.inspect` reads the recording (``pixel_history``, ``failures``);
this module turns what it read into sentences. No Rerun here: plain dicts in,
strings out.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dynremove.events import CASE_BOTH_IN_CLUSTER, CASE_GEOMETRY, CASE_ONE_IN_CLUSTER
from dynremove.refine.colour import delta_e
from dynremove.refine.fields import blurred_lab
from dynremove.refine.parallax import SEARCH_CAP_DE as _LINE_CAP
from dynremove.refine.select import MISFIT_MOVER_P, MISPLACED, REASONS

# a blend offset from this many levels up (any channel) is told as more than light
_LARGE_OFFSET = 40
# what a small blend offset answers: the words of the fill line
_LIGHT_OR_REST = ("the photos' light differing there, exposure, glare or shade, needs "
                  "this; so does part of a mover left in the reference around the region")


def levels_words(off) -> str:
    """B/G/R levels as the recording holds them (``sink``: 128 + levels, clipped to
    0..255): "+12/-3/-128" reads "≤ -128" and "≥ +127" at the clip, where the true
    value may be anything beyond (a trial read "-128/-128/-128" as a measurement)."""
    return "/".join("≤ -128" if c <= -128 else "≥ +127" if c >= 127 else f"{c:+d}"
                    for c in off)


def _label(v: bool | None) -> str:
    return "?" if v is None else ("dynamic" if v else "static")


def m_text(M: float) -> str:
    """M to two decimals, as the per-scan map holds it (round(M · 10⁴) as uint16):
    a decision's exact M and the map's print the same figure (0.24503 and 0.2450
    both "0.24"; a trial saw "M = 0.25" in the verdict and "M 0.24" in the history)."""
    return f"{round(float(M), 4):.2f}"


def _src_name(h: dict[str, Any], s: int) -> str:
    names = h.get("source_names", [])
    return names[s] if 0 <= s < len(names) else f"source {s}"


def _winning(d: dict[str, Any]) -> tuple[list[dict], list[str]]:
    win = [c for c in d["candidates"] if c["cluster"] == d["win_cluster"] and c["cluster"] >= 0]
    return win, sorted({c["src_name"] for c in win})


def cluster_words(sc: dict[str, Any] | None, d: dict[str, Any] | None,
                  n_sources: int, *, short: bool = False) -> str | None:
    """The winning cluster A_m of one scan in words, or None when nothing says.

    ``sc``: the scan's entry of ``pixel_history(...)["scans"]`` (the per-scan
    maps, for every pixel); ``d``: the recorded decision of that scan (probes,
    dynamic and sampled pixels), used when the recording has no cluster maps.
    """
    if sc is not None and sc.get("n_candidates") is not None:
        n, k, size = sc["n_candidates"], sc["n_clusters"], sc["win_size"]
        srcs, b_m = list(sc["win_sources"] or []), sc["b_m"]
        cid = d["win_cluster"] if d is not None else None
    elif d is not None:
        win, srcs = _winning(d)
        n, k, size, b_m, cid = (len(d["candidates"]), d["n_clusters"], len(win),
                                d["win_weight"], d["win_cluster"])
    else:
        return None
    if not k or not size:
        return (f"no cluster: {n} candidate{'s' if n != 1 else ''}, all DBSCAN noise"
                if n else "no candidate (all outside the sources)")
    rest = _the_others(n, k, size, d)
    # (0 sources known: a recording cut short before the run info's source names)
    of = f" of {n_sources}" if n_sources else ""
    if short:
        return (f"A_m {size} of {n} candidates from {len(srcs)}{of} sources"
                f"{', ' + rest if rest else ''}, b_m {b_m:.2f}, k {k}")
    return (f"winning cluster A_m{'' if cid is None else f' (cluster {cid})'}: {size} of "
            f"{n} candidates from {len(srcs)}{of} sources ({', '.join(srcs)})"
            f"{'; ' + rest if rest else ''}; b_m = Σ B_l = {b_m:.2f}; "
            f"k = {k} cluster{'s' if k != 1 else ''}")


def _against_t_r(M: float, t_r: float) -> str:
    """"≤ t_r 0.30" or "> t_r 0.30"; t_r NaN (the recording stops before the run's
    parameters): says so instead of comparing with it."""
    if t_r != t_r:
        return "(t_r unknown: the recording stops before the run's parameters)"
    return f"{'≤' if M <= t_r else '>'} t_r {t_r:.2f}"


def _the_others(n: int, k: int, size: int, d: dict[str, Any] | None) -> str:
    """Where the candidates outside A_m went: other clusters or DBSCAN noise (label −1).
    Counted from the decision's labels when it is recorded and matches; else from
    k alone (k = 1: all the others are noise); "" when A_m holds them all."""
    others = n - size
    if others <= 0:
        return ""
    labels = [c["cluster"] for c in d["candidates"]] if d is not None else None
    if labels is not None and len(labels) == n:
        noise = sum(1 for c in labels if c < 0)
    elif k == 1:
        noise = others
    else:
        return (f"the other {others} in the {k - 1} other cluster{'s' if k > 2 else ''} "
                "or DBSCAN noise")
    if noise == others:
        return f"the other {others} DBSCAN noise"
    if noise == 0:
        return f"the other {others} in {k - 1} other cluster{'s' if k > 2 else ''}"
    return (f"the other {others}: {others - noise} in {k - 1} other "
            f"cluster{'s' if k > 2 else ''}, {noise} DBSCAN noise")


def candidate_counts(d: dict[str, Any]) -> str:
    """A recorded decision's candidates by DBSCAN label, the winner first: "6
    candidates: 2 in the winner cluster 0 (b_m 1.87: its members), 4 noise" (noise:
    label −1)."""
    cands = d["candidates"]
    n = len(cands)
    head = f"{n} candidate{'s' if n != 1 else ''}"
    if not n:
        return head
    by: dict[int, int] = {}
    for c in cands:
        by[c["cluster"]] = by.get(c["cluster"], 0) + 1
    win = d["win_cluster"]

    def listed(keep) -> str:  # the candidates ``keep`` takes: source, position, B_l
        return ", ".join(f"{m['src_name']} ({m['x']},{m['y']}) B_l {m['B']:.2f}"
                         for m in cands if keep(m["cluster"]))

    parts = []
    for c in sorted((c for c in by if c >= 0), key=lambda c: (c != win, c)):
        if c == win:
            parts.append(f"{by[c]} in the winner cluster {c} (b_m {d['win_weight']:.2f}: "
                         f"{listed(lambda k, c=c: k == c)})")
        else:
            parts.append(f"{by[c]} in cluster {c}")
    if by.get(-1):
        noise = ("all" if by[-1] == n else str(by[-1])) + " noise"
        if win < 0:
            # no cluster: where they were is all there is to read (a trial's probe of
            # an undecided pixel said only "2 candidates: all noise")
            noise += f" ({listed(lambda k: k < 0)})"
        parts.append(noise)
    return head + ": " + ", ".join(parts)


def _added_by(h: dict[str, Any]) -> str:
    """Which rule of the fill by selection added a pixel to L, as far as the recording
    tells: ``completed`` == 1 is the region rule; a pixel within a patch of the frame's
    edge may be the edge rule (``select.to_the_border``); elsewhere the consensus
    growth (a fresh-user trial read all three rules offered for one pixel)."""
    if (h.get("selection") or {}).get("completed") == 1:
        return ("its region of L was replaced almost whole, so the graph cut's choice to "
                "keep it was overruled (--select-complete)")
    growth = ("the sources, near a mover, agree with one another and the reference alone "
              "differs, or none agrees with the reference and it shows the movers' colours "
              "(--select-grow-px)")
    H, W = h.get("size", (0, 0))
    p = int(h.get("patch_size") or 0)
    x, y = h.get("x", -1), h.get("y", -1)
    if H and W and p and min(x, y, W - 1 - x, H - 1 - y) < p:
        return (f"at the frame's edge, where the scans' p×p patches stop short (L taken "
                f"to the edge), or where {growth}")
    return "where " + growth


def _not_reached(h: dict[str, Any]) -> str:
    """The first line for a pixel no recorded scan says anything about."""
    cut = h.get("interrupted")
    if cut and cut.get("scans_began") and "visit_step" in cut:
        where = f"the run was {cut['message']}"
        if not cut["reached"]:
            return (f"not reached: {where}, before scan {cut['scan']} came to this pixel "
                    f"(its step would have been {cut['visit_step']})")
        return (f"visited by scan {cut['scan']} at step {cut['visit_step']}, but {where} "
                "before the scan's maps were recorded (at its end); of an unfinished scan "
                "only the dynamic, probed and sampled decisions are kept, and this pixel "
                "was none of them")
    if cut:
        return f"no scan reached it: the run was {cut['message']}"
    if h.get("ended_early"):
        # a file cut short (a copy interrupted, a disk full): read up to its last
        # complete message, which may lie inside a scan (a fresh-user trial's
        # head -c copy said "no scan reached it" above a history of patches there)
        return ("no decision about it is recorded: the recording ends before the run "
                "finished (cut short), and of an unfinished scan only the dynamic, "
                "probed and sampled decisions are kept; this pixel was none of them")
    return "no scan of this recording reached it"


_STEP_NAMES = {"refine": "the refinement", "fill by selection": "the fill by selection",
               "fused fill": "the fused fill", "fusion": "the fill"}


def after_scan_message(scan: int, more: bool, stage: str | None = None) -> str:
    """Where a run interrupted after scan ``scan`` had finished (its summary recorded)
    ends: "interrupted after the scans (during the refinement)", or "interrupted
    after scan 0, before scan 1 began" when ``more`` scans were to come. ``stage``:
    the CLI's "during refine", "after scan 0"... (a scan's end is said already)."""
    if more:
        return f"interrupted after scan {scan}, before scan {scan + 1} began"
    when, _, name = (stage or "").partition(" ")
    if when not in ("during", "after") or not name or name.startswith("scan"):
        return "interrupted after the scans"
    return f"interrupted after the scans ({when} {_STEP_NAMES.get(name, name)})"


def before_scans_message(stage: str | None = None) -> str:
    """Where a run interrupted before any scan started recording ends: "interrupted
    before the scans began (after correspondence)". A scan's own stage ("during scan
    0": the CLI's progress names the first scan as its set-up begins, before the
    scan records anything) is said as "as scan 0 was starting"."""
    when, _, name = (stage or "").partition(" ")
    if when in ("during", "after") and name.startswith("scan "):
        stage = f"as {name} was starting"
    return "interrupted before the scans began" + (f" ({stage})" if stage else "")


def more_scans(scan: int, n_dynamic: float, params: dict[str, Any]) -> bool:
    """Whether the scans go on after ``scan`` (as the driver decides: up to
    ``max_scans``, and only while a scan finds dynamic pixels)."""
    return scan + 1 < int(params.get("max_scans", 1)) and n_dynamic > 0


_STAGE_WORDS = {"clean": "the L clean-up", "votes": "the border votes",
                "snap": "GrabCut (snap to edges)", "select": "the fill by selection"}


def clean_rule_words(h: dict[str, Any]) -> str:
    """" (...)": which step of the L clean-up dropped the pixel (``h["clean_rule"]``
    from ``inspect.pixel_history``), or "" when it is not known."""
    cp = h.get("clean_params") or {}
    p, n = cp.get("patch_size"), cp.get("min_region_px")
    if h.get("clean_rule") == "opening" and p:
        return (f" (its opening, a disc of {max(1, int(p) // 4)} px radius: --patch-size "
                f"{p} // 4, erased it: the scans' map around it is a mesh or a strip "
                "thinner than the disc; where the set is flat, a majority filter keeps "
                "such a mesh that hangs on a solid part, not where it is 3-D: there it "
                "kept static 3-D structure; --no-clean-mask keeps the scans' map as it is, "
                "over the whole photo)")
    if h.get("clean_rule") == "small" and n:
        return (f" (its region was under --min-region-px {n} px after the opening; a "
                "smaller --min-region-px keeps such regions)")
    return ""


def verdict_lines(h: dict[str, Any]) -> list[str]:
    """A few lines (at most five, then the static 3-D test's in the history's head), in
    words: why the pixel ended up as it did.

    1. the scans' verdict with M vs t_r and what neighbouring patch writes had
       done to it before its turn; 2. the winning cluster A_m (size, sources,
       b_m), from the per-scan maps for any pixel, else from a recorded decision;
    3. what the post-scan steps did; 4. the fill (which source, or the reference
    kept); 5. ground truth, when recorded.
    """
    x, y, t_r = h["x"], h["y"], h["t_r"]
    dec = {d["scan"]: d for d in h["decisions"]}
    scans = h.get("scans") or [dict(scan=d["scan"], step=d["step"], M=d["M"],
                                    verdict="dynamic" if d["dynamic"] else "static",
                                    overwritten_before=None, first_overwritten=None,
                                    chosen_source=d["chosen_src"])
                               for d in h["decisions"]]
    lines = []
    dyn = [sc for sc in scans if sc["verdict"] == "dynamic"]
    key = dyn[0] if dyn else (scans[0] if scans else None)
    if key is None:
        lines.append(_not_reached(h))
    else:
        M = key["M"]
        if M != M:
            why = ("no cluster of candidates formed (undecided: no M to compare with "
                   "t_r, so the scan does not call it dynamic)")
        else:
            why = f"M = {m_text(M)} {_against_t_r(M, t_r)}"
        if dyn:
            head = f"dynamic in scan {key['scan']} (step {key['step']}): {why}"
            others = [sc["scan"] for sc in scans if sc is not key]
            if others:
                head += f"; scans {', '.join(map(str, others))}: " + ", ".join(
                    f"{sc['verdict']}" + (f" M {m_text(sc['M'])}" if sc["M"] == sc["M"] else "")
                    for sc in scans if sc is not key)
        else:
            head = (f"{key['verdict']} in every scan: scan {key['scan']} (step "
                    f"{key['step']}) {why}" if len(scans) > 1 else
                    f"{key['verdict']} in scan {key['scan']} (step {key['step']}): {why}")
            if len(scans) > 1:
                head += "; then " + ", ".join(
                    f"scan {sc['scan']} " + (f"M {m_text(sc['M'])}" if sc["M"] == sc["M"]
                                             else "no cluster") for sc in scans[1:])
        n = key.get("overwritten_before")
        if n:
            # ("in the scan's working copy": a trial read it as the clean photo's pixel
            # changing, at a pixel the clean photo keeps)
            # (which M does not read: it compares the pixel's own f_c and f_g, changed
            # only where the pixel itself is replaced; the README of session 45 and
            # this line had said the scan judged the content the patches left there)
            head += (f"; its content in the scan's working copy had been overwritten by {n} "
                     f"neighbouring patch{'es' if n > 1 else ''} before its turn (first at "
                     f"step {key['first_overwritten']}), which M does not read (see "
                     "'Overwritten' below)")
        elif n == 0:
            head += "; no neighbouring patch had overwritten it before its turn"
        lines.append(head)
        words = cluster_words(key, dec.get(key["scan"]), len(h["source_names"]))
        lines.append(words if words is not None else
                     "candidates and clusters were not recorded at this pixel (a recording "
                     f"without cluster maps): re-run with --probe {x},{y} to see them")
    st = h.get("stages") or {}
    if len(st) > 1:
        names = list(st)
        # which step of the clean-up dropped it, where no later step put it back
        later = [st[c] for c in names[names.index("clean") + 1:] if c != "select"] \
            if "clean" in st else []
        changes = [f"{'added' if st[b] else 'dropped'} by {_STAGE_WORDS.get(b, b)}"
                   + (clean_rule_words(h) if b == "clean" and not st[b] and not any(later)
                      else "")
                   for a, b in zip(names, names[1:]) if st[a] != st[b] and b != "select"]
        if names[-1] == "select" and len(names) > 2 and st["select"] != st[names[-2]]:
            # the fill changed L itself: say so, or "dropped by GrabCut; in the final
            # mask: yes" reads as a contradiction (a fresh-user trial)
            sel_ = h.get("selection") or {}
            if not st["select"]:
                changes.append("left out by the fill by selection (it kept the reference)")
            elif sel_.get("lingering"):
                changes.append("added back by the fill by selection: a mover that lingered, "
                               "or its cast shadow (--select-minority: the sources that saw "
                               "the background agree against the reference)")
            else:
                changes.append("added back by the fill by selection: " + _added_by(h))
        if changes:
            lines.append("after the scans: " + "; ".join(changes) +
                         f"; in the final mask: {'yes' if st[names[-1]] else 'no'}")
        else:
            kept = ", ".join(_STAGE_WORDS.get(b, b) for b in names[1:] if b != "select")
            lines.append(f"after the scans: still {_label(st[names[0]])}: not changed by {kept}")
    sel = h.get("selection") or {}
    if "source" in sel:
        k = sel["source"]
        others = "; ".join(f"{n}: {why}" for n, why in (sel.get("reasons") or {}).items()
                           if why not in ("chosen", REASONS[MISPLACED]))
        if sel.get("inpainted") and h.get("final_dynamic"):
            lines.append("fill: inpainted (OpenCV Telea): " + (
                f"{mp}'s view, chosen here, does not continue the photo kept around its "
                "part of the fill (--select-misplaced-de)" if (mp := _misplaced(sel))
                else "no source shows the background here")
                + (f" ({others})" if others else ""))
        elif k > 0:
            why = (" — a mover that lingered, or its cast shadow: the reference and most "
                   "sources show it, the sources that saw the background filled it"
                   if sel.get("lingering")
                   else " — the photomontage kept the reference here, but the rest of its "
                   "region of L was replaced (--select-complete): a piece of the same mover"
                   + (f"; {region}" if (region := region_words(sel)) else "")
                   if sel.get("completed") == 1 else "")
            if not h.get("final_dynamic"):
                why += (" — outside the final mask: the value written is within the fill's "
                        "--select-tau of the reference's (the margin the fill may change "
                        "around L)")
            off = sel.get("offset")
            if off and max(abs(c) for c in off) >= 1:
                # what the ring around the region asked for: exposure and light, or, when
                # large, a shadow or another object the ring saw (a trial read -115
                # levels as light)
                why += ("; the blend added B/G/R " + levels_words(off)
                        + " levels to it, to meet the reference around the region"
                        + (" (a large correction: the ring there differs from this source "
                           "by more than light does, e.g. a shadow, a wrong source, or part "
                           "of a mover left in the reference around the region)"
                           if max(abs(c) for c in off) >= _LARGE_OFFSET else
                           # (a trial read the light as the cause where the ring was the
                           # rest of a cup the fill had left: both ask for an offset)
                           f" ({_LIGHT_OR_REST})"))
                seam = sel.get("seam_blend")
                if seam and max(abs(c) for c in seam) >= 1:
                    why += (", of which " + levels_words(seam) + " blend the seam with the "
                            "next photo's patch, whose light differed (--select-seam-levels)")
            fx, fy = sel.get("fill_x"), sel.get("fill_y")
            # (where the fill's field across L leads, not the flow's match that the
            # static 3-D test reads: a trial read the two as a contradiction)
            plane = int(sel.get("planes") or 0) - 1
            at = (f" at ({fx:.1f}, {fy:.1f}) in it (where the fill's field across L leads"
                  + (f": plane {plane} of the ring around its region, the one on which "
                     "the sources agree best here, --select-planes" if plane > 0 else "")
                  + ")" if fx is not None and fy is not None else "")
            # a source in the scan's winning cluster that the fill turned down as
            # showing a mover: the scan's candidate and the fill's sample are two places
            # in it (a trial read them as a contradiction)
            # (a scan that called the pixel dynamic: its cluster was not the reference's
            # content; where it called it static, a lingering mover's sources agree)
            won = {n for sc in h.get("scans") or () if sc.get("verdict") == "dynamic"
                   for n in (sc.get("win_sources") or ())}
            mover = {n for n, r in (sel.get("reasons") or {}).items()
                     if r.startswith(("still shows", "its own mover", "shows the reference"))}
            both = sorted(won & mover)
            lines.append(f"fill: filled from source {_src_name(h, k - 1)}{at}{why}"
                         + (f" (others: {others})" if others else "")
                         + (f"; {', '.join(both)} in the scan's winning cluster above: its "
                            "candidate there, propagated from the neighbours' matches, lay "
                            "elsewhere in it than the fill's sample, which shows the mover"
                            if both else ""))
        elif sel.get("explained"):
            # ("parallax, not a mover" was read as a certainty by a trial where the
            # one source that showed it had the mover lingering there too)
            lines.append("fill: reference kept, explained as static 3-D structure: enough "
                         "sources show its content as the geometry expects (a mover that "
                         "stayed in place in those photos looks the same)")
        elif sel.get("completed") == 2:
            region = region_words(sel)
            lines.append("fill: reference kept — the photomontage took a source here, but "
                         + ("kept the reference on the rest of its region of L "
                            f"(--select-complete): static, as the rest; {region}" if region
                            else "this pixel, in the fill's margin outside L, only continued "
                            "the source of a region of L that keeps the reference whole "
                            "(--select-complete): it keeps it too"))
        elif sel.get("completed") == 3:
            off = sel.get("offset")
            would = (" (it would have added B/G/R " + levels_words(off)
                     + " levels here)" if off and max(abs(c) for c in off) >= 1 else "")
            lines.append("fill: reference kept — the photomontage took a source here, but "
                         "the blend would have had to shift that region's fill by more than "
                         "light does to meet the photo around it (--select-misfit-levels)"
                         + would + ", while the reference's pixels in that region have, "
                         f"on the whole, not the movers' colours (mean P(mover) under "
                         f"{MISFIT_MOVER_P:g}): "
                         "the source shows other content than the scene here, a static "
                         "part flagged in error")
        elif sel.get("completed") == 4:
            region = region_words(sel)
            lines.append("fill: reference kept — the photomontage took a source here, but it "
                         "replaced only part of this region of L, and the part it kept has "
                         "the movers' colours with no source showing it as the reference "
                         "does: the rest of a mover that no photo shows free, so the mover "
                         "is kept whole rather than left with holes (--select-keep-partial)"
                         + (f"; {region}" if region else ""))
        elif sel.get("relit"):
            # (a trial read "relit" on the first line and "reference kept" here as a
            # contradiction: the reference's texture is kept, its light is not)
            gain = sel.get("relight_l")
            lines.append("fill: no source's value; the reference's own texture, relit to the "
                         "other photos' light"
                         + (f" ({gain:+.1f} CIE L*)" if gain is not None else "")
                         + ": a faint shade beside the removed movers (--select-shade-de)"
                         + (" (not in the final mask: changed by under --select-tau)"
                            if not h.get("final_dynamic") else ""))
        else:
            lines.append("fill: reference kept" + (" (not in the final mask)"
                                                     if not h.get("final_dynamic") else ""))
    elif h.get("refill") and h.get("final_dynamic"):
        lines.append(f"fill: refilled after the scans by --fill median (the sources' "
                     f"{h['refill']} at their matches), not by the scans' patch writes")
    elif h["replacements"] or h.get("covered_by"):
        # the scans' writes are the output (no fill after them): the last patch
        # written over the pixel, centred on it or on a neighbour, is what it shows
        # (a trial read the first write at the pixel while a later scan's patch
        # from another source had covered it)
        writes = h["replacements"] + list(h.get("covered_by") or ())
        r = max(writes, key=lambda e: e["step"])
        sx, sy = r["src_x"] + h["x"] - r["x"], r["src_y"] + h["y"] - r["y"]
        if (r["x"], r["y"]) == (h["x"], h["y"]):
            where = f"written here at step {r['step']} (scan {r['scan']})"
        else:
            where = (f"by the patch written around ({r['x']},{r['y']}) at step {r['step']} "
                     f"(scan {r['scan']})")
        last = (f": the last of {len(writes)} writes over this pixel" if len(writes) > 1
                else "")
        if h.get("ended_early") and h.get("refill"):
            # (a trial's cut recording said "fill:" of a scan patch that the fill by
            # selection, past the cut, had redone from another source)
            lines.append(f"the scans' patch here: {r['src_name']}'s pixel ({sx},{sy}), "
                         f"{where}{last}; the recording ends before the fill after the "
                         "scans, which redoes the pixels it replaces: what the clean photo "
                         "shows here is not recorded")
        else:
            lines.append(f"fill: {r['src_name']}'s pixel ({sx},{sy}), {where}{last}")
    if h.get("gt") is not None:
        fin, gt = h.get("final_dynamic"), h["gt"]
        kind = ("correct" if fin == gt else "FALSE NEGATIVE (a mover left in)" if gt
                else "FALSE POSITIVE (static pixel replaced)")
        lines.append(f"final L {_label(fin)}, ground truth {_label(gt)}: {kind}")
    if len(lines) > 5:  # the fill and ground truth matter more than the clusters
        lines = lines[:1] + lines[-4:]
    return lines


# a filled pixel that the blend's correction took nearer the input than the chosen
# source's sample, and within this CIE76 ΔE of the input, "shows nearly what the
# reference showed" (twice the fill's --select-tau of 10: the input is the
# recording's JPEG)
_BACK_DE = 20.0


def _lab_de(a: list[int], b: list[int]) -> float:
    """CIE76 ΔE between two B, G, R colours (0–255), as the fill measures it."""
    lab = blurred_lab(np.array([[a, b]], np.uint8), 0.0)[0]
    return float(delta_e(lab[0], lab[1]))


def _misplaced(sel: dict[str, Any]) -> str | None:
    """The photo whose view of an inpainted pixel did not fit around its part of the
    fill (``select.misplaced_pieces``), or None: no source showed the pixel free."""
    return next((n for n, why in (sel.get("reasons") or {}).items()
                 if why == REASONS[MISPLACED]), None)


def _brought_back(h: dict[str, Any]) -> str:
    """Where the blend's offset took a filled pixel back near the input reference (a
    trial read "removed, filled from tim1" on a pixel still the cup's red: the ring
    around the region lay on the cup's kept parts), the words that say so; else ""."""
    got, off = h.get("clean_input"), (h.get("selection") or {}).get("offset")
    if not got or not off:
        return ""
    clean, ref = got
    sample = [min(255, max(0, c - o)) for c, o in zip(clean, off)]
    to_ref, to_sample = _lab_de(clean, ref), _lab_de(clean, sample)
    if to_ref >= _BACK_DE or to_ref >= to_sample:
        return ""
    return (f", but the blend's correction took it back near what the reference showed "
            f"here (ΔE {to_ref:.1f} from the input, {to_sample:.1f} from the source's "
            "sample): the clean photo still shows much of it")


def outcome_line(h: dict[str, Any]) -> str:
    """What became of the pixel, in a few words: "removed (in the final mask), filled
    from view1.png" or "kept (not in the final mask)". Needs ``final_dynamic``."""
    sel = h.get("selection") or {}
    k = sel.get("source", 0)
    if not h.get("final_dynamic"):
        if sel.get("relit"):
            gain = sel.get("relight_l")
            return ("kept (not in the final mask), relit: a faint shade that the other "
                    "photos see lit, given their light"
                    + (f" ({gain:+.1f} CIE L*)" if gain is not None else "")
                    + " with this photo's own texture (--select-shade-de)")
        if k > 0 and not sel.get("inpainted"):
            # the fill's margin or a seam: a source's value written within ΔE
            # select_tau of the reference's, so not counted in the final mask
            return (f"not in the final mask, but written from {_src_name(h, k - 1)}, "
                    "close to the reference's colour (the fill's margin around L)")
        return "kept (not in the final mask)"
    if sel.get("inpainted"):
        if mp := _misplaced(sel):
            return (f"removed (in the final mask), inpainted: {mp}'s view of it was "
                    "misplaced")
        return "removed (in the final mask), inpainted: no source shows the background there"
    if k > 0:
        return f"removed (in the final mask), filled from {_src_name(h, k - 1)}" + _brought_back(h)
    if "source" in sel:
        return "in the final mask, but the reference kept there"
    return "removed (in the final mask)"


# the update cases of Sec. 3.2.3 (``events.CASE_*``)
_CASE_WORDS = {
    CASE_ONE_IN_CLUSTER: "case 1: one of the source's two candidates in A_m",
    CASE_BOTH_IN_CLUSTER: "case 2: both in A_m, the better by the geometry",
    CASE_GEOMETRY: "case 3: neither in A_m, the source occluded there: by the geometry"}

LEGEND = ("(M: how alike the pixel and the winning cluster A_m of its candidate matches "
          "are, Sec. 3.2.1; at or under t_r it is called dynamic. b_m: A_m's weight, the "
          "sum of its candidates' confidences B_l. Overwritten: each dynamic pixel's "
          "chosen patch q* is written into the scan's working copy as the scan goes (what "
          "the viewer shows), and f_c and f_g are updated at that pixel only (Sec. 3.2.2); "
          "M compares a pixel's own f_c and f_g, so its neighbours' writes do not enter its "
          "M: they reach its decision through the matches N and confidences C that their "
          "updates changed (Sec. 3.2.3), which give its candidates, and, if it is called "
          "dynamic, through the patch chosen to overlap them. "
          "step: the visiting order, the viewer's `step` timeline)")

VOTES_LEGEND = ("(the border votes: the scan decides on whole patches, so its map overshoots "
                "or stops short of an object's outline; along the map's border each pixel is "
                "put to the sources, sampled through the background behind the map: a pixel "
                "just outside it that no source agrees with is added, one just inside that "
                "most sources agree with is dropped)")


def _fold(events: list[tuple[int, str]], max_lines: int) -> list[str]:
    """Sort by step; print at most ``max_lines`` lines, eliding the middle."""
    events.sort(key=lambda e: e[0])
    lines = [t for _, t in events]
    if len(lines) > max_lines:
        k = max_lines // 2
        lines = lines[:k] + [f"  … {len(lines) - 2 * k} more lines …"] + lines[-k:]
    return lines


def region_words(sel: dict[str, Any]) -> str | None:
    """The region rule (--select-complete) in numbers at a pixel of L that no static
    evidence explained: the share of its region of L that the graph cut replaced,
    against the run's share; None where the recording has no share there."""
    f = sel.get("region_share")
    if f is None:
        return None
    rule = sel.get("region_rule") or {}
    share, px = rule.get("select_complete"), rule.get("select_complete_px")
    head = f"the graph cut replaced {100 * f:.0f} % of its region of L"
    if not isinstance(share, float) or share != share or share <= 0:
        return head + " (--select-complete 0: no region rule)"
    lo, hi = 100 * (1 - share), 100 * share
    if f >= share:
        tail = f"at least {hi:.0f} % (--select-complete {share:g}): a mover, replaced whole"
        if sel.get("source", 0) == 0 and not sel.get("completed"):
            reach = (f"{px:g} px" if isinstance(px, (int, float)) and px == px
                     else "its reach")
            tail += (f", but this pixel is farther than --select-complete-px {reach} from "
                     "its replaced pixels, or no source next to it may fill it")
    elif f < 1.0 - share:
        tail = (f"under {lo:.0f} % (1 − --select-complete {share:g}), counting the "
                "region's pixels that the static 3-D test explained as kept: static, the "
                "reference kept whole")
    elif sel.get("completed") == 4:
        tail = f"between {lo:.0f} and {hi:.0f} %"
    else:
        tail = f"between {lo:.0f} and {hi:.0f} %: each pixel as the cut decided"
    return f"{head} ({tail})"


def weighed_words(sel: dict[str, Any], n_sources: int = 0) -> str | None:
    """What the graph cut weighed at a pixel of the fill's region: the data costs of
    the reference and of the cheapest source, and the supports of the fill's colour
    consensus that set them; None where the recording has no costs there."""
    cost, sup = sel.get("data_cost") or {}, sel.get("support") or {}
    if "reference" not in cost:
        return None
    # (a trial read the κ and γ terms as the reference's too)
    txt = f"data cost of the reference {cost['reference']:.1f} (its ΔE to the consensus), " + (
        f"of the cheapest source {cost['best_source']:.1f} (its ΔE to the consensus, plus "
        "--select-kappa and --select-gamma × its P(mover), which only a source pays)"
        if "best_source" in cost else "no source may fill it")
    if "reference" in sup and "sources" in sup:
        txt += (f"; the consensus: the reference's support {sup['reference']:.2f} (its "
                "weight 1 − P(mover), plus each source that agrees with it or votes it "
                f"static by flow or epipolar line) against {sup['sources']:.2f} for the "
                "best-supported source (each weight, 0–1, counts a photo)")
        if sup["reference"] >= sup["sources"]:
            # (a trial had to read the code to learn why a cup stayed: the sources of a
            # three-photo set disagreed, one showing the table, one its own cup; and
            # another read "the most backing" of 1.49 against 1.49: a tie, which the
            # reference wins, ``select_fill``'s consensus)
            tied = f"{sup['reference']:.2f}" == f"{sup['sources']:.2f}"
            txt += ("; in short: the other photos do not agree with one another on "
                    "anything else here, so what the reference shows "
                    + ("ties with the best-supported source, and a tie keeps the "
                       "reference" if tied else "has the most backing and stays")
                    + (" (with three photos, two sources that disagree with each other "
                       "cannot outvote the reference; more photos can)"
                       if n_sources == 2 else ""))
    else:
        txt += ("; the reference was the suspect here: the consensus is the sources' own, "
                "and keeping the reference costs --select-ref-cost, or, where it agrees "
                "with that consensus (ΔE under --select-tau), its distance to it plus "
                "--select-gamma × its P(mover)")
        if cost["reference"] == 0:
            txt += ("; here nothing: no majority of the photos says that it shows the "
                    "mover (no two photos agree, or both sources of three show a mover, "
                    "or, of two photos, the movers' colour model does not single it out), "
                    "and it has not the movers' colour")
    return txt


def static_test_line(h: dict[str, Any]) -> str | None:
    """The fill's static 3-D structure test at a pixel of L, in words (None outside
    L or for a run without it): how many sources had to show the reference's content
    as static, which did and how (the flow match, or the epipolar search's best
    CIE76 ΔE against --select-search-de, and where on the source's epipolar line
    that best match lies, in the source's pixels), why the others did not, grouped, and
    whether the reference's colour, being a mover's, decided it anyway
    (``select.EVIDENCE``)."""
    sel = h.get("selection") or {}
    ev, need = sel.get("evidence") or {}, sel.get("static_need", 0)
    if not ev or not need:
        return None
    de = sel.get("line_de") or {}
    lx, ly = sel.get("line_x") or {}, sel.get("line_y") or {}
    search_de = (sel.get("thresholds") or {}).get("select_search_de")
    against_de = (sel.get("thresholds") or {}).get("select_search_against_de")
    against_on = isinstance(against_de, float) and against_de > 0
    near = f" and something within ΔE {against_de:.1f} on its epipolar line" if against_on else ""

    def on_line(n: str) -> str:
        at = f" at ({lx[n]:.0f}, {ly[n]:.0f}) in it" if n in lx and n in ly else ""
        # the search caps each cell's distance (``parallax.SEARCH_CAP_DE``): "30.0" is
        # "nothing alike", not a measured 30 (a trial read it as a figure)
        return (f" (ΔE ≥ {_LINE_CAP:.0f}, nothing alike{at})" if de[n] >= _LINE_CAP - 0.05
                else f" (ΔE {de[n]:.1f}{at})")

    def named(code: int) -> list[str]:
        return [n + (on_line(n) if code in (2, 3, 5, 7, 8) and n in de else "")
                for n, c in ev.items() if c == code]

    groups = [(1, "its flow match shows it"),
              (2, "found on the epipolar line"),
              (3, "found on the epipolar line, but too few others are for that to count "
                  "while another source that sees it shows something else"
                  + (f" (outside the movers' colours, or with nothing within ΔE "
                     f"{against_de:.1f} on its line: no copy of the mover)"
                     if against_on else "")),
              # (a trial read "0 count (its flow match agrees ...)" as a contradiction)
              (4, "not counted: its flow match agrees, but in the movers' colours, so it "
                  "may show its own copy of the mover"),
              (5, "not found: its flow match differs"
                  + (f", and nothing on the epipolar line is within ΔE {search_de:.1f}"
                     if isinstance(search_de, float) and search_de == search_de
                     and any(n in de for n, c in ev.items() if c == 5) else "")),
              (6, "outside the frame"),
              (7, "found on the epipolar line, but as well elsewhere on it (a plain "
                  "colour along the line; --select-search-unique), and the other source "
                  "found nothing: that does not count alone"),
              (8, "found on the epipolar line beyond the parallax the flow followed, at "
                  "a depth that keypoints beside it show (--select-search-beyond-px)")]
    parts = [f"{what}: {', '.join(who)}" for code, what in groups if (who := named(code))]
    counted = sum(c in (1, 2, 8) for c in ev.values())
    passed = bool(sel.get("explained"))
    if ({2, 8} & set(ev.values())) and sum(c in (1, 2, 4, 8) for c in ev.values()) < max(2, need):
        # (``select_fill``: the epipolar search's weaker evidence counts from one
        # source where no other source that sees the pixel contradicts it)
        # (a trial read "no other source contradicts it" beside another source's
        # "nothing alike" on the line, which showed plain wall: the rule's words now)
        parts.append("the epipolar search's evidence counts from one source here: every "
                     "other source that did not find the content shows the movers' "
                     f"colours at its flow match{near}; the rule cannot tell that from "
                     "a copy of the mover in that photo hiding the content (it assumes "
                     "one, whether or not the photo shows the mover), so it is not "
                     "counted as a contradiction")
    # ("3 of the 2 needed" read as a bug to a trial: more may count than are needed)
    evidence = (f"{counted} source{'s count' if counted != 1 else ' counts'} as showing the "
                f"reference's content here, {need} needed (" + "; ".join(parts) + ")")
    p = sel.get("ref_mover_p")
    if passed:
        why_not = ""
    elif p is not None and p >= 0.5 and counted >= need:
        why_not = (f"; the reference's colour is the movers' (P {p:.2f} ≥ 0.5), which "
                   "overrules that")
    elif p is not None and p >= 0.5:
        why_not = f"; and the reference's colour is the movers' (P {p:.2f} ≥ 0.5)"
    elif sel.get("lingering"):
        why_not = "; a mover that lingered: the sources that saw the background decide"
    else:
        why_not = ""
    replaced = bool(h.get("final_dynamic")) and sel.get("source", 0) > 0
    if passed and p is not None and p >= 0.5:  # (only a flat set keeps such a pixel)
        evidence += (f"; the reference's colour is the movers' (P {p:.2f} ≥ 0.5), but in a "
                     "flat set two or more such matches count whatever the colour")
    if passed and not replaced:
        return "static 3-D structure test: kept as static: " + evidence
    if passed:
        return ("static 3-D structure test: passed (" + evidence + "), yet the fill's "
                "candidates here, sampled through the sources' fields across L, disagree "
                f"with the reference, and the photomontage took {_src_name(h, sel['source'] - 1)}")
    if replaced:
        region = region_words(sel) if not sel.get("completed") else None
        return ("static 3-D structure test: not passed: " + evidence + why_not
                + (f"; {region}" if region else ""))
    if sel.get("completed") == 2:
        return ("static 3-D structure test: not passed (" + evidence + why_not + "); the "
                "photomontage took a source here, but the reference is kept with the rest "
                "of its region of L, which the photomontage kept (--select-complete)")
    if sel.get("completed") == 3:
        return ("static 3-D structure test: not passed (" + evidence + why_not + "); the "
                "photomontage took a source here, but the reference is kept: the fill did "
                "not fit the photo around its region (--select-misfit-levels)")
    if sel.get("completed") == 4:
        return ("static 3-D structure test: not passed (" + evidence + why_not + "); the "
                "reference is kept all the same, with the rest of its mover (see the fill "
                "line)")
    region = region_words(sel)
    weighed = weighed_words(sel, len(h.get("source_names") or []))
    cost = sel.get("data_cost") or {}
    dearer = ("reference" in cost and "best_source" in cost
              and cost["reference"] > cost["best_source"])
    why_kept = ("though a source cost less here by itself, changing label from its kept "
                "neighbours costs more (the seams, --select-beta)" if dearer else
                "it was the cheapest label here")
    return ("static 3-D structure test: not passed (" + evidence + why_not + "), but the "
            f"photomontage kept the reference: {why_kept} (its distance to the sources' "
            "consensus, with the seams" + (f": {weighed}" if weighed else "")
            + ")" + (f"; {region}" if region else ""))


# what each step after the scans does, for a non-expert (``plain_words``)
_STAGE_PLAIN = {"clean": "the clean-up of the scans' map (it fills small gaps and drops "
                         "specks)",
                "votes": "the check of the region's border against the other photos",
                "snap": "the snapping of the region to the edges in the photo",
                "select": "the fill, which takes or leaves whole parts of an object"}


def plain_words(h: dict[str, Any]) -> str | None:
    """Why the pixel ended up as it did, in one sentence without the paper's symbols
    (two fresh-user trials found the lines below it hard going for a non-expert),
    or None where no scan reached it. Needs ``final_dynamic``. The counts are the
    scans' (how many of the other photos the trusted group of matches comes from),
    so that a group of two photos out of five is not read as "the other photos"
    (a third trial)."""
    scans = h.get("scans") or [dict(verdict="dynamic" if d["dynamic"] else "static",
                                    win_sources=None) for d in h["decisions"]]
    fin = h.get("final_dynamic")
    if not scans or fin is None:
        return None
    sel = h.get("selection") or {}
    k = sel.get("source", 0)
    n_src = len(h.get("source_names") or ())
    moved = any(sc["verdict"] == "dynamic" for sc in scans)
    st = h.get("stages") or {}
    names = list(st)
    adders = [_STAGE_PLAIN.get(b, b) for a, b in zip(names, names[1:]) if st[b] and not st[a]]
    droppers = [_STAGE_PLAIN.get(b, b) for a, b in zip(names, names[1:])
                if st[a] and not st[b]]
    if fin:
        if sel.get("lingering") and k > 0:
            return (f"something that moved but stayed in place in most of the photos; "
                    f"{_src_name(h, k - 1)}, which saw the scene behind it, fills the spot")
        why = ("the photos whose matches the scans trust most here do not show what this "
               "photo shows, so it counts as part of something that moved" if moved else
               "the scans did not flag it, but " + (adders[-1] if adders else "a later step")
               + " added it to what was found moving (see 'after the scans' below)")
        if sel.get("inpainted"):
            if mp := _misplaced(sel):
                return (f"{why}; {mp} shows this spot free, but its view of it does not "
                        "line up with the photo around it, so the clean photo paints it in "
                        "from around it")
            return (f"{why}; no other photo shows this spot free of moving things, so the "
                    "clean photo paints it in from around it")
        if k > 0:
            return f"{why}; the clean photo shows {_src_name(h, k - 1)}'s view of the spot"
        return why
    if sel.get("relit"):
        return ("it is not counted as moving, but it lies in a faint shade beside what was "
                "removed (a soft shadow it cast, most likely), which the other photos show "
                "lit: the clean photo keeps this photo's texture there and takes their light")
    if k > 0 and not sel.get("inpainted"):
        return (f"it is not counted as moving, but it lies on the edge of a filled region, "
                f"where the clean photo blends in {_src_name(h, k - 1)}'s view of the spot, "
                "close to this photo's colour")
    hedge = ("; an object that stayed in place in those photos would look the same")
    if sel.get("explained"):
        return ("some of the other photos show this content where the cameras' positions "
                "say they should (see the static 3-D test below), so it counts as the scene "
                "and stays as the photo shows it" + hedge)
    if moved:
        return ("the scans took it for part of something that moved, but "
                + (droppers[-1] if droppers else "a later step")
                + " left it out (see 'after the scans' and 'fill' below), so it stays as "
                "the photo shows it")
    if all(sc["verdict"] == "undecided" for sc in scans):
        # (a trial: at the frame's corner, with no candidate or one, "agree on
        # nothing" read as a disagreement where there was nothing to compare)
        ns = [sc.get("n_candidates") for sc in scans]
        most = max(ns) if ns and None not in ns else None
        if most == 0:
            return ("no other photo sees this spot (its matches fall outside them, as at "
                    "the frame's edge), so there is nothing to compare it with, and it "
                    "stays as the photo shows it")
        if most == 1:
            return ("only one of its matches falls inside another photo, too few to agree "
                    "on anything (as at the frame's edge), so the scans could not call it "
                    "moving, and it stays as the photo shows it")
        return ("its matches in the other photos agree on nothing, so the scans could not "
                "call it moving, and it stays as the photo shows it")
    win = next((sc.get("win_sources") for sc in scans if sc.get("win_sources")), None)
    if not win:
        return ("the photos whose matches the scans trust most here show what this photo "
                "shows, so it counts as part of the scene and stays as the photo shows it")
    few = n_src and 2 * len(win) <= n_src
    return (f"{len(win)} of the {n_src} other photos ({', '.join(win)}) "
            + ("shows" if len(win) == 1 else "show") + " here what this "
            "photo shows, and the scans trust their matches most, so it counts as part of "
            "the scene and stays as the photo shows it"
            + ("; the others show something else here" + hedge if few else ""))


def format_pixel_history(h: dict[str, Any], *, max_lines: int = 30,
                         seen_legends: set[str] | None = None) -> str:
    """The verdict in words (≤ 5 lines), then the steps that changed the pixel.

    Runs of patch writes over the pixel are folded into one line per scan;
    the whole text stays within ``max_lines`` lines. With ``seen_legends`` (a set,
    updated here), a glossary already in it is not repeated: several pixels of one
    ``inspect`` call give each glossary once.
    """
    verdict = verdict_lines(h)
    fin = h.get("final_dynamic")
    if fin is None or not (h.get("scans") or h["decisions"]):
        lines = [f"pixel ({h['x']}, {h['y']}): " + verdict[0]]
    else:  # the outcome first, then how the scans and the steps after them got there
        plain = plain_words(h)
        lines = [f"pixel ({h['x']}, {h['y']}): " + outcome_line(h)]
        lines += [f"  in plain words: {plain}"] if plain else []
        lines.append("  the scans: " + verdict[0])
    lines += ["  " + v for v in verdict[1:]]
    st = static_test_line(h)
    if st is not None:
        lines.append("  " + st)
    for legend, needed in ((LEGEND, any(("M = " in ln or "b_m" in ln) for ln in lines)),
                           (VOTES_LEGEND, any("by the border votes" in ln for ln in lines))):
        if needed and (seen_legends is None or legend not in seen_legends):
            lines.append("  " + legend)
            if seen_legends is not None:
                seen_legends.add(legend)
    ev: list[tuple[int, str]] = []
    dec_scans = {d["scan"] for d in h["decisions"]}
    for sc in h.get("scans", []):
        if sc["scan"] in dec_scans:
            continue
        M = sc["M"]
        mtxt = "no cluster" if M != M else f"M {m_text(M)} {_against_t_r(M, h['t_r'])}"
        cw = cluster_words(sc, None, len(h["source_names"]), short=True)
        ev.append((sc["step"], f"  scan {sc['scan']} step {sc['step']}: {sc['verdict']} "
                               f"({mtxt}{'; ' + cw if cw and M == M else ''}; "
                               "from the per-scan maps)"))
    for d in h["decisions"]:
        if d["M"] != d["M"]:
            verdict = f"no cluster → {'DYNAMIC' if d['dynamic'] else 'undecided'}"
        else:
            verdict = (f"M {m_text(d['M'])} {_against_t_r(d['M'], d['t_r'])} → "
                       f"{'DYNAMIC' if d['dynamic'] else 'static'}")
        cd = d["consensus_dist"]
        txt = (f"  scan {d['scan']} step {d['step']}: {verdict} [{'+'.join(d['why'])}]; "
               + candidate_counts(d)
               + (f"; squared SIFT distance to A_m's weighted mean f̂_g {cd:.3f}" if cd == cd
                  else "")
               # M term by term (a trial: "the colour term is about 0" was what a
               # teacher needed to say, and nothing said it)
               + (f"; M = colour term {d['m_terms'][0]:.2f} + SIFT term "
                  f"{d['m_terms'][1]:.2f} (λ4 {d['m_terms'][2]:.2f} × S_e of the Lab "
                  f"distance to f̂_c, λ5 {d['m_terms'][3]:.2f} × S_e of that SIFT "
                  "distance; each S_e is 1 where the two agree)" if d.get("m_terms") else ""))
        ev.append((d["step"], txt))
    for r in h["replacements"]:
        # (the scan's own fill, which the fill by selection redoes: "fill:" above)
        ev.append((r["step"], f"  scan {r['scan']} step {r['step']}: the scan wrote the patch "
                              f"of {r['src_name']} at ({r['src_x']},{r['src_y']}) here"
                              + (" (the scan's own fill, redone by the fill by selection: "
                                 "its \"fill:\" line above is what the clean photo shows)"
                                 if "source" in (h.get("selection") or {}) else "")
                              + f", patch score {r['score']:.2f}"
                              # (n_patches counts A_m's patches tied at the best score,
                              # not its candidates: "the only candidate patch" beside
                              # "4 of 12 candidates" read as a contradiction to a trial)
                              + (f" (a tie-break among the {r['n_patches']} patches of "
                                 "A_m with that score)" if r["n_patches"] > 1
                                 else " (the best of A_m's patches)")))
    by_scan: dict[int, list[dict]] = {}
    for r in h["covered_by"]:
        by_scan.setdefault(r["scan"], []).append(r)
    own = {sc["scan"]: sc["step"] for sc in h.get("scans", [])}
    own.update({d["scan"]: d["step"] for d in h["decisions"]})
    for scan, rs in by_scan.items():
        steps = [r["step"] for r in rs]
        srcs = sorted({r["src_name"] for r in rs})
        n_before = sum(1 for st in steps if scan in own and st < own[scan])
        ev.append((min(steps), f"  scan {scan} steps {min(steps)}–{max(steps)}: overwritten "
                               f"by {len(rs)} patches centred nearby ({', '.join(srcs)})"
                   + (f", {n_before} of them before its own step {own[scan]}"
                      if scan in own else "")))
    n_upd = len(h["updates"])
    if n_upd:
        u0 = h["updates"][0]
        cases = sorted({int(u["case"]) for u in h["updates"]})
        ev.append((u0["step"], f"  {n_upd} correspondence updates at this pixel (Sec. 3.2.3: "
                               + "; ".join(_CASE_WORDS.get(c, f"case {c}") for c in cases)
                               + ")"))
    st = h.get("stages") or {}
    if st:
        last = max([sc["step"] for sc in h.get("scans", [])] + [e for e, _ in ev] + [0])
        n_scans = len(h.get("scans", [])) or (1 + max([d["scan"] for d in h["decisions"]],
                                                       default=0))
        H, W = h.get("size", (0, 0))
        first_stage = n_scans * H * W if H and W else last + 1
        ev.append((first_stage, "  L after each step: " + " → ".join(
            f"{k} {_label(v)} (step {first_stage + i})" for i, (k, v) in enumerate(st.items()))))
    tail = []
    cut = h.get("interrupted")
    if h.get("final_dynamic") is not None:
        fin = f"final L = {_label(h['final_dynamic'])}"
        if h.get("gt") is not None:
            fin += f", ground truth = {_label(h['gt'])}"
        tail.append("  " + fin)
    elif ev:  # (without a history, the first line has said where the run ends)
        tail.append(f"  no final L: the run was {cut['message']}" if cut else
                    "  no final L: the recording ends before the run finished")
    photo = h.get("photo")
    if photo:
        tail.append(f"  ({_analysis_note(h['size'], photo)})")
    if not ev:  # nothing changed it: no empty history
        return "\n".join(lines + tail)
    lines.append("history (jump to a step on the `step` timeline):")
    lines += _fold(ev, max_lines - len(lines) - len(tail))
    return "\n".join(lines + tail)


def _analysis_note(size: tuple[int, int], photo: tuple[int, int]) -> str:
    """"pixels of the WxH analysis image; the photos are W0xH0, analysed at ×s"."""
    H, W = size
    return (f"pixels of the {W}x{H} analysis image; the photos are {photo[0]}x{photo[1]}, "
            f"analysed at ×{W / photo[0]:.3g}")


# -- failures ----------------------------------------------------------------------


# ``inspect.failure_cause``'s causes, in words
FAILURE_CAUSES = {
    "never": "never flagged (the scans and the steps after them left it)",
    "scan": "flagged by the scans",
    "explained": "kept as static 3-D structure (the sources show its content where the "
                 "geometry expects)",
    "misfit": "kept: its fill did not fit the photo around it (--select-misfit-levels)",
    "region": "kept with its region of L (--select-complete)",
    "partial": "kept whole with its mover, which the fill could replace only in part "
               "(--select-keep-partial)",
    "lingering": "added as a mover that lingered (--select-minority)",
}


def failure_words(why: str, share: float) -> str:
    """``inspect.failure_cause``'s cause in words, with the share of the region it
    holds where that is not all of it (a trial could not tell which flagged regions
    a rule had kept, nor why)."""
    verb, _, stage = why.partition(":")
    if verb in ("dropped", "added") and stage:
        words = (f"{verb} by {_STAGE_WORDS.get(stage, stage)}"
                 + (" (it kept the reference)" if why == "dropped:select" else ""))
    else:
        words = FAILURE_CAUSES.get(why, why)
    return words if share >= 0.995 else f"{100 * share:.0f} % of it {words}"


def format_failures(items: list[dict[str, Any]]) -> str:
    """One line per failure region."""
    lines = ["region (kind, area, box: top-left x,y and width x height), a pixel in it "
             "(of the share named first below), the steps at which each scan visited that "
             "pixel (one per scan; jump to them on the `step` timeline), the pixel in it "
             "whose M looked most as the region wrongly is, over every scan's M map (a "
             "missed region's highest M, a false alarm's lowest: at or under t_r a scan "
             "calls a pixel dynamic), and what made the region so, its largest shares "
             "first:"]
    for e in items:
        x0, y0, w, h = e["bbox"]
        steps = ", ".join(str(s) for s in e.get("steps", []))
        ph = e.get("photo_pixel")
        s = (f"{e['kind']} {e['area']:6d} px  box ({x0},{y0}) {w}x{h} px  pixel "
             f"{e['pixel'][0]},{e['pixel'][1]}"
             + (f" (photo {ph[0]},{ph[1]})" if ph else "")
             + f"  steps {steps}; {e['n_decisions']} recorded decision"
             + ("" if e["n_decisions"] == 1 else "s"))
        if e["worst"]:
            s += (f"; {'highest' if e['kind'] == 'FN' else 'lowest'} M {e['worst']['M']:.2f} at "
                  f"({e['worst']['x']},{e['worst']['y']}) step {e['worst']['step']}")
        if e.get("why"):
            s += f"; {failure_words(e['why'], e.get('why_share', 1.0))}"
            s += "".join(f"; {failure_words(c, f)}" for c, f in e.get("why_more", []))
        lines.append(s)
    if items and items[0].get("photo"):
        lines.append(f"({_analysis_note(items[0]['size'], items[0]['photo'])}: --pixel "
                     "takes these; \"photo X,Y\" is the same pixel in the photo)")
    if items:
        lines.append("explain one: dynremove inspect REC --pixel X,Y; in the viewer, type "
                     "the step into the time panel's `step` field")
    return "\n".join(lines)

"""The default layout of a dynremove recording (sent with every recording).

::

    ┌ reference + overlays ───────────┬ L | M | errors ─────────────────┐
    │ image, L, decisions, current +  ├ per scan | input | fill ────────┤
    │ its verdict, chosen patch, line │                                 │
    ├ sources | similarity | coverage ┼ counts | Jaccard | seconds ─────┤
    │ image + candidates + q* + dim   ├ log | read M | run ─────────────┤
    │ matches of the previous chunk   │                                 │
    └─────────────────────────────────┴─────────────────────────────────┘

Every container and view has a title, and no tab group holds more than three
short-titled tabs, so none hides behind the tab bar's overflow arrow (checked on
a 1600×900 headless Chromium screenshot). Views are named by
the image's file name first (narrow titles are cut from the right). The time
panel is on ``step`` and plays a whole scan in about a minute.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from viewer import paths as P

SCAN_SECONDS = 60.0  # default playback: one scan (H·W steps) in about a minute


def _reference_view(p: P.Paths, name: str = "reference + overlays") -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        name=name,
        origin=p(P.REFERENCE),
        contents=[p(P.REFERENCE_IMAGE), p(P.REFERENCE_DYNAMIC),
                  p(P.REFERENCE_DECISIONS) + "/**", p(P.REFERENCE_CURRENT),
                  p(P.REFERENCE_CURRENT_LABEL), p(P.REFERENCE_CHOSEN_PATCH),
                  p(P.REFERENCE_SCANLINE)],
    )


def _dynamic_view(p: P.Paths, name: str = "L") -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name=name, origin=p(P.REFERENCE),
                             contents=[p(P.REFERENCE_DYNAMIC), p(P.REFERENCE_SCANLINE)])


def _maps(p: P.Paths, *, errors: bool = True) -> rrb.Tabs:
    # "errors" (L against the ground truth) only where the run has one (``run --gt``)
    return rrb.Tabs(
        _dynamic_view(p),
        rrb.Spatial2DView(name="M", origin=p(P.REFERENCE),
                          contents=[p(P.REFERENCE_M), p(P.REFERENCE_SCANLINE),
                                    p(P.REFERENCE_CURRENT), p(P.REFERENCE_CURRENT_LABEL)]),
        *([rrb.Spatial2DView(name="errors", origin=p(P.REFERENCE),
                             contents=[p(P.REFERENCE_IMAGE), p(P.ERRORS_LABELS),
                                       p(P.ERRORS_LEGEND), p(P.REFERENCE_SCANLINE)])]
          if errors else []),
        name="maps",
    )


def _more(p: P.Paths, names: Sequence[str] = ()) -> rrb.Tabs:
    per_scan = rrb.Grid(
        rrb.Spatial2DView(name="M (lossless)", origin=p(P.SCAN_MAPS),
                          contents=[p(P.scan_map("M")), p(P.scan_map("undecided"))]),
        rrb.Spatial2DView(name="verdict", origin=p(P.scan_map("verdict"))),
        rrb.Spatial2DView(name="patch source", origin=p(P.scan_map("chosen_source"))),
        rrb.Spatial2DView(name="overwritten before",
                          origin=p(P.scan_map("overwritten_before"))),
        # the core's decision: b_m = Σ B_l of A_m, |A_m|, A_m's sources, |P|, k
        rrb.Spatial2DView(name="b_m", origin=p(P.scan_map("b_m"))),
        rrb.Spatial2DView(name="|A_m|", origin=p(P.scan_map("win_size"))),
        rrb.Spatial2DView(name="A_m src", origin=p(P.scan_map("win_sources"))),
        rrb.Spatial2DView(name="|P|", origin=p(P.scan_map("n_candidates"))),
        rrb.Spatial2DView(name="k", origin=p(P.scan_map("n_clusters"))),
        grid_columns=3, name="per scan")
    return rrb.Tabs(
        per_scan,
        rrb.Spatial2DView(name="input", origin=p(P.REFERENCE),
                          contents=[p(P.REFERENCE_INPUT), p(P.REFERENCE_DYNAMIC),
                                    p(P.GT_MASK), p(P.GT_BACKGROUND)]),
        rrb.Spatial2DView(name="fill", origin=p("result"),
                          contents=[p(P.RESULT_CLEAN), p(P.RESULT_SOURCE), p(P.RESULT_SEAMS),
                                    p(P.ERRORS_BACKGROUND)]),
        # what the blend added to the chosen sources (grey: nothing; tinted: a colour
        # or light correction), over the clean photo
        rrb.Spatial2DView(name="blend offset", origin=p("result"),
                          contents=[p(P.RESULT_CLEAN), p(P.RESULT_OFFSET)]),
        # the part of it that blended the steps of light where two sources meet
        rrb.Spatial2DView(name="seam blend", origin=p("result"),
                          contents=[p(P.RESULT_CLEAN), p(P.RESULT_SEAM_BLEND)]),
        # inside L: which sources show the reference's content as static, and how
        # (green: they count; red: not found; hover a pixel for the words)
        rrb.Grid(*[rrb.Spatial2DView(
            name=f"static test: {n}", origin=p("result"),
            contents=[p(P.RESULT_CLEAN), p(f"{P.RESULT_EVIDENCE}/{n}")]) for n in names],
            rrb.Spatial2DView(name="sources needed", origin=p("result"),
                              contents=[p(P.RESULT_CLEAN), p(P.RESULT_STATIC_NEED)]),
            grid_columns=3, name="static 3-D test"),
        # each source's own movers (it never fills there) and why it did or did not
        # fill each pixel (hover for the words): issue 10's per-view mover maps (a
        # trial found them recorded but in no view)
        rrb.Grid(*[rrb.Spatial2DView(
            name=f"{n}: movers, why", origin=p("result"),
            contents=[p(P.RESULT_CLEAN), p(f"{P.RESULT_REASONS}/{n}"),
                      p(f"{P.RESULT_MOVERS}/{n}")]) for n in names],
            grid_columns=3, name="per source"),
        # the fill's own decisions over the clean photo: kept as static 3-D structure,
        # a mover that lingered, inpainted (no source free), decided with its region
        rrb.Grid(*[rrb.Spatial2DView(name=name, origin=p("result"),
                                     contents=[p(P.RESULT_CLEAN), p(ent)])
                   for name, ent in (("kept as static 3-D", P.RESULT_EXPLAINED),
                                     ("lingering mover", P.RESULT_LINGERING),
                                     ("inpainted", P.RESULT_INPAINTED),
                                     ("faint shade relit", P.RESULT_RELIT),
                                     ("decided with its region", P.RESULT_COMPLETED),
                                     ("field across L: planes", P.RESULT_PLANES))],
                 grid_columns=2, name="fill decisions"),
        name="more maps",
    )


def _source_view(p: P.Paths, name: str, s: int) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        name=f"{name} (source {s})",
        origin=p(P.source(name, "")),
        contents=[p(P.source(name, leaf)) for leaf in
                  (P.IMAGE, P.FOLLOWED_MOVER, P.MATCHES, P.CANDIDATES, P.CHOSEN_PATCH)],
    )


def _whole_run() -> rrb.VisibleTimeRange:
    inf = rrb.TimeRangeBoundary.infinite()
    return rrb.VisibleTimeRange("step", start=inf, end=inf)


def _plot(p: P.Paths, name: str, stats: Sequence[str]) -> rrb.TimeSeriesView:
    inf = rrb.TimeRangeBoundary.infinite()
    return rrb.TimeSeriesView(
        name=name, origin=p(P.STATS), contents=[p(P.stat(n)) for n in stats],
        time_ranges=_whole_run(),  # the whole run, not a window around the cursor
        axis_x=rrb.TimeAxis(view_range=rrb.TimeRange(start=inf, end=inf)),
        plot_legend=rrb.PlotLegend(rrb.components.Corner2D.LeftTop))


def _plots(p: P.Paths, *, jaccard: bool = True) -> rrb.Tabs:
    # the Jaccard plot only where the run has a ground-truth mask (``run --gt``):
    # without one it would stay empty
    return rrb.Tabs(
        _plot(p, "counts", ("n_dynamic", "n_replaced", "n_undecided",
                                     "dynamic_px")),
        *([_plot(p, "Jaccard", ("jaccard",))] if jaccard else []),
        _plot(p, "seconds", ("seconds",)),
        name="plots",
    )


def _texts(p: P.Paths) -> rrb.Tabs:
    return rrb.Tabs(
        rrb.TextLogView(name="log", origin=p(), contents=[p(P.LOG), p("probes/**")]),
        rrb.TextDocumentView(name="read M", origin=p(P.REFERENCE_M_LEGEND)),
        rrb.TextDocumentView(name="run", origin=p(P.RUN_INFO)),
        name="log and notes",
    )


def _run_layout(names: list[str], p: P.Paths, *, label: str | None = None,
                jaccard: bool = True) -> rrb.Container:
    sources = rrb.Grid(*[_source_view(p, n, s) for s, n in enumerate(names)],
                       grid_columns=max(1, min(3, len(names))), name="sources")
    similarity = rrb.Grid(*[rrb.Spatial2DView(name=f"{n} C_{s}", origin=p(P.similarity(n)))
                            for s, n in enumerate(names)],
                          grid_columns=max(1, min(3, len(names))), name="similarity C_s")
    return rrb.Vertical(
        rrb.Horizontal(_reference_view(p),
                       rrb.Vertical(_maps(p, errors=jaccard), _more(p, names), name="maps",
                                    row_shares=[3, 2]),
                       column_shares=[3, 2], name="reference"),
        rrb.Horizontal(
            rrb.Tabs(sources, similarity,
                     rrb.Spatial2DView(name="coverage", origin=p(P.COVERAGE)),
                     name="sources"),
            rrb.Vertical(_plots(p, jaccard=jaccard), _texts(p), row_shares=[1, 1],
                         name="plots and log"),
            column_shares=[3, 2], name="sources and plots"),
        row_shares=[3, 2],
        name=label or "run",
    )


def _panels(size: tuple[int, int] | None = None) -> list:
    fps = None
    if size is not None:
        fps = max(1.0, size[0] * size[1] / SCAN_SECONDS)
    return [rrb.TimePanel(timeline="step", state="expanded", fps=fps),
            rrb.SelectionPanel(state="expanded"),
            rrb.BlueprintPanel(state="collapsed")]


def make_blueprint(source_names: Sequence[str], *, root: str = "",
                   size: tuple[int, int] | None = None, jaccard: bool = True) -> rrb.Blueprint:
    """Default layout of one run.

    Parameters
    ----------
    source_names : sequence of str
        Names of the sources in order ``s = 0..S-1`` (image names are turned
        into entity names with :func:`viewer.paths.entity_names`, as the sink does).
    root : str
        Root prefix of the run's entities (``""`` or e.g. ``"runs/paper"``).
    size : (H, W), optional
        Image size: the time panel then plays one scan (H·W steps) in about
        :data:`SCAN_SECONDS` seconds instead of one step per frame.
    jaccard : bool
        Whether the run has a ground-truth mask: the "errors" map and the
        "Jaccard" plot are shown only then (they would stay empty).
    """
    names = P.entity_names(list(source_names))
    return rrb.Blueprint(_run_layout(names, P.Paths(root), jaccard=jaccard), *_panels(size),
                         auto_views=False)


def make_compare_blueprint(source_names: Sequence[str], roots: Sequence[str], *,
                           size: tuple[int, int] | None = None,
                           jaccard: bool = True) -> rrb.Blueprint:
    """Layout of several runs logged side by side under ``roots`` (``--compare``).

    The first tab shows every run's reference and L next to each other; then
    one tab per run with its full layout.
    """
    names = P.entity_names(list(source_names))
    side = rrb.Vertical(
        rrb.Horizontal(*[_reference_view(P.Paths(r), name=f"{r}: reference") for r in roots],
                       name="references"),
        rrb.Horizontal(*[_dynamic_view(P.Paths(r), name=f"{r}: L") for r in roots],
                       name="dynamic maps"),
        rrb.Horizontal(*[rrb.TimeSeriesView(name=f"{r}: stats", origin=P.Paths(r)(P.STATS),
                                            time_ranges=_whole_run())
                         for r in roots], name="stats"),
        row_shares=[3, 2, 1], name="side by side")
    tabs = [_run_layout(names, P.Paths(r), label=r, jaccard=jaccard) for r in roots]
    return rrb.Blueprint(rrb.Tabs(side, *tabs, name="runs"), *_panels(size),
                         auto_views=False)

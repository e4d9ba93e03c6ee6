"""The default layout of a dynremove recording (sent with every recording).

::

    ┌ reference + overlays ───────────┬ L ──────────┐
    │ image, L, decisions, current,   │ M (scan)    │
    │ chosen patch, scan line         │ errors/input│
    ├ sources grid ───────────────────┼ stats / log ┤
    │ image + candidates + q* + N     │ C_s, cover. │
    └─────────────────────────────────┴─────────────┘

The time panel is on ``step``: scrubbing it replays the removal pixel by pixel.
"""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from viewer import paths as P


def _reference_view(p: P.Paths, name: str = "reference + overlays") -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        name=name,
        origin=p(P.REFERENCE),
        contents=[p(P.REFERENCE_IMAGE), p(P.REFERENCE_DYNAMIC), p(P.REFERENCE_DECISIONS),
                  p(P.REFERENCE_CURRENT), p(P.REFERENCE_CHOSEN_PATCH),
                  p(P.REFERENCE_SCANLINE)],
    )


def _dynamic_view(p: P.Paths, name: str = "dynamic map L") -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name=name, origin=p(P.REFERENCE),
                             contents=[p(P.REFERENCE_DYNAMIC), p(P.REFERENCE_SCANLINE)])


def _side_views(p: P.Paths) -> rrb.Tabs:
    return rrb.Tabs(
        _dynamic_view(p),
        rrb.Spatial2DView(name="M (current scan)", origin=p(P.REFERENCE),
                          contents=[p(P.REFERENCE_M), p(P.REFERENCE_SCANLINE),
                                    p(P.REFERENCE_CURRENT)]),
        rrb.Spatial2DView(name="errors vs ground truth", origin=p(P.REFERENCE),
                          contents=[p(P.REFERENCE_IMAGE), p(P.ERRORS_LABELS)]),
        rrb.Spatial2DView(name="input + L", origin=p(P.REFERENCE),
                          contents=[p(P.REFERENCE_INPUT), p(P.REFERENCE_DYNAMIC)]),
        rrb.Spatial2DView(name="ground truth", origin=p(P.GROUND_TRUTH),
                          contents=[p(P.GT_BACKGROUND), p(P.GT_MASK)]),
    )


def _source_view(p: P.Paths, name: str) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(
        name=f"source {name}",
        origin=p(P.source(name, "")),
        contents=[p(P.source(name, leaf)) for leaf in
                  (P.IMAGE, P.CANDIDATES, P.CHOSEN_PATCH, P.MATCHES)],
    )


def _plots(p: P.Paths) -> rrb.Tabs:
    return rrb.Tabs(
        rrb.TimeSeriesView(name="counts per scan", origin=p(P.STATS),
                           contents=[p(P.stat(n)) for n in
                                     ("n_dynamic", "n_replaced", "n_undecided",
                                      "dynamic_px")]),
        rrb.TimeSeriesView(name="Jaccard", origin=p(P.STATS),
                           contents=[p(P.stat("jaccard"))]),
        rrb.TimeSeriesView(name="seconds per scan", origin=p(P.STATS),
                           contents=[p(P.stat("seconds"))]),
    )


def _run_layout(names: list[str], p: P.Paths, *, label: str | None = None) -> rrb.Container:
    sources = rrb.Grid(*[_source_view(p, n) for n in names],
                       grid_columns=max(1, min(3, len(names))), name="sources")
    maps = rrb.Tabs(
        rrb.Grid(*[rrb.Spatial2DView(name=f"C {n}", origin=p(P.similarity(n)))
                   for n in names], name="similarity C_s"),
        rrb.Spatial2DView(name="coverage", origin=p(P.COVERAGE)),
    )
    return rrb.Vertical(
        rrb.Horizontal(_reference_view(p), _side_views(p), column_shares=[3, 2]),
        rrb.Horizontal(
            rrb.Tabs(sources, maps),
            rrb.Vertical(_plots(p), rrb.TextLogView(name="log", origin=p(P.LOG)),
                         row_shares=[1, 1]),
            column_shares=[3, 2]),
        row_shares=[3, 2],
        name=label,
    )


def _panels() -> list:
    return [rrb.TimePanel(timeline="step", state="expanded"),
            rrb.SelectionPanel(state="expanded"),
            rrb.BlueprintPanel(state="collapsed")]


def make_blueprint(source_names: Sequence[str], *, root: str = "") -> rrb.Blueprint:
    """Default layout of one run.

    Parameters
    ----------
    source_names : sequence of str
        Names of the sources in order ``s = 0..S-1`` (image names are turned
        into entity names with :func:`viewer.paths.entity_names`, as the sink does).
    root : str
        Root prefix of the run's entities (``""`` or e.g. ``"runs/paper"``).
    """
    names = P.entity_names(list(source_names))
    return rrb.Blueprint(_run_layout(names, P.Paths(root)), *_panels(),
                         auto_views=False)


def make_compare_blueprint(source_names: Sequence[str],
                           roots: Sequence[str]) -> rrb.Blueprint:
    """Layout of several runs logged side by side under ``roots`` (``--compare``).

    The first tab shows every run's reference and L next to each other; then
    one tab per run with its full layout.
    """
    names = P.entity_names(list(source_names))
    side = rrb.Vertical(
        rrb.Horizontal(*[_reference_view(P.Paths(r), name=f"{r}: reference") for r in roots]),
        rrb.Horizontal(*[_dynamic_view(P.Paths(r), name=f"{r}: L") for r in roots]),
        rrb.Horizontal(*[rrb.TimeSeriesView(name=f"{r}: stats", origin=P.Paths(r)(P.STATS))
                         for r in roots]),
        row_shares=[3, 2, 1], name="side by side")
    tabs = [_run_layout(names, P.Paths(r), label=r) for r in roots]
    return rrb.Blueprint(rrb.Tabs(side, *tabs), *_panels(), auto_views=False)

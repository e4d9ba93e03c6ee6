"""Entity paths of a dynremove recording, in one place (users: recordings/README.md).

Every path is relative to an optional *root*, so that two runs can be logged
side by side in one recording (``--compare``: roots ``runs/main`` and ``runs/compare``)::

    >>> p = Paths()
    >>> p(REFERENCE_IMAGE)
    '/reference/image'
    >>> Paths("runs/paper")(source("cam_2", CANDIDATES))
    '/runs/paper/sources/cam_2/candidates'

Layout::

    reference/input          static JPEG: the reference as loaded
    reference/image          JPEG snapshot of the rewritten reference (every N rows)
    reference/dynamic        SegmentationImage: L (1 = dynamic)
    reference/M              colour-mapped M of the current scan, fixed range [0, 1]
    reference/scanline       the row being visited
    reference/M_legend       how to read M (static text; the colour bar is under the map)
    reference/decisions/scan<k>/rows_<a>_<b>
                             Points2D of one chunk's recorded decisions (+ text
                             AnyValues), logged ONCE at the chunk's last step and
                             cleared when the next scan starts: an instance index
                             always means the same decision, or nothing
    reference/current        the decision at this step (cleared on the next step)
    reference/current_label  its verdict in words, on a box beside the pixel
    reference/chosen_patch   Boxes2D of the written patch at this step
    sources/<name>/image     static JPEG
    sources/<name>/candidates  candidates of the current decision, coloured by cluster
                             (every decision at detail "full"; at "default" probes,
                             sampled static ones and dynamic ones at x, y % 4 == 0)
    sources/<name>/chosen_patch  Boxes2D of q* in that source (same steps)
    sources/<name>/chunk_matches  correspondences updated in the previous chunk (dim)
    sources/<name>/followed_mover  static: where the flow followed the reference's
                             mover into this source (fill by selection: such a
                             source never fills there)
    scan_maps/*              per scan, at its last step, lossless: M (uint16, M·10⁴,
                             65535 = undecided), verdict, chosen_source,
                             overwritten_before, first_overwritten (derived from the
                             Replacement events in the sink); from the core's
                             decision maps (Sec. 3.2.1): n_candidates |P|,
                             n_clusters k, win_size |A_m| (uint8), win_sources
                             (uint16 bitmask, bit s = source s) and b_m
                             (float32, Σ B_l over A_m, 0 = no winning cluster)
    errors/legend            class-coloured legend points under the errors map
    probes/x<X>_y<Y>         TextLog: each probe pixel's decisions in words, per step
    similarity/<name>        colour-mapped C_s (start and after each scan)
    coverage                 colour-mapped coverage (in how many sources seen)
    stats/*                  scalars (per scan, per snapshot)
    ground_truth/mask, ground_truth/background
    errors/labels            TP/FP/FN SegmentationImage of L vs ground truth
    errors/background        |clean - ground truth| (at the end)
    result/clean             lossless (PNG) final image, result/dynamic: final L
    events/decisions|replacements|updates   raw event records, lossless columns
                             (one row per flush, each event with its own step)
    run/info, run/params, run/coverage      static run description
    log                      TextLog
"""

from __future__ import annotations

import re
from dataclasses import dataclass

# -- reference ---------------------------------------------------------------
REFERENCE = "reference"
REFERENCE_INPUT = "reference/input"
REFERENCE_IMAGE = "reference/image"
REFERENCE_DYNAMIC = "reference/dynamic"
REFERENCE_M = "reference/M"
REFERENCE_SCANLINE = "reference/scanline"
REFERENCE_DECISIONS = "reference/decisions"
REFERENCE_CURRENT = "reference/current"
REFERENCE_CHOSEN_PATCH = "reference/chosen_patch"
REFERENCE_CURRENT_LABEL = "reference/current_label"
REFERENCE_M_LEGEND = "reference/M_legend"


def decisions_chunk(scan: int, rows: tuple[int, int]) -> str:
    """Entity of one chunk's decisions: ``reference/decisions/scan<k>/rows_<a>_<b>``.

    >>> decisions_chunk(1, (479, 470))
    'reference/decisions/scan1/rows_0470_0479'
    """
    a, b = sorted(int(r) for r in rows)
    return f"{REFERENCE_DECISIONS}/scan{int(scan)}/rows_{a:04d}_{b:04d}"


# -- per source (leaf names under sources/<name>/) -----------------------------
SOURCES = "sources"
IMAGE = "image"
CANDIDATES = "candidates"
CHOSEN_PATCH = "chosen_patch"
MATCHES = "chunk_matches"
SIMILARITY = "similarity"
FOLLOWED_MOVER = "followed_mover"

# -- the rest ------------------------------------------------------------------
COVERAGE = "coverage"
STATS = "stats"
GROUND_TRUTH = "ground_truth"
GT_MASK = "ground_truth/mask"
GT_BACKGROUND = "ground_truth/background"
ERRORS = "errors"
ERRORS_LABELS = "errors/labels"
ERRORS_BACKGROUND = "errors/background"
ERRORS_LEGEND = "errors/legend"
SCAN_MAPS = "scan_maps"
SCAN_MAP_NAMES = ("M", "verdict", "chosen_source", "overwritten_before",
                  "first_overwritten")
CLUSTER_MAP_NAMES = ("n_candidates", "n_clusters", "win_size", "win_sources", "b_m")
M_SCALE = 10000  # scan_maps/M holds round(M · M_SCALE) as uint16
M_UNDECIDED = 65535
STAGE_TIMELINE = "stage"
RESULT_CLEAN = "result/clean"
RESULT_CLEAN_SCAN = "result/clean_scan"  # as the scans left it (before fusion)
RESULT_DYNAMIC = "result/dynamic"
RESULT_STAGES = "result/stages"  # L after each post-scan step: result/stages/<name>
RESULT_SOURCE = "result/selection/source"  # which image filled each pixel (0 = reference)
RESULT_SEAMS = "result/selection/seams"  # boundaries between the chosen images
# the field across L each pixel of the hole was sampled through (uint8): 1 the
# membrane, 1 + k plane k of the ring around its region (--select-planes), 0 outside
RESULT_PLANES = "result/selection/planes"
RESULT_MOVERS = "result/selection/movers"  # per source: where it shows a mover (rejected)
RESULT_REASONS = "result/selection/reasons"  # per source: why it did or did not fill
RESULT_EXPLAINED = "result/selection/explained"  # L kept: static 3-D structure
RESULT_LINGERING = "result/selection/lingering"  # a mover most photos show, seen free by 2+
# 1/2: replaced/kept with its region of L; 3: kept, its fill did not fit the photo around it
RESULT_COMPLETED = "result/selection/completed"
# the share of each pixel's region of L that the graph cut replaced (uint16,
# round(share · P_SCALE), DE_NONE outside the regions), --select-complete and
# --select-complete-px as values
RESULT_REGION_SHARE = "result/selection/region_share"
# what the graph cut weighed inside the fill's region (uint16, round(x · DE_SCALE),
# DE_NONE where not defined): data_cost/{reference,best_source}, the data costs (ΔE);
# support/{reference,sources}, the fill's colour consensus support of the reference
# and of the best source (none where the reference was the suspect)
RESULT_DATA_COST = "result/selection/data_cost"
RESULT_SUPPORT = "result/selection/support"
RESULT_INPAINTED = "result/selection/inpainted"  # no source free there: OpenCV inpainting
# a faint shade beside the movers relit to the other photos' light (Selection.relit),
# and the CIE L* it gained there (uint16, round(ΔL · DE_SCALE), DE_NONE where not relit)
RESULT_RELIT = "result/selection/relit"
RESULT_RELIGHT_L = "result/selection/relight_l"
# what the blend added to the chosen source (Selection.offset), an RGB image of
# OFFSET_ZERO + levels (clipped to 0..255): grey where it added nothing or no source filled
RESULT_OFFSET = "result/selection/offset"
OFFSET_ZERO = 128
# the part of it that blended away the steps of light at the seams between two
# sources (Selection.seam_offset, ``montage.seam_steps``), the same encoding
RESULT_SEAM_BLEND = "result/selection/seam_blend"
# where in the chosen source each replaced pixel was sampled (the source's field there),
# in that source's pixels at the analysed size: fill_match/x and /y (uint16,
# round(px · XY_SCALE), DE_NONE where the reference was kept, inpainted or off the frame)
RESULT_FILL_MATCH = "result/selection/fill_match"
# the static 3-D structure test inside L: per source, whether it shows the reference's
# content (EVIDENCE codes) and the best CIE76 ΔE along its epipolar line (uint16,
# round(ΔE · DE_SCALE), DE_NONE where not searched); how many sources had to show it;
# the reference's P(mover colour) (uint16, round(P · P_SCALE), DE_NONE outside L)
RESULT_EVIDENCE = "result/selection/static_evidence"
RESULT_LINE_DE = "result/selection/line_de"
# ... and where on the line that best match lies, in the source's pixels: per source
# line_match/<source>/x and /y (uint16, round(px · XY_SCALE), DE_NONE where not
# searched or outside the source)
RESULT_LINE_MATCH = "result/selection/line_match"
XY_SCALE = 8
RESULT_STATIC_NEED = "result/selection/static_need"
RESULT_REF_MOVER_P = "result/selection/ref_mover_p"
DE_SCALE = 100
P_SCALE = 10000
DE_NONE = 65535
EVENTS_DECISIONS = "events/decisions"
EVENTS_REPLACEMENTS = "events/replacements"
EVENTS_UPDATES = "events/updates"
RUN_INFO = "run/info"
RUN_PARAMS = "run/params"
RUN_COVERAGE = "run/coverage"
LOG = "log"
RUN_INTERRUPTED = "run/interrupted"  # static: where an interrupted run ends

# Class ids of the AnnotationContext logged at the root (segmentation + points).
CLASS_BACKGROUND = 0
CLASS_DYNAMIC = 1
CLASS_FP = 2
CLASS_FN = 3
CLASS_TP = 4
CLASS_STATIC = 5  # a recorded decision that came out static
CLASS_PROBE = 6  # a probe pixel's decision
CLASS_UNDECIDED = 7
CLASS_DECISION = 8  # carries the reasons (Decision["why"] bits) as keypoint names

# Names of the stats/* scalar series.
STAT_NAMES = ("n_dynamic", "n_replaced", "n_undecided", "seconds", "dynamic_px",
              "jaccard")


def stat(name: str) -> str:
    """Path of the ``stats/<name>`` scalar series."""
    return f"{STATS}/{name}"


def source(name: str, leaf: str) -> str:
    """Path ``sources/<name>/<leaf>`` (``name`` as returned by :func:`entity_names`)."""
    return f"{SOURCES}/{name}/{leaf}"


def scan_map(name: str) -> str:
    """Path ``scan_maps/<name>`` of a per-scan map (:data:`SCAN_MAP_NAMES`,
    :data:`CLUSTER_MAP_NAMES`)."""
    return f"{SCAN_MAPS}/{name}"


def similarity(name: str) -> str:
    """Path of the colour-mapped C_s of source ``name``."""
    return f"{SIMILARITY}/{name}"


@dataclass(frozen=True)
class Paths:
    """Map a relative path to an absolute entity path under ``root``."""

    root: str = ""

    def __call__(self, rel: str = "") -> str:
        parts = [p for p in (self.root.strip("/"), rel.strip("/")) if p]
        return "/" + "/".join(parts)


def entity_names(names: list[str]) -> list[str]:
    """Turn image names into unique, safe entity-path parts.

    The extension is dropped and anything but ``[A-Za-z0-9_-]`` becomes ``_``;
    duplicates get a ``_<i>`` suffix.

    >>> entity_names(["a/00010.jpg", "b/00010.jpg", "my img.png", ""])
    ['00010', '00010_1', 'my_img', 'img_3']
    """
    out: list[str] = []
    for i, name in enumerate(names):
        base = name.replace("\\", "/").rsplit("/", 1)[-1]
        if "." in base[1:]:
            base = base[: base.rindex(".")]
        base = re.sub(r"[^A-Za-z0-9_-]", "_", base) or f"img_{i}"
        cand = base
        k = 1
        while cand in out:
            cand = f"{base}_{k}"
            k += 1
        out.append(cand)
    return out

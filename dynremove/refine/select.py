"""Fill by selection: keep the reference where it is right, copy one free source elsewhere.

The default preset's last step (not in the paper). It replaces the per-channel
median of all sources (``fill.fuse_background``), which averages every
source's *own* mover into the fill as a ghost and refills static 3-D structure
that the scan flagged with doubled content.

1. **Evidence that the reference is static** (geometry). Each source is
   matched to the reference by homography + DIS flow, without the scan's gate.
   A flow match *explains* a reference pixel when it agrees in colour (CIE76
   ΔE < ``tau``), lies within ``select_epipolar_px`` of its epipolar line, and
   departs from the homography by no more than the parallax the static scene
   shows between the two views (``TwoView.parallax_px``, measured on the F
   inliers; a rotation or a planar scene allows ~1 px, a wide baseline tens).
   Pixels of L explained by at least half of the sources that see them (their
   match inside the source's frame; at least two, or one of two sources) are
   static 3-D structure that the scan's homography-gated matches could not
   follow: near the border, the sources that do not reach a pixel do not vote.
   Where the set has parallax, a pixel whose flow match failed (thin
   structure against the sky, far off the plane) may instead be found by a
   search along its epipolar line (``parallax.epipolar_search``, its window
   weighted by colour likeness to the centre: ``select_search_support_de``); that weaker
   evidence counts where at least two sources, and half of them, explain it. Where
   one source's match would decide alone (three photos or two) against a source
   that found nothing, it must be unique on its line (``select_search_unique``).
   A source that did not find the content counts against such a match where its
   flow match lacks the movers' colours, or where nothing on its line comes
   near the content (``select_search_against_de``): only a source whose flow
   match has the movers' colours, and whose line holds something like the
   content, may be showing its own copy of the mover over it.
   **A mover that lingered** (``_minority_witnesses``, ``select_minority``):
   where the reference and most sources show an object and two or more
   sources, agreeing, show the scene's common colours behind it, L takes the
   region; there the sources that still show it never fill, and the witnesses'
   consensus decides even where the set has much parallax.
   With three photos (``select_minority_one``), one source that saw the
   scene where the other still shows the reference's content completes a
   mover that the scans found in part: L takes the rest of it.
2. **Background candidates.** Every source is sampled through its field,
   re-interpolated across the rest of L (``fields.background_field``), and
   re-chosen, pixel by pixel, among the planes that the ring around each region
   shows, where the sources agree at one of them clearly better than through the
   membrane (``planes.plane_fields``, ``select_planes``: a table's edge or a
   balcony hidden by a mover comes out in place, not blended); where
   the set has parallax, found instead by a plane + parallax sweep for the
   depth at which the sources agree (``parallax.sweep_fields``); then
   re-aligned by flow from the filled reference (``fill.realign_fields``; up
   to ``fuse_realign_max_px``), filled for that with the sources' median
   where none shows a mover (a lingering mover's copies, a mover the flow
   followed into a source).
3. **Consensus with independent, weighted witnesses.** A colour model of the
   movers (histogram of L against a ring around it, as GrabCut's) gives each
   candidate a mover probability; a witness counts ``1 - p``, so a source
   showing its own mover (or a near-copy of the reference) carries no weight.
   Where the set is flat, a source whose candidate lands on the reference's
   mover as the flow followed it into that source (``_followed_mover``) carries
   none either, and never fills where another source may. With
   ``select_line_px`` (off by default: measured mixed), where the set is 3-D, a
   candidate sampled off the pixel's epipolar line in its source (the field
   interpolated across L, or re-aligned, led it where the static scene cannot
   be) carries only a tenth of its weight where another source's sample lies on
   its line (in a source whose static flow matches lie that near their lines:
   elsewhere the geometry's error is as large).
   The consensus at a pixel is the candidate with the most weighted support.
4. **Graph cut** (``montage.expansion_labels``, photomontage). Labels: the
   reference and every source. The data cost is the distance to the
   consensus, plus a preference for the reference outside L and a cost for
   keeping it inside L (unless explained, or unless it agrees with the
   sources' consensus: then it costs what a source showing it would, less
   κ); the seam cost puts seams where
   the sources agree. Where the sets' parallax is large (median
   ``parallax_px`` > ``select_parallax_px``), the consensus may also keep the
   reference inside L: the scan's flags there are mostly 3-D structure.
   Where no majority can be counted (two photos; or no two photos agree; or,
   of three, both sources show a mover), the colour model decides whether the
   reference keeps its pixel (``reference_cost``).
   A region of L that the cut replaced almost whole (``select_complete``) is
   a mover: its fragments kept as the reference are replaced too, so that no
   piece of it stays in the photo; one it kept almost whole is static: its
   replaced fragments keep the reference (``complete_regions``). One replaced
   only in part, whose kept part shows the movers' colours and no source's
   copy of it, keeps the reference whole (``partial_movers``): the rest of
   the mover was seen free nowhere, and half a mover is worse than a whole one.
5. **Blend** (``montage.offset_blend``): exposure and white-balance
   differences leave no edge; the light part of its offset, which spreads
   into the fill, is kept to what light does (``montage.light_only``: a change
   of hue is content, only its brightness is kept). A replaced region that
   the blend had to shift by more than light does (``select_misfit_levels``),
   where the reference lacks the movers' colours, keeps the reference
   (``misfit_regions``): its fill shows other content than the scene there.
   Where two sources meet inside the region and their light still differs by
   up to ``select_seam_levels``, the step is blended in the gradient domain
   (``montage.seam_steps``: Poisson image editing within 64 px of the seam,
   the region's edge held). A piece of the fill whose source differs from
   the reference on the kept photo around it (``select_misplaced_de``) shows
   content misplaced there (``misplaced_pieces``). It is inpainted (OpenCV
   Telea), as are the pixels of L that no source shows free; both reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import apply_homography, dense_correspondence, pixel_grid
from dynremove.method.geometry import TwoView, sampson_sq
from dynremove.params import Params
from dynremove.refine.colour import delta_e, pairwise_delta_e
from dynremove.refine.concurrency import for_each_source
from dynremove.refine.fields import (background_fields, blurred_lab, interpolate_field,
                                     sample_bilinear)
from dynremove.refine.fill import median_fill, realign_fields
from dynremove.refine.parallax import (epipolar_search, fit_parallax, line_points,
                                       search_beyond, sweep_fields)
from dynremove.refine.montage import (LIGHT_SIGMA_PX, add_offset, expansion_labels,
                                      offset_blend, pairwise_distance, seam_steps)
from dynremove.refine.morphology import dilate_disc, drop_small, fill_holes, grow_replaced
from dynremove.refine.planes import plane_fields

_FORBIDDEN = 1e6  # data cost of a label that may not be used
_UNSEEN_PX = 12  # pixels no source sees, this near a replaced mover, are inpainted with it
_UNSEEN_CORE_PX = 48  # ... and its own pixels of L that no source sees, this far in
_DE_CAP = 40.0  # colour distances are capped here in the data cost
# ``misfit_regions``: a region whose reference has the movers' colours at this mean
# P(mover) or more is replaced whatever its offset (a true mover whose only free
# source was lit otherwise: DAVIS bmx-trees, kite-surf, parkour and motocross-jump_s3
# lost most of their movers to the offset alone)
MISFIT_MOVER_P = 0.6
# A pixel of L that this many sources explain (a geometrically valid flow match of
# its colour) is static, however many photos there are: with 8-10 wide-baseline
# views the far ones rarely match 3-D structure, and "half of the sources" left
# static structure in L. Changes nothing up to 6 sources. Chosen on 6 composites of
# 10 views, checked on 6 of 9 views (seed 1), after ``min_witnesses``: damage
# 1.23 -> 0.95 % and 1.20 -> 0.96 %, leftover 22.5 -> 23.1 % and 29.9 -> 30.1 %,
# whole-image PSNR +0.44 and +0.18 dB, J 0.706 -> 0.727 and 0.755 -> 0.769.
_EXPLAIN_CAP = 3
# A source shows the reference's mover where the flow carried it, if it carried at
# least this share of the mover's region (a connected region of L) off its epipolar
# line with the mover's colour. The stray colour matches of a mover the flow lost
# reach 0-14 % (synthetic scenes, 3 views); on the fit half of DAVIS, 0.15 / 0.3 /
# 0.5 gave own-mover fill 12.3 / 12.0 / 12.2 % (13.5 without), the check half 10.1 /
# 10.1 / 11.6 % (19.1 without), J unchanged.
_FOLLOWED_SHARE = 0.3
_RING_OK = 0.6  # share of a lingering region's surroundings a witness sees as the reference
# ``select_line_px``: what is left of the vote of a source's sample off the pixel's
# epipolar line, where another source's sample lies on its line. None at all gave a
# source's sample on its line the consensus also where that sample was the source's
# own mover (seed-41 v4 entry-P10+dog_s3+drift-chicane: a white car pasted on the door,
# -3.2 dB); a tenth kept the rule's gains there and lets several off-line samples still
# outvote one on its line (README, session 72)
_OFF_LINE_VOTE = 0.1
# With two sources, one witness (``select_minority_one``): a lingering region must be
# at least this share of the image and lie in L on at least this share of its area
_ONE_WITNESS_FRAC = 0.002
_ONE_WITNESS_IN_L = 0.2


@dataclass
class Selection:
    """What the fill by selection decided (all (H, W) unless said)."""

    clean: npt.NDArray[np.uint8]  # (H, W, 3) the clean reference
    replaced: npt.NDArray[np.bool_]  # the final dynamic map: pixels of L taken from a source,
    # and pixels near L whose source differs from the reference (ΔE >= tau)
    label: npt.NDArray[np.int16]  # -1 not considered, 0 reference kept, k+1 source k
    explained: npt.NDArray[np.bool_]  # pixels of L kept as static 3-D structure
    movers: npt.NDArray[np.bool_]  # (S, H, W) where source k's candidate shows a mover
    no_source: npt.NDArray[np.bool_]  # replaced pixels no source showed free (inpainted)
    seams: npt.NDArray[np.bool_]  # boundaries between labels inside the region
    parallax_px: float  # median measured parallax of the set (px)
    consensus_mode: str  # "scan" (trust L) or "parallax" (colour consensus inside L)
    # the median over the sources of the 95th percentile of the parallax (px): with
    # parallax_px, what ``treated_as_3d`` read
    parallax_p95_px: float = float("nan")
    # for the full-resolution output (refine.upsample): each source's field, and per
    # replaced pixel which sources' samples were combined (S, H, W)
    fields: list = field(default_factory=list)
    members: npt.NDArray[np.bool_] | None = None
    # (S, H, W) uint8, why each source did or did not fill each pixel of the region:
    # REASONS[code]; 0 outside the region
    reasons: npt.NDArray[np.uint8] | None = None
    # pixels of a mover that lingered: the reference and most sources show it, two
    # or more sources saw the background (``_minority_witnesses``)
    lingering: npt.NDArray[np.bool_] | None = None
    # where the graph cut's choice was overruled by its region's (``complete_regions``,
    # ``select_complete``), uint8: 1 replaced with a region replaced almost whole, 2
    # kept with a region kept almost whole, 3 (MISFIT_KEPT) kept because its region's
    # fill did not fit the photo around it (``misfit_regions``), 4 (PARTIAL_KEPT) kept
    # whole with a region replaced only in part whose kept part is the mover's
    # (``partial_movers``, ``select_keep_partial``), 0 elsewhere
    completed: npt.NDArray[np.uint8] | None = None
    # the share of each pixel's region of L that the graph cut replaced, before that
    # rule (``region_shares``); where the region's pixels that the static test
    # explained, counted as kept, bring it under 1 − ``select_complete`` (static), that
    # share; float32 in [0, 1]; NaN outside the regions
    region_share: npt.NDArray[np.float32] | None = None
    # (S,) float32: the Gaussian σ (working px) each source's fill was blurred by, to
    # match a reference softer than it (``reference_blur``); 0 where it is not
    blur_sigma: npt.NDArray[np.float32] | None = None
    # what the graph cut weighed at each pixel of the region, float32 (NaN outside it):
    # data_cost (2, H, W), the reference's and the cheapest source's (CIE76 ΔE, with
    # κ and γ·P(mover); NaN where no source may fill); support (2, H, W), the fill's
    # colour consensus: the reference's (itself and the sources' static votes) and the
    # best source's (the sources agreeing with it), NaN where the reference was the
    # suspect (its consensus left it out)
    data_cost: npt.NDArray[np.float32] | None = None
    support: npt.NDArray[np.float32] | None = None
    # the static 3-D structure test inside L (``explained``), per source (S, H, W)
    # uint8: EVIDENCE[code] (0 outside L); the best CIE76 ΔE of the reference's
    # content along the source's epipolar line (S, H, W) float32 (NaN where not
    # searched); how many sources had to show it (H, W) uint8 (0 outside L); and the
    # reference's P(mover colour) (H, W) float32 (NaN outside L)
    static_evidence: npt.NDArray[np.uint8] | None = None
    line_de: npt.NDArray[np.float32] | None = None
    # where on that line the best match lies, in the source's pixels (S, H, W, 2)
    # float32 (x, y; NaN where not searched); None where the search did not run
    line_xy: npt.NDArray[np.float32] | None = None
    static_need: npt.NDArray[np.uint8] | None = None
    ref_mover_p: npt.NDArray[np.float32] | None = None
    # (S, H, W) bool, in each *source's* own frame: where the flow followed the
    # reference's movers into it (``_followed_mover``; all False where it did not)
    followed: npt.NDArray[np.bool_] | None = None
    # (H, W, 3) float32, B/G/R levels: what the blend added to the chosen source's
    # value (``montage.offset_blend``: the photos' exposure and light around the
    # region); NaN where no source filled the pixel (kept, or inpainted), but where
    # ``misfit_regions`` kept the reference (``completed`` 3): what it would have added
    offset: npt.NDArray[np.float32] | None = None
    # (H, W, 3) float32, B/G/R levels: the part of ``offset`` that removed the steps of
    # light at the seams between sources (``montage.seam_steps``; 0 elsewhere), which
    # the full-size fill takes upsampled label by label; None: no step removed
    seam_offset: npt.NDArray[np.float32] | None = None
    # (H, W) bool: L as the fill by selection last saw it (the scans' map grown by its
    # own steps); the blend's pixels that may show a mover (``offset_blend``'s
    # ``suspect``), at full size too (``upsample.full_resolution``)
    mask: npt.NDArray[np.bool_] | None = None
    # a faint shade beside the replaced region relit to the sources' light
    # (``shade.relight_shade``): (H, W) bool, the pixels changed (beside ``replaced``,
    # and inside it where the shade runs into the fill); (H, W, 3) float32, the CIE Lab
    # offset added there (0 elsewhere). None: nothing relit
    relit: npt.NDArray[np.bool_] | None = None
    relight: npt.NDArray[np.float32] | None = None
    # (H, W) bool: the pieces of the fill whose source did not continue the photo kept
    # around them (``misplaced_pieces``): inpainted (also in ``no_source``); None: none
    misplaced: npt.NDArray[np.bool_] | None = None
    # (H, W) int16: the plane of the ring around its region of the hole that each
    # pixel's fields were taken from (``planes.plane_fields``; numbered per region from
    # 1), 0 where the membrane was kept, -1 outside the hole; None: no plane chosen
    planes: npt.NDArray[np.int16] | None = None


REASONS = {0: "not considered", 1: "chosen",
           2: "combined (agrees with the chosen one: averaged with it)",
           3: "its own mover, by colour (its sample has the colours of the movers found "
              "in the reference, and differs from the fill's colour consensus)",
           4: "outside its frame or no content",
           5: "disagrees with the fill's colour consensus",
           6: "agrees with the fill's colour consensus, but not with the source chosen "
              "here, so not averaged with it",
           # ("still shows the mover that lingered here" read as a fact to a trial on a
           # static sign that the lingering rule took: the witnesses decide it)
           7: "still shows what the reference shows here: the mover that lingered, as "
              "the sources that saw past it say (static structure standing off the "
              "rest would look the same)",
           8: "shows the reference's mover, moved here (the flow followed it)",
           9: "disagrees with the fill's colour consensus, and its sample lies off "
              "this pixel's epipolar line in it (farther than --select-line-px), where "
              "the scene behind the mover cannot be: a tenth of a vote in that "
              "consensus, as another source's sample lies on its line",
           10: "chosen, but its view of this part of the fill is misplaced: on the photo "
               "kept around that part it differs from the reference by more than "
               "--select-misplaced-de, so the part is inpainted instead"}
OUTSIDE, STILL_LINGERING = 4, 7  # the codes that say a source saw nothing of the region
# ``Selection.completed``: the region rule's codes (1 replaced, 2 kept with its region
# of L), ``misfit_regions``' (kept: its fill did not fit the photo around it) and
# ``partial_movers``' (kept whole: only part of a mover could be replaced)
MISFIT_KEPT = 3
PARTIAL_KEPT = 4
# ``partial_movers``: a kept part counts as the scene's where some source shows what
# the reference shows on at least this share of it
_PARTIAL_AGREE = 0.5
OWN_MOVER, FOLLOWED = 3, 8  # the codes of a source showing a mover of its own: by colour,
# or the reference's mover where the flow followed it
DISAGREES = 5  # a source whose sample differs from the fill's colour consensus
OFF_LINE = 9  # ... and off the pixel's epipolar line (a tenth of a vote: ``select_line_px``)
MISPLACED = 10  # the chosen source, whose part of the fill did not fit around it: inpainted
# ``misplaced_pieces``: the pieces judged (at least this many px), the ring of kept
# photo around each (this wide, at least this many px of it)
_MISPLACED_MIN_PX = 30
_MISPLACED_RING_PX = 3
_MISPLACED_MIN_RING_PX = 15
# ... and none where they would take more than this share of the fill (the composites
# reach 0.15, where the rule helps most; DAVIS motocross-jump 0.30)
_MISPLACED_MAX_SHARE = 0.25


def unconfirmed_fill(sel: "Selection", replaced: npt.NDArray[np.bool_]
                     ) -> npt.NDArray[np.bool_]:
    """Pixels of ``replaced`` (H, W) bool filled from one source alone while another
    source that reaches them shows a mover of its own there or disagrees with the
    fill (``reasons`` OWN_MOVER, FOLLOWED, DISAGREES or OFF_LINE): nothing confirms
    the fill there. (H, W) bool; all False without the per-source reasons."""
    if sel.reasons is None or sel.members is None:
        return np.zeros(replaced.shape, bool)
    single = replaced & ~sel.no_source & (sel.label > 0) & (sel.members.sum(0) == 1)
    against = np.isin(sel.reasons, (OWN_MOVER, FOLLOWED, DISAGREES, OFF_LINE)).any(0)
    return single & against


def kept_pieces(sel: "Selection", replaced: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Pixels kept as the reference shows them, enclosed by ``replaced`` (H, W) bool,
    that only photos showing the mover count as static: pieces of a mover left over
    the fill. (H, W) bool.

    An island of the reference that the replaced region encloses (4-connected) is
    such a piece where the sources whose evidence keeps it (``static_evidence``: their
    flow match or their epipolar line shows its content, on half of it or more)
    exist, and none of them is free on the replaced rim around it (chosen, combined
    or agreeing with the fill's consensus on half of the rim, 3 px wide): they show the
    reference's mover there too (it stayed in place in those photos), so they vouch
    for its pieces, not for the scene. ``bursts/tim6`` as tim2-tim5 (tim4 the
    reference): the cup's letters and lid pieces, 2.4 % of the replaced region; on the
    12 composites and DAVIS's camel, parkour and car-roundabout at most 0.2 %, where the
    islands (up to 17 % of the region) are the scene seen through a mover, kept by
    photos that show the scene around them.
    """
    out = np.zeros(replaced.shape, bool)
    if sel.static_evidence is None or sel.reasons is None:
        return out
    why = sel.reasons
    for isl, rim in _enclosed_islands(replaced):
        if rim.sum() < 5:
            continue
        vouch = _vouching(sel.static_evidence, isl)
        if vouch and all(np.isin(why[k][rim], (1, 2, 6)).mean() < 0.5 for k in vouch):
            out |= isl
    return out


def _enclosed_islands(replaced: npt.NDArray[np.bool_], *,
                      within: npt.NDArray[np.bool_] | None = None, min_px: int = 1,
                      rim_px: int = 3):
    """The islands (4-connected) of pixels that ``replaced`` (H, W) bool encloses and
    does not hold (within ``within``, of ``min_px`` or more), each with its rim: the
    replaced pixels within ``rim_px`` of it. Yields ``(island, rim)``, (H, W) bool each
    (``kept_pieces``, ``fill_kept_pieces``)."""
    islands = fill_holes(replaced) & ~replaced
    if within is not None:
        islands &= within
    if not islands.any():
        return
    n, cc = cv2.connectedComponents(islands.view(np.uint8), connectivity=4)
    sizes = np.bincount(cc.ravel(), minlength=n)
    for j in range(1, n):
        if sizes[j] >= min_px:
            isl = cc == j
            yield isl, dilate_disc(isl, rim_px) & ~isl & replaced


def _vouching(evidence: npt.NDArray[np.uint8], isl: npt.NDArray[np.bool_]) -> list[int]:
    """The sources whose static evidence (EV_FLOW, EV_LINE or EV_LINE_BEYOND) keeps
    half of ``isl`` or more: they show its content in place."""
    return [k for k in range(evidence.shape[0])
            if np.isin(evidence[k][isl], (EV_FLOW, EV_LINE, EV_LINE_BEYOND)).mean() >= 0.5]


def fill_kept_pieces(lab: npt.NDArray[np.intp], allowed: npt.NDArray[np.bool_],
                     free: npt.NDArray[np.bool_], labs: npt.NDArray[np.float32], tau: float,
                     evidence: npt.NDArray[np.uint8], d_cons: npt.NDArray[np.float32], *,
                     rim_px: int = 3, share: float = 0.5, min_px: int = 10
                     ) -> npt.NDArray[np.intp]:
    """The pieces of a mover that its fill encloses, given the fill's source.

    An island of the reference (label 0) of ``min_px`` or more that the replaced
    pixels (label > 0) enclose (4-connected) takes the label most common on its rim
    (``rim_px`` wide) where all of these hold:

    * that source is free on all of the island (``free``: it shows no mover of its
      own there) and differs from the reference there (CIE76 ΔE over ``tau``, on
      ``share`` of the island or more): the photo seen free around the island does
      not show what the reference shows there;
    * no source that keeps the island (``evidence`` EV_FLOW, EV_LINE or EV_LINE_BEYOND on half of it
      or more) is seen free around it (chosen, or free and within ``tau`` of the
      fill's colour consensus ``d_cons``, on half of the rim or more): only photos
      that show the mover in place vouch for it, as ``kept_pieces`` counts them.

    Such an island is a piece of the mover (its lettering, a lid's rim) that the
    static 3-D test kept; left, it floats in the fill. ``bursts/tim6`` as tim2-tim5
    (tim4 the reference): the cup's lid pieces and a letter, 500 px, 498 filled;
    tim2/4/6: 309 of 321 px. The scene seen through a mover (a pillar between a
    rider's arm and body on the composites) is kept: a photo that shows the scene
    around it shows the island in place too (the first form, without that test,
    replaced entry-P10's pillar: damage 0.17 -> 0.79 %). Pinholes under ``min_px``
    stay: where the reference shows the scene through a mover there, they hold the
    blend's offset to it (filled, the 6-view entry-P10+kite-surf check set's specks of
    1-11 px raised its leftover from 18.6 to 19.5 %).

    Parameters
    ----------
    lab : (h, w) int ndarray
        Labels: 0 the reference, k ≥ 1 source k − 1.
    allowed : (h, w) bool ndarray
        Where a label may change (the fill's region).
    free : (S, h, w) bool ndarray
        Where each source shows no mover of its own.
    labs : (S + 1, h, w, 3) float32 ndarray
        The reference and the sources (aligned to it) in CIE Lab.
    tau : float
        ΔE under which two colours agree (``select_tau``).
    evidence : (S, h, w) uint8 ndarray
        ``Selection.static_evidence`` on the same box.
    d_cons : (S, h, w) float32 ndarray
        Each source's ΔE to the fill's colour consensus.

    Returns
    -------
    lab : (h, w) int ndarray
        A copy with the pieces relabelled.
    """
    out = lab.copy()
    for isl, rim in _enclosed_islands(lab != 0, within=allowed, min_px=min_px, rim_px=rim_px):
        if not rim.any():
            continue
        k = int(np.bincount(lab[rim]).argmax())
        if k == 0 or not free[k - 1][isl].all():
            continue
        if (delta_e(labs[k][isl], labs[0][isl]) > tau).mean() < share:
            continue  # the photo seen free around it shows it too: the scene
        if any(((lab[rim] == i + 1) | (free[i][rim] & (d_cons[i][rim] < tau))).mean() >= 0.5
               for i in _vouching(evidence, isl)):
            continue  # a photo seen free around it shows it in place: the scene
        out[isl] = k
    return out


# Inside L, whether each source shows the reference's content as static (a pixel of
# L is kept as static 3-D structure where enough of them do: ``Selection.explained``)
EVIDENCE = {0: "not in L",
            1: "its match shows the reference's content (flow, on its epipolar line)",
            2: "shows the reference's content elsewhere on its epipolar line",
            3: "shows the reference's content on its epipolar line, but too few other "
               "sources show it for that weaker evidence to count, and another source "
               "that sees the pixel shows something else there",
            4: "its match agrees, but in the movers' colours",
            5: "its match differs and nothing on its epipolar line matches",
            6: "outside its frame",
            7: "shows the reference's content on its epipolar line, but as well elsewhere "
               "on it (a plain colour matching along the line), and the other source "
               "found nothing there: an ambiguous match does not count alone",
            8: "shows the reference's content on its epipolar line beyond the parallax "
               "the flow followed, at a depth the keypoints beside it show "
               "(--select-search-beyond-px)"}
EV_FLOW, EV_LINE, EV_LINE_ALONE, EV_MOVER_COLOUR, EV_NOT_FOUND, EV_UNSEEN = 1, 2, 3, 4, 5, 6
EV_AMBIGUOUS, EV_LINE_BEYOND = 7, 8
# ``select_search_unique``'s ratio test: the second minimum lies farther than this
# along the line (source px: the search window's width, 5 cells at half scale) and
# must cost more than select_search_unique × the best + _UNIQUE_DE (ΔE)
_UNIQUE_PX, _UNIQUE_DE = 10.0, 2.0
# ``select_search_beyond_px``: a match beyond the flow's stretch of the line counts
# where it costs less than the flow stretch's best / _BEYOND_RATIO - _UNIQUE_DE
_BEYOND_RATIO = 1.5


_BINS = 12  # per Lab axis, in the movers' colour model
# a region of L holding at most this share of L's core is judged by the colours of the
# rest of L (``_reference_mover_probability``): 12 composites damage 0.460 -> 0.385 %,
# DAVIS J 0.595 -> 0.611, with the one-source epipolar evidence (README, session 52)
_LEFT_OUT_SHARE = 0.5
# ... and, for the _SIMILAR_MAX largest such regions, leaves out too each other one of
# them whose core's colour histogram overlaps its own by more than this Bhattacharyya
# coefficient (pairwise, not transitively): the door's two pillars of the 3-view
# entry-P10+kite-surf composites (seed 7) vouched for each other, damage 1.69 and
# 2.57 % -> 0.84 and 0.82 % (README, session 52). Not with two photos: a mover cut in
# two by a pole, its pieces all of L, would be judged by nothing (P 0.5), and there
# the reference costs nothing unless its P is over 0.5 (``reference_cost``)
_SIMILAR_BC = 0.5
_SIMILAR_MAX = 40


def _followed_mover(flow: npt.NDArray[np.float32], found: npt.NDArray[np.bool_],
                    regions: npt.NDArray[np.int32]) -> npt.NDArray[np.bool_] | None:
    """Where a source shows the reference's movers, in the source's own frame.

    A slow mover overlaps itself from photo to photo, so behind the reference's
    mover most sources show their own copy of it, agreeing with each other: the
    consensus took it as the background (a translucent camel on DAVIS camel,
    own-mover fill 53 %). The flow (homography + DIS) follows such a mover: its
    pixels are found again in the source in their own colour but off their
    epipolar line, or farther from the homography than the static scene's
    parallax. Where it did so for at least ``_FOLLOWED_SHARE`` of a region of L,
    the pixels it found are splatted into the source's frame and closed into
    regions (a 9 px disc, holes filled, 2 px margin): the mover as the source
    shows it (motion segmentation by tracking, as in Wang & Adelson, *Representing
    moving images with layers*, 1994, reduced to one layer per region).

    Parameters
    ----------
    flow : (H, W, 2) float32 ndarray
        The reference → source matches (x, y) in source pixels.
    found : (H, W) bool ndarray
        Pixels of L whose match has the reference's colour and fails the geometry.
    regions : (H, W) int32 ndarray
        The connected regions of L (0 outside), ``cv2.connectedComponents``.

    Returns
    -------
    (H, W) bool ndarray or None
        None where no region was followed (fewer than 20 px in all).
    """
    n = int(regions.max()) + 1
    share = np.bincount(regions[found], minlength=n) / np.maximum(np.bincount(regions.ravel(),
                                                                             minlength=n), 1)
    share[0] = 0.0
    pts = found & (share >= _FOLLOWED_SHARE)[regions]
    if pts.sum() < 20:
        return None
    H, W = found.shape
    m = np.zeros((H, W), np.uint8)
    m[np.clip(np.rint(flow[..., 1][pts]).astype(np.int64), 0, H - 1),
      np.clip(np.rint(flow[..., 0][pts]).astype(np.int64), 0, W - 1)] = 1
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE,
                         cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)))
    return dilate_disc(fill_holes(m > 0), 2)


def _core_and_ring(L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The movers' colour model's two samples of L (H, W) bool: its core (L eroded
    by 5×5) and a ring around it (4 to 30 px), both (H, W) bool."""
    core = cv2.erode(L.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return core, dilate_disc(L, 30) & ~dilate_disc(L, 4)


def _mover_model(lab_ref: np.ndarray, L: np.ndarray) -> np.ndarray | None:
    """The movers' colour model, as GrabCut's: P(mover | Lab bin) (``_BINS``³,)
    float64 from the histograms of the reference's Lab ``lab_ref`` (H, W, 3) in
    L's core (L eroded by 5×5) against a ring around L (4 to 30 px); None when
    either is empty. Built once per L, read by ``_mover_probability``."""
    core, ring = _core_and_ring(L)
    if not core.any() or not ring.any():
        return None
    hf, hb = _lab_hist(lab_ref[core], _BINS), _lab_hist(lab_ref[ring], _BINS)
    return (hf + 1e-4) / (hf + hb + 2e-4)


def _mover_probability(model: np.ndarray | None, values: np.ndarray) -> np.ndarray:
    """P(mover | colour) of Lab ``values`` (..., 3) under ``_mover_model``'s
    ``model``: (...) float32, zero where there is no model."""
    if model is None:
        return np.zeros(values.shape[:-1], np.float32)
    return model[_lab_bins(values, _BINS)].astype(np.float32)


def _reference_mover_probability(lab_ref: np.ndarray, L: np.ndarray,
                                 model: np.ndarray | None, *, alike: bool = True
                                 ) -> np.ndarray:
    """P(mover | colour) of the reference's own pixels (H, W) float32, each region of
    L judged by the colours of the *rest* of L (leave one out).

    ``_mover_model`` learns the movers' colours from L itself, so a false positive
    of the scans (a pillar, a bollard, a tree that parallax made look dynamic)
    vouches for its own colours: its pixels' P(mover) is high because they are in
    L. Here a connected region (8-connected) holding at most ``_LEFT_OUT_SHARE`` of
    L's core is judged by the histogram of the other regions' core against the
    same ring (GrabCut's model, as ``_mover_model``). A region holding more than
    that share, a region with no core (thinner than 5 px: it is not in the model
    anyway), L of one region, and the pixels outside L keep the whole model's P;
    where no region holds more than half of the core (or two hold half each),
    every region is judged by the rest. For the ``_SIMILAR_MAX`` largest such
    regions, the rest also leaves out each other one of them whose core's colour
    histogram overlaps its own (Bhattacharyya coefficient over ``_SIMILAR_BC``;
    pairwise, not transitive): two pillars of a door do not vouch for each other.
    Where nothing is left, P is 1e-4 / (ring + 2e-4): 0.5 at colours the ring lacks
    (the pieces of one mover that a pole cut in two, all of L); ``alike=False`` (two
    photos, where 0.5 keeps the reference) leaves out the region alone.
    lab_ref : (H, W, 3) float32 Lab; L : (H, W) bool; model : ``_mover_model(lab_ref, L)``
    of the same L (None: zeros, as ``_mover_probability``).
    """
    p = _mover_probability(model, lab_ref)
    if model is None:
        return p
    n, comp = cv2.connectedComponents(L.astype(np.uint8), connectivity=8)
    if n <= 2:
        return p
    core, ring = _core_and_ring(L)
    hb = _lab_hist(lab_ref[ring], _BINS)
    nb = _BINS ** 3
    cc, bins = comp[core], _lab_bins(lab_ref[core], _BINS)
    counts = np.bincount(cc, minlength=n)
    h_all = np.bincount(bins, minlength=nb).astype(np.float64)
    left_out = np.flatnonzero((counts > 0) & (counts <= _LEFT_OUT_SHARE * counts.sum()))
    if not len(left_out):
        return p
    # each region's core bins and pixels, grouped by region (one sort, not a pass each)
    bins_by = np.split(bins[np.argsort(cc, kind="stable")], np.cumsum(counts)[:-1])
    px = np.flatnonzero(L)
    lbl = comp.ravel()[px]
    px_by = np.split(px[np.argsort(lbl, kind="stable")],
                     np.cumsum(np.bincount(lbl, minlength=n))[:-1])
    flat_lab, flat_p = lab_ref.reshape(-1, 3), p.reshape(-1)
    h_by = {int(r): np.bincount(bins_by[r], minlength=nb).astype(np.float64) for r in left_out}
    # the largest of them, and which pairs have overlapping colours
    big = ([int(r) for r in left_out[np.argsort(-counts[left_out], kind="stable")[:_SIMILAR_MAX]]]
           if alike else [])
    root = (np.stack([np.sqrt(h_by[r] / h_by[r].sum()) for r in big]) if big
            else np.zeros((0, nb)))
    similar = (root @ root.T) > _SIMILAR_BC
    np.fill_diagonal(similar, False)
    rank = {r: i for i, r in enumerate(big)}
    for r in left_out:
        r = int(r)
        h = h_all - h_by[r]
        if r in rank:
            for i in np.flatnonzero(similar[rank[r]]):
                h = h - h_by[big[i]]
        h = cv2.GaussianBlur(h.reshape(_BINS, _BINS * _BINS), (3, 3), 0.7).ravel()
        hf = h / max(h.sum(), 1e-9)
        flat_p[px_by[r]] = ((hf + 1e-4) / (hf + hb + 2e-4))[
            _lab_bins(flat_lab[px_by[r]], _BINS)]
    return p


def _valid_at(valid: np.ndarray, field: np.ndarray) -> np.ndarray:
    """``valid`` (H, W) bool looked up at the nearest pixel of ``field`` (H, W, 2)."""
    m = cv2.remap(valid.astype(np.uint8), np.ascontiguousarray(field[..., 0]),
                  np.ascontiguousarray(field[..., 1]), cv2.INTER_NEAREST,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return m.astype(bool)


def _consensus_growth(lab_r, sources, base, mask, valid, P, model):
    """Pixels near L that the reference alone shows differently (a cast shadow, a
    part of the mover the scan missed): at least ``max(2, S/2)`` sources, sampled
    through their geometry-bounded matches, agree with one another and the
    reference disagrees with all of them (ΔE >= ``select_tau``). With
    ``select_grow_alone``, also where no source agrees with the reference, at
    least two see the pixel (even if they disagree among themselves: with three
    photos, one source often shows its own mover there) and the reference's
    colour is more likely a mover's than the scene's (``model``: the ``_mover_model`` of
    ``mask``).
    Only components touching L are kept, so the consensus never acts far from a
    detected mover.

    Returns ``(grown, alone)`` (H, W) bool: the pixels added to L, and those of
    them that only the second rule added (weaker evidence: the caller may veto
    them where the geometry explains the reference)."""
    S = len(sources)
    near = dilate_disc(mask, P.select_grow_px) & ~mask
    if S < 2 or not near.any():
        return np.zeros(mask.shape, bool), np.zeros(mask.shape, bool)
    ring = dilate_disc(mask, 2 * P.select_grow_px) & ~mask
    # only the box of the ring (which holds ``near``) is sampled, 8 px wider so
    # that the 1 px blur there equals the whole image's
    ry, rx = np.nonzero(ring | near)
    y0, y1 = max(ry.min() - 8, 0), min(ry.max() + 9, mask.shape[0])
    x0, x1 = max(rx.min() - 8, 0), min(rx.max() + 9, mask.shape[1])
    box = (slice(y0, y1), slice(x0, x1))
    ys, xs = np.nonzero(near[box])
    ring_b = ring[box]
    lab_rb = lab_r[box]

    def sample(k):
        f = np.ascontiguousarray(base[k][box])
        warped, ins = sample_bilinear(sources[k], f)
        if valid is not None:
            ins &= _valid_at(valid[k], f)
        lab_k = blurred_lab(warped, 1.0)
        # exposure and white balance: the source's median Lab offset to the
        # reference around L, so a darker reference is not a "difference"
        around = ring_b & ins
        if around.sum() > 50:
            lab_k = lab_k + np.median(lab_rb[around] - lab_k[around], axis=0)
        return lab_k[ys, xs], ins[ys, xs]

    per_source = for_each_source(sample, S)
    labs = np.stack([lab for lab, _ in per_source])  # (S, n, 3)
    ok = np.stack([ins for _, ins in per_source])  # (S, n)
    tau = P.select_tau
    d = pairwise_delta_e(labs)  # (S, S, n)
    agree = (d < tau) & ok[:, None] & ok[None]
    count = agree.sum(1)  # sources agreeing with source k (itself included)
    best = np.argmax(count, 0)
    n_best = count[best, np.arange(len(ys))]
    cons = labs[best, np.arange(len(ys))]
    d_ref = delta_e(lab_rb[ys, xs], cons)
    need = max(2, int(np.ceil(0.5 * S - 1e-6)))
    hit = np.zeros(mask.shape, np.uint8)
    agreed = (n_best >= need) & (d_ref >= tau)
    hit[ys + y0, xs + x0] = agreed
    alone = np.zeros(mask.shape, bool)
    if P.select_grow_alone:
        # no source agrees with the reference (those outside their frame aside),
        # and the reference shows the colours of L's movers there: a pixel next
        # to the mover whose sources show their own movers (its trail in a
        # video) keeps the scene's colours and is left alone
        unmatched = (((delta_e(labs, lab_rb[ys, xs]) >= tau) | ~ok).all(0) & (ok.sum(0) >= 2)
                     & (_mover_probability(model, lab_rb[ys, xs]) > 0.5))
        hit[ys + y0, xs + x0] |= unmatched
        alone[ys + y0, xs + x0] = unmatched & ~agreed
    hit = cv2.morphologyEx(hit, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    grown = capped_growth(mask, hit > 0)
    return grown, grown & alone


def _lab_bins(x: np.ndarray, bins: int) -> np.ndarray:
    """Bin index of Lab colours ``x`` (..., 3) in a ``bins``³ grid (as GrabCut-style
    colour models here: L* 0–100, a*, b* −64–64)."""
    lum = np.clip(x[..., 0] / 100 * bins, 0, bins - 1).astype(np.intp)
    a = np.clip((x[..., 1] + 64) / 128 * bins, 0, bins - 1).astype(np.intp)
    b = np.clip((x[..., 2] + 64) / 128 * bins, 0, bins - 1).astype(np.intp)
    return (lum * bins + a) * bins + b


def _lab_hist(values: np.ndarray, bins: int) -> np.ndarray:
    """Normalised histogram (bins³,) float64 of Lab colours ``values`` (n, 3), blurred
    over neighbouring (a, b) bins (σ 0.7 bin) so that close colours share mass."""
    h = np.bincount(_lab_bins(values, bins), minlength=bins ** 3).astype(np.float64)
    h = cv2.GaussianBlur(h.reshape(bins, bins * bins), (3, 3), 0.7).ravel()
    return h / max(h.sum(), 1e-9)


def _lab_offset(lab_r: np.ndarray, lab_w: np.ndarray, where: np.ndarray) -> np.ndarray:
    """A source's exposure and white-balance offset: the median of the reference's
    Lab minus the source's matched Lab (both (H, W, 3) float32) over every 7th
    pixel of ``where`` (H, W) bool. (3,) float32; zero with 100 pixels or fewer."""
    off = np.flatnonzero(where)[::7]
    if len(off) <= 100:
        return np.zeros(3, np.float32)
    return np.median(lab_r.reshape(-1, 3)[off] - lab_w.reshape(-1, 3)[off], axis=0
                     ).astype(np.float32)


def _coarse_fill(values: np.ndarray, valid: np.ndarray, scale: int = 8) -> np.ndarray:
    """``values`` (H, W, C) float32 filled where not ``valid`` by normalised convolution
    (``fields.interpolate_field``) on a grid ``scale`` times coarser, upsampled
    bilinearly: a smooth field's interpolation at 1/scale² of the cost."""
    H, W = valid.shape
    h, w = max(1, H // scale), max(1, W // scale)
    wv = cv2.resize(valid.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    num = cv2.resize(np.where(valid[..., None], values, 0).astype(np.float32), (w, h),
                     interpolation=cv2.INTER_AREA).reshape(h, w, -1)
    coarse = num / np.maximum(wv, 1e-6)[..., None]
    coarse = interpolate_field(coarse, wv < 0.05)
    return cv2.resize(coarse, (W, H), interpolation=cv2.INTER_LINEAR).reshape(H, W, -1)


def to_the_border(mask: npt.NDArray[np.bool_], px: int) -> npt.NDArray[np.bool_]:
    """The pixels between ``mask`` (H, W) bool and the image's edge, along rows and
    columns, where the mask comes within ``px`` of that edge (not the mask's own
    pixels). (H, W) bool.

    The scans compare p × p patches, so a mover cut by the frame's edge is flagged
    up to a few pixels short of it (``px``: the patch size). A fresh-user trial
    found a bottle's green edge left in a clean photo (shaky_desk6, ``--ref
    desk6.jpg``: the last column unflagged in 230 of its 383 rows)."""
    out = np.zeros_like(mask)
    k = max(0, min(px, mask.shape[0], mask.shape[1]))
    if k == 0:
        return out
    out[:, -k:] |= np.logical_or.accumulate(mask[:, -k:], axis=1)
    out[:, :k] |= np.logical_or.accumulate(mask[:, :k][:, ::-1], axis=1)[:, ::-1]
    out[-k:] |= np.logical_or.accumulate(mask[-k:], axis=0)
    out[:k] |= np.logical_or.accumulate(mask[:k][::-1], axis=0)[::-1]
    return out & ~mask


def unseen_part_of_replaced(unseen: npt.NDArray[np.bool_], replaced: npt.NDArray[np.bool_],
                            mask: npt.NDArray[np.bool_], max_px: int) -> npt.NDArray[np.bool_]:
    """The pixels of ``unseen`` in a region of ``mask`` that ``replaced`` covers in
    part, within ``max_px`` (chessboard distance) of a replaced pixel; all (H, W)
    bool. A region no source replaced at all is not taken (a mover out of every
    other frame stays as the reference shows it)."""
    n, comp = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    hit = np.zeros(n, bool)
    hit[np.unique(comp[replaced])] = True
    hit[0] = False
    near = cv2.distanceTransform((~replaced).astype(np.uint8), cv2.DIST_C, 3) <= max_px
    return unseen & hit[comp] & near


def min_witnesses(n_sources: int) -> int:
    """How many sources must witness a lingering mover (``_minority_witnesses``):
    ``max(2, ⌈S / 3⌉)``, 2 up to 6 sources.

    With many photos, two of them are a small minority, and across a wide
    baseline two far views often agree against the reference where static
    3-D structure occludes what it shows (a fountain's basin over the ground
    beside it): with 10 views, two witnesses took static ground for a lingering
    mover and refilled it. Measured on 6 composites of 10 views (the choice) and
    6 others of 9 views with another seed (the check; ``dynremove composite
    --n-views 9 --seed 1``): damage 2.03 → 1.23 % and 1.74 → 1.20 %, leftover
    22.4 → 22.5 % and 29.2 → 29.9 %, whole-image PSNR +0.68 and +0.56 dB. Up to
    6 sources (7 photos) nothing changes.
    """
    return max(2, -(-int(n_sources) // 3))


def darker(lab: npt.NDArray[np.float32], lab_seen: npt.NDArray[np.float32], tau: float
           ) -> npt.NDArray[np.bool_]:
    """Where ``lab`` shows ``lab_seen``'s colour in shadow: its L lower by ``tau`` or
    more, and its a, b within that L difference (CIE76 units; (..., 3) float Lab
    in, (...) bool out). A shadow or a dark reflection lowers L far more than it
    moves the hue."""
    dL = lab_seen[..., 0] - lab[..., 0]
    dab = np.sqrt(((lab_seen[..., 1:] - lab[..., 1:]) ** 2).sum(-1))
    return (dL >= tau) & (dab < dL)


def smooth_gain(L: npt.NDArray[np.float32], L_seen: npt.NDArray[np.float32],
                where: npt.NDArray[np.bool_], tau: float, *, sigma_px: float = 3.0
                ) -> npt.NDArray[np.bool_]:
    """The pixels of ``where`` at which ``L`` is ``L_seen`` times a smooth gain: the
    gain g, the ratio (L + 1) / (L_seen + 1) averaged over ``where`` by a normalised
    Gaussian of σ ``sigma_px``, leaves ``|(L + 1) - g (L_seen + 1)|`` under ``tau / 2``.
    A shadow darkens the ground and keeps its texture; a dark object over it (a
    dark coat in a crowd, next to a mover) does not (CIE L in 0-100; (H, W) in and
    out). Without it, breakdance's moving crowd took 2,600 px of such "shadow"."""
    ratio = np.where(where, (L + 1.0) / (L_seen + 1.0), 0.0).astype(np.float32)
    num = cv2.GaussianBlur(ratio, (0, 0), sigma_px)
    den = cv2.GaussianBlur(where.astype(np.float32), (0, 0), sigma_px)
    gain = num / np.maximum(den, 1e-6)
    return where & (np.abs((L + 1.0) - gain * (L_seen + 1.0)) < 0.5 * tau)


def capped_growth(core: npt.NDArray[np.bool_], add: npt.NDArray[np.bool_]
                  ) -> npt.NDArray[np.bool_]:
    """The pixels of ``add`` outside ``core`` (both (H, W) bool) that connect to it
    (8-connected through ``core | add``), each component of ``core`` growing by at
    most its own area: a shadow is no larger than its mover, and a small false
    alarm must not seed a large region. (H, W) bool."""
    n, comp = cv2.connectedComponents((core | add).view(np.uint8), connectivity=8)
    added = add & ~core
    a_core = np.bincount(comp[core], minlength=n)
    a_added = np.bincount(comp[added], minlength=n)
    ok = (a_core > 0) & (a_added <= a_core)
    ok[0] = False
    return ok[comp] & added


def attach_shadow(region: npt.NDArray[np.uint8], dark: npt.NDArray[np.bool_]
                  ) -> npt.NDArray[np.uint8]:
    """``region`` (H, W) uint8 0/1 with the pixels of ``dark`` (H, W) bool that
    connect to it (``capped_growth``). Returns (H, W) uint8 0/1."""
    return region | capped_growth(region > 0, dark).view(np.uint8)


def _minority_witnesses(lab_r: np.ndarray, lab_w: np.ndarray, geo_ok: np.ndarray,
                        flow_agree: np.ndarray, mask: np.ndarray, ratio: float, *,
                        found=None, one_witness: bool = False, min_frac: float = 5e-4,
                        tau: float = 10.0, bins: int = 12
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mover that lingered in most photos, seen free in a minority of the sources.

    The scans' majority rule calls such an object static: the reference and the
    sources that still show it out-vote the (at least two) sources that saw the
    background. Which side shows the mover cannot be told by counting: the same
    counts arise where two sources show their *own* movers over the reference's
    background. Issue 10 asks for the rule "a region seen free in a minority of
    the sources (at least 2) is filled from them when they agree with each other
    and with the surroundings"; here it is (not in the paper):

    1. **Witnesses.** Pixels where at least two sources (``min_witnesses``: more
       from 7 sources up) agree with each other
       (CIE76 ΔE < ``tau``) and not with the reference, sampled through a match
       the geometry allows (the flow where it is valid, else the homography plus
       the parallax of the valid matches around). A source whose flow found the
       reference's colour anyway (``flow_agree``) still shows that content and
       is no witness; with ``found(k, region)`` (the epipolar search, used where
       the set has much parallax), neither is one in which the reference's
       content lies somewhere on its epipolar line.
    2. **Surroundings, colour.** The histogram of the reference's Lab over every
       pixel that no witnesses dispute (outside ``mask``) models the static
       photo. Where the witnesses' colour is more common there than the
       reference's own by more than ``ratio`` (log-likelihood ratio, smoothed
       over σ 3 px), the reference shows something foreign to the scene; where
       theirs is the rarer colour, they show their own movers.
    3. **Regions.** Hysteresis (seeds above ``ratio``, grown through witnessed
       pixels above 1.5), holes filled; then grown into the witnessed pixels next
       to them where the reference shows the witnesses' colour darker by a smooth
       gain (``darker``, ``smooth_gain``: the mover's cast shadow or reflection,
       which the colour test cannot tell from the scene), by at most their own
       area (``attach_shadow``); components
       under ``min_frac`` of the image dropped.
    4. **Surroundings, geometry.** At least two (``min_witnesses``) of a region's
       witnesses must see its surroundings (a ring 3–10 px out) as the reference does on
       ``_RING_OK`` of it: across a wide baseline a whole neighbourhood differs,
       and such sources witness nothing about what the reference hides.
    5. **Three photos** (``one_witness``, for two sources; not in the paper). Two
       witnesses cannot be had, and a cup moved by a few centimetres between
       two of the three shots is then seen free in one source only: the scans
       flag the part of it that both sources see past and leave the rest
       (``bursts/tim6`` as three photos: a half-removed, translucent cup).
       One witness counts where the other source still shows the reference's
       content (near it in colour, or its flow found it), and a region must
       lie in L on ``_ONE_WITNESS_IN_L`` of its area: the scans found part of
       the mover (a single witness is weak evidence, and across a wide baseline
       a misaligned view "witnesses" static 3-D structure). The caller raises
       ``min_frac`` to ``_ONE_WITNESS_FRAC`` and takes only the region's part
       outside L (inside L the fill decides as before).

    Parameters
    ----------
    lab_r : (H, W, 3) float32 ndarray
        The reference, blurred Lab.
    lab_w : (S, H, W, 3) float32 ndarray
        Each source sampled through that match, blurred Lab, exposure matched.
    geo_ok : (S, H, W) bool ndarray
        Where that match lies inside the source's frame (and content).
    flow_agree : (S, H, W) bool ndarray
        Where the source's flow match agrees with the reference in colour.
    mask : (H, W) bool ndarray
        The current dynamic map (excluded from the colour model and the rings).
    ratio : float
        ``Params.select_minority`` (>= 1).
    one_witness : bool
        Step 5: one witness suffices (the caller sets it for two sources).

    Returns
    -------
    region : (H, W) bool ndarray
        Where the reference shows a mover that two or more witnesses saw past
        (may overlap ``mask``).
    witnessed : (H, W) bool ndarray
        The pixels of ``region`` that the witnesses themselves dispute (before
        the regions' morphology).
    witnesses : (S, H, W) bool ndarray
        Over each region, the sources that witnessed it (and see its
        surroundings): the only ones that may fill it.
    """
    S, H, W = geo_ok.shape
    n_wit = 1 if one_witness else min_witnesses(S)
    out = np.zeros((H, W), bool)
    none = (out, out, np.zeros((S, H, W), bool))
    if S < 2:
        return none
    near = geo_ok & (delta_e(lab_w, lab_r) < tau)
    dis = geo_ok & ~near & ~flow_agree

    raw = np.zeros((H, W), bool)

    # one witness only where a source still shows the reference's content: the
    # split of a mover that lingered in one of two sources (step 5)
    split = (near | flow_agree).any(0) if one_witness else True

    def witnessed():
        ys, xs = np.nonzero((dis.sum(0) >= n_wit) & split)
        d = dis[:, ys, xs]  # (S, n)
        v = lab_w[:, ys, xs]  # (S, n, 3)
        agree = (pairwise_delta_e(v) < tau) & d[:, None] & d[None]
        count = agree.sum(1)  # (S, n): witnesses agreeing with source k, itself included
        best = np.argmax(count, 0) if len(ys) else np.zeros(0, np.intp)
        cand = np.zeros((H, W), np.uint8)
        cand[ys, xs] = count[best, np.arange(len(ys))] >= n_wit
        raw[:] = cand > 0
        cand = cv2.morphologyEx(cv2.morphologyEx(cand, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)),
                                cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
        return cand, ys, xs, v[best, np.arange(len(ys))]

    cand, ys, xs, v_best = witnessed()
    if found is not None and cand.any():
        # a source in which the reference's content lies somewhere on its epipolar
        # line still shows it (the match was only misplaced): no witness there
        # (searched only where this source would witness; the sources on threads)
        shown = for_each_source(lambda k: found(k, (cand > 0) & dis[k]), S)
        for k in range(S):
            dis[k] &= ~shown[k]
        cand, ys, xs, v_best = witnessed()
    if not cand.any():
        return none
    # the colour model of the undisputed static photo
    undisputed = ~cv2.dilate(cand, np.ones((9, 9), np.uint8)).astype(bool) & ~mask
    if undisputed.sum() < 0.05 * H * W:
        return none
    h = _lab_hist(lab_r[undisputed], bins) + 0.05 / bins ** 3  # floor: 5 % of uniform
    # the witnesses' colour: the best-supported agreeing source at each pixel
    wit = np.zeros((H, W, 3), np.float32)
    wit[ys, xs] = v_best
    llr = np.where(cand > 0, np.log(h[_lab_bins(wit, bins)]) - np.log(h[_lab_bins(lab_r, bins)]),
                   0.0).astype(np.float32)
    llr = cv2.GaussianBlur(llr, (0, 0), 3.0)
    hi = ((cand > 0) & (llr > np.log(ratio))).astype(np.uint8)
    hi = cv2.morphologyEx(hi, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    lo = ((cand > 0) & (llr > np.log(1.5))).astype(np.uint8)
    lo = cv2.morphologyEx(lo, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) | hi
    n, comp = cv2.connectedComponents(lo, connectivity=8)
    seeded = np.zeros(n, bool)
    seeded[np.unique(comp[hi > 0])] = True
    seeded[0] = False
    grown = fill_holes(seeded[comp].astype(np.uint8))
    # its cast shadow (or dark reflection): the scene's own colour, darker, so the
    # colour test leaves it out, and the ring below would then lie on it, where the
    # witnesses see the ground unshadowed (a lingering mover with a shadow was
    # rejected whole, or its shadow's darkness blended into the fill: tim6's cup)
    dark = (cand > 0) & darker(lab_r, wit, tau)
    grown = attach_shadow(grown, dark & smooth_gain(lab_r[..., 0], wit[..., 0], dark, tau))
    n, comp, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_frac * H * W
    keep[0] = False
    # the witnesses must see the region's surroundings as the reference does:
    # where their whole neighbourhood differs (another side of a wide baseline),
    # they are no witnesses of what the reference hides
    agree_r = near | flow_agree
    wit_map = np.zeros((S, H, W), bool)
    for c in np.nonzero(keep)[0]:
        bx, by, bw, bh = stats[c, :4]
        ya, yb = max(by - 12, 0), min(by + bh + 12, H)
        xa, xb = max(bx - 12, 0), min(bx + bw + 12, W)
        R = comp[ya:yb, xa:xb] == c
        ring = dilate_disc(R, 10) & ~dilate_disc(R, 3) & ~mask[ya:yb, xa:xb]
        if ring.sum() < 20:
            keep[c] = False
            continue
        is_wit = dis[:, ya:yb, xa:xb][:, R].mean(1) >= 0.5
        ring_ok = agree_r[:, ya:yb, xa:xb][:, ring].mean(1)
        good = is_wit & (ring_ok >= _RING_OK)
        keep[c] = good.sum() >= n_wit
        if one_witness and keep[c]:
            keep[c] = mask[ya:yb, xa:xb][R].mean() >= _ONE_WITNESS_IN_L
        if keep[c]:
            wit_map[:, ya:yb, xa:xb] |= good[:, None, None] & R[None]
    region = keep[comp]
    return region, region & raw, wit_map


def member_median(values: npt.NDArray[np.uint8], member: npt.NDArray[np.bool_]
                  ) -> npt.NDArray[np.uint8]:
    """Per-channel median of ``values`` (S, n, 3) uint8 over the sources ``member``
    (S, n) marks (at least one per column), as uint8 (n, 3): of an even count,
    the middle pair's mean rounded half up. Computed in integers (sorting, no
    NaN median)."""
    v = np.where(member[..., None], values, np.uint16(512)).astype(np.uint16)
    v.sort(axis=0)
    m = member.sum(0)
    i = np.arange(values.shape[1])
    lo, hi = v[(m - 1) // 2, i], v[m // 2, i]
    return ((lo + hi + 1) // 2).astype(np.uint8)


def mixture_detail(chosen: npt.NDArray[np.uint8], mixture: npt.NDArray[np.uint8],
                   rep: npt.NDArray[np.bool_], sigma_px: float) -> npt.NDArray[np.uint8]:
    """The median of the combined sources, at the chosen source's level.

    The blend brings each chosen source to the reference's level with an offset
    measured on the ring around the replaced region, where the chosen source
    alone is seen (``montage.offset_blend``); the replaced pixels show the median
    of the sources combined there instead. Where the others are brighter or
    darker than the chosen one (photos exposed differently, light that changes
    with the view), that median's level is not the one the offset corrects: on
    ``bursts/sanitizer`` the median of five photos came out ΔE ~7 darker and
    greyer than the table around it, a bottle-shaped shade. So only the median's
    detail is kept: its difference from the chosen source, less that
    difference's local mean (a Gaussian of σ ``sigma_px`` over the replaced
    pixels, normalised: Knutsson & Westin's normalised convolution, CVPR 1993).
    What averages out (noise, a sub-pixel misalignment, a source's own glint) is
    finer than that; a level that differs is smoother.

    Parameters
    ----------
    chosen, mixture : (n, 3) uint8 ndarrays
        The chosen source and the median at the ``n`` pixels of ``rep``
        (row-major).
    rep : (h, w) bool ndarray
    sigma_px : float
        σ of the local mean, pixels of ``rep``'s grid.

    Returns
    -------
    (n, 3) uint8 ndarray
        ``chosen + (mixture − chosen) − G_σ(mixture − chosen)``, rounded, clipped.
    """
    ys, xs = np.nonzero(rep)
    if not len(ys):
        return mixture.copy()
    r = int(np.ceil(3 * sigma_px)) + 1
    y0, y1 = max(ys.min() - r, 0), min(ys.max() + r + 1, rep.shape[0])
    x0, x1 = max(xs.min() - r, 0), min(xs.max() + r + 1, rep.shape[1])
    d = mixture.astype(np.float32) - chosen.astype(np.float32)
    img = np.zeros((y1 - y0, x1 - x0, 3), np.float32)
    img[ys - y0, xs - x0] = d
    w = np.zeros((y1 - y0, x1 - x0), np.float32)
    w[ys - y0, xs - x0] = 1.0
    num = cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_CONSTANT)
    den = cv2.GaussianBlur(w, (0, 0), sigma_px, borderType=cv2.BORDER_CONSTANT)
    local = num[ys - y0, xs - x0] / np.maximum(den[ys - y0, xs - x0], 1e-6)[:, None]
    v = mixture.astype(np.float32) - local
    v += 0.5
    return np.clip(v, 0, 255, out=v).astype(np.uint8)


# σ (working px) tried by ``reference_blur``, and the gradient energy ratio under
# which the reference counts as softer than a source
_BLUR_SIGMAS = (0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
_SOFTER = 0.6
_BLUR_MIN_PX = 400


def _gradient_energy(gray: np.ndarray, where: np.ndarray) -> float:
    """Mean squared Sobel gradient of ``gray`` (float32) over ``where``."""
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    return float((gx * gx + gy * gy)[where].mean())


def reference_blur(reference: np.ndarray, source: np.ndarray, static: np.ndarray) -> float:
    """The Gaussian σ (px) that brings a source's sharpness down to the reference's.

    A reference shot with camera shake or out of focus is softer than the other
    photos, and a fill taken from them shows as a sharp patch (a visual trial: the
    bottle's outline in crisp wood grain inside a soft photo). Over ``static``
    pixels (the scene, where the aligned source agrees with the reference), the
    mean squared gradient of the reference is compared with the source's: under
    ``_SOFTER`` of it, σ is the one of ``_BLUR_SIGMAS`` whose blur of the source
    comes nearest the reference's energy (in log ratio); else 0. Gradient energy,
    not a pixel difference, so that a match a pixel off does not read as blur.

    reference, source : (h, w, 3) uint8 BGR, aligned; static : (h, w) bool.
    Returns σ in px (0.0: no blur; also with fewer than ``_BLUR_MIN_PX`` pixels).
    """
    if static.sum() < _BLUR_MIN_PX:
        return 0.0
    g_ref = cv2.cvtColor(reference, cv2.COLOR_BGR2GRAY).astype(np.float32)
    g_src = cv2.cvtColor(source, cv2.COLOR_BGR2GRAY).astype(np.float32)
    e_ref, e_src = _gradient_energy(g_ref, static), _gradient_energy(g_src, static)
    if e_src <= 0 or e_ref >= _SOFTER * e_src:
        return 0.0
    target = math.log(max(e_ref, 1e-6))
    best = min(_BLUR_SIGMAS, key=lambda sg: abs(math.log(max(_gradient_energy(
        cv2.GaussianBlur(g_src, (0, 0), sg), static), 1e-6)) - target))
    return float(best)


def _cluster_median(cand_img, labs, lab, rep, free, tau):
    """Each replaced pixel's chosen source, replaced by the per-channel median of the
    free sources that agree with it (ΔE < ``tau``): the chosen region keeps one
    source's content while its noise and sub-pixel misalignment average out.
    The median's level stays the chosen source's (``mixture_detail``)."""
    out = cand_img.copy()
    ys, xs = np.nonzero(rep)
    chosen = lab[ys, xs]
    lab_c = labs[chosen, ys, xs]  # (n, 3)
    tau = np.broadcast_to(tau, rep.shape)[ys, xs]
    member = free[:, ys, xs] & (delta_e(labs[1:, ys, xs], lab_c) < tau)
    member[chosen - 1, np.arange(len(ys))] = True
    out[chosen, ys, xs] = mixture_detail(cand_img[chosen, ys, xs],
                                         member_median(cand_img[1:, ys, xs], member),
                                         rep, LIGHT_SIGMA_PX)
    members = np.zeros((len(cand_img) - 1,) + rep.shape, bool)
    members[:, ys, xs] = member
    return out, members


def grow_into_rim(lab: npt.NDArray[np.intp], allowed: npt.NDArray[np.bool_],
                  free: npt.NDArray[np.bool_], labs: npt.NDArray[np.float32],
                  mover_p: npt.NDArray[np.floating], tau: float, px: int
                  ) -> npt.NDArray[np.intp]:
    """The cut's replaced region grown by a rim of ``px`` pixels round a mover.

    A mover's edge is blurred over a few pixels (the lens, JPEG, its motion), and
    the outermost of them differ from the scene by less than ``tau``: the cut
    keeps them as the reference, and the clean photo shows a thin line of the
    mover's colour round where it stood, the blend's ring lying on it too (tim6's
    cup: a pale outline, the fill paler than the table). Here each kept pixel
    within ``px`` of a replaced one (3×3 steps, ``grow_replaced``) takes that
    neighbour's source where the source is free there and within ``tau`` of the
    reference (the same scene, up to the halo), and the nearest replaced pixel
    has the movers' colours (``mover_p`` ≥ 0.5: a mover's edge, not the edge of
    static structure the scans flagged).

    Measured (session 50, ``eval``): on the composites, whose pasted movers have
    no blurred edge and whose damage leaves out the 5 px round the true mask,
    damage 0.455 → 0.467 %, leftover 15.53 → 15.31 %, PSNR −0.04 dB; without the
    colour condition damage rose to 0.494 %.

    Parameters
    ----------
    lab : (h, w) int ndarray
        The cut's labels (0: the reference, k: source k − 1).
    allowed : (h, w) bool ndarray
        Where the rim may go (the fill region, not what the static 3-D test kept).
    free : (S, h, w) bool ndarray
        Where each source shows no mover of its own and is inside its frame.
    labs : (S + 1, h, w, 3) float32 ndarray
        The candidates' blurred CIE Lab, the reference first.
    mover_p : (h, w) float ndarray
        The reference's probability of the movers' colours.
    tau : float
        CIE76 ΔE of agreement.
    px : int
        The rim's width (analysis pixels).

    Returns
    -------
    lab : (h, w) int ndarray
        A new label map where the rim applies (else ``lab`` itself).
    """
    near = grow_replaced(np.where(allowed | (lab != 0), lab, -1).astype(np.int16), px)
    ys, xs = np.nonzero((lab == 0) & allowed & (near > 0))
    if len(ys) == 0:
        return lab
    k = near[ys, xs].astype(np.intp)
    ok = free[k - 1, ys, xs] & (delta_e(labs[k, ys, xs], labs[0, ys, xs]) < tau)
    # the nearest replaced pixel (each replaced pixel its own label of the transform)
    _, idx = cv2.distanceTransformWithLabels((lab == 0).astype(np.uint8), cv2.DIST_L2, 3,
                                             labelType=cv2.DIST_LABEL_PIXEL)
    zy, zx = np.nonzero(lab != 0)
    lut = np.zeros(int(idx.max()) + 1, np.intp)
    lut[idx[zy, zx]] = np.arange(len(zy))
    j = lut[idx[ys, xs]]
    ok &= mover_p[zy[j], zx[j]] >= 0.5
    if not ok.any():
        return lab
    out = lab.copy()
    out[ys[ok], xs[ok]] = k[ok]
    return out


def misplaced_pieces(label: npt.NDArray[np.intp], replaced: npt.NDArray[np.bool_],
                     d_ref: npt.NDArray[np.float32], usable: npt.NDArray[np.bool_],
                     suspect: npt.NDArray[np.bool_], max_de: float, *,
                     min_px: int = _MISPLACED_MIN_PX, ring_px: int = _MISPLACED_RING_PX,
                     min_ring_px: int = _MISPLACED_MIN_RING_PX,
                     max_share: float = _MISPLACED_MAX_SHARE) -> npt.NDArray[np.bool_]:
    """The pieces of the fill whose source shows content misplaced there.

    A piece is one source's 8-connected part of the replaced region. Where the
    piece borders the photo that the fill kept (the reference, outside L), its
    source must continue that photo: the fill's seam with the kept photo is
    there. A source whose match is tens of pixels off (the near ground of a
    wide-baseline set, whose parallax no field follows: a lawn matched to the
    gravel in front of it) differs from the reference all along that border.
    The piece is judged by the median CIE76 ΔE between its source and the
    reference over the kept pixels within ``ring_px`` of it (outside L, inside
    the source's frame): over ``max_de``, misplaced. The blend cannot mend it
    (``montage.offset_blend`` leaves such ring pixels out as content, not
    light), and the graph cut's seam cost is one term among others. Not in
    the paper; the test is Photomontage's seam cost (Agarwala et al., SIGGRAPH
    2004) read on a finished fill.

    Parameters
    ----------
    label : (h, w) int ndarray
        The fill's labels (0 the reference, k ≥ 1 source k − 1).
    replaced : (h, w) bool ndarray
        The pixels taken from a source (the pieces are judged there).
    d_ref : (S + 1, h, w) float32 ndarray
        CIE76 ΔE between the reference and each label's candidate (blurred Lab;
        index 0 the reference itself).
    usable : (S + 1, h, w) bool ndarray
        Where each label's candidate lies inside its frame.
    suspect : (h, w) bool ndarray
        Kept pixels that may show a mover (L, and the movers' colours): no
        evidence of the scene.
    max_de : float
        > 0.
    min_px, ring_px, min_ring_px : int
        Pieces under ``min_px`` pixels, or with fewer than ``min_ring_px``
        kept pixels around them, are not judged by their own ring; one whose
        outline lies on misplaced pieces for half of it or more goes with them
        (repeated while they grow).
    max_share : float
        Where the misplaced pieces would take more than this share of
        ``replaced``, none is returned: so much of a fill at odds with the kept
        photo says that photo still holds the mover (L missed parts of it), not
        that the fill is misplaced.

    Returns
    -------
    misplaced : (h, w) bool ndarray
        The pixels of the misplaced pieces.

    Examples
    --------
    Two pieces of source 1 beside a kept photo: the first continues it (ΔE 4
    on its ring), the second, a fifth of the fill, does not (ΔE 35):

    >>> import numpy as np
    >>> lab = np.zeros((12, 30), np.intp); lab[1:11, 1:13] = lab[3:9, 18:24] = 1
    >>> d = np.zeros((2, 12, 30), np.float32); d[1] = 4.0; d[1, :, 15:] = 35.0
    >>> usable = np.ones((2, 12, 30), bool)
    >>> bad = misplaced_pieces(lab, lab > 0, d, usable, np.zeros((12, 30), bool), 20.0)
    >>> int(bad[:, :15].sum()), int(bad[:, 15:].sum())
    (0, 36)
    """
    out = np.zeros(replaced.shape, bool)
    if not replaced.any():
        return out
    h, w = replaced.shape
    kept = ~replaced & (label == 0) & ~suspect
    unjudged = []  # (box, piece) of the pieces without enough kept photo around them
    for k in np.unique(label[replaced]):
        if k < 1:
            continue
        n, comp, stats, _ = cv2.connectedComponentsWithStats(
            (replaced & (label == k)).view(np.uint8), connectivity=8)
        for c in range(1, n):
            bx, by, bw, bh, area = stats[c]
            ya, yb = max(by - ring_px - 1, 0), min(by + bh + ring_px + 1, h)
            xa, xb = max(bx - ring_px - 1, 0), min(bx + bw + ring_px + 1, w)
            piece = comp[ya:yb, xa:xb] == c
            ring = dilate_disc(piece, ring_px) & kept[ya:yb, xa:xb] & usable[k, ya:yb, xa:xb]
            if area < min_px or ring.sum() < min_ring_px:
                unjudged.append(((ya, yb, xa, xb), piece))
            elif np.median(d_ref[k, ya:yb, xa:xb][ring]) > max_de:
                out[ya:yb, xa:xb] |= piece
    # a piece that the misplaced ones enclose (half of its outline or more) lies
    # where the fields are misplaced: it goes with them (a speck of lawn left amid
    # the gravel inpainted around it), in turn as the misplaced region grows
    changed = out.any()
    while changed:
        changed = False
        for (ya, yb, xa, xb), piece in unjudged:
            if out[ya:yb, xa:xb][piece].any():
                continue
            edge = dilate_disc(piece, 1) & ~piece
            if edge.any() and out[ya:yb, xa:xb][edge].mean() >= 0.5:
                out[ya:yb, xa:xb] |= piece
                changed = True
    # where much of the fill would go, the doubt falls on the kept photo instead: parts
    # of the mover that L left out ring the fill (DAVIS motocross-jump, J 0.41: 30 % of
    # its fill, whose sky and trees Telea turned into the bike's colours)
    if out.sum() > max_share * replaced.sum():
        out[:] = False
    return out


def misfit_regions(replaced: npt.NDArray[np.bool_], offset: npt.NDArray[np.float32],
                   p_ref: npt.NDArray[np.float32], max_levels: float, *,
                   max_p: float = MISFIT_MOVER_P) -> npt.NDArray[np.bool_]:
    """Replaced regions whose fill does not fit the photo around them: to keep.

    The blend (``montage.offset_blend``) adds to the chosen source what makes
    it meet the reference on the region's ring: the photos' exposure and light,
    a few levels. Where it must add more than ``max_levels`` (the median over
    the region of the largest channel's |offset|), the source shows other
    content than the scene around the region continues into (a near-camera
    bollard or kerb whose match lies tens of pixels off, matched to the
    pavement beside it). Where the reference there does not show the
    movers' colours either (its mean P(mover) under ``max_p``), the region is
    static scene that the detection flagged in error, and its fill would only
    damage the photo: the reference is kept.

    Parameters
    ----------
    replaced : (h, w) bool ndarray
        The pixels the fill replaced; its 8-connected regions are judged.
    offset : (h, w, 3) float32 ndarray
        The blend's offset, B/G/R levels; NaN where no source's value was
        written (inpainted pixels: they go with their region).
    p_ref : (h, w) float32 ndarray
        The reference's P(mover colour) (``_reference_mover_probability``).
    max_levels : float
        > 0.
    max_p : float

    Returns
    -------
    misfit : (h, w) bool ndarray
        The pixels of the regions to keep as the reference shows them.

    Examples
    --------
    Two replaced squares: the first filled with an offset of 3 levels (light),
    the second with one of 60 (other content), both with the scene's colours:

    >>> import numpy as np
    >>> rep = np.zeros((8, 16), bool); rep[2:6, 1:5] = rep[2:6, 10:14] = True
    >>> off = np.full((8, 16, 3), np.nan, np.float32)
    >>> off[2:6, 1:5] = 3.0; off[2:6, 10:14] = -60.0
    >>> keep = misfit_regions(rep, off, np.full((8, 16), 0.2, np.float32), 20.0)
    >>> int(keep[:, :8].sum()), int(keep[:, 8:].sum())
    (0, 16)
    """
    n, comp = cv2.connectedComponents(replaced.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(replaced.shape, bool)
    idx = comp.ravel()
    mag = np.abs(offset).reshape(-1, 3).max(1)  # NaN where no source's value
    ok = (idx > 0) & np.isfinite(mag)
    # the median |offset| of each region: one sort by (region, magnitude)
    r_ok, m_ok = idx[ok], mag[ok]
    order = np.lexsort((m_ok, r_ok))
    r_s, m_s = r_ok[order], m_ok[order]
    lo = np.searchsorted(r_s, np.arange(n), "left")
    hi = np.searchsorted(r_s, np.arange(n), "right")
    cnt = hi - lo
    has = cnt > 0
    med = np.zeros(n)
    med[has] = 0.5 * (m_s[lo[has] + (cnt[has] - 1) // 2] + m_s[lo[has] + cnt[has] // 2])
    p = np.nan_to_num(p_ref, nan=0.0).ravel()
    p_mean = np.bincount(idx, weights=p, minlength=n) / np.maximum(
        np.bincount(idx, minlength=n), 1)
    bad = has & (med > max_levels) & (p_mean < max_p)
    bad[0] = False
    return bad[comp]


def region_shares(label: npt.NDArray[np.intp], core: npt.NDArray[np.bool_], *,
                  static: npt.NDArray[np.bool_] | None = None
                  ) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.float64]]:
    """The regions of ``core`` (8-connected; (h, w) int32, 0 outside) and the share
    of each that ``label`` (h, w) took from a source (label != 0): (n,) float64,
    region 0's set to 0. What ``complete_regions`` compares with its share.

    With ``static`` (h, w) bool, the pixels of L that the static 3-D test
    explained, the regions are those of ``core`` ∪ ``static`` and a region's share
    is its replaced pixels of ``core`` over all its pixels: what the test
    explained counts as kept (``complete_regions``).
    """
    m = core if static is None else core | static
    n, comp = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
    size = np.bincount(comp.ravel(), minlength=n)
    n_rep = np.bincount(comp.ravel(), weights=((label != 0) & core).ravel(), minlength=n)
    share = n_rep / np.maximum(size, 1)
    share[0] = 0.0
    return comp, share


def reference_cost(ref_cost: float, p_mover: npt.NDArray[np.floating],
                   usable: npt.NDArray[np.bool_], agree: npt.NDArray[np.bool_],
                   own: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """The data cost of keeping the reference where it is the suspect (inside L), where
    no majority of the photos can say that it shows the mover.

    With two photos (one source) which one shows the mover is not known: the
    colour model must say the reference does and the source does not, or keeping
    the reference costs nothing. With more, where no two photos agree (each source
    shows something of its own there, the reference a third thing), nothing
    outvotes the reference, and it costs nothing where it has not the movers'
    colour (``bursts/shaky_desk6`` as desk1, desk2 and desk4: both sources' bottles
    stood on desk the reference shows, and the sources' consensus, one source,
    pasted its bottle there; with desk6 too, a brown fleck on the desk's edge;
    DAVIS J 0.5918 -> 0.5954, README, session 51). With three photos, also where
    both sources show a mover (the same walker, photographed before and after):
    both candidates have the movers' colours, or the flow followed the reference's
    mover into them (``own``).

    Parameters
    ----------
    ref_cost : float
        ``Params.select_ref_cost``, the cost elsewhere.
    p_mover : (S + 1, h, w) float ndarray
        Each candidate's P(mover colour), the reference first.
    usable : (S + 1, h, w) bool ndarray
    agree : (S + 1, S + 1, h, w) bool ndarray
        Pairs of usable candidates within ``select_tau`` (the diagonal: usable).
    own : (S, h, w) bool ndarray
        Where the flow followed the reference's mover into each source.

    Returns
    -------
    (h, w) float64 ndarray
    """
    S = len(p_mover) - 1
    if S == 1:
        return np.where((p_mover[0] > 0.5) & (p_mover[1] < 0.5), ref_cost, 0.0)
    keep = ((agree.sum((0, 1)) - usable.sum(0)) == 0) & (usable[1:].sum(0) >= 2)
    if S == 2:
        keep |= ((p_mover[1:] > 0.5) | own | ~usable[1:]).all(0) & usable[1:].any(0)
    return np.where(keep & (p_mover[0] < 0.5), 0.0, ref_cost)


def complete_regions(label: npt.NDArray[np.intp], core: npt.NDArray[np.bool_],
                     allowed: npt.NDArray[np.bool_], share: float, reach_px: int, *,
                     regions: tuple[np.ndarray, np.ndarray] | None = None,
                     partial: npt.NDArray[np.bool_] | None = None,
                     static: npt.NDArray[np.bool_] | None = None,
                     judged: tuple[np.ndarray, np.ndarray] | None = None
                     ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.uint8]]:
    """Decide each region of L whole where the graph cut decided most of it.

    A connected region of ``core`` (8-connected) of which at least ``share`` of the
    pixels took a source is a mover. Its pixels that kept the reference are
    mostly the mover's parts whose colour the movers' model misses (a cup's
    brown sleeve in front of a wooden desk, a camel's leg in shadow): kept, they
    stay in the clean photo as fragments of the mover. Each of them within
    ``reach_px`` of the region's replaced pixels (steps of the 8-neighbourhood,
    through the kept pixels of the region) takes a neighbouring replaced
    pixel's source (``morphology.grow_replaced``: a 3×3 grey dilation per step, the
    largest label among the neighbours), where that source is allowed.

    Conversely, a region of which less than ``1 − share`` took a source is static
    (3-D structure the scans flagged, kept by the consensus): its replaced pixels,
    fragments of a fill misplaced on that structure, keep the reference, where the
    reference is allowed; so do the pixels outside ``core`` (the fill's margin)
    whose replaced run only continued them (no pixel of ``core`` left in it).

    With ``static``, the pixels of L that the static 3-D test explained (the
    graph cut keeps the reference there), whether a region is static is judged
    with them: over the regions of ``core`` ∪ ``static``, what the test explained
    counting as kept. A scans' flag whose middle the sources explained (a pillar,
    a statue's edge) leaves unexplained fragments around it, which the cut
    replaced in part: judged alone they were no static region, and their
    misplaced fills stayed in the photo. Whether a region is a mover is still
    judged on ``core`` alone, and a region of ``core`` judged a mover is never
    reverted: a mover beside structure that the test explained (a rider in front
    of a fountain's edge) would otherwise be kept, or not completed.

    Parameters
    ----------
    label : (h, w) int ndarray
        The graph cut's labels: 0 the reference, k >= 1 source k − 1.
    core : (h, w) bool ndarray
        The pixels of L that no static evidence explained (the suspect movers).
    allowed : (L, h, w) bool ndarray
        Where each label may be taken (its data cost is not forbidden: the source
        sees the pixel, shows no mover of its own there).
    share : float
        In (0.5, 1]: the replaced share from which a region counts as replaced
        (and ``1 − share`` the share under which it counts as kept).
    reach_px : int
        How far, in pixel steps, a replaced region's labels spread.
    regions : (comp, frac), optional
        ``region_shares(label, core)``, when the caller has it already.
    partial : (n,) bool ndarray, optional
        Regions (indices of ``comp``) to keep whole as well, whatever their share
        (``partial_movers``); their pixels are marked ``PARTIAL_KEPT``.
    static : (h, w) bool ndarray, optional
        The pixels of L that the static test explained (disjoint from ``core``).
    judged : (comp, frac), optional
        ``region_shares(label, core, static=static)``, when the caller has it already.

    Returns
    -------
    label : (h, w) int ndarray
        ``label`` with those pixels relabelled (a copy; ``label`` is not changed).
    changed : (h, w) uint8 ndarray
        1 where a pixel took a source with its region, 2 where it kept the
        reference with its region, ``PARTIAL_KEPT`` (4) where it kept it with a
        region of ``partial``, 0 elsewhere.

    Measured on the 12 composites and 19 DAVIS sets (README, session 36):
    share 0.7, 6 px took the mean leftover from 16.44 to 15.61 %, the damage from
    0.454 to 0.445 % and the whole-image PSNR from 29.20 to 29.38 dB; DAVIS J
    0.576 → 0.585.
    """
    out = label.copy()
    changed = np.zeros(label.shape, np.uint8)
    comp, frac = region_shares(label, core) if regions is None else regions
    if len(frac) <= 1:
        return out, changed
    # the regions judged: those of core, or of core and what the static test explained
    if static is None:
        jcomp, jfrac = comp, frac
    else:
        jcomp, jfrac = region_shares(label, core, static=static) if judged is None else judged
    rep = out != 0
    kept = jfrac < 1.0 - share
    kept[0] = False  # (not a region of core)
    whole = frac >= share
    whole[0] = False
    # (a part of core that the cut replaced as a mover's stays replaced, whatever the
    # explained pixels around it: a rider before a fountain whose edges the test
    # explained)
    back = kept[jcomp] & ~whole[comp] & rep & allowed[0]
    out[back] = 0
    changed[back] = 2
    if partial is not None:
        keep_p = np.asarray(partial, bool).copy()
        keep_p[0] = False
        back_p = keep_p[comp] & ~kept[jcomp] & rep & allowed[0]
        out[back_p] = 0
        changed[back_p] = PARTIAL_KEPT
        back = back | back_p
    if back.any():
        # the cut's replaced pixels outside ``core`` (the fill's margin) that only
        # continued the reverted ones keep the reference too: a replaced component
        # with no pixel of ``core`` left, next to a reverted pixel
        m, rc = cv2.connectedComponents((out != 0).astype(np.uint8), connectivity=8)
        has_core = np.bincount(rc[core], minlength=m) > 0

        def touching(pixels):  # the replaced components next to ``pixels``, (m,) bool
            near = cv2.dilate(pixels.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            t = np.zeros(m, bool)
            t[np.unique(rc[near])] = True
            return t

        trail = (touching(back) & ~has_core)[rc] & (rc > 0) & allowed[0]
        out[trail] = 0
        changed[trail] = 2
        if partial is not None:
            # (a trail next to a region kept whole as a part of a mover says so)
            changed[trail & touching(changed == PARTIAL_KEPT)[rc]] = PARTIAL_KEPT
    todo = whole[comp] & ~rep
    if not todo.any() or reach_px <= 0:
        return out, changed
    # the replaced pixels' labels grown into the region's kept pixels only (−1: fixed)
    grown = grow_replaced(np.where(rep, out, np.where(todo, 0, -1)).astype(np.int16),
                          int(reach_px))
    ys, xs = np.nonzero(todo & (grown >= 1))
    k = grown[ys, xs].astype(np.intp)
    ok = allowed[k, ys, xs]
    out[ys[ok], xs[ok]] = k[ok]
    changed[ys[ok], xs[ok]] = 1
    return out, changed


def partial_movers(comp: npt.NDArray[np.intp], frac: npt.NDArray[np.floating],
                   label: npt.NDArray[np.intp], p_ref: npt.NDArray[np.floating],
                   shown: npt.NDArray[np.bool_], share: float, min_p: float, *,
                   seen: npt.NDArray[np.bool_] | None = None,
                   max_shown: float = _PARTIAL_AGREE) -> npt.NDArray[np.bool_]:
    """The regions of L replaced only in part whose kept part is the rest of a mover.

    A region of which between ``1 − share`` and ``share`` took a source is left
    by ``complete_regions`` as the graph cut chose. Where its kept part has the
    movers' colours (mean P(mover) of the reference at least ``min_p``) and, on
    most of it (more than ``1 − max_shown``), no source shows what the reference
    shows, that part is no static scene that the sources confirm: it is the
    mover's rest, which no source offered free (three photos of a cup moved by a
    few centimetres: each source shows its own cup over part of it). Replacing
    the other part leaves the mover broken (a cup with holes, half a tube);
    such a region is kept whole. A kept part that the sources confirm (a mask
    that reached over static scene beside the mover) leaves the region as it is,
    and so does one that no source sees at all (``seen``): outside every other
    frame, it is inpainted with the replaced part (``unseen_part_of_replaced``),
    so the mover goes whole that way.

    Parameters
    ----------
    comp : (h, w) int ndarray
        The regions of L, 0 outside (``region_shares``).
    frac : (n,) float ndarray
        Each region's replaced share (``region_shares``).
    label : (h, w) int ndarray
        The graph cut's labels: 0 the reference, k >= 1 source k − 1.
    p_ref : (h, w) float ndarray
        The reference's P(mover colour) (NaN counts 0).
    shown : (h, w) bool ndarray
        Where some source that sees the pixel shows what the reference shows
        (CIE76 ΔE under the fill's tau).
    share : float
        ``Params.select_complete``, in (0.5, 1].
    min_p : float
        ``Params.select_keep_partial``, in (0, 1].
    seen : (h, w) bool ndarray, optional
        Where some source sees the pixel (inside its frame, with content); only
        those kept pixels are judged, and a region kept mostly where none sees
        it is left as it is (default: every pixel seen).
    max_shown : float
        The kept part counts as the mover's only where ``shown`` covers less than
        this share of its judged pixels (default ``_PARTIAL_AGREE``, 0.5).

    Returns
    -------
    partial : (n,) bool ndarray
        The regions to keep whole (index 0, outside L, is False).

    Examples
    --------
    A region half replaced, its kept half with the movers' colours and shown
    by no source, and the same region with its kept half shown by a source:

    >>> import numpy as np
    >>> comp = np.zeros((4, 8), np.intp); comp[:, :4] = 1; comp[:, 4:] = 2
    >>> label = np.zeros((4, 8), np.intp); label[:2] = 1
    >>> frac = np.array([0.0, 0.5, 0.5])
    >>> shown = np.zeros((4, 8), bool); shown[2:, 4:] = True
    >>> partial_movers(comp, frac, label, np.full((4, 8), 0.8), shown, 0.7, 0.5).tolist()
    [False, True, False]
    """
    n = len(frac)
    between = (frac >= 1.0 - share) & (frac < share)
    between[0] = False
    if not between.any():
        return between
    kept_all = (comp > 0) & (label == 0)
    n_kept = np.bincount(comp[kept_all], minlength=n)
    kept = kept_all if seen is None else kept_all & seen
    idx = comp[kept]
    cnt = np.bincount(idx, minlength=n).astype(np.float64)
    p = np.nan_to_num(np.asarray(p_ref, np.float64), nan=0.0)[kept]
    p_mean = np.bincount(idx, weights=p, minlength=n) / np.maximum(cnt, 1)
    shown_share = np.bincount(idx, weights=shown[kept].astype(np.float64),
                              minlength=n) / np.maximum(cnt, 1)
    return (between & (cnt > 0) & (2 * cnt >= n_kept) & (p_mean >= min_p)
            & (shown_share < max_shown))


def median_parallax_px(views: list[TwoView], field: str = "parallax_px") -> float:
    """The parallax of the photo set: the median over the sources of
    ``TwoView.parallax_px`` (px; a source without a measure counts 0), 0 without
    sources. Above ``Params.select_parallax_px`` the default preset treats the
    set as 3-D (``Selection.consensus_mode`` "parallax", ``Params.snap_veto``).
    ``field="parallax_p95_px"``: the same median of the 95th percentile."""
    vals = [getattr(v, field) for v in views]
    return float(np.median([x if np.isfinite(x) else 0.0 for x in vals])) if views else 0.0


def treated_as_3d(views: list[TwoView], params: Params) -> bool:
    """Whether the default preset treats the set as 3-D (``Selection.consensus_mode``
    "parallax": the epipolar search, the colour consensus inside L, GrabCut's veto;
    no majority clean-up of L, no tracking of the movers by the flow).

    3-D where the median over the sources of the 90th percentile of the F inliers'
    distance from the homography (``median_parallax_px``) is over
    ``select_parallax_px``, or the median of their 95th percentile is over
    ``select_parallax_p95_px`` (0 = that test off). Columns and a balcony before
    a façade hold 5-16 % of entry-P10's matches: the 90th percentile falls on the
    façade (2-4 px) and the 95th on the columns (190-400 px), and treated as flat
    such a set refilled its columns (damage 2.9 % of the photo, 0.23 % as 3-D).
    The 95th is not read at the 8 px of the 90th: a mover's matches that fit the
    epipolar geometry reach there (DAVIS car-roundabout with ``--ref 5``, 27 px;
    synthetic scenes, up to 73 px), and the 3-D consensus then keeps a slow mover
    (README, "Session 64").
    """
    if median_parallax_px(views) > params.select_parallax_px:
        return True
    return (params.select_parallax_p95_px > 0
            and median_parallax_px(views, "parallax_p95_px") > params.select_parallax_p95_px)


def select_fill(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                views: list[TwoView], mask: npt.NDArray[np.bool_], params: Params, *,
                valid: npt.NDArray[np.bool_] | None = None,
                flows: npt.NDArray[np.float32] | None = None,
                no_fill: npt.NDArray[np.bool_] | None = None,
                true_background: npt.NDArray[np.uint8] | None = None) -> Selection:
    """Fill ``mask`` by selecting, per region, one source that is free there.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
    sources : (S, H, W, 3) uint8 ndarray
    views : list of TwoView
        The reference → source geometry (H, F, measured parallax) per source.
    mask : (H, W) bool ndarray
        The dynamic map L after the refinement steps.
    params : Params
        ``select_*`` fields (see ``Params``).
    valid : (S, H, W) bool ndarray, optional
        Where each *source* has content (False: a transparent or empty border of
        a pre-aligned frame). Sampling a source where it is not valid counts as
        outside its frame: never evidence, never fill.
    flows : (S, H, W, 2) float32 ndarray, optional
        Each source's homography + flow matches (``dense_correspondence(...,
        method="homography+flow")`` of the gray images), if the caller has them
        (the pipeline keeps them from its correspondence stage); computed here
        otherwise.
    no_fill : (S,) bool ndarray, optional
        Sources whose evidence counts but whose pixels never fill (a black-and-white
        photo beside colour ones).
    true_background : (H, W, 3) uint8 ndarray, optional
        For evaluation only (``dynremove eval --methods true-fields``): the
        reference without its movers (a composite's ``background.png``). The fields
        across L are then its own matches in each source (``dense_correspondence``
        of its gray image, homography + flow), not the ones the method estimates
        from around L: the fill as it would be with the hidden background's
        geometry right, an upper bound on what better fields can give. Everything
        else (L, the consensus, the selection, the blend) is the method's.

    Returns
    -------
    Selection
        ``clean`` equals ``reference`` outside ``mask`` dilated by
        ``select_margin_px``.
    """
    H, W = mask.shape
    S = len(sources)
    P = params
    par = median_parallax_px(views)
    par95 = median_parallax_px(views, "parallax_p95_px")
    mode = "parallax" if treated_as_3d(views, P) else "scan"
    empty = Selection(clean=reference.copy(), replaced=np.zeros((H, W), bool),
                      label=np.full((H, W), -1, np.int16), explained=np.zeros((H, W), bool),
                      movers=np.zeros((S, H, W), bool), no_source=np.zeros((H, W), bool),
                      seams=np.zeros((H, W), bool), parallax_px=par, consensus_mode=mode,
                      parallax_p95_px=par95)
    # a mover cut by the frame's edge: the scans' patches leave the last few pixels
    # before the edge unflagged, the mask is taken to the edge
    mask = mask | to_the_border(mask, P.patch_size)
    region = dilate_disc(mask, P.select_margin_px)
    # (an empty L still gets the minority witnesses: a mover that lingered in most
    # photos may be all the scans left unflagged)
    if S == 0 or not (mask.any() or P.select_minority > 0):
        return empty
    mask = mask.copy()
    tau = P.select_tau
    lab_r = blurred_lab(reference, 1.0)
    g_r = cv2.cvtColor(reference, cv2.COLOR_BGR2GRAY)
    src_gray = [cv2.cvtColor(s, cv2.COLOR_BGR2GRAY) for s in sources]
    gx, gy = pixel_grid(H, W)
    grid = np.stack([gx, gy], -1)

    # 1. flow matches and the pixels of L they explain
    votes = np.zeros((S, H, W), np.float32)
    matched = np.zeros((S, H, W), bool)  # the flow match on its line, the reference's colour
    searched = np.zeros((S, H, W), bool)  # in L, found by the epipolar search instead
    # ... and there, unique on the line (``select_search_unique``; tested where one
    # source's match decides alone: two sources or one)
    unique = np.ones((S, H, W), bool)
    test_unique = S <= 2 and P.select_search_unique > 0
    line_de = np.full((S, H, W), np.nan, np.float32)  # best ΔE on the line, where searched
    beyond = np.zeros((S, H, W), bool)  # ... found beyond the flow's range (search_beyond)
    line_xy = (np.full((S, H, W, 2), np.nan, np.float32)  # ... and where it lies
               if mode == "parallax" and P.select_search_de > 0 else None)
    seen = np.zeros((S, H, W), bool)  # the flow match inside the source's content
    # the flow sample's P(mover colour) under the model of L as the refinement left it
    # (not the model of L grown below), and where the flow found the reference's colour
    # off its epipolar line or beyond the parallax bound (it followed the content there)
    p_flow = np.zeros((S, H, W), np.float32)
    off_line = np.zeros((S, H, W), bool)
    base: list = [None] * S
    lab_s: list = [None] * S  # the sources' blurred Lab, exposure matched, where computed
    offsets: list = [None] * S  # the reference's Lab minus each source's (median off L)
    if P.select_minority > 0:
        lab_ws = np.zeros((S, H, W, 3), np.float32)
        geo_ok = np.zeros((S, H, W), bool)
        flow_agree = np.zeros((S, H, W), bool)

    colours = _mover_model(lab_r, mask)  # the colours of L as the refinement left it
    # where each source shows the reference's movers, in its own frame (where the set
    # is flat enough that the consensus trusts the scan, L is the movers)
    followed: list = [None] * S
    track = P.select_track_movers and mode == "scan" and mask.any()
    regions = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)[1] if track else None

    # the visible pixels whose flow matches set the epipolar search's range (L and 4 px)
    off_l = ~dilate_disc(mask, 4) if mode == "parallax" and P.select_search_de > 0 else None
    # each source's 90th percentile of its static flow's distance from the epipolar
    # lines (px; inf: not measured), for ``select_line_px``
    line_p90 = np.full(S, np.inf)
    far_l = ~dilate_disc(mask, 8) if mode == "parallax" and P.select_line_px > 0 else None

    def match(k):
        v = views[k]
        nf = (flows[k] if flows is not None else
              dense_correspondence(g_r, src_gray[k], v.H, method="homography+flow",
                                   flow_preset=P.flow_preset))
        hx, hy = apply_homography(v.H, gx, gy)
        bound = (v.parallax_px if np.isfinite(v.parallax_px) else 0.0) + 2.0
        off_h = np.hypot(nf[..., 0] - hx, nf[..., 1] - hy)
        within = off_h <= bound
        # the fill's field keeps flow as far as the scan's gate allows
        keep = off_h <= max(bound, P.flow_gate * max(H, W))
        base[k] = np.where(keep[..., None], nf, np.stack([hx, hy], -1)).astype(np.float32)
        warped, inside = sample_bilinear(sources[k], nf)
        if valid is not None:
            inside &= _valid_at(valid[k], nf)
        lab_w = blurred_lab(warped, 1.0)
        geo = inside & within
        seen[k] = inside
        d_line = sampson_sq(v.F, grid, nf) if v.F is not None else None
        if d_line is not None and P.select_epipolar_px > 0:
            geo &= d_line <= P.select_epipolar_px ** 2
        near_w = inside & (delta_e(lab_w, lab_r) < tau)
        if d_line is not None and far_l is not None:
            # how near its epipolar lines this source's flow matches of the static
            # scene lie (those that agree with the reference in colour, away from L)
            static = inside & within & near_w & far_l
            if static.sum() > 100:
                line_p90[k] = math.sqrt(float(np.percentile(d_line[static], 90)))
        # exposure and white balance: the epipolar search compares the reference
        # with the source itself, not with its samples at matches that agree
        offsets[k] = _lab_offset(lab_r, lab_w, geo & ~mask)
        ok = geo & near_w
        if P.select_minority > 0:
            # the minority witnesses' match: the flow where the geometry allows it,
            # elsewhere the homography plus the parallax that the valid matches
            # around show; exposure and white balance matched (the median Lab
            # offset off L, on every 7th pixel)
            h_xy = np.stack([hx, hy], -1).astype(np.float32)
            f_g = np.where(geo[..., None], nf, h_xy + _coarse_fill(nf - h_xy, geo))
            w_b, geo_ok[k] = sample_bilinear(sources[k], f_g)
            if valid is not None:
                geo_ok[k] &= _valid_at(valid[k], f_g)
            # where the flow found the reference's colour (wherever it led), the
            # source still shows that content: it does not witness against it
            flow_agree[k] = near_w
            lab_b = blurred_lab(w_b, 1.0)
            lab_ws[k] = lab_b + _lab_offset(lab_r, lab_b, geo_ok[k] & ~mask)
        p_flow[k] = _mover_probability(colours, lab_w)
        off_line[k] = near_w & ~geo
        votes[k] = ok * (1.0 - p_flow[k])
        if mode == "parallax" and P.select_search_de > 0:
            # static 3-D structure whose flow match failed (thin, or far off the
            # plane): its best match along the epipolar line in this source
            lab_s[k] = blurred_lab(sources[k], 1.0) + offsets[k]
            res = epipolar_search(lab_r, lab_s[k], v, nf, off_l, mask & ~ok,
                                  support_de=P.select_search_support_de,
                                  unique_px=_UNIQUE_PX if test_unique else 0.0)
            cost, mu = res[0], res[1]
            searched[k] = cost < P.select_search_de
            if test_unique:
                unique[k] = res[2] > P.select_search_unique * cost + _UNIQUE_DE
            if P.select_search_beyond_px > 0:
                # structure nearer (or farther) than the flow followed: found on the
                # stretch of its line that the keypoints around it show, where
                # nothing on the flow's stretch matched, and clearly better than
                # that stretch's best (its ratio test: a mover's colour that turns
                # up far along a line is no match)
                c_far, mu_far = search_beyond(lab_r, lab_s[k], v, nf, off_l,
                                              mask & ~ok, ring_px=P.select_search_beyond_px,
                                              support_de=P.select_search_support_de)
                far = ~searched[k] & (c_far < P.select_search_de) & (
                    cost > _BEYOND_RATIO * c_far + _UNIQUE_DE)
                searched[k] |= far
                unique[k] |= far
                beyond[k] = far
                mu = np.where(far, mu_far, mu)
                cost = np.where(far, c_far, cost)
            line_de[k] = np.where(np.isfinite(cost), cost, np.nan)
            line_xy[k] = line_points(v, mu)  # (NaN where not searched)
        matched[k] = ok
        if track:
            followed[k] = _followed_mover(nf, mask & near_w & ~geo, regions)


    for_each_source(match, S)
    # a coarse test (a third of the search's time at 854×480): a grid of at
    # least 200 px on its long side, 3×3 cells
    veto_scale = min(0.5, max(0.25, 200 / max(H, W)))

    def source_lab(k):
        """Source k's blurred Lab, exposure matched (computed once)."""
        if lab_s[k] is None:
            lab_s[k] = blurred_lab(sources[k], 1.0) + offsets[k]
        return lab_s[k]

    def found(k, region):
        """Where source k shows the reference's content of ``region`` somewhere on its
        epipolar line (the veto of the weaker evidence below; L as it stands then)."""
        if views[k].F is None:
            return np.zeros(region.shape, bool)
        nf = flows[k] if flows is not None else base[k]
        cost, _ = epipolar_search(lab_r, source_lab(k), views[k], nf,
                                  ~dilate_disc(mask | region, 4), region,
                                  scale=veto_scale, box=3)
        return cost < max(P.select_search_de, 1e-6)

    grown = np.zeros((H, W), bool)
    if P.select_grow_px > 0:
        grown, alone = _consensus_growth(lab_r, sources, base, mask, valid, P, colours)
        if alone.any() and mode == "parallax" and P.select_search_de > 0:
            # where the set has much parallax, a pixel that no source's match agrees
            # with may be 3-D structure matched off its line: the epipolar search
            # keeps it static if any source shows its content on the line
            grown &= ~(alone & np.any(for_each_source(lambda k: found(k, alone), S), axis=0))
        mask = mask | grown
        region = dilate_disc(mask, P.select_margin_px)
    minority = np.zeros((H, W), bool)
    wit_map = np.zeros((S, H, W), bool)
    if P.select_minority > 0:
        # (the search guards the plane + parallax estimate of the match, which
        # can be far off only where the set has much parallax)
        region_m, witnessed, wit_map = _minority_witnesses(
            lab_r, lab_ws, geo_ok, flow_agree, mask, P.select_minority,
            found=found if mode == "parallax" else None, tau=tau)
        # inside what the scans (or the growth) found, only the pixels that the
        # witnesses themselves dispute change treatment; outside it, what is added
        # is at least 5 px wide (a rim along a mover's outline is not a mover)
        disc5 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        added = cv2.morphologyEx((region_m & ~mask).astype(np.uint8), cv2.MORPH_OPEN,
                                 disc5) > 0
        minority = added | (region_m & mask & witnessed)
        if P.select_minority_one and S == 2:
            # three photos: the rest of a mover the scans found in part, seen free
            # in one source only; what the scans missed, and nothing inside L (there
            # a single witness overruled the other source's static evidence: on the
            # 3-view composites, a misaligned view against 3-D structure)
            region_1, _, wit_1 = _minority_witnesses(
                lab_r, lab_ws, geo_ok, flow_agree, mask, P.select_minority,
                found=found if mode == "parallax" else None, one_witness=True,
                min_frac=_ONE_WITNESS_FRAC, tau=tau)
            added_1 = cv2.morphologyEx((region_1 & ~mask & ~minority).astype(np.uint8),
                                       cv2.MORPH_OPEN, disc5) > 0
            minority |= added_1
            wit_map |= wit_1 & added_1[None]
        del lab_ws, geo_ok, flow_agree
        mask = mask | minority
        region = dilate_disc(mask, P.select_margin_px)
    if not mask.any():
        return empty
    colours = _mover_model(lab_r, mask)  # L grown as above
    # (a region of L that is a minority of it is judged by the rest's colours)
    p_ref = _reference_mover_probability(lab_r, mask, colours, alike=S >= 2)
    # half of the sources that see the pixel (in their frame), at least min(2, S / 2):
    # near the image border, where some sources do not reach, the others decide;
    # and at most _EXPLAIN_CAP (from 7 sources up: see there)
    need = np.minimum(np.maximum(min(2, max(1, int(np.ceil(0.5 * S - 1e-6)))),
                                 np.ceil(0.5 * seen.sum(0) - 1e-6)), _EXPLAIN_CAP).astype(np.int64)
    flow_vote = votes > 0.5
    line_found = np.zeros((S, H, W), bool)
    ambiguous = np.zeros((S, H, W), bool)  # (EV_AMBIGUOUS)
    if searched.any():
        # the epipolar search is weaker evidence (any colour on the line may
        # match): it counts where at least two sources, and half of them, agree;
        # or where no other source that sees the pixel contradicts it: each found
        # the content too, or shows the movers' colours there without having found
        # the reference's colour off its line (a copy the flow followed). A pillar
        # that only one of two sources sees, the rider hiding it in the other, was
        # refilled with the wall (v3 entry-P10+bmx-trees damage 0.86 -> 0.51 %;
        # with the flow's followed copies not counted against it, DAVIS
        # car-roundabout J 0.816 -> 0.586: the car kept). Where one source's match
        # decides alone (need 1) and no other source found the content, that match
        # must be unique on its line: with three photos of ``bursts/tim6`` (tim1,
        # tim3, tim5) the standing man's dark shirt matched the dark screen all
        # along tim1's line and he stayed as a dark figure (README, session 58)
        shown = matched | searched
        against = seen & ~shown & ((p_flow < 0.5) | off_line)
        if P.select_search_against_de > 0:
            # ... but a source whose line holds nothing within select_search_against_de
            # of the reference's content shows no copy of the reference's mover
            # there (a copy would match on the line): it contradicts, whatever the
            # colour at its flow match. tim6 as tim1, tim3, tim5: the man's head
            # beside the screen matched the screen on tim1's line alone, tim5's
            # samples at the screen's edge had the movers' dark colours, and the
            # head stayed in the clean photo (70 % of a box inside it dark; 10 %
            # with the rule). (NaN, not searched, is no contradiction.)
            against |= seen & ~shown & (line_de >= P.select_search_against_de)
        line_found = searched & (
            (shown.sum(0) >= np.maximum(2, need))[None] | (~against.any(0))[None] & unique)
        ambiguous = searched & ~line_found & ~unique & (~against.any(0))[None]
        votes = np.maximum(votes, line_found.astype(np.float32))
    explained = mask & ((votes > 0.5).sum(0) >= need) & (p_ref < 0.5)
    if mode == "scan":
        # where the set is flat, a flow match within the homography's few pixels of
        # parallax, on its epipolar line, in the reference's colour, is static
        # evidence by itself where at least two sources (and ``need``) show it: the
        # movers' colour model, learned from L, learns the colours of L's false
        # positives as well (where the set is 3-D the bound is wide, tens of pixels,
        # and a slow mover's flow stays within it: there the model must agree)
        alone = mask & (matched.sum(0) >= np.maximum(need, 2))
        explained |= alone
        flow_vote |= matched & alone[None]  # they count (``evidence``), whatever the colour
    explained &= ~minority
    # a speck the static test kept inside a lingering mover (its lettering, found in
    # place by the sources that show the mover too) is the mover's: under one scan
    # patch (p² px) and enclosed by the minority region. tim6 with tim4.jpg: the cup's
    # white letters stayed as a translucent "Ho" over the fill (larger enclosed
    # regions are static scene seen through a mover: parkour_s3 J 0.754 -> 0.707
    # without the size bound)
    if minority.any():
        island = fill_holes(minority.astype(np.uint8)).astype(bool) & explained
        explained &= ~(island & ~drop_small(island, P.patch_size ** 2 + 1).astype(bool))
    # why each source did or did not count towards ``explained`` (for inspect)
    evidence = np.where(np.broadcast_to(mask, (S, H, W)), EV_NOT_FOUND, 0).astype(np.uint8)
    evidence[mask[None] & searched & ~line_found] = EV_LINE_ALONE
    evidence[mask[None] & ambiguous] = EV_AMBIGUOUS
    evidence[mask[None] & line_found & ~flow_vote] = EV_LINE
    evidence[mask[None] & line_found & ~flow_vote & beyond] = EV_LINE_BEYOND
    evidence[mask[None] & matched & ~flow_vote & ~line_found] = EV_MOVER_COLOUR
    evidence[mask[None] & flow_vote] = EV_FLOW
    evidence[mask[None] & ~seen & ~flow_vote & ~line_found] = EV_UNSEEN
    core = mask & ~explained

    # 2. background candidates through the fields, re-aligned
    hole = cv2.dilate(dilate_disc(core, 2).astype(np.uint8), np.ones((7, 7), np.uint8)
                      ).astype(bool)
    fields = background_fields(base, hole)

    def showing_movers(fields):
        """(S, H, W): where each source, sampled through ``fields``, shows a mover
        of its own (a lingering mover's copy, the reference's mover followed into it)."""
        shows = minority[None] & ~wit_map
        for k in range(S):
            if followed[k] is not None:
                shows[k] |= _valid_at(followed[k], fields[k])
        return shows

    planes = np.full((H, W), -1, np.int16)
    if P.select_planes and core.any():
        # hidden edges between depths: the planes around each region of the hole,
        # where the sources agree (a source showing a mover of its own is no witness,
        # a sample in the movers' colours a weak one)
        fields, planes = plane_fields(
            [source_lab(k) for k in range(S)], base, fields, hole, ~dilate_disc(mask, 4),
            showing_movers(fields), static=matched, seed=P.seed,
            mover_p=lambda v: _mover_probability(colours, v))
    if P.select_sweep and mode == "parallax" and core.any():
        # hidden 3-D structure: the depth at which the sources agree, not a membrane
        model = fit_parallax(base, views, ~dilate_disc(mask, 4), seed=P.seed)
        if model is not None:
            fields, _ = sweep_fields([blurred_lab(s, 0.0) for s in sources], views, model,
                                     hole, fields)
    if P.fuse_realign > 0 and core.any():
        for _ in range(P.fuse_realign):
            # the target of the re-measured matches: the sources' median where none
            # shows a mover (a lingering mover's copies, a mover the flow followed);
            # with them in it, a flow that may move 32 px pulled the witnesses'
            # matches onto the copies
            first, _ = median_fill(reference, sources, fields, dilate_disc(core, 2),
                                   exclude=showing_movers(fields))
            fields = realign_fields(first, src_gray, fields, hole, [v.H for v in views],
                                    P.flow_preset, P.fuse_realign_max_px)

    if true_background is not None and core.any():
        # (evaluation only: the hidden background's own matches across the hole)
        g_true = cv2.cvtColor(np.ascontiguousarray(true_background), cv2.COLOR_BGR2GRAY)

        def true_field(k):
            nf = dense_correspondence(g_true, src_gray[k], views[k].H,
                                      method="homography+flow", flow_preset=P.flow_preset)
            return np.where(hole[..., None], nf, fields[k]).astype(np.float32)

        fields = for_each_source(true_field, S)
    ys, xs = np.nonzero(region)
    y0, y1 = max(ys.min() - 2, 0), min(ys.max() + 3, H)
    x0, x1 = max(xs.min() - 2, 0), min(xs.max() + 3, W)
    roi = (slice(y0, y1), slice(x0, x1))
    reg, in_core, in_mask = region[roi], core[roi], mask[roi]
    cand = [reference[roi]]
    inside = [np.ones(reg.shape, bool)]

    def sample(k):
        warped, ins = sample_bilinear(sources[k], fields[k])
        if valid is not None:
            ins &= _valid_at(valid[k], fields[k])
        return warped[roi], ins[roi]

    for warped, ins in for_each_source(sample, S):
        cand.append(warped)
        inside.append(ins)
    cand_img = np.stack(cand)
    usable = np.stack(inside)
    labs = np.empty(cand_img.shape, np.float32)

    def to_lab(k):
        labs[k] = blurred_lab(cand_img[k], 1.0)

    for_each_source(to_lab, len(cand_img))

    # 3. weighted consensus
    p_mover = _mover_probability(colours, labs)
    p_mover[0] = p_ref[roi]  # (the reference: its regions judged by the rest of L)
    weight = (1.0 - p_mover) * usable
    weight[0] = 1.0  # outside L the reference is a trusted witness
    weight[0][in_mask] = 1.0 - p_mover[0][in_mask]
    dist = pairwise_distance(labs)  # (S+1, S+1, h, w)
    # where a mover lingered, the sources that did not witness the background
    # there still show it (as the reference does): they never fill
    copies = minority[y0:y1, x0:x1][None] & ~wit_map[:, y0:y1, x0:x1] & usable[1:]
    # where a source's candidate lands on the reference's mover, followed there by the
    # flow (``_followed_mover``): that source shows its own copy of the mover
    own = np.zeros((S,) + reg.shape, bool)
    for k in range(S):
        if followed[k] is not None:
            own[k] = _valid_at(followed[k], fields[k][roi]) & usable[k + 1] & in_mask
    weight[1:][own] = 0.0
    weight[1:][copies] = 0.0
    # where the set is 3-D, a sample off the pixel's epipolar line in its source
    # cannot show the static scene behind the mover (the fields are interpolated
    # across L and re-aligned by flow: a pillar's fill taken from the wall beside
    # it): where another source's sample lies on its line, its vote shrinks to
    # ``_OFF_LINE_VOTE``. Only in a source whose geometry places its own static
    # flow that near its lines (90 % of it): elsewhere (a hand-held desk, a lawn
    # before the camera) "off the line" is the geometry's error as often as the
    # sample's, and bursts/tim6 had a tube's copy, on its line by that margin,
    # outvote three sources showing the table
    off_line = np.zeros((S,) + reg.shape, bool)
    if mode == "parallax" and P.select_line_px > 0:
        for k in range(S):
            if views[k].F is not None and line_p90[k] <= P.select_line_px:
                off_line[k] = (sampson_sq(views[k].F, grid[roi], fields[k][roi])
                               > P.select_line_px ** 2) & in_mask
        # (a source that still shows a lingering mover, or the reference's mover
        # followed into it, has no vote: its sample on the line is no witness)
        off_line &= (~off_line & usable[1:] & (weight[1:] > 0)).any(0)[None]
        weight[1:][off_line] *= _OFF_LINE_VOTE
    agree = (dist < tau) & usable[:, None] & usable[None]
    support = (agree * weight[None]).sum(1)
    v_roi = votes[:, y0:y1, x0:x1]
    support[0] = weight[0] + np.maximum(agree[0, 1:] * weight[1:], v_roi).sum(0)

    def consensus(sup, first):
        best = first + np.argmax(sup + 1e-3 * (np.arange(len(sup)) == 0)[:, None, None], 0)
        c = np.take_along_axis(labs, best[None, ..., None].repeat(3, -1), 0)[0]
        return np.minimum(delta_e(labs, c), _DE_CAP), c

    D, cons = consensus(support, 0)
    # inside L the reference is the suspect: the sources' own consensus decides
    # (with much parallax, only where the minority witnesses said so)
    suspect = in_core if mode == "scan" else in_core & minority[y0:y1, x0:x1]
    if suspect.any():
        Ds, cons_s = consensus(support[1:], 1)
        D = np.where(suspect[None], Ds, D)
        ref_cost = reference_cost(P.select_ref_cost, p_mover, usable, agree, own)
        # where the reference agrees with the sources' consensus (ΔE under tau), it
        # costs what a source showing it would, less κ: its distance to it and its
        # movers'-colour term. The scans' flag that the sources contradict then
        # costs nothing, and the sources' own ghosts (a bottle's faint outline that
        # agrees within tau) stay out (``bursts/shaky_desk6`` as desk1, desk2, desk6
        # and desk4); DAVIS J 0.5867 -> 0.5918, 12 composites damage 0.467 -> 0.460 %,
        # leftover 15.32 -> 15.34 % (README, session 51)
        ref_cost = np.minimum(ref_cost, np.where(
            (Ds[0] < tau) & usable[1:].any(0), Ds[0] + P.select_gamma * p_mover[0], np.inf))
        D[0] = np.where(suspect, ref_cost, D[0])
        cons = np.where(suspect[..., None], cons_s, cons)
    D[1:] += P.select_kappa + P.select_gamma * p_mover[1:]
    D[1:][copies] = _FORBIDDEN
    D[~usable] = _FORBIDDEN
    D[1:, ~reg] = _FORBIDDEN
    # what the static 3-D test kept is the reference's: the sources' candidates there
    # come through fields interpolated across L, not through the matches that showed
    # its content (a graph cut that could still take a source drew a bar of wall
    # across a face in tim6; 12 composites: damage 0.502 -> 0.499 %, leftover 17.07
    # -> 17.21 %; DAVIS J 0.569 -> 0.570)
    D[1:, explained[roi]] = _FORBIDDEN
    if no_fill is not None:
        D[1:][np.asarray(no_fill, bool)] = _FORBIDDEN
    # a source showing its own mover never fills where another source may; where
    # none may, the pixel is still replaced, and inpainted (``no_src`` below)
    D[1:][own & ((D[1:] < _FORBIDDEN) & ~own).any(0)[None]] = _FORBIDDEN
    # and there the reference shows a mover that the flow followed into the sources
    # (with three photos, only where its colour is the movers': a source's copy of
    # the mover, moved, is followed onto the scene beside the reference's mover)
    followed_here = own.any(0) & in_core
    # ... but not where the reference has the scene's colour and every source followed
    # there shows what the reference shows: the followed region, closed and grown in
    # the source's frame, reaches past its mover onto the scene (``bursts/shaky_desk6``
    # as desk1, desk2, desk5 and desk4: the reference lost to desk1's bottle there,
    # and a piece of it was pasted onto the desk). It rests on the colour model: a
    # slow mover's part in the scene's colours, whose copy agrees, loses the penalty
    # too (DAVIS's slow movers camel, cows and dog_s3 measured unchanged, J within
    # 0.001; the cost of keeping the reference inside L stays --select-ref-cost)
    followed_here &= ~((p_mover[0] < 0.5) & ((dist[0, 1:] < tau) | ~own).all(0))
    if S == 2:
        followed_here &= p_mover[0] >= 0.5
    D[0] = np.where(followed_here, np.maximum(D[0], 2 * _DE_CAP), D[0])
    D[0, ~reg] = 0.0

    # what the cut weighs (for the debugger)
    d_src = np.where(D[1:] < _FORBIDDEN, D[1:], np.inf).min(0)
    cost_map = np.stack([np.where(reg, D[0], np.nan),
                         np.where(reg & np.isfinite(d_src), d_src, np.nan)]).astype(np.float32)
    sup_map = np.stack([np.where(reg & ~suspect, support[0], np.nan),
                        np.where(reg & ~suspect, support[1:].max(0), np.nan)]
                       ).astype(np.float32)

    # 4. graph cut, 5. blend
    lab = expansion_labels(D.astype(np.float64), labs, beta=P.select_beta, cycles=2,
                           distance=dist, forbidden=_FORBIDDEN)
    region_rule = np.zeros(lab.shape, np.uint8)
    rcomp, rfrac = region_shares(lab, in_core)
    # the share the region rule decided on, for the debugger: a region of L is static
    # with its explained pixels counted as kept, a mover on its own
    # (``complete_regions``' ``static``); with explained pixels the share only falls
    jcomp, jfrac = region_shares(lab, in_core, static=explained[roi])
    share_map = np.where(rcomp > 0, rfrac[rcomp], np.nan).astype(np.float32)
    share_map = np.where(in_core & (jfrac[jcomp] < 1.0 - P.select_complete)
                         & (rfrac[rcomp] < P.select_complete), jfrac[jcomp],
                         share_map).astype(np.float32)
    if P.select_complete > 0:
        # a region replaced only in part whose kept part is the mover's rest, which
        # no source showed free: kept whole (tim6 as tim1, tim3, tim5: a cup with
        # holes and half a tube before; 12 composites damage 0.282 -> 0.263 %, DAVIS J
        # unchanged; README, session 59)
        partial = (partial_movers(rcomp, rfrac, lab, p_mover[0],
                                  ((dist[0, 1:] < tau) & usable[1:]).any(0),
                                  P.select_complete, P.select_keep_partial,
                                  seen=usable[1:].any(0))
                   if P.select_keep_partial > 0 else None)
        # (a region whose middle the static test explained, a pillar or a statue, is
        # judged static with it: its unexplained fragments are no mover of their own;
        # 12 composites damage 0.226 -> 0.223 %, relit 0.266 -> 0.204 %, seed-21
        # 0.501 -> 0.469 %, leftover unchanged; DAVIS J 0.6302 -> 0.6307; README,
        # session 70)
        lab, region_rule = complete_regions(lab, in_core, D < _FORBIDDEN, P.select_complete,
                                            P.select_complete_px, regions=(rcomp, rfrac),
                                            partial=partial, static=explained[roi],
                                            judged=(jcomp, jfrac))
    movers = np.zeros((S, H, W), bool)
    d_cons = delta_e(labs[1:], cons)
    mv = (usable[1:] & (p_mover[1:] > 0.5) & (d_cons > tau)
          | copies | own)
    movers[:, y0:y1, x0:x1] = mv & reg[None]
    free = usable[1:] & ~mv
    if no_fill is not None:
        free[np.asarray(no_fill, bool)] = False
    if P.select_halo_px > 0:
        lab = grow_into_rim(lab, reg & ~explained[roi], free, labs, p_mover[0], tau,
                            P.select_halo_px)
    if P.select_fill_pieces:
        # pieces of a mover that photos showing it in place vouched for, enclosed by
        # its fill: filled too (tim6 as tim2-tim5: the cup's lid pieces and a letter,
        # 500 px, left floating; 12 composites damage 0.226 -> 0.226 %, leftover
        # 15.33 -> 15.29 %; DAVIS J 0.6294 -> 0.6294; README, session 62)
        lab = fill_kept_pieces(lab, reg, free, labs, tau,
                               evidence=evidence[:, y0:y1, x0:x1], d_cons=d_cons)
    rep = lab != 0
    no_src = rep & in_core & ~free.any(0)
    # the band of the photo that no source's frame reaches (a reference at the end of
    # a pan), next to a mover the sources replaced: inpainted with it, so the mover
    # leaves no stump there (the last rows of a dancer's legs, which the scans could
    # not flag with nothing to compare); a mover out of every other frame, far from
    # any replaced pixel, stays as the reference shows it
    unseen = reg & ~usable[1:].any(0) & ~rep
    lab_b, rep_b = lab, rep  # what the sources fill and blend (then the inpainting)
    if unseen.any() and (rep & in_core).any():
        # and the part of a replaced mover that no source reaches, however wide (up
        # to _UNSEEN_CORE_PX): a bottle cut by the frame's edge, in an 18 px band no
        # source reached, kept its last 6 px columns green with the 12 px band alone
        # (a fresh-user trial, shaky_desk6 with --ref desk6.jpg)
        core_unseen = unseen_part_of_replaced(unseen & in_core, rep & in_core, in_core,
                                              _UNSEEN_CORE_PX)
        unseen &= dilate_disc((rep & in_core) | core_unseen, _UNSEEN_PX)
        # each takes the label of the replaced pixels next to it, so that the fill
        # at full size (``upsample.full_resolution``) replaces and inpaints it too
        # (a pixel's label is set at the step its distance is reached: more steps
        # change none of those)
        near = grow_replaced(np.where(rep, lab, 0).astype(np.int16), _UNSEEN_PX + (
            _UNSEEN_CORE_PX if core_unseen.any() else 0))
        unseen &= near > 0
        lab = np.where(unseen, near, lab)
        rep = lab != 0
        no_src |= unseen
    else:
        unseen[:] = False
    clean = reference.copy()
    seam_offset = None
    misplaced = np.zeros(reg.shape, bool)
    members = np.zeros((S, H, W), bool)
    offset = np.full((H, W, 3), np.nan, np.float32)
    blur_sigma = np.zeros(S, np.float32)
    if rep_b.any():
        # a reference softer than the sources (camera shake, focus): their fill is
        # blurred to match it, where the scene around the region says so
        scene = ~dilate_disc(in_mask, 6)
        for k in np.unique(lab_b[rep_b]):
            if k >= 1:
                blur_sigma[k - 1] = reference_blur(
                    cand_img[0], cand_img[k], scene & usable[k] & (dist[0, k] < tau))
        for k in np.flatnonzero(blur_sigma):
            cand_img[k + 1] = cv2.GaussianBlur(cand_img[k + 1], (0, 0), float(blur_sigma[k]))
        # each label's source as sampled, for the seams' guidance (``seam_steps``;
        # ``_cluster_median`` returns a new array, and nothing writes into this one)
        raw_img = cand_img if P.select_seam_levels > 0 else None
        if P.select_cluster_median:
            # where the scan is trusted, every free source is a witness of the
            # hidden background, not only those agreeing with the chosen one
            cand_img, mem = _cluster_median(
                cand_img, labs, lab_b, rep_b, free,
                np.where(in_core, np.inf, tau) if mode == "scan" else tau)
            members[:, y0:y1, x0:x1] = mem
        else:
            ly, lx = np.nonzero(rep_b)
            members[lab_b[ly, lx] - 1, ly + y0, lx + x0] = True
        # (L's pixels are no evidence of light: a mover's kept parts are content)
        clean[roi] = offset_blend(reference[roi], cand_img, lab_b, rep_b, usable, labs,
                                  suspect=in_mask)
        members[:, y0:y1, x0:x1] &= ~no_src[None]  # inpainted: no source's value
        fy, fx = np.nonzero(rep_b & ~no_src)
        offset[fy + y0, fx + x0] = (clean[fy + y0, fx + x0].astype(np.float32)
                                    - cand_img[lab_b[fy, fx], fy, fx])
        if P.select_misfit_levels > 0:
            # a region whose fill the blend had to shift by more than light does,
            # where the reference lacks the movers' colours: static scene whose
            # fill shows other content; it keeps the reference (12 composites:
            # damage 0.389 -> 0.291 %, leftover 15.40 -> 15.42 %; DAVIS J 0.6115 ->
            # 0.6182; README, session 53)
            misfit = misfit_regions(rep, offset[roi], p_mover[0], P.select_misfit_levels)
            if misfit.any():
                lab, lab_b = np.where(misfit, 0, lab), np.where(misfit, 0, lab_b)
                rep, rep_b = lab != 0, rep_b & ~misfit
                no_src &= ~misfit
                unseen &= ~misfit
                region_rule[misfit] = MISFIT_KEPT
                clean[roi][misfit] = reference[roi][misfit]
                members[:, y0:y1, x0:x1] &= ~misfit[None]  # (``offset`` keeps what
                # the blend would have added there: the debugger shows why)
        if P.select_misplaced_de > 0:
            # a source whose part of the fill does not continue the photo kept around
            # it shows content misplaced there: inpainted instead (SceauxCastle+goat
            # in 4 views: a lawn pasted on the gravel under the goat's leg; README,
            # session 74)
            # (the kept photo in the movers' colours may be a part of a mover that L
            # left out: no evidence of the scene either)
            misplaced = misplaced_pieces(lab_b, rep_b & ~no_src, dist[0], usable,
                                         in_mask | (p_mover[0] >= 0.5),
                                         P.select_misplaced_de)
            if misplaced.any():
                no_src |= misplaced
                members[:, y0:y1, x0:x1] &= ~misplaced[None]
                my_, mx_ = np.nonzero(misplaced)
                offset[my_ + y0, mx_ + x0] = np.nan
        if raw_img is not None:
            # the steps of light left where two sources meet: blended in the
            # gradient domain (bursts/tim6: the table where the tube was, patches
            # 10-30 levels apart; README, session 73)
            corr = seam_steps(clean[roi], raw_img, lab_b, rep_b & ~no_src,
                              max_step=P.select_seam_levels)
            if corr.any():
                cy_, cx_ = np.nonzero(corr.any(-1))
                clean[cy_ + y0, cx_ + x0] = add_offset(clean[cy_ + y0, cx_ + x0],
                                                       corr[cy_, cx_])
                offset[cy_ + y0, cx_ + x0] += corr[cy_, cx_]
                seam_offset = np.zeros((H, W, 3), np.float32)
                seam_offset[roi] = corr
    if no_src.any():
        sub = np.ascontiguousarray(clean[roi])
        clean[roi] = cv2.inpaint(sub, no_src.astype(np.uint8), 5, cv2.INPAINT_TELEA)
    why = np.where(d_cons < tau, 6, 5).astype(np.uint8)
    why[off_line & (d_cons >= tau)] = OFF_LINE
    why[members[:, y0:y1, x0:x1]] = 2
    why[mv] = OWN_MOVER
    why[own] = FOLLOWED
    why[copies] = STILL_LINGERING
    why[~usable[1:]] = OUTSIDE
    # (an inpainted pixel has no chosen source)
    chosen_k = lab_b[None] == np.arange(1, S + 1)[:, None, None]
    why[chosen_k & ~no_src[None]] = 1
    why[chosen_k & misplaced[None]] = MISPLACED
    reasons = np.zeros((S, H, W), np.uint8)
    reasons[:, y0:y1, x0:x1] = np.where(reg[None], why, 0)
    # a lingering mover: witnessed against the reference where the reference and
    # the sources still showing it are the majority (the case the scans' majority
    # rule gets wrong; a mover that most sources saw past is no such case)
    n_copies = copies.sum(0)
    lingering = np.zeros((H, W), bool)
    lingering[roi] = minority[roi] & (n_copies + 1 > usable[1:].sum(0) - n_copies)
    label = np.full((H, W), -1, np.int16)
    label[roi] = np.where(reg, lab, -1)
    completed = np.zeros((H, W), np.uint8)
    completed[roi] = np.where(reg, region_rule, 0)
    region_share = np.full((H, W), np.nan, np.float32)
    region_share[roi] = share_map
    data_cost = np.full((2, H, W), np.nan, np.float32)
    data_cost[:, y0:y1, x0:x1] = cost_map
    sup = np.full((2, H, W), np.nan, np.float32)
    sup[:, y0:y1, x0:x1] = sup_map
    seams = np.zeros((H, W), bool)
    seams[roi] = reg & ((np.diff(lab, axis=0, prepend=lab[:1]) != 0)
                        | (np.diff(lab, axis=1, prepend=lab[:, :1]) != 0))
    # the dynamic map: replaced pixels of L, and those outside it where the
    # reference differed from what replaced it (not mere seam placement)
    d_chosen = np.take_along_axis(delta_e(labs, labs[0]), lab[None], 0)[0]
    replaced = np.zeros((H, W), bool)
    replaced[roi] = rep & (in_mask | (d_chosen >= tau)) | unseen
    # ... and any pixel the fill wrote ΔE tau or more from the reference, unblurred
    # (the blend's offset, not the chosen source alone, decides what is written: a
    # fresh-user trial found 30 px outside the mask of tim6 changed by ΔE 10-19.6)
    lab_out = cv2.cvtColor(clean[roi].astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)
    lab_in = cv2.cvtColor(reference[roi].astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)
    replaced[roi] |= rep & (delta_e(lab_out, lab_in) >= tau)
    nos = np.zeros((H, W), bool)
    nos[roi] = no_src
    mis = None
    if misplaced.any():
        mis = np.zeros((H, W), bool)
        mis[roi] = misplaced
    return Selection(clean=clean, replaced=replaced, label=label, explained=explained,
                     movers=movers, no_source=nos, seams=seams, parallax_px=par,
                     parallax_p95_px=par95,
                     consensus_mode=mode, fields=fields, members=members, reasons=reasons,
                     lingering=lingering, completed=completed, region_share=region_share,
                     blur_sigma=blur_sigma,
                     data_cost=data_cost, support=sup,
                     static_evidence=evidence,
                     line_de=line_de, line_xy=line_xy,
                     static_need=np.where(mask, np.minimum(need, 255), 0).astype(np.uint8),
                     ref_mover_p=np.where(mask, p_ref, np.nan).astype(np.float32),
                     followed=np.stack([np.zeros((H, W), bool) if f is None else f
                                        for f in followed]),
                     offset=offset, mask=mask, seam_offset=seam_offset, misplaced=mis,
                     planes=planes if (planes > 0).any() else None)


__all__ = ["EVIDENCE", "FOLLOWED", "MISFIT_KEPT", "MISFIT_MOVER_P", "MISPLACED", "OUTSIDE",
           "OWN_MOVER",
           "PARTIAL_KEPT", "REASONS", "STILL_LINGERING",
           "Selection", "attach_shadow", "capped_growth", "complete_regions", "darker",
           "fill_kept_pieces", "kept_pieces",
           "grow_into_rim",
           "median_parallax_px", "treated_as_3d", "member_median", "min_witnesses", "smooth_gain",
           "to_the_border", "unseen_part_of_replaced",
           "misfit_regions", "misplaced_pieces", "mixture_detail", "partial_movers",
           "reference_cost",
           "region_shares",
           "select_fill"]

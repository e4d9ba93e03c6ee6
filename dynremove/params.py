"""Parameters of the method (paper Sec. 3), in one frozen dataclass.

Symbols follow the paper. Where the paper gives a value it is the default here;
where it is silent (patch size, DBSCAN, t_r and the scalings that make the σ's
meaningful) the value was chosen by measurement: see README "Design choices".

Two presets:

* ``default`` (``DEFAULT``, and what ``Params()`` gives): the best variant the
  evidence supports (the paper's core, plus the engineered steps of
  ``dynremove.refine`` named in the fields below).
* ``paper`` (``PAPER``): the method as written; only the scalings the paper
  leaves open (SIFT, HoG and coordinate units, p, ε, minPts, t_r) are filled
  in, and every engineered step is off.

The field defaults *are* the default preset, so ``Params()``,
``preset("default")`` and ``remove_dynamic``'s default agree; the paper's
method is always asked for by name (``PAPER`` / ``preset("paper")``). Where
the two presets differ, the comment gives the paper preset's value.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from dynremove.errors import InputError

CORRESPONDENCE_METHODS = ("homography+flow", "homography", "flow", "gated")
WRITE_MODES = ("patch", "pixel")
FILL_MODES = ("select", "median")


def _one_of(choices) -> str:
    """('a', 'b', 'c') -> "a, b or c" (the choices of a flag, in an error)."""
    c = [str(x) for x in choices]
    return c[0] if len(c) == 1 else ", ".join(c[:-1]) + " or " + c[-1]


@dataclass(frozen=True, kw_only=True, slots=True)
class Params:
    """Parameters of the method (paper Sec. 3). Make variants with ``replace``.

    ``Params()`` is the *default* preset (the best measured variant), not the
    paper's method: use ``PAPER`` or ``preset("paper")`` for that.
    """

    # --- features (Sec. 3.1) -------------------------------------------------
    patch_size: int = 13  # p      : patch side in analysis px (odd) for f_c, f_g and removal (the paper gives no value; paper preset 9)
    sift_scale: float = 0.2  # SIFT / set-max is multiplied by this (unit of σ_g; measured)
    hog_bins: int = 8  # bins of the rotation-invariant HoG g_h
    hog_scale: float = 10.0  # unit-L2 HoG is multiplied by this (unit of σ_h)
    coord_scale_px: float = 8.0  # Sampson distance is measured in units of this

    # --- similarity, Eq. (1) and H ------------------------------------------
    lambda1: float = 0.15  # λ1 : Lab weight in C_s and H
    lambda2: float = 0.40  # λ2 : SIFT weight in C_s and H
    lambda3: float = 0.45  # λ3 : epipolar weight in C_s and H (absent: λ1, λ2 scaled to λ1+λ2+λ3)
    sigma_c: float = 4.8  # σ_c : Lab (CIE units)
    sigma_g: float = 0.25  # σ_g : SIFT (after sift_scale)
    sigma_e: float = 0.17  # σ_e : squared Sampson distance (coord units)

    # --- decision, Eq. (DB_cost) and M --------------------------------------
    dbscan_eps: float = 0.5  # ε of DBSCAN on the distance 𝓑 (Eq. DB_cost; B_l is a candidate's weight)
    dbscan_min_pts: int = 2  # minPts of DBSCAN (the point itself counts)
    t_r: float = 0.3  # t_r : static if M(x) > t_r (paper: 0.15–0.8; measured; paper preset 0.4)

    # --- removal, patch choice q* -------------------------------------------
    lambda6: float = 0.12  # λ6 : Lab term of q*
    lambda7: float = 0.36  # λ7 : HoG term of q*
    lambda8: float = 0.03  # λ8 : epipolar term of q* (absent: the overlap terms scaled up by λ8)
    sigma_h: float = 4.8  # σ_h : HoG (after hog_scale)
    tie_tol: float = 1e-3  # patches within this of the best score tie
    write: str = "patch"  # "patch": write p×p; "pixel": centre only

    # --- scans ---------------------------------------------------------------
    max_scans: int = 1  # at most this many scans, alternating direction; fewer when a scan finds no dynamic pixel (paper preset 4)
    update: bool = True  # update f, N and C after a write (Sec. 3.2.3)
    use_epipolar: bool = True  # λ3/λ8 terms on (off, or a source without F: the other terms rescaled to the same top score)
    use_hog: bool = True  # λ7 term on

    # --- correspondences ----------------------------------------------------
    correspondence: str = "gated"  # N_{r→s}: pre-warp + DIS flow gated by H (paper preset "homography+flow")
    flow_preset: str = "medium"  # DIS preset: "fast", "medium", "ultrafast"
    flow_gate: float = 0.02  # "gated": flow kept within this × max side of H
    flow_gate_epipolar_px: float = 0.0  # "gated": also keep flow this close to its epipolar line

    # --- engineered steps (dynremove.refine; all off in the paper preset) ---
    clean_mask: bool = True  # morphological clean-up of L (open/close, holes)
    min_region_px: int = 64  # drop dynamic components smaller than this many analysis px (paper preset 0)
    clean_majority: bool = True  # where the set is flat (median parallax ≤ --select-parallax-px), the clean-up also keeps the regions of a majority filter of L (binary median, the opening's window) that hold part of what the opening alone keeps: a slow mover's holed scan map is kept
    refine_tau: float = 16.0  # pixel votes at L's border (refine.mask.refine_mask): a source agrees with the reference under this CIE76 ΔE; 0 = off
    refine_shrink_frac: float = 1.0  # drop a rim pixel when this share of the sources that see it agree (1.0: all of them; 0.8 before session 58)
    refine_rim_px: int = 3  # width (analysis px) of the inner rim that may be dropped
    refine_ring_px: int = 6  # width (analysis px) of the outer ring that may be added (no source agrees)
    refine_iters: int = 2  # refinement passes
    snap: bool = True  # GrabCut the map's border onto colour edges (refine.mask.snap_to_edges)
    snap_inner_px: int = 6  # deeper than this (analysis px) inside the map: sure object
    snap_outer_px: int = 12  # ring of probable background around the map, this wide (analysis px)
    snap_iters: int = 3  # GrabCut iterations
    snap_veto: bool = True  # in a set whose median parallax exceeds --select-parallax-px, GrabCut may not add a pixel where --refine-shrink-frac of the sources agree with the reference (ΔE under --refine-tau; refine.mask.veto_agreed)
    fuse: bool = True  # refill L after the scans, as --fill says (selection or median); off: keep the scans' patch writes (paper)
    fuse_margin_px: int = 2  # the fused region is L dilated by this (analysis px)
    fuse_combine: str = "median"  # "median" (per channel) or "medoid" of the sources' samples
    fuse_realign: int = 2  # passes re-measuring the matches from the cleaned reference (paper preset 0)
    fuse_realign_max_px: float = 32.0  # a re-measured match may move at most this far (analysis px)
    exposure_match: float = 0.10  # scale a source's channels to the reference's exposure where a gain departs from 1 by this fraction or more (method.exposure; 0 = off)
    near_copy_agree: float = 0.99  # drop sources agreeing with the reference on this share of pixels (0 = off)
    fill: str = "select"  # "select": one free source per region (refine.select); "median": of all
    select_tau: float = 10.0  # CIE76 ΔE under which two candidates agree
    select_margin_px: int = 8  # the fill may change pixels within this of L (analysis px)
    select_kappa: float = 6.0  # data cost (ΔE) of taking a source instead of the reference
    select_ref_cost: float = 30.0  # data cost (ΔE) of keeping the reference inside L
    select_beta: float = 0.3  # weight of the photomontage seam cost (ΔE)
    select_gamma: float = 20.0  # data cost (ΔE) of a candidate with mover colours, × P(mover)
    select_epipolar_px: float = 2.0  # a flow match explaining the reference is this near its line (analysis px)
    select_line_px: float = 0.0  # in a 3-D set (see --select-parallax-px), a source's sample for the fill that lies farther than this (Sampson distance, analysis px) from the pixel's epipolar line in that source keeps a tenth of its vote in the fill's colour consensus where another source's sample lies on its line: the static scene behind a mover can only be seen on that line. Tested only in a source whose static flow matches lie within this of their lines at 90 % of their pixels (0 = off, the default: measured mixed, README session 72; 3 keeps a porch's pillar that a wide-baseline set's fill took from the wall beside it, but kept a cup whole in a 4-photo hand-held burst)
    select_cluster_median: bool = True  # a chosen source's pixel is the median of the free sources agreeing with it
    select_grow_px: int = 40  # L grows where the sources agree and the reference alone differs, this near it (analysis px; 0 = off)
    select_shade_de: float = 3.0  # a faint shade beside a removed mover (its soft cast shadow), darker than the light the other photos agree on by this much or more in CIE L* (at a 4 px scale) but under --select-shade-max-de, is relit to their light, keeping the reference's texture (0 = off)
    select_shade_max_de: float = 15.0  # a shade that differs from the other photos' light by this CIE76 dE or more (at a 4 px scale) is too deep to relight: a hard shadow, whose relit rim would show as an outline (pixels relit by --select-tau or more join the mask)
    select_shade_px: int = 120  # how far from the replaced region such a shade is looked for (analysis px; at most the replaced region's own area is relit)
    select_grow_alone: bool = True  # L also grows where no source agrees with the reference (at least two see it, even if they disagree among themselves) and the reference shows the colours of L's movers
    select_parallax_px: float = 8.0  # the set's median measured parallax (analysis px; per source the 90th percentile of the keypoint matches' distance from one plane) above which it is treated as 3-D (see also --select-parallax-p95-px): colour consensus may keep the reference in L, the epipolar search and --snap-veto run
    select_parallax_p95_px: float = 150.0  # the set is 3-D too where the median over the sources of the 95th percentile of the keypoint matches' distance from one plane is over this (analysis px): 3-D structure holding 5-10 % of the matches (a porch before a façade) leaves the 90th percentile (--select-parallax-px) on the plane; a mover's matches that fit the epipolar geometry rarely reach this far (0 = off)
    select_search_de: float = 8.0  # in a 3-D set (see --select-parallax-px), a pixel of L is also static where a source shows its content on its epipolar line: the best match's CIE76 ΔE (mean over ~10 px, weighted: see --select-search-support-de) is under this (0 = off)
    select_search_support_de: float = 5.0  # the epipolar search's window weighs its cells by their colour's likeness to the centre's, exp(-dE / this) in CIE76 dE (adaptive support weights, Yoon & Kweon 2006), so that a thin structure is compared, not the background around it (0 = a plain box)
    select_search_beyond_px: int = 0  # in a 3-D set, the epipolar search also looks beyond the flow's range of parallax, around the parallax that at least 2 keypoint matches (inliers of F) within this many px of a part of L agree on (a bollard near the camera: 200 px of parallax the flow does not follow); a match there counts where nothing in the flow's range matched and it costs under 1/1.5 of that range's best minus 2 dE (0 = off, the default: measured mixed, README session 69; 40 keeps a pillar or a bollard near the camera, and a mover that other photos show far along its line may stay)
    select_search_unique: float = 1.5  # with three photos or two, where one source's epipolar match would keep a pixel of L as static while the other source found nothing, that match must be unique: the best match farther than 10 px along the line must cost more than this × its ΔE + 2 (a ratio test: a plain dark shirt matches all along a dark screen; 0 = off)
    select_search_against_de: float = 16.0  # in a 3-D set, where fewer than two sources found a pixel of L's content on their epipolar lines, another source that sees the pixel contradicts them when nothing on its own line comes within this CIE76 dE, even where its flow match has the movers' colours (a copy of the reference's mover would match on the line: a dark screen's edge beside a man's head is no copy of him; 0 = off: such a source never contradicts)
    select_minority: float = 4.0  # a mover that lingered: L takes regions where two or more sources agree against the reference and their colour is this many times more common than the reference's in the rest of the photo (0 = off, else >= 1)
    select_minority_one: bool = True  # with three photos (two sources), --select-minority's region also where one source saw the scene and the other still shows the reference's content there, L taking only its part outside L: the rest of a mover the scans found in part (the region at least 0.2 % of the image, 20 % of it in L)
    select_track_movers: bool = True  # where the set is flat (see --select-parallax-px), a source shows the reference's mover where the flow followed it (30 % of a region of L found in its colour, off its epipolar line): that source never fills there
    select_complete: float = 0.7  # decide each region of L whole where the fill decided most of it, a share in (0.5, 1]: a region replaced at least this much is a mover (its kept pieces within --select-complete-px are replaced too); one replaced less than 1 - this is static (its replaced pieces keep the reference); in between, as the fill chose (0 = off)
    select_keep_partial: float = 0.5  # a region of L that the fill replaced only in part (between 1 - --select-complete and --select-complete of it) is kept whole where its kept part has the movers' colours (mean P(mover) at least this) and, on most of it, no source shows what the reference shows: the rest of a mover that no photo shows free, kept beside its replaced part, left it broken (a cup with holes); half a mover is not removed (0 = off; off too with --select-complete 0, which defines the shares)
    select_complete_px: int = 6  # how far (analysis px) --select-complete's replacement reaches from a region's replaced pixels (0: none; the static rule still applies)
    select_fill_pieces: bool = True  # an island of the reference that the replaced region encloses takes the source filling around it where that source is free on all of it and differs from the reference on half of it or more, and no source seen free around it shows the island in place: a piece of a mover (its lettering, a lid's rim) that only photos showing the mover in place vouched for (off: kept, and a note names such pieces)
    select_halo_px: int = 2  # the replaced region also takes a rim this wide (analysis px) of kept pixels next to it where the chosen source is free and within --select-tau of the reference and the nearest replaced pixel has the movers' colours: a mover's blurred edge, which the cut keeps as close enough to the scene, left its outline (0 = off)
    select_misfit_levels: float = 20.0  # a replaced region whose fill the blend had to shift by more than this (B/G/R levels: the median over the region of its largest channel's offset) to meet the photo around it, while the reference there lacks the movers' colours (mean P under 0.6), keeps the reference: the fill shows other content than the scene there, a static part flagged in error (0 = off)
    select_misplaced_de: float = 20.0  # a piece of the fill (one source's connected part, 30 analysis px or more) whose source differs from the reference on the photo kept around it by more than this (median CIE76 ΔE over a 3 px ring) shows content misplaced there (a match tens of px off): inpainted instead (OpenCV Telea) and reported (0 = off)
    select_seam_levels: float = 50.0  # steps of light at the fill's seams (where two sources meet inside the replaced region, each brought to the reference's level on the ring around it) up to this many B/G/R levels (any channel) are removed by a Poisson solve within 64 px of the seam, the region's edge held (Pérez et al. 2003); a larger step is content and kept (0 = off)
    select_planes: bool = True  # the fields across L re-chosen among the planes of the ring around each region of it (proposed by each sector's affine fit and each source's homographies found one after the other on the static flow matches, refitted as a homography per source), per pixel the plane at which the sources agree best (each pair weighed by 1 - P(mover colour) of its samples) where it beats the membrane by 2 CIE76 dE (refine.planes): an edge between two depths hidden by a mover (a table's edge, a balcony) comes out in place, not blended
    select_sweep: bool = False  # in a 3-D set (see --select-parallax-px), matches across L by a plane + parallax sweep (refine.parallax), not a membrane (measured mixed: off)

    seed: int = 0  # seeds RANSAC/MAGSAC so runs are reproducible
    candidate_set: bool = True  # P as a set (the paper): a repeated (s, x, y) candidate counts once

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            # a value of another type fails the comparisons below in Python's words
            if f.default is not dataclasses.MISSING and f.default is not None:
                _check_type(f.name, v, type(f.default))
            if isinstance(v, float) and not math.isfinite(v):  # NaN passes every comparison
                raise InputError(f"{f.name} must be a finite number, got {v}")
        if self.patch_size < 3 or self.patch_size % 2 == 0:
            raise InputError(f"patch_size must be odd and >= 3, got {self.patch_size}")
        if self.dbscan_eps <= 0:
            raise InputError(f"dbscan_eps must be > 0, got {self.dbscan_eps}")
        if self.dbscan_min_pts < 1:
            raise InputError(f"dbscan_min_pts must be >= 1, got {self.dbscan_min_pts}")
        if not 0.0 <= self.t_r <= 1.0:
            raise InputError(f"t_r must be in [0, 1], got {self.t_r}")
        if self.max_scans < 1:
            raise InputError(f"max_scans must be >= 1, got {self.max_scans}")
        for name in ("sigma_c", "sigma_g", "sigma_e", "sigma_h", "sift_scale",
                     "hog_scale", "coord_scale_px"):
            if getattr(self, name) <= 0:
                raise InputError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.correspondence not in CORRESPONDENCE_METHODS:
            raise InputError(
                f"correspondence must be {_one_of(CORRESPONDENCE_METHODS)}, "
                f"got {self.correspondence!r}")
        if self.write not in WRITE_MODES:
            raise InputError(f"write must be {_one_of(WRITE_MODES)}, got {self.write!r}")
        if self.flow_preset not in ("fast", "medium", "ultrafast"):
            raise InputError(f"flow_preset must be {_one_of(('fast', 'medium', 'ultrafast'))}, "
                             f"got {self.flow_preset!r}")
        if not 0.0 <= self.exposure_match < 1.0:
            raise InputError(f"exposure_match must be in [0, 1), got {self.exposure_match}")
        if not 0.0 <= self.near_copy_agree <= 1.0:
            raise InputError(f"near_copy_agree must be in [0, 1], got {self.near_copy_agree}")
        if self.fill not in FILL_MODES:
            raise InputError(f"fill must be {_one_of(FILL_MODES)}, got {self.fill!r}")
        for name in ("select_tau", "select_beta"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.select_complete != 0 and not 0.5 < self.select_complete <= 1.0:
            raise InputError(f"select_complete must be 0 (off) or in (0.5, 1], got "
                             f"{self.select_complete}")
        if not 0.0 <= self.select_keep_partial <= 1.0:
            raise InputError(f"select_keep_partial must be in [0, 1] (0 = off), got "
                             f"{self.select_keep_partial}")
        if self.select_minority != 0 and not self.select_minority >= 1:
            raise InputError(f"select_minority must be 0 (off) or >= 1, got {self.select_minority}")
        for name in ("select_grow_px", "select_shade_de", "select_shade_px",
                     "select_shade_max_de",
                     "select_kappa", "select_ref_cost", "select_gamma", "select_epipolar_px",
                     "select_line_px",
                     "select_parallax_px", "select_parallax_p95_px", "select_margin_px",
                     "select_search_de",
                     "select_search_support_de", "select_search_unique",
                     "select_search_beyond_px",
                     "select_search_against_de", "select_complete_px",
                     "select_halo_px",
                     "select_misfit_levels", "select_misplaced_de", "select_seam_levels"):
            if getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.fuse_combine not in ("median", "medoid"):
            raise InputError(f"fuse_combine must be median/medoid, got {self.fuse_combine!r}")
        if not self.fuse_realign_max_px > 0:
            raise InputError(f"fuse_realign_max_px must be > 0, got {self.fuse_realign_max_px}")
        if self.refine_tau < 0 or not 0.0 < self.refine_shrink_frac <= 1.0:
            raise InputError("refine_tau must be >= 0 and refine_shrink_frac in (0, 1]")
        for name in ("refine_rim_px", "refine_ring_px", "refine_iters", "fuse_realign",
                     "fuse_margin_px", "snap_inner_px", "snap_outer_px", "snap_iters"):
            if getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.hog_bins < 2:
            raise InputError(f"hog_bins must be >= 2, got {self.hog_bins}")
        if self.candidate_set not in (True, False):
            raise InputError(f"candidate_set must be True or False, got {self.candidate_set!r}")

    # λ4, λ5 of Eq. (DB_cost) and M
    @property
    def lambda4(self) -> float:
        return self.lambda1 / (self.lambda1 + self.lambda2)

    @property
    def lambda5(self) -> float:
        return self.lambda2 / (self.lambda1 + self.lambda2)

    def replace(self, **changes: object) -> "Params":
        """A copy with ``changes`` (field names as keywords). Raises InputError on
        a name that is no field (naming the closest) or a bad value."""
        _check_names(changes)
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _check_names(kw: dict) -> None:
    """Raise InputError for a keyword that names no field of Params, with the closest
    field names (a mistyped name raised Python's TypeError, which ``except
    InputError`` missed)."""
    import difflib

    names = [f.name for f in dataclasses.fields(Params)]
    for k in kw:
        if k not in names:
            close = difflib.get_close_matches(str(k), names, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(close)}?" if close else \
                "; help(dynremove.Params) lists them"
            raise InputError(f"Params has no field {k!r}{hint}")


def _check_type(name: str, value: object, kind: type) -> None:
    """Raise InputError (a ValueError) unless ``value`` fits a field whose default is a ``kind``:
    a bool for a switch, an int (not a bool) for a count, a number for a real, a
    str for a choice (NumPy scalars too)."""
    if kind is bool:
        ok = isinstance(value, (bool, np.bool_))
        what = "True or False"
    elif kind is int:
        ok = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        what = "an int"
    elif kind is float:
        ok = (isinstance(value, (int, float, np.integer, np.floating))
              and not isinstance(value, (bool, np.bool_)))
        what = "a number"
    else:
        ok = isinstance(value, kind)
        what = f"a {kind.__name__}"
    if not ok:
        raise InputError(f"{name} must be {what}, got {value!r} ({type(value).__name__})")


# Chosen on the even-indexed DAVIS sets, checked on the odd ones (README "Results"):
# flow gated by the homography (flow follows slow objects), one scan (more scans
# re-flag thousands of written pixels and lower J), t_r 0.3, a cleaned L, border
# votes, GrabCut snapping and the fused fill. These are the field defaults.
DEFAULT = Params()
# The method as written: the paper's ungated flow and four alternating scans, p 9,
# t_r 0.4, and none of the engineered steps of dynremove.refine.
PAPER = Params(patch_size=9, t_r=0.4, correspondence="homography+flow", max_scans=4,
               clean_mask=False, clean_majority=False, min_region_px=0, refine_tau=0.0, snap=False,
               fuse=False, fuse_realign=0, candidate_set=True, near_copy_agree=0.0, exposure_match=0.0)

PRESETS: dict[str, Params] = {"default": DEFAULT, "paper": PAPER}


def preset(name: str) -> Params:
    """Return the named preset (``"default"`` or ``"paper"``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise InputError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}") from None


FIELD_CHOICES: dict[str, tuple[str, ...]] = {
    "write": WRITE_MODES, "correspondence": CORRESPONDENCE_METHODS,
    "flow_preset": ("fast", "medium", "ultrafast"), "fuse_combine": ("median", "medoid"),
    "fill": FILL_MODES,
}


def field_docs() -> dict[str, str]:
    """Each field's comment in this file (symbol, unit, meaning): the CLI's help."""
    import re
    from pathlib import Path

    docs = {}
    try:
        text = Path(__file__).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):  # an install of .pyc files only (a trial's)
        return docs
    for line in text.splitlines():
        m = re.match(r"^    (\w+): [^=]+=[^#]*#\s*(.+)$", line)
        if m and m.group(1) not in docs:
            docs[m.group(1)] = m.group(2).strip()
    return docs


def params_fields() -> list[dataclasses.Field]:
    return list(dataclasses.fields(Params))


def _document_fields() -> None:
    """Each field, its default and its comment in ``Params.__doc__``, so that
    ``help(Params)`` says what the CLI's help says (a fresh-user trial: 77 fields and
    not a word on any)."""
    if Params.__doc__ is None:  # (python -OO)
        return
    docs = field_docs()
    lines = [f"    {f.name} : {f.type}, default {getattr(DEFAULT, f.name)!r}"
             + ("" if getattr(PAPER, f.name) == getattr(DEFAULT, f.name)
                else f" (paper {getattr(PAPER, f.name)!r})")
             + (f"\n        {docs[f.name]}" if f.name in docs else "")
             for f in dataclasses.fields(Params)]
    Params.__doc__ = (Params.__doc__.rstrip() + "\n\n    Fields (the CLI's flags, "
                      "``--patch-size`` for ``patch_size``)\n    ------\n" + "\n".join(lines))


_document_fields()


def _checked_init(init):
    """Params' generated ``__init__`` behind ``_check_names``."""
    import functools

    @functools.wraps(init)
    def __init__(self, **kw):
        _check_names(kw)
        init(self, **kw)
    return __init__


Params.__init__ = _checked_init(Params.__init__)


__all__ = ["Params", "PRESETS", "PAPER", "DEFAULT", "preset", "params_fields", "field"]

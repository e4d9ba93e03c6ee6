"""The whole run: features → geometry → correspondences → scans → refine → result.

``dynremove.method`` (the paper) then ``dynremove.refine`` (the default preset's
engineered steps, each switched by ``Params``).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import platform
from concurrent.futures import Future, ThreadPoolExecutor
import time
import warnings
from importlib.metadata import PackageNotFoundError, version
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import cv2
import numba
import numpy as np
import numpy.typing as npt

from dynremove.errors import InputError, Note
from dynremove.events import EventSink, NullSink, RunInfo
from dynremove.method import correspondence, exposure, features, geometry
from dynremove.method.scan import _kernels as kn
from dynremove.method.scan.driver import ScanInputs, pack_params, run_scans
from dynremove.io import AUTO_MAX_SIDE, ImageSet, resolve_ref, size_hint
from dynremove.params import DEFAULT, Params, preset
from dynremove.refine.colour import delta_e
from dynremove.refine.concurrency import check_fork_safe, for_each_source, numba_threads_safe
from dynremove.refine.duplicates import agreement_with_reference, duplicate_sources
from dynremove.refine.fill import fuse_background
from dynremove.refine.mask import refine_mask, snap_to_edges, veto_agreed
from dynremove.refine.morphology import clean_mask
from dynremove.refine.select import (FOLLOWED, OUTSIDE, OWN_MOVER, PARTIAL_KEPT, STILL_LINGERING,
                                     Selection, kept_pieces, median_parallax_px, select_fill,
                                     treated_as_3d, unconfirmed_fill)
from dynremove.refine.shade import apply_offset, relight_shade
from dynremove.refine.upsample import full_resolution

Progress = Callable[[str, float], None]


@dataclass(eq=False)
class Result:
    """What ``remove_dynamic`` produces, at the size it analysed (H, W).

    Images are BGR uint8, masks (H, W) bool. What a user reads first: ``clean``,
    ``dynamic``, ``coverage``, ``warnings`` (the run's notes) and ``ref_index`` (the
    reference used: the one ``ref="auto"`` chose). ``pipeline.full_resolution_output``
    makes the clean photo and mask at the photos' own size. ``M``, ``N``, ``C``,
    ``dynamic_raw``, ``clean_scan`` and ``stages`` are the method's (Sec. 3)
    intermediate maps, as the debugger shows them; ``selection`` the fill's.
    Printed, it summarises itself (the arrays are not listed); compared, it is the
    same object or not (``==`` of its arrays would be ambiguous).
    """

    clean: npt.NDArray[np.uint8]  # (H, W, 3) the reference with dynamic objects removed
    clean_scan: npt.NDArray[np.uint8]  # (H, W, 3) as the scans left it (= replayed events)
    dynamic: npt.NDArray[np.bool_]  # (H, W) final dynamic map L (after clean-up, if on)
    dynamic_raw: npt.NDArray[np.bool_]  # (H, W) L as the scans left it
    M: list[np.ndarray]  # (H, W) float32 M map of every scan
    # (H, W) sources that agree with the output: in ``dynamic`` with the fill by
    # selection, those it combined there (0 where it inpainted: no source saw it free);
    # elsewhere, those whose match agrees with the reference as the scans left it
    coverage: npt.NDArray[np.uint8]
    scans: np.ndarray  # SCAN_SUMMARY_DTYPE records
    timings: dict[str, float]  # seconds per stage that ran (they add up to "total")
    N: np.ndarray  # (S, H, W, 2) int32 final correspondences
    C: np.ndarray  # (S, H, W) float32 final similarity
    ref_index: int
    params: dict
    geometry: list[dict] = field(default_factory=list)  # matches/inliers per source
    # L after each step that changes it, in order: "scan", then (default preset)
    # "clean", "votes", "snap", "select" (pixels replaced by the fill); the last
    # one equals ``dynamic``
    stages: dict[str, np.ndarray] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    # the fill by selection (default preset): per-pixel source, mover maps, seams
    selection: Selection | None = None
    source_indices: list[int] = field(default_factory=list)  # images used as sources
    # the reference is black and white and the colour sources were used in gray
    # (``gray_like_reference``): the full-resolution fill does the same
    gray_sources: bool = False
    # per source (as ``source_indices``): the (3, 256) uint8 B, G, R tone curves that
    # matched its exposure to the reference's (``method.exposure``; the identity where
    # not changed); the full-size fill maps the full-size sources through them too
    source_curves: list[np.ndarray] = field(default_factory=list)

    def __repr__(self) -> str:
        H, W = self.dynamic.shape
        t = self.timings.get("total")
        return (f"Result({W}x{H}, reference {self.ref_index}, sources "
                f"{self.source_indices}, {100 * self.dynamic.mean():.1f} % dynamic, "
                f"{len(self.scans)} scan(s), {len(self.warnings)} note(s)"
                + (f", {t:.1f} s" if t is not None else "") + ")")


def api_params(params: Params | str | dict | None) -> Params:
    """``remove_dynamic``'s ``params``: a Params, a preset name (``"default"``,
    ``"paper"``), a dict of Params fields over the default preset, or None (the
    default preset). Raises InputError for an unknown name, field or bad value, or
    another type."""
    if params is None:
        return DEFAULT
    if isinstance(params, Params):
        return params
    if isinstance(params, str):
        try:  # (as ref="auto", any case: a trial's "Default" was refused)
            return preset(params.strip().lower())
        except ValueError as e:
            raise InputError(f"params: {e}") from None
    if isinstance(params, dict):
        fields = [f.name for f in dataclasses.fields(Params)]
        unknown = sorted(set(params) - set(fields), key=str)
        if unknown:
            # (a trial's mistyped field got no hint)
            near = [m for u in unknown
                    for m in difflib.get_close_matches(str(u), fields, n=1, cutoff=0.75)]
            raise InputError(f"params: unknown field(s) {', '.join(map(str, unknown))} ("
                             + (f"did you mean {', '.join(near)}? " if near else "")
                             + "the fields of dynremove.Params)")
        try:
            return DEFAULT.replace(**params)
        except (TypeError, ValueError) as e:
            raise InputError(f"params: {e}") from None
    raise InputError("params must be a dynremove.Params, a preset name, a dict of Params "
                     f"fields or None, got {type(params).__name__}")


def api_ref(ref: int | str | None, images: Sequence[np.ndarray],
            names: Sequence[str], names_given: bool = True,
            notes: list[str] | None = None) -> int:
    """``remove_dynamic``'s ``ref`` as an index: None = the middle image; an int,
    negative from the end as in Python; ``"auto"`` (``video.auto_reference``: its
    note, which names the choice, is warned and appended to ``notes``); a name of
    ``names``. Raises InputError when it names nothing or is out of range."""
    if isinstance(ref, str) and ref.strip().lower() == "auto":
        from dynremove.video import auto_reference

        r, note, _ = auto_reference(images, names)
        warnings.warn(note, Note, stacklevel=3)
        if notes is not None:
            notes.append(note)
        return r
    if isinstance(ref, (bool, float)):
        raise InputError(f"reference {ref!r}: give an int index, a name or 'auto'")
    if isinstance(ref, (np.integer, int)):
        ref = int(ref)
    try:
        return resolve_ref(ref, names, label=f"ref={ref!r}")  # the API's words, not --ref
    except InputError as e:
        if names_given or not isinstance(ref, str) or "names no input image" not in str(e):
            raise
        raise InputError(f"{e}; pass names=[...] (e.g. the file names) to refer to images "
                         "by name") from None


def _api_probes(probes: object, W: int, H: int) -> list[tuple[int, int]]:
    """``remove_dynamic``'s ``probes`` as (x, y) int pairs inside the W×H image;
    InputError otherwise (a trial's float, triple or bare int leaked IndexError,
    ValueError and TypeError)."""
    try:
        items = list(probes)  # type: ignore[call-overload]
    except TypeError:
        raise InputError(f"probes={probes!r}: give a sequence of (x, y) pixels, e.g. "
                         "[(120, 40)]") from None
    out = []
    for p in items:
        ok = (isinstance(p, (tuple, list, np.ndarray)) and len(p) == 2 and all(
            isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in p))
        if not ok:
            raise InputError(f"probe {p!r}: give an (x, y) pair of int pixel coordinates")
        x, y = int(p[0]), int(p[1])
        if not (0 <= x < W and 0 <= y < H):
            raise InputError(f"probe pixel ({x}, {y}) is outside the {W}x{H} image")
        out.append((x, y))
    return out


def _api_valid_masks(valid_masks: object, n: int, W: int, H: int) -> list[np.ndarray]:
    """``remove_dynamic``'s ``valid_masks``: one (H, W) mask per image, as bool;
    InputError otherwise (a wrong count or size leaked IndexError and ValueError)."""
    try:
        masks = list(valid_masks)  # type: ignore[call-overload]
    except TypeError:
        raise InputError(f"valid_masks: give one ({H}, {W}) bool mask per image, got "
                         f"{type(valid_masks).__name__}") from None
    if len(masks) != n:
        raise InputError(f"valid_masks: {len(masks)} given for {n} images: give one "
                         f"({H}, {W}) bool mask per image, in the same order")
    out = []
    for i, m in enumerate(masks):
        a = np.asarray(m)
        if a.shape != (H, W):
            raise InputError(f"valid_masks[{i}]: shape {a.shape}, the images are "
                             f"{W}x{H}: give ({H}, {W}) bool masks")
        out.append(a.astype(bool))
    return out


def _array_hint(i: int, im: object, *, bits: int = 16) -> str:
    """What is wrong with ``im`` (image ``i`` of the API's input) as an (H, W, 3)
    uint8 BGR array, and the line of code that fixes it: one sentence. ``bits``:
    the bit depth of the set's 16-bit images (``_uint16_depth``)."""
    if im is None:
        return (f"image {i} is None (cv2.imread returns None for a file it could not "
                "read: check that path)")
    if isinstance(im, (str, bytes, os.PathLike)):
        return (f"image {i} is a path ({os.fsdecode(im)!r}), not an image: read the photos "
                "with dynremove.io.load_image_set(paths, max_side=1280) and pass the set "
                "itself (EXIF orientation, borders, the command line's analysis size) or "
                "cv2.imread")
    if not isinstance(im, np.ndarray):
        kind = f"{type(im).__module__}.{type(im).__qualname__}".removeprefix("builtins.")
        if kind.startswith("PIL."):
            return (f"image {i} is a {kind}: pass np.asarray(img.convert('RGB'))[..., ::-1] "
                    "(an (H, W, 3) uint8 array in BGR order, as cv2.imread gives)")
        return (f"image {i} is of type {kind}, not an array: pass (H, W, 3) uint8 BGR arrays "
                "(as cv2.imread gives)")
    got = f"got {im.shape} {im.dtype}"
    if im.ndim == 2 or (im.ndim == 3 and im.shape[2] == 1):
        return (f"image {i}: expected (H, W, 3) uint8, {got}: a gray image; pass "
                "cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)")
    if im.ndim == 3 and im.shape[2] == 4:
        return (f"image {i}: expected (H, W, 3) uint8, {got}: with an alpha channel; pass "
                "img[..., :3] (BGRA to BGR, as the command line does)")
    if im.ndim == 3 and im.shape[0] in (1, 3, 4) and im.shape[2] > 4:
        return (f"image {i}: expected (H, W, 3) uint8, {got}: channels first; pass "
                "np.ascontiguousarray(np.moveaxis(img, 0, -1)) (and BGR order)")
    if im.ndim != 3 or im.shape[2] != 3:
        return f"image {i}: expected (H, W, 3) uint8, {got}"
    if im.dtype == np.uint16:
        # (a trial's 12-bit data: ">> 8", as this said, left it at 0-15, and the run
        # then blamed near-copies and too few matches)
        what = ("16-bit" if bits == 16 else
                f"16-bit holding {bits}-bit values (none above {2 ** bits - 1})")
        fix = ("img.astype(np.uint8)" if bits == 8 else
               f"(img >> {bits - 8}).astype(np.uint8), the same shift for every photo")
        return (f"image {i}: expected (H, W, 3) uint8, {got}: {what}; pass {fix}, "
                "as the command line reads them")
    if np.issubdtype(im.dtype, np.floating):
        top = float(np.nanmax(im)) if im.size else 0.0
        fix = ("(img * 255).round().astype(np.uint8)" if top <= 1.0 else
               "img.clip(0, 255).round().astype(np.uint8)")
        return (f"image {i}: expected (H, W, 3) uint8, {got} (largest value {top:.3g}); "
                f"pass {fix}")
    return f"image {i}: expected (H, W, 3) uint8, {got}; pass img.astype(np.uint8) if its values are 0-255"


def _uint16_depth(images: Sequence[object]) -> int:
    """The bit depth of the 16-bit arrays among ``images``: the smallest of 8, 10, 12,
    14 and 16 bits that holds their largest value (one depth for the set, as
    ``io.load_image_set`` reads 16-bit files)."""
    tops = [int(im.max()) for im in images
            if isinstance(im, np.ndarray) and im.dtype == np.uint16 and im.size]
    top = max(tops, default=2 ** 16 - 1)
    return next(b for b in (8, 10, 12, 14, 16) if top < 2 ** b)


def validate_images(images: Sequence[np.ndarray], ref: int) -> None:
    """Raise InputError unless images are ≥ 2 same-size (H, W, 3) uint8 arrays; the
    message names the first bad image and the line of code that converts it."""
    if len(images) < 2:
        raise InputError(f"need at least 2 images, got {len(images)}")
    for i, im in enumerate(images):
        if not isinstance(im, np.ndarray) or im.dtype != np.uint8 or im.ndim != 3 or im.shape[2] != 3:
            raise InputError(_array_hint(i, im, bits=_uint16_depth(images)))
    shape = images[0].shape
    for i, im in enumerate(images):
        if im.shape != shape:
            raise InputError(f"image {i} is {im.shape[1]}x{im.shape[0]}, image 0 is "
                             f"{shape[1]}x{shape[0]}: all images must have the same size"
                             + size_hint(im.shape[:2], shape[:2]))
    if shape[0] < 16 or shape[1] < 16:
        raise InputError(f"images are too small ({shape[1]}x{shape[0]}); need at least 16x16")
    if not 0 <= ref < len(images):
        raise InputError(f"reference index {ref} out of range 0..{len(images) - 1}")


# the share of a fill that, resting on one photo the others contradict, gets a note
UNCONFIRMED_SHARE = 0.5
# a reference this dark against the other photos' median level (×) gets a note
DARK_REFERENCE = 0.5


# peak memory of a run ≈ MEMORY_BASE_BYTES + MEMORY_BYTES_PER_PX × views × analysed
# pixels: fitted on `dynremove bench` (7 × 854×480: 1.9 GB) and 5 × 4032×3024 analysed
# at full size (21.4 GB, /usr/bin/time -v); a rough figure
MEMORY_BASE_BYTES, MEMORY_BYTES_PER_PX = 0.3e9, 350.0


def physical_memory() -> float | None:
    """This machine's physical memory in bytes (None where the OS does not say)."""
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def memory_needed(n: int, H: int, W: int) -> float:
    """The rough peak memory, in bytes, of analysing ``n`` images of H × W px."""
    return MEMORY_BASE_BYTES + MEMORY_BYTES_PER_PX * n * H * W


def check_memory(n: int, H: int, W: int) -> None:
    """InputError when analysing ``n`` images of H × W px would need more memory than
    the machine has (``remove_dynamic`` on full-size phone photos: a trial's six of
    12 MP asked for 7 GB at once and died with MemoryError, where the command line
    refuses them in one line), saying how to analyse a smaller copy."""
    need = memory_needed(n, H, W)
    have = physical_memory()
    if have is None or need <= have:
        return
    raise InputError(
        f"analysing {n} images of {W}x{H} ({W * H / 1e6:.1f} MP) needs about "
        f"{need / 1e9:.0f} GB of memory, more than this machine's {have / 1e9:.0f} GB: "
        f"read them with dynremove.io.load_image_set(paths, max_side={AUTO_MAX_SIDE}) "
        "(an analysis copy, as the command line makes; "
        "pipeline.full_resolution_output then gives the clean photo at full size), or "
        "pass fewer or smaller images")


def prepare(images: Sequence[np.ndarray], ref: int, params: Params, *,
            timings: dict[str, float] | None = None,
            progress: Progress | None = None) -> tuple[ScanInputs, list[geometry.TwoView]]:
    """Features, geometry, dense correspondences and similarity maps (Sec. 3.1)."""
    clock = _Clock({} if timings is None else timings, progress)
    out = _prepare(images, ref, params, clock)
    clock.stop()
    return out


class _Clock:
    """The stages' seconds and progress lines. A stage runs from its start to the
    next one's (its seconds go to ``timings[name]``), so the stages add up to the
    run; ``progress`` hears ``(name, 0.0)`` when it starts and ``(name, 1.0)`` when
    it ends, its fractions in between stay below 1. A stage started with
    ``show=False`` reports its own progress (the scans: one line per scan)."""

    def __init__(self, timings: dict[str, float], progress: Progress | None) -> None:
        self.timings, self.progress = timings, progress
        self.name: str | None = None
        self.show = False
        self.t = 0.0

    def start(self, name: str, *, show: bool = True) -> None:
        self.stop()
        self.name, self.show, self.t = name, show, time.perf_counter()
        if show and self.progress:
            self.progress(name, 0.0)

    def tick(self, frac: float) -> None:
        if self.show and self.progress and self.name is not None:
            self.progress(self.name, min(frac, 0.999))

    def stop(self) -> None:
        if self.name is None:
            return
        self.timings[self.name] = time.perf_counter() - self.t
        if self.show and self.progress:
            self.progress(self.name, 1.0)
        self.name = None


def _prepare(images: Sequence[np.ndarray], ref: int, params: Params, clock: _Clock,
             on_geometry: Callable[[list[geometry.TwoView]], None] | None = None
             ) -> tuple[ScanInputs, list[geometry.TwoView]]:
    """``prepare`` on ``clock``, whose last stage ("similarity") is left running;
    ``on_geometry(views)`` is called as soon as the geometry is known."""
    p = params.patch_size
    srcs = [i for i in range(len(images)) if i != ref]
    clock.start("features")
    grays = [features.to_gray(im) for im in images]
    g8 = [np.clip(g + 0.5, 0, 255).astype(np.uint8) for g in grays]
    # the geometry and the flow need only the gray photos: they run on a thread of
    # their own while the dense SIFT is computed (OpenCV releases the GIL; the
    # results do not depend on it: the estimation seeds its own thread's RNG)
    flows = (np.empty((len(srcs),) + g8[ref].shape + (2,), np.float32)
             if params.correspondence in ("homography+flow", "gated") else None)

    def match_sources():
        views = geometry.geometry_for_sources(g8[ref], [g8[s] for s in srcs],
                                              seed=params.seed)
        Ns = for_each_source(lambda k: correspondence.dense_correspondence(
            g8[ref], g8[srcs[k]], views[k].H, method=params.correspondence,
            flow_preset=params.flow_preset,
            gate_px=params.flow_gate * max(g8[ref].shape),
            F=views[k].F, epipolar_px=params.flow_gate_epipolar_px,
            flow_out=None if flows is None else flows[k]), len(srcs))
        return views, Ns

    with ThreadPoolExecutor(max_workers=1) as pool:
        if numba_threads_safe():
            matching = pool.submit(match_sources)
        else:  # (numba's workqueue layer: no parallel kernel beside another thread's)
            matching = Future()
            matching.set_result(match_sources())
        # the Lab, f_c and f_g written straight into the scan's arrays (the
        # reference's, and the sources' stacked): a stack of the per-photo arrays
        # cost 0.9 s of copying at 7 × 854×480
        H, W = grays[ref].shape

        def stacked(shape, dtype):
            one, stack = np.empty(shape, dtype), np.empty((len(srcs),) + shape, dtype)
            return one, stack, [one if i == ref else stack[srcs.index(i)]
                                for i in range(len(images))]

        lab_r, src_lab, labs = stacked((H, W, 3), np.float32)
        fc_r, fc_s, fc = stacked((H, W, 3), np.float32)
        for i, im in enumerate(images):
            features.to_lab(im, out=labs[i])
            features.patch_mean(labs[i], patch_size=p, out=fc[i])  # f_c from the Lab
        fg_r, fg_s, fg = stacked((H, W, 128), np.uint8)
        for i, g in enumerate(grays):
            features.dense_sift(g, patch_size=p, out=fg[i])
            clock.tick((i + 1) / len(grays))
        unit = features.sift_unit(fg, sift_scale=params.sift_scale)
        # the scan's inputs, stacked per source
        packed = dict(
            img=images[ref].copy(), lab=lab_r, gray=grays[ref].copy(), fc_r=fc_r, fg_r=fg_r,
            src_img=np.ascontiguousarray(np.stack([images[s] for s in srcs])),
            src_lab=src_lab,
            src_gray=np.ascontiguousarray(np.stack([grays[s] for s in srcs])),
            fc_s=fc_s, fg_s=fg_s)
        # (the stages' seconds: "geometry" and "correspondence" are what is left of
        # the matching when the features are done)
        clock.start("geometry")
        views, Ns = matching.result()
        # a source shot brighter or darker than the reference: mapped to its levels
        # (its colours only: the SIFT descriptors are normalised, the flow uses the
        # patches' mean-normalised intensities)
        curves = np.tile(np.arange(256, dtype=np.uint8), (len(srcs), 3, 1))
        if params.exposure_match > 0 and srcs:
            curves = exposure.exposure_curves(images[ref], [images[s] for s in srcs], Ns,
                                              min_change=params.exposure_match)
            for k in np.flatnonzero(exposure.changed(curves)):
                im = exposure.apply_curves(images[srcs[k]], curves[k])
                lab_k = features.to_lab(im)
                packed["src_img"][k] = im
                packed["src_lab"][k] = lab_k
                packed["src_gray"][k] = features.to_gray(im)
                packed["fc_s"][k] = features.patch_mean(lab_k, patch_size=p)
    if on_geometry is not None:
        on_geometry(views)
    clock.start("correspondence")
    Nf = np.ascontiguousarray(np.stack(Ns))
    N = correspondence.round_matches(Nf)

    S = len(srcs)
    F = np.zeros((S, 3, 3), np.float64)
    hasF = np.zeros(S, np.bool_)
    for k, v in enumerate(views):
        if v.F is not None:
            F[k], hasF[k] = v.F, True
    clock.start("similarity")
    st = ScanInputs(**packed, N=N, C=np.zeros(N.shape[:3], np.float32), F=F, hasF=hasF,
                    sift_unit=unit, Nf=Nf, Nf_flow=flows, curves=curves)
    pf, pi = pack_params(params, sift_unit=unit)
    st.C = kn._similarity_map(st.N, st.fc_r, st.fg_r, st.fc_s, st.fg_s, st.F, st.hasF, pf, pi)
    return st, views


def remove_dynamic(images: Sequence[np.ndarray], *, ref: int | str | None = None,
                   params: Params | str | dict | None = None,
                   sink: EventSink | None = None,
                   probes: Sequence[tuple[int, int]] = (), sample_static: float = 0.0,
                   names: Sequence[str] | None = None, preset_name: str = "custom",
                   kernel: str = "numba", chunk_rows: int | None = None,
                   progress: Progress | None = None,
                   valid_masks: Sequence[np.ndarray] | None = None,
                   true_background: np.ndarray | None = None) -> Result:
    """Detect the moving objects in the reference and replace them (Algorithm 1).

    The images are analysed at the size given (the command line analyses photos
    larger than 1280 px at that size, ``--max-side``): to do the same, read them with
    ``dynremove.io.load_image_set(paths, max_side=1280)`` (EXIF orientation, 16-bit,
    alpha and gray handled as the command line does; its ``.images``, ``.paths``).

    Parameters
    ----------
    images : sequence (or iterable) of (H, W, 3) uint8 BGR ndarrays, or an ImageSet
        The set; all the same size (as ``cv2.imread`` gives; a stacked (N, H, W, 3)
        array too). An ``ImageSet`` from ``dynremove.io.load_image_set`` is taken
        whole: its images, and its names, validity masks and loading notes where
        ``names`` and ``valid_masks`` are not given (the command line's reading).
        They are analysed at the size given: full-size photos at full size.
    ref : int or str, optional
        The reference: an index (negative counts from the end, as in Python), a
        name of ``names``, or ``"auto"`` (the sharpest image with the most keypoint
        matches, as ``run --ref auto``; a note in ``Result.warnings`` names it).
        Default: the middle image (of an even number, the later of the two middle ones).
    params : Params, str, dict or None
        The method's parameters: a Params, a preset name (``"default"``,
        ``"paper"``), a dict of Params fields applied over the default preset, or
        None (the default preset).
    sink : EventSink, optional
        Observer of the scans (default NullSink: nothing recorded).
    probes : sequence of (x, y) ints
        Pixels whose every decision is recorded, static or not.
    sample_static : float in [0, 1]
        Fraction of static decisions recorded (deterministic sample).
    names : sequence of str, optional
        One per image, in order: how notes, warnings and a recording name them, and
        what a str ``ref`` may name (default ``image0``, ``image1``, ...).
    preset_name : str
        The preset's name as a recording reports it (default: the name given as
        ``params``, else "custom").
    kernel : {"numba", "reference"}
        The compiled scan or the slow readable one (tests).
    chunk_rows : int >= 1, optional
        Rows the compiled scan visits between two returns to Python (progress,
        Ctrl-C); the default suits the image size. The result does not depend on it.
    progress : callable (stage: str, fraction: float) -> None, optional
        Told each stage's start (0.0), progress and end (1.0), in order:
        "features", "geometry", "correspondence", "similarity", "scan 0" (and
        "scan 1", ... where more scans run), "coverage", then, where they run,
        "refine" and "fusion" (the fill, which the command line's bar calls "fill
        by selection"). ``Result.timings`` has the same keys, but one "scans" for
        all the scans.
    valid_masks : sequence of (H, W) bool ndarrays, optional
        Per image, where it has content (False: transparent or empty border of a
        pre-aligned frame). Never flagged in the reference (the input is kept
        there), never used as fill from a source.
    true_background : (H, W, 3) uint8 ndarray, optional
        For evaluation only: the reference without its movers. The fill by
        selection then samples the sources across L through this image's own
        matches in them, not through the fields it estimates (``select_fill``'s
        ``true_background``; ``dynremove eval --methods true-fields``).

    Returns
    -------
    Result
        ``clean`` (H, W, 3) uint8 and ``dynamic`` (H, W) bool, at the input's size;
        ``coverage`` (H, W) uint8: how many sources the output was made from (inside
        ``dynamic``: 0 where inpainted), the counts that the CLI's coverage.png
        scales to 0–255 (its report.json gives the factor, ``value_per_source``);
        ``warnings``: the run's notes as sentences (each also issued as a
        warning of category ``dynremove.Note``, a ``UserWarning``); ``timings``:
        seconds per stage (they add up to ``"total"``); ``scans``: one record per
        scan (``SCAN_SUMMARY_DTYPE``'s fields: scan, direction, n_dynamic,
        n_replaced, n_undecided, seconds).
        The notes name the command line's flags; the same setting here is the
        ``Params`` field of that name with underscores (``--select-minority 0``:
        ``params={"select_minority": 0}``).

    Raises
    ------
    InputError
        Fewer than 2 images; an image that is not an (H, W, 3) uint8 array (the
        message says which, and the line of code that converts it: gray, BGRA,
        16-bit, float, None from a failed ``cv2.imread``, a PIL image); images of
        different sizes; ``names`` not one per image; a ``ref`` that names nothing
        or is out of range; an unknown preset, Params field, a value of the wrong
        type or range; a probe that is not an (x, y) pair of ints or lies outside the
        image; ``sample_static`` outside [0, 1]; ``chunk_rows`` under 1;
        ``valid_masks`` not one (H, W) mask per image; an unknown ``kernel``; images
        whose analysis would need more memory than the machine has (``check_memory``);
        ``params`` of another type; a ``progress`` that is not callable, a ``sink``
        without the EventSink methods; a ``true_background`` that is not an
        (H, W, 3) uint8 array of the images' size.
    RuntimeError
        In a process forked from one that had already run dynremove on numba's
        OpenMP layer (``refine.concurrency.check_fork_safe``): use the "spawn" or
        "forkserver" start method of ``multiprocessing``.
    """
    check_fork_safe()
    set_notes: list[str] = []
    if isinstance(images, ImageSet):
        # as ``load_image_set`` read them: its names, validity masks (a border or
        # transparency: without them the README's recipe flagged a black border as
        # moving, a trial's 10 190 px) and notes, where the call gives none
        set_notes = list(images.notes)
        names = images.names if names is None else names
        valid_masks = images.valid_masks if valid_masks is None else valid_masks
        images = images.images
    if isinstance(params, str) and preset_name == "custom":
        preset_name = params.strip().lower()
    params = api_params(params)
    if isinstance(images, np.ndarray) and images.ndim in (2, 3):
        # (a trial's single photo read as 180 "images" of one row each)
        raise InputError(f"images is one array of shape {images.shape}: pass a list of "
                         "photos, [img0, img1, ...], or a stacked (N, H, W, 3) array")
    if isinstance(images, Mapping):
        raise InputError("images is a mapping: pass a list of photos, e.g. "
                         "list(images.values()) (a mapping iterates over its keys)")
    if isinstance(images, np.ndarray) or not isinstance(images, Sequence):
        # a stacked (N, H, W, 3) array, a generator, a map: read once, as a list
        try:
            images = list(images)
        except TypeError:
            raise InputError("images must be a sequence of (H, W, 3) uint8 BGR arrays, got "
                             f"{type(images).__name__}") from None
    validate_images(images, 0)
    check_memory(len(images), *images[0].shape[:2])
    if kernel not in ("numba", "reference"):
        raise InputError(f"kernel must be 'numba' or 'reference', got {kernel!r}")
    names_given = names is not None
    if names is None:
        names = [f"image{i}" for i in range(len(images))]
    else:
        names = [str(n) for n in names]
        if len(names) != len(images):
            raise InputError(f"names: {len(names)} given for {len(images)} images: "
                             "give one name per image, in the same order")
    auto_note: list[str] = []
    ref = api_ref(ref, images, names, names_given=names_given, notes=auto_note)
    images, gray_note = gray_like_reference(images, ref)
    gray_apart, gray_apart_note = gray_beside_colour(images, ref, names)
    # every photo black and white (a trial: the sanitizer set in gray, its bottle's cap
    # removed and its body kept, with no word of why)
    all_gray_note = (ALL_GRAY_NOTE if gray_note is None and is_gray(images[ref])
                     and all(is_gray(im) for i, im in enumerate(images) if i != ref)
                     else None)
    sink = NullSink() if sink is None else sink
    missing = [m for m in ("enabled", "start", "scan_started", "chunk", "scan_finished",
                           "finish") if not hasattr(sink, m)]
    if missing:
        raise InputError(f"sink={type(sink).__name__}: an EventSink is needed (it lacks "
                         f"{', '.join(missing)}): a viewer.RerunSink, a "
                         "dynremove.events.MemorySink, or None")
    if progress is not None and not callable(progress):
        raise InputError(f"progress={progress!r}: give a callable (stage: str, fraction: "
                         "float) -> None, or None")
    H, W = images[0].shape[:2]
    probes = _api_probes(probes, W, H)
    if not (isinstance(sample_static, (int, float, np.number))
            and not isinstance(sample_static, bool) and 0.0 <= sample_static <= 1.0):
        raise InputError(f"sample_static={sample_static!r}: give a fraction in [0, 1]")
    if chunk_rows is not None and (isinstance(chunk_rows, bool) or not isinstance(
            chunk_rows, (int, np.integer)) or chunk_rows < 1):
        raise InputError(f"chunk_rows={chunk_rows!r}: give an int of 1 or more (or None)")
    if valid_masks is not None:
        valid_masks = _api_valid_masks(valid_masks, len(images), W, H)
    if true_background is not None:
        tb = np.asarray(true_background)
        if tb.dtype != np.uint8 or tb.shape != (H, W, 3):
            raise InputError(f"true_background: shape {tb.shape} {tb.dtype}, the images are "
                             f"{W}x{H}: give an ({H}, {W}, 3) uint8 array")
        true_background = tb
    if sink.enabled and hasattr(type(sink), "begin"):  # optional hook (RerunSink): open
        sink.begin(names, (H, W), images=images, ref=ref)  # the recording before features
    timings: dict[str, float] = {}
    t_all = time.perf_counter()
    clock = _Clock(timings, progress)
    msgs: list[str] = set_notes + auto_note + [n for n in (gray_note, gray_apart_note,
                                                           all_gray_note) if n]
    srcs = [i for i in range(len(images)) if i != ref]
    keep: list[np.ndarray] = []

    def geometry_notes(views: list[geometry.TwoView]) -> None:
        """The notes the geometry gives, warned as soon as it is known."""
        nonlocal srcs

        def drop(gone) -> None:
            """Leave out the sources ``gone`` (indices into the current ones); ``keep``
            holds the kept ones' indices into the sources before any was dropped."""
            nonlocal views, srcs
            sub = np.setdiff1d(np.arange(len(srcs)), gone)
            keep[:] = [(keep[0] if keep else np.arange(len(srcs)))[sub]]
            views = [views[k] for k in sub]
            srcs = [srcs[k] for k in sub]

        strays = _strays(views)
        if strays:
            good = [v.n_inliers_H for k, v in enumerate(views)
                    if geometry.aligned(v) and k not in strays]
            msgs.append(_strays_note([(names[srcs[k]], views[k].n_matches,
                                       views[k].n_inliers_F, views[k].n_inliers_H)
                                      for k in strays], min(good)))
            drop(strays)
        all_copies = False
        if params.near_copy_agree > 0 and len(srcs) >= 1:
            overlap = np.ones(len(srcs))
            agree = agreement_with_reference(
                np.asarray(images[ref]), np.stack([images[s] for s in srcs]),
                [v.H for v in views], overlap=overlap)
            copy = agree >= params.near_copy_agree

            def alike(k: int) -> str:
                # (a trial read "100.0 % alike" of two frames of a pan 190 px apart)
                return (f"{100 * agree[k]:.1f} % alike" if overlap[k] >= 0.95 else
                        f"{100 * agree[k]:.1f} % alike where it overlaps the reference, "
                        f"{100 * overlap[k]:.0f} % of it")

            if copy.any() and not copy.all():
                msgs.append("near-copies of the reference, not used as evidence (they would "
                            "out-vote the views that saw the background): " + ", ".join(
                                f"{names[srcs[k]]} ({alike(k)})"
                                for k in np.flatnonzero(copy)))
                drop(np.flatnonzero(copy))
            elif copy.all():  # (kept: there is nothing else to compare with)
                all_copies = True
                msgs.append("every other photo is a near-copy of the reference ("
                            + ", ".join(f"{names[srcs[k]]} {alike(k)}"
                                        for k in range(len(srcs)))
                            + "): none shows the scene otherwise, so nothing can be found "
                            "moving; photos taken further apart in time are needed")
        # (where every source is a near-copy of the reference, that note says it all:
        # a trial read "near-copies among the sources" and "only 2 of 4" after it)
        if params.near_copy_agree > 0 and len(srcs) > 2 and not all_copies:
            dups = duplicate_sources(np.stack([images[s] for s in srcs]),
                                     [v.H for v in views], params.near_copy_agree)
            if dups:
                msgs.append("near-copies among the sources, each counted once (the same "
                            "evidence twice would out-vote the others): " + ", ".join(
                                f"{names[srcs[j]]} (of {names[srcs[k]]}, {100 * a:.1f} % "
                                "alike)" for j, k, a in dups))
                drop([j for j, _, _ in dups])
        weak = [k for k, v in enumerate(views) if not geometry.aligned(v)]
        if weak:
            msgs.append(_few_matches_note([(names[srcs[k]], views[k].n_matches,
                                            views[k].n_inliers_H) for k in weak],
                                          some_F=any(views[k].F is not None for k in weak)))
        note = _weak_reference_note(images, ref, srcs, views, names, weak)
        if note:
            msgs.append(note)
        if weak and 2 * len(weak) >= len(views):
            msgs.append(f"{len(weak)} of {len(views)} sources could not be aligned to the "
                        "reference: the result is unreliable (misaligned fill, missed or "
                        "false detections). " + (
                            f"None aligns at the {W}x{H} analysed: that may be too small "
                            "to match (a larger --max-side, where the photos are larger), "
                            "or they may not show the reference's scene"
                            if len(weak) == len(views) and max(H, W) < _SMALL_PX else
                            "None aligns: they may not show the reference's scene (check "
                            "the reference, --ref, and the photos), or overlap it too little"
                            if len(weak) == len(views) else
                            "Photos that overlap more, or show more texture, give more "
                            f"matches; so does a larger --max-side than the {W}x{H} "
                            "analysed, where the photos were larger than that"))
        few = _seen_by_fewer_than_two(views, H, W) if len(views) >= 2 else 0.0
        if few >= 0.25:
            # (with three photos, "fewer than two other photos" read as "not both";
            # and the run does not keep the reference there: one photo alone is
            # compared with it, a fresh-user trial found a parkour runner half removed)
            seen_by = ("only one of the two other photos, or neither" if len(views) == 2
                       else "fewer than two other photos")
            msgs.append(f"{100 * few:.0f} % of the reference is seen by {seen_by} (the "
                        "camera moved far between them): there one photo alone, or none, is "
                        "compared with it, so a mover may stay, whole or in part, and a "
                        "static part may be refilled; photos that overlap more, or more "
                        "photos, cover it")
        if len(srcs) == 1 and not all_copies:
            msgs.append(("only 2 photos" if len(images) == 2 else
                         f"only 2 of the {len(images)} photos are used (the notes above say "
                         "why the others are not)")
                        + ": where they disagree, either may show the mover; the "
                        "reference is kept there unless the colours of the detected region "
                        "single it out (3 or more photos decide by consensus)")
        if all(v.F is None for v in views) and params.use_epipolar:
            msgs.append("no source has a fundamental matrix: the epipolar terms are off")
        for m in msgs:
            warnings.warn(m, Note, stacklevel=4)

    st, views = _prepare(images, ref, params, clock, on_geometry=geometry_notes)
    if keep:  # near-copies dropped (the notes said so)
        st = _keep_sources(st, keep[0])
        views = [views[k] for k in keep[0]]
    # each source's B, G, R gain at its median level (the note, report.json)
    gains = ([exposure.mean_gain(st.curves[k], images[srcs[k]]) for k in range(len(srcs))]
             if st.curves is not None else [np.ones(3)] * len(srcs))
    scaled = [] if st.curves is None else list(np.flatnonzero(exposure.changed(st.curves)))
    # each source's overall factor: the geometric mean of its B, G, R gains
    factors = [float(np.exp(np.log(g).mean())) for g in gains]
    if scaled:
        def level(k):
            g = gains[k]
            m = factors[k]
            bgr = "B/G/R ×" + "/".join(f"{v:.2f}" for v in g)
            if np.abs(np.log(g) - np.log(m)).max() > abs(np.log(m)):
                # the channels part more than the whole moves: a colour cast (a
                # trial read "darker (×1.03, B/G/R ×1.22/1.02/0.88)" of a warm photo)
                tint = "warmer" if g[0] > g[2] else "cooler"
                return f"{names[srcs[k]]} {tint} in colour ({bgr})"
            return (f"{names[srcs[k]]} {'darker' if m > 1 else 'brighter'} (×{m:.2f}"
                    + ("" if np.ptp(g) < 0.03 else f", {bgr}") + ")")
        msgs.append("photos exposed differently from the reference, their colours mapped to "
                    "its levels before comparing: " + ", ".join(level(k) for k in scaled)
                    + " (--exposure-match 0 turns this off)")
        warnings.warn(msgs[-1], Note, stacklevel=2)
        if factors and np.median(factors) <= DARK_REFERENCE:
            # the others' colours squeezed into the reference's few levels: its
            # differences shrink as much, and the thresholds (ΔE, t_r) see less (a
            # fresh-user trial's reference at ×0.25 kept its bottle)
            msgs.append(f"the reference is much darker than the other photos (their levels "
                        f"×{np.median(factors):.2f} to match it): what moved differs less in "
                        "its few levels, so less of it may be found; a brighter photo as "
                        "--ref may do better")
            warnings.warn(msgs[-1], Note, stacklevel=2)
    probe = np.zeros((H, W), np.bool_)
    for (x, y) in probes:
        probe[y, x] = True
    clock.start("scans", show=False)  # a line per scan
    if sink.enabled:
        cov0 = _coverage(st, params)
        sink.start(RunInfo(
            names=names, ref_index=ref, source_indices=srcs, images=list(images),
            params=params.to_dict(), preset=preset_name, versions=versions(),
            size=(H, W), N0=st.N.copy(), C0=st.C.copy(), coverage=cov0,
            probes=[(int(x), int(y)) for x, y in probes]))
    if progress:  # (a ProgressBar times scan 0 from the end of the similarity)
        progress("scan 0", 0.0)

    def scan_progress(scan: int, done: int, total: int) -> None:
        if progress:
            progress(f"scan {scan}", done / total)

    every = getattr(sink, "record_every_rows", None) if sink.enabled else None
    if chunk_rows is None and isinstance(every, (int, np.integer)) and every >= 1:
        # the sink snapshots the reference at the end of a chunk of rows: chunks that
        # divide its period make them fall every ``every`` rows (a trial's
        # --record-every-rows 1 got one every 2-3 rows, the default chunk of H // 50)
        chunk_rows = max(d for d in range(1, min(every, max(1, H // 50)) + 1)
                         if every % d == 0)
    L, M_maps, summaries = run_scans(st, params, sink=sink, probe=probe,
                                     sample_static=sample_static, chunk_rows=chunk_rows,
                                     kernel=kernel, progress=scan_progress)
    # the coverage map: the sources whose match agrees with the reference as the scans
    # left it (the refinement and the fills do not change ``st``; the fill by selection
    # writes its own pixels into it at the end). It is the last reader of the SIFT
    # descriptors f_g: measured now, and f_g (128 bytes per pixel and photo: 0.8 GB for
    # 5 photos at 1280×960) is released before the refinement and the fill, whose own
    # arrays then take its place
    clock.start("coverage")
    cov = _coverage(st, params)
    st.fg_r = st.fg_s = None
    clock.stop()
    stages = {"scan": L}  # the same array as Result.dynamic_raw
    dyn = L.copy()
    clean = st.img
    ref_img = np.asarray(images[ref])
    # a stage that does not run (the paper preset's refine and fill) has no line
    # and no entry in ``timings``
    if params.clean_mask or params.refine_tau > 0 or params.snap:
        clock.start("refine")
    # a flat set (the fill's "scan" consensus mode): the clean-up keeps a slow mover's
    # holed map (majority filter); with parallax a mesh is more often 3-D structure,
    # and GrabCut's growth may be vetoed
    flat = not treated_as_3d(views, params)
    majority = params.clean_majority and flat
    if params.clean_mask:
        dyn = stages["clean"] = clean_mask(L, params, majority=majority)
    if params.refine_tau > 0:
        dyn = stages["votes"] = refine_mask(ref_img, st.src_img, st.Nf, dyn, params,
                                            majority=majority)
        clock.tick(0.5)
    if params.snap:
        snapped = snap_to_edges(ref_img, dyn, params)
        if params.snap_veto and params.refine_tau > 0 and not flat:
            snapped = veto_agreed(ref_img, st.src_img, st.Nf, dyn, snapped, params)
        dyn = stages["snap"] = snapped
    clock.stop()
    selection = None
    if params.fuse:
        clock.start("fusion")
    pre_fill = dyn  # L as the fill by selection takes it
    if params.fuse and params.fill == "select":
        valid_src = None if valid_masks is None else np.stack([valid_masks[s] for s in srcs])
        if st.curves is not None:
            for k, s in enumerate(srcs):
                clip = clipped_highlights(np.asarray(images[s]), st.curves[k])
                if clip is not None:
                    if valid_src is None:
                        valid_src = np.ones((len(srcs),) + clip.shape, bool)
                    valid_src[k] &= ~clip
        selection = select_fill(ref_img, st.src_img, views, dyn, params, valid=valid_src,
                                flows=st.Nf_flow, no_fill=gray_apart[srcs],
                                true_background=true_background)
        shade = relight_shade(selection.clean, st.src_img, selection.fields,
                              selection.replaced, reach_px=params.select_shade_px,
                              min_dl=params.select_shade_de,
                              max_de=params.select_shade_max_de,
                              valid=valid_src, no_fill=gray_apart[srcs])
        if shade is not None:
            selection.clean = apply_offset(selection.clean, shade.offset, shade.relit)
            selection.relit, selection.relight = shade.relit, shade.offset
            # a pixel the fill's blend had already moved, relit further: ΔE tau or more
            # from the reference joins the dynamic map, as the fill's own writes do
            ys, xs = np.nonzero(shade.relit & ~selection.replaced)
            moved = delta_e(features.to_lab(selection.clean[ys, xs][None]),
                            features.to_lab(ref_img[ys, xs][None]))[0] >= params.select_tau
            selection.replaced[ys[moved], xs[moved]] = True
        clean = selection.clean
        dyn = stages["select"] = selection.replaced
    elif params.fuse:
        clean, _ = fuse_background(
            ref_img, st.src_img, st.Nf, dyn, margin_px=params.fuse_margin_px,
            combine=params.fuse_combine,
            realign=params.fuse_realign, homographies=[v.H for v in views],
            flow_preset=params.flow_preset, realign_max_px=params.fuse_realign_max_px)
    if valid_masks is not None:  # no content in the reference: never flagged, kept as is
        valid_ref = np.asarray(valid_masks[ref], bool)
        dyn = stages["valid"] = dyn & valid_ref
        clean = np.where(valid_ref[..., None], clean, ref_img)
    # inside the fill by selection, the coverage map counts what the fill used (the
    # fill's stage)
    if selection is not None:
        cov = _selection_coverage(cov, dyn, selection)
        mis = (dyn & selection.misplaced if selection.misplaced is not None
               else np.zeros_like(dyn))
        n_ns = int((dyn & selection.no_source & ~mis).sum())
        if n_ns:
            share = 100 * n_ns / max(1, dyn.sum())
            ns = dyn & selection.no_source & ~mis
            # of them, where every source that reaches the pixel shows the mover, moved
            # (a slow mover that overlaps itself from photo to photo)
            n_fw = 0
            if selection.reasons is not None:
                r = selection.reasons[:, ns]
                n_fw = int(((r == FOLLOWED).any(0) & np.isin(r, (FOLLOWED, OUTSIDE, OWN_MOVER)).all(0)).sum())
            # (a fresh-user trial on three photos of a static façade read of "the mover"
            # where a pillar, standing off the wall, had been followed by the flow)
            why = (f", {n_fw} px of them because every photo shows its own copy of the mover there, "
                   "displaced (a mover that moved less than its size; or static structure "
                   "standing off the rest, whose parallax the flow followed: look at it)"
                   if n_fw >= 0.5 * n_ns else "")
            msgs.append(f"{n_ns} px ({'under 0.1' if share < 0.1 else f'{share:.1f}'} % of "
                        f"the replaced region) {'was' if n_ns == 1 else 'were'} seen free by "
                        "no source: inpainted "
                        f"(OpenCV Telea){why}")
            warnings.warn(msgs[-1], Note, stacklevel=2)
        n_mp = int(mis.sum())
        if n_mp:
            used = [k - 1 for k in np.unique(selection.label[mis]) if k >= 1]
            msgs.append(f"{n_mp} px of the fill ({100 * n_mp / max(1, dyn.sum()):.1f} % of the "
                        f"replaced region; {_where(mis)}) would have come from "
                        f"{_names([names[srcs[k]] for k in used])}, whose view there does "
                        "not continue the photo kept around it (its match misplaced there, "
                        "as by a near scene's depth): inpainted instead (OpenCV Telea); "
                        "--select-misplaced-de 0 keeps that view")
            warnings.warn(msgs[-1], Note, stacklevel=2)
        n_lg = int((dyn & selection.lingering).sum()) if selection.lingering is not None else 0
        if n_lg >= 5e-4 * dyn.size:  # (a few stray pixels of a mover are no such case)
            lg = dyn & selection.lingering
            used = [k - 1 for k in np.unique(selection.label[lg]) if k >= 1]
            # the witnesses: the sources that neither still show the mover there nor
            # miss the region over most of it
            wit = [k for k in range(len(srcs)) if selection.reasons is not None and
                   np.isin(selection.reasons[k][lg], (OUTSIDE, STILL_LINGERING),
                           invert=True).mean() >= 0.5]
            wit = sorted(set(wit) | set(used))
            # the sources that still show it over most of it (each part of a large
            # region may have other witnesses: "most photos" was wrong when 5 of 6
            # sources witnessed one part or another, a fresh-user trial on DAVIS dog)
            still = [k for k in range(len(srcs)) if k not in wit and selection.reasons
                     is not None and (selection.reasons[k][lg] == STILL_LINGERING).mean() >= 0.5]
            shown = (f"the reference and {_names([names[srcs[k]] for k in still])} show it in "
                     "place" if still else "the reference and other photos show it in place "
                     "(each part in other ones)")
            said = (f"{_names([names[srcs[k]] for k in wit])} saw the background there "
                    + ("and filled it" if used == wit else
                       f"and it was filled from {_names([names[srcs[k]] for k in used])}"))
            msgs.append(
                f"{n_lg} px show a mover that lingered: {shown}; {said}"
                # (shorter than it was: a trial found the 600-character note hard to act on)
                + (f" (a 3-D set, {_off_plane(views, params)}: what was taken for a mover "
                   "may be static structure standing off "
                   "the rest, and an edge a mover hides may come out misplaced: look at it)"
                   if selection.consensus_mode == "parallax" else "")
                + ("; --no-select-minority-one turns off its three-photo rule (one photo "
                   "that saw the background is enough), --select-minority 0 the whole step"
                   if len(srcs) == 2 and params.select_minority_one else
                   "; --select-minority 0 turns this step off"))
            warnings.warn(msgs[-1], Note, stacklevel=2)
    if selection is not None and selection.relit is not None:
        n_rl, n_in = relit_px(selection, dyn)
        if n_rl >= 5e-4 * dyn.size:
            # (a review: the fill's pixels it relit were neither counted nor said)
            msgs.append(f"{n_rl} px beside the removed movers ({_where(selection.relit & ~dyn)}) "
                        "were a faint shade that the other photos see lit (a soft cast "
                        f"shadow: darker than their light by {params.select_shade_de:g} CIE L* "
                        "or more, and than the ground around it, and under ΔE "
                        f"{params.select_shade_max_de:g} from their light): relit to it, with "
                        "the reference's own texture"
                        + (f", as were {n_in} px of the fill where the shade runs into it"
                           if n_in else "")
                        + f"; the mask holds only those changed by ΔE {params.select_tau:g} "
                        "or more (--select-shade-de 0 turns this off)")
            warnings.warn(msgs[-1], Note, stacklevel=2)
    if selection is not None and selection.blur_sigma is not None and selection.blur_sigma.any():
        # (the fill blurred to the reference's sharpness: said, so that a soft fill
        # is not taken for a fault of the sources)
        soft = [int(k) for k in np.flatnonzero(selection.blur_sigma)]
        msgs.append(f"the reference is softer than {_names([names[srcs[k]] for k in soft])} "
                    "(camera shake or focus?): their fill was blurred to match it (σ "
                    + ", ".join(f"{selection.blur_sigma[k]:.1f}" for k in soft)
                    + " working px)")
        warnings.warn(msgs[-1], Note, stacklevel=2)
    if selection is not None and selection.completed is not None:
        n_pk = int((selection.completed == PARTIAL_KEPT).sum())
        if n_pk >= 5e-4 * selection.completed.size:
            # (where: a trial read the note as covering another mover of the photo,
            # left with holes by other rules)
            msgs.append(f"{n_pk} px that the fill would have replaced were kept as the "
                        f"reference shows them ({_where(selection.completed == PARTIAL_KEPT)}), "
                        "with the rest of their mover: the fill could "
                        "replace only part of it, and over the rest no other photo shows "
                        "the background (they show the mover there too, or movers of their "
                        "own), so the mover is kept whole rather than left with holes "
                        "(--select-keep-partial 0 turns this rule off)")
            warnings.warn(msgs[-1], Note, stacklevel=2)
    if selection is not None and dyn.any():
        # pieces of a mover left inside the replaced region: islands of the reference
        # that the fill kept because photos showing the mover in place vouch for them.
        # A fresh-user trial found tim6's cup (tim2-tim5, tim4 the reference) left as a
        # see-through ghost with its letters, and nothing said (README, session 61)
        pieces = kept_pieces(selection, dyn)
        n_pc = int(pieces.sum())
        if n_pc >= 2e-4 * dyn.size and n_pc >= KEPT_PIECES * dyn.sum():
            msgs.append(f"{n_pc} px enclosed by the replaced region ({100 * n_pc / dyn.sum():.0f} % "
                        f"of its area) were kept as the reference shows them "
                        f"({_where(pieces)}): the photos that show them in place show the "
                        "mover around them too, so these are likely pieces of the mover left "
                        "over the fill (its lettering, parts of it that stayed in place in "
                        "those photos): look at them (a run with --record, then 'dynremove "
                        "inspect --pixel', says why each was kept)")
            warnings.warn(msgs[-1], Note, stacklevel=2)
        # most of the fill resting on one photo that the others contradict: three
        # photos whose movers overlap (a fresh-user trial on tim6 as tim3, tim4, tim5
        # found half a cup left and nothing said; measured on the composites, the
        # bursts and DAVIS: at most 29 % of a fill, 89 % on that one)
        n_rep = int((dyn & ~selection.no_source).sum())
        n_un = int(unconfirmed_fill(selection, dyn).sum())
        if n_rep >= 5e-4 * dyn.size and n_un >= UNCONFIRMED_SHARE * n_rep:
            # and what the fill put back of what was found moving (a second trial saw
            # the cup's sleeve kept and the note silent on it)
            n_kept = int((pre_fill & ~selection.replaced).sum())
            kept = (f"; {n_kept} px ({100 * n_kept / max(1, int(pre_fill.sum())):.0f} % of "
                    "what was found moving) were kept as the reference shows them, where "
                    "the other photos did not agree on anything else"
                    + (" (with three photos, two that disagree cannot outvote the "
                       "reference)" if len(srcs) == 2 else "")
                    if n_kept >= 0.25 * pre_fill.sum() else "")
            msgs.append(f"{100 * n_un / n_rep:.0f} % of the replaced region ({n_un} px) was "
                        "filled from one photo alone, where the other photos show a mover "
                        "of their own or something else: nothing confirms the fill there, "
                        f"and parts of a mover may remain or be pasted in{kept} (look at "
                        "it: the coverage map, coverage.png or Result.coverage, counts one "
                        "photo there; more photos, or photos taken further apart in time, "
                        "let the fill be cross-checked)")
            warnings.warn(msgs[-1], Note, stacklevel=2)
    if selection is not None and dyn.any():
        note = _knee_note(views, params)
        if note:
            msgs.append(note)
            warnings.warn(msgs[-1], Note, stacklevel=2)
    # (with two photos most of the photo is undecided on every run: said only where
    # it left nothing found, beside the note on two photos)
    undecided = _undecided_note(summaries, ref_img.shape[0] * ref_img.shape[1], len(srcs))
    if undecided and (len(srcs) > 1 or not dyn.any()):
        msgs.append(undecided)
        warnings.warn(msgs[-1], Note, stacklevel=2)
    if not dyn.any():
        flagged = int(sum(int(sm["n_dynamic"]) for sm in summaries))
        n_pre = int(pre_fill.sum()) if selection is not None else 0
        if n_pre:
            # found, then kept by the fill (a trial read "nothing was found moving"
            # right after the note that a mover was kept whole)
            msgs.append("nothing was removed: the clean image is the reference unchanged "
                        f"(the steps before the fill found {n_pre} px moving, and the fill "
                        "kept them as the reference shows them: the notes above, and "
                        "'dynremove inspect' on a recording, say why)")
        else:
            msgs.append("nothing was found moving in the reference: the clean image is the "
                        "reference unchanged" + (
                            f" (the scans flagged {flagged} px, scattered in pieces that the "
                            "clean-up of L removed: each thinner than its opening, or under "
                            f"--min-region-px {params.min_region_px} px)"
                            if flagged and params.clean_mask else ""))
        warnings.warn(msgs[-1], Note, stacklevel=2)
    elif selection is not None:
        # almost nothing left of much that was flagged: said, as where nothing is (a
        # fresh-user trial on tim4, tim5, tim6: 23 468 px flagged, 42 removed, no note)
        flagged = int(summaries[0]["n_dynamic"]) if summaries else 0
        n_dyn = int(dyn.sum())
        if flagged >= 2e-3 * dyn.size and n_dyn < LITTLE_REMOVED * flagged:
            msgs.append(_little_removed_note(flagged, pre_fill, dyn, selection.explained))
            warnings.warn(msgs[-1], Note, stacklevel=2)
    last = int(summaries[-1]["n_dynamic"]) if summaries else 0
    if params.max_scans > 1 and len(summaries) == params.max_scans and last > 0:
        # the paper's scans alternate until one calls no pixel dynamic; the cap stops
        # them first on most real sets (a trial read 6411, 2755, 2323, 2640 px and
        # took the last scan for the end of the method)
        msgs.append(f"the scans stopped at --max-scans {params.max_scans} while the last "
                    f"still called {last} px dynamic (the paper's scans go on until one "
                    "calls none): a larger --max-scans runs more")
        warnings.warn(msgs[-1], Note, stacklevel=2)
    clock.stop()
    timings["total"] = time.perf_counter() - t_all
    result = Result(
        clean=clean, clean_scan=st.img, dynamic=dyn, dynamic_raw=L, M=M_maps, coverage=cov,
        scans=np.array(summaries), timings=timings, N=st.N, C=st.C, ref_index=ref,
        params=params.to_dict(),
        geometry=[{"source": names[srcs[k]], "matches": v.n_matches,
                   "inliers_F": v.n_inliers_F, "inliers_H": v.n_inliers_H,
                   "parallax_px": (round(v.parallax_px, 2) if np.isfinite(v.parallax_px)
                                   else None),
                   "parallax_p95_px": (round(v.parallax_p95_px, 2)
                                       if np.isfinite(v.parallax_p95_px) else None),
                   "exposure_gain_bgr": [round(float(g), 3) for g in gains[k]]}
                  for k, v in enumerate(views)],
        warnings=msgs, stages=stages, selection=selection, source_indices=list(srcs),
        source_curves=([c for c in st.curves] if st.curves is not None else []),
        gray_sources=gray_note is not None)
    sink.finish(result)
    return result


# a run that removes less than this share of what the scans flagged says so
LITTLE_REMOVED = 0.1
# kept pieces of a mover inside the replaced region (``select.kept_pieces``) of at
# least this share of its area (and 0.02 % of the photo) are said: 1.2-6.0 % on the
# 3- and 4-photo tim6 sets that show them, at most 0.2 % on the composites and DAVIS
KEPT_PIECES = 0.01


def _little_removed_note(flagged: int, pre_fill: np.ndarray, dyn: np.ndarray,
                         explained: np.ndarray) -> str:
    """The note of a run that removed little of what its scans flagged: ``flagged``
    px flagged, ``pre_fill`` (H, W) bool the L the fill took, ``dyn`` the final
    mask, ``explained`` the pixels of L kept as static 3-D structure. The fill both
    keeps pixels of L and adds some beside them, counted apart (a trial read "the
    fill kept -1536 of those" where it had added 1536)."""
    n_dyn, n_pre = int(dyn.sum()), int(pre_fill.sum())
    n_kept, n_added = int((pre_fill & ~dyn).sum()), int((dyn & ~pre_fill).sum())
    n_ex = int((pre_fill & explained).sum())
    return (f"little was removed: {n_dyn} px ({_where(dyn)}), of the {flagged} px the "
            f"scans flagged: the clean-up of L and the border steps after it left {n_pre} px, "
            f"and the fill kept {n_kept} of those as the reference shows them"
            + (f" and added {n_added} px beside them" if n_added else "")
            + (f" ({n_ex} px as static 3-D structure that other photos show in place)"
               if n_ex else "")
            + ": 'dynremove inspect' on a recording says why at each pixel")


def relit_px(selection: Selection | None, dynamic: np.ndarray | None = None
             ) -> tuple[int, int]:
    """The pixels ``shade.relight_shade`` changed outside the dynamic map and inside
    it: (outside, inside), at the analysis size; (0, 0) without a relit shade.
    ``dynamic`` (H, W) bool defaults to the fill's (``Selection.replaced``)."""
    relit = getattr(selection, "relit", None)
    if relit is None:
        return 0, 0
    dyn = selection.replaced if dynamic is None else dynamic
    return int((relit & ~dyn).sum()), int((relit & dyn).sum())


def misplaced_px(selection: Selection | None) -> int:
    """The replaced pixels of the fill's misplaced pieces (``select.misplaced_pieces``:
    inpainted instead), at the analysis size; 0 without any."""
    mis = getattr(selection, "misplaced", None)
    return 0 if mis is None else int((mis & selection.replaced).sum())


def _where(mask: np.ndarray, n: int = 3) -> str:
    """Where ``mask`` (H, W) bool lies, in words: the boxes of its ``n`` largest parts
    (8-connected after a 5 px closing; x then y, in the analysed image's pixels, as
    ``inspect --pixel`` counts), largest first, and how many more parts there are."""
    joined = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    k, _, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    if k <= 1:
        return "nowhere"
    order = 1 + np.argsort(-stats[1:, cv2.CC_STAT_AREA], kind="stable")
    # a part under 2 % of the largest is counted, not boxed (a review read
    # "x 426–426, y 838–838" beside a 5 000 px part)
    big = stats[order[0], cv2.CC_STAT_AREA]
    order = [i for i in order[:n] if i == order[0] or stats[i, cv2.CC_STAT_AREA] >= 0.02 * big]
    boxes = [f"x {x}–{x + w - 1}, y {y}–{y + h - 1}" for x, y, w, h, _ in
             (stats[i] for i in order)]
    more = k - 1 - len(boxes)
    return "at " + "; ".join(boxes) + (f"; and {more} smaller part{'s' * (more > 1)}"
                                       if more > 0 else "")


def _names(who: list[str]) -> str:
    """'tim1' / 'tim1 and tim2' / 'a, b and 2 more' (notes naming photos)."""
    if not who:
        return "them"
    if len(who) <= 3:
        return who[0] if len(who) == 1 else ", ".join(who[:-1]) + " and " + who[-1]
    return f"{', '.join(who[:2])} and {len(who) - 2} more"


def is_gray(image: npt.NDArray[np.uint8], *, tol: int = 3) -> bool:
    """Whether a (H, W, 3) uint8 BGR image is black and white: on every 7th pixel,
    the 99.5th percentile of its largest channel difference is at most ``tol``
    (levels of 255; a B&W JPEG keeps a level or two of chroma noise)."""
    px = np.asarray(image).reshape(-1, 3)[::7].astype(np.int16)
    if len(px) == 0:
        return False
    spread = px.max(axis=1) - px.min(axis=1)
    return bool(np.percentile(spread, 99.5) <= tol)


def _in_gray(image: np.ndarray) -> np.ndarray:
    """A (H, W, 3) BGR image in gray, still 3 channels (OpenCV's weights)."""
    g = cv2.cvtColor(np.asarray(image), cv2.COLOR_BGR2GRAY)
    return cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)


ALL_GRAY_NOTE = ("every photo is black and white: without colour to go by, a mover in "
                 "the scene's gray levels may be found only in part: look at the clean photo")


def gray_like_reference(images: Sequence[np.ndarray], ref: int
                        ) -> tuple[list[np.ndarray], str | None]:
    """Where the reference is black and white (``is_gray``) and some other photo is
    not, every photo converted to gray (BGR → gray → BGR, OpenCV's weights), and
    a note; else the images as given and None.

    A colour source would otherwise fill a B&W reference with colour, and its
    colours, which the reference cannot match, would flag static scene as
    dynamic (a fresh-user trial: shaky_desk6 with desk4 saved as gray, a brown
    patch where the bottle was and twice the mask)."""
    images = list(images)
    if not is_gray(images[ref]):
        return images, None
    colour = [i for i, im in enumerate(images) if i != ref and not is_gray(im)]
    if not colour:
        return images, None
    for i in colour:
        images[i] = _in_gray(images[i])
    return images, (f"the reference is black and white: the {len(colour)} colour "
                    f"photo{'' if len(colour) == 1 else 's'} among the others "
                    f"{'was' if len(colour) == 1 else 'were'} used in gray, so that the "
                    "fill matches it; without colour to go by, a mover in the scene's gray "
                    "levels may be found only in part: look at the clean photo")


def gray_beside_colour(images: Sequence[np.ndarray], ref: int, names: Sequence[str]
                       ) -> tuple[npt.NDArray[np.bool_], str | None]:
    """The other half of ``gray_like_reference``: black-and-white photos beside a
    colour reference and colour sources, (N,) bool per image, and a note; none (and
    None) otherwise. Their evidence counts but they never fill (``select_fill``'s
    ``no_fill``): their levels mapped to the reference's channels would paste a tinted
    grey (a fresh-user trial's sanitizer2.jpg saved as grey read "cooler in colour").
    Where every source is grey, they fill: nothing else could."""
    apart = np.zeros(len(images), bool)
    if is_gray(images[ref]):
        return apart, None
    apart[[i for i, im in enumerate(images) if i != ref and is_gray(im)]] = True
    if not apart.any() or apart.sum() == len(images) - 1:
        return np.zeros(len(images), bool), None
    return apart, ("black-and-white photos among colour ones: "
                   + ", ".join(names[i] for i in np.flatnonzero(apart))
                   + " count as evidence but do not fill the colour reference")


def full_resolution_output(result: Result, full_images: Sequence[np.ndarray]
                           ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
    """The clean reference and dynamic map at the size of ``full_images``.

    ``full_images``: every image of the set at full resolution, in the order the
    run was given them (the run itself used smaller copies). Pixels outside the
    replaced region and the relit shade (``Selection.relit``: changed by less than
    ``select_tau``) are the full-resolution reference's, byte for byte
    (``refine.upsample.full_resolution``). Raises InputError when they are not
    (H, W, 3) uint8 images of one size with the analysed images' aspect, or too few.
    """
    n = 1 + max([result.ref_index] + list(result.source_indices))
    if len(full_images) < n:
        raise InputError(f"full_images: {len(full_images)} images, the run had at least {n}")
    if result.gray_sources:  # as the analysis did, whatever is_gray says at this size
        full_images = [im if i == result.ref_index or np.asarray(im).ndim != 3
                       else _in_gray(im) for i, im in enumerate(full_images)]
    ref = np.asarray(full_images[result.ref_index])
    srcs = [np.asarray(full_images[i]) for i in result.source_indices]
    if result.source_curves:  # exposure matched as the analysis did
        srcs = [exposure.apply_curves(im, c) if im.dtype == np.uint8 and im.ndim == 3 else im
                for im, c in zip(srcs, result.source_curves)]
    h, w = result.clean.shape[:2]
    for im in [ref] + srcs:
        if im.dtype != np.uint8 or im.ndim != 3 or im.shape[2] != 3 or im.shape != ref.shape:
            raise InputError(f"full_images: expected (H, W, 3) uint8 images of one size, got "
                             f"{im.shape} {im.dtype}")
    H, W = ref.shape[:2]
    if H < h or W < w or abs(H * w - W * h) > max(H, W):  # the aspect, within a pixel
        raise InputError(f"full_images are {W}x{H}: not the analysed {w}x{h} photos at "
                         "full size (turned, or cropped?)")
    return full_resolution(ref, srcs, result.clean, result.dynamic, result.selection,
                           tau=float(result.params.get("select_tau", 10.0)))


def _keep_sources(st: ScanInputs, keep: np.ndarray) -> ScanInputs:
    """``st`` restricted to the sources ``keep`` (indices along the S axis)."""
    per_source = ("src_img", "src_lab", "src_gray", "fc_s", "fg_s", "N", "C", "F", "hasF", "Nf",
                  "Nf_flow", "curves")
    return dataclasses.replace(st, **{
        k: np.ascontiguousarray(getattr(st, k)[keep]) for k in per_source
        if getattr(st, k) is not None})


def _seen_by_fewer_than_two(views: list[geometry.TwoView], H: int, W: int,
                            step: int = 8) -> float:
    """Share of the reference (an (H, W) image, sampled every ``step`` px) that fewer
    than two sources see, each source's frame mapped through its homography."""
    ys, xs = np.mgrid[step // 2:H:step, step // 2:W:step].astype(np.float64)
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    seen = np.zeros(xs.size, np.int64)
    for v in views:
        q = v.H @ pts
        with np.errstate(divide="ignore", invalid="ignore"):
            u, w = q[0] / q[2], q[1] / q[2]
        seen += (q[2] > 0) & (u >= 0) & (u <= W - 1) & (w >= 0) & (w <= H - 1)
    return float(np.mean(seen < 2))


def _coverage(st: ScanInputs, params: Params) -> np.ndarray:
    """Sources whose current match agrees with the reference's current features."""
    pf, _ = pack_params(params, sift_unit=st.sift_unit)
    return kn._appearance_support(st.N, st.fc_r, st.fg_r, st.fc_s, st.fg_s, pf)


def _selection_coverage(cov: np.ndarray, dynamic: np.ndarray, selection: Selection
                        ) -> np.ndarray:
    """``cov`` with the fill by selection's pixels: inside ``dynamic`` (the replaced
    pixels kept in the output), the number of sources the output was made from
    (``Selection.members``: the chosen source and the free ones whose sample through
    their field agrees with it; their median is the output), and 0 exactly where no
    source showed the background free (``Selection.no_source``: inpainted). A pixel
    of ``dynamic`` only relit (``Selection.relit``, no source filled it) keeps ``cov``."""
    if selection.members is None or not dynamic.any():
        return cov
    if selection.relit is not None:  # relit only (no source filled it): not "inpainted"
        dynamic = dynamic & ~(selection.relit & (selection.label < 1) & ~selection.no_source)
    n = np.minimum(selection.members.sum(0), 255).astype(np.uint8)
    return np.where(dynamic, np.where(selection.no_source, 0, n), cov).astype(cov.dtype)


def clipped_highlights(source: np.ndarray, curve: np.ndarray) -> np.ndarray | None:
    """Where a source shot brighter than the reference is clipped white: (H, W) bool
    (its pixels at 254-255 in all three channels, 2 px wider), or None where its
    tone ``curve`` (3, 256) does not darken level 255 below 250 in every channel
    (the source is not brighter) or nothing is clipped.

    Mapped to the reference's levels (``exposure.apply_curves``), such a highlight is
    one flat colour with no texture; as evidence and fill it is no view of the scene
    (a trial's burst with two photos 1-1.2 stops brighter: their clipped glare agreed
    with each other, "witnessed" a lingering mover on the table and replaced the
    glare with a flat grey-blue patch). The fill by selection treats it as no content.
    """
    if not (np.asarray(curve)[:, 255] < 250).all():
        return None
    m = cv2.inRange(source, (254, 254, 254), (255, 255, 255))
    if not m.any():
        return None
    return cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))) > 0


STRAY_SHARE_OF_MEDIAN = 0.15  # homography inliers under this share of the others' median ...
STRAY_SHARE_OF_MATCHES = 0.2  # ... and under this share of its own matches: a stray


def _strays(views: list[geometry.TwoView]) -> list[int]:
    """Sources without a homography (``geometry.aligned``) while the aligned ones have
    a median of ``4 × MIN_MATCHES`` or more homography inliers: a photo of another
    scene, one too blurred to match, or one that overlaps too little. Used, it is
    aligned by the flow alone and its content fills the reference (a breakdance
    frame among camel photos, 39 matches and an F on 10, pasted its dancer's
    colours into the fill). Measured on parkour's first frame (108 matches, an F
    on 54, its homography folded): kept without a pre-warp, J 0.506; left out,
    0.544. Where no source aligns well (a fast pan, a sky), none is a stray: the
    run keeps them all and says it is unreliable."""
    good = [v.n_inliers_H for v in views if geometry.aligned(v)]
    if not good or np.median(good) < 4 * geometry.MIN_MATCHES:
        return []
    med = float(np.median(good))
    # ... and a source whose homography fits few of its own matches and far fewer
    # than the others' (a trial: tim2 mirrored, 10 of 83 matches on a homography
    # against the others' 82-183; a desk photo among tim6's, 8 of 45). Legitimate
    # sources measured on the 19 DAVIS sets, the bursts and the 48 composites: the
    # fewest inliers against the median 0.07 (dog's last frame, 9 of its 24 matches),
    # the smallest share of its matches 0.21 (parkour, 18 of 87): never both.
    return [k for k, v in enumerate(views) if not geometry.aligned(v)
            or (v.n_inliers_H < STRAY_SHARE_OF_MEDIAN * med
                and v.n_inliers_H < STRAY_SHARE_OF_MATCHES * v.n_matches)]


def _undecided_note(summaries: list, n_px: int, n_sources: int, *,
                    share: float = 0.5) -> str:
    """The note on a first scan that left at least ``share`` of the reference's
    ``n_px`` pixels undecided (no cluster of candidate matches formed: the scans call
    none of them dynamic), or ''. A fresh-user trial ran two photos in which a cup
    moved 150 px: 84 % of the photo was undecided, and the only notes were "only 2
    photos" and "nothing was found moving ... in specks". (With two photos most of a
    photo is undecided on every run, 79-90 % measured: the caller says it there only
    when nothing was found.)"""
    if not summaries or n_px <= 0:
        return ""
    frac = int(summaries[0]["n_undecided"]) / n_px
    if frac < share:
        return ""
    why = ("with 2 photos a pixel's candidates come from the other photo alone, and "
           "they must agree with each other" if n_sources == 1 else
           "too few of the other photos agree about it: photos that overlap more, or "
           "more photos, decide more")
    return (f"the scans could not decide {100 * frac:.0f} % of the reference (no cluster "
            f"of candidate matches formed there: {why}); they call no such pixel "
            "dynamic, so a mover there may stay")


def _off_plane(views: list[geometry.TwoView], params: Params) -> str:
    """How far the set's keypoint matches lie off one plane, as ``treated_as_3d``
    read it (for a note)."""
    p90 = median_parallax_px(views)
    if p90 > params.select_parallax_px or params.select_parallax_p95_px <= 0:
        return f"its keypoint matches {p90:.0f} px off one plane"
    return (f"5 % of its keypoint matches "
            f"{median_parallax_px(views, 'parallax_p95_px'):.0f} px or more off one plane")


def _knee_note(views: list[geometry.TwoView], params: Params) -> str:
    """The note of a set whose 3-D structure is small: the median over the sources of
    the 90th percentile of the parallax is at most ``select_parallax_px``, of the
    95th over it (otherwise ``_near_limit_note``'s, or ''). Columns in front of a façade hold 8-16 % of
    entry-P10's matches: treated as flat, a 4-view composite of it refilled one
    (damage 2.8 % of the photo, 1.0 % as 3-D), and DAVIS drift-straight_s3 kept part
    of its car (J 0.54, 0.83 as 3-D). The far matches may also lie on a mover that
    fits the epipolar geometry, so the 95th decides only far out, over
    ``select_parallax_p95_px`` (``treated_as_3d``): near, it made 3-D a car the
    camera pans with (car-roundabout, --ref 5, 27 px) and synthetic scenes whose
    lingering mover the 3-D consensus then kept (README, session 41). The note
    says which way the set went and the flag that turns it the other way."""
    limit, far = params.select_parallax_px, params.select_parallax_p95_px
    p90 = median_parallax_px(views)
    p95 = median_parallax_px(views, "parallax_p95_px")
    if not p90 <= limit < p95:
        return _near_limit_note(p90, p95, limit, far)
    if treated_as_3d(views, params):
        return (f"the set was treated as 3-D: 5 % of the matches depart from one plane by "
                f"{p95:.0f} px or more (over the {far:g} px of --select-parallax-p95-px), "
                f"though the median parallax is {p90:.1f} px (3-D structure standing off "
                "the scene, such as columns before a façade, or matches on a mover): if the "
                "clean photo kept part of the mover, --select-parallax-p95-px 0 treats the "
                "set as flat")
    return (f"the set was treated as flat (median parallax {p90:.1f} px, not over the "
            f"{limit:g} px of --select-parallax-px), though 5 % of the matches depart from "
            f"one plane by {p95:.0f} px or more (3-D structure in front of the scene, or "
            "matches on a mover): if the clean photo lost static structure or kept part of "
            "the mover, --select-parallax-px 0 treats the set as 3-D")


# a median parallax within this factor of --select-parallax-px is near it: the set
# would have gone the other way had its photos been shot a little otherwise
NEAR_LIMIT = 1.25


def _near_limit_note(p90: float, p95: float, limit: float, far: float) -> str:
    """The note of a set whose median parallax ``p90`` (px) decided alone, and within
    ``NEAR_LIMIT`` of ``limit`` (``select_parallax_px``), which way it went ('' where
    it did not, or not near it; ``far``: ``select_parallax_p95_px``). A fresh-user
    trial found ``bursts/shaky_desk6`` with its last photo as the reference treated
    as 3-D at 8.2 px, and the same six phone photos flat or 3-D as they were stored
    (4.8 px or 7.3 px with 153 px far out), and nothing said so; the two ways clean
    L and decide its fill differently (README, "Fill by selection"). The note names
    the value of ``--select-parallax-px`` that takes the set the other way."""
    if not limit / NEAR_LIMIT < p90 <= limit * NEAR_LIMIT:  # (also limit 0, NaN, inf)
        return ""
    if far > 0 and p95 > far:
        return ""  # (3-D by the far matches too: the median parallax does not decide it)
    if p90 > limit:
        other = math.ceil(p90 * 2.0) / 2.0  # the next half pixel at or above it
        return (f"the set was treated as 3-D by a narrow margin: its median parallax, "
                f"{p90:.1f} px, is just over the {limit:g} px of --select-parallax-px (the "
                "photos were shot from nearly one place): if the clean photo kept part of "
                f"the mover, --select-parallax-px {other:g} treats the set as flat")
    other = math.floor(p90 * 2.0 - 1e-9) / 2.0  # the last half pixel under it
    return (f"the set was treated as flat by a narrow margin: its median parallax, "
            f"{p90:.1f} px, is just under the {limit:g} px of --select-parallax-px (3-D "
            "above it): if the clean photo lost static structure standing off the scene, "
            f"or kept part of the mover, --select-parallax-px {other:g} treats the set as 3-D")


STRAYS_NOTE = "left out, no homography with the reference"  # how _strays_note begins


def _strays_note(strays: list[tuple[str, int, int, int]], least: int) -> str:
    """The note for the sources ``_strays`` leaves out (``(name, matches, F inliers,
    homography inliers)``); ``least``: the fewest homography inliers among the
    sources kept."""
    parts = ", ".join(f"{name} ({m} keypoint match{'' if m == 1 else 'es'}, {f} on one F"
                      + (f", {h} on a homography" if h >= geometry.ALIGNED_MIN_INLIERS
                         else "") + ")"
                      for name, m, f, h in strays)
    return (f"{STRAYS_NOTE}: {parts}, where the photos "
            f"that align have {least} or more homography inliers. Another scene, "
            "mirrored, too blurred, or too little overlap?")


def _weak_reference_note(images, ref: int, srcs: list[int], views, names,
                         weak: list[int], *, ratio: float = 0.6) -> str | None:
    """A note when the reference matches its neighbours far less than they match
    their other neighbours (a reference blurred, heavily compressed or shot
    otherwise): then the few matches are the reference's doing, not the sources'.

    Checked only where matches are scarce (a source not aligned, or a median under
    ``RETRY_BELOW`` × 6 matches). On each side of the reference in the photos' order,
    the next photo j is matched with the one after it, i (``geometry.peer_matches``):
    the same step as the reference's to j. The note is given when the reference's
    matches with the js add up to under ``ratio`` times the is' (a JPEG of quality 15
    as the reference of the sanitizer burst: 72 against 178; the three bursts as
    shot, with the first, middle or last photo as the reference: no note; the 19
    DAVIS sets so: 3 notes of 57, for frames that ``--ref auto`` passes over too:
    drift-straight's and motocross-jump_s3's middle frames, with 221 and 47
    matches against 1,060 and 137 for the frames it takes, and dog's last)."""
    counts = [v.n_matches for v in views]
    if not (weak or np.median(counts) < 6 * geometry.RETRY_BELOW):
        return None
    where = {s: k for k, s in enumerate(srcs)}

    def gray(i):
        return cv2.cvtColor(np.asarray(images[i]), cv2.COLOR_BGR2GRAY)

    own = peers = 0
    pairs = []
    for step in (-1, 1):
        j, i = ref + step, ref + 2 * step
        if j in where and i in where:
            own += views[where[j]].n_matches
            peers += geometry.peer_matches(gray(i), gray(j))
            pairs.append((names[i], names[j]))
    if not pairs or peers < 2 * geometry.RETRY_BELOW or own >= ratio * peers:
        return None
    between = " and ".join(f"{a}–{b}" for a, b in pairs)
    return (f"the reference matches the photos next to it far less than they match "
            f"their other neighbours ({own} keypoint matches against {peers} for "
            f"{between}): if it is blurred, heavily compressed or shot otherwise, "
            "another reference aligns better (--ref auto takes the sharpest with the "
            "most matches)")


# the long side under which a set that aligns nowhere is said to be too small (a trial
# ran --max-side 50: 13-14 matches a photo, and the note blamed the photos)
_SMALL_PX = 320


def _few_matches_note(weak: list[tuple[str, int, int]], *, some_F: bool = False) -> str:
    """One note for every source not aligned (``geometry.aligned``; ``(name, matches,
    homography inliers)``), in the form of ``io``'s per-file notes: "a.jpg, b.jpg:
    what". ``some_F``: some of them still have an F."""
    names = [name for name, _, _ in weak]
    lo, hi = min(n for _, n, _ in weak), max(n for _, n, _ in weak)
    what = (f"only {lo}" if lo == hi else f"only {lo} to {hi}") + \
        f" keypoint match{'' if hi == 1 else 'es'}"
    if any(n >= geometry.MIN_MATCHES for _, n, _ in weak):
        # (a source with more matches than some aligned one: its matches agree on no
        # homography, which is what leaves it out)
        what += f" (fewer than {geometry.ALIGNED_MIN_INLIERS} of them on one homography)"
    one = len(weak) == 1
    tail = (f"no homography pre-warp for {'it' if one else 'them'} (an epipolar term from "
            "an F on few matches at most)" if some_F
            else f"no epipolar term and no homography pre-warp for {'it' if one else 'them'}")
    if one:
        return f"{names[0]}: {what} with the reference; {tail}"
    who = (", ".join(names) if len(names) <= 4
           else f"{len(names)} images ({names[0]}, ..., {names[-1]})")
    return f"{who}: {what} each with the reference; {tail}"


def _dist_version(name: str) -> str:
    """Installed version of a distribution, without importing it (sklearn: ~1.5 s)."""
    try:
        return version(name)
    except PackageNotFoundError:
        return "unknown"


def versions() -> dict[str, str]:
    """The versions of dynremove, its libraries and Python (report.json's, the bench's)."""
    return {"dynremove": _dist_version("dynremove"), "numpy": np.__version__,
            "opencv": cv2.__version__, "numba": numba.__version__,
            "scikit-learn": _dist_version("scikit-learn"),
            "python": platform.python_version()}

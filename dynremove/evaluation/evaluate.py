"""Evaluation on sets with ground truth (``dynremove eval``).

Layout of an evaluation set (as `dynremove eval --help` gives it)::

    <set>/frames/*            the views, sorted by name (any image format)
    <set>/masks/<stem>.png    optional: true dynamic mask of a frame (0 / 255)
    <set>/background.png      optional: the reference view without moving objects
    <set>/free.png            optional: 0/255, reference pixels some other view sees
                              free of movers (written by ``dynremove composite``)

Every folder below ``DATA_DIR`` that has a ``frames/`` sub-folder is a set; its
name is its path relative to ``DATA_DIR`` (``davis/camel``). The reference is
the middle frame unless ``--ref`` says otherwise.

Methods, run on each set with the same inputs (see :data:`METHODS`):

``dynremove``    the chosen preset (``--preset``, default ``default``) and flags
``paper``        the ``paper`` preset (the method as written)
``single-scan``  ``paper`` with ``max_scans=1, update=False`` (no N/C update)
``median``       median stack, homography alignment, global Lab threshold
``median-flow``  median stack, homography + DIS flow alignment
``telea``        OpenCV Telea inpainting of the reference given the TRUE mask
                 (no detection: its Jaccard is null)

and, only where ``--methods`` names it (:data:`DIAGNOSTICS`):

``true-fields``  ``dynremove`` whose fill samples the sources across L through
                 the TRUE background's own matches in them (``background.png``,
                 homography + DIS flow), not through the fields it estimates:
                 the whole-photo figures the fill would reach with the hidden
                 background's geometry right (an upper bound for better fields;
                 the detection, consensus and selection are the method's). Sets
                 without a background get no figures.

Figures: Jaccard of the reference's detected mask with its true mask (after
the method's own clean-up); PSNR and SSIM of the cleaned reference against
``background.png`` inside the true mask (only where both exist; PSNR is capped
at :data:`PSNR_CAP_DB` so that JSON stays finite); seconds of the method on
that set (alignment and everything, not the loading). ``null`` where a figure
does not apply.

Whole-photo figures (sets with a background; see :mod:`dynremove.evaluation.metrics`):
``psnr_whole`` / ``ssim_whole`` over the whole image; ``damage`` = percent of
all pixels, outside the true mask dilated by 5 px, that were right in the
input reference and are wrong in the output (CIE76 ΔE > 10 after a 1 px
blur); ``leftover`` = percent of the recoverable true-mask pixels (``free.png``;
the whole true mask without it) still wrong in the output; ``unrecoverable`` =
percent of the true mask that no other view saw free (``null`` without
``free.png``); ``leftover_kept`` + ``leftover_refilled`` = ``leftover``, split
into the pixels the output left as the input showed them (a missed detection)
and those it changed into something still wrong (a wrong fill)
(:func:`~dynremove.evaluation.whole_photo.leftover_split`); of the wrong fill,
``leftover_misplaced`` is the part that shows the true background shifted by at most
2 px (the right content, misplaced:
:func:`~dynremove.evaluation.whole_photo.misplaced_fill_percent`). For dynremove's
own runs the kept part is split by the step that left it
(:func:`~dynremove.evaluation.whole_photo.kept_by_step`): ``kept_missed`` (never
in the scans' map), ``kept_refinement`` (dropped by the clean-up, the votes or the
snap), ``kept_fill`` (in the map the fill started from, kept by the fill) and
``kept_replaced`` (replaced, yet alike the input); they add up to ``leftover_kept``.

Parallelism and clusters
------------------------
Sets run in parallel with :mod:`joblib` (``--jobs N``, default 1; each worker
runs OpenCV single-threaded). The work goes through :func:`joblib.Parallel`
under the ambient backend, so a cluster can be used without code changes by
wrapping :func:`run_eval` in a ``joblib.parallel_config`` block (neither Dask nor
Ray is a dependency of dynremove; install them yourself)::

    # Dask
    from dask.distributed import Client
    import joblib
    from dynremove.evaluation.evaluate import run_eval
    client = Client("tcp://scheduler:8786")          # or Client() for a local one
    with joblib.parallel_config(backend="dask"):
        report = run_eval("data/", jobs=-1)

    # Ray
    import ray, joblib
    from ray.util.joblib import register_ray
    ray.init(address="auto")
    register_ray()
    with joblib.parallel_config(backend="ray"):
        report = run_eval("data/", jobs=-1)

The data folder must be readable by the workers at the same path. Results are
identical to a local run (every method is seeded).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import cv2
import numpy as np
from joblib import Parallel, delayed

from dynremove import io
from dynremove.errors import InputError
from dynremove.evaluation import baselines
from dynremove.evaluation.metrics import jaccard, psnr_in_mask, ssim_in_mask
from dynremove.evaluation.whole_photo import (damage_percent, kept_by_step, leftover_percent,
                                              leftover_split, misplaced_fill_percent,
                                              own_mover_fill_percent, psnr, ssim)
from dynremove.params import Params, preset
from dynremove.pipeline import Result, remove_dynamic
from dynremove.refine.concurrency import one_thread_per_worker, quiet_worker_restarts

METHODS = ("dynremove", "paper", "median", "median-flow", "telea", "single-scan")
#: Methods run only when ``--methods`` names them (not part of the default list).
DIAGNOSTICS = ("true-fields",)
#: What the table and the JSON (``diagnostics``) say the ``true-fields`` column is.
TRUE_FIELDS_LEGEND = (
    "true-fields is a diagnostic, not a method: the dynremove run (same preset and "
    "flags) whose fill samples the other photos across the mask through the true "
    "background's own matches in them (background.png; '-' without one); against "
    "dynremove it shows what better fields could take off the wrong fill")
PSNR_CAP_DB = 100.0  # an exact match would be +inf; JSON has no infinity
#: Figures of a row (``null`` where they do not apply).
SCORE_KEYS = ("jaccard", "psnr", "ssim", "psnr_whole", "ssim_whole", "damage", "leftover",
              "leftover_kept", "leftover_refilled", "leftover_misplaced", "kept_missed",
              "kept_refinement", "kept_fill", "kept_replaced", "unrecoverable", "own_mover")

# Variants of the base preset for ``--ablation`` (field -> value). A variant whose
# fields are not all Params fields, or whose values Params rejects, is skipped with
# a note; one identical to the base is skipped too (it would repeat "full").
ABLATIONS: dict[str, dict[str, Any]] = {
    # each removes (or swaps) one step of the default preset
    "ungated-flow": {"correspondence": "homography+flow"},  # the paper's N
    "corr-homography": {"correspondence": "homography"},
    "corr-flow": {"correspondence": "flow"},
    "four-scans": {"max_scans": 4},  # the paper's alternating scans
    "no-update": {"update": False},
    "no-epipolar": {"use_epipolar": False},
    "no-hog": {"use_hog": False},
    "pixel-write": {"write": "pixel"},
    "p9": {"patch_size": 9},
    "t_r-0.4": {"t_r": 0.4},
    "no-clean": {"clean_mask": False, "min_region_px": 0},
    "no-refine": {"refine_tau": 0.0},
    "refine-shrink-0.8": {"refine_shrink_frac": 0.8},  # the default until session 58
    "no-snap": {"snap": False},
    "no-realign": {"fuse_realign": 0},
    "fuse-medoid": {"fuse_combine": "medoid", "fuse_realign": 0},
    "no-fuse": {"fuse": False},
}


# --------------------------------------------------------------------------- sets
@dataclass(frozen=True)
class EvalSet:
    """One set on disk (nothing is read until :func:`load_set`)."""

    name: str
    path: Path
    frames: tuple[Path, ...]

    @property
    def masks_dir(self) -> Path:
        return self.path / "masks"

    @property
    def background(self) -> Path | None:
        p = self.path / "background.png"
        return p if p.is_file() else None

    @property
    def free(self) -> Path | None:
        p = self.path / "free.png"
        return p if p.is_file() else None

    def mask_path(self, frame: Path) -> Path | None:
        p = self.masks_dir / (frame.stem + ".png")
        return p if p.is_file() else None


def image_files(folder: Path) -> list[Path]:
    """The image files of a folder, sorted; hidden files skipped.

    The rule of ``run`` and ``batch`` (:func:`dynremove.io.list_inputs`): a file is
    an image when its suffix is a common image suffix or when OpenCV or Pillow
    recognise its content (AVIF, HEIC with the extra, no or odd suffix, ...).
    """
    files = sorted((q for q in folder.iterdir() if q.is_file() and not q.name.startswith(".")),
                   key=io.natural_key)
    return [q for q in files if q.suffix.lower() in io.IMAGE_EXTS or io.is_image_file(q)]


def _frames_folders(root: Path) -> list[Path]:
    """Every folder named ``frames`` below ``root`` (itself included), sorted; folders
    reached through symbolic links are searched too, as ``batch`` does (a fresh-user
    trial's folder of links to DAVIS sets read as "no set": ``Path.rglob`` does not
    follow them), each real folder once (a link to an ancestor ends there)."""
    out, seen = [], set()
    for dirpath, dirnames, _ in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames.sort()
        if "frames" in dirnames:
            out.append(Path(dirpath) / "frames")
    return sorted(out)


def _patterns(pattern: str | Sequence[str] | None) -> list[str]:
    """``--sets``' globs: comma-separated, or a list of such strings."""
    pats: list[str] = []
    if pattern:
        for p in ([pattern] if isinstance(pattern, str) else pattern):
            pats.extend(s.strip() for s in p.split(",") if s.strip())
    return pats


def _matches(name: str, pat: str) -> bool:
    """Whether the set ``name`` (``davis/camel``) or its last part matches ``pat``."""
    return fnmatch.fnmatch(name, pat) or fnmatch.fnmatch(name.rpartition("/")[2], pat)


def unmatched_patterns(found: Sequence[EvalSet], pattern: str | Sequence[str] | None
                       ) -> list[str]:
    """The globs of ``pattern`` that match none of ``found`` (a trial's typo in
    ``--sets camel,camle`` was dropped without a word)."""
    return [p for p in _patterns(pattern) if not any(_matches(s.name, p) for s in found)]


def find_sets(data_dir: str | Path, pattern: str | Sequence[str] | None = None) -> list[EvalSet]:
    """Every ``<set>/frames/`` folder below ``data_dir`` (itself included), sorted by name.

    ``pattern``: shell glob(s) (comma-separated or a list) matched against the set
    name (``davis/camel``) or its last part (``camel``). Sets with fewer than 2
    frames are ignored.
    """
    root = Path(data_dir)
    io.require_folder(root)
    pats = _patterns(pattern)
    found = []
    for fr in _frames_folders(root):
        set_dir = fr.parent
        name = set_dir.relative_to(root).as_posix() if set_dir != root else root.name
        if pats and not any(_matches(name, p) for p in pats):
            continue
        frames = image_files(fr)
        if len(frames) >= 2:
            found.append(EvalSet(name=name, path=set_dir, frames=tuple(frames)))
    return sorted(found, key=lambda s: s.name)


@dataclass
class LoadedSet:
    name: str
    images: list[np.ndarray]
    names: list[str]
    ref: int
    gt: np.ndarray | None  # (H, W) bool, true mask of the reference
    background: np.ndarray | None  # (H, W, 3) uint8, true clean reference
    scale: float
    notes: list[str]
    free: np.ndarray | None = None  # (H, W) bool: ref pixels some other view sees free
    # (H, W) bool true mask of every image (None where an image has none)
    masks: list[np.ndarray | None] | None = None


def load_set(es: EvalSet, *, max_side: int | None = None, ref: str | int | None = None
             ) -> LoadedSet:
    """Read the frames (downscaled as ``io.load_image_set``), the ref mask and background."""
    iset = io.load_image_set(list(es.frames), max_side=max_side)
    if isinstance(ref, str) and ref.strip().lower() == "auto":
        from dynremove.video import auto_reference

        r, _, _ = auto_reference(iset.images, iset.names)
    else:
        r = io.resolve_ref(ref, iset.names, numbers=False)
    H, W = iset.images[0].shape[:2]
    # the truth files must have the frames' own size (as ``run --gt`` requires): one of
    # another size or shape is another set's, and was resized into place and scored
    # (a fresh-user trial: camel's masks at 300x500 scored J 0.316, with no word)
    native = tuple(iset.original_size)
    masks: list[np.ndarray | None] = []
    for f in es.frames:
        mp = es.mask_path(f)
        masks.append(io.read_mask(mp, (W, H), native=native) if mp is not None else None)
    gt = masks[r]
    bg = None
    if es.background is not None:
        bg, _ = io.read_image(es.background)
        io.require_size(es.background, (bg.shape[1], bg.shape[0]), native)
        if bg.shape[:2] != (H, W):
            interp = cv2.INTER_AREA if bg.shape[1] > W else cv2.INTER_LINEAR
            bg = cv2.resize(bg, (W, H), interpolation=interp)
    free = None
    if es.free is not None:
        free = io.read_mask(es.free, (W, H), native=native)
    return LoadedSet(name=es.name, images=iset.images, names=iset.names, ref=r, gt=gt,
                     background=bg, scale=iset.scale, notes=list(iset.notes), free=free,
                     masks=masks)


# --------------------------------------------------------------------------- methods
def _finite(x: float | None, cap: float = PSNR_CAP_DB) -> float | None:
    if x is None:
        return None
    if math.isnan(x):
        return None
    return float(min(x, cap))


def score(ls: LoadedSet, clean: np.ndarray | None, dynamic: np.ndarray | None,
          result: Result | None = None) -> dict[str, float | None]:
    """Every figure of :data:`SCORE_KEYS` that applies (the others None).

    Jaccard if a detection and a true mask exist; PSNR/SSIM in the true mask;
    whole-image PSNR/SSIM with a background; damage / leftover / unrecoverable
    with a background and a true mask (``free.png`` for the recoverable part);
    own_mover (:func:`own_mover_fill`) for a run's ``result`` whose sources
    have true masks.
    """
    out: dict[str, float | None] = dict.fromkeys(SCORE_KEYS)
    if result is not None:
        out["own_mover"] = own_mover_fill(ls, result)
    if dynamic is not None and ls.gt is not None:
        out["jaccard"] = float(jaccard(dynamic, ls.gt))
    if clean is None or ls.background is None:
        return out
    out["psnr_whole"] = _finite(psnr(clean, ls.background))
    out["ssim_whole"] = float(ssim(clean, ls.background))
    if ls.gt is not None and ls.gt.any():
        out["psnr"] = _finite(psnr_in_mask(clean, ls.background, ls.gt))
        out["ssim"] = float(ssim_in_mask(clean, ls.background, ls.gt))
    if ls.gt is not None and clean.ndim == 3 and clean.shape[2] == 3:
        out["damage"] = float(damage_percent(ls.images[ls.ref], clean, ls.background, ls.gt))
        left, unrec = leftover_percent(clean, ls.background, ls.gt, ls.free)
        out["leftover"], out["unrecoverable"] = left, unrec
        out["leftover_kept"], out["leftover_refilled"] = leftover_split(
            clean, ls.images[ls.ref], ls.background, ls.gt, ls.free)
        out["leftover_misplaced"] = misplaced_fill_percent(
            clean, ls.images[ls.ref], ls.background, ls.gt, ls.free)
        if result is not None and result.stages and out["leftover_kept"] is not None:
            split = kept_by_step(clean, ls.images[ls.ref], ls.background, ls.gt, ls.free,
                                 **_steps(result))
            out.update({f"kept_{k}": v for k, v in split.items()})
    return out


def _steps(result: Result) -> dict[str, np.ndarray]:
    """A dynremove run's maps for ``kept_by_step``: the scans' map, the map its fill
    started from (the stage before "select"; the final map without a fill by
    selection) and the pixels it replaced (its final map)."""
    names = list(result.stages)
    fill_input = (result.stages[names[names.index("select") - 1]] if "select" in names
                  else result.dynamic)
    return dict(scanned=result.dynamic_raw, fill_input=fill_input, replaced=result.dynamic)


def own_mover_fill(ls: LoadedSet, result: Result) -> float | None:
    """Percent of the pixels the fill by selection replaced whose fill came mostly
    from the sources' own true movers (``whole_photo.own_mover_fill_percent``);
    None without a fill by selection, or where a source used has no true mask."""
    sel = result.selection
    if sel is None or not len(sel.fields) or sel.members is None or ls.masks is None:
        return None
    return own_mover_fill_percent(sel.replaced, sel.members, np.stack(sel.fields),
                                  [ls.masks[i] for i in result.source_indices])


def run_method(method: str, ls: LoadedSet, params: Any | None = None, *,
               detail: dict | None = None, label: str | None = None
               ) -> tuple[np.ndarray | None, np.ndarray | None, list[str]]:
    """Run one method on a loaded set: (clean, dynamic, notes); None = not applicable.

    With ``detail`` (a dict), the pipeline's :class:`Result` is stored under
    ``"result"``. Each note starts with ``label`` (default ``method``): the method's
    name in the table (a preset or variant run as ``"pipeline"``)."""
    notes: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if method in ("median", "median-flow"):
            align = "homography" if method == "median" else "homography+flow"
            clean, dyn = baselines.median_baseline(ls.images, ls.ref, align=align)
        elif method == "true-fields":
            if ls.background is None:
                clean, dyn = None, None
                notes.append("true-fields: no background.png")
            else:
                res = remove_dynamic(ls.images, ref=ls.ref, params=params, names=ls.names,
                                     true_background=ls.background)
                clean, dyn = res.clean, res.dynamic
                if detail is not None:
                    detail["result"] = res
        elif method == "telea":
            if ls.gt is None:
                clean, dyn = None, None
                notes.append("telea: no true mask of the reference")
            else:
                clean, dyn = baselines.telea_inpaint(ls.images[ls.ref], ls.gt), None
        else:
            if params is None:
                raise ValueError(f"method {method!r} needs params")
            res = remove_dynamic(ls.images, ref=ls.ref, params=params, names=ls.names)
            clean, dyn = res.clean, res.dynamic
            if detail is not None:
                detail["result"] = res
    seen = set()
    for w in caught:
        msg = f"{label or method}: {w.message}"
        if msg not in seen:
            seen.add(msg)
            notes.append(msg)
    return clean, dyn, notes


def _params_dict(p: Any) -> dict:
    return dataclasses.asdict(p)


def _make_params(d: dict) -> Any:
    return Params(**d)


def method_params(method: str, chosen: Any) -> Any | None:
    """Params of a pipeline method (``dynremove`` and ``true-fields`` = ``chosen``); None
    for baselines."""
    if method in ("dynremove", "true-fields"):
        return chosen
    if method == "paper":
        return preset("paper")
    if method == "single-scan":
        return preset("paper").replace(max_scans=1, update=False)
    return None


_WARM: set[tuple] = set()  # the params (as sorted items) already warmed up in this process


def warm_up(pd: dict) -> float:
    """Run the pipeline with the params dict ``pd`` once on a 96×64 synthetic set,
    so that its compiled kernels are built (a fresh install: 30-60 s, numba) or
    loaded from numba's cache (a new process: about a second) before a timed run.
    Once per process and params; returns the seconds it took (0.0 when done before)."""
    key = tuple(sorted(pd.items()))
    if key in _WARM:
        return 0.0
    from dynremove.evaluation.synth import make_scene

    t = time.perf_counter()
    scene = make_scene(seed=0, n_views=3, size=(64, 96), n_objects=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 96x64 set has few keypoints
        remove_dynamic(scene.images, ref=scene.ref_index, params=_make_params(pd))
    _WARM.add(key)
    return time.perf_counter() - t


def eval_set(es: EvalSet, variants: Sequence[tuple[str, dict | None]], *,
             max_side: int | None = None, ref: str | int | None = None,
             single_thread: bool = False) -> dict:
    """Run every (method, params-dict) on one set; the unit of parallel work.

    The pipeline's kernels are first built or loaded (:func:`warm_up`), outside
    the seconds recorded per method.

    Returns ``{"set", "rows": [...], "info": {...}, "seconds": wall}``. A method
    that raises is recorded with null figures and an ``error`` string, so one
    failing set does not lose the others.
    """
    if single_thread:
        one_thread_per_worker()  # in a worker: parallelism comes from joblib
    t_set = time.perf_counter()
    try:
        ls = load_set(es, max_side=max_side, ref=ref)
    except Exception as e:  # noqa: BLE001 - a set that cannot be read: recorded, as
        # a failing method is, and the others go on (a trial lost a 19-set run to one
        # truncated frame)
        msg = " ".join(str(e).split()) if isinstance(e, InputError) else \
            f"{type(e).__name__}: {e}"
        rows = [{"set": es.name, "method": m, **dict.fromkeys(SCORE_KEYS), "seconds": None,
                 "error": msg} for m, _ in variants]
        return {"set": es.name, "rows": rows,
                "info": {"set": es.name, "error": msg, "notes": [msg]},
                "seconds": time.perf_counter() - t_set}
    rows, notes = [], list(ls.notes)
    if ls.gt is None and ls.background is None:
        # nothing to score against: the methods are not run (a trial's eval of the
        # bursts spent 17 s on a set it then left blank)
        rows = [{"set": es.name, "method": m, **dict.fromkeys(SCORE_KEYS), "seconds": None}
                for m, _ in variants]
        variants = []
    # the kernels compiled or loaded outside the methods' seconds (the first set of
    # a fresh install reported 68 s against 9.5 s on a rerun)
    for _, pd in variants:
        if pd is not None:
            warm_up(pd)
    done: dict[Any, tuple] = {}  # identical params run once
    for method, pd in variants:
        # (the pipeline's presets run as "pipeline", and identical ones once; a
        # diagnostic with the same params is another run)
        base = "pipeline" if pd is not None and method not in DIAGNOSTICS else method
        key = (base, tuple(sorted(pd.items())) if pd else None)
        row: dict[str, Any] = {"set": es.name, "method": method}
        try:
            if key in done:
                clean, dyn, secs, res = done[key]
            else:
                t = time.perf_counter()
                params = _make_params(pd) if pd is not None else None
                detail: dict = {}
                clean, dyn, n = run_method(base, ls, params, detail=detail, label=method)
                secs = time.perf_counter() - t
                # each note once, under the method that gave it (a trial found the same
                # note three times, and the paper preset's "stopped at --max-scans 4"
                # unattributed beside the default's)
                notes.extend(x for x in n if x not in notes)
                res = detail.get("result")
                done[key] = (clean, dyn, secs, res)
            row.update(score(ls, clean, dyn, res))
            row["seconds"] = round(secs, 3) if (clean is not None or dyn is not None) else None
        except Exception as e:  # noqa: BLE001 - recorded, the run goes on
            row.update(dict.fromkeys(SCORE_KEYS))
            row.update({"seconds": None, "error": f"{type(e).__name__}: {e}"})
        rows.append(row)
    H, W = ls.images[0].shape[:2]
    info = {"set": es.name, "n_images": len(ls.images), "ref": ls.names[ls.ref],
            "size": [W, H], "scale": round(ls.scale, 4), "has_mask": ls.gt is not None,
            "has_background": ls.background is not None, "has_free": ls.free is not None,
            "mask_fraction": float(ls.gt.mean()) if ls.gt is not None else None,
            "notes": notes}
    return {"set": es.name, "rows": rows, "info": info,
            "seconds": time.perf_counter() - t_set}


def _run_parallel(sets: Sequence[EvalSet], variants: Sequence[tuple[str, dict | None]], *,
                  jobs: int, max_side: int | None, ref: str | int | None,
                  on_done: Callable[[int, int, dict], None] | None = None) -> list[dict]:
    results: dict[str, dict] = {}
    tasks = (delayed(eval_set)(es, variants, max_side=max_side, ref=ref, single_thread=True)
             for es in sets)
    if jobs == 1:
        gen: Iterable[dict] = (eval_set(es, variants, max_side=max_side, ref=ref)
                               for es in sets)
    else:
        quiet_worker_restarts()
        gen = Parallel(n_jobs=jobs, return_as="generator_unordered")(tasks)
    try:
        for k, res in enumerate(gen, 1):
            results[res["set"]] = res
            if on_done:
                on_done(k, len(sets), res)
    except BaseException as e:
        # the sets already scored, in the sets' order, for the caller to keep (a
        # Ctrl-C threw away every finished set: a trial's two of six)
        e.partial_results = [results[es.name] for es in sets if es.name in results]
        raise
    return [results[es.name] for es in sets]


def _stderr_progress(k: int, n: int, res: dict) -> None:
    js = [f"{r['method']} {r['jaccard']:.3f}" for r in res["rows"]
          if r.get("jaccard") is not None][:2]
    err = sum(1 for r in res["rows"] if "error" in r)
    info = res.get("info", {})
    if "error" in info:
        print(f"[{k}/{n}] {res['set']}: not run: {info['error']}", file=sys.stderr, flush=True)
        return
    unscored = not (info.get("has_mask", True) or info.get("has_background", True))
    print(f"[{k}/{n}] {res['set']}: {res['seconds']:.1f} s"
          + (f", reference {info['ref']}" if info.get("ref") else "")
          + (f"  (J {', '.join(js)})" if js else "")
          + ("  (no masks/<reference>.png and no background.png: nothing to score, not "
             "run; '-' in the table)" if unscored else "")
          + (f"  {_count(err, 'method')} failed" if err else ""), file=sys.stderr,
          flush=True)


def _mean(vals: Iterable[float | None]) -> float | None:
    v = [x for x in vals if x is not None]
    return float(np.mean(v)) if v else None


def summarize(rows: Sequence[dict], methods: Sequence[str]) -> dict[str, dict]:
    """Per method: mean of every figure (:data:`SCORE_KEYS`) and seconds over the sets
    where defined, with ``n_<figure>`` counts for jaccard, psnr and the whole-photo ones."""
    out = {}
    for m in methods:
        rs = [r for r in rows if r["method"] == m]
        out[m] = {k: _mean(r.get(k) for r in rs) for k in SCORE_KEYS + ("seconds",)}
        for k in ("jaccard", "psnr", "psnr_whole", "damage", "leftover"):
            out[m][f"n_{k}"] = sum(r.get(k) is not None for r in rs)
    return out


def _check_ref_fits_some(ref: str | int | None, found: Sequence[EvalSet]) -> None:
    """InputError, once, for a ``ref`` that ``io.resolve_ref`` finds out of range in
    every set (a trial's ``--ref 99`` was an error row, a progress line and an error
    line per set). A name that some set lacks stays that set's error."""
    if ref is None or str(ref).strip().lower() == "auto":
        return
    errors = []
    for es in found:
        try:
            io.resolve_ref(ref, [Path(f).name for f in es.frames], numbers=False)
            return
        except InputError as e:
            errors.append(str(e))
    if all("out of range" in e for e in errors):
        n = max(len(es.frames) for es in found)
        raise InputError(f"--ref {ref}: out of range in every set (the largest has {n} "
                         f"frames: 0..{n - 1})")


def _check_patterns(found: Sequence[EvalSet], sets: str | None, data_dir: str | Path) -> None:
    """An ``InputError`` naming the ``--sets`` globs that match no set found, and the
    sets there are."""
    missed = unmatched_patterns(found, sets)
    if missed:
        every = [x.name for x in find_sets(data_dir)]
        raise InputError(f"--sets: {', '.join(repr(p) for p in missed)} "
                         f"match{'es' if len(missed) == 1 else ''} no set (the sets below "
                         f"{data_dir}: {', '.join(every[:12])}"
                         f"{f' and {len(every) - 12} more' if len(every) > 12 else ''})")


def run_eval(data_dir: str | Path, *, sets: str | None = None, params: Any | None = None,
             preset_name: str = "default", methods: Sequence[str] = METHODS,
             jobs: int = 1, max_side: int | None = None, ref: str | int | None = None,
             progress: bool = True) -> dict:
    """Evaluate ``methods`` on every set below ``data_dir``; returns the JSON report."""
    bad = [m for m in methods if m not in METHODS + DIAGNOSTICS]
    if bad:
        raise InputError(f"unknown method(s) {', '.join(bad)}; choose from "
                         f"{', '.join(METHODS + DIAGNOSTICS)}")
    chosen = preset(preset_name) if params is None else params
    found = find_sets(data_dir, sets)
    if not found:
        raise InputError(f"{data_dir}: no set with a frames/ folder"
                         + (f" matching {sets!r}" if sets else ""))
    _check_patterns(found, sets, data_dir)
    _check_ref_fits_some(ref, found)
    variants = []
    for m in methods:
        p = method_params(m, chosen)
        variants.append((m, _params_dict(p) if p is not None else None))
    t0 = time.perf_counter()
    if jobs != 1:  # compiled here once, so that the workers load numba's cache
        for _, pd in variants:
            if pd is not None:
                warm_up(pd)
    try:
        results = _run_parallel(found, variants, jobs=jobs, max_side=max_side, ref=ref,
                                on_done=_stderr_progress if progress else None)
    except BaseException as e:
        done = getattr(e, "partial_results", None)
        if done:  # what was scored before the interruption, as a report of those sets
            e.partial_report = {**_eval_report(done, methods, variants, t0, jobs, max_side,
                                               preset_name, chosen),
                                "interrupted": True, "n_sets_found": len(found)}
        raise
    return _eval_report(results, methods, variants, t0, jobs, max_side, preset_name, chosen)


def _eval_report(results: list[dict], methods: Sequence[str], variants: list, t0: float,
                 jobs: int, max_side: int | None, preset_name: str, chosen: Any) -> dict:
    """``run_eval``'s JSON report of the sets scored (``results``, in order)."""
    rows = [r for res in results for r in res["rows"]]
    return {
        "sets": rows,
        "summary": summarize(rows, list(methods)),
        "set_info": [res["info"] for res in results],
        "methods": list(methods),
        "wall_s": round(time.perf_counter() - t0, 2),
        "jobs": jobs,
        "max_side": max_side,
        "preset": preset_name,
        "params": _params_dict(chosen),
        "method_params": {m: pd for m, pd in variants if pd is not None},
        **({"diagnostics": {"true-fields": TRUE_FIELDS_LEGEND}}
           if "true-fields" in methods else {}),
    }


# --------------------------------------------------------------------------- ablation
def ablation_variants(base: Any, names: Sequence[str] | None = None
                      ) -> tuple[list[tuple[str, dict, dict]], list[str]]:
    """``[("full", {}, params), (name, changes, params), ...]`` and skip notes.

    Variants are ``dataclasses.replace(base, **changes)``; robust to Params
    changing: unknown fields or rejected values skip the variant.
    """
    fields = {f.name for f in dataclasses.fields(Params)}
    if names:
        unknown = [n for n in names if n not in ABLATIONS]
        if unknown:
            raise InputError(f"unknown ablation(s) {', '.join(unknown)}; "
                             f"choose from {', '.join(ABLATIONS)}")
    chosen = list(names) if names else list(ABLATIONS)
    base_d = _params_dict(base)
    out = [("full", {}, base_d)]
    notes = []
    for n in chosen:
        ch = ABLATIONS[n]
        missing = sorted(set(ch) - fields)
        if missing:
            notes.append(f"{n}: skipped (no Params field {', '.join(missing)})")
            continue
        try:
            p = dataclasses.replace(base, **ch)
        except (TypeError, ValueError) as e:
            notes.append(f"{n}: skipped ({e})")
            continue
        d = _params_dict(p)
        if d == base_d:
            notes.append(f"{n}: skipped (same as the base preset)")
            continue
        out.append((n, dict(ch), d))
    return out, notes


def run_ablation(data_dir: str | Path, *, base: Any, names: Sequence[str] | None = None,
                 sets: str | None = None, jobs: int = 1, max_side: int | None = None,
                 ref: str | int | None = None, progress: bool = True,
                 preset_name: str = "default") -> dict:
    """Every ablation variant of ``base`` on every set: rows and per-variant means."""
    variants, notes = ablation_variants(base, names)
    found = find_sets(data_dir, sets)
    if not found:
        raise InputError(f"{data_dir}: no set with a frames/ folder"
                         + (f" matching {sets!r}" if sets else ""))
    _check_patterns(found, sets, data_dir)
    t0 = time.perf_counter()
    results = _run_parallel(found, [(n, d) for n, _, d in variants], jobs=jobs,
                            max_side=max_side, ref=ref,
                            on_done=_stderr_progress if progress else None)
    rows = [r for res in results for r in res["rows"]]
    summ = summarize(rows, [n for n, _, _ in variants])
    table = [{"variant": n, "changes": ch, "mean_jaccard": summ[n]["jaccard"],
              "mean_psnr": summ[n]["psnr"], "mean_ssim": summ[n]["ssim"],
              "mean_psnr_whole": summ[n]["psnr_whole"], "mean_damage": summ[n]["damage"],
              "mean_leftover": summ[n]["leftover"],
              "mean_leftover_kept": summ[n]["leftover_kept"],
              "mean_leftover_refilled": summ[n]["leftover_refilled"],
              "mean_leftover_misplaced": summ[n]["leftover_misplaced"],
              "mean_seconds": summ[n]["seconds"], "n_sets": summ[n]["n_jaccard"]}
             for n, ch, _ in variants]
    return {"ablation": table, "sets": rows, "set_info": [res["info"] for res in results],
            "skipped": notes, "wall_s": round(time.perf_counter() - t0, 2), "jobs": jobs,
            "max_side": max_side, "preset": preset_name, "params": _params_dict(base)}


# --------------------------------------------------------------------------- tables
def _count(n: int, word: str) -> str:
    """``"1 set"``, ``"2 sets"``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def _fmt(x: float | None, spec: str) -> str:
    """``format(x, spec)``, or "-" (padded to the spec's width: "4.1f" gives "   -")."""
    if x is None:
        width = spec.split(".")[0]
        return "-".rjust(int(width) if width.isdigit() else 1)
    return format(x, spec)


def _render(table: list[list[str]], n_body: int, n_left: int = 1) -> list[str]:
    """Aligned lines: header, rule, ``n_body`` rows, rule, the rest (means)."""
    widths = [max(len(r[i]) for r in table) for i in range(len(table[0]))]
    lines = []
    for k, r in enumerate(table):
        if k == 1 or k == n_body + 1:
            lines.append("  ".join("-" * w for w in widths))
        lines.append("  ".join(c.ljust(w) if i < n_left else c.rjust(w)
                               for i, (c, w) in enumerate(zip(r, widths))).rstrip())
    return lines


def format_table(report: dict) -> str:
    """Sets as rows, methods as columns: ``J`` (and ``J/PSNR/SSIM`` in the true mask
    where a background exists), then the means per method. Sets with a background
    get a second table, "whole photo": per method ``PSNR SSIM dmg% left%`` over the
    whole image, the set's ``unrec%`` (true-mask pixels no other view saw free), and
    the means (``mean unrec %`` on a row of its own)."""
    methods = report["methods"]
    rows = report["sets"]
    info = {i["set"]: i for i in report.get("set_info", [])}
    by = {(r["set"], r["method"]): r for r in rows}
    set_names = list(dict.fromkeys(r["set"] for r in rows))
    any_bg = any(i.get("has_background") for i in info.values())

    def cell(r: dict | None, bg: bool) -> str:
        if r is None:
            return "-"
        if "error" in r:
            return "error"
        s = _fmt(r.get("jaccard"), "5.3f")
        if bg:
            s += f" {_fmt(r.get('psnr'), '4.1f')} {_fmt(r.get('ssim'), '5.3f')}"
        return s

    table = [["set"] + list(methods)]
    for s in set_names:
        bg = bool(info.get(s, {}).get("has_background"))
        table.append([s] + [cell(by.get((s, m)), bg) for m in methods])
    summ = report.get("summary") or summarize(rows, methods)
    n_sets = max((summ[m].get("n_jaccard", 0) for m in methods), default=0)  # scored
    table.append([f"mean J ({_count(n_sets, 'set')})"]
                 + [_fmt(summ[m]["jaccard"], ".3f") for m in methods])
    if any(summ[m]["own_mover"] is not None for m in methods):
        # (the fill by selection, on sets whose every frame has a true mask)
        table.append(["mean own-mover fill %"]
                     + [_fmt(summ[m]["own_mover"], ".1f") for m in methods])
    if any_bg:
        table.append(["mean PSNR dB (in mask)"] + [_fmt(summ[m]["psnr"], ".2f") for m in methods])
        table.append(["mean SSIM (in mask)"] + [_fmt(summ[m]["ssim"], ".3f") for m in methods])
    table.append(["mean seconds"] + [_fmt(summ[m]["seconds"], ".1f") for m in methods])
    head = "cells: Jaccard" + (" | sets with a background: Jaccard PSNR(dB) SSIM in the true "
                               "mask" if any_bg else "")
    if report.get("max_side"):  # (run and batch score at the size they write)
        head += (f"\n  scored at the analysis size (--max-side {report['max_side']}): the true "
                 "masks are resized to it")
    if any(summ[m]["own_mover"] is not None for m in methods):
        head += ("\n  own-mover fill %: of the pixels the fill replaced, those taken mostly "
                 "from the other photos' own true movers (ghosts); the mean row here, "
                 "each set's in --json (own_mover)")
    if "telea" in methods:  # (a trial read its column of '-' as a failure)
        head += ("\n  telea is given the true mask: it has no Jaccard ('-'); it scores "
                 "only the fill, where a background is known")
    if "true-fields" in methods:  # (a trial found nothing in the table saying what it is)
        head += ("\n  " + TRUE_FIELDS_LEGEND)
    out = [head] + _render(table, len(set_names))
    if any_bg:
        out += [""] + _format_whole(report, methods, by, info, set_names)
    return "\n".join(out)


def _format_whole(report: dict, methods: Sequence[str], by: dict, info: dict,
                  set_names: Sequence[str]) -> list[str]:
    """The "whole photo" table of :func:`format_table` (sets with a background)."""
    bg_sets = [s for s in set_names if info.get(s, {}).get("has_background")]

    def cell(r: dict | None) -> str:
        if r is None:
            return "-"
        if "error" in r:
            return "error"
        # (each figure at a fixed width, so that the columns line up within the cells)
        return (f"{_fmt(r.get('psnr_whole'), '4.1f')} {_fmt(r.get('ssim_whole'), '5.3f')} "
                f"{_fmt(r.get('damage'), '5.2f')} {_fmt(r.get('leftover'), '5.1f')}")

    def unrec(s: str) -> float | None:
        vals = [by[(s, m)].get("unrecoverable") for m in methods if (s, m) in by]
        return next((v for v in vals if v is not None), None)

    table = [["set", "unrec%"] + list(methods)]
    for s in bg_sets:
        table.append([s, _fmt(unrec(s), ".1f")] + [cell(by.get((s, m))) for m in methods])
    bg_rows = [r for r in report["sets"] if r["set"] in set(bg_sets)]
    summ = summarize(bg_rows, methods)
    mean_unrec = _mean(unrec(s) for s in bg_sets)
    n = len(bg_sets)
    table.append([f"mean PSNR dB ({_count(n, 'set')})", ""]
                 + [_fmt(summ[m]["psnr_whole"], ".2f") for m in methods])
    table.append(["mean SSIM", ""] + [_fmt(summ[m]["ssim_whole"], ".3f") for m in methods])
    table.append(["mean damage %", ""] + [_fmt(summ[m]["damage"], ".2f") for m in methods])
    table.append(["mean leftover %", ""] + [_fmt(summ[m]["leftover"], ".1f") for m in methods])
    table.append(["  kept as input %", ""]
                 + [_fmt(summ[m]["leftover_kept"], ".1f") for m in methods])
    for key, label in (("kept_missed", "never detected"),
                       ("kept_refinement", "dropped after scans"),
                       ("kept_fill", "kept by the fill"), ("kept_replaced", "replaced, alike")):
        if any(summ[m][key] is not None for m in methods):
            table.append([f"    {label} %", ""] + [_fmt(summ[m][key], ".1f") for m in methods])
    table.append(["  refilled wrong %", ""]
                 + [_fmt(summ[m]["leftover_refilled"], ".1f") for m in methods])
    table.append(["    of it misplaced %", ""]
                 + [_fmt(summ[m]["leftover_misplaced"], ".1f") for m in methods])
    # the only figure of the unrec% column: a row of its own, the methods' cells blank
    table.append(["mean unrec %", _fmt(mean_unrec, ".1f")] + [""] * len(methods))
    head = ["whole photo, cells: PSNR(dB) SSIM damage% leftover%",
            "  damage%: of all pixels, outside the true mask + 5 px: right in the input, "
            "wrong in the output (CIE76 dE > 10, 1 px blur)",
            "  leftover%: of the recoverable true mask, still wrong (kept as input: the "
            "output still shows the input there; refilled wrong: changed, still wrong; "
            "of it misplaced: the true background shifted up to 2 px on each axis matches "
            "it; kept + refilled = leftover, all of the same recoverable true mask)",
            "  kept as input, by the step that left it (dynremove's runs): never in the "
            "scans' map; in it but dropped after (clean-up, votes, snap); in the map the "
            "fill started from, kept by the fill; replaced, but alike the input",
            "  unrec%: of the true mask, seen free by no other view"]
    return head + _render(table, len(bg_sets), n_left=1)


def format_ablation(report: dict) -> str:
    """The ablation's table: per variant, the mean J and in-mask PSNR, and, where the
    sets have a true background (composites), the whole-photo measures the normal
    table gives (a fresh-user trial: with J and the in-mask PSNR alone, a variant
    that tripled the damage read as the better one)."""
    whole = any(a.get("mean_damage") is not None for a in report["ablation"])
    head = ["variant", "changes", "mean J", "PSNR in mask dB"]
    if whole:
        head += ["damage %", "leftover %", "PSNR whole dB"]
    table = [head + ["mean s", "sets"]]
    for a in report["ablation"]:
        ch = ", ".join(f"{k}={v}" for k, v in a["changes"].items()) or "(base)"
        row = [a["variant"], ch, _fmt(a["mean_jaccard"], ".3f"), _fmt(a["mean_psnr"], ".2f")]
        if whole:
            row += [_fmt(a.get("mean_damage"), ".2f"), _fmt(a.get("mean_leftover"), ".1f"),
                    _fmt(a.get("mean_psnr_whole"), ".2f")]
        table.append(row + [_fmt(a["mean_seconds"], ".1f"), str(a["n_sets"])])
    widths = [max(len(r[i]) for r in table) for i in range(len(table[0]))]
    lines = ["  ".join(c.ljust(w) if i < 2 else c.rjust(w)
                       for i, (c, w) in enumerate(zip(r, widths))) for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    legend = ("higher J and PSNR are better; lower damage % (of all pixels: right in the "
              "input, wrong in the output) and leftover % (of the true mask) are better"
              if whole else "higher J and PSNR are better")
    return "\n".join(lines + [legend] + [f"note: {n}" for n in report.get("skipped", [])])


__all__ = ["METHODS", "DIAGNOSTICS", "ABLATIONS", "SCORE_KEYS", "EvalSet", "LoadedSet",
           "find_sets", "load_set", "score", "run_method", "eval_set", "run_eval", "run_ablation",
           "ablation_variants", "summarize", "format_table", "format_ablation",
           "image_files"]

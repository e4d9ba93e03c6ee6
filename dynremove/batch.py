"""Many sets at once: ``dynremove batch ROOT --out DIR [--jobs N]``.

A *set* below ROOT is a folder holding images directly, a folder with a
``frames/`` sub-folder (the ``eval`` layout; ``masks/<ref stem>.png`` there, if
present, gives the Jaccard of the result), or a video file. ROOT itself may be a
set. A file named as a video that cannot be read is a set that fails; an earlier
run's outputs and an earlier batch's DIR below ROOT are not sets. Each set's
outputs are those of ``dynremove run`` (:func:`write_outputs`) in ``DIR/<set>/``
(a video named as another set keeps its suffix: ``camel.mp4``);
``DIR/summary.json`` and ``DIR/summary.csv`` list every set with its status
(``ok``, ``error``), whether it was skipped (not re-run), figures, seconds, notes
(those of its ``report.json``: unaligned sources, a blurry reference, ...) and
error message.

Resume: a set whose ``report.json`` carries the same *batch key* (a hash of the
parameters, the options and the bytes of every input file) and whose images
exist is skipped: its row keeps the outcome, figures, seconds and notes of the
run that made the outputs (from the previous ``summary.json``, else from
``report.json``), with ``skipped`` true. A failing set does not stop the others;
the command exits 1 at the end.

Sets run in parallel with joblib (``--jobs``; each worker runs OpenCV
single-threaded), or on a Dask cluster (``--scheduler tcp://host:port``, extra
``dynremove[dask]``) through joblib's ``dask`` backend: one task per set, on every
worker thread of the cluster (``--jobs`` is then unused). The workers import the
same dynremove and read ROOT and write DIR at the same paths (a shared disk).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io as _pyio
import json
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Generator, Sequence

import cv2
import numpy as np

from dynremove import io
from dynremove.errors import InputError, interruption
from dynremove.evaluation.metrics import jaccard
from dynremove.params import Params
from dynremove.refine.concurrency import one_thread_per_worker, quiet_worker_restarts
from dynremove.pipeline import full_resolution_output, misplaced_px, relit_px, remove_dynamic
from dynremove.video import (auto_reference, blurry_reference_note, blurry_sources_note,
                             parse_span, relative_sharpness)

OUTPUT_FILES = (*io.RUN_OUTPUTS, "report.json")
SUMMARY_FIELDS = ("set", "status", "skipped", "n_images", "reference", "dynamic_fraction",
                  "jaccard_vs_gt", "seconds", "notes", "error", "inputs", "out")
NOTES_SEP = " | "  # between the notes of a set in summary.csv (a list in summary.json)
SKIP_DIRS = {"masks", "gt", "groundtruth", "ground_truth"}  # beside frames/: not sets
DASK_CONNECT_TIMEOUT_S = 30


# --- outputs of one run (shared with ``dynremove run``) ---------------------------------
def at_output_size(res: Any, iset: Any, output_size: str = "full") -> Any:
    """``res`` with clean, dynamic and coverage at the input's full resolution.

    Only when ``output_size`` is ``"full"`` and the run worked on downscaled
    photos or video frames: the originals are read again (a clip's frames were
    kept, ``ImageSet.originals``) and ``pipeline.full_resolution_output``
    recomputes the replaced pixels; the others are the input's, byte for byte.
    """
    if output_size != "full" or iset.scale >= 1.0:
        return res
    # (timed from the reading of the originals, as the terminal's "full-size output"
    # line is: a trial read 7.0 s there against 5.5 s in report.json)
    t = time.perf_counter()
    kept = getattr(iset, "originals", None)
    full = list(kept) if kept is not None else [io.read_image(p)[0] for p in iset.paths]
    W0, H0 = iset.original_size
    for i, op in enumerate(getattr(iset, "conformed", None) or []):
        if op is not None:  # brought to the set's size when read: the same here
            full[i], _ = io.conform(full[i], None, op, (H0, W0))
    clean, dyn = full_resolution_output(res, full)
    Hf, Wf = clean.shape[:2]
    cov = cv2.resize(res.coverage, (Wf, Hf), interpolation=cv2.INTER_NEAREST)
    sel = res.selection
    if sel is not None and sel.members is not None:
        # the pixels the full-size fill adds to the mask (its seams, and one working
        # pixel beyond what it replaced) count the sources the fill took there, as
        # L's pixels do: 0 only next to inpainted ones (not the outside's count)
        used = np.where((sel.label >= 1) & ~sel.no_source,
                        np.minimum(sel.members.sum(0), 255), 0).astype(res.coverage.dtype)
        g = int(np.ceil(max(Wf / used.shape[1], Hf / used.shape[0]))) + 1  # the growth
        near = cv2.dilate(cv2.resize(used, (Wf, Hf), interpolation=cv2.INTER_NEAREST),
                          np.ones((2 * g + 1, 2 * g + 1), np.uint8))
        added = dyn & ~cv2.resize(res.dynamic.view(np.uint8), (Wf, Hf),
                                  interpolation=cv2.INTER_NEAREST).astype(bool)
        cov[added] = near[added]
    timings = dict(res.timings, full_resolution=time.perf_counter() - t)
    return dataclasses.replace(res, clean=clean, dynamic=dyn, coverage=cov, timings=timings)


def own_peak_rss_mb() -> float:
    """This process's peak resident set size (MiB) since it started its program.

    Linux: ``VmHWM`` of /proc/self/status, the high-water mark of the process's
    own address space. ``getrusage``'s ru_maxrss (the fallback elsewhere, KiB on
    Linux, bytes on macOS) is not that for a process started from a large one
    (a ``bench`` or a notebook): the kernel carries the parent's high-water mark
    over the fork and exec into it, so a run started from a process of 4 GB
    would report 4 GB.
    """
    try:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration, ValueError):
        import resource

        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return rss / 2 ** 20 if sys.platform == "darwin" else rss / 1024


def _throughput(res: Any, iset: Any) -> dict:
    """Scan speed (reference pixels visited per second, all scans) and peak memory."""
    h, w = iset.images[0].shape[:2]
    n_scans = max(1, len(res.scans))
    t_scan = float(res.timings.get("scans", 0.0))
    return {"scan_mpx_per_s": round(h * w * n_scans / t_scan / 1e6, 3) if t_scan > 0 else None,
            "working_mpx": round(h * w / 1e6, 3), "peak_rss_mb": round(own_peak_rss_mb(), 1)}


def _scene_entry(res) -> dict:
    """report.json's ``scene``: whether the run treated the set as flat or 3-D (the
    sources' median measured parallax against ``select_parallax_px``, and their 95th
    percentile against ``select_parallax_p95_px``: ``select.treated_as_3d``), which decides
    the clean-up of L, GrabCut's veto, the epipolar search and the fill's consensus;
    nothing without the fill by selection (the paper preset)."""
    sel = res.selection
    if sel is None:
        return {}
    limit = float(res.params.get("select_parallax_px", float("nan")))
    far = float(res.params.get("select_parallax_p95_px", float("nan")))
    p95 = float(sel.parallax_p95_px)
    return {"scene": {"median_parallax_px": round(float(sel.parallax_px), 2),
                      "parallax_threshold_px": limit,
                      "median_parallax_p95_px": round(p95, 2) if np.isfinite(p95) else None,
                      "parallax_p95_threshold_px": far,
                      "treated_as": "3-D" if sel.consensus_mode == "parallax" else "flat"}}


def write_outputs(out: Path, res: Any, *, iset: Any, ref: int, preset_name: str,
                  gt: np.ndarray | None = None, record: str | None = None,
                  reference: dict | None = None, extra: dict | None = None) -> dict:
    """clean.png, dynamic_mask.png (0/255), coverage.png and report.json, atomically.

    ``clean.png`` carries the reference photo's EXIF (orientation reset) and ICC
    profile where it had them, and its alpha channel where it has transparent pixels
    (resized to the clean photo when that is smaller). ``reference``: how the
    reference was chosen (merged into ``report["reference"]``); ``extra``: more
    top-level report entries.
    """
    like = iset.paths[ref] if not getattr(iset, "video", None) else None
    clean = res.clean
    alpha = io.read_alpha(like) if like is not None else None
    if alpha is not None:
        if alpha.shape != clean.shape[:2]:
            alpha = cv2.resize(alpha, clean.shape[1::-1], interpolation=cv2.INTER_AREA)
        clean = np.dstack([clean, alpha])
    io.write_photo(out / "clean.png", clean, like=like)
    io.write_image(out / "dynamic_mask.png", res.dynamic.astype(np.uint8) * 255)
    n_src = max(1, len(iset.images) - 1)
    io.write_image(out / "coverage.png",
                   (res.coverage.astype(np.float32) * (255.0 / n_src)).astype(np.uint8))
    H, W = res.clean.shape[:2]
    relit = relit_px(getattr(res, "selection", None))
    report = {
        "inputs": [str(p) for p in iset.paths],
        "reference": {"index": ref, "name": iset.names[ref], **(reference or {})},
        "size": {"width": W, "height": H, "original_width": iset.original_size[0],
                 "original_height": iset.original_size[1], "scale": iset.scale,
                 "working_width": iset.images[0].shape[1],
                 "working_height": iset.images[0].shape[0]},
        "preset": preset_name,
        "params": res.params,
        "scans": [{"scan": int(s["scan"]), "direction": int(s["direction"]),
                   "dynamic_px": int(s["n_dynamic"]), "replaced_px": int(s["n_replaced"]),
                   "undecided_px": int(s["n_undecided"]), "seconds": float(s["seconds"])}
                  for s in res.scans],
        "dynamic_fraction": float(res.dynamic.mean()),
        "uncovered_dynamic_px": int((res.dynamic & (res.coverage == 0)).sum()),
        # a faint shade beside the movers relit to the other photos' light, outside the
        # mask (at the analysis size, as the run's note counts it: ``res`` may hold the
        # full-size outputs by now; changed by under --select-tau)
        "relit_px": relit[0],
        # ... and inside it, where the shade runs into the fill
        "relit_in_mask_px": relit[1],
        # the fill's pieces whose source did not continue the photo around them,
        # inpainted instead (at the analysis size, as the run's note counts them; also
        # in uncovered_dynamic_px and 0 in coverage.png: no source's value there)
        "misplaced_px": misplaced_px(getattr(res, "selection", None)),
        # coverage.png holds count × 255 / sources (uint8, truncated)
        "coverage_png": {"sources": n_src, "value_per_source": round(255.0 / n_src, 4)},
        "geometry": res.geometry,
        **_scene_entry(res),
        "seconds": {k: round(float(v), 4) for k, v in res.timings.items()},
        "throughput": _throughput(res, iset),
        "notes": list(iset.notes) + list(res.warnings),
        "recording": str(record) if record else None,
    }
    video = getattr(iset, "video", None)
    if video:
        report["video"] = video
    valid = getattr(iset, "valid", None) or []
    if any(v is not None for v in valid):
        report["no_content_fraction"] = {
            n: (0.0 if v is None else round(float(1 - v.mean()), 5))
            for n, v in zip(iset.names, valid)}
    if gt is not None:
        if gt.shape != res.dynamic.shape:  # the output is larger than the analysis
            gt = cv2.resize(gt.astype(np.uint8), res.dynamic.shape[::-1],
                            interpolation=cv2.INTER_NEAREST).astype(bool)
        report["jaccard_vs_gt"] = jaccard(res.dynamic, gt)
    report.update(extra or {})
    io.write_json(out / "report.json", report)
    return report


def load_for_reference(inputs: Sequence[str | os.PathLike], ref: str | int | None, *,
                       on_loaded: Callable[[io.ImageSet], None] | None = None,
                       numbers: bool = True, **load
                       ) -> tuple[io.ImageSet, int, dict, list[str]]:
    """``io.load_image_set(inputs, **load)`` and ``choose_reference(ref, ...)``; when the
    reference is a photo that was brought to the set's size (a phone's crop), the set
    is read again at the reference's own size, so that its clean photo has that size
    and no border it lacks. ``on_loaded(iset)`` is called after each read (the CLI
    keeps the set for an interruption). ``numbers``: digits in ``ref`` may be a photo's
    number (``io.resolve_ref``; not for ``batch``, whose ``--ref`` is every set's).
    Returns (iset, ref, ref_info, ref_notes)."""
    iset = io.load_image_set(list(inputs), **load)
    if on_loaded is not None:
        on_loaded(iset)
    i, info, notes = choose_reference(ref, iset, numbers=numbers)
    if iset.conformed and iset.conformed[i] is not None:
        iset = io.load_image_set(list(inputs), size_of=i, **load)
        if on_loaded is not None:
            on_loaded(iset)
        i, info, notes = choose_reference(ref, iset, numbers=numbers)
    return iset, i, info, notes


def distinct_images(images: Sequence[np.ndarray]) -> list[int]:
    """The indices of the images that are not a pixel-for-pixel copy of an earlier
    one, in order."""
    seen: dict[bytes, list[int]] = {}
    out = []
    for i, im in enumerate(images):
        key = hashlib.blake2b(np.ascontiguousarray(im).data, digest_size=16).digest()
        if not any(np.array_equal(images[j], im) for j in seen.get(key, [])):
            out.append(i)
        seen.setdefault(key, []).append(i)
    return out


def choose_reference(ref: str | int | None, iset: io.ImageSet, *, numbers: bool = True
                     ) -> tuple[int, dict, list[str]]:
    """The reference index, how it was chosen (for the report) and notes.

    ``ref`` is an index, a file name, a path (exactly that input), ``"auto"``
    (:func:`~dynremove.video.auto_reference`) or None (the middle one of the distinct
    images, ``distinct_images``; a note suggests ``--ref auto`` when it is much
    blurrier than the others). ``numbers`` as in ``io.resolve_ref``.
    """
    valid = getattr(iset, "valid", None)
    if isinstance(ref, str) and ref.strip().lower() == "auto":
        i, note, info = auto_reference(iset.images, iset.names, valid)
        return i, {"chosen_by": "auto", **info}, [note]
    i = io.resolve_ref(ref, iset.names, paths=getattr(iset, "paths", None), numbers=numbers)
    if ref is None or ref == "":
        # the middle of the distinct photos: a file given twice (under two names)
        # does not move it (a fresh-user trial: desk6.jpg and DESK6.JPG made desk5
        # the reference instead of desk4)
        distinct = distinct_images(iset.images)
        n = len(distinct)
        i = distinct[n // 2]
        info: dict = {"chosen_by": "middle"}
        if n < len(iset.images):
            info["n_distinct"] = n
        if n % 2 == 0:  # the other middle one, for the note's --ref hint
            info["other_middle"] = distinct[n // 2 - 1]
        sharp = relative_sharpness(iset.images, valid)
        notes = [n for n in (blurry_reference_note(iset.images, i, iset.names, sharp=sharp),
                             blurry_sources_note(iset.images, i, iset.names, sharp=sharp))
                 if n]
        return i, info, notes
    note = blurry_sources_note(iset.images, i, iset.names, valid)
    return i, {"chosen_by": "given"}, [note] if note else []


# --- finding sets ---------------------------------------------------------------------
@dataclass(frozen=True)
class BatchSet:
    name: str  # relative to ROOT, posix ("davis/camel"); ROOT's own name for ROOT
    inputs: tuple[Path, ...]  # image files, or one video
    gt: Path | None = None  # masks/ folder of the eval layout (reference mask by stem)


def _images_in(folder: Path) -> list[Path]:
    """The photos of a folder, without an earlier run's outputs (``io.earlier_outputs``)."""
    try:
        files = sorted((q for q in folder.iterdir()
                        if q.is_file() and not q.name.startswith(".")), key=io.natural_key)
    except OSError:
        return []
    ours = io.earlier_outputs(q.name for q in files)
    # (a video named .jpg is a video: a set of its own, not "one photo only")
    return [q for q in files if q.name not in ours
            and (q.suffix.lower() in io.IMAGE_EXTS or io.is_image_file(q))
            and not io.is_video_file(q)]


def find_sets(root: str | os.PathLike, *, exclude: Sequence[Path] = (),
              notes: list[str] | None = None) -> list[BatchSet]:
    """Every set below ``root`` (itself included), sorted by name; see the module doc.

    ``notes`` (a list) receives a line for what a user may expect to be run and is
    not: the subfolders of a folder that is itself a set (never searched), a
    folder with a single photo (no set), and the files of a set's folder that are
    not images."""
    notes = [] if notes is None else notes
    root = Path(root)
    if root.is_file():  # one video (as the help says), or nothing batch can run
        if io.is_video_file(root):
            return [BatchSet(root.stem, (root,))]
        raise InputError(f"{root}: is a file, and not a video that can be read: give a "
                         "folder of sets or one video")
    if not root.is_dir():
        raise InputError(f"{root}: no such folder")
    skip = {p.resolve() for p in exclude}
    top = root.resolve()
    visited: set[Path] = set()  # each real folder once (a link back up looped 41 times)
    found: list[BatchSet] = []

    def name_of(d: Path) -> str:
        if d != root:
            return d.relative_to(root).as_posix()
        # ROOT itself a set: named as `run` names its folder (the parent's name for a
        # generic one: a trial's `batch .` inside tim6/frames wrote X/frames)
        return io.scene_folder(root.resolve()).name

    def walk(d: Path) -> None:
        real = d.resolve()
        if real in skip:
            return
        if d != root and d.is_symlink():
            if real != top and top not in real.parents:
                notes.append(f"{name_of(d)}: a link to a folder outside {root} ({real}): "
                             "not searched")
                return
            if real in visited:
                notes.append(f"{name_of(d)}: a link to a folder searched already "
                             f"({real}): not searched again")
                return
        if real in visited:
            return
        visited.add(real)
        if d != root and (d / "summary.json").is_file() and (d / "summary.csv").is_file():
            # an earlier batch's --out inside ROOT: its sets' outputs are not photos
            notes.append(f"{name_of(d)}: an earlier dynremove batch's outputs (its "
                         "summary.json and summary.csv): not searched")
            return
        fr = d / "frames"
        if fr.is_dir():
            imgs = _images_in(fr)
            if len(imgs) >= 2:
                gt = d / "masks"
                found.append(BatchSet(name_of(d), tuple(imgs), gt if gt.is_dir() else None))
                return
        imgs = _images_in(d)
        try:
            entries = sorted(q for q in d.iterdir() if not q.name.startswith("."))
        except OSError:
            entries = []
        ours = io.earlier_outputs(q.name for q in entries if q.is_file())
        if len(imgs) >= 2:
            found.append(BatchSet(name_of(d), tuple(imgs)))
            kept = {q.name for q in imgs}
            if ours:  # (as ``run`` on the folder says)
                notes.append(io.outputs_note(name_of(d), ours))
            other = [q.name for q in entries if q.is_file() and q.name not in kept
                     and not (ours and q.name in (*ours, "report.json"))
                     and not io.is_video_file(q)]
            if other:  # (as ``run`` on the folder says)
                notes.append(io.skipped_note(name_of(d), other))
            videos = [q.name for q in entries if q.is_file() and q.name not in kept
                      and io.is_video_file(q)]
            if videos:  # (as ``run`` says; a trial's clip.mp4 beside photos went unsaid)
                notes.append(f"{name_of(d)}: skipped {len(videos)} video(s) beside its "
                             f"photos: {', '.join(videos)} (a video is run as a set of its "
                             "own where its folder holds no set of photos)")
            subs = [q.name for q in entries if q.is_dir() and q.name.lower() not in SKIP_DIRS
                    and q.resolve() not in skip]
            if subs:
                notes.append(f"{name_of(d)}: its {len(imgs)} photos are one set, so its "
                             f"subfolders are not searched: {', '.join(subs)} (move the "
                             "photos into a subfolder of their own)")
            return
        if len(imgs) == 1:
            notes.append(f"{name_of(d)}: one photo only ({imgs[0].name}): not a set")
        if not entries and d != root:  # (a trial's empty folder went unmentioned)
            notes.append(f"{name_of(d)}: an empty folder: not a set")
        if ours and not imgs:
            # (a trial's batch into a folder inside ROOT: the next batch over ROOT ran
            # each set's clean.png, dynamic_mask.png and coverage.png as three photos)
            notes.append(f"{name_of(d)}: the outputs of an earlier dynremove run "
                         f"({', '.join(sorted(ours))} beside its report.json): not a set")
        for q in entries:
            if q.is_dir() and q.name.lower() not in SKIP_DIRS:
                if q.is_symlink():
                    links.append(q)  # after the real folders: they keep their own names
                else:
                    walk(q)
            elif q.is_file() and (io.is_video_file(q) or q.suffix.lower() in io.VIDEO_SUFFIXES):
                # a file named as a video that cannot be read is a set that fails, in
                # the summary and the exit code (a fresh-user trial's fake.mp4 vanished
                # without a word, then with a note only)
                rel = q.relative_to(root)
                found.append(BatchSet(rel.with_suffix("").as_posix(), (q,)))

    links: list[Path] = []
    walk(root)
    while links:
        walk(links.pop(0))
    return sorted(_distinct_names(found), key=lambda s: s.name)


def _set_folder_at(out: Path, root: Path) -> Path | None:
    """The folder below ``root`` that holds ``out`` (or is it) and whose photos are a
    set (themselves or in its ``frames/``); None if there is none."""
    o, top = out.resolve(), root.resolve()
    for d in (o, *o.parents):
        if d == top or top not in d.parents:
            return None
        if len(_images_in(d)) >= 2 or len(_images_in(d / "frames")) >= 2:
            return d
    return None


def _distinct_names(sets: list[BatchSet]) -> list[BatchSet]:
    """Each set's output folder is named after it: a video named as a folder or another
    video (``camel/``, ``camel.mp4``, ``camel.avi``) keeps its suffix (``camel.mp4``), so
    that no two sets write into one folder (a fresh-user trial lost two of three that
    way, and a resume re-ran them every time). InputError if two names still clash."""
    count: dict[str, int] = {}
    for bs in sets:
        count[bs.name] = count.get(bs.name, 0) + 1
    out = []
    for bs in sets:
        src = Path(bs.inputs[0])
        if count[bs.name] > 1 and len(bs.inputs) == 1 and src.is_file():
            bs = BatchSet(bs.name + src.suffix, bs.inputs, bs.gt)
        out.append(bs)
    seen: dict[str, BatchSet] = {}
    for bs in out:
        if bs.name in seen:
            raise InputError(f"two sets would write to one output folder {bs.name!r}: "
                             f"{seen[bs.name].inputs[0]} and {bs.inputs[0]} (rename one)")
        seen[bs.name] = bs
    return out


# --- one set ----------------------------------------------------------------------------
VIDEO_OPTIONS = ("frames", "span", "pick")  # the options only a video set reads


def batch_key(bs: BatchSet, options: dict) -> str:
    """Hash of the options (parameters, preset, size, reference, ...) and the inputs' bytes.
    A folder of photos leaves out the options that take frames from a video
    (``frames``, ``span``, ``pick``): a changed ``--span`` re-ran every photo set."""
    if not (len(bs.inputs) == 1 and io.is_video_file(Path(bs.inputs[0]))):
        options = {k: v for k, v in options.items() if k not in VIDEO_OPTIONS}
    h = hashlib.sha256(json.dumps(options, sort_keys=True, default=str).encode())
    for p in bs.inputs:
        h.update(p.name.encode() + b"\0")
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:32]


def _is_done(out: Path, key: str) -> dict | None:
    try:
        report = json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        return None
    if report.get("batch_key") != key or not all((out / f).is_file() for f in OUTPUT_FILES):
        return None
    return report


def run_set(bs: BatchSet, out_root: Path, options: dict, *, single_thread: bool = False,
            progress: Callable[[str, float], None] | None = None) -> dict:
    """Run one set into ``out_root/<set>``; never raises (errors go into the row).
    ``progress``: given to the pipeline (stage, fraction done), as ``run``'s bar."""
    if single_thread:
        one_thread_per_worker()  # in a worker: parallelism comes from joblib
    t0 = time.perf_counter()
    out = out_root / bs.name
    row: dict[str, Any] = dict.fromkeys(SUMMARY_FIELDS)
    row.update({"set": bs.name, "skipped": False, "notes": [], "inputs": len(bs.inputs),
                "out": str(out)})
    try:
        key = batch_key(bs, options)
        row["batch_key"] = key
        done = _is_done(out, key)
        if done is not None:  # the outcome of the run that wrote the outputs
            row.update(_row_from_report(done), status="ok", skipped=True,
                       seconds=_earlier_seconds(done))
            return row
        _check_writable(out)  # before the analysis, as `run` checks --out
        # outputs of a run with other options or inputs: replaced, and said (as `run`
        # says it; a trial's second batch with another --ref replaced them silently)
        replaced = (out / "report.json").is_file()
        params = Params(**options["params"])
        # --frames and --span are for the video sets (a folder of photos has its own)
        video = len(bs.inputs) == 1 and io.is_video_file(Path(bs.inputs[0]))
        iset, ref, ref_info, notes = load_for_reference(
            bs.inputs, options.get("ref"), numbers=False, max_side=options.get("max_side"),
            frames=options.get("frames") if video else None,
            span=options.get("span") if video else None,
            pick=options.get("pick") or "sharpest")
        iset.notes.extend(notes)
        if replaced:
            iset.notes.append(f"{out} held the outputs of an earlier run with other options "
                              "or inputs: this run replaced them")
        with warnings.catch_warnings():  # the run's warnings are in res.warnings
            warnings.simplefilter("ignore")
            res = remove_dynamic(iset.images, ref=ref, params=params, names=iset.names,
                                 preset_name=options["preset"], valid_masks=iset.valid_masks,
                                 progress=progress)
            res = at_output_size(res, iset, options.get("output_size", "full"))
        gt = None
        if bs.gt is not None:
            mp = bs.gt / (Path(iset.names[ref]).stem + ".png")
            if mp.is_file():  # scored at the size written, as `run --gt` scores
                H, W = res.dynamic.shape
                gt = io.read_mask(mp, (W, H))
        out.mkdir(parents=True, exist_ok=True)
        extra = {"batch_key": key, "batch_seconds": round(time.perf_counter() - t0, 3)}
        report = write_outputs(out, res, iset=iset, ref=ref, preset_name=options["preset"],
                               gt=gt, reference=ref_info, extra=extra)
        row.update(_row_from_report(report), status="ok")
    except Exception as e:  # noqa: BLE001 - recorded in the summary, the batch goes on
        stop = interruption(e)
        if stop is not None:
            # a Ctrl-C that landed inside a compiled call (a SystemError around it):
            # the batch stops, this set is not run (a fresh-user trial saw it
            # recorded as failed, and the batch go on)
            raise stop from None
        msg = " ".join(str(e).split()) or type(e).__name__
        if (out / "report.json").is_file():  # left as they were: nothing is lost
            msg += f" ({out} still holds an earlier run's outputs, not this run's)"
        row.update(status="error", error=msg if isinstance(e, InputError)
                   else f"{type(e).__name__}: {msg}")
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


def _check_writable(out: Path) -> None:
    """InputError if the set's output folder, or the nearest folder above it that
    exists, cannot be written (a fresh-user trial's read-only set folder gave a
    PermissionError naming a temporary file, after the whole analysis). Nothing is
    created here: a set that fails leaves no folder behind."""
    p = io.nearest_existing(out)
    if not p.is_dir():
        raise InputError(f"{out}: cannot be created: {p} is a file, not a folder")
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(f"{out}: not writable" if p == out else
                         f"{out}: cannot be created: {p} is not writable")


def _row_from_report(report: dict) -> dict:
    return {"n_images": len(report.get("inputs", [])),
            "reference": report.get("reference", {}).get("name"),
            "dynamic_fraction": round(float(report.get("dynamic_fraction", 0.0)), 5),
            "jaccard_vs_gt": (round(report["jaccard_vs_gt"], 4)
                              if report.get("jaccard_vs_gt") is not None else None),
            "notes": [str(n) for n in report.get("notes") or []]}


def _earlier_seconds(report: dict) -> float | None:
    """Seconds of the run that wrote ``report`` (:func:`run_batch` prefers the
    previous summary's figure, which includes writing the outputs)."""
    if report.get("batch_seconds") is not None:
        return float(report["batch_seconds"])
    secs = report.get("seconds") or {}  # written before batch_seconds existed
    if secs.get("total") is None:
        return None
    return round(float(secs["total"]) + float(secs.get("full_resolution", 0.0)), 3)


def _previous_rows(out: Path) -> dict[str, dict]:
    """The rows of ``out/summary.json`` by set name ({} when missing or unreadable)."""
    try:
        prev = json.loads((out / "summary.json").read_text())
        return {r["set"]: r for r in prev.get("sets", []) if isinstance(r, dict) and "set" in r}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}


def _earlier_row(out: Path, p: dict | None) -> dict | None:
    """The previous summary's row ``p`` of a set that this batch did not reach, when
    ``out`` (the set's folder) still holds the outputs of the run it describes (the
    same batch key, ``ok``); marked as not re-checked. None otherwise."""
    if not p or p.get("status") != "ok" or not p.get("batch_key"):
        return None
    if _is_done(out, p["batch_key"]) is None:
        return None
    note = ("from the earlier run: this batch was cut short before the set (its inputs "
            "were not checked for changes)")
    return {**p, "skipped": True, "notes": [*(p.get("notes") or []), note]}


def _finished_on_disk(bs: BatchSet, out_root: Path, options: dict, *, since: float
                      ) -> dict | None:
    """The row of a set whose folder holds whole outputs that this batch wrote (its
    report.json written at or after ``since``, a wall-clock time, and the same batch
    key), when the batch was cut short before the set's row came back; else None."""
    out = out_root / bs.name
    try:
        if (out / "report.json").stat().st_mtime < since:
            return None
        key = batch_key(bs, options)
    except (OSError, ValueError):
        return None
    report = _is_done(out, key)
    if report is None:
        return None
    row: dict[str, Any] = dict.fromkeys(SUMMARY_FIELDS)
    row.update({"set": bs.name, "skipped": False, "inputs": len(bs.inputs), "out": str(out),
                "batch_key": key, **_row_from_report(report), "status": "ok",
                "seconds": _earlier_seconds(report)})
    return row


def _keep_earlier(row: dict, prev: dict[str, dict]) -> dict:
    """A skipped row with the seconds of the previous summary's row of the same set,
    when that row is the run that made the outputs (same batch key, ``ok``)."""
    p = prev.get(row["set"])
    if (row.get("skipped") and p and p.get("batch_key") == row.get("batch_key")
            and p.get("status") == "ok" and p.get("seconds") is not None):
        row["seconds"] = p["seconds"]
    return row


# --- the batch --------------------------------------------------------------------------
def run_batch(root: str | os.PathLike, out: str | os.PathLike, *, params: Params,
              preset_name: str, jobs: int = 1, max_side: int | None = None,
              ref: str | None = None, frames: int | None = None, span: str | None = None,
              pick: str = "sharpest", scheduler: str | None = None,
              on_done: Callable[[int, int, dict], None] | None = None,
              on_note: Callable[[str], None] | None = None,
              on_start: Callable[[int, int, BatchSet], Callable[[str, float], None] | None]
              | None = None) -> dict:
    """Run every set below ``root`` into ``out``; write and return the summary.

    ``on_done(k, n, row)``: as each set finishes (k of n, in finishing order).
    ``on_start(k, n, set)``: before each set runs, when they run one at a time
    (``jobs`` 1); it may return a progress callable (stage, fraction) for that
    set's pipeline. With ``jobs`` > 1 or a scheduler the sets start in workers:
    ``on_note`` says how many run at a time.

    Returns ``{"root", "out", "sets": [row, ...], "n_ok", "n_skipped", "n_failed",
    "wall_s", "jobs", "scheduler", "notes"}``; rows in set-name order (see
    SUMMARY_FIELDS); ``notes``: what the search of ``root`` did not run (each also
    given to ``on_note`` before the sets run).
    """
    if Path(out).resolve() == Path(root).resolve():
        raise InputError(f"--out {out}: is ROOT itself (the search would meet the outputs "
                         "and skip them); choose a folder beside it, or one below it")
    held = _set_folder_at(Path(out), Path(root))
    if held is not None:
        # (a trial's --out photos/trip1 left trip1 out of this batch and every later one,
        # and wrote the summary among its photos; `run` refuses its photos' own folder)
        where = "is" if held == Path(out).resolve() else "is inside"
        raise InputError(f"--out {out}: {where} the folder of the set "
                         f"{held.relative_to(Path(root).resolve()).as_posix()} (its photos "
                         "would not be run); choose a folder beside ROOT, or one of its own")
    if span:  # its form and order, before any set runs (a trial's 9:3 failed at the
        # first video, after the sets before it had run)
        parse_span(span, sys.maxsize)
    notes: list[str] = []
    # (the sets first: a ROOT with none leaves no empty --out folder behind)
    sets = find_sets(root, exclude=[Path(out)], notes=notes)
    if (frames is not None or span) and not any(
            len(bs.inputs) == 1 and io.is_video_file(Path(bs.inputs[0])) for bs in sets):
        # (a trial's --span on folders of photos ran them all without a word, and a
        # changed span ran them all again: it is no part of their options now)
        given = " and ".join(f for f, v in (("--frames", frames), ("--span", span))
                             if v is not None and v != "")
        notes.append(f"{given}: {'they take' if ' and ' in given else 'it takes'} frames "
                     "from a video, and no set here is one: ignored")
        frames, span = None, None
    for n in notes:
        if on_note is not None:
            on_note(n)
    if not sets:
        raise InputError(f"{root}: no sets found (a set is a folder of at least 2 images, "
                         "a folder with frames/, or a video)")
    existed = Path(out).exists()
    out = io.prepare_out_dir(out)
    prev = _previous_rows(out)
    options = {"params": params.to_dict(), "preset": preset_name, "max_side": max_side,
               "ref": ref, "frames": frames, "span": span, "pick": pick}
    t0 = time.perf_counter()
    t0_wall = time.time()
    results: dict[str, dict] = {}

    def summary_of(rows: list[dict], workers: int | None, **extra) -> dict:
        return {"root": str(root), "out": str(out), "sets": rows,
                "n_ok": sum(r["status"] == "ok" and not r.get("skipped") for r in rows),
                "n_skipped": sum(bool(r.get("skipped")) for r in rows),
                "n_failed": sum(r["status"] == "error" for r in rows),
                "wall_s": round(time.perf_counter() - t0, 3),
                "jobs": None if scheduler else jobs, "scheduler": scheduler,
                "workers": workers, "preset": preset_name, "options": options,
                "notes": notes, **extra}

    try:
        rows, workers = _run_all(sets, out, options, jobs=jobs, scheduler=scheduler,
                                 on_done=on_done, prev=prev, results=results,
                                 on_start=on_start, on_note=on_note)
    except BaseException as e:
        if isinstance(e, InputError) and not results:
            # a set-up error before any set ran (--scheduler: no Dask, no cluster): no
            # summary, and no empty --out left behind; an earlier summary stays as it
            # was (a fresh-user trial found it rewritten as "interrupted")
            if not existed and not any(out.iterdir()):
                out.rmdir()
            raise
        # interrupted (Ctrl-C, SIGTERM) or failed: the summary still lists the sets
        # that finished (each set's own outputs are already whole on disk), and says
        # how many did not run; the same command again resumes
        # a set whose outputs a worker wrote whole as the interruption landed, before
        # its row came back, finished too (a fresh-user trial's --jobs 2 batch said
        # "2 of 8 sets finished" beside a third set's complete outputs)
        for bs in sets:
            if bs.name not in results:
                row = _finished_on_disk(bs, out, options, since=t0_wall)
                if row is not None:
                    results[bs.name] = row
        done = [results[bs.name] for bs in sets if bs.name in results]
        n_not_run = len(sets) - len(done)
        # a set this run did not reach keeps the earlier summary's row while its
        # outputs are still that run's (an interrupted batch wiped the rows of the
        # sets finished before: a fresh-user trial)
        rows = [results.get(bs.name) or _earlier_row(out / bs.name, prev.get(bs.name))
                for bs in sets]
        if scheduler:
            workers = None  # (the cluster's, unknown once cut)
        else:  # as a finished batch says it (a trial's cut --jobs 1 batch said null)
            workers = _workers(jobs, len(sets))  # (as _run_all)
        _write_summary(out, summary_of([r for r in rows if r is not None], workers,
                                       interrupted=True, n_not_run=n_not_run))
        raise
    summary = summary_of(rows, workers)
    _write_summary(out, summary)
    return summary


def _write_summary(out: Path, summary: dict) -> None:
    """``summary.json`` and ``summary.csv`` (SUMMARY_FIELDS, one row per set), each
    written atomically."""
    rows = summary["sets"]
    io.write_json(out / "summary.json", summary)
    buf = _pyio.StringIO()
    w = csv.DictWriter(buf, fieldnames=SUMMARY_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: NOTES_SEP.join(r.get(k) or []) if k == "notes" else r.get(k)
                    for k in SUMMARY_FIELDS})
    io._atomic_write_bytes(out / "summary.csv", buf.getvalue().encode())


def _workers(jobs: int, n_sets: int) -> int:
    """Sets run at once without a scheduler: ``--jobs`` (joblib's count: -1 = all
    cores), at most one per set."""
    from joblib import effective_n_jobs

    return 1 if jobs == 1 else min(effective_n_jobs(jobs), n_sets)


def _run_all(sets: Sequence[BatchSet], out: Path, options: dict, *, jobs: int,
             scheduler: str | None, on_done: Callable[[int, int, dict], None] | None,
             prev: dict[str, dict] | None = None,
             results: dict[str, dict] | None = None,
             on_start: Callable[[int, int, BatchSet], Callable[[str, float], None] | None]
             | None = None,
             on_note: Callable[[str], None] | None = None) -> tuple[list[dict], int]:
    """The rows in set order, and the number of workers (joblib's, or the Dask
    cluster's when ``scheduler``). ``prev``: the previous summary's rows by set
    (:func:`_keep_earlier`). ``results``: filled with each row by set name as it
    arrives (what finished is there when the run is cut short)."""
    from joblib import Parallel, delayed, parallel_config

    results = {} if results is None else results
    on_done = _with_earlier(on_done, prev or {})
    if not scheduler:
        # one at a time in this process, on all its threads: with --jobs 1, or one set
        # (a trial's --jobs 16 on one set started 16 workers; a joblib pool of one
        # would run it here on one thread)
        n = _workers(jobs, len(sets))
        if n == 1:
            def one(k: int, bs: BatchSet) -> dict:
                progress = on_start(k, len(sets), bs) if on_start else None
                return run_set(bs, out, options, progress=progress)
            _collect((one(k, bs) for k, bs in enumerate(sets, 1)), sets, on_done, results)
        else:
            quiet_worker_restarts()
            cores = os.cpu_count() or 1
            if on_note is not None and n > cores:
                on_note(f"--jobs {jobs}: more sets at a time than this machine's {cores} "
                        "cores; they share the cores (each set runs on one), so the batch "
                        "is no faster and needs more memory")
            if on_note is not None:
                on_note(f"{len(sets)} set{'s' if len(sets) != 1 else ''}, {n} at a time: "
                        "a line as each one finishes")
            # (n workers, not --jobs: a trial's --jobs 16 on one set started 16)
            _collect(Parallel(n_jobs=n, return_as="generator_unordered")(
                delayed(run_set)(bs, out, options, single_thread=True) for bs in sets),
                sets, on_done, results)
        return [results[bs.name] for bs in sets], n
    # Dask: the workers import dynremove and read / write the same paths (shared disk)
    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler needs the optional extra: "
                         "pip install 'dynremove[dask]'") from None
    try:
        client = Client(scheduler, timeout=DASK_CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as e:
        raise InputError(f"--scheduler {scheduler}: cannot connect "
                         f"({' '.join(str(e).split())})") from None
    try:
        if not client.nthreads():  # else the sets would wait for ever
            try:
                client.wait_for_workers(1, timeout=DASK_CONNECT_TIMEOUT_S)
            except TimeoutError:
                raise InputError(f"--scheduler {scheduler}: no worker joined within "
                                 f"{DASK_CONNECT_TIMEOUT_S} s") from None
        workers = len(client.nthreads())
        if on_note is not None:
            on_note(f"{len(sets)} sets on the cluster's {sum(client.nthreads().values())} "
                    "worker threads: a line as each one finishes")
        with parallel_config(backend="dask"):  # joblib's backend: the default client
            _collect(Parallel(n_jobs=-1, return_as="generator_unordered")(
                delayed(run_set)(bs, out, options, single_thread=True) for bs in sets),
                sets, on_done, results)
    finally:
        client.close()
    return [results[bs.name] for bs in sets], workers


def _with_earlier(on_done: Callable[[int, int, dict], None] | None, prev: dict[str, dict]
                  ) -> Callable[[int, int, dict], None]:
    """``on_done`` applied after :func:`_keep_earlier` (in the main process)."""
    def cb(k: int, n: int, row: dict) -> None:
        _keep_earlier(row, prev)
        if on_done:
            on_done(k, n, row)
    return cb


def _collect(gen: Generator[dict, None, None], sets: Sequence[BatchSet],
             on_done: Callable[[int, int, dict], None] | None, results: dict) -> list[dict]:
    """The rows of ``gen`` into ``results`` (and ``on_done``), as they come.

    ``gen`` is closed however the loop ends: an interruption that reaches the main
    thread between two rows (in ``on_done``) leaves joblib's generator suspended, its
    workers running their sets on; closing it aborts them here and now (joblib kills
    its loky workers). A fresh-user trial saw two workers outlive a batch cut short
    by SIGINT and write a set 16 s after the command had exited 130."""
    try:
        for k, row in enumerate(gen, 1):
            results[row["set"]] = row
            if on_done:
                on_done(k, len(sets), row)
    finally:
        with warnings.catch_warnings():  # ("exited early": it was told to)
            warnings.simplefilter("ignore")
            gen.close()
    return list(results.values())


def _is_photo_note(note: str) -> bool:
    """True for a note about one photo (``"name.jpg: ..."``), not the whole set."""
    head, sep, _ = note.partition(": ")
    return bool(sep) and " " not in head and "." in head


def _shorten(note: str, limit: int = 90) -> str:
    """The note's first clause (before `` (`` or ``. ``), at most ``limit`` characters
    cut at a word; ``…`` when something was left out."""
    text = " ".join(note.split())
    short = text
    for stop in (" (", ". ", "; "):
        i = short.find(stop)
        if i >= 20:
            short = short[:i]
    if len(short) > limit:
        short = short[:limit].rsplit(" ", 1)[0].rstrip(",;:")
    return short if short == text else short.rstrip(".") + "…"


def notes_phrase(notes: Sequence[str]) -> str:
    """``"1 note: <note>"`` or ``"5 notes: <note>…; 4 more in report.json"``, shortened;
    ``""`` without notes. The note shown: the first saying the result is unreliable,
    else the first about the whole set (not one photo), else the first."""
    if not notes:
        return ""
    main = min(notes, key=lambda m: ("unreliable" not in m.lower(), _is_photo_note(m)))
    n = len(notes)
    more = f"; {n - 1} more in report.json" if n > 1 else ""
    return f"{n} note{'' if n == 1 else 's'}: {_shorten(main)}{more}"


def stderr_progress(k: int, n: int, row: dict) -> None:
    """One line per finished set on stderr (with its notes, shortened)."""
    secs = "" if row.get("seconds") is None else f" ({row['seconds']:.1f} s)"
    if row["status"] == "error":
        what = f"error: {row.get('error')}{secs}"
    else:
        what = (f"{row['status']}, {100 * (row['dynamic_fraction'] or 0):.1f} % dynamic"
                + (f", J {row['jaccard_vs_gt']:.3f}" if row.get("jaccard_vs_gt")
                   is not None else "") + secs)
        if row.get("skipped"):
            what = f"skipped (done before, same parameters and inputs): {what}"
        phrase = notes_phrase(row.get("notes") or [])
        what += f", {phrase}" if phrase else ""
    print(f"[{k}/{n}] {row['set']}: {what}", file=sys.stderr, flush=True)

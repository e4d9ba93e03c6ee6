"""Picking frames: from a video clip (``read_video``) and the reference (``--ref auto``).

A clip is read once with OpenCV (FFmpeg); of each even window of the span the
sharpest frame (variance of the Laplacian) or the centre one is kept. The same
sharpness, with SIFT keypoint matches, picks the reference among a set.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from dynremove.errors import InputError

VIDEO_FRAMES = 7  # frames taken from a video by default
BLANK_STD = 2.0  # grey levels: a frame whose grey varies less than this has no picture


# --- video --------------------------------------------------------------------------
def parse_span(span: str | None, n_total: int, notes: list[str] | None = None
               ) -> tuple[int, int]:
    """``START:END`` frame numbers (END excluded; either may be empty) -> (start, end).

    An END past the clip is cut to it; with ``notes``, a line saying so is appended
    (a trial's ``--span 30:50`` on a clip of 35 frames was cut without a word).
    Raises InputError on a malformed span or one with no frame in the clip."""
    if not span:
        return 0, n_total
    a, sep, b = span.partition(":")
    try:
        start = int(a) if a.strip() else 0
        end = int(b) if b.strip() else n_total
    except ValueError:
        start = end = -1
    if not sep or start < 0 or end < 0:
        raise InputError(f"--span {span}: expected START:END, frame numbers >= 0 "
                         "(either may be empty)")
    if start >= end:  # (a trial's 10:5 was told the clip's length, not the order)
        raise InputError(f"--span {span}: END must be greater than START (END is excluded)")
    if end > n_total and start < n_total and notes is not None:
        notes.append(f"--span {span}: the clip has {n_total} frames (0..{n_total - 1}): "
                     f"the span taken is {start}:{n_total}")
    end = min(end, n_total)
    if start >= end:
        raise InputError(f"--span {span}: no frames (the clip has {n_total}: 0..{n_total - 1})")
    return start, end


def sharpness(img: np.ndarray, valid: np.ndarray | None = None, *,
              relative: bool = False) -> float:
    """Variance of the Laplacian of the grey image (at most 640 px), over ``valid``;
    with ``relative``, divided by the grey image's own variance there (the same for
    a darker or lower-contrast exposure of the same frame: a reference at 35 %
    exposure was called "much blurrier" by the plain figure)."""
    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    f = min(1.0, 640.0 / max(g.shape))
    if f < 1.0:
        size = (max(1, round(g.shape[1] * f)), max(1, round(g.shape[0] * f)))
        g = cv2.resize(g, size, interpolation=cv2.INTER_AREA)
        if valid is not None:
            valid = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    lap = cv2.Laplacian(g, cv2.CV_32F, ksize=3)
    gf = g.astype(np.float32)
    if valid is not None:
        inner = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        if inner.any():
            lap, gf = lap[inner], gf[inner]
    if relative:
        return float(lap.var() / max(float(gf.var()), 1e-6))
    return float(lap.var())


def is_blank(img: np.ndarray) -> bool:
    """A frame with no picture: one flat colour, black or a fade's (the standard
    deviation of its grey, at most 160 px, under ``BLANK_STD``)."""
    g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    f = min(1.0, 160.0 / max(g.shape))
    if f < 1.0:
        g = cv2.resize(g, (max(1, round(g.shape[1] * f)), max(1, round(g.shape[0] * f))),
                       interpolation=cv2.INTER_AREA)
    return float(g.std()) < BLANK_STD


def _content_range(p: Path, start: int, end: int) -> tuple[tuple[int, int] | None, int]:
    """The first and last frame of ``start:end`` that is not blank (``is_blank``), or
    None when all are, and the end of the frames that could be read (every frame
    decoded once)."""
    cap = cv2.VideoCapture(str(p))
    first = last = None
    read_end = start
    try:
        if start:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        for i in range(start, end):
            ok, fr = cap.read()
            if not ok:
                break
            read_end = i + 1
            if not is_blank(fr):
                first = i if first is None else first
                last = i
    finally:
        cap.release()
    return (None if first is None else (first, last)), read_end


def read_video(path: str | os.PathLike, *, frames: int | None = None,
               span: str | None = None, pick: str = "sharpest", _replan: bool = True
               ) -> tuple[list[np.ndarray], list[int], list[str]]:
    """Take ``frames`` frames (default 7) from a clip, one per even window of ``span``.

    ``pick="sharpest"``: the frame with the largest variance of the Laplacian
    among the middle half of each window (so that two picks are at least half a
    window apart: picks at two windows' common edge were neighbours, one of
    them adding almost nothing); ``"even"``: the window's centre. Returns images
    (BGR uint8), their frame numbers (0-based) and notes. Read with OpenCV
    (FFmpeg) in one pass; a clip that cannot be read up to the frame count it
    reports (a truncated file), or that starts or ends with blank frames (black,
    a fade: ``is_blank``), is read a second time, its windows over the frames
    it has with a picture. InputError when no frame of the span has one.
    """
    p = Path(path)
    n_want = VIDEO_FRAMES if frames is None else int(frames)
    if n_want < 2:
        raise InputError(f"--frames {n_want}: need at least 2")
    if pick not in ("sharpest", "even"):
        raise InputError(f"--pick {pick}: expected 'sharpest' or 'even'")
    # FFmpeg's own messages ("moov atom not found") would reach the terminal before
    # the one-line error below says the same; the user may still ask for them
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    cap = cv2.VideoCapture(str(p))
    try:
        if not cap.isOpened():
            raise InputError(f"{p}: a video OpenCV cannot open (damaged, or a codec "
                             "this OpenCV build lacks)")
        n_total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if n_total <= 0:  # some containers do not say: count
            n_total = 0
            while cap.grab():
                n_total += 1
            cap.release()
            cap = cv2.VideoCapture(str(p))
        notes: list[str] = []
        start, end = parse_span(span, n_total, notes)
        n = min(n_want, end - start)
        if n < 2:
            raise InputError(f"{p}: need at least 2 frames, the span has {end - start}")
        edges = [start + round(k * (end - start) / n) for k in range(n + 1)]
        centres = [(edges[k] + edges[k + 1] - 1) // 2 for k in range(n)]
        # (sharpest) the middle half of each window: at least half a window between picks
        inner = [(edges[k] + (edges[k + 1] - edges[k]) // 4,
                  edges[k + 1] - (edges[k + 1] - edges[k]) // 4) for k in range(n)]
        best: list[tuple[float, int, np.ndarray | None]] = [(-1.0, -1, None)] * n
        if start:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        i, k = start, 0
        last = centres[-1] if pick == "even" else end - 1
        stopped = None  # the first frame that could not be read (a truncated clip)
        content = None  # (sharpest) the first and last frame with a picture
        blank_pick = False  # (even) a window's centre is blank
        while i <= last:
            ok = cap.grab()
            if not ok:
                stopped = i
                break
            while k + 1 < n and i >= edges[k + 1]:
                k += 1
            if pick == "even":
                if i == centres[k]:
                    ok, fr = cap.retrieve()
                    if ok:
                        best[k] = (0.0, i, fr)
                        blank_pick |= is_blank(fr)
            else:
                ok, fr = cap.retrieve()
                if ok and not is_blank(fr):
                    content = (i, i) if content is None else (content[0], i)
                    s = sharpness(fr)
                    if inner[k][0] <= i < inner[k][1] and s > best[k][0]:
                        best[k] = (s, i, fr)
            i += 1
    finally:
        cap.release()
    got = [(idx, fr) for _, idx, fr in best if fr is not None]
    # read again over the frames the clip has, with a picture: a truncated clip (a
    # trial's gave 4 frames of 12 that could be read, where it had enough for all
    # 7), and one that starts or ends blank (a trial's fade-in from black stopped
    # the run: "has content in only 0.0 % of the frame")
    stop = end
    if stopped is not None and len(got) < n and stopped - start >= 2:
        stop = stopped
    read_end = stopped if stopped is not None else end  # the frames decoded end here
    if pick == "even" and blank_pick:
        content, read_end = _content_range(p, start, stop)
    if content is None and (blank_pick or (pick == "sharpest" and i > start)):
        raise InputError(f"{p}: every frame of the span {start}:{stop} is blank (one flat "
                         "colour: black, or a fade); --span chooses the frames to take from")
    lo, hi = start, stop
    if content is not None:
        lo = max(content[0], start)
        if content[1] + 1 < read_end:  # blank frames after the last picture (read ones)
            hi = min(content[1] + 1, stop)
    if (lo, hi) != (start, end) and hi - lo >= 2 and _replan:
        imgs, idx, again = read_video(p, frames=n_want, span=f"{lo}:{hi}", pick=pick,
                                      _replan=False)
        # (the user's --span note stays; the first pass's other notes were of its windows)
        said = [n for n in notes if n.startswith("--span")]
        if stop < end:
            said.append(f"{p.name}: the clip reports {n_total} frames but could be read "
                        f"only up to frame {stop - 1} (truncated?)")
        if (lo, hi) != (start, stop):
            blank = [f"{a}..{b - 1}" for a, b in ((start, lo), (hi, stop)) if b > a]
            said.append(f"{p.name}: frames {' and '.join(blank)} are blank (one flat "
                        "colour: black, or a fade)")
        said[-1] += f": the frames were chosen from {lo}:{hi}"
        return imgs, idx, said + again
    if len(got) < 2:
        raise InputError(f"{p}: could read {len(got)} frame(s) of the span "
                         f"{start}:{end} (truncated or unsupported video)")
    if len(got) < n:
        notes.append(f"{p.name}: {n - len(got)} window(s) had no readable frame")
    taken = ("all of them" if len(got) == end - start else
             f"{pick}, one per {(end - start) / n:.3g}-frame window")
    notes.append(f"{p.name}: {len(got)} of the {end - start} frames {start}..{end - 1} "
                 f"taken ({taken}): " + ", ".join(str(idx) for idx, _ in got))
    return [fr for _, fr in got], [idx for idx, _ in got], notes


# --- the reference ------------------------------------------------------------------
def keypoint_matches(images: Sequence[np.ndarray], *, max_side: int = 640,
                     n_features: int = 1500) -> np.ndarray:
    """(V, V) int: SIFT matches passing Lowe's ratio test (0.75) between every pair."""
    sift = cv2.SIFT_create(nfeatures=n_features)
    desc = []
    for im in images:
        g = cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)
        f = min(1.0, max_side / max(g.shape))
        if f < 1.0:
            g = cv2.resize(g, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
        desc.append(sift.detectAndCompute(g, None)[1])
    V = len(images)
    M = np.zeros((V, V), np.int64)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    for i in range(V):
        for j in range(i + 1, V):
            if desc[i] is None or desc[j] is None or len(desc[i]) < 2 or len(desc[j]) < 2:
                continue
            pairs = bf.knnMatch(desc[i], desc[j], k=2)
            M[i, j] = M[j, i] = sum(1 for m in pairs
                                    if len(m) == 2 and m[0].distance < 0.75 * m[1].distance)
    return M


def auto_reference(images: Sequence[np.ndarray], names: Sequence[str],
                   valid: Sequence[np.ndarray | None] | None = None
                   ) -> tuple[int, str, dict]:
    """``--ref auto``: the frame with the most keypoint matches among the sharp ones.

    Sharp: variance of the Laplacian at least half the sharpest frame's. Returns
    the index, a one-line note and the figures (for the report).
    """
    valid = list(valid) if valid else [None] * len(images)
    sharp = [sharpness(im, v) for im, v in zip(images, valid)]
    M = keypoint_matches(images)
    matches = M.sum(axis=1)
    cands = [i for i in range(len(images)) if sharp[i] >= 0.5 * max(sharp)]
    best = max(cands, key=lambda i: (matches[i], sharp[i]))
    mid = len(images) // 2
    note = (f"--ref auto: {names[best]} (sharpness {sharp[best]:.0f}, {int(matches[best])} "
            f"keypoint matches with the others; the middle frame {names[mid]}: "
            f"{sharp[mid]:.0f}, {int(matches[mid])})")
    info = {"sharpness": [round(s, 1) for s in sharp], "matches": matches.tolist()}
    return best, note, info


def relative_sharpness(images: Sequence[np.ndarray],
                       valid: Sequence[np.ndarray | None] | None = None) -> list[float]:
    """Each image's ``sharpness(..., relative=True)``, over its ``valid`` pixels: what
    the blurry-reference and blurry-sources notes compare (computed once for both)."""
    valid = list(valid) if valid else [None] * len(images)
    return [sharpness(im, v, relative=True) for im, v in zip(images, valid)]


def blurry_reference_note(images: Sequence[np.ndarray], ref: int, names: Sequence[str],
                          valid: Sequence[np.ndarray | None] | None = None,
                          *, ratio: float = 0.5, sharp: Sequence[float] | None = None
                          ) -> str | None:
    """A note suggesting ``--ref auto`` when the reference is much blurrier than the
    others (variance of the Laplacian relative to the image's own variance, below
    ``ratio`` x the others' median). ``sharp``: ``relative_sharpness`` of the images,
    if already computed."""
    sharp = relative_sharpness(images, valid) if sharp is None else sharp
    others = [s for i, s in enumerate(sharp) if i != ref]
    med = float(np.median(others)) if others else 0.0
    if med <= 0 or sharp[ref] >= ratio * med:
        return None
    return (f"the reference {names[ref]} is much blurrier than the others (variance of "
            f"the Laplacian over the image's, {sharp[ref]:.3f} vs a median of {med:.3f}): "
            "try --ref auto")


def blurry_sources_note(images: Sequence[np.ndarray], ref: int, names: Sequence[str],
                        valid: Sequence[np.ndarray | None] | None = None,
                        *, ratio: float = 0.5, sharp: Sequence[float] | None = None
                        ) -> str | None:
    """A note naming the sources much blurrier than the set (variance of the Laplacian
    relative to the image's own variance, below ``ratio`` x the median of all the
    photos): where one of them alone shows the background, the fill is as soft (a
    trial's tim2 with a 25 px motion blur filled part of the cup's place with a
    smooth oval, without a word). None when there is none. ``sharp``: as
    ``blurry_reference_note``'s."""
    sharp = relative_sharpness(images, valid) if sharp is None else sharp
    med = float(np.median(sharp))
    soft = [i for i, v in enumerate(sharp) if i != ref and med > 0 and v < ratio * med]
    if not soft:
        return None
    which = ", ".join(f"{names[i]} ({sharp[i]:.3f})" for i in soft)
    return (f"much blurrier than the other photos (variance of the Laplacian over the "
            f"image's, median {med:.3f}): {which}; where only such a photo shows the "
            "background, the fill is as soft: leave it out if the set has enough without")


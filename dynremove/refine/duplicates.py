"""Near-copies of the reference: sources that carry no independent evidence.

When a subject pauses during a burst, some photos are near-copies of the
reference: the mover stands in the same place. The scan's consensus counts
every source once, so two or three such copies out-vote the views that saw the
background and the mover is called static (measured on DAVIS camel with two
near-copies among six sources: J 0.76 → 0.07). A near-copy is detected after
alignment by the homography: the share of its pixels (inside its frame) whose
colour agrees with the reference (CIE76 ΔE < ``de_max`` after a σ 1.5 px blur,
at half resolution). Ordinary views of a hand-held set disagree on a few
percent at least (the mover itself, parallax, shake); a copy agrees almost
everywhere.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.refine.colour import delta_e
from dynremove.refine.fields import blurred_lab


def agreement_with_reference(reference: npt.NDArray[np.uint8],
                             sources: npt.NDArray[np.uint8],
                             homographies: list[npt.NDArray[np.float64]], *,
                             de_max: float = 5.0, min_overlap: float = 0.25,
                             overlap: npt.NDArray[np.float64] | None = None
                             ) -> npt.NDArray[np.float64]:
    """Share of each source's aligned pixels that agree with the reference.

    Parameters
    ----------
    reference : (H, W, 3) uint8 ndarray
    sources : (S, H, W, 3) uint8 ndarray
    homographies : list of S (3, 3) float64 ndarrays
        Reference → source (``TwoView.H``).
    de_max : float
        CIE76 distance under which two pixels agree.
    min_overlap : float
        A source that covers less of the reference's frame than this (aligned) gets 0.
    overlap : (S,) float64 ndarray, optional
        Filled with the share of the reference's frame each source covers.

    Returns
    -------
    agree : (S,) float64 ndarray in [0, 1]
        Over the pixels the source covers.
    """
    H, W = reference.shape[:2]
    h, w = max(8, H // 2), max(8, W // 2)
    S_half = np.diag([w / W, h / H, 1.0])

    lab_r = blurred_lab(cv2.resize(reference, (w, h), interpolation=cv2.INTER_AREA), 1.5)
    out = np.zeros(len(sources))
    for k, src in enumerate(sources):
        Hh = S_half @ homographies[k] @ np.linalg.inv(S_half)
        small = cv2.resize(src, (w, h), interpolation=cv2.INTER_AREA)
        warped = cv2.warpPerspective(small, Hh, (w, h),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        inside = cv2.warpPerspective(np.ones((h, w), np.uint8), Hh, (w, h),
                                     flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
        inside = cv2.erode(inside, np.ones((5, 5), np.uint8)).astype(bool)
        if overlap is not None:
            overlap[k] = float(inside.mean())
        if inside.sum() < min_overlap * h * w:
            continue
        d = delta_e(blurred_lab(warped, 1.5), lab_r)
        out[k] = float((d[inside] < de_max).mean())
    return out


MIN_COPY_OVERLAP = 0.9  # a source is a copy of another only where it covers this much of it


def duplicate_sources(sources: npt.NDArray[np.uint8],
                      homographies: list[npt.NDArray[np.float64]], agree_min: float
                      ) -> list[tuple[int, int, float]]:
    """Sources that are near-copies of an earlier source: the same evidence twice.

    Source j is a copy of source k < j when, aligned to k (``H_j H_k⁻¹``: source k
    → reference → source j), at least ``agree_min`` of its pixels agree with k's
    (``agreement_with_reference`` with k as the reference) and it covers at least
    ``MIN_COPY_OVERLAP`` of k's frame (a source panned away from k shows what k
    does not: a trial's 300-frame pan dropped frame 298 as a copy of frame 9, alike
    only where they overlapped). A copy of a copy counts against the first one kept.

    Returns
    -------
    list of (j, k, agreement)
        Each copy ``j``, the kept source ``k`` it copies, and their agreement.
    """
    S = len(sources)
    dropped: list[tuple[int, int, float]] = []
    gone: set[int] = set()
    for k in range(S):
        if k in gone:
            continue
        later = [j for j in range(k + 1, S) if j not in gone]
        if not later:
            break
        inv_k = np.linalg.inv(homographies[k])
        agree = agreement_with_reference(sources[k], sources[later],
                                         [homographies[j] @ inv_k for j in later],
                                         min_overlap=MIN_COPY_OVERLAP)
        for j, a in zip(later, agree):
            if a >= agree_min:
                dropped.append((j, k, float(a)))
                gone.add(j)
    return dropped


__all__ = ["agreement_with_reference", "duplicate_sources"]

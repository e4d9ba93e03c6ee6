"""Dense correspondences N_{r→s} (Sec. 3.1).

The paper uses a dense flow field; a hand-held set has large displacements, so
by default the source is first pre-warped onto the reference by the homography
H_s, and DIS optical flow (OpenCV) takes up the residual. N is stored as integer
pixel positions in the source (PatchMatch-style nearest-neighbour field), which
makes every candidate an exact pixel with exact features.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

from dynremove.method.geometry import apply_homography, sampson_sq

_DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


@functools.lru_cache(maxsize=4)
def pixel_grid(H: int, W: int) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """x and y coordinates of every pixel, two (H, W) float32 arrays, read-only.

    Made once per size and shared (a run asks for it once per source and step:
    ~10 ms each at 854×480); write to a copy."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    xs.flags.writeable = False
    ys.flags.writeable = False
    return xs, ys


def dis_flow(gray_a: npt.NDArray[np.uint8], gray_b: npt.NDArray[np.uint8], *,
             preset: str = "medium") -> npt.NDArray[np.float32]:
    """DIS optical flow a → b, (H, W, 2) float32 displacement (dx, dy)."""
    dis = cv2.DISOpticalFlow_create(_DIS_PRESETS[preset])
    return dis.calc(gray_a, gray_b, None)


def dense_correspondence(ref_gray: npt.NDArray[np.uint8], src_gray: npt.NDArray[np.uint8],
                         H_rs: npt.NDArray[np.float64], *, method: str = "homography+flow",
                         flow_preset: str = "medium",
                         gate_px: float = 0.0, F: npt.NDArray[np.float64] | None = None,
                         epipolar_px: float = 0.0,
                         flow_out: npt.NDArray[np.float32] | None = None
                         ) -> npt.NDArray[np.float32]:
    """Dense map N_{r→s}: for each reference pixel, its match in the source.

    Parameters
    ----------
    ref_gray, src_gray : (H, W) uint8 ndarray
    H_rs : (3, 3) float64 ndarray
        Homography reference → source (identity when unknown).
    method : {"homography+flow", "homography", "flow", "gated"}
        "gated": homography + flow, but the flow is kept only where it stays
        within ``gate_px`` of the homography; elsewhere (flow that followed a
        moving object) the homography's match is used. With ``F`` and
        ``epipolar_px`` > 0, flow within ``epipolar_px`` of its epipolar line is
        kept as well (parallax of a 3-D scene).
    flow_out : (H, W, 2) float32 ndarray, optional
        With "homography+flow" or "gated": receives the homography + flow
        matches before any gate (what "homography+flow" returns), so a later
        step that needs them does not run the flow again.

    Returns
    -------
    Nf : (H, W, 2) float32 ndarray
        Sub-pixel (x, y) in the source; may fall outside the source image.
        ``round_matches`` gives the integer field of the scan.
    """
    Hh, Ww = ref_gray.shape
    xs, ys = pixel_grid(Hh, Ww)
    if method == "flow":
        f = dis_flow(ref_gray, src_gray, preset=flow_preset)
        mx, my = xs + f[..., 0], ys + f[..., 1]
    elif method == "homography":
        mx, my = apply_homography(H_rs, xs, ys)
    else:  # "homography+flow" and "gated"
        # warped(x) = src(H_rs x): the source brought into the reference frame
        warped = cv2.warpPerspective(src_gray, H_rs, (Ww, Hh),
                                     flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                     borderMode=cv2.BORDER_REPLICATE)
        f = dis_flow(ref_gray, warped, preset=flow_preset)
        mx, my = apply_homography(H_rs, xs + f[..., 0], ys + f[..., 1])
        if flow_out is not None:
            flow_out[..., 0], flow_out[..., 1] = mx, my
        if method == "gated":
            hx, hy = apply_homography(H_rs, xs, ys)
            far = np.hypot(mx - hx, my - hy) > gate_px
            if F is not None and epipolar_px > 0:
                # parallax moves matches along epipolar lines: keep those flows too
                on_line = sampson_sq(F, np.stack([xs, ys], -1),
                                     np.stack([mx, my], -1)) <= epipolar_px ** 2
                far &= ~on_line
            mx, my = np.where(far, hx, mx), np.where(far, hy, my)
    return np.stack([mx, my], axis=-1).astype(np.float32)


def round_matches(Nf: npt.NDArray[np.float32]) -> npt.NDArray[np.int32]:
    """Sub-pixel matches (..., 2) float → the integer pixel field N used by the scan."""
    big = 1 << 20
    return np.clip(np.rint(Nf), -big, big).astype(np.int32)

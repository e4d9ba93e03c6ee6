"""Background displacement fields across L, sampling through them, source votes.

Inside a moving object the correspondences followed the object; outside it
they follow the background. Each source's sub-pixel displacement field is
re-interpolated across L from the static pixels around it as a *membrane*
(harmonic) surface, solved coarse to fine (``harmonic_fill``). A plane's
displacement is locally close to linear, and a harmonic fill reproduces a
linear field exactly, where a normalised Gaussian blur (``interpolate_field``)
leans towards the side with more valid pixels (measured in the README: +0.8 dB
inside the mask).

``source_votes`` gives, at each pixel, the Lab distance between the reference
and every source sampled through the interpolated field; the mask refinement
(``mask.refine_mask``) reads them.
"""

from __future__ import annotations

import threading

import cv2
import numba
import numpy as np
import numpy.typing as npt

from dynremove.method.correspondence import pixel_grid
from dynremove.refine.concurrency import for_each_source


def interpolate_field(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                      need: npt.NDArray[np.bool_] | None = None) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole``: normalised Gaussian convolution.

    A quick, smooth, but biased estimate; ``harmonic_fill`` uses it as the
    coarsest level. A hole pixel takes its value at the first, smallest blur
    that reaches it; with ``need`` (H, W) bool, the blurs stop once every hole
    pixel of ``need`` has one (the others may stay unfilled).
    """
    out = field.copy()
    valid = (~hole).astype(np.float32)
    todo = hole.copy()
    if not valid.any():
        return out
    need = hole if need is None else need
    for sigma in (2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0):
        if not (todo & need).any():
            break
        g = _gaussian_taps(sigma, max(field.shape[:2]))
        w = cv2.sepFilter2D(valid, -1, g, g, borderType=cv2.BORDER_CONSTANT)
        ok = todo & (w > 1e-3)
        if not ok.any():
            continue
        for c in range(field.shape[2]):
            num = cv2.sepFilter2D(field[..., c] * valid, -1, g, g,
                                  borderType=cv2.BORDER_CONSTANT)
            out[..., c][ok] = num[ok] / w[ok]
        todo &= ~ok
    return out


def _gaussian_taps(sigma: float, n: int) -> npt.NDArray[np.float32]:
    """The taps of ``cv2.GaussianBlur(img, (k, k), sigma)`` for float32 images, k = 6σ
    rounded up to odd, cut to the 2n − 1 that can reach a pixel of an image whose
    longer side is ``n`` (beyond, every tap meets the constant border's zeros).
    ``sepFilter2D`` with them equals ``GaussianBlur`` with ``BORDER_CONSTANT``
    bit for bit (the taps' order from the centre is kept), without a border of
    k / 2 px on every side: σ = 128 px on a 38×50 image padded it to 806×818."""
    k = int(6 * sigma) | 1
    g = cv2.getGaussianKernel(k, sigma, cv2.CV_32F)
    c = k // 2
    return g[max(c - (n - 1), 0):c + n]


def harmonic_fill(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                  iters: int = 40, need: npt.NDArray[np.bool_] | None = None
                  ) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole`` with the membrane (Laplace) solution.

    Each channel is solved on its own arithmetic, so from the main thread the
    channels are split in two halves solved on two threads (``for_each_source``;
    OpenCV and the compiled sweeps release the GIL): the same values, bit for bit
    (the blend's six 6-channel membranes of the bench scene: 0.33 -> 0.27 s in all;
    OpenCV's blurs inside already use both cores).
    See ``_harmonic_fill`` for the method and the parameters.
    """
    C = field.shape[2]
    if C >= _SPLIT_CHANNELS and threading.current_thread() is threading.main_thread():
        cuts = [slice(0, C // 2), slice(C // 2, C)]
        parts = for_each_source(lambda k: _harmonic_fill(field[..., cuts[k]], hole,
                                                         iters=iters, need=need), 2)
        return np.concatenate(parts, axis=-1)
    return _harmonic_fill(field, hole, iters=iters, need=need)


# from this many channels up, ``harmonic_fill`` solves two halves on two threads
_SPLIT_CHANNELS = 4


def _harmonic_fill(field: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                   iters: int = 40, need: npt.NDArray[np.bool_] | None = None
                   ) -> npt.NDArray[np.float32]:
    """Fill ``field`` (H, W, C) where ``hole`` with the membrane (Laplace) solution.

    Coarse to fine: the field is area-averaged over its valid pixels to half
    size (a coarse pixel is a hole if any of its fine pixels is), solved there,
    upsampled as the starting point, and relaxed by ``iters`` Jacobi sweeps.
    Valid pixels are never changed.

    With ``need``, the result is that solve's only at the pixels of ``need``
    (bit for bit): at each level the Jacobi sweeps run only inside boxes around
    the pixels that decide ``need``: after ``iters`` sweeps a
    pixel depends on the pixels within ``iters`` steps of it, and on the coarse
    solution under them. A box edge that the full solve does not have is
    ``iters + 1`` px or more from every pixel kept. Elsewhere the values are
    left as the coarse start (not the membrane).

    Parameters
    ----------
    field : (H, W, C) float32 ndarray
    hole : (H, W) bool ndarray
    need : (H, W) bool ndarray, optional
        Where the result must be the solve's (default: every pixel).

    Returns
    -------
    out : (H, W, C) float32 ndarray
    """
    H, W = hole.shape
    need = hole if need is None else need
    if not hole.any() or hole.all():
        return field.copy()
    if min(H, W) < 24:
        return interpolate_field(field, hole, need=need)
    valid = (~hole).astype(np.float32)
    h2, w2 = (H + 1) // 2, (W + 1) // 2
    cvalid = cv2.resize(valid, (w2, h2), interpolation=cv2.INTER_AREA)
    chole = cvalid < 0.999
    if chole.all():
        return interpolate_field(field, hole, need=need)
    cfield = np.empty((h2, w2, field.shape[2]), np.float32)
    for c in range(field.shape[2]):
        cfield[..., c] = cv2.resize(field[..., c] * valid, (w2, h2),
                                    interpolation=cv2.INTER_AREA) / np.maximum(cvalid, 1e-6)
    del valid
    # the sweeps' box in harmonic_fill: the holes' bounding box, 1 px wider
    rows, cols = np.flatnonzero(hole.any(1)), np.flatnonzero(hole.any(0))
    y0, y1 = max(rows[0] - 1, 0), min(rows[-1] + 2, H)
    x0, x1 = max(cols[0] - 1, 0), min(cols[-1] + 2, W)
    boxes = mask_boxes(need & hole, iters + 1, (y0, y1, x0, x1))
    if not boxes:  # every pixel of need is a valid one: never changed
        return field.copy()
    # the coarse pixels the bilinear start reads inside the boxes
    cneed = np.zeros((h2, w2), bool)
    for (by0, by1, bx0, bx1), _ in boxes:
        cneed[max(by0 // 2 - 2, 0):(by1 + 1) // 2 + 2,
              max(bx0 // 2 - 2, 0):(bx1 + 1) // 2 + 2] = True
    coarse = _harmonic_fill(np.where(chole[..., None], 0, cfield).astype(np.float32), chole,
                           iters=iters, need=cneed)
    out = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_LINEAR).reshape(H, W, -1)
    # the valid pixels as given (cv2.copyTo with a mask: the copy that
    # ``out[~hole] = field[~hole]`` makes, ~50× faster at 854×480)
    out = cv2.copyTo(np.ascontiguousarray(field, np.float32), (~hole).astype(np.uint8),
                     out).reshape(H, W, -1)
    for (by0, by1, bx0, bx1), keep in boxes:
        # the sweeps move the holes' pixels only, so they visit only those: the
        # box's rows as runs of hole pixels
        sub_hole = hole[by0:by1, bx0:bx1]
        sub = out[by0:by1, bx0:bx1]
        C = sub.shape[2]
        flat = sub.reshape(sub.shape[0], -1)
        edge = np.diff(np.pad(sub_hole.astype(np.int8), ((0, 0), (1, 1))), axis=1)
        ry, rx0 = np.nonzero(edge == 1)
        rx1 = np.nonzero(edge == -1)[1]
        done = _jacobi_sweeps(flat, C, ry.astype(np.int32), (rx0 * C).astype(np.int32),
                              (rx1 * C).astype(np.int32), iters)
        np.copyto(sub, done.reshape(sub.shape), where=keep[..., None])
    return out


@numba.njit(cache=True, nogil=True)
def _jacobi_sweeps(flat, C, ry, rx0, rx1, iters):
    """``iters`` Jacobi sweeps of the membrane on the runs of hole pixels (row
    ``ry``, columns ``rx0 // C`` to ``rx1 // C`` exclusive) of ``flat`` (h, w·C)
    float32, an (h, w, C) box with its channels side by side; returns the swept
    box (``flat`` is not changed). Each hole pixel becomes the mean of its 4
    neighbours (the box's edge replicated), all from the previous sweep's values;
    the other pixels are fixed. The same sums as ``cv2.filter2D`` with the
    4-neighbour cross of weights 1/4 (up, left, right, down), bit for bit."""
    h, wc = flat.shape
    # two buffers with a replicated 1-px frame: the inner loops need no bounds
    a = np.empty((h + 2, wc + 2 * C), np.float32)
    a[1:h + 1, C:wc + C] = flat
    b = a.copy()
    q = np.float32(0.25)
    for _ in range(iters):
        a[0, C:wc + C] = a[1, C:wc + C]
        a[h + 1, C:wc + C] = a[h, C:wc + C]
        for y in range(h + 2):
            for c in range(C):
                a[y, c] = a[y, C + c]
                a[y, wc + C + c] = a[y, wc + c]
        for r in range(ry.shape[0]):
            y = ry[r] + 1
            _sweep_run(a[y - 1], a[y], a[y + 1], b[y], rx0[r] + C, rx1[r] + C, C, q)
        a, b = b, a
    return a[1:h + 1, C:wc + C].copy()


@numba.njit(cache=True, nogil=True)
def _sweep_run(up, mid, down, dst, lo, hi, C, q):
    """One run of ``_jacobi_sweeps`` (on slices, which the compiler vectorises:
    indexing the rows directly runs ~7× slower)."""
    u, d, o = up[lo:hi], down[lo:hi], dst[lo:hi]
    left, right = mid[lo - C:hi - C], mid[lo + C:hi + C]
    for i in range(hi - lo):
        s = q * u[i]
        s += q * left[i]
        s += q * right[i]
        s += q * d[i]
        o[i] = s


def mask_boxes(need: npt.NDArray[np.bool_], margin: int, bounds: tuple[int, int, int, int],
               *, block: int = 8) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
    """Boxes (inside ``bounds`` = y0, y1, x0, x1) that hold ``need`` with ``margin``.

    For local operations on a sparse mask (``need`` inside ``bounds``): a box
    edge that is not one of ``bounds`` is at least ``margin`` px from the pixels
    the box keeps. ``need`` is grouped on a grid of ``block`` px, and blocks
    within ``margin`` of each other share a box.

    Returns
    -------
    boxes : list of ((y0, y1, x0, x1), (h, w) bool ndarray)
        Each box, and the pixels of ``need`` it keeps (box coordinates); every
        pixel of ``need`` is kept by exactly one box.
    """
    H, W = need.shape
    if not need.any():
        return []
    nb_y, nb_x = -(-H // block), -(-W // block)
    pad = np.zeros((nb_y * block, nb_x * block), bool)
    pad[:H, :W] = need
    blocks = pad.reshape(nb_y, block, nb_x, block).any(axis=(1, 3)).astype(np.uint8)
    r = -(-margin // block)
    grown = cv2.dilate(blocks, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    n, comp, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8)
    Y0, Y1, X0, X1 = bounds
    out = []
    for i in range(1, n):
        bx, by, bw, bh = stats[i, :4]
        y0, y1 = max(by * block, Y0), min((by + bh) * block, Y1)
        x0, x1 = max(bx * block, X0), min((bx + bw) * block, X1)
        mine = np.repeat(np.repeat(comp[by:by + bh, bx:bx + bw] == i, block, 0), block, 1)
        keep = need[y0:y1, x0:x1] & mine[y0 - by * block:y1 - by * block,
                                         x0 - bx * block:x1 - bx * block]
        out.append(((y0, y1, x0, x1), keep))
    return out


def background_field(Nf: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_]
                     ) -> npt.NDArray[np.float32]:
    """Matches (H, W, 2) with the *displacement* re-interpolated across ``hole``."""
    return background_fields([Nf], hole)[0]


def background_fields(Nf, hole: npt.NDArray[np.bool_]) -> list[npt.NDArray[np.float32]]:
    """``[background_field(f, hole) for f in Nf]`` in one membrane solve.

    The solve is linear and the same for every field given the same ``hole``, so
    the S fields (each (H, W, 2) float32) are solved as the 2·S channels of one
    field: one coarse-to-fine pass and one set of sweeps instead of S (each
    channel's arithmetic unchanged, results bit for bit those of S calls).
    """
    if len(Nf) == 0:
        return []
    grid = np.stack(pixel_grid(*hole.shape), axis=-1)
    disp = np.concatenate([f - grid for f in Nf], axis=-1)
    out = harmonic_fill(disp, hole)
    return [out[..., 2 * k:2 * k + 2] + grid for k in range(len(Nf))]


def sample_bilinear(src: npt.NDArray[np.uint8], field: npt.NDArray[np.float32]):
    """Bilinear sample of ``src`` at ``field``; returns (image, inside)."""
    H, W = src.shape[:2]
    mx, my = np.ascontiguousarray(field[..., 0]), np.ascontiguousarray(field[..., 1])
    warped = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (mx >= 0) & (mx <= W - 1) & (my >= 0) & (my <= H - 1)
    return warped, inside


def remap_points(src: np.ndarray, mx: np.ndarray, my: np.ndarray,
                 interpolation: int = cv2.INTER_LINEAR, *, cols: int = 4096, **kw
                 ) -> np.ndarray:
    """``cv2.remap`` of ``src`` at a list of ``N`` points (``mx``, ``my``): (N,) or
    (N, C), the values the dense remap gives there. OpenCV's remap takes fewer than
    32767 rows, so the points are laid out in rows of ``cols``; ``kw`` goes to it
    (``borderMode``, ``borderValue``)."""
    n = len(mx)
    rows = max(1, -(-n // cols))
    maps = []
    for m in (mx, my):
        block = np.zeros(rows * cols, np.float32)
        block[:n] = m
        maps.append(block.reshape(rows, cols))
    out = cv2.remap(src, maps[0], maps[1], interpolation, **kw)
    return out.reshape((rows * cols,) + out.shape[2:])[:n]


def blurred_lab(img: npt.NDArray[np.uint8], blur_sigma: float) -> npt.NDArray[np.float32]:
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    return cv2.cvtColor(img.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)


def source_votes(reference: npt.NDArray[np.uint8], sources: npt.NDArray[np.uint8],
                 Nf: npt.NDArray[np.float32], hole: npt.NDArray[np.bool_], *,
                 blur_sigma: float = 1.0) -> npt.NDArray[np.float32]:
    """Per-source Lab distance to the reference through the background field.

    Returns
    -------
    D : (S, H, W) float32 ndarray
        CIE Lab distance (both images blurred by ``blur_sigma`` px) between the
        reference and source ``s`` sampled at its match, the matches being
        re-interpolated across ``hole``; ``inf`` where the match falls outside
        the source.
    """
    lab_r = blurred_lab(reference, blur_sigma)
    D = np.empty((len(sources),) + hole.shape, np.float32)
    fields = background_fields(Nf, hole)

    def vote(s):
        warped, inside = sample_bilinear(sources[s], fields[s])
        d = np.sqrt(((blurred_lab(warped, blur_sigma) - lab_r) ** 2).sum(-1))
        D[s] = np.where(inside, d, np.inf)

    for_each_source(vote, len(sources))
    return D


__all__ = ["interpolate_field", "harmonic_fill", "mask_boxes", "background_field",
           "background_fields",
           "remap_points", "sample_bilinear",
           "blurred_lab", "source_votes"]

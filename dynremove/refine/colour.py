"""CIE76 colour differences, compiled: the fill's most repeated arithmetic.

The selection compares every candidate with the reference, with the consensus
and with every other candidate, each time as ``np.linalg.norm(a - b, axis=-1)``
over Lab triples. NumPy's reduction over a last axis of length 3 is slow (a
strided reduce per pixel); the kernel here does the subtraction, the squares and
the root in one pass on all cores, in the same order of operations, so that its
results equal NumPy's bit for bit (checked in ``tests/test_colour.py``).
"""

from __future__ import annotations

import threading

import numba
import numpy as np
import numpy.typing as npt


def _delta_e_loop(a, b, out):
    """out[i] = |a[i] - b[i % M]| for a (N, 3), b (M, 3), N a multiple of M,
    as NumPy's norm computes it: sqrt((x² + y²) + z²)."""
    m = b.shape[0]
    for i in numba.prange(a.shape[0]):
        j = i % m
        x = a[i, 0] - b[j, 0]
        y = a[i, 1] - b[j, 1]
        z = a[i, 2] - b[j, 2]
        out[i] = np.sqrt((x * x + y * y) + z * z)


# on all cores from the main thread; serial from the fill's per-source threads
# (numba's fallback "workqueue" threading layer allows no concurrent launches)
_delta_e_parallel = numba.njit(cache=True, nogil=True, parallel=True)(_delta_e_loop)
_delta_e_serial = numba.njit(cache=True, nogil=True)(_delta_e_loop)


def delta_e(a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """CIE76 ΔE ``|a - b|`` over the last axis (length 3) of two Lab arrays.

    Parameters
    ----------
    a, b : (..., 3) float ndarrays
        Broadcastable against each other (NumPy rules).

    Returns
    -------
    (...) ndarray of the broadcast shape, float32 when both inputs are float32
    (float64 otherwise), equal bit for bit to ``np.linalg.norm(a - b, axis=-1)``.

    Raises
    ------
    ValueError
        When the last axis is not of length 3 or the shapes do not broadcast.
    """
    a, b = np.asarray(a), np.asarray(b)
    if a.shape[-1:] != (3,) or b.shape[-1:] != (3,):
        raise ValueError(f"delta_e needs (..., 3) arrays, got {a.shape} and {b.shape}")
    dtype = np.result_type(a, b, np.float32)
    shape = np.broadcast_shapes(a.shape, b.shape)
    if a.shape != shape:  # ΔE is symmetric: the full-shape operand goes first
        a, b = b, a
    if a.shape != shape:
        a = np.broadcast_to(a, shape)
    # b repeats along a's leading axes when what it holds is a trailing block of
    # the shape (a source against the reference, the consensus); else in full
    bs = (1,) * (len(shape) - b.ndim) + b.shape
    k = next(i for i in range(len(shape)) if bs[i:] == shape[i:])
    if any(n != 1 for n in bs[:k]):
        b = np.broadcast_to(b, shape)
    a2 = np.ascontiguousarray(a, dtype).reshape(-1, 3)
    b2 = np.ascontiguousarray(b, dtype).reshape(-1, 3)
    out = np.empty(a2.shape[0], dtype)
    if out.size and b2.shape[0]:
        kernel = (_delta_e_parallel if threading.current_thread() is threading.main_thread()
                  else _delta_e_serial)
        kernel(a2, b2, out)
    return out.reshape(shape[:-1])


def _pairwise_loop(v, out):
    """out[a, b, i] = out[b, a, i] = |v[a, i] - v[b, i]| for v (K, N, 3), as ``_delta_e_loop``."""
    K = v.shape[0]
    for i in numba.prange(v.shape[1]):
        for a in range(K):
            out[a, a, i] = 0.0
            for b in range(a + 1, K):
                x = v[a, i, 0] - v[b, i, 0]
                y = v[a, i, 1] - v[b, i, 1]
                z = v[a, i, 2] - v[b, i, 2]
                d = np.sqrt((x * x + y * y) + z * z)
                out[a, b, i] = d
                out[b, a, i] = d


_pairwise_parallel = numba.njit(cache=True, nogil=True, parallel=True)(_pairwise_loop)
_pairwise_serial = numba.njit(cache=True, nogil=True)(_pairwise_loop)


def pairwise_delta_e(values: npt.NDArray[np.floating]) -> np.ndarray:
    """``(K, K, ...)`` ΔE between every pair of ``values`` (K, ..., 3), 0 on the
    diagonal; equal bit for bit to ``np.linalg.norm(v[:, None] - v[None], axis=-1)``."""
    values = np.asarray(values)
    K = len(values)
    dtype = np.result_type(values, np.float32)
    rest = values.shape[1:-1]
    v = np.ascontiguousarray(values, dtype).reshape(K, -1, 3)
    out = np.empty((K, K, v.shape[1]), dtype)
    if out.size:
        kernel = (_pairwise_parallel if threading.current_thread() is threading.main_thread()
                  else _pairwise_serial)
        kernel(v, out)
    return out.reshape((K, K) + rest)


__all__ = ["delta_e", "pairwise_delta_e"]

"""Jacobi sweeps of Laplace's equation over a region of an image, in one numba kernel: the
smoothing of :func:`facetransfer.composite.membrane_blend`'s membrane.

A sweep sets every pixel of the region to the mean of its 4 neighbours as the sweep before left
them (beyond the box the image's edge pixels are replicated); pixels outside the region keep
their values. The arithmetic is that of ``cv2.filter2D`` with the kernel ``[[0, 1/4, 0], [1/4,
0, 1/4], [0, 1/4, 0]]`` (float32, ``BORDER_REPLICATE``) followed by a masked copy, which the
sweeps were: the neighbours' quarters (exact products: a power of two) added to zero in the
kernel's row-major order (above, left, right, below), in float32, so the result is the same to
the bit, without two calls per sweep that hold the interpreter.
"""

from __future__ import annotations

import numpy as np

from .errors import ShapeError
from .jit import maybe_njit as _maybe_njit

__all__ = ["jacobi_sweeps"]


def jacobi_sweeps(h: np.ndarray, inner: np.ndarray, origin: tuple[int, int],
                  iterations: int) -> None:
    """``iterations`` Jacobi sweeps of Laplace's equation over a region, in place.

    Parameters
    ----------
    h : (H, W, 3) float32, C-contiguous
        The image; only its box ``[y0:y0 + h, x0:x0 + w]`` is read and written.
    inner : (h, w) bool or uint8
        The region within the box (the pixels a sweep sets).
    origin : (y0, x0)
        The box's top-left pixel in ``h``.
    iterations : int
        Sweeps (none when <= 0).
    """
    y0, x0 = int(origin[0]), int(origin[1])
    m = np.ascontiguousarray(inner).view(np.uint8)
    if (h.dtype != np.float32 or h.ndim != 3 or h.shape[2] != 3 or not h.flags.c_contiguous
            or m.ndim != 2 or y0 < 0 or x0 < 0 or y0 + m.shape[0] > h.shape[0]
            or x0 + m.shape[1] > h.shape[1]):
        raise ShapeError(f"jacobi_sweeps: h must be a C-contiguous (H, W, 3) float32 image "
                         f"holding the region's box, got {h.shape} {h.dtype} and a box of "
                         f"{m.shape} at {(y0, x0)}")
    if iterations > 0 and m.size:
        _sweeps_kernel(h, m, y0, x0, int(iterations),
                       np.empty((int(iterations), 3, 3 * m.shape[1]), np.float32))


def _sweeps_kernel_py(h, inner, y0, x0, iterations, rings):  # pragma: no cover (numba)
    """:func:`jacobi_sweeps` with the scratch ``rings`` (iterations, 3, 3 w) float32: the
    sweeps pipelined down the box, sweep ``k`` a row behind sweep ``k - 1`` (it needs that
    sweep's rows above, at and below its own), each sweep's last three rows kept in its ring
    (row ``y`` in slot ``y % 3``: the region's pixels the sums, the rest as they were), the
    first sweep reading ``h`` itself and the last sweep's row ``y`` written back once the first
    has made row ``y + max(iterations, 2)`` (no sweep reads ``h``'s row ``y`` after that). The
    box is read from memory once, not once a sweep; every value is the same sum of the same
    values as sweep after sweep over the whole box."""
    H, W = inner.shape
    n = iterations
    hf = h.reshape(h.size)
    lag = max(n, 2)  # the last sweep's row y written back once the first has read it
    for t in range(H + lag):
        for k in range(n):
            y = t - k
            if y < 0 or y >= H:
                continue
            out = rings[k, y % 3]
            row = np.uint64(3 * ((y0 + y) * h.shape[1] + x0))
            if k == 0:
                up = np.uint64(3 * ((y0 + max(y - 1, 0)) * h.shape[1] + x0))
                dn = np.uint64(3 * ((y0 + min(y + 1, H - 1)) * h.shape[1] + x0))
                _sums(hf[up:up + np.uint64(3 * W)], hf[row:row + np.uint64(3 * W)],
                      hf[dn:dn + np.uint64(3 * W)], out)
            else:
                src = rings[k - 1]
                _sums(src[max(y - 1, 0) % 3], src[y % 3], src[min(y + 1, H - 1) % 3], out)
            for x in range(W):  # outside the region: the values as they were
                if not inner[y, x]:
                    for c in range(3):
                        out[3 * x + c] = hf[row + np.uint64(3 * x + c)]
        y = t - lag
        if 0 <= y < H:
            row = np.uint64(3 * ((y0 + y) * h.shape[1] + x0))
            last = rings[n - 1, y % 3]  # outside the region it holds the values as they were
            for i in range(3 * W):
                hf[row + np.uint64(i)] = last[i]


def _sums_py(up, row, dn, out):  # pragma: no cover (numba, inlined)
    """``out`` (3 w,) = the 4 neighbours' mean (:func:`_mean4`) of each channel value of the
    row ``row`` (3 w,) between the rows ``up`` and ``dn``: the left and right neighbours
    replicated at the row's ends; between them a loop without branches, on unsigned indices
    (one the compiler vectorises)."""
    L = row.shape[0]
    W = L // 3
    for x in (0, W - 1):
        for c in range(3):
            j = 3 * x + c
            out[j] = _mean4(up[j], row[3 * max(x - 1, 0) + c], row[3 * min(x + 1, W - 1) + c],
                            dn[j])
    for i in range(3, L - 3):
        j = np.uint64(i)
        out[j] = _mean4(up[j], row[j - np.uint64(3)], row[j + np.uint64(3)], dn[j])


def _mean4_py(a, b, c, d):  # pragma: no cover (numba, inlined)
    """``filter2D``'s sum of the 4 neighbours' quarters: ``0 + a/4 + b/4 + c/4 + d/4`` in
    float32, in this order (above, left, right, below)."""
    q = np.float32(0.25)
    return (((np.float32(0.0) + a * q) + b * q) + c * q) + d * q


_mean4 = _maybe_njit(_mean4_py, inline=True)
_sums = _maybe_njit(_sums_py, inline=True)
_sweeps_kernel = _maybe_njit(_sweeps_kernel_py)

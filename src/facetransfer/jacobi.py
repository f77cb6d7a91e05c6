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
from .render.raster import _maybe_njit

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
        _sweeps_kernel(h, m, y0, x0, int(iterations), np.empty((2, 3 * m.shape[1]), np.float32))


def _sweeps_kernel_py(h, inner, y0, x0, iterations, new):  # pragma: no cover (numba)
    """:func:`jacobi_sweeps` with the scratch ``new`` (2, 3 w) float32: each sweep's sums a
    row at a time on its channels' flat run (a loop without branches between the row's ends,
    on unsigned indices: one the compiler vectorises), into one of two scratch rows; a row
    is written back at the region's pixels once the next row's sums have read it (the rows
    before it are no longer read by the sweep), so the sweep reads only the values of the
    one before, without a scratch image as large as the box (in the cache, not memory)."""
    H, W = inner.shape
    hf = h.reshape(h.size)
    for _ in range(iterations):
        for y in range(H):
            nr = new[y % 2]
            up = np.uint64(3 * ((y0 + max(y - 1, 0)) * h.shape[1] + x0))
            row = np.uint64(3 * ((y0 + y) * h.shape[1] + x0))
            dn = np.uint64(3 * ((y0 + min(y + 1, H - 1)) * h.shape[1] + x0))
            for x in (0, W - 1):  # the row's ends: their left or right neighbour replicated
                for c in range(3):
                    j = np.uint64(3 * x + c)
                    jl = np.uint64(3 * max(x - 1, 0) + c)
                    jr = np.uint64(3 * min(x + 1, W - 1) + c)
                    nr[j] = _mean4(hf[up + j], hf[row + jl], hf[row + jr], hf[dn + j])
            for i in range(3, 3 * W - 3):
                j = np.uint64(i)
                nr[j] = _mean4(hf[up + j], hf[row + j - np.uint64(3)],
                               hf[row + j + np.uint64(3)], hf[dn + j])
            if y > 0:
                _write_row(h, inner, y0, x0, y - 1, new[(y - 1) % 2])
        _write_row(h, inner, y0, x0, H - 1, new[(H - 1) % 2])


def _write_row_py(h, inner, y0, x0, y, nr):  # pragma: no cover (numba, inlined)
    """Row ``y`` of the box set to the scratch row ``nr`` (3 w,) at the region's pixels."""
    for x in range(inner.shape[1]):
        if inner[y, x]:
            for c in range(3):
                h[y0 + y, x0 + x, c] = nr[3 * x + c]


_write_row = _maybe_njit(_write_row_py, inline=True)


def _mean4_py(a, b, c, d):  # pragma: no cover (numba, inlined)
    """``filter2D``'s sum of the 4 neighbours' quarters: ``0 + a/4 + b/4 + c/4 + d/4`` in
    float32, in this order (above, left, right, below)."""
    q = np.float32(0.25)
    return (((np.float32(0.0) + a * q) + b * q) + c * q) + d * q


_mean4 = _maybe_njit(_mean4_py, inline=True)
_sweeps_kernel = _maybe_njit(_sweeps_kernel_py)

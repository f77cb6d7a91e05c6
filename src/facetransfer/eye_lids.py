"""The closing lids' mix of the eye region (:func:`facetransfer.eyes.paint_shaded_eyes`) in two
numba kernels: each pixel's share of the closed frame, and the mix itself written into the
region's box of the eye layer.

Both take whole arrays and the box's offset (one layout, one compiled kernel each) and give
the bytes of the numpy expressions they replace, in their order of operations:

* :func:`lid_shares`: ``t = where(tid >= 0, side[maximum(tid, 0)], -1)``, then
  ``where(t >= 0, a[maximum(t, 0)], 0.0).astype(float32)``;
* :func:`mix_lids`: ``rint((1 - w[..., None]) * open + w[..., None] * closed)
  .astype(uint8)``, in float32.
"""

from __future__ import annotations

import numpy as np

from .jit import maybe_njit as _maybe_njit

__all__ = ["lid_shares", "mix_lids"]


def _lid_shares_py(tid, y0, x0, side, a, w):  # pragma: no cover (numba)
    """``w`` (h, w) float32: at the pixel ``(y0 + iy, x0 + ix)`` of the raster's ``tid`` (H, W)
    int32, ``a[side[f]]`` (float64 rounded to float32) where its triangle ``f`` is one of an
    eye's lids (``side[f] >= 0``: the eye), 0 elsewhere and on the background."""
    for iy in range(w.shape[0]):
        for ix in range(w.shape[1]):
            f = tid[np.uint64(y0 + iy), np.uint64(x0 + ix)]
            s = side[f] if f >= 0 else -1
            w[iy, ix] = np.float32(a[s]) if s >= 0 else np.float32(0.0)


def _mix_lids_py(w, closed, img, y0, x0):  # pragma: no cover (numba)
    """``img`` (H, W, 3) uint8 on the box of ``w``'s shape at ``(x0, y0)``, in place: per
    channel ``rint((1 - w) o + w c)`` in float32 of its value ``o`` and ``closed``'s ``c``
    (h, w, 3) uint8, ``w`` (h, w) float32."""
    one = np.float32(1.0)
    for iy in range(w.shape[0]):
        for ix in range(w.shape[1]):
            a = w[iy, ix]
            b = one - a
            y, x = np.uint64(y0 + iy), np.uint64(x0 + ix)
            for c in range(3):
                o = np.float32(img[y, x, c])
                v = b * o + a * np.float32(closed[iy, ix, c])
                img[y, x, c] = np.uint8(np.rint(v))


_lid_shares = _maybe_njit(_lid_shares_py)
_mix_lids = _maybe_njit(_mix_lids_py)


def lid_shares(tid: np.ndarray, box: tuple[int, int, int, int], side: np.ndarray,
               a: np.ndarray) -> np.ndarray:
    """The closed frame's share per pixel of the box ``(y0, x0, h, w)`` of a raster's
    ``tid`` (H, W) int32: ``a`` (2,) float64 (each eye's,
    :meth:`facetransfer.eyes.EyeTexture.closing`) of the eye ``side`` (F',) int8 gives the
    pixel's triangle, 0 off the lids; ``(h, w)`` float32."""
    y0, x0, h, w = box
    out = np.empty((h, w), np.float32)
    _lid_shares(np.ascontiguousarray(tid, np.int32), int(y0), int(x0),
                np.ascontiguousarray(side, np.int8),
                np.ascontiguousarray(a, np.float64), out)
    return out


def mix_lids(w: np.ndarray, closed: np.ndarray, img: np.ndarray, origin: tuple[int, int]
             ) -> None:
    """``img`` (H, W, 3) uint8 (C-contiguous), on the box of ``w``'s shape whose top-left pixel
    is ``origin = (y0, x0)``, mixed with ``closed`` (h, w, 3) uint8 by ``w`` (h, w) float32, in
    place (:func:`_mix_lids_py`)."""
    _mix_lids(np.ascontiguousarray(w, np.float32), np.ascontiguousarray(closed, np.uint8), img,
              int(origin[0]), int(origin[1]))

"""Masks and boxes of a frame's shading labels (the ``labels`` of
:func:`facetransfer.render.shade_layers`: per pixel, its triangle's flags) in one numba pass
each, for :func:`facetransfer.rewrite._shade_frame`, :func:`facetransfer.eyes._paint_eyes` and
:func:`facetransfer.jaw._paint_jaw`.

Each gives the bytes of the numpy expressions it replaces (``labels != 0``, ``np.bitwise_and(
labels, bit) != 0``, ``&=`` with the face's mask, ``&= ~ring``, ``count_nonzero``, and
:func:`facetransfer.composite.mask_box` of ``np.bitwise_and(labels, bits)``), which passed
over the face's crop two to eight times a region. The kernels take the whole labels and a
box's offset (one layout, one compiled kernel each).
"""

from __future__ import annotations

import numpy as np

from .render.raster import _maybe_njit

__all__ = ["bits_box", "bits_mask", "frame_masks"]


def _bits_box_py(labels, bits, box):  # pragma: no cover (numba)
    """``box`` (4,) int64 = ``(x0, y0, x1, y1)`` (ends exclusive) of the pixels of ``labels``
    (H, W) uint8 with a bit of ``bits`` set; ``x1 = 0`` when there is none."""
    H, W = labels.shape
    x0, y0, x1, y1 = W, H, 0, 0
    for y in range(H):
        first = -1
        last = -1
        for x in range(W):
            if labels[y, x] & bits:
                if first < 0:
                    first = x
                last = x
        if first >= 0:
            x0, x1 = min(x0, first), max(x1, last + 1)
            y0 = min(y0, y)
            y1 = y + 1
    box[0], box[1], box[2], box[3] = x0, y0, x1, y1


def _bits_mask_py(labels, face_mask, y0, x0, a, b, out):  # pragma: no cover (numba)
    """``out`` (h, w) bool on the box of its shape at ``(x0, y0)`` of ``labels`` (H, W) uint8
    and ``face_mask`` (H, W) bool: a pixel with a bit of ``a`` and a bit of ``b`` set, in the
    face; returns how many."""
    n = 0
    for iy in range(out.shape[0]):
        for ix in range(out.shape[1]):
            v = labels[y0 + iy, x0 + ix]
            m = (v & a) != 0 and (v & b) != 0 and face_mask[y0 + iy, x0 + ix]
            out[iy, ix] = m
            n += m
    return n


def _frame_masks_py(labels, mouth_bit, ring_bit, face, mouth, ring):  # pragma: no cover (numba)
    """``face = labels != 0``, ``ring = (labels & ring_bit) != 0`` and ``mouth = (labels &
    mouth_bit) != 0`` outside ``ring`` (all (H, W), bool)."""
    for y in range(labels.shape[0]):
        for x in range(labels.shape[1]):
            v = labels[y, x]
            r = (v & ring_bit) != 0
            face[y, x] = v != 0
            ring[y, x] = r
            mouth[y, x] = (v & mouth_bit) != 0 and not r


_bits_box = _maybe_njit(_bits_box_py)
_bits_mask = _maybe_njit(_bits_mask_py)
_frame_masks = _maybe_njit(_frame_masks_py)


def bits_box(labels: np.ndarray, bits: int, margin: int) -> tuple[slice, slice] | None:
    """:func:`facetransfer.composite.mask_box` of ``np.bitwise_and(labels, bits)``: the
    ``(rows, columns)`` of the box of the pixels of ``labels`` (H, W) uint8 with a bit of
    ``bits`` set, grown by ``margin`` and clipped to the image; None when there are none."""
    box = np.empty(4, np.int64)
    _bits_box(np.ascontiguousarray(labels, np.uint8), np.uint8(bits), box)
    x0, y0, x1, y1 = box.tolist()
    if x1 <= x0:
        return None
    H, W = labels.shape
    return (slice(max(y0 - margin, 0), min(y1 + margin, H)),
            slice(max(x0 - margin, 0), min(x1 + margin, W)))


def bits_mask(labels: np.ndarray, face_mask: np.ndarray, box: tuple[slice, slice], a: int,
              b: int | None = None) -> tuple[np.ndarray, int]:
    """``(mask, count)``: on the box ``(rows, columns)`` (unit steps, within the image) of
    ``labels`` (H, W) uint8, the pixels with a bit of ``a`` set (and one of ``b``) inside
    ``face_mask`` (H, W) bool, ``(h, w)`` bool, and how many: ``(np.bitwise_and(lab, a) !=
    0) & (np.bitwise_and(lab, b) != 0) & face_mask[box]`` of ``lab = labels[box]``."""
    rows, cols = box
    out = np.empty((rows.stop - rows.start, cols.stop - cols.start), bool)
    n = _bits_mask(np.ascontiguousarray(labels, np.uint8), np.ascontiguousarray(face_mask, bool),
                   int(rows.start), int(cols.start), np.uint8(a), np.uint8(a if b is None else b),
                   out)
    return out, int(n)


def frame_masks(labels: np.ndarray, mouth_bit: int, ring_bit: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(face, mouth, ring)`` (H, W) bool of ``labels`` (H, W) uint8 (:func:`_frame_masks`):
    the covered pixels, the mouth's (``mouth_bit``) outside its ring, the ring's
    (``ring_bit``; 0: none)."""
    lab = np.ascontiguousarray(labels, np.uint8)
    face, mouth, ring = (np.empty(lab.shape, bool) for _ in range(3))
    _frame_masks(lab, np.uint8(mouth_bit), np.uint8(ring_bit), face, mouth, ring)
    return face, mouth, ring

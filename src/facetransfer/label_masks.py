"""Masks and boxes of a frame's shading labels (the ``labels`` of
:func:`facetransfer.render.shade_layers`: per pixel, its triangle's flags) in one numba pass
each: the frame's masks for :func:`facetransfer.rewrite._shade_frame`, the regions' boxes for
:func:`facetransfer.eyes.paint_shaded_eyes` and :func:`facetransfer.jaw.paint_shaded_jaw`.

Each gives the bytes of the numpy expressions it replaces (``labels != 0``, ``np.bitwise_and(
labels, bit) != 0``, ``&= ~ring``: five passes over the face's crop; and
:func:`facetransfer.composite.mask_box` of ``np.bitwise_and(labels, bits)``). (The regions'
masks in the face on their boxes stay numpy's: a kernel measured twice as slow as its 3-4
vectorised calls on boxes of ~10,000 pixels.)
"""

from __future__ import annotations

import numpy as np

from .jit import maybe_njit as _maybe_njit

__all__ = ["bits_box", "frame_masks"]


def _bits_box_py(labels, bits, box):  # pragma: no cover (numba)
    """``box`` (4,) int64 = ``(x0, y0, x1, y1)`` (ends exclusive) of the pixels of ``labels``
    (H, W) uint8 with a bit of ``bits`` set; ``x1 = 0`` when there is none. (A row's labels
    or-ed first, a vectorised pass; only a row with such a pixel is searched, from each end
    up to the box found so far.)"""
    H, W = labels.shape
    x0, y0, x1, y1 = W, H, 0, 0
    for y in range(H):
        acc = np.uint8(0)
        for x in range(W):
            acc |= labels[y, x]
        if acc & bits == 0:
            continue
        for x in range(x0):
            if labels[y, x] & bits:
                x0 = x
                break
        for x in range(W - 1, x1 - 1, -1):
            if labels[y, x] & bits:
                x1 = x + 1
                break
        y0 = min(y0, y)
        y1 = y + 1
    box[0], box[1], box[2], box[3] = x0, y0, x1, y1


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


def frame_masks(labels: np.ndarray, mouth_bit: int, ring_bit: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(face, mouth, ring)`` (H, W) bool of ``labels`` (H, W) uint8 (:func:`_frame_masks`):
    the covered pixels, the mouth's (``mouth_bit``) outside its ring, the ring's
    (``ring_bit``; 0: none)."""
    lab = np.ascontiguousarray(labels, np.uint8)
    face, mouth, ring = (np.empty(lab.shape, bool) for _ in range(3))
    _frame_masks(lab, np.uint8(mouth_bit), np.uint8(ring_bit), face, mouth, ring)
    return face, mouth, ring

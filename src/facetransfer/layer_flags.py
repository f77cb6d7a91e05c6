"""The triangles' layer flags of one frame's shading (:func:`facetransfer.rewrite._shade_frame`,
the flags of :func:`facetransfer.render.shade_layers`) made in one numba kernel: a bit on every
triangle, and bits on the eye region's triangles and rim, the jaw region's and its ring's, and
the mouth's triangles and ring.

What :func:`facetransfer.eyes.eye_flags` and :func:`facetransfer.jaw.jaw_flags` or-ed into a
full array, then the mouth's triangles by index and its ring by mask (about a dozen numpy calls
a frame), in one pass: every bit is or-ed where its triangles are, so the bytes are the same.
"""

from __future__ import annotations

import numpy as np

from .errors import ShapeError
from .jit import maybe_njit as _maybe_njit

__all__ = ["MASKS", "layer_flags"]

#: The masks :func:`layer_flags` takes.
MASKS = 5
_NONE = np.zeros(0, bool)
_NO_FACES = np.zeros(0, np.int64)


def _or_mask_py(out, m, bit):  # pragma: no cover (numba, inlined)
    """``out[m] |= bit`` (``m`` (n,) bool, or empty: nothing)."""
    if m.shape[0]:
        for f in range(out.shape[0]):
            out[f] |= np.uint8(m[f]) * bit  # (no branch: vectorised)


_or_mask = _maybe_njit(_or_mask_py, inline=True)


def _layer_flags_py(out, base, m0, b0, m1, b1, m2, b2, m3, b3, m4, b4, faces,
                    face_bit):  # pragma: no cover (numba)
    """``out`` (n,) uint8: ``base``, or-ed with ``b<k>`` where ``m<k>`` (n,) bool is set (an
    empty mask: none) and with ``face_bit`` at the triangles ``faces`` (m,) int64 (negative:
    from the end, as numpy indexes); False (nothing written past ``out``) at an index out of
    range. (The masks separate arguments: one compiled kernel, no stacked copy.)"""
    n = out.shape[0]
    out[:] = base
    _or_mask(out, m0, b0)
    _or_mask(out, m1, b1)
    _or_mask(out, m2, b2)
    _or_mask(out, m3, b3)
    _or_mask(out, m4, b4)
    for j in range(faces.shape[0]):
        f = faces[j]
        if f < 0:
            f += n
        if f < 0 or f >= n:
            return False
        out[f] |= face_bit
    return True


_layer_flags = _maybe_njit(_layer_flags_py)


def layer_flags(n: int, base: int, masks: list, faces: np.ndarray | None = None,
                face_bit: int = 0) -> np.ndarray:
    """``(n,) uint8``: ``base`` on every triangle, or-ed with ``bit`` on the triangles of each
    ``(mask (n,) bool or None, bit)`` of ``masks`` (at most :data:`MASKS`; None: none) and
    with ``face_bit`` on the triangles ``faces`` (indices, as numpy indexes them);
    ShapeError for a mask of another length or an index out of range."""
    if len(masks) > MASKS:
        raise ShapeError(f"layer_flags takes at most {MASKS} masks, got {len(masks)}")
    args = []
    for m, bit in list(masks) + [(None, 0)] * (MASKS - len(masks)):
        m = _NONE if m is None else np.ascontiguousarray(m, bool)
        if m.shape != (n,) and m is not _NONE:
            raise ShapeError(f"a triangle mask must be ({n},) bool, got {m.shape}")
        args += [m, np.uint8(bit)]
    idx = _NO_FACES if faces is None else np.ascontiguousarray(faces, np.int64).reshape(-1)
    out = np.empty(n, np.uint8)
    if not _layer_flags(out, np.uint8(base), *args, idx, np.uint8(face_bit)):
        raise ShapeError(f"triangle indices must lie within the {n} triangles")
    return out

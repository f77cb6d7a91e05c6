"""Small pure geometry shared across stages: barycentric coordinates in image or UV space.

Arrays in, arrays out, no dependence on the rest of the package, so that :mod:`facetransfer.texture`
(texel points, the z-buffer test of Eq. (L1)) and :mod:`facetransfer.correspond.detect` (image
points lifted onto a scan) share one formula without importing each other.
"""

from __future__ import annotations

import numpy as np

__all__ = ["barycentric_2d"]


def barycentric_2d(tri_xy: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of 2D points in 2D triangles.

    Parameters
    ----------
    tri_xy : (m, 3, 2) float
        Triangle corners (e.g. projected vertices in pixels, or texel positions).
    p : (m, 2) float
        One point per triangle.

    Returns
    -------
    (m, 3) float64
        ``(l0, l1, l2)`` with ``p = l0 a + l1 b + l2 c`` and ``l0 + l1 + l2 = 1``; a point outside
        its triangle has a negative coordinate. Degenerate triangles (zero area) do not raise:
        their determinant is replaced by ``1e-300``.
    """
    a, b, c = tri_xy[:, 0], tri_xy[:, 1], tri_xy[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) > 1e-300, den, 1e-300)
    l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.stack([1.0 - l1 - l2, l1, l2], axis=1)

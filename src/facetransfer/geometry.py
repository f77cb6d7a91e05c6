"""Small pure geometry shared across stages: barycentric coordinates in image or UV space, a
triangle mesh's check and its vertex normals.

Arrays in, arrays out, depending on nothing of the package but its errors and its numba
decorator (:mod:`facetransfer.jit`), so that :mod:`facetransfer.texture` (texel points, the
z-buffer test of Eq. (L1)) and :mod:`facetransfer.correspond.detect` (image points lifted onto a
scan) share one formula without importing each other, and the scans' template fitting
(:mod:`facetransfer.correspond.fitting`, below the renderer) has the normals the renderer
shades with without loading the rasteriser: one mesh check (:func:`check_mesh`, its
:class:`~facetransfer.errors.RenderError` messages as the renderer's) and one face cross
product (:func:`face_cross`, numba) serve both.
"""

from __future__ import annotations

import numpy as np

from .errors import RenderError, ShapeError
from .jit import maybe_njit

__all__ = ["barycentric_2d", "check_mesh", "face_cross", "vertex_normals"]


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


def check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) float64 finite and faces (F, 3) int64 in range; rejects empty meshes.

    Returns
    -------
    V : (n, 3) float64, C-contiguous
    F : (F, 3) int64, C-contiguous

    Raises
    ------
    ShapeError
        If either array has the wrong shape, or the faces are not integers.
    RenderError
        If the mesh is empty, has a non-finite vertex, or a face indexes a vertex it lacks.
    """
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ShapeError(f"vertices must be (n, 3), got {V.shape}")
    if V.shape[0] == 0:
        raise RenderError("cannot render an empty mesh (0 vertices)")
    if not np.all(np.isfinite(V)):
        raise RenderError("vertices contain NaN or infinite coordinates")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3:
        raise ShapeError(f"faces must be (F, 3), got {F.shape}")
    if F.shape[0] == 0:
        raise RenderError("cannot render a mesh with no faces (0 triangles)")
    if not np.issubdtype(F.dtype, np.integer):
        raise ShapeError(f"faces must be integer indices, got dtype {F.dtype}")
    F = np.ascontiguousarray(F, dtype=np.int64)
    lo, hi = int(F.min()), int(F.max())
    if lo < 0 or hi >= V.shape[0]:
        raise RenderError(f"faces index vertices {lo}..{hi} but the mesh has {V.shape[0]} vertices")
    return V, F


def _face_cross_py(V, i0, i1, i2):  # pragma: no cover (numba)
    """Cross product ``(V[i1] - V[i0]) x (V[i2] - V[i0])`` of a triangle (2 x area x unit
    normal) as three floats."""
    ax, ay, az = V[i1, 0] - V[i0, 0], V[i1, 1] - V[i0, 1], V[i1, 2] - V[i0, 2]
    bx, by, bz = V[i2, 0] - V[i0, 0], V[i2, 1] - V[i0, 1], V[i2, 2] - V[i0, 2]
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


#: :func:`_face_cross_py` compiled: called from numba kernels (the normals here, the
#: rasteriser's degenerate-mesh check). numba caches a kernel by its own file and does not see
#: a change in another file's function it calls: after editing this one, touch
#: ``render/raster.py`` too (or clear numba's cache), or its cached check keeps the old code.
face_cross = maybe_njit(_face_cross_py)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (right-hand rule on the face vertex order).

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    (n, 3) float64
        Unit normals; vertices on no non-degenerate face get (0, 0, 0).

    Raises
    ------
    ShapeError, RenderError
        As :func:`check_mesh`.
    """
    V, F = check_mesh(vertices, faces)
    N = np.zeros_like(V)
    _normals_kernel(V, F, N)
    return N


def _normals_kernel_py(V, F, N):  # pragma: no cover
    """Sum of face cross products (2 x area x unit normal) per vertex, then normalised."""
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        nx, ny, nz = face_cross(V, i0, i1, i2)
        for i in (i0, i1, i2):
            N[i, 0] += nx
            N[i, 1] += ny
            N[i, 2] += nz
    for i in range(N.shape[0]):
        norm = np.sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2)
        if norm > 0:
            N[i, 0] /= norm
            N[i, 1] /= norm
            N[i, 2] /= norm


_normals_kernel = maybe_njit(_normals_kernel_py)

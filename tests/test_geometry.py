"""Tests of facetransfer.geometry: the vertex normals every stage shares (the renderer's
shading, the scans' template fitting, the glTF export), the mesh check before them."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.errors import MeshError, RenderError, ShapeError
from facetransfer.geometry import check_mesh, vertex_normals


def _cap(n: int = 40):
    """A spherical cap grid of the unit sphere around +z, counter-clockwise seen from +z."""
    u = np.linspace(-1.2, 1.2, n)
    U, W = np.meshgrid(u, u)
    P = np.stack([np.sin(U) * np.cos(0.8 * W), np.sin(0.8 * W), np.cos(U) * np.cos(0.8 * W)],
                 -1).reshape(-1, 3)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    return P, F


def test_vertex_normals_of_plane_and_cap():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    np.testing.assert_allclose(vertex_normals(V, F), np.tile([0, 0, 1.0], (4, 1)))
    Vc, Fc = _cap()
    N = vertex_normals(Vc, Fc)
    # normals of a sphere cap point outwards, up to discretisation near the border
    assert np.min(np.einsum("ij,ij->i", N, Vc / np.linalg.norm(Vc, axis=1)[:, None])) > 0.95
    # a vertex on no face, or only on degenerate ones, has none
    V0 = np.vstack([V, [[5.0, 5, 5], [6, 6, 6]]])
    F0 = np.vstack([F, [[4, 4, 5]]])
    np.testing.assert_array_equal(vertex_normals(V0, F0)[4:], 0.0)


def test_the_mesh_check_raises_the_renderers_errors():
    """The normals moved out of the renderer keep its errors: a caller's ``except RenderError``
    (``facetransfer.render.RenderError``, the same class) still catches them."""
    import facetransfer.render as render

    assert render.RenderError is RenderError and issubclass(RenderError, MeshError)
    V = np.zeros((3, 3))
    with pytest.raises(RenderError, match="0 vertices"):
        vertex_normals(np.zeros((0, 3)), [[0, 1, 2]])
    with pytest.raises(RenderError, match="NaN or infinite"):
        check_mesh(np.full((3, 3), np.nan), [[0, 1, 2]])
    with pytest.raises(RenderError, match="index vertices 0..3"):
        vertex_normals(V, [[0, 1, 3]])
    with pytest.raises(RenderError, match="no faces"):
        check_mesh(V, np.zeros((0, 3), int))
    with pytest.raises(ShapeError, match=r"vertices must be \(n, 3\)"):
        check_mesh(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ShapeError, match="integer indices"):
        vertex_normals(V, [[0.0, 1.0, 2.0]])
    Vc, Fc = check_mesh(V.astype(np.float32), np.array([[0, 1, 2]], np.int32))
    assert Vc.dtype == np.float64 and Fc.dtype == np.int64 and Vc.flags.c_contiguous

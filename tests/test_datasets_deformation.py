"""Deformation transfer (Sumner & Popović 2004) on small synthetic meshes with exact answers."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.datasets.deformation import (DeformationTransfer, component_anchors,
                                               deformation_gradients, transfer_deformation,
                                               triangle_frames)
from facetransfer.errors import MeshError, ShapeError


def grid(n: int = 7, bump: float = 0.3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An n×n height-field patch: vertices (n², 3), triangles (2 (n-1)², 3)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = bump * np.sin(3 * x) * np.cos(2 * y) + 0.02 * rng.standard_normal(x.shape)
    V = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return V, F.astype(np.int64)


def rotation(axis, angle) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_frames_fourth_vertex_hand_computed():
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]])
    fr = triangle_frames(V, np.array([[0, 1, 2]]))
    # n = (2,0,0) x (0,2,0) = (0,0,4); n / sqrt|n| = (0,0,2)
    np.testing.assert_allclose(fr[0], [[2, 0, 0], [0, 2, 0], [0, 0, 2]])


def test_gradients_of_rest_are_identity():
    V, F = grid()
    Q = deformation_gradients(V, V, F)
    np.testing.assert_allclose(Q, np.broadcast_to(np.eye(3), Q.shape), atol=1e-12)


def test_gradients_of_similarity_equal_the_map():
    V, F = grid()
    A = 1.7 * rotation([1, 2, 3], 0.8)
    Q = deformation_gradients(V, V @ A.T + [1, -2, 3], F)
    np.testing.assert_allclose(Q, np.broadcast_to(A, Q.shape), atol=1e-12)


def test_transfer_onto_source_reproduces_deformation():
    V, F = grid()
    rng = np.random.default_rng(1)
    D = V + 0.05 * rng.standard_normal(V.shape)  # non-rigid
    out = transfer_deformation(V, D, V, F)
    np.testing.assert_allclose(out, D, atol=1e-10 * np.abs(D).max())


def test_transfer_of_similarity_onto_other_target_is_exact():
    V, F = grid(seed=0)
    T, _ = grid(bump=0.6, seed=3)  # a different shape, same triangles
    A = 0.9 * rotation([0, 1, 0.3], 0.5)
    out = transfer_deformation(V, V @ A.T, T, F, fixed=np.array([5]))
    # the target moves by the same similarity about the anchored vertex 5
    expect = (T - T[5]) @ A.T + T[5] + (V[5] @ A.T - V[5])
    np.testing.assert_allclose(out, expect, atol=1e-10)


def test_nonrigid_transfer_differs_between_targets():
    V, F = grid(seed=0)
    T, _ = grid(bump=0.8, seed=4)
    D = V.copy()
    D[:, 2] += 0.2 * np.exp(-((V[:, 0] - 0.5) ** 2 + (V[:, 1] - 0.5) ** 2) / 0.05)
    out = transfer_deformation(V, D, T, F)
    off_src, off_tgt = D - V, out - T
    rel = np.linalg.norm(off_tgt - off_src) / np.linalg.norm(off_src)
    assert 0.02 < rel < 1.0  # same kind of motion, shaped by the target
    # the transferred target's own gradients match the source's closely (least squares)
    Qs = deformation_gradients(V, D, F)
    Qt = deformation_gradients(T, out, F)
    assert np.linalg.norm(Qt - Qs) < 0.5 * np.linalg.norm(Qs - np.eye(3))


def test_batched_solve_matches_single():
    V, F = grid()
    rng = np.random.default_rng(2)
    D = V + 0.03 * rng.standard_normal((2, 3) + V.shape)
    dt = DeformationTransfer(V, F, [0])
    Q = deformation_gradients(V, D, F)
    batch = dt.solve(Q, D[..., [0], :])
    one = dt.solve(Q[1, 2], D[1, 2][[0]])
    np.testing.assert_allclose(batch[1, 2], one, atol=1e-12)
    np.testing.assert_allclose(batch, D, atol=1e-9)


def test_component_anchors_one_per_component():
    V, F = grid(4)
    F2 = np.concatenate([F, F + len(V)])
    a = component_anchors(2 * len(V), F2, preferred=np.array([20, 3]))
    np.testing.assert_array_equal(a, [3, 20])


def test_bad_input():
    V, F = grid(3)
    Vd = V.copy()
    Vd[F[0, 1]] = Vd[F[0, 0]]  # collapse a triangle
    with pytest.raises(MeshError, match="degenerate"):
        triangle_frames(Vd, F)
    with pytest.raises(ShapeError, match="does not match rest"):
        deformation_gradients(V, V[:-1], F)
    with pytest.raises(MeshError, match="outside"):
        triangle_frames(V, F + 100)
    with pytest.raises(ShapeError, match="fixed"):
        DeformationTransfer(V, F, [])
    dt = DeformationTransfer(V, F, [0])
    with pytest.raises(ShapeError, match="gradients"):
        dt.solve(np.zeros((3, 3, 3)), np.zeros((1, 3)))
    with pytest.raises(ShapeError, match="fixed_positions"):
        dt.solve(deformation_gradients(V, V, F), np.zeros((2, 3)))

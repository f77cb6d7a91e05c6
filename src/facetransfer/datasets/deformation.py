"""Deformation transfer (Sumner & Popović 2004), used to make generic expressions identity-specific.

A source mesh deforms from ``S`` (rest) to ``S'``; per triangle ``j`` the deformation gradient is the
3 × 3 matrix ``Q_j = Ṽ_j V_j^{-1}`` where ``V_j = [v2 - v1, v3 - v1, v4 - v1]`` and the fourth
vertex ``v4 = v1 + n / sqrt(|n|)``, ``n = (v2 - v1) × (v3 - v1)`` (their Eq. (1)-(4)). The target
(same triangles, rest shape ``T``) is deformed to the vertex positions ``x`` that minimise

    Σ_j || X̃_j(x) W_j^{-1} - Q_j ||_F²          (their Eq. (5), correspondence = identity)

where ``W_j`` is the target's rest frame and ``X̃_j(x)`` the deformed target frame, the fourth vertex
of every triangle being a free unknown as in the paper. The system is linear in ``x`` and the same
for the three coordinates; its normal equations are factorised once per target rest shape and then
solved for many deformations at once. Translation is removed by fixing a vertex per connected
component.

References
----------
R. W. Sumner and J. Popović, "Deformation transfer for triangle meshes", ACM TOG 23(3), 2004,
doi:10.1145/1015706.1015736. Used by Vlasic et al. 2005, §4.1, to place one expression on many faces.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla

from ..errors import MeshError, ShapeError

__all__ = [
    "triangle_frames",
    "deformation_gradients",
    "DeformationTransfer",
    "transfer_deformation",
    "component_anchors",
]


def _check_mesh(vertices: np.ndarray, faces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim < 2 or v.shape[-1] != 3:
        raise ShapeError(f"{what} must be (..., n_vertices, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ShapeError(f"faces must be (n_faces, 3) with n_faces > 0, got {f.shape}")
    if f.min() < 0 or f.max() >= v.shape[-2]:
        raise MeshError(f"faces index vertices outside 0..{v.shape[-2] - 1}")
    return v, f


def triangle_frames(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-triangle frames ``[v2 - v1, v3 - v1, v4 - v1]`` as matrix columns.

    Parameters
    ----------
    vertices : (..., n_vertices, 3) float64
    faces : (n_faces, 3) int64

    Returns
    -------
    frames : (..., n_faces, 3, 3) float64
        Column ``k`` is edge ``k``; the third edge is ``n / sqrt(|n|)`` with ``n`` the unnormalised
        normal (Sumner & Popović 2004, Eq. (1)), so it scales like the other two edges.

    Raises
    ------
    MeshError
        If a triangle is degenerate (zero area).
    """
    v, f = _check_mesh(vertices, faces, "vertices")
    p1 = v[..., f[:, 0], :]
    e1 = v[..., f[:, 1], :] - p1
    e2 = v[..., f[:, 2], :] - p1
    n = np.cross(e1, e2)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    if np.any(nn <= 0):
        raise MeshError(f"{int(np.count_nonzero(nn <= 0))} degenerate (zero-area) triangles")
    e3 = n / np.sqrt(nn)
    return np.stack([e1, e2, e3], axis=-1)


def deformation_gradients(rest: np.ndarray, deformed: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Deformation gradients ``Q_j = Ṽ_j V_j^{-1}`` from ``rest`` to ``deformed`` (their Eq. (4)).

    Parameters
    ----------
    rest : (n_vertices, 3) float64
    deformed : (..., n_vertices, 3) float64
    faces : (n_faces, 3) int64

    Returns
    -------
    gradients : (..., n_faces, 3, 3) float64
        Identity matrices where ``deformed == rest``.
    """
    rest, f = _check_mesh(rest, faces, "rest")
    deformed = np.asarray(deformed, dtype=np.float64)
    if deformed.shape[-2:] != rest.shape:
        raise ShapeError(f"deformed {deformed.shape} does not match rest {rest.shape}")
    Vinv = np.linalg.inv(triangle_frames(rest, f))  # (F, 3, 3)
    return triangle_frames(deformed, f) @ Vinv


def component_anchors(n_vertices: int, faces: np.ndarray, preferred: np.ndarray | None = None) -> np.ndarray:
    """One vertex per connected component of the mesh, to fix its translation.

    Parameters
    ----------
    n_vertices : int
    faces : (n_faces, 3) int64
    preferred : (m,) int64, optional
        Candidate vertices in order of preference; the first one in each component is taken,
        otherwise the component's lowest index.

    Returns
    -------
    anchors : (n_components,) int64
        Vertices not used by any triangle are not components and are not returned.
    """
    f = np.asarray(faces, dtype=np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    g = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, label = csgraph.connected_components(g, directed=False)
    used = np.zeros(n_vertices, dtype=bool)
    used[f.ravel()] = True
    anchors: dict[int, int] = {}
    for c in ([] if preferred is None else np.asarray(preferred, dtype=np.int64)):
        if used[c] and label[c] not in anchors:
            anchors[label[c]] = int(c)
    for vtx in np.flatnonzero(used):
        if label[vtx] not in anchors:
            anchors[label[vtx]] = int(vtx)
    return np.array(sorted(anchors.values()), dtype=np.int64)


class DeformationTransfer:
    """Deformation transfer onto one target rest shape; factorises once, solves many deformations.

    Parameters
    ----------
    target_rest : (n_vertices, 3) float64
        The target's undeformed mesh (e.g. one identity's neutral face).
    faces : (n_faces, 3) int64
        Triangles shared by source and target (correspondence is the identity map).
    fixed : (m,) int64
        Vertices whose positions are given at solve time (at least one per connected component,
        see :func:`component_anchors`), removing the translation null space.

    Notes
    -----
    The paper's fourth vertex of each deformed triangle appears only in that triangle's term, so it
    is eliminated in closed form: with ``M_j = W_j^{-T}`` (columns ``m_1, m_2, m_3``) the term is
    ``|| m_1 e_1 + m_2 e_2 + m_3 e_3 - q ||²`` (``e_k`` deformed edges, ``q = Q_j[c, :]``), minimised
    over ``e_3`` by projecting out ``m_3``, which is normal to the rest triangle. What remains is
    two rows per triangle, ``U_j^T [m_1 m_2] [e_1 e_2] = U_j^T q`` with ``U_j`` an orthonormal basis
    of the rest triangle's plane: the same minimiser as the full system with ``n`` instead of
    ``n + n_faces`` unknowns (a Poisson-type system). Its normal equations are factorised with
    SuperLU once; :meth:`solve` then costs two triangular solves per right-hand side.
    """

    def __init__(self, target_rest: np.ndarray, faces: np.ndarray, fixed: np.ndarray) -> None:
        v, f = _check_mesh(target_rest, faces, "target_rest")
        if v.ndim != 2:
            raise ShapeError(f"target_rest must be (n_vertices, 3), got {v.shape}")
        fixed = np.unique(np.asarray(fixed, dtype=np.int64))
        if fixed.size == 0 or fixed.min() < 0 or fixed.max() >= len(v):
            raise ShapeError(f"fixed must be 1..n vertex indices in 0..{len(v) - 1}, got {fixed}")
        n, F = len(v), len(f)
        self.n_vertices, self.faces, self.fixed = n, f, fixed
        W = triangle_frames(v, f)  # (F, 3, 3), columns e1, e2, n/sqrt|n|
        Winv = np.linalg.inv(W)
        u1 = W[:, :, 0] / np.linalg.norm(W[:, :, 0], axis=1, keepdims=True)
        nh = W[:, :, 2] / np.linalg.norm(W[:, :, 2], axis=1, keepdims=True)
        U = np.stack([u1, np.cross(nh, u1)], axis=2)  # (F, 3, 2) basis of the triangle plane
        # G[j, s, k] = sum_r U[j, r, s] * M[j, r, k] with M = Winv^T, i.e. M[j, r, k] = Winv[j, k, r]
        G = np.einsum("jrs,jkr->jsk", U, Winv[:, :2, :])  # (F, 2, 2)
        coef = np.concatenate([-(G[:, :, :1] + G[:, :, 1:]), G], axis=2)  # (F, 2, 3): x1, x2, x3
        rows = np.repeat(np.arange(2 * F), 3)
        cols = np.repeat(f, 2, axis=0).ravel()
        A = sp.csr_matrix((coef.ravel(), (rows, cols)), shape=(2 * F, n))
        free = np.ones(n, dtype=bool)
        free[fixed] = False
        self._U = U
        self._A_free = A[:, np.flatnonzero(free)].tocsc()
        self._A_fixed = A[:, fixed].tocsc()
        self._free = np.flatnonzero(free)
        N = (self._A_free.T @ self._A_free).tocsc()
        # N is symmetric positive definite: symmetric ordering, no pivoting (40x faster than the
        # default partial pivoting on the face region, same factors up to rounding).
        self._solve = spla.splu(N, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                options={"SymmetricMode": True}).solve

    def solve(self, gradients: np.ndarray, fixed_positions: np.ndarray) -> np.ndarray:
        """Vertex positions whose deformation gradients best match ``gradients``.

        Parameters
        ----------
        gradients : (..., n_faces, 3, 3) float64
            Source deformation gradients (:func:`deformation_gradients`).
        fixed_positions : (..., m, 3) float64
            Positions of the ``fixed`` vertices (in the sorted order of ``self.fixed``), one set
            per deformation.

        Returns
        -------
        vertices : (..., n_vertices, 3) float64
        """
        Q = np.asarray(gradients, dtype=np.float64)
        F = len(self.faces)
        if Q.shape[-3:] != (F, 3, 3):
            raise ShapeError(f"gradients must be (..., {F}, 3, 3), got {Q.shape}")
        P = np.asarray(fixed_positions, dtype=np.float64)
        batch = Q.shape[:-3]
        if P.shape != batch + (len(self.fixed), 3):
            raise ShapeError(f"fixed_positions must be {batch + (len(self.fixed), 3)}, got {P.shape}")
        B = int(np.prod(batch, dtype=np.int64))
        Qb = Q.reshape(B, F, 3, 3)
        # b[2j + s, (batch, c)] = (Q_j U_j)[c, s]
        QU = np.einsum("bjcr,jrs->jsbc", Qb, self._U)
        b = QU.reshape(2 * F, B * 3)
        Pb = np.transpose(P.reshape(B, -1, 3), (1, 0, 2)).reshape(-1, B * 3)
        rhs = self._A_free.T @ (b - self._A_fixed @ Pb)
        x = self._solve(np.asarray(rhs))
        out = np.empty((self.n_vertices, B * 3))
        out[self._free] = x
        out[self.fixed] = Pb
        verts = out.reshape(self.n_vertices, B, 3)
        return np.transpose(verts, (1, 0, 2)).reshape(batch + (self.n_vertices, 3))


def transfer_deformation(source_rest: np.ndarray, source_deformed: np.ndarray,
                         target_rest: np.ndarray, faces: np.ndarray, *,
                         fixed: np.ndarray | None = None) -> np.ndarray:
    """One-shot deformation transfer of ``source_rest -> source_deformed`` onto ``target_rest``.

    Parameters
    ----------
    source_rest, target_rest : (n_vertices, 3) float64
    source_deformed : (..., n_vertices, 3) float64
    faces : (n_faces, 3) int64
    fixed : (m,) int64, optional
        Anchor vertices (default one per connected component). Each is placed at the target's rest
        position plus the source's displacement there.

    Returns
    -------
    (..., n_vertices, 3) float64
        The target deformed like the source.

    References
    ----------
    Sumner & Popović 2004, §3-4.
    """
    src = np.asarray(source_rest, dtype=np.float64)
    tgt = np.asarray(target_rest, dtype=np.float64)
    dfm = np.asarray(source_deformed, dtype=np.float64)
    if src.shape != tgt.shape:
        raise ShapeError(f"source_rest {src.shape} and target_rest {tgt.shape} differ")
    if fixed is None:
        fixed = component_anchors(len(src), faces)
    dt = DeformationTransfer(tgt, faces, fixed)
    Q = deformation_gradients(src, dfm, faces)
    P = tgt[dt.fixed] + (dfm[..., dt.fixed, :] - src[dt.fixed])
    return dt.solve(Q, P)

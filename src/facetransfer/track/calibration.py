"""Calibrating the MediaPipe -> iBUG-68 correspondence against points with known truth.

:mod:`facetransfer.track.landmarks` maps MediaPipe Face Landmarker's 478 points to the 68 iBUG
points by a fixed linear combination, ``ibug_i = sum_j W[i, j] * mp_j``. This module finds such
a ``W`` from frames where the true iBUG points are known (``benchmarks/calibrate_landmarks.py``
makes those frames): each iBUG point gets a small fixed set of nearby MediaPipe points (its
current 1-2 plus the nearest vertices of MediaPipe's canonical mesh) and their weights are solved
by least squares, with

- weights summing to 1, so the combination is an affine one: it commutes with every similarity
  (and affine) map of the image, hence the fit is the same in any face-aligned frame up to the
  frame's scale, which is removed by dividing each frame's residual by its eye-corner distance
  (the normalisation of the NME the benchmark reports);
- a ridge towards the prior weights (the hand-made table), so that points the data does not
  pin down stay where the table put them.

Per iBUG point ``i`` with candidates ``c`` (``X_f``: (c, 2) candidate points in frame ``f``,
``t_f`` the true point, ``s_f`` the frame's scale)::

    min_w  1/F sum_f |X_f^T w - t_f|^2 / s_f^2  +  lam |w - w0|^2   s.t.  1^T w = 1

solved in the null space of ``1^T`` (``w = w0 + B u``, ``B`` orthonormal, ``1^T B = 0``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError

__all__ = ["CalibratedPoint", "candidate_sets", "solve_point_weights", "calibrate_mapping",
           "mapping_error", "best_triangle_point"]


@dataclass(frozen=True)
class CalibratedPoint:
    """The weights of one iBUG point.

    Attributes
    ----------
    indices : (c,) int64
        MediaPipe point indices.
    weights : (c,) float64
        Their weights (sum 1).
    """

    indices: np.ndarray
    weights: np.ndarray


def candidate_sets(canonical: np.ndarray, table, *, k: int = 8) -> list[np.ndarray]:
    """Candidate MediaPipe points of each iBUG point: the table's own plus the ``k`` canonical
    mesh vertices nearest to the table's point (3-D, on MediaPipe's canonical face).

    Parameters
    ----------
    canonical : (468, 3) float
        MediaPipe's canonical face mesh vertices.
    table : sequence of 68 tuples of int
        The prior correspondence (e.g. :data:`~facetransfer.track.landmarks.MP_TO_IBUG`).
    k : int
        Number of nearest vertices added.

    Returns
    -------
    list of (c_i,) int64, the table's indices first, then by distance
    """
    C = np.asarray(canonical, np.float64)
    if C.ndim != 2 or C.shape[1] != 3:
        raise ShapeError(f"canonical mesh must be (n, 3), got {C.shape}")
    out = []
    for idx in table:
        own = [int(j) for j in idx]
        d = np.linalg.norm(C - C[own].mean(axis=0), axis=1)
        near = [int(j) for j in np.argsort(d, kind="stable") if int(j) not in own][:k]
        out.append(np.array(own + near, np.int64))
    return out


def _null_basis(c: int) -> np.ndarray:
    """(c, c-1) orthonormal basis of the vectors summing to 0."""
    U, _, _ = np.linalg.svd(np.eye(c) - 1.0 / c)
    return U[:, : c - 1]


def solve_point_weights(X: np.ndarray, t: np.ndarray, scale: np.ndarray, w0: np.ndarray, *,
                        ridge: float) -> np.ndarray:
    """Affine weights of one point (module notes).

    Parameters
    ----------
    X : (F, c, d) float
        Candidate points per frame (pixels).
    t : (F, d) float
        True point per frame.
    scale : (F,) float
        Per-frame normalisation (the true eye-corner distance).
    w0 : (c,) float
        Prior weights, summing to 1.
    ridge : float
        Weight of ``|w - w0|^2`` against the mean squared normalised residual.

    Returns
    -------
    (c,) float64, summing to 1
    """
    X, t = np.asarray(X, np.float64), np.asarray(t, np.float64)
    s, w0 = np.asarray(scale, np.float64), np.asarray(w0, np.float64)
    if X.ndim != 3 or t.shape != (X.shape[0], X.shape[2]) or s.shape != (X.shape[0],):
        raise ShapeError(f"X (F, c, d), t (F, d), scale (F,) expected, got {X.shape}, {t.shape}, "
                         f"{s.shape}")
    if w0.shape != (X.shape[1],) or not np.isclose(w0.sum(), 1.0):
        raise ShapeError(f"w0 must be ({X.shape[1]},) summing to 1, got {w0.shape}")
    F, c, _ = X.shape
    if c == 1:
        return np.ones(1)
    Xn, tn = X / s[:, None, None], t / s[:, None]
    B = _null_basis(c)                                                      # (c, c-1)
    M = np.einsum("fcd,ck->fdk", Xn, B).reshape(-1, c - 1)                 # (F d, c-1)
    b = (np.einsum("fcd,c->fd", Xn, w0) - tn).reshape(-1)                  # (F d,)
    u = np.linalg.solve(M.T @ M / F + ridge * np.eye(c - 1), -(M.T @ b) / F)
    return w0 + B @ u


def calibrate_mapping(points: np.ndarray, truth: np.ndarray, scale: np.ndarray, candidates,
                      prior: np.ndarray, *, ridge: float, fixed=()) -> list[CalibratedPoint]:
    """Weights of every iBUG point from frames with known truth.

    Parameters
    ----------
    points : (F, n, d) float
        MediaPipe points per frame (n >= the largest candidate index + 1); frames with any NaN
        are left out.
    truth : (F, 68, d) float
        True iBUG points.
    scale : (F,) float
        Per-frame normalisation.
    candidates : list of 68 (c_i,) int arrays
        From :func:`candidate_sets`.
    prior : (68, n) float
        Prior weight matrix (rows sum to 1).
    ridge : float
        See :func:`solve_point_weights`.
    fixed : iterable of int
        iBUG points that keep their prior weights.

    Returns
    -------
    list of 68 :class:`CalibratedPoint`
    """
    P, T = np.asarray(points, np.float64), np.asarray(truth, np.float64)
    s = np.asarray(scale, np.float64)
    if P.ndim != 3 or T.shape != (P.shape[0], 68, P.shape[2]) or s.shape != (P.shape[0],):
        raise ShapeError(f"points (F, n, d), truth (F, 68, d), scale (F,) expected, got "
                         f"{P.shape}, {T.shape}, {s.shape}")
    ok = np.isfinite(P).all(axis=(1, 2)) & np.isfinite(T).all(axis=(1, 2)) & (s > 0)
    P, T, s = P[ok], T[ok], s[ok]
    fixed = set(int(i) for i in fixed)
    out = []
    for i, cand in enumerate(candidates):
        cand = np.asarray(cand, np.int64)
        w0 = np.asarray(prior, np.float64)[i, cand]
        if i in fixed or not len(P):
            out.append(CalibratedPoint(cand, w0))
            continue
        out.append(CalibratedPoint(cand, solve_point_weights(P[:, cand], T[:, i], s, w0,
                                                             ridge=ridge)))
    return out


def mapping_error(W: np.ndarray, points: np.ndarray, truth: np.ndarray, scale: np.ndarray
                  ) -> np.ndarray:
    """Per-frame, per-point distance of ``W @ points`` from ``truth`` / ``scale``, (F, 68)."""
    Y = np.einsum("im,fmd->fid", np.asarray(W, np.float64), np.asarray(points, np.float64))
    return np.linalg.norm(Y - truth, axis=2) / np.asarray(scale, np.float64)[:, None]


def best_triangle_point(V2: np.ndarray, m: np.ndarray, scale: np.ndarray, triangles: np.ndarray
                        ) -> tuple[int, np.ndarray, float]:
    """The surface point (a triangle and barycentric coordinates) whose projections best match
    one detected point over frames.

    For every candidate triangle the affine weights of its 3 vertices (sum 1) are solved by least
    squares, ``min_w 1/F sum_f |V2_f[tri]^T w - m_f|^2 / s_f^2``, clipped into the triangle
    (negative weights to 0, renormalised); the triangle with the smallest mean squared error wins.

    Parameters
    ----------
    V2 : (F, n, 2) float
        Projected true vertices per frame (pixels).
    m : (F, 2) float
        The detected point per frame.
    scale : (F,) float
        Per-frame normalisation (the true eye-corner distance).
    triangles : (T, 3) int
        Candidate triangles (vertex indices into ``V2``).

    Returns
    -------
    index : int
        Row of ``triangles``.
    bary : (3,) float64
    rms : float
        Root mean squared normalised error of that point.
    """
    tri = np.asarray(triangles, np.int64)
    if tri.ndim != 2 or tri.shape[1] != 3 or not len(tri):
        raise ShapeError(f"triangles must be (T, 3), T > 0, got {tri.shape}")
    s = np.asarray(scale, np.float64)[:, None, None]
    A = np.asarray(V2, np.float64)[:, tri] / s[..., None]                  # (F, T, 3, 2)
    mt = np.asarray(m, np.float64)[:, None, :] / s                         # (F, 1, 2)
    E = A[:, :, 1:] - A[:, :, :1]                                           # (F, T, 2, 2)
    r0 = A[:, :, 0] - mt                                                    # (F, T, 2)
    N = np.einsum("ftkd,ftld->tkl", E, E) + 1e-12 * np.eye(2)
    g = np.einsum("ftkd,ftd->tk", E, r0)
    u = -np.linalg.solve(N, g[..., None])[..., 0]                           # (T, 2)
    w = np.concatenate([1 - u.sum(1, keepdims=True), u], axis=1)
    w = np.clip(w, 0.0, None)
    w /= w.sum(axis=1, keepdims=True)
    res = np.einsum("ftkd,tk->ftd", A, w) - mt                              # (F, T, 2)
    err = (res ** 2).sum(axis=2).mean(axis=0)                               # (T,)
    best = int(np.argmin(err))
    return best, w[best], float(np.sqrt(err[best]))

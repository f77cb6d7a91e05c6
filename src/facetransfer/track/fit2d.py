"""Small pure solvers for fitting the model to 2-D points: weak-perspective pose, bounded
activations, clip identity (the building blocks of :mod:`facetransfer.track.capture`).

Every residual is measured in units of the face size (the outer eye-corner distance ``iod`` of
the frame's detections), so the weights of the terms do not depend on the image resolution.
A 2-D target set is ``(p, w)``: pixel positions ``(n, 2)`` and per-point weights ``(n,)`` (0 where
unknown). The camera is Eq. (7): ``p = s F R[:2] X + t``.

References
----------
Vlasic et al. 2005, §5.1, Eq. (7)-(9); the bounded activation step is a box-constrained
quadratic program solved by cyclic coordinate descent (projected Gauss-Seidel), checked against
``scipy.optimize.lsq_linear`` in the tests.
"""

from __future__ import annotations

import numpy as np

from .camera import Pose, compose, pose_jacobian, project

__all__ = ["project_basis", "pose_gauss_newton", "box_qp", "normal_terms", "targets_normal"]

try:  # numba is a dependency; the fallback keeps the module importable while it compiles
    from numba import njit
except ImportError:  # pragma: no cover
    def njit(*a, **k):
        return (lambda f: f) if not (a and callable(a[0])) else a[0]


def project_basis(B: np.ndarray, pose: Pose) -> np.ndarray:
    """Image-plane directions of a linear basis: ``s F R[:2] B`` (translation-free).

    Parameters
    ----------
    B : (k, n, 3) float64
        ``k`` 3-D displacement fields over ``n`` points.

    Returns
    -------
    (k, n, 2) float64
    """
    Y = B @ (pose.scale * pose.rotation[:2].T)  # one matrix product (einsum: 3x slower)
    Y[..., 1] *= -1.0
    return Y


def pose_gauss_newton(X: np.ndarray, targets: list, pose: Pose, iod: float, *,
                      iterations: int = 2, damping: float = 1e-6) -> Pose:
    """Gauss-Newton steps of the weak-perspective pose (Eq. (7)) for fixed 3-D points.

    Parameters
    ----------
    X : (n, 3) float64
        Model points.
    targets : list of (p (n, 2), w (n,))
        Weighted 2-D targets of the same points (weights 0 where unknown).
    pose : Pose
        Start.
    iod : float
        Face size in pixels (residual unit).

    Returns
    -------
    Pose
    """
    for _ in range(iterations):
        Y = X @ pose.rotation.T
        J = pose_jacobian(Y, pose.scale).reshape(-1, 6)      # (2n, 6)
        q = project(X, pose.rotation, pose.scale, pose.translation)
        A = damping * np.eye(6)
        b = np.zeros(6)
        for p, w in targets:
            ww = np.repeat(w, 2) / iod ** 2
            r = np.nan_to_num(p - q).ravel()
            Jw = J * ww[:, None]
            A += Jw.T @ J
            b += Jw.T @ r
        d = np.linalg.solve(A, b)
        d[:3] = np.clip(d[:3], -0.3, 0.3)
        d[3] = np.clip(d[3], -0.3, 0.3)
        pose = compose(pose, d)
    return pose


def normal_terms(Y: np.ndarray, r: np.ndarray, w: np.ndarray, iod: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``G = Σ_i w_i Y_i Y_iᵀ``, ``h = Σ_i w_i Y_i r_i`` for ``r ≈ Σ_j x_j Y_j`` (in iod units).

    Parameters
    ----------
    Y : (k, n, 2) float64
        Projected basis (:func:`project_basis`).
    r : (n, 2) float64
        Residual targets (NaN allowed where ``w == 0``).
    w : (n,) float64

    Returns
    -------
    G : (k, k), h : (k,)
    """
    k = Y.shape[0]
    Yf = Y.reshape(k, -1)
    ww = np.repeat(w, 2) / iod ** 2
    Yw = Yf * ww
    return Yw @ Yf.T, Yw @ np.nan_to_num(r).ravel()


def targets_normal(Y: np.ndarray, base: np.ndarray, targets: list, iod: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`normal_terms` summed over target sets, residuals ``p - base``."""
    k = Y.shape[0]
    G = np.zeros((k, k))
    h = np.zeros(k)
    for p, w in targets:
        g_, h_ = normal_terms(Y, p - base, w, iod)
        G += g_
        h += h_
    return G, h


@njit(cache=True)
def _box_qp(G, h, x, lo, hi, sweeps, tol):  # pragma: no cover (compiled)
    k = x.shape[0]
    for _ in range(sweeps):
        change = 0.0
        for j in range(k):
            g = h[j]
            for m in range(k):
                g -= G[j, m] * x[m]
            new = x[j] + g / G[j, j]
            if new < lo[j]:
                new = lo[j]
            elif new > hi[j]:
                new = hi[j]
            d = new - x[j]
            if d != 0.0:
                x[j] = new
                change = max(change, abs(d))
        if change < tol:
            break
    return x


def box_qp(G: np.ndarray, h: np.ndarray, x0: np.ndarray, *, lo: float | np.ndarray = 0.0,
           hi: float | np.ndarray = 1.0, sweeps: int = 200, tol: float = 1e-7) -> np.ndarray:
    """``argmin_x ½ xᵀ G x - hᵀ x`` subject to ``lo <= x <= hi`` (cyclic coordinate descent).

    Parameters
    ----------
    G : (k, k) float64
        Symmetric positive definite (add a ridge for that).
    h : (k,) float64
    x0 : (k,) float64
        Start (clipped into the box).

    Returns
    -------
    (k,) float64
    """
    k = h.shape[0]
    lo_ = np.broadcast_to(np.asarray(lo, np.float64), (k,)).copy()
    hi_ = np.broadcast_to(np.asarray(hi, np.float64), (k,)).copy()
    x = np.clip(np.asarray(x0, np.float64), lo_, hi_).copy()
    return _box_qp(np.ascontiguousarray(G, np.float64), np.ascontiguousarray(h, np.float64), x,
                   lo_, hi_, int(sweeps), float(tol))

"""Weak-perspective pose of the tracker (Vlasic et al. 2005, §5.1, Eq. (7)) and its linearisation.

A model point ``X`` (model units, y up) lands at the pixel ``p = s F R[:2] X + t`` with
``F = diag(1, -1)`` (image y points down), ``R`` a rotation, ``s > 0`` pixels per model unit and
``t`` the pixel position of the model origin — the convention shared with
:class:`facetransfer.render.WeakPerspective`.

For Gauss-Newton the pose is updated multiplicatively around the current estimate::

    R <- exp([ω]x) R,    s <- s exp(σ),    t <- t + τ

with the 6-vector ``δ = (ω, σ, τ)``; :func:`pose_jacobian` is ``∂p/∂δ`` at ``δ = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError

__all__ = ["Pose", "project", "so3_exp", "so3_log", "pose_jacobian", "compose", "fit_affine_pose",
           "nearest_rotation"]

#: Number of pose parameters in a Gauss-Newton step: rotation (3), log-scale (1), translation (2).
N_POSE = 6


@dataclass(frozen=True)
class Pose:
    """A weak-perspective pose, Eq. (7).

    Attributes
    ----------
    rotation : (3, 3) float64
    scale : float
    translation : (2,) float64
    """

    rotation: np.ndarray
    scale: float
    translation: np.ndarray

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels of model points, (n, 3) -> (n, 2)."""
        return project(X, self.rotation, self.scale, self.translation)

    def update(self, delta: np.ndarray) -> "Pose":
        """The pose after a Gauss-Newton step ``δ = (ω, σ, τ)`` (6,)."""
        return compose(self, delta)


def project(X: np.ndarray, R: np.ndarray, s: float, t: np.ndarray) -> np.ndarray:
    """Weak-perspective projection ``s F R[:2] X + t`` (Eq. (7)).

    Parameters
    ----------
    X : (..., 3) float64
    R : (3, 3) float64
    s : float
    t : (2,) float64

    Returns
    -------
    (..., 2) float64
    """
    Y = X @ R[:2].T
    Y = Y * s
    Y[..., 1] *= -1.0
    return Y + t


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp([ω]x)`` of a rotation vector (Rodrigues), (3,) -> (3, 3)."""
    w = np.asarray(omega, dtype=np.float64)
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`so3_exp`), (3, 3) -> (3,)."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-8:
        return v / 2
    if np.pi - th < 1e-6:  # near pi: use the symmetric part
        B = (R + np.eye(3)) / 2
        axis = np.sqrt(np.clip(np.diag(B), 0, None))
        i = int(np.argmax(axis))
        axis = B[i] / max(axis[i], 1e-12)
        return th * axis / np.linalg.norm(axis)
    return th / (2 * np.sin(th)) * v


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The proper rotation nearest to a 3x3 matrix in the Frobenius norm."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def compose(pose: Pose, delta: np.ndarray) -> Pose:
    """Apply a step ``δ = (ω, σ, τ)``: ``R <- exp([ω]x) R``, ``s <- s e^σ``, ``t <- t + τ``."""
    d = np.asarray(delta, dtype=np.float64)
    if d.shape != (N_POSE,):
        raise ShapeError(f"pose step must be (6,), got {d.shape}")
    return Pose(orthonormalize(so3_exp(d[:3]) @ pose.rotation), float(pose.scale * np.exp(d[3])),
                pose.translation + d[4:6])


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Remove round-off from a rotation matrix (one Gram-Schmidt sweep over its rows)."""
    r0 = R[0] / np.linalg.norm(R[0])
    r1 = R[1] - (R[1] @ r0) * r0
    r1 /= np.linalg.norm(r1)
    return np.stack([r0, r1, np.cross(r0, r1)])


def pose_jacobian(Y: np.ndarray, s: float) -> np.ndarray:
    """``∂p/∂δ`` of Eq. (7) at ``δ = 0`` for rotated points ``Y = R X``.

    Parameters
    ----------
    Y : (n, 3) float64
        Model points already rotated by the current ``R``.
    s : float

    Returns
    -------
    (n, 2, 6) float64
        Columns: ω (3), σ (log-scale), τ (2).
    """
    n = Y.shape[0]
    J = np.zeros((n, 2, N_POSE))
    # d(exp([ω]x) Y)/dω = -[Y]x ; rows x, y of it, image y flipped by F.
    J[:, 0, 1] = s * Y[:, 2]
    J[:, 0, 2] = -s * Y[:, 1]
    J[:, 1, 0] = s * Y[:, 2]      # -(-Y3)
    J[:, 1, 2] = -s * Y[:, 0]     # -(Y1)
    J[:, 0, 3] = s * Y[:, 0]
    J[:, 1, 3] = -s * Y[:, 1]
    J[:, 0, 4] = 1.0
    J[:, 1, 5] = 1.0
    return J


def fit_affine_pose(X: np.ndarray, p: np.ndarray) -> Pose:
    """Weak-perspective pose best explaining 2-D points ``p`` of 3-D points ``X``.

    Fits an affine camera ``p = A X + b`` by least squares, then takes the nearest scaled
    rotation (the rows of ``A`` orthonormalised, scale their mean norm). Used to start the
    initialisation of §5.2.

    Parameters
    ----------
    X : (n, 3) float64, n >= 4
    p : (n, 2) float64

    Returns
    -------
    Pose
    """
    X = np.asarray(X, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or p.shape != (X.shape[0], 2) or X.shape[0] < 4:
        raise ShapeError(f"need (n, 3) and (n, 2) points with n >= 4, got {X.shape}, {p.shape}")
    Xc = X - X.mean(0)
    pc = p - p.mean(0)
    A, *_ = np.linalg.lstsq(Xc, pc, rcond=None)  # (3, 2): pc ≈ Xc A
    A = A.T.copy()                                 # (2, 3)
    A[1] *= -1.0                                   # undo F
    s = float(np.mean(np.linalg.norm(A, axis=1)))
    r1 = A[0] / max(np.linalg.norm(A[0]), 1e-12)
    r2 = A[1] - (A[1] @ r1) * r1
    r2 /= max(np.linalg.norm(r2), 1e-12)
    R = nearest_rotation(np.stack([r1, r2, np.cross(r1, r2)]))
    t = p.mean(0) - project(X.mean(0)[None], R, s, np.zeros(2))[0]
    return Pose(R, s, t)

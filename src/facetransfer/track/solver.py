"""Pose and model weights from stacked linear constraints (Vlasic et al. 2005, §5.1, Eq. (7)-(9)).

With all attributes but one (mode ``m``) fixed, the tracked vertex ``i`` is linear in that
mode's weights, ``f_i = M_{m,i} w_m`` (Eq. (9)), and its pixel is ``p_i = s F R[:2] f_i + t``
(Eq. (7)). Every tracked vertex contributes the symmetric KLT constraint ``Z_i (p_i - p0_i) = e_i``
(Eq. (6), (8)); we minimise the matching quadratic energy

    E(δ) = Σ_i (p_i(δ) - p0_i)ᵀ Z_i (p_i(δ) - p0_i) - 2 e_iᵀ (p_i(δ) - p0_i)

whose Gauss-Newton normal equations, with the pose linearised around the current estimate
(:func:`facetransfer.track.camera.pose_jacobian`), are ``(Σ J_iᵀ Z_i J_i) δ = Σ J_iᵀ (e_i - Z_i
(p_i - p0_i))`` for the unknowns ``δ = (ω, σ, τ, Δw_m)`` — the rigid pose and the mode's weights
solved together (Bascle & Blake 1998; Brand & Bhotika 2001). A landmark target is the same
constraint with ``Z = I`` and ``e`` the displacement to the target. Weights are regularised toward
the training distribution with the Tikhonov term ``λ (w - μ)ᵀ Σ⁻¹ (w - μ)`` (:meth:`Prior.
from_model`: ``μ`` the mode's training row labelled "neutral" where it has one, else the rows'
mean; ``Σ`` the rows' covariance in the gauge hyperplane below, with a small ridge).

The clip-constant mode (identity) is not solved per frame: each frame pair's system is reduced
to the identity block by the Schur complement over that frame's pose (:func:`schur_reduce`),
accumulated over all pairs of a pass, and solved once (§5.1: "we accumulate the mentioned linear
systems from each pair of frames and solve them together").

Gauge: the model has no constant term, so ``s f(w_m)`` is unchanged by ``w_m -> c w_m``,
``s -> s / c``. Each mode's weights are therefore kept on a fixed hyperplane ``aᵀ w = aᵀ μ``
through the training mean: for data sets built as mean + offsets (ICT-FaceKit, FaceWarehouse)
the training attribute vectors all lie on such a hyperplane (their covariance is singular along
its normal ``a``); otherwise ``a`` is the mean direction. Steps move in the hyperplane
(``w = w_0 + Q y`` with ``Q`` an orthonormal basis of ``a``'s complement, :class:`Prior`), so
the weights stay comparable with the training rows and ``s`` carries the image size.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError, TrackError
from .camera import N_POSE, Pose, compose, fit_affine_pose, pose_jacobian, project

log = logging.getLogger(__name__)

__all__ = ["FrameState", "BasisCache", "normal_equations", "point_terms", "schur_reduce",
           "prior_terms", "project_to_gauge", "full_jacobian", "solve_step", "weight_jacobian",
           "fit_points", "Prior", "flow_normal_equations"]


@dataclass(frozen=True)
class FrameState:
    """Pose and weights of one frame.

    Attributes
    ----------
    pose : Pose
    weights : dict mode name -> (r,) float64
    """

    pose: Pose
    weights: dict

    def with_weights(self, name: str, w: np.ndarray) -> "FrameState":
        ws = dict(self.weights)
        ws[name] = np.asarray(w, dtype=np.float64)
        return FrameState(self.pose, ws)


@dataclass(frozen=True)
class Prior:
    """Gauge and Gaussian prior of one mode's weights (see the module notes).

    Attributes
    ----------
    mean : (r,) float64
        ``μ``, the prior's centre: the training row labelled ``neutral`` if the mode has one
        (a face at rest is the natural expectation for expressions and visemes), else the
        mean training vector.
    Q : (r, k) float64
        Orthonormal basis of the gauge hyperplane's directions (``k = r - 1``, or ``r`` for a
        mode of rank 1 without a gauge).
    inv_cov : (k, k) float64
        Inverse covariance of the training vectors in the coordinates ``y = Qᵀ (w - μ)``.
    """

    mean: np.ndarray
    Q: np.ndarray
    inv_cov: np.ndarray

    @classmethod
    def from_model(cls, model, mode) -> "Prior":
        k = model.mode_index(mode)
        U = model.factors[k]
        labels = [str(l).lower() for l in model.labels[k]]
        mu = U[labels.index("neutral")] if "neutral" in labels else U.mean(axis=0)
        r = mu.size
        C = np.cov(U, rowvar=False, bias=True).reshape(r, r) if U.shape[0] > 1 else np.zeros((r, r))
        evals, evecs = np.linalg.eigh(C)
        tr = max(float(evals.sum()), 1e-12)
        if r == 1:
            Q = np.eye(1)
        else:
            if evals[0] < 1e-4 * tr:
                a = evecs[:, 0]                      # normal of the training hyperplane
            else:
                a = mu / max(np.linalg.norm(mu), 1e-300)
            Q = _complement(a)
        Ct = Q.T @ C @ Q
        Ct = Ct + (1e-6 * max(np.trace(Ct) / Ct.shape[0], 1e-12)) * np.eye(Ct.shape[0])
        return cls(mu, Q, np.linalg.inv(Ct))


def _complement(a: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the complement of a unit vector, (r,) -> (r, r - 1)."""
    a = a / np.linalg.norm(a)
    e0 = np.zeros_like(a)
    e0[int(np.argmax(np.abs(a)))] = 1.0
    # Householder reflection taking a to ±e0; its other columns span a's complement
    v = a - np.sign(a @ e0) * e0 if abs(a @ e0) < 1 - 1e-15 else np.zeros_like(a)
    H = np.eye(a.size) if not v.any() else np.eye(a.size) - 2.0 * np.outer(v, v) / (v @ v)
    keep = [j for j in range(a.size) if j != int(np.argmax(np.abs(a)))]
    return H[:, keep]


class BasisCache:
    """Model evaluation with the clip-constant modes contracted once (Eq. (5), (9)).

    Parameters
    ----------
    model : MultilinearModel
    constant : dict mode name -> (r,) weights
        Modes fixed for the whole pass (the identity); contracted into the core once.
    """

    def __init__(self, model, constant: dict | None = None) -> None:
        self.model = model
        constant = dict(constant or {})
        core = model.core
        names = list(model.mode_names)
        for name in sorted(constant, key=model.mode_index, reverse=True):
            k = names.index(name)
            core = np.tensordot(core, np.asarray(constant[name], float), axes=([k + 1], [0]))
            names.pop(k)
        self.core = np.ascontiguousarray(core)          # (3n, r_free...)
        self.free = tuple(names)
        self.constant = constant
        self.vertices = None                            # all of the model's vertices
        self._n = model.n_vertices

    def restrict(self, vertices) -> "BasisCache":
        """The same cache over a subset of vertices (their rows copied once)."""
        sub = object.__new__(BasisCache)
        sub.model = self.model
        sub.core = np.ascontiguousarray(self._rows(vertices))
        sub.free = self.free
        sub.constant = self.constant
        sub.vertices = np.asarray(vertices, dtype=np.int64)
        sub._n = sub.vertices.size
        return sub

    def _rows(self, vertices):
        if vertices is None:
            return self.core
        v = np.asarray(vertices, dtype=np.int64)
        return self.core.reshape(self._n, 3, *self.core.shape[1:])[v].reshape(
            3 * v.size, *self.core.shape[1:])

    def basis(self, mode: str, weights: dict, vertices=None) -> np.ndarray:
        """Eq. (9) for a free mode at the given vertices, (m, 3, r_mode)."""
        if mode not in self.free:
            v = vertices if self.vertices is None else (
                self.vertices if vertices is None else self.vertices[np.asarray(vertices)])
            return self.model.mode_basis(mode, weights, vertices=v)
        k = self.free.index(mode)
        out = self._rows(vertices)
        for j in reversed(range(len(self.free))):
            if j != k:
                out = np.tensordot(out, weights[self.free[j]], axes=([j + 1], [0]))
        return out.reshape(-1, 3, out.shape[-1])

    def shape(self, weights: dict, vertices=None) -> np.ndarray:
        """Eq. (5) at the given vertices, (m, 3)."""
        out = self._rows(vertices)
        for j in reversed(range(len(self.free))):
            out = np.tensordot(out, weights[self.free[j]], axes=([j + 1], [0]))
        return out.reshape(-1, 3)


def weight_jacobian(B: np.ndarray, R: np.ndarray, s: float) -> np.ndarray:
    """``∂p/∂w_m = s F R[:2] M_{m,i}`` (Eq. (8)), (n, 3, r) -> (n, 2, r)."""
    Jw = np.matmul(R[:2] * s, B)
    Jw[:, 1] *= -1.0
    return Jw


def full_jacobian(X: np.ndarray, B: np.ndarray, pose: Pose) -> np.ndarray:
    """Jacobian of Eq. (7)/(8) w.r.t. ``(ω, σ, τ, w_m)``, (n, 2, 6 + r)."""
    Y = X @ pose.rotation.T
    return np.concatenate([pose_jacobian(Y, pose.scale),
                           weight_jacobian(B, pose.rotation, pose.scale)], axis=2)


def normal_equations(J: np.ndarray, Z: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A = Σ J_iᵀ Z_i J_i``, ``b = Σ J_iᵀ e_i`` of the stacked Eq. (8) systems.

    Parameters
    ----------
    J : (n, 2, P)
    Z : (n, 2, 2)
    e : (n, 2)

    Returns
    -------
    A : (P, P), b : (P,)
    """
    J0, J1 = J[:, 0, :], J[:, 1, :]
    ZJ0 = Z[:, 0, 0, None] * J0 + Z[:, 0, 1, None] * J1
    ZJ1 = Z[:, 1, 0, None] * J0 + Z[:, 1, 1, None] * J1
    A = J0.T @ ZJ0 + J1.T @ ZJ1
    b = J0.T @ e[:, 0] + J1.T @ e[:, 1]
    return A, b


def point_terms(p: np.ndarray, target: np.ndarray, weights: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Z and e of point targets: ``Z = w I``, ``e = w (target - p)``, (n, 2, 2), (n, 2)."""
    w = np.asarray(weights, dtype=np.float64)
    Z = w[:, None, None] * np.eye(2)[None]
    return Z, w[:, None] * (target - p)


def prior_terms(w: np.ndarray, prior: Prior, lam: float, offset: int = N_POSE
                ) -> tuple[np.ndarray, np.ndarray]:
    """Tikhonov prior ``λ yᵀ C⁻¹ y`` on the gauge coordinates ``y = Qᵀ (w + Q Δy - μ)``.

    Returns additions to ``(A, b)`` of size ``offset + k`` (pose unknowns first).
    """
    k = prior.Q.shape[1]
    P = offset + k
    A = np.zeros((P, P))
    b = np.zeros(P)
    y = prior.Q.T @ (w - prior.mean)
    A[offset:, offset:] = lam * prior.inv_cov
    b[offset:] = -lam * (prior.inv_cov @ y)
    return A, b


def project_to_gauge(w: np.ndarray, prior: Prior) -> np.ndarray:
    """The nearest weights on the mode's gauge hyperplane: ``μ + Q Qᵀ (w - μ)``."""
    return prior.mean + prior.Q @ (prior.Q.T @ (np.asarray(w, float) - prior.mean))


def solve_step(A: np.ndarray, b: np.ndarray, *, damping: float = 1e-4) -> np.ndarray:
    """Solve ``(A + damping diag(A) + ε I) δ = b`` (Levenberg-damped Gauss-Newton step)."""
    d = np.diag(A).copy()
    eps = 1e-12 * max(float(d.max(initial=0.0)), 1e-12)
    M = A + np.diag(damping * d + eps)
    try:
        return np.linalg.solve(M, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M, b, rcond=None)[0]


def schur_reduce(A: np.ndarray, b: np.ndarray, n_first: int = N_POSE
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Eliminate the first ``n_first`` unknowns (the frame's pose) from ``A x = b``.

    Returns the reduced system ``(S, c)`` for the remaining unknowns:
    ``S = A_22 - A_21 A_11⁻¹ A_12``, ``c = b_2 - A_21 A_11⁻¹ b_1``.
    """
    A11, A12 = A[:n_first, :n_first], A[:n_first, n_first:]
    A21, A22 = A[n_first:, :n_first], A[n_first:, n_first:]
    reg = 1e-9 * max(float(np.trace(A11)), 1e-12) * np.eye(n_first)
    K = np.linalg.solve(A11 + reg, np.concatenate([A12, b[:n_first, None]], axis=1))
    return A22 - A21 @ K[:, :-1], b[n_first:] - A21 @ K[:, -1]


def fit_points(model, vertices: np.ndarray, targets: np.ndarray, *,
               state: FrameState | None = None, point_weights: np.ndarray | None = None,
               modes: tuple[str, ...] | None = None, prior: float = 1.0,
               priors: dict | None = None, iterations: int = 30, tol: float = 1e-10,
               fix_pose: bool = False) -> FrameState:
    """Fit pose and weights so model vertices project onto 2-D targets (Eq. (7)-(9), §5.2).

    Coordinate descent over ``modes`` (Eq. (8), (9)); each step solves the pose and one mode's
    weights together by Gauss-Newton with the prior of :class:`Prior` (weight ``prior``,
    relative to a mean squared pixel error: the data term is the weighted *mean* of the squared
    distances).

    Parameters
    ----------
    model : MultilinearModel
    vertices : (k,) int
        Model vertices with targets.
    targets : (k, 2) float
        Pixel positions.
    state : FrameState, optional
        Start (default: mean weights and an affine pose fit).
    point_weights : (k,) float, optional
    modes : tuple of str, optional
        Modes to solve (default all); the others stay fixed.
    prior : float
        ``λ`` of the Tikhonov prior (0 = none).
    iterations : int
        Coordinate-descent sweeps.
    fix_pose : bool
        Keep the pose fixed (solve weights only).

    Returns
    -------
    FrameState
    """
    v = np.asarray(vertices, dtype=np.int64)
    T = np.asarray(targets, dtype=np.float64)
    if T.shape != (v.size, 2):
        raise ShapeError(f"targets must be ({v.size}, 2), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise TrackError("landmark targets must be finite")
    pw = np.ones(v.size) if point_weights is None else np.asarray(point_weights, float)
    pw = pw / pw.sum()
    modes = tuple(model.mode_names) if modes is None else tuple(modes)
    priors = priors or {m: Prior.from_model(model, m) for m in modes}
    if state is None:
        w0 = model.default_weights()
        w0.update({m: priors[m].mean.copy() for m in modes})
        X = model.synthesize(w0, vertices=v)
        state = FrameState(fit_affine_pose(X, T), w0)
    pose = state.pose
    weights = {k: (project_to_gauge(x, priors[k]) if k in priors else np.asarray(x, float).copy())
               for k, x in state.weights.items()}
    prev = np.inf
    for _ in range(max(int(iterations), 1)):
        for m in modes:
            pose, weights[m] = _point_step(model, m, weights, pose, v, T, pw, priors[m], prior,
                                           fix_pose)
        X = model.synthesize(weights, vertices=v)
        p = project(X, pose.rotation, pose.scale, pose.translation)
        err = float(np.sum(pw * np.sum((p - T) ** 2, axis=1)))
        if abs(prev - err) <= tol * max(err, 1e-30) or err < 1e-24:
            break
        prev = err
    return FrameState(pose, weights)


def _point_step(model, m: str, weights: dict, pose: Pose, v: np.ndarray, T: np.ndarray,
                pw: np.ndarray, prior_m: Prior, prior: float, fix_pose: bool
                ) -> tuple[Pose, np.ndarray]:
    """One Gauss-Newton step of :func:`fit_points` for the pose and mode ``m`` (Eq. (8), (9)):
    vertices ``v`` (k,) toward targets ``T`` (k, 2) with point weights ``pw`` (k,) summing to
    1. Returns the new pose and the mode's new weights (r,)."""
    B = model.mode_basis(m, weights, vertices=v)
    X = B @ weights[m]
    p = project(X, pose.rotation, pose.scale, pose.translation)
    Q = prior_m.Q                                  # gauge: (r, k)
    J = full_jacobian(X, B @ Q, pose)
    Z, e = point_terms(p, T, pw)
    A, b = normal_equations(J, Z, e)
    if prior > 0:
        Ap, bp = prior_terms(weights[m], prior_m, prior)
        A, b = A + Ap, b + bp
    if fix_pose:
        d = np.zeros(A.shape[0])
        d[N_POSE:] = solve_step(A[N_POSE:, N_POSE:], b[N_POSE:])
    else:
        d = solve_step(A, b)
    return compose(pose, d[:N_POSE]), weights[m] + Q @ d[N_POSE:]


# -------------------------------------------------------------------------------- fast path
try:  # numba is a dependency; the numpy functions above are the reference and the fallback
    import numba as _nb
except ImportError:  # pragma: no cover
    _nb = None


def _flow_normal_py(X, BQ, R, s, Z, e, A, b, G):  # pragma: no cover (compiled by numba)
    n, _, k = BQ.shape
    P = 6 + k
    J = np.zeros((2, P))
    for i in range(n):
        y0 = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2]
        y1 = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2]
        y2 = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2]
        # pose columns (see camera.pose_jacobian)
        J[0, 0] = 0.0
        J[0, 1] = s * y2
        J[0, 2] = -s * y1
        J[0, 3] = s * y0
        J[0, 4] = 1.0
        J[0, 5] = 0.0
        J[1, 0] = s * y2
        J[1, 1] = 0.0
        J[1, 2] = -s * y0
        J[1, 3] = -s * y1
        J[1, 4] = 0.0
        J[1, 5] = 1.0
        # weight columns: s F R[:2] M_{m,i} Q (Eq. (8))
        for c in range(k):
            bx, by, bz = BQ[i, 0, c], BQ[i, 1, c], BQ[i, 2, c]
            J[0, 6 + c] = s * (R[0, 0] * bx + R[0, 1] * by + R[0, 2] * bz)
            J[1, 6 + c] = -s * (R[1, 0] * bx + R[1, 1] * by + R[1, 2] * bz)
        z00 = Z[i, 0, 0]
        z01 = Z[i, 0, 1]
        z11 = Z[i, 1, 1]
        for p in range(P):
            zj0 = z00 * J[0, p] + z01 * J[1, p]
            zj1 = z01 * J[0, p] + z11 * J[1, p]
            b[p] += J[0, p] * e[i, 0] + J[1, p] * e[i, 1]
            for q in range(p, P):
                A[p, q] += zj0 * J[0, q] + zj1 * J[1, q]
                G[p, q] += J[0, p] * J[0, q] + J[1, p] * J[1, q]
    for p in range(P):
        for q in range(p):
            A[p, q] = A[q, p]
            G[p, q] = G[q, p]


_flow_normal_nb = _nb.njit(cache=True, fastmath=True, nogil=True)(_flow_normal_py) if _nb else None


def flow_normal_equations(X: np.ndarray, BQ: np.ndarray, pose: Pose, Z: np.ndarray,
                          e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal equations of the stacked Eq. (8) systems, built point by point (numba).

    Equals ``normal_equations(full_jacobian(X, BQ, pose), Z, e)`` without forming ``J``.

    Parameters
    ----------
    X : (n, 3)
        Tracked vertices (model units).
    BQ : (n, 3, k)
        Eq. (9) basis times the gauge basis.
    pose : Pose
    Z : (n, 2, 2), e : (n, 2)

    Returns
    -------
    A : (6 + k, 6 + k)
    b : (6 + k,)
    G : (6 + k, 6 + k)
        ``Σ J_iᵀ J_i`` (the pixel metric of the unknowns).
    """
    k = BQ.shape[2]
    A = np.zeros((6 + k, 6 + k))
    b = np.zeros(6 + k)
    G = np.zeros((6 + k, 6 + k))
    fn = _flow_normal_nb if _flow_normal_nb is not None else _flow_normal_py
    fn(np.ascontiguousarray(X, np.float64), np.ascontiguousarray(BQ, np.float64),
       np.ascontiguousarray(pose.rotation, np.float64), float(pose.scale),
       np.ascontiguousarray(Z, np.float64), np.ascontiguousarray(e, np.float64), A, b, G)
    return A, b, G

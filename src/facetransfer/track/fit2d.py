"""Small pure solvers for fitting the model to 2-D points: weak-perspective pose, bounded
activations, clip identity (the building blocks of :mod:`facetransfer.track.capture`).

Every residual is measured in units of the face size (the outer eye-corner distance ``iod`` of
the frame's detections), so the weights of the terms do not depend on the image resolution.
A 2-D target set is ``(p, w)``: pixel positions ``(n, 2)`` and per-point weights ``(n,)`` (0 where
unknown). The camera is Eq. (7): ``p = s F R[:2] X + t``.

For a linear basis ``D`` (the ARKit deltas) the projected basis ``Y = s F R[:2] D`` need not be
formed per frame: its normal matrix is ``s² Σ_ab (R[:2]ᵀR[:2])_ab C_ab`` of the pose-free moments
``C`` (:func:`gram_blocks`, once per shape and nominal weights; :func:`rig_normal`).

References
----------
Vlasic et al. 2005, §5.1, Eq. (7)-(9); the bounded activation step is a box-constrained
quadratic program solved by cyclic coordinate descent (projected Gauss-Seidel), checked against
``scipy.optimize.lsq_linear`` in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Pose

__all__ = ["Targets", "project_basis", "pose_gauss_newton", "box_qp", "normal_terms",
           "targets_normal", "gram_blocks", "rig_normal", "rig_solve"]

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


@dataclass(frozen=True)
class Targets:
    """A frame's 2-D target sets, stacked (see the module notes).

    Attributes
    ----------
    p : (T, n, 2) float64
        Pixel targets per set, 0 where unknown.
    w : (T, n) float64
        Their weights, 0 where unknown.
    nominal : (n,) float64
        The weights summed over the sets as they would be with every point known: the
        :func:`gram_blocks` of a clip are made for these (:func:`rig_normal`).
    """

    p: np.ndarray
    w: np.ndarray
    nominal: np.ndarray

    @classmethod
    def stack(cls, targets: list, nominal: np.ndarray | None = None) -> "Targets":
        """From a list of ``(p (n, 2), w (n,))`` (``p`` NaN allowed: its weight is set to 0);
        ``nominal`` defaults to the summed weights."""
        p = np.stack([np.asarray(p_, np.float64) for p_, _ in targets])
        w = np.stack([np.asarray(w_, np.float64) for _, w_ in targets])
        bad = ~np.isfinite(p).all(-1)
        if bad.any():
            p[bad] = 0.0
            w[bad] = 0.0
        return cls(p, w, w.sum(0) if nominal is None else np.asarray(nominal, np.float64))

    def __len__(self) -> int:
        return len(self.p)


def pose_gauss_newton(X: np.ndarray, targets, pose: Pose, iod: float, *,
                      iterations: int = 2, damping: float = 1e-6) -> Pose:
    """Gauss-Newton steps of the weak-perspective pose (Eq. (7)) for fixed 3-D points.

    Each step solves ``(JᵀWJ + damping I) δ = JᵀW r`` (``J``: :func:`~.camera.pose_jacobian`,
    ``r``: target minus projection, in iod units), clips the rotation and log-scale steps to
    ±0.3 and applies ``δ`` by :func:`~.camera.compose` (one compiled kernel).

    Parameters
    ----------
    X : (n, 3) float64
        Model points.
    targets : list of (p (n, 2), w (n,)), or Targets
        Weighted 2-D targets of the same points (weights 0 where unknown).
    pose : Pose
        Start.
    iod : float
        Face size in pixels (residual unit).

    Returns
    -------
    Pose
    """
    tg = targets if isinstance(targets, Targets) else Targets.stack(targets)
    X = np.ascontiguousarray(X, np.float64)
    R = np.ascontiguousarray(pose.rotation, np.float64)
    s, t = float(pose.scale), np.ascontiguousarray(pose.translation, np.float64)
    for _ in range(iterations):
        R, s, t = _pose_step(X, tg.p, tg.w, R, s, t, float(iod), float(damping))
    return Pose(R, s, t)


@njit(cache=True)
def _pose_step(X, p, w, R, s, t, iod, damping):  # pragma: no cover (compiled)
    """One damped Gauss-Newton step of Eq. (7) and its update (camera.compose)."""
    A = np.zeros((6, 6))
    b = np.zeros(6)
    jx = np.zeros(6)
    jy = np.zeros(6)
    jx[4] = 1.0
    jy[5] = 1.0
    for i in range(6):
        A[i, i] = damping
    i2 = iod * iod
    for n in range(X.shape[0]):
        ws, rx, ry = 0.0, 0.0, 0.0                     # Σ_t w_t, Σ_t w_t r_t at this point
        y0 = R[0, 0] * X[n, 0] + R[0, 1] * X[n, 1] + R[0, 2] * X[n, 2]
        y1 = R[1, 0] * X[n, 0] + R[1, 1] * X[n, 1] + R[1, 2] * X[n, 2]
        for k in range(p.shape[0]):
            if w[k, n] != 0.0:
                ws += w[k, n]
                rx += w[k, n] * (p[k, n, 0] - (s * y0 + t[0]))
                ry += w[k, n] * (p[k, n, 1] - (-(s * y1) + t[1]))
        if ws == 0.0:
            continue
        y2 = R[2, 0] * X[n, 0] + R[2, 1] * X[n, 1] + R[2, 2] * X[n, 2]
        jx[1], jx[2], jx[3] = s * y2, -s * y1, s * y0             # camera.pose_jacobian
        jy[0], jy[2], jy[3] = s * y2, -s * y0, -s * y1
        ws, rx, ry = ws / i2, rx / i2, ry / i2
        for a in range(6):
            b[a] += jx[a] * rx + jy[a] * ry
            for c in range(a + 1):
                A[a, c] += ws * (jx[a] * jx[c] + jy[a] * jy[c])
    for a in range(6):
        for c in range(a):
            A[c, a] = A[a, c]
    d = np.linalg.solve(A, b)
    for a in range(4):
        d[a] = min(max(d[a], -0.3), 0.3)
    return _compose(R, s, t, d)


@njit(cache=True)
def _compose(R, s, t, d):  # pragma: no cover (compiled)
    """camera.compose: ``R <- orthonormalize(exp([ω]x) R)``, ``s <- s e^σ``, ``t <- t + τ``."""
    th = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    K = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    E = np.eye(3) + K
    if th >= 1e-12:
        E = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th ** 2 * (K @ K)
    Rn = E @ R
    r0 = Rn[0] / np.sqrt(np.sum(Rn[0] * Rn[0]))
    r1 = Rn[1] - np.sum(Rn[1] * r0) * r0
    r1 = r1 / np.sqrt(np.sum(r1 * r1))
    out = np.empty((3, 3))
    out[0], out[1] = r0, r1
    out[2, 0] = r0[1] * r1[2] - r0[2] * r1[1]
    out[2, 1] = r0[2] * r1[0] - r0[0] * r1[2]
    out[2, 2] = r0[0] * r1[1] - r0[1] * r1[0]
    return out, s * np.exp(d[3]), t + d[4:6]


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


def gram_blocks(D: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted second moments of a 3-D basis, the pose-free part of Eq. (9)'s normal matrix.

    ``C[a, b] = Σ_p w_p D[:, p, a] D[:, p, b]ᵀ``: with ``Y = s F R[:2] D`` (Eq. (7), ``FᵀF = I``)
    ``Σ_p w_p Y_pᵀ Y_p = s² Σ_ab M_ab C[a, b]`` for ``M = R[:2]ᵀ R[:2]`` (:func:`rig_normal`), so a
    frame's normal matrix costs nine ``(k, k)`` sums instead of a ``(k, 2n)`` product.

    Parameters
    ----------
    D : (k, n, 3) float64
        Basis (e.g. the ARKit deltas at the tracked points).
    w : (n,) float64
        Point weights.

    Returns
    -------
    (3, 3, k, k) float64
        Symmetric: ``C[a, b] = C[b, a]ᵀ``.
    """
    Dt = np.ascontiguousarray(np.moveaxis(D, 2, 0))                        # (3, k, n)
    k = D.shape[0]
    C = np.empty((3, 3, k, k))
    for a in range(3):
        Dw = Dt[a] * w
        for b in range(a, 3):
            C[a, b] = Dw @ Dt[b].T
            C[b, a] = C[a, b].T
    return C


def rig_normal(D: np.ndarray, blocks: np.ndarray, nominal: np.ndarray, pose: Pose,
               p: np.ndarray, w: np.ndarray, base: np.ndarray, iod: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`targets_normal` of ``project_basis(D, pose)`` from precomputed :func:`gram_blocks`.

    ``G = s²/iod² (Σ_ab M_ab C_ab + Σ_{p: w_p ≠ n_p} (w_p - n_p) D_p M D_pᵀ)`` with ``M =
    R[:2]ᵀ R[:2]``, ``C = gram_blocks(D, nominal)`` and ``w = Σ_t w_t`` (the correction runs over
    the few points whose summed weight ``w_p`` differs from the nominal ``n_p``: lost points,
    missing flow); ``h = s/iod² D (R[:2]ᵀ F Σ_t w_t (p_t - base))``, one ``(k, 3n)`` product.

    Parameters
    ----------
    D : (k, n, 3) float64
    blocks : (3, 3, k, k) float64
        ``gram_blocks(D, nominal)``.
    nominal : (n,) float64
    pose : Pose
    p : (T, n, 2) float64
        Target sets (pixels; finite).
    w : (T, n) float64
        Their weights.
    base : (n, 2) float64
        The projection the residuals ``p - base`` are measured from.
    iod : float

    Returns
    -------
    G : (k, k), h : (k,)
        As :func:`targets_normal` (Eq. (9) at a fixed pose, Eq. (7)).

    References
    ----------
    Vlasic et al. 2005, Eq. (7), (9).
    """
    k = len(D)
    return _rig_normal(D.reshape(k, -1), blocks.reshape(9, -1), nominal, pose.rotation,
                       float(pose.scale), p, w, base, float(iod))


def rig_solve(D: np.ndarray, blocks: np.ndarray, pose: Pose, targets: Targets,
              base: np.ndarray, iod: float, x0: np.ndarray, *,
              ridge: np.ndarray, rhs: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              sweeps: int = 200, tol: float = 1e-7) -> np.ndarray:
    """The bounded activations of one frame at a fixed pose: :func:`box_qp` of
    ``(G + diag(ridge), h + rhs)`` with ``G, h`` from :func:`rig_normal`, in one compiled call.

    Parameters
    ----------
    D, pose, base, iod
        As :func:`rig_normal`.
    blocks : (3, 3, k, k) float64
        ``gram_blocks(D, targets.nominal)``.
    targets : Targets
        The frame's target sets (``p``, ``w`` and ``nominal`` of :func:`rig_normal`).
    x0 : (k,) float64
        Start (clipped into the box).
    ridge : (k,) float64
        Added to the diagonal of ``G`` (priors, temporal terms).
    rhs : (k,) float64
        Added to ``h`` (their pulls, minus a sparsity weight).
    lo, hi : (k,) float64
        Bounds.

    Returns
    -------
    (k,) float64

    References
    ----------
    Vlasic et al. 2005, Eq. (7), (9).
    """
    k = len(D)
    x = np.minimum(np.maximum(np.asarray(x0, np.float64), lo), hi)        # np.clip, new array
    return _rig_solve(D.reshape(k, -1), blocks.reshape(9, -1), targets.nominal, pose.rotation,
                      float(pose.scale), targets.p, targets.w, base, float(iod),
                      np.ascontiguousarray(ridge, np.float64),
                      np.ascontiguousarray(rhs, np.float64), x,
                      np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64),
                      int(sweeps), float(tol))


@njit(cache=True)
def _rig_normal(D2, B9, nominal, R, s, p, w, base, iod):  # pragma: no cover (compiled)
    """rig_normal on ``D2 = D.reshape(k, 3n)``, ``B9 = blocks.reshape(9, k²)``."""
    k, n = D2.shape[0], nominal.shape[0]
    M = np.empty(9)                                                        # R[:2]ᵀ R[:2]
    for a in range(3):
        for b in range(3):
            M[3 * a + b] = R[0, a] * R[0, b] + R[1, a] * R[1, b]
    G = np.dot(M, B9).reshape(k, k)                                        # Σ_ab M_ab C_ab
    v = np.zeros(3 * n)                                                    # R[:2]ᵀ F Σ_t w_t r_t
    odd = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        wt, rx, ry = 0.0, 0.0, 0.0
        for t in range(w.shape[0]):
            wt += w[t, i]
            rx += w[t, i] * (p[t, i, 0] - base[i, 0])
            ry += w[t, i] * (p[t, i, 1] - base[i, 1])
        for c in range(3):
            v[3 * i + c] = R[0, c] * rx - R[1, c] * ry
        if wt != nominal[i]:                                   # off its nominal weight
            odd[m] = i
            m += 1
    if m:
        E, Ew = np.empty((k, 3 * m)), np.empty((k, 3 * m))
        for j in range(m):
            i = odd[j]
            dw = -nominal[i]
            for t in range(w.shape[0]):
                dw += w[t, i]
            for r in range(k):
                for a in range(3):
                    E[r, 3 * j + a] = D2[r, 3 * i + a]
                    Ew[r, 3 * j + a] = dw * (D2[r, 3 * i] * M[a] + D2[r, 3 * i + 1] * M[3 + a]
                                             + D2[r, 3 * i + 2] * M[6 + a])
        G += np.dot(Ew, E.T)
    c = s / (iod * iod)
    return G * (s * c), np.dot(D2, v) * c


@njit(cache=True)
def _rig_solve(D2, B9, nominal, R, s, p, w, base, iod, ridge, rhs, x, lo, hi, sweeps,
               tol):  # pragma: no cover (compiled)
    G, h = _rig_normal(D2, B9, nominal, R, s, p, w, base, iod)
    for j in range(G.shape[0]):
        G[j, j] += ridge[j]
    return _box_qp(G, h + rhs, x, lo, hi, sweeps, tol)


@njit(cache=True)
def _box_qp(G, h, x, lo, hi, sweeps, tol):  # pragma: no cover (compiled)
    """Cyclic coordinate descent keeping the residual ``g = h - G x`` up to date: a coordinate
    that moves costs one column update, one held at its bound nothing (the fresh dot product
    of every coordinate in every sweep was latency-bound: ~4x slower on the 51 ARKit shapes)."""
    k = x.shape[0]
    Gt = np.ascontiguousarray(G.T)                       # rows of Gt: columns of G
    g = h.copy()
    for j in range(k):
        for m in range(k):
            g[m] -= G[m, j] * x[j]
    for _ in range(sweeps):
        change = 0.0
        for j in range(k):
            new = x[j] + g[j] / G[j, j]
            if new < lo[j]:
                new = lo[j]
            elif new > hi[j]:
                new = hi[j]
            d = new - x[j]
            if d != 0.0:
                x[j] = new
                for m in range(k):
                    g[m] -= Gt[j, m] * d
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
    lo_, hi_ = np.full(k, lo, np.float64), np.full(k, hi, np.float64)   # broadcast copies
    x = np.minimum(np.maximum(np.asarray(x0, np.float64), lo_), hi_)      # np.clip, new array
    return _box_qp(np.ascontiguousarray(G, np.float64), np.ascontiguousarray(h, np.float64), x,
                   lo_, hi_, int(sweeps), float(tol))

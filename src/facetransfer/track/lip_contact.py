"""The lips' contact in the capture fit: a shut mouth's lips touch, they do not cross.

For a fixed identity the face is linear in one frame's ARKit activations ``a`` (the bilinear
model of Vlasic et al. 2005, Eq. (5), with the identity contracted: ``X(a) = N + Σ_j a_j Δ_j``,
:class:`~facetransfer.track.capture_points.Shape`), so the gap between an upper and a lower
inner-lip vertex along the face's up axis ``u`` is linear too::

    gap_i(a) = uᵀ (N_up(i) - N_low(i)) + Σ_j a_j uᵀ (Δ_j,up(i) - Δ_j,low(i)) = g0_i + C_i a

at the inner-lip landmark pairs :data:`LIP_PAIRS` (iBUG 61-67, 62-66, 63-65). Combinations of
the lip shapes (mouthClose, the rolls, shrugs and presses against jawOpen) hold the lips'
outline while moving the upper inner lip below the lower one: the model's lips pass through
each other (``benchmarks/bench_shut_mouth.py``), which no bound on a single activation can
forbid. The frame's expression step (Eq. (9), a box-constrained quadratic program) therefore
gets the inequalities ``g0 + C a >= min(0, g0)`` (the lips may touch; an identity whose lips
cross at rest, as one of the synthetic benchmark's FaceKit faces does, keeps its own contact:
the expression is not made to part them): where the box solution satisfies them it is kept as
it is; otherwise :func:`contact_qp` solves the program with them (their Lagrange multipliers
maximise the dual: semi-smooth Newton steps where they reach its KKT point, L-BFGS-B where they
do not; each evaluation a warm-started box solve).

The gap is measured on the model's mesh (without the clip's offset of the tracked points: the
lips an animator sees), in model units, along ``u`` = the neutral face's chin (iBUG 8) to nose
bridge (27) direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fit2d import _box_qp, njit

__all__ = ["LIP_PAIRS", "LipContact", "lip_contact", "contact_qp"]

#: iBUG (upper, lower) inner-lip landmark pairs along the mouth
LIP_PAIRS = ((61, 67), (62, 66), (63, 65))


@dataclass(frozen=True)
class LipContact:
    """The inner-lip gaps ``g0 + C a`` of one identity's rig (module notes).

    Attributes
    ----------
    g0 : (q,) float64
        The neutral face's gaps at :data:`LIP_PAIRS` (model units).
    C : (q, K) float64
        Each activation's change of them.
    floor : (q,) float64
        The least gaps allowed: 0 (the lips may touch), or the neutral face's own gap where
        that is less (an identity whose lips cross at rest: the expression is not
        made to part them); :func:`lip_contact`.
    """

    g0: np.ndarray
    C: np.ndarray
    floor: np.ndarray

    def gaps(self, a: np.ndarray) -> np.ndarray:
        """The gaps ``g0 + C a`` (q,) of activations ``a`` (K,)."""
        return self.g0 + self.C @ a

    def crossed(self, a: np.ndarray) -> bool:
        """Whether any gap of ``a`` (K,) is below its :attr:`floor`."""
        return bool(np.min(self.C @ a - (self.floor - self.g0)) < 0.0)

    def solve(self, G: np.ndarray, h: np.ndarray, a: np.ndarray, lo: np.ndarray,
              hi: np.ndarray) -> np.ndarray:
        """:func:`contact_qp` with these gaps held at or above their :attr:`floor`; ``a`` (K,)
        the box solution, returned as it is where no gap is below it."""
        if not self.crossed(a):
            return a
        return contact_qp(G, h, a, lo, hi, self.C, self.floor - self.g0)


def lip_contact(neutral: np.ndarray, deltas: np.ndarray) -> LipContact:
    """The :class:`LipContact` of a rig at the tracked points (rows 0-67: the iBUG landmark
    vertices of the mesh).

    Parameters
    ----------
    neutral : (P, 3) float64
        The rig's neutral face (without the clip's offset), model units.
    deltas : (K, P, 3) float64
        Its activations' displacements.
    """
    up = neutral[27] - neutral[8]
    up = up / np.linalg.norm(up)
    upper, lower = (np.array(i) for i in zip(*LIP_PAIRS))
    g0 = (neutral[upper] - neutral[lower]) @ up                             # (q,)
    C = ((deltas[:, upper] - deltas[:, lower]) @ up).T                      # (q, K)
    return LipContact(np.ascontiguousarray(g0), np.ascontiguousarray(C), np.minimum(0.0, g0))


def contact_qp(G: np.ndarray, h: np.ndarray, a: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               C: np.ndarray, d: np.ndarray, *, iterations: int = 200, tol: float = 1e-9
               ) -> np.ndarray:
    """``argmin_a ½ aᵀ G a - hᵀ a`` subject to ``lo <= a <= hi`` and ``C a >= d``.

    The dual in the multipliers ``λ >= 0`` of ``C a >= d``: ``θ(λ) = min_{lo<=a<=hi} ½ aᵀ G a
    - hᵀ a - λᵀ (C a - d)``, attained at ``a(λ)`` = the box solution of ``(G, h + Cᵀλ)``
    (:func:`~.fit2d.box_qp`, warm-started), is concave and differentiable with gradient
    ``d - C a(λ)``. First semi-smooth Newton steps on it (compiled): ``λ_A += S⁻¹ (d - C a)_A``
    over the active constraints ``A`` (violated or ``λ > 0``), ``S = C_AF G_FF⁻¹ C_AFᵀ`` over
    the activations ``F`` strictly inside the box, ``λ = max(λ, 0)``; they are kept where they
    end at the KKT point (``a = a(λ)``, ``λ >= 0``, every gap held, the ones with ``λ > 0`` at
    their floor: the minimiser, the problem being convex), the common case. Where they do not
    (a gap whose free activations cannot move it makes ``S`` singular: the steps stop or
    cycle), ``θ`` is maximised by L-BFGS-B (a bounded quasi-Newton method, every step raising
    ``θ``). A gap no ``a`` in the box reaches is held at the most the box gives it (``d_i``
    lowered to ``max_box C_i a``); where the gaps cannot be met together (``θ`` unbounded)
    ``λ`` stops at a large cap: ``a(λ)`` stays in the box, finite, never NaN.

    Parameters
    ----------
    G : (K, K) float64
        Symmetric positive definite.
    h : (K,) float64
    a : (K,) float64
        Start (the box solution without the constraints).
    lo, hi : (K,) float64
        Bounds.
    C : (q, K) float64
    d : (q,) float64
    iterations : int
        Quasi-Newton steps at most, after at most 20 Newton steps (at the cap, ``a(λ)`` of
        the last ``λ`` is returned).
    tol : float
        Projected-gradient tolerance of the dual (the violation of ``C a >= d`` at ``λ > 0``).

    Returns
    -------
    (K,) float64

    References
    ----------
    Nocedal & Wright, Numerical Optimization (2006), §12.9 (duality), §7.2 (L-BFGS-B).
    """
    G = np.ascontiguousarray(G, np.float64)
    h, C, d = (np.ascontiguousarray(v, np.float64) for v in (h, C, d))
    lo, hi = np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64)
    x = np.minimum(np.maximum(np.asarray(a, np.float64), lo), hi)         # np.clip, new array
    d = np.minimum(d, np.maximum(C * lo, C * hi).sum(axis=1))     # a gap's most the box reaches
    x, kkt = _newton(G, h, x, lo, hi, C, d, 20, 1e-7)
    if kkt:
        return x
    from scipy.optimize import minimize  # 0.17 s to import: only where the Newton steps fail

    scale = 1e6 * (np.abs(G).max() + np.abs(h).max() + 1.0)
    cap = scale / np.maximum(np.abs(C).max(axis=1), 1e-12)                 # (q,) λ's bound
    state = [x]

    def neg_dual(lam):                                         # -θ(λ), -∇θ(λ)
        y = _box_qp(G, h + C.T @ lam, state[0].copy(), lo, hi, 5000, 1e-12)
        state[0] = y
        r = d - C @ y                                          # > 0: violated
        return -(0.5 * y @ G @ y - h @ y + lam @ r), -r

    res = minimize(neg_dual, np.zeros(len(d)), jac=True, method="L-BFGS-B",
                   bounds=[(0.0, c) for c in cap],
                   options={"maxiter": int(iterations), "gtol": float(tol), "ftol": 0.0})
    return _box_qp(G, h + C.T @ res.x, state[0].copy(), lo, hi, 5000, 1e-12)   # a(λ*)


@njit(cache=True)
def _newton(G, h, x, lo, hi, C, d, iterations, tol):  # pragma: no cover (compiled)
    """contact_qp's semi-smooth Newton steps from ``x`` (updated in place): ``(x, True)`` at
    the KKT point (gaps within ``tol``), ``(x, False)`` where they stop short of it."""
    q = C.shape[0]
    lam = np.zeros(q)
    for it in range(iterations + 1):
        r = d - C @ x                                         # > 0: violated
        act = np.zeros(q, np.bool_)
        done = True
        for i in range(q):
            act[i] = r[i] > tol or lam[i] > 0.0
            if r[i] > tol or (lam[i] > 0.0 and abs(r[i]) > tol):
                done = False
        if done:
            return x, True
        A = np.flatnonzero(act)
        F = np.flatnonzero((x > lo + 1e-9) & (x < hi - 1e-9))
        if F.size == 0 or it == iterations:                  # no free activation; the cap
            break
        Cf = np.empty((A.size, F.size))
        for i in range(A.size):
            for j in range(F.size):
                Cf[i, j] = C[A[i], F[j]]
        Gf = np.empty((F.size, F.size))
        for i in range(F.size):
            for j in range(F.size):
                Gf[i, j] = G[F[i], F[j]]
        S = Cf @ np.linalg.solve(Gf, np.ascontiguousarray(Cf.T))   # (|A|, |A|)
        ridge = 1e-9 * max(np.trace(S), 1e-12)
        for i in range(A.size):
            S[i, i] += ridge
        step = np.linalg.solve(S, r[A])
        for i in range(A.size):
            lam[A[i]] = max(lam[A[i]] + step[i], 0.0)
        x = _box_qp(G, h + C.T @ lam, x, lo, hi, 400, 1e-9)
    return x, False

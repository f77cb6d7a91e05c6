"""The paper's imputation (Vlasic et al. 2005, §4.4): stacked PPCA equations of every mode, EM.

The paper's scheme
------------------
For every attribute mode ``j`` the mode-``j`` vectors of ``T`` (columns of the unfolding
``T_(j)``, one per vertex coordinate and combination of the other attributes) are treated as
samples of a ``d_j``-dimensional Gaussian whose covariance is a probabilistic PCA,
``C_j = W_j W_j^T + σ_j² I`` [Tipping & Bishop 1999]. Its mean is taken per vertex coordinate and
mode index (the average over the other attributes, e.g. identity ``i``'s average face for the
identity mode), so that the huge shared mean shape and each identity's own shape are explained by
the mean and ``C_j`` models the *displacements* between the mode's items (who smiles how).
Given ``C_j``, every mode vector with missing entries yields the linear equations of the
conditional mean ``x_m = μ_m + C_mo C_oo^{-1} (x_o - μ_o)``; equivalently, the missing values
minimise the negative log-likelihood ``½ (x - μ)^T C_j^{-1} (x - μ)``. A missing value lies in one
mode vector of every mode, so the equations of all modes are stacked and solved together in the
least-squares sense — the objective

    J(T, {C_j}) = Σ_j ½ [ Σ_columns (x - μ)^T C_j^{-1} (x - μ) + n_j log det C_j ]

("sum over modes of the PPCA negative log-likelihood", the paper's Σ_j ||T_j - U_j J_j||² in its
probabilistic reading) is minimised over the missing values and the means (step 1, one linear
system), then over the PPCA parameters with the filled tensor (step 2, closed form), and the two
steps are repeated. Each step minimises ``J`` over its own variables, so ``J`` never rises. The
per-(coordinate, index) means are integrated out (flat prior), which is what the centred
equations of step 1 do; hence ``n_j = 3 n (N / d_j - 1)`` (REML counts, ``N`` cells).

Hard and soft imputation
------------------------
Step 1 as written ("solve the equations", ``em="hard"``) treats the guesses as data, and with a
full covariance step 2 then shrinks ``C_j`` around them: ``J`` has no lower bound (its eigenvalues
reach the floor) and the fill drifts. The default ``em="soft"`` is the proper EM of the same
model: step 2 also sees the posterior covariance ``A_mm^{-1}`` of the missing cells (one matrix
for all coordinates), and ``J`` becomes the variational free energy (``J`` with the expected
scatter minus the posterior's entropy), which also never rises. On ict-trilinear with 50 % of
the cells missing, soft EM's relative error is 5.3 % against 6.8 % for hard EM (both with full
covariances; PPCA ranks ``ceil(d_j / 2)`` make hard EM 5.5 %).

Structure that makes it fast
----------------------------
The quadratic form of mode ``j`` acts on the cells of one vertex coordinate with the matrix
``A_j = P_j ⊗ H`` (``P_j = C_j^{-1}`` on mode ``j``, ``H`` the centring matrix over the other
modes), the *same* for all ``3 n`` coordinates. Hence step 1 is one ``(n_missing × n_missing)``
solve, ``X_m = B X_k`` with ``B = -A_mm^{-1} A_mk``, and step 2 needs only the Gram matrix of the
cells, ``G = X X^T``, which is ``G_kk`` (computed once) transformed by ``B``. No iteration touches
the ``3 n``-long vectors; the cost is one Gram product and one final fill. An over-relaxed step
[Salakhutdinov & Roweis 2003], kept only when it lowers ``J`` further, halves the iterations.
Cells must number at most a few thousand (``A`` is ``N × N``).

References
----------
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4.
Tipping & Bishop 1999, "Probabilistic principal component analysis", J. R. Stat. Soc. B 61(3).
Salakhutdinov & Roweis 2003, "Adaptive overrelaxed bound optimization methods", ICML.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
import scipy.linalg

from ..arrays import check_iterations, real_array
from ..errors import DatasetError, ShapeError
from .cells import Progress, check_tensor, validate_mask
from .ppca import FLOOR, ppca_eigen

log = logging.getLogger(__name__)

__all__ = ["MAX_CELLS", "mode_scatters", "mode_operator", "joint_operator", "solve_missing",
           "TensorImputation", "impute_tensor"]

#: Largest number of cells :func:`impute_tensor` accepts (it builds N × N matrices).
MAX_CELLS = 3000


def mode_scatters(gram: np.ndarray, shape: Sequence[int]) -> list[np.ndarray]:
    """Scatter of every mode's vectors about their per-(coordinate, index) mean, from the cell Gram.

    Parameters
    ----------
    gram : (N, N) array, N = prod(shape)
        ``G = Σ_p w_p x_p x_p^T`` over vertex coordinates ``p``, cells in C order.
    shape : (d_1, ..., d_K)

    Returns
    -------
    list of (d_j, d_j) arrays
        ``S_j = Σ_p Σ_o (x_{p,:,o} - x̄_{p,:})(x_{p,:,o} - x̄_{p,:})^T`` where ``o`` runs over the
        other modes' index combinations and ``x̄`` is the mean over ``o``.
    """
    shape = tuple(shape)
    K = len(shape)
    Gt = np.asarray(gram).reshape(shape + shape)
    out = []
    for j in range(K):
        d = shape[j]
        n_o = int(np.prod(shape)) // d
        Gj = np.moveaxis(Gt, (j, K + j), (0, 1)).reshape(d, d, n_o, n_o)
        S = np.einsum("abii->ab", Gj) - Gj.sum(axis=(2, 3)) / n_o
        out.append((S + S.T) / 2)
    return out


def mode_operator(precision: np.ndarray, shape: Sequence[int], mode: int) -> np.ndarray:
    """Quadratic form of one mode on the cells of one coordinate: ``A_j = P_j ⊗ H``.

    ``x^T A_j x = Σ_o (x_{:,o} - x̄)^T P_j (x_{:,o} - x̄)`` for a cell vector ``x`` (C order).

    Parameters
    ----------
    precision : (d_j, d_j) array, ``P_j = C_j^{-1}``
    shape : (d_1, ..., d_K)
    mode : int, 0-based attribute mode ``j``

    Returns
    -------
    (N, N) array
    """
    shape = tuple(shape)
    n_o = int(np.prod(shape)) // shape[mode]
    eye = np.ones((1, 1))
    ones = np.ones((1, 1))
    for k, d in enumerate(shape):
        if k == mode:
            eye, ones = np.kron(eye, precision), np.kron(ones, precision)
        else:
            eye, ones = np.kron(eye, np.eye(d)), np.kron(ones, np.ones((d, d)))
    return eye - ones / n_o


def joint_operator(precisions: Sequence[np.ndarray], shape: Sequence[int]) -> np.ndarray:
    """``A = Σ_j A_j``: the equations of all modes stacked (§4.4, "solve them together")."""
    return sum(mode_operator(P, shape, j) for j, P in enumerate(precisions))


def solve_missing(operator: np.ndarray, missing: np.ndarray) -> np.ndarray:
    """Least-squares fill of the missing cells: ``B = -A_mm^{-1} A_mk``, so ``x_m = B x_k``.

    Parameters
    ----------
    operator : (N, N) symmetric positive semi-definite ``A``
    missing : (N,) bool

    Returns
    -------
    (n_missing, n_known) array
    """
    return _solve_posterior(operator, missing)[0]


def _solve_posterior(operator: np.ndarray, missing: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """``B = -A_mm^{-1} A_mk``, the posterior covariance ``A_mm^{-1}`` and its log-determinant."""
    m = np.asarray(missing, dtype=bool)
    Amm = operator[np.ix_(m, m)]
    Amk = operator[np.ix_(m, ~m)]
    Amm = (Amm + Amm.T) / 2
    try:
        cf = scipy.linalg.cho_factor(Amm, lower=True)
        B = -scipy.linalg.cho_solve(cf, Amk)
        Sig = scipy.linalg.cho_solve(cf, np.eye(Amm.shape[0]))
        logdet = -2.0 * float(np.sum(np.log(np.diag(cf[0]))))
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        raise DatasetError("the imputation equations are singular: some missing cell is not tied "
                           "to any known cell") from None
    return B, (Sig + Sig.T) / 2, logdet


def _full_gram(Gkk: np.ndarray, B: np.ndarray, inv_perm: np.ndarray) -> np.ndarray:
    """Cell Gram ``G = X X^T`` with ``X_m = B X_k``, back in C order of the cells."""
    Gmk = B @ Gkk
    G = np.block([[Gkk, Gmk.T], [Gmk, Gmk @ B.T]])  # cells ordered [known, missing]
    return G[np.ix_(inv_perm, inv_perm)]


def _resolve_ranks(ranks, shape, mode_names) -> list[int | None]:
    K = len(shape)
    if ranks is None:
        return [None] * K
    if isinstance(ranks, Mapping):
        names = list(mode_names) if mode_names is not None else [str(k) for k in range(K)]
        unknown = set(ranks) - set(names)
        if unknown:
            raise ValueError(f"PPCA ranks for unknown mode(s) {sorted(unknown)}; modes are {names}")
        out = [ranks.get(n) for n in names]
    else:
        out = list(ranks)
        if len(out) != K:
            raise ValueError(f"{len(out)} PPCA ranks for {K} modes")
    for r, d in zip(out, shape):
        if r is not None and not 1 <= int(r) <= d:
            raise ValueError(f"PPCA rank {r} must be between 1 and {d}")
    return [None if r is None else int(r) for r in out]


@dataclass(frozen=True)
class TensorImputation:
    """Result of :func:`impute_tensor`.

    Attributes
    ----------
    tensor : (P, d_1, ..., d_K) float64, filled
    history : tuple of float
        Objective ``J`` (sum over modes of the PPCA negative log-likelihood) per iteration.
    iterations : int
    converged : bool
    covariances : tuple of (d_j, d_j) arrays, the final mode covariances
    """

    tensor: np.ndarray
    history: tuple[float, ...]
    iterations: int
    converged: bool
    covariances: tuple[np.ndarray, ...] = ()


def impute_tensor(tensor: np.ndarray, mask: np.ndarray, *, ranks=None,
                  row_weights: np.ndarray | None = None, tol: float = 1e-6, max_iter: int = 100,
                  mode_names: Sequence[str] | None = None,
                  labels: Sequence[Sequence[str]] | None = None,
                  em: str = "soft", accelerate: bool = True, modes: Sequence[int] | None = None,
                  init: np.ndarray | None = None,
                  progress: Progress | None = None) -> TensorImputation:
    """The paper's imputation (§4.4) of whole missing cells of a ``(P, d_1..d_K)`` tensor.

    Parameters
    ----------
    tensor : (P, d_1, ..., d_K) array
        Mode 0 holds the ``P = 3 n`` vertex coordinates; missing cells may hold anything (NaN).
    mask : (d_1, ..., d_K) bool
        True where the cell is known.
    ranks : sequence or mapping of int or None, optional
        PPCA latent dimension per attribute mode (``None``: full-covariance Gaussian).
    row_weights : (P,) array, optional
        Non-negative weight of each coordinate in the covariance estimates (e.g. to emphasise the
        mouth). The fill of each coordinate is its own least-squares solution either way.
    tol : float
        Stop when the imputed values change by less than this (relative Frobenius norm).
    max_iter : int
    mode_names, labels : optional, for error messages
    em : {"soft", "hard"}
        ``hard``: the paper's least-squares fill, alternating with the PPCA update; ``J`` as in the
        module docstring. ``soft``: proper EM, the PPCA update also sees the posterior covariance
        ``A_mm^{-1}`` of the missing cells (the same for every coordinate), and ``J`` is the
        variational free energy (``J`` with the expected scatter, minus the posterior's entropy).
        Both never raise their ``J``; ``soft`` does not shrink the covariances around its own
        guesses and is more accurate at high missing fractions.
    init : (P, d_1, ..., d_K) array, optional
        A complete first guess (e.g. the averaging baseline's); the mode covariances start from
        it instead of from isotropic ones.
    modes : sequence of int, optional
        Attribute modes (0-based) whose equations are used (default all; for ablations).
    accelerate : bool
        Try an over-relaxed step ``B + η (B_new - B)`` each iteration [Salakhutdinov & Roweis
        2003] and keep it only when it lowers ``J`` more than the plain step (so ``J`` still never
        rises).
    progress : callable(done, total), optional

    Returns
    -------
    TensorImputation

    References
    ----------
    Vlasic et al. 2005, §4.4 "Description" and "Probabilistic Interpretation";
    Tipping & Bishop 1999.
    """
    mask = validate_mask(mask, np.shape(tensor)[1:], mode_names=mode_names, labels=labels)
    T = check_tensor(tensor, mask)
    ranks_l = _resolve_ranks(ranks, mask.shape, mode_names)
    if em not in ("soft", "hard"):
        raise ValueError(f"em must be 'soft' or 'hard', got {em!r}")
    check_iterations(max_iter, tol, "impute_tensor")
    P = T.shape[0]
    missing = ~mask.ravel()
    Y = T.reshape(P, -1)
    w = _check_row_weights(row_weights, P)
    offset, Yk0, Gkk, n_eff = _centred_known(Y, missing, w)
    if not missing.any():
        return TensorImputation(T.copy(), (), 0, True, ())
    if mask.size > MAX_CELLS:
        raise DatasetError(f"{mask.size} cells {mask.shape}: the §4.4 solver builds cells × cells "
                           f"matrices and supports at most {MAX_CELLS} cells; use method "
                           f"'average' for larger data sets")
    prob = _problem(mask.shape, missing, Gkk, n_eff, ranks_l, modes, em == "soft")
    prob, B, post = _initial_fill(prob, Y, offset, w, init)
    B, fit, history, it, converged = _iterate(prob, B, post, tol=tol, max_iter=max_iter,
                                              accelerate=accelerate, progress=progress)
    filled = Y.copy()
    filled[:, missing] = offset + Yk0 @ B.T
    return TensorImputation(filled.reshape(T.shape), tuple(history), it, converged,
                            tuple(fit.covariances))


# ------------------------------------------------------------------ the steps of impute_tensor
@dataclass(frozen=True)
class _Problem:
    """What stays fixed while :func:`impute_tensor` iterates.

    Attributes
    ----------
    shape : (d_1, ..., d_K) cells
    missing : (N,) bool, the missing cells in C order
    gram : (n_known, n_known) float64
        ``G_kk``, Gram matrix of the known cells (coordinates centred and weighted).
    n_eff : float, total weight of the coordinates (``P`` unweighted)
    n_cols : K floats, REML sample counts ``n_eff (N / d_j - 1)`` of the mode covariances
    active : modes whose equations are stacked
    ranks : K PPCA latent dimensions (``None``: full covariance)
    inv_perm : (N,) int, cells ordered [known, missing] back to C order
    soft : bool, soft (proper) EM rather than hard imputation
    floors : K eigenvalue floors of the mode covariances (set by the first fill)
    """

    shape: tuple[int, ...]
    missing: np.ndarray
    gram: np.ndarray
    n_eff: float
    n_cols: tuple[float, ...]
    active: tuple[int, ...]
    ranks: tuple[int | None, ...]
    inv_perm: np.ndarray
    soft: bool
    floors: tuple[float, ...] = ()


@dataclass(frozen=True)
class _ModeFit:
    """Step 2's result: ``J`` and the PPCA model of every mode (identity for unused modes)."""

    objective: float
    precisions: tuple[np.ndarray, ...]
    covariances: tuple[np.ndarray, ...]


def _check_row_weights(row_weights: np.ndarray | None, P: int) -> np.ndarray | None:
    """``row_weights`` as a (P,) float64 array of non-negative weights (``None`` stays ``None``)."""
    if row_weights is None:
        return None
    w = real_array(row_weights, "row_weights")   # (before, complex: its real part taken)
    if w.shape != (P,):
        raise ShapeError(f"row_weights must be ({P},) non-negative, got shape {w.shape}")
    if (w < 0).any() or not np.isfinite(w).all() or w.sum() <= 0:   # the shape was said
        raise ValueError(f"row_weights must be finite, non-negative and not all zero, got "
                         f"{int((w < 0).sum())} negative, "
                         f"{int(w.size - np.count_nonzero(np.isfinite(w)))} NaN or infinite, "
                         f"sum {float(np.nansum(w)):g}")
    return w


def _centred_known(Y: np.ndarray, missing: np.ndarray, w: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Known cells centred per coordinate, and their weighted Gram matrix.

    ``J`` is invariant to a per-coordinate constant, so the known cells' mean is taken out.

    Parameters
    ----------
    Y : (P, N) cells as columns
    missing : (N,) bool
    w : (P,) coordinate weights or None

    Returns
    -------
    offset : (P, 1), Yk0 : (P, n_known) centred known cells, gram : (n_known, n_known),
    n_eff : float, total coordinate weight
    """
    Yk = Y[:, ~missing]
    offset = Yk.mean(axis=1, keepdims=True)  # J is invariant to a per-coordinate constant
    Yk0 = Yk - offset
    if w is None:
        return offset, Yk0, Yk0.T @ Yk0, float(Y.shape[0])
    return offset, Yk0, (Yk0 * w[:, None]).T @ Yk0, float(w.sum())


def _problem(shape, missing, gram, n_eff, ranks, modes, soft) -> _Problem:
    """The fixed parts of the iteration; ValueError if no mode gives equations."""
    N = missing.size
    # REML sample counts: the per-(coordinate, index) mean takes one of n_o columns
    n_cols = tuple(n_eff * (N // d - 1) for d in shape)
    use = range(len(shape)) if modes is None else [int(j) for j in modes]
    active = tuple(j for j in range(len(shape)) if n_cols[j] > 0 and j in use)
    if not active:
        raise ValueError(f"no attribute mode gives equations (modes={list(use)})")
    inv_perm = np.argsort(np.concatenate([np.flatnonzero(~missing), np.flatnonzero(missing)]))
    return _Problem(tuple(shape), missing, gram, n_eff, n_cols, active, tuple(ranks), inv_perm,
                    soft)


def _e_step(prob: _Problem, precs) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Step 1 (§4.4 "solve them together"): the joint least-squares fill ``X_m = B X_k``.

    Returns
    -------
    B : (n_missing, n_known)
    Sig : (n_missing, n_missing) posterior covariance ``A_mm^{-1}`` (soft EM), else None
    logdet : float, its log-determinant
    """
    A = sum(mode_operator(precs[j], prob.shape, j) for j in prob.active)
    B, Sig, logdet = _solve_posterior(A, prob.missing)
    return B, (Sig if prob.soft else None), logdet


def _scatters(prob: _Problem, B: np.ndarray, Sig: np.ndarray | None) -> list[np.ndarray]:
    """Mode scatters ``S_j`` of the filled cells (expected scatters if ``Sig`` is given)."""
    G = _full_gram(prob.gram, B, prob.inv_perm)
    if Sig is not None:
        N, nm = prob.missing.size, int(prob.missing.sum())
        mm = prob.inv_perm >= N - nm  # cells that are missing, in C order
        G[np.ix_(mm, mm)] += prob.n_eff * Sig[np.ix_(prob.inv_perm[mm] - (N - nm),
                                                     prob.inv_perm[mm] - (N - nm))]
    return mode_scatters(G, prob.shape)


def _m_step(prob: _Problem, B: np.ndarray, Sig: np.ndarray | None, logdet: float) -> _ModeFit:
    """Step 2: ML PPCA of every mode from the filled tensor (Tipping & Bishop 1999), and ``J``."""
    S = _scatters(prob, B, Sig)
    covs, precs, obj = [], [], 0.0
    for j, d in enumerate(prob.shape):
        if j not in prob.active:
            covs.append(np.eye(d))
            precs.append(np.zeros((d, d)))
            continue
        U, c = ppca_eigen(S[j] / prob.n_cols[j], prob.ranks[j], prob.floors[j])
        covs.append((U * c) @ U.T)
        precs.append((U / c) @ U.T)
        obj += 0.5 * (float(np.sum((U.T @ S[j] @ U).diagonal() / c))
                      + prob.n_cols[j] * float(np.sum(np.log(c))))
    if Sig is not None:  # minus the entropy of the Gaussian posterior of the missing cells
        obj -= 0.5 * prob.n_eff * logdet
    return _ModeFit(obj, tuple(precs), tuple(covs))


def _initial_fill(prob: _Problem, Y: np.ndarray, offset: np.ndarray, w: np.ndarray | None,
                  init: np.ndarray | None
                  ) -> tuple[_Problem, np.ndarray, tuple[np.ndarray | None, float]]:
    """Step 1 with isotropic modes (which also sets the eigenvalue floors), or from ``init``.

    Returns the problem with its floors, ``B`` and step 1's ``(Sig, logdet)``.
    """
    B, Sig, logdet = _e_step(prob, [np.eye(d) for d in prob.shape])
    S0 = _scatters(prob, B, Sig)
    prob = replace(prob, floors=tuple(
        FLOOR * max(float(np.trace(S0[j])) / (max(n, 1e-300) * d), 1e-300)
        for j, (n, d) in enumerate(zip(prob.n_cols, prob.shape))))
    if init is not None:  # mode covariances of a given complete guess, then step 1
        B, Sig, logdet = _e_step(prob, _guess_precisions(prob, Y, offset, w, init))
    return prob, B, (Sig, logdet)


def _guess_precisions(prob: _Problem, Y: np.ndarray, offset: np.ndarray, w: np.ndarray | None,
                      init: np.ndarray) -> list[np.ndarray]:
    """PPCA precisions ``(d_j, d_j)`` of every mode of a complete first guess ``init``."""
    P = Y.shape[0]
    Z = real_array(init, "init")
    if Z.shape != (P,) + prob.shape:   # a wrong size failed in the reshape, naming no shape
        raise ShapeError(f"init must be a finite tensor of shape {(P,) + prob.shape}, got "
                         f"{Z.shape}")
    Z = Z.reshape(P, -1) - offset
    if not np.isfinite(Z[:, prob.missing]).all():
        raise ShapeError(f"init must be a finite tensor of shape {(P,) + prob.shape}")
    Zf = Y.copy() - offset
    Zf[:, prob.missing] = Z[:, prob.missing]
    Sg = mode_scatters((Zf * (1.0 if w is None else w[:, None])).T @ Zf, prob.shape)
    precs = []
    for j, d in enumerate(prob.shape):
        U, c = ppca_eigen(Sg[j] / max(prob.n_cols[j], 1e-300), prob.ranks[j], prob.floors[j])
        precs.append((U / c) @ U.T)
    return precs


def _iterate(prob: _Problem, B: np.ndarray, post: tuple[np.ndarray | None, float], *,
             tol: float, max_iter: int, accelerate: bool, progress: Progress | None):
    """Steps 1 and 2 repeated until the fill changes by less than ``tol``.

    Returns
    -------
    B : (n_missing, n_known) the final fill, fit : _ModeFit, history : list of J (one more than
    the iterations: J at the returned fill last), iterations : int, converged : bool
    """
    history: list[float] = []
    converged = False
    it = 0
    fit = _m_step(prob, B, *post)
    eta = 1.0
    for it in range(1, max_iter + 1):
        history.append(fit.objective)
        B_new, Sig, logdet = _e_step(prob, fit.precisions)  # step 1
        cand = _m_step(prob, B_new, Sig, logdet)  # step 2
        if accelerate:
            B_new, cand, eta = _over_relax(prob, B, B_new, cand, (Sig, logdet), eta)
        change = _fill_change(prob.gram, B, B_new)
        B, fit = B_new, cand
        log.debug("impute iteration %d: J = %.9g, change %.3e", it, fit.objective, change)
        if progress is not None:
            progress(it, max_iter)
        if change < tol:
            converged = True
            break
    history.append(fit.objective)  # J at the returned fill
    return B, fit, history, it, converged


def _over_relax(prob: _Problem, B: np.ndarray, B_new: np.ndarray, cand: _ModeFit,
                post: tuple[np.ndarray | None, float], eta: float
                ) -> tuple[np.ndarray, _ModeFit, float]:
    """Over-relaxed fill ``B + η (B_new - B)`` (Salakhutdinov & Roweis 2003), kept only if J ends
    lower still; returns the step taken, its fit and the next ``η`` (reset to 1 on failure)."""
    eta = min(2.0 * eta, 64.0)
    B_try = B + eta * (B_new - B)
    trial = _m_step(prob, B_try, *post)
    if trial.objective < cand.objective:
        return B_try, trial, eta
    return B_new, cand, 1.0


def _fill_change(gram: np.ndarray, B: np.ndarray, B_new: np.ndarray) -> float:
    """Relative Frobenius change of the filled cells, ``||(B_new - B) X_k|| / ||B_new X_k||``."""
    dB = B_new - B
    num = float(np.sum((dB @ gram) * dB))
    den = float(np.sum((B_new @ gram) * B_new))
    return float(np.sqrt(max(num, 0.0) / max(den, 1e-300)))

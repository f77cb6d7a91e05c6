"""Multilinear algebra (Vlasic et al. 2005, §3): unfoldings, mode-n products, N-mode SVD, ALS.

This module knows nothing about faces. It is built for the shapes of face data: one huge mode
(vertex coordinates, 3 × 30,000) and a few small attribute modes (≤ 100). Small modes are
factored through their Gram matrices (d_n × d_n), so no SVD of the huge unfolding is ever taken,
and the huge mode may be left unfactored (``skip``), which is the paper's Eq. (4).

Unfolding convention
--------------------
``unfold(T, n)`` moves axis ``n`` to the front and reshapes in C (row-major) order::

    unfold(T, n)[i_n, j] with j enumerating the remaining indices in their original order,
    the last index varying fastest.

This is the convention of ``tensorly`` (and of Kolda & Bader up to a column permutation, which
changes no column space, Gram matrix or singular value). Mode numbers are 0-based here: the paper's
mode 1 (vertices) is our mode 0, its mode 2 our mode 1, and so on.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .arrays import check_iterations, real_array
from .errors import FaceTransferError, ShapeError

log = logging.getLogger(__name__)

__all__ = [
    "TensorShapeError",
    "unfold",
    "fold",
    "mode_dot",
    "multi_mode_dot",
    "mode_gram",
    "leading_eigvecs",
    "ranks_for_variance",
    "Tucker",
    "nmode_svd",
    "hooi",
    "attribute_gram",
    "tucker_to_tensor",
]


class TensorShapeError(ShapeError):
    """Shapes of a tensor and a matrix (or a rank list) do not agree.

    A :class:`facetransfer.errors.ShapeError` (so a ``ValueError``), as every other shape error
    of the library."""


def _check_mode(tensor: np.ndarray, mode: int) -> int:
    if not -tensor.ndim <= mode < tensor.ndim:
        raise TensorShapeError(f"mode {mode} out of range for a tensor of shape {tensor.shape}")
    return mode % tensor.ndim


def unfold(tensor: np.ndarray, mode: int) -> np.ndarray:
    """Mode-n unfolding (matricization).

    Parameters
    ----------
    tensor : (d_0, ..., d_{N-1}) array
    mode : int
        0-based mode ``n``.

    Returns
    -------
    (d_n, prod_{m != n} d_m) array
        Columns are the mode-n vectors (Fig. 2 of the paper), ordered as described in the module
        docstring.
    """
    tensor = np.asarray(tensor)
    mode = _check_mode(tensor, mode)
    return np.moveaxis(tensor, mode, 0).reshape(tensor.shape[mode], -1)


def fold(matrix: np.ndarray, mode: int, shape: Sequence[int]) -> np.ndarray:
    """Inverse of :func:`unfold`: ``fold(unfold(T, n), n, T.shape) == T``.

    Parameters
    ----------
    matrix : (shape[n], prod of the other dims) array
    mode : int
    shape : sequence of int
        Shape of the tensor to rebuild.
    """
    shape = tuple(int(s) for s in shape)
    if not -len(shape) <= mode < len(shape):
        raise TensorShapeError(f"mode {mode} out of range for a tensor of shape {shape}")
    mode = mode % len(shape)
    matrix = np.asarray(matrix)
    rest = [s for i, s in enumerate(shape) if i != mode]
    if matrix.shape != (shape[mode], int(np.prod(rest))):
        raise TensorShapeError(
            f"matrix of shape {matrix.shape} cannot be folded in mode {mode} into shape {shape}")
    return np.moveaxis(matrix.reshape([shape[mode]] + rest), 0, mode)


def mode_dot(tensor: np.ndarray, matrix: np.ndarray, mode: int) -> np.ndarray:
    """Mode-n product ``T ×_n M`` (§3, "Mode-n Product").

    Every mode-n vector ``v`` of ``T`` is replaced by ``M v``.

    Parameters
    ----------
    tensor : (d_0, ..., d_n, ..., d_{N-1}) array
    matrix : (k, d_n) array, or (d_n,) vector
        A vector contracts the mode away (``T ×_n w^T`` in Eq. (5) and (9)).

    Returns
    -------
    (d_0, ..., k, ..., d_{N-1}) array, or the tensor with mode ``n`` removed for a vector.
    """
    tensor = np.asarray(tensor)
    matrix = np.asarray(matrix)
    mode = _check_mode(tensor, mode)
    if matrix.ndim == 1:
        if matrix.shape[0] != tensor.shape[mode]:
            raise TensorShapeError(f"shapes {tensor.shape} and {matrix.shape} not aligned in "
                                   f"mode-{mode} product")
        return np.tensordot(tensor, matrix, axes=([mode], [0]))
    if matrix.ndim != 2 or matrix.shape[1] != tensor.shape[mode]:
        raise TensorShapeError(f"shapes {tensor.shape} and {matrix.shape} not aligned in "
                               f"mode-{mode} product")
    out = np.tensordot(tensor, matrix, axes=([mode], [1]))  # new axis last
    return np.moveaxis(out, -1, mode)


def multi_mode_dot(tensor: np.ndarray, matrices: Sequence[np.ndarray | None],
                   modes: Sequence[int] | None = None, *, transpose: bool = False) -> np.ndarray:
    """Product with several matrices, ``T ×_{m_1} M_1 ×_{m_2} M_2 ...`` (Eq. (1), (2)).

    Parameters
    ----------
    tensor : N-way array
    matrices : sequence of (k_i, d_{m_i}) arrays, vectors, or None (skip that mode)
    modes : sequence of int, optional
        Defaults to ``range(len(matrices))``.
    transpose : bool
        Multiply by ``M_i^T`` instead (Eq. (1)); matrices then have shape ``(d_{m_i}, k_i)``.

    Notes
    -----
    Products run from the mode whose matrix shrinks the tensor the most, which keeps the
    intermediate small; vectors (which remove a mode) are applied in decreasing mode order so
    the remaining mode numbers stay valid.
    """
    if modes is None:
        modes = list(range(len(matrices)))
    if len(modes) != len(matrices):
        raise TensorShapeError(f"{len(matrices)} matrices for {len(modes)} modes")
    tensor = np.asarray(tensor)
    pairs = []
    for m, M in zip(modes, matrices):
        if M is None:
            continue
        M = np.asarray(M)
        if transpose and M.ndim == 2:
            M = M.T
        pairs.append((_check_mode(tensor, m), M))
    mats = [(m, M) for m, M in pairs if M.ndim == 2]
    vecs = [(m, M) for m, M in pairs if M.ndim == 1]
    # shrink first: order by ratio of new to old size
    mats.sort(key=lambda p: p[1].shape[0] / max(p[1].shape[1], 1))
    for m, M in mats:
        tensor = mode_dot(tensor, M, m)
    for m, v in sorted(vecs, key=lambda p: -p[0]):
        tensor = mode_dot(tensor, v, m)
    return tensor


def mode_gram(tensor: np.ndarray, mode: int) -> np.ndarray:
    """Gram matrix of the mode-n unfolding, ``unfold(T, n) @ unfold(T, n).T``, shape (d_n, d_n).

    Computed with one contraction over all other modes; its eigenvectors are the left singular
    vectors of the unfolding (the N-mode SVD factor, §3) without an SVD of the huge matrix.
    """
    tensor = np.asarray(tensor)
    mode = _check_mode(tensor, mode)
    A = unfold(tensor, mode)
    return A @ A.T


def leading_eigvecs(gram: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Leading eigenpairs of a symmetric PSD matrix, in decreasing order.

    Returns
    -------
    vectors : (d, rank) array, orthonormal columns, sign fixed so the largest-magnitude entry of
        each column is positive (a deterministic choice).
    eigenvalues : (d,) array, all eigenvalues in decreasing order, clipped at 0.
    """
    w, V = np.linalg.eigh((gram + gram.T) / 2)
    order = np.argsort(w)[::-1]
    w, V = np.clip(w[order], 0, None), V[:, order]
    V = V[:, :rank]
    idx = np.argmax(np.abs(V), axis=0)
    V = V * np.sign(V[idx, np.arange(V.shape[1])])
    return V, w


def ranks_for_variance(eigenvalues: np.ndarray, fraction: float) -> int:
    """Smallest rank whose leading eigenvalues hold at least ``fraction`` of their sum."""
    if not 0 < fraction <= 1:
        raise ValueError(f"retained variance must be in (0, 1], got {fraction}")
    total = float(np.sum(eigenvalues))
    if total <= 0:
        return 1
    cum = np.cumsum(eigenvalues) / total
    return int(min(np.searchsorted(cum, fraction - 1e-12) + 1, len(eigenvalues)))


@dataclass(frozen=True)
class Tucker:
    """Result of :func:`nmode_svd` or :func:`hooi` (Eq. (3), or Eq. (4) with skipped modes).

    Attributes
    ----------
    core : array
        Core tensor; a skipped mode keeps its full size (the paper's model tensor M, Eq. (4)).
    factors : tuple of (d_n, r_n) arrays or None
        Orthonormal-column factor per mode; ``None`` for a skipped mode.
    eigenvalues : tuple of (d_n,) arrays or None
        Eigenvalues of each mode's Gram matrix of the *data* (the squared mode-n singular values),
        for explained variance; ``None`` for skipped modes.
    errors : tuple of float
        Relative reconstruction error ``||T - T̂||_F / ||T||_F`` after the N-mode SVD and after each
        ALS sweep (non-increasing).
    """

    core: np.ndarray
    factors: tuple[np.ndarray | None, ...]
    eigenvalues: tuple[np.ndarray | None, ...]
    errors: tuple[float, ...]

    @property
    def ranks(self) -> tuple[int, ...]:
        return tuple(self.core.shape)

    def explained_variance(self, mode: int) -> np.ndarray:
        """Fraction of the data's mode-n variance held by each kept component, shape (r_n,)."""
        ev = self.eigenvalues[mode]
        if ev is None:
            raise ValueError(f"mode {mode} was not factored")
        total = ev.sum()
        r = self.core.shape[mode]
        return ev[:r] / total if total > 0 else np.zeros(r)

    def to_tensor(self) -> np.ndarray:
        """Reconstruction ``C ×_n U_n`` over the factored modes (Eq. (2)–(4))."""
        return tucker_to_tensor(self.core, self.factors)


def tucker_to_tensor(core: np.ndarray, factors: Sequence[np.ndarray | None]) -> np.ndarray:
    """``core ×_0 U_0 ×_1 U_1 ...`` skipping ``None`` factors (Eq. (2))."""
    return multi_mode_dot(core, list(factors), list(range(len(factors))))


def _factors_from_grams(shape, grams: dict[int, np.ndarray]):
    """All eigenvectors and eigenvalues of each mode's Gram (``None`` for modes not given)."""
    vecs: list[np.ndarray | None] = [None] * len(shape)
    eig: list[np.ndarray | None] = [None] * len(shape)
    for n, g in grams.items():
        vecs[n], eig[n] = leading_eigvecs(g, shape[n])
    return vecs, eig


def _resolve_ranks(shape, ranks, skip, variance, grams_eig) -> list[int]:
    out = []
    for n, d in enumerate(shape):
        if n in skip:
            out.append(d)
            continue
        r = None if ranks is None else ranks[n]
        if r is None:
            r = ranks_for_variance(grams_eig[n], variance) if variance is not None else d
        r = int(r)
        if not 1 <= r <= d:
            raise TensorShapeError(f"rank {r} for mode {n} must be between 1 and {d} "
                                   f"(tensor shape {tuple(shape)})")
        out.append(r)
    return out


def _rel_error(norm2_t: float, core: np.ndarray) -> float:
    # With orthonormal factors, ||T - T̂||² = ||T||² - ||C||² (Pythagoras on the projection).
    return float(np.sqrt(max(norm2_t - float(np.vdot(core, core)), 0.0) / norm2_t)) if norm2_t > 0 else 0.0


def nmode_svd(tensor: np.ndarray, ranks: Sequence[int | None] | None = None, *,
              skip: Sequence[int] = (), variance: float | None = None) -> Tucker:
    """Truncated N-mode SVD (HOSVD), Eq. (1)–(3); with ``skip`` it yields Eq. (4).

    Parameters
    ----------
    tensor : (d_0, ..., d_{N-1}) array
    ranks : sequence of int or None, length N, optional
        Kept components per mode; ``None`` entries (or no list) keep all, or as many as
        ``variance`` needs. Ignored for skipped modes.
    skip : sequence of int
        Modes left unfactored (the vertex mode in Eq. (4)).
    variance : float in (0, 1], optional
        Retained-variance truncation for modes without an explicit rank.

    Returns
    -------
    Tucker

    Notes
    -----
    Each factored mode's factor holds the leading eigenvectors of its Gram matrix ``T_(n) T_(n)^T``
    (d_n × d_n), equal to the left singular vectors of ``T_(n)`` [De Lathauwer 1997]. Peak memory is
    about one extra copy of the data (the unfolding made for the Gram product).

    References
    ----------
    Vlasic et al. 2005, §3, Eq. (1)–(3) and §4.3, Eq. (4).
    """
    T, norm2 = _finite_data(tensor)
    N = T.ndim
    skip = _skipped(T, skip)
    if ranks is not None and len(ranks) != N:
        raise TensorShapeError(f"{len(ranks)} ranks given for a tensor of shape {T.shape}")
    active = [n for n in range(N) if n not in skip]
    if skip and _prod(T.shape[n] for n in active) <= GRAM_LIMIT:
        # one pass over the big (skipped) mode; each mode's Gram is a partial trace of the joint one
        G, _ = attribute_gram(T, skip)
        grams = {n: _gram_contract(G, [None] * len(active), j) for j, n in enumerate(active)}
    else:
        grams = {n: mode_gram(T, n) for n in active}
    vecs, eig = _factors_from_grams(T.shape, grams)
    rk = _resolve_ranks(T.shape, ranks, skip, variance, eig)
    factors = tuple(None if vecs[n] is None else vecs[n][:, :rk[n]] for n in range(N))
    if skip and active:
        core = _kron_core(T, skip, active, [factors[n] for n in active])  # Eq. (1) / (4)
    else:
        core = multi_mode_dot(T, list(factors), transpose=True)  # Eq. (1)
    err = _rel_error(norm2, core)
    return Tucker(core, factors, tuple(eig), (err,))


def _finite_data(tensor: np.ndarray) -> tuple[np.ndarray, float]:
    """The tensor as float64 and its squared norm, refused (FaceTransferError naming its shape)
    when it holds NaN or infinities: the eigensolver would fail on them with LinAlgError
    ("Eigenvalues did not converge"), which names neither the tensor nor the cause."""
    T = real_array(tensor, "tensor", nonempty=True)   # (before, complex: its real part taken)
    norm2 = float(np.vdot(T, T))    # NaN or inf iff an entry is (or it overflows)
    if not np.isfinite(norm2):
        raise FaceTransferError(f"tensor of shape {T.shape} holds NaN or infinite values (or "
                               "values too large to square)")
    return T, norm2


def _skipped(T: np.ndarray, skip: Sequence[int]) -> set[int]:
    """The modes ``skip`` (negative: from the end) as 0-based mode numbers, each checked to be
    a mode of ``T``: one out of range would otherwise wrap onto another mode."""
    return {_check_mode(T, int(s)) for s in skip}


_LETTERS = "abcdefghijklmnopqrstuvwxyz"


def attribute_gram(tensor: np.ndarray, skip: Sequence[int]) -> tuple[np.ndarray, tuple[int, ...]]:
    """Gram matrix of the tensor over its factored ("attribute") modes jointly.

    With the skipped modes moved to the front and the tensor viewed as a ``(P_s, D)`` matrix
    ``A`` (``D`` = product of the attribute dims), returns ``A^T A`` reshaped to
    ``(d_a1, ..., d_aK, d_a1, ..., d_aK)`` and the attribute modes' order. Every N-mode SVD and ALS
    quantity of the attribute modes is a contraction of this small tensor.
    """
    N = tensor.ndim
    active = tuple(n for n in range(N) if n not in skip)
    lead = [n for n in range(N) if n in skip]
    A = np.moveaxis(tensor, lead + list(active), range(N)).reshape(-1, _prod(tensor.shape[n] for n in active))
    G = A.T @ A
    dims = tuple(tensor.shape[n] for n in active)
    return G.reshape(dims + dims), active


def _prod(xs) -> int:
    out = 1
    for x in xs:
        out *= int(x)
    return out


def _gram_contract(G: np.ndarray, projections: Sequence[np.ndarray | None], keep: int | None) -> np.ndarray:
    """Contract the attribute Gram ``G`` with ``P_m = U_m U_m^T`` on every mode but ``keep``.

    Returns the mode-``keep`` Gram matrix of ``T ×_{m≠keep} U_m^T`` (``(d_keep, d_keep)``), or, with
    ``keep=None``, the scalar ``||T ×_m U_m^T||²``. ``None`` projections mean the identity.
    """
    K = G.ndim // 2
    rows, cols = _LETTERS[:K], _LETTERS[K:2 * K]
    ops, subs = [G], [rows + cols]
    out = ""
    col_sub = list(cols)
    for m in range(K):
        if m == keep:
            continue
        if projections[m] is None:
            col_sub[m] = rows[m]  # identity: trace over the pair
        else:
            ops.append(projections[m])
            subs.append(rows[m] + cols[m])
    subs[0] = rows + "".join(col_sub)
    if keep is not None:
        out = rows[keep] + col_sub[keep]
    return np.einsum(",".join(subs) + "->" + out, *ops, optimize=True)


def _hooi_gram(T: np.ndarray, skip: set, ranks, variance, init: "Tucker | None", max_iter: int,
               tol: float, norm2: float) -> "Tucker":
    """HOOI over the attribute modes through their joint Gram matrix (see :func:`hooi`).

    The initial N-mode SVD (unless ``init`` is given) comes from the same Gram: the mode-n Gram
    of the data is its partial trace over the other attribute modes.
    """
    G, active = attribute_gram(T, skip)
    if ranks is not None and len(ranks) != T.ndim:
        raise TensorShapeError(f"{len(ranks)} ranks given for a tensor of shape {T.shape}")
    if init is None:
        full, eig = _factors_from_grams(T.shape, {n: _gram_contract(G, [None] * len(active), j)
                                                  for j, n in enumerate(active)})
        rk = _resolve_ranks(T.shape, ranks, skip, variance, eig)
        U = [full[n][:, :rk[n]] for n in active]
        eigenvalues = tuple(eig)
    else:
        U = [init.factors[n] for n in active]
        eigenvalues = init.eigenvalues
    P = [u @ u.T for u in U]
    errors = [_err_from_core_norm(norm2, float(_gram_contract(G, P, None)))]
    for it in range(max_iter):
        for j in range(len(active)):
            U[j], _ = leading_eigvecs(_gram_contract(G, P, j), U[j].shape[1])
            P[j] = U[j] @ U[j].T
        errors.append(_err_from_core_norm(norm2, float(_gram_contract(G, P, None))))
        log.debug("HOOI sweep %d: relative error %.3e", it + 1, errors[-1])
        if errors[-2] - errors[-1] <= tol * max(errors[-2], 1e-300):
            break
    factors: list[np.ndarray | None] = [None] * T.ndim
    for n, u in zip(active, U):
        factors[n] = u
    return Tucker(_kron_core(T, skip, active, U), tuple(factors), eigenvalues, tuple(errors))


def _kron_core(T: np.ndarray, skip, active, U) -> np.ndarray:
    """Core ``T ×_n U_nᵀ`` over the attribute modes (Eq. (1)/(4)) in one matrix product: the
    attribute unfolding times the Kronecker product of the factors (C order, as the unfolding)."""
    lead = [n for n in range(T.ndim) if n in skip]
    A = np.moveaxis(T, lead + list(active), range(T.ndim)).reshape(-1, _prod(T.shape[n] for n in active))
    W = U[0]
    for u in U[1:]:
        W = np.kron(W, u)
    core = (A @ W).reshape(tuple(T.shape[n] for n in lead) + tuple(u.shape[1] for u in U))
    return np.moveaxis(core, range(T.ndim), lead + list(active))


def _err_from_core_norm(norm2: float, core2: float) -> float:
    return float(np.sqrt(max(norm2 - core2, 0.0) / norm2)) if norm2 > 0 else 0.0


#: Largest product of attribute dims for which :func:`hooi` works through the attribute Gram.
GRAM_LIMIT = 4096


def hooi(tensor: np.ndarray, ranks: Sequence[int | None] | None = None, *,
         skip: Sequence[int] = (), variance: float | None = None, max_iter: int = 50,
         tol: float = 1e-10, init: Tucker | None = None) -> Tucker:
    """N-mode SVD refined by alternating least squares (HOOI) [De Lathauwer 1997], §3.

    Each sweep re-estimates one factor with the others fixed: the leading eigenvectors of the Gram
    matrix of ``T ×_{m≠n} U_m^T``. Each update maximises ``||C||`` over that factor, so the error
    ``||T - T̂||`` never rises; iteration stops when it falls by less than ``tol`` (relative).

    Parameters
    ----------
    tensor, ranks, skip, variance
        As for :func:`nmode_svd` (which provides the initial guess).
    max_iter : int
        Maximum ALS sweeps.
    tol : float
        Stop when the relative error decreases by less than this between sweeps.
    init : Tucker, optional
        Start from this decomposition instead of the N-mode SVD.

    Returns
    -------
    Tucker
        ``errors`` holds the error of the initial guess and of every sweep.
    """
    check_iterations(max_iter, tol, "hooi")
    T, norm2 = _finite_data(tensor)
    N = T.ndim
    skip = _skipped(T, skip)
    active = [n for n in range(N) if n not in skip]
    if ranks is not None and len(ranks) != N:
        raise TensorShapeError(f"{len(ranks)} ranks given for a tensor of shape {T.shape}")
    if init is not None:
        _check_init(init, T.shape, active, ranks)
    if skip and _prod(T.shape[n] for n in active) <= GRAM_LIMIT:
        # The skipped (vertex) mode is never factored, so the data enter every sweep only through
        # the small joint Gram of the attribute modes: one pass over the big tensor, then sweeps
        # of cost O(D² r) with D = d_1 ... d_K, and one final projection for the core.
        return _hooi_gram(T, skip, ranks, variance, init, max_iter, tol, norm2)
    start = init if init is not None else nmode_svd(T, ranks, skip=sorted(skip), variance=variance)
    factors = list(start.factors)
    errors = [start.errors[-1] if start.errors else _rel_error(norm2, start.core)]
    core = start.core
    for it in range(max_iter):
        for n in active:
            others = [None if (m == n or m in skip) else factors[m] for m in range(N)]
            Y = multi_mode_dot(T, others, transpose=True)
            V, _ = leading_eigvecs(mode_gram(Y, n), factors[n].shape[1])
            factors[n] = V
        core = multi_mode_dot(T, factors, transpose=True)
        err = _rel_error(norm2, core)
        errors.append(err)
        log.debug("HOOI sweep %d: relative error %.3e", it + 1, err)
        if errors[-2] - errors[-1] <= tol * max(errors[-2], 1e-300):
            break
    return Tucker(core, tuple(factors), start.eigenvalues, tuple(errors))


def _check_init(init: Tucker, shape: tuple, active: list[int], ranks) -> None:
    """:func:`hooi`'s ``init``: a factor ``(d_n, r_n)`` for every factored mode of a tensor of
    ``shape``, of the rank ``ranks`` asks where it asks one (the ranks are the init's: a rank
    given besides it would otherwise be ignored without a word)."""
    if len(init.factors) != len(shape):
        raise TensorShapeError(f"init has {len(init.factors)} factors for a tensor of shape "
                               f"{shape}")
    for n in active:
        U = init.factors[n]
        if U is None or U.ndim != 2 or U.shape[0] != shape[n]:
            raise TensorShapeError(f"init's factor of mode {n} has shape "
                                   f"{None if U is None else U.shape}, expected ({shape[n]}, r) "
                                   f"for a tensor of shape {shape}")
        r = None if ranks is None else ranks[n]
        if r is not None and int(r) != U.shape[1]:
            raise TensorShapeError(f"rank {r} asked for mode {n}, but init's factor has rank "
                                   f"{U.shape[1]}: the ranks come from init (give one or the "
                                   "other)")

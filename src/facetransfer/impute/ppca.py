"""Probabilistic PCA (Tipping & Bishop 1999): the per-mode Gaussian of §4.4's missing-data scheme.

The closed-form ML fit from a scatter matrix, its negative log-likelihood, the conditional mean of
missing entries (the linear equations §4.4 solves), and a plain EM PCA of one incomplete matrix.

References
----------
Tipping & Bishop 1999, "Probabilistic principal component analysis", J. R. Stat. Soc. B 61(3).
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..errors import DatasetError, ShapeError

__all__ = ["FLOOR", "PPCA", "ppca_eigen", "ppca_fit", "ppca_nll", "conditional_mean",
           "ppca_incomplete"]

#: Relative eigenvalue floor of the mode covariances (keeps them invertible; exact data).
FLOOR = 1e-10


@dataclass(frozen=True)
class PPCA:
    """A probabilistic PCA model ``x ~ N(mean, W W^T + σ² I)`` [Tipping & Bishop 1999].

    Attributes
    ----------
    mean : (d,) float64
    components : (d, q) float64
        ``W``; columns are orthogonal, column ``k`` has squared norm ``λ_k - σ²``.
    noise_var : float
        ``σ²``.
    """

    mean: np.ndarray
    components: np.ndarray
    noise_var: float

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    def covariance(self) -> np.ndarray:
        """``W W^T + σ² I``, shape (d, d)."""
        W = self.components
        return W @ W.T + self.noise_var * np.eye(self.dim)

    def precision(self) -> np.ndarray:
        """Inverse covariance, shape (d, d)."""
        C = self.covariance()
        return np.linalg.inv((C + C.T) / 2)


def ppca_eigen(cov: np.ndarray, rank: int | None, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvectors and model eigenvalues of the ML PPCA of a sample covariance.

    Parameters
    ----------
    cov : (d, d) array, the sample covariance
    rank : int or None, latent dimension ``q`` (``None``: full covariance)
    floor : float, lower bound on every eigenvalue

    Returns
    -------
    U : (d, d) eigenvectors, eigenvalues descending
    c : (d,) eigenvalues of the model covariance (the last ``d - q`` equal ``σ²``)
    """
    d = cov.shape[0]
    lam, U = np.linalg.eigh((cov + cov.T) / 2)
    lam, U = lam[::-1], U[:, ::-1]
    q = d if rank is None else int(rank)
    c = np.maximum(lam, floor)
    if q < d:
        s2 = max(float(np.mean(lam[q:])), floor)  # Tipping & Bishop 1999, Eq. (8)
        c = np.concatenate([np.maximum(lam[:q], s2), np.full(d - q, s2)])
    return U, c


def ppca_fit(scatter: np.ndarray, n_samples: float, rank: int | None = None, *,
             mean: np.ndarray | None = None, floor: float = 0.0) -> PPCA:
    """Maximum-likelihood PPCA from a scatter matrix (closed form).

    Parameters
    ----------
    scatter : (d, d) array
        ``Σ_s (x_s - μ)(x_s - μ)^T`` over the samples.
    n_samples : float
        Number (or total weight) of samples.
    rank : int, optional
        Latent dimension ``q``; ``None`` (or ``d``) gives the full-covariance Gaussian.
    mean : (d,) array, optional
        Stored in the result (zeros if not given).
    floor : float
        Lower bound on every eigenvalue of the covariance (the constrained ML estimate).

    Returns
    -------
    PPCA
        ``W = U_q (Λ_q - σ² I)^{1/2}``, ``σ² = mean of the discarded eigenvalues`` (Tipping &
        Bishop 1999, Eq. (7)–(8)).
    """
    S = np.asarray(scatter, dtype=np.float64)
    if S.ndim != 2 or S.shape[0] != S.shape[1]:
        raise ShapeError(f"scatter must be a square (d, d) matrix, got {S.shape}")
    if not n_samples > 0:
        raise ValueError(f"n_samples must be positive, got {n_samples}")
    d = S.shape[0]
    if rank is not None and not 1 <= rank <= d:
        raise ValueError(f"PPCA rank {rank} must be between 1 and {d}")
    U, c = ppca_eigen(S / n_samples, rank, floor)
    q = d if rank is None else int(rank)
    s2 = float(c[-1]) if q < d else 0.0
    W = U[:, :q] * np.sqrt(np.maximum(c[:q] - s2, 0.0))
    mu = np.zeros(d) if mean is None else np.asarray(mean, dtype=np.float64)
    return PPCA(mu, W, s2)


def ppca_nll(cov: np.ndarray, scatter: np.ndarray, n_samples: float) -> float:
    """Gaussian negative log-likelihood up to constants: ``½ [tr(C^{-1} S) + n log det C]``.

    Parameters
    ----------
    cov : (d, d) covariance ``C``
    scatter : (d, d) scatter ``S`` about the mean
    n_samples : float
    """
    L = np.linalg.cholesky((cov + cov.T) / 2)
    logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
    Linv_S = scipy.linalg.solve_triangular(L, scatter, lower=True)
    tr = float(np.trace(scipy.linalg.solve_triangular(L, Linv_S.T, lower=True)))
    return 0.5 * (tr + n_samples * logdet)


def conditional_mean(mean: np.ndarray, cov: np.ndarray, x: np.ndarray,
                     missing: np.ndarray) -> np.ndarray:
    """Conditional mean of the missing entries of a Gaussian vector given the known ones.

    ``x_m = μ_m + C_mo C_oo^{-1} (x_o - μ_o)`` — the linear equations a PPCA gives for missing
    values (§4.4).

    Parameters
    ----------
    mean : (d,) array
    cov : (d, d) array
    x : (d,) or (d, n) array
        Values (entries at ``missing`` are ignored); several columns share one missing pattern.
    missing : (d,) bool

    Returns
    -------
    (n_missing,) or (n_missing, n) array
    """
    m = np.asarray(missing, dtype=bool)
    o = ~m
    x = np.asarray(x, dtype=np.float64)
    mu = np.asarray(mean, dtype=np.float64)
    dx = x[o] - (mu[o] if x.ndim == 1 else mu[o][:, None])
    if not o.any():
        return mu[m] if x.ndim == 1 else np.repeat(mu[m][:, None], x.shape[1], axis=1)
    sol = np.linalg.solve(cov[np.ix_(o, o)], dx)
    out = cov[np.ix_(m, o)] @ sol
    return out + (mu[m] if x.ndim == 1 else mu[m][:, None])


def ppca_incomplete(matrix: np.ndarray, rank: int | None = None, *, tol: float = 1e-8,
                    max_iter: int = 200) -> tuple[PPCA, np.ndarray, tuple[float, ...]]:
    """PPCA of an incomplete matrix whose columns are samples, and the matrix filled.

    Alternates (i) the ML PPCA of the filled columns and (ii) replacing every missing entry by its
    conditional mean given the known entries of its column (:func:`conditional_mean`); both steps
    lower the Gaussian negative log-likelihood of the filled matrix.

    Parameters
    ----------
    matrix : (d, n) array
        NaN marks missing entries; every row needs one known entry.
    rank : int, optional
        PPCA latent dimension (``None``: full covariance).

    Returns
    -------
    ppca : PPCA
    filled : (d, n) array
    history : tuple of float
        Negative log-likelihood after each iteration (non-increasing).
    """
    X = np.array(matrix, dtype=np.float64)
    if X.ndim != 2:
        raise ShapeError(f"matrix must be (d, n), got {X.shape}")
    miss = np.isnan(X)
    if miss.all(axis=1).any():
        raise DatasetError(f"row {int(np.nonzero(miss.all(axis=1))[0][0])} of the matrix has no "
                           f"known entry")
    d, n = X.shape
    row_mean = np.nanmean(X, axis=1)
    X[miss] = np.broadcast_to(row_mean[:, None], X.shape)[miss]
    patterns: dict[bytes, list[int]] = {}
    for c in np.nonzero(miss.any(axis=0))[0]:
        patterns.setdefault(miss[:, c].tobytes(), []).append(int(c))
    history: list[float] = []
    floor = None
    for _ in range(max_iter):
        mu = X.mean(axis=1)
        Xc = X - mu[:, None]
        S = Xc @ Xc.T
        if floor is None:
            floor = FLOOR * max(float(np.trace(S)) / (d * n), 1e-300)
        model = ppca_fit(S, n, rank, mean=mu, floor=floor)
        C = model.covariance()
        history.append(ppca_nll(C, S, n))
        old = X[miss].copy()
        for key, cols in patterns.items():
            m = np.frombuffer(key, dtype=bool)
            X[np.ix_(m, cols)] = conditional_mean(mu, C, X[:, cols], m)
        change = np.linalg.norm(X[miss] - old) / max(np.linalg.norm(X[miss]), 1e-300)
        if change < tol:
            break
    return model, X, tuple(history)

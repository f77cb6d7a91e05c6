"""The imputation methods by name, and filling a face data set's missing cells (§4.4)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..arrays import real_array
from ..datasets.base import FaceDataset
from ..errors import ShapeError
from .baselines import average_impute, naive_impute, tensorly_impute
from .cells import Progress, validate_mask
from .joint import TensorImputation, impute_tensor
from .regions import dataset_regions, impute_tensor_regions

log = logging.getLogger(__name__)

__all__ = ["METHODS", "ImputeResult", "impute_tensor_by", "impute_dataset"]

#: Imputation methods understood by :func:`impute_dataset`.
METHODS = ("ppca", "average", "naive", "tensorly")


@dataclass(frozen=True)
class ImputeResult:
    """Result of :func:`impute_dataset`.

    Attributes
    ----------
    dataset : FaceDataset
        Filled (mask all True); ``provenance["imputation"]`` records the method and the imputed
        cells by label.
    imputed : (d_1, ..., d_K) bool
        Cells that were filled.
    history : tuple of float
        The method's objective per iteration (``ppca``: sum over modes of the PPCA negative
        log-likelihood, non-increasing); empty for one-shot methods.
    iterations : int
    converged : bool
    seconds : float
    """

    dataset: FaceDataset
    imputed: np.ndarray
    history: tuple[float, ...] = ()
    iterations: int = 0
    converged: bool = True
    seconds: float = 0.0


def impute_tensor_by(method: str, tensor: np.ndarray, mask: np.ndarray, *, rng=None,
                     tol: float = 1e-6, max_iter: int = 100, ranks=None,
                     row_weights: np.ndarray | None = None, mode_names=None, labels=None,
                     progress: Progress | None = None, **options) -> TensorImputation:
    """Fill a ``(P, d_1..d_K)`` tensor's missing cells with one of :data:`METHODS`."""
    if method not in METHODS:
        raise ValueError(f"unknown imputation method {method!r}; choose one of "
                         f"{', '.join(METHODS)}")
    kw = dict(mode_names=mode_names, labels=labels)
    if method == "ppca":
        memberships = options.pop("memberships", None)
        if memberships is not None:
            return impute_tensor_regions(tensor, mask, memberships, ranks=ranks, tol=tol,
                                         max_iter=max_iter, progress=progress, **kw, **options)
        return impute_tensor(tensor, mask, ranks=ranks, row_weights=row_weights, tol=tol,
                             max_iter=max_iter, progress=progress, **kw, **options)
    if method == "average":
        return TensorImputation(average_impute(tensor, mask, **kw), (), 0, True)
    if method == "naive":
        filled, steps = naive_impute(tensor, mask, progress=progress, **kw, **options)
        return TensorImputation(filled, (), steps, True)
    filled = tensorly_impute(tensor, mask, ranks=ranks, max_iter=max_iter, tol=tol, rng=rng, **kw,
                             **options)
    return TensorImputation(filled, (), 0, True)


def impute_dataset(dataset: FaceDataset, *, method: str = "ppca", rng=None, tol: float = 1e-6,
                   max_iter: int = 100, progress: Progress | None = None, ranks=None,
                   vertex_weights: np.ndarray | None = None,
                   regions: str | int | None = None) -> ImputeResult:
    """Fill the missing cells of a face data set (§4.4).

    Parameters
    ----------
    dataset : FaceDataset
        ``vertices`` (d_1..d_K, n, 3) with NaN in missing cells, ``mask`` True where known.
    method : {"ppca", "average", "naive", "tensorly"}
        ``ppca`` is the paper's scheme (:func:`impute_tensor`); the others are the baselines.
    rng : seed or Generator, optional
        Only ``tensorly`` uses randomness.
    tol, max_iter : convergence of the iterative methods
    progress : callable(done, total), optional
    ranks : mapping mode name -> PPCA latent dimension (``ppca``) or Tucker rank (``tensorly``)
    vertex_weights : (n_vertices,) array, optional
        ``ppca`` only: per-vertex weights of the covariance estimates (region emphasis).
    regions : "mouth" or int, optional
        ``ppca`` only: separate mode covariances per soft face region, fills blended
        (:func:`~.regions.region_memberships`; ``"mouth"`` is §4.4's suggested mouth emphasis).

    Returns
    -------
    ImputeResult

    Raises
    ------
    DatasetError
        A slice (identity, expression, ...) with no data at all, all cells missing, one identity,
        or NaN in a known cell.
    """
    if not isinstance(dataset, FaceDataset):
        raise TypeError(f"expected a FaceDataset, got {type(dataset).__name__}")
    t0 = time.perf_counter()
    mask = validate_mask(dataset.mask, dataset.shape, mode_names=dataset.mode_names,
                         labels=dataset.labels)
    T = dataset.data_tensor()
    row_w = _row_weights(dataset, vertex_weights)
    rk = ranks
    if method == "tensorly" and isinstance(ranks, Mapping):
        rk = [ranks.get(n, -(-d // 2)) for n, d in zip(dataset.mode_names, dataset.shape)]
    extra = {}
    if regions is not None:
        if method != "ppca":
            raise ValueError(f"regions apply to method 'ppca' only, not {method!r}")
        if vertex_weights is not None:
            raise ValueError("give either vertex_weights or regions, not both")
        extra["memberships"] = dataset_regions(dataset, regions)
    res = impute_tensor_by(method, T, mask, rng=rng, tol=tol, max_iter=max_iter, ranks=rk,
                           row_weights=row_w, mode_names=dataset.mode_names,
                           labels=dataset.labels, progress=progress, **extra)
    K = len(dataset.shape)
    verts = np.moveaxis(res.tensor, 0, K).reshape(dataset.vertices.shape)
    imputed = ~mask
    info = {"method": method, "regions": regions, "n_imputed": int(imputed.sum()),
            "cells": [list(c) for c in dataset.missing_cells()],
            "iterations": int(res.iterations), "converged": bool(res.converged)}
    out = dataset.with_vertices(np.ascontiguousarray(verts), np.ones_like(mask), imputation=info)
    dt = time.perf_counter() - t0
    log.info("imputed %d cells with %s in %.2f s (%d iterations)", info["n_imputed"], method, dt,
             res.iterations)
    return ImputeResult(out, imputed, tuple(res.history), int(res.iterations),
                        bool(res.converged), dt)


def _row_weights(dataset: FaceDataset, vertex_weights: np.ndarray | None) -> np.ndarray | None:
    """Per-vertex weights ``(n,)`` as per-coordinate weights ``(3 n,)`` (vertex-major)."""
    if vertex_weights is None:
        return None
    vw = real_array(vertex_weights, "vertex_weights")   # (before, complex: its real part taken)
    if vw.shape != (dataset.n_vertices,):
        raise ShapeError(f"vertex_weights must be ({dataset.n_vertices},), got {vw.shape}")
    return np.repeat(vw, 3)

"""Measuring §4.4's imputation: hide random known cells, predict them, score every method.

The error is the paper's (§4.4 "Evaluation"): the Frobenius norm of the error over the held-out
cells divided by that of the whole data set.

References
----------
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4, Fig. 4.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np

from ..datasets.base import FaceDataset
from ..errors import DatasetError
from .baselines import reference_indices
from .cells import validate_mask
from .joint import TensorImputation
from .methods import METHODS, impute_tensor_by
from .regions import dataset_regions

__all__ = ["EVAL_VARIANTS", "random_holdout", "EvalRecord", "ImputeEvaluation",
           "evaluate_imputation"]

#: Variants :func:`evaluate_imputation` also accepts: the paper's scheme with face regions.
EVAL_VARIANTS = {"ppca-mouth": {"regions": "mouth"}, "ppca-regions8": {"regions": 8}}


def random_holdout(mask: np.ndarray, fraction: float, rng) -> np.ndarray:
    """Hide ``fraction`` of all cells at random, never emptying a slice of any mode.

    Parameters
    ----------
    mask : (d_1..d_K) bool, cells known in the data set
    fraction : float in [0, 1)
        Fraction of *all* cells to hide (rounded); only known cells are hidden.
    rng : numpy Generator or seed

    Returns
    -------
    (d_1..d_K) bool
        The held-out cells (a subset of ``mask``).

    Raises
    ------
    DatasetError
        If that many cells cannot be hidden without emptying a slice.
    """
    if not 0 <= fraction < 1:
        raise ValueError(f"missing fraction must be in [0, 1), got {fraction}")
    rng = np.random.default_rng(rng)
    mask = np.asarray(mask, dtype=bool)
    n_hide = int(round(fraction * mask.size))
    counts = [mask.sum(axis=tuple(a for a in range(mask.ndim) if a != k)) for k in range(mask.ndim)]
    held = np.zeros_like(mask)
    cand = np.flatnonzero(mask)
    rng.shuffle(cand)
    n = 0
    for flat in cand:
        if n >= n_hide:
            break
        idx = np.unravel_index(flat, mask.shape)
        if all(counts[k][idx[k]] > 1 for k in range(mask.ndim)):
            for k in range(mask.ndim):
                counts[k][idx[k]] -= 1
            held[idx] = True
            n += 1
    if n < n_hide:
        raise DatasetError(f"cannot hide {n_hide} of {mask.size} cells without emptying a slice "
                           f"(hid {n}); lower the missing fraction")
    return held


@dataclass(frozen=True)
class EvalRecord:
    """One method at one missing fraction, over the trials (see :func:`evaluate_imputation`)."""

    method: str
    missing: float
    error_mean: float
    error_max: float
    relative_error_mean: float
    seconds: float
    errors: tuple[float, ...] = ()
    relative_errors: tuple[float, ...] = ()


@dataclass(frozen=True)
class ImputeEvaluation:
    """Result of :func:`evaluate_imputation`.

    Attributes
    ----------
    results : tuple of EvalRecord
    examples : dict
        For the Fig. 4 picture: ``{"missing": f, "cells": [(i_1..i_K), ...],
        "truth": (n_ex, n, 3), "<method>": (n_ex, n, 3) ...}`` from the first trial at one
        fraction.
    """

    results: tuple[EvalRecord, ...]
    examples: dict = field(default_factory=dict)


def _errors(pred: np.ndarray, truth: np.ndarray, held: np.ndarray, total_norm: float,
            neutral: np.ndarray) -> tuple[float, float]:
    """Paper's error (held-out error / whole data norm) and error / held-out displacement norm."""
    d = (pred - truth)[:, held]
    disp = (truth - neutral)[:, held]
    e = float(np.linalg.norm(d))
    nd = float(np.linalg.norm(disp))
    return e / total_norm, (e / nd if nd > 0 else float("nan"))


def evaluate_imputation(dataset: FaceDataset, fractions: Sequence[float], *, trials: int = 5,
                        seed: int = 0, methods: Sequence[str] = METHODS, n_examples: int = 6,
                        example_fraction: float | None = None,
                        progress: Callable[[str], None] | None = None,
                        **kw) -> ImputeEvaluation:
    """Hide random cells, predict them with every method, and measure the errors (§4.4).

    For every fraction and trial the same held-out cells are given to every method. The error is
    the paper's: Frobenius norm of the error over the held-out cells divided by the Frobenius norm
    of the whole data set; the relative error divides instead by the norm of the held-out cells'
    displacement from their identity's neutral cell.

    Parameters
    ----------
    dataset : FaceDataset
        Cells missing in the data set itself are never held out nor scored.
    fractions : sequence of float in (0, 1)
    trials : int
    seed : int
        Seeds the held-out cells (trial ``t`` of fraction ``f`` uses ``[seed, t, round(1000 f)]``).
    methods : sequence of :data:`METHODS`
    n_examples : int, held-out faces kept for Fig. 4
    example_fraction : float, optional
        Fraction whose first trial provides the examples (default: the one nearest 0.15, the
        paper's Fig. 4).
    progress : callable(str), optional, called after each (method, fraction, trial)
    **kw : passed to :func:`impute_tensor_by` (``ranks``, ``tol``, ``max_iter``)

    Returns
    -------
    ImputeEvaluation
    """
    _check_methods(methods)
    variant_memberships = {m: dataset_regions(dataset, EVAL_VARIANTS[m]["regions"])
                           for m in methods if m in EVAL_VARIANTS}
    fractions = _check_fractions(fractions, trials)
    data = _EvalData.of(dataset)
    _check_hides_cells(fractions, data.base.size)
    if example_fraction is None:
        example_fraction = min(fractions, key=lambda f: abs(f - 0.15))
    acc: dict[tuple[str, float], list[tuple[float, float, float]]] = {}
    examples: dict = {}
    for f in fractions:
        for t in range(trials):
            rng = np.random.default_rng([seed, t, int(round(1000 * f))])
            held = random_holdout(data.base, f, rng)
            want_ex = t == 0 and f == example_fraction
            if want_ex:
                examples = _example_cells(dataset, data.T, held, f, seed, n_examples)
            for m, res, dt in _run_methods(data, held, rng, methods, variant_memberships, kw):
                e, r = _errors(res.tensor, data.T, held, data.total_norm, data.neutral)
                acc.setdefault((m, f), []).append((e, r, dt))
                if want_ex:
                    examples[m] = np.stack([res.tensor[(slice(None),) + c]
                                            for c in examples["cells"]])
                if progress is not None:
                    progress(f"{m} {f:.2f} trial {t + 1}: error {e:.4f}, relative {r:.3f}")
    n = dataset.n_vertices
    for key in [k for k in examples if k not in ("missing", "cells", "labels")]:
        examples[key] = examples[key].reshape(len(examples["cells"]), n, 3)
    return ImputeEvaluation(_records(acc, methods, fractions), examples)


def check_no_repeats(values: Sequence, what: str) -> None:
    """ValueError naming the first value given twice in ``values`` (a method or fraction given
    twice was run twice, its rows reported and written twice, the report's counts doubled)."""
    seen = set()
    for v in values:
        if v in seen:
            raise ValueError(f"{what} gives {v!r} twice: give each once")
        seen.add(v)


def _check_methods(methods: Sequence[str]) -> None:
    for m in methods:
        if m not in METHODS and m not in EVAL_VARIANTS:
            raise ValueError(f"unknown imputation method {m!r}; choose from "
                             f"{', '.join(METHODS + tuple(EVAL_VARIANTS))}")
    check_no_repeats(list(methods), "methods")


def _check_fractions(fractions: Sequence[float], trials: int) -> list[float]:
    if trials < 1:
        raise ValueError(f"trials must be at least 1, got {trials}")
    fractions = [float(f) for f in fractions]
    for f in fractions:
        if not 0 < f < 1:
            raise ValueError(f"missing fractions must be in (0, 1), got {f}")
    check_no_repeats(fractions, "missing fractions")
    return fractions


def _check_hides_cells(fractions: Sequence[float], n_cells: int) -> None:
    """DatasetError for a fraction that hides no cell of a data set of ``n_cells`` (rounded to
    none; before: numpy's "need at least one array to stack", naming nothing)."""
    for f in fractions:
        if round(f * n_cells) < 1:
            raise DatasetError(f"missing fraction {f:g} hides no cell of the data set's "
                               f"{n_cells} (give more than {0.5 / n_cells:.3g})")


@dataclass(frozen=True)
class _EvalData:
    """What every trial of :func:`evaluate_imputation` scores against.

    Attributes
    ----------
    base : (d_1..d_K) bool, cells known in the data set
    T : (3 n, d_1..d_K) float64, the data tensor (NaN in missing cells)
    total_norm : float, Frobenius norm of the known cells (the paper's denominator)
    neutral : (3 n, d_1..d_K) float64
        Every cell holds its identity's neutral face (or, if that is missing in the data set, the
        identity's mean known face).
    mode_names, labels : of the data set
    """

    base: np.ndarray
    T: np.ndarray
    total_norm: float
    neutral: np.ndarray
    mode_names: tuple[str, ...]
    labels: tuple[tuple[str, ...], ...]

    @classmethod
    def of(cls, dataset: FaceDataset) -> "_EvalData":
        base = validate_mask(dataset.mask, dataset.shape, mode_names=dataset.mode_names,
                             labels=dataset.labels)
        T = dataset.data_tensor()
        K = len(dataset.shape)
        ref = reference_indices(dataset.mode_names, dataset.labels, dataset.shape)
        # each identity's neutral (or, if it is missing in the data set, its mean known face)
        neutral = np.empty_like(T)
        for i in range(dataset.shape[0]):
            if base[(i,) + ref]:
                face = T[(slice(None), i) + ref]
            else:
                face = T[:, i][:, base[i]].mean(axis=1)
            neutral[:, i] = face.reshape((-1,) + (1,) * (K - 1))
        return cls(base, T, float(np.linalg.norm(T[:, base])), neutral, dataset.mode_names,
                   dataset.labels)


def _example_cells(dataset: FaceDataset, T: np.ndarray, held: np.ndarray, fraction: float,
                   seed: int, n_examples: int) -> dict:
    """Up to ``n_examples`` held-out cells for Fig. 4, with labels and true meshes (3 n,)."""
    cells = list(zip(*np.nonzero(held)))
    pick = np.random.default_rng([seed, 99]).permutation(len(cells))[:n_examples]
    cells = [tuple(int(v) for v in cells[p]) for p in sorted(pick)]
    return {"missing": fraction, "cells": cells,
            "labels": ["/".join(dataset.labels[k][i] for k, i in enumerate(c)) for c in cells],
            "truth": np.stack([T[(slice(None),) + c] for c in cells])}


def _run_methods(data: _EvalData, held: np.ndarray, rng, methods: Sequence[str],
                 variant_memberships: dict, kw: dict
                 ) -> Iterator[tuple[str, TensorImputation, float]]:
    """Each method's fill of the data with ``held`` hidden, and its seconds, in order."""
    mask = data.base & ~held
    Tin = data.T.copy()
    Tin[:, ~mask] = np.nan
    names = dict(mode_names=data.mode_names, labels=data.labels)
    for m in methods:
        t0 = time.perf_counter()
        if m in variant_memberships:
            res = impute_tensor_by("ppca", Tin, mask, memberships=variant_memberships[m],
                                   **names, **kw)
        else:
            res = impute_tensor_by(m, Tin, mask, rng=rng, **names, **kw)
        yield m, res, time.perf_counter() - t0


def _records(acc: dict, methods: Sequence[str], fractions: Sequence[float]
             ) -> tuple[EvalRecord, ...]:
    """One :class:`EvalRecord` per (method, fraction) from the trials' (error, relative, s)."""
    results = []
    for m in methods:
        for f in fractions:
            v = np.array(acc[(m, f)])
            results.append(EvalRecord(m, f, float(v[:, 0].mean()), float(v[:, 0].max()),
                                      float(np.nanmean(v[:, 1])), float(v[:, 2].mean()),
                                      tuple(float(x) for x in v[:, 0]),
                                      tuple(float(x) for x in v[:, 1])))
    return tuple(results)

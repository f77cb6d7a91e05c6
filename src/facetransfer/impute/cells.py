"""The cells of an incomplete data set (§4.4): the mask of known cells and the tensor checks every
imputation method shares."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from ..arrays import real_array
from ..errors import DatasetError, ShapeError

__all__ = ["Progress", "validate_mask", "check_tensor"]

Progress = Callable[[int, int], None]


def validate_mask(mask: np.ndarray, shape: Sequence[int], *,
                  mode_names: Sequence[str] | None = None,
                  labels: Sequence[Sequence[str]] | None = None) -> np.ndarray:
    """Check that a mask of known cells can be imputed; return it as a bool array.

    Parameters
    ----------
    mask : (d_1, ..., d_K) array of bool (True = known)
    shape : the data set's cells ``(d_1, ..., d_K)``
    mode_names, labels : optional, used to name the offending slice

    Raises
    ------
    DatasetError
        The mask's shape differs, every cell is missing, there is only one identity (mode 0), or
        some slice of some mode (e.g. one identity, one expression) has no known cell at all.
    """
    shape = tuple(int(s) for s in shape)
    m = np.asarray(mask)
    if m.shape != shape:
        raise DatasetError(f"mask shape {m.shape} does not match the data set's cells {shape}")
    if m.dtype != bool:
        if not np.isin(m, (0, 1)).all():
            raise DatasetError("mask must be boolean (True = known cell)")
        m = m.astype(bool)
    names = list(mode_names) if mode_names is not None else [f"mode {k}" for k in range(len(shape))]
    if shape[0] < 2:
        raise DatasetError(f"imputation needs at least 2 {names[0]}s (mode 0), got {shape[0]}")
    if not m.any():
        raise DatasetError(f"all {m.size} cells are missing: nothing to impute from")
    for k in range(len(shape)):
        axes = tuple(a for a in range(len(shape)) if a != k)
        has = m.any(axis=axes) if axes else m
        if not has.all():
            i = int(np.nonzero(~has)[0][0])
            which = (f"{names[k]} {labels[k][i]!r} (mode {k} {names[k]!r}, index {i})"
                     if labels is not None and mode_names is not None else
                     f"{names[k]} index {i}")   # before: "mode 0 '0' (mode 0 'mode 0', index 0)"
            raise DatasetError(f"{which} has no known cell (mask {shape}): a slice with no "
                               "data at all cannot be imputed")
    return m


def check_tensor(tensor: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The ``(P, d_1..d_K)`` tensor as float64, its cells matching ``mask`` and finite where known.

    Raises
    ------
    ShapeError
        The tensor does not have one more mode than the mask, has no coordinates, or holds
        other than real numbers (complex, text).
    DatasetError
        Its cells differ from the mask's, or a known cell holds NaN or infinite coordinates.
    """
    T = real_array(tensor, "tensor")    # (before, complex: its real part; text: numpy's error)
    if T.ndim != mask.ndim + 1:
        raise ShapeError(f"tensor must be (3n, d_1..d_K) with cells {mask.shape}, got {T.shape}")
    if T.shape[1:] != mask.shape:
        raise DatasetError(f"mask shape {mask.shape} does not match the tensor's cells "
                           f"{T.shape[1:]}")
    if T.shape[0] == 0:
        raise ShapeError(f"tensor {T.shape} has no vertex coordinates (mode 0 is empty)")
    known = T.reshape(T.shape[0], -1)[:, mask.ravel()]
    if not np.isfinite(known).all():
        raise DatasetError("known cells contain NaN or infinite coordinates")
    return T

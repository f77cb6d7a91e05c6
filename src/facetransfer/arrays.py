"""Numbers at the public boundary: an array converted to float64 once, and refused with one
clear :class:`~facetransfer.errors.ShapeError` naming what it is and its shape.

``np.asarray(x, dtype=np.float64)`` alone casts complex values to their real part (with only a
``ComplexWarning``), and fails on strings or ragged lists with numpy's own message, which names
neither the argument nor what was expected. The model's weights, the tensor algebra's tensors
and the imputation's tensor, init and row and vertex weights are converted here (other
modules' validators keep their own checks and errors: meshes, scans, tracks).
"""

from __future__ import annotations

import numpy as np

from .errors import ShapeError

__all__ = ["real_array", "check_iterations"]


def real_array(values, what: str, *, finite: bool = False, nonempty: bool = False
               ) -> np.ndarray:
    """``values`` as a float64 array, refused unless it holds real numbers.

    Parameters
    ----------
    values : array_like
        Integers, booleans or floats (any nesting that numpy reads as one array).
    what : str
        What the values are, for the message (e.g. ``"weights of mode 'identity'"``).
    finite : bool
        Also refuse NaN and infinite values (the message counts them).
    nonempty : bool
        Also refuse an array with no elements (the message gives its shape).

    Returns
    -------
    np.ndarray
        float64, the same shape (a copy only where a conversion needed one).

    Raises
    ------
    ShapeError
        Complex, text, object or ragged values; with ``finite``, NaN or infinities; with
        ``nonempty``, no elements.
    """
    try:
        raw = np.asarray(values)
    except ValueError:     # ragged nesting: numpy names neither the argument nor the fix
        raise ShapeError(f"{what} must be an array of real numbers, got a ragged sequence "
                         "(rows of different lengths)") from None
    if raw.dtype.kind not in "biuf":
        kind = {"c": "complex", "U": "text", "S": "text",
                "O": "Python object"}.get(raw.dtype.kind, str(raw.dtype))
        raise ShapeError(f"{what} must be real numbers, got {kind} values of shape "
                         f"{raw.shape}")
    a = raw.astype(np.float64, copy=False)
    if nonempty and a.size == 0:
        raise ShapeError(f"{what} is empty (shape {a.shape})")
    if finite and not np.isfinite(a).all():
        bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        raise ShapeError(f"{what} holds {bad} NaN or infinite value(s) (shape {a.shape})")
    return a


def check_iterations(max_iter, tol, where: str) -> None:
    """The options every iterative solver shares, checked: ``max_iter`` an integer >= 0 and
    ``tol`` a real number, not NaN (a negative ``max_iter`` ran no iteration and a NaN ``tol``
    never stopped early, each without a word; a negative ``tol``, never stopping early, is a
    choice).

    Raises
    ------
    ValueError
        Naming ``where`` (the function) and the value given.
    """
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise ValueError(f"{where}: max_iter must be an integer >= 0, got {max_iter!r}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.integer, np.floating)) \
            or np.isnan(tol):
        raise ValueError(f"{where}: tol must be a number (not NaN), got {tol!r}")

"""Reading ``.npz`` files so that any damage is one clear error naming the file.

``numpy.load`` answers a truncated, empty or foreign file with many exception types
(``zipfile.BadZipFile``, ``EOFError``, ``ValueError`` with numpy's ``allow_pickle`` hint, ``OSError``,
``KeyError``, ``zlib.error``…). :func:`read_npz` turns all of them into the caller's
:class:`~facetransfer.errors.FaceTransferError` subclass, with the path and what was expected.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError


def check_input_file(path: str | os.PathLike, what: str,
                     error: type[FaceTransferError] = FaceTransferError) -> Path:
    """``path`` as a Path if it is an existing regular file; else ``error`` saying what it is.

    Raises
    ------
    FaceTransferError (``error``)
        ``"{what} {path} does not exist"``, ``"... is a folder, not a file"`` or ``"... is empty"``.
    """
    p = Path(path)
    if p.is_dir():
        raise error(f"{what} {p} is a folder, not a file")
    if not p.is_file():
        raise error(f"{what} {p} does not exist")
    if p.stat().st_size == 0:
        raise error(f"{what} {p} is empty")
    return p


def read_npz(path: str | os.PathLike, what: str,
             error: type[FaceTransferError] = FaceTransferError) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file, read eagerly (no pickles).

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be, for messages (``"track file"``).
    error : FaceTransferError subclass
        Raised for any problem.

    Returns
    -------
    dict name -> ndarray

    Raises
    ------
    FaceTransferError (``error``)
        Missing, a folder, empty, truncated, damaged, or not an ``.npz`` file of plain arrays.
    """
    p = check_input_file(path, what, error)
    try:
        z = np.load(p, allow_pickle=False)
    except MemoryError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, EOFError, OSError, ValueError (pickle)…
        raise error(f"{what} {p} is truncated or not a {what} ({_reason(exc)})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise error(f"{what} {p} is not a {what} (a single .npy array, not an .npz archive)")
    try:
        with z:
            return {k: z[k] for k in z.files}
    except MemoryError:
        raise
    except Exception as exc:  # a damaged member: bad CRC, zlib.error, EOFError, pickle…
        raise error(f"{what} {p} is truncated or not a {what} ({_reason(exc)})") from None


def _reason(exc: Exception) -> str:
    """A short cause without numpy's advice (its ``allow_pickle`` hint misleads here)."""
    if isinstance(exc, ValueError) and "pickle" in str(exc):
        return "not an .npz archive of arrays"
    return exc.__class__.__name__


def scalar(data: dict, key: str, kind: type, path, what: str,
           error: type[FaceTransferError] = FaceTransferError):
    """``data[key]`` as a Python ``kind`` (int, float, str, bool); else ``error`` naming it."""
    try:
        a = np.asarray(data[key])
        if a.size != 1:
            raise ValueError
        v = kind(a.reshape(()).item()) if kind is not str else str(a.reshape(()))
    except (KeyError, ValueError, TypeError, OverflowError):
        raise error(f"{what} {path}: {key!r} must be one {kind.__name__}") from None
    if kind is float and not np.isfinite(v):
        raise error(f"{what} {path}: {key!r} must be finite, got {v}")
    return v

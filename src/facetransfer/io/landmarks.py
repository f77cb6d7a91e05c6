"""Precomputed MediaPipe landmarks beside a video: ``NAME.mediapipe478.npz``.

Key ``landmarks``: ``(F, 478, 3)`` (or ``(F, 478, 2)``) float, pixel x, y and a relative z per
frame, NaN where no face was found.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import VideoError
from .npz import read_npz

WHAT = "MediaPipe landmarks file"

#: The farthest a landmark's pixel position may lie from the origin (a frame is at most 65536
#: pixels a side; a face may leave it).
MAX_PIXEL = 1e6


def read_mediapipe_landmarks(path: str | os.PathLike, n_frames: int | None = None) -> np.ndarray:
    """Read and validate ``NAME.mediapipe478.npz``.

    Parameters
    ----------
    path : path-like
    n_frames : int, optional
        Keep only the first ``n_frames`` frames.

    Returns
    -------
    (F, 478, 3) float64
        NaN rows where no face was found (a 2-column file gets z = 0).

    Raises
    ------
    VideoError
        Missing, truncated or damaged file, no ``landmarks`` key, wrong shape or dtype, infinite
        values (the message names the file).
    """
    data = read_npz(path, WHAT, VideoError)
    if "landmarks" not in data:
        raise VideoError(f"{WHAT} {path} has no 'landmarks' array (keys: "
                         f"{', '.join(sorted(data)) or 'none'})")
    a = data["landmarks"]
    if a.dtype.kind not in "fiu" or a.ndim != 3 or a.shape[1] != 478 or a.shape[2] not in (2, 3):
        raise VideoError(f"{WHAT} {path}: 'landmarks' must be (frames, 478, 3) numbers, got "
                         f"{a.shape} {a.dtype}")
    a = a[:n_frames].astype(np.float64)
    if a.shape[2] == 2:
        a = np.concatenate([a, np.zeros(a.shape[:2] + (1,))], axis=2)
    if np.isinf(a).any():
        raise VideoError(f"{WHAT} {path} has infinite coordinates")
    if np.nanmax(np.abs(a[..., :2]), initial=0.0) > MAX_PIXEL:
        # not pixel positions (1e300 overflowed the fit's arithmetic: a traceback)
        raise VideoError(f"{WHAT} {path} has coordinates beyond {MAX_PIXEL:g} pixels: not "
                         "pixel positions")
    return a

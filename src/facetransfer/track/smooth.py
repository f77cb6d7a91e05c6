"""Zero-phase temporal smoothing of a track's pose and per-frame weights (beyond the paper)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["smooth_track"]


def smooth_track(rotation: np.ndarray, scale: np.ndarray, translation: np.ndarray,
                 weights: dict, sigma: float, *, constant: Sequence[str] = ()
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Zero-phase Gaussian smoothing of pose and per-frame weights (no lag).

    Rotations are smoothed as sign-aligned quaternions and renormalised; the scale in log space.

    Returns
    -------
    rotation (F, 3, 3), scale (F,), translation (F, 2), weights dict
    """
    from scipy.ndimage import gaussian_filter1d
    from scipy.spatial.transform import Rotation

    if sigma <= 0 or rotation.shape[0] < 3:
        return rotation, scale, translation, weights
    g = lambda a: gaussian_filter1d(a, sigma, axis=0, mode="nearest")  # noqa: E731
    q = Rotation.from_matrix(rotation).as_quat()
    for i in range(1, q.shape[0]):
        if q[i] @ q[i - 1] < 0:
            q[i] = -q[i]
    q = g(q)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = Rotation.from_quat(q).as_matrix()
    s = np.exp(g(np.log(scale)))
    t = g(translation)
    w = {k: (v if k in constant else g(v)) for k, v in weights.items()}
    return R, s, t, w

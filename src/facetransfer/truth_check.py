"""The checks a ground-truth file (``CLIP.truth.npz``, :func:`facetransfer.synth.load_truth`)
passes before it is used: its pose and weights by a track's own checks
(:class:`facetransfer.track.result.Track`), its points' shapes and values.

Before, a truth file's arrays were used as read: an fps of NaN passed, an empty rotation array
or a frame size of the wrong shape was an IndexError or TypeError in ``texture lift``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_truth"]


def check_truth(t):
    """``t`` (a :class:`facetransfer.synth.SyntheticTruth`) if its arrays are what
    :func:`facetransfer.synth.write_clip` writes; else ValueError saying which is not
    (a :class:`~facetransfer.errors.TrackError` for the pose and weights)."""
    from .track.result import Track

    if not isinstance(t.meta, dict):
        raise ValueError(f"its meta is a JSON {type(t.meta).__name__}, not an object")
    R = np.asarray(t.rotation)
    F = R.shape[0] if R.ndim == 3 else 0
    Track(fps=t.fps, frame_size=t.frame_size, rotation=R, scale=t.scale,
          translation=t.translation, weights=t.weights, landmarks2d=np.zeros((F, 68, 2)),
          confidence=np.ones(F), lost=np.zeros(F, bool), model_hash="",
          mode_names=tuple(t.weights))
    v, vis, L, lm = (np.asarray(a) for a in (t.vertices2d, t.visible, t.landmarks2d,
                                              t.landmark_indices))
    if v.ndim != 3 or v.shape[0] != F or v.shape[2] != 2 or not _finite(v):
        raise ValueError(f"vertices2d must be ({F}, n, 2) finite numbers, got {v.shape} {v.dtype}")
    if vis.shape != v.shape[:2] or vis.dtype.kind != "b":
        raise ValueError(f"visible must be {v.shape[:2]} flags, got {vis.shape} {vis.dtype}")
    if L.shape not in ((F, 68, 2), (F, 0, 2)) or not _finite(L):
        raise ValueError(f"landmarks2d must be ({F}, 68, 2) finite numbers, got {L.shape} "
                         f"{L.dtype}")
    if lm.ndim != 1 or lm.dtype.kind not in "iu" or \
            lm.size and (lm.min() < 0 or lm.max() >= v.shape[1]):
        raise ValueError(f"landmark_indices must be vertex numbers below {v.shape[1]}")
    return t


def _finite(a: np.ndarray) -> bool:
    """Whether ``a`` holds real numbers, all finite."""
    return a.dtype.kind in "iuf" and bool(np.isfinite(a).all())

"""Face measures from MediaPipe's 478 face-mesh points, shared by the benchmarks.

Each measure is the mean distance of some point pairs over the outer eye corners' distance
(33-263): the mouth's opening and width, each eye's lid gap and each brow's height over its
upper lid, as ``bench_capture.py`` compares them with the tracked iBUG-68 points (iBUG 62-66,
48-54, 37-41 and 38-40 / 43-47 and 44-46, 19-37 / 24-44) and ``bench_transfer_judge.py``
compares a transfer's result with its source and target.
"""

from __future__ import annotations

import numpy as np

#: The outer eye corners whose distance every measure is divided by.
EYE_CORNERS = (33, 263)
MOUTH_OPEN = ((13, 14),)
MOUTH_WIDTH = ((61, 291),)
#: Per eye (the subject's side): the upper and lower lid points of two vertical lines.
LIDS = {"Left": ((385, 380), (387, 373)), "Right": ((160, 144), (158, 153))}
#: Per brow (the subject's side): a brow point and the upper lid point below it.
BROWS = {"Left": ((334, 386),), "Right": ((105, 159),)}


def measure(P: np.ndarray, pairs) -> np.ndarray:
    """``(F,)``: the mean distance of the point ``pairs`` in ``P`` (F, 478, 2 or 3; x and y
    are used) over the outer eye corners' distance."""
    P = np.asarray(P, np.float64)[..., :2]
    a, b = EYE_CORNERS
    eye = np.linalg.norm(P[:, a] - P[:, b], axis=-1)
    return np.mean([np.linalg.norm(P[:, i] - P[:, j], axis=-1) for i, j in pairs], axis=0) / eye


def faces_in_pixels(frames, fps: float):
    """``(i, frame, xy)`` for each frame of ``frames`` (a clip at ``fps``) where Face
    Landmarker (video mode, :func:`facetransfer.fidelity.landmarker_scores`) finds a face:
    ``xy`` (478, 2) its points in the frame's pixels."""
    from facetransfer.fidelity import landmarker_scores

    _, P = landmarker_scores(frames, fps)
    for i, f in enumerate(frames):
        if np.isfinite(P[i]).all():
            H, W = f.shape[:2]
            yield i, f, P[i, :, :2] * (W, H)


def frame_lab(frame: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` float32: an 8-bit RGB frame in CIELAB (OpenCV's conversion of it scaled
    to 0..1: L 0..100), the colour space the lips' and the chin's benchmarks judge in."""
    import cv2

    return cv2.cvtColor(np.asarray(frame, np.float32) / 255.0, cv2.COLOR_RGB2LAB)

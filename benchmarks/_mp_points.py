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

"""Which frames the detector may skip: never one where the eyes move.

:func:`facetransfer.track.detect.detect_clip` with ``every`` > 1 shows the detector one frame
of ``every`` and interpolates the frames between (:func:`~facetransfer.track.detect.
between_detections`). A blink is too fast for that: its lids close and open within three to
five frames at 30 fps, and a peak on a frame not shown is lost (the thirty-ninth session
measured `driving_d6`'s eyeBlinkRight peaks 1.00 -> 0.82 with every other frame shown). Two
cues, both known before the frame is detected, make the detector see a frame anyway:

- the eye scores (eyeBlink, eyeSquint, eyeWide of either eye) of the last two frames shown
  moved by :data:`EYE_SCORE_STEP` a frame or more (a blink or a widening under way);
- the picture around either eye changed from the previous frame more than
  :data:`EYE_CHANGE_RATIO` times as much as the picture around the nose (a lid moving where the
  head does not: the nose's change is the head's motion and the camera's noise).

On Face Landmarker's own scores of the four real clips (BENCHMARKS.md, "Forty-sixth session"),
both cues show 51-76 % of the frames and keep the blink scores within 0.07 of every frame's
(99th percentile) where every other frame alone lost up to 0.24.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..arkit import ARKIT_NAMES

__all__ = ["EYE_SCORE_STEP", "EYE_CHANGE_RATIO", "EYE_SCORES", "eye_scores_moving",
           "eyes_changed"]

#: Eye scores' change a frame (between the last two frames shown) from which the next frame
#: is shown.
EYE_SCORE_STEP = 0.05
#: The eyes' picture change, as a multiple of the nose's (plus one level), from which a frame
#: is shown.
EYE_CHANGE_RATIO = 2.0
#: Columns of the 52 scores that the rule watches.
EYE_SCORES = np.array([i for i, n in enumerate(ARKIT_NAMES)
                       if n.startswith(("eyeBlink", "eyeSquint", "eyeWide"))])

_EYES = (slice(36, 42), slice(42, 48))      # iBUG-68 eye contours
_NOSE = slice(27, 36)


def eye_scores_moving(scores: list, skipped: list) -> bool:
    """Whether the eye scores of the last two frames shown moved by :data:`EYE_SCORE_STEP` a
    frame or more.

    Parameters
    ----------
    scores : list of (52,) arrays
        Each frame's scores so far (NaN where the detector gave none).
    skipped : list of bool
        Each frame's: not shown to the detector.
    """
    # from the end, the two last only: asked before every frame, a scan of the whole list
    # made the clip's detection quadratic in its length
    shown = list(itertools.islice((i for i in range(len(skipped) - 1, -1, -1)
                                   if not skipped[i]), 2))
    if len(shown) < 2:
        return False
    a, b = shown
    step = np.abs(np.asarray(scores[a])[EYE_SCORES] - np.asarray(scores[b])[EYE_SCORES])
    with np.errstate(invalid="ignore"):
        return bool(np.nanmax(step, initial=0.0) / (a - b) >= EYE_SCORE_STEP)


def _box(points: np.ndarray, half_w: float, half_h: float, shape) -> tuple[slice, slice]:
    """Rows and columns of a box about ``points`` (n, 2), ``half_w`` and ``half_h`` of their
    width either side of their mean, clipped to an image of ``shape``."""
    c = points.mean(axis=0)
    w = max(float(np.ptp(points[:, 0])), 1.0)
    x0, x1 = int(c[0] - half_w * w), int(c[0] + half_w * w) + 1
    y0, y1 = int(c[1] - half_h * w), int(c[1] + half_h * w) + 1
    H, W = shape[:2]
    return slice(min(max(y0, 0), H), min(max(y1, 0), H)), slice(min(max(x0, 0), W),
                                                                  min(max(x1, 0), W))


def _change(gray: np.ndarray, prev: np.ndarray, box: tuple[slice, slice]) -> float:
    """Mean absolute difference of two grey images in ``box``, in levels (0 for no pixel)."""
    a, b = gray[box], prev[box]
    if not a.size:
        return 0.0
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def eyes_changed(gray: np.ndarray, prev: np.ndarray, points: np.ndarray) -> bool:
    """Whether the picture about either eye changed from ``prev`` to ``gray`` (H, W) uint8 more
    than :data:`EYE_CHANGE_RATIO` times the picture about the nose (plus one level), the boxes
    placed by the last iBUG-68 ``points`` (68, 2) held (pixels of these images)."""
    if not np.isfinite(points).all():
        return False
    eyes = max(_change(gray, prev, _box(points[s], 0.8, 0.5, gray.shape)) for s in _EYES)
    nose = _change(gray, prev, _box(points[_NOSE], 0.7, 0.5, gray.shape))
    return eyes > EYE_CHANGE_RATIO * (nose + 1.0)

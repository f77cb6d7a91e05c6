"""MediaPipe's blendshape scores as a per-frame observation of the activations (beyond §5).

Face Landmarker scores 51 of the 52 ARKit blendshapes in every frame from the image itself, not
only from its landmarks. On footage with a known truth (``benchmarks/bench_capture.py``:
identities outside the model, painted by OpenCV) its jawOpen and mouthPucker follow the truth
better than any fit of our model to 2-D points can (jawOpen r 0.92-0.93 against 0.86-0.89),
but on another scale: its scores are compressed by a factor that changes from clip to clip
(0.35-0.71 of the true jawOpen's amplitude). So the capture tracker reads them through a
per-clip line fitted to its own first pass:

1. The clip is tracked from the points alone (:mod:`facetransfer.track.capture`).
2. Per scored shape, a line maps the score onto that pass's activation: the reduced major axis
   (the line through both means whose slope is the ratio of the standard deviations), so the
   mapped score keeps the amplitude our geometry measured and takes its timing from the
   detector. The funnel's slope is bounded (:data:`MAX_SLOPE`): where the detector's funnel
   hardly moves, our first pass's larger one is not its amplitude but our own false funnel;
   the bounded line passes through both medians (the rest levels, which those few false
   funnels do not raise as they raise our mean) and keeps the score's weight in the score's
   own units (:class:`ScoreLine`).
3. The clip is tracked again with a ridge pulling each frame's activation toward its mapped
   score (:func:`score_targets`), beside the points, flow and temporal terms.

References
----------
Vlasic et al. 2005, §5 (tracking with a multilinear model); MediaPipe Face Landmarker
(blendshape scores); Sokal & Rohlf, *Biometry* (reduced major axis regression).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..arkit import ARKIT_NAMES
from ..errors import ShapeError

__all__ = ["MAX_SLOPE", "SCORED_SHAPES", "ScoreLine", "fit_score_lines", "score_targets"]

#: the shapes whose score the fit reads (``bench_capture.py``, synthetic clips with truth). Left
#: out: the smiles (reading them raised the 51-shape activation error from 0.083 / 0.104 / 0.127
#: / 0.088 to 0.087 / 0.105 / 0.138 / 0.094: mouthSmileRight's score follows a one-sided smile
#: at r 0.49-0.52), the brows and squints (Face Landmarker's browInnerUp follows the truth better
#: than our fit on 1 clip of 4, its eyeSquint on 2, all below r 0.4) and the gaze, which follows
#: the iris (:mod:`facetransfer.track.gaze`)
SCORED_SHAPES: tuple[str, ...] = (
    "jawOpen", "mouthFunnel", "mouthPucker", "eyeBlinkLeft", "eyeBlinkRight")

#: below this standard deviation over the clip a score says nothing (the shape never moves)
MIN_SCORE_STD = 0.01

#: the largest slope a shape's line may take. On the clips where Face Landmarker reads real
#: funnels (``bench_capture.py``'s synthetic ``turned`` and ``eyes_closed`` against the truth;
#: ``driving_d6``'s "O") our first pass's funnel is 0.49-0.78 of its own, so a reduced major
#: axis steeper than 1 does not measure a compressed score: it scales the detector's small
#: funnels by our first pass's false ones, the lips parted in speech (``WDA_KatieHill_000``
#: 2.95: its 0.043-0.057 read as 0.115). Such a line is flattened to the bound through both
#: medians (its term weighed up, :class:`ScoreLine`).
MAX_SLOPE: dict[str, float] = {"mouthFunnel": 1.0}


@dataclass(frozen=True)
class ScoreLine:
    """Per ARKit shape, the line ``activation ≈ offset + slope * score`` of one clip.

    Attributes
    ----------
    offset, slope : (52,) float64
        In :data:`~facetransfer.arkit.ARKIT_NAMES` order; NaN for a shape not read.
    weight : (52,) float64
        The factor on the second pass's score term (``CaptureOptions.scores``): 1, or where the
        reduced major axis's slope ``b`` was bounded to ``c`` (:data:`MAX_SLOPE`), ``(b / c)²``:
        the term ``w (x - offset - c s)²`` is ``w c² ((x - offset) / c - s)²`` in the score's
        units, so the bound changes the score's scale, not how much one unit of it is trusted.
        NaN for a shape not read.
    """

    offset: np.ndarray
    slope: np.ndarray
    weight: np.ndarray

    def used(self) -> np.ndarray:
        """(52,) bool: the shapes with a line."""
        return np.isfinite(self.slope)


def fit_score_lines(activations: np.ndarray, scores: np.ndarray,
                    names: tuple[str, ...] = SCORED_SHAPES) -> ScoreLine:
    """The reduced-major-axis line of each shape in ``names`` (module notes, step 2).

    Parameters
    ----------
    activations : (F, 52) float
        The first pass's activations; NaN rows (lost frames) are skipped.
    scores : (F, 52) float
        The detector's scores, NaN where it found no face.
    names : tuple of str
        ARKit names to fit.

    Returns
    -------
    ScoreLine
        ``slope = std(a) / std(s)``, ``offset = mean(a) - slope mean(s)`` over the frames where
        both are known; where that slope exceeds :data:`MAX_SLOPE`, the bound, ``offset =
        median(a) - slope median(s)`` and a ``weight`` of ``(b / bound)²`` (``b`` the unbounded
        slope), so that a unit of the score weighs in the fit as the unbounded line's did: on
        a clip whose detector's funnel hardly moves that is large (WDA_KatieHill_000: 8.7), and
        the term holds the funnel near the detector's flat line, as it did before the bound. No line where fewer than 8 such
        frames exist or the score's std is below :data:`MIN_SCORE_STD`.
    """
    A, S = np.asarray(activations, np.float64), np.asarray(scores, np.float64)
    if A.shape != S.shape or A.ndim != 2 or A.shape[1] != len(ARKIT_NAMES):
        raise ShapeError(f"activations and scores must both be (F, {len(ARKIT_NAMES)}), got "
                         f"{A.shape} and {S.shape}")
    offset = np.full(len(ARKIT_NAMES), np.nan)
    slope = np.full(len(ARKIT_NAMES), np.nan)
    weight = np.full(len(ARKIT_NAMES), np.nan)
    for n in names:
        k = ARKIT_NAMES.index(n)
        ok = np.isfinite(A[:, k]) & np.isfinite(S[:, k])
        if ok.sum() < 8:
            continue
        a, s = A[ok, k], S[ok, k]
        if s.std() < MIN_SCORE_STD:
            continue
        b = a.std() / s.std()
        slope[k] = min(b, MAX_SLOPE.get(n, np.inf))
        weight[k] = (b / slope[k]) ** 2 if slope[k] < b else 1.0   # b = 0: a flat line, 1
        offset[k] = (a.mean() - b * s.mean() if slope[k] == b
                     else np.median(a) - slope[k] * np.median(s))
    return ScoreLine(offset, slope, weight)


def score_targets(line: ScoreLine, scores: np.ndarray) -> np.ndarray:
    """The mapped scores ``clip(offset + slope * score, 0, 1)``, (F, 52); NaN where a shape has
    no line or the frame no score."""
    S = np.asarray(scores, np.float64)
    return np.clip(line.offset + line.slope * S, 0.0, 1.0)

"""One frame of the performance capture's fit (:mod:`facetransfer.track.capture`, step 3).

A frame's state (pose and expression), the reliabilities of the points it is fitted to and
their targets in the frame's detections, and the fit itself: the weak-perspective pose (Eq. (7),
Gauss-Newton) alternated with the expression (Eq. (9): bounded least squares for ARKit
activations, the training prior for other modes), the eyeLook* activations following the iris
centres at each pose (:mod:`facetransfer.track.gaze`). The capture's yaw is that of ``R = Rx(a)
Ry(b) Rz(c)`` (:func:`sin_yaw`; :mod:`facetransfer.render.cameras` names the conventions).
The detected lips' gap and how shut it says they are (:func:`lips_gap`, :func:`lips_gate`) gate
the funnel (:func:`facetransfer.track.capture.funnel_ridges`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError
from .camera import Pose, fit_affine_pose
from .capture_points import Shape
from .detect import ClipDetections
from .fit2d import Targets, pose_gauss_newton
from .gaze import frame_gaze_activations

__all__ = ["FrameState", "PointWeights", "sin_yaw", "residual_rms", "gaze_fixed",
           "fit_frame", "detection_targets", "iris_of", "lips_gap", "lips_gate", "LIPS_SHUT",
           "LIPS_APART"]

#: The inner lips' gap (:func:`lips_gap`, eye-corner distances) at or below which the lips are
#: shut (their 10th-90th percentiles on the real clips' shut mouths: 0.004-0.016) ...
LIPS_SHUT = 0.02
#: ... and at or above which they are apart (a real "O": 0.06-0.35, 10th percentile 0.11)
LIPS_APART = 0.05


@dataclass(frozen=True)
class FrameState:
    """One frame's fit: pose and the per-frame parameters (activations or mode weights)."""

    pose: Pose
    x: np.ndarray          # ARKit: (K,) activations; generic: concatenated per-frame weights
    residual: float        # weighted rms of the detection term, in eye distances


def sin_yaw(pose: Pose) -> float:
    """Sine of the yaw ``b`` of ``R = Rx(a) Ry(b) Rz(c)``: ``R[0, 2]``, clipped to [-1, 1]
    (NaN kept; in Python's floats: the fit asks at every pose step, NumPy's scalar clip is
    ten times slower)."""
    return min(max(float(pose.rotation[0, 2]), -1.0), 1.0)


def residual_rms(X: np.ndarray, st_pose: Pose, p: np.ndarray, w: np.ndarray, iod: float) -> float:
    """Weighted rms distance (eye distances) of the points ``X`` (P, 3) at ``st_pose`` from
    ``p`` (P, 2; weights ``w`` 0 where unknown)."""
    r2 = np.sum((st_pose.project(X) - p) ** 2, axis=1)
    return float(np.sqrt(np.dot(w, r2) / max(np.sum(w), 1e-12)) / iod)


def gaze_fixed(shape: Shape, pose: Pose, x: np.ndarray, gaze: tuple,
                X: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The eyeLook* activations from ``gaze`` = (iris centres (2, 2), closed (2,)) at ``pose``
    and the frame's eye corners (:mod:`.gaze`): ``(held in the fit, written after it)``, (K,)
    each, NaN for every other shape. A closed eye's vertical gaze is 0 in the fit (its lids
    are the blink's: eyeLookDown's lid drop would take half the blink) and its bridged value
    after. ``X`` (P, 3): ``shape.points(x)`` when known."""
    iris, closed = gaze
    X = shape.points(x) if X is None else X
    after_, held_ = frame_gaze_activations(X[:68], iris, closed, pose.rotation, pose.scale,
                                           pose.translation)                 # (8,) each
    held, after = np.full(shape.size, np.nan), np.full(shape.size, np.nan)
    k = shape.gaze_k >= 0
    after[shape.gaze_k[k]] = after_[k]
    held[shape.gaze_k[k]] = np.where(np.isfinite(held_[k]), held_[k], after_[k] * 0.0)
    return held, after


def fit_frame(shape: Shape, targets: Targets, iod: float, pose: Pose | None, x: np.ndarray,
               prev: np.ndarray | None, iterations: int, gaze: tuple | None = None,
               anchor: tuple | None = None, extra_ridge: np.ndarray | None = None) -> FrameState:
    """Alternate pose (Gauss-Newton, Eq. (7)) and expression (bounded or prior-weighted LS,
    Eq. (9)) for one frame (``targets``: the detections first); with ``gaze`` (:func:`iris_of`;
    ARKit models) the eyeLook* activations follow the iris at each pose; ``anchor`` and
    ``extra_ridge`` (K,) as in :meth:`Shape.solve`."""
    p, w = targets.p[0], targets.w[0]
    base = shape
    if pose is None:
        X = shape.points(x)                                                 # (P, 3)
        ok = w > 0
        pose = fit_affine_pose(X[ok], p[ok])
    shape = base.at_view(sin_yaw(pose))                 # the offset at the head's yaw
    X = shape.points(x)
    after = None
    for _ in range(iterations):
        pose = pose_gauss_newton(X, targets, pose, iod, iterations=1)
        shape = base.at_view(sin_yaw(pose))
        held, after = (None, None) if gaze is None else gaze_fixed(shape, pose, x, gaze, X)
        x = shape.solve(pose, targets, iod, x, prev, held, anchor, extra_ridge)
        X = shape.points(x)
    if after is not None:
        x = np.where(np.isfinite(after), after, x)
        X = shape.points(x)
    pose = pose_gauss_newton(X, targets, pose, iod, iterations=1)
    return FrameState(pose, x, residual_rms(X, pose, p, w, iod))


@dataclass(frozen=True)
class PointWeights:
    """Reliability of every tracked point: iBUG-68, then the dense points (MediaPipe indices)."""

    w: np.ndarray
    mp_index: np.ndarray | None = None
    iris: np.ndarray | None = None     # (F, 2, 2) iris centres the gaze follows (NaN: free)
    closed: np.ndarray | None = None   # (F, 2) eyes with closed lids (vertical gaze free)
    anchors: np.ndarray | None = None  # (F, K) mapped detector scores (NaN: none)
    anchor_weights: np.ndarray | None = None  # (K,) their terms' factors (ScoreLine.weight)
    extra_ridges: np.ndarray | None = None  # (F, K) added to the prior's ridge (funnel_ridges)

    def flow_nominal(self, flow: float) -> np.ndarray:
        """Summed weights (P,) of the detection and flow terms with every point known (the
        flow moves the 68 iBUG points only)."""
        wf = flow * self.w
        wf[68:] = 0.0
        return self.w + wf

    def anchor(self, i: int) -> tuple | None:
        """Frame ``i``'s mapped scores (K,) and their terms' factors (K,) for the fit, or
        None."""
        if self.anchors is None:
            return None
        w = np.ones(self.anchors.shape[1]) if self.anchor_weights is None else self.anchor_weights
        return self.anchors[i], w

    def extra_ridge(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s extra ridge on the activations toward 0 (K,), or None."""
        return None if self.extra_ridges is None else self.extra_ridges[i]


def detection_targets(det: ClipDetections, i: int, pw: PointWeights) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``i``'s targets for the tracked points and their weights (0 where unknown)."""
    p = det.points[i]
    if pw.mp_index is not None and len(pw.mp_index):
        p = np.concatenate([p, np.asarray(det.points478[i, pw.mp_index], np.float64)])
    return p, np.where(np.isfinite(p).all(1), pw.w, 0.0)


def iris_of(weights: PointWeights, i: int) -> tuple | None:
    """Frame ``i``'s two iris centres (2, 2) the gaze follows (NaN rows: that eye's free) and
    which eyes are closed (2,), or None."""
    if weights.iris is None or not np.isfinite(weights.iris[i]).any():
        return None
    return weights.iris[i], weights.closed[i]


def lips_gap(points: np.ndarray) -> np.ndarray:
    """The inner lips' gap of iBUG points ``(F, 68, 2)``: the mean distance of the pairs 61-67,
    62-66, 63-65 over the outer eye corners' (36-45), ``(F,)``; NaN where a point is unknown.

    Both are distances between points symmetric about the face's midline or along it, so under
    the weak-perspective camera of Eq. (7) the ratio changes little with the head's pose."""
    P = np.asarray(points, np.float64)
    if P.ndim != 3 or P.shape[1:] != (68, 2):
        raise ShapeError(f"lips_gap needs iBUG points (F, 68, 2), got {P.shape}")
    gap = np.linalg.norm(P[:, [61, 62, 63]] - P[:, [67, 66, 65]], axis=2).mean(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return gap / np.linalg.norm(P[:, 36] - P[:, 45], axis=1)


def lips_gate(gap: np.ndarray, shut: float = LIPS_SHUT, apart: float = LIPS_APART
              ) -> np.ndarray:
    """How shut the lips are, from their gap ``(F,)`` (:func:`lips_gap`): 1 at or below
    ``shut``, 0 at or above ``apart``, linear between; 0 where the gap is unknown, ``(F,)``."""
    if not apart > shut:
        raise ValueError(f"lips_gate needs apart > shut, got shut {shut}, apart {apart}")
    with np.errstate(invalid="ignore"):
        g = np.clip((apart - np.asarray(gap, np.float64)) / (apart - shut), 0.0, 1.0)
    return np.where(np.isfinite(g), g, 0.0)

"""Options of the paper's KLT tracker (:func:`facetransfer.track.tracker.track_video`), and the
progress callback every tracker reports to.

The defaults are defined once here; the CLI and :class:`~facetransfer.track.settings.TrackerSettings`
use them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from ..errors import TrackError

__all__ = ["TrackOptions", "Progress"]

#: ``progress(stage, done, total)``: a tracker's report after each unit of work (a frame, a
#: frame pair). Shared by the trackers (:mod:`.tracker`, :mod:`.capture`).
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TrackOptions:
    """Settings of :func:`~.tracker.track_video` (defaults defined once here; the CLI uses them).

    Attributes
    ----------
    passes : int
        Passes through the video (§5.1: "several passes").
    levels : int
        Pyramid levels (multi-scale).
    iterations : int
        Gauss-Newton iterations per level (each cycles through the per-frame modes).
    n_points : int
        Tracked vertices per frame pair (about a thousand in the paper).
    half_window : int
        KLT window half-size in pixels of each level (window ``2 h + 1`` square).
    prior : float
        Weight of the training-distribution prior in the per-frame solves (mean squared pixel
        error per unit of Mahalanobis distance, for a face 100 pixels between the outer eye
        corners; scaled with the face size).
    identity_prior : float
        Weight of the prior in the per-pass identity solve.
    init_prior : float
        Prior weight of the landmark fit at initialisation (see :func:`~.init.fit_landmarks`).
    init_weight : float
        Weight of the initial landmarks in the identity solve, in frame pairs.
    snap_frames : int
        Frames tracked back and forth to snap the initial alignment (0 = off).
    snap_rounds : int
    anchor : bool
        Add detector landmarks of every frame as an extra term (needs a detector).
    anchor_weight : float
        Weight of the anchor term relative to the flow term.
    robust : float
        Points whose window correlation between the frames is below this get no weight
        (occlusions, the mouth interior, the silhouette); full weight above ``robust + 0.3``.
        0 = off.
    tolerance : float
        A level's iterations stop when a cycle moves the vertices by less than this (rms, in
        pixels of that level).
    keyframe : float
        Weight of a second KLT term against the first tracked frame (on the two finest
        levels; beyond the paper, reduces drift; 0 = off).
    temporal : float
        Damping toward the predicted state (per pixel of rms vertex motion per parameter),
        stabilising directions the flow does not determine.
    smooth : float
        Sigma (frames) of the zero-phase Gaussian smoothing of pose and per-frame weights
        (0 = off).
    lost_threshold : float
        Frames with confidence below this are lost.
    recover : bool
        Re-initialise from the detector when the face is lost.
    visibility_scale : float
        Resolution factor of the visibility raster.
    reselect : int
        Choose the tracked vertices (visibility raster, texture strength, spread) anew every
        ``reselect`` frame pairs; in between the last choice is reused with its points
        re-projected, unless the head turned by more than ``reselect_degrees`` or the scale
        changed by more than 5 % since (1 = every pair, as in the paper).
    reselect_degrees : float
        Head rotation (degrees) since the last choice that forces a new one.
    """

    passes: int = 2
    levels: int = 3
    iterations: int = 3
    n_points: int = 1000
    half_window: int = 4
    prior: float = 0.02
    identity_prior: float = 0.5
    init_prior: float = 1.0
    init_weight: float = 10.0
    snap_frames: int = 8
    snap_rounds: int = 1
    anchor: bool = False
    anchor_weight: float = 0.05
    temporal: float = 0.02
    keyframe: float = 0.5
    tolerance: float = 0.02
    robust: float = 0.4
    smooth: float = 0.0
    lost_threshold: float = 0.3
    recover: bool = True
    visibility_scale: float = 0.25
    reselect: int = 1
    reselect_degrees: float = 3.0

    def __post_init__(self) -> None:
        for name in ("passes", "levels", "iterations", "n_points", "half_window", "reselect"):
            if int(getattr(self, name)) < 1:
                raise TrackError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("prior", "identity_prior", "init_prior", "init_weight", "anchor_weight",
                     "smooth", "snap_frames", "keyframe", "temporal", "robust",
                     "reselect_degrees"):
            if not getattr(self, name) >= 0:
                raise TrackError(f"{name} must be >= 0, got {getattr(self, name)}")

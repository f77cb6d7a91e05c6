"""Resuming the capture tracker's detections after an interruption.

Detection (:func:`facetransfer.track.detect.detect_clip`: MediaPipe and the point flow on every
frame) is most of the capture tracker's time, so its results are what an interrupted run keeps:
:class:`DetectionCheckpoint` saves the frames detected so far atomically every ~20 s and when the
run is interrupted, and a later run of the same clip continues at the first frame not detected.
The saved file is keyed by the video's identity, the frame limit and the detector (not the
model: detection does not use it); a file of another run, of the KLT tracker
(:mod:`facetransfer.track.checkpoint`) or a damaged one is ignored and replaced.

Once detection is complete the same file also holds the fit in progress
(:mod:`facetransfer.track.fit_checkpoint`, keyed by the model and the capture options as well):
:meth:`DetectionCheckpoint.save_fit` and :meth:`DetectionCheckpoint.saved_fit`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass

import numpy as np

from .checkpoint import ProgressFile, video_identity
from .detect import ClipDetections
from .fit_checkpoint import SavedFit, pack_fit, unpack_fit

log = logging.getLogger(__name__)

__all__ = ["DETECT_CHECKPOINT_VERSION", "DetectionCheckpoint", "SavedDetections",
           "detection_key", "landmarker_identity", "face_detector_id"]

#: bumped when the saved layout changes (older files are then ignored)
DETECT_CHECKPOINT_VERSION = 3  # 2: with the blendshape scores; 3: in square pixels
#: what the file holds (a KLT tracker's progress file has no such entry)
LAYOUT = "capture-detections"


def detection_key(video_id: str, max_frames: int | None, detector_id: str) -> str:
    """sha256 of everything saved detections depend on.

    Parameters
    ----------
    video_id : str
        :func:`facetransfer.track.checkpoint.video_identity` of the clip.
    max_frames : int or None
        The run's frame limit.
    detector_id : str
        Identifies the detector (e.g. :func:`landmarker_identity`).
    """
    doc = {"layout": LAYOUT, "video": video_id, "max_frames": max_frames,
           "detector": detector_id, "version": DETECT_CHECKPOINT_VERSION}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def landmarker_identity() -> str:
    """The default detector (MediaPipe Face Landmarker in video mode) by its registered sha256
    and its warm-up (no file is read)."""
    from ..assets import REGISTRY
    from .detect import VideoLandmarker

    sha = REGISTRY["face_landmarker"].files[0].sha256
    return f"mediapipe-video:{sha}:warmup{VideoLandmarker.warmup_frames}"


def face_detector_id(face: str | None) -> str | None:
    """The detector's part of a progress file's key when ``face`` says which of several people
    is detected (``track --face``), so that another person's progress is not continued; None
    (the default detector's) without one."""
    return None if face is None else f"{landmarker_identity()}|face={face}"


@dataclass(frozen=True)
class SavedDetections:
    """What a progress file restores.

    Attributes
    ----------
    detections : ClipDetections
        The first ``detections.n_frames`` frames.
    complete : bool
        Detection had finished (the run was interrupted while fitting).
    """

    detections: ClipDetections
    complete: bool


def _lossless32(a: np.ndarray) -> np.ndarray:
    """``a`` as float32 when that loses nothing (the flow: OpenCV's float32 differences), else
    float64."""
    a32 = a.astype(np.float32)
    return a32 if np.array_equal(a32.astype(a.dtype), a, equal_nan=True) else a


class DetectionCheckpoint(ProgressFile):
    """The capture tracker's progress file (atomic ``.npz``): the detections of the first frames.

    Parameters
    ----------
    path : path-like
    key : str
        :func:`detection_key` of the run.
    every : float
        Seconds between periodic saves (0 = after every frame).
    budget : float
        Largest share of the time spent saving: the next periodic save waits at least the last
        save's duration divided by ``budget`` (the file grows with the clip; 30 min of video
        is about 290 MB; ``inf``: no limit).
    best_effort : bool
        See :class:`~facetransfer.track.checkpoint.ProgressFile`.
    """

    def __init__(self, path, key: str, *, every: float = 20.0, budget: float = 0.05,
                 best_effort: bool = False) -> None:
        super().__init__(path, key, every=every, best_effort=best_effort)
        self.budget = float(budget)
        self._fit: tuple[str, SavedFit] | None = None   # the fit in progress, saved with each save

    @classmethod
    def for_video(cls, path, video: str | os.PathLike, max_frames: int | None,
                  detector_id: str | None = None, **kw) -> "DetectionCheckpoint":
        """The progress file of detecting ``video`` (a file) with the default detector."""
        vid = video_identity(str(video))
        return cls(path, detection_key(vid, max_frames, detector_id or landmarker_identity()),
                   **kw)

    def load(self) -> SavedDetections | None:
        """The saved detections, or None (no file, another run's, unreadable or damaged)."""
        d = self._entries("removing unreadable progress file %s (%s); starting afresh")
        if d is None:
            self.remove()                       # unreadable (or no file: nothing to remove)
            return None
        if str(d.get("key", "")) != self.key:
            what = ("another video, frame limit or detector" if str(d.get("layout", "")) == LAYOUT
                    else "the klt tracker's progress")
            log.warning("ignoring progress file %s of another run (%s); starting afresh",
                        self.path, what)
            return None
        try:
            saved = self._restore(d)
            self._fit = unpack_fit(d) if saved.complete else None
            return saved
        except Exception as exc:  # entries missing, wrong shapes or dtypes: a damaged file
            log.warning("removing damaged progress file %s (%s); starting afresh", self.path,
                        exc.__class__.__name__)
            self.remove()
            return None

    @staticmethod
    def _restore(d: dict) -> SavedDetections:
        P = d["points"]
        k = P.shape[0]
        raw = d["points478"] if bool(d["has478"]) else None
        if (k < 1 or P.shape != (k, 68, 2) or d["flow"].shape != P.shape
                or int(d["n_frames"]) != k or (raw is not None and raw.shape != (k, 478, 2))):
            raise ValueError("inconsistent arrays")
        scores = d["scores"] if "scores" in d and d["scores"].size else None
        if scores is not None and scores.shape != (k, 52):
            raise ValueError("inconsistent arrays")
        change = d["change"] if "change" in d and d["change"].size else None
        if change is not None and change.shape != (k,):
            raise ValueError("inconsistent arrays")
        shown = d["shown"] if "shown" in d and d["shown"].size else None
        if shown is not None and shown.shape != (k,):
            raise ValueError("inconsistent arrays")
        det = ClipDetections(P.astype(np.float64), d["flow"].astype(np.float64),
                             None if raw is None else raw.astype(np.float32),
                             None if scores is None else scores.astype(np.float32),
                             float(d["pixel_aspect"]), change, shown)
        return SavedDetections(det, bool(d["complete"]))

    def save(self, det: ClipDetections, *, complete: bool = False) -> None:
        """Write the detections of the first ``det.n_frames`` frames atomically."""
        t0 = time.monotonic()
        arrays = {"key": np.array(self.key), "layout": np.array(LAYOUT),
                  "version": np.array(DETECT_CHECKPOINT_VERSION),
                  "n_frames": np.array(det.n_frames), "complete": np.array(bool(complete)),
                  "points": _lossless32(det.points), "flow": _lossless32(det.flow),
                  "has478": np.array(det.points478 is not None),
                  "points478": (np.zeros((0, 478, 2), np.float32) if det.points478 is None
                                else np.asarray(det.points478, np.float32)),
                  "scores": (np.zeros((0, 52), np.float32) if det.scores is None
                             else np.asarray(det.scores, np.float32)),
                  "pixel_aspect": np.float64(det.pixel_aspect),
                  "change": (np.zeros(0, np.float32) if det.change is None
                             else np.asarray(det.change, np.float32)),
                  "shown": (np.zeros(0, bool) if det.shown is None
                            else np.asarray(det.shown, bool))}
        if complete and self._fit is not None:
            arrays.update(pack_fit(self._fit[1], self._fit[0]))
        self._write(arrays)
        self._wait = max(self.every, (self._last - t0) / max(self.budget, 1e-6))
        log.info("saved the detections of %d frames to %s", det.n_frames, self.path)

    def saved_fit(self, key: str) -> SavedFit | None:
        """The fit in progress that :meth:`load` found, if it is of the run ``key``
        (:func:`facetransfer.track.fit_checkpoint.fit_key`), else None."""
        if self._fit is None:
            return None
        if self._fit[0] != key:
            log.warning("ignoring the fit saved in %s (another model or other options); "
                        "fitting afresh", self.path)
            return None
        return self._fit[1]

    def save_fit(self, det: ClipDetections, key: str, fit: SavedFit) -> None:
        """Save the complete detections ``det`` with the fit in progress ``fit`` of run ``key``
        (kept for every later :meth:`save`)."""
        self._fit = (key, fit)
        self.save(det, complete=True)

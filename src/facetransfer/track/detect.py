"""Per-frame detections of a whole clip: MediaPipe landmarks in video mode and point flow.

One decoding pass over the clip gives, for every frame ``t``, the detector's iBUG-68 points
(through :func:`facetransfer.track.landmarks.mediapipe_to_ibug`) and the pyramidal Lucas-Kanade
flow of frame ``t-1``'s points into frame ``t`` (OpenCV, with a forward-backward check). The
capture tracker (:mod:`facetransfer.track.capture`) then needs no frames at all: it fits the
model to these measurements, so detections can be computed once and reused.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Iterable

import cv2
import numpy as np

from ..errors import ShapeError
from .init import MediaPipeDetector, create_landmarker, import_tasks_api
from .landmarks import mediapipe_to_ibug
from .mp_result import array_reader
from .shots import CUT_FLOW_FAILED, CUT_LEVELS
from .skip_rule import eye_scores_moving, eyes_changed

__all__ = ["FLOW_SLACK", "FLOW_CROP_SHARE", "FLOW_SPAN", "THUMB_BLOCKS", "ClipDetections",
           "VideoLandmarker", "detect_clip", "flow_scale", "point_flow", "picture_change",
           "preload_mediapipe"]


@dataclass(frozen=True)
class ClipDetections:
    """What the detector and the flow saw in each frame of a clip.

    Attributes
    ----------
    points : (F, 68, 2) float64
        iBUG-68 detections in pixels, NaN where no face was found.
    flow : (F, 68, 2) float64
        ``flow[t]``: displacement of ``points[t-1]`` into frame ``t`` (Lucas-Kanade), NaN where
        the flow failed its forward-backward check or there was no previous detection;
        ``flow[0]`` is NaN.
    points478 : (F, 478, 2) float32 or None
        MediaPipe's raw points (kept for diagnostics and exports).
    scores : (F, 52) float32 or None
        MediaPipe's blendshape scores in :data:`facetransfer.arkit.ARKIT_NAMES` order, NaN
        where it found no face and for ``tongueOut`` (it has no such score); the capture fit
        reads them as a calibrated per-frame observation of the activations
        (:mod:`facetransfer.track.scores`).
    pixel_aspect : float
        The points are in the frames resampled to square pixels (their columns ``round(W
        pixel_aspect)``, :mod:`facetransfer.track.aspect`); 1: the stored pixels are square.
    change : (F,) float32 or None
        How much each frame's picture differs from the previous one's: the mean absolute
        difference of their 32x32 grey thumbnails, in levels (NaN for a first frame); where it
        jumps, the clip cuts to another shot (:mod:`facetransfer.track.shots`). None: not
        measured (detections without the flow).
    shown : (F,) bool or None
        The frames shown to the detector (:func:`detect_clip`'s ``every``); the others' points,
        raw points and scores are interpolated from those (:func:`between_detections`).
        None: every frame was shown.
    """

    points: np.ndarray
    flow: np.ndarray
    points478: np.ndarray | None = None
    scores: np.ndarray | None = None
    pixel_aspect: float = 1.0
    change: np.ndarray | None = None
    shown: np.ndarray | None = None

    def __post_init__(self) -> None:
        P = np.asarray(self.points, dtype=np.float64)
        if P.ndim != 3 or P.shape[1:] != (68, 2):
            raise ShapeError(f"detections must be (F, 68, 2), got {P.shape}")
        Fl = np.asarray(self.flow, dtype=np.float64)
        if Fl.shape != P.shape:
            raise ShapeError(f"flow must be {P.shape}, got {Fl.shape}")
        object.__setattr__(self, "points", P)
        object.__setattr__(self, "flow", Fl)
        if self.scores is not None:
            S = np.asarray(self.scores, dtype=np.float32)
            if S.shape != (P.shape[0], 52):
                raise ShapeError(f"scores must be ({P.shape[0]}, 52), got {S.shape}")
            object.__setattr__(self, "scores", S)
        if self.change is not None:
            C = np.asarray(self.change, dtype=np.float32)
            if C.shape != (P.shape[0],):
                raise ShapeError(f"change must be ({P.shape[0]},), got {C.shape}")
            object.__setattr__(self, "change", C)
        if self.shown is not None:
            V = np.asarray(self.shown, dtype=bool)
            if V.shape != (P.shape[0],):
                raise ShapeError(f"shown must be ({P.shape[0]},), got {V.shape}")
            object.__setattr__(self, "shown", None if V.all() else V)
        a = float(self.pixel_aspect)
        if not np.isfinite(a) or a <= 0:
            raise ShapeError(f"pixel_aspect must be > 0, got {self.pixel_aspect}")
        object.__setattr__(self, "pixel_aspect", a)

    @property
    def n_frames(self) -> int:
        return int(self.points.shape[0])

    @property
    def found(self) -> np.ndarray:
        """(F,) bool: frames with a detection."""
        return np.all(np.isfinite(self.points), axis=(1, 2))

    @classmethod
    def from_points(cls, points: np.ndarray) -> "ClipDetections":
        """Detections without flow (e.g. a MediaPipe-478 reference file mapped to iBUG)."""
        P = np.asarray(points, dtype=np.float64)
        return cls(P, np.full_like(P, np.nan))


class VideoLandmarker(MediaPipeDetector):
    """MediaPipe Face Landmarker (Tasks API) in VIDEO running mode: 478 points per frame.

    Video mode tracks the face between frames inside MediaPipe, which is faster than detecting
    it anew in every frame. Timestamps must increase: call :meth:`detect478` in frame order.

    Its tracking state makes a frame's points depend on the frames before it: a run started in
    the middle of a clip (a resumed :func:`detect_clip`) first shows the detector the
    :attr:`warmup_frames` frames before its start. Measured on face_2 and driving_d9 (resumed at
    frame 60): the iBUG points of the first resumed frame then differ from an uninterrupted
    run's by 0.05 px on average (0.2 px at most; 1.6-2.2 px on average without the warm-up),
    later frames by 0.02-0.09 px (MediaPipe's own state never becomes identical); on a longer
    clip (``driving_d6``, 1,008 frames) 0.1-0.5 px over the next ~150 frames, 1.3 px at most.
    """

    #: frames shown to the detector before a resumed run's first frame (see the class notes)
    warmup_frames = 20

    def __init__(self, model_path: str | os.PathLike | None = None, *, fps: float = 30.0,
                 blendshapes: bool = False) -> None:
        self._lm = create_landmarker(model_path, video=True, blendshapes=blendshapes)
        self._reader = array_reader(self._lm)       # None: through the API's objects
        self._dt = 1000.0 / max(float(fps), 1e-3)
        self._i = 0

    def _stamp(self) -> int:
        """The next frame's timestamp (ms); the clock moves on."""
        ts = int(round(self._i * self._dt))
        self._i += 1
        return ts

    def _detect(self, image):
        return self._lm.detect_for_video(image, self._stamp())

    def _detect_arrays(self, image):
        if self._reader is None:
            return super()._detect_arrays(image)
        return self._reader.detect_for_video(image, self._stamp())

    def close(self) -> None:
        self._reader = None
        super().close()

    def at_least(self, frame: int) -> "VideoLandmarker":
        """This landmarker with its clock at frame ``frame`` at least (one not shown every
        frame of a clip: its timestamps must still increase)."""
        self._i = max(self._i, int(frame))
        return self

    def skip(self, frame: np.ndarray) -> None:
        """A frame not shown (:func:`detect_clip`'s ``every``): the clock moves on."""
        self._i += 1


def _import_mediapipe() -> None:
    try:
        import_tasks_api()
    except Exception:  # noqa: BLE001 - create_landmarker's own import reports it
        pass


def preload_mediapipe() -> Callable[[], None]:
    """Start importing MediaPipe's Tasks API on a background thread; returns ``wait()``.

    The import (:func:`facetransfer.track.init.import_tasks_api`: 0.25 CPU-s here, 0.85 with
    the drawing helpers MediaPipe's package would import) holds the interpreter lock only part
    of the time, so it overlaps work that mostly does not (decoding, reading the model file).
    Call ``wait()`` before forking (:func:`facetransfer.track.obtain.start_background_track`):
    the child then inherits the imported modules instead of importing them again, and no import
    lock is held across the fork. A failed import is silent here; the detector's own import
    (:func:`facetransfer.track.init.create_landmarker`) reports it.
    """
    thread = threading.Thread(target=_import_mediapipe, name="import-mediapipe", daemon=True)
    thread.start()
    return thread.join


#: :func:`point_flow` works on the points' box grown by the window's half plus
#: ``FLOW_SLACK`` pixels of the top pyramid level (the motion between frames and the pyramid's
#: own border: 64 pixels of the frame at the default window and 2 levels) when that box is at
#: most ``FLOW_CROP_SHARE`` of the frame (1: always). Each call builds the pyramids and the
#: first frame's derivatives of all it is given: with a face 400 pixels tall in a 1080p frame
#: 4.7 -> 1.4 ms a frame (BENCHMARKS.md, "Thirty-fourth session"), with issue 13's 512x480
#: faces, whose box is half the frame or more, 1.6 -> 1.36 ("Fifty-third session (helper
#: cpu53b)"); the displacements within 0.022 px of the whole frame's (Lucas-Kanade's own
#: stopping tolerance here is 0.03), 0.0001 px on average.
FLOW_SLACK, FLOW_CROP_SHARE = 6, 1.0

#: Lucas-Kanade's calls of :func:`point_flow` take the points' minimum eigenvalue as their
#: error (unread): the same points and status, without OpenCV's last pass over each window at
#: the finest level that the default error (the window's mean difference) takes.
_LK_FLAGS = cv2.OPTFLOW_LK_GET_MIN_EIGENVALS


#: :func:`point_flow`'s settings (the window, the pyramid's levels, the forward-backward
#: tolerance) are in the pixels of a face whose eyes' centres (the means of iBUG points 36-41
#: and 42-47) lie at most ``FLOW_SPAN`` pixels apart: the data folder's clips, 106-142 px by
#: their detections. A larger face is carried on its box shrunk by ``span / FLOW_SPAN``
#: (:func:`flow_scale`), so that in the frame's pixels each setting grows with the face. The
#: rule of the rewrite's settings (:data:`facetransfer.face_scale.FACE_SPAN`), measured on the
#: detected points, as the flow has no model. Fixed, a 4K face (eyes about 480 px apart) lost
#: 25-84 % of its points a frame and a frame carried by the flow lost its face
#: (BENCHMARKS.md, "Fifty-fifth session (helper fast4k55)").
FLOW_SPAN = 145.0


def flow_scale(pts: np.ndarray) -> float:
    """The factor of :func:`point_flow`'s pixel settings for the iBUG-68 points ``pts``
    (68, 2): 1 up to :data:`FLOW_SPAN` pixels between the eyes' centres, ``span / FLOW_SPAN``
    beyond; 1 for other points or where an eye has no finite point."""
    P = np.asarray(pts, np.float64)
    if P.shape != (68, 2):
        return 1.0
    eyes = [e[np.isfinite(e).all(axis=1)] for e in (P[36:42], P[42:48])]
    if not all(len(e) for e in eyes):
        return 1.0
    span = float(np.hypot(*(eyes[0].mean(axis=0) - eyes[1].mean(axis=0))))
    return max(1.0, span / FLOW_SPAN)


def point_flow(prev_gray: np.ndarray, gray: np.ndarray, pts: np.ndarray, *,
               window: int = 21, levels: int = 2, max_fb: float = 1.0,
               scale: float | None = None) -> np.ndarray:
    """Lucas-Kanade displacement of points from one frame into the next, (n, 2), NaN on failure.

    A point fails when OpenCV loses it or when tracking it back lands more than ``max_fb``
    pixels from where it started (forward-backward check). The flow is computed on the
    points' box (:data:`FLOW_SLACK`, :data:`FLOW_CROP_SHARE`), its error left as OpenCV's
    cheaper one (:data:`_LK_FLAGS`). ``window``, ``levels`` and ``max_fb`` are pixels of a face
    of at most :data:`FLOW_SPAN`; ``scale`` (default: :func:`flow_scale` of ``pts``) above 1
    carries the points on the box shrunk by it (:func:`_shrunk_flow`).
    """
    ok = np.all(np.isfinite(pts), axis=1)
    out = np.full(pts.shape, np.nan)
    if not ok.any():
        return out
    s = flow_scale(pts) if scale is None else max(1.0, float(scale))
    if s > 1.0:
        out[ok] = _shrunk_flow(prev_gray, gray, pts[ok], s, window, levels, max_fb)
        return out
    box = _flow_box(pts[ok], prev_gray.shape[:2], window, levels)
    x0, y0 = (0, 0) if box is None else (box[1].start, box[0].start)
    if box is not None:
        prev_gray, gray = prev_gray[box], gray[box]
    p0 = (pts[ok] - (x0, y0)).astype(np.float32).reshape(-1, 1, 2)
    out[ok] = _lk(prev_gray, gray, p0, window, levels, max_fb)
    return out


def _lk(prev_gray: np.ndarray, gray: np.ndarray, p0: np.ndarray, window: int, levels: int,
        max_fb: float) -> np.ndarray:
    """Pyramidal Lucas-Kanade of the points ``p0`` (n, 1, 2) float32 from ``prev_gray`` into
    ``gray`` and back: their displacements (n, 2) float64, NaN where lost or back more than
    ``max_fb`` pixels from where they started."""
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, p0, None, winSize=(window, window),
                                          maxLevel=levels, criteria=crit, flags=_LK_FLAGS)
    pb, st2, _ = cv2.calcOpticalFlowPyrLK(gray, prev_gray, p1, None, winSize=(window, window),
                                          maxLevel=levels, criteria=crit, flags=_LK_FLAGS)
    fb = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb < max_fb)
    d = (p1 - p0).reshape(-1, 2).astype(np.float64)
    d[~good] = np.nan
    return d


def _shrunk_flow(prev_gray: np.ndarray, gray: np.ndarray, pts: np.ndarray, s: float,
                 window: int, levels: int, max_fb: float) -> np.ndarray:
    """:func:`_lk` of the finite points ``pts`` (n, 2) on their box (grown ``s`` times
    :func:`_flow_box`'s margin; the whole frame where that is too much of it) shrunk ``s``
    times, with the settings as they are: in the frame's pixels each grows ``s`` times. The
    box is averaged over whole blocks of ``floor(s)`` pixels (OpenCV's fast area resampling)
    and resampled linearly by the rest of ``s`` (below 2); returns the displacements in the
    frame's pixels (n, 2)."""
    box = _flow_box(pts, prev_gray.shape[:2], window, levels, grow=s)
    rows, cols = box if box is not None else (slice(0, prev_gray.shape[0]),
                                              slice(0, prev_gray.shape[1]))
    k = max(1, min(int(s), rows.stop - rows.start, cols.stop - cols.start))
    h, w = (rows.stop - rows.start) // k * k, (cols.stop - cols.start) // k * k
    rows, cols = slice(rows.start, rows.start + h), slice(cols.start, cols.start + w)
    size = (max(int(round(w / s)), 1), max(int(round(h / s)), 1))
    a, b = (_shrunk(g[rows, cols], k, size) for g in (prev_gray, gray))
    f = np.array([a.shape[1] / w, a.shape[0] / h])    # a pixel's centre maps to the small one's
    p0 = ((pts - (cols.start, rows.start) + 0.5) * f - 0.5).astype(np.float32).reshape(-1, 1, 2)
    return _lk(a, b, p0, window, levels, max_fb) / f


def _shrunk(gray: np.ndarray, k: int, size: tuple[int, int]) -> np.ndarray:
    """``gray`` (h, w), both multiples of ``k``, averaged over k x k blocks and then resampled
    linearly to ``size`` (width, height) where that is not yet its size."""
    if k > 1:
        gray = cv2.resize(gray, (gray.shape[1] // k, gray.shape[0] // k),
                          interpolation=cv2.INTER_AREA)
    if (gray.shape[1], gray.shape[0]) != tuple(size):
        gray = cv2.resize(gray, tuple(size), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(gray)


def _flow_box(pts: np.ndarray, shape: tuple[int, int], window: int, levels: int,
              grow: float = 1.0) -> tuple[slice, slice] | None:
    """The rows and columns :func:`point_flow` works on: the box of ``pts`` (n, 2) grown by
    ``(window // 2 + FLOW_SLACK) * 2**levels`` pixels (times ``grow``, rounded up), its corner
    on the top pyramid level's grid (so the crop's pyramid samples the frame's), clipped to the
    frame ``shape`` (H, W); None when that box is more than :data:`FLOW_CROP_SHARE` of the
    frame."""
    H, W = shape
    step = 2 ** int(levels)
    m = (int(window) // 2 + FLOW_SLACK) * step
    if grow != 1.0:
        m = int(np.ceil(m * float(grow)))
    lo = np.floor(pts.min(axis=0)).astype(np.int64) - m
    hi = np.ceil(pts.max(axis=0)).astype(np.int64) + m + 1
    x0, y0 = max(int(lo[0]), 0) // step * step, max(int(lo[1]), 0) // step * step
    x1, y1 = min(int(hi[0]), W), min(int(hi[1]), H)
    if x1 <= x0 or y1 <= y0 or (x1 - x0) * (y1 - y0) > FLOW_CROP_SHARE * H * W:
        return None
    return slice(y0, y1), slice(x0, x1)


#: :func:`thumbnail`: frames whose shorter side is at least twice this are first averaged over
#: whole blocks of ``shorter side // THUMB_BLOCKS`` pixels.
THUMB_BLOCKS = 256


def thumbnail(gray: np.ndarray) -> np.ndarray:
    """A grey frame's 32x32 thumbnail, float32 (:func:`picture_change`): its area average.

    A large frame (shorter side >= 2 :data:`THUMB_BLOCKS`) is averaged over k x k blocks
    first (k = shorter side // :data:`THUMB_BLOCKS`; the last rows and columns that fill no
    block are left out): OpenCV's area resampling by a whole factor is its fast one, by
    33.75 (1080 rows to 32) its slow one (5.8 -> 1.2 ms a 1080p frame; the thumbnail within a
    level of the direct one, a picture change within 1 %: 0.02 levels on real footage, whose
    cuts change by 36-72, :mod:`facetransfer.track.shots`)."""
    H, W = gray.shape[:2]
    k = min(H, W) // THUMB_BLOCKS
    if k >= 2:
        h, w = H - H % k, W - W % k
        gray = cv2.resize(gray[:h, :w], (w // k, h // k), interpolation=cv2.INTER_AREA)
    return cv2.resize(gray, (32, 32), interpolation=cv2.INTER_AREA).astype(np.float32)


def picture_change(prev_gray: np.ndarray, gray: np.ndarray) -> float:
    """Mean absolute difference of two grey frames' 32x32 thumbnails, in levels
    (:attr:`ClipDetections.change`)."""
    return float(np.abs(thumbnail(prev_gray) - thumbnail(gray)).mean())


class _Found:
    """What :func:`detect_clip` has found so far: per frame the points, the flow (a future while
    it is computed) and MediaPipe's raw points."""

    def __init__(self, keep478: bool, resume: ClipDetections | None, aspect: float = 1.0
                 ) -> None:
        self.keep478 = keep478
        self.aspect = aspect
        if resume is not None and resume.pixel_aspect != aspect:
            raise ShapeError(f"resuming detections of pixel aspect {resume.pixel_aspect} on "
                             f"frames of {aspect}")
        self.P: list = [] if resume is None else list(resume.points)
        self.Fl: list = [] if resume is None else list(resume.flow)
        self.change: list = [] if resume is None else (
            list(resume.change) if resume.change is not None else [np.nan] * resume.n_frames)
        self.raw: list = []
        self.scores: list = []
        self.skipped: list = [] if resume is None else (
            [False] * resume.n_frames if resume.shown is None else list(~resume.shown))
        if keep478 and resume is not None:
            if resume.points478 is None:
                raise ShapeError("resuming with keep478 needs the saved detections' points478")
            self.raw = list(resume.points478)
        if resume is not None:
            self.scores = (list(resume.scores) if resume.scores is not None
                           else [_NAN52] * resume.n_frames)

    def add(self, pts: np.ndarray, flow, q: np.ndarray | None,
            scores: np.ndarray | None = None, change: float = np.nan,
            skipped: bool = False) -> None:
        self.change.append(change)
        self.skipped.append(skipped)
        if self.keep478:
            self.raw.append(np.full((478, 2), np.nan, np.float32) if q is None else
                            np.asarray(q[:478], np.float32))
        self.scores.append(_NAN52 if scores is None else scores)
        self.P.append(pts)
        self.Fl.append(flow)                 # last: len(Fl) frames are complete

    def result(self) -> ClipDetections:
        """The complete frames (waits for their flow)."""
        n = len(self.Fl)
        if not n:
            raise ShapeError("the clip has no frames")
        self.Fl = [_NAN68 if f is None else f.result() if isinstance(f, Future) else f
                   for f in self.Fl]
        S = np.stack(self.scores[:n])
        C = np.asarray(self.change[:n], np.float32)
        P, Fl = np.stack(self.P[:n]), np.stack(self.Fl)
        raw = np.stack(self.raw[:n]) if self.keep478 else None
        skipped = np.asarray(self.skipped[:n], bool)
        if skipped.any():
            P, raw, S = between_detections(P, Fl, raw, S, skipped, C)
        return ClipDetections(P, Fl, raw, None if np.isnan(S).all() else S,
                              self.aspect, None if np.isnan(C).all() else C, ~skipped)


def between_detections(P: np.ndarray, flow: np.ndarray, raw: np.ndarray | None,
                       S: np.ndarray, skipped: np.ndarray, change: np.ndarray | None = None):
    """``(P, raw, S)`` with the frames ``skipped`` (F,) (not shown to the detector,
    :func:`detect_clip`'s ``every``) interpolated linearly in time between the shown frames on
    either side: the 68 points ``P`` (F, 68, 2), the 478 ``raw`` (F, 478, 2) or None and the
    scores ``S`` (F, 52). Where no shown frame with a face follows, or the one that follows
    starts another shot (its picture ``change`` (F,) at least
    :data:`facetransfer.track.shots.CUT_LEVELS`), a skipped frame (never the first of a shot:
    :func:`_add_frame`) takes the last shown frame's scores and its points moved by the point
    ``flow`` (F, 68, 2) (the points whose flow failed by the others' median step, the 478 by
    it too), or no face where the flow failed for :data:`~facetransfer.track.shots.
    CUT_FLOW_FAILED` of them."""
    P, S = P.copy(), S.copy()
    raw = None if raw is None else raw.copy()
    cut = np.zeros(len(P), bool) if change is None else \
        np.nan_to_num(np.asarray(change, np.float64)) >= CUT_LEVELS
    shown = np.flatnonzero(~skipped)
    for i in np.flatnonzero(skipped):
        k = np.searchsorted(shown, i)
        a = int(shown[k - 1])                    # a skip follows a shown frame with a face
        if k < shown.size and np.isfinite(P[shown[k]]).all() and not cut[shown[k]]:
            b = int(shown[k])
            t = (i - a) / (b - a)
            P[i] = (1 - t) * P[a] + t * P[b]
            S[i] = (1 - t) * S[a] + t * S[b]
            if raw is not None:
                raw[i] = (1 - t) * raw[a] + t * raw[b]
            continue
        _moved_on(P, raw, S, flow, i, a)
    return P, raw, S


def _moved_on(P: np.ndarray, raw, S: np.ndarray, flow: np.ndarray, i: int, a: int) -> None:
    """Frame ``i`` (skipped, after the last shown frame ``a`` of its shot) in place: frame
    ``i - 1``'s points moved by the point flow, the failed ones by the others' median step;
    no face where it failed for :data:`~facetransfer.track.shots.CUT_FLOW_FAILED` of them (the
    face gone) or frame ``i - 1`` has none."""
    ok = np.isfinite(flow[i]).all(axis=1) & np.isfinite(P[i - 1]).all(axis=1)
    if ok.mean() <= 1.0 - CUT_FLOW_FAILED:
        P[i], S[i] = np.nan, np.nan
        if raw is not None:
            raw[i] = np.nan
        return
    step = np.median(flow[i][ok], axis=0)
    P[i] = P[i - 1] + np.where(ok[:, None], flow[i], step)
    S[i] = S[a]
    if raw is not None:
        raw[i] = raw[i - 1] + step.astype(raw.dtype)


_NAN68 = np.full((68, 2), np.nan)
_NAN52 = np.full(52, np.nan, np.float32)


def _skipped(detector, fr: np.ndarray, show: bool, last: bool, prev):
    """A frame a resumed run detected before: shown to the detector when ``show`` (its
    warm-up); its grey image (and thumbnail) is the flow's start when ``last``. Returns the
    flow's start."""
    if show:
        _detect_one(detector, fr)
    return _grey(fr) if last else prev


def _grey(fr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A frame's grey image (the flow's) and its :func:`thumbnail` (the picture change's)."""
    gray = cv2.cvtColor(np.ascontiguousarray(fr), cv2.COLOR_RGB2GRAY)
    return gray, thumbnail(gray)


def _detect_one(detector, fr: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One frame's iBUG-68 points (NaN without a face), the raw 478 and the blendshape
    scores (52,) (each None when the detector gives none)."""
    if hasattr(detector, "detect_scored"):
        q, scores = detector.detect_scored(fr)
        return (_NAN68 if q is None else mediapipe_to_ibug(q)), q, scores
    if hasattr(detector, "detect478"):
        q = detector.detect478(fr)
        return (_NAN68 if q is None else mediapipe_to_ibug(q)), q, None
    d = detector.detect(fr)
    return (_NAN68 if d is None else np.asarray(d, dtype=np.float64)), None, None


def _skips(detector, found: _Found, every: int, eyes: bool = False) -> bool:
    """Whether the next frame may be not shown to the detector (``every`` > 1): fewer than
    ``every`` frames since the last one shown, which found a face, and a detector that can
    ``skip`` (:func:`_add_frame` then shows it anyway where the picture changed as at a cut,
    :data:`facetransfer.track.shots.CUT_LEVELS`); with ``eyes``, not after eye scores that
    moved (:func:`facetransfer.track.skip_rule.eye_scores_moving`) nor where the picture about
    the eyes changed (:func:`~facetransfer.track.skip_rule.eyes_changed`)."""
    if every <= 1 or not found.P or not hasattr(detector, "skip"):
        return False
    since = next((j for j, s in enumerate(reversed(found.skipped)) if not s), len(found.P))
    last = len(found.P) - 1 - since
    return (since + 1 < every and last >= 0 and bool(np.isfinite(found.P[last]).all())
            and not (eyes and eye_scores_moving(found.scores, found.skipped)))


def _add_frame(found: _Found, detector, fr: np.ndarray, prev, pool, every: int,
               eyes: bool = False):
    """Detect (or skip: :func:`_skips`) one frame into ``found``, with the flow of the
    previous frame's points on ``pool`` (None: no flow) from ``prev``, the previous frame's
    grey image and thumbnail; returns this frame's."""
    if pool is not None:
        grey = pool.submit(_grey, fr)
    skip = pool is not None and prev is not None and _skips(detector, found, every, eyes)
    if skip:                      # a picture that changed as at a cut, or at the eyes, is shown
        gray, thumb = grey.result()
        skip = (float(np.abs(thumb - prev[1]).mean()) < CUT_LEVELS
                and not (eyes and eyes_changed(gray, prev[0], found.P[-1])))
    if skip:                      # held for now, interpolated in found.result()
        detector.skip(fr)
        pts, q, scores = found.P[-1], None, None
    else:
        pts, q, scores = _detect_one(detector, fr)
    f, change = None, np.nan
    if pool is not None:
        gray, thumb = grey.result()
        if prev is not None:
            if found.P:
                f = pool.submit(point_flow, prev[0], gray, found.P[-1])
            change = float(np.abs(thumb - prev[1]).mean())   # picture_change
        prev = gray, thumb
    found.add(pts, f, q, scores, change, skip)
    return prev


def detect_clip(frames: Iterable[np.ndarray], detector, *, n_frames: int | None = None,
                flow: bool = True, progress: Callable[[int, int], None] | None = None,
                keep478: bool = False, resume: ClipDetections | None = None,
                checkpoint=None, start: int = 0, pixel_aspect: float = 1.0,
                every: int = 1, eyes: bool = False) -> ClipDetections:
    """Detect the face in every frame and the point flow between neighbouring frames.

    Parameters
    ----------
    frames : iterable of (H, W, 3) uint8
        The clip in order (read once).
    detector : object with ``detect478(frame) -> (478, 2) | None`` (e.g. :class:`VideoLandmarker`)
        or ``detect(frame) -> (68, 2) | None``.
    n_frames : int, optional
        Stop after this many frames (also the progress total, if known).
    flow : bool
        Also compute :func:`point_flow` of the detections.
    progress : callable(done, total), optional
        ``total`` is ``n_frames`` or 0 when unknown.
    keep478 : bool
        Keep MediaPipe's raw points.
    resume : ClipDetections, optional
        The first ``k`` frames' detections (an interrupted run's): those frames are decoded but
        not detected again, except the detector's ``warmup_frames`` last ones, which are shown
        to it (results discarded) so that a tracking detector starts frame ``k`` from a settled
        state; frame ``k - 1``'s image gives the flow into frame ``k``.
    checkpoint : object with ``due() -> bool`` and ``save(ClipDetections)``, optional
        Given the detections so far whenever ``due()`` and when interrupted
        (:class:`KeyboardInterrupt`, re-raised), e.g.
        :class:`facetransfer.track.detect_checkpoint.DetectionCheckpoint`.
    start : int
        Without ``resume``: detect from this frame on, as a resumed run would (the frames before
        it decoded, the last ``warmup_frames`` of them shown to the detector); the result then
        holds frames ``start ..`` only, and its first frame has no flow (no points before it).
        Used by :mod:`facetransfer.track.video_detect` for a clip's later part.
    every : int
        Show the detector one frame of ``every`` after a frame where it found a face (a
        detector that can ``skip``): the frames between are given the detections on either
        side interpolated (:func:`between_detections`); their flow is measured as for any
        other frame, from the last points held.
    eyes : bool
        With ``every`` > 1, also show every frame where the eyes move
        (:mod:`facetransfer.track.skip_rule`: a blink is too fast to be interpolated; an
        expression source's).
    pixel_aspect : float
        The frames are a video's resampled by it to square pixels (:mod:`.aspect`): the result
        says so (:attr:`ClipDetections.pixel_aspect`), and ``resume`` must.

    Returns
    -------
    ClipDetections
    """
    if resume is not None and start:
        raise ValueError("detect_clip: give resume or start, not both")
    k = int(start) if resume is None else resume.n_frames
    warm = k - int(getattr(detector, "warmup_frames", 0))
    found = _Found(keep478, resume, float(pixel_aspect))
    prev = None                      # the previous frame's grey image and thumbnail
    tick = progress or (lambda done, total: None)
    # the flow of frame i-1's points runs on a second thread while frame i is detected (OpenCV
    # and MediaPipe both release the GIL): on two cores it costs almost no time
    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            for i, fr in enumerate(frames):
                if n_frames is not None and i >= n_frames:
                    break
                if i < k:                                  # done before: skipped
                    prev = _skipped(detector, fr, i >= warm, flow and i == k - 1, prev)
                    tick(i + 1, n_frames or 0)
                    continue
                prev = _add_frame(found, detector, fr, prev, pool if flow else None, every,
                                  eyes)
                if checkpoint is not None and checkpoint.due():
                    checkpoint.save(found.result())
                tick(i + 1, n_frames or 0)
        except KeyboardInterrupt:
            if checkpoint is not None and found.Fl:
                checkpoint.save(found.result())
            raise
    return found.result()

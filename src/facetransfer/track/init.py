"""First-frame alignment (Vlasic et al. 2005, §5.2): feature points, then pose and weights.

Feature points come from the user (``--init POINTS.json``: ``{"points": {"36": [x, y], ...}}``,
pixel positions keyed by iBUG-68 number, 0-based; at least the eye corners 36, 39, 42, 45, the
nose tip 30 and the mouth corners 48, 54) or from an automatic detector — here MediaPipe Face
Landmarker (the paper used Viola-Jones features), mapped to iBUG-68 by
:mod:`facetransfer.track.landmarks`. The pose and all weights are fitted to the points
(:func:`facetransfer.track.solver.fit_points`); the tracker then "snaps" the alignment by
tracking the first frames back and forth.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from ..arkit import ARKIT_NAMES
from ..errors import AssetError, TrackError
from .landmarks import IBUG_WEIGHTS, REQUIRED_IBUG, eye_distance, ibug_names, mediapipe_to_ibug
from .solver import FrameState, fit_points

log = logging.getLogger(__name__)

__all__ = ["load_init_points", "check_init_points", "MediaPipeDetector", "LazyDetector",
           "fit_landmarks",
           "points_to_array", "require_landmarks"]


def require_landmarks(model) -> np.ndarray:
    """The model's 68 landmark vertices, or :class:`TrackError` if it has none."""
    lm = getattr(model, "landmarks", None)
    if lm is None or np.asarray(lm).shape != (68,):
        prov = getattr(model, "provenance", None) or {}
        src = prov.get("source") or prov.get("dataset")
        raise TrackError("the model" + (f" (built from {src})" if src else "") + " has no "
                         "landmark vertices (68 iBUG-68 points are needed to initialise "
                         "tracking): models built from ict-arkit, ict-bilinear or ict-trilinear "
                         "have them, a manifest's or a FaceWarehouse folder's do not")
    return np.asarray(lm, dtype=np.int64)


def check_init_points(points: dict, frame_size: tuple[int, int], *, where: str = "init points"
                      ) -> dict[int, np.ndarray]:
    """Validate ``{ibug number: (x, y)}``: numbers 0..67, the required ones present, in the image.

    Raises
    ------
    TrackError
    """
    W, H = int(frame_size[0]), int(frame_size[1])
    out: dict[int, np.ndarray] = {}
    for k, xy in points.items():
        try:
            i = int(k)
        except (TypeError, ValueError):
            raise TrackError(f"{where}: key {k!r} is not an iBUG-68 number (0..67)") from None
        if not 0 <= i < 68:
            raise TrackError(f"{where}: point number {i} is outside iBUG-68 (0..67)")
        try:
            a = np.asarray(xy, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise TrackError(f"{where}: point {i} must be [x, y], got {xy!r}") from None
        if a.shape != (2,) or not np.all(np.isfinite(a)):
            raise TrackError(f"{where}: point {i} must be [x, y], got {xy!r}")
        if not (-0.5 <= a[0] <= W - 0.5 and -0.5 <= a[1] <= H - 0.5):
            raise TrackError(f"{where}: point {i} at ({a[0]:g}, {a[1]:g}) is outside the "
                             f"{W}x{H} image")
        out[i] = a
    missing = [i for i in REQUIRED_IBUG if i not in out]
    if missing:
        names = ibug_names()
        raise TrackError(f"{where}: too few points; missing "
                         + ", ".join(f"{i} ({names[i]})" for i in missing)
                         + f" (need at least {', '.join(map(str, REQUIRED_IBUG))})")
    return out


def load_init_points(path: str | os.PathLike, frame_size: tuple[int, int]) -> dict[int, np.ndarray]:
    """Read ``{"points": {"36": [x, y], ...}}`` and validate it against the frame size."""
    p = Path(path)
    if not p.is_file():
        raise TrackError(f"init points file {p} does not exist")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        msg = getattr(exc, "msg", exc)
        raise TrackError(f"init points file {p} is not valid JSON ({msg})") from None
    if not isinstance(data, dict) or not isinstance(data.get("points"), dict):
        raise TrackError(f'init points file {p} must hold {{"points": {{"36": [x, y], ...}}}}')
    return check_init_points(data["points"], frame_size, where=f"init points {p}")


def points_to_array(points: dict[int, np.ndarray]) -> np.ndarray:
    """``{ibug: (x, y)}`` -> (68, 2) with NaN for absent points."""
    out = np.full((68, 2), np.nan)
    for i, xy in points.items():
        out[int(i)] = xy
    return out


def fit_landmarks(model, landmarks: np.ndarray, *, state: FrameState | None = None,
                  modes: tuple[str, ...] | None = None, prior: float = 4.0,
                  iterations: int = 30, weights: np.ndarray | None = None) -> FrameState:
    """Fit pose and weights to iBUG-68 image points (§5.2).

    Parameters
    ----------
    model : MultilinearModel
        With 68 landmark vertices.
    landmarks : (68, 2) float
        Pixel positions, NaN where unknown (at least 4 must be known).
    state : FrameState, optional
        Start; default the mean face with an affine pose.
    modes : tuple of str, optional
        Modes to fit (default all).
    prior : float
        Tikhonov weight, in squared pixels per unit of Mahalanobis distance (see
        :func:`~facetransfer.track.solver.fit_points`) scaled by the face size (outer
        eye-corner distance / 50 pixels, squared).
    weights : (68,) float, optional
        Per-point reliability (default :data:`~facetransfer.track.landmarks.IBUG_WEIGHTS`).

    Returns
    -------
    FrameState
    """
    vid = require_landmarks(model)
    L = np.asarray(landmarks, dtype=np.float64)
    ok = np.all(np.isfinite(L), axis=1)
    if ok.sum() < 4:
        raise TrackError(f"need at least 4 landmarks to fit the pose, got {int(ok.sum())}")
    w = (IBUG_WEIGHTS if weights is None else np.asarray(weights, float))[ok]
    iod = eye_distance(L)
    lam = prior * (max(iod, 1.0) / 50.0) ** 2
    return fit_points(model, vid[ok], L[ok], state=state, point_weights=w, modes=modes,
                      prior=lam, iterations=iterations)


class MediaPipeDetector:
    """MediaPipe Face Landmarker (Tasks API) returning iBUG-68 points.

    Parameters
    ----------
    model_path : path-like, optional
        ``face_landmarker.task``; default from the asset registry
        (``facetransfer.assets.asset_path("face_landmarker")``).
    faces : int
        The most faces :meth:`detect_every` finds (the others give the first).

    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, model_path: str | os.PathLike | None = None, *, faces: int = 1) -> None:
        self._lm = create_landmarker(model_path, video=False, faces=faces)

    def detect_every(self, frame: np.ndarray) -> list[np.ndarray]:
        """Every face found (up to ``faces``): MediaPipe's 478 landmarks of each in pixels."""
        import mediapipe as mp

        f = np.ascontiguousarray(frame, dtype=np.uint8)
        H, W = f.shape[:2]
        res = self._detect(mp.Image(image_format=mp.ImageFormat.SRGB, data=f))
        return [np.array([(q.x, q.y) for q in face], dtype=np.float64) * (W, H) - 0.5
                for face in res.face_landmarks]

    def detect478(self, frame: np.ndarray) -> np.ndarray | None:
        """MediaPipe's 478 landmarks in pixels (x, y), (478, 2), or None if no face."""
        return self.detect_scored(frame)[0]

    def detect_scored(self, frame: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(points, scores)``: the 478 landmarks in pixels (478, 2) and, for a landmarker
        made with blendshapes, its 52 scores in :data:`facetransfer.arkit.ARKIT_NAMES` order
        (52,) float32 (NaN for ``tongueOut``, which it does not score); None without a face
        (scores also None without blendshapes)."""
        import mediapipe as mp

        f = np.ascontiguousarray(frame, dtype=np.uint8)
        pts, scores = self._detect_arrays(mp.Image(image_format=mp.ImageFormat.SRGB, data=f))
        if pts is None:
            return None, None
        H, W = f.shape[:2]
        return pts * (W, H) - 0.5, scores  # normalised [0, 1] -> pixel centres at integers

    def _detect_arrays(self, image) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The first face's landmarks in normalised coordinates (478, 2) float64 and its
        scores (as :meth:`detect_scored`'s), or ``(None, None)`` without a face."""
        res = self._detect(image)
        if not res.face_landmarks:
            return None, None
        pts = np.array([(q.x, q.y) for q in res.face_landmarks[0]], dtype=np.float64)
        scores = None
        if getattr(res, "face_blendshapes", None):
            scores = blendshape_scores(res.face_blendshapes[0])
        return pts, scores

    def _detect(self, image):
        return self._lm.detect(image)

    def detect(self, frame: np.ndarray) -> np.ndarray | None:
        """iBUG-68 points (68, 2) in pixels, or None if no face was found."""
        P = self.detect478(frame)
        return None if P is None else mediapipe_to_ibug(P)

    def close(self) -> None:
        lm, self._lm = getattr(self, "_lm", None), None
        if lm is not None:
            lm.close()

    def __enter__(self) -> "MediaPipeDetector":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover
        try:
            self.close()
        except Exception:
            pass


#: Column of each ARKit name in :func:`blendshape_scores`' output.
_ARKIT_INDEX = {n: k for k, n in enumerate(ARKIT_NAMES)}


def blendshape_scores(categories) -> np.ndarray:
    """MediaPipe's blendshape categories (``category_name``, ``score``) as (52,) float32 in
    :data:`facetransfer.arkit.ARKIT_NAMES` order, NaN for a name it did not score."""
    out = np.full(len(ARKIT_NAMES), np.nan, np.float32)
    for c in categories:
        k = _ARKIT_INDEX.get(c.category_name)
        if k is not None:
            out[k] = c.score
    return out


#: Modules that MediaPipe's Tasks API imports for what this package never calls: its drawing
#: helpers (which import matplotlib's pyplot), its audio, text, retrieval and decision tasks,
#: and the microphone of the audio tasks (which imports ``sounddevice``, and catches the
#: OSError of a machine without PortAudio: that module lazy instead, its error came at the
#: first look at it, e.g. hypothesis's scan of ``sys.modules``). The audio package itself
#: too: its classifier's annotations look into the microphone's module as the class is
#: made, so that module alone lazy still loaded, searching for PortAudio with the compiler
#: and linker (``ctypes.util.find_library``; 0.03 CPU-s of processes a start). They are
#: loaded lazily (:func:`import_tasks_api`).
UNUSED_BY_TRACKING = frozenset({"mediapipe.tasks.python.vision.drawing_styles",
                                "mediapipe.tasks.python.vision.drawing_utils",
                                "mediapipe.tasks.python.audio",
                                "mediapipe.tasks.python.audio.core.audio_record",
                                "mediapipe.tasks.python.text",
                                "mediapipe.tasks.python.retrieval",
                                "mediapipe.tasks.python.decision"})


class _LazyFinder:
    """A meta path finder that gives the modules ``names`` a
    :class:`importlib.util.LazyLoader`: importing one binds it as usual, and its code runs on
    the first access of one of its attributes."""

    def __init__(self, names: frozenset) -> None:
        self.names = names

    def find_spec(self, name, path, target=None):
        import importlib.machinery
        import importlib.util

        if name not in self.names:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return None
        spec.loader = importlib.util.LazyLoader(spec.loader)
        return spec


def import_tasks_api():
    """``(BaseOptions, vision)`` of MediaPipe's Tasks API, its C++ logging set to errors only.

    Importing ``mediapipe.tasks.python`` also imports its drawing helpers (matplotlib's pyplot)
    and ``sounddevice``: 0.55 of its 0.85 CPU-s here (``python -X importtime``). Those modules
    (:data:`UNUSED_BY_TRACKING`) are made lazy first: each loads, whole, on its first use.

    Raises
    ------
    ImportError
        MediaPipe is not installed or cannot be imported.
    """
    import sys

    os.environ.setdefault("GLOG_minloglevel", "2")  # MediaPipe's C++ logging: errors only
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    if not any(isinstance(f, _LazyFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _LazyFinder(UNUSED_BY_TRACKING))
    from mediapipe.tasks.python import BaseOptions, vision

    return BaseOptions, vision


def create_landmarker(model_path: str | os.PathLike | None = None, *, video: bool = False,
                      blendshapes: bool = False, faces: int = 1):
    """A MediaPipe ``FaceLandmarker`` (Tasks API) in IMAGE or VIDEO running mode.

    ``model_path``: ``face_landmarker.task`` (default from the asset registry);
    ``blendshapes``: also output its 52 blendshape scores; ``faces``: the most faces it finds.
    """
    try:
        BaseOptions, vision = import_tasks_api()
    except ImportError as exc:  # pragma: no cover
        raise AssetError(f"mediapipe is not installed ({exc})") from None
    p = Path(_landmarker_path() if model_path is None else model_path)
    if not p.is_file():
        raise AssetError(f"face landmarker model {p} does not exist")
    mode = vision.RunningMode.VIDEO if video else vision.RunningMode.IMAGE
    opts = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(p)),
                                        running_mode=mode, num_faces=int(faces),
                                        output_face_blendshapes=bool(blendshapes))
    return vision.FaceLandmarker.create_from_options(opts)


def _landmarker_path() -> Path:
    try:
        from ..assets import asset_path

        return Path(asset_path("face_landmarker"))
    except ImportError:  # pragma: no cover - until the asset registry exists
        root = os.environ.get("FACETRANSFER_DATA_DIR")
        if not root:
            raise AssetError("the MediaPipe face landmarker is not available: set "
                             "FACETRANSFER_DATA_DIR") from None
        return Path(root) / "mediapipe" / "face_landmarker.task"


class LazyDetector:
    """A :class:`MediaPipeDetector` created on first use (e.g. only if the face is lost).

    If the detector cannot be created (asset missing), :meth:`detect` returns None and a
    warning is logged once.
    """

    def __init__(self, model_path: str | os.PathLike | None = None) -> None:
        self._path = model_path
        self._det: MediaPipeDetector | None = None
        self._failed = False

    def detect(self, frame: np.ndarray) -> np.ndarray | None:
        if self._det is None and not self._failed:
            try:
                self._det = MediaPipeDetector(self._path)
            except AssetError as exc:
                self._failed = True
                log.warning("face detector unavailable, cannot recover lost frames: %s", exc)
        return None if self._det is None else self._det.detect(frame)

    def close(self) -> None:
        if self._det is not None:
            self._det.close()
            self._det = None

    def __enter__(self) -> "LazyDetector":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""The result of tracking a face through a video, and its file format (``TRACK.npz``).

A :class:`Track` holds, per frame, the weak-perspective pose of Eq. (7) (Vlasic et al. 2005,
§5.1) — rotation ``R``, scale ``s`` (pixels per model unit) and translation ``t`` (pixels) — and
the multilinear model's attribute weights of Eq. (5), one array per mode; the identity (the
attribute constant over the clip) is the same on every frame.

File format (``numpy.savez``, written atomically), one key per field:

======================  ===================  =======================================================
key                     shape / dtype        meaning
======================  ===================  =======================================================
``fps``                 () float64           frame rate of the source video
``frame_size``          (2,) int64           ``(W, H)`` of the source video in pixels
``rotation``            (F, 3, 3) float64    model-to-camera rotation per frame
``scale``               (F,) float64         pixels per model unit per frame
``translation``         (F, 2) float64       pixel position of the model origin per frame
``weights_<mode>``      (F, r_mode) float64  attribute weights of each mode per frame
``landmarks2d``         (F, 68, 2) float64   pixel positions of the 68 tracked landmarks
``confidence``          (F,) float64         tracking confidence in [0, 1]
``lost``                (F,) bool            frames where the face was lost (pose held, re-found)
``model_hash``          () str               :attr:`MultilinearModel.content_hash` of the model used
``mode_names``          (K,) str             the model's modes, in order
``source``              () str               the tracked video's path
``blendshapes``         (F, 52) float32      ARKit activations in [0, 1] (only for an ARKit model)
``blendshape_names``    (52,) str            their names, :data:`facetransfer.arkit.ARKIT_NAMES`
``detections2d``        (F, 68, 2) float64   the detector's points the fit took (a capture track)
``pixel_aspect``        () float64           a pixel's width over its height (absent: 1)
``shot_starts``         (S,) int64           first frames of the later shots (absent: one shot)
``source_first_frame``  () int64             the clip's first frame number (absent: not recorded)
``source_timecode``     () str               the clip's start timecode ("" none; with the above)
``occluded``            (F, 3) bool          mouth, right eye, left eye covered (absent: not tested)
``made_by``             () str               what made a performance that was not tracked from
                                             ``source`` ("transfer": ``transfer --save-track``'s
                                             new performance); absent: a track of ``source``
``format_version``      () int64             version of this layout
======================  ===================  =======================================================
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import TrackError
from ..io.atomic import atomic_path
from ..io.source_facts import SourceFacts

__all__ = ["Track", "TRACK_FORMAT_VERSION", "MADE_BY_TRANSFER", "made_by_of", "made_by_words"]

#: Version of the track file layout written by :meth:`Track.save`.
TRACK_FORMAT_VERSION = 1

#: :attr:`Track.made_by` of a transfer's new performance (``transfer --save-track``).
MADE_BY_TRANSFER = "transfer"

#: The longest :attr:`Track.made_by` a track file may hold (characters): a word or two.
MADE_BY_LONGEST = 200

#: The frame rates a track may have (frames per second): beyond them the video writer fails
#: with a message about itself, not the track (1e-300 and 1e300 were read).
FPS_RANGE = (1e-2, 1e4)

#: The largest frame side a track may name (pixels): a video or plate is far smaller.
MAX_FRAME_SIDE = 1 << 16

#: How far a track file's rotations may stray from rotations, ``max |R Rᵀ - I|`` (the 64
#: tracks of a development machine's track cache: at most 9e-16).
ROTATION_TOLERANCE = 1e-4

#: The values a track file's pose and points may hold, in sides of its frame (the longer of
#: ``frame_size``): ``scale`` (pixels per model unit) within ``SCALE_SIDES``, the pixel
#: positions (``translation``, ``landmarks2d``, ``detections2d``) within ``PIXEL_SIDES`` of the
#: frame's corner, and every weight within ``WEIGHT_LIMIT``. The tracker's tracks of the data
#: folder's clips (driving_d6, face_2, WDA_KatieHill_000, forty-sixth session) hold scales of
#: 0.025-0.040 sides, positions of 0.17-1.04 sides and weights within 12: the bounds leave
#: four to five orders of magnitude; beyond them a frame rendered empty (1e300, 1e-300).
SCALE_SIDES = (1e-6, 1e3)
PIXEL_SIDES = 100.0
WEIGHT_LIMIT = 1e6


def _track_array(name: str, val, shape: tuple, dtype=np.float64) -> np.ndarray:
    """``val`` as an array of ``shape`` and ``dtype``, finite where it is float; a
    :class:`TrackError` naming the field otherwise."""
    a = np.asarray(val, dtype=dtype)
    if a.shape != shape:
        raise TrackError(f"track {name} must have shape {shape}, got {a.shape}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise TrackError(f"track {name} has non-finite values")
    return a


@dataclass(frozen=True, eq=False)
class Track:
    """Per-frame pose and model weights of a tracked face (Vlasic et al. 2005, §5.1, Eq. (7)).

    Attributes
    ----------
    fps : float
    frame_size : (int, int)
        ``(W, H)`` of the video in pixels.
    rotation : (F, 3, 3) float64
    scale : (F,) float64
    translation : (F, 2) float64
    weights : dict mode name -> (F, r) float64
        The identity (constant mode) has the same row on every frame.
    landmarks2d : (F, 68, 2) float64
        Pixel positions of the iBUG-68 landmarks: the model's landmark vertices; in a capture
        track with the clip's 3-D offsets added (static and view-dependent), at the pose with
        the pitch restored (:mod:`facetransfer.track.capture`).
    confidence : (F,) float64 in [0, 1]
    lost : (F,) bool
    model_hash : str
    mode_names : tuple of str
    source : str
        Path of the tracked video.
    blendshapes : (F, 52) float32 in [0, 1] or None
        ARKit activations per frame (models with ARKit-named expressions,
        :mod:`facetransfer.arkit`); ``None`` otherwise.
    blendshape_names : tuple of str or None
        Names of the ``blendshapes`` columns (:data:`facetransfer.arkit.ARKIT_NAMES`).
    detections2d : (F, 68, 2) float64 or None
        The detector's iBUG-68 points in pixels that the fit was fitted to (a capture track,
        :mod:`facetransfer.track.capture`), NaN where it found no face; ``detections2d -
        landmarks2d`` is the fit's residual (what the model did not follow, e.g. the lips,
        :mod:`facetransfer.lips`). None: not recorded.
    info : dict
        Free-form run details (not saved; e.g. per-pass residuals).
    pixel_aspect : float
        The width of the video's pixels over their height, as the capture tracker resampled
        the frames to square pixels to fit (:mod:`facetransfer.track.aspect`): the camera's
        ``x = s (R X)_x / pixel_aspect + t_x``; every pixel position (``translation``,
        ``landmarks2d``, ``detections2d``) is in the stored pixels. 1 for square pixels.
    shot_starts : tuple of int
        Frames where a new shot starts in a clip edited from several
        (:mod:`facetransfer.track.shots`: each captured on its own, with its own identity save
        a later shot of the first one's person, with that one's; the rewrite chooses its
        reference frames within each); empty for one shot.
    source_facts : SourceFacts or None
        The tracked clip's first frame number and start timecode as read when it was tracked
        (:func:`facetransfer.io.source_facts.read_source_facts`), what the exports number
        and time the frames by; None: not recorded (a track made before they were, or not
        from a clip: an export then reads them from ``source`` if it is still there).
    occluded : (F, 3) bool or None
        Per frame, whether the mouth, the right eye and the left eye were found covered
        (:mod:`facetransfer.track.occlusion`: their activations bridged there); None: not
        tested.
    made_by : str
        "" for a track of its clip (``source``, tracked or imported); else what made this
        performance instead (:data:`MADE_BY_TRANSFER`: a transfer's new performance, the
        source's expressions on the target's head, ``transfer --save-track``), which is no
        clip's own track: a transfer refuses it as one (``--target-track``,
        :func:`facetransfer.transfer_plan.check_given_tracks`), a performance's readers
        (``export``, ``view``, ``puppet``, ``edit``, ``--performance``) take it as before. Kept
        by the transforms that copy a track (:func:`dataclasses.replace`: ``take_frames``,
        ``edit``); not part of a render's key (:mod:`facetransfer.render_cache`).
    """

    fps: float
    frame_size: tuple[int, int]
    rotation: np.ndarray
    scale: np.ndarray
    translation: np.ndarray
    weights: dict
    landmarks2d: np.ndarray
    confidence: np.ndarray
    lost: np.ndarray
    model_hash: str
    mode_names: tuple[str, ...]
    source: str = ""
    blendshapes: np.ndarray | None = None
    blendshape_names: tuple[str, ...] | None = None
    info: dict = field(default_factory=dict)
    detections2d: np.ndarray | None = None
    pixel_aspect: float = 1.0
    shot_starts: tuple[int, ...] = ()
    source_facts: SourceFacts | None = None
    occluded: np.ndarray | None = None
    made_by: str = ""

    def __post_init__(self) -> None:
        R = np.asarray(self.rotation, dtype=np.float64)
        if R.ndim != 3 or R.shape[1:] != (3, 3):
            raise TrackError(f"track rotation must be (F, 3, 3), got {R.shape}")
        F = R.shape[0]
        if F < 1:
            raise TrackError("a track needs at least one frame")
        self._check_pose(R, F)
        self._check_weights(F)
        self._check_clip(F)
        self._check_blendshapes(F)
        if self.detections2d is not None:
            D = np.asarray(self.detections2d, dtype=np.float64)
            if D.shape != (F, 68, 2):
                raise TrackError(f"track detections2d must have shape {(F, 68, 2)}, got {D.shape}")
            if np.isinf(D).any():
                raise TrackError("track detections2d must be finite or NaN (no face)")
            object.__setattr__(self, "detections2d", D)
        if self.occluded is not None:
            C = np.asarray(self.occluded, dtype=bool)
            if C.shape != (F, 3):
                raise TrackError(f"track occluded must have shape {(F, 3)}, got {C.shape}")
            object.__setattr__(self, "occluded", C)

    def _check_pose(self, R: np.ndarray, F: int) -> None:
        """The per-frame pose, points, confidence and lost flags, checked and stored as arrays
        of ``F`` frames."""
        set_ = object.__setattr__
        set_(self, "rotation", _track_array("rotation", R, (F, 3, 3)))
        set_(self, "scale", _track_array("scale", self.scale, (F,)))
        if np.any(self.scale <= 0):
            raise TrackError("track scale must be > 0 on every frame")
        set_(self, "translation", _track_array("translation", self.translation, (F, 2)))
        set_(self, "landmarks2d", _track_array("landmarks2d", self.landmarks2d, (F, 68, 2)))
        conf = _track_array("confidence", self.confidence, (F,))
        if np.any((conf < 0) | (conf > 1)):
            raise TrackError("track confidence must lie in [0, 1]")
        set_(self, "confidence", conf)
        set_(self, "lost", _track_array("lost", self.lost, (F,), bool))

    def _check_weights(self, F: int) -> None:
        """The mode names and each mode's weights ``(F, r)``, finite."""
        names = tuple(str(n) for n in self.mode_names)
        if not names:
            raise TrackError("a track needs at least one mode name")
        if len(set(names)) != len(names):
            raise TrackError(f"track mode names {list(names)} repeat a name")
        object.__setattr__(self, "mode_names", names)
        if set(self.weights) != set(names):
            raise TrackError(f"track weights are given for modes {sorted(self.weights)}, "
                             f"expected {list(names)}")
        w = {}
        for n in names:
            a = np.asarray(self.weights[n], dtype=np.float64)
            if a.ndim != 2 or a.shape[0] != F:
                raise TrackError(f"track weights of mode {n!r} must be ({F}, r), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise TrackError(f"track weights of mode {n!r} have non-finite values")
            w[n] = a
        object.__setattr__(self, "weights", w)

    def _check_clip(self, F: int) -> None:
        """What the track says of its clip: frame size, rate, pixel aspect, shots, model and
        source."""
        set_ = object.__setattr__
        size = tuple(int(v) for v in np.asarray(self.frame_size).ravel())
        if len(size) != 2 or min(size) <= 0 or max(size) > MAX_FRAME_SIDE:
            raise TrackError(f"track frame_size must be (W, H) in 1..{MAX_FRAME_SIDE}, got "
                             f"{list(size)}")
        set_(self, "frame_size", size)
        fps = float(self.fps)
        if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:    # NaN too
            raise TrackError(f"track fps must lie in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}], "
                             f"got {self.fps}")
        set_(self, "fps", fps)
        aspect = float(self.pixel_aspect)
        if not np.isfinite(aspect) or aspect <= 0:
            raise TrackError(f"track pixel_aspect must be > 0, got {self.pixel_aspect}")
        set_(self, "pixel_aspect", aspect)
        starts = tuple(int(v) for v in np.asarray(self.shot_starts, dtype=np.int64).ravel())
        if any(not 0 < a < F for a in starts) or list(starts) != sorted(set(starts)):
            raise TrackError(f"track shot_starts must be increasing frames in 1..{F - 1}, got "
                             f"{list(starts)}")
        set_(self, "shot_starts", starts)
        set_(self, "model_hash", str(self.model_hash))
        set_(self, "source", str(self.source))
        if self.source_facts is not None and not isinstance(self.source_facts, SourceFacts):
            raise TrackError(f"track source_facts must be a SourceFacts, got "
                             f"{type(self.source_facts).__name__}")
        made = "" if self.made_by is None else str(self.made_by)   # None: a clip's, not "None"
        if len(made) > MADE_BY_LONGEST or not made.isprintable():
            raise TrackError(f"track made_by must be a line of at most {MADE_BY_LONGEST} "
                             f"characters, got {made[:40]!r}")
        set_(self, "made_by", made)

    def _check_blendshapes(self, F: int) -> None:
        if self.blendshapes is None:
            if self.blendshape_names is not None:
                raise TrackError("track has blendshape names but no blendshapes")
            return
        a = np.asarray(self.blendshapes)   # checked before the cast to float32 (1e300 made
        # numpy's overflow warning, a line before the error)
        names = tuple(str(n) for n in (self.blendshape_names or ()))
        if a.ndim != 2 or a.shape[0] != F or a.shape[1] != len(names):
            raise TrackError(f"track blendshapes must be ({F}, {len(names)}) for its "
                             f"{len(names)} names, got {a.shape}")
        a64 = a.astype(np.float64)
        if not np.all(np.isfinite(a64)) or a64.size and (a64.min() < 0 or a64.max() > 1):
            raise TrackError("track blendshapes must be finite and lie in [0, 1]")
        object.__setattr__(self, "blendshapes", np.asarray(a, np.float32))
        object.__setattr__(self, "blendshape_names", names)

    # ------------------------------------------------------------------ access
    @property
    def n_frames(self) -> int:
        return int(self.rotation.shape[0])

    def _check_frame(self, i: int) -> int:
        i = int(i)
        if not -self.n_frames <= i < self.n_frames:
            raise TrackError(f"frame {i} outside the track's {self.n_frames} frames")
        return i

    def camera(self, i: int):
        """Camera of frame ``i``: a :class:`~facetransfer.render.WeakPerspective`."""
        from ..render import WeakPerspective

        i = self._check_frame(i)
        return WeakPerspective(float(self.scale[i]), self.rotation[i], self.translation[i],
                               self.pixel_aspect)

    def weights_at(self, i: int) -> dict[str, np.ndarray]:
        """Weights of every mode at frame ``i``: dict mode name -> (r,) (copies)."""
        i = self._check_frame(i)
        return {n: self.weights[n][i].copy() for n in self.mode_names}

    @property
    def label(self) -> str:
        """How a message names this track: the file it was read from (:meth:`load`), else
        the video it was tracked from ("of clip.mp4"), else nothing."""
        if self.info.get("file"):
            return str(self.info["file"])
        return f"of {self.source}" if self.source else ""

    def other_video(self, video) -> str | None:
        """The name of the video this track was made from where it is not ``video``'s (a
        renamed copy passes; another clip of the same size would be followed with the wrong
        motion), else None."""
        made = Path(str(self.source)).name if self.source else ""
        return made if made and made != Path(str(video)).name else None

    def warn_other_video(self, video, consequence: str, role: str = "") -> None:
        """A warning where :meth:`other_video`: "ROLE track LABEL was made from X, not Y: if
        that is another clip, CONSEQUENCE"."""
        made = self.other_video(video)
        if made:
            logging.getLogger(__name__).warning(
                "%strack %s was made from %s, not %s: if that is another clip, %s",
                f"{role} " if role else "", self.label, made, Path(str(video)).name,
                consequence)

    def check_video(self, n_frames: int, size: tuple[int, int], *, what: str = "video") -> None:
        """Raise :class:`TrackError` unless the track matches a video's frame count and size."""
        size = (int(size[0]), int(size[1]))
        if size != self.frame_size:
            raise TrackError(f"track {self.label} is for frames of "
                             f"{self.frame_size[0]}x{self.frame_size[1]}, but {what} is "
                             f"{size[0]}x{size[1]}")
        if int(n_frames) != self.n_frames:
            raise TrackError(f"track {self.label} has {self.n_frames} frames, but {what} "
                             f"has {n_frames}")

    def check_model(self, model) -> None:
        """Raise :class:`TrackError` unless ``model`` is the model this track was made with
        (where that is a default model, the refusal says how to give it: leave out --model for
        this version's, another version's kept file by name: :mod:`facetransfer.model_hint`)."""
        from ..model_hint import model_hint

        why = None
        if tuple(model.mode_names) != self.mode_names:
            why = f"has modes {self.mode_names}, the model {model.mode_names}"
        for n, r in zip(model.mode_names, model.ranks):
            if why is None and self.weights[n].shape[1] != r:
                why = (f"was made with another model: its weights of mode {n!r} have "
                       f"{self.weights[n].shape[1]} components, the model's {r}")
        if why is None and self.model_hash and self.model_hash != model.content_hash:
            why = (f"was made with a different model (model hash {self.model_hash[:12]}, this "
                   f"one's {model.content_hash[:12]})")
        if why is not None:
            raise TrackError(f"track {self.label} {why}" + (
                model_hint(self.model_hash)
                or " (give the model it was tracked with as --model)"))

    def with_source_facts(self, clip=None) -> "Track":
        """This track with the first frame number and start timecode of ``clip`` (default:
        ``source``), the clip it was tracked from, recorded (:attr:`source_facts`; a track
        that records them already is returned as it is). Called where a track is made from a
        clip, before the clip can move."""
        if self.source_facts is not None:
            return self
        from dataclasses import replace

        from ..io.source_facts import read_source_facts

        return replace(self, source_facts=read_source_facts(self.source if clip is None
                                                            else clip))

    # ------------------------------------------------------------------ file i/o
    def save(self, path: str | os.PathLike, *, overwrite: bool = True) -> Path:
        """Write the track to ``path`` (``.npz``) atomically and return the path."""
        arrays = {
            "format_version": np.int64(TRACK_FORMAT_VERSION),
            "fps": np.float64(self.fps),
            "frame_size": np.asarray(self.frame_size, dtype=np.int64),
            "rotation": self.rotation, "scale": self.scale, "translation": self.translation,
            "landmarks2d": self.landmarks2d, "confidence": self.confidence, "lost": self.lost,
            "model_hash": np.array(self.model_hash), "mode_names": np.array(self.mode_names),
            "source": np.array(self.source), "pixel_aspect": np.float64(self.pixel_aspect),
        }
        for n in self.mode_names:
            arrays[f"weights_{n}"] = self.weights[n]
        if self.blendshapes is not None:
            arrays["blendshapes"] = self.blendshapes
            arrays["blendshape_names"] = np.array(self.blendshape_names)
        if self.detections2d is not None:
            arrays["detections2d"] = self.detections2d
        if self.occluded is not None:
            arrays["occluded"] = self.occluded
        if self.made_by:             # a track of a clip: written as before the key was
            arrays["made_by"] = np.array(self.made_by)
        if self.shot_starts:
            arrays["shot_starts"] = np.asarray(self.shot_starts, np.int64)
        if self.source_facts is not None:
            arrays["source_first_frame"] = np.int64(self.source_facts.first_frame)
            arrays["source_timecode"] = np.array(self.source_facts.timecode or "")
        with atomic_path(path, overwrite=overwrite) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Track":
        """Read and validate a track file written by :meth:`save`.

        Raises
        ------
        TrackError
            Missing, truncated or malformed file, a newer format version, or inconsistent arrays.
        """
        from ..io.npz import read_npz, scalar

        p = Path(path)
        data = read_npz(p, "track file", TrackError)
        required = ("fps", "frame_size", "rotation", "scale", "translation", "landmarks2d",
                    "confidence", "lost", "model_hash", "mode_names")
        missing = [k for k in required if k not in data]
        if missing:
            from ..io.npz import known_npz

            kind = known_npz(p, data)   # as probe names it (synth-video's truth, ...)
            raise TrackError(f"{p} is not a track file (missing {', '.join(missing)})"
                             if kind is None else f"{p} is {kind}, not a track: give a track "
                             "of the clip (`facetransfer track`)")
        _check_version(data, p)
        _check_kinds(data, p)
        names = tuple(str(n) for n in np.atleast_1d(data["mode_names"]))
        absent = [n for n in names if f"weights_{n}" not in data]
        if absent:
            raise TrackError(f"track file {p} lacks weights of mode(s) {absent}")
        _check_rotations(data["rotation"], p)
        _check_ranges(data, names, p)
        try:
            return cls(fps=scalar(data, "fps", float, p, "track file", TrackError),
                       frame_size=tuple(np.asarray(data["frame_size"]).ravel()),
                       rotation=data["rotation"], scale=data["scale"],
                       translation=data["translation"],
                       weights={n: data[f"weights_{n}"] for n in names},
                       landmarks2d=data["landmarks2d"], confidence=data["confidence"],
                       lost=data["lost"],
                       model_hash=scalar(data, "model_hash", str, p, "track file", TrackError),
                       mode_names=names,
                       source=str(data.get("source", "")),
                       blendshapes=data.get("blendshapes"),
                       blendshape_names=(None if "blendshape_names" not in data else
                                         tuple(str(n) for n in
                                               np.atleast_1d(data["blendshape_names"]))),
                       detections2d=data.get("detections2d"),
                       pixel_aspect=(scalar(data, "pixel_aspect", float, p, "track file",
                                            TrackError) if "pixel_aspect" in data else 1.0),
                       shot_starts=tuple(np.asarray(data.get("shot_starts", ())).ravel()),
                       source_facts=_source_facts(data, p), info={"file": str(p)},
                       occluded=data.get("occluded"),
                       made_by=scalar(data, "made_by", str, p, "track file", TrackError)
                       if "made_by" in data else "")
        except (TrackError, ValueError, TypeError, OverflowError) as exc:
            if str(p) in str(exc):   # said of the file already: not twice
                raise TrackError(str(exc)) from None
            raise TrackError(f"track file {p} is invalid: {exc}") from None


def made_by_words(made_by: str) -> str:
    """What a message calls a track file marked ``made_by`` (:attr:`Track.made_by`, not "")."""
    if made_by == MADE_BY_TRANSFER:
        return ("a transfer's saved performance (--save-track: the source's expressions on the "
                "target's head)")
    return f"a performance made by {made_by}"


def made_by_of(path: str | os.PathLike) -> str:
    """The :attr:`Track.made_by` of the track file ``path``, read alone (its other arrays are
    not read: a check before any work); "" for a track of a clip, a file written before the
    key was, or one that is not a readable track file (:meth:`Track.load` says what is wrong
    with it where it is read)."""
    from ..io.npz import NOT_ARCHIVE_ERRORS

    try:
        z = np.load(path, mmap_mode="r", allow_pickle=False)   # an .npy: mapped, not read
        if not isinstance(z, np.lib.npyio.NpzFile):
            return ""
        with z:
            if "made_by" not in z.files:
                return ""
            a = z["made_by"]
    except (*NOT_ARCHIVE_ERRORS, AttributeError, KeyError):
        return ""
    return str(a.reshape(())) if a.dtype.kind in "US" and a.size == 1 else ""


#: Track file keys that hold text; every other key holds numbers.
_TEXT_KEYS = ("mode_names", "blendshape_names", "model_hash", "source", "source_timecode",
              "made_by")


def _check_version(data: dict, p: Path) -> None:
    """TrackError unless the file's ``format_version`` (absent: 1) is one this reads."""
    from ..io.npz import scalar

    version = scalar(data, "format_version", int, p, "track file", TrackError) \
        if "format_version" in data else 1
    if version > TRACK_FORMAT_VERSION:
        raise TrackError(f"track file {p} has format version {version}, newer than this "
                         f"facetransfer reads ({TRACK_FORMAT_VERSION})")
    if version < 1:    # no version was ever 0 or negative: not written by save
        raise TrackError(f"track file {p} has format version {version}; versions start at 1")


def _check_kinds(data: dict, p: Path) -> None:
    """TrackError where an array of a track file holds the wrong kind of value: text where
    numbers belong or numbers where text does, flags other than 0/1 in ``lost``, fractions in
    ``shot_starts`` (before: ``lost`` of 0.5 read as True, ``shot_starts`` 1.5 as frame 1)."""
    for k, a in data.items():
        if k in _TEXT_KEYS and a.dtype.kind not in "US":
            raise TrackError(f"track file {p}: {k!r} must hold text, got {a.dtype}")
        if k not in _TEXT_KEYS and a.dtype.kind not in "biuf":
            raise TrackError(f"track file {p}: {k!r} must hold numbers, got {a.dtype}")
    lost = data["lost"]
    if lost.dtype.kind != "b" and not np.isin(lost, (0, 1)).all():
        raise TrackError(f"track file {p}: 'lost' must hold flags (True/False or 0/1)")
    starts = data.get("shot_starts")
    if starts is not None and starts.dtype.kind == "f" and \
            not np.array_equal(starts, np.round(starts)):
        raise TrackError(f"track file {p}: 'shot_starts' must hold whole frame numbers")


def _check_rotations(rotation: np.ndarray, p: Path) -> None:
    """TrackError naming the first frame whose ``rotation`` (F, 3, 3) is not a rotation
    (orthonormal, determinant +1, to :data:`ROTATION_TOLERANCE`): the renderer refused it
    without naming the track, the exports read a head's angles from it (scaled or zero
    matrices were read)."""
    R = np.asarray(rotation, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or not np.isfinite(R).all():
        return   # said by the track's own checks
    with np.errstate(all="ignore"):
        off = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
        bad = (off > ROTATION_TOLERANCE) | (np.linalg.det(R) < 0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise TrackError(f"track file {p}: rotation of frame {k} is not a rotation matrix "
                         f"(R Rᵀ = I, det R = +1)")


def _value_ranges(data: dict, names: tuple) -> dict[str, tuple[float, float]]:
    """``{key: (low, high)}``: the values a track file's numbers may hold (:data:`SCALE_SIDES`,
    :data:`PIXEL_SIDES`, :data:`WEIGHT_LIMIT`); none where its ``frame_size`` is not one (the
    track's own checks say so)."""
    size = np.asarray(data["frame_size"], dtype=np.float64).ravel()
    if size.size != 2 or not np.isfinite(size).all() or size.min() <= 0:
        return {}
    side = float(size.max())
    pixels = (-PIXEL_SIDES * side, PIXEL_SIDES * side)
    return {"scale": (SCALE_SIDES[0] * side, SCALE_SIDES[1] * side), "translation": pixels,
            "landmarks2d": pixels, "detections2d": pixels,
            **{f"weights_{n}": (-WEIGHT_LIMIT, WEIGHT_LIMIT) for n in names}}


def _check_ranges(data: dict, names: tuple, p: Path) -> None:
    """TrackError naming the key and the first frame of a value that is not a number or that
    no tracked face holds (:func:`_value_ranges`; ``detections2d`` NaN where the detector found
    no face): before, a scale or translation of 1e300 or 1e-300 rendered an empty frame with a
    warning of the renderer's, weights of 1e300 "all triangles are degenerate", naming neither
    the track nor the frame, and a NaN was "non-finite values" without its frame."""
    for key, (lo, hi) in _value_ranges(data, names).items():
        a = np.asarray(data[key], dtype=np.float64) if key in data else np.empty(0)
        if a.ndim == 0 or a.size == 0:
            continue                      # absent, or a shape the track's own checks say
        v = a.reshape(len(a), -1)
        with np.errstate(invalid="ignore"):
            bad = ~((v >= lo) & (v <= hi))
        if key == "detections2d":
            bad &= ~np.isnan(v)
        if bad.any():
            k = int(np.flatnonzero(bad.any(axis=1))[0])
            x = float(v[k][bad[k]][0])
            w, h = (int(n) for n in np.asarray(data["frame_size"]).ravel())
            what = "not a number" if np.isnan(x) else (
                f"outside [{lo:g}, {hi:g}], what a face tracked in {w}x{h} frames holds")
            raise TrackError(f"track file {p}: {key} of frame {k} is {x:g}, {what}")


def _source_facts(data: dict, p: Path) -> SourceFacts | None:
    """The clip's numbering a track file records (keys ``source_first_frame`` and
    ``source_timecode``), None where it records none (written before they were)."""
    from ..io.npz import scalar

    if "source_first_frame" not in data:
        return None
    if "source_timecode" in data and data["source_timecode"].dtype.kind not in "US":
        raise TrackError(f"track file {p}: 'source_timecode' must hold text, got "
                         f"{data['source_timecode'].dtype}")
    first = scalar(data, "source_first_frame", int, p, "track file", TrackError)
    timecode = str(data["source_timecode"]) if "source_timecode" in data else ""
    try:
        return SourceFacts(first, timecode or None)
    except ValueError as exc:
        raise TrackError(f"track file {p}: source_first_frame/source_timecode: {exc}") from None

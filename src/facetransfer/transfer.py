"""Face transfer applications on tracked performances (Vlasic et al. 2005, §5, §6, Fig. 1, Fig. 7).

A tracked video is a :class:`~facetransfer.track.Track`: per frame a weak-perspective pose
(Eq. (7)) and one weight vector per model mode (Eq. (5)). Because the multilinear model separates
the attributes, a new performance is made by picking each attribute's weights from a different
track and synthesising the face from Eq. (5) (§6: "the pose from the original video with the
expression from the new video"):

* :func:`time_map` / :func:`resample_track`: put a source track on the target's timeline (another
  frame rate or length; ``align`` = ``trim`` | ``loop`` | ``hold``);
* :func:`recombine`: identity, expression, viseme and pose from up to three tracks (Fig. 1,
  Fig. 7B–7D);
* :func:`edit_track`: add a training expression over a frame range or scale an expression's
  component (Fig. 7E);
* :func:`puppet_frames`: drive an identity of the model from a video, rendered alone.

Rendering the new performance back into footage is :mod:`facetransfer.rewrite` (one frame) and
:mod:`facetransfer.video_transfer` (the job). Every function here is pure: tracks in, a new
track out.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005,
§5 (Eq. (5), (7)), §6 and Figures 1 and 7.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from .arkit import attach_activations, is_arkit_model
from .errors import FaceTransferError, RewriteError, ShapeError
from .topology import close_mouth, mesh_topology
from .track.project import project_landmarks, take_frames

log = logging.getLogger(__name__)

__all__ = [
    "ALIGN_MODES",
    "nearest_frames",
    "TransferError",
    "TimeMap",
    "time_map",
    "resample_track",
    "constant_weights",
    "recombine",
    "project_landmarks",
    "EditAdd",
    "EditScale",
    "edit_activations",
    "parse_add",
    "parse_scale",
    "ramp_envelope",
    "edit_track",
    "puppet_frames",
    "take_frames",
    "identity_from_label",
    "parse_weights",
]

#: Ways to align a source performance with the target's length (see :func:`time_map`).
ALIGN_MODES = ("trim", "loop", "hold")


class TransferError(FaceTransferError):
    """A transfer, edit or alignment that cannot be done with the given tracks and options."""


# ---------------------------------------------------------------------------------------------
# time alignment
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TimeMap:
    """Where each output frame takes a source from.

    Attributes
    ----------
    source_time : (n_out,) float64
        Position in source frames (fractional: linear interpolation between neighbours).
    align : str
        The alignment used (``"trim"``, ``"loop"`` or ``"hold"``).
    """

    source_time: np.ndarray
    align: str

    @property
    def n_frames(self) -> int:
        return int(self.source_time.shape[0])

    @property
    def nearest(self) -> np.ndarray:
        """(n_out,) int64: the nearest source frame of every output frame."""
        return np.floor(self.source_time + 0.5).astype(np.int64)


def time_map(n_source: int, fps_source: float, n_target: int, fps_target: float, *,
             align: str | None = None) -> TimeMap:
    """Map the target's frames onto source time at the target's frame rate.

    Output frame ``j`` (time ``j / fps_target``) reads the source at frame
    ``j * fps_source / fps_target``. When that runs past the source's last frame:

    * ``"trim"``: the output stops there (``n_out`` = frames of the target that the source covers,
      its last frame for its own duration: a 0.8 s source of 20 frames gives 24 at 30 fps);
    * ``"loop"``: the source restarts from its first frame;
    * ``"hold"``: the source's last frame is held.

    The default (``align=None``) is ``"trim"`` when the source is at least as long as the target
    (its extra frames are dropped; the output has the target's length) and ``"hold"`` when it is
    shorter (the target keeps its length; the source's last frame is held).

    Parameters
    ----------
    n_source, n_target : int
        Frame counts (>= 1).
    fps_source, fps_target : float
        Frame rates (> 0).
    align : {"trim", "loop", "hold"} or None, keyword-only

    Returns
    -------
    TimeMap
        ``source_time`` of length ``n_target`` (``loop``, ``hold``) or at most ``n_target``
        (``trim``).
    """
    for what, n in (("source", n_source), ("target", n_target)):
        if isinstance(n, bool) or not float(n).is_integer():  # 40.7 was taken as 40
            raise TransferError(f"frame counts are whole numbers, got {what} {n!r}")
    if int(n_source) < 1 or int(n_target) < 1:
        raise TransferError(f"frame counts must be >= 1, got source {n_source}, target {n_target}")
    if not (fps_source > 0 and fps_target > 0 and np.isfinite(fps_source * fps_target)):
        raise TransferError(f"frame rates must be > 0, got source {fps_source}, "
                            f"target {fps_target}")
    n_source, n_target = int(n_source), int(n_target)
    ratio = float(fps_source) / float(fps_target)
    t = np.arange(n_target, dtype=np.float64) * ratio  # source frame at each target frame
    last = n_source - 1
    if align is None:
        align = "trim" if t[-1] <= last + 1e-9 else "hold"
    if align not in ALIGN_MODES:
        raise TransferError(f"align must be one of {', '.join(ALIGN_MODES)}, got {align!r}")
    if align == "trim":   # to the end of the source's last frame (it lasts 1 / fps_source)
        t = t[t < n_source - 1e-9]
        t = np.minimum(t, last)
    elif align == "loop":   # a repeat an ulp short (29.97 / 23.976 = 1.2499...8) is one
        t = np.mod(t, n_source)
        t[t > n_source - 1e-9] = 0.0
        # between the last frame and the wrap, interpolate towards the last frame (no blend with 0)
        t = np.minimum(t, last)
    else:
        t = np.minimum(t, last)
    return TimeMap(t, align)


def _interp_rows(a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``a`` (n, ...) at fractional rows ``t`` (m,).

    Written ``a0 + (a1 - a0) f``: where both rows hold the same value it is that value, bit
    for bit (a track's constant identity stays constant; ``a0 (1 - f) + a1 f`` rounds it
    apart by an ulp, and the render then takes it for an identity that changes: 1.3 s a
    call instead of 4 ms, :meth:`facetransfer.model.MultilinearModel.clip_basis`)."""
    i0 = np.clip(np.floor(t).astype(np.int64), 0, a.shape[0] - 1)
    i1 = np.minimum(i0 + 1, a.shape[0] - 1)
    f = (t - i0).reshape((-1,) + (1,) * (a.ndim - 1))
    a0 = a[i0]
    return a0 + (a[i1] - a0) * f


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotations (F, 3, 3) of (F, 3, 3) matrices
    (:func:`facetransfer.track.camera.nearest_rotation`, the SVD projection)."""
    from .track.camera import nearest_rotation  # here: the track package is slow to import

    return np.stack([nearest_rotation(r) for r in R]) if len(R) else np.asarray(R, np.float64)


def resample_track(track, tmap: TimeMap):
    """The track sampled at ``tmap.source_time`` (linear in pose and weights).

    Rotations are interpolated linearly and projected back onto rotations; a resampled frame is
    lost if either source frame it reads is lost. A frame between the two sides of a cut
    (``track.shot_starts``) takes the earlier shot's last frame (two shots are not blended),
    and the cuts move to the first frames that read their shots. Frame rate and size are kept
    (the caller sets the target's with :func:`dataclasses.replace`).

    Parameters
    ----------
    track : Track
    tmap : TimeMap

    Returns
    -------
    Track
        With ``tmap.n_frames`` frames.
    """
    t = np.asarray(tmap.source_time, dtype=np.float64)
    if t.size == 0:
        raise TransferError("time map is empty: the source covers none of the target")
    if t.min() < 0 or t.max() > track.n_frames - 1 + 1e-9:
        raise TransferError(f"time map reads source frames {t.min():.1f}..{t.max():.1f}, "
                            f"outside the track's {track.n_frames} frames")
    i0 = np.floor(t).astype(np.int64)
    t = np.where(np.isin(np.minimum(i0 + 1, track.n_frames - 1), track.shot_starts), i0, t)
    i1 = np.minimum(i0 + 1, track.n_frames - 1)
    frac = t - i0
    lost = track.lost[i0] | ((frac > 1e-9) & track.lost[i1])
    return dataclasses.replace(
        track, shot_starts=_resampled_starts(track.shot_starts, t),
        rotation=_orthonormalize(_interp_rows(track.rotation, t)),
        scale=_interp_rows(track.scale, t),
        translation=_interp_rows(track.translation, t),
        weights={n: _interp_rows(w, t) for n, w in track.weights.items()},
        landmarks2d=_interp_rows(track.landmarks2d, t),
        confidence=np.minimum(track.confidence[i0], track.confidence[i1]),
        lost=lost,
        blendshapes=(None if track.blendshapes is None else  # affine in the weights (Eq. A)
                     np.clip(_interp_rows(track.blendshapes, t), 0.0, 1.0)),
        # an observation of a frame, not interpolated: the nearest frame's (whose image a
        # resampled mouth is textured from, video_transfer's ``mouth_index``)
        detections2d=(None if track.detections2d is None else
                      track.detections2d[np.minimum(tmap.nearest, track.n_frames - 1)]),
        info={},
    )


def _resampled_starts(starts, t: np.ndarray) -> tuple[int, ...]:
    """The cuts ``starts`` (source frames) of a track resampled at source times ``t`` (m,): the
    first frame reading each cut's shot, where that is neither the first frame nor past the
    last; none when ``t`` runs back somewhere (a cut is then no frame's)."""
    if not starts or len(t) < 2 or np.any(np.diff(t) < 0):
        return ()
    ks = np.searchsorted(t, np.asarray(starts, np.float64) - 1e-9, side="left")
    return tuple(sorted({int(k) for k in ks if 0 < k < len(t)}))


# ---------------------------------------------------------------------------------------------
# recombination (Fig. 1, Fig. 7B-D)
# ---------------------------------------------------------------------------------------------

def constant_weights(track, mode: str) -> np.ndarray:
    """A constant attribute of a track (e.g. its identity): mean over frames not lost, (r,)."""
    if mode not in track.weights:
        raise TransferError(f"track has no mode {mode!r} (modes: {', '.join(track.mode_names)})")
    good = ~track.lost
    w = track.weights[mode]
    if not good.any():
        raise TransferError(f"the face is lost in every frame of {track.source or 'the track'}; "
                            f"no {mode} to take from it")
    return w[good].mean(axis=0)


def _check_compatible(target, other, what: str) -> None:
    if tuple(other.mode_names) != tuple(target.mode_names):
        raise TransferError(f"{what} track has modes {other.mode_names}, the target "
                            f"{target.mode_names}: track both with the same model")
    for n in target.mode_names:
        if other.weights[n].shape[1] != target.weights[n].shape[1]:
            raise TransferError(f"{what} track has {other.weights[n].shape[1]} {n} weights, the "
                                f"target {target.weights[n].shape[1]}: use the same model")
    if target.model_hash and other.model_hash and target.model_hash != other.model_hash:
        raise TransferError(f"{what} track was made with a different model than the target "
                            f"(model hashes differ)")


def _placement(track) -> tuple[np.ndarray, float]:
    """The head's usual place and size in a track: the median translation in shown (square)
    pixels and the median scale, over the frames not lost (all frames if every one is)."""
    ok = ~np.asarray(track.lost, bool)
    ok = ok if ok.any() else np.ones_like(ok)
    t = np.asarray(track.translation, np.float64)[ok] * (float(track.pixel_aspect), 1.0)
    return np.median(t, axis=0), float(np.median(np.asarray(track.scale)[ok]))


def pose_about(pose, target):
    """The pose track ``pose`` of frames framed otherwise than the ``target``'s (another size
    or pixel shape), moved onto the target's head: its rotation, and its head's motion about
    its usual place (:func:`_placement`) scaled by the two heads' sizes, about the target's
    head's usual place.

    A weak-perspective camera (Eq. (7)) maps a model point ``X`` to the stored pixel
    ``x = s (R X)_x / a + t_x``, ``y = s (R X)_y + t_y`` (``a``: the pixels' aspect). With
    ``k = S_t / S_p`` (the heads' median scales) and ``T_p``, ``T_t`` their median places in
    shown pixels: ``s' = k s`` and ``t'`` (shown) ``= T_t + k (t a - T_p)``; the landmarks move
    alike. The rewrite draws the new face over the target's own head (§6), so the pose moves
    the face about where that head is, at its size: a close-up's pose drives a medium shot
    (copied as it is, a close-up's head would be drawn filling the medium shot).

    Returns
    -------
    Track
        ``pose`` with the target's ``frame_size`` and ``pixel_aspect``; ``detections2d``
        dropped (pixels of the other frame).
    """
    (tp, sp), (tt, st) = _placement(pose), _placement(target)
    k = st / sp
    a0, a1 = float(pose.pixel_aspect), float(target.pixel_aspect)

    def moved(p: np.ndarray) -> np.ndarray:
        return (tt + k * (np.asarray(p, np.float64) * (a0, 1.0) - tp)) / (a1, 1.0)

    return dataclasses.replace(
        pose, frame_size=tuple(target.frame_size), pixel_aspect=a1, scale=pose.scale * k,
        translation=moved(pose.translation), landmarks2d=moved(pose.landmarks2d),
        detections2d=None)


def recombine(target, *, expression=None, viseme=None, identity=None, pose=None,
              align: str | None = None, identity_mode: str = "identity",
              expression_mode: str = "expression", viseme_mode: str = "viseme"):
    """A new performance on the target's timeline, each attribute from its chosen source.

    Implements the attribute mixing of Vlasic et al. (2005) §6 / Fig. 1 and Fig. 7B–D: the new
    face of frame ``j`` is Eq. (5) with the identity, expression and viseme weights taken from
    the chosen tracks, seen by the pose (weak-perspective camera, Eq. (7)) of the pose track.

    Parameters
    ----------
    target : Track
        The footage rendered into: fixes the timeline (frame rate, frame count), frame size and
        by default pose and every attribute not given.
    expression, viseme : Track, optional, keyword-only
        Sources of the per-frame expression / viseme weights, resampled to the target's frame
        rate with ``align``.
    identity : Track or (r,) array, optional
        A track (its identity: the mean over frames not lost) or identity weights.
    pose : Track, optional
        Source of the per-frame rotation, scale and translation (default: the target); of
        another frame size or pixel shape, its head's motion moved onto the target's head
        (:func:`pose_about`).
    align : {"trim", "loop", "hold"} or None
        See :func:`time_map`. With ``trim`` the result is shortened to the shortest source.

    Returns
    -------
    Track
        Target's fps, frame size and source path; ``lost`` where the target or any source used
        for the frame is lost (those frames keep the original footage when rendered);
        ``landmarks2d`` copied from the pose track and ``blendshapes`` None (new weights:
        :func:`project_landmarks` with the model recomputes both, and the exports of
        :mod:`facetransfer.export` need the blendshapes); ``detections2d`` None.
    """
    sources = {}
    for what, tr in (("expression", expression), ("viseme", viseme), ("pose", pose)):
        if tr is not None:
            _check_compatible(target, tr, what)
            sources[what] = tr
    if viseme is not None and viseme_mode not in target.mode_names:
        raise TransferError(f"--viseme-from needs a model with a {viseme_mode!r} mode; this one "
                            f"has {', '.join(target.mode_names)}")
    if pose is not None and (tuple(pose.frame_size) != tuple(target.frame_size)
                             or pose.pixel_aspect != target.pixel_aspect):
        log.info("the pose source's %dx%d frames are framed otherwise than the target's "
                 "%dx%d: its head's motion moves the target's head", *pose.frame_size,
                 *target.frame_size)
        sources["pose"] = pose_about(pose, target)
    base, resampled = _on_timeline(target, sources, align)
    n_out = base.n_frames
    posed = resampled.get("pose", base)
    weights = {m: base.weights[m].copy() for m in base.mode_names}
    lost = base.lost.copy()
    for what, mode in (("expression", expression_mode), ("viseme", viseme_mode)):
        if what in resampled:
            if what == "expression" and mode not in weights:
                raise TransferError(f"the model has no {mode!r} mode")
            weights[mode] = resampled[what].weights[mode].copy()
    for tr in resampled.values():
        lost |= tr.lost
    if identity is not None:
        if identity_mode not in weights:
            raise TransferError(f"the model has no {identity_mode!r} mode")
        wid = _identity_weights(target, identity, identity_mode, weights[identity_mode].shape[1])
        weights[identity_mode] = np.broadcast_to(wid, (n_out, wid.shape[0])).copy()
    conf = base.confidence.copy()
    for tr in resampled.values():
        conf = np.minimum(conf, tr.confidence)
    return dataclasses.replace(
        base, rotation=posed.rotation.copy(), scale=posed.scale.copy(),
        translation=posed.translation.copy(), landmarks2d=posed.landmarks2d.copy(),
        weights=weights, lost=lost, confidence=conf, info={},
        blendshapes=None, blendshape_names=None,  # new weights: project_landmarks attaches them
        detections2d=None)  # a new performance: nobody detected it


def _on_timeline(target, sources: dict, align: str | None):
    """``(base, resampled)``: every source track resampled to the target's frame rate
    (:func:`time_map` with ``align``), all cut to the shortest, and the target cut alike."""
    n = target.n_frames
    resampled = {}
    n_out = n
    for what, tr in sources.items():
        tm = time_map(tr.n_frames, tr.fps, n, target.fps, align=align)
        resampled[what] = resample_track(tr, tm)
        n_out = min(n_out, tm.n_frames)
    for what in resampled:
        if resampled[what].n_frames > n_out:
            resampled[what] = take_frames(resampled[what], np.arange(n_out))
    base = take_frames(target, np.arange(n_out)) if n_out < n else target
    return base, resampled


def _identity_weights(target, identity, identity_mode: str, r: int) -> np.ndarray:
    """The identity (r,) of :func:`recombine`: a track's constant identity or given weights."""
    if hasattr(identity, "weights"):
        _check_compatible(target, identity, "identity")
        wid = constant_weights(identity, identity_mode)
    else:
        wid = np.asarray(identity, dtype=np.float64).ravel()
    if wid.shape != (r,) or not np.all(np.isfinite(wid)):
        raise TransferError(f"identity weights must be {r} finite numbers, got shape "
                            f"{wid.shape}")
    return wid


# ---------------------------------------------------------------------------------------------
# editing (Fig. 7E)
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EditAdd:
    """Add the training expression ``label`` over frames ``start..stop`` (inclusive)."""

    label: str
    start: int
    stop: int
    amount: float = 1.0


@dataclass(frozen=True)
class EditScale:
    """Scale the component of the expression weights along ``label`` − neutral by ``factor``."""

    label: str
    factor: float


_ADD_RE = re.compile(r"^\s*([A-Za-z0-9_.\-]+?)(?:\*([-+0-9.eE]+))?@(\d+)-(\d+)\s*$")
_SCALE_RE = re.compile(r"^\s*([A-Za-z0-9_.\-]+)=(\S+)\s*$")


def parse_add(text: str) -> EditAdd:
    """Parse ``LABEL@START-STOP`` or ``LABEL*AMOUNT@START-STOP`` (frames, inclusive, 0-based)."""
    m = _ADD_RE.match(str(text))
    if not m:
        raise TransferError(f"--add {text!r}: expected EXPRESSION@START-STOP, e.g. frown@120-180")
    label, amount, a, b = m.group(1), m.group(2), int(m.group(3)), int(m.group(4))
    if b < a:
        raise TransferError(f"--add {text!r}: the range ends ({b}) before it starts ({a})")
    try:
        amt = 1.0 if amount is None else float(amount)
    except ValueError:
        raise TransferError(f"--add {text!r}: amount {amount!r} is not a number") from None
    return EditAdd(label, a, b, amt)


def parse_scale(text: str) -> EditScale:
    """Parse ``LABEL=FACTOR``."""
    m = _SCALE_RE.match(str(text))
    if not m:
        raise TransferError(f"--scale {text!r}: expected EXPRESSION=FACTOR, e.g. smile=1.5")
    try:
        f = float(m.group(2))
    except ValueError:
        raise TransferError(f"--scale {text!r}: {m.group(2)!r} is not a number") from None
    if not np.isfinite(f):
        raise TransferError(f"--scale {text!r}: the factor must be finite")
    return EditScale(m.group(1), f)


def _expression_direction(model, label: str, mode: str, neutral: str) -> np.ndarray:
    """``training_weights(label) − training_weights(neutral)`` in ``mode`` (r,)."""
    k = model.mode_index(mode)
    labels = model.labels[k]
    if label not in labels:
        raise TransferError(f"unknown {mode} {label!r}; the model knows: {', '.join(labels)}")
    if neutral not in labels:
        raise TransferError(f"the model's {mode} mode has no {neutral!r} training item to "
                            f"measure {label!r} from")
    return model.training_weights(k, label) - model.training_weights(k, neutral)


def ramp_envelope(n_frames: int, start: int, stop: int, ramp: int, *, at=None) -> np.ndarray:
    """(n_frames,) weights (``at``: at those frames): 1 on ``start..stop``, ramps outside.

    The edit holds at full strength on every frame of its range, as ``--add EXPR@START-END``
    says; it eases in over the ``ramp`` frames before ``start`` and out over the ``ramp``
    frames after ``stop`` (a frame ``d`` frames outside the range weighs
    ``smoothstep(1 - d / (ramp + 1))``), cut where the clip ends; 0 beyond. With ``ramp=0``
    it is a box 1 on ``start..stop``. (Ramps inside the range would give its end frames
    nothing, and a range shorter than two ramps would never reach full strength.)
    """
    t = np.arange(n_frames, dtype=np.float64) if at is None else np.asarray(at, np.float64)
    d = np.maximum(np.maximum(start - t, t - stop), 0.0)     # frames outside the range
    x = np.clip(1.0 - d / (max(int(ramp), 0) + 1.0), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def edit_track(track, model, *, add: Sequence[EditAdd] = (), scale: Sequence[EditScale] = (),
               ramp: int = 8, mode: str = "expression", neutral: str = "neutral"):
    """Edit a tracked performance (Vlasic et al. 2005, §6, Fig. 7E: "we manually add a frown").

    Scaling is applied first, then additions:

    * ``EditScale(label, f)``: with ``d = w(label) − w(neutral)`` (training weights), each
      frame's ``w`` becomes ``w + (f − 1) ((w − w(neutral)) · d / d · d) d``: the component of
      the expression (relative to neutral) along ``d`` is multiplied by ``f``, the rest is kept.
    * ``EditAdd(label, a, b, amount)``: ``w += amount · e(t) · d`` with ``e`` the envelope of
      :func:`ramp_envelope` (1 on ``a..b``, smooth ramps of ``ramp`` frames outside it).

    For a model of ARKit expressions (:func:`facetransfer.arkit.is_arkit_model`) the same
    edits act on the activations the weights convert to exactly, clipped to [0, 1]
    (:func:`_edit_activations`): ``jawOpen=2`` doubles the jawOpen curve and leaves the others.
    A label the model lacks whose two sides it has names both (``mouthSmile``, or ``smile``:
    :data:`SIDE_WORDS`); an ARKit model's in any case (``JawOpen``, a take's column).

    Parameters
    ----------
    track : Track
    model : MultilinearModel
        The model the track was made with (its training weights define the expressions).
    add, scale : EditAdd / EditScale, their text, or sequences of them, keyword-only
        An edit, or its text as the CLI takes it (``"frown@120-180"``, ``"smile=1.5"``:
        :func:`parse_add`, :func:`parse_scale`).
    ramp : int
        Ramp length in frames at each end of an added range.
    mode, neutral : str
        The edited mode and its neutral training label.

    Returns
    -------
    Track

    Raises
    ------
    TransferError
        Unknown expression, a frame range outside the clip or ending before it starts, an
        amount or factor that is not finite, a track of another model.
    """
    add, scale = _edits(add, EditAdd, parse_add), _edits(scale, EditScale, parse_scale)
    if mode not in track.weights:
        raise TransferError(f"the track has no {mode!r} mode (modes: {', '.join(track.mode_names)})")
    if tuple(model.mode_names) != tuple(track.mode_names) or \
            model.ranks[model.mode_index(mode)] != track.weights[mode].shape[1]:
        raise TransferError("the track was made with another model (modes or ranks differ)")
    if int(ramp) < 0:
        raise TransferError(f"ramp must be >= 0 frames, got {ramp}")
    _check_edits(add, scale, track.n_frames)
    k = model.mode_index(mode)
    scale = [dataclasses.replace(s, label=x) for s in scale
             for x in _edited_labels(model.labels[k], s.label)]
    add = [dataclasses.replace(a, label=x) for a in add
           for x in _edited_labels(model.labels[k], a.label)]
    if mode == "expression" and is_arkit_model(model):
        w = _edit_activations(track.weights[mode], model, scale, add, int(ramp))
    else:
        w = _edit_weights(track.weights[mode], model, k, scale, add, int(ramp), mode, neutral)
    weights = dict(track.weights)
    weights[mode] = w
    return attach_activations(dataclasses.replace(track, weights=weights, info={}), model)


def _edits(edits, kind: type, parse) -> list:
    """:func:`edit_track`'s ``add`` or ``scale`` as a list of ``kind``: one edit or a sequence,
    each an edit or its text (``parse``); anything else a TransferError naming it."""
    items = [edits] if isinstance(edits, (str, kind)) else list(edits)
    out = [parse(e) if isinstance(e, str) else e for e in items]
    for e in out:
        if not isinstance(e, kind):
            raise TransferError(f"an edit must be an {kind.__name__} or its text, got "
                                f"{type(e).__name__} {e!r}")
    return out


def _check_edits(add: list, scale: list, n: int) -> None:
    """The edits' frame ranges lie in the clip of ``n`` frames and run forwards, and their
    amounts and factors are finite (a NaN reached the track as non-finite weights; a range
    ending before its start weighed every frame less than 1 and edited nothing fully)."""
    for a in add:
        where = f"--add {a.label}@{a.start}-{a.stop}"
        if a.start < 0 or a.stop > n - 1:
            raise TransferError(f"{where}: frames outside the clip (0-{n - 1})")
        if a.stop < a.start:
            raise TransferError(f"{where}: the range ends ({a.stop}) before it starts "
                                f"({a.start})")
        if not np.isfinite(a.amount):
            raise TransferError(f"{where}: the amount must be finite, got {a.amount}")
    for sc in scale:
        if not np.isfinite(sc.factor):
            raise TransferError(f"--scale {sc.label}={sc.factor}: the factor must be finite")


#: Words for an ARKit shape on both sides of the face: ``--scale smile=1.5`` is both
#: ``mouthSmileLeft`` and ``mouthSmileRight``.
SIDE_WORDS = {"smile": "mouthSmile", "frown": "mouthFrown", "blink": "eyeBlink",
              "squint": "eyeSquint", "sneer": "noseSneer", "dimple": "mouthDimple"}


def _edited_labels(labels, label: str) -> list[str]:
    """The training labels an edit's ``label`` names: itself where the model has it, else
    both sides of it (``mouthSmile``, or a word of :data:`SIDE_WORDS`: ``smile``) where the
    model has ``...Left`` and ``...Right``; else itself (unknown: refused by the edit)."""
    if label in labels:
        return [label]
    stem = SIDE_WORDS.get(label, label)
    sides = [f"{stem}Left", f"{stem}Right"]
    return sides if all(s in labels for s in sides) else [label]


def _edit_activations(w: np.ndarray, model, scale, add, ramp: int) -> np.ndarray:
    """:func:`edit_track` of an ARKit model's expression weights ``(F, r)``: their activations
    (Eq. (A)) edited, :func:`edit_activations`. (A projection on the weights would also count
    the other shapes' part along the shape's direction: ``jawOpen=2`` made jawOpen 6 times.)"""
    from .arkit import activations_to_weights, arkit_rows, weights_to_activations

    act = edit_activations(weights_to_activations(model, w, clip=False), scale=scale, add=add,
                           ramp=ramp, has=arkit_rows(model) >= 0)
    return activations_to_weights(model, np.clip(act, 0.0, 1.0))   # every curve in ARKit's


def edit_activations(activations: np.ndarray, *, scale=(), add=(), ramp: int = 8, has=None,
                     owner: str = "the model", frames=None) -> np.ndarray:
    """ARKit activation curves ``(F, 52)`` (:data:`facetransfer.arkit.ARKIT_NAMES` order)
    edited as :func:`edit_track` edits an ARKit model's (and ``edit take.csv`` a take's): each
    ``EditScale`` (or its text) multiplies its shape's curve by its factor (>= 0), then each
    ``EditAdd`` adds ``amount`` times the :func:`ramp_envelope` of its range; each edited curve
    clipped to [0, 1], the others as given. A label: one of the 52 shapes or both sides of one
    (:data:`SIDE_WORDS`), in any case (:func:`_spelled`). ``has``: (52,) bool, the shapes
    ``owner`` holds (default: all); an edit of another, an unknown name (:func:`_arkit_index`),
    a range outside the frames, a factor or amount not finite are refused. ``frames``: (F,)
    the rows' frame positions, which ranges count (default 0..F-1; a take's on its timeline).

    Returns
    -------
    (F, 52) float64
    """
    from .arkit import ARKIT_NAMES

    act = np.array(activations, dtype=np.float64)
    add, scale = _edits(add, EditAdd, parse_add), _edits(scale, EditScale, parse_scale)
    at = np.arange(len(act), dtype=np.float64) if frames is None else np.asarray(frames, float)
    _check_edits(add, scale, int(np.floor(at[-1] + 1e-6)) + 1 if len(at) else 0)
    has = np.ones(len(ARKIT_NAMES), bool) if has is None else np.asarray(has, bool)
    touched = np.zeros(len(ARKIT_NAMES), bool)
    for s in (dataclasses.replace(s, label=x) for s in scale
              for x in _edited_labels(ARKIT_NAMES, _spelled(s.label))):
        if s.factor < 0:  # clipped to [0, 1], the shape would be gone: not what was asked
            raise TransferError(f"--scale {s.label}={s.factor:g}: an ARKit activation lies in "
                                "0..1, so a negative factor would only remove the shape; give "
                                f"{s.label}=0 to remove it")
        j = _arkit_index(s.label, has, owner)
        act[:, j], touched[j] = act[:, j] * s.factor, True
    for a in (dataclasses.replace(a, label=x) for a in add
              for x in _edited_labels(ARKIT_NAMES, _spelled(a.label))):
        j = _arkit_index(a.label, has, owner)
        act[:, j], touched[j] = act[:, j] + a.amount * ramp_envelope(
            len(act), a.start, a.stop, ramp, at=at), True
    act[:, touched] = np.clip(act[:, touched], 0.0, 1.0)
    return act


def _spelled(label: str) -> str:
    """``label`` as ARKit spells the shape (or the two sides' stem, or word) it names in any
    case: ``JawOpen`` (a take's column, a Live Link curve) is ``jawOpen``; else as given."""
    from .arkit import ARKIT_NAMES

    names = {n.lower(): n for n in ARKIT_NAMES} | {w: w for w in SIDE_WORDS}
    names |= {k[:-4]: n[:-4] for k, n in names.items() if k.endswith("left")}
    return names.get(label.lower(), label)


def _arkit_index(label: str, has: np.ndarray, owner: str = "the model") -> int:
    """The ARKit index of ``label``, a shape ``owner`` has (``has`` (52,) bool); else a
    :class:`TransferError` naming the closest name (and, but for a take's 52, the shapes it
    has): an edit of a shape it lacks changes nothing."""
    import difflib

    from .arkit import ARKIT_NAMES

    known = [n for n, h in zip(ARKIT_NAMES, has) if h]
    if label in ARKIT_NAMES and label not in known:
        why = " (its data set has none)" if owner == "the model" else \
            f" (no column {label[0].upper()}{label[1:]})"
        raise TransferError(f"{owner} has no {label} shape{why}: an edit of it would change "
                            "nothing")
    if label not in known:
        lower = {n.lower(): n for n in known + list(SIDE_WORDS)}
        close = difflib.get_close_matches(label.lower(), list(lower), n=1)   # else no guess
        hint = f" (did you mean {lower[close[0]]}?)" if close else ""
        names = "the 52 ARKit names" if len(known) == 52 else ", ".join(known)
        raise TransferError(f"unknown expression {label!r}{hint}; {owner} knows: {names}, and "
                            f"{', '.join(SIDE_WORDS)} (both sides)")
    return ARKIT_NAMES.index(label)


def _edit_weights(w: np.ndarray, model, k: int, scale, add, ramp: int, mode: str,
                  neutral: str) -> np.ndarray:
    """:func:`edit_track` on the weights ``(F, r)`` of mode ``k`` (the module's equations)."""
    w = np.array(w, dtype=np.float64)
    n = len(w)
    w0 = model.training_weights(k, neutral) if neutral in model.labels[k] else None
    for s in scale:
        d = _expression_direction(model, s.label, mode, neutral)
        dd = float(d @ d)
        if dd == 0:
            raise TransferError(f"{s.label!r} has the same weights as {neutral!r}; nothing to scale")
        c = (w - w0) @ d / dd  # (F,) component along d
        w = w + (s.factor - 1.0) * c[:, None] * d[None, :]
    for a in add:
        d = _expression_direction(model, a.label, mode, neutral)
        e = ramp_envelope(n, a.start, a.stop, ramp)
        w = w + a.amount * e[:, None] * d[None, :]
    return w


# ---------------------------------------------------------------------------------------------
# puppetry
# ---------------------------------------------------------------------------------------------

def puppet_frames(track, model, identity: np.ndarray, *, size: tuple[int, int] | None = None,
                  background=(40, 40, 48), identity_mode: str = "identity",
                  color=(205, 170, 150), start: int = 0) -> Iterator[np.ndarray]:
    """Drive a synthetic actor (an identity of the model) with a tracked performance.

    Each frame renders Eq. (5) with ``identity`` and the track's other weights, seen by the
    track's camera, Lambert-shaded on a plain background, with the mouth gap and eye holes
    closed: the eye holes show eyeballs turned by the frame's eyeLook* activations (straight
    ahead for a track without ARKit activations), an open mouth a dark cavity with the upper
    teeth, a shut eye or mouth a line (:mod:`facetransfer.puppet_face`), all occluded by the
    lids and lips. A frame where the face was lost shows its nearest tracked frame (the
    earlier on ties; :func:`facetransfer.track.project.held_lost`), as ``facetransfer export``
    writes it and the capture tracker stores it: not a KLT track's drifting state there.
    ``start``: yield frames ``start`` to the end only (those of a whole run: a render
    continued after an interrupt).

    Parameters
    ----------
    track : Track
    model : MultilinearModel
    identity : (r,) float64
    size : (W, H), optional
        Default: the track's frame size.
    background : (3,) colour

    Yields
    ------
    (H, W, 3) uint8
    """
    from .puppet_face import arkit_activations, paint_face, puppet_face
    from .render import render
    from .track.project import nearest_tracked

    size = tuple(track.frame_size) if size is None else (int(size[0]), int(size[1]))
    r = model.ranks[model.mode_index(identity_mode)]
    wid = np.asarray(identity, dtype=np.float64).ravel()
    if wid.shape != (r,):
        raise TransferError(f"identity weights must have {r} values, got {wid.shape}")
    bg = np.broadcast_to(np.asarray(background, np.uint8), (size[1], size[0], 3)).copy()
    sx = size[0] / track.frame_size[0]
    sy = size[1] / track.frame_size[1]
    # a solid head: the mouth gap and the eye holes closed, their fills painted as a mouth
    # cavity and eyeballs (facetransfer.puppet_face)
    topo = mesh_topology(model, lips=False)
    face = puppet_face(model, topo, arkit_activations(track))
    n_all = topo.n_closed + len(topo.eye_loops)
    colors = np.broadcast_to(np.asarray(color, np.float64), (n_all, 3))

    def draw(i: int) -> np.ndarray:
        w = track.weights_at(i)
        w[identity_mode] = wid
        # the identity contracted once (model.py); the eye loops' centres appended
        V = face.vertices(close_mouth(model.synthesize(w), topo))
        cam = track.camera(i)
        if (sx, sy) != (1.0, 1.0):
            cam = type(cam)(cam.scale * np.sqrt(sx * sy), cam.rotation,
                            cam.translation * np.array([sx, sy]), cam.pixel_aspect)
        out = render(V, face.faces, cam, size, colors=colors, background=bg)
        paint_face(out.image, out.raster, V, cam, face, i)
        return out.image

    # a lost frame shows its nearest tracked one (held_lost's rule, as the exports write it,
    # whichever tracker), each drawn once for a run of lost frames around it
    near, shown = nearest_tracked(track.lost), (-1, bg)
    for i in range(max(0, int(start)), track.n_frames):
        if int(near[i]) != shown[0]:
            shown = (int(near[i]), draw(int(near[i])))
        yield shown[1]


def identity_from_label(model, label: str, mode: str = "identity") -> np.ndarray:
    """Training weights of an identity given by label (TransferError listing known labels)."""
    k = model.mode_index(mode)
    if label not in model.labels[k]:
        raise TransferError(f"unknown identity {label!r}; the model knows: "
                            f"{', '.join(model.labels[k][:20])}"
                            + (" ..." if len(model.labels[k]) > 20 else ""))
    return model.training_weights(k, label)


def parse_weights(text: str, r: int, *, what: str = "--identity-weights") -> np.ndarray:
    """``"0.1,0.2,..."`` (r numbers) or a ``.npy`` / ``.txt`` file of r numbers -> (r,)."""
    from pathlib import Path

    p = Path(text)
    if p.suffix.lower() in (".npy", ".txt", ".csv") and not p.is_file():
        raise TransferError(f"{what} {text}: " + ("a folder, not a file" if p.is_dir() else
                                                  "no such file"))
    try:
        if p.suffix in (".npy", ".txt", ".csv") and p.is_file():
            vals = np.load(p, allow_pickle=False) if p.suffix == ".npy" \
                else np.loadtxt(p, delimiter=",")
        else:
            vals = np.array([float(v) for v in str(text).replace(" ", ",").split(",") if v])
    except (ValueError, OSError, EOFError) as exc:
        why = "not a NumPy array file (np.save writes one)" if p.suffix == ".npy" else exc
        raise TransferError(f"{what} {text!r}: not a list of numbers or a .npy file ({why})") \
            from None
    if isinstance(vals, np.lib.npyio.NpzFile):   # before: its key names read as numbers
        vals.close()
        raise TransferError(f"{what} {text}: an .npz archive, not a single .npy array")
    if np.asarray(vals).dtype.kind not in "biuf":   # text; complex (its imaginary part lost)
        raise TransferError(f"{what} {text}: holds {np.asarray(vals).dtype} values, not real "
                            "numbers")
    vals = np.asarray(vals, dtype=np.float64).ravel()
    if vals.shape != (r,):
        raise TransferError(f"{what}: expected {r} finite numbers, got {vals.size}")
    if not np.all(np.isfinite(vals)):   # before: "expected 3 finite numbers, got 3"
        raise TransferError(f"{what}: expected {r} finite numbers, got NaN or infinity")
    return vals


#: How far (standard deviations of the training identities' weights, per component) given
#: identity weights may lie: the training identities lie within 3.4 of their mean in the
#: default model, a tracked identity within 1; the zero vector lies 53 away (a face blown up
#: past the frame, measured).
IDENTITY_LIMIT = 6.0


#: :func:`check_identity_weights`' word on where identity weights come from.
IDENTITY_SOURCES = ("identity weights are coordinates in the model's identity space, e.g. a "
                    "training row (--identity-label; `facetransfer model info` lists them) or "
                    "a track's identity")


def check_identity_weights(model, w: np.ndarray, *, what: str = "--identity-weights",
                           hint: str = IDENTITY_SOURCES) -> None:
    """Refuse identity weights ``w`` (r,) outside the space the model's identities span: a
    component farther than :data:`IDENTITY_LIMIT` standard deviations from the training
    identities' mean (TransferError naming ``what``, the component and, ``hint``, where such
    weights come from)."""
    k = model.mode_index(model.identity_mode)
    U = np.asarray(model.factors[k], np.float64)
    if len(U) < 2:
        return
    z = np.abs(np.asarray(w, np.float64) - U.mean(0)) / np.maximum(U.std(0), 1e-12)
    j = int(np.argmax(z))
    if z[j] > IDENTITY_LIMIT:
        raise TransferError(f"{what}: component {j} ({w[j]:.4g}) lies {z[j]:.0f} standard "
                            f"deviations from the training identities' (at most "
                            f"{IDENTITY_LIMIT:g}): {hint}")


def nearest_frames(query: np.ndarray, bank: np.ndarray, valid: np.ndarray | None = None
                   ) -> np.ndarray:
    """For each query row the index of the nearest bank row (Euclidean), among ``valid`` ones.

    The performance-driven texture of §6 ("the weighted sum of nearest neighbors") with one
    neighbour: the frame of the texture video whose attributes are closest.

    Parameters
    ----------
    query : (n, r)
    bank : (m, r)
    valid : (m,) bool, optional

    Returns
    -------
    (n,) int64
    """
    Q = np.asarray(query, np.float64)
    B = np.asarray(bank, np.float64)
    if Q.ndim != 2 or B.ndim != 2 or Q.shape[1] != B.shape[1]:
        raise ShapeError(f"query and bank must be (n, r) and (m, r), got {Q.shape} and "
                         f"{B.shape}")
    ok = np.ones(B.shape[0], bool) if valid is None else np.asarray(valid, bool)
    if ok.shape != B.shape[:1]:
        raise ShapeError(f"valid must be ({B.shape[0]},) for a bank of {B.shape}, got "
                         f"{ok.shape}")
    if not ok.any():
        raise RewriteError("no frame to take a texture from (all lost)")
    idx = np.flatnonzero(ok)
    d = ((Q[:, None, :] - B[None, idx, :]) ** 2).sum(axis=-1)
    return idx[np.argmin(d, axis=1)]

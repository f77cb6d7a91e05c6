"""Tracks recombined into a new performance (Vlasic et al. 2005, §6, Fig. 1, Fig. 7B–D): time maps
and recombination, pure functions on tracks.

A tracked video is a :class:`~facetransfer.track.Track`: per frame a weak-perspective pose
(Eq. (7)) and one weight vector per model mode (Eq. (5)). Because the multilinear model separates
the attributes, a new performance is made by picking each attribute's weights from a different
track and synthesising the face from Eq. (5) (§6: "the pose from the original video with the
expression from the new video"):

* :func:`time_map` / :func:`resample_track`: put a source track on the target's timeline (another
  frame rate or length; ``align`` = ``trim`` | ``loop`` | ``hold``);
* :func:`recombine`: identity, expression, viseme and pose from up to three tracks (Fig. 1,
  Fig. 7B–7D);
* editing a track (Fig. 7E: add a training expression over a frame range, scale an
  expression's component) is :mod:`facetransfer.performance_edit`.

Rendering the new performance back into footage is :mod:`facetransfer.rewrite` (one frame) and
:mod:`facetransfer.video_transfer` (the job); rendering it alone, the puppet, is
:func:`facetransfer.puppet_video.puppet_frames`; the §6 texture's nearest frames (a transfer's
mouth frames) are :func:`facetransfer.texture.function.nearest_frames`. Every function here is
pure, tracks in and a new track out.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005,
§5 (Eq. (5), (7)), §6 and Figures 1 and 7.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from .errors import FaceTransferError
from .track.project import take_frames

log = logging.getLogger(__name__)

__all__ = [
    "ALIGN_MODES",
    "TransferError",
    "TimeMap",
    "time_map",
    "resample_track",
    "source_frames_read",
    "constant_weights",
    "recombine",
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
        occluded=(None if track.occluded is None else       # covered where either side is
                  track.occluded[i0] | ((frac > 1e-9)[:, None] & track.occluded[i1])),
        info={},
    )


def source_frames_read(track, tmap: TimeMap) -> tuple[np.ndarray, np.ndarray]:
    """The frames of ``track`` (a source) each output frame of ``tmap`` reads, as
    :func:`resample_track` reads them: ``(i0, i1)``, each ``(tmap.n_frames,) int64``, the
    frame at or before its source time and the next where the time lies between the two (not
    across a cut), else ``i0`` again. An output frame is lost where ``track.lost[i0] |
    track.lost[i1]``."""
    t = np.asarray(tmap.source_time, np.float64)
    n = track.n_frames
    i0 = np.clip(np.floor(t).astype(np.int64), 0, n - 1)
    i1 = np.minimum(i0 + 1, n - 1)
    between = (t - i0 > 1e-9) & ~np.isin(i1, track.shot_starts)
    return i0, np.where(between, i1, i0)


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
        :func:`facetransfer.track.project.project_landmarks` with the model recomputes both,
        and the exports of :mod:`facetransfer.export` need the blendshapes); ``detections2d``
        None.
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

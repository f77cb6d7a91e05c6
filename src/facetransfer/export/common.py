"""What every export format shares: the model check, the activations, the head pose.

Beyond the paper: a track (``TRACK.npz``) holds the weak-perspective pose of Eq. (7) and, for a
model whose expressions are ARKit blendshapes (:mod:`facetransfer.arkit`), the 52 activations
per frame. Exporters read only those; this module turns the pose into the quantities animation
tools key (head Euler angles in radians, a quaternion, a translation in model units).

Conventions (camera coordinates of :class:`facetransfer.render.WeakPerspective`: x right,
y up, z towards the viewer):

* ``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)`` (intrinsic Y-X'-Z''), angles in **radians**;
  positive yaw turns the face towards the image's right (the subject's left), positive pitch
  tips the top of the head towards the camera (looking down), positive roll turns the face
  counter-clockwise in the image. These are the "head angles" of
  :mod:`facetransfer.render.cameras` (ARKit's order); the previews' and the synthetic
  footage's "render angles" have the same axes and signs in another order, in degrees. A Live
  Link Face take writes the yaw and the roll with the app's other sign
  (:data:`facetransfer.export.livelink.HEAD_SIGNS`).
* Head translation in model units: ``((t_x - (W-1)/2) / s, -(t_y - (H-1)/2) / s, 0)``, the model
  origin's offset from the image centre at the face's depth (weak perspective has no depth);
  the centre as the renderer has it, pixel ``k`` centred at ``k`` (before the fifty-fourth
  session ``W/2``: half a pixel off, 0.29 mm on driving_d6 at 17 px a cm).
"""

from __future__ import annotations

import logging

import numpy as np

from ..arkit import ARKIT_NAMES
from ..errors import FaceTransferError

log = logging.getLogger(__name__)

__all__ = ["ExportError", "require_activations", "resolve_model", "activations_from_weights",
           "clip_facts", "with_clip_facts", "head_euler", "head_quaternions",
           "head_translation", "source_name"]


class ExportError(FaceTransferError):
    """A track cannot be exported (no activations, wrong model, unknown format)."""


_NO_ACTIVATIONS = ("has no ARKit blendshape activations; track the video with the default "
                   "model (ict-arkit: `facetransfer track` without --model) or with a model built "
                   "from the ict-arkit data set with its expression rank untruncated (the 52 "
                   "ARKit blendshapes)")


def require_activations(track, *, what: str = "track") -> np.ndarray:
    """The track's activations in :data:`ARKIT_NAMES` order, ``(F, 52) float32``.

    Raises
    ------
    ExportError
        If the track has none, naming the model that gives them.
    """
    if track.blendshapes is None:
        src = f" {track.label}" if track.label else ""
        raise ExportError(f"{what}{src} {_NO_ACTIVATIONS}")
    names = tuple(track.blendshape_names)
    if names == ARKIT_NAMES:
        return np.asarray(track.blendshapes, dtype=np.float32)
    unknown = sorted(set(names) - set(ARKIT_NAMES))
    if unknown:
        raise ExportError(f"{what} has blendshapes {unknown[:5]} that are not ARKit names")
    out = np.zeros((track.n_frames, len(ARKIT_NAMES)), np.float32)
    for j, n in enumerate(names):
        out[:, ARKIT_NAMES.index(n)] = track.blendshapes[:, j]
    return out


def resolve_model(track, model=None, *, progress=None, announce=None):
    """The model of ``track``: ``model`` if given (checked), else the default model if the
    track was made with it (``progress`` and ``announce`` go to
    :func:`facetransfer.default_model.load_default_model`, which builds it on first use).

    Raises
    ------
    ExportError, TrackError
        No model given and the track is not of the default model; or a model that does not
        match the track (modes, ranks or content hash).
    """
    if model is None:
        from ..default_model import kept_model_hint, load_default_model

        model = load_default_model(progress=progress, announce=announce)
        if track.model_hash and track.model_hash != model.content_hash:
            name = f"track {track.label}" if track.label else "the track"
            raise ExportError(f"{name} was not made with the default model (ict-arkit) here "
                              f"(model hash {track.model_hash[:12]}, this one's "
                              f"{model.content_hash[:12]})" + (
                                  kept_model_hint(track.model_hash) or "; pass the model it "
                                  "was tracked with (--model M.npz)"))
    track.check_model(model)
    return model


def head_euler(rotation: np.ndarray) -> np.ndarray:
    """Yaw, pitch, roll in radians per frame: the head angles (see the module's conventions).

    Parameters
    ----------
    rotation : (F, 3, 3) float
        Model-to-camera rotations.

    Returns
    -------
    (F, 3) float64
        ``[yaw, pitch, roll]`` in radians with ``R = Ry(yaw) Rx(pitch) Rz(roll)``: yaw about y,
        positive toward the image's right; pitch about x, positive looking down; roll about
        z, positive counter-clockwise in the image.
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(rotation, np.float64)).as_euler("YXZ")


def head_quaternions(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(F, 4)`` in ``(x, y, z, w)`` order (glTF's), ``w >= 0``."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(rotation, np.float64)).as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def head_translation(track) -> np.ndarray:
    """Per-frame translation of the model origin in model units, ``(F, 3) float64``, from the
    frame's centre ``((W - 1) / 2, (H - 1) / 2)``, where the renderer and
    :func:`facetransfer.render.look_at_weak_perspective` put it (as the video is shown: a track
    of non-square pixels, :mod:`facetransfer.track.aspect`, in square ones)."""
    from ..track.aspect import to_shown_x

    W, H = track.frame_size
    a = float(track.pixel_aspect)
    s = np.asarray(track.scale, np.float64)
    t = np.asarray(track.translation, np.float64)
    out = np.zeros((track.n_frames, 3))
    tx = t[:, 0] if a == 1.0 else to_shown_x(t[:, 0], a)
    out[:, 0] = (tx - (W * a - 1.0) / 2.0) / s
    out[:, 1] = -(t[:, 1] - (H - 1.0) / 2.0) / s
    return out


def identity_rig(track, model):
    """The clip's person as an ARKit blendshape rig (identity of frame 0; it is constant)."""
    from ..arkit import expression_rig, is_arkit_model

    if not is_arkit_model(model):
        raise ExportError("the model's expressions are not ARKit blendshapes; morph targets need "
                          "a model built from the ict-arkit data set (the default model)")
    return expression_rig(model, track.weights_at(0))


def source_name(source: str | None) -> str:
    """The file name of the video a track was made from, as an exported file records it: not
    its folder (a file handed on would carry the home folder's layout)."""
    from pathlib import PurePath

    return PurePath(source).name if source else ""


def activations_from_weights(track, model):
    """``track`` with ARKit activations made from its expression weights (the least-squares
    inverse of Eq. (A), :func:`facetransfer.arkit.attach_activations`): a track without them
    (e.g. one recombined in Python, Fig. 1) exported all the same.

    Parameters
    ----------
    track : facetransfer.track.Track
    model : MultilinearModel
        The model the track was made with.

    Raises
    ------
    ExportError, TrackError
        Where it is impossible: the track has no expression mode; its weights are not the
        model's (the shapes named, :meth:`~facetransfer.track.Track.check_model`); the model's
        expressions are not the 52 ARKit blendshapes (:func:`facetransfer.arkit.
        arkit_shortfall`).
    """
    from ..arkit import arkit_shortfall, attach_activations

    name = f"track {track.label}" if track.label else "the track"
    if "expression" not in track.weights:
        raise ExportError(f"{name} has no ARKit blendshape activations and no expression weights "
                          f"to make them from (its modes: {', '.join(track.mode_names)})")
    track.check_model(model)
    short = arkit_shortfall(model)
    if short:
        raise ExportError(f"{name} has no ARKit blendshape activations and its model cannot "
                          f"give them: {short}")
    return attach_activations(track, model)


def clip_facts(track):
    """The first frame number and start timecode of the clip ``track`` was made from (a
    :class:`~facetransfer.io.source_facts.SourceFacts`) and a note of where they come from:
    :func:`facetransfer.io.source_facts.track_source_facts`, the one rule the messages'
    frame numbers follow too (:func:`facetransfer.io.frame_numbers.track_first_number`).

    Returns
    -------
    (SourceFacts, str)
    """
    from ..io.source_facts import track_source_facts

    return track_source_facts(track)


def with_clip_facts(track):
    """``(track, note)``: ``track`` with :func:`clip_facts` recorded in it (unchanged where it
    records them), so that every part of an export takes the same ones, read once."""
    import dataclasses

    facts, note = clip_facts(track)
    if track.source_facts is facts:
        return track, note
    return dataclasses.replace(track, source_facts=facts), note

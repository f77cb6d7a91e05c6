"""A face dialled in the browser: the dial editor's saved face, read and made the model's weights.

``facetransfer view`` writes a page whose "Save face" button downloads what its sliders show
as a small JSON file (:data:`FORMAT`)::

    {"format": "facetransfer-face", "version": 1, "model": "<content hash>",
     "source": "take.npz", "frame": 40,
     "identity": [...],                      # the shown frame's person, or the mean
     "identity_dials": {"width": 1.5},       # units of facetransfer.dials (at most 5 either
                                             # way, DIAL_LIMIT), added to it
     "shape_kind": "arkit",                  # or a mode name: the training expressions
     "shapes": {"jawOpen": 0.5},             # slider values in [0, 1] (another mode's rows
                                             # named MODE:LABEL, e.g. "viseme:eel")
     "head": {"yaw": 20.0, "pitch": -5.0, "roll": 0.0}}   # degrees

``frame`` is the shown frame's number (a plate's as its files, ``1004`` of a plate numbered
from 1001; a video's or a take's row from 0; :mod:`facetransfer.io.frame_numbers`), None on a
model's page.

``render --face`` and ``model synth --face`` make that face with the model itself: the identity
moved by the dials on the whole face (the page shows their offsets of the neutral only, without
the model's identity-expression cross term), the expression from the ARKit activations
(:func:`facetransfer.arkit.activations_to_weights`, exact for an untruncated expression mode)
or from the training expressions' weights (the mesh is linear in a mode's weights, so a slider
at ``v`` adds ``v`` times that expression's offset, as the page does). The head angles are the
page's (three.js's Euler order ``YXZ``): ``R = Ry(yaw) Rx(pitch) Rz(roll)`` in camera axes (x
right, y up, z toward the viewer), the rotation of the track's frame it shows. A file edited by
hand is held to the same ranges: a shape outside [0, 1], a dial beyond its limit, an identity
beyond the model's (as ``transfer --identity-weights``) or a head angle by another name is
refused, naming the file and the value.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .dials import DIAL_LIMIT
from .errors import FaceTransferError

__all__ = ["FORMAT", "FaceFileError", "DialledFace", "read_face", "face_weights",
           "face_rotation"]

#: The ``format`` of the file (and its ``version``).
FORMAT, VERSION = "facetransfer-face", 1


class FaceFileError(FaceTransferError):
    """A face file that cannot be read, or not for this model."""


@dataclass(frozen=True)
class DialledFace:
    """A face of the dial editor (the module notes): its values as the page saved them."""

    path: Path
    model_hash: str
    identity: np.ndarray          # (r,) float64
    identity_dials: dict          # dial name -> units
    shape_kind: str               # "arkit" or the expression mode's name
    shapes: dict                  # shape name -> slider value
    head: tuple                   # (yaw, pitch, roll) degrees
    frame: int | None = None
    source: str = ""


def _finite(x) -> bool:
    """Whether a JSON value is a finite number (not a bool; an integer too large for a float,
    as JSON allows, is not one)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _numbers(path: Path, d: dict, key: str) -> dict:
    v = d.get(key, {})
    if not isinstance(v, dict) or not all(isinstance(k, str) and _finite(x)
                                          for k, x in v.items()):
        raise FaceFileError(f"{path}: {key!r} must map names to numbers")
    return {k: float(x) for k, x in v.items()}


def _within(path: Path, values: dict, what: str, lo: float, hi: float, why: str) -> dict:
    """``values`` unchanged, or FaceFileError naming the first value outside ``[lo, hi]``."""
    for name, x in values.items():
        if not lo <= x <= hi:
            raise FaceFileError(f"{path}: {what} {name}={x:g} is outside {lo:g} to {hi:g} "
                                f"({why})")
    return values


def _what_else(p: Path, exc: Exception) -> str:
    """What a file that is no JSON is, for the message: a track, a model, a take, ..."""
    from .file_facts import file_kind
    from .io.npz import NOT_NPZ, content_kind

    kind = content_kind(p)
    if kind is None:            # a zip archive: an .npz, perhaps the model or track itself
        try:
            kind = {"track": "a track file", "model": "a model file"}.get(file_kind(p),
                                                                          "a zip archive")
        except FaceTransferError:
            kind = "a zip archive"
    return f"not JSON: {exc}" if kind == NOT_NPZ else f"it is {kind}"


def read_face(path: str | os.PathLike) -> DialledFace:
    """Read a face file (the module notes); FaceFileError naming the file if it is not one."""
    p = Path(path)
    if not p.is_file():
        raise FaceFileError(f"face file {p} does not exist" if not p.exists()
                            else f"face file {p} is not a file")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FaceFileError(f"{p} is not a face file ({_what_else(p, exc)}; the dial editor's "
                            "Save face writes one)") from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise FaceFileError(f"{p} is not a face file (expected \"format\": \"{FORMAT}\", as "
                            "the dial editor's Save face writes)")
    if d.get("version") != VERSION:
        raise FaceFileError(f"{p}: face file version {d.get('version')!r}, this facetransfer "
                            f"reads version {VERSION}")
    ident = np.asarray(d.get("identity", []), dtype=object)
    head = _numbers(p, d, "head")
    if ident.ndim != 1 or not ident.size or not all(_finite(x) for x in ident):
        raise FaceFileError(f"{p}: 'identity' must be a list of numbers")
    unknown = sorted(set(head) - {"yaw", "pitch", "roll"})
    if unknown:
        raise FaceFileError(f"{p}: 'head' has {', '.join(map(repr, unknown))}; expected "
                            "'yaw', 'pitch' and 'roll' (degrees)")
    dials = _within(p, _numbers(p, d, "identity_dials"), "identity dial", -DIAL_LIMIT,
                    DIAL_LIMIT, "the dials' range, standard deviations over the training faces")
    shapes = _within(p, _numbers(p, d, "shapes"), "shape", 0.0, 1.0, "the page's sliders")
    frame = d.get("frame")
    return DialledFace(p, str(d.get("model", "")), ident.astype(np.float64), dials,
                       str(d.get("shape_kind", "arkit")), shapes,
                       tuple(head.get(k, 0.0) for k in ("yaw", "pitch", "roll")),
                       int(frame) if isinstance(frame, int) else None, str(d.get("source", "")))


def _identity(face: DialledFace, model) -> tuple[str, np.ndarray]:
    """The identity mode's name and the face's identity, moved by its dials (Eq. (D2))."""
    from .dials import DialError, learn_dials

    dials = None
    if face.identity_dials:
        try:
            dials = learn_dials(model)
        except DialError as exc:
            raise FaceFileError(f"{face.path}: the model has no identity dials ({exc})") from None
    mode = dials.mode if dials is not None else model.identity_mode
    r = model.ranks[model.mode_index(mode)]
    if face.identity.size != r:
        raise FaceFileError(f"{face.path}: its identity has {face.identity.size} weights, the "
                            f"model's {mode} mode {r}")
    if mode == model.identity_mode:   # as --identity-weights: a hand-edited file's zeros
        _plausible(face, model)         # drew a face blown past its frame
    if dials is None:
        return mode, face.identity
    try:
        return mode, dials.apply(face.identity, face.identity_dials)
    except DialError as exc:
        raise FaceFileError(f"{face.path}: {exc}") from None


def _plausible(face: DialledFace, model) -> None:
    """FaceFileError naming the file where its identity lies beyond the model's identities,
    as :func:`facetransfer.transfer.check_identity_weights` refuses ``--identity-weights``."""
    from .transfer import TransferError, check_identity_weights

    try:
        check_identity_weights(model, face.identity, what=f"{face.path}: its identity",
                               hint="the dial editor saves the shown frame's person or the "
                               "mean; move it with 'identity_dials'")
    except TransferError as exc:
        raise FaceFileError(str(exc)) from None


def _expression(face: DialledFace, model, rest: dict) -> dict[str, np.ndarray]:
    """The weights of the modes the face's shape sliders move (``rest``: every mode's at rest;
    the identity's is not moved)."""
    from .arkit import ARKIT_NAMES, activations_to_weights, is_arkit_model

    if face.shape_kind == "arkit":
        if not is_arkit_model(model):
            raise FaceFileError(f"{face.path} was dialled with ARKit blendshapes; the model has "
                                "none")
        unknown = sorted(set(face.shapes) - set(ARKIT_NAMES))
        if unknown:
            raise FaceFileError(f"{face.path}: unknown ARKit blendshape(s) {', '.join(unknown)}")
        a = np.array([[face.shapes.get(n, 0.0) for n in ARKIT_NAMES]])
        return {"expression": activations_to_weights(model, a)[0]}
    if face.shape_kind not in model.mode_names:
        raise FaceFileError(f"{face.path}: its sliders are of a mode {face.shape_kind!r} the "
                            f"model does not have ({', '.join(model.mode_names)})")
    out: dict[str, np.ndarray] = {}
    for name, v in face.shapes.items():           # LABEL of the main mode, or MODE:LABEL
        mode, _, label = name.rpartition(":")
        mode = mode or face.shape_kind
        if mode not in rest or mode == model.identity_mode \
                or label not in model.labels[model.mode_index(mode)]:
            raise FaceFileError(f"{face.path}: unknown shape {name!r} (a row of the model's "
                                f"{', '.join(m for m in rest if m != model.identity_mode)})")
        base = rest[mode]
        out[mode] = out.get(mode, base) + v * (model.training_weights(mode, label) - base)
    return out


def face_weights(face: DialledFace, model) -> dict[str, np.ndarray]:
    """The model's weights of a dialled face (per mode, ``(r_k,)`` each; the module notes).

    Raises FaceFileError where the file was made with another model, or names a dial or a
    shape the model does not have.
    """
    from .dials import neutral_weights

    if face.model_hash and face.model_hash != model.content_hash:
        from .model_hint import model_hint

        raise FaceFileError(f"{face.path} was dialled on another model (content hash "
                            f"{face.model_hash[:12]}, this one {model.content_hash[:12]})" + (
                                model_hint(face.model_hash)
                                or ": give the model its page was written from"))
    mode, identity = _identity(face, model)
    weights = {**neutral_weights(model, mode), mode: identity}
    return {**weights, **_expression(face, model, weights)}


def face_rotation(face: DialledFace) -> np.ndarray:
    """The head rotation ``(3, 3)`` of the page: ``Ry(yaw) Rx(pitch) Rz(roll)`` (the module
    notes; scipy's intrinsic ``"YXZ"``)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("YXZ", face.head, degrees=True).as_matrix()

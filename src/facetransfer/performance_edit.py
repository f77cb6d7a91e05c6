"""Editing a tracked performance (Vlasic et al. 2005, §6, Fig. 7E: "we manually add a frown").

The multilinear model's expression weights (Eq. (5)) of a track are edited frame by frame:

* :func:`edit_track`: add a training expression over a frame range, with smooth ramps
  (:func:`ramp_envelope`), or scale the component of the expression along a training
  expression's direction (:class:`EditAdd`, :class:`EditScale`; their text as the ``edit``
  command takes it: :func:`parse_add`, :func:`parse_scale`);
* :func:`edit_activations`: the same edits on ARKit activation curves, which is what
  :func:`edit_track` does for a model of ARKit expressions and what
  :func:`facetransfer.take.edit_take` does to a Live Link Face take.

Like :mod:`facetransfer.transfer` (whose :class:`~facetransfer.transfer.TransferError` the
edits raise), every function here is pure: a track (or curves) in, a new one out.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005,
§5 (Eq. (5)), §6 and Figure 7E.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .arkit import attach_activations, is_arkit_model
from .transfer import TransferError

__all__ = [
    "EditAdd",
    "EditScale",
    "SIDE_WORDS",
    "edit_activations",
    "edit_track",
    "parse_add",
    "parse_scale",
    "ramp_envelope",
]


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
               ramp: int = 8, mode: str = "expression", neutral: str = "neutral",
               first: int = 0):
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
    first : int
        The number of the track's first frame, which an added range counts from (0: its
        rows; ``edit`` gives a plate's track's first number, 1001, as
        :mod:`facetransfer.io.frame_numbers` numbers it).

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
    _check_edits(add, scale, track.n_frames, int(first))
    add = [dataclasses.replace(a, start=a.start - int(first), stop=a.stop - int(first))
           for a in add]                              # the track's rows
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


def _check_edits(add: list, scale: list, n: int, first: int = 0) -> None:
    """The edits' frame ranges lie in the clip of ``n`` frames numbered from ``first`` and run
    forwards, and their amounts and factors are finite (a NaN reached the track as non-finite
    weights; a range ending before its start weighed every frame less than 1 and edited
    nothing fully)."""
    for a in add:
        amount = f"*{a.amount:g}" if a.amount != 1 and np.isfinite(a.amount) else ""  # as typed
        where = f"--add {a.label}{amount}@{a.start}-{a.stop}"
        if a.start < first or a.stop > first + n - 1:
            raise TransferError(f"{where}: frames outside the clip ({first}-{first + n - 1}"
                                + (", a plate's track: numbered as the plate's files)"
                                   if first else ")"))
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
    ``EditAdd`` adds ``amount`` times the :func:`ramp_envelope` of its range; each value the
    edit changes clipped to [0, 1], every other as given (a take's value past 1 outside an
    added range, or of a curve not edited, is kept: before, an edited curve was clipped
    whole, and ``edit take.csv`` rewrote such fields it had not touched as 1). A label: one of the 52 shapes or both sides of one
    (:data:`SIDE_WORDS`), in any case (:func:`_spelled`). ``has``: (52,) bool, the shapes
    ``owner`` holds (default: all); an edit of another, an unknown name (:func:`_arkit_index`),
    a range outside the frames, a factor or amount not finite are refused. ``frames``: (F,)
    the rows' frame positions, which ranges count (default 0..F-1; a take's on its timeline).

    Returns
    -------
    (F, 52) float64
    """
    from .arkit import ARKIT_NAMES

    given = np.asarray(activations, dtype=np.float64)
    act = given.copy()
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
    moved = touched & (act != given)                # the values the edit changed, only
    act[moved] = np.clip(act[moved], 0.0, 1.0)
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

"""A neutral pose for the exported curves (beyond the paper): what Live Link Face calls
calibration.

An ARKit activation means "how far from this person's rest". A capture reads the rest of a
face the model cannot show exactly as a few shapes held on all clip long (a resting ``eyeWide``
of 0.1-0.3 on faces MediaPipe scores at 0.01, BENCHMARKS.md "Twenty-first session"): an
animation rig driven by those curves never rests. Live Link Face lets its user record a neutral
face and measures every later frame from it; ``facetransfer export --neutral FRAME`` does the
same with a frame of the track, or ``--neutral auto`` with the frame whose non-gaze activations
sum least (the most relaxed face of the clip):

    a' = clip((a - n) / (1 - n), 0, 1)

per shape, ``n`` the neutral frame's activation (at most :data:`MAX_NEUTRAL`), so the neutral
frame exports 0 and a fully active shape still exports 1. The gaze (``eyeLook*``) is left as
tracked: it comes from the iris, and 0 means looking straight ahead, not "at rest".
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..arkit import ARKIT_NAMES
from .common import ExportError, require_activations

__all__ = ["MAX_NEUTRAL", "calibrated", "neutral_arg", "neutral_frame", "with_neutral"]

#: Highest neutral level a shape is measured from (above, the rescaling would amplify noise).
MAX_NEUTRAL = 0.9
#: The shapes left as tracked: the gaze.
_GAZE = np.array([n.startswith("eyeLook") for n in ARKIT_NAMES])


def neutral_frame(activations: np.ndarray, lost: np.ndarray | None = None) -> int:
    """The frame whose non-gaze activations sum least, among the frames not ``lost``.

    Parameters
    ----------
    activations : (F, 52) float
        In :data:`~facetransfer.arkit.ARKIT_NAMES` order.
    lost : (F,) bool, optional

    Raises
    ------
    ExportError
        Every frame lost.
    """
    a = np.asarray(activations, np.float64)
    total = np.nansum(a[:, ~_GAZE], axis=1)
    ok = np.isfinite(a[:, ~_GAZE]).all(axis=1)
    if lost is not None:
        ok &= ~np.asarray(lost, bool)
    if not ok.any():
        raise ExportError("no frame of the track has a face to take as the neutral pose")
    return int(np.flatnonzero(ok)[np.argmin(total[ok])])


def calibrated(activations: np.ndarray, neutral: int) -> np.ndarray:
    """The activations measured from frame ``neutral`` (module notes), ``(F, 52) float32``."""
    a = np.asarray(activations, np.float64)
    n = np.clip(a[int(neutral)], 0.0, MAX_NEUTRAL)
    n[_GAZE] = 0.0
    return np.clip((a - n) / (1.0 - n), 0.0, 1.0).astype(np.float32)


def neutral_arg(value) -> int | str:
    """``--neutral``'s value: a frame number (int >= 0) or ``"auto"``.

    Raises
    ------
    ExportError
        Anything else.
    """
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    try:
        i = int(value)
    except (TypeError, ValueError):
        i = -1
    if i < 0:
        raise ExportError(f"--neutral must be a frame number or auto, got {value!r}")
    return i


def with_neutral(track, neutral, *, take=None):
    """``track`` with its activations measured from a neutral frame: ``neutral`` a frame
    number (counted from 0; of a plate's track, the plate's own number, as
    :mod:`facetransfer.io.frame_numbers` numbers it), ``"auto"`` (:func:`neutral_frame`) or
    None (the track unchanged). The frame used is recorded in ``info["neutral_frame"]`` (its
    row, counted from 0). ``take``: the path of the Live Link Face take ``track`` was made
    from (:func:`facetransfer.take.take_track`), named by the error of a frame past its end,
    with its timeline's rate (a take's frames are numbered on it).

    Raises
    ------
    ExportError
        A frame number outside the track, a lost frame, or another word than ``auto``.
    """
    from ..io.frame_numbers import track_first_number

    if neutral is None:
        return track
    a = require_activations(track)
    said = neutral_arg(neutral)
    first = track_first_number(track)   # a plate's track: its frames by the plate's numbers
    if said == "auto":
        i = neutral_frame(a, track.lost)
    elif not 0 <= (i := said - first) < track.n_frames:
        of = "the track" if take is None else f"the take {take}"
        raise ExportError(f"--neutral {said}: {of} has frames {first} to "
                          f"{first + track.n_frames - 1}"
                          + ("" if take is None else f" (on its {track.fps:g} fps timeline)")
                          + (" (a plate's, numbered as its files)" if first else ""))
    elif bool(np.asarray(track.lost)[i]):
        raise ExportError(f"--neutral {said}: the face is lost in that frame")
    return dataclasses.replace(track, blendshapes=calibrated(a, i),
                               blendshape_names=ARKIT_NAMES,
                               info={**track.info, "neutral_frame": i})

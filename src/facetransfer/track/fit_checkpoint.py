"""Resuming the capture tracker's fit after an interruption (beyond the paper).

The capture tracker (:mod:`facetransfer.track.capture`) first detects every frame, then fits the
model: the clip's identity and offset from frames spread through it, then every frame in two
runs from the most reliable one (forward to the end, backward to the start). Detections resume
on their own (:mod:`facetransfer.track.detect_checkpoint`); this module holds what the fit saves
beside them, so that an interrupted fit continues at the frame it stopped at:

- the identity phase's result: identity weights, the static offset of the tracked points, the
  sampled frames, the start frame and its seed state;
- the frames fitted so far (pose, parameters, residual) and where each run stands;
- in the second pass (:mod:`facetransfer.track.scores`), the lines that map the detector's
  scores onto the first pass's activations (the saved frames are then the second pass's).

Everything is float64, saved and restored exactly, so a resumed fit equals an uninterrupted one
bit for bit. A fit saved by another model, other options or another fixed identity has another
:func:`fit_key` and is ignored (the detections are still used).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass

import numpy as np

__all__ = ["FIT_VERSION", "fit_key", "SavedFit", "pack_fit", "unpack_fit"]

#: bumped when the saved fit changes layout or meaning (older fits are then ignored)
#: 2: the second pass (score lines); 3: the inner lips weighed up (INNER_LIPS); 4: the lips'
#: contact held (lip_contact); 5: that contact solved exactly (contact_qp by its dual); 6:
#: the score lines' weights (a bounded slope); 7: the funnel's ridge where the lips are shut
#: (``CaptureOptions.funnel_gate``)
FIT_VERSION = 7
#: prefix of the fit's entries in the progress file
PREFIX = "fit_"


def fit_key(model_hash: str, options, fixed: dict | None) -> str:
    """sha256 of everything a saved fit depends on besides the detections.

    Parameters
    ----------
    model_hash : str
        The model's content hash.
    options : CaptureOptions
    fixed : dict or None
        ``{"identity": (r,)}`` when the identity was kept fixed.
    """
    doc = {"model": model_hash, "options": dataclasses.asdict(options),
           "fixed": {k: np.asarray(v, np.float64).tolist() for k, v in sorted((fixed or {})
                                                                             .items())},
           "version": FIT_VERSION}
    text = json.dumps(doc, sort_keys=True, default=lambda o: np.asarray(o).tolist())
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class SavedFit:
    """A fit in progress, as arrays.

    Attributes
    ----------
    identity : (r,) float64 or None
    offset : (P, 3) or (P, 6) float64
        Static offset of the tracked points; with a view-dependent part
        (``CaptureOptions.view_offset_prior``), that part after it.
    frames : (n,) int64
        The frames the identity was fitted on.
    start : int
        The frame both runs start from.
    seed : (R (3, 3), s, t (2,), x (K,), residual)
        The start frame's state from the identity phase.
    valid : (F,) bool
        Frames fitted so far.
    rotation, scale, translation, x, residual : (F, 3, 3), (F,), (F, 2), (F, K), (F,) float64
        Their states (zeros where not ``valid``).
    forward_next, backward_next : int
        The next frame of the forward run (``F``: done) and of the backward run (-1: done).
    lines : (3, 52) float64 or None
        In the second pass: the score lines' offsets, slopes and weights (NaN: a shape not
        read);
        None in the first.
    """

    identity: np.ndarray | None
    offset: np.ndarray
    frames: np.ndarray
    start: int
    seed: tuple
    valid: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray
    translation: np.ndarray
    x: np.ndarray
    residual: np.ndarray
    forward_next: int
    backward_next: int
    lines: np.ndarray | None = None


def pack_fit(fit: SavedFit, key: str) -> dict:
    """The progress file's entries of ``fit`` (names start with :data:`PREFIX`)."""
    R, s, t, x, r = fit.seed
    d = {"key": np.array(key), "has_identity": np.array(fit.identity is not None),
         "identity": np.zeros(0) if fit.identity is None else np.asarray(fit.identity, float),
         "offset": fit.offset, "frames": np.asarray(fit.frames, np.int64),
         "start": np.array(int(fit.start)), "seed_R": R, "seed_s": np.array(float(s)),
         "seed_t": t, "seed_x": x, "seed_residual": np.array(float(r)), "valid": fit.valid,
         "rotation": fit.rotation, "scale": fit.scale, "translation": fit.translation,
         "x": fit.x, "residual": fit.residual,
         "forward_next": np.array(int(fit.forward_next)),
         "backward_next": np.array(int(fit.backward_next)),
         "lines": np.zeros((0, 52)) if fit.lines is None else np.asarray(fit.lines, float)}
    return {PREFIX + k: np.asarray(v) for k, v in d.items()}


def unpack_fit(entries: dict) -> tuple[str, SavedFit] | None:
    """``(key, fit)`` from a progress file's entries, or None when it holds no fit.

    Raises
    ------
    ValueError
        The entries are inconsistent (a damaged file).
    """
    if PREFIX + "key" not in entries:
        return None
    d = {k[len(PREFIX):]: v for k, v in entries.items() if k.startswith(PREFIX)}
    F = len(d["valid"])
    lines = np.asarray(d.get("lines", np.zeros((0, 52))), np.float64)
    if lines.shape == (2, 52):     # an older version's (FIT_VERSION 5): its key is never taken,
        return None                # and the file's detections are kept, not called damaged
    shapes = {"rotation": (F, 3, 3), "scale": (F,), "translation": (F, 2), "residual": (F,)}
    if any(d[k].shape != v for k, v in shapes.items()) or d["x"].shape[0] != F \
            or d["offset"].ndim != 2 or not 0 <= int(d["start"]) < F \
            or (lines.size and lines.shape != (3, 52)):
        raise ValueError("inconsistent fit arrays")
    fit = SavedFit(
        identity=d["identity"] if bool(d["has_identity"]) else None, offset=d["offset"],
        frames=d["frames"], start=int(d["start"]),
        seed=(d["seed_R"], float(d["seed_s"]), d["seed_t"], d["seed_x"],
              float(d["seed_residual"])),
        valid=d["valid"].astype(bool), rotation=d["rotation"], scale=d["scale"],
        translation=d["translation"], x=d["x"], residual=d["residual"],
        forward_next=int(d["forward_next"]), backward_next=int(d["backward_next"]),
        lines=lines if lines.size else None)
    return str(d["key"]), fit

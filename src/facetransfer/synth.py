"""Synthetic face footage with exact ground truth, for tests, benchmarks and demos (issue 5, §6).

A *performance* says what a multilinear model (Vlasic et al. 2005, Eq. (5)) does over time: the
identity, the weights of every other mode per frame, and the head pose of the tracker's
weak-perspective camera (§5.1, Eq. (7)). :func:`make_clip` renders it, textured, over a
background and returns the frames with the truth per frame: pose, weights per mode, the 68
landmarks and every vertex in pixels, and per-vertex visibility. :func:`write_clip` writes the
video and ``<name>.truth.npz`` beside it.

Performance spec (JSON; its keys :data:`SPEC_KEYS`, :mod:`facetransfer.synth_keys`')
------------------------------------------------------------------------------------
::

    {
      "fps": 25,                        # frames per second (default 25)
      "n_frames": 100,                  # clip length (default: last keyframe + 1, else 100)
      "size": [640, 480],               # frame width, height (default 640 x 480)
      "identity": "id03",               # a training label, a weight list [w1, ..., w_r], or a
                                        # blend {"id01": 0.5, "id03": 0.5} (default: mode mean)
      "tracks": {                       # keyframes per non-identity mode
        "expression": [[0, "neutral"], [25, {"smile": 1.0}], [60, {"smile": 0.3, "open": 0.7}],
                       [90, [0.1, 0.2, ...]]],
        "viseme": [[0, "rest"], [10, "aa"]]
      },
      "pose": {                         # smooth oscillation of the head ...
        "yaw_deg": 10, "pitch_deg": 5, "roll_deg": 3,   # amplitudes in degrees (render angles)
        "translate_px": 8,              # amplitude of the image drift in pixels
        "scale": 0.05,                  # relative amplitude of the scale change
        "period_s": 4.0,                # period of the yaw oscillation (others detuned)
        "fill": 0.55                    # face height as a fraction of the frame height
      }
    }

or ``"pose": {"keys": [[frame, {"yaw_deg": .., "pitch_deg": .., "roll_deg": .., "tx": ..,
"ty": .., "scale": ..}], ...], "fill": 0.55}`` for keyframed pose (``tx``, ``ty`` pixels from
the frame centre, ``scale`` relative, 1 = the ``fill`` framing).

A keyframe value is a training label, a blend ``{label: amount}`` meaning
``base + sum amount * (w_label - base)`` (``base`` is the ``"neutral"`` row of the mode if it
has one, else the mode mean; for identity the mean), or a raw weight vector of the mode's rank.
Weights between keyframes are eased (smoothstep) interpolations; before the first and after the
last keyframe they hold. Modes without a track stay at their base.

Camera: the face is framed once from the identity's base shape: scale ``s`` makes its height
``fill`` of the frame, and the head turns about the centre of its bounding box, which sits at the
frame centre plus the drift. Pixel coordinates follow the project convention: x right, y down,
the centre of the top-left pixel at (0, 0).

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005,
§4.3 Eq. (5) (synthesis from weights), §5.1 Eq. (7) (weak-perspective camera).
"""

from __future__ import annotations

import json
import math
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from .background import background_image
from .errors import AssetError, FaceTransferError, TrackError, VideoError
from .io.atomic import atomic_path, check_output_path
from .io.npz import read_npz
from .render import WeakPerspective, render, rotation_from_euler
from .synth_keys import MAX_FRAMES, SPEC_KEYS  # the keys of a spec, read by the parser below

log = logging.getLogger(__name__)

__all__ = ["SpecError", "Performance", "SyntheticTruth", "SyntheticClip", "load_performance",
           "performance_from_spec", "random_performance", "procedural_skin_texture",
           "procedural_vertex_colors", "procedural_background", "make_clip",
           "write_clip", "synthesize_video", "load_truth", "truth_path",
           "load_texture_image", "SPEC_KEYS"]

DEFAULT_FPS = 25.0
DEFAULT_SIZE = (640, 480)
DEFAULT_FILL = 0.55
SKIN_RGB = (214, 160, 134)
#: Lambert shading of the synthetic face: light from above-left in front, soft ambient.
LIGHT = (0.25, 0.35, 1.0)
AMBIENT = 0.5


class SpecError(FaceTransferError):
    """A performance spec that cannot be used with the given model."""


# --------------------------------------------------------------------------------------------
# Performance: per-frame weights and pose
# --------------------------------------------------------------------------------------------

class _Posed:
    """Per-frame weak-perspective poses (Eq. (7)) held as ``scale`` (F,), ``rotation`` (F, 3, 3)
    and ``translation`` (F, 2): what :class:`Performance` and :class:`SyntheticTruth` share."""

    scale: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.scale.shape[0])

    def camera(self, frame: int) -> WeakPerspective:
        """The weak-perspective camera of one frame."""
        return WeakPerspective(float(self.scale[frame]), self.rotation[frame],
                               self.translation[frame])


@dataclass(frozen=True, eq=False)
class Performance(_Posed):
    """What the model does in every frame.

    Attributes
    ----------
    fps : float
    size : (W, H)
    weights : dict mode name -> (n_frames, r_k) float64
        Weights of every mode per frame (identity constant).
    rotation : (n_frames, 3, 3) float64
    scale : (n_frames,) float64
        Pixels per model unit.
    translation : (n_frames, 2) float64
        Pixels, Eq. (7).
    spec : dict
        The spec it was made from (or the seed of a random one), for provenance.
    """

    fps: float
    size: tuple[int, int]
    weights: dict[str, np.ndarray]
    rotation: np.ndarray
    scale: np.ndarray
    translation: np.ndarray
    spec: dict = field(default_factory=dict)

    def frame_weights(self, frame: int) -> dict[str, np.ndarray]:
        return {m: w[frame] for m, w in self.weights.items()}


def _base(model, mode: str) -> np.ndarray:
    k = model.mode_index(mode)
    if k > 0 and "neutral" in model.labels[k]:
        return model.training_weights(k, "neutral")
    return model.weight_mean(k)


def _value_weights(model, mode: str, value, where: str) -> np.ndarray:
    """Weights (r,) of a keyframe value: label, {label: amount} blend or weight list, within
    the model's reach (:meth:`~facetransfer.model.MultilinearModel.check_reach`)."""
    k = model.mode_index(mode)
    r = model.ranks[k]
    base = _base(model, mode)
    try:
        if isinstance(value, str):
            return model.training_weights(k, value)
        if isinstance(value, Mapping):
            w = base.copy()
            for label, amount in value.items():
                w += _amount(amount, label) * (model.training_weights(k, label) - base)
        else:
            w = np.asarray(value, dtype=np.float64)
            if w.shape != (r,) or not np.all(np.isfinite(w)):
                raise ValueError(f"expected a label, a {{label: amount}} blend or {r} finite "
                                 f"weights for mode {mode!r}, got {value!r}")
        return model.check_reach(k, w)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{where}: {exc}") from None


def _amount(amount, label) -> float:
    """A blend's ``{label: amount}`` amount as a finite float, else ValueError (NaN or infinity
    made a NaN face that failed later); its caller says where in the spec."""
    try:
        a = float(amount)
    except (TypeError, ValueError):
        a = math.nan
    if not math.isfinite(a) or isinstance(amount, bool):
        raise ValueError(f"amount of {label!r} must be a finite number, got {amount!r}")
    return a


def _ease(x: np.ndarray) -> np.ndarray:
    """Smoothstep 3x^2 - 2x^3 on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _keyframe_track(keys: list[tuple[int, np.ndarray]], n_frames: int) -> np.ndarray:
    """(n_frames, r) eased interpolation between keyframes ``(frame, value)`` (sorted)."""
    frames = np.array([f for f, _ in keys], dtype=np.float64)
    vals = np.stack([v for _, v in keys])
    t = np.arange(n_frames, dtype=np.float64)
    j = np.clip(np.searchsorted(frames, t, side="right") - 1, 0, len(keys) - 1)
    j1 = np.minimum(j + 1, len(keys) - 1)
    span = frames[j1] - frames[j]
    a = np.where(span > 0, (t - frames[j]) / np.where(span > 0, span, 1.0), 0.0)
    a = _ease(a)[:, None]
    out = vals[j] * (1 - a) + vals[j1] * a
    out[t < frames[0]] = vals[0]
    return out


def _parse_keys(raw, what: str) -> list[tuple[int, Any]]:
    if not isinstance(raw, list) or not raw:
        raise SpecError(f"{what} must be a non-empty list of [frame, value] keyframes")
    keys = []
    for i, item in enumerate(raw):
        if not isinstance(item, (list, tuple)) or len(item) != 2:
            raise SpecError(f"{what}[{i}] must be [frame, value], got {item!r}")
        try:
            f = int(item[0])
            if isinstance(item[0], float) and item[0] != f:   # 1.5 was read as frame 1
                raise ValueError
        except (TypeError, ValueError, OverflowError):
            raise SpecError(f"{what}[{i}]: frame must be an integer, got {item[0]!r}") from None
        if f < 0:
            raise SpecError(f"{what}[{i}]: frame must be >= 0, got {f}")
        keys.append((f, item[1]))
    keys.sort(key=lambda kv: kv[0])
    return keys


def _frame_camera_params(model, identity_w: np.ndarray, size, fill: float):
    """Scale and model centre that frame the identity's base face at ``fill`` of the height."""
    w = {m: _base(model, m) for m in model.mode_names}
    w[model.mode_names[0]] = identity_w
    V = model.synthesize(w)
    lo, hi = V.min(axis=0), V.max(axis=0)
    height = float(max(hi[1] - lo[1], 1e-12))
    return fill * size[1] / height, 0.5 * (lo + hi)


def _pose_arrays(yaw, pitch, roll, tx, ty, rel_scale, s0, centre, size):
    """Rotation, scale and translation arrays from per-frame pose parameters: ``yaw``,
    ``pitch``, ``roll`` (n,) render angles in degrees (:func:`facetransfer.render.
    rotation_from_euler`, ``R = Rz(roll) Ry(yaw) Rx(pitch)``; yaw > 0 turns the face toward the
    image's right, pitch > 0 looks down, roll > 0 counter-clockwise), ``tx``, ``ty`` (n,) pixels
    of drift, ``rel_scale`` (n,) times ``s0``."""
    n = len(yaw)
    R = np.stack([rotation_from_euler(yaw[i], pitch[i], roll[i]) for i in range(n)])
    s = s0 * np.asarray(rel_scale, dtype=np.float64)
    W, H = size
    # the model centre c lands at the frame centre + drift: t = p_c - s diag(1,-1) R[:2] c
    Rc = np.einsum("fij,j->fi", R[:, :2], centre)
    t = np.stack([(W - 1) / 2 + np.asarray(tx) - s * Rc[:, 0],
                  (H - 1) / 2 + np.asarray(ty) + s * Rc[:, 1]], axis=1)
    return R, s, t


def _check_size(size) -> tuple[int, int]:
    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        raise SpecError(f"size must be [width, height], got {size!r}") from None
    if not (8 <= W <= 8192 and 8 <= H <= 8192):
        raise SpecError(f"size must be between 8 and 8192 pixels each, got {size!r}")
    return W, H


def _num(obj: Mapping, key: str, default: float, where: str) -> float:
    """A finite number from a spec object, or ``default`` if absent."""
    val = obj.get(key, default)
    try:
        out = float(val)
    except (TypeError, ValueError):
        out = float("nan")
    if isinstance(val, bool) or not np.isfinite(out):
        raise SpecError(f"{where} must be a finite number, got {val!r}")
    return out


def performance_from_spec(model, spec: Mapping) -> Performance:
    """Resolve a performance spec (see the module docstring) against a model.

    Parameters
    ----------
    model : MultilinearModel
    spec : mapping
        Parsed JSON spec.

    Returns
    -------
    Performance

    Raises
    ------
    SpecError
        Unknown keys, modes or labels, weights of the wrong length, bad frame numbers.
    """
    _check_spec_keys(spec)
    fps = _num(spec, "fps", DEFAULT_FPS, "fps")
    if not 0 < fps <= 1000:
        raise SpecError(f"fps must be in (0, 1000], got {fps}")
    size = _check_size(spec.get("size", DEFAULT_SIZE))
    id_mode = model.mode_names[0]
    identity = _value_weights(model, id_mode, spec["identity"], "identity") \
        if "identity" in spec else _base(model, id_mode)
    parsed, last = _spec_tracks(model, spec)
    pose = spec.get("pose", {}) or {}
    if not isinstance(pose, Mapping):
        raise SpecError(f"pose must be an object, got {pose!r}")
    pose = dict(pose)
    if "keys" in pose:
        last = max(last, _parse_keys(pose["keys"], "pose.keys")[-1][0])
    n_frames = _spec_n_frames(spec, last)
    weights = _mode_weights(model, identity, parsed, n_frames)
    fill = _num(pose, "fill", DEFAULT_FILL, "pose.fill")
    pose.pop("fill", None)
    if not 0 < fill <= 2:
        raise SpecError(f"pose.fill must be in (0, 2], got {fill}")
    s0, centre = _frame_camera_params(model, identity, size, fill)
    if "keys" in pose:
        yaw, pitch, roll, tx, ty, rs = _keyed_pose(pose, n_frames)
    else:
        yaw, pitch, roll, tx, ty, rs = _oscillating_pose(pose, np.arange(n_frames) / fps)
    if np.any(rs <= 0):
        raise SpecError("pose scale must stay > 0")
    R, s, tr = _pose_arrays(yaw, pitch, roll, tx, ty, rs, s0, centre, size)
    return Performance(fps, size, weights, R, s, tr, dict(spec))


def _check_spec_keys(spec) -> None:
    """SpecError unless ``spec`` is a mapping of the known top-level keys."""
    if not isinstance(spec, Mapping):
        raise SpecError(f"a performance spec must be a JSON object, got {type(spec).__name__}")
    unknown = set(spec) - set(SPEC_KEYS["spec"])
    if unknown:
        raise SpecError(f"unknown performance spec key(s) {sorted(unknown)}; known: "
                        f"{sorted(SPEC_KEYS['spec'])}")


def _spec_tracks(model, spec: Mapping) -> tuple[dict[str, list[tuple[int, np.ndarray]]], int]:
    """Keyframes ``(frame, weights (r,))`` per non-identity mode, and the last keyed frame (-1)."""
    id_mode = model.mode_names[0]
    tracks = spec.get("tracks", {}) or {}
    if not isinstance(tracks, Mapping):
        raise SpecError("tracks must be an object {mode: [[frame, value], ...]}")
    parsed = {}
    last = -1
    for mode, raw in tracks.items():
        if mode not in model.mode_names:
            raise SpecError(f"track for unknown mode {mode!r}; the model has modes "
                            f"{', '.join(model.mode_names)}")
        if mode == id_mode:
            raise SpecError(f"the {id_mode} is constant: give it as \"identity\", not a track")
        keys = _parse_keys(raw, f"tracks.{mode}")
        parsed[mode] = [(f, _value_weights(model, mode, v, f"tracks.{mode} frame {f}"))
                        for f, v in keys]
        last = max(last, keys[-1][0])
    return parsed, last


def _spec_n_frames(spec: Mapping, last: int) -> int:
    """The clip length: ``n_frames``, else the last keyframe + 1, else 100."""
    n_frames = _num(spec, "n_frames", last + 1 if last >= 0 else 100, "n_frames")
    if n_frames != int(n_frames):
        raise SpecError(f"n_frames must be an integer, got {n_frames}")
    n_frames = int(n_frames)
    if not 1 <= n_frames <= MAX_FRAMES:   # --frames' limit (before, 100000 here: less)
        raise SpecError(f"n_frames must be between 1 and {MAX_FRAMES}, got {n_frames}")
    return n_frames


def _mode_weights(model, identity: np.ndarray, parsed: dict, n_frames: int
                  ) -> dict[str, np.ndarray]:
    """Weights (n_frames, r_k) of every mode: the identity constant, tracks eased, others at base."""
    weights = {}
    for mode in model.mode_names:
        if mode == model.mode_names[0]:
            weights[mode] = np.tile(identity, (n_frames, 1))
        elif mode in parsed:
            weights[mode] = _keyframe_track(parsed[mode], n_frames)
        else:
            weights[mode] = np.tile(_base(model, mode), (n_frames, 1))
    return weights


def _keyed_pose(pose: dict, n_frames: int) -> np.ndarray:
    """Keyframed pose: (6, n_frames) yaw, pitch, roll (render angles in degrees, as
    :func:`_pose_arrays` takes them), tx, ty (pixels), relative scale.

    ``pose`` holds ``keys`` and nothing else (``fill`` already taken out).
    """
    names, keys = SPEC_KEYS["pose.keys"], []
    for f, v in _parse_keys(pose.pop("keys"), "pose.keys"):
        if not isinstance(v, Mapping) or set(v) - set(names):
            raise SpecError(f"pose.keys frame {f}: expected an object with keys from "
                            f"{names}, got {v!r}")
        keys.append((f, np.array([_num(v, k, 1.0 if k == "scale" else 0.0,
                                       f"pose.keys frame {f}: {k}") for k in names])))
    if pose:
        raise SpecError(f"unknown pose key(s) {sorted(pose)} beside 'keys'")
    return _keyframe_track(keys, n_frames).T


def _oscillating_pose(pose: Mapping, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """Smooth head oscillation at times ``t`` (n,) seconds: yaw, pitch, roll (render angles in
    degrees, as :func:`_pose_arrays` takes them), tx, ty (pixels) and relative scale, each (n,);
    the periods are detuned from ``period_s``."""
    if set(pose) - set(SPEC_KEYS["pose"]):    # fill and keys were taken out
        raise SpecError(f"unknown pose key(s) {sorted(set(pose) - set(SPEC_KEYS['pose']))}; "
                        f"known: {sorted(SPEC_KEYS['pose'])}")
    period = _num(pose, "period_s", 4.0, "pose.period_s")
    if not period > 0:
        raise SpecError(f"pose.period_s must be > 0, got {period}")
    ph = 2 * np.pi * t / period
    yaw = _num(pose, "yaw_deg", 0.0, "pose.yaw_deg") * np.sin(ph)
    pitch = _num(pose, "pitch_deg", 0.0, "pose.pitch_deg") * np.sin(1.37 * ph + 0.5)
    roll = _num(pose, "roll_deg", 0.0, "pose.roll_deg") * np.sin(0.71 * ph + 1.0)
    amp = _num(pose, "translate_px", 0.0, "pose.translate_px")
    tx, ty = amp * np.sin(0.53 * ph + 2.0), amp * np.sin(0.89 * ph + 0.3)
    rs = 1.0 + _num(pose, "scale", 0.0, "pose.scale") * np.sin(0.61 * ph + 1.2)
    return yaw, pitch, roll, tx, ty, rs


def load_performance(model, path: str | os.PathLike) -> Performance:
    """Read a JSON performance spec file and resolve it against a model."""
    p = Path(path)
    if not p.is_file():
        raise SpecError(f"performance spec {p} does not exist")
    try:
        spec = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"performance spec {p} is not valid JSON: {exc}") from None
    try:
        return performance_from_spec(model, spec)
    except SpecError as exc:
        raise SpecError(f"{p}: {exc}") from None


def _smooth_noise(n: int, rng: np.random.Generator, n_waves: int = 3,
                  min_period: float = 40.0, max_period: float = 160.0) -> np.ndarray:
    """(n,) smooth zero-mean curve in [-1, 1]: a few sinusoids with random periods/phases."""
    t = np.arange(n, dtype=np.float64)
    out = np.zeros(n)
    amps = rng.uniform(0.5, 1.0, n_waves)
    for a, p, ph in zip(amps, rng.uniform(min_period, max_period, n_waves),
                        rng.uniform(0, 2 * np.pi, n_waves)):
        out += a * np.sin(2 * np.pi * t / p + ph)
    return out / amps.sum()


def random_performance(model, n_frames: int = 100, *, seed: int = 0,
                       size: tuple[int, int] = DEFAULT_SIZE, fps: float = DEFAULT_FPS,
                       identity=None, yaw_deg: float = 8.0, pitch_deg: float = 5.0,
                       roll_deg: float = 3.0, translate_px: float = 10.0,
                       scale_var: float = 0.03, fill: float = DEFAULT_FILL,
                       key_every: float = 1.0) -> Performance:
    """A seeded random performance: smooth walks between training rows and gentle head motion.

    Every non-identity mode gets a keyframe about every ``key_every`` seconds (jittered): a
    random training row at a random amount (0.4 to 1) from the mode's base, eased in between.
    The identity is a random blend of two training identities unless given (label, weights
    or blend, as in a spec). The head sways by a few degrees and drifts by a few pixels:
    ``yaw_deg``, ``pitch_deg``, ``roll_deg`` are the amplitudes of its render angles in degrees
    (:func:`facetransfer.render.rotation_from_euler`).

    Returns
    -------
    Performance
    """
    if n_frames < 1:
        raise SpecError(f"n_frames must be >= 1, got {n_frames}")
    size = _check_size(size)
    rng = np.random.default_rng(seed)
    id_mode = model.mode_names[0]
    if identity is None:
        labels = model.labels[0]
        a, b = rng.choice(len(labels), size=2, replace=len(labels) < 2)
        mix = rng.uniform(0.2, 0.8)
        identity = {labels[a]: mix, labels[b]: 1 - mix} if a != b else labels[a]
    id_w = _value_weights(model, id_mode, identity, "identity")
    step = max(1, int(round(key_every * fps)))
    weights = {id_mode: np.tile(id_w, (n_frames, 1))}
    for k, mode in enumerate(model.mode_names[1:], start=1):
        base = _base(model, mode)
        frames = [0]
        while frames[-1] < n_frames - 1:
            frames.append(frames[-1] + int(rng.integers(max(1, step // 2), step + step // 2 + 1)))
        keys = []
        for i, f in enumerate(frames):
            if i == 0:
                keys.append((f, base))
                continue
            row = model.factors[k][rng.integers(model.factors[k].shape[0])]
            keys.append((f, base + rng.uniform(0.4, 1.0) * (row - base)))
        weights[mode] = _keyframe_track(keys, n_frames)
    s0, centre = _frame_camera_params(model, id_w, size, fill)
    yaw = yaw_deg * _smooth_noise(n_frames, rng, min_period=2 * fps, max_period=6 * fps)
    pitch = pitch_deg * _smooth_noise(n_frames, rng, min_period=2 * fps, max_period=6 * fps)
    roll = roll_deg * _smooth_noise(n_frames, rng, min_period=2 * fps, max_period=6 * fps)
    tx = translate_px * _smooth_noise(n_frames, rng, min_period=3 * fps, max_period=8 * fps)
    ty = translate_px * _smooth_noise(n_frames, rng, min_period=3 * fps, max_period=8 * fps)
    rs = 1.0 + scale_var * _smooth_noise(n_frames, rng, min_period=3 * fps, max_period=8 * fps)
    R, s, t = _pose_arrays(yaw, pitch, roll, tx, ty, rs, s0, centre, size)
    return Performance(float(fps), size, weights, R, s, t,
                       {"random": True, "seed": int(seed), "n_frames": int(n_frames)})


# --------------------------------------------------------------------------------------------
# Appearance: procedural skin texture, vertex colours and background
# --------------------------------------------------------------------------------------------

def _band_noise(shape: tuple[int, int], rng: np.random.Generator, sigmas=(2.0, 6.0, 16.0),
                weights=(0.35, 0.4, 0.25)) -> np.ndarray:
    """Zero-mean unit-std band-limited noise: blurred white noise at a few scales."""
    import cv2

    out = np.zeros(shape, np.float32)
    for s, w in zip(sigmas, weights):
        n = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), s)
        out += w * n / max(float(n.std()), 1e-6)
    return out / max(float(out.std()), 1e-6)


def procedural_skin_texture(uvs: np.ndarray | None = None, landmarks_uv: np.ndarray | None = None,
                            *, size: int = 512, seed: int = 0) -> np.ndarray:
    """A plain skin-tone UV texture with smooth blotches, and darker brows, eyes and lips.

    The default face texture's ``source="procedural"`` (:func:`facetransfer.texture.default.
    default_face_texture`; the default is the Lee Perry-Smith head's, :mod:`facetransfer.texture.
    lee_perry_smith`) and synthetic footage's skin. The noise is band-limited (Gaussian-blurred, sigma >= 2 texels) so that
    a tracker's KLT features find corners without aliasing: on a 30-frame random performance of
    the ICT face at 640x480, pyramidal KLT (15x15, 3 levels) follows visible vertices with a
    median error of 0.05 px (90 %: 0.18 px), against 0.08 px (0.26 px) with the more natural
    :func:`facetransfer.texture.default_face_texture`, whose finer noise aliases when minified.

    Parameters
    ----------
    uvs : (n, 2) float64, optional
        Unused except for validation; kept for symmetry with per-vertex colouring.
    landmarks_uv : (68, 2) float64, optional
        UVs of the iBUG-68 landmarks (v up); brows, eyes and lips are painted where they are.
    size : int
        Texture side in texels.
    seed : int

    Returns
    -------
    (size, size, 3) uint8 RGB
    """
    import cv2

    rng = np.random.default_rng(seed)
    tex = np.empty((size, size, 3), np.float32)
    tex[:] = SKIN_RGB
    tone = _band_noise((size, size), rng)
    spots = _band_noise((size, size), rng, sigmas=(3.0,), weights=(1.0,))
    tex += 16.0 * tone[..., None] * np.array([1.0, 0.85, 0.8], np.float32)
    freckles = np.clip(spots - 1.2, 0, None)  # sparse darker blotches
    tex -= 40.0 * freckles[..., None] * np.array([0.6, 0.8, 0.9], np.float32)
    if landmarks_uv is not None and np.shape(landmarks_uv) == (68, 2):
        px = np.column_stack([landmarks_uv[:, 0] * (size - 1),
                              (1 - landmarks_uv[:, 1]) * (size - 1)])
        layer = np.zeros((size, size, 3), np.float32)
        alpha = np.zeros((size, size), np.float32)
        thick = max(2, size // 80)

        def poly(idx, colour, closed=True, width=0):
            pts = np.round(px[list(idx)] * 16).astype(np.int32).reshape(-1, 1, 2)
            if width:
                cv2.polylines(layer, [pts], closed, colour, width, cv2.LINE_AA, 4)
                cv2.polylines(alpha, [pts], closed, 1.0, width, cv2.LINE_AA, 4)
            else:
                cv2.fillPoly(layer, [pts], colour, cv2.LINE_AA, 4)
                cv2.fillPoly(alpha, [pts], 1.0, cv2.LINE_AA, 4)

        poly(range(17, 22), (95, 65, 50), closed=False, width=2 * thick)  # brows
        poly(range(22, 27), (95, 65, 50), closed=False, width=2 * thick)
        poly(range(48, 60), (170, 80, 80))  # lips
        poly(range(36, 42), (60, 45, 40))  # eyes
        poly(range(42, 48), (60, 45, 40))
        alpha = cv2.GaussianBlur(alpha, (0, 0), 1.5)[..., None]
        layer = cv2.GaussianBlur(layer, (0, 0), 1.5)
        tex = tex * (1 - alpha) + layer * alpha * (1 + 0.1 * tone[..., None])
    return np.clip(np.rint(tex), 0, 255).astype(np.uint8)


def procedural_vertex_colors(vertices: np.ndarray, *, landmarks: np.ndarray | None = None,
                             seed: int = 0) -> np.ndarray:
    """Per-vertex skin colours from smooth 3D noise (for models without UVs).

    Sum of random Fourier features of the vertex positions (wavelengths 5-30 % of the face
    size), plus darker lips/eyes/brows around the iBUG-68 landmark vertices if given.

    Returns
    -------
    (n, 3) uint8
    """
    V = np.asarray(vertices, dtype=np.float64)
    rng = np.random.default_rng(seed)
    extent = float(np.ptp(V, axis=0).max()) or 1.0
    X = (V - V.mean(axis=0)) / extent
    k = rng.normal(size=(24, 3)) * rng.uniform(2 * np.pi / 0.3, 2 * np.pi / 0.05, (24, 1)) \
        / np.sqrt(3)
    feats = np.cos(X @ k.T + rng.uniform(0, 2 * np.pi, 24))  # (n, 24)
    tone = feats @ rng.normal(size=24)
    tone /= max(float(tone.std()), 1e-9)
    col = np.array(SKIN_RGB, np.float64) + 18.0 * tone[:, None] * [1.0, 0.85, 0.8]
    if landmarks is not None and len(landmarks) == 68:
        L = V[np.asarray(landmarks)]
        r = 0.025 * extent
        for idx, colour in ((range(17, 27), (95, 65, 50)), (range(48, 68), (170, 80, 80)),
                            (range(36, 48), (60, 45, 40))):
            d = np.min(np.linalg.norm(V[:, None] - L[list(idx)][None], axis=2), axis=1)
            a = np.exp(-0.5 * (d / r) ** 2)[:, None]
            col = col * (1 - a) + np.array(colour) * a
    return np.clip(np.rint(col), 0, 255).astype(np.uint8)


def procedural_background(size: tuple[int, int], *, seed: int = 0) -> np.ndarray:
    """A textured still background ``(H, W, 3) uint8``: a colour gradient, soft blobs and
    band-limited noise, in hues unlike skin so the face stands out."""
    import cv2

    W, H = size
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    c0, c1 = rng.uniform(40, 120, 3), rng.uniform(60, 160, 3)
    c0[2] += 40  # bluish/greenish
    g = (xx / max(W - 1, 1) * 0.6 + yy / max(H - 1, 1) * 0.4)[..., None]
    img = c0 * (1 - g) + c1 * g
    for _ in range(12):
        cx, cy = rng.uniform(0, W), rng.uniform(0, H)
        rad = rng.uniform(0.04, 0.18) * max(W, H)
        col = rng.uniform(20, 200, 3)
        a = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * rad ** 2))[..., None]
        img = img * (1 - 0.6 * a) + col * 0.6 * a
    img += 14.0 * _band_noise((H, W), rng, sigmas=(1.5, 5.0))[..., None]
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.7)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def load_texture_image(path: str | os.PathLike) -> np.ndarray:
    """Read a UV texture image file as ``(H, W, 3) uint8`` RGB.

    Raises
    ------
    AssetError
        The file is missing or is not an image OpenCV can read.
    """
    import cv2

    p = Path(path)
    if not p.is_file():
        raise AssetError(f"texture image {p} does not exist")
    from .io.frame_file import read_image

    img = read_image(p, cv2.IMREAD_COLOR)
    if img is None or img.ndim != 3 or img.shape[2] != 3:
        raise AssetError(f"texture {p} is not an image OpenCV can read")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# --------------------------------------------------------------------------------------------
# Clips and truth
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SyntheticTruth(_Posed):
    """Ground truth of a synthetic clip, per frame.

    Attributes
    ----------
    fps : float
    frame_size : (W, H)
    rotation : (F, 3, 3) float64
    scale : (F,) float64
    translation : (F, 2) float64
        Weak-perspective pose of Eq. (7): ``p = s diag(1, -1) R[:2] X + t``.
    weights : dict mode -> (F, r_k) float64
    landmarks2d : (F, 68, 2) float64
        Projected model landmark vertices (``(F, 0, 2)`` if the model has none).
    vertices2d : (F, n, 2) float64
        Every model vertex in pixels.
    visible : (F, n) bool
        Per-vertex visibility (:func:`facetransfer.render.vertex_visibility`).
    landmark_indices : (68,) int64 or (0,)
    meta : dict
        Model hash, performance spec, seed.
    path : str
        The file it was read from ('' if made in memory; not saved).
    """

    fps: float
    frame_size: tuple[int, int]
    rotation: np.ndarray
    scale: np.ndarray
    translation: np.ndarray
    weights: dict[str, np.ndarray]
    landmarks2d: np.ndarray
    vertices2d: np.ndarray
    visible: np.ndarray
    landmark_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    meta: dict = field(default_factory=dict)
    path: str = ""

    @property
    def model_hash(self) -> str:
        """Content hash of the model the clip was rendered with ('' if not recorded)."""
        return str(self.meta.get("model_hash") or "")

    def check_model(self, model) -> None:
        """Raise :class:`TrackError` unless ``model`` is the one the clip was rendered with:
        the same modes and ranks, and the content hash where the truth records it."""
        ours = {m: int(w.shape[1]) for m, w in self.weights.items()}
        theirs = dict(zip(model.mode_names, (int(r) for r in model.ranks)))
        if ours != theirs or self.model_hash not in ("", model.content_hash):
            raise TrackError(f"ground truth {self.path or '(in memory)'} was rendered with "
                             f"another model (modes and ranks {ours}, the model's {theirs}"
                             + (", the same but another content hash" if ours == theirs else "")
                             + "): give the model synth-video used as --model")


@dataclass(frozen=True, eq=False)
class SyntheticClip:
    """Frames ``(F, H, W, 3) uint8`` RGB and their :class:`SyntheticTruth`."""

    frames: np.ndarray
    truth: SyntheticTruth


def _appearance(model, texture, colors, seed: int):
    """(uvs, texture, colors) to render the model with; procedural if nothing given."""
    if texture is not None:
        if model.uvs is None:
            raise SpecError("a texture needs a model with UVs; this model has none")
        return model.uvs, texture, None
    if colors is not None:
        return None, None, colors
    if model.uvs is not None:
        lm_uv = model.uvs[model.landmarks] if model.landmarks is not None else None
        return model.uvs, procedural_skin_texture(landmarks_uv=lm_uv, seed=seed), None
    V = model.synthesize(model.default_weights())
    return None, None, procedural_vertex_colors(V, landmarks=model.landmarks, seed=seed)


def _background_image(background, size, seed: int) -> np.ndarray:
    """The clip's background (H, W, 3) uint8: procedural unless a colour or image is given."""
    if background is None:
        return procedural_background(size, seed=seed + 1)
    return background_image(background, *size, error=SpecError)


def _iter_render(model, perf: Performance, *, texture=None, colors=None, background=None,
                 seed: int = 0, progress: Callable[[int], None] | None = None):
    """Yield ``(frame, vertices2d, visible)`` per frame of the performance."""
    uvs, tex, col = _appearance(model, texture, colors, seed)
    bg = _background_image(background, perf.size, seed)
    for f in range(perf.n_frames):
        V = model.synthesize(perf.frame_weights(f))  # Eq. (5)
        cam = perf.camera(f)
        res = render(V, model.faces, cam, perf.size, uvs=uvs, texture=tex, colors=col,
                     light=LIGHT, ambient=AMBIENT, background=bg)
        yield res.image, cam.project(V), res.visible
        if progress is not None:
            progress(1)


def _truth(model, perf: Performance, v2d: list, vis: list, seed: int) -> SyntheticTruth:
    V2 = np.stack(v2d)
    lm = np.asarray(model.landmarks if model.landmarks is not None else [], np.int64)
    meta = {"model_hash": getattr(model, "content_hash", None), "performance": perf.spec,
            "seed": int(seed), "mode_names": list(model.mode_names)}
    return SyntheticTruth(perf.fps, tuple(perf.size), perf.rotation.copy(), perf.scale.copy(),
                          perf.translation.copy(), {m: w.copy() for m, w in perf.weights.items()},
                          V2[:, lm], V2, np.stack(vis), lm, meta)


def make_clip(model, performance: Performance, *, texture: np.ndarray | None = None,
              colors: np.ndarray | None = None, background=None, seed: int = 0,
              progress: Callable[[int], None] | None = None) -> SyntheticClip:
    """Render a performance into frames held in memory, with the exact truth.

    Parameters
    ----------
    model : MultilinearModel
    performance : Performance
        From :func:`performance_from_spec`, :func:`load_performance` or
        :func:`random_performance`.
    texture : (Ht, Wt, 3) uint8, optional
        UV texture (needs ``model.uvs``); default: :func:`procedural_skin_texture` if the model
        has UVs, else :func:`procedural_vertex_colors`.
    colors : (n, 3) uint8, optional
        Per-vertex colours instead of a texture.
    background : (H, W, 3) uint8 or (3,) colour, optional
        Default :func:`procedural_background`.
    seed : int
        Seed of the procedural texture and background.
    progress : callable(int), optional
        Called with 1 after every frame (e.g. ``tqdm.update``).

    Returns
    -------
    SyntheticClip
    """
    frames, v2d, vis = [], [], []
    for img, xy, v in _iter_render(model, performance, texture=texture, colors=colors,
                                   background=background, seed=seed, progress=progress):
        frames.append(img)
        v2d.append(xy)
        vis.append(v)
    return SyntheticClip(np.stack(frames), _truth(model, performance, v2d, vis, seed))


def truth_path(video_path: str | os.PathLike) -> Path:
    """``CLIP.mp4`` -> ``CLIP.truth.npz`` (same folder and base name)."""
    p = Path(video_path)
    return p.with_name(p.stem + ".truth.npz")


def _save_truth(truth: SyntheticTruth, path: Path) -> None:
    arrays = {"fps": np.float64(truth.fps), "frame_size": np.asarray(truth.frame_size, np.int64),
              "rotation": truth.rotation, "scale": truth.scale, "translation": truth.translation,
              "landmarks2d": truth.landmarks2d, "vertices2d": truth.vertices2d,
              "visible": truth.visible, "landmark_indices": truth.landmark_indices,
              "meta": np.array(json.dumps(truth.meta, default=str))}
    for mode, w in truth.weights.items():
        arrays[f"weights_{mode}"] = w      # a track's layout (files before: weights__<mode>)
    np.savez_compressed(path, **arrays)


def load_truth(path: str | os.PathLike) -> SyntheticTruth:
    """Read ``CLIP.truth.npz`` (or the truth beside ``CLIP.mp4``)."""
    p = Path(path)
    if p.suffix.lower() != ".npz":
        p = truth_path(p)
    from .truth_check import check_truth

    z = read_npz(p, "ground-truth file", VideoError)
    try:
        meta = json.loads(str(z["meta"]))
        weights = {k[len("weights_"):].lstrip("_"): z[k] for k in z if k.startswith("weights_")}
        order = meta["mode_names"] if "mode_names" in meta else list(weights)
        weights = {m: weights[m] for m in order if m in weights}
        size = tuple(int(v) for v in np.ravel(z["frame_size"]))
        return check_truth(SyntheticTruth(float(z["fps"]), size,
                                          z["rotation"], z["scale"], z["translation"], weights,
                                          z["landmarks2d"], z["vertices2d"], z["visible"],
                                          z["landmark_indices"], meta, str(p)))
    except (KeyError, ValueError, OSError, TypeError, OverflowError) as exc:
        raise VideoError(f"ground-truth file {p} is not a facetransfer truth file: {exc}") from None


def write_clip(clip: SyntheticClip, path: str | os.PathLike, *,
               overwrite: bool = True, options=None) -> tuple[Path, Path]:
    """Write ``clip`` as a video (:class:`facetransfer.io.video.VideoWriter`: H.264 unless
    ``options`` say otherwise) and its truth beside it, both atomically.

    Returns
    -------
    (video_path, truth_path)
    """
    from .io.video import VideoWriter

    video = check_output_path(path, overwrite=overwrite)
    tpath = truth_path(video)
    with atomic_path(tpath, overwrite=overwrite) as tmp:
        _save_truth(clip.truth, tmp)
        with VideoWriter(video, clip.truth.fps, clip.truth.frame_size, overwrite=overwrite,
                         options=options) as w:
            for frame in clip.frames:
                w.write(frame)
    return video, tpath


def synthesize_video(model, performance: Performance, path: str | os.PathLike, *,
                     texture: np.ndarray | None = None, colors: np.ndarray | None = None,
                     background=None, seed: int = 0, overwrite: bool = True,
                     progress: Callable[[int], None] | None = None,
                     options=None) -> SyntheticTruth:
    """Render a performance straight to ``path`` (frames streamed, not held in memory) and
    write the truth beside it; both atomic. Arguments as :func:`make_clip`; ``options``: the
    codec (:class:`facetransfer.io.video.VideoOptions`)."""
    from .io.video import VIDEO_SUFFIXES, VideoWriter

    video = check_output_path(path, overwrite=overwrite)
    if video.suffix.lower() not in VIDEO_SUFFIXES:
        raise VideoError(f"video output {video} must end in {', '.join(VIDEO_SUFFIXES)}")
    tpath = truth_path(video)
    v2d, vis = [], []
    with atomic_path(tpath, overwrite=overwrite) as tmp:
        with VideoWriter(video, performance.fps, performance.size, overwrite=overwrite,
                         options=options) as w:
            for img, xy, v in _iter_render(model, performance, texture=texture, colors=colors,
                                           background=background, seed=seed, progress=progress):
                w.write(img)
                v2d.append(xy)
                vis.append(v)
            truth = _truth(model, performance, v2d, vis, seed)
            _save_truth(truth, tmp)
    return truth

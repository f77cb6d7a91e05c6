"""Gaze from MediaPipe's iris centres: each eye's direction in the head's frame (beyond the paper).

The face model has no eyeballs, so the 2-D fit sees gaze only through the eyelids. Face
Landmarker also places each iris centre (points 468: the subject's right eye, 473: the left),
and the tracked pose says how the head is turned. A simple eyeball per eye turns the two into
gaze angles:

- the iris at rest (looking straight ahead, along the head's +z) sits at :data:`IRIS_REST` from
  the midpoint of the eye's corners (iBUG 36/39, 42/45 of the tracked face), scaled by the
  eye's width;
- the eyeball turns about a centre :data:`EYE_RADIUS` behind that rest point, so the iris
  centre is ``c + r d`` for a unit gaze direction ``d``;
- the camera is the tracker's weak perspective ``p = s F R[:2] X + t`` (Eq. (7), ``F = diag(1,
  -1)``): ``R[:2] d = (F (p - t) / s - R[:2] c) / r`` gives ``R d`` up to the depth component,
  which is the root toward the camera (a visible iris). One closed form per frame and eye,
  vectorised over frames.
  :func:`frame_gaze_activations` is the same for one frame, compiled (the capture fit asks at
  every pose step).

The iris sits in front of the eye corners, so on a turned head its 2-D offset from the corners
moves although the eye does not: the pose takes that out (a naive 2-D offset is biased by about
``sin(yaw) * 0.55 cm``, 0.1 eye width at 30° yaw).

While the lids close the detector's iris slides down with them: :func:`usable_iris` finds
those frames (a dip of the lid gap) and bridges the iris over them.

Angles are in radians, ``yaw`` positive toward the subject's left (the model's +x), ``pitch``
positive up (+y): directions in the head's frame, not rotations (the head's own pitch,
:mod:`facetransfer.render.cameras`, is positive looking *down*; its yaw has this sign).
:func:`gaze_activations` maps them to ARKit's ``eyeLook*`` coefficients (``Left`` = the
subject's own left eye, ``Out`` = toward that eye's ear).

References
----------
ICT-FaceKit ``generic_neutral_mesh.obj`` (eye geometry measured there, see the constants);
the Gullstrand schematic eye (entrance pupil ~3.0 mm behind the cornea) and the eye's centre of
rotation ~13.5 mm behind the cornea (Fry & Hill 1962); MediaPipe Face Landmarker (iris points).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError

try:  # numba is a dependency; the fallback keeps the module importable while it compiles
    from numba import njit
except ImportError:  # pragma: no cover
    def njit(*a, **k):
        return (lambda f: f) if not (a and callable(a[0])) else a[0]

__all__ = ["EyeModel", "eye_model", "gaze_angles", "frame_gaze_activations", "gaze_direction",
           "project_iris", "running_median", "usable_iris",
           "GazeOptions", "gaze_activations", "activation_gaze", "GAZE_NAMES", "IRIS_INDEX",
           "CORNER_INDEX"]

#: Eyes in this module's order: the subject's right eye, then the left.
EYES = ("Right", "Left")
#: iBUG-68 (outer, inner) corners of each eye, in :data:`EYES` order.
CORNER_INDEX = ((36, 39), (45, 42))
#: MediaPipe's iris centres (the subject's right eye, the left), of the 478 points.
IRIS_INDEX = (468, 473)
#: MediaPipe's eye corners (outer, inner) matching :data:`CORNER_INDEX`.
MP_CORNER_INDEX = ((33, 133), (263, 362))
#: MediaPipe's mid upper and lower lid points of each eye (:data:`EYES` order).
MP_LID_INDEX = ((159, 145), (386, 374))

#: Corner distance (inner to outer, 3-D) of FaceKit's generic neutral eye, cm (landmarks 42, 45).
FACEKIT_EYE_WIDTH = 2.687
#: Iris centre at rest minus the corners' midpoint, cm, for the left eye (+x = outward; the
#: right eye mirrors x): the centre of the pupil vertices (those PupilDilate_L moves) of
#: FaceKit's generic neutral eyeball, (3.29, 3.62, 9.45), against landmarks 42/45's midpoint
#: (3.15, 3.34, 8.90). 0.55 cm in front of the corners.
IRIS_REST = (0.14, 0.27, 0.55)
#: Centre of rotation to the iris centre as seen (the entrance pupil), cm: 13.5 mm (centre of
#: rotation behind the cornea, Fry & Hill 1962) - 3.0 mm (entrance pupil, Gullstrand).
EYE_RADIUS = 1.05


@dataclass(frozen=True)
class EyeModel:
    """Both eyeballs in the head's (model) frame.

    Attributes
    ----------
    centre : (2, 3) float64
        Centres of rotation, :data:`EYES` order.
    radius : (2,) float64
        Centre to iris centre.
    """

    centre: np.ndarray
    radius: np.ndarray


def eye_model(points68: np.ndarray, *, rest: tuple = IRIS_REST,
              radius: float = EYE_RADIUS) -> EyeModel:
    """Eyeballs placed behind the eye corners of a face.

    Parameters
    ----------
    points68 : (68, 3) float
        The iBUG-68 landmark vertices of the tracked face (a frame's fit or the neutral), in the
        model's units (cm).
    rest : (3,) float
        Iris at rest minus the corners' midpoint for the left eye at FaceKit's eye width
        (:data:`IRIS_REST`); x mirrors for the right eye, all scale with the eye's width.
    radius : float
        Centre of rotation to iris at FaceKit's eye width (:data:`EYE_RADIUS`).

    Returns
    -------
    EyeModel
    """
    P = np.asarray(points68, np.float64)
    if P.shape != (68, 3):
        raise ShapeError(f"eye_model needs (68, 3) landmark vertices, got {P.shape}")
    centres, radii = [], []
    for k, (o, i) in enumerate(CORNER_INDEX):
        k_scale = np.linalg.norm(P[o] - P[i]) / FACEKIT_EYE_WIDTH
        off = np.array(rest, np.float64) * k_scale
        off[0] *= 1.0 if EYES[k] == "Left" else -1.0
        iris = (P[o] + P[i]) / 2 + off
        centres.append(iris - np.array([0.0, 0.0, radius * k_scale]))
        radii.append(radius * k_scale)
    return EyeModel(np.stack(centres), np.array(radii))


def gaze_direction(angles: np.ndarray) -> np.ndarray:
    """Unit gaze directions in the head's frame, ``(..., 2) [yaw, pitch] -> (..., 3)``:
    ``(sin yaw cos pitch, sin pitch, cos yaw cos pitch)``; radians, yaw positive toward the
    subject's left (+x), pitch positive up (+y)."""
    a = np.asarray(angles, np.float64)
    y, p = a[..., 0], a[..., 1]
    return np.stack([np.sin(y) * np.cos(p), np.sin(p), np.cos(y) * np.cos(p)], -1)


def _angles(d: np.ndarray) -> np.ndarray:
    """Inverse of :func:`gaze_direction`, ``(..., 3) -> (..., 2)`` ``[yaw, pitch]`` in radians
    (the module's signs)."""
    return np.stack([np.arctan2(d[..., 0], d[..., 2]),
                     np.arctan2(d[..., 1], np.hypot(d[..., 0], d[..., 2]))], -1)


def project_iris(eyes: EyeModel, angles: np.ndarray, R: np.ndarray, s: np.ndarray,
                 t: np.ndarray) -> np.ndarray:
    """Image positions of the iris centres for given gaze (the forward model of
    :func:`gaze_angles`).

    Parameters
    ----------
    eyes : EyeModel
    angles : (F, 2, 2) float
        ``[frame, eye, (yaw, pitch)]``, radians (yaw > 0 toward the subject's left, pitch > 0
        up).
    R : (F, 3, 3), s : (F,), t : (F, 2)
        Weak-perspective pose per frame.

    Returns
    -------
    (F, 2, 2) float64
        Pixels, ``[frame, eye, (x, y)]``.
    """
    X = eyes.centre[None] + eyes.radius[None, :, None] * gaze_direction(angles)   # (F, 2, 3)
    Y = np.einsum("fij,fej->fei", np.asarray(R, np.float64)[:, :2], X)
    Y = Y * np.asarray(s, np.float64)[:, None, None]
    Y[..., 1] *= -1.0
    return Y + np.asarray(t, np.float64)[:, None, :]


def gaze_angles(eyes: EyeModel, iris: np.ndarray, R: np.ndarray, s: np.ndarray,
                t: np.ndarray) -> np.ndarray:
    """Each eye's gaze from its iris centre in the image, given the head's pose (closed form).

    Parameters
    ----------
    eyes : EyeModel
    iris : (F, 2, 2) float
        Iris centres in pixels, ``[frame, eye (EYES order), (x, y)]``; NaN where unknown.
    R : (F, 3, 3) float
        Head rotation per frame.
    s : (F,) float
        Pixels per model unit.
    t : (F, 2) float
        Translation, pixels.

    Returns
    -------
    (F, 2, 2) float64
        ``[frame, eye, (yaw, pitch)]`` in radians in the head's frame (yaw > 0 toward the
        subject's left, pitch > 0 up); NaN where ``iris`` is. An
        iris farther from the centre's image than the radius allows is taken on the eyeball's
        silhouette (gaze perpendicular to the view).
    """
    p = np.asarray(iris, np.float64)
    R = np.asarray(R, np.float64)
    s = np.asarray(s, np.float64)
    if p.ndim != 3 or p.shape[1:] != (2, 2) or R.shape != (len(p), 3, 3):
        raise ShapeError(f"gaze_angles needs iris (F, 2, 2) and R (F, 3, 3), got {p.shape} "
                         f"and {R.shape}")
    q = (p - np.asarray(t, np.float64)[:, None, :]) / s[:, None, None]
    q[..., 1] *= -1.0                                                     # F^-1 = F
    q = (q - np.einsum("fij,ej->fei", R[:, :2], eyes.centre)) / eyes.radius[None, :, None]
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(n > 1.0, q / np.maximum(n, 1e-300), q)
    ez = np.sqrt(np.clip(1.0 - np.sum(q * q, axis=-1, keepdims=True), 0.0, None))
    e = np.concatenate([q, ez], -1)                                       # R d, camera frame
    d = np.einsum("fji,fej->fei", R, e)                                   # R^T e
    return _angles(d)


def running_median(x: np.ndarray, size: int) -> np.ndarray:
    """The running median of ``x`` over ``size`` samples, the ends continued by their values.

    ``out[i]`` is the element of rank ``size // 2`` (from 0, ascending) among
    ``x[i - size // 2 .. i - size // 2 + size - 1]``, indices clipped to ``x`` (its first and
    last values repeated): ``scipy.ndimage.median_filter(x, size=size, mode="nearest")`` to the
    bit for finite ``x`` (an even ``size`` takes the upper of the two middle values, as SciPy
    does; an empty ``x`` gives an empty result, as SciPy's), without importing ``scipy.ndimage``
    (0.06 CPU-s in a tracking process, which needs nothing else of it). A NaN ranks above every
    number here (NumPy's sort order); SciPy's result beside a NaN depends on where it sits, so
    it is no reference there (:func:`usable_iris` fills the NaN first).

    Parameters
    ----------
    x : (F,) float
    size : int
        Samples in the window, >= 1.

    Returns
    -------
    (F,) float
    """
    x = np.asarray(x)
    size = int(size)
    if x.ndim != 1 or size < 1:
        raise ShapeError(f"running_median needs a 1-D array and a window >= 1, got {x.shape}, "
                         f"{size}")
    if not x.size:       # np.pad cannot continue the ends of nothing
        return x.copy()
    h = size // 2
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(x, (h, size - 1 - h), "edge"), size)
    return np.partition(windows, h, axis=1)[:, h]


def usable_iris(points478: np.ndarray, *, open_fraction: float = 0.75, window: int = 31,
                max_gap: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """The iris centres of a clip, bridged over frames where the lids hide the iris.

    While the lids close (a blink, a squint) the detector's iris centre slides with them, which
    would read as a downward gaze. An eye whose lid gap (mid upper to mid lower lid, / corner
    distance) is below ``open_fraction`` of its running median over ``window`` frames is
    closed (a blink is a dip; looking down, which lowers the lids for longer, is not): there the
    iris's offset from the eye corners' midpoint is interpolated linearly from the open frames
    around (at most ``max_gap`` frames away), so the gaze holds through a blink.

    Parameters
    ----------
    points478 : (F, 478, 2) float
        Face Landmarker's points per frame, NaN where no face was found.
    open_fraction : float
        Fraction of the running median lid gap below which an eye counts as closed.
    window : int
        Frames of the running median (odd).
    max_gap : int
        Farthest open frame (frames) a closed one is bridged from (0: none).

    Returns
    -------
    iris : (F, 2, 2) float64
        ``[frame, eye (EYES order), (x, y)]``, NaN where unknown.
    closed : (F, 2) bool
        Where the eye is closed (``iris`` bridged there, or NaN).
    """
    P = np.asarray(points478, np.float64)
    if P.ndim != 3 or P.shape[1] <= max(IRIS_INDEX) or P.shape[2] != 2:
        raise ShapeError(f"usable_iris needs (F, 478, 2) points, got {P.shape}")
    iris = P[:, list(IRIS_INDEX)].copy()
    closed = np.zeros((len(P), 2), bool)
    f = np.arange(len(P))
    for k, ((o, i), (u, lo)) in enumerate(zip(MP_CORNER_INDEX, MP_LID_INDEX)):
        gap = np.linalg.norm(P[:, u] - P[:, lo], axis=1) / np.linalg.norm(P[:, o] - P[:, i], axis=1)
        ok = np.isfinite(gap) & np.isfinite(iris[:, k]).all(1)
        if not ok.any():
            continue
        base = running_median(np.where(ok, gap, np.median(gap[ok])), int(window))
        is_open = ok & (gap >= open_fraction * base)
        closed[:, k] = ok & ~is_open
        mid = (P[:, o] + P[:, i]) / 2
        d = iris[:, k] - mid
        iris[~is_open, k] = np.nan
        good = np.flatnonzero(is_open)
        if not len(good) or max_gap <= 0:
            continue
        j = np.searchsorted(good, f)
        near = np.minimum(np.abs(good[np.clip(j, 0, len(good) - 1)] - f),
                          np.abs(good[np.clip(j - 1, 0, len(good) - 1)] - f))
        fill = closed[:, k] & (near <= max_gap)
        for c in range(2):
            iris[fill, k, c] = mid[fill, c] + np.interp(f[fill], good, d[good, c])
    return iris, closed


#: ARKit's eyeLook* names this module writes.
GAZE_NAMES = tuple(f"eyeLook{k}{e}" for e in ("Left", "Right")
                   for k in ("Down", "In", "Out", "Up"))


@dataclass(frozen=True)
class GazeOptions:
    """How gaze angles become ARKit activations.

    Apple does not say which angle an eyeLook* of 1 means. The defaults match Face Landmarker's
    own blendshapes: on the 4 real clips of ``benchmarks/bench_capture.py`` the regression of
    our angle on its ``eyeLookOut - eyeLookIn`` is 34-36° per unit (median per eye), on
    ``eyeLookUp - eyeLookDown`` 26-30° per unit.

    Attributes
    ----------
    horizontal : float
        Yaw (radians) that means activation 1 for eyeLookIn/Out.
    vertical : float
        Pitch (radians) that means activation 1 for eyeLookUp/Down.
    """

    horizontal: float = float(np.deg2rad(35.0))
    vertical: float = float(np.deg2rad(28.0))


def gaze_activations(angles: np.ndarray, options: GazeOptions | None = None,
                     closed: np.ndarray | None = None) -> dict:
    """ARKit eyeLook* activations in [0, 1] from gaze angles.

    Parameters
    ----------
    angles : (F, 2, 2) float
        From :func:`gaze_angles` (``[frame, eye (right, left), (yaw, pitch)]``, radians, yaw
        > 0 toward the subject's left, pitch > 0 up).
    options : GazeOptions
    closed : (F, 2) bool, optional
        Eyes whose lids are closed (:func:`usable_iris`): their Up/Down are NaN (e.g. for a
        fit that gives a closed eye's lids to the blink), their In/Out kept.

    Returns
    -------
    dict of str -> (F,) float64
        One entry per name of :data:`GAZE_NAMES`; NaN where the angles are. Looking toward the
        subject's left (yaw > 0) is ``eyeLookOutLeft`` and ``eyeLookInRight``.
    """
    opt = options or GazeOptions()
    a = np.asarray(angles, np.float64)
    out = {}
    for k, eye in enumerate(EYES):
        h = a[:, k, 0] / opt.horizontal * (1.0 if eye == "Left" else -1.0)   # + = outward
        v = a[:, k, 1] / opt.vertical
        if closed is not None:
            v = np.where(np.asarray(closed)[:, k], np.nan, v)
        for name, x in (("Out", h), ("In", -h), ("Up", v), ("Down", -v)):
            out[f"eyeLook{name}{eye}"] = np.where(np.isfinite(x), np.clip(x, 0.0, 1.0), np.nan)
    return out


def activation_gaze(activations: np.ndarray, options: GazeOptions | None = None) -> np.ndarray:
    """Gaze angles from ARKit eyeLook* activations: the inverse of :func:`gaze_activations`
    where the activations are inside (0, 1) (one of each eye's In/Out and Up/Down pair is 0).

    Parameters
    ----------
    activations : (F, 52) float
        In :data:`facetransfer.arkit.ARKIT_NAMES` order.
    options : GazeOptions

    Returns
    -------
    (F, 2, 2) float64
        ``[frame, eye (right, left), (yaw, pitch)]`` in radians, this module's convention
        (yaw positive toward the subject's left, pitch positive up).
    """
    from ..arkit import ARKIT_NAMES

    opt = options or GazeOptions()
    a = np.asarray(activations, np.float64)
    if a.ndim != 2 or a.shape[1] != len(ARKIT_NAMES):
        raise ShapeError(f"activations must be (F, {len(ARKIT_NAMES)}), got shape {a.shape}")
    col = {n: a[:, ARKIT_NAMES.index(n)] for n in GAZE_NAMES}
    out = np.zeros((len(a), 2, 2))
    for k, eye in enumerate(EYES):
        outward = col[f"eyeLookOut{eye}"] - col[f"eyeLookIn{eye}"]
        out[:, k, 0] = outward * opt.horizontal * (1.0 if eye == "Left" else -1.0)
        out[:, k, 1] = (col[f"eyeLookUp{eye}"] - col[f"eyeLookDown{eye}"]) * opt.vertical
    return out


def frame_gaze_activations(points68: np.ndarray, iris: np.ndarray, closed: np.ndarray,
                           R: np.ndarray, s: float, t: np.ndarray,
                           options: GazeOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One frame's eyeLook* activations: :func:`eye_model`, :func:`gaze_angles` and
    :func:`gaze_activations` in one compiled step (the capture fit calls it at every pose step).

    Parameters
    ----------
    points68 : (68, 3) float64
        The tracked face's landmark vertices (only the eye corners are read).
    iris : (2, 2) float64
        Iris centres in pixels, :data:`EYES` order; NaN where unknown.
    closed : (2,) bool
        Eyes with closed lids (their Up/Down are NaN in ``held``).
    R : (3, 3), s : float, t : (2,)
        The head's weak-perspective pose (Eq. (7)).
    options : GazeOptions

    Returns
    -------
    free : (8,) float64
        ``gaze_activations(angles)`` in :data:`GAZE_NAMES` order.
    held : (8,) float64
        ``gaze_activations(angles, closed=closed)`` likewise.
    """
    P = np.asarray(points68, np.float64)
    if P.shape != (68, 3):
        raise ShapeError(f"frame_gaze_activations needs (68, 3) landmark vertices, got {P.shape}")
    opt = options or GazeOptions()
    corners = np.ascontiguousarray(P[np.array(CORNER_INDEX)])              # (eye, o/i, 3)
    out = _frame_gaze(corners, np.ascontiguousarray(iris, np.float64),
                      np.asarray(closed, np.bool_), np.ascontiguousarray(R, np.float64),
                      float(s), np.ascontiguousarray(t, np.float64),
                      np.asarray(IRIS_REST, np.float64), float(EYE_RADIUS),
                      float(opt.horizontal), float(opt.vertical))
    return out[0], out[1]


@njit(cache=True)
def _frame_gaze(corners, iris, closed, R, s, t, rest, radius, horizontal,
                vertical):  # pragma: no cover (compiled)
    """The per-frame body of eye_model, gaze_angles and gaze_activations: (2, 8) free, held."""
    out = np.full((2, 8), np.nan)
    for k in range(2):                                    # EYES: Right, Left
        sign = 1.0 if k == 1 else -1.0
        o, i = corners[k, 0], corners[k, 1]
        dc = o - i
        ks = np.sqrt(np.sum(dc * dc)) / FACEKIT_EYE_WIDTH
        centre = (o + i) / 2 + rest * ks * np.array([sign, 1.0, 1.0])     # eye_model
        centre[2] -= radius * ks
        q0 = (iris[k, 0] - t[0]) / s
        q1 = -((iris[k, 1] - t[1]) / s)                                   # F^-1 = F
        r = radius * ks
        q0 = (q0 - (R[0, 0] * centre[0] + R[0, 1] * centre[1] + R[0, 2] * centre[2])) / r
        q1 = (q1 - (R[1, 0] * centre[0] + R[1, 1] * centre[1] + R[1, 2] * centre[2])) / r
        n = np.sqrt(q0 * q0 + q1 * q1)
        if n > 1.0:
            q0, q1 = q0 / max(n, 1e-300), q1 / max(n, 1e-300)
        ez = np.sqrt(max(1.0 - (q0 * q0 + q1 * q1), 0.0)) if np.isfinite(n) else np.nan
        d0 = R[0, 0] * q0 + R[1, 0] * q1 + R[2, 0] * ez                    # Rᵀ e
        d1 = R[0, 1] * q0 + R[1, 1] * q1 + R[2, 1] * ez
        d2 = R[0, 2] * q0 + R[1, 2] * q1 + R[2, 2] * ez
        h = np.arctan2(d0, d2) / horizontal * sign                        # + = outward
        v = np.arctan2(d1, np.hypot(d0, d2)) / vertical
        col = 4 * (1 - k)                                                 # GAZE_NAMES: Left first
        for row in range(2):
            vv = np.nan if (row == 1 and closed[k]) else v
            for j, x in enumerate((-vv, -h, h, vv)):                      # Down, In, Out, Up
                if np.isfinite(x):
                    out[row, col + j] = min(max(x, 0.0), 1.0)
    return out

"""The cameras the renderer images meshes with (Vlasic et al. 2005, §5.1, Eq. (7)).

:class:`WeakPerspective` is the tracker's camera (``p = s diag(1, -1) R[:2] X + t``, depth
``(R X)[2]``, larger = nearer); :class:`Pinhole` is for previews. Also head rotations from
Euler angles and a camera that frames a mesh.

Head angles
-----------
A head rotation ``R`` (3, 3) maps model coordinates (x toward the subject's left, which is the
image's right; y up; z toward the camera) to camera coordinates. The package names its yaw,
pitch and roll in three orders. All three share the axes and the signs, with the right-hand
rule (``Rx(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]]``, and so on):

* yaw about y: positive turns the face toward the image's right (the subject's left);
* pitch about x: positive tips the top of the head toward the camera (the face looks down);
* roll about z: positive turns the face counter-clockwise in the image.

They differ in the order the three rotations are composed in and in the unit:

* **render angles**, ``R = Rz(roll) Ry(yaw) Rx(pitch)``, **degrees**: :func:`rotation_from_euler`
  and its inverse :func:`euler_from_rotation`; the previews (``facetransfer render --pose``),
  the synthetic footage of :mod:`facetransfer.synth`.
* **head angles**, ``R = Ry(yaw) Rx(pitch) Rz(roll)`` (intrinsic Y-X'-Z''), **radians**: ARKit's
  and Live Link Face's order (a take's ``HeadYaw`` and ``HeadRoll`` with the other sign:
  :data:`facetransfer.export.livelink.HEAD_SIGNS`); :func:`facetransfer.export.common.
  head_euler` and its inverse in :func:`facetransfer.take.take_track`; the viewer's sliders
  (in degrees there).
* **capture angles**, ``R = Rx(pitch) Ry(yaw) Rz(roll)``, **radians**: the capture tracker's
  (:mod:`facetransfer.track.capture`), which reads the sine of the yaw as ``R[0, 2]`` (the
  tracked points' view-dependent offset, :meth:`facetransfer.track.capture_points.Shape.at_view`)
  and rescales the pitch about the camera's x axis alone.

A rotation about one axis has the same angle in all three (up to the unit); a combined one does
not, so an angle moves between them only through the matrix (``head_euler(rotation_from_euler(
yaw, pitch, roll))``). The eyes' gaze angles (:mod:`facetransfer.track.gaze`) are directions,
not rotations: yaw with the head's sign, pitch positive *up*.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..errors import ShapeError
from ..jit import maybe_njit as _maybe_njit

__all__ = ["Camera", "WeakPerspective", "Pinhole", "rotation_from_euler", "euler_from_rotation",
           "look_at_weak_perspective", "project_frames"]


class Camera(Protocol):
    """What :func:`rasterize` needs from a camera."""

    rotation: np.ndarray
    perspective: bool

    def project(self, X: np.ndarray) -> np.ndarray: ...

    def depth(self, X: np.ndarray) -> np.ndarray: ...

    def to_camera(self, X: np.ndarray) -> np.ndarray: ...


#: ``np.allclose(R @ R.T, I, atol=1e-6)``'s bound per entry (``atol + rtol |I|``)
_ORTHONORMAL_TOL = 1e-6 + 1e-5 * np.eye(3)


def _as_rotation(R) -> np.ndarray:
    """``R`` as a (3, 3) float64 proper rotation; ShapeError otherwise. (The test of
    ``np.allclose`` written out, and the determinant's sign by the triple product: a camera
    is made several times a frame.)"""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise ShapeError(f"rotation must be a finite (3, 3) array, got shape {R.shape}")
    if not (np.abs(R @ R.T - np.eye(3)) <= _ORTHONORMAL_TOL).all() or _det3(R) < 0:
        raise ShapeError("rotation must be a proper rotation matrix (R R^T = I, det R = +1)")
    return R


def _det3(R: np.ndarray) -> float:
    """The determinant of a (3, 3) matrix, ``R[0] · (R[1] × R[2])``."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _as_vector(x, n: int, what: str) -> np.ndarray:
    """``x`` as a finite (n,) float64 array; ShapeError naming ``what`` otherwise."""
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ShapeError(f"{what} must be finite ({n},), got {a.shape}")
    return a


def _as_positive(x, what: str) -> float:
    """``x`` as a finite float > 0; ShapeError naming ``what`` otherwise."""
    v = float(x)
    if not np.isfinite(v) or v <= 0:
        raise ShapeError(f"{what} must be a finite number > 0, got {x}")
    return v


def _as_points(X) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ShapeError(f"points must be (n, 3), got {X.shape}")
    return X


def _pixels_py(Y, sx, tx, sy, ty, out):  # pragma: no cover (numba)
    """``out[:, 0] = sx * Y[:, 0] + tx`` and ``out[:, 1] = sy * Y[:, 1] + ty`` (``Y``, ``out``
    (n, 2) float64): :meth:`WeakPerspective.project`'s pixels from the rotated points, the
    numpy expressions' two roundings each, in one call (it projects 5 times a frame)."""
    for i in range(Y.shape[0]):
        out[i, 0] = sx * Y[i, 0] + tx
        out[i, 1] = sy * Y[i, 1] + ty


_pixels = _maybe_njit(_pixels_py)


@dataclass(frozen=True, eq=False)
class WeakPerspective:
    """The tracker's weak-perspective camera (Vlasic et al. 2005, §5.1, Eq. (7)).

    Attributes
    ----------
    scale : float
        ``s`` > 0, pixels per model unit.
    rotation : (3, 3) float64
        ``R``, model to camera rotation (camera looks along -z, y up).
    translation : (2,) float64
        ``t``, pixel position of the model origin (x right, y down).
    pixel_aspect : float
        ``a`` > 0, the width of a pixel over its height (a video's sample aspect ratio, as the
        frames were resampled to square pixels for tracking: :mod:`facetransfer.track.aspect`);
        a model unit spans ``s / a`` pixels across and ``s`` down: ``x = s (R X)_x / a + t_x``.
        1 for square pixels.
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    pixel_aspect: float = 1.0

    #: The projection does not divide by depth.
    perspective = False

    def __post_init__(self) -> None:
        s = _as_positive(self.scale, "camera scale")
        t = _as_vector(self.translation, 2, "weak-perspective translation")
        a = _as_positive(self.pixel_aspect, "camera pixel aspect")
        object.__setattr__(self, "pixel_aspect", a)
        object.__setattr__(self, "scale", s)
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        object.__setattr__(self, "translation", t)

    def shifted(self, dx: float, dy: float) -> "WeakPerspective":
        """The camera of the crop whose top-left pixel is ``(dx, dy)``: the translation less
        ``(dx, dy)`` (scale and rotation as they are, not checked again)."""
        out = object.__new__(WeakPerspective)
        object.__setattr__(out, "scale", self.scale)
        object.__setattr__(out, "pixel_aspect", self.pixel_aspect)
        object.__setattr__(out, "rotation", self.rotation)
        object.__setattr__(out, "translation",
                           self.translation - np.array([dx, dy], np.float64))
        return out

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """Rotated coordinates ``R @ X`` per point, (n, 3) -> (n, 3)."""
        return _as_points(X) @ self.rotation.T

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels ``s * diag(1 / a, -1) @ R[:2] @ X + t`` (Eq. (7); ``a`` the pixel aspect,
        1 for square pixels), (n, 3) -> (n, 2)."""
        Y = _as_points(X) @ self.rotation[:2].T  # (n, 2), C-contiguous: one compiled kernel
        out = np.empty_like(Y)
        # (s / a) Y_x + t_x and (-s) Y_y + t_y, the numpy expressions' operations in one call
        _pixels(Y, float(self.scale / self.pixel_aspect), float(self.translation[0]),
                float(-self.scale), float(self.translation[1]), out)
        return out

    def depth(self, X: np.ndarray) -> np.ndarray:
        """Depth ``(R @ X)[2]`` per point, larger = nearer, (n, 3) -> (n,)."""
        return _as_points(X) @ self.rotation[2]


def project_frames(X: np.ndarray, rotation: np.ndarray, scale: np.ndarray,
                   translation: np.ndarray, pixel_aspect: float = 1.0) -> np.ndarray:
    """``(k, m, 2)`` float64: the points ``X`` (k, m, 3) of k frames seen by their cameras,
    ``WeakPerspective(scale[i], rotation[i], translation[i], pixel_aspect).project(X[i])`` of
    each (Eq. (7)) in a few products for the k frames, bit for bit (each frame's rotation
    product the same BLAS call's; a camera object per frame, checked, cost as much as its
    projection: ~0.1 ms a frame).

    Parameters
    ----------
    X : (k, m, 3) float
    rotation : (k, 3, 3) float
    scale : (k,) float
    translation : (k, 2) float
    pixel_aspect : float

    Raises
    ------
    ShapeError
        The camera's own (:class:`WeakPerspective`) where a frame's is not one: not finite,
        a scale or pixel aspect not > 0, not a proper rotation.
    """
    R = np.asarray(rotation, np.float64)
    s, t = np.asarray(scale, np.float64), np.asarray(translation, np.float64)
    a = _as_positive(pixel_aspect, "camera pixel aspect")
    if not _proper_cameras(R, s, t):
        for i in range(len(R)):                 # the camera's own check says what is wrong
            WeakPerspective(s[i], R[i], t[i], a)
    Rt = np.ascontiguousarray(R[:, :2].transpose(0, 2, 1))               # (k, 3, 2)
    Y = np.matmul(np.ascontiguousarray(X, np.float64), Rt)              # (k, m, 2)
    # (s / a) Y_x + t_x and (-s) Y_y + t_y: the camera's roundings
    Y[..., 0] = (s / a)[:, None] * Y[..., 0] + t[:, 0, None]
    Y[..., 1] = (-s)[:, None] * Y[..., 1] + t[:, 1, None]
    return Y


def _proper_cameras(R: np.ndarray, s: np.ndarray, t: np.ndarray) -> bool:
    """Whether every camera ``(R[k], s[k], t[k])`` (k, 3, 3), (k,), (k, 2) passes
    :class:`WeakPerspective`'s checks (:func:`_as_rotation`, :func:`_as_positive`,
    :func:`_as_vector`): finite, a scale > 0, a proper rotation (``R R^T = I`` within
    :data:`_ORTHONORMAL_TOL`, a determinant > 0)."""
    if not (np.isfinite(R).all() and np.isfinite(t).all() and np.isfinite(s).all()
            and (s > 0).all()):
        return False
    RRt = np.matmul(R, R.transpose(0, 2, 1))
    return bool((np.abs(RRt - np.eye(3)) <= _ORTHONORMAL_TOL).all()
                and (np.linalg.det(R) > 0).all())


@dataclass(frozen=True, eq=False)
class Pinhole:
    """A pinhole camera for previews: camera coordinates ``Xc = R @ X + T``.

    The camera looks along -z of its coordinates with y up; a point in front has ``Xc_z < 0``
    and lands at pixel ``(cx + f Xc_x / -Xc_z, cy - f Xc_y / -Xc_z)``. Its depth is ``Xc_z``
    (larger = nearer, as for :class:`WeakPerspective`).

    Attributes
    ----------
    focal : float
        Focal length in pixels, > 0.
    center : (2,) float64
        Principal point ``(cx, cy)`` in pixels.
    rotation : (3, 3) float64
    translation : (3,) float64
    near : float
        Triangles with a vertex closer than ``near`` (camera units, > 0) are not drawn.
    """

    focal: float
    center: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    near: float = 1e-3

    perspective = True

    def __post_init__(self) -> None:
        f = float(self.focal)
        if not np.isfinite(f) or f <= 0:
            raise ShapeError(f"pinhole focal length must be finite and > 0, got {self.focal}")
        c = _as_vector(self.center, 2, "pinhole center")
        T = _as_vector(self.translation, 3, "pinhole translation")
        if not float(self.near) > 0:
            raise ShapeError(f"pinhole near distance must be > 0, got {self.near}")
        object.__setattr__(self, "focal", f)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "translation", T)
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        object.__setattr__(self, "near", float(self.near))

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """Camera coordinates ``R @ X + T`` per point, (n, 3) -> (n, 3)."""
        return _as_points(X) @ self.rotation.T + self.translation

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels (n, 2); points at or behind the camera plane give non-finite values."""
        Xc = self.to_camera(X)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = -Xc[:, 2]
            return np.stack([self.center[0] + self.focal * Xc[:, 0] / w,
                             self.center[1] - self.focal * Xc[:, 1] / w], axis=1)

    def depth(self, X: np.ndarray) -> np.ndarray:
        """Depth ``(R @ X + T)[2]`` per point, larger = nearer, (n, 3) -> (n,)."""
        return self.to_camera(X)[:, 2]


def rotation_from_euler(yaw_deg: float = 0.0, pitch_deg: float = 0.0,
                        roll_deg: float = 0.0) -> np.ndarray:
    """Head rotation from render angles in degrees: ``R = Rz(roll) @ Ry(yaw) @ Rx(pitch)``.

    Yaw turns about the model's vertical (y) axis, positive toward the image's right (the
    subject's left); pitch about x, positive tips the top of the head toward the camera (looks
    down); roll about the view (z) axis, positive counter-clockwise in the image (the
    right-hand rule; the module's "Head angles"). Returns a (3, 3) float64 rotation.
    """
    y, p, r = np.deg2rad([yaw_deg, pitch_deg, roll_deg])
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def euler_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_from_euler`: the render angles ``(yaw_deg, pitch_deg,
    roll_deg)`` of ``R = Rz(roll) Ry(yaw) Rx(pitch)``, in degrees, yaw in [-90, 90] (axes and
    signs: the module's "Head angles")."""
    R = _as_rotation(R)
    yaw = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    pitch = np.arctan2(R[2, 1], R[2, 2])
    roll = np.arctan2(R[1, 0], R[0, 0])
    return tuple(float(v) for v in np.rad2deg([yaw, pitch, roll]))


def look_at_weak_perspective(vertices: np.ndarray, size: tuple[int, int], *,
                             rotation: np.ndarray | None = None, fill: float = 0.8,
                             offset: tuple[float, float] = (0.0, 0.0)) -> WeakPerspective:
    """A weak-perspective camera that frames ``vertices`` in an image of ``size = (W, H)``.

    The rotated bounding box is centred (plus ``offset`` pixels) and scaled so that it fills
    ``fill`` of the smaller image side.
    """
    V = _as_points(vertices)
    R = np.eye(3) if rotation is None else _as_rotation(rotation)
    W, H = _as_size(size)
    Y = V @ R[:2].T
    lo, hi = Y.min(axis=0), Y.max(axis=0)
    extent = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-12))
    s = fill * min(W, H) / extent
    c = 0.5 * (lo + hi)
    t = np.array([(W - 1) / 2 - s * c[0] + offset[0], (H - 1) / 2 + s * c[1] + offset[1]])
    return WeakPerspective(s, R, t)


def _as_size(size) -> tuple[int, int]:
    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ShapeError(f"image size must be (width, height), got {size!r}") from None
    if W <= 0 or H <= 0 or W > 32768 or H > 32768:
        raise ShapeError(f"image size must be positive (width, height) <= 32768, got {size!r}")
    return W, H

"""Z-buffer rasterisation of triangle meshes under the tracker's cameras (paper §5.1, §6).

The tracker of Vlasic et al. (2005) images the face with a weak-perspective camera (§5.1,
Eq. (7)): a vertex ``X`` (model coordinates, y up, camera looking along -z) lands at the pixel

    p = s * diag(1, -1) @ R[:2] @ X + t                                         # Eq. (7)

with ``s`` pixels per model unit, ``R`` a rotation and ``t`` an image translation in pixels
(x right, y down; the centre of the top-left pixel is (0, 0)). The depth of a point is
``(R @ X)[2]``: larger is nearer the camera. A pinhole camera is provided for previews.

This module turns a mesh and a camera into

* a :class:`Raster`: per pixel the depth, the id of the nearest triangle and its barycentric
  coordinates (perspective-correct for the pinhole camera);
* per-vertex visibility (:func:`vertex_visibility`), which the tracker needs every frame to
  choose the vertices it follows and the texture lifting (§6) needs to weight samples;
* a colour image (:func:`render`) from per-vertex colours or a UV texture, optionally
  Lambert-shaded.

Rasterisation rule: a pixel centre ``(px, py)`` belongs to a triangle if it lies inside or on
the triangle's boundary (edge functions of one sign or zero). Among the triangles covering a
pixel the nearest wins; equal depths go to the lower triangle index. Triangles with zero
projected area are skipped silently (the edge-on ones of a face mesh). Two implementations obey
this rule exactly: a vectorised numpy reference (:func:`rasterize_reference`) and a numba kernel
(the default), which are tested to give identical pixels.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005,
§5.1 Eq. (7) (weak-perspective camera), §6 (texture lifting and rendering).
Pineda. A parallel algorithm for polygon rasterization. SIGGRAPH 1988 (edge functions).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .errors import AssetError, MeshError, ShapeError

log = logging.getLogger(__name__)

try:  # numba is a hard dependency; the fallback keeps the module importable without it
    import numba

    _HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    numba = None
    _HAVE_NUMBA = False

__all__ = [
    "WeakPerspective",
    "Pinhole",
    "Raster",
    "RenderResult",
    "RenderError",
    "rasterize",
    "Rasterizer",
    "rasterize_reference",
    "vertex_visibility",
    "vertex_normals",
    "render",
    "rotation_from_euler",
    "euler_from_rotation",
    "look_at_weak_perspective",
    "render_model",
    "sample_texture",
    "shade_texture",
]


class RenderError(MeshError):
    """A mesh, camera or texture that cannot be rendered."""


# --------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------

class Camera(Protocol):
    """What :func:`rasterize` needs from a camera."""

    rotation: np.ndarray
    perspective: bool

    def project(self, X: np.ndarray) -> np.ndarray: ...

    def depth(self, X: np.ndarray) -> np.ndarray: ...

    def to_camera(self, X: np.ndarray) -> np.ndarray: ...


def _as_rotation(R) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ShapeError(f"rotation must be a finite (3, 3) array, got shape {R.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ShapeError("rotation must be a proper rotation matrix (R R^T = I, det R = +1)")
    return R


def _as_points(X) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ShapeError(f"points must be (n, 3), got {X.shape}")
    return X


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
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    #: The projection does not divide by depth.
    perspective = False

    def __post_init__(self) -> None:
        s = float(self.scale)
        if not np.isfinite(s) or s <= 0:
            raise ShapeError(f"camera scale must be a finite number > 0, got {self.scale}")
        t = np.asarray(self.translation, dtype=np.float64)
        if t.shape != (2,) or not np.all(np.isfinite(t)):
            raise ShapeError(f"weak-perspective translation must be finite (2,), got {t.shape}")
        object.__setattr__(self, "scale", s)
        object.__setattr__(self, "rotation", _as_rotation(self.rotation))
        object.__setattr__(self, "translation", t)

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """Rotated coordinates ``R @ X`` per point, (n, 3) -> (n, 3)."""
        return _as_points(X) @ self.rotation.T

    def project(self, X: np.ndarray) -> np.ndarray:
        """Pixels ``s * diag(1, -1) @ R[:2] @ X + t`` (Eq. (7)), (n, 3) -> (n, 2)."""
        Y = _as_points(X) @ self.rotation[:2].T  # (n, 2)
        out = np.empty_like(Y)
        out[:, 0] = self.scale * Y[:, 0] + self.translation[0]
        out[:, 1] = -self.scale * Y[:, 1] + self.translation[1]
        return out

    def depth(self, X: np.ndarray) -> np.ndarray:
        """Depth ``(R @ X)[2]`` per point, larger = nearer, (n, 3) -> (n,)."""
        return _as_points(X) @ self.rotation[2]


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
        c = np.asarray(self.center, dtype=np.float64)
        T = np.asarray(self.translation, dtype=np.float64)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ShapeError(f"pinhole center must be finite (2,), got {c.shape}")
        if T.shape != (3,) or not np.all(np.isfinite(T)):
            raise ShapeError(f"pinhole translation must be finite (3,), got {T.shape}")
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
    """Head rotation from angles in degrees: ``R = Rz(roll) @ Ry(yaw) @ Rx(pitch)``.

    Yaw turns about the model's vertical (y) axis, pitch about x (nodding), roll about the view
    (z) axis; angles follow the right-hand rule. Returns a (3, 3) float64 rotation.
    """
    y, p, r = np.deg2rad([yaw_deg, pitch_deg, roll_deg])
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def euler_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_from_euler`: ``(yaw_deg, pitch_deg, roll_deg)``."""
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


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Raster:
    """Per-pixel result of rasterising a mesh.

    Attributes
    ----------
    depth : (H, W) float32
        Depth of the nearest surface (camera depth, larger = nearer); ``-inf`` on background.
    tri_id : (H, W) int32
        Index of the nearest triangle; -1 on background.
    bary : (H, W, 3) float32
        Barycentric coordinates in that triangle of the 3D surface point seen at the pixel
        centre (perspective-correct for :class:`Pinhole`); 0 on background.
    mask : (H, W) bool
        ``tri_id >= 0``.
    """

    depth: np.ndarray
    tri_id: np.ndarray
    bary: np.ndarray
    mask: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        """``(W, H)``."""
        return int(self.tri_id.shape[1]), int(self.tri_id.shape[0])


@dataclass(frozen=True, eq=False)
class RenderResult:
    """A rendered image with the raster behind it.

    Attributes
    ----------
    image : (H, W, 3) uint8 RGB
    raster : Raster
    visible : (n_vertices,) bool
        Per-vertex visibility (see :func:`vertex_visibility`).
    """

    image: np.ndarray
    raster: Raster
    visible: np.ndarray


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------

def _as_size(size) -> tuple[int, int]:
    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ShapeError(f"image size must be (width, height), got {size!r}") from None
    if W <= 0 or H <= 0 or W > 32768 or H > 32768:
        raise ShapeError(f"image size must be positive (width, height) <= 32768, got {size!r}")
    return W, H


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) float64 finite and faces (F, 3) int64 in range; rejects empty meshes."""
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ShapeError(f"vertices must be (n, 3), got {V.shape}")
    if V.shape[0] == 0:
        raise RenderError("cannot render an empty mesh (0 vertices)")
    if not np.all(np.isfinite(V)):
        raise RenderError("vertices contain NaN or infinite coordinates")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3:
        raise ShapeError(f"faces must be (F, 3), got {F.shape}")
    if F.shape[0] == 0:
        raise RenderError("cannot render a mesh with no faces (0 triangles)")
    if not np.issubdtype(F.dtype, np.integer):
        raise ShapeError(f"faces must be integer indices, got dtype {F.dtype}")
    F = np.ascontiguousarray(F, dtype=np.int64)
    lo, hi = int(F.min()), int(F.max())
    if lo < 0 or hi >= V.shape[0]:
        raise RenderError(f"faces index vertices {lo}..{hi} but the mesh has {V.shape[0]} vertices")
    return V, F


def _check_not_all_degenerate(V: np.ndarray, F: np.ndarray) -> None:
    """Reject a mesh whose triangles all have zero area in 3D."""
    scale = float(_bbox_diagonal(V))
    if scale == 0.0 or not _any_nondegenerate(V, F, (1e-12 * scale * scale) ** 2):
        raise RenderError(f"all {F.shape[0]} triangles are degenerate (zero area)")


def _any_nondegenerate_py(V, F, eps2):  # pragma: no cover
    """True as soon as one triangle has squared doubled area > eps2 (stops early)."""
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, az = V[i1, 0] - V[i0, 0], V[i1, 1] - V[i0, 1], V[i1, 2] - V[i0, 2]
        bx, by, bz = V[i2, 0] - V[i0, 0], V[i2, 1] - V[i0, 1], V[i2, 2] - V[i0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        if nx * nx + ny * ny + nz * nz > eps2:
            return True
    return False


# --------------------------------------------------------------------------------------------
# Rasterisation: shared setup
# --------------------------------------------------------------------------------------------

def _screen(V: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel positions (n, 2), depths (n,) and perspective weights q = 1/w (n,) of vertices.

    For the weak-perspective camera q = 1. For the pinhole camera q = 1 / (-Xc_z); vertices
    nearer than ``camera.near`` get q = 0, which marks their triangles as not drawable.
    """
    if not isinstance(camera, (WeakPerspective, Pinhole)) and not (
            hasattr(camera, "project") and hasattr(camera, "depth")
            and hasattr(camera, "rotation")):
        raise ShapeError(f"camera must be a WeakPerspective or Pinhole, got "
                         f"{type(camera).__name__}")
    if getattr(camera, "perspective", False):
        Xc = camera.to_camera(V)
        w = -Xc[:, 2]
        ok = w > camera.near
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(ok, 1.0 / np.where(ok, w, 1.0), 0.0)
            xy = np.stack([camera.center[0] + camera.focal * Xc[:, 0] * q,
                           camera.center[1] - camera.focal * Xc[:, 1] * q], axis=1)
        xy[~ok] = 0.0
        z = np.where(ok, Xc[:, 2], 0.0)
    else:
        xy = camera.project(V)
        z = camera.depth(V)
        q = np.ones(V.shape[0])
    return np.ascontiguousarray(xy), np.ascontiguousarray(z), np.ascontiguousarray(q)


def _empty_raster(W: int, H: int) -> Raster:
    return Raster(np.full((H, W), -np.inf, np.float32), np.full((H, W), -1, np.int32),
                  np.zeros((H, W, 3), np.float32), np.zeros((H, W), bool))


# --------------------------------------------------------------------------------------------
# numpy reference implementation
# --------------------------------------------------------------------------------------------

def _edges_np(x0, y0, x1, y1, x2, y2, px, py):
    """Edge functions of pixel centres; their sum is the signed double area (same op order as
    the numba kernel so both give bit-identical results)."""
    w0 = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)
    w1 = (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2)
    w2 = (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0)
    return w0, w1, w2


def _tri_setup_np(xy, q, F, W, H, cull):
    """Per-triangle signed area, drawability and clipped pixel bounding box."""
    x = xy[:, 0][F]  # (F, 3)
    y = xy[:, 1][F]
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
    ok = (area != 0) & np.isfinite(area) & np.all(q[F] > 0, axis=1)
    if cull:
        ok &= area < 0  # front-facing: counter-clockwise seen from the camera (y up) -> area < 0
    xmin = np.maximum(np.ceil(x.min(axis=1)), 0.0)
    xmax = np.minimum(np.floor(x.max(axis=1)), W - 1.0)
    ymin = np.maximum(np.ceil(y.min(axis=1)), 0.0)
    ymax = np.minimum(np.floor(y.max(axis=1)), H - 1.0)
    ok &= (xmin <= xmax) & (ymin <= ymax)
    return x, y, area, ok, xmin, xmax, ymin, ymax


def _bary_depth_np(x, y, zt, qt, area, px, py, perspective):
    """Barycentrics (m, 3) and depth (m,) at pixels for triangles given per row."""
    w0, w1, w2 = _edges_np(x[:, 0], y[:, 0], x[:, 1], y[:, 1], x[:, 2], y[:, 2], px, py)
    b0, b1, b2 = w0 / area, w1 / area, w2 / area
    if perspective:
        c0, c1, c2 = b0 * qt[:, 0], b1 * qt[:, 1], b2 * qt[:, 2]
        s = c0 + c1 + c2
        b0, b1, b2 = c0 / s, c1 / s, c2 / s
    depth = b0 * zt[:, 0] + b1 * zt[:, 1] + b2 * zt[:, 2]
    return w0, w1, w2, b0, b1, b2, depth


def rasterize_reference(vertices: np.ndarray, faces: np.ndarray, camera, size: tuple[int, int],
                        *, cull_backfaces: bool = False) -> Raster:
    """Vectorised numpy rasteriser: the reference that the numba kernel must match exactly.

    Same arguments and result as :func:`rasterize`. Memory grows with the summed bounding-box
    areas of the triangles; use it for tests and small images.
    """
    V, F = _check_mesh(vertices, faces)
    W, H = _as_size(size)
    xy, z, q = _screen(V, camera)
    x, y, area, ok, xmin, xmax, ymin, ymax = _tri_setup_np(xy, q, F, W, H, cull_backfaces)
    tri = np.flatnonzero(ok)
    out = _empty_raster(W, H)
    if tri.size == 0:
        return out
    bw = (xmax[tri] - xmin[tri] + 1).astype(np.int64)
    bh = (ymax[tri] - ymin[tri] + 1).astype(np.int64)
    count = bw * bh
    start = np.cumsum(count) - count
    t = np.repeat(tri, count)  # candidate (triangle, pixel) pairs
    k = np.arange(int(count.sum())) - np.repeat(start, count)
    bwr = np.repeat(bw, count)
    px = np.repeat(xmin[tri], count) + (k % bwr)
    py = np.repeat(ymin[tri], count) + (k // bwr)
    zt, qt = z[F[t]], q[F[t]]
    a = area[t]
    w0, w1, w2, b0, b1, b2, d = _bary_depth_np(x[t], y[t], zt, qt, a, px, py, perspective=bool(
        getattr(camera, "perspective", False)))
    pos = a > 0
    inside = np.where(pos, (w0 >= 0) & (w1 >= 0) & (w2 >= 0), (w0 <= 0) & (w1 <= 0) & (w2 <= 0))
    d = d.astype(np.float32)  # the z-buffer holds float32 depths
    inside &= d > -np.inf  # NaN and -inf never beat the empty z-buffer
    t, px, py, d = t[inside], px[inside].astype(np.int64), py[inside].astype(np.int64), d[inside]
    pix = py * W + px
    order = np.lexsort((t, -d, pix))  # per pixel: nearest first, then lowest triangle id
    pix, t, d = pix[order], t[order], d[order]
    first = np.ones(pix.size, bool)
    first[1:] = pix[1:] != pix[:-1]
    pix, t, d = pix[first], t[first], d[first]
    out.depth.ravel()[pix] = d
    out.tri_id.ravel()[pix] = t.astype(np.int32)
    out.mask.ravel()[pix] = True
    py, px = np.divmod(pix, W)
    _, _, _, b0, b1, b2, _ = _bary_depth_np(x[t], y[t], z[F[t]], q[F[t]], area[t],
                                            px.astype(np.float64), py.astype(np.float64),
                                            perspective=bool(getattr(camera, "perspective", False)))
    out.bary.reshape(-1, 3)[pix] = np.stack([b0, b1, b2], axis=1).astype(np.float32)
    return out


# --------------------------------------------------------------------------------------------
# numba kernel
# --------------------------------------------------------------------------------------------

def _raster_kernel_py(xy, z, q, F, W, H, cull, perspective, zbuf, tid, bary):  # pragma: no cover
    """Z-buffer loop over triangles; fills ``zbuf`` (H, W) float32, ``tid`` (H, W) int32 and
    ``bary`` (H, W, 3) float32 at every pixel a triangle wins. Returns the bounding box
    ``(x_lo, y_lo, x_hi, y_hi)`` (inclusive) of the pixels written (empty: lo > hi).

    Must stay operation-for-operation equal to :func:`rasterize_reference`.
    """
    bx0, by0, bx1, by1 = W, H, -1, -1
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        q0, q1, q2 = q[i0], q[i1], q[i2]
        if not (q0 > 0 and q1 > 0 and q2 > 0):
            continue
        x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0 or not np.isfinite(area):
            continue
        if cull and area > 0:
            continue
        xmin = max(np.ceil(min(x0, x1, x2)), 0.0)
        xmax = min(np.floor(max(x0, x1, x2)), W - 1.0)
        ymin = max(np.ceil(min(y0, y1, y2)), 0.0)
        ymax = min(np.floor(max(y0, y1, y2)), H - 1.0)
        if xmin > xmax or ymin > ymax:
            continue
        z0, z1, z2 = z[i0], z[i1], z[i2]
        pos = area > 0
        wrote = False
        for iy in range(int(ymin), int(ymax) + 1):
            py = float(iy)
            for ix in range(int(xmin), int(xmax) + 1):
                px = float(ix)
                w0 = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)
                w1 = (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2)
                w2 = (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0)
                if pos:
                    if w0 < 0 or w1 < 0 or w2 < 0:
                        continue
                elif w0 > 0 or w1 > 0 or w2 > 0:
                    continue
                b0 = w0 / area
                b1 = w1 / area
                b2 = w2 / area
                if perspective:
                    c0 = b0 * q0
                    c1 = b1 * q1
                    c2 = b2 * q2
                    s = c0 + c1 + c2
                    b0 = c0 / s
                    b1 = c1 / s
                    b2 = c2 / s
                d = np.float32(b0 * z0 + b1 * z1 + b2 * z2)
                if d > zbuf[iy, ix]:
                    zbuf[iy, ix] = d
                    tid[iy, ix] = f
                    bary[iy, ix, 0] = b0
                    bary[iy, ix, 1] = b1
                    bary[iy, ix, 2] = b2
                    wrote = True
        if wrote:
            bx0 = min(bx0, int(xmin))
            by0 = min(by0, int(ymin))
            bx1 = max(bx1, int(xmax))
            by1 = max(by1, int(ymax))
    return bx0, by0, bx1, by1


def _maybe_njit(fn):
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn) if _HAVE_NUMBA else fn


_raster_kernel = _maybe_njit(_raster_kernel_py)
_any_nondegenerate = _maybe_njit(_any_nondegenerate_py)


def rasterize(vertices: np.ndarray, faces: np.ndarray, camera, size: tuple[int, int], *,
              cull_backfaces: bool = False) -> Raster:
    """Z-buffer rasterisation of a triangle mesh (numba kernel).

    Parameters
    ----------
    vertices : (n, 3) float64
        Model coordinates.
    faces : (F, 3) int64
        Triangles; zero-area ones are skipped.
    camera : WeakPerspective or Pinhole
    size : (W, H)
        Image width and height in pixels.
    cull_backfaces : bool, keyword-only
        Skip triangles whose vertex order is clockwise as seen from the camera (normals, by the
        right-hand rule, pointing away from it).

    Returns
    -------
    Raster
        Depth, triangle id, barycentrics and mask; background if nothing projects into the image.

    Raises
    ------
    RenderError, ShapeError
        Empty mesh, faces out of range, non-finite vertices, bad size.
    """
    V, F = _check_mesh(vertices, faces)
    W, H = _as_size(size)
    return _rasterize_checked(V, F, camera, W, H, cull_backfaces)


def _rasterize_checked(V, F, camera, W, H, cull) -> Raster:
    xy, z, q = _screen(V, camera)
    perspective = bool(getattr(camera, "perspective", False))
    zbuf = np.full((H, W), -np.inf, np.float32)
    tid = np.full((H, W), -1, np.int32)
    bary = np.zeros((H, W, 3), np.float32)
    _raster_kernel(xy, z, q, F, W, H, bool(cull), perspective, zbuf, tid, bary)
    return Raster(zbuf, tid, bary, tid >= 0)


class Rasterizer:
    """Rasterise many frames of one size into reused buffers (no allocation per frame).

    ``Rasterizer(size).rasterize(vertices, faces, camera)`` gives the same result as
    :func:`rasterize`, but the returned :class:`Raster` views the rasterizer's buffers: it is
    valid until the next call (copy it to keep it). Only the region written by the previous
    call is cleared, so a face filling part of the frame costs only its own pixels.

    Parameters
    ----------
    size : (W, H)
    """

    def __init__(self, size: tuple[int, int]) -> None:
        self.size = _as_size(size)
        W, H = self.size
        self._depth = np.full((H, W), -np.inf, np.float32)
        self._tid = np.full((H, W), -1, np.int32)
        self._bary = np.zeros((H, W, 3), np.float32)
        self._mask = np.zeros((H, W), bool)
        self._dirty = (0, 0, -1, -1)

    def rasterize(self, vertices: np.ndarray, faces: np.ndarray, camera, *,
                  cull_backfaces: bool = False) -> Raster:
        """See :func:`rasterize`; the result is overwritten by the next call."""
        V, F = _check_mesh(vertices, faces)
        return self._run(V, F, camera, cull_backfaces)

    def _run(self, V: np.ndarray, F: np.ndarray, camera, cull: bool) -> Raster:
        W, H = self.size
        x0, y0, x1, y1 = self._dirty
        if x1 >= x0 and y1 >= y0:
            region = (slice(y0, y1 + 1), slice(x0, x1 + 1))
            self._depth[region] = -np.inf
            self._tid[region] = -1
            self._bary[region] = 0.0
            self._mask[region] = False
        xy, z, q = _screen(V, camera)
        box = _raster_kernel(xy, z, q, F, W, H, bool(cull),
                             bool(getattr(camera, "perspective", False)),
                             self._depth, self._tid, self._bary)
        self._dirty = tuple(int(b) for b in box)
        x0, y0, x1, y1 = self._dirty
        if x1 >= x0 and y1 >= y0:
            region = (slice(y0, y1 + 1), slice(x0, x1 + 1))
            np.greater_equal(self._tid[region], 0, out=self._mask[region])
        return Raster(self._depth, self._tid, self._bary, self._mask)


_scratch = threading.local()


def _scratch_rasterizer(W: int, H: int) -> Rasterizer:
    """A per-thread :class:`Rasterizer` for internal use (visibility without a given raster)."""
    cache = getattr(_scratch, "cache", None)
    if cache is None:
        cache = _scratch.cache = {}
    r = cache.get((W, H))
    if r is None:
        if len(cache) > 4:
            cache.clear()
        r = cache[(W, H)] = Rasterizer((W, H))
    return r


# --------------------------------------------------------------------------------------------
# Visibility
# --------------------------------------------------------------------------------------------

def vertex_visibility(vertices: np.ndarray, faces: np.ndarray, camera, size: tuple[int, int], *,
                      raster: Raster | None = None, tol: float | None = None) -> np.ndarray:
    """Which vertices the camera sees.

    A vertex is visible if (1) it projects inside the image, (2) it belongs to at least one
    front-facing triangle and (3) the triangle that wins the z-buffer at its nearest pixel,
    with its plane evaluated at the vertex's exact image position, is not nearer than the
    vertex by more than ``tol`` plus that triangle's depth change over one pixel (at most
    ``3 tol``). Evaluating the winner's plane at the vertex, rather than reading the depth at
    the pixel centre, makes the test exact for the vertex's own triangles; ``tol`` absorbs
    curvature between neighbouring triangles, the one-pixel slope term triangles smaller than
    a pixel on steep surfaces (small, distant faces). A silhouette vertex
    whose nearest pixel centre falls just off the mesh is tested against the winners of the 8
    pixels around it instead (visible if any passes).

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64
    camera : WeakPerspective or Pinhole
    size : (W, H)
    raster : Raster, optional
        The raster of this mesh and camera if already computed (it is not recomputed).
    tol : float, optional
        Depth tolerance in model (camera) units; default 1% of the mesh's bounding-box diagonal.

    Returns
    -------
    (n,) bool

    References
    ----------
    Vlasic et al. 2005, §5.1 (tracked vertices must be visible) and §6 (texture lifting).
    """
    V, F = _check_mesh(vertices, faces)
    W, H = _as_size(size)
    if raster is None:
        raster = _scratch_rasterizer(W, H)._run(V, F, camera, False)
    elif raster.tri_id.shape != (H, W):
        raise ShapeError(f"raster is {raster.size}, expected size {(W, H)}")
    if tol is None:
        tol = _default_tol(V)
    elif not (np.isfinite(tol) and tol >= 0):
        raise ShapeError(f"visibility tolerance must be a finite number >= 0, got {tol}")
    return _visibility(V, F, camera, raster, float(tol))


@_maybe_njit
def _plane_depth(xy, z, q, F, f, vx, vy, perspective, tol):  # pragma: no cover
    """Depth of triangle ``f``'s (perspective-correct) plane at image point (vx, vy), and the
    allowance for a vertex tested against it: ``tol`` plus the triangle's depth change over one
    pixel (its screen-space depth gradient), at most ``3 tol``."""
    i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
    x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], xy[i2, 1]
    area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    b0 = ((x2 - x1) * (vy - y1) - (y2 - y1) * (vx - x1)) / area
    b1 = ((x0 - x2) * (vy - y2) - (y0 - y2) * (vx - x2)) / area
    b2 = ((x1 - x0) * (vy - y0) - (y1 - y0) * (vx - x0)) / area
    if perspective:
        c0 = b0 * q[i0]
        c1 = b1 * q[i1]
        c2 = b2 * q[i2]
        s = c0 + c1 + c2
        b0 = c0 / s
        b1 = c1 / s
        b2 = c2 / s
    z0, z1, z2 = z[i0], z[i1], z[i2]
    gx = ((z1 - z0) * (y2 - y0) - (z2 - z0) * (y1 - y0)) / area
    gy = ((z2 - z0) * (x1 - x0) - (z1 - z0) * (x2 - x0)) / area
    allow = tol + min(np.sqrt(gx * gx + gy * gy), 3.0 * tol)
    return b0 * z0 + b1 * z1 + b2 * z2, allow


def _visibility_kernel_py(xy, z, q, F, tid, cand, tol, perspective, vis):  # pragma: no cover
    """Per candidate vertex: the winning triangle at its nearest pixel (or, if that pixel is
    background, any winner of the 8 pixels around it), with its plane evaluated at the vertex,
    must not be nearer than the vertex by more than its allowance (see _plane_depth)."""
    H, W = tid.shape
    for v in range(xy.shape[0]):
        if not cand[v]:
            continue
        vx, vy = xy[v, 0], xy[v, 1]
        cx, cy = int(np.rint(vx)), int(np.rint(vy))
        f = tid[cy, cx]
        if f >= 0:
            d, allow = _plane_depth(xy, z, q, F, f, vx, vy, perspective, tol)
            vis[v] = d <= z[v] + allow
            continue
        for iy in range(max(cy - 1, 0), min(cy + 1, H - 1) + 1):
            for ix in range(max(cx - 1, 0), min(cx + 1, W - 1) + 1):
                f = tid[iy, ix]
                if f >= 0:
                    d, allow = _plane_depth(xy, z, q, F, f, vx, vy, perspective, tol)
                    if d <= z[v] + allow:
                        vis[v] = True


_visibility_kernel = _maybe_njit(_visibility_kernel_py)


def _bbox_diagonal_py(V):  # pragma: no cover
    """Length of the diagonal of the axis-aligned bounding box of V (n, 3)."""
    lo0 = hi0 = V[0, 0]
    lo1 = hi1 = V[0, 1]
    lo2 = hi2 = V[0, 2]
    for i in range(1, V.shape[0]):
        lo0, hi0 = min(lo0, V[i, 0]), max(hi0, V[i, 0])
        lo1, hi1 = min(lo1, V[i, 1]), max(hi1, V[i, 1])
        lo2, hi2 = min(lo2, V[i, 2]), max(hi2, V[i, 2])
    return np.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2)


_bbox_diagonal = _maybe_njit(_bbox_diagonal_py)


def _default_tol(V: np.ndarray) -> float:
    """Default visibility tolerance: 1 % of the mesh's bounding-box diagonal."""
    return 0.01 * float(_bbox_diagonal(V))


def _front_vertices_py(xy, q, F, front):  # pragma: no cover
    """Mark the vertices of drawable, counter-clockwise (front-facing) triangles."""
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        if not (q[i0] > 0 and q[i1] > 0 and q[i2] > 0):
            continue
        x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], xy[i2, 1]
        if (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0) < 0:
            front[i0] = True
            front[i1] = True
            front[i2] = True


_front_vertices = _maybe_njit(_front_vertices_py)


def _visibility(V, F, camera, raster: Raster, tol: float) -> np.ndarray:
    n = V.shape[0]
    H, W = raster.tri_id.shape
    xy, z, q = _screen(V, camera)
    front = np.zeros(n, bool)
    _front_vertices(xy, q, F, front)
    with np.errstate(invalid="ignore"):
        cand = front & (q > 0) & (xy[:, 0] >= -0.5) & (xy[:, 0] < W - 0.5) \
            & (xy[:, 1] >= -0.5) & (xy[:, 1] < H - 0.5)
    vis = np.zeros(n, bool)
    if cand.any():
        _visibility_kernel(xy, z, q, F, np.ascontiguousarray(raster.tri_id, dtype=np.int32),
                           cand, float(tol), bool(getattr(camera, "perspective", False)), vis)
    return vis


# --------------------------------------------------------------------------------------------
# Shading and colour
# --------------------------------------------------------------------------------------------

def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (right-hand rule on the face vertex order).

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64

    Returns
    -------
    (n, 3) float64
        Unit normals; vertices on no non-degenerate face get (0, 0, 0).
    """
    V, F = _check_mesh(vertices, faces)
    N = np.zeros_like(V)
    _normals_kernel(V, F, N)
    return N


def _normals_kernel_py(V, F, N):  # pragma: no cover
    """Sum of face cross products (2 x area x unit normal) per vertex, then normalised."""
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, az = V[i1, 0] - V[i0, 0], V[i1, 1] - V[i0, 1], V[i1, 2] - V[i0, 2]
        bx, by, bz = V[i2, 0] - V[i0, 0], V[i2, 1] - V[i0, 1], V[i2, 2] - V[i0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        for i in (i0, i1, i2):
            N[i, 0] += nx
            N[i, 1] += ny
            N[i, 2] += nz
    for i in range(N.shape[0]):
        norm = np.sqrt(N[i, 0] ** 2 + N[i, 1] ** 2 + N[i, 2] ** 2)
        if norm > 0:
            N[i, 0] /= norm
            N[i, 1] /= norm
            N[i, 2] /= norm


_normals_kernel = _maybe_njit(_normals_kernel_py)


def _check_texture(texture) -> np.ndarray:
    if texture is None:
        raise AssetError("texture is missing (None)")
    T = np.asarray(texture)
    if T.ndim != 3 or T.shape[2] != 3 or T.dtype != np.uint8 or T.shape[0] < 1 or T.shape[1] < 1:
        raise AssetError(f"texture must be an (H, W, 3) uint8 RGB image, got {T.shape} {T.dtype}")
    return T


def _check_colors(colors, n: int) -> np.ndarray:
    C = np.asarray(colors)
    if C.shape != (n, 3):
        raise ShapeError(f"colors must be (n_vertices, 3) = ({n}, 3), got {C.shape}")
    if C.dtype == np.uint8:
        return C.astype(np.float64)
    C = C.astype(np.float64)
    if not np.all(np.isfinite(C)):
        raise ShapeError("colors contain NaN or infinite values")
    # float colours: 0..1 if they all fit, otherwise 0..255
    return C * 255.0 if C.max(initial=0.0) <= 1.0 else C


def _background(background, W: int, H: int) -> np.ndarray:
    if background is None:
        return np.zeros((H, W, 3), np.uint8)
    B = np.asarray(background)
    if B.ndim == 1 and B.shape == (3,):
        if not np.all((B >= 0) & (B <= 255)):
            raise ShapeError(f"background colour must be 3 values in 0..255, got {B}")
        return np.broadcast_to(B.astype(np.uint8), (H, W, 3)).copy()
    if B.shape != (H, W, 3) or B.dtype != np.uint8:
        raise ShapeError(f"background must be a colour (3,) or an ({H}, {W}, 3) uint8 image, "
                         f"got {B.shape} {B.dtype}")
    return B.copy()


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup, ``uv`` (m, 2) with v up -> (m, 3) float64 in 0..255.

    Texel ``(col, row) = (u (Wt - 1), (1 - v) (Ht - 1))``; coordinates are clamped to the image.
    """
    T = _check_texture(texture)
    Ht, Wt = T.shape[:2]
    u = np.clip(uv[:, 0], 0.0, 1.0) * (Wt - 1)
    v = (1.0 - np.clip(uv[:, 1], 0.0, 1.0)) * (Ht - 1)
    c0 = np.minimum(np.floor(u).astype(np.intp), Wt - 1)
    r0 = np.minimum(np.floor(v).astype(np.intp), Ht - 1)
    c1 = np.minimum(c0 + 1, Wt - 1)
    r1 = np.minimum(r0 + 1, Ht - 1)
    fu = (u - c0)[:, None]
    fv = (v - r0)[:, None]
    Tf = T.astype(np.float32) if T.size <= 4096 * 4096 * 3 else T
    top = Tf[r0, c0] * (1 - fu) + Tf[r0, c1] * fu
    bot = Tf[r1, c0] * (1 - fu) + Tf[r1, c1] * fu
    return top * (1 - fv) + bot * fv


def _texel_py(tex, u, v):  # pragma: no cover (numba)
    """Bilinear sample (r, g, b) of ``tex`` at texture coordinates ``(u, v)`` (v up, clamped to
    [0, 1]): texel ``(col, row) = (u (Wt - 1), (1 - v) (Ht - 1))``, as :func:`sample_texture`."""
    Ht, Wt = tex.shape[0], tex.shape[1]
    u = min(max(u, 0.0), 1.0) * (Wt - 1)
    v = (1.0 - min(max(v, 0.0), 1.0)) * (Ht - 1)
    c0 = min(int(np.floor(u)), Wt - 1)
    r0 = min(int(np.floor(v)), Ht - 1)
    c1 = min(c0 + 1, Wt - 1)
    r1 = min(r0 + 1, Ht - 1)
    fu = u - c0
    fv = v - r0
    out0 = (tex[r0, c0, 0] * (1.0 - fu) + tex[r0, c1, 0] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 0] * (1.0 - fu) + tex[r1, c1, 0] * fu) * fv
    out1 = (tex[r0, c0, 1] * (1.0 - fu) + tex[r0, c1, 1] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 1] * (1.0 - fu) + tex[r1, c1, 1] * fu) * fv
    out2 = (tex[r0, c0, 2] * (1.0 - fu) + tex[r0, c1, 2] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 2] * (1.0 - fu) + tex[r1, c1, 2] * fu) * fv
    return out0, out1, out2


_texel = _maybe_njit(_texel_py)


def _shade_uv_kernel_py(tid, bary, F, uvs, tex, select, image, mask):  # pragma: no cover
    """Unlit texture shading of the covered pixels whose triangle is selected (bilinear,
    the texel convention of :func:`sample_texture`)."""
    H, W = tid.shape
    for iy in range(H):
        for ix in range(W):
            f = tid[iy, ix]
            if f < 0 or not select[f]:
                continue
            mask[iy, ix] = True
            i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
            b0, b1, b2 = float(bary[iy, ix, 0]), float(bary[iy, ix, 1]), float(bary[iy, ix, 2])
            c = _texel(tex, b0 * uvs[i0, 0] + b1 * uvs[i1, 0] + b2 * uvs[i2, 0],
                       b0 * uvs[i0, 1] + b1 * uvs[i1, 1] + b2 * uvs[i2, 1])
            for k in range(3):
                image[iy, ix, k] = min(max(np.rint(c[k]), 0.0), 255.0)


_shade_uv_kernel = _maybe_njit(_shade_uv_kernel_py)


def shade_texture(raster: Raster, faces: np.ndarray, uvs: np.ndarray, texture: np.ndarray,
                  select: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Texture the pixels of a raster without lighting, in one pass (numba).

    Every pixel covered by a (selected) triangle takes the bilinear texture sample
    (:func:`sample_texture`) at the barycentric interpolation of its triangle's ``uvs``.

    Parameters
    ----------
    raster : Raster
        Of a mesh with faces ``faces``.
    faces : (F, 3) int
    uvs : (n, 2) float
        Texture coordinates (v up) of the mesh's vertices.
    texture : (Ht, Wt, 3) uint8
    select : (F,) bool, optional
        Shade only these triangles (the others stay black and outside the mask).

    Returns
    -------
    image : (H, W, 3) uint8
        Black where nothing is shaded.
    mask : (H, W) bool
        The shaded pixels.
    """
    T = _check_texture(texture)
    Fa = np.ascontiguousarray(faces, dtype=np.int64)
    U = np.ascontiguousarray(uvs, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] != 2 or (Fa.size and Fa.max() >= U.shape[0]):
        raise ShapeError(f"uvs must be (n, 2) covering the faces' vertices, got {U.shape}")
    sel = np.ones(len(Fa), bool) if select is None else np.ascontiguousarray(select, dtype=bool)
    if sel.shape != (len(Fa),):
        raise ShapeError(f"select must be ({len(Fa)},) bool, got {sel.shape}")
    H, W = raster.tri_id.shape
    if raster.tri_id.size and raster.tri_id.max() >= len(Fa):
        raise ShapeError(f"the raster's triangles exceed the {len(Fa)} faces given")
    image = np.zeros((H, W, 3), np.uint8)
    mask = np.zeros((H, W), bool)
    _shade_uv_kernel(np.ascontiguousarray(raster.tri_id), np.ascontiguousarray(raster.bary), Fa,
                     U, np.ascontiguousarray(T), sel, image, mask)
    return image, mask


def render(vertices: np.ndarray, faces: np.ndarray, camera, size: tuple[int, int], *,
           colors: np.ndarray | None = None, uvs: np.ndarray | None = None,
           texture: np.ndarray | None = None, shading: str = "lambert",
           light: tuple[float, float, float] = (0.0, 0.0, 1.0), ambient: float = 0.25,
           background=None, cull_backfaces: bool = False,
           visibility_tol: float | None = None) -> RenderResult:
    """Render a mesh to an RGB image with a z-buffer.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64
    camera : WeakPerspective or Pinhole
    size : (W, H)
    colors : (n, 3) uint8 (0..255) or float (0..1, or 0..255 if any exceeds 1), optional
        Per-vertex colours, interpolated with the barycentrics.
    uvs : (n, 2) float64, optional
        Texture coordinates (v up); used with ``texture``.
    texture : (Ht, Wt, 3) uint8, optional
        Sampled bilinearly at ``(u (Wt-1), (1-v) (Ht-1))``; takes precedence over ``colors``.
    shading : {"lambert", "none"}
        ``"lambert"`` multiplies the colour by ``ambient + (1 - ambient) max(0, n . light)``
        with interpolated vertex normals in camera space.
    light : (3,) float
        Direction towards the light in camera space; (0, 0, 1) lights from the camera.
    ambient : float in [0, 1]
    background : None, (3,) colour or (H, W, 3) uint8, optional
        What shows where no triangle is (default black).
    cull_backfaces : bool
    visibility_tol : float, optional
        Passed to :func:`vertex_visibility` as ``tol``.

    Returns
    -------
    RenderResult
        With a camera that shows none of the mesh (all behind the camera or outside the image)
        the image is the background, the raster is empty and ``visible`` is all False; a
        warning is logged.

    Raises
    ------
    RenderError, ShapeError, AssetError
        Empty mesh, faces out of range, all triangles degenerate, bad colours, a texture that
        is not an (H, W, 3) uint8 image, uvs of the wrong shape.
    """
    V, F = _check_mesh(vertices, faces)
    W, H = _as_size(size)
    _check_not_all_degenerate(V, F)
    if shading not in ("lambert", "none"):
        raise RenderError(f"shading must be 'lambert' or 'none', got {shading!r}")
    if not 0.0 <= float(ambient) <= 1.0:
        raise RenderError(f"ambient must be in [0, 1], got {ambient}")
    n = V.shape[0]
    if texture is not None or uvs is not None:
        T = _check_texture(texture)
        UV = np.asarray(uvs, dtype=np.float64) if uvs is not None else None
        if UV is None or UV.shape != (n, 2):
            raise ShapeError(f"uvs must be (n_vertices, 2) = ({n}, 2) with a texture, got "
                             f"{None if UV is None else UV.shape}")
    else:
        T = UV = None
    C = _check_colors(colors, n) if colors is not None else None
    image = _background(background, W, H)

    raster = _rasterize_checked(V, F, camera, W, H, cull_backfaces)
    if not raster.mask.any():
        log.warning("the mesh is entirely behind the camera or outside the %dx%d image; "
                    "rendering the background only", W, H)
        return RenderResult(image, raster, np.zeros(n, bool))
    if visibility_tol is not None and not (np.isfinite(visibility_tol) and visibility_tol >= 0):
        raise ShapeError(f"visibility tolerance must be a finite number >= 0, got "
                         f"{visibility_tol}")
    tol = _default_tol(V) if visibility_tol is None \
        else float(visibility_tol)
    visible = _visibility(V, F, camera, raster, tol)

    if T is not None:
        src, uv_arr, tex_arr, col_arr = 1, UV, np.ascontiguousarray(T), _DUMMY_COLORS
    elif C is not None:
        src, uv_arr, tex_arr, col_arr = 0, _DUMMY_UV, _DUMMY_TEX, C
    else:
        src, uv_arr, tex_arr, col_arr = 0, _DUMMY_UV, _DUMMY_TEX, np.full((n, 3), 200.0)
    if shading == "lambert":
        L = np.asarray(light, dtype=np.float64)
        if L.shape != (3,) or not np.linalg.norm(L) > 0:
            raise ShapeError(f"light must be a non-zero (3,) direction, got {L}")
        L = L / np.linalg.norm(L)
        Nc = np.ascontiguousarray(vertex_normals(V, F) @ camera.rotation.T)  # camera space
    else:
        L, Nc = np.zeros(3), _DUMMY_COLORS
    _shade_kernel(raster.tri_id, raster.bary, F, src, col_arr, uv_arr, tex_arr,
                  shading == "lambert", Nc, L, float(ambient), image)
    return RenderResult(image, raster, visible)


_DUMMY_COLORS = np.zeros((1, 3))
_DUMMY_UV = np.zeros((1, 2))
_DUMMY_TEX = np.zeros((1, 1, 3), np.uint8)


def _shade_kernel_py(tid, bary, F, src, colors, uvs, tex, lambert, normals, light, ambient,
                     image):  # pragma: no cover
    """Colour every covered pixel: interpolated vertex colour (src 0) or bilinear texture
    sample at the interpolated uv (src 1), times ``ambient + (1 - ambient) max(0, n . l)``."""
    H, W = tid.shape
    for iy in range(H):
        for ix in range(W):
            f = tid[iy, ix]
            if f < 0:
                continue
            i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
            b0, b1, b2 = float(bary[iy, ix, 0]), float(bary[iy, ix, 1]), float(bary[iy, ix, 2])
            if src == 1:
                cr, cg, cb = _texel(tex, b0 * uvs[i0, 0] + b1 * uvs[i1, 0] + b2 * uvs[i2, 0],
                                    b0 * uvs[i0, 1] + b1 * uvs[i1, 1] + b2 * uvs[i2, 1])
            else:
                cr = b0 * colors[i0, 0] + b1 * colors[i1, 0] + b2 * colors[i2, 0]
                cg = b0 * colors[i0, 1] + b1 * colors[i1, 1] + b2 * colors[i2, 1]
                cb = b0 * colors[i0, 2] + b1 * colors[i1, 2] + b2 * colors[i2, 2]
            if lambert:
                nx = b0 * normals[i0, 0] + b1 * normals[i1, 0] + b2 * normals[i2, 0]
                ny = b0 * normals[i0, 1] + b1 * normals[i1, 1] + b2 * normals[i2, 1]
                nz = b0 * normals[i0, 2] + b1 * normals[i1, 2] + b2 * normals[i2, 2]
                nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                cos = 0.0
                if nn > 0:
                    cos = max((nx * light[0] + ny * light[1] + nz * light[2]) / nn, 0.0)
                g = ambient + (1.0 - ambient) * cos
                cr *= g
                cg *= g
                cb *= g
            image[iy, ix, 0] = min(max(np.rint(cr), 0.0), 255.0)
            image[iy, ix, 1] = min(max(np.rint(cg), 0.0), 255.0)
            image[iy, ix, 2] = min(max(np.rint(cb), 0.0), 255.0)


_shade_kernel = _maybe_njit(_shade_kernel_py)


def render_model(model, weights, *, size: tuple[int, int] = (640, 480), yaw_deg: float = 0.0,
                 pitch_deg: float = 0.0, roll_deg: float = 0.0, scale: float = 1.0,
                 fill: float = 0.8, colors: np.ndarray | None = None,
                 texture: np.ndarray | None = None, background=(255, 255, 255),
                 shading: str = "lambert") -> RenderResult:
    """A framed preview of a multilinear model face (Eq. (5)) under a weak-perspective camera.

    Parameters
    ----------
    model : MultilinearModel
        Anything with ``synthesize(weights)``, ``faces`` and ``uvs``.
    weights : mapping mode -> (r_k,)
    size : (W, H)
    yaw_deg, pitch_deg, roll_deg : float
        Head rotation (:func:`rotation_from_euler`), about the centre of the face's box.
    scale : float
        Zoom relative to the framing (1: the rotated face box fills ``fill`` of the image).
    colors, texture : optional
        Per-vertex colours, or a UV texture (needs ``model.uvs``); default plain grey.
    background : colour (3,) or (H, W, 3) uint8
    shading : {"lambert", "none"}

    Returns
    -------
    RenderResult
    """
    if not (np.isfinite(scale) and scale > 0):
        raise ShapeError(f"preview scale must be > 0, got {scale}")
    V = np.asarray(model.synthesize(weights), dtype=np.float64)
    R = rotation_from_euler(yaw_deg, pitch_deg, roll_deg)
    cam = look_at_weak_perspective(V, size, rotation=R, fill=fill * scale)
    uvs = model.uvs if texture is not None else None
    if texture is not None and uvs is None:
        raise RenderError("a texture needs a model with UVs; this model has none")
    return render(V, model.faces, cam, size, colors=colors, uvs=uvs, texture=texture,
                  shading=shading, background=background)

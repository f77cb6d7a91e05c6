"""Z-buffer rasterisation of triangle meshes (paper §5.1, §6): a :class:`Raster` per image.

Rasterisation rule: a pixel centre ``(px, py)`` belongs to a triangle if it lies inside or on
the triangle's boundary (edge functions of one sign or zero). Among the triangles covering a
pixel the nearest wins; equal depths go to the lower triangle index. Triangles with zero
projected area are skipped silently. Two implementations obey this rule exactly: a vectorised
numpy reference (:func:`rasterize_reference`) and a numba kernel (:func:`rasterize`,
:class:`Rasterizer`), which are tested to give identical pixels.

References
----------
Pineda. A parallel algorithm for polygon rasterization. SIGGRAPH 1988 (edge functions).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ..errors import RenderError, ShapeError
from ..geometry import check_mesh as _check_mesh
from ..geometry import face_cross as _face_cross
from ..jit import HAVE_NUMBA as _HAVE_NUMBA
from ..jit import maybe_njit as _maybe_njit
from .cameras import Pinhole, WeakPerspective, _as_size

__all__ = ["Raster", "rasterize", "Rasterizer", "rasterize_reference", "coverage"]


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


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------

def _check_not_all_degenerate(V: np.ndarray, F: np.ndarray) -> None:
    """Reject a mesh whose triangles all have zero area in 3D."""
    scale = float(_bbox_diagonal(V))
    if scale == 0.0 or not _any_nondegenerate(V, F, (1e-12 * scale * scale) ** 2):
        raise RenderError(f"all {F.shape[0]} triangles are degenerate (zero area)")


def _any_nondegenerate_py(V, F, eps2):  # pragma: no cover
    """True as soon as one triangle has squared doubled area > eps2 (stops early)."""
    for f in range(F.shape[0]):
        nx, ny, nz = _face_cross(V, F[f, 0], F[f, 1], F[f, 2])
        if nx * nx + ny * ny + nz * nz > eps2:
            return True
    return False


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

def _edges_py(x0, y0, x1, y1, x2, y2, px, py):  # pragma: no cover (numba, inlined)
    """The edge functions of pixel centre ``(px, py)`` (as :func:`_edges_np`)."""
    w0 = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1)
    w1 = (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2)
    w2 = (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0)
    return w0, w1, w2


_edges = _maybe_njit(_edges_py, inline=True)


def _trailing_zeros_py(m):  # pragma: no cover (numba: an intrinsic)
    """The index of the lowest set bit of ``m`` (a non-zero uint64)."""
    m = int(m)
    return (m & -m).bit_length() - 1


if _HAVE_NUMBA:
    from numba.cpython.unsafe.numbers import trailing_zeros as _tzcnt

    def _trailing_zeros_nb(m):  # pragma: no cover (numba, inlined)
        return _tzcnt(m)

    _trailing_zeros = _maybe_njit(_trailing_zeros_nb, inline=True)
else:  # pragma: no cover
    _trailing_zeros = _trailing_zeros_py

#: The side of a tile of :func:`_raster_kernel`: one bit per pixel of a uint64
_TILE = 8


def _tile_row_py(x0, y0, x1, y1, x2, y2, pos, tx, hi, py):  # pragma: no cover (numba, inlined)
    """Bit ``c`` (uint64) set where pixel ``tx + c`` (``c < 8``, at most ``hi``) of row ``py``
    lies inside the triangle (the rule of :func:`rasterize`): eight pixels at once, without a
    branch per pixel (vectorised)."""
    bits = np.uint64(0)
    for c in range(_TILE):
        ix = tx + c
        w0, w1, w2 = _edges(x0, y0, x1, y1, x2, y2, float(ix), py)
        if pos:
            inside = not ((w0 < 0) | (w1 < 0) | (w2 < 0))
        else:
            inside = not ((w0 > 0) | (w1 > 0) | (w2 > 0))
        bits |= np.uint64(inside & (ix <= hi)) << np.uint64(c)
    return bits


_tile_row = _maybe_njit(_tile_row_py, inline=True)


def _tile_mask_py(x0, y0, x1, y1, x2, y2, pos, tx, ty, hi, yhi):  # pragma: no cover (numba)
    """The inside pixels of the 8 x 8 tile whose top-left pixel is ``(tx, ty)``, up to column
    ``hi`` and row ``yhi``: bit ``8 r + c`` (uint64) for pixel ``(tx + c, ty + r)``."""
    m = np.uint64(0)
    for r in range(_TILE):
        bits = _tile_row(x0, y0, x1, y1, x2, y2, pos, tx, hi, float(ty + r))
        m |= (bits if ty + r <= yhi else np.uint64(0)) << np.uint64(_TILE * r)
    return m


_tile_mask = _maybe_njit(_tile_mask_py, inline=True)


def _pixel_box_py(x0, y0, x1, y1, x2, y2, W, H):  # pragma: no cover (numba, inlined)
    """The pixel centres a triangle's bounding box holds, clipped to a ``W`` x ``H`` image:
    ``(xmin, xmax, ymin, ymax)`` float, inclusive (empty: ``xmin > xmax`` or ``ymin > ymax``;
    convert to int only then: a far vertex's coordinate need not fit one)."""
    xmin = max(np.ceil(min(x0, x1, x2)), 0.0)
    xmax = min(np.floor(max(x0, x1, x2)), W - 1.0)
    ymin = max(np.ceil(min(y0, y1, y2)), 0.0)
    ymax = min(np.floor(max(y0, y1, y2)), H - 1.0)
    return xmin, xmax, ymin, ymax


_pixel_box = _maybe_njit(_pixel_box_py, inline=True)


def _draw_pixel_py(tri, f, area, perspective, iy, ix, zbuf, tid, bary):  # pragma: no cover
    """The z-buffer test and write of pixel ``(ix, iy)`` inside triangle ``f``, whose screen
    coordinates, depths and perspective weights are ``tri = (x0, y0, x1, y1, x2, y2, z0, z1,
    z2, q0, q1, q2)``; True if it wins (numba, inlined)."""
    x0, y0, x1, y1, x2, y2, z0, z1, z2, q0, q1, q2 = tri
    w0, w1, w2 = _edges(x0, y0, x1, y1, x2, y2, float(ix), float(iy))
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
        return True
    return False


_draw_pixel = _maybe_njit(_draw_pixel_py, inline=True)


def _raster_kernel_py(xy, z, q, F, W, H, cull, perspective, zbuf, tid, bary):  # pragma: no cover
    """Z-buffer loop over triangles; fills ``zbuf`` (H, W) float32, ``tid`` (H, W) int32 and
    ``bary`` (H, W, 3) float32 at every pixel a triangle wins. Returns the bounding box
    ``(x_lo, y_lo, x_hi, y_hi)`` (inclusive) of the pixels written (empty: lo > hi).

    Must stay operation-for-operation equal to :func:`rasterize_reference`. A triangle's
    bounding box is covered by 8 x 8 tiles; a tile's inside pixels are found at once, as the
    bits of a uint64 (:func:`_tile_mask`, no branch per pixel: the inside test mispredicts at
    both ends of every short row, and most triangles of a face span a few pixels), and only
    those are drawn, lowest bit first (the order of a triangle's own pixels changes nothing:
    each is written once).
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
        xmin, xmax, ymin, ymax = _pixel_box(x0, y0, x1, y1, x2, y2, W, H)
        if xmin > xmax or ymin > ymax:
            continue
        tri = (x0, y0, x1, y1, x2, y2, z[i0], z[i1], z[i2], q0, q1, q2)
        pos = area > 0
        lo, hi, ylo, yhi = int(xmin), int(xmax), int(ymin), int(ymax)
        wrote = False
        for tx in range(lo, hi + 1, _TILE):
            for ty in range(ylo, yhi + 1, _TILE):
                m = np.uint64(_tile_mask(x0, y0, x1, y1, x2, y2, pos, tx, ty, hi, yhi))
                while m != 0:
                    k = _trailing_zeros(m)
                    m &= m - np.uint64(1)
                    if _draw_pixel(tri, f, area, perspective, ty + k // _TILE, tx + k % _TILE,
                                   zbuf, tid, bary):
                        wrote = True
        if wrote:
            bx0 = min(bx0, lo)
            by0 = min(by0, ylo)
            bx1 = max(bx1, hi)
            by1 = max(by1, yhi)
    return bx0, by0, bx1, by1


_raster_kernel = _maybe_njit(_raster_kernel_py)
_any_nondegenerate = _maybe_njit(_any_nondegenerate_py)


def _raster_fresh_py(xy, z, q, F, W, H, cull, perspective, zbuf, tid, bary,
                     mask):  # pragma: no cover (numba)
    """:func:`_raster_kernel` into new buffers, ``zbuf`` and ``tid`` (H, W) unset and set
    first to the background (-inf, -1), ``bary`` zeros (numpy's, whose pages the OS gives
    zeroed: only the drawn pixels' are touched), and ``mask`` (H, W) bool ``tid >= 0`` after:
    numpy's ``full`` and comparison of :func:`_rasterize_checked` in the same call."""
    for y in range(H):
        for x in range(W):
            zbuf[y, x] = -np.inf
            tid[y, x] = -1
    _raster_kernel(xy, z, q, F, W, H, cull, perspective, zbuf, tid, bary)
    for y in range(H):
        for x in range(W):
            mask[y, x] = tid[y, x] >= 0


_raster_fresh = _maybe_njit(_raster_fresh_py)


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


def _covered_py(mask, x, y):  # pragma: no cover (numba, inlined)
    """Whether the pixel nearest the point ``(x, y)`` is set in ``mask`` (False off it)."""
    ix, iy = int(np.floor(x + 0.5)), int(np.floor(y + 0.5))
    return 0 <= iy < mask.shape[0] and 0 <= ix < mask.shape[1] and mask[iy, ix] != 0


_covered = _maybe_njit(_covered_py, inline=True)


def _coverage_kernel_py(xy, F, W, H, front, skip, mask):  # pragma: no cover (numba)
    """``mask[iy, ix] = 1`` at every pixel inside a non-degenerate triangle of ``F`` drawn at
    the pixel positions ``xy`` (n, 2), by :func:`rasterize`'s inside rule (``front``: only
    triangles that face the camera, as its ``cull_backfaces`` keeps); no depth, no
    barycentrics (the silhouettes of meshes whose triangles span a pixel or two, a loop over
    each triangle's box is cheaper than tiles). ``mask`` (H, W) uint8 holds 0 or 1 and each
    pixel of a box is or-ed with its inside test, without a branch (a pixel covered already
    was skipped, and a test against the one before: both branches mispredicted on the
    triangles' small boxes; the same 0s and 1s, ~30 % less time).
    A triangle whose three corners fall on pixels set in ``skip`` (H, W) uint8 is not drawn
    (``mask`` holds its pixels already; whether a point falls on ``skip`` is found once a
    point, not once a corner)."""
    on = np.empty(xy.shape[0], np.bool_)
    for i in range(xy.shape[0]):  # (a point not finite: only on triangles not drawn)
        x, y = xy[i, 0], xy[i, 1]
        on[i] = np.isfinite(x) and np.isfinite(y) and _covered(skip, x, y)
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if area == 0 or not np.isfinite(area) or (front and area > 0):
            continue
        if on[i0] and on[i1] and on[i2]:
            continue
        xmin, xmax, ymin, ymax = _pixel_box(x0, y0, x1, y1, x2, y2, W, H)
        if xmin > xmax or ymin > ymax:
            continue
        pos = area > 0
        for iy in range(int(ymin), int(ymax) + 1):
            for ix in range(int(xmin), int(xmax) + 1):
                w0, w1, w2 = _edges(x0, y0, x1, y1, x2, y2, float(ix), float(iy))
                if pos:
                    inside = not ((w0 < 0) | (w1 < 0) | (w2 < 0))
                else:
                    inside = not ((w0 > 0) | (w1 > 0) | (w2 > 0))
                mask[iy, ix] |= np.uint8(inside)


_coverage_kernel = _maybe_njit(_coverage_kernel_py)


def coverage(points: np.ndarray, faces: np.ndarray, size: tuple[int, int], *,
             front: bool = False, known: np.ndarray | None = None) -> np.ndarray:
    """The pixels a 2D triangle mesh covers: ``(H, W) bool``, what :func:`rasterize`'s ``mask``
    is for a mesh drawn at the pixel positions ``points`` (n, 2) (its inside rule; degenerate
    triangles and ones out of the image cover nothing; ``front``: only the triangles its
    ``cull_backfaces`` keeps), without depths or barycentrics.

    ``known`` (H, W) bool: pixels known to be covered, set in the result; a triangle whose
    three corners lie two pixels inside them (their 5 x 5 erosion, nearest pixel) is not drawn
    (its pixels are taken to be among them: ``known`` should hold no hole a triangle could
    span)."""
    xy = np.ascontiguousarray(points, np.float64)
    F = np.ascontiguousarray(faces, np.int64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ShapeError(f"points must be (n, 2), got {xy.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or (F.size and (F.min() < 0 or F.max() >= len(xy))):
        raise ShapeError(f"faces must be (F, 3) indices of the {len(xy)} points")
    W, H = _as_size(size)
    if known is None:
        mask, skip = np.zeros((H, W), np.uint8), np.zeros((0, 0), np.uint8)
    else:
        if np.shape(known) != (H, W):
            raise ShapeError(f"known must be ({H}, {W}) bool, got {np.shape(known)}")
        import cv2

        mask = np.array(known, bool).view(np.uint8)
        skip = cv2.erode(mask, np.ones((5, 5), np.uint8), borderType=cv2.BORDER_CONSTANT,
                         borderValue=0)
    _coverage_kernel(xy, F, W, H, bool(front), skip, mask)
    return mask.view(bool)


def _rasterize_checked(V, F, camera, W, H, cull) -> Raster:
    return _raster_of(_screen(V, camera), F, camera, W, H, cull)


def rasterize_drawn(vertices: np.ndarray, faces: np.ndarray, camera,
                    size: tuple[int, int]) -> tuple[Raster, np.ndarray]:
    """:func:`rasterize` (no culling) and the pixel positions (n, 2) float64 it drew the
    vertices at: for a :class:`WeakPerspective` camera its ``project(vertices)`` (the render
    of a frame needs both; one projection instead of two)."""
    V, F = _check_mesh(vertices, faces)
    W, H = _as_size(size)
    screen = _screen(V, camera)
    return _raster_of(screen, F, camera, W, H, False), screen[0]


def _raster_of(screen, F, camera, W, H, cull) -> Raster:
    """The raster of the checked faces ``F`` drawn at ``screen = (xy, z, q)``
    (:func:`_screen`)."""
    xy, z, q = screen
    perspective = bool(getattr(camera, "perspective", False))
    zbuf, tid = np.empty((H, W), np.float32), np.empty((H, W), np.int32)
    bary, mask = np.zeros((H, W, 3), np.float32), np.empty((H, W), bool)
    _raster_fresh(xy, z, q, F, W, H, bool(cull), perspective, zbuf, tid, bary, mask)
    return Raster(zbuf, tid, bary, mask)


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

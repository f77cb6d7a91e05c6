"""Which vertices a camera sees (paper §5.1: the tracked vertices must be visible; §6: texture
lifting weights samples by visibility)."""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError
from ..geometry import check_mesh as _check_mesh
from .cameras import _as_size
from ..jit import maybe_njit as _maybe_njit
from .raster import Raster, _bbox_diagonal, _scratch_rasterizer, _screen

__all__ = ["vertex_visibility"]


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
    return _visibility(V, F, camera, raster, _tolerance(V, tol))


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


def _default_tol(V: np.ndarray) -> float:
    """Default visibility tolerance: 1 % of the mesh's bounding-box diagonal."""
    return 0.01 * float(_bbox_diagonal(V))


def _tolerance(V: np.ndarray, tol: float | None) -> float:
    """The visibility tolerance ``tol`` checked, or the default for the vertices (n, 3)."""
    if tol is None:
        return _default_tol(V)
    if not (np.isfinite(tol) and tol >= 0):
        raise ShapeError(f"visibility tolerance must be a finite number >= 0, got {tol}")
    return float(tol)


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

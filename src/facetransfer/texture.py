"""Texture from video and the performance-driven texture function (Vlasic et al. 2005, §6).

§6: "Once we obtain the 3D geometry, we can lift the texture from the video by assigning pixel
colors to the corresponding mesh vertices. A simple performance-driven texture function can be
obtained with the weighted sum of nearest neighbors."

Pipeline, per tracked frame (pose and mesh known):

1. :func:`lift_vertex_colors` / :func:`lift_uv_texture`: sample the frame where each vertex (or
   each texel's surface point) projects, with a confidence weight

       weight = visible * max(0, n_c . d)^p                                          (1)

   where ``n_c`` is the unit surface normal in camera coordinates, ``d`` the unit direction from
   the surface towards the camera (``(0, 0, 1)`` for the weak-perspective camera of §5.1, Eq. (7))
   and ``visible`` the z-buffer test of :mod:`facetransfer.render`. Samples seen obliquely (near
   the silhouette) or hidden get little or no weight.
2. :func:`merge_textures`: the weight-normalised mean over frames; texels never seen are filled
   by push-pull interpolation (:func:`fill_holes`).
3. :class:`TextureFunction`: the texture for an attribute vector (e.g. expression and viseme
   weights concatenated) is the weighted sum of the lifted textures of the ``k`` training frames
   nearest in attribute space, each texel weighted by kernel weight times its weight (1).

:func:`lift_track` runs step 1 over a tracked (or synthetic) clip. The default face texture is
procedural (:func:`default_face_texture`) until the template is fitted to the Lee Perry-Smith
scan; :func:`lee_perry_smith_texture` then carries the scan's colour map onto the template's UVs
by closest points (:func:`bake_texture`); credit :data:`LEE_PERRY_SMITH_CREDIT` wherever it is
shown.

Colours are float32 on the 0..255 scale of the uint8 frames. Texture images follow
:func:`facetransfer.render.sample_texture`: texel ``(col, row) = (u (T - 1), (1 - v) (T - 1))``
with v up, so a lifted texture renders back with :func:`facetransfer.render.render` directly.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, §6.
S. Gortler, R. Grzeszczuk, R. Szeliski, M. Cohen. The Lumigraph. SIGGRAPH 1996 (push-pull).
"""

from __future__ import annotations

import hashlib
import logging
from collections import OrderedDict
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .errors import FaceTransferError, ShapeError
from .io.atomic import atomic_path, write_image
from .render import rasterize, vertex_normals, vertex_visibility

log = logging.getLogger(__name__)

__all__ = [
    "TextureError",
    "LiftedTexture",
    "LiftedUVTexture",
    "MergedTexture",
    "UVAtlas",
    "uv_atlas",
    "obliqueness_weight",
    "lift_vertex_colors",
    "lift_uv_texture",
    "merge_textures",
    "fill_holes",
    "fill_vertex_colors",
    "TextureFunction",
    "LiftedTrack",
    "lift_track",
    "attribute_vector",
    "default_face_texture",
    "bake_texture",
    "BakedTexture",
    "load_lee_perry_smith",
    "lee_perry_smith_texture",
    "lee_perry_smith_template_texture",
    "LEE_PERRY_SMITH_CREDIT",
    "texture_to_uint8",
]

#: Credit line to show wherever the Lee Perry-Smith head texture is shown (CC-BY 3.0).
LEE_PERRY_SMITH_CREDIT = "Lee Perry-Smith (Infinite Realities), CC-BY 3.0"


class TextureError(FaceTransferError):
    """Bad input to texture lifting, merging or the texture function."""


class LiftedTexture(NamedTuple):
    """Per-vertex colours lifted from one frame.

    Attributes
    ----------
    colors : (n_vertices, 3) float32
        RGB on the 0..255 scale; 0 where the weight is 0.
    weights : (n_vertices,) float32
        Confidence (1): visibility times obliqueness, in [0, 1].
    """

    colors: np.ndarray
    weights: np.ndarray


class LiftedUVTexture(NamedTuple):
    """A UV texture lifted from one frame.

    Attributes
    ----------
    texture : (T, T, 3) float32
        RGB on the 0..255 scale; 0 where the weight is 0.
    weight : (T, T) float32
        Confidence (1) per texel, in [0, 1]; 0 outside the UV charts.
    """

    texture: np.ndarray
    weight: np.ndarray


class MergedTexture(NamedTuple):
    """Weighted mean of several lifted textures.

    Attributes
    ----------
    texture : (..., 3) float32
        Weighted mean colour (holes filled when requested).
    weight : (...,) float32
        Total weight per texel or vertex; 0 where nothing was seen.
    """

    texture: np.ndarray
    weight: np.ndarray


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------

def _check_frame(frame) -> np.ndarray:
    f = np.asarray(frame)
    if f.ndim != 3 or f.shape[2] != 3 or f.shape[0] == 0 or f.shape[1] == 0 or f.dtype != np.uint8:
        raise ShapeError(f"frame must be an (H, W, 3) uint8 RGB image, got {f.shape} {f.dtype}")
    return f


def _check_vertices(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0:
        raise ShapeError(f"vertices must be (n, 3) with n > 0, got {V.shape}")
    if not np.all(np.isfinite(V)):
        raise TextureError("vertices contain NaN or infinite coordinates")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or not np.issubdtype(F.dtype, np.integer):
        raise ShapeError(f"faces must be a non-empty (F, 3) integer array, got {F.shape} {F.dtype}")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= V.shape[0]:
        raise TextureError(f"faces index vertices {F.min()}..{F.max()} but there are {V.shape[0]}")
    return V, F


def _check_uvs(uvs, n: int) -> np.ndarray:
    if uvs is None:
        raise TextureError("this mesh has no texture coordinates (uvs is None)")
    U = np.asarray(uvs, dtype=np.float64)
    if U.shape != (n, 2):
        raise ShapeError(f"uvs must be (n_vertices, 2) = ({n}, 2), got {U.shape}")
    if not np.all(np.isfinite(U)):
        raise TextureError("uvs contain NaN or infinite values")
    return U


def _check_raster(raster, frame: np.ndarray):
    if raster is not None and raster.tri_id.shape != frame.shape[:2]:
        raise ShapeError(f"raster is {raster.tri_id.shape} (H, W) but the frame is {frame.shape[:2]}")
    return raster


def texture_to_uint8(texture) -> np.ndarray:
    """Round a float 0..255 texture (or colours) to uint8, clipping to the range."""
    return np.clip(np.rint(np.asarray(texture, dtype=np.float64)), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------
# sampling and weights
# --------------------------------------------------------------------------------------------

def _bilinear(frame: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``frame`` at pixel positions ``xy`` (m, 2), clamped; (m, 3) float32.

    Pixel centres are at integer coordinates, ``(0, 0)`` the centre of the top-left pixel.
    """
    H, W = frame.shape[:2]
    x = np.clip(xy[:, 0], 0.0, W - 1.0)
    y = np.clip(xy[:, 1], 0.0, H - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.intp), W - 1)
    y0 = np.minimum(np.floor(y).astype(np.intp), H - 1)
    x1 = np.minimum(x0 + 1, W - 1)
    y1 = np.minimum(y0 + 1, H - 1)
    fx = (x - x0)[:, None].astype(np.float32)
    fy = (y - y0)[:, None].astype(np.float32)
    f = frame.astype(np.float32) if frame.dtype != np.float32 else frame
    top = f[y0, x0] * (1 - fx) + f[y0, x1] * fx
    bot = f[y1, x0] * (1 - fx) + f[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def obliqueness_weight(normals, points, camera, *, power: float = 2.0) -> np.ndarray:
    """``max(0, n_c . d)^p`` of Eq. (1): how squarely the surface faces the camera.

    Parameters
    ----------
    normals : (m, 3) float64
        Surface normals in model coordinates (need not be unit; zero normals give 0).
    points : (m, 3) float64
        Surface points in model coordinates (used for the pinhole camera's view rays).
    camera : WeakPerspective or Pinhole
    power : float, keyword-only
        ``p`` >= 0; larger values favour frontal views more strongly.

    Returns
    -------
    (m,) float64 in [0, 1]
    """
    if not np.isfinite(power) or power < 0:
        raise TextureError(f"power must be a finite number >= 0, got {power}")
    N = np.asarray(normals, dtype=np.float64) @ camera.rotation.T  # camera-space normals
    nn = np.linalg.norm(N, axis=1)
    if getattr(camera, "perspective", False):
        P = camera.to_camera(points)
        d = -P / np.maximum(np.linalg.norm(P, axis=1, keepdims=True), 1e-300)
        c = np.einsum("ij,ij->i", N, d)
    else:
        c = N[:, 2]  # view direction (0, 0, 1): towards the camera
    cos = np.divide(c, nn, out=np.zeros_like(c), where=nn > 0)
    return np.maximum(cos, 0.0) ** power


def _visible_points(P: np.ndarray, tri: np.ndarray, V: np.ndarray, F: np.ndarray, camera,
                    raster, tol: float) -> np.ndarray:
    """Z-buffer test of surface points ``P`` (m, 3) lying on triangles ``tri`` (m,).

    A point is visible if it projects inside the image and the triangle that wins the z-buffer at
    its nearest pixel, with its plane evaluated at the point's exact image position, is not nearer
    than the point by more than ``tol`` (as :func:`facetransfer.render.vertex_visibility`).
    """
    H, W = raster.tri_id.shape
    xy = camera.project(P)
    z = camera.depth(P)
    ix = np.rint(xy[:, 0])
    iy = np.rint(xy[:, 1])
    ok = np.isfinite(xy).all(axis=1) & (ix >= 0) & (ix <= W - 1) & (iy >= 0) & (iy <= H - 1)
    vis = np.zeros(P.shape[0], bool)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return vis
    win = raster.tri_id[iy[idx].astype(np.intp), ix[idx].astype(np.intp)].astype(np.int64)
    own = win == tri[idx]
    vis[idx[own]] = True
    other = np.flatnonzero(~own & (win >= 0))
    if other.size:
        j = idx[other]
        Ft = F[win[other]]
        sxy = camera.project(V[Ft.ravel()]).reshape(-1, 3, 2)
        sz = camera.depth(V[Ft.ravel()]).reshape(-1, 3)
        b = _bary2d(sxy, xy[j])
        d = np.einsum("mk,mk->m", b, sz)
        vis[j] = d <= z[j] + tol
    # background at the nearest pixel (point on a silhouette edge): not occluded
    vis[idx[~own & (win < 0)]] = True
    return vis


def _bary2d(tri_xy: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (m, 3) of points ``p`` (m, 2) in 2D triangles (m, 3, 2)."""
    a, b, c = tri_xy[:, 0], tri_xy[:, 1], tri_xy[:, 2]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) > 1e-300, den, 1e-300)
    l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.stack([1.0 - l1 - l2, l1, l2], axis=1)


def _default_tol(V: np.ndarray) -> float:
    return 0.01 * float(np.linalg.norm(np.ptp(V, axis=0)))


# --------------------------------------------------------------------------------------------
# per-vertex lifting
# --------------------------------------------------------------------------------------------

def lift_vertex_colors(frame, vertices, faces, camera, *, raster=None, power: float = 2.0,
                       tol: float | None = None) -> LiftedTexture:
    """Assign each mesh vertex the frame's colour where it projects (§6), with weight (1).

    Parameters
    ----------
    frame : (H, W, 3) uint8 RGB
    vertices : (n, 3) float64
        The tracked mesh in model coordinates.
    faces : (F, 3) int64
    camera : WeakPerspective or Pinhole
        The frame's camera (§5.1, Eq. (7)).
    raster : Raster, optional, keyword-only
        The z-buffer of this mesh in this frame, if already computed.
    power : float, keyword-only
        Obliqueness exponent ``p`` of Eq. (1).
    tol : float, optional, keyword-only
        Depth tolerance of the visibility test (model units); default 1% of the mesh diagonal.

    Returns
    -------
    LiftedTexture
        ``colors`` (n, 3) float32 sampled bilinearly, ``weights`` (n,) float32.

    References
    ----------
    Vlasic et al. 2005, §6 ("assigning pixel colors to the corresponding mesh vertices").
    """
    f = _check_frame(frame)
    V, F = _check_vertices(vertices, faces)
    H, W = f.shape[:2]
    raster = _check_raster(raster, f)
    tol = _default_tol(V) if tol is None else float(tol)
    vis = vertex_visibility(V, F, camera, (W, H), raster=raster, tol=tol)
    w = obliqueness_weight(vertex_normals(V, F), V, camera, power=power) * vis  # Eq. (1)
    colors = np.zeros((V.shape[0], 3), np.float32)
    idx = np.flatnonzero(w > 0)
    if idx.size:
        colors[idx] = _bilinear(f, camera.project(V[idx]))
    else:
        log.warning("lift_vertex_colors: no vertex of the mesh is visible in the %dx%d frame", W, H)
    return LiftedTexture(colors, w.astype(np.float32))


# --------------------------------------------------------------------------------------------
# UV atlas and UV lifting
# --------------------------------------------------------------------------------------------

class UVAtlas:
    """Texel -> (triangle, barycentric) map of a mesh topology's UV layout, computed once.

    Texel ``(row, col)`` of a ``T x T`` texture sits at ``u = col / (T - 1)``,
    ``v = 1 - row / (T - 1)`` (the convention of :func:`facetransfer.render.sample_texture`).
    A texel is covered by a triangle if its centre lies inside or on the triangle in UV space;
    where UV triangles overlap, the lowest triangle index wins. Triangles with zero UV area are
    skipped.

    Parameters
    ----------
    faces : (F, 3) int64
    uvs : (n, 2) float64, v up
    tex_size : int
        ``T`` >= 2.

    Attributes
    ----------
    texel_tri : (T, T) int32
        Covering triangle, -1 where none.
    texel_bary : (T, T, 3) float32
        Barycentric coordinates in that triangle (0 where none).
    mask : (T, T) bool
        ``texel_tri >= 0``.
    """

    def __init__(self, faces, uvs, tex_size: int = 512):
        F = np.asarray(faces)
        if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or not np.issubdtype(F.dtype, np.integer):
            raise ShapeError(f"faces must be a non-empty (F, 3) integer array, got {F.shape}")
        U = np.asarray(uvs, dtype=np.float64)
        if U.ndim != 2 or U.shape[1] != 2 or not np.all(np.isfinite(U)):
            raise ShapeError(f"uvs must be a finite (n, 2) array, got {U.shape}")
        if F.min() < 0 or F.max() >= U.shape[0]:
            raise TextureError(f"faces index vertices up to {F.max()} but uvs has {U.shape[0]} rows")
        T = int(tex_size)
        if T != tex_size or T < 2 or T > 16384:
            raise TextureError(f"tex_size must be an integer in 2..16384, got {tex_size!r}")
        self.faces = F.astype(np.int64)
        self.uvs = U
        self.tex_size = T
        self.texel_tri, self.texel_bary = _rasterize_uv(self.faces, U, T)
        self.mask = self.texel_tri >= 0
        flat = np.flatnonzero(self.mask.ravel())
        self._flat = flat
        self._tri = self.texel_tri.ravel()[flat].astype(np.int64)
        self._bary = self.texel_bary.reshape(-1, 3)[flat].astype(np.float64)

    @property
    def n_texels(self) -> int:
        """Number of covered texels."""
        return int(self._flat.size)

    @property
    def texel_triangles(self) -> np.ndarray:
        """Triangle of every covered texel, in row-major texel order, ``(m,) int64``."""
        return self._tri

    def interpolate(self, values) -> np.ndarray:
        """Barycentric interpolation of per-vertex ``values`` (n, c) at covered texels: (m, c)."""
        X = np.asarray(values, dtype=np.float64)
        if X.ndim != 2 or X.shape[0] != self.uvs.shape[0]:
            raise ShapeError(f"values must be (n_vertices, c) with n = {self.uvs.shape[0]}, "
                             f"got {X.shape}")
        Ft = self.faces[self._tri]  # (m, 3)
        return np.einsum("mk,mkc->mc", self._bary, X[Ft])

    def scatter(self, values, fill: float = 0.0) -> np.ndarray:
        """Put per-texel ``values`` (m, ...) of the covered texels into a (T, T, ...) image."""
        X = np.asarray(values)
        out = np.full((self.tex_size * self.tex_size,) + X.shape[1:], fill, dtype=X.dtype)
        out[self._flat] = X
        return out.reshape((self.tex_size, self.tex_size) + X.shape[1:])

    def matches(self, faces, uvs, tex_size: int) -> bool:
        """True if this atlas was built for exactly these faces, uvs and size."""
        return (int(tex_size) == self.tex_size and np.shape(faces) == self.faces.shape
                and np.shape(uvs) == self.uvs.shape and np.array_equal(faces, self.faces)
                and np.array_equal(uvs, self.uvs))


def _rasterize_uv(F: np.ndarray, U: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised point-in-triangle test of texel centres in UV space (see :class:`UVAtlas`)."""
    x = U[:, 0][F] * (T - 1)  # (F, 3) texel columns
    y = (1.0 - U[:, 1][F]) * (T - 1)  # (F, 3) texel rows
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
    xmin = np.maximum(np.ceil(x.min(1) - 1e-9), 0)
    xmax = np.minimum(np.floor(x.max(1) + 1e-9), T - 1)
    ymin = np.maximum(np.ceil(y.min(1) - 1e-9), 0)
    ymax = np.minimum(np.floor(y.max(1) + 1e-9), T - 1)
    ok = (np.abs(area) > 1e-12) & (xmin <= xmax) & (ymin <= ymax)
    tri_id = np.full(T * T, -1, np.int64)
    bary = np.zeros((T * T, 3), np.float32)
    tris = np.flatnonzero(ok)
    # process in chunks to bound memory (candidates = summed bounding-box areas)
    bw = (xmax - xmin + 1).astype(np.int64)
    bh = (ymax - ymin + 1).astype(np.int64)
    count = np.where(ok, bw * bh, 0)
    chunks = np.array_split(tris, max(1, int(count.sum() // 4_000_000) + 1))
    for ch in reversed(chunks):  # later chunks first, so that lower indices overwrite
        if ch.size == 0:
            continue
        c = count[ch]
        start = np.cumsum(c) - c
        t = np.repeat(ch, c)
        k = np.arange(int(c.sum())) - np.repeat(start, c)
        bwr = np.repeat(bw[ch], c)
        px = np.repeat(xmin[ch], c) + (k % bwr)
        py = np.repeat(ymin[ch], c) + (k // bwr)
        b = _bary2d(np.stack([x[t], y[t]], axis=2), np.stack([px, py], axis=1))
        eps = 1e-9
        inside = (b >= -eps).all(axis=1)
        t, px, py, b = t[inside], px[inside], py[inside], b[inside]
        pix = (py * T + px).astype(np.int64)
        order = np.lexsort((t, pix))  # per texel, lowest triangle index first
        pix, t, b = pix[order], t[order], b[order]
        first = np.ones(pix.size, bool)
        first[1:] = pix[1:] != pix[:-1]
        pix, t, b = pix[first], t[first], b[first]
        tri_id[pix] = t
        b = np.clip(b, 0.0, 1.0)
        bary[pix] = b / b.sum(axis=1, keepdims=True)
    return tri_id.reshape(T, T).astype(np.int32), bary.reshape(T, T, 3)


_ATLAS_CACHE: "OrderedDict[str, UVAtlas]" = OrderedDict()
_ATLAS_CACHE_SIZE = 4


def uv_atlas(faces, uvs, tex_size: int = 512) -> UVAtlas:
    """A :class:`UVAtlas`, cached by the content of ``faces``, ``uvs`` and ``tex_size``."""
    F = np.ascontiguousarray(faces, dtype=np.int64)
    U = np.ascontiguousarray(uvs, dtype=np.float64)
    h = hashlib.sha1(F.tobytes())
    h.update(U.tobytes())
    h.update(str((F.shape, U.shape, int(tex_size))).encode())
    key = h.hexdigest()
    if key in _ATLAS_CACHE:
        _ATLAS_CACHE.move_to_end(key)
        return _ATLAS_CACHE[key]
    atlas = UVAtlas(F, U, tex_size)
    _ATLAS_CACHE[key] = atlas
    while len(_ATLAS_CACHE) > _ATLAS_CACHE_SIZE:
        _ATLAS_CACHE.popitem(last=False)
    return atlas


def lift_uv_texture(frame, vertices, faces, uvs, camera, tex_size: int = 512, *, raster=None,
                    atlas: UVAtlas | None = None, power: float = 2.0,
                    tol: float | None = None) -> LiftedUVTexture:
    """Lift a UV texture from one frame: every covered texel samples the frame (§6).

    Each texel's surface point (barycentric in its UV triangle) is projected into the frame and
    sampled bilinearly; its weight is Eq. (1) with the interpolated normal and a z-buffer
    visibility test of the point.

    Parameters
    ----------
    frame : (H, W, 3) uint8 RGB
    vertices : (n, 3) float64
    faces : (F, 3) int64
    uvs : (n, 2) float64, v up
    camera : WeakPerspective or Pinhole
    tex_size : int
        ``T``, texture width and height.
    raster : Raster, optional, keyword-only
        The frame's z-buffer of this mesh, if already computed.
    atlas : UVAtlas, optional, keyword-only
        Precomputed atlas for these faces, uvs and size (otherwise :func:`uv_atlas`, cached).
    power : float, keyword-only
        Obliqueness exponent ``p`` of Eq. (1).
    tol : float, optional, keyword-only
        Depth tolerance in model units (default 1% of the mesh diagonal).

    Returns
    -------
    LiftedUVTexture
        ``texture`` (T, T, 3) float32 and ``weight`` (T, T) float32.

    References
    ----------
    Vlasic et al. 2005, §6.
    """
    f = _check_frame(frame)
    V, F = _check_vertices(vertices, faces)
    U = _check_uvs(uvs, V.shape[0])
    H, W = f.shape[:2]
    raster = _check_raster(raster, f)
    if atlas is None:
        atlas = uv_atlas(F, U, tex_size)
    elif not atlas.matches(F, U, tex_size):
        raise TextureError("atlas was built for other faces, uvs or tex_size")
    if raster is None:
        raster = rasterize(V, F, camera, (W, H))
    tol = _default_tol(V) if tol is None else float(tol)
    P = atlas.interpolate(V)  # (m, 3) texel surface points
    N = atlas.interpolate(vertex_normals(V, F))
    vis = _visible_points(P, atlas.texel_triangles, V, F, camera, raster, tol)
    w = obliqueness_weight(N, P, camera, power=power) * vis  # Eq. (1)
    col = np.zeros((P.shape[0], 3), np.float32)
    idx = np.flatnonzero(w > 0)
    if idx.size:
        col[idx] = _bilinear(f, camera.project(P[idx]))
    else:
        log.warning("lift_uv_texture: no texel of the mesh is visible in the %dx%d frame", W, H)
    return LiftedUVTexture(atlas.scatter(col), atlas.scatter(w.astype(np.float32)))


# --------------------------------------------------------------------------------------------
# merging and hole filling
# --------------------------------------------------------------------------------------------

def _stack_lifted(lifted) -> tuple[np.ndarray, np.ndarray]:
    if len(lifted) == 0:
        raise TextureError("need at least one lifted texture")
    cols, ws = [], []
    shape = None
    for i, item in enumerate(lifted):
        if len(item) != 2:
            raise TextureError(f"lifted[{i}] must be a (texture, weight) pair")
        c = np.asarray(item[0], dtype=np.float32)
        w = np.asarray(item[1], dtype=np.float32)
        if c.shape[-1:] != (3,) or w.shape != c.shape[:-1]:
            raise ShapeError(f"lifted[{i}]: texture {c.shape} and weight {w.shape} must be "
                             "(..., 3) and (...)")
        if shape is None:
            shape = c.shape
        elif c.shape != shape:
            raise ShapeError(f"lifted[{i}] has shape {c.shape}, expected {shape} like lifted[0]")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
            raise TextureError(f"lifted[{i}] weights must be finite and >= 0")
        cols.append(c)
        ws.append(w)
    return np.stack(cols), np.stack(ws)


def merge_textures(lifted: Sequence, *, fill: str = "auto", min_weight: float = 1e-6) -> MergedTexture:
    """Weighted mean of lifted textures over frames, with holes filled.

    ``texture = Σ_f w_f tex_f / Σ_f w_f`` per texel (or vertex).

    Parameters
    ----------
    lifted : sequence of (texture (..., 3), weight (...)) pairs
        E.g. :class:`LiftedUVTexture` or :class:`LiftedTexture` results of several frames.
    fill : {"auto", "pushpull", "inpaint", "none"}, keyword-only
        How to fill texels whose total weight is below ``min_weight``: ``"auto"`` is push-pull
        for (T, T, 3) images and nothing for per-vertex colours (use :func:`fill_vertex_colors`).
    min_weight : float, keyword-only

    Returns
    -------
    MergedTexture
    """
    if fill not in ("auto", "pushpull", "inpaint", "none"):
        raise TextureError(f"fill must be 'auto', 'pushpull', 'inpaint' or 'none', got {fill!r}")
    C, Wt = _stack_lifted(lifted)
    total = Wt.sum(axis=0)
    num = np.einsum("f...,f...c->...c", Wt, C)
    known = total > min_weight
    tex = np.zeros_like(num)
    tex[known] = num[known] / total[known][:, None]
    is_image = tex.ndim == 3
    if fill == "auto":
        fill = "pushpull" if is_image else "none"
    if fill != "none":
        if not is_image:
            raise TextureError(f"fill={fill!r} needs (T, T, 3) textures, got {tex.shape}; use "
                               "fill_vertex_colors for per-vertex colours")
        tex = fill_holes(tex, known, method=fill)
    return MergedTexture(tex.astype(np.float32), total.astype(np.float32))


def fill_holes(texture, known, *, method: str = "pushpull") -> np.ndarray:
    """Fill texels where ``known`` is False from the known ones.

    Parameters
    ----------
    texture : (T, T', 3) float (0..255)
    known : (T, T') bool
    method : {"pushpull", "inpaint"}, keyword-only
        ``"pushpull"``: pyramid push-pull (Gortler et al. 1996), smooth and fast.
        ``"inpaint"``: ``cv2.inpaint`` (Telea), on the uint8-rounded texture.

    Returns
    -------
    (T, T', 3) float32, equal to ``texture`` where ``known``.
    """
    tex = np.asarray(texture, dtype=np.float32)
    k = np.asarray(known)
    if tex.ndim != 3 or tex.shape[2] != 3 or k.shape != tex.shape[:2] or k.dtype != bool:
        raise ShapeError(f"texture (H, W, 3) and known (H, W) bool expected, got {tex.shape} "
                         f"and {k.shape} {k.dtype}")
    if method not in ("pushpull", "inpaint"):
        raise TextureError(f"method must be 'pushpull' or 'inpaint', got {method!r}")
    if k.all():
        return tex.copy()
    if not k.any():
        log.warning("fill_holes: nothing known; returning mid-grey")
        return np.full_like(tex, 128.0)
    if method == "inpaint":
        filled = cv2.inpaint(texture_to_uint8(tex), (~k).astype(np.uint8), 3, cv2.INPAINT_TELEA)
        out = filled.astype(np.float32)
    else:
        out = _push_pull(tex, k.astype(np.float32))
    out[k] = tex[k]
    return out


def _push_pull(tex: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Push-pull: average known values down a pyramid, then fill holes from coarser levels."""
    H, W = w.shape
    if H <= 1 and W <= 1:
        return tex
    # pull (down): premultiplied 2x2 sums, weights clipped to 1 so that known texels dominate
    Hp, Wp = H + (H % 2), W + (W % 2)
    cp = np.zeros((Hp, Wp, 3), np.float32)
    wp = np.zeros((Hp, Wp), np.float32)
    cp[:H, :W] = tex * w[..., None]
    wp[:H, :W] = w
    # 2x2 block sums (an exact halving: INTER_AREA averages the blocks)
    c2 = cv2.resize(cp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    w2 = cv2.resize(wp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    if c2.ndim == 2:  # a 1-pixel-wide level: cv2 drops the channel axis of (1, 1, 3)
        c2 = c2.reshape(Hp // 2, Wp // 2, 3)
    coarse = np.divide(c2, w2[..., None], out=np.zeros_like(c2), where=w2[..., None] > 0)
    coarse = _push_pull(coarse, np.minimum(w2, 1.0))
    # push (up): bilinear upsampling of the coarse level, blended in by missing weight
    up = cv2.resize(coarse, (Wp, Hp), interpolation=cv2.INTER_LINEAR)[:H, :W]
    a = np.clip(w, 0.0, 1.0)[..., None]
    return a * tex + (1.0 - a) * up


def fill_vertex_colors(colors, known, faces) -> np.ndarray:
    """Fill unknown per-vertex colours by harmonic interpolation over the mesh graph.

    Solves ``L c = 0`` at unknown vertices (graph Laplacian of the triangle edges) with the
    known colours fixed. Components with no known vertex get the mean known colour.

    Parameters
    ----------
    colors : (n, 3) float
    known : (n,) bool
    faces : (F, 3) int64

    Returns
    -------
    (n, 3) float32
    """
    C = np.asarray(colors, dtype=np.float64)
    k = np.asarray(known)
    if C.ndim != 2 or C.shape[1] != 3 or k.shape != (C.shape[0],) or k.dtype != bool:
        raise ShapeError(f"colors (n, 3) and known (n,) bool expected, got {C.shape}, {k.shape}")
    n = C.shape[0]
    F = np.asarray(faces, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3 or F.size and (F.min() < 0 or F.max() >= n):
        raise ShapeError(f"faces must be (F, 3) indices into {n} vertices, got {F.shape}")
    if k.all() or not k.any():
        out = C.copy() if k.any() else np.full_like(C, 128.0)
        return out.astype(np.float32)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    u = np.flatnonzero(~k)
    kk = np.flatnonzero(k)
    Luu = L[u][:, u].tocsc()
    rhs = -(L[u][:, kk] @ C[kk])
    # isolated unknown components make Luu singular: a tiny pull to the mean colour fixes that
    Luu = Luu + sp.identity(len(u), format="csc") * 1e-9
    rhs += 1e-9 * C[kk].mean(axis=0)
    out = C.copy()
    out[u] = sla.splu(Luu).solve(rhs)
    return out.astype(np.float32)


# --------------------------------------------------------------------------------------------
# performance-driven texture function
# --------------------------------------------------------------------------------------------

class TextureFunction:
    """Performance-driven texture: weighted sum of nearest neighbours in attribute space (§6).

    Built from textures lifted from ``F`` tracked frames and the attribute vectors of those
    frames (e.g. expression and viseme weights concatenated). For a query attribute vector
    ``a`` with nearest training frames ``i = 1..k`` at distances ``d_i``, every texel is

        tex(a) = (Σ_i κ_i w_i tex_i + λ tex_all) / (Σ_i κ_i w_i + λ)                   (2)

    with kernel weights ``κ_i`` (normalised to sum 1), the per-texel confidences ``w_i`` of
    Eq. (1), and ``tex_all`` the merged texture of all frames (weight ``λ = prior * min_i κ_i``),
    which fills texels none of the neighbours saw. A query equal to a training vector returns that
    frame's texture wherever the frame saw it (the other neighbours fill the rest).

    Parameters
    ----------
    textures : (F, ..., 3) float
        Lifted textures (images (F, T, T, 3) or per-vertex colours (F, n, 3)), 0..255.
    weights : (F, ...) float
        Their confidences (Eq. (1)).
    attributes : (F, r) float
        Attribute vector of every frame.
    k : int
        Neighbours used (clipped to F).
    kernel : {"gaussian", "inverse"}
        ``exp(-d² / (2 h²))`` or ``1 / d²``.
    bandwidth : float, optional
        ``h`` of the Gaussian kernel; default the median distance from each training vector to
        its nearest other one (1 with a single frame).
    prior : float
        ``λ / min_i κ_i`` of Eq. (2), > 0.
    faces : (F, 3) int64, optional
        For per-vertex colours: fill vertices no frame saw in ``tex_all`` by harmonic
        interpolation over the mesh (:func:`fill_vertex_colors`); otherwise they stay 0.

    Notes
    -----
    All lifted textures are held in memory as float32: ``F * T * T * 16`` bytes (200 frames at
    T = 256 take 210 MB); lift every few frames or use a smaller ``T`` for long clips.

    References
    ----------
    Vlasic et al. 2005, §6 ("the weighted sum of nearest neighbors").
    """

    def __init__(self, textures, weights, attributes, *, k: int = 4, kernel: str = "gaussian",
                 bandwidth: float | None = None, prior: float = 1e-6, faces=None):
        C = np.asarray(textures, dtype=np.float32)
        Wt = np.asarray(weights, dtype=np.float32)
        A = np.asarray(attributes, dtype=np.float64)
        if A.ndim != 2 or A.shape[0] == 0 or A.shape[1] == 0:
            raise ShapeError(f"attributes must be (F, r) with F, r > 0, got {A.shape}")
        if not np.all(np.isfinite(A)):
            raise TextureError("attributes contain NaN or infinite values")
        nF = A.shape[0]
        if C.shape[:1] != (nF,) or C.shape[-1] != 3 or Wt.shape != C.shape[:-1]:
            raise ShapeError(f"textures (F, ..., 3) and weights (F, ...) with F = {nF} expected, "
                             f"got {C.shape} and {Wt.shape}")
        if not (np.all(np.isfinite(Wt)) and np.all(Wt >= 0)) or not np.all(np.isfinite(C)):
            raise TextureError("textures must be finite and weights finite and >= 0")
        if kernel not in ("gaussian", "inverse"):
            raise TextureError(f"kernel must be 'gaussian' or 'inverse', got {kernel!r}")
        if int(k) != k or k < 1:
            raise TextureError(f"k must be an integer >= 1, got {k!r}")
        if not (np.isfinite(prior) and prior > 0):
            raise TextureError(f"prior must be a finite number > 0, got {prior}")
        self.textures = C
        self.weights = Wt
        self.attributes = A
        self.k = int(min(k, nF))
        self.kernel = kernel
        if bandwidth is None:
            bandwidth = _median_nn_distance(A)
        if not (np.isfinite(bandwidth) and bandwidth > 0):
            raise TextureError(f"bandwidth must be a finite number > 0, got {bandwidth}")
        self.bandwidth = float(bandwidth)
        self.prior = float(prior)
        fill = "pushpull" if C.ndim == 4 else "none"
        merged = merge_textures(list(zip(C, Wt)), fill=fill)
        if C.ndim == 3 and faces is not None:  # per-vertex colours: fill unseen vertices
            filled = fill_vertex_colors(merged.texture, merged.weight > 1e-6, faces)
            merged = MergedTexture(filled, merged.weight)
        self.merged = merged

    @classmethod
    def from_lifted(cls, lifted: Sequence, attributes, **kwargs) -> "TextureFunction":
        """Build from a sequence of (texture, weight) pairs, one per frame (see ``__init__``)."""
        C, Wt = _stack_lifted(lifted)
        return cls(C, Wt, attributes, **kwargs)

    @property
    def n_frames(self) -> int:
        return int(self.attributes.shape[0])

    def neighbours(self, attributes) -> tuple[np.ndarray, np.ndarray]:
        """Indices (k,) of the nearest training frames and their kernel weights (k,), summing to 1."""
        a = np.asarray(attributes, dtype=np.float64)
        if a.shape != (self.attributes.shape[1],) or not np.all(np.isfinite(a)):
            raise ShapeError(f"attributes must be a finite ({self.attributes.shape[1]},) vector, "
                             f"got shape {a.shape}")
        d = np.linalg.norm(self.attributes - a, axis=1)
        idx = np.argsort(d, kind="stable")[: self.k]
        dk = d[idx]
        exact = dk <= 1e-12 * max(1.0, float(np.abs(a).max()))
        if self.kernel == "inverse":
            kappa = 1.0 / np.where(exact, 1.0, dk) ** 2
        else:
            kappa = np.exp(-0.5 * ((dk - dk[0]) / self.bandwidth) ** 2)  # shifted: no underflow
        if exact.any():
            # a query equal to training frames returns them; the other neighbours only fill
            # texels those frames did not see
            kappa = np.where(exact, 1.0, 1e-9 * kappa / kappa.max())
        return idx, kappa / kappa.sum()

    def __call__(self, attributes) -> np.ndarray:
        """Texture for one attribute vector (r,): Eq. (2); shape like one training texture."""
        idx, kappa = self.neighbours(attributes)
        w = kappa.reshape((-1,) + (1,) * (self.weights.ndim - 1)) * self.weights[idx]  # (k, ...)
        lam = self.prior * float(kappa.min())  # λ of Eq. (2), below every neighbour's kernel weight
        fb = self.merged.texture
        num = np.einsum("k...,k...c->...c", w, self.textures[idx]) + lam * fb
        den = (w.sum(axis=0) + lam)[..., None]
        out = np.divide(num, den, out=fb.astype(np.float64), where=den > 0)
        return out.astype(np.float32)

    def save(self, path) -> None:
        """Write to an ``.npz`` file (atomically)."""
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, textures=self.textures, weights=self.weights,
                                attributes=self.attributes, k=self.k, kernel=self.kernel,
                                bandwidth=self.bandwidth, prior=self.prior)

    @classmethod
    def load(cls, path) -> "TextureFunction":
        """Read a file written by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(z["textures"], z["weights"], z["attributes"], k=int(z["k"]),
                           kernel=str(z["kernel"]), bandwidth=float(z["bandwidth"]),
                           prior=float(z["prior"]))
        except (OSError, KeyError, ValueError) as exc:
            if isinstance(exc, FaceTransferError):
                raise
            raise TextureError(f"cannot read texture function {path}: {exc}") from None


def _median_nn_distance(A: np.ndarray) -> float:
    if A.shape[0] < 2:
        return 1.0
    D = np.linalg.norm(A[:, None] - A[None], axis=2) if A.shape[0] <= 2000 else None
    if D is None:
        from scipy.spatial import cKDTree
        d, _ = cKDTree(A).query(A, k=2)
        nn = d[:, 1]
    else:
        np.fill_diagonal(D, np.inf)
        nn = D.min(axis=1)
    nn = nn[nn > 0]
    return float(np.median(nn)) if nn.size else 1.0


# --------------------------------------------------------------------------------------------
# lifting a whole tracked performance
# --------------------------------------------------------------------------------------------

class LiftedTrack(NamedTuple):
    """UV textures lifted from the frames of a tracked (or synthetic) clip.

    Attributes
    ----------
    lifted : list of LiftedUVTexture
        One per used frame.
    attributes : (F, r) float64
        The frames' attribute vectors (:func:`attribute_vector`), for :class:`TextureFunction`.
    frames : (F,) int64
        Indices of the used frames in the clip.
    """

    lifted: list
    attributes: np.ndarray
    frames: np.ndarray


def attribute_vector(model, weights: dict) -> np.ndarray:
    """Concatenated weights of every mode but identity (the first mode): ``(..., Σ r_k)``.

    These are the coordinates of the texture function's nearest-neighbour search (§6: the
    texture varies with expression and viseme, not with the constant identity).
    """
    modes = list(model.mode_names[1:])
    if not modes:
        raise TextureError("the model has only an identity mode: no attributes to index by")
    missing = [m for m in modes if m not in weights]
    if missing:
        raise TextureError(f"weights lack the modes {missing}")
    return np.concatenate([np.asarray(weights[m], dtype=np.float64) for m in modes], axis=-1)


def lift_track(model, frames, track, *, tex_size: int = 256, step: int = 1, power: float = 2.0,
               progress=None) -> LiftedTrack:
    """Lift a UV texture from every ``step``-th frame of a tracked clip (§6).

    Parameters
    ----------
    model : MultilinearModel
        The model the clip was tracked (or synthesised) with; needs ``uvs``.
    frames : iterable of (H, W, 3) uint8
        The clip's frames in order, from frame 0 (e.g. :func:`facetransfer.io.video.iter_frames`).
    track : Track or SyntheticTruth
        Anything with ``rotation (F, 3, 3)``, ``scale (F,)``, ``translation (F, 2)`` and
        ``weights`` (mode -> (F, r)): the per-frame pose of Eq. (7) and weights of Eq. (5).
    tex_size : int, keyword-only
    step : int, keyword-only
        Use frames 0, step, 2 step, ...
    power : float, keyword-only
        Obliqueness exponent of Eq. (1).
    progress : callable(int), optional, keyword-only
        Called with 1 after each used frame.

    Returns
    -------
    LiftedTrack
    """
    from .render import WeakPerspective

    if getattr(model, "uvs", None) is None:
        raise TextureError("lifting a UV texture needs a model with texture coordinates")
    if int(step) != step or step < 1:
        raise TextureError(f"step must be an integer >= 1, got {step!r}")
    n = int(np.asarray(track.scale).shape[0])
    faces = np.asarray(model.faces, dtype=np.int64)
    atlas = uv_atlas(faces, model.uvs, tex_size)
    lifted, attrs, used = [], [], []
    i = -1
    for i, frame in enumerate(frames):
        if i >= n:
            raise TextureError(f"the clip has more frames than the track ({n})")
        if i % step:
            continue
        w = {m: np.asarray(track.weights[m])[i] for m in model.mode_names}
        V = model.synthesize(w)  # Eq. (5)
        cam = WeakPerspective(float(track.scale[i]), track.rotation[i], track.translation[i])
        lifted.append(lift_uv_texture(frame, V, faces, model.uvs, cam, tex_size, atlas=atlas,
                                      power=power))
        attrs.append(attribute_vector(model, w))
        used.append(i)
        if progress is not None:
            progress(1)
    if i + 1 != n:
        raise TextureError(f"the clip has {i + 1} frames but the track has {n}")
    return LiftedTrack(lifted, np.asarray(attrs, dtype=np.float64), np.asarray(used, np.int64))


# --------------------------------------------------------------------------------------------
# default face texture
# --------------------------------------------------------------------------------------------

#: iBUG-68 landmark index groups used to place features on the procedural texture.
_LIPS_OUTER = list(range(48, 60))
_LIPS_INNER = list(range(60, 68))
_BROWS = (list(range(17, 22)), list(range(22, 27)))
_EYES = (list(range(36, 42)), list(range(42, 48)))


def default_face_texture(model_or_uvs, size: int = 512, seed: int = 0, *,
                         source: str = "procedural") -> np.ndarray:
    """The default face texture for a face mesh's UV layout.

    ``source="procedural"``: a plain procedural skin texture: skin tone with smooth
    low-frequency variation, fine noise (so that a KLT tracker finds gradients everywhere) and,
    where the landmarks can be located in UV space, darker red lips, darker brows and eyelid
    lines. Deterministic, fast, needs no asset.

    ``source="lee-perry-smith"``: the Lee Perry-Smith scan carried onto the ICT-FaceKit template
    UVs by template fitting (:func:`lee_perry_smith_template_texture`; first call about 15 s,
    then cached). Needs a mesh whose UVs are ICT-FaceKit's (e.g. a model built from the ICT
    data sets). Show it with the credit :data:`LEE_PERRY_SMITH_CREDIT`.
    ``source="auto"``: Lee Perry-Smith where it applies and its assets are available, else
    procedural.

    Parameters
    ----------
    model_or_uvs : MultilinearModel, FaceDataset, Mesh or (n, 2) array
        Anything with ``uvs`` (and optionally ``landmarks``, iBUG-68 vertex indices, and
        ``vertex_subset``, indices into the ICT-FaceKit mesh), or the uvs.
    size : int
        Texture width and height ``T``.
    seed : int
        Seed of the noise (procedural only).
    source : {"procedural", "lee-perry-smith", "auto"}, keyword-only

    Returns
    -------
    (T, T, 3) uint8 RGB, in the convention of :func:`facetransfer.render.sample_texture`.
    """
    if source not in ("procedural", "lee-perry-smith", "auto"):
        raise TextureError(f"source must be 'procedural', 'lee-perry-smith' or 'auto', got {source!r}")
    if source != "procedural":
        try:
            if not _uses_ict_uvs(model_or_uvs):
                raise TextureError("the Lee Perry-Smith texture is carried onto ICT-FaceKit UVs; "
                                   "this mesh's UVs are not ICT-FaceKit's")
            return lee_perry_smith_template_texture(size)
        except (FaceTransferError, RuntimeError, OSError, ImportError) as exc:
            if source == "lee-perry-smith":
                raise
            log.info("default_face_texture: Lee Perry-Smith texture not available (%s); "
                     "using the procedural texture", exc)
    if isinstance(model_or_uvs, np.ndarray):
        uvs, lm = model_or_uvs, None
    else:
        uvs = getattr(model_or_uvs, "uvs", None)
        lm = getattr(model_or_uvs, "landmarks", None)
    if uvs is None:
        raise TextureError("default_face_texture needs texture coordinates; the model has none")
    U = np.asarray(uvs, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] != 2 or U.shape[0] == 0 or not np.all(np.isfinite(U)):
        raise ShapeError(f"uvs must be a finite (n, 2) array, got {U.shape}")
    T = int(size)
    if T != size or T < 8 or T > 8192:
        raise TextureError(f"size must be an integer in 8..8192, got {size!r}")
    rng = np.random.default_rng(seed)
    base = np.array([214.0, 164.0, 138.0])  # a mid skin tone, RGB
    low = cv2.GaussianBlur(rng.normal(size=(T, T, 2)).astype(np.float32), (0, 0), T / 24)
    low /= np.maximum(low.std(axis=(0, 1)), 1e-6)
    # brightness (7 levels) and redness (4 levels) vary slowly over the face
    low = low[..., :1] * 7.0 * np.array([1.0, 0.85, 0.8]) + low[..., 1:] * 4.0 * np.array([1.0, -0.3, -0.3])
    mid = cv2.GaussianBlur(rng.normal(size=(T, T)).astype(np.float32), (0, 0), T / 128)
    mid *= 6.0 / max(float(mid.std()), 1e-6)
    fine = rng.normal(scale=5.0, size=(T, T)).astype(np.float32)
    fine = cv2.GaussianBlur(fine, (0, 0), 0.7) * 1.6
    tex = base + low + (mid + fine)[..., None]
    if lm is not None:
        L = np.asarray(lm, dtype=np.int64)
        if L.ndim == 1 and L.size == 68 and L.min() >= 0 and L.max() < U.shape[0]:
            tex = _paint_features(tex, U[L] * (T - 1) * [1, -1] + [0, T - 1], T)
        else:
            log.warning("default_face_texture: landmarks are not 68 valid vertex indices; "
                        "painting skin only")
    return texture_to_uint8(tex)


def _paint_features(tex: np.ndarray, pts: np.ndarray, T: int) -> np.ndarray:
    """Darken lips, brows and eyelids at landmark texel positions ``pts`` (68, 2) (col, row)."""
    scale = np.linalg.norm(pts[45] - pts[36])  # outer eye corners: the face's width in texels
    if not np.isfinite(scale) or scale < 2:
        return tex

    def layer(draw) -> np.ndarray:
        m = np.zeros((T, T), np.uint8)
        draw(m)
        return cv2.GaussianBlur(m.astype(np.float32) / 255.0, (0, 0), max(scale * 0.02, 0.8))

    def poly(idx):
        return np.rint(pts[idx] * 16).astype(np.int32).reshape(-1, 1, 2)

    lips = layer(lambda m: cv2.fillPoly(m, [poly(_LIPS_OUTER)], 255, cv2.LINE_AA, shift=4))
    mouth = layer(lambda m: cv2.fillPoly(m, [poly(_LIPS_INNER)], 255, cv2.LINE_AA, shift=4))
    thick = max(int(round(scale * 0.06)), 1)
    brows = layer(lambda m: [cv2.polylines(m, [poly(b)], False, 255, thick, cv2.LINE_AA, shift=4)
                             for b in _BROWS])
    lids = layer(lambda m: [cv2.polylines(m, [poly(e)], True, 255, max(thick // 2, 1),
                                          cv2.LINE_AA, shift=4) for e in _EYES])
    lip_col = np.array([170.0, 92.0, 90.0])
    tex = tex * (1 - lips[..., None]) + (lip_col + (tex - tex.mean((0, 1))) * 0.5) * lips[..., None]
    tex = tex * (1 - 0.5 * mouth[..., None])
    tex = tex * (1 - 0.55 * brows[..., None]) + np.array([60.0, 40.0, 30.0]) * 0.55 * brows[..., None]
    tex = tex * (1 - 0.35 * lids[..., None])
    return tex


# --------------------------------------------------------------------------------------------
# texture transfer between aligned meshes (e.g. a scan onto the fitted template's UVs)
# --------------------------------------------------------------------------------------------

class BakedTexture(NamedTuple):
    """A texture carried from one mesh onto another's UV layout.

    Attributes
    ----------
    texture : (T, T, 3) uint8
        Holes (texels with no source point within ``max_distance``) filled by push-pull.
    distance : (T, T) float32
        Distance from each texel's surface point to the source sample used (model units);
        ``inf`` outside the target's UV charts.
    """

    texture: np.ndarray
    distance: np.ndarray


def bake_texture(vertices, faces, uvs, source_vertices, source_faces, source_uvs, source_image,
                 tex_size: int = 512, *, source_samples: int | None = None,
                 max_distance: float | None = None) -> BakedTexture:
    """Carry a source mesh's colour map onto a target mesh's UVs by closest surface points.

    Both meshes must already be aligned in 3D (e.g. the template fitted to a scan, §4.1–4.2).
    The source surface is sampled densely (the texel points of a ``source_samples``² UV atlas
    of the source, coloured from ``source_image``); every covered texel of the target's UV atlas
    takes the colour of the nearest source sample. Used to put the Lee Perry-Smith scan
    (credit :data:`LEE_PERRY_SMITH_CREDIT`) on the template's UVs once the template is fitted.

    Parameters
    ----------
    vertices, faces, uvs : (n, 3) float64, (F, 3) int64, (n, 2) float64
        Target mesh (already aligned with the source) and its UVs.
    source_vertices, source_faces, source_uvs : (m, 3), (G, 3), (m, 2)
        Source mesh and its UVs (v up).
    source_image : (Hs, Ws, 3) uint8
        Source colour map (row 0 at the top, sampled like :func:`facetransfer.render.sample_texture`).
    tex_size : int
    source_samples : int, optional, keyword-only
        Side of the source sampling atlas; default ``max(Hs, Ws)``.
    max_distance : float, optional, keyword-only
        Texels farther than this from any source sample are holes (filled); default 5% of the
        target's bounding-box diagonal.

    Returns
    -------
    BakedTexture
    """
    from scipy.spatial import cKDTree

    from .render import sample_texture

    V, F = _check_vertices(vertices, faces)
    U = _check_uvs(uvs, V.shape[0])
    Vs, Fs = _check_vertices(source_vertices, source_faces)
    Us = _check_uvs(source_uvs, Vs.shape[0])
    img = np.asarray(source_image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise TextureError(f"source_image must be an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
    S = int(source_samples) if source_samples is not None else int(max(img.shape[:2]))
    src = UVAtlas(Fs, Us, S)
    P_src = src.interpolate(Vs)
    C_src = sample_texture(img, src.interpolate(Us))
    dst = uv_atlas(F, U, tex_size)
    P = dst.interpolate(V)
    d, j = cKDTree(P_src).query(P, k=1)
    if max_distance is None:
        max_distance = 0.05 * float(np.linalg.norm(np.ptp(V, axis=0)))
    ok = d <= max_distance
    col = np.where(ok[:, None], C_src[j], 0.0)
    known = dst.scatter(ok)
    tex = fill_holes(dst.scatter(col.astype(np.float32)), known)
    dist = dst.scatter(d.astype(np.float32), fill=np.inf)
    return BakedTexture(texture_to_uint8(tex), dist)


def load_lee_perry_smith():
    """The Lee Perry-Smith head scan and its colour map (credit :data:`LEE_PERRY_SMITH_CREDIT`).

    Returns
    -------
    mesh : Mesh
        9,279 vertices, 17,684 triangles, y up, facing +z; ``uvs`` converted to v up (the glTF
        file stores v down).
    image : (1024, 1024, 3) uint8 RGB
        ``Map-COL.jpg``.

    Raises
    ------
    AssetError
        The asset is missing (offline, no mirror) or fails its checksum.
    """
    from .assets import asset_path
    from .errors import AssetError
    from .io.mesh import Mesh, read_mesh

    root = asset_path("lee-perry-smith")
    mesh = read_mesh(root / "LeePerrySmith.glb")
    if mesh.uvs is None:
        raise AssetError(f"{root / 'LeePerrySmith.glb'} has no texture coordinates")
    uvs = mesh.uvs.copy()
    uvs[:, 1] = 1.0 - uvs[:, 1]  # glTF: v down -> v up
    img = cv2.imread(str(root / "Map-COL.jpg"), cv2.IMREAD_COLOR)
    if img is None:
        raise AssetError(f"{root / 'Map-COL.jpg'} is not an image OpenCV can read")
    return Mesh(mesh.vertices, mesh.faces, uvs), cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def lee_perry_smith_texture(fitted_vertices, faces, uvs, size: int = 512, *,
                            source_samples: int = 1024, use_cache: bool = True) -> np.ndarray:
    """The Lee Perry-Smith colour map carried onto a template's UVs (issue 5 default texture).

    Parameters
    ----------
    fitted_vertices : (n, 3) float64
        The template fitted to the Lee Perry-Smith scan, in the scan's coordinates
        (template fitting, §4.1–4.2).
    faces : (F, 3) int64
        The template's triangles.
    uvs : (n, 2) float64
        The template's UVs (v up).
    size : int
    source_samples : int, keyword-only
        Side of the scan's sampling atlas (:func:`bake_texture`); 1024 matches its colour map.
    use_cache : bool, keyword-only
        Reuse / store the result in the user cache (``cache_dir()/textures``), keyed by the
        inputs' content.

    Returns
    -------
    (size, size, 3) uint8
        Show it with the credit :data:`LEE_PERRY_SMITH_CREDIT`.
    """
    from .assets import cache_dir

    V, F = _check_vertices(fitted_vertices, faces)
    U = _check_uvs(uvs, V.shape[0])
    h = hashlib.sha256()
    for a in (V, F, U):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"lps-v1-{int(size)}-{int(source_samples)}".encode())
    path = cache_dir() / "textures" / f"lee-perry-smith-{h.hexdigest()[:16]}-{int(size)}.png"
    if use_cache and path.is_file():
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is not None and img.shape == (int(size), int(size), 3):
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    mesh, image = load_lee_perry_smith()
    tex = bake_texture(V, F, U, mesh.vertices, mesh.faces, mesh.uvs, image, size,
                       source_samples=source_samples).texture
    if use_cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_image(path, tex)
        log.info("cached the Lee Perry-Smith texture at %s", path)
    return tex


#: Bump when the Lee Perry-Smith template pipeline changes (invalidates cached results).
_LPS_PIPELINE_VERSION = 2
#: iBUG-68 points detected on the rendered scan and used as fitting features (no jaw contour).
_LPS_FEATURES = tuple(range(17, 68))


def _uses_ict_uvs(model_or_uvs) -> bool:
    """True if the mesh's UVs are those of ICT-FaceKit vertices (``vertex_subset`` or 0..n-1)."""
    from .datasets.ict import ict_template

    U = model_or_uvs if isinstance(model_or_uvs, np.ndarray) else getattr(model_or_uvs, "uvs", None)
    if U is None:
        return False
    U = np.asarray(U, dtype=np.float64)
    sub = None if isinstance(model_or_uvs, np.ndarray) else getattr(model_or_uvs, "vertex_subset", None)
    ict_uvs = ict_template("face").mesh.uvs
    sub = np.arange(U.shape[0]) if sub is None else np.asarray(sub, dtype=np.int64)
    if U.ndim != 2 or sub.shape != (U.shape[0],) or sub.size == 0 or sub.max() >= len(ict_uvs) \
            or sub.min() < 0:
        return False
    return bool(np.allclose(U, ict_uvs[sub], atol=1e-6))


def _lps_features(mesh, image, *, size: int = 640):
    """iBUG feature points on the Lee Perry-Smith scan: detected on a frontal rendering.

    The scan is rendered frontally with its colour map, MediaPipe's face landmarker finds the
    478 points (mapped to iBUG-68), and each point is lifted back onto the scan surface through
    the z-buffer (:func:`facetransfer.correspond.detect.detect_scan_features`).
    """
    from .correspond.detect import FeatureDetectionError, detect_scan_features

    V = mesh.vertices
    head = V[V[:, 1] > np.percentile(V[:, 1], 20)]  # the bust's head, not the shoulders
    try:
        return detect_scan_features(V, mesh.faces, uvs=mesh.uvs, texture=image, view="front",
                                    ids=_LPS_FEATURES, size=size, fill=0.9,
                                    frame_vertices=head).features
    except FeatureDetectionError:
        raise TextureError("no face found on the rendered Lee Perry-Smith scan") from None


def lee_perry_smith_template_texture(size: int = 512, *, use_cache: bool = True) -> np.ndarray:
    """The Lee Perry-Smith scan's colour map on the ICT-FaceKit template's UVs (issue 5).

    Pipeline (run once, then cached in the user cache, ``cache_dir()/textures``):

    1. feature points on the scan: iBUG-68 brows, nose, eyes and lips detected by MediaPipe on a
       frontal rendering and lifted onto the surface (:func:`_lps_features`);
    2. template fitting (§4.2, :func:`facetransfer.correspond.fitting.fit_template`) of the
       ICT-FaceKit face area to the scan;
    3. closest-point transfer of the colour map to the template's UVs (:func:`bake_texture`).

    The image applies to every mesh whose UVs are ICT-FaceKit's (the ICT data sets and the
    models built from them). Credit :data:`LEE_PERRY_SMITH_CREDIT` wherever it is shown.

    Parameters
    ----------
    size : int
        Texture width and height.
    use_cache : bool, keyword-only

    Returns
    -------
    (size, size, 3) uint8 RGB

    Raises
    ------
    AssetError
        The ICT-FaceKit, Lee Perry-Smith or MediaPipe assets are missing.
    TextureError, FitDivergedError
        No face detected on the scan, or the fit failed.
    """
    from .assets import cache_dir
    from .datasets.ict import ict_template

    T = int(size)
    if T != size or T < 8 or T > 8192:
        raise TextureError(f"size must be an integer in 8..8192, got {size!r}")
    tmpl = ict_template("face")
    h = hashlib.sha256()
    for a in (tmpl.mesh.vertices, tmpl.mesh.faces, tmpl.mesh.uvs, tmpl.landmarks):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"lps-ict-v{_LPS_PIPELINE_VERSION}".encode())
    key = h.hexdigest()[:16]
    folder = cache_dir() / "textures"
    tex_path = folder / f"lee-perry-smith-ict-face-{key}-{T}.png"
    fit_path = folder / f"lee-perry-smith-ict-face-{key}-fit.npy"
    if use_cache and tex_path.is_file():
        img = cv2.imread(str(tex_path), cv2.IMREAD_COLOR)
        if img is not None and img.shape == (T, T, 3):
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    fitted = None
    if use_cache and fit_path.is_file():
        try:
            fitted = np.load(fit_path, allow_pickle=False)
        except (OSError, ValueError):
            fitted = None
        if fitted is not None and fitted.shape != tmpl.mesh.vertices.shape:
            fitted = None
    if fitted is None:
        from .correspond.fitting import fit_template, load_template
        from .correspond.meshops import clean_scan

        mesh, image = load_lee_perry_smith()
        features = _lps_features(mesh, image)
        scan = clean_scan(mesh.vertices, mesh.faces, name="LeePerrySmith.glb")
        fit = fit_template(scan, features, load_template("ict"))   # with the identity prior
        log.info("fitted the ICT template to the Lee Perry-Smith scan: %s", fit.stats)
        fitted = fit.vertices
        if use_cache:
            folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(fit_path) as tmp:
                np.save(tmp, fitted)
    tex = lee_perry_smith_texture(fitted, tmpl.mesh.faces, tmpl.mesh.uvs, T, use_cache=False)
    if use_cache:
        folder.mkdir(parents=True, exist_ok=True)
        write_image(tex_path, tex)
    return tex

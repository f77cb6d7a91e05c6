"""Lifting the texture from video (§6, Eq. (L1)): frame colours onto mesh vertices or texels.

"Once we obtain the 3D geometry, we can lift the texture from the video by assigning pixel colors
to the corresponding mesh vertices." Every sample (a vertex, or a texel's surface point) takes the
frame's colour where it projects, with the confidence weight

    weight = visible * max(0, n_c . d)^p                                             (L1)

where ``n_c`` is the unit surface normal in camera coordinates, ``d`` the unit direction from the
surface towards the camera (``(0, 0, 1)`` for the weak-perspective camera of §5.1, Eq. (7)) and
``visible`` the z-buffer test of :mod:`facetransfer.render`. Eq. (L1) and the sampling are written
once (:func:`_weighted_samples`) for both :func:`lift_vertex_colors` and :func:`lift_uv_texture`;
:func:`lift_track` runs the UV lifting over a tracked (or synthetic) clip, keeping every
frame's texture (for the texture function); :func:`lift_merged` merges them as they come.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from ..geometry import barycentric_2d, vertex_normals
from ..render import rasterize, vertex_visibility
from .atlas import UVAtlas, uv_atlas
from .base import TextureError, check_frame, check_raster, check_uvs, check_vertices, default_tol
from .function import attribute_vector
from .merge import MergedTexture, TextureSum

log = logging.getLogger(__name__)

__all__ = ["LiftedTexture", "LiftedUVTexture", "LiftedTrack", "obliqueness_weight",
           "lift_vertex_colors", "lift_uv_texture", "lift_track", "lift_merged"]


class LiftedTexture(NamedTuple):
    """Per-vertex colours lifted from one frame.

    Attributes
    ----------
    colors : (n_vertices, 3) float32
        RGB on the 0..255 scale; 0 where the weight is 0.
    weights : (n_vertices,) float32
        Confidence (L1): visibility times obliqueness, in [0, 1].
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
        Confidence (L1) per texel, in [0, 1]; 0 outside the UV charts.
    """

    texture: np.ndarray
    weight: np.ndarray


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
    """``max(0, n_c . d)^p`` of Eq. (L1): how squarely the surface faces the camera.

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


def _weighted_samples(frame: np.ndarray, points: np.ndarray, normals: np.ndarray,
                      visible: np.ndarray, camera, power: float, what: str
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The weights (L1) of surface samples and the frame's colours where they project.

    Parameters
    ----------
    frame : (H, W, 3) uint8
    points : (m, 3) float64
        Surface points (vertices or texel points), model coordinates.
    normals : (m, 3) float64
        Their normals (need not be unit).
    visible : (m,) bool
        The z-buffer test of every point.
    camera : WeakPerspective or Pinhole
    power : float
        ``p`` of Eq. (L1).
    what : str
        Start of the warning logged when nothing is visible (e.g. ``"lift_uv_texture: no texel"``).

    Returns
    -------
    colors : (m, 3) float32
        Bilinear samples, 0 where the weight is 0.
    weights : (m,) float64
        Eq. (L1), in [0, 1].
    """
    w = obliqueness_weight(normals, points, camera, power=power) * visible  # Eq. (L1)
    colors = np.zeros((points.shape[0], 3), np.float32)
    idx = np.flatnonzero(w > 0)
    if idx.size:
        colors[idx] = _bilinear(frame, camera.project(points[idx]))
    else:
        H, W = frame.shape[:2]
        log.warning("%s of the mesh is visible in the %dx%d frame", what, W, H)
    return colors, w


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
        b = barycentric_2d(sxy, xy[j])
        d = np.einsum("mk,mk->m", b, sz)
        vis[j] = d <= z[j] + tol
    # background at the nearest pixel (point on a silhouette edge): not occluded
    vis[idx[~own & (win < 0)]] = True
    return vis


# --------------------------------------------------------------------------------------------
# per-vertex and UV lifting
# --------------------------------------------------------------------------------------------

def _checked_inputs(frame, vertices, faces, raster, tol):
    """The checked frame, vertices ``(n, 3)``, faces ``(F, 3)`` and raster of one lift, and its
    depth tolerance (default :func:`.base.default_tol`)."""
    f = check_frame(frame)
    V, F = check_vertices(vertices, faces)
    raster = check_raster(raster, f)
    return f, V, F, raster, default_tol(V) if tol is None else float(tol)


def lift_vertex_colors(frame, vertices, faces, camera, *, raster=None, power: float = 2.0,
                       tol: float | None = None) -> LiftedTexture:
    """Assign each mesh vertex the frame's colour where it projects (§6), with weight (L1).

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
        Obliqueness exponent ``p`` of Eq. (L1).
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
    f, V, F, raster, tol = _checked_inputs(frame, vertices, faces, raster, tol)
    H, W = f.shape[:2]
    vis = vertex_visibility(V, F, camera, (W, H), raster=raster, tol=tol)
    colors, w = _weighted_samples(f, V, vertex_normals(V, F), vis, camera, power,
                                  "lift_vertex_colors: no vertex")
    return LiftedTexture(colors, w.astype(np.float32))


def lift_uv_texture(frame, vertices, faces, uvs, camera, tex_size: int = 512, *, raster=None,
                    atlas: UVAtlas | None = None, power: float = 2.0,
                    tol: float | None = None) -> LiftedUVTexture:
    """Lift a UV texture from one frame: every covered texel samples the frame (§6).

    Each texel's surface point (barycentric in its UV triangle) is projected into the frame and
    sampled bilinearly; its weight is Eq. (L1) with the interpolated normal and a z-buffer
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
        Obliqueness exponent ``p`` of Eq. (L1).
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
    f, V, F, raster, tol = _checked_inputs(frame, vertices, faces, raster, tol)
    U = check_uvs(uvs, V.shape[0])
    H, W = f.shape[:2]
    if atlas is None:
        atlas = uv_atlas(F, U, tex_size)
    elif not atlas.matches(F, U, tex_size):
        raise TextureError("atlas was built for other faces, uvs or tex_size")
    if raster is None:
        raster = rasterize(V, F, camera, (W, H))
    P = atlas.interpolate(V)  # (m, 3) texel surface points
    N = atlas.interpolate(vertex_normals(V, F))
    vis = _visible_points(P, atlas.texel_triangles, V, F, camera, raster, tol)
    col, w = _weighted_samples(f, P, N, vis, camera, power, "lift_uv_texture: no texel")
    return LiftedUVTexture(atlas.scatter(col), atlas.scatter(w.astype(np.float32)))


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
        The frames' attribute vectors (:func:`attribute_vector`), for
        :class:`~.function.TextureFunction`.
    frames : (F,) int64
        Indices of the used frames in the clip.
    """

    lifted: list
    attributes: np.ndarray
    frames: np.ndarray


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
        Anything with ``camera(i)`` (the weak-perspective camera of Eq. (7) at frame ``i``),
        ``scale (F,)`` and ``weights`` (mode -> (F, r), Eq. (5)).
    tex_size : int, keyword-only
    step : int, keyword-only
        Use frames 0, step, 2 step, ...
    power : float, keyword-only
        Obliqueness exponent of Eq. (L1).
    progress : callable(int), optional, keyword-only
        Called with 1 after each used frame.

    Returns
    -------
    LiftedTrack
        Every used frame's texture, held: ``tex_size² x 16`` bytes each (4 MB at 512);
        :func:`lift_merged` merges them as they come instead.
    """
    lifted, attrs, used = [], [], []
    for i, w, tex in _lifted_frames(model, frames, track, tex_size, step, power, progress):
        lifted.append(tex)
        attrs.append(attribute_vector(model, w))
        used.append(i)
    return LiftedTrack(lifted, np.asarray(attrs, dtype=np.float64), np.asarray(used, np.int64))


def lift_merged(model, frames, track, *, tex_size: int = 256, step: int = 1,
                power: float = 2.0, progress=None) -> tuple[MergedTexture, int]:
    """:func:`lift_track` merged (:func:`facetransfer.texture.merge.merge_textures`, holes
    filled) as the frames come, in the memory of one texture whatever the clip's length.

    Parameters
    ----------
    model, frames, track, tex_size, step, power, progress
        As :func:`lift_track`'s.

    Returns
    -------
    merged : MergedTexture
        ``(tex_size, tex_size, 3)`` and its total weight per texel.
    n_used : int
        The frames lifted.
    """
    sums = TextureSum()
    for _, _, tex in _lifted_frames(model, frames, track, tex_size, step, power, progress):
        sums.add(*tex)
    return sums.merged(), sums.count


def _lifted_frames(model, frames, track, tex_size: int, step: int, power: float, progress):
    """Yield ``(i, weights (mode -> (r,)), LiftedUVTexture)`` of every ``step``-th frame of
    the clip; raise :class:`TextureError` unless the clip has the track's frames."""
    if getattr(model, "uvs", None) is None:
        raise TextureError("lifting a UV texture needs a model with texture coordinates")
    if int(step) != step or step < 1:
        raise TextureError(f"step must be an integer >= 1, got {step!r}")
    n = int(np.asarray(track.scale).shape[0])
    faces = np.asarray(model.faces, dtype=np.int64)
    atlas = uv_atlas(faces, model.uvs, tex_size)
    i = -1
    for i, frame in enumerate(frames):
        if i >= n:
            raise TextureError(f"the clip has more frames than the track ({n})")
        if i % step:
            continue
        w = {m: np.asarray(track.weights[m])[i] for m in model.mode_names}
        V = model.synthesize(w)  # Eq. (5)
        yield i, w, lift_uv_texture(frame, V, faces, model.uvs, track.camera(i), tex_size,
                                    atlas=atlas, power=power)
        if progress is not None:
            progress(1)
    if i + 1 != n:
        raise TextureError(f"the clip has {i + 1} frames but the track has {n}")

"""Z-buffer rasterisation and shading of triangle meshes under the tracker's cameras (paper §5.1,
§6).

The tracker of Vlasic et al. (2005) images the face with a weak-perspective camera (§5.1,
Eq. (7)): a vertex ``X`` (model coordinates, y up, camera looking along -z) lands at the pixel

    p = s * diag(1, -1) @ R[:2] @ X + t                                         # Eq. (7)

with ``s`` pixels per model unit, ``R`` a rotation and ``t`` an image translation in pixels
(x right, y down; the centre of the top-left pixel is (0, 0)). The depth of a point is
``(R @ X)[2]``: larger is nearer the camera. A pinhole camera is provided for previews.

The package turns a mesh and a camera (:mod:`.cameras`: any :class:`Camera`) into

* a :class:`Raster` (:mod:`.raster`): per pixel the depth, the id of the nearest triangle and its
  barycentric coordinates (perspective-correct for the pinhole camera);
* per-vertex visibility (:func:`vertex_visibility`, :mod:`.visibility`), which the tracker needs
  every frame to choose the vertices it follows and the texture lifting (§6) needs to weight
  samples;
* a colour image (:func:`render`, here; the shading kernels in :mod:`.shading`) from per-vertex
  colours or a UV texture, optionally Lambert-shaded.

Every public name is importable from ``facetransfer.render``, but
:func:`.raster.coverage` and :data:`.shading.MAX_LAYERS` (from their modules).

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
from dataclasses import dataclass

import numpy as np

from ..background import background_image
from ..errors import RenderError, ShapeError
from ..geometry import check_mesh as _check_mesh
from .cameras import (Camera, Pinhole, WeakPerspective, _as_size, euler_from_rotation,
                      look_at_weak_perspective, project_frames, rotation_from_euler)
from .raster import (Raster, Rasterizer, _check_not_all_degenerate, _rasterize_checked, rasterize,
                     rasterize_reference)
from .shading import (_check_colors, check_shading, check_textured, interpolate_vertex_values,
                      sample_texture, shade_image, shade_layers, shade_texture)
from .visibility import _tolerance, _visibility, vertex_visibility

log = logging.getLogger(__name__)

__all__ = [
    "Camera",
    "WeakPerspective",
    "Pinhole",
    "Raster",
    "RenderResult",
    "RenderError",
    "rasterize",
    "Rasterizer",
    "rasterize_reference",
    "vertex_visibility",
    "render",
    "rotation_from_euler",
    "euler_from_rotation",
    "look_at_weak_perspective",
    "project_frames",
    "render_model",
    "sample_texture",
    "shade_texture",
    "shade_layers",
    "interpolate_vertex_values",
]


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
    check_shading(shading, ambient)
    n = V.shape[0]
    T, UV = check_textured(texture, uvs, n)
    C = _check_colors(colors, n) if colors is not None else None
    image = (np.zeros((H, W, 3), np.uint8) if background is None
             else background_image(background, W, H))

    raster = _rasterize_checked(V, F, camera, W, H, cull_backfaces)
    if not raster.mask.any():
        log.warning("the mesh is entirely behind the camera or outside the %dx%d image; "
                    "rendering the background only", W, H)
        return RenderResult(image, raster, np.zeros(n, bool))
    visible = _visibility(V, F, camera, raster, _tolerance(V, visibility_tol))
    shade_image(image, raster, V, F, camera.rotation, texture=T, uvs=UV, colors=C,
                lambert=shading == "lambert", light=light, ambient=float(ambient))
    return RenderResult(image, raster, visible)


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
        Head rotation in degrees, render angles (:func:`rotation_from_euler`: ``R = Rz(roll)
        Ry(yaw) Rx(pitch)``; yaw > 0 turns the face toward the image's right, pitch > 0 looks
        down, roll > 0 turns it counter-clockwise), about the centre of the face's box.
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

"""One rewritten frame: the new performance rendered back into a frame of the target footage
(Vlasic et al. 2005, §6).

For a frame of the target video (§6, Fig. 7C–7E):

1. the new face geometry (Eq. (5) with the recombined weights) is posed with the target's camera
   (Eq. (7)) and rasterised;
2. the mouth gap of the mesh is closed for texturing, as the paper does ("the mouth shapes closed-
   off for texturing", Fig. 7A–C): the inner-lip boundary loop is triangulated as a fan around an
   added centre vertex (:func:`facetransfer.topology.mesh_topology`,
   :func:`facetransfer.topology.close_mouth`);
3. the face is textured with the target's face texture (``texture="constant"``: lifted from the
   target video, one texture for the whole clip, as in the paper; ``"frame"``, the default:
   lifted from the current target frame, which keeps that frame's lighting; where the new face
   lies within half a pixel of where that frame's track has it, the frame's own pixels, not
   resampled: :mod:`facetransfer.unmoved`), the mouth (lips and
   the closed gap) with the *source* performance's mouth (the source frame warped through the
   source's own tracked geometry: the performance-driven texture of §6 with the nearest
   neighbour being the source's own frame, read where the source's lips were detected and the
   new lips moved by the fit's residual there, :mod:`facetransfer.lips`; or the texture
   function of §6, :mod:`facetransfer.texture.face`), scaled to the face's colours by a gain
   fitted on the skin around it (:mod:`facetransfer.mouth`);
4. the rendered face is blended into the target frame in the gradient domain (Pérez et al.
   2003): ``blend="poisson"`` solves the Poisson equation exactly
   (:func:`facetransfer.composite.composite_face`); ``"fast"`` (default, ~5x faster) adds a
   membrane correction interpolated from the region's outline
   (:func:`facetransfer.composite.membrane_blend`). The blend region stays a few pixels inside
   the rendered silhouette, so its boundary lies on the target's own face. The mesh's eye holes
   are closed and the lids, eyes and brows textured from an open-eyed target frame
   (:mod:`facetransfer.eyes`, ``eyes="model"``, the default), so the new performance's blinks
   show; with ``eyes="target"`` the holes stay out of the rendered mask and the target's own
   eyes show through them (§6). Outside
   the (feathered) face mask the output equals the target frame exactly. Frames where the face
   is lost keep the original frame.

:func:`rewrite_frame` does one frame (:func:`rewrite_frame_part`: its work on the face's box
only). A clip, whose frames share their textures and meshes, is
:func:`facetransfer.rewrite_clip.rewrite_frames`; the whole job (reading, tracking,
recombining, writing) is :mod:`facetransfer.video_transfer`.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, §6, Fig. 7.
Pérez, Gangnet, Blake. Poisson image editing. SIGGRAPH 2003.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from .composite import (composite_alpha, composite_face, erode_mask, extend_nearest,
                        membrane_alpha, membrane_blend, over)
from .errors import ShapeError
from .face_scale import face_scale, face_span
from .rim import drawn_inside, lifted_positions
from .unmoved import unmoved_uvs
from .eyes import EyeTexture, paint_shaded_eyes
from .jaw import JawTexture, paint_shaded_jaw
from .label_masks import frame_masks
from .layer_flags import layer_flags
from .lip_colour import LipTint, tint_mouth
from .mouth import blend_mouth, inside_mouth, mouth_ring_faces
from .mouth_inside import DrawnInside, paint_inside
from .texture.face import FaceTexture
from .render import shade_layers
from .jit import maybe_njit as _maybe_njit, read_only
from .rewrite_options import BlendOptions
from .topology import MeshTopology, close_mouth

log = logging.getLogger(__name__)

__all__ = [
    "FrameTextures",
    "RewriteFrame",
    "rewrite_frame",
    "rewrite_frame_part",
    "paste_part",
    "paste_image",
]


@dataclass(frozen=True)
class RewriteFrame:
    """One rewritten frame.

    Attributes
    ----------
    image : (H, W, 3) uint8
        The composite.
    rendered : (H, W, 3) uint8
        The textured new face before blending (black outside ``face_mask``).
    face_mask : (H, W) bool
        Pixels covered by the closed new mesh (eye holes excluded).
    mouth_mask : (H, W) bool
        Pixels textured from the source's mouth.
    matte : (H, W) float32 in [0, 1], optional
        Asked for (``matte=True``): the fraction of each pixel the blend took from the new
        face, the alpha with which ``image`` departs from the target frame: 0 where ``image``
        is the frame's own pixel exactly, 1 where it was wholly replaced, between on the
        feathered seam (:func:`_blend_matte`); all 0 in a frame without a face. None when not
        asked for.
    """

    image: np.ndarray
    rendered: np.ndarray
    face_mask: np.ndarray
    mouth_mask: np.ndarray
    matte: np.ndarray | None = None


@dataclass(frozen=True)
class FrameTextures:
    """What the new face is painted with at one frame (§6): the target's face texture and the
    textures laid over it.

    Attributes
    ----------
    face : FaceTexture
        The target's face texture (uvs for the closed mesh).
    mouth : FaceTexture, optional
        The source's mouth for this frame; without it the face texture covers the mouth.
    eyes : EyeTexture, optional
        The eye region's texture (the topology then has its eye holes closed:
        :func:`facetransfer.eyes.eye_texture`); without it the target's eyes show through.
    jaw : JawTexture, optional
        The jaw region's texture from a closed-mouth target frame
        (:func:`facetransfer.jaw.jaw_texture`, for the topology), pasted with its per-vertex
        ``alpha`` (:meth:`facetransfer.jaw.JawTexture.at` gives a frame's); without it the jaw
        is textured from ``face`` like the rest of the face.
    mouth_ring : (F',) bool, optional
        The triangles around the mouth whose colours in the source's frame and in the face
        set the mouth's gain; default :func:`facetransfer.mouth.mouth_ring_faces` of the
        topology.
    lip_tint : LipTint, optional
        The target's lip colour for the source's lips (:mod:`facetransfer.lip_colour`);
        without it the lips keep the source's colour against the skin.
    inside : DrawnInside, optional
        The mouth's inside painted over ``mouth``'s in the mouth's opening where it opens wider
        than the frames ``mouth`` comes from show (:mod:`facetransfer.mouth_inside`).
    """

    face: FaceTexture
    mouth: FaceTexture | None = None
    eyes: EyeTexture | None = None
    jaw: JawTexture | None = None
    mouth_ring: np.ndarray | None = None
    lip_tint: LipTint | None = None
    inside: DrawnInside | None = None


def rewrite_frame(target_frame: np.ndarray, vertices: np.ndarray, camera, topo: MeshTopology,
                  textures: FrameTextures, *, blending: BlendOptions | None = None,
                  matte: bool = False, scale: float | None = None) -> RewriteFrame:
    """Render the new face into one target frame (§6): :func:`rewrite_frame_part` pasted
    into the frame.

    Parameters
    ----------
    target_frame : (H, W, 3) uint8
    vertices : (n_vertices, 3) or (n_closed, 3)
        The new face (Eq. (5)) in model coordinates; the mouth is closed here if needed.
    camera : WeakPerspective
        The target's pose at this frame (Eq. (7)).
    topo : MeshTopology
    textures : FrameTextures
        The target's face texture and the mouth, eye and jaw textures over it.
    blending : BlendOptions, optional
        How the rendered face goes into the frame (default :class:`BlendOptions`: the
        membrane blend, ``"fast"``).
    matte : bool
        Also give :attr:`RewriteFrame.matte` (computed only when asked).
    scale : float, optional
        The factor of the rewrite's pixel settings for the face's size
        (:func:`facetransfer.face_scale.face_scale`); default: of this frame's face.

    Returns
    -------
    RewriteFrame
    """
    return paste_part(np.asarray(target_frame), rewrite_frame_part(
        target_frame, vertices, camera, topo, textures, blending=blending, matte=matte,
        scale=scale), matte=matte)


def rewrite_frame_part(target_frame: np.ndarray, vertices: np.ndarray, camera,
                       topo: MeshTopology, textures: FrameTextures, *,
                       blending: BlendOptions | None = None, matte: bool = False,
                       scale: float | None = None):
    """:func:`rewrite_frame`'s work, on the face's box only: ``(box, RewriteFrame of the
    box)`` with ``box = (x0, y0, x1, y1)`` (end exclusive) in the frame, or None where the face
    is not in the frame; :func:`paste_part` makes the whole frame of it (a render in processes
    sends back this much, not a frame). ``scale``: as :func:`rewrite_frame`'s (a clip's
    frames take their shot's: :func:`facetransfer.face_scale.shot_scale`)."""
    T = np.asarray(target_frame)
    if T.ndim != 3 or T.shape[2] != 3 or T.dtype != np.uint8:
        raise ShapeError(f"target frame must be (H, W, 3) uint8, got {T.shape} {T.dtype}")
    blending = BlendOptions() if blending is None else blending
    H, W = T.shape[:2]
    V = np.asarray(vertices, dtype=np.float64)
    if V.shape[0] == topo.n_vertices:
        V = close_mouth(V, topo)
    if V.shape != (topo.n_closed, 3):
        raise ShapeError(f"vertices must be ({topo.n_vertices} or {topo.n_closed}, 3), "
                         f"got {V.shape}")
    # the pixel settings of a face larger than the ones they were chosen for, grown with it
    if scale is None:
        scale = face_scale(face_span(V, camera, topo.eye_loops))
    blending = blending.scaled(scale)
    # all per-frame work happens in the face's bounding box (plus a margin wider than any
    # filter below: erosion, outline ring, membrane margin, feathering); the rest is T
    box = _face_box(V, camera, (W, H),
                    margin=int(blending.erode) + int(np.ceil(blending.feather)) + 16)
    if box is None:  # nothing of the face in the frame
        return None
    x0, y0, x1, y1 = box
    cam = camera if box == (0, 0, W, H) else _shift_camera(camera, x0, y0)
    if textures.mouth is not None and textures.mouth_ring is None:
        textures = dataclasses.replace(textures, mouth_ring=mouth_ring_faces(topo))
    lifted = lifted_positions(textures.face, target_frame)  # None: not the frame's own
    res = _rewrite_crop(T[y0:y1, x0:x1], V, cam, topo, textures, blending,
                        None if lifted is None else lifted - (x0, y0), matte=matte, scale=scale)
    return box, res


def paste_part(T: np.ndarray, part, *, matte: bool = False) -> RewriteFrame:
    """The full frame from ``(box, crop result)``; ``None``: the frame unchanged, no face
    (``matte``: with an all-zero matte)."""
    H, W = T.shape[:2]
    if part is None:
        empty = np.zeros((H, W), bool)
        return RewriteFrame(T.copy(), np.zeros_like(T), empty, empty.copy(),
                            np.zeros((H, W), np.float32) if matte else None)
    (x0, y0, x1, y1), res = part
    if (x0, y0, x1, y1) == (0, 0, W, H):
        return res

    def paste(crop, base):
        base[y0:y1, x0:x1] = crop
        return base

    return RewriteFrame(paste(res.image, T.copy()), paste(res.rendered, np.zeros_like(T)),
                        paste(res.face_mask, np.zeros((H, W), bool)),
                        paste(res.mouth_mask, np.zeros((H, W), bool)),
                        None if res.matte is None else
                        paste(res.matte, np.zeros((H, W), np.float32)))


def paste_image(T: np.ndarray, part) -> tuple[np.ndarray, bool]:
    """The composite of the whole frame from ``(box, crop result)`` (None: the frame
    unchanged), as :func:`paste_part`'s ``image``, and whether a face was rendered (its
    ``face_mask`` has a pixel): a writer's share of a frame, without the whole frame's rendered
    face and masks (:func:`facetransfer.rewrite_clip.rewrite_frame_parts`)."""
    image = T.copy()
    if part is None:
        return image, False
    (x0, y0, x1, y1), res = part
    image[y0:y1, x0:x1] = res.image
    return image, bool(res.face_mask.any())


def _face_box(V: np.ndarray, camera, size: tuple[int, int], *, margin: int
              ) -> tuple[int, int, int, int] | None:
    """``(x0, y0, x1, y1)`` (end exclusive) of the mesh's projection grown by ``margin``
    pixels and clipped to the frame; the whole frame for cameras other than weak perspective;
    None when the projection misses the frame."""
    from .render import WeakPerspective

    W, H = size
    if not isinstance(camera, WeakPerspective):
        return 0, 0, W, H
    ext = np.empty(4, np.int64)  # the finite points' box grown by margin (one kernel)
    if not _extent_kernel(camera.project(V), int(margin), ext):
        return None
    x0, y0, x1, y1 = ext.tolist()
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _extent_kernel_py(p, margin, ext):  # pragma: no cover (numba)
    """``ext`` (4,) int64 = ``floor`` of the least x and y less ``margin`` and ``ceil`` of the
    largest plus ``margin + 1``, of the points ``p`` (n, 2) float64 whose coordinates are both
    finite (int64 as numpy casts and adds); whether there is one. (:func:`_face_box`'s numpy
    steps, the rows with a non-finite coordinate dropped, the extremes, floor and ceil and
    the margin, in one pass.)"""
    found = False
    xlo = ylo = np.inf
    xhi = yhi = -np.inf
    for i in range(p.shape[0]):
        x, y = p[i, 0], p[i, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        found = True
        xlo, xhi = min(xlo, x), max(xhi, x)
        ylo, yhi = min(ylo, y), max(yhi, y)
    if found:
        ext[0], ext[1] = np.int64(np.floor(xlo)) - margin, np.int64(np.floor(ylo)) - margin
        ext[2] = np.int64(np.ceil(xhi)) + margin + 1
        ext[3] = np.int64(np.ceil(yhi)) + margin + 1
    return found


_extent_kernel = _maybe_njit(_extent_kernel_py)


def _shift_camera(camera, x0: int, y0: int):
    """The camera of the crop whose top-left pixel is ``(x0, y0)`` of the frame."""
    return camera.shifted(float(x0), float(y0))


def _rewrite_crop(T, V, camera, topo, textures: FrameTextures, blending: BlendOptions,
                  lifted=None, *, matte: bool = False, scale: float = 1.0) -> RewriteFrame:
    """:func:`rewrite_frame` on a crop ``T`` of the frame, ``camera`` shifted to the crop;
    ``lifted``: where the per-frame face texture lifted the vertices, in the crop's pixels
    (:func:`facetransfer.rim.lifted_positions`), or None; ``matte``: with its matte
    (:func:`_blend_matte`); ``scale``: the pixel settings' factor for the face's size
    (:func:`facetransfer.face_scale.face_scale`; ``blending`` is scaled already)."""
    from .render.raster import rasterize_drawn

    # the raster and where it drew the vertices (camera.project(V), one projection for both)
    raster, drawn = rasterize_drawn(V, topo.faces, camera, (T.shape[1], T.shape[0]))
    own = None
    if lifted is not None:
        own, textures = _target_own(T, V, camera, topo, textures, raster, drawn, lifted, scale)
    face_img, face_mask, mouth_img, mouth_mask, ring = _shade_frame(raster, V, topo, textures,
                                                                    own, scale)
    lip_tint, erode, feather = textures.lip_tint, blending.erode, blending.feather
    fan = inside_mouth(raster.tri_id, topo) if mouth_img is not None else None
    if textures.inside is not None and fan is not None:  # an inside its frames never show
        paint_inside(mouth_img, raster, V, camera, topo, textures.inside, fan)
    if lip_tint is not None and mouth_img is not None:  # the target's lip colour, not inside
        tint_mouth(mouth_img, raster, topo.faces, lip_tint,
                   mouth_mask if fan is None else mouth_mask & ~fan)
    rendered = face_img if mouth_img is None else over(face_img, mouth_img, mouth_mask)
    if not face_mask.any():
        return RewriteFrame(T.copy(), rendered, face_mask, mouth_mask,
                            np.zeros(face_mask.shape, np.float32) if matte else None)
    # The blend region stays ``erode`` pixels inside the rendered silhouette, so its outline
    # (the Dirichlet boundary of the Poisson problem) lies on the target's own face, which
    # covers the same silhouette up to the change of expression, not on the background.
    region = erode_mask(face_mask, int(erode)) if erode > 0 else face_mask
    if not region.any():
        region = face_mask
    if blending.mode == "none":
        out = over(T, rendered, region)
    elif blending.mode == "fast":
        face = rendered
        if mouth_img is not None and mouth_mask.any():
            # the source's mouth first takes the colours of the face around it (a gain)
            face = blend_mouth(T, face_img, face_mask, mouth_img, mouth_mask & region, ring,
                               blending.mouth_feather, fan, scale=scale)
        out = membrane_blend(T, face, region, feather=feather)
    else:
        # The guidance field on the region's outline is the source's difference across it, so
        # each source is extended beyond its mask by its nearest inside pixel (no step there).
        face_src = extend_nearest(face_img, face_mask)
        if mouth_img is not None and (mouth_mask & region).any():
            mouth_src = extend_nearest(mouth_img, mouth_mask)
            out = composite_face(T, face_src, region, mouth_source=mouth_src,
                                 mouth_mask=mouth_mask & region,
                                 color_match=blending.color_match, feather=feather)
        else:
            out = composite_face(T, face_src, region, color_match=blending.color_match,
                                 feather=feather)
    return RewriteFrame(np.ascontiguousarray(out, dtype=np.uint8), rendered, face_mask,
                        mouth_mask, _blend_matte(region, mouth_mask if mouth_img is not None
                                                 else None, blending) if matte else None)


def _target_own(T, V, camera, topo, textures: FrameTextures, raster, drawn, lifted, scale):
    """Where :func:`_rewrite_crop` keeps the crop ``T``'s own pixels, given ``lifted`` (where
    the per-frame face texture lifted the vertices) and ``drawn`` (where the raster drew
    them): ``(own, textures)``, ``own = (T, where)`` of :func:`_shade_frame` (the target's
    outline drawn inside its face, :func:`facetransfer.rim.drawn_inside`), ``textures`` with
    the face texture looked up where drawn where the new face did not move
    (:func:`facetransfer.unmoved.unmoved_uvs`)."""
    from .render import WeakPerspective

    # (a pinhole draws by its own formula; the raster's projection is of V made
    # C-contiguous float64, which a product of another layout might round otherwise)
    if not isinstance(camera, WeakPerspective) or not (
            V.dtype == np.float64 and V.flags.c_contiguous):
        drawn = camera.project(V)
    # not the target's own outline drawn inside its face: the target's pixels there instead
    own = (T, drawn_inside(raster.mask, raster, topo.faces, lifted, drawn, scale=scale))
    # nor its pixels resampled where the new face did not move: looked up where drawn
    face = textures.face
    uvs = unmoved_uvs(face.uvs, (face.image.shape[1], face.image.shape[0]), lifted, drawn)
    if uvs is not None:
        textures = dataclasses.replace(textures, face=dataclasses.replace(face, uvs=uvs))
    return own, textures


def _blend_matte(region: np.ndarray, mouth_mask: np.ndarray | None,
                 blending: BlendOptions) -> np.ndarray:
    """The matte of one crop's blend (:attr:`RewriteFrame.matte`), (h, w) float32: the alpha
    with which the blend of ``blending.mode`` departs from the target over ``region`` (h, w)
    bool (the eroded face mask) and, with a source's mouth, ``mouth_mask`` (h, w) bool (its
    pixels): ``"none"`` the region (pasted over), ``"fast"`` the membrane blend's seam fade
    (:func:`facetransfer.composite.membrane_alpha`), ``"poisson"`` the solve's feathered masks
    (:func:`facetransfer.composite.composite_alpha`, which reach ``feather`` pixels beyond the
    region). Outside it the output is the target's pixel to the bit; inside it may equal it.

    The pixels kept as the target's own (its outline drawn inside the face, ``_keep_own``)
    count as the new face's: they are blended like the rest (the membrane's correction added,
    or solved for), so the output there is not the target's pixel to the bit, and a compositor
    who keeps the plate where the matte is 0 must take them from the rewrite."""
    if blending.mode == "none":
        return region.astype(np.float32)
    if blending.mode == "fast":
        return membrane_alpha(region, feather=blending.feather)
    mouth = None if mouth_mask is None else mouth_mask & region
    if mouth is not None and not mouth.any():
        mouth = None
    return composite_alpha(region, mouth_mask=mouth, feather=blending.feather)


#: The layers of one frame's shading (bits of :func:`facetransfer.render.shade_layers`' flags):
#: the face texture (every triangle), the eye region's, the jaw region's (and its ring), the
#: source's mouth; and labels: the eye region's rim, the jaw region, the jaw region's ring.
_FACE, _EYES, _JAW, _MOUTH = 1, 2, 4, 8
_RIM, _JAW_REGION, _JAW_RING, _MOUTH_RING = 16, 32, 64, 128


def _shade_frame(raster, V: np.ndarray, topo: MeshTopology, textures: FrameTextures,
                 own: tuple[np.ndarray, np.ndarray] | None = None, scale: float = 1.0):
    """The new face textured at one frame (§6): every texture it takes sampled in one pass
    over the raster (:func:`facetransfer.render.shade_layers`), then the eye and jaw regions
    pasted into the face (:func:`facetransfer.eyes.paint_shaded_eyes`,
    :func:`facetransfer.jaw.paint_shaded_jaw`). ``own = (frame, where)``: the face texture replaced
    by the (cropped) target frame's own pixels ``where`` (:func:`facetransfer.rim.
    drawn_inside`), under the regions; ``scale``: the factor of the pastes' pixel settings
    (:func:`facetransfer.face_scale.face_scale`).

    Returns
    -------
    face_img : (H, W, 3) uint8
        The face texture, eye and jaw regions painted (black outside ``face_mask``).
    face_mask : (H, W) bool
        The pixels the mesh covers.
    mouth_img : (H, W, 3) uint8 or None
        The source's mouth on the mouth's triangles; None without a mouth texture.
    mouth_mask : (H, W) bool
    ring : (H, W) bool or None
        The pixels of ``textures.mouth_ring``'s triangles, where ``mouth_img`` holds the
        source's frame too (to compare with the face); None without a mouth texture or a ring.
    """
    face_texture, mouth_texture, eye_texture, jaw_texture, mouth_ring = (
        textures.face, textures.mouth, textures.eyes, textures.jaw, textures.mouth_ring)
    # the triangles' flags in one kernel (what eyes.eye_flags and jaw.jaw_flags give, or-ed)
    masks = []
    layers = [(face_texture.uvs, np.asarray(face_texture.image, np.uint8)), None, None, None]
    if eye_texture is not None:
        masks += [(eye_texture.select, _EYES), (eye_texture.rim, _RIM)]
        layers[1] = (eye_texture.uvs, eye_texture.image)
    if jaw_texture is not None:
        masks += [(jaw_texture.select, _JAW | _JAW_REGION), (jaw_texture.ring, _JAW | _JAW_RING)]
        layers[2] = (jaw_texture.uvs, jaw_texture.image)
    with_mouth = mouth_texture is not None and topo.mouth_faces.size > 0
    if with_mouth:
        masks.append((mouth_ring, _MOUTH | _MOUTH_RING))
        layers[3] = (mouth_texture.uvs, np.asarray(mouth_texture.image, np.uint8))
    flags = layer_flags(topo.faces.shape[0], _FACE, masks,
                        topo.mouth_faces if with_mouth else None, _MOUTH)
    (face_img, eye_img, jaw_img, mouth_img), labels = shade_layers(raster, topo.faces, layers,
                                                                   flags)
    # every covered pixel has the face's bit; the mouth's pixels outside its ring (one kernel)
    face_mask, mouth_mask, ring = frame_masks(
        labels, _MOUTH if with_mouth else 0,
        _MOUTH_RING if with_mouth and mouth_ring is not None else 0)
    if own is not None:
        _keep_own(face_img, face_mask, *own, scale=scale)
    if eye_texture is not None:  # lids, eyes and brows from the open-eyed frame (issue 13)
        face_img = paint_shaded_eyes(raster, topo.faces, V, face_img, face_mask, eye_texture,
                                     eye_img, labels, (_EYES, _RIM), scale=scale)
    if jaw_texture is not None:  # chin and jaw from the closed-mouth frame (issue 13)
        face_img = paint_shaded_jaw(face_img, face_mask, jaw_texture, jaw_img, labels,
                                    (_JAW_REGION, _JAW_RING), raster, topo.faces, scale=scale)
    if not with_mouth or mouth_ring is None:
        ring = None
    return face_img, face_mask, mouth_img, mouth_mask, ring


def _keep_own(face_img: np.ndarray, face_mask: np.ndarray, frame: np.ndarray,
              where: np.ndarray, *, scale: float = 1.0) -> None:
    """``face_img`` (H, W, 3) uint8 made ``frame``'s own pixels ``where`` (H, W) bool, in place,
    with a soft edge (a Gaussian of 1.5 px, times ``scale``: :mod:`facetransfer.face_scale`) on
    ``face_mask``: the face texture's shading meets the frame's without a step
    (:func:`_keep_own_kernel`)."""
    x, y, w, h = cv2.boundingRect(where.view(np.uint8))
    if not w:
        return
    r = int(round(4 * scale))  # the box's margin, where the blur's edge lies
    x, y = max(x - r, 0), max(y - r, 0)
    box = (slice(y, y + h + 2 * r), slice(x, x + w + 2 * r))
    wb = np.ascontiguousarray(where[box])
    blur = cv2.GaussianBlur(wb.view(np.uint8).astype(np.float32), (0, 0), 1.5 * scale)
    _keep_own_kernel(blur, wb, face_mask, read_only(frame), face_img, x, y,
                     np.float32(0.5 / 255))


def _keep_own_kernel_py(blur, where, face_mask, frame, face_img, x0, y0,
                        least):  # pragma: no cover (numba)
    """:func:`_keep_own`'s mix on its box (``blur``'s shape at ``(x0, y0)`` of the whole
    arrays: one layout, one compiled kernel), in place: per pixel ``a = max(blur, where) *
    face_mask`` (float32) and, where ``a > least``, ``face_img = rint(f + a (t - f))`` with
    ``f``, ``t`` the face's and the frame's channel values in float32 (the numpy expressions'
    operations, in their order)."""
    for by in range(blur.shape[0]):
        for bx in range(blur.shape[1]):
            y, x = y0 + by, x0 + bx
            if not face_mask[y, x]:
                continue
            a = max(blur[by, bx], np.float32(1.0) if where[by, bx] else np.float32(0.0))
            if not a > least:
                continue
            for c in range(3):
                f = np.float32(face_img[y, x, c])
                t = np.float32(frame[y, x, c])
                face_img[y, x, c] = np.uint8(np.rint(f + a * (t - f)))


_keep_own_kernel = _maybe_njit(_keep_own_kernel_py)

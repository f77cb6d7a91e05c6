"""A jaw that transfers: the chin and jaw skin textured from a closed-mouth target frame.

The rewrite textures the face from each target frame (``texture="frame"``), looked up through
the target's own tracked mesh. Where the target opens its mouth and the new performance does
not, that lookup carries the target's own opening into the result: the chin's stretched skin
and the shadows under the lower lip and along the jaw move with the target, not with the new
jaw (issue 13: on the open-mouth pair ``WDA_KatieHill_000`` -> ``driving_d6`` MediaPipe's
jawOpen of the result followed the target's with a standardised weight of +0.41; with one
texture for the clip, +0.31 — ``benchmarks/bench_transfer_jaw.py``). The same held for the
brows, solved in :mod:`facetransfer.eyes` by texturing them from one frame. Here likewise
(Vlasic et al. 2005, §6: the face texture "from the target video (constant throughout the
sequence)", applied to the jaw only):

1. the jaw region is every triangle that the ARKit jaw shapes move (:data:`JAW_SHAPES`,
   :func:`facetransfer.eyes.region_vertices`), without the mouth's triangles (those show the
   source's mouth);
2. it is textured from one target frame whose mouth is closed and which faces the camera
   (:func:`closed_jaw_frame`), looked up through the target's tracked geometry in that frame
   (:func:`jaw_texture`; five frames spanning the target's openings, cross-faded by the new
   jaw's opening, measured the same on the jaw and worse on the smile: they show more of the
   target's own mouth);
3. in every frame the region is pasted into the per-frame face scaled to its colours
   (:func:`paint_jaw`, :func:`facetransfer.patch.match_outline`: the frames' exposure may
   differ), compared over a ring of triangles around the region (:data:`RING`), which the
   jaw does not move: inside the region the target's own opening would bias the ratio. One
   gain for the three channels (the geometric mean of the ring's, as the mouth's inside in
   :mod:`facetransfer.mouth`): per channel, a smile's blush, the lips or hair in the ring
   would tint the region (a green chin in ``make demo``'s smiling frames). The hue is then the
   current frame's, smooth (:data:`JAW_HUE_SIGMA`), compared over the region and its ring
   where both show like skin: the same skin under another head pose and light has another
   hue (an orange cheek in the demo's turned open-mouth frame);
4. only where the target's own expression moves the region away from the reference
   frame's (:func:`jaw_strengths`, per vertex): where the target's skin is where the
   reference frame's is, its own frame shows it already, lit as it is now. The closed frame's
   texture seen from another head pose is stretched and lit from elsewhere (seams and dark,
   green or orange patches on the cheeks of ``make demo``'s turned and smiling frames:
   BENCHMARKS.md, "Fourteenth session", "Fifteenth session"); the skin that moved fades it
   in, the rest of the region keeps its own frame's; so does the skin that the reference frame
   sees edge-on (:func:`facetransfer.region_weights.facing_weights`: the jaw line, under the chin);
5. and, near the mouth, where the current frame's colour departs from the reference frame's
   in a way lighting does not explain (:data:`JAW_LOOK`, :mod:`facetransfer.jaw_look`): a
   tongue, the teeth, the mouth's gap, which the model does not explain and the tracked
   geometry does not move for. Those pixels neither set the region's hue (:func:`paint_jaw`:
   the hue match spread a tongue's red over the new chin) nor fade back to the current frame
   where it is most unlike the reference frame (the paste's rejection gave the darkest red
   back: a stripe under the new lip's corner).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from .arkit import ARKIT_NAMES, expression_rig, is_arkit_model
from .io.frame_numbers import track_first_number
from .label_masks import bits_box
from .eyes import close_region, faces_around, reference_frame, region_faces, region_vertices
from .region_weights import (JAW_POINTS, facing_weights, model_vertices, moved_strengths,
                             vertex_alpha)
from .jaw_look import LOOK_RAMP, look_strengths, mouth_reach
from .patch import REJECT, match_outline_into, ring_inset
from .render import interpolate_vertex_values, shade_layers
from .render.shading import interpolate_vertex_pair
from .texture.face import frame_uvs
from .topology import close_mouth

log = logging.getLogger(__name__)

__all__ = ["JAW_SHAPES", "JAW_THRESHOLD", "JawTexture", "jaw_region", "mouth_closure",
           "closed_jaw_frame", "jaw_texture", "jaw_strengths", "paint_jaw", "paint_shaded_jaw"]

#: ARKit blendshapes whose vertices take the closed-mouth frame's texture.
JAW_SHAPES = ("jawOpen", "jawForward", "jawLeft", "jawRight")
#: A vertex belongs to the jaw region when a jaw shape moves it by more than this fraction of
#: that shape's largest displacement.
JAW_THRESHOLD = 0.15
#: Rings of triangles around the jaw region over which its exposure is matched.
RING = 3
#: :func:`jaw_strengths`' ramp: the closed frame's texture starts to show at a vertex of the
#: jaw region that the target's expression has moved from where it is in the reference frame
#: by the first fraction of the jawOpen shape's displacement (its RMS over the region, the
#: model's mean person: 1.7 cm for the default model), and shows fully from the second
#: (0.05-0.15: 0.85-2.6 mm).
JAW_BLEND = (0.05, 0.15)
#: The scale (pixels) at which the region takes the current frame's hue
#: (:func:`facetransfer.patch._hue_field`, compared over the region and its ring): the
#: closed frame's skin seen under another head pose has another hue (an orange patch on the
#: cheek of ``make demo``'s turned open-mouth frame, where the frame shows it pale); its
#: brightness stays the gain's, so the target's own shadows do not come back.
JAW_HUE_SIGMA = 10.0
#: :func:`facetransfer.jaw_look.look_strengths`' ramp (the hue step of the current frame's
#: colour from the reference frame's, near the mouth): the region also takes the reference
#: frame where the target's mouth shows what the model does not explain; None: the
#: geometric rule only.
JAW_LOOK: tuple[float, float] | None = LOOK_RAMP
#: A pixel whose appearance strength (interpolated) exceeds this neither sets the region's hue
#: nor is rejected by the paste (:func:`paint_jaw`, :func:`_look_far`).
LOOK_HUE = 0.5
#: Pixels by which those pixels grow (two blocks of the hue field's grid,
#: :data:`facetransfer.patch.SHADING_STEP`: a block's mean counts all its pixels).
LOOK_GROW = 6
_GROW = np.ones((2 * LOOK_GROW + 1,) * 2, np.uint8)
# Where the closed frame's texture (matched) and the current frame's differ by more than
# facetransfer.patch.REJECT, a pixel fades back to the current frame (paint_jaw): what the closed
# frame shows at the jaw line of a turned head is often hair or the gap under it (a black
# wedge under the ear of the demo's turned frames without it).


@dataclass(frozen=True)
class JawTexture:
    """The texture of the jaw region for a whole clip.

    Attributes
    ----------
    image : (Ht, Wt, 3) uint8
        The closed-mouth target frame.
    uvs : (n_closed, 2) float64
        Texture coordinates (v up, :func:`facetransfer.texture.face.frame_uvs`) of the closed
        mesh's vertices in that frame.
    select : (F',) bool
        The triangles of the topology textured from ``image``.
    frame : int
        The target frame ``image`` is.
    ring : (F',) bool or None
        The triangles around the region (not in it, not the mouth's) whose colours in
        ``image`` and in the current frame set the region's gain; None: the region's own.
    verts : (m,) int64 or None
        The vertices of the region's triangles that :attr:`strengths` gives.
    strengths : (F, m) float32 in [0, 1] or None
        Per target frame and vertex of :attr:`verts`, how much the region takes of ``image``
        there (:func:`jaw_strengths`); None: fully everywhere in every frame.
    alpha : (n,) float32 or None
        This frame's (:meth:`at`), per vertex of the topology: the opacity of the region's
        paste, interpolated over its pixels; None: fully opaque.
    look : (F, m) float32 or None
        Per target frame and vertex of :attr:`verts`, the appearance rule's strength
        (:mod:`facetransfer.jaw_look`); None: no rule.
    look_alpha : (n,) float32 or None
        This frame's :attr:`look` per vertex of the topology (0 off the region's vertices);
        None where no vertex has any.
    """

    image: np.ndarray
    uvs: np.ndarray
    select: np.ndarray
    frame: int
    ring: np.ndarray | None = None
    verts: np.ndarray | None = None
    strengths: np.ndarray | None = None
    alpha: np.ndarray | None = None
    look: np.ndarray | None = None
    look_alpha: np.ndarray | None = None

    def at(self, i: int) -> "JawTexture | None":
        """The texture for target frame ``i`` with its per-vertex :attr:`alpha`; None where
        no vertex takes any (the frame is left as its own texture shows it)."""
        if self.strengths is None:
            return self
        s = self.strengths[i]
        if not s.size or float(s.max()) <= 0.0:
            return None
        look = None
        if self.look is not None and float(self.look[i].max(initial=0.0)) > LOOK_HUE:
            look = vertex_alpha(len(self.uvs), self.verts, self.look[i], rest=0.0)
        return replace(self, alpha=vertex_alpha(len(self.uvs), self.verts, s), look_alpha=look)


def jaw_region(model, topo, *, threshold: float = JAW_THRESHOLD, rig=None) -> np.ndarray | None:
    """The jaw region's triangles, ``(len(topo.faces),) bool``, or None for a model without
    ARKit names.

    The triangles whose vertices the :data:`JAW_SHAPES` move (of the model's mean person; small
    holes closed), without ``topo.mouth_faces``. It reaches along the jaw line and under the
    chin, where the surface is seen nearly edge-on: the target's own chin outline and the
    shadow below it are what moved with the target's opening (with only the triangles that
    face the camera, the target's opening shows again on the open-mouth pair:
    ``BENCHMARKS.md``).
    """
    if not is_arkit_model(model):
        return None
    if rig is None:
        rig = expression_rig(model, model.default_weights())
    verts = region_vertices(model, JAW_SHAPES, threshold=threshold, rig=rig)
    vmask = np.zeros(topo.n_closed, bool)
    vmask[:verts.size] = verts
    vmask = close_region(topo.faces, vmask)
    sel = region_faces(topo.faces, vmask, rings=0)
    sel[np.asarray(topo.mouth_faces, np.int64)] = False
    return sel


def mouth_closure(track) -> np.ndarray:
    """How open each frame's mouth is, ``(F,)``: the jawOpen activation when the track has
    ARKit activations, else the model landmarks' inner-lip gap (iBUG 62-66) over the outer
    eye-corner distance (iBUG 36-45)."""
    if track.blendshapes is not None and track.blendshape_names is not None:
        names = list(track.blendshape_names)
        if "jawOpen" in names:
            return np.asarray(track.blendshapes, np.float64)[:, names.index("jawOpen")]
    L = np.asarray(track.landmarks2d, np.float64)
    eye = np.maximum(np.linalg.norm(L[:, 36] - L[:, 45], axis=1), 1e-9)
    return np.linalg.norm(L[:, 62] - L[:, 66], axis=1) / eye


def closed_jaw_frame(track, n_frames: int | None = None, *, quantile: float = 0.25) -> int:
    """The target frame to texture the jaw from: mouth closed, facing the camera.

    Among the frames (of the first ``n_frames``) where the face is not lost and the mouth is at
    most as open as the ``quantile`` of :func:`mouth_closure`, the one facing the camera most
    squarely (plus half its tracking confidence).

    Raises
    ------
    RewriteError
        The face is lost in every frame.
    """
    return reference_frame(track, mouth_closure(track), n_frames, quantile, low=True,
                           points=JAW_POINTS)


def jaw_texture(frames, track, model, topo, *, frame: int | None = None,
                n_frames: int | None = None, rig=None) -> JawTexture | None:
    """Lift the jaw region's texture from a closed-mouth target frame.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8
        The target video.
    track : Track
        The target's own track.
    model : MultilinearModel
    topo : MeshTopology
        The topology the new face is rasterised with (eye holes closed or not).
    frame : int, optional
        The reference frame; default :func:`closed_jaw_frame`.
    n_frames : int, optional
        Choose the reference frame among the first ``n_frames`` only (default: all).
    rig : ExpressionRig, optional
        :func:`facetransfer.arkit.expression_rig` of the model's mean person, if at hand.

    Returns
    -------
    JawTexture or None
        None for a model without ARKit names or without a jaw region.
    """
    if not is_arkit_model(model):
        return None
    select = jaw_region(model, topo, rig=rig)
    if select is None or not select.any():
        return None
    m = len(frames) if n_frames is None else min(int(n_frames), len(frames))
    i = closed_jaw_frame(track, m) if frame is None else int(frame)
    img = np.asarray(frames[i])
    Vi = close_mouth(model.synthesize(track.weights_at(i)), topo)
    uvs = frame_uvs(Vi, track.camera(i), (img.shape[1], img.shape[0]))
    ring = faces_around(topo.faces, select, rings=RING)
    ring[np.asarray(topo.mouth_faces, np.int64)] = False
    verts, strengths = jaw_strengths(model, track, topo, select, i, rig=rig)
    look = None
    if JAW_LOOK is not None:
        look = look_strengths(frames, track, model, verts, i, mouth_reach(model, topo, verts),
                              m, ramp=JAW_LOOK)
        np.maximum(strengths, look, out=strengths)
    strengths *= facing_weights(Vi, topo.faces, track.rotation[i], verts)
    shown = strengths.max(axis=1) > 0 if verts.size else np.zeros(len(strengths), bool)
    log.info("jaw: textured from target frame %d, %d triangles, in %d of %d frames",
             track_first_number(track) + i, int(select.sum()), int(np.count_nonzero(shown)),
             len(strengths))     # a plate's frame by its number
    return JawTexture(img, uvs, select, i, ring, verts, strengths, look=look)


def jaw_strengths(model, track, topo, select: np.ndarray, reference: int, *, rig=None,
                  ramp: tuple[float, float] = JAW_BLEND) -> tuple[np.ndarray, np.ndarray]:
    """How much of the reference frame's texture each vertex of the jaw region takes in each
    frame: ``(verts (m,) int64, strengths (F, m) float32 in [0, 1])``.

    ``d``, the distance of a vertex of the target's face in frame ``i`` (Eq. 5: its identity
    and that frame's expression, no pose) from the same vertex in the ``reference`` frame,
    divided by the RMS over the region of the jawOpen shape's displacement (the model's mean
    person), goes through a smoothstep from ``ramp[0]`` to ``ramp[1]``. The skin the target's
    own expression moved (the chin of an opened jaw, the cheeks of a smile) takes the
    reference frame; the skin that stayed (the cheek by the ear of an opened jaw) keeps its
    own frame's texture, lit as the frame is.

    Parameters
    ----------
    model : MultilinearModel
        ARKit-named (:func:`facetransfer.arkit.is_arkit_model`).
    track : Track
        The target's.
    topo : MeshTopology
    select : (F',) bool
        The region's triangles (:func:`jaw_region`).
    reference : int
        The frame the region is textured from.
    rig : ExpressionRig, optional
        :func:`facetransfer.arkit.expression_rig` of the model's mean person, if at hand.
    ramp : (float, float)
        :data:`JAW_BLEND`.
    """
    verts = model_vertices(model, topo, select)
    if rig is None:
        rig = expression_rig(model, model.default_weights(), vertices=verts)
        full = rig.deltas[ARKIT_NAMES.index("jawOpen")]
    else:
        full = rig.deltas[ARKIT_NAMES.index("jawOpen")][verts]
    scale = float(np.sqrt((full ** 2).sum(-1).mean()))
    return verts, moved_strengths(model, track, verts, reference, scale, ramp)


def paint_jaw(raster, faces: np.ndarray, face_image: np.ndarray, face_mask: np.ndarray,
              texture: JawTexture, *, feather: float = 4.0) -> np.ndarray:
    """The rendered face with its jaw region textured from the closed-mouth frame.

    Parameters
    ----------
    raster : Raster
        Of the new mesh with the topology ``faces``.
    faces : (F', 3) int
    face_image : (H, W, 3) uint8
        The face shaded from the face texture.
    face_mask : (H, W) bool
    texture : JawTexture
    feather : float
        Soft-edge width in pixels of the region's outline.

    Returns
    -------
    (H, W, 3) uint8
        ``face_image`` with the jaw region replaced (shifted to its colours).
    """
    # labels in the high bits (4-7): the low ones (2 and 4) would select layers this call does
    # not give, which shade_layers refuses
    flags = jaw_flags(texture, shaded=1, region=16, ring=32)
    (img,), labels = shade_layers(raster, faces, [(texture.uvs, texture.image)], flags)
    return paint_shaded_jaw(np.array(face_image, copy=True), face_mask, texture, img, labels,
                            (16, 32), raster, faces, feather=feather)


def jaw_flags(texture: JawTexture, *, shaded: int, region: int, ring: int) -> np.ndarray:
    """Per triangle, ``(F',) uint8``: the bit ``shaded`` on the triangles textured from the
    closed-mouth frame (the region and its ring), ``region`` on the region's
    (``texture.select``), ``ring`` on the ring's (``texture.ring``), for
    :func:`facetransfer.render.shade_layers`."""
    sel = np.asarray(texture.select, bool).view(np.uint8)
    flags = sel * np.uint8(shaded | region)
    if texture.ring is not None:
        flags |= np.asarray(texture.ring, bool).view(np.uint8) * np.uint8(shaded | ring)
    return flags


def paint_shaded_jaw(face_image: np.ndarray, face_mask: np.ndarray, texture: JawTexture,
                     img: np.ndarray, labels: np.ndarray, bits: tuple[int, int], raster, faces,
                     *, feather: float = 4.0, scale: float = 1.0) -> np.ndarray:
    """:func:`paint_jaw` with the region shaded already (``img`` (H, W, 3) the closed-mouth
    frame on the region and its ring, ``labels`` (H, W) uint8 of
    :func:`facetransfer.render.shade_layers` with the bits ``(region, ring)`` of
    :func:`jaw_flags`; ``raster`` and ``faces`` interpolate :attr:`JawTexture.alpha`),
    painting ``face_image`` in place and returning it. ``feather``, :data:`JAW_HUE_SIGMA` and
    :data:`LOOK_GROW` times ``scale`` (:func:`facetransfer.face_scale.face_scale`: a 4-px
    feather on a face 2.5 times the data folder's showed the region's top edge as a step
    across the cheek at the mouth's height: BENCHMARKS.md, "Fifty-fourth session (helper
    large54)")."""
    # the work on the box of the region and its ring, grown by the pixels the ring's erosion
    # reaches (patch._ring); the gain fit keeps the frame's coordinates (origin)
    sl = bits_box(labels, bits[0] | bits[1], ring_inset(scale))  # mask_box of the bits
    if sl is None:
        return face_image
    lab, fm = labels[sl], face_mask[sl]
    mask = np.bitwise_and(lab, bits[0]) != 0
    mask &= fm
    if np.count_nonzero(mask) == 0:
        return face_image
    compare = None
    if texture.ring is not None:
        compare = np.bitwise_and(lab, bits[1]) != 0
        compare &= fm
        if np.count_nonzero(compare) < 8:
            compare = None
    opacity, far = 1.0, None
    if texture.alpha is not None and texture.look_alpha is not None:  # one pass for both
        opacity, look = interpolate_vertex_pair(raster, faces, texture.alpha,
                                                texture.look_alpha, box=sl)
        far = _look_far(look, scale)
    elif texture.alpha is not None:
        opacity = interpolate_vertex_values(raster, faces, texture.alpha, box=sl)
    elif texture.look_alpha is not None:
        far = _look_far(interpolate_vertex_values(raster, faces, texture.look_alpha, box=sl),
                        scale)
    match_outline_into(face_image[sl], img[sl], mask, fm, face_image[sl],
                       feather=feather * scale, compare=compare, reject=REJECT,
                       reject_where=far, origin=(sl[1].start, sl[0].start), opacity=opacity,
                       grey_where=True, hue=JAW_HUE_SIGMA * scale,
                       hue_where=far if JAW_HUE_SIGMA > 0 else None, scale=scale)
    return face_image


def _look_far(look: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """``(h, w) bool``: the pixels away from where the appearance rule took the reference
    frame, those whose appearance strength ``look`` (h, w) float32 is at most
    :data:`LOOK_HUE`, away from the others by more than :data:`LOOK_GROW` pixels times
    ``scale`` (two of the hue field's blocks at a face up to
    :data:`facetransfer.face_scale.FACE_SPAN`: a block partly of the tongue still carries its
    red; the hue field's scale grows with the face). Only these

    - set the paste's hue match: a tongue's or the lips' red where the reference frame shows
      skin does not tint the pasted skin (the match itself comes after the paste's gain, at
      the frame's exposure);
    - may be rejected by the paste (:data:`facetransfer.patch.REJECT`, back to the current
      frame where the two frames' colours differ by a factor over 1.65): the rule took the
      reference frame there *because* the current frame shows another thing than skin; the
      rejection, meant for hair or the gap under a turned jaw in the reference frame, gave
      the current frame's darkest red back (a dark-red stripe under the new lip's corner on
      the judge's ``open`` pair, frame 79: the target's lower lip pressed out by its tongue,
      ``benchmarks/bench_jaw_appearance.py``)."""
    import cv2

    r = int(round(LOOK_GROW * scale))
    grow = _GROW if r == LOOK_GROW else np.ones((2 * r + 1,) * 2, np.uint8)
    return cv2.dilate((look > LOOK_HUE).view(np.uint8), grow) == 0

"""A jaw that transfers: the chin and jaw skin textured from target frames whose mouth opening
matches the new performance's.

The rewrite textures the face from each target frame (``texture="frame"``), looked up through
the target's own tracked mesh. Where the target opens its mouth and the new performance does
not, that lookup carries the target's own opening into the result: the chin's stretched skin
and the shadows under the lower lip and along the jaw move with the target, not with the new
jaw (issue 13: on the open-mouth pair ``WDA_KatieHill_000`` -> ``driving_d6`` MediaPipe's
jawOpen of the result followed the target's with a standardised weight of +0.41 next to the
source's: ``benchmarks/bench_transfer_jaw.py``). The brows had the same trouble, solved in
:mod:`facetransfer.eyes` by texturing them from one frame. A single closed-mouth frame would
lose the shading of a real opening when the new jaw opens; so here (Vlasic et al. 2005, §6:
the performance-driven texture, a function of the attributes lifted from the video's frames,
with the jaw opening as the one attribute):

1. the jaw region is every triangle that the ARKit jaw shapes move (:data:`JAW_SHAPES`,
   :func:`facetransfer.eyes.region_vertices`), without the mouth's triangles (those show the
   source's mouth);
2. a few target frames spanning the target's mouth openings (:data:`BANK`; in each share of
   the openings the frame facing the camera most squarely: :func:`jaw_frames`) are its
   texture, looked up through the target's tracked geometry in each (:func:`jaw_texture`);
3. in every frame the region shows the reference frames whose opening brackets the new
   performance's (:func:`jaw_opening`), cross-faded by it (:meth:`JawTexture.mix`), pasted into
   the per-frame face scaled to its colours (:func:`paint_jaw`,
   :func:`facetransfer.eyes.match_outline`: the frames' exposure may differ), compared over a
   ring of triangles around the region (:data:`RING`), which the jaw does not move.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .arkit import ARKIT_NAMES, expression_rig, is_arkit_model, weights_to_activations
from .errors import RewriteError
from .eyes import close_region, match_outline, region_faces, region_vertices
from .render import shade_texture
from .texture.face import frame_uvs
from .topology import close_mouth

log = logging.getLogger(__name__)

__all__ = ["JAW_SHAPES", "JAW_THRESHOLD", "BANK", "JawTexture", "jaw_region", "jaw_opening",
           "jaw_frames", "jaw_texture", "paint_jaw"]

#: ARKit blendshapes whose vertices take the closed-mouth frame's texture.
JAW_SHAPES = ("jawOpen", "jawForward", "jawLeft", "jawRight")
#: A vertex belongs to the jaw region when a jaw shape moves it by more than this fraction of
#: that shape's largest displacement.
JAW_THRESHOLD = 0.15
#: Rings of triangles around the jaw region over which its exposure is matched.
RING = 3
#: Reference frames of the jaw region (spanning the target's mouth openings).
BANK = 5
#: Reference frames whose jaw openings differ by less than this count as one.
SAME_OPENING = 0.02


@dataclass(frozen=True)
class JawTexture:
    """The texture of the jaw region for a whole clip: a few target frames by mouth opening.

    Attributes
    ----------
    images : tuple of (Ht, Wt, 3) uint8
        The reference target frames, by increasing opening.
    uvs : (K, n_closed, 2) float64
        Texture coordinates (v up, :func:`facetransfer.texture.face.frame_uvs`) of the closed
        mesh's vertices in each.
    openings : (K,) float64
        Their jaw openings (:func:`jaw_opening`), increasing.
    frames : (K,) int64
        The target frames the images are.
    select : (F',) bool
        The triangles of the topology textured from the images.
    ring : (F',) bool or None
        The triangles around the region (not in it, not the mouth's) whose colours in the
        images and in the current frame set the region's gain; None: the region's own.
    """

    images: tuple
    uvs: np.ndarray
    openings: np.ndarray
    frames: np.ndarray
    select: np.ndarray
    ring: np.ndarray | None = None

    def mix(self, opening: float) -> list[tuple[int, float]]:
        """``[(k, weight), ...]``: the reference frames whose openings bracket ``opening``,
        weighted by a smoothstep of where it lies between them (the nearest alone outside
        the bank's range)."""
        o = self.openings
        if o.size == 1 or opening <= o[0]:
            return [(0, 1.0)]
        if opening >= o[-1]:
            return [(o.size - 1, 1.0)]
        k = int(np.searchsorted(o, opening)) - 1
        t = (opening - o[k]) / max(o[k + 1] - o[k], 1e-9)
        t = t * t * (3.0 - 2.0 * t)
        return [(k, 1.0 - t), (k + 1, t)]


def jaw_region(model, topo, *, threshold: float = JAW_THRESHOLD, rig=None) -> np.ndarray | None:
    """The jaw region's triangles, ``(len(topo.faces),) bool``, or None for a model without
    ARKit names.

    The triangles whose vertices the :data:`JAW_SHAPES` move (of the model's mean person; small
    holes closed), without ``topo.mouth_faces``. It reaches along the jaw line and under the
    chin, where the surface is seen nearly edge-on: the target's own chin outline and the
    shadow below it are what moved with the target's opening (on the open-mouth pair, keeping
    only the triangles that face the reference frame's camera, ``|normal . view| >= 0.4`` or
    ``0.6``, brought MediaPipe's jawOpen of the result back from +0.76 to +0.61 or +0.55 with
    the source; per-frame texture: +0.53).
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


def jaw_opening(model, track) -> np.ndarray:
    """The jawOpen activation of each frame of a track of an ARKit model, ``(F,)`` in [0, 1]
    (from its expression weights, :func:`facetransfer.arkit.weights_to_activations`)."""
    a = weights_to_activations(model, np.asarray(track.weights["expression"], np.float64))
    return a[:, ARKIT_NAMES.index("jawOpen")]


def jaw_frames(track, opening: np.ndarray, n_frames: int | None = None, k: int | None = None
               ) -> np.ndarray:
    """The reference frames of the jaw region, ``(K,) int64`` by increasing opening.

    The frames (of the first ``n_frames``) where the face is not lost, sorted by ``opening``
    and split into ``k`` (default :data:`BANK`) equal shares; of each share the frame facing
    the camera most squarely (plus half its tracking confidence). Frames whose openings lie
    within :data:`SAME_OPENING` of a kept one are dropped.

    Raises
    ------
    RewriteError
        The face is lost in every frame.
    """
    good = np.flatnonzero(~np.asarray(track.lost)[:n_frames])
    if good.size == 0:
        raise RewriteError(f"the face is lost in every frame of "
                           f"{track.source or 'the target'}")
    o = np.asarray(opening, np.float64)
    score = track.rotation[:, 2, 2] + 0.5 * np.asarray(track.confidence)
    picked = []
    for share in np.array_split(good[np.argsort(o[good], kind="stable")], k or BANK):
        if share.size:
            picked.append(int(share[np.argmax(score[share])]))
    picked = sorted(set(picked), key=lambda j: (o[j], j))
    out = [picked[0]]
    for j in picked[1:]:
        if o[j] - o[out[-1]] > SAME_OPENING:
            out.append(j)
    return np.asarray(out, np.int64)


def jaw_texture(frames, track, model, topo, *, n_frames: int | None = None, rig=None,
                k: int | None = None) -> JawTexture | None:
    """Lift the jaw region's texture from target frames spanning its mouth openings.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8
        The target video.
    track : Track
        The target's own track.
    model : MultilinearModel
    topo : MeshTopology
        The topology the new face is rasterised with (eye holes closed or not).
    n_frames : int, optional
        Choose the reference frames among the first ``n_frames`` only (default: all).
    rig : ExpressionRig, optional
        :func:`facetransfer.arkit.expression_rig` of the model's mean person, if at hand.
    k : int, optional
        At most this many reference frames (default :data:`BANK`).

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
    opening = jaw_opening(model, track)
    idx = jaw_frames(track, opening, m, k)
    images, uvs = [], []
    for i in idx:
        img = np.asarray(frames[int(i)])
        Vi = close_mouth(model.synthesize(track.weights_at(int(i))), topo)
        images.append(img)
        uvs.append(frame_uvs(Vi, track.camera(int(i)), (img.shape[1], img.shape[0])))
    ring = region_faces(topo.faces, np.isin(np.arange(topo.n_closed), topo.faces[select]),
                        rings=RING) & ~select
    ring[np.asarray(topo.mouth_faces, np.int64)] = False
    log.info("jaw: textured from target frames %s (jawOpen %s), %d triangles", idx.tolist(),
             np.round(opening[idx], 2).tolist(), int(select.sum()))
    return JawTexture(tuple(images), np.asarray(uvs), opening[idx], idx, select, ring)


def paint_jaw(raster, faces: np.ndarray, face_image: np.ndarray, face_mask: np.ndarray,
              texture: JawTexture, opening: float, *, feather: float = 4.0) -> np.ndarray:
    """The rendered face with its jaw region textured from the reference frames.

    Parameters
    ----------
    raster : Raster
        Of the new mesh with the topology ``faces``.
    faces : (F', 3) int
    face_image : (H, W, 3) uint8
        The face shaded from the face texture.
    face_mask : (H, W) bool
    texture : JawTexture
    opening : float
        The new face's jaw opening (:func:`jaw_opening`): which reference frames show
        (:meth:`JawTexture.mix`).
    feather : float
        Soft-edge width in pixels of the region's outline.

    Returns
    -------
    (H, W, 3) uint8
        ``face_image`` with the jaw region replaced (scaled to its colours).
    """
    sel = texture.select if texture.ring is None else texture.select | texture.ring
    acc, shown = None, None
    for k, w in texture.mix(float(opening)):
        img, shown = shade_texture(raster, faces, texture.uvs[k], texture.images[k], sel)
        acc = w * img.astype(np.float32) if acc is None else acc + w * img
    shown &= face_mask
    tri = np.maximum(raster.tri_id, 0)
    mask = shown & texture.select[tri]
    if not mask.any():
        return face_image
    compare = None if texture.ring is None else shown & texture.ring[tri]
    if compare is not None and compare.sum() < 8:
        compare = None
    part = np.clip(np.rint(acc), 0, 255).astype(np.uint8)
    return match_outline(face_image, part, mask, face_mask, feather=feather, compare=compare)

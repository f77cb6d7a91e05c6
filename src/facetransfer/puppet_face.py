"""The puppet's eyes and mouth: eyeballs that look where the track looks, a dark mouth cavity.

:func:`facetransfer.puppet_video.puppet_frames` renders the model's face as a solid head: its eye
holes closed by fans around their centres, its mouth gap by the topology's fan
(:func:`facetransfer.topology.close_mouth`). Shaded in the skin's colour those fills read as skin:
a blink closed skin over skin, the gaze did not show and an open mouth was a skin-coloured disc.
Here the pixels where a fill wins the z-buffer are painted after the render (so the lids and
lips occlude them as they occlude any surface):

- an eye fill's pixel shows the eyeball behind the eye's corners
  (:func:`facetransfer.track.gaze.eye_model`) at that pixel: the pixel is taken back through
  the weak-perspective camera (Eq. (7)) onto the ball's front, and the angle between that
  point's direction from the ball's centre and the gaze (:func:`facetransfer.track.gaze.
  activation_gaze` of the frame's eyeLook* activations, the inverse of what the tracker reads
  from Face Landmarker's iris points) makes it pupil (:data:`PUPIL`), iris (:data:`IRIS`, its
  rim :data:`LIMBUS`) or sclera (:data:`SCLERA`). The iris is a disc on the ball, so it
  foreshortens as the eye or the head turns; a half-closed eye shows the part of it its lids
  leave. A track without ARKit activations (a model whose expressions are not ARKit-named,
  e.g. ``ict-bilinear``) looks straight ahead (the head's +z);
- a mouth fill's pixel is the cavity (:data:`CAVITY`, darker toward the fan's centre, the back
  of the mouth: :data:`CAVITY_BACK`), with the upper teeth (:data:`TEETH`) in a band of
  :data:`TEETH_SHOW` eye widths under the middle of the upper lip;
- an eye or the mouth whose fill shows only a sliver (on average lower than :data:`SHUT` of its
  width, and half a row of pixels more for a sliver under a pixel high: the model's lids in a
  blink and its lips at rest do not quite meet) is shut, its
  pixels the skin darkened by :data:`SHUT_LINE` (the lids' or the lips' line): a blink hides
  the eyeball, a mouth at rest shows no cavity. As on the ``view`` page, the lids closing
  darken the eyeball by their gap (:func:`lid_light`, :data:`LID_SHADE`); at and under the
  face's shut gap (:func:`shut_gaps_at_blink`: ``LID_SHADE[0]``, or a little over the face's own
  gap at ``eyeBlink`` 1 where its lids stop wider apart) the eye is shut, as the ``view`` page
  and the exported glb and USD hide it.

The colours are :data:`PALETTE`'s, the ``view`` page's too (one palette for both previews).

:func:`preview_face` is the same head in :func:`facetransfer.render.render_model`'s framing,
``facetransfer render``'s picture; :func:`draw_face` under a camera of the caller's (``model
sheet``'s and ``model dials``' tiles). The eyes and the mouth cost ~0.7 ms of CPU a frame (a
480x480 frame of ~8 ms on one thread; ``benchmarks/bench_puppet_face.py``).

Beyond the paper (its §8 names puppetry; the paper renders no eyes).

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, Eq. (7).
The visible iris diameter (~11.8 mm) and a daylight pupil (~4 mm): textbook averages
(e.g. Atchison & Smith, Optics of the Human Eye, 2000).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .palette import CAVITY_BACK, PALETTE, TEETH_SHOW, TEETH_SPAN
from .track.gaze import CORNER_INDEX, EYE_RADIUS, activation_gaze, eye_model, gaze_direction

__all__ = ["PALETTE", "SKIN", "SCLERA", "IRIS", "LIMBUS", "PUPIL", "CAVITY", "TEETH",
           "CAVITY_BACK", "IRIS_RIM", "IRIS_RADIUS", "PUPIL_RADIUS",
           "TEETH_SHOW", "SHUT", "SHUT_LINE", "LID_PAIRS", "LID_SHADE", "SHUT_MARGIN",
           "PuppetFace", "puppet_face", "arkit_activations", "track_gaze", "lid_gaps",
           "blink_shapes", "shut_gaps_at_blink", "face_shut_gaps", "lid_light", "paint_face",
           "preview_face", "draw_face"]

# PALETTE (the two previews' colours, the view page's too, and the mouth's inside a rewrite
# draws where its target never shows one), CAVITY_BACK and TEETH_SHOW: facetransfer.palette's.

#: The skin (RGB): :data:`PALETTE`'s.
SKIN = PALETTE["skin"]
#: The white of the eye (RGB): an off-white.
SCLERA = PALETTE["sclera"]
#: The iris (RGB): a brown.
IRIS = PALETTE["iris"]
#: The iris's dark rim (RGB).
LIMBUS = PALETTE["limbus"]
#: The pupil (RGB).
PUPIL = PALETTE["pupil"]
#: The inside of an open mouth: a dark red-brown (RGB), at the lips; darker toward the back.
CAVITY = PALETTE["cavity"]
#: The upper teeth (RGB).
TEETH = PALETTE["teeth"]
#: The iris is :data:`IRIS` from the pupil's edge to this fraction of the way to its edge, then
#: blends into :data:`LIMBUS` at the edge.
IRIS_RIM = 0.75
#: The visible iris's radius, cm at FaceKit's eye width (:data:`facetransfer.track.gaze.
#: FACEKIT_EYE_WIDTH`): half of an 11.8 mm visible iris.
IRIS_RADIUS = 0.59
#: The pupil's radius, cm at FaceKit's eye width: half of a 4 mm daylight pupil.
PUPIL_RADIUS = 0.2
#: An eye or the mouth whose fill shows on average less high than this fraction of its width
#: (right eye, left, mouth; the corners' distance) is shut: the model's lids in a blink and its
#: lips at rest leave a sliver of their holes (the mean person in ``ict-arkit``: eyeBlink* = 1
#: shows 3 % of the eye's width, 0.8 shows 8 %, open eyes 26 %; the mouth at rest 0.8 % of its
#: width, jawOpen = 0.1 shows 4.7 %).
SHUT = (0.05, 0.05, 0.025)
#: How much of a row of pixels along its width a shut fill's sliver may light beyond
#: :data:`SHUT` (:func:`_shut`: a sliver under a pixel high, aliased).
_SLIVER_ROW = 0.5
#: A shut eye's or mouth's sliver: the skin there darkened by this factor (the lids' or lips'
#: line).
SHUT_LINE = 0.5
#: iBUG-68 upper and lower lid points facing each other, per eye (the subject's right, left).
LID_PAIRS = (((37, 41), (38, 40)), ((43, 47), (44, 46)))
#: Lid gap (mean of :data:`LID_PAIRS`' distances over the corner distance, in the head's frame)
#: at and below which the eyeball is hidden, and from which it is fully lit; between, its colour
#: is scaled by a smoothstep (:func:`lid_light`): the puppet's and the ``view`` page's
#: (:mod:`facetransfer.export.viewer`) alike. FaceKit's lids part 0.34 eye widths at rest, 0.19
#: looking down, and stop 0.066 apart at ``eyeBlink`` 1 (a 1.8 mm slit in the mesh), where the
#: eyeball must not show.
LID_SHADE = (0.08, 0.18)
#: How far above a face's own lid gap at ``eyeBlink`` 1 its eyes still count as shut, in eye
#: widths (:func:`shut_gaps_at_blink`; never under ``LID_SHADE[0]``, 0.08): about 0.08 mm, an
#: eyeBlink a few hundredths under 1. The default model's lids stop 0.066-0.075 apart there, so
#: its rule stays 0.08. Not more: the test model's identity 1 (0.098 at eyeBlink 1) narrows its
#: lids to 0.100-0.103 at half blinks with other shapes, which the page still lights at 11-13 %
#: (BENCHMARKS.md, fifty-sixth session, review56a). Was ``export.gltf_eyes.SHUT_MARGIN``.
SHUT_MARGIN = 0.003
#: What the lids' fills are painted with, by :attr:`PuppetFace.kind`.
_RIGHT, _LEFT, _MOUTH = 0, 1, 2
#: The ball's Lambert term: ``_EYE_AMBIENT + (1 - _EYE_AMBIENT) n_z`` (its normal toward the
#: camera); the corners, beyond the ball's silhouette, at the ambient alone.
_EYE_AMBIENT = 0.55


@dataclass(frozen=True)
class PuppetFace:
    """The puppet's solid head and what its fills show, for one clip.

    Attributes
    ----------
    faces : (F', 3) int64
        The closed mesh's faces (model faces and the mouth fan) followed by each eye hole's
        fan around a centre vertex (``n_closed + k`` for the ``k``-th eye loop).
    kind : (F' + 1,) int8
        Indexed by a raster's ``tri_id + 1``: 0 the right eye's fan, 1 the left eye's, 2 the
        mouth fan; -1 the others and the background.
    eye_loops : tuple of (k,) int64
        The topology's eye holes (right, left).
    landmarks : (68,) int64 or None
        The model's iBUG-68 vertices (the eye corners place the eyeballs).
    gaze : (F, 2, 2) float64 or None
        The track's gaze, ``[frame, eye (right, left), (yaw, pitch)]`` (radians); None: straight
        ahead.
    mouth : tuple
        ``(first row of the mouth fan in faces, its triangles)``: triangle ``j`` has the lip
        edge ``loop[j + 1], loop[j]`` and the centre (:func:`facetransfer.topology.
        mesh_topology`).
    rim : (m,) int64
        The fills' vertices but their centres (the eye and mouth loops): their projections'
        box holds every pixel of the fills.
    shut : (2,) float
        Each eye's shut gap (:func:`face_shut_gaps` of the face drawn): :func:`lid_light`'s
        lower end, at and under which the eyeball is hidden.
    """

    faces: np.ndarray
    kind: np.ndarray
    eye_loops: tuple
    landmarks: np.ndarray | None
    gaze: np.ndarray | None
    mouth: tuple
    rim: np.ndarray
    shut: tuple = (LID_SHADE[0], LID_SHADE[0])

    def vertices(self, V: np.ndarray) -> np.ndarray:
        """``V`` (n_closed, 3), a frame's closed mesh, with each eye loop's centre appended."""
        if not self.eye_loops:
            return V
        return np.concatenate([V] + [V[loop].mean(axis=0, keepdims=True)
                                     for loop in self.eye_loops])


def puppet_face(model, topo, activations: np.ndarray | None = None, *,
                gaze: np.ndarray | None = None, weights=None) -> PuppetFace:
    """The solid head of ``model``'s topology ``topo`` (:func:`facetransfer.topology.
    mesh_topology`) and what its fills show (module docstring).

    Eyeballs need both eye holes and the model's landmarks; without them the eye holes stay
    closed in the skin's colour. ``gaze`` (F, 2, 2), ``[frame, eye (right, left), (yaw,
    pitch)]`` in radians (:func:`track_gaze` of a track: a take's recorded eye angles), turns
    the eyes frame by frame; else ``activations`` (F, 52), ARKit's in
    :data:`facetransfer.arkit.ARKIT_NAMES` order (:func:`arkit_activations` of a track), by
    their eyeLook* curves (:func:`facetransfer.track.gaze.activation_gaze`); neither: the eyes
    look straight ahead. ``weights`` (mode -> (r_k,)): the drawn face's, whose identity sets
    each eye's shut gap (:func:`face_shut_gaps`; its expression is not read); None: the fixed
    ``LID_SHADE[0]``.
    """
    n_c = topo.n_closed
    faces = [topo.faces]
    for k, loop in enumerate(topo.eye_loops):
        faces.append(np.stack([np.roll(loop, -1), loop, np.full_like(loop, n_c + k)], axis=1))
    faces = np.concatenate(faces)
    kind = np.full(faces.shape[0] + 1, -1, np.int8)
    lm = None if model.landmarks is None else np.asarray(model.landmarks, np.int64)
    if len(topo.eye_loops) == 2 and lm is not None:
        row = topo.faces.shape[0] + 1
        for k, loop in enumerate(topo.eye_loops):
            kind[row:row + len(loop)] = (_RIGHT, _LEFT)[k]
            row += len(loop)
    fan = topo.mouth_fan
    kind[fan.start + 1:fan.stop + 1] = _MOUTH
    if gaze is None and activations is not None:
        gaze = activation_gaze(np.asarray(activations, np.float64))
    gaze = None if gaze is None else np.asarray(gaze, np.float64)
    rim = np.concatenate([np.zeros(0, np.int64), topo.mouth_loop, *topo.eye_loops])
    return PuppetFace(faces, kind, tuple(topo.eye_loops), lm, gaze,
                      (fan.start, int(topo.mouth_loop.size)), rim.astype(np.int64),
                      tuple(face_shut_gaps(model, weights)))


def arkit_activations(track) -> np.ndarray | None:
    """``(F, 52)``: ``track``'s blendshape activations if they are ARKit's 52, else None."""
    from .arkit import ARKIT_NAMES

    b, names = track.blendshapes, track.blendshape_names
    if b is None or names is None or tuple(names) != tuple(ARKIT_NAMES):
        return None
    return np.asarray(b, np.float64)


def track_gaze(track) -> np.ndarray | None:
    """``(F, 2, 2)``, ``[frame, eye (right, left), (yaw, pitch)]`` in radians: where the eyes
    of ``track`` look, as the puppet (:func:`puppet_face`) and the ``view`` page show them.

    A Live Link Face take's own eye angles where it recorded them (``LeftEyeYaw``, ...: the
    iPhone's measure of each eye's rotation, what a rig reading the take's eye rotation curves
    is driven with; :func:`facetransfer.take.take_track` keeps them in the track's
    ``info["eye_gaze"]``, one row a frame); else :func:`facetransfer.track.gaze.
    activation_gaze` of its ARKit activations (the tracker's scale, 35° a unit of
    eyeLookIn/Out, 28° of Up/Down: what ``export`` writes as a take's eye angles); None for a
    track without ARKit activations (the eyes look ahead).
    """
    recorded = track.info.get("eye_gaze")
    if recorded is not None and np.shape(recorded) == (track.n_frames, 2, 2):
        return np.asarray(recorded, np.float64)
    a = arkit_activations(track)
    return None if a is None else activation_gaze(a)


def paint_face(image: np.ndarray, raster, V: np.ndarray, camera, face: PuppetFace,
               i: int) -> None:
    """Paint, in place, the eye and mouth fills of a rendered puppet frame.

    Parameters
    ----------
    image : (H, W, 3) uint8
        The render of ``V`` with ``face.faces`` under ``camera``.
    raster : Raster
        Its raster (``tri_id``, ``bary``).
    V : (n_closed + n_eyes, 3) float64
        The frame's mesh (:meth:`PuppetFace.vertices`).
    camera : WeakPerspective
    face : PuppetFace
    i : int
        The track's frame (its gaze).
    """
    if not face.rim.size:
        return
    # the fills' pixels lie in the box of their vertices' projections (a tenth of a frame)
    P = camera.project(V[face.rim])
    H, W = raster.tri_id.shape
    x0, y0 = np.maximum(np.floor(P.min(axis=0)).astype(np.int64) - 1, 0)
    x1, y1 = np.minimum(np.ceil(P.max(axis=0)).astype(np.int64) + 2, (W, H))
    tid = raster.tri_id[y0:max(y0, y1), x0:max(x0, x1)]
    kind = face.kind[tid + 1]
    ys, xs = np.nonzero(kind >= 0)
    if not ys.size:
        return
    k = kind[ys, xs]
    tid = tid[ys, xs]
    ys, xs = ys + y0, xs + x0
    lit = np.ones(2) if face.landmarks is None else lid_light(V[face.landmarks], face.shut)
    shut = _shut(np.bincount(k, minlength=3), V, camera, face)
    shut = (shut | np.append(lit <= 0.0, False))[k]
    if shut.any():   # the lids or the lips meeting: a line darker than the skin
        image[ys[shut], xs[shut]] = (image[ys[shut], xs[shut]] * SHUT_LINE).astype(np.uint8)
    eye = (k != _MOUTH) & ~shut
    if eye.any():
        _paint_eyeballs(image, ys[eye], xs[eye], k[eye], V, camera, face, i, lit)
    m = (k == _MOUTH) & ~shut
    if m.any():
        _paint_mouth(image, ys[m], xs[m], tid[m], raster.bary[ys[m], xs[m]], V, face)


def lid_gaps(points68: np.ndarray) -> np.ndarray:
    """``(..., 2)``, the right eye's and the left's lid gap of iBUG-68 landmark vertices
    ``points68`` ``(..., 68, 3)`` (any leading axes: frames): the mean of :data:`LID_PAIRS`'
    distances over the eye's corner distance, unsigned (:data:`LID_SHADE`'s measure)."""
    P = np.asarray(points68, np.float64)
    out = []
    for (o, i), pairs in zip(CORNER_INDEX, LID_PAIRS):
        gap = np.mean([np.linalg.norm(P[..., u, :] - P[..., lo, :], axis=-1) for u, lo in pairs],
                      axis=0)
        out.append(gap / np.maximum(np.linalg.norm(P[..., o, :] - P[..., i, :], axis=-1), 1e-12))
    return np.stack(out, axis=-1)


def shut_gaps_at_blink(blink68: np.ndarray) -> np.ndarray:
    """``(..., 2)``, each eye's (right, left) shut gap: the lid gap (:func:`lid_gaps`, eye
    widths) at and under which its eyeball is hidden, of a face's iBUG-68 landmark vertices
    with both ``eyeBlink`` shapes at 1, ``blink68`` ``(..., 68, 3)`` (the head's frame, +y up).

    The larger of ``LID_SHADE[0]`` (0.08) and the face's own gap there plus
    :data:`SHUT_MARGIN`, at most ``LID_SHADE[1]``: a face whose shut lids stop wider apart (the
    test model's identity 1: 0.098) hides its shut eyes too. Lids that cross at ``eyeBlink`` 1
    (the upper below the lower on average over :data:`LID_PAIRS`) passed a gap of 0 on the
    way: 0.08 stands. The one rule of the puppet (:func:`lid_light`), the exported glb and USD
    (:func:`facetransfer.export.gltf_eyes.shut_gaps`) and the ``view`` page (its ``placeEyes``
    computes the same of the face its dials show, :func:`facetransfer.export.viewer.eye_data`).
    """
    P = np.asarray(blink68, np.float64)
    gap = lid_gaps(P)
    apart = np.stack([np.mean([P[..., u, 1] - P[..., lo, 1] for u, lo in pairs], axis=0) > 0
                      for pairs in LID_PAIRS], axis=-1)
    own = np.where(apart, np.minimum(gap + SHUT_MARGIN, LID_SHADE[1]), 0.0)
    return np.maximum(LID_SHADE[0], own)


def blink_shapes(model) -> list[int] | None:
    """The :data:`facetransfer.arkit.ARKIT_NAMES` indices of ``eyeBlinkLeft`` and
    ``eyeBlinkRight`` (the rows of an :func:`facetransfer.arkit.expression_rig`'s deltas that
    :func:`shut_gaps_at_blink` shuts the eyes with), or None where ``model`` has no ARKit
    shapes or lacks either eyeBlink: its rig's row of a missing shape is zero, its "lids at
    eyeBlink 1" the open neutral's, which would put the shut gap at ``LID_SHADE[1]`` and hide
    the eyes whenever the lids narrow under 0.18 (a look down). The shut gap is then
    ``LID_SHADE[0]`` (the puppet, the exported glb and USD, the ``view`` page)."""
    from .arkit import ARKIT_NAMES, arkit_rows, is_arkit_model

    if not is_arkit_model(model):
        return None
    j = [ARKIT_NAMES.index(n) for n in ("eyeBlinkLeft", "eyeBlinkRight")]
    return j if bool(np.all(arkit_rows(model)[j] >= 0)) else None


def face_shut_gaps(model, weights) -> np.ndarray:
    """``(2,)``, :func:`shut_gaps_at_blink` of ``model``'s face of ``weights`` (mode -> (r_k,):
    its identity; the expression is not read) with both ``eyeBlink`` shapes at 1 (its
    :func:`facetransfer.arkit.expression_rig` at the landmarks). ``LID_SHADE[0]`` for both eyes
    where ``weights`` is None or the model has no landmarks or no eyeBlinks
    (:func:`blink_shapes`)."""
    from .arkit import expression_rig

    blink = blink_shapes(model)
    if weights is None or model.landmarks is None or blink is None:
        return np.full(2, LID_SHADE[0])
    rig = expression_rig(model, weights, vertices=np.asarray(model.landmarks, np.int64))
    D = np.asarray(rig.deltas, np.float64)
    return shut_gaps_at_blink(np.asarray(rig.neutral, np.float64) + D[blink].sum(axis=0))


def lid_light(points68: np.ndarray, shut=None) -> np.ndarray:
    """``(2,)``, the right eye's and the left's: how much its eyeball is lit as its lids close,
    ``smoothstep(shut, LID_SHADE[1], gap)`` of the lid gap (:func:`lid_gaps`) of a face's
    iBUG-68 landmark vertices ``points68`` (68, 3): 1 open, 0 shut (the ``view`` page's shade).
    ``shut`` (2,): each eye's shut gap (:func:`face_shut_gaps` of the face; None:
    ``LID_SHADE[0]``, the same light to the bit as before it was per face); where it is
    ``LID_SHADE[1]`` the light steps from 0 to 1 there."""
    lo = LID_SHADE[0] if shut is None else np.asarray(shut, np.float64)
    span = LID_SHADE[1] - lo
    gap = lid_gaps(points68)
    u = np.clip((gap - lo) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    u = np.where(span > 0, u, (gap > lo).astype(np.float64))
    return u * u * (3.0 - 2.0 * u)


def _shut(count: np.ndarray, V: np.ndarray, camera, face: PuppetFace) -> np.ndarray:
    """``(3,) bool``, the right eye, the left and the mouth: whether the fill's visible part
    (``count`` pixels each) is narrower on average than :data:`SHUT` of its width (the eye's
    corners, the mouth's, projected): the model's lids and lips do not quite meet in a blink
    or at rest, a sliver of their holes shows. A sliver thinner than a pixel lights a whole
    row of pixels where it crosses their centres and none a subpixel away, so up to
    :data:`_SLIVER_ROW` of a row along the width is allowed for beyond it: before, the mouth
    at rest of a 64x64 puppet showed the cavity and teeth at one subpixel position and not
    at another (5 pixels for a 12 pixel wide mouth), a flicker of teeth as a head moves. Without
    landmarks none is."""
    if face.landmarks is None:
        return np.zeros(3, bool)
    P = camera.project(V[face.landmarks[[36, 39, 45, 42, 48, 54]]])
    width = np.linalg.norm(P[0::2] - P[1::2], axis=1)
    return count < np.asarray(SHUT) * width ** 2 + _SLIVER_ROW * width


def _paint_eyeballs(image, ys, xs, k, V, camera, face: PuppetFace, i: int, lit) -> None:
    """Paint the eye fills' pixels ``(ys, xs)`` (eye ``k`` each: 0 right, 1 left) with the
    eyeball's sclera, iris (its rim darker: :data:`IRIS_RIM`) or pupil seen there (module
    docstring), shaded by ``lit`` (2,)
    (:func:`lid_light`: its lids closing darken it, as on the ``view`` page)."""
    eyes = eye_model(V[face.landmarks])
    angles = np.zeros((2, 2)) if face.gaze is None else face.gaze[i]
    g = gaze_direction(angles)                                        # (2, 3), the head's frame
    R = np.asarray(camera.rotation, np.float64)
    s, a = float(camera.scale), float(camera.pixel_aspect)
    t = np.asarray(camera.translation, np.float64)
    # Eq. (7) taken back: the pixel's (R X)[:2] (x columns s / a per unit, y down)
    q = np.stack([(xs - t[0]) * (a / s), (t[1] - ys) / s], axis=1)
    q = (q - (eyes.centre @ R[:2].T)[k]) / eyes.radius[k, None]
    n2 = np.sum(q * q, axis=1)
    q = q / np.sqrt(np.maximum(n2, 1.0))[:, None]                      # beyond it: the rim
    ez = np.sqrt(np.clip(1.0 - np.sum(q * q, axis=1), 0.0, None))
    d = np.column_stack([q, ez]) @ R                                  # R^T e, the head's frame
    cos = np.sum(d * g[k], axis=1)
    # the iris and the pupil as discs on the ball (its radius EYE_RADIUS at FaceKit's width)
    a_iris, a_pupil = (np.arcsin(min(r / EYE_RADIUS, 1.0)) for r in (IRIS_RADIUS, PUPIL_RADIUS))
    # from the pupil's edge to the iris's: IRIS, then toward LIMBUS past IRIS_RIM of the way
    t = (np.arccos(np.clip(cos, -1.0, 1.0)) - a_pupil) / max(a_iris - a_pupil, 1e-12)
    rim = np.clip((t - IRIS_RIM) / (1.0 - IRIS_RIM), 0.0, 1.0)[:, None]
    iris = np.array(IRIS, np.float64) * (1.0 - rim) + np.array(LIMBUS, np.float64) * rim
    colour = np.where((cos > np.cos(a_pupil))[:, None], np.array(PUPIL, np.float64),
                      np.where((cos > np.cos(a_iris))[:, None], iris,
                               np.array(SCLERA, np.float64)))
    light = (_EYE_AMBIENT + (1.0 - _EYE_AMBIENT) * ez) * np.asarray(lit)[k]
    image[ys, xs] = np.clip(colour * light[:, None] + 0.5, 0, 255).astype(np.uint8)


def _paint_mouth(image, ys, xs, tid, bary, V, face: PuppetFace) -> None:
    """Paint the mouth fan's pixels ``(ys, xs)`` (triangle ``tid``, barycentrics ``bary``
    (n, 3), the fan's centre last) with the cavity, darker toward the centre, and the upper
    teeth: the band, in the head's frame, from the upper lip's middle down :data:`TEETH_SHOW`
    eye widths, over the middle 55 % of the mouth's width."""
    w = bary[:, 2].astype(np.float64)
    colour = np.array(CAVITY, np.float64) * (1.0 - (1.0 - CAVITY_BACK) * w)[:, None]
    if face.landmarks is not None:
        start, k = face.mouth
        loop = V[face.faces[start:start + k, 1]]
        c = V[face.faces[start, 2]]                                       # the fan's centre
        half = (loop[:, 0].max() - loop[:, 0].min()) / 2
        mid = loop[(np.abs(loop[:, 0] - c[0]) < 0.25 * half) & (loop[:, 1] > c[1]), 1]
        E = V[face.landmarks[[36, 39, 42, 45]]]
        show = TEETH_SHOW * (np.linalg.norm(E[0] - E[1]) + np.linalg.norm(E[2] - E[3])) / 2
        X = np.einsum("nk,nkd->nd", bary.astype(np.float64), V[face.faces[tid]])
        if mid.size:
            teeth = (X[:, 1] > mid.min() - show) & (np.abs(X[:, 0] - c[0]) < TEETH_SPAN * half)
            colour[teeth] = TEETH
    image[ys, xs] = np.clip(colour + 0.5, 0, 255).astype(np.uint8)


def preview_face(model, weights, *, size: tuple[int, int] = (640, 480), yaw_deg: float = 0.0,
                 pitch_deg: float = 0.0, roll_deg: float = 0.0, scale: float = 1.0,
                 fill: float = 0.8, background=(255, 255, 255)):
    """:func:`facetransfer.render.render_model`'s preview (the same framing and grey Lambert
    shading) of the model's face with its eye holes and mouth gap closed and painted as the
    puppet's (:func:`paint_face`): ``facetransfer render``'s picture. The eyes look where the
    expression weights' eyeLook* activations say for an ARKit model
    (:func:`facetransfer.arkit.weights_to_activations`), straight ahead otherwise; a model
    without landmarks (no holes found) is rendered as ``render_model`` renders it.

    Parameters
    ----------
    model : MultilinearModel
    weights : mapping mode -> (r_k,)
    size, yaw_deg, pitch_deg, roll_deg, scale, fill, background
        As :func:`facetransfer.render.render_model`'s.

    Returns
    -------
    RenderResult
        Its ``visible`` holds the model's vertices only (not the fills' centres).
    """
    from .arkit import is_arkit_model, weights_to_activations
    from .errors import ShapeError
    from .render import look_at_weak_perspective, rotation_from_euler
    from .topology import mesh_topology

    if not (np.isfinite(scale) and scale > 0):
        raise ShapeError(f"preview scale must be > 0, got {scale}")
    V = np.asarray(model.synthesize(weights), dtype=np.float64)
    cam = look_at_weak_perspective(V, size, rotation=rotation_from_euler(yaw_deg, pitch_deg,
                                                                         roll_deg),
                                   fill=fill * scale)
    acts = None
    if is_arkit_model(model):
        acts = weights_to_activations(model, np.asarray(weights["expression"])[None])[0]
    return draw_face(model, mesh_topology(model, lips=False), V, cam, size, activations=acts,
                     background=background, weights=weights)


def draw_face(model, topo, V: np.ndarray, camera, size: tuple[int, int], *,
              activations: np.ndarray | None = None, colour=None,
              background=(255, 255, 255), weights=None):
    """The face ``V`` (n, 3) of ``model`` rendered under ``camera`` into an image of ``size``
    ``(W, H)``, its eye holes and mouth gap closed and painted as the puppet's
    (:func:`paint_face`): :func:`preview_face`'s picture with a camera of the caller's (a
    sheet's tiles share one). ``topo``: :func:`facetransfer.topology.mesh_topology` of the
    model with ``lips=False``; ``activations`` (52,): the face's ARKit activations, which turn
    its eyes (none: they look ahead); ``colour``: the skin's RGB in [0, 1] (default the
    renderer's grey); ``weights`` (mode -> (r_k,)): the face's, whose identity sets the eyes'
    shut gap (:func:`face_shut_gaps`; None: ``LID_SHADE[0]``).

    Returns
    -------
    RenderResult
        Its ``visible`` holds ``V``'s vertices only (not the fills' centres).
    """
    import dataclasses

    from .render import render
    from .topology import close_mouth

    acts = None if activations is None else np.asarray(activations, np.float64).reshape(1, -1)
    face = puppet_face(model, topo, acts, weights=weights)
    V = np.asarray(V, dtype=np.float64)
    Vc = face.vertices(close_mouth(V, topo))
    colors = None if colour is None else np.tile(np.asarray(colour, np.float64), (len(Vc), 1))
    res = render(Vc, face.faces, camera, size, colors=colors, background=background)
    paint_face(res.image, res.raster, Vc, camera, face, 0)
    return dataclasses.replace(res, visible=res.visible[:V.shape[0]])

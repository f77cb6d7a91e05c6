"""A mouth's inside drawn where the target's own frames never show one.

A transfer's mouth is textured from the source of its motion (§6: the source video's mouth,
:mod:`facetransfer.mouth`). A ready performance (``--performance``, a Live Link Face take) has
no pictures: its mouth is textured from the target's own frames (the texture function of §6
lifted from them, or the target's frame of the nearest expression). Where the target never opens
its mouth (a photo with the lips shut, a clip whose speaker keeps them closed) those frames hold
no inside: the new mouth's opening, the mouth-closing fan (:attr:`facetransfer.topology.
MeshTopology.mouth_fan`), shows the lips' colour stretched across it, not a dark gap and teeth,
and Face Landmarker reads such a mouth as less open (BENCHMARKS.md, "Fifty-fourth session").

Here, decided by measurement:

1. :func:`drawn_inside` measures how much inside the target's frames show: in each frame the
   mouth texture can come from, the fan of the target's own tracked mesh (Eq. 5, Eq. 7) is
   rasterised with the lips and the skin around them, and its pixels darker than
   :data:`INSIDE_DARK` of the lips' median luminance are counted, over the squared distance
   of the inner mouth corners (iBUG 60, 64). The most of any frame is what the frames *show*.
   The same frames give the colours: the skin's around the mouth and the lips' darkest tones;
2. per output frame, the new mouth's opening is the fan's pixels in the render over the same
   squared width; the inside is drawn by :meth:`DrawnInside.strength`, a smoothstep of that
   opening over what the frames show (:data:`SHOWN_RAMP`: the target's own inside stretched
   less than four times stays the target's) times one of the opening itself (:data:`OPEN_RAMP`: a
   mouth that hardly parts shows a line, the lips' own);
3. :func:`paint_inside` paints the fan's pixels of the mouth texture, placed in the head's frame
   of the new mesh as the puppet's mouth is (:mod:`facetransfer.puppet_face`), from the
   opening's edges where the lips are seen to end: the cavity at :data:`CAVITY_LEVEL` of the
   target's skin (the palette's cavity over its skin, :data:`facetransfer.palette.PALETTE`),
   half its lips' darkest tone's hue and half the palette's, darker toward the back (the
   fan's centre, :data:`facetransfer.palette.CAVITY_BACK`); the tongue, a dome over the lower
   lip in the lips' colour darkened (:data:`TONGUE_SHARE`, :data:`TONGUE_LEVEL`); the lower
   teeth over it (:data:`facetransfer.dental.LOWER_SHOW`, :data:`LOWER_SHARE`) and the upper
   teeth under the upper lip (:data:`facetransfer.palette.TEETH_SHOW` eye widths, at most
   :data:`UPPER_SHARE` of the opening), over the middle of the mouth's width, drawn on the
   dental arch behind the lips (:func:`facetransfer.dental.dental_arch`) seen along the
   camera's view in the head's frame (:data:`facetransfer.dental.ARCH_CURVE`: a turned head's far
   teeth foreshortened, hidden past the far lip's corner), in the palette's teeth colour at
   :data:`TEETH_LEVEL` of the target's skin (one gain: lit like the target's face), darker
   toward the mouth's corners, in the upper lip's shadow and on the lower teeth, parted at the
   incisors; the lips' inner edge blended over :data:`EDGE_FEATHER` of the mouth's width. The
   mouth texture then takes the face's colours around it as any mouth does
   (:func:`facetransfer.mouth.blend_mouth`).

Only a mouth textured from the target's own frames is drawn (:class:`facetransfer.rewrite_clip.
MouthSource` ``own``): a transfer from a video shows the source's own mouth, to the bit as
before.

Beyond the paper (its §6 takes the mouth from the source video, which a take does not have).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .dental import ARCH_CURVE, LOWER_SHADE, LOWER_SHOW, dental_arch, teeth_shade
from .mouth import mouth_ring_faces
from .palette import CAVITY_BACK, PALETTE, TEETH_SHOW, TEETH_SPAN
from .region_weights import smoothstep
from .topology import MeshTopology, close_mouth

log = logging.getLogger(__name__)

__all__ = ["INSIDE_DARK", "SHOWN_RAMP", "OPEN_RAMP", "MEASURED_FRAMES", "SeenMouth",
           "DrawnInside", "drawn_inside", "shown_inside", "paint_inside"]

#: A pixel of the target's mouth opening (its fan, as its track has it) shows the inside when
#: its luminance is below this fraction of the lips' median: the cavity's dark, not the lips'
#: colour the fan covers where the lips meet (a photo with the lips shut: none).
INSIDE_DARK = 0.6
#: :meth:`DrawnInside.strength`'s ramp over the new opening divided by what the target's frames
#: show (both the fan's pixels over the squared inner mouth width): drawn from four times,
#: fully from eight. A take opens the mouths of the clips that talk with it open (which show
#: 0.15-0.17) to 3.1-3.8 times that, whose own inside is kept; those that never open it
#: (photos with the lips shut show at most 0.01, ``driving_d9``'s closed stretch 0.03) to 19
#: times and more.
SHOWN_RAMP = (4.0, 8.0)
#: ... and over the new opening itself: a mouth parted by less than 0.02 shows the lips' line
#: (the puppet's shut mouth: :data:`facetransfer.puppet_face.SHUT`), drawn fully from 0.06.
OPEN_RAMP = (0.02, 0.06)
#: The target's frames measured by :func:`drawn_inside` at most (evenly spaced): as many as
#: the texture function lifts (:data:`facetransfer.texture.face.MOUTH_MAX_FRAMES`), ~2.5 ms
#: each.
MEASURED_FRAMES = 120
#: The upper teeth take at most this share of the opening's height, the lower teeth
#: :data:`LOWER_SHARE`: the cavity shows between them.
UPPER_SHARE = 0.45
LOWER_SHARE = 0.25
#: The teeth's luminance over the target's skin's (the median around its mouth), measured
#: where real teeth show: the brightest twentieth of the opening (MediaPipe's inner lips in
#: the clips' frames opened over a quarter of their width, where that twentieth is over 1.6
#: times the opening's median; the human points' in the photo) over the median of the skin
#: about the mouth: ``takeo.ppm`` 1.55 (and 1.56 darkened to 0.35), ``WDA_KatieHill_000``
#: 1.48, ``driving_d6`` 1.35, ``face_2`` 0.85 (a darkly lit face), ``driving_d9`` 0.67 (lower
#: teeth in the lip's shadow): their median. Over the eye whites' (their brightest tenth)
#: the clips' ratios are no steadier (1.46, 0.93, 1.22, 0.70): the teeth follow the light
#: the skin shows. (mouth54's 1.25, the palette's teeth over its skin, 1.21, a little more,
#: drew them under every source whose upper teeth show lit.)
TEETH_LEVEL = 1.35
#: The tongue: a dome over the lower lip rising to this share of the opening's height in the
#: middle, over this fraction of the mouth's half-width, in the lips' colour at
#: :data:`TONGUE_LEVEL` of their luminance (darker toward the mouth's corners).
TONGUE_SHARE = 0.35
TONGUE_SPAN = 0.75
TONGUE_LEVEL = 0.6
#: The lips' inner edge: the drawn inside fades in over this fraction of the mouth's width
#: (in pixels, at least one).
EDGE_FEATHER = 0.06
#: Luminance (Rec. 601) of RGB.
_LUMA = np.array([0.299, 0.587, 0.114])
#: The palette's cavity over its skin, in luminance: how dark the cavity is at the lips.
CAVITY_LEVEL = float(_LUMA @ PALETTE["cavity"] / (_LUMA @ PALETTE["skin"]))


@dataclass(frozen=True)
class SeenMouth:
    """What one target frame shows of its mouth (:func:`shown_inside`).

    Attributes
    ----------
    shown : float
        The fan's pixels darker than :data:`INSIDE_DARK` of the lips' median luminance, over
        the squared distance of the inner mouth corners (pixels).
    skin : (3,) float64
        The median colour of the skin around the mouth.
    lips : (3,) float64
        The lips' median colour.
    dark : (3,) float64
        The mean colour of the lips' darkest tenth (where they meet: what shows of the inside
        between shut lips).
    """

    shown: float
    skin: np.ndarray
    lips: np.ndarray
    dark: np.ndarray


@dataclass(frozen=True)
class DrawnInside:
    """The inside drawn into a clip's mouth where it opens beyond its target's frames.

    Attributes
    ----------
    shown : float
        The most inside the target's frames show (:attr:`SeenMouth.shown`), the largest over
        the frames measured.
    cavity : (3,) float64
        The cavity's colour at the lips (RGB, 0-255).
    tongue : (3,) float64
        The tongue's colour at its front.
    teeth : (3,) float64
        The teeth's colour facing the light.
    corners : (2,) int64
        The model's vertices of the inner mouth corners (iBUG 60, 64): the mouth's width.
    eyes : (4,) int64
        The model's vertices of the eye corners (iBUG 36, 39, 42, 45): the teeth's scale.
    """

    shown: float
    cavity: np.ndarray
    tongue: np.ndarray
    teeth: np.ndarray
    corners: np.ndarray
    eyes: np.ndarray

    def strength(self, opening: float) -> float:
        """How much of the drawn inside a frame takes, in [0, 1], for the new mouth's
        ``opening`` (its fan's pixels over the squared inner mouth width)."""
        ratio = opening / max(self.shown, 1e-6)
        return float(smoothstep(np.float64(ratio), SHOWN_RAMP)
                     * smoothstep(np.float64(opening), OPEN_RAMP))


def drawn_inside(frames, track, model, topo: MeshTopology, rows) -> DrawnInside | None:
    """What a clip's mouth draws where it opens wider than the target's frames ``rows`` show.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8
        The target's frames.
    track : Track
        The target's own track (row ``i`` is frame ``i``).
    model : MultilinearModel
        With iBUG-68 landmarks.
    topo : MeshTopology
        With a mouth-closing fan.
    rows : (m,) int
        The frames the mouth's texture can come from (the texture function's lifted frames,
        or the nearest frames); at most :data:`MEASURED_FRAMES` of them, evenly spaced, are
        measured.

    Returns
    -------
    DrawnInside or None
        None without landmarks, a fan, or a frame where the mouth and its skin are seen.
    """
    if model.landmarks is None or topo.mouth_fan.stop == topo.mouth_fan.start:
        return None
    lm = np.asarray(model.landmarks, np.int64)
    corners, eyes = lm[[60, 64]], lm[[36, 39, 42, 45]]
    rows = np.unique(np.asarray(rows, np.int64))
    rows = rows[(rows >= 0) & (rows < min(len(frames), track.n_frames))]
    rows = rows[~np.asarray(track.lost, bool)[rows]]
    if rows.size > MEASURED_FRAMES:
        rows = rows[np.unique(np.linspace(0, rows.size - 1, MEASURED_FRAMES).round()
                              .astype(np.int64))]
    parts = _parts(topo)
    seen = [s for s in (shown_inside(np.asarray(frames[i]), V, track.camera(i), topo, corners,
                                     parts)
                        for i, V in zip(rows, _mouth_meshes(model, track, topo, rows, parts[0])))
            if s is not None]
    if not seen:
        return None
    shown = max(s.shown for s in seen)
    cavity, tongue, teeth = _colours(*(np.median([getattr(s, k) for s in seen], axis=0)
                                       for k in ("skin", "lips", "dark")))
    log.info("mouth inside: the target's frames show %.3f (%d measured); drawn where the new "
             "mouth opens beyond %.3f, cavity %s, teeth %s", shown, len(seen),
             SHOWN_RAMP[0] * shown, np.round(cavity).astype(int), np.round(teeth).astype(int))
    return DrawnInside(float(shown), cavity, tongue, teeth, corners, eyes)


def _mouth_meshes(model, track, topo: MeshTopology, rows: np.ndarray, faces: np.ndarray):
    """The closed meshes (n_closed, 3) of ``track``'s ``rows`` (Eq. 5, no pose) where the
    triangles ``faces`` reach, one by one: their vertices synthesised for every row in one
    product (the rest of each mesh is 0), the mouth's centre closed
    (:func:`facetransfer.topology.close_mouth`)."""
    verts = np.unique(faces)
    verts = verts[verts < topo.n_vertices]
    W = {m: np.asarray(track.weights[m])[rows] for m in track.mode_names}
    part = model.synthesize(W, vertices=verts)                        # (m, k, 3)
    for P in part:
        V = np.zeros((topo.n_vertices, 3))
        V[verts] = P
        yield close_mouth(V, topo)


def _parts(topo: MeshTopology) -> tuple[np.ndarray, np.ndarray]:
    """``(faces, part)``: the triangles of the mouth and of its ring of skin
    (:func:`facetransfer.mouth.mouth_ring_faces`) and each one's part: 0 the fan, 1 the lips,
    2 the skin."""
    part = np.full(len(topo.faces), -1, np.int8)
    part[mouth_ring_faces(topo)] = 2
    part[np.asarray(topo.mouth_faces, np.int64)] = 1
    part[topo.mouth_fan] = 0
    keep = np.flatnonzero(part >= 0)
    return topo.faces[keep], part[keep]


def shown_inside(frame: np.ndarray, V: np.ndarray, camera, topo: MeshTopology,
                 corners: np.ndarray, parts: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> SeenMouth | None:
    """How much inside one target frame shows, and its mouth's colours.

    Parameters
    ----------
    frame : (H, W, 3) uint8
    V : (n_closed, 3) float64
        The target's closed mesh in that frame (:func:`facetransfer.topology.close_mouth`).
    camera : WeakPerspective
        Its pose (Eq. 7).
    topo : MeshTopology
    corners : (2,) int64
        The model's inner mouth corners.
    parts : optional
        :func:`_parts` of ``topo``, if at hand.

    Returns
    -------
    SeenMouth or None
        None where fewer than 8 pixels of the lips or of the skin are seen.
    """
    from .render import rasterize

    faces, part = _parts(topo) if parts is None else parts
    P = camera.project(V[np.unique(faces)])
    H, W = frame.shape[:2]
    x0, y0 = (max(int(np.floor(v)) - 1, 0) for v in P.min(axis=0))
    x1, y1 = min(int(np.ceil(P[:, 0].max())) + 2, W), min(int(np.ceil(P[:, 1].max())) + 2, H)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    cam = camera.shifted(float(x0), float(y0)) if hasattr(camera, "shifted") else camera
    tid = rasterize(V, faces, cam, (x1 - x0, y1 - y0)).tri_id
    crop = frame[y0:y1, x0:x1].astype(np.float64)
    label = np.where(tid >= 0, part[np.maximum(tid, 0)], -1)
    lips, skin = crop[label == 1], crop[label == 2]
    if len(lips) < 8 or len(skin) < 8:
        return None
    luma = lips @ _LUMA
    fan = crop[label == 0] @ _LUMA
    width = float(np.linalg.norm(np.subtract(*camera.project(V[corners]))))
    shown = np.count_nonzero(fan < INSIDE_DARK * np.median(luma)) / max(width, 1.0) ** 2
    return SeenMouth(float(shown), np.median(skin, axis=0), np.median(lips, axis=0),
                     lips[luma <= np.percentile(luma, 10)].mean(axis=0))


def _colours(skin: np.ndarray, lips: np.ndarray, dark: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(cavity, tongue, teeth)`` (3,) float64 of the target's mouth (:class:`SeenMouth`'s
    fields). The cavity at :data:`CAVITY_LEVEL` of the skin's luminance (the palette's cavity
    over its skin), its hue half the lips' dark tone's and half the palette cavity's (a
    lipstick's red, whose dark tone is the lips' and not the inside's, was a saturated red
    cavity; the palette's alone where that tone is black); the tongue the lips' colour at
    :data:`TONGUE_LEVEL` of theirs; the teeth the palette's at :data:`TEETH_LEVEL` of the
    skin's luminance (one gain for the three channels: the target's light, not its skin's
    hue)."""
    palette = np.asarray(PALETTE["cavity"], np.float64)
    hue = palette / float(_LUMA @ palette)
    d = float(_LUMA @ dark)
    if d > 1.0:
        hue = 0.5 * (hue + dark / d)
    teeth = np.asarray(PALETTE["teeth"], np.float64)
    teeth *= TEETH_LEVEL * float(_LUMA @ skin) / float(_LUMA @ teeth)
    cavity = hue * (CAVITY_LEVEL * float(_LUMA @ skin))
    return np.minimum(cavity, 255.0), lips * TONGUE_LEVEL, np.minimum(teeth, 255.0)


def paint_inside(mouth_img: np.ndarray, raster, V: np.ndarray, camera, topo: MeshTopology,
                 inside: DrawnInside, fan: np.ndarray) -> float:
    """Paint, in place, the drawn inside into the mouth texture's fan pixels of one frame.

    Parameters
    ----------
    mouth_img : (H, W, 3) uint8
        The mouth's texture as rendered (the fan's pixels are painted).
    raster : Raster
        Of the new closed mesh ``V`` with ``topo.faces`` under ``camera``.
    V : (n_closed, 3) float64
        The new face (Eq. 5), mouth closed.
    camera : WeakPerspective
    topo : MeshTopology
    inside : DrawnInside
    fan : (H, W) bool
        The fan's pixels (:func:`facetransfer.mouth.inside_mouth`).

    Returns
    -------
    float
        The strength drawn (:meth:`DrawnInside.strength`; 0: nothing painted).
    """
    ys, xs = np.nonzero(fan)
    width = float(np.linalg.norm(np.subtract(*camera.project(V[inside.corners]))))
    if not ys.size or width <= 1.0:
        return 0.0
    s = inside.strength(ys.size / width ** 2)
    if s <= 0.0:
        return 0.0
    tid = raster.tri_id[ys, xs]
    bary = raster.bary[ys, xs].astype(np.float64)
    X = np.einsum("nk,nkd->nd", bary, V[topo.faces[tid]])        # the head's frame
    px = 1.0 / max(float(getattr(camera, "scale", 1.0)), 1e-9)   # model units a pixel
    view = np.asarray(getattr(camera, "rotation", np.eye(3)), np.float64)[2]
    colour = _inside_colours(X, bary[:, 2], V, topo, inside, px, -view)
    a = s * _edge_alpha(fan, ys, xs, max(1.0, EDGE_FEATHER * width))
    old = mouth_img[ys, xs].astype(np.float64)
    mouth_img[ys, xs] = np.clip(old + a[:, None] * (colour - old) + 0.5, 0, 255).astype(np.uint8)
    return s


def _edge_alpha(fan: np.ndarray, ys: np.ndarray, xs: np.ndarray, feather: float) -> np.ndarray:
    """``(n,)`` in (0, 1]: the fan's pixels ``(ys, xs)`` faded in over ``feather`` pixels from
    the lips' inner edge (their distance to the nearest pixel outside the fan)."""
    import cv2

    y0, x0 = max(int(ys.min()) - 1, 0), max(int(xs.min()) - 1, 0)
    box = fan[y0:int(ys.max()) + 2, x0:int(xs.max()) + 2]
    pad = np.pad(box, 1).view(np.uint8)
    d = cv2.distanceTransform(pad, cv2.DIST_L2, 3)[1:-1, 1:-1]
    return np.clip(d[ys - y0, xs - x0] / feather, 0.0, 1.0)


def _visible_edges(X: np.ndarray, px: float):
    """The opening's visible upper and lower edges over the points ``X`` (n, >= 2) it shows
    (the fan's, or the dental arch's: x and y in the head's frame): a function of x (m,)
    giving ``(up, low)`` (m,) there, the highest and the lowest point seen in its column (x in
    bins of 1.5 pixels, ``px`` model units a pixel), interpolated between columns. The lips
    occlude the fan's rim (the inner-lip loop lies behind their edge), so the teeth hang from
    where the lips are seen to end."""
    x, y = X[:, 0], X[:, 1]
    lo, hi = float(x.min()), float(x.max())
    nb = max(int((hi - lo) / (1.5 * px)), 1)
    b = np.minimum(((x - lo) * (nb / max(hi - lo, 1e-12))).astype(np.int64), nb - 1)
    top, bottom = np.full(nb, -np.inf), np.full(nb, np.inf)
    np.maximum.at(top, b, y)
    np.minimum.at(bottom, b, y)
    seen = np.isfinite(top)
    centres = (lo + (np.arange(nb) + 0.5) * ((hi - lo) / nb))[seen]
    return lambda at: (np.interp(at, centres, top[seen]), np.interp(at, centres, bottom[seen]))


def _arch_hits(X: np.ndarray, ray: np.ndarray, middle: float, front: float, eye: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, y, seen)`` (n,): where the view rays through the fan's points ``X`` (n, 3) (the
    head's frame; ``ray`` (3,) the camera's view into the head there) first meet the dental
    arch ``z = front - ARCH_CURVE x'²`` (x' = (x - ``middle``) / ``eye``, z in eye widths as
    well): the arch point's x less ``middle`` and its y, and whether the ray meets the arch at
    all (a ray passing beside its far side sees the cheek's dark inside). A frontal ray
    (``ray`` along -z) meets it straight behind its point: ``x`` is the point's."""
    P = np.column_stack([X[:, 0] - middle, X[:, 1], X[:, 2]]) / eye
    d = ray / max(float(np.linalg.norm(ray)), 1e-12)
    # X + t d on the arch: a t² + b t + c = 0
    a = ARCH_CURVE * d[0] ** 2
    b = d[2] + 2.0 * ARCH_CURVE * P[:, 0] * d[0]
    c = P[:, 2] - front / eye + ARCH_CURVE * P[:, 0] ** 2
    disc = b * b - 4.0 * a * c
    seen = disc >= 0.0
    root = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):       # the nearer root, stably
        t = np.where(b < 0.0, 2.0 * c / (root - b), (-b - root) / (2.0 * a))
    t = np.where(seen & np.isfinite(t), t, 0.0)
    return eye * (P[:, 0] + t * d[0]), eye * (P[:, 1] + t * d[1]), seen


def _inside_colours(X: np.ndarray, back: np.ndarray, V: np.ndarray, topo: MeshTopology,
                    inside: DrawnInside, px: float, ray: np.ndarray) -> np.ndarray:
    """``(n, 3)`` float64: the colour of the inside at the fan's points ``X`` (n, 3) (the head's
    frame; ``back`` (n,) the fan centre's barycentric): the cavity darker toward the back, the
    tongue, the lower and the upper teeth over it (module docstring), the teeth on the dental
    arch seen along ``ray`` (3,), the camera's view into the head (:func:`_arch_hits`); ``px``
    model units a pixel (the parts' edges are soft over one)."""
    colour = inside.cavity[None, :] * (1.0 - (1.0 - CAVITY_BACK) * back)[:, None]
    arch = dental_arch(V, topo, inside.eyes)
    eye, half, middle = arch.eye, arch.half, arch.middle
    x, y = X[:, 0] - middle, X[:, 1]
    edges = _visible_edges(X, px)
    up, low = edges(X[:, 0])

    def over(part, a):                                   # ``part`` (n, 3) where ``a`` (n,)
        colour[:] += a[:, None] * (part - colour)

    u = np.clip(np.abs(x) / (TONGUE_SPAN * half), 0.0, 1.0)
    top = low + TONGUE_SHARE * np.maximum(up - low, 0.0) * np.sqrt(1.0 - u * u)     # a dome
    over(inside.tongue[None, :] * (1.0 - 0.4 * u)[:, None],
         np.clip((top - y) / px + 0.5, 0.0, 1.0) * (u < 1.0))
    span = TEETH_SPAN * half
    for lower, front in ((True, arch.lower), (False, arch.upper)):
        xa, ya, seen = _arch_hits(X, ray, middle, front, eye)
        if not seen.any():
            continue
        # the lips' edges where they cover the arch (a nod moves them over it, not the teeth)
        at_up, at_low = _visible_edges(np.column_stack([xa, ya])[seen], px)(xa)
        gap = np.maximum(at_up - at_low, 0.0)
        reach = _seen_as(xa, ray, eye)
        teeth = teeth_shade(inside.teeth, xa, span, eye)
        if lower:
            edge = at_low + np.minimum(LOWER_SHOW * eye, LOWER_SHARE * gap)
            a = np.clip((edge - ya) / px + 0.5, 0.0, 1.0)
            over(teeth * LOWER_SHADE, a * np.clip((0.8 * span - reach) / px + 0.5, 0, 1)
                 * seen)
        else:
            edge = at_up - np.minimum(TEETH_SHOW * eye, UPPER_SHARE * gap)
            under = 0.6 + 0.4 * np.clip((up - y) / (0.1 * eye), 0.0, 1.0)  # the lip's shadow
            a = np.clip((ya - edge) / px + 0.5, 0.0, 1.0)
            over(teeth * under[:, None], a * np.clip((span - reach) / px + 0.5, 0, 1)
                 * seen)
    return colour


def _seen_as(x: np.ndarray, ray: np.ndarray, eye: float) -> np.ndarray:
    """``(n,)`` >= 0: how far from the middle the teeth at the dental arch's points ``x`` (n,)
    from the middle (model units; ``eye`` the eye width) reach as a frontal view's do: ``|x|``,
    or nearer the middle where ``ray`` (3,) sees the arch more squarely than a frontal view
    sees it there (the arch's normal against the view, both across the head: a nod does not
    turn the teeth). A turned head's near side, its canine seen squarely, shows teeth past the
    frontal span; the far side is foreshortened and hidden by the arch's own geometry
    (:func:`_arch_hits`). Frontal: ``|x|``."""
    u = x / eye
    v = np.array([-ray[0], -ray[2]]) / max(float(np.hypot(ray[0], ray[2])), 1e-12)
    facing = (2.0 * ARCH_CURVE * u * v[0] + v[1]) / np.sqrt(1.0 + (2.0 * ARCH_CURVE * u) ** 2)
    with np.errstate(divide="ignore"):
        slope = np.sqrt(np.maximum(1.0 / np.maximum(facing, 0.0) ** 2 - 1.0, 0.0))
    return np.minimum(np.abs(x), eye * slope / (2.0 * ARCH_CURVE))

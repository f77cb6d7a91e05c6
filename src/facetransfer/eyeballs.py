"""The eyeballs turned to the new performance's gaze (beyond the paper).

The eye region (:mod:`facetransfer.eyes`) shows one target frame's eyeball through the new lids,
so the result kept that frame's gaze in every frame, whatever the source looked at. Here each
eye's eyeball texture is shifted, per frame, by how far the new performance's gaze moves the
iris from where the reference frame's gaze has it, both as the reference frame sees them: an
eyeball behind each eye's corners (:func:`facetransfer.track.gaze.eye_model`) turned by the
eyeLook* activations (:func:`facetransfer.track.gaze.activation_gaze`, the inverse of what the
tracker reads from Face Landmarker's iris points) and projected with that frame's pose
(:func:`facetransfer.track.gaze.project_iris`). What the shift uncovers beyond the reference
frame's eye opening (the sclera under its lids) is filled once per clip from the opening's
nearest pixel (:func:`extend_eyeballs`).

With :data:`LIFT` (off by the judge: BENCHMARKS.md, "Fifty-third session (helper eyeball53)"),
an eye of the reference frame looking aside shows instead the eyeball of a frame of the clip
looking nearer ahead (:func:`eyeball_frames`), lifted into the reference frame through the two
frames' eyeballs (:func:`_eye_affine`), the lids and brows still the reference frame's: turned
to the new gaze, it uncovers less of what its frame hides.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .io.frame_numbers import track_first_number
from .jit import maybe_njit as _maybe_njit
from .topology import close_mouth
from .track.gaze import GazeOptions, activation_gaze, eye_model, project_iris

log = logging.getLogger(__name__)

__all__ = ["GROW", "RIM_WIDTH", "LIMIT", "IRIS_CONTRAST", "IRIS_LEVEL", "BAND", "ELONGATION",
           "SOFT",
           "Eyeballs", "extend_eyeballs", "eyeballs_of", "shift_eyeballs", "track_gaze",
           "gaze_offset", "eye_offsets", "eyeball_frames", "EYEBALL_GAIN", "EYEBALL_VIEW",
           "EYEBALL_ANGLE", "LIFT_GROW", "LIFT", "eye_room", "SKIN_SHARE", "SKIN_DISTANCE",
           "SKIN_SPREAD_MIN", "EYE_MIN_WIDTH",
           "SKIN_RING"]

#: :func:`extend_eyeballs`: the opening grows by this fraction of the eye's width (pixels of the
#: reference frame) under the lids; its own rim of this many pixels (lashes and the lid margin
#: where the track's margin is a little off) is redone too ...
GROW, RIM = 0.35, 1
#: ... in :func:`eyeballs_of`, one pixel per this many of the eye's width, rounded (at least
#: :data:`RIM`): the data folder's clips' eyes, 43-59 px wide over all their frames, 1 px,
#: where it was chosen (2 px from 63 px: a face of eyes ~140-150 px apart, about where
#: :data:`facetransfer.face_scale.FACE_SPAN` grows the rewrite's other pixel settings); a face
#: 2.5 times larger (a 1280x1280 clip: eyes 120 px wide) 3 px. With 1 px there, the lashes were
#: continued under the lids as the eyeball: the sclera that a turned iris uncovers showed as a
#: flat grey-brown wedge (BENCHMARKS.md, "Fifty-fourth session (helper large54)").
RIM_WIDTH = 42.0
#: The largest shift of an iris, a fraction of its eye's width in the reference frame (beyond it
#: the inpainted sclera would show more than the eye).
LIMIT = 0.3


@dataclass(frozen=True)
class Eyeballs:
    """The reference frame's eyeballs, to be turned to another gaze.

    Attributes
    ----------
    image : (H, W, 3) uint8
        The reference frame with each eye's opening extended under its lids
        (:func:`extend_eyeballs`).
    eyes : EyeModel
        The target's eyeballs in the reference frame (model units).
    angles : (2, 2) float64
        The reference frame's gaze, ``[eye (right, left), (yaw, pitch)]`` (radians; yaw > 0
        toward the subject's left, pitch > 0 up: :mod:`facetransfer.track.gaze`).
    pose : tuple
        ``(R (3, 3), s, t (2,), pixel aspect)``, the reference frame's weak-perspective pose.
    limit : (2,) float64
        Each eye's largest shift in pixels (:data:`LIMIT`).
    lookup : (F' + 1,) int8
        Indexed by a raster's ``tri_id + 1``: the eye (0 right, 1 left) whose opening a fill
        triangle of the eye-closed topology closes; -1 for the others and for the background.
    iris : (2, 2) float64
        Where :attr:`angles` put each iris in the reference frame (pixels).
    source : (2,) int64 or None
        Per eye, the frame whose eyeball :attr:`image` shows there, lifted into the reference
        frame (:func:`eyeball_frames`; :attr:`angles` is that frame's gaze); None: the
        reference frame's own eyeballs.
    room : (2, 4) float64 or None
        A photo's (:func:`eye_room`): per eye, its long axis (x, y) (a unit vector) and the
        most pixels its iris may move along it forward, then backward: the sclera the photo
        shows beyond the iris on the side the move uncovers; both 0 for an opening that does
        not show an eye (that eye keeps the photo's gaze, and so does its fellow: one eye
        turned beside one held looked aside of each other). None: :attr:`limit` alone.
    """

    image: np.ndarray
    eyes: object
    angles: np.ndarray
    pose: tuple
    limit: np.ndarray
    lookup: np.ndarray
    iris: np.ndarray
    source: np.ndarray | None = None
    room: np.ndarray | None = None

    @property
    def lifted(self) -> bool:
        """Whether an eye's eyeball is another frame's (:attr:`source`): :attr:`image` then
        differs from the reference frame's eye even where no gaze moves it."""
        return self.source is not None

    def shift(self, angles: np.ndarray) -> np.ndarray:
        """``(2, 2)`` pixels, ``[eye, (x, y)]``: where gaze ``angles`` (2, 2) puts each iris in
        the reference frame, minus where its own gaze does (:attr:`iris`), at most
        :attr:`limit` long; a photo's (:attr:`room`) along its eye no farther than the sclera
        it shows, and both eyes held where either opening shows no eye."""
        d = _project(self.eyes, angles, self.pose) - self.iris
        n = np.linalg.norm(d, axis=1)
        scale = np.where(n > self.limit, self.limit / np.maximum(n, 1e-12), 1.0)
        d = d * scale[:, None]
        if self.room is not None:        # a photo: no farther than the sclera it shows
            axis, room = self.room[:, :2], self.room[:, 2:]
            t = (d * axis).sum(axis=1)
            d = d + (np.clip(t, -room[:, 1], room[:, 0]) - t)[:, None] * axis
            if not (room > 0).any(axis=1).all():   # one eye held holds its fellow (review55c:
                d[:] = 0.0                          # one eye turned, one not, diverged)
        return d


def _project(eyes, angles: np.ndarray, pose: tuple) -> np.ndarray:
    """``(2, 2)``: :func:`facetransfer.track.gaze.project_iris` of one frame, pose ``(R, s, t,
    pixel aspect)`` (columns ``t_x + (x - t_x) / aspect``: :mod:`facetransfer.track.aspect`)."""
    R, s, t, aspect = pose
    p = project_iris(eyes, np.asarray(angles, np.float64)[None], R[None], np.array([s]),
                     t[None])[0]
    if aspect != 1.0:
        p[:, 0] = t[0] + (p[:, 0] - t[0]) / aspect
    return p


def track_gaze(track) -> np.ndarray | None:
    """``(F, 2, 2)`` gaze angles of a track's eyeLook* activations
    (:func:`facetransfer.track.gaze.activation_gaze`), or None without ARKit blendshapes."""
    from .arkit import ARKIT_NAMES

    b, names = track.blendshapes, track.blendshape_names
    if b is None or names is None or tuple(names) != tuple(ARKIT_NAMES):
        return None
    return activation_gaze(np.asarray(b, np.float64))


def gaze_offset(track) -> np.ndarray | None:
    """``(F,)``: how far each frame's eyes look from straight ahead (the head's +z), the mean
    over the two eyes of :func:`eye_offsets`, 0 where unknown; None without ARKit
    blendshapes. An eye looking ahead has its iris amid its opening: shifted to any other
    gaze, it uncovers the least of the eyeball its frame hides (:func:`extend_eyeballs`)."""
    off = eye_offsets(track)
    return None if off is None else np.nan_to_num(off.mean(axis=1), nan=0.0)


def eye_offsets(track) -> np.ndarray | None:
    """``(F, 2)``: each eye's (right, left) gaze off straight ahead in each frame,
    ``hypot(yaw / horizontal, pitch / vertical)`` of :func:`track_gaze`
    (:class:`facetransfer.track.gaze.GazeOptions`: an eyeLook* activation of 1 is 1), NaN
    where unknown; None without ARKit blendshapes."""
    g = track_gaze(track)
    if g is None:
        return None
    opt = GazeOptions()
    return np.hypot(g[..., 0] / opt.horizontal, g[..., 1] / opt.vertical)


#: :func:`eyeball_frames`: an eye takes another frame's eyeball where that frame's eye looks
#: nearer ahead than the reference frame's by at least this (:func:`eye_offsets`; 1 = an
#: eyeLook* of 1), its view's degrees counted in (:data:`EYEBALL_ANGLE`) ...
EYEBALL_GAIN = 0.1
#: ... its head turned at most this many degrees from the reference frame's (the eyeball is
#: lifted through the two frames' poses: a sphere seen from another side shows another part)
EYEBALL_VIEW = 8.0
#: ... each degree of that turn counting as this much gaze off ahead.
EYEBALL_ANGLE = 0.01
#: :func:`eyeballs_of` takes an eye's eyeball from another frame (:func:`eyeball_frames`) where
#: it is given the clip's frames. Off by measurement: on the judge (BENCHMARKS.md, "Fifty-third
#: session (helper eyeball53)") it gained the demo's blinks (0.84/0.73 -> 0.86/0.77), brows
#: (0.67 -> 0.70) and horizontal gaze (demo 0.82 -> 0.83, fps 0.26 -> 0.32) but lost the demo's
#: vertical gaze 0.41 -> 0.38; the brief's floor is 0.02. The tests set it.
LIFT = False
#: :func:`_lift_eyes`: another frame's eyeball is continued under its lids this much farther
#: (a fraction of its eye's width) than :data:`GROW`, so that it covers the reference frame's
#: grown opening where the two openings differ.
LIFT_GROW = 0.3


def eyeball_frames(track, reference: int, n_frames: int | None = None) -> np.ndarray:
    """``(2,) int64``: per eye (right, left), the frame whose eyeball the eye region textured
    from frame ``reference`` shows: ``reference``, or the frame (of the first ``n_frames``,
    the face not lost, the eye region inside the picture:
    :func:`facetransfer.region_weights.seen_frames`) whose eye is as open as the clip's
    median or more (its eyeBlink), its head within :data:`EYEBALL_VIEW` of the reference's,
    and looks most nearly ahead (:func:`eye_offsets`, plus :data:`EYEBALL_ANGLE` per degree of
    view), where that is :data:`EYEBALL_GAIN` nearer than the reference frame's eye. Both
    ``reference`` where the track has no eyeLook* activations."""
    from .arkit import ARKIT_NAMES
    from .region_weights import EYE_POINTS, seen_frames

    out = np.full(2, int(reference), np.int64)
    off = eye_offsets(track)
    good = seen_frames(track, np.flatnonzero(~np.asarray(track.lost, bool)[:n_frames]),
                       EYE_POINTS)
    if off is None or good.size == 0:
        return out
    R = np.asarray(track.rotation, np.float64)
    c = (np.einsum("fab,ab->f", R[good], R[int(reference)]) - 1.0) / 2.0
    cost = off[good] + EYEBALL_ANGLE * np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))[:, None]
    blink = np.asarray(track.blendshapes, np.float64)[good][
        :, [ARKIT_NAMES.index("eyeBlinkRight"), ARKIT_NAMES.index("eyeBlinkLeft")]]
    ok = (np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))[:, None] <= EYEBALL_VIEW) \
        & (blink <= np.nanmedian(blink, axis=0)) & np.isfinite(cost)
    for e in (0, 1):
        if ok[:, e].any() and np.isfinite(off[int(reference), e]):
            k = int(np.argmin(np.where(ok[:, e], cost[:, e], np.inf)))
            if cost[k, e] <= off[int(reference), e] - EYEBALL_GAIN:
                out[e] = good[k]
    return out


def _lift_eyes(ext: np.ndarray, eye: np.ndarray, image: np.ndarray, V: np.ndarray, track,
               frames: tuple, which: np.ndarray, mesh: tuple, reach: int, models: tuple) -> None:
    """Put, in place, into ``ext`` (H, W, 3) uint8 (the reference frame's extended eyeballs,
    :func:`extend_eyeballs`) within ``reach`` pixels of each eye ``which`` (2,) bool's opening
    (``eye`` (H, W) int8 of :func:`_eye_map`) the eyeball of another frame (``image``
    (H', W', 3) uint8, its mesh ``V``), extended under its own lids (:data:`LIFT_GROW`) and
    mapped from that frame's pixels to the reference frame's (:func:`_eye_affine`).

    ``frames``: ``(reference, other)`` frame numbers of ``track``; ``mesh``: ``(faces,
    fill_eye, lm)`` as :func:`eyeballs_of` has them; ``models``: the two frames' eyeballs
    (:func:`facetransfer.track.gaze.eye_model`, model units)."""
    import cv2

    i, j = frames
    cams = track.camera(i), track.camera(j)
    other, width = _eye_map(V, *mesh[:2], cams[1], image.shape[:2], mesh[2])
    other[~np.isin(other, np.flatnonzero(which))] = -1
    src = extend_eyeballs(image, other >= 0, iris=True,
                          grow=max(int(round((GROW + LIFT_GROW) * width.max())), 2))
    for e in np.flatnonzero(which).tolist():
        near = cv2.distanceTransform((eye != e).view(np.uint8), cv2.DIST_L2, 5) <= reach
        if not near.any() or not (other == e).any():
            continue
        ys, xs = np.nonzero(near)
        y0, x0 = ys.min(), xs.min()
        M = _eye_affine(models, cams, e)          # the other frame's pixels -> the reference's
        M[:, 2] -= (x0, y0)
        box = cv2.warpAffine(src, M, (int(xs.max()) + 1 - x0, int(ys.max()) + 1 - y0),
                             flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        ext[ys, xs] = box[ys - y0, xs - x0]


def _eye_affine(models: tuple, cams: tuple, e: int) -> np.ndarray:
    """``(2, 3)`` float64: the affine map of eye ``e``'s eyeball from the pixels of one frame
    (``models[1]``, ``cams[1]``) to another's (``models[0]``, ``cams[0]``): each frame's
    eyeball (:class:`facetransfer.track.gaze.EyeModel`, centred where that frame's mesh puts
    it) seen by its camera, on the plane through its iris at rest (its radius before its
    centre, the head's +z) spanned by the head's x and y (the weak-perspective image of a
    plane is affine; the eye's corners lie half a radius behind it)."""
    import cv2

    pts = []
    for eyes, cam in zip(models, cams):
        c, r = eyes.centre[e], float(eyes.radius[e])
        front = c + np.array([0.0, 0.0, r])
        pts.append(cam.project(np.stack([front, front + (r, 0.0, 0.0), front + (0.0, r, 0.0)]))
                   .astype(np.float32))
    return cv2.getAffineTransform(pts[1], pts[0]).astype(np.float64)


def extend_eyeballs(image: np.ndarray, opening: np.ndarray, *, grow: int,
                    rim: int = RIM, iris: bool = False) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with each pixel within ``grow`` pixels of ``opening`` (H, W)
    bool (the eyes' openings), and of the opening's own outer ``rim`` pixels, taking the colour
    of the nearest pixel of the rest of the opening: the eyeball continued under the lids (the
    sclera beyond the corners, the iris above and below).

    A pixel beyond the iris's extent along its eye's long axis whose nearest pixel is the iris
    (:func:`_iris_pixels`: an eye turned into its corner) takes the colour of its nearest pixel
    of the eye's sclera instead: the eyeball beyond the iris is sclera. Before, the iris was
    continued there, and an eye turned back from that corner showed it as a dark grey blob over
    that half of the eye (walk52: ``transfer --target orig.mp4 --expression-from face_2.mp4
    --max-frames 30``, whose reference frame's left eye looks fully in). The nearest sclera,
    not one colour for the eye (review52d): an eye with its sclera lit on one side of the iris
    and in shade on the other had the shaded side's hidden part filled with the lit side's
    colour, a light stripe with a hard edge beside the shaded sclera (``make demo``'s pair,
    frame 29). What is continued beside that sclera (the iris above and below the iris, the
    lid margins) passes into it over :data:`SOFT` of the iris's length (eyeref53: a step
    there read as a straight cut, ``make demo``'s frame 40).

    With ``iris`` (eyeball53: another frame's eyeball, :func:`_lift_eyes`; off for the
    reference frame's own, as before), the eyeball of an eye with an iris is continued as an
    eyeball: a hidden pixel over or under the iris (within its extent along the eye) whose
    nearest pixel is the iris or a catchlight in it takes its nearest pixel of the iris's dark
    part (a catchlight on the opening's rim, where the track puts it, was drawn out into a
    bar across the lid), and every hidden pixel beyond the iris its nearest sclera's, as
    beyond an iris in its corner (the lid margins and the corners' shade were continued into
    a flat grey wedge where an iris turned far away from them uncovers it)."""
    import cv2

    core = cv2.erode(opening.view(np.uint8), np.ones((3, 3), np.uint8), iterations=rim) \
        if rim > 0 else opening.view(np.uint8)
    out = np.array(image, copy=True)
    if not core.any():
        return out
    ys, xs, src = _nearest(core, grow + rim)
    iris_px, eye, axes, span, sclera = _iris_pixels(image, core)
    k = eye[src[:, 0], src[:, 1]]                       # each source's eye
    p = xs * axes[k, 0] + ys * axes[k, 1]                # the pixel's place along its long axis
    beyond = (p < span[k, 0]) | (p > span[k, 1])
    side = (iris_px[src[:, 0], src[:, 1]] | (iris & np.isfinite(span[k, 0]))) & beyond
    out[ys, xs] = image[src[:, 0], src[:, 1]]
    if iris and iris_px.any():
        near = cv2.dilate(iris_px.view(np.uint8), np.ones((5, 5), np.uint8)) > 0
        over = near[src[:, 0], src[:, 1]] & (p >= span[k, 0]) & (p <= span[k, 1])
        at = _nearest_to(iris_px, ys[over], xs[over])
        out[ys[over], xs[over]] = image[at[:, 0], at[:, 1]]
    w = _toward_sclera(side, ys, xs, SOFT * (span[k, 1] - span[k, 0]), image.shape[:2])
    mix = w > 0
    if mix.any():
        at = _nearest_to(sclera, ys[mix], xs[mix])
        a = w[mix, None]
        out[ys[mix], xs[mix]] = np.rint((1.0 - a) * out[ys[mix], xs[mix]]
                                        + a * image[at[:, 0], at[:, 1]]).astype(np.uint8)
    return out


def _toward_sclera(side: np.ndarray, ys: np.ndarray, xs: np.ndarray, width: np.ndarray,
                   shape: tuple) -> np.ndarray:
    """``(m,)`` in [0, 1]: how much of the sclera each hidden pixel ``(ys, xs)`` takes: 1 on
    ``side`` (m,) bool (beyond the iris), falling to 0 at ``width`` (m,) pixels (its eye's)
    from the nearest of them (eyeref53: the step between the sclera beyond the iris and the
    iris or lid margin continued beside it showed as a straight cut, ``make demo``'s frame
    40); 0 everywhere without ``side`` (nothing changes)."""
    import cv2

    if not side.any():
        return side.astype(np.float64)
    free = np.ones(shape, np.uint8)
    free[ys[side], xs[side]] = 0
    d = cv2.distanceTransform(free, cv2.DIST_L2, 5)[ys, xs]
    return np.clip(1.0 - d / np.maximum(np.nan_to_num(width, neginf=0.0), 1e-9), 0.0, 1.0)


def _nearest_to(mask: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """``(m, 2)`` (row, column): the nearest ``mask`` (H, W) bool pixel to each of the pixels
    ``(ys, xs)``, as :func:`_nearest` finds them."""
    import cv2

    _, label = cv2.distanceTransformWithLabels((~mask).view(np.uint8), cv2.DIST_L2, 5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    return np.argwhere(mask)[label[ys, xs] - 1]


#: :func:`_iris_pixels`: an eye's opening holds an iris where its luma's 10th percentile is
#: below this share of its 90th (an iris against the sclera: 0.3 in walk52's ``orig.mp4``; a
#: closed or featureless opening is near 1: nothing changes).
IRIS_CONTRAST = 0.7
#: ... its iris is darker than this share of the way from that 10th percentile to the 90th
#: (the iris 0-0.2 in walk52's ``orig.mp4`` and ``make demo``'s target, the sclera in the
#: shade of a corner 0.4-0.7: a share of 0.5 took that shade for the iris).
IRIS_LEVEL = 0.3
#: :func:`_iris_pixels`: the sclera is read on the eye's middle band, within this share of
#: its half-height (twice its pixels' standard deviation across its long axis) of its middle.
BAND = 0.5
#: :func:`_iris_pixels`: a part of an opening has a long axis where its pixels' variance along
#: it is at least this many times that across it (its length 1.7 times its height; an eye
#: open wide, its corners to its lids, is 2-3 times. Review52d: a part about as tall as wide, an
#: eye nearly closed or a piece of one, had its axis put upright by chance, and the eyeball
#: above its iris, under the lid, was made sclera: a white cap over the iris). Without one
#: the part is filled from its nearest pixels, as an eye without an iris is.
ELONGATION = 3.0
#: :func:`_toward_sclera`: the fill passes from the sclera beyond an iris to what is continued
#: beside it (the iris above and below it, the lid margins) over this share of the iris's
#: length along its eye.
SOFT = 0.3


def _nearest(core: np.ndarray, reach: float):
    """``(ys, xs, src)``: the pixels within ``reach`` of ``core`` (H, W) uint8 (not in it) and
    each one's nearest core pixel ``(m, 2)`` (row, column): distanceTransform's labels of the
    zero pixels (the core, one label each, numbered in row-major order)."""
    import cv2

    dist, label = cv2.distanceTransformWithLabels((core == 0).view(np.uint8), cv2.DIST_L2, 5,
                                                  labelType=cv2.DIST_LABEL_PIXEL)
    ring = (dist > 0) & (dist <= reach)
    ys, xs = np.nonzero(ring)
    return ys, xs, np.argwhere(core != 0)[label[ys, xs] - 1]


def _iris_pixels(image: np.ndarray, core: np.ndarray):
    """``(iris, eye, axes, span, sclera)``: per connected part of ``core`` (H, W) uint8 (an
    eye's opening), its iris: the largest connected part of its dark pixels (luma under
    :data:`IRIS_LEVEL` of the way from its 10th percentile to its 90th, where the 10th is
    under :data:`IRIS_CONTRAST` of the 90th), (H, W) bool; the part of each pixel (H, W) int32
    (0 outside); each part's long axis ``(k + 1, 2)`` (x, y) unit vectors (its pixels'
    principal direction; row 0 unused; a part not :data:`ELONGATION` long has none, nor an
    iris); its iris's extent along that axis ``(k + 1, 2)`` (an empty one without an iris or
    sclera); and its sclera (H, W) bool, its pixels above the midpoint on its middle band
    (:data:`BAND`: not the lids' grey margins) beside the iris (not the catchlights in it), of
    the eyes with an iris."""
    import cv2

    n, eye = cv2.connectedComponents(core, connectivity=8)
    luma = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    iris, sclera = np.zeros(core.shape, bool), np.zeros(core.shape, bool)
    axes = np.tile(np.array([1.0, 0.0]), (n, 1))
    span = np.tile(np.array([np.inf, -np.inf]), (n, 1))
    for k in range(1, n):
        yy, xx = np.nonzero(eye == k)
        across = np.zeros(len(xx))
        if len(xx) > 2:
            w, vec = np.linalg.eigh(np.cov(np.stack([xx, yy]).astype(np.float64)))
            if w.max() < ELONGATION * w.min():
                continue
            axes[k] = vec[:, int(np.argmax(w))]
            across = ((yy - yy.mean()) * axes[k, 0] - (xx - xx.mean()) * axes[k, 1]) \
                / max(2.0 * np.sqrt(max(w.min(), 0.0)), 1e-9)
        v = luma[yy, xx].astype(np.float64)
        lo, hi = np.percentile(v, [10, 90])
        if not lo < IRIS_CONTRAST * hi:
            continue
        low = v < lo + IRIS_LEVEL * (hi - lo)
        dark = np.zeros(core.shape, np.uint8)
        dark[yy[low], xx[low]] = 1
        _, parts, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=8)
        big = parts == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        iy, ix = np.nonzero(big)
        along = ix * axes[k, 0] + iy * axes[k, 1]
        p = xx * axes[k, 0] + yy * axes[k, 1]    # the sclera: beside the iris (no catchlight)
        mid = (v >= 0.5 * (lo + hi)) & (np.abs(across) <= BAND) \
            & ((p < along.min()) | (p > along.max()))
        if mid.any():
            iris |= big
            span[k] = along.min(), along.max()
            sclera[yy[mid], xx[mid]] = True
    return iris, eye, axes, span, sclera


def eyeballs_of(image: np.ndarray, track, i: int, model, faces: np.ndarray, V: np.ndarray,
                fill_eye: np.ndarray, *, frames=None, n_frames: int | None = None,
                topo=None) -> Eyeballs | None:
    """The eyeballs of the target's frame ``i`` (``image``), or None where the track has no
    eyeLook* activations.

    With the clip's ``frames`` and :data:`LIFT`, an eye of frame ``i`` looking aside shows
    the eyeball of a frame of the clip looking nearer ahead (:func:`eyeball_frames`), lifted
    into frame ``i`` (:func:`_lift_eyes`): the lids and brows stay frame ``i``'s, and turned
    to another gaze the eyeball uncovers little that its frame hides (before, the iris of an
    eye looking hard into its corner was turned back across a sclera filled beyond it:
    ``make demo``'s wedge in frames 33-85).

    Parameters
    ----------
    image : (H, W, 3) uint8
    track : Track
        The target's (ARKit blendshapes).
    i : int
    model : MultilinearModel
    faces : (F', 3) int
        The eye-closed topology.
    V : (n_closed, 3)
        The target's mesh in frame ``i`` (model coordinates, eyes and mouth closed).
    fill_eye : (F',) int8
        Per triangle of the eye-closed topology, the eye (0 right, 1 left) whose opening a
        fill triangle closes; -1 for the others.
    frames : sequence of (H, W, 3) uint8, optional
        The target's frames (of the first ``n_frames``) to take the eyeballs from.
    topo : MeshTopology, optional
        The eye-closed topology, for the other frames' meshes (with ``frames``).
    """
    gaze = track_gaze(track)
    if gaze is None or model.landmarks is None or not (fill_eye >= 0).any():
        return None
    lm = np.asarray(model.landmarks, np.int64)
    eyes = eye_model(V[lm])
    eye, width = _eye_map(V, faces, fill_eye, track.camera(i), image.shape[:2], lm)
    grow = max(int(round(GROW * width.max())), 2)
    rim = _rim(width)                  # the rim grows with the eye
    ext = extend_eyeballs(image, eye >= 0, grow=grow, rim=rim)
    pose = (np.asarray(track.rotation[i], np.float64), float(track.scale[i]),
            np.asarray(track.translation[i], np.float64), float(track.pixel_aspect))
    angles, source = gaze[i], None
    src = eyeball_frames(track, i, n_frames) if frames is not None and LIFT \
        else np.full(2, i)
    for j in np.unique(src[src != i]).tolist():
        angles, source = np.array(angles, copy=True), src
        Vj = close_mouth(model.synthesize(track.weights_at(j)), topo)
        _lift_eyes(ext, eye, np.asarray(frames[j]), Vj, track, (i, j), src == j,
                   (faces, fill_eye, lm), grow + rim + 2, (eyes, eye_model(Vj[lm])))
        angles[src == j] = gaze[j][src == j]
    if source is not None:
        n0 = track_first_number(track)  # a plate's frames by their numbers
        log.info("eyes: the eyeballs of target frame %d from frames %d (right), %d (left)",
                 n0 + i, *(n0 + k for k in source.tolist()))
    photo = _held(frames)              # a photo: no other eyeball, nor its own hidden sclera
    return Eyeballs(ext, eyes, angles, pose, LIMIT * width,
                    np.concatenate([np.array([-1], np.int8), np.asarray(fill_eye, np.int8)]),
                    _project(eyes, angles, pose), source,
                    eye_room(image, eye, width) if photo else None)


#: :func:`eye_room`: an opening of which this share or more is the colour of the skin about it
#: (nearer than :data:`SKIN_DISTANCE` to its median) does not show an eye (a photo's track put
#: it on a lid or the nose: ``stills/breakingbad.jpg``'s left face's right eye 0.47, the right
#: face's two 0.42; the eyes 0.07-0.19, at any exposure and in grey: BENCHMARKS.md
#: "Fifty-fifth session (helper eyeroom55)").
SKIN_SHARE = 0.3
#: ... a CIELAB distance (OpenCV's 8-bit Lab) in units of the skin's own spread (the median
#: distance of its pixels from their median, at least :data:`SKIN_SPREAD_MIN`): a picture
#: darker, or grey, has its colours nearer, and the skin's spread shrinks with them (eyeroom55:
#: a fixed distance of 15 read breakingbad at 0.4 times its brightness as all skin), ...
SKIN_DISTANCE = 1.0
#: ... the spread no less than this (a skin of one flat colour, a synthetic picture's), ...
SKIN_SPREAD_MIN = 2.0
#: :func:`eye_room`: an eye narrower than this (pixels, corner to corner) has no room: its iris
#: a few pixels, its sclera one or two, too few to tell them from the lids' shade (eyeroom55:
#: ``einstein.jpg``'s eyes, 12-15 px, and ``takeo.ppm``'s, 16-17 px, once the skin test let
#: them move, showed a white block beside the iris and a flat grey block in the inner corner;
#: ``breakingbad.jpg``'s are 41-65 px).
EYE_MIN_WIDTH = 24.0
#: ... the skin about an opening being its eye's pixels this far outside it (shares of its
#: eye's width), in no opening.
SKIN_RING = (0.15, 0.4)


def eye_room(image: np.ndarray, eye: np.ndarray, width: np.ndarray) -> np.ndarray:
    """``(2, 4)`` float64, :attr:`Eyeballs.room`: per eye (right, left) of ``image`` (H, W, 3)
    uint8, its openings ``eye`` (H, W) int8 (:func:`_eye_map`, widths ``width`` (2,) pixels),
    the long axis (x, y) of its opening and the sclera the picture shows beyond its iris
    (:func:`_iris_pixels`; not the skin's colour, :func:`_skin_like`) behind it, then ahead
    of it along that axis, in pixels: how far a move forward, then backward, may take the
    iris before it uncovers what the picture never showed. An eye whose opening shows no iris
    beside sclera, or is :data:`SKIN_SHARE` skin or more (at any exposure, in colour or grey:
    :func:`_skin_like`), or is narrower than :data:`EYE_MIN_WIDTH`, has no room.

    The iris and the sclera are found inside each opening's rim grown with its eye, as
    :func:`eyeballs_of` grows the rim it redoes (:func:`_rim` of the eye's own width: a turned
    head's far eye keeps the 1 px of an eye its size): before (review55c), inside :data:`RIM`
    alone, a larger eye's lashes left there joined an iris touching the lids into one dark
    part spanning the eye, and the eye had no room."""
    import cv2

    out = np.zeros((2, 4))
    out[:, 0] = 1.0
    core = np.zeros(eye.shape, np.uint8)
    for e in (0, 1):
        core |= cv2.erode((eye == e).view(np.uint8), np.ones((3, 3), np.uint8),
                          iterations=_rim(width[e]))
    iris, part, axes, span, sclera = _iris_pixels(image, core)
    lab = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2LAB).astype(np.float64)
    for e in (0, 1):
        m = eye == e
        count = np.bincount(part[m], minlength=2)[1:]    # the part of the opening's core
        k = int(count.argmax()) + 1 if count.max() > 0 else 0
        if k == 0 or not np.isfinite(span[k, 0]) or width[e] < EYE_MIN_WIDTH:
            continue                     # no iris beside sclera (or too small to tell)
        skin = _skin_like(lab, m, eye, float(width[e]))
        if skin[m].mean() >= SKIN_SHARE:
            continue
        ys, xs = np.nonzero(sclera & (part == k) & ~skin)
        if xs.size == 0:
            continue
        p = xs * axes[k, 0] + ys * axes[k, 1]
        out[e] = (*axes[k], max(span[k, 0] - p.min(), 0.0), max(p.max() - span[k, 1], 0.0))
    return out


def _skin_like(lab: np.ndarray, m: np.ndarray, eye: np.ndarray, width: float) -> np.ndarray:
    """``(H, W)`` bool: the pixels of the opening ``m`` (H, W) bool whose colour (``lab``
    (H, W, 3) float64, OpenCV's 8-bit CIELAB) lies within :data:`SKIN_DISTANCE` times the
    skin's spread of the median of the skin about it (:data:`SKIN_RING` of the eye's
    ``width`` pixels outside it, in no opening of ``eye`` (H, W) int8)."""
    import cv2

    d = cv2.distanceTransform((~m).view(np.uint8), cv2.DIST_L2, 5)
    ring = (d > SKIN_RING[0] * width) & (d < SKIN_RING[1] * width) & (eye < 0)
    out = np.zeros(m.shape, bool)
    if ring.any():
        skin = np.median(lab[ring], axis=0)
        spread = max(float(np.median(np.linalg.norm(lab[ring] - skin, axis=1))),
                     SKIN_SPREAD_MIN)
        out[m] = np.linalg.norm(lab[m] - skin, axis=1) < SKIN_DISTANCE * spread
    return out


def _rim(width: np.ndarray) -> int:
    """The openings' rim in pixels for eyes ``width`` pixels wide (one, or each eye's): what
    :func:`eyeballs_of` redoes (of the wider eye) and :func:`eye_room` measures inside (of
    each eye): :data:`RIM_WIDTH` of the width, rounded, at least :data:`RIM`."""
    return max(RIM, int(round(float(np.max(width)) / RIM_WIDTH)))


def _held(frames) -> bool:
    """Whether ``frames`` are one picture held (a photo as the target,
    :func:`facetransfer.transfer_plan.held_frames`: a read-only view of its one frame), or one
    frame (any: a one-frame plate, ``--max-frames 1``, ``transfer --frame 0`` of a video, a
    one-frame shot; none has another frame's eyeball to take)."""
    return isinstance(frames, np.ndarray) and frames.ndim == 4 \
        and (len(frames) == 1 or frames.strides[0] == 0)


def _eye_map(V: np.ndarray, faces: np.ndarray, fill_eye: np.ndarray, cam, shape: tuple,
             lm: np.ndarray):
    """``(eye, width)``: per pixel of a frame of ``shape`` (H, W) the eye (0 right, 1 left)
    whose opening (a fill triangle of ``fill_eye``) the mesh ``V`` seen by ``cam`` shows
    there, -1 elsewhere, (H, W) int8; each eye's width (corner to corner, iBUG 36-39, 42-45
    of the landmark vertices ``lm``) in pixels, (2,)."""
    from .render import rasterize

    px = cam.project(V[lm[[36, 39, 42, 45]]])
    width = np.array([np.linalg.norm(px[0] - px[1]), np.linalg.norm(px[2] - px[3])])
    tid = rasterize(V, faces, cam, (shape[1], shape[0])).tri_id
    return np.where(tid >= 0, fill_eye[np.maximum(tid, 0)], -1).astype(np.int8), width


def shift_eyeballs(eye_img: np.ndarray, tri_id: np.ndarray, bary: np.ndarray, faces: np.ndarray,
                   uvs: np.ndarray, eyeballs: Eyeballs, shift: np.ndarray) -> None:
    """Resample, in place, the pixels of ``eye_img`` (h, w, 3) uint8 that show a fill triangle
    (``tri_id`` (h, w), ``bary`` (h, w, 3) of the raster over the same pixels) from
    :attr:`Eyeballs.image` moved by ``shift`` (2, 2) pixels per eye (:meth:`Eyeballs.shift`):
    a pixel whose surface point the reference frame sees at ``q`` shows what it has at
    ``q - shift``. ``uvs`` (n, 2): the reference frame's texture coordinates
    (:func:`facetransfer.texture.face.frame_uvs`). The fill's pixels and where they read are
    found in one pass over the region's box (:func:`_fill_kernel`), the reads are OpenCV's
    bilinear ``remap`` (at most :data:`REMAP_CHUNK` at a time)."""
    import cv2

    h, w = tri_id.shape
    ys, xs = np.empty(h * w, np.int64), np.empty(h * w, np.int64)
    mx, my = np.empty(h * w, np.float32), np.empty(h * w, np.float32)
    H, W = eyeballs.image.shape[:2]
    n = _fill_kernel(eyeballs.lookup, tri_id, bary, np.asarray(faces, np.int64),
                     np.ascontiguousarray(uvs, np.float64),
                     np.ascontiguousarray(shift, np.float64), float(W - 1), float(H - 1),
                     ys, xs, mx, my)
    if n == 0:
        return
    vals = np.empty((n, 3), np.uint8)
    for i in range(0, n, REMAP_CHUNK):
        j = min(i + REMAP_CHUNK, n)
        vals[i:j] = cv2.remap(eyeballs.image, mx[None, i:j], my[None, i:j], cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)[0]
    _scatter_kernel(ys[:n], xs[:n], vals, eye_img)


#: The most pixels :func:`shift_eyeballs` reads in one ``cv2.remap`` (whose maps must have
#: fewer than ``SHRT_MAX`` = 32767 columns).
REMAP_CHUNK = 32000


def _fill_kernel_py(lookup, tri_id, bary, faces, uvs, shift, wm1, hm1, ys, xs, mx,
                    my):  # pragma: no cover (numba)
    """The pixels of ``tri_id`` (h, w) whose triangle closes an eye (``lookup[tri_id + 1] >=
    0``), in row-major order, into ``ys``, ``xs``; where each reads the reference image
    (:func:`shift_eyeballs`): its surface point's uv (the ``bary``-weighted sum of its
    corners' ``uvs``, in float64 and in order, as ``numpy.einsum`` sums it) less its eye's
    ``shift``, in pixels ``(u wm1 - dx, (1 - v) hm1 - dy)`` cast to float32, into ``mx``,
    ``my``. Returns how many."""
    n = 0
    for y in range(tri_id.shape[0]):
        for x in range(tri_id.shape[1]):
            t = tri_id[y, x]
            e = lookup[t + 1]
            if e < 0:
                continue
            u = v = 0.0
            for k in range(3):
                b = np.float64(bary[y, x, k])
                u += b * uvs[faces[t, k], 0]
                v += b * uvs[faces[t, k], 1]
            ys[n], xs[n] = y, x
            mx[n] = np.float32(u * wm1 - shift[e, 0])
            my[n] = np.float32((1.0 - v) * hm1 - shift[e, 1])
            n += 1
    return n


def _scatter_kernel_py(ys, xs, vals, img):  # pragma: no cover (numba)
    """``img[ys, xs] = vals`` (``vals`` (n, 3) uint8; ``img`` (h, w, 3), in place)."""
    for i in range(ys.shape[0]):
        for c in range(3):
            img[ys[i], xs[i], c] = vals[i, c]


_fill_kernel = _maybe_njit(_fill_kernel_py)
_scatter_kernel = _maybe_njit(_scatter_kernel_py)

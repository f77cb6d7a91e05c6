"""The target's lip colour on the source's mouth.

The rewrite textures the mouth, lips included, from the mouth's source (§6: "the mouth texture
from the source video"; :mod:`facetransfer.mouth`) and scales it to the face's colours by a
gain fitted on the skin around it. That gain maps the source's skin onto the target's, so the
lips keep the source's colour relative to its skin: on ``make demo``'s pair the target's red
lipstick became the source's pale lips, a part of the source's identity in the result.

Lip colour is a property of the person (the lips' tint against the skin beside them), not of the
expression. So, per clip:

1. the lips are the vertices inside the outer lip contour (iBUG 48-59) of the model's mean face,
   seen from the front, fading out over a band around it (:func:`lip_vertex_weights`);
2. in a few frames spread through each clip the colour of the lips' middle band (away from
   the mouth's opening, where teeth or the gap may show) and of the skin ring around the
   mouth is read through the clip's tracked geometry, as the texture is; their per-channel
   ratio, the median over frames, is the clip's lip tint (:func:`lip_ratio`);
3. the source's mouth texture is multiplied, per channel and weighted by the lips' weight at
   each pixel, by the target's tint over the source's (:func:`tint_mouth`), before the gain
   to the face's colours; onto paler lips each pixel only as far as the source's skin
   colour along the tint's hue (:func:`tint_reach`: a red lipstick's highlights and the
   skin the lips' band covers keep their colour); there, too, the tinted lips are brought to
   the target's lip colour in CIELAB (:func:`recolour_lips`): a deep lipstick's colour is
   not a hue a per-channel factor can reach (the upper lip stayed red), so each pixel's
   ``L, a, b`` keep only a share of their distance from the target's lip colour, the
   target's lips' spread over the source's, squared (:func:`lab_spread`). The skin, the
   teeth and the mouth's inside are not touched. How far each pixel takes the tint is
   measured from the source's lip colour of the clip, not of the frame: lips pressed shut,
   deeper than the clip's, left a third of their lipstick untinted, red.

The same person's clip on both sides gives a tint of 1 up to noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .composite import mask_box
from .errors import ShapeError
from .render import interpolate_vertex_values, sample_texture
from .jit import maybe_njit as _maybe_njit
from .topology import MeshTopology, _face_size, inside_polygon

__all__ = ["LIP_LEVELS", "TINT_RANGE", "KEEP_MIN", "KEEP_SAME", "FLAT", "CHROMA_RAMP", "LipColour",
           "LipTint", "lip_vertex_weights", "lip_ratio", "lab_spread", "tint_mouth",
           "tint_reach", "recolour_lips", "rgb_to_lab", "skin_ahead"]

#: The outer lip contour's scales about its centre at which a vertex's weight steps down:
#: inside the first scale 1, beyond the last 0 (the mouth's region reaches 1.1).
LIP_LEVELS = (0.9, 0.97, 1.04)
#: The inner lip contour (iBUG 60-67) grown by this about its centre: vertices inside it are
#: not read for the lips' colour (the opening, teeth and gap may show there).
INNER_GROWTH = 1.35
#: Per-channel tints allowed (two people's lips against their skin).
TINT_RANGE = (0.5, 2.0)
#: Frames read per clip for its lips' colour.
SAMPLES = 24
#: The least share of its CIELAB distance from the target's lip colour a lip pixel keeps
#: (:func:`recolour_lips`; the share is the target's lips' spread over the source's, squared).
KEEP_MIN = 0.1
#: A pixel's CIELAB chroma over which :func:`recolour_lips` ramps its move in: none below the
#: first, all above the second (the mouth's dark inside, grey, stays).
CHROMA_RAMP = (8.0, 20.0)
#: A ``keep`` above this is taken as 1 (the lips' spreads alike): one clip read as the target
#: and as the source, through the two textures, gave (1, 0.987, 0.933), and ``driving_d9``
#: onto ``face_2`` (1, 0.93, 1).
KEEP_SAME = 0.85
#: A source's lips' spread (CIELAB) under which they are of one colour: ``keep`` 1 there.
FLAT = 0.01


@dataclass(frozen=True)
class LipColour:
    """A clip's lips against its skin (:func:`lip_ratio`).

    Attributes
    ----------
    ratio : (3,) float64
        The lips' colour over the skin's (RGB, ``c + 1``), the median over the frames read.
    skin : (3,) float64
        The skin's colour (RGB levels), the median over the frames read.
    samples : (k, 3) float32
        Each lip vertex's colour over its frame's skin (``c + 1``), all frames' pooled.
    frame : (k,) int64
        The frame (0, 1, ...) of each sample.
    """

    ratio: np.ndarray
    skin: np.ndarray
    samples: np.ndarray
    frame: np.ndarray


@dataclass(frozen=True)
class LipTint:
    """The lips' per-vertex weight and the per-channel tint from the source's lips to the
    target's.

    Attributes
    ----------
    weights : (n_closed,) float32
        1 on the lips, 0 off them (:func:`lip_vertex_weights`).
    tint : (3,) float64
        Multiplies the source's lips (RGB): the target's lip-to-skin ratio over the source's.
    target_ratio, source_ratio : (3,) float64
        Each clip's lip-to-skin ratio (:func:`lip_ratio`).
    target_lab : (3,) float64 or None
        The target's lip colour on the source's skin in CIELAB (OpenCV, L 0..100): the
        target's ``ratio`` times the source's skin (:func:`recolour_lips`).
    keep : (3,) float64 or None
        The share of ``L, a, b``'s distance from ``target_lab`` a lip pixel keeps: the target's
        lips' spread over the source's (:func:`lab_spread`, both on the source's skin),
        squared, in ``[KEEP_MIN, 1]``, 1 above :data:`KEEP_SAME` (:func:`_keep`). None (and
        ``target_lab`` None) without the clips' samples: the tint alone.
    source_lips : (3,) float64 or None
        The source's lip colour, ``log(c + 1)`` of its ``ratio`` times its skin (the clip's):
        where :func:`tint_reach` places the source's lip colour; None (the tint from the
        ratios alone): each frame's lips' median.
    """

    weights: np.ndarray
    tint: np.ndarray
    target_ratio: np.ndarray
    source_ratio: np.ndarray
    target_lab: np.ndarray | None = None
    keep: np.ndarray | None = None
    source_lips: np.ndarray | None = None

    @classmethod
    def of(cls, weights: np.ndarray, target: "LipColour | np.ndarray",
           source: "LipColour | np.ndarray") -> "LipTint":
        """From the two clips' :func:`lip_ratio` (or their ratios (3,) alone: the tint
        alone), the tint clipped to :data:`TINT_RANGE`."""
        tr, sr = (np.asarray(getattr(r, "ratio", r), np.float64).reshape(3)
                  for r in (target, source))
        tint = np.clip(tr / sr, *TINT_RANGE)
        w = np.asarray(weights, np.float32)
        if isinstance(target, LipColour) and isinstance(source, LipColour):
            lips = np.log(sr * (np.asarray(source.skin, np.float64) + 1.0))
            lips = lips if np.isfinite(lips).all() else None
            st, ss = (lab_spread(c, source.skin) for c in (target, source))
            lab = rgb_to_lab(tr * (source.skin + 1.0) - 1.0)
            if st is not None and ss is not None and np.isfinite(lab).all():
                return cls(w, tint, tr, sr, lab, _keep(st, ss), lips)
            return cls(w, tint, tr, sr, source_lips=lips)
        return cls(w, tint, tr, sr)

    def recolours(self) -> bool:
        """Whether :func:`tint_mouth` brings the lips to ``target_lab``: with the clips'
        samples, a ``keep`` below 1 and the target's lips paler than the source's
        (:func:`skin_ahead` > 0)."""
        return self.target_lab is not None and bool((self.keep < 1.0).any()) \
            and skin_ahead(self) > 0.0

    def grey(self) -> "LipTint":
        """The tint for a monochrome target (:mod:`facetransfer.monochrome`): one factor for
        the three channels, the target's lip-to-skin ratio over the source's in BT.601 luma,
        clipped to :data:`TINT_RANGE` (per channel, a grey target's ratio over a colour
        source's turned red lips cyan)."""
        luma = np.array([0.299, 0.587, 0.114])
        t = float(np.clip((luma @ self.target_ratio) / (luma @ self.source_ratio), *TINT_RANGE))
        return LipTint(self.weights, np.full(3, t), self.target_ratio, self.source_ratio)


def _keep(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    """:attr:`LipTint.keep` of the two clips' :func:`lab_spread` (3,): their ratio squared in
    ``[KEEP_MIN, 1]``, 1 above :data:`KEEP_SAME`, and 1 where the source's lips are of one
    colour (a spread under :data:`FLAT`: nothing to narrow, and 0 over 0 is no ratio) or a
    spread is not a number."""
    with np.errstate(divide="ignore", invalid="ignore"):
        keep = np.clip((target / source) ** 2, KEEP_MIN, 1.0)
    keep[(keep > KEEP_SAME) | ~(source >= FLAT) | ~np.isfinite(keep)] = 1.0
    return keep


def _mean_face_landmarks(model) -> tuple[np.ndarray, np.ndarray]:
    """``(V, lm)``: the mean face (n, 3) and its 68 landmarks (68, 3)."""
    V = model.synthesize(model.default_weights())
    return V, V[np.asarray(model.landmarks)]


def _inside_scaled(poly: np.ndarray, points: np.ndarray, scale: float) -> np.ndarray:
    """(n,) bool: ``points`` (n, 2) inside ``poly`` (k, 2) scaled by ``scale`` about its
    centre."""
    ctr = poly.mean(0)
    return inside_polygon(ctr + scale * (poly - ctr), points)


def lip_vertex_weights(model, topo: MeshTopology) -> tuple[np.ndarray, np.ndarray]:
    """The lips' weight per vertex of the closed mesh, and the vertices to read their colour at.

    Parameters
    ----------
    model : MultilinearModel
        With iBUG-68 landmarks.
    topo : MeshTopology

    Returns
    -------
    weights : (n_closed,) float32
        The fraction of :data:`LIP_LEVELS` at whose scale of the mean face's outer lip contour
        the vertex lies inside (seen from the front, on the face's front); 0 for the mouth's
        centre vertex.
    read : (m,) int64
        Vertices of weight 1 outside the inner lip contour grown by :data:`INNER_GROWTH`.
    """
    if model.landmarks is None:
        raise ShapeError("the model has no landmarks: the lips cannot be found")
    V, lm = _mean_face_landmarks(model)
    outer, inner = lm[48:60, :2], lm[60:68, :2]
    front = V[:, 2] > lm[48:68, 2].min() - 0.25 * _face_size(lm)
    w = np.zeros(topo.n_closed, np.float32)
    for s in LIP_LEVELS:
        w[:len(V)] += (_inside_scaled(outer, V[:, :2], s) & front) / len(LIP_LEVELS)
    read = (w[:len(V)] >= 1.0) & ~_inside_scaled(inner, V[:, :2], INNER_GROWTH)
    return w, np.flatnonzero(read)


def lip_ratio(samples, lips: np.ndarray, skin: np.ndarray) -> "LipColour | None":
    """A clip's lips over its skin, per channel.

    Parameters
    ----------
    samples : iterable of (image (H, W, 3) uint8, uvs (n_closed, 2))
        Frames of the clip and their texture coordinates (v up, :func:`frame_uvs`).
    lips, skin : (m,) int
        The vertices read as lips and as the skin around them.

    Returns
    -------
    LipColour or None
        Its ``ratio`` (3,) the median over frames of the ratio of the median colours (RGB,
        ``c + 1``), its ``skin`` the median over frames of the skin's; None without a frame.
    """
    ratios, skins, pooled = [], [], []
    both = np.concatenate([lips, skin])
    for image, uvs in samples:  # one look-up per frame (it converts the image once)
        c = sample_texture(image, np.asarray(uvs, np.float64)[both])
        a, b = np.median(c[:len(lips)], axis=0), np.median(c[len(lips):], axis=0)
        ratios.append((a + 1.0) / (b + 1.0))
        skins.append(b)
        pooled.append(((c[:len(lips)] + 1.0) / (b + 1.0)).astype(np.float32))
    if not ratios:
        return None
    frame = np.repeat(np.arange(len(pooled)), [len(p) for p in pooled])
    return LipColour(np.median(np.asarray(ratios), axis=0),
                     np.median(np.asarray(skins, np.float64), axis=0),
                     np.concatenate(pooled), frame)


def tint_mouth(mouth_img: np.ndarray, raster, faces: np.ndarray, tint: LipTint,
               mask: np.ndarray) -> None:
    """Multiply the source's lips by the tint, in place, no pixel past the source's skin.

    Each pixel is multiplied per channel by ``1 + w * phi * (tint - 1)``: ``w`` the lips'
    weight there, ``phi`` (:func:`tint_reach`) 1 at the source's lip colour, less for a pixel
    already nearer the target's lip colour than the source's lips are, so that none is moved
    past the source's skin colour along the tint's hue. Onto lips paler than the source's (a
    red lipstick onto pale lips, tint (1.03, 1.60, 1.51)) the whole tint turned what the
    lipstick's band also holds (its white highlights, bared teeth, the skin beyond the
    lipstick where the lips' band reaches over it) cyan-white: G and B above R before the
    mouth's gain (:func:`facetransfer.mouth.blend_mouth`); those now keep their colour and
    take the gain as the skin does. Then, onto paler lips and with the clips' samples
    (``tint.target_lab``), the tinted pixels are brought to the target's lip colour in
    CIELAB by :func:`recolour_lips`, as far as ``w * phi``. Onto lips redder than the
    source's, ``phi`` is 1 and there is no recolouring: the tint as it was.

    Parameters
    ----------
    mouth_img : (H, W, 3) uint8
        The mouth's texture at the raster's pixels.
    raster : Raster
        Of the closed mesh with ``faces``.
    faces : (F, 3) int
    tint : LipTint
    mask : (H, W) bool
        The mouth's pixels (outside it nothing changes).
    """
    box = mask_box(mask, 0)
    if box is None:
        return
    w = interpolate_vertex_values(raster, faces, tint.weights, box)
    w *= mask[box]
    sub = mouth_img[box]
    core = w >= 0.999
    w *= tint_reach(sub, tint, core)
    gain = 1.0 + w[..., None] * (tint.tint.astype(np.float32) - 1.0)
    sub[...] = np.clip(sub * gain + 0.5, 0, 255).astype(np.uint8)
    if tint.recolours() and np.count_nonzero(core) >= MIN_LIP_PIXELS:  # else the whole tint
        recolour_lips(sub, w, tint.target_lab, tint.keep)


def lab_spread(colour: LipColour, skin: np.ndarray) -> np.ndarray | None:
    """The spread of a clip's lips in CIELAB on a given skin colour.

    Each sample (a lip vertex over its frame's skin) times ``skin + 1``, minus 1, is taken to
    CIELAB (:func:`rgb_to_lab`); per frame the spread of ``L, a, b`` over its samples is their
    interquartile range over 1.349 (the standard deviation of a normal distribution, robust
    to a few vertices on the teeth or the skin); the result is its median over frames. Both
    clips put on one (the source's) skin compare lips, not light.

    Parameters
    ----------
    colour : LipColour
    skin : (3,) float
        RGB levels.

    Returns
    -------
    (3,) float64 or None
        None without a frame of 4 samples.
    """
    rgb = colour.samples * (np.asarray(skin, np.float32) + 1.0) - 1.0
    lab = rgb_to_lab(rgb)
    per = []
    for f in np.unique(colour.frame):
        x = lab[colour.frame == f]
        if len(x) >= 4:
            q = np.percentile(x, [25, 75], axis=0)
            per.append((q[1] - q[0]) / 1.349)
    return np.median(np.asarray(per, np.float64), axis=0) if per else None


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (OpenCV's conversion, L 0..100) of RGB levels (..., 3), clipped to 0..255."""
    import cv2

    x = np.clip(np.asarray(rgb, np.float32), 0, 255) / 255.0
    return cv2.cvtColor(x.reshape(-1, 1, 3), cv2.COLOR_RGB2LAB).reshape(x.shape).astype(
        np.float64)


def recolour_lips(image: np.ndarray, w: np.ndarray, target_lab: np.ndarray,
                  keep: np.ndarray) -> None:
    """Bring the tinted lips to the target's lip colour in CIELAB, in place.

    A pixel's ``L, a, b`` become ``target_lab + keep (lab - target_lab)`` where it takes the
    whole move: ``w`` times the ramp of its chroma over :data:`CHROMA_RAMP`, so that the
    mouth's dark inside (and whatever is grey) stays; pixels of ``w`` 0 (a lipstick's
    highlights, teeth, skin: :func:`tint_reach`) are not touched, nor are those the ramp
    leaves where they are (their levels as they were, not through CIELAB and back).

    Parameters
    ----------
    image : (h, w, 3) uint8
        The tinted mouth (RGB).
    w : (h, w) float32
        The share of the tint each pixel took (the lips' weight times :func:`tint_reach`);
        in float64 (or int32), the move is in float64, as numpy's.
    target_lab : (3,) float
        :attr:`LipTint.target_lab`.
    keep : (3,) float
        :attr:`LipTint.keep`.
    """
    import cv2

    moved = w > 0.0
    if not moved.any():
        return
    lab = cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    c0, c1 = CHROMA_RAMP
    go = np.zeros(w.shape, np.uint8)  # the moved pixels' steps in one kernel, and then theirs
    w = np.ascontiguousarray(w, np.result_type(w, np.float32))  # numpy's precision of the move
    _move_lab(lab, w, np.float32(c0), np.float32(c1 - c0), 1.0 - np.asarray(keep, np.float32),
              np.asarray(target_lab, np.float32), go)
    rgb = cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)
    out = np.array(image, copy=True, order="C")  # (the image a crop's view or not: one layout)
    _put_moved(rgb, go, out)
    image[...] = out


def _move_lab_py(lab, w, c0, span, k, t, go):  # pragma: no cover (numba)
    """:func:`recolour_lips`' move of ``lab`` (h, w, 3) float32 in place where ``w`` (h, w)
    float32 (or float64: the move in float64) is above 0: ``ww = w clip((hypot(a, b) - c0) /
    span, 0, 1)`` and ``x += ww k (t - x)`` per channel (``k = 1 - keep``, ``t`` the target's
    colour, (3,) float32), ``go = ww > 0`` (h, w) uint8: the numpy expressions' operations,
    in their order and precision, without the moved pixels gathered and scattered."""
    zero, one = np.float32(0.0), np.float32(1.0)
    for y in range(w.shape[0]):
        for x in range(w.shape[1]):
            if not w[y, x] > zero:
                continue
            r = (np.hypot(lab[y, x, 1], lab[y, x, 2]) - c0) / span
            ww = w[y, x] * min(max(r, zero), one)
            for c in range(3):
                v = lab[y, x, c]
                lab[y, x, c] = v + ww * k[c] * (t[c] - v)
            go[y, x] = ww > zero


def _put_moved_py(rgb, go, image):  # pragma: no cover (numba)
    """``image`` (h, w, 3) uint8 set to ``clip(rgb 255 + 0.5, 0, 255)`` truncated (``rgb``
    (h, w, 3) float32) where ``go`` (h, w) uint8, in place."""
    for y in range(go.shape[0]):
        for x in range(go.shape[1]):
            if go[y, x]:
                for c in range(3):
                    v = rgb[y, x, c] * np.float32(255.0) + np.float32(0.5)
                    image[y, x, c] = np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))


_move_lab = _maybe_njit(_move_lab_py)
_put_moved = _maybe_njit(_put_moved_py)


def _hue_axis(tint: LipTint) -> tuple[np.ndarray, float, float]:
    """``(d, |d|^2, s)`` of :func:`tint_reach`: the tint's hue in log RGB, its squared length
    and the source's skin's place along it (0 without a hue)."""
    d = np.log(np.asarray(tint.tint, np.float64).reshape(3))
    d -= d.mean()
    dd = float(d @ d)
    u = np.log(np.asarray(tint.source_ratio, np.float64).reshape(3))
    return d, dd, (-float((u - u.mean()) @ d) / dd if dd > 1e-8 else 0.0)


def skin_ahead(tint: LipTint) -> float:
    """The source's skin's place along the tint's hue (:func:`tint_reach`'s ``s``): > 0 when
    the target's lips are paler than the source's, nearer the skin's hue."""
    return _hue_axis(tint)[2]


#: Pixels of weight 1 needed to read the source's lip colour in a frame (fewer: the whole tint).
MIN_LIP_PIXELS = 8
#: ``log(c + 1)`` of the 256 levels.
_LOG_LEVELS = np.log1p(np.arange(256, dtype=np.float32))


def tint_reach(image: np.ndarray, tint: LipTint, lips: np.ndarray) -> np.ndarray:
    """The share of the tint each pixel takes: all of it at the source's lip colour and
    beyond, none at the source's skin colour and beyond, along the tint's hue.

    In log RGB (``log(c + 1)``) the tint moves a colour by ``log(tint)``; its hue part ``d =
    log(tint) - mean(log(tint))`` runs from the source's lip colour to the target's (each
    relative to its skin). A pixel's place along it is ``p = <log(c + 1) - m, d> / |d|^2``,
    ``m`` the source's lip colour (``tint.source_lips``, the clip's; without it the median log
    colour of the ``lips`` pixels; shading, the same added to every channel, does not change
    ``p``): 0 at the source's lip colour, 1 at the target's, ``s = -<u, d> / |d|^2`` at the
    source's skin (``u`` the hue part of ``log(source_ratio)``). A frame's own median put the
    lips' colour of a frame whose lips are deeper than the clip's (pressed shut:
    ``WDA_KatieHill_000``'s frames 87-90, 0.9 of ``|d|`` deeper) at 0: a third of the lips,
    the clip's lipstick, then lay towards the skin, took under half of the tint and stayed red.

    When the skin lies ahead (``s > 0``: the target's lips paler than the source's, nearer
    the skin's hue) the pixel takes ``phi = clip(1 - p / max(s, 1), 0, 1)``: the whole tint at
    the source's lip colour and deeper, none at the skin's hue (``s``, or the target's lip
    colour if that lies beyond it) or paler, linearly between, so no pixel goes past it
    (``p + phi <= max(s, 1)``). A red lipstick's white highlight, bared teeth and the skin
    the lips' band reaches over lie there: multiplied by the whole tint they crossed to cyan.
    Otherwise (``s <= 0``: the target's lips redder), for a tint without a hue (a grey one) or
    with fewer than :data:`MIN_LIP_PIXELS` pixels of ``lips``: 1 everywhere, the whole tint.

    Parameters
    ----------
    image : (h, w, 3) uint8
        The source's mouth (RGB).
    tint : LipTint
        Its ``tint`` and ``source_ratio`` (3,) are read.
    lips : (h, w) bool
        The pixels that give the source's lip colour in this image.

    Returns
    -------
    (h, w) float32
        ``phi`` in [0, 1].
    """
    d, dd, s = _hue_axis(tint)
    if s <= 0.0 or np.count_nonzero(lips) < MIN_LIP_PIXELS:
        return np.ones(image.shape[:2], np.float32)
    k = (d / (dd * max(s, 1.0))).astype(np.float32)  # p / max(s, 1) = (q - median) per pixel
    q = _LOG_LEVELS[image[..., 0]] * k[0]
    q += _LOG_LEVELS[image[..., 1]] * k[1]
    q += _LOG_LEVELS[image[..., 2]] * k[2]
    q -= np.median(q[lips]) if tint.source_lips is None else \
        np.float32(np.asarray(tint.source_lips, np.float64) @ k)
    return np.clip(1.0 - q, 0.0, 1.0, out=q)

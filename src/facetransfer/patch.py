"""A texture region of a reference frame pasted into the current frame (§6, beyond).

The eye region (:mod:`facetransfer.eyes`) and the jaw (:mod:`facetransfer.jaw`) are textured
from one target frame (eyes open, mouth closed) rather than from the current one. The current
frame's exposure, white balance and shading differ from that frame's, and near the region's
outline it may show another thing (hair, the gap under the jaw of a turned head). So the part
is scaled per channel by a smooth gain field fitted robustly to the two frames' ratio
(:func:`gain_field`), pixels that are too unlike fade back to the current frame (``reject``),
and the seam is feathered (:func:`match_outline`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .composite import blend_paste, channel_rows, feather_alpha
from .errors import RewriteError
from .jit import maybe_njit as _maybe_njit

__all__ = ["GAIN_RANGE", "REJECT", "REJECT_GROW", "RING_INSET", "match_outline",
           "match_outline_into", "gain_field", "ring_inset"]

#: Per-channel gains allowed between the eye region's frame and the current one
#: (:func:`match_outline`).
GAIN_RANGE = (0.7, 1.4)
#: Reweighting steps and most pixels of the robust fit of :func:`gain_field`.
GAIN_ITERATIONS, GAIN_SAMPLES = 5, 4096
#: The plane of :func:`gain_field` is held constant beyond this fraction of its samples at
#: each end of their columns and of their rows: it is evaluated where the compared pixels
#: lie, not extrapolated from a few of them. (The jaw region's ring in a smiling, open-mouthed
#: frame of ``make demo`` lies almost wholly above the chin; 4 % of its pixels, under the chin
#: where the target's own opening shades the neck, tilted the plane and darkened the new chin
#: by a quarter: BENCHMARKS.md, "Nineteenth session".)
GAIN_SUPPORT = 0.1
#: Pixels by which a rejection (:func:`match_outline`'s ``reject``) grows beyond the pixels
#: that are unlike enough: the transition from skin to hair in the reference frame; and the
#: rejection's blur (a Gaussian's standard deviation). Both, like :data:`RING_INSET`, at a face
#: up to :data:`facetransfer.face_scale.FACE_SPAN`, grown with a larger one (``scale``).
REJECT_GROW = 2
REJECT_BLUR = 2.0
#: Pixels inside the face that the compared pixels keep from its outline (:func:`_ring`).
RING_INSET = 2
#: Log ratios between a reference frame's texture (matched) and the current frame's from
#: which a pixel fades back to the current frame, fully at the second (a factor of 1.65-2.5;
#: :func:`match_outline`'s ``reject``): the reference frame shows another thing there, not the
#: same skin in another expression. At the eye region's rim and at the hairline it often shows
#: skin where the current frame shows hair; at the jaw line of a turned head
#: (:mod:`facetransfer.jaw`) hair or the gap under it.
REJECT = (0.5, 0.9)


def match_outline(face: np.ndarray, part: np.ndarray, mask: np.ndarray, face_mask: np.ndarray,
                  *, feather: float = 3.0, compare: np.ndarray | None = None,
                  reject: tuple[float, float] | None = None,
                  reject_where: np.ndarray | None = None) -> np.ndarray:
    """Paste ``part`` into ``face`` inside ``mask``, shifted to the face's colours.

    ``face`` and ``part`` show the same surface there (the same person's skin lifted from two
    frames), so their ratio is the change of exposure, white balance and shading between the
    frames plus the change of expression. ``part`` is scaled per channel by a smooth gain
    (:func:`gain_field`: the ratio's robust planar fit over ``mask`` inside the face, 2 px from
    its edge, clipped to :data:`GAIN_RANGE`): robust to the expression's share and to hair,
    unlike a membrane pinned at every outline pixel; planar, so that a light falling off across
    the face as the head turns away from the reference frame is followed; and a gain keeps dark
    pixels (iris, lashes) dark where an offset would tint them. The seam fades over ``feather``
    pixels inside the mask.

    Parameters
    ----------
    face, part : (H, W, 3) uint8
    mask, face_mask : (H, W) bool
    feather : float
    compare : (H, W) bool, optional
        Where ``face`` and ``part`` are compared instead of ``mask`` (a ring around the region
        that the expression does not move, e.g.).
    reject : (lo, hi), optional
        Pixels where the matched ``part`` and ``face`` differ by more than a factor
        ``exp(lo)`` (in some channel, either way) fade back to ``face``, fully at ``exp(hi)``:
        what the reference frame shows there is another thing (hair or the gap under it over
        the jaw line of a frontal frame, where a turned head shows skin), not the same skin in
        another expression. The price: a shadow the current frame's own expression casts that
        is darker than that (the target's open jaw, deeper than ``exp(lo)``) shows again.
    reject_where : (H, W) bool, optional
        Only these pixels may be rejected (default: all of ``mask``).

    Returns
    -------
    (H, W, 3) uint8
    """
    out = face.copy()
    match_outline_into(face, part, mask, face_mask, out, feather=feather, compare=compare,
                       reject=reject, reject_where=reject_where)
    return out


def match_outline_into(face, part, mask, face_mask, out, *, feather, compare, reject,
                       reject_where, origin: tuple[int, int] = (0, 0),
                       gain_range: tuple[float, float] = GAIN_RANGE,
                       grey_where: np.ndarray | bool | None = None,
                       opacity: float | np.ndarray = 1.0, shading: float = 0.0,
                       hue: float = 0.0, hue_where: np.ndarray | None = None,
                       scale: float = 1.0) -> None:
    """:func:`match_outline` written into ``out`` (H, W, 3) uint8, which holds ``face``'s
    pixels on entry (``face`` itself: every read of ``face`` comes before the paste); only
    the region's pixels are written; ``gain_range``: the gains' clip (default
    :data:`GAIN_RANGE`). ``origin``: the position ``(x, y)`` of these arrays'
    top-left pixel in the image whose coordinates the gain fit takes (a crop of it whose
    border lies at least 2 pixels beyond ``mask`` and ``compare`` gives that image's
    pixels). ``grey_where`` (H, W) bool: pixels scaled by one gain for the three channels (the
    geometric mean of the channels' gains, :func:`_grey`), which keeps their hue; True: all.
    ``opacity`` in [0, 1], a number or per pixel (H, W) float32: the paste's alpha scaled
    by it. ``shading`` > 0: the gained part is then brought to the face's own low-frequency
    shading at that scale (:func:`_shading_field`, its Gaussian's standard deviation in
    pixels), compared where the gain is. ``hue`` > 0: then to the face's smooth hue at that
    scale, its brightness kept (:func:`_hue_field`), compared over the region and where the
    gain is, of those only at the pixels ``hue_where`` (H, W) bool where given (e.g. not
    where the jaw region shows a tongue, :mod:`facetransfer.jaw_look`). ``scale``: the factor
    of the compared pixels' inset and the rejection's growth and blur (:func:`ring_inset`,
    :data:`REJECT_GROW`; :func:`facetransfer.face_scale.face_scale`; the caller scales
    ``feather``, ``shading`` and ``hue``), the crop's border then ``ring_inset(scale)``
    pixels beyond ``mask`` and ``compare``."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    if w == 0 or h == 0:
        return
    ring, rbox = _ring(mask if compare is None else compare, face_mask, ring_inset(scale))
    box = (slice(y, y + h), slice(x, x + w))      # the work is done on the region's box only
    pb = np.ascontiguousarray(part[box])
    if ring is not None and np.count_nonzero(ring) >= 8:  # part scaled by gain_field's gains
        ox, oy = origin
        gy, gx = _gain_factors(face, part, ring, GAIN_ITERATIONS,
                               (x + ox, y + oy, x + w + ox, y + h + oy), GAIN_SAMPLES,
                               origin=(rbox[0], rbox[1]), shift=origin)
        if grey_where is True:
            gy, gx = _grey(gy), _grey(gx)
        f = np.empty(pb.shape, np.float32)
        _apply_gain(pb, gy, gx, *gain_range, f)
        if isinstance(grey_where, np.ndarray) and grey_where[box].any():
            g = np.empty(pb.shape, np.float32)
            _apply_gain(pb, _grey(gy), _grey(gx), *gain_range, g)
            np.copyto(f, g, where=grey_where[box][..., None])
    else:
        f = pb.astype(np.float32)
    if shading > 0 and ring is not None:
        _shade_to(f, face, ring, rbox, (x, y, w, h), shading)
    if hue > 0:
        valid = np.array(mask[box], copy=True)
        if ring is not None:
            _or_box(valid, ring, rbox, (x, y, w, h))
        if hue_where is not None:
            valid &= hue_where[box]
        g = _hue_field(f, face[box], valid, hue) if valid.any() else None
        if g is not None:
            cv2.multiply(f, g, dst=f)
    # the distance to the nearest pixel outside the region (the box's edge counts as outside:
    # one pixel beyond it is outside the region, or the image ends there)
    mb = np.ascontiguousarray(mask[box])
    a = feather_alpha(mb, feather, edge_outside=True)
    if isinstance(opacity, np.ndarray):
        a *= opacity[box]
    elif opacity < 1.0:
        a *= np.float32(opacity)
    fb = np.ascontiguousarray(face[box])
    if reject is not None:  # the fade a (1 - r), r the rejection where reject_where
        where = mb if reject_where is None else np.ascontiguousarray(reject_where[box])
        _reject_fade(_rejection_blur(f, fb, reject, scale), where, a)
    blend_paste(mb, fb, f, a, out[box])  # in place: the region's pixels of ``out``


#: :func:`_shading_field`: the Gaussian's standard deviation in pixels, how far a compared
#: block's ratio may be from 1 (its log) and still count, the grid's step in pixels, and the
#: clip of the field's gain.
SHADING_SIGMA = 6.0
SHADING_LIMIT = 0.25
SHADING_STEP = 3  # (:func:`_block_means` is written for 3 x 3 blocks)
SHADING_RANGE = (0.8, 1.25)


def ring_inset(scale: float = 1.0) -> int:
    """:data:`RING_INSET` for a face ``scale`` times the size it is given for
    (:func:`facetransfer.face_scale.face_scale`), rounded: the pixels by which the compared
    pixels keep inside the face, and a caller's crop reaches beyond the region."""
    return int(round(RING_INSET * scale))


def _shade_to(f: np.ndarray, face: np.ndarray, ring: np.ndarray, rbox: tuple[int, int],
              box: tuple[int, int, int, int], sigma: float = SHADING_SIGMA) -> None:
    """``f`` (h, w, 3) float32, the gained part on the region's box ``box = (x, y, w, h)`` of
    ``face``, times :func:`_shading_field` of it against ``face`` over the compared pixels
    ``ring`` (its top-left pixel at ``rbox``) at the scale ``sigma``, in place."""
    x, y, w, h = box
    valid = np.zeros((h, w), bool)
    _or_box(valid, ring, rbox, box)  # the compared pixels that fall in the region's box
    g = _shading_field(f, face[y:y + h, x:x + w], valid, sigma)
    if g is not None:
        cv2.multiply(f, g, dst=f)


def _coarse(part: np.ndarray, face: np.ndarray, valid: np.ndarray):
    """The two images and the compared pixels on a grid :data:`SHADING_STEP` times coarser:
    ``(f1, p1, m)``, the block means of ``face`` (h, w, 3) uint8 and ``part`` (h, w, 3)
    float32 plus 1 and the share of ``valid`` (h, w) bool pixels per block, all float32; None
    for a box smaller than a block. Over whole blocks (the last ``h % k`` rows and ``w % k``
    columns do not count, and a field interpolated back over all of them is stretched by less
    than a block). The means are OpenCV's ``INTER_AREA`` resize's to the bit (the face's
    rounded to uint8), in one kernel (:func:`_block_means`)."""
    k = SHADING_STEP
    h, w = valid.shape
    if h < k or w < k:
        return None
    f1 = np.empty((h // k, w // k, 3), np.float32)
    p1, m = np.empty_like(f1), np.empty((h // k, w // k), np.float32)
    _block_means(part, face, valid.view(np.uint8), f1, p1, m)
    return f1, p1, m


def _block_means_py(part, face, valid, f1, p1, m):  # pragma: no cover (numba)
    """:func:`_coarse`'s means of the 3 x 3 blocks into ``f1``, ``p1`` (h', w', 3) and ``m``
    (h', w') float32, as ``cv2.resize(..., INTER_AREA)`` computes them for a whole factor
    (its ``resizeAreaFast``: a block's values summed in row-major order, four at a time
    (``sum += ((a + b) + c) + d``; in int for uint8, in float32 for float32), times the
    float32 ``1 / 9``; the uint8 mean rounded to even) and ``cv2.add(., 1.0)``: ``f1`` the
    rounded mean of ``face`` (uint8) plus 1, ``p1`` the mean of ``part`` (float32) plus 1,
    ``m`` the share of ``valid`` (uint8 0/1; its sums exact in any order)."""
    scale, one = np.float32(1.0) / np.float32(9.0), np.float32(1.0)
    for by in range(m.shape[0]):
        y = 3 * by
        for bx in range(m.shape[1]):
            x = 3 * bx
            c = (np.int64(valid[y, x]) + valid[y, x + 1] + valid[y, x + 2] + valid[y + 1, x]
                 + valid[y + 1, x + 1] + valid[y + 1, x + 2] + valid[y + 2, x]
                 + valid[y + 2, x + 1] + valid[y + 2, x + 2])
            m[by, bx] = np.float32(c) * scale
            for ch in range(3):
                si = (np.int64(face[y, x, ch]) + face[y, x + 1, ch] + face[y, x + 2, ch]
                      + face[y + 1, x, ch] + face[y + 1, x + 1, ch] + face[y + 1, x + 2, ch]
                      + face[y + 2, x, ch] + face[y + 2, x + 1, ch] + face[y + 2, x + 2, ch])
                f1[by, bx, ch] = np.float32(np.rint(np.float32(si) * scale)) + one
                s = ((part[y, x, ch] + part[y, x + 1, ch]) + part[y, x + 2, ch]) \
                    + part[y + 1, x, ch]
                s = s + (((part[y + 1, x + 1, ch] + part[y + 1, x + 2, ch])
                          + part[y + 2, x, ch]) + part[y + 2, x + 1, ch])
                p1[by, bx, ch] = (s + part[y + 2, x + 2, ch]) * scale + one


_block_means = _maybe_njit(_block_means_py)


def _weighted_sums(f1: np.ndarray, p1: np.ndarray, m: np.ndarray, sigma: float):
    """The Gaussian-weighted sums (``sigma`` pixels of the full grid) of the coarse images
    over the blocks of weight ``m``, and of the weights: ``(num, den, wt)``, a normalised
    convolution's parts (a full neighbourhood's weights sum to 1)."""
    m3 = cv2.merge([m, m, m])
    s = sigma / SHADING_STEP
    return tuple(cv2.GaussianBlur(a, (0, 0), s)
                 for a in (cv2.multiply(f1, m3), cv2.multiply(p1, m3), m))


def _shading_field(part: np.ndarray, face: np.ndarray, valid: np.ndarray,
                   sigma: float = SHADING_SIGMA) -> np.ndarray | None:
    """The smooth per-channel gain ``(h, w, 3)`` float32 that brings ``part`` (h, w, 3)
    float32 to ``face``'s (h, w, 3) uint8 low-frequency shading, or None where no pixel
    compares.

    On a grid :data:`SHADING_STEP` times coarser (block means, :func:`_coarse`), over the
    blocks at least half of whose pixels are ``valid`` (h, w) bool and whose channel ratios
    ``(1 + face) / (1 + part)`` all lie within ``exp(±SHADING_LIMIT)`` (unlike blocks,
    another thing or another expression, do not count): the ratio of the two images'
    Gaussian-weighted sums (``sigma`` pixels), a normalised convolution; 1 where the weights
    sum to 5 % of a full neighbourhood or less; clipped to :data:`SHADING_RANGE`;
    interpolated back to every pixel. The plane of gains (:func:`gain_field`) matches the
    exposure; this matches what another head pose does to the shading inside the region, so
    the region does not show as patches with seams (the eye region of ``make demo``'s turned
    frames: BENCHMARKS.md, "Fourteenth session").
    """
    grid = _coarse(part, face, valid)
    if grid is None:
        return None
    f1, p1, m = grid
    lim = float(np.exp(SHADING_LIMIT))
    # every channel's ratio within the limit (cv2.inRange: one pass; numpy's reductions over
    # a last axis of 3 took 40 times longer), on blocks mostly of compared pixels
    ok = cv2.inRange(cv2.divide(f1, p1), (1.0 / lim,) * 3, (lim,) * 3)
    if not _keep_blocks(m, ok, ok):
        return None
    num, den, wt = _weighted_sums(f1, p1, m, sigma)
    g = cv2.divide(num, np.maximum(den, 1e-6))
    _held_gain(g, wt, *(np.float32(b) for b in (0.05, *SHADING_RANGE)))  # full: weights sum 1
    h, w = valid.shape
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_LINEAR)


def _keep_blocks_py(m, ok, ok2):  # pragma: no cover (numba)
    """``m`` (h, w) float32 set to 0, in place, at the blocks that do not compare: where
    ``ok`` or ``ok2`` (h, w) uint8 (``cv2.inRange``'s) is 0 or ``m`` is below 0.5 (numpy's
    ``m[~ok | (m < 0.5)] = 0``); whether a block is left (``m.any()``)."""
    left = False
    for y in range(m.shape[0]):
        for x in range(m.shape[1]):
            if ok[y, x] == 0 or ok2[y, x] == 0 or m[y, x] < np.float32(0.5):
                m[y, x] = np.float32(0.0)
            elif m[y, x] != 0:
                left = True
    return left


def _held_gain_py(g, wt, least, lo, hi):  # pragma: no cover (numba)
    """``g`` (h, w, 3) float32 made 1 where the weights ``wt`` (h, w) float32 sum to ``least``
    or less, then clipped to ``lo .. hi`` (all float32), in place: numpy's ``copyto(g, 1,
    where=wt <= least)`` and ``clip(g, lo, hi)``."""
    for y in range(g.shape[0]):
        for x in range(g.shape[1]):
            unit = wt[y, x] <= least
            for c in range(3):
                v = np.float32(1.0) if unit else g[y, x, c]
                g[y, x, c] = min(max(v, lo), hi)


_keep_blocks = _maybe_njit(_keep_blocks_py)
_held_gain = _maybe_njit(_held_gain_py)


def _or_box(valid: np.ndarray, ring: np.ndarray, rbox: tuple[int, int],
            box: tuple[int, int, int, int]) -> None:
    """``valid`` (h, w) bool on the box ``box = (x, y, w, h)``, or-ed in place with the pixels
    of ``ring`` (its top-left pixel at ``rbox``) that fall in it."""
    x, y, w, h = box
    rx, ry = rbox
    ax0, ay0 = max(x, rx), max(y, ry)
    ax1, ay1 = min(x + w, rx + ring.shape[1]), min(y + h, ry + ring.shape[0])
    if ax1 > ax0 and ay1 > ay0:
        valid[ay0 - y:ay1 - y, ax0 - x:ax1 - x] |= ring[ay0 - ry:ay1 - ry, ax0 - rx:ax1 - rx]


#: :func:`_hue_field`: how far a compared block's brightness ratio (its log) and each
#: channel's hue ratio may be from 1 and still count, and the clip of the field's gain.
HUE_LIMITS = (0.4, 0.3)
HUE_RANGE = (0.8, 1.25)
_THIRDS = np.full((1, 3), 1.0 / 3.0, np.float32)  # cv2.transform: the mean of 3 channels


def _hue_field(part: np.ndarray, face: np.ndarray, valid: np.ndarray, sigma: float
               ) -> np.ndarray | None:
    """The smooth per-channel gain ``(h, w, 3)`` float32 of product 1 over the channels that
    brings ``part``'s (h, w, 3) float32 hue to ``face``'s (h, w, 3) uint8 at the scale
    ``sigma`` (pixels), leaving its brightness: :func:`_shading_field`'s ratio of
    Gaussian-weighted sums over the ``valid`` blocks, divided by its geometric mean over the
    channels, on blocks whose brightness ratio lies within ``exp(±HUE_LIMITS[0])`` and whose
    channels' hue ratios lie within ``exp(±HUE_LIMITS[1])`` (hair, teeth, lips: another
    thing); None where no block compares. Where the weights sum to 5 % of a full
    neighbourhood or less (:func:`_shading_field`), the field is the hue of all the compared
    blocks (:func:`_region_hue`), not 1: a hole of the compared pixels wider than ~1.6
    ``sigma`` (where :mod:`facetransfer.jaw_look` took the reference frame: a tongue, a lip
    pressed out) takes the region's hue, not the reference frame's own."""
    grid = _coarse(part, face, valid)
    if grid is None:
        return None
    f1, p1, m = grid
    # the log ratios, their mean over the channels (the brightness) and the rest (the hue);
    # OpenCV throughout: numpy's reductions over a last axis of 3 are many times slower
    lr = cv2.subtract(cv2.log(f1), cv2.log(p1))
    grey = cv2.transform(lr, _THIRDS)
    ok = cv2.inRange(cv2.subtract(lr, cv2.merge([grey, grey, grey])), (-HUE_LIMITS[1],) * 3,
                     (HUE_LIMITS[1],) * 3)
    if not _keep_blocks(m, ok, cv2.inRange(grey, -HUE_LIMITS[0], HUE_LIMITS[0])):
        return None
    num, den, wt = _weighted_sums(f1, p1, m, sigma)
    lg = cv2.subtract(cv2.log(cv2.max(num, 1e-6)), cv2.log(cv2.max(den, 1e-6)))
    mean = cv2.transform(lg, _THIRDS)
    g = cv2.exp(cv2.subtract(lg, cv2.merge([mean, mean, mean])))
    held = wt <= np.float32(0.05)
    if held.any():
        g[held] = _region_hue(f1, p1, m)
    np.clip(g, np.float32(HUE_RANGE[0]), np.float32(HUE_RANGE[1]), out=g)
    h, w = valid.shape
    return cv2.resize(g, (w, h), interpolation=cv2.INTER_LINEAR)


def _region_hue(f1: np.ndarray, p1: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``(3,) float32`` of product 1: the hue ratio of the coarse images ``f1`` and ``p1``
    (h, w, 3) float32 over all their blocks of weight ``m`` (h, w) float32 (not all 0), the
    ratio of the weighted sums divided by its geometric mean over the channels; 1 where that
    is not finite (a NaN in the part). The sums in float64 by one BLAS product each (numpy's
    ``einsum`` in float64 took five times longer: ~0.15 ms a frame of the jaw)."""
    w = m.reshape(-1).astype(np.float64)
    lg = np.log(w @ f1.reshape(-1, 3).astype(np.float64)) - \
        np.log(w @ p1.reshape(-1, 3).astype(np.float64))
    g = np.exp(lg - lg.mean())
    return (g if np.isfinite(g).all() else np.ones(3)).astype(np.float32)


def _grey(g: np.ndarray) -> np.ndarray:
    """Per-channel gain factors (n, 3) as one factor for all three: the geometric mean of each
    row, so the gain's product over rows and columns is the mean of the channels' log gains.
    (numpy's log and exp; the mean, ``((a + b) + c) / 3`` as numpy's sums a row of three, and
    the repeat in a kernel.)"""
    m = np.empty(g.shape[0])
    _row_means(np.log(g), m)
    return _repeat3(np.exp(m, out=m))


def _row_means_py(lg, m):  # pragma: no cover (numba)
    """``m = ((lg[:, 0] + lg[:, 1]) + lg[:, 2]) / 3`` (``lg`` (n, 3), ``m`` (n,) float64)."""
    for i in range(lg.shape[0]):
        m[i] = ((lg[i, 0] + lg[i, 1]) + lg[i, 2]) / 3.0


def _repeat3_py(m):  # pragma: no cover (numba)
    """``m`` (n,) repeated for three channels, a new (n, 3) array."""
    out = np.empty((m.shape[0], 3))
    for i in range(m.shape[0]):
        out[i, 0] = out[i, 1] = out[i, 2] = m[i]
    return out


_row_means = _maybe_njit(_row_means_py)
_repeat3 = _maybe_njit(_repeat3_py)


def _ring(compare: np.ndarray, face_mask: np.ndarray, inset: int = RING_INSET):
    """The pixels of ``compare`` (H, W) bool at least ``inset`` pixels inside ``face_mask``
    (H, W) bool (its square erosion of side ``2 inset + 1``, pixels beyond the image outside)
    on the box of ``compare`` only: ``(ring (h, w) bool or None, (x0, y0))`` (None:
    ``compare`` is empty)."""
    x, y, w, h = cv2.boundingRect(compare.view(np.uint8))
    if w == 0 or h == 0:
        return None, (0, 0)
    H, W = face_mask.shape
    r = int(inset)
    # the erosion on the box grown by its reach (clipped to the image): the box's pixels see
    # their true neighbours, the image's border stays outside
    gx0, gy0, gx1, gy1 = max(x - r, 0), max(y - r, 0), min(x + w + r, W), min(y + h + r, H)
    grown = np.ascontiguousarray(face_mask[gy0:gy1, gx0:gx1]).view(np.uint8)
    square = _SQUARE5 if r == 2 else np.ones((2 * r + 1,) * 2, np.uint8)
    deep = cv2.erode(grown, square, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    ring = compare[y:y + h, x:x + w] & deep[y - gy0:y - gy0 + h, x - gx0:x - gx0 + w].view(bool)
    return ring, (x, y)


_SQUARE5 = np.ones((5, 5), np.uint8)


def _rejection_blur(f: np.ndarray, fb: np.ndarray, reject: tuple[float, float],
                    scale: float = 1.0) -> np.ndarray:
    """``b`` (h, w) float32, whose ``r = clip(2 b, 0, 1)`` (that last step in
    :func:`_reject_fade`) is the rejection: how far each pixel's largest per-channel absolute
    log ratio of ``f`` (h, w, 3) float32 and ``fb`` (h, w, 3) uint8 (``|log(1 + f) - log(1 +
    fb)|``) lies between ``reject = (lo, hi)``, grown by :data:`REJECT_GROW` pixels (the soft
    edge of hair in the reference frame is less unlike the skin than the hair, and would be
    left as a thin grey outline) and blurred by :data:`REJECT_BLUR`, both times ``scale``."""
    lo, hi = (float(v) for v in reject)
    r = np.empty(f.shape[:2], np.float32)
    _reject_kernel(f, fb, lo, max(hi - lo, 1e-6), r)
    grow = int(round(REJECT_GROW * scale))
    if grow > 0 and r.any():
        r = cv2.dilate(r, np.ones((2 * grow + 1,) * 2, np.uint8))
    return cv2.GaussianBlur(r, (0, 0), REJECT_BLUR * scale)


def _reject_fade_py(blur, where, a):  # pragma: no cover (numba)
    """``a *= 1 - r`` with ``r = clip(2 blur, 0, 1)`` where ``where`` (h, w) bool and 0
    elsewhere: match_outline's rejection (:func:`_rejection_blur`) in float32 as numpy's ``r *=
    where; a *= 1.0 - r`` were, in one pass (``a``, ``blur`` (h, w) float32)."""
    H, W = a.shape
    one, zero = np.float32(1.0), np.float32(0.0)
    for y in range(H):
        for x in range(W):
            r = min(max(blur[y, x] * np.float32(2.0), zero), one)
            a[y, x] = a[y, x] * (one - (r if where[y, x] else zero))


def _reject_kernel(f: np.ndarray, fb: np.ndarray, lo: float, span: float,
                   r: np.ndarray) -> None:
    """``r = clip((max_c |log(1 + f) - log(1 + fb)| - lo) / span, 0, 1)`` per pixel: ``f``
    (h, w, 3) float32, ``fb`` (h, w, 3) uint8, ``r`` (h, w) float32 (:func:`_reject_rows`)."""
    cls = np.empty(3 * r.shape[1], np.uint8)
    _reject_rows(channel_rows(np.ascontiguousarray(f)), channel_rows(np.ascontiguousarray(fb)),
                 float(lo), float(span), r, cls)


def _reject_rows_py(f, fb, lo, span, r, cls):  # pragma: no cover (numba)
    """:func:`_reject_kernel` on rows ``(h, 3 w)`` of channel values, with one log per pixel
    (of the largest ratio ``(1 + f) / (1 + fb)`` or its inverse) and none where that ratio
    lies outside ``exp(lo)..exp(lo + span)``.

    Most pixels are decided without division, a row's channel values at once (vectorised,
    into ``cls`` (3 w,) uint8): below the ramp by ``max <= q' min`` in every channel with
    ``q'`` a little under ``exp(lo)`` (then the exact ratio is below ``exp(lo)``, so its
    correctly rounded quotient is at most that: the same 0 as the quotients give), beyond it
    by ``max > q'' min`` in some channel with ``q''`` a little over ``exp(lo + span)`` (then
    the quotient is at least that: 1)."""
    H, W = r.shape
    q_lo, q_hi = np.exp(lo), np.exp(lo + span)
    q_safe, q_sure = q_lo * (1.0 - 2.0 ** -50), q_hi * (1.0 + 2.0 ** -50)
    for y in range(H):
        for j in range(3 * W):  # 0: below, 1: undecided, 2: beyond
            u, v = 1.0 + np.float64(f[y, j]), 1.0 + np.float64(fb[y, j])
            a, b = max(u, v), min(u, v)
            cls[j] = np.uint8(a > q_safe * b) + np.uint8(a > q_sure * b)
        for x in range(W):
            c = max(cls[3 * x], max(cls[3 * x + 1], cls[3 * x + 2]))
            if c != 1:
                r[y, x] = 0.0 if c == 0 else 1.0
                continue
            q = 1.0
            for k in range(3 * x, 3 * x + 3):
                u, v = 1.0 + f[y, k], 1.0 + fb[y, k]
                q = max(q, max(u, v) / min(u, v))
            if q <= q_lo:
                r[y, x] = 0.0
            elif q >= q_hi:
                r[y, x] = 1.0
            else:
                r[y, x] = (np.log(q) - lo) / span


_reject_rows = _maybe_njit(_reject_rows_py)


def gain_field(face: np.ndarray, part: np.ndarray, where: np.ndarray, *,
               iterations: int = GAIN_ITERATIONS, box: tuple[int, int, int, int] | None = None,
               max_samples: int = GAIN_SAMPLES) -> np.ndarray:
    """Per-channel gains taking ``part`` to ``face``'s colours.

    The log ratio ``log(1 + face) - log(1 + part)`` over the pixels ``where`` is fitted, per
    channel, by a plane ``a + b x + c y`` in least absolute deviations (iteratively reweighted
    least squares): the median's robustness (pixels whose content differs, e.g. the target's own
    lids and lashes, are outvoted), plus the plane's gradient of shading. Coordinates are
    centred on the pixels' centroid and scaled by their extent, so the gains do not depend on
    the crop. The plane is evaluated where the pixels lie: beyond the middle of their columns
    and rows (:data:`GAIN_SUPPORT`) it is held at its value there, not extrapolated from the
    few pixels beyond. Clipped to :data:`GAIN_RANGE`.

    Parameters
    ----------
    face, part : (H, W, 3) uint8
    where : (H, W) bool
        At least 3 pixels not on one line.
    iterations : int
        Reweighting steps.
    box : (x0, y0, x1, y1), optional
        Return the gains of this box of pixels only (default: the whole image).
    max_samples : int
        At most this many of the ``where`` pixels (evenly strided) enter the fit.

    Returns
    -------
    (y1 - y0, x1 - x0, 3) float32
    """
    x0, y0, x1, y1 = (0, 0, where.shape[1], where.shape[0]) if box is None else box
    if x1 < x0 or y1 < y0:
        raise RewriteError(f"gain_field: box {tuple(box)} ends before it starts "
                           "(x0, y0, x1, y1 with x1 >= x0 and y1 >= y0)")
    gy, gx = _gain_factors(face, part, where, iterations, (x0, y0, x1, y1), max_samples)
    return np.clip(gy[:, None, :] * gx[None, :, :], *GAIN_RANGE).astype(np.float32)


#: ``log(1 + v)`` of the 256 values of a uint8
_LOG1P_U8 = np.log1p(np.arange(256, dtype=np.float64))


def _gain_factors(face, part, where, iterations: int, box, max_samples: int, *,
                  origin: tuple[int, int] = (0, 0), shift: tuple[int, int] = (0, 0)):
    """The fit of :func:`gain_field` as its separable factors over ``box = (x0, y0, x1, y1)``:
    ``gy (y1 - y0, 3)`` and ``gx (x1 - x0, 3)`` float64, the unclipped gain at pixel ``(x, y)``
    being ``gy[y - y0] * gx[x - x0]``.

    ``where`` may be a crop of the mask whose top-left pixel is ``origin`` in ``face`` and
    ``part``; the fit's coordinates are those of ``face`` plus ``shift`` (as ``box``'s)."""
    m = np.ascontiguousarray(where).view(np.uint8)
    n = cv2.countNonZero(m)
    if n == 0:
        raise RewriteError("the gain fit needs at least one pixel, got an empty mask")
    k = -(-n // max(1, -(-n // int(max_samples))))  # the samples: every step-th pixel
    x0, y0, x1, y1 = box
    # exp(a + b x + c y) = exp(a) exp(b x) exp(c y): separable over the box's rows and columns,
    # each coordinate held within the samples' middle (GAIN_SUPPORT; 0: extrapolated): the
    # plane and its exponents in one kernel (_gain_fit), their exp numpy's
    step = max(1, k // 1024)     # at most ~1024 of the samples give the middle's ends
    lo = int(round(GAIN_SUPPORT * (len(range(0, k, step)) - 1)))
    u, v, r, centre = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty(3)
    _gain_samples(m, n, int(origin[0]), int(origin[1]), int(shift[0]), int(shift[1]), face,
                  part, int(max_samples), _LOG1P_U8, u, v, r, centre)
    gx, gy = np.empty((x1 - x0, 3)), np.empty((y1 - y0, 3))
    _gain_fit(u, v, r, centre, int(iterations), step, lo, GAIN_SUPPORT > 0, int(x0), int(y0),
              gx, gy)
    return np.exp(gy, out=gy), np.exp(gx, out=gx)


def _gain_fit_py(u, v, r, centre, iterations, step, lo, held, x0, y0, ex,
                 ey):  # pragma: no cover (numba)
    """:func:`_gain_factors`' plane of the samples ``u``, ``v``, ``r`` (:func:`_gain_samples`,
    centred on ``centre``; :func:`_plane_l1_kernel`, ``iterations`` steps) and its exponents
    over the box (:func:`_exponents` into ``ex`` (w, 3), ``ey`` (h, 3)) in one call (its
    arrays C-contiguous always: one compiled kernel)."""
    coef = np.empty((3, 3))
    _plane_l1_kernel(u, v, r, iterations, coef)
    _exponents(u, v, step, lo, held, x0, y0, centre[0], centre[1], centre[2], coef, ex, ey)


def _exponents_py(u, v, step, lo, held, x0, y0, cx, cy, scale, coef, ex,
                  ey):  # pragma: no cover (numba)
    """The exponents of :func:`_gain_factors`' separable gains: ``ex`` (w, 3) = ``xs coef[1]``
    and ``ey`` (h, 3) = ``coef[0] + ys coef[2]`` (per channel) with ``xs = (x - cx) / scale``
    over the columns ``x0 .. x0 + w - 1`` and ``ys`` the rows' likewise, each clipped, when
    ``held``, to the middle of ``u`` (``v``): the ``lo``-th and ``(m - 1 - lo)``-th
    smallest of its ``m`` samples of stride ``step``; float64, numpy's operations in order."""
    xlo = xhi = ylo = yhi = 0.0
    if held:
        b = u[::step].copy()
        m = b.shape[0]
        xlo, xhi = np.partition(b, lo)[lo], np.partition(b, m - 1 - lo)[m - 1 - lo]
        b = v[::step].copy()
        ylo, yhi = np.partition(b, lo)[lo], np.partition(b, m - 1 - lo)[m - 1 - lo]
    for i in range(ex.shape[0]):
        x = (np.float64(x0 + i) - cx) / scale
        if held:
            x = min(max(x, xlo), xhi)
        for c in range(3):
            ex[i, c] = x * coef[1, c]
    for i in range(ey.shape[0]):
        y = (np.float64(y0 + i) - cy) / scale
        if held:
            y = min(max(y, ylo), yhi)
        for c in range(3):
            ey[i, c] = coef[0, c] + y * coef[2, c]


def _gain_samples_py(m, n, ox, oy, sx0, sy0, face, part, max_samples, lut, u, v, r,
                     centre):  # pragma: no cover (numba)
    """The samples of :func:`gain_field`'s fit from the ``n`` pixels set in ``m`` (h, w)
    uint8, in row-major order (as ``cv2.findNonZero`` lists them), ``m``'s top-left pixel
    ``(ox, oy)`` of ``face`` and ``part``, at coordinates shifted by ``(sx0, sy0)``:
    ``centre = (cx, cy, scale)``, the pixels' mean position and the larger extent of their
    rows and columns (at least 1); for every ``step``-th pixel (``step = ceil(n /
    max_samples)``) the centred, scaled coordinates ``u = (x - cx) / scale``, ``v = (y - cy) /
    scale`` and the log ratios ``r = lut[face] - lut[part]`` (3 channels). The means are the
    integer sums over ``n`` (as numpy's mean of the coordinates, whose float sums are
    exact). Two passes over ``m``, no list of its pixels: the first without a branch per
    pixel (a row's count, column sum and extremes by selects: vectorised), the second
    counting down to the next sample, not ``i % step`` per pixel (an integer division)."""
    dx, dy = np.int64(ox) + np.int64(sx0), np.int64(oy) + np.int64(sy0)
    sx = sy = np.int64(0)
    W = m.shape[1]
    x_lo, x_hi, y_lo, y_hi = W, -1, m.shape[0], -1
    for y in range(m.shape[0]):
        c = row_x = np.int64(0)
        lo, hi = W, -1
        for x in range(W):
            b = np.int64(m[y, x] != 0)
            c += b
            row_x += x * b
            lo = min(lo, x if b else W)
            hi = max(hi, x if b else -1)
        sx += row_x
        x_lo, x_hi = min(x_lo, lo), max(x_hi, hi)
        if c:
            sx += c * dx
            sy += c * (y + dy)
            y_lo, y_hi = min(y_lo, y), max(y_hi, y)
    cx, cy = float(sx) / float(n), float(sy) / float(n)
    scale = float(max(y_hi - y_lo, x_hi - x_lo, 1))
    step = max(1, -(-n // max_samples))
    j = left = 0  # left: the set pixels to pass before the next sample (every step-th)
    for yy in range(m.shape[0]):
        for xx in range(m.shape[1]):
            if not m[yy, xx]:
                continue
            if left == 0:
                x, y = np.int64(xx) + ox, np.int64(yy) + oy
                u[j] = (x + sx0 - cx) / scale
                v[j] = (y + sy0 - cy) / scale
                for c in range(3):
                    r[j, c] = lut[face[y, x, c]] - lut[part[y, x, c]]
                j += 1
                left = step
            left -= 1
    centre[0], centre[1], centre[2] = cx, cy, scale


def _plane_l1_kernel_py(u, v, r, iterations, coef):  # pragma: no cover (numba)
    """Per channel c, the plane ``coef[:, c] = (a, b, c)`` fitting ``r[:, c]`` (k, 3) by
    ``a + b u + c v`` in least absolute deviations: ``iterations`` steps of iteratively
    reweighted least squares (weights ``1 / max(|residual|, 1e-3)``, from 1; the normal
    equations with a ridge of 1e-9, solved by Cramer's rule). The weights and residuals are
    kept per channel (contiguous: the reweighting is vectorised), the sums in registers."""
    k = r.shape[0]
    w = np.ones((3, k))
    rt = np.empty((3, k))
    for i in range(k):
        for c in range(3):
            rt[c, i] = r[i, c]
    sums = np.empty((3, 9))  # per channel: sum w, wu, wv, wuu, wuv, wvv, wr, wur, wvr
    for _ in range(iterations):
        for c in range(3):
            _plane_sums(u, v, rt[c], w[c], sums[c])
            _solve_plane(sums[c], coef, c)
        for c in range(3):
            _reweight(u, v, rt[c], coef[0, c], coef[1, c], coef[2, c], w[c])


def _plane_sums_py(u, v, r, w, out):  # pragma: no cover (numba, inlined)
    """The weighted moments of one channel, ``out`` (9,) = sums over i of ``w, w u, w v,
    w u², w u v, w v², w r, w r u, w r v`` (in order of i)."""
    s0 = s1 = s2 = s3 = s4 = s5 = t0 = t1 = t2 = 0.0
    for i in range(r.shape[0]):
        ui, vi = u[i], v[i]
        wi, wr = w[i], w[i] * r[i]
        s0 += wi
        s1 += wi * ui
        s2 += wi * vi
        s3 += wi * (ui * ui)
        s4 += wi * (ui * vi)
        s5 += wi * (vi * vi)
        t0 += wr
        t1 += wr * ui
        t2 += wr * vi
    out[0], out[1], out[2], out[3], out[4] = s0, s1, s2, s3, s4
    out[5], out[6], out[7], out[8] = s5, t0, t1, t2


def _solve_plane_py(m, coef, c):  # pragma: no cover (numba, inlined)
    """``coef[:, c]`` from the moments ``m`` (9,) of :func:`_plane_sums`: the normal
    equations with a ridge of 1e-9, by Cramer's rule."""
    a00, a01, a02 = m[0] + 1e-9, m[1], m[2]
    a11, a12, a22 = m[3] + 1e-9, m[4], m[5] + 1e-9
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    b0, b1, b2 = m[6], m[7], m[8]
    coef[0, c] = (c00 * b0 + c01 * b1 + c02 * b2) / det
    coef[1, c] = (c01 * b0 + c11 * b1 + c12 * b2) / det
    coef[2, c] = (c02 * b0 + c12 * b1 + c22 * b2) / det


def _reweight_py(u, v, r, a, b, c, w):  # pragma: no cover (numba, inlined)
    """``w = 1 / max(|r - a - b u - c v|, 1e-3)`` (one channel's weights, vectorised)."""
    for i in range(r.shape[0]):
        w[i] = 1.0 / max(abs(r[i] - a - b * u[i] - c * v[i]), 1e-3)


_plane_sums = _maybe_njit(_plane_sums_py, inline=True)
_solve_plane = _maybe_njit(_solve_plane_py, inline=True)
_reweight = _maybe_njit(_reweight_py, inline=True)


def _apply_gain(part: np.ndarray, gy: np.ndarray, gx: np.ndarray, lo: float, hi: float,
                f: np.ndarray) -> None:
    """``f = part * clip(gy gx, lo, hi)`` (the float32 gain of :func:`gain_field`) per pixel
    and channel: ``part`` (h, w, 3) uint8, ``gy`` (h, 3), ``gx`` (w, 3) float64, ``f``
    (h, w, 3) float32, all C-contiguous; by rows of channel values (vectorised)."""
    h, w = part.shape[:2]
    _gain_rows(channel_rows(part), np.ascontiguousarray(gy),
               np.ascontiguousarray(gx).reshape(3 * w), lo, hi, channel_rows(f), np.empty(3 * w))


def _gain_rows_py(part, gy, gx, lo, hi, f, row):  # pragma: no cover (numba)
    """:func:`_apply_gain` on rows ``(h, 3 w)`` of channel values, ``gx`` (3 w,) float64 and
    ``row`` (3 w,) float64 scratch (a row's ``gy`` repeated per pixel)."""
    H, L = f.shape
    for y in range(H):
        g0, g1, g2 = gy[y, 0], gy[y, 1], gy[y, 2]
        for x in range(L // 3):
            row[3 * x] = g0
            row[3 * x + 1] = g1
            row[3 * x + 2] = g2
        for j in range(L):
            g = np.float32(min(max(row[j] * gx[j], lo), hi))
            f[y, j] = np.float32(part[y, j]) * g


_gain_rows = _maybe_njit(_gain_rows_py)
_gain_samples = _maybe_njit(_gain_samples_py)
_reject_fade = _maybe_njit(_reject_fade_py)
_plane_l1_kernel = _maybe_njit(_plane_l1_kernel_py)
_exponents = _maybe_njit(_exponents_py)
_gain_fit = _maybe_njit(_gain_fit_py)

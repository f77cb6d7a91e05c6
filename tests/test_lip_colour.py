"""The target's lip colour on the source's mouth (:mod:`facetransfer.lip_colour`).

Synthetic footage of one identity rendered from a UV texture: the target's texture has its lips
painted (a lipstick: the lips' texels scaled per channel), the source's has not. The rewrite
takes the mouth from the source's frames; with ``lip_colour="target"`` the lips of the result
take the target's paint, the skin and the mouth's inside stay as they were.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer import lip_colour as lc  # noqa: E402
from facetransfer import rewrite_clip as rc  # noqa: E402
from facetransfer import topology  # noqa: E402
from facetransfer.render import (WeakPerspective, interpolate_vertex_values,  # noqa: E402
                                 rasterize)
from facetransfer.rewrite_options import RewriteError, RewriteOptions  # noqa: E402

from test_speed50_references import _old_recolour  # noqa: E402 (the numpy it replaced)
from test_transfer_mouth import Scene  # noqa: E402

PAINT = np.array([1.25, 0.55, 0.7])  # the target's lipstick, per channel (RGB)
YAWS = [0, 5, -4]


class FixedTexture(Scene):
    """The scene with one texture for every expression."""

    def __init__(self, model, texture):
        super().__init__(model)
        self.fixed = texture

    def texture(self, e):
        return self.fixed


@pytest.fixture(scope="module")
def weights(quick_model):
    topo = topology.mesh_topology(quick_model)
    return (topo,) + lc.lip_vertex_weights(quick_model, topo)


@pytest.fixture(scope="module")
def clips(quick_model, weights):
    """(target frames, source frames, track, painted-lips truth weights per pixel)."""
    from facetransfer.texture import uv_atlas

    topo, w, _ = weights
    plain = Scene(quick_model)
    base = plain.base
    atlas = uv_atlas(topo.faces, plain.uvs, base.shape[0])
    tri = atlas.texel_tri
    wt = np.zeros(tri.shape, np.float64)
    ok = tri >= 0
    wt[ok] = (atlas.texel_bary[ok] * w[topo.faces[tri[ok]]]).sum(-1)
    painted = np.clip(base * (1 + wt[..., None] * (PAINT - 1)), 0, 255)
    n = quick_model.training_weights("expression", "neutral")
    target, track = FixedTexture(quick_model, np.rint(painted).astype(np.uint8)).clip(
        [n] * len(YAWS), YAWS)
    source, _ = FixedTexture(quick_model, np.rint(base).astype(np.uint8)).clip(
        [n] * len(YAWS), YAWS)
    return target, source, track


def test_the_lips_weigh_one_inside_the_contour_and_nothing_outside(quick_model, weights):
    topo, w, read = weights
    lm = np.asarray(quick_model.landmarks)
    assert w.shape == (topo.n_closed,) and w.dtype == np.float32
    assert set(np.unique(w)) <= {0.0, np.float32(1 / 3), np.float32(2 / 3), 1.0}
    assert w[topo.n_vertices] == 0.0  # the mouth's centre: the inside
    np.testing.assert_array_equal(w[lm[60:68]], 1.0)  # the inner lip contour: lips
    # the outer contour lies between the second and third level: a third
    np.testing.assert_allclose(w[lm[48:60]], 1 / 3, atol=1e-6)
    assert w[lm[30]] == 0 and w[lm[8]] == 0 and w[lm[33]] == 0  # nose tip, chin, below nose
    assert read.size > 20 and (w[read] == 1).all()
    assert not np.isin(lm[60:68], read).any()  # not at the opening


def test_lip_ratio_reads_the_median_colours_at_the_vertices():
    img = np.zeros((10, 20, 3), np.uint8)
    img[:, :10] = (200, 60, 80)   # lips on the left half
    img[:, 10:] = (180, 140, 120)  # skin on the right
    uvs = np.array([[0.1, 0.5], [0.2, 0.4], [0.3, 0.6], [0.8, 0.5], [0.9, 0.3]])
    r = lc.lip_ratio([(img, uvs), (img, uvs)], np.array([0, 1, 2]), np.array([3, 4]))
    np.testing.assert_allclose(r.ratio, np.array([201, 61, 81]) / np.array([181, 141, 121]))
    np.testing.assert_allclose(r.skin, [180, 140, 120])
    np.testing.assert_allclose(r.samples, np.tile(r.ratio, (6, 1)), rtol=1e-6)
    np.testing.assert_array_equal(r.frame, [0, 0, 0, 1, 1, 1])
    assert lc.lip_ratio([], np.array([0]), np.array([1])) is None


def test_the_tint_is_the_ratio_of_ratios_clipped():
    t = lc.LipTint.of(np.ones(4), [1.2, 0.5, 0.6], [1.0, 1.0, 0.2])
    np.testing.assert_allclose(t.tint, [1.2, 0.5, lc.TINT_RANGE[1]])
    assert t.weights.dtype == np.float32
    assert t.target_lab is None and t.keep is None  # ratios alone: the tint alone


def _lab(rgb) -> np.ndarray:
    """OpenCV's CIELAB of one RGB colour (levels), the reference."""
    import cv2

    return cv2.cvtColor(np.array([[rgb]], np.float32) / 255.0, cv2.COLOR_RGB2LAB)[0, 0]


def _colour(skin, *frames) -> lc.LipColour:
    """A clip's :class:`LipColour` whose frames' lip vertices have the given RGB levels on
    ``skin`` (each frame a list of colours)."""
    s = np.add(skin, 1.0)
    samples = np.concatenate([(np.add(f, 1.0) / s) for f in frames]).astype(np.float32)
    ratio = np.median([np.median(np.add(f, 1.0), axis=0) / s for f in frames], axis=0)
    frame = np.repeat(np.arange(len(frames)), [len(f) for f in frames])
    return lc.LipColour(ratio, np.asarray(skin, np.float64), samples, frame)


def test_lab_spread_is_the_interquartile_range_of_the_lips_on_the_skin():
    """Four vertices a frame, two of each of two colours: the 25th and 75th percentiles are
    the two colours, the spread their CIELAB difference over 1.349 (put on another skin:
    the same levels times that skin over this one's)."""
    a, b = (150, 50, 60), (200, 120, 110)
    c = _colour(SKIN, [a, a, b, b], [b, a, b, a], [a, a, a, a])
    np.testing.assert_allclose(lc.lab_spread(c, SKIN), np.abs(_lab(b) - _lab(a)) / 1.349,
                               atol=1e-3)  # the median of (d, d, 0) over the three frames
    other = np.array([180.0, 150.0, 140.0])
    on = (np.add(a, 1) / np.add(SKIN, 1) * (other + 1) - 1,
          np.add(b, 1) / np.add(SKIN, 1) * (other + 1) - 1)
    np.testing.assert_allclose(lc.lab_spread(c, other),
                               np.abs(_lab(on[1]) - _lab(on[0])) / 1.349, atol=1e-3)
    assert lc.lab_spread(_colour(SKIN, [a, b, a]), SKIN) is None  # under 4 samples


def test_the_lab_target_and_keep_from_the_two_clips():
    """``target_lab`` is the target's lip ratio on the source's skin; ``keep`` the spreads'
    ratio squared, at least :data:`KEEP_MIN`, at most 1."""
    dark, light = (110, 28, 36), LIPSTICK
    source = _colour(SKIN, [dark, dark, light, light])
    narrow = _colour(PALE_SKIN, [PALE_LIPS] * 2 + [np.add(PALE_LIPS, 6)] * 2)
    t = lc.LipTint.of(np.ones(4), narrow, source)
    on_source = narrow.ratio * (np.add(SKIN, 1)) - 1
    np.testing.assert_allclose(t.target_lab, _lab(on_source), atol=1e-3)
    expect = (lc.lab_spread(narrow, SKIN) / lc.lab_spread(source, SKIN)) ** 2
    assert (expect < 0.2).all()
    np.testing.assert_allclose(t.keep, np.clip(expect, lc.KEEP_MIN, 1.0))
    # the other way the target's lips spread more: nothing kept less than all
    np.testing.assert_array_equal(lc.LipTint.of(np.ones(4), source, narrow).keep, 1.0)
    g = t.grey()  # a monochrome target: the tint alone, one factor (test_monochrome)
    assert g.target_lab is None and g.keep is None and np.ptp(g.tint) == 0
    assert t.recolours() and not lc.LipTint.of(np.ones(4), source, narrow).recolours()


def test_lips_of_a_like_spread_are_not_recoloured():
    """A target's lips whose spread is a little narrower than the source's (the spreads'
    ratio squared between :data:`KEEP_SAME` and 1, as one clip read through the two textures
    gives; the tint about 1, its hue towards the skin): ``keep`` is 1 and :func:`tint_mouth`
    the tint alone, to the level (the recolouring's round trip through CIELAB changed a
    mouth rewritten with its own frames, ``test_transfer_mouth``)."""
    dark, light = np.array((110, 28, 36)), np.array(LIPSTICK)
    source = _colour(SKIN, [dark, dark, light, light])
    near = np.rint(light + 0.97 * (dark - light))
    target = _colour(SKIN, [light, light, near, near])  # L's spread ratio squared 0.944
    ratio2 = (lc.lab_spread(target, SKIN) / lc.lab_spread(source, SKIN)) ** 2
    assert ((ratio2 > lc.KEEP_SAME) & (ratio2 < 1.0)).any(), ratio2
    t = lc.LipTint.of(np.ones(4), target, source)
    assert lc.skin_ahead(t) > 0 and not t.recolours()
    np.testing.assert_array_equal(t.keep[ratio2 > lc.KEEP_SAME], 1.0)
    raster, F, img, _ = _two_lips_mouth()
    mask = raster.tri_id >= 0
    out, alone = img.copy(), img.copy()
    lc.tint_mouth(out, raster, F, t, mask)
    lc.tint_mouth(alone, raster, F, dataclasses.replace(t, target_lab=None, keep=None), mask)
    np.testing.assert_array_equal(out, alone)


def test_lips_of_one_colour_are_not_recoloured():
    """A source whose lip vertices are of one colour in every frame (a spread of 0, as a
    flat-shaded render's): ``keep`` is 1, not 0 over 0 taken as the least (0.1, the lips
    pulled nine tenths of the way to one colour); nor is a spread that is not a number."""
    source = _colour(SKIN, [LIPSTICK] * 4, [LIPSTICK] * 4)
    target = _colour(PALE_SKIN, [PALE_LIPS] * 4, [PALE_LIPS] * 4)
    np.testing.assert_array_equal(lc.lab_spread(source, SKIN), 0.0)
    t = lc.LipTint.of(np.ones(4), target, source)
    assert t.target_lab is not None and lc.skin_ahead(t) > 0  # paler lips: it could recolour
    np.testing.assert_array_equal(t.keep, 1.0)
    assert not t.recolours()
    keep = lc._keep(np.array([0.5, np.nan, 0.0]), np.array([2.0, 1.0, 0.0]))
    np.testing.assert_array_equal(keep, [lc.KEEP_MIN, 1.0, 1.0])


def test_recolour_leaves_the_colours_it_does_not_move_to_the_level():
    """Pixels of a weight but a chroma under :data:`CHROMA_RAMP`'s first (the mouth's dark
    inside, grey) keep their levels exactly: CIELAB and back alone changes some colours by a
    level (found here among 200000 random ones, so the check can fail); the coloured ones
    move."""
    import cv2

    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (400, 500, 3), dtype=np.uint8)
    lab = cv2.cvtColor(img.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    grey = np.hypot(lab[..., 1], lab[..., 2]) < lc.CHROMA_RAMP[0]
    trip = np.clip(cv2.cvtColor(lab, cv2.COLOR_LAB2RGB) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    assert (trip[grey] != img[grey]).any()           # the round trip alone moves some
    out = img.copy()
    lc.recolour_lips(out, np.ones(img.shape[:2], np.float32), np.array([40.0, 30.0, 15.0]),
                     np.full(3, lc.KEEP_MIN))
    np.testing.assert_array_equal(out[grey], img[grey])
    assert (out[~grey] != img[~grey]).all(axis=-1).mean() > 0.9


@pytest.mark.parametrize("seed", range(4))
def test_recolour_kernels_equal_the_numpy_expressions(seed):
    """The recolouring's kernels (the move in CIELAB, the moved pixels written back) against
    the numpy expressions they replaced, bit for bit: random colours (grey and coloured),
    weights of 0, of 1, between and negative, several targets and keeps, a crop's view."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (90, 130, 3), dtype=np.uint8)
    img[:20] = img[:20, :, :1]  # grey rows: chroma under the ramp
    w = rng.random((90, 130)).astype(np.float32)
    w[rng.random(w.shape) < 0.3] = 0.0
    w[rng.random(w.shape) < 0.1] = 1.0
    w[rng.random(w.shape) < 0.05] = -0.5
    target = np.array([40.0, 30.0, 15.0]) + rng.normal(0, 10, 3)
    keep = np.clip(rng.random(3), lc.KEEP_MIN, 1.0)
    for box in ((slice(None), slice(None)), (slice(7, 80), slice(3, 121))):
        want, got = img.copy(), img.copy()
        _old_recolour(want[box], w[box], target, keep)
        lc.recolour_lips(got[box], w[box], target, keep)
        np.testing.assert_array_equal(got, want)
        assert (got != img).any()


def test_tint_mouth_scales_the_masked_pixels_by_their_weight():
    V = np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [30, 30, 0]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    cam = WeakPerspective(1.0, np.eye(3), np.array([1.0, 1.0]))
    raster = rasterize(V, F, cam, (34, 34))
    img = np.full((34, 34, 3), 100, np.uint8)
    mask = raster.tri_id == 0
    tint = lc.LipTint.of(np.ones(4), [1.5, 0.5, 1.0], [1.0, 1.0, 1.0])
    lc.tint_mouth(img, raster, F, tint, mask)
    np.testing.assert_array_equal(img[mask], np.tile([150, 50, 100], (mask.sum(), 1)))
    np.testing.assert_array_equal(img[~mask], 100)
    half = lc.LipTint(np.array([0, 0, 0, 1], np.float32), tint.tint, tint.target_ratio,
                      tint.source_ratio)  # weight 1 at one vertex only: the interpolation
    img2 = np.full((34, 34, 3), 100, np.uint8)
    lc.tint_mouth(img2, raster, F, half, raster.tri_id >= 0)
    w = np.where(raster.tri_id == 1, raster.bary[..., 1], 0.0)  # vertex 3 is F[1][1]
    expect = np.clip(np.rint(100 * (1 + w[..., None] * (tint.tint - 1))), 0, 255)
    cov = raster.tri_id >= 0
    assert np.abs(img2[cov].astype(float) - expect[cov]).max() <= 1


#: A red lipstick's mouth against its skin, and pale lips against theirs (RGB levels).
LIPSTICK, HIGHLIGHT, SKIN = (152, 56, 60), (235, 215, 210), (200, 140, 130)
PALE_LIPS, PALE_SKIN = (158, 96, 98), (200, 150, 140)


def _lipstick_mouth():
    """``(raster, faces, image, parts)``: two triangles of weight-1 lips covering a 34x34
    image (v up: rows 3-33, columns 1-31) whose left 20 columns are lipstick, then 6 of a
    white highlight, then 8 of skin (the lips' band reaching past the lipstick); ``parts``:
    the three column slices."""
    V = np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [30, 30, 0]], float)
    F = np.array([[0, 1, 2], [1, 3, 2]])
    raster = rasterize(V, F, WeakPerspective(1.0, np.eye(3), np.array([1.0, 33.0])), (34, 34))
    img = np.empty((34, 34, 3), np.uint8)
    parts = (slice(0, 20), slice(20, 26), slice(26, 34))
    for sl, c in zip(parts, (LIPSTICK, HIGHLIGHT, SKIN)):
        img[:, sl] = c
    return raster, F, img, parts


def test_a_lipstick_onto_pale_lips_tints_the_lips_and_leaves_highlight_and_skin():
    """A red lipstick's mouth onto pale lips: tint (1.04, 1.59, 1.51), as from
    ``WDA_KatieHill_000`` onto ``driving_d6`` (1.03, 1.60, 1.51). The lipstick takes the whole
    tint; its white highlight and the skin the lips' band covers keep their colour (the whole
    tint, the rule before, turned the highlight (244, 255, 255) and the skin (208, 222, 196):
    G and B above R, cyan-white); the tint each takes, :func:`tint_reach`, is 1, 0 and 0."""
    raster, F, img, (lip, hi, skin) = _lipstick_mouth()
    tint = lc.LipTint.of(np.ones(4), np.add(PALE_LIPS, 1) / np.add(PALE_SKIN, 1),
                         np.add(LIPSTICK, 1) / np.add(SKIN, 1))
    np.testing.assert_allclose(tint.tint, [1.04, 1.59, 1.51], atol=0.005)
    mask = raster.tri_id >= 0
    assert mask[3:, 1:32].all() and mask.sum() == 31 * 31
    out = img.copy()
    lc.tint_mouth(out, raster, F, tint, mask)
    c = out[mask].astype(int)
    assert (c[:, 0] >= c[:, 1]).all() and (c[:, 0] >= c[:, 2]).all()  # no channel crosses R
    np.testing.assert_array_equal(out[:, hi][mask[:, hi]], np.tile(HIGHLIGHT, (31 * 6, 1)))
    np.testing.assert_array_equal(out[:, skin][mask[:, skin]], img[:, skin][mask[:, skin]])
    body = np.clip(np.rint(np.multiply(LIPSTICK, tint.tint)), 0, 255)
    assert np.abs(out[:, lip][mask[:, lip]] - body).max() <= 1
    phi = lc.tint_reach(img, tint, mask)
    np.testing.assert_allclose(phi[:, lip], 1.0)
    np.testing.assert_allclose(phi[:, hi], 0.0)
    np.testing.assert_allclose(phi[:, skin], 0.0, atol=1e-5)  # the skin's place: s exactly


def test_onto_redder_lips_the_whole_tint_as_before():
    """The other way (pale lips onto a lipstick, the skin behind the source's lips along the
    tint's hue): every pixel takes the whole tint, ``1 + w (tint - 1)``, to the level, with
    the clips' samples or without (no recolouring in CIELAB: ``make demo``'s pair)."""
    raster, F, img, _ = _lipstick_mouth()
    for c, sl in ((PALE_LIPS, slice(0, 20)), (PALE_SKIN, slice(26, 34))):
        img[:, sl] = c
    tint = lc.LipTint.of(np.ones(4), np.add(LIPSTICK, 1) / np.add(SKIN, 1),
                         np.add(PALE_LIPS, 1) / np.add(PALE_SKIN, 1))
    mask = raster.tri_id >= 0
    np.testing.assert_array_equal(lc.tint_reach(img, tint, mask), 1.0)
    out = img.copy()
    lc.tint_mouth(out, raster, F, tint, mask)
    expect = np.clip(img * tint.tint.astype(np.float32) + 0.5, 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(out[mask], expect[mask])
    # with the clips' samples (a CIELAB target and keep), no recolouring this way: the same
    samples = lc.LipTint.of(np.ones(4), _colour(SKIN, [LIPSTICK, (120, 30, 40)] * 2),
                            _colour(PALE_SKIN, [PALE_LIPS, (150, 110, 105)] * 2))
    assert samples.target_lab is not None and lc.skin_ahead(samples) < 0
    out, alone = img.copy(), img.copy()
    lc.tint_mouth(out, raster, F, samples, mask)
    lc.tint_mouth(alone, raster, F, dataclasses.replace(samples, target_lab=None, keep=None),
                  mask)
    np.testing.assert_array_equal(out, alone)
    assert (out[mask] != img[mask]).any()


#: A lipstick's upper lip, darker and deeper than its lower one (LIPSTICK), and the mouth's
#: dark inside (RGB levels).
DARK_LIPSTICK, INSIDE = (110, 28, 36), (24, 12, 13)


def _two_lips_mouth():
    """``(raster, faces, image, parts)`` of :func:`_lipstick_mouth` with its columns: a dark
    lipstick (the upper lip), the lipstick (the lower), a white highlight, the mouth's dark
    inside, skin."""
    raster, F, img, _ = _lipstick_mouth()
    parts = (slice(0, 10), slice(10, 18), slice(18, 22), slice(22, 26), slice(26, 34))
    for sl, c in zip(parts, (DARK_LIPSTICK, LIPSTICK, HIGHLIGHT, INSIDE, SKIN)):
        img[:, sl] = c
    return raster, F, img, parts


def _de_to(img, mask, lab) -> np.ndarray:
    """CIE76 ΔE of the masked pixels against one CIELAB colour."""
    import cv2

    x = cv2.cvtColor(img.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)[mask]
    return np.linalg.norm(x - np.asarray(lab, np.float32), axis=-1)


def test_a_lipstick_takes_the_pale_lips_colour_on_both_lips():
    """A lipstick whose upper lip is darker and deeper (110, 28, 36) than its lower (152, 56,
    60), onto pale lips of a narrow spread: the tint alone leaves the upper lip red (at most
    ΔE 14.4 from the target's lip colour on the source's skin, the lower 6.4: measured; the
    tint maps the lips' median, between the two); with the clips' samples both lips come
    within 2 (measured 1.34 and 1.60: ``keep`` 0.1, a tenth of the distance, and the 8-bit
    rounding; the lower lip, paler than the clip's lip colour, between the two, takes 0.84 of
    the tint and of the move, :func:`tint_reach`: 0.72 when that was measured from the
    frame's median, here the lower lip's). The highlight is not
    touched; the mouth's dark inside (grey, which the tint moves) is as the tint alone
    leaves it."""
    raster, F, img, (up, low, hi, inside, skin) = _two_lips_mouth()
    mask = raster.tri_id >= 0
    source = _colour(SKIN, [DARK_LIPSTICK, DARK_LIPSTICK, LIPSTICK, LIPSTICK])
    target = _colour(PALE_SKIN, [PALE_LIPS] * 2 + [np.add(PALE_LIPS, 6)] * 2)
    tint = lc.LipTint.of(np.ones(4), target, source)
    np.testing.assert_allclose(tint.keep, lc.KEEP_MIN)
    alone = img.copy()       # the same tint without the recolouring
    lc.tint_mouth(alone, raster, F, dataclasses.replace(tint, target_lab=None, keep=None),
                  mask)
    out = img.copy()
    lc.tint_mouth(out, raster, F, tint, mask)
    m = {k: np.zeros_like(mask) for k in ("up", "low")}
    m["up"][:, up], m["low"][:, low] = mask[:, up], mask[:, low]
    before = {k: _de_to(alone, v, tint.target_lab).max() for k, v in m.items()}
    after = {k: _de_to(out, v, tint.target_lab).max() for k, v in m.items()}
    assert before["up"] > 12 and before["low"] > 6, before
    assert after["up"] < 2.0 and after["low"] < 2.0, after  # keep 0.1: a tenth, and rounding
    np.testing.assert_array_equal(out[:, hi], img[:, hi])
    assert (alone[:, inside][mask[:, inside]] != INSIDE).any()  # the tint reached it
    np.testing.assert_array_equal(out[:, inside], alone[:, inside])
    # the skin the lips' band covers takes a little of the tint (tint_reach 0.16): the
    # recolouring takes it no further from its colour than the tint alone did
    sk = np.zeros_like(mask)
    sk[:, skin] = mask[:, skin]
    moved = {k: _de_to(v, sk, _lab(SKIN)) for k, v in (("alone", alone), ("new", out))}
    assert (moved["new"] <= moved["alone"] + 1e-3).all(), moved


#: Lips pressed shut: the lipstick deeper than the clip's (``WDA_KatieHill_000`` at its frames
#: 87-90: a median of (138, 40, 39) against (156, 71, 74) in its other frames).
PRESSED = (110, 22, 26)


def test_lips_pressed_shut_take_the_targets_colour_as_the_usual_ones_do():
    """A red lipstick's clip onto pale lips with the open pair's ``keep`` (0.37, 0.45, 0.13);
    a frame whose lips are mostly pressed shut, deeper than the clip's lipstick (20 columns,
    the rest of its lipstick 6, skin 8), against a frame of the clip's lipstick. Before,
    ``tint_reach`` measured from the frame's own median (the pressed red): the clip's lipstick
    lay towards the skin, took 0.015 of the tint and stayed 15.3 from the target's colour in
    ``a, b`` (0.53 in the usual frame), red. Now it is measured from the clip's lip colour
    (``source_lips``): every lip pixel takes the whole tint in both frames, and the lipstick
    comes out the same in both, to the level."""
    raster, F, img, _ = _lipstick_mouth()
    mask = raster.tri_id >= 0
    source = _colour(SKIN, [LIPSTICK] * 3 + [(140, 48, 52)], [LIPSTICK, (160, 64, 66)] * 2)
    tint = dataclasses.replace(
        lc.LipTint.of(np.ones(4), _colour(PALE_SKIN, [PALE_LIPS, (150, 92, 95)] * 2), source),
        keep=np.array([0.37, 0.45, 0.13]))
    assert tint.recolours()
    lips = mask.copy()
    lips[:, 26:] = False
    out = {}
    for name, deep in (("usual", LIPSTICK), ("pressed", PRESSED)):
        im = img.copy()
        im[:, :20], im[:, 20:26], im[:, 26:] = deep, LIPSTICK, SKIN
        np.testing.assert_array_equal(lc.tint_reach(im, tint, mask)[lips], 1.0)
        out[name] = im.copy()
        lc.tint_mouth(out[name], raster, F, tint, mask)
    lipstick = (slice(5, 30), slice(21, 25))
    np.testing.assert_array_equal(out["pressed"][lipstick], out["usual"][lipstick])
    ab = lc.rgb_to_lab(out["pressed"][lipstick].reshape(-1, 3))[:, 1:] - tint.target_lab[1:]
    assert np.median(np.linalg.norm(ab, axis=1)) < 1.0      # measured 0.53


def _rewrite(scene_model, clips, weights, lip_colour):
    target, source, track = clips
    topo = weights[0]
    return list(rc.rewrite_frames(target, track, track, scene_model,
                                  mouth_source=rc.MouthSource(source, track), topo=topo,
                                  options=RewriteOptions(lip_colour=lip_colour, lips="model",
                                                         eyes="target", jaw="frame",
                                                         mouth="frame", blend="none")))


def test_the_result_takes_the_targets_lipstick(quick_model, clips, weights):
    """Measured (mean absolute error on the lips' pixels of weight 1, against the painted
    target): 35.1 levels with the source's colour, 1.6 with the target's."""
    target, _, track = clips
    topo, w, _ = weights
    errs = {}
    for mode in ("source", "target"):
        outs = _rewrite(quick_model, clips, weights, mode)
        e = []
        for i, o in enumerate(outs):
            V = topology.close_mouth(quick_model.synthesize(track.weights_at(i)), topo)
            r = rasterize(V, topo.faces, track.camera(i), (target.shape[2], target.shape[1]))
            lips = (interpolate_vertex_values(r, topo.faces, w) > 0.999) & o.mouth_mask
            assert lips.sum() > 40
            e.append(np.abs(o.image[lips].astype(float) - target[i][lips]).mean())
        errs[mode] = float(np.mean(e))
    assert errs["target"] < 5.0, errs
    assert errs["source"] > 4 * errs["target"], errs


def test_a_lipstick_source_onto_plain_lips(quick_model, clips, weights):
    """The other way: the painted lips as the source, the plain ones the target (the tint
    and the recolouring in CIELAB, :func:`recolour_lips`). Measured (mean absolute error on
    the lips' pixels of weight 1, against the plain target): 35.1 levels with the source's
    colour, 2.11 with the target's (2.21 with the tint alone: a paint per channel is what a
    tint undoes; the recolouring must not undo that)."""
    target, source, track = clips
    topo, w, _ = weights
    errs = {}
    for mode in ("source", "target"):
        outs = _rewrite(quick_model, (source, target, track), weights, mode)
        e = []
        for i, o in enumerate(outs):
            V = topology.close_mouth(quick_model.synthesize(track.weights_at(i)), topo)
            r = rasterize(V, topo.faces, track.camera(i), (target.shape[2], target.shape[1]))
            lips = (interpolate_vertex_values(r, topo.faces, w) > 0.999) & o.mouth_mask
            e.append(np.abs(o.image[lips].astype(float) - source[i][lips]).mean())
        errs[mode] = float(np.mean(e))
    assert errs["target"] < 2.5, errs
    assert errs["source"] > 10 * errs["target"], errs


def test_the_clip_tint_recovers_the_paint_and_is_one_for_the_same_texture(quick_model, clips,
                                                                         weights):
    """Measured: (1.232, 0.561, 0.713) for the paint (1.25, 0.55, 0.7); exactly 1 for the
    target's own frames as the source."""
    target, source, track = clips
    topo = weights[0]
    for src, expect, tol in ((source, PAINT, 0.04), (target, np.ones(3), 1e-9)):
        r = rc._ClipRenderer.build(target, track, track, quick_model,
                                   RewriteOptions(lips="model", eyes="target", jaw="frame"),
                                   mouth_source=rc.MouthSource(src, track), topo=topo)
        np.testing.assert_allclose(r.lip_tint.tint, expect, atol=tol)


def test_source_colour_and_bad_mode():
    assert RewriteOptions().lip_colour == "target"
    with pytest.raises(RewriteError, match="lip_colour must be one of target, source"):
        RewriteOptions(lip_colour="lipstick")


def test_the_option_reaches_the_rewrite_from_transfer_and_batch_transfer():
    """``--lip-colour`` (and ``--lips``, which batch transfer dropped before) from the command
    line to the :class:`RewriteOptions` of ``transfer`` and of each ``batch transfer`` job."""
    from facetransfer.batch.jobs import rewrite_options as job_options
    from facetransfer.cli.batch import transfer_settings
    from facetransfer.cli.main import build_parser
    from facetransfer.cli.transfer import rewrite_options

    p = build_parser()
    base = ["transfer", "--target", "t.mp4", "--expression-from", "s.mp4", "--out", "o.mp4"]
    assert rewrite_options(p.parse_args(base)).lip_colour == "target"
    o = rewrite_options(p.parse_args(base + ["--lip-colour", "source", "--lips", "model"]))
    assert (o.lip_colour, o.lips) == ("source", "model")
    batch = ["batch", "transfer", "--manifest", "pairs.csv", "--out", "d"]
    o = job_options(transfer_settings(p.parse_args(batch)))
    assert (o.lip_colour, o.lips) == ("target", "residual")
    o = job_options(transfer_settings(p.parse_args(batch + ["--lip-colour", "source",
                                                            "--lips", "model"])))
    assert (o.lip_colour, o.lips) == ("source", "model")


def test_the_demo_command_passes_every_rewrite_option(monkeypatch):
    """``facetransfer demo`` accepts the rewrite options of ``transfer``; each reaches
    :func:`facetransfer.demo.run_demo` (``--lips`` and ``--lip-colour`` were accepted and
    dropped before)."""
    import facetransfer.cli.demo as cli_demo
    import facetransfer.demo as demo
    from facetransfer.cli.main import build_parser

    seen = {}

    class Stop(Exception):
        pass

    def fake(out, **kw):
        seen.update(kw)
        raise Stop

    monkeypatch.setattr(demo, "run_demo", fake)
    monkeypatch.setattr(cli_demo, "load_model_and_mediapipe", lambda *a: None)
    args = build_parser().parse_args(["demo", "--out", "o", "--lips", "model", "--lip-colour",
                                      "source", "--jaw", "frame", "--eyes", "target"])
    with pytest.raises(Stop):
        cli_demo.run_demo(args)
    opts = seen["options"]
    assert (opts.lips, opts.lip_colour, opts.jaw, opts.eyes) == ("model", "source", "frame",
                                                                 "target")
    # a bad one is refused before any work (the model is not loaded)
    monkeypatch.setattr(cli_demo, "load_model_and_mediapipe", lambda *a: pytest.fail("loaded"))
    for what, bad in (("lip_colour", "lipstick"), ("lips", "painted")):
        args = build_parser().parse_args(["demo", "--out", "o"])
        setattr(args, what, bad)   # past argparse's choices, as a library caller could
        with pytest.raises(RewriteError, match=f"{what} must be one of"):
            cli_demo.run_demo(args)

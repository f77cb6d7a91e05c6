"""The shading field of a pasted region (facetransfer.patch._shading_field, issue 13): the
reference frame's texture brought to the current frame's low-frequency shading, unlike pixels
left out."""

from __future__ import annotations

import numpy as np

from facetransfer import patch

H, W = 120, 150


def _skin() -> np.ndarray:
    """A textured skin patch (H, W, 3) float32: a colour with fine noise (the detail the field
    must keep)."""
    rng = np.random.default_rng(0)
    base = np.array([190.0, 140.0, 115.0], np.float32)
    return (base * (1 + 0.05 * rng.standard_normal((H, W, 1)))).astype(np.float32)


def _shading() -> np.ndarray:
    """A smooth shading (H, W, 1): a bump 15 % brighter left of the middle, 8 % darker at
    the right edge (no plane fits it)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    bump = 0.15 * np.exp(-((xx - 50) ** 2 + (yy - 60) ** 2) / (2 * 25.0 ** 2))
    return (1 + bump - 0.08 * (xx / W) ** 4)[..., None]


def test_the_field_is_the_smooth_shading_between_the_two():
    part = _skin()
    face = np.clip(np.rint(part * _shading()), 0, 255).astype(np.uint8)
    g = patch._shading_field(part, face, np.ones((H, W), bool))
    assert g.shape == (H, W, 3) and g.dtype == np.float32
    inner = (slice(15, H - 15), slice(15, W - 15))
    want = np.repeat(_shading(), 3, axis=2)[inner]
    # the noise averages out: within 1.5 % of the true shading, away from the border
    np.testing.assert_allclose(g[inner], want, atol=0.015)
    # and it is smooth: the part's detail stays (corrected, it is the face to rounding)
    err = np.abs(part * g - face)[inner]
    assert np.median(err) < 2.0


def test_unlike_pixels_do_not_count_and_nothing_to_compare_gives_none():
    part = _skin()
    face = np.clip(np.rint(part * 1.1), 0, 255).astype(np.uint8)
    hair = face.copy()
    hair[40:80, 60:100] = (40, 30, 25)  # hair in the current frame: 4x darker
    g = patch._shading_field(part, hair, np.ones((H, W), bool))
    # beside the hair the gain is the skin's 1.1, not pulled down by the hair
    np.testing.assert_allclose(g[40:80, 20:50], 1.1, atol=0.02)
    np.testing.assert_allclose(g[85:110, 60:100], 1.1, atol=0.02)
    # only the compared pixels count: a face 30 % brighter outside them changes nothing
    valid = np.zeros((H, W), bool)
    valid[:, : W // 2] = True
    bright = face.copy()
    bright[:, W // 2 + 10:] = np.clip(part[:, W // 2 + 10:] * 1.3, 0, 255).astype(np.uint8)
    g2 = patch._shading_field(part, bright, valid)
    np.testing.assert_allclose(g2[:, : W // 2 - 10], 1.1, atol=0.02)
    assert patch._shading_field(part, face, np.zeros((H, W), bool)) is None
    assert patch._shading_field(part[:2, :2], face[:2, :2], np.ones((2, 2), bool)) is None


def test_the_gain_is_clipped():
    part = _skin()
    face = np.clip(np.rint(part * 1.5), 0, 255).astype(np.uint8)  # beyond the limit: unlike
    assert patch._shading_field(part, face, np.ones((H, W), bool)) is None
    face = np.clip(np.rint(part * 1.2), 0, 255).astype(np.uint8)
    g = patch._shading_field(part, face, np.ones((H, W), bool))
    assert g.max() <= patch.SHADING_RANGE[1] and g.min() >= patch.SHADING_RANGE[0]
    np.testing.assert_allclose(np.median(g), 1.2, atol=0.02)


def _hue() -> np.ndarray:
    """A smooth change of hue (H, W, 3) of product 1 over the channels: red up and blue
    down by up to 10 % toward the right (another light on the same skin)."""
    xx = np.mgrid[0:H, 0:W][1].astype(np.float32) / W
    lr = np.stack([0.1 * xx, -0.02 * xx, -0.08 * xx], axis=2)
    return np.exp(lr - lr.mean(axis=2, keepdims=True))


def test_the_hue_field_carries_the_hue_and_leaves_the_brightness():
    """patch._hue_field: the part takes the face's smooth hue; a brightness difference (here
    the face 30 % darker: the region's own shadow, another exposure) stays the part's, and
    blocks unlike skin (hair) do not count."""
    part = _skin()
    face = np.clip(np.rint(part * _hue() * 0.7), 0, 255).astype(np.uint8)
    hair = face.copy()
    hair[:, :30] = (40, 30, 25)
    for f in (face, hair):
        g = patch._hue_field(part, f, np.ones((H, W), bool), 10.0)
        assert g.shape == (H, W, 3) and g.dtype == np.float32
        inner = (slice(12, H - 12), slice(45, W - 12))
        np.testing.assert_allclose(g[inner], _hue()[inner], atol=0.015)
        # of product 1: the brightness is left to the gain (to the second order of the step
        # between neighbouring blocks, which the field's linear interpolation averages: the
        # held blocks under the hair take the region's hue, 5 % from the field's beside them)
        np.testing.assert_allclose(np.log(g).sum(axis=2), 0, atol=5e-4)
    # nothing to compare: no field
    assert patch._hue_field(part, face, np.zeros((H, W), bool), 10.0) is None


def test_a_wide_hole_of_the_compared_pixels_takes_the_regions_hue():
    """A hole of the compared pixels wider than the field's reach (where the jaw's appearance
    rule took the reference frame: a tongue, a lip pressed out) takes the hue of all the
    compared blocks, here the face's warm tint (R over G 1.08), not the part's own (1: before,
    the field was held at 1 there, and the reference frame's skin pasted where a tongue was
    kept its hue in a warmer frame)."""
    part = _skin()
    tint = np.array([1.08, 1.0, 0.92], np.float32)
    face = np.clip(np.rint(part * tint * 0.8), 0, 255).astype(np.uint8)
    valid = np.ones((H, W), bool)
    valid[10:90, 40:120] = False                          # 80 px: beyond ~1.6 sigma inside
    g = patch._hue_field(part, face, valid, 10.0)
    want = tint / np.exp(np.log(tint).mean())
    np.testing.assert_allclose(g[45:55, 75:85].reshape(-1, 3), np.tile(want, (100, 1)),
                               atol=0.01)
    np.testing.assert_allclose(g[valid].reshape(-1, 3).mean(0), want, atol=0.01)
    part[20, 20, 0] = np.nan                  # a NaN compared: the hole is held at 1
    np.testing.assert_array_equal(patch._hue_field(part, face, valid, 10.0)[50, 80], 1.0)


def _shading_field_numpy(part, face, valid, sigma=patch.SHADING_SIGMA):
    """:func:`facetransfer.patch._shading_field` with its masking and holding as the numpy
    expressions they were before the forty-fifth session (the reference of its kernels)."""
    import cv2

    grid = patch._coarse(part, face, valid)
    if grid is None:
        return None
    f1, p1, m = grid
    lim = float(np.exp(patch.SHADING_LIMIT))
    ok = cv2.inRange(cv2.divide(f1, p1), (1.0 / lim,) * 3, (lim,) * 3) > 0
    m[~ok | (m < 0.5)] = 0.0
    if not m.any():
        return None
    num, den, wt = patch._weighted_sums(f1, p1, m, sigma)
    g = cv2.divide(num, np.maximum(den, 1e-6))
    np.copyto(g, 1.0, where=(wt <= 0.05)[..., None])
    np.clip(g, *patch.SHADING_RANGE, out=g)
    return cv2.resize(g, (valid.shape[1], valid.shape[0]), interpolation=cv2.INTER_LINEAR)


def _hue_field_numpy(part, face, valid, sigma):
    """:func:`facetransfer.patch._hue_field` likewise (the reference of its kernels)."""
    import cv2

    grid = patch._coarse(part, face, valid)
    if grid is None:
        return None
    f1, p1, m = grid
    lr = cv2.subtract(cv2.log(f1), cv2.log(p1))
    grey = cv2.transform(lr, patch._THIRDS)
    lim = patch.HUE_LIMITS
    ok = cv2.inRange(cv2.subtract(lr, cv2.merge([grey, grey, grey])), (-lim[1],) * 3,
                     (lim[1],) * 3) > 0
    ok &= cv2.inRange(grey, -lim[0], lim[0]) > 0
    m[~ok | (m < 0.5)] = 0.0
    if not m.any():
        return None
    num, den, wt = patch._weighted_sums(f1, p1, m, sigma)
    lg = cv2.subtract(cv2.log(cv2.max(num, 1e-6)), cv2.log(cv2.max(den, 1e-6)))
    mean = cv2.transform(lg, patch._THIRDS)
    g = cv2.exp(cv2.subtract(lg, cv2.merge([mean, mean, mean])))
    # held: the hue of all compared blocks (the ratio of their sums, of product 1)
    ratio = np.log((f1 * m[..., None]).sum(axis=(0, 1), dtype=np.float64)) - \
        np.log((p1 * m[..., None]).sum(axis=(0, 1), dtype=np.float64))
    held = np.exp(ratio - ratio.mean()).astype(np.float32)
    np.copyto(g, held, where=(wt <= 0.05)[..., None])
    np.clip(g, *patch.HUE_RANGE, out=g)
    return cv2.resize(g, (valid.shape[1], valid.shape[0]), interpolation=cv2.INTER_LINEAR)


def test_the_fields_kernels_equal_their_numpy_expressions():
    """The shading and hue fields (their blocks' masking and the held, clipped gain as
    kernels) against the numpy expressions, bit for bit: a shaded, tinted skin with unlike
    patches (some blocks refused, some clipped, thin neighbourhoods held at 1), sparse and
    absent compared pixels (None), and a box smaller than a block."""
    rng = np.random.default_rng(45)
    skin = _skin()
    face = np.clip(skin * _shading() * np.array([1.3, 1.0, 0.8], np.float32), 0, 255)
    face = face.astype(np.uint8)
    face[30:50, 20:60] = (20, 20, 20)             # hair: refused blocks
    part = skin.copy()
    part[80:100, 100:140] *= 0.6                  # a darker patch: clipped gains
    for valid in (np.ones((H, W), bool), rng.random((H, W)) < 0.6,
                  rng.random((H, W)) < 0.02, np.zeros((H, W), bool)):
        for ours, ref, args in ((patch._shading_field, _shading_field_numpy, ()),
                                (patch._hue_field, _hue_field_numpy, (8.0,))):
            got, want = ours(part, face, valid, *args), ref(part, face, valid, *args)
            assert (got is None) == (want is None)
            if want is not None:
                np.testing.assert_array_equal(got, want)
    small = np.ones((2, 5), bool)
    assert patch._shading_field(part[:2, :5], face[:2, :5], small) is None

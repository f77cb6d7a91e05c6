"""Tests of facetransfer.composite: Poisson image editing (Pérez et al. 2003) and colour matching."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.composite import (CompositeError, composite_face, feather_mask, match_color,
                                    poisson_blend, poisson_blend_multi)
from facetransfer.errors import ShapeError

H, W = 96, 128


def _target(seed=0):
    """Smooth colour ramps plus a little noise: gradients everywhere, no clipping."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W]
    t = np.stack([40 + xx * 1.2, 30 + yy * 1.5, 110 + 40 * np.sin(xx / 13.0)], -1)
    return np.clip(t + rng.normal(0, 3, t.shape), 0, 255).astype(np.uint8)


def _smooth_source(seed=1):
    rng = np.random.default_rng(seed)
    s = np.clip(rng.normal(128, 40, (H, W, 3)), 0, 255).astype(np.uint8)
    return cv2.GaussianBlur(s, (0, 0), 3)


def _disc(cx, cy, r):
    yy, xx = np.mgrid[:H, :W]
    return (xx - cx) ** 2 + (yy - cy) ** 2 < r * r


@pytest.mark.parametrize("method", ["solver", "auto"])
def test_identity_source_equals_target(method):
    t = _target()
    m = _disc(60, 50, 25)
    out = poisson_blend(t, t, m, method=method)
    if method == "solver":
        np.testing.assert_array_equal(out, t)
    else:  # OpenCV: rounding inside its solver, at most 1 grey level
        assert np.abs(out.astype(int) - t).max() <= 1


def test_constant_offset_source_returns_target():
    """Guidance = source gradients = target gradients, so f = target (Pérez Eq. 7)."""
    t = _target()
    s = (t.astype(int) + 37).clip(0, 255).astype(np.uint8)
    assert (t.astype(int) + 37 <= 255).all()  # no clipping: gradients agree exactly
    for m in (_disc(60, 50, 25), np.pad(np.ones((H - 20, W - 30), bool), ((10, 10), (15, 15)))):
        out = poisson_blend(s, t, m, method="solver")
        assert np.abs(out.astype(int) - t).max() <= 1


def test_pasted_content_keeps_source_gradients():
    """A source pattern is carried over with its gradients; the boundary matches the target."""
    t = np.full((H, W, 3), 100, np.uint8)
    s = t.copy()
    s[40:56, 50:70] = 160  # a bright square inside the mask
    m = _disc(60, 48, 25)
    out = poisson_blend(s, t, m, method="solver").astype(int)
    # the square's step (60 levels) survives; the surrounding stays at the target level 100
    assert abs((out[48, 60] - out[48, 40]).mean() - 60) <= 1
    assert np.abs(out[~m] - 100).max() == 0


def test_solver_matches_seamless_clone_on_interior_region():
    """Measured: mean |ours - OpenCV| about 2.8 grey levels on this scene (OpenCV solves over the
    bounding box with its own boundary treatment); bound 5 inside, 1 % of pixels over 15."""
    t, s = _target(), _smooth_source()
    m = _disc(64, 48, 30)
    ours = poisson_blend(s, t, m, method="solver").astype(int)
    cv = poisson_blend(s, t, m, method="opencv").astype(int)
    d = np.abs(ours - cv)[m]
    assert d.mean() < 5.0
    assert np.mean(d > 15) < 0.01
    # and both differ clearly from a plain paste (the blend did something)
    assert np.abs(ours - s)[m].mean() > 10


def test_auto_chooses_solver_where_opencv_does_not_serve():
    t = _target()
    s = (t.astype(int) + 20).clip(0, 255).astype(np.uint8)
    two = _disc(30, 30, 12) | _disc(95, 60, 15)
    border = np.zeros((H, W), bool)
    border[:, :30] = True
    for m in (two, border):
        with pytest.raises(CompositeError):
            poisson_blend(s, t, m, method="opencv")
        out = poisson_blend(s, t, m, method="auto")
        assert np.abs(out.astype(int) - t).max() <= 1
        np.testing.assert_array_equal(out[~m], t[~m])


def test_whole_image_region_is_solvable():
    t = _target()
    s = (t.astype(int) + 10).clip(0, 255).astype(np.uint8)
    out = poisson_blend(s, t, np.ones((H, W), bool))
    # no Dirichlet boundary: defined up to a constant, tied to the target's mean
    assert np.abs(out.astype(int) - t).max() <= 1


def test_multiple_sources_each_region_from_its_source():
    """Face from source A, mouth from source B (Fig. 7D): each keeps its own gradients."""
    t = np.full((H, W, 3), 90, np.uint8)
    a = t.copy()
    a[20:30, 20:30] = 150   # feature inside region A
    b = t.copy()
    b[60:66, 80:96] = 30    # feature inside region B
    ma = _disc(25, 25, 18)
    mb = _disc(88, 63, 16)
    out = poisson_blend_multi(t, [(a, ma), (b, mb)]).astype(int)
    assert abs(out[25, 25, 0] - out[25, 36, 0] - 60) <= 1
    assert abs(out[63, 88, 0] - out[63, 76, 0] + 60) <= 1
    np.testing.assert_array_equal(out[~(ma | mb)], t[~(ma | mb)])


def test_adjacent_regions_from_two_sources():
    """Two touching regions with different constant offsets of the target: both return target."""
    t = _target()
    a = (t.astype(int) + 30).clip(0, 255).astype(np.uint8)
    b = (t.astype(int) - 25).clip(0, 255).astype(np.uint8)
    ma = np.zeros((H, W), bool)
    ma[20:70, 20:64] = True
    mb = np.zeros((H, W), bool)
    mb[20:70, 64:110] = True
    out = poisson_blend_multi(t, [(a, ma), (b, mb)])
    assert np.abs(out.astype(int) - t).max() <= 1


def test_feathered_mask_and_exact_outside():
    t, s = _target(), _smooth_source()
    m = _disc(64, 48, 20)
    alpha = feather_mask(m, 4.0)
    assert alpha.dtype == np.float32 and alpha.min() == 0 and alpha.max() == 1
    assert (alpha[m] >= 0.5).all() and (alpha[~m] <= 0.5).all()
    assert (alpha > 0).sum() > m.sum()  # grows beyond the hard mask
    out = poisson_blend(s, t, alpha)
    np.testing.assert_array_equal(out[alpha == 0], t[alpha == 0])
    # offset source with a feathered mask still reproduces the target
    s2 = (t.astype(int) + 15).clip(0, 255).astype(np.uint8)
    assert np.abs(poisson_blend(s2, t, alpha).astype(int) - t).max() <= 1


def test_mixed_gradients_keep_stronger_target_texture():
    t = _target()
    flat = np.full_like(t, 128)
    m = _disc(64, 48, 25)
    out = poisson_blend(flat, t, m, mixed=True, method="solver")
    # a flat source has zero gradients, so mixed blending keeps the target's everywhere
    assert np.abs(out.astype(int) - t).max() <= 1
    plain = poisson_blend(flat, t, m, mixed=False, method="solver")
    assert np.abs(plain.astype(int) - t)[m].mean() > 5


def test_match_color_matches_lab_statistics():
    rng = np.random.default_rng(3)
    s = np.clip(rng.normal((90, 120, 160), 12, (H, W, 3)), 0, 255).astype(np.uint8)
    t = _target()
    m = _disc(64, 48, 30)
    out = match_color(s, t, m)
    lab = lambda x: cv2.cvtColor(x.astype(np.float32) / 255, cv2.COLOR_RGB2LAB)[m]
    np.testing.assert_allclose(lab(out).mean(0), lab(t).mean(0), atol=1.0)
    np.testing.assert_allclose(lab(out).std(0), lab(t).std(0), rtol=0.1, atol=0.5)


def test_composite_face_outside_equals_target_and_mouth_source():
    t = _target()
    face = _smooth_source()
    fm = _disc(64, 48, 32)
    fm &= ~_disc(52, 38, 5)  # eye hole: the target shows through
    mouth_src = t.copy()
    mouth_src[60:64, 56:72] = 20
    mm = _disc(64, 62, 9)
    out = composite_face(t, face, fm, mouth_source=mouth_src, mouth_mask=mm, feather=3)
    grown = feather_mask(fm, 3) > 0
    grown |= feather_mask(mm, 3) > 0
    np.testing.assert_array_equal(out[~grown], t[~grown])
    assert not grown[38, 52]  # the eye hole's centre keeps the target's own pixel
    np.testing.assert_array_equal(out[38, 52], t[38, 52])
    # the dark mouth bar from the mouth source survives with its contrast
    assert out[62, 64].mean() < out[55, 64].mean() - 40
    assert not np.array_equal(out[fm], t[fm])


def test_composite_face_empty_mask_returns_target():
    t = _target()
    out = composite_face(t, _smooth_source(), np.zeros((H, W), bool))
    np.testing.assert_array_equal(out, t)


def test_bad_inputs():
    t = _target()
    m = _disc(64, 48, 20)
    with pytest.raises(ShapeError):
        poisson_blend(t[:, :10], t, m)
    with pytest.raises(ShapeError):
        poisson_blend(t, t, m[:10])
    with pytest.raises(CompositeError):
        poisson_blend(t, t, m, method="magic")
    with pytest.raises(CompositeError):
        poisson_blend(t, t, m.astype(float) * 2)
    with pytest.raises(ShapeError):
        poisson_blend(t[..., 0], t, m)
    with pytest.raises(CompositeError):
        poisson_blend_multi(t, [])
    with pytest.raises(CompositeError):
        composite_face(t, t, m, mouth_source=t)
    with pytest.raises(ShapeError):
        composite_face(t, t, m.astype(np.uint8))
    with pytest.raises(CompositeError):
        feather_mask(m, -1)
    with pytest.raises(ShapeError):
        feather_mask(m.astype(float), 2)
    with pytest.raises(CompositeError):
        match_color(t, t, np.zeros((H, W), bool))
    with pytest.raises(ValueError):  # all errors are ValueErrors for the CLI
        poisson_blend(t, t, np.full((H, W), np.nan))


def test_composite_face_ignores_rendered_background():
    """A rendered face on black: pixels outside face_mask must not leak a dark seam."""
    t = _target()
    fm = _disc(64, 48, 28)
    face = np.where(fm[..., None], (t.astype(int) + 25).clip(0, 255), 0).astype(np.uint8)
    for feather in (0.0, 4.0):
        out = composite_face(t, face, fm, color_match=False, feather=feather)
        assert np.abs(out.astype(int) - t).max() <= 1


def test_valid_mask_uses_target_gradient_on_invalid_edges():
    """Pérez by default (source difference across the outline); with ``valid`` the target's."""
    t = _target()
    m = _disc(64, 48, 20)
    s = np.where(m[..., None], (t.astype(int) + 40).clip(0, 255), 0).astype(np.uint8)
    plain = poisson_blend_multi(t, [(s, m)])          # black outside: a step at the outline
    valid = poisson_blend_multi(t, [(s, m, m)])
    assert np.abs(valid.astype(int) - t).max() <= 1
    assert np.abs(plain.astype(int) - t)[m].mean() > 20
    with pytest.raises(ShapeError):
        poisson_blend_multi(t, [(s, m, m.astype(np.uint8))])


def test_membrane_crop_is_the_masks_box_grown_by_the_margin_and_clipped():
    from facetransfer.composite import MEMBRANE_MARGIN, membrane_crop

    mask = np.zeros((40, 50), bool)
    assert membrane_crop(mask) is None
    mask[10:14, 20:31] = True
    assert membrane_crop(mask, 3) == (slice(7, 17), slice(17, 34))
    m = MEMBRANE_MARGIN
    assert membrane_crop(mask) == (slice(10 - m, 14 + m), slice(20 - m, 31 + m))
    mask[0, 49] = True                                   # the box reaches the image's corner
    assert membrane_crop(mask, 5) == (slice(0, 19), slice(15, 50))

"""The per-frame kernels of the rewrite (issue 13, speed) against their references.

Each numba kernel or OpenCV shortcut that replaced numpy code in the per-frame render is
compared with the formulation it replaced (written out here as the reference) or with a
synthetic ground truth: the feather distances with ``cv2.distanceTransform``, the outline's
pixels with ``np.nonzero``, push-pull with the numpy pyramid, the gain fit with the numpy
normal equations, the rejection with ``log1p``, and the membrane's 4 Jacobi sweeps with the
exact harmonic answer on a disc.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer import composite, patch
from facetransfer.composite import _nonzero, feather_alpha, membrane_blend
from facetransfer.texture import fill_holes


def _blobs(rng, shape, smooth=3.0, level=0.5) -> np.ndarray:
    """A random (H, W) bool mask of smooth blobs."""
    return cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), smooth) > level


@pytest.mark.parametrize("feather", [0.5, 2.0, 3.0, 4.0])
@pytest.mark.parametrize("edge_outside", [False, True])
def test_feather_alpha_equals_the_distance_transform(feather, edge_outside):
    rng = np.random.default_rng(int(feather * 10) + edge_outside)
    m = _blobs(rng, (61, 73), level=0.48)
    m[:, :4] = True  # touches the crop's edge
    m[20:23, 30:33] = False  # a small hole
    m8 = m.view(np.uint8)
    if edge_outside:
        d = cv2.distanceTransform(np.pad(m8, 1), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    else:
        d = cv2.distanceTransform(m8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    ref = np.clip(d / feather, 0.0, 1.0)
    a = feather_alpha(m, feather, edge_outside=edge_outside)
    assert a.dtype == np.float32 and a.shape == m.shape
    np.testing.assert_allclose(a, ref, rtol=0, atol=1e-6)
    assert (a[~m] == 0).all() and (a[m] > 0).all()


def test_nonzero_equals_numpy():
    rng = np.random.default_rng(3)
    m = rng.random((37, 53)) < 0.3
    for mask in (m, np.zeros((5, 7), bool), np.ones((4, 3), bool)):
        ry, rx = _nonzero(mask)
        ey, ex = np.nonzero(mask)
        np.testing.assert_array_equal(ry, ey)
        np.testing.assert_array_equal(rx, ex)


#: the mean of the 4 neighbours: the membrane's Jacobi sweep as a 3x3 filter
_FOUR_NEIGHBOURS = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)


def _push_pull_reference(tex: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The numpy push-pull that the kernels replaced (2x2 block means by INTER_AREA, bilinear
    push by INTER_LINEAR, blended by the weight)."""
    H, W = w.shape
    if H <= 1 and W <= 1:
        return tex
    Hp, Wp = H + (H % 2), W + (W % 2)
    cp = np.zeros((Hp, Wp, 3), np.float32)
    wp = np.zeros((Hp, Wp), np.float32)
    cp[:H, :W] = tex * w[..., None]
    wp[:H, :W] = w
    c2 = cv2.resize(cp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    w2 = cv2.resize(wp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    c2 = c2.reshape(Hp // 2, Wp // 2, 3)
    coarse = np.divide(c2, w2[..., None], out=np.zeros_like(c2), where=w2[..., None] > 0)
    coarse = _push_pull_reference(coarse, np.minimum(w2, 1.0))
    up = cv2.resize(coarse, (Wp, Hp), interpolation=cv2.INTER_LINEAR)[:H, :W]
    a = np.clip(w, 0.0, 1.0)[..., None]
    return a * tex + (1.0 - a) * up


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1), (13, 9), (64, 33), (101, 150)])
def test_push_pull_equals_the_numpy_pyramid(shape):
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    known = rng.random(shape) < 0.15
    known.flat[0] = True
    tex = (rng.random(shape + (3,)) * 255).astype(np.float32)
    out = fill_holes(tex, known)
    ref = _push_pull_reference(tex, known.astype(np.float32))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-3)
    np.testing.assert_array_equal(out[known], tex[known])


def _gain_coefficients_reference(face, part, where, iterations=5, max_samples=4096):
    """The numpy IRLS of :func:`facetransfer.patch.gain_field` before the kernel: (3, 3)
    coefficients (a, b, c) per channel, the centring (cx, cy, scale), and the range of the
    centred, scaled columns and rows within which the plane is evaluated (held beyond)."""
    ys, xs = np.nonzero(where)
    cy, cx = ys.mean(), xs.mean()
    scale = float(max(np.ptp(ys), np.ptp(xs), 1))
    step = max(1, -(-ys.size // int(max_samples)))
    ys, xs = ys[::step], xs[::step]
    A = np.stack([np.ones(ys.size), (xs - cx) / scale, (ys - cy) / scale], axis=1)
    r = np.log1p(face[ys, xs].astype(np.float64)) - np.log1p(part[ys, xs].astype(np.float64))
    w = np.ones_like(r)
    for _ in range(iterations):
        Aw = (A[:, None, :] * w[:, :, None]).transpose(1, 2, 0)
        M = Aw @ A + 1e-9 * np.eye(3)
        coef = np.linalg.solve(M, Aw @ r.T[:, :, None])[..., 0].T
        w = 1.0 / np.maximum(np.abs(r - A @ coef), 1e-3)
    return coef, cx, cy, scale, _middle(A[:, 1]), _middle(A[:, 2])


def _middle(a, most=1024):
    """The samples' middle (1 - 2 GAIN_SUPPORT) by sorting at most ``most`` of them."""
    b = np.sort(a[::max(1, a.size // most)])
    lo = int(round(patch.GAIN_SUPPORT * (b.size - 1)))
    return b[lo], b[b.size - 1 - lo]


def test_gain_field_equals_the_numpy_fit():
    rng = np.random.default_rng(7)
    H, W = 90, 120
    yy, xx = np.mgrid[0:H, 0:W]
    part = rng.integers(40, 220, (H, W, 3)).astype(np.uint8)
    shade = np.exp(0.1 + 0.002 * xx - 0.0015 * yy)[..., None] * np.array([1.0, 0.9, 1.1])
    face = np.clip(np.rint(part * shade + rng.normal(0, 3, (H, W, 3))), 0, 255).astype(np.uint8)
    face[30:40, 50:70] = 10  # outliers the L1 fit outvotes
    where = _blobs(rng, (H, W), smooth=6.0, level=0.45)
    box = (10, 5, 100, 80)
    coef, cx, cy, scale, xq, yq = _gain_coefficients_reference(face, part, where)
    x = np.clip((np.arange(box[0], box[2]) - cx) / scale, *xq)
    y = np.clip((np.arange(box[1], box[3]) - cy) / scale, *yq)
    ref = np.exp(coef[0] + x[None, :, None] * coef[1] + y[:, None, None] * coef[2])
    ref = np.clip(ref, *patch.GAIN_RANGE)
    g = patch.gain_field(face, part, where, box=box)
    assert g.shape == (box[3] - box[1], box[2] - box[0], 3) and g.dtype == np.float32
    np.testing.assert_allclose(g, ref, rtol=1e-5)


def test_apply_gain_equals_numpy():
    """The gain's kernel over rows of channel values is numpy's clipped outer product of the
    separable factors times the part, in float32, bit for bit."""
    rng = np.random.default_rng(23)
    h, w = 31, 45
    part = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    gy, gx = rng.uniform(0.5, 1.5, (h, 3)), rng.uniform(0.6, 1.6, (w, 3))
    f = np.empty((h, w, 3), np.float32)
    patch._apply_gain(part, gy, gx, *patch.GAIN_RANGE, f)
    g = np.clip(gy[:, None, :] * gx[None, :, :], *patch.GAIN_RANGE).astype(np.float32)
    np.testing.assert_array_equal(f, part.astype(np.float32) * g)


def test_plane_l1_kernel_equals_its_python_twin():
    """The robust plane fit's kernel (moments in registers, weights per channel) and its
    pure-Python source give the same planes, bit for bit."""
    rng = np.random.default_rng(29)
    k = 300
    u, v = rng.uniform(-0.5, 0.5, k), rng.uniform(-0.5, 0.5, k)
    r = 0.1 + 0.3 * u[:, None] - 0.2 * v[:, None] + rng.normal(0, 0.05, (k, 3))
    r[:20] += 2.0  # outliers
    a, b = np.empty((3, 3)), np.empty((3, 3))
    patch._plane_l1_kernel(u, v, r, 5, a)
    patch._plane_l1_kernel_py(u, v, r, 5, b)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[1], 0.3, atol=0.03)


def test_rejection_equals_the_log_ratio():
    rng = np.random.default_rng(11)
    fb = rng.integers(0, 256, (40, 50, 3)).astype(np.uint8)
    f = (fb * np.exp(rng.normal(0, 0.6, fb.shape))).astype(np.float32)
    lo, hi = 0.5, 0.9
    d = np.abs(np.log1p(f) - np.log1p(fb.astype(np.float32))).max(axis=-1)
    r = np.clip((d - lo) / (hi - lo), 0.0, 1.0).astype(np.float32)
    assert 0.05 < (r > 0).mean() < 0.95  # the ramp is exercised on both sides
    # grown by REJECT_GROW pixels: the largest value over the (2g + 1)^2 square around each
    g = patch.REJECT_GROW
    pad = np.pad(r, g, constant_values=-np.inf)
    grown = np.max([pad[g + dy: g + dy + r.shape[0], g + dx: g + dx + r.shape[1]]
                    for dy in range(-g, g + 1) for dx in range(-g, g + 1)], axis=0)
    ref = np.clip(cv2.GaussianBlur(grown.astype(np.float32), (0, 0), 2.0) * 2.0, 0.0, 1.0)
    # the paste's fade of an alpha of 1 everywhere: 1 - r
    a = np.ones(fb.shape[:2], np.float32)
    patch._reject_fade(patch._rejection_blur(f, fb, (lo, hi)), np.ones(a.shape, bool), a)
    np.testing.assert_allclose(1.0 - a, ref, rtol=0, atol=1e-5)


def test_gain_samples_equal_numpy():
    """The kernel's centring and samples are numpy's (mean of the coordinates, every
    step-th pixel in row-major order), to the bit."""
    rng = np.random.default_rng(11)
    H, W = 70, 90
    face = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    part = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    where = _blobs(rng, (H, W), smooth=4.0, level=0.5)
    ys, xs = np.nonzero(where)
    cy, cx = ys.mean(), xs.mean()
    scale = float(max(np.ptp(ys), np.ptp(xs), 1))
    step = -(-ys.size // 500)
    ys, xs = ys[::step], xs[::step]
    k = ys.size
    u, v, r, centre = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty(3)
    patch._gain_samples(where.view(np.uint8), int(where.sum()), 0, 0, 0, 0, face, part, 500,
                        patch._LOG1P_U8, u, v, r, centre)
    np.testing.assert_array_equal(centre, [cx, cy, scale])
    np.testing.assert_array_equal(u, (xs - cx) / scale)
    np.testing.assert_array_equal(v, (ys - cy) / scale)
    np.testing.assert_array_equal(r, np.log1p(face[ys, xs].astype(np.float64))
                                  - np.log1p(part[ys, xs].astype(np.float64)))
    with pytest.raises(ValueError, match="empty mask"):
        patch.gain_field(face, part, np.zeros((H, W), bool))


def test_match_outline_on_a_crop_with_its_origin_equals_the_whole_image():
    """The jaw's paste works on the box of its region and ring grown by 2 px, the gain fit
    in the frame's coordinates (``origin``): the same pixels as on the whole image."""
    rng = np.random.default_rng(5)
    H, W = 90, 110
    face = rng.integers(40, 220, (H, W, 3), dtype=np.uint8)
    part = np.clip(face * 1.1 + rng.normal(0, 20, face.shape), 0, 255).astype(np.uint8)
    yy, xx = np.mgrid[0:H, 0:W]
    face_mask = ((yy - 45) / 40.0) ** 2 + ((xx - 50) / 48.0) ** 2 <= 1
    face_mask &= _blobs(rng, (H, W), smooth=1.5, level=0.2)  # a few holes
    mask = face_mask & (yy > 50) & (xx > 30) & (xx < 85)
    compare = face_mask & (yy > 40) & (xx > 22) & (xx < 93) & ~mask
    assert mask.sum() > 200 and compare.sum() > 200
    kw = dict(feather=4.0, compare=compare, reject=patch.REJECT, reject_where=None)
    whole = face.copy()
    patch.match_outline_into(face, part, mask, face_mask, whole, **kw)
    ys, xs = np.nonzero(mask | compare)
    sl = (slice(max(ys.min() - 2, 0), ys.max() + 3), slice(max(xs.min() - 2, 0), xs.max() + 3))
    crop = face.copy()
    kw["compare"] = compare[sl]
    patch.match_outline_into(crop[sl], part[sl], mask[sl], face_mask[sl], crop[sl], **kw,
                             origin=(sl[1].start, sl[0].start))
    assert (whole != face).any()
    np.testing.assert_array_equal(crop, whole)


def _harmonic_disc():
    """A disc (128², radius 40), the target a harmonic function of (x, y) per channel (its
    exact Poisson answer with a flat source is the target itself) and a flat source."""
    yy, xx = np.mgrid[0:128, 0:128].astype(np.float64)
    X, Y = xx - 64.3, yy - 63.7
    mask = X ** 2 + Y ** 2 <= 40 ** 2
    harm = 120 + 0.6 * X - 0.4 * Y + 0.01 * (X ** 2 - Y ** 2) + 0.006 * X * Y
    truth = np.stack([harm, 0.8 * harm + 10, 200 - 0.5 * harm], axis=-1)
    T = np.clip(np.rint(truth), 0, 255).astype(np.uint8)
    return T, np.full_like(T, 64), mask, truth


def test_membrane_four_sweeps_match_ten_on_a_harmonic_disc():
    T, S, mask, truth = _harmonic_disc()
    f4 = membrane_blend(T, S, mask, feather=0, outlier=None)  # the default: 4 sweeps
    f10 = membrane_blend(T, S, mask, feather=0, smooth_iterations=10, outlier=None)
    np.testing.assert_array_equal(f4[~mask], T[~mask])
    np.testing.assert_array_equal(f10[~mask], T[~mask])
    for f in (f4, f10):  # push-pull + sweeps: within 4 levels of the exact answer (range 80)
        e = np.abs(f - truth)[mask]
        assert e.max() < 4.0 and e.mean() < 0.85
    assert np.abs(f4.astype(int) - f10)[mask].max() <= 1


def test_membrane_sweeps_on_the_interior_box_equal_the_whole_crop():
    """The sweeps on the interior's box give what sweeps over the whole crop give."""
    rng = np.random.default_rng(2)
    m = _blobs(rng, (70, 90), smooth=5.0, level=0.47)
    t = rng.integers(0, 256, (70, 90, 3)).astype(np.uint8)
    s = rng.integers(0, 256, (70, 90, 3)).astype(np.uint8)
    ring, interior, ry, rx, dr = composite._outline(m, t, s, None)
    d = np.zeros(t.shape, np.float32)
    d[ry, rx] = dr
    h = fill_holes(d, ring)
    for _ in range(6):
        sweep = cv2.filter2D(h, -1, _FOUR_NEIGHBOURS, borderType=cv2.BORDER_REPLICATE)
        h = np.where(interior[..., None], sweep, h)
    np.testing.assert_array_equal(composite._membrane(m, t, s, None, 6), h)


def test_shade_texture_refuses_a_raster_of_more_triangles():
    from facetransfer.errors import ShapeError
    from facetransfer.render import Raster, shade_texture

    tid = np.full((4, 5), -1, np.int32)
    tid[2, 3] = 7  # the faces given have 2 triangles
    r = Raster(np.zeros((4, 5), np.float32), tid, np.full((4, 5, 3), 1 / 3, np.float32), tid >= 0)
    F = np.array([[0, 1, 2], [1, 2, 3]])
    uvs = np.random.default_rng(0).random((4, 2))
    tex = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ShapeError, match="exceed the 2 faces"):
        shade_texture(r, F, uvs, tex)
    tid[2, 3] = 1
    img, mask = shade_texture(r, F, uvs, tex)
    assert mask.sum() == 1 and mask[2, 3]


@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (5, 1), (13, 9), (64, 33), (101, 150)])
def test_push_pull_points_equal_fill_holes(shape):
    """The sparse finest pull gives fill_holes' texels to the bit."""
    from facetransfer.texture.merge import push_pull_points

    rng = np.random.default_rng(shape[0] * 7 + shape[1])
    known = rng.random(shape) < 0.1
    known.flat[-1] = True
    ry, rx = np.nonzero(known)
    vals = rng.normal(0, 40, (ry.size, 3)).astype(np.float32)
    vals[0] = -0.0  # a negative zero sums as the dense kernel's
    d = np.zeros(shape + (3,), np.float32)
    d[ry, rx] = vals
    np.testing.assert_array_equal(push_pull_points(shape, ry, rx, vals), fill_holes(d, known))
    every = np.nonzero(np.ones(shape, bool))  # every pixel known: nothing to fill
    full = rng.normal(0, 1, (every[0].size, 3)).astype(np.float32)
    np.testing.assert_array_equal(push_pull_points(shape, *every, full),
                                  full.reshape(shape + (3,)))


@pytest.mark.parametrize("edge", ["below", "beyond"])
def test_reject_kernel_equals_the_quotients_at_the_ramp_edge(edge):
    """The division-free tests for pixels below and beyond the ramp decide as the quotients
    do, also for ratios within a few ulps of exp(lo) and exp(lo + span)."""
    rng = np.random.default_rng(13)
    lo, span = 0.5, 0.4
    fb = rng.integers(0, 256, (60, 50, 3)).astype(np.uint8)
    at = np.exp(lo) if edge == "below" else np.exp(lo + span)
    q = at * (1.0 + rng.integers(-4, 5, (60, 50, 3)) * 2.0 ** -52)
    q[:20] = rng.uniform(0.5, 2.0, (20, 50, 3))  # and ratios anywhere
    f = ((1.0 + fb) * np.where(rng.random((60, 50, 3)) < 0.5, q, 1 / q) - 1.0)
    f = np.maximum(f, 0).astype(np.float32)
    u, v = 1.0 + f.astype(np.float64), 1.0 + fb
    ratio = np.maximum(np.maximum(u, v) / np.minimum(u, v), 1.0).max(axis=-1)
    want = np.where(ratio <= np.exp(lo), 0.0,
                    np.where(ratio >= np.exp(lo + span), 1.0, (np.log(ratio) - lo) / span))
    r = np.empty((60, 50), np.float32)
    patch._reject_kernel(f, fb, lo, span, r)
    np.testing.assert_array_equal(r, want.astype(np.float32))
    assert 0 < (r == 0).mean() < 1


def test_blend_paste_rejected_equals_the_numpy_fade():
    """The rejection's fade and the paste (kernels over rows of channel values) equal numpy's
    r = clip(2 blur, 0, 1), r *= where, a *= 1 - r and rint(base + a (f - base)) clipped,
    where m, in float32, bit for bit; outside m the image is left alone (a view of a larger
    one, written in place)."""
    rng = np.random.default_rng(17)
    h, w = 40, 50
    m = rng.random((h, w)) < 0.7
    where = rng.random((h, w)) < 0.5
    base = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    f = (rng.random((h, w, 3)) * 300 - 20).astype(np.float32)
    a = rng.random((h, w)).astype(np.float32)
    blur = (rng.random((h, w)) * 0.8).astype(np.float32)
    big = rng.integers(0, 256, (h + 6, w + 9, 3), dtype=np.uint8)
    before = big.copy()
    faded = a.copy()
    patch._reject_fade(blur, where, faded)
    composite.blend_paste(m, base, f, faded, big[2:2 + h, 5:5 + w])
    r = np.clip(blur * np.float32(2.0), np.float32(0.0), np.float32(1.0))
    r *= where
    fade = (a * (np.float32(1.0) - r))[..., None]
    b = base.astype(np.float32)
    want = np.clip(np.rint(b + fade * (f - b)), 0, 255).astype(np.uint8)
    want = np.where(m[..., None], want, before[2:2 + h, 5:5 + w])
    np.testing.assert_array_equal(faded, fade[..., 0])
    np.testing.assert_array_equal(big[2:2 + h, 5:5 + w], want)
    before[2:2 + h, 5:5 + w] = want
    np.testing.assert_array_equal(big, before)  # nothing written outside the crop
    assert (want != base).any()
    # the membrane's paste: f + s in float32
    s = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    out = base.copy()
    composite.blend_paste(m, base, f, a, out, s=s)
    fs = f + s.astype(np.float32)
    want = np.clip(np.rint(b + a[..., None] * (fs - b)), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(out, np.where(m[..., None], want, base))


def test_interpolate_vertex_values_is_the_barycentric_mix():
    """render.interpolate_vertex_values against numpy: at every covered pixel the barycentric
    mix of its triangle's three values, 0 elsewhere; a box gives the same pixels."""
    from facetransfer.render import WeakPerspective, interpolate_vertex_values, rasterize

    rng = np.random.default_rng(3)
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 0.5]], float)
    F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    r = rasterize(V, F, WeakPerspective(20.0, np.eye(3), np.array([32.0, 30.0])), (64, 60))
    vals = rng.uniform(0, 1, len(V))
    got = interpolate_vertex_values(r, F, vals)
    cov = r.tri_id >= 0
    assert cov.sum() > 500
    want = np.zeros(r.tri_id.shape)
    want[cov] = (r.bary[cov] * vals[F[r.tri_id[cov]]]).sum(axis=1)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-6)
    box = (slice(10, 40), slice(5, 50))
    np.testing.assert_array_equal(interpolate_vertex_values(r, F, vals, box=box), got[box])
    with pytest.raises(ValueError, match="values"):
        interpolate_vertex_values(r, F, vals[:3])


@pytest.mark.parametrize("seed", range(3))
def test_interpolate_vertex_pair_is_two_interpolations(seed):
    """render.shading.interpolate_vertex_pair (the jaw's two alphas in one pass) gives the
    bits of two interpolate_vertex_values calls, on the whole raster and on a box (negative,
    zero and float64 values among them); it refuses values short of the faces' vertices."""
    from facetransfer.render import WeakPerspective, interpolate_vertex_values, rasterize
    from facetransfer.render.shading import interpolate_vertex_pair

    rng = np.random.default_rng(seed)
    V = rng.normal(0, 1, (40, 3))
    F = rng.integers(0, 40, (60, 3))
    r = rasterize(V, F, WeakPerspective(12.0, np.eye(3), np.array([32.0, 30.0])), (64, 60))
    assert (r.tri_id >= 0).sum() > 300
    a = rng.normal(0, 1, 40)
    b = np.where(rng.random(40) < 0.5, 0.0, rng.uniform(0, 1, 40)).astype(np.float32)
    for box in (None, (slice(7, 41), slice(3, 50))):
        got = interpolate_vertex_pair(r, F, a, b, box=box)
        for g, v in zip(got, (a, b)):
            want = interpolate_vertex_values(r, F, v, box=box)
            assert g.dtype == np.float32 and g.shape == want.shape
            np.testing.assert_array_equal(g.view(np.uint32), want.view(np.uint32))
    with pytest.raises(ValueError, match="values"):
        interpolate_vertex_pair(r, F, a, b[:3])


def _gain_factors_numpy(face, part, where, box, max_samples=4096):
    """:func:`facetransfer.patch._gain_factors` with its tail as the numpy expressions it was
    before the forty-fifth session (the columns' and rows' coordinates, held within the
    samples' middle by ``np.partition``, times the plane's coefficients, then ``np.exp``)."""
    n = int(np.count_nonzero(where))
    k = -(-n // max(1, -(-n // int(max_samples))))
    u, v, r, centre = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty(3)
    patch._gain_samples(np.ascontiguousarray(where).view(np.uint8), n, 0, 0, 0, 0, face, part,
                        int(max_samples), patch._LOG1P_U8, u, v, r, centre)
    cx, cy, scale = centre
    coef = np.empty((3, 3))
    patch._plane_l1_kernel(u, v, r, patch.GAIN_ITERATIONS, coef)

    def middle(a):
        b = a[::max(1, a.size // 1024)]
        lo = int(round(patch.GAIN_SUPPORT * (b.size - 1)))
        part_ = np.partition(b, (lo, b.size - 1 - lo))
        return float(part_[lo]), float(part_[b.size - 1 - lo])

    x0, y0, x1, y1 = box
    xs, ys = (np.arange(x0, x1) - cx) / scale, (np.arange(y0, y1) - cy) / scale
    if patch.GAIN_SUPPORT > 0:
        np.clip(xs, *middle(u), out=xs)
        np.clip(ys, *middle(v), out=ys)
    return np.exp(coef[0] + ys[:, None] * coef[2]), np.exp(xs[:, None] * coef[1])


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("support", [0.0, 0.1, 0.3])
def test_gain_factors_exponents_equal_the_numpy_expressions(seed, support, monkeypatch):
    """The separable gains' kernel (the middle by ``np.partition`` in numba, the exponents in
    float64 in numpy's order) against the numpy expressions it replaced, bit for bit: masks
    of a few pixels to 20,000 (more than the 4096 samples, more than 1024 of them strided),
    boxes inside and beyond the mask's, and no holding (``GAIN_SUPPORT`` 0)."""
    monkeypatch.setattr(patch, "GAIN_SUPPORT", support)
    rng = np.random.default_rng(seed)
    H, W = (12, 15) if seed == 0 else (int(rng.integers(60, 200)), int(rng.integers(60, 200)))
    face = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    part = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    where = _blobs(rng, (H, W), smooth=2.0 + seed, level=0.5)
    where[H // 2, W // 3:W // 3 + 3] = True
    for box in ((0, 0, W, H), (3, 2, W - 5, H - 1), (-4, -6, W + 7, H + 3)):
        gy, gx = patch._gain_factors(face, part, where, patch.GAIN_ITERATIONS, box, 4096)
        ry, rx = _gain_factors_numpy(face, part, where, box)
        np.testing.assert_array_equal(gy, ry)
        np.testing.assert_array_equal(gx, rx)


def _feather_alpha_before(m, feather, edge_outside):
    """:func:`facetransfer.composite.feather_alpha` as it was before the forty-fifth session
    (the band by ``cv2.subtract`` and ``cv2.findNonZero``, searched pixel by pixel; here in
    Python): the reference its one-pass kernel must equal bit for bit."""
    r = max(int(np.ceil(feather)), 1)
    m8 = m.view(np.uint8)
    deep = cv2.erode(m8, np.ones((2 * r + 1, 2 * r + 1), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0 if edge_outside else 1)
    a = deep.astype(np.float32)
    band = cv2.findNonZero(cv2.subtract(m8, deep))
    if band is None:
        return a
    k = 2 * r + 1
    d2 = np.array([(i // k - r) ** 2 + (i % k - r) ** 2 for i in range(k * k)])
    order = np.argsort(d2, kind="mergesort")
    h, w = m.shape
    for x, y in band.reshape(-1, 2):
        best = 2 * (r + 1) * (r + 1)
        for i in order:
            yy, xx = y + i // k - r, x + i % k - r
            if not (0 <= yy < h and 0 <= xx < w):
                if edge_outside:
                    best = d2[i]
                    break
            elif m8[yy, xx] == 0:
                best = d2[i]
                break
        a[y, x] = min(np.sqrt(np.float32(best)) / np.float32(max(feather, 1e-6)),
                      np.float32(1.0))
    return a


@pytest.mark.parametrize("feather", [0.5, 1.0, 2.0, 2.5, 3.0, 4.0])
@pytest.mark.parametrize("edge_outside", [False, True])
def test_feather_alpha_kernel_equals_the_band_search_before(feather, edge_outside):
    """The one-pass kernel (1 in the erosion, 0 outside, the search between) against the
    band search it replaced, bit for bit: blobs touching the crop's edges, a hole, an all-set
    and an empty crop, a one-pixel-wide line."""
    rng = np.random.default_rng(int(feather * 10) + 3 * edge_outside)
    m = _blobs(rng, (47, 59), level=0.5)
    m[:, :3] = True
    m[10:12, 20:22] = False
    line = np.zeros((9, 30), bool)
    line[4, 2:28] = True
    for mask in (m, np.ones((12, 9), bool), np.zeros((6, 8), bool), line):
        np.testing.assert_array_equal(feather_alpha(mask, feather, edge_outside=edge_outside),
                                      _feather_alpha_before(mask, feather, edge_outside))


def test_grey_equals_the_numpy_geometric_mean():
    """The gains' grey (one factor per row, the geometric mean of its three) against numpy's
    ``repeat(exp(log(g).mean(axis=1, keepdims=True)), 3, axis=1)``, bit for bit: gains
    around 1, spread over two orders, a single row and none."""
    rng = np.random.default_rng(31)
    for g in (rng.uniform(0.7, 1.4, (257, 3)), np.exp(rng.normal(0, 2, (1000, 3))),
              np.array([[0.5, 1.0, 2.0]]), np.empty((0, 3))):
        want = np.repeat(np.exp(np.log(g).mean(axis=1, keepdims=True)), 3, axis=1)
        got = patch._grey(g)
        assert got.shape == g.shape and got.dtype == np.float64
        np.testing.assert_array_equal(got, want)


def _push_pull_before(tex: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The push-pull as the per-level calls made it before its kernels took every pull in one
    call and each push step's overlay (a pull kernel per level; per push step a resize, a
    contiguous cut and a masked copy of the known texels)."""
    from facetransfer.texture import merge

    levels = [(np.ascontiguousarray(tex, np.float32), known.astype(np.float32))]
    while levels[-1][1].shape[0] > 1 or levels[-1][1].shape[1] > 1:
        c, wl = levels[-1]
        hc, wc = (wl.shape[0] + 1) // 2, (wl.shape[1] + 1) // 2
        cc, ww = np.empty((hc, wc, 3), np.float32), np.empty((hc, wc), np.float32)
        merge._pull_kernel(c, wl, cc, ww)
        levels.append((cc, ww))
    filled = levels[-1][0]
    for c, wl in reversed(levels[:-1]):
        up = cv2.resize(filled, (2 * filled.shape[1], 2 * filled.shape[0]),
                        interpolation=cv2.INTER_LINEAR)
        filled = np.ascontiguousarray(up[:wl.shape[0], :wl.shape[1]])
        cv2.copyTo(c, (wl > 0).view(np.uint8), filled)
    return filled


@pytest.mark.parametrize("shape", [(2, 1), (1, 2), (3, 3), (1, 9), (13, 9), (64, 33),
                                   (101, 150), (255, 7)])
@pytest.mark.parametrize("density", [0.002, 0.1, 0.6])
def test_push_pull_levels_equal_the_per_level_calls(shape, density):
    """Every pull in one kernel and each push step's overlay in one: the texels of the
    per-level calls, to the bit; the input is left as it was."""
    rng = np.random.default_rng(shape[0] * 31 + shape[1] + int(density * 1000))
    known = rng.random(shape) < density
    known.flat[0] = False  # an unknown texel, and a known one
    known.flat[rng.integers(1, known.size)] = True
    tex = (rng.normal(0, 60, shape + (3,)) / rng.integers(1, 8, shape + (3,))).astype(np.float32)
    tex[0, 0] = -0.0
    before = tex.copy()
    out = fill_holes(tex, known)
    np.testing.assert_array_equal(tex, before)
    ref = _push_pull_before(tex, known)
    assert out.dtype == np.float32 and out.shape == tex.shape and out.flags.c_contiguous
    np.testing.assert_array_equal(out.view(np.uint32), ref.view(np.uint32))


def test_push_pull_points_read_no_texel_of_the_buffers_before_writing_it():
    """The pyramid's buffers are not cleared (but the first level, by the kernel): filled with
    NaN first, the points' push-pull is the same to the bit."""
    from facetransfer.texture import merge

    rng = np.random.default_rng(5)
    shape = (37, 20)
    known = rng.random(shape) < 0.05
    known.flat[3] = True
    ry, rx = np.nonzero(known)
    vals = rng.normal(0, 40, (ry.size, 3)).astype(np.float32)
    col, wgt, offsets, shapes = merge._pyramid(*shape)
    col.fill(np.nan)
    wgt.fill(np.nan)
    merge._pull_from_points(ry.astype(np.int64), rx.astype(np.int64), vals, col, wgt,
                            *merge._as_arrays(offsets, shapes))
    out = np.empty(shape + (3,), np.float32)
    merge._points_over(merge._push_levels(col, wgt, offsets, shapes), ry.astype(np.int64),
                       rx.astype(np.int64), vals, out)
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out, merge.push_pull_points(shape, ry, rx, vals))

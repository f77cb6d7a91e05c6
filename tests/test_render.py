"""Tests of facetransfer.render: exact hand-computed rasters, numba == numpy reference, errors."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from facetransfer.errors import AssetError, MeshError, ShapeError
from facetransfer.render import (
    Pinhole,
    WeakPerspective,
    euler_from_rotation,
    look_at_weak_perspective,
    rasterize,
    rasterize_reference,
    render,
    rotation_from_euler,
    sample_texture,
    vertex_visibility,
)

I3 = np.eye(3)


def cap_mesh(nr: int = 20, nc: int = 20, *, noise: float = 0.0, seed: int = 0):
    """A face-like spherical cap grid, counter-clockwise seen from +z."""
    u = np.linspace(-1.2, 1.2, nc)
    v = np.linspace(-1.2, 1.2, nr)
    U, Vv = np.meshgrid(u, v)
    P = np.stack([np.sin(U) * np.cos(0.8 * Vv), 1.2 * np.sin(0.8 * Vv),
                  np.cos(U) * np.cos(0.8 * Vv)], -1).reshape(-1, 3)
    P += noise * np.random.default_rng(seed).normal(size=P.shape)
    i = (np.arange(nr - 1)[:, None] * nc + np.arange(nc - 1)[None]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + nc + 1], 1), np.stack([i, i + nc + 1, i + nc], 1)])
    return P, F


def one_triangle():
    # projects with s=1, t=(1, 5) to a=(1, 5), b=(5, 5), c=(1, 1); depths 0, 1, 2
    V = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 1.0], [0.0, 4.0, 2.0]])
    F = np.array([[0, 1, 2]])
    # a rotation that keeps x, y but the depth must be the z coordinate: identity
    return V, F, WeakPerspective(1.0, I3, np.array([1.0, 5.0]))


# ------------------------------------------------------------------------------- cameras

def test_weak_perspective_projection_equals_eq7():
    rng = np.random.default_rng(1)
    R = rotation_from_euler(23.0, -11.0, 7.0)
    cam = WeakPerspective(3.5, R, np.array([100.0, 80.0]))
    X = rng.normal(size=(50, 3))
    expected = 3.5 * (np.diag([1.0, -1.0]) @ R[:2] @ X.T).T + np.array([100.0, 80.0])
    np.testing.assert_allclose(cam.project(X), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cam.depth(X), (R @ X.T)[2], rtol=0, atol=1e-12)


def test_pinhole_projection_formula():
    R = rotation_from_euler(5.0, 3.0, -2.0)
    T = np.array([0.1, -0.2, -10.0])
    cam = Pinhole(500.0, np.array([320.0, 240.0]), R, T)
    X = np.random.default_rng(2).normal(size=(20, 3))
    Xc = X @ R.T + T
    expected = np.stack([320 + 500 * Xc[:, 0] / -Xc[:, 2], 240 - 500 * Xc[:, 1] / -Xc[:, 2]], 1)
    np.testing.assert_allclose(cam.project(X), expected, atol=1e-9)
    np.testing.assert_allclose(cam.depth(X), Xc[:, 2], atol=1e-12)


def test_euler_round_trip():
    for angles in [(10.0, -20.0, 5.0), (0.0, 0.0, 0.0), (-45.0, 30.0, 170.0)]:
        R = rotation_from_euler(*angles)
        np.testing.assert_allclose(R @ R.T, I3, atol=1e-12)
        np.testing.assert_allclose(euler_from_rotation(R), angles, atol=1e-9)
    # yaw turns +x towards -z (right-hand rule about y)
    np.testing.assert_allclose(rotation_from_euler(90, 0, 0) @ [1, 0, 0], [0, 0, -1], atol=1e-12)


@pytest.mark.parametrize("kwargs", [
    dict(scale=0.0, rotation=I3, translation=[0, 0]),
    dict(scale=1.0, rotation=np.ones((3, 3)), translation=[0, 0]),
    dict(scale=1.0, rotation=I3, translation=[0, 0, 0]),
    dict(scale=1.0, rotation=-I3, translation=[0, 0]),  # reflection, det = -1
])
def test_weak_perspective_rejects_bad_parameters(kwargs):
    with pytest.raises(ShapeError):
        WeakPerspective(**kwargs)


def test_pinhole_rejects_bad_parameters():
    with pytest.raises(ShapeError):
        Pinhole(-1.0, [0, 0], I3, [0, 0, 0])
    with pytest.raises(ShapeError):
        Pinhole(1.0, [0, 0], I3, [0, 0])


# ------------------------------------------------------------------------------- raster: exact

EXPECTED_MASK = np.array([
    [0, 0, 0, 0, 0, 0, 0, 0],
    [0, 1, 0, 0, 0, 0, 0, 0],
    [0, 1, 1, 0, 0, 0, 0, 0],
    [0, 1, 1, 1, 0, 0, 0, 0],
    [0, 1, 1, 1, 1, 0, 0, 0],
    [0, 1, 1, 1, 1, 1, 0, 0],
    [0, 0, 0, 0, 0, 0, 0, 0],
], bool)  # 8 x 7 image: inclusive edges, pixel centres at integer coordinates


@pytest.mark.parametrize("raster_fn", [rasterize, rasterize_reference])
def test_one_triangle_pixels_and_barycentrics(raster_fn):
    V, F, cam = one_triangle()
    r = raster_fn(V, F, cam, (8, 7))
    np.testing.assert_array_equal(r.mask, EXPECTED_MASK)
    np.testing.assert_array_equal(r.tri_id, np.where(EXPECTED_MASK, 0, -1))
    assert r.depth.dtype == np.float32 and r.tri_id.dtype == np.int32
    assert np.all(r.depth[~EXPECTED_MASK] == -np.inf)
    # pixel (x, y) = a + beta (b - a) + gamma (c - a): (3, 3) -> (0, 1/2, 1/2); (2, 4) -> (1/2, 1/4, 1/4)
    np.testing.assert_array_equal(r.bary[3, 3], [0.0, 0.5, 0.5])
    np.testing.assert_array_equal(r.bary[4, 2], [0.5, 0.25, 0.25])
    np.testing.assert_array_equal(r.bary[5, 1], [1.0, 0.0, 0.0])
    assert r.depth[3, 3] == 1.5 and r.depth[4, 2] == 0.75 and r.depth[1, 1] == 2.0
    np.testing.assert_allclose(r.bary[r.mask].sum(axis=1), 1.0, atol=1e-6)


@pytest.mark.parametrize("raster_fn", [rasterize, rasterize_reference])
@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_nearer_triangle_wins(raster_fn, order):
    big_far = np.array([[-10.0, -10.0, 0.0], [10.0, -10.0, 0.0], [0.0, 10.0, 0.0]])
    small_near = np.array([[-2.0, -2.0, 1.0], [2.0, -2.0, 1.0], [0.0, 2.0, 1.0]])
    V = np.concatenate([big_far, small_near])
    tris = [np.array([0, 1, 2]), np.array([3, 4, 5])]
    F = np.stack([tris[order[0]], tris[order[1]]])
    near_id = order.index(1)
    cam = WeakPerspective(1.0, I3, np.array([10.0, 10.0]))
    r = raster_fn(V, F, cam, (21, 21))
    assert r.tri_id[10, 10] == near_id and r.depth[10, 10] == 1.0  # centre: near triangle
    assert r.tri_id[15, 3] == 1 - near_id and r.depth[15, 3] == 0.0  # outside the small one
    assert r.tri_id[0, 0] == -1


def test_equal_depth_goes_to_lower_index_and_culling():
    V = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 4.0, 0.0]])
    F = np.array([[0, 2, 1], [0, 1, 2]])  # same triangle, clockwise then counter-clockwise
    cam = WeakPerspective(1.0, I3, np.array([1.0, 5.0]))
    for fn in (rasterize, rasterize_reference):
        r = fn(V, F, cam, (8, 7))
        np.testing.assert_array_equal(r.tri_id, np.where(EXPECTED_MASK, 0, -1))
        rc = fn(V, F, cam, (8, 7), cull_backfaces=True)  # the clockwise one is culled
        np.testing.assert_array_equal(rc.tri_id, np.where(EXPECTED_MASK, 1, -1))


def test_degenerate_triangles_skipped_silently():
    V, F, cam = one_triangle()
    V = np.concatenate([V, [[1.0, 1.0, 5.0]]])
    F = np.array([[0, 1, 2], [3, 3, 3], [0, 1, 0]])
    r = rasterize(V, F, cam, (8, 7))
    np.testing.assert_array_equal(r.tri_id, np.where(EXPECTED_MASK, 0, -1))


@pytest.mark.parametrize("seed", [0, 1])
def test_numba_equals_reference_random_soup(seed):
    rng = np.random.default_rng(seed)
    n = 300
    V = rng.uniform(-1, 1, size=(n, 3))
    F = rng.integers(0, n, size=(400, 3))
    cam = WeakPerspective(60.0, rotation_from_euler(*rng.uniform(-30, 30, 3)),
                          np.array([50.0, 40.0]))
    for cull in (False, True):
        a = rasterize(V, F, cam, (101, 83), cull_backfaces=cull)
        b = rasterize_reference(V, F, cam, (101, 83), cull_backfaces=cull)
        assert a.mask.sum() > 1000
        np.testing.assert_array_equal(a.tri_id, b.tri_id)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.bary, b.bary)


@pytest.mark.parametrize("seed", [3, 4])
def test_numba_equals_reference_cap_mesh_both_cameras(seed):
    V, F = cap_mesh(30, 30, noise=0.01, seed=seed)
    rng = np.random.default_rng(seed)
    R = rotation_from_euler(*rng.uniform(-40, 40, 3))
    cams = [look_at_weak_perspective(V, (160, 120), rotation=R),
            Pinhole(200.0, np.array([80.0, 60.0]), R, np.array([0.0, 0.0, -4.0]))]
    for cam in cams:
        a = rasterize(V, F, cam, (160, 120))
        b = rasterize_reference(V, F, cam, (160, 120))
        assert a.mask.sum() > 2000
        np.testing.assert_array_equal(a.tri_id, b.tri_id)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.bary, b.bary)

def test_raster_kernel_equals_its_python_twin():
    # triangles of a few pixels (one 8 x 8 tile) and larger ones (several tiles, cut by the
    # image's edge): the compiled kernel and its pure-Python source give the same buffers
    from facetransfer.render.raster import _raster_kernel, _raster_kernel_py, _screen

    rng = np.random.default_rng(7)
    V = rng.uniform(-1, 1, size=(60, 3))
    F = np.concatenate([rng.integers(0, 60, size=(12, 3)),
                        np.arange(48).reshape(16, 3)])  # neighbours in the cloud: small ones
    cam = WeakPerspective(30.0, rotation_from_euler(10.0, -20.0, 5.0), np.array([20.0, 17.0]))
    xy, z, q = _screen(V, cam)
    out = []
    for kernel in (_raster_kernel, _raster_kernel_py):
        bufs = (np.full((33, 37), -np.inf, np.float32), np.full((33, 37), -1, np.int32),
                np.zeros((33, 37, 3), np.float32))
        box = kernel(xy, z, q, F, 37, 33, False, False, *bufs)
        out.append((tuple(int(b) for b in box),) + bufs)
    assert (out[0][2] >= 0).sum() > 300
    assert out[0][0] == out[1][0]
    for a, b in zip(out[0][1:], out[1][1:]):
        np.testing.assert_array_equal(a, b)



@pytest.mark.parametrize("seed", range(4))
def test_coverage_is_the_rasters_mask(seed):
    """:func:`facetransfer.render.raster.coverage` of a 2D soup (cut by the image's edge,
    degenerate triangles among them) is the raster's mask of the same triangles drawn at
    those pixels, with and without the back faces; its compiled kernel is its Python twin."""
    from facetransfer.render.raster import _coverage_kernel, _coverage_kernel_py, coverage

    rng = np.random.default_rng(seed)
    P = rng.uniform([-10, -10], [90, 70], size=(200, 2))
    F = np.concatenate([rng.integers(0, 200, size=(300, 3)), [[0, 0, 1], [2, 3, 2]]])
    pixels = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    for front in (False, True):
        got = coverage(P, F, (80, 60), front=front)
        want = rasterize(np.c_[P, np.zeros(200)], F, pixels, (80, 60),
                         cull_backfaces=front).mask
        assert want.sum() > 1000
        np.testing.assert_array_equal(got, want)
    twins = [np.zeros((60, 80), np.uint8) for _ in range(2)]
    for kernel, mask in zip((_coverage_kernel, _coverage_kernel_py), twins):
        kernel(P, F.astype(np.int64), 80, 60, True, np.zeros((0, 0), np.uint8), mask)
    np.testing.assert_array_equal(twins[0], twins[1])


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(-40, 60, allow_nan=False), st.floats(-40, 50, allow_nan=False)),
                min_size=3, max_size=12),
       st.lists(st.tuples(st.integers(0, 11), st.integers(0, 11), st.integers(0, 11)),
                min_size=1, max_size=16),
       st.booleans())
def test_coverage_matches_the_raster_on_any_soup(points, faces, front):
    """Fuzzed 2D soups (any points, coincident and collinear ones among them, triangles past
    the image on every side): :func:`facetransfer.render.raster.coverage` is the raster's
    mask of the same triangles."""
    from facetransfer.render.raster import coverage

    P = np.array(points, np.float64)
    F = np.array(faces, np.int64) % len(P)
    pixels = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    got = coverage(P, F, (24, 16), front=front)
    try:
        want = rasterize(np.c_[P, np.zeros(len(P))], F, pixels, (24, 16),
                         cull_backfaces=front).mask
    except MeshError:  # a soup of (nearly) degenerate triangles only: the raster refuses it
        assume(False)
    np.testing.assert_array_equal(got, want)


def test_coverage_with_known_pixels_skips_the_triangles_inside_them():
    """A grid of small triangles over a rectangle: given its middle as ``known``, coverage is
    the same (the triangles two pixels inside it are skipped, the rest drawn); ``known``
    pixels outside the mesh are kept; bad points, faces and ``known`` are refused."""
    from facetransfer.render.raster import coverage

    n = 21
    g = np.stack(np.meshgrid(np.linspace(5, 55, n), np.linspace(4, 34, n)), -1).reshape(-1, 2)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    F = np.concatenate([np.c_[a, a + n, a + 1], np.c_[a + 1, a + n, a + n + 1]])
    whole = coverage(g, F, (60, 40))
    known = np.zeros((40, 60), bool)
    known[10:30, 12:50] = True
    np.testing.assert_array_equal(coverage(g, F, (60, 40), known=known), whole)
    extra = known.copy()
    extra[38, 58] = True
    assert coverage(g, F, (60, 40), known=extra)[38, 58]
    with pytest.raises(ShapeError, match="points"):
        coverage(np.c_[g, g[:, :1]], F, (60, 40))
    with pytest.raises(ShapeError, match="faces"):
        coverage(g, F + len(g), (60, 40))
    with pytest.raises(ShapeError, match="known"):
        coverage(g, F, (60, 40), known=known[:20])


def test_pinhole_barycentrics_are_perspective_correct():
    # a slanted quad: the 3D point rebuilt from the barycentrics must project to the pixel centre
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, -1.5], [1.0, 1.0, -1.5], [-1.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    cam = Pinhole(60.0, np.array([32.0, 32.0]), I3, np.array([0.0, 0.0, -3.0]))
    r = rasterize(V, F, cam, (64, 64))
    ys, xs = np.nonzero(r.mask)
    assert xs.size > 500
    P = np.einsum("mk,mkc->mc", r.bary[ys, xs].astype(np.float64), V[F[r.tri_id[ys, xs]]])
    np.testing.assert_allclose(cam.project(P), np.stack([xs, ys], 1), atol=1e-3)
    np.testing.assert_allclose(r.depth[ys, xs], cam.depth(P), rtol=1e-5)


# ------------------------------------------------------------------------------- visibility

def test_occluded_vertex_is_not_visible():
    # a small front-facing triangle at z=0, a big one at z=1 in front of it (both CCW from +z)
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0],
                  [-10.0, -10.0, 1.0], [10.0, -10.0, 1.0], [0.0, 10.0, 1.0],
                  [20.0, 20.0, 0.0], [22.0, 20.0, 0.0], [21.0, 22.0, 0.0]])
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    cam = WeakPerspective(2.0, I3, np.array([50.0, 50.0]))
    vis = vertex_visibility(V, F, cam, (100, 100))
    np.testing.assert_array_equal(vis, [False, False, False, True, True, True, True, True, True])
    # remove the occluder: the small triangle becomes visible
    vis2 = vertex_visibility(V, F[[0, 2]], cam, (100, 100))
    np.testing.assert_array_equal(vis2[:3], True)


def test_visibility_back_facing_and_outside_image():
    V, F = cap_mesh(15, 15)
    cam = look_at_weak_perspective(V, (100, 100))
    vis = vertex_visibility(V, F, cam, (100, 100))
    assert vis.all()  # a convex cap seen from the front
    back = WeakPerspective(cam.scale, rotation_from_euler(180.0, 0, 0), cam.translation)
    assert not vertex_visibility(V, F, back, (100, 100)).any()  # only back faces
    away = WeakPerspective(cam.scale, I3, cam.translation + 1000.0)
    assert not vertex_visibility(V, F, away, (100, 100)).any()


def test_visibility_uses_given_raster_and_checks_its_size():
    V, F = cap_mesh(10, 10)
    cam = look_at_weak_perspective(V, (50, 40))
    r = rasterize(V, F, cam, (50, 40))
    np.testing.assert_array_equal(vertex_visibility(V, F, cam, (50, 40), raster=r),
                                  vertex_visibility(V, F, cam, (50, 40)))
    with pytest.raises(ShapeError):
        vertex_visibility(V, F, cam, (40, 50), raster=r)


# ------------------------------------------------------------------------------- render

def test_render_per_vertex_colours_exact():
    V, F, cam = one_triangle()
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    res = render(V, F, cam, (8, 7), colors=colors, shading="none", background=(1, 2, 3))
    np.testing.assert_array_equal(res.image[3, 3], [0, 128, 128])  # (0, .5, .5) * 255 rounded
    np.testing.assert_array_equal(res.image[5, 1], [255, 0, 0])
    np.testing.assert_array_equal(res.image[0, 0], [1, 2, 3])
    assert res.visible.all()


def test_render_texture_lookup_and_lambert():
    V, F, cam = one_triangle()
    V = V * [1, 1, 0]  # flat, facing the camera
    tex = np.zeros((2, 256, 3), np.uint8)
    tex[:, :, 0] = np.arange(256)  # red = column
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    res = render(V, F, cam, (8, 7), uvs=uvs, texture=tex, shading="none")
    # pixel (3, 3): u = 0.5 -> column 127.5 -> red 127.5, rounded to even 128
    assert res.image[3, 3, 0] == 128 and res.image[5, 1, 0] == 0 and res.image[5, 5, 0] == 255
    lit = render(V, F, cam, (8, 7), colors=np.full((3, 3), 200, np.uint8))
    np.testing.assert_array_equal(lit.image[EXPECTED_MASK], 200)  # normal along the light
    side = render(V, F, cam, (8, 7), colors=np.full((3, 3), 200, np.uint8),
                  light=(1.0, 0.0, 1.0), ambient=0.0)
    assert int(side.image[3, 3, 0]) == round(200 * np.sqrt(0.5))


def test_sample_texture_bilinear():
    tex = np.array([[[0, 0, 0], [100, 100, 100]], [[50, 50, 50], [150, 150, 150]]], np.uint8)
    # row 0 is v = 1 (top); centre is the mean of all four
    np.testing.assert_allclose(sample_texture(tex, np.array([[0.5, 0.5], [0.0, 1.0], [1.0, 0.0]])),
                               [[75, 75, 75], [0, 0, 0], [150, 150, 150]])


def test_render_outside_frame_returns_background_and_warns(caplog):
    V, F = cap_mesh(10, 10)
    bg = np.full((30, 40, 3), 7, np.uint8)
    cam = WeakPerspective(10.0, I3, np.array([-500.0, -500.0]))
    with caplog.at_level(logging.WARNING, logger="facetransfer.render"):
        res = render(V, F, cam, (40, 30), background=bg)
    assert "outside" in caplog.text
    np.testing.assert_array_equal(res.image, bg)
    assert not res.visible.any() and not res.raster.mask.any()


def test_render_behind_pinhole_camera_renders_nothing(caplog):
    V, F = cap_mesh(10, 10)
    cam = Pinhole(100.0, np.array([20.0, 15.0]), I3, np.array([0.0, 0.0, 5.0]))  # behind
    with caplog.at_level(logging.WARNING, logger="facetransfer.render"):
        res = render(V, F, cam, (40, 30))
    assert "behind" in caplog.text
    assert not res.image.any() and not res.visible.any()


def test_render_full_cap_shows_face_pixels():
    V, F = cap_mesh(30, 30)
    cam = look_at_weak_perspective(V, (120, 100), rotation=rotation_from_euler(20, 10, 0))
    res = render(V, F, cam, (120, 100), background=(0, 0, 255))
    assert res.raster.mask.sum() > 3000
    assert np.all(res.image[~res.raster.mask] == np.array([0, 0, 255], np.uint8))
    face = res.image[res.raster.mask].astype(int)
    assert np.all(face[:, 0] == face[:, 2]) and np.all(face[:, 0] >= 50)  # grey, >= ambient
    assert face[:, 0].max() >= 195  # some pixels face the light


# ------------------------------------------------------------------------------- bad input

def test_bad_meshes_rejected():
    cam = WeakPerspective(1.0, I3, np.zeros(2))
    with pytest.raises(MeshError, match="empty"):
        rasterize(np.zeros((0, 3)), np.zeros((0, 3), int), cam, (10, 10))
    with pytest.raises(MeshError, match="no faces"):
        rasterize(np.zeros((3, 3)), np.zeros((0, 3), int), cam, (10, 10))
    with pytest.raises(MeshError, match="index vertices"):
        rasterize(np.zeros((3, 3)), np.array([[0, 1, 3]]), cam, (10, 10))
    with pytest.raises(MeshError, match="index vertices"):
        vertex_visibility(np.zeros((3, 3)), np.array([[0, 1, -1]]), cam, (10, 10))
    with pytest.raises(ShapeError):
        rasterize(np.zeros((3, 2)), np.array([[0, 1, 2]]), cam, (10, 10))
    with pytest.raises(ShapeError):
        rasterize(np.zeros((3, 3)), np.array([[0.0, 1, 2]]), cam, (10, 10))
    with pytest.raises(MeshError, match="NaN"):
        rasterize(np.full((3, 3), np.nan), np.array([[0, 1, 2]]), cam, (10, 10))
    with pytest.raises(ShapeError, match="size"):
        rasterize(np.eye(3), np.array([[0, 1, 2]]), cam, (0, 10))
    with pytest.raises(MeshError, match="degenerate"):
        render(np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]), np.array([[0, 1, 2], [0, 0, 1]]),
               cam, (10, 10))


def test_bad_render_options_rejected():
    V, F, cam = one_triangle()
    with pytest.raises(AssetError, match="uint8"):
        render(V, F, cam, (8, 7), uvs=np.zeros((3, 2)), texture=np.zeros((4, 4, 3)))
    with pytest.raises(AssetError, match="uint8"):
        render(V, F, cam, (8, 7), uvs=np.zeros((3, 2)), texture=np.zeros((4, 4), np.uint8))
    with pytest.raises(AssetError, match="missing"):
        render(V, F, cam, (8, 7), uvs=np.zeros((3, 2)))
    with pytest.raises(ShapeError, match="uvs"):
        render(V, F, cam, (8, 7), uvs=np.zeros((2, 2)), texture=np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ShapeError, match="colors"):
        render(V, F, cam, (8, 7), colors=np.zeros((4, 3)))
    with pytest.raises(ShapeError, match="background"):
        render(V, F, cam, (8, 7), background=np.zeros((7, 9, 3), np.uint8))
    with pytest.raises(MeshError, match="shading"):
        render(V, F, cam, (8, 7), shading="phong")
    with pytest.raises(ShapeError, match="light"):
        render(V, F, cam, (8, 7), light=(0, 0, 0))


def test_rasterizer_reuses_buffers_and_matches_rasterize():
    from facetransfer.render import Rasterizer

    V, F = cap_mesh(25, 25, noise=0.005, seed=5)
    rz = Rasterizer((90, 70))
    cams = [look_at_weak_perspective(V, (90, 70), rotation=rotation_from_euler(a, 0, 0),
                                     fill=f, offset=(o, -o))
            for a, f, o in [(0, 0.9, 0.0), (30, 0.4, 20.0), (-20, 0.6, -15.0)]]
    cams.append(WeakPerspective(10.0, I3, np.array([-900.0, 0.0])))  # nothing in view
    for cam in cams:  # each call must fully clear what the previous one wrote
        a = rz.rasterize(V, F, cam)
        b = rasterize(V, F, cam, (90, 70))
        for name in ("depth", "tri_id", "bary", "mask"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(vertex_visibility(V, F, cam, (90, 70)),
                                      vertex_visibility(V, F, cam, (90, 70), raster=b))


def test_triangle_ids_agree_with_trimesh_ray_casting():
    """Independent reference: one orthographic trimesh ray per pixel centre hits the same
    triangle that wins our z-buffer (pixels exactly on a shared edge may differ)."""
    trimesh = pytest.importorskip("trimesh")
    from trimesh.ray.ray_triangle import RayMeshIntersector

    V, F = cap_mesh(16, 16, noise=0.01, seed=7)
    # fold a flap in front of part of the cap so that occlusion matters
    V = np.concatenate([V, [[-0.3, -0.3, 1.4], [0.5, -0.2, 1.5], [0.1, 0.6, 1.45]]])
    F = np.concatenate([F, [[len(V) - 3, len(V) - 2, len(V) - 1]]])
    size = (80, 60)
    cam = look_at_weak_perspective(V, size, rotation=rotation_from_euler(25, -10, 5))
    r = rasterize(V, F, cam, size)
    ys, xs = np.mgrid[0:60, 0:80]
    ox = (xs.ravel() - cam.translation[0]) / cam.scale
    oy = -(ys.ravel() - cam.translation[1]) / cam.scale
    Vc = cam.to_camera(V)
    origins = np.stack([ox, oy, np.full_like(ox, Vc[:, 2].max() + 1)], 1)
    hit = RayMeshIntersector(trimesh.Trimesh(Vc, F, process=False)).intersects_first(
        origins, np.tile([0.0, 0.0, -1.0], (origins.shape[0], 1))).reshape(60, 80)
    either = (hit >= 0) | r.mask
    assert either.sum() > 1500 and (r.tri_id == len(F) - 1).sum() > 50
    assert np.mean(hit[either] == r.tri_id[either]) > 0.995


def test_bad_camera_rejected():
    V, F, _ = one_triangle()
    with pytest.raises(ShapeError, match="camera"):
        rasterize(V, F, (1.0, I3, np.zeros(2)), (8, 7))
    with pytest.raises(ShapeError, match="camera"):
        render(V, F, None, (8, 7))


def test_bad_visibility_tolerance_rejected():
    V, F, cam = one_triangle()
    with pytest.raises(ShapeError, match="tolerance"):
        vertex_visibility(V, F, cam, (8, 7), tol=-1.0)
    with pytest.raises(ShapeError, match="tolerance"):
        render(V, F, cam, (8, 7), visibility_tol=float("nan"))


def test_occluded_vertex_is_not_visible_pinhole():
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0],
                  [-5.0, -5.0, 2.0], [5.0, -5.0, 2.0], [0.0, 5.0, 2.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    cam = Pinhole(40.0, np.array([50.0, 50.0]), I3, np.array([0.0, 0.0, -10.0]))
    np.testing.assert_array_equal(vertex_visibility(V, F, cam, (100, 100)),
                                  [False, False, False, True, True, True])
    np.testing.assert_array_equal(vertex_visibility(V, F[:1], cam, (100, 100)), [True] * 3 +
                                  [False] * 3)  # vertices on no triangle are never visible


def test_shade_texture_equals_numpy_lookup_on_selected_triangles():
    from facetransfer.render import shade_texture

    P, F = cap_mesh(16, 16)
    uvs = (P[:, :2] - P[:, :2].min(0)) / np.ptp(P[:, :2], axis=0)
    rng = np.random.default_rng(3)
    tex = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    cam = look_at_weak_perspective(P, (90, 70))
    r = rasterize(P, F, cam, (90, 70))
    select = rng.random(len(F)) < 0.5
    img, mask = shade_texture(r, F, uvs, tex, select)
    tid = r.tri_id
    want = (tid >= 0) & select[np.maximum(tid, 0)]
    np.testing.assert_array_equal(mask, want)
    assert want.sum() > 500 and (~want & (tid >= 0)).sum() > 500
    b = r.bary[want].astype(np.float64)
    uv = np.einsum("mk,mkc->mc", b, uvs[F[tid[want]]])
    ref = np.clip(np.rint(sample_texture(tex, uv)), 0, 255)
    diff = np.abs(img[want].astype(int) - ref.astype(int))
    assert diff.max() <= 1 and diff.mean() < 0.01     # float32 vs float64 rounding only
    assert not img[~want].any()
    full, fmask = shade_texture(r, F, uvs, tex)
    np.testing.assert_array_equal(fmask, tid >= 0)
    np.testing.assert_array_equal(full[want], img[want])
    with pytest.raises(ShapeError):
        shade_texture(r, F, uvs[:5], tex)
    with pytest.raises(ShapeError):
        shade_texture(r, F, uvs, tex, select[:-1])
    with pytest.raises(AssetError):
        shade_texture(r, F, uvs, tex.astype(np.float32))


def test_shade_layers_kernel_equals_its_python_twin():
    # four layers over a small raster: the compiled kernel and its pure-Python source
    from facetransfer.jit import read_only
    from facetransfer.render.shading import _shade_layers_kernel, _shade_layers_kernel_py

    P, F = cap_mesh(8, 8)
    rng = np.random.default_rng(9)
    r = rasterize(P, F, look_at_weak_perspective(P, (30, 24)), (30, 24))
    flags = rng.integers(0, 256, len(F)).astype(np.uint8)
    layers = [(rng.random((len(P), 2)), rng.integers(0, 256, (9 + k, 13, 3), dtype=np.uint8))
              for k in range(4)]
    got = {}
    for y0, x0, h, w in ((0, 0, 24, 30), (3, 5, 15, 20)):  # the whole raster and a box of it
        out = []
        for kernel in (_shade_layers_kernel, _shade_layers_kernel_py):
            args = []
            for uv, tex in layers:
                args += [uv, read_only(tex), np.zeros((h, w, 3), np.uint8)]  # as shade_layers
            labels = np.zeros((h, w), np.uint8)
            ok = kernel(r.tri_id, r.bary, y0, x0, F.astype(np.int64), flags, *args, labels,
                        np.empty((w, 4, 4), np.int64), np.empty((w, 4, 2)),
                        np.empty(w, np.uint8))
            out.append([ok, labels] + args[2::3])
        assert out[0][0] and out[1][0]
        for a, b in zip(out[0][1:], out[1][1:]):
            np.testing.assert_array_equal(a, b)
        got[y0] = out[0][1:]
    assert (got[0][1] > 0).any(axis=-1).sum() > 100
    for whole, box in zip(got[0], got[3]):  # the box's pixels are the whole raster's
        np.testing.assert_array_equal(box, whole[3:18, 5:25])


def test_shade_layers_equal_one_pass_per_layer_and_label_pixels():
    from facetransfer.render import shade_layers, shade_texture

    P, F = cap_mesh(16, 16)
    rng = np.random.default_rng(5)
    r = rasterize(P, F, look_at_weak_perspective(P, (90, 70)), (90, 70))
    uvs = [rng.random((len(P), 2)) for _ in range(2)]
    texs = [rng.integers(0, 256, (37, 53, 3), dtype=np.uint8),
            rng.integers(0, 256, (20, 31, 3), dtype=np.uint8)]
    sel = [rng.random(len(F)) < 0.7, rng.random(len(F)) < 0.3]
    label = rng.random(len(F)) < 0.4
    # layers in slots 0 and 2 (slot 1 unused), a label on bit 6
    flags = sel[0].astype(np.uint8) | (sel[1].astype(np.uint8) << 2) | \
        (label.astype(np.uint8) << 6)
    images, labels = shade_layers(r, F, [(uvs[0], texs[0]), None, (uvs[1], texs[1])], flags)
    assert images[1] is None and len(images) == 3
    for img, k in ((images[0], 0), (images[2], 1)):
        want, mask = shade_texture(r, F, uvs[k], texs[k], sel[k])
        assert mask.sum() > 300
        np.testing.assert_array_equal(img, want)
    tid = r.tri_id
    np.testing.assert_array_equal(labels, np.where(tid >= 0, flags[np.maximum(tid, 0)], 0))
    with pytest.raises(ShapeError, match="not given"):  # slot 1 is None
        shade_layers(r, F, [(uvs[0], texs[0]), None, (uvs[1], texs[1])], flags | 2)
    with pytest.raises(ShapeError, match="not given"):  # slot 2 beyond the layers given
        shade_layers(r, F, [(uvs[0], texs[0])], flags)

"""Two of the render's kernels of the forty-sixth session against the numpy expressions they
replaced (commit ``c1ab903``): ``WeakPerspective.project``'s pixels from the rotated points
(``render.cameras._pixels``): the same bits on random cameras and points, pixel aspects other
than 1, and the edges (no points, one, NaN and infinities, a view of a larger array, float32
points); and ``rasterize``'s buffers set and its mask made in the raster kernel's call
(``render.raster._raster_fresh``): the same rasters for meshes in, across and out of the
image, images of one row or column, culled or not, weak-perspective and pinhole cameras."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.geometry import check_mesh
from facetransfer.render import (Pinhole, WeakPerspective, look_at_weak_perspective, rasterize,
                                 rotation_from_euler)
from facetransfer.render.cameras import _pixels
from facetransfer.render.raster import _raster_kernel, _screen


def _before(cam: WeakPerspective, X) -> np.ndarray:
    Y = np.asarray(X, np.float64) @ cam.rotation[:2].T
    out = np.empty_like(Y)
    out[:, 0] = (cam.scale / cam.pixel_aspect) * Y[:, 0] + cam.translation[0]
    out[:, 1] = -cam.scale * Y[:, 1] + cam.translation[1]
    return out


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float64).view(np.uint64)


@pytest.mark.parametrize("seed", range(8))
def test_project_equals_the_numpy_expressions(seed):
    rng = np.random.default_rng(seed)
    for _ in range(40):
        R = rotation_from_euler(*rng.uniform(-180, 180, 3))
        cam = WeakPerspective(float(10 ** rng.uniform(-3, 5)), R,
                              rng.normal(size=2) * 10 ** rng.uniform(0, 6),
                              pixel_aspect=float(rng.choice([1.0, rng.uniform(0.4, 2.5)])))
        X = rng.normal(size=(int(rng.integers(0, 2000)), 3)) * 10 ** rng.uniform(-4, 4)
        got = cam.project(X)
        assert got.shape == (len(X), 2) and got.dtype == np.float64
        np.testing.assert_array_equal(_bits(got), _bits(_before(cam, X)))


def test_project_edges_equal_the_numpy_expressions():
    rng = np.random.default_rng(1)
    cam = WeakPerspective(3.7, rotation_from_euler(20.0, -35.0, 8.0), np.array([101.5, -7.25]),
                          pixel_aspect=0.9)
    big = rng.normal(size=(50, 6))
    X = rng.normal(size=(30, 3))
    X[3, 1], X[7, 0], X[9, 2] = np.nan, np.inf, -np.inf
    for pts in (np.zeros((0, 3)), X[:1], X, big[:, ::2], X.astype(np.float32), X.tolist()):
        np.testing.assert_array_equal(_bits(cam.project(pts)), _bits(_before(cam, pts)))


def test_pixels_kernel_equals_its_python_twin():
    rng = np.random.default_rng(2)
    Y = rng.normal(size=(300, 2)) * 1e3
    outs = [np.empty((300, 2)) for _ in range(2)]
    for kernel, out in zip((_pixels, _pixels.py_func), outs):
        kernel(Y, 1.7, -3.25, -2.5, 11.0, out)
    np.testing.assert_array_equal(_bits(outs[0]), _bits(outs[1]))


def _raster_before(V, F, camera, W, H, cull):
    """``rasterize`` as it was at ``c1ab903``: numpy's buffers, then the kernel, then the
    mask."""
    V, F = check_mesh(V, F)
    xy, z, q = _screen(V, camera)
    zbuf = np.full((H, W), -np.inf, np.float32)
    tid = np.full((H, W), -1, np.int32)
    bary = np.zeros((H, W, 3), np.float32)
    _raster_kernel(xy, z, q, F, W, H, bool(cull), bool(getattr(camera, "perspective", False)),
                   zbuf, tid, bary)
    return zbuf, tid, bary, tid >= 0


def _grid_mesh(n: int, rng):
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    P = np.stack([u, v, 0.3 * np.sin(3 * u) + 0.05 * rng.normal(size=u.shape)], -1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()
    return P.reshape(-1, 3), np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


@pytest.mark.parametrize("size,offset", [((64, 48), (0.0, 0.0)), ((64, 48), (-30.0, 17.0)),
                                         ((64, 48), (500.0, 0.0)), ((64, 1), (0.0, 0.0)),
                                         ((1, 40), (0.0, 0.0)), ((33, 71), (12.5, -20.0))])
@pytest.mark.parametrize("cull", [False, True])
def test_rasterize_equals_numpy_buffers_then_the_kernel(size, offset, cull):
    rng = np.random.default_rng(size[0] + size[1])
    P, F = _grid_mesh(15, rng)
    cam = look_at_weak_perspective(P, size, fill=1.2, offset=offset,
                                   rotation=rotation_from_euler(10.0, 25.0, -5.0))
    pin = Pinhole(60.0, np.array([size[0] / 2, size[1] / 2]), rotation_from_euler(5, -10, 0),
                  np.array([0.1, 0.0, -3.0]))
    for camera in (cam, pin):
        got = rasterize(P, F, camera, size, cull_backfaces=cull)
        want = _raster_before(P, F, camera, *size, cull)
        for a, b in zip((got.depth, got.tri_id, got.bary, got.mask), want, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(a, b)


def test_rasterize_drawn_is_rasterize_and_the_projection():
    # the frame's render takes the raster and camera.project(V) from one projection
    from facetransfer.render.raster import rasterize_drawn

    rng = np.random.default_rng(11)
    P, F = _grid_mesh(20, rng)
    for offset in ((0.0, 0.0), (-40.0, 25.0)):
        cam = look_at_weak_perspective(P, (90, 70), fill=1.1, offset=offset,
                                       rotation=rotation_from_euler(-15.0, 30.0, 4.0))
        r, xy = rasterize_drawn(P, F, cam, (90, 70))
        want = rasterize(P, F, cam, (90, 70))
        for a, b in zip((r.depth, r.tri_id, r.bary, r.mask),
                        (want.depth, want.tri_id, want.bary, want.mask)):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(_bits(xy), _bits(cam.project(P)))

"""``rewrite._face_box``'s extent of the projected mesh in one kernel (forty-sixth session,
``rewrite._extent_kernel``) against the numpy steps it replaced (commit ``c1ab903``): random
meshes in, across and out of the frame, rows with NaN or infinite coordinates, none finite, no
vertices, margins of 0 and more, a pixel aspect other than 1."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import rewrite as rw
from facetransfer.render import WeakPerspective, rotation_from_euler


def _before(V, camera, size, *, margin):
    W, H = size
    p = camera.project(V)
    if not np.isfinite(p).all():
        p = p[np.isfinite(p).all(axis=1)]
    if p.size == 0:
        return None
    x, y = p[:, 0], p[:, 1]
    lo = np.floor([x.min(), y.min()]).astype(np.int64) - margin
    hi = np.ceil([x.max(), y.max()]).astype(np.int64) + margin + 1
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), W), min(int(hi[1]), H)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


@pytest.mark.parametrize("seed", range(10))
def test_face_box_equals_the_numpy_steps(seed):
    rng = np.random.default_rng(seed)
    for _ in range(30):
        cam = WeakPerspective(float(10 ** rng.uniform(0, 3)),
                              rotation_from_euler(*rng.uniform(-60, 60, 3)),
                              rng.uniform(-400, 900, 2),
                              pixel_aspect=float(rng.choice([1.0, 0.9])))
        V = rng.normal(size=(int(rng.integers(0, 400)), 3))
        if len(V) and rng.random() < 0.4:  # rows with non-finite coordinates, or all of them
            bad = rng.random(len(V)) < rng.choice([0.1, 1.0])
            V[bad, int(rng.integers(0, 3))] = rng.choice([np.nan, np.inf, -np.inf])
        size = (int(rng.integers(1, 700)), int(rng.integers(1, 700)))
        margin = int(rng.choice([0, 3, 40]))
        assert rw._face_box(V, cam, size, margin=margin) == \
            _before(V, cam, size, margin=margin)


def test_face_box_exact_integers_and_halves():
    # points on whole and half pixels: floor and ceil at their edges
    cam = WeakPerspective(1.0, np.eye(3), np.array([0.0, 0.0]))
    for pts in ([[3.0, -4.0, 0.0], [10.5, -20.5, 0.0]], [[0.0, 0.0, 0.0]],
                [[-0.0, -0.0, 0.0], [511.0, -479.0, 0.0]]):
        V = np.array(pts)
        for margin in (0, 1, 7):
            assert rw._face_box(V, cam, (512, 480), margin=margin) == \
                _before(V, cam, (512, 480), margin=margin)


def test_extent_kernel_equals_its_python_twin():
    rng = np.random.default_rng(5)
    p = rng.normal(size=(200, 2)) * 300
    p[::17, 0] = np.nan
    p[3::29, 1] = np.inf
    outs = [np.empty(4, np.int64) for _ in range(2)]
    found = [k(p, 9, o) for k, o in zip((rw._extent_kernel, rw._extent_kernel.py_func), outs)]
    assert found == [True, True]
    np.testing.assert_array_equal(*outs)
    assert not rw._extent_kernel(np.full((4, 2), np.nan), 2, outs[0])

"""The membrane's Jacobi sweeps in one kernel against the per-sweep OpenCV calls they replaced
(``cv2.filter2D`` of the 4 neighbours' mean, ``BORDER_REPLICATE``, then a masked copy), to
the bit, and against Laplace's equation itself."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.errors import ShapeError
from facetransfer.jacobi import jacobi_sweeps

_FOUR = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)


def _sweeps_before(h: np.ndarray, inner: np.ndarray, box, iterations: int) -> np.ndarray:
    """The sweeps as ``composite._membrane`` made them before: a filter and a masked copy per
    sweep on the box's view."""
    out = h.copy()
    hb = out[box]
    m = np.ascontiguousarray(inner).view(np.uint8)
    for _ in range(iterations):
        sweep = cv2.filter2D(hb, -1, _FOUR, borderType=cv2.BORDER_REPLICATE)
        cv2.copyTo(sweep, m, hb)
    return out


def _image(rng, shape) -> np.ndarray:
    h = rng.normal(0, 40, shape + (3,)) / rng.integers(1, 8, shape + (3,))
    h = h.astype(np.float32)
    h.flat[::97] = 0.0
    h.flat[5::131] = -0.0
    return h


@pytest.mark.parametrize("shape, box", [
    ((1, 1), (slice(0, 1), slice(0, 1))),
    ((1, 9), (slice(0, 1), slice(2, 8))),
    ((7, 1), (slice(0, 7), slice(0, 1))),
    ((30, 41), (slice(0, 30), slice(0, 41))),     # the whole image: edges replicated
    ((64, 50), (slice(5, 60), slice(3, 47))),     # a box inside: its own edges replicated
    ((310, 290), (slice(0, 300), slice(11, 290))),
])
@pytest.mark.parametrize("iterations", [0, 1, 4, 7])
def test_sweeps_equal_filter2d_and_masked_copies(shape, box, iterations):
    rng = np.random.default_rng(shape[0] * 100 + shape[1] + iterations)
    h = _image(rng, shape)
    bh, bw = box[0].stop - box[0].start, box[1].stop - box[1].start
    inner = rng.random((bh, bw)) < 0.8
    ref = _sweeps_before(h, inner, box, iterations)
    out = h.copy()
    jacobi_sweeps(out, inner, (box[0].start, box[1].start), iterations)
    np.testing.assert_array_equal(out.view(np.uint32), ref.view(np.uint32))
    outside = np.ones(shape, bool)
    outside[box] = ~inner
    np.testing.assert_array_equal(out[outside].view(np.uint32), h[outside].view(np.uint32))


def test_sweeps_converge_to_the_harmonic_plane():
    """A linear ramp is harmonic: fixed on the border, the sweeps reach it from zero inside."""
    H, W = 12, 15
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    ramp = np.stack([2 * xx + yy, xx - 3 * yy, np.full_like(xx, 7)], axis=-1)
    inner = np.zeros((H, W), bool)
    inner[1:-1, 1:-1] = True
    h = ramp.copy()
    h[inner] = 0.0
    jacobi_sweeps(h, inner, (0, 0), 2000)
    np.testing.assert_allclose(h, ramp, atol=1e-3)


def test_sweeps_refuse_a_box_beyond_the_image():
    h = np.zeros((10, 10, 3), np.float32)
    with pytest.raises(ShapeError, match=r"box of \(4, 4\) at \(8, 0\)"):
        jacobi_sweeps(h, np.ones((4, 4), bool), (8, 0), 1)
    with pytest.raises(ShapeError, match="float32"):
        jacobi_sweeps(h.astype(np.float64), np.ones((4, 4), bool), (0, 0), 1)

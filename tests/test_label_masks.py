"""The shading labels' masks and boxes in one kernel each (forty-sixth session,
:mod:`facetransfer.label_masks`) against the numpy expressions ``rewrite._shade_frame``,
``eyes.paint_shaded_eyes`` and ``jaw.paint_shaded_jaw`` made them with (commit ``c1ab903``,
where they were ``_paint_eyes`` and ``_paint_jaw``), on random labels and at the edges: no
pixel with the bits, one pixel, a bit on the image's border, images of one row or column,
margins past the image, labels that are a view."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.composite import mask_box
from facetransfer.label_masks import _bits_box, _frame_masks, bits_box, frame_masks


def _labels(rng, shape, density):
    lab = rng.integers(0, 256, shape).astype(np.uint8)
    lab[rng.random(shape) > density] = 0
    return lab


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("shape", [(37, 53), (1, 40), (30, 1), (1, 1)])
def test_label_masks_equal_the_numpy_expressions(seed, shape):
    rng = np.random.default_rng(seed)
    lab = _labels(rng, shape, [0.0, 0.01, 0.3, 1.0, 0.6, 0.05][seed])
    for bits, margin in ((2, 3), (16, 0), (16 | 32, 2), (1, 12), (255, 1)):
        assert bits_box(lab, bits, margin) == mask_box(np.bitwise_and(lab, bits), margin)
    for mouth_bit, ring_bit in ((8, 128), (8, 0), (0, 0)):
        f, m, r = frame_masks(lab, mouth_bit, ring_bit)
        np.testing.assert_array_equal(f, lab != 0)
        ring = np.bitwise_and(lab, ring_bit) != 0
        mouth = np.bitwise_and(lab, mouth_bit) != 0
        mouth &= ~ring
        np.testing.assert_array_equal(m, mouth)
        np.testing.assert_array_equal(r, ring)


def test_label_box_of_one_pixel_at_the_border_and_of_none():
    lab = np.zeros((20, 30), np.uint8)
    assert bits_box(lab, 255, 3) is None
    lab[19, 29] = 4
    assert bits_box(lab, 4, 2) == mask_box(lab, 2) == (slice(17, 20), slice(27, 30))
    assert bits_box(lab, 8, 2) is None
    lab[0, 0] = 4
    assert bits_box(lab, 4, 50) == (slice(0, 20), slice(0, 30))


def test_label_box_and_masks_of_a_view():
    rng = np.random.default_rng(4)
    big = _labels(rng, (50, 35), 0.3)
    lab = big[::2]  # a view, not contiguous
    for bits in (2, 6, 128):
        assert bits_box(lab, bits, 1) == mask_box(np.bitwise_and(lab, bits), 1)
    f, m, r = frame_masks(lab, 8, 128)
    np.testing.assert_array_equal(f, lab != 0)
    np.testing.assert_array_equal(r, np.bitwise_and(lab, 128) != 0)
    np.testing.assert_array_equal(m, (np.bitwise_and(lab, 8) != 0) & ~r)


def test_label_kernels_equal_their_python_twins():
    rng = np.random.default_rng(8)
    lab = _labels(rng, (40, 50), 0.3)
    boxes = [np.empty(4, np.int64) for _ in range(2)]
    for kernel, box in zip((_bits_box, _bits_box.py_func), boxes):
        kernel(lab, np.uint8(34), box)
    np.testing.assert_array_equal(*boxes)
    three = [[np.empty((40, 50), bool) for _ in range(3)] for _ in range(2)]
    for kernel, (f, m, r) in zip((_frame_masks, _frame_masks.py_func), three):
        kernel(lab, np.uint8(8), np.uint8(128), f, m, r)
    for a, b in zip(*three):
        np.testing.assert_array_equal(a, b)

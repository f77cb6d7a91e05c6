"""The encoder's 4:2:0 planes (:func:`facetransfer.io.video._yuv420p`): its chroma kernel gives
the bytes of the OpenCV steps it replaced (an ``INTER_AREA`` halving, then ``cv2.transform``
by the BT.601 matrix), so a video's bytes do not change with it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer.io.video import _BT601_CHROMA, _yuv420p


def _opencv_planes(rgb: np.ndarray) -> np.ndarray:
    """The planes as the writer made them before its chroma kernel."""
    H, W = rgb.shape[:2]
    out = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
    mean = cv2.resize(rgb, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    uv = cv2.transform(mean, _BT601_CHROMA)
    n = H * W
    planes = out.reshape(-1)
    planes[n:n + n // 4] = uv[..., 0].reshape(-1)
    planes[n + n // 4:] = uv[..., 1].reshape(-1)
    return out


@pytest.mark.parametrize("shape", [(2, 2), (4, 6), (64, 48), (512, 512), (270, 480)])
def test_random_frames_give_opencvs_bytes(shape):
    rng = np.random.default_rng(sum(shape))
    rgb = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    np.testing.assert_array_equal(_yuv420p(rgb), _opencv_planes(rgb))


def test_every_colour_of_a_block_gives_opencvs_bytes():
    """Blocks of one colour over a lattice of the RGB cube (the transform's rounding), and
    blocks whose four values make every sum 0..1020 (the halving's rounding)."""
    levels = np.r_[0:256:5, 1, 127, 128, 254, 255]
    r, g, b = np.meshgrid(levels, levels, levels, indexing="ij")
    colours = np.stack([r, g, b], -1).reshape(-1, 3).astype(np.uint8)
    side = int(np.ceil(np.sqrt(len(colours))))
    grid = np.zeros((side * side, 3), np.uint8)
    grid[:len(colours)] = colours
    rgb = np.repeat(np.repeat(grid.reshape(side, side, 3), 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(_yuv420p(rgb), _opencv_planes(rgb))
    sums = np.arange(1021)
    quads = np.stack([np.minimum(sums, 255), np.clip(sums - 255, 0, 255),
                      np.clip(sums - 510, 0, 255), np.clip(sums - 765, 0, 255)], -1)
    assert (quads.sum(-1) == sums).all()
    blocks = np.zeros((2, 2 * len(sums), 3), np.uint8)
    for c in range(3):
        q = np.roll(quads, c, axis=1).astype(np.uint8)
        blocks[0, 0::2, c], blocks[0, 1::2, c] = q[:, 0], q[:, 1]
        blocks[1, 0::2, c], blocks[1, 1::2, c] = q[:, 2], q[:, 3]
    np.testing.assert_array_equal(_yuv420p(blocks), _opencv_planes(blocks))


def test_a_view_of_a_frame_is_read_as_its_values():
    rng = np.random.default_rng(1)
    big = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    view = big[3:35, 5:55]
    np.testing.assert_array_equal(_yuv420p(view), _opencv_planes(np.ascontiguousarray(view)))

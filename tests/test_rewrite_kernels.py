"""The rewrite's per-frame kernels against the numpy expressions they replaced (forty-fifth
session), bit for bit (:mod:`facetransfer.rewrite`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from facetransfer import rewrite


def _keep_own_numpy(face_img, face_mask, frame, where) -> None:
    """:func:`facetransfer.rewrite._keep_own` as numpy expressions (the reference)."""
    x, y, w, h = cv2.boundingRect(where.view(np.uint8))
    if not w:
        return
    x, y = max(x - 4, 0), max(y - 4, 0)
    box = (slice(y, y + h + 8), slice(x, x + w + 8))
    a = np.maximum(cv2.GaussianBlur(where[box].astype(np.float32), (0, 0), 1.5), where[box])
    a *= face_mask[box]
    ys, xs = np.nonzero(a > 0.5 / 255)
    f = face_img[box][ys, xs].astype(np.float32)
    t = frame[box][ys, xs].astype(np.float32)
    face_img[box][ys, xs] = np.rint(f + a[ys, xs][:, None] * (t - f)).astype(np.uint8)


def _blobs(rng, shape, n: int, radii: tuple[int, int] = (1, 13)) -> np.ndarray:
    """``n`` random discs (radius ``radii[0]`` to ``radii[1] - 1`` px, 1-12 by default) on a
    ``shape`` (H, W) bool mask."""
    m = np.zeros(shape, np.uint8)
    for _ in range(n):
        cv2.circle(m, (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0]))),
                   int(rng.integers(*radii)), 1, -1)
    return m.view(bool)


@pytest.mark.parametrize("seed", range(6))
def test_keep_own_equals_its_numpy_expressions(seed):
    """Random faces, frames and kept pixels (discs anywhere: at the image's edges, where the
    box is cut; none at all), on a face mask that covers some of them: the same bytes."""
    rng = np.random.default_rng(seed)
    H, W = int(rng.integers(20, 120)), int(rng.integers(20, 120))
    face = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    mask = _blobs(rng, (H, W), 6) | (rng.random((H, W)) < 0.5)
    where = _blobs(rng, (H, W), int(rng.integers(0, 4))) & mask
    got, want = face.copy(), face.copy()
    rewrite._keep_own(got, mask, frame, where)
    _keep_own_numpy(want, mask, frame, where)
    np.testing.assert_array_equal(got, want)
    if where.any():  # the frame's own pixels where kept, well inside the discs
        deep = cv2.erode(where.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)
        np.testing.assert_array_equal(got[deep], frame[deep])
    np.testing.assert_array_equal(got[~mask], face[~mask])


def test_keep_own_of_a_view_writes_the_view():
    """The face image as a crop of a larger one (the region paints in place): only the crop
    changes, as the numpy expressions change it."""
    rng = np.random.default_rng(7)
    big = rng.integers(0, 256, (80, 90, 3), dtype=np.uint8)
    frame = rng.integers(0, 256, (60, 70, 3), dtype=np.uint8)
    mask = np.ones((60, 70), bool)
    where = _blobs(rng, (60, 70), 3)
    got, want = big.copy(), big.copy()
    rewrite._keep_own(got[10:70, 5:75], mask, frame, where)
    _keep_own_numpy(want[10:70, 5:75], mask, frame, where)
    np.testing.assert_array_equal(got, want)
    assert (got != big).any()

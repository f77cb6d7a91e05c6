"""The capture benchmark's own renderer (benchmarks/_cvpaint.py) and performance curves."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import _cvpaint as cvp  # noqa: E402

CAM = cvp.Camera(focal=400.0, distance=100.0, size=(64, 48))


def _scene(faces, colours, cull=True):
    m = len(faces)
    return cvp.PaintScene(np.asarray(faces, np.int64), np.asarray(colours, float),
                          np.full(m, cull), np.ones(m))   # ambient 1: unshaded colours


def test_project_pinhole():
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [1.0, 0.0, 50.0]])
    p = cvp.project(X, CAM)
    cx, cy = 31.5, 23.5
    np.testing.assert_allclose(p[0], [cx, cy])
    np.testing.assert_allclose(p[1], [cx + 4.0, cy])          # 400 px / 100 cm
    np.testing.assert_allclose(p[2], [cx, cy - 8.0])          # y up -> image y down
    np.testing.assert_allclose(p[3], [cx + 8.0, cy])          # half the depth: twice the scale


def test_rotation_ypr_orthonormal_and_yaw_turns_to_image_right():
    R = cvp.rotation_ypr(25.0, -10.0, 5.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0)
    nose = cvp.rotation_ypr(30.0, 0, 0) @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(nose, [0.5, 0.0, np.sqrt(3) / 2], atol=1e-12)


def test_paint_fills_a_facing_triangle_with_its_colour():
    X = np.array([[-3.0, -3.0, 0.0], [3.0, -3.0, 0.0], [0.0, 3.0, 0.0]])   # counter-clockwise
    bg = np.zeros((48, 64, 3), np.uint8)
    img = cvp.paint(_scene([[0, 1, 2]], [[1.0, 0.5, 0.0]]), X, CAM, bg)
    c = cvp.project(X, CAM).mean(axis=0).round().astype(int)
    np.testing.assert_array_equal(img[c[1], c[0]], [255, 127, 0])
    assert img[2, 2].sum() == 0                                          # background kept
    coverage = img[..., 0].sum() / 255.0                                 # anti-aliased area
    # 24 px base and height (288 px²); cv2 fills edge pixels inclusively, so the painted area
    # is the triangle grown by at most half a painting pixel (1/4 output pixel) all round
    perimeter = 24 + 2 * np.hypot(12, 24)
    assert 288 <= coverage <= 288 + 0.25 * perimeter


def test_paint_culls_back_faces_only_when_asked():
    X = np.array([[-3.0, -3.0, 0.0], [0.0, 3.0, 0.0], [3.0, -3.0, 0.0]])   # clockwise: away
    bg = np.zeros((48, 64, 3), np.uint8)
    assert cvp.paint(_scene([[0, 1, 2]], [[1, 1, 1]]), X, CAM, bg).sum() == 0
    assert cvp.paint(_scene([[0, 1, 2]], [[1, 1, 1]], cull=False), X, CAM, bg).sum() > 0


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_paint_nearer_triangle_wins_whatever_the_order(order):
    far = np.array([[-4.0, -4.0, -5.0], [4.0, -4.0, -5.0], [0.0, 4.0, -5.0]])
    near = far * [0.5, 0.5, 0] + [0, 0, 5.0]
    X = np.concatenate([far, near])
    tris = [[0, 1, 2], [3, 4, 5]]
    cols = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    scene = _scene([tris[i] for i in order], [cols[i] for i in order])
    img = cvp.paint(scene, X, CAM, np.zeros((48, 64, 3), np.uint8))
    c = cvp.project(near, CAM).mean(axis=0).round().astype(int)
    np.testing.assert_array_equal(img[c[1], c[0]], [0, 0, 255])
    assert (img[..., 0] == 255).any()                                    # far one shows around


def test_blinks_are_fast():
    import _capture_data as cd
    from facetransfer.arkit import ARKIT_NAMES

    spec = cd.ClipSpec("t", 7, n_frames=240)
    A = cd.activation_curves(spec, np.random.default_rng(3))
    assert A.shape == (240, 52) and A.min() >= 0 and A.max() <= 1
    b = A[:, ARKIT_NAMES.index("eyeBlinkLeft")] > 1e-6
    edges = np.flatnonzero(np.diff(np.r_[0, b.astype(int), 0]))
    runs = edges[1::2] - edges[::2]
    assert len(runs) >= 4
    assert runs.min() >= 3 and runs.max() <= 7                          # 4-6 frames close + open
    assert np.all(A[:, ARKIT_NAMES.index("tongueOut")] == 0)


def test_hard_start_is_held_then_released():
    import _capture_data as cd
    from facetransfer.arkit import ARKIT_NAMES

    start = (("jawOpen", 0.75), ("eyeBlinkLeft", 1.0))
    A = cd.activation_curves(cd.ClipSpec("t", 5, n_frames=60, start=start),
                             np.random.default_rng(0))
    plain = cd.activation_curves(cd.ClipSpec("t", 5, n_frames=60), np.random.default_rng(0))
    assert A[:4, ARKIT_NAMES.index("jawOpen")].min() >= 0.75               # held on frames 0-3
    assert A[:4, ARKIT_NAMES.index("eyeBlinkLeft")].min() == 1.0
    np.testing.assert_array_equal(A[14:], plain[14:])          # released by frame 14 (8 + 6)

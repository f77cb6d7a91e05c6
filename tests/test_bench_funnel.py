"""The funnel benchmark's measures (benchmarks/bench_funnel.py): the mouth's width and the lips'
protrusion read from MediaPipe-478 points at any head pose, and its groups of frames."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

pytest.importorskip("bench_capture")
import bench_funnel as bf  # noqa: E402


def _rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return Rx @ Ry


def _face() -> np.ndarray:
    """478 points: random, but for the eye corners 100 apart and the mouth corners 60 apart."""
    P = np.random.default_rng(3).normal(0.0, 40.0, (478, 3))
    P[33], P[263] = (-50.0, 0.0, 0.0), (50.0, 0.0, 0.0)
    P[61], P[291] = (-30.0, 70.0, -10.0), (30.0, 70.0, -10.0)
    P[13], P[14] = (0.0, 68.0, -12.0), (0.0, 72.0, -12.0)
    return P


def test_similarity_onto_undoes_a_turned_scaled_moved_copy():
    P = _face()
    Q = 1.7 * P @ _rotation(25, -10).T + (300.0, 200.0, 5.0)
    np.testing.assert_allclose(bf.similarity_onto(Q, P), P, atol=1e-9)


def test_mouth_geometry_reads_a_funnel_at_any_pose():
    base = _face()
    frames = [base.copy() for _ in range(5)]
    pushed = base.copy()
    pushed[list(bf.LIPS), 2] -= 8.0               # the lips 8 toward the camera (z grows away)
    narrow = base.copy()
    narrow[61, 0] += 6.0
    narrow[291, 0] -= 6.0                         # the mouth 12 narrower
    for P, (yaw, pitch, s) in zip([base, pushed, narrow], [(20, 5, 1.3), (-15, 8, 0.8),
                                                           (10, -12, 1.1)]):
        frames.append(s * P @ _rotation(yaw, pitch).T + (250.0, 240.0, 0.0))
    g = bf.mouth_geometry(np.stack(frames))
    np.testing.assert_allclose(g["protrusion"], [0, 0, 0, 0, 0, 0, 0.08, 0], atol=1e-9)
    np.testing.assert_allclose(g["width"], [0.6] * 7 + [0.48], atol=1e-9)
    np.testing.assert_allclose(g["gap"], 0.04, atol=1e-9)


def test_frame_groups():
    ours = np.array([0.2, 0.09, 0.2, 0.01, 0.3, 0.01])
    peer = np.array([0.01, 0.04, 0.06, 0.01, 0.3, 0.01])
    jaw = np.array([0.0, 0.0, 0.0, 0.05, 0.5, 0.2])
    m = bf.frame_groups(ours, peer, jaw, high=0.08, low=0.05)
    assert m["disputed"].tolist() == [True, True, False, False, False, False]
    assert m["neutral"].tolist() == [False, False, False, True, False, False]
    assert m["peer_high"].tolist() == [False, False, False, False, True, False]

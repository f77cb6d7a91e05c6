"""The hard-start benchmark's choice of first frames (benchmarks/bench_hard_start.py): a head
turned or nodded by a known angle, closed eyes and an open mouth, put in a clip of MediaPipe's
canonical face, are found where they were put."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

hs = pytest.importorskip("bench_hard_start")


def _canonical():
    from facetransfer import assets

    try:
        assets.asset_file("canonical_face_model", download=False)
    except Exception as exc:                      # no asset mirror here
        pytest.skip(f"MediaPipe's canonical face is not available: {exc}")
    return hs.canonical_face()


def _rot(yaw, pitch):
    a, b = np.radians(yaw), np.radians(pitch)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return Rx @ Ry


def _clip(n=150):
    """``n`` frames of the canonical face (478 points: the 468 and 10 iris points at the
    centre) at 12 px a unit, each nodded a little (±3°); frame 20 turned 25°, frame 35 nodded
    -20°, frame 50's eyes closed, frame 65's mouth open."""
    C = _canonical()
    C = np.concatenate([C, np.repeat(C.mean(0, keepdims=True), 10, axis=0)])
    out = []
    for i in range(n):
        X = C.copy()
        if i == 50:
            for up, lo in ((160, 144), (158, 153), (159, 145), (385, 380), (387, 373),
                           (386, 374)):
                X[up] = X[lo]
        if i == 65:
            X[14] = X[14] + [0.0, 2.5, 0.0]              # the lower lip down (image y down)
        yaw = 25.0 if i == 20 else 0.0
        pitch = {20: 0.0, 35: -20.0}.get(i, 3.0 * np.sin(i))
        out.append(12.0 * X @ _rot(yaw, pitch).T + [256.0, 256.0, 0.0])
    return np.array(out)


def test_head_angles_read_the_turn_and_the_nod():
    ref = _clip()
    yaw, pitch = hs.head_angles(ref)
    assert abs(yaw[0]) < 0.01 and abs(pitch[0]) < 0.01            # the face as it is: frontal
    assert abs(abs(yaw[20]) - 25.0) < 0.5 and abs(pitch[20]) < 0.5
    assert abs(abs(pitch[35]) - 20.0) < 0.5 and abs(yaw[35]) < 0.5
    assert abs(abs(pitch[5]) - 3.0 * abs(np.sin(5))) < 0.1


def test_hard_starts_find_each_hard_frame_and_keep_a_cut_long_enough():
    ref = _clip()
    picks = hs.hard_starts(ref)
    assert {k: v["frame"] for k, v in picks.items() if k != "easy"} == \
        {"yaw": 20, "pitch": 35, "blink": 50, "mouth": 65}
    assert abs(picks["yaw"]["value"]) == pytest.approx(25.0, abs=0.5)
    assert picks["blink"]["value"] == pytest.approx(0.0, abs=1e-6)
    assert picks["easy"]["frame"] not in (20, 35, 50, 65)
    # a hard frame too near the end (fewer than MIN_FRAMES after it) or before MARGIN: not taken
    late = ref[:65 + hs.MIN_FRAMES - 1]
    assert hs.hard_starts(late)["mouth"]["frame"] != 65
    early = np.concatenate([ref[20:21], ref])                        # the turn on frame 0 too
    assert hs.hard_starts(early)["yaw"]["frame"] == 21
    gap = ref.copy()
    gap[40] = np.nan                          # a frame the reference has no face on
    yaw, _ = hs.head_angles(gap)
    assert np.isnan(yaw[40]) and np.isfinite(np.delete(yaw, 40)).all()
    picks = hs.hard_starts(gap)
    assert {k: v["frame"] for k, v in picks.items() if k != "easy"} == \
        {"yaw": 20, "pitch": 35, "blink": 50, "mouth": 65}
    assert picks["easy"]["frame"] not in (20, 35, 40, 50, 65)


def test_canonical_face_is_in_the_axes_of_mediapipes_points():
    """As the references' points (pixels, y down; z smaller nearer the camera): the forehead
    (10) above the chin (152), the nose tip (4) nearer than the outer eye corner (33), the
    subject's right eye corner (33) left of the left one (263)."""
    C = _canonical()
    assert C[10, 1] < C[152, 1] - 10.0
    assert C[4, 2] < C[33, 2] - 3.0
    assert C[33, 0] < C[263, 0] - 8.0

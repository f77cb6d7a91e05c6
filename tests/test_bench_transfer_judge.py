"""The transfer judge's floor (benchmarks/bench_transfer_judge.py): each partial of a render
beside the pure render's, and the leak over it."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

bj = pytest.importorskip("bench_transfer_judge")


def _judged(partial, pose):
    return {"result_source": 0.9, "result_target": 0.2, "source_target": 0.1,
            "target_partial": partial, "target_partial_pose": pose, "amplitude": 1.0}


def test_add_floor_subtracts_the_pure_renders_partial_and_keeps_the_rest():
    after = {"eyeBlinkLeft": _judged(0.36, 0.31), "jawOpen": _judged(-0.01, 0.43)}
    pure = {"eyeBlinkLeft": _judged(0.25, 0.19), "jawOpen": _judged(0.13, float("nan"))}
    out = bj.add_floor(after, pure)
    blink = out["eyeBlinkLeft"]
    assert blink["target_partial_floor"] == 0.25 and blink["target_partial_pose_floor"] == 0.19
    assert blink["target_leak"] == pytest.approx(0.11)
    assert blink["target_leak_pose"] == pytest.approx(0.12)
    assert out["jawOpen"]["target_leak"] == pytest.approx(-0.14)   # below the floor: negative
    assert math.isnan(out["jawOpen"]["target_leak_pose"])
    for n in after:                                     # the old keys as they were, not mutated
        assert {k: out[n][k] for k in after[n]} == after[n]
        assert "target_leak" not in after[n]


def test_add_floor_without_the_pose_partial_adds_only_the_plain_floor():
    after = {"m": {"target_partial": 0.5}}
    out = bj.add_floor(after, {"m": {"target_partial": 0.2}, "other": {"target_partial": 0.0}})
    assert out == {"m": {"target_partial": 0.5, "target_partial_floor": 0.2,
                         "target_leak": pytest.approx(0.3)}}


def test_largest_leaks_orders_by_the_leak_not_the_partial():
    after = bj.add_floor({"a": _judged(0.6, 0.1), "b": _judged(0.3, 0.1), "c": _judged(0.1, 0.1),
                          "d": _judged(float("nan"), 0.1)},
                         {"a": _judged(0.55, 0.1), "b": _judged(0.0, 0.3), "c": _judged(-0.1, 0.0),
                          "d": _judged(0.0, -0.1)})
    assert [n for n, _ in bj.largest_leaks(after, top=3)] == ["b", "c", "a"]
    assert [n for n, _ in bj.largest_leaks(after, "target_leak_pose", top=1)] == ["d"]
    line = bj.leak_line("demo", after, top=1)
    assert "b +0.30/+0.00=+0.30" in line and np.isfinite(bj.largest_leaks(after)[0][1])

"""The shut-mouth benchmark's measures (benchmarks/bench_shut_mouth.py): its segments where a
lip gap stays below a level, and its split of a signal's spread into jitter and wander."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

sm = pytest.importorskip("bench_shut_mouth")


def test_shut_segments_are_long_runs_below_the_level_less_their_ends():
    x = np.full(100, 0.1)
    x[10:40] = 0.001                      # 30 frames shut
    x[50:55] = 0.001                      # too short
    x[70:90] = 0.002
    x[80] = np.nan                        # a frame without a face ends a run
    assert sm.shut_segments(x, 0.012, 8, 3) == [(13, 37), (73, 77), (84, 87)]
    assert sm.shut_segments(x, 0.012, 15, 3) == [(13, 37)]


def test_stillness_tells_jitter_from_wander():
    rng = np.random.default_rng(0)
    t = np.arange(400)
    noise = rng.normal(0.0, 0.01, 400)
    slow = 0.01 * np.sqrt(2.0) * np.sin(t / 40.0)
    seg = [(0, 200), (200, 400)]
    n, s = sm.stillness(noise, seg), sm.stillness(slow, seg)
    assert n["jitter"] == pytest.approx(0.01, rel=0.1) and n["wander"] < 0.3 * n["std"]
    assert s["wander"] == pytest.approx(s["std"], rel=0.05) and s["jitter"] < 0.05 * s["std"]
    assert sm.stillness(np.full(400, np.nan), seg)["std"] is None

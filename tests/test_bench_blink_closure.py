"""The capture benchmark's third reading of blinks (benchmarks/bench_capture.py): eyeBlink*
against the lids' closure that the reference's own points show."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

bc = pytest.importorskip("bench_capture")
import _mp_points as mp  # noqa: E402
from facetransfer.arkit import ARKIT_NAMES  # noqa: E402


def _blinking_points(gaps: np.ndarray) -> np.ndarray:
    """478 points per frame (F, 478, 2): eye corners 100 apart, each eye's two lid pairs
    ``gaps`` (F,) apart, the rest fixed."""
    F = len(gaps)
    P = np.zeros((F, 478, 2))
    P[:, mp.EYE_CORNERS[0]] = (-50.0, 0.0)
    P[:, mp.EYE_CORNERS[1]] = (50.0, 0.0)
    for pairs in mp.LIDS.values():
        for a, b in pairs:
            P[:, a, 1] = -gaps / 2
            P[:, b, 1] = gaps / 2
    return P


def test_the_lids_closure_and_each_scores_slope_on_it():
    """Lids 10 apart at rest (over an eye-corner distance of 100), shut to 0 in a blink: the
    closure is 1 - gap / 10 (exact, clipped at 0 where the eye opens wider than at rest); a
    score that is the closure reads slope 1, one that is 0.6 of it (plus 0.02) slope 0.6 and
    std ratio 0.6, at r 1."""
    gaps = np.array([10.0] * 12 + [8.0, 4.0, 0.0, 0.0, 4.0, 8.0] + [10.0] * 10 + [12.0])
    ref = _blinking_points(gaps)
    c = bc.lid_closure(ref, "Left")
    np.testing.assert_allclose(c, np.clip(1 - gaps / 10.0, 0, 1), atol=1e-12)
    F = len(gaps)
    ours, peer = np.zeros((F, len(ARKIT_NAMES))), np.zeros((F, len(ARKIT_NAMES)))
    for side in ("Left", "Right"):
        k = ARKIT_NAMES.index(f"eyeBlink{side}")
        ours[:, k] = c
        peer[:, k] = 0.6 * c + 0.02
    out = bc.blink_closure(ours, peer, ref)
    for eye in ("eyeBlinkLeft", "eyeBlinkRight"):
        assert out[eye]["ours"]["slope"] == pytest.approx(1.0, abs=1e-4)
        assert out[eye]["ours"]["std_ratio"] == pytest.approx(1.0, abs=1e-4)
        assert out[eye]["mediapipe"]["slope"] == pytest.approx(0.6, abs=1e-4)
        assert out[eye]["mediapipe"]["std_ratio"] == pytest.approx(0.6, abs=1e-4)
        assert out[eye]["mediapipe"]["corr"] == pytest.approx(1.0, abs=1e-4)


def test_a_frame_the_reference_lost_leaves_the_others_closure(tmp_path):
    """review56b: a frame without reference points (NaN) made the clip's median gap NaN, so
    every frame's closure, and the clip's slope and r, came out empty; it is now that frame's
    alone."""
    gaps = np.array([10.0] * 12 + [8.0, 4.0, 0.0, 0.0, 4.0, 8.0] + [10.0] * 10)
    ref = _blinking_points(gaps)
    ref[3] = np.nan
    c = bc.lid_closure(ref, "Right")
    want = np.clip(1 - gaps / 10.0, 0, 1)
    want[3] = np.nan
    np.testing.assert_allclose(c, want, atol=1e-12)
    F = len(gaps)
    ours = np.zeros((F, len(ARKIT_NAMES)))
    ours[:, ARKIT_NAMES.index("eyeBlinkRight")] = np.nan_to_num(c)
    out = bc.blink_closure(ours, ours, ref)["eyeBlinkRight"]["ours"]
    assert out["slope"] == pytest.approx(1.0, abs=1e-4) and out["corr"] == pytest.approx(1.0)

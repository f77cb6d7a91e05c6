"""MediaPipe's blendshape scores read by the capture fit (facetransfer.track.scores)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.errors import ShapeError
from facetransfer.track.detect import ClipDetections
from facetransfer.track.scores import (MIN_SCORE_STD, SCORED_SHAPES, fit_score_lines,
                                       score_targets)

JAW, BLINK = ARKIT_NAMES.index("jawOpen"), ARKIT_NAMES.index("eyeBlinkLeft")
FUN = ARKIT_NAMES.index("mouthFunnel")


def _clip(F=40, seed=0):
    rng = np.random.default_rng(seed)
    S = np.full((F, 52), np.nan)
    S[:, :51] = rng.uniform(0, 1, (F, 51))
    A = rng.uniform(0, 1, (F, 52))
    return A, S


def test_a_linear_score_maps_exactly_onto_the_activation():
    A, S = _clip()
    A[:, JAW] = 0.1 + 0.6 * S[:, JAW]                # our pass: the score, on another scale
    A[:, BLINK] = 0.9 - 0.3 * S[:, BLINK]            # a negative relation: |slope| is kept
    A[:, FUN] *= 0.5                                 # within the funnel's bound (MAX_SLOPE)
    line = fit_score_lines(A, S)
    assert line.slope[JAW] == pytest.approx(0.6) and line.offset[JAW] == pytest.approx(0.1)
    np.testing.assert_allclose(score_targets(line, S)[:, JAW], A[:, JAW], atol=1e-12)
    assert set(np.array(ARKIT_NAMES)[line.used()]) == set(SCORED_SHAPES)
    # the reduced major axis keeps our amplitude: std(target) == std(activation)
    t = score_targets(line, S)
    for n in SCORED_SHAPES:
        k = ARKIT_NAMES.index(n)
        assert t[:, k].std() == pytest.approx(A[:, k].std(), rel=0.05), n


def test_the_line_is_the_reduced_major_axis_not_the_regression():
    """With noise in our pass, ordinary least squares shrinks the slope by the correlation;
    the line used keeps the ratio of the standard deviations."""
    rng = np.random.default_rng(1)
    A, S = _clip(F=400)
    A[:, JAW] = 0.2 + 0.5 * S[:, JAW] + rng.normal(0, 0.1, 400)
    line = fit_score_lines(A, S)
    assert line.slope[JAW] == pytest.approx(A[:, JAW].std() / S[:, JAW].std())
    ols = np.polyfit(S[:, JAW], A[:, JAW], 1)[0]
    assert ols < 0.9 * line.slope[JAW]


def test_lost_frames_constant_scores_and_other_shapes_have_no_line():
    A, S = _clip()
    A[:5] = np.nan                                    # lost frames of the first pass
    S[5:12] = np.nan                                  # frames without a face
    S[:, BLINK] = 0.3 + MIN_SCORE_STD / 10 * np.sin(np.arange(len(S)))   # never moves
    line = fit_score_lines(A, S)
    ok = np.isfinite(A[:, JAW]) & np.isfinite(S[:, JAW])
    assert line.slope[JAW] == pytest.approx(A[ok, JAW].std() / S[ok, JAW].std())
    assert np.isnan(line.slope[BLINK])
    assert np.isnan(line.slope[ARKIT_NAMES.index("browInnerUp")])   # not a scored shape
    t = score_targets(line, S)
    assert np.isnan(t[5:12, JAW]).all() and np.isnan(t[:, BLINK]).all()
    assert np.nanmin(t) >= 0 and np.nanmax(t) <= 1
    few = fit_score_lines(A[:12], S[:12])              # 0 frames where both are known
    assert not few.used().any()


def test_bad_shapes_are_refused():
    A, S = _clip()
    with pytest.raises(ShapeError, match=r"\(F, 52\)"):
        fit_score_lines(A[:, :51], S[:, :51])
    with pytest.raises(ShapeError, match="scores must be"):
        ClipDetections(np.zeros((3, 68, 2)), np.zeros((3, 68, 2)), None, np.zeros((3, 51)))


def test_track_command_reads_the_scores_unless_told_not_to():
    """``track --no-scores`` gives the capture options of one pass (points and flow only);
    by default the second pass reads the scores (``CaptureOptions.scores``)."""
    import argparse

    from facetransfer.cli.track import add_track_options, track_settings
    from facetransfer.track.capture import CaptureOptions

    p = argparse.ArgumentParser()
    add_track_options(p)
    assert track_settings(p.parse_args([])).capture.scores == CaptureOptions().scores > 0
    assert track_settings(p.parse_args(["--no-scores"])).capture.scores == 0.0
    assert track_settings(p.parse_args(["--no-scores", "--smooth", "1"])).capture.smooth == 1.0


def test_a_funnel_line_steeper_than_the_bound_is_flattened_through_the_medians():
    """funnel55c: where our first pass's funnel moves 3 times as much as the detector's (on
    real clips: our false funnels of parted lips), the line's slope is bounded to MAX_SLOPE,
    passes through both medians (the rest levels) and its term is weighed by (3 / 1)², so one
    unit of the score weighs as before; the jaw's steep line is kept."""
    from facetransfer.track.scores import MAX_SLOPE

    assert MAX_SLOPE == {"mouthFunnel": 1.0}
    A, S = _clip(F=200)
    S[:, FUN] = 0.01 + 0.02 * np.sin(np.arange(200) / 7.0)
    A[:, FUN] = 3.0 * S[:, FUN]                       # a steep line: slope 3
    A[:, JAW] = 0.1 + 3.0 * S[:, JAW]
    line = fit_score_lines(A, S)
    assert line.slope[FUN] == pytest.approx(1.0) and line.weight[FUN] == pytest.approx(9.0)
    assert line.offset[FUN] == pytest.approx(np.median(A[:, FUN]) - np.median(S[:, FUN]))
    assert line.slope[JAW] == pytest.approx(3.0) and line.weight[JAW] == pytest.approx(1.0)
    t = score_targets(line, S)
    assert t[:, FUN].std() == pytest.approx(S[:, FUN].std(), rel=1e-9)   # the score's scale
    assert np.nanmedian(t[:, FUN]) == pytest.approx(np.median(A[:, FUN]), abs=1e-9)
    assert np.isnan(line.weight[ARKIT_NAMES.index("browInnerUp")])       # not a scored shape


def test_a_shape_the_first_pass_never_moved_has_a_flat_line_of_weight_one():
    """A shape whose first-pass activation is constant over the clip (std 0: slope 0) keeps
    the flat line it had before the bound, weighed 1; before the lead's mend its weight was
    0 / 0 = NaN, a NaN factor in every frame's term."""
    A, S = _clip(F=60)
    A[:, FUN] = 0.0
    line = fit_score_lines(A, S)
    assert line.slope[FUN] == 0.0 and line.weight[FUN] == 1.0
    assert np.isfinite(line.weight[line.used()]).all()
    assert np.all(score_targets(line, S)[:, FUN] == line.offset[FUN])

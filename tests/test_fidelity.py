"""The independent judge of transfer fidelity (facetransfer.fidelity) on real footage."""

from __future__ import annotations

import numpy as np


def test_a_result_equal_to_the_source_follows_it_exactly(data_dir):
    from facetransfer.fidelity import judge_frames
    from facetransfer.io.video import read_video

    src, fps = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=60)
    tgt, _ = read_video(data_dir / "video" / "WDA_KatieHill_000.mp4", max_frames=60)
    src, tgt = src[:, ::2, ::2], tgt[:, ::2, ::2]
    fid = judge_frames(src, tgt, src, fps=fps)
    # the same frames through the same detector: correlation 1 with the source
    assert abs(fid.with_source["jawOpen"] - 1.0) < 1e-6
    assert abs(fid.with_source["mouthOpening"] - 1.0) < 1e-6
    assert fid.with_target["jawOpen"] < 0.9
    assert abs(fid.with_source["gazeHorizontal"] - 1.0) < 1e-6
    assert abs(fid.with_source["gazeVertical"] - 1.0) < 1e-6
    line = fid.line()
    assert "jawOpen r=+1.00 with the source" in line and "\n" not in line
    assert "gaze +1.00 / " in line
    assert abs(fid.with_source["browInnerUp"] - 1.0) < 1e-6 and "brows +1.00 / " in line


def test_the_panels_judged_side_by_side_score_as_one_after_the_other(data_dir):
    """judge_frames scores its three sequences on threads: exactly the figures of scoring them
    one after the other (each its own landmarker in video mode; a second aspect too)."""
    from facetransfer.fidelity import fidelity_of, judge_frames, panel_scores
    from facetransfer.io.video import read_video

    src, fps = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=60)
    tgt, _ = read_video(data_dir / "video" / "WDA_KatieHill_000.mp4", max_frames=60)
    src, tgt = src[:, ::2, ::2], tgt[:, ::2, ::2]
    res = np.ascontiguousarray(src[:, :, ::-1])       # a mirrored source: another result
    aspects = (1.0, 1.0, 1.1)
    fid = judge_frames(src, tgt, res, fps=fps, aspects=aspects)
    one_by_one = fidelity_of(*(panel_scores(x, fps, a) for x, a in zip((src, tgt, res),
                                                                      aspects)))
    for got, want in ((fid.with_source, one_by_one.with_source),
                      (fid.with_target, one_by_one.with_target)):
        assert got.keys() == want.keys()
        np.testing.assert_array_equal(list(got.values()), list(want.values()))
    r = fid.with_source["mouthOpening"]         # judged, and not the source itself
    assert np.isfinite(r) and r < 0.999


def test_a_frozen_result_has_no_correlation(data_dir):
    from facetransfer.fidelity import judge_frames
    from facetransfer.io.video import read_video

    src, fps = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=20)
    frozen = np.repeat(src[:1], len(src), axis=0)
    fid = judge_frames(src, src, frozen, fps=fps)
    assert np.isnan(fid.with_source["jawOpen"])  # the result never moves: nothing to follow


def test_gaze_is_toward_the_subjects_left_and_up():
    from facetransfer.arkit import MEDIAPIPE_NAMES
    from facetransfer.fidelity import gaze

    S = np.zeros((3, 51))
    S[0, MEDIAPIPE_NAMES.index("eyeLookOutLeft")] = 0.6    # both eyes to the subject's left
    S[0, MEDIAPIPE_NAMES.index("eyeLookInRight")] = 0.4
    S[1, MEDIAPIPE_NAMES.index("eyeLookInLeft")] = 0.5     # to the right
    S[1, MEDIAPIPE_NAMES.index("eyeLookOutRight")] = 0.5
    S[2, MEDIAPIPE_NAMES.index("eyeLookDownLeft")] = 0.2   # down
    S[2, MEDIAPIPE_NAMES.index("eyeLookDownRight")] = 0.4
    np.testing.assert_allclose(gaze(S), [[0.5, 0.0], [-0.5, 0.0], [0.0, -0.3]])


def test_a_measure_that_does_not_move_is_said_so_not_printed_as_nan():
    """NaN (a score that does not move, a clip without a face) was printed as "+nan" in the
    demo's line; it is "–", explained once."""
    from facetransfer.fidelity import Fidelity

    names = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp", "mouthPucker",
             "mouthOpening", "gazeHorizontal", "gazeVertical")
    s = {n: 0.5 for n in names} | {"browInnerUp": float("nan")}
    t = {n: -0.25 for n in names}
    line = Fidelity(s, t).line()
    assert "nan" not in line and "brows – / -0.25" in line and "jawOpen r=+0.50" in line
    assert line.endswith("(–: a measure that does not move in one of the clips, or a clip "
                         "without a face)")
    assert "(–" not in Fidelity(t, t).line()

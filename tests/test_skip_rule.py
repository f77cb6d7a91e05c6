"""Frames the detector may not skip (:mod:`facetransfer.track.skip_rule`): where the eyes move,
by the last scores or by the picture, a frame between two shown ones is shown too."""

from __future__ import annotations

import numpy as np

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.track.detect import detect_clip
from facetransfer.track.skip_rule import (EYE_CHANGE_RATIO, EYE_SCORE_STEP, EYE_SCORES,
                                          eye_scores_moving, eyes_changed)

SIZE, F = 96, 14
BLINK = list(ARKIT_NAMES).index("eyeBlinkLeft")


def _points() -> np.ndarray:
    """iBUG-68 points of a face in a 96-pixel frame: eyes about (30, 40) and (66, 40), the
    nose's nine points about (48, 55), the rest along the chin."""
    P = np.zeros((68, 2))
    P[:, 0], P[:, 1] = np.linspace(16, 80, 68), 85.0
    t = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    for k, cx in ((36, 30.0), (42, 66.0)):
        P[k:k + 6] = np.stack([cx + 6 * np.cos(t), 40 + 2 * np.sin(t)], -1)
    P[27:36] = np.stack([np.r_[48, 48, 48, 48, 43, 45.5, 48, 50.5, 53],
                         np.r_[42, 46, 50, 54, 58, 59, 60, 59, 58]], -1)
    return P


def _texture() -> np.ndarray:
    """A grey texture of 2-pixel blocks, as busy about the nose as about the eyes."""
    rng = np.random.default_rng(3)
    tex = np.kron(rng.uniform(40, 215, (SIZE // 2, SIZE // 2)), np.ones((2, 2)))
    return np.repeat(tex[..., None], 3, axis=2).astype(np.uint8)


def _lid(frame: np.ndarray, cx: float, level: int = 20) -> np.ndarray:
    """``frame`` with a dark lid drawn over the eye at column ``cx``."""
    out = frame.copy()
    out[37:44, int(cx) - 7:int(cx) + 8] = level
    return out


class ScriptedDetector:
    """The 68 points of :func:`_points` on every frame, the 52 scores of ``scores(i)``;
    records the frames it is shown; its clock moves on a skipped frame."""

    warmup_frames = 0

    def __init__(self, scores=lambda i: np.zeros(52, np.float32)) -> None:
        self.i, self.shown, self.scores = 0, [], scores

    def detect_scored(self, frame):
        self.shown.append(self.i)
        s = self.scores(self.i)
        self.i += 1
        return _points_478(), s

    def skip(self, frame) -> None:
        self.i += 1


def _points_478() -> np.ndarray:
    """478 points whose iBUG-68 mapping is :func:`_points` (least squares through the
    mapping matrix, which has full row rank)."""
    from facetransfer.track.landmarks import mapping_matrix

    A = mapping_matrix(478)
    return np.linalg.lstsq(A, _points(), rcond=None)[0]


def test_eye_scores_moving_looks_at_the_last_two_shown_frames_per_frame_between():
    z = np.zeros(52, np.float32)
    blink = z.copy()
    blink[BLINK] = 0.3
    assert eye_scores_moving([z, z, blink], [False, True, False])   # 0.3 over 2 frames
    assert not eye_scores_moving([z, z, blink], [False, True, True])  # one frame shown
    small = z.copy()
    small[BLINK] = 2 * EYE_SCORE_STEP * 0.9                          # 0.9 step a frame
    assert not eye_scores_moving([z, z, small], [False, True, False])
    jaw = z.copy()
    jaw[list(ARKIT_NAMES).index("jawOpen")] = 0.9                   # not an eye score
    assert not eye_scores_moving([z, jaw], [False, False])
    nan = np.full(52, np.nan, np.float32)                             # a detector without scores
    assert not eye_scores_moving([nan, nan], [False, False])
    assert set(np.asarray(ARKIT_NAMES)[EYE_SCORES]) == {
        f"eye{k}{s}" for k in ("Blink", "Squint", "Wide") for s in ("Left", "Right")}


class _Read(list):
    """A list that records the indices read."""

    def __init__(self, items) -> None:
        super().__init__(items)
        self.read = []

    def __getitem__(self, i):
        self.read.append(i)
        return super().__getitem__(i)


def test_eye_scores_moving_reads_only_the_end_of_a_long_clip():
    """Asked before every frame, it read every frame's flag so far: a clip's detection did
    work quadratic in its length (an hour at 30 fps, 5.8e9 reads)."""
    n = 100_000
    z = np.zeros(52, np.float32)
    skipped = _Read([bool(i % 2) for i in range(n)])
    assert not eye_scores_moving([z] * n, skipped)
    assert sorted(skipped.read) == [n - 4, n - 3, n - 2, n - 1]


def test_eyes_changed_by_a_lid_not_by_the_whole_picture():
    grey = _texture()[..., 0]
    P = _points()
    assert eyes_changed(_lid(_texture(), 30)[..., 0], grey, P)           # a lid over one eye
    assert not eyes_changed(grey, grey, P)
    brighter = np.clip(grey.astype(int) + 25, 0, 255).astype(np.uint8)  # the light changes
    assert not eyes_changed(brighter, grey, P)
    shifted = np.roll(grey, 3, axis=1)                                   # the head moves
    assert not eyes_changed(shifted, grey, P)
    assert not eyes_changed(_lid(_texture(), 30)[..., 0], grey, np.full((68, 2), np.nan))
    # one pixel changed by 100 levels: under EYE_CHANGE_RATIO levels over the eye's box
    speck = grey.copy()
    speck[40, 30] = (int(grey[40, 30]) + 100) % 256
    assert not eyes_changed(speck, grey, P)
    assert eyes_changed(speck, grey, P * 0.15 + (26, 34))   # the same speck in a tiny eye
    assert EYE_CHANGE_RATIO < 100 / 4


def test_a_blink_on_a_frame_between_is_shown_by_the_picture():
    frames = [_texture() for _ in range(F)]
    frames[5] = _lid(frames[5], 30)                      # lids closed on frame 5 alone
    det = ScriptedDetector()
    got = detect_clip(frames, det, keep478=True, every=2, eyes=True)
    # 5 shown (its eye changed from 4), 6 too (changed back from 5), then every other frame
    assert det.shown == [0, 2, 4, 5, 6, 8, 10, 12]
    assert got.shown.tolist() == [i in det.shown for i in range(F)]
    plain = ScriptedDetector()
    detect_clip([_texture() for _ in range(F)], plain, keep478=True, every=2, eyes=True)
    assert plain.shown == list(range(0, F, 2))


def test_a_blink_under_way_in_the_scores_shows_the_next_frame():
    def scores(i):
        s = np.zeros(52, np.float32)
        s[BLINK] = 0.9 if i in (6, 7, 8) else 0.0
        return s

    det = ScriptedDetector(scores)
    got = detect_clip([_texture() for _ in range(F)], det, keep478=True, every=2, eyes=True)
    # 6 is 0.9 after 4's 0: 7 shown; 7 holds 0.9: 8 skipped; 9 shown (0 after 0.9): 10 shown
    assert det.shown == [0, 2, 4, 6, 7, 9, 10, 12]
    np.testing.assert_allclose(got.scores[8, BLINK], 0.45)   # between 7 and 9, interpolated
    np.testing.assert_allclose(got.scores[7, BLINK], 0.9)

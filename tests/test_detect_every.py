"""The detector shown one frame of ``every`` (detect_clip's ``every``; issue 13's target):
which frames it sees, and what the frames between are given."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.track.detect import between_detections, detect_clip

F, SIZE = 15, 96


def _frames() -> list[np.ndarray]:
    """A smooth random texture moving left by 1 pixel a frame (a window sliding right)."""
    rng = np.random.default_rng(5)
    tex = np.kron(rng.uniform(0, 255, (SIZE // 8, 2 * SIZE // 8, 3)), np.ones((8, 8, 1)))
    return [tex[:, t: t + SIZE].astype(np.uint8) for t in range(F)]


def _truth(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``i``'s 478 points, 68 of them (the first) and 52 scores, all linear in ``i``."""
    base = np.stack(np.meshgrid(np.linspace(30, 66, 26), np.linspace(30, 66, 19)), -1)
    q = base.reshape(-1, 2)[:478] + (1.0 * i, 0.5 * i)
    s = np.linspace(0, 1, 52, dtype=np.float32) * 0.5 + 0.02 * i
    return q, q[:68], s


class FixedDetector:
    """Points and scores linear in the frame index (known from its clock), no face in the
    frames of ``lost``; records the frames it was shown; it cannot skip a frame."""

    warmup_frames = 0

    def __init__(self, lost=()) -> None:
        self.i, self.shown, self.lost = 0, [], set(lost)

    def detect_scored(self, frame):
        i = self.i
        self.i += 1
        self.shown.append(i)
        if i in self.lost:
            return None, None
        q, _, s = _truth(i)
        return q, s


class LinearDetector(FixedDetector):
    """:class:`FixedDetector` whose clock ``skip`` moves on."""

    def skip(self, frame) -> None:
        self.i += 1


def _ibug(q: np.ndarray) -> np.ndarray:
    from facetransfer.track.landmarks import mediapipe_to_ibug

    return mediapipe_to_ibug(q)


def test_every_other_frame_shown_and_the_frames_between_interpolated_exactly():
    det = LinearDetector()
    got = detect_clip(_frames(), det, keep478=True, every=2)
    assert det.shown == list(range(0, F, 2))          # 0, 2, 4, ... (F odd: the last shown)
    for i in range(F):
        q, _, s = _truth(i)
        np.testing.assert_allclose(got.points478[i], q, atol=1e-4)
        np.testing.assert_allclose(got.points[i], _ibug(q), atol=1e-4)
        np.testing.assert_allclose(got.scores[i, :51], s[:51], atol=1e-6)
    # the flow is measured on every frame, skipped or not
    assert np.isfinite(got.flow[1:]).all(axis=(1, 2)).sum() >= F - 3


def test_every_three_frames_and_a_skipped_last_frame_moved_by_the_flow():
    det = LinearDetector()
    frames = _frames()[:11]                                # shown 0, 3, 6, 9; 10 skipped
    got = detect_clip(frames, det, keep478=True, every=3)
    assert det.shown == [0, 3, 6, 9]
    for i in (1, 2, 4, 5, 7, 8):
        np.testing.assert_allclose(got.points[i], _ibug(_truth(i)[0]), atol=1e-4)
    # after the last shown frame: its points moved by the point flow (the texture moves one
    # pixel left a frame), its scores held
    step = got.points[10] - got.points[9]
    ok = np.isfinite(got.flow[10]).all(axis=1)
    assert ok.sum() > 30
    np.testing.assert_allclose(step[ok], got.flow[10][ok])
    np.testing.assert_allclose(np.median(step[ok], axis=0), (-1.0, 0.0), atol=0.15)
    np.testing.assert_array_equal(got.scores[10], got.scores[9])


def test_a_frame_after_a_lost_face_is_always_shown():
    det = LinearDetector(lost={4})
    got = detect_clip(_frames(), det, keep478=True, every=2)
    # 4 has no face: 5 is shown (nothing to interpolate from), then every other frame again
    assert det.shown == [0, 2, 4, 5, 7, 9, 11, 13]
    assert not got.found[4] and got.found[3] and got.found[5]
    np.testing.assert_allclose(got.points[6], _ibug(_truth(6)[0]), atol=1e-4)


def test_every_one_and_a_detector_that_cannot_skip_see_every_frame():
    for every, det in ((1, LinearDetector()), (2, FixedDetector())):
        got = detect_clip(_frames(), det, keep478=True, every=every)
        assert det.shown == list(range(F))
        assert got.found.all()


def test_between_detections_interpolates_only_the_skipped_frames():
    P = np.zeros((5, 68, 2))
    P[0], P[4] = 10.0, 30.0
    P[1:4] = P[0]                                        # held while reading
    flow = np.full((5, 68, 2), np.nan)
    S = np.zeros((5, 52), np.float32)
    S[4] = 1.0
    raw = np.zeros((5, 478, 2), np.float32)
    raw[4] = 8.0
    skipped = np.array([False, True, True, True, False])
    P2, raw2, S2 = between_detections(P, flow, raw, S, skipped)
    np.testing.assert_allclose(P2[:, 0, 0], [10, 15, 20, 25, 30])
    np.testing.assert_allclose(S2[:, 3], [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(raw2[:, 7, 1], [0, 2, 4, 6, 8])
    assert P[2, 0, 0] == 10.0                            # the inputs are not changed


@pytest.mark.parametrize("every", [0, -1])
def test_every_below_one_shows_every_frame(every):
    det = LinearDetector()
    detect_clip(_frames()[:4], det, every=every)
    assert det.shown == [0, 1, 2, 3]


def test_the_frames_shown_are_kept_saved_joined_and_cut_with_the_detections(tmp_path):
    """``shown`` says which frames the detector saw: through a progress file, a join of two
    parts (the split detection) and a shot's cut; every frame shown is None."""
    from facetransfer.track.detect_checkpoint import DetectionCheckpoint
    from facetransfer.track.shots import shot_detections
    from facetransfer.track.video_detect import join_detections

    got = detect_clip(_frames(), LinearDetector(), keep478=True, every=2)
    np.testing.assert_array_equal(got.shown, np.arange(F) % 2 == 0)
    assert detect_clip(_frames(), LinearDetector(), keep478=True).shown is None
    ck = DetectionCheckpoint(tmp_path / "t.partial.npz", "k", every=1e9)
    ck.save(got)
    np.testing.assert_array_equal(ck.load().detections.shown, got.shown)
    whole = detect_clip(_frames()[:4], LinearDetector(), keep478=True)
    joined = join_detections(whole, got)
    np.testing.assert_array_equal(joined.shown, np.r_[np.ones(4, bool), got.shown])
    np.testing.assert_array_equal(shot_detections(got, 3, 9).shown, got.shown[3:9])
    with pytest.raises(ValueError, match=r"shown must be \(15,\)"):
        type(got)(got.points, got.flow, shown=np.ones(14, bool))


def test_a_frame_the_detector_did_not_see_is_half_as_sure(arkit_model):
    """The capture fit's confidence of an interpolated frame is halved
    (:data:`facetransfer.track.capture.UNSEEN_CONFIDENCE`), so a texture's reference frame is
    one the detector saw; the fit itself does not depend on ``shown``."""
    import dataclasses

    from facetransfer.track import capture
    from facetransfer.track.detect import ClipDetections
    from facetransfer.track.project import project_landmarks

    from conftest import synthetic_arkit_track

    tr = project_landmarks(synthetic_arkit_track(arkit_model, 8)[0], arkit_model)
    det = ClipDetections(tr.landmarks2d, np.full_like(tr.landmarks2d, np.nan))
    half = dataclasses.replace(det, shown=np.arange(8) % 2 == 0)
    a = capture.capture_detections(det, arkit_model, frame_size=tr.frame_size)
    b = capture.capture_detections(half, arkit_model, frame_size=tr.frame_size)
    np.testing.assert_array_equal(a.blendshapes, b.blendshapes)
    assert a.confidence.min() > 0
    np.testing.assert_allclose(b.confidence, a.confidence * np.where(half.shown, 1.0, 0.5))


def test_a_join_interpolates_across_it_and_a_resumed_run_across_its_start(tmp_path):
    """A part ending on a skipped frame (moved by the flow) is interpolated with the next
    part's first frame once joined; a run resumed after such a frame does the same."""
    from facetransfer.track.video_detect import join_detections

    frames = _frames()
    first = detect_clip(frames[:6], LinearDetector(), keep478=True, every=2)   # 5 skipped
    assert not first.shown[5]
    det = LinearDetector()
    det.i = 6
    second = detect_clip(frames[6:], det, keep478=True, every=2)
    joined = join_detections(first, second)
    whole = detect_clip(frames, LinearDetector(), keep478=True, every=2)
    np.testing.assert_allclose(joined.points[5], _ibug(_truth(5)[0]), atol=1e-4)
    np.testing.assert_allclose(joined.points, whole.points, atol=1e-4)
    np.testing.assert_array_equal(joined.shown, whole.shown)
    det = LinearDetector()
    det.i = 6
    resumed = detect_clip(frames, det, keep478=True, every=2, resume=first)
    np.testing.assert_allclose(resumed.points, whole.points, atol=1e-4)
    np.testing.assert_array_equal(resumed.shown, whole.shown)


def _cut_frames(cut: int, n: int = 30) -> list[np.ndarray]:
    """A drifting texture, then from frame ``cut`` another one (a cut to another shot)."""
    rng = np.random.default_rng(9)
    a, b = (np.kron(rng.uniform(0, 255, (SIZE // 8, 2 * SIZE // 8 + 8, 3)), np.ones((8, 8, 1)))
            for _ in range(2))
    return [(a if t < cut else b)[:, t: t + SIZE].astype(np.uint8) for t in range(n)]


class CutDetector(LinearDetector):
    """:class:`LinearDetector`'s face moved 60 px down from frame ``cut`` on (another shot),
    or none there (``face=False``)."""

    def __init__(self, cut: int, face: bool = True) -> None:
        super().__init__()
        self.cut, self.face = cut, face

    def detect_scored(self, frame):
        i = self.i
        q, s = super().detect_scored(frame)
        if i >= self.cut:
            return (q + (0.0, 60.0), s) if self.face else (None, None)
        return q, s


@pytest.mark.parametrize("cut", [21, 22])
def test_no_frame_is_interpolated_across_a_cut(cut):
    """A frame whose picture changed as at a cut is shown (21); a skipped frame before a cut
    (21, the cut at 22) is the old shot's last frame moved by the flow, not half-way to the
    new shot's face."""
    det = CutDetector(cut)
    got = detect_clip(_cut_frames(cut), det, keep478=True, every=2)
    assert cut in det.shown and got.shown[cut]
    np.testing.assert_allclose(got.points[cut], _ibug(_truth(cut)[0] + (0.0, 60.0)), atol=1e-4)
    before = got.points[cut - 1] - _ibug(_truth(cut - 1)[0])   # the old face, not moved down
    assert np.abs(np.median(before, axis=0)).max() < 2.5


def test_a_cut_to_a_shot_without_a_face_leaves_no_face_held():
    det = CutDetector(21, face=False)
    got = detect_clip(_cut_frames(21), det, keep478=True, every=2)
    assert got.found[:21].all() and not got.found[21:].any()


def test_a_skipped_frame_whose_flow_failed_is_lost_and_partial_failures_take_the_median():
    P = np.zeros((3, 68, 2))
    P[0] = np.arange(68)[:, None]
    P[1] = P[0]
    flow = np.full((3, 68, 2), np.nan)
    S = np.zeros((3, 52), np.float32)
    raw = np.zeros((3, 478, 2), np.float32)
    skipped = np.array([False, True, False])
    P[2] = np.nan                                        # the next shown frame: no face
    lost, _, _ = between_detections(P, flow, raw, S, skipped)
    assert np.isnan(lost[1]).all()
    flow[1, :60] = (2.0, 1.0)                            # 8 points failed: the median step
    moved, raw2, _ = between_detections(P, flow, raw, S, skipped)
    np.testing.assert_allclose(moved[1] - P[0], np.tile((2.0, 1.0), (68, 1)))
    np.testing.assert_allclose(raw2[1], np.tile((2.0, 1.0), (478, 1)))

"""The capture's point flow and picture change on large frames (facetransfer.track.detect):
worked on the face's box and on whole blocks, as the whole frame gives them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facetransfer.track import detect
from facetransfer.track.detect import picture_change, point_flow, thumbnail


def _texture(shape, seed=0):
    """A smooth random grey texture (Lucas-Kanade needs gradients everywhere)."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (shape[0] // 8 + 2, shape[1] // 8 + 2)).astype(np.float32)
    big = cv2.resize(small, (shape[1] + 16, shape[0] + 16), interpolation=cv2.INTER_CUBIC)
    return big


def _shifted(tex, shape, dx, dy):
    """``shape`` of ``tex`` seen moved by (dx, dy) pixels (bilinear), uint8."""
    H, W = shape
    M = np.float32([[1, 0, dx - 8], [0, 1, dy - 8]])
    return np.clip(cv2.warpAffine(tex, M, (W, H), flags=cv2.INTER_LINEAR), 0, 255).astype(
        np.uint8)


@pytest.mark.parametrize("shift", [(2.5, -1.25), (-7.0, 4.5)])
def test_the_flow_on_the_faces_box_of_a_1080p_frame_is_the_whole_frames(shift, monkeypatch):
    shape = (1080, 1920)
    tex = _texture(shape)
    a, b = _shifted(tex, shape, 0.0, 0.0), _shifted(tex, shape, *shift)
    rng = np.random.default_rng(1)
    pts = np.array([900.0, 400.0]) + rng.uniform(0, 350, (68, 2))   # a face 350 px across
    pts[5] = np.nan                                                   # an unknown point
    assert detect._flow_box(pts[np.isfinite(pts).all(1)], shape, 21, 2) is not None
    crop = point_flow(a, b, pts)
    monkeypatch.setattr(detect, "FLOW_CROP_SHARE", 0.0)               # never cropped
    whole = point_flow(a, b, pts)
    assert np.isnan(crop[5]).all() and np.isnan(whole[5]).all()
    ok = np.isfinite(whole).all(1)
    assert ok.sum() >= 60 and np.array_equal(ok, np.isfinite(crop).all(1))
    np.testing.assert_allclose(crop[ok], whole[ok], atol=0.03)       # LK's own tolerance
    np.testing.assert_allclose(np.median(crop[ok], axis=0), shift, atol=0.05)


@pytest.mark.parametrize("shift", [(1.5, -0.75), (-4.0, 2.5)])
def test_the_flow_of_a_face_filling_a_512_frame_is_on_its_box_as_the_whole_frames(
        shift, monkeypatch):
    """Issue 13's frames (512x480, a face half of it and more): the flow on the face's box
    (its pyramids and derivatives a third smaller), within Lucas-Kanade's tolerance of the
    whole frame's."""
    shape = (480, 512)
    tex = _texture(shape, seed=5)
    a, b = _shifted(tex, shape, 0.0, 0.0), _shifted(tex, shape, *shift)
    rng = np.random.default_rng(2)
    pts = np.array([150.0, 110.0]) + rng.uniform(0, 230, (68, 2))   # a face 230 px across
    rows, cols = detect._flow_box(pts, shape, 21, 2)
    assert (rows.stop - rows.start) * (cols.stop - cols.start) < 0.75 * shape[0] * shape[1]
    crop = point_flow(a, b, pts)
    monkeypatch.setattr(detect, "FLOW_CROP_SHARE", 0.0)               # never cropped
    whole = point_flow(a, b, pts)
    ok = np.isfinite(whole).all(1)
    assert ok.sum() >= 60 and np.array_equal(ok, np.isfinite(crop).all(1))
    np.testing.assert_allclose(crop[ok], whole[ok], atol=0.03)
    np.testing.assert_allclose(np.median(crop[ok], axis=0), shift, atol=0.05)


def test_the_flows_error_is_the_cheap_one_and_its_points_are_the_defaults(monkeypatch):
    """Lucas-Kanade is asked for the minimum eigenvalue as its (unread) error, which skips a
    pass over every window; the points and status are those of the default error."""
    shape = (480, 512)
    tex = _texture(shape, seed=7)
    a, b = _shifted(tex, shape, 0.0, 0.0), _shifted(tex, shape, 2.25, 1.0)
    pts = np.array([140.0, 120.0]) + np.random.default_rng(3).uniform(0, 240, (68, 2))
    real, flags = cv2.calcOpticalFlowPyrLK, []

    def spy(*args, **kwargs):
        flags.append(kwargs.get("flags", 0))
        return real(*args, **kwargs)

    monkeypatch.setattr(cv2, "calcOpticalFlowPyrLK", spy)
    got = point_flow(a, b, pts)
    assert flags == [cv2.OPTFLOW_LK_GET_MIN_EIGENVALS] * 2
    monkeypatch.setattr(detect, "_LK_FLAGS", 0)
    np.testing.assert_array_equal(got, point_flow(a, b, pts))
    assert np.isfinite(got).all(1).sum() >= 60


def test_the_flows_box_sits_on_the_top_levels_grid_and_only_when_small(monkeypatch):
    pts = np.array([[1001.3, 533.7], [1200.9, 790.2]])
    rows, cols = detect._flow_box(pts, (1080, 1920), 21, 2)
    m = (21 // 2 + detect.FLOW_SLACK) * 4
    assert cols.start % 4 == 0 and rows.start % 4 == 0
    assert cols.start <= 1001.3 - m and cols.stop >= 1200.9 + m
    assert rows.start <= 533.7 - m and rows.stop >= 790.2 + m
    # the same face in a 512x480 frame covers most of it: still its box (FLOW_CROP_SHARE 1),
    # or the whole frame where a box may be at most a quarter of the frame
    rows, cols = detect._flow_box(pts - (900, 450), (480, 512), 21, 2)
    assert (rows.stop - rows.start) * (cols.stop - cols.start) > 0.25 * 480 * 512
    assert rows.start >= 0 and cols.start >= 0 and rows.stop <= 480 and cols.stop <= 512
    monkeypatch.setattr(detect, "FLOW_CROP_SHARE", 0.25)
    assert detect._flow_box(pts - (900, 450), (480, 512), 21, 2) is None
    # a box reaching past the frame is clipped to it
    rows, cols = detect._flow_box(np.array([[5.0, 3.0], [300.0, 200.0]]), (1080, 1920), 21, 2)
    assert rows.start == 0 and cols.start == 0


def test_the_thumbnail_of_a_large_frame_by_whole_blocks_is_the_area_average():
    tex = _texture((1080, 1920), seed=3)
    a, b = _shifted(tex, (1080, 1920), 0, 0), _shifted(tex, (1080, 1920), 40.0, 0.0)
    direct = cv2.resize(a, (32, 32), interpolation=cv2.INTER_AREA).astype(np.float32)
    t = thumbnail(a)
    assert t.shape == (32, 32) and t.dtype == np.float32
    assert np.abs(t - direct).max() <= 1.0
    change = np.abs(cv2.resize(a, (32, 32), interpolation=cv2.INTER_AREA).astype(np.float32)
                    - cv2.resize(b, (32, 32), interpolation=cv2.INTER_AREA)).mean()
    assert change > 1.0 and picture_change(a, b) == pytest.approx(change, rel=0.02)
    # a small frame: exactly OpenCV's area average, as before
    small = a[:480, :512]
    np.testing.assert_array_equal(
        thumbnail(small), cv2.resize(small, (32, 32), interpolation=cv2.INTER_AREA))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.integers(16, 4000), st.integers(16, 3000), st.integers(1, 68),
       st.floats(-500, 4500), st.floats(-500, 3500), st.floats(0, 900), st.integers(0, 3))
def test_the_flows_box_lies_in_the_frame_and_holds_the_points_grown(W, H, n, x, y, spread,
                                                                    levels):
    """Points anywhere (in, across or out of frames of any size): a box, when one is taken,
    lies inside the frame, starts on the top level's grid, holds every point's neighbourhood
    that lies in the frame, and is at most the share of the frame; no box otherwise."""
    rng = np.random.default_rng(n)
    pts = np.array([x, y]) + rng.uniform(0, spread, (n, 2))
    box = detect._flow_box(pts, (H, W), 21, levels)
    if box is None:
        return
    rows, cols = box
    step, m = 2 ** levels, (21 // 2 + detect.FLOW_SLACK) * 2 ** levels
    assert 0 <= cols.start < cols.stop <= W and 0 <= rows.start < rows.stop <= H
    assert cols.start % step == 0 and rows.start % step == 0
    assert (cols.stop - cols.start) * (rows.stop - rows.start) <= detect.FLOW_CROP_SHARE * H * W
    assert cols.start <= max(pts[:, 0].min() - m, 0) and rows.start <= max(pts[:, 1].min() - m, 0)
    assert cols.stop >= min(pts[:, 0].max() + m, W) and rows.stop >= min(pts[:, 1].max() + m, H)


def _katie(data_dir, stop: int):
    """``WDA_KatieHill_000``'s first ``stop`` frames (RGB, 512 px) and their iBUG-68 points
    from the data folder's MediaPipe reference."""
    from facetransfer.io.video_read import iter_frames
    from facetransfer.track.landmarks import mediapipe_to_ibug

    clip = data_dir / "video" / "WDA_KatieHill_000.mp4"
    frames = list(iter_frames(clip, stop=stop))
    ref = np.load(clip.with_name("WDA_KatieHill_000.mediapipe478.npz"))["landmarks"][:stop]
    return frames, np.stack([mediapipe_to_ibug(q[:, :2]) for q in ref])


def _grey4(rgb):
    """A 512 px frame's grey image four times larger (2048 px: a face of 4K footage)."""
    return cv2.resize(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), None, fx=4, fy=4,
                      interpolation=cv2.INTER_CUBIC)


def test_the_flow_keeps_a_face_four_times_larger_as_it_keeps_the_face(data_dir):
    """The flow's pixel settings grow with the face (:func:`detect.flow_scale`): a real clip's
    40 frames four times larger lose about the points the clip loses at its own size, and move
    the kept ones four times as far. In fixed pixels they lost 22-94 % of the points a frame
    (the clip itself 0-68 %), a frame carried by the flow losing its face past 80 %."""
    frames, P = _katie(data_dir, 40)
    G = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    lost1, lost4, err = [], [], []
    for i in range(39):
        f1 = point_flow(G[i], G[i + 1], P[i])
        f4 = point_flow(_grey4(frames[i]), _grey4(frames[i + 1]), 4 * P[i])
        assert detect.flow_scale(P[i]) == 1.0 and detect.flow_scale(4 * P[i]) > 2.5
        ok1, ok4 = np.isfinite(f1).all(1), np.isfinite(f4).all(1)
        lost1.append(1 - ok1.mean())
        lost4.append(1 - ok4.mean())
        both = ok1 & ok4
        eye = np.linalg.norm(P[i, 36] - P[i, 45])
        err.append(np.median(np.linalg.norm(f4[both] / 4 - f1[both], axis=1)) / eye)
    lost1, lost4 = np.array(lost1), np.array(lost4)
    assert lost4.mean() <= 0.15 and (lost4 <= lost1 + 0.25).all()
    assert np.median(err) < 0.005                   # a 512 px face's eyes: 0.8 px of ~160


def _carried(frames, P, k: int) -> np.ndarray:
    """``detect_clip(every=2)`` of two frames ``k`` times larger, the first shown to a detector
    that gives ``k`` times its reference points ``P`` (2, 68, 2): the second frame's points,
    carried by the flow (no shown frame after it), divided by ``k``."""

    class Detector:
        """The reference points of the frames it is shown; it can skip one."""

        def __init__(self):
            self.seen = 0

        def detect(self, fr):
            self.seen += 1
            return k * P[self.seen - 1]

        def skip(self, fr):
            self.seen += 1

    big = [cv2.resize(f, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC) for f in frames]
    det = detect.detect_clip(big, Detector(), every=2)
    assert det.shown.tolist() == [True, False]
    return det.points[1] / k


def test_a_4k_faces_last_frame_carried_by_the_flow_keeps_its_face(data_dir):
    """``detect_clip``'s ``every`` = 2 (the transfer's ``--speed fast``) on two frames (a fast
    turn) of a face four times larger: the last frame, never shown to the detector, is carried
    by the flow and keeps its face, as near the detector's points as at 512 px, and far nearer
    than the frame before (it was lost: 87 % of the points' flow failed at the fixed
    settings)."""
    frames, P = _katie(data_dir, 35)
    eye = np.linalg.norm(P[34, 36] - P[34, 45])
    err = {k: np.linalg.norm(_carried(frames[33:], P[33:], k) - P[34], axis=1).mean() / eye
           for k in (1, 4)}                                # 0.027 and 0.028 eye distances
    held = np.linalg.norm(P[33] - P[34], axis=1).mean() / eye          # 0.075
    assert np.isfinite(err[4]) and err[4] <= 1.2 * err[1] and err[4] < 0.5 * held


def test_the_flows_scale_is_one_on_the_data_clips_and_the_rewrites_rule_beyond(data_dir):
    """The data folder's clips (every frame's reference points) keep the flow's pixel settings
    as they are, so their tracks are as before to the bit; beyond, the factor is the rewrite's
    (:func:`facetransfer.face_scale.face_scale`) of the points' eye centres' distance."""
    from facetransfer.face_scale import FACE_SPAN, face_scale
    from facetransfer.track.landmarks import mediapipe_to_ibug

    assert detect.FLOW_SPAN == FACE_SPAN
    for name in ("WDA_KatieHill_000", "driving_d6", "driving_d9", "face_2"):
        ref = np.load(data_dir / "video" / f"{name}.mediapipe478.npz")["landmarks"]
        scales = [detect.flow_scale(mediapipe_to_ibug(q[:, :2])) for q in ref]
        assert max(scales) == 1.0, name
    pts = np.zeros((68, 2))
    pts[36:42], pts[42:48] = (100.0, 300.0), (100.0 + 2.5 * FACE_SPAN, 300.0)
    assert detect.flow_scale(pts) == pytest.approx(face_scale(2.5 * FACE_SPAN)) == 2.5
    pts[36:42] = np.nan                                     # no eye: the settings as they are
    assert detect.flow_scale(pts) == 1.0 and detect.flow_scale(pts[:30]) == 1.0

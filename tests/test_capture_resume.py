"""Resuming the capture tracker's detections (facetransfer.track.detect_checkpoint, issue 12)."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.io.video import iter_frames, write_video
from facetransfer.track.checkpoint import video_identity
from facetransfer.track.detect import ClipDetections, detect_clip
from facetransfer.track.detect_checkpoint import (DetectionCheckpoint, detection_key,
                                                  landmarker_identity)
from facetransfer.track.result import Track

F, SIZE, NO_FACE = 36, 128, 5


def _digest(frame: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(frame).tobytes()).hexdigest()


@pytest.fixture(scope="module")
def clip(tmp_path_factory, data_dir):
    """A small synthetic video (a smooth texture drifting right) and face-like points for each
    of its decoded frames (MediaPipe's reference points of face_2, scaled into the frame)."""
    rng = np.random.default_rng(3)
    tex = rng.uniform(0, 255, (SIZE // 8, 2 * SIZE // 8, 3))
    tex = np.kron(tex, np.ones((8, 8, 1)))
    frames = [np.clip(tex[:, t: t + SIZE] + rng.normal(0, 3, (SIZE, SIZE, 3)), 0, 255)
              .astype(np.uint8) for t in range(F)]
    video = tmp_path_factory.mktemp("resume") / "clip.mp4"
    write_video(video, frames, 25.0)
    with np.load(data_dir / "video" / "face_2.mediapipe478.npz") as z:
        ref = z["landmarks"][:F, :, :2] * (SIZE / 844.0)
    index = {_digest(fr): i for i, fr in enumerate(iter_frames(video))}
    assert len(index) == F                                  # every frame is told apart
    return video, index, ref.astype(np.float32)


class FakeDetector:
    """Deterministic stand-in for MediaPipe in video mode: a frame's points depend on it and on
    the frame shown before it (a tracking state one frame deep, hence ``warmup_frames = 1``);
    frame :data:`NO_FACE` has no face. Counts its calls; may stop (KeyboardInterrupt) at one."""

    warmup_frames = 1

    def __init__(self, clip, stop_at: int | None = None) -> None:
        _, self.index, self.ref = clip
        self.calls = 0
        self.stop_at = stop_at
        self.prev = None

    def detect478(self, frame):
        i = self.index[_digest(frame)]
        if i == self.stop_at:
            raise KeyboardInterrupt
        self.calls += 1
        prev, self.prev = self.prev, i
        if i == NO_FACE:
            return None
        q = self.ref[i].astype(np.float64)
        return q if prev is None else q + 0.25 * (self.ref[prev] - q)

    def close(self) -> None:
        pass


class ScoredDetector(FakeDetector):
    """:class:`FakeDetector` with blendshape scores (``detect_scored``, as MediaPipe's
    landmarker made with blendshapes): jawOpen rises through the clip, the rest stay small."""

    def detect_scored(self, frame):
        i = self.index[_digest(frame)]
        q = self.detect478(frame)
        if q is None:
            return None, None
        s = np.full(52, np.nan, np.float32)
        s[:51] = 0.05
        s[0] = 0.1 + 0.02 * i                            # a score that moves
        from facetransfer.arkit import ARKIT_NAMES
        s[ARKIT_NAMES.index("jawOpen")] = 0.5 + 0.4 * np.sin(i / 4.0)
        return q, s


def _equal(a: ClipDetections, b: ClipDetections) -> None:
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.flow, b.flow)
    np.testing.assert_array_equal(a.points478, b.points478)
    assert (a.scores is None) == (b.scores is None)
    if a.scores is not None:
        np.testing.assert_array_equal(a.scores, b.scores)


def _key(video, max_frames=None):
    return detection_key(video_identity(str(video)), max_frames, "fake")


def _stop_at(k):
    """A progress callback interrupting the run once ``k`` frames are done."""
    def stop(done, total):
        if done == k:
            raise KeyboardInterrupt
    return stop


def test_interrupted_detection_continues_exactly_where_it_stopped(clip, tmp_path):
    """Stopped after k frames, a second run detects only frames k.. (plus the detector's one
    warm-up frame) and gives exactly the uninterrupted run's detections, flow included."""
    video = clip[0]
    full = detect_clip(iter_frames(video), FakeDetector(clip), keep478=True)
    assert np.isfinite(full.flow[1:]).any() and not full.found[NO_FACE]
    k = 17
    ck = DetectionCheckpoint(tmp_path / "t.partial.npz", _key(video), every=1e9)
    with pytest.raises(KeyboardInterrupt):
        detect_clip(iter_frames(video), FakeDetector(clip), keep478=True, progress=_stop_at(k),
                    checkpoint=ck)
    saved = ck.load()
    assert saved is not None and saved.detections.n_frames == k and not saved.complete
    # interrupted again while skipping the frames done (nothing new: the same file), then
    # after a few new frames
    with pytest.raises(KeyboardInterrupt):
        detect_clip(iter_frames(video), FakeDetector(clip), keep478=True, progress=_stop_at(5),
                    resume=saved.detections, checkpoint=ck)
    _equal(ck.load().detections, saved.detections)
    k2 = k + 6
    with pytest.raises(KeyboardInterrupt):
        detect_clip(iter_frames(video), FakeDetector(clip), keep478=True, progress=_stop_at(k2),
                    resume=saved.detections, checkpoint=ck)
    again = ck.load().detections
    assert again.n_frames == k2
    _equal(again, ClipDetections(full.points[:k2], full.flow[:k2], full.points478[:k2]))
    det = FakeDetector(clip)
    res = detect_clip(iter_frames(video), det, keep478=True, resume=saved.detections,
                      checkpoint=ck)
    assert det.calls == F - k + FakeDetector.warmup_frames
    _equal(res, full)
    # without the warm-up frame the tracking state differs at the seam (and only there)
    det.warmup_frames = 0
    det.prev = None
    cold = detect_clip(iter_frames(video), det, keep478=True, resume=saved.detections)
    same = (cold.points478 == full.points478) | np.isnan(full.points478)
    differs = np.flatnonzero(~np.all(same, axis=(1, 2)))
    assert differs.tolist() == [k]


def test_scores_are_saved_and_resumed_with_the_detections(clip, tmp_path):
    """The blendshape scores go into the progress file and come back exactly; a resumed run's
    scores equal an uninterrupted run's, the no-face frame's are NaN."""
    video = clip[0]
    full = detect_clip(iter_frames(video), ScoredDetector(clip), keep478=True)
    assert full.scores.shape == (F, 52) and np.isnan(full.scores[NO_FACE]).all()
    assert np.isnan(full.scores[:, -1]).all()               # tongueOut: never scored
    ck = DetectionCheckpoint(tmp_path / "t.partial.npz", _key(video), every=1e9)
    with pytest.raises(KeyboardInterrupt):
        detect_clip(iter_frames(video), ScoredDetector(clip), keep478=True,
                    progress=_stop_at(11), checkpoint=ck)
    saved = ck.load()
    assert saved.detections.scores.shape == (11, 52)
    res = detect_clip(iter_frames(video), ScoredDetector(clip), keep478=True,
                      resume=saved.detections, checkpoint=ck)
    _equal(res, full)


def test_periodic_saves_hold_every_finished_frame(clip, tmp_path):
    """``every=0``: saved after each frame; stopped inside the detector at frame k, the file
    holds frames 0..k-1, equal to the uninterrupted run's."""
    video = clip[0]
    full = detect_clip(iter_frames(video), FakeDetector(clip), keep478=True)
    ck = DetectionCheckpoint(tmp_path / "t.partial.npz", _key(video), every=0, budget=np.inf)
    with pytest.raises(KeyboardInterrupt):
        detect_clip(iter_frames(video), FakeDetector(clip, stop_at=9), keep478=True,
                    checkpoint=ck)
    assert ck.saves == 9 + 1                                 # 9 frames, then the interrupt
    saved = ck.load().detections
    assert saved.n_frames == 9
    _equal(saved, ClipDetections(full.points[:9], full.flow[:9], full.points478[:9]))
    assert saved.points.dtype == np.float64 and saved.points478.dtype == np.float32


def test_a_progress_file_of_another_run_is_ignored(clip, tmp_path, caplog):
    video = clip[0]
    path = tmp_path / "t.partial.npz"
    ck = DetectionCheckpoint(path, _key(video), every=1e9)
    det = detect_clip(iter_frames(video, stop=6), FakeDetector(clip), keep478=True)
    ck.save(det)
    assert ck.load() is not None
    for other in (DetectionCheckpoint(path, _key(video, max_frames=20)),          # frame limit
                  DetectionCheckpoint(path, detection_key("other", None, "fake")),  # video
                  DetectionCheckpoint.for_video(path, video, None)):            # detector
        caplog.clear()
        with caplog.at_level("WARNING"):
            assert other.load() is None
        assert "of another run (another video" in caplog.text and path.is_file()
    # the klt tracker's progress file (same name) is not taken for detections
    np.savez(path, key=np.array("klt run"), next_frame=np.array(3))
    with caplog.at_level("WARNING"):
        assert ck.load() is None
    assert "klt tracker" in caplog.text and path.is_file()
    # a damaged one is removed
    for junk in (b"", b"not an npz"):
        path.write_bytes(junk)
        assert ck.load() is None and not path.exists()
    np.savez(path, key=np.array(ck.key), points=np.zeros((3, 68, 2)))  # entries missing
    assert ck.load() is None and not path.exists()


def test_the_default_detector_is_identified_by_its_asset():
    ident = landmarker_identity()
    assert "64184e229b263107" in ident and ident.endswith("warmup20")


class _Fakes:
    """The fake detectors the capture tracker created; ``stop_at`` for the next ones."""

    def __init__(self, clip) -> None:
        self.clip, self.made, self.stop_at = clip, [], None

    def __call__(self, *a, **k) -> FakeDetector:
        self.made.append(FakeDetector(self.clip, self.stop_at))
        return self.made[-1]


@pytest.fixture()
def fakes(clip, monkeypatch):
    """The capture tracker's MediaPipe replaced by :class:`FakeDetector` (one per run)."""
    from facetransfer.track import video_detect

    f = _Fakes(clip)
    monkeypatch.setattr(video_detect, "FollowingLandmarker", f)
    return f


def test_cli_capture_continues_an_interrupted_run(clip, quick_model_path, tmp_path, capsys,
                                                  fakes):
    video = clip[0]
    out, ref, partial = tmp_path / "t.npz", tmp_path / "ref.npz", tmp_path / "t.partial.npz"
    args = ["track", str(video), "--model", str(quick_model_path), "--out", str(out)]
    assert main(args[:-1] + [str(ref)]) == 0 and not (tmp_path / "ref.partial.npz").exists()
    capsys.readouterr()
    fakes.stop_at = 0                 # before the first frame: nothing saved, none promised
    assert main(args) == 130 and not partial.exists()
    # one line (the progress was said on a line of its own before the CLI's)
    assert capsys.readouterr().err.splitlines() == [
        "facetransfer track: interrupted; no progress was saved yet: the same command starts "
        "again"]
    fakes.stop_at = 20                                       # interrupted in frame 20
    assert main(args) == 130
    assert capsys.readouterr().err.splitlines() == [
        f"facetransfer track: interrupted; the progress is in {partial}: run the same command "
        "again to continue"]
    assert partial.is_file() and not out.exists()
    fakes.stop_at = None
    assert main(args) == 0
    assert "continued an interrupted run from frame 20" in capsys.readouterr().out
    assert fakes.made[-1].calls == F - 20 + FakeDetector.warmup_frames
    assert not partial.exists()
    a, b = Track.load(out), Track.load(ref)
    np.testing.assert_allclose(a.landmarks2d, b.landmarks2d, atol=1e-9)
    for m in b.weights:
        np.testing.assert_allclose(a.weights[m], b.weights[m], atol=1e-9)


def test_cli_capture_interrupted_while_fitting_keeps_every_detection(
        clip, quick_model_path, tmp_path, capsys, fakes, monkeypatch):
    from facetransfer.track import capture

    video = clip[0]
    out, partial = tmp_path / "t.npz", tmp_path / "t.partial.npz"
    args = ["track", str(video), "--model", str(quick_model_path), "--out", str(out),
            "--max-frames", "12"]
    real_fit = capture.capture_detections

    def fit_stops(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(capture, "capture_detections", fit_stops)
    assert main(args) == 130
    assert "run the same command again" in capsys.readouterr().err and partial.is_file()
    monkeypatch.setattr(capture, "capture_detections", real_fit)
    n_made = len(fakes.made)
    assert main(args) == 0
    assert "continued an interrupted run from frame 12" in capsys.readouterr().out
    assert len(fakes.made) == n_made and not partial.exists()        # no detector at all
    assert Track.load(out).n_frames == 12


def test_cli_capture_restart_and_other_runs_progress(clip, quick_model_path, tmp_path, capsys,
                                                     caplog, fakes):
    video = clip[0]
    out, partial = tmp_path / "t.npz", tmp_path / "t.partial.npz"
    args = ["track", str(video), "--model", str(quick_model_path), "--out", str(out),
            "--max-frames", "12"]
    fakes.stop_at = 8
    assert main(args) == 130 and partial.is_file()
    fakes.stop_at = None
    assert main(args + ["--restart"]) == 0                   # --restart: detected afresh
    assert "continued" not in capsys.readouterr().out and not partial.exists()
    assert fakes.made[-1].calls == 12
    # another run's progress (here: another frame limit) is ignored, replaced, then removed
    fakes.stop_at = 8
    assert main(args[:-1] + ["20", "--overwrite"]) == 130 and partial.is_file()
    fakes.stop_at = None
    with caplog.at_level("WARNING"):
        assert main(args + ["--overwrite"]) == 0
    assert "continued" not in capsys.readouterr().out and "of another run" in caplog.text
    assert fakes.made[-1].calls == 12 and not partial.exists()


def test_mediapipe_resumed_mid_clip_agrees_with_an_uninterrupted_run(data_dir, tmp_path):
    """The real detector: frames before the seam come from the file (exact); from the seam on,
    MediaPipe's tracking state (warmed up on the 20 frames before) leaves sub-pixel
    differences (see VideoLandmarker); the flow into the seam frame is exact."""
    from facetransfer.track.detect import VideoLandmarker

    video = data_dir / "video" / "driving_d9.mp4"
    n, k = 44, 30
    ck = DetectionCheckpoint.for_video(tmp_path / "t.partial.npz", video, n)

    def run(**kw):
        with VideoLandmarker(fps=25.0) as det:
            return detect_clip(iter_frames(video), det, n_frames=n, keep478=True, **kw)

    full = run()
    with pytest.raises(KeyboardInterrupt):
        run(progress=_stop_at(k), checkpoint=ck)
    res = run(resume=ck.load().detections)
    _equal(ClipDetections(res.points[:k], res.flow[:k], res.points478[:k]),
           ClipDetections(full.points[:k], full.flow[:k], full.points478[:k]))
    d = np.linalg.norm(res.points[k:] - full.points[k:], axis=2)          # (n - k, 68) px
    iod = np.linalg.norm(full.points[k, 36] - full.points[k, 45])
    # measured: 0.03-0.06 px mean per frame, 0.21 px at most (without the warm-up 1.6 px mean
    # at the seam)
    assert d.mean(axis=1).max() < 0.15 and d.max() < 0.5 and iod > 100
    np.testing.assert_array_equal(res.flow[k], full.flow[k])  # frame k-1's points and image


def test_batch_track_clip_continues_an_interrupted_capture(clip, quick_model, tmp_path, fakes):
    """``batch track`` (a whole clip, the capture tracker) resumes from ``NAME.partial.npz``
    as ``facetransfer track`` does, and removes it once the track is written."""
    from facetransfer.batch import jobs
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.track.settings import TrackerSettings

    video = str(clip[0])
    job, settings = ClipJob("c", video, "auto"), TrackerSettings()
    ref = jobs._track(video, quick_model, "auto", settings, source=video, checkpoint=None)
    out = tmp_path / "c.npz"
    partial = jobs.partial_path(out)
    fakes.stop_at = 25
    with pytest.raises(KeyboardInterrupt):
        jobs.track_clip(job, str(out), quick_model, settings)
    assert partial.is_file() and not out.exists()
    fakes.stop_at = None
    row = jobs.track_clip(job, str(out), quick_model, settings)
    assert row.status == "done" and not partial.exists()
    assert fakes.made[-1].calls == F - 25 + FakeDetector.warmup_frames
    np.testing.assert_allclose(Track.load(out).landmarks2d, ref.landmarks2d, atol=1e-9)


def test_batch_track_clip_of_max_frames_as_track_does(clip, quick_model_path, quick_model,
                                                      tmp_path, capsys, fakes):
    """A clip's first ``max_frames`` frames with the capture tracker (``batch track
    --max-frames``): the track ``track --max-frames`` writes, continued from its progress file
    after an interrupt, and a progress file of another limit not taken for it."""
    from facetransfer.batch import jobs
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.track.settings import TrackerSettings

    video, n = str(clip[0]), 24
    ref = tmp_path / "ref.npz"
    assert main(["track", video, "--model", str(quick_model_path), "--out", str(ref),
                 "--max-frames", str(n)]) == 0
    capsys.readouterr()
    job, settings = ClipJob("c", video, "auto", None, n), TrackerSettings()
    out = tmp_path / "c.npz"
    fakes.stop_at = 15
    with pytest.raises(KeyboardInterrupt):
        jobs.track_clip(job, str(out), quick_model, settings)
    assert jobs.partial_path(out).is_file()
    fakes.stop_at = None
    row = jobs.track_clip(job, str(out), quick_model, settings)
    assert row.frames == n and not jobs.partial_path(out).exists()
    assert fakes.made[-1].calls == n - 15 + FakeDetector.warmup_frames  # frames 15..n only
    a, b = Track.load(out), Track.load(ref)
    assert a.n_frames == b.n_frames == n
    np.testing.assert_allclose(a.landmarks2d, b.landmarks2d, atol=1e-9)
    fakes.stop_at = 15            # (redone over its track: the batch's --overwrite)
    with pytest.raises(KeyboardInterrupt):
        jobs.track_clip(job, str(out), quick_model, settings, True)
    fakes.stop_at = None          # the same clip, another limit: from its first frame
    row = jobs.track_clip(dataclasses.replace(job, max_frames=20), str(out), quick_model,
                          settings, True)
    assert row.frames == 20 and fakes.made[-1].calls == 20


def test_a_transfers_track_is_kept_continued_and_reused_in_the_cache(clip, quick_model, tmp_path,
                                                                     fakes, monkeypatch):
    """``obtain_track`` (the tracking of ``transfer``, ``puppet`` and ``demo``) with the track
    cache: interrupted, its progress waits in the cache and the next run continues it; then the
    same frames of the same file come from the cache with no detector made; a touched file or
    another frame count is tracked afresh."""
    import os

    from facetransfer.io.video import read_video
    from facetransfer.track.obtain import obtain_track

    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    tracks = tmp_path / "cache" / "facetransfer" / "tracks"
    video = clip[0]
    frames, fps = read_video(video)
    ref = obtain_track(video, quick_model, frames=frames, fps=fps, cache=False)
    assert not tracks.exists()
    fakes.stop_at = 25
    with pytest.raises(KeyboardInterrupt):
        obtain_track(video, quick_model, frames=frames, fps=fps)
    assert len(list(tracks.glob("*.partial.npz"))) == 1
    fakes.stop_at = None
    tr = obtain_track(video, quick_model, frames=frames, fps=fps)
    assert fakes.made[-1].calls == F - 25 + FakeDetector.warmup_frames
    np.testing.assert_allclose(tr.landmarks2d, ref.landmarks2d, atol=1e-9)
    assert tr.info["resumed"] == {"frame": 25} and "resumed" not in ref.info  # said by transfer
    assert [p.name.endswith(".partial.npz") for p in tracks.iterdir()] == [False]
    made = len(fakes.made)
    _same_track(obtain_track(video, quick_model, frames=frames, fps=fps), tr)
    assert len(fakes.made) == made                           # from the cache
    obtain_track(video, quick_model, frames=frames, fps=fps, max_frames=F - 5)
    assert len(fakes.made) == made + 1 and len(list(tracks.glob("*.npz"))) == 2
    st = os.stat(video)
    os.utime(video, ns=(st.st_atime_ns, st.st_mtime_ns + 10 ** 9))
    obtain_track(video, quick_model, frames=frames, fps=fps)
    assert len(fakes.made) == made + 2


# ------------------------------------------------------------------------------ the fit
def _stop_tracking_at(k: int):
    """A progress callback that interrupts the fit when ``k`` frames are tracked."""
    def prog(stage, done, total):
        if stage == "track" and done == k:
            raise KeyboardInterrupt
    return prog


def _count_fits(monkeypatch) -> dict:
    """``{"identity": 0 or 1, "frames": n}``, kept up to date: whether the capture ran its
    identity phase and how many frames it fitted from now on."""
    from facetransfer.track import capture

    calls = {"identity": 0, "frames": 0}
    real_id, real_fit = capture._clip_identity, capture.fit_frame
    monkeypatch.setattr(capture, "_clip_identity",
                        lambda *a, **k: calls.__setitem__("identity", 1) or real_id(*a, **k))
    monkeypatch.setattr(capture, "fit_frame",
                        lambda *a, **k: calls.__setitem__("frames", calls["frames"] + 1)
                        or real_fit(*a, **k))
    return calls


def _same_track(a: Track, b: Track) -> None:
    for name in ("rotation", "scale", "translation", "landmarks2d", "confidence", "lost"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for m in b.weights:
        np.testing.assert_array_equal(a.weights[m], b.weights[m], err_msg=m)
    if b.blendshapes is not None:
        np.testing.assert_array_equal(a.blendshapes, b.blendshapes)


def test_interrupted_fit_continues_exactly_where_it_stopped(clip, arkit_model, tmp_path,
                                                            monkeypatch):
    """Interrupted in the forward run and again in the backward run, the fit continues from
    the saved frames (no identity phase, no frame fitted twice) and ends bit for bit where an
    uninterrupted fit ends."""
    from facetransfer.track import capture
    from facetransfer.track.fit_checkpoint import fit_key

    video, _, _ = clip
    det = detect_clip(iter_frames(video), FakeDetector(clip), n_frames=F, keep478=True)
    ref = capture.capture_detections(det, arkit_model)
    start = ref.info["start_frame"]
    assert 4 <= start <= F - 4                  # both runs are long enough to stop in
    key = fit_key(arkit_model.content_hash, capture.CaptureOptions(), None)
    path = tmp_path / "t.partial.npz"
    fwd_stop, bwd_stop = (F - start) // 2, (F - start) + start // 2
    with pytest.raises(KeyboardInterrupt):      # in the forward run
        capture.capture_detections(det, arkit_model, checkpoint=DetectionCheckpoint(
            path, "k", every=1e9), progress=_stop_tracking_at(fwd_stop))
    ck = DetectionCheckpoint(path, "k", every=0.0)
    assert ck.load().complete
    fit = ck.saved_fit(key)
    assert fit.forward_next == start + fwd_stop and fit.backward_next == start - 1
    lost = int(start <= NO_FACE < fit.forward_next)
    assert fit.valid.sum() == fwd_stop - lost and not fit.valid[fit.forward_next:].any()
    with pytest.raises(KeyboardInterrupt):      # resumed, then stopped in the backward run
        capture.capture_detections(det, arkit_model, checkpoint=ck,
                                   progress=_stop_tracking_at(bwd_stop))
    ck = DetectionCheckpoint(path, "k")
    ck.load()
    fit = ck.saved_fit(key)
    assert fit.forward_next == F and fit.backward_next == start - 1 - start // 2
    calls = _count_fits(monkeypatch)
    out = capture.capture_detections(det, arkit_model, checkpoint=ck)
    left = fit.backward_next + 1 - int(NO_FACE <= fit.backward_next)   # frames still to fit
    assert calls == {"identity": 0, "frames": left}
    _same_track(out, ref)


def test_a_fit_of_other_options_is_not_continued(clip, quick_model, tmp_path, caplog):
    from facetransfer.track import capture

    video, _, _ = clip
    det = detect_clip(iter_frames(video), FakeDetector(clip), n_frames=20, keep478=True)
    path = tmp_path / "t.partial.npz"
    with pytest.raises(KeyboardInterrupt):
        capture.capture_detections(det, quick_model, checkpoint=DetectionCheckpoint(path, "k"),
                                   progress=_stop_tracking_at(5))
    other = capture.CaptureOptions(flow=0.25)
    ck = DetectionCheckpoint(path, "k")
    assert ck.load().complete
    with caplog.at_level("WARNING"):
        out = capture.capture_detections(det, quick_model, options=other, checkpoint=ck)
    assert "another model or other options" in caplog.text
    _same_track(out, capture.capture_detections(det, quick_model, options=other))


def test_fit_interrupted_in_the_second_pass_continues_exactly(clip, arkit_model, tmp_path,
                                                             monkeypatch):
    """With the detector's scores the fit runs a second pass (stage ``refine``); interrupted
    there, it continues with the saved score lines and the second pass's frames (no identity
    phase, no first pass again) and ends bit for bit where an uninterrupted fit ends."""
    from facetransfer.track import capture
    from facetransfer.track.fit_checkpoint import fit_key

    video, _, _ = clip
    det = detect_clip(iter_frames(video), ScoredDetector(clip), n_frames=F, keep478=True)
    ref = capture.capture_detections(det, arkit_model)
    assert "jawOpen" in ref.info["score_shapes"]
    one = capture.capture_detections(det, arkit_model,
                                     options=capture.CaptureOptions(scores=0.0))
    assert not np.array_equal(one.blendshapes, ref.blendshapes)   # the second pass did work
    path = tmp_path / "t.partial.npz"
    stop = 7

    def prog(stage, done, total):
        if stage == "refine" and done == stop:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        capture.capture_detections(det, arkit_model, progress=prog,
                                   checkpoint=DetectionCheckpoint(path, "k", every=1e9))
    ck = DetectionCheckpoint(path, "k")
    assert ck.load().complete
    fit = ck.saved_fit(fit_key(arkit_model.content_hash, capture.CaptureOptions(), None))
    assert fit.lines is not None and fit.lines.shape == (3, 52)   # offsets, slopes, weights
    lost = int(ref.info["start_frame"] <= NO_FACE < fit.forward_next)
    assert fit.valid.sum() == stop - lost
    calls = _count_fits(monkeypatch)
    out = capture.capture_detections(det, arkit_model, checkpoint=ck)
    assert calls == {"identity": 0, "frames": F - 1 - stop + lost}
    _same_track(out, ref)


def _wrapped_stop_at(k: int, stop: type = KeyboardInterrupt):
    """:func:`_stop_tracking_at` as a signal arriving inside a numba-compiled kernel comes
    back: a ``SystemError`` ("returned a result with an exception set") caused by the
    interrupt."""
    def prog(stage, done, total):
        if stage == "track" and done == k:
            try:
                raise stop
            except stop as exc:
                raise SystemError("CPUDispatcher(<function _pose_step>) returned a result "
                                  "with an exception set") from exc
    return prog


def test_an_interrupt_inside_a_compiled_kernel_keeps_the_fit_and_says_one_line(
        clip, arkit_model, tmp_path, capsys, monkeypatch):
    """A SIGTERM or Ctrl-C in the fit's numba kernels came back as a SystemError: a
    traceback, exit 1, the fit's progress not saved (a new user's walk). Now the interrupt
    itself: the progress saved, then continued bit for bit; the CLI's one line, 130 / 143."""
    from facetransfer.cli import main as cli_main
    from facetransfer.track import capture
    from facetransfer.track.fit_checkpoint import fit_key

    video, _, _ = clip
    det = detect_clip(iter_frames(video), FakeDetector(clip), n_frames=F, keep478=True)
    path = tmp_path / "t.partial.npz"
    with pytest.raises(KeyboardInterrupt):
        capture.capture_detections(det, arkit_model, checkpoint=DetectionCheckpoint(
            path, "k", every=1e9), progress=_wrapped_stop_at(5))
    ck = DetectionCheckpoint(path, "k", every=0.0)
    assert ck.load().complete
    key = fit_key(arkit_model.content_hash, capture.CaptureOptions(), None)
    assert ck.saved_fit(key).valid.sum() >= 4
    _same_track(capture.capture_detections(det, arkit_model, checkpoint=ck),
                capture.capture_detections(det, arkit_model))
    for stop, status, what in ((KeyboardInterrupt, 130, "interrupted"),
                               (cli_main.Terminated, 143, "terminated")):
        def command(args, stop=stop):
            try:
                raise stop
            except stop as exc:
                raise SystemError("returned a result with an exception set") from exc

        args = cli_main.build_parser().parse_args(["probe", str(video)])
        monkeypatch.setattr(args, "func", command, raising=False)
        assert cli_main._run(args) == status
        assert capsys.readouterr().err.strip() == f"facetransfer probe: {what}"
    args = cli_main.build_parser().parse_args(["probe", str(video)])

    def broken(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:    # a fault while an interrupt was handled: its own
            raise SystemError("a real fault, no interrupt")

    monkeypatch.setattr(args, "func", broken, raising=False)
    with pytest.raises(SystemError, match="a real fault"):
        cli_main._run(args)


def test_an_older_versions_second_pass_fit_is_no_fit_not_a_damaged_file():
    """A progress file saved mid second pass by the version before funnel55c holds its score
    lines as (2, 52) (offsets, slopes): read now, it is no fit (its key, of FIT_VERSION 5, is
    never taken), not "inconsistent fit arrays", which made the checkpoint throw the file's
    finished detections away as damaged (reread55a)."""
    import dataclasses

    from facetransfer.track.fit_checkpoint import SavedFit, pack_fit, unpack_fit

    F = 2
    fit = SavedFit(identity=None, offset=np.zeros((4, 3)), frames=np.arange(F), start=0,
                   seed=(np.eye(3), 1.0, np.zeros(2), np.zeros(5), 0.0),
                   valid=np.ones(F, bool), rotation=np.tile(np.eye(3), (F, 1, 1)),
                   scale=np.ones(F), translation=np.zeros((F, 2)), x=np.zeros((F, 5)),
                   residual=np.zeros(F), forward_next=F, backward_next=-1,
                   lines=np.zeros((3, 52)))
    key, back = unpack_fit(pack_fit(fit, "k"))
    assert key == "k" and back.lines.shape == (3, 52)
    old = pack_fit(dataclasses.replace(fit, lines=np.zeros((2, 52))), "k5")
    assert unpack_fit(old) is None

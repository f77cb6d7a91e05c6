"""``facetransfer track`` and automatic initialisation on real footage (§5.2)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.io.video import read_video, write_video
from facetransfer.track import Track
from facetransfer.track.landmarks import REQUIRED_IBUG, mediapipe_to_ibug

from conftest import clip_with_points

KEY = list(REQUIRED_IBUG)  # eye corners, nose tip, mouth corners


@pytest.fixture(scope="module")
def small_clip(quick_model, tmp_path_factory):
    """An 8-frame synthetic clip on disk and a POINTS.json of its first frame's landmarks."""
    return clip_with_points(quick_model, 8, 5, tmp_path_factory.mktemp("trackcli"))


def _run(capsys, *argv):
    code = main(["track", *map(str, argv)])
    err = capsys.readouterr().err.strip().splitlines()
    return code, [l for l in err if l.startswith("facetransfer track")]


def test_cli_tracks_and_writes_track_and_overlay(small_clip, quick_model_path, quick_model,
                                                 tmp_path, capsys):
    video, pts, clip = small_clip
    out, ov = tmp_path / "t.npz", tmp_path / "ov.mp4"
    code = main(["track", *map(str, (video, "--model", quick_model_path, "--out", out, "--init",
                                     pts, "--passes", "1", "--overlay", ov))])
    assert code == 0
    # a model of other expressions: said in a sentence (before: "the model its expressions")
    assert ("note: the track has no ARKit blendshape activations: the model's expressions are "
            "not ARKit blendshapes (the default model's, ict-arkit, are)"
            in capsys.readouterr().out.splitlines())
    tr = Track.load(out)
    assert tr.n_frames == 8 and tr.frame_size == (320, 240) and tr.fps == 25
    assert tr.model_hash == quick_model.content_hash
    # video compression adds noise; the landmarks still follow the face (measured 0.5 px)
    err = np.linalg.norm(tr.landmarks2d - clip.truth.landmarks2d, axis=2).mean(axis=1)
    assert err.max() < 2.5
    frames, _ = read_video(ov)
    assert frames.shape == (8, 240, 320, 3)
    ov2 = tmp_path / "ov2.mp4"
    assert _run(capsys, video, "--model", quick_model_path, "--from-track", out,
                "--overlay", ov2)[0] == 0 and ov2.is_file()


def test_cli_bad_input_is_one_line_exit_2(small_clip, quick_model_path, quick_model, tmp_path,
                                          capsys):
    video, pts, clip = small_clip
    out = tmp_path / "t.npz"
    m = ("--model", quick_model_path, "--out", out)

    txt = tmp_path / "notvideo.mp4"
    txt.write_text("hello")
    code, lines = _run(capsys, txt, *m, "--init", pts)
    assert code == 2 and len(lines) == 1 and "notvideo.mp4" in lines[0]
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    code, lines = _run(capsys, empty, *m, "--init", pts)
    assert code == 2 and "is empty" in lines[0]

    far = tmp_path / "far.json"
    far.write_text(json.dumps({"points": {str(i): [500.0, 10.0] for i in REQUIRED_IBUG}}))
    code, lines = _run(capsys, video, *m, "--init", far)
    assert code == 2 and "outside the 320x240 image" in lines[0]
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"points": {"36": [100, 100], "45": [150, 100]}}))
    code, lines = _run(capsys, video, *m, "--init", few)
    assert code == 2 and "too few points" in lines[0] and "30" in lines[0]

    nolm = tmp_path / "nolm.npz"
    dataclasses.replace(quick_model, landmarks=None).save(nolm)
    code, lines = _run(capsys, video, "--model", nolm, "--out", out, "--init", pts)
    assert code == 2 and "no landmark vertices" in lines[0]
    assert "models built from ict-arkit, ict-bilinear or ict-trilinear have them" in lines[0]

    wrong = tmp_path / "wrong.npz"
    F = 8
    Track(25.0, (640, 480), np.tile(np.eye(3), (F, 1, 1)), np.ones(F), np.zeros((F, 2)),
          {"identity": np.zeros((F, 5)), "expression": np.zeros((F, 5))}, np.zeros((F, 68, 2)),
          np.ones(F), np.zeros(F, bool), quick_model.content_hash,
          ("identity", "expression")).save(wrong)
    code, lines = _run(capsys, video, "--model", quick_model_path, "--from-track", wrong,
                       "--overlay", tmp_path / "o.mp4")
    assert code == 2 and "640x480" in lines[0] and "320x240" in lines[0]
    code, lines = _run(capsys, video, "--model", quick_model_path, "--from-track", wrong)
    assert code == 2 and "--overlay" in lines[0]
    assert not out.exists()
    # a track of the clip's first frames (track --max-frames): the --max-frames that draws them
    short, k = tmp_path / "short.npz", 4
    Track(25.0, (320, 240), np.tile(np.eye(3), (k, 1, 1)), np.ones(k), np.zeros((k, 2)),
          {"identity": np.zeros((k, 5)), "expression": np.zeros((k, 5))},
          np.zeros((k, 68, 2)), np.ones(k), np.zeros(k, bool), quick_model.content_hash,
          ("identity", "expression")).save(short)
    code, lines = _run(capsys, video, "--model", quick_model_path, "--from-track", short,
                       "--overlay", tmp_path / "o.mp4")
    assert code == 2 and lines[0].endswith(
        f"track {short} has 4 frames, the video {video} 8: give --max-frames 4 to draw the "
        "frames it covers"), lines


def test_cli_video_without_a_face(quick_model_path, tmp_path, capsys):
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, (3, 120, 160, 3), dtype=np.uint8)
    noface = tmp_path / "noise.mp4"
    write_video(noface, frames, 25)
    code, lines = _run(capsys, noface, "--model", quick_model_path, "--out", tmp_path / "t.npz")
    assert code == 2 and "no face found" in lines[0] and "frames 0-2" in lines[0]


def test_mediapipe_auto_init_on_a_real_frame(data_dir, quick_model):
    from facetransfer.track.init import MediaPipeDetector, fit_landmarks
    from facetransfer.track.camera import project

    frame = read_video(data_dir / "video" / "face_2.mp4", max_frames=1)[0][0]
    ref = mediapipe_to_ibug(np.load(data_dir / "video" / "face_2.mediapipe478.npz")
                            ["landmarks"][0, :, :2])
    with MediaPipeDetector() as det:
        L = det.detect(frame)
    assert L.shape == (68, 2)
    iod = np.linalg.norm(ref[36] - ref[45])
    # against the stored MediaPipe 0.10.21 reference (measured 1.4 % of the eye distance)
    assert np.linalg.norm(L[KEY] - ref[KEY], axis=1).mean() < 0.03 * iod
    st = fit_landmarks(quick_model, L)
    P = project(quick_model.synthesize(st.weights, vertices=quick_model.landmarks),
                st.pose.rotation, st.pose.scale, st.pose.translation)
    # the fitted model's landmark vertices land near the detections (measured ~4 %)
    assert np.linalg.norm(P[KEY] - ref[KEY], axis=1).mean() < 0.08 * iod


def test_cli_rejects_bad_options(quick_model_path, small_clip, tmp_path, capsys):
    video, pts, _ = small_clip
    base = (video, "--model", quick_model_path, "--init", pts)
    for option, value, said in (("--passes", "0", "argument --passes: expected an integer "
                                                   "in [1, 100], got '0'"),
                                ("--keyframe", "-1", "argument --keyframe: expected a number "
                                                     "in [0, 1e+06], got '-1'")):
        with pytest.raises(SystemExit) as exc:
            _run(capsys, *base, "--out", tmp_path / "t.npz", option, value)
        assert exc.value.code == 2 and said in capsys.readouterr().err
    code, lines = _run(capsys, *base)
    assert code == 2 and "--out is required" in lines[0]
    code, lines = _run(capsys, *base, "--out", tmp_path / "missing" / "t.npz")
    assert code == 2 and "does not exist" in lines[0]


def test_cli_continues_an_interrupted_run(small_clip, quick_model_path, tmp_path, capsys,
                                          monkeypatch):
    from facetransfer.track import tracker

    video, pts, clip = small_clip
    out = tmp_path / "t.npz"
    partial = tmp_path / "t.partial.npz"
    args = (video, "--model", quick_model_path, "--out", out, "--init", pts, "--passes", "2")
    ref = tmp_path / "ref.npz"
    assert _run(capsys, *args[:3], "--out", ref, *args[5:])[0] == 0
    real = tracker.FaceTracker.track_pair
    calls = {"n": 0}

    def interrupted(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 20:       # the snap (7 frames back and forth: 14 pairs), then 5 frames
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(tracker.FaceTracker, "track_pair", interrupted)
    assert main(["track", *map(str, args)]) == 130
    err = capsys.readouterr().err
    assert "run the same command again" in err and partial.is_file() and not out.exists()
    monkeypatch.setattr(tracker.FaceTracker, "track_pair", real)
    assert main(["track", *map(str, args)]) == 0
    assert "continued an interrupted run from pass 1" in capsys.readouterr().out
    assert not partial.exists()
    np.testing.assert_allclose(Track.load(out).landmarks2d, Track.load(ref).landmarks2d,
                               atol=1e-9)
    # --restart drops the progress file of an interrupted run
    partial.write_bytes(b"junk")
    assert main(["track", *map(str, args), "--restart"]) == 2   # the track exists now
    assert "pass --overwrite" in capsys.readouterr().err and partial.is_file()
    assert main(["track", *map(str, args), "--restart", "--overwrite"]) == 0
    assert "continued" not in capsys.readouterr().out and not partial.exists()


def test_the_overlay_draws_the_landmarks_as_contours():
    """The 68 points drawn as the lines of the jaw, brows, nose, eyes and lips
    (:data:`facetransfer.track.overlay.IBUG_CONTOURS`): a segment between two points of one
    contour is drawn (48-49, the outer lips), none between two contours (30-31, the nose's
    bridge and base); a contour with an unknown point is left out."""
    import numpy as np

    from facetransfer.track.overlay import IBUG_CONTOURS, draw_overlay

    assert [b - a for a, b, _ in IBUG_CONTOURS] == [17, 5, 5, 4, 5, 6, 6, 12, 8]
    L = np.full((68, 2), 5.0)                              # every point in the corner ...
    L[48], L[49] = (50, 100), (150, 100)                   # ... but these
    L[30], L[31] = (20, 150), (180, 150)
    frame = np.zeros((200, 200, 3), np.uint8)
    no_mesh = (np.zeros((0, 2)), np.zeros((0, 2), np.int64))

    def red(img, x, y):
        return int(img[y - 1:y + 2, x - 1:x + 2, 0].max())

    img = draw_overlay(frame, *no_mesh, L)
    assert red(img, 100, 100) > 150                        # on the lips' line
    assert red(img, 100, 150) == 0                         # between the nose's two lines
    L[50] = np.nan
    assert red(draw_overlay(frame, *no_mesh, L), 100, 100) == 0

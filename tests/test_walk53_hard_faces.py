"""Faults found by walk53 (hard faces in ordinary footage: occluded, blurred, dark, small, cut by
the frame's edge, rolled, late, leaving for a second): what ``track`` and ``transfer`` say of
the frames where a face was lost, and the face ``--face`` points at where a larger one is
beside it."""

from __future__ import annotations

import dataclasses
import sys

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))

from conftest import still_track  # noqa: E402
from facetransfer.io.video import read_video, write_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from test_track_cli import small_clip  # noqa: E402,F401  (a fixture)
from test_transfer_cli import clips, run  # noqa: E402,F401  (a fixture)


def _with_lost(path, frames, out):
    """The track at ``path`` with ``frames`` marked lost, written to ``out``."""
    track = Track.load(path)
    lost = np.zeros(track.n_frames, bool)
    lost[list(frames)] = True
    dataclasses.replace(track, lost=lost).save(out)
    return out


def test_track_names_the_frames_where_the_face_was_lost(small_clip, quick_model,
                                                        quick_model_path, monkeypatch, tmp_path,
                                                        capsys):
    """``track`` of a clip whose face leaves the picture for a second (walk53's ``gap.mp4``,
    frames 45-74) said ``30 lost`` and not which: the frames were found only by loading the
    track. Now it prints the note ``export`` and ``puppet`` print, naming the runs and what
    each command makes of them; none where no frame is lost."""
    import facetransfer.cli.track as cli_track

    video, pts, _ = small_clip
    found = still_track(quick_model, 8)
    lost = np.zeros(8, bool)
    lost[[2, 3, 5]] = True
    tracks = iter([dataclasses.replace(found, lost=lost), found])
    monkeypatch.setattr(cli_track, "_track_klt", lambda *a, **k: next(tracks))
    code, out, err = run(["track", video, "--model", quick_model_path, "--init", pts,
                          "--out", tmp_path / "t.npz", "--no-progress"], capsys)
    assert code == 0, err
    lines = out.strip().splitlines()
    assert lines[0].endswith(", 3 lost"), out
    assert lines[1] == ("note: the face is lost in frames 2-3, 5: marked lost (a transfer keeps "
                        "those frames as they are, export and puppet hold the nearest tracked "
                        "frame)"), out
    code, out, err = run(["track", video, "--model", quick_model_path, "--init", pts,
                          "--out", tmp_path / "u.npz", "--no-progress"], capsys)
    assert code == 0, err
    assert "lost" not in out, out


def test_transfer_says_whose_face_was_lost_and_where(clips, quick_model_path, tmp_path,
                                                     capsys):
    """A transfer whose expression source leaves the picture for a second (walk53: ``gap.mp4``
    onto ``driving_d6``) keeps the target's own frames there and said ``(30 kept original: face
    lost)``, although the target's face was never lost: whose face, and which frames, were
    not said. Now the line names the clip and the frames (an image sequence's by its own
    numbers, and the source's own where they differ), the target's own lost frames apart from
    a source's."""
    src = _with_lost(clips["source_track"], [2, 3], tmp_path / "src.npz")
    tgt = _with_lost(clips["target_track"], [0], tmp_path / "tgt.npz")
    cases = ((clips["target_track"], src, "(2 kept original: the expression source's face is "
                                          "lost in frames 2-3)"),
             (tgt, clips["source_track"], "(1 kept original: the target's face is lost in "
                                          "frame 0)"),
             (tgt, src, "(3 kept original: the target's face is lost in frame 0; the "
                        "expression source's face is lost in frames 2-3)"))
    for i, (target_track, source_track, said) in enumerate(cases):
        code, out, err = run(["transfer", "--target", clips["target"], "--target-track",
                              target_track, "--expression-from", clips["source"],
                              "--source-track", source_track, "--model", quick_model_path,
                              "--no-progress", "--out", tmp_path / f"o{i}.mp4"], capsys)
        assert code == 0, err
        assert said in out, out
    # an image sequence numbered from 1001 (a plate's rewrite): its own numbers
    code, out, err = run(["transfer", "--target", clips["target"], "--target-track",
                          clips["target_track"], "--expression-from", clips["source"],
                          "--source-track", src, "--model", quick_model_path, "--no-progress",
                          "--out", tmp_path / "seq" / "o.%04d.png", "--start-number", "1001"],
                         capsys)
    assert code == 0, err
    assert ("numbered 1001-1006 (2 kept original: the expression source's face is lost in "
            "its frames 2-3, the result's 1003-1004)") in out, out


@pytest.mark.parametrize("encoded", [False, True])
def test_a_small_face_said_by_face_is_followed_beside_a_larger_one(data_dir, tmp_path,
                                                                   encoded):
    """walk53's ``small_busy.mp4``: ``driving_d6`` shrunk to a face ~60 pixels tall, pasted into
    ``stills/breakingbad.jpg`` made 1920x1080 (two people, their faces ~300 pixels), and
    ``track --face 1362,762`` on the small face. The whole-frame search finds only the large
    faces, and the point said was nearer neither of them than their size: the larger face of
    the photo was followed (yaw -44 deg, jawOpen 0.02 throughout); where the whole-frame
    search found no face (these frames as they are, not through H.264), the tiles' search took
    the first tile's face, the other person's. Now the tiles about the point are searched
    first, and the small face is followed in every frame."""
    from facetransfer.track.detect import detect_clip
    from facetransfer.track.face_crop import FollowingLandmarker, subject_point

    still = cv2.imread(str(data_dir / "stills" / "breakingbad.jpg"))[..., ::-1]
    back = cv2.resize(still, (1920, 1080), interpolation=cv2.INTER_AREA)
    clip = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=3)[0]
    frames = np.stack([back] * len(clip))
    for k, f in enumerate(clip):
        frames[k, 700:824, 1300:1424] = cv2.resize(f, (124, 124), interpolation=cv2.INTER_AREA)
    if encoded:                      # as the clip was made: the whole frame finds the others
        write_video(tmp_path / "small.mp4", frames, 30.0)
        frames = read_video(tmp_path / "small.mp4")[0]
    with FollowingLandmarker(fps=30.0, subject=subject_point("1362,762", (1920, 1080))) as fl:
        det = detect_clip(frames, fl, flow=False)
    assert det.found.all()
    centre = np.nanmean(det.points, axis=1)
    assert (np.abs(centre - (1362, 762)) < 40).all(), centre


def _face_track(n: int, cut: dict):
    """A track of ``n`` frames of one face inside a 64x64 frame (every measure of eyes and
    mouth alike), frame 0 the most confident (the reference every rule picks), and the points
    ``cut`` ({iBUG number: (x, y)}) of frame 0 moved where they are."""
    from facetransfer.track import Track

    face = np.random.default_rng(3).uniform(12, 52, (68, 2))
    L = np.repeat(face[None], n, axis=0)
    for k, xy in cut.items():
        L[0, k] = xy
    conf = np.full(n, 0.6)
    conf[0] = 1.0
    return Track(fps=25.0, frame_size=(64, 64), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.ones(n), translation=np.zeros((n, 2)),
                 weights={"identity": np.zeros((n, 2)), "expression": np.zeros((n, 3))},
                 landmarks2d=L, confidence=conf, lost=np.zeros(n, bool), model_hash="x",
                 mode_names=("identity", "expression"))


def test_a_region_is_not_textured_from_a_frame_that_cuts_it():
    """walk53's ``edge.mp4`` (the face pushed half out of the picture and back) transferred:
    the eye region's second view was textured from frame 74, whose left eye the frame's edge
    cut, and its closed-eye texture from frame 50, that eye out of the picture: the re-entering
    eye's lids were streaked with the edge's pixels (frames 74-78). Now a region's reference
    frames (open eyes, closed eyes, closed mouth, each view's) are those that show its points
    inside the picture, where any does (then 15 alone, no closed-eye frame: the streaks gone);
    a clip that cuts them in every frame keeps its frames."""
    from facetransfer.eyes import closed_eye_frame, open_eye_frame, reference_candidates
    from facetransfer.jaw import closed_jaw_frame

    whole = _face_track(3, {})
    assert open_eye_frame(whole) == 0 and closed_jaw_frame(whole) == 0
    brow = _face_track(3, {20: (30.0, -4.0)})           # a brow above the frame's top
    assert open_eye_frame(brow) == 1 and closed_jaw_frame(brow) == 0
    chin = _face_track(3, {8: (30.0, 70.0)})            # the chin below its bottom
    assert open_eye_frame(chin) == 0 and closed_jaw_frame(chin) == 1
    every = _face_track(1, {20: (30.0, -4.0), 8: (30.0, 70.0)})
    assert open_eye_frame(every) == 0 and closed_jaw_frame(every) == 0
    shut = _face_track(3, {45: (70.0, 30.0)})           # frame 0's eye, cut, reads as closed
    shut.landmarks2d[0, [37, 38, 43, 44]] = shut.landmarks2d[0, [41, 40, 47, 46]]
    assert closed_eye_frame(shut) is None

    from facetransfer.region_weights import EYE_POINTS, in_picture   # each view's candidates

    assert in_picture(brow, EYE_POINTS).tolist() == [False, True, True]
    assert reference_candidates(brow, np.ones(3), None, 0.5, low=False,
                                points=EYE_POINTS).tolist() == [1, 2]

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
    not said. Now the line names the clip and the frames, the target's own lost frames apart
    from a source's."""
    src = _with_lost(clips["source_track"], [2, 3], tmp_path / "src.npz")
    tgt = _with_lost(clips["target_track"], [0], tmp_path / "tgt.npz")
    cases = ((clips["target_track"], src, "(2 kept original: the expression source's face is "
                                          "lost in frames 2-3)"),
             (tgt, clips["source_track"], "(1 kept original: the target's face is lost in "
                                          "frames 0)"),
             (tgt, src, "(3 kept original: the target's face is lost in frames 0; the "
                        "expression source's face is lost in frames 2-3)"))
    for i, (target_track, source_track, said) in enumerate(cases):
        code, out, err = run(["transfer", "--target", clips["target"], "--target-track",
                              target_track, "--expression-from", clips["source"],
                              "--source-track", source_track, "--model", quick_model_path,
                              "--no-progress", "--out", tmp_path / f"o{i}.mp4"], capsys)
        assert code == 0, err
        assert said in out, out


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

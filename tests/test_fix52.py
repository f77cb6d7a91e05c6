"""Faults found by walk52 (phone footage) in what ``transfer`` and ``puppet`` draw, mended by
helper fix52: the puppet's note of the frames where the face was lost."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))

from facetransfer.track import Track  # noqa: E402
from test_transfer_cli import clips, run  # noqa: E402,F401  (a fixture)


def test_puppet_says_which_frames_it_holds_where_the_face_was_lost(clips, quick_model_path,
                                                                   tmp_path, capsys):
    """``puppet`` of a clip whose face leaves the picture (walk52's ``leave.mp4``): the frames
    where the face was lost show the nearest tracked frame's head, which ``export`` says in a
    note and the puppet said nothing of. Now it prints the same note, one line naming them, for
    ``puppet VIDEO --track`` and ``puppet TRACK.npz``; none where no frame is lost."""
    track = Track.load(clips["source_track"])
    lost = np.zeros(track.n_frames, bool)
    lost[[2, 3, 5]] = True
    lost_path = tmp_path / "lost.npz"
    dataclasses.replace(track, lost=lost).save(lost_path)
    note = ("note: the face is lost in frames 2-3, 5: the puppet holds the nearest tracked "
            "frame's head there")
    for argv in (["puppet", clips["source"], "--track", lost_path],
                 ["puppet", lost_path]):
        code, out, err = run([*argv, "--model", quick_model_path, "--identity", "id04",
                              "--no-progress", "--out", tmp_path / "p.mp4", "--overwrite"],
                             capsys)
        assert code == 0, err
        lines = out.strip().splitlines()
        assert lines[-1] == note, out
        assert sum("the face is lost" in line for line in lines) == 1, out
    code, out, err = run(["puppet", clips["source"], "--track", clips["source_track"],
                          "--model", quick_model_path, "--identity", "id04", "--no-progress",
                          "--out", tmp_path / "q.mp4"], capsys)
    assert code == 0, err
    assert "the face is lost" not in out, out

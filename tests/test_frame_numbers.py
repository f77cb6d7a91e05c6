"""Frame numbers a user recognises (:mod:`facetransfer.io.frame_numbers`): every message that
names frames of a plate numbered from 1001 names them by the plate's own numbers, as its files
carry them, and the options that take a frame number (``transfer --frame``, ``edit --add``,
``--neutral``) take them so; a video's frames are counted from 0.

Before, a transfer onto a plate written as a video, and a transfer from a plate, named the
plate's lost frames counted from 0 (``frames 5-7`` for ``sh.1006-1008``), and ``--frame``,
``--add`` and ``--neutral`` took rows counted from 0 of a plate numbered from 1001."""

from __future__ import annotations

import contextlib
import dataclasses
import io

import cv2
import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.io.frame_numbers import (first_number, frame_index, frame_runs, frame_span,
                                           frames_said)
from facetransfer.track import Track

#: The plate's frames where the face is hidden (each a flat grey of its own).
HIDDEN = (1006, 1007, 1008)


def _main(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def plate(data_dir, arkit_model_path, tmp_path_factory):
    """A PNG plate ``sh.####.png`` of ``driving_d6``'s first 20 frames numbered 1001-1020 (read
    at the default 24 fps), its face hidden in :data:`HIDDEN` (a flat grey each), and
    ``driving_d9``'s first 20 frames (30 fps), each tracked; with what tracking the plate
    printed."""
    from facetransfer.io.video import read_video

    d = tmp_path_factory.mktemp("plate54")
    (d / "plate").mkdir()
    frames = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=20)[0]
    for k, f in enumerate(frames, start=1001):
        f = np.full_like(f, 40 + 10 * (k - HIDDEN[0])) if k in HIDDEN else f
        cv2.imwrite(str(d / "plate" / f"sh.{k}.png"), f[..., ::-1])
    paths = {"plate": d / "plate" / "sh.####.png", "plate_track": d / "plate.npz",
             "video": data_dir / "video" / "driving_d9.mp4", "video_track": d / "d9.npz",
             "model": arkit_model_path, "dir": d}
    code, said, err = _main(["track", paths["plate"], "--model", arkit_model_path, "--out",
                             paths["plate_track"], "--no-progress"])
    assert code == 0, err
    code, _, err = _main(["track", paths["video"], "--model", arkit_model_path, "--max-frames",
                          20, "--out", paths["video_track"], "--no-progress"])
    assert code == 0, err
    paths["track_said"] = said
    return paths


def test_a_clip_s_numbers(tmp_path):
    """A plate's first number is its lowest file's; a video's, a photo's or a plate gone is 0;
    a frame number is read back as its row, and one outside the clip is refused naming the
    plate's numbers."""
    for k in (1001, 1002, 1003):
        (tmp_path / f"sh.{k}.png").write_bytes(b"")
    assert first_number(tmp_path / "sh.####.png") == 1001
    assert first_number(tmp_path / "sh.%04d.png") == 1001
    assert first_number(tmp_path / "clip.mp4") == 0
    assert first_number(tmp_path / "gone" / "sh.####.png") == 0
    assert frame_span(1001, 3) == "1001-1003" and frame_span(0, 1) == "0"
    lost = np.array([0, 1, 1, 0, 1], bool)
    assert frame_runs(lost, 1001) == "1002-1003, 1005" and frame_runs(lost) == "1-2, 4"
    assert frame_index(1002, 1001, 3, "--frame 1002") == 1
    with pytest.raises(ValueError, match=r"^--frame 2: no such frame; the plate's frames are "
                                         r"1001-1003 \(an image sequence's"):
        frame_index(2, 1001, 3, "--frame 2")


def test_track_and_probe_name_a_plate_s_lost_frames_by_its_numbers(plate):
    """``track`` of the plate names its hidden frames 1006-1008 (as did export's note, in
    parentheses after 5-7), and ``probe`` of the track says them so and how it is numbered."""
    assert ("note: the face is lost in frames 1006-1008: marked lost (a transfer keeps those "
            "frames as they are, export and puppet hold the nearest tracked frame)"
            in plate["track_said"]), plate["track_said"]
    code, said, err = _main(["probe", plate["plate_track"]])
    assert code == 0, err
    assert "a track of 20 frames (numbered 1001-1020, as the plate's files) at 24 fps" in said
    assert "face lost in 3 of 20 frames (1006-1008)" in said, said


def test_a_transfer_onto_a_plate_names_its_lost_frames_by_the_plate_s_numbers(plate):
    """Onto the plate, written as a video: the frames kept as they were are the plate's
    1006-1008 (before: "frames 5-7"); written as a sequence numbered from 1 by
    ``--start-number``, they are named as that sequence's files are."""
    args = ["transfer", "--target", plate["plate"], "--target-track", plate["plate_track"],
            "--expression-from", plate["video"], "--source-track", plate["video_track"],
            "--max-frames", 20, "--model", plate["model"], "--no-progress"]
    code, said, err = _main(args + ["--out", plate["dir"] / "onto.mp4"])
    assert code == 0, err
    assert "20 frames (3 kept original: the target's face is lost in frames 1006-1008)" in said
    code, said, err = _main(args + ["--out", plate["dir"] / "seq" / "o.%04d.png",
                                    "--start-number", 1])
    assert code == 0, err
    assert ("numbered 1-20 (3 kept original: the target's face is lost in frames 6-8)"
            in said), said
    assert sorted(p.name for p in (plate["dir"] / "seq").iterdir())[5:8] == \
        ["o.0006.png", "o.0007.png", "o.0008.png"]


def test_a_transfer_from_a_plate_names_its_lost_frames_by_the_plate_s_numbers(plate):
    """The plate (24 fps) as the expression source of a 30 fps clip: the result's frame k
    reads the plate at 0.8 k, so its frames 6-9 read the hidden 1006-1008 (6 at 4.8, between
    1005 and 1006; 9 at 7.2, between 1008 and 1009; 10 at 8.0 reads 1009 alone). Both are
    said (before: "frames 6-9", as if they were the plate's)."""
    t = np.arange(20) * 24 / 30                    # the time map, as the truth of the numbers
    reads = [{int(np.floor(x)), int(np.ceil(x))} for x in t]
    kept = [k for k, r in enumerate(reads) if r & {5, 6, 7}]
    assert kept == [6, 7, 8, 9]
    code, said, err = _main(["transfer", "--target", plate["video"], "--target-track",
                             plate["video_track"], "--expression-from", plate["plate"],
                             "--source-track", plate["plate_track"], "--max-frames", 20,
                             "--model", plate["model"], "--no-progress",
                             "--out", plate["dir"] / "from.mp4"])
    assert code == 0, err
    assert ("20 frames (4 kept original: the expression source's face is lost in its frames "
            "1006-1008, the result's 6-9)") in said, said


def test_frame_takes_a_plate_s_number(plate):
    """``--frame 1007`` of a transfer onto the plate writes the plate's frame 1007 (its face
    hidden: kept as it was, its own grey to the bit); ``--frame 6``, a row counted from 0, is
    refused naming the plate's numbers (before: 1007 was refused, 6 wrote sh.1007)."""
    args = ["transfer", "--target", plate["plate"], "--target-track", plate["plate_track"],
            "--expression-from", plate["video"], "--source-track", plate["video_track"],
            "--max-frames", 20, "--model", plate["model"], "--no-progress"]
    out = plate["dir"] / "one.png"
    code, said, err = _main(args + ["--out", out, "--frame", 1007])
    assert code == 0, err
    assert said.startswith(f"wrote {out}: one image, frame 1007 of the transfer (kept "
                           "original: the face is lost there)"), said
    np.testing.assert_array_equal(cv2.imread(str(out)),
                                  cv2.imread(str(plate["dir"] / "plate" / "sh.1007.png")))
    code, _, err = _main(args + ["--out", plate["dir"] / "six.png", "--frame", 6])
    assert code == 2
    assert ("--frame 6: the transfer has 20 frames (the target "
            f"{plate['plate']}'s), numbered 1001-1020 as the plate's files") in err, err
    assert "Traceback" not in err and not (plate["dir"] / "six.png").exists()


def test_edit_and_neutral_take_a_plate_s_numbers(plate, arkit_model):
    """``edit --add eyeBlinkLeft@1010-1012`` of the plate's track edits its rows 9-11 (the
    curve at 1 there, every other row as it was), ``--add ...@5-7`` is refused naming
    1001-1020; ``export --neutral 1010`` measures the take from row 9 (as the library does
    from that row), said as frame 1010."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export.livelink import read_livelink
    from facetransfer.export.neutral import calibrated
    from facetransfer.track.project import held_lost

    track = Track.load(plate["plate_track"])
    code, said, err = _main(["edit", plate["plate_track"], "--model", plate["model"], "--add",
                             "eyeBlinkLeft@1010-1012", "--ramp", 0,
                             "--out", plate["dir"] / "e.npz"])
    assert code == 0, err
    assert "20 frames (numbered 1001-1020 as the plate's files), 1 addition(s)" in said, said
    j = ARKIT_NAMES.index("eyeBlinkLeft")
    new = Track.load(plate["dir"] / "e.npz").blendshapes
    np.testing.assert_allclose(new[9:12, j], 1.0, atol=1e-4)
    rest = np.ones(20, bool)
    rest[9:12] = False
    np.testing.assert_allclose(new[rest], track.blendshapes[rest], atol=1e-4)
    assert track.blendshapes[9:12, j].max() < 0.9       # the edit changed them
    code, _, err = _main(["edit", plate["plate_track"], "--model", plate["model"], "--add",
                          "eyeBlinkLeft@5-7", "--out", plate["dir"] / "f.npz"])
    assert code == 2 and "frames outside the clip (1001-1020" in err, err

    csv = plate["dir"] / "n.csv"
    code, said, err = _main(["export", plate["plate_track"], "--model", plate["model"],
                             "--neutral", 1010, "--out", csv])
    assert code == 0, err
    assert "measured from the neutral frame 1010" in said, said
    truth = calibrated(held_lost(track).blendshapes, 9)
    np.testing.assert_allclose(read_livelink(csv).activations, truth, atol=1e-7)
    code, _, err = _main(["export", plate["plate_track"], "--model", plate["model"],
                          "--neutral", 9, "--out", plate["dir"] / "m.csv"])
    assert code == 2 and "--neutral 9: the track has frames 1001 to 1020" in err, err


def test_occluders_name_a_plate_s_frames_by_its_numbers(plate, arkit_model, monkeypatch):
    """``track --occluders`` of the plate names the frames its mouth was found covered in by
    the plate's numbers (the capture and the test of the pixels stood in for: rows 10-12)."""
    import facetransfer.cli.track as cli_track
    import facetransfer.track.occlusion as occlusion

    track = Track.load(plate["plate_track"])
    monkeypatch.setattr(cli_track, "_capture", lambda *a, **k: (track, arkit_model))

    def covered(video, tr, model):
        occluded = np.zeros((tr.n_frames, len(occlusion.REGIONS)), bool)
        occluded[10:13, occlusion.REGIONS.index("mouth")] = True
        return dataclasses.replace(tr, occluded=occluded)

    monkeypatch.setattr(occlusion, "hold_occluded_video", covered)
    code, said, err = _main(["track", plate["plate"], "--model", plate["model"], "--occluders",
                             "--out", plate["dir"] / "occ.npz", "--no-progress"])
    assert code == 0, err
    assert "note: covered: mouth in frames 1011-1013 (" in said, said


def test_an_older_tracks_first_number_is_the_exports_rule(quick_model, tmp_path):
    """A track made before tracks recorded their clip's numbering (no ``source_facts``) is
    numbered by one rule in the messages (``track_first_number``, what ``probe``, ``edit --add``
    and ``--neutral`` use) and in the exports (``export.usd.source_first_frame``,
    ``export.common.clip_facts``): its plate's first number where the plate at its ``source``
    is still its clip (of its frame size); 0 where another plate now lies there (before: the
    messages took that plate's 2001, the USD 0) or none does (the plate moved)."""
    from conftest import still_track

    from facetransfer.export.common import clip_facts
    from facetransfer.export.usd import source_first_frame
    from facetransfer.io.frame_numbers import track_first_number
    from facetransfer.io.source_facts import SourceFacts

    for name, size, first in (("same", 64, 1001), ("other", 32, 2001)):
        (tmp_path / name).mkdir()
        for k in range(first, first + 3):
            cv2.imwrite(str(tmp_path / name / f"sh.{k}.png"), np.full((size, size, 3), 90,
                                                                     np.uint8))
    cases = {"same": 1001, "other": 0, "moved": 0}
    for name, want in cases.items():
        old = still_track(quick_model, 3, source=str(tmp_path / name / "sh.####.png"))
        assert old.source_facts is None
        got = (track_first_number(old), source_first_frame(old), clip_facts(old)[0].first_frame)
        assert got == (want, want, want), name
    # a recorded numbering is the track's, whatever is at its source now
    kept = dataclasses.replace(still_track(quick_model, 3,
                                           source=str(tmp_path / "other" / "sh.####.png")),
                               source_facts=SourceFacts(1001, None))
    assert track_first_number(kept) == source_first_frame(kept) == 1001
    # a video's track: 0 by both, nothing read
    video = still_track(quick_model, 3, source=str(tmp_path / "clip.mp4"))
    assert track_first_number(video) == source_first_frame(video) == 0


def test_one_lost_frame_is_said_as_one_frame():
    """walk55b: a 4K transfer said "1 kept original: the target's face is lost in frames 23";
    one frame is "frame 23", several are "frames ...", in the transfer's and the track's
    notes alike."""
    from types import SimpleNamespace

    from facetransfer.cli.export import lost_note

    one, two = np.zeros(24, bool), np.zeros(24, bool)
    one[23], two[[5, 7]] = True, True
    assert frames_said(one) == "frame 23" and frames_said(one, 1001) == "frame 1024"
    assert frames_said(two, 1001) == "frames 1006, 1008"
    assert frames_said(np.zeros(3, bool)) == ""
    track = SimpleNamespace(lost=one, source_facts=None, source=None)
    assert lost_note(track, "held").startswith("the face is lost in frame 23: held")

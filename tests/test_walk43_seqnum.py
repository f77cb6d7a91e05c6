"""What a compositor expects of a rewritten sequence (forty-third session's walk): its frames
numbered from a start number of their own (``--start-number``), and a plate written as a video
tagged with the colour its frames are in."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from _writing import write_rest  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.video import VideoOptions, read_video, write_video  # noqa: E402
from test_render_cache import _Model, _track  # noqa: E402
from test_transfer_cli import clips, plate_transfer_args  # noqa: E402,F401 (fixture)
from test_video_sequence import _plate  # noqa: E402


@pytest.fixture(scope="module")
def target(clips, tmp_path_factory):
    """The synthetic target's frames as a lossless video decodes them."""
    lossless = tmp_path_factory.mktemp("seqnum") / "target.mkv"
    write_video(lossless, read_video(clips["target"])[0], 25.0, options=VideoOptions(crf=0))
    return lossless, read_video(lossless)[0]


def _names(folder: Path) -> list[str]:
    return sorted(q.name for q in folder.iterdir())


def test_start_number_numbers_the_frames_and_changes_nothing_else(clips, target,
                                                                  quick_model_path, tmp_path,
                                                                  capsys, monkeypatch):
    """A plate numbered from 1001 written with ``--start-number 1``: its frames are named from
    1, hold what a run without it writes (named 1001 on), and the saved track is the same
    track (its exports number and time it as without it)."""
    from facetransfer.export.livelink import source_timecode
    from facetransfer.export.usd import source_first_frame
    from facetransfer.track.result import Track

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    _, frames = target
    _plate(tmp_path / "plate", frames)
    common = plate_transfer_args(clips, quick_model_path)
    runs = {}
    for name, extra in (("plain", []), ("one", ["--start-number", "1"])):
        (tmp_path / name).mkdir()
        code = main(["transfer", "--target", str(tmp_path / "plate" / "sh010.####.png"),
                     *common, "--out", str(tmp_path / name / "ft.%04d.png"),
                     "--save-track", str(tmp_path / f"{name}.npz"), *extra])
        said = capsys.readouterr()
        assert code == 0, said.err
        runs[name] = _names(tmp_path / name)
        first = 1 if extra else 1001
        assert f"numbered {first}-{first + len(frames) - 1}" in said.out
    n = len(frames)
    assert runs["plain"] == [f"ft.{1001 + i:04d}.png" for i in range(n)]
    assert runs["one"] == [f"ft.{1 + i:04d}.png" for i in range(n)]
    for a, b in zip(runs["plain"], runs["one"]):
        assert np.array_equal(cv2.imread(str(tmp_path / "plain" / a)),
                              cv2.imread(str(tmp_path / "one" / b)))
    plain, one = Track.load(tmp_path / "plain.npz"), Track.load(tmp_path / "one.npz")
    assert one.source == plain.source and one.info.get("start_timecode") == \
        plain.info.get("start_timecode")
    assert source_first_frame(one) == source_first_frame(plain)
    assert source_timecode(one) == source_timecode(plain)
    assert np.array_equal(one.weights["expression"], plain.weights["expression"])


@pytest.mark.parametrize("argv, said", [
    (["--start-number", "-1"], "argument --start-number: expected an integer >= 0, got '-1'"),
    (["--start-number", "x"], "argument --start-number: expected an integer >= 0, got 'x'"),
    (["--start-number", "1001", "--out", "OUT.mov"],
     "--start-number numbers image sequences only (e.g. shot/%04d.exr), not the video "),
])
def test_a_bad_start_number_is_one_line(argv, said, clips, tmp_path, capsys):
    """A negative or non-integer ``--start-number``, or one for a video file: one line, exit
    status 2, before any work."""
    out = ["--out", str(tmp_path / "x.%04d.png")] if "--out" not in argv else []
    argv = [str(tmp_path / a) if a == "OUT.mov" else a for a in argv]
    try:
        code = main(["transfer", "--target", str(clips["target"]), "--expression-from",
                     str(clips["source"]), "--no-progress", *out, *argv])
    except SystemExit as exc:      # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and said in err[-1] and "Traceback" not in "\n".join(err)
    assert not list(tmp_path.glob("x.*"))


def test_track_and_puppet_take_the_start_number_for_sequences_only(clips, tmp_path, capsys):
    """``track --overlay`` and ``puppet`` take ``--start-number`` too; without an image
    sequence to number it is refused in one line."""
    for argv in (["track", str(clips["target"]), "--out", str(tmp_path / "t.npz"),
                  "--start-number", "3"],
                 ["track", str(clips["target"]), "--out", str(tmp_path / "t.npz"),
                  "--overlay", str(tmp_path / "o.mp4"), "--start-number", "3"],
                 ["puppet", str(clips["target"]), "--out", str(tmp_path / "p.mp4"),
                  "--start-number", "3"]):
        assert main(argv) == 2
        assert "--start-number numbers image sequences only" in \
            capsys.readouterr().err.strip().splitlines()[-1]


def test_an_interrupted_sequence_continues_under_another_start_number(tmp_path, monkeypatch):
    """The render cache keeps a sequence's frames counted from 0 and names them only when
    they are placed: a run interrupted without ``--start-number`` is continued by one with
    it (the same key), and its frames are placed from that number, as if written at once."""
    from facetransfer import render_cache as rc

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(6)]
    out = tmp_path / "out" / "sh010.%04d.png"
    keys = {first: rc.puppet_key(_track(), _Model("m"), np.zeros(2),
                                 VideoOptions(first_number=first), images=True)
            for first in (None, 1001)}
    assert keys[None] == keys[1001]

    def writer(first):
        return rc.parts_writer(keys[first], out, 25.0, (32, 24), 6,
                               video_options=VideoOptions(first_number=first))

    with pytest.raises(KeyboardInterrupt):
        write_rest(writer(None), frames, stop=4)
    w = writer(1001)
    assert write_rest(w, frames) == 4
    assert _names(out.parent) == [f"sh010.{1001 + i:04d}.png" for i in range(6)]
    for i, f in enumerate(frames):
        got = cv2.cvtColor(cv2.imread(str(out.parent / f"sh010.{1001 + i:04d}.png")),
                           cv2.COLOR_BGR2RGB)
        assert np.array_equal(got, f)


def _described(path: Path) -> str:
    """ffmpeg's own description of ``path``'s first video stream (``ffmpeg -i``)."""
    from facetransfer.io.ffmpeg import ffmpeg_exe

    err = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True,
                         text=True).stderr
    return next(line for line in err.splitlines() if "Video:" in line)


def test_an_exr_plate_written_as_a_video_names_srgb_rec709(clips, target, quick_model_path,
                                                          tmp_path, capsys, monkeypatch):
    """An OpenEXR plate (scene-linear, shown through the sRGB curve) rewritten as a ``.mov``:
    its header names Rec.709 primaries and the sRGB transfer (was: unknown), and the matrix
    its values were converted by (BT.601); a PNG plate's names none, as before."""
    from facetransfer.io.video_display import video_colour
    from test_exr import _exr_plate

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    _, frames = target
    plate = _exr_plate(tmp_path / "plate", frames)
    common = plate_transfer_args(clips, quick_model_path)
    out = tmp_path / "out.mov"
    code = main(["transfer", "--target", str(plate), *common, "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    tags = video_colour(out)
    assert (tags.matrix, tags.primaries, tags.transfer) == ("smpte170m", "bt709",
                                                             "iec61966-2-1")
    assert "smpte170m/bt709/iec61966-2-1" in _described(out)
    from facetransfer.io.video_like import like_video

    _plate(tmp_path / "png", frames[:2])
    png = like_video(None, tmp_path / "png" / "sh010.####.png", tmp_path / "o.mov")
    assert (png.primaries, png.transfer) == (None, None)


@pytest.mark.parametrize("transfer, named", [("Printing density", ("bt709", "iec61966-2-1")),
                                             ("Linear", ("bt709", "iec61966-2-1")),
                                             ("ITU-R 709-4", ("bt709", "bt709")),
                                             ("Unspecified video", (None, None))])
def test_a_dpx_plate_written_as_a_video_names_how_it_was_shown(transfer, named, tmp_path):
    """A DPX plate of log or linear light is shown through the sRGB curve, one of Rec.709 video
    codes as they are: a video written from it names that (read back from the file); one of
    no transfer the project knows names none."""
    from facetransfer.io.dpx import DpxImage, write_dpx
    from facetransfer.io.video_display import video_colour
    from facetransfer.io.video_like import like_video
    from test_dpx import _spec

    folder = tmp_path / "plate"
    folder.mkdir()
    codes = np.full((16, 16, 3), 500, np.uint16)
    for i in range(2):
        write_dpx(folder / f"sh010.{1001 + i:04d}.dpx",
                  DpxImage(codes, 10, transfer, _spec(16, 16, 3, 10, transfer, i)))
    out = tmp_path / "out.mp4"
    opts = like_video(None, folder / "sh010.####.dpx", out)
    assert (opts.primaries, opts.transfer) == named
    write_video(out, [np.full((16, 16, 3), 128, np.uint8)] * 2, 25.0, options=opts)
    tags = video_colour(out)
    assert (tags.matrix, tags.primaries, tags.transfer) == ("smpte170m", *named)

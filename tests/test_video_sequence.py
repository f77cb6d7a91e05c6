"""Image sequences read as videos (facetransfer.io.video_sequence): a plate of numbered frames
(``plate/%04d.png``, ``plate/####.png``, numbered from 1001 as compositing packages do) is an
input of every command, and a rewritten plate is numbered as it was."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.video import (VideoOptions, check_video_output, iter_frames,  # noqa: E402
                                   read_video, video_info)
from facetransfer.io.video_sequence import percent_pattern, same_sequence_files  # noqa: E402
from test_transfer_cli import clips  # noqa: E402,F401 (the fixture: synthetic clips, tracks)


@pytest.fixture(scope="module")
def frames(data_dir):
    return read_video(data_dir / "video" / "driving_d6.mp4", max_frames=8)[0]


def _plate(folder: Path, frames, *, first=1001, name="sh010.{:04d}.png", convert=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        img = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
        cv2.imwrite(str(folder / name.format(first + i)), convert(img) if convert else img)


@pytest.mark.parametrize("kind", ["8-bit", "16-bit", "16-bit grey", "alpha", "grey", "jpeg"])
def test_a_plate_reads_as_the_frames_it_holds(frames, tmp_path, kind, monkeypatch):
    """Whatever its depth and channels, a plate numbered from 1001 reads as its frames: whole,
    from a later frame, at 24 fps unless a rate is given."""
    convert = {"16-bit": lambda im: im.astype(np.uint16) * 257,
               "16-bit grey": lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY).astype(np.uint16)
               * 257,
               "alpha": lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2BGRA),
               "grey": lambda im: cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)}.get(kind)
    name = "sh010.{:04d}.jpg" if kind == "jpeg" else "sh010.{:04d}.png"
    _plate(tmp_path, frames, name=name, convert=convert)
    pattern = tmp_path / name.replace("{:04d}", "####")
    expect = frames.astype(int)
    if kind in ("grey", "16-bit grey"):
        grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
        expect = np.repeat(np.stack(grey)[..., None], 3, -1).astype(int)
    got, fps = read_video(pattern)
    tol = {"jpeg": 12.0}.get(kind, 0)   # 16 bits as round(v / 257): 8-bit * 257 exactly
    assert got.shape == frames.shape and fps == 24.0
    assert (np.abs(got.astype(int) - expect).mean() if kind == "jpeg" else
            np.abs(got.astype(int) - expect).max()) <= tol
    later = np.stack(list(iter_frames(percent_pattern(pattern), start=3, stop=6)))
    assert np.array_equal(later, got[3:6])
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "29.97")
    info = video_info(pattern)
    assert (info.fps, info.n_frames, info.size, info.sar) == (29.97, 8, (480, 480), (1, 1))
    assert not info.piped and info.steps is None


def test_a_replaced_frame_is_read_anew(frames, tmp_path):
    """What is read of a sequence is kept by its files' sizes and times: a frame rewritten
    (a plate re-rendered) is read as it is now."""
    _plate(tmp_path, frames[:3])
    pattern = tmp_path / "sh010.%04d.png"
    assert np.array_equal(read_video(pattern)[0][1], frames[1])
    cv2.imwrite(str(tmp_path / "sh010.1002.png"), np.zeros((480, 480, 3), np.uint8))
    assert read_video(pattern)[0][1].max() == 0
    _plate(tmp_path, frames[3:4], first=1004)
    assert video_info(pattern).n_frames == 4


def test_what_a_sequence_cannot_be(frames, tmp_path, monkeypatch):
    """Each bad plate gets one line naming what is wrong and where."""
    _plate(tmp_path / "gap", frames[:4])
    (tmp_path / "gap" / "sh010.1003.png").unlink()
    _plate(tmp_path / "size", frames[:2])
    cv2.imwrite(str(tmp_path / "size" / "sh010.1003.png"), np.zeros((10, 12, 3), np.uint8))
    (tmp_path / "empty").mkdir()
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "sh010.1001.png").write_bytes(b"not a png")
    cases = {
        tmp_path / "gap" / "sh010.%04d.png": "frame 1003 is missing (sh010.1003.png): frames "
                                             "1001-1002 and 1004 are present",
        tmp_path / "empty" / "sh010.####.png": "no file matches it (e.g. sh010.0001.png",
        tmp_path / "none" / "x_%04d.png": "folder " + str(tmp_path / "none") + " does not exist",
        tmp_path / "broken" / "sh010.####.png": "cannot read frame file",
        tmp_path / "empty" / "a%03d_%03d.png": "exactly one frame-number field",
        tmp_path / "empty" / "plate.####.cin": ".cin frames are not read",
    }
    for pattern, said in cases.items():
        with pytest.raises(VideoError, match="image sequence") as err:
            read_video(pattern)
        assert said in str(err.value) and str(pattern) in str(err.value)
    with pytest.raises(VideoError, match=r"sh010.1003.png is 12x10, its first frame 480x480"):
        read_video(tmp_path / "size" / "sh010.%04d.png")
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "fast")
    with pytest.raises(VideoError, match="FACETRANSFER_SEQUENCE_FPS .* got 'fast'"):
        video_info(tmp_path / "gap" / "sh010.%04d.png")


def test_an_output_sequence_never_writes_over_an_input_plate(tmp_path):
    """The same files by another spelling (``####``/``%04d``/``%05d``) are refused; another
    name or folder is not."""
    plate = tmp_path / "sh010.####.png"
    for out, refused in (("sh010.%04d.png", True), ("sh010.%05d.png", True),
                         ("sh010_out.%04d.png", False), ("out/sh010.%04d.png", False)):
        assert same_sequence_files(tmp_path / out, plate) == refused
    (tmp_path / "out").mkdir()
    with pytest.raises(VideoError, match="would write over the frames of the input"):
        check_video_output(tmp_path / "sh010.%05d.png", inputs=[plate])
    check_video_output(tmp_path / "out" / "sh010.%04d.png", inputs=[plate])
    with pytest.raises(VideoError, match=r"as sh010.%04d.png \(#### is read"):
        check_video_output(tmp_path / "out" / "sh010.####.png")
    with pytest.raises(VideoError, match="first frame number must be an integer >= 0"):
        VideoOptions(first_number=-1)


def test_a_sequence_is_keyed_by_its_files(frames, tmp_path, monkeypatch, quick_model):
    """The track cache and the resumable tracker know a sequence by its files: a frame
    changed is another video."""
    from facetransfer.track.cache import track_key
    from facetransfer.track.checkpoint import video_identity

    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    _plate(tmp_path, frames[:3])
    pattern = tmp_path / "sh010.%04d.png"
    key, ident = track_key(pattern, 3, "capture", None, quick_model), video_identity(pattern)
    assert key is not None and ident.startswith("sequence:")
    cv2.imwrite(str(tmp_path / "sh010.1002.png"), np.zeros((480, 480, 3), np.uint8))
    assert track_key(pattern, 3, "capture", None, quick_model) != key
    assert video_identity(pattern) != ident


def test_batch_names_a_sequence_by_its_shot(tmp_path):
    from facetransfer.batch.manifest import _stem

    assert _stem("plate/sh010.####.png") == "sh010"
    assert _stem("plate/sh010_%04d.png") == "sh010"
    (tmp_path / "shot12").mkdir()
    assert _stem(tmp_path / "shot12" / "%04d.png") == "shot12"
    assert _stem("clip.v2.mp4") == "clip.v2"


def test_probe_and_the_rate_of_a_sequence(frames, tmp_path, capsys):
    from facetransfer.cli.main import main

    _plate(tmp_path, frames[:5])
    pattern = str(tmp_path / "sh010.####.png")
    assert main(["probe", pattern, "--sequence-fps", "25"]) == 0
    out = capsys.readouterr().out
    assert "image sequence, frames 1001-1005; read at 25 fps, 5 frames, 0.2 s" in out
    assert main(["probe", pattern, "--json"]) == 0
    import json

    [facts] = json.loads(capsys.readouterr().out)
    assert facts["first_number"] == 1001 and facts["audio"] is None
    with pytest.raises(SystemExit) as code:
        main(["probe", pattern, "--sequence-fps", "0"])
    assert code.value.code == 2
    assert "expected a frame rate in (0, 1000], got '0'" in capsys.readouterr().err


def test_a_plate_is_rewritten_as_the_video_of_its_frames(clips, quick_model_path, tmp_path,
                                                        capsys, monkeypatch):
    """A transfer onto a PNG plate numbered from 1001 gives the frames a transfer onto the
    same frames in a video gives, numbered 1001 on; written over the plate, it is refused and
    the plate is untouched."""
    from facetransfer.cli.main import main
    from facetransfer.io.video import write_video

    monkeypatch.delenv("FACETRANSFER_SEQUENCE_FPS", raising=False)
    clip = clips
    lossless = tmp_path / "target.mkv"
    write_video(lossless, read_video(clip["target"])[0], 25.0, options=VideoOptions(crf=0))
    target = read_video(lossless)[0]            # the video's frames, as its decoder gives them
    _plate(tmp_path / "plate", target)
    common = ["--target-track", clip["target_track"], "--expression-from", clip["source"],
              "--source-track", clip["source_track"], "--model", quick_model_path,
              "--no-progress"]
    plate = tmp_path / "plate" / "sh010.####.png"
    (tmp_path / "out").mkdir()
    code = main(["transfer", "--target", str(plate), *map(str, common), "--sequence-fps", "25",
                 "--out", str(tmp_path / "out" / "sh010_ft.####.png")])   # as %04d
    out = capsys.readouterr()
    assert code == 0, out.err
    assert f"{len(target)} frames numbered 1001-{1000 + len(target)}, no audio" in out.out
    names = sorted(q.name for q in (tmp_path / "out").iterdir())
    assert names == [f"sh010_ft.{1001 + i:04d}.png" for i in range(len(target))]
    code = main(["transfer", "--target", str(lossless), *map(str, common),
                 "--out", str(tmp_path / "video_%03d.png")])
    assert code == 0, capsys.readouterr().err
    for i in range(len(target)):
        a = cv2.imread(str(tmp_path / "out" / names[i]))
        b = cv2.imread(str(tmp_path / f"video_{i:03d}.png"))
        assert np.array_equal(a, b)
    before = sorted((q.name, q.stat().st_mtime_ns) for q in (tmp_path / "plate").iterdir())
    capsys.readouterr()
    code = main(["transfer", "--target", str(plate), *map(str, common), "--sequence-fps", "25",
                 "--overwrite", "--out", str(tmp_path / "plate" / "sh010.%04d.png")])
    assert code == 2 and "would write over the frames of the input" in capsys.readouterr().err
    assert sorted((q.name, q.stat().st_mtime_ns)
                  for q in (tmp_path / "plate").iterdir()) == before


def test_a_folder_given_as_a_video_names_its_sequence(frames, tmp_path):
    """A plate's folder given where a video goes: the pattern to give instead is named (not
    for a folder with one numbered still)."""
    _plate(tmp_path / "plate", frames[:2])
    with pytest.raises(VideoError, match=r"is a folder, not a video file \(its image sequence: "
                                         r"give .*plate/sh010\.%04d\.png\)"):
        video_info(tmp_path / "plate")
    cv2.imwrite(str(tmp_path / "still7.png"), frames[0])
    with pytest.raises(VideoError, match=r"is a folder, not a video file$"):
        video_info(tmp_path)


def test_one_frame_of_a_plate_given_as_a_video_names_its_sequence(frames, tmp_path, caplog):
    """One numbered frame of a plate given where a video goes: read as a still of one frame,
    and a warning names the plate's pattern (the frame's own run of digits, beside another
    sequence in the same folder); a numbered still alone, or an unnumbered image: no word."""
    _plate(tmp_path / "plate", frames[:3])
    _plate(tmp_path / "plate", frames[:2], first=1, name="aa_{:03d}.png")   # another before it
    cv2.imwrite(str(tmp_path / "still7.png"), frames[0])
    cv2.imwrite(str(tmp_path / "poster.png"), frames[0])
    with caplog.at_level("WARNING", logger="facetransfer.io.video_read"):
        got, _ = read_video(tmp_path / "plate" / "sh010.1002.png")
        for still in ("still7.png", "poster.png"):
            read_video(tmp_path / still)
    assert got.shape[0] == 1
    said = [r.getMessage() for r in caplog.records if "one frame of" in r.getMessage()]
    assert said == [f"{tmp_path / 'plate' / 'sh010.1002.png'} is one frame of the image "
                    f"sequence {tmp_path / 'plate' / 'sh010.%04d.png'} (3 files) and is read "
                    f"as a still of one frame; give {tmp_path / 'plate' / 'sh010.%04d.png'} "
                    "to read the sequence"]

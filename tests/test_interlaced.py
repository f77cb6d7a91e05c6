"""Interlaced video: decoded by ffmpeg where OpenCV returns black frames, tracked on its first
field, written back interlaced (facetransfer.io.video_pipe, facetransfer.track.aspect)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from facetransfer.io.video import VideoOptions, iter_frames, read_video, video_info, write_video
from facetransfer.io.video_like import like_video
from facetransfer.io.video_display import exact_seek, field_named, first_field
from facetransfer.track.aspect import View, field_frame


def _woven(frames: np.ndarray, top_first: bool = True) -> np.ndarray:
    """Pairs of progressive frames woven into interlaced ones: the first of each pair gives
    the field shown first (the top rows 0, 2, ... for ``top_first``), the second the other."""
    a, b = frames[0::2], frames[1::2]
    n = min(len(a), len(b))
    out = a[:n].copy()
    k = 1 if top_first else 0
    out[:, k::2] = b[:n, k::2]
    return out


@pytest.fixture(scope="module")
def interlaced(data_dir, tmp_path_factory):
    """60 frames of ``driving_d6`` woven into 30 interlaced ones (top field first), written
    losslessly as interlaced H.264 at 15 fps; and the progressive frames of its first fields."""
    frames = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=60)[0]
    d = tmp_path_factory.mktemp("interlaced")
    woven = _woven(frames)
    path = d / "woven.mp4"
    write_video(path, woven, 15.0, options=VideoOptions(crf=0, field="top"))
    firsts = d / "firsts.mkv"
    write_video(firsts, frames[0::2], 15.0, options=VideoOptions(crf=0))
    return path, woven, firsts


def test_the_first_field_is_read_from_the_first_frame_else_the_header():
    def desc(i, fields=""):
        return ("Input #0, avi, from 'x.avi':\n"
                f"  Stream #0:0: Video: dvvideo, yuv411p{fields}, 720x480 [SAR 10:11], 25 fps\n"
                f"[Parsed_showinfo_0 @ 0x1] n:   0 pts:      0 fmt:yuv411p s:720x480 i:{i} "
                "iskey:1 type:I\n")
    assert field_named(desc("T")) == "top" and field_named(desc("B")) == "bottom"
    assert field_named(desc("P")) is None and field_named("") is None
    # a first frame progressive in a stream whose header says interlaced (broadcast captures)
    assert field_named(desc("P", "(tv, bt709, bottom first)")) == "bottom"
    assert field_named(desc("P", "(top coded first (swapped))")) == "top"
    assert field_named(desc("P", "(tv, bt709, progressive)")) is None
    assert field_named(desc("B", "(top first)")) == "bottom"          # the frame's own flag


def _ffmpeg(*args) -> None:
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe

    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", *map(str, args)], check=True)


@pytest.mark.parametrize("kind", ["dv", "ts"])
def test_dv_and_transport_streams_read_whole_and_from_any_frame(data_dir, tmp_path, kind,
                                                                caplog):
    """DV (interlaced with no field order in its header: OpenCV's frames were black) and H.264
    in an MPEG transport stream (AVCHD's .mts: OpenCV's seek landed nowhere, so reading from
    frame 40 found no frames)."""
    src = data_dir / "video" / "driving_d6.mp4"
    if kind == "dv":
        path = tmp_path / "clip.avi"
        _ffmpeg("-i", src, "-t", 2, "-vf", "scale=720:480,setsar=10/11", "-r", "30000/1001",
                "-c:v", "dvvideo", "-pix_fmt", "yuv411p", "-an", path)
    else:
        path = tmp_path / "clip.ts"
        _ffmpeg("-i", src, "-t", 2, "-c:v", "copy", "-an", "-f", "mpegts", path)
    info = video_info(path)
    assert info.piped == (kind == "dv") and exact_seek(path) == (kind == "dv")   # AVI: exact
    assert (info.sar == (10, 11)) == (kind == "dv")
    frames = read_video(path)[0]
    assert len(frames) >= 59 and frames.mean() > 100
    later = read_video(path, start=40, max_frames=5)[0]
    np.testing.assert_array_equal(later, frames[40:45])
    np.testing.assert_array_equal(np.stack(list(iter_frames(path, start=40, stop=45))), later)
    from facetransfer.track.aspect import warn_stored_fit

    with caplog.at_level(logging.WARNING, logger="facetransfer.track.aspect"):
        warn_stored_fit(path, "optical-flow tracker")
    said = ["0.91 times as wide as tall" in caplog.text, "is interlaced" in caplog.text]
    assert said == ([True, True] if kind == "dv" else [False, False])


def test_an_interlaced_h264_is_read_as_its_woven_frames(interlaced, data_dir):
    """OpenCV returns this file's frames black (or whatever its buffer held); read through
    ffmpeg they are the woven frames written (lossless but for the YUV round trip)."""
    path, woven, _ = interlaced
    assert first_field(path) == "top" and video_info(path).piped
    got = read_video(path)[0]
    assert got.shape == woven.shape
    assert np.abs(got.astype(int) - woven).mean() < 2.0      # 4:2:0 of woven chroma
    np.testing.assert_array_equal(read_video(path, start=7, max_frames=3)[0], got[7:10])
    progressive = data_dir / "video" / "driving_d6.mp4"
    assert first_field(progressive) is None and not video_info(progressive).piped


def test_the_first_field_keeps_its_rows_and_fills_the_others_between_them():
    f = (np.arange(9, dtype=np.uint8) * 20)[:, None, None].repeat(2, 1).repeat(3, 2)
    f[1::2] = 255                              # the second field: another instant
    top = field_frame(f, "top")
    np.testing.assert_array_equal(top[0::2], f[0::2])
    np.testing.assert_array_equal(top[1:8:2, 0, 0], [20, 60, 100, 140])
    f = (np.arange(8, dtype=np.uint8) * 20)[:, None, None].repeat(2, 1).repeat(3, 2)
    f[0::2] = 255
    bottom = field_frame(f, "bottom")
    np.testing.assert_array_equal(bottom[1::2], f[1::2])
    np.testing.assert_array_equal(bottom[0::2, 0, 0], [20, 40, 80, 120])   # row 0: its edge


def test_an_interlaced_clip_is_captured_as_its_first_fields(interlaced, arkit_model):
    """Tracked on its first field, the woven clip gives the activations of the progressive
    frames of those fields; on the woven frames (two instants a frame) several times further."""
    from facetransfer.track.capture import capture_video

    path, _, firsts = interlaced
    ref = capture_video(firsts, arkit_model)
    tr = capture_video(path, arkit_model)
    woven = capture_video(path, arkit_model, view=View())
    assert tr.n_frames == ref.n_frames == 30 and tr.frame_size == ref.frame_size
    err = np.abs(tr.blendshapes - ref.blendshapes).mean()
    err_woven = np.abs(woven.blendshapes - ref.blendshapes).mean()
    assert err < 0.01 and err_woven > 2 * err


def test_a_rewritten_interlaced_video_stays_interlaced(interlaced, tmp_path, caplog):
    path, woven, _ = interlaced
    opts = like_video(None, path)
    assert opts.field == "top"
    out = tmp_path / "again.mov"
    write_video(out, woven[:4], 15.0, options=VideoOptions(codec="prores", field="bottom"))
    assert first_field(out) == "bottom"
    with caplog.at_level(logging.WARNING, logger="facetransfer.io.video_like"):
        assert like_video(VideoOptions(codec="h265"), path).field is None
    assert "x265 writes progressive frames" in caplog.text


def test_probe_says_how_a_video_is_read(interlaced, data_dir, tmp_path, capsys):
    import json

    from facetransfer.cli.main import main

    path = interlaced[0]
    d9 = data_dir / "video" / "driving_d9.mp4"
    assert main(["probe", str(path), str(d9), "--json"]) == 0
    woven, shown = json.loads(capsys.readouterr().out)
    assert (woven["field"], woven["decoder"], woven["n_frames"], woven["fps"]) == \
        ("top", "ffmpeg", 30, 15.0)
    assert woven["size"] == woven["shown_size"] == [480, 480] and woven["audio"] is None
    assert (shown["sar"], shown["shown_size"], shown["field"], shown["decoder"]) == \
        ([15, 16], [480, 480], None, "OpenCV")
    assert shown["exact_seek"] and shown["audio"] == "aac"
    assert main(["probe", str(path)]) == 0
    text = capsys.readouterr().out
    assert "interlaced, top field first (decoded by ffmpeg" in text
    assert main(["probe", str(tmp_path / "none.mp4")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"facetransfer probe: error: video {tmp_path / 'none.mp4'} does not exist"]

"""Videos of variable frame rate read on a constant-rate timeline (facetransfer.io.video_timeline)."""

from __future__ import annotations

import logging
import subprocess

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facetransfer.io import video_timeline as vt
from facetransfer.io.video import VideoOptions, encode_video, ffmpeg_exe
from facetransfer.io.video_read import iter_frames, read_video, video_info

LISTING = """#extradata 0:       54, 0xe3fc1382
#software: Lavf63.1.102
#tb 0: 1/15360
#media_type 0: video
0,      -1024,          0,      512,    28155, 0x272c98c7
0,       -512,       2048,      512,    10123, 0xa26893a8, F=0x0
0,          0,       1024,      512,     2094, 0x9e600d91, F=0x0
0,        512,        512,      512,     1053, 0x592103a0, F=0x0
"""


def test_framecrc_times_are_sorted_seconds():
    np.testing.assert_allclose(vt._framecrc_times(LISTING), np.array([0, 1, 2, 4]) * 512 / 15360)
    assert vt._framecrc_times("0, 0, 0, 1, 1, 0x0\n") is None            # no time base
    assert vt._framecrc_times("#tb 0: 1/0\n0, 0, 0, 1, 1, 0x0\n") is None  # a zero one
    nopts = LISTING.replace("  2048,", " -9223372036854775808,")
    assert vt._framecrc_times(nopts) is None                            # a packet without time


@pytest.mark.parametrize("times,want", [
    (np.arange(10) / 30, None),                                          # even
    (np.cumsum([0] + [0.033, 0.034, 0.033] * 5), None),                  # a millisecond time base
    (np.r_[np.arange(5), np.arange(5) + 8] / 10, [0, 1, 2, 3, 4, 4, 4, 4, 5, 6, 7, 8, 9]),
    (np.r_[0, 0.1, 0.2, 0.21, 0.3, 0.4, 0.5, 0.6], [0, 1, 3, 4, 5, 6, 7]),  # two in a step: the later
])
def test_timeline_steps(times, want, caplog):
    with caplog.at_level(logging.WARNING):
        got = vt._timeline(np.asarray(times, float), len(times), "v.mp4")
    if want is None:
        assert got is None and not caplog.records
        return
    fps, steps = got
    assert list(steps) == want
    assert "v.mp4 has a variable frame rate" in caplog.text


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="#tb0123456789:/ ,-\nxF=a", max_size=300))
def test_the_listing_parser_never_raises(text):
    """Whatever ffmpeg prints (a damaged file's listing), the times are None or sorted."""
    times = vt._framecrc_times(text)
    assert times is None or (np.all(np.diff(times) >= 0) and np.isfinite(times).all())


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=200))
def test_the_colour_description_parser_never_raises(pixels):
    from facetransfer.io.video_display import colour_named

    colour_named(f"  Stream #0:0: Video: h264, {pixels}, 512x480\n")


def test_timeline_needs_every_packet():
    times = np.r_[np.arange(5), np.arange(5) + 8] / 10
    assert vt._timeline(times, len(times) + 1, "v.mp4") is None        # a count that differs
    assert vt._timeline(None, 10, "v.mp4") is None


@pytest.fixture(scope="module")
def uneven(tmp_path_factory):
    """12 frames of grey levels 0, 20, ... 220 at 10 fps, frames 6-11 shown 0.5 s late: a
    5-step gap (re-timed by ffmpeg, losslessly encoded)."""
    d = tmp_path_factory.mktemp("vfr")
    frames = np.repeat((np.arange(12) * 20).astype(np.uint8)[:, None, None, None], 3, axis=3)
    frames = np.broadcast_to(frames, (12, 32, 48, 3)).copy()
    even = encode_video(d / "even.mp4", frames, 10, options=VideoOptions(crf=0)).path
    out = d / "uneven.mp4"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(even), "-vf",
                    "setpts='if(gte(N,6),N+5,N)/10/TB'", "-fps_mode", "vfr", "-c:v", "libx264",
                    "-crf", "0", str(out)], check=True)
    return even, out


def _levels(frames) -> list[int]:
    return [int(round(float(f.mean()) / 20)) for f in frames]


def test_an_uneven_video_is_read_on_its_constant_rate_timeline(uneven):
    even, path = uneven
    info = video_info(path)
    assert info.fps == pytest.approx(10) and info.n_frames == 17
    frames, fps = read_video(path)
    want = [0, 1, 2, 3, 4, 5, 5, 5, 5, 5, 5, 6, 7, 8, 9, 10, 11]
    assert fps == pytest.approx(10) and _levels(frames) == want
    for start, stop, seek in ((0, None, True), (4, 12, True), (7, 9, False), (12, 30, True)):
        got = list(iter_frames(path, start=start, stop=stop, seek=seek))
        assert _levels(got) == want[start:stop]
        assert all(np.array_equal(a, b) for a, b in zip(got, frames[start:stop]))
    assert _levels(read_video(path, start=3, max_frames=5)[0]) == want[3:8]
    a, b = list(iter_frames(path, start=6, stop=8))
    a[:] = 255                                  # a frame yielded twice is two arrays
    assert b.max() < 255
    plain = video_info(even)                    # an even video: as stored, no steps
    assert plain.steps is None and plain.n_frames == 12


def test_the_warning_is_said_once_per_file(uneven, caplog):
    _, path = uneven
    from facetransfer.io import video_read

    vt._cached_timeline.cache_clear()
    video_read._kept_info.cache_clear()     # the file as if never read in this process
    with caplog.at_level(logging.WARNING):
        for _ in range(3):
            video_info(path)
            read_video(path)
    assert caplog.text.count("has a variable frame rate") == 1
    assert "read at a constant 10.000 fps, 17 frames for its 12" in caplog.text


def test_times_beyond_a_floats_range_are_no_times():
    """Found by the fuzz test above once: a 400-digit time raised OverflowError."""
    line = "0, 0, {}, 1, 2, x\n"
    assert vt._framecrc_times("#tb 0: 1/1\n" + line.format("9" * 400)) is None
    assert vt._framecrc_times("#tb 0: " + "9" * 400 + "/1\n" + line.format(5)) is None
    assert vt._framecrc_times("#tb 0: " + "9" * 300 + "/1\n" + line.format("9" * 300)) is None
    np.testing.assert_allclose(vt._framecrc_times("#tb 0: 1/30\n" + line.format(6)), [0.2])


def test_a_matroska_files_frames_are_its_packets(tmp_path, data_dir):
    """A Matroska file stores no frame count: OpenCV's is its duration times its rate, and
    with a target's audio (AAC's last packet runs past the video) 20 H.265 frames at 25 fps
    said 22 (OpenCV 4.x); its video packets are counted instead; every frame decoded is one
    of them."""
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 255, (64, 64, 3), dtype=np.uint8) for _ in range(20)]
    out = encode_video(tmp_path / "c.mkv", frames, 25,
                       options=VideoOptions(codec="h265", crf=28, preset="veryfast"),
                       audio_from=data_dir / "video" / "WDA_KatieHill_000.mp4").path
    info = video_info(out)
    assert info.n_frames == 20
    assert len(read_video(out)[0]) == 20
    assert vt.packet_count(out) == 20


#: Files whose container EXACT_SEEK names, made as cameras and editors make them: H.264 with
#: B-frames and open GOPs (keyframes every 12), an MP4 cut by stream copy (an edit list hiding
#: the frames before the cut), one whose first frame is at 7.3 s, Matroska and AVI.
_SEEK_FILES = {
    "bframes_open_gop.mp4": (["-bf", "3", "-g", "12", "-x264-params", "open-gop=1"], None),
    "edit_list.mp4": (["-bf", "3", "-g", "12"], ["-ss", "0.9"]),
    "late_start.mp4": (["-bf", "3", "-g", "12", "-output_ts_offset", "7.3"], None),
    "open_gop.mkv": (["-bf", "3", "-g", "12", "-x264-params", "open-gop=1"], None),
    "bframes.avi": (["-bf", "3", "-g", "12"], None),
}


@pytest.mark.parametrize("name", sorted(_SEEK_FILES))
def test_a_seek_where_it_is_exact_gives_the_frames_decoded_in_turn(tmp_path, name):
    """``iter_frames(start=s)`` by the container's seek (what the second detection process
    reads its warm-up with, track.video_detect) against the same frames decoded from the
    start, at starts on, after and just before keyframes."""
    from facetransfer.io.video_display import exact_seek
    from facetransfer.io.video_read import seeks_exactly

    made, cut = _SEEK_FILES[name]
    src, path = tmp_path / "src.mp4", tmp_path / name
    lavfi = ["-f", "lavfi", "-i", "testsrc2=size=96x64:rate=25:duration=2.4"]
    x264 = ["-c:v", "libx264", "-pix_fmt", "yuv420p"]
    if cut:     # the cut by stream copy of a file coded as the others
        subprocess.run([ffmpeg_exe(), "-v", "error", *lavfi, *x264, *made, str(src)], check=True)
        subprocess.run([ffmpeg_exe(), "-v", "error", *cut, "-i", str(src), "-c", "copy",
                        str(path)], check=True)
    else:
        subprocess.run([ffmpeg_exe(), "-v", "error", *lavfi, *x264, *made, str(path)],
                       check=True)
    whole = list(iter_frames(path, seek=False))
    assert exact_seek(path) and len(whole) >= 36
    # each keeps to its rate: the seek is used (an AVI of B-frames by its decoding times)
    assert seeks_exactly(path, video_info(path).fps)
    assert not any(np.array_equal(whole[i], whole[i + 1]) for i in range(len(whole) - 1))
    for s in (1, 5, 11, 12, 13, 23, 24, 30, len(whole) - 2):
        got = list(iter_frames(path, start=s, stop=s + 2, seek=True))
        assert len(got) == 2, (name, s)
        for a, b in zip(got, whole[s:s + 2]):
            np.testing.assert_array_equal(a, b, err_msg=f"{name} from frame {s}")


def test_a_seek_in_a_video_whose_rate_drifts_gives_the_frames_decoded_in_turn(tmp_path):
    """A 30 fps clip slowed to 25 fps for two seconds (a phone in the dark): every interval
    within UNEVEN, so it is read as stored, frame by frame; OpenCV's seek numbers the frame it
    lands on by its time, and landed 2 frames late after the slow part (4 before it, at its
    average rate). Such a video is now read from a later frame by decoding those before it,
    and ``probe`` says its seeks are not exact."""
    from facetransfer.io.video_facts import video_facts
    from facetransfer.io.video_read import seeks_exactly
    from facetransfer.io.video_timeline import on_rate_grid

    path = tmp_path / "drift.mp4"
    times = "if(lt(N,60),N/30,if(lt(N,120),2+(N-60)*0.04,4.4+(N-120)/30))"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "testsrc2=size=96x64:rate=30:duration=6", "-vf",
                    f"settb=1/90000,setpts='{times}/TB'", "-fps_mode", "passthrough",
                    "-enc_time_base:v", "1/90000", "-c:v", "libx264", "-pix_fmt", "yuv420p",
                    "-g", "30", "-video_track_timescale", "90000", str(path)], check=True)
    info = video_info(path)
    assert info.steps is None and info.n_frames == 180          # read as stored
    whole = list(iter_frames(path, seek=False))
    for s in (20, 50, 80, 119, 130, 170):
        got = next(iter_frames(path, start=s, stop=s + 1, seek=True))
        np.testing.assert_array_equal(got, whole[s], err_msg=f"from frame {s}")
    assert not seeks_exactly(path, info.fps) and not video_facts(path).exact_seek
    even = tmp_path / "even.mp4"
    encode_video(even, whole[:40], 30.0, options=VideoOptions(crf=0))
    assert on_rate_grid(even, video_info(even).fps) and seeks_exactly(even, 30.0)

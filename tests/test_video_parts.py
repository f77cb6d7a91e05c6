"""A video written in parts that outlive an interruption (facetransfer.io.video_parts)."""

import json
import os

import numpy as np
import pytest

from _writing import write_rest

from facetransfer.errors import VideoError
from facetransfer.io import video_parts as vp
from facetransfer.io.video import (VideoOptions, VideoWriter, encode_video, has_audio,
                                   read_video, stored_frame_count)

LOSSLESS = VideoOptions(crf=0)  # x264 lossless in YUV: decoded frames do not depend on parts


def _frames(n=23, h=48, w=64, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    return [np.roll(base, 3 * i, axis=1) for i in range(n)]


@pytest.fixture
def small_parts(monkeypatch):
    monkeypatch.setattr(vp, "PART_FRAMES", 5)


def _write(folder, out, frames, *, stop=None, audio_from=None, overwrite=True):
    """Write ``frames`` from where the folder's parts end; Ctrl-C before frame ``stop``."""
    w = vp.PartsWriter(folder, out, 25.0, (frames[0].shape[1], frames[0].shape[0]),
                       n_frames=len(frames), options=LOSSLESS, audio_from=audio_from,
                       overwrite=overwrite)
    return w, write_rest(w, frames, stop=stop, marked=lambda i: i % 2 == 0)


def test_an_interrupted_video_continues_and_equals_one_written_at_once(small_parts, tmp_path):
    frames = _frames()
    folder, out = tmp_path / "parts", tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, out, frames, stop=12)
    kept = vp.kept_parts(folder)
    # two full parts and the 2 frames of the third (ffmpeg finished it): nothing lost
    assert [(p.start, p.frames, p.marked) for p in kept] == [(0, 5, 3), (5, 5, 2), (10, 2, 1)]
    assert not out.exists()
    w, start = _write(folder, out, frames)
    assert start == 12 and w.resumed == 12
    assert w.result.n_frames == 23 and w.marked == 12  # even frames 0..22
    assert not folder.exists()
    one = tmp_path / "one.mp4"
    encode_video(one, frames, 25.0, options=LOSSLESS)
    a, fps = read_video(out)
    b, _ = read_video(one)
    assert fps == 25.0 and a.shape == b.shape == (23, 48, 64, 3)
    assert np.array_equal(a, b)


def test_the_joined_video_carries_the_audio(small_parts, tmp_path, data_dir):
    clip = data_dir / "video" / "driving_d9.mp4"
    if not has_audio(clip):
        pytest.skip("the clip has no audio")
    w, _ = _write(tmp_path / "p", tmp_path / "a.mp4", _frames(12), audio_from=clip)
    assert w.result.audio and has_audio(tmp_path / "a.mp4")
    assert stored_frame_count(tmp_path / "a.mp4") == 12


def test_a_frame_cut_short_in_the_pipe_is_dropped(tmp_path):
    """An interrupt in the middle of a frame's bytes: the part keeps the whole frames."""
    frames = _frames(4)
    w = VideoWriter(tmp_path / "p.mov", 25.0, (64, 48), options=LOSSLESS, detached=True)
    for f in frames[:3]:
        w.write(f)
    w._proc.stdin.write(b"\x10" * 1000)  # part of a fourth frame
    done = w.close(prefix=True)
    assert done is not None and done.n_frames == 3 == stored_frame_count(tmp_path / "p.mov")
    assert np.array_equal(read_video(tmp_path / "p.mov")[0], read_video(_one(tmp_path, frames[:3]))[0])


def _one(tmp_path, frames):
    p = tmp_path / "ref.mp4"
    encode_video(p, frames, 25.0, options=LOSSLESS)
    return p


def test_a_detached_ffmpeg_is_out_of_the_terminals_reach(tmp_path):
    w = VideoWriter(tmp_path / "p.mov", 25.0, (64, 48), detached=True)
    try:
        assert os.getsid(w._proc.pid) == w._proc.pid != os.getsid(0)
    finally:
        w.close(commit=False)
    w = VideoWriter(tmp_path / "q.mov", 25.0, (64, 48))
    try:
        assert os.getsid(w._proc.pid) == os.getsid(0)
    finally:
        w.close(commit=False)
    assert not any(tmp_path.iterdir())


def test_a_damaged_part_and_those_after_it_are_dropped(small_parts, tmp_path):
    frames = _frames(17)
    folder = tmp_path / "parts"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, tmp_path / "o.mp4", frames, stop=15)
    assert [p.frames for p in vp.kept_parts(folder)] == [5, 5, 5]
    (folder / "00000005.mov").write_bytes(b"damaged")
    (folder / ".00000015.123-abc.part.mov").write_bytes(b"left by a killed writer")
    kept = vp.kept_parts(folder)
    assert [(p.start, p.frames) for p in kept] == [(0, 5)]
    assert sorted(os.listdir(folder)) == ["00000000.mov", "lock", "parts.json"]
    assert json.loads((folder / "parts.json").read_text())["parts"][0]["frames"] == 5
    w, start = _write(folder, tmp_path / "o.mp4", frames)
    assert start == 5 and np.array_equal(read_video(tmp_path / "o.mp4")[0],
                                         read_video(_one(tmp_path, frames))[0])


def test_parts_of_a_longer_video_are_not_taken_up(small_parts, tmp_path):
    folder = tmp_path / "parts"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, tmp_path / "o.mp4", _frames(20), stop=12)
    w, start = _write(folder, tmp_path / "o.mp4", _frames(8, seed=1))
    assert start == 0 and w.result.n_frames == 8


def test_one_writer_at_a_time(tmp_path):
    folder = tmp_path / "parts"
    w = vp.PartsWriter(folder, tmp_path / "o.mp4", 25.0, (64, 48), n_frames=3)
    try:
        assert vp.folder_in_use(folder)
        with pytest.raises(vp.PartsBusy, match=str(folder)):
            vp.PartsWriter(folder, tmp_path / "o2.mp4", 25.0, (64, 48), n_frames=3)
    finally:
        w.close(commit=False)
    assert not vp.folder_in_use(folder)
    assert not folder.exists()  # interrupted before its first frame: nothing kept


def test_what_cannot_be_written_in_parts(tmp_path):
    with pytest.raises(VideoError, match="image sequence"):
        vp.PartsWriter(tmp_path / "p", tmp_path / "f%03d.png", 25.0, (64, 48), n_frames=3)
    (tmp_path / "o.mp4").write_bytes(b"keep")
    with pytest.raises(ValueError, match="--overwrite"):
        vp.PartsWriter(tmp_path / "p", tmp_path / "o.mp4", 25.0, (64, 48), n_frames=3)
    w = vp.PartsWriter(tmp_path / "p", tmp_path / "x.mp4", 25.0, (64, 48), n_frames=3)
    w.write(_frames(1)[0])
    with pytest.raises(VideoError, match="1 frames were written, not 3"):
        w.close()
    assert (tmp_path / "o.mp4").read_bytes() == b"keep" and not (tmp_path / "x.mp4").exists()


@pytest.mark.parametrize("suffix", [".mp4", ".mov", ".mkv", ".avi"])
def test_every_container_keeps_the_frames_and_their_rate(small_parts, tmp_path, suffix):
    """Parts joined into each container decode to the frames, at the rate written (an AVI
    once reported 600 fps: the parts' time base)."""
    from facetransfer.io.video import video_info

    frames = _frames(12)
    w = vp.PartsWriter(tmp_path / "p", tmp_path / f"o{suffix}", 29.97, (64, 48), n_frames=12,
                       options=LOSSLESS)
    with w:
        for f in frames:
            w.write(f)
    out = tmp_path / f"o{suffix}"
    assert video_info(out).fps == pytest.approx(29.97, abs=0.01)
    assert stored_frame_count(out) == 12
    assert np.array_equal(read_video(out)[0], read_video(_one(tmp_path, frames))[0])


def test_a_part_that_cannot_be_written_says_where_and_the_way_around(tmp_path, monkeypatch):
    from facetransfer.io import video as iov

    def full(self, frame):
        raise VideoError(f"cannot write video {self.path} (ffmpeg exit status 1): No space "
                         "left on device")

    monkeypatch.setattr(iov.VideoWriter, "write", full)
    w = vp.PartsWriter(tmp_path / "p", tmp_path / "o.mp4", 25.0, (64, 48), n_frames=3)
    with pytest.raises(VideoError) as err:
        with w:
            w.write(_frames(1)[0])
    msg = str(err.value)
    assert "00000000.mov" in msg and "No space left on device" in msg
    assert f"a part of {tmp_path / 'o.mp4'} in the render cache" in msg
    assert "FACETRANSFER_RENDER_CACHE=off" in msg and len(msg.splitlines()) == 1
    assert not (tmp_path / "o.mp4").exists()
    assert not (tmp_path / "p").exists()  # no part kept: no folder left


def test_the_joined_video_and_a_video_written_at_once_carry_the_start_timecode(
        small_parts, tmp_path, data_dir):
    """A timecode in the options (a rewritten plate's, :func:`like_video`) is the written
    file's start timecode: joined from parts (each part without one), with the audio muxed
    in, or encoded at once; in MP4, QuickTime and Matroska files (AVI holds none). The
    parts' frames are unchanged by it."""
    from facetransfer.io.video_display import timecode_of

    frames, tc = _frames(12), "01:02:03:04"
    opt = VideoOptions(crf=0, timecode=tc)
    for name in ("j.mp4", "j.mov", "j.mkv", "j.avi"):
        w = vp.PartsWriter(tmp_path / ("p" + name), tmp_path / name, 25.0, (64, 48),
                           n_frames=12, options=opt, overwrite=True)
        write_rest(w, frames)
        assert timecode_of(tmp_path / name) == (None if name.endswith("avi") else tc)
    assert np.array_equal(read_video(tmp_path / "j.mov")[0],
                          read_video(_one(tmp_path, frames))[0])
    clip = data_dir / "video" / "driving_d9.mp4"
    encode_video(tmp_path / "a.mp4", frames, 25.0, options=VideoOptions(timecode="10:00:00:00"),
                 audio_from=clip)
    assert timecode_of(tmp_path / "a.mp4") == "10:00:00:00" and has_audio(tmp_path / "a.mp4")
    assert timecode_of(clip) is None


def test_a_timecode_is_checked_before_it_reaches_ffmpeg():
    from facetransfer.io.video_display import checked_timecode

    for good in ("00:00:00:00", "23:59:59;29", "01:00:00.12"):
        assert checked_timecode(good) == good
    for bad in ("1:00:00:00", "01:00:00:00 -y", "01:61:00:00", 3600, ""):
        with pytest.raises(VideoError, match="timecode"):
            VideoOptions(timecode=bad)


def test_a_rewrite_takes_its_videos_timecode_and_probe_says_it(tmp_path):
    from facetransfer.io.video_facts import fact_lines, video_facts
    from facetransfer.io.video_like import like_video

    plate, plain = tmp_path / "plate.mov", tmp_path / "plain.mov"
    encode_video(plate, _frames(3), 25.0, options=VideoOptions(timecode="01:00:10:05"))
    encode_video(plain, _frames(3), 25.0)
    assert like_video(None, plate).timecode == "01:00:10:05"
    assert like_video(VideoOptions(timecode="02:00:00:00"), plate).timecode == "02:00:00:00"
    assert like_video(None, plain).timecode is None
    assert "; timecode 01:00:10:05 (the results start at it)" in fact_lines(video_facts(plate))[2]
    assert "timecode" not in " ".join(fact_lines(video_facts(plain)))


def test_a_join_that_fails_says_how_ffmpeg_ended(small_parts, tmp_path, monkeypatch):
    """A join stopped by a file size limit (``ulimit -f``: SIGXFSZ, nothing on stderr) said
    only "ffmpeg failed"; now how it ended. The output is left as it was (none)."""
    import signal
    import subprocess

    from facetransfer.io.ffmpeg import exit_cause

    assert exit_cause(1) == "exit status 1"
    if hasattr(signal, "SIGXFSZ"):
        assert exit_cause(-signal.SIGXFSZ) == (f"killed by signal {int(signal.SIGXFSZ)}: file "
                                               "size limit exceeded")
    frames = _frames()
    folder, out = tmp_path / "parts", tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        _write(folder, out, frames, stop=12)
    real = subprocess.run

    def limited(cmd, *a, **k):
        if "concat" in cmd:
            return subprocess.CompletedProcess(cmd, -9, "", "")
        return real(cmd, *a, **k)

    monkeypatch.setattr(vp.subprocess, "run", limited)
    with pytest.raises(VideoError, match=r"cannot join the parts of .*out.mp4 \(ffmpeg killed "
                       r"by signal 9\)$"):
        _write(folder, out, frames)
    assert not out.exists()


def test_two_runs_writing_one_new_video_at_once_the_later_is_refused(small_parts, tmp_path):
    """Both runs checked the output at their start (not there yet); the later one replaced the
    other's video at its end without --overwrite (two puppets to p.mp4: both 'wrote', exit 0).
    Now it is refused, in parts or written at once, and the first run's video stays."""
    out, frames = tmp_path / "p.mp4", _frames(12)
    late = vp.PartsWriter(tmp_path / "c1", out, 25.0, (64, 48), n_frames=12, options=LOSSLESS)
    direct = VideoWriter(out, 25.0, (64, 48), options=LOSSLESS, overwrite=False)
    out.write_bytes(b"the other run's video")                  # finished first
    for f in frames:
        late.write(f)
        direct.write(f)
    with pytest.raises(ValueError, match="p.mp4 exists; pass --overwrite"):
        late.close()
    with pytest.raises(ValueError, match="p.mp4 exists; pass --overwrite"):
        direct.close()
    assert out.read_bytes() == b"the other run's video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c1", "p.mp4"]  # no temporary file


def _counting(monkeypatch) -> list:
    """The names of the files :func:`stored_frame_count` reads (a part's count, the joined
    file's), in order."""
    import facetransfer.io.video as video

    real, names = video.stored_frame_count, []

    def counted(path):
        names.append(os.path.basename(path))
        return real(path)

    monkeypatch.setattr(video, "stored_frame_count", counted)
    monkeypatch.setattr(vp, "stored_frame_count", counted)
    return names


def test_the_last_part_is_counted_in_the_joined_file_not_on_its_own(small_parts, tmp_path,
                                                                    monkeypatch):
    """Each full part is read back as it is finished, the joined file at the join; the last
    part no longer on its own in between (one ffmpeg run in series at the transfer's end):
    the joined file holds the frames listed only if it holds its own."""
    names = _counting(monkeypatch)
    w, _ = _write(tmp_path / "p", tmp_path / "out.mp4", _frames(12))
    assert w.result.n_frames == 12
    parts = [n for n in names if n.endswith(".mov")]
    assert len(parts) == 2 and not any(n.startswith(".00000010.") for n in parts), names
    assert len(names) == 3 and "out" in names[-1]


def test_a_last_part_short_of_its_frames_is_refused_at_the_join(small_parts, tmp_path,
                                                                monkeypatch):
    """A last part that holds fewer frames than were written to it: the joined file is
    refused (not the output), and the next run takes up the parts before it only."""
    real = VideoWriter.write

    def dropping(self, frame):
        if self.n_frames == 1 and self.path.name == "00000010.mov":
            self.n_frames += 1        # said written, never sent to ffmpeg
            return
        real(self, frame)

    folder, out = tmp_path / "p", tmp_path / "out.mp4"
    monkeypatch.setattr(VideoWriter, "write", dropping)
    with pytest.raises(VideoError, match=r"its parts hold 12 frames, the joined file 11"):
        _write(folder, out, _frames(12))
    assert not out.exists()
    assert [(p.start, p.frames) for p in vp.kept_parts(folder)] == [(0, 5), (5, 5)]

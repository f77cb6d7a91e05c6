"""Edit lists other than a phone's one trim (helper review52c): a zero-length edit before the
shown one, and a clip of two pieces joined by reference, read as the frames ffmpeg shows
(BENCHMARKS.md, "Fifty-second session (helper review52c)")."""

from __future__ import annotations

import struct
import subprocess

import numpy as np
import pytest

imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")

FF = imageio_ffmpeg.get_ffmpeg_exe()
W, H, N = 64, 48, 90
_CONTAINERS = {b"moov", b"trak", b"edts", b"mdia"}


def _numbered_clip(path):
    """A 90-frame 30 fps H.264 clip with B-frames and a keyframe every 30 frames, frame k's
    left half at level (k % 16) * 16 + 8 and its right half at (k // 16) * 16 + 8."""
    frames = np.zeros((N, H, W, 3), np.uint8)
    for k in range(N):
        frames[k, :, :W // 2] = (k % 16) * 16 + 8
        frames[k, :, W // 2:] = (k // 16) * 16 + 8
    subprocess.run([FF, "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo",
                    "-pix_fmt", "rgb24", "-s", f"{W}x{H}", "-r", "30", "-i", "-", "-c:v",
                    "libx264", "-crf", "10", "-g", "30", "-bf", "3", "-pix_fmt", "yuv420p",
                    str(path)], input=frames.tobytes(), check=True)


def _numbers(frames) -> list[int]:
    """Each frame's number, as :func:`_numbered_clip` wrote it."""
    left = frames[:, 8:-8, 4:W // 2 - 4].reshape(len(frames), -1).mean(1)
    right = frames[:, 8:-8, W // 2 + 4:-4].reshape(len(frames), -1).mean(1)
    return [int(a + 16 * b) for a, b in zip(np.rint((left - 8) / 16), np.rint((right - 8) / 16))]


def _boxes(data: bytes) -> list:
    out, at = [], 0
    while at + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[at:at + 8])
        payload = data[at + 8:at + size]
        out.append([kind, _boxes(payload) if kind in _CONTAINERS else payload])
        at += size
    return out


def _bytes(boxes) -> bytes:
    out = b""
    for kind, payload in boxes:
        body = _bytes(payload) if isinstance(payload, list) else payload
        out += struct.pack(">I4s", len(body) + 8, kind) + body
    return out


def _with_edits(src, dst, edits):
    """``src`` (an MP4 of one video track, its index after its media) written to ``dst`` with
    the edit list ``edits``: ``(seconds shown, first frame shown)`` each."""
    top = _boxes(src.read_bytes())
    moov = next(p for k, p in top if k == b"moov")
    mvhd = next(p for k, p in moov if k == b"mvhd")
    trak = next(p for k, p in moov if k == b"trak")
    mdia = next(p for k, p in trak if k == b"mdia")
    mdhd = next(p for k, p in mdia if k == b"mdhd")
    movie_scale, media_scale = struct.unpack(">I", mvhd[12:16])[0], struct.unpack(
        ">I", mdhd[12:16])[0]
    edts = next(p for k, p in trak if k == b"edts")
    first = struct.unpack(">i", next(p for k, p in edts if k == b"elst")[12:16])[0]  # B-frames
    entries = b"".join(struct.pack(">Iihh", round(s * movie_scale),
                                   first + round(k * media_scale / 30), 1, 0) for s, k in edits)
    edts[:] = [[b"elst", struct.pack(">II", 0, len(edits)) + entries]]
    dst.write_bytes(_bytes(top))


def _shown(path) -> np.ndarray:
    raw = subprocess.run([FF, "-v", "error", "-i", str(path), "-map", "0:v:0", "-fps_mode",
                          "passthrough", "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                         capture_output=True, check=True).stdout
    return np.frombuffer(raw, np.uint8).reshape(-1, H, W, 3)


@pytest.mark.parametrize("edits, numbers", [
    ([(0.0, 0), (2.0, 10)], list(range(10, 70))),                    # a zero-length edit first
    ([(1.0, 5), (1.0, 50)], list(range(5, 35)) + list(range(50, 80))),   # two pieces
])
def test_a_clip_edited_by_reference_reads_as_the_frames_ffmpeg_shows(tmp_path, edits, numbers,
                                                                     caplog):
    """The count, the frames and a read from the middle are ffmpeg's. Before: the zero-length
    edit's clip counted 30 frames for the 60 shown, and the two pieces' 43 (each 'the clip'
    for every command), from OpenCV's count less the packets hidden."""
    from facetransfer.io.video_read import iter_frames, read_video, video_info
    whole, cut = tmp_path / "whole.mp4", tmp_path / "cut.mp4"
    _numbered_clip(whole)
    _with_edits(whole, cut, edits)
    assert _numbers(_shown(cut)) == numbers             # what a player shows
    info = video_info(cut)
    assert info.n_frames == len(numbers) and info.steps is None
    frames, _ = read_video(cut)
    assert _numbers(frames) == numbers
    assert _numbers(np.stack(list(iter_frames(cut, start=40, stop=45)))) == numbers[40:45]
    assert _numbers(read_video(cut, start=33, max_frames=4)[0]) == numbers[33:37]
    assert "truncated" not in caplog.text and "variable frame rate" not in caplog.text


@pytest.mark.parametrize("edits", [[(1.0, 200)], [(0.0, 10)]])
def test_an_edit_list_past_the_media_is_refused_saying_so(tmp_path, edits):
    """An edit list showing media past the last frame (or for no time) shows no picture:
    refused in words that say so (before: 'no frame from frame 0 on decodes, though its header
    counts 90 (damaged, or cut short)', after the count and probe had said 90 frames)."""
    from facetransfer.errors import VideoError
    from facetransfer.io.video_read import video_info
    whole, cut = tmp_path / "whole.mp4", tmp_path / "past.mp4"
    _numbered_clip(whole)
    _with_edits(whole, cut, edits)
    assert len(_shown(cut)) == 0
    with pytest.raises(VideoError, match="shows none of the frames it stores: its edit list shows no time"):
        video_info(cut)


def test_a_trimmed_clip_cut_short_is_said_to_be(tmp_path):
    """A trimmed clip (its index first) cut short: its trim's count, and the packets there
    fewer (probe's 'cut short?'), not a clip of variable rate of the packets left."""
    from facetransfer.io.video_facts import video_facts
    whole, trim, cut = tmp_path / "whole.mp4", tmp_path / "trim.mp4", tmp_path / "cut.mp4"
    _numbered_clip(whole)
    subprocess.run([FF, "-v", "error", "-y", "-ss", "1.03", "-i", str(whole), "-c", "copy",
                    "-movflags", "+faststart", str(trim)], check=True)
    data = trim.read_bytes()
    cut.write_bytes(data[:len(data) * 2 // 3])
    facts = video_facts(cut)
    assert facts.n_frames == 59 and facts.stored_frames < 50 and not facts.variable_rate

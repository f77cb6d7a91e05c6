"""The one video writer (facetransfer.io.video): codecs, CRF, image sequences, audio, failures."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facetransfer.errors import VideoError
from facetransfer.io import video as iov
from facetransfer.io.video_like import like_video
from facetransfer.io.video import (VideoOptions, VideoWriter, check_video_output,
                                   decoded_frame_count, encode_video, has_audio, read_video,
                                   video_info)

SRC = Path(__file__).resolve().parents[1] / "src"


def stream_info(path) -> str:
    """ffmpeg's description of the first video stream ("Video: h264 (High) ..., yuv420p...")."""
    res = subprocess.run([iov.ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                         capture_output=True, text=True)
    return next(ln for ln in res.stderr.splitlines() if "Video:" in ln)


def psnr(a, b) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0 ** 2 / mse))


def smooth_frames(n=8, h=64, w=96, seed=0) -> np.ndarray:
    """Moving colour gradients with a little grey texture: (n, h, w, 3) uint8."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    tex = rng.normal(0, 4, (h, w))
    out = []
    for i in range(n):
        r = 128 + 60 * np.sin((x + 3 * i) / 17.0)
        g = 128 + 50 * np.cos((y - 2 * i) / 13.0)
        b = 100 + 0.8 * x
        out.append(np.stack([r, g, b], -1) + tex[..., None])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def noisy_frames(n=6, h=64, w=64, seed=1) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, h, w, 3), dtype=np.uint8)


def test_h264_by_default_yuv420p_crf18_and_decodes(tmp_path):
    frames = smooth_frames()
    res = encode_video(tmp_path / "v.mp4", frames, 25)
    assert res.n_frames == 8 and res.size == (96, 64) and not res.audio
    info = stream_info(res.path)
    assert "h264" in info and "yuv420p" in info
    back, fps = read_video(res.path)
    assert back.shape == frames.shape and fps == pytest.approx(25)
    # measured on this content: 37.5 dB (CRF 0: 43.5 dB, the ceiling of 8-bit 4:2:0 as OpenCV
    # decodes it); the old writer, OpenCV's mp4v: 34.8 dB
    assert psnr(back, frames) > 36.5
    import cv2

    peer = cv2.VideoWriter(str(tmp_path / "mp4v.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 25,
                           (96, 64))
    for f in frames:
        peer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    peer.release()
    assert psnr(back, frames) > psnr(read_video(tmp_path / "mp4v.mp4")[0], frames) + 2
    # the encoder's settings are recorded in the stream by x264
    assert b"crf=18.0" in res.path.read_bytes()


def test_frames_reach_ffmpeg_as_its_own_yuv420p_conversion():
    """The writer pipes 4:2:0 planes made by OpenCV: the same BT.601 limited-range matrix as
    ffmpeg's own ``rgb24`` -> ``yuv420p`` (Y to 1 level), chroma of each 2x2 block's mean."""
    frames = np.concatenate([smooth_frames(n=1), noisy_frames(n=1, h=64, w=96)])
    for f in frames:
        res = subprocess.run([iov.ffmpeg_exe(), "-loglevel", "error", "-f", "rawvideo",
                              "-pix_fmt", "rgb24", "-s", "96x64", "-i", "-", "-f", "rawvideo",
                              "-pix_fmt", "yuv420p", "-"], input=f.tobytes(),
                             capture_output=True, check=True)
        theirs = np.frombuffer(res.stdout, np.uint8).astype(int)
        ours = iov._yuv420p(f).ravel().astype(int)
        assert ours.shape == theirs.shape == (96 * 64 * 3 // 2,)
        n = 96 * 64
        assert np.abs(ours[:n] - theirs[:n]).max() <= 1
        rgb = f.astype(np.float64)
        luma = 16 + (65.481 * rgb[..., 0] + 128.553 * rgb[..., 1] + 24.966 * rgb[..., 2]) / 255
        assert np.abs(ours[:n].reshape(64, 96) - luma).max() <= 1   # BT.601, limited range
        cb = 128 + (-37.797 * rgb[..., 0] - 74.203 * rgb[..., 1] + 112.0 * rgb[..., 2]) / 255
        cr = 128 + (112.0 * rgb[..., 0] - 93.786 * rgb[..., 1] - 18.214 * rgb[..., 2]) / 255
        for plane, ref in ((ours[n:n + n // 4], cb), (ours[n + n // 4:], cr)):
            ref = ref.reshape(32, 2, 48, 2).mean(axis=(1, 3))
            assert np.abs(plane.reshape(32, 48) - ref).max() <= 1


def test_odd_size_is_padded_to_even_by_repeating_edges(tmp_path):
    frames = smooth_frames(n=4, h=33, w=47)
    res = encode_video(tmp_path / "odd.mp4", frames, 10)
    assert res.size == (48, 34)
    back, _ = read_video(res.path)
    assert back.shape == (4, 34, 48, 3)
    assert psnr(back[:, :33, :47], frames) > 35.5   # measured 36.9 dB
    # the added row and column repeat the last ones (up to coding)
    assert np.abs(back[:, 33].astype(int) - back[:, 32].astype(int)).mean() < 3


def test_an_odd_size_grown_is_said_once_naming_the_output(tmp_path, caplog):
    """A compositor laying the result over the plate must know it is a pixel larger: one
    warning naming the output (not a part file), none for an even size."""
    from facetransfer.io.video_parts import PartsWriter

    frames = smooth_frames(n=3, h=33, w=47)
    out = tmp_path / "res.mp4"
    with caplog.at_level(logging.WARNING, logger="facetransfer.io"):
        w = PartsWriter(tmp_path / "parts", out, 10, (47, 33), n_frames=3)
        for f in frames:
            w.write(f)
        w.close()
        encode_video(tmp_path / "even.mp4", smooth_frames(n=2, h=34, w=48), 10)
    said = [r.getMessage() for r in caplog.records if "odd size" in r.getMessage()]
    assert said == [f"{out}: the frames' odd size 47x33 is stored as 48x34, the edge repeated "
                    "(4:2:0 holds even sizes only); an image sequence keeps 47x33"]
    assert read_video(out)[0].shape == (3, 34, 48, 3)


@pytest.mark.parametrize("codec,suffix,name,db", [("h265", ".mkv", "hevc", 37.0),
                                                  ("prores", ".mov", "prores", 43.0)])
def test_other_codecs(tmp_path, codec, suffix, name, db):
    frames = smooth_frames(n=5)
    res = encode_video(tmp_path / f"v{suffix}", frames, 30, options=VideoOptions(codec))
    assert name in stream_info(res.path)
    assert decoded_frame_count(res.path) == 5
    back, _ = read_video(res.path)
    # measured: H.265 CRF 18 38.4 dB, ProRes 422 HQ 44.4 dB
    assert back.shape == frames.shape and psnr(back, frames) > db


def test_lower_crf_is_bigger_and_closer(tmp_path):
    frames = noisy_frames()
    out = {}
    for crf in (8, 18, 30):
        p = encode_video(tmp_path / f"c{crf}.mp4", frames, 25, options=VideoOptions(crf=crf)).path
        out[crf] = (p.stat().st_size, psnr(read_video(p)[0], frames))
    assert out[8][0] > out[18][0] > out[30][0]
    assert out[8][1] > out[18][1] > out[30][1]


def test_image_sequence_lossless_and_replaced_only_with_overwrite(tmp_path):
    frames = noisy_frames(n=5)
    pattern = tmp_path / "frames" / "%05d.png"
    res = encode_video(pattern, frames, 25)
    assert res.kind == "images" and res.n_frames == 5
    names = sorted(p.name for p in pattern.parent.iterdir())
    assert names == [f"{i:05d}.png" for i in range(5)]           # frame 0 is 00000.png
    from PIL import Image

    np.testing.assert_array_equal(np.asarray(Image.open(pattern.parent / "00003.png")),
                                  frames[3])
    with pytest.raises(VideoError, match="--overwrite"):
        encode_video(pattern, frames[:2], 25, overwrite=False)
    (pattern.parent / "notes.txt").write_text("mine")
    encode_video(pattern, frames[:2], 25, overwrite=True)          # a shorter sequence
    left = sorted(p.name for p in pattern.parent.iterdir())
    assert left == ["00000.png", "00001.png", "notes.txt"]         # old 2..4 gone, others kept


def test_audio_of_another_file_is_muxed_and_cut(tmp_path):
    # a 2-second tone as the audio source
    tone = tmp_path / "tone.m4a"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "sine=frequency=440:duration=2", "-c:a", "aac", str(tone)], check=True)
    res = encode_video(tmp_path / "a.mp4", smooth_frames(n=10), 10, audio_from=tone)
    assert res.audio and has_audio(res.path)
    assert decoded_frame_count(res.path) == 10
    out = subprocess.run([iov.ffmpeg_exe(), "-hide_banner", "-i", str(res.path)],
                         capture_output=True, text=True).stderr
    h, m, s = re.search(r"Duration: (\d+):(\d+):([\d.]+)", out).groups()
    assert float(s) == pytest.approx(1.0, abs=0.1)    # 10 frames at 10 fps, not the tone's 2 s
    mute = encode_video(tmp_path / "mute.mp4", smooth_frames(n=2), 10).path
    res2 = encode_video(tmp_path / "c.mp4", smooth_frames(n=3), 10, audio_from=mute)
    assert not res2.audio and not has_audio(res2.path)  # no audio to keep: none, no error


@pytest.mark.parametrize("out,match", [
    ("x.png", "frame number"),                     # issue 16: MPEG-4 written into a .png
    ("x.txt", "neither a video"),
    ("x", "neither a video"),
    ("frames/%s.png", "%05d"),
    ("frames/%05d_%d.png", "%05d"),
    ("frames/%05d.txt", "image extension"),
])
def test_bad_outputs(tmp_path, out, match):
    with pytest.raises(VideoError, match=match):
        check_video_output(tmp_path / out)


def test_a_video_named_with_a_percent_sign_is_a_video(tmp_path):
    """``take 100% final.mp4`` is a video (before: taken for a frame pattern and refused,
    "a frame pattern needs an image extension"); written and read back under its name. An
    image's name with a ``%`` but no field is still asked for one; ``%d`` in a video's name is
    still a pattern without an image extension."""
    out = tmp_path / "take 100% final.mp4"
    assert check_video_output(out).kind == "video"
    encode_video(out, smooth_frames(n=3), 25)
    assert decoded_frame_count(out) == 3
    with pytest.raises(VideoError, match="exactly one frame number field"):
        check_video_output(tmp_path / "fr 5%.png")
    with pytest.raises(VideoError, match="needs an image extension"):
        check_video_output(tmp_path / "shot_%03d.mp4")
    assert check_video_output(tmp_path / "f_%03d.png").kind == "images"


def test_preset_reaches_x264(tmp_path):
    # x264 writes its settings into the stream: subme 7 is medium's, 4 faster's (the
    # default), 2 veryfast's
    fast = encode_video(tmp_path / "f.mp4", smooth_frames(n=3), 25,
                        options=VideoOptions(preset="veryfast")).path
    assert b"subme=2 " in fast.read_bytes()
    slow = encode_video(tmp_path / "m.mp4", smooth_frames(n=3), 25,
                        options=VideoOptions(preset="medium")).path
    assert b"subme=7 " in slow.read_bytes()
    default = encode_video(tmp_path / "d.mp4", smooth_frames(n=3), 25).path
    assert b"subme=4 " in default.read_bytes()


def test_default_preset_is_written_without_b8x8_partitions(tmp_path):
    """The default preset is x264's "faster" with B-frames' 8x8 partitions not searched
    (:data:`DEFAULT_X264_PARAMS`: 11-18 % less of the encoder's CPU for the same quality,
    measured in BENCHMARKS.md), as the stream's own settings say (``analyse``: the I and the
    P/B partitions, 0x100 the B-frames' 8x8); any other preset is x264's own, b8x8 kept, and
    H.265 gets no x264 settings."""
    assert iov.DEFAULT_X264_PARAMS == "partitions=i4x4,i8x8,p8x8"
    args = iov._encode_args(VideoOptions(), ".mp4")
    assert args[args.index("-x264-params") + 1] == iov.DEFAULT_X264_PARAMS
    assert args[args.index("-preset") + 1] == "faster"
    default = encode_video(tmp_path / "d.mp4", smooth_frames(n=3), 25).path.read_bytes()
    assert b"analyse=0x3:0x13 " in default and b"subme=4 " in default
    for preset in ("medium", "veryfast"):
        opt = VideoOptions(preset=preset)
        assert "-x264-params" not in iov._encode_args(opt, ".mp4")
        data = encode_video(tmp_path / f"{preset}.mp4", smooth_frames(n=3), 25,
                            options=opt).path.read_bytes()
        assert b"analyse=0x3:0x113 " in data
    assert "-x264-params" not in iov._encode_args(VideoOptions(codec="h265"), ".mp4")


@pytest.mark.parametrize("kw,match", [({"crf": 52}, "0 to 51"), ({"crf": -1}, "0 to 51"),
                                      ({"preset": "warp"}, "preset must be one of"),
                                      ({"crf": 2.5}, "integer"), ({"codec": "vp9"}, "h264"),
                                      ({"codec": "prores", "crf": 10}, "prores"),
                                      ({"sar": (0, 1)}, "pixel aspect"),
                                      ({"sar": (1.5, 2)}, "pixel aspect"),
                                      ({"sar": (1, 2, 3)}, "pixel aspect"),
                                      ({"sar": (70000, 1)}, "pixel aspect"),
                                      ({"primaries": "bt709,x"}, "colour name"),
                                      ({"transfer": 709}, "colour name")])
def test_bad_options(kw, match):
    with pytest.raises(VideoError, match=match):
        VideoOptions(**kw)


def test_prores_needs_mov_and_missing_encoder_is_named(tmp_path, monkeypatch):
    with pytest.raises(VideoError, match=r"\.mov"):
        check_video_output(tmp_path / "p.mp4", VideoOptions("prores"))
    monkeypatch.setattr(iov, "ffmpeg_encoders", lambda exe: frozenset({"libx264"}))
    with pytest.raises(VideoError, match="lacks the libx265 encoder"):
        check_video_output(tmp_path / "v.mp4", VideoOptions("h265"))
    check_video_output(tmp_path / "v.mp4")  # h264 is there


def test_writer_refuses_wrong_frames_and_leaves_nothing(tmp_path):
    with pytest.raises(VideoError, match="does not match"):
        with VideoWriter(tmp_path / "v.mp4", 25, (64, 48)) as w:
            w.write(np.zeros((48, 64, 3), np.uint8))
            w.write(np.zeros((40, 64, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(VideoError, match="no frames"):
        encode_video(tmp_path / "v.mp4", [], 25)
    assert list(tmp_path.iterdir()) == []


_FULL_DISK = r"""
import resource, sys
import numpy as np
from facetransfer.io.video import encode_video
frames = np.random.default_rng(0).integers(0, 256, (30, 96, 128, 3), dtype=np.uint8)
resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))   # the disk "fills" at 20 kB
try:
    encode_video(sys.argv[1], frames, 25, overwrite=True)
except ValueError as exc:
    print(type(exc).__name__, exc)
    sys.exit(2)
"""


def test_full_disk_fails_and_keeps_the_old_video(tmp_path):
    """Issue 16, defect 1: a write that runs out of space raises, and with overwrite the old
    file survives unchanged; no temporary file is left."""
    out = tmp_path / "v.mp4"
    encode_video(out, smooth_frames(n=3), 25)
    before = out.read_bytes()
    r = subprocess.run([sys.executable, "-c", _FULL_DISK, str(out)], capture_output=True,
                       text=True, env={**os.environ, "PYTHONPATH": str(SRC)})
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stdout.startswith("VideoError cannot write video") and str(out) in r.stdout
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_full_disk_on_a_real_small_filesystem(tmp_path):
    """The same on a 64 kB tmpfs (ENOSPC), where the system allows mounting one."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        out = mnt / "v.mp4"
        encode_video(out, smooth_frames(n=2, h=32, w=32), 25)
        before = out.read_bytes()
        with pytest.raises(VideoError, match="No space left"):
            encode_video(out, noisy_frames(n=20, h=128, w=128), 25, overwrite=True)
        assert out.read_bytes() == before
        with pytest.raises(VideoError, match="No space left"):
            encode_video(mnt / "f" / "%03d.png", noisy_frames(n=20, h=128, w=128), 25)
        assert sorted(p.name for p in mnt.iterdir()) == ["f", "v.mp4"]
        assert list((mnt / "f").iterdir()) == []
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_short_output_is_refused(tmp_path, monkeypatch):
    """If the file ffmpeg wrote holds fewer frames than were sent, nothing is written."""
    out = tmp_path / "v.mp4"
    encode_video(out, smooth_frames(n=2), 25)
    before = out.read_bytes()
    monkeypatch.setattr(iov, "stored_frame_count", lambda path: 1)
    with pytest.raises(VideoError, match="holds 1"):
        encode_video(out, smooth_frames(n=4), 25, overwrite=True)
    assert out.read_bytes() == before and sorted(os.listdir(tmp_path)) == ["v.mp4"]


def _tone(tmp_path):
    tone = tmp_path / "tone.m4a"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "sine=frequency=440:duration=2", "-c:a", "aac", str(tone)], check=True)
    return tone


@pytest.mark.parametrize("known,short,match", [
    (True, "encoded", "4 frames were written but the file holds 1"),
    (False, "encoded", "4 frames were written but the file holds 1"),
    (False, "muxed", "with the audio of .* it holds 1 frames, not 4")])
def test_short_output_with_audio_is_refused(tmp_path, monkeypatch, known, short, match):
    """With audio, the file with the audio is counted; when it is short, the message says
    which step lost frames (the encode or a second pass's mux), and nothing is written. With
    the number of frames ``known``, the audio is encoded in the same pass (no mux file)."""
    tone = _tone(tmp_path)
    out = tmp_path / "v.mp4"
    real = iov.stored_frame_count

    def count(path):
        muxed = ".audio.part" in Path(path).name
        return 1 if muxed or short == "encoded" else real(path)

    monkeypatch.setattr(iov, "stored_frame_count", count)
    frames = smooth_frames(n=4)
    with pytest.raises(VideoError, match=match):
        encode_video(out, frames if known else iter(frames), 10, audio_from=tone)
    assert not out.exists() and sorted(os.listdir(tmp_path)) == ["tone.m4a"]


@pytest.mark.parametrize("n_frames,passes", [(4, 1), (None, 2), (6, 2)])
def test_audio_in_one_pass_when_the_frames_are_known(tmp_path, monkeypatch, n_frames, passes):
    """With the frames known beforehand the audio is encoded with them (one ffmpeg run, the
    file counted once); unknown, or promised wrong (6 for 4), it is muxed in a second run.
    Either way the file has 4 frames and 0.4 s of audio (the tone lasts 2 s)."""
    tone = _tone(tmp_path)
    real, calls = iov.stored_frame_count, []
    monkeypatch.setattr(iov, "stored_frame_count", lambda p: calls.append(p) or real(p))
    runs = []
    real_mux = iov.mux_audio
    monkeypatch.setattr(iov, "mux_audio", lambda *a, **k: runs.append(a) or real_mux(*a, **k))
    res = encode_video(tmp_path / "v.mp4", iter(smooth_frames(n=4)), 10, audio_from=tone,
                       n_frames=n_frames)
    assert res.audio and len(calls) == 1 and 1 + len(runs) == passes
    assert (".audio.part" in Path(calls[0]).name) == (passes == 2)
    assert decoded_frame_count(res.path) == 4
    out = subprocess.run([iov.ffmpeg_exe(), "-hide_banner", "-i", str(res.path)],
                         capture_output=True, text=True).stderr
    assert "Audio: aac" in out
    h, m, s = re.search(r"Duration: (\d+):(\d+):([\d.]+)", out).groups()
    assert float(s) == pytest.approx(0.4, abs=0.05)


def test_stored_frame_count_agrees_with_decoding(tmp_path):
    p = encode_video(tmp_path / "v.mp4", smooth_frames(n=7), 25).path
    assert iov.stored_frame_count(p) == decoded_frame_count(p) == 7
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    with pytest.raises(VideoError, match="bad.mp4"):
        iov.stored_frame_count(bad)


def test_video_info_of_written_video(tmp_path):
    p = encode_video(tmp_path / "v.mov", smooth_frames(n=6), 29.97).path
    info = video_info(p)
    assert info.n_frames == 6 and info.fps == pytest.approx(29.97, abs=1e-3)


#: every codec, in a container that holds it
EVERY_CODEC = pytest.mark.parametrize("codec,suffix", [("h264", ".mp4"), ("h265", ".mkv"),
                                                       ("prores", ".mov")])


def _plain_and_with(tmp_path, codec: str, suffix: str, **option) -> tuple[Path, Path]:
    """The same frames written with ``VideoOptions(codec)`` and with ``option`` too (the test
    skipped where this ffmpeg has no encoder of ``codec``)."""
    if iov.CODECS[codec] not in iov.ffmpeg_encoders(iov.ffmpeg_exe()):
        pytest.skip(f"this ffmpeg has no {codec} encoder")
    frames = smooth_frames(n=3)
    return tuple(encode_video(tmp_path / f"{name}{suffix}", frames, 25,
                              options=VideoOptions(codec=codec, **kw)).path
                 for name, kw in (("plain", {}), ("with", option)))


@EVERY_CODEC
def test_pixel_aspect_ratio_is_written_and_read_back(tmp_path, codec, suffix):
    """A 15:16 pixel aspect (a 96x64 video shown 90x64) reaches the file's header and
    OpenCV reads it back; the pixels are those written without it."""
    plain, wide = _plain_and_with(tmp_path, codec, suffix, sar=(30, 32))
    assert VideoOptions(sar=(30, 32)).sar == (15, 16)  # in lowest terms
    assert video_info(wide).sar == (15, 16) and video_info(plain).sar == (1, 1)
    assert "SAR 15:16" in stream_info(wide)
    np.testing.assert_array_equal(read_video(wide)[0], read_video(plain)[0])


def test_a_plate_with_alpha_is_said_to_lose_it(tmp_path, caplog):
    """A ProRes 4444 video with alpha and an RGBA PNG sequence: one warning each that the
    result carries no alpha (before: dropped without a word); none for opaque ones, nor for
    the PNG plate written as a PNG sequence (which keeps it: tests/test_plate_alpha.py)."""
    import cv2

    alpha = tmp_path / "a.mov"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "testsrc=size=64x48:rate=10:duration=0.3", "-c:v", "prores_ks",
                    "-profile:v", "4", "-pix_fmt", "yuva444p10le", str(alpha)], check=True)
    opaque = encode_video(tmp_path / "o.mp4", smooth_frames(n=2), 10).path
    plate = tmp_path / "plate"
    plate.mkdir()
    for k in (1001, 1002):
        cv2.imwrite(str(plate / f"p.{k}.png"), np.full((8, 8, 4), 128, np.uint8))
        cv2.imwrite(str(plate / f"q.{k}.png"), np.full((8, 8, 3), 128, np.uint8))
    with caplog.at_level(logging.WARNING, logger="facetransfer.io"):
        for v in (plate / "p.%04d.png", plate / "q.%04d.png"):
            like_video(None, v, tmp_path / "r.%04d.png")  # a PNG plate's alpha: kept
        assert not [r for r in caplog.records if "has an alpha" in r.getMessage()]
        for v in (alpha, opaque, plate / "p.%04d.png", plate / "q.%04d.png"):
            like_video(None, v)
    said = [r.getMessage() for r in caplog.records if "has an alpha" in r.getMessage()]
    why = "has an alpha channel; the result is written without one (colour only; transfer keeps "
    assert said == [f"{alpha} {why}a video's in ProRes 4444, --codec prores, and in PNG, TIFF "
                    "or DPX sequences)",
                    f"{plate / 'p.%04d.png'} {why}a plate's in a PNG, TIFF or DPX sequence, not "
                    "in a video)"]


def test_like_video_takes_the_inputs_aspect_unless_given(tmp_path):
    src = encode_video(tmp_path / "src.mp4", smooth_frames(n=2), 25,
                       options=VideoOptions(sar=(8, 9))).path
    square = encode_video(tmp_path / "sq.mp4", smooth_frames(n=2), 25).path
    assert like_video(None, src) == VideoOptions(sar=(8, 9))
    assert like_video(VideoOptions(crf=20), src) == VideoOptions(crf=20, sar=(8, 9))
    assert like_video(VideoOptions(sar=(4, 3)), src).sar == (4, 3)  # given: kept
    assert like_video(None, square) == VideoOptions()
    assert like_video(None, None) == VideoOptions()
    still = tmp_path / "still.png"
    still.write_bytes(b"not a video")
    assert like_video(None, still) == VideoOptions()


@EVERY_CODEC
def test_colour_matrix_named_in_the_header_unless_the_input_names_none(tmp_path, codec,
                                                                       suffix):
    """Every video names the BT.601 matrix and limited range its frames were converted with;
    a video rewriting one whose header names no matrix names none either (a player guesses
    alike for both); OpenCV reads either back to the same pixels."""
    tagged, plain = _plain_and_with(tmp_path, codec, suffix, colour_tags=False)
    assert iov.colour_matrix(tagged) == "smpte170m" and "(tv, smpte170m" in stream_info(tagged)
    assert iov.colour_matrix(plain) is None
    np.testing.assert_array_equal(read_video(tagged)[0], read_video(plain)[0])
    assert like_video(None, tagged).colour_tags
    assert not like_video(None, plain).colour_tags
    assert not like_video(VideoOptions(codec=codec), plain).colour_tags


@EVERY_CODEC
def test_primaries_and_transfer_named_as_given(tmp_path, codec, suffix):
    """The primaries and transfer of the video a result rewrites reach the header beside the
    BT.601 matrix (ffmpeg takes them from the frames: set by a filter, not its output options);
    the pixels are those written without them."""
    from facetransfer.io.video_display import ColourTags

    plain, named = _plain_and_with(tmp_path, codec, suffix, primaries="bt709", transfer="bt709")
    assert iov.video_colour(named) == ColourTags("smpte170m", "bt709", "bt709")
    assert iov.video_colour(plain) == ColourTags("smpte170m", None, None)
    np.testing.assert_array_equal(read_video(named)[0], read_video(plain)[0])


def test_like_video_takes_an_sdr_inputs_colour_and_warns_of_hdr_once(tmp_path, caplog):
    sdr = encode_video(tmp_path / "sdr.mp4", smooth_frames(n=2), 25,
                       options=VideoOptions(primaries="bt709", transfer="bt709")).path
    opt = like_video(None, sdr)
    assert (opt.colour_tags, opt.primaries, opt.transfer) == (True, "bt709", "bt709")
    given = like_video(VideoOptions(primaries="smpte170m"), sdr)     # given: kept
    assert (given.primaries, given.transfer) == ("smpte170m", None)
    hlg = encode_video(tmp_path / "hlg.mp4", smooth_frames(n=2), 25,
                       options=VideoOptions(primaries="bt2020", transfer="arib-std-b67")).path
    with caplog.at_level("WARNING"):
        for _ in range(2):
            opt = like_video(None, hlg)
    assert (opt.primaries, opt.transfer) == (None, None)   # written as what it is read as
    assert caplog.text.count("is HDR or wide-gamut video") == 1
    assert "transfer arib-std-b67" in caplog.text


def test_opencv_decodes_by_the_named_matrix(tmp_path):
    """Why the tags matter: the same YCbCr planes named BT.709 decode to other RGB than
    unnamed ones (OpenCV: BT.601), by the matrices' difference on a saturated red."""
    frames = np.zeros((2, 32, 32, 3), np.uint8)
    frames[..., 0] = 220
    base = encode_video(tmp_path / "a.mp4", frames, 25,
                        options=VideoOptions(crf=0, colour_tags=False)).path
    named = tmp_path / "b.mp4"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-i", str(base), "-c", "copy",
                    "-bsf:v", "h264_metadata=matrix_coefficients=1", str(named)], check=True)
    assert iov.colour_matrix(named) == "bt709" and iov.colour_matrix(base) is None
    a, b = read_video(base)[0][0, 16, 16].astype(int), read_video(named)[0][0, 16, 16].astype(int)
    assert abs(a[0] - 220) <= 2 and abs(a[1]) <= 2  # BT.601 both ways
    assert abs(b[0] - a[0]) >= 15  # the same planes as BT.709: another red


@pytest.mark.parametrize("num,den,want", [(15, 16, (15, 16)), (30.0, 32.0, (15, 16)),
                                          (0, 1, (1, 1)), (1, 0, (1, 1)), (-4, 3, (1, 1)),
                                          (float("nan"), 1, (1, 1)), (1.5, 1, (1, 1))])
def test_pixel_aspect_of_what_a_container_reports(num, den, want):
    assert iov.pixel_aspect(num, den) == want


def test_what_is_read_of_a_video_follows_the_file(tmp_path):
    """video_info and ffmpeg's description are kept per file (its stamp): the same path
    written again is read again."""
    p = tmp_path / "v.mp4"
    encode_video(p, smooth_frames(n=6), 25)
    assert video_info(p).n_frames == 6 and iov.colour_matrix(p) == "smpte170m"
    assert video_info(p) is not video_info(p) and video_info(p) == video_info(str(p))
    encode_video(p, smooth_frames(n=9), 30, options=VideoOptions(colour_tags=False),
                 overwrite=True)
    info = video_info(p)
    assert info.n_frames == 9 and info.fps == pytest.approx(30)
    assert iov.colour_matrix(p) is None


def test_output_that_is_the_audio_input_is_refused(tmp_path):
    p = encode_video(tmp_path / "v.mp4", smooth_frames(n=2), 25).path
    before = p.read_bytes()
    with pytest.raises(VideoError, match="also the audio input"):
        encode_video(p, smooth_frames(n=3), 25, audio_from=p, overwrite=True)
    assert p.read_bytes() == before


def _audio_packets(path) -> list[str]:
    """The MD5 of each audio packet of ``path`` as stored (stream copy, no decoding)."""
    out = subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-i", str(path), "-map", "0:a:0",
                          "-c", "copy", "-f", "framemd5", "-"], capture_output=True, text=True,
                         check=True).stdout
    return [line.rsplit(",", 1)[1].strip() for line in out.splitlines()
            if line and not line.startswith("#")]


@pytest.mark.parametrize("n_frames", [4, None])
def test_aac_audio_is_copied_not_encoded_again(tmp_path, n_frames):
    """AAC audio goes into an MP4 as it is stored (no second lossy generation): the output's
    audio packets are the source's first ones, byte for byte, in one pass or muxed after."""
    tone = _tone(tmp_path)
    assert iov.audio_codec(tone) == "aac"
    res = encode_video(tmp_path / "v.mp4", iter(smooth_frames(n=4)), 10, audio_from=tone,
                       n_frames=n_frames)
    ours, theirs = _audio_packets(res.path), _audio_packets(tone)
    assert res.audio and 15 <= len(ours) < len(theirs)    # 0.4 s of 2 s: ~19 of ~95 packets
    assert ours == theirs[:len(ours)]


def test_audio_of_another_codec_is_encoded_to_aac(tmp_path):
    """Audio an MP4 does not take as it is (PCM from a WAV) is encoded to AAC."""
    wav = tmp_path / "tone.wav"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "sine=frequency=440:duration=2", str(wav)], check=True)
    assert iov.audio_codec(wav) == "pcm_s16le"
    res = encode_video(tmp_path / "v.mp4", smooth_frames(n=4), 10, audio_from=wav)
    assert res.audio and iov.audio_codec(res.path) == "aac"
    assert iov.audio_codec(encode_video(tmp_path / "m.mp4", smooth_frames(n=2), 10).path) is None


@pytest.mark.parametrize("n_frames,second,copied", [(4, "aac", True), (None, "aac", True),
                                                    (4, "pcm_s16le", False)])
def test_every_audio_stream_is_kept(tmp_path, n_frames, second, copied):
    """A target with two audio streams (a second language, a commentary, a camera's separate
    channel) keeps both, in order: copied when the container takes every one as it is, else
    all encoded to AAC (before: the first only, the rest lost without a word)."""
    two = tmp_path / "two.mov"
    subprocess.run([iov.ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "sine=frequency=440:duration=2", "-f", "lavfi", "-i",
                    "sine=frequency=660:duration=2", "-map", "0", "-map", "1", "-c:a:0", "aac",
                    "-c:a:1", second, "-ac:a:1", "1", str(two)], check=True)
    assert iov.audio_codecs(two) == ("aac", second)
    res = encode_video(tmp_path / "v.mp4", iter(smooth_frames(n=4)), 10, audio_from=two,
                       n_frames=n_frames)
    assert res.audio and iov.audio_codecs(res.path) == ("aac", "aac")
    out = subprocess.run([iov.ffmpeg_exe(), "-hide_banner", "-i", str(res.path)],
                         capture_output=True, text=True).stderr
    assert re.findall(r"Audio: aac[^\n]*?(stereo|mono)", out) == ["mono", "mono"]
    if copied:
        assert _audio_packets(res.path) == _audio_packets(two)[:len(_audio_packets(res.path))]


@pytest.mark.parametrize("pixels,want", [
    ("yuv420p(tv, bt709, progressive)", "bt709"),
    ("yuv420p(tv, smpte170m/unknown/unknown, progressive)", "smpte170m"),
    ("yuvj420p(pc, bt470bg/bt470bg/smpte170m)", "bt470bg"),
    ("yuv420p(tv, unknown/bt709/bt709, progressive)", None),
    ("yuv420p(progressive)", None), ("yuv420p(tv, progressive)", None), ("yuv420p", None)])
def test_matrix_named_in_ffmpegs_description(pixels, want):
    from facetransfer.io.video_display import colour_named

    text = ("Input #0, mov,mp4,m4a,3gp,3g2,mj2, from 'x.mp4':\n"
            "  Stream #0:0[0x1](und): Audio: aac (LC) (mp4a / 0x6134706D), 44100 Hz, stereo\n"
            f"  Stream #0:1[0x2](und): Video: h264 (High) (avc1 / 0x31637661), {pixels}, "
            "512x480 [SAR 15:16 DAR 1:1], 789 kb/s, 30 fps\n")
    assert colour_named(text).matrix == want
    tags = colour_named(text)
    if "/" in pixels:                           # matrix/primaries/transfer
        said = pixels.split(", ")[1].rstrip(")").split("/")
        assert [tags.matrix, tags.primaries, tags.transfer] == [
            None if n == "unknown" else n for n in said[:3]] + [None] * (3 - len(said))
    elif want:                                  # one name: all three
        assert tags.primaries == tags.transfer == want

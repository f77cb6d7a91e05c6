"""A video target of more than 8 bits (facetransfer.io.video_depth): decoded a second time in
16 bits, each output frame that decode moved by the 8-bit rewrite's change; written as ProRes
from 16-bit frames (10 bits in the file) or as a 16-bit PNG or TIFF sequence; an 8-bit target
and H.264 outputs as before."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.ffmpeg import ffmpeg_exe  # noqa: E402
from facetransfer.io.plate_depth import deep_frame  # noqa: E402
from facetransfer.io.video import VideoOptions, VideoWriter, read_video, write_video  # noqa: E402
from facetransfer.io.video_depth import (VideoDepth, pixel_format_bits, video_bits,  # noqa: E402
                                         video_depth)
from facetransfer.io.video_like import like_video  # noqa: E402
from facetransfer.io.video_planes import DecodedPlanes  # noqa: E402
from test_transfer_cli import clips  # noqa: E402,F401 (the fixture: synthetic clips, tracks)


def _encode16(path: Path, frames16: np.ndarray, codec: list, fps: float = 25.0) -> Path:
    """``(F, H, W, 3)`` uint16 RGB frames encoded by ffmpeg with ``codec``'s arguments."""
    F, H, W, _ = frames16.shape
    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb48le",
                    "-s", f"{W}x{H}", "-r", str(fps), "-i", "-", *codec, str(path)],
                   input=np.ascontiguousarray(frames16, "<u2").tobytes(), check=True)
    return path


PRORES = ["-c:v", "prores_ks", "-profile:v", "3", "-pix_fmt", "yuv422p10le"]


def _decode16(path: Path, size: tuple[int, int]) -> np.ndarray:
    """``(F, H, W, 3) uint16``: ffmpeg's 16-bit RGB decode of a video."""
    W, H = size
    raw = subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(path), "-map", "0:v:0", "-f",
                          "rawvideo", "-pix_fmt", "rgb48le", "-"],
                         capture_output=True, check=True).stdout
    return np.frombuffer(raw, "<u2").reshape(-1, H, W, 3)


def _with_fine(frames: np.ndarray, seed: int) -> np.ndarray:
    """8-bit frames as 16-bit ones with a smooth detail below 8 bits (-128..128 around each
    level, waves of a phase of their own per frame and channel: what a codec can keep)."""
    F, H, W, C = frames.shape
    y, x = np.mgrid[0:H, 0:W]
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, (F, C))
    fine = np.rint(128 * np.sin(x[None, :, :, None] / 5.0 + y[None, :, :, None] / 7.0
                                + phase[:, None, None, :]))
    return np.clip(frames.astype(np.int64) * 257 + fine.astype(np.int64), 0, 65535) \
        .astype(np.uint16)


def _ramps(S: int, F: int = 3) -> np.ndarray:
    """``(F, S, S, 3) uint8``: smooth colour ramps, a little different each frame (what a
    codec keeps within a fraction of a level)."""
    y, x = np.mgrid[0:S, 0:S] * 32 // S
    return np.array([np.dstack([40 + x * 5 + k, 60 + y * 4, 200 - x * 2 - y * 2])
                     for k in range(F)]).astype(np.uint8)


def test_pixel_format_bits():
    for fmt, bits in (("yuv420p", 8), ("yuvj420p", 8), ("nv12", 8), ("rgb24", 8), ("bgra", 8),
                      ("ya8", 8), ("yuv422p10le", 10), ("yuva444p10le", 10), ("p010le", 10),
                      ("y210le", 10), ("v210", 10), ("x2rgb10le", 10), ("gbrp12le", 12),
                      ("yuv444p12le", 12), ("gray10le", 10), ("gray16be", 16), ("rgb48le", 16),
                      ("rgba64be", 16), ("ya16le", 16), ("p016le", 16), ("gbrap16le", 16),
                      ("", 8), (None, 8)):
        assert pixel_format_bits(fmt) == bits, fmt


def test_deep_frame_moves_the_16_bit_decode_by_the_change():
    """The change, not the rewrite's value, is carried: where the 8-bit frame the rewrite saw
    (another decoder's) is not round(v / 257), an unchanged pixel is still v and a changed one
    v + (rewritten - shown) * 257, clipped."""
    v = np.array([[[1000, 30000, 65000], [5000, 5000, 5000], [65400, 200, 40000]]], np.uint16)
    shown = np.array([[[5, 116, 252], [20, 20, 20], [254, 1, 155]]], np.uint8)  # not round
    rew = np.array([[[5, 116, 252], [22, 19, 20], [255, 0, 160]]], np.uint8)
    out = deep_frame(v, shown, rew)
    assert out.dtype == np.uint16
    assert np.array_equal(out[0, 0], v[0, 0])                        # unchanged: to the bit
    assert np.array_equal(out[0, 1], [5000 + 2 * 257, 5000 - 257, 5000])
    assert np.array_equal(out[0, 2], [65535, 0, 40000 + 5 * 257])    # clipped at both ends
    rgba = deep_frame(np.dstack([v, np.array([[7, 8, 9]], np.uint16)]), shown, rew)
    assert np.array_equal(rgba[..., 3], [[7, 8, 9]])                # the alpha as it was
    assert np.array_equal(rgba[..., :3], out)                        # the colour as RGB's


def test_decoded_planes_reads_16_bit_frames_in_any_order_a_few_ahead(tmp_path):
    frames16 = np.random.default_rng(1).integers(0, 65536, (5, 8, 12, 3), dtype=np.uint16)
    mkv = _encode16(tmp_path / "lossless.mkv", frames16, ["-c:v", "ffv1", "-pix_fmt",
                                                          "gbrp16le"])
    assert video_bits(mkv) == 16
    planes = DecodedPlanes(mkv, "rgb48le", "the 16-bit colour of", start=1)
    got = {i: planes.frame(i) for i in (2, 1, 4, 3)}
    for i, f in got.items():
        assert np.array_equal(f, frames16[i]), i
    with pytest.raises(VideoError, match="frame 2 of .*lossless.mkv was read already"):
        planes.frame(2)
    planes.close()
    short = DecodedPlanes(mkv, "rgb48le", "the 16-bit colour of")
    with pytest.raises(VideoError, match="the 16-bit colour of .* ends at frame 5"):
        short.frame(7)
    short.close()


def test_a_deep_target_written_in_8_bits_is_warned_of_once(tmp_path, caplog):
    """A transfer (a command that carries depth) writing a 10-bit target as H.264 or JPEG
    says once that its depth is lost and what keeps it; ProRes, H.265 and 16-bit sequences,
    an 8-bit target and a command that does not carry depth say nothing."""
    import logging

    frames = _ramps(32)
    ten = _encode16(tmp_path / "ten.mov", _with_fine(frames, 9), PRORES)
    eight = write_video(tmp_path / "eight.mp4", frames, 25.0)
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        like_video(VideoOptions("prores"), ten, tmp_path / "r.mov")
        like_video(VideoOptions("h265"), ten, tmp_path / "r.mp4")
        like_video(None, ten, tmp_path / "s" / "%04d.png")
        like_video(None, eight, tmp_path / "r.mp4")
        like_video(None, ten)
        assert not caplog.records
        for out in ("r.mp4", "r2.mp4", "s/%04d.jpg"):
            like_video(None, ten, tmp_path / out)
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"{ten} has 10 bits a sample; the result is written in 8 (--codec prores "
                    "or h265, or a 16-bit PNG, TIFF or DPX sequence, keeps them)"]


def test_a_deep_sdr_target_written_in_8_bits_keeps_its_colour_names(tmp_path, caplog):
    """The depth warning does not cost a 10-bit BT.709 target's primaries and transfer in an
    H.264 result (they are still named, as an 8-bit target's are); a 10-bit target with alpha
    written as a TIFF sequence (its alpha kept in 8 bits) is warned of as not deep."""
    import logging

    frames = _ramps(32)
    tagged = _encode16(tmp_path / "709.mov", _with_fine(frames, 10), [
        "-vf", "setparams=color_primaries=bt709:color_trc=bt709:colorspace=bt709", *PRORES,
        "-colorspace", "bt709"])
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        opt = like_video(None, tagged, tmp_path / "r.mp4")
    assert (opt.deep, opt.primaries, opt.transfer) == (False, "bt709", "bt709")
    assert len(caplog.records) == 1 and "has 10 bits a sample" in caplog.records[0].getMessage()
    deep = like_video(VideoOptions("prores"), tagged, tmp_path / "r.mov")
    assert (deep.deep, deep.matrix, deep.primaries, deep.transfer) == (
        True, "bt709", "bt709", "bt709")
    from test_plate_alpha import _prores_4444

    rgba = np.random.default_rng(11).integers(0, 256, (2, 16, 16, 4), dtype=np.uint8)
    mov = _prores_4444(tmp_path / "a.mov", rgba)   # decodes in 12 bits
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        like_video(None, mov, tmp_path / "png" / "%04d.png")    # 16 bits with its alpha
        assert not caplog.records
        like_video(None, mov, tmp_path / "tif" / "%04d.tif")    # alpha kept, in 8 bits
    assert [r.getMessage() for r in caplog.records] == [
        f"{mov} has 12 bits a sample; the result is written in 8 (a TIFF sequence with alpha "
        "is written in 8 bits; --codec prores, or a PNG or DPX sequence, keeps them and the "
        "alpha)"]
    assert video_depth(tmp_path / "tif" / "%04d.tif", mov) is None


def test_which_targets_and_outputs_are_written_deep(tmp_path):
    frames = np.random.default_rng(2).integers(0, 256, (3, 16, 16, 3), dtype=np.uint8)
    ten = _encode16(tmp_path / "ten.mov", _with_fine(frames, 3), PRORES)
    eight = write_video(tmp_path / "eight.mov", frames, 25.0, options=VideoOptions("prores"))
    h264 = write_video(tmp_path / "eight.mp4", frames, 25.0)
    assert (video_bits(ten), video_bits(eight), video_bits(h264)) == (10, 10, 8)
    prores = VideoOptions(codec="prores")
    assert like_video(prores, ten, tmp_path / "r.mov").deep
    assert not like_video(prores, ten).deep                      # a command that does not carry it
    assert not like_video(None, ten, tmp_path / "r.mp4").deep    # H.264: 8 bits
    assert not like_video(prores, h264, tmp_path / "r.mov").deep
    assert like_video(VideoOptions("h265"), ten, tmp_path / "r.mp4").deep   # Main 10
    with pytest.raises(VideoError, match="16-bit frames are written as ProRes or H.265 only, "
                                         "not h264"):
        VideoOptions(deep=True)
    with pytest.raises(VideoError, match="by the bt709 matrix are written as ProRes or in 16 "
                                         "bits only"):
        VideoOptions(matrix="bt709")
    deep = like_video(prores, ten, tmp_path / "r.mov")
    assert isinstance(video_depth(tmp_path / "r.mov", ten, deep), VideoDepth)
    assert video_depth(tmp_path / "r.mov", ten, prores) is None
    assert video_depth(tmp_path / "r.mp4", ten, None) is None
    for seq in ("s/%04d.png", "s/%04d.tif", "s/%04d.dpx"):
        made = video_depth(tmp_path / seq, ten)
        assert isinstance(made, VideoDepth) and made.kept == "in the target's 10 bits"
    assert video_depth(tmp_path / "s/%04d.jpg", ten) is None
    assert video_depth(tmp_path / "s/%04d.png", h264) is None
    from facetransfer.io.video_facts import fact_lines, video_facts

    assert fact_lines(video_facts(ten))[-1] == (
        "  10 bits a sample, seen in 8: kept by transfer in ProRes or H.265 (--codec prores or "
        "h265: 10 bits, an HDR video's colour too) or a 16-bit PNG, TIFF or DPX sequence")
    assert video_facts(h264).bits == 8 and not any("bits" in ln
                                                   for ln in fact_lines(video_facts(h264)))


def test_the_writer_pipes_16_bit_frames_into_prores(tmp_path):
    """16-bit frames reach ProRes's 10 bits (their detail below 8 bits kept); 8-bit frames
    into the same writer are v * 257; a 16-bit frame into an 8-bit writer is refused."""
    S = 128   # smooth colour ramps (ProRes keeps them within a fraction of a level)
    frames = _ramps(S)
    deep16 = _with_fine(frames, 5)
    out = tmp_path / "deep.mov"
    with VideoWriter(out, 25.0, (S, S), options=VideoOptions("prores", deep=True)) as w:
        w.write(deep16[0])
        w.write(deep16[1])
        w.write(frames[2])
    eight = tmp_path / "eight.mov"   # the same frames through 8 bits lose their detail
    write_video(eight, np.rint(deep16[:2] / 257.0).astype(np.uint8), 25.0,
                options=VideoOptions("prores"))

    def rms(a, b):   # in 8-bit levels
        return np.sqrt((((a.astype(np.float64) - b) / 257.0) ** 2).mean())

    got = _decode16(out, (S, S))
    assert rms(got[:2], deep16[:2]) < 0.2 < 0.4 < rms(_decode16(eight, (S, S)), deep16[:2])
    assert np.abs((got[2].astype(np.float64) - frames[2] * 257.0) / 257.0).mean() < 0.25
    with pytest.raises(VideoError, match="16-bit frames are written to PNG or TIFF sequences"):
        with VideoWriter(tmp_path / "no.mov", 25.0, (S, S),
                         options=VideoOptions("prores")) as w:
            w.write(deep16[0])


def test_a_transfer_onto_a_10_bit_target_keeps_its_depth(clips, quick_model_path, tmp_path,
                                                         capsys):
    """Onto a 10-bit ProRes target: written as a PNG sequence, 16-bit frames whose every pixel
    is the target's 16-bit decode moved by a whole number of 8-bit levels, most of them not
    moved at all (before: 8 bits, every pixel's detail below 8 bits lost); as ProRes, 10 bits
    that keep the target's values outside the face within ProRes's own loss, where an 8-bit
    rewrite of the same target (as before) is off by more than twice that."""
    import cv2

    from facetransfer.cli.main import main

    frames = read_video(clips["target"])[0]
    F, H, W, _ = frames.shape
    target = _encode16(tmp_path / "target.mov", _with_fine(frames, 6), PRORES)
    truth = _decode16(target, (W, H)).astype(np.int64)
    common = ["transfer", "--target-track", clips["target_track"], "--expression-from",
              clips["source"], "--source-track", clips["source_track"], "--model",
              quick_model_path, "--no-progress", "--target", target]
    (tmp_path / "out").mkdir()
    assert main([*map(str, common), "--out", str(tmp_path / "out" / "r.%04d.png")]) == 0
    assert ", in the target's 10 bits" in capsys.readouterr().out
    got = np.array([cv2.imread(str(tmp_path / "out" / f"r.{i:04d}.png"),
                               cv2.IMREAD_UNCHANGED)[..., ::-1] for i in range(F)])
    assert got.dtype == np.uint16
    moved = got.astype(np.int64) - truth
    inside = (got > 0) & (got < 65535)                           # not clipped
    assert (moved[inside] % 257 == 0).all()
    kept = (moved == 0).all(axis=-1)
    assert 0.5 < kept.mean() < 0.99                              # the face, and only it, moved
    outside = np.array([cv2.erode(k.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
                        for k in kept])                          # ProRes's blocks: 8x8
    out = tmp_path / "r.mov"
    assert main([*map(str, common), "--codec", "prores", "--out", str(out)]) == 0
    assert ", in the target's 10 bits" in capsys.readouterr().out
    assert video_bits(out) == 10
    plain = tmp_path / "plain.mov"   # the 8-bit rewrite of the same target, as before
    write_video(plain, read_video(out)[0], 25.0, options=VideoOptions("prores"))

    def rms(path):   # outside the face, in 8-bit levels
        d = (_decode16(path, (W, H)).astype(np.float64) - truth) / 257.0
        return np.sqrt((d[outside] ** 2).mean())

    # ProRes's own loss on this rough synthetic texture is ~0.6 of a level; through 8 bits
    # (OpenCV's rounding, the other decoder's) more than twice that
    assert rms(out) < 0.6 * rms(plain)


def _hlg(path: Path, frames: np.ndarray) -> Path:
    """A phone's kind of HDR video: 10-bit HEVC, BT.2020 primaries and matrix, HLG."""
    return _encode16(path, _with_fine(frames, 7), [
        "-vf", "setparams=color_primaries=bt2020:color_trc=arib-std-b67:colorspace=bt2020nc",
        "-c:v", "libx265", "-pix_fmt", "yuv420p10le", "-colorspace", "bt2020nc",
        "-x265-params", "log-level=error"])


def test_an_hdr_target_written_deep_keeps_its_colour(tmp_path, caplog):
    """An HLG target written as H.265 or ProRes: 16-bit frames converted by its own matrix,
    its primaries and transfer named, no warning; as H.264, 8-bit SDR and the warning; as a
    16-bit PNG sequence (its values as decoded), no warning."""
    import logging

    from facetransfer.io.video_display import video_colour

    hlg = _hlg(tmp_path / "hlg.mp4", _ramps(64))
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        for codec in ("h265", "prores"):
            opt = like_video(VideoOptions(codec), hlg, tmp_path / "r.mov")
            assert (opt.deep, opt.matrix, opt.primaries, opt.transfer) == (
                True, "bt2020nc", "bt2020", "arib-std-b67"), codec
        like_video(None, hlg, tmp_path / "s" / "%04d.png")
        assert not caplog.records
        opt = like_video(None, hlg, tmp_path / "r.mp4")
    assert (opt.deep, opt.matrix, opt.primaries) == (False, "smpte170m", None)
    assert len(caplog.records) == 1 and caplog.records[0].getMessage().endswith(
        "looks flatter than the original does in an HDR player (--codec h265 or prores, or a "
        "16-bit PNG or TIFF sequence, keeps its 10 bits and its colour)")
    deep = like_video(VideoOptions("h265"), hlg, tmp_path / "r.mp4")
    out = tmp_path / "r.mp4"
    truth = _decode16(hlg, (64, 64))
    with VideoWriter(out, 25.0, (64, 64), options=deep) as w:
        for f in truth:
            w.write(f)
    tags = video_colour(out)
    assert (tags.matrix, tags.primaries, tags.transfer) == ("bt2020nc", "bt2020", "arib-std-b67")
    assert video_bits(out) == 10
    err = (_decode16(out, (64, 64)).astype(np.float64) - truth) / 257.0
    assert np.sqrt((err ** 2).mean()) < 1.0   # x265 at CRF 18 (0.6 here); by another matrix: tens


def test_decoded_planes_follow_a_variable_rates_timeline(tmp_path):
    """A video of variable frame rate is read on its constant-rate timeline: frame ``i`` of
    the 16-bit decode is the stored frame the reader's frame ``i`` shows (repeated across the
    gap), from any start."""
    from facetransfer.io.video_read import video_info

    levels = (np.arange(12) * 5000 + 1000).astype(np.uint16)
    frames16 = np.broadcast_to(levels[:, None, None, None], (12, 16, 24, 3)).copy()
    lossless = ["-c:v", "png", "-pix_fmt", "rgb48be"]   # 16-bit PNG in QuickTime: counted
    even = _encode16(tmp_path / "even.mov", frames16, lossless, fps=10)
    uneven = tmp_path / "uneven.mov"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(even), "-vf",
                    "setpts='if(gte(N,6),N+5,N)/10/TB'", "-fps_mode", "vfr", *lossless,
                    str(uneven)], check=True)
    steps = video_info(uneven).steps
    assert steps is not None and len(steps) == 17          # a 5-step gap after frame 5
    shown = read_video(uneven)[0][:, 0, 0, 0]
    for start in (0, 4, 8):
        planes = DecodedPlanes(uneven, "rgb48le", "the 16-bit colour of", start=start)
        got = [int(planes.frame(i)[0, 0, 0]) for i in range(start, 17)]
        assert got == [int(levels[s]) for s in steps[start:]], start
        # the frames the reader shows (OpenCV takes this codec's 16 bits as v / 256)
        assert np.abs(np.array(got) / 256.0 - shown[start:]).max() <= 0.5
        planes.close()

"""A plate's time (facetransfer.io.plate_header): the frame rate and SMPTE timecode in a DPX or
OpenEXR frame's header, read where the plate is opened (its rate, its start timecode carried
by the results and the exports) and written into the DPX and OpenEXR frames of a sequence made
from another target (its rate, each frame's timecode from the target's start on)."""

from __future__ import annotations

import dataclasses
import logging
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.io.plate_header import (FrameHeader, frame_header,  # noqa: E402
                                          rate_fraction, timecode_after, timecode_text,
                                          timecode_word, usable_rate, written_header)
from facetransfer.io.video_display import timecode_seconds  # noqa: E402
from test_dpx import target  # noqa: E402,F401 (the fixture)
from test_transfer_cli import clips, plate_transfer_args  # noqa: E402,F401 (the fixture)

TIMECODES = ["00:00:00:00", "01:00:00:07", "10:59:59:24", "23:59:59:29", "13:45:07;28",
             "00:01:00;02"]


def _exr(path: Path, timecode: str | None = None, fps: Fraction | None = None,
         aspect: float | None = None, rgb: np.ndarray | None = None) -> None:
    """An OpenEXR frame (4x4 black, or the sRGB frame ``rgb`` in linear half floats) whose
    header holds ``timecode`` (written field by field through OpenEXR's own ``TimeCode``),
    ``fps`` and the pixel aspect ratio ``aspect``."""
    from facetransfer.io.exr import srgb_decode

    import OpenEXR

    header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
    if timecode is not None:
        tc = OpenEXR.TimeCode()
        hh, mm, ss, ff = (int(v) for v in timecode.replace(";", ":").split(":"))
        tc.hours, tc.minutes, tc.seconds, tc.frame = hh, mm, ss, ff
        tc.dropFrame = ";" in timecode
        header["timeCode"] = tc
    if fps is not None:
        header["framesPerSecond"] = fps
    if aspect is not None:
        header["pixelAspectRatio"] = float(aspect)
    pixels = np.zeros((4, 4, 3), np.float16) if rgb is None else \
        srgb_decode(rgb).astype(np.float16)
    with OpenEXR.File(header, {"RGB": pixels}) as f:
        f.write(str(path))


def _dpx(path: Path, rgb: np.ndarray | None = None, *, word: int | None = None,
         film: float | None = None, tv: float | None = None, aspect: float | None = None
         ) -> None:
    """A 10-bit DPX frame written by OpenImageIO with the timecode ``word``, the film and
    television headers' frame rates and the pixel aspect ratio given."""
    import OpenImageIO as oiio

    rgb = np.zeros((8, 8, 3), np.uint8) if rgb is None else rgb
    spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, "uint16")
    spec.attribute("oiio:BitsPerSample", 10)
    spec.attribute("dpx:Transfer", "ITU-R 709-4")
    if word is not None:
        spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"),
                       np.array([word, 0], np.uint32))
    for name, value in (("dpx:FrameRate", film), ("dpx:TemporalFrameRate", tv),
                        ("PixelAspectRatio", aspect)):
        if value is not None:
            spec.attribute(name, float(value))
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image((rgb.astype(np.uint16) * 257).astype(np.uint16))
    out.close()


def _oiio_word(path: Path) -> int:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    word = inp.spec().getattribute("smpte:TimeCode")
    inp.close()
    return int(word[0])


@pytest.mark.parametrize("tc", TIMECODES)
def test_timecode_words_are_packed_as_openexr_and_openimageio_pack_them(tc, tmp_path):
    """SMPTE 12M's word: OpenEXR's own ``TimeCode`` built from the fields, as OpenImageIO
    packs it, is the word made here, and reads back as the timecode; a non-drop one as
    OpenImageIO's own DPX text of the word."""
    import OpenImageIO as oiio

    _exr(tmp_path / "t.exr", tc)
    assert _oiio_word(tmp_path / "t.exr") == timecode_word(tc)
    assert timecode_text(timecode_word(tc)) == tc
    assert frame_header(tmp_path / "t.exr") == FrameHeader(None, tc)
    if ";" not in tc:
        _dpx(tmp_path / "t.dpx", word=timecode_word(tc))
        inp = oiio.ImageInput.open(str(tmp_path / "t.dpx"))
        assert inp.spec().get_string_attribute("dpx:TimeCode") == tc
        inp.close()
        assert frame_header(tmp_path / "t.dpx").timecode == tc


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 0xFFFFFFFF))
def test_any_header_word_reads_as_a_timecode_that_packs_back_or_as_none(word):
    """A header's 32 bits, whatever they hold (flags, user bits, garbage): a timecode whose
    digits and drop-frame flag pack back to the same digit fields, or None; never an error."""
    text = timecode_text(word)
    if text is not None:
        mask = 0x3F7F7F3F | (1 << 6)                 # the digits and the drop-frame flag
        assert timecode_word(text) == word & mask


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.sampled_from([24.0, 25.0, 30000 / 1001, 60000 / 1001, 50.0]),
       st.integers(0, 24 * 3600 * 60 - 1), st.integers(0, 5000))
def test_counting_on_is_adding(fps, start, k):
    """``timecode_after(timecode_after(t, a), b) == timecode_after(t, a + b)`` from any frame
    of the day, drop-frame at 29.97 and 59.94."""
    drop = round(fps) in (30, 60) and fps != round(fps)
    t0 = timecode_after("00:00:00;00" if drop else "00:00:00:00", start, fps)
    a = k // 2
    assert timecode_after(timecode_after(t0, a, fps), k - a, fps) == timecode_after(t0, k, fps)


def test_words_that_are_not_timecodes_read_as_none():
    assert timecode_text(0xFFFFFFFF) is None                  # an unset DPX field
    assert timecode_text(timecode_word("01:00:00:00") | 0x0A) is None   # a digit 10
    assert timecode_text(0x24000000) is None                  # hour 24
    with pytest.raises(ValueError, match="not HH:MM:SS:FF"):
        timecode_word("1:00:00:00")


@pytest.mark.parametrize("start,fps", [("00:00:58;20", 30000 / 1001), ("00:09:59;50", 30000 / 1001),
                                       ("00:00:59;50", 60000 / 1001), ("23:59:59:20", 25.0),
                                       ("10:00:00:00", 24.0)])
def test_a_timecode_counts_on_as_the_clock(start, fps):
    """Each of 3000 frames on: its timecode is the start's time plus the frames' time at the
    true rate (drop-frame at 29.97 and 59.94 keeps to the clock), no label is skipped twice
    or shown for a frame that drops it, and midnight wraps."""
    t0 = timecode_seconds(start, fps)
    seen = set()
    for k in range(0, 3000):
        tc = timecode_after(start, k, fps)
        assert tc not in seen
        seen.add(tc)
        want = (t0 + k / fps) % 86400.0
        assert timecode_seconds(tc, fps) == pytest.approx(want, abs=1e-6), (k, tc)
        if ";" in tc:
            mm, ss, ff = int(tc[3:5]), int(tc[6:8]), int(tc[9:])
            skip = 2 if round(fps) == 30 else 4
            assert not (ss == 0 and ff < skip and mm % 10), tc     # a dropped label
    if start.startswith("23"):
        assert timecode_after(start, 5, fps) == "00:00:00:00"


def test_rates_are_written_as_fractions_and_read_from_either_header(tmp_path):
    assert rate_fraction(24000 / 1001) == Fraction(24000, 1001)
    assert rate_fraction(29.97) == Fraction(30000, 1001)
    assert rate_fraction(25.0) == 25 and rate_fraction(12.5) == Fraction(25, 2)
    assert usable_rate(23.976) == 24000 / 1001 and usable_rate(float("nan")) is None
    assert usable_rate(25.0) == 25.0 and usable_rate(0xFFFFFFFF) is None
    _dpx(tmp_path / "f.dpx", film=24.0, tv=25.0)              # ffmpeg's order: film first
    _dpx(tmp_path / "t.dpx", tv=50.0)
    _dpx(tmp_path / "n.dpx", film=0.0)
    assert [frame_header(tmp_path / f"{n}.dpx").fps for n in "ftn"] == [24.0, 50.0, None]
    _exr(tmp_path / "e.exr", fps=Fraction(30000, 1001))
    assert frame_header(tmp_path / "e.exr").fps == pytest.approx(30000 / 1001)
    (tmp_path / "x.dpx").write_bytes(b"SDPX" + b"\0" * 40)       # damaged: nothing said
    assert frame_header(tmp_path / "x.dpx") == FrameHeader()
    _dpx(tmp_path / "a.dpx", aspect=2.0)                      # an anamorphic scan's 2x
    _dpx(tmp_path / "s.dpx", aspect=1.0)
    _exr(tmp_path / "d.exr", aspect=10 / 11)                  # DV's
    assert [frame_header(tmp_path / n).sar for n in ("a.dpx", "s.dpx", "d.exr", "f.dpx")] == \
        [(2, 1), None, (10, 11), None]
    assert written_header(25.0, "00:00:59:24", 1) == FrameHeader(25.0, "00:01:00:00")
    assert written_header(25.0, None, 3) == FrameHeader(25.0, None)


def _dpx_plate(folder: Path, frames, fps: float, start: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        _dpx(folder / f"sh010.{1001 + i:04d}.dpx", rgb, film=fps,
             word=timecode_word(timecode_after(start, i, fps)))
    return folder / "sh010.####.dpx"


def test_a_plate_is_read_at_its_headers_rate_from_its_timecode(target, tmp_path, capsys,
                                                               caplog, monkeypatch):
    """A DPX plate whose headers say 25 fps and 10:00:00:00 on: read at 25 fps, not the
    default 24, said by ``probe`` with its timecode, no warning; ``--sequence-fps`` overrides
    the header, said in a warning; an exported take of its track starts at its timecode."""
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import source_timecode
    from facetransfer.io.video_display import timecode_of
    from facetransfer.io.video_sequence import SEQUENCE_FPS_VARIABLE, open_sequence

    monkeypatch.delenv(SEQUENCE_FPS_VARIABLE, raising=False)
    _, frames = target
    plate = _dpx_plate(tmp_path / "plate", frames, 25.0, "10:00:00:00")
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        seq = open_sequence(plate)
    assert (seq.fps, seq.rate_from, seq.timecode) == (25.0, "header", "10:00:00:00")
    assert "stores no frame rate" not in caplog.text
    assert timecode_of(plate) == "10:00:00:00"
    track = dataclasses.make_dataclass("T", [("source", str)])(str(plate))
    assert source_timecode(track) == "10:00:00:00"
    assert main(["probe", str(plate)]) == 0
    said = capsys.readouterr().out
    assert "read at 25 fps, " in said and "(its frames' headers' rate" in said
    assert "timecode 10:00:00:00 (the results start at it)" in said
    caplog.clear()
    monkeypatch.setenv(SEQUENCE_FPS_VARIABLE, "24")
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        seq = open_sequence(plate)
    assert (seq.fps, seq.rate_from) == (24.0, "said")
    assert "its frames' headers say 25 fps; read at 24 fps" in caplog.text


def test_a_plates_rate_and_timecode_carry_into_a_video_and_a_video_s_into_frames(
        clips, target, quick_model_path, tmp_path, capsys, monkeypatch):
    """Onto a 25 fps DPX plate starting at 10:00:00:00, the rewrite written as MP4 plays at
    25 fps and starts at 10:00:00:00; onto an OpenEXR plate of pixels 8:9, the MP4 is shown
    at that shape; onto a video that starts at 01:00:59:20 and has pixels 8:9, the rewrite
    written as DPX or OpenEXR frames records 25 fps, each frame's timecode on from it and the
    pixels' aspect."""
    from facetransfer.cli.main import main
    from facetransfer.io.video import VideoOptions, read_video, write_video
    from facetransfer.io.video_display import timecode_of
    from facetransfer.io.video_read import video_info
    from facetransfer.io.video_sequence import SEQUENCE_FPS_VARIABLE

    monkeypatch.delenv(SEQUENCE_FPS_VARIABLE, raising=False)
    lossless, frames = target
    plate = _dpx_plate(tmp_path / "plate", frames, 25.0, "10:00:00:00")
    args = plate_transfer_args(clips, quick_model_path, fps=None)
    code = main(["transfer", "--target", str(plate), *args, "--out", str(tmp_path / "r.mp4")])
    assert code == 0, capsys.readouterr().err
    assert video_info(tmp_path / "r.mp4").fps == pytest.approx(25.0)
    assert timecode_of(tmp_path / "r.mp4") == "10:00:00:00"
    exr = tmp_path / "exr_plate"
    exr.mkdir()
    for i, rgb in enumerate(frames):
        _exr(exr / f"p.{i:04d}.exr", fps=Fraction(25), aspect=8 / 9, rgb=rgb)
    code = main(["transfer", "--target", str(exr / "p.%04d.exr"), *args,
                 "--out", str(tmp_path / "x.mp4")])
    assert code == 0, capsys.readouterr().err
    assert video_info(tmp_path / "x.mp4").sar == (8, 9)
    assert video_info(tmp_path / "x.mp4").fps == pytest.approx(25.0)
    video = tmp_path / "t.mkv"
    write_video(video, read_video(lossless)[0], 25.0,
                options=VideoOptions(crf=0, timecode="01:00:59:20", sar=(8, 9)))
    for suffix in ("dpx", "exr"):
        code = main(["transfer", "--target", str(video), *args,
                     "--out", str(tmp_path / suffix / f"ft.%04d.{suffix}")])
        assert code == 0, capsys.readouterr().err
        for i in range(len(frames)):
            got = frame_header(tmp_path / suffix / f"ft.{i:04d}.{suffix}")
            assert got.fps == pytest.approx(25.0)
            assert got.timecode == timecode_after("01:00:59:20", i, 25.0)
            assert got.sar == (8, 9)
    from facetransfer.io.exr import read_exr_image

    assert read_exr_image(tmp_path / "exr" / "ft.0000.exr").header["colorInteropID"] == \
        "lin_rec709_scene"                           # what its floats are, said
    assert frame_header(tmp_path / "dpx" / "ft.0005.dpx").timecode == "01:01:00:00"


@pytest.mark.parametrize("tc, fps, ok", [
    ("01:00:00:24", 25.0, True), ("01:00:00:25", 25.0, False), ("01:00:00:30", 25.0, False),
    ("23:59:59:24", 25.0, True), ("24:00:00:00", 25.0, False), ("00:61:00:00", 25.0, False),
    ("00:00:10;05", 25.0, False),                     # no drop-frame count at 25 fps
    ("00:01:00;02", 30000 / 1001, True), ("00:01:00;00", 30000 / 1001, False),
    ("00:01:00;01", 30000 / 1001, False), ("00:10:00;00", 30000 / 1001, True),
    ("00:01:00:00", 30000 / 1001, True),              # a non-drop count at 29.97
    ("00:00:00:23", 24000 / 1001, True), ("00:00:00:24", 24000 / 1001, False),
    ("00:00:01:119", 120.0, True), ("00:00:01:05", 120.0, True),
    ("01:02:03;04", 30.0, False), ("00:00:00;10", 60.0, False),   # integer rates: no drop
])
def test_a_typed_timecode_must_name_a_frame(tc, fps, ok):
    from facetransfer.io.plate_header import exact_timecode

    if ok:
        assert exact_timecode(f" {tc} ", fps) == tc
    else:
        with pytest.raises(ValueError, match="names no frame|is not HH:MM:SS:FF"):
            exact_timecode(tc, fps)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.sampled_from([24.0, 25.0, 30000 / 1001, 60000 / 1001, 50.0, 120.0]),
       st.integers(0, 24 * 3600 * 60 - 1))
def test_every_timecode_of_the_day_is_exact_and_counts_back(fps, frame):
    """Every frame of the day's timecode (:func:`timecode_after` from midnight, drop-frame at
    29.97 and 59.94) is accepted by :func:`exact_timecode` and counts back to its frame; the
    next frame number past the rate is not a timecode there."""
    from facetransfer.io.plate_header import exact_timecode, timecode_count

    drop = round(fps) in (30, 60) and fps != round(fps)
    rate = round(fps)
    frame %= 24 * 3600 * rate - (2 * (round(fps) // 30) * 9 * 144 if drop else 0)
    tc = timecode_after("00:00:00;00" if drop else "00:00:00:00", frame, fps)
    assert exact_timecode(tc, fps) == tc
    assert timecode_count(tc, fps)[0] == frame
    past = f"{tc[:9]}{rate:0{len(tc) - 9}d}"                   # frames = the rate
    with pytest.raises(ValueError, match="names no frame"):
        exact_timecode(past, fps)

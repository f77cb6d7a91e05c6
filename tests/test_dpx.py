"""DPX plates (facetransfer.io.dpx): code values of 8 to 16 bits shown to the tracker by their
transfer characteristic (Cineon log, linear, video), read as the frames they hold; a rewrite
written as DPX keeps every code value it does not change, to the bit, with the plate's header
and alpha, and shows the rewrite of the same frames where it changes them."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.dpx import (DpxImage, dpx_header, graded_codes, read_dpx_image,  # noqa: E402
                                 shown_dpx, write_dpx)
from facetransfer.io.exr import srgb_decode  # noqa: E402
from facetransfer.io.video import VideoOptions, read_video, write_video  # noqa: E402
from test_transfer_cli import (clips, plate_and_video_rewrites,  # noqa: E402,F401 (fixture)
                               plate_transfer_args)

#: Kodak's Cineon conventions, written out here from their definition (not the module's)
BLACK, WHITE = 95, 685


def _cineon_light(c10):
    """Light relative to white, black subtracted, of 10-bit log codes."""
    b = 10 ** ((BLACK - WHITE) * 0.002 / 0.6)
    return (10 ** ((np.asarray(c10, float) - WHITE) * 0.002 / 0.6) - b) / (1 - b)


def _srgb_levels(light):
    x = np.clip(light, 0, 1)
    return 255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _spec(w: int, h: int, channels: int, bits: int, transfer: str, timecode: int = 0):
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(w, h, channels, "uint16")
    spec.attribute("oiio:BitsPerSample", bits)
    spec.attribute("dpx:Transfer", transfer)
    spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"),
                   np.array([0x01000000 + timecode, 0], np.uint32))
    return spec


def _levels(codes, transfer: str) -> np.ndarray:
    """Display levels (not rounded) of 10-bit codes by their transfer."""
    x = np.asarray(codes, float) / 1023
    return {"Printing density": lambda: _srgb_levels(_cineon_light(x * 1023)),
            "Linear": lambda: _srgb_levels(x), "ITU-R 709-4": lambda: 255 * x}[transfer]()


def _log_codes(rgb: np.ndarray) -> np.ndarray:
    """8-bit sRGB frames as 10-bit Cineon log codes (the inverse of the curve above)."""
    b = 10 ** ((BLACK - WHITE) * 0.002 / 0.6)
    light = srgb_decode(rgb).astype(np.float64)
    return np.clip(np.rint(WHITE + 300 * np.log10(light * (1 - b) + b)), 0, 1023).astype(
        np.uint16)


@pytest.mark.parametrize("bits", [8, 10, 12, 16])
def test_every_code_is_written_and_read_back_as_itself(bits, tmp_path):
    top = (1 << bits) - 1
    codes = np.linspace(0, top, 64 * 64 * 3).round().astype(np.uint16).reshape(64, 64, 3) \
        if bits == 16 else np.resize(np.arange(top + 1, dtype=np.uint16), (64, 64, 3))
    write_dpx(tmp_path / "c.dpx", DpxImage(codes, bits, "Linear", _spec(64, 64, 3, bits,
                                                                          "Linear")))
    got = read_dpx_image(tmp_path / "c.dpx")
    assert got.bits == bits and got.transfer == "Linear"
    assert np.array_equal(got.codes, codes)
    assert dpx_header(tmp_path / "c.dpx") == (bits, "Linear", 3)


def test_codes_are_shown_by_their_transfer():
    codes = np.array([[[0, 95, 685], [1023, 380, 512]]], np.uint16)
    log = shown_dpx(DpxImage(codes, 10, "Printing density"))
    want = np.rint(_srgb_levels(_cineon_light(codes))).astype(np.uint8)
    assert np.array_equal(log, want)
    assert log[0, 0].tolist() == [0, 0, 255] and log[0, 1, 0] == 255   # black, white, above
    video = shown_dpx(DpxImage(codes, 10, "ITU-R 709-4"))
    assert np.array_equal(video, np.rint(codes / 1023 * 255).astype(np.uint8))
    linear = shown_dpx(DpxImage(codes, 10, "Linear"))
    assert np.array_equal(linear, np.rint(_srgb_levels(codes / 1023)).astype(np.uint8))
    luma = shown_dpx(DpxImage(codes[..., :1], 10, ""))
    assert luma.shape == (1, 2, 3) and np.array_equal(luma[..., 2], video[..., 0])


def test_a_plate_of_video_levels_is_shown_between_its_reference_codes(tmp_path):
    """A 10-bit plate whose header says black is code 64 and white 940 (video levels): shown
    between them (beyond, as black and white), rewritten within them, probed so."""
    from facetransfer.io.dpx import dpx_summary

    spec = _spec(8, 2, 3, 10, "ITU-R 709-4")
    spec.attribute("dpx:LowData", 64)
    spec.attribute("dpx:HighData", 940)
    codes = np.array([0, 64, 502, 940, 1023, 300, 700, 64], np.uint16)
    codes = np.repeat(np.stack([codes, codes])[..., None], 3, axis=2)
    write_dpx(tmp_path / "v.dpx", DpxImage(codes, 10, "ITU-R 709-4", spec))
    plate = read_dpx_image(tmp_path / "v.dpx")
    assert plate.coding == ("video", 10, 64, 940)
    shown = shown_dpx(plate)
    want = np.rint(np.clip((codes.astype(float) - 64) / 876, 0, 1) * 255).astype(np.uint8)
    assert np.array_equal(shown, want) and shown[0, :5, 0].tolist() == [0, 0, 128, 255, 255]
    rewritten = shown.copy()
    rewritten[1] = np.array([0, 255, 10, 20, 30, 40, 50, 60], np.uint8)[:, None]
    out = graded_codes(plate, shown, rewritten)
    assert out[1, 0, 0] == 0 and out[1, 1:].min() >= 64 and out[1, 1:].max() <= 940
    assert np.array_equal(shown_dpx(DpxImage(out, 10, "ITU-R 709-4", plate.spec)), rewritten)
    assert np.array_equal(out[0], codes[0])
    assert "shown as they are between codes 64 (black) and 940 (white)" in \
        dpx_summary(tmp_path / "v.dpx")


def test_every_8_bit_level_made_log_is_shown_as_itself():
    levels = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    assert np.array_equal(shown_dpx(DpxImage(_log_codes(levels), 10, "Logarithmic")), levels)


@pytest.mark.parametrize("transfer", ["Printing density", "Linear", "ITU-R 709-4"])
def test_a_graded_frame_changes_only_what_the_rewrite_changed(transfer):
    rng = np.random.default_rng(4)
    codes = rng.integers(0, 1024, (30, 40, 3)).astype(np.uint16)
    plate = DpxImage(codes, 10, transfer)
    shown = shown_dpx(plate)
    rewritten = shown.copy()
    rewritten[5:15, 10:30] = rng.integers(0, 256, (10, 20, 3), dtype=np.uint8)
    rewritten[20, 5, 0] = shown[20, 5, 0] ^ 1                  # one channel of a pixel moved
    out = graded_codes(plate, shown, rewritten)
    changed = np.any(rewritten != shown, axis=2)
    assert out.dtype == np.uint16 and np.array_equal(out[~changed], codes[~changed])
    # each changed sample the code nearest the rewritten level plus the plate's part below a
    # level, within half a code's step of it (a 10-bit linear code spans 3 levels in the
    # dark), unless that code is shown as another level than the rewrite's
    levels = _levels(np.arange(1024), transfer)
    step = np.maximum(np.abs(np.diff(levels, prepend=levels[0])),
                      np.abs(np.diff(levels, append=levels[-1])))
    inside = (levels[codes] > 0) & (levels[codes] < 255) if transfer != "ITU-R 709-4" \
        else np.ones(codes.shape, bool)
    aim = rewritten + np.where(inside, levels[codes] - shown, 0.0)
    moved = changed[..., None] & (aim > 0) & (aim < 255)
    near = np.abs(levels[out] - aim) <= step[out] / 2 + 1e-6
    other = np.rint(levels[np.clip(np.rint(np.interp(aim, levels, np.arange(1024))), 0, 1023)
                           .astype(int)]) != rewritten
    assert np.all((near | other)[moved]) and near[moved].mean() > 0.9
    again = shown_dpx(DpxImage(out, 10, transfer))
    shows = np.isin(rewritten, np.rint(levels).astype(int))   # a code shows that level
    assert np.array_equal(again[changed[..., None] & shows],      # shown as the rewrite
                          rewritten[changed[..., None] & shows])
    assert transfer == "Linear" or shows.all()                  # codes finer than levels
    if transfer == "Printing density":                          # beyond white: not kept
        beyond = changed[..., None] & ((codes > WHITE) | (codes < BLACK))
        assert beyond.sum() > 50 and np.all((out[beyond] >= BLACK) & (out[beyond] <= WHITE))
    else:                                                       # the channels not moved kept
        assert out[20, 5, 1] == codes[20, 5, 1] and out[20, 5, 2] == codes[20, 5, 2]


def test_the_header_and_alpha_are_kept_and_8_bit_frames_written_as_video(tmp_path):
    rng = np.random.default_rng(5)
    codes = rng.integers(0, 1024, (12, 16, 4)).astype(np.uint16)
    write_dpx(tmp_path / "a.dpx", DpxImage(codes, 10, "Printing density",
                                           _spec(16, 12, 4, 10, "Printing density", 7)))
    plate = read_dpx_image(tmp_path / "a.dpx")
    rgb = plate.rgb().copy()
    rgb[3:6, 4:8] = 500
    write_dpx(tmp_path / "b.dpx", plate.with_rgb(rgb))
    got = read_dpx_image(tmp_path / "b.dpx")
    assert np.array_equal(got.codes[..., 3], codes[..., 3]) and np.array_equal(got.rgb(), rgb)
    assert got.spec.get_string_attribute("dpx:TimeCode") == "01:00:00:07"
    assert got.transfer == "Printing density" and got.bits == 10
    eight = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    write_dpx(tmp_path / "c.dpx", eight)
    video = read_dpx_image(tmp_path / "c.dpx")
    assert (video.bits, video.transfer) == (10, "ITU-R 709-4")
    assert np.array_equal(video.codes, np.rint(eight / 255 * 1023).astype(np.uint16))
    assert np.array_equal(shown_dpx(video), eight)
    rgba = rng.integers(0, 256, (12, 16, 4), dtype=np.uint8)   # a plate's alpha beside it
    write_dpx(tmp_path / "d.dpx", rgba)
    assert np.array_equal(read_dpx_image(tmp_path / "d.dpx").codes,
                          np.rint(rgba / 255 * 1023).astype(np.uint16))
    for deep in (rng.integers(0, 65536, (12, 16), dtype=np.uint16),     # a 16-bit plate's
                 rng.integers(0, 65536, (12, 16, 4), dtype=np.uint16)):
        write_dpx(tmp_path / "e.dpx", deep)
        got = read_dpx_image(tmp_path / "e.dpx")
        assert (got.bits, got.transfer) == (16, "ITU-R 709-4")
        assert np.array_equal(got.codes.reshape(deep.shape), deep)
    with pytest.raises(ValueError, match=r"a DPX frame is .* not \(12, 16\) float32"):
        write_dpx(tmp_path / "f.dpx", np.zeros((12, 16), np.float32))


def test_a_file_that_is_not_dpx_is_one_error_naming_it(tmp_path):
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(6, 4, 3, "float")          # 32-bit float samples: not codes
    out = oiio.ImageOutput.create("dpx")
    assert out.open(str(tmp_path / "f.dpx"), spec)
    assert out.write_image(np.zeros((4, 6, 3), np.float32))
    out.close()
    with pytest.raises(VideoError, match=r"f.dpx \(32-bit samples: 8, 10, 12 and 16-bit"):
        read_dpx_image(tmp_path / "f.dpx")
    (tmp_path / "x.dpx").write_bytes(b"PNG?" + bytes(100))
    with pytest.raises(VideoError, match=r"x.dpx is not a DPX file"):
        read_dpx_image(tmp_path / "x.dpx")
    with pytest.raises(VideoError, match="cannot read the DPX frame"):
        read_dpx_image(tmp_path / "missing.dpx")


@pytest.fixture(scope="module")
def target(clips, tmp_path_factory):
    """The synthetic target's frames as a lossless video decodes them."""
    lossless = tmp_path_factory.mktemp("dpx") / "target.mkv"
    write_video(lossless, read_video(clips["target"])[0], 25.0, options=VideoOptions(crf=0))
    return lossless, read_video(lossless)[0]


def _log_plate(folder: Path, frames, bright_rows: int = 0) -> Path:
    """The frames as a 10-bit log plate numbered from 1001, as a film scan: RGBA, a timecode
    per frame; the top ``bright_rows`` above white (a highlight the display clips)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        codes = _log_codes(rgb)
        codes[:bright_rows] = np.maximum(codes[:bright_rows], 800)
        alpha = np.full(codes.shape[:2] + (1,), 100 + i, np.uint16)
        h, w = codes.shape[:2]
        write_dpx(folder / f"sh010.{1001 + i:04d}.dpx",
                  DpxImage(np.concatenate([codes, alpha], axis=2), 10, "Printing density",
                           _spec(w, h, 4, 10, "Printing density", i)))
    return folder / "sh010.####.dpx"


def test_a_log_plate_reads_as_the_frames_it_holds(target, tmp_path, capsys, monkeypatch):
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    _, frames = target
    plate = _log_plate(tmp_path, frames)
    got, _ = read_video(plate)
    assert np.array_equal(got, frames)
    assert main(["probe", str(plate), "--sequence-fps", "25"]) == 0
    said = capsys.readouterr().out
    assert "DPX, RGBA, 10 bits, transfer Printing density: Cineon log" in said
    assert "a rewrite written as .dpx keeps every code value it does not change" in said


def test_a_log_plate_is_rewritten_in_its_own_codes(clips, target, quick_model_path, tmp_path,
                                                  capsys, monkeypatch):
    """Onto a 10-bit log plate, the rewrite written as DPX: numbered as the plate, 10-bit log,
    every pixel the rewrite did not change the plate's codes (highlights above white
    included), every changed one shown as the 8-bit rewrite of the same frames (a PNG
    sequence of the video); the plate's alpha and timecodes kept; written as PNG, the same
    colour with the plate's alpha in 8 bits."""
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    lossless, frames = target
    plate = _log_plate(tmp_path / "plate", frames, bright_rows=6)
    common = plate_transfer_args(clips, quick_model_path)
    said = plate_and_video_rewrites(plate, lossless, common, tmp_path, "dpx", capsys)
    assert ", in the plate's code values, with its header and alpha, no audio" in said
    code = main(["transfer", "--target", str(plate), *map(str, common),   # its alpha in PNG
                 "--out", str(tmp_path / "rgba" / "ft.%04d.png")])
    assert code == 0 and "with the plate's alpha" in capsys.readouterr().out
    changed_any = 0
    for i in range(len(frames)):
        rgba = _png(tmp_path / "rgba" / f"ft.{1001 + i:04d}.png", alpha=True)
        assert np.array_equal(rgba[6:, :, :3], _png(tmp_path / f"png_{i:03d}.png")[6:])
        assert np.all(rgba[:6, :, :3] == 255)                 # above white: shown white
        assert np.all(rgba[..., 3] == round((100 + i) * 255 / 1023))
        got = read_dpx_image(tmp_path / "out" / f"ft.{1001 + i:04d}.dpx")
        src = read_dpx_image(tmp_path / "plate" / f"sh010.{1001 + i:04d}.dpx")
        rewritten = _png(tmp_path / f"png_{i:03d}.png")
        same = np.all(rewritten == frames[i], axis=2)
        assert np.array_equal(got.codes[same], src.codes[same])       # alpha too
        assert np.array_equal(got.codes[..., 3], src.codes[..., 3])
        assert np.array_equal(shown_dpx(got)[~same], rewritten[~same])  # shown as the rewrite
        assert src.codes[:6, :, :3].max() >= 800 and np.array_equal(got.codes[:6], src.codes[:6])
        assert got.spec.get_string_attribute("dpx:TimeCode") == f"01:00:00:{i:02d}"
        assert (got.bits, got.transfer) == (10, "Printing density")
        changed_any += int((~same).sum())
    assert changed_any > 1000


def _png(path: Path, alpha: bool = False) -> np.ndarray:
    import cv2

    if alpha:
        return cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGRA2RGBA)
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


@pytest.mark.parametrize("pix_fmt", ["gray", "rgb24", "rgba", "gray16le", "rgb48be",
                                     "rgba64le", "gbrp10le", "gbrp10be", "gbrp12le"])
def test_a_plate_written_by_ffmpeg_reads_as_ffmpeg_decodes_it(pix_fmt, tmp_path):
    """Another writer's DPX (ffmpeg's: 8, 10, 12 or 16 bits, luma, RGB or RGBA, either byte
    order; its 8 and 16-bit lines padded to a 32-bit word, which OpenImageIO itself does not
    read): the codes ffmpeg decodes, in widths whose lines need padding (30, 34) or not (32);
    an 8-bit one's frames the PNG it was made from."""
    import subprocess

    import cv2

    from facetransfer.io.ffmpeg import ffmpeg_exe

    rng = np.random.default_rng(6)
    grey = pix_fmt.startswith("gray")
    channels = 1 if grey else 4 if pix_fmt.startswith("rgba") else 3
    for w in (30, 32, 34):
        rgb = rng.integers(0, 256, (24, w, 1 if grey else 3), dtype=np.uint8)
        cv2.imwrite(str(tmp_path / f"c{w}.png"), rgb if grey else rgb[..., ::-1])
        dpx = tmp_path / f"f{w}.0001.dpx"
        subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(tmp_path / f"c{w}.png"),
                        "-pix_fmt", pix_fmt, str(dpx)], check=True)
        got = read_dpx_image(dpx)
        assert got.kind == "video" and got.codes.shape == (24, w, channels)
        deep = got.bits > 8
        raw = subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(dpx), "-f", "rawvideo",
                              "-pix_fmt", ({1: "gray16le", 3: "rgb48le", 4: "rgba64le"} if deep
                                           else {1: "gray", 3: "rgb24", 4: "rgba"})[channels],
                              "-"], check=True, capture_output=True).stdout
        want = np.frombuffer(raw, np.uint16 if deep else np.uint8).reshape(24, w, channels)
        assert np.array_equal(got.codes, want >> (16 - got.bits) if deep else want), w
        if not deep:
            frames, _ = read_video(tmp_path / f"f{w}.%04d.dpx")
            assert np.array_equal(frames[0], np.repeat(rgb, 3, axis=2) if grey else rgb)


def test_a_damaged_dpx_frame_is_one_line_naming_it(tmp_path):
    """A frame cut short: one line naming its file, exit status 2 (a fresh process, as a user
    runs it: no OpenImageIO report at the exit either)."""
    import os
    import subprocess

    rng = np.random.default_rng(7)
    for i in (1, 2, 3):
        write_dpx(tmp_path / f"p.{i:04d}.dpx", rng.integers(0, 256, (16, 24, 3), np.uint8))
    good = (tmp_path / "p.0001.dpx").read_bytes()
    (tmp_path / "p.0001.dpx").write_bytes(good[:len(good) - 200])
    exe = Path(sys.executable).with_name("facetransfer")
    res = subprocess.run([str(exe), "probe", str(tmp_path / "p.####.dpx")], capture_output=True,
                         text=True, env=dict(os.environ, FACETRANSFER_SEQUENCE_FPS="25"))
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("facetransfer probe: error: cannot read the DPX frame ")
    assert "p.0001.dpx (damaged: " in lines[0]
    res = subprocess.run([str(exe), "probe", str(tmp_path / "p.0002.dpx").replace("0002", "%04d")
                          .replace("p.%04d", "q.%04d")], capture_output=True, text=True)
    assert res.returncode == 2 and "no file matches it" in res.stderr

"""OpenEXR plates (facetransfer.io.exr): scene-linear frames shown through the sRGB curve to the
tracker, read as the frames they hold; a rewrite written as OpenEXR keeps every float it does
not change, bit for bit, and is the rewrite of the same frames in 8 bits where it does."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.exr import (ExrImage, exr_pixel_type, graded_frame, read_exr,  # noqa: E402
                                 read_exr_image, shown_frame, srgb_decode, srgb_encode,
                                 write_exr)
from facetransfer.io.video import VideoOptions, read_video, write_video  # noqa: E402
from test_transfer_cli import (clips, plate_and_video_rewrites,  # noqa: E402,F401 (fixture)
                               plate_transfer_args)


def test_the_srgb_curve_is_iec_61966_2_1_and_inverts_on_every_level():
    levels = np.arange(256, dtype=np.uint8)
    assert np.array_equal(srgb_encode(srgb_decode(levels)), levels)
    # the curve's points: its linear segment's end, mid grey, 128, and clipping
    assert srgb_encode(np.array([0.0031308, 0.2158605, 0.5, 1.0, 4.0, -0.5])).tolist() == \
        [10, 128, 188, 255, 255, 0]
    assert srgb_decode(np.array([0, 10, 128, 255])) == pytest.approx(
        [0.0, 10 / 255 / 12.92, ((128 / 255 + 0.055) / 1.055) ** 2.4, 1.0], rel=1e-6)
    # a renderer's NaN shows black, infinities clip
    assert srgb_encode(np.array([np.nan, np.inf, -np.inf])).tolist() == [0, 255, 0]
    # a half-float frame is shown by a table of every half value: the curve's own levels
    every = np.arange(65536, dtype=np.uint16).view(np.float16).reshape(256, 256, 1)
    every = np.repeat(every, 3, axis=2)
    assert np.array_equal(shown_frame(ExrImage(every)), srgb_encode(every.astype(np.float32)))
    # half floats hold every level closely enough to encode back to it
    assert np.array_equal(srgb_encode(srgb_decode(levels).astype(np.float16)), levels)


def test_exr_files_keep_their_floats_and_say_their_pixel_type(tmp_path):
    rng = np.random.default_rng(0)
    lin = (rng.random((30, 40, 3)) * 6 - 1).astype(np.float32)   # beyond [0, 1] both ways
    write_exr(tmp_path / "f.exr", lin)
    write_exr(tmp_path / "h.exr", lin.astype(np.float16))
    write_exr(tmp_path / "u.exr", srgb_encode(lin))
    assert [exr_pixel_type(tmp_path / f"{k}.exr") for k in "fhu"] == ["float", "half", "half"]
    assert np.array_equal(read_exr(tmp_path / "f.exr"), lin)
    assert np.array_equal(read_exr(tmp_path / "h.exr"), lin.astype(np.float16).astype(np.float32))
    assert np.array_equal(srgb_encode(read_exr(tmp_path / "u.exr")), srgb_encode(lin))
    (tmp_path / "x.exr").write_bytes(b"\x89PNG not an exr")
    with pytest.raises(VideoError, match="x.exr is not an OpenEXR file"):
        exr_pixel_type(tmp_path / "x.exr")
    with pytest.raises(VideoError, match="cannot read the OpenEXR frame .*x.exr"):
        read_exr(tmp_path / "x.exr")


def test_a_graded_frame_changes_only_what_the_rewrite_changed():
    rng = np.random.default_rng(1)
    plate = (rng.random((20, 30, 3)) * 3 - 0.2).astype(np.float32)
    shown = srgb_encode(plate)
    rewritten = shown.copy()
    rewritten[5:9, 10:20] = rng.integers(0, 256, (4, 10, 3), dtype=np.uint8)
    out = graded_frame(plate, shown, rewritten)
    changed = np.any(rewritten != shown, axis=2)
    assert changed.sum() > 30 and np.array_equal(out[~changed], plate[~changed])
    inside = (plate >= 0) & (plate <= 1)
    # the plate's part below a level, in levels: at most half of one
    level = np.where(plate <= 0.0031308, 12.92 * plate,
                     1.055 * np.abs(plate) ** (1 / 2.4) - 0.055) * 255
    detail = np.where(inside, level - shown, 0.0)
    assert np.abs(detail).max() <= 0.5 + 1e-4
    again = np.where(inside, 1.055 * np.abs(out) ** (1 / 2.4) - 0.055, 0) * 255
    big = inside & (out > 0.0031308) & changed[..., None]
    assert np.abs(again[big] - (rewritten + detail)[big]).max() < 1e-3
    assert np.array_equal(srgb_encode(out[changed]), rewritten[changed])  # shown as rewritten
    assert ((~inside) & changed[..., None]).sum() > 10    # some clipped, and not glowing:
    assert np.array_equal(out[(~inside) & changed[..., None]],
                          srgb_decode(rewritten)[(~inside) & changed[..., None]])


@pytest.fixture(scope="module")
def target(clips, tmp_path_factory):
    """The synthetic target's frames as a lossless video decodes them."""
    lossless = tmp_path_factory.mktemp("exr") / "target.mkv"
    write_video(lossless, read_video(clips["target"])[0], 25.0, options=VideoOptions(crf=0))
    return lossless, read_video(lossless)[0]


def _exr_plate(folder: Path, frames, bright_rows: int = 0) -> Path:
    """The frames as a half-float plate numbered from 1001, the top ``bright_rows`` three
    times brighter (beyond 1 where they were white), as a compositing package writes one:
    ZIP-compressed, with an alpha channel and an attribute of its own (its shot)."""
    import OpenEXR

    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        lin = srgb_decode(rgb)
        lin[:bright_rows] *= 3.0
        alpha = np.full(lin.shape[:2], 0.25 + i / 100, np.float16)
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
                  "shot": "sh010"}
        with OpenEXR.File(header, {"RGB": lin.astype(np.float16), "A": alpha}) as f:
            f.write(str(folder / f"sh010.{1001 + i:04d}.exr"))
    return folder / "sh010.####.exr"


def test_an_exr_plate_reads_as_the_frames_it_holds(target, tmp_path, capsys, monkeypatch):
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    _, frames = target
    plate = _exr_plate(tmp_path, frames)
    got, _ = read_video(plate)
    assert np.array_equal(got, frames)
    assert main(["probe", str(plate), "--sequence-fps", "25"]) == 0
    assert "OpenEXR, scene-linear: shown through the sRGB curve" in capsys.readouterr().out


def test_an_exr_plate_is_rewritten_in_its_own_floats(clips, target, quick_model_path, tmp_path,
                                                    capsys, monkeypatch):
    """Onto a half-float plate, the rewrite written as OpenEXR: numbered as the plate, half
    floats, every pixel the rewrite did not change the plate's float (highlights above 1
    included), every changed one the 8-bit rewrite of the same frames (a PNG sequence of the
    video) shown through the curve."""
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    lossless, frames = target
    plate = _exr_plate(tmp_path / "plate", frames, bright_rows=6)
    common = plate_transfer_args(clips, quick_model_path)
    said = plate_and_video_rewrites(plate, lossless, common, tmp_path, "exr", capsys)
    assert ", in the plate's floats, with its other channels, no audio" in said
    changed_any = 0
    for i in range(len(frames)):
        out = tmp_path / "out" / f"ft.{1001 + i:04d}.exr"
        assert exr_pixel_type(out) == "half"
        got = read_exr(out)
        src = read_exr(tmp_path / "plate" / f"sh010.{1001 + i:04d}.exr")
        rewritten = _png(tmp_path / f"png_{i:03d}.png")
        same = np.all(rewritten == frames[i], axis=2)
        assert np.array_equal(got[same], src[same])
        assert np.array_equal(srgb_encode(got[~same][:, None])[:, 0], rewritten[~same])
        assert src[:6].max() > 1.0 and np.array_equal(got[:6], src[:6])  # outside the face
        changed_any += int((~same).sum())
        # the rest of the plate's file as it was: its alpha, its attributes, its compression
        plate_file, out_file = (read_exr_image(tmp_path / "plate" / f"sh010.{1001 + i:04d}.exr"),
                                read_exr_image(out))
        assert np.array_equal(out_file.other["A"], plate_file.other["A"])
        assert out_file.header["shot"] == "sh010"
        assert out_file.header["compression"] == plate_file.header["compression"]
    assert changed_any > 1000


def _png(path: Path) -> np.ndarray:
    import cv2

    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _windowed(src: Path, dst: Path, data, shown) -> None:
    """``src`` with its header's data and display windows set to ``data`` and ``shown``
    (x0, y0, x1, y1): the same pixels, placed in a larger frame."""
    import struct

    b = bytearray(src.read_bytes())
    for name, box in ((b"dataWindow", data), (b"displayWindow", shown)):
        at = b.index(name + b"\0box2i\0") + len(name) + 7 + 4
        struct.pack_into("<4i", b, at, *box)
    dst.write_bytes(bytes(b))


def test_a_frame_cropped_to_its_content_is_placed_in_its_display_window(tmp_path):
    """Compositing packages write a frame's data window (its content's box) inside a larger
    display window: read, it is the display window with the data where it belongs."""
    rng = np.random.default_rng(2)
    lin = rng.random((30, 40, 3)).astype(np.float16).astype(np.float32)
    write_exr(tmp_path / "a.exr", lin)
    _windowed(tmp_path / "a.exr", tmp_path / "b.exr", (10, 0, 49, 29), (0, 0, 99, 79))
    got = read_exr(tmp_path / "b.exr")
    assert got.shape == (80, 100, 3)
    assert np.array_equal(got[0:30, 10:50], lin) and got[30:].max() == 0 == got[:, :10].max()
    _windowed(tmp_path / "a.exr", tmp_path / "c.exr", (-5, 0, 34, 29), (0, 0, 19, 9))
    assert np.array_equal(read_exr(tmp_path / "c.exr"), lin[:10, 5:25])   # beyond: cut
    for name in ("b", "c"):     # shown as its display window through the curve
        image = read_exr_image(tmp_path / f"{name}.exr")
        assert np.array_equal(shown_frame(image), srgb_encode(image.displayed()))
    # rewritten, the data window beyond the display window (overscan) is kept as it was
    over = read_exr_image(tmp_path / "c.exr")
    shown = over.displayed()
    again = over.with_rgb(shown + 1)
    assert np.array_equal(again.rgb[:10, 5:25], (shown + 1).astype(over.rgb.dtype))
    assert np.array_equal(again.rgb[10:], over.rgb[10:]) and \
        np.array_equal(again.rgb[:, :5], over.rgb[:, :5])


def test_a_damaged_exr_frame_is_one_line_naming_it(tmp_path):
    """A damaged frame of an OpenEXR plate: one line naming its file, exit status 2, and not
    OpenCV's own log line (in a fresh process, as a user runs it)."""
    import os
    import subprocess

    rng = np.random.default_rng(3)
    for i in (1, 2, 3):
        write_exr(tmp_path / f"p.{i:04d}.exr", rng.random((16, 24, 3)).astype(np.float16))
    good = (tmp_path / "p.0001.exr").read_bytes()
    (tmp_path / "p.0001.exr").write_bytes(good[:len(good) // 2])
    exe = Path(sys.executable).with_name("facetransfer")
    # probe: no model is loaded (a first run would say that it builds the default model)
    res = subprocess.run([str(exe), "probe", str(tmp_path / "p.####.exr")], capture_output=True,
                         text=True, env=dict(os.environ, FACETRANSFER_SEQUENCE_FPS="25"))
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert lines[0].startswith("facetransfer probe: error: cannot read the OpenEXR frame ")
    assert lines[0].endswith("p.0001.exr (damaged, or not RGB floats)")

"""A target's alpha (facetransfer.io.plate_alpha): an RGBA PNG or TIFF plate's carried into a
rewrite written as a PNG or TIFF sequence, a video's (ProRes 4444) into one written as ProRes,
frame by frame and unchanged; the colour the rewrite of the same frames without alpha; other
outputs (and TIFFs of associated alpha) said, once, to lose it."""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.plate_alpha import (PlateAlpha, keeps_alpha, plate_alpha,  # noqa: E402
                                         sequence_has_alpha, video_has_alpha)
from facetransfer.io.video import VideoOptions, VideoWriter, read_video, write_video  # noqa: E402
from facetransfer.io.video_sequence import open_sequence  # noqa: E402
from test_transfer_cli import clips, plate_transfer_args  # noqa: E402,F401 (the fixture)


def _imwrite_rgba(path: Path, rgb: np.ndarray, alpha: np.ndarray) -> None:
    """As a keyer writes it: a PNG, or a TIFF with unassociated (straight) alpha (Pillow's)."""
    from PIL import Image

    Image.fromarray(np.dstack([rgb, alpha])).save(path)


def _rgba_plate(folder: Path, frames, *, suffix: str = ".png", first: int = 1001) -> Path:
    """The frames as an RGBA sequence numbered from ``first``, as a keyer writes one: each
    frame's alpha a ramp of its own (0 at the left edge, opaque in the middle)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, rgb in enumerate(frames):
        H, W = rgb.shape[:2]
        ramp = np.clip(np.arange(W) * 4 + i, 0, 255).astype(np.uint8)
        _imwrite_rgba(folder / f"sh010.{first + i:04d}{suffix}", rgb, np.tile(ramp, (H, 1)))
    return folder / f"sh010.%04d{suffix}"


def _read_rgba(path: Path) -> np.ndarray:
    """The stored RGBA (Pillow: OpenCV premultiplies a straight TIFF's colour)."""
    from PIL import Image

    with Image.open(path) as im:
        assert im.mode == "RGBA", (path, im.mode)
        return np.asarray(im)


def test_what_keeps_alpha_and_which_plates_have_it(tmp_path):
    frames = np.full((2, 8, 10, 3), 90, np.uint8)
    plate = _rgba_plate(tmp_path / "a", frames)
    opaque = tmp_path / "b"
    opaque.mkdir()
    import cv2

    for k in (1, 2):
        cv2.imwrite(str(opaque / f"o.{k:04d}.png"), frames[0])
    assert sequence_has_alpha(open_sequence(plate))
    assert not sequence_has_alpha(open_sequence(opaque / "o.%04d.png"))
    for out, keeps in (("o/%04d.png", True), ("o/f.%05d.PNG", True), ("o/%04d.tif", True),
                       ("o/%04d.TIFF", True), ("o/%04d.dpx", True), ("o/%04d.jpg", False),
                       ("o/%04d.exr", False),
                       ("o.mov", False), ("o.png", False)):
        assert keeps_alpha(out) is keeps, out
    assert isinstance(plate_alpha(tmp_path / "r.%04d.png", plate), PlateAlpha)
    assert isinstance(plate_alpha(tmp_path / "r.%04d.dpx", plate), PlateAlpha)
    hashes = Path(str(plate).replace("%04d", "####"))     # a plate named as packages name it
    assert isinstance(plate_alpha(tmp_path / "r.%04d.png", hashes), PlateAlpha)
    assert plate_alpha(tmp_path / "r.%04d.jpg", plate) is None
    assert plate_alpha(tmp_path / "r.mp4", plate) is None
    assert plate_alpha(tmp_path / "r.%04d.png", opaque / "o.%04d.png") is None
    assert plate_alpha(tmp_path / "r.%04d.png", None) is None
    # a TIFF with straight alpha: carried; one whose alpha is associated (its colour stored
    # premultiplied, ExtraSamples 1): not
    tiff = _rgba_plate(tmp_path / "t", frames, suffix=".tif")
    assert isinstance(plate_alpha(tmp_path / "r.%04d.png", tiff), PlateAlpha)
    _associate(tiff, 2)
    assert sequence_has_alpha(open_sequence(tiff))
    assert plate_alpha(tmp_path / "r.%04d.tif", tiff) is None


def _associate(pattern: Path, n: int) -> None:
    """Mark the first ``n`` TIFF frames' alpha associated (ExtraSamples 1 in place of 2)."""
    from PIL import Image

    for i in range(n):
        f = Path(str(pattern) % (1001 + i))
        with Image.open(f) as im:
            off = next(o for o in _tag_offsets(f) if o[0] == 338)[1]
        data = bytearray(f.read_bytes())
        assert data[off:off + 2] in (b"\x02\x00", b"\x00\x02")
        data[off:off + 2] = b"\x01\x00" if data[off] == 2 else b"\x00\x01"
        f.write_bytes(bytes(data))
        with Image.open(f) as im:
            assert im.tag_v2.get(338) == (1,)


def _tag_offsets(f: Path):
    """``(tag, offset of its inline value)`` of a little- or big-endian TIFF's first IFD."""
    import struct

    b = f.read_bytes()
    e = "<" if b[:2] == b"II" else ">"
    ifd = struct.unpack(e + "I", b[4:8])[0]
    n = struct.unpack(e + "H", b[ifd:ifd + 2])[0]
    for k in range(n):
        at = ifd + 2 + 12 * k
        yield struct.unpack(e + "H", b[at:at + 2])[0], at + 8


def test_a_straight_tiff_plate_reads_as_stored(tmp_path, monkeypatch):
    """OpenCV reads an RGBA TIFF with unassociated alpha premultiplied; the sequence reader
    gives its stored colour (before: semi-transparent pixels darker than stored); an
    associated one's stored colour is read as it is stored too."""
    import cv2

    from facetransfer.io.frame_file import tiff_alpha_kind

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (2, 6, 10, 3), dtype=np.uint8)
    plate = _rgba_plate(tmp_path / "t", frames, suffix=".tif")
    first = Path(str(plate) % 1001)
    assert tiff_alpha_kind(first) == "straight"
    premultiplied = cv2.imread(str(first), cv2.IMREAD_COLOR)[..., ::-1]
    assert not np.array_equal(premultiplied, frames[0])  # OpenCV's own reading
    assert np.array_equal(read_video(plate)[0], frames)
    _associate(plate, 2)
    assert tiff_alpha_kind(first) == "premultiplied"
    as_opencv = [cv2.imread(str(plate) % (1001 + i))[..., ::-1] for i in range(2)]
    assert np.array_equal(read_video(plate)[0], np.stack(as_opencv))  # read as before


def test_plate_alpha_reads_8_and_16_bit_alpha_and_checks_the_size(tmp_path):
    import cv2

    (tmp_path / "p").mkdir()
    rgb = np.random.default_rng(0).integers(0, 256, (6, 5, 3), dtype=np.uint8)
    a16 = np.array([[0, 257, 32767, 65535, 128]] * 6, np.uint16)
    cv2.imwrite(str(tmp_path / "p" / "f.0001.png"), np.dstack([rgb.astype(np.uint16) * 257, a16]))
    cv2.imwrite(str(tmp_path / "p" / "f.0002.png"), rgb)   # a frame without alpha: opaque
    cv2.imwrite(str(tmp_path / "p" / "f.0003.png"), np.zeros((4, 5, 4), np.uint8))
    pa = PlateAlpha(tmp_path / "p" / "f.%04d.png")
    out = pa(0, rgb, rgb)
    assert out.dtype == np.uint8 and out.shape == (6, 5, 4)
    assert np.array_equal(out[..., :3], rgb)
    assert out[0, :, 3].tolist() == [0, 1, 127, 255, 0]  # 16-bit alpha rounded to 8 bits
    assert np.array_equal(pa(1, rgb, rgb)[..., 3], np.full((6, 5), 255, np.uint8))
    with pytest.raises(VideoError, match=r"f\.0003\.png of the plate is 5x4, the rewrite 5x6"):
        pa(2, rgb, rgb)


def test_an_rgba_frame_is_written_only_where_the_output_holds_alpha(tmp_path):
    rgba = np.random.default_rng(1).integers(0, 256, (2, 6, 8, 4), dtype=np.uint8)
    for pattern in ("s/%03d.png", "t/%03d.tif"):
        out = write_video(tmp_path / pattern, rgba, 25.0)
        for i in range(2):
            assert np.array_equal(_read_rgba(Path(str(out) % i)), rgba[i]), pattern
    for pattern in ("j/%03d.jpg", "v.mp4"):
        with pytest.raises(VideoError, match=r"frame of shape \(6, 8, 4\) does not match"), \
                VideoWriter(tmp_path / pattern, 25.0, (8, 6)) as w:
            w.write(rgba[0])
    with pytest.raises(VideoError, match=r"16-bit frames are written to PNG or TIFF"), \
            VideoWriter(tmp_path / "w.mp4", 25.0, (8, 6)) as w:
        w.write(rgba[0, ..., :3].astype(np.uint16) * 257)   # not wrapped to 8 bits unsaid


@pytest.mark.parametrize("cache,suffix", [("on", ".png"), ("off", ".png"), ("on", ".tif")])
def test_a_transfer_onto_an_rgba_plate_keeps_its_alpha(clips, quick_model_path, tmp_path,
                                                       capsys, caplog, monkeypatch, cache,
                                                       suffix):
    """Onto an RGBA PNG plate numbered from 1001, written as a PNG sequence (through the
    render cache's frames, and straight to the pattern without it): every
    frame's alpha the plate's, bit for bit; its colour the rewrite of the same frames without
    alpha (a lossless video of them); numbered as the plate; no warning. Written as JPEG:
    colour only, and the warning says so."""
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", cache)
    lossless = tmp_path / "target.mkv"
    write_video(lossless, read_video(clips["target"])[0], 25.0, options=VideoOptions(crf=0))
    frames = read_video(lossless)[0]
    plate = _rgba_plate(tmp_path / "plate", frames, suffix=suffix)
    assert np.array_equal(read_video(plate)[0], frames)  # the colour read as stored
    common = plate_transfer_args(clips, quick_model_path)
    (tmp_path / "out").mkdir()
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        code = main(["transfer", "--target", str(plate), *map(str, common),
                     "--out", str(tmp_path / "out" / f"ft.%04d{suffix}")])
        out = capsys.readouterr()
        assert code == 0, out.err
        assert ", with the plate's alpha, no audio" in out.out  # the summary line says it
        assert not [r for r in caplog.records if "alpha" in r.getMessage()]
        code = main(["transfer", "--target", str(lossless), *map(str, common),
                     "--out", str(tmp_path / "png_%03d.png")])
        assert code == 0, capsys.readouterr().err
        code = main(["transfer", "--target", str(plate), *map(str, common),
                     "--out", str(tmp_path / "jpg" / "ft.%04d.jpg")])
        out = capsys.readouterr()
        assert code == 0, out.err
        assert "alpha" not in out.out
    said = [r.getMessage() for r in caplog.records if "has an alpha" in r.getMessage()]
    assert said == [f"{plate} has an alpha channel; the result is written without one (colour "
                    "only; transfer keeps a plate's in a PNG, TIFF or DPX sequence, not in a "
                    "video)"]
    changed = 0
    for i in range(len(frames)):
        got = _read_rgba(tmp_path / "out" / f"ft.{1001 + i:04d}{suffix}")
        src = _read_rgba(tmp_path / "plate" / f"sh010.{1001 + i:04d}{suffix}")
        rewritten = _read_rgba_or_rgb(tmp_path / f"png_{i:03d}.png")
        assert np.array_equal(got[..., 3], src[..., 3])
        assert np.array_equal(got[..., :3], rewritten)
        changed += int((rewritten != frames[i]).any(axis=2).sum())
    assert changed > 1000  # the face was rewritten


def _read_rgba_or_rgb(path: Path) -> np.ndarray:
    import cv2

    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _prores_4444(path: Path, rgba: np.ndarray, fps: float = 25.0) -> Path:
    """``rgba`` (F, H, W, 4) as ProRes 4444 with its alpha plane in 16 bits."""
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe

    F, H, W, _ = rgba.shape
    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgba", "-s",
                    f"{W}x{H}", "-r", str(fps), "-i", "-", "-c:v", "prores_ks", "-profile:v", "4",
                    "-pix_fmt", "yuva444p10le", "-alpha_bits", "16", str(path)],
                   input=np.ascontiguousarray(rgba).tobytes(), check=True)
    return path


def _video_alpha16(path: Path, size: tuple[int, int]) -> np.ndarray:
    """Every frame's alpha plane of a video, (F, H, W) uint16, as ffmpeg decodes it."""
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe

    W, H = size
    raw = subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(path), "-vf", "alphaextract",
                          "-f", "rawvideo", "-pix_fmt", "gray16le", "-"],
                         capture_output=True, check=True).stdout
    return np.frombuffer(raw, "<u2").reshape(-1, H, W)


def test_video_alpha_reads_each_frames_alpha_in_any_order_a_few_ahead(tmp_path):
    from facetransfer.io.plate_alpha import VideoAlpha

    rng = np.random.default_rng(2)
    rgba = rng.integers(0, 256, (6, 16, 24, 4), dtype=np.uint8)
    mov = _prores_4444(tmp_path / "a.mov", rgba)
    assert video_has_alpha(mov)
    assert not video_has_alpha(write_video(tmp_path / "o.mp4", rgba[..., :3], 25.0))
    va = VideoAlpha(mov, start=1)
    got = {i: va.alpha(i) for i in (2, 1, 4, 3)}   # as two threads a few frames ahead ask
    for i, a in got.items():
        assert np.array_equal(a, rgba[i, ..., 3]), i
    with pytest.raises(VideoError, match="frame 2 .* was read already"):
        va.alpha(2)
    out = va(5, None, rgba[5, ..., :3])
    assert np.array_equal(out, rgba[5])
    va.close()
    with pytest.raises(VideoError, match=r"alpha plane is written as ProRes 4444 only, not h264"):
        VideoOptions(alpha=True)


def test_a_transfer_onto_a_prores_4444_target_keeps_its_alpha(clips, quick_model_path, tmp_path,
                                                              capsys, caplog):
    """Onto a ProRes 4444 target with alpha, written with --codec prores (through the render
    cache's parts and without it): ProRes 4444, every frame's alpha the target's, bit for bit
    (in 8 bits); the colour the ProRes 422 rewrite of the same frames without alpha, up to
    the codecs; as a PNG sequence, RGBA frames with the same alpha; no warning. Written as H.264 (the default), colour only, and the warning says
    that ProRes keeps it."""
    from facetransfer.cli.main import main
    from facetransfer.io.video_display import described_input

    frames = read_video(clips["target"])[0]
    F, H, W, _ = frames.shape
    ramp = np.clip(np.arange(W)[None, :] * 3 + np.arange(F)[:, None], 0, 255).astype(np.uint8)
    alpha = np.broadcast_to(ramp[:, None, :], (F, H, W))
    target = _prores_4444(tmp_path / "target.mov", np.concatenate([frames, alpha[..., None]], 3))
    opaque = tmp_path / "opaque.mov"
    write_video(opaque, frames, 25.0, options=VideoOptions(codec="prores"))
    common = ["--target-track", clips["target_track"], "--expression-from", clips["source"],
              "--source-track", clips["source_track"], "--model", quick_model_path,
              "--no-progress", "--overwrite"]
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        for cache in ("on", "off"):
            os.environ["FACETRANSFER_RENDER_CACHE"] = cache
            try:
                out = tmp_path / f"r_{cache}.mov"
                assert main(["transfer", "--target", str(target), *map(str, common),
                             "--codec", "prores", "--out", str(out)]) == 0, \
                    capsys.readouterr().err
                assert ", in 10 of the target's 12 bits, with its alpha" in capsys.readouterr().out
            finally:
                os.environ.pop("FACETRANSFER_RENDER_CACHE")
            assert "prores (4444)" in described_input(out) and video_has_alpha(out)
            # in 16 bits (ProRes 4444 decodes in 12), as the target's decodes: to the bit
            assert np.array_equal(_video_alpha16(out, (W, H)), _video_alpha16(target, (W, H)))
        (tmp_path / "png").mkdir()   # as a PNG sequence: 16-bit RGBA frames, the same alpha
        assert main(["transfer", "--target", str(target), *map(str, common),
                     "--out", str(tmp_path / "png" / "r.%04d.png")]) == 0
        import cv2

        want = _video_alpha16(target, (W, H))
        for i in range(F):
            png = cv2.imread(str(tmp_path / "png" / f"r.{i:04d}.png"), cv2.IMREAD_UNCHANGED)
            assert png.dtype == np.uint16 and np.array_equal(png[..., 3], want[i])
        assert not [r for r in caplog.records if "has an alpha" in r.getMessage()]
        assert main(["transfer", "--target", str(opaque), *map(str, common),
                     "--codec", "prores", "--out", str(tmp_path / "plain.mov")]) == 0
        assert main(["transfer", "--target", str(target), *map(str, common),
                     "--out", str(tmp_path / "r.mp4")]) == 0
    said = [r.getMessage() for r in caplog.records if "has an alpha" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{target} has an alpha channel; the result "
                                                 "is written without one (colour only; "
                                                 "transfer keeps a video's in ProRes 4444")
    assert not video_has_alpha(tmp_path / "r.mp4")
    got, plain = read_video(tmp_path / "r_on.mov")[0], read_video(tmp_path / "plain.mov")[0]
    mse = np.mean((got.astype(np.float64) - plain) ** 2)
    assert 10 * np.log10(255.0 ** 2 / mse) > 38  # the same rewrite, 4444 against 422 HQ
    assert (got != frames).any(axis=3).sum() > 1000  # the face was rewritten

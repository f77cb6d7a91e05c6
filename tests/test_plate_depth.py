"""A 16-bit PNG or TIFF plate (facetransfer.io.plate_depth): rewritten as a 16-bit sequence,
every pixel the rewrite did not change is the plate's value to the bit, a changed one the 8-bit
rewrite with the plate's detail below 8 bits; grey stays grey, a PNG's 16-bit alpha stays as it
is; both kinds of file read in 8 bits as round(v / 257)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.plate_depth import PlateDepth, deep_frame, plate_depth  # noqa: E402
from facetransfer.io.video import VideoOptions, read_video, write_video  # noqa: E402
from test_transfer_cli import clips, plate_transfer_args  # noqa: E402,F401 (the fixture)


def _write16(path: Path, img: np.ndarray) -> None:
    """A 16-bit grey, RGB or RGBA frame (RGB order) through OpenCV."""
    import cv2

    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), img)


def _read16(path: Path) -> np.ndarray:
    import cv2

    if path.suffix == ".dpx":   # 16-bit codes of a video transfer (facetransfer.io.dpx)
        from facetransfer.io.dpx import read_dpx_image

        got = read_dpx_image(path)
        assert (got.bits, got.transfer) == (16, "ITU-R 709-4"), path
        return got.codes[..., 0] if got.codes.shape[2] == 1 else got.codes
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint16, path
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return img


def test_deep_frame_keeps_the_plate_where_nothing_changed():
    rng = np.random.default_rng(0)
    from facetransfer.io.frame_file import shown_16

    eight = lambda a: np.rint(a / 257.0).astype(np.uint8)  # noqa: E731 (round(v / 257))
    every = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    assert np.array_equal(shown_16(every)[..., 0], eight(every))
    assert np.array_equal(shown_16((np.arange(256, dtype=np.uint16) * 257)[None])[0, :, 1],
                          np.arange(256))
    plate = rng.integers(0, 65536, (5, 7, 3), dtype=np.uint16)
    plate[0, :3] = [[0, 65535, 128], [65535, 0, 65407], [127, 65408, 257]]  # the ends
    shown = eight(plate)
    rew = shown.copy()
    rew[1:3, 2:5] = rng.integers(0, 256, (2, 3, 3), dtype=np.uint8)
    rew[0, :3] = [[255, 0, 0], [0, 255, 255], [255, 0, 1]]
    out = deep_frame(plate, shown, rew)
    changed = (rew != shown).any(axis=2)
    assert np.array_equal(out[~changed], plate[~changed])
    assert np.array_equal(eight(out), rew)                     # reads back as the rewrite
    fine = plate.astype(int) - shown.astype(int) * 257         # the plate's own detail kept
    keep = (rew.astype(int) * 257 + fine >= 0) & (rew.astype(int) * 257 + fine <= 65535)
    assert np.array_equal((out.astype(int) - rew.astype(int) * 257)[keep], fine[keep])
    grey = plate[..., 0]
    out = deep_frame(grey, np.repeat(eight(grey)[..., None], 3, 2),
                     np.repeat(rew[..., :1], 3, 2))
    assert out.shape == grey.shape and np.array_equal(eight(out), rew[..., 0])
    rgba = np.dstack([plate, rng.integers(0, 65536, (5, 7), dtype=np.uint16)])
    out = deep_frame(rgba, shown, rew)
    assert np.array_equal(out[..., 3], rgba[..., 3]) and np.array_equal(eight(out[..., :3]), rew)


def test_which_plates_and_outputs_stay_16_bit(tmp_path):
    frames = np.full((2, 6, 8, 3), 40000, np.uint16)
    for name, img, suffix in (("rgb", frames[0], ".tif"), ("grey", frames[0, ..., 0], ".png"),
                              ("rgba", np.dstack([frames[0], frames[0, ..., 0]]), ".png"),
                              ("rgba_t", np.dstack([frames[0], frames[0, ..., 0]]), ".tif"),
                              ("eight", (frames[0] >> 8).astype(np.uint8), ".png")):
        (tmp_path / name).mkdir()
        for k in (1, 2):
            _write16(tmp_path / name / f"p.{k:04d}{suffix}", img) if img.dtype == np.uint16 \
                else __import__("cv2").imwrite(str(tmp_path / name / f"p.{k:04d}{suffix}"), img)
    pat = {n: next((tmp_path / n).glob("p.0001.*")).with_name(
        "p.%04d" + next((tmp_path / n).glob("p.0001.*")).suffix) for n in
        ("rgb", "grey", "rgba", "rgba_t", "eight")}
    assert isinstance(plate_depth(tmp_path / "o.%04d.png", pat["rgb"]), PlateDepth)
    assert isinstance(plate_depth(tmp_path / "o.%04d.tif", pat["grey"]), PlateDepth)
    assert isinstance(plate_depth(tmp_path / "o.%04d.png", pat["rgba"]), PlateDepth)
    assert plate_depth(tmp_path / "o.%04d.tif", pat["rgba"]) is None     # 8-bit RGBA TIFF
    assert isinstance(plate_depth(tmp_path / "o.%04d.dpx", pat["rgba"]), PlateDepth)
    assert isinstance(plate_depth(tmp_path / "o.%04d.dpx", pat["rgb"]), PlateDepth)
    assert plate_depth(tmp_path / "o.%04d.png", pat["rgba_t"]) is None
    assert plate_depth(tmp_path / "o.%04d.png", pat["eight"]) is None
    assert plate_depth(tmp_path / "o.%04d.jpg", pat["rgb"]) is None
    assert plate_depth(tmp_path / "o.mp4", pat["rgb"]) is None
    with pytest.raises(VideoError, match=r"16-bit plate .* is not 16-bit grey, RGB or RGBA"):
        __import__("cv2").imwrite(str(tmp_path / "rgb" / "p.0002.tif"),
                                  np.zeros((6, 8, 3), np.uint8))
        PlateDepth(pat["rgb"])(1, np.zeros((6, 8, 3), np.uint8), np.zeros((6, 8, 3), np.uint8))


@pytest.mark.parametrize("kind,suffix,out_suffix", [
    ("rgb", ".png", ".png"), ("rgb", ".tif", ".tif"), ("grey", ".tif", ".tif"),
    ("rgba", ".png", ".png"), ("rgba", ".png", ".dpx"), ("grey", ".tif", ".dpx")])
def test_a_transfer_onto_a_16_bit_plate_keeps_its_values(clips, quick_model_path, tmp_path,
                                                         capsys, monkeypatch, kind, suffix,
                                                         out_suffix):
    """Onto a 16-bit plate (the synthetic target's frames over low bytes of noise), written as
    a 16-bit sequence of the same kind or as DPX: every pixel the 8-bit rewrite of the same
    frames left unchanged is the plate's value to the bit (before: 8 bits, every pixel's low
    byte lost), every changed one the 8-bit rewrite over the plate's low byte; grey stays grey,
    a PNG's 16-bit alpha as it was."""
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    lossless = tmp_path / "target.mkv"
    frames = read_video(clips["target"])[0]
    if kind == "grey":   # a grey target: the rewrite greys what it changes
        frames = np.repeat(frames.mean(axis=3, keepdims=True).round().astype(np.uint8), 3, 3)
    write_video(lossless, frames, 25.0, options=VideoOptions(crf=0, codec="h264"))
    frames = read_video(lossless)[0]
    rng = np.random.default_rng(4)
    (tmp_path / "plate").mkdir()
    plates = []
    for i, rgb in enumerate(frames):   # detail below 8 bits: -128..128 around each level
        fine = rng.integers(-128, 129, rgb.shape)
        p16 = np.clip(rgb.astype(np.int64) * 257 + fine, 0, 65535).astype(np.uint16)
        if kind == "grey":
            p16 = p16[..., 0]
        if kind == "rgba":
            p16 = np.dstack([p16, rng.integers(0, 65536, rgb.shape[:2], dtype=np.uint16)])
        _write16(tmp_path / "plate" / f"sh010.{1001 + i:04d}{suffix}", p16)
        plates.append(p16)
    plate = tmp_path / "plate" / f"sh010.%04d{suffix}"
    shown = read_video(plate)[0]
    if kind != "grey":
        assert np.array_equal(shown, frames)   # the plate's high bytes, as the tool sees it
    common = plate_transfer_args(clips, quick_model_path)
    (tmp_path / "out").mkdir()
    assert main(["transfer", "--target", str(plate), *map(str, common),
                 "--out", str(tmp_path / "out" / f"ft.%04d{out_suffix}")]) == 0, \
        capsys.readouterr().err
    said = capsys.readouterr().out   # the summary line says what was kept
    assert ", in the plate's 16 bits" + (", with its alpha" if kind == "rgba" else "") + \
        ", no audio" in said
    assert main(["transfer", "--target", str(plate), *map(str, common), "--out",
                 str(tmp_path / "eight" / "ft.%04d.jpg")]) == 0   # 8 bits: the same rewrite
    changed_any = 0
    for i in range(len(frames)):
        got = _read16(tmp_path / "out" / f"ft.{1001 + i:04d}{out_suffix}")
        assert got.shape == plates[i].shape
        colour, plate_colour = (got, plates[i]) if got.ndim == 2 else (got[..., :3],
                                                                       plates[i][..., :3])
        high = np.rint(colour / 257.0).astype(np.uint8)
        seen = shown[i][..., 0] if got.ndim == 2 else shown[i]
        same = high == seen if got.ndim == 2 else (high == seen).all(axis=2)
        assert np.array_equal(colour[same], plate_colour[same])       # the plate, to the bit
        fine_in = plate_colour.astype(int) - np.rint(plate_colour / 257.0).astype(int) * 257
        fine_out = colour.astype(int) - high.astype(int) * 257        # its detail everywhere
        inside = (high > 0) & (high < 255)                            # (clipped at the ends)
        assert np.array_equal(fine_out[inside], fine_in[inside])
        if kind == "rgba":
            assert np.array_equal(got[..., 3], plates[i][..., 3])
        changed_any += int((~same).sum())
    assert changed_any > 1000   # the face was rewritten


def test_probe_says_what_a_rewrite_keeps_of_a_plate(tmp_path, monkeypatch):
    """``probe`` names a plate's depth and alpha, and a video's alpha plane, with what a
    rewrite keeps of them; an 8-bit opaque plate and an opaque video say neither."""
    import cv2

    from facetransfer.io.video_facts import fact_lines, video_facts

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    for name, img in (("deep", np.full((8, 8, 4), 40000, np.uint16)),
                      ("flat", np.full((8, 8, 3), 90, np.uint8))):
        (tmp_path / name).mkdir()
        for k in (1, 2):
            cv2.imwrite(str(tmp_path / name / f"p.{k:04d}.png"), img)
    deep = video_facts(tmp_path / "deep" / "p.%04d.png")
    assert (deep.bits, deep.alpha) == (16, True)
    assert fact_lines(deep)[-1] == ("  RGB images, 16 bits, seen in 8 (a PNG or DPX sequence "
                                    "written from it stays 16-bit, with its alpha; a TIFF one "
                                    "is 8-bit); alpha: kept by transfer in a PNG, TIFF or DPX "
                                    "sequence; no audio")
    flat = video_facts(tmp_path / "flat" / "p.%04d.png")
    assert (flat.bits, flat.alpha) == (8, False)
    assert fact_lines(flat)[-1] == "  RGB images, 8 bits; no audio"
    rgba = np.random.default_rng(5).integers(0, 256, (3, 16, 24, 4), dtype=np.uint8)
    from test_plate_alpha import _prores_4444

    mov = _prores_4444(tmp_path / "a.mov", rgba)
    assert video_facts(mov).alpha and fact_lines(video_facts(mov))[-1] == (
        "  alpha plane: kept by transfer in ProRes 4444 (--codec prores) or a PNG, TIFF or "
        "DPX sequence")
    plain = write_video(tmp_path / "o.mp4", rgba[..., :3], 25.0)
    assert not video_facts(plain).alpha
    assert not any("alpha" in ln for ln in fact_lines(video_facts(plain)))

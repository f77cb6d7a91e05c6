"""OpenEXR plates of other primaries than Rec.709's (facetransfer.io.primaries): ACES2065-1,
ACEScg, P3, Rec.2020 and Adobe RGB brought to linear Rec.709 as OpenColorIO's ACES
configuration brings them, shown to the tracker in their own colours, and a rewrite graded
back into the plate's primaries."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.io.exr import (graded_frame, read_exr, read_exr_image,  # noqa: E402
                                 srgb_decode, srgb_encode)
from facetransfer.io.primaries import REC709, named_chromaticities, to_rec709  # noqa: E402
from test_exr import target  # noqa: E402,F401 (the fixture)
from test_transfer_cli import (clips, plate_and_video_rewrites,  # noqa: E402,F401 (fixture)
                               plate_transfer_args)

#: OpenEXR's linear colour interop IDs and OpenColorIO's ACES configuration's names of them.
SPACES = {"lin_ap0_scene": "ACES2065-1", "lin_ap1_scene": "ACEScg",
          "lin_p3d65_scene": "Linear P3-D65", "lin_rec2020_scene": "Linear Rec.2020",
          "lin_adobergb_scene": "Linear AdobeRGB"}


def _ocio(rgb: np.ndarray, space: str) -> np.ndarray:
    """``rgb`` (H, W, 3) float32 of ``space`` as linear Rec.709, by OpenColorIO (OpenImageIO's
    built-in ACES configuration)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBufAlgo.colorconvert(oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32)),
                                         space, "Linear Rec.709 (sRGB)",
                                         colorconfig="ocio://default")
    return buf.get_pixels(oiio.FLOAT)


@pytest.mark.parametrize("interop", list(SPACES))
def test_the_matrices_are_opencolorios(interop):
    import OpenEXR

    chroma = OpenEXR.colorInteropIDToChromaticities(interop)
    rgb = np.random.default_rng(1).uniform(-0.2, 4.0, (8, 8, 3)).astype(np.float32)
    want = _ocio(rgb, SPACES[interop])
    got = rgb @ to_rec709(chroma).T.astype(np.float32)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    assert named_chromaticities({"colorInteropID": interop}) == tuple(chroma)


def test_rec709_and_nonsense_are_left_as_they_are():
    assert to_rec709(REC709) is None and to_rec709(None) is None
    assert to_rec709([0.64, 0.33, 0.3, 0.6, 0.15]) is None           # not eight numbers
    assert to_rec709([0.3] * 8) is None                              # no triangle
    assert named_chromaticities({}) is None
    assert named_chromaticities({"colorInteropID": "data"}) is None


def _plate(folder: Path, frames, how: str) -> tuple[Path, np.ndarray]:
    """The frames as a float OpenEXR plate in ACEScg (AP1) whose values show as the frames
    (decoded, brought from Rec.709 to AP1 by OpenColorIO), the primaries named ``how``:
    by ``chromaticities`` or by ``colorInteropID``."""
    import OpenEXR

    folder.mkdir(parents=True, exist_ok=True)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if how == "chromaticities":
        header["chromaticities"] = OpenEXR.colorInteropIDToChromaticities("lin_ap1_scene")
    else:
        header["colorInteropID"] = "lin_ap1_scene"
    to_709 = to_rec709(OpenEXR.colorInteropIDToChromaticities("lin_ap1_scene"))
    for i, rgb in enumerate(frames):
        ap1 = (srgb_decode(rgb).astype(np.float64) @ np.linalg.inv(to_709).T).astype(np.float32)
        with OpenEXR.File(header, {"RGB": ap1}) as f:
            f.write(str(folder / f"sh010.{1001 + i:04d}.exr"))
    return folder / "sh010.####.exr", to_709


@pytest.mark.parametrize("how", ["chromaticities", "colorInteropID"])
def test_an_acescg_plate_is_seen_in_its_own_colours(target, how, tmp_path, monkeypatch):
    """An ACEScg plate of the target's frames reads as those frames (what OpenColorIO makes
    of its values, through the sRGB curve); taken as Rec.709 (before) it read far off."""
    from facetransfer.io.video import read_video

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    _, frames = target
    plate, _ = _plate(tmp_path / how, frames, how)
    got, _ = read_video(plate)
    assert np.array_equal(got, frames)
    values = read_exr(tmp_path / how / "sh010.1001.exr")
    assert np.array_equal(srgb_encode(_ocio(values, "ACEScg")), frames[0])
    assert np.abs(srgb_encode(values).astype(int) - frames[0]).mean() > 3   # seen as Rec.709


def test_a_graded_frame_of_other_primaries_shows_the_rewrite():
    """Changed pixels brought back into the plate's primaries show (in Rec.709, through the
    curve) as the rewrite; unchanged ones are the plate's floats to the bit."""
    rng = np.random.default_rng(3)
    m = to_rec709((0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767))   # AP1
    plate = rng.uniform(0.02, 0.7, (16, 16, 3)).astype(np.float32)
    shown = srgb_encode(plate @ m.T.astype(np.float32))
    rewritten = shown.copy()
    rewritten[4:9, 3:12] = rng.integers(20, 230, (5, 9, 3))
    got = graded_frame(plate, shown, rewritten, m)
    same = np.all(rewritten == shown, axis=2)
    assert np.array_equal(got[same], plate[same])
    assert np.array_equal(srgb_encode(got @ m.T.astype(np.float32))[~same], rewritten[~same])


def test_an_acescg_plate_is_rewritten_in_its_primaries(clips, target, quick_model_path,
                                                      tmp_path, capsys, monkeypatch):
    """Onto an ACEScg plate, the rewrite written as OpenEXR: every pixel the rewrite did not
    change the plate's float, every changed one in ACEScg showing as the 8-bit rewrite of
    the same frames (a PNG sequence of the video); the header's primaries kept."""
    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")
    lossless, frames = target
    plate, to_709 = _plate(tmp_path / "plate", frames, "colorInteropID")
    plate_and_video_rewrites(plate, lossless, plate_transfer_args(clips, quick_model_path),
                             tmp_path, "exr", capsys)
    changed = 0
    for i in range(len(frames)):
        got = read_exr_image(tmp_path / "out" / f"ft.{1001 + i:04d}.exr")
        src = read_exr(tmp_path / "plate" / f"sh010.{1001 + i:04d}.exr")
        rewritten = _png(tmp_path / f"png_{i:03d}.png")
        same = np.all(rewritten == frames[i], axis=2)
        assert np.array_equal(got.rgb[same], src[same])
        shown = srgb_encode(got.rgb[~same] @ to_709.T.astype(np.float32))
        assert np.array_equal(shown, rewritten[~same])
        assert got.header["colorInteropID"] == "lin_ap1_scene"
        changed += int((~same).sum())
    assert changed > 1000


def _png(path: Path) -> np.ndarray:
    import cv2

    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def test_probe_names_a_plates_primaries(target, tmp_path, capsys, monkeypatch):
    from facetransfer.cli.main import main

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")  # undone after (the CLI sets it)
    _, frames = target
    plate, _ = _plate(tmp_path / "p", frames[:2], "chromaticities")
    assert main(["probe", str(plate), "--sequence-fps", "25"]) == 0
    assert "OpenEXR, scene-linear in the primaries lin_ap1_scene (brought to Rec.709's first)" \
        in capsys.readouterr().out

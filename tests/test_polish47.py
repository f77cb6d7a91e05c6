"""Forty-seventh session, helper polish47: ``texture blend`` keeps a target's alpha,
``synth-video --texture`` is held to a square image as ``export --texture`` is, a CMYK JPEG is
not taken as carrying alpha, and the performance spec's keys are one constant
(BENCHMARKS.md, "Forty-seventh session (helper polish47)")."""

from __future__ import annotations

import logging
import re

import cv2
import numpy as np

from facetransfer.cli.main import main


def _blend_case(tmp_path):
    """An RGBA target (8 and 16 bits: a ramp of alpha, random colour), a source and a mask."""
    rng = np.random.default_rng(4)
    bgra = rng.integers(0, 256, (40, 50, 4), dtype=np.uint8)
    bgra[..., 3] = (np.arange(50) * 5)[None].astype(np.uint8)
    assert cv2.imwrite(str(tmp_path / "t8.png"), bgra)
    assert cv2.imwrite(str(tmp_path / "t16.png"), bgra.astype(np.uint16) * 257 + 3)
    assert cv2.imwrite(str(tmp_path / "s.png"), rng.integers(0, 256, (40, 50, 3), np.uint8))
    m = np.zeros((40, 50), np.uint8)
    m[10:30, 10:40] = 255
    assert cv2.imwrite(str(tmp_path / "m.png"), m)
    return m


def test_texture_blend_keeps_the_target_s_alpha(tmp_path, caplog, capsys):
    """An RGBA PNG target gives an RGBA PNG whose alpha is the target's, every pixel (8-bit:
    as stored; 16-bit: as stored, in the 16-bit output), its colour off the mask the target's
    (before: RGB, the alpha dropped, said nowhere); an 8-bit alpha beside a 16-bit result is
    ``x 257``; a .jpg out is written without it and says so once, naming the target."""
    m = _blend_case(tmp_path)
    common = ["texture", "blend", "--source", str(tmp_path / "s.png"), "--mask",
              str(tmp_path / "m.png")]
    for name in ("t8", "t16"):
        t = cv2.imread(str(tmp_path / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        out = tmp_path / f"o_{name}.png"
        capsys.readouterr()
        assert main(common + ["--target", str(tmp_path / f"{name}.png"), "--out", str(out)]) == 0
        assert "the target's alpha kept" in capsys.readouterr().out
        o = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
        assert o.shape == (40, 50, 4) and o.dtype == t.dtype, (o.shape, o.dtype)
        assert np.array_equal(o[..., 3], t[..., 3])
        assert np.array_equal(o[m == 0], t[m == 0])
        assert not np.array_equal(o[m > 0][:, :3], t[m > 0][:, :3])   # the blend did paste
    deep_src = tmp_path / "s16.png"        # a 16-bit source into the 8-bit target: 8 bits out
    assert cv2.imwrite(str(deep_src), cv2.imread(str(tmp_path / "s.png")).astype(np.uint16) * 257)
    assert main(["texture", "blend", "--source", str(deep_src), "--mask", str(tmp_path / "m.png"),
                 "--target", str(tmp_path / "t8.png"), "--out", str(tmp_path / "o8.png")]) == 0
    o8 = cv2.imread(str(tmp_path / "o8.png"), cv2.IMREAD_UNCHANGED)
    t8 = cv2.imread(str(tmp_path / "t8.png"), cv2.IMREAD_UNCHANGED)
    assert o8.dtype == np.uint8 and np.array_equal(o8[..., 3], t8[..., 3])
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(common + ["--target", str(tmp_path / "t8.png"),
                              "--out", str(tmp_path / "o.jpg")]) == 0
    assert cv2.imread(str(tmp_path / "o.jpg"), cv2.IMREAD_UNCHANGED).shape == (40, 50, 3)
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
        f"target {tmp_path / 't8.png'} has alpha; {tmp_path / 'o.jpg'} holds none: written "
        "without it (give a .png to keep it)"]


def test_texture_blend_of_an_8_bit_alpha_beside_a_16_bit_result_scales_it(tmp_path):
    """The alpha goes in the result's bits: an 8-bit RGBA target with a 16-bit source stays 8
    (the target's depth), and :func:`facetransfer.cli.texture._with_alpha` puts an 8-bit alpha
    beside a 16-bit result ``x 257`` (255 -> 65535), a 16-bit one beside 8 bits rounded."""
    from facetransfer.cli.texture import _with_alpha

    _blend_case(tmp_path)
    a8 = cv2.imread(str(tmp_path / "t8.png"), cv2.IMREAD_UNCHANGED)[..., 3]
    res16 = np.zeros((40, 50, 3), np.uint16)
    got = _with_alpha(res16, str(tmp_path / "t8.png"), tmp_path / "o.png")
    assert got.dtype == np.uint16 and np.array_equal(got[..., 3], a8.astype(np.uint16) * 257)
    got = _with_alpha(np.zeros((40, 50, 3), np.uint8), str(tmp_path / "t16.png"),
                      tmp_path / "o.png")
    assert got.dtype == np.uint8 and np.array_equal(got[..., 3], a8)   # (a x 257 + 3) / 257


def test_texture_blend_of_an_rgba_tiff_target_keeps_its_stored_colour_and_alpha(tmp_path,
                                                                              caplog):
    """An 8-bit RGBA TIFF of straight alpha (what Pillow writes) is blended in its stored
    colour, and its alpha kept beside it (before: OpenCV's reader premultiplied the colour,
    the blend darkened where the alpha is low, and the PNG was written without alpha). One
    whose alpha is associated (colour stored premultiplied) is written without it, said in one
    warning naming the target."""
    from PIL import Image

    from test_plate_alpha import _tag_offsets

    m = _blend_case(tmp_path)
    alpha = np.tile((np.arange(50) * 5).astype(np.uint8), (40, 1))
    rgba = np.dstack([np.full((40, 50, 3), 200, np.uint8), alpha])
    Image.fromarray(rgba, "RGBA").save(tmp_path / "t.tif")
    args = ["texture", "blend", "--source", str(tmp_path / "s.png"), "--mask",
            str(tmp_path / "m.png"), "--target", str(tmp_path / "t.tif")]
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(args + ["--out", str(tmp_path / "o.png")]) == 0
    assert [r for r in caplog.records if r.levelname == "WARNING"] == []
    o = cv2.imread(str(tmp_path / "o.png"), cv2.IMREAD_UNCHANGED)
    assert o.shape == (40, 50, 4) and np.array_equal(o[..., 3], alpha)
    assert (o[..., :3][m == 0] == 200).all()          # before: 200 x alpha / 255
    # the same file with its alpha marked associated (ExtraSamples 1)
    f = tmp_path / "t.tif"
    off = next(o for o in _tag_offsets(f) if o[0] == 338)[1]
    data = bytearray(f.read_bytes())
    data[off:off + 2] = b"\x01\x00" if data[off] == 2 else b"\x00\x01"
    f.write_bytes(bytes(data))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(args + ["--out", str(tmp_path / "p.png")]) == 0
    assert cv2.imread(str(tmp_path / "p.png"), cv2.IMREAD_UNCHANGED).shape == (40, 50, 3)
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
        f"target {f} has alpha; its colour is stored premultiplied (a TIFF's associated "
        "alpha): written without it"]


def test_synth_video_refuses_a_texture_that_is_not_square(arkit_model_path, tmp_path, capsys):
    """``synth-video --texture`` renders the image as the model's UV texture: a picture that is
    not square is refused in one line naming the file and what was expected, the check of
    ``export --texture`` (before: rendered, stretched over the UVs); nothing is written."""
    sheet = tmp_path / "sheet.png"
    assert cv2.imwrite(str(sheet), np.full((30, 80, 3), 90, np.uint8))
    out = tmp_path / "c.mp4"
    capsys.readouterr()
    assert main(["synth-video", "--model", str(arkit_model_path), "--random", "--frames", "1",
                 "--size", "64x48", "--texture", str(sheet), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"facetransfer synth-video: error: --texture {sheet} is 80x30: a texture of the "
        "model's UVs is a square image in their layout (as `facetransfer texture default` or "
        "`texture lift` writes it, e.g. 512x512)"]
    assert not out.exists()


def test_a_cmyk_jpeg_is_not_taken_as_carrying_alpha(tmp_path, caplog):
    """A CMYK JPEG (Pillow's), which ffmpeg decodes as ``gbrap``, has no alpha (its fourth
    channel is black): before, :func:`video_has_alpha` said it had, and a transfer onto it
    warned that its alpha would be dropped. An RGBA PNG still has alpha."""
    from PIL import Image

    from facetransfer.io.plate_alpha import video_has_alpha
    from facetransfer.io.video_facts import fact_lines, video_facts
    from facetransfer.io.video_like import like_video
    from facetransfer.io.video_planes import stored_pixel_format

    cmyk, rgba = tmp_path / "c.jpg", tmp_path / "a.png"
    Image.fromarray(np.full((32, 32, 4), (10, 200, 30, 40), np.uint8), "CMYK").save(cmyk)
    Image.fromarray(np.full((32, 32, 4), (10, 200, 30, 40), np.uint8), "RGBA").save(rgba)
    assert stored_pixel_format(cmyk).startswith(("gbrap", "cmyk"))
    assert not video_has_alpha(cmyk)
    assert not video_facts(cmyk).alpha
    assert "colour stored as CMYK, read as RGB" in "\n".join(fact_lines(video_facts(cmyk)))
    assert video_has_alpha(rgba) and video_facts(rgba).alpha
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        like_video(None, cmyk, tmp_path / "o.mp4")
    assert not [r for r in caplog.records if r.levelname == "WARNING"]   # before: "has an alpha"


def test_the_spec_keys_are_the_parser_s(arkit_model):
    """:data:`facetransfer.synth.SPEC_KEYS` is what the parser takes: each key of it is taken
    where it belongs, one beside them is refused naming the constant's keys."""
    import pytest

    from facetransfer.synth import SPEC_KEYS, SpecError, performance_from_spec

    values = {"n_frames": 3, "fps": 25, "size": [64, 48], "identity": "id01", "tracks": {},
              "pose": {}, "yaw_deg": 5, "pitch_deg": 2, "roll_deg": 1, "translate_px": 3,
              "scale": 0.1, "period_s": 2, "fill": 0.5, "tx": 1, "ty": 2}
    for key in SPEC_KEYS["spec"]:
        performance_from_spec(arkit_model, {key: values[key]})
    for key in SPEC_KEYS["pose"]:
        pose = {"keys": [[0, {}]]} if key == "keys" else {key: values[key]}
        performance_from_spec(arkit_model, {"n_frames": 3, "pose": pose})
    for key in SPEC_KEYS["pose.keys"]:
        performance_from_spec(arkit_model, {"pose": {"keys": [[0, {key: values[key]}]]}})
    with pytest.raises(SpecError, match=r"known: \['fill', 'keys', 'period_s'"):
        performance_from_spec(arkit_model, {"pose": {"tx": 1}})
    with pytest.raises(SpecError, match=rf"known: {re.escape(str(sorted(SPEC_KEYS['spec'])))}"):
        performance_from_spec(arkit_model, {"frames": 3})


def test_the_help_reads_the_keys_without_the_renderer():
    """The command line's parser names the spec's keys (:mod:`facetransfer.synth_keys`, which
    :mod:`facetransfer.synth` re-exports) without importing :mod:`facetransfer.synth` and its
    renderer at start-up (about 0.17 s more a command when it did, seen while mending)."""
    import subprocess
    import sys

    import facetransfer.synth as synth
    import facetransfer.synth_keys as keys

    assert synth.SPEC_KEYS is keys.SPEC_KEYS
    code = ("import sys\nfrom facetransfer.cli.main import build_parser\nbuild_parser()\n"
            "print('facetransfer.synth_keys' in sys.modules, 'facetransfer.synth' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["True", "False"], out


def test_texture_blend_keeps_a_grey_alpha_tiff_s_alpha_and_adds_none_to_a_cmyk_one(tmp_path,
                                                                                capsys):
    """An 8-bit grey + alpha TIFF target keeps its alpha beside the blend (before: OpenCV's
    reader dropped it, the PNG was written without it and nothing said so); a CMYK TIFF target,
    which holds no alpha, gets none (before: OpenCV gave it as BGRA, and the PNG gained an
    opaque alpha said to be "the target's alpha kept")."""
    from PIL import Image

    m = _blend_case(tmp_path)
    alpha = np.tile((np.arange(50) * 5).astype(np.uint8), (40, 1))
    Image.fromarray(np.dstack([np.full((40, 50), 200, np.uint8), alpha]), "LA").save(
        tmp_path / "la.tif")
    Image.fromarray(np.full((40, 50, 4), 60, np.uint8), "CMYK").save(tmp_path / "k.tif")
    for name, out in (("la.tif", "la.png"), ("k.tif", "k.png")):
        assert main(["texture", "blend", "--source", str(tmp_path / "s.png"), "--mask",
                     str(tmp_path / "m.png"), "--target", str(tmp_path / name),
                     "--out", str(tmp_path / out)]) == 0
    said = capsys.readouterr().out.splitlines()
    la = cv2.imread(str(tmp_path / "la.png"), cv2.IMREAD_UNCHANGED)
    assert la.shape == (40, 50, 4) and np.array_equal(la[..., 3], alpha)
    assert (la[..., :3][m == 0] == 200).all()        # stored, not premultiplied
    k = cv2.imread(str(tmp_path / "k.png"), cv2.IMREAD_UNCHANGED)
    assert k.shape == (40, 50, 3)
    assert "alpha kept" in said[0] and "alpha" not in said[1]

"""The matte of a transfer (``transfer --matte``, facetransfer.io.matte): 0 exactly where the
output is the plate's pixel to the bit, above 0 wherever the output differs from the plate;
written as 16-bit grey PNG / TIFF, float OpenEXR or a grey video, continued after an
interruption as the output is."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from _writing import interrupt_renders  # noqa: E402
from facetransfer import rewrite_clip as rc  # noqa: E402
from facetransfer import rewrite_options as rwo  # noqa: E402
from facetransfer.io.matte import (MatteError, MatteWriter, check_matte_output,  # noqa: E402
                                   matte_frame, matte_options)
from facetransfer.io.video import (VideoOptions, VideoWriter, read_video,  # noqa: E402
                                   write_video)
from facetransfer.transfer import recombine  # noqa: E402
import test_transfer_cli  # noqa: E402
import test_transfer_rewrite  # noqa: E402

run = test_transfer_cli.run
# the fixtures of the synthetic clips, shared
clips = test_transfer_cli.clips
topo, face_texture = test_transfer_rewrite.topo, test_transfer_rewrite.face_texture
synthetic = test_transfer_rewrite.synthetic

MODES = ("fast", "poisson", "none")


def _check_invariant(image, plate, matte) -> None:
    """Where ``matte`` is 0 the image is the plate's to the bit; where it differs, the matte
    is above 0 (``matte`` float or integer levels)."""
    changed = np.any(image != plate, axis=-1)
    assert changed.any()                        # the face was rewritten
    assert not (changed & (matte == 0)).any()   # every changed pixel is in the matte
    zero = matte == 0
    np.testing.assert_array_equal(image[zero], plate[zero])


@pytest.mark.parametrize("blend", MODES)
def test_the_matte_is_the_blend_s_alpha_and_changes_no_pixel(quick_model, topo, synthetic,
                                                             blend):
    """Each blend: the frames rendered with a matte are those rendered without (to the bit);
    the matte is 0 where the frame is the target's, > 0 where it differs, 1 deep inside the
    face; fractions only on the seam of the feathered blends; on forked workers the same."""
    fa, ta, fb, tb, _ = synthetic
    new = recombine(tb, expression=ta)
    kw = dict(mouth_source=rc.MouthSource(fa, ta), topo=topo,
              options=rwo.RewriteOptions(blend=blend))
    plain = list(rc.rewrite_frames(fb, tb, new, quick_model, **kw))
    matted = list(rc.rewrite_frames(fb, tb, new, quick_model, matte=True, **kw))
    forked = list(rc.rewrite_frames(fb, tb, new, quick_model, matte=True,
                                    run=rc.RenderRun(workers=2, processes=True, start=1), **kw))
    assert all(p.matte is None for p in plain)
    for i, (p, m) in enumerate(zip(plain, matted)):
        np.testing.assert_array_equal(p.image, m.image)
        a = m.matte
        assert a.shape == fb[i].shape[:2] and a.dtype == np.float32
        assert a.min() >= 0 and a.max() == 1.0
        _check_invariant(m.image, fb[i], a)
        between = ((a > 0) & (a < 1)).sum()
        assert (between == 0) if blend == "none" else (between > 50)
        if blend != "poisson":   # the region: the face mask eroded (Poisson's feather reaches out)
            assert not (a > 0)[~m.face_mask].any()
        if blend == "none":      # pasted: the rendered face, wholly
            np.testing.assert_array_equal(m.image[a == 1], m.rendered[a == 1])
        assert (a == 1).sum() > 1000
    for f, m in zip(forked, matted[1:]):
        np.testing.assert_array_equal(f.matte, m.matte)
        np.testing.assert_array_equal(f.image, m.image)


def test_a_frame_without_a_face_has_an_all_zero_matte(quick_model, topo, synthetic):
    fa, ta, fb, tb, _ = synthetic
    lost = dataclasses.replace(ta, lost=np.array([False, True, False, False, False]))
    new = recombine(tb, expression=lost)
    outs = list(rc.rewrite_frames(fb, tb, new, quick_model, topo=topo, matte=True,
                                  mouth_source=rc.MouthSource(fa, lost)))
    assert outs[1].matte.dtype == np.float32 and not outs[1].matte.any()
    assert outs[0].matte.any()


# ------------------------------------------------------------------------------ file formats
def test_matte_frames_in_each_format(tmp_path):
    """16-bit grey PNG and TIFF, float OpenEXR (channel Y), grey 8-bit video: what the file
    holds is the matte (to a 16-bit level, exactly, to an 8-bit level); a fraction too small
    for the file's first level is that level, never 0; no face: all 0."""
    import OpenEXR

    a = np.zeros((24, 32), np.float32)
    a[4:20, 6:26] = np.linspace(0, 1, 16 * 20, dtype=np.float32).reshape(16, 20)
    a[2, 2] = 1e-7                                        # touched, below every level
    for pattern in ("m.%03d.png", "m.%03d.tif", "m.%03d.exr"):
        path = tmp_path / pattern
        with MatteWriter(VideoWriter(path, 25.0, (32, 24), n_frames=2), path, (32, 24)) as w:
            w.write(0, a)
            w.write(1, None)
        f0, f1 = (tmp_path / (pattern % i) for i in (0, 1))
        if pattern.endswith(".exr"):
            with OpenEXR.File(str(f0)) as f:
                ch = f.channels()
                assert list(ch) == ["Y"]
                got = np.asarray(ch["Y"].pixels)
            assert got.dtype == np.float32 and np.array_equal(got, a)
            with OpenEXR.File(str(f1)) as f:
                assert not np.asarray(f.channels()["Y"].pixels).any()
            continue
        got = cv2.imread(str(f0), cv2.IMREAD_UNCHANGED)
        assert got.dtype == np.uint16 and got.shape == (24, 32)
        want = np.rint(a * 65535).astype(np.uint16)
        want[2, 2] = 1
        np.testing.assert_array_equal(got, want)
        assert not cv2.imread(str(f1), cv2.IMREAD_UNCHANGED).any()
    v = matte_frame(a, (32, 24), tmp_path / "m.mp4")
    assert v.shape == (24, 32, 3) and v.dtype == np.uint8 and v[2, 2, 0] == 1
    assert np.array_equal(v[..., 0], v[..., 2]) and v.max() == 255


def test_an_exr_matte_is_tagged_as_data_not_colour(tmp_path):
    """An OpenEXR matte is data: ``colorInteropID`` ``data`` (the Color Interop Forum's name
    for channels no colour transform may touch), not the ``lin_rec709_scene`` of the colour
    frames (a colour-managed Read converted it to its working space as if it were a colour),
    with the output's rate, timecode and pixel aspect; the colour frames keep theirs."""
    import OpenEXR

    from facetransfer.io.video import VideoOptions

    opts = VideoOptions(timecode="01:00:00:00", sar=(2, 1))
    path = tmp_path / "m.%04d.exr"
    with MatteWriter(VideoWriter(path, 25.0, (8, 6), n_frames=1,
                                 options=matte_options(opts, path)), path, (8, 6)) as w:
        w.write(0, np.full((6, 8), 0.5, np.float32))
    with OpenEXR.File(str(tmp_path / "m.0000.exr")) as f:
        h = f.header()
        assert h["colorInteropID"] == "data" and list(f.channels()) == ["Y"]
        assert h["pixelAspectRatio"] == 2.0 and h["timeCode"].hours == 1
    rgb = tmp_path / "c.%04d.exr"
    with VideoWriter(rgb, 25.0, (8, 6), n_frames=1) as w:
        w.write(np.zeros((6, 8, 3), np.uint8))
    with OpenEXR.File(str(tmp_path / "c.0000.exr")) as f:
        assert f.header()["colorInteropID"] == "lin_rec709_scene"


def test_matte_options_follow_the_output():
    """A matte sequence is numbered, timed and shaped as the output; a .mov or .mkv matte is
    lossless 16-bit grey (PNG, FFV1) whatever the output's codec; an .mp4 matte takes the
    output's codec (ProRes: H.264), never alpha or 16 bits."""
    out = VideoOptions(codec="prores", first_number=1001, timecode="01:00:00:00", sar=(2, 1),
                       alpha=True, deep=True)
    seq = matte_options(out, "m/%04d.exr")
    assert (seq.first_number, seq.timecode, seq.sar, seq.crf) == (1001, "01:00:00:00", (2, 1),
                                                                  None)
    for name, codec in (("m.mov", "png"), ("m.mkv", "ffv1")):
        o = matte_options(out, name)
        assert (o.codec, o.grey, o.crf, o.field, o.alpha) == (codec, True, None, None, False)
        assert (o.timecode, o.sar) == ("01:00:00:00", (2, 1))
        assert matte_options(VideoOptions(crf=0, field="top"), name).codec == codec
    mp4 = matte_options(out, "m.mp4")
    assert mp4.codec == "h264" and not mp4.alpha and not mp4.deep and mp4.sar == (2, 1)
    assert matte_options(VideoOptions(crf=0), "m.mp4").crf == 0


def _decoded16(path) -> np.ndarray:
    """A video's frames as ffmpeg decodes them into 16-bit grey, ``(n, H, W) uint16``."""
    import subprocess

    from facetransfer.io.video import ffmpeg_exe, video_info

    info = video_info(path)
    res = subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(path), "-f", "rawvideo",
                          "-pix_fmt", "gray16le", "-"], capture_output=True, check=True)
    W, H = info.size
    return np.frombuffer(res.stdout, "<u2").reshape(-1, H, W)


def _probe(path) -> str:
    import subprocess

    from facetransfer.io.video import ffmpeg_exe

    return subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                          capture_output=True, text=True).stderr


@pytest.mark.parametrize("name, codec", [("m.mov", "png"), ("m.mkv", "ffv1")])
def test_a_mov_or_mkv_matte_is_lossless_16_bit(name, codec, tmp_path, caplog):
    """A .mov (QuickTime PNG) or .mkv (FFV1) matte decodes back to the 16-bit PNG
    sequence's levels exactly: 0 stays 0, 1 is 65535, a ramp every level, a touched pixel
    below the first level is 1; a frame without a face all 0; the output's rate, timecode and
    pixel aspect; no warning. (The old 8-bit H.264 / ProRes mattes failed every one.)"""
    a = np.zeros((24, 32), np.float32)
    a[4:20, 6:26] = np.linspace(0, 1, 16 * 20, dtype=np.float32).reshape(16, 20)
    a[2, 2] = 1e-7
    a[0, :] = 1.0
    path = tmp_path / name
    opts = matte_options(VideoOptions(codec="prores", timecode="01:00:00:00", sar=(2, 1)), path)
    with MatteWriter(VideoWriter(path, 24.0, (32, 24), options=opts), path, (32, 24)) as w:
        w.write(0, a)
        w.write(1, None)
        w.write(2, a)
    assert not caplog.records
    got = _decoded16(path)
    want = matte_frame(a, (32, 24), tmp_path / "m.%03d.png")
    assert got.shape == (3, 24, 32) and want[2, 2] == 1 and want[0].min() == 65535
    np.testing.assert_array_equal(got[0], want)
    np.testing.assert_array_equal(got[2], want)
    assert not got[1].any()
    said = _probe(path)
    assert f"Video: {codec}" in said and "gray16" in said and "SAR 2:1" in said
    assert "24 fps" in said and "01:00:00:00" in said
    if name.endswith(".mov"):
        assert "tmcd" in said


def test_an_mp4_matte_is_lossy_and_says_so(tmp_path, caplog):
    """.mp4 holds no lossless codec players read: the matte is 8-bit H.264 as before, and one
    warning names the lossless choices."""
    path = tmp_path / "m.mp4"
    with MatteWriter(VideoWriter(path, 25.0, (32, 24), options=matte_options(None, path)),
                     path, (32, 24)) as w:
        w.write(0, np.full((24, 32), 0.5, np.float32))
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "lossy" in warned[0] and ".mov or .mkv" in warned[0]


@pytest.mark.parametrize("matte, said", [
    ("m.%03d.jpg", "a matte sequence is written as .png, .tif, .tiff or .exr frames"),
    ("m.avi", "a matte is an image sequence (e.g. matte/%05d.png, 16-bit) or a video "
              "(.mp4, .mov or .mkv), not .avi"),
    ("m.png", "not .png"),
    ("o.%03d.png", "is also --out: give the matte its own name"),
])
def test_a_bad_matte_is_refused_naming_it(matte, said, tmp_path):
    with pytest.raises(MatteError, match=None) as e:
        check_matte_output(tmp_path / matte, out=tmp_path / "o.%03d.png")
    assert said in str(e.value) and str(tmp_path / matte) in str(e.value)
    assert isinstance(e.value, ValueError)


# --------------------------------------------------------------------------------- the CLI
def _lossless_target(clips, tmp_path) -> tuple[Path, np.ndarray]:
    """The synthetic target as a lossless video, and its frames as decoded."""
    p = tmp_path / "target.mkv"
    write_video(p, read_video(clips["target"])[0], 25.0, options=VideoOptions(crf=0))
    return p, read_video(p)[0]


def _args(clips, target, model_path) -> list:
    return ["transfer", "--target", target, "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", model_path, "--no-progress"]


def _pngs(folder: Path, flags=cv2.IMREAD_UNCHANGED) -> list[np.ndarray]:
    return [cv2.imread(str(f), flags) for f in sorted(folder.iterdir())]


@pytest.mark.parametrize("blend", MODES)
def test_the_written_matte_holds_the_invariant(blend, clips, quick_model_path, tmp_path,
                                               capsys):
    """``transfer --out out/%03d.png --matte matte/%03d.png --blend B``: one 16-bit grey
    frame per output frame, of the same names; where it is 0 the written output is the
    plate's pixel to the bit, and every pixel the output changed is above 0 in it."""
    target, plate = _lossless_target(clips, tmp_path)
    code, out, err = run(_args(clips, target, quick_model_path)
                         + ["--blend", blend, "--out", tmp_path / "out" / "%03d.png",
                            "--matte", tmp_path / "matte" / "%03d.png"], capsys)
    assert code == 0, err
    assert f"wrote the matte {tmp_path / 'matte' / '%03d.png'}" in out
    names = sorted(q.name for q in (tmp_path / "out").iterdir())
    assert names == sorted(q.name for q in (tmp_path / "matte").iterdir()) and len(names) == 6
    images = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in _pngs(tmp_path / "out",
                                                                 cv2.IMREAD_COLOR)]
    for image, p, m in zip(images, plate, _pngs(tmp_path / "matte")):
        assert m.dtype == np.uint16 and m.shape == p.shape[:2] and m.max() == 65535
        _check_invariant(image, p, m)


def test_a_video_matte_and_a_float_matte(clips, quick_model_path, tmp_path, capsys):
    """``--matte m.mkv`` with a video output: FFV1, one frame per output frame at its rate,
    decoded in 16 bits the 16-bit PNG matte of the same transfer exactly (before: read in 8
    bits and compared within 2 levels, as when an .mkv matte was lossy H.264: a matte off by a
    level passed); ``--matte m/%03d.exr`` with ``--start-number``: numbered as the output
    sequence, the floats of the PNG matte to its level, 0 where it is 0."""
    import OpenEXR

    from facetransfer.io.video import video_info

    target, plate = _lossless_target(clips, tmp_path)
    base = _args(clips, target, quick_model_path)
    code, _, err = run(base + ["--out", tmp_path / "o.mkv", "--matte", tmp_path / "m.mkv"],
                       capsys)
    assert code == 0, err
    video = _decoded16(tmp_path / "m.mkv")
    assert video.shape == plate.shape[:3] and "Video: ffv1" in _probe(tmp_path / "m.mkv")
    assert video_info(tmp_path / "m.mkv").fps == video_info(tmp_path / "o.mkv").fps == 25.0
    code, _, err = run(base + ["--out", tmp_path / "s" / "%03d.png", "--matte",
                               tmp_path / "e" / "%03d.exr", "--start-number", "7"], capsys)
    assert code == 0, err
    assert sorted(q.name for q in (tmp_path / "e").iterdir()) == \
        [f"{7 + i:03d}.exr" for i in range(6)]
    code, _, err = run(base + ["--out", tmp_path / "p.mkv", "--matte",
                               tmp_path / "pm" / "%03d.png"], capsys)
    assert code == 0, err
    pngs = _pngs(tmp_path / "pm")
    assert len(pngs) == 6
    for i, m16 in enumerate(pngs):
        with OpenEXR.File(str(tmp_path / "e" / f"{7 + i:03d}.exr")) as f:
            a = np.asarray(f.channels()["Y"].pixels)
        assert m16.max() == 65535 and 0 < (a == 0).mean() < 1
        assert np.array_equal(a == 0, m16 == 0)
        assert np.abs(a * 65535 - m16).max() <= 0.5 + 1e-3
        np.testing.assert_array_equal(video[i], m16)


def test_a_bad_matte_is_one_line_before_any_work(clips, quick_model_path, tmp_path, capsys,
                                                monkeypatch):
    """An existing matte without --overwrite, the output's or an input's name, a format a
    matte is not written in: one line naming --matte (before, "output ... exists" or "output
    ... is also an input" left the user to tell which output), exit 2, before the model is
    even loaded."""
    import facetransfer.cli.transfer as ct

    def no_work(*a, **k):
        raise AssertionError("work began")

    monkeypatch.setattr(ct, "resolve_model", no_work)
    (tmp_path / "old.mkv").write_bytes(b"x")
    base = _args(clips, clips["target"], quick_model_path) + ["--out", tmp_path / "o.mp4"]
    for matte, said in ((tmp_path / "old.mkv", "exists; pass --overwrite to replace it"),
                        (tmp_path / "o.mp4", "is also --out"),
                        (clips["target"], "is also an input"),
                        (tmp_path / "m.gif", "not .gif"),
                        (tmp_path / "m.%03d.bmp", "not .bmp")):
        code, _, err = run(base + ["--matte", matte], capsys)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and said in lines[0] and str(matte) in lines[0]
        assert lines[0].startswith("facetransfer transfer: error: --matte"), lines
    assert (tmp_path / "old.mkv").read_bytes() == b"x" and not (tmp_path / "o.mp4").exists()


def test_an_interrupted_transfer_finishes_its_output_and_its_matte(clips, quick_model_path,
                                                                  tmp_path, capsys,
                                                                  monkeypatch):
    """A transfer interrupted without a matte (2 frames kept), then with one (interrupted at
    frame 4: the matte renders from 0, the output writes only the frames it lacks), then
    run to the end: only frames 4 and 5 are rendered, and the output and the matte equal
    those of a run at once without the render cache."""
    from facetransfer.io import video_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(video_parts, "PART_FRAMES", 2)
    stop = [2]
    calls = interrupt_renders(monkeypatch, stop)
    base = _args(clips, clips["target"], quick_model_path) + ["--crf", "0", "--out",
                                                              tmp_path / "o.mp4"]
    matte = ["--matte", tmp_path / "m" / "%03d.png"]
    code, _, err = run(base, capsys)
    assert code == 130 and calls == [0, 1]
    stop[0], calls[:] = 4, []
    code, _, err = run(base + matte, capsys)
    assert code == 130 and sorted(calls) == [0, 1, 2, 3]
    assert not (tmp_path / "o.mp4").exists() and not (tmp_path / "m").exists()
    stop[0], calls[:] = None, []
    code, out, err = run(base + matte, capsys)
    assert code == 0, err
    assert sorted(calls) == [4, 5] and "continued an interrupted render from frame 4" in out
    assert not list((tmp_path / "cache" / "facetransfer" / "renders").iterdir())
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    code, _, err = run(_args(clips, clips["target"], quick_model_path)
                       + ["--crf", "0", "--out", tmp_path / "once.mp4", "--matte",
                          tmp_path / "once" / "%03d.png"], capsys)
    assert code == 0, err
    a, b = read_video(tmp_path / "o.mp4")[0], read_video(tmp_path / "once.mp4")[0]
    assert a.shape == b.shape == (6, *a.shape[1:]) and np.array_equal(a, b)
    ma, mb = _pngs(tmp_path / "m"), _pngs(tmp_path / "once")
    assert len(ma) == len(mb) == 6
    assert all(np.array_equal(x, y) and x.any() for x, y in zip(ma, mb))


def test_transfer_video_refuses_a_bad_matte_before_any_work(tmp_path):
    """The library's call: a matte named as the output, as an input, or of another kind is a
    ValueError naming it, raised before the model is looked at (None here)."""
    from facetransfer.transfer_plan import TransferSources
    from facetransfer.video_transfer import transfer_video

    target = tmp_path / "t.mp4"
    write_video(target, np.zeros((2, 16, 16, 3), np.uint8), 25.0)
    sources = TransferSources.of(target, expression_from=target)
    out = tmp_path / "o.mp4"
    for matte, said in ((out, "is also --out"), (target, "is also an input"),
                        (tmp_path / "m.%03d.jpg", "not .jpg")):
        with pytest.raises(ValueError) as e:
            transfer_video(sources, out, None, matte=matte)
        assert said in str(e.value) and str(matte) in str(e.value)
    assert not out.exists()


@pytest.mark.parametrize("name", ["m.mov", "m.mkv"])
def test_a_mov_or_mkv_matte_holds_the_invariant(name, clips, quick_model_path, tmp_path,
                                               capsys):
    """``transfer --out out/%03d.png --matte m.mov`` (or ``.mkv``): decoded in 16 bits, the
    video matte is the 16-bit PNG sequence matte of the same transfer exactly, one frame per
    output frame at its rate; where it is 0 the output is the plate's pixel to the bit and
    every pixel the output changed is above 0 in it."""
    target, plate = _lossless_target(clips, tmp_path)
    base = _args(clips, target, quick_model_path)
    code, _, err = run(base + ["--out", tmp_path / "out" / "%03d.png", "--matte",
                               tmp_path / name], capsys)
    assert code == 0 and "lossy" not in err, err
    code, _, err = run(base + ["--out", tmp_path / "o2" / "%03d.png", "--matte",
                               tmp_path / "seq" / "%03d.png"], capsys)
    assert code == 0, err
    mattes = _decoded16(tmp_path / name)
    assert mattes.shape == (6, *plate.shape[1:3]) and "25 fps" in _probe(tmp_path / name)
    images = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in _pngs(tmp_path / "out",
                                                                 cv2.IMREAD_COLOR)]
    for image, p, m, s in zip(images, plate, mattes, _pngs(tmp_path / "seq")):
        np.testing.assert_array_equal(m, s)
        assert m.max() == 65535
        _check_invariant(image, p, m)


def test_an_interrupted_transfer_continues_its_mov_matte(clips, quick_model_path, tmp_path,
                                                        capsys, monkeypatch):
    """A transfer with ``--matte m.mov`` interrupted at frame 4 (parts of 2 frames), then
    run to the end: the lossless parts are joined by stream copy into a matte equal, decoded
    in 16 bits, to that of a run at once without the render cache; still QuickTime PNG."""
    from facetransfer.io import video_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(video_parts, "PART_FRAMES", 2)
    stop = [4]
    calls = interrupt_renders(monkeypatch, stop)
    base = _args(clips, clips["target"], quick_model_path)
    args = base + ["--out", tmp_path / "o.mov", "--matte", tmp_path / "m.mov"]
    code, _, err = run(args, capsys)
    assert code == 130 and sorted(calls) == [0, 1, 2, 3]
    assert not (tmp_path / "m.mov").exists()
    stop[0], calls[:] = None, []
    code, out, err = run(args, capsys)
    assert code == 0, err
    assert sorted(calls) == [4, 5] and "continued an interrupted render from frame 4" in out
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    code, _, err = run(base + ["--out", tmp_path / "once.mov", "--matte",
                               tmp_path / "once_m.mov"], capsys)
    assert code == 0, err
    a, b = _decoded16(tmp_path / "m.mov"), _decoded16(tmp_path / "once_m.mov")
    assert a.shape[0] == 6 and a.max() == 65535 and np.array_equal(a, b)
    said = _probe(tmp_path / "m.mov")
    assert "Video: png" in said and "gray16be" in said


def test_the_grey_codecs_refuse_what_they_cannot_write(tmp_path):
    """PNG / FFV1 grey: no CRF, fields or alpha; only in .mov / .mkv; (H, W) uint16 frames
    only, each refusal a VideoError naming the file or option."""
    from facetransfer.errors import VideoError
    from facetransfer.io.video import check_video_output

    for bad in (dict(crf=0), dict(field="top"), dict(alpha=True)):
        with pytest.raises(VideoError, match="lossless grey"):
            VideoOptions(codec="png", **bad)
    with pytest.raises(VideoError, match=r"go in a \.mov or \.mkv file, not \.mp4"):
        check_video_output(tmp_path / "m.mp4", VideoOptions(codec="ffv1"))
    with VideoWriter(tmp_path / "m.mkv", 25.0, (8, 6), options=VideoOptions(codec="ffv1")) as w:
        for frame in (np.zeros((6, 8, 3), np.uint8), np.zeros((6, 8), np.uint8)):
            with pytest.raises(VideoError, match=r"takes \(H, W\) uint16 grey frames of 8x6"):
                w.write(frame)
        w.write(np.zeros((6, 8), np.uint16))


def test_a_plate_targets_matte_is_numbered_as_the_plate(clips, quick_model_path, tmp_path,
                                                        capsys, monkeypatch):
    """A PNG plate numbered from 1001 as the target, ``--out o.mp4 --matte m/sh010.%04d.exr``:
    the matte's frames numbered 1001-1006 as the plate (``--start-number``'s default, which
    README and ``--help`` promise; no test held it), said so, each the PNG matte of the same
    transfer to its level; with ``--start-number 7`` from 7. A video target's matte is numbered
    from 0 (the other tests)."""
    import OpenEXR

    from test_video_sequence import _plate
    from test_transfer_cli import plate_transfer_args

    monkeypatch.setenv("FACETRANSFER_SEQUENCE_FPS", "25")   # undone after (the CLI sets it)
    _plate(tmp_path / "plate", read_video(clips["target"])[0])
    base = ["transfer", "--target", tmp_path / "plate" / "sh010.####.png",
            *plate_transfer_args(clips, quick_model_path)]
    code, out, err = run(base + ["--out", tmp_path / "o.mp4", "--matte",
                                 tmp_path / "m" / "sh010.%04d.exr"], capsys)
    assert code == 0, err
    assert f"wrote the matte {tmp_path / 'm' / 'sh010.%04d.exr'} numbered 1001-1006" in out
    assert sorted(q.name for q in (tmp_path / "m").iterdir()) == \
        [f"sh010.{1001 + i:04d}.exr" for i in range(6)]
    code, _, err = run(base + ["--out", tmp_path / "p.mp4", "--matte",
                               tmp_path / "pm" / "%03d.png", "--start-number", "7"], capsys)
    assert code == 0, err
    pngs = sorted((tmp_path / "pm").iterdir())
    assert [q.name for q in pngs] == [f"{7 + i:03d}.png" for i in range(6)]
    for i, q in enumerate(pngs):
        m16 = cv2.imread(str(q), cv2.IMREAD_UNCHANGED)
        with OpenEXR.File(str(tmp_path / "m" / f"sh010.{1001 + i:04d}.exr")) as f:
            a = np.asarray(f.channels()["Y"].pixels)
        assert m16.max() == 65535 and np.array_equal(a == 0, m16 == 0)
        assert np.abs(a * 65535 - m16).max() <= 0.5 + 1e-3


def test_a_matte_overwritten_by_a_shorter_one_keeps_no_frame_of_the_old(clips, quick_model_path,
                                                                       tmp_path, capsys):
    """``--overwrite`` over a matte sequence of 6 frames with a transfer of 3 (``--max-frames
    3``): the folder holds the 3 new frames only (a compositor reading it would otherwise take
    the old frames 3-5 for this output's), each as a transfer of 3 frames writes it; without
    ``--overwrite`` the old matte is refused, untouched."""
    base = _args(clips, clips["target"], quick_model_path)
    matte = tmp_path / "m" / "%03d.png"
    code, _, err = run(base + ["--out", tmp_path / "o.mp4", "--matte", matte], capsys)
    assert code == 0, err
    old = _pngs(tmp_path / "m")
    assert len(old) == 6
    code, _, err = run(base + ["--out", tmp_path / "o2.mp4", "--matte", matte,
                               "--max-frames", "3"], capsys)
    assert code == 2 and "--matte: output frames" in err and "exist (6 files)" in err
    assert len(_pngs(tmp_path / "m")) == 6
    code, _, err = run(base + ["--out", tmp_path / "o.mp4", "--matte", matte, "--max-frames",
                               "3", "--overwrite"], capsys)
    assert code == 0, err
    assert sorted(q.name for q in (tmp_path / "m").iterdir()) == ["000.png", "001.png",
                                                                  "002.png"]
    code, _, err = run(base + ["--out", tmp_path / "o3.mp4", "--matte",
                               tmp_path / "m3" / "%03d.png", "--max-frames", "3"], capsys)
    assert code == 0, err
    fresh = _pngs(tmp_path / "m3")
    assert len(fresh) == 3 and all(np.array_equal(a, b) and a.any()
                                   for a, b in zip(_pngs(tmp_path / "m"), fresh))

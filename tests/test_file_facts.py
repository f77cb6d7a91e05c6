"""``facetransfer probe`` on a track file and a Live Link Face take (facetransfer.file_facts)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.file_facts import file_kind, take_facts, track_facts
from facetransfer.io.frame_numbers import frame_runs


def test_runs_of_lost_frames():
    m = np.zeros(20, bool)
    assert frame_runs(m) == ""
    m[[3, 4, 5, 9, 12, 13, 15, 18]] = True
    assert frame_runs(m) == "3-5, 9, 12-13, 15, ... (5 runs)"
    assert frame_runs(m, limit=5) == "3-5, 9, 12-13, 15, 18"
    assert frame_runs(m, 1001, limit=5) == "1004-1006, 1010, 1013-1014, 1016, 1019"


def test_a_track_is_described(arkit_model, make_arkit_track, tmp_path, monkeypatch, capsys):
    """Frames, rate, size, video, model (the default one, by its file's recorded hash),
    activations, lost frames: the values the track holds, as lines and as JSON."""
    import facetransfer.default_model as dm

    track, _, _ = make_arkit_track(arkit_model, 30, fps=25.0)
    lost = np.zeros(30, bool)
    lost[[3, 4, 5, 20]] = True
    track = dataclasses.replace(track, lost=lost, source="clip.mp4",
                                confidence=np.where(lost, 0.0, 0.9))
    track.save(tmp_path / "t.npz")
    assert file_kind(tmp_path / "t.npz") == "track"
    monkeypatch.setattr(dm, "default_model_path", lambda: tmp_path / "none.npz")
    f = track_facts(tmp_path / "t.npz")
    assert (f["frames"], f["fps"], f["seconds"], f["activations"]) == (30, 25.0, 1.2, 52)
    assert (f["lost_frames"], f["lost"], f["default_model"]) == (4, "3-5, 20", None)
    assert f["mean_confidence"] == pytest.approx(0.9 * 26 / 30)
    arkit_model.save(tmp_path / "default.npz")                   # the default model, built
    monkeypatch.setattr(dm, "default_model_path", lambda: tmp_path / "default.npz")
    assert main(["probe", str(tmp_path / "t.npz")]) == 0
    out = capsys.readouterr().out.splitlines()
    W, H = track.frame_size
    assert out[0] == f"{tmp_path / 't.npz'}: a track of 30 frames at 25 fps (1.20 s), {W}x{H}"
    assert out[1].startswith("  made from: clip.mp4; with the default model (ict-arkit), hash "
                             f"{arkit_model.content_hash[:12]}...")
    assert out[2] == "  ARKit activations: 52 (exports and takes use them)"
    assert out[3] == "  face lost in 4 of 30 frames (3-5, 20); mean confidence 0.78"
    dataclasses.replace(track, model_hash="0" * 64).save(tmp_path / "o.npz")
    assert main(["probe", str(tmp_path / "o.npz"), "--json"]) == 0
    (g,) = json.loads(capsys.readouterr().out)
    assert g["default_model"] is False and g["kind"] == "track" and g["frames"] == 30


def test_a_take_is_described(arkit_model, make_arkit_track, tmp_path, capsys):
    """The exporter's take (every column, 25 fps) and another tool's (camelCase names, 60
    rows a second, no TongueOut, no rotations)."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export.livelink import write_livelink

    track, _, _ = make_arkit_track(arkit_model, 30, fps=25.0)
    write_livelink(track, tmp_path / "take.csv", start="10:00:00:00", labels="clip")
    f = take_facts(tmp_path / "take.csv")
    assert (f["rows"], f["timecode_rate"], f["shapes"], f["missing_shapes"]) == (30, 25, 52, [])
    assert f["first_timecode"] == "10:00:00:00.000" and f["last_timecode"] == "10:00:01:04.000"
    assert len(f["head_rotation"]) == 3 and len(f["eye_rotation"]) == 6
    assert f["seconds"] == pytest.approx(29 / 25)
    names = [n for n in ARKIT_NAMES if n != "tongueOut"]
    rows = ["Timecode,BlendShapeCount," + ",".join(names)]
    rows += [f"00:00:0{k // 60}:{k % 60:02d},{len(names)}," + ",".join(["0.1"] * len(names))
             for k in range(90)]
    (tmp_path / "other.csv").write_text("\n".join(rows) + "\n")
    assert main(["probe", str(tmp_path / "other.csv")]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"{tmp_path / 'other.csv'}: a Live Link Face take of 90 rows (60 fps timecode), from "
        "00:00:00:00 to 00:00:01:29 (1.48 s apart)",
        "  shapes: 51 of 52 (missing, read as 0: TongueOut)",
        "  head rotation: none; eye rotation: none"]
    # one head column left out: the two used said, the third read as 0 (before: "no")
    cols = ["Timecode", "BlendShapeCount", *names, "HeadYaw", "HeadPitch"]
    rows = [",".join(cols)] + [f"00:00:00:{k:02d},{len(names)}," + ",".join(
        ["0.1"] * (len(names) + 2)) for k in range(20)]
    (tmp_path / "yawpitch.csv").write_text("\n".join(rows) + "\n")
    assert main(["probe", str(tmp_path / "yawpitch.csv")]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "  head rotation: HeadYaw, HeadPitch (HeadRoll read as 0); eye rotation: none")


@pytest.mark.parametrize("fps, start, labels, said", [
    (25.0, None, "app", "(30 fps timecode, rows 25 a second)"),
    (30000 / 1001, "00:59:59;28", "app", "(30 fps timecode, rows 29.97 a second)"),
    (50.0, None, "app", "(60 fps timecode, rows 50 a second)"),
    (25.0, None, "clip", "(25 fps timecode)"), (30.0, None, "app", "(30 fps timecode)")])
def test_a_take_says_its_rows_rate_beside_its_timecodes(arkit_model, make_arkit_track, tmp_path,
                                                        capsys, fps, start, labels, said):
    """An export of a 25 fps clip counts 30 a second with thousandths (the app's way): probe
    says its rows' own rate too, the rate ``puppet take.csv`` plays them at (the walk of
    chains, forty-eighth session; a 29.97 fps clip's after a drop-frame start, whose rows count
    clock time). Before: "(30 fps timecode)" alone, and a 25 fps take looked like a 30 fps
    one."""
    from facetransfer.export.livelink import write_livelink

    track, _, _ = make_arkit_track(arkit_model, 40, fps=fps)
    write_livelink(track, tmp_path / "take.csv", start=start, labels=labels)
    f = take_facts(tmp_path / "take.csv")
    assert f["row_rate"] == pytest.approx(fps)
    assert main(["probe", str(tmp_path / "take.csv")]) == 0
    assert f"take of 40 rows {said}, from" in capsys.readouterr().out.splitlines()[0]


def test_a_model_or_a_foreign_archive_given_to_probe(arkit_model, tmp_path, capsys):
    arkit_model.save(tmp_path / "m.npz")
    assert main(["probe", str(tmp_path / "m.npz")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"facetransfer probe: error: {tmp_path / 'm.npz'} is a model file, not a video: "
        f"`facetransfer model info {tmp_path / 'm.npz'}` describes it")
    # an archive of something else: what it holds, not "a track or a model ... `facetransfer
    # probe x.npz` says what it holds" (the advice to run the command that said it)
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    np.savez(tmp_path / "c.truth.npz", meta=np.zeros(1), vertices2d=np.zeros((1, 3, 2)),
             landmark_indices=np.arange(3))
    for name, what in (("x.npz", "arrays a"),
                       ("c.truth.npz", "a synthetic clip's ground truth")):
        assert main(["probe", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"facetransfer probe: error: {tmp_path / name} is an .npz archive of "
                       f"{what}" + (" (synth-video's CLIP.truth.npz)" if "truth" in name else "")
                       + ", not a track or a model: probe describes videos, image sequences, "
                       "tracks and Live Link Face takes (a model: `facetransfer model info`)"], err


def test_a_damaged_archive_given_to_probe_is_named(tmp_path, capsys):
    """A truncated track (the zip's end cut off) and a file that is no archive at all: the
    one line names the file and says what is wrong with it (before: "an input file is
    truncated or damaged" without a name, or numpy's advice on pickles)."""
    good = tmp_path / "t.npz"
    np.savez(good, fps=np.float64(30.0), frame_size=np.array([64, 64]))
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:-40])
    text = tmp_path / "text.npz"
    text.write_text("hello")
    for path, why in ((cut, "BadZipFile"), (text, "not an .npz archive of arrays")):
        assert main(["probe", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"facetransfer probe: error: {path} is truncated or not an .npz archive "
                       f"({why})"], err


def test_a_missing_track_or_take_given_to_probe_is_named_as_one(tmp_path, capsys):
    """A track, model or take that is not there (or a folder, or empty) is named as what its
    name says it is (before: "video t.npz does not exist", "No such file or directory")."""
    (tmp_path / "d.npz").mkdir()
    (tmp_path / "e.npz").write_bytes(b"")
    for name, said in (("t.npz", "track or model file {} does not exist"),
                       ("take.csv", "take {} does not exist"),
                       ("d.npz", "track or model file {} is a folder, not a file"),
                       ("e.npz", "track or model file {} is empty")):
        assert main(["probe", str(tmp_path / name)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["facetransfer probe: error: " + said.format(tmp_path / name)], err


@pytest.mark.parametrize("name", ["face.jpg", "face.pgm"])
def test_a_still_image_is_described_as_one(tmp_path, capsys, name):
    """A photo given to probe is said to be a still image (tracked as a clip of one frame, a
    transfer's target held over its source's frames), not a 25 fps video of one frame whose
    seeks are not exact (a grey ``.pgm``, which transfer reads as a still, was, before)."""
    import cv2

    photo = tmp_path / name
    cv2.imwrite(str(photo), np.full((48, 64), 128, np.uint8))
    assert main(["probe", str(photo)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == [f"{photo}: 64x48", "  a still image: tracked as a clip of one frame; "
                       "as a transfer's target, held over its expression source's frames"], out
    assert "fps" not in " ".join(out) and "seeks" not in " ".join(out)


def test_a_still_s_colour_is_said_in_words(tmp_path, capsys):
    """A still's colour line says how its pixels are stored and that it tags no primaries or
    curve (before: ffmpeg's ``gbr/?/? (matrix/primaries/transfer)``, ``bt470bg/?/?``); tags a
    still does carry are named; a video's line keeps its wording."""
    import cv2

    from facetransfer.io.video_display import ColourTags
    from facetransfer.io.video_facts import fact_lines, video_facts

    cv2.imwrite(str(tmp_path / "a.jpg"), np.full((48, 64, 3), 128, np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.full((48, 64, 3), 128, np.uint8))
    untagged = "primaries and curve not tagged (taken as sRGB); no audio"
    for name, stored in (("a.jpg", "stored as YCbCr (BT.601, as JPEG stores it), read as RGB"),
                         ("b.png", "RGB")):
        assert main(["probe", str(tmp_path / name)]) == 0
        out = capsys.readouterr().out.splitlines()
        assert out[2] == f"  colour {stored}, {untagged}", out
    png = video_facts(tmp_path / "b.png")
    tagged = dataclasses.replace(png, colour=ColourTags("gbr", "bt709", "iec61966-2-1"))
    assert fact_lines(tagged)[2] == "  colour RGB, primaries Rec.709, curve sRGB; no audio"
    half = dataclasses.replace(png, colour=ColourTags("gbr", "bt2020", None))
    assert fact_lines(half)[2] == ("  colour RGB, primaries Rec.2020, curve not tagged (taken "
                                   "as sRGB's): HDR or wide gamut, seen as 8-bit SDR; no audio")
    clip = dataclasses.replace(png, n_frames=10, path=str(tmp_path / "c.mp4"),
                               colour=ColourTags("bt709", "bt709", "bt709"))
    assert fact_lines(clip)[2].startswith("  colour bt709/bt709/bt709 (matrix/primaries/"
                                          "transfer); audio none")


def test_a_still_s_colour_says_what_its_pixels_are(tmp_path, capsys):
    """Stills that are not 8-bit RGB or a colour JPEG: a grey PNG or JPEG is grey (before: "RGB",
    and the grey JPEG "stored as YCbCr"), a palette PNG RGB from a palette, an RGBA PNG RGB
    with alpha (before: the alpha not said), a CMYK JPEG CMYK (before: "YCbCr"), a lossy WebP
    YCbCr as WebP stores it (before: "as JPEG stores it"); a 16-bit grey PNG's bits said
    without "RGB images"."""
    import cv2
    from PIL import Image

    rgb = (np.random.default_rng(0).random((32, 40, 3)) * 255).astype(np.uint8)
    stills = {"grey.png": (Image.fromarray(rgb[..., 0]), "grey, read as RGB"),
              "grey.jpg": (Image.fromarray(rgb[..., 0]), "grey, read as RGB"),
              "pal.png": (Image.fromarray(rgb).convert("P"), "RGB from a palette"),
              "rgba.png": (Image.fromarray(np.dstack([rgb, rgb[..., :1]])), "RGB with alpha"),
              "cmyk.jpg": (Image.fromarray(rgb).convert("CMYK"),
                           "stored as CMYK, read as RGB"),
              "lossy.webp": (Image.fromarray(rgb),
                             "stored as YCbCr (BT.601, as WebP stores it), read as RGB")}
    for name, (img, stored) in stills.items():
        img.save(tmp_path / name)
        assert main(["probe", str(tmp_path / name)]) == 0
        out = capsys.readouterr().out.splitlines()
        assert out[2] == (f"  colour {stored}, primaries and curve not tagged (taken as sRGB); "
                          "no audio"), (name, out)
    assert cv2.imwrite(str(tmp_path / "grey16.png"), np.full((32, 40), 30000, np.uint16))
    assert main(["probe", str(tmp_path / "grey16.png")]) == 0
    assert capsys.readouterr().out.splitlines()[2] == (
        "  colour grey, read as RGB, primaries and curve not tagged (taken as sRGB); 16 bits, "
        "seen in 8 (a PNG, TIFF or DPX sequence written from it stays 16-bit)")


def test_a_track_of_an_image_sequence_is_described_without_the_rate_warning(
        arkit_model, make_arkit_track, tmp_path, caplog):
    """The track's own rate is what probe says; looking up its source sequence's timecode
    (a PNG sequence has none) no longer warns that the sequence stores no frame rate."""
    import logging

    import cv2

    for i in range(3):
        cv2.imwrite(str(tmp_path / f"sh.{i + 1:04d}.png"), np.zeros((8, 8, 3), np.uint8))
    track, _, _ = make_arkit_track(arkit_model, 3, fps=25.0)
    track = dataclasses.replace(track, source=str(tmp_path / "sh.####.png"))
    track.save(tmp_path / "t.npz")
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        f = track_facts(tmp_path / "t.npz")
    assert f["fps"] == 25.0 and f["source_timecode"] is None
    assert not [r for r in caplog.records if "stores no frame rate" in r.getMessage()]


def test_probe_of_several_files_describes_the_good_ones_and_names_the_bad(
        arkit_model, make_arkit_track, tmp_path, capsys):
    """One damaged file among several: the others are still described (before: nothing was
    printed but the one error), the damaged one named on stderr, exit status 2; with --json
    it is an entry with its error."""
    track, _, _ = make_arkit_track(arkit_model, 5)
    track.save(tmp_path / "t.npz")
    good = (tmp_path / "t.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(good[:len(good) // 2])
    argv = ["probe", str(tmp_path / "cut.npz"), str(tmp_path / "t.npz")]
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out.startswith(f"{tmp_path / 't.npz'}: a track of 5 frames")
    assert err.strip().splitlines() == [f"facetransfer probe: error: {tmp_path / 'cut.npz'} is "
                                        "truncated or not an .npz archive (BadZipFile)"]
    assert main(argv + ["--json"]) == 2
    listed = json.loads(capsys.readouterr().out)
    assert listed[0] == {"path": str(tmp_path / "cut.npz"), "error": f"{tmp_path / 'cut.npz'} "
                         "is truncated or not an .npz archive (BadZipFile)"}
    assert listed[1]["frames"] == 5

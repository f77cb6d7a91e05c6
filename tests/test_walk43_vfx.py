"""What a compositor's walk found (forty-third session): a plate rewritten into a sequence,
its outputs, its hand-off to animation."""

from __future__ import annotations

import pytest


def test_an_output_sequence_under_a_file_is_refused_by_name(tmp_path):
    """``--out afile/x.%04d.png`` with ``afile`` a file: refused before any work, saying so
    (was: checked, then ``File exists: afile`` after the tracking)."""
    from facetransfer.io.video import VideoError, check_video_output

    (tmp_path / "afile").write_text("x")
    for out in (tmp_path / "afile" / "x.%04d.png", tmp_path / "afile" / "sub" / "x.%04d.exr"):
        with pytest.raises(VideoError, match=f"output folder {tmp_path / 'afile'} is a file, "
                                             "not a folder"):
            check_video_output(out)
    assert check_video_output(tmp_path / "new" / "x.%04d.png").kind == "images"


def test_a_deep_video_with_alpha_written_as_tiff_is_said_why_it_is_8_bits(tmp_path, caplog):
    """A ProRes 4444 target (10 bits, alpha) written as a TIFF sequence is written in 8 bits
    (with its alpha: OpenCV writes no 16-bit TIFF alpha); the warning said a TIFF sequence
    would keep the bits, the very output asked for. Now it names the ones that do."""
    import logging
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).parent))
    from test_plate_alpha import _prores_4444

    from facetransfer.io.video_like import like_video

    rgba = np.full((2, 32, 32, 4), 200, np.uint8)
    mov = _prores_4444(tmp_path / "a.mov", rgba)
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        like_video(None, mov, tmp_path / "o" / "x.%04d.tif")
    said = [r.getMessage() for r in caplog.records if "bits a sample" in r.getMessage()]
    assert len(said) == 1 and "a TIFF sequence with alpha is written in 8 bits" in said[0]
    assert "PNG or DPX sequence, keeps them" in said[0]


def test_a_png_sequence_of_non_square_pixels_is_warned_of(tmp_path, caplog):
    """A target of pixels 15:16 written as a PNG sequence: the frames are as stored and PNG
    has no field for the ratio; this was silent (a video, DPX or OpenEXR output records it)."""
    import logging
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe
    from facetransfer.io.video_like import like_video

    mp4 = tmp_path / "sar.mp4"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "testsrc=size=64x60:rate=25:duration=0.2", "-vf", "setsar=15/16",
                    "-pix_fmt", "yuv420p", str(mp4)], check=True)

    def said(out):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="facetransfer"):
            opts = like_video(None, mp4, out)
        assert opts.sar == (15, 16)
        return [r.getMessage() for r in caplog.records if "pixel aspect" in r.getMessage()]

    png = said(tmp_path / "o" / "x.%04d.png")
    assert len(png) == 1 and "has pixels 15:16" in png[0] and ".png files store no" in png[0]
    assert said(tmp_path / "o" / "x.%04d.exr") == [] and said(tmp_path / "o.mov") == []


def test_an_output_that_cannot_hold_the_start_timecode_is_warned_of(tmp_path, caplog):
    """A 23.976 fps plate starting at 01:00:00:00 written as a PNG sequence (numbered from 0)
    or an AVI: the timecode was dropped silently; a .mov keeps it, and says nothing."""
    import logging
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe
    from facetransfer.io.video_like import like_video

    mov = tmp_path / "tc.mov"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "testsrc=size=64x64:rate=24000/1001:duration=0.2", "-timecode",
                    "01:00:00:00", "-pix_fmt", "yuv420p", str(mov)], check=True)

    def said(out):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="facetransfer"):
            assert like_video(None, mov, out).timecode == "01:00:00:00"
        return [r.getMessage() for r in caplog.records if "timecode" in r.getMessage()]

    png = said(tmp_path / "o" / "x.%04d.png")
    assert len(png) == 1 and "starts at timecode 01:00:00:00; .png files hold none" in png[0]
    assert len(said(tmp_path / "o.avi")) == 1
    assert said(tmp_path / "o.mov") == [] and said(tmp_path / "e" / "x.%04d.exr") == []
    assert said(None) == []      # no output: a track's reading


def test_a_timecode_given_to_a_usd_export_is_refused_saying_what_usd_takes(
        arkit_model, make_arkit_track, tmp_path, capsys):
    """``export T.npz --out take.usda --timecode 02:00:00:00``: it said "only livelink takes
    carry one, not usd", though a USD export records the plate's start timecode; now it says
    what usd takes (source or none), and before the model is loaded or a texture lifted."""
    from facetransfer.cli.main import main

    track, _, _ = make_arkit_track(arkit_model, 4)
    track.save(tmp_path / "t.npz")
    arkit_model.save(tmp_path / "m.npz")
    for fmt in ("usda", "glb"):
        code = main([str(x) for x in ["export", tmp_path / "t.npz", "--model", tmp_path / "m.npz",
                                      "--out", tmp_path / f"t.{fmt}", "--timecode",
                                      "02:00:00:00"]])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1, err
        fmt = "usd" if fmt == "usda" else fmt
        assert err[-1].endswith(f"--timecode 02:00:00:00: a timecode of your own is written "
                                f"into livelink takes only; {fmt} takes source (the tracked "
                                "video's start timecode, recorded in the file) or none"), err
        assert not (tmp_path / f"t.{fmt}").exists()


def test_an_rgba_plate_written_as_prores_is_not_told_prores_keeps_it(tmp_path, caplog):
    """An RGBA PNG plate (a keyer's) written with ``--codec prores``: its alpha is dropped
    (a plate's alpha goes to image sequences only), and the warning said "transfer keeps a
    target's in ProRes 4444", the output just asked for."""
    import logging

    import cv2
    import numpy as np

    from facetransfer.io.video import VideoOptions
    from facetransfer.io.video_like import like_video

    (tmp_path / "p").mkdir()
    for k in (1001, 1002):
        cv2.imwrite(str(tmp_path / "p" / f"k.{k}.png"), np.full((16, 16, 4), 200, np.uint8))
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        opts = like_video(VideoOptions("prores"), tmp_path / "p" / "k.####.png",
                          tmp_path / "o.mov")
    said = [r.getMessage() for r in caplog.records if "alpha" in r.getMessage()]
    assert not opts.alpha and len(said) == 1
    assert "keeps a plate's in a PNG, TIFF or DPX sequence, not in a video" in said[0]
    assert "ProRes 4444" not in said[0]


def test_probe_says_which_sequences_keep_a_16_bit_rgba_plate_deep(tmp_path):
    """probe said of a 16-bit RGBA PNG plate (and of a deep video with alpha) that a TIFF
    sequence written from it stays 16-bit; transfer writes that TIFF in 8 bits."""
    import cv2
    import numpy as np

    from facetransfer.io.plate_depth import plate_depth
    from facetransfer.io.video_facts import fact_lines, video_facts

    for name, img in (("rgba", np.full((8, 8, 4), 40000, np.uint16)),
                      ("rgb", np.full((8, 8, 3), 40000, np.uint16))):
        (tmp_path / name).mkdir()
        for k in (1001, 1002):
            cv2.imwrite(str(tmp_path / name / f"p.{k}.png"), img)
    rgba, rgb = tmp_path / "rgba" / "p.####.png", tmp_path / "rgb" / "p.####.png"
    assert plate_depth(tmp_path / "o" / "x.%04d.tif", rgba) is None         # 8 bits
    assert plate_depth(tmp_path / "o" / "x.%04d.png", rgba) is not None     # 16 bits
    assert plate_depth(tmp_path / "o" / "x.%04d.tif", rgb) is not None
    said = fact_lines(video_facts(rgba))[-1]
    assert "(a PNG or DPX sequence written from it stays 16-bit, with its alpha; a TIFF one " \
           "is 8-bit)" in said
    assert "(a PNG, TIFF or DPX sequence written from it stays 16-bit)" in \
        fact_lines(video_facts(rgb))[-1]


def test_an_exr_plate_s_alpha_dropped_by_another_output_is_said(tmp_path, caplog):
    """An OpenEXR plate with an A channel written as PNG or ProRes lost it silently, and
    probe did not say the plate has it; an .exr output keeps it and says nothing."""
    import logging

    import numpy as np
    import OpenEXR

    from facetransfer.io.video import VideoOptions
    from facetransfer.io.video_facts import fact_lines, video_facts
    from facetransfer.io.video_like import like_video

    (tmp_path / "p").mkdir()
    for k in (1001, 1002):
        px = np.full((8, 8, 4), 0.5, np.float16)
        OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGBA": px}).write(
            str(tmp_path / "p" / f"e.{k}.exr"))
    plate = tmp_path / "p" / "e.####.exr"

    def said(out, options=None):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="facetransfer"):
            like_video(options, plate, out)
        return [r.getMessage() for r in caplog.records if "beyond its colour" in r.getMessage()]

    png = said(tmp_path / "o" / "x.%04d.png")
    assert len(png) == 1 and "(A); a .png result holds the colour only" in png[0]
    assert len(said(tmp_path / "o.mov", VideoOptions("prores"))) == 1
    assert said(tmp_path / "e" / "x.%04d.exr") == []
    assert "its other channels (A; only an .exr output holds them)" in \
        fact_lines(video_facts(plate))[-1]


def test_an_export_names_lost_frames_by_the_plate_s_numbers(arkit_model, make_arkit_track,
                                                             tmp_path, capsys):
    """The track of a plate numbered from 1001 whose first frames have no face: the USD's
    time codes start at 1001, and the note said "lost in frames 0-1" only; then it added the
    plate's numbers, 1001-1002, in parentheses; now it names them by those alone, as every
    message names a plate's frames."""
    import cv2
    import numpy as np

    from facetransfer.cli.main import main

    (tmp_path / "plate").mkdir()
    for k in range(1001, 1005):
        cv2.imwrite(str(tmp_path / "plate" / f"sh.{k}.png"), np.zeros((8, 8, 3), np.uint8))
    track, _, _ = make_arkit_track(arkit_model, 4)
    from dataclasses import replace

    lost = np.zeros(4, bool)
    lost[:2] = True
    track = replace(track, source=str(tmp_path / "plate" / "sh.####.png"), lost=lost)
    track.with_source_facts().save(tmp_path / "t.npz")    # as tracking the plate records it
    arkit_model.save(tmp_path / "m.npz")
    assert main([str(x) for x in ["export", tmp_path / "t.npz", "--model", tmp_path / "m.npz",
                                  "--out", tmp_path / "t.csv"]]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == ("note: the face is lost in frames 1001-1002: they hold the nearest "
                       "tracked frame's values"), out

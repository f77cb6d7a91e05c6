"""What a new user's walk through the README and the less-used commands found (forty-sixth
session, helper walk)."""

from __future__ import annotations


def _option_help(words: list[str], flag: str) -> str:
    """The help text of ``flag`` in the subcommand ``words`` (e.g. ``["puppet"]``)."""
    from facetransfer.cli.main import build_parser

    parser = build_parser()
    for w in words:
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        parser = sub.choices[w]
    action = next(a for a in parser._actions if flag in a.option_strings)
    return action.help % {"prog": parser.prog, "default": action.default} \
        if "%(" in action.help else action.help.replace("%%", "%")


def test_codec_help_promises_a_targets_depth_only_where_a_target_is_rewritten():
    """``puppet``, ``track --overlay`` and ``synth-video`` write 8-bit renders of their own
    (no target's frames: ``like_video`` is not given their output), yet their ``--codec`` help
    said ProRes kept "a target's alpha" and H.265 "a 10-bit or HDR target's depth"; and
    ``track``'s said an image sequence was ``--out frames/%05d.png`` (its ``--out`` is the
    track file: the sequence is ``--overlay``)."""
    for words in (["puppet"], ["track"], ["synth-video"]):
        text = _option_help(words, "--codec")
        assert "target" not in text, (words, text)
        assert "ProRes 422 HQ" in text
    assert "ignored for an image sequence (--overlay frames/%05d.png)" in \
        _option_help(["track"], "--codec")
    assert "(--overlay shot/%04d.exr" in _option_help(["track"], "--start-number")
    for words in (["transfer"], ["demo"]):
        assert "10-bit or HDR target's depth" in _option_help(words, "--codec")
    assert "(--out frames/%05d.png)" in _option_help(["transfer"], "--codec")


def test_the_tools_own_warning_comes_before_its_error_line():
    """``model build --dataset scans.csv --impute none`` on a manifest with a missing cell
    warned "1 of 9 cells missing", then failed with one error line; on a pipe the warning was
    most often printed after the error (5 runs of 6): configured before :func:`filtered_stderr`
    moved descriptor 2 onto its pipe, the log handler wrote through the filter's thread while
    the error line went straight out. Logging now writes to ``sys.stderr`` as it is."""
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    src = str(Path(__file__).resolve().parents[1] / "src")
    code = textwrap.dedent(f"""
        import io, logging, sys
        sys.path.insert(0, {src!r})
        from facetransfer.cli.main import configure_logging
        from facetransfer.cli.stderr import filtered_stderr
        configure_logging(False)
        with filtered_stderr():
            logging.getLogger("facetransfer.datasets").warning("1 of 9 cells missing")
            print("facetransfer model build: error: 1 missing cells", file=sys.stderr)
        kept, sys.stderr = sys.stderr, io.StringIO()
        logging.getLogger("facetransfer.x").warning("said now")
        said, sys.stderr = sys.stderr.getvalue(), kept
        print(repr(said))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ("WARNING facetransfer.datasets: 1 of 9 cells missing\n"
                        "facetransfer model build: error: 1 missing cells\n")
    assert r.stdout == repr("WARNING facetransfer.x: said now\n") + "\n"


def test_probe_does_not_say_it_describes_models(tmp_path, capsys):
    """Handed another project file, ``probe`` said it "describes videos, image sequences,
    tracks, models and Live Link Face takes"; handed a model, it refuses it and points to
    ``model info``. Its refusals now say so."""
    import numpy as np

    from facetransfer.cli.main import main

    model, other = tmp_path / "m.npz", tmp_path / "fn.npz"
    np.savez(model, core=np.zeros(3), metadata=np.array("{}"))
    np.savez(other, textures=np.zeros(3), k=np.array(4))
    assert main(["probe", str(model), str(other)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"facetransfer probe: error: {model} is a model file, not a video: "
                   f"`facetransfer model info {model}` describes it",
                   f"facetransfer probe: error: {other} is an .npz archive of arrays k, "
                   "textures, not a track or a model: probe describes videos, image sequences, "
                   "tracks and Live Link Face takes (a model: `facetransfer model info`)"]


def test_an_option_for_another_option_is_refused_without_it(tmp_path, capsys):
    """``texture lift --k`` (the texture function's neighbours) without ``--function``,
    ``export --texture-step`` without ``--texture-from`` and ``edit --ramp`` without ``--add``
    were ignored in silence (the run ended as if they were not given): one line now, nothing
    written. With the option they act with, they act as before."""
    from facetransfer.cli.main import main

    t, v = str(tmp_path / "t.npz"), str(tmp_path / "v.mp4")
    cases = [(["texture", "lift", v, "--track", t, "--k", "3", "--out", str(tmp_path / "x.png")],
              "texture lift", "--k", "--function"),
             (["export", t, "--texture-step", "3", "--out", str(tmp_path / "x.glb")],
              "export", "--texture-step", "--texture-from"),
             (["edit", t, "--scale", "smile=1.2", "--ramp", "3", "--out", str(tmp_path / "x.npz")],
              "edit", "--ramp", "--add")]
    for argv, command, flag, needed in cases:
        assert main(argv) == 2, argv
        assert capsys.readouterr().err.strip().splitlines() == [
            f"facetransfer {command}: error: {flag} acts only with {needed}, which is not "
            f"given: give {needed} or leave {flag} out"]
    assert list(tmp_path.iterdir()) == []


def test_option_with_gives_the_default_where_not_given():
    from facetransfer.cli.common import option_with

    assert option_with(None, 8, "--ramp", [], "--add") == 8
    assert option_with(3, 8, "--ramp", ["smile@1-2"], "--add") == 3
    assert option_with(None, 4, "--k", "tf.npz", "--function") == 4


def test_texture_lift_warns_of_a_video_the_track_was_not_made_from(tmp_path, caplog, capsys):
    """``texture lift OTHER.mp4 --track T.npz`` (T made from another clip of the same size)
    lifted another face's pixels through the track's motion in silence; ``export
    --texture-from`` warned of the same. Now lift does too; of the track's own clip, nothing."""
    import logging
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).parent))
    from conftest import still_track
    from test_texture_track import _cap_dataset

    from facetransfer.cli.main import main
    from facetransfer.io.video import write_video
    from facetransfer.model import build_model

    model = build_model(_cap_dataset(), {"identity": 3, "expression": 3})
    model.save(tmp_path / "m.npz")
    still_track(model, 3, source=str(tmp_path / "shot.mp4")).save(tmp_path / "t.npz")
    frames = np.full((3, 64, 64, 3), 128, np.uint8)
    for name in ("shot.mp4", "other.mp4"):
        write_video(tmp_path / name, frames, 25)
    said = []
    for name in ("shot.mp4", "other.mp4"):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="facetransfer"):
            assert main(["texture", "lift", str(tmp_path / name), "--track",
                         str(tmp_path / "t.npz"), "--model", str(tmp_path / "m.npz"),
                         "--size", "16", "--out", str(tmp_path / f"{name}.png")]) == 0
        said.append([r.getMessage() for r in caplog.records if "was made from" in
                     r.getMessage()])
    assert "merged from 3 frames," in capsys.readouterr().out
    assert main(["texture", "lift", str(tmp_path / "shot.mp4"), "--track", str(tmp_path / "t.npz"),
                 "--model", str(tmp_path / "m.npz"), "--size", "16", "--step", "5",
                 "--out", str(tmp_path / "one.png")]) == 0
    assert "(merged from 1 frame, " in capsys.readouterr().out     # was "from 1 frames"
    assert said[0] == []
    assert said[1] == [f"track {tmp_path / 't.npz'} was made from shot.mp4, not other.mp4: if "
                       "that is another clip, the texture is lifted through another face's motion"]


def test_the_demo_sheets_caption_draws_a_dash_not_question_marks(tmp_path):
    """``facetransfer demo``'s fidelity line says "–" for a measure that does not move; drawn
    under the contact sheet by OpenCV's Hershey font it read "jawOpen r=??? with the source,
    ??? with the target" (three "?" for the dash's three UTF-8 bytes)."""
    import numpy as np
    from PIL import Image

    from facetransfer.demo import contact_sheet

    frames = [np.full((60, 400, 3), 90, np.uint8)] * 2
    drawn = {}
    for name, caption in (("dash", "jawOpen r=\u2013 with the source"),
                          ("ascii", "jawOpen r=- with the source"),
                          ("asked", "jawOpen r=??? with the source")):
        contact_sheet(frames, tmp_path / f"{name}.png", caption=caption, scale=1.0)
        drawn[name] = np.asarray(Image.open(tmp_path / f"{name}.png"))
    assert np.array_equal(drawn["dash"], drawn["ascii"])
    assert not np.array_equal(drawn["dash"], drawn["asked"])
    from facetransfer.demo import drawable_caption

    assert drawable_caption("r=\u2013, 3\u00d74, caf\u00e9") == "r=-, 3x4, caf?"


def test_a_take_given_as_a_manifest_is_named_so(tmp_path):
    """``model build --dataset take.csv`` (or ``impute eval``) listed the take's 63 columns
    in lower case as unknown; it now says the file is a take."""
    import pytest

    from facetransfer.datasets.manifest import read_manifest
    from facetransfer.errors import DatasetError

    take = tmp_path / "take.csv"
    take.write_text("Timecode,BlendShapeCount,EyeBlinkLeft,JawOpen\n"
                    "00:00:00:00.000,61,0.1,0.2\n")
    with pytest.raises(DatasetError) as info:
        read_manifest(take)
    assert str(info.value) == (f"{take} is a Live Link Face take (its header starts Timecode,"
                               "BlendShapeCount), not a manifest of meshes: expected the columns "
                               "path, identity, expression[, viseme]")


def test_track_refuses_overlay_encoding_options_without_an_overlay(tmp_path, capsys):
    """``track V --out T.npz --codec prores`` (or ``--crf``, ``--preset``) wrote the track and
    ignored the option, which sets only the ``--overlay`` video; ``--start-number`` was already
    refused there ("none is written here")."""
    from facetransfer.cli.main import main

    t = tmp_path / "t.npz"
    for extra, flag in ((["--codec", "prores"], "--codec"), (["--crf", "30"], "--crf"),
                        (["--preset", "slow"], "--preset")):
        assert main(["track", str(tmp_path / "v.mp4"), "--out", str(t), *extra]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [
            f"facetransfer track: error: {flag} sets the --overlay video's encoding, and none is "
            f"written here: give --overlay OVERLAY.mp4 or leave {flag} out"]
    assert not t.exists()


def test_scan_fit_refuses_options_it_would_not_use(tmp_path, capsys):
    """``scan fit`` took ``--texture`` / ``--flip-v`` with a feature file (they act only on the
    automatic search), ``--template-landmarks`` with the ICT template (even a file that did
    not exist) and ``--prior identity+expression`` with ``--reference``, and ignored them."""
    from facetransfer.cli.main import main

    scan, out = str(tmp_path / "s.ply"), str(tmp_path / "fit.obj")
    cases = [(["--features", "f.json", "--texture", "t.png"],
              "--texture acts only with --features auto (the points found on the scan's "
              "rendering)"),
             (["--features", "f.json", "--flip-v"], "--flip-v acts only with --features auto "
              "(the points found on the scan's rendering)"),
             (["--template-landmarks", "x.json"], "--template-landmarks is for a mesh template; "
              "the ict template has its own landmarks"),
             (["--template", "M.NPZ", "--template-landmarks", "x.json"],   # as load_template
              "--template-landmarks is for a mesh template; the M.NPZ template has its own "
              "landmarks"),                                                # reads it: a model
             (["--reference", "n.obj", "--prior", "identity+expression"],
              "--prior is not used with --reference (the reference fit is deformed)")]
    for extra, why in cases:
        assert main(["scan", "fit", scan, *extra, "--out", out]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [
            f"facetransfer scan fit: error: {why}: leave it out"]
    assert list(tmp_path.iterdir()) == []


def test_view_of_a_model_refuses_another_model(tmp_path, capsys):
    """``view M.npz --model OTHER.npz`` wrote M's page and ignored ``--model`` (which names a
    track's or a take's model)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_texture_track import _cap_dataset

    from facetransfer.cli.main import main
    from facetransfer.model import build_model

    m, other = tmp_path / "m.npz", tmp_path / "other.npz"
    build_model(_cap_dataset(), {"identity": 3, "expression": 3}).save(m)
    other.write_bytes(m.read_bytes())
    out = tmp_path / "page.html"
    assert main(["view", str(m), "--model", str(other), "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"facetransfer view: error: --model is a track's or a take's model; {m} is a model "
        "itself: view it without --model"]
    assert not out.exists()


def test_puppet_refuses_a_tracker_where_nothing_is_tracked(tmp_path, data_dir, capsys):
    """``puppet TRACK.npz --tracker flow``, ``puppet take.csv --tracker landmarks`` and
    ``puppet VIDEO --track T.npz --tracker flow`` rendered and ignored ``--tracker`` (nothing
    is tracked there); ``--track`` and ``--face`` were already refused with a track or take."""
    from facetransfer.cli.main import main

    clip = str(data_dir / "video" / "face_2.mp4")
    t, take, out = tmp_path / "t.npz", tmp_path / "take.csv", str(tmp_path / "p.mp4")
    t.write_bytes(b"x")
    take.write_text("Timecode,BlendShapeCount,JawOpen\n00:00:00:00.000,1,0.5\n")
    cases = [([str(t), "--tracker", "flow"], f"{t} is a track file: --tracker is for a video"),
             ([str(take), "--tracker", "landmarks"],
              f"{take} is a Live Link Face take: --tracker is for a video"),
             ([clip, "--track", str(t), "--tracker", "klt"], f"--tracker flow chooses how VIDEO "
              f"is tracked, but --track {t} is tracked already: give one of them")]
    for argv, says in cases:
        assert main(["puppet", *argv, "--out", out]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [
            f"facetransfer puppet: error: {says}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz", "take.csv"]


def test_edit_builds_the_default_model_as_the_other_commands_do(tmp_path, monkeypatch, capsys):
    """``edit T.npz`` without ``--model`` where the default model is not built yet (a track
    from another machine, a cleared cache) said "no default model cached yet (run `facetransfer
    demo` ...)"; ``export``, ``view`` and ``puppet`` build it on first use, and so does edit
    now. Its help said "the demo's default model"."""
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).parent))
    from conftest import still_track
    from test_texture_track import _cap_dataset

    import facetransfer.default_model as dm
    from facetransfer.cli.main import main
    from facetransfer.model import build_model

    model = build_model(_cap_dataset(), {"identity": 3, "expression": 3})
    still_track(model, 4, source="shot.mp4").save(tmp_path / "t.npz")
    built = []
    monkeypatch.setattr(dm, "default_model_path", lambda: tmp_path / "not-built.npz")
    monkeypatch.setattr(dm, "load_default_model",
                        lambda **kw: built.append(1) or model)
    label = model.labels[model.mode_index("expression")][1]
    assert main(["edit", str(tmp_path / "t.npz"), "--add", f"{label}@1-2", "--ramp", "0",
                 "--out", str(tmp_path / "e.npz")]) == 0, capsys.readouterr().err
    assert built == [1] and np.load(tmp_path / "e.npz")["fps"] == 25.0
    assert "if the track was made with it" in _option_help(["edit"], "--model")


def test_a_folder_given_for_a_video_proposes_its_largest_sequence(tmp_path):
    """A plate folder given where a video is expected names the sequence to give; with two
    stray numbered stills sorted first (``notes1.png``, ``notes2.png``) it proposed those
    instead of the plate's frames."""
    import cv2
    import numpy as np

    from facetransfer.io.video import VideoError
    from facetransfer.io.video_read import video_info
    from facetransfer.io.video_sequence import suggested_pattern

    img = np.zeros((8, 8, 3), np.uint8)
    for name in ["notes1.png", "notes2.png"] + [f"sh010.{k}.png" for k in range(1001, 1006)]:
        cv2.imwrite(str(tmp_path / name), img)
    assert suggested_pattern(tmp_path) == tmp_path / "sh010.%04d.png"
    try:
        video_info(tmp_path)
    except VideoError as exc:
        assert str(exc).endswith(f"(its image sequence: give {tmp_path / 'sh010.%04d.png'})")
    else:
        raise AssertionError("a folder was read as a video")
    (tmp_path / "alone").mkdir()
    cv2.imwrite(str(tmp_path / "alone" / "still7.png"), img)
    assert suggested_pattern(tmp_path / "alone") is None


def test_a_folder_of_an_unpadded_numbering_proposes_the_pattern_that_reads_every_frame(
        tmp_path):
    """Frames numbered without padding (``frame1.png`` .. ``frame30.png``): ``frame%01d.png``
    reads all 30; the pattern of the most names of one width, ``frame%02d.png``, proposed
    before, reads 10 .. 30 and left frames 1-9 out. The plate beside stray stills still
    wins."""
    import cv2
    import numpy as np

    from facetransfer.io.video_sequence import sequence_files, suggested_pattern

    img = np.zeros((8, 8, 3), np.uint8)
    for k in range(1, 31):
        cv2.imwrite(str(tmp_path / f"frame{k}.png"), img)
    for name in ("notes1.png", "notes2.png", "notes3.png"):
        cv2.imwrite(str(tmp_path / name), img)
    got = suggested_pattern(tmp_path)
    assert got == tmp_path / "frame%01d.png"
    assert sorted(sequence_files(got)) == list(range(1, 31))


def test_every_subcommands_help_says_what_it_does():
    """``facetransfer model build --help`` (and ``model info|synth|sheet|dials``, ``scan
    smooth|features|fit``, ``texture default``) printed only the usage and the options: the
    one line its group's help gives it was not its description."""
    import argparse

    from facetransfer.cli.main import build_parser

    def leaves(parser, path):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            yield " ".join(path), parser
        for action in subs:
            for name, child in action.choices.items():
                yield from leaves(child, path + [name])

    undescribed = [name for name, p in leaves(build_parser(), []) if not p.description]
    assert undescribed == []
    described = dict(leaves(build_parser(), []))
    assert described["model build"].description == "Build a model from a data set."
    assert described["scan fit"].format_help().count("Fit the template to a scan") == 1


def test_a_takes_page_says_take_not_track(tmp_path, arkit_model):
    """``view take.csv``'s page said "track of take.csv"; a track's page still says "track of"
    its clip."""
    import json
    import re
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from conftest import synthetic_arkit_track

    from facetransfer.export.livelink import write_livelink
    from facetransfer.export.viewer import viewer_page
    from facetransfer.take import take_track

    def about(page):
        data = re.search(r'<script id="ft-data" type="application/json">(.*?)</script>', page,
                         re.S).group(1)
        return json.loads(data)["about"]

    track, _, _ = synthetic_arkit_track(arkit_model, 6)
    write_livelink(track, tmp_path / "take.csv")
    k = arkit_model.mode_index("identity")
    take = take_track(tmp_path / "take.csv", arkit_model, arkit_model.weight_mean(k))
    said = about(viewer_page(arkit_model, track=take, title="take.csv"))
    assert said.endswith(f"take take.csv, {take.n_frames} frames at {take.fps:g} fps"), said
    said = about(viewer_page(arkit_model, track=track, title="t.npz"))
    assert said.endswith("track of synthetic.mp4, 6 frames at 25 fps"), said


def test_a_track_or_a_video_given_as_a_mesh_is_named(tmp_path):
    """``scan smooth T.npz`` (or a video) said trimesh's "cannot read mesh T.npz: file_type
    'npz' not supported"; it now says what the file is and which files are meshes."""
    import numpy as np
    import pytest

    from facetransfer.errors import MeshError
    from facetransfer.io.mesh import read_mesh
    from facetransfer.io.video import write_video

    np.savez(tmp_path / "t.npz", rotation=np.eye(3))
    with pytest.raises(MeshError) as info:
        read_mesh(tmp_path / "t.npz")
    assert str(info.value) == (f"mesh file {tmp_path / 't.npz'} is an .npz archive (a track, "
                               "a model, a ground truth), not a mesh: give one of .obj, .ply, "
                               ".stl, .off, .glb")
    write_video(tmp_path / "v.mp4", np.zeros((2, 16, 16, 3), np.uint8), 25)
    with pytest.raises(MeshError, match="is a video, not a mesh"):
        read_mesh(tmp_path / "v.mp4")


def test_every_option_and_argument_has_help():
    """Each option and argument of each command says what it is in its ``--help`` (before,
    ``view --out``, ``edit --out`` and ``TRACK.npz``, ``batch transfer --manifest``, ``batch
    export --format``, ``puppet``'s, ``export``'s and ``probe``'s inputs showed a bare name)."""
    import argparse

    from test_readme import _subcommands

    from facetransfer.cli.main import build_parser

    parsers = {"facetransfer": build_parser(), **_subcommands(build_parser())}
    assert len(parsers) > 30
    bare = [(words, a.option_strings or a.dest) for words, p in parsers.items()
            for a in p._actions
            if not a.help and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
    assert bare == []

"""CLI tests of ``facetransfer render`` and ``facetransfer synth-video``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.model import build_model
from facetransfer.synth import load_truth

from test_synth import tiny_dataset


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    m = build_model(tiny_dataset(), {"identity": 3, "expression": 4})
    p = tmp_path_factory.mktemp("cli") / "tiny.npz"
    m.save(p)
    return p


def test_render_preview_png(model_path, tmp_path, capsys):
    import cv2

    out = tmp_path / "face.png"
    rc = main(["render", str(model_path), "--like", "identity=id1,expression=smile",
               "--pose", "yaw=20,pitch=-5,scale=0.9", "--size", "120x100",
               "--background", "0,0,255", "--out", str(out)])
    assert rc == 0 and "wrote" in capsys.readouterr().out
    img = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert img.shape == (100, 120, 3)
    bg = np.all(img == [0, 0, 255], axis=2)
    assert 0.2 < bg.mean() < 0.9  # the face covers part of the frame
    face = img[~bg]
    assert np.all(face[:, 0] == face[:, 1])  # grey Lambert shading


@pytest.mark.parametrize("argv, match", [
    (["--pose", "yaw=abc"], "--pose"),
    (["--pose", "tilt=3"], "--pose"),
    (["--size", "100"], "--size"),
    (["--background", "1,2"], "--background"),
    (["--like", "identity=nobody"], "unknown identity"),
    (["--weights", "expression=1,2"], "expression has 2 values"),
])
def test_render_bad_arguments(model_path, tmp_path, capsys, argv, match):
    rc = main(["render", str(model_path), "--out", str(tmp_path / "x.png"), *argv])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_render_bad_paths(model_path, tmp_path, capsys):
    assert main(["render", str(tmp_path / "none.npz"), "--out", str(tmp_path / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["render", str(model_path), "--out", str(tmp_path / "no" / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["render", str(model_path), "--out", str(tmp_path / "x.gif")]) == 2
    assert ".png" in capsys.readouterr().err


def test_synth_video_random(model_path, tmp_path, capsys):
    import cv2

    out = tmp_path / "clip.mp4"
    rc = main(["synth-video", "--model", str(model_path), "--random", "--frames", "6",
               "--seed", "2", "--size", "64x48", "--fps", "12", "--identity", "id0",
               "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    cap = cv2.VideoCapture(str(out))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    assert (cap.get(cv2.CAP_PROP_FRAME_WIDTH), cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (64, 48)
    cap.release()
    tr = load_truth(out)
    assert tr.n_frames == 6 and tr.fps == 12 and tr.landmarks2d.shape == (6, 68, 2)


def test_synth_video_spec_with_overrides(model_path, tmp_path, capsys):
    spec = tmp_path / "perf.json"
    spec.write_text(json.dumps({"fps": 30, "size": [80, 60],
                                "tracks": {"expression": [[0, "neutral"], [4, "open"]]}}))
    out = tmp_path / "c.mp4"
    rc = main(["synth-video", "--model", str(model_path), "--performance", str(spec),
               "--identity", "0.5,0.2,0.1", "--size", "48x40", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    tr = load_truth(tmp_path / "c.truth.npz")
    assert tr.frame_size == (48, 40) and tr.fps == 30 and tr.n_frames == 5
    np.testing.assert_array_equal(tr.weights["identity"][0], [0.5, 0.2, 0.1])


@pytest.mark.parametrize("argv, match", [
    ([], "give --performance SPEC.json or --random"),
    (["--random", "--performance", "p.json"], "--random, not both"),
    (["--random", "--frames", "0"], "--frames"),
    (["--random", "--fps", "-3"], "--fps"),
    (["--random", "--identity", "1,2"], "identity"),
    (["--performance", "missing.json"], "does not exist"),
    (["--random", "--texture", "nothere.png"], "does not exist"),
    (["--random", "--texture", "notimage.png"], "not an image"),
])
def test_synth_video_bad_arguments(model_path, tmp_path, capsys, monkeypatch, argv, match):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notimage.png").write_text("plain text")
    rc = main(["synth-video", "--model", str(model_path), "--out", "c.mp4", *argv])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and err.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ["notimage.png"]


def test_synth_video_texture_file(model_path, tmp_path, capsys):
    import cv2

    tex = np.zeros((32, 32, 3), np.uint8)
    tex[:] = (0, 255, 0)  # BGR green on disk -> RGB (0, 255, 0)
    cv2.imwrite(str(tmp_path / "tex.png"), tex)
    rc = main(["synth-video", "--model", str(model_path), "--random", "--frames", "2",
               "--size", "64x48", "--texture", str(tmp_path / "tex.png"),
               "--out", str(tmp_path / "g.mp4")])
    assert rc == 0, capsys.readouterr().err
    cap = cv2.VideoCapture(str(tmp_path / "g.mp4"))
    ok, bgr = cap.read()
    cap.release()
    assert ok
    tr = load_truth(tmp_path / "g.mp4")
    xy = np.rint(tr.vertices2d[0][tr.visible[0]]).astype(int)
    px = bgr[xy[:, 1], xy[:, 0]].astype(int)  # BGR at visible vertices: shaded green
    assert np.median(px[:, 1]) > 100 and np.median(px[:, 0]) < 40 and np.median(px[:, 2]) < 40


def test_synth_video_to_an_image_sequence_says_it_writes_a_video(model_path, tmp_path, capsys):
    """An image-sequence --out in a folder not made yet: said to need a video (before: "output
    folder ... does not exist", and once made, "expected a video")."""
    rc = main(["synth-video", "--model", str(model_path), "--random", "--frames", "2",
               "--out", str(tmp_path / "sv" / "%04d.png")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.endswith("synth-video writes no image sequence)") and "\n" not in err


def test_a_wrong_colour_or_a_missing_spec_is_said_before_the_model(tmp_path, capsys, monkeypatch):
    """``render --background`` and ``synth-video --performance`` are checked before the model
    is resolved: on a first run that builds the default model (a minute), a wrong colour or a
    missing spec file was said after it (and its "building" line came first)."""
    import facetransfer.cli.render as cli_render

    def no_model(path):
        raise AssertionError("the model was resolved before the arguments were checked")

    monkeypatch.setattr(cli_render, "resolve_model", no_model)
    assert main(["render", "--background", "300,0,0", "--out", str(tmp_path / "r.png")]) == 2
    assert "--background" in capsys.readouterr().err
    assert main(["synth-video", "--performance", str(tmp_path / "missing.json"),
                 "--out", str(tmp_path / "s.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        f"facetransfer synth-video: error: performance spec {tmp_path / 'missing.json'} "
        "does not exist"]

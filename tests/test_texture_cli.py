"""CLI ``facetransfer texture default|lift|blend``: outputs, and one-line errors with exit 2."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from facetransfer.cli import main as cli_main
from facetransfer.model import build_model
from facetransfer.synth import make_clip, random_performance, write_clip

from test_texture_track import _cap_dataset


@pytest.fixture()
def run():
    return lambda *argv: cli_main.main([str(a) for a in argv])


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("tm") / "cap.npz"
    build_model(_cap_dataset(), {"identity": 3, "expression": 3}).save(p)
    return p


def _write(path, rgb):
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def _read(path):
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def test_blend_offset_source_gives_target(run, tmp_path):
    yy, xx = np.mgrid[:80, :100]
    t = np.stack([60 + xx, 50 + yy, 100 + 0 * xx], -1).astype(np.uint8)
    s = t + 30
    m = np.zeros((80, 100), np.uint8)
    m[:40, :50] = 255  # touches the border: the solver path
    _write(tmp_path / "s.png", s)
    _write(tmp_path / "t.png", t)
    _write(tmp_path / "m.png", np.dstack([m] * 3))
    for extra in ([], ["--feather", "3"]):
        assert run("texture", "blend", "--source", tmp_path / "s.png", "--target", tmp_path / "t.png",
                   "--mask", tmp_path / "m.png", "--out", tmp_path / "o.png", "--overwrite",
                   *extra) == 0
        assert np.abs(_read(tmp_path / "o.png").astype(int) - t).max() <= 1


def test_default_and_lift(run, tmp_path, model_path):
    assert run("texture", "default", "--model", model_path, "--size", 64, "--out", tmp_path / "d.png") == 0
    assert _read(tmp_path / "d.png").shape == (64, 64, 3)

    from facetransfer.model import load_model

    model = load_model(model_path)
    yy, xx = np.mgrid[:64, :64]
    ramp = np.stack([40 + 3 * xx, 40 + 3 * yy, 120 + 0 * xx], -1).astype(np.uint8)
    _write(tmp_path / "ramp.png", ramp)
    clip = make_clip(model, random_performance(model, 6, seed=0, size=(160, 128)), texture=ramp)
    write_clip(clip, tmp_path / "c.mp4")
    rc = run("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "c.truth.npz", "--model",
             model_path, "--size", 64, "--step", 2, "--function", tmp_path / "tf.npz",
             "--out", tmp_path / "lift.png")
    assert rc == 0
    lifted = _read(tmp_path / "lift.png").astype(float)
    truth = ramp.astype(float)
    # Lambert shading and video compression: the lifted texture is darker but follows the ramps
    for ch in (0, 1):
        c = np.corrcoef(lifted[8:56, 8:56, ch].ravel(), truth[8:56, 8:56, ch].ravel())[0, 1]
        assert c > 0.9
    assert (tmp_path / "tf.npz").is_file()



def test_lift_from_an_odd_sized_clip_and_its_truth(run, tmp_path, model_path, capsys):
    """synth-video at an odd size (63x47) stores its frames grown to 64x48 (4:2:0, the edge
    repeated) beside a truth of 63x47: lifting the clip through its own truth was refused
    ("track ... is for 63x47 frames, the video is 64x48"). The frames are now taken without
    the repeated edge (here 95x79 in 96x80), the texture's ramp where it belongs; a truth of
    another size is still refused."""
    from facetransfer.model import load_model

    model = load_model(model_path)
    yy, xx = np.mgrid[:64, :64]
    ramp = np.stack([40 + 3 * xx, 40 + 3 * yy, 120 + 0 * xx], -1).astype(np.uint8)
    perf = random_performance(model, 3, seed=0, size=(95, 79))
    write_clip(make_clip(model, perf, texture=ramp), tmp_path / "odd.mp4")
    capsys.readouterr()
    assert run("texture", "lift", tmp_path / "odd.mp4", "--track", tmp_path / "odd.truth.npz",
               "--model", model_path, "--size", 32, "--out", tmp_path / "l.png") == 0, \
        capsys.readouterr().err
    lifted = _read(tmp_path / "l.png").astype(float)
    c = np.corrcoef(lifted[4:28, 4:28, 0].ravel(), np.tile(np.arange(24), 24))[0, 1]
    assert c > 0.9                                    # the ramp along u, where it belongs
    assert run("texture", "lift", tmp_path / "odd.mp4", "--track", tmp_path / "odd.truth.npz",
               "--model", model_path, "--size", 32, "--out", tmp_path / "l.png") == 2
    other = random_performance(model, 3, seed=0, size=(93, 79))   # not the clip's: refused
    write_clip(make_clip(model, other), tmp_path / "other.mp4")
    capsys.readouterr()
    assert run("texture", "lift", tmp_path / "odd.mp4", "--track", tmp_path / "other.truth.npz",
               "--model", model_path, "--size", 32, "--out", tmp_path / "l2.png") == 2
    assert "is for 93x79 frames, the video is 96x80" in capsys.readouterr().err


def test_errors_are_one_line(run, tmp_path, model_path, capsys):
    img = np.zeros((20, 20, 3), np.uint8)
    _write(tmp_path / "a.png", img)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    cases = [
        ("texture", "blend", "--source", tmp_path / "a.png", "--target", tmp_path / "a.png",
         "--mask", tmp_path / "missing.png", "--out", tmp_path / "o.png"),
        ("texture", "blend", "--source", tmp_path / "bad.png", "--target", tmp_path / "a.png",
         "--mask", tmp_path / "a.png", "--out", tmp_path / "o.png"),
        ("texture", "blend", "--source", tmp_path / "a.png", "--target", tmp_path / "a.png",
         "--mask", tmp_path / "a.png", "--out", tmp_path / "nodir" / "o.png"),
        ("texture", "default", "--model", tmp_path / "nomodel.npz", "--out", tmp_path / "d.png"),
        ("texture", "default", "--model", model_path, "--out", tmp_path / "d.txt"),
        ("texture", "default", "--model", model_path, "--source", "lee-perry-smith",
         "--out", tmp_path / "d.png"),  # the cap model's UVs are not ICT-FaceKit's
        ("texture", "lift", tmp_path / "none.mp4", "--track", tmp_path / "t.npz", "--model",
         model_path, "--out", tmp_path / "l.png"),
    ]
    for argv in cases:
        capsys.readouterr()
        assert run(*argv) == 2
        err = capsys.readouterr().err.strip()
        assert re.match(r"facetransfer texture \w+: error:", err) and "\n" not in err
    # a mask of 0 and 1 (white is 255): nothing would be pasted; said, not a copy of the target
    _write(tmp_path / "one.png", np.ones((20, 20, 3), np.uint8))
    assert run("texture", "blend", "--source", tmp_path / "a.png", "--target", tmp_path / "a.png",
               "--mask", tmp_path / "one.png", "--out", tmp_path / "o.png") == 2
    assert capsys.readouterr().err.strip().endswith(
        "has no white pixel (above 127; its brightest is 1): nothing to paste (a mask of 0 and "
        "1? white is 255)")
    assert not (tmp_path / "o.png").exists()


def test_lift_a_track_of_the_clips_first_frames(run, tmp_path, model_path, capsys):
    """A track of a clip's first frames only (``track --max-frames``) lifts from those frames
    (before: "the clip has more frames than the track"); a bad --k is refused before anything
    is written; a track of another model is named with its file and the cause."""
    from facetransfer.model import load_model
    from facetransfer.synth import load_truth
    from facetransfer.track import Track

    model = load_model(model_path)
    clip = make_clip(model, random_performance(model, 6, seed=1, size=(160, 128)))
    write_clip(clip, tmp_path / "c.mp4")
    t = load_truth(tmp_path / "c.truth.npz")
    k = 4

    def first(weights):
        return Track(fps=t.fps, frame_size=t.frame_size, rotation=t.rotation[:k],
                     scale=t.scale[:k], translation=t.translation[:k], weights=weights,
                     landmarks2d=np.zeros((k, 68, 2)), confidence=np.ones(k),
                     lost=np.zeros(k, bool), model_hash=model.content_hash,
                     mode_names=model.mode_names, source=str(tmp_path / "c.mp4"))

    first({m: w[:k] for m, w in t.weights.items()}).save(tmp_path / "t4.npz")
    argv = ("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "t4.npz", "--model",
            model_path, "--size", 32, "--step", 1)
    assert run(*argv, "--function", tmp_path / "f.npz", "--k", 0,
               "--out", tmp_path / "bad.png") == 2
    assert "--k must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists() and not (tmp_path / "f.npz").exists()
    assert run(*argv, "--out", tmp_path / "l.png") == 0
    assert "merged from 4 frames" in capsys.readouterr().out
    other = {m: np.zeros((k, r + 1)) for m, r in zip(model.mode_names, model.ranks)}
    other_track = first(other)
    object.__setattr__(other_track, "model_hash", "0" * 16)
    other_track.save(tmp_path / "other.npz")
    assert run(*argv[:4], tmp_path / "other.npz", *argv[5:], "--out", tmp_path / "o.png") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"facetransfer texture lift: error: track {tmp_path / 'other.npz'} was "
                          "made with another model") and "--model" in err, err


def test_lift_function_that_would_not_fit_is_refused_with_the_step_that_fits(
        run, tmp_path, model_path, capsys, monkeypatch):
    """``--function`` holds every used frame's texture (twice while the function is made):
    past the memory available it is refused before any frame is read, naming the --step that
    fits; the merged texture alone is made in one texture's memory and is not refused."""
    from facetransfer.io import memory
    from facetransfer.model import load_model

    model = load_model(model_path)
    clip = make_clip(model, random_performance(model, 6, seed=2, size=(160, 128)))
    write_clip(clip, tmp_path / "c.mp4")
    # 6 frames of 64² textures (64 KB each, 128 KB while the function is made): room for 2
    monkeypatch.setattr(memory, "available_memory", lambda: 2 * 2 * 64 * 64 * 16)
    argv = ("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "c.truth.npz",
            "--model", model_path, "--size", 64)
    capsys.readouterr()
    assert run(*argv, "--function", tmp_path / "f.npz", "--out", tmp_path / "l.png") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--function keeps the texture of each of the 6 frames" in err[0]
    assert "give --step 3 or more" in err[0]
    assert not (tmp_path / "l.png").exists() and not (tmp_path / "f.npz").exists()
    assert run(*argv, "--step", 3, "--function", tmp_path / "f.npz",
               "--out", tmp_path / "l.png") == 0
    assert run(*argv, "--out", tmp_path / "m.png") == 0      # no function: merged as it goes
    assert "merged from 6 frames" in capsys.readouterr().out
    # the function named as the texture: said as such (before: "is also an input")
    assert run(*argv, "--function", tmp_path / "n.png", "--out", tmp_path / "n.png") == 2
    assert "is --out's file" in capsys.readouterr().err


def test_lift_from_a_truth_of_another_model_is_one_line(run, tmp_path, model_path, capsys):
    """``--track CLIP.truth.npz`` with a model of other modes or ranks than the clip's: one
    line naming the truth file (before: a KeyError traceback, exit 1, for a model with a mode
    the clip has not; a shape error about weights for other ranks)."""
    from facetransfer.model import load_model

    model = load_model(model_path)
    write_clip(make_clip(model, random_performance(model, 3, seed=0, size=(96, 80))),
               tmp_path / "c.mp4")
    three = tmp_path / "three.npz"
    build_model(_cap_dataset(), {"identity": 2, "expression": 3}).save(three)
    capsys.readouterr()
    assert run("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "c.truth.npz",
               "--model", three, "--size", 32, "--out", tmp_path / "l.png") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"facetransfer texture lift: error: ground truth {tmp_path / 'c.truth.npz'} was "
                   "rendered with another model (modes and ranks {'identity': 3, 'expression': "
                   "3}, the model's {'identity': 2, 'expression': 3}): give the model "
                   "synth-video used as --model"], err
    assert not (tmp_path / "l.png").exists()


def test_lift_from_a_truth_of_another_model_without_model_is_one_line(run, tmp_path, model_path,
                                                                    capsys, monkeypatch):
    """``--track CLIP.truth.npz`` without ``--model`` (README: the default model, for a truth it
    rendered; another is refused, naming the file), of a clip another model rendered: one line
    naming the truth file and asking for --model (before: an AttributeError traceback, exit 1,
    from the track-only path that names a track by its ``label``)."""
    import facetransfer.default_model as default_model
    from facetransfer.model import load_model

    model = load_model(model_path)
    write_clip(make_clip(model, random_performance(model, 3, seed=0, size=(96, 80))),
               tmp_path / "c.mp4")
    other = build_model(_cap_dataset(), {"identity": 2, "expression": 3})
    monkeypatch.setattr(default_model, "load_default_model", lambda **kw: other)
    capsys.readouterr()
    assert run("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "c.truth.npz",
               "--size", 32, "--out", tmp_path / "l.png") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (f"facetransfer texture lift: error: ground truth "
                       f"{tmp_path / 'c.truth.npz'} was rendered with another model (modes and "
                       "ranks {'identity': 3, 'expression': 3}, the model's {'identity': 2, "
                       "'expression': 3}): give the model synth-video used as --model"), err
    assert not (tmp_path / "l.png").exists()
    monkeypatch.setattr(default_model, "load_default_model", lambda **kw: model)
    assert run("texture", "lift", tmp_path / "c.mp4", "--track", tmp_path / "c.truth.npz",
               "--size", 32, "--out", tmp_path / "l.png") == 0    # the model that rendered it
    assert (tmp_path / "l.png").is_file()


def test_blend_with_opencv_where_it_cannot_is_said_in_the_options_words(run, tmp_path, capsys):
    """``--method opencv`` with a mask touching the border (or with --feather): one line in
    the command's words (before: "method='opencv' needs ...; use method='solver'")."""
    img = np.full((40, 50, 3), 90, np.uint8)
    _write(tmp_path / "a.png", img)
    m = np.zeros((40, 50), np.uint8)
    m[10:30, :20] = 255                          # reaches the left border
    _write(tmp_path / "m.png", np.dstack([m] * 3))
    for extra in ([], ["--feather", "2"]):
        capsys.readouterr()
        assert run("texture", "blend", "--source", tmp_path / "a.png", "--target",
                   tmp_path / "a.png", "--mask", tmp_path / "m.png", "--method", "opencv",
                   *extra, "--out", tmp_path / "o.png") == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"facetransfer texture blend: error: --method opencv needs a mask "
                       f"({tmp_path / 'm.png'}) of one connected region at least 2 pixels from "
                       "the image border, and no --feather; give --method solver or auto"], err
    assert not (tmp_path / "o.png").exists()


def test_blend_keeps_a_16_bit_target_s_bits(run, tmp_path, caplog, capsys):
    """A 16-bit PNG target gives a 16-bit PNG whose values off the mask are the target's, and
    inside a source offset by a constant the target's again (the solver's, in 16 bits; before:
    an 8-bit file, said nowhere); an 8-bit source is taken as ``x 257``; a .jpg out says in a
    warning naming the target that it holds 8 bits; --method opencv is refused."""
    yy, xx = np.mgrid[:60, :70]
    t = np.stack([1000 + 300 * xx, 2000 + 400 * yy, 40000 + 0 * xx], -1).astype(np.uint16)
    m = np.zeros((60, 70), np.uint8)
    m[15:45, 20:50] = 255
    assert cv2.imwrite(str(tmp_path / "t.png"), t[..., ::-1])
    assert cv2.imwrite(str(tmp_path / "s.png"), (t[..., ::-1] + 5000).astype(np.uint16))
    _write(tmp_path / "m.png", np.dstack([m] * 3))
    flat = np.full((60, 70, 3), 100, np.uint8)
    _write(tmp_path / "s8.png", flat)
    common = ("texture", "blend", "--target", tmp_path / "t.png", "--mask", tmp_path / "m.png")
    assert run(*common, "--source", tmp_path / "s.png", "--out", tmp_path / "o.png") == 0
    o = cv2.imread(str(tmp_path / "o.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert o.dtype == np.uint16
    assert np.array_equal(o[m == 0], t[m == 0])
    assert np.abs(o.astype(int) - t).max() <= 2      # an offset source gives the target back
    assert run(*common, "--source", tmp_path / "s8.png", "--out", tmp_path / "o8.png") == 0
    o8 = cv2.imread(str(tmp_path / "o8.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert o8.dtype == np.uint16 and np.array_equal(o8[m == 0], t[m == 0])
    inner = o8[25:35, 30:40].astype(int)             # flat source: the membrane of the border
    assert inner.min() > 255 and np.ptp(inner[..., 2]) == 0 and inner[0, 0, 2] == 40000
    caplog.clear()
    assert run(*common, "--source", tmp_path / "s.png", "--out", tmp_path / "o.jpg") == 0
    assert cv2.imread(str(tmp_path / "o.jpg"), cv2.IMREAD_UNCHANGED).dtype == np.uint8
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
        f"target {tmp_path / 't.png'} is 16-bit; {tmp_path / 'o.jpg'} holds 8 bits: written in "
        "8 (give a .png to keep 16)"]
    capsys.readouterr()
    assert run(*common, "--source", tmp_path / "s.png", "--method", "opencv",
               "--out", tmp_path / "cv.png") == 2
    assert capsys.readouterr().err.strip() == (
        f"facetransfer texture blend: error: --method opencv takes 8-bit images; the target "
        f"{tmp_path / 't.png'} is 16-bit: give --method solver or auto (16 bits kept)")
    assert not (tmp_path / "cv.png").exists()


def test_blend_scales_an_8_bit_source_to_a_16_bit_target_by_257(run, tmp_path):
    """An 8-bit source's gradients join a 16-bit target's on its scale, ``x 257`` (255 ->
    65535), not ``<< 8`` or unscaled: a target that is the source ``x 257`` plus a constant
    comes back inside the mask within rounding (``<< 8``: off by ~150, unscaled: by
    thousands; a flat source, the test above, or a ramp cannot tell them). A 16-bit source
    into an 8-bit target is taken in 8 bits (``round(v / 257)``)."""
    yy, xx = np.mgrid[:60, :70]
    bump = 150 * np.exp(-((xx - 35) ** 2 + (yy - 30) ** 2) / 120.0)   # not harmonic: a ramp
    s8 = np.rint(np.stack([bump + 2 * xx, bump + 40, 3 * yy + 0 * xx], -1)).astype(np.uint8)
    t16 = s8.astype(np.uint16) * 257 + 1234
    m = np.zeros((60, 70), np.uint8)
    m[10:50, 15:55] = 255
    _write(tmp_path / "s8.png", s8)
    assert cv2.imwrite(str(tmp_path / "t16.png"), t16[..., ::-1])
    _write(tmp_path / "m.png", np.dstack([m] * 3))
    assert run("texture", "blend", "--source", tmp_path / "s8.png", "--target",
               tmp_path / "t16.png", "--mask", tmp_path / "m.png", "--out",
               tmp_path / "o.png") == 0
    o = cv2.imread(str(tmp_path / "o.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert o.dtype == np.uint16
    assert np.abs(o.astype(int) - t16).max() <= 2
    s16 = s8.astype(np.uint16) * 257 + 257 * 7             # the source, 16-bit, 7 levels up
    assert cv2.imwrite(str(tmp_path / "s16.png"), s16[..., ::-1])
    t8 = (s8.astype(int) + 20).astype(np.uint8)
    _write(tmp_path / "t8.png", t8)
    assert run("texture", "blend", "--source", tmp_path / "s16.png", "--target",
               tmp_path / "t8.png", "--mask", tmp_path / "m.png", "--out",
               tmp_path / "o8.png") == 0
    o8 = cv2.imread(str(tmp_path / "o8.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert o8.dtype == np.uint8 and np.abs(o8.astype(int) - t8).max() <= 1

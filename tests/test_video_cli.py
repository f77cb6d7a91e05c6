"""Commands that write video: --codec/--crf, bad outputs, a full disk, the default model, and
third-party log lines kept off stderr (issue 13 items 2-3, issue 16 defect 1)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.io import video as iov
from facetransfer.io.video import decoded_frame_count, read_video, write_video
from facetransfer.synth import make_clip, random_performance
from facetransfer.track import Track

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture(scope="module")
def clip_and_track(quick_model, tmp_path_factory):
    """A 6-frame synthetic clip on disk and its true track (no tracking needed)."""
    d = tmp_path_factory.mktemp("videocli")
    perf = random_performance(quick_model, 6, seed=2, size=(160, 120), fps=25, fill=0.8)
    clip = make_clip(quick_model, perf, seed=2)
    video = d / "clip.mp4"
    write_video(video, clip.frames, 25)
    t = clip.truth
    track = d / "clip.npz"
    Track(fps=t.fps, frame_size=t.frame_size, rotation=t.rotation, scale=t.scale,
          translation=t.translation, weights=t.weights, landmarks2d=t.landmarks2d,
          confidence=np.ones(t.n_frames), lost=np.zeros(t.n_frames, bool),
          model_hash=quick_model.content_hash, mode_names=quick_model.mode_names,
          source=str(video)).save(track)
    return video, track


def _errors(capsys, command):
    err = capsys.readouterr().err
    return [ln for ln in err.splitlines() if ln.startswith(f"facetransfer {command}")]


def test_overlay_is_h264_and_can_be_an_image_sequence(clip_and_track, quick_model_path,
                                                      tmp_path, capsys):
    video, track = clip_and_track
    ov = tmp_path / "ov.mp4"
    assert main(["track", str(video), "--model", str(quick_model_path), "--from-track",
                 str(track), "--overlay", str(ov)]) == 0
    res = subprocess.run([iov.ffmpeg_exe(), "-hide_banner", "-i", str(ov)], capture_output=True,
                         text=True)
    assert "Video: h264" in res.stderr and "yuv420p" in res.stderr
    assert decoded_frame_count(ov) == 6
    seq = tmp_path / "ov" / "f%03d.png"
    assert main(["track", str(video), "--model", str(quick_model_path), "--from-track",
                 str(track), "--overlay", str(seq)]) == 0
    assert sorted(p.name for p in seq.parent.iterdir()) == [f"f{i:03d}.png" for i in range(6)]
    mov = tmp_path / "ov.mov"
    assert main(["track", str(video), "--model", str(quick_model_path), "--from-track",
                 str(track), "--overlay", str(mov), "--codec", "prores"]) == 0
    assert read_video(mov)[0].shape == (6, 120, 160, 3)


@pytest.mark.parametrize("argv_tail,match", [
    # issue 16: no MPEG-4 in a .png; transfer writes one image of a one-frame transfer (or
    # --frame N's), so a clip of six frames is refused naming --frame (still53)
    (["--out", "{tmp}/x.png"], ("x.png is one image, but the transfer has 6 frames",
                                "x.png is an image")),
    (["--out", "{tmp}/x.gif"], "neither a video"),
    (["--out", "{tmp}/frames/%s.png"], "%05d"),
    (["--out", "{tmp}/x.mp4", "--crf", "60"], "0 to 51"),
    (["--out", "{tmp}/x.mp4", "--codec", "prores"], ".mov"),
    (["--out", "{tmp}/x.mov", "--codec", "prores", "--crf", "20"], "prores"),
])
def test_transfer_and_puppet_refuse_bad_outputs_before_any_work(
        clip_and_track, quick_model_path, tmp_path, capsys, argv_tail, match):
    video, track = clip_and_track
    tail = [a.format(tmp=tmp_path) for a in argv_tail]
    for k, argv in enumerate((["transfer", "--target", str(video), "--performance", str(track)],
                              ["puppet", str(video), "--identity", "id01", "--track",
                               str(track)])):
        code = main([*argv, "--model", str(quick_model_path), *tail])
        lines = _errors(capsys, argv[0])
        said = match[k] if isinstance(match, tuple) else match
        assert code == 2 and len(lines) == 1 and said in lines[0], lines
    assert sorted(os.listdir(tmp_path)) == []


def test_missing_encoder_is_named(clip_and_track, quick_model_path, tmp_path, capsys,
                                  monkeypatch):
    video, track = clip_and_track
    monkeypatch.setattr(iov, "ffmpeg_encoders", lambda exe: frozenset({"libx264"}))
    code = main(["puppet", str(video), "--model", str(quick_model_path), "--identity", "id01",
                 "--track", str(track), "--out", str(tmp_path / "p.mp4"), "--codec", "h265"])
    lines = _errors(capsys, "puppet")
    assert code == 2 and len(lines) == 1 and "lacks the libx265 encoder" in lines[0]


_FULL_DISK = r"""
import resource, sys
from facetransfer.cli.main import main
resource.setrlimit(resource.RLIMIT_FSIZE, (1500, 1500))   # the disk "fills" at 1.5 kB
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("cache", ["off", "on"])
def test_full_disk_exits_2_and_keeps_the_old_video(clip_and_track, quick_model_path, tmp_path,
                                                   cache):
    """Issue 16, defect 1: no "wrote ..." and exit 0 over a broken file; the old one survives.
    Written in one piece, the line names the output; in parts (the render cache), the part,
    the output and the way around it."""
    video, track = clip_and_track
    d = tmp_path / "out"
    d.mkdir()
    out = d / "p.mp4"
    argv = ["puppet", str(video), "--model", str(quick_model_path), "--identity", "id01",
            "--track", str(track), "--out", str(out)]
    assert main(argv) == 0
    before = out.read_bytes()
    assert len(before) > 1500
    env = {**os.environ, "PYTHONPATH": str(SRC), "FACETRANSFER_RENDER_CACHE": cache,
           "XDG_CACHE_HOME": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-c", _FULL_DISK, *argv, "--overwrite"],
                       capture_output=True, env=env)
    stdout, stderr = r.stdout.decode(), r.stderr.decode()  # bytes: keep tqdm's \r as they are
    lines = [ln.split("\r")[-1] for ln in stderr.split("\n")]  # a bar's last state per line
    lines = [ln for ln in lines if ln.strip()]
    assert r.returncode == 2 and "wrote" not in stdout, stdout + stderr
    assert len(lines) == 1 and lines[0].startswith("facetransfer puppet: error: cannot write "
                                                   "video "), lines
    if cache == "off":
        assert lines[0].startswith(f"facetransfer puppet: error: cannot write video {out}")
    else:
        assert f"a part of {out} in the render cache" in lines[0]
        assert "FACETRANSFER_RENDER_CACHE=off" in lines[0]
    assert out.read_bytes() == before
    assert sorted(os.listdir(d)) == ["p.mp4"]


def test_default_model_when_model_is_absent(clip_and_track, quick_model, tmp_path, capsys,
                                            monkeypatch):
    """No --model: the default model is loaded through load_default_model, with a one-line
    message and a bar when it is built (here a stand-in returns the quick model)."""
    import facetransfer.default_model as dm

    video, track = clip_and_track
    calls = []

    def fake(*, progress=None, announce=None):
        calls.append(1)
        announce("building the default model (ict-arkit) once into CACHE")
        for k in range(3):
            progress(k + 1, 3)
        return quick_model

    monkeypatch.setattr(dm, "load_default_model", fake)
    assert main(["track", str(video), "--from-track", str(track), "--overlay",
                 str(tmp_path / "ov.mp4")]) == 0
    assert main(["puppet", str(video), "--identity", "id01", "--track", str(track),
                 "--out", str(tmp_path / "p.mp4")]) == 0
    assert main(["transfer", "--target", str(video), "--target-track", str(track),
                 "--performance", str(track), "--out", str(tmp_path / "t.mp4"),
                 "--no-progress"]) == 0
    assert len(calls) == 3
    err = capsys.readouterr().err
    assert err.count("building the default model (ict-arkit) once into CACHE") == 3
    for name in ("ov.mp4", "p.mp4", "t.mp4"):
        assert decoded_frame_count(tmp_path / name) == 6


def test_every_model_command_takes_the_default_model_without_model(quick_model, arkit_model,
                                                                   make_arkit_track, tmp_path,
                                                                   monkeypatch, capsys):
    """No plumbing: ``model info|synth|sheet|dials``, ``render``, ``synth-video`` and ``texture
    default|lift`` use the default model when no model is named (before, ``texture lift``,
    ``texture default`` and ``synth-video`` required ``--model``, the others a MODEL). The
    lift takes it only for a track made with it (else it asks for --model)."""
    import dataclasses

    import facetransfer.default_model as dm

    monkeypatch.setattr(dm, "load_default_model", lambda **kw: quick_model)
    monkeypatch.chdir(tmp_path)
    for argv in (["model", "info"], ["model", "synth", "--out", "f.obj"],
                 ["model", "sheet", "--out", "s.png", "--max-identities", "1"],
                 ["model", "dials", "--out", "d.png"], ["render", "--out", "r.png"],
                 ["synth-video", "--random", "--frames", "4", "--size", "128x96", "--out",
                  "c.mp4"],
                 ["texture", "default", "--source", "procedural", "--size", "64", "--out",
                  "t.png"]):
        assert main(argv) == 0, argv
    out = capsys.readouterr().out
    assert f"{quick_model.n_vertices} vertices" in out and "wrote c.mp4 (4 frames" in out
    for name in ("f.obj", "s.png", "d.png", "r.png", "c.mp4", "c.truth.npz", "t.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert main(["texture", "lift", "c.mp4", "--track", "c.truth.npz", "--size", "64",
                 "--out", "lift.png"]) == 0
    assert (tmp_path / "lift.png").stat().st_size > 0
    track, _, _ = make_arkit_track(arkit_model, 4)       # a track of another model
    dataclasses.replace(track, model_hash="0" * 16).save(tmp_path / "other.npz")
    assert main(["texture", "lift", "c.mp4", "--track", "other.npz", "--out", "o.png"]) == 2
    assert "pass the model it was tracked with (--model M.npz)" in capsys.readouterr().err
    assert not (tmp_path / "o.png").exists()
    capsys.readouterr()


@pytest.mark.slow
def test_no_third_party_lines_unless_verbose(data_dir, quick_model_path, tmp_path):
    """``track`` with MediaPipe's initialisation on real footage, in a fresh process: its
    W0000/I0000 and TensorFlow Lite lines appear only with -v."""
    clip = data_dir / "video" / "WDA_KatieHill_000.mp4"
    base = [sys.executable, "-m", "facetransfer.cli.main"]
    argv = ["track", str(clip), "--model", str(quick_model_path), "--out",
            str(tmp_path / "t.npz"), "--max-frames", "2", "--passes", "1", "--init", "auto"]
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    for k in ("GLOG_minloglevel", "TF_CPP_MIN_LOG_LEVEL"):
        env.pop(k, None)
    quiet = subprocess.run(base + argv, capture_output=True, text=True, env=env)
    loud = subprocess.run(base + ["-v"] + argv + ["--overwrite"], capture_output=True,
                          text=True, env=env)
    assert quiet.returncode == 0 and loud.returncode == 0, quiet.stderr + loud.stderr

    def native(text):  # glog lines (W0000 00:00:…) and TensorFlow Lite's INFO/WARNING lines
        pat = re.compile(r"[WIEF]\d{4} \d\d:\d\d:|INFO: Created TensorFlow|WARNING: (Logging "
                         r"before|All log messages)")
        return [ln for ln in text.replace("\r", "\n").splitlines() if pat.search(ln)]

    assert native(loud.stderr)          # MediaPipe did speak (the test can fail)
    assert native(quiet.stderr) == []
    after = subprocess.run(base + argv + ["--overwrite", "-v"], capture_output=True, text=True,
                           env=env)             # -v after the command, as users type it
    assert after.returncode == 0 and native(after.stderr), after.stderr
    assert "wrote" in quiet.stdout

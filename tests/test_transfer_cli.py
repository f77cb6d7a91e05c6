"""CLI tests of ``facetransfer transfer | edit | puppet`` on small synthetic clips with truth tracks."""

from __future__ import annotations

import sys

import numpy as np
import pytest

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))

from _writing import interrupt_renders  # noqa: E402
from facetransfer.cli.main import main  # noqa: E402
from facetransfer.io.video import read_video, write_video  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from test_transfer_rewrite import render_clip  # noqa: E402


@pytest.fixture(scope="module")
def clips(quick_model, tmp_path_factory):
    """target.mp4 (id03, neutral) and source.mp4 (id01, expressions) with their truth tracks."""
    from facetransfer.topology import mesh_topology
    from facetransfer.texture import default_face_texture

    m = quick_model
    topo = mesh_topology(m)
    tex = default_face_texture(m, 256)
    d = tmp_path_factory.mktemp("clips")
    labels = ["neutral", "open", "smile", "open", "frown", "neutral"]
    e_a = [m.training_weights("expression", l) for l in labels]
    e_b = [m.training_weights("expression", "neutral")] * 6
    fa, ta = render_clip(m, topo, tex, "id01", e_a, [0, 4, 8, 4, 0, -4], seed=1)
    fb, tb = render_clip(m, topo, tex, "id03", e_b, [-4, 0, 4, 8, 4, 0], seed=2)
    paths = {"source": d / "source.mp4", "target": d / "target.mp4",
             "source_track": d / "source.npz", "target_track": d / "target.npz"}
    write_video(paths["source"], fa, 25.0)
    write_video(paths["target"], fb, 25.0)
    ta.save(paths["source_track"])
    tb.save(paths["target_track"])
    return paths


def plate_transfer_args(clips, model_path, fps: str | None = "25") -> list[str]:
    """The arguments of a ``transfer`` onto a plate made from ``clips``' target: the clips'
    tracks (no capture), the source's expressions, ``model_path``, no bars, the plate's rate
    (None: none given, the plate's header's)."""
    return [str(a) for a in ("--target-track", clips["target_track"], "--expression-from",
                             clips["source"], "--source-track", clips["source_track"],
                             "--model", model_path, "--no-progress")] + (
        [] if fps is None else ["--sequence-fps", fps])


def plate_and_video_rewrites(plate, video, args, tmp_path, suffix: str, capsys) -> str:
    """``transfer`` with ``args`` (:func:`plate_transfer_args`) onto ``plate``, written as
    ``tmp_path/out/ft.%04d.SUFFIX`` (numbered as the plate), and onto ``video`` (the plate's
    frames as a lossless video), written as ``tmp_path/png_%03d.png``: the truth a plate's
    rewrite is judged by. Returns what the plate's run printed."""
    (tmp_path / "out").mkdir(exist_ok=True)
    code = main(["transfer", "--target", str(plate), *map(str, args),
                 "--out", str(tmp_path / "out" / f"ft.%04d.{suffix}")])
    said = capsys.readouterr()
    assert code == 0, said.err
    code = main(["transfer", "--target", str(video), *map(str, args),
                 "--out", str(tmp_path / "png_%03d.png")])
    assert code == 0, capsys.readouterr().err
    return said.out


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_transfer_with_track_files(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "out.mp4"
    code, stdout, err = run(["transfer", "--target", clips["target"], "--target-track",
                             clips["target_track"], "--expression-from", clips["source"],
                             "--source-track", clips["source_track"], "--model",
                             quick_model_path, "--out", out, "--save-track", tmp_path / "new.npz",
                             "--meshes", tmp_path / "meshes", "--no-progress"], capsys)
    assert code == 0, err
    assert "no audio" in stdout  # synthetic clips have none: skipped quietly
    frames, fps = read_video(out)
    target, _ = read_video(clips["target"])
    assert frames.shape == target.shape and fps == 25.0
    new = Track.load(tmp_path / "new.npz")
    src = Track.load(clips["source_track"])
    np.testing.assert_allclose(new.weights["expression"], src.weights["expression"])
    assert len(list((tmp_path / "meshes").glob("frame_*.obj"))) == 6
    # the open mouth of frame 1 changed the face; the corners (background) did not
    diff = np.abs(frames[1].astype(int) - target[1].astype(int)).max(axis=-1)
    assert diff[40:100, 40:90].max() > 40
    assert diff[:10, :10].max() <= 6  # mp4v re-encoding only


def test_transfer_with_frames_past_the_memory_budget(clips, quick_model_path, tmp_path, capsys,
                                                     monkeypatch):
    """Frames decoded into a file (the budget 0) transfer exactly as frames in memory do, and
    leave nothing in the frame files' folder."""
    outs = {}
    for spill in (False, True):
        if spill:
            (tmp_path / "frames").mkdir()
            monkeypatch.setenv("FACETRANSFER_TMPDIR", str(tmp_path / "frames"))
            monkeypatch.setenv("FACETRANSFER_FRAME_MEMORY", "0")
        outs[spill] = tmp_path / f"out_{spill}.mp4"
        code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                            clips["target_track"], "--expression-from", clips["source"],
                            "--source-track", clips["source_track"], "--model",
                            quick_model_path, "--out", outs[spill], "--no-progress"], capsys)
        assert code == 0, err
    a, _ = read_video(outs[False])
    b, _ = read_video(outs[True])
    np.testing.assert_array_equal(a, b)
    assert list((tmp_path / "frames").iterdir()) == []


@pytest.mark.parametrize("tracks, renders", [("on", "on"), ("on", "off"), ("off", "on"),
                                             ("off", "off")])
def test_an_interrupted_transfer_says_what_it_kept(clips, quick_model_path, tmp_path, capsys,
                                                   monkeypatch, tracks, renders):
    """Ctrl-C: exit 130, one line saying what the track and render caches keep."""
    import facetransfer.video_transfer as vt

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(vt, "transfer_video", interrupted)
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", tracks)
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", renders)
    code, _, err = run(["transfer", "--target", clips["target"], "--expression-from",
                        clips["source"], "--model", quick_model_path, "--out",
                        tmp_path / "o.mp4", "--no-progress"], capsys)
    assert code == 130 and len(err.strip().splitlines()) == 1
    assert err.startswith("facetransfer transfer: interrupted")
    said = {("on", "on"): "; the tracking and the frames rendered so far are kept in the cache",
            ("on", "off"): "; the tracking done so far is kept in the track cache",
            ("off", "on"): "; the frames rendered so far are kept in the render cache",
            ("off", "off"): None}[tracks, renders]
    if said is None:
        assert err.strip() == "facetransfer transfer: interrupted"
    else:
        assert err.startswith("facetransfer transfer: interrupted" + said)


def test_an_interrupt_after_some_outputs_names_them_and_the_overwrite(
        clips, quick_model_path, tmp_path, capsys, monkeypatch):
    """Interrupted after the video and the track were written, before the meshes: the line
    names them and says the next run needs --overwrite (before: "the same command
    continues", which then refused the video as existing)."""
    import facetransfer.video_transfer as vt

    def half_done(sources, out, model, *, save_track=None, **k):
        with open(out, "wb") as f, open(save_track, "wb") as g:
            f.write(b"video")
            g.write(b"track")
        raise KeyboardInterrupt

    monkeypatch.setattr(vt, "transfer_video", half_done)
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    out, st = tmp_path / "o.mp4", tmp_path / "s.npz"
    code, _, err = run(["transfer", "--target", clips["target"], "--expression-from",
                        clips["source"], "--model", quick_model_path, "--out", out,
                        "--save-track", st, "--no-progress"], capsys)
    assert code == 130 and err.strip() == (
        "facetransfer transfer: interrupted; the tracking and the frames rendered so far are "
        "kept in the cache: the same command with --overwrite continues from them; it had "
        f"written {out}, {st}")


def test_transfer_refuses_existing_output(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "exists.mp4"
    out.write_bytes(b"keep me")
    argv = ["transfer", "--target", clips["target"], "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", quick_model_path, "--out", out, "--no-progress"]
    code, _, err = run(argv, capsys)
    assert code == 2 and "exists" in err and "--overwrite" in err
    assert len(err.strip().splitlines()) == 1
    assert out.read_bytes() == b"keep me"
    code, _, err = run(argv + ["--overwrite"], capsys)
    assert code == 0, err
    assert out.stat().st_size > 1000


def test_transfer_mismatched_frame_size(clips, quick_model_path, tmp_path, capsys):
    import dataclasses

    bad = dataclasses.replace(Track.load(clips["target_track"]), frame_size=(64, 64))
    bad.save(tmp_path / "bad.npz")
    out = tmp_path / "o.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        tmp_path / "bad.npz", "--expression-from", clips["source"],
                        "--source-track", clips["source_track"], "--model", quick_model_path,
                        "--out", out, "--no-progress"], capsys)
    assert code == 2 and "64x64" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert not list(tmp_path.glob(".o*"))  # nothing half-written


def test_transfer_target_without_face(quick_model_path, tmp_path, capsys):
    rng = np.random.default_rng(0)
    write_video(tmp_path / "noise.mp4", (rng.random((3, 96, 96, 3)) * 255).astype(np.uint8), 25)
    out = tmp_path / "o.mp4"
    code, _, err = run(["transfer", "--target", tmp_path / "noise.mp4", "--identity-label",
                        "id01", "--model", quick_model_path, "--tracker", "landmarks",
                        "--out", out, "--no-progress"], capsys)
    assert code == 2 and "no face" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_transfer_needs_something_to_transfer(clips, quick_model_path, tmp_path, capsys):
    code, _, err = run(["transfer", "--target", clips["target"], "--model", quick_model_path,
                        "--out", tmp_path / "o.mp4"], capsys)
    assert code == 2 and "nothing to transfer" in err
    code, _, err = run(["transfer", "--target", clips["target"], "--identity-label", "nobody",
                        "--target-track", clips["target_track"], "--model", quick_model_path,
                        "--out", tmp_path / "o.mp4", "--no-progress"], capsys)
    assert code == 2 and "unknown identity 'nobody'" in err


def test_identity_change_with_track(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "id.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--identity-label", "id05", "--model",
                        quick_model_path, "--out", out, "--save-track", tmp_path / "t.npz",
                        "--no-progress"], capsys)
    assert code == 0, err
    from facetransfer.model import load_model

    m = load_model(quick_model_path)
    new = Track.load(tmp_path / "t.npz")
    np.testing.assert_allclose(new.weights["identity"][3], m.training_weights("identity", "id05"))


def test_edit_cli(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "edited.npz"
    code, stdout, err = run(["edit", clips["source_track"], "--model", quick_model_path,
                             "--add", "frown@1-4", "--scale", "smile=1.5", "--ramp", "1",
                             "--out", out], capsys)
    assert code == 0, err
    a, b = Track.load(clips["source_track"]), Track.load(out)
    assert not np.allclose(a.weights["expression"][2], b.weights["expression"][2])
    np.testing.assert_array_equal(a.weights["identity"], b.weights["identity"])
    for bad, msg in ((["--add", "grin@1-2"], "unknown expression 'grin'"),
                     (["--add", "frown@2-60"], "outside the clip"),
                     (["--scale", "smile"], "EXPRESSION=FACTOR"),
                     ([], "nothing to do")):
        o2 = tmp_path / "bad.npz"
        code, _, err = run(["edit", clips["source_track"], "--model", quick_model_path, *bad,
                            "--out", o2], capsys)
        assert code == 2 and msg in err and len(err.strip().splitlines()) == 1, (bad, err)
        assert not o2.exists()
    code, _, err = run(["edit", clips["source_track"], "--model", quick_model_path, "--add",
                        "frown@1-2", "--out", out], capsys)
    assert code == 2 and "exists" in err


def test_puppet_cli(clips, quick_model_path, tmp_path, capsys):
    out = tmp_path / "puppet.mp4"
    code, stdout, err = run(["puppet", clips["source"], "--model", quick_model_path,
                             "--identity", "id04", "--track", clips["source_track"],
                             "--out", out], capsys)
    assert code == 0, err
    frames, _ = read_video(out)
    assert frames.shape[0] == 6
    # a plain background around the rendered face
    assert np.abs(frames[0, :8, :8].astype(int) - np.array([40, 40, 48])).max() <= 6
    assert frames[0, 50:80, 50:80].mean() > 90
    # a track of the video's first frames: the --max-frames that drives the puppet for those
    from facetransfer.track.project import take_frames

    short = tmp_path / "short.npz"
    take_frames(Track.load(clips["source_track"]), np.arange(4)).save(short)
    code, _, err = run(["puppet", clips["source"], "--model", quick_model_path, "--identity",
                        "id04", "--track", short, "--out", tmp_path / "p2.mp4"], capsys)
    assert code == 2 and err.strip().endswith(
        f"track {short} has 4 frames, the video {clips['source']} 6: give --max-frames 4 to "
        "drive the puppet for those"), err
    code, _, err = run(["puppet", clips["source"], "--model", quick_model_path, "--identity",
                        "id04", "--track", short, "--max-frames", "4",
                        "--out", tmp_path / "p2.mp4"], capsys)
    assert code == 0, err


def test_edit_then_render_performance(clips, quick_model_path, tmp_path, capsys):
    """Fig. 7E: add a frown to the target's own track, render it back into the target."""
    edited = tmp_path / "edited.npz"
    code, _, err = run(["edit", clips["target_track"], "--model", quick_model_path, "--add",
                        "open@1-4", "--ramp", "0", "--out", edited], capsys)
    assert code == 0, err
    out = tmp_path / "edited.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--performance", edited, "--model",
                        quick_model_path, "--out", out, "--no-progress"], capsys)
    assert code == 0, err
    frames, _ = read_video(out)
    target, _ = read_video(clips["target"])
    d = np.abs(frames.astype(int) - target.astype(int)).max(axis=-1)
    # the mouth opened on frames 1-4; frames 0 and 5 are only re-rendered (and re-encoded)
    lm = Track.load(clips["target_track"]).landmarks2d[:, 48:68]  # the mouth's landmarks
    x0, y0 = np.floor(lm.min(axis=(0, 1))).astype(int) - 3
    x1, y1 = np.ceil(lm.max(axis=(0, 1))).astype(int) + 6
    mouth = [float(d[i, y0:y1, x0:x1].mean()) for i in range(6)]
    assert min(mouth[2], mouth[3]) > 1.5 * max(mouth[0], mouth[5]), mouth  # ~21 vs ~12
    bad = tmp_path / "bad.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--performance", edited, "--identity-label",
                        "id01", "--model", quick_model_path, "--out", bad,
                        "--no-progress"], capsys)
    assert code == 2 and "excludes" in err and not bad.exists()


def test_identity_and_pose_from_videos_and_align(clips, quick_model_path, tmp_path, capsys):
    """Fig. 1: attributes from several videos; --align trim shortens to a shorter source."""
    import dataclasses

    src = Track.load(clips["source_track"])
    tgt = Track.load(clips["target_track"])
    out, new = tmp_path / "mix.mp4", tmp_path / "mix.npz"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--identity-from", clips["source"],
                        "--identity-track", clips["source_track"], "--pose-from",
                        clips["source"], "--pose-track", clips["source_track"], "--model",
                        quick_model_path, "--out", out, "--save-track", new, "--no-progress"],
                       capsys)
    assert code == 0, err
    mix = Track.load(new)
    np.testing.assert_allclose(mix.weights["identity"], src.weights["identity"])
    np.testing.assert_allclose(mix.weights["expression"], tgt.weights["expression"])
    np.testing.assert_allclose(mix.rotation, src.rotation, atol=1e-12)
    # a 3-frame source with --align trim: the output has 3 frames
    short = dataclasses.replace(src, rotation=src.rotation[:3], scale=src.scale[:3],
                                translation=src.translation[:3],
                                weights={k: v[:3] for k, v in src.weights.items()},
                                landmarks2d=src.landmarks2d[:3], confidence=src.confidence[:3],
                                lost=src.lost[:3])
    short.save(tmp_path / "short.npz")
    out2 = tmp_path / "trim.mp4"
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--expression-from", clips["source"],
                        "--source-track", tmp_path / "short.npz", "--align", "trim",
                        "--model", quick_model_path, "--out", out2, "--no-progress"], capsys)
    assert code == 0, err
    assert read_video(out2)[0].shape[0] == 3


def test_landmarks_file_is_checked_only_for_the_tracker_that_reads_it(tmp_path):
    """A damaged ``NAME.mediapipe478.npz`` stops ``--tracker landmarks`` before any work, and
    is not read at all by the trackers that never use it (capture, flow)."""
    from facetransfer.cli.common import check_landmarks_file
    from facetransfer.errors import FaceTransferError

    video = tmp_path / "clip.mp4"
    (tmp_path / "clip.mediapipe478.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(FaceTransferError, match="clip.mediapipe478.npz"):
        check_landmarks_file(video, "landmarks")
    for tracker in ("auto", "capture", "flow"):
        assert check_landmarks_file(video, tracker) is None


def test_an_interrupted_transfer_renders_only_the_frames_it_had_not(clips, quick_model_path,
                                                                   tmp_path, capsys,
                                                                   monkeypatch):
    """Ctrl-C in the render, then the same command: only the frames no kept part holds are
    rendered, and the video equals one rendered at once (lossless: the parts do not show)."""
    from facetransfer.io import video_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(video_parts, "PART_FRAMES", 2)
    stop = [3]  # frame 3 interrupted, whichever thread renders what when
    calls = interrupt_renders(monkeypatch, stop)
    argv = ["transfer", "--target", clips["target"], "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", quick_model_path, "--crf", "0", "--no-progress", "--out"]
    code, _, err = run(argv + [tmp_path / "o.mp4"], capsys)
    assert code == 130 and "the frames rendered so far are kept" in err
    [folder] = (tmp_path / "cache" / "facetransfer" / "renders").iterdir()
    # a full part of frames 0-1 and frame 2, finished by ffmpeg when interrupted
    assert [(p.start, p.frames) for p in video_parts.kept_parts(folder)] == [(0, 2), (2, 1)]
    assert not (tmp_path / "o.mp4").exists()
    stop[0], calls[:] = None, []
    code, out, err = run(argv + [tmp_path / "o.mp4"], capsys)
    assert code == 0, err
    assert "continued an interrupted render from frame 3" in out
    assert sorted(calls) == [3, 4, 5] and not folder.exists()
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    code, _, err = run(argv + [tmp_path / "once.mp4"], capsys)
    assert code == 0, err
    a, b = read_video(tmp_path / "o.mp4")[0], read_video(tmp_path / "once.mp4")[0]
    assert a.shape == b.shape == (6, *a.shape[1:]) and np.array_equal(a, b)


def test_an_interrupted_image_sequence_continues(clips, quick_model_path, tmp_path, capsys,
                                                monkeypatch):
    """``--out frames/%03d.png``: Ctrl-C in the render keeps the frames written (none of them
    beside the pattern yet, an older sequence untouched); the same command renders only the
    rest, and the frames equal those of a sequence written at once."""
    from facetransfer.io import sequence_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    stop = [4]
    calls = interrupt_renders(monkeypatch, stop)
    out = tmp_path / "seq"
    out.mkdir()
    for i in range(9):  # an older, longer sequence of the same pattern
        (out / f"f{i:03d}.png").write_bytes(b"old")
    argv = ["transfer", "--target", clips["target"], "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", quick_model_path, "--no-progress", "--overwrite", "--out"]
    code, _, err = run(argv + [out / "f%03d.png"], capsys)
    assert code == 130 and "the frames rendered so far are kept" in err
    [folder] = (tmp_path / "cache" / "facetransfer" / "renders").iterdir()
    assert sequence_parts.kept_frames(folder, "f%03d.png", 6) == [True] * 4
    assert all((out / f"f{i:03d}.png").read_bytes() == b"old" for i in range(9))
    stop[0], calls[:] = None, []
    code, text, err = run(argv + [out / "f%03d.png"], capsys)
    assert code == 0, err
    assert "continued an interrupted render from frame 4" in text
    assert sorted(calls) == [4, 5] and not folder.exists()
    assert sorted(q.name for q in out.iterdir()) == [f"f{i:03d}.png" for i in range(6)]
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    code, _, err = run(argv + [tmp_path / "once%03d.png"], capsys)
    assert code == 0, err
    from PIL import Image

    for i in range(6):
        a = np.asarray(Image.open(out / f"f{i:03d}.png"))
        b = np.asarray(Image.open(tmp_path / f"once{i:03d}.png"))
        assert a.shape == b.shape and a.ndim == 3 and np.array_equal(a, b)


def test_sigterm_keeps_what_an_interrupt_keeps(clips, quick_model_path, tmp_path, capsys,
                                              monkeypatch):
    """``kill`` (SIGTERM) ends the command as Ctrl-C does, exit 143, one line; a child forked
    meanwhile dies of SIGTERM as before; the handler is restored afterwards."""
    import os
    import signal
    import time

    import facetransfer.video_transfer as vt

    before = signal.getsignal(signal.SIGTERM)
    child_handler = []

    def killed(*a, **k):
        pid = os.fork()
        if pid == 0:  # the child reports whether SIGTERM would kill it
            os._exit(0 if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL else 1)
        child_handler.append(os.waitpid(pid, 0)[1])
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises here
        raise AssertionError("SIGTERM was not turned into an interrupt")

    monkeypatch.setattr(vt, "transfer_video", killed)
    monkeypatch.setenv("FACETRANSFER_TRACK_CACHE", "on")
    code, _, err = run(["transfer", "--target", clips["target"], "--expression-from",
                        clips["source"], "--model", quick_model_path, "--out",
                        tmp_path / "o.mp4", "--no-progress"], capsys)
    assert code == 143 and len(err.strip().splitlines()) == 1
    assert err.startswith("facetransfer transfer: terminated; the tracking and the frames "
                          "rendered so far are kept in the cache")
    assert child_handler == [0]
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize("cache", ["on", "off"])
def test_the_targets_pixel_aspect_ratio_is_kept(clips, quick_model_path, tmp_path, capsys,
                                                 monkeypatch, cache):
    """A target whose pixels are not square (8:9: its 128 columns shown as 114) gives a result,
    a puppet video and a track overlay shown at its shape: in parts (the render cache) or in
    one piece; ``--crf 0`` and the same frames as a square-pixel target's result. The colour
    matrix is named where the target names one, and left to the player where it does not."""
    from facetransfer.io.video import VideoOptions, colour_matrix, video_info

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", cache)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    target = tmp_path / "narrow.mkv"
    write_video(target, read_video(clips["target"])[0], 25.0,
                options=VideoOptions(crf=0, sar=(8, 9)))
    square = tmp_path / "square.mkv"
    write_video(square, read_video(clips["target"])[0], 25.0,
                options=VideoOptions(crf=0, colour_tags=False))
    common = ["--target-track", clips["target_track"], "--expression-from", clips["source"],
              "--source-track", clips["source_track"], "--model", quick_model_path,
              "--crf", "0", "--no-progress"]
    for tgt, out in ((target, "out.mp4"), (square, "sq.mp4")):
        code, _, err = run(["transfer", "--target", tgt, *common, "--out", tmp_path / out],
                           capsys)
        assert code == 0, err
    assert video_info(tmp_path / "out.mp4").sar == (8, 9)
    assert video_info(tmp_path / "sq.mp4").sar == (1, 1)
    assert colour_matrix(tmp_path / "out.mp4") == "smpte170m"
    assert colour_matrix(tmp_path / "sq.mp4") is None
    np.testing.assert_array_equal(read_video(tmp_path / "out.mp4")[0],
                                  read_video(tmp_path / "sq.mp4")[0])
    code, _, err = run(["puppet", target, "--model", quick_model_path, "--identity", "id04",
                        "--track", clips["target_track"], "--out", tmp_path / "p.mp4",
                        "--no-progress"], capsys)
    assert code == 0, err
    assert video_info(tmp_path / "p.mp4").sar == (8, 9)
    code, _, err = run(["track", target, "--model", quick_model_path, "--out",
                        tmp_path / "t.npz", "--overlay", tmp_path / "ov.mp4", "--no-progress"],
                       capsys)
    assert code == 0, err
    assert video_info(tmp_path / "ov.mp4").sar == (8, 9)
    # tracked at the shown shape (114 of 128 columns), told in the stored pixels
    tr = Track.load(tmp_path / "t.npz")
    assert tr.pixel_aspect == 114 / 128 and tr.frame_size == (128, 128)


def test_an_interrupted_puppet_renders_only_the_frames_it_had_not(clips, quick_model_path,
                                                                 tmp_path, capsys, monkeypatch):
    """``puppet`` keeps its render in parts as ``transfer`` does: Ctrl-C at frame 3, then the
    same command renders frames 3-5 only, and the video equals one written at once."""
    import facetransfer.render as render_module
    from facetransfer.io import video_parts

    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "on")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(video_parts, "PART_FRAMES", 2)
    real, drawn, stop = render_module.render, [], [3]

    def counted(*a, **k):  # one call a frame, in order
        if stop[0] is not None and len(drawn) >= stop[0]:
            raise KeyboardInterrupt
        drawn.append(1)
        return real(*a, **k)

    monkeypatch.setattr(render_module, "render", counted)
    argv = ["puppet", clips["source"], "--model", quick_model_path, "--identity", "id04",
            "--track", clips["source_track"], "--crf", "0", "--no-progress", "--out"]
    code, _, err = run(argv + [tmp_path / "p.mp4"], capsys)
    assert code == 130 and "the frames rendered so far are kept" in err
    assert not (tmp_path / "p.mp4").exists()
    stop[0], drawn[:] = None, []
    code, out, err = run(argv + [tmp_path / "p.mp4"], capsys)
    assert code == 0, err
    assert "continued an interrupted render from frame 3" in out and len(drawn) == 3
    monkeypatch.setenv("FACETRANSFER_RENDER_CACHE", "off")
    code, _, err = run(argv + [tmp_path / "once.mp4"], capsys)
    assert code == 0, err
    a, b = read_video(tmp_path / "p.mp4")[0], read_video(tmp_path / "once.mp4")[0]
    assert a.shape == b.shape == (6, *a.shape[1:]) and np.array_equal(a, b)


def _held_as_captured(track, lost):
    """``track`` with the frames ``lost`` marked lost and holding the values the capture
    tracker keeps there (its own rule, ``capture._fill_lost``: the nearest tracked frame's,
    the earlier on ties), the values the CSV, glb and USD exports write."""
    import dataclasses

    from facetransfer.track.capture import _fill_lost

    lost = np.asarray(lost, bool)
    src, _ = _fill_lost([None if lost[i] else i for i in range(track.n_frames)])
    src = np.asarray(src)
    return dataclasses.replace(
        track, rotation=track.rotation[src], scale=track.scale[src],
        translation=track.translation[src],
        weights={m: w[src] for m, w in track.weights.items()},
        landmarks2d=track.landmarks2d[src], confidence=np.where(lost, 0.0, track.confidence),
        lost=lost, blendshapes=None if track.blendshapes is None else track.blendshapes[src],
        detections2d=None if track.detections2d is None else track.detections2d[src]), src


def test_puppet_shows_lost_frames_as_the_exports_hold_them(clips, quick_model):
    """Lost frames at the start, in the middle and at the end of a track are rendered from the
    values the track holds there, as the exports write them: each equals the frame rendered
    for the same values unmarked (before: the background before the face first appeared, the
    last tracked frame after a loss)."""
    import dataclasses

    from facetransfer.puppet_video import puppet_frames
    from facetransfer.transfer import identity_from_label

    track = Track.load(clips["source_track"])
    lost = np.zeros(track.n_frames, bool)
    lost[[0, 3, track.n_frames - 1]] = True
    held, src = _held_as_captured(track, lost)
    assert list(src) == [1, 1, 2, 2, 4, 4]      # start, a tie (the earlier), end
    wid = identity_from_label(quick_model, "id04")
    size = (40, 30)
    shown = list(puppet_frames(held, quick_model, wid, size=size))
    filled = list(puppet_frames(dataclasses.replace(held, lost=np.zeros_like(lost)),
                                quick_model, wid, size=size))
    plain = list(puppet_frames(track, quick_model, wid, size=size))
    assert len(shown) == len(filled) == track.n_frames
    for i in range(track.n_frames):
        assert np.array_equal(shown[i], filled[i]), i
        assert np.array_equal(shown[i], plain[src[i]]), i
    assert not np.array_equal(shown[0], shown[0][0, 0])     # a face, not the background


def test_puppet_start_gives_the_frames_of_a_whole_run(clips, quick_model):
    """``puppet_frames(start=k)`` gives the frames a whole run gives from k on, also where
    frame k is lost (rendered from the values the track holds there)."""
    from facetransfer.puppet_video import puppet_frames
    from facetransfer.transfer import identity_from_label

    track = Track.load(clips["source_track"])
    lost = np.zeros(track.n_frames, bool)
    lost[[3, 4]] = True
    track, _ = _held_as_captured(track, lost)
    wid = identity_from_label(quick_model, "id04")
    whole = list(puppet_frames(track, quick_model, wid))
    assert np.array_equal(whole[3], whole[2]) and np.array_equal(whole[4], whole[5])
    assert not np.array_equal(whole[5], whole[2])
    for k in (0, 3, 4, 5):
        part = list(puppet_frames(track, quick_model, wid, start=k))
        assert len(part) == 6 - k
        assert all(np.array_equal(a, b) for a, b in zip(part, whole[k:]))


def test_an_interlaced_target_gives_an_interlaced_result(clips, quick_model_path, tmp_path,
                                                         capsys):
    """A target coded interlaced (top field first), which OpenCV reads as black frames, is
    rewritten as the same frames coded progressive are, and the result is interlaced too."""
    from facetransfer.io.video import VideoOptions
    from facetransfer.io.video_display import first_field

    frames = read_video(clips["target"])[0]
    common = ["--target-track", clips["target_track"], "--expression-from", clips["source"],
              "--source-track", clips["source_track"], "--model", quick_model_path,
              "--crf", "0", "--no-progress"]
    results = []
    for name, field in (("interlaced", "top"), ("progressive", None)):
        target = tmp_path / f"{name}.mp4"
        write_video(target, frames, 25.0, options=VideoOptions(crf=0, field=field))
        out = tmp_path / f"{name}_out.mp4"
        code, _, err = run(["transfer", "--target", target, *common, "--out", out], capsys)
        assert code == 0, err
        assert first_field(out) == field
        results.append(read_video(out)[0].astype(int))
    assert results[0].shape == results[1].shape and results[0].mean() > 50
    assert np.abs(results[0] - results[1]).mean() < 1.0


def test_the_inputs_are_probed_at_once_and_kept(clips, tmp_path, monkeypatch):
    """_probe_at_once asks every input's video_info on threads: afterwards each is kept (no
    process runs when asked again), and a missing input is left for the checks' own error."""
    import subprocess

    from facetransfer.cli.transfer import _probe_at_once
    from facetransfer.io.video import video_info

    a, b = tmp_path / "a.mp4", tmp_path / "b.mp4"
    a.write_bytes(clips["target"].read_bytes())
    b.write_bytes(clips["source"].read_bytes())
    _probe_at_once([str(a), str(b), str(tmp_path / "missing.mp4")])

    def no_process(*args, **kwargs):
        raise AssertionError("a probe ran again")

    monkeypatch.setattr(subprocess, "run", no_process)
    monkeypatch.setattr(subprocess, "Popen", no_process)
    assert video_info(a).n_frames == video_info(b).n_frames > 0


def test_a_source_track_of_other_frames_is_one_line(clips, quick_model_path, tmp_path, capsys,
                                                    caplog):
    """A --source-track of another clip with frames of another size: its error alone (before:
    the error, then a warning that the track was made from another video)."""
    import dataclasses

    tr = Track.load(clips["source_track"])
    other = tmp_path / "other.npz"
    dataclasses.replace(tr, frame_size=(tr.frame_size[0] + 2, tr.frame_size[1]),
                        source=str(tmp_path / "elsewhere.mp4")).save(other)
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--expression-from", clips["source"],
                        "--source-track", other, "--model", quick_model_path,
                        "--out", tmp_path / "o.mp4", "--no-progress"], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "expression track" in lines[0] \
        and "frames but" in lines[0], lines
    assert not [r.getMessage() for r in caplog.records if "expression track" in r.getMessage()]


def test_one_path_for_two_outputs_is_refused_before_any_work(clips, quick_model_path, tmp_path,
                                                              capsys):
    """--meshes named as --out (or as --save-track) was found only after the render, as "File
    exists", the video written and no meshes: refused first."""
    base = ["transfer", "--target", clips["target"], "--target-track", clips["target_track"],
            "--expression-from", clips["source"], "--source-track", clips["source_track"],
            "--model", quick_model_path, "--no-progress"]
    for extra, said in ((["--out", tmp_path / "o.mp4", "--meshes", tmp_path / "o.mp4"],
                         f"--meshes {tmp_path / 'o.mp4'} is also --out"),
                        (["--out", tmp_path / "o.mp4", "--save-track", tmp_path / "t.npz",
                          "--meshes", tmp_path / "t.npz"],
                         f"--meshes {tmp_path / 't.npz'} is also --save-track")):
        code, _, err = run(base + extra, capsys)
        assert code == 2 and err.strip().endswith(said + ": give each output its own name"), err
    assert not any(tmp_path.iterdir())


def test_a_face_to_track_beside_its_track_is_refused(clips, quick_model_path, tmp_path, capsys):
    """--source-face with --source-track was taken and ignored (nothing is tracked): refused,
    as --target-face with --target-track is."""
    code, _, err = run(["transfer", "--target", clips["target"], "--target-track",
                        clips["target_track"], "--expression-from", clips["source"],
                        "--source-track", clips["source_track"], "--source-face", "left",
                        "--model", quick_model_path, "--out", tmp_path / "o.mp4"], capsys)
    assert code == 2 and err.strip().endswith(
        f"--source-face chooses the face to track, but --source-track {clips['source_track']} "
        "is tracked already (its face is the one used): give one of them"), err


def test_puppet_of_a_track_file_alone_is_the_puppet_of_its_video(clips, quick_model_path,
                                                                   tmp_path, capsys):
    """``puppet TRACK.npz``: the frames ``puppet VIDEO --track TRACK.npz`` renders, with no video
    needed (a track whose clip is gone renders the same); the clip's timecode recorded in the
    track is the output's; ``--max-frames`` takes the first frames; a flag for a video is
    refused."""
    import dataclasses

    from facetransfer.io.source_facts import SourceFacts
    from facetransfer.io.video_display import timecode_of

    with_video = tmp_path / "with_video.mp4"
    code, _, err = run(["puppet", clips["source"], "--model", quick_model_path, "--identity",
                        "id04", "--track", clips["source_track"], "--out", with_video], capsys)
    assert code == 0, err
    track = Track.load(clips["source_track"])
    gone = dataclasses.replace(track, source=str(tmp_path / "moved_away.mp4"),
                               source_facts=SourceFacts(0, "01:02:03:04"))
    alone_track = tmp_path / "alone.npz"
    gone.save(alone_track)
    alone = tmp_path / "alone.mp4"
    code, out, err = run(["puppet", alone_track, "--model", quick_model_path, "--identity",
                          "id04", "--out", alone], capsys)
    assert code == 0, err
    assert "6 frames" in out and "audio" not in out
    a, fps_a = read_video(with_video)
    b, fps_b = read_video(alone)
    assert fps_a == fps_b == 25.0
    np.testing.assert_array_equal(a, b)
    assert timecode_of(alone) == "01:02:03:04"
    short = tmp_path / "short.mp4"
    code, out, err = run(["puppet", alone_track, "--model", quick_model_path, "--identity",
                          "id04", "--max-frames", "4", "--out", short], capsys)
    assert code == 0, err
    from facetransfer.track.project import take_frames

    first4 = tmp_path / "first4.npz"
    take_frames(track, np.arange(4)).save(first4)
    code, _, err = run(["puppet", clips["source"], "--model", quick_model_path, "--identity",
                        "id04", "--track", first4, "--max-frames", "4",
                        "--out", tmp_path / "short_video.mp4"], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(read_video(short)[0],
                                  read_video(tmp_path / "short_video.mp4")[0])
    code, _, err = run(["puppet", alone_track, "--model", quick_model_path, "--track",
                        alone_track, "--out", tmp_path / "x.mp4"], capsys)
    assert code == 2 and err.strip().endswith(
        f"{alone_track} is a track file: --track is for a video"), err
    assert not (tmp_path / "x.mp4").exists()


def test_puppet_of_a_track_file_takes_its_clip_as_puppet_video_does(clips, quick_model_path,
                                                                      tmp_path, capsys, caplog):
    """``puppet TRACK.npz`` where its clip is still there is ``puppet VIDEO --track``: the
    clip's pixels' aspect (a track of the optical-flow tracker, ``--tracker klt``, records none:
    square in the track, 8:9 in the clip), its audio; where another clip of the track's size
    has taken its place (3 frames, the track 6), neither its audio nor its aspect (before: the
    puppet said and carried 'the audio of' a clip it never moved with)."""
    import dataclasses
    import logging
    import subprocess

    from facetransfer.io.video import ffmpeg_exe, has_audio, video_info
    from facetransfer.io.video_options import VideoOptions

    tone = tmp_path / "tone.m4a"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-f", "lavfi", "-i",
                    "sine=frequency=440:duration=1", "-c:a", "aac", str(tone)], check=True)
    frames = read_video(clips["source"])[0]
    clip = tmp_path / "narrow.mkv"
    write_video(clip, frames, 25.0, options=VideoOptions(crf=0, sar=(8, 9)), audio_from=tone)
    track = Track.load(clips["source_track"])
    assert track.pixel_aspect == 1.0            # as the optical-flow tracker's
    flow = tmp_path / "flow.npz"
    dataclasses.replace(track, source=str(clip), source_facts=None).save(flow)
    common = ["--model", quick_model_path, "--identity", "id04", "--no-progress"]
    code, _, err = run(["puppet", clip, "--track", flow, *common, "--out",
                        tmp_path / "video.mp4"], capsys)
    assert code == 0, err
    code, out, err = run(["puppet", flow, *common, "--out", tmp_path / "alone.mp4"], capsys)
    assert code == 0, err
    assert out.rstrip().endswith("with the audio of narrow.mkv"), out
    for name in ("video.mp4", "alone.mp4"):
        assert video_info(tmp_path / name).sar == (8, 9), name
        assert has_audio(tmp_path / name), name
    np.testing.assert_array_equal(read_video(tmp_path / "video.mp4")[0],
                                  read_video(tmp_path / "alone.mp4")[0])
    before = clip.read_bytes()          # its clip is an input: not replaced, even so asked
    code, _, err = run(["puppet", flow, *common, "--out", clip, "--overwrite"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and str(clip) in err, err
    assert clip.read_bytes() == before
    write_video(clip, frames[:3], 25.0, options=VideoOptions(crf=0, sar=(8, 9)),
                audio_from=tone)                 # another clip where the track's was
    with caplog.at_level(logging.WARNING):
        code, out, err = run(["puppet", flow, *common, "--out", tmp_path / "other.mp4"],
                             capsys)
    assert code == 0, err
    assert "audio" not in out and "6 frames" in out, out
    assert "which is now 3 frames of" in caplog.text, caplog.text
    assert not has_audio(tmp_path / "other.mp4")
    assert video_info(tmp_path / "other.mp4").sar == (1, 1)


def test_puppet_of_a_plates_track_numbers_its_frames_as_the_plate(clips, quick_model_path,
                                                                   tmp_path, capsys, caplog):
    """``puppet TRACK.npz`` of a PNG plate numbered from 1001 that is still there, a track
    made before tracks recorded their clip's numbering, at 30 fps (a plate's rate is a
    setting, ``--sequence-fps``, not the files'; the plate read at 24): written from 1001 as
    the plate is (before: from 0), nothing said of another clip (a check of the rate took the
    plate for another clip)."""
    import dataclasses
    import logging

    from facetransfer.io.video_options import VideoOptions

    (tmp_path / "plate").mkdir()
    pattern = tmp_path / "plate" / "p.%04d.png"
    write_video(pattern, read_video(clips["source"])[0], 25.0,
                options=VideoOptions(first_number=1001))
    track = dataclasses.replace(Track.load(clips["source_track"]), source=str(pattern),
                                source_facts=None, fps=30.0)
    track.save(tmp_path / "plate.npz")
    (tmp_path / "out").mkdir()
    with caplog.at_level(logging.WARNING):
        code, out, err = run(["puppet", tmp_path / "plate.npz", "--model", quick_model_path,
                              "--no-progress", "--out", tmp_path / "out" / "f.%04d.png"],
                             capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == \
        [f"f.{n}.png" for n in range(1001, 1007)]
    assert "another clip" not in caplog.text, caplog.text


def test_puppet_and_export_show_a_klt_tracks_lost_frames_as_their_nearest_tracked(
        clips, quick_model, tmp_path):
    """A track whose lost frames hold another state than a tracked frame's (the paper's KLT
    tracker keeps the flow's drifting state there, a landmarks track the previous fit): the
    puppet and the CSV show each lost frame as its nearest tracked frame, the earlier on ties,
    as for a capture track (before: a head drifted off and shrunk in the puppet, the CSV's
    drifted activations)."""
    import csv
    import dataclasses

    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export import export_track
    from facetransfer.track.project import nearest_tracked
    from facetransfer.puppet_video import puppet_frames
    from facetransfer.transfer import identity_from_label

    track = Track.load(clips["source_track"])
    lost = np.zeros(track.n_frames, bool)
    lost[[0, 3, track.n_frames - 1]] = True
    src = nearest_tracked(lost)
    assert list(src) == [1, 1, 2, 2, 4, 4]
    drift = {m: np.where(lost[:, None], w + 0.5 * np.std(w, axis=0) + 0.1, w)
             for m, w in track.weights.items()}
    klt = dataclasses.replace(      # a drifted, shrunken head where the face was lost
        track, lost=lost, scale=np.where(lost, track.scale * 0.3, track.scale),
        translation=np.where(lost[:, None], track.translation + 7.0, track.translation),
        weights={m: (w if m == quick_model.identity_mode else drift[m])
                 for m, w in track.weights.items()}, blendshapes=None)
    bs = np.random.default_rng(0).uniform(0.0, 0.5, (track.n_frames, 52)).astype(np.float32)
    wid = identity_from_label(quick_model, "id04")
    size = (40, 30)
    shown = list(puppet_frames(klt, quick_model, wid, size=size))
    plain = list(puppet_frames(track, quick_model, wid, size=size))
    for i in range(track.n_frames):
        assert np.array_equal(shown[i], plain[src[i]]), i
    held = dataclasses.replace(klt, lost=np.zeros_like(lost))   # the same frames, unmarked
    held = dataclasses.replace(
        held, rotation=track.rotation[src], scale=track.scale[src],
        translation=track.translation[src], weights={m: w[src] for m, w in track.weights.items()},
        blendshapes=bs[src], blendshape_names=ARKIT_NAMES)
    klt = dataclasses.replace(klt, blendshapes=np.where(lost[:, None], 1 - bs, bs),
                              blendshape_names=ARKIT_NAMES)     # drifted
    rows = []
    for t, name in ((klt, "klt.csv"), (held, "held.csv")):
        path = export_track(t, "livelink", tmp_path / name, timecode=None)
        with open(path, newline="") as f:
            rows.append([r[2:] for r in csv.reader(f)])
    assert rows[0] == rows[1]

"""A Live Link Face take as a transfer's expression source (facetransfer.take)."""

from __future__ import annotations

import importlib.util

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.take import (is_take, take_on_timeline, take_performance, take_rate,  # noqa: E402
                               take_seconds)
from facetransfer.transfer import TransferError  # noqa: E402


def test_timecodes_count_in_the_takes_own_rate():
    tc = [f"10:00:0{s}:{f:02d}.000" for s in (0, 1) for f in range(60)]   # 60 fps
    assert take_rate(tc) == 60
    np.testing.assert_allclose(take_seconds(tc), np.arange(120) / 60, atol=1e-9)
    # 30 nominal frames a second, rows half a frame apart (the app's 59.94 fps takes)
    tc = ["00:00:00:00.000", "00:00:00:00.500", "00:00:00:01.000", "00:00:00:29.500",
          "00:00:01:00.000"]
    assert take_rate(tc) == 30
    np.testing.assert_allclose(take_seconds(tc), [0, 0.5 / 30, 1 / 30, 29.5 / 30, 1.0])
    assert take_rate(["00:00:00:23.000"]) == 24 and take_rate(["00:00:00:24.000"]) == 25
    assert take_rate(["00:00:00:26.000", "00:00:00:28.000", "00:00:01:00.000"]) == 30
    with pytest.raises(TransferError, match="back in time at row 3"):
        take_seconds(["00:00:01:00.000", "00:00:01:01.000", "00:00:00:05.000"])
    with pytest.raises(TransferError, match="HH:MM:SS:FF"):
        take_seconds(["00:00:01"])
    assert is_take("a/b.CSV") and not is_take("a/b.mp4") and not is_take(None)


def test_a_take_is_resampled_onto_the_targets_frames():
    t = np.linspace(0.0, 1.0, 11)                    # rows every 0.1 s, value 10 t
    v = np.stack([10 * t, 1 - t], axis=1)
    got = take_on_timeline(t, v, 20, 25.0)           # the take is longer: trimmed to 20
    np.testing.assert_allclose(got[:, 0], 10 * np.arange(20) / 25.0)
    held = take_on_timeline(t, v, 40, 25.0)          # shorter: its last row held
    assert held.shape == (40, 2) and np.all(held[25:, 0] == 10.0)
    # trimmed at the end of the last row's 0.1 s (1.1 s), as time_map trims an 11-frame video
    # of 10 fps: 28 frames (was 26, to half a target frame past the last row)
    assert take_on_timeline(t, v, 40, 25.0, align="trim").shape == (28, 2)
    looped = take_on_timeline(t, v, 40, 25.0, align="loop")
    # 11 rows 0.1 s apart last 1.1 s: 1.2 s is 0.1 s into the second time through (was 1.04)
    np.testing.assert_allclose(looped[30, 0], 10 * (30 / 25.0 - 1.1))
    with pytest.raises(TransferError, match="align"):
        take_on_timeline(t, v, 5, 25.0, align="stretch")


@pytest.mark.parametrize("take_fps, target_fps", [(30.0, 60.0), (25.0, 30.0), (24.0, 60.0),
                                                  (30.0, 25.0), (25.0, 25.0)])
def test_a_trimmed_take_keeps_the_frames_a_trimmed_video_keeps(take_fps, target_fps):
    """``--align trim`` with a take keeps the target's frames within its last row's own span,
    as :func:`facetransfer.transfer.time_map` keeps a video's last frame for its length.
    Before, half a target frame: a 30 fps take of 90 rows on a 60 fps target gave 179 frames
    where the same clip as a video gives 180. Rows written with the app's thousandths of a
    frame (a 23.976 fps clip's, up to 1/60000 s off) do not add a frame."""
    from facetransfer.transfer import time_map

    rows = 90
    t = np.arange(rows) / take_fps
    v = np.arange(rows, dtype=np.float64)[:, None]
    n = 4 * rows
    got = take_on_timeline(t, v, n, target_fps, align="trim")[:, 0]
    video = time_map(rows, take_fps, n, target_fps, align="trim").source_time
    assert got.shape == video.shape
    np.testing.assert_allclose(got, video, atol=1e-9)
    ntsc = 24000 / 1001                                  # rows rounded to 1/30000 s
    rounded = np.round(np.arange(rows) / ntsc * 30000) / 30000
    assert take_on_timeline(rounded, v, n, ntsc, align="trim").shape[0] == rows


@pytest.mark.parametrize("take_fps, target_fps, rows", [
    (25.0, 30000 / 1001, 166), (30.0, 24000 / 1001, 249), (24.0, 60000 / 1001, 400),
    (50.0, 60000 / 1001, 1167), (24000 / 1001, 24.0, 1001)])
def test_a_trimmed_take_keeps_a_frame_a_thousandth_of_a_frame_inside_its_end(take_fps,
                                                                           target_fps, rows):
    """An NTSC rate beside a whole one puts a target frame 1/1001 of a frame short of a take's
    end (a 25 fps take of 166 rows ends at 6.64 s, 29.97 fps frame 199 at 6.63997 s): the
    trimmed video keeps that frame, and so does the take (review48a). Before, the slack for
    the app's rounded rows was 1/1000 of a frame, more than that: 199 frames for 200. The
    slack still takes a 23.976 fps take's rows, rounded to 1/30000 s, as ending where its
    video does (2399 rows from a time-of-day start: 2399 frames)."""
    from facetransfer.export.livelink import format_timecode
    from facetransfer.transfer import time_map

    t = np.arange(rows) / take_fps
    v = np.arange(rows, dtype=np.float64)[:, None]
    n = int(rows * target_fps / take_fps) + 4
    video = time_map(rows, take_fps, n, target_fps, align="trim").source_time
    got = take_on_timeline(t, v, n, target_fps, align="trim")[:, 0]
    assert got.shape == video.shape
    np.testing.assert_allclose(got, video, atol=1e-9)
    ntsc = 24000 / 1001
    codes = [format_timecode(k, ntsc, "01:02:03:04", labels="app") for k in range(2399)]
    rounded = take_seconds(codes, warn=False)
    assert codes[1].endswith(".251")                      # the app's thousandths: rounded
    assert take_on_timeline(rounded, rounded[:, None], 2500, ntsc, align="trim").shape == \
        (2399, 1)


@pytest.mark.parametrize("take_fps, target_fps", [(30.0, 25.0), (25.0, 30.0), (60.0, 24.0),
                                                  (30.0, 30.0)])
def test_a_looped_take_repeats_as_a_looped_video_of_its_rate(take_fps, target_fps):
    """``--align loop`` with a take repeats it where the same frames as a video repeat
    (:func:`facetransfer.transfer.time_map`): after its last row's own span. Before, the span
    was the target's frame: a 30 fps take of 90 rows on a 25 fps target came 1/150 s later
    each time through, and frame 75 (3.0 s, the second time's first row) showed row 89."""
    from facetransfer.transfer import time_map

    rows = 90
    t = np.arange(rows) / take_fps
    v = np.arange(rows, dtype=np.float64)[:, None]        # a row's value is its number
    n = int(5 * rows * target_fps / take_fps)              # five times through
    got = take_on_timeline(t, v, n, target_fps, align="loop")[:, 0]
    video = time_map(rows, take_fps, n, target_fps, align="loop").source_time
    np.testing.assert_allclose(got, video, atol=1e-9)
    first = np.flatnonzero(np.isclose(np.arange(n) * take_fps / target_fps % rows, 0))[1:]
    assert first.size and np.all(np.abs(got[first]) < 1e-9)   # each repeat starts at row 0


@pytest.mark.parametrize("fps, start", [(60.0, "01:02:03:04"), (25.0, "10:11:12:13"),
                                        (30.0, "01:02:03:04"), (24.0, None)])
def test_a_looped_take_of_the_apps_timecodes_repeats_from_its_first_row(fps, start):
    """A take at the target's own rate, its rows' times read from time-of-day timecodes (as
    every take the app records has), looped: each repeat's first frame shows row 0, as the
    looped video does (review48a). Before, the loop's span (last row plus the rows' median
    step, both differences of ~3723 s) came out an ulp past ``j / fps`` at most wraps: the
    frame stayed an ulp short of the repeat and showed the last row (a 60 fps take from
    01:02:03:04 looped at 60 fps: every row count from 62 to 178, the take's end shown for
    a frame where its start belongs)."""
    from facetransfer.export.livelink import format_timecode
    from facetransfer.transfer import time_map

    codes = [format_timecode(k, fps, start, labels="app") for k in range(int(3 * fps))]
    off = []
    for rows in range(int(fps) + 2, len(codes), 2):          # each over a second: rate known
        t = take_seconds(codes[:rows], warn=False)
        v = np.arange(rows, dtype=np.float64)[:, None]     # a row's value is its number
        got = take_on_timeline(t, v, 3 * rows, fps, align="loop")[:, 0]
        video = time_map(rows, fps, 3 * rows, fps, align="loop").source_time
        if not np.allclose(got, video, atol=1e-6):
            off.append(rows)
    assert off == []


def test_a_take_written_from_a_track_drives_the_same_expressions(arkit_model, make_arkit_track,
                                                                  tmp_path):
    """The exporter's take of a track, driving that track's own person: its activations come
    back (to the CSV's 8 decimals), identity and pose stay the target's, landmarks and
    blendshapes are the new expression's."""
    from facetransfer.export.livelink import write_livelink

    track, a, _ = make_arkit_track(arkit_model, 30, fps=25.0)     # 1.2 s: its rate shows
    take = write_livelink(track, tmp_path / "take.csv")
    target, _, _ = make_arkit_track(arkit_model, 30, seed=5, identity=2, fps=25.0)
    new = take_performance(take, target, arkit_model)
    assert new.n_frames == 30
    np.testing.assert_allclose(new.blendshapes, a, atol=1e-6)
    np.testing.assert_array_equal(new.weights["identity"], target.weights["identity"])
    np.testing.assert_array_equal(new.rotation, target.rotation)
    assert not np.allclose(new.landmarks2d, target.landmarks2d)
    slow, _, _ = make_arkit_track(arkit_model, 60, seed=5, identity=2, fps=50.0)
    twice = take_performance(take, slow, arkit_model)          # a 50 fps target: 2 frames a row
    np.testing.assert_allclose(twice.blendshapes[::2], a, atol=1e-6)
    np.testing.assert_allclose(twice.blendshapes[1:-1:2], (a[:-1] + a[1:]) / 2, atol=1e-6)


def test_a_take_needs_a_model_of_arkit_expressions(quick_model, arkit_model, make_arkit_track,
                                                   tmp_path):
    from facetransfer.export.livelink import write_livelink

    track, _, _ = make_arkit_track(arkit_model, 4)
    take = write_livelink(track, tmp_path / "take.csv")
    with pytest.raises(TransferError, match="ARKit blendshapes"):
        take_performance(take, track, quick_model)
    (tmp_path / "bad.csv").write_text("Timecode,BlendShapeCount,HeadYaw\n00:00:00:00,0,0\n")
    with pytest.raises(TransferError, match="lacks the columns"):
        take_performance(tmp_path / "bad.csv", track, arkit_model)


@pytest.fixture(scope="module")
def arkit_clip(arkit_model, tmp_path_factory):
    """A 10-frame target clip of the ARKit model's person 2 (neutral, turning), its truth
    track and the model file."""
    from test_transfer_rewrite import render_clip

    from facetransfer.io.video import write_video
    from facetransfer.texture import default_face_texture
    from facetransfer.topology import mesh_topology

    m = arkit_model
    d = tmp_path_factory.mktemp("take")
    neutral = m.training_weights("expression", "neutral")
    frames, track = render_clip(m, mesh_topology(m), default_face_texture(m, 256),
                                m.labels[0][2], [neutral] * 10, [0, 2, 4, 6, 8, 6, 4, 2, 0, -2],
                                seed=3)
    write_video(d / "target.mp4", frames, 25.0)
    track.save(d / "target.npz")
    m.save(d / "arkit.npz")
    return d


def test_transfer_from_a_take_on_the_command_line(arkit_clip, arkit_model, make_arkit_track,
                                                  tmp_path, capsys):
    """``transfer --expression-from take.csv``: the new performance is the take's (its
    activations at the target's frames), the video is written; what a take cannot be
    combined with, and a damaged take, are one line each before any work."""
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import read_video
    from facetransfer.track import Track

    track, a, _ = make_arkit_track(arkit_model, 30, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv")      # longer: the first 10 frames
    d = arkit_clip
    base = ["transfer", "--target", d / "target.mp4", "--target-track", d / "target.npz",
            "--model", d / "arkit.npz", "--no-progress", "--expression-from"]
    code = main([str(x) for x in base + [take, "--out", tmp_path / "out.mp4", "--save-track",
                                         tmp_path / "new.npz"]])
    assert code == 0, capsys.readouterr().err
    new = Track.load(tmp_path / "new.npz")
    np.testing.assert_allclose(new.blendshapes, a[:10], atol=1e-6)
    assert read_video(tmp_path / "out.mp4")[0].shape == read_video(d / "target.mp4")[0].shape
    capsys.readouterr()
    (tmp_path / "bad.csv").write_text("Timecode,BlendShapeCount\n00:00:00:00.000,61\n")
    lines = take.read_text().splitlines()      # a row repeated: the take is named (was not)
    (tmp_path / "rep.csv").write_text("\n".join(lines[:3] + lines[2:]) + "\n")
    for extra, said in (([take, "--pose-from", d / "target.mp4"], "--pose-from cannot be added"),
                        ([tmp_path / "bad.csv"], "lacks the columns"),
                        ([tmp_path / "rep.csv"], f"take {tmp_path / 'rep.csv'}'s timecodes "
                                                 "repeat at row 3"),
                        ([tmp_path / "none.csv"], "does not exist")):
        code = main([str(x) for x in base + extra + ["--out", tmp_path / "o2.mp4"]])
        err = capsys.readouterr().err
        assert code == 2 and said in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o2.mp4").exists()


def test_a_batch_of_pairs_takes_a_take_as_transfer_does(arkit_clip, arkit_model,
                                                        make_arkit_track, tmp_path, capsys,
                                                        monkeypatch):
    """A pairs manifest whose ``expression_from`` is a take: the row is rendered (before, its
    inputs were all opened as videos: "not a video"), the same video as ``transfer`` writes."""
    import functools

    from facetransfer.batch import cluster
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import read_video

    monkeypatch.setattr(cluster, "open_client",
                        functools.partial(cluster.open_client, processes=False))
    take = write_livelink(make_arkit_track(arkit_model, 30, fps=25.0)[0], tmp_path / "take.csv")
    d = arkit_clip
    common = ["--model", d / "arkit.npz"]
    assert main([str(x) for x in ["transfer", "--target", d / "target.mp4", "--target-track",
                                  d / "target.npz", "--expression-from", take, "--out",
                                  tmp_path / "ref.mp4", "--no-progress"] + common]) == 0
    man = tmp_path / "pairs.csv"
    man.write_text("name,target,target_track,expression_from\n"
                   f"t,{d / 'target.mp4'},{d / 'target.npz'},{take}\n")
    assert main([str(x) for x in ["batch", "transfer", "--manifest", man, "--out",
                                  tmp_path / "out", "--workers", "1"] + common]) == 0
    capsys.readouterr()
    np.testing.assert_array_equal(read_video(tmp_path / "out" / "t.mp4")[0],
                                  read_video(tmp_path / "ref.mp4")[0])


def test_takes_written_by_other_tools_are_read(arkit_model, make_arkit_track, tmp_path,
                                               caplog):
    """Names in ARKit's camelCase, no rotation columns, a shape left out, timecodes without
    thousandths at 60 a second, a byte-order mark and CRLF lines (a spreadsheet's save): the shapes given are the take's, the one left out is 0 (said
    once), the rows 1/60 s apart. A file without any shape column stays refused."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export.livelink import read_livelink

    rng = np.random.default_rng(1)
    names = [n for n in ARKIT_NAMES if n != "tongueOut"]
    a = rng.uniform(0, 1, (90, len(names)))
    lines = ["Timecode,BlendShapeCount," + ",".join(names)]
    for k in range(90):
        s, f = divmod(k, 60)
        lines.append(f"00:00:0{s}:{f:02d},{len(names)}," + ",".join(f"{v:.6f}" for v in a[k]))
    (tmp_path / "other.csv").write_text("\ufeff" + "\r\n".join(lines) + "\r\n",
                                        encoding="utf-8")      # as a spreadsheet saves it
    take = read_livelink(tmp_path / "other.csv", lenient=True)
    assert "TongueOut" in take.missing and "HeadYaw" in take.missing
    got = take.activations[:, [ARKIT_NAMES.index(n) for n in names]]
    np.testing.assert_allclose(got, a, atol=1e-6)
    assert np.all(take.activations[:, ARKIT_NAMES.index("tongueOut")] == 0)
    np.testing.assert_allclose(take_seconds(take.timecodes), np.arange(90) / 60)
    with pytest.raises(Exception, match="lacks the columns"):
        read_livelink(tmp_path / "other.csv")                   # the app's layout: strict
    target, _, _ = make_arkit_track(arkit_model, 30, fps=20.0)  # 1.5 s at 20 fps
    with caplog.at_level("WARNING", logger="facetransfer.take"):
        new = take_performance(tmp_path / "other.csv", target, arkit_model)
    assert [r.message for r in caplog.records if "tongueOut" in r.message.lower()
            or "TongueOut" in r.message][0].endswith("TongueOut: taken as 0")
    np.testing.assert_allclose(new.blendshapes[:, ARKIT_NAMES.index("jawOpen")],
                               a[::3, names.index("jawOpen")], atol=1e-5)
    (tmp_path / "none.csv").write_text("Timecode,BlendShapeCount,HeadYaw\n00:00:00:00,0,0.1\n")
    with pytest.raises(TransferError, match="lacks the columns"):
        take_performance(tmp_path / "none.csv", target, arkit_model)


def test_a_take_seen_on_a_face_has_its_curves_and_its_heads_rotation(arkit_model,
                                                                     make_arkit_track,
                                                                     tmp_path, capsys):
    """``take_track`` (what ``puppet take.csv`` renders): the take's activations at its own
    rate and the head's rotation its yaw, pitch and roll give back (the inverse of the
    exporter's angles, to the CSV's decimals); ``puppet`` writes its frames."""
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import read_video
    from facetransfer.take import take_track

    track, a, _ = make_arkit_track(arkit_model, 30, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv")
    wid = arkit_model.factors[0][2]
    got = take_track(take, arkit_model, wid)
    assert got.fps == 25.0 and got.n_frames == 30 and got.frame_size == (512, 512)
    np.testing.assert_allclose(got.blendshapes, a, atol=1e-6)
    np.testing.assert_allclose(got.rotation, track.rotation, atol=1e-6)
    np.testing.assert_array_equal(got.weights["identity"][0], wid)
    assert np.all((got.landmarks2d > 0) & (got.landmarks2d < 512))
    model = tmp_path / "arkit.npz"
    arkit_model.save(model)
    out = tmp_path / "preview.mp4"
    code = main([str(x) for x in ["puppet", take, "--identity", arkit_model.labels[0][2],
                                  "--model", model, "--out", out, "--max-frames", 12,
                                  "--no-progress"]])
    assert code == 0, capsys.readouterr().err
    frames, fps = read_video(out)
    assert frames.shape == (12, 512, 512, 3) and fps == 25.0
    assert frames[:, 256].std() > 10                       # a face, not the plain background
    code = main([str(x) for x in ["puppet", take, "--identity", arkit_model.labels[0][2],
                                  "--model", model, "--out", tmp_path / "o.mp4", "--face",
                                  "left"]])
    assert code == 2 and "--face is for a video" in capsys.readouterr().err
    # no --identity: the model's mean face (before: a usage error)
    code = main([str(x) for x in ["puppet", take, "--model", model, "--out",
                                  tmp_path / "mean.mp4", "--max-frames", 4, "--no-progress"]])
    out_text = capsys.readouterr().out
    assert code == 0 and "4 frames of the mean face performing the take" in out_text
    assert read_video(tmp_path / "mean.mp4")[0].shape == (4, 512, 512, 3)


def test_a_takes_turned_face_is_framed_at_the_centre(arkit_model, make_arkit_track, tmp_path):
    """``take_track`` (``puppet take.csv``, ``view``) keeps the box of the mean face, turned
    as the take's head is, at the frame's centre on every frame, at one scale (before: one
    translation, the unturned face's, for every frame; the model turns about its origin, off
    the face, and a turned face was drawn up to several pixels off centre)."""
    from facetransfer.export.livelink import write_livelink
    from facetransfer.take import take_track

    track, _, ang = make_arkit_track(arkit_model, 20, fps=25.0)
    assert np.abs(ang).max() > 0.3                  # turns a preview shows
    take = write_livelink(track, tmp_path / "take.csv")
    got = take_track(take, arkit_model, arkit_model.weight_mean(0))
    mean = arkit_model.synthesize(arkit_model.default_weights())
    assert np.ptp(got.scale) == 0
    for k in range(got.n_frames):
        p = got.scale[k] * (mean @ got.rotation[k][:2].T) * (1.0, -1.0) + got.translation[k]
        np.testing.assert_allclose(0.5 * (p.min(axis=0) + p.max(axis=0)), (255.5, 255.5),
                                   atol=1e-6)
    assert np.ptp(got.translation, axis=0).max() > 1.0   # it moves as the head turns


def test_a_take_is_placed_by_the_targets_timecode(arkit_clip, arkit_model, make_arkit_track,
                                                  tmp_path, capsys, caplog):
    """A take recorded beside the camera, both clocks synced: the target's first frame is the
    take's row at the target's start timecode (``--take-sync timecode``, the default); with
    ``--take-sync start``, or a timecode the take does not span, its first row."""
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import VideoOptions, read_video, write_video
    from facetransfer.take import timecode_seconds
    from facetransfer.track import Track

    assert timecode_seconds("01:00:00:00", 25.0) == 3600.0
    assert timecode_seconds("00:01:00;02", 29.97) == pytest.approx(1800 / 29.97)  # dropped 0, 1
    assert timecode_seconds("00:10:00;00", 30000 / 1001) == pytest.approx(17982 * 1.001 / 30)
    track, a, _ = make_arkit_track(arkit_model, 75, fps=25.0)        # 00:00:00:00 .. 00:00:02:24
    take = write_livelink(track, tmp_path / "take.csv")
    target, _, _ = make_arkit_track(arkit_model, 10, seed=5, identity=2, fps=25.0)
    at = take_performance(take, target, arkit_model, start_timecode="00:00:01:05")
    np.testing.assert_allclose(at.blendshapes, a[30:40], atol=1e-6)
    with caplog.at_level("WARNING", logger="facetransfer.take"):
        late = take_performance(take, target, arkit_model, start_timecode="00:01:00:00")
    np.testing.assert_allclose(late.blendshapes, a[:10], atol=1e-6)
    assert "does not span the target's start timecode 00:01:00:00" in caplog.text
    d = arkit_clip
    plate = tmp_path / "plate.mov"
    write_video(plate, read_video(d / "target.mp4")[0], 25.0,
                options=VideoOptions(crf=0, timecode="00:00:02:00"))
    for sync, first in (("timecode", 50), ("start", 0)):
        code = main([str(x) for x in [
            "transfer", "--target", plate, "--target-track", d / "target.npz", "--model",
            d / "arkit.npz", "--expression-from", take, "--take-sync", sync, "--out",
            tmp_path / f"{sync}.mp4", "--save-track", tmp_path / f"{sync}.npz",
            "--no-progress"]])
        assert code == 0, capsys.readouterr().err
        got = Track.load(tmp_path / f"{sync}.npz").blendshapes
        np.testing.assert_allclose(got, a[first:first + 10], atol=1e-6)


def _glb_and_usd_record_the_timecode(base: list, tmp_path: Path, capsys) -> None:
    """``export --format glb|usd`` of the timecoded plate's track (``base``: the livelink
    export's arguments): the plate's start timecode in the file's metadata (the glTF's
    ``extras``, the USD root layer's ``customLayerData``), said on the summary line; none
    with ``--timecode none``."""
    from pygltflib import GLTF2

    from facetransfer.cli.main import main

    glb = [str(x) for x in base[:2] + ["--format", "glb"] + base[4:] + [tmp_path / "t.glb"]]
    assert main(glb) == 0
    assert "the start timecode 00:00:02:00 of " in capsys.readouterr().out
    assert GLTF2().load(str(tmp_path / "t.glb")).extras["timecode"] == "00:00:02:00"
    assert main(glb + ["--timecode", "none"]) == 0
    assert "timecode" not in GLTF2().load(str(tmp_path / "t.glb")).extras
    if importlib.util.find_spec("pxr") is None:
        return
    from pxr import Usd

    assert main([str(x) for x in base[:2] + ["--format", "usd"] + base[4:]
                 + [tmp_path / "t.usda"]]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "t.usda"))      # kept: its layer lives with it
    assert stage.GetRootLayer().customLayerData["timecode"] == "00:00:02:00"
    capsys.readouterr()


def test_a_take_exported_from_a_timecoded_plate_starts_at_its_timecode(arkit_clip, arkit_model,
                                                                       tmp_path, capsys):
    """``export --format livelink`` of a plate's track: the take's first row is the plate's
    start timecode (``--timecode source``, the default), so that it lines up with the plate
    in an editor and ``transfer`` places it back by it, to the frame; a timecode given, or
    none; a bad one is one line."""
    import dataclasses

    from facetransfer.arkit import attach_activations
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import format_timecode, read_livelink
    from facetransfer.io.video import VideoOptions, read_video, write_video
    from facetransfer.track import Track

    assert format_timecode(0, 25.0, "01:00:00:00") == "01:00:00:00.000"
    assert format_timecode(3, 25.0, "01:00:00:10") == "01:00:00:13.000"
    d = arkit_clip
    plate = tmp_path / "plate.mov"
    write_video(plate, read_video(d / "target.mp4")[0], 25.0,
                options=VideoOptions(crf=0, timecode="00:00:02:00"))
    tr = attach_activations(Track.load(d / "target.npz"), arkit_model)
    tr = dataclasses.replace(tr, source=str(plate))
    tr.save(tmp_path / "plate.npz")
    base = ["export", tmp_path / "plate.npz", "--format", "livelink", "--model",
            d / "arkit.npz", "--overwrite", "--out"]
    # the app's rows (the default) count 30 a second: 01:00:00:05 of a 25 fps plate is 0.2 s
    # past the second, 01:00:00:06.000; the clip's own count writes it as the plate does
    for extra, first in (([], "00:00:02:00.000"), (["--timecode", "none"], "00:00:00:00.000"),
                         (["--timecode", "01:00:00:05"], "01:00:00:06.000"),
                         (["--timecode", "01:00:00:05", "--take-rate", "clip"],
                          "01:00:00:05.000")):
        assert main([str(x) for x in base + [tmp_path / "take.csv"] + extra]) == 0
        assert read_livelink(tmp_path / "take.csv").timecodes[0] == first
    assert "from timecode 01:00:00:05 (--timecode)" in capsys.readouterr().out
    assert main([str(x) for x in base + [tmp_path / "take.csv"]]) == 0
    code = main([str(x) for x in [
        "transfer", "--target", plate, "--target-track", tmp_path / "plate.npz", "--model",
        d / "arkit.npz", "--expression-from", tmp_path / "take.csv", "--out",
        tmp_path / "back.mp4", "--save-track", tmp_path / "back.npz", "--no-progress"]])
    assert code == 0, capsys.readouterr().err
    np.testing.assert_allclose(Track.load(tmp_path / "back.npz").blendshapes, tr.blendshapes,
                               atol=1e-6)
    capsys.readouterr()
    import functools

    from facetransfer.batch import cluster

    batch = ["batch", "export", tmp_path / "plate.npz", "--format", "livelink", "--out",
             tmp_path / "b", "--model", d / "arkit.npz", "--workers", "1"]
    with pytest.MonkeyPatch.context() as mp:     # batch export: the same first timecode
        mp.setattr(cluster, "open_client", functools.partial(cluster.open_client,
                                                             processes=False))
        assert main([str(x) for x in batch]) == 0
        default = (tmp_path / "b" / "plate.csv").read_bytes()
        # --take-rate clip: the command's own rows; the earlier output (the app's) is of other
        # options (a failed row, kept) until --overwrite
        assert main([str(x) for x in base + [tmp_path / "clip.csv", "--take-rate", "clip"]]) == 0
        assert main([str(x) for x in batch + ["--take-rate", "clip"]]) == 1
        assert (tmp_path / "b" / "plate.csv").read_bytes() == default
        assert main([str(x) for x in batch + ["--take-rate", "clip", "--overwrite"]]) == 0
        assert main([str(x) for x in batch + ["--take-rate", "clip", "--format", "glb"]]) == 2
    assert default == (tmp_path / "take.csv").read_bytes()      # the command's default rows
    assert (tmp_path / "b" / "plate.csv").read_bytes() == (tmp_path / "clip.csv").read_bytes()
    assert read_livelink(tmp_path / "b" / "plate.csv").timecodes[0] == "00:00:02:00.000"
    assert read_livelink(tmp_path / "b" / "plate.csv").timecodes[1] == "00:00:02:01.000"
    assert read_livelink(tmp_path / "take.csv").timecodes[1] == "00:00:02:01.200"
    capsys.readouterr()
    _glb_and_usd_record_the_timecode(base, tmp_path, capsys)
    for name, extra in (("t2.csv", ["--timecode", "1:00"]),
                        ("t3.csv", ["--timecode", "01:00:00:99"]),     # no frame 99
                        ("t4.csv", ["--timecode", "24:00:00:00"]),
                        ("t2.json", ["--timecode", "01:00:00:00", "--format", "json"])):
        code = main([str(x) for x in base + [tmp_path / name] + extra])
        err = capsys.readouterr().err
        assert code == 2 and "timecode" in err and len(err.strip().splitlines()) == 1, err


def test_a_damaged_take_is_named_by_line_and_column(arkit_model, make_arkit_track, tmp_path):
    """A row cut short, a value that is no number, a timecode that is none and an activation
    outside 0..1: each named by the file, its line and column (before: Python's own words,
    "list index out of range", and a timecode error without a file; 7.5 taken as it was)."""
    from facetransfer.export.common import ExportError
    from facetransfer.export.livelink import read_livelink, write_livelink

    track, _, _ = make_arkit_track(arkit_model, 6)
    good = write_livelink(track, tmp_path / "take.csv").read_text().splitlines()
    header = good[0].split(",")
    jaw = header.index("JawOpen")

    def damaged(line: int, edit) -> Path:
        rows = [r.split(",") for r in good]
        rows[line - 1] = edit(rows[line - 1])
        p = tmp_path / f"bad{line}.csv"
        p.write_text("\n".join(",".join(r) for r in rows) + "\n")
        return p

    def at(col, value):
        def edit(r):
            r[col] = value
            return r
        return edit

    cases = ((damaged(3, lambda r: r[:10]), f"line 3 has 10 fields, its header {len(header)}"),
             (damaged(4, at(jaw, "abc")), "line 4, column JawOpen: 'abc' is not a finite number"),
             (damaged(5, at(jaw, "nan")), "line 5, column JawOpen: 'nan' is not a finite number"),
             (damaged(2, at(0, "xx:yy")), "line 2: timecode 'xx:yy' is not HH:MM:SS:FF.mmm"),
             (damaged(6, at(jaw, "7.5")), "line 6, column JawOpen: 7.5 is outside 0..1"),
             # a column named twice: one of the two silently won (before)
             (damaged(1, at(jaw + 1, "jawOpen")), "names the column JawOpen twice"))
    for path, said in cases:
        with pytest.raises(ExportError) as exc:
            read_livelink(path, lenient=True)
        assert str(exc.value).startswith(f"{path} {said}"), str(exc.value)
    assert len(read_livelink(tmp_path / "take.csv").timecodes) == 6


def test_a_take_whose_curves_pass_one_as_the_apps_do_is_read(arkit_model, tmp_path):
    """ARKit's coefficients pass 1 a little at the extremes and the app writes them so (its
    public take alex_rom_4.csv: eyeLookIn up to 1.053 in 91 of 3809 rows): such a take is read,
    its value kept as written, and what it drives clipped to 1 (its preview's curves); before,
    every command refused it as "outside 0..1". A value past any activation is still refused."""
    from conftest import mean_person_track

    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export.common import ExportError
    from facetransfer.export.livelink import read_livelink, write_livelink
    from facetransfer.take import take_track

    def take(value: str, name: str):
        p = write_livelink(mean_person_track(arkit_model, np.zeros((4, 52), np.float32)),
                           tmp_path / name)
        rows = [r.split(",") for r in p.read_text().splitlines()]
        rows[2][rows[0].index("EyeLookInLeft")] = value
        p.write_text("\n".join(",".join(r) for r in rows) + "\n")
        return p

    j = ARKIT_NAMES.index("eyeLookInLeft")
    app = take("1.0533207655", "app.csv")
    assert read_livelink(app, lenient=True).activations[1, j] == 1.0533207655
    track = take_track(app, arkit_model, arkit_model.weight_mean("identity"))
    np.testing.assert_allclose(track.blendshapes[:, j], [0.0, 1.0, 0.0, 0.0], atol=1e-6)
    with pytest.raises(ExportError, match="line 3, column EyeLookInLeft: 1.3 is outside 0..1"):
        read_livelink(take("1.3", "bad.csv"), lenient=True)


def test_a_short_takes_rate_guess_names_the_take(caplog):
    """A take within one second of timecode: its rate is a guess, said once naming the take
    (a batch worker's line named nothing)."""
    import logging

    tc = [f"00:00:00:{i:02d}.000" for i in range(20)]
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        t = take_seconds(tc, name="take clips/short.csv")
    np.testing.assert_allclose(t[1], 1 / 24)
    assert [r.getMessage() for r in caplog.records] == [
        "take clips/short.csv lies within one second of timecode: its frames are taken at 24 "
        "a second (the smallest timecode rate above its frame numbers)"]


def test_a_take_at_the_plates_own_rate_counts_its_frames():
    """A take exported from a 23.976 fps plate (rows labelled as the plate's timecode counts
    its frames, 24 a second) is read back frame for frame: row k at k / 23.976 s from the
    plate's start (read as clock time, row 1000 would fall a frame late); a take of another
    rate (60 on a 29.97 plate), with the app's sub-frames, or beside a drop-frame start is
    read as clock time."""
    from facetransfer import take as tk
    from facetransfer.export.livelink import format_timecode

    fps = 24000 / 1001
    codes = [format_timecode(k, fps, "01:00:00:00") for k in range(1100)]
    assert codes[1000] == "01:00:41:16.000"
    clock, first = tk._take_clock(codes, fps, "01:00:00:00", "t")
    np.testing.assert_allclose(clock - first, np.arange(1100) / fps, atol=1e-9)
    sixty = [f"00:00:{k // 60:02d}:{k % 60:02d}.000" for k in range(120)]
    clock, first = tk._take_clock(sixty, 30000 / 1001, "00:00:00:00", "t")
    np.testing.assert_allclose(clock, np.arange(120) / 60.0, atol=1e-9)
    app = [f"00:00:{k // 60:02d}:{k % 60:02d}.{(k * 7) % 1000:03d}" for k in range(120)]
    clock, first = tk._take_clock(app, 60000 / 1001, "00:00:00:00", "t")   # the app's clock
    np.testing.assert_allclose(clock, np.arange(120) / 60.0 + (np.arange(120) * 7 % 1000)
                               / 60000.0, atol=1e-9)
    drop = [format_timecode(k, 30000 / 1001, "01:00:00;00") for k in range(40)]
    clock, first = tk._take_clock(drop, 30000 / 1001, "01:00:00;00", "t")
    np.testing.assert_allclose(clock - first, np.arange(40) / (30000 / 1001), atol=2e-5)


def test_a_take_past_midnight_and_a_short_one_are_read_frame_for_frame():
    """An export from 23:59:50:00 runs past midnight (its rows start again at 00:00:00:00):
    read on, not "go back in time" (both readers), and placed by a target start after
    midnight; a take of whole frames within one second is read at the target's rate (before:
    a guessed 24, 3.8 frames off after 20 frames of a 30 fps clip)."""
    from facetransfer import take as tk
    from facetransfer.export.livelink import format_timecode

    codes = [format_timecode(k, 25.0, "23:59:50:00") for k in range(400)]
    assert codes[250] == "00:00:00:00.000"
    clock, first = tk._take_clock(codes, 25.0, "00:00:02:00", "t")
    np.testing.assert_allclose(clock - clock[0], np.arange(400) / 25.0, atol=1e-9)
    assert first - clock[0] == pytest.approx(12.0)                 # 10 s to midnight + 2
    np.testing.assert_allclose(tk.take_seconds(codes, warn=False), np.arange(400) / 25.0,
                               atol=1e-9)
    short = [format_timecode(k, 30.0, "01:00:00:00") for k in range(20)]
    clock, _ = tk._take_clock(short, 30.0, None, "t")
    np.testing.assert_allclose(clock - clock[0], np.arange(20) / 30.0, atol=1e-9)


def test_a_short_take_says_where_it_is_held_and_an_aligned_one_says_nothing(
        arkit_model, make_arkit_track, tmp_path, caplog):
    """A take that ends before the target does holds its last row on the rest, said with the
    frames (before: the performance stood still without a word); a take whose first row is
    the target's start timecode is placed there without a warning (before: one, for the
    right case)."""
    from facetransfer.export.livelink import write_livelink

    track, a, _ = make_arkit_track(arkit_model, 20, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv", start="10:00:00:00")
    target, _, _ = make_arkit_track(arkit_model, 30, seed=5, identity=2, fps=25.0)
    with caplog.at_level("WARNING", logger="facetransfer.take"):
        held = take_performance(take, target, arkit_model)
    np.testing.assert_allclose(held.blendshapes[19:], np.tile(a[19], (11, 1)), atol=1e-6)
    assert "ends at the target's frame 19: its last row is held on frames 20-29" in caplog.text
    caplog.clear()
    with caplog.at_level("INFO", logger="facetransfer.take"):
        at = take_performance(take, target, arkit_model, start_timecode="10:00:00:00",
                              align="trim")
    assert at.n_frames == 20 and not [r for r in caplog.records if r.levelname == "WARNING"]
    assert "0.000 s into it" in caplog.text                           # said, as information


def test_a_takes_preview_runs_at_its_rows_ntsc_rate_from_its_start_timecode(
        arkit_model, make_arkit_track, tmp_path):
    """The app's takes carry clock time: a 29.97 fps take's rows lie 1001 / 30000 s apart.
    Its preview (``take_track``, ``puppet``, ``view``) runs at 29.97 (before: 30, 0.6 s adrift
    in ten minutes); whole-frame rows count frames at their nominal rate; the preview's start
    timecode is the take's first row's (before: none)."""
    from facetransfer.take import take_track

    from facetransfer.export.livelink import HEADER, LIVELINK_NAMES

    cols = ",".join(HEADER)
    rows = []
    for j in range(120):                    # 4 s at 29.97 fps, clock time at 30 nominal
        t = 59 + 20 / 30 + j * 1001 / 30000
        s, f = int(t), (t - int(t)) * 30
        ff, milli = int(f), int(round((f - int(f)) * 1000))
        if milli == 1000:
            ff, milli = ff + 1, 0
        tc = f"00:00:{s:02d}:{ff:02d}.{milli:03d}"
        rows.append(",".join([tc, "61"] + ["0.5" if n == "JawOpen" else "0"
                                           for n in LIVELINK_NAMES] + ["0"] * 9))
    take = tmp_path / "ntsc.csv"
    take.write_text(cols + "\n" + "\n".join(rows) + "\n")
    got = take_track(take, arkit_model, arkit_model.factors[0][0])
    assert got.fps == pytest.approx(30000 / 1001) and got.n_frames == 120
    from facetransfer.take import _rows_rate, _timecode_fields

    for n in (600, 18000):     # a long take too (the span's count alone missed it past ~500)
        t = 59 + 20 / 30 + np.arange(n) * 1001 / 30000
        tc = [f"00:{int(x // 60):02d}:{int(x % 60):02d}:{int((x % 1) * 30):02d}."
              f"{min(int(round(((x % 1) * 30 % 1) * 1000)), 999):03d}" for x in t]
        assert _rows_rate(take_seconds(tc, warn=False), _timecode_fields(tc)) == \
            pytest.approx(30000 / 1001), n
    assert got.info["start_timecode"] == "00:00:59:20"
    whole = tmp_path / "whole.csv"
    whole.write_text(cols + "\n" + "\n".join(
        ",".join([f"10:00:0{j // 30}:{j % 30:02d}.000", "61"] + ["0"] * 61) for j in range(60))
        + "\n")
    got = take_track(whole, arkit_model, arkit_model.factors[0][0])
    assert got.fps == 30.0 and got.info["start_timecode"] == "10:00:00:00"
    one = tmp_path / "one.csv"       # one row: at the rate it is said to be read at (before:
    one.write_text(cols + "\n" + ",".join(["10:00:00:05.000", "61"] + ["0"] * 61) + "\n")
    assert take_track(one, arkit_model, arkit_model.factors[0][0]).fps == 24.0  # said 24, 30


def test_a_takes_track_records_the_takes_start_and_exports_from_it(arkit_model,
                                                                   make_arkit_track,
                                                                   tmp_path, capsys):
    """A take seen as a track (``take_track``) records its first row's timecode as its clip's
    start (first frame 0): saved and exported, its take starts where the take did, with no
    note of an older track's clip read (before: the CSV was "read as its clip", giving no
    timecode, and the rows started at 00:00:00:00)."""
    from facetransfer.cli.main import main
    from facetransfer.export.livelink import read_livelink, write_livelink
    from facetransfer.io.source_facts import SourceFacts
    from facetransfer.take import take_track

    track, _, _ = make_arkit_track(arkit_model, 30, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv", start="01:02:03:04")
    got = take_track(take, arkit_model, arkit_model.factors[0][0])
    assert got.source_facts == SourceFacts(0, "01:02:03:04")
    saved = got.save(tmp_path / "take_track.npz")
    model = tmp_path / "arkit.npz"
    arkit_model.save(model)
    code = main([str(x) for x in ["export", saved, "--model", model, "--out",
                                  tmp_path / "again.csv"]])
    out = capsys.readouterr().out
    assert code == 0 and "note:" not in out, out
    assert read_livelink(tmp_path / "again.csv").timecodes[0].startswith("01:02:03:04")


def test_a_takes_start_timecode_counts_the_frames_it_plays_at(arkit_model, make_arkit_track,
                                                              tmp_path):
    """A 25 fps clip's take in the app's labels (frames of 30 a second, with thousandths) is
    played at 25 (``take_track``, ``puppet``, ``export take.csv``): its start timecode counts
    frames of 25, the clip's own (before: the label's frame number, of 30: from the clip's frame
    13 it said 15, 0.08 s late, and from frame 24 it said 28, a frame 25 fps has not)."""
    from facetransfer.export.livelink import read_livelink, write_livelink
    from facetransfer.take import take_track

    track, _, _ = make_arkit_track(arkit_model, 8, fps=25.0)
    for start, label in (("01:00:00:13", "01:00:00:15.600"), ("01:00:00:24", "01:00:00:28.800"),
                         ("23:59:59:00", "23:59:59:00.000")):
        take = write_livelink(track, tmp_path / "take.csv", start=start, overwrite=True)
        assert read_livelink(take).timecodes[0] == label
        got = take_track(take, arkit_model, arkit_model.factors[0][0])
        assert got.fps == 25.0 and got.source_facts.timecode == start, (start, got.source_facts)
        assert got.info["start_timecode"] == start


def test_a_short_take_of_the_apps_labels_is_read_at_unreals_rate(caplog):
    """A take within one second whose labels carry thousandths of a frame (the app's, and
    ``export --take-rate app``) counts frames of 30 a second (60 where a frame number passes
    29), as Unreal's importer reads it, without a guess said: 15 frames of a 25 fps clip are
    read at k / 25 s (before: a guessed 24, the last row 0.12 s early)."""
    import logging

    from facetransfer.export.livelink import format_timecode

    app = [format_timecode(k, 25.0, labels="app") for k in range(15)]
    assert app[14] == "00:00:00:16.800"
    with caplog.at_level(logging.WARNING, logger="facetransfer"):
        t = take_seconds(app, name="take short_app.csv")
        assert take_rate(app) == 30
    np.testing.assert_allclose(t, np.arange(15) / 25.0, atol=1e-9)
    assert caplog.records == []
    fifty = [format_timecode(k, 50.0, labels="app") for k in range(40)]   # 0.8 s, 60-based
    assert take_rate(fifty) == 60
    np.testing.assert_allclose(take_seconds(fifty), np.arange(40) / 50.0, atol=1e-9)
    early = [format_timecode(k, 50.0, labels="app") for k in range(20)]   # frames below 30
    assert take_rate(early) == 30      # as Unreal reads it: no frame number passes 29


def test_a_take_exports_as_glb_or_json(arkit_model, make_arkit_track, tmp_path, capsys):
    """``export take.csv --out face.glb`` (or ``.usd``, ``.json``): the take on the model's mean
    person, as ``puppet take.csv`` shows it, its activations exactly the take's (to the CSV's
    decimals); before, a take was refused ("not a track") and reached a
    glTF only through a transfer onto a video and a track of the result. A take asked for as a
    take, or with ``--texture-from`` (it has no video), is one line and exit status 2."""
    import pygltflib
    from test_export import _read_accessor

    from facetransfer.cli.main import main
    from facetransfer.export.common import head_quaternions
    from facetransfer.export.livelink import write_livelink
    from facetransfer.export.mpjson import read_mediapipe_json

    track, a, _ = make_arkit_track(arkit_model, 12, fps=25.0)
    take = write_livelink(track, tmp_path / "take.csv")
    model = tmp_path / "arkit.npz"
    arkit_model.save(model)
    for out in ("face.json", "face.glb"):
        code = main([str(x) for x in ["export", take, "--model", model,
                                      "--out", tmp_path / out]])
        assert code == 0, capsys.readouterr().err
        assert f"wrote {tmp_path / out}: 12 frames" in capsys.readouterr().out
    np.testing.assert_allclose(read_mediapipe_json(tmp_path / "face.json"), a, atol=1e-6)
    g = pygltflib.GLTF2().load(str(tmp_path / "face.glb"))
    assert len(g.meshes[0].extras["targetNames"]) == 52
    assert g.accessors[g.animations[0].samplers[0].input].count == 12
    # the take's head rotation, the head turning in place: a take holds no translation (before
    # the review, the preview's framing moved it with its rotation: 2.6 cm here, 0.8 on face_2's)
    channels = {c.target.path: g.animations[0].samplers[c.sampler].output
                for c in g.animations[0].channels if c.target.node == 0}   # the face node's
    q = _read_accessor(g, channels["rotation"])
    np.testing.assert_allclose(np.abs(np.sum(q * head_quaternions(track.rotation), axis=1)), 1,
                               atol=1e-5)
    moved = _read_accessor(g, channels["translation"])
    np.testing.assert_array_equal(moved, np.repeat(moved[:1], 12, axis=0))
    for extra, said in ((["--out", tmp_path / "again.csv"], "is a Live Link Face take already"),
                        (["--out", tmp_path / "t.glb", "--texture-from", take],
                         "is a take, of no video")):
        code = main([str(x) for x in ["export", take, "--model", model, *extra]])
        assert code == 2 and said in capsys.readouterr().err


def test_a_take_onto_a_plate_from_1001_starts_at_its_first_frame_and_says_the_rates(
        arkit_model, make_arkit_track, tmp_path, caplog):
    """A take onto a plate numbered from 1001 that stores no timecode (PNG) is placed from its
    first row at the plate's first frame, 1001: the plate's numbers are not a timecode (a take
    whose first row reads 00:00:41:17, frame 1001 at 24 fps, is placed as one from 00:00:00:00).
    Where it ends early because its rows run at 30 a second on a plate read at 24 fps (a PNG
    plate's default rate), the warning says both rates (before: only the frames, which read
    as if the take were placed six rows ahead)."""
    import dataclasses

    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.source_facts import SourceFacts

    track, a, _ = make_arkit_track(arkit_model, 30, fps=30.0)
    plain = write_livelink(track, tmp_path / "take.csv", labels="clip")
    late = write_livelink(track, tmp_path / "late.csv", start="00:00:33:11", labels="clip")
    target, _, _ = make_arkit_track(arkit_model, 30, seed=5, identity=2, fps=24.0)
    plate = dataclasses.replace(target, source="plate/sh.####.png",
                                source_facts=SourceFacts(1001, None))
    with caplog.at_level("WARNING", logger="facetransfer.take"):
        onto = take_performance(plain, plate, arkit_model)
    moved = take_performance(late, plate, arkit_model)
    np.testing.assert_allclose(onto.blendshapes[0], a[0], atol=1e-6)     # row 0 at 1001
    np.testing.assert_allclose(onto.blendshapes[4], a[5], atol=1e-6)     # 4/24 s: row 5
    np.testing.assert_allclose(moved.blendshapes, onto.blendshapes, atol=1e-9)
    assert ("ends at the target's frame 1024 (its rows 30 a second, the target's frames 24): "
            "its last row is held on frames 1025-1030") in caplog.text, caplog.text


def test_a_takes_glb_and_usd_eyes_look_where_the_take_recorded(arkit_model, tmp_path, capsys):
    """``export take.csv --out face.glb`` (and ``.usda``) of a take whose eye rotation columns
    say 20° to the subject's left and 0.1 rad down while its eyeLook* curves are all 0: the
    eyeballs' pupils (+z) point there, as the puppet and the ``view`` page show the take
    (:func:`facetransfer.puppet_face.track_gaze`). Before the review, the glb and the USD
    turned the eyes by the eyeLook* curves alone: the exported eyes looked straight ahead
    while the page's looked aside."""
    import pygltflib
    from scipy.spatial.transform import Rotation
    from test_export import _read_accessor
    from test_puppet_eyes import RECORDED, _take_with_eye_columns

    from facetransfer.cli.main import main
    from facetransfer.track.gaze import gaze_direction

    take = _take_with_eye_columns(arkit_model, tmp_path / "t.csv", **RECORDED)
    model = tmp_path / "arkit.npz"
    arkit_model.save(model)
    want = gaze_direction([0.35, -0.1])       # + toward the subject's left, pitch up
    for out in ("face.glb", "face.usda"):
        code = main([str(x) for x in ["export", take, "--model", model,
                                      "--out", tmp_path / out]])
        assert code == 0, capsys.readouterr().err
    g = pygltflib.GLTF2().load(str(tmp_path / "face.glb"))
    chans = {c.target.node: g.animations[0].samplers[c.sampler].output
             for c in g.animations[0].channels if c.target.path == "rotation"}
    for node in (1, 2):                       # eyeRight, eyeLeft
        q = _read_accessor(g, chans[node]).astype(np.float64)
        np.testing.assert_allclose(Rotation.from_quat(q).apply([0.0, 0.0, 1.0]),
                                   np.tile(want, (len(q), 1)), atol=1e-6)
    pxr = pytest.importorskip("pxr", reason="usd-core is not installed (extra [usd])")
    stage = pxr.Usd.Stage.Open(str(tmp_path / "face.usda"))
    rot = stage.GetPrimAtPath("/Face/Skel/Anim").GetAttribute("rotations")
    for t in rot.GetTimeSamples():
        for q in list(rot.Get(t))[1:]:        # the eye joints'
            xyzw = [*q.GetImaginary(), q.GetReal()]
            np.testing.assert_allclose(Rotation.from_quat(xyzw).apply([0.0, 0.0, 1.0]), want,
                                       atol=1e-6)


def test_a_takes_exported_eyes_each_follow_their_own_recorded_column(arkit_model, tmp_path,
                                                                       capsys):
    """The glb's ``eyeRight`` follows the take's ``RightEye*`` columns and ``eyeLeft`` its
    ``LeftEye*`` (reread55c: with both eyes recorded alike, a swap of the two went unseen)."""
    import pygltflib
    from scipy.spatial.transform import Rotation
    from test_export import _read_accessor
    from test_puppet_eyes import _take_with_eye_columns

    from facetransfer.cli.main import main
    from facetransfer.track.gaze import gaze_direction

    take = _take_with_eye_columns(arkit_model, tmp_path / "t.csv", LeftEyeYaw=-0.2,
                                  LeftEyePitch=0.05, RightEyeYaw=-0.35, RightEyePitch=0.1)
    model = tmp_path / "arkit.npz"
    arkit_model.save(model)
    code = main([str(x) for x in ["export", take, "--model", model,
                                  "--out", tmp_path / "face.glb"]])
    assert code == 0, capsys.readouterr().err
    g = pygltflib.GLTF2().load(str(tmp_path / "face.glb"))
    assert [n.name for n in g.nodes[1:3]] == ["eyeRight", "eyeLeft"]
    chans = {c.target.node: g.animations[0].samplers[c.sampler].output
             for c in g.animations[0].channels if c.target.path == "rotation"}
    for node, want in ((1, gaze_direction([0.35, -0.1])), (2, gaze_direction([0.2, -0.05]))):
        q = _read_accessor(g, chans[node]).astype(np.float64)
        np.testing.assert_allclose(Rotation.from_quat(q).apply([0.0, 0.0, 1.0]),
                                   np.tile(want, (len(q), 1)), atol=1e-6)

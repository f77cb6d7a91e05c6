"""``facetransfer batch track | transfer | export`` on an in-process Dask LocalCluster (no network):
outputs identical to the single-clip commands, summary.csv, failures, rerun, Ctrl-C, the model
scattered once, chunked tracking at the seams, and the issue's bad input."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import json
import socket
import sys
import types

import numpy as np
import pytest

from facetransfer.batch import cluster as batch_cluster
from facetransfer.batch import jobs as batch_jobs
from facetransfer.batch import run as batch_run
from facetransfer.cli.main import main
from facetransfer.io.video import read_video
from facetransfer.track import Track

from _tracks import assert_same_track_file
from conftest import clip_with_points

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture
def inproc(monkeypatch):
    """The CLI's embedded cluster as worker threads of this process (fast, no network)."""
    orig = batch_cluster.open_client
    monkeypatch.setattr(batch_cluster, "open_client",
                        functools.partial(orig, processes=False))


@pytest.fixture(scope="module")
def clips(quick_model, tmp_path_factory):
    """Two 8-frame synthetic clips (different faces and motion) and their first-frame points."""
    d = tmp_path_factory.mktemp("batchclips")
    return {name: clip_with_points(quick_model, 8, seed, d, video=f"{name}.mp4",
                                   points=f"{name}.json")
            for name, seed in (("a", 3), ("b", 4))}


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, [ln for ln in cap.err.splitlines() if ln.startswith("facetransfer")]


def _summary(path):
    with open(path, newline="") as fh:
        return {r["clip"]: r for r in csv.DictReader(fh)}


def test_batch_track_writes_what_track_writes_and_fails_bad_rows(clips, quick_model_path, inproc,
                                                                 tmp_path, capsys, monkeypatch):
    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    ref = tmp_path / "ref_a.npz"
    assert _cli(capsys, "track", va, "--model", quick_model_path, "--out", ref, "--init", pa,
                "--passes", "1")[0] == 0
    notvideo = tmp_path / "notvideo.mp4"
    notvideo.write_text("hello")
    man = tmp_path / "clips.csv"
    man.write_text("video,init,name\n"
                   f"{va},{pa},\n"
                   f"{vb},{pb},bee\n"
                   "missing.mp4,,\n"          # relative to the manifest's folder
                   f"{notvideo},,\n")
    out = tmp_path / "out"
    code, stdout, _ = _cli(capsys, "batch", "track", "--manifest", man, "--model",
                           quick_model_path, "--out", out, "--passes", "1", "--workers", "2")
    assert code == 1  # two rows failed, the others went on
    assert_same_track_file(out / "a.npz", ref)
    rows = _summary(out / "summary.csv")
    assert list(rows) == ["a", "bee", "missing", "notvideo"]
    tb = Track.load(out / "bee.npz")
    assert rows["bee"]["status"] == "done" and int(rows["bee"]["frames"]) == 8
    assert float(rows["bee"]["fps"]) == 25 and float(rows["bee"]["seconds"]) > 0
    np.testing.assert_allclose(float(rows["bee"]["mean_confidence"]), tb.confidence.mean(),
                               rtol=1e-5)
    assert rows["missing"]["status"] == "failed"
    assert str(tmp_path / "missing.mp4") in rows["missing"]["error"]
    assert rows["notvideo"]["status"] == "failed" and str(notvideo) in rows["notvideo"]["error"]
    assert "2 done, 2 failed" in stdout
    assert not (out / "missing.npz").exists()

    # a rerun tracks nothing that is done: the finished clips are skipped, untouched
    mtime = (out / "a.npz").stat().st_mtime_ns
    log = tmp_path / "calls.txt"  # tasks are pickled (by value, for this stand-in): a file
    log.write_text("")
    real = batch_jobs.track_clip
    monkeypatch.setattr(batch_jobs, "track_clip", lambda job, *a, **kw: (
        open(log, "a").write(job.name + "\n"), real(job, *a, **kw))[1])
    code, stdout, _ = _cli(capsys, "batch", "track", "--manifest", man, "--model",
                           quick_model_path, "--out", out, "--passes", "1", "--no-progress")
    assert code == 1 and sorted(log.read_text().split()) == ["missing", "notvideo"]
    assert (out / "a.npz").stat().st_mtime_ns == mtime
    rows = _summary(out / "summary.csv")
    assert rows["a"]["status"] == rows["bee"]["status"] == "skipped"
    assert int(rows["a"]["frames"]) == 8


def test_ctrl_c_cancels_the_pending_clips_and_keeps_the_finished(clips, quick_model_path,
                                                                 tmp_path, capsys, monkeypatch):
    (va, pa, _), (vb, _, _) = clips["a"], clips["b"]
    orig = batch_cluster.open_client
    monkeypatch.setattr(batch_cluster, "open_client",
                        functools.partial(orig, processes=False))
    real_finish = batch_run._Collector.finish

    def finish_then_ctrl_c(self, job, row):
        real_finish(self, job, row)
        raise KeyboardInterrupt

    monkeypatch.setattr(batch_run._Collector, "finish", finish_then_ctrl_c)
    monkeypatch.setattr(batch_cluster, "default_workers", lambda: 1)  # b waits behind a
    out = tmp_path / "out"
    argv = ("batch", "track", va, vb, "--init", pa, "--model", quick_model_path, "--out", out,
            "--passes", "1")
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    # in the CLI's line (it was a line of its own before it)
    assert code == 130 and f"facetransfer batch track: interrupted; finished outputs are kept " \
        f"in {out}" in err.splitlines()[-1]
    rows = _summary(out / "summary.csv")
    assert rows["a"]["status"] == "done" and rows["b"]["status"] == "cancelled"
    assert Track.load(out / "a.npz").n_frames == 8
    monkeypatch.setattr(batch_run._Collector, "finish", real_finish)
    code = main([str(a) for a in argv])
    capsys.readouterr()
    rows = _summary(out / "summary.csv")
    # b was cancelled while it ran on the worker thread, which may still have finished it
    assert code == 0 and rows["a"]["status"] == "skipped"
    assert rows["b"]["status"] in ("done", "skipped") and Track.load(out / "b.npz").n_frames == 8


def test_ctrl_c_while_the_tasks_are_submitted_writes_the_summary(clips, quick_model_path,
                                                                  inproc, tmp_path, capsys,
                                                                  monkeypatch):
    """A Ctrl-C as the run submits its tasks (a batch of many clips submits for seconds while
    the first ones run) ended it with no summary: the clips' rows and digests were lost. Now
    the run's: what was submitted cancelled, the summary written, exit 130."""
    from facetransfer.batch.track_submit import TrackSubmit

    (va, pa, _), (vb, _, _) = clips["a"], clips["b"]
    real_submit, submitted = TrackSubmit.submit, []

    def submit_then_ctrl_c(self, job):
        if submitted:
            raise KeyboardInterrupt
        submitted.append(job.name)
        real_submit(self, job)

    monkeypatch.setattr(TrackSubmit, "submit", submit_then_ctrl_c)
    out = tmp_path / "out"
    code = main([str(a) for a in ("batch", "track", va, vb, "--init", pa, "--model",
                                  quick_model_path, "--out", out, "--passes", "1")])
    capsys.readouterr()
    assert code == 130 and submitted == ["a"]
    rows = _summary(out / "summary.csv")          # before: no summary.csv
    assert rows["b"]["status"] == "cancelled" and rows["b"]["job"].startswith("v2:")
    assert rows["a"]["status"] in ("cancelled", "done")


def test_ctrl_c_before_the_cluster_is_there_says_no_outputs_kept(clips, quick_model_path,
                                                                tmp_path, capsys, monkeypatch):
    """Ctrl-C while the cluster starts or the scheduler is asked (a hung one: the only way
    out): nothing ran, so no "finished outputs are kept in DIR" of a folder never made."""
    @contextlib.contextmanager
    def interrupted(**kw):
        raise KeyboardInterrupt
        yield

    monkeypatch.setattr(batch_cluster, "open_client", interrupted)
    out = tmp_path / "out"
    code = main([str(a) for a in ("batch", "track", clips["a"][0], "--model", quick_model_path,
                                  "--out", out, "--scheduler", "tcp://127.0.0.1:8786")])
    err = capsys.readouterr().err
    assert code == 130 and err.splitlines() == ["facetransfer batch track: interrupted"]
    assert not out.exists()


def test_the_model_is_never_pickled_with_a_task(quick_model, tmp_path, monkeypatch):
    """Real worker processes, four tasks: a model of a file is not pickled at all (each worker
    loads it from its path, :mod:`facetransfer.batch.model_ref`); one built in memory is
    pickled once (scattered to the workers)."""
    import dataclasses

    from facetransfer.batch import batch_track, clip_jobs, open_client
    from facetransfer.model import MultilinearModel, load_model

    pickled = []
    monkeypatch.setattr(MultilinearModel, "__reduce_ex__",
                        lambda self, proto: pickled.append(1) or object.__reduce_ex__(self,
                                                                                      proto),
                        raising=False)
    jobs = clip_jobs([tmp_path / f"missing{i}.mp4" for i in range(4)])
    of_file = load_model(quick_model.save(tmp_path / "m.npz"))
    in_memory = dataclasses.replace(quick_model)
    with open_client(workers=1) as client:
        res = batch_track(jobs, tmp_path / "out", of_file, client=client)
        assert len(pickled) == 0
        res2 = batch_track(jobs, tmp_path / "out2", in_memory, client=client)
        assert len(pickled) == 1
    # each row failed on its worker with its own path
    for r in (res, res2):
        assert [r.status for r in r.rows] == ["failed"] * 4
        assert all(f"missing{i}.mp4" in r.error for i, r in enumerate(r.rows))


@pytest.mark.slow
def test_chunked_clip_is_one_identity_and_smooth_at_the_seams(quick_model, quick_model_path,
                                                              inproc, tmp_path, capsys):
    """A 30-frame clip in 3 chunks of <= 14 frames (5 shared), joined: one identity, landmarks
    on the ground truth at the seams as elsewhere, close to the clip tracked whole."""
    from facetransfer.batch import plan_chunks, seam_difference

    video, pts, clip = clip_with_points(quick_model, 30, 7, tmp_path, video="long.mp4",
                                        points="p.json")
    common = ("--model", quick_model_path, "--init", pts, "--passes", "1")
    assert _cli(capsys, "track", video, "--out", tmp_path / "whole.npz", *common)[0] == 0
    assert _cli(capsys, "batch", "track", video, "--out", tmp_path / "out", "--chunk", 14,
                "--overlap", 5, "--workers", 2, *common)[0] == 0
    whole = Track.load(tmp_path / "whole.npz")
    joined = Track.load(tmp_path / "out" / "long.npz")
    chunks = plan_chunks(30, 14, 5)
    assert len(chunks) == 3 and joined.n_frames == 30 and joined.fps == 25
    assert joined.source == str(video) and joined.model_hash == quick_model.content_hash
    assert np.ptp(joined.weights["identity"], axis=0).max() == 0
    err = np.linalg.norm(joined.landmarks2d - clip.truth.landmarks2d, axis=2).mean(axis=1)
    assert err.max() < 2.5  # as the whole-clip tracker on this footage (test_track_cli)
    rep = seam_difference(whole, joined, chunks, radius=3)
    assert max(rep.seam_px) < 2.0
    # no step at a seam: the motion there is the footage's, as in the whole-clip track
    assert all(m < w + 1.0 for m, w in zip(rep.motion_px, rep.whole_motion_px))


def test_max_frames_tracks_the_first_frames_and_a_rerun_knows_its_limit(
        clips, quick_model_path, inproc, tmp_path, capsys):
    """``batch track --max-frames`` as ``track --max-frames``: the same track file; the
    limit is part of the job's digest, so a rerun with another limit (or other tracker
    options) does not report the earlier track as "skipped" but a failed row naming
    --overwrite (before: no --max-frames; the options were not recorded at all); a manifest's
    max_frames column per clip, an empty cell taking --max-frames."""
    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    common = ("--model", quick_model_path, "--passes", "1")
    ref = tmp_path / "ref.npz"
    assert _cli(capsys, "track", va, "--init", pa, "--out", ref, "--max-frames", 5,
                *common)[0] == 0
    out = tmp_path / "out"
    argv = ("batch", "track", va, "--init", pa, "--out", out, *common)
    assert _cli(capsys, *argv, "--max-frames", 5)[0] == 0
    assert_same_track_file(out / "a.npz", ref)
    assert Track.load(out / "a.npz").n_frames == 5
    row = _summary(out / "summary.csv")["a"]
    assert row["status"] == "done" and int(row["frames"]) == 5
    assert row["job"].startswith("v2:") and len(row["job"]) == 19
    kept = (out / "a.npz").read_bytes()
    assert _cli(capsys, *argv, "--max-frames", 5)[0] == 0
    assert _summary(out / "summary.csv")["a"]["status"] == "skipped"
    for other in (("--max-frames", 6), ("--max-frames", 5, "--passes", 2), ()):
        code, stdout, _ = _cli(capsys, *argv, *other)
        row = _summary(out / "summary.csv")["a"]
        assert code == 1 and row["status"] == "failed", (other, row)
        assert row["error"] == (f"{out / 'a.npz'} was made from other inputs or options than "
                                "a's now; remove it to redo this clip alone, or --overwrite "
                                "redoes every clip")
        assert (out / "a.npz").read_bytes() == kept
    assert _cli(capsys, *argv, "--max-frames", 6, "--overwrite")[0] == 0
    assert Track.load(out / "a.npz").n_frames == 6
    assert _cli(capsys, *argv, "--max-frames", 4)[0] == 1   # the track says it, too
    assert "holds a track of 6 frames, more than max_frames 4" in _summary(
        out / "summary.csv")["a"]["error"]

    man = tmp_path / "clips.csv"
    man.write_text(f"video,init,max_frames\n{va},{pa},3\n{vb},{pb},\n")
    assert _cli(capsys, "batch", "track", "--manifest", man, "--out", tmp_path / "m",
                "--max-frames", 7, *common)[0] == 0
    assert [Track.load(tmp_path / "m" / f"{n}.npz").n_frames for n in "ab"] == [3, 7]


@pytest.mark.parametrize("value, said", [
    (0, "--max-frames must be >= 1, got 0"), (-2, "--max-frames must be >= 1, got -2"),
    ("ten", "argument --max-frames: invalid int value: 'ten'")])
def test_bad_max_frames_is_one_line(value, said, clips, quick_model_path, tmp_path, capsys):
    """As ``track --max-frames``: its type and its check."""
    try:
        code, _, lines = _cli(capsys, "batch", "track", clips["a"][0], "--model",
                              quick_model_path, "--out", tmp_path / "o", "--max-frames", value)
    except SystemExit as e:                          # the parser's error
        code, lines = e.code, capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1 and said in lines[0], lines
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("cell, said", [
    ("0", "line 3: max_frames must be >= 1, got 0"),
    ("2.5", "line 3: max_frames must be a whole number of frames >= 1, got '2.5'")])
def test_a_bad_max_frames_cell_is_one_line(cell, said, clips, quick_model_path, tmp_path,
                                           capsys):
    man = tmp_path / "clips.csv"
    man.write_text(f"video,max_frames\n{clips['a'][0]},4\n{clips['b'][0]},{cell}\n")
    code, _, lines = _cli(capsys, "batch", "track", "--manifest", man, "--model",
                          quick_model_path, "--out", tmp_path / "o")
    assert code == 2 and lines == [f"facetransfer batch track: error: manifest {man} {said}"]


def test_max_frames_of_a_chunked_clip(quick_model, quick_model_path, inproc, tmp_path, capsys):
    """``--chunk`` with ``--max-frames``: the chunks cover the first max_frames frames only
    (counted no further), joined; a limit within one chunk is the clip tracked whole, as
    ``track --max-frames`` does."""
    video, pts, clip = clip_with_points(quick_model, 20, 5, tmp_path, video="long.mp4",
                                        points="p.json")
    assert batch_jobs.count_frames(str(video), 14) == 14
    assert batch_jobs.count_frames(str(video)) == 20
    common = ("--model", quick_model_path, "--init", pts, "--passes", "1")
    assert _cli(capsys, "batch", "track", video, "--out", tmp_path / "c", "--chunk", 10,
                "--overlap", 2, "--max-frames", 14, *common)[0] == 0
    joined = Track.load(tmp_path / "c" / "long.npz")
    assert joined.n_frames == 14 and np.ptp(joined.weights["identity"], axis=0).max() == 0
    err = np.linalg.norm(joined.landmarks2d - clip.truth.landmarks2d[:14], axis=2).mean(axis=1)
    assert err.max() < 2.5
    assert _cli(capsys, "batch", "track", video, "--out", tmp_path / "w", "--chunk", 10,
                "--overlap", 2, "--max-frames", 9, *common)[0] == 0
    assert _cli(capsys, "track", video, "--out", tmp_path / "ref.npz", "--max-frames", 9,
                *common)[0] == 0
    assert_same_track_file(tmp_path / "w" / "long.npz", tmp_path / "ref.npz")


def test_batch_transfer_calls_what_transfer_calls(clips, quick_model_path, inproc, tmp_path,
                                                  capsys):
    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    ta, tb = tmp_path / "ta.npz", tmp_path / "tb.npz"
    for v, p, t in ((va, pa, ta), (vb, pb, tb)):
        assert _cli(capsys, "track", v, "--model", quick_model_path, "--out", t, "--init", p,
                    "--passes", "1")[0] == 0
    ref = tmp_path / "ref.mp4"
    assert _cli(capsys, "transfer", "--target", va, "--target-track", ta, "--expression-from",
                vb, "--source-track", tb, "--model", quick_model_path, "--out", ref,
                "--no-progress")[0] == 0
    man = tmp_path / "pairs.csv"
    man.write_text("name,target,target_track,expression_from,source_track\n"
                   f"ab,{va},{ta},{vb},{tb}\n"
                   f"gone,{tmp_path / 'gone.mp4'},,{vb},{tb}\n")
    out = tmp_path / "out"
    code, stdout, _ = _cli(capsys, "batch", "transfer", "--manifest", man, "--model",
                           quick_model_path, "--out", out, "--workers", "1")
    assert code == 1
    got, _ = read_video(out / "ab.mp4")
    want, _ = read_video(ref)
    assert got.shape == want.shape == (8, 240, 320, 3) and np.array_equal(got, want)
    rows = _summary(out / "summary.csv")
    assert rows["ab"]["status"] == "done" and int(rows["ab"]["frames"]) == 8
    assert rows["gone"]["status"] == "failed" and "gone.mp4" in rows["gone"]["error"]


def test_batch_transfer_writes_the_codec_asked_for(clips, quick_model_path, inproc, tmp_path,
                                                   capsys):
    """``--codec prores`` writes DIR/NAME.mov as ProRes, and of a 10-bit target in its depth
    (as ``transfer`` does); ``--codec h265 --crf 23`` DIR/NAME.mp4 as H.265; a bad --crf is one
    line and status 2 before any clip runs."""
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe
    from facetransfer.io.video_depth import video_bits
    from facetransfer.io.video_display import described_input

    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    ta, tb = tmp_path / "ta.npz", tmp_path / "tb.npz"
    for v, p, t in ((va, pa, ta), (vb, pb, tb)):
        assert _cli(capsys, "track", v, "--model", quick_model_path, "--out", t, "--init", p,
                    "--passes", "1")[0] == 0
    deep = tmp_path / "a10.mov"   # the target as 10-bit ProRes
    subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(va), "-c:v", "prores_ks",
                    "-profile:v", "3", "-pix_fmt", "yuv422p10le", str(deep)], check=True)
    man = tmp_path / "pairs.csv"
    man.write_text("name,target,target_track,expression_from,source_track\n"
                   f"ab,{deep},{ta},{vb},{tb}\n")
    out = tmp_path / "out"
    code, _, err = _cli(capsys, "batch", "transfer", "--manifest", man, "--model",
                        quick_model_path, "--out", out, "--workers", "1", "--codec", "prores")
    assert code == 0, err
    assert "prores" in described_input(out / "ab.mov") and video_bits(out / "ab.mov") == 10
    assert not (out / "ab.mp4").exists()
    assert _summary(out / "summary.csv")["ab"]["output"] == str(out / "ab.mov")
    code, _, err = _cli(capsys, "batch", "transfer", "--manifest", man, "--model",
                        quick_model_path, "--out", out, "--workers", "1", "--codec", "h265",
                        "--crf", "23")
    assert code == 0, err
    assert "hevc" in described_input(out / "ab.mp4") and len(read_video(out / "ab.mp4")[0]) == 8
    code, _, err = _cli(capsys, "batch", "transfer", "--manifest", man, "--model",
                        quick_model_path, "--out", out, "--crf", "60")
    assert code == 2 and len(err) == 1 and "--crf must be an integer from 0 to 51" in err[0]


def _stub_export(monkeypatch, calls):
    import importlib

    import facetransfer.cli.export  # noqa: F401 - the CLI's own import, before the stand-in
    import facetransfer.export as real
    importlib.import_module("facetransfer.export.livelink")   # the job digest's take labels

    mod = types.ModuleType("facetransfer.export")
    mod.FORMATS, mod.GEOMETRY_FORMATS = real.FORMATS, real.GEOMETRY_FORMATS

    def export_track(track, fmt, out, *, model=None, overwrite=False, texture=None,
                     neutral=None, labels=None):
        calls.append((track.n_frames, fmt, model is not None, neutral, labels))
        with open(out, "w") as fh:
            json.dump({"frames": track.n_frames, "format": fmt}, fh)
        return out

    mod.export_track = export_track
    monkeypatch.setitem(sys.modules, "facetransfer.export", mod)


def test_batch_export_on_a_running_scheduler(clips, quick_model_path, tmp_path, capsys,
                                             monkeypatch):
    """``--scheduler`` of a cluster started apart (its workers are threads of this process),
    with a stand-in for facetransfer.export (its own tests cover the formats)."""
    from dask.distributed import LocalCluster

    calls = []
    _stub_export(monkeypatch, calls)
    t1, t2 = tmp_path / "one.npz", tmp_path / "two.npz"
    (va, pa, _) = clips["a"]
    assert _cli(capsys, "track", va, "--model", quick_model_path, "--out", t1, "--init", pa,
                "--passes", "1")[0] == 0
    t2.write_bytes(b"not a track")
    out = tmp_path / "exp"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as running:
        code, _, _ = _cli(capsys, "batch", "export", t1, t2, "--format", "livelink", "--out",
                          out, "--model", quick_model_path, "--scheduler",
                          running.scheduler_address, "--neutral", "auto", "--take-rate",
                          "clip")
    assert code == 1 and calls == [(8, "livelink", True, "auto", "clip")]
    assert json.loads((out / "one.csv").read_text()) == {"frames": 8, "format": "livelink"}
    rows = _summary(out / "summary.csv")
    assert rows["one"]["status"] == "done" and rows["two"]["status"] == "failed"
    assert "two.npz" in rows["two"]["error"]
    code, _, lines = _cli(capsys, "batch", "export", t1, "--format", "json", "--out",
                          tmp_path / "exp2", "--neutral", "middle")
    assert code == 2 and len(lines) == 1 and "--neutral must be a frame number or auto" in lines[0]


def test_batch_export_with_the_real_module(clips, quick_model_path, inproc, tmp_path, capsys):
    pytest.importorskip("facetransfer.export",
                        reason="facetransfer.export is not on this branch yet (issue 14)")
    t1 = tmp_path / "one.npz"
    (va, pa, _) = clips["a"]
    assert _cli(capsys, "track", va, "--model", quick_model_path, "--out", t1, "--init", pa,
                "--passes", "1")[0] == 0
    code, _, _ = _cli(capsys, "batch", "export", t1, "--format", "json", "--out",
                      tmp_path / "exp", "--model", quick_model_path)
    row = _summary(tmp_path / "exp" / "summary.csv")["one"]
    # the quick model's expressions are not ARKit-named: export_track must say so, one line
    assert code == 1 and row["status"] == "failed" and "blendshapes" in row["error"]


# ------------------------------------------------------------------------------- bad input
def test_duplicate_names_are_refused_before_anything_runs(clips, quick_model_path, tmp_path,
                                                          capsys):
    va = clips["a"][0]
    other = tmp_path / "x"
    other.mkdir()
    dup = other / "a.mp4"
    dup.write_bytes(va.read_bytes())
    out = tmp_path / "out"
    code, _, lines = _cli(capsys, "batch", "track", va, dup, "--model", quick_model_path,
                          "--out", out)
    assert code == 2 and len(lines) == 1
    assert "two clips have the name 'a'" in lines[0] and str(dup) in lines[0]
    assert not out.exists()
    man = tmp_path / "m.csv"
    man.write_text(f"video,name\n{va},same\n{dup},SAME\n")
    code, _, lines = _cli(capsys, "batch", "track", "--manifest", man, "--model",
                          quick_model_path, "--out", out)
    assert code == 2 and "'SAME'" in lines[0]


def test_bad_cluster_and_output_arguments(clips, quick_model_path, tmp_path, capsys):
    va = clips["a"][0]
    m = ("--model", quick_model_path)
    afile = tmp_path / "file"
    afile.write_text("x")
    code, _, lines = _cli(capsys, "batch", "track", va, *m, "--out", afile)
    assert code == 2 and lines == [f"facetransfer batch track: error: output folder {afile} "
                                   "is a file"]
    code, _, lines = _cli(capsys, "batch", "track", va, *m, "--out", tmp_path / "o",
                          "--workers", 0)
    assert code == 2 and "--workers must be >= 1, got 0" in lines[0]
    code, _, lines = _cli(capsys, "batch", "track", va, *m, "--out", tmp_path / "o",
                          "--chunk", 100, "--overlap", 80)
    assert code == 2 and "--overlap must be between 1 and --chunk/2 = 50" in lines[0]
    code, _, lines = _cli(capsys, "batch", "track", *m, "--out", tmp_path / "o")
    assert code == 2 and "VIDEO files or --manifest" in lines[0]
    (tmp_path / "o").mkdir(exist_ok=True)
    clash = tmp_path / "o" / "t.npz"  # an input where its output would go
    clash.write_bytes(b"keep")
    code, _, lines = _cli(capsys, "batch", "track", clash, *m, "--out", tmp_path / "o")
    assert code == 2 and f"output {clash} of 't' is also one of its inputs" in lines[0]
    assert clash.read_bytes() == b"keep"
    bad = tmp_path / "bad.csv"
    bad.write_text("clip,init\nx.mp4,\n")
    code, _, lines = _cli(capsys, "batch", "track", "--manifest", bad, *m, "--out",
                          tmp_path / "o")
    assert code == 2 and "unknown column(s) ['clip']" in lines[0] and "bad.csv" in lines[0]


def test_a_scheduler_that_does_not_answer(clips, quick_model_path, tmp_path, capsys):
    """Nothing listening, an unknown host, not an address: one line each, status 2."""
    with socket.socket() as s:  # a free port, nothing listening once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ("batch", "track", clips["a"][0], "--model", quick_model_path, "--out",
            tmp_path / "o", "--scheduler")
    for addr, said in ((f"tcp://127.0.0.1:{port}", "Connection refused (start it with `dask "
                        "scheduler`, or check the address)"),
                       ("tcp://no-such-host.invalid:8786", "the host 'no-such-host.invalid' "
                        "is not known")):
        code, _, lines = _cli(capsys, *argv, addr)
        assert code == 2 and len(lines) == 1, lines
        assert lines[0].startswith("facetransfer batch track: error: no Dask scheduler "
                                   f"answered at {addr}: {said}")
    for addr in ("nonsense:addr:1", "tcp://127.0.0.1:99999"):   # 99999: "Connection refused"
        code, _, lines = _cli(capsys, *argv, addr)
        assert code == 2 and lines == [f"facetransfer batch track: error: --scheduler {addr!r} is "
                                       "not an address like tcp://HOST:8786"]
    assert not (tmp_path / "o").exists()


@contextlib.contextmanager
def _not_a_scheduler(kind: str):
    """A local port where something that is not a Dask scheduler listens: ``"http"`` a web
    server (it waits for a request), ``"silent"`` a program that accepts and says nothing,
    ``"close"`` one that closes each connection at once, ``"greet"`` one that says a line
    first (as an SSH server does: read as Dask's frame count, 3e18 bytes were allocated)."""
    import http.server
    import threading

    if kind == "http":
        srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0),
                                              http.server.BaseHTTPRequestHandler)
        th = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05})
        th.start()
        try:
            yield f"tcp://127.0.0.1:{srv.server_address[1]}"
        finally:
            srv.shutdown()
            srv.server_close()
            th.join()
        return
    srv, kept, stop = socket.create_server(("127.0.0.1", 0)), [], threading.Event()
    srv.settimeout(0.05)

    def serve():
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            if kind == "close":
                conn.close()
                continue
            if kind == "greet":
                conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
            kept.append(conn)

    th = threading.Thread(target=serve)
    th.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        th.join()
        for c in kept:
            c.close()
        srv.close()


#: The CLI in a child process, which then prints the threads it has left (the test does not
#: hang if the run does: the child is killed after a generous timeout).
_CHILD = ("import sys, threading; from facetransfer.cli.main import main; code = main(sys.argv[1:])"
          "; print('threads', sorted(t.name for t in threading.enumerate())); sys.exit(code)")


@pytest.mark.parametrize("kind, said", [
    ("http", " within 2 s: something there accepts connections but said nothing in Dask's "
     "protocol"),
    ("silent", " within 2 s: something there accepts connections but said nothing in Dask's "
     "protocol"),
    ("close", ": something there accepts connections but closed them without a Dask answer"),
    ("greet", ": something there answered, but not in Dask's protocol"),
])
def test_a_port_that_answers_but_is_no_dask_scheduler(kind, said, clips, quick_model_path,
                                                      tmp_path):
    """``--scheduler`` of a web server's port, of a program that accepts and says nothing (Dask
    reads the handshake without a deadline: hung for good, 300 s measured), of one that closes
    at once (a message of a ConnectionResetError) or one that speaks first ("out of memory"):
    one line within about --timeout, naming the address and what was expected; no traceback,
    no Dask log line, no thread left."""
    import subprocess

    with _not_a_scheduler(kind) as addr:
        r = subprocess.run([sys.executable, "-c", _CHILD, "batch", "track", str(clips["a"][0]),
                            "--model", str(quick_model_path), "--out", str(tmp_path / "o"),
                            "--scheduler", addr, "--timeout", "2"],
                           capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines() == [
        f"facetransfer batch track: error: no Dask scheduler answered at {addr}{said} (is it the "
        "scheduler's address? `dask scheduler` prints it, port 8786 by default)"]
    assert r.stdout.splitlines() == ["threads ['MainThread']"]
    assert not (tmp_path / "o").exists()


def test_a_dask_worker_is_not_taken_for_the_scheduler(tmp_path):
    """A worker's address (the one a worker's log shows) answers in Dask's protocol: it is said
    as a worker's, not connected to as a client (a TypeError of its identity handler)."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      dashboard_address=None) as running:
        worker = next(iter(running.scheduler_info["workers"]))
        with pytest.raises(batch_run.BatchError, match=f"{worker} is a Dask worker, not a "
                                                       "scheduler; give the scheduler's"):
            with batch_cluster.open_client(scheduler=worker, timeout=5):
                pass
        with batch_cluster.open_client(scheduler=running.scheduler_address,
                                       timeout=5) as client:
            assert client.submit(int, "7").result() == 7


def test_an_output_that_is_not_this_clips_track_is_kept_unless_overwrite(quick_model, tmp_path):
    """What a rerun finds at DIR/NAME.npz: this clip's track (skipped), nothing (tracked), or
    something else, which was replaced with a warning before (a user's file, another clip's
    track, another model's): now the clip's row fails naming it and --overwrite."""
    from facetransfer.batch.manifest import ClipJob

    from conftest import still_track

    tr = still_track(quick_model, 3, source="clips/face_2.mp4")
    job = ClipJob("face_2", "elsewhere/face_2.mp4", "auto")
    out = tmp_path / "face_2.npz"
    assert batch_run._done_track(out, job, quick_model.content_hash) is None
    tr.save(out)
    assert batch_run._done_track(out, job, quick_model.content_hash).status == "skipped"
    for why, make in (("holds a track made with another model", lambda: None),
                      ("holds a track of katie.mp4, not of face_2.mp4",
                       lambda: Track.save(dataclasses.replace(tr, source="katie.mp4"), out,
                                          overwrite=True)),
                      ("is not a track", lambda: out.write_text("my precious notes"))):
        make()
        row = batch_run._done_track(out, job, "another" if "model" in why
                                    else quick_model.content_hash)
        assert row.status == "failed" and row.error.startswith(f"{out} {why}"), row
        assert row.error.endswith("; --overwrite replaces it")
    assert out.read_text() == "my precious notes"


def test_a_rerun_knows_an_output_of_other_inputs_from_its_own(arkit_model, make_arkit_track,
                                                              inproc, tmp_path, capsys):
    """``batch export`` records what made each output (the summary's ``job``): the same
    command again skips it; after the track changed, the old export is not reported as this
    track's (before: "skipped", the stale file kept as the result) but a failed row naming
    --overwrite, the file kept; --overwrite redoes it."""
    import os

    track, _, _ = make_arkit_track(arkit_model, 6, seed=1)
    t, m, out = tmp_path / "t.npz", tmp_path / "m.npz", tmp_path / "exp"
    track.save(t)
    arkit_model.save(m)
    argv = ("batch", "export", t, "--format", "livelink", "--out", out, "--model", m)
    assert _cli(capsys, *argv)[0] == 0
    first = _summary(out / "summary.csv")["t"]
    kept = (out / "t.csv").read_bytes()
    assert first["status"] == "done" and first["job"].startswith("v2:")
    assert _cli(capsys, *argv)[0] == 0
    assert _summary(out / "summary.csv")["t"]["status"] == "skipped"
    make_arkit_track(arkit_model, 6, seed=2)[0].save(t, overwrite=True)
    st = os.stat(t)
    os.utime(t, ns=(st.st_atime_ns, st.st_mtime_ns + 10 ** 9))
    assert _cli(capsys, *argv)[0] == 1
    row = _summary(out / "summary.csv")["t"]
    assert row["status"] == "failed" and row["error"] == (
        f"{out / 't.csv'} was made from other inputs or options than t's now; remove it to "
        "redo this clip alone, or --overwrite redoes every clip")
    assert (out / "t.csv").read_bytes() == kept
    assert _cli(capsys, *argv)[0] == 1                            # and the next run too
    assert _summary(out / "summary.csv")["t"]["status"] == "failed"
    assert _cli(capsys, *argv, "--overwrite")[0] == 0
    assert _summary(out / "summary.csv")["t"]["status"] == "done"
    assert (out / "t.csv").read_bytes() != kept


def test_the_embedded_cluster_has_no_more_workers_than_clips(clips, quick_model_path, inproc,
                                                            tmp_path, capsys, monkeypatch):
    """--workers 100 for one clip on this machine's cores started 100 worker processes (no
    clip finished in 2 minutes on 2 cores): the cluster has at most one worker per clip, and
    more workers than cores are said; the summary's count is singular for one clip."""
    asked = []
    orig = batch_cluster.open_client

    def spy(**kw):
        asked.append(kw["workers"])
        return orig(**kw)

    monkeypatch.setattr(batch_cluster, "open_client", spy)
    t1 = tmp_path / "one.npz"
    (va, pa, _) = clips["a"]
    assert _cli(capsys, "track", va, "--model", quick_model_path, "--out", t1, "--init", pa,
                "--passes", "1")[0] == 0
    main(["batch", "export", str(t1), "--format", "json", "--out", str(tmp_path / "exp"),
          "--model", str(quick_model_path), "--workers", "100"])
    said = capsys.readouterr()
    assert asked == [1]
    assert f"note: --workers 100 on {batch_cluster.default_workers()} cores" in said.err
    assert "export: 1 clip (1 failed)" in said.out


def test_a_klt_clip_saves_its_progress_as_often_as_a_captured_one(monkeypatch):
    """A batch worker ends without saving (README: every SAVE_EVERY seconds, with either
    tracker); the klt tracker was given track_video's own 20 s."""
    from facetransfer.track import tracker as track_tracker
    from facetransfer.track.settings import TrackerSettings

    seen = {}

    def fake_track_video(video, model, **kw):
        seen.update(kw)
        return "track"

    monkeypatch.setattr(track_tracker, "track_video", fake_track_video)
    out = batch_jobs._track("clip.mp4", None, "auto", TrackerSettings(tracker="klt"),
                            source="clip.mp4", checkpoint="clip.progress.npz")
    assert out == "track" and seen["checkpoint_every"] == batch_jobs.SAVE_EVERY


def test_a_later_chunk_without_a_face_says_so(quick_model, monkeypatch):
    """A later chunk in which no face is found: its capture's "no face found" (before: numpy's
    "need at least one array to stack" from the identity phase of no frames)."""
    from facetransfer.batch.chunks import Chunk
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.errors import VideoError
    from facetransfer.track import aspect, video_detect
    from facetransfer.track.detect import ClipDetections
    from facetransfer.track.settings import TrackerSettings

    n = 12
    det = ClipDetections(np.full((n, 68, 2), np.nan), np.full((n, 68, 2), np.nan),
                         np.full((n, 478, 2), np.nan, np.float32), None)
    monkeypatch.setattr(video_detect, "detect_video",
                        lambda frames, **kw: (det, 25.0, (64, 64), "v.mp4"))
    monkeypatch.setattr(aspect.View, "of", classmethod(lambda cls, video: cls()))
    from facetransfer.track.capture import held_identity

    assert held_identity(det, quick_model, None, np.zeros(5)) is None
    with pytest.raises(VideoError, match="no face found in v.mp4"):
        batch_jobs._chunk_capture(np.zeros((n, 64, 64, 3), np.uint8), quick_model,
                                  TrackerSettings(), ClipJob("v", "v.mp4"), Chunk(1, 10, 22),
                                  np.zeros(5))


def test_a_moved_or_copied_project_keeps_its_outputs(clips, quick_model_path, inproc, tmp_path,
                                                     capsys, monkeypatch):
    """The same command in a project (clips, manifest, output folder) moved or copied to
    another disk: the job digest held the inputs' paths and inodes, so every output was "made
    from other inputs or options" (3 of 3 clips refused, measured); now it holds their content:
    every clip is skipped with the digest it had, its track untouched. A clip replaced by
    another file under its name is still told apart."""
    import os
    import shutil

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    proj = tmp_path / "proj"
    (proj / "clips").mkdir(parents=True)
    for n in "ab":
        shutil.copy2(clips[n][0], proj / "clips" / f"{n}.mp4")
        shutil.copy2(clips[n][1], proj / "clips" / f"{n}.json")
    (proj / "clips.csv").write_text("video,init\nclips/a.mp4,clips/a.json\n"
                                    "clips/b.mp4,clips/b.json\n")

    def run(root):
        return _cli(capsys, "batch", "track", "--manifest", root / "clips.csv", "--model",
                    quick_model_path, "--out", root / "tracks", "--passes", "1", "--no-progress")

    assert run(proj)[0] == 0
    made = {n: (proj / "tracks" / f"{n}.npz").read_bytes() for n in "ab"}
    keys = {n: r["job"] for n, r in _summary(proj / "tracks" / "summary.csv").items()}
    copy, moved = tmp_path / "disk2" / "proj", tmp_path / "moved"
    shutil.copytree(proj, copy)                  # times kept, other inodes
    os.rename(proj, moved)
    for root in (copy, moved):
        code, out, _ = run(root)
        assert code == 0 and "(2 skipped)" in out, out
        assert {n: (r["status"], r["job"]) for n, r in _summary(
            root / "tracks" / "summary.csv").items()} == {n: ("skipped", keys[n]) for n in "ab"}
        assert {n: (root / "tracks" / f"{n}.npz").read_bytes() for n in "ab"} == made
    shutil.copy2(clips["b"][0], copy / "clips" / "a.mp4")      # b's frames under a's name
    assert run(copy)[0] == 1
    rows = _summary(copy / "tracks" / "summary.csv")
    assert rows["b"]["status"] == "skipped" and rows["a"]["status"] == "failed"
    assert rows["a"]["error"] == (f"{copy / 'tracks' / 'a.npz'} was made from other inputs or "
                                  "options than a's now; remove it to redo this clip alone, or "
                                  "--overwrite redoes every clip")
    assert (copy / "tracks" / "a.npz").read_bytes() == made["a"]


def test_a_summary_of_the_format_before_still_keeps_its_outputs(arkit_model, make_arkit_track,
                                                                inproc, tmp_path, capsys,
                                                                monkeypatch):
    """A summary an older version wrote (digests of 16 hex digits, of the inputs' paths,
    inodes and times): the rerun after the upgrade skips what it finished (its digest computed
    the old way matches) and records the new digest; an output whose input changed since is
    still refused, its line saying that an older summary also counted where files lay."""
    import re

    from facetransfer.batch import digest

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    m, out = tmp_path / "m.npz", tmp_path / "exp"
    arkit_model.save(m)
    tracks = [tmp_path / f"{n}.npz" for n in "tu"]
    for i, t in enumerate(tracks):
        make_arkit_track(arkit_model, 5, seed=i)[0].save(t)
    argv = ("batch", "export", *tracks, "--format", "json", "--out", out, "--model", m,
            "--no-progress")
    new_keys = batch_run.job_keys
    monkeypatch.setattr(batch_run, "job_keys", lambda jobs, what: {   # the version before
        j.name: digest.legacy_job_key(j, what) for j in jobs})
    assert _cli(capsys, *argv)[0] == 0
    old = {n: r["job"] for n, r in _summary(out / "summary.csv").items()}
    assert all(re.fullmatch("[0-9a-f]{16}", k) for k in old.values()), old
    monkeypatch.setattr(batch_run, "job_keys", new_keys)
    make_arkit_track(arkit_model, 5, seed=7)[0].save(tracks[1], overwrite=True)
    for _ in range(2):                          # the upgraded summary reads alike
        assert _cli(capsys, *argv)[0] == 1
        rows = _summary(out / "summary.csv")
        assert rows["t"]["status"] == "skipped" and rows["t"]["job"].startswith("v2:")
        assert rows["u"]["status"] == "failed" and rows["u"]["job"] == old["u"]
        assert rows["u"]["error"] == (
            f"{out / 'u.json'} was made from other inputs or options than u's now (or its "
            "files were moved or copied since: an older version's summary recorded where they "
            "lay); remove it to redo this clip alone, or --overwrite redoes every clip")


def test_a_take_written_with_the_angles_signs_before_is_exported_again(
        arkit_model, make_arkit_track, inproc, tmp_path, capsys, monkeypatch):
    """A livelink take a version before the fifty-fourth session's review wrote (its digest
    names its labels, not its angles' signs; its HeadYaw, HeadRoll and eye yaw turned against
    the app's): a rerun of the same ``batch export`` writes it again with the app's signs
    (before: skipped as this version's, the head turning the wrong way in Unreal kept); the
    next rerun skips it."""
    from facetransfer.export import livelink
    from facetransfer.export.common import head_euler

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    t, m, out = tmp_path / "t.npz", tmp_path / "m.npz", tmp_path / "exp"
    track = make_arkit_track(arkit_model, 6, seed=1)[0]
    track.save(t)
    arkit_model.save(m)
    take = ("batch", "export", t, "--format", "livelink", "--out", out, "--model", m,
            "--no-progress")
    yaw = head_euler(track.rotation)[:, 0]
    assert np.all(np.abs(yaw) > 1e-3)
    new_words, signs = batch_run._export_what, livelink.HEAD_SIGNS
    monkeypatch.setattr(batch_run, "_export_what", batch_run._export_what_labelled)
    monkeypatch.setattr(livelink, "HEAD_SIGNS", np.ones(3))          # the writer before
    assert _cli(capsys, *take)[0] == 0
    np.testing.assert_allclose(livelink.read_livelink(out / "t.csv").pose[:, 0], yaw, atol=1e-7)
    monkeypatch.setattr(batch_run, "_export_what", new_words)
    monkeypatch.setattr(livelink, "HEAD_SIGNS", signs)
    assert _cli(capsys, *take)[0] == 0
    row = _summary(out / "summary.csv")["t"]
    assert row["status"] == "done", row
    np.testing.assert_allclose(livelink.read_livelink(out / "t.csv").pose[:, 0], -yaw, atol=1e-7)
    assert _cli(capsys, *take)[0] == 0
    assert _summary(out / "summary.csv")["t"]["status"] == "skipped"


def _old_export_words(fmt, texture, neutral, model, labels=None):
    """``batch export``'s options in its digests as a version before ``--take-rate`` wrote
    them (its takes labelled in the clip's frames)."""
    return f"export {fmt} {texture} {neutral!r} " + (
        "default" if model is None else model.content_hash)


@pytest.mark.parametrize("form", ["v2", "legacy"])
def test_a_take_an_earlier_version_wrote_is_exported_again(form, arkit_model, make_arkit_track,
                                                            inproc, tmp_path, capsys,
                                                            monkeypatch):
    """A livelink take written by a version whose digest did not name its labels (rows in the
    clip's frames, the old default): a rerun exports it again with the labels asked for
    (before: skipped as the new default's, the take Unreal misplaces kept); the take so
    written is skipped by the next rerun; a json export of those words is skipped as before."""
    from facetransfer.batch import digest
    from facetransfer.export.livelink import read_livelink

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    t, m, out = tmp_path / "t.npz", tmp_path / "m.npz", tmp_path / "exp"
    make_arkit_track(arkit_model, 6, seed=1)[0].save(t)               # 25 fps
    arkit_model.save(m)
    take = ("batch", "export", t, "--format", "livelink", "--out", out, "--model", m,
            "--no-progress")
    data = ("batch", "export", t, "--format", "json", "--out", tmp_path / "js", "--model", m,
            "--no-progress")
    new_words, new_keys = batch_run._export_what, batch_run.job_keys
    monkeypatch.setattr(batch_run, "_export_what", _old_export_words)   # the version before
    if form == "legacy":
        monkeypatch.setattr(batch_run, "job_keys", lambda jobs, what: {
            j.name: digest.legacy_job_key(j, what) for j in jobs})
    assert _cli(capsys, *take, "--take-rate", "clip")[0] == 0 and _cli(capsys, *data)[0] == 0
    assert read_livelink(out / "t.csv").timecodes[1] == "00:00:00:01.000"
    monkeypatch.setattr(batch_run, "_export_what", new_words)
    monkeypatch.setattr(batch_run, "job_keys", new_keys)
    assert _cli(capsys, *data)[0] == 0
    assert _summary(tmp_path / "js" / "summary.csv")["t"]["status"] == "skipped"
    assert _cli(capsys, *take)[0] == 0
    row = _summary(out / "summary.csv")["t"]
    assert row["status"] == "done" and row["job"].startswith("v2:"), row
    assert read_livelink(out / "t.csv").timecodes[1] == "00:00:00:01.200"  # the app's labels
    assert _cli(capsys, *take)[0] == 0
    assert _summary(out / "summary.csv")["t"]["status"] == "skipped"
    assert _cli(capsys, *take, "--take-rate", "clip")[0] == 1        # of other options now
    assert read_livelink(out / "t.csv").timecodes[1] == "00:00:00:01.200"

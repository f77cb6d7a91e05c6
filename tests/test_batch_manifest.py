"""Batch manifests and the summary table (:mod:`facetransfer.batch.manifest`, ``.summary``)."""

from __future__ import annotations

import pytest

from facetransfer.batch import (BatchError, Row, clip_jobs, export_jobs, pair_jobs, read_summary,
                                write_summary)


def test_clip_manifest_resolves_paths_against_its_folder(tmp_path):
    d = tmp_path / "m"
    d.mkdir()
    man = d / "clips.csv"
    man.write_text("video,name,init\n"
                   "takes/one.mp4,,pts/one.json\n"
                   "\n"
                   f"{tmp_path / 'two.mp4'},second,\n")
    jobs = clip_jobs(["/data/three.mp4"], man)
    assert [(j.name, j.video, j.init) for j in jobs] == [
        ("three", "/data/three.mp4", "auto"),
        ("one", str(d / "takes" / "one.mp4"), str(d / "pts" / "one.json")),
        ("second", str(tmp_path / "two.mp4"), "auto")]


@pytest.mark.parametrize("text, message", [
    ("", "is empty"),
    ("video,fps\nx.mp4,25\n", "unknown column(s) ['fps']"),
    ("name\nx\n", "lacks the column(s) ['video']"),
    ("video,name\n,x\n", "line 2: column 'video' is empty"),
    ("video\n", "has no rows"),
    ("video,name\nx.mp4,../up\n", "'../up' cannot be an output file name"),
])
def test_bad_clip_manifests(tmp_path, text, message):
    man = tmp_path / "bad.csv"
    man.write_text(text)
    with pytest.raises(BatchError) as e:
        clip_jobs(manifest=man)
    assert message in str(e.value) and "bad.csv" in str(e.value)


def test_the_face_to_track_per_clip_and_per_pair(tmp_path):
    """``face`` (clips) and ``target_face`` / ``source_face`` (pairs) are values, not paths; an
    empty cell takes ``--face``; a cell that names no place fails before any clip runs."""
    man = tmp_path / "clips.csv"
    man.write_text('video,face\na.mp4,right\nb.mp4,\nc.mp4,"120, 80"\n')
    jobs = clip_jobs(["d.mp4"], man, face="left")
    assert [(j.name, j.face) for j in jobs] == [("d", "left"), ("a", "right"), ("b", "left"),
                                                ("c", "120, 80")]
    assert clip_jobs(["d.mp4"])[0].face is None
    with pytest.raises(BatchError, match="--face must be left, right, centre or pixels X,Y, "
                                         "got 'upstairs'"):
        clip_jobs(["d.mp4"], face="upstairs")
    man.write_text("video,face\na.mp4,right\nb.mp4,middle\n")
    with pytest.raises(BatchError, match=r"clips.csv line 3: face must be left, right, centre "
                                         r"or pixels X,Y, got 'middle'"):
        clip_jobs(manifest=man)
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("target,expression_from,target_face,source_face\nt.mp4,s.mp4,right,left\n")
    assert pair_jobs(pairs)[0].sources == {"expression_from": str(tmp_path / "s.mp4"),
                                           "target_face": "right", "source_face": "left"}
    pairs.write_text('target,expression_from,source_face\nt.mp4,s.mp4,"-3,4"\n')
    with pytest.raises(BatchError, match="pairs.csv line 2: source_face must be left"):
        pair_jobs(pairs)


def test_missing_manifest_and_no_clips(tmp_path):
    with pytest.raises(BatchError, match="manifest .*nope.csv does not exist"):
        clip_jobs(manifest=tmp_path / "nope.csv")
    with pytest.raises(BatchError, match="no clips"):
        clip_jobs([])
    with pytest.raises(BatchError, match="no track files"):
        export_jobs([])


def test_names_clash_also_in_case_and_across_sources(tmp_path):
    man = tmp_path / "m.csv"
    man.write_text("video\nother/Take1.mp4\n")
    with pytest.raises(BatchError, match="two clips have the name 'Take1'.*take1.mp4.*Take1.mp4"):
        clip_jobs(["take1.mp4"], man)
    with pytest.raises(BatchError, match="name 'x'"):
        export_jobs(["a/x.npz", "b/x.npz"])


def test_pairs_manifest(tmp_path):
    man = tmp_path / "pairs.csv"
    man.write_text("target,expression_from,source_track,identity_label,name\n"
                   "t.mp4,s.mp4,s.npz,,\n"
                   "t.mp4,,,id03,t_as_id03\n")
    a, b = pair_jobs(man)
    assert a.name == "t" and a.target == tmp_path / "t.mp4"
    assert a.sources == {"expression_from": str(tmp_path / "s.mp4"),
                         "source_track": str(tmp_path / "s.npz")}
    assert b.name == "t_as_id03" and b.sources == {"identity_label": "id03"}  # not a path


@pytest.mark.parametrize("rows, message", [
    ("t.mp4,,,\n", "nothing to transfer"),
    ("t.mp4,,s.npz,\n", "source_track needs expression_from"),
    ("t.mp4,s.mp4,,\nt.mp4,s2.mp4,,\n", "two clips have the name 't'"),
    ("t.mp4,,,v.mp4\n", None),
])
def test_bad_pairs(tmp_path, rows, message):
    man = tmp_path / "pairs.csv"
    man.write_text("target,expression_from,source_track,identity_from\n" + rows)
    if message is None:
        assert pair_jobs(man)[0].sources == {"identity_from": str(tmp_path / "v.mp4")}
        return
    with pytest.raises(BatchError, match=message):
        pair_jobs(man)


def test_summary_round_trip_and_one_line_errors(tmp_path):
    rows = [Row("a", "done", 120, 25.0, 3.5, 0.93, output="/o/a.npz", job="1f2e3d",
                matte="/o/a.matte/a.%05d.png", note="taken\n from an earlier attempt"),
            Row("b", "failed", error="video /x/b.mp4 does not exist\n  (details)"),
            Row("c", "cancelled")]
    p = write_summary(tmp_path / "summary.csv", rows)
    assert p.read_text().splitlines()[0] == \
        "clip,frames,fps,seconds,mean_confidence,status,error,output,job,matte,note"
    back = read_summary(p)
    assert back == [Row("a", "done", 120, 25.0, 3.5, 0.93, output="/o/a.npz", job="1f2e3d",
                        matte="/o/a.matte/a.%05d.png", note="taken from an earlier attempt"),
                    Row("b", "failed", error="video /x/b.mp4 does not exist (details)"),
                    Row("c", "cancelled")]
    # a summary written before the matte column: read with none
    p.write_text("clip,frames,fps,seconds,mean_confidence,status,error,output,job\n"
                 "a,120,25,3.5,0.93,done,,/o/a.mp4,v2:1f2e3d\n")
    assert read_summary(p) == [Row("a", "done", 120, 25.0, 3.5, 0.93, output="/o/a.mp4",
                                   job="v2:1f2e3d")]
    with pytest.raises(ValueError, match="status must be one of"):
        Row("d", "ok")


def test_a_pipeline_engineers_manifests_and_arguments(tmp_path, monkeypatch, capsys):
    """A walk with Dask: paths absolute before they reach a worker (a real scheduler's runs in
    its own folder: a relative clip "does not exist" there, and a rerun from another folder
    took every output for another job's); a column given twice and a row of more cells than
    its header refused (before: the last column won, the extra cell dropped); an export named
    like the summary refused; a chunk of a few frames refused; --timeout inf refused."""
    import os

    from facetransfer.batch.manifest import export_jobs
    from facetransfer.batch.run import _outputs

    monkeypatch.chdir(tmp_path)
    (tmp_path / "m").mkdir()
    man = tmp_path / "m" / "clips.csv"
    man.write_text("video,name\n../clips/a.mp4,x\n")
    assert clip_jobs(["b.mp4"], man)[0].video == str(tmp_path / "b.mp4")
    assert clip_jobs(manifest=man)[0].video == os.path.normpath(tmp_path / "clips" / "a.mp4")
    assert export_jobs(["t.npz"])[0].track == tmp_path / "t.npz"
    man.write_text("video,video\na.mp4,b.mp4\n")
    with pytest.raises(BatchError, match=r"has the column\(s\) \['video'\] more than once"):
        clip_jobs(manifest=man)
    man.write_text("video,name\na.mp4,x,,\n")       # a spreadsheet's trailing commas: taken
    assert clip_jobs(manifest=man)[0].name == "x"
    man.write_text("video,name\n\na.mp4,x,extra\n")
    with pytest.raises(BatchError, match="clips.csv line 3 has 3 cells, its header 2"):
        clip_jobs(manifest=man)
    with pytest.raises(BatchError, match="is the batch's summary.csv"):
        _outputs(export_jobs(["a/summary.npz"]), tmp_path, ".csv")
    with pytest.raises(BatchError, match=r"distinct names \(files of distinct names\)"):
        export_jobs(["a/t.npz", "b/t.npz"])
    from facetransfer.batch.run import batch_track

    with pytest.raises(BatchError, match="--chunk must be 0 .* or at least 10 frames"):
        batch_track([], tmp_path / "out", None, client=None, chunk=2)
    from facetransfer.cli.main import main

    for t in ("inf", "nan", "0", "1e12"):        # 1e12: a traceback (a socket's deadline)
        assert main(["batch", "track", "a.mp4", "--out", str(tmp_path / "o"), "--timeout",
                     t]) == 2
        assert capsys.readouterr().err.splitlines() == [
            "facetransfer batch track: error: --timeout must be a number of seconds > 0 and at "
            f"most 86400, got {float(t):g}"]


def test_a_clip_replaced_since_its_track_is_not_skipped(quick_model, tmp_path):
    """``batch track`` again after the clip under the same name was replaced by another (of
    another size and rate): its track is a failed row naming --overwrite (before: "skipped",
    the stale track kept as this run's)."""
    import numpy as np

    from conftest import still_track
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.batch.run import _done_track
    from facetransfer.io.video import write_video

    video = tmp_path / "shot.mp4"
    write_video(video, np.zeros((5, 64, 64, 3), np.uint8), 25.0)
    out = tmp_path / "shot.npz"
    still_track(quick_model, 5, source=str(video)).save(out)
    job = ClipJob("shot", str(video), "auto", None)
    assert _done_track(out, job, quick_model.content_hash).status == "skipped"
    write_video(video, np.zeros((5, 48, 80, 3), np.uint8), 30.0)
    row = _done_track(out, job, quick_model.content_hash)
    assert row.status == "failed" and "64x64 frames at 25 fps" in row.error
    assert "80x48 at 30 fps" in row.error and "--overwrite" in row.error


def test_a_lost_scheduler_and_a_dead_worker_are_said_as_such():
    """Dask's cancellations were reported as "FutureCancelledError: track_clip-923c...
    cancelled for reason: scheduler-connection-lost." on every row; the scheduler's logger's
    tracebacks printed without -v."""
    import logging

    from facetransfer.batch.cluster import quiet_dask
    from facetransfer.batch.run import _error_line

    class FutureCancelledError(Exception):
        pass

    assert _error_line(FutureCancelledError(
        "track_clip-923c cancelled for reason: scheduler-connection-lost.")).startswith(
        "the scheduler was lost")
    assert _error_line(FutureCancelledError("x cancelled for reason: already forgotten.")) \
        .startswith("its worker died")
    assert _error_line(ValueError("video a.mp4 does not exist")) == "video a.mp4 does not exist"
    import distributed  # noqa: F401 (its configuration sets its loggers' levels)

    quiet_dask(False)
    assert logging.getLogger("distributed.client").level == logging.CRITICAL
    quiet_dask(True)
    assert logging.getLogger("distributed.client").level == logging.INFO
    quiet_dask(False)


def test_the_summary_keeps_other_clips_and_an_unrecorded_output_is_not_adopted(tmp_path):
    """A run of some of the clips wrote a summary of those only, so a later run of them all
    took another clip's stale output for its own; an output that finished after a Ctrl-C (its
    row cancelled, no digest) was adopted by the next run whatever its options (a walk)."""
    from facetransfer.batch.manifest import ExportJob
    from facetransfer.batch.run import UNKNOWN_JOB, _Collector, _earlier, _earlier_rows, _kept
    from facetransfer.batch.summary import Row, write_summary

    write_summary(tmp_path / "summary.csv", [Row("A", "done", job="ka"),
                                             Row("B", "done", job="kb"),
                                             Row("C", "cancelled")])
    col = _Collector.__new__(_Collector)          # only what write() reads
    col.names, col.rows, col.summary = ["A"], {"A": Row("A", "skipped", job="ka")}, \
        tmp_path / "summary.csv"
    col.others = [r for r in _earlier_rows(tmp_path) if r.clip not in col.names]
    col.write()
    assert _earlier(tmp_path) == {"A": "ka", "B": "kb", "C": UNKNOWN_JOB}
    jobs = [ExportJob(n, tmp_path / f"{n}.npz") for n in "ABC"]
    outs = {n: tmp_path / f"{n}.json" for n in "ABC"}
    kept = _kept(jobs, outs, tmp_path, {"A": "ka", "B": "kb2", "C": "kc"},
                 lambda out, name: Row(name, "skipped"))
    assert kept["A"].status == "skipped"
    assert kept["B"].status == "failed" and "other inputs or options" in kept["B"].error
    assert kept["C"].status == "failed" and "after an interrupt" in kept["C"].error


def test_an_output_a_stopped_run_leaves_is_known_to_the_next(tmp_path):
    """The rows a run does not finish record what made their output. A clip cancelled by a
    Ctrl-C whose worker wrote it afterwards (the README's "then skipped by the next run"):
    its row had no digest and the next run of the same command refused it ("finished after an
    interrupt"); a task that failed in an --overwrite run left the earlier run's output, and
    its row forgot that run's digest, so the run after took that output for its own."""
    from facetransfer.batch.manifest import ExportJob
    from facetransfer.batch.run import _Collector, _kept, _unfinished

    write_summary(tmp_path / "summary.csv", [Row("B", "done", job="kb-before")])
    jobs = [ExportJob(n, tmp_path / f"{n}.npz") for n in "AB"]
    outs = {n: tmp_path / f"{n}.json" for n in "AB"}
    outs["B"].write_text("the earlier run's")
    keys = {"A": "ka", "B": "kb"}
    col = _Collector.__new__(_Collector)          # only what fail() and write() read
    col.names, col.rows, col.summary, col.others = ["A", "B"], {}, tmp_path / "summary.csv", []
    col.progress, col.last_write = None, 0.0
    col.unfinished = _unfinished(jobs, outs, tmp_path, keys)
    col.fail(jobs[1], RuntimeError("no face"), outs["B"])    # B failed, A cancelled
    col.write()
    outs["A"].write_text("written by A's worker after the Ctrl-C")
    assert {r.clip: (r.status, r.job) for r in read_summary(tmp_path / "summary.csv")} == {
        "A": ("cancelled", "ka"), "B": ("failed", "kb-before")}
    kept = _kept(jobs, outs, tmp_path, keys, lambda out, name: Row(name, "skipped"))
    assert kept["A"].status == "skipped" and kept["A"].job == "ka"
    assert kept["B"].status == "failed" and "other inputs or options" in kept["B"].error
    kept = _kept(jobs, outs, tmp_path, {"A": "ka2", "B": "kb"},
                 lambda out, name: Row(name, "skipped"))
    assert kept["A"].status == "failed" and "other inputs or options" in kept["A"].error


def test_a_jobs_options_text_names_what_differs_from_the_defaults():
    """The tracker options in a ``batch track`` digest: what was changed, so that a version
    adding an option (at its default) does not make every earlier track another job's."""
    import dataclasses

    from facetransfer.batch.run import options_text
    from facetransfer.track.options import TrackOptions
    from facetransfer.track.settings import TrackerSettings

    assert options_text(TrackerSettings()) == "TrackerSettings()"
    assert options_text(TrackerSettings("klt", TrackOptions(passes=3))) == (
        "TrackerSettings(tracker='klt', klt=TrackOptions(passes=3))")
    old = dataclasses.make_dataclass("Opt", [("a", int, dataclasses.field(default=1))],
                                     frozen=True)
    new = dataclasses.make_dataclass("Opt", [("a", int, dataclasses.field(default=1)),
                                             ("b", float, dataclasses.field(default=0.5))],
                                     frozen=True)
    assert options_text(old()) == options_text(new()) == "Opt()"
    assert options_text(new(b=0.25)) == "Opt(b=0.25)"

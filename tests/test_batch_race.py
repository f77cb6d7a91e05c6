"""Two ``batch`` runs into one folder at once: a job replaces its output only with the batch's
``--overwrite`` (or, for a pair rendered again, while it is still the file the run found); an
output another run wrote meanwhile is kept and the job's row fails, saying so. "Meanwhile" is
made deterministic: the other run's file is written from inside the job (a stand-in for the
tracker or the render), or is there before the job starts."""

from __future__ import annotations

import os
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.batch import jobs as J  # noqa: E402
from facetransfer.batch import ownership as O  # noqa: E402
from facetransfer.batch.manifest import ClipJob, ExportJob, PairJob  # noqa: E402
from facetransfer.errors import VideoError  # noqa: E402
from facetransfer.io.atomic import write_bytes_atomic  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.settings import TrackerSettings  # noqa: E402

import test_batch  # noqa: E402
from conftest import still_track  # noqa: E402

clips, inproc = test_batch.clips, test_batch.inproc
_cli, _summary = test_batch._cli, test_batch._summary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _which(p: Path) -> tuple:
    st = p.stat()
    return st.st_ino, st.st_mtime_ns, st.st_size


def _theirs(model, video, n: int = 5) -> Track:
    """Another run's track of ``video`` (``n`` frames: told apart from this run's)."""
    return still_track(model, n, source=str(video))


def test_a_track_job_keeps_the_track_another_run_wrote_meanwhile(clips, quick_model, tmp_path,
                                                                  monkeypatch):
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    calls = []

    def tracked(*a, **k):           # the other run finishes while this one tracks
        calls.append(1)
        if not out.exists():
            _theirs(quick_model, video).save(out, overwrite=False)
        return still_track(quick_model, 8, source=str(video))

    monkeypatch.setattr(J, "_track", tracked)
    with pytest.raises(O.OutputTaken, match="written by another run") as e:
        J.track_clip(job, str(out), quick_model, TrackerSettings())
    assert str(out) in str(e.value) and isinstance(e.value, ValueError)
    kept = _which(out)
    assert Track.load(out).n_frames == 5
    # there before the job starts: refused before any tracking
    with pytest.raises(O.OutputTaken, match="since this run began"):
        J.track_clip(job, str(out), quick_model, TrackerSettings())
    assert len(calls) == 1 and _which(out) == kept
    # the batch's --overwrite: replaced
    row = J.track_clip(job, str(out), quick_model, TrackerSettings(), True)
    assert row.status == "done" and Track.load(out).n_frames == 8


def test_a_joined_clip_and_an_export_keep_an_output_another_run_wrote(
        clips, quick_model, arkit_model, make_arkit_track, tmp_path, monkeypatch):
    from facetransfer.batch import chunks

    video = clips["a"][0]
    out = tmp_path / "a.npz"
    _theirs(quick_model, video).save(out)
    kept = _which(out)
    monkeypatch.setattr(chunks, "join_tracks",
                        lambda *a: still_track(quick_model, 8, source=str(video)))
    with pytest.raises(O.OutputTaken):
        J.join_clip(ClipJob("a", str(video)), str(out), quick_model, [], [])
    assert _which(out) == kept
    row = J.join_clip(ClipJob("a", str(video)), str(out), quick_model, [], [], True)
    assert row.status == "done" and Track.load(out).n_frames == 8

    track, js = tmp_path / "k.npz", tmp_path / "k.json"
    make_arkit_track(arkit_model, 4)[0].save(track)
    js.write_text("theirs")
    with pytest.raises(O.OutputTaken):
        J.export_one(ExportJob("k", track), "json", str(js))
    assert js.read_text() == "theirs"
    # a take the run found and writes again (an earlier version's): while it is still that file
    planned = O.output_identity(js)
    J.export_one(ExportJob("k", track), "json", str(js), planned=planned)
    assert js.read_text() != "theirs"
    planned = O.output_identity(js)
    os.unlink(js)
    js.write_text("theirs")
    with pytest.raises(O.OutputTaken, match="since this run began"):
        J.export_one(ExportJob("k", track), "json", str(js), planned=planned)
    assert js.read_text() == "theirs"
    J.export_one(ExportJob("k", track), "json", str(js), overwrite=True)
    assert js.read_text() != "theirs"


class _Render:
    """A stand-in for :func:`facetransfer.video_transfer.transfer_video`: ``before`` (the other
    run, meanwhile), then this run's result written as the real one commits it."""

    def __init__(self, before=None):
        self.before, self.seen = before, []

    def __call__(self, sources, out, model, *, overwrite, matte=None, **kw):
        self.seen.append(overwrite)
        if self.before is not None:
            self.before(Path(out), matte)
        write_bytes_atomic(out, b"mine", overwrite=overwrite)
        plan = types.SimpleNamespace(target_track=types.SimpleNamespace(confidence=np.ones(3)),
                                     fps=25.0)
        return types.SimpleNamespace(plan=plan, n_frames=3, matte=None)


SETTINGS = {"texture": "frame", "blend": "poisson", "mouth": None, "align": "trim",
            "max_frames": None, "track_method": "auto", "speed": "fast"}


def test_a_pair_keeps_a_result_another_run_wrote_and_replaces_only_what_it_found(
        clips, tmp_path, monkeypatch):
    from facetransfer import video_transfer

    job = PairJob("p", clips["a"][0], {"expression_from": str(clips["b"][0])})
    out = tmp_path / "p.mp4"

    def pair(render, **kw):
        monkeypatch.setattr(video_transfer, "transfer_video", render)
        return J.transfer_pair(job, str(out), None, dict(SETTINGS), **kw)

    # none there when planned: one written meanwhile is the other run's, kept
    theirs = _Render(lambda o, m: o.write_bytes(b"theirs"))
    with pytest.raises(O.OutputTaken, match="written by another run while this run"):
        pair(theirs)
    assert theirs.seen == [False] and out.read_bytes() == b"theirs"
    # its own result, found when planned and rendered again (for its matte): replaced
    planned, render = O.output_identity(out), _Render()
    assert planned and pair(render, planned=planned).status == "done"
    assert render.seen == [True] and out.read_bytes() == b"mine"
    # the file found was replaced before the job began (by another run): kept
    planned = O.output_identity(out)
    os.unlink(out)
    out.write_bytes(b"theirs again")
    render = _Render()
    with pytest.raises(O.OutputTaken, match="since this run began"):
        pair(render, planned=planned)
    assert render.seen == [] and out.read_bytes() == b"theirs again"
    # --overwrite: replaced
    assert pair(_Render(), overwrite=True).status == "done" and out.read_bytes() == b"mine"


def test_a_pair_whose_matte_another_run_placed_meanwhile_says_so(clips, tmp_path,
                                                                 monkeypatch):
    from facetransfer import video_transfer

    job = PairJob("p", clips["a"][0], {"expression_from": str(clips["b"][0])})
    out, matte = tmp_path / "p.mp4", J.matte_pattern(tmp_path, "p", ".png")

    def placed(o, m):    # the other run's matte placed, its result not yet: refused here
        Path(m).parent.mkdir()
        (Path(m).parent / "p.00000.png").write_bytes(b"theirs")
        raise VideoError(f"output frames {m} were written meanwhile by another run (1 files); "
                         "pass --overwrite to replace them")

    monkeypatch.setattr(video_transfer, "transfer_video", _Render(placed))
    with pytest.raises(O.OutputTaken):
        J.transfer_pair(job, str(out), None, dict(SETTINGS), str(matte))
    assert (Path(matte).parent / "p.00000.png").read_bytes() == b"theirs"


def _race(model_path, out, clips, capsys, *more):
    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    man = out.parent / "clips.csv"
    man.write_text(f"video,init\n{va},{pa}\n{vb},{pb}\n")
    return _cli(capsys, "batch", "track", "--manifest", man, "--model", model_path, "--out",
                out, "--passes", "1", "--workers", "1", "--no-progress", *more)


def test_two_batch_runs_into_one_folder_keep_the_first_run_s_track(clips, quick_model_path,
                                                                   inproc, tmp_path, capsys,
                                                                   monkeypatch):
    """Clip ``a``'s track is written by another run of the same command while this one
    tracks it: kept, its row failed (exit 1), ``b`` done. With the other run's summary row
    there, the row takes that run's digest and the same command again skips ``a``; without
    it, a rerun refuses ``a`` (options not recorded) and ``--overwrite`` replaces it."""
    first = tmp_path / "first" / "out"
    first.parent.mkdir()
    assert _race(quick_model_path, first, clips, capsys)[0] == 0    # the other run, alone
    real = J._track

    def meanwhile(out_dir, summary: bool):
        def track(video, *a, **k):
            res = real(video, *a, **k)
            if Path(str(video)).stem == "a" and not (out_dir / "a.npz").exists():
                shutil.copy2(first / "a.npz", out_dir / "a.npz")
                if summary:     # that run's summary, as it writes it as it finishes
                    text = (first / "summary.csv").read_text()
                    (out_dir / "summary.csv").write_text(text.replace(str(first),
                                                                      str(out_dir)))
            return res
        return track

    for summary in (True, False):
        out = tmp_path / f"with{summary}" / "out"
        out.parent.mkdir()
        monkeypatch.setattr(J, "_track", meanwhile(out, summary))
        code, said, _ = _race(quick_model_path, out, clips, capsys)
        kept = _which(out / "a.npz")
        rows = _summary(out / "summary.csv")
        assert code == 1 and "1 done, 1 failed" in said, said
        assert rows["a"]["status"] == "failed" and "written by another run" in rows["a"]["error"]
        assert rows["b"]["status"] == "done"
        mine = _summary(first / "summary.csv")["a"]["job"]
        assert rows["a"]["job"] == (mine if summary else "another-run")
        monkeypatch.setattr(J, "_track", real)
        code, said, _ = _race(quick_model_path, out, clips, capsys)
        assert _which(out / "a.npz") == kept
        rows = _summary(out / "summary.csv")
        if summary:
            assert code == 0 and rows["a"]["status"] == "skipped", said
        else:
            assert code == 1 and rows["a"]["status"] == "failed", said
            assert "written by another run into the folder" in rows["a"]["error"]
            code, said, _ = _race(quick_model_path, out, clips, capsys, "--overwrite")
            assert code == 0 and _which(out / "a.npz") != kept, said


def test_a_pair_removes_only_the_leftover_matte_its_run_found(clips, tmp_path, monkeypatch):
    """Frames of a pair's matte beside no result: those the run found when it planned
    (:func:`O.matte_identity`) are removed before the render, which then writes without
    replacing; others there at the job's start are another run's, kept (OutputTaken)."""
    from facetransfer import video_transfer

    job = PairJob("p", clips["a"][0], {"expression_from": str(clips["b"][0])})
    out, matte = tmp_path / "p.mp4", J.matte_pattern(tmp_path, "p", ".png")
    frame = Path(matte).parent / "p.00000.png"
    frame.parent.mkdir()
    frame.write_bytes(b"left over")
    planned = O.matte_identity(matte)
    assert planned and O.matte_identity(J.matte_pattern(tmp_path, "q", ".png")) == ""

    def seen(o, m):                       # the real render refuses frames without overwrite
        assert not Path(m).parent.exists() or not any(Path(m).parent.iterdir())

    render = _Render(seen)
    monkeypatch.setattr(video_transfer, "transfer_video", render)
    row = J.transfer_pair(job, str(out), None, dict(SETTINGS), str(matte), planned_matte=planned)
    assert row.status == "done" and render.seen == [False] and not frame.exists()
    # frames written since the run planned (none then, or others): another run's, kept
    os.unlink(out)
    frame.write_bytes(b"theirs")
    for before in ("", planned):
        with pytest.raises(O.OutputTaken, match="frames .* written by another run"):
            J.transfer_pair(job, str(out), None, dict(SETTINGS), str(matte),
                            planned_matte=before)
        assert frame.read_bytes() == b"theirs" and not out.exists()


def _seen_elsewhere(monkeypatch):
    """``os.stat`` as a client on another machine than the worker sees a shared folder (NFS):
    the same inode, size and times, its own device number for the mount."""
    real = os.stat

    def stat(path, *a, **k):
        st = real(path, *a, **k)
        return types.SimpleNamespace(**{f: getattr(st, f) for f in dir(st)
                                        if f.startswith("st_") and f != "st_dev"},
                                     st_dev=st.st_dev + 1)

    monkeypatch.setattr(os, "stat", stat)


def test_a_worker_on_another_machine_replaces_what_its_client_planned(
        clips, arkit_model, make_arkit_track, tmp_path, monkeypatch):
    """On a cluster of several machines sharing DIR, the client records the outputs it does
    again and the worker that renders them checks them: a file's device number is each
    machine's own, so the identity compared leaves it out (before, every output planned was
    "written by another run": a take of an earlier version, a result rendered again for its
    matte, a matte beside no result)."""
    from facetransfer import video_transfer

    track, js = tmp_path / "k.npz", tmp_path / "k.json"
    make_arkit_track(arkit_model, 4)[0].save(track)
    js.write_text("an earlier version's")
    out, matte = tmp_path / "p.mp4", J.matte_pattern(tmp_path, "p", ".png")
    out.write_bytes(b"its own result")
    frame = Path(matte).parent / "p.00000.png"
    frame.parent.mkdir()
    frame.write_bytes(b"left over")
    with monkeypatch.context() as client:
        _seen_elsewhere(client)
        planned = {p: O.output_identity(p) for p in (js, out)}
        planned_matte = O.matte_identity(matte)
    assert all(planned.values()) and planned_matte
    row = J.export_one(ExportJob("k", track), "json", str(js), planned=planned[js])
    assert row.status == "done" and js.read_text() != "an earlier version's"
    monkeypatch.setattr(video_transfer, "transfer_video", _Render())
    job = PairJob("p", clips["a"][0], {"expression_from": str(clips["b"][0])})
    row = J.transfer_pair(job, str(out), None, dict(SETTINGS), planned=planned[out])
    assert row.status == "done" and out.read_bytes() == b"mine"
    out.unlink()
    row = J.transfer_pair(job, str(out), None, dict(SETTINGS), str(matte),
                          planned_matte=planned_matte)
    assert row.status == "done" and not frame.exists()


def test_a_track_finished_by_the_stopped_run_s_worker_is_that_job_s(clips, quick_model_path,
                                                                    inproc, tmp_path, capsys,
                                                                    monkeypatch):
    """A run stopped while clip ``a`` was tracked (its row cancelled, with its digest): on a
    scheduler of its own the task goes on, and writes ``a.npz`` while the same command run
    again tracks it. That track is of the same job: the row keeps the job's digest, and the
    command once more skips it (before: 'another-run', and the next run failed the clip,
    naming --overwrite, where README says a clip finished after a stop is skipped)."""
    out = tmp_path / "out"
    assert _race(quick_model_path, out, clips, capsys)[0] == 0
    kept = tmp_path / "a.npz"
    shutil.move(out / "a.npz", kept)
    summary = (out / "summary.csv").read_text().splitlines(keepends=True)
    rows = _summary(out / "summary.csv")
    key = rows["a"]["job"]
    (out / "summary.csv").write_text("".join(
        summary[:1] + [f"a,,,0,,cancelled,,{out / 'a.npz'},{key},\n"]
        + [ln for ln in summary[1:] if not ln.startswith("a,")]))
    real = J._track

    def track(video, *a, **k):         # the stopped run's task finishes meanwhile
        res = real(video, *a, **k)
        if Path(str(video)).stem == "a" and not (out / "a.npz").exists():
            shutil.copy2(kept, out / "a.npz")
        return res

    monkeypatch.setattr(J, "_track", track)
    code, said, _ = _race(quick_model_path, out, clips, capsys)
    row = _summary(out / "summary.csv")["a"]
    assert code == 1 and row["status"] == "failed" and "another run" in row["error"], said
    assert row["job"] == key
    monkeypatch.setattr(J, "_track", real)
    code, said, _ = _race(quick_model_path, out, clips, capsys)
    assert code == 0 and _summary(out / "summary.csv")["a"]["status"] == "skipped", said


def test_a_job_claims_its_output_another_run_s_job_of_it_fails_at_its_start(
        clips, quick_model, tmp_path, monkeypatch):
    """Two runs' jobs of one output that both may replace it (here ``overwrite``; in a batch,
    both found the same earlier result and do it again): the first holds it
    while it runs (its claim file), so the other's fails at its start naming the holder, and
    writes nothing, not even its progress file. Before, both passed the check that the output
    was the file they found (the first had not written yet) and both replaced it, the later
    without a word."""
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    _theirs(quick_model, video, 3).save(out)          # the result both runs found
    errors, calls = [], []

    def tracked(*a, **k):          # the other run's job of it starts while this one tracks
        calls.append(1)
        n = 8 if len(calls) == 1 else 5       # this run's, the other's
        if n == 8:
            try:
                J.track_clip(job, str(out), quick_model, TrackerSettings(), True)
            except O.OutputTaken as exc:
                errors.append(str(exc))
        return still_track(quick_model, n, source=str(video))

    monkeypatch.setattr(J, "_track", tracked)
    partial = J.partial_path(out)
    partial.write_bytes(b"this run's progress")
    row = J.track_clip(job, str(out), quick_model, TrackerSettings(), True)
    assert row.status == "done" and Track.load(out).n_frames == 8
    assert len(calls) == 1 and len(errors) == 1
    assert errors[0].startswith(f"{out} is being written by another run "
                                f"(pid {os.getpid()} on host ")
    assert "run the same command again once that run has ended" in errors[0]
    assert not O.claim_path(out).exists() and not partial.exists()


def test_a_claim_held_by_another_process_refuses_and_one_left_by_a_killed_run_is_taken(
        clips, quick_model, arkit_model, make_arkit_track, tmp_path, monkeypatch):
    """A claim is held by its process: another process's (another machine's, on a shared
    folder) refuses every job of that output, naming its process and host, and leaves the
    progress file that run resumes from; once that process is killed (SIGKILL: no cleanup),
    its claim file, left behind, is taken over and the output written, or removed."""
    import subprocess

    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    claim = O.claim_path(out)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR | "
         "os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, b'pid 4242 on host "
         "render-7, since 20:00'); print('held', flush=True); sys.stdin.read()", str(claim)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        partial = J.partial_path(out)
        partial.write_bytes(b"that run's progress")
        monkeypatch.setattr(J, "_track", lambda *a, **k: still_track(quick_model, 8,
                                                                     source=str(video)))
        for overwrite in (False, True):
            with pytest.raises(O.OutputTaken, match=r"is being written by another run \(pid "
                                                    r"4242 on host render-7, since 20:00; two"):
                J.track_clip(job, str(out), quick_model, TrackerSettings(), overwrite)
        track, js = tmp_path / "k.npz", tmp_path / "a.json"
        make_arkit_track(arkit_model, 4)[0].save(track)
        assert not out.exists() and partial.read_bytes() == b"that run's progress"
        assert O.remove_stale_claims(tmp_path) == [] and claim.exists()     # held: kept
    finally:
        holder.kill()
        holder.wait()
    assert claim.exists()         # left by the killed run
    row = J.track_clip(job, str(out), quick_model, TrackerSettings())
    assert row.status == "done" and Track.load(out).n_frames == 8 and not claim.exists()
    row = J.export_one(ExportJob("k", track), "json", str(js))
    assert row.status == "done" and not O.claim_path(js).exists()
    # one left by a run stopped or killed (its workers end without removing it), not held:
    # removed by the next run as it plans, and by the stopped run once its cluster is closed
    claim.write_text("pid 4242 on host render-7, since 20:00")
    assert O.remove_stale_claims(tmp_path) == [claim] and not claim.exists()


@pytest.mark.filterwarnings("ignore:Port 8787 is already in use")
@pytest.mark.parametrize("how", ["--overwrite", "a failed result"])
def test_two_runs_started_together_that_redo_one_result_write_it_once(
        how, clips, quick_model_path, inproc, tmp_path, capsys, monkeypatch):
    """Two ``batch`` runs of one folder started together, both redoing results there (both
    with ``--overwrite``, or both finding pairs' results that do not decode): each output is
    written by exactly one of them, and the other's row says why (its job of it started
    while the first held it, or after the first had replaced the file it found). Before, both
    said "done", exit 0, and the later one's outputs were left. This run (on a thread) holds
    ``a`` while the other runs from its start to its end."""
    import threading

    from facetransfer import video_transfer
    from facetransfer.cli.main import main

    out = tmp_path / "out"
    if how == "--overwrite":
        assert _race(quick_model_path, out, clips, capsys)[0] == 0      # the earlier results
        man = out.parent / "clips.csv"
        argv = ["batch", "track", "--manifest", man, "--passes", "1", "--overwrite"]
    else:
        man = tmp_path / "pairs.csv"
        man.write_text(f"name,target,expression_from\na,{clips['a'][0]},{clips['b'][0]}\n"
                       f"b,{clips['b'][0]},{clips['a'][0]}\n")
        out.mkdir()
        for n in "ab":
            (out / f"{n}.mp4").write_bytes(b"a render that failed")
        argv = ["batch", "transfer", "--manifest", man, "--texture", "frame"]
        monkeypatch.setattr(video_transfer, "transfer_video", _Render())
    argv = [str(a) for a in argv + ["--model", quick_model_path, "--out", out, "--workers",
                                    "1", "--no-progress"]]
    found = {n: _which(p) for n in "ab" for p in out.glob(f"{n}.*") if p.suffix != ".csv"}
    holding, other_done, codes = threading.Event(), threading.Event(), {}
    where, name = ((J, "_track") if how == "--overwrite"
                   else (video_transfer, "transfer_video"))
    real = getattr(where, name)

    def meanwhile(first, *a, **k):     # this run's job of a: the other run goes meanwhile
        if Path(str(getattr(first, "target", first))).stem == "a" and not holding.is_set():
            holding.set()
            other_done.wait(300)
        return real(first, *a, **k)

    monkeypatch.setattr(where, name, meanwhile)
    this = threading.Thread(target=lambda: codes.update(this=main(argv)))
    this.start()
    try:
        assert holding.wait(300)
        codes["other"] = main(argv)
        theirs = _summary(out / "summary.csv")
    finally:
        other_done.set()
        this.join(300)
    rows = _summary(out / "summary.csv")
    # a: this run's (the other's job started while this one held it); b: the other's (done
    # before this run's job of it began, which found another file than the one it planned)
    assert codes == {"this": 1, "other": 1}, (rows, theirs)
    assert rows["a"]["status"] == "done" and theirs["a"]["status"] == "failed"
    assert "is being written by another run (pid " in theirs["a"]["error"]
    assert theirs["b"]["status"] == "done" and rows["b"]["status"] == "failed"
    assert "written by another run since this run began" in rows["b"]["error"]
    assert all(_which(Path(rows[n]["output"])) != found[n] for n in "ab")
    assert not list(out.glob(".*.claim"))

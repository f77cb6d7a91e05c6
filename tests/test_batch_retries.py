"""A batch job run twice by one run (Dask's scheduler takes the first attempt's worker for lost,
its heartbeat missed, and runs the task again while that attempt may go on), and a clip's
chunks under two runs at once: the retry waits for the first attempt's claim and takes the
output it wrote (:func:`facetransfer.batch.ownership.earlier_output`); another run's chunks
of a clip being tracked fail at once, none tracked twice."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import types
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.batch import jobs as J  # noqa: E402
from facetransfer.batch import ownership as O  # noqa: E402
from facetransfer.batch.manifest import BatchError, ClipJob, ExportJob, PairJob  # noqa: E402
from facetransfer.io.atomic import write_bytes_atomic  # noqa: E402
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.settings import TrackerSettings  # noqa: E402

import test_batch  # noqa: E402
from conftest import clip_with_points, still_track  # noqa: E402

clips, inproc = test_batch.clips, test_batch.inproc
_cli, _summary = test_batch._cli, test_batch._summary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

OWNER = "run0001 v2:00112233aabbccdd"


def _waiting(monkeypatch) -> threading.Event:
    """An event set as a job of :mod:`~facetransfer.batch.ownership` first sleeps waiting for
    a claim (the retry waiting, seen, not guessed from a join's timeout: on a loaded machine
    the retry may not yet have reached the claim)."""
    import time

    seen = threading.Event()

    def sleep(seconds):
        seen.set()
        time.sleep(seconds)

    monkeypatch.setattr(O, "time", types.SimpleNamespace(
        monotonic=time.monotonic, strftime=time.strftime, sleep=sleep))
    return seen


def _attempt(job, out, model, rows, **kw):
    """A job's attempt on a thread of its own (a worker's), its row or error in ``rows``."""
    def go():
        try:
            rows.append(J.track_clip(job, str(out), model, TrackerSettings(), **kw))
        except Exception as exc:  # noqa: BLE001
            rows.append(exc)
    t = threading.Thread(target=go)
    t.start()
    return t


def test_a_retry_of_the_run_s_own_job_waits_for_the_first_attempt_and_takes_its_track(
        clips, quick_model, tmp_path, monkeypatch):
    """Two attempts of one job of one run at once (a worker's threads): the second waits for
    the first's claim, then takes the track it wrote, tracking nothing, its row saying so.
    Before, it failed at once, "is being written by another run", though the first attempt
    finished the output. A job of another run (another owner) is still refused at once."""
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    go_on, calls, retry = threading.Event(), [], []

    def tracked(*a, **k):            # the first attempt: the retry starts meanwhile
        calls.append(1)
        assert go_on.wait(60)
        return still_track(quick_model, 7, source=str(video))

    monkeypatch.setattr(J, "_track", tracked)
    first_rows = []
    first = _attempt(job, out, quick_model, first_rows, owner=OWNER)
    while not calls and first.is_alive():
        first.join(0.01)
    assert calls, first_rows
    other = []
    _attempt(job, out, quick_model, other, owner="run0002 v2:00112233aabbccdd").join(30)
    assert isinstance(other[0], O.OutputTaken) and "being written by another run" in \
        str(other[0])
    waiting = _waiting(monkeypatch)
    second = _attempt(job, out, quick_model, retry, owner=OWNER)
    while not waiting.is_set() and second.is_alive():
        second.join(0.01)
    assert second.is_alive() and not retry      # waiting, not failed
    go_on.set()
    first.join(30)
    second.join(30)
    row = retry[0]
    assert not isinstance(row, Exception), row
    assert row.status == "done" and row.frames == 7 and len(calls) == 1
    assert row.note.startswith("this run's earlier attempt of the job (pid ") and not row.error
    assert "wrote the output: taken after waiting" in row.note
    assert first_rows[0].status == "done" and first_rows[0].note == ""
    assert Track.load(out).n_frames == 7


def _outcome(call, a, k):
    """``call(*a, **k)``'s result, or the exception it raised."""
    try:
        return call(*a, **k)
    except Exception as exc:  # noqa: BLE001
        return exc


#: What :func:`_run_twice` runs (set by the test; module-level: Dask pickles the task's
#: function, by reference where it is a module's).
_TWICE: dict = {}


def _run_twice(*a, **k):
    """A clip's task as Dask may run it: the first attempt, and, from inside its tracking
    (its worker taken for lost), a second of the same arguments, whose result the run gets."""
    real, waiting, second = _TWICE["real"], _TWICE["waiting"], []

    def first_tracks(*ta, **tk):
        t = threading.Thread(target=lambda: second.append(_outcome(real, a, k)))
        t.start()
        while not waiting.is_set() and t.is_alive():
            t.join(0.01)
        second.insert(0, t)
        J._track = _TWICE["tracked"]
        return _TWICE["tracked"]()

    J._track = first_tracks
    _TWICE["first"] = real(*a, **k)
    second[0].join(60)
    if isinstance(second[-1], Exception):
        raise second[-1]
    return second[-1]


def test_a_clip_s_task_run_again_by_dask_while_its_first_attempt_tracks_is_done_once(
        clips, quick_model, quick_model_path, inproc, tmp_path, capsys, monkeypatch):
    """``batch track`` as a user runs it; Dask runs the clip's task again while the first
    attempt still tracks (its worker taken for lost): here the task the run submitted is run
    a second time, with the arguments the run gave it, from inside the first's tracking, and
    the run gets the second's result, as from Dask. The retry waits for the first attempt and
    takes its track: tracked once, the row done with a note, exit 0. Before, the retry failed
    at once, "is being written by another run", that run its own: the row failed, exit 1,
    while the first attempt wrote the track."""
    video, pts, _ = clips["a"]
    calls = []
    monkeypatch.setitem(_TWICE, "real", J.track_clip)
    monkeypatch.setitem(_TWICE, "waiting", _waiting(monkeypatch))
    monkeypatch.setitem(_TWICE, "tracked", lambda *a, **k: calls.append(1) or still_track(
        quick_model, 8, source=str(video)))
    monkeypatch.setattr(J, "_track", J._track)      # (restored after _run_twice's)
    monkeypatch.setattr(J, "track_clip", _run_twice)
    out = tmp_path / "out"
    code, said, err = _cli(capsys, "batch", "track", video, "--out", out, "--init", pts,
                           "--model", quick_model_path, "--workers", 1, "--no-progress")
    row = _summary(out / "summary.csv")["a"]
    assert (code, row["status"], row["error"]) == (0, "done", ""), (said, err, row)
    assert row["note"].startswith("this run's earlier attempt of the job (pid ")
    assert "wrote the output: taken after waiting" in row["note"] and len(calls) == 1
    first = _TWICE.pop("first")
    assert first.status == "done" and not first.note
    assert Track.load(out / "a.npz").n_frames == 8 and not list(out.glob(".*.claim"))


def test_a_retry_started_after_the_first_attempt_ended_takes_its_output(
        clips, quick_model, tmp_path, monkeypatch):
    """The first attempt ended before its retry began (a worker without a nanny, not ended
    when taken for lost): the claim it leaves says which file it wrote, and the retry takes
    it. Before, the retry found an output there that the run had not found, "written by
    another run since this run began". A job of another run still says so; the run's end
    removes the claim left."""
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    calls = []
    monkeypatch.setattr(J, "_track", lambda *a, **k: calls.append(1) or still_track(
        quick_model, 6, source=str(video)))
    assert J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER).note == ""
    row = J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER)
    assert row.status == "done" and row.frames == 6 and len(calls) == 1
    assert "wrote the output: taken" in row.note and "waiting" not in row.note
    assert O.claim_path(out).exists()
    with pytest.raises(O.OutputTaken, match="written by another run since this run began"):
        J.track_clip(job, str(out), quick_model, TrackerSettings(), owner="run0002 x")
    J.track_clip(job, str(out), quick_model, TrackerSettings(), True, owner=OWNER)
    assert O.remove_stale_claims(tmp_path) == [O.claim_path(out)] and len(calls) == 2


def test_a_retry_of_a_join_a_pair_or_an_export_takes_the_output_its_first_attempt_wrote(
        clips, quick_model, arkit_model, make_arkit_track, tmp_path, monkeypatch):
    """As a clip's track: a join, a pair's render and an export run again by their run (the
    first attempt ended) take the output the first wrote, done once."""
    from facetransfer import video_transfer
    from facetransfer.batch import chunks

    video, done = clips["a"][0], []
    monkeypatch.setattr(chunks, "join_tracks", lambda *a: done.append("join") or still_track(
        quick_model, 8, source=str(video)))

    def render(sources, out, model, *, overwrite, matte=None, **kw):
        done.append("pair")
        write_bytes_atomic(out, Path(video).read_bytes(), overwrite=overwrite)
        plan = types.SimpleNamespace(target_track=types.SimpleNamespace(confidence=np.ones(8)),
                                     fps=25.0)
        return types.SimpleNamespace(plan=plan, n_frames=8, matte=None)

    monkeypatch.setattr(video_transfer, "transfer_video", render)
    track = tmp_path / "k.npz"
    make_arkit_track(arkit_model, 4)[0].save(track)
    settings = {"texture": "frame", "blend": "poisson", "mouth": None, "align": "trim",
                "max_frames": None, "track_method": "auto", "speed": "fast"}
    runs = {"join": lambda: J.join_clip(ClipJob("a", str(video)), str(tmp_path / "a.npz"),
                                        quick_model, [], [], owner=OWNER),
            "pair": lambda: J.transfer_pair(
                PairJob("p", video, {"expression_from": str(clips["b"][0])}),
                str(tmp_path / "p.mp4"), None, dict(settings), owner=OWNER),
            "export": lambda: J.export_one(ExportJob("k", track), "json",
                                           str(tmp_path / "k.json"), owner=OWNER)}
    for what, run in runs.items():
        first = run()
        out = Path(first.output)
        made = O.output_identity(out)
        row = run()
        assert first.note == "" and row.status == "done" and row.frames == first.frames
        assert "wrote the output: taken" in row.note and O.output_identity(out) == made
    assert done == ["join", "pair"]


def _holder(claim: Path, words: str):
    """Another process holding ``claim`` with ``words`` until told (a line on its stdin:
    words to add, then it ends) or killed."""
    code = ("import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT); "
            "fcntl.flock(fd, fcntl.LOCK_EX); os.ftruncate(fd, 0); "
            "os.write(fd, sys.argv[2].encode()); "
            "print('held', flush=True); more = sys.stdin.readline().strip(); "
            "os.write(fd, ('\\n' + more).encode()) if more else None")
    p = subprocess.Popen([sys.executable, "-c", code, str(claim), words],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline() == "held\n"
    return p


def test_a_retry_waits_for_an_attempt_in_another_process_bounded(
        clips, quick_model, tmp_path, monkeypatch):
    """The first attempt in another worker process (its claim names the run and the job):
    waited for; once it ends having written the output, taken; once killed without having
    written it, the job is done again, the row saying so; held past the wait
    (:data:`RETRY_WAIT`), the row fails saying that attempt still holds it."""
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    claim, calls = O.claim_path(out), []
    monkeypatch.setattr(J, "_track", lambda *a, **k: calls.append(1) or still_track(
        quick_model, 8, source=str(video)))
    words = f"pid 4242 on host render-7, since 20:00\njob {OWNER}"
    # 1. it writes the output, says so and ends
    p, rows, waiting = _holder(claim, words), [], _waiting(monkeypatch)
    try:
        t = _attempt(job, out, quick_model, rows, owner=OWNER)
        while not waiting.is_set() and t.is_alive():
            t.join(0.01)
        assert t.is_alive() and not rows
        still_track(quick_model, 5, source=str(video)).save(out)
        p.stdin.write(f"done {O.output_identity(out)}\n")
        p.stdin.flush()
        t.join(30)
    finally:
        p.kill()
        p.wait()
    assert rows[0].status == "done" and rows[0].frames == 5 and not calls
    assert "(pid 4242 on host render-7, since 20:00; Dask ran it again" in rows[0].note
    # 2. killed before writing (a worker's nanny ends it): done again, planned the file there
    planned = O.output_identity(out)
    p, rows = _holder(claim, words), []
    waiting.clear()
    t = _attempt(job, out, quick_model, rows, owner=OWNER, planned=planned)
    while not waiting.is_set() and t.is_alive():
        t.join(0.01)
    p.kill()
    p.wait()
    t.join(30)
    assert rows[0].status == "done" and rows[0].frames == 8 and len(calls) == 1
    assert "ended without the output: done again after waiting" in rows[0].note
    # 3. held past the wait: said, nothing written
    monkeypatch.setattr(O, "RETRY_WAIT", 0.3)
    kept, p = O.output_identity(out), _holder(claim, words)
    try:
        with pytest.raises(BatchError, match=r"still being written by this run's earlier "
                                             r"attempt of the job \(pid 4242 on host render-7"):
            J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER)
    finally:
        p.kill()
        p.wait()
    assert O.output_identity(out) == kept and len(calls) == 1


def test_a_retry_takes_no_file_its_killed_first_attempt_did_not_write(
        clips, quick_model, tmp_path, monkeypatch):
    """The first attempt was killed after taking its claim but before its checks (its claim
    names this run's job, and no more); a file is there that the run did not find (another
    run's, finished between this run's planning and that claim; or a user's): not that
    attempt's, so not taken: the retry says another run wrote it, and keeps it. Before, any
    file other than the one planned was taken as the attempt's, the row done with this run's
    digest. One that attempt wrote (past its checks, its claim says so) is still taken."""
    video = clips["a"][0]
    job, out = ClipJob("a", str(video)), tmp_path / "a.npz"
    monkeypatch.setattr(J, "_track", lambda *a, **k: still_track(quick_model, 8,
                                                                  source=str(video)))
    words = f"pid 4242 on host render-7, since 20:00\njob {OWNER}"
    still_track(quick_model, 5, source=str(video)).save(out)         # not planned: none then
    theirs = O.output_identity(out)
    O.claim_path(out).write_text(words)
    with pytest.raises(O.OutputTaken, match="written by another run since this run began"):
        J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER)
    assert O.output_identity(out) == theirs
    # an attempt past its checks: what it writes is its own. Its claim's words while it
    # tracks are what a kill then leaves (the output written, the claim not yet "done")
    during = []

    def tracking(*a, **k):
        during.append(O.claim_path(out).read_text())
        return still_track(quick_model, 6, source=str(video))

    out.unlink()
    monkeypatch.setattr(J, "_track", tracking)
    J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER)
    O.claim_path(out).write_text(during[0])
    row = J.track_clip(job, str(out), quick_model, TrackerSettings(), owner=OWNER)
    assert row.frames == 6 and "wrote the output: taken" in row.note and len(during) == 1


def test_a_clip_s_chunks_another_run_is_tracking_are_not_tracked_again(
        quick_model, quick_model_path, inproc, tmp_path, capsys, monkeypatch):
    """Two runs of one ``batch track --chunk`` at once: the clip's chunks are claimed by the
    first run's client until its join ends, so the other run's row of that clip fails at
    once, naming the holder, and tracks none of its chunks; the first run's track is written
    and no claim is left. Before, both tracked every chunk and one join failed."""
    from facetransfer.cli.main import main

    video, pts, _ = clip_with_points(quick_model, 20, 5, tmp_path, video="long.mp4",
                                     points="p.json")
    out = tmp_path / "out"
    argv = [str(a) for a in ("batch", "track", video, "--out", out, "--chunk", 10,
                             "--overlap", 2, "--model", quick_model_path, "--init", pts,
                             "--passes", "1", "--workers", 1, "--no-progress")]
    holding, other_done, codes, calls = threading.Event(), threading.Event(), {}, []
    real = J._track

    def tracked(*a, **k):
        calls.append(threading.current_thread().name)
        if not holding.is_set():         # the first run's first chunk: the other runs
            holding.set()
            assert other_done.wait(300)
        return real(*a, **k)

    monkeypatch.setattr(J, "_track", tracked)
    this = threading.Thread(target=lambda: codes.update(this=main(argv)))
    this.start()
    try:
        assert holding.wait(300)
        n = len(calls)
        codes["other"] = main(argv)
        theirs, other_calls = _summary(out / "summary.csv"), len(calls) - n
    finally:
        other_done.set()
        this.join(300)
    assert codes == {"this": 0, "other": 1}
    assert other_calls == 0
    assert theirs["long"]["status"] == "failed" and theirs["long"]["job"] == "another-run"
    assert theirs["long"]["error"].startswith(
        f"{out / 'long.npz'}: its chunks are being tracked by another run (pid {os.getpid()}")
    rows = _summary(out / "summary.csv")
    assert rows["long"]["status"] == "done" and Track.load(out / "long.npz").n_frames == 20
    assert not list(out.glob(".*.claim"))


#: The chunk claims the client held as each count of a clip's frames ran (:func:`_count`).
_CHUNK_CLAIMS_SEEN: list = []


def _count(video, max_frames=None) -> int:
    """A clip's frames counted (8, one chunk), noting how many chunk claims are held."""
    _CHUNK_CLAIMS_SEEN.append(sum(k.endswith(".chunks.claim") for k in O._HELD))
    return 8


def test_a_chunked_run_holds_a_bounded_number_of_chunk_claims(
        clips, quick_model, tmp_path, monkeypatch):
    """The client claims the chunks of at most ``MAX_CLAIMS`` clips at once (each claim an
    open file), the rest queued and claimed as rows become final; every clip done, no claim
    left. Before, every clip was claimed as the run began: a run of more clips than the
    process may open files ran the rest unclaimed (300 clips under a limit of 200: 136)."""
    from facetransfer.batch import run as R
    from facetransfer.batch.cluster import open_client
    from facetransfer.batch.track_submit import TrackSubmit

    video = clips["a"][0]
    monkeypatch.setattr(TrackSubmit, "MAX_CLAIMS", 2)
    monkeypatch.setattr(J, "count_frames", _count)
    monkeypatch.setattr(J, "_track", lambda *a, **k: still_track(quick_model, 8,
                                                                  source=str(video)))
    monkeypatch.setattr(sys.modules[__name__], "_CHUNK_CLAIMS_SEEN", [])
    jobs = [ClipJob(f"c{i}", str(video)) for i in range(5)]
    with open_client(workers=1, processes=False) as client:
        res = R.batch_track(jobs, tmp_path / "out", quick_model, client=client, chunk=10,
                            overlap=2)
    assert [r.status for r in res.rows] == ["done"] * 5, res.rows
    assert len(_CHUNK_CLAIMS_SEEN) == 5 and max(_CHUNK_CLAIMS_SEEN) <= 2, _CHUNK_CLAIMS_SEEN
    assert not list((tmp_path / "out").glob(".*.claim"))


@pytest.mark.filterwarnings("ignore:Port 8787 is already in use")
def test_the_embedded_cluster_keeps_the_model_on_every_worker():
    """The model is scattered to every worker; Dask's active memory manager dropped the
    copies no task waited for (every 2 s), leaving one: that worker lost (its heartbeat
    missed), every clip left was cancelled, "its worker died, more than once", none run
    again. The embedded cluster runs without it."""
    from facetransfer.batch.cluster import open_client, scatter_model

    with open_client(workers=2, processes=False) as client:
        amm = client.run_on_scheduler(lambda dask_scheduler: dask_scheduler.extensions[
            "amm"].running)
        fut = scatter_model(client, bytes(1000))
        assert not amm and len(client.who_has([fut])[fut.key]) == 2


def test_a_pair_s_retry_after_its_first_attempt_died_between_the_matte_and_the_result(
        clips, tmp_path, monkeypatch):
    """The first attempt of a pair with a matte was killed between the matte's commit and the
    result's (the matte is committed first): its claim names this run's job, its frames are
    there beside no result. The retry renders the pair again, those frames removed as its
    own. Before, it failed, "the frames ... were written by another run", its own attempt's.
    Another run's claim left there (another owner), or this run's attempt's killed before its
    checks, still keeps such frames."""
    from facetransfer import video_transfer

    import test_batch_race

    job = PairJob("p", clips["a"][0], {"expression_from": str(clips["b"][0])})
    out, matte = tmp_path / "p.mp4", J.matte_pattern(tmp_path, "p", ".png")
    frame = Path(matte).parent / "p.00000.png"
    render = test_batch_race._Render()
    monkeypatch.setattr(video_transfer, "transfer_video", render)
    settings = dict(test_batch_race.SETTINGS)
    for owner, ours in ((f"run0002 {OWNER.split()[1]}", False), (OWNER, False),
                        (OWNER, True)):
        frame.parent.mkdir(exist_ok=True)
        frame.write_bytes(b"the first attempt's")     # planned: none there (planned_matte "")
        # this run's attempt wrote them only past its checks (killed before: not its)
        O.claim_path(out).write_text(f"pid 4242 on host render-7, since 20:00\njob {owner}"
                                     + ("\nchecked" if ours else ""))
        if not ours:
            with pytest.raises(O.OutputTaken, match="frames .* written by another run"):
                J.transfer_pair(job, str(out), None, dict(settings), str(matte), owner=OWNER)
            assert frame.exists() and not out.exists()
            continue
        row = J.transfer_pair(job, str(out), None, dict(settings), str(matte), owner=OWNER)
        assert row.status == "done" and out.read_bytes() == b"mine" and not frame.exists()
        assert "ended without the output: done again" in row.note and render.seen == [False]

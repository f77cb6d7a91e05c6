"""The model of a batch run on the workers (:mod:`facetransfer.batch.model_ref`): its file's
path and hash in each task, each worker loading it once; a worker lost on a scheduler whose
active memory manager is on (Dask's default, a user's own scheduler) loses nothing the other
clips need."""

from __future__ import annotations

import dataclasses
import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer.batch import model_ref as MR  # noqa: E402
from facetransfer.batch.manifest import BatchError  # noqa: E402

import test_batch  # noqa: E402

clips = test_batch.clips

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_a_model_of_a_file_is_sent_as_its_path_and_loaded_once_per_worker(
        quick_model, tmp_path, monkeypatch):
    from facetransfer.model import load_model, model_file

    p = quick_model.save(tmp_path / "m.npz")
    model = load_model(p)
    ref = MR.model_ref(model)
    assert ref == MR.ModelRef(str(p.absolute()), model.content_hash, False)
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    loads = []
    real = MR._load
    monkeypatch.setattr(MR, "_load", lambda r: loads.append(r) or real(r))
    first = MR.worker_model(ref)
    assert MR.worker_model(ref) is first and len(loads) == 1
    assert first.content_hash == model.content_hash
    assert MR.worker_model(model) is model and MR.worker_model(None) is None
    # built in memory: no file to load it from (the run scatters it)
    from facetransfer.model import MultilinearModel

    fresh = MultilinearModel(core=model.core, factors=model.factors,
                             mode_names=model.mode_names, labels=model.labels, faces=model.faces)
    assert model_file(fresh) is None and MR.model_ref(fresh) is None


def test_a_model_file_replaced_since_or_not_there_is_said_naming_it(quick_model, tmp_path,
                                                                     monkeypatch):
    from facetransfer.model import load_model, model_file

    p = quick_model.save(tmp_path / "m.npz")
    ref = MR.model_ref(load_model(p))
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    other = load_model(p)
    dataclasses.replace(other, provenance={"note": "another"}).save(p)  # another model there
    assert model_file(other) is None      # not the file it was loaded from any more
    with pytest.raises(BatchError, match=r"m\.npz holds another model now \(sha256 "):
        MR.worker_model(ref)
    p.unlink()
    with pytest.raises(BatchError, match=rf"the run's model {p} cannot be loaded on the worker "
                                         r"on .*m\.npz is not there \(every worker must see"):
        MR.worker_model(ref)


def test_a_model_file_the_workers_do_not_see_is_sent_to_them_saying_so(
        clips, quick_model_path, tmp_path, monkeypatch, caplog):
    """Workers on machines without the client's file (its user cache not shared, no
    ``--model`` on the shared file system): the model is scattered to them, as before, with a
    warning naming the hosts and the file, not every clip failed "cannot be loaded"."""
    from facetransfer.model import load_model

    model = load_model(quick_model_path)
    elsewhere = MR.ModelRef(str(tmp_path / "not-here" / "m.npz"), model.content_hash)
    monkeypatch.setattr(MR, "model_ref", lambda m: elsewhere)
    _sent_to_a_worker_without_the_file(clips, model, elsewhere, tmp_path, caplog)


def _sent_to_a_worker_without_the_file(clips, model, elsewhere, tmp_path, caplog) -> None:
    """Clip "a" tracked by one in-process worker that does not see ``elsewhere``'s file: done,
    the model sent to it with the warning naming that file."""
    from facetransfer.batch import batch_track, open_client, run
    from facetransfer.batch.manifest import ClipJob

    (va, pa, _) = clips["a"]
    with open_client(workers=1, processes=False) as client:
        res = batch_track([ClipJob("a", str(va), init=str(pa))], tmp_path / "out", model,
                          client=client)
    assert [(r.status, r.error) for r in res.rows] == [("done", "")]
    said = [r.getMessage() for r in caplog.records if r.name == run.__name__]
    assert said and f"do not see the model file {elsewhere.path}: it is sent" in said[0]


def _block_clip(name: str, folder: str) -> None:
    """Run on each worker: the tracking of the clip ``name`` waits, once it has begun (a file
    ``started-PID`` in ``folder``), for ``folder/go``; a worker started again runs as usual."""
    from facetransfer.batch import jobs

    real = jobs._track

    def _track(video, *args, **kw):
        if os.path.basename(str(video)).startswith(name + "."):
            open(os.path.join(folder, f"started-{os.getpid()}"), "w").close()
            while not os.path.exists(os.path.join(folder, "go")):
                time.sleep(0.05)
        return real(video, *args, **kw)

    jobs._track = _track


def _wait(what, seconds: float = 120.0):
    """``what()`` once true (polled), else the test fails naming it."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        got = what()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"not seen within {seconds:g} s: {what.__doc__}")


def test_a_worker_lost_under_the_active_memory_manager_loses_no_clip(clips, quick_model_path,
                                                                     tmp_path):
    """A real cluster (worker processes with nannies) whose scheduler runs Dask's active memory
    manager (ReduceReplicas), as a user's own ``dask scheduler`` does by default; a worker is
    killed (SIGKILL) while it tracks the last clip left. Before, the model was scattered, the
    manager had left its one copy on that worker, and the clip was cancelled with it ("its
    worker died, more than once"); now it is tracked again on the other worker."""
    import dask
    from dask.distributed import Client, LocalCluster

    from facetransfer.batch import batch_track
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.model import load_model

    (va, pa, _), (vb, pb, _) = clips["a"], clips["b"]
    gate = tmp_path / "gate"
    gate.mkdir()
    out = tmp_path / "out"
    model = load_model(quick_model_path)       # as the CLI loads it
    amm = {"distributed.scheduler.active-memory-manager.start": True,
           "distributed.scheduler.active-memory-manager.interval": "100ms",
           "distributed.scheduler.active-memory-manager.policies": [
               {"class": "distributed.active_memory_manager.ReduceReplicas"}]}
    with dask.config.set(amm), \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                         dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        assert client.run_on_scheduler(
            lambda dask_scheduler: dask_scheduler.extensions["amm"].running)
        client.run(_block_clip, "a", str(gate))
        done, killed = [], []

        def kill_a_s_worker():
            def b_done_a_begun():
                """clip b done, clip a's tracking begun"""
                return done and list(gate.glob("started-*"))
            try:
                started = _wait(b_done_a_begun)

                def model_on_one_worker():
                    """the scattered model (if any) on one worker, the manager's doing"""
                    held = [len(w) for k, w in client.who_has().items()
                            if str(k).startswith("MultilinearModel")]
                    return held == [] or held == [1]
                _wait(model_on_one_worker)
                os.kill(int(started[0].name.split("-")[1]), signal.SIGKILL)
                killed.append(started[0].name)
            finally:
                (gate / "go").touch()

        th = threading.Thread(target=kill_a_s_worker)
        th.start()
        jobs = [ClipJob("b", str(vb), init=str(pb)), ClipJob("a", str(va), init=str(pa))]
        res = batch_track(jobs, out, model, client=client,
                          progress=lambda row: done.append(row.clip))
        th.join()
    assert killed
    rows = {r.clip: r for r in res.rows}
    assert {n: (r.status, r.error) for n, r in rows.items()} == {"a": ("done", ""),
                                                                  "b": ("done", "")}
    assert (out / "a.npz").is_file() and (out / "b.npz").is_file()
    assert not list(out.glob(".*.claim"))


def test_a_model_file_written_over_in_place_after_a_worker_loaded_it_is_checked_again(
        quick_model, tmp_path, monkeypatch):
    """A worker keeps the models it loaded (their cores mapped, not read): a file written over
    in place since (a ``cp`` of another build onto it, the same inode) made its later tasks,
    this run's and a later run's with that hash, read the new bytes as the run's model,
    silently (review53b: the default model's core read other values); now the file is loaded
    and checked again, and refused naming it. A file replaced by a rename (as ``save``
    writes) leaves the mapped one as it was: the loaded model is kept."""
    from facetransfer.model import load_model

    p = quick_model.save(tmp_path / "m.npz")
    other = dataclasses.replace(load_model(p), provenance={"note": "another"}).save(
        tmp_path / "other.npz")
    ref = MR.model_ref(load_model(p))
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    first = MR.worker_model(ref)
    inode, mtime = p.stat().st_ino, p.stat().st_mtime_ns
    with open(p, "r+b") as fh:                       # cp other.npz m.npz: in place
        fh.write(other.read_bytes())
        fh.truncate()
    os.utime(p, ns=(mtime + 10 ** 9, mtime + 10 ** 9))
    assert p.stat().st_ino == inode
    with pytest.raises(BatchError, match=r"m\.npz holds another model now \(sha256 .*"
                                         r"replaced since the run began\?$"):
        MR.worker_model(ref)

    q = quick_model.save(tmp_path / "n.npz")
    ref = MR.model_ref(load_model(q))
    first = MR.worker_model(ref)
    dataclasses.replace(load_model(q), provenance={"note": "another"}).save(q)  # a rename
    assert MR.worker_model(ref) is first


def test_the_workers_drop_the_model_as_the_run_ends(clips, quick_model_path, tmp_path,
                                                      monkeypatch):
    """A user's long-lived cluster keeps nothing of a run that is over: each worker kept the
    run's model (its mapped core's pages counted in its memory, 126 MB of an idle worker
    after a 30-frame track of the default model) until two other models were used
    (review53b); now the run's end asks them to drop it. Threads in this process: the
    workers' kept models are this module's."""
    from facetransfer.batch import batch_track, open_client
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.model import load_model

    model = load_model(quick_model_path)
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    loads = []
    real = MR._load
    monkeypatch.setattr(MR, "_load", lambda r: loads.append(r) or real(r))
    (va, pa, _) = clips["a"]
    with open_client(workers=1, processes=False) as client:
        res = batch_track([ClipJob("a", str(va), init=str(pa))], tmp_path / "out", model,
                          client=client)
    assert [(r.status, r.error) for r in res.rows] == [("done", "")]
    assert [r.content_hash for r in loads] == [model.content_hash]   # it was loaded
    assert model.content_hash not in MR._LOADED                     # and is no longer kept


def test_a_worker_whose_own_default_model_is_another_build_is_sent_the_model(
        clips, quick_model_path, tmp_path, monkeypatch, caplog):
    """The default model where a worker does not see the client's user cache: the worker's own
    default model is another build (another version's, or the recipe's bits on another
    machine). It was taken as seen: the model was not sent, and the worker's every clip failed,
    "holds another model now ... replaced since the run began?" (review53b); now the model is
    sent to it, with the warning, as to a worker with no file."""
    from facetransfer import default_model
    from facetransfer.model import load_model

    model = load_model(quick_model_path)
    (tmp_path / "cache").mkdir()
    own = dataclasses.replace(model, provenance={"note": "another build"}).save(
        tmp_path / "cache" / "default.npz")
    monkeypatch.setattr(default_model, "default_model_path", lambda: own)
    elsewhere = MR.ModelRef(str(tmp_path / "client-cache" / "default.npz"), model.content_hash,
                            default=True)
    monkeypatch.setattr(MR, "model_ref", lambda m: elsewhere)
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    _sent_to_a_worker_without_the_file(clips, model, elsewhere, tmp_path, caplog)
    # a worker that joins later, its own default another build, says whose model it is
    with pytest.raises(BatchError, match=r"default\.npz holds another model now .*: this "
                                         r"machine's own default model, another build"):
        MR.worker_model(elsewhere)


def test_a_model_file_only_touched_or_copied_again_is_still_sent_as_its_path(
        clips, quick_model, tmp_path, monkeypatch):
    """A model file whose modification time changed after the run loaded it, its content the
    same (touched: a backup tool, ``touch``; or the same model copied onto it again) was taken
    for another file: the model was sent whole to every worker (``client.scatter``: the
    default model's 0.45 GB pickled to each, lost with a worker under the active memory
    manager), in silence. The file is now judged by its content: the workers get its path and
    load it; a file written over with another model is still not taken for the run's."""
    from facetransfer.batch import batch_track, cluster, open_client
    from facetransfer.batch.manifest import ClipJob
    from facetransfer.model import load_model

    p = quick_model.save(tmp_path / "m.npz")
    model = load_model(p)
    ref = MR.ModelRef(str(p.absolute()), model.content_hash, False)
    st = p.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10 ** 9))      # touched
    assert MR.model_ref(model) == ref
    sent = []
    monkeypatch.setattr(cluster, "scatter_model", lambda c, m: sent.append(m))
    monkeypatch.setattr(MR, "_LOADED", type(MR._LOADED)())
    (va, pa, _) = clips["a"]
    with open_client(workers=1, processes=False) as client:
        res = batch_track([ClipJob("a", str(va), init=str(pa))], tmp_path / "out", model,
                          client=client)
    assert [(r.status, r.error) for r in res.rows] == [("done", "")] and sent == []

    same = p.read_bytes()
    other = dataclasses.replace(model, provenance={"note": "another"}).save(
        tmp_path / "other.npz").read_bytes()
    for data, want in ((same, ref), (other, None)):                  # cp X m.npz: in place
        with open(p, "r+b") as fh:
            fh.write(data)
            fh.truncate()
        st = p.stat()
        os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10 ** 9))
        assert MR.model_ref(model) == want

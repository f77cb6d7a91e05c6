"""A batch job's claim of its output (:func:`facetransfer.batch.ownership.claimed`) against the
moments other runs look at it: another run's planning checking the claim files there
(:func:`~facetransfer.batch.ownership.remove_stale_claims`), locks that are the process's (as
``flock`` is over NFS), a claim file replaced under its holder."""

from __future__ import annotations

import fcntl
import os

import pytest

from facetransfer.batch import ownership as O


def test_a_claim_another_run_s_planning_is_checking_is_taken_once_it_has_looked(
        tmp_path, monkeypatch):
    """Another run's planning locks each claim file there for a moment to see whether a
    process holds it (:func:`remove_stale_claims`); a job making its claim in that moment
    found it held and failed, "being written by another run", though no run was writing it.
    The job now tries again for a moment before saying so."""
    out = tmp_path / "a.npz"
    real, looked = O._open_claim, []

    def opened(path, create=True):
        if looked:              # the job tries again: the other run has looked by then
            os.close(looked.pop())
            looked.append(None)
        fd = real(path, create)
        if create and not looked:     # the other run's check locks it as the job opens it
            other = os.open(path, os.O_RDWR)
            fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
            looked.append(other)
        return fd

    monkeypatch.setattr(O, "_open_claim", opened)
    with O.claimed(out):
        assert "pid " in O.claim_path(out).read_text()
    assert looked == [None] and not O.claim_path(out).exists()


def test_a_claim_another_run_holds_is_still_refused(tmp_path):
    """The moment's wait does not let a job take a claim another process holds."""
    out = tmp_path / "a.npz"
    fd = os.open(O.claim_path(out), os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        os.write(fd, b"pid 4242 on host render-7, since 20:00")
        with pytest.raises(O.OutputTaken, match=r"another run \(pid 4242 on host render-7"):
            with O.claimed(out):
                pass
    finally:
        os.close(fd)


def test_a_claim_is_this_process_s_own_where_locks_are_the_process_s(tmp_path, monkeypatch):
    """Over NFS, Linux makes ``flock`` a whole-file POSIX lock, which is the process's, not
    the open file's (here: ``lockf``, the same locks on a local disk): a second job of one
    output in one process (a worker's threads running two runs' jobs; the threads of a
    cluster in the client) took the claim the first held, and its end (or the stopped run's
    :func:`remove_stale_claims` in that process) removed the file and let go of the lock.
    A claim held in this process is now refused, and kept, as one held in another."""
    monkeypatch.setattr(fcntl, "flock", fcntl.lockf)
    out = tmp_path / "a.npz"
    with O.claimed(out):
        said = O.claim_path(out).read_text()
        with pytest.raises(O.OutputTaken, match=r"is being written by another run \(pid "):
            with O.claimed(out):
                pass
        assert O.remove_stale_claims(tmp_path) == []
        assert O.claim_path(out).read_text() == said
    assert not O.claim_path(out).exists()


def test_a_job_s_end_removes_its_own_claim_file_not_one_put_in_its_place(tmp_path):
    """Where locks are each machine's own (an NFS mount with ``local_lock`` or ``nolock``),
    a run on another machine sees a claim held here as unheld, removes it and makes its own;
    the end of the job here then removed that run's claim, held, so a third run took the
    output too. A job's end now removes its claim file only while it is the one it made."""
    out = tmp_path / "a.npz"
    theirs = tmp_path / "theirs"
    with O.claimed(out):
        theirs.write_text("pid 4242 on host render-7, since 20:00")
        os.replace(theirs, O.claim_path(out))
    assert O.claim_path(out).read_text() == "pid 4242 on host render-7, since 20:00"


def test_where_the_file_system_refuses_locks_a_job_leaves_no_claim_file(tmp_path, monkeypatch):
    """A file system that refuses locks (``ENOLCK``): the job runs unclaimed, as said, but
    left behind the empty claim file it had made to lock, one a job, which no run removes
    (:func:`remove_stale_claims` cannot lock it either). It now removes it."""
    import errno

    def refused(fd, how):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", refused)
    out = tmp_path / "a.npz"
    with O.claimed(out):
        out.write_bytes(b"the job's output")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]


def test_a_file_another_run_wrote_is_said_to_be_replaced_by_a_run_again_with_overwrite(
        tmp_path):
    """Since the fiftieth session a run with ``--overwrite`` keeps an output another run
    wrote after it began, and its row said "--overwrite replaces it", to one who had given
    it: the row now says a run again with ``--overwrite`` replaces it."""
    out = tmp_path / "a.npz"
    out.write_bytes(b"the output the run found")
    planned = O.output_identity(out)
    (tmp_path / "theirs").write_bytes(b"another run's output, written since")
    os.replace(tmp_path / "theirs", out)
    with pytest.raises(O.OutputTaken) as e:
        O.still_planned(out, planned)
    assert str(e.value).endswith("this run's result not written; run again with --overwrite "
                                 "to replace it"), str(e.value)


_FORKS_AND_WAITS = """
import os, sys, time
from facetransfer.batch import ownership as O
with O.claimed(sys.argv[1]):
    if os.fork() == 0:          # the tracker's detector, forked while the job holds its claim
        time.sleep(60)
        os._exit(0)
    print("forked", flush=True)
    time.sleep(60)
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="forks")
def test_a_claim_ends_with_its_job_s_process_not_with_a_child_it_forked(tmp_path):
    """A job's process forks while it holds its claim (the tracker's detector of a clip's
    second part; a render's processes): the child had the claim's descriptor, so where the
    job's process was killed (SIGKILL, the OOM killer) the claim stayed held while the child
    went on, and the next run's job said the output was being written by a run that was
    gone. The child now lets go of it at its start."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "a.npz"
    job = subprocess.Popen([sys.executable, "-c", _FORKS_AND_WAITS, str(out)],
                           stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert job.stdout.readline() == "forked\n"
        job.kill()
        job.wait()
        with O.claimed(out):      # the child still runs
            assert "pid " in O.claim_path(out).read_text()
    finally:
        try:
            os.killpg(job.pid, signal.SIGKILL)     # the child
        except ProcessLookupError:
            pass
        job.wait()

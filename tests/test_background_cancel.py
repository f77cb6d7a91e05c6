"""A forked background track stopped by its parent (track.obtain._BackgroundTrack.cancel), and
the second detection process (track.video_detect.SplitDetection.cancel), are gone even where
they could not take a SIGTERM: one that reaches the child in the fork's first
instants, before its default handler is back (cli.main._default_sigterm_in_child), is lost,
and the child then tracked the whole clip and waited for ever to hand its track to a parent
that had left."""

import contextlib
import multiprocessing
import os
import signal
import time
from pathlib import Path

import pytest

from facetransfer.track import obtain, video_detect

pytestmark = pytest.mark.skipif(
    "fork" not in multiprocessing.get_all_start_methods() or not Path("/proc/self").exists(),
    reason="needs fork and /proc")

_READY = "FACETRANSFER_TEST_CHILD_READY"


def _deaf_job():
    """A background job that cannot take a SIGTERM (as in the fork's first instants)."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    Path(os.environ[_READY]).write_text(str(os.getpid()))
    time.sleep(60)


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead and not yet reaped, does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _wait(what, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if what():
            return True
        time.sleep(0.05)
    return what()


@contextlib.contextmanager
def _forked(ready: Path):
    """The pid of the forked job once it has written it to ``ready``; on leaving, the job
    killed if it still runs (a failed test leaves no child)."""
    try:
        assert _wait(ready.exists, 30), "the forked job did not start"
        yield int(ready.read_text())
    finally:
        if ready.exists() and _alive(int(ready.read_text())):
            os.kill(int(ready.read_text()), signal.SIGKILL)


def _background(tmp_path, monkeypatch, job):
    """``(ready, bg)``: a background track started with ``job`` in the tracker's place, which
    writes its pid to ``ready`` (:func:`_forked`)."""
    ready = tmp_path / "ready"
    monkeypatch.setenv(_READY, str(ready))
    monkeypatch.setattr(obtain, "_background_track_job", job)
    bg = obtain.start_background_track("v.mp4", object(), 10, method="auto", options=None,
                                       parallel=True)
    assert bg is not None
    return ready, bg


def test_a_cancelled_child_that_missed_its_sigterm_is_stopped(tmp_path, monkeypatch):
    ready, bg = _background(tmp_path, monkeypatch, _deaf_job)
    with _forked(ready) as pid:
        bg.cancel()
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"


def test_a_cancelled_second_detection_that_missed_its_sigterm_is_stopped(tmp_path,
                                                                         monkeypatch):
    ready = tmp_path / "ready"
    monkeypatch.setenv(_READY, str(ready))
    monkeypatch.setattr(video_detect, "_child_job", _deaf_job)
    split = video_detect.SplitDetection.start("v.mp4", 5, 10, 25.0)
    assert split is not None
    with _forked(ready) as pid:
        split.cancel()
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"


def _saving_job():
    """A background job that, on a Ctrl-C, saves its progress (a moment's work) as the
    tracker's checkpoint does."""
    Path(os.environ[_READY]).write_text(str(os.getpid()))
    try:
        time.sleep(60)
    except KeyboardInterrupt:
        time.sleep(0.3)
        Path(os.environ[_READY] + ".saved").write_text("saved")
        raise


def test_a_child_that_got_the_ctrl_c_too_saves_its_progress_before_it_is_killed(
        tmp_path, monkeypatch):
    """A Ctrl-C reaches the background tracker too, which saves its progress; its parent,
    interrupted as well, killed it at once, mid-save: its progress was lost and its temporary
    file left in the user cache (1 of 7 Ctrl-Cs while tracking). Cancelled for a Ctrl-C
    (:func:`facetransfer.track.obtain.grace_for`), a running child is given a moment to end."""
    ready, bg = _background(tmp_path, monkeypatch, _saving_job)
    with _forked(ready) as pid:
        os.kill(pid, signal.SIGINT)                  # the terminal's Ctrl-C, in the child
        bg.cancel(grace=obtain.grace_for(KeyboardInterrupt()))
        assert Path(str(ready) + ".saved").exists()
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"
        assert obtain.grace_for(KeyboardInterrupt()) > 0
        assert obtain.grace_for(ValueError()) == 0     # not interrupted: nothing to save


def test_a_ctrl_c_to_the_parent_alone_reaches_the_child_which_saves_its_progress(
        tmp_path, monkeypatch):
    """A SIGINT sent to the parent alone (``kill -INT PID``, a job runner's stop) reached no
    child: the parent waited out the grace while the child tracked on, then killed it, its
    progress lost. The parent now hands its child the interrupt, which saves and ends."""
    ready, bg = _background(tmp_path, monkeypatch, _saving_job)
    with _forked(ready) as pid:
        bg.cancel(grace=obtain.grace_for(KeyboardInterrupt()))     # the child got nothing
        assert Path(str(ready) + ".saved").exists(), "the child's progress was not saved"
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"


def _slow_saving_job():
    """:func:`_saving_job` whose save says when it begins, and takes a while."""
    Path(os.environ[_READY]).write_text(str(os.getpid()))
    try:
        time.sleep(60)
    except KeyboardInterrupt:
        Path(os.environ[_READY] + ".saving").write_text("saving")
        time.sleep(1.0)
        Path(os.environ[_READY] + ".saved").write_text("saved")
        raise


def test_a_child_saving_on_the_terminals_ctrl_c_is_not_cut_short_by_its_parents(
        tmp_path, monkeypatch):
    """The terminal's Ctrl-C reaches the child too; the one its parent then sends it (as for a
    Ctrl-C to the parent alone) must not raise inside its save (the child takes one)."""
    ready, bg = _background(tmp_path, monkeypatch, _slow_saving_job)
    with _forked(ready) as pid:
        os.kill(pid, signal.SIGINT)                  # the terminal's Ctrl-C, in the child
        assert _wait(Path(str(ready) + ".saving").exists, 10)
        bg.cancel(grace=obtain.grace_for(KeyboardInterrupt()))     # sends it another
        assert Path(str(ready) + ".saved").exists(), "the child's save was cut short"
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"


@contextlib.contextmanager
def _once_handler():
    """A child's one-Ctrl-C handler (signals._InterruptOnce) set in this process for the
    block."""
    from facetransfer import signals

    handler = signals._InterruptOnce(signal.getsignal(signal.SIGINT))
    before = signal.signal(signal.SIGINT, handler)
    try:
        yield handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_childs_ctrl_c_before_its_job_is_raised_as_the_job_begins_and_taken_once():
    from facetransfer.signals import interrupted_once

    with _once_handler():
        os.kill(os.getpid(), signal.SIGINT)          # before the job: noted, nothing raised
        time.sleep(0.01)
        with pytest.raises(KeyboardInterrupt):
            with interrupted_once():
                raise AssertionError("the job ran after its Ctrl-C")
    saved = []
    with _once_handler():
        with pytest.raises(KeyboardInterrupt):
            with interrupted_once():
                try:
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(1)
                except KeyboardInterrupt:
                    os.kill(os.getpid(), signal.SIGINT)  # a second one: ignored in the save
                    time.sleep(0.05)
                    saved.append(True)
                    raise
        os.kill(os.getpid(), signal.SIGINT)          # after the job: ignored
        time.sleep(0.01)
    assert saved == [True]


def test_a_childs_ctrl_c_that_python_ignored_is_taken_again(monkeypatch):
    """An interrupt raised where Python drops it (a weak reference's callback) is sent again
    (signals.send_later): the child's one Ctrl-C must be taken then, not ignored."""
    from facetransfer.signals import interrupted_once, send_later

    with _once_handler() as handler:
        with pytest.raises(KeyboardInterrupt):
            with interrupted_once():
                with contextlib.suppress(KeyboardInterrupt):     # dropped, as in a callback
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(1)
                assert handler.state == "stopping"
                send_later(signal.SIGINT)
                time.sleep(2)


def test_a_cancelled_childs_pool_has_closed_its_pipes_when_cancel_returns(tmp_path, monkeypatch):
    """At the interpreter's exit Python 3.11 wakes every pool's manager thread through a pipe
    that thread closes as it ends: a manager still ending then ("Exception ignored ... Bad
    file descriptor") put a traceback after an interrupted command's one line. Cancelled, the
    pool's manager thread has ended."""
    ready, bg = _background(tmp_path, monkeypatch, _saving_job)
    with _forked(ready):
        manager = bg._pool._executor_manager_thread
        bg.cancel(grace=obtain.grace_for(KeyboardInterrupt()))
        assert not manager.is_alive()


def test_a_child_whose_parent_was_killed_outright_ends(tmp_path):
    """A parent killed outright (``kill -9``, the out-of-memory killer) left its background
    tracker running to the end, then waiting for ever to hand its result to no one (its own
    copy of the result pipe kept the pipe open): it ends with its parent."""
    import subprocess
    import sys
    import textwrap

    ready = tmp_path / "ready"
    code = textwrap.dedent("""
        import os, signal, time
        from pathlib import Path
        from facetransfer.track import obtain

        def job():
            Path(os.environ["READY"]).write_text(str(os.getpid()))
            time.sleep(60)

        obtain._background_track_job = job
        bg = obtain.start_background_track("v.mp4", object(), 10, method="auto",
                                           options=None, parallel=True)
        while not Path(os.environ["READY"]).exists():
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    src = str(Path(__file__).resolve().parents[1] / "src")
    # no pipes: an orphaned child holding them would keep run() waiting
    r = subprocess.run([sys.executable, "-c", code], timeout=120, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL,
                       env={**os.environ, "PYTHONPATH": src, "READY": str(ready)})
    assert r.returncode == -signal.SIGKILL
    with _forked(ready) as pid:
        assert _wait(lambda: not _alive(pid), 10), "the orphaned child still runs"


def _deaf_to_ctrl_c_job():
    """A background job that does not stop on a Ctrl-C (one stuck in a compiled kernel)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    Path(os.environ[_READY]).write_text(str(os.getpid()))
    time.sleep(60)


def test_a_second_ctrl_c_in_the_parent_kills_the_child_at_once(tmp_path, monkeypatch):
    """The child takes one Ctrl-C only; a user who presses it again because the first seemed
    slow must still get out: the parent's second interrupt, while it gives the child its
    grace, ends the wait and kills the child (not the grace's end)."""
    import concurrent.futures

    ready, bg = _background(tmp_path, monkeypatch, _deaf_to_ctrl_c_job)
    waited = []

    def second_ctrl_c(futures, timeout=None):
        waited.append(timeout)
        raise KeyboardInterrupt                   # pressed again during the grace

    with _forked(ready) as pid:
        monkeypatch.setattr(concurrent.futures, "wait", second_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            bg.cancel(grace=600.0)                 # the first Ctrl-C's; the child is deaf
        assert waited == [600.0]
        assert _wait(lambda: not _alive(pid), 10), "the child outlived the second Ctrl-C"


def test_a_second_ctrl_c_before_the_kill_began_still_kills_the_child(tmp_path, monkeypatch):
    """A second interrupt raised as the cancel began (before ``kill_forked``'s own ``try``)
    left the child running: ``result()``'s pool shutdown, and the exit, then waited for its
    whole track. The cancel kills it all the same."""
    from facetransfer import signals

    ready, bg = _background(tmp_path, monkeypatch, _deaf_to_ctrl_c_job)
    real, calls = signals.kill_forked, []

    def interrupted_at_its_start(pool, future, **kw):
        calls.append(kw)
        if len(calls) == 1:
            raise KeyboardInterrupt                # landed before anything was done
        return real(pool, future, **kw)

    with _forked(ready) as pid:
        monkeypatch.setattr(signals, "kill_forked", interrupted_at_its_start)
        with pytest.raises(KeyboardInterrupt):
            bg.cancel(grace=600.0)
        assert _wait(lambda: not _alive(pid), 10), "the child outlived the second Ctrl-C"

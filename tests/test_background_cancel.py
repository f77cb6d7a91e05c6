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


def test_a_cancelled_child_that_missed_its_sigterm_is_stopped(tmp_path, monkeypatch):
    ready = tmp_path / "ready"
    monkeypatch.setenv(_READY, str(ready))
    monkeypatch.setattr(obtain, "_background_track_job", _deaf_job)
    bg = obtain.start_background_track("v.mp4", object(), 10, method="auto", options=None,
                                       parallel=True)
    assert bg is not None
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
    ready = tmp_path / "ready"
    monkeypatch.setenv(_READY, str(ready))
    monkeypatch.setattr(obtain, "_background_track_job", _saving_job)
    bg = obtain.start_background_track("v.mp4", object(), 10, method="auto", options=None,
                                       parallel=True)
    assert bg is not None
    with _forked(ready) as pid:
        os.kill(pid, signal.SIGINT)                  # the terminal's Ctrl-C, in the child
        bg.cancel(grace=obtain.grace_for(KeyboardInterrupt()))
        assert Path(str(ready) + ".saved").exists()
        assert _wait(lambda: not _alive(pid), 10), "the cancelled child still runs"
        assert obtain.grace_for(KeyboardInterrupt()) > 0
        assert obtain.grace_for(ValueError()) == 0     # not interrupted: nothing to save

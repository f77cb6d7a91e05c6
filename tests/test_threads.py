"""Tests of :mod:`facetransfer.threads`: work done ahead on a thread of its own."""

from __future__ import annotations

import threading

import pytest

from facetransfer.threads import Ahead


def test_ahead_gives_its_value_once_done_and_runs_beside_the_caller():
    gate = threading.Event()
    ahead = Ahead(lambda x: gate.wait(10) and 2 * x, 21, name="ahead-test")
    running = [t for t in threading.enumerate() if t.name == "ahead-test"]
    assert not ahead.done() and len(running) == 1 and running[0].daemon
    gate.set()
    assert ahead.result() == 42 and ahead.done()
    assert ahead.result() == 42      # asked again: the same value, nothing run again


def test_ahead_raises_the_error_of_its_work_where_the_result_is_asked():
    ahead = Ahead(lambda: [][1])
    with pytest.raises(IndexError):
        ahead.result()
    assert ahead.done()


def _interrupted_meanwhile(release: threading.Event | None = None) -> threading.Thread:
    """A Ctrl-C to the main thread 0.05 s from now, and ``release`` (if any) set 0.2 s after
    it; the thread sending them (joined by :func:`_sent`)."""
    import signal
    import time

    def later():
        time.sleep(0.05)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
        if release is not None:
            time.sleep(0.2)          # the interrupt is in; the work ends only now
            release.set()

    sender = threading.Thread(target=later, daemon=True)
    sender.start()
    return sender


def _sent(sender: threading.Thread) -> None:
    """``sender`` joined: its Ctrl-C delivered while the test's handler is there (one that
    comes here, the test having failed otherwise, would stop the whole session)."""
    try:
        sender.join()
    except KeyboardInterrupt:
        pass


@pytest.fixture
def ctrl_c():
    """Python's own Ctrl-C handler in the main thread while the test runs."""
    import signal

    if not hasattr(signal, "pthread_kill") or threading.current_thread() is not \
            threading.main_thread():
        pytest.skip("needs a signal sent to the main thread")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_a_wait_cut_short_by_a_ctrl_c_leaves_the_work_seen_running(ctrl_c):
    """An interrupted :meth:`Ahead.wait` leaves :meth:`Ahead.done` false and the next wait
    waiting while the work runs (Python 3.11's interrupted ``Thread.join`` took the thread
    for ended: a caller's wait for the work in its error path returned at once)."""
    release, ended = threading.Event(), []
    ahead = Ahead(lambda: ended.append(release.wait(10)))
    sender = _interrupted_meanwhile()
    try:
        with pytest.raises(KeyboardInterrupt):
            ahead.wait()
        assert not ahead.done() and not ended
        threading.Timer(0.1, release.set).start()     # the work ends while the next wait waits
        ahead.wait()
        assert ahead.done() and ended == [True]
    finally:
        release.set()
        _sent(sender)


def test_wait_out_waits_for_the_work_through_an_interrupt_then_raises_it(ctrl_c):
    """A Ctrl-C while :meth:`Ahead.wait_out` waits is raised once the work has ended (a plain
    wait left it running while the interpreter exited: a thread in native code then aborted
    the process)."""
    release, ended = threading.Event(), []
    ahead = Ahead(lambda: ended.append(release.wait(10)))
    sender = _interrupted_meanwhile(release)
    try:
        with pytest.raises(KeyboardInterrupt):
            ahead.wait_out()
        assert ended == [True] and ahead.done()
    finally:
        release.set()
        _sent(sender)

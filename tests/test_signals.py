"""Ctrl-C and SIGTERM held while this process forks (facetransfer.signals)."""

from __future__ import annotations

import os
import signal

import pytest

from facetransfer.signals import deferred_signals


def test_a_signal_in_the_block_is_raised_on_leaving_it_and_a_child_keeps_the_handlers():
    """A Ctrl-C inside the block (a fork's at-fork hooks, where Python would print "Exception
    ignored" and go on) is noted, then raised by its own handler as the block ends; the
    handlers are the old ones after it, and in a child forked inside it."""
    before = signal.getsignal(signal.SIGINT)
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_signals():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):          # the interpreter runs the handler meanwhile
                pass
            reached.append(True)
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:                   # the child: the parent's own handler again
                os.write(w, b"1" if signal.getsignal(signal.SIGINT) is before else b"0")
                os._exit(0)
            os.waitpid(pid, 0)
            child_ok = os.read(r, 1) == b"1"
    assert reached == [True] and child_ok
    assert signal.getsignal(signal.SIGINT) is before
    with deferred_signals():               # nothing noted: nothing raised
        pass
    assert signal.getsignal(signal.SIGINT) is before


def test_a_child_forked_in_the_block_dies_of_sigterm_and_defers_again():
    """A review: the CLI's SIGTERM handler was put back in a child forked inside the block (the
    CLI's own at-fork reset ran first), so a worker stopped with ``terminate()`` raised
    instead of dying; the child may defer signals itself."""
    def terminated(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, terminated)
    try:
        with deferred_signals():
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:
                ok = signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
                with deferred_signals():
                    ok = ok and callable(signal.getsignal(signal.SIGINT)) and \
                        signal.getsignal(signal.SIGINT) is not signal.default_int_handler
                os.write(w, b"1" if ok else b"0")
                os._exit(0)
            os.waitpid(pid, 0)
            assert os.read(r, 1) == b"1"
        assert signal.getsignal(signal.SIGTERM) is terminated
    finally:
        signal.signal(signal.SIGTERM, old)


def test_an_interrupt_sent_again_reaches_the_main_thread_without_pthread_kill(monkeypatch):
    """Where there is no ``signal.pthread_kill`` (not POSIX: Windows), the interrupt sent again
    (:func:`facetransfer.signals.send_later`) failed in its timer thread (an AttributeError
    printed there) and was lost; it is then handed to the main thread as a signal would be
    (``_thread.interrupt_main``)."""
    import threading
    import time

    from facetransfer import signals

    monkeypatch.delattr(signal, "pthread_kill")
    failed = []
    monkeypatch.setattr(threading, "excepthook", failed.append)
    with pytest.raises(KeyboardInterrupt):
        signals.send_later(signal.SIGINT)
        end = time.monotonic() + 10
        while time.monotonic() < end and not failed:   # a handler runs between bytecodes
            pass
    assert not failed

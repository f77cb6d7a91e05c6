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

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

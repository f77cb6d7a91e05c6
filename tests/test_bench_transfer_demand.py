"""benchmarks/bench_transfer_demand.py: a process tree's demand for cores read from the
scheduler's events (the parsing and the arithmetic; perf itself is not run here)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_transfer_demand as bd  # noqa: E402


def _lines():
    # pid/tid time: event: trace, as `perf script -F pid,tid,time,event,trace` prints them
    return [
        " 10/10 1.000: sched:sched_process_fork: comm=cli pid=10 child_comm=cli child_pid=11",
        " 10/10 1.000: sched:sched_process_fork: comm=cli pid=10 child_comm=cli child_pid=20",
        " 99/99 1.000: sched:sched_process_fork: comm=other pid=99 child_comm=x child_pid=98",
        # 10 runs 1.0-1.5, preempted (R): waits 1.5-1.6, runs 1.6-2.0
        " 0/0 1.000: sched:sched_switch: prev_comm=idle prev_pid=0 prev_prio=120 "
        "prev_state=R ==> next_comm=cli next_pid=10 next_prio=120",
        " 10/10 1.500: sched:sched_switch: prev_comm=cli prev_pid=10 prev_prio=120 "
        "prev_state=R+ ==> next_comm=other next_pid=99 next_prio=120",
        " 99/99 1.600: sched:sched_switch: prev_comm=other prev_pid=99 prev_prio=120 "
        "prev_state=S ==> next_comm=cli next_pid=10 next_prio=120",
        " 10/10 2.000: sched:sched_switch: prev_comm=cli prev_pid=10 prev_prio=120 "
        "prev_state=S ==> next_comm=idle next_pid=0 next_prio=120",
        # thread 11 of process 10 woken at 1.2, runs 1.3-1.8 and sleeps
        " 10/10 1.200: sched:sched_waking: comm=cli pid=11 prio=120 target_cpu=001",
        " 0/0 1.300: sched:sched_switch: prev_comm=idle prev_pid=0 prev_prio=120 "
        "prev_state=R ==> next_comm=cli next_pid=11 next_prio=120",
        " 10/11 1.800: sched:sched_switch: prev_comm=cli prev_pid=11 prev_prio=120 "
        "prev_state=S ==> next_comm=idle next_pid=0 next_prio=120",
        # process 20 (forked) runs 1.4-1.9
        " 0/0 1.400: sched:sched_switch: prev_comm=idle prev_pid=0 prev_prio=120 "
        "prev_state=R ==> next_comm=child next_pid=20 next_prio=120",
        " 20/20 1.900: sched:sched_switch: prev_comm=child prev_pid=20 prev_prio=120 "
        "prev_state=D ==> next_comm=idle next_pid=0 next_prio=120",
    ]


def test_the_tree_holds_the_forked_threads_and_processes_only():
    events, children, group = bd.parse(_lines())
    assert bd.tree(children, 10) == {10, 11, 20}
    assert group[11] == 10 and group[20] == 20


def test_demand_counts_running_and_preempted_threads():
    events, children, group = bd.parse(_lines())
    spans = bd.intervals(events, bd.tree(children, 10))
    t0, demand, running, per = bd.curves(spans, group)
    assert t0 == 1.0
    at = lambda t: int(round((t - t0) / bd.STEP))  # noqa: E731
    # 1.25: 10 running, 11 woken (waiting): demand 2, one running
    assert demand[at(1.25)] == 2 and running[at(1.25)] == 1
    # 1.55: 10 preempted (waiting), 11 and 20 running: demand 3
    assert demand[at(1.55)] == 3 and running[at(1.55)] == 2
    # 1.95: 10 alone
    assert demand[at(1.95)] == 1
    s = bd.summary(demand, running, per, window=0.5)
    assert s["cpu"] == pytest.approx(0.9 + 0.5 + 0.5, abs=0.005)    # 10: 0.5 + 0.4
    assert s["processes"] == {"10": pytest.approx(1.4, abs=0.005),
                              "20": pytest.approx(0.5, abs=0.005)}
    # short of two cores: 1.0-1.2 one thread (0.2), 1.9-2.0 one (0.1); 1.8-1.9 two (10, 20)
    assert s["short"] == pytest.approx(0.3, abs=0.01)
    assert [w["t"] for w in s["windows"]] == [0.0, 0.5, 1.0]
    assert s["windows"][0]["demand"] == pytest.approx(np.mean(np.minimum(
        demand[:500], 2)), abs=1e-3)


def test_the_phases_are_the_windows_before_the_fork_between_the_tracks_and_the_render_and_after():
    n = 1000
    per = {1: np.ones(n), 2: np.zeros(n), 3: np.zeros(n), 4: np.zeros(n)}
    per[2][100:600] = 1        # the forked tracker, 0.5 CPU-s
    per[3][650:950] = 1        # an encoder, 0.3 CPU-s
    per[4][10:20] = 1          # a probe, 0.01 CPU-s: not an encoder
    demand = per[1] + per[2] + per[3] + per[4]
    ph = bd.phases(demand, per, root=1)
    assert ph["start"] == pytest.approx(0.1 - 0.01)   # 0-0.1 s at 1, the probe's 0.01 s at 2
    assert ph["setup"] == pytest.approx(0.05)         # 0.6-0.65 s
    assert ph["end"] == pytest.approx(0.05)           # 0.95-1.0 s
    assert bd.phases(per[1], {1: per[1]}, root=1) == {"start": 0.0, "setup": 0.0, "end": 0.0}

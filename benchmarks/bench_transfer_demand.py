"""Where issue 13's transfer cannot use both cores: its threads' demand, from the scheduler.

``bench_transfer_cores.py`` reads the machine's busy cores, which other work on a shared
machine fills; this reads, from the kernel's scheduler events (``perf sched record``, Linux,
root or ``perf_event_paranoid`` <= 1), how many threads of the command's own process tree
(the CLI, its forked tracker, ffmpeg, ffprobe) were running or waiting to run at each
moment: its *demand*. Where the demand is below 2 the command leaves a core of a two-core
machine idle whatever else runs, so its idle windows show on a loaded machine too (stretched
in time by the load: compare the fractions, not the seconds). A thread waiting to run after
it was preempted counts as demand (``sched_switch``'s ``prev_state`` R), one woken counts
from its wakeup.

    python benchmarks/bench_transfer_demand.py --out out/demand --window 0.25 --rows
    python benchmarks/bench_transfer_demand.py --out out/demand-ab --base-rev main --rounds 4

With ``--base SRC`` or ``--base-rev REV`` the base tree and this one run in turn (the base
first in odd rounds); each run's line gives the core-seconds short in the start, the render's
set-up and the end (:func:`phases`), and the medians close the report. ``--rows``: every
window's row as well.

Writes ``OUT/transfer_demand.json`` (per run: wall, CPU seconds, core-seconds short of two,
and per window the demand and each process's running threads) and
``OUT/transfer_demand.png``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _revision import add_base_options, base_src  # noqa: E402

_SWITCH = re.compile(r"prev_pid=(\d+) prev_prio=\S+ prev_state=(\S+) ==> next_comm=.*? "
                     r"next_pid=(\d+)")
_WAKE = re.compile(r"comm=.*? pid=(\d+) ")
_FORK = re.compile(r"comm=.*? pid=(\d+) child_comm=.*? child_pid=(\d+)")

#: Seconds a bin of the demand curve.
STEP = 0.001


def parse(lines) -> tuple[list, dict, dict]:
    """``(events, children, group)`` of ``perf script -F pid,tid,time,event,trace`` lines:
    ``(t, kind, tid, state)`` with kind ``in``/``out``/``wake``, the tids forked by each tid,
    and each tid's process."""
    events, children, group = [], collections.defaultdict(list), {}
    for line in lines:
        head, _, rest = line.partition(": ")
        parts = head.split()
        if len(parts) < 2 or "/" not in parts[0]:
            continue
        pid, _, tid = parts[0].partition("/")
        group[int(tid)] = int(pid)
        t = float(parts[1])
        name, _, trace = rest.partition(": ")
        if name.endswith("sched_switch") and (m := _SWITCH.search(trace)):
            events += [(t, "out", int(m.group(1)), m.group(2)), (t, "in", int(m.group(3)), "")]
        elif name.endswith(("sched_waking", "sched_wakeup_new")) and (m := _WAKE.search(trace)):
            events.append((t, "wake", int(m.group(1)), ""))
        elif name.endswith("sched_process_fork") and (m := _FORK.search(trace)):
            children[int(m.group(1))].append(int(m.group(2)))
    return events, children, group


def tree(children: dict, root: int) -> set:
    """``root`` and every thread and process forked from it, transitively."""
    seen, todo = set(), [root]
    while todo:
        p = todo.pop()
        if p not in seen:
            seen.add(p)
            todo += children.get(p, [])
    return seen


def intervals(events: list, ours: set) -> list:
    """``(start, end, tid, running)`` of each thread of ``ours``: running from its switch in
    to its switch out; waiting to run from a wakeup, or from a switch out in state R
    (preempted), to its switch in."""
    state, out = {}, []
    for t, kind, tid, st in events:
        if tid not in ours:
            continue
        cur = state.get(tid)
        if kind == "wake":
            if cur is None:
                state[tid] = (t, False)
            continue
        if cur is not None:
            out.append((cur[0], t, tid, cur[1]))
        state[tid] = (t, True) if kind == "in" else ((t, False) if st.startswith("R") else None)
    return out


def curves(spans: list, group: dict) -> tuple[float, np.ndarray, np.ndarray, dict]:
    """``(t0, demand, running, per_process)`` binned by :data:`STEP` from :func:`intervals`."""
    t0, t1 = min(s[0] for s in spans), max(s[1] for s in spans)
    n = int((t1 - t0) / STEP) + 2
    demand, running = np.zeros(n), np.zeros(n)
    per = collections.defaultdict(lambda: np.zeros(n))
    for a, b, tid, run in spans:
        i, j = int((a - t0) / STEP), int((b - t0) / STEP)
        demand[i:j] += 1
        if run:
            running[i:j] += 1
            per[group.get(tid, tid)][i:j] += 1
    return t0, demand, running, dict(per)


def summary(demand: np.ndarray, running: np.ndarray, per: dict, window: float,
            cores: int = 2) -> dict:
    """Wall, CPU and core-seconds short of ``cores`` of a run, and per window the demand
    (capped at ``cores``) and the running threads of the four busiest processes."""
    k = max(1, int(round(window / STEP)))
    capped = np.minimum(demand, cores)
    big = sorted(per, key=lambda p: -per[p].sum())[:4]
    rows = [{"t": round(i * STEP, 3), "demand": round(float(capped[i:i + k].mean()), 3),
             "running": round(float(running[i:i + k].mean()), 3),
             "processes": {str(p): round(float(per[p][i:i + k].mean()), 3) for p in big}}
            for i in range(0, len(demand), k)]
    return {"wall": round(len(demand) * STEP, 3), "cpu": round(float(running.sum() * STEP), 3),
            "short": round(float((cores - capped).sum() * STEP), 3),
            "short_fraction": round(float((cores - capped).mean() / cores), 4),
            "processes": {str(p): round(float(per[p].sum() * STEP), 3) for p in big},
            "windows": rows}


def phases(demand: np.ndarray, per: dict, root: int, cores: int = 2) -> dict:
    """Core-seconds short of ``cores`` in the three windows where the transfer runs one
    thread: ``start``, up to the forked tracker's first run (the busiest process after
    ``root``); ``setup``, from its last run to the first run of the first encoder (the
    processes of 0.2 CPU-s or more besides those two: the parts' ffmpeg); ``end``, after the
    last encoder's last run (the frame counts and the join). Zero where a process is missing."""
    capped = np.minimum(demand, cores)
    short = lambda a, b: round(float((cores - capped[a:b]).sum() * STEP), 3)  # noqa: E731
    cpu = {p: c.sum() * STEP for p, c in per.items() if p != root}
    busy = sorted(cpu, key=lambda p: -cpu[p])
    if not busy:
        return {"start": 0.0, "setup": 0.0, "end": 0.0}
    ran = lambda p: np.flatnonzero(per[p] > 0)  # noqa: E731
    tracker = ran(busy[0])
    enc = [ran(p) for p in busy[1:] if cpu[p] >= 0.2]
    out = {"start": short(0, tracker[0]), "setup": 0.0, "end": 0.0}
    if enc:
        out["setup"] = short(tracker[-1], min(e[0] for e in enc))
        out["end"] = short(max(e[-1] for e in enc), len(capped))
    return out


def run_once(src: Path, folder: Path) -> dict:
    """Issue 13's command (``bench_transfer_e2e_ab.py``'s) with ``src`` first on the path,
    under ``perf sched record``; its :func:`summary` at a 1 ms step (windows added later)."""
    from bench_transfer_e2e_ab import FRAMES, _videos
    from _report import facetransfer_exe

    target, source = _videos()
    data, pidfile = folder / "sched.data", folder / "root.pid"
    cmd = (f"echo $$ > {pidfile}; exec {facetransfer_exe()} transfer --target {target} "
           f"--expression-from {source} --out {folder / 'demand.mp4'} --max-frames {FRAMES} "
           "--overwrite --no-progress")
    env = dict(os.environ, PYTHONPATH=str(src), FACETRANSFER_TRACK_CACHE="off")
    subprocess.run(["perf", "sched", "record", "-o", str(data), "--", "sh", "-c", cmd],
                   check=True, capture_output=True, env=env)
    (folder / "demand.mp4").unlink(missing_ok=True)
    script = subprocess.Popen(["perf", "script", "-i", str(data), "-F",
                               "pid,tid,time,event,trace"], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    events, children, group = parse(script.stdout)
    script.wait()
    data.unlink(missing_ok=True)
    root = int(pidfile.read_text())
    ours = tree(children, root)
    return (*curves(intervals(events, ours), group), root)


def plot(runs: list, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    for i, r in enumerate(runs):
        t = [w["t"] for w in r["windows"]]
        ax.plot(t, [w["demand"] for w in r["windows"]], lw=1,
                label=f"run {i + 1}: {r['short']:.2f} core-s short of 2 in {r['wall']:.1f} s")
    ax.axhline(2.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("seconds from the start")
    ax.set_ylabel("threads running or runnable (capped at 2)")
    ax.set_title("issue 13's transfer: its own demand for cores")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--window", type=float, default=0.25, help="seconds a row")
    ap.add_argument("--rows", action="store_true", help="print every window's row")
    add_base_options(ap)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    trees = {"new": Path(__file__).resolve().parents[1] / "src"}
    base = base_src(args, "bench_demand_")
    if base is not None:      # in turn, the base first in odd rounds
        trees = {"base": base, **trees}
    runs = {name: [] for name in trees}
    for r in range(args.rounds):
        order = list(trees) if r % 2 == 0 else list(trees)[::-1]
        for name in order:
            with tempfile.TemporaryDirectory(dir=out) as tmp:
                _, demand, running, per, root = run_once(trees[name], Path(tmp))
            s = summary(demand, running, per, args.window)
            s["phases"] = phases(demand, per, root)
            runs[name].append(s)
            _print_run(f"{name} {r + 1}", s, args.rows)
    for name, rs in runs.items():
        med = {k: float(np.median([r[k] for r in rs])) for k in ("wall", "cpu", "short")}
        ph = {k: float(np.median([r["phases"][k] for r in rs])) for k in ("start", "setup", "end")}
        print(f"{name}: medians {med['wall']:.2f} s, {med['cpu']:.2f} CPU-s, "
              f"{med['short']:.2f} core-s short (start {ph['start']:.2f}, set-up "
              f"{ph['setup']:.2f}, end {ph['end']:.2f})")
    (out / "transfer_demand.json").write_text(json.dumps(
        {"trees": {k: str(v) for k, v in trees.items()}, "runs": runs}, indent=1))
    plot([r for rs in runs.values() for r in rs], out / "transfer_demand.png")
    return 0


def _print_run(label: str, s: dict, rows: bool) -> None:
    ph = s["phases"]
    print(f"{label}: {s['wall']:.2f} s, {s['cpu']:.2f} CPU-s, {s['short']:.2f} core-s short "
          f"of 2 ({100 * s['short_fraction']:.1f} %; start {ph['start']:.2f}, set-up "
          f"{ph['setup']:.2f}, end {ph['end']:.2f})", flush=True)
    for w in s["windows"] if rows else ():
        print(f"  {w['t']:7.2f}  demand {w['demand']:4.2f}  running {w['running']:4.2f}  "
              + "  ".join(f"{p}:{v:4.2f}" for p, v in w["processes"].items()))


if __name__ == "__main__":
    raise SystemExit(main())

"""What the parent process of issue 13's transfer runs, and when: its main thread's stack
sampled every ``--step`` seconds while ``facetransfer transfer`` runs in this process.

The command is issue 13's 10-second pair (``driving_d9`` with the expressions of
``driving_d6``, default model, H.264 CRF 18, no track cache), as
:mod:`bench_transfer_e2e_ab` runs it, but in-process, so that a thread of this process can read
the main thread's frames (``sys._current_frames``): no profiler's hooks, the calls as they
run. Beside each sample: the process's CPU seconds (every thread of it, not its forked
tracker or ffmpeg) and the machine's busy cores (``/proc/stat``, Linux). Per window of
``--window`` seconds it prints the parent's cores, the machine's, and the most frequent
innermost frames of the package with what they wait in (the innermost frame of all).

    python benchmarks/profile_transfer_parent.py --out out/parent --from 3 --to 5

Writes ``OUT/parent_samples.json`` (time, CPU seconds, busy and total jiffies, stack of
``(file, function, line)``, innermost first).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import threading
import time
from pathlib import Path

# timed from scratch: no track reused from the track cache (facetransfer.track.cache)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"
# as the console script's transfer (facetransfer.cli.main.SERIAL_POOLS), before NumPy loads
for _name in ("OPENBLAS_NUM_THREADS", "OPENCV_FOR_THREADS_NUM"):
    os.environ.setdefault(_name, "1")

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _ticks() -> tuple[int, int]:
    """``(busy, total)`` jiffies of all cores since boot (idle and iowait not busy)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    return sum(v) - v[3] - v[4], sum(v)


def _stack(frame) -> list:
    """``[(file below src/, function, line), ...]`` of ``frame`` outwards."""
    out = []
    while frame is not None:
        c = frame.f_code
        out.append((c.co_filename.rsplit("/src/", 1)[-1], c.co_name, frame.f_lineno))
        frame = frame.f_back
    return out


def sample(command: list[str], step: float) -> list:
    """Run the CLI's ``command`` here, as its console script would (``sys.argv``), with a
    thread sampling the main thread every ``step`` seconds: ``[(t, cpu, (busy, total),
    stack), ...]``."""
    from facetransfer.cli.main import main

    t0, samples, halt = time.perf_counter(), [], threading.Event()
    main_id = threading.get_ident()

    def run() -> None:
        while not halt.wait(step):
            f = sys._current_frames().get(main_id)
            t = os.times()
            samples.append((time.perf_counter() - t0, t.user + t.system, _ticks(), _stack(f)))

    th = threading.Thread(target=run, daemon=True)
    th.start()
    argv, sys.argv = sys.argv, ["facetransfer", *command]
    try:
        main()
    finally:
        sys.argv = argv
        halt.set()
        th.join()
    return samples


def _key(stack: list, depth: int) -> str:
    """The ``depth`` innermost frames of the package, and the innermost frame of all."""
    ours = [f"{f[0].split('/', 1)[1]}:{f[1]}" for f in stack
            if f[0].startswith("facetransfer/")][:depth]
    inner = stack[0] if stack else ("?", "?", 0)
    return " < ".join(ours) + f" || {inner[0].rsplit('/', 1)[-1]}:{inner[1]}"


def report(samples: list, lo: float, hi: float, window: float, depth: int,
           cores: int) -> None:
    """Print, per window of ``[lo, hi)``, the parent's and the machine's busy cores and the
    three most frequent stacks (:func:`_key`)."""
    t = lo
    while t < hi:
        w = [s for s in samples if t <= s[0] < t + window]
        if len(w) > 1:
            dt = max(w[-1][0] - w[0][0], 1e-9)
            parent = (w[-1][1] - w[0][1]) / dt
            machine = cores * (w[-1][2][0] - w[0][2][0]) / max(w[-1][2][1] - w[0][2][1], 1)
            print(f"{t:6.2f} s  parent {parent:4.2f}  machine {machine:4.2f}  ({len(w)})")
            for k, n in collections.Counter(_key(s[3], depth) for s in w).most_common(3):
                print(f"        {n:3d} {k[:200]}")
        t += window


def main(argv=None) -> int:
    from bench_transfer_e2e_ab import FRAMES, _videos

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--step", type=float, default=0.005, help="seconds between samples")
    ap.add_argument("--window", type=float, default=0.1, help="seconds a printed row")
    ap.add_argument("--from", dest="lo", type=float, default=0.0)
    ap.add_argument("--to", dest="hi", type=float, default=1e9)
    ap.add_argument("--depth", type=int, default=3, help="package frames a stack shows")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    target, source = _videos()
    samples = sample(["transfer", "--target", str(target), "--expression-from", str(source),
                      "--out", str(out / "parent.mp4"), "--max-frames", str(FRAMES),
                      "--overwrite", "--no-progress"], args.step)
    (out / "parent_samples.json").write_text(json.dumps(samples))
    (out / "parent.mp4").unlink(missing_ok=True)
    end = samples[-1][0] if samples else 0.0
    report(samples, args.lo, min(args.hi, end), args.window, args.depth, os.cpu_count() or 1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

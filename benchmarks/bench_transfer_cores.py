"""How busy the cores are during issue 13's 10-second transfer: where the wall time is CPU and
where it is waiting.

Each round runs the peer (Face Landmarker in VIDEO mode with blendshapes on the target's 300
frames, a fresh process), then ``facetransfer transfer`` on issue 13's 10-second pair
(``driving_d9`` with the expressions of ``driving_d6``, default model, H.264 CRF 18, no track
cache), as :mod:`bench_transfer_e2e_ab` does, while the machine's busy cores are read from
``/proc/stat`` every ``--step`` seconds (Linux). Per round: wall seconds, the CPU seconds of
the command and everything it started (its forked tracker, ffmpeg), the least wall time those
CPU seconds allow on the machine's cores (CPU / cores), and the core-seconds left idle while
it ran (the machine's, so anything else running counts as busy). ``wall = (CPU + idle) /
cores`` up to the sampling: a command is only faster than its CPU allows by doing less work,
and only as slow as its CPU where the cores are never idle.

    python benchmarks/bench_transfer_cores.py --rounds 3 --out out/benchmarks

Writes ``OUT/transfer_cores.json`` and ``OUT/transfer_cores.png`` (busy cores over each run).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# timed from scratch: no track reused from the track cache (facetransfer.track.cache)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import arguments, children_cpu, facetransfer_exe, save_json, save_plot  # noqa: E402
from bench_transfer_e2e_ab import FRAMES, _videos, peer  # noqa: E402


def _cpu_ticks() -> tuple[int, int]:
    """``(busy, total)`` jiffies of all cores since boot (``/proc/stat``'s first line; idle
    and iowait count as not busy)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    return sum(v) - v[3] - v[4], sum(v)


class CoreSampler:
    """Busy cores (0..cores) of the machine every ``step`` seconds, on a thread, from
    :meth:`start` to :meth:`stop`: ``times`` (s from the start) and ``busy``."""

    def __init__(self, step: float) -> None:
        self.step, self.cores = float(step), os.cpu_count() or 1
        self.times: list[float] = []
        self.busy: list[float] = []
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0, last = time.perf_counter(), _cpu_ticks()
        while not self._halt.wait(self.step):
            cur = _cpu_ticks()
            self.times.append(time.perf_counter() - t0)
            self.busy.append(self.cores * (cur[0] - last[0]) / max(cur[1] - last[1], 1))
            last = cur

    def start(self) -> "CoreSampler":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._halt.set()
        self._thread.join()

    def idle_core_seconds(self) -> float:
        """The core-seconds not busy over the samples."""
        return float(sum((self.cores - b) * self.step for b in self.busy))


def one_run(out: Path, step: float) -> dict:
    """The command once, sampled: wall, CPU, the floor, idle core-seconds, the curve."""
    target, source = _videos()
    sampler = CoreSampler(step).start()
    t, c = time.perf_counter(), children_cpu()
    subprocess.run([facetransfer_exe(), "transfer", "--target", str(target), "--expression-from",
                    str(source), "--out", str(out), "--max-frames", str(FRAMES), "--overwrite",
                    "--no-progress"], check=True, capture_output=True)
    wall, cpu = time.perf_counter() - t, children_cpu() - c
    sampler.stop()
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "cpu_floor_s": round(cpu / sampler.cores, 2),
            "idle_core_s": round(sampler.idle_core_seconds(), 2),
            "times": [round(x, 2) for x in sampler.times],
            "busy_cores": [round(x, 2) for x in sampler.busy]}


def plot(rounds: list, cores: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    for i, r in enumerate(rounds):
        ax.plot(r["times"], r["busy_cores"], lw=1,
                label=f"round {i + 1}: {r['wall_s']:.2f} s wall, {r['cpu_s']:.1f} CPU-s, "
                      f"{r['idle_core_s']:.1f} core-s idle")
    ax.axhline(cores, color="k", lw=0.8, ls="--")
    ax.axvline(10.0, color="grey", lw=0.8, ls=":", label="the clip's 10 s")
    ax.set_xlabel("seconds from the command's start")
    ax.set_ylabel(f"busy cores (of {cores})")
    ax.set_ylim(0, cores + 0.2)
    ax.set_title("10-s transfer (driving_d9 <- driving_d6): the machine's busy cores")
    ax.legend(fontsize=7, loc="lower center")
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--step", type=float, default=0.1, help="sampling interval, seconds")
    args = ap.parse_args()
    if not Path("/proc/stat").is_file():
        raise SystemExit("bench_transfer_cores: needs Linux's /proc/stat")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rounds, peers = [], []
    with tempfile.TemporaryDirectory(prefix="bench_cores_") as tmp:
        one_run(Path(tmp) / "warm.mp4", args.step)   # numba's caches, the page cache
        for i in range(args.rounds):
            peers.append(round(peer(), 2))
            rounds.append(one_run(Path(tmp) / "result.mp4", args.step))
            r = rounds[-1]
            print(f"round {i + 1}: peer {peers[-1]:.2f} s; transfer {r['wall_s']:.2f} s wall, "
                  f"{r['cpu_s']:.1f} CPU-s (floor {r['cpu_floor_s']:.2f} s), "
                  f"{r['idle_core_s']:.2f} core-s idle", flush=True)
    cores = os.cpu_count() or 1
    keys = ("wall_s", "cpu_s", "cpu_floor_s", "idle_core_s")
    report = {"target": str(_videos()[0]), "source": str(_videos()[1]), "frames": FRAMES,
              "cores": cores, "step_s": args.step, "peer_s": peers, "rounds": rounds,
              "medians": {k: float(np.median([r[k] for r in rounds])) for k in keys}
              | {"peer_s": float(np.median(peers))}}
    save_json(report, out / "transfer_cores.json")
    plot(rounds, cores, out / "transfer_cores.png")
    print("medians:", ", ".join(f"{k} {v:.2f}" for k, v in report["medians"].items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

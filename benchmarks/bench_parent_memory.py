"""The transfer's parent process's memory through the render: its peak, what it holds when the
render begins, and its resident memory while it renders.

Each round runs issue 13's transfer (``driving_d9`` <- ``driving_d6``, ``--max-frames 300``,
track and render caches off) through the CLI in a fresh process (``--run``) that samples its
own ``VmRSS`` (``/proc/self/status``) every 20 ms and stamps the render's start and end
(``video_transfer.render_plan`` wrapped). At the render's start it also sizes what the parent
holds: the capture's point samplers kept by ``track.capture_points`` (``_SAMPLERS``), the
plan's frames (target, mouth, texture) and its tracks' arrays.

Usage::

    python benchmarks/bench_parent_memory.py --out out/benchmarks [--rounds 3]

Writes ``OUT/parent_memory.json`` and ``OUT/parent_memory.png``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from _report import arguments, save_json, save_plot  # benchmarks/ is on sys.path

DATA = Path(os.environ.get("FACETRANSFER_DATA_DIR", "../shared/data")) / "video"


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _nbytes(obj, seen=None) -> int:
    """The bytes of the numpy arrays reachable through ``obj``'s attributes, lists, dicts."""
    import numpy as np

    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes if obj.base is None else _nbytes(obj.base, seen)
    if isinstance(obj, (bytes, bytearray)):    # the memory of a frozen array (a topology's faces)
        return len(obj)
    if isinstance(obj, dict):
        return sum(_nbytes(v, seen) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_nbytes(v, seen) for v in obj)
    fields = getattr(obj, "__dict__", None)
    return 0 if fields is None else sum(_nbytes(v, seen) for v in fields.values())


def _held(plan) -> dict:
    """MB of what the parent holds at the render's start."""
    from facetransfer.track import capture_points

    mb = 1 / 2 ** 20
    return {
        "samplers": len(capture_points._SAMPLERS),
        "samplers_mb": _nbytes(list(capture_points._SAMPLERS.values())) * mb,
        "target_frames_mb": plan.target_frames.nbytes * mb,
        "mouth_frames_mb": plan.mouth_frames.nbytes * mb,
        "mouth_frames_are_target": plan.mouth_frames is plan.target_frames,
        "texture_frames_mb": 0 if plan.texture_frames is None else plan.texture_frames.nbytes * mb,
        "tracks_mb": {k: _nbytes(t) * mb for k, t in plan.source_tracks.items()},
        "new_track_mb": _nbytes(plan.new_track) * mb,
        "mouth_track_mb": _nbytes(plan.mouth_track) * mb,
    }


def run_once(out: Path) -> None:
    """One transfer in this process, its memory sampled; the report written to ``out``."""
    import facetransfer.video_transfer as vt
    from facetransfer.cli.main import main

    t0, samples, stamps, held = time.monotonic(), [], {}, {}
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            samples.append((time.monotonic() - t0, _rss_mb()))
            time.sleep(0.02)

    render = vt.render_plan

    def timed_render(plan, *args, **kwargs):
        stamps["render_start"] = time.monotonic() - t0
        held.update(_held(plan))
        try:
            return render(plan, *args, **kwargs)
        finally:
            stamps["render_end"] = time.monotonic() - t0

    vt.render_plan = timed_render
    threading.Thread(target=sample, daemon=True).start()
    dest = out.with_suffix(".mp4")
    code = main(["transfer", "--target", str(DATA / "driving_d9.mp4"), "--expression-from",
                 str(DATA / "driving_d6.mp4"), "--out", str(dest), "--max-frames", "300",
                 "--no-progress", "--overwrite"])
    done.set()
    hwm = [ln for ln in Path("/proc/self/status").read_text().splitlines()
           if ln.startswith("VmHWM:")][0]
    out.write_text(json.dumps({"exit": code, "samples": samples, "stamps": stamps,
                               "held": held, "peak_mb": int(hwm.split()[1]) / 1024}))


def _summary(run: dict) -> dict:
    import numpy as np

    s = np.asarray(run["samples"])
    a, b = run["stamps"]["render_start"], run["stamps"]["render_end"]
    r = s[(s[:, 0] >= a) & (s[:, 0] <= b), 1]
    return {"peak_mb": run["peak_mb"], "render_median_mb": float(np.median(r)),
            "render_max_mb": float(r.max()), "at_render_start_mb": float(r[0]),
            "held": run["held"]}


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--run", help="internal: one round in this process, its JSON here")
    args = ap.parse_args()
    if args.run:
        run_once(Path(args.run))
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, FACETRANSFER_TRACK_CACHE="off", FACETRANSFER_RENDER_CACHE="off")
    runs = []
    for i in range(args.rounds):
        path = out / f"parent_memory.{i}.json"
        subprocess.run([sys.executable, __file__, "--run", str(path)], env=env, check=True)
        runs.append(json.loads(path.read_text()))
        path.unlink()
        path.with_suffix(".mp4").unlink(missing_ok=True)
        print(json.dumps(_summary(runs[-1])), flush=True)
    save_json({"rounds": [_summary(r) for r in runs]}, out / "parent_memory.json")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4))
    for r in runs:
        t, m = zip(*r["samples"])
        ax.plot(t, m, lw=0.8)
        ax.axvline(r["stamps"]["render_start"], color="grey", lw=0.5)
    ax.set_xlabel("s"), ax.set_ylabel("parent VmRSS (MB)")
    ax.set_title("the transfer's parent: resident memory (render start: grey)")
    save_plot(fig, out / "parent_memory.png")


if __name__ == "__main__":
    main()

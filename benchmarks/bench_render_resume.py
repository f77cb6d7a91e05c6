"""What writing a transfer's video in parts costs, and what a continued render saves.

``facetransfer transfer`` encodes its frames into parts kept in the render cache
(``facetransfer.io.video_parts``, ``facetransfer.render_cache``) and joins them at the end, so
that an interrupted run continues its render. This runs the command on a pair of the data
folder's clips (``driving_d9`` the target, ``driving_d6`` the source, 300 frames; ``--target``,
``--source`` and ``--frames`` for others, e.g. 1080p clips), each run a fresh process, with the
tracks in a private track cache filled by a first run (so that the runs differ only in their
render), in turn for ``--rounds`` rounds:

- ``one piece``: ``FACETRANSFER_RENDER_CACHE=off``, the video encoded in one ffmpeg pass;
- ``parts``: the default, parts of 250 frames joined by stream copy;
- ``interrupted``: the default, SIGINT to the command's process group (as a terminal's Ctrl-C)
  at ``--at`` of the parts run's median time, then the same command again (``resumed``).

Reported: wall and CPU seconds of each (the command, its tracker and ffmpeg processes), the
frame the resumed run continued from, the file sizes, and the quality of each video (PSNR of
the Y plane, every frame) against the same render encoded losslessly (``--crf 0``, one piece).
No peer: MediaPipe does not render video.

Usage::

    python benchmarks/bench_render_resume.py --out out/benchmarks [--rounds 2]

Writes ``OUT/render_resume.json`` and ``OUT/render_resume.png``.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# benchmarks/ is on sys.path
from _report import arguments, children_cpu, facetransfer_exe, save_json, save_plot

DATA = Path(os.environ.get("FACETRANSFER_DATA_DIR", "../shared/data")) / "video"


def run(args: list[str], env: dict, interrupt_after: float | None = None) -> dict:
    """One run of ``facetransfer transfer ARGS`` in its own process group: wall and CPU
    seconds, exit status, the frame a continued render started from."""
    t, c = time.perf_counter(), children_cpu()
    # SIGINT as a terminal has it: a shell's background job starts with it ignored
    p = subprocess.Popen([facetransfer_exe(), "transfer", *args], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    if interrupt_after is not None:
        try:
            p.wait(interrupt_after)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGINT)
    out, err = p.communicate()
    found = re.search(r"continued an interrupted render from frame (\d+)", out)
    return {"seconds": time.perf_counter() - t, "cpu_seconds": children_cpu() - c,
            "status": p.returncode, "resumed_from": int(found.group(1)) if found else 0,
            "stderr": err.strip().splitlines()[-1:] if p.returncode else []}


def psnr_y(video: Path, reference: Path) -> float:
    """PSNR of the Y plane (BT.601) over every frame of ``video`` against ``reference``."""
    from facetransfer.io.video import iter_frames

    w = np.array([0.299, 0.587, 0.114])
    sse, count = 0.0, 0
    for a, b in zip(iter_frames(video), iter_frames(reference)):
        d = a.astype(np.float64) @ w - b.astype(np.float64) @ w
        sse += float((d * d).sum())
        count += d.size
    return float(10 * np.log10(255.0 ** 2 / (sse / count)))


def measure(args, tmp: Path) -> dict:
    from facetransfer.default_model import default_model_path, load_default_model

    load_default_model()  # built once in the user's cache if missing, not in the private one
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp / "cache"), FACETRANSFER_TRACK_CACHE="on")
    base = ["--target", str(args.target), "--expression-from", str(args.source),
            "--model", str(default_model_path()), "--max-frames", str(args.frames),
            "--overwrite", "--no-progress"]
    off = dict(env, FACETRANSFER_RENDER_CACHE="off")
    print("tracking both clips once (the track cache) and the lossless reference ...")
    first = run(base + ["--crf", "0", "--out", str(tmp / "lossless.mp4")], off)
    assert first["status"] == 0, first
    runs: dict[str, list] = {"one piece": [], "parts": [], "interrupted": [], "resumed": []}
    for r in range(args.rounds):
        runs["one piece"].append(run(base + ["--out", str(tmp / "one.mp4")], off))
        runs["parts"].append(run(base + ["--out", str(tmp / "parts.mp4")], env))
        at = args.at * float(np.median([x["seconds"] for x in runs["parts"]]))
        runs["interrupted"].append(run(base + ["--out", str(tmp / "resumed.mp4")], env, at))
        runs["resumed"].append(run(base + ["--out", str(tmp / "resumed.mp4")], env))
        print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]['seconds']:.1f} s (status "
                                            f"{v[-1]['status']})" for k, v in runs.items())
              + f"; continued from frame {runs['resumed'][-1]['resumed_from']}")
    files = {k: tmp / f"{n}.mp4" for k, n in (("one piece", "one"), ("parts", "parts"),
                                              ("resumed", "resumed"))}
    quality = {k: {"psnr_y_db": psnr_y(p, tmp / "lossless.mp4"),
                   "mbit_per_s": p.stat().st_size * 8 / 1e6 / (args.frames / _fps(p))}
               for k, p in files.items()}
    return {"runs": runs, "quality": quality}


def _fps(path: Path) -> float:
    from facetransfer.io.video import video_info

    return video_info(path).fps


def summary(runs: dict) -> dict:
    return {k: {"median_seconds": float(np.median([x["seconds"] for x in v])),
                "median_cpu_seconds": float(np.median([x["cpu_seconds"] for x in v]))}
            for k, v in runs.items()}


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = report["summary"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    names = ["one piece", "parts", "interrupted", "resumed"]
    ax.bar(names, [s[k]["median_seconds"] for k in names],
           color=["#888", "#4a7", "#c84", "#48c"])
    ax.bar(["interrupted\n+ resumed"], [s["interrupted"]["median_seconds"]],
           color="#c84")
    ax.bar(["interrupted\n+ resumed"], [s["resumed"]["median_seconds"]],
           bottom=[s["interrupted"]["median_seconds"]], color="#48c")
    ax.set_ylabel("wall seconds (median)")
    ax.set_title(f"{report['frames']} frames, tracks cached; resumed from frame "
                 f"{report['resumed_from']}", fontsize=9)
    q = report["quality"]
    bx.bar(list(q), [v["psnr_y_db"] for v in q.values()], color=["#888", "#4a7", "#48c"])
    for i, v in enumerate(q.values()):
        bx.text(i, v["psnr_y_db"], f"{v['psnr_y_db']:.2f} dB\n{v['mbit_per_s']:.2f} Mbit/s",
                ha="center", va="bottom", fontsize=8)
    bx.set_ylim(min(v["psnr_y_db"] for v in q.values()) - 3,
                max(v["psnr_y_db"] for v in q.values()) + 2)
    bx.set_ylabel("PSNR Y against the lossless render (dB)")
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    ap.add_argument("--target", type=Path, default=DATA / "driving_d9.mp4")
    ap.add_argument("--source", type=Path, default=DATA / "driving_d6.mp4")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--at", type=float, default=0.6,
                    help="interrupt at this share of the parts run's median time")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out) as t:
        res = measure(args, Path(t))
    report = {"target": args.target.name, "source": args.source.name, "frames": args.frames,
              "rounds": args.rounds, "interrupt_at": args.at, "summary": summary(res["runs"]),
              "resumed_from": int(np.median([x["resumed_from"] for x in res["runs"]["resumed"]])),
              **res}
    save_json(report, out / "render_resume.json")
    plot(report, out / "render_resume.png")
    for k, v in report["summary"].items():
        print(f"{k}: {v['median_seconds']:.1f} s, {v['median_cpu_seconds']:.1f} CPU-s")
    for k, v in report["quality"].items():
        print(f"{k}: PSNR Y {v['psnr_y_db']:.2f} dB against the lossless render, "
              f"{v['mbit_per_s']:.2f} Mbit/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

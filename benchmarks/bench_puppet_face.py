"""The puppet's eyes and mouth (facetransfer.puppet_face): its CPU per frame and a contact sheet.

``facetransfer puppet`` renders every frame of a clip, so what the eyeballs and the mouth's
cavity cost per frame matters. This tree and the revision ``--before`` render, in turn and each
in a fresh process (its own ``src`` first on the path) on one thread (``NUMBA_NUM_THREADS``
and the BLAS's at 1: the machine's other work moves multithreaded CPU figures by half),
frames 300-499 of ``driving_d6`` (a blink at 380) with the default model's mean person
(``puppet_frames``, warmed up on 5 frames first), for ``BENCH_ROUNDS`` (5) rounds: CPU ms per
frame (``time.process_time``), medians and spreads. Each tree also renders four frames of the
clip (neutral, a blink, looking to the subject's left, an open mouth) for a before / after
contact sheet, whole and around the eyes.

Usage::

    [BENCH_ROUNDS=5] python benchmarks/bench_puppet_face.py --out out/s52-puppet [--before main]

Writes ``OUT/puppet_face.json``, ``OUT/puppet_face.png`` (CPU per frame of each round) and
``OUT/sheet.png`` (rows: before, after, before's eyes, after's eyes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

#: The sheet's frames of driving_d6 and what they show (their activations in the track).
SHEET = {41: "neutral", 380: "blink (eyeBlink* 1)", 361: "looking to its left (0.47)",
         699: "jaw open (0.88)"}
#: The timed frames.
TIMED = (300, 500)


def _worker(track_path: str, sheet_path: str) -> None:
    """In the tree on the path: time puppet_frames over :data:`TIMED`, print JSON, save the
    :data:`SHEET` frames to ``sheet_path`` (.npy)."""
    import time

    try:
        from facetransfer.puppet_video import puppet_frames
    except ImportError:   # a tree before the fifty-third session (--before): in transfer
        from facetransfer.transfer import puppet_frames
    from facetransfer.default_model import load_default_model
    from facetransfer.track.project import take_frames
    from facetransfer.track.result import Track

    track, model = Track.load(track_path), load_default_model()
    wid = model.weight_mean("identity")
    for _ in puppet_frames(take_frames(track, np.arange(5)), model, wid):
        pass                                          # numba's kernels compiled or loaded
    sub = take_frames(track, np.arange(*TIMED))
    c0 = time.process_time()
    n = sum(1 for _ in puppet_frames(sub, model, wid))
    cpu = time.process_time() - c0
    frames = [next(puppet_frames(take_frames(track, np.array([i])), model, wid))
              for i in SHEET]
    np.save(sheet_path, np.stack(frames))
    print(json.dumps({"frames": n, "cpu_ms_per_frame": 1000 * cpu / n}))


def _run(src: Path | None, track: Path, sheet: Path) -> float:
    """CPU ms per frame of one worker process of the tree ``src`` (None: this script's)."""
    env = dict(os.environ, NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=str(src or Path(__file__).resolve().parents[1] / "src"))
    out = subprocess.run([sys.executable, __file__, "--worker", str(track), str(sheet)],
                         env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])["cpu_ms_per_frame"]


def _track(out: Path, data: Path) -> Path:
    """driving_d6's track (``facetransfer track``, the default model), made once in ``out``."""
    from _revision import run_command

    path = out / "driving_d6.track.npz"
    if not path.is_file():
        code, err = run_command(["track", data / "video" / "driving_d6.mp4", "--out", path])
        if code:
            raise SystemExit(f"track failed: {err}")
    return path


def _sheet(before: np.ndarray, now: np.ndarray, path: Path, eyes: tuple) -> None:
    """The contact sheet: the frames of each tree side by side, then their eyes (``eyes``:
    rows, columns of the frames) twice as large."""
    import cv2
    from _report import save_sheet

    def zoom(frames):
        return np.concatenate([cv2.resize(f[eyes], (f.shape[1], f.shape[1] * (eyes[0].stop -
                               eyes[0].start) // (eyes[1].stop - eyes[1].start)),
                               interpolation=cv2.INTER_NEAREST) for f in frames], axis=1)

    labels = " | ".join(f"{i} {what}" for i, what in SHEET.items())
    rows = [np.concatenate(list(before), axis=1), np.concatenate(list(now), axis=1),
            zoom(before), zoom(now)]
    save_sheet([np.ascontiguousarray(r) for r in rows],
               [f"before: {labels}", "after", "before: the eyes", "after: the eyes"], path)


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from _report import save_plot

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for x, name in enumerate(("before", "now")):
        v = report["cpu_ms_per_frame"][name]
        ax.plot([x] * len(v), v, "o", alpha=0.6)
        ax.hlines(np.median(v), x - 0.2, x + 0.2, color="k")
    ax.set_xticks([0, 1], [f"before ({report['before']})", "now"])
    ax.set_ylabel("CPU ms per frame (one thread)")
    ax.set_title("puppet_frames, driving_d6 frames 300-499")
    save_plot(fig, path)


def main() -> int:
    from _report import save_json
    from _revision import now_and_before

    from facetransfer.assets import data_dir

    rounds = int(os.environ.get("BENCH_ROUNDS", "5"))
    out, trees, rev = now_and_before(__doc__, "main")
    track = _track(out, Path(data_dir()))
    times = {"before": [], "now": []}
    for _ in range(rounds):
        for name in ("before", "now"):
            times[name].append(_run(trees[name], track, out / f"sheet_{name}.npy"))
    report = {"before": rev, "frames": list(TIMED), "rounds": rounds, "cpu_ms_per_frame": times,
              "median": {k: float(np.median(v)) for k, v in times.items()},
              "spread": {k: [float(min(v)), float(max(v))] for k, v in times.items()}}
    save_json(report, out / "puppet_face.json")
    _plot(report, out / "puppet_face.png")
    before, now = (np.load(out / f"sheet_{k}.npy") for k in ("before", "now"))
    _sheet(before, now, out / "sheet.png", (slice(180, 250), slice(120, 360)))
    print(json.dumps(report["median"]), f"wrote {out / 'puppet_face.json'}, "
          f"{out / 'puppet_face.png'} and {out / 'sheet.png'}")
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--worker":
        _worker(sys.argv[2], sys.argv[3])
        sys.exit(0)
    sys.exit(main())

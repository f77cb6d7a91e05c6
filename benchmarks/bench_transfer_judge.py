"""Transfer fidelity by an independent judge (issue 13): MediaPipe on source, target and result.

Runs Face Landmarker (Tasks API, VIDEO mode, blendshapes) on the three panels of a
``source | target | result`` video (what ``facetransfer demo`` writes; made with the demo's default
inputs when ``--video`` is absent) and correlates, over frames, the result's blendshapes and mouth
opening (MediaPipe 13-14 over the outer eye corners 33-263) with the source's and the target's.
A transfer carries the source when the result follows the source and not the target.

Usage::

    python benchmarks/bench_transfer_judge.py --out out/benchmarks [--video out/demo.mp4]

Writes ``OUT/transfer_judge.json`` and ``OUT/transfer_judge.png``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

SHAPES = ("jawOpen", "mouthPucker", "mouthSmileLeft", "mouthSmileRight", "browInnerUp",
          "eyeBlinkLeft", "eyeBlinkRight")


def panel_scores(video: Path, k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`facetransfer.fidelity.panel_scores` of panel ``k`` (0, 1, 2) of the video."""
    from facetransfer.fidelity import panel_scores as scores
    from facetransfer.io.video import iter_frames, video_info

    info = video_info(video)
    w = info.size[0] // 3
    return scores((f[:, k * w:(k + 1) * w] for f in iter_frames(video)), info.fps)


def judge(video: Path) -> dict:
    from facetransfer.arkit import MEDIAPIPE_NAMES
    from facetransfer.fidelity import correlation as _corr

    (S, Sm), (T, Tm), (R, Rm) = (panel_scores(video, k) for k in range(3))
    out = {}
    for n in SHAPES:
        k = MEDIAPIPE_NAMES.index(n)
        out[n] = {"result_source": _corr(R[:, k], S[:, k]),
                  "result_target": _corr(R[:, k], T[:, k]),
                  "amplitude": float(np.nanstd(R[:, k]) / max(np.nanstd(S[:, k]), 1e-9))}
    out["mouth_opening"] = {"result_source": _corr(Rm, Sm), "result_target": _corr(Rm, Tm),
                            "amplitude": float(np.nanstd(Rm) / max(np.nanstd(Sm), 1e-9))}
    return out


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    names = list(res)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.bar(x - 0.2, [res[n]["result_source"] for n in names], 0.4, label="result ~ source")
    ax.bar(x + 0.2, [res[n]["result_target"] for n in names], 0.4, label="result ~ target")
    ax.axhline(0.8, color="g", ls=":", lw=1)
    ax.axhline(0.3, color="r", ls=":", lw=1)
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel("correlation over frames")
    ax.set_title("transfer fidelity, judged by MediaPipe (green: 0.8 with the source; red: 0.3)")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--video", help="source | target | result video (default: run the demo)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = Path(args.video) if args.video else out / "judge_demo" / "demo.mp4"
    if not args.video:
        exe = Path(sys.executable).parent / "facetransfer"
        subprocess.run([str(exe), "demo", "--out", str(video.parent), "--overwrite"], check=True)
    res = judge(video)
    from facetransfer.io.atomic import atomic_path

    with atomic_path(out / "transfer_judge.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps({"video": str(video), "scores": res}, indent=2))
    plot(res, out / "transfer_judge.png")
    for n, r in res.items():
        print(f"{n:15s} result~source {r['result_source']:+.2f}  result~target "
              f"{r['result_target']:+.2f}  amplitude {r['amplitude']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

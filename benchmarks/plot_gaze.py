"""Picture of the gaze on one real clip: our eyeLook* with the iris (the default) and without
(``CaptureOptions(gaze=False)``: the lids only) against Face Landmarker's own eyeLook*.

Per eye, ``out - in`` and ``up - down`` over the frames; the JSON holds the correlations.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/plot_gaze.py [--clip driving_d6] [--frames 400]
        [--out out/benchmarks]

Writes ``OUT/gaze_CLIP.png`` and ``OUT/gaze_CLIP.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402
from bench_capture import _data_dir, corr  # noqa: E402


def _series(A: np.ndarray, side: str) -> dict:
    from facetransfer.arkit import ARKIT_NAMES

    c = lambda n: A[:, ARKIT_NAMES.index(n)]  # noqa: E731
    return {"out - in": c(f"eyeLookOut{side}") - c(f"eyeLookIn{side}"),
            "up - down": c(f"eyeLookUp{side}") - c(f"eyeLookDown{side}")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", default="driving_d6")
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--out", default="out/benchmarks")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path, save_figure
    from facetransfer.track.capture import CaptureOptions, capture_detections, detect_video

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = _data_dir() / "video" / f"{args.clip}.mp4"
    with filtered_stderr():
        _, mp = cached_landmarker(video, out / "capture_cache")
        det, fps, size, src = detect_video(str(video), max_frames=args.frames)
    model = load_default_model()
    runs = {name: capture_detections(det, model, options=CaptureOptions(gaze=g), fps=fps,
                                     frame_size=size).blendshapes.astype(np.float64)
            for name, g in (("ours (iris)", True), ("ours (lids only)", False))}
    F = det.n_frames
    fig, axes = plt.subplots(4, 1, figsize=(12, 10), sharex=True)
    res = {}
    for r, (side, key) in enumerate([(s, k) for s in ("Left", "Right")
                                     for k in ("out - in", "up - down")]):
        ax = axes[r]
        ref = _series(mp[:F], side)[key]
        ax.plot(ref, color="k", lw=1.5, label="Face Landmarker")
        for (name, A), col in zip(runs.items(), ("tab:blue", "tab:gray")):
            v = _series(A, side)[key]
            c = corr(v, ref)
            res[f"{name} {side} {key}"] = c
            ax.plot(v, color=col, lw=1, label=f"{name}, r {c if c is None else round(c, 2)}")
        ax.set_ylabel(f"eyeLook {side}\n{key}")
        ax.legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel(f"frame ({args.clip}, {F} frames)")
    fig.suptitle("gaze: ours against Face Landmarker's eyeLook* (Left = the subject's own)")
    fig.tight_layout()
    save_figure(fig, out / f"gaze_{args.clip}.png", dpi=100)
    with atomic_path(out / f"gaze_{args.clip}.json") as tmp:
        Path(tmp).write_text(json.dumps({"clip": args.clip, "frames": F, "corr": res}, indent=1))
    print(json.dumps(res, indent=1))
    print(f"wrote {out / f'gaze_{args.clip}.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

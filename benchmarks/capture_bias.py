"""Where the capture's 7-point error comes from: per point, its bias against Face Landmarker's.

On the synthetic clips of ``bench_capture.py`` (made and cached by it first: run
``bench_capture.py --only synthetic --out OUT`` before), each tracker's error at the 7 key points
(iBUG 36, 39, 42, 45, 30, 48, 54), divided by the true eye-corner distance of its frame, is
split into its bias (the mean error vector over the clip) and the rest (the per-frame scatter
around that mean). Trackers: the default capture (``capture_video``) and Face Landmarker
through the calibrated mapping. Also: how far our points sit from Face Landmarker's, and
Face Landmarker's NME after smoothing its points over time (how much of its error is jitter).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/capture_bias.py --out OUT [--model M.npz]

Writes ``OUT/capture_bias.json`` and ``OUT/capture_bias.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_capture as bc  # noqa: E402

POINTS = ["R eye out", "R eye in", "L eye in", "L eye out", "nose", "mouth R", "mouth L"]


def split_error(P: np.ndarray, T: np.ndarray) -> dict:
    """Bias (|mean error vector|) and scatter (mean |error - mean|) per key point, in % of the
    true eye-corner distance; the signed mean error (x, y); the median NME."""
    E = (P[:, bc.KEY7] - T[:, bc.KEY7]) / bc.iod(T)[:, None, None]        # (F, 7, 2)
    mean = E.mean(axis=0)
    return {"nme7_median": float(np.median(np.linalg.norm(E, axis=2).mean(axis=1)) * 100),
            "bias": (np.linalg.norm(mean, axis=1) * 100).round(3).tolist(),
            "signed_bias": (mean * 100).round(3).tolist(),
            "scatter": (np.linalg.norm(E - mean, axis=2).mean(axis=0) * 100).round(3).tolist()}


def smoothed_nme(P: np.ndarray, T: np.ndarray, sigmas=(1, 2, 4)) -> dict:
    from scipy.ndimage import gaussian_filter1d

    return {str(s): float(np.median(bc.nme(gaussian_filter1d(P, s, axis=0, mode="nearest"),
                                           T, bc.KEY7)) * 100) for s in sigmas}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--model", help="model (.npz); default: the default model")
    args = ap.parse_args()
    from facetransfer.default_model import load_default_model
    from facetransfer.model import load_model
    from facetransfer.track.capture import capture_video

    out = Path(args.out)
    cache = out / "capture_cache"
    model = load_model(args.model) if args.model else load_default_model()
    res = {}
    for clip in bc.synthetic_clips(cache, False):
        T = clip.landmarks
        with bc.filtered_stderr(True):
            mp = bc.run_mediapipe(clip.video, cache)["landmarks"]
            ours = capture_video(str(clip.video), model).landmarks2d
        gap = np.linalg.norm(ours[:, bc.KEY7] - mp[:, bc.KEY7], axis=2) / bc.iod(T)[:, None]
        res[clip.name] = {"ours": split_error(ours, T), "mediapipe": split_error(mp, T),
                          "ours_to_mediapipe": float(gap.mean() * 100),
                          "mediapipe_smoothed_nme7": smoothed_nme(mp, T)}
        print(clip.name, {k: round(v["nme7_median"], 2) for k, v in res[clip.name].items()
                          if isinstance(v, dict) and "nme7_median" in v},
              "ours-MP %.2f" % res[clip.name]["ours_to_mediapipe"])
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.io.atomic import save_figure, write_text_atomic

    write_text_atomic(out / "capture_bias.json", json.dumps(res, indent=1))
    save_figure(_plot(res), out / "capture_bias.png")
    print(f"wrote {out / 'capture_bias.json'} and {out / 'capture_bias.png'}")
    return 0


def _plot(res: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(res), figsize=(4.5 * len(res), 4), sharey=True)
    for ax, (name, r) in zip(np.atleast_1d(axes), res.items()):
        x = np.arange(len(POINTS))
        for k, (who, c) in enumerate((("ours", "tab:red"), ("mediapipe", "tab:blue"))):
            ax.bar(x + (k - 0.5) * 0.38, r[who]["bias"], 0.38, color=c, label=f"{who} bias")
            ax.plot(x + (k - 0.5) * 0.38, r[who]["scatter"], "k_", ms=12)
        ax.set_xticks(x, POINTS, rotation=60, fontsize=8)
        ax.set_title(f"{name}: NME ours {r['ours']['nme7_median']:.2f}, "
                     f"MP {r['mediapipe']['nme7_median']:.2f}", fontsize=9)
    np.atleast_1d(axes)[0].set_ylabel("% of eye distance (bars: bias; ticks: scatter)")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


if __name__ == "__main__":
    raise SystemExit(main())

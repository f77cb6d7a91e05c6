"""The exported curves' resting levels, as tracked and measured from a neutral frame
(``facetransfer export --neutral auto``), against Face Landmarker's blendshapes on the same
frames.

The four real clips of the data folder are tracked by the default capture tracker; Face
Landmarker (VIDEO mode, blendshapes: the peer, also the independent judge) scores the same
frames. Per clip and shape: the mean level over the clip (where a rig rests), the correlation
over frames and the amplitude ratio (std ours / std the peer's), as tracked and after the
neutral calibration of :mod:`facetransfer.export.neutral` with the automatic neutral frame.
Shapes: those issue 12 names (jawOpen, the blinks, smiles, browInnerUp, mouthFunnel,
mouthPucker) and the lids' eyeWide and eyeSquint.

Usage::

    python benchmarks/bench_neutral.py --out out/benchmarks

Writes ``OUT/neutral.json`` and ``OUT/neutral.png``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from _report import arguments, save_json, save_plot  # benchmarks/ is on sys.path

import numpy as np

CLIPS = ("WDA_KatieHill_000", "driving_d6", "driving_d9", "face_2")
SHAPES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight",
          "browInnerUp", "mouthFunnel", "mouthPucker", "eyeWideLeft", "eyeWideRight",
          "eyeSquintLeft", "eyeSquintRight")


def _r(a, b) -> float | None:
    return float(np.corrcoef(a, b)[0, 1]) if a.std() > 1e-6 and b.std() > 1e-6 else None


def measure(ours: np.ndarray, peer: np.ndarray) -> dict:
    """Per shape: mean levels, correlation, amplitude ratio over the frames both scored."""
    from facetransfer.arkit import ARKIT_NAMES

    out = {}
    for n in SHAPES:
        j = ARKIT_NAMES.index(n)
        ok = np.isfinite(ours[:, j]) & np.isfinite(peer[:, j])
        a, b = ours[ok, j].astype(float), peer[ok, j].astype(float)
        out[n] = {"mean": float(a.mean()), "peer_mean": float(b.mean()), "r": _r(a, b),
                  "amplitude": float(a.std() / b.std()) if b.std() > 1e-6 else None}
    return out


def clip_rows(name: str, data: Path, cache: Path, model) -> dict:
    from _mp_video import cached_landmarker, filtered_stderr  # benchmarks/ is on sys.path

    from facetransfer.export.neutral import calibrated, neutral_frame
    from facetransfer.track.capture import capture_video

    video = data / f"{name}.mp4"
    with filtered_stderr():
        _, scores = cached_landmarker(video, cache, shown=True)
        track = capture_video(str(video), model)
    a = np.asarray(track.blendshapes, np.float64)
    n = min(len(a), len(scores))
    a, s = a[:n], np.asarray(scores[:n], np.float64)
    i = neutral_frame(a, track.lost[:n])
    return {"frames": n, "neutral_frame": i, "tracked": measure(a, s),
            "calibrated": measure(calibrated(a, i), s)}


def summary(report: dict) -> dict:
    """Per shape and variant: the median over clips of |mean - peer mean|, r and amplitude."""
    out = {}
    for v in ("tracked", "calibrated"):
        out[v] = {}
        for n in SHAPES:
            rows = [c[v][n] for c in report["clips"].values()]
            gap = [abs(r["mean"] - r["peer_mean"]) for r in rows]
            rs = [r["r"] for r in rows if r["r"] is not None]
            amp = [r["amplitude"] for r in rows if r["amplitude"] is not None]
            out[v][n] = {"level_gap": float(np.median(gap)),
                         "r": float(np.median(rs)) if rs else None,
                         "amplitude": float(np.median(amp)) if amp else None}
    return out


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = report["summary"]
    x = np.arange(len(SHAPES))
    fig, ax = plt.subplots(figsize=(11, 3.8))
    for k, (v, label) in enumerate((("tracked", "as tracked"),
                                    ("calibrated", "--neutral auto"))):
        ax.bar(x + (k - 0.5) * 0.38, [s[v][n]["level_gap"] for n in SHAPES], 0.38, label=label)
    ax.set_xticks(x, SHAPES, rotation=35, ha="right", fontsize=8)
    ax.set_ylabel("|mean level - Face Landmarker's|\n(median over 4 clips)")
    ax.set_title("where the exported curves rest, against Face Landmarker on the same frames")
    ax.legend()
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from facetransfer.default_model import load_default_model

    data = Path(os.environ.get("FACETRANSFER_DATA_DIR", "../shared/data")) / "video"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = load_default_model()
    report = {"clips": {}}
    for name in CLIPS:
        report["clips"][name] = clip_rows(name, data, out / "neutral_cache", model)
        c = report["clips"][name]
        print(f"{name}: neutral frame {c['neutral_frame']}; " + ", ".join(
            f"{n} {c['tracked'][n]['mean']:.2f}->{c['calibrated'][n]['mean']:.2f} "
            f"(peer {c['tracked'][n]['peer_mean']:.2f})" for n in ("jawOpen", "eyeWideLeft",
                                                                   "mouthSmileLeft")), flush=True)
    report["summary"] = summary(report)
    for n in SHAPES:
        t, c = report["summary"]["tracked"][n], report["summary"]["calibrated"][n]
        print(f"  {n:16s} level gap {t['level_gap']:.3f} -> {c['level_gap']:.3f}; r "
              f"{t['r']} -> {c['r']}; amplitude {t['amplitude']} -> {c['amplitude']}")
    save_json(report, out / "neutral.json")
    plot(report, out / "neutral.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

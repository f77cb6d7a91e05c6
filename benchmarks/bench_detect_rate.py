"""What a transfer's expression source keeps with the detector shown fewer frames (issue 13's 10 s).

Each real clip of the data folder is captured three ways with the default model: the detector
shown every frame (the reference), every other frame (``every=2``, as a transfer's target), and
every other frame plus every frame where the eyes move (``every=2, eyes=True``,
:mod:`facetransfer.track.skip_rule`, a transfer's expression source). For each of the second and
third: the share of frames shown, the CPU seconds of the capture (in turn, after a warm-up), and
per activation the correlation with the reference over frames, the 99th percentiles (a blink's
peak) and the ratio of standard deviations.

    python benchmarks/bench_detect_rate.py --frames 300 --out out/benchmarks

Writes ``OUT/detect_rate.json`` and ``OUT/detect_rate.png``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import clip_benchmark  # noqa: E402

CLIPS = ("driving_d6", "driving_d9", "WDA_KatieHill_000", "face_2")
SHAPES = ("eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthSmileLeft", "browInnerUp",
          "mouthFunnel")
VARIANTS = {"every2": (2, False), "every2_eyes": (2, True)}


def _capture(frames, model, every: int, eyes: bool):
    """``(activations (F, 52), CPU seconds, share of frames shown)``."""
    from facetransfer.track.capture import capture_video
    from facetransfer.track.video_detect import detect_video

    t = time.process_time()
    det = detect_video(frames, workers=1, every=every, eyes=eyes)[0]
    tr = capture_video(frames, model, detections=det)
    share = 1.0 if det.shown is None else float(np.mean(det.shown))
    return np.asarray(tr.blendshapes, np.float64), time.process_time() - t, share


def _compare(ref: np.ndarray, got: np.ndarray) -> dict:
    """Per shape of :data:`SHAPES`: r, the two 99th percentiles, the std ratio."""
    from facetransfer.arkit import ARKIT_NAMES

    out = {}
    for name in SHAPES:
        j = list(ARKIT_NAMES).index(name)
        a, b = ref[:, j], got[:, j]
        out[name] = {"r": round(float(np.corrcoef(a, b)[0, 1]), 3),
                     "p99_every_frame": round(float(np.percentile(a, 99)), 3),
                     "p99": round(float(np.percentile(b, 99)), 3),
                     "std_ratio": round(float(b.std() / max(a.std(), 1e-9)), 3)}
    return out


def clip_rows(video: Path, model, frames: int) -> dict:
    """The three captures of ``video``'s first ``frames`` frames, compared (module notes)."""
    from facetransfer.io.video import read_video

    clip = read_video(video, max_frames=frames)[0]
    _capture(clip[:20], model, 1, False)                     # warm-up: kernels, landmarker
    ref, cpu_ref, _ = _capture(clip, model, 1, False)
    rows = {"every_frame": {"cpu_s": round(cpu_ref, 2)}}
    for name, (every, eyes) in VARIANTS.items():
        got, cpu, share = _capture(clip, model, every, eyes)
        rows[name] = {"cpu_s": round(cpu, 2), "shown": round(share, 3),
                      "shapes": _compare(ref, got)}
        print(f"{video.stem} {name}: shown {share:.2f}, {cpu:.2f} CPU-s (every frame "
              f"{cpu_ref:.2f}); " + ", ".join(f"{k} r {v['r']:.3f} p99 {v['p99_every_frame']:.2f}"
                                               f"->{v['p99']:.2f}"
                                               for k, v in rows[name]["shapes"].items()),
              flush=True)
    return rows


def plot(report: dict, path: Path) -> None:
    """Per clip, the blinks' 99th percentile (every frame, every other, with the eyes) and the
    CPU seconds of each capture."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from _report import save_plot

    clips = list(report["clips"])
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(clips))
    for k, (label, key) in enumerate((("every frame", None), ("every other", "every2"),
                                      ("every other + eyes", "every2_eyes"))):
        p99 = [np.mean([(report["clips"][c]["every2"]["shapes"][s]["p99_every_frame"]
                         if key is None else report["clips"][c][key]["shapes"][s]["p99"])
                        for s in ("eyeBlinkLeft", "eyeBlinkRight")]) for c in clips]
        cpu = [report["clips"][c]["every_frame" if key is None else key]["cpu_s"]
               for c in clips]
        ax.bar(x + 0.27 * (k - 1), p99, 0.27, label=label)
        bx.bar(x + 0.27 * (k - 1), cpu, 0.27, label=label)
    for a, title in ((ax, "eyeBlink L/R 99th percentile (mean)"),
                     (bx, "capture CPU seconds")):
        a.set_xticks(x, clips, rotation=15)
        a.set_title(title)
    ax.legend(fontsize=8)
    save_plot(fig, path)


if __name__ == "__main__":
    clip_benchmark(__doc__, "detect_rate", CLIPS, clip_rows, plot)

"""The eye region pasted where the reference frame shows what the clip usually does (issue 13).

The eye region of a transfer (:mod:`facetransfer.eyes`) is textured from one open-eyed target
frame. Where that frame shows something the clip usually does not show there (most often a
strand of the fringe over the brow's tail or the forehead), pasting it into every frame puts a
patch of hair on the forehead. :func:`facetransfer.region_weights.usual_weights` keeps the current
frame's texture at such vertices (away from the lids).

Truth without a judge: a **self-transfer**, the target's own track as the new performance,
must give back the target's frames. Each of the three target clips of
``bench_transfer_judge.py`` (the 150 frames of their cached tracks in ``OUT/judge_pairs/``) is
rewritten twice, with the rule (``usual``, the default) and without it (``always``: the
region pasted wherever the target's expression moved it, as before). On the pixels where the
two results differ (by more than 2 levels in a channel), the mean absolute error of each
against the target frame (RGB levels), and each whole frame's PSNR.

The rule only ever shows more of the current frame, which a self-transfer rewards; whether the
target's own expression comes back with it is the judge's question
(``bench_transfer_judge.py``: brows and blinks ~ target).

Usage::

    python benchmarks/bench_eye_rim.py --out out/benchmarks

Writes ``OUT/eye_rim.json``, ``OUT/eye_rim.png`` (error per clip) and ``OUT/eye_rim_CLIP.png``
(target | always | usual at the frame where they differ most).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from bench_transfer_judge import PAIRS, _track  # noqa: E402

#: A pixel counts as changed by the rule beyond this many levels in a channel.
CHANGED = 2


@contextlib.contextmanager
def _always():
    """The eye region without :func:`facetransfer.region_weights.usual_weights` (as before it)."""
    import facetransfer.eyes as eyes

    original = eyes.usual_weights      # the name eyes calls: every vertex usual
    eyes.usual_weights = lambda frames, track, model, verts, *a, **k: np.ones(len(verts),
                                                                              np.float32)
    try:
        yield
    finally:
        eyes.usual_weights = original


def self_transfer(frames, track, model) -> list[np.ndarray]:
    """The target's frames rewritten with its own performance (default options)."""
    from facetransfer.rewrite import rewrite_frames

    return [r.image for r in rewrite_frames(frames, track, track, model, workers=1,
                                            processes=False)]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def measure(clip: str, model, cache: Path, data: Path, out: Path) -> dict:
    from facetransfer.io.video import iter_frames
    from facetransfer.track.result import Track

    track = Track.load(_track(clip, model, cache, data))
    frames = [f for f, _ in zip(iter_frames(data / f"{clip}.mp4"), range(track.n_frames))]
    t = time.perf_counter()
    usual = self_transfer(frames, track, model)
    with _always():
        always = self_transfer(frames, track, model)
    seconds = time.perf_counter() - t
    err_u, err_a, changed, psnr_u, psnr_a = [], [], [], [], []
    for f, u, a in zip(frames, usual, always):
        m = np.abs(u.astype(np.int16) - a).max(axis=-1) > CHANGED
        changed.append(int(m.sum()))
        if m.any():
            err_u.append(np.abs(u[m].astype(np.float64) - f[m]).mean())
            err_a.append(np.abs(a[m].astype(np.float64) - f[m]).mean())
        psnr_u.append(psnr(u, f))
        psnr_a.append(psnr(a, f))
    k = int(np.argmax(changed))
    _picture(clip, frames[k], always[k], usual[k], k, out / f"eye_rim_{clip}.png")
    return {"frames": len(frames), "seconds": seconds,
            "changed_pixels_mean": float(np.mean(changed)),
            "frames_changed": int(np.count_nonzero(changed)),
            "mae_changed": {"usual": float(np.mean(err_u)) if err_u else 0.0,
                            "always": float(np.mean(err_a)) if err_a else 0.0},
            "psnr_frame_median": {"usual": float(np.median(psnr_u)),
                                  "always": float(np.median(psnr_a))}}


def _picture(clip, target, always, usual, k, path: Path) -> None:
    import cv2

    from facetransfer.io.atomic import atomic_path

    row = np.concatenate([target, always, usual], axis=1)
    cv2.putText(row, f"{clip} frame {k}: target | always | usual", (8, 24),
                cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 2)
    with atomic_path(path, overwrite=True) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(row, cv2.COLOR_RGB2BGR))


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    clips = list(res)
    x = np.arange(len(clips))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for j, (v, c) in enumerate((("always", "#fc9272"), ("usual", "#3182bd"))):
        ax.bar(x - 0.2 + 0.4 * j, [res[c_]["mae_changed"][v] for c_ in clips], 0.4, color=c,
               label=v)
    ax.set_xticks(x, clips)
    ax.set_ylabel("mean |result - target| (levels)")
    ax.set_title("self-transfer: the pixels the rule changes, against the target frame")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    args = ap.parse_args()
    out = Path(args.out)
    (out / "judge_pairs").mkdir(parents=True, exist_ok=True)
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    data = Path(data_dir()) / "video"
    model = load_default_model()
    res = {}
    for _, clip in PAIRS.values():
        res[clip] = r = measure(clip, model, out / "judge_pairs", data, out)
        print(f"{clip}: {r['frames_changed']}/{r['frames']} frames changed, "
              f"{r['changed_pixels_mean']:.0f} px a frame; error there always "
              f"{r['mae_changed']['always']:.2f} -> usual {r['mae_changed']['usual']:.2f}; "
              f"PSNR {r['psnr_frame_median']['always']:.2f} -> "
              f"{r['psnr_frame_median']['usual']:.2f} dB", flush=True)
    with atomic_path(out / "eye_rim.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(res, indent=2))
    plot(res, out / "eye_rim.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

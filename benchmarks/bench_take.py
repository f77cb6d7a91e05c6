"""A Live Link Face take as the expression source of a transfer, judged as a video source is.

``facetransfer transfer --target T.mp4 --expression-from take.csv`` (:mod:`facetransfer.take`)
makes the target perform a take's ARKit activations with no source pictures: the mouth's
texture comes from the target's own frames. Is the performance carried as well as from the
source video itself? For each real pair of ``bench_transfer_judge.py`` (the demo pair, the pair
at different frame rates, the open-mouth target), the source clip's capture (the default
tracker, its first 150 frames, cached) is written as a Live Link Face CSV by the project's
exporter, and the same target is rendered twice from the same target track: from the source
video (``video``, the default transfer) and from the take (``take``). The independent judge,
Face Landmarker on the source (the frame matched by time), the target and each result, gives
per measure the correlation over frames of the result with the source and with the target and
the amplitude (the result's standard deviation over the source's).

The take here comes from the project's own capture of the source video, not from the app:
what it measures is the take path (timecodes, resampling, activations to weights, the
target-textured mouth) against the video path on the same performance; an iPhone's ARKit
activations of the same performance would differ as two trackers do.

Usage::

    python benchmarks/bench_take.py --out out/benchmarks [--pairs demo,fps,open]

Writes ``OUT/take.json`` and ``OUT/take.png``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_transfer_judge as judge  # noqa: E402
from _report import save_json  # noqa: E402

#: The measures reported (the judge's names): the mouth, the eyes, the brows, a smile.
REPORTED = ("jawOpen", "mouth_opening", "mouthSmileLeft", "mouthPucker", "eyeBlinkLeft",
            "eyeBlinkRight", "browInnerUp", "brow_height_left", "gaze_horizontal")


def _render(plan, model, mouth: str | None = None) -> tuple[list, float]:
    """The rewritten frames of a plan (before encoding) and the render's seconds (``mouth``:
    the mouth's texture, :class:`~facetransfer.rewrite_options.RewriteOptions`; None: the
    default)."""
    from facetransfer import video_transfer as vt
    from facetransfer.rewrite_options import RewriteOptions

    frames: list[np.ndarray] = []
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        vt.render_plan(plan, model, vt.RenderTarget(Path(tmp) / "r.mp4", overwrite=True),
                       options=RewriteOptions(mouth=mouth),
                       compose=lambda i, r: frames.append(r.image) or r.image)
    return frames, time.perf_counter() - t


def take_pair(name: str, model, out: Path, data: Path, n: int = judge.FRAMES) -> dict:
    """One pair rendered from its source video and from its take, both judged."""
    from facetransfer import transfer_plan as tp
    from facetransfer.export.common import head_euler
    from facetransfer.export.livelink import write_livelink
    from facetransfer.io.video import video_info
    from facetransfer.track import Track

    src, tgt = judge.PAIRS[name]
    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    tt, st = (judge._track(c, model, cache, data) for c in (tgt, src))
    take = write_livelink(Track.load(st), cache / f"{src}.take.csv", overwrite=True)
    common = dict(max_frames=n, target_track=tt)
    video = tp.plan_transfer(data / f"{tgt}.mp4", model, expression_from=data / f"{src}.mp4",
                             expression_track=st, **common)
    taken = tp.plan_transfer(data / f"{tgt}.mp4", model, expression_from=take, **common)
    m = min(video.n_frames, taken.n_frames)
    results, seconds = {}, {}
    for kind, plan, mouth in (("video", video, None), ("take", taken, None),
                              ("take_frame", taken, "frame"), ("take_function", taken,
                                                                 "function")):
        results[kind], seconds[kind] = _render(plan, model, mouth)
    sar = {c: video_info(data / f"{c}.mp4").sar for c in (src, tgt)}
    source = [video.mouth_frames[video.mouth_index[i]] for i in range(m)]
    S = judge.scores(source, video.fps, sar[src])
    T = judge.scores([video.target_frames[i] for i in range(m)], video.fps, sar[tgt])
    pose = np.degrees(head_euler(video.target_track.rotation[:m])[:, [1, 0]])
    judged = {k: judge.compare(S, T, judge.scores(v[:m], video.fps, sar[tgt]), pose)
              for k, v in results.items()}
    box = _mouth_box(video.new_track.landmarks2d[:m, 48:68], video.target_frames[0].shape)
    flicker = {k: mouth_flicker(v[:m], box) for k, v in results.items()}
    flicker["target"] = mouth_flicker([video.target_frames[i] for i in range(m)], box)
    return {"source": src, "target": tgt, "frames": m, "render_seconds": seconds,
            "mouth_flicker": flicker, **judged}


def _mouth_box(lips: np.ndarray, shape) -> tuple[slice, slice]:
    """The box (rows, columns) holding every frame's mouth points ``lips`` (F, 20, 2), grown by
    a fifth of its size, within a frame of ``shape``."""
    lo, hi = np.nanmin(lips, axis=(0, 1)), np.nanmax(lips, axis=(0, 1))
    pad = 0.2 * (hi - lo)
    (x0, y0), (x1, y1) = np.floor(lo - pad).astype(int), np.ceil(hi + pad).astype(int)
    return slice(max(y0, 0), min(y1, shape[0])), slice(max(x0, 0), min(x1, shape[1]))


def mouth_flicker(frames, box: tuple[slice, slice]) -> float:
    """Mean absolute second difference over time, in levels, of the pixels in ``box``:
    ``|I_t - (I_{t-1} + I_{t+1}) / 2|``. Smooth motion costs little; a texture that changes
    from one frame to the next and back (a mouth taken from another frame) a lot."""
    a = np.stack([np.asarray(f)[box] for f in frames]).astype(np.float32)
    return float(np.abs(a[1:-1] - 0.5 * (a[:-2] + a[2:])).mean())


KINDS = ("video", "take", "take_frame", "take_function")


def _line(name: str, r: dict) -> str:
    cells = []
    for k in REPORTED:
        rs = "/".join(f"{r[c][k]['result_source']:+.2f}" for c in KINDS)
        amp = "/".join(f"{r[c][k]['amplitude']:.2f}" for c in KINDS)
        cells.append(f"{k} {rs} (amp {amp})")
    jaw = "/".join(f"{r[c]['jawOpen']['result_target']:+.2f}" for c in KINDS)
    return (f"{name}: result ~ source, {' / '.join(KINDS)}: " + "; ".join(cells)
            + f"; jawOpen ~ target {jaw}; render seconds "
            + "/".join(f"{r['render_seconds'][c]:.1f}" for c in KINDS)
            + "; mouth flicker (levels) " + "/".join(f"{r['mouth_flicker'][c]:.2f}"
                                                     for c in KINDS + ("target",)))


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, axes = plt.subplots(len(res), 1, figsize=(11, 3.0 * len(res)), squeeze=False)
    x = np.arange(len(REPORTED))
    for ax, (name, r) in zip(axes[:, 0], res.items()):
        for j, (kind, c) in enumerate((("video", "#6baed6"), ("take", "#08519c"))):
            ax.bar(x - 0.2 + 0.4 * j, [r[kind][k]["result_source"] for k in REPORTED], 0.4,
                   color=c, label=f"from the {kind}: result ~ source")
        judge.decorate(ax, REPORTED, f"{name}: {r['source']} -> {r['target']} "
                       f"({r['frames']} frames)", target_line=False)
    axes[0, 0].legend(fontsize=8, loc="lower left")
    fig.suptitle("a transfer driven by the source video and by its Live Link Face take, "
                 "judged by Face Landmarker")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--pairs", default=",".join(judge.PAIRS))
    ap.add_argument("--frames", type=int, default=judge.FRAMES)
    args = ap.parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model, data = load_default_model(), Path(data_dir()) / "video"
    res = {}
    for name in args.pairs.split(","):
        res[name] = take_pair(name, model, out, data, args.frames)
        print(_line(name, res[name]), flush=True)
    save_json(res, out / "take.json")
    plot(res, out / "take.png")
    print(f"wrote {out / 'take.json'}, {out / 'take.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

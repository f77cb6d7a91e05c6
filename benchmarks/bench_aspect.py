"""Capture of videos whose pixels are not square, against the same clips in square pixels.

Archive and broadcast video often stores pixels that are shown wider or narrower than tall
(HDV 1440x1080 shown 1920x1080; DV 720x480 at 10:11). For each real clip of the data folder
(first ``--frames`` frames), this script writes it losslessly in square pixels, squeezed to 4/5
of its width with a sample aspect ratio of 5:4, and stretched to 4/3 of its width at 3:4 (all
three shown alike), then tracks every version with the default ``facetransfer`` capture and
compares each with the square clip's track:

* ``ours``: the capture as it is (the frames resampled to square pixels for detection and fit,
  :mod:`facetransfer.track.aspect`);
* ``stored``: the same capture told to ignore the aspect (``view=View()``: how every version
  before the twenty-fifth session tracked such a clip);
* the peer, Face Landmarker in VIDEO mode, run on the stored frames as any caller of MediaPipe
  would (its blendshapes against its own on the square clip).

Per clip and version: mean absolute difference of the ARKit activations over the mouth's,
jaw's, eyes' and brows' 14 channels, and of jawOpen alone; the identity weights' largest
difference (ours and ``stored``).

Interlaced video too (DV, HDV and broadcast are): ``2 --frames`` frames of each clip woven in
pairs into interlaced ones (the first of a pair gives the top field, shown first; H.264 coded
interlaced, lossless, at half the rate) against the progressive frames of those first fields:
``ours`` (the tracker shown the first field), ``woven`` (shown the woven frames,
``view=View()``), and Face Landmarker on the woven frames against itself on the first fields.
(Before the twenty-fifth session OpenCV read such a file as black frames: no face at all.)

Writes ``OUT/aspect.json`` and ``OUT/aspect.png``::

    PYTHONPATH=src FACETRANSFER_DATA_DIR=... python benchmarks/bench_aspect.py --out out/benchmarks
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _mp_video import run_landmarker  # noqa: E402
from _report import clip_benchmark, save_plot  # noqa: E402

CHANNELS = ("jawOpen", "mouthSmileLeft", "mouthSmileRight", "mouthPucker", "mouthFunnel",
            "mouthStretchLeft", "mouthStretchRight", "mouthPressLeft", "mouthPressRight",
            "eyeBlinkLeft", "eyeBlinkRight", "eyeWideLeft", "browInnerUp", "browDownLeft")
CLIPS = ("driving_d6", "driving_d9", "WDA_KatieHill_000", "face_2")
#: (name, factor of the width, sample aspect ratio): each shown as the square clip
VERSIONS = (("squeezed 5:4", 0.8, (5, 4)), ("stretched 3:4", 4 / 3, (3, 4)))


def _versions(clip: Path, n: int, d: Path) -> dict:
    """The clip's first ``n`` frames, square, then each of :data:`VERSIONS`, losslessly."""
    import cv2

    from facetransfer.io.video import VideoOptions, read_video, video_info, write_video

    frames, fps = read_video(clip, max_frames=n)
    if video_info(clip).sar != (1, 1):       # shown shape first: the square clip is the truth
        from facetransfer.track.aspect import display_frames, video_aspect

        frames = np.stack(list(display_frames(frames, video_aspect(clip))))
    out = {"square": d / "square.mkv"}
    write_video(out["square"], frames, fps, options=VideoOptions(crf=0))
    H, W = frames.shape[1:3]
    for name, k, sar in VERSIONS:
        w = int(round(W * k))
        mode = cv2.INTER_AREA if k < 1 else cv2.INTER_CUBIC
        v = np.stack([cv2.resize(f, (w, H), interpolation=mode) for f in frames])
        out[name] = d / f"{name.split()[0]}.mkv"
        write_video(out[name], v, fps, options=VideoOptions(crf=0, sar=sar))
    return out


def _columns(names) -> list[int]:
    return [list(names).index(c) for c in CHANNELS]


def _interlaced(clip: Path, n: int, d: Path) -> tuple[Path, Path]:
    """``2 n`` frames of a clip woven into ``n`` interlaced ones (top field first) and the
    ``n`` progressive frames of their first fields, both lossless, at half the clip's rate."""
    from facetransfer.io.video import VideoOptions, read_video, write_video

    frames, fps = read_video(clip, max_frames=2 * n)
    firsts = frames[0::2][: len(frames) // 2]
    woven = firsts.copy()
    woven[:, 1::2] = frames[1::2][: len(woven), 1::2]
    paths = d / "firsts.mkv", d / "woven.mp4"
    write_video(paths[0], firsts, fps / 2, options=VideoOptions(crf=0))
    write_video(paths[1], woven, fps / 2, options=VideoOptions(crf=0, field="top"))
    return paths


def _peer(path: Path) -> np.ndarray:
    """Face Landmarker's blendshapes on a clip decoded by ``facetransfer`` (OpenCV, which
    :func:`run_landmarker` reads a path with, returns an interlaced H.264's frames black)."""
    from facetransfer.io.video import read_video

    frames, fps = read_video(path)
    return run_landmarker(list(frames), fps=fps)[1]


def _interlaced_row(clip: Path, model, n: int, cols: list[int]) -> dict:
    from facetransfer.track.aspect import View
    from facetransfer.track.capture import capture_video

    with tempfile.TemporaryDirectory() as tmp:
        firsts, woven = _interlaced(clip, n, Path(tmp))
        ref = capture_video(firsts, model)
        ours = capture_video(woven, model)
        flat = capture_video(woven, model, view=View())
        row = {"ours": _compare(ours.blendshapes, ref.blendshapes, cols),
               "stored": _compare(flat.blendshapes, ref.blendshapes, cols),
               "face_landmarker": _compare(_peer(woven), _peer(firsts), cols)}
    print(f"{clip.stem:18s} interlaced     ours {row['ours']['mean_abs']:.3f}  woven "
          f"{row['stored']['mean_abs']:.3f}  Face Landmarker "
          f"{row['face_landmarker']['mean_abs']:.3f}", flush=True)
    return row


def _compare(a: np.ndarray, b: np.ndarray, cols: list[int]) -> dict:
    ok = np.isfinite(a[:, cols]).all(1) & np.isfinite(b[:, cols]).all(1)
    d = np.abs(a[ok][:, cols] - b[ok][:, cols])
    return {"mean_abs": float(d.mean()), "jawOpen_mean_abs": float(d[:, 0].mean()),
            "jawOpen_r": float(np.corrcoef(a[ok][:, cols[0]], b[ok][:, cols[0]])[0, 1])}


def _clip_rows(clip: Path, model, n: int) -> dict:
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.aspect import View
    from facetransfer.track.capture import capture_video

    cols = _columns(ARKIT_NAMES)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = _versions(clip, n, Path(tmp))
        ref = capture_video(paths["square"], model)
        mp_ref = run_landmarker(paths["square"])[1]
        for name, _, _ in VERSIONS:
            ours = capture_video(paths[name], model)
            stored = capture_video(paths[name], model, view=View())
            peer = run_landmarker(paths[name])[1]
            rows[name] = {
                "pixel_aspect": ours.pixel_aspect,
                "ours": _compare(ours.blendshapes, ref.blendshapes, cols),
                "stored": _compare(stored.blendshapes, ref.blendshapes, cols),
                "face_landmarker": _compare(peer, mp_ref, cols),
                "identity_max_abs": {
                    "ours": float(np.abs(ours.weights["identity"][0]
                                         - ref.weights["identity"][0]).max()),
                    "stored": float(np.abs(stored.weights["identity"][0]
                                           - ref.weights["identity"][0]).max()),
                    "scale": float(np.abs(ref.weights["identity"][0]).max())},
                "head_scale_ratio": {"ours": float(np.median(ours.scale / ref.scale)),
                                     "stored": float(np.median(stored.scale / ref.scale))}}
            print(f"{clip.stem:18s} {name:14s} ours {rows[name]['ours']['mean_abs']:.3f}  "
                  f"stored {rows[name]['stored']['mean_abs']:.3f}  Face Landmarker "
                  f"{rows[name]['face_landmarker']['mean_abs']:.3f}", flush=True)
    rows["interlaced"] = _interlaced_row(clip, model, n, cols)
    return rows


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels, series = [], {"ours": [], "stored": [], "face_landmarker": []}
    for clip, rows in report["clips"].items():
        for name, row in rows.items():
            labels.append(f"{clip}\n{name}")
            for k in series:
                series[k].append(row[k]["mean_abs"])
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(max(8, 1.1 * len(labels)), 4.5))
    names = {"ours": "ours (square pixels; interlaced: the first field)",
             "stored": "ours, stored pixels (interlaced: the woven frames)",
             "face_landmarker": "Face Landmarker on the stored (woven) frames"}
    for j, (k, v) in enumerate(series.items()):
        ax.bar(x + (j - 1) * 0.27, v, 0.27, label=names[k])
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("mean |activation - square clip's|")
    ax.set_title("ARKit activations of non-square-pixel copies against the square clip")
    ax.legend(fontsize=8)
    save_plot(fig, path)


def main() -> None:
    clip_benchmark(__doc__, "aspect", CLIPS, _clip_rows, _plot, channels=list(CHANNELS),
                   versions=[{"name": n, "width_factor": k, "sar": list(s)}
                             for n, k, s in VERSIONS])


if __name__ == "__main__":
    main()

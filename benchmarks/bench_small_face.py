"""Capture of small faces in large frames (a medium-wide shot), against the same clips framed
close.

Face Landmarker looks for a face in the whole frame shrunk to 128x128, so a face under about a
tenth of the frame's height is never found. For each real clip of the data folder (first
``--frames`` frames), this script shrinks the frames by each of :data:`SCALES` and pastes them
off-centre into grey 1920x1080 frames (H.264, CRF 12: a camera's wide shot of the same
performance; the face then spans 60-140 pixels), tracks them with the default ``facetransfer``
capture (:mod:`facetransfer.track.face_crop`: found in tiles, followed in a crop) and compares
with the capture of the close clip:

* frames where a face was found: ours, and the peer, Face Landmarker in VIDEO mode on the same
  wide frames;
* the ARKit activations (mean absolute difference over the mouth's, jaw's, eyes' and brows' 14
  channels, jawOpen's correlation) against the close clip's capture;
* the tracked 68 points, taken back to the close clip's pixels, against Face Landmarker's on the
  close frames (median over frames of the mean distance, in eye distances: the NME), with ours
  on the close clip itself as the floor.

Writes ``OUT/small_face.json`` and ``OUT/small_face.png``::

    PYTHONPATH=src FACETRANSFER_DATA_DIR=... python benchmarks/bench_small_face.py --out out/benchmarks
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _mp_video import run_landmarker  # noqa: E402
from _report import clip_benchmark, save_plot  # noqa: E402
from bench_aspect import CHANNELS, CLIPS, _columns, _compare  # noqa: E402

#: Shrink factors of the close clips' frames (480-844 pixels square) in a 1920x1080 frame.
SCALES = (0.3, 0.18)
FRAME = (1920, 1080)
AT = (1180, 330)


def _wide(clip: Path, n: int, scale: float, path: Path) -> tuple[float, float]:
    """The clip's first ``n`` frames shrunk by ``scale`` into grey :data:`FRAME` frames at
    :data:`AT` (scaled to a 480-pixel clip's), written to ``path``; returns ``(shrink, fps)``:
    the factor from the close clip's pixels to the wide frame's."""
    import cv2

    from facetransfer.io.video import VideoOptions, read_video, write_video

    frames, fps = read_video(clip, max_frames=n)
    k = scale * 480 / frames.shape[1]
    W, H = FRAME
    out = np.full((len(frames), H, W, 3), 118, np.uint8)
    for i, f in enumerate(frames):
        s = cv2.resize(f, None, fx=k, fy=k, interpolation=cv2.INTER_AREA)
        out[i, AT[1]:AT[1] + s.shape[0], AT[0]:AT[0] + s.shape[1]] = s
    write_video(path, out, fps, options=VideoOptions(crf=12))
    return k, fps


def _nme(points: np.ndarray, ref: np.ndarray) -> float:
    """Median over frames of the 68 points' mean distance to ``ref``'s, in ``ref``'s outer
    eye-corner distances (frames where both have points)."""
    ok = np.isfinite(points).all((1, 2)) & np.isfinite(ref).all((1, 2))
    eyes = np.linalg.norm(ref[ok, 36] - ref[ok, 45], axis=1)
    return float(np.median(np.linalg.norm(points[ok] - ref[ok], axis=2).mean(1) / eyes))


def _clip_rows(clip: Path, model, n: int) -> dict:
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.capture import capture_video
    from facetransfer.track.landmarks import mediapipe_to_ibug
    from facetransfer.track.project import project_landmarks

    cols = _columns(ARKIT_NAMES)
    close = project_landmarks(capture_video(clip, model, max_frames=n), model)
    mp_close = run_landmarker(clip)[0][:close.n_frames]
    ref68 = np.stack([mediapipe_to_ibug(p) for p in mp_close])
    rows = {"floor_nme": _nme(close.landmarks2d, ref68)}
    with tempfile.TemporaryDirectory() as tmp:
        for scale in SCALES:
            path = Path(tmp) / f"wide_{scale}.mp4"
            k, _ = _wide(clip, n, scale, path)
            t = time.perf_counter()
            ours = project_landmarks(capture_video(path, model), model)
            seconds = time.perf_counter() - t
            peer = run_landmarker(path)[0]
            back = (ours.landmarks2d - AT) / k
            face = float(np.nanmedian(np.ptp(ref68[..., 1], axis=1)) * k)
            rows[f"x{scale}"] = {
                "face_pixels": face,
                "found": {"ours": float((~ours.lost).mean()),
                          "face_landmarker": float(np.isfinite(peer).all((1, 2)).mean())},
                "ours": _compare(ours.blendshapes, close.blendshapes, cols),
                "nme": _nme(back, ref68), "seconds_per_frame": seconds / ours.n_frames}
            r = rows[f"x{scale}"]
            print(f"{clip.stem:18s} x{scale:<5} face {face:5.0f} px  found ours "
                  f"{r['found']['ours']:.2f} / Face Landmarker {r['found']['face_landmarker']:.2f}"
                  f"  activations {r['ours']['mean_abs']:.3f} (jaw r {r['ours']['jawOpen_r']:.2f})"
                  f"  NME {r['nme']:.3f} (floor {rows['floor_nme']:.3f})", flush=True)
    return rows


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = [f"{c}\nx{s}" for c in report["clips"] for s in SCALES]
    x = np.arange(len(labels))
    rows = [report["clips"][c][f"x{s}"] for c in report["clips"] for s in SCALES]
    axes[0].bar(x - 0.2, [r["found"]["ours"] for r in rows], 0.4, label="ours")
    axes[0].bar(x + 0.2, [r["found"]["face_landmarker"] for r in rows], 0.4,
                label="Face Landmarker (whole frame)")
    axes[0].set_ylabel("share of frames with a face")
    axes[0].set_ylim(0, 1.3)
    axes[1].bar(x - 0.2, [r["nme"] for r in rows], 0.4, label="ours, wide shot")
    axes[1].bar(x + 0.2, [report["clips"][c]["floor_nme"] for c in report["clips"]
                          for _ in SCALES], 0.4, label="ours, close clip (floor)")
    axes[1].set_ylabel("68-point NME (Face Landmarker, close clip)")
    for ax in axes:
        ax.set_xticks(x, labels, fontsize=7, rotation=30, ha="right")
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle("Small faces in 1920x1080 frames")
    save_plot(fig, path)


def main() -> None:
    clip_benchmark(__doc__, "small_face", CLIPS, _clip_rows, _plot, channels=list(CHANNELS),
                   frame=list(FRAME), scales=list(SCALES))


if __name__ == "__main__":
    main()

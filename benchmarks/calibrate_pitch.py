"""Calibrate the capture's detector pitch gain (issue 12): how much too small Face Landmarker
shows a head's pitch, and what the capture should divide its fitted pitch by.

On the calibration clips of ``calibrate_landmarks.py`` (the benchmark's generator and painter,
identity / performance seeds disjoint from ``bench_capture.py``'s: :func:`calibration_specs`
checks it), three measurements:

1. **the detector's gain**: per clip, a rigid weak-perspective pose of the *true* 3-D landmarks
   fitted to Face Landmarker's 68 points and to the true 68 points; the slope of the first
   pitch against the second (pitch ``a`` of ``R = Rx(a) Ry Rz``, about the camera's x axis);
2. **the capture's gain**: the slope of the capture's pitch on Face Landmarker's detections
   against its pitch on the true points (``pitch_gain=1``; clip-centred, pooled);
3. **the capture's error** at each candidate ``pitch_gain``: 7- and 51-point NME (median over
   frames, % of the true eye-corner distance), mean over the clips, against Face Landmarker
   through the calibrated mapping. The default
   (:data:`~facetransfer.track.capture.DETECTOR_PITCH_GAIN`) is the gain with the smallest sum
   of the two means.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/calibrate_pitch.py [--out out/benchmarks]
        [--clips 16] [--frames 48] [--gains 1,0.95,0.92,0.9,0.88,0.86,0.82]

Paints and detects the clips the first time (about 3 minutes, cached in ``OUT/capture_cache``
with ``calibrate_landmarks.py``'s); writes ``OUT/calibrate_pitch.json``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _capture_data as cd  # noqa: E402
import bench_capture as bc  # noqa: E402
from _mp_video import filtered_stderr  # noqa: E402
from calibrate_landmarks import calibration_specs  # noqa: E402

log = logging.getLogger("calibrate_pitch")


def pitch(R: np.ndarray) -> np.ndarray:
    """Pitch ``a`` (degrees) of ``R = Rx(a) Ry Rz``, (..., 3, 3) -> (...)."""
    return np.degrees(np.arctan2(-R[..., 1, 2], R[..., 2, 2]))


def rigid_pitch(X: np.ndarray, p: np.ndarray, w: np.ndarray) -> float:
    """Pitch of the weak-perspective pose of the 3-D points ``X`` (68, 3) best fitting ``p``."""
    from facetransfer.track.camera import fit_affine_pose
    from facetransfer.track.fit2d import Targets, pose_gauss_newton

    pose = fit_affine_pose(X, p)
    pose = pose_gauss_newton(X, Targets.stack([(p, w)], w), pose,
                             float(np.linalg.norm(p[36] - p[45])), iterations=6)
    return float(pitch(pose.rotation))


def load_clips(cache: Path, n_clips: int, n_frames: int) -> list[dict]:
    """Per calibration clip: detections (Face Landmarker in VIDEO mode and flow), the truth."""
    from facetransfer.track.video_detect import detect_video

    fk = cd.facekit_loader(cache)
    out = []
    for spec in calibration_specs(n_clips, n_frames):
        clip = cd.load_clip(cache, spec, fk_loader=fk)
        with filtered_stderr(True):
            det, fps, size, _ = detect_video(str(clip.video))
        out.append({"name": spec.name, "det": det, "fps": fps, "size": size,
                    "truth": clip.landmarks.astype(np.float64), "vertices": clip.vertices})
        log.info("clip %s ready", spec.name)
    return out


def gains(clips: list[dict], model) -> dict:
    """Measurements 1 and 2 of the module notes."""
    from facetransfer.track.capture import (CaptureOptions, capture_detections,
                                            capture_point_weights)
    from facetransfer.track.detect import ClipDetections

    w = capture_point_weights()
    lm = np.asarray(model.landmarks)
    det_gain, fit, floor = [], [], []
    exact = CaptureOptions(pitch_gain=1.0)
    for c in clips:
        X = c["vertices"][:, lm].astype(np.float64)
        t = [rigid_pitch(X[f], c["truth"][f], w) for f in range(len(X))]
        m = [rigid_pitch(X[f], c["det"].points[f], w) for f in range(len(X))]
        det_gain.append(float(np.polyfit(t, m, 1)[0]))
        a = pitch(capture_detections(c["det"], model, options=exact).rotation)
        b = pitch(capture_detections(ClipDetections.from_points(c["truth"]), model,
                                     options=exact).rotation)
        fit.append(a - a.mean())
        floor.append(b - b.mean())
    A, B = np.concatenate(fit), np.concatenate(floor)
    return {"detector_gain_per_clip": np.round(det_gain, 3).tolist(),
            "detector_gain_median": round(float(np.median(det_gain)), 3),
            "capture_gain_pooled": round(float(A @ B / (B @ B)), 3)}


def errors(clips: list[dict], model, candidates) -> dict:
    """Measurement 3 of the module notes: mean 7- and 51-point NME per candidate gain."""
    from facetransfer.track.capture import CaptureOptions, capture_detections

    med = lambda P, T, idx: float(np.median(bc.nme(P, T, idx)) * 100)  # noqa: E731
    res = {"mediapipe": {"nme7": np.mean([med(c["det"].points, c["truth"], bc.KEY7)
                                           for c in clips]),
                         "nme51": np.mean([med(c["det"].points, c["truth"], bc.INNER51)
                                           for c in clips])}}
    for g in candidates:
        n7, n51 = [], []
        for c in clips:
            tr = capture_detections(c["det"], model, options=CaptureOptions(pitch_gain=g),
                                    fps=c["fps"], frame_size=c["size"])
            n7.append(med(tr.landmarks2d, c["truth"], bc.KEY7))
            n51.append(med(tr.landmarks2d, c["truth"], bc.INNER51))
        res[f"{g:g}"] = {"nme7": float(np.mean(n7)), "nme51": float(np.mean(n51)),
                         "nme7_per_clip": np.round(n7, 3).tolist()}
        log.info("pitch_gain %g: 7-pt %.3f, 51-pt %.3f", g, res[f"{g:g}"]["nme7"],
                 res[f"{g:g}"]["nme51"])
    return {k: {kk: (round(vv, 3) if isinstance(vv, float) else vv) for kk, vv in v.items()}
            for k, v in res.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--clips", type=int, default=16)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--gains", default="1,0.95,0.92,0.9,0.88,0.86,0.82")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s",
                        datefmt="%H:%M:%S")
    from facetransfer.default_model import load_default_model

    out = Path(args.out)
    model = load_default_model()
    clips = load_clips(out / "capture_cache", args.clips, args.frames)
    res = gains(clips, model) | {"nme": errors(clips, model,
                                               [float(g) for g in args.gains.split(",")])}
    cand = {k: v for k, v in res["nme"].items() if k != "mediapipe"}
    res["best_sum"] = min(cand, key=lambda k: cand[k]["nme7"] + cand[k]["nme51"])
    print(json.dumps(res, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    (out / "calibrate_pitch.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark of issue 12: performance capture, side by side with MediaPipe Face Landmarker.

Measures, in one run, every tracker on the same frames:

1. ``synthetic``: clips painted by OpenCV (``_cvpaint``: polygons back to front, not
   ``facetransfer.render``) of fresh ICT-FaceKit identities that are not in the model's training
   set, with ARKit performances (blinks, jaw, smiles, brows, pucker/funnel) and head yaw / pitch up
   to ±30° from frame 0 on (``_capture_data``). Per clip and tracker: median and mean 7-point NME
   (iBUG 36, 39, 42, 45, 30, 48, 54) and 51-point NME (iBUG 17-67), normalised by the true outer
   eye-corner distance (36-45) per frame; 3-D vertex error in mm over the narrow face area
   (FaceKit vertices 0-6705) after a per-frame similarity alignment (Umeyama: rotation,
   translation, scale) of the tracked face to the true one; activation mean absolute error over
   MediaPipe's 51 shapes and per key shape; correlation over frames of eye and mouth opening.
   Trackers: ``mediapipe`` (Face Landmarker, VIDEO mode, blendshapes, its points mapped to iBUG
   by ``mediapipe_to_ibug``, the calibrated correspondence), ``mediapipe_table`` (the same
   through the uncalibrated table ``MP_TO_IBUG``), ``ours`` (the default
   tracker, ``capture_video``), ``klt`` (the paper's tracker, ``track_video`` with default
   options), ``floor`` (the model fitted to the true 68 points on every frame by
   ``fit_landmarks``), ``capfloor`` (the capture tracker's own fit to the true 68 points: the
   floor of ``ours``, its model and priors, without MediaPipe's errors).
2. ``real``: clips of ``FACETRANSFER_DATA_DIR/video`` against their stored MediaPipe references:
   correlation and std ratio (ours / reference) of mouth opening, mouth width, eye opening and brow
   height (each / outer eye-corner distance) and of our activations against MediaPipe's
   blendshapes; drift and jitter on ``driving_d6``; gaze: Face Landmarker's eyeLook* against the
   iris offsets of its own points 468-477 and against our eyeLook* activations.
3. ``speed``: whole-process wall time of ``facetransfer track`` against a process running Face
   Landmarker in VIDEO mode over the same 354-frame 512x512 clip, in turn.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_capture.py --out out/benchmarks
        [--model M.npz] [--quick] [--only synthetic|real|speed] [--trackers ours,mediapipe,floor]
        [--models ict-bilinear,ict-trilinear]

Writes ``OUT/capture.json`` and ``OUT/capture.png`` and prints a compact table.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import _capture_data as cd  # noqa: E402
import _mp_points as mp  # noqa: E402
from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402

log = logging.getLogger("bench_capture")

KEY7 = [36, 39, 42, 45, 30, 48, 54]
INNER51 = list(range(17, 68))
NARROW = 6706                                 # FaceKit narrow face area: vertices 0..6705
KEY_SHAPES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight",
              "browInnerUp", "browDownLeft", "mouthFunnel", "mouthPucker")
REAL_SHAPES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight",
               "browInnerUp", "mouthFunnel", "mouthPucker")
REAL_CLIPS = ("face_2", "WDA_KatieHill_000", "driving_d9", "driving_d6")
#: --quick: (clip, first frame, frames); driving_d6 300-419 has the most eye motion
QUICK_REAL = (("WDA_KatieHill_000", 0, 100), ("driving_d6", 300, 120))
#: Targets of issue 12 (real clips): correlation floor per measure, std ratio band; synthetic NME.
TARGETS = {"mouth_open": 0.85, "mouth_width": 0.85, "eye_open": 0.85, "brow": 0.7,
           "jawOpen": 0.85, "eyeBlinkLeft": 0.85, "eyeBlinkRight": 0.85, "browInnerUp": 0.7,
           "std_ratio": (0.75, 1.33), "nme7": 0.025}
TRACKERS = ("mediapipe", "mediapipe_table", "ours", "ours_points", "klt", "floor", "capfloor")
FLOOR_PRIOR: list = [None]                    # --floor-prior
QUIET = [True]                                # drop MediaPipe's native log lines (not with -v)


class BenchInputError(ValueError):
    """Bad input to the benchmark: reported as one line, exit status 2."""


# ------------------------------------------------------------------------------ metrics
def iod(P: np.ndarray) -> np.ndarray:
    """Outer eye-corner distance (iBUG 36-45) per frame, (F, 68, 2) -> (F,)."""
    return np.linalg.norm(P[:, 36] - P[:, 45], axis=1)


def nme(pred: np.ndarray, truth: np.ndarray, points) -> np.ndarray:
    """Per-frame mean point error / true eye-corner distance, (F,); NaN where pred is missing."""
    e = np.linalg.norm(pred[:, points] - truth[:, points], axis=2).mean(axis=1)
    return e / iod(truth)


def similarity_error(A: np.ndarray, B: np.ndarray) -> float:
    """Mean distance between B and A after the similarity (Umeyama 1991) best mapping A onto B."""
    ma, mb = A.mean(0), B.mean(0)
    a, b = A - ma, B - mb
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (a * a).sum()
    return float(np.linalg.norm(s * a @ R.T - b, axis=1).mean())


def openings(P: np.ndarray) -> dict[str, np.ndarray]:
    """Face measures from iBUG-68 points (F, 68, 2), each / outer eye-corner distance, (F,)."""
    d = lambda i, j: np.linalg.norm(P[:, i] - P[:, j], axis=1)  # noqa: E731
    s = iod(P)
    return {"mouth_open": d(62, 66) / s, "mouth_width": d(48, 54) / s,
            "eye_open": (d(37, 41) + d(38, 40) + d(43, 47) + d(44, 46)) / 4 / s,
            "brow": (d(19, 37) + d(24, 44)) / 2 / s}


def openings_mp(P: np.ndarray) -> dict[str, np.ndarray]:
    """The same measures from MediaPipe's 478 points (F, 478, 2) (:mod:`_mp_points`)."""
    return {"mouth_open": mp.measure(P, mp.MOUTH_OPEN),
            "mouth_width": mp.measure(P, mp.MOUTH_WIDTH),
            "eye_open": mp.measure(P, mp.LIDS["Right"] + mp.LIDS["Left"]),
            "brow": mp.measure(P, mp.BROWS["Right"] + mp.BROWS["Left"])}


def corr(a: np.ndarray, b: np.ndarray) -> float | None:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or np.std(a[ok]) < 1e-9 or np.std(b[ok]) < 1e-9:
        return None
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def std_ratio(a: np.ndarray, b: np.ndarray) -> float | None:
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or np.std(b[ok]) < 1e-12:
        return None
    return float(np.std(a[ok]) / np.std(b[ok]))


def _r(x, k=4):
    return None if x is None or not np.isfinite(x) else round(float(x), k)


def score_synthetic(clip: cd.SyntheticClip, pred: dict) -> dict:
    """Metrics of one tracker's output ``pred`` (keys landmarks, activations, vertices)."""
    from facetransfer.arkit import ARKIT_NAMES, MEDIAPIPE_NAMES

    T = clip.landmarks
    P = pred["landmarks"]
    found = np.all(np.isfinite(P), axis=(1, 2))
    n7, n51 = nme(P, T, KEY7), nme(P, T, INNER51)
    out = {"frames": int(len(T)), "missed": int((~found).sum()),
           "nme7_median": _r(np.nanmedian(n7)), "nme7_mean": _r(np.nanmean(n7)),
           "nme51_median": _r(np.nanmedian(n51)), "nme51_mean": _r(np.nanmean(n51)),
           "nme7_frame0": _r(n7[0])}
    ot, op = openings(T), openings(P)
    out["corr_eye_open"] = _r(corr(op["eye_open"], ot["eye_open"]))
    out["corr_mouth_open"] = _r(corr(op["mouth_open"], ot["mouth_open"]))
    A = pred.get("activations")
    if A is not None:
        cols = [ARKIT_NAMES.index(n) for n in MEDIAPIPE_NAMES]
        err = np.abs(A - clip.activations)
        out["act_mae51"] = _r(np.nanmean(err[:, cols]))
        out["act_mae"] = {n: _r(np.nanmean(err[:, ARKIT_NAMES.index(n)])) for n in KEY_SHAPES}
        out["act_corr"] = {n: _r(corr(A[:, ARKIT_NAMES.index(n)],
                                      clip.activations[:, ARKIT_NAMES.index(n)]))
                           for n in KEY_SHAPES}
        # amplitude against the truth: whether a score is compressed (std of the prediction
        # over the std of the true activation, per key shape)
        out["act_std_ratio"] = {n: _r(std_ratio(A[:, ARKIT_NAMES.index(n)],
                                                clip.activations[:, ARKIT_NAMES.index(n)]))
                                for n in KEY_SHAPES}
    V = pred.get("vertices")
    if V is not None:
        sub = pred["vertex_subset"]
        keep = sub < NARROW
        e = [similarity_error(V[i][keep], clip.vertices[i][sub[keep]].astype(np.float64))
             for i in range(len(V))]
        out["v3d_mm_median"] = _r(10.0 * np.median(e), 3)   # ICT units are cm
        out["v3d_mm_mean"] = _r(10.0 * np.mean(e), 3)
    return out


# ------------------------------------------------------------------------------ trackers
def _model_subset(model) -> np.ndarray:
    vs = getattr(model, "vertex_subset", None)
    return np.arange(model.n_vertices) if vs is None else np.asarray(vs, np.int64)


def _activations(model, weights: np.ndarray) -> np.ndarray | None:
    from facetransfer.arkit import is_arkit_model, weights_to_activations

    return weights_to_activations(model, weights) if is_arkit_model(model) else None


def run_mediapipe(video: Path, cache: Path, *, table: bool = False) -> dict:
    """Face Landmarker on a clip: iBUG-68 points, blendshapes, the raw 478 points. The iBUG
    points through ``mediapipe_to_ibug`` (the calibrated correspondence), or with ``table``
    through the uncalibrated table ``MP_TO_IBUG`` (tracker ``mediapipe_table``)."""
    from facetransfer.track.landmarks import mediapipe_to_ibug, table_matrix

    with filtered_stderr(QUIET[0]):
        pts, shp = cached_landmarker(video, cache, shown=True)
    L = np.einsum("im,fmd->fid", table_matrix(pts.shape[1]), pts) if table else \
        mediapipe_to_ibug(pts)
    return {"landmarks": L, "activations": shp, "points478": pts}


def run_ours(video: Path, model, max_frames: int | None = None, *, tracker: str = "capture"
             ) -> dict:
    """Our default tracker as ``facetransfer track`` runs it (``capture``: the model fitted to
    detections and flow on every frame, then again with Face Landmarker's scores), the same
    without the scores' second pass (``points``: ``track --no-scores``), or the paper's ``klt``
    tracker (``track_video`` with default options); its landmarks, activations and unposed face
    vertices per frame."""
    from facetransfer.track import track_video
    from facetransfer.track.capture import CaptureOptions, capture_video

    t0 = time.perf_counter()
    with filtered_stderr(QUIET[0]):
        if tracker in ("capture", "points"):
            opts = CaptureOptions(scores=0.0) if tracker == "points" else None
            tr = capture_video(str(video), model, max_frames=max_frames, options=opts)
        else:
            tr = track_video(str(video), model, max_frames=max_frames)
    sec = time.perf_counter() - t0
    A = None
    if tr.blendshapes is not None:
        A = np.asarray(tr.blendshapes, np.float64)
    elif "expression" in tr.weights:
        A = _activations(model, tr.weights["expression"])
    V = np.stack([model.synthesize(tr.weights_at(i)) for i in range(tr.n_frames)])
    return {"landmarks": tr.landmarks2d, "activations": A, "vertices": V,
            "vertex_subset": _model_subset(model), "seconds": sec,
            "lost": int(np.sum(tr.lost)), "has_blendshapes": tr.blendshapes is not None}


def run_capture_floor(truth68: np.ndarray, model) -> dict:
    """The capture tracker's own fit (default options, but no correction of the detector's
    pitch: these points are exact) to the true 68 points of every frame, without MediaPipe and
    flow: the floor of ``ours``, its model and priors."""
    from facetransfer.track.capture import CaptureOptions, capture_detections
    from facetransfer.track.detect import ClipDetections

    tr = capture_detections(ClipDetections.from_points(np.asarray(truth68, np.float64)), model,
                            options=CaptureOptions(pitch_gain=1.0))
    V = np.stack([model.synthesize(tr.weights_at(i)) for i in range(tr.n_frames)])
    A = None if tr.blendshapes is None else np.asarray(tr.blendshapes, np.float64)
    return {"landmarks": tr.landmarks2d, "activations": A, "vertices": V,
            "vertex_subset": _model_subset(model)}


def run_floor(truth68: np.ndarray, model, prior: float | None = None) -> dict:
    """The model fitted to the true 68 points on every frame (warm-started from the previous);
    ``prior``: :func:`~facetransfer.track.init.fit_landmarks`'s prior (default its own)."""
    from facetransfer.track.init import fit_landmarks

    lm = np.asarray(model.landmarks, np.int64)
    P, A, V = [], [], []
    state = None
    kw = {} if prior is None else {"prior": float(prior)}
    for L in truth68:
        state = fit_landmarks(model, L, state=state, **kw)
        X = model.synthesize(state.weights)
        P.append(state.pose.project(X[lm]))
        V.append(X)
        if "expression" in state.weights:
            A.append(state.weights["expression"])
    acts = _activations(model, np.array(A)) if A else None
    return {"landmarks": np.array(P), "activations": acts, "vertices": np.array(V),
            "vertex_subset": _model_subset(model)}


# ------------------------------------------------------------------------------ synthetic
def synthetic_clips(cache: Path, quick: bool) -> list[cd.SyntheticClip]:
    from dataclasses import replace

    specs = [replace(s, n_frames=60) for s in cd.CLIPS[:2]] if quick else list(cd.CLIPS)
    fk = cd.facekit_loader(cache)

    clips = []
    for s in specs:
        t0 = time.perf_counter()
        clips.append(cd.load_clip(cache, s, fk_loader=fk))
        log.info("synthetic clip %s ready (%.1f s)", s.name, time.perf_counter() - t0)
    return clips


def _training_identities(model) -> np.ndarray | None:
    """The model's training identity weights over the FaceKit's 100 components (row 0, the
    generic neutral, dropped), from its provenance."""
    w = (getattr(model, "provenance", {}) or {}).get("identity_weights")
    return None if w is None else np.asarray(w, float)[1:]


def run_synthetic(models: dict, trackers, cache: Path, quick: bool) -> dict:
    """Every tracker (and every model for ours/floor) on every synthetic clip."""
    clips = synthetic_clips(cache, quick)
    out = {"clips": {}, "identity_check": {}}
    training = {k: _training_identities(m) for k, m in models.items()}
    sheets = []
    for clip in clips:
        res, kept = {}, {}
        out["identity_check"][clip.name] = {
            "norm": _r(np.linalg.norm(clip.identity_weights), 3),
            "min_distance_to_training": {k: _r(cd.identity_distance(clip.identity_weights, t), 3)
                                         for k, t in training.items()}}
        for tk in trackers:
            for mname, model in (models.items() if not tk.startswith("mediapipe")
                                 else [("main", None)]):
                label = tk if mname == "main" else f"{tk}[{mname}]"
                t0 = time.perf_counter()
                try:
                    if tk.startswith("mediapipe"):
                        pred = run_mediapipe(clip.video, cache, table=tk == "mediapipe_table")
                    elif tk in ("ours", "ours_points", "klt"):
                        pred = run_ours(clip.video, model, tracker={
                            "ours": "capture", "ours_points": "points"}.get(tk, "klt"))
                    elif tk == "capfloor":
                        pred = run_capture_floor(clip.landmarks, model)
                    else:
                        pred = run_floor(clip.landmarks, model, FLOOR_PRIOR[0])
                except Exception as exc:  # a tracker that fails is a result, not a crash
                    log.exception("%s failed on %s", label, clip.name)
                    res[label] = {"error": f"{type(exc).__name__}: {exc}"}
                    continue
                res[label] = score_synthetic(clip, pred)
                if mname == "main":
                    kept[tk] = pred["landmarks"]
                    if tk == "ours":
                        kept["ours_nme7"] = nme(pred["landmarks"], clip.landmarks, KEY7)
                res[label]["seconds"] = round(time.perf_counter() - t0, 2)
                for k in ("lost", "has_blendshapes"):
                    if k in pred:
                        res[label][k] = pred[k]
                log.info("%s %s: 7-pt NME median %s", clip.name, label, res[label]["nme7_median"])
        out["clips"][clip.name] = res
        sheets.append((clip, kept))
    if sheets:
        try:
            contact_sheet(sheets, cache.parent / "capture_frames.png")
        except Exception:
            log.exception("contact sheet failed")
    return out


_COLOURS = {"truth": (0, 220, 0), "ours": (230, 30, 30), "ours_points": (250, 140, 140),
            "mediapipe": (40, 90, 255),
            "mediapipe_table": (120, 160, 255),
            "floor": (240, 200, 0), "capfloor": (200, 0, 200), "klt": (0, 200, 200)}


def contact_sheet(sheets, path: Path) -> None:
    """Frames 0, F/2 and our worst frame of every clip with the truth and every tracker's 68
    points (green truth, red ours, blue MediaPipe, yellow floor)."""
    import cv2

    from facetransfer.io.atomic import write_image
    from facetransfer.io.video import read_video

    rows = []
    for clip, kept in sheets:
        frames, _ = read_video(clip.video)
        worst = int(np.nanargmax(kept["ours_nme7"])) if "ours_nme7" in kept else len(frames) - 1
        cells = []
        for i in (0, len(frames) // 2, worst):
            img = np.ascontiguousarray(frames[i])
            for name, P in [("truth", clip.landmarks)] + [(k, v) for k, v in kept.items()
                                                          if not k.endswith("_nme7")]:
                for x, y in P[i]:
                    if np.isfinite(x) and np.isfinite(y):
                        cv2.circle(img, (int(round(x)), int(round(y))), 2, _COLOURS[name], -1)
            img = _crop_face(img, clip.landmarks[i], 360)
            cv2.putText(img, f"{clip.name} frame {i}" + (" (worst ours)" if i == worst else ""),
                        (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            cells.append(img)
        rows.append(np.concatenate(cells, axis=1))
    sheet = np.concatenate(rows, axis=0)
    legend = np.zeros((24, sheet.shape[1], 3), np.uint8)
    x = 6
    for name, col in _COLOURS.items():
        cv2.circle(legend, (x + 4, 12), 4, col, -1)
        cv2.putText(legend, name, (x + 12, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                    cv2.LINE_AA)
        x += 110
    write_image(path, np.concatenate([legend, sheet], axis=0))


def _crop_face(img: np.ndarray, P: np.ndarray, size: int) -> np.ndarray:
    """A square crop around the points (1.5 times their extent), resized to ``size``."""
    import cv2

    c, half = P.mean(axis=0), 0.75 * np.ptp(P, axis=0).max()
    x0, y0 = np.floor(c - half).astype(int)
    x1, y1 = np.ceil(c + half).astype(int)
    H, W = img.shape[:2]
    pad = max(0, -x0, -y0, x1 - W, y1 - H)
    if pad:
        img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT)
    crop = img[y0 + pad:y1 + pad, x0 + pad:x1 + pad]
    return cv2.resize(crop, (size, size), interpolation=cv2.INTER_AREA)


# ------------------------------------------------------------------------------ real clips
def _data_dir() -> Path:
    from facetransfer import assets

    d = assets.data_dir()
    if d is None or not (Path(d) / "video").is_dir():
        raise BenchInputError(f"FACETRANSFER_DATA_DIR ({d or 'unset'}) must be the asset mirror "
                              "with the real clips in its video/ folder")
    return Path(d)


def real_clip_scores(ours: dict, ref478: np.ndarray, mp_shapes: np.ndarray) -> dict:
    """Correlation and std ratio of our measures and activations against the reference."""
    from facetransfer.arkit import ARKIT_NAMES

    F = len(ours["landmarks"])
    mo, mr = openings(ours["landmarks"]), openings_mp(ref478[:F])
    out = {"frames": F, "lost": ours["lost"], "seconds": round(ours["seconds"], 2),
           "fps": round(F / ours["seconds"], 2), "measures": {}, "activations": {}}
    for k in mo:
        out["measures"][k] = {"corr": _r(corr(mo[k], mr[k])),
                              "std_ratio": _r(std_ratio(mo[k], mr[k]))}
    A = ours["activations"]
    for n in REAL_SHAPES:
        j = ARKIT_NAMES.index(n)
        if A is None:
            out["activations"][n] = None
            continue
        out["activations"][n] = {"corr": _r(corr(A[:, j], mp_shapes[:F, j])),
                                 "std_ratio": _r(std_ratio(A[:, j], mp_shapes[:F, j]))}
    return out



def blink_levels(A: np.ndarray | None, shapes: np.ndarray, ref478: np.ndarray, *,
                 closed: float = 0.35, opened: float = 0.9) -> dict:
    """eyeBlink* where the reference's own lids say the eye is closed and where it is open.

    ARKit defines eyeBlink as 0 for an open eye and 1 for a closed one, so on real footage,
    with no truth, the frames whose lid gap (the reference's points, / the eye-corner
    distance) is below ``closed`` times the clip's median gap should score near 1 and those
    above ``opened`` times it near 0. Per eye: the number of closed frames and the mean score
    there and on open frames, ours and Face Landmarker's; a scale that differs between the two
    shows as a different span (closed - open), which a std ratio cannot place.
    """
    from facetransfer.arkit import ARKIT_NAMES

    F = len(shapes) if A is None else min(len(A), len(shapes), len(ref478))
    P = np.asarray(ref478[:F], np.float64)
    out = {}
    for side, pairs in mp.LIDS.items():
        gap = mp.measure(P, pairs)
        med = np.median(gap)
        shut, wide = gap < closed * med, gap > opened * med
        k = ARKIT_NAMES.index(f"eyeBlink{side}")
        lv = lambda x, m: _r(float(np.mean(x[m]))) if m.any() else None  # noqa: E731
        row = {"closed_frames": int(shut.sum()),
               "mediapipe": {"closed": lv(shapes[:F, k], shut), "open": lv(shapes[:F, k], wide)}}
        if A is not None:
            row["ours"] = {"closed": lv(A[:F, k], shut), "open": lv(A[:F, k], wide)}
        out[f"eyeBlink{side}"] = row
    return out


def lid_closure(ref478: np.ndarray, side: str) -> np.ndarray:
    """``(F,)``: how closed eye ``side`` is by the reference's own lids, ``1 - gap / median
    gap`` clipped to [0, 1] (the gap: :data:`_mp_points.LIDS` over the eye-corner distance; the
    clip's median gap is its eye at rest, nearly every frame's): 0 open, 1 the lids touching,
    linear between, as ARKit's eyeBlink is defined; NaN where the reference has no points (a
    frame it lost: the median is of the others)."""
    gap = mp.measure(np.asarray(ref478, np.float64), mp.LIDS[side])
    with np.errstate(invalid="ignore"):
        return np.clip(1.0 - gap / np.nanmedian(gap), 0.0, 1.0)


def blink_closure(A: np.ndarray | None, shapes: np.ndarray, ref478: np.ndarray) -> dict:
    """eyeBlink* of ours and Face Landmarker's against the lids' closure that the reference's
    points show (:func:`lid_closure`), per eye: correlation, the slope of the score on the
    closure (least squares with an intercept: 1 where a score reads the lids' closure at its
    own amplitude) and the std ratio score : closure. A third reading beside ours and the
    peer's, from the peer's own points: which of the two scores follows the lids at their
    amplitude. ``{"eyeBlinkLeft": {"ours": {...}, "mediapipe": {...}}, ...}``."""
    from facetransfer.arkit import ARKIT_NAMES

    F = len(shapes) if A is None else min(len(A), len(shapes), len(ref478))
    out = {}
    for side in mp.LIDS:
        c = lid_closure(np.asarray(ref478[:F]), side)
        k = ARKIT_NAMES.index(f"eyeBlink{side}")
        row = {}
        for who, S in (("ours", A), ("mediapipe", shapes)):
            if S is None:
                continue
            y = np.asarray(S[:F, k], np.float64)
            ok = np.isfinite(y) & np.isfinite(c)
            slope = (float(np.polyfit(c[ok], y[ok], 1)[0])
                     if ok.sum() >= 3 and np.std(c[ok]) > 1e-9 else None)
            row[who] = {"corr": _r(corr(y, c)), "slope": _r(slope), "std_ratio": _r(std_ratio(y, c))}
        out[f"eyeBlink{side}"] = row
    return out


#: MediaPipe eye corners (outer, inner) and iris centre per eye, by the subject's side.
_EYES = {"Right": (33, 133, 468), "Left": (263, 362, 473)}


def iris_gaze(P: np.ndarray) -> dict[str, np.ndarray]:
    """Gaze of each eye from MediaPipe's iris points, (F, 478, 2) -> per eye ``out`` (towards the
    outer corner) and ``up``: the iris centre's offset from the eye-corner midpoint along and
    across the eye axis, / the eye's corner distance, (F,) each."""
    out = {}
    mouth = P[:, 13]
    for side, (o, i, c) in _EYES.items():
        ax = P[:, o] - P[:, i]
        w = np.linalg.norm(ax, axis=1)
        u = ax / w[:, None]
        n = np.stack([-u[:, 1], u[:, 0]], 1)
        mid = (P[:, o] + P[:, i]) / 2
        n *= np.sign(np.sum(n * (mid - mouth), axis=1))[:, None]     # towards the brows
        d = P[:, c] - mid
        out[f"out{side}"] = np.sum(d * u, axis=1) / w
        out[f"up{side}"] = np.sum(d * n, axis=1) / w
    return out


def gaze_scores(mp478: np.ndarray, shapes: np.ndarray, A: np.ndarray | None) -> dict:
    """Correlation over frames with Face Landmarker's own gaze (``eyeLookOut - eyeLookIn``,
    ``eyeLookUp - eyeLookDown`` per eye) of (a) the iris offsets of :func:`iris_gaze` on the
    same run's points (what an iris term could reach) and (b) our eyeLook* activations."""
    from facetransfer.arkit import ARKIT_NAMES

    F = len(mp478) if A is None else min(len(mp478), len(A))
    g = iris_gaze(np.asarray(mp478[:F], np.float64))
    col = lambda X, n: X[:F, ARKIT_NAMES.index(n)]  # noqa: E731
    res = {}
    for side in ("Left", "Right"):
        ref = {"out": col(shapes, f"eyeLookOut{side}") - col(shapes, f"eyeLookIn{side}"),
               "up": col(shapes, f"eyeLookUp{side}") - col(shapes, f"eyeLookDown{side}")}
        for k, r in ref.items():
            ours = None
            if A is not None:
                ours = (col(A, f"eyeLookOut{side}") - col(A, f"eyeLookIn{side}") if k == "out"
                        else col(A, f"eyeLookUp{side}") - col(A, f"eyeLookDown{side}"))
            res[f"{k}{side}"] = {"iris_corr": _r(corr(g[f"{k}{side}"], r)),
                                 "ours_corr": None if ours is None else _r(corr(ours, r)),
                                 "mediapipe_std": _r(float(np.std(r)))}
    return res


def peer_agreement(mp478: np.ndarray, ref478: np.ndarray) -> dict:
    """Today's Face Landmarker (Tasks API, VIDEO mode) against the stored reference (FaceMesh
    0.10.21) on the same frames: how far two MediaPipe versions agree, a ceiling for ours."""
    a, b = openings_mp(mp478), openings_mp(ref478[:len(mp478)])
    return {k: {"corr": _r(corr(a[k], b[k])), "std_ratio": _r(std_ratio(a[k], b[k]))} for k in a}


def trimmed_clip(video: Path, start: int, n: int, cache: Path) -> Path:
    """Frames ``start .. start+n-1`` of a clip as an mp4 in the cache (H.264, crf 16)."""
    from facetransfer.io.atomic import atomic_path
    from facetransfer.io.video import read_video

    path = cache / f"trim-{video.stem}-{start}-{n}.mp4"
    if not path.is_file():
        frames, fps = read_video(video, start=start, stop=start + n)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            cd.write_mp4(tmp, frames, fps)
    return path


def drift_jitter(P: np.ndarray, ref68: np.ndarray) -> dict:
    """Jitter: median frame-to-frame second difference of the 68 points / eye distance.
    Drift: median 51-point NME vs the reference over the last 10 % of frames minus the first
    10 %. Also the reference's own jitter (MediaPipe's), for scale."""
    def jitter(Q):
        acc = np.linalg.norm(Q[2:] - 2 * Q[1:-1] + Q[:-2], axis=2)        # (F-2, 68)
        return float(np.nanmedian(acc / iod(Q)[1:-1, None]))

    e = nme(P, ref68, INNER51)
    k = max(1, len(e) // 10)
    return {"jitter": _r(jitter(P), 5), "jitter_reference": _r(jitter(ref68), 5),
            "drift": _r(np.nanmedian(e[-k:]) - np.nanmedian(e[:k]), 5),
            "nme51_first10": _r(np.nanmedian(e[:k])), "nme51_last10": _r(np.nanmedian(e[-k:])),
            "frames": int(len(P))}


#: MediaPipe points of the skull (eye corners, nose, forehead, cheeks): a frame's points are
#: aligned on these (2-D similarity) before the mouth is read in the head's frame.
_SKULL = (33, 133, 263, 362, 168, 6, 197, 195, 5, 4, 1, 10, 151, 9, 8, 107, 336, 234, 454, 127,
          356)
#: what a linear reading of Face Landmarker's jawOpen may use, in the head's frame: the inner
#: lower lip (14), the inner upper lip (13), the chin (152), the outer lower lip (17) (heights)
_JAW_READING = (14, 13, 152, 17)


def _head_frame(P: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(F, 478, 2) points each similarity-aligned on :data:`_SKULL` to ``ref`` (478, 2) (Umeyama
    1991, in 2-D, no reflection), centred, in units of ``ref``'s outer eye-corner distance."""
    out = np.empty_like(P)
    b = ref[list(_SKULL)] - ref[list(_SKULL)].mean(0)
    for i, p in enumerate(P):
        a = p[list(_SKULL)]
        ma = a.mean(0)
        U, sv, Vt = np.linalg.svd((a - ma).T @ b)
        d = np.array([1.0, np.sign(np.linalg.det(U @ Vt))])
        out[i] = (p - ma) @ (U * d) @ Vt * ((sv * d).sum() / np.sum((a - ma) ** 2))
    return out / np.linalg.norm(ref[33] - ref[263])


def jaw_reading_ceiling(clips: dict) -> dict:
    """How far Face Landmarker's own jawOpen is a geometric reading of its own landmarks.

    ``clips``: name -> (points (F, 478, 2), blendshapes (F, 52)) of one Face Landmarker run.
    Per clip, the correlation with its jawOpen of (a) its lip gap (13-14), (b) the least-squares
    line through the mouth's heights in the head's frame (:data:`_JAW_READING`) fitted on the
    *other* clips (leave one clip out), (c) the same fitted on the clip itself (an upper
    bound of any linear reading). A tracker that reads the jaw from these points, as ours does,
    should not be expected above (b).
    """
    from facetransfer.arkit import ARKIT_NAMES

    j = ARKIT_NAMES.index("jawOpen")
    ok = {n: v for n, v in clips.items() if len(v[0]) >= 10 and np.isfinite(v[0]).all()}
    if len(ok) < 2:
        return {}
    ref = np.mean([v[0].mean(0) for v in ok.values()], axis=0)
    X = {n: np.c_[_head_frame(v[0], ref)[:, list(_JAW_READING), 1], np.ones(len(v[0]))]
         for n, v in ok.items()}
    y = {n: v[1][:, j] for n, v in ok.items()}
    out = {}
    for n, (P, _) in ok.items():
        gap = np.linalg.norm(P[:, 13] - P[:, 14], axis=1) / np.linalg.norm(P[:, 33] - P[:, 263],
                                                                         axis=1)
        others = [m for m in ok if m != n]
        b = np.linalg.lstsq(np.concatenate([X[m] for m in others]),
                            np.concatenate([y[m] for m in others]), rcond=None)[0]
        own = np.linalg.lstsq(X[n], y[n], rcond=None)[0]
        out[n] = {"lip_gap": _r(corr(gap, y[n])),
                  "linear_other_clips": _r(corr(X[n] @ b, y[n])),
                  "linear_own_clip": _r(corr(X[n] @ own, y[n]))}
    out["median"] = {k: _r(float(np.median([v[k] for v in out.values() if v[k] is not None])))
                     for k in ("lip_gap", "linear_other_clips", "linear_own_clip")}
    return out


def run_real(model, cache: Path, quick: bool) -> dict:
    """Our track on the real clips against the stored MediaPipe references."""
    from facetransfer.track.landmarks import mediapipe_to_ibug

    vdir = _data_dir() / "video"
    clips = QUICK_REAL if quick else [(c, 0, None) for c in REAL_CLIPS]
    out, landmarker = {"clips": {}}, {}
    for name, start, n in clips:
        video = vdir / f"{name}.mp4"
        refp = vdir / f"{name}.mediapipe478.npz"
        if not (video.is_file() and refp.is_file()):
            log.warning("real clip %s missing in %s; skipped", name, vdir)
            continue
        with np.load(refp) as z:
            ref = np.asarray(z["landmarks"], float)[..., :2]
        if start:
            video, ref = trimmed_clip(video, start, n, cache), ref[start:start + n]
        with filtered_stderr(QUIET[0]):
            mp478, shapes = cached_landmarker(video, cache, shown=True)
        landmarker[name] = (np.asarray(mp478, float)[..., :2], np.asarray(shapes, float))
        try:
            ours = run_ours(video, model, max_frames=n)
        except Exception as exc:
            log.exception("ours failed on %s", name)
            out["clips"][name] = {"error": f"{type(exc).__name__}: {exc}"}
            continue
        r = real_clip_scores(ours, ref, shapes)
        r["mediapipe_vs_reference"] = peer_agreement(mp478, ref)
        r["gaze"] = gaze_scores(mp478, shapes, ours["activations"])
        r["blink_levels"] = blink_levels(ours["activations"], shapes, ref)
        r["blink_closure"] = blink_closure(ours["activations"], shapes, ref)
        if name == "driving_d6":
            F = len(ours["landmarks"])
            r["drift_jitter"] = drift_jitter(ours["landmarks"], mediapipe_to_ibug(ref[:F]))
        out["clips"][name] = r
        log.info("real %s: %s", name, {k: v["corr"] for k, v in r["measures"].items()})
    out["summary"] = real_summary(out["clips"])
    out["jaw_reading_ceiling"] = jaw_reading_ceiling(landmarker)
    return out


def _verdict(key: str, c, s) -> str:
    lo, hi = TARGETS["std_ratio"]
    t = TARGETS.get(key)
    ok_c = None if t is None or c is None else c >= t
    ok_s = None if s is None else lo <= s <= hi
    if ok_c is None and ok_s is None:
        return "-"
    return "PASS" if (ok_c is not False and ok_s is not False) else "FAIL"


def real_summary(clips: dict) -> dict:
    """Median over clips of each correlation and std ratio, with the issue's verdict."""
    rows = {}
    good = [c for c in clips.values() if "error" not in c]
    keys = [("measures", k) for k in ("mouth_open", "mouth_width", "eye_open", "brow")]
    keys += [("activations", n) for n in REAL_SHAPES]
    for grp, k in keys:
        vals = [c[grp][k] for c in good if c[grp].get(k)]
        cs = [v["corr"] for v in vals if v["corr"] is not None]
        ss = [v["std_ratio"] for v in vals if v["std_ratio"] is not None]
        c = _r(np.median(cs)) if cs else None
        s = _r(np.median(ss)) if ss else None
        rows[k] = {"corr_median": c, "std_ratio_median": s, "target_corr": TARGETS.get(k),
                   "verdict": _verdict(k, c, s)}
    return rows


def print_real(real: dict) -> None:
    print("\nreal clips: ours vs MediaPipe (correlation over frames / std ratio ours:ref)")
    names = list(real["clips"])
    print(f"{'measure':16s} " + " ".join(f"{n[:17]:>17s}" for n in names)
          + f" {'median':>13s} {'target':>10s} verdict")
    lo, hi = TARGETS["std_ratio"]
    for k, row in real["summary"].items():
        cells = []
        for n in names:
            c = real["clips"][n]
            v = None if "error" in c else (c["measures"].get(k) or c["activations"].get(k))
            cells.append(f"{_fmt(v):>17s}")
        med = _fmt({"corr": row["corr_median"], "std_ratio": row["std_ratio_median"]})
        tgt = f">={row['target_corr']:.2f}" if row["target_corr"] else "-"
        print(f"{k:16s} " + " ".join(cells) + f" {med:>13s} {tgt:>10s} {row['verdict']}")
    print(f"(std ratio target {lo}-{hi})")
    peer = [c["mediapipe_vs_reference"] for c in real["clips"].values()
            if "mediapipe_vs_reference" in c]
    if peer:
        print("peer check, Face Landmarker now vs the stored reference (median corr/std ratio): "
              + ", ".join(f"{k} {np.median([p[k]['corr'] for p in peer]):.2f}/"
                          f"{np.median([p[k]['std_ratio'] for p in peer]):.2f}" for k in peer[0]))
    gz = [c["gaze"] for c in real["clips"].values() if "gaze" in c]
    if gz:
        med = lambda k, f: np.nanmedian([np.nan if g[k][f] is None else g[k][f]  # noqa: E731
                                         for g in gz])
        print("gaze vs Face Landmarker's eyeLook* (median corr): " + ", ".join(
            f"{k} iris {med(k, 'iris_corr'):.2f} ours {med(k, 'ours_corr'):.2f}" for k in gz[0]))
    _print_blink_levels(real)
    _print_blink_closure(real)
    ceil = real.get("jaw_reading_ceiling", {}).get("median")
    if ceil:
        print("Face Landmarker's jawOpen read from its own points (median corr): lip gap "
              f"{ceil['lip_gap']:.2f}, linear fit on the other clips "
              f"{ceil['linear_other_clips']:.2f}, on the clip itself {ceil['linear_own_clip']:.2f}")
    for n, c in real["clips"].items():
        if "drift_jitter" in c:
            d = c["drift_jitter"]
            print(f"{n}: jitter {d['jitter']} (reference {d['jitter_reference']}), drift "
                  f"{d['drift']} over {d['frames']} frames; tracking {c['fps']} fps, "
                  f"{c['lost']} lost")


def _print_blink_closure(real: dict) -> None:
    """One line per eye: the median over clips of eyeBlink*'s slope on the lids' closure
    (:func:`blink_closure`), ours and Face Landmarker's, and their std ratios."""
    rows = [c["blink_closure"] for c in real["clips"].values() if "blink_closure" in c]
    if not rows:
        return
    print("eyeBlink* against the lids' closure by the reference's points (1 - gap / median gap; "
          "ARKit: slope 1), median over clips of slope / std ratio / r:")
    for eye in rows[0]:
        cells = []
        for who, label in (("ours", "ours"), ("mediapipe", "Face Landmarker")):
            vals = [r[eye][who] for r in rows if who in r[eye]]
            med = [np.nanmedian([np.nan if v[f] is None else v[f] for v in vals])
                   for f in ("slope", "std_ratio", "corr")]
            cells.append(f"{label} {med[0]:.2f} / {med[1]:.2f} / {med[2]:.2f}")
        print(f"  {eye}: " + ", ".join(cells))


def _print_blink_levels(real: dict) -> None:
    """One line per clip and eye with a closed frame: eyeBlink* on closed / open lids."""
    print("eyeBlink* where the reference's lids are closed (<35 % of the median gap) / open "
          "(ARKit: 1 / 0), ours vs Face Landmarker:")
    for n, c in real["clips"].items():
        for eye, row in c.get("blink_levels", {}).items():
            if not row["closed_frames"] or "ours" not in row:
                continue
            o, m = row["ours"], row["mediapipe"]
            print(f"  {n} {eye} ({row['closed_frames']} closed frames): ours {o['closed']:.2f} / "
                  f"{o['open']:.2f}, Face Landmarker {m['closed']:.2f} / {m['open']:.2f}")


def _fmt(v) -> str:
    if not v:
        return "-"
    c = "-" if v.get("corr") is None else f"{v['corr']:.2f}"
    s = "-" if v.get("std_ratio") is None else f"{v['std_ratio']:.2f}"
    return f"{c}/{s}"


# ------------------------------------------------------------------------------ speed
SPEED_FRAMES = 354


def speed_clip(cache: Path) -> Path:
    """The first 354 frames of ``driving_d9`` resized to 512x512 (cached)."""
    import cv2

    from facetransfer.io.atomic import atomic_path
    from facetransfer.io.video import read_video

    path = cache / f"speed-driving_d9-{SPEED_FRAMES}f-512.mp4"
    if not path.is_file():
        frames, fps = read_video(_data_dir() / "video" / "driving_d9.mp4", stop=SPEED_FRAMES)
        small = [cv2.resize(f, (512, 512), interpolation=cv2.INTER_AREA) for f in frames]
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            cd.write_mp4(tmp, small, fps)
    return path


def _console_script() -> list[str]:
    exe = Path(sys.executable).parent / "facetransfer"
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "facetransfer.cli.main"]


def _children_cpu() -> float:
    """CPU seconds (user + system) of every finished child process and its own children."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _timed(cmd: list[str]) -> tuple[float, str, float]:
    """Run ``cmd``: ``(wall seconds, its stderr, CPU seconds of it and its children)``."""
    t0, c0 = time.perf_counter(), _children_cpu()
    p = subprocess.run(cmd, capture_output=True, text=True)
    sec, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} ... exited {p.returncode}: "
                           f"{(p.stderr or p.stdout).strip()[-300:]}")
    return sec, p.stderr, cpu


#: rounds of the speed test (the three commands in turn each round; medians reported)
SPEED_ROUNDS = 3


def _round(cmds: dict) -> tuple[dict, dict]:
    """One round: each command in turn; ``({name: wall s}, {name: CPU s})``."""
    wall, cpu = {}, {}
    for name, cmd in cmds.items():
        wall[name], _, cpu[name] = _timed(cmd)
    return wall, cpu


def run_speed(args, model, cache: Path) -> dict:
    """Whole-process wall time of ``facetransfer track`` (the default: two detection processes),
    of ``track --workers 1`` and of a MediaPipe VIDEO-mode process, in turn, on the same clip,
    :data:`SPEED_ROUNDS` rounds; the medians and every round. Also each one's CPU seconds (user
    + system, its children's too): on a machine other work shares, the wall ratio of two
    processes against one moves with the cores left free, the CPU ratio much less."""
    from facetransfer.default_model import default_model_path

    clip = speed_clip(cache)
    mpath = args.model or str(default_model_path())
    here = Path(__file__).resolve().parent
    rounds, cpus = [], []
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        ours_cmd = _console_script() + ["track", str(clip), "--model", mpath,
                                        "--out", str(Path(tmp) / "t.npz"), "--overwrite"]
        mp_cmd = [sys.executable, str(here / "_mp_video.py"), str(clip), str(Path(tmp) / "m.npz")]
        try:
            for _ in range(1 if args.quick else SPEED_ROUNDS):
                wall, cpu = _round({"mediapipe": mp_cmd, "ours": ours_cmd,
                                    "ours_one_process": ours_cmd + ["--workers", "1"]})
                rounds.append(wall)
                cpus.append(cpu)
        except RuntimeError as exc:
            log.error("speed run failed: %s", exc)
            return {"error": str(exc)}
    med = {k: float(np.median([r[k] for r in rounds])) for k in rounds[0]}
    cpu = {k: float(np.median([r[k] for r in cpus])) for k in cpus[0]}
    return {"clip": str(clip), "frames": SPEED_FRAMES, "size": "512x512",
            "ours_command": " ".join(ours_cmd[1:3] + ["--model", "M", "--out", "T.npz"]),
            "ours_seconds": round(med["ours"], 2), "mediapipe_seconds": round(med["mediapipe"], 2),
            "ours_one_process_seconds": round(med["ours_one_process"], 2),
            "ours_fps": round(SPEED_FRAMES / med["ours"], 2),
            "ours_one_process_fps": round(SPEED_FRAMES / med["ours_one_process"], 2),
            "mediapipe_fps": round(SPEED_FRAMES / med["mediapipe"], 2),
            "ratio": round(med["ours"] / med["mediapipe"], 3),
            "ratio_one_process": round(med["ours_one_process"] / med["mediapipe"], 3),
            "round_ratios": [round(r["ours"] / r["mediapipe"], 3) for r in rounds],
            "rounds": [{k: round(v, 2) for k, v in r.items()} for r in rounds],
            "cpu_seconds": {k: round(v, 2) for k, v in cpu.items()},
            "cpu_ratio": round(cpu["ours"] / cpu["mediapipe"], 3),
            "cpu_ratio_one_process": round(cpu["ours_one_process"] / cpu["mediapipe"], 3),
            "cpu_rounds": [{k: round(v, 2) for k, v in r.items()} for r in cpus],
            "target_ratio": 2.0, "goal_ratio": 1.0}


# ------------------------------------------------------------------------------ plot
def plot(res: dict, path: Path) -> None:
    """Bars: 7-point NME per clip per tracker, activation error and correlation with the truth
    per key shape, real-clip correlations against the targets, speed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, axes = plt.subplots(3, 2, figsize=(14, 13))
    syn, real, sp = res.get("synthetic"), res.get("real"), res.get("speed")
    if syn:
        _bars(axes[0, 0], syn["clips"], lambda m: m.get("nme7_median"), 100,
              "7-point NME, median (% of eye-corner distance)", target=100 * TARGETS["nme7"])
        _act_bars(axes[0, 1], syn["clips"])
        _act_bars(axes[1, 0], syn["clips"], "act_corr")
    if real:
        _real_bars(axes[1, 1], real)
    if sp and "error" not in sp:
        ax = axes[2, 0]
        ax.bar(["ours (facetransfer track)", "ours, --workers 1", "MediaPipe VIDEO"],
               [sp["ours_fps"], sp.get("ours_one_process_fps", np.nan), sp["mediapipe_fps"]],
               color=["tab:blue", "lightsteelblue", "tab:orange"])
        ax.axhline(sp["mediapipe_fps"] / 2, color="k", ls="--", lw=1, label="target: half MediaPipe")
        ax.set_ylabel("frames per second (whole process)")
        ax.set_title(f"speed, {sp['frames']} frames 512², ratio {sp['ratio']:.2f}")
        ax.legend()
    for ax in axes.ravel():
        if not ax.has_data():
            ax.set_axis_off()
    fig.suptitle(f"capture benchmark (issue 12), model {Path(res['models']['main']).name}")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _bars(ax, clips: dict, get, scale, title, target=None) -> None:
    names = list(clips)
    tks = sorted({t for r in clips.values() for t in r})
    w = 0.8 / max(1, len(tks))
    for k, t in enumerate(tks):
        vals = [get(clips[n].get(t, {})) for n in names]
        ax.bar(np.arange(len(names)) + k * w, [np.nan if v is None else scale * v for v in vals],
               w, label=t)
    if target is not None:
        ax.axhline(target, color="k", ls="--", lw=1, label="target")
    ax.set_xticks(np.arange(len(names)) + w * (len(tks) - 1) / 2, names)
    ax.set_title(title)
    ax.legend(fontsize=8)


def _act_bars(ax, clips: dict, key: str = "act_mae") -> None:
    """Per key shape and tracker, the mean over clips of ``key`` (``act_mae`` or ``act_corr``;
    clips where the shape does not move have no correlation)."""
    tks = sorted({t for r in clips.values() for t, m in r.items() if m.get(key)})
    w = 0.8 / max(1, len(tks))
    for k, t in enumerate(tks):
        vals = [np.nanmean([r[t][key][n] for r in clips.values() if r.get(t, {})
                            .get(key) and r[t][key].get(n) is not None] or [np.nan])
                for n in KEY_SHAPES]
        ax.bar(np.arange(len(KEY_SHAPES)) + k * w, vals, w, label=t)
    ax.set_xticks(np.arange(len(KEY_SHAPES)) + w * (len(tks) - 1) / 2, KEY_SHAPES, rotation=30,
                  fontsize=8)
    what = "mean absolute error" if key == "act_mae" else "correlation over frames"
    ax.set_title(f"activation {what} vs truth (synthetic, mean over clips)")
    ax.legend(fontsize=8)


def _real_bars(ax, real: dict) -> None:
    summary = real["summary"]
    names = list(summary)
    c = [summary[n]["corr_median"] for n in names]
    ax.bar(np.arange(len(names)) - 0.2, [np.nan if v is None else v for v in c], 0.4,
           color="tab:blue", label="ours vs MediaPipe reference, median correlation")
    peer = [c["mediapipe_vs_reference"] for c in real["clips"].values()
            if "mediapipe_vs_reference" in c]
    pc = [np.median([p[n]["corr"] for p in peer]) if peer and n in peer[0] else np.nan
          for n in names]
    ax.bar(np.arange(len(names)) + 0.2, pc, 0.4, color="tab:orange",
           label="Face Landmarker now vs the reference (peer check)")
    t = [summary[n]["target_corr"] for n in names]
    ax.scatter(np.arange(len(names)), [np.nan if v is None else v for v in t], marker="_",
               s=400, color="k", label="target", zorder=3)
    ax.set_xticks(np.arange(len(names)), names, rotation=30, fontsize=8)
    ax.set_ylim(-0.2, 1.3)
    ax.set_title("real clips: correlation over frames (median over clips)")
    ax.legend(fontsize=7, ncol=2, loc="upper right")


# ------------------------------------------------------------------------------ models
def load_models(args) -> tuple[dict, dict]:
    """The main model (``--model`` or the default model) and the ``--models`` extras."""
    from facetransfer.model import load_model

    if args.model:
        main, desc = load_model(args.model), {"main": str(args.model)}
    else:
        from facetransfer.default_model import default_model_path, load_default_model

        main, desc = load_default_model(announce=log.info), {"main": str(default_model_path())}
    models = {"main": main}
    for name in [m for m in (args.models or "").split(",") if m]:
        try:
            models[name] = _paper_model(name)
        except Exception as exc:  # a paper model that cannot be built is reported, not fatal
            log.error("cannot build %s: %s", name, exc)
            desc[name] = f"failed: {exc}"
            continue
        desc[name] = name
    for k, m in models.items():
        desc[k + "_shape"] = {"modes": list(m.mode_names), "sizes": list(m.shape),
                              "ranks": list(m.ranks), "vertices": int(m.n_vertices),
                              "hash": m.content_hash}
    return models, desc


def _paper_model(name: str):
    """A paper model (``ict-bilinear``, ``ict-trilinear``) with the ranks of ``model build``."""
    from facetransfer.datasets import load_dataset
    from facetransfer.default_model import dataset_ranks
    from facetransfer.model import build_model

    ds = load_dataset(name)
    return build_model(ds, dataset_ranks(ds))


# ------------------------------------------------------------------------------ report
def print_table(res: dict) -> None:
    syn = res.get("synthetic")
    if syn:
        print("\nsynthetic clips (NME / true eye-corner distance; 3-D error mm after similarity)")
        print(f"{'clip':14s} {'tracker':22s} {'nme7 med':>8s} {'mean':>6s} {'f0':>6s} "
              f"{'nme51':>6s} {'3d mm':>6s} {'actMAE':>6s} {'r eye':>6s} {'r mouth':>7s} miss")
        for cname, r in syn["clips"].items():
            for tk, m in r.items():
                if "error" in m:
                    print(f"{cname:14s} {tk:22s} ERROR {m['error'][:60]}")
                    continue
                f = lambda k, s=100: "-" if m.get(k) is None else f"{s * m[k]:.2f}"  # noqa: E731
                print(f"{cname:14s} {tk:22s} {f('nme7_median'):>8s} {f('nme7_mean'):>6s} "
                      f"{f('nme7_frame0'):>6s} {f('nme51_median'):>6s} {f('v3d_mm_median', 1):>6s} "
                      f"{f('act_mae51', 1):>6s} {f('corr_eye_open', 1):>6s} "
                      f"{f('corr_mouth_open', 1):>7s} {m['missed']}")
        print(f"target: ours 7-pt NME <= {100 * TARGETS['nme7']:.1f} % and below mediapipe on "
              f"every clip -> {syn.get('verdict', '-')}")
    real = res.get("real")
    if real:
        print_real(real)
    sp = res.get("speed")
    if sp and "error" not in sp:
        print(f"\nspeed on {sp['frames']} frames {sp['size']}: ours {sp['ours_fps']:.1f} fps "
              f"({sp['ours_seconds']:.1f} s), mediapipe {sp['mediapipe_fps']:.1f} fps "
              f"({sp['mediapipe_seconds']:.1f} s): ratio {sp['ratio']:.2f} "
              f"(target <= 2: {'PASS' if sp['ratio'] <= 2 else 'FAIL'}; medians of "
              f"{len(sp['rounds'])} rounds in turn, each {sp['round_ratios']}); "
              f"--workers 1: {sp['ours_one_process_seconds']:.1f} s, ratio "
              f"{sp['ratio_one_process']:.2f}")
        if "cpu_seconds" in sp:
            c = sp["cpu_seconds"]
            print(f"CPU (user + system, medians): ours {c['ours']:.2f} s, --workers 1 "
                  f"{c['ours_one_process']:.2f} s, mediapipe {c['mediapipe']:.2f} s: ratio "
                  f"{sp['cpu_ratio']:.2f} (--workers 1: {sp['cpu_ratio_one_process']:.2f})")


def synthetic_verdict(syn: dict) -> str:
    """Ours <= the target and below every MediaPipe column (calibrated and table mapping)."""
    ok = []
    for r in syn["clips"].values():
        o = r.get("ours", {})
        if o.get("nme7_median") is None:
            return "FAIL (ours missing)"
        peers = [r.get(t, {}).get("nme7_median") for t in ("mediapipe", "mediapipe_table")]
        if all(m is None for m in peers):
            return "not judged (no MediaPipe column in this run)"
        ok.append(o["nme7_median"] <= TARGETS["nme7"]
                  and all(m is None or o["nme7_median"] < m for m in peers))
    return "PASS" if all(ok) else f"FAIL ({sum(ok)}/{len(ok)} clips)"


def write_outputs(res: dict, out: Path) -> None:
    from facetransfer.io.atomic import write_text_atomic

    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "capture.json", json.dumps(res, indent=1, default=_json))
    try:
        plot(res, out / "capture.png")
    except Exception:  # the figures are in the JSON; a plot failure must not lose them
        log.exception("plot failed")


def _json(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _keep_other_parts(res: dict, path: Path, parts) -> dict:
    """With ``--only``: the other parts of an earlier ``capture.json`` are kept (each part
    records the model hash and ``quick`` flag it was measured with)."""
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return res
    kept = {k: old[k] for k in ("synthetic", "real", "speed") if k in old and k not in parts}
    if kept:
        log.info("keeping %s from the earlier %s", ", ".join(kept), path)
    return res | kept


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    ap.add_argument("--model", help="model (.npz); default: the default model (ict-arkit)")
    ap.add_argument("--models", default="",
                    help="extra models for ours/floor: ict-bilinear,ict-trilinear")
    ap.add_argument("--quick", action="store_true",
                    help="2 short synthetic clips, 2 real clips, no speed (about 2 minutes)")
    ap.add_argument("--only", choices=("synthetic", "real", "speed"), help="run one part")
    ap.add_argument("--trackers", default=",".join(TRACKERS),
                    help=f"comma-separated subset of {','.join(TRACKERS)}")
    ap.add_argument("--floor-prior", type=float, default=None,
                    help="prior weight of the floor's landmark fit (default: fit_landmarks')")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s", datefmt="%H:%M:%S")
    log.setLevel(logging.INFO)
    QUIET[0] = not args.verbose
    FLOOR_PRIOR[0] = args.floor_prior
    trackers = [t for t in args.trackers.split(",") if t]
    bad = sorted(set(trackers) - set(TRACKERS))
    if bad:
        print(f"bench_capture: unknown tracker(s) {', '.join(bad)} in --trackers; expected "
              f"{', '.join(TRACKERS)}", file=sys.stderr)
        return 2
    if args.model and not Path(args.model).is_file():
        print(f"bench_capture: model file {args.model} does not exist", file=sys.stderr)
        return 2
    out = Path(args.out)
    cache = out / "capture_cache"
    parts = [args.only] if args.only else (["synthetic", "real"] if args.quick
                                           else ["synthetic", "real", "speed"])
    try:
        return _run(args, trackers, out, cache, parts)
    except BenchInputError as exc:
        print(f"bench_capture: {exc}", file=sys.stderr)
        return 2


def _run(args, trackers, out: Path, cache: Path, parts) -> int:
    t0 = time.perf_counter()
    models, desc = load_models(args)
    res = {"benchmark": "capture (issue 12)", "quick": bool(args.quick), "models": desc,
           "trackers": trackers, "machine": {"python": platform.python_version(),
                                             "cpus": os.cpu_count()},
           "data_version": cd.DATA_VERSION, "date": time.strftime("%Y-%m-%d %H:%M:%S"),
           "notes": {"floor": "facetransfer.track.init.fit_landmarks on the true 68 points of every "
                              "frame, warm-started from the previous frame, prior "
                              + ("fit_landmarks' default" if args.floor_prior is None
                                 else str(args.floor_prior)),
                     "v3d": "mean vertex distance over FaceKit vertices 0-6705 after a per-frame "
                            "similarity alignment (Umeyama) of the tracked to the true face, mm",
                     "nme": "mean point distance / true outer eye-corner distance (36-45) per "
                            "frame; median and mean over frames",
                     "camera": "synthetic: pinhole 1200 px at 100 cm (12 px/cm), 512x512, 30 fps"}}
    res = _keep_other_parts(res, out / "capture.json", parts) if args.only else res
    stamp = {"model_hash": models["main"].content_hash, "quick": bool(args.quick),
             "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    if "synthetic" in parts:
        res["synthetic"] = run_synthetic(models, trackers, cache, args.quick) | stamp
        res["synthetic"]["verdict"] = synthetic_verdict(res["synthetic"])
        write_outputs(res, out)
    if "real" in parts and "ours" in trackers:
        res["real"] = run_real(models["main"], cache, args.quick) | stamp
        write_outputs(res, out)
    if "speed" in parts:
        res["speed"] = run_speed(args, models["main"], cache) | stamp
    res["seconds"] = round(time.perf_counter() - t0, 1)
    write_outputs(res, out)
    print_table(res)
    print(f"\nwrote {out / 'capture.json'} and {out / 'capture.png'} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

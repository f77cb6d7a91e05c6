"""Calibrate the MediaPipe -> iBUG-68 correspondence (issue 12) on synthetic clips with truth.

Writes ``src/facetransfer/data/mediapipe_ibug.json``, which
:func:`facetransfer.track.landmarks.mediapipe_to_ibug` loads.

The calibration clips are made by the *same* generator and painter as ``bench_capture.py``
(``_capture_data.make_clip``: fresh ICT-FaceKit identities, ARKit performances with blinks and
hard starts, head yaw / pitch up to ±30°, painted by OpenCV ``_cvpaint``) but from a *disjoint*
part of its seed stream: identity / performance indices ``CALIB_INDEX0 ..`` (101 on), where the
benchmark's 4 clips use 1-4; the start poses and expressions are drawn from a seed of their own.
:func:`calibration_specs` checks that no calibration index, identity draw or clip name is one of
the benchmark's, so the benchmark stays a held-out test of the result.

MediaPipe Face Landmarker runs in VIDEO mode on each clip (``_mp_video.cached_landmarker``, the
benchmark's runner and cache). For every iBUG point the weights of its table points
(:data:`~facetransfer.track.landmarks.MP_TO_IBUG`) plus the ``k`` nearest vertices of MediaPipe's
canonical mesh are solved by least squares against the true 2-D iBUG points of all frames
(:mod:`facetransfer.track.calibration`: weights summing to 1, residual / true eye-corner
distance, ridge towards the table). The ridge is chosen by leave-one-clip-out cross-validation.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/calibrate_landmarks.py [--out out/benchmarks]
        [--clips 16] [--frames 48] [--k 8] [--keep 0,1,...] [--dense] [--dry-run]

``--dense`` also calibrates the dense correspondence of the default model (FaceKit topology,
:mod:`facetransfer.track.dense`): for each MediaPipe point of the geometric correspondence, the
triangle and barycentric point within 1.2 cm of it on the mean face whose *true* projections
(the clips' face vertices through their known pose and camera) best match MediaPipe's point over
all frames; first fitted on 12 clips and checked on the other 4, then fitted on all 16, and
written to ``src/facetransfer/data/mediapipe_facekit_dense.json``.

``--keep``: iBUG points that keep the table's weights. Prints the cross-validation table and
writes ``OUT/calibrate_landmarks.json`` (the figures) and ``OUT/calibrate_landmarks.png`` (the
clip-mean offsets of both mappings on the benchmark's clips, and the stills) besides the data
file.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import _capture_data as cd  # noqa: E402
from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402

log = logging.getLogger("calibrate_landmarks")

#: First identity / performance index of the calibration clips (the benchmark uses 1-4).
CALIB_INDEX0 = 101
#: Seed of the calibration clips' start poses and expressions (not used by the benchmark).
START_SEED = (*cd.SEED_STREAM, 9001)
RIDGES = (1e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2)
KEY7 = [36, 39, 42, 45, 30, 48, 54]
INNER51 = list(range(17, 68))
_STARTS = ((), (("jawOpen", 0.7),), (("eyeBlinkLeft", 1.0), ("eyeBlinkRight", 1.0)),
           (("mouthSmileLeft", 0.8), ("mouthSmileRight", 0.7)), (("mouthPucker", 0.8),),
           (("browInnerUp", 0.8), ("jawOpen", 0.4)), (("mouthFunnel", 0.7),),
           (("browDownLeft", 0.7), ("browDownRight", 0.7), ("mouthSmileLeft", 0.5)))


def calibration_specs(n_clips: int, n_frames: int) -> list[cd.ClipSpec]:
    """The calibration clips' recipes, checked disjoint from the benchmark's (module notes)."""
    rng = np.random.default_rng(START_SEED)
    specs = [cd.ClipSpec(f"calib{k:02d}", CALIB_INDEX0 + k, n_frames=n_frames,
                         yaw0=round(float(rng.uniform(-30, 30)), 1),
                         pitch0=round(float(rng.uniform(-25, 25)), 1),
                         start=_STARTS[k % len(_STARTS)]) for k in range(n_clips)]
    bench_index = {s.index for s in cd.CLIPS}
    bench_names = {s.name for s in cd.CLIPS}
    clash = [s.name for s in specs if s.index in bench_index or s.name in bench_names]
    if clash:
        raise RuntimeError(f"calibration clips {clash} share a seed or name with bench_capture")
    bench_w = np.stack([cd.identity_weights(s.index, 1.0) for s in cd.CLIPS])
    for s in specs:
        d = np.linalg.norm(bench_w - cd.identity_weights(s.index, 1.0), axis=1).min()
        if d < 1.0:
            raise RuntimeError(f"calibration identity {s.index} is {d:.3f} std from a benchmark "
                               "identity")
    return specs


def load_frames(cache: Path, specs) -> list[dict]:
    """Per clip: MediaPipe's 478 points (VIDEO mode) and the true 68 points, (F, ., 2)."""
    fk = cd.facekit_loader(cache)

    out = []
    for s in specs:
        t0 = time.perf_counter()
        clip = cd.load_clip(cache, s, fk_loader=fk)
        with filtered_stderr(not log.isEnabledFor(logging.DEBUG)):
            pts, _ = cached_landmarker(clip.video, cache)
        out.append({"spec": s, "points": pts[:, :468], "truth": clip.landmarks,
                    "vertices": clip.vertices, "pose": clip.pose})
        log.info("clip %s: %d frames, %d without a face (%.1f s)", s.name, len(pts),
                 int(np.isnan(pts).any(axis=(1, 2)).sum()), time.perf_counter() - t0)
    return out


def _stack(clips) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    P = np.concatenate([c["points"] for c in clips])
    T = np.concatenate([c["truth"] for c in clips])
    return P, T, np.linalg.norm(T[:, 36] - T[:, 45], axis=1)


def weight_matrix(points, n: int = 468) -> np.ndarray:
    """(68, n) matrix of a list of :class:`~facetransfer.track.calibration.CalibratedPoint`."""
    W = np.zeros((68, n))
    for i, p in enumerate(points):
        W[i, p.indices] = p.weights
    return W


def _summary(err: np.ndarray) -> dict:
    """Median over frames of the 7-, 51- and 17-point (jaw) mean error, % of eye distance."""
    f = lambda idx: round(100 * float(np.nanmedian(np.nanmean(err[:, idx], axis=1))), 3)  # noqa
    return {"nme7": f(KEY7), "nme51": f(INNER51), "jaw": f(list(range(17)))}


def cross_validate(clips, candidates, prior, keep, ridges) -> dict:
    """Leave-one-clip-out error of the table and of the calibration at each ridge."""
    from facetransfer.track.calibration import calibrate_mapping, mapping_error

    rows = {"table": [], **{f"{r:g}": [] for r in ridges}}
    for k in range(len(clips)):
        train = [c for j, c in enumerate(clips) if j != k]
        Pt, Tt, st = _stack(train)
        Pv, Tv, sv = _stack([clips[k]])
        ok = np.isfinite(Pv).all(axis=(1, 2))
        rows["table"].append(mapping_error(prior, Pv[ok], Tv[ok], sv[ok]))
        for r in ridges:
            W = weight_matrix(calibrate_mapping(Pt, Tt, st, candidates, prior, ridge=r,
                                                fixed=keep))
            rows[f"{r:g}"].append(mapping_error(W, Pv[ok], Tv[ok], sv[ok]))
    return {k: _summary(np.concatenate(v)) for k, v in rows.items()}


def read_pts(path: Path) -> np.ndarray:
    """iBUG ``.pts`` points (68, 2), converted from the format's 1-based pixels to 0-based
    (pixel centres at integers, as ``_mp_video`` reports MediaPipe's points)."""
    lines = path.read_text().split("{", 1)[1].split("}", 1)[0].split()
    P = np.asarray(lines, float).reshape(-1, 2)
    if P.shape != (68, 2):
        raise ValueError(f"{path}: expected 68 points, got {P.shape[0]}")
    return P - 1.0


def image_landmarks(image: np.ndarray) -> np.ndarray:
    """Face Landmarker in IMAGE mode on one RGB image: (478, 2) pixels (NaN: no face)."""
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    from _mp_video import _task_path

    opts = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(
        _task_path())), running_mode=vision.RunningMode.IMAGE, num_faces=1)
    H, W = image.shape[:2]
    with vision.FaceLandmarker.create_from_options(opts) as lm:
        res = lm.detect(mp.Image(image_format=mp.ImageFormat.SRGB,
                                 data=np.ascontiguousarray(image, np.uint8)))
    if not res.face_landmarks:
        return np.full((478, 2), np.nan)
    return np.array([[q.x * W - 0.5, q.y * H - 0.5] for q in res.face_landmarks[0]])


def face_crop_landmarks(image: np.ndarray, around: np.ndarray, size: int = 512) -> np.ndarray:
    """:func:`image_landmarks` on a square crop (twice the points' extent, resized to ``size``)
    around ``around`` (68, 2), mapped back to the image's pixels: Face Landmarker's detector
    misses small faces (einstein's is 85 px wide in 817x1024)."""
    import cv2

    c, half = around.mean(axis=0), np.ptp(around, axis=0).max()
    f = size / (2 * half)
    A = np.array([[f, 0, size / 2 - f * c[0]], [0, f, size / 2 - f * c[1]]])
    crop = cv2.warpAffine(image, A, (size, size), flags=cv2.INTER_AREA if f < 1 else
                          cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return (image_landmarks(crop) - A[:, 2]) / f


def validate_stills(matrices: dict) -> dict:
    """NME (% of the human outer eye-corner distance) of each mapping on the stills with human
    iBUG-68 annotation (``FACETRANSFER_DATA_DIR/stills``), MediaPipe in IMAGE mode."""
    import cv2

    from facetransfer import assets

    d = Path(assets.data_dir() or "") / "stills"
    out: dict = {}
    for pts in sorted(d.glob("*.pts")):
        img = next((p for p in sorted(d.glob(pts.stem + ".*")) if p.suffix != ".pts"), None)
        bgr = None if img is None else cv2.imread(str(img), cv2.IMREAD_COLOR)
        if bgr is None:
            log.warning("no readable image for %s", pts)
            continue
        H = read_pts(pts)
        with filtered_stderr(not log.isEnabledFor(logging.DEBUG)):
            P = face_crop_landmarks(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), H)
        s = np.linalg.norm(H[36] - H[45])
        row = {}
        for name, W in matrices.items():
            e = np.linalg.norm(W @ P[:W.shape[1]] - H, axis=1) / s
            row[name] = {"nme7": _pct(e[KEY7]), "nme51": _pct(e[INNER51]),
                         "jaw": _pct(e[:17]), "per_point": [_pct(x) for x in e]}
        out[pts.stem] = row
    return out


#: Points whose table mapping sat off the FaceKit's iBUG vertices with one sign on all 4 clips.
BIASED = {"inner lip 61/63/65/67": [61, 63, 65, 67], "outer lip 49/53/56/58": [49, 53, 56, 58],
          "nostril wings 31/35": [31, 35], "nose bridge 29": [29], "nose tip 30": [30],
          "mouth corners 48/54": [48, 54]}


def face_frame_offsets(cache: Path, matrices: dict) -> dict:
    """Per benchmark clip: the true points and each mapping's offsets from them in the face's
    frame (x along the true eye axis, / the true eye-corner distance), (F, 68, 2) each."""
    out = {}
    for spec in cd.CLIPS:
        clip = cd.load_clip(cache, spec)
        with filtered_stderr(not log.isEnabledFor(logging.DEBUG)):
            pts, _ = cached_landmarker(clip.video, cache)
        T = clip.landmarks
        ax = T[:, 45] - T[:, 36]
        s = np.linalg.norm(ax, axis=1)
        c, sn = ax[:, 0] / s, ax[:, 1] / s
        R = np.stack([np.stack([c, sn], 1), np.stack([-sn, c], 1)], 1)       # (F, 2, 2)
        ctr = T[:, 36:48].mean(axis=1, keepdims=True)
        row = {"truth": np.einsum("fij,fpj->fpi", R, T - ctr) / s[:, None, None]}
        for name, W in matrices.items():
            Y = np.einsum("im,fmd->fid", W, pts[:, :W.shape[1]])
            row[name] = np.einsum("fij,fpj->fpi", R, Y - T) / s[:, None, None]
        out[spec.name] = row
    return out


def benchmark_bias(offsets: dict) -> dict:
    """On the benchmark's own 4 clips (held out): the length of the clip-mean offset of each
    mapping's points from the truth (:func:`face_frame_offsets`), % of the true eye-corner
    distance, averaged over the points of each :data:`BIASED` group; and the 7- / 51-point NME
    median of the mapped MediaPipe points."""
    rows: dict = {}
    for clip, row in offsets.items():
        for name, d in row.items():
            if name == "truth":
                continue
            off = np.linalg.norm(np.nanmean(d, axis=0), axis=1)             # (68,)
            e = np.linalg.norm(d, axis=2)
            rows.setdefault(name, {})[clip] = {
                "nme7": round(100 * float(np.nanmedian(e[:, KEY7].mean(1))), 3),
                "nme51": round(100 * float(np.nanmedian(e[:, INNER51].mean(1))), 3),
                "bias": {g: round(100 * float(off[idx].mean()), 2) for g, idx in BIASED.items()}}
    return rows


def plot_offsets(offsets: dict, stills: dict, path: Path, *, gain: float = 3.0) -> None:
    """The clip-mean offsets of each mapping on the benchmark's clips, drawn ``gain`` times
    enlarged on the mean true face (one colour per clip), and the stills' NME."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    names = [k for k in next(iter(offsets.values())) if k != "truth"]
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(5.5 * (len(names) + 1), 5.5))
    for ax, name in zip(axes, names):
        for (clip, row), col in zip(offsets.items(), plt.cm.tab10.colors):
            P = np.nanmean(row["truth"], axis=0)
            D = np.nanmean(row[name], axis=0)
            ax.scatter(P[17:, 0], P[17:, 1], s=4, color="0.6")
            ax.quiver(P[17:, 0], P[17:, 1], gain * D[17:, 0], gain * D[17:, 1], color=col,
                      angles="xy", scale_units="xy", scale=1, width=0.004, label=clip)
        ax.set_title(f"{name}: clip-mean offset from the truth (x{gain:g})")
        ax.set_aspect("equal")
        ax.invert_yaxis()
        ax.legend(fontsize=7)
    ax = axes[-1]
    x = np.arange(len(stills))
    for k, (name, off) in enumerate((("table", -0.2), ("calibrated", 0.2))):
        for j, (m, hatch) in enumerate((("nme7", ""), ("nme51", "//"))):
            ax.bar(x + off + (j - 0.5) * 0.2, [r[name][m] for r in stills.values()], 0.2,
                   color=("tab:gray", "tab:blue")[k], hatch=hatch,
                   label=f"{name} {m.replace('nme', '')}-pt")
    ax.set_xticks(x, list(stills))
    ax.set_ylabel("NME, % of the human eye-corner distance")
    ax.set_title("stills with human iBUG-68 points")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _pct(e) -> float | None:
    v = float(np.mean(e))
    return round(100 * v, 3) if np.isfinite(v) else None


def choose_ridge(cv: dict, ridges, tolerance: float = 0.03) -> float:
    """The largest ridge whose held-out 51-point NME is within ``tolerance`` (relative) of the
    best: smaller ridges buy little and give large weights of opposite signs, which amplify
    MediaPipe's frame-to-frame noise and extrapolate outside the calibration faces."""
    best = min(cv[f"{r:g}"]["nme51"] for r in ridges)
    return float(max(r for r in ridges if cv[f"{r:g}"]["nme51"] <= (1 + tolerance) * best))


# ------------------------------------------------------------------------------ dense
def projected_vertices(clip: dict) -> np.ndarray:
    """The true face-area vertices of a calibration clip projected as ``make_clip`` paints them,
    (F, FACE_END, 2) float32 pixels."""
    import _cvpaint as cvp

    cam = cvp.Camera(size=cd.SIZE)
    out = np.empty(clip["vertices"].shape[:2] + (2,), np.float32)
    for i, (X, P) in enumerate(zip(clip["vertices"], clip["pose"])):
        R = cvp.rotation_ypr(*P[:3])
        out[i] = cvp.project(cvp.to_camera(X.astype(np.float64), R,
                                           np.array([P[3], P[4], 0.0])), cam)
    return out


def calibrate_dense(clips, model, dc, *, radius: float = 1.2) -> tuple:
    """Per MediaPipe point of the geometric correspondence ``dc``: the triangle and barycentric
    point of the model's face (FaceKit topology) within ``radius`` cm of the geometric point on
    the mean face whose true projections best match MediaPipe's point over ``clips``
    (:func:`~facetransfer.track.calibration.best_triangle_point`).

    Returns
    -------
    triangles (P, 3), bary (P, 3), rms_geometric (P,), rms_calibrated (P,)
    """
    from scipy.spatial import cKDTree

    from facetransfer.track.calibration import best_triangle_point

    V2 = np.concatenate([projected_vertices(c) for c in clips])             # (F, n, 2)
    M = np.concatenate([c["points"] for c in clips])                        # (F, 468, 2)
    T = np.concatenate([c["truth"] for c in clips])
    ok = np.isfinite(M).all(axis=(1, 2))
    V2, M, s = V2[ok], M[ok], np.linalg.norm(T[ok, 36] - T[ok, 45], axis=1)
    neutral = model.synthesize(model.default_weights())
    here = dc.sample(neutral)                                               # (P, 3)
    tree = cKDTree(neutral)
    faces = np.asarray(model.faces, np.int64)
    tris, bary, rms0, rms1 = [], [], [], []
    for p, j in enumerate(dc.mp_index):
        near = np.zeros(len(neutral), bool)
        near[tree.query_ball_point(here[p], radius)] = True
        cand = np.unique(np.vstack([faces[near[faces].any(axis=1)], dc.triangles[p:p + 1]]),
                         axis=0)
        k, w, e = best_triangle_point(V2, M[:, j], s, cand)
        geo = np.einsum("fkd,k->fd", V2[:, dc.triangles[p]], dc.bary[p]) - M[:, j]
        tris.append(cand[k])
        bary.append(w)
        rms0.append(float(np.sqrt(((geo / s[:, None]) ** 2).sum(1).mean())))
        rms1.append(e)
    return np.array(tris), np.array(bary), np.array(rms0), np.array(rms1)


def dense_error(clips, triangles, bary, mp_index) -> np.ndarray:
    """Per point rms distance (/ true eye-corner distance) of MediaPipe's points from the
    projections of their surface points, (P,)."""
    V2 = np.concatenate([projected_vertices(c) for c in clips])
    M = np.concatenate([c["points"] for c in clips])
    T = np.concatenate([c["truth"] for c in clips])
    ok = np.isfinite(M).all(axis=(1, 2))
    s = np.linalg.norm(T[ok, 36] - T[ok, 45], axis=1)
    Y = np.einsum("fpkd,pk->fpd", V2[ok][:, triangles], bary)
    d = (Y - M[ok][:, mp_index]) / s[:, None, None]
    return np.sqrt((d ** 2).sum(2).mean(0))


def run_dense(args, clips) -> dict:
    """Calibrate the dense correspondence of the default model (held-out check on the last 4
    clips first) and write ``mediapipe_facekit_dense.json``. The geometric correspondence it
    starts from (the search centres) uses the iBUG mapping installed when the run starts."""
    from facetransfer.default_model import load_default_model
    from facetransfer.track.dense import faces_hash, mediapipe_correspondence

    model = load_default_model(announce=log.info)
    dc = mediapipe_correspondence(model, calibrated=False)
    train, test = clips[:-4], clips[-4:]
    tr, ba, _, _ = calibrate_dense(train, model, dc)
    e_geo = dense_error(test, dc.triangles, dc.bary, dc.mp_index)
    e_cal = dense_error(test, tr, ba, dc.mp_index)
    held = {"clips": [c["spec"].name for c in test],
            "rms_median_geometric": round(100 * float(np.median(e_geo)), 3),
            "rms_median_calibrated": round(100 * float(np.median(e_cal)), 3),
            "rms_mean_geometric": round(100 * float(np.mean(e_geo)), 3),
            "rms_mean_calibrated": round(100 * float(np.mean(e_cal)), 3)}
    print(f"dense points, held-out clips, rms % of eye distance: geometric median "
          f"{held['rms_median_geometric']:.2f} mean {held['rms_mean_geometric']:.2f} -> calibrated "
          f"median {held['rms_median_calibrated']:.2f} mean {held['rms_mean_calibrated']:.2f}")
    tr, ba, _, _ = calibrate_dense(clips, model, dc)
    doc = {"format": "facetransfer MediaPipe dense correspondence on a FaceKit-topology face",
           "version": 1, "n_vertices": int(model.n_vertices),
           "faces_sha256": faces_hash(model.faces),
           "provenance": {"script": "benchmarks/calibrate_landmarks.py --dense",
                          "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
                          "clips": [c["spec"].name for c in clips],
                          "identity_indices": [c["spec"].index for c in clips],
                          "held_out_check": held},
           "mp_index": dc.mp_index.tolist(), "triangles": tr.tolist(),
           "bary": np.round(ba, 6).tolist()}
    if not args.dry_run:
        from facetransfer.io.atomic import write_text_atomic

        dest = Path(__file__).resolve().parents[1] / "src/facetransfer/data/" \
            "mediapipe_facekit_dense.json"
        write_text_atomic(dest, json.dumps(doc) + "\n")
        print(f"wrote {dest}")
    return held


def write_data(path: Path, points, provenance: dict) -> None:
    """The data file: weights per iBUG point (rounded to 1e-6, sum exactly 1) and provenance."""
    from facetransfer.io.atomic import write_text_atomic
    from facetransfer.track.landmarks import ibug_names

    rows = []
    names = ibug_names()
    for i, p in enumerate(points):
        w = np.round(p.weights, 6)
        w[np.argmax(np.abs(w))] += round(1.0 - float(w.sum()), 6)
        keep = w != 0
        rows.append({"ibug": i, "name": names[i], "mediapipe": p.indices[keep].tolist(),
                     "weights": [float(x) for x in w[keep]]})
    doc = {"format": "facetransfer MediaPipe-to-iBUG-68 correspondence", "version": 1,
           "description": "iBUG point i = sum of weights * MediaPipe Face Landmarker points "
                          "(pixel coordinates); rows sum to 1",
           "provenance": provenance, "points": rows}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder (cache inside)")
    ap.add_argument("--clips", type=int, default=16)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--k", type=int, default=8, help="nearest canonical vertices added")
    ap.add_argument("--keep", default="", help="iBUG points keeping the table, e.g. 0,1,2")
    ap.add_argument("--ridge", type=float, default=None, help="skip the cross-validation")
    ap.add_argument("--dry-run", action="store_true", help="do not write the data file")
    ap.add_argument("--dense", action="store_true",
                    help="also calibrate the dense correspondence of the default model")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(message)s", datefmt="%H:%M:%S")
    log.setLevel(logging.INFO)
    try:
        keep = [int(x) for x in args.keep.split(",") if x.strip()]
    except ValueError:
        print(f"calibrate_landmarks: --keep must be comma-separated integers, got {args.keep!r}",
              file=sys.stderr)
        return 2
    return run(args, keep)


def solve(args, clips, candidates, prior, keep) -> tuple[list, float, dict | None]:
    """The calibrated points, the ridge and the cross-validation table (None with --ridge)."""
    from facetransfer.track.calibration import calibrate_mapping

    cv, ridge = None, args.ridge
    if ridge is None:
        cv = cross_validate(clips, candidates, prior, keep, RIDGES)
        ridge = choose_ridge(cv, RIDGES)
        print("leave-one-clip-out median NME, % of the true eye-corner distance")
        print(f"{'mapping':10s} {'7-pt':>7s} {'51-pt':>7s} {'jaw':>7s}")
        for k, v in cv.items():
            print(f"{k:10s} {v['nme7']:7.3f} {v['nme51']:7.3f} {v['jaw']:7.3f}"
                  + ("  <- chosen" if k == f"{ridge:g}" else ""))
    P, T, s = _stack(clips)
    return calibrate_mapping(P, T, s, candidates, prior, ridge=ridge, fixed=keep), ridge, cv


def provenance_of(args, specs, n_frames: int, ridge: float, keep, cv) -> dict:
    """What the data file records about its making."""
    import mediapipe

    return {
        "script": "benchmarks/calibrate_landmarks.py", "prior": "facetransfer.track.landmarks."
        "MP_TO_IBUG", "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "seed_stream": list(cd.SEED_STREAM), "start_seed": list(START_SEED),
        "data_version": cd.DATA_VERSION,
        "clips": [{"name": s_.name, "index": s_.index, "frames": s_.n_frames, "yaw0": s_.yaw0,
                   "pitch0": s_.pitch0, "start": [list(x) for x in s_.start]} for s_ in specs],
        "frames": n_frames, "mediapipe": mediapipe.__version__, "mode": "VIDEO",
        "k_nearest": args.k, "ridge": ridge, "kept_table": keep,
        "benchmark_indices_excluded": [s_.index for s_ in cd.CLIPS],
        "cross_validation": cv}


def print_checks(res: dict) -> None:
    print("held out, the benchmark's clips: MediaPipe's mapped points, NME % and clip-mean "
          "offset % (table -> calibrated)")
    for clip, row in res["benchmark_clips"]["table"].items():
        new = res["benchmark_clips"]["calibrated"][clip]
        print(f"  {clip:12s} nme7 {row['nme7']:.2f} -> {new['nme7']:.2f}  nme51 {row['nme51']:.2f}"
              f" -> {new['nme51']:.2f}  " + ", ".join(
                  f"{g.split()[0]}{g.split()[-1]} {row['bias'][g]:.1f}->{new['bias'][g]:.1f}"
                  for g in BIASED))
    print("stills with human iBUG-68 points, NME % (table -> calibrated):")
    for name, row in res["stills"].items():
        print(f"  {name:12s} " + "  ".join(
            f"{k} {row['table'][k]:.2f} -> {row['calibrated'][k]:.2f}"
            for k in ("nme7", "nme51", "jaw")))
    print(f"noise gain sqrt(sum w^2): median {res['noise_gain']['median']}, "
          f"max {res['noise_gain']['max']} (table: 0.71-1)")


def run(args, keep) -> int:
    from facetransfer.io.atomic import write_text_atomic
    from facetransfer.track.calibration import candidate_sets
    from facetransfer.track.dense import _canonical
    from facetransfer.track.landmarks import MP_TO_IBUG, table_matrix

    out = Path(args.out)
    cache = out / "capture_cache"
    specs = calibration_specs(args.clips, args.frames)
    clips = load_frames(cache, specs)
    prior = table_matrix(468)
    points, ridge, cv = solve(args, clips, candidate_sets(_canonical(), MP_TO_IBUG, k=args.k),
                              prior, keep)
    n_ok = int(sum(np.isfinite(c["points"]).all(axis=(1, 2)).sum() for c in clips))
    provenance = provenance_of(args, specs, n_ok, ridge, keep, cv)
    W = weight_matrix(points)
    gain = np.sqrt((W ** 2).sum(axis=1))
    res = {"provenance": provenance,
           "stills": validate_stills({"table": prior, "calibrated": W}),
           "noise_gain": {"max": round(float(gain.max()), 3),
                          "median": round(float(np.median(gain)), 3)},
           }
    offsets = face_frame_offsets(cache, {"table": prior, "calibrated": W})
    res["benchmark_clips"] = benchmark_bias(offsets)
    print_checks(res)
    out.mkdir(parents=True, exist_ok=True)
    plot_offsets(offsets, res["stills"], out / "calibrate_landmarks.png")
    if args.dense:
        res["dense"] = run_dense(args, clips)
    write_text_atomic(out / "calibrate_landmarks.json", json.dumps(res, indent=1))
    if not args.dry_run:
        dest = Path(__file__).resolve().parents[1] / "src/facetransfer/data/mediapipe_ibug.json"
        write_data(dest, points, provenance)
        print(f"wrote {dest} (ridge {ridge:g}, {n_ok} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark of issue 7: face tracking in monocular video (Vlasic et al. 2005, §5.1, §5.2).

Measures, in one run:

1. synthetic footage with ground truth (``facetransfer.synth``, the ICT bilinear model, several
   seeds = identities, gentle and strong head motion, 640x480): mean 3-D vertex error in mm (in
   camera space after the fitted scale, and of the shape alone after a similarity alignment),
   rotation error (degrees), landmark error (pixels and fraction of the outer eye-corner
   distance) and weight error per mode (RMS in units of the training spread), for the tracker
   and for the plain baseline (OpenCV pyramidal LK on the projected vertices, then the model
   fitted to the moved points);
2. real clips (``FACETRANSFER_DATA_DIR/video``): landmark error against the stored MediaPipe
   references (eye corners, nose tip, mouth corners; and all 51 inner iBUG points), drift over
   the 1008 frames of ``driving_d6`` (error vs frame), jitter (frame-to-frame landmark
   acceleration on still segments), with anchoring off and on, and the LK baseline;
3. speed: frames per second of a single forward pass at 640x480 with ~1000 tracked vertices and
   of the full multi-pass tracking, beside MediaPipe Face Landmarker's own per-frame time
   (wall clock and process CPU time: the machine may be shared).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_track.py [--out out/benchmarks]
        [--model MODEL.npz] [--max-frames N] [--seeds 3] [--synthetic-frames 60]

Writes ``OUT/track.json``, ``OUT/track.png`` and ``OUT/track_overlay.png``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

KEY = [36, 39, 42, 45, 30, 48, 54]          # eye corners, nose tip, mouth corners (iBUG-68)
INNER = list(range(17, 68))
CLIPS = ("face_2", "WDA_KatieHill_000", "driving_d9", "driving_d6")


# ------------------------------------------------------------------------------ helpers
class Clock:
    """Wall and process-CPU time of a block."""

    def __enter__(self):
        self.w0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.w0
        self.cpu = time.process_time() - self.c0


class CachedDetector:
    """MediaPipe detections cached by frame content (shared by all runs on a clip)."""

    def __init__(self, det):
        self.det = det
        self.cache: dict[bytes, np.ndarray | None] = {}
        self.seconds = []

    @staticmethod
    def key(frame):
        data = np.ascontiguousarray(frame[::7, ::7]).tobytes()
        return hashlib.blake2b(data, digest_size=16).digest()

    def detect(self, frame):
        k = self.key(frame)
        if k not in self.cache:
            with Clock() as c:
                self.cache[k] = self.det.detect(frame)
            self.seconds.append((c.wall, c.cpu))
        return self.cache[k]


def load_or_build_model(path: Path):
    from facetransfer.model import load_model

    if not path.is_file():
        from facetransfer.cli.main import main as cli

        code = cli(["model", "build", "--dataset", "ict-bilinear", "--out", str(path)])
        if code:
            raise SystemExit(f"could not build the ICT bilinear model ({code})")
    return load_model(path)


def rotation_deg(Ra, Rb):
    dR = np.einsum("fij,fkj->fik", Ra, Rb)
    return np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def camera_points(V, R, s, t):
    """(F, n, 3): pixel x, y and depth (pixels) of model vertices under each frame's pose."""
    Y = np.einsum("fij,fnj->fni", R, V) * s[:, None, None]
    Y[..., 1] *= -1
    Y[..., :2] += t[:, None, :]
    return Y


def similarity_error(A, B):
    """Mean distance after aligning A to B with rotation, translation and scale (per frame)."""
    out = []
    for a, b in zip(A, B):
        a0, b0 = a - a.mean(0), b - b.mean(0)
        U, S, Vt = np.linalg.svd(a0.T @ b0)
        D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
        c = (S * np.diag(D)).sum() / (a0 ** 2).sum()
        out.append(np.linalg.norm(c * a0 @ R - b0, axis=1).mean())
    return np.array(out)


def synth_metrics(model, est, truth, stride=4):
    """Errors of an estimate (R, s, t, weights) against synthetic truth."""
    F = truth.n_frames
    v = np.arange(0, model.n_vertices, stride)
    Vt = model.synthesize(truth.weights, vertices=v)
    Ve = model.synthesize(est["weights"], vertices=v)
    Pt = camera_points(Vt, truth.rotation, truth.scale, truth.translation)
    Pe = camera_points(Ve, est["rotation"], est["scale"], est["translation"])
    Pe[..., 2] += (Pt[..., 2].mean(1) - Pe[..., 2].mean(1))[:, None]   # depth offset unobservable
    cm_per_px = 1.0 / truth.scale                                        # ICT model units: cm
    err3d = np.linalg.norm(Pe - Pt, axis=2).mean(1) * cm_per_px * 10.0   # mm
    shape = similarity_error(Ve, Vt) * 10.0                              # mm
    L = est["landmarks2d"]
    lm = np.linalg.norm(L - truth.landmarks2d, axis=2).mean(1)
    iod = np.linalg.norm(truth.landmarks2d[:, 36] - truth.landmarks2d[:, 45], axis=1)
    werr = {}
    for k in model.mode_names:
        spread = np.sqrt(np.trace(model.weight_cov(k)) / model.ranks[model.mode_index(k)])
        werr[k] = float(np.sqrt(np.mean((est["weights"][k] - truth.weights[k]) ** 2)) / spread)
    return {"vertex3d_mm": float(err3d.mean()), "shape_mm": float(shape.mean()),
            "rotation_deg": float(rotation_deg(est["rotation"], truth.rotation).mean()),
            "landmark_px": float(lm.mean()), "landmark_frac_iod": float((lm / iod).mean()),
            "landmark_px_last": float(lm[-1]), "weight_rms_per_spread": werr}


def track_dict(tr):
    return {"rotation": tr.rotation, "scale": tr.scale, "translation": tr.translation,
            "weights": tr.weights, "landmarks2d": tr.landmarks2d}


# ------------------------------------------------------------------------------ LK baseline
def track_lk(frames, model, L0, *, n_points=1000, prior=0.002):
    """Baseline: cv2.calcOpticalFlowPyrLK on the projected vertices, model fitted to the moved
    points (pose + per-frame modes; identity from the first-frame fit)."""
    import cv2

    from facetransfer.track.camera import project
    from facetransfer.track.init import fit_landmarks
    from facetransfer.track.klt import build_pyramid
    from facetransfer.track.solver import fit_points
    from facetransfer.track.tracker import FaceTracker, TrackOptions

    H, W = frames[0].shape[:2]
    tr = FaceTracker(model, (W, H), TrackOptions(n_points=n_points))
    st = fit_landmarks(model, L0)
    states = [st]
    gray0 = cv2.cvtColor(frames[0], cv2.COLOR_RGB2GRAY)
    pyr0 = build_pyramid(frames[0], 2)
    for fr in frames[1:]:
        gray1 = cv2.cvtColor(fr, cv2.COLOR_RGB2GRAY)
        sel, q = tr.select_vertices(st, pyr0)
        if sel.size >= 10:
            p1, ok, _ = cv2.calcOpticalFlowPyrLK(gray0, gray1, q.astype(np.float32), None,
                                                 winSize=(15, 15), maxLevel=3)
            ok = ok.ravel() == 1
            if ok.sum() >= 10:
                st = fit_points(model, sel[ok], p1[ok].astype(float), state=st,
                                modes=tr.per_frame, prior=prior, iterations=3)
        states.append(st)
        gray0, pyr0 = gray1, build_pyramid(fr, 2)
    R = np.stack([s.pose.rotation for s in states])
    s = np.array([s.pose.scale for s in states])
    t = np.stack([s_.pose.translation for s_ in states])
    w = {k: np.stack([s_.weights[k] for s_ in states]) for k in model.mode_names}
    X = model.synthesize(w, vertices=model.landmarks)
    L = np.stack([project(X[i], R[i], s[i], t[i]) for i in range(len(states))])
    return {"rotation": R, "scale": s, "translation": t, "weights": w, "landmarks2d": L}


# ------------------------------------------------------------------------------ 1. synthetic
MOTIONS = {"gentle": dict(yaw_deg=8, pitch_deg=5, roll_deg=3, translate_px=10),
           "strong": dict(yaw_deg=25, pitch_deg=12, roll_deg=8, translate_px=30)}


def bench_synthetic(model, seeds, n_frames, log):
    from facetransfer.synth import make_clip, random_performance
    from facetransfer.track.tracker import TrackOptions, track_video

    rows = []
    for motion, kw in MOTIONS.items():
        for seed in seeds:
            perf = random_performance(model, n_frames, seed=seed, size=(640, 480), fps=25, **kw)
            clip = make_clip(model, perf, seed=seed)
            T = clip.truth
            rng = np.random.default_rng(seed)
            iod = np.linalg.norm(T.landmarks2d[0, 36] - T.landmarks2d[0, 45])
            L0 = T.landmarks2d[0] + rng.normal(size=(68, 2)) * 0.01 * iod   # detector-like noise
            res = {"motion": motion, "seed": seed, "n_frames": n_frames}
            with Clock() as c:
                tr = track_video(clip.frames, model, init=L0,
                                 options=TrackOptions(passes=2, recover=False))
            res["tracker"] = synth_metrics(model, track_dict(tr), T)
            res["tracker"]["seconds"] = c.wall
            with Clock() as c:
                lk = track_lk(clip.frames, model, L0)
            res["lk_baseline"] = synth_metrics(model, lk, T)
            res["lk_baseline"]["seconds"] = c.wall
            log(f"synthetic {motion} seed {seed}: tracker {res['tracker']['landmark_px']:.2f} px "
                f"{res['tracker']['vertex3d_mm']:.2f} mm {res['tracker']['rotation_deg']:.2f} deg; "
                f"LK {res['lk_baseline']['landmark_px']:.2f} px "
                f"{res['lk_baseline']['vertex3d_mm']:.2f} mm")
            rows.append(res)
    summary = {}
    for motion in MOTIONS:
        for meth in ("tracker", "lk_baseline"):
            sel = [r[meth] for r in rows if r["motion"] == motion]
            summary[f"{motion}/{meth}"] = {
                k: float(np.mean([s[k] for s in sel]))
                for k in ("vertex3d_mm", "shape_mm", "rotation_deg", "landmark_px",
                          "landmark_frac_iod", "landmark_px_last")}
            summary[f"{motion}/{meth}"]["weight_rms_per_spread"] = {
                m: float(np.mean([s["weight_rms_per_spread"][m] for s in sel]))
                for m in model.mode_names}
    return {"runs": rows, "summary": summary}


# ------------------------------------------------------------------------------ 2. real clips
def real_errors(L, ref):
    iod = np.linalg.norm(ref[:, 36] - ref[:, 45], axis=1)
    ok = np.isfinite(iod)
    key = np.linalg.norm(L[:, KEY] - ref[:, KEY], axis=2).mean(1) / iod
    inner = np.linalg.norm(L[:, INNER] - ref[:, INNER], axis=2).mean(1) / iod
    return key, inner, ok


def jitter(L, ref, still):
    """Mean |L[t+1] - 2 L[t] + L[t-1]| over the eye corners and nose on still frames, / eye
    distance (the mouth moves while talking, so it is left out)."""
    iod = np.linalg.norm(ref[:, 36] - ref[:, 45], axis=1)
    acc = L[2:, RIGID] - 2 * L[1:-1, RIGID] + L[:-2, RIGID]
    acc = np.linalg.norm(acc, axis=2).mean(1) / iod[1:-1]
    m = still[1:-1] & np.isfinite(acc)
    return float(acc[m].mean()) if m.any() else float("nan")


RIGID = [36, 39, 42, 45, 27, 30]            # eye corners and nose: move only with the head


def still_frames(ref):
    """Frames where the head holds still: the reference eye corners and nose, averaged over 9
    frames (MediaPipe's own jitter removed), move less than 0.3 % of the eye distance per
    frame; the mouth may move."""
    from scipy.ndimage import uniform_filter1d

    iod = np.linalg.norm(ref[:, 36] - ref[:, 45], axis=1)
    P = uniform_filter1d(np.nan_to_num(ref[:, RIGID]), 9, axis=0, mode="nearest")
    v = np.r_[np.nan, np.linalg.norm(np.diff(P, axis=0), axis=2).mean(1) / iod[1:]]
    v[~np.isfinite(v)] = 1.0
    return v < 0.003


def bench_real(model, data, max_frames, log, det, passes):
    from facetransfer.io.video import read_video
    from facetransfer.track.landmarks import mediapipe_to_ibug
    from facetransfer.track.tracker import TrackOptions, track_video

    out = {}
    curves = {}
    for name in CLIPS:
        path = data / "video" / f"{name}.mp4"
        frames, fps = read_video(path, max_frames=max_frames)
        F = len(frames)
        ref = mediapipe_to_ibug(np.load(data / "video" / f"{name}.mediapipe478.npz")
                                ["landmarks"][:F, :, :2])
        still = still_frames(ref)
        cd = CachedDetector(det)
        with Clock() as c:
            for fr in frames:                      # MediaPipe's own per-frame time
                cd.detect(fr)
        mp_L = np.stack([cd.detect(fr) if cd.detect(fr) is not None else np.full((68, 2), np.nan)
                         for fr in frames])
        res = {"n_frames": F, "fps": fps, "size": list(frames.shape[2:0:-1]),
               "still_frames": int(still.sum()),
               "mediapipe_ms_per_frame_wall": 1000 * c.wall / F,
               "mediapipe_ms_per_frame_cpu": 1000 * c.cpu / F}
        k, i, ok = real_errors(mp_L, ref)
        res["mediapipe_live"] = {"key_frac_iod": float(np.nanmean(k)),
                                 "inner_frac_iod": float(np.nanmean(i)),
                                 "jitter_frac_iod": jitter(mp_L, ref, still)}
        res["reference_jitter_frac_iod"] = jitter(ref, ref, still)
        curves[name] = {}
        for label, anchor, kf in (("tracker_paper", False, 0.0), ("tracker", False, None),
                                  ("tracker_anchor", True, None)):
            kw = {} if kf is None else {"keyframe": kf}
            with Clock() as c:
                tr = track_video(frames, model, init="auto", detector=cd,
                                 options=TrackOptions(passes=passes, anchor=anchor, **kw))
            k, i, ok = real_errors(tr.landmarks2d, ref)
            res[label] = {"key_frac_iod": float(np.nanmean(k)),
                          "inner_frac_iod": float(np.nanmean(i)),
                          "key_frac_iod_first100": float(np.nanmean(k[:100])),
                          "key_frac_iod_last100": float(np.nanmean(k[-100:])),
                          "jitter_frac_iod": jitter(tr.landmarks2d, ref, still),
                          "mean_confidence": float(tr.confidence.mean()),
                          "lost_frames": int(tr.lost.sum()),
                          "reinitialised": len(tr.info["reinitialised"]),
                          "seconds_wall": c.wall, "seconds_cpu": c.cpu, "passes": passes}
            curves[name][label] = k.tolist()
            if anchor:   # zero-phase smoothing of the same run (no lag), sigma 1.5 frames
                Ls = smoothed_landmarks(model, tr, 1.5)
                ks, i_s, _ = real_errors(Ls, ref)
                res["tracker_anchor_smooth"] = {
                    "key_frac_iod": float(np.nanmean(ks)), "inner_frac_iod": float(np.nanmean(i_s)),
                    "jitter_frac_iod": jitter(Ls, ref, still), "sigma_frames": 1.5}
            log(f"{name} {label}: key {res[label]['key_frac_iod']:.3f} IOD, jitter "
                f"{res[label]['jitter_frac_iod']:.4f}, {c.wall:.0f} s")
            if name == "driving_d6" and anchor:
                out["_overlay_track"] = tr
        first = np.nan_to_num(mp_L[0], nan=np.nan)
        L0 = first if np.isfinite(first[KEY]).all() else ref[0]
        with Clock() as c:
            lk = track_lk(frames, model, L0)
        k, i, ok = real_errors(lk["landmarks2d"], ref)
        res["lk_baseline"] = {"key_frac_iod": float(np.nanmean(k)),
                              "inner_frac_iod": float(np.nanmean(i)),
                              "key_frac_iod_first100": float(np.nanmean(k[:100])),
                              "key_frac_iod_last100": float(np.nanmean(k[-100:])),
                              "jitter_frac_iod": jitter(lk["landmarks2d"], ref, still),
                              "seconds_wall": c.wall}
        curves[name]["lk_baseline"] = k.tolist()
        log(f"{name} LK: key {res['lk_baseline']['key_frac_iod']:.3f} IOD")
        out[name] = res
    return out, curves


def smoothed_landmarks(model, tr, sigma):
    """Landmarks of a track after :func:`facetransfer.track.tracker.smooth_track`."""
    from facetransfer.track.tracker import smooth_track

    R, s, t, w = smooth_track(tr.rotation, tr.scale, tr.translation, tr.weights, sigma,
                              constant=("identity",))
    X = model.synthesize(w, vertices=model.landmarks)
    Y = np.einsum("fij,fnj->fni", R[:, :2], X) * s[:, None, None]
    Y[..., 1] *= -1
    return Y + t[:, None, :]


# ------------------------------------------------------------------------------ 3. speed
def bench_speed(model, det, log, n_frames=60):
    from facetransfer.synth import make_clip, random_performance
    from facetransfer.track.tracker import TrackOptions, track_video

    perf = random_performance(model, n_frames, seed=11, size=(640, 480), fps=25)
    frames = make_clip(model, perf, seed=11).frames
    L0 = make_clip(model, random_performance(model, 1, seed=11, size=(640, 480)), seed=11
                   ).truth.landmarks2d[0]
    out = {"n_frames": n_frames, "size": [640, 480], "threads": os.environ.get("OMP_NUM_THREADS")}
    # warm-up (numba compile, caches)
    track_video(frames[:3], model, init=L0, options=TrackOptions(passes=1, snap_frames=0))
    for label, opt in (("single_pass", TrackOptions(passes=1, snap_frames=0, recover=False)),
                       ("single_pass_paper", TrackOptions(passes=1, snap_frames=0, recover=False,
                                                          keyframe=0.0)),
                       ("full_3_passes", TrackOptions(passes=3, recover=False))):
        marks = {}

        def progress(stage, done, total, marks=marks):
            now = (time.perf_counter(), time.process_time())
            marks.setdefault(stage, [now, now, 0])
            marks[stage][1] = now
            marks[stage][2] = done

        with Clock() as c:
            tr = track_video(frames, model, init=L0, options=opt, progress=progress)
        tm = tr.info["timings"]
        n_pairs = sum(m[2] for k, m in marks.items())
        res = {"fps_wall": n_frames / c.wall, "fps_cpu": n_frames / c.cpu,
               "seconds_wall": c.wall, "seconds_cpu": c.cpu, "frame_pairs": n_pairs,
               "ms_per_pair_wall": 1000 * tm.get("pair", 0) / max(n_pairs, 1),
               "solve_ms_per_pair": 1000 * tm.get("solve", 0) / max(n_pairs, 1),
               "solve_ms_per_system": 1000 * tm.get("solve", 0)
               / max(tr.info["counts"]["solve"], 1),
               "systems_per_pair": tr.info["counts"]["solve"] / max(n_pairs, 1),
               "klt_terms_ms_per_pair": 1000 * tm.get("terms", 0) / max(n_pairs, 1),
               "select_ms_per_pair": 1000 * tm.get("select", 0) / max(n_pairs, 1),
               "tracked_vertices": tr.info.get("mean_points")}
        p1 = marks.get("pass 1/1")
        res["keyframe_weight"] = opt.keyframe
        if p1 is not None and p1[2] > 1:
            res["pass_fps_wall"] = p1[2] / (p1[1][0] - p1[0][0])
            res["pass_fps_cpu"] = p1[2] / max(p1[1][1] - p1[0][1], 1e-9)
        out[label] = res
        log(f"speed {label}: {res['fps_wall']:.1f} fps wall ({res['fps_cpu']:.1f} fps CPU), "
            f"solve {res['solve_ms_per_system']:.2f} ms per system (wall)")
    out["micro_cpu"] = micro_cpu(model, frames, L0)
    mc = out["micro_cpu"]
    log(f"speed CPU per frame pair {mc['pair_ms_cpu']:.1f} ms, per system "
        f"{mc['system_ms_cpu']:.3f} ms, KLT terms {mc['klt_ms_cpu']:.2f} ms")
    with Clock() as c:
        for fr in frames:
            det.detect(fr)
    out["mediapipe"] = {"ms_per_frame_wall": 1000 * c.wall / n_frames,
                        "ms_per_frame_cpu": 1000 * c.cpu / n_frames,
                        "fps_wall": n_frames / c.wall}
    with Clock() as c:
        track_lk(frames, model, L0)
    out["lk_baseline"] = {"fps_wall": n_frames / c.wall, "fps_cpu": n_frames / c.cpu}
    log(f"speed MediaPipe {out['mediapipe']['ms_per_frame_wall']:.1f} ms/frame, LK baseline "
        f"{out['lk_baseline']['fps_wall']:.1f} fps")
    return out


def micro_cpu(model, frames, L0, reps=30):
    """Process-CPU time of one frame pair, one stacked system (build + solve) and one KLT
    evaluation, repeated on a fixed pair (so the machine's load does not enter)."""
    from facetransfer.track.camera import project
    from facetransfer.track.init import fit_landmarks
    from facetransfer.track.klt import klt_terms_at, sample_windows
    from facetransfer.track.solver import solve_step
    from facetransfer.track.tracker import FaceTracker, TrackOptions

    H, W = frames[0].shape[:2]
    tr = FaceTracker(model, (W, H), TrackOptions())
    st = fit_landmarks(model, L0)
    p0, p1 = tr.pyramid(frames[0]), tr.pyramid(frames[1])
    with Clock() as c:
        for _ in range(reps):
            res = tr.track_pair(p0, p1, st, st)
    pair = c.cpu / reps
    sel, q = tr.select_vertices(st, p0)
    with Clock() as c:
        for _ in range(reps):
            tr.select_vertices(st, p0)
    select = c.cpu / reps
    m = tr.per_frame[0]
    cache = tr.cache(st.weights).restrict(sel)
    B = cache.basis(m, st.weights)
    X = B @ st.weights[m]
    wi = sample_windows(p0.levels[0], q, tr.offsets)
    Z, e, _ = klt_terms_at(p1.levels[0], q, wi, tr.offsets, tr.wwin)
    with Clock() as c:
        for _ in range(reps * 10):
            klt_terms_at(p1.levels[0], q, wi, tr.offsets, tr.wwin)
    klt = c.cpu / (reps * 10)
    with Clock() as c:
        for _ in range(reps * 10):
            A, b, G = tr._flow_system(Z, e, X, B, st.pose, st.weights[m], m, None, st.weights, st)
            solve_step(A, b)
    system = c.cpu / (reps * 10)
    return {"pair_ms_cpu": 1000 * pair, "select_ms_cpu": 1000 * select,
            "klt_ms_cpu": 1000 * klt, "system_ms_cpu": 1000 * system,
            "n_points": int(sel.size),
            "systems_in_pair": tr.counts.get("solve", 0) / max(tr.counts.get("pair", 1), 1)}


# ------------------------------------------------------------------------------ outputs
def plot(results, curves, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, ax = plt.subplots(2, 2, figsize=(13, 9))
    a = ax[0, 0]
    if "driving_d6" in curves:
        for label, ys in curves["driving_d6"].items():
            a.plot(np.asarray(ys, float), label=label, lw=0.8)
    a.set_title("driving_d6: key-point error vs frame (vs MediaPipe reference)")
    a.set_xlabel("frame")
    a.set_ylabel("error / outer eye-corner distance")
    a.set_ylim(0, 0.3)
    a.legend()
    a = ax[0, 1]
    names = [n for n in CLIPS if n in results["real"]]
    meths = ["tracker_paper", "tracker", "tracker_anchor", "tracker_anchor_smooth",
             "lk_baseline", "mediapipe_live"]
    x = np.arange(len(names))
    for j, m in enumerate(meths):
        a.bar(x + j * 0.14, [results["real"][n].get(m, {}).get("key_frac_iod", np.nan)
                             for n in names], 0.14, label=m)
    a.set_xticks(x + 0.35)
    a.set_xticklabels(names, fontsize=8)
    a.set_title("real clips: mean key-point error / eye distance")
    a.legend(fontsize=8)
    a = ax[1, 0]
    s = results["synthetic"]["summary"]
    keys = list(s)
    metrics = ["landmark_px", "vertex3d_mm", "shape_mm", "rotation_deg"]
    x = np.arange(len(metrics))
    for j, k in enumerate(keys):
        a.bar(x + j * 0.2, [s[k][m] for m in metrics], 0.2, label=k)
    a.set_xticks(x + 0.3)
    a.set_xticklabels(metrics)
    a.set_title("synthetic (640x480, truth): mean errors")
    a.legend(fontsize=8)
    a = ax[1, 1]
    sp = results["speed"]
    labels = ["single pass\n(paper)", "single pass\n(+key frame)", "3 passes + snap",
              "LK baseline", "MediaPipe"]
    sp1, sp0 = sp["single_pass"], sp.get("single_pass_paper", sp["single_pass"])
    wall = [sp0.get("pass_fps_wall", sp0["fps_wall"]), sp1.get("pass_fps_wall", sp1["fps_wall"]),
            sp["full_3_passes"]["fps_wall"], sp["lk_baseline"]["fps_wall"],
            sp["mediapipe"]["fps_wall"]]
    cpu = [sp0.get("pass_fps_cpu", sp0["fps_cpu"]), sp1.get("pass_fps_cpu", sp1["fps_cpu"]),
           sp["full_3_passes"]["fps_cpu"], sp["lk_baseline"]["fps_cpu"],
           1000.0 / sp["mediapipe"]["ms_per_frame_cpu"]]
    x = np.arange(len(labels))
    a.bar(x - 0.2, wall, 0.4, label="wall clock (machine shared, loaded)")
    a.bar(x + 0.2, cpu, 0.4, label="process CPU time")
    a.set_xticks(x)
    a.set_xticklabels(labels, fontsize=8)
    a.axhline(30, color="k", ls="--", lw=0.8)
    a.set_title("speed at 640x480, ~1000 tracked vertices (frames per second)")
    a.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


def overlay_picture(model, track, data, path, max_frames):
    import cv2

    from facetransfer.io.atomic import write_image
    from facetransfer.io.video import read_video
    from facetransfer.track.overlay import overlay_frames

    frames, _ = read_video(data / "video" / "driving_d6.mp4", max_frames=max_frames)
    idx = np.linspace(0, len(frames) - 1, 4).astype(int)
    imgs = [img for i, img in enumerate(overlay_frames(frames, track, model)) if i in idx]
    pic = np.concatenate(imgs, axis=1)
    pic = cv2.resize(pic, None, fx=0.6, fy=0.6, interpolation=cv2.INTER_AREA)
    write_image(path, pic)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--model", default=None, help="bilinear model (default: build ict-bilinear)")
    ap.add_argument("--max-frames", type=int, default=None, help="frames per real clip")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--synthetic-frames", type=int, default=60)
    ap.add_argument("--passes", type=int, default=2, help="passes on real clips")
    ap.add_argument("--skip", default="",
                    help="comma list of sections to skip: synthetic,real,speed")
    args = ap.parse_args(argv)
    from facetransfer.track.init import MediaPipeDetector

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(os.environ.get("FACETRANSFER_DATA_DIR", "/work/shared/data"))
    model = load_or_build_model(Path(args.model) if args.model else out / "track_model.npz")
    skip = set(filter(None, args.skip.split(",")))
    t0 = time.perf_counter()

    def log(msg):
        print(f"[{time.perf_counter() - t0:7.1f} s] {msg}", flush=True)

    results = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                           "cpus": os.cpu_count(), "load_avg_start": os.getloadavg()},
               "model": {"modes": list(model.mode_names), "ranks": list(model.ranks),
                         "n_vertices": model.n_vertices, "hash": model.content_hash},
               "settings": vars(args)}
    curves = {}
    with MediaPipeDetector() as det:
        if "speed" not in skip:
            results["speed"] = bench_speed(model, det, log)
        if "synthetic" not in skip:
            results["synthetic"] = bench_synthetic(model, list(range(args.seeds)),
                                                   args.synthetic_frames, log)
        if "real" not in skip:
            real, curves = bench_real(model, data, args.max_frames, log, det, args.passes)
            tr = real.pop("_overlay_track", None)
            results["real"] = real
            if tr is not None:
                overlay_picture(model, tr, data, out / "track_overlay.png", args.max_frames)
    prev = out / "track.json"
    if skip and prev.is_file():   # keep the sections of an earlier run that were skipped now
        old = json.loads(prev.read_text())
        for sec in ("speed", "synthetic", "real"):
            if sec in skip and sec in old:
                results[sec] = old[sec]
        if "real" in skip and "drift_curves_driving_d6" in old:
            curves = {"driving_d6": old["drift_curves_driving_d6"]}
    results["machine"]["load_avg_end"] = os.getloadavg()
    results["seconds_total"] = time.perf_counter() - t0
    results["drift_curves_driving_d6"] = curves.get("driving_d6", {})
    from facetransfer.io.atomic import atomic_path, write_text_atomic

    write_text_atomic(out / "track.json", json.dumps(results, indent=1, default=float))
    if {"speed", "synthetic", "real"} <= set(results):
        with atomic_path(out / "track.png") as tmp:
            plot(results, curves, tmp)
    log(f"wrote {out / 'track.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

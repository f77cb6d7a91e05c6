"""Benchmark of issue 14: exports, semantic identity dials and the viewer.

Measures, in one run:

(a) agreement with MediaPipe: each clip of the data folder (``video/``) is tracked with the
    default model (the capture tracker where it exists, else ``track_video``), exported as
    MediaPipe-layout JSON and read back; MediaPipe Face Landmarker (the peer, run here with
    ``output_face_blendshapes=True`` in VIDEO mode, the same pass that feeds the tracker its
    landmarks) gives its own blendshapes. Reported per clip and blendshape: Pearson correlation
    over frames with a face in both, and the mean absolute difference. Goal: r >= 0.8 for
    jawOpen, eyeBlinkLeft, eyeBlinkRight. As a referee for both, each of the three is also
    correlated with the lip gap / eyelid closure measured on the clip's reference landmarks.
(b) round trips on a synthetic 1,000-frame track of the default model: CSV read back (ours and
    Python's csv), the glb's morph weights at key k vs the track's frame k (pygltflib), the glb's
    mesh as trimesh loads it, UsdSkel weights at time k (pxr), the JSON read back.
(c) dials: R² and leave-one-out R² of each semantic dial of the default model; the stated change
    per unit vs the change measured on 8 training identities.
(d) export cost: seconds and bytes per format for the 1,000-frame clip, and the viewer's page
    (model page, track page).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_export.py [--out out/benchmarks]
        [--clips face_2,WDA_KatieHill_000,driving_d6,driving_d9] [--max-frames N]
        [--skip-agreement]

Writes ``OUT/export.json`` and ``OUT/export.png``. A skipped part keeps its figures from an
existing ``OUT/export.json`` (marked ``"carried_over": true``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("MPLBACKEND", "Agg")

CLIPS = ("face_2", "WDA_KatieHill_000", "driving_d6", "driving_d9")
KEY_SHAPES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")


def _recording_landmarker(fps: float):
    """The tracker's own detector (:class:`facetransfer.track.detect.VideoLandmarker`, with
    blendshapes: the capture runs as ``facetransfer track`` runs it, second pass included)
    that also keeps its scores: ``.scores``, per frame (52,) in ARKIT_NAMES order or None."""
    from facetransfer.track.detect import VideoLandmarker

    class RecordingLandmarker(VideoLandmarker):
        def detect_scored(self, frame):
            pts, scores = super().detect_scored(frame)
            self.scores.append(scores)
            return pts, scores

    det = RecordingLandmarker(fps=fps, blendshapes=True)
    det.scores = []
    return det


def _track(clip: Path, model, detector, max_frames):
    try:
        from facetransfer.track.capture import capture_video
    except ImportError:
        from facetransfer.track import track_video

        return track_video(clip, model, detector=detector, max_frames=max_frames), "track_video"
    return capture_video(clip, model, detector=detector, max_frames=max_frames), "capture"


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    if len(x) < 3 or x.std() == 0 or y.std() == 0:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])


def _geometry(ref: Path, n: int) -> dict:
    """Lip gap and eyelid closure from the clip's reference landmarks (MediaPipe 478 points,
    ``NAME.mediapipe478.npz``), over the inter-ocular distance: a geometric check of jawOpen
    and the blinks independent of either blendshape estimator."""
    L = np.load(ref)["landmarks"][:n, :, :2]  # (F, 478, 2) pixels
    iod = np.linalg.norm(L[:, 33] - L[:, 263], axis=1)
    gap = lambda a, b: np.linalg.norm(L[:, a] - L[:, b], axis=1) / iod  # noqa: E731
    # subject's left eye = MediaPipe's 386/374 (image right); right eye 159/145
    return {"jawOpen": gap(13, 14), "eyeBlinkLeft": -gap(386, 374),
            "eyeBlinkRight": -gap(159, 145)}


def agreement(model, data_dir: Path, clips, max_frames, tmp: Path) -> dict:
    from facetransfer.arkit import ARKIT_NAMES, MEDIAPIPE_NAMES
    from facetransfer.export import export_track
    from facetransfer.export.mpjson import read_mediapipe_json
    from facetransfer.io.video import video_info

    out = {}
    for name in clips:
        clip = data_dir / "video" / f"{name}.mp4"
        info = video_info(clip)
        det = _recording_landmarker(info.fps)
        t0 = time.perf_counter()
        try:
            track, tracker = _track(clip, model, det, max_frames)
        finally:
            det.close()
        secs = time.perf_counter() - t0
        ours = read_mediapipe_json(export_track(track, "json", tmp / f"{name}.json",
                                                model=model, overwrite=True))
        theirs = np.full((track.n_frames, len(ARKIT_NAMES)), np.nan)
        for k, s in enumerate(det.scores[:track.n_frames]):
            if s is not None:
                theirs[k] = s                   # MEDIAPIPE_NAMES = ARKIT_NAMES[:51]
        ok = ~np.isnan(ours[:, 0]) & ~np.isnan(theirs[:, 0])
        per = {}
        for j, n in enumerate(MEDIAPIPE_NAMES):
            x, y = ours[ok, j], theirs[ok, j]
            per[n] = {"r": _pearson(x, y), "mad": float(np.mean(np.abs(x - y))),
                      "mean_ours": float(x.mean()), "mean_mediapipe": float(y.mean())}
        rs = np.array([v["r"] for v in per.values()])
        geo = _geometry(data_dir / "video" / f"{name}.mediapipe478.npz", track.n_frames)
        ref = {}
        for n, g in geo.items():
            j = MEDIAPIPE_NAMES.index(n)
            good = ok & np.isfinite(g)
            ref[n] = {"r_ours": _pearson(ours[good, j], g[good]),
                      "r_mediapipe": _pearson(theirs[good, j], g[good])}
        out[name] = {"frames": track.n_frames, "frames_compared": int(ok.sum()),
                     "tracker": tracker, "track_seconds": secs,
                     "key": {n: per[n] for n in KEY_SHAPES},
                     "vs_landmark_geometry": ref,
                     "median_r_all51": float(np.nanmedian(rs)),
                     "shapes_r_ge_0.8": int(np.sum(rs >= 0.8)), "per_shape": per}
        print("    vs landmark geometry: " + ", ".join(
            f"{n} ours {v['r_ours']:.3f} / MediaPipe {v['r_mediapipe']:.3f}"
            for n, v in ref.items()), flush=True)
        print(f"  {name}: " + ", ".join(f"{n} r={per[n]['r']:.3f}" for n in KEY_SHAPES)
              + f"; median r over 51 = {np.nanmedian(rs):.3f} ({secs:.1f} s, {tracker})",
              flush=True)
    return out


def synthetic_track(model, n: int, seed: int = 0):
    from scipy.spatial.transform import Rotation

    from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
    from facetransfer.track import Track

    rng = np.random.default_rng(seed)
    t = np.arange(n) / 25.0
    a = (0.5 + 0.5 * np.sin(t[:, None] * rng.uniform(0.5, 4, 52) + rng.uniform(0, 6, 52)))
    a = a.astype(np.float32)
    a[:, ARKIT_NAMES.index("tongueOut")] = 0
    ang = 0.3 * np.sin(t[:, None] * np.array([0.7, 1.1, 0.5]))
    k = model.mode_index("identity")
    return Track(fps=25.0, frame_size=(640, 480), rotation=Rotation.from_euler("YXZ", ang)
                 .as_matrix(), scale=np.full(n, 10.0), translation=np.tile((320.0, 240.0), (n, 1)),
                 weights={"identity": np.tile(model.factors[k][3], (n, 1)),
                          "expression": activations_to_weights(model, a)},
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n), lost=np.zeros(n, bool),
                 model_hash=model.content_hash, mode_names=model.mode_names,
                 source="synthetic", blendshapes=a, blendshape_names=ARKIT_NAMES), a, ang


def cost_and_round_trips(model, n_frames: int, tmp: Path) -> tuple[dict, dict]:
    import pygltflib
    import trimesh

    from facetransfer.arkit import expression_rig
    from facetransfer.export import export_track
    from facetransfer.export.livelink import LIVELINK_NAMES, read_livelink
    from facetransfer.export.mpjson import read_mediapipe_json
    from facetransfer.export.viewer import write_viewer

    track, a, ang = synthetic_track(model, n_frames)
    cost, rt = {}, {}
    for fmt, ext in (("livelink", "csv"), ("glb", "glb"), ("usd", "usd"), ("json", "json")):
        t0 = time.perf_counter()
        p = export_track(track, fmt, tmp / f"clip.{ext}", model=model, overwrite=True)
        cost[fmt] = {"seconds": time.perf_counter() - t0, "bytes": p.stat().st_size}
    take = read_livelink(tmp / "clip.csv")
    with open(tmp / "clip.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    py = np.array([[float(r[n]) for n in LIVELINK_NAMES] for r in rows])
    from facetransfer.export.livelink import _TO_ARKIT

    rt["livelink_max_abs_error"] = float(np.abs(take.activations - a).max())
    rt["livelink_python_csv_max_abs_error"] = float(np.abs(py - a[:, _TO_ARKIT]).max())
    rt["livelink_head_angle_max_abs_error_rad"] = float(np.abs(take.pose[:, :3] - ang).max())
    g = pygltflib.GLTF2().load(str(tmp / "clip.glb"))
    anim = g.animations[0]
    ch = next(c for c in anim.channels if c.target.path == "weights")
    acc = g.accessors[anim.samplers[ch.sampler].output]
    view = g.bufferViews[acc.bufferView]
    W = np.frombuffer(g.binary_blob(), np.float32, acc.count, view.byteOffset).reshape(-1, 52)
    rt["glb_keys"] = int(W.shape[0])
    rt["glb_weights_max_abs_error"] = float(np.abs(W - a).max())
    tm = trimesh.load(tmp / "clip.glb", force="mesh", process=False)
    rig = expression_rig(model, track.weights_at(0))
    rt["glb_trimesh_vertices_max_abs_error_m"] = float(np.abs(np.asarray(tm.vertices)
                                                              - rig.neutral * 0.01).max())
    try:
        from pxr import Usd, UsdSkel

        stage = Usd.Stage.Open(str(tmp / "clip.usd"))
        cache = UsdSkel.Cache()
        cache.Populate(UsdSkel.Root(stage.GetPrimAtPath("/Face")), Usd.PrimDefaultPredicate)
        aq = cache.GetSkelQuery(UsdSkel.Skeleton(stage.GetPrimAtPath("/Face/Skel"))) \
            .GetAnimQuery()
        U = np.array([np.array(aq.ComputeBlendShapeWeights(Usd.TimeCode(k)))
                      for k in range(n_frames)])
        rt["usd_weights_max_abs_error"] = float(np.abs(U - a).max())
    except ImportError:
        rt["usd_weights_max_abs_error"] = None
    rt["json_max_abs_error"] = float(np.abs(read_mediapipe_json(tmp / "clip.json") - a).max())
    mp_, tp = tmp / "model.npz", tmp / "track.npz"
    model.save(mp_)
    track.save(tp)
    for what, src in (("viewer_model_page", mp_), ("viewer_track_page", tp)):
        t0 = time.perf_counter()
        p = write_viewer(src, tmp / f"{what}.html", model=model, overwrite=True)
        cost[what] = {"seconds": time.perf_counter() - t0, "bytes": p.stat().st_size}
    return cost, rt


def dial_figures(model) -> dict:
    from facetransfer.dials import identity_measurements, learn_dials

    t0 = time.perf_counter()
    dials = learn_dials(model)
    secs = time.perf_counter() - t0
    W = model.factors[model.mode_index("identity")][:8]
    out = {"seconds": secs, "identities": int(model.shape[0]), "unit": dials.unit, "dials": {}}
    for j, d in enumerate(dials.dials):
        m0 = identity_measurements(model, W)[:, j]
        m1 = identity_measurements(model, W + d.direction)[:, j]
        ch = m1 - m0
        out["dials"][d.name] = {"r2": d.r2, "r2_loo": d.r2_loo, "sigma": d.sigma,
                                "stated_per_unit": d.effect,
                                "measured_per_unit_mean": float(ch.mean()),
                                "measured_per_unit_max_rel_dev": float(
                                    np.abs(ch - d.effect).max() / abs(d.effect))}
    return out


def plot(res: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    ag = res.get("agreement") or {}
    clips = [c for c in ag if isinstance(ag[c], dict) and "key" in ag[c]]
    names = list(KEY_SHAPES) + ["median (51)"]
    w = 0.8 / max(len(clips), 1)
    for i, c in enumerate(clips):
        vals = [ag[c]["key"][n]["r"] for n in KEY_SHAPES] + [ag[c]["median_r_all51"]]
        ax[0].bar(np.arange(len(names)) + i * w, vals, w, label=c)
    ax[0].axhline(0.8, color="k", ls="--", lw=1, label="goal 0.8")
    ax[0].set_xticks(np.arange(len(names)) + 0.4 - w / 2, names)
    ax[0].set_ylabel("Pearson r, ours vs MediaPipe")
    ax[0].set_title("(a) agreement with MediaPipe (peer)")
    ax[0].legend(fontsize=7)
    dl = res["dials"]["dials"]
    x = np.arange(len(dl))
    ax[1].bar(x - 0.2, [v["r2"] for v in dl.values()], 0.4, label="R² (fit)")
    ax[1].bar(x + 0.2, [v["r2_loo"] for v in dl.values()], 0.4, label="R² (leave one out)")
    ax[1].set_xticks(x, list(dl), rotation=45, ha="right")
    ax[1].set_ylim(min(0, min(v["r2_loo"] for v in dl.values())), 1.05)
    ax[1].set_title(f"(c) identity dials of the default model ({res['dials']['identities']} ids)")
    ax[1].legend(fontsize=8, loc="lower left")
    cost = res["cost"]
    keys = list(cost)
    ax[2].bar(keys, [cost[k]["bytes"] / 1e6 for k in keys], color="tab:blue")
    ax[2].set_ylabel("MB (bars)")
    ax2 = ax[2].twinx()
    ax2.plot(keys, [cost[k]["seconds"] for k in keys], "o-", color="tab:red")
    ax2.set_ylabel("seconds (dots)")
    ax[2].set_title(f"(d) export cost, {res['frames']} frames")
    ax[2].tick_params(axis="x", rotation=30)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--clips", default=",".join(CLIPS))
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--frames", type=int, default=1000, help="frames of the synthetic clip")
    ap.add_argument("--skip-agreement", action="store_true")
    args = ap.parse_args(argv)
    data_dir = Path(os.environ.get("FACETRANSFER_DATA_DIR", ""))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    old = {}
    if (out / "export.json").is_file():
        old = json.loads((out / "export.json").read_text())
    from facetransfer.default_model import load_default_model

    t0 = time.perf_counter()
    model = load_default_model(announce=lambda m: print(m, file=sys.stderr))
    res = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                       "omp_threads": os.environ.get("OMP_NUM_THREADS")},
           "model": {"vertices": model.n_vertices, "ranks": list(model.ranks),
                     "load_seconds": time.perf_counter() - t0}, "frames": args.frames}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        print("(b, d) round trips and export cost", flush=True)
        res["cost"], res["round_trips"] = cost_and_round_trips(model, args.frames, tmp)
        print("  " + json.dumps(res["round_trips"]), flush=True)
        print("(c) dials", flush=True)
        res["dials"] = dial_figures(model)
        if args.skip_agreement:
            res["agreement"] = {**old.get("agreement", {}), "carried_over": True}
        else:
            print("(a) agreement with MediaPipe", flush=True)
            res["agreement"] = agreement(model, data_dir, args.clips.split(","),
                                         args.max_frames, tmp)
    from facetransfer.io.atomic import write_text_atomic

    write_text_atomic(out / "export.json", json.dumps(res, indent=1) + "\n")
    plot(res, out / "export.png")
    print(f"wrote {out / 'export.json'} and {out / 'export.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

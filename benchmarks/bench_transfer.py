"""Benchmark of issue 6: face transfer and video rewrite (Vlasic et al. 2005, §6, Fig. 7).

Measures, in one run:

(a) synthetic footage with ground truth (``facetransfer.synth``, the default ICT bilinear model):
    actor A performs random expressions, actor B (another identity, other pose, other
    background) is the target footage; the truth is B performing A's expressions with B's pose.
    We track both videos (§5), transfer A's expressions onto B's footage and compare with the
    truth: PSNR and SSIM on the face region, and the landmark error (pixels) of the new
    performance. For reference: the same rewrite with the truth tracks (rendering error alone)
    and the untouched target (what "doing nothing" scores). PSNR and SSIM also in the eye
    region (lids, eyes and brows of the truth mesh: ``psnr_eyes_db``); rows ``..._eyes=target``
    keep the target's own eyes (the holes open, ``--eyes target``). Rows ``..._mouth=function`` take
    the mouth from the texture function of §6 (``--mouth function``) instead of the source's
    frame; ``tracked_performance_mouth=...`` rewrite with a ready performance (``--performance``)
    whose mouth comes from the target's own footage (nearest frame or texture function).
(b) identity leakage: the result is tracked again; we report the distance of its identity
    weights to the target's and to the source's (normalised by the A-B distance: 0 = the
    target's identity, 1 = the source's).
(c) outside the face mask the result must equal the target frame: PSNR there (inf = exact).
(d) speed: end-to-end seconds (read, track both clips, render, blend, write with audio) for a
    10-second 512x512 clip pair at 25 fps, and the share of each stage; goal: no slower than the
    clip's duration. Wall clock and the main process's CPU time (the machine may be shared;
    the expression source is tracked and frames are rendered in forked processes). Timed
    for each ``--speed`` preset of ``facetransfer transfer`` (``--speed-presets``); (a) also
    compares the tracking presets' quality (``--quality-presets``).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_transfer.py [--out out/benchmarks]
        [--frames 60] [--size 320] [--speed-seconds 10] [--quick]
        [--skip-quality | --skip-speed] [--speed-presets fast,balanced]
        [--quality-presets balanced,fast]

A part that is skipped keeps its figures from an existing ``OUT/transfer.json`` (marked
``"carried_over": true``).

Writes ``OUT/transfer.json`` and ``OUT/transfer.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

# timed from scratch: no track reused from the track cache (facetransfer.track.cache)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"

import numpy as np  # noqa: E402

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("MPLBACKEND", "Agg")


# ------------------------------------------------------------------------------------ metrics
def sq_err(a, b, mask=None) -> tuple[float, int]:
    """Sum of squared differences and number of values (over ``mask``)."""
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    if mask is not None:
        d = d[mask]
    return float(d.sum()), int(d.size)


def psnr_of(sums) -> float:
    """PSNR (dB) of pooled squared errors ``[(sum, count), ...]`` (inf when all exact)."""
    tot = sum(s for s, _ in sums)
    cnt = sum(c for _, c in sums)
    m = tot / cnt if cnt else 0.0
    return float("inf") if m == 0 else float(10 * np.log10(255.0 ** 2 / m))


def psnr(a, b, mask=None) -> float:
    return psnr_of([sq_err(a, b, mask)])


def ssim(a, b, mask=None, sigma: float = 1.5) -> float:
    """Mean SSIM (Wang et al. 2004) on luma with Gaussian windows, averaged over ``mask``."""
    from scipy.ndimage import gaussian_filter

    def luma(x):
        x = np.asarray(x, np.float64)
        return 0.299 * x[..., 0] + 0.587 * x[..., 1] + 0.114 * x[..., 2]

    x, y = luma(a), luma(b)
    C1, C2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    mx, my = gaussian_filter(x, sigma), gaussian_filter(y, sigma)
    sxx = gaussian_filter(x * x, sigma) - mx * mx
    syy = gaussian_filter(y * y, sigma) - my * my
    sxy = gaussian_filter(x * y, sigma) - mx * my
    s = ((2 * mx * my + C1) * (2 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
    return float(s[mask].mean() if mask is not None else s.mean())


def face_mask(model, weights, camera, size):
    from facetransfer.render import rasterize

    return rasterize(model.synthesize(weights), model.faces, camera, size).mask


def track_of(clip_truth, model, source=""):
    """A Track holding a synthetic clip's truth."""
    from facetransfer.track import Track

    t = clip_truth
    n = t.n_frames
    return Track(fps=t.fps, frame_size=t.frame_size, rotation=t.rotation, scale=t.scale,
                 translation=t.translation, weights=t.weights, landmarks2d=t.landmarks2d,
                 confidence=np.ones(n), lost=np.zeros(n, bool), model_hash=model.content_hash,
                 mode_names=model.mode_names, source=source)


def track_frames(frames, model, fps, speed="balanced"):
    from facetransfer.track.presets import track_options
    from facetransfer.track.tracker import track_video

    tr = track_video(frames, model, progress=None, options=track_options(speed))
    return dataclasses.replace(tr, fps=float(fps))


def eye_region_masks(model, topo, perf_t, frames_b, truth_b, size) -> list[np.ndarray]:
    """Per frame, the pixels of the truth's eye region (issue 13): the triangles of
    :func:`facetransfer.eyes.eye_texture` (lids, eyes, brows, the closed holes) on the truth
    mesh, rasterised with the eye holes closed."""
    from facetransfer.eyes import eye_texture
    from facetransfer.render import rasterize
    from facetransfer.topology import close_mouth

    closed, tex = eye_texture(frames_b, truth_b, model, topo)
    out = []
    for i in range(perf_t.n_frames):
        V = close_mouth(model.synthesize(perf_t.frame_weights(i)), closed)
        tid = rasterize(V, closed.faces, perf_t.camera(i), size).tri_id
        out.append((tid >= 0) & tex.select[np.maximum(tid, 0)] if tex is not None
                   else np.zeros(tid.shape, bool))
    return out


# ------------------------------------------------------------------------------------ (a)-(c)
def synthetic_quality(model, *, n_frames: int, size: int, seed: int = 0, log=print,
                      speeds=("balanced",)) -> dict:
    from facetransfer import rewrite_clip as rc
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer.texture import face as ftex
    from facetransfer import topology
    from facetransfer.synth import make_clip, random_performance
    from facetransfer.track.project import project_landmarks
    from facetransfer.texture.function import nearest_frames
    from facetransfer.transfer import constant_weights, recombine

    idm = model.mode_names[0]
    labels = model.labels[0]
    perf_a = random_performance(model, n_frames, seed=seed + 11, size=(size, size),
                                identity=labels[1], key_every=0.6)
    perf_b = random_performance(model, n_frames, seed=seed + 23, size=(size, size),
                                identity=labels[4], key_every=1.5)
    # the truth: B's identity and pose, A's expressions
    w_t = dict(perf_b.weights)
    for m in model.mode_names[1:]:
        w_t[m] = perf_a.weights[m]
    perf_t = dataclasses.replace(perf_b, weights=w_t)
    t0 = time.perf_counter()
    clip_a = make_clip(model, perf_a, seed=seed + 1)
    clip_b = make_clip(model, perf_b, seed=seed + 2)
    clip_t = make_clip(model, perf_t, seed=seed + 2)  # same texture and background as B
    log(f"(a) rendered 3 synthetic clips of {n_frames} frames at {size}px in "
        f"{time.perf_counter() - t0:.1f} s")
    truth_a, truth_b = track_of(clip_a.truth, model), track_of(clip_b.truth, model)

    t0 = time.perf_counter()
    tr_a = track_frames(clip_a.frames, model, perf_a.fps)
    tr_b = track_frames(clip_b.frames, model, perf_b.fps)
    track_seconds = {"balanced": time.perf_counter() - t0}
    log(f"(a) tracked both clips in {time.perf_counter() - t0:.1f} s")
    # the other tracking presets of `facetransfer transfer --speed`
    other = {}
    for sp in speeds:
        if sp == "balanced":
            continue
        t0 = time.perf_counter()
        other[sp] = (track_frames(clip_a.frames, model, perf_a.fps, sp),
                     track_frames(clip_b.frames, model, perf_b.fps, sp))
        track_seconds[sp] = time.perf_counter() - t0
        log(f"(a) tracked both clips with --speed {sp} in {track_seconds[sp]:.1f} s")
    topo = topology.mesh_topology(model)

    def run(ta, tb, texture="frame", blend="fast", mouth="frame", mouth_from="source",
            eyes="model"):
        """``mouth_from="target"``: the mouth from B's own footage, as for a ready performance
        (``--performance``): its nearest frame (``mouth="frame"``) or the texture function
        lifted from its frames."""
        from facetransfer.track.project import take_frames

        new = project_landmarks(recombine(tb, expression=ta), model)
        src = rc.MouthSource(clip_a.frames, ta)
        if mouth_from == "target":
            names = model.mode_names[1:]
            j = nearest_frames(np.concatenate([new.weights[m] for m in names], axis=1),
                               np.concatenate([tb.weights[m] for m in names], axis=1),
                               ~tb.lost)
            src = rc.MouthSource(clip_b.frames, take_frames(tb, j), j)
            if mouth == "function":
                src = dataclasses.replace(src, function=ftex.mouth_texture_function(
                    model, clip_b.frames, tb, topo))
        opts = RewriteOptions().with_(texture=texture, blend=blend, mouth=mouth, eyes=eyes)
        outs = list(rc.rewrite_frames(clip_b.frames, tb, new, model, mouth_source=src,
                                      options=opts, topo=topo))
        return new, outs

    import scipy.ndimage as ndi

    results = {}
    runs = {
        "tracked_frame_fast": (tr_a, tr_b, "frame", "fast"),
        "tracked_constant_fast": (tr_a, tr_b, "constant", "fast"),
        "tracked_frame_poisson": (tr_a, tr_b, "frame", "poisson"),
        "truth_tracks_frame_fast": (truth_a, truth_b, "frame", "fast"),
        "truth_tracks_constant_fast": (truth_a, truth_b, "constant", "fast"),
        # the mouth texture (--mouth): the texture function of §6 lifted from the source
        # instead of the source's frame at that time
        "tracked_frame_fast_mouth=function": (tr_a, tr_b, "frame", "fast", "function"),
        "truth_tracks_frame_fast_mouth=function": (truth_a, truth_b, "frame", "fast",
                                                   "function"),
        # a ready performance (--performance): the mouth from the target's own footage, its
        # nearest frame in attribute space or the texture function of its frames
        "tracked_performance_mouth=frame": (tr_a, tr_b, "frame", "fast", "frame", "target"),
        "tracked_performance_mouth=function": (tr_a, tr_b, "frame", "fast", "function",
                                               "target"),
        # the eyes (issue 13): the target's own eyes through the mesh's holes (the paper's
        # rewrite) instead of the new performance's lids over an open-eyed target frame
        "tracked_frame_fast_eyes=target": (tr_a, tr_b, "frame", "fast", "frame", "source",
                                           "target"),
        "truth_tracks_frame_fast_eyes=target": (truth_a, truth_b, "frame", "fast", "frame",
                                                "source", "target"),
    }
    for sp, (ta_, tb_) in other.items():
        runs[f"tracked_{sp}_preset_frame_fast"] = (ta_, tb_, "frame", "fast")
    masks = [face_mask(model, perf_t.frame_weights(i), perf_t.camera(i), (size, size))
             for i in range(n_frames)]
    eye_masks = eye_region_masks(model, topo, perf_t, clip_b.frames, truth_b, (size, size))
    for name, (ta, tb, tex, bl, *mouth) in runs.items():
        t0 = time.perf_counter()
        new, outs = run(ta, tb, tex, bl, *mouth)
        dt = time.perf_counter() - t0
        errs = [sq_err(o.image, clip_t.frames[i], masks[i]) for i, o in enumerate(outs)]
        p = [psnr_of([e]) for e in errs]
        s = [ssim(o.image, clip_t.frames[i], masks[i]) for i, o in enumerate(outs)]
        lm = np.linalg.norm(new.landmarks2d - clip_t.truth.landmarks2d, axis=-1).mean(axis=-1)
        outside = []
        for i, o in enumerate(outs):
            grown = ndi.binary_dilation(o.face_mask, iterations=4) if o.face_mask.any() \
                else o.face_mask
            outside.append(sq_err(o.image, clip_b.frames[i], ~grown))
        mouth_errs = [sq_err(o.image, clip_t.frames[i], o.mouth_mask) for i, o in enumerate(outs)]
        eye_errs = [sq_err(o.image, clip_t.frames[i], eye_masks[i]) for i, o in enumerate(outs)]
        eye_ssim = [ssim(o.image, clip_t.frames[i], eye_masks[i]) for i, o in enumerate(outs)
                    if eye_masks[i].any()]
        results[name] = {"psnr_face_db": psnr_of(errs), "psnr_face_db_min": float(np.min(p)),
                         "psnr_mouth_db": psnr_of(mouth_errs),
                         "psnr_eyes_db": psnr_of(eye_errs),
                         "ssim_eyes": float(np.mean(eye_ssim)) if eye_ssim else None,
                         "ssim_face": float(np.mean(s)),
                         "landmark_error_px": float(lm.mean()),
                         "psnr_outside_mask_db": psnr_of(outside),
                         "seconds_per_frame": dt / n_frames}
        if name == "tracked_frame_fast":
            result_frames = np.stack([o.image for o in outs])
        log(f"(a) {name}: PSNR {psnr_of(errs):.2f} dB (mouth {psnr_of(mouth_errs):.2f}, "
            f"eyes {psnr_of(eye_errs):.2f}), "
            f"SSIM {np.mean(s):.3f}, landmarks "
            f"{lm.mean():.2f} px, outside-mask PSNR {psnr_of(outside)}")
    base_p = [sq_err(clip_b.frames[i], clip_t.frames[i], masks[i]) for i in range(n_frames)]
    base_s = [ssim(clip_b.frames[i], clip_t.frames[i], masks[i]) for i in range(n_frames)]
    base_e = [sq_err(clip_b.frames[i], clip_t.frames[i], eye_masks[i]) for i in range(n_frames)]
    base_es = [ssim(clip_b.frames[i], clip_t.frames[i], eye_masks[i]) for i in range(n_frames)
               if eye_masks[i].any()]
    results["untouched_target"] = {"psnr_face_db": psnr_of(base_p),
                                   "ssim_face": float(np.mean(base_s)),
                                   "psnr_eyes_db": psnr_of(base_e),
                                   "ssim_eyes": float(np.mean(base_es)) if base_es else None}

    # (b) identity leakage: track the result again
    t0 = time.perf_counter()
    tr_r = track_frames(result_frames, model, perf_b.fps)
    w_r = constant_weights(tr_r, idm)
    w_a_tr, w_b_tr = constant_weights(tr_a, idm), constant_weights(tr_b, idm)
    w_a, w_b = perf_a.weights[idm][0], perf_b.weights[idm][0]
    ab = float(np.linalg.norm(w_a - w_b))
    leak = {"to_target_truth": float(np.linalg.norm(w_r - w_b)) / ab,
            "to_source_truth": float(np.linalg.norm(w_r - w_a)) / ab,
            "to_target_tracked": float(np.linalg.norm(w_r - w_b_tr)) / ab,
            "to_source_tracked": float(np.linalg.norm(w_r - w_a_tr)) / ab,
            "target_tracked_to_target_truth": float(np.linalg.norm(w_b_tr - w_b)) / ab,
            "note": "identity-weight distances divided by |w_source - w_target| (truth); "
                    "0 = the target's identity, 1 = the source's"}
    log(f"(b) identity of the re-tracked result: {leak['to_target_tracked']:.3f} from the "
        f"target's tracked identity, {leak['to_source_tracked']:.3f} from the source's (against "
        f"the true identities {leak['to_target_truth']:.3f} / {leak['to_source_truth']:.3f}: the "
        f"tracker's own identity error is {leak['target_tracked_to_target_truth']:.3f}) "
        f"({time.perf_counter() - t0:.1f} s)")
    return {"n_frames": n_frames, "size": [size, size], "identities": [labels[1], labels[4]],
            "quality": results, "identity_leakage": leak,
            "track_seconds_both_clips": track_seconds}


# ------------------------------------------------------------------------------------ (d)
def speed(model, *, seconds: float, size: int, log=print, tmpdir: Path,
          presets=("fast",)) -> dict:
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer.transfer_plan import TransferSources
    from facetransfer.video_transfer import transfer_video
    from facetransfer.synth import make_clip, random_performance
    from facetransfer.io.video import write_video

    fps = 25.0
    n = int(round(seconds * fps))
    labels = model.labels[0]
    paths = {}
    for name, ident, seed in (("source", labels[2], 5), ("target", labels[6], 7)):
        perf = random_performance(model, n, seed=seed, size=(size, size), identity=ident)
        clip = make_clip(model, perf, seed=seed)
        paths[name] = tmpdir / f"{name}.mp4"
        write_video(paths[name], clip.frames, fps)
    log(f"(d) wrote a {seconds:g} s {size}x{size} clip pair ({n} frames each)")
    runs = {}
    for preset in presets:
        c0, t0 = time.process_time(), time.perf_counter()
        res = transfer_video(
            TransferSources.of(paths["target"], expression_from=paths["source"]),
            tmpdir / "result.mp4", model, overwrite=True, options=RewriteOptions(speed=preset))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        stages = dict(res.timings)
        total = sum(stages.values())
        runs[preset] = {
            "clip_seconds": seconds, "frames": n, "size": [size, size], "speed_preset": preset,
            "wall_seconds": wall, "cpu_seconds_main_process": cpu,
            "realtime_factor": wall / seconds, "stage_seconds": stages,
            "stage_share": {k: v / total for k, v in stages.items()},
            "goal_met": wall <= seconds}
        log(f"(d) --speed {preset}: end to end {wall:.1f} s wall ({cpu:.1f} s CPU in the main "
            f"process) for a {seconds:g} s clip: "
            + ", ".join(f"{k} {v:.1f} s" for k, v in stages.items()))
    out = dict(runs[presets[0]])
    out["presets"] = runs
    return out


# ------------------------------------------------------------------------------------ plot
def plot(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    q = report.get("synthetic", {}).get("quality", {})
    if q:
        names = list(q)
        axes[0].bar(range(len(names)), [q[k]["psnr_face_db"] for k in names], color="C0")
        axes[0].set_xticks(range(len(names)), [k.replace("_", "\n") for k in names], fontsize=7)
        axes[0].set_ylabel("PSNR on the face (dB)")
        ax2 = axes[0].twinx()
        ax2.plot(range(len(names)), [q[k]["ssim_face"] for k in names], "o-", color="C3")
        ax2.set_ylabel("SSIM on the face", color="C3")
        axes[0].set_title("(a) transfer vs ground truth")
    lk = report.get("synthetic", {}).get("identity_leakage")
    if lk:
        keys = ["to_target_tracked", "to_source_tracked", "to_target_truth", "to_source_truth",
                "target_tracked_to_target_truth"]
        labels = ["result-target\n(tracked)", "result-source\n(tracked)",
                  "result-target\n(truth)", "result-source\n(truth)",
                  "target tracked-\ntarget truth"]
        axes[1].bar(range(5), [lk[k] for k in keys], color=["C2", "C1", "C2", "C1", "C7"])
        axes[1].set_xticks(range(5), labels, fontsize=7)
        axes[1].set_ylabel("identity distance / |source - target|")
        axes[1].set_title("(b) identity of the re-tracked result")
    sp = report.get("speed")
    if sp:
        st = sp["stage_seconds"]
        axes[2].bar(range(len(st)), list(st.values()), color="C4")
        axes[2].set_xticks(range(len(st)), list(st))
        axes[2].axhline(sp["clip_seconds"], color="k", ls="--", label="clip duration")
        axes[2].set_ylabel("seconds")
        axes[2].set_title(f"(d) {sp['clip_seconds']:g} s {sp['size'][0]}px pair: "
                          f"{sp['wall_seconds']:.0f} s total")
        axes[2].legend()
    fig.tight_layout()
    from facetransfer.io.atomic import save_figure

    save_figure(fig, path, dpi=110, format="png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--model", help="model .npz (default: the demo's default model)")
    ap.add_argument("--frames", type=int, default=60, help="synthetic clip length")
    ap.add_argument("--size", type=int, default=320, help="synthetic frame size (square)")
    ap.add_argument("--speed-seconds", type=float, default=10.0)
    ap.add_argument("--speed-size", type=int, default=512)
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-quality", action="store_true", help="only the speed part (d)")
    ap.add_argument("--speed-presets", default="fast,balanced",
                    help="comma-separated `--speed` presets timed in (d); the first is the "
                    "headline figure")
    ap.add_argument("--quality-presets", default="balanced,fast",
                    help="comma-separated tracking presets compared in (a)")
    ap.add_argument("--quick", action="store_true", help="30 frames, 2-second speed clip")
    ap.add_argument("--replot", metavar="JSON", help="only redraw the plot of a report")
    args = ap.parse_args(argv)
    if args.replot:
        plot(json.loads(Path(args.replot).read_text()), Path(args.out) / "transfer.png")
        return 0
    if args.quick:
        args.frames, args.speed_seconds = 30, 2.0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from facetransfer.demo import ensure_default_model
    from facetransfer.io.atomic import write_text_atomic
    from facetransfer.model import load_model

    model = load_model(args.model) if args.model else ensure_default_model()
    report = {"benchmark": "transfer", "issue": 6, "model": {
        "modes": list(model.mode_names), "ranks": list(model.ranks),
        "n_vertices": model.n_vertices, "hash": model.content_hash[:16]},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "omp_threads": os.environ.get("OMP_NUM_THREADS")},
        "settings": vars(args)}
    t0 = time.perf_counter()
    if not args.skip_quality:
        report["synthetic"] = synthetic_quality(
            model, n_frames=args.frames, size=args.size,
            speeds=tuple(x for x in args.quality_presets.split(",") if x))
    if not args.skip_speed:
        with tempfile.TemporaryDirectory() as d:
            report["speed"] = speed(model, seconds=args.speed_seconds, size=args.speed_size,
                                    tmpdir=Path(d),
                                    presets=tuple(x for x in args.speed_presets.split(",") if x))
    report["benchmark_seconds"] = time.perf_counter() - t0
    old_path = out / "transfer.json"
    if (args.skip_quality or args.skip_speed) and old_path.is_file():
        try:
            old = json.loads(old_path.read_text())
        except ValueError:
            old = {}
        for key in ("synthetic", "speed"):
            if key not in report and key in old:
                report[key] = dict(old[key], carried_over=True)
    write_text_atomic(out / "transfer.json", json.dumps(report, indent=2, default=float))
    plot(report, out / "transfer.png")
    print(f"wrote {out / 'transfer.json'} and {out / 'transfer.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

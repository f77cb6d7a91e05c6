"""Benchmark of issue 13 (output): outside the face, the result must equal the target up to
encoding, at least 45 dB at the default CRF.

For real pairs of the data folder, the source's expressions are put on the target (landmark
tracks from the ``NAME.mediapipe478.npz`` beside each clip, so no tracker runs) and every frame is
rewritten (``facetransfer.rewrite_clip.rewrite_frames``, the frames ``facetransfer transfer`` writes).
The rewritten frames are then encoded by the one writer (``facetransfer.io.video``) at each CRF
offered for H.264 and H.265, and as ProRes, decoded again with the project's reader (OpenCV) and
compared with the decoded target frames outside the face mask (the rewritten face's mask,
dilated by 8 pixels): PSNR over RGB and over luma (BT.601 Y). Side by side: the peer, OpenCV's
``mp4v`` writer (MPEG-4 Part 2, what facetransfer wrote before), and the rewritten frames before
encoding (exactly the target there: inf dB). OpenCV's YUV -> RGB conversion rounds down half of
the levels and repeats chroma, which caps any 8-bit 4:2:0 round trip at about 45 dB; the column
``psnr_rgb_exact_decode`` shows what the same encodings give when the clips are read with ffmpeg's
exact conversion instead (``-sws_flags accurate_rnd+full_chroma_int``). Also the bitrate and the encoding cost (CPU
milliseconds per frame of encoding and of the writer's decoding check: wall time means little on
a shared machine), and, at CRF 18, two faster x264 presets than the default (medium).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_video.py [--out out/benchmarks]
        [--frames 60] [--model M.npz] [--quick]

Writes ``OUT/video.json`` and ``OUT/video.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PAIRS = (("driving_d6", "WDA_KatieHill_000"),   # the demo's pair (target: MPEG-4 Part 2, noisy)
         ("WDA_KatieHill_000", "driving_d9"),    # target H.264, 512x480, 30 fps
         ("driving_d9", "face_2"))               # target H.264, 844x844
H264_CRFS = (0, 10, 14, 18, 23, 28)
H265_CRFS = (18, 28)
PRESETS = ("veryfast", "ultrafast")  # besides the default, medium (at CRF 18)
GOAL_DB = 45.0
DILATE = 8


def luma(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma of RGB frames, float64."""
    x = rgb.astype(np.float64)
    return 0.299 * x[..., 0] + 0.587 * x[..., 1] + 0.114 * x[..., 2]


def psnr_outside(a: np.ndarray, b: np.ndarray, outside: np.ndarray) -> tuple[float, float]:
    """PSNR (dB) of RGB and of luma over the pixels where ``outside`` (F, H, W) is True."""
    d = (a.astype(np.float64) - b.astype(np.float64))[outside]         # (N, 3)
    dy = (luma(a) - luma(b))[outside]
    out = []
    for mse in (np.mean(d ** 2), np.mean(dy ** 2)):
        out.append(float("inf") if mse == 0 else float(10 * np.log10(255.0 ** 2 / mse)))
    return out[0], out[1]


def landmark_tracks(source: Path, target: Path, model, n_frames: int, tmp: Path):
    """Track files of both clips from their precomputed MediaPipe landmarks.

    Without their ARKit activations: ``transfer.resample_track`` does not resample them yet,
    so a source at another frame rate fails in ``plan_transfer``; the rewrite uses the weights.
    """
    import dataclasses

    from facetransfer.io.video import video_info
    from facetransfer.track import obtain

    paths = []
    for video, n in ((target, n_frames), (source, None)):
        if n is None:  # the source: as many seconds as the target's frames
            ti, si = video_info(target), video_info(video)
            n = int(np.ceil(n_frames / ti.fps * si.fps)) + 2
        tr = obtain.obtain_track(video, model, max_frames=n, method="landmarks")
        tr = dataclasses.replace(tr, blendshapes=None, blendshape_names=None)
        p = tmp / f"{video.stem}.track.npz"
        tr.save(p, overwrite=True)
        paths.append(p)
    return paths


def rewrite_pair(source: Path, target: Path, model, n_frames: int, tmp: Path):
    """Target frames, rewritten frames and face masks (dilated) of one transfer."""
    import cv2

    from facetransfer import rewrite_clip as rc
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer import transfer_plan as tp

    tt, st = landmark_tracks(source, target, model, n_frames, tmp)
    plan = tp.plan_transfer(target, model, target_track=tt, expression_from=source,
                            expression_track=st, max_frames=n_frames, parallel=False)
    frames, masks = [], []
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * DILATE + 1, 2 * DILATE + 1))
    source = rc.MouthSource(plan.mouth_frames, plan.mouth_track, plan.mouth_index)
    for r in rc.rewrite_frames(plan.target_frames, plan.target_track, plan.new_track, model,
                               mouth_source=source, options=RewriteOptions(
                                   texture="frame", blend="fast", mouth="frame")):
        frames.append(r.image)
        masks.append(cv2.dilate(r.face_mask.astype(np.uint8), kernel) > 0)
    return np.asarray(plan.target_frames[:len(frames)]), np.stack(frames), np.stack(masks), \
        plan.fps


def read_accurate(path: Path, n: int, size: tuple[int, int]) -> np.ndarray:
    """The first ``n`` frames decoded by ffmpeg with exact rounding and interpolated chroma
    (``-sws_flags bicubic+accurate_rnd+full_chroma_int``), cropped to ``size`` (W, H)."""
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path), output_params=[
        "-sws_flags", "bicubic+accurate_rnd+full_chroma_int"])
    W, H = next(gen)["size"]
    out = [np.frombuffer(b, np.uint8).reshape(H, W, 3) for _, b in zip(range(n), gen)]
    gen.close()
    return np.stack(out)[:, :size[1], :size[0]]


def encode_mp4v(path: Path, frames: np.ndarray, fps: float) -> None:
    """The peer: OpenCV's MPEG-4 Part 2 writer, as facetransfer used it before."""
    import cv2

    h, w = frames.shape[1:3]
    wr = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
    for f in frames:
        wr.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    wr.release()


def settings():
    """(label, codec, crf, preset, suffix) of every encoding measured."""
    out = [(f"h264 crf {c}", "h264", c, "medium", ".mp4") for c in H264_CRFS]
    out += [(f"h264 crf 18 {p}", "h264", 18, p, ".mp4") for p in PRESETS]
    out += [(f"h265 crf {c}", "h265", c, "medium", ".mp4") for c in H265_CRFS]
    out += [("prores 422 HQ", "prores", None, "medium", ".mov"),
            ("mp4v (OpenCV, before)", "mp4v", None, None, ".mp4")]
    return out


def cpu_seconds() -> float:
    """CPU time of this process and its finished children (ffmpeg), user + system."""
    import resource

    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


def measure_pair(source: Path, target: Path, model, n_frames: int, tmp: Path, log=print):
    from facetransfer.io.video import VideoOptions, encode_video, read_video

    t0 = time.perf_counter()
    tgt, res, masks, fps = rewrite_pair(source, target, model, n_frames, tmp)
    outside = ~masks
    n, h, w = res.shape[:3]
    raw_rgb, raw_y = psnr_outside(res, tgt, outside)
    tgt_acc = read_accurate(target, n, (w, h))
    row = {"source": source.name, "target": target.name, "frames": int(n), "size": [w, h],
           "fps": fps, "outside_fraction": float(outside.mean()),
           "rewrite_seconds": time.perf_counter() - t0,
           "before_encoding": {"psnr_rgb": raw_rgb, "psnr_y": raw_y}, "encodings": []}
    log(f"{target.name} <- {source.name}: {n} frames {w}x{h}, {outside.mean():.0%} outside "
        f"the face; before encoding {raw_rgb:.1f} dB")
    for label, codec, crf, preset, suffix in settings():
        p = tmp / f"{target.stem}.{codec}.{crf}.{preset}{suffix}"
        t, c = time.perf_counter(), cpu_seconds()
        if codec == "mp4v":
            encode_mp4v(p, res, fps)
        else:
            encode_video(p, res, fps, options=VideoOptions(codec, crf, preset), overwrite=True)
        sec, cpu = time.perf_counter() - t, cpu_seconds() - c
        back, _ = read_video(p)
        back = back[:, :h, :w]
        rgb, y = psnr_outside(back, tgt, outside)
        acc = None
        if codec in ("h264", "prores") and preset == "medium":
            # with an exact reader: outside the face the result is the target as read, so
            # encode the exactly decoded target the same way and decode it exactly again
            q = tmp / f"exact{suffix}"
            encode_video(q, tgt_acc, fps, options=VideoOptions(codec, crf), overwrite=True)
            acc = psnr_outside(read_accurate(q, n, (w, h)), tgt_acc, outside)[0]
            q.unlink()
        mbps = p.stat().st_size * 8 / 1e6 / (n / fps)
        row["encodings"].append({"label": label, "codec": codec, "crf": crf, "preset": preset,
                                 "psnr_rgb": rgb, "psnr_y": y, "psnr_rgb_exact_decode": acc,
                                 "mbit_per_s": mbps,
                                 "encode_fps_wall": n / sec, "cpu_ms_per_frame": 1e3 * cpu / n})
        log(f"  {label:22s} outside the face {rgb:5.1f} dB RGB, {y:5.1f} dB Y, "
            f"{mbps:6.2f} Mbit/s, {1e3 * cpu / n:5.1f} CPU-ms/frame (encode + check)")
        p.unlink()
    return row


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6))
    ax, bx = axes
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, row in enumerate(report["pairs"]):
        c = colours[k % len(colours)]
        enc = row["encodings"]
        h264 = [e for e in enc if e["codec"] == "h264" and e["preset"] == "medium"]
        name = row["target"].rsplit(".", 1)[0]
        ax.plot([e["crf"] for e in h264], [e["psnr_rgb"] for e in h264], "o-", color=c,
                label=f"{name}: H.264")
        h265 = [e for e in enc if e["codec"] == "h265"]
        ax.plot([e["crf"] for e in h265], [e["psnr_rgb"] for e in h265], "s--", color=c,
                label=f"{name}: H.265")
        exact = [e for e in h264 if e.get("psnr_rgb_exact_decode") is not None]
        if exact:
            ax.plot([e["crf"] for e in exact], [e["psnr_rgb_exact_decode"] for e in exact],
                    "-.", color=c, lw=1, alpha=0.7, label=f"{name}: H.264, exact reader")
        for e in enc:
            if e["codec"] == "mp4v":
                ax.axhline(e["psnr_rgb"], color=c, ls=":", lw=1.2,
                           label=f"{name}: mp4v (before)")
            if e["codec"] == "prores":
                ax.plot([-1.5], [e["psnr_rgb"]], "D", color=c)
        bx.plot([e["mbit_per_s"] for e in h264], [e["psnr_rgb"] for e in h264], "o-", color=c,
                label=f"{name}: H.264 (CRF {h264[0]['crf']}..{h264[-1]['crf']})")
        m = [e for e in enc if e["codec"] == "mp4v"][0]
        bx.plot([m["mbit_per_s"]], [m["psnr_rgb"]], "x", color=c, ms=9,
                label=f"{name}: mp4v (before)")
    for a in axes:
        a.axhline(GOAL_DB, color="k", lw=1, ls="--")
        a.grid(alpha=0.3)
        a.set_ylabel("PSNR outside the face vs the target (dB, RGB)")
    ax.axvline(18, color="grey", lw=0.8)
    ax.set_xlabel("CRF (diamonds at -1.5: ProRes 422 HQ; dotted: mp4v)")
    ax.set_title("Outside the face after encoding (goal 45 dB, dashed; default CRF 18)")
    ax.legend(fontsize=6, loc="upper right", ncol=2)
    bx.set_xscale("log")
    bx.set_xlabel("bitrate (Mbit/s)")
    bx.set_title("Quality against size")
    bx.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    save_figure(fig, path, dpi=120)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--model", help="model .npz (default: the default model)")
    ap.add_argument("--frames", type=int, default=60, help="target frames per pair")
    ap.add_argument("--quick", action="store_true", help="the demo pair only, 20 frames")
    ap.add_argument("--replot", metavar="JSON", help="only redraw the plot of a report")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        plot(json.loads(Path(args.replot).read_text()), out / "video.png")
        return 0
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import write_text_atomic
    from facetransfer.model import load_model

    root = data_dir()
    if root is None:
        print("set FACETRANSFER_DATA_DIR to the data folder", file=sys.stderr)
        return 2
    model = load_model(args.model) if args.model else load_default_model()
    pairs = PAIRS[:1] if args.quick else PAIRS
    n = 20 if args.quick else args.frames
    report = {"benchmark": "video output (issue 13)", "frames": n, "goal_db": GOAL_DB,
              "dilate_px": DILATE, "model": args.model or "default (ict-arkit)",
              "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
              "pairs": []}
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        for s, t in pairs:
            report["pairs"].append(measure_pair(root / "video" / f"{s}.mp4",
                                                root / "video" / f"{t}.mp4", model, n,
                                                Path(tmp)))
    write_text_atomic(out / "video.json", json.dumps(report, indent=1))
    plot(report, out / "video.png")
    print(f"wrote {out / 'video.json'} and {out / 'video.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

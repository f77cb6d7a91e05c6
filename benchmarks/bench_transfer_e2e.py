"""End to end of issue 13: a 10-second transfer's time per stage, and outside the face after
encoding, decoded exactly.

1. **Speed**: ``facetransfer transfer --target TARGET --expression-from SOURCE --out R.mp4`` (default
   model, capture tracker, H.264 CRF 18) on 10 s of ``driving_d9`` (512x480, 30 fps: 300 frames)
   with ``driving_d6`` as the source, timed as a command (wall clock, a fresh process), and the
   same work in this process stage by stage (model load, read, track, render, write:
   ``plan_transfer`` + ``render_plan``, what the command runs; with the CPU seconds of the
   plan and of the render, in this process and in its children: the forked tracker, the ffmpeg
   encoder). The command runs twice in turn, with its CPU seconds (all its processes: half of
   that is the least wall time on 2 cores)
   (the first may pay numba's compilation and a cold page cache; the second is reported), and
   ``facetransfer --help`` is timed too. The peer: MediaPipe Face Landmarker in VIDEO mode over
   the same target frames (``benchmarks/_mp_video.py``), with and without blendshapes.
2. **Outside the face**: the rewritten frames of that run (before encoding: exactly the target
   frames as the project's reader decoded them, outside the face) are encoded by the project's
   writer (``facetransfer.io.video.encode_video``, libx264, yuv420p) at each CRF offered and
   compared with the **target file itself**, both decoded by the imageio-ffmpeg binary, over the
   pixels outside the face mask (the rendered face's mask, dilated by 8 px) of every frame:

   - ``y``: the luma planes as stored (``-pix_fmt yuv420p``, the Y plane, no colour conversion);
   - ``rgb``: both converted to rgb24 by ffmpeg with exact rounding and full chroma
     interpolation (``-sws_flags bicubic+accurate_rnd+full_chroma_int``).

   The difference then holds everything the pipeline does to the pixels it does not mean to
   change: the reader's YUV->RGB (OpenCV), the writer's RGB->YUV and the codec.

Usage::

    python benchmarks/bench_transfer_e2e.py --out out/benchmarks [--seconds 10]

Writes ``OUT/transfer_e2e.json`` and ``OUT/transfer_e2e.png``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# timed from scratch: no track reused from the track cache (facetransfer.track.cache)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"

# the stages in this process run as the command runs them: OpenBLAS on one thread
# (facetransfer.cli.main.serial_blas), set before NumPy loads it
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from _report import children_cpu, facetransfer_exe, save_json  # noqa: E402  (on sys.path)

CRFS = (0, 10, 14, 18, 23, 28)
DILATE = 8
GOAL_DB = 45.0


def decode(path: Path, n: int, kind: str) -> np.ndarray:
    """The first ``n`` frames of a video decoded by ffmpeg: ``"y"`` (F, H, W) the stored luma
    plane, ``"rgb"`` (F, H, W, 3) rgb24 with exact conversion."""
    import imageio_ffmpeg

    if kind == "y":
        gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="yuv420p", bits_per_pixel=12)
    else:
        gen = imageio_ffmpeg.read_frames(str(path), output_params=[
            "-sws_flags", "bicubic+accurate_rnd+full_chroma_int"])
    W, H = next(gen)["size"]
    out = []
    for _, b in zip(range(n), gen):
        a = np.frombuffer(b, np.uint8)
        out.append(a[:W * H].reshape(H, W) if kind == "y" else a.reshape(H, W, 3))
    gen.close()
    return np.stack(out)


def psnr(a: np.ndarray, b: np.ndarray, where: np.ndarray) -> float:
    d = (a.astype(np.float64) - b.astype(np.float64))[where]
    mse = float(np.mean(d ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def run_command(source: Path, target: Path, frames: int, out: Path, repeats: int = 2
                ) -> tuple[list, list]:
    """Wall seconds of ``facetransfer transfer`` in a fresh process, ``repeats`` times in turn
    (the first also pays numba's compilation when its cache is cold, and the page cache), and
    the CPU seconds of each run: the command, its forked tracker and its ffmpeg processes
    together (what two cores must share: wall time cannot fall below half of it)."""
    times, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), children_cpu()
        subprocess.run([facetransfer_exe(), "transfer", "--target", str(target), "--expression-from",
                        str(source), "--out", str(out), "--max-frames", str(frames),
                        "--overwrite", "--no-progress"], check=True, capture_output=True)
        times.append(time.perf_counter() - t)
        cpu.append(children_cpu() - c)
    return times, cpu


def help_seconds(repeats: int = 3) -> float:
    """Fastest wall seconds of ``facetransfer --help`` in a fresh process."""
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        subprocess.run([facetransfer_exe(), "--help"], check=True, capture_output=True)
        times.append(time.perf_counter() - t)
    return min(times)


def mediapipe_peer(target: Path, frames: int) -> dict:
    """The peer: MediaPipe Face Landmarker (Tasks API, VIDEO mode) over the same target frames
    in this process, with blendshapes (the judge's set-up) and without (what the capture
    tracker runs), and the seconds of importing MediaPipe in a fresh process."""
    from _mp_video import filtered_stderr, run_landmarker  # benchmarks/ is on sys.path

    from facetransfer.io.video import read_video

    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import cv2, numpy; from mediapipe.tasks.python "
                    "import vision"], check=True, capture_output=True)
    with_python = time.perf_counter() - t
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import cv2, numpy"], check=True, capture_output=True)
    out = {"import_seconds": with_python - (time.perf_counter() - t)}
    fr, _ = read_video(target, max_frames=frames)
    with filtered_stderr():
        run_landmarker(fr[:2])  # MediaPipe imported, graph code loaded
        for key, shapes in (("video_mode_seconds", False), ("video_mode_blendshapes_seconds", True)):
            t = time.perf_counter()
            run_landmarker(fr, blendshapes=shapes)
            out[key] = time.perf_counter() - t
    return out


def _cpu() -> tuple[float, float]:
    """CPU seconds (user + system) of this process and of its finished children."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime, b.ru_utime + b.ru_stime


def staged(source: Path, target: Path, frames: int, out: Path):
    """The same transfer in this process: seconds per stage, CPU seconds of the plan (reading
    and tracking: this process and the forked tracker) and of the render (this process's
    threads and the ffmpeg encoder), rewritten frames, face masks."""
    import cv2

    from facetransfer import transfer_plan as tp
    from facetransfer import video_transfer as vt
    from facetransfer.default_model import load_default_model

    t = time.perf_counter()
    model = load_default_model()
    timings = {"model": time.perf_counter() - t}
    c0 = _cpu()
    plan = tp.plan_transfer(target, model, expression_from=source, max_frames=frames)
    c1 = _cpu()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * DILATE + 1, 2 * DILATE + 1))
    imgs, masks = [], []

    def keep(i, r):
        imgs.append(r.image)
        masks.append(cv2.dilate(r.face_mask.astype(np.uint8), kernel) > 0)
        return r.image

    done = vt.render_plan(plan, model, vt.RenderTarget(out, overwrite=True), compose=keep)
    c2 = _cpu()
    timings.update(done.timings)
    cpu = {"plan": {"this_process": c1[0] - c0[0], "children": c1[1] - c0[1]},
           "render": {"this_process": c2[0] - c1[0], "children": c2[1] - c1[1]}}
    targets = np.stack([np.asarray(plan.target_frames[i]) for i in range(len(imgs))])
    return timings, cpu, np.stack(imgs), np.stack(masks), plan.fps, targets


def outside(target: Path, frames: np.ndarray, masks: np.ndarray, fps: float, tmp: Path,
            targets: np.ndarray) -> list:
    """Rows per CRF: the result against the target file itself (``psnr_y``, ``psnr_rgb``) and
    against the target after encoding (``psnr_y_encoded``: the target's frames as the reader
    gave them, written by the same writer at the same CRF: what differs is the rewrite alone,
    "up to encoding")."""
    from facetransfer.io.video import VideoOptions, encode_video

    n = len(frames)
    ref = {k: decode(target, n, k) for k in ("y", "rgb")}
    keep = ~masks
    rows = []
    for crf in CRFS:
        p = tmp / f"crf{crf}.mp4"
        encode_video(p, frames, fps, options=VideoOptions("h264", crf), overwrite=True)
        row = {"crf": crf, "mbit_per_s": p.stat().st_size * 8 / 1e6 / (n / fps)}
        for k in ("y", "rgb"):
            back = decode(p, n, k)
            row[f"psnr_{k}"] = psnr(back, ref[k], keep)
        q = tmp / f"target_crf{crf}.mp4"
        encode_video(q, targets, fps, options=VideoOptions("h264", crf), overwrite=True)
        row["psnr_y_encoded"] = psnr(decode(p, n, "y"), decode(q, n, "y"), keep)
        print(f"  CRF {crf:2d}: outside the face Y {row['psnr_y']:.1f} dB, RGB (exact) "
              f"{row['psnr_rgb']:.1f} dB; Y against the target after encoding "
              f"{row['psnr_y_encoded']:.1f} dB; {row['mbit_per_s']:.2f} Mbit/s", flush=True)
        rows.append(row)
        p.unlink()
        q.unlink()
    # before encoding: the rewritten frames against the target decoded exactly to rgb24
    rows.append({"crf": None, "label": "before encoding (RGB, exact decode of the target)",
                 "psnr_rgb": psnr(frames, ref["rgb"], keep)})
    return rows


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    rows = [r for r in report["outside"] if r["crf"] is not None]
    ax.plot([r["crf"] for r in rows], [r["psnr_y"] for r in rows], "o-", label="Y plane")
    ax.plot([r["crf"] for r in rows], [r["psnr_rgb"] for r in rows], "s--",
            label="rgb24, exact conversion")
    ax.plot([r["crf"] for r in rows], [r["psnr_y_encoded"] for r in rows], "^-",
            label="Y plane, vs the target after encoding")
    ax.axhline(GOAL_DB, color="k", ls=":", lw=1)
    ax.axvline(18, color="grey", lw=0.8)
    ax.set_xlabel("CRF (H.264)")
    ax.set_ylabel("PSNR outside the face (dB)")
    ax.set_title("outside the face, both decoded by ffmpeg")
    ax.legend()
    st = report["stages"]
    names = [k for k in st if k != "total"]
    bx.barh(names, [st[k] for k in names])
    mp = report.get("mediapipe", {}).get("video_mode_seconds")
    if mp is not None:
        bx.barh(["MediaPipe VIDEO\n(peer, same frames)"], [mp], color="grey")
    bx.axvline(report["seconds"], color="k", ls=":", lw=1)
    bx.set_xlabel("seconds")
    cmd = report["command_seconds"]
    bx.set_title(f"{report['seconds']:.0f} s of video"
                 + (f": command {cmd:.1f} s" if cmd is not None else ""))
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--source", default="driving_d6")
    ap.add_argument("--target", default="driving_d9")
    args = ap.parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.io.video import video_info

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(data_dir()) / "video"
    source, target = data / f"{args.source}.mp4", data / f"{args.target}.mp4"
    info = video_info(target)
    n = int(round(args.seconds * info.fps))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        runs, cpus = run_command(source, target, n, tmp / "cmd.mp4")
        cmd = runs[-1]
        print(f"command: {', '.join(f'{t:.1f}' for t in runs)} s for {n} frames (in turn); "
              f"CPU {', '.join(f'{c:.1f}' for c in cpus)} s (all its processes)", flush=True)
        helps = help_seconds()
        print(f"--help: {helps:.2f} s", flush=True)
        sys.path.insert(0, str(Path(__file__).parent))
        from _mp_video import filtered_stderr

        with filtered_stderr():  # MediaPipe's native log lines
            stages, stage_cpu, frames, masks, fps, targets = staged(source, target, n,
                                                                    tmp / "staged.mp4")
        total = sum(stages.values())
        print("stages: " + ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f}%)"
                                     for k, v in stages.items()), flush=True)
        print("CPU: " + "; ".join(f"{k} {v['this_process']:.1f} s here, {v['children']:.1f} s "
                                  f"in child processes" for k, v in stage_cpu.items())
              + " (plan: the forked tracker; render: the ffmpeg encoder)", flush=True)
        peer = mediapipe_peer(target, n)
        print("MediaPipe VIDEO mode on the same frames: " + ", ".join(
            f"{k} {v:.1f}" for k, v in peer.items()), flush=True)
        rows = outside(target, frames, masks, fps, tmp, targets)
    stages["total"] = total
    report = {"source": source.name, "target": target.name, "frames": n, "fps": fps,
              "size": list(info.size), "seconds": n / fps, "command_seconds": cmd,
              "command_runs": runs, "command_cpu_seconds": cpus,
              "command_cpu_floor_2_cores": cpus[-1] / 2, "help_seconds": helps,
              "command_beyond_stages": cmd - total, "stages": stages, "stage_cpu": stage_cpu,
              "shares": {k: v / total for k, v in stages.items() if k != "total"},
              "mediapipe": peer,
              "outside_fraction": float((~masks).mean()), "outside": rows}
    save_json(report, out / "transfer_e2e.json")
    plot(report, out / "transfer_e2e.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

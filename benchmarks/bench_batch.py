"""Benchmark of issue 17: many clips on Dask distributed (``facetransfer batch track``).

Measures, in one run:

1. eight clips cut from the data folder (``FACETRANSFER_DATA_DIR/video``; pieces of
   ``--frames`` frames), tracked by the peer — a shell loop of ``facetransfer track`` over the
   clips, one process after another — and by ``batch track`` on an embedded LocalCluster with
   1 and with 2 worker processes: wall time and its ratio to the peer, the overhead per task
   (wall time minus the tracking seconds the tasks report, per clip), and the peak memory of
   each worker (resident set size polled from the scheduler) beside the peer's peak;
2. ``driving_d6`` (1008 frames) tracked whole and in 4 overlapping chunks on 2 workers: time,
   the landmark difference whole vs chunked near the seams and elsewhere, and both tracks'
   landmark error against the stored MediaPipe references (eye corners, nose tip, mouth
   corners, as a fraction of the eye distance).

Both sides use the same tracker settings (``--passes``, ``--points``) and the same model, so
their outputs are the same files. The machine may be shared: the load average is recorded.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_batch.py [--out out/benchmarks]
        [--model MODEL.npz] [--frames 120] [--passes 1] [--points 500]

Writes ``OUT/batch.json`` and ``OUT/batch.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

KEY = [36, 39, 42, 45, 30, 48, 54]  # eye corners, nose tip, mouth corners (iBUG-68)
#: (clip, first frame) of the eight pieces
PIECES = (("face_2", 0), ("WDA_KatieHill_000", 0), ("WDA_KatieHill_000", 80),
          ("driving_d9", 0), ("driving_d9", 240), ("driving_d9", 467),
          ("driving_d6", 300), ("driving_d6", 700))


def cut_pieces(video_dir: Path, folder: Path, n: int) -> list[Path]:
    """Write the eight pieces of ``n`` frames (re-encoded) into ``folder``."""
    from facetransfer.io.video import read_video, write_video

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for clip, start in PIECES:
        p = folder / f"{clip}_{start:04d}.mp4"
        if not p.is_file():
            frames, fps = read_video(video_dir / f"{clip}.mp4", start=start, stop=start + n)
            write_video(p, frames, fps)
        out.append(p)
    return out


class MemoryPoll(threading.Thread):
    """Peak resident memory of each worker, polled from the scheduler every 0.5 s."""

    def __init__(self, client):
        super().__init__(daemon=True)
        self.client, self.peak, self.stop = client, {}, threading.Event()

    def run(self):
        while not self.stop.is_set():
            try:
                for addr, w in self.client.scheduler_info()["workers"].items():
                    m = w.get("metrics", {}).get("memory", 0)
                    self.peak[addr] = max(self.peak.get(addr, 0), m)
            except Exception:  # noqa: BLE001 (cluster closing)
                pass
            self.stop.wait(0.5)


def serial_peer(clips, model_path, out: Path, args) -> dict:
    """``for c in clips; do facetransfer track c ...; done``: wall time and peak memory."""
    out.mkdir(parents=True, exist_ok=True)
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu0 = ru.ru_utime + ru.ru_stime
    t0 = time.perf_counter()
    for c in clips:
        subprocess.run([sys.executable, "-m", "facetransfer.cli.main", "track", str(c),
                        "--model", str(model_path), "--out", str(out / f"{c.stem}.npz"),
                        "--passes", str(args.passes), "--points", str(args.points)],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_s": wall, "peak_rss_mb": ru.ru_maxrss * 1024 / 1e6,
            "cpu_s": ru.ru_utime + ru.ru_stime - cpu0}


def batch_run(clips, model_path, out: Path, workers: int, args, *, chunk: int = 0,
              overlap: int = 30) -> dict:
    """``facetransfer batch track`` (library calls, so that memory can be polled)."""
    from facetransfer.batch import batch_track, clip_jobs, open_client
    from facetransfer.model import load_model
    from facetransfer.track import TrackOptions

    t0 = time.perf_counter()
    cpu_client0 = time.process_time()
    model = load_model(model_path)
    t_load = time.perf_counter() - t0
    opt = TrackOptions(passes=args.passes, n_points=args.points)
    with open_client(workers=workers) as client:
        t_cluster = time.perf_counter() - t0 - t_load
        poll = MemoryPoll(client)
        poll.start()
        t1 = time.perf_counter()
        res = batch_track(clip_jobs([str(c) for c in clips]), out, model, client=client,
                          options=opt, chunk=chunk, overlap=overlap, overwrite=True)
        t_run = time.perf_counter() - t1
        poll.stop.set()
        poll.join()
        cpu = client.run(_process_cpu)  # worker processes: CPU seconds since they started
    wall = time.perf_counter() - t0
    task_s = sum(r.seconds for r in res.rows)
    return {"workers": workers, "wall_s": wall, "load_model_s": t_load, "cluster_s": t_cluster,
            "run_s": t_run, "task_seconds": task_s, "failed": res.n_failed,
            "client_cpu_s": time.process_time() - cpu_client0,
            "workers_cpu_s": sum(cpu.values()),
            "overhead_per_task_s": (t_run * workers - task_s) / len(clips),
            "worker_peak_rss_mb": sorted(v / 1e6 for v in poll.peak.values()),
            "per_clip_s": {r.clip: r.seconds for r in res.rows}}


def _process_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def key_error(track, ref_path: Path) -> float:
    """Mean error of the key landmarks against MediaPipe, as a fraction of the eye distance."""
    from facetransfer.track.landmarks import mediapipe_to_ibug

    with np.load(ref_path) as z:
        ref = mediapipe_to_ibug(z["landmarks"][:, :, :2])  # (F, 68, 2)
    n = min(len(ref), track.n_frames)
    L, R = track.landmarks2d[:n, KEY], ref[:n, KEY]
    ok = np.all(np.isfinite(R), axis=(1, 2))
    iod = np.linalg.norm(R[ok, 0] - R[ok, 3], axis=1)
    return float((np.linalg.norm(L[ok] - R[ok], axis=2).mean(1) / iod).mean())


def chunk_experiment(video: Path, model_path, out: Path, args) -> dict:
    """driving_d6 whole (the peer: ``facetransfer track``) against 4 chunks on 2 workers."""
    from facetransfer.batch import plan_chunks, seam_difference
    from facetransfer.track import Track

    whole_out = out / "whole"
    peer = serial_peer([video], model_path, whole_out, args)
    whole = Track.load(whole_out / f"{video.stem}.npz")
    n = whole.n_frames
    chunk = -(-(n + 3 * args.overlap) // 4)  # 4 chunks
    chunks = plan_chunks(n, chunk, args.overlap)
    res = batch_run([video], model_path, out / "chunked", 2, args, chunk=chunk,
                    overlap=args.overlap)
    joined = Track.load(out / "chunked" / f"{video.stem}.npz")
    rep = seam_difference(whole, joined, chunks, radius=args.overlap // 2)
    ref = video.with_name(video.stem + ".mediapipe478.npz")
    return {"frames": n, "chunk": chunk, "overlap": args.overlap,
            "chunks": [(c.start, c.stop) for c in chunks],
            "whole_wall_s": peer["wall_s"], "chunked_wall_s": res["wall_s"],
            "chunked_task_seconds": res["task_seconds"],
            "seams": list(rep.seams), "seam_px": list(rep.seam_px),
            "elsewhere_px": rep.elsewhere_px, "motion_px": list(rep.motion_px),
            "whole_motion_px": list(rep.whole_motion_px),
            "iod_px": rep.iod_px,
            "key_error_whole_iod": key_error(whole, ref) if ref.is_file() else None,
            "key_error_chunked_iod": key_error(joined, ref) if ref.is_file() else None,
            "per_frame_px": np.linalg.norm(whole.landmarks2d - joined.landmarks2d,
                                           axis=2).mean(1).tolist()}


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    m = result["many_clips"]
    names = ["serial track", "batch 1 worker", "batch 2 workers"]
    walls = [m["serial"]["wall_s"], m["batch1"]["wall_s"], m["batch2"]["wall_s"]]
    ax[0].bar(names, walls, color=["0.5", "C0", "C1"])
    for i, w in enumerate(walls):
        ax[0].text(i, w, f"{w:.0f} s\n({walls[0] / w:.2f}x)", ha="center", va="bottom")
    ax[0].set_ylabel("wall time, 8 clips (s)")
    ax[0].set_title(f"8 clips x {result['frames_per_clip']} frames "
                    f"(load {result['load_average'][0]:.1f} on {os.cpu_count()} cores)")
    mem = [m["serial"]["peak_rss_mb"]] + m["batch1"]["worker_peak_rss_mb"] + \
        m["batch2"]["worker_peak_rss_mb"]
    labels = ["serial"] + ["1w: w0"] + [f"2w: w{i}" for i in range(len(
        m["batch2"]["worker_peak_rss_mb"]))]
    ax[1].bar(labels, mem, color=["0.5"] + ["C0"] + ["C1"] * (len(mem) - 2))
    ax[1].set_ylabel("peak resident memory (MB)")
    ax[1].set_title("memory per process")
    c = result["chunks"]
    ax[2].plot(c["per_frame_px"], lw=0.8, label="|whole - chunked| (px)")
    for s in c["seams"]:
        ax[2].axvline(s, color="C3", ls="--", lw=0.8)
    ax[2].set_xlabel("frame of driving_d6")
    ax[2].set_ylabel("mean landmark difference (px)")
    ax[2].set_title(f"4 chunks vs whole: seams {np.mean(c['seam_px']):.2f} px, elsewhere "
                    f"{c['elsewhere_px']:.2f} px (eye dist. {c['iod_px']:.0f} px)")
    ax[2].legend(loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--model", help="model file (default: the default model, cached)")
    ap.add_argument("--frames", type=int, default=120, help="frames per piece")
    ap.add_argument("--passes", type=int, default=1)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--overlap", type=int, default=40)
    ap.add_argument("--skip-chunks", action="store_true")
    args = ap.parse_args(argv)

    from facetransfer.default_model import default_model_path, load_default_model

    data = Path(os.environ["FACETRANSFER_DATA_DIR"]) / "video"
    out = Path(args.out)
    work = out / "batch_work"
    model_path = Path(args.model) if args.model else default_model_path()
    if not args.model:
        load_default_model()  # built once into the cache
    clips = cut_pieces(data, work / "clips", args.frames)
    result = {"machine": platform.platform(), "cpus": os.cpu_count(),
              "load_average": os.getloadavg(), "model": str(model_path),
              "frames_per_clip": args.frames, "passes": args.passes, "points": args.points,
              "clips": [c.name for c in clips]}
    many = {"serial": serial_peer(clips, model_path, work / "serial", args)}
    print("serial", many["serial"], flush=True)
    for w in (1, 2):
        many[f"batch{w}"] = batch_run(clips, model_path, work / f"batch{w}", w, args)
        print(f"batch {w}", many[f"batch{w}"], flush=True)
    for w in (1, 2):
        many[f"batch{w}"]["ratio_to_serial"] = many["serial"]["wall_s"] / many[f"batch{w}"][
            "wall_s"]
    result["many_clips"] = many
    if not args.skip_chunks:
        result["chunks"] = chunk_experiment(data / "driving_d6.mp4", model_path, work / "d6",
                                            args)
        print("chunks", {k: v for k, v in result["chunks"].items() if k != "per_frame_px"},
              flush=True)
    result["load_average_end"] = os.getloadavg()
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.io.atomic import write_text_atomic

    write_text_atomic(out / "batch.json", json.dumps(result, indent=1))
    if "chunks" in result:
        plot(result, out / "batch.png")
    print(f"wrote {out / 'batch.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The H.264 encoder alone on the frames issue 13's transfer writes: x264 settings against the
default's CPU, size and quality.

The rewritten frames of ``facetransfer transfer`` (``driving_d9`` with the expressions of
``driving_d6``, 300 frames, 512x480) are made once in this process (``plan_transfer`` +
``render_plan``, as ``bench_transfer_e2e.py`` does; kept in ``--frames`` to be reused), with
the face masks (dilated 8 px) and the target's frames as the reader gave them. Both are turned
into ``yuv420p`` by the writer's own conversion (``facetransfer.io.video._yuv420p``) and each
setting is an ffmpeg run on that file with the writer's arguments (x264 preset ``faster``, CRF
18, the ``-threads`` / ``-x264-params`` of the setting appended, so x264's ``faster`` is the
base whatever this tree's default adds) and reports:

- ``cpu``: user + system seconds of the ffmpeg process (``os.wait4``), each round, the
  settings in turn; with ``--busy N`` beside N busy-looping processes (the transfer's render
  threads compete for the same cores);
- ``bytes``; ``psnr_out_file``: the luma outside the face against the target file itself;
  ``psnr_out_encoded``: against the target's frames encoded alike (issue 13's "up to
  encoding", the 45 dB bar); ``psnr_whole``: the whole luma against the frames before
  encoding.

    python benchmarks/bench_x264_params.py --out out/benchmarks [--busy 2] [--rounds 3]

Writes ``OUT/x264_params.json`` and ``OUT/x264_params.png``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["FACETRANSFER_TRACK_CACHE"] = "off"
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import save_json, save_plot  # noqa: E402

#: Settings on top of the base ("faster", CRF 18): ``-threads`` and ``-x264-params``.
SETTINGS = {
    "faster (x264's)": [], "threads=1": ["-threads", "1"], "threads=2": ["-threads", "2"],
    "threads=4": ["-threads", "4"], "rc-lookahead=10": ["-x264-params", "rc-lookahead=10"],
    "rc-lookahead=15": ["-x264-params", "rc-lookahead=15"], "ref=1": ["-x264-params", "ref=1"],
    "subme=3": ["-x264-params", "subme=3"], "subme=2": ["-x264-params", "subme=2"],
    "me=dia": ["-x264-params", "me=dia"], "b-adapt=0": ["-x264-params", "b-adapt=0"],
    "weightp=0": ["-x264-params", "weightp=0"], "weightb=0": ["-x264-params", "weightb=0"],
    "bframes=2": ["-x264-params", "bframes=2"], "mbtree=0": ["-x264-params", "mbtree=0"],
    "lookahead-threads=1": ["-x264-params", "lookahead-threads=1"],
    "sync-lookahead=0": ["-x264-params", "sync-lookahead=0"],
    "chroma-me=0": ["-x264-params", "chroma-me=0"],
    "no b8x8 (the default)": ["-x264-params", "partitions=i4x4,i8x8,p8x8"],
    "no b8x8, i4x4": ["-x264-params", "partitions=i8x8,p8x8"],
    "no b8x8, p8x8": ["-x264-params", "partitions=i4x4,i8x8"],
    "no b8x8, threads=2": ["-threads", "2", "-x264-params", "partitions=i4x4,i8x8,p8x8"],
    "no b8x8, subme=3": ["-x264-params", "partitions=i4x4,i8x8,p8x8:subme=3"],
}
BASE = "faster (x264's)"


def frames(path: Path) -> dict:
    """The transfer's written frames, face masks, target frames and fps (made once)."""
    if not path.exists():
        from bench_transfer_e2e import staged

        from facetransfer.assets import data_dir

        data = Path(data_dir()) / "video"
        with tempfile.TemporaryDirectory() as tmp:
            _, _, fr, masks, fps, targets = staged(data / "driving_d6.mp4",
                                                   data / "driving_d9.mp4", 300,
                                                   Path(tmp) / "s.mp4")
        np.savez(path, frames=fr, masks=masks, targets=targets, fps=fps)
    return dict(np.load(path))


def write_yuv(images: np.ndarray, path: Path) -> None:
    """``images`` as the writer pipes them to ffmpeg: ``yuv420p`` by its own conversion."""
    from facetransfer.io.video import _yuv420p

    with open(path, "wb") as f:
        for im in images:
            f.write(np.ascontiguousarray(_yuv420p(im)).tobytes())


def command(src: Path, dst: Path, extra: list, hw, fps: float) -> list:
    """ffmpeg encoding ``src`` as the writer does at x264's ``faster``, then ``extra``."""
    from facetransfer.io.video import VideoOptions, _encode_args, ffmpeg_exe

    args = _encode_args(VideoOptions(codec="h264"), ".mp4")
    if "-x264-params" in args:   # the base is x264's own preset: the setting adds to it
        i = args.index("-x264-params")
        args = args[:i] + args[i + 2:]
    return [ffmpeg_exe(), "-hide_banner", "-nostdin", "-loglevel", "error", "-y", "-f",
            "rawvideo", "-pix_fmt", "yuv420p", "-s", f"{hw[1]}x{hw[0]}", "-framerate",
            str(fps), "-i", str(src), *args, *extra, "-f", "mp4", str(dst)]


def run(cmd: list) -> tuple[float, float]:
    """CPU seconds (user + system) and wall seconds of one ffmpeg run."""
    t = time.perf_counter()
    proc = subprocess.Popen(cmd)
    _, status, use = os.wait4(proc.pid, 0)
    if status:
        raise SystemExit(f"ffmpeg failed: {' '.join(cmd)}")
    return use.ru_utime + use.ru_stime, time.perf_counter() - t


def decode_y(path, n: int) -> np.ndarray:
    """The stored luma planes of the first ``n`` frames, decoded by ffmpeg."""
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="yuv420p", bits_per_pixel=12)
    w, h = next(gen)["size"]
    out = [np.frombuffer(b, np.uint8)[:w * h].reshape(h, w) for _, b in zip(range(n), gen)]
    gen.close()
    return np.stack(out)


def psnr(a: np.ndarray, b: np.ndarray, where=None) -> float:
    d = a.astype(np.float64) - b.astype(np.float64)
    return float(10 * np.log10(255.0 ** 2 / np.mean((d if where is None else d[where]) ** 2)))


def quality(extra: list, ref: dict, tmp: Path) -> dict:
    """Bytes and PSNRs of one setting (see the module's docstring)."""
    n, hw, fps = len(ref["masks"]), ref["masks"].shape[1:], float(ref["fps"])
    run(command(tmp / "frames.yuv", tmp / "r.mp4", extra, hw, fps))
    run(command(tmp / "targets.yuv", tmp / "t.mp4", extra, hw, fps))
    y, yt, keep = decode_y(tmp / "r.mp4", n), decode_y(tmp / "t.mp4", n), ~ref["masks"]
    return {"bytes": (tmp / "r.mp4").stat().st_size,
            "psnr_out_file": psnr(y, ref["y_file"], keep),
            "psnr_out_encoded": psnr(y, yt, keep), "psnr_whole": psnr(y, ref["y_in"])}


def timed(settings: dict, ref: dict, tmp: Path, rounds: int, busy: int) -> dict:
    """CPU and wall seconds of each setting, ``rounds`` rounds in turn, beside ``busy``
    busy-looping processes."""
    hw, fps = ref["masks"].shape[1:], float(ref["fps"])
    out = {k: {"cpu": [], "wall": []} for k in settings}
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        for r in range(rounds):
            for k, extra in settings.items():
                cpu, wall = run(command(tmp / "frames.yuv", tmp / "x.mp4", extra, hw, fps))
                out[k]["cpu"].append(cpu)
                out[k]["wall"].append(wall)
            print(f"round {r + 1} of {rounds}", flush=True)
    finally:
        for p in spin:
            p.kill()
            p.wait()
    return out


def plot(rows: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6))
    base = rows[BASE]
    for k, r in rows.items():
        dx = float(np.median(r["cpu"]) - np.median(base["cpu"]))
        dy = r["psnr_out_encoded"] - base["psnr_out_encoded"]
        ax.plot(dx, dy, "o", color="C3" if k == "no b8x8 (the default)" else "C0")
        ax.annotate(k, (dx, dy), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.axhline(-0.1, color="grey", ls=":", lw=1)
    ax.axvline(-0.3, color="grey", ls=":", lw=1)
    ax.set_xlabel("encoder CPU-s, 300 frames, against x264's faster (median)")
    ax.set_ylabel("dB outside the face, vs the target encoded alike, against faster")
    ax.set_title("x264 settings on issue 13's written frames (CRF 18)")
    save_plot(fig, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--frames", default="out/benchmarks/x264_frames.npz")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy", type=int, default=0, help="busy-looping processes beside it")
    args = ap.parse_args()
    from facetransfer.assets import data_dir

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ref = frames(Path(args.frames))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_yuv(ref["frames"], tmp / "frames.yuv")
        write_yuv(ref["targets"], tmp / "targets.yuv")
        n = len(ref["masks"])
        ref["y_file"] = decode_y(Path(data_dir()) / "video" / "driving_d9.mp4", n)
        ref["y_in"] = _luma(tmp / "frames.yuv", ref)
        rows = {k: quality(e, ref, tmp) for k, e in SETTINGS.items()}
        for k, t in timed(SETTINGS, ref, tmp, args.rounds, args.busy).items():
            rows[k].update(t)
    base = float(np.median(rows[BASE]["cpu"]))
    for k, r in rows.items():
        c = float(np.median(r["cpu"]))
        print(f"{k:24s} CPU {c:.2f} s ({c - base:+.2f}; {min(r['cpu']):.2f}-{max(r['cpu']):.2f})"
              f" {r['bytes'] / 1e6:.3f} MB, outside vs file {r['psnr_out_file']:.2f} dB, vs "
              f"encoded {r['psnr_out_encoded']:.2f} dB, whole {r['psnr_whole']:.2f} dB")
    save_json({"busy": args.busy, "rounds": args.rounds, "frames": len(ref["masks"]),
               "settings": {k: SETTINGS[k] for k in rows}, "rows": rows},
              out / "x264_params.json")
    plot(rows, out / "x264_params.png")
    return 0


def _luma(path: Path, ref: dict):
    """The luma planes of a ``yuv420p`` file of ``ref``'s frames' size."""
    h, w = ref["masks"].shape[1:]
    raw = np.fromfile(path, np.uint8).reshape(len(ref["masks"]), h * w * 3 // 2)
    return raw[:, :h * w].reshape(-1, h, w)


if __name__ == "__main__":
    sys.exit(main())

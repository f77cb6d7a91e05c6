"""Memory of a transfer of long or high-resolution clips: decoded frames in memory or in files.

``facetransfer transfer`` keeps both clips' decoded frames for the whole job. Past a share of the
available memory a clip is decoded into an unnamed file instead (``facetransfer.io.memory``).
This runs the command on a 1080p pair made from the data folder's clips (``driving_d9`` onto
itself scaled to 1152x1080 and ``driving_d6`` to 1080x1080, both padded to 1920x1080, all their
frames by default) twice in turn:

- ``memory``: every frame in memory (``FACETRANSFER_FRAME_MEMORY`` far above the clips);
- ``files``: the default budget, or ``--budget`` (the 1080p clips pass it at 3.6 GB each only
  on a machine with less than 15 GB available, so the default run sets 1G);

sampling every 0.5 s the process tree's proportional resident memory from ``/proc/PID/
smaps_rollup`` (a page shared by the forked tracker and its parent counts once): anonymous
(``Pss_Anon``: what only swap could free) and file-backed (``Pss_File``: the page cache of the
frame files and of the libraries, which the kernel takes back under pressure). With ``--limit`` (e.g. ``6G``)
and a writable cgroup-v1 memory hierarchy (``/sys/fs/cgroup/memory``, as root), both runs are
repeated inside a control group of that limit: the exit status says whether the kernel killed
the job. No peer: MediaPipe does not rewrite video.

Usage::

    python benchmarks/bench_memory.py --out out/benchmarks [--frames N] [--limit 6G]

Writes ``OUT/memory.json`` and ``OUT/memory.png``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from _report import arguments, facetransfer_exe, save_json, save_plot  # benchmarks/ is on sys.path

DATA = Path(os.environ.get("FACETRANSFER_DATA_DIR", "../shared/data")) / "video"
CGROUP = Path("/sys/fs/cgroup/memory")


def make_clip(src: Path, out: Path, width: int, frames: int | None) -> Path:
    """``src`` scaled to ``width`` x 1080 and padded to 1920x1080, H.264 (made once)."""
    import imageio_ffmpeg

    if out.exists():
        return out
    tmp = out.with_name(out.stem + ".partial.mp4")
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-y", "-i", str(src), "-vf",
           f"scale={width}:1080,pad=1920:1080:{(1920 - width) // 2}:0", "-c:v", "libx264",
           "-preset", "veryfast", "-crf", "20", "-pix_fmt", "yuv420p", "-an"]
    if frames:
        cmd += ["-frames:v", str(frames)]
    subprocess.run(cmd + [str(tmp)], check=True)
    tmp.rename(out)
    return out


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            kids = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            kids = []
        todo += [int(k) for k in kids]
    return out


def _pss(pids: list[int]) -> tuple[int, int]:
    """Summed proportional anonymous and file-backed memory (``Pss_Anon``, ``Pss_File`` of
    ``/proc/PID/smaps_rollup``, bytes) of ``pids``: a page the forked tracker shares with its
    parent counts once."""
    anon = fil = 0
    for p in pids:
        try:
            for line in Path(f"/proc/{p}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss_Anon:"):
                    anon += int(line.split()[1]) * 1024
                elif line.startswith("Pss_File:"):
                    fil += int(line.split()[1]) * 1024
        except OSError:
            pass
    return anon, fil


def run(target: Path, source: Path, out: Path, env: dict, cgroup: Path | None) -> dict:
    """The command once, its memory sampled; in ``cgroup`` when given."""
    exe = facetransfer_exe()
    cmd = [exe, "transfer", "--target", str(target), "--expression-from", str(source),
           "--out", str(out), "--overwrite", "--no-progress"]
    pre = None
    if cgroup is not None:
        (cgroup / "memory.max_usage_in_bytes").write_text("0")
        pre = lambda: (cgroup / "cgroup.procs").write_text(str(os.getpid()))  # noqa: E731
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=pre)
    peak_anon = peak_file = peak_sum = 0
    series = []
    while proc.poll() is None:
        anon, fil = _pss(_tree(proc.pid))
        peak_anon, peak_file = max(peak_anon, anon), max(peak_file, fil)
        peak_sum = max(peak_sum, anon + fil)
        series.append((time.perf_counter() - t, anon / 2**30, fil / 2**30))
        time.sleep(0.5)
    _, err = proc.communicate()
    row = {"seconds": time.perf_counter() - t, "returncode": proc.returncode,
           "killed": proc.returncode == -9, "peak_anon_gib": peak_anon / 2**30,
           "peak_file_gib": peak_file / 2**30, "peak_rss_gib": peak_sum / 2**30,
           "stderr_tail": err.decode("utf-8", "replace").strip().splitlines()[-1:],
           "series": series}
    if cgroup is not None:
        row["cgroup_peak_gib"] = int((cgroup / "memory.max_usage_in_bytes").read_text()) / 2**30
    return row


def make_cgroup(limit: str) -> Path | None:
    """A fresh cgroup-v1 memory group of ``limit`` bytes, or None where none can be made."""
    from facetransfer.io.memory import parse_bytes

    g = CGROUP / f"facetransfer-bench-{os.getpid()}"
    try:
        g.mkdir()
        (g / "memory.limit_in_bytes").write_text(str(parse_bytes(limit)))
        return g
    except OSError:
        return None


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = report["runs"]
    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 3.6), sharey=True)
    for ax, (name, r) in zip(axes, runs.items()):
        t = [s[0] for s in r["series"]]
        ax.stackplot(t, [s[1] for s in r["series"]], [s[2] for s in r["series"]],
                     labels=["anonymous", "file-backed"], alpha=0.8)
        end = "killed by the kernel" if r["killed"] else f"exit {r['returncode']}"
        ax.set_title(f"{name}\n{r['seconds']:.0f} s, {end}", fontsize=9)
        ax.set_xlabel("seconds")
    axes[0].set_ylabel("resident memory (GiB)")
    axes[0].legend(loc="upper left", fontsize=8)
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    ap.add_argument("--frames", type=int, default=None, help="frames of each clip (all)")
    ap.add_argument("--budget", default="1G", help="frame memory of the files run")
    ap.add_argument("--limit", default=None, help="also run both in a cgroup of this memory")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = out / "memory_clips"
    work.mkdir(exist_ok=True)
    tag = "" if args.frames is None else f"_{args.frames}"
    target = make_clip(DATA / "driving_d9.mp4", work / f"d9_1080{tag}.mp4", 1152, args.frames)
    source = make_clip(DATA / "driving_d6.mp4", work / f"d6_1080{tag}.mp4", 1080, args.frames)
    from facetransfer.io.memory import available_memory, frame_budget
    from facetransfer.io.video import video_info

    info = video_info(target)
    report = {"target": target.name, "source": source.name, "frames": info.n_frames,
              "size": list(info.size), "decoded_gib_per_clip":
              info.n_frames * info.size[0] * info.size[1] * 3 / 2**30,
              "available_gib": available_memory() / 2**30,
              "default_budget_gib": frame_budget() / 2**30, "runs": {}}
    modes = {"memory": "1000G", "files": args.budget}
    groups = [None]
    if args.limit:
        g = make_cgroup(args.limit)
        if g is None:
            report["limit_note"] = f"no writable cgroup-v1 memory hierarchy at {CGROUP}"
        else:
            groups.append(g)
            report["limit"] = args.limit
    try:
        for g in groups:
            for name, budget in modes.items():
                env = dict(os.environ, FACETRANSFER_FRAME_MEMORY=budget, FACETRANSFER_TRACK_CACHE="off")
                key = name if g is None else f"{name}, {args.limit} limit"
                r = run(target, source, work / "result.mp4", env, g)
                report["runs"][key] = r
                print(f"{key}: {r['seconds']:.1f} s, exit {r['returncode']}, peak anonymous "
                      f"{r['peak_anon_gib']:.2f} GiB, file-backed {r['peak_file_gib']:.2f} GiB",
                      flush=True)
    finally:
        for g in groups[1:]:
            try:
                g.rmdir()
            except OSError:
                pass
    save_json(report, out / "memory.json")
    plot(report, out / "memory.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

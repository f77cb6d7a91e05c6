"""End to end of issue 13, this tree against another revision, in turn, with the peer each round.

The machine's speed drifts by 20-35 % within an hour (Face Landmarker alone on the same 300
frames took 2.2 to 3.1 s in one session), so a change to the transfer's speed is measured
against the revision before it in the same run: each round runs the peer (Face Landmarker in
VIDEO mode with blendshapes on the target's 300 frames, a fresh process), then the base's
``facetransfer transfer`` and this tree's, the base first in odd rounds and second in even
ones (a run after another may find the machine otherwise: always second, the new tree took
that alone), on issue 13's 10-second pair (``driving_d9`` with
the expressions of ``driving_d6``, default model, H.264 CRF 18). Wall seconds, and the CPU
seconds of each command with its forked tracker and its ffmpeg. Both trees' bytecode is
compiled first and each command runs once before the rounds (numba's caches, the page cache).
Each round's ``cpu_diff`` is this tree's CPU seconds less the base's: the medians of those
pairs spread less than the difference of the two medians. ``--render-cache off`` times both
without the render cache (``FACETRANSFER_RENDER_CACHE=off``: one encoder, no parts); by
default it is on, as a user's command runs.
With ``--hd`` the pair is first made 1080p (:data:`HD_FILTER`: footage as a camera would give
it, the face ~330 pixels tall) and the peer runs on that target.

    python benchmarks/bench_transfer_e2e_ab.py --base-rev main~5 --rounds 3 --out out/benchmarks
    python benchmarks/bench_transfer_e2e_ab.py --hd --base-rev main~5 --out out/benchmarks-hd

Writes ``OUT/transfer_e2e_ab.json`` and ``OUT/transfer_e2e_ab.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

# timed from scratch: no track reused from the track cache (facetransfer.track.cache)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _revision import extract_src  # noqa: E402
from _report import children_cpu, facetransfer_exe  # noqa: E402

TARGET, SOURCE, FRAMES = "driving_d9.mp4", "driving_d6.mp4", 300


#: ``--hd``: the pair made 1080p, as footage from a camera would be: each clip scaled to
#: 640 rows (its face ~330 pixels tall) over its own frame scaled to 1920x1080 and blurred
#: (a background that moves with the clip, not a flat border), H.264 CRF 18, square pixels.
HD_FILTER = ("[0:v]split[a][b];[a]scale=1920:1080,setsar=1,boxblur=20[bg];"
             "[b]scale=-2:640,setsar=1[fg];[bg][fg]overlay=(W-w)/2:(H-h)/2,setsar=1")

_VIDEOS: tuple[Path, Path] | None = None   # the pair this run times (main sets it)


def _videos() -> tuple[Path, Path]:
    if _VIDEOS is not None:
        return _VIDEOS
    from facetransfer.assets import data_dir

    root = data_dir() / "video"
    return root / TARGET, root / SOURCE


def hd_pair(folder: Path) -> tuple[Path, Path]:
    """The pair at 1080p (:data:`HD_FILTER`; made once into ``folder``, with the audio)."""
    import imageio_ffmpeg

    folder.mkdir(parents=True, exist_ok=True)
    made = []
    for clip in _videos():
        out = folder / f"{clip.stem}_1080p.mp4"
        if not out.exists():
            tmp = out.with_name(out.stem + ".partial.mp4")
            subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-y", "-i",
                            str(clip), "-frames:v", str(FRAMES), "-filter_complex", HD_FILTER,
                            "-c:v", "libx264", "-preset", "veryfast", "-crf", "18",
                            "-pix_fmt", "yuv420p", "-c:a", "copy", str(tmp)], check=True)
            tmp.rename(out)
        made.append(out)
    return made[0], made[1]


def command(src: Path, out: Path) -> tuple[float, float]:
    """Wall and CPU seconds of one ``facetransfer transfer`` with ``src`` first on the path."""
    target, source = _videos()
    env = dict(os.environ, PYTHONPATH=str(src))
    exe = facetransfer_exe()
    t, c = time.perf_counter(), children_cpu()
    subprocess.run([exe, "transfer", "--target", str(target), "--expression-from", str(source),
                    "--out", str(out), "--max-frames", str(FRAMES), "--overwrite",
                    "--no-progress"], check=True, capture_output=True, env=env)
    return time.perf_counter() - t, children_cpu() - c


def peer() -> float:
    """Seconds of Face Landmarker alone on the target's frames, in a fresh process."""
    target, _ = _videos()
    code = ("import sys, time\n"
            f"sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})\n"
            "from _mp_video import filtered_stderr, run_landmarker\n"
            "from facetransfer.io.video import read_video\n"
            f"fr, _ = read_video({str(target)!r}, max_frames={FRAMES})\n"
            "with filtered_stderr():\n"
            "    run_landmarker(fr[:2])\n"
            "    t = time.perf_counter()\n"
            "    run_landmarker(fr, blendshapes=True)\n"
            "    print(time.perf_counter() - t)\n")
    res = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return float(res.stdout.split()[-1])


def plot(rows: list, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(rows))
    for key, colour in (("peer", "tab:grey"), ("base", "tab:orange"), ("new", "tab:blue")):
        ax.plot(x, [r[key] for r in rows], "o-", color=colour,
                label={"peer": "Face Landmarker alone", "base": "base revision",
                       "new": "this tree"}[key])
    ax.axhline(10.0, color="k", lw=0.8, ls="--", label="the clip's 10 s")
    ax.set_xticks(x, [f"round {i + 1}" for i in x])
    ax.set_ylabel("wall seconds")
    ax.set_title(f"10-s transfer end to end, in turn ({_videos()[0].name})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-rev", required=True, help="git revision of this repository")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--hd", action="store_true", help="the pair made 1080p (HD_FILTER)")
    ap.add_argument("--render-cache", choices=("on", "off"), default="on",
                    help="FACETRANSFER_RENDER_CACHE for both commands (default on)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    global _VIDEOS
    os.environ["FACETRANSFER_RENDER_CACHE"] = args.render_cache
    if args.hd:
        _VIDEOS = hd_pair(out / "hd")
    trees = {"base": extract_src(args.base_rev, "bench_e2e_ab_"),
             "new": Path(__file__).resolve().parents[1] / "src"}
    for src in trees.values():
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(src)], check=True)
        command(src, out / "ab.mp4")                       # warm: caches, page cache
    rows = []
    for r in range(args.rounds):
        row = {"peer": round(peer(), 2)}
        names = ("base", "new") if r % 2 == 0 else ("new", "base")
        for name in names:
            wall, cpu = command(trees[name], out / "ab.mp4")
            row[name], row[f"{name}_cpu"] = round(wall, 2), round(cpu, 2)
        row["first"], row["cpu_diff"] = names[0], round(row["new_cpu"] - row["base_cpu"], 2)
        print(row, flush=True)
        rows.append(row)
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0] if k != "first"}
    print("medians: " + ", ".join(f"{k} {v:.2f}" for k, v in med.items()))
    (out / "transfer_e2e_ab.json").write_text(json.dumps(
        {"base_rev": args.base_rev, "render_cache": args.render_cache,
         "target": str(_videos()[0]), "source": str(_videos()[1]),
         "rounds": rows, "medians": med}, indent=1))
    plot(rows, out / "transfer_e2e_ab.png")
    (out / "ab.mp4").unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

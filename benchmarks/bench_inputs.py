"""Unusual inputs tried as a user would: each as a transfer's target and as its source.

The first three seconds of ``driving_d6`` re-encoded by the imageio-ffmpeg binary in the forms
footage arrives in: an odd frame size (4:4:4), 10-bit HEVC, VP9 in WebM, grey, ProRes 4444
with alpha, 64x64, transposed, a single frame, two seconds of black before the face, and an
audio-only file. Each runs ``facetransfer transfer --max-frames 90`` as the target (the source
``WDA_KatieHill_000``) and as the source (onto ``WDA_KatieHill_000``), in a fresh process,
and is judged on what a user sees and keeps:

* ``ok``: status 0 with the result's frame size that of the target as shown (grown by a pixel
  to an even size for 4:2:0, with a warning saying so) and, for a black-and-white target, a
  black-and-white result (:mod:`facetransfer.monochrome`), or status 2 with one line of the
  tool's own (an input that cannot be used) and no traceback;
* the result's frame at three quarters of its length goes into a contact picture (past a
  black opening).

Writes ``OUT/inputs.json`` and ``OUT/inputs.png``::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_inputs.py --out out/benchmarks
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import facetransfer_exe, out_and_data, save_json, save_plot  # noqa: E402

SECONDS = 3
#: frames of each transfer (the target's first; 90: all of a re-encoded clip's 3 seconds)
FRAMES = 90
#: name, ffmpeg output arguments (after ``-i driving_d6.mp4 -t 3``), file suffix
VARIANTS = (
    ("odd 511x383, 4:4:4", ["-vf", "scale=511:383", "-c:v", "libx264", "-pix_fmt", "yuv444p"],
     ".mp4"),
    ("10-bit HEVC", ["-c:v", "libx265", "-pix_fmt", "yuv420p10le", "-x265-params",
                     "log-level=error"], ".mp4"),
    ("VP9 WebM", ["-c:v", "libvpx-vp9", "-b:v", "1M"], ".webm"),
    ("grey", ["-vf", "format=gray", "-c:v", "libx264", "-pix_fmt", "gray"], ".mp4"),
    ("ProRes 4444, alpha", ["-c:v", "prores_ks", "-profile:v", "4", "-pix_fmt", "yuva444p10le"],
     ".mov"),
    ("64x64", ["-vf", "scale=64:64", "-c:v", "libx264"], ".mp4"),
    ("transposed", ["-vf", "transpose=1", "-c:v", "libx264"], ".mp4"),
    ("one frame", ["-frames:v", "1", "-c:v", "libx264"], ".mp4"),
    ("2 s of black first", ["-vf", "drawbox=enable='lt(t,2)':x=0:y=0:w=iw:h=ih:color=black:"
                            "t=fill", "-c:v", "libx264"], ".mp4"),
    ("audio only", ["-vn", "-c:a", "aac"], ".m4a"),
)


def make_inputs(data: Path, folder: Path) -> list[tuple[str, Path]]:
    """The :data:`VARIANTS` of ``driving_d6``'s first seconds in ``folder``."""
    from facetransfer.io.video import ffmpeg_exe

    src = data / "video" / "driving_d6.mp4"
    made = []
    for k, (name, args, suffix) in enumerate(VARIANTS):
        out = folder / f"in{k}{suffix}"
        subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-i", str(src), "-t", str(SECONDS),
                        *args, str(out)], check=True, capture_output=True)
        made.append((name, out))
    return made


def run_transfer(target: Path, source: Path, out: Path) -> dict:
    """``facetransfer transfer`` in a fresh process: status, stderr's lines, seconds."""
    t = time.perf_counter()
    res = subprocess.run([facetransfer_exe(), "transfer", "--target", str(target),
                          "--expression-from", str(source), "--out", str(out), "--max-frames",
                          str(FRAMES), "--overwrite", "--no-progress"],
                         capture_output=True, text=True)
    err = [ln for ln in res.stderr.splitlines() if ln.strip()]
    return {"status": res.returncode, "stderr": err, "stdout": res.stdout.strip(),
            "seconds": round(time.perf_counter() - t, 2)}


def judge(run: dict, target: Path, out: Path) -> dict:
    """:func:`run_transfer`'s outcome judged (module notes), with the result's size."""
    from facetransfer.io.video import video_info

    run = dict(run)
    if run["status"] == 2:
        ok = len(run["stderr"]) == 1 and run["stderr"][0].startswith("facetransfer transfer: "
                                                                      "error: ")
        return run | {"ok": ok and "Traceback" not in " ".join(run["stderr"])}
    if run["status"] != 0:
        return run | {"ok": False}
    from facetransfer.io.video import read_video
    from facetransfer.monochrome import is_monochrome

    want, got = video_info(target).size, video_info(out).size
    grown = tuple(v + v % 2 for v in want)
    said = any("odd size" in ln for ln in run["stderr"])
    mono = is_monochrome(read_video(target)[0])
    run |= {"size": list(got), "target_size": list(want), "target_monochrome": mono}
    if mono:
        run["result_monochrome"] = is_monochrome(read_video(out)[0])
    run["ok"] = (tuple(got) == tuple(want) or (tuple(got) == grown and said)) and \
        run.get("result_monochrome", True)
    return run


def late_frame(path: Path) -> np.ndarray | None:
    from facetransfer.io.video import read_video

    try:
        frames = read_video(path)[0]
    except Exception:  # noqa: BLE001 - an unreadable result shows as a blank cell
        return None
    return frames[(3 * len(frames)) // 4]


def _plot(rows: list[dict], pictures: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(rows), figsize=(1.6 * len(rows), 3.8))
    for j, row in enumerate(rows):
        for i, role in enumerate(("as_target", "as_source")):
            ax = axes[i, j]
            ax.axis("off")
            img = pictures.get((row["input"], role))
            r = row[role]
            if img is not None:
                ax.imshow(img)
            else:
                ax.text(0.5, 0.5, f"status {r['status']}", ha="center", va="center", fontsize=7)
            verdict = "ok" if r["ok"] else "NOT OK"
            ax.set_title(f"{row['input']}\n{role.replace('_', ' ')}: {verdict}" if i == 0 else
                         f"{role.replace('_', ' ')}: {verdict}", fontsize=6)
    fig.suptitle("facetransfer transfer on unusual inputs (each result at 3/4 of its length)",
                 fontsize=9)
    save_plot(fig, path)


def main() -> int:
    out, data = out_and_data(__doc__)
    other = data / "video" / "WDA_KatieHill_000.mp4"
    rows, pictures = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for k, (name, path) in enumerate(make_inputs(data, folder)):
            row = {"input": name, "file": path.name}
            for role, (target, source) in (("as_target", (path, other)),
                                           ("as_source", (other, path))):
                res = folder / f"r{k}_{role}.mp4"
                row[role] = judge(run_transfer(target, source, res), target, res)
                if row[role]["status"] == 0:
                    pictures[(name, role)] = late_frame(res)
                print(f"{name:22s} {role:9s} status {row[role]['status']} "
                      f"{'ok' if row[role]['ok'] else 'NOT OK'} "
                      f"{(row[role]['stderr'] or [''])[-1][:100]}")
            rows.append(row)
    report = {"benchmark": "unusual inputs", "seconds_of_source": SECONDS, "frames": FRAMES,
              "rows": rows,
              "all_ok": all(r[k]["ok"] for r in rows for k in ("as_target", "as_source"))}
    save_json(report, out / "inputs.json")
    _plot(rows, pictures, out / "inputs.png")
    print(f"all ok: {report['all_ok']}; wrote {out / 'inputs.json'} and {out / 'inputs.png'}")
    return 0 if report["all_ok"] else 1


if __name__ == "__main__":
    sys.exit(main())

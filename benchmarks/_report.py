"""What every benchmark script does around its measurements: its command line (``--out``),
the ``facetransfer`` command it times and the CPU its child processes took, and writing its
JSON and its plot."""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path


def arguments(doc: str) -> argparse.ArgumentParser:
    """A parser described by the first line of the script's docstring, with ``--out``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    return ap


def out_and_data(doc: str) -> tuple[Path, Path]:
    """``(--out, created; the asset mirror)`` of a script run on the data folder's clips (its
    ``FACETRANSFER_DATA_DIR``), its command line described by ``doc``."""
    from facetransfer.assets import data_dir

    out = Path(arguments(doc).parse_args().out)
    out.mkdir(parents=True, exist_ok=True)
    root = data_dir()
    if root is None:
        raise SystemExit("set FACETRANSFER_DATA_DIR to the asset mirror (its video/ clips)")
    return out, Path(root)


def save_json(report: dict, path: Path) -> None:
    """Write ``report`` to ``path`` as indented JSON, atomically."""
    import json

    from facetransfer.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(report, indent=1))


def save_sheet(rows: list, labels: list, path: Path) -> None:
    """Write ``rows`` (each ``(h, W, 3)`` uint8 RGB, all of one width) one under another as an
    image at ``path`` (atomically), each with its text of ``labels`` at its top left (drawn on
    the rows)."""
    import cv2
    import numpy as np

    from facetransfer.io.atomic import atomic_path

    for row, text in zip(rows, labels):
        cv2.putText(row, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1)
    with atomic_path(path, overwrite=True) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(np.concatenate(rows), cv2.COLOR_RGB2BGR))


def save_plot(fig, path: Path) -> None:
    """Lay ``fig`` out, write it to ``path`` atomically and close it."""
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def clip_benchmark(doc: str, stem: str, clips, clip_rows, plot, **extra) -> None:
    """The main of a benchmark over real clips of the data folder: ``--out`` and ``--frames``
    (default 150) parsed, ``clip_rows(video, model, frames)`` run for each of ``clips`` with
    the default model, ``OUT/<stem>.json`` (with ``extra``) and ``OUT/<stem>.png``
    (``plot(report, path)``) written."""
    ap = arguments(doc)
    ap.add_argument("--frames", type=int, default=150)
    args = ap.parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model

    model = load_default_model()
    video = Path(data_dir()) / "video"
    report = {"frames": args.frames, **extra,
              "clips": {c: clip_rows(video / f"{c}.mp4", model, args.frames) for c in clips}}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    save_json(report, out / f"{stem}.json")
    plot(report, out / f"{stem}.png")
    print(f"wrote {out / f'{stem}.json'} and {out / f'{stem}.png'}")


def facetransfer_exe() -> str:
    """The console script of the running environment."""
    return str(Path(sys.executable).parent / "facetransfer")


def children_cpu() -> float:
    """CPU seconds (user + system) of every finished child process and its own children."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def clip_start(video: Path, seconds: float, folder: Path):
    """``(path, frames)``: the first ``seconds`` of ``video`` copied losslessly in RGB (FFV1) to
    ``folder``, and that copy's frames as the tools read them (the truth a plate is made of)."""
    import subprocess

    from facetransfer.io.ffmpeg import ffmpeg_exe
    from facetransfer.io.video import read_video

    clip = Path(folder) / "clip.mkv"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-i", str(video), "-t", str(seconds),
                    "-c:v", "ffv1", "-pix_fmt", "rgb24", str(clip)], check=True)
    return clip, read_video(clip)[0]

"""OpenEXR plates: a transfer onto a scene-linear plate, against the same frames as a video and
as a PNG plate, and what of the plate's floats the rewrite keeps.

Issue 13's 10-second pair (``driving_d9`` with the expressions of ``driving_d6``, 300 frames,
default model, the track cache off): the target given as its H.264 video, as a PNG plate of its
decoded frames, and as a half-float OpenEXR plate of the same frames decoded to linear light
with the top and bottom tenth of the frame made three times brighter (values up to 3: a
window, a lamp), the PNG plate holding what the EXR plate shows (its frames through the sRGB
curve), each written as its own kind (MP4, PNG, EXR). Measured: wall and CPU seconds
of each ``facetransfer transfer``, reading the 300 frames, and of the EXR result: the share of
pixels the rewrite left unchanged, whether each of them is the plate's float to the bit, the
brightest value kept, and the result shown through the sRGB curve against the PNG plate's
result (the same 8-bit rewrite). No peer writes OpenEXR here: the PNG plate and the video are
the comparison.

    python benchmarks/bench_exr.py --out out/benchmarks

Writes ``OUT/exr.json`` and ``OUT/exr.png``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["FACETRANSFER_TRACK_CACHE"] = "off"
os.environ["FACETRANSFER_SEQUENCE_FPS"] = "30"   # the video's rate, for the plates

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import arguments, children_cpu, facetransfer_exe, save_json, save_plot  # noqa: E402

TARGET, SOURCE, FRAMES = "driving_d9.mp4", "driving_d6.mp4", 300


def _plates(frames, folder: Path):
    """A half-float EXR plate of the frames (bright bands) from 1001, and a PNG plate of what
    it shows (the EXR plate through the sRGB curve: the frames the tracker and the rewrite see
    in both); ``(patterns, shown frames)``."""
    import cv2

    from facetransfer.io.exr import srgb_decode, srgb_encode, write_exr

    (folder / "png").mkdir(parents=True)
    (folder / "exr").mkdir()
    band = max(1, frames.shape[1] // 10)
    shown = np.empty_like(frames)
    for i, rgb in enumerate(frames):
        lin = srgb_decode(rgb)
        lin[:band] *= 3.0
        lin[-band:] *= 3.0
        lin = lin.astype(np.float16)
        write_exr(folder / "exr" / f"sh.{1001 + i:04d}.exr", lin)
        shown[i] = srgb_encode(lin)
        cv2.imwrite(str(folder / "png" / f"sh.{1001 + i:04d}.png"), shown[i][..., ::-1])
    return {"png": folder / "png" / "sh.####.png", "exr": folder / "exr" / "sh.####.exr"}, shown


def _transfer(target, source, out: Path) -> dict:
    t, c = time.perf_counter(), children_cpu()
    subprocess.run([facetransfer_exe(), "transfer", "--target", str(target),
                    "--expression-from", str(source), "--out", str(out), "--max-frames",
                    str(FRAMES), "--overwrite", "--no-progress"], check=True, capture_output=True)
    return {"wall": round(time.perf_counter() - t, 2), "cpu": round(children_cpu() - c, 1)}


def _read_seconds(path) -> float:
    from facetransfer.io.video import read_video

    t = time.perf_counter()
    read_video(path, max_frames=FRAMES)
    return round(time.perf_counter() - t, 2)


def _kept(folder: Path, png_out: Path, frames) -> dict:
    """What of the EXR plate's floats the EXR result keeps, and its 8-bit look against the
    PNG plate's result."""
    import cv2

    from facetransfer.io.exr import read_exr, srgb_encode

    unchanged = exact = 0
    brightest, off = 0.0, []
    for i in range(len(frames)):
        plate = read_exr(folder / "exr" / f"sh.{1001 + i:04d}.exr")
        out = read_exr(folder / "out_exr" / f"ft.{1001 + i:04d}.exr")
        png = cv2.imread(str(png_out.parent / f"ft.{1001 + i:04d}.png"))[..., ::-1]
        same = np.all(png == frames[i], axis=2)      # where the 8-bit rewrite changed nothing
        unchanged += int(same.sum())
        exact += int(np.all(out[same] == plate[same], axis=1).sum())
        brightest = max(brightest, float(out.max()))
        off.append(np.abs(srgb_encode(out).astype(int) - png.astype(int))[~same].max()
                   if (~same).any() else 0)
    n = len(frames) * frames.shape[1] * frames.shape[2]
    return {"unchanged_share": round(unchanged / n, 4), "unchanged_exact_share":
            round(exact / max(unchanged, 1), 6), "brightest_kept": brightest,
            "changed_max_levels_from_png_result": int(max(off))}


def plot(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    kinds = ["video", "png", "exr"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.bar(kinds, [report["transfer"][k]["wall"] for k in kinds], color="tab:blue",
           label="transfer, wall s")
    ax.bar(kinds, [report["read_seconds"][k] for k in kinds], color="tab:orange",
           label="reading 300 frames, s")
    ax.set_title(f"OpenEXR plate: {100 * report['kept']['unchanged_exact_share']:.2f} % of "
                 "unchanged pixels exact", fontsize=9)
    ax.legend(fontsize=8)
    save_plot(fig, path)


def main() -> int:
    args = arguments(__doc__).parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.io.video import read_video

    video = Path(data_dir()) / "video"
    frames, _ = read_video(video / TARGET, max_frames=FRAMES)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        plates, shown = _plates(frames, folder)
        plates["video"] = video / TARGET
        outs = {"video": folder / "ft.mp4", "png": folder / "out_png" / "ft.%04d.png",
                "exr": folder / "out_exr" / "ft.%04d.exr"}
        for k in ("out_png", "out_exr"):
            (folder / k).mkdir()
        report = {"frames": FRAMES, "target": TARGET, "source": SOURCE,
                  "read_seconds": {k: _read_seconds(plates[k]) for k in ("video", "png",
                                                                         "exr")},
                  "transfer": {k: _transfer(plates[k], video / SOURCE, outs[k])
                               for k in ("video", "png", "exr")}}
        # the PNG plate holds what the EXR plate shows: the same rewrite in 8 bits
        report["kept"] = _kept(folder, outs["png"], shown)
    print(report)
    save_json(report, out / "exr.json")
    plot(report, out / "exr.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

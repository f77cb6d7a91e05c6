"""A DPX plate through ``facetransfer transfer`` (facetransfer.io.dpx).

The first three seconds of ``driving_d6`` (the expressions of ``WDA_KatieHill_000``) as the
plates a film scan and a grade hand over: 10-bit DPX of Cineon log (printing density) and of
video codes (ITU-R 709; full range, and video levels: black 64, white 940), each frame's levels
encoded with a smooth detail below an 8-bit level of its own (a blurred noise field of up to 2
codes), RGBA, a timecode per frame, written by OpenImageIO; and the 10-bit video plate as
ffmpeg writes it (another writer's header). Each is rewritten as a DPX sequence and as a PNG
sequence in a fresh process. Judged against the plate: the share of all pixels whose codes are
the plate's to the bit (alpha included), the largest difference in codes outside the rewritten
face (the pixels whose shown level the rewrite left as it was), how far the changed pixels are
shown from the 8-bit rewrite (the PNG sequence), whether the timecode and transfer are the
plate's; with the command's seconds, and the same clip as a PNG plate for the speed.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_dpx.py --out out/benchmarks

Writes ``OUT/dpx.json`` and ``OUT/dpx.png``.
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

from _report import (clip_start, facetransfer_exe, out_and_data, save_json,  # noqa: E402
                     save_plot)

SECONDS = 3
BLACK, WHITE = 95, 685   # Kodak's Cineon conventions (10-bit codes)


def _log_codes(light: np.ndarray) -> np.ndarray:
    b = 10 ** ((BLACK - WHITE) * 0.002 / 0.6)
    return WHITE + 300 * np.log10(np.clip(light, 0, None) * (1 - b) + b)


def make_plates(data: Path, folder: Path) -> tuple[dict, list]:
    """The clip's frames (lossless) and its DPX and PNG plates (module notes)."""
    import cv2
    import OpenImageIO as oiio

    from facetransfer.io.dpx import DpxImage, write_dpx
    from facetransfer.io.exr import srgb_decode
    from facetransfer.io.ffmpeg import ffmpeg_exe

    clip, frames = clip_start(data / "video" / "driving_d6.mp4", SECONDS, folder)
    rng = np.random.default_rng(0)
    paths = {}
    for kind, transfer in (("log", "Printing density"), ("video", "ITU-R 709-4"),
                           ("video levels", "ITU-R 709-4")):
        d = folder / f"plate_{kind.replace(' ', '_')}"
        d.mkdir()
        for i, rgb in enumerate(frames):
            fine = cv2.GaussianBlur(rng.normal(0, 1, rgb.shape).astype(np.float32), (0, 0), 4)
            fine = fine / (np.abs(fine).max() + 1e-9) * 2.0
            c = _log_codes(srgb_decode(rgb).astype(np.float64)) if kind == "log" \
                else rgb / 255.0 * 876 + 64 if kind == "video levels" else rgb / 255.0 * 1023
            codes = np.clip(np.rint(c + fine), 0, 1023).astype(np.uint16)
            alpha = np.full(rgb.shape[:2] + (1,), 1023 - i, np.uint16)
            spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 4, "uint16")
            spec.attribute("dpx:Transfer", transfer)
            if kind == "video levels":       # black at code 64, white at 940
                spec.attribute("dpx:LowData", 64)
                spec.attribute("dpx:HighData", 940)
            spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"),
                           np.array([0x01000000 + _bcd(i), 0], np.uint32))
            write_dpx(d / f"p.{1001 + i:04d}.dpx",
                      DpxImage(np.concatenate([codes, alpha], 2), 10, transfer, spec))
        paths[f"10-bit {kind}, RGBA"] = d / "p.%04d.dpx"
    (folder / "plate_ffmpeg").mkdir()
    subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(clip), "-pix_fmt", "gbrp10le",
                    "-start_number", "1001", str(folder / "plate_ffmpeg" / "p.%04d.dpx")],
                   check=True)
    paths["10-bit video, ffmpeg's"] = folder / "plate_ffmpeg" / "p.%04d.dpx"
    (folder / "plate_png").mkdir()
    for i, rgb in enumerate(frames):
        cv2.imwrite(str(folder / "plate_png" / f"p.{1001 + i:04d}.png"), rgb[..., ::-1])
    paths["8-bit PNG (speed only)"] = folder / "plate_png" / "p.%04d.png"
    return paths, frames


def _bcd(n: int) -> int:
    """Frame ``n`` of the first second as SMPTE's BCD frames field."""
    return (n // 10) << 4 | n % 10


def judge(plate: Path, out: Path, png: Path, n: int, first: int = 1001) -> dict:
    """The rewrite ``out`` (DPX) against ``plate`` and the 8-bit rewrite ``png``."""
    from facetransfer.io.dpx import read_dpx_image, shown_dpx

    same = total = worst = changed = within = exact = 0
    kept_header = True
    for i in range(n):
        name = lambda p: str(p).replace("%04d", f"{first + i:04d}")  # noqa: E731
        p, g = read_dpx_image(name(plate)), read_dpx_image(name(out))
        rewritten = np.asarray(__import__("PIL.Image").Image.open(name(png)).convert("RGB"))
        kept = np.all(rewritten == shown_dpx(p), axis=2)
        same += int(np.all(g.codes == p.codes, axis=2).sum())
        total += kept.size
        worst = max(worst, int(np.abs(g.codes.astype(int) - p.codes)[kept].max()))
        diff = np.abs(shown_dpx(g).astype(int) - rewritten)[~kept]
        changed += diff.size
        within += int((diff <= 1).sum())
        exact += int((diff == 0).sum())
        kept_header &= (g.transfer, g.bits) == (p.transfer, p.bits) and \
            g.spec.get_string_attribute("dpx:TimeCode") == \
            p.spec.get_string_attribute("dpx:TimeCode")
    return {"pixels_exact_share": round(same / total, 4),
            "largest_code_difference_outside_face": worst,
            "changed_samples_shown_as_rewritten": round(exact / max(changed, 1), 4),
            "changed_samples_within_a_level": round(within / max(changed, 1), 4),
            "header_kept": bool(kept_header)}


def _transfer(plate: Path, source: Path, out: Path) -> tuple[int, float, str]:
    out.parent.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    run = subprocess.run([facetransfer_exe(), "transfer", "--target", str(plate),
                          "--expression-from", str(source), "--out", str(out), "--no-progress",
                          "--sequence-fps", "30"], capture_output=True, text=True)
    return run.returncode, round(time.perf_counter() - t, 2), run.stderr.strip()[-300:]


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    rows = [r for r in rows if "pixels_exact_share" in r]
    fig, (a, b) = plt.subplots(1, 2, figsize=(7.4, 2.9))
    names = [r["plate"].replace(", ", ",\n") for r in rows]
    a.bar_label(a.bar(names, [100 * r["pixels_exact_share"] for r in rows]), fmt="%.1f",
                fontsize=7)
    a.set_ylabel("pixels equal to the plate's, %")
    shown = [100 * r["changed_samples_shown_as_rewritten"] for r in rows]
    b.bar_label(b.bar(names, shown), fmt="%.1f", fontsize=7)
    b.set_ylabel("changed samples shown\nas the 8-bit rewrite, %")
    for ax in (a, b):
        ax.tick_params(axis="x", labelsize=7)
    fig.suptitle("a DPX plate through transfer, rewritten as DPX", fontsize=9)
    save_plot(fig, path)


def main() -> int:
    out, data = out_and_data(__doc__)
    source = data / "video" / "WDA_KatieHill_000.mp4"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths, frames = make_plates(data, folder)
        for name, plate in paths.items():
            suffix = plate.suffix
            res, png = folder / name / f"r.%04d{suffix}", folder / name / "png" / "r.%04d.png"
            status, seconds, err = _transfer(plate, source, res)
            row = {"plate": name, "status": status, "seconds": seconds}
            if status == 0 and suffix == ".dpx":
                status, row["seconds_png_out"], err = _transfer(plate, source, png)
                row |= judge(plate, res, png, len(frames)) if status == 0 else {"error": err}
            elif status:
                row["error"] = err
            rows.append(row)
            print(row, flush=True)
    dpx = [r for r in rows if "pixels_exact_share" in r]
    ok = len(dpx) == 4 and all(r["largest_code_difference_outside_face"] == 0 and
                               r["header_kept"] for r in dpx)
    save_json({"benchmark": "a DPX plate through transfer", "seconds_of_clip": SECONDS,
               "rows": rows, "all_ok": ok}, out / "dpx.json")
    plot(rows, out / "dpx.png")
    print(f"all ok: {ok}; wrote {out / 'dpx.json'} and {out / 'dpx.png'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

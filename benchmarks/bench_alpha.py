"""A target's alpha channel through ``facetransfer transfer`` (facetransfer.io.plate_alpha).

The first three seconds of ``driving_d6`` (the expressions of ``WDA_KatieHill_000``) with a
soft matte of its own, as a keyer leaves one: an ellipse around the head, opaque inside,
fading over 40 pixels, drifting a pixel a frame, in 10 bits. Written as the forms footage with
alpha arrives in, each rewritten by ``facetransfer transfer`` in a fresh process:

* ProRes 4444 written with ``--codec prores`` (ProRes 4444 with the alpha) and as an RGBA PNG
  sequence; and with the default H.264 (colour only, one warning);
* an RGBA PNG plate written as a PNG sequence, an RGBA TIFF plate (straight alpha, as Pillow
  writes it) as a TIFF sequence;
* the same frames opaque (ProRes 422 HQ, PNG and TIFF plates without alpha) as the reference
  for the colour and the time.

Judged: every result frame's alpha against the target's as the target file holds it (rounded
to 8 bits: pixels that differ), the colour against the opaque target's rewrite (PSNR over the frame), the warnings,
and the command's seconds. A picture: a late frame of each result over a checkerboard.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_alpha.py --out out/benchmarks

Writes ``OUT/alpha.json`` and ``OUT/alpha.png``.
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


def _ffmpeg() -> str:
    from facetransfer.io.ffmpeg import ffmpeg_exe

    return ffmpeg_exe()


def matte(F: int, H: int, W: int) -> np.ndarray:
    """(F, H, W) uint16: an ellipse around the head, opaque inside, fading over 40 pixels,
    drifting a pixel a frame, in 10 bits scaled to 16."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    out = np.empty((F, H, W), np.uint16)
    for i in range(F):
        r = np.hypot((x - W / 2 - i + F / 2) / (0.36 * W), (y - H * 0.45) / (0.48 * H))
        a = np.clip((1.0 - r) * (0.4 * W) / 40.0, 0.0, 1.0)
        out[i] = (np.rint(a * 1023) * 64).astype(np.uint16)
    return out


def make_targets(data: Path, folder: Path) -> dict:
    """The clip's frames with the matte: ProRes 4444, an RGBA PNG plate; opaque: ProRes 422 HQ,
    a PNG plate. Returns the paths, the frames and the matte in 8 bits."""
    import cv2

    from facetransfer.io.video import read_video

    clip = folder / "clip.mp4"
    subprocess.run([_ffmpeg(), "-v", "error", "-y", "-i", str(data / "video" / "driving_d6.mp4"),
                    "-t", str(SECONDS), "-c:v", "libx264", "-crf", "0", str(clip)], check=True)
    frames = read_video(clip)[0]
    F, H, W, _ = frames.shape
    a16 = matte(F, H, W)
    rgba64 = np.concatenate([frames.astype(np.uint16) * 257, a16[..., None]], axis=3)
    paths = {}
    for name, alpha in (("prores_4444.mov", True), ("prores_422.mov", False)):
        fmt = ["-profile:v", "4", "-pix_fmt", "yuva444p10le", "-alpha_bits", "16"] if alpha \
            else ["-profile:v", "3", "-pix_fmt", "yuv422p10le"]
        subprocess.run([_ffmpeg(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgba64le",
                        "-s", f"{W}x{H}", "-r", "30", "-i", "-", "-c:v", "prores_ks", *fmt,
                        str(folder / name)], input=rgba64.tobytes(), check=True)
        paths[name] = folder / name
    a8 = ((a16.astype(np.uint32) + 128) // 257).astype(np.uint8)
    # what the ProRes file holds (its alpha coded in 10 bits) is the video targets' reference
    stored = video_alpha(paths["prores_4444.mov"], (W, H))
    from PIL import Image

    for name, alpha in (("rgba", True), ("rgb", False), ("rgba_tif", True), ("rgb_tif", False)):
        (folder / name).mkdir()
        suffix = ".tif" if name.endswith("_tif") else ".png"
        for i in range(F):   # a TIFF as Pillow writes it: straight (unassociated) alpha
            img = np.dstack([frames[i], a8[i]]) if alpha else frames[i]
            if suffix == ".tif":
                Image.fromarray(img).save(folder / name / f"p.{1001 + i:04d}{suffix}")
            else:
                cv2.imwrite(str(folder / name / f"p.{1001 + i:04d}{suffix}"),
                            cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if alpha else
                                         cv2.COLOR_RGB2BGR))
        paths[name] = folder / name / f"p.%04d{suffix}"
    return {"paths": paths, "frames": frames,
            "alpha": {"prores_4444.mov": stored, "rgba": a8, "rgba_tif": a8}}


def video_alpha(path: Path, size: tuple[int, int]) -> np.ndarray | None:
    """(F, H, W) uint8 alpha planes of a video (16 bits rounded), None without alpha (ffmpeg's
    ``alphaextract`` fails on a stream without one)."""
    W, H = size
    res = subprocess.run([_ffmpeg(), "-v", "error", "-i", str(path), "-vf", "alphaextract", "-f",
                          "rawvideo", "-pix_fmt", "gray16le", "-"], capture_output=True)
    raw = res.stdout
    if res.returncode != 0 or not raw:
        return None
    a16 = np.frombuffer(raw, "<u2").reshape(-1, H, W).astype(np.uint32)
    return ((a16 + 128) // 257).astype(np.uint8)


def read_result(out: Path, size: tuple[int, int]):
    """(colour (F, H, W, 3) uint8, alpha (F, H, W) uint8 or None) of a result."""
    from facetransfer.io.video import read_video

    if "%" not in out.name:
        return read_video(out)[0], video_alpha(out, size)
    from PIL import Image

    files = sorted(out.parent.glob(out.name.split("%")[0] + "*" + out.suffix))
    imgs = []
    for f in files:    # as stored (OpenCV premultiplies a straight TIFF's colour)
        if f.suffix.lower() == ".png":   # 16-bit ones too (of a deep target), rounded
            imgs.append(_png_rgba8(f))
            continue
        with Image.open(f) as im:
            imgs.append(np.asarray(im))
    rgb = np.stack([im[..., :3] for im in imgs])
    alpha = np.stack([im[..., 3] for im in imgs]) if imgs[0].shape[2] == 4 else None
    return rgb, alpha


def _png_rgba8(path: Path) -> np.ndarray:
    """A PNG's RGB(A) in 8 bits (a 16-bit one's values rounded, ``(v + 128) // 257``)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    return img


def run(target: Path, source: Path, out: Path, extra=()) -> dict:
    out.parent.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    res = subprocess.run([facetransfer_exe(), "transfer", "--target", str(target),
                          "--expression-from", str(source), "--out", str(out), "--overwrite",
                          "--no-progress", "--sequence-fps", "30", *extra],
                         capture_output=True, text=True)
    return {"status": res.returncode, "seconds": round(time.perf_counter() - t, 2),
            "warnings": [ln for ln in res.stderr.splitlines() if "alpha" in ln]}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


#: name, target, output, extra arguments, the opaque run whose colour it is compared with
CASES = (("ProRes 4444 -> ProRes", "prores_4444.mov", "r_4444.mov", ("--codec", "prores"),
          "opaque ProRes -> ProRes"),
         ("ProRes 4444 -> PNG sequence", "prores_4444.mov", "png_v/r.%04d.png", (),
          "opaque ProRes -> PNG sequence"),
         ("ProRes 4444 -> H.264", "prores_4444.mov", "r_4444.mp4", (), None),
         ("RGBA PNG plate -> PNG sequence", "rgba", "png_p/r.%04d.png", (),
          "opaque PNG plate -> PNG sequence"),
         ("RGBA TIFF plate -> TIFF sequence", "rgba_tif", "tif_p/r.%04d.tif", (),
          "opaque TIFF plate -> TIFF sequence"),
         ("opaque ProRes -> ProRes", "prores_422.mov", "r_422.mov", ("--codec", "prores"), None),
         ("opaque ProRes -> PNG sequence", "prores_422.mov", "png_o/r.%04d.png", (), None),
         ("opaque PNG plate -> PNG sequence", "rgb", "png_q/r.%04d.png", (), None),
         ("opaque TIFF plate -> TIFF sequence", "rgb_tif", "tif_q/r.%04d.tif", (), None))


def _plot(rows: list[dict], pictures: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(pictures), figsize=(2.4 * len(pictures), 2.9))
    for ax, (name, img) in zip(np.atleast_1d(axes), pictures.items()):
        ax.imshow(img)
        ax.axis("off")
        row = next(r for r in rows if r["case"] == name)
        kept = row.get("alpha_pixels_differing")
        ax.set_title(f"{name}\n" + ("alpha: none" if kept is None else
                                   f"alpha: {kept} px differ"), fontsize=7)
    fig.suptitle("a target's alpha through transfer (a late frame over a checkerboard)",
                 fontsize=9)
    save_plot(fig, path)


def _over_checkers(rgb: np.ndarray, alpha: np.ndarray | None) -> np.ndarray:
    H, W = rgb.shape[:2]
    y, x = np.mgrid[0:H, 0:W]
    board = np.where(((x // 16 + y // 16) % 2)[..., None] == 0, 200, 120).astype(np.float64)
    a = np.ones((H, W, 1)) if alpha is None else alpha[..., None] / 255.0
    return np.clip(rgb * a + board * (1 - a), 0, 255).astype(np.uint8)


def main() -> int:
    out, data = out_and_data(__doc__)
    source = data / "video" / "WDA_KatieHill_000.mp4"
    rows, results, pictures = [], {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        made = make_targets(data, folder)
        F, H, W, _ = made["frames"].shape
        for name, target, result, extra, _ in reversed(CASES):  # the opaque references first
            res = folder / result
            row = {"case": name} | run(made["paths"][target], source, res, extra)
            if row["status"] == 0:
                rgb, alpha = read_result(res, (W, H))
                results[name] = rgb
                row["frames"] = len(rgb)
                if alpha is not None:
                    want = made["alpha"][target][:len(alpha)]
                    row["alpha_pixels_differing"] = int((alpha != want).sum())
                pictures[name] = _over_checkers(rgb[(3 * len(rgb)) // 4], None if alpha is None
                                                else alpha[(3 * len(rgb)) // 4])
            rows.append(row)
            print(f"{name:34s} status {row['status']} {row['seconds']:6.2f} s  alpha differing: "
                  f"{row.get('alpha_pixels_differing', '-')}  warnings: {len(row['warnings'])}",
                  flush=True)
        for row, (name, _, _, _, ref) in zip(reversed(rows), CASES):
            if ref and name in results and ref in results:
                row["colour_psnr_db_vs_opaque"] = round(float(psnr(results[name],
                                                                   results[ref])), 2)
    rows = rows[::-1]
    keeps = {name for name, _, _, _, ref in CASES if ref}   # these must carry the alpha
    ok = all(r["status"] == 0 for r in rows) and all(
        r.get("alpha_pixels_differing") == 0 and not r["warnings"]
        for r in rows if r["case"] in keeps) and \
        len(next(r for r in rows if r["case"] == "ProRes 4444 -> H.264")["warnings"]) == 1
    report = {"benchmark": "a target's alpha through transfer", "seconds_of_clip": SECONDS,
              "rows": rows, "all_ok": ok}
    save_json(report, out / "alpha.json")
    _plot(rows, {k: v for k, v in pictures.items() if not k.startswith("opaque")},
          out / "alpha.png")
    for r in rows:
        print(r)
    print(f"all ok: {ok}; wrote {out / 'alpha.json'} and {out / 'alpha.png'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

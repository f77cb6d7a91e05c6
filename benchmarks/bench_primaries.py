"""OpenEXR plates in ACES primaries through ``facetransfer`` (facetransfer.io.primaries).

The first four seconds of ``WDA_KatieHill_000`` (25 fps) as the OpenEXR plates an ACES pipeline
hands over: half floats in ACEScg (AP1, named by ``colorInteropID``) and in ACES2065-1 (AP0,
named by ``chromaticities``), their values OpenColorIO's (OpenImageIO's built-in ACES
configuration) of the frames' linear Rec.709; the frames as a lossless video, the reference;
and as half floats in linear Rec.709 (no primaries named), the floor: what half floats alone
cost against the video.
Run by this tree and by the revision before (``--before``, default ``a1daf76``: every plate
taken as Rec.709), in fresh processes:

- ``track`` of each plate against the track of the video (the same face): the 52 activations'
  mean absolute difference and the identity weights' RMS difference;
- ``transfer`` onto each plate with the expressions of ``driving_d6``, written as OpenEXR,
  against the same transfer onto the video written as PNG: each result brought to linear
  Rec.709 by OpenColorIO and through the sRGB curve, its PSNR against the PNG's over the pixels
  the rewrite changed and over the whole frame, and the share of all pixels that are the
  plate's floats to the bit.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_primaries.py --out out/benchmarks

Writes ``OUT/primaries.json`` and ``OUT/primaries.png``.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import save_json, save_plot  # noqa: E402
from _revision import now_and_before, run_command  # noqa: E402

SECONDS = 4
FPS = 25.0
PLATES = {"ACEScg": ("colorInteropID", "lin_ap1_scene"),
          "ACES2065-1": ("chromaticities", "lin_ap0_scene"),
          "Linear Rec.709 (sRGB)": (None, None)}     # the floor: half floats, no primaries


def _ocio(rgb: np.ndarray, source: str, target: str) -> np.ndarray:
    import OpenImageIO as oiio

    buf = oiio.ImageBufAlgo.colorconvert(oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32)),
                                         source, target, colorconfig="ocio://default")
    return buf.get_pixels(oiio.FLOAT)


def make_plates(clip: Path, folder: Path) -> tuple[dict, np.ndarray]:
    """The clip's first seconds as a lossless video and as the two ACES plates (module
    notes); and the frames."""
    import OpenEXR

    from facetransfer.io.exr import srgb_decode
    from facetransfer.io.video import VideoOptions, read_video, write_video

    frames = read_video(clip, max_frames=int(SECONDS * FPS))[0]
    paths = {"video": folder / "target.mkv"}
    write_video(paths["video"], frames, FPS, options=VideoOptions(crf=0))
    for name, (how, interop) in PLATES.items():
        d = folder / name.split()[-1].strip("()")
        d.mkdir()
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        if how is not None:
            header[how] = interop if how == "colorInteropID" else \
                OpenEXR.colorInteropIDToChromaticities(interop)
        for i, rgb in enumerate(frames):
            aces = _ocio(srgb_decode(rgb), "Linear Rec.709 (sRGB)", name)
            with OpenEXR.File(header, {"RGB": aces.astype(np.float16)}) as f:
                f.write(str(d / f"p.{1001 + i:04d}.exr"))
        paths[name] = d / "p.%04d.exr"
    return paths, frames


def capture_row(plate: Path, reference, src, folder: Path) -> dict:
    from facetransfer.track import Track

    out = folder / "t.npz"
    status, err = run_command(["track", plate, "--out", out, "--sequence-fps", FPS], src)
    if status:
        return {"error": err}
    got = Track.load(out)
    n = min(got.n_frames, reference.n_frames)
    ident = got.weights["identity"][0] - reference.weights["identity"][0]
    return {"activation_mae_vs_video": round(float(np.abs(
                got.blendshapes[:n] - reference.blendshapes[:n]).mean()), 4),
            "identity_rms_vs_video": round(float(np.sqrt(np.mean(ident ** 2))), 4)}


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return round(10 * np.log10(255.0 ** 2 / mse), 2) if mse > 0 else float("inf")


def transfer_row(name: str, plate: Path, source: Path, png: Path, frames, src,
                 folder: Path) -> dict:
    """The transfer onto ``plate`` against the one onto the video (``png``)."""
    from PIL import Image

    from facetransfer.io.exr import read_exr, srgb_encode

    out = folder / "r.%04d.exr"
    status, err = run_command(["transfer", "--target", plate, "--expression-from", source,
                               "--out", out, "--sequence-fps", FPS], src)
    if status:
        return {"error": err}
    changed, whole, errors, exact, total = [], [], [], 0, 0
    for i in range(len(frames)):
        got = read_exr(str(out) % (1001 + i))
        shown = srgb_encode(_ocio(got, name, "Linear Rec.709 (sRGB)"))
        want = np.asarray(Image.open(str(png) % i).convert("RGB"))
        moved = np.any(want != frames[i], axis=2)
        changed.append(_psnr(shown[moved], want[moved]))
        whole.append(_psnr(shown, want))
        errors.append(np.abs(shown[moved].astype(int) - want[moved]).max(axis=1))
        exact += int(np.all(got == read_exr(str(plate) % (1001 + i)), axis=2).sum())
        total += moved.size
    errors = np.concatenate(errors)
    return {"changed_psnr_db": round(float(np.median(changed)), 2),
            "frame_psnr_db": round(float(np.median(whole)), 2),
            "changed_p99_levels": int(np.percentile(errors, 99)),
            "changed_over_4_levels_share": round(float(np.mean(errors > 4)), 4),
            "pixels_plates_floats_share": round(exact / total, 4)}


def plot(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    rows = [r for r in report["rows"] if "changed_psnr_db" in r]
    short = {"ACEScg": "AP1", "ACES2065-1": "AP0", "Linear Rec.709 (sRGB)": "Rec.709"}
    fig, (a, b) = plt.subplots(1, 2, figsize=(8.4, 2.9))
    names = [f"{short.get(r['plate'], r['plate'])}\n{r['tree']}" for r in rows]
    a.bar_label(a.bar(names, [r["activation_mae_vs_video"] for r in rows]), fmt="%.4f",
                fontsize=7)
    a.set_ylabel("capture vs the video's: MAE", fontsize=8)
    b.bar_label(b.bar(names, [r["changed_psnr_db"] for r in rows]), fmt="%.1f", fontsize=7)
    b.set_ylabel("changed pixels vs video's: dB", fontsize=8)
    for ax in (a, b):
        ax.tick_params(labelsize=7)
    save_plot(fig, path)


def main() -> int:
    from facetransfer.assets import data_dir
    from facetransfer.track import Track

    out, trees, before = now_and_before(__doc__, "a1daf76")
    source = data_dir() / "video" / "driving_d6.mp4"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths, frames = make_plates(data_dir() / "video" / "WDA_KatieHill_000.mp4", folder)
        png = folder / "ref" / "r.%04d.png"
        png.parent.mkdir()
        for cmd in (["track", paths["video"], "--out", folder / "ref.npz"],
                    ["transfer", "--target", paths["video"], "--expression-from", source,
                     "--out", png]):
            status, err = run_command(cmd)
            assert status == 0, err
        reference = Track.load(folder / "ref.npz")
        for name in PLATES:
            for tree, src in trees.items() if PLATES[name][0] else [("now", None)]:
                work = folder / f"{name}_{tree}"
                work.mkdir()
                row = {"plate": name, "tree": tree,
                       **capture_row(paths[name], reference, src, work),
                       **transfer_row(name, paths[name], source, png, frames, src, work)}
                rows.append(row)
                print(row, flush=True)
    save_json({"benchmark": "OpenEXR plates in ACES primaries", "before": before,
               "rows": rows}, out / "primaries.json")
    plot({"rows": rows}, out / "primaries.png")
    print(f"wrote {out / 'primaries.json'} and {out / 'primaries.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

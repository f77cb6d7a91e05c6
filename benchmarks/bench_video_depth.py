"""A 10-bit video target through ``facetransfer transfer`` (facetransfer.io.video_depth).

The first three seconds of ``driving_d6`` (the expressions of ``WDA_KatieHill_000``) as a
10-bit video with detail below 8 bits, as a camera or a grade leaves one: each frame's levels
times 257 plus a smooth detail of its own (a blurred noise field, -128..128 in 16 bits),
encoded as ProRes 422 HQ, as 10-bit H.265 (4:2:0) and as a phone's HDR video (10-bit H.265,
BT.2020, HLG). Each is rewritten as ProRes (``--codec prores``), as H.265 (``--codec h265``)
and as a PNG sequence, in a fresh process (the track cache off), by this tree and, with
``--base-src OLD/src``, by another one in the same run. Judged against the target's own 16-bit
decode (ffmpeg, the same decoder for both): outside the face (the pixels this tree's PNG
output leaves at the target's value, grown by 3 pixels), the RMS and largest difference in
8-bit levels and the share of pixels equal to the target's to the bit; inside it, how far the
16-bit output read in 8 bits is from the 8-bit rewrite of the other tree (the two decoders'
rounding carried with the change); the output's bits and colour tags, whether the command
warned of HDR, and its seconds.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_video_depth.py --out out/benchmarks \
        [--base-src OLD/src]

Writes ``OUT/video_depth.json`` and ``OUT/video_depth.png``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import arguments, facetransfer_exe, save_json, save_plot  # noqa: E402

SECONDS = 3
TARGETS = {"prores422": ("mov", ["-c:v", "prores_ks", "-profile:v", "3",
                                 "-pix_fmt", "yuv422p10le"]),
           "hevc10": ("mp4", ["-c:v", "libx265", "-pix_fmt", "yuv420p10le", "-crf", "8",
                              "-x265-params", "log-level=error"]),
           "hlg10": ("mp4", ["-vf", "setparams=color_primaries=bt2020:color_trc=arib-std-b67:"
                             "colorspace=bt2020nc", "-c:v", "libx265", "-pix_fmt",
                             "yuv420p10le", "-colorspace", "bt2020nc", "-crf", "8",
                             "-x265-params", "log-level=error"])}
OUTPUTS = {"prores": ("r.mov", ["--codec", "prores"]), "h265": ("r.mp4", ["--codec", "h265"]),
           "png": ("png/r.%04d.png", [])}


def make_targets(data: Path, folder: Path) -> dict:
    """The 10-bit targets (module notes)."""
    import cv2

    from facetransfer.io.ffmpeg import ffmpeg_exe
    from facetransfer.io.video import read_video

    frames, fps = read_video(data / "video" / "driving_d6.mp4",
                             max_frames=int(SECONDS * 30))
    rng = np.random.default_rng(0)
    raw = bytearray()
    for rgb in frames:
        fine = cv2.GaussianBlur(rng.normal(0, 1, rgb.shape).astype(np.float32), (0, 0), 4)
        fine = np.clip(np.rint(fine / (np.abs(fine).max() + 1e-9) * 128), -128, 128)
        raw += np.clip(rgb.astype(np.int64) * 257 + fine.astype(np.int64), 0, 65535) \
            .astype("<u2").tobytes()
    h, w = frames.shape[1:3]
    paths = {}
    for name, (ext, codec) in TARGETS.items():
        paths[name] = folder / f"{name}.{ext}"
        subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt",
                        "rgb48le", "-s", f"{w}x{h}", "-framerate", str(fps), "-i", "-",
                        *codec, str(paths[name])], input=bytes(raw), check=True)
    return paths


def decode16(path: Path) -> np.ndarray:
    """``(F, H, W, 3) uint16``: a video's or a PNG sequence's frames in 16 bits (ffmpeg)."""
    import cv2

    from facetransfer.io.ffmpeg import ffmpeg_exe

    if "%" in path.name:
        files = sorted(path.parent.glob("*.png"))
        imgs = [cv2.imread(str(f), cv2.IMREAD_UNCHANGED)[..., ::-1] for f in files]
        return np.array([i.astype(np.uint16) * (257 if i.dtype == np.uint8 else 1)
                         for i in imgs])
    from facetransfer.io.video_read import video_info

    w, h = video_info(path).size
    raw = subprocess.run([ffmpeg_exe(), "-v", "error", "-i", str(path), "-map", "0:v:0",
                          "-f", "rawvideo", "-pix_fmt", "rgb48le", "-"],
                         capture_output=True, check=True).stdout
    return np.frombuffer(raw, "<u2").reshape(-1, h, w, 3)


def run(target: Path, out: Path, args: list, source: Path, src: str | None) -> dict:
    env = dict(os.environ, FACETRANSFER_TRACK_CACHE="off")   # each run tracks: fair seconds
    if src:
        env["PYTHONPATH"] = src
    out.parent.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    p = subprocess.run([facetransfer_exe(), "transfer", "--target", str(target),
                        "--expression-from", str(source), "--out", str(out), "--no-progress",
                        *args], capture_output=True, text=True, env=env)
    row = {"status": p.returncode, "seconds": round(time.perf_counter() - t, 2),
           "said": p.stdout.strip().splitlines()[-1:] or p.stderr.strip().splitlines()[-1:],
           "warned_hdr": "HDR" in p.stderr}
    if p.returncode == 0 and "%" not in out.name:
        from facetransfer.io.video_depth import video_bits
        from facetransfer.io.video_display import video_colour

        tags = video_colour(out)
        row |= {"bits": video_bits(out), "colour": f"{tags.matrix}/{tags.primaries}/"
                                                   f"{tags.transfer}"}
    return row


def judge(got: np.ndarray, truth: np.ndarray, face: np.ndarray,
          rewrite8: np.ndarray | None) -> dict:
    """Outside and inside the face (module notes), in 8-bit levels."""
    import cv2

    grown = np.array([cv2.dilate(f.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
                      for f in face])
    d = (got.astype(np.float64) - truth) / 257.0
    out = d[~grown]
    row = {"outside_rms_levels": round(float(np.sqrt((out ** 2).mean())), 3),
           "outside_max_levels": round(float(np.abs(out).max()), 3),
           "outside_exact_share": round(float((out == 0).all(axis=-1).mean()), 4)}
    if rewrite8 is not None:
        inside = (got.astype(np.float64) / 257.0 - rewrite8 / 257.0)[face]
        row["inside_vs_8bit_rewrite_mean_levels"] = round(float(np.abs(inside).mean()), 3)
    return row


def plot(rows: list[dict], path: Path) -> None:
    """Outside the face, RMS in 8-bit levels, each target and output, this tree beside the
    other (log scale: an HDR target written as SDR is tens of levels off)."""
    import matplotlib.pyplot as plt

    cases = list(dict.fromkeys((r["target"], r["output"]) for r in rows))
    trees = list(dict.fromkeys(r["tree"] for r in rows))
    fig, ax = plt.subplots(figsize=(1.0 + 0.9 * len(cases), 3.2))
    width = 0.8 / len(trees)
    for k, tree in enumerate(trees):
        got = {(r["target"], r["output"]): r.get("outside_rms_levels") for r in rows
               if r["tree"] == tree}
        xs = np.arange(len(cases)) + (k - (len(trees) - 1) / 2) * width
        vals = [max(got.get(c) or 0.0, 1e-3) for c in cases]
        ax.bar(xs, vals, width, label=tree)
        for x, c in zip(xs, cases):
            if got.get(c) == 0:
                ax.text(x, 1.5e-3, "0", ha="center", fontsize=7)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(cases)), [f"{t}\n-> {o}" for t, o in cases], fontsize=7)
    ax.set_ylabel("outside the face: RMS, 8-bit levels")
    ax.set_title("a deep video target through transfer, against its own 16-bit decode",
                 fontsize=9)
    ax.legend(fontsize=7)
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    ap.add_argument("--base-src", help="another tree's src folder, run beside this one")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.assets import data_dir

    data = Path(data_dir())
    source = data / "video" / "WDA_KatieHill_000.mp4"
    trees = {"this tree": None} | ({"base": args.base_src} if args.base_src else {})
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for tname, target in make_targets(data, folder).items():
            truth = decode16(target).astype(np.float64)
            results, face = {}, None
            for oname, (rel, extra) in OUTPUTS.items():
                for tree, src in trees.items():
                    res = folder / tname / oname / tree.replace(" ", "_") / rel
                    row = {"target": tname, "output": oname, "tree": tree,
                           **run(target, res, extra, source, src)}
                    if row["status"] == 0:
                        results[(oname, tree)] = decode16(res)
                    rows.append(row)
            png = results.get(("png", "this tree"))
            if png is not None:
                face = (png.astype(np.float64) != truth).any(axis=-1)
            for row in rows:
                key = (row["output"], row["tree"])
                if row["target"] == tname and key in results and face is not None:
                    other = results.get(("png", "base")) if row["tree"] == "this tree" \
                        and row["output"] == "png" else None
                    row |= judge(results[key], truth, face, other)
                    row["face_share"] = round(float(face.mean()), 4)
            for row in rows:
                if row["target"] == tname:
                    print(row, flush=True)
    ok = all(r["status"] == 0 for r in rows) and all(
        r.get("outside_exact_share") == 1.0 for r in rows
        if r["tree"] == "this tree" and r["output"] == "png")
    save_json({"benchmark": "a 10-bit video target through transfer",
               "seconds_of_clip": SECONDS, "rows": rows, "all_ok": ok}, out / "video_depth.json")
    plot(rows, out / "video_depth.png")
    print(f"all ok: {ok}; wrote {out / 'video_depth.json'} and {out / 'video_depth.png'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

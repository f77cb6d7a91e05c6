"""The mouth texture function's resolution on 512², 1080p and 4K targets: 256² vs "auto" (§6).

A performance's mouth (``--expression-from take.csv``, ``--performance``, ``edit``) is drawn from
the texture function lifted from the target's frames
(:func:`facetransfer.texture.face.mouth_texture_function`). This makes a 1080p and a 4K target
from ``WDA_KatieHill_000`` (scaled with Lanczos into 1080x1080 and 2160x2160, padded to 16:9, as
walk55b did) beside the 512² clip, tracks them, and for each builds the function twice: the old
whole UV atlas at 256² (float32) and ``tex_size="auto"`` (the mouth's UV square at ~1 texel per
screen pixel, float16, :class:`facetransfer.texture.face.MouthLayout`). Per build: the side,
the screen pixels one texel spans at the mouth, the frames lifted, the textures' bytes, the
traced peak of Python's allocations while lifting, the seconds; and how close the function's
texture, redrawn at every 4th frame's own attributes on that frame's mesh and camera, is to the
footage on the lips (PSNR, and the mean gradient magnitude as a share of the footage's).
``--frames-study``: on the 1080p clip, the texture at held-out frames' attributes (every 5th
frame left out of the lifting) against the footage, for 4..32 lifted frames (the paper's
nearest-neighbour function needs enough of them).

Usage::

    python benchmarks/bench_mouth_res.py --out out/bench_mouth [--frames 40] [--frames-4k 12]
        [--frames-study]

Writes ``OUT/mouth_res.json`` and ``OUT/mouth_res.png``; the clips and tracks in ``OUT/clips``
(reused).
"""

from __future__ import annotations

import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from _report import arguments, facetransfer_exe, save_json, save_plot  # benchmarks/ on sys.path

SCALES = {"512": None, "1080": "scale=1080:1080:flags=lanczos,pad=1920:1080:420:0,setsar=1",
          "4k": "scale=2160:2160:flags=lanczos,pad=3840:2160:840:0,setsar=1"}


def make_clip(folder: Path, name: str, n: int) -> tuple[Path, Path]:
    """``WDA_KatieHill_000``'s first ``n`` frames at size ``name`` and its track (made once)."""
    import imageio_ffmpeg

    from facetransfer.assets import data_dir

    video, track = folder / f"t{name}.mp4", folder / f"t{name}.npz"
    if not video.exists():
        vf = ["-vf", SCALES[name]] if SCALES[name] else []
        subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-i",
                        str(Path(data_dir()) / "video" / "WDA_KatieHill_000.mp4"),
                        "-frames:v", str(n), "-an", *vf, "-c:v", "libx264", "-crf", "14",
                        "-pix_fmt", "yuv420p", str(video)], check=True)
    if not track.exists():
        subprocess.run([*facetransfer_exe().split(), "track", str(video), "--out", str(track)],
                       check=True)
    return video, track


def lips_mask(model, topo, track, i: int, size: tuple[int, int], erode: int) -> np.ndarray:
    """Pixels of frame ``i`` covered by the lips (the mouth's triangles but the fan), eroded."""
    import cv2

    fan = np.zeros(len(topo.faces), bool)
    fan[topo.mouth_fan] = True
    mf = topo.mouth_faces[~fan[topo.mouth_faces]]
    xy = track.camera(i).project(model.synthesize(track.weights_at(i)))
    mask = np.zeros((size[1], size[0]), np.uint8)
    cv2.fillPoly(mask, list(np.rint(xy[topo.faces[mf]]).astype(np.int32)), 1)
    return cv2.erode(mask, np.ones((erode, erode), np.uint8)).astype(bool)


def redraw_scores(model, topo, frames, track, fn, rows, erode: int) -> dict:
    """PSNR on the lips and gradient share (redrawn / footage) of ``fn``'s texture at
    ``rows``' attributes drawn on their meshes, means over ``rows``."""
    import cv2

    from facetransfer.render import render
    from facetransfer.texture.function import attribute_vector
    from facetransfer.topology import close_mouth

    def grad(img, m):
        g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float64)
        return float(np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1))[m]
                     .mean())

    psnr, share = [], []
    for i in rows:
        f = np.asarray(frames[i])
        size = (f.shape[1], f.shape[0])
        w = track.weights_at(int(i))
        img = render(close_mouth(model.synthesize(w), topo), topo.faces, track.camera(int(i)),
                     size, uvs=fn.uvs, texture=fn.texture(attribute_vector(model, w)),
                     shading="none", background=f).image
        m = lips_mask(model, topo, track, int(i), size, erode)
        d = ((img.astype(float) - f.astype(float)) ** 2)[m].mean()
        psnr.append(10 * np.log10(255.0 ** 2 / max(d, 1e-12)))
        share.append(grad(img, m) / grad(f, m))
    return {"psnr_lips": float(np.mean(psnr)), "gradient_share": float(np.mean(share))}


def build(model, topo, frames, track, tex_size) -> tuple[object, dict]:
    """The mouth function at ``tex_size`` and its side, texel size, frames, bytes, peak, time."""
    from facetransfer.texture.face import _closed_uvs, mouth_layout, mouth_texture_function

    tracemalloc.start()
    t = time.perf_counter()
    fn = mouth_texture_function(model, frames, track, topo, tex_size=tex_size)
    sec = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    uvs = _closed_uvs(model, topo)
    lay = mouth_layout(model, track, topo, uvs, np.flatnonzero(~track.lost[:len(frames)]))
    T = fn.function.textures.shape[1]
    texel_px = lay.texel_pixels if tex_size == "auto" else lay.pixels_per_uv / (T - 1)
    return fn, {"tex_size": int(T), "texel_pixels": float(texel_px),
                "pixels_per_uv": lay.pixels_per_uv, "frames": int(fn.frames.size),
                "bytes": int(fn.function.textures.nbytes + fn.function.weights.nbytes),
                "traced_peak": int(peak), "seconds": sec}


def clip_rows(model, topo, video: Path, track_path: Path) -> dict:
    from facetransfer.io.video_read import read_video
    from facetransfer.track.result import Track

    frames, _ = read_video(video)
    track = Track.load(track_path)
    n = min(len(frames), track.n_frames)
    erode = max(3, int(round(frames.shape[2] / 512 * 3)) | 1)
    rows = [i for i in range(0, n, 4) if not track.lost[i]]
    out = {}
    for name, T in (("256", 256), ("auto", "auto")):
        fn, r = build(model, topo, frames[:n], track, T)
        r.update(redraw_scores(model, topo, frames, track, fn, rows, erode))
        out[name] = r
        print(video.name, name, r, flush=True)
    return out


def frames_study(model, topo, video: Path, track_path: Path, counts) -> dict:
    """Held-out PSNR on the lips (every 5th frame left out) against the frames lifted."""
    from facetransfer.io.video_read import read_video
    from facetransfer.texture.face import mouth_texture_function
    from facetransfer.track.project import take_frames
    from facetransfer.track.result import Track

    frames, _ = read_video(video)
    track = Track.load(track_path)
    n = min(len(frames), track.n_frames)
    held = np.arange(2, n, 5)
    train = np.setdiff1d(np.arange(n), held)
    out = {}
    for c in counts:
        fn = mouth_texture_function(model, frames[train], take_frames(track, train), topo,
                                    tex_size="auto", max_frames=int(c))
        out[int(c)] = redraw_scores(model, topo, frames, track, fn, held, 7)
        print("frames", c, out[int(c)], flush=True)
    return out


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    clips = list(report["clips"])
    fig, ax = plt.subplots(1, 3 + ("frames_study" in report), figsize=(16, 4))
    x = np.arange(len(clips))
    for k, (name, off) in enumerate((("256", -0.2), ("auto", 0.2))):
        r = [report["clips"][c][name] for c in clips]
        ax[0].bar(x + off, [v["texel_pixels"] for v in r], 0.4, label=name)
        ax[1].bar(x + off, [v["gradient_share"] for v in r], 0.4, label=name)
        ax[2].bar(x + off, [v["bytes"] / 2 ** 20 for v in r], 0.4, label=name)
    for a, t in zip(ax, ("screen px per mouth texel", "lips' gradient / footage's",
                         "lifted textures (MiB)")):
        a.set_xticks(x, clips)
        a.set_title(t)
        a.legend()
    if "frames_study" in report:
        s = report["frames_study"]
        ax[3].plot([int(k) for k in s], [v["psnr_lips"] for v in s.values()], "o-")
        ax[3].set_xlabel("frames lifted")
        ax[3].set_title("held-out lips PSNR (dB), 1080p")
    save_plot(fig, path)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--frames-4k", type=int, default=12)
    ap.add_argument("--frames-study", action="store_true")
    args = ap.parse_args()
    from facetransfer.default_model import load_default_model
    from facetransfer.topology import mesh_topology

    out = Path(args.out)
    (out / "clips").mkdir(parents=True, exist_ok=True)
    model = load_default_model()
    topo = mesh_topology(model)
    report = {"clips": {}}
    for name in SCALES:
        v, t = make_clip(out / "clips", name, args.frames_4k if name == "4k" else args.frames)
        report["clips"][name] = clip_rows(model, topo, v, t)
    if args.frames_study:
        report["frames_study"] = frames_study(model, topo, *make_clip(out / "clips", "1080",
                                                                      args.frames),
                                              (4, 8, 16, 32))
    save_json(report, out / "mouth_res.json")
    plot(report, out / "mouth_res.png")


if __name__ == "__main__":
    sys.exit(main())

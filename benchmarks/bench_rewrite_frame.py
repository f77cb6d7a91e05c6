"""Per-frame CPU of the rewrite (issue 13, the render's share): this tree against another.

The issue-13 demo pair (``driving_d9`` as the target, the expressions of ``driving_d6``, default
model, capture tracker, the default :class:`~facetransfer.rewrite_options.RewriteOptions`):
``rewrite_frames`` on one worker, OpenCV on one thread, CPU seconds (``time.process_time``)
per frame over ``--frames`` frames that follow the first ``--parity-frames`` (which pay the
set-up and numba's cache load, and are kept for the comparison), in a fresh process per run.
With ``--base-rev REV`` (a git revision of this repository, extracted to a temporary folder)
or ``--base SRC`` (the ``src`` folder of another checkout) both trees run in turn, ``--pairs``
times (the machine is shared: the spread between runs is the noise), and the first
``--parity-frames`` rewritten frames of the two are compared: PSNR over the face mask (the
pixels either face covers) and over the whole frame, and the count of pixels that differ
outside the face mask (0: the outside is bit-identical). Without a base only this tree runs.
With ``--matte`` this tree also computes each frame's matte (``transfer --matte``:
``rewrite_frames(..., matte=True)``); against ``--base src`` (this tree's own) the difference
is the matte's cost per frame, and the parity says that the frames are the same with it.

    python benchmarks/bench_rewrite_frame.py --out out/benchmarks [--base-rev main | --base SRC]
        [--matte]

Writes ``OUT/rewrite_frame.json`` and ``OUT/rewrite_frame.png``; the two clips' tracks are kept
in ``OUT/rewrite_frame_tracks/`` for later runs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from _revision import add_base_options, base_src, rewrite_plan  # benchmarks/ is on sys.path

TARGET, SOURCE = "driving_d9.mp4", "driving_d6.mp4"
#: frames of the target used (10 s at 30 fps, as issue 13's end-to-end goal)
CLIP = 300


def _video(name: str) -> Path:
    from facetransfer.assets import DATA_DIR_ENV, data_dir

    root = data_dir()
    if root is None:
        raise SystemExit(f"bench_rewrite_frame: set ${DATA_DIR_ENV} to the asset mirror "
                         f"(its video/{name} is the demo pair)")
    return Path(root) / "video" / name


def worker(tracks: Path, frames: int, parity: int, save: Path, matte: bool = False) -> dict:
    """Render ``frames`` frames here (the tree on ``sys.path``; ``matte``: with their mattes);
    saves the first ``parity``."""
    import cv2

    cv2.setNumThreads(1)
    from facetransfer.default_model import load_default_model
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer.texture.face import resolve_mouth_mode
    from facetransfer.video_transfer import plan_transfer

    model = load_default_model()
    tt, et = tracks / "target.npz", tracks / "expression.npz"
    plan = plan_transfer(_video(TARGET), model, expression_from=_video(SOURCE),
                         target_track=tt if tt.exists() else None,
                         expression_track=et if et.exists() else None, max_frames=CLIP)
    if not tt.exists():  # tracked once, for every later run
        tracks.mkdir(parents=True, exist_ok=True)
        plan.source_tracks["target"].save(tt)
        plan.source_tracks["expression"].save(et)
    opts = RewriteOptions()
    opts = opts.with_(mouth=resolve_mouth_mode(opts.mouth, model, performance=plan.performance))
    # this tree's call or an older one's
    it = rewrite_plan(plan, model, opts, workers=1, **({"matte": True} if matte else {}))
    t0 = time.process_time()
    kept = [next(it) for _ in range(max(parity, 1))]  # the first pays the set-up
    t1 = time.process_time()
    for _ in range(frames):  # timed, nothing kept (no fresh pages for kept frames)
        next(it)
    t2 = time.process_time()
    np.savez(save, image=np.stack([r.image for r in kept]),
             face=np.stack([r.face_mask for r in kept]))
    return {"first_frames_s": t1 - t0, "per_frame_ms": (t2 - t1) / max(frames, 1) * 1e3}


def run(src: Path, tracks: Path, frames: int, parity: int, save: Path,
        matte: bool = False) -> dict:
    """:func:`worker` in a fresh process with ``src`` first on its path."""
    # OpenBLAS on one thread, as the commands that render run it (facetransfer.cli.main.serial_blas)
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, __file__, "--worker", "--tracks", str(tracks),
                          "--frames", str(frames), "--parity-frames", str(parity),
                          "--save", str(save), *(["--matte"] if matte else [])], env=env,
                         check=True, capture_output=True,
                         text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def parity(a_path: Path, b_path: Path) -> dict:
    """Per-frame PSNR of two runs' frames over the face mask and the whole frame, and the
    pixels that differ outside the face mask."""
    a, b = np.load(a_path), np.load(b_path)
    n = min(len(a["image"]), len(b["image"]))
    face_db, frame_db, outside = [], [], 0
    for i in range(n):
        x, y = a["image"][i].astype(np.float64), b["image"][i].astype(np.float64)
        face = a["face"][i] | b["face"][i]
        d2 = ((x - y) ** 2).sum(axis=-1) / 3.0
        for where, acc in ((face, face_db), (np.ones_like(face), frame_db)):
            mse = float(d2[where].mean()) if where.any() else 0.0
            acc.append(float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse))
        outside += int(((x != y).any(axis=-1) & ~face).sum())
    return {"frames": n, "face_psnr_db": face_db, "frame_psnr_db": frame_db,
            "differing_outside_face": outside}


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4))
    names = list(res["runs"])
    ms = [res["runs"][k] for k in names]
    ax0.boxplot(ms, showmeans=True)
    ax0.set_xticks(range(1, len(names) + 1), names)
    ax0.axhline(20, color="grey", ls="--", lw=1, label="goal 20 ms")
    ax0.set_ylabel("CPU ms per frame (1 worker, 1 thread)")
    ax0.set_ylim(bottom=0)
    ax0.legend()
    if "parity" in res:
        p = res["parity"]
        ax1.plot(np.minimum(p["face_psnr_db"], 99), label="face mask")
        ax1.plot(np.minimum(p["frame_psnr_db"], 99), label="whole frame")
        ax1.axhline(40, color="grey", ls="--", lw=1, label="40 dB")
        ax1.set_xlabel("frame")
        ax1.set_ylabel("PSNR this tree vs base (dB; 99: identical)")
        ax1.legend()
    fig.suptitle("rewrite: per-frame CPU on the demo pair (driving_d9 <- driving_d6)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    add_base_options(ap)
    ap.add_argument("--frames", type=int, default=100, help="frames timed per run")
    ap.add_argument("--parity-frames", type=int, default=60, help="frames compared")
    ap.add_argument("--pairs", type=int, default=3, help="runs of each tree, in turn")
    ap.add_argument("--matte", action="store_true",
                    help="this tree computes each frame's matte too (transfer --matte)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--tracks", help=argparse.SUPPRESS)
    ap.add_argument("--save", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.frames < 1 or args.parity_frames < 1 or args.frames + args.parity_frames > CLIP:
        ap.error(f"--frames and --parity-frames must be >= 1 and add up to at most {CLIP}")
    if args.worker:
        print(json.dumps(worker(Path(args.tracks), args.frames, args.parity_frames,
                                Path(args.save), args.matte)))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tracks = out / "rewrite_frame_tracks"
    here = Path(__file__).resolve().parents[1] / "src"
    base = base_src(args, "bench_rewrite_frame_")
    trees = {"this tree": here} | ({"base": base} if base else {})
    runs = {name: [] for name in trees}
    for _ in range(args.pairs):
        for name, src in trees.items():
            r = run(src, tracks, args.frames, args.parity_frames,
                    out / f"rewrite_frame_{name.replace(' ', '_')}.npz",
                    matte=args.matte and name == "this tree")
            runs[name].append(r["per_frame_ms"])
            print(f"{name}: {r['per_frame_ms']:.1f} ms per frame", flush=True)
    res = {"frames": args.frames, "runs": runs, "load_average": os.getloadavg(),
           "matte": bool(args.matte),
           "median_ms": {k: float(np.median(v)) for k, v in runs.items()}}
    if base:
        res["base"] = str(args.base or args.base_rev)
        res["parity"] = parity(out / "rewrite_frame_this_tree.npz", out / "rewrite_frame_base.npz")
        p = res["parity"]
        print(f"parity: face PSNR min {min(p['face_psnr_db']):.1f} dB, whole frame min "
              f"{min(p['frame_psnr_db']):.1f} dB, {p['differing_outside_face']} pixels differ "
              "outside the face")
    (out / "rewrite_frame.json").write_text(json.dumps(res, indent=1))
    plot(res, out / "rewrite_frame.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

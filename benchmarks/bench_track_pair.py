"""CPU of issue 13's two tracks as the transfer makes them: this tree against another.

The issue-13 pair (``driving_d9`` as the target, ``driving_d6`` as the expression source, 300
frames each, decoded first): the source tracked in a forked child
(``obtain.start_background_track``, its detector shown every other frame and every frame where
the eyes move) while this process tracks the target (every other frame), as
``transfer_plan.plan_transfer`` runs them; CPU seconds (user + system) of this process and of
the child over the two tracks only (not the imports, the model, the decoding), in a fresh
process per run with the command's single-threaded BLAS and OpenCV
(``facetransfer.cli.main.SERIAL_POOLS``) and the track cache off. With ``--base-rev REV`` (a git
revision of this repository, extracted to a temporary folder) or ``--base SRC`` both trees run
in turn, ``--rounds`` times (the machine is shared: the spread is the noise), and the tracks
they made are compared array by array (``identical``: every array equal, NaN for NaN).

    python benchmarks/bench_track_pair.py --out out/benchmarks [--base-rev main | --base SRC]

Writes ``OUT/track_pair.json`` and keeps the last run's tracks in ``OUT/track_pair_*.npz``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

from _revision import add_base_options, base_src  # benchmarks/ is on sys.path

TARGET, SOURCE, FRAMES = "driving_d9.mp4", "driving_d6.mp4", 300


def worker(save: str) -> dict:
    """Both tracks here (the tree on ``sys.path``); CPU of this process and of the child."""
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.video import read_video
    from facetransfer.track import obtain
    from facetransfer.track.capture import load_kernels
    from facetransfer.track.detect import preload_mediapipe

    wait = preload_mediapipe()
    model = load_default_model()
    video = Path(data_dir()) / "video"
    target, source = str(video / TARGET), str(video / SOURCE)
    frames, fps = read_video(target, max_frames=FRAMES)
    pre_read = read_video(source, max_frames=FRAMES)
    load_kernels()
    wait()

    def cpu(who):
        r = resource.getrusage(who)
        return r.ru_utime + r.ru_stime

    here, kids = cpu(resource.RUSAGE_SELF), cpu(resource.RUSAGE_CHILDREN)
    early = obtain.start_background_track(source, model, len(pre_read[0]), frames=pre_read,
                                          method="auto", options=None, parallel=True,
                                          detect_every=2, detect_eyes=True)
    tt = obtain.obtain_track(target, model, frames=frames, fps=fps, max_frames=len(frames),
                             method="auto", workers=1, detect_every=2, cache=False)
    st = early.result()
    here, kids = cpu(resource.RUSAGE_SELF) - here, cpu(resource.RUSAGE_CHILDREN) - kids
    tt.save(f"{save}_target.npz")
    st.save(f"{save}_source.npz")
    return {"parent": here, "child": kids, "total": here + kids}


def run(src: Path, save: Path) -> dict:
    """One worker in a fresh process on the tree ``src``."""
    env = dict(os.environ, PYTHONPATH=str(src), FACETRANSFER_TRACK_CACHE="off",
               OPENBLAS_NUM_THREADS="1", OPENCV_FOR_THREADS_NUM="1")
    out = subprocess.run([sys.executable, __file__, "--worker", "--save", str(save)], env=env,
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def same_arrays(a: Path, b: Path) -> list[str]:
    """The names of the arrays that differ between two track files (or are in one only)."""
    x, y = np.load(a, allow_pickle=False), np.load(b, allow_pickle=False)
    differ = sorted(set(x.files) ^ set(y.files))
    for k in sorted(set(x.files) & set(y.files)):
        u, v = x[k], y[k]
        nan = u.dtype.kind in "fc"
        if u.shape != v.shape or not np.array_equal(u, v, equal_nan=nan):
            differ.append(k)
    return differ


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    add_base_options(ap)
    ap.add_argument("--rounds", type=int, default=4, help="runs of each tree, in turn")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--save", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.save)))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    here = Path(__file__).resolve().parents[1] / "src"
    base = base_src(args, "bench_track_pair_")
    trees = {"this_tree": here} | ({"base": base} if base else {})
    runs = {name: [] for name in trees}
    for _ in range(args.rounds):
        for name, src in trees.items():
            r = run(src, out / f"track_pair_{name}")
            runs[name].append(r)
            print(f"{name}: parent {r['parent']:.2f}, child {r['child']:.2f}, total "
                  f"{r['total']:.2f} CPU-s", flush=True)
    res = {"rounds": args.rounds, "runs": runs, "load_average": os.getloadavg(),
           "median": {n: {k: float(np.median([r[k] for r in v])) for k in v[0]}
                      for n, v in runs.items()}}
    if base:
        res["base"] = str(args.base or args.base_rev)
        res["differ"] = {w: same_arrays(out / f"track_pair_this_tree_{w}.npz",
                                        out / f"track_pair_base_{w}.npz")
                         for w in ("target", "source")}
        print("tracks:", ", ".join(f"{w} {'identical' if not d else 'differ in ' + str(d)}"
                                   for w, d in res["differ"].items()))
    (out / "track_pair.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

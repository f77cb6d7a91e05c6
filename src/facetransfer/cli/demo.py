"""``facetransfer demo``: the main job end to end on the default clips (build the default model,
track two clips, transfer, write the video, a contact sheet and the track).

    facetransfer demo [--out out] [--frames N] [--source S.mp4] [--target T.mp4]

It takes ``transfer``'s rewrite options (:func:`.transfer.add_rewrite_options`); the job is
:func:`facetransfer.demo.run_demo`.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import FaceTransferError
from .common import (MODEL_HELP, add_video_options, bar_factory, check_positive, frame_count,
                     load_model_and_mediapipe, subcommand_parser, video_options)
from .transfer import add_rewrite_options, rewrite_options


def register(sub) -> None:
    """Add ``demo`` to the facetransfer parser."""
    d = subcommand_parser(
        sub, "demo", "the main job end to end on the default clips",
        "Build the default model if needed, track two clips of the data folder "
        "($FACETRANSFER_DATA_DIR/video), transfer the expressions of driving_d6.mp4 onto "
        "WDA_KatieHill_000.mp4 and write OUT/demo.mp4 (source | target | result), OUT/demo.png "
        "(contact sheet) and OUT/demo_track.npz.")
    d.add_argument("--out", default="out", metavar="DIR", help="output folder")
    d.add_argument("--frames", type=int, default=120, help="target frames to use")
    d.add_argument("--source", metavar="S.mp4", help="expression source (default driving_d6)")
    d.add_argument("--target", metavar="T.mp4", help="target footage (default WDA_KatieHill_000)")
    d.add_argument("--model", metavar="M.npz", help=MODEL_HELP)
    d.add_argument("--overwrite", action="store_true",
                   help="replace the outputs of an earlier run in the folder")
    add_rewrite_options(d)
    add_video_options(d, what="OUT/demo.mp4 (demo.mov for prores)", sequences=False)
    d.set_defaults(func=run_demo)


def run_demo(args) -> int:
    from ..demo import run_demo as demo

    check_positive(args.frames, "--frames")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FaceTransferError(f"--out {out} is a file; demo writes into a folder (give a "
                                "folder name)")
    vopt, opts = video_options(args), rewrite_options(args)  # checked before any work
    t0 = time.perf_counter()
    model = load_model_and_mediapipe(args.model, args.tracker != "landmarks")
    loaded = time.perf_counter() - t0  # the default model's first build too
    res = demo(args.out, frames=args.frames, source=args.source, target=args.target,
               model=model, options=opts, overwrite=args.overwrite,
               progress_factory=bar_factory(), video_options=vopt)
    t = dict(res.timings)
    t["model"], t["total"] = t.get("model", 0.0) + loaded, t.get("total", 0.0) + loaded
    print(f"wrote {res.video} ({frame_count(res.n_frames)}: source | target | result), "
          f"{res.sheet}, {res.track}")
    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in t.items())
          + ("" if res.method == "auto" else f" (tracking: {res.method})"))
    if res.fidelity is not None:
        print(res.fidelity.line())
    return 0

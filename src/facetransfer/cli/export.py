"""``facetransfer export``: a track's ARKit curves and head pose for animation tools.

    facetransfer export TRACK.npz --format livelink --out take.csv        # Live Link Face CSV
    facetransfer export TRACK.npz --format glb --out face.glb [--texture TEX.png]
    facetransfer export TRACK.npz --format usd --out face.usd [--model M.npz]
    facetransfer export TRACK.npz --format json --out blendshapes.json    # MediaPipe layout
"""

from __future__ import annotations

import argparse
import sys

from ..export import FORMATS


def register(sub) -> None:
    """Add ``facetransfer export``."""
    p = sub.add_parser(
        "export", help="write a track's ARKit blendshapes and head pose (Live Link CSV, glb, "
        "USD, MediaPipe JSON)",
        description="Export a track's ARKit activations and head pose: livelink (Live Link Face "
        "CSV), glb (glTF 2.0 with 52 morph targets and the animation), usd (UsdSkel), json "
        "(MediaPipe's blendshape layout).")
    p.add_argument("track", metavar="TRACK.npz")
    p.add_argument("--format", required=True, metavar="FMT",
                   help=f"one of {', '.join(FORMATS)}")
    p.add_argument("--out", required=True, metavar="FILE", help="file to write")
    p.add_argument("--model", metavar="M.npz",
                   help="the model the track was made with (default: the default model, if the "
                   "track was made with it)")
    p.add_argument("--texture", metavar="TEX.png",
                   help="base-colour texture in the template's UV layout (glb only)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def default_model_for(track):
    """The default model for a track given without ``--model`` (built once with a progress bar;
    an error asking for ``--model`` if the track was made with another model)."""
    from tqdm import tqdm

    from ..export.common import resolve_model

    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, desc="default model", unit="identity", leave=False,
                       disable=not sys.stderr.isatty())
        bar.update(done - bar.n)

    try:
        return resolve_model(track, progress=progress,
                             announce=lambda m: print(m, file=sys.stderr))
    finally:
        if bar is not None:
            bar.close()


def run(args: argparse.Namespace) -> int:
    from ..errors import FaceTransferError
    from ..export import export_track
    from ..io.atomic import check_output_path
    from ..track import Track

    if args.format not in FORMATS:
        raise FaceTransferError(f"--format: unknown format {args.format!r}; choose one of "
                                f"{', '.join(FORMATS)}")
    check_output_path(args.out, overwrite=args.overwrite)
    track = Track.load(args.track)
    model = None
    if args.model:
        from ..model import load_model

        model = load_model(args.model)
    elif args.format in ("glb", "usd"):
        model = default_model_for(track)
    path = export_track(track, args.format, args.out, model=model, overwrite=args.overwrite,
                        texture=args.texture)
    print(f"wrote {path}: {track.n_frames} frames ({args.format})")
    return 0

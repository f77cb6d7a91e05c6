"""``facetransfer view``: a self-contained HTML dial editor for a model or a track.

    facetransfer view MODEL.npz --out page.html
    facetransfer view TRACK.npz --out page.html [--model M.npz] [--neutral auto]
"""

from __future__ import annotations

import argparse


def register(sub) -> None:
    """Add ``facetransfer view``."""
    p = sub.add_parser(
        "view", help="write a self-contained HTML page with sliders for blendshapes, identity "
        "dials and head pose (and a timeline for a track)",
        description="One HTML file, no network needed: three.js inlined, a slider per "
        "blendshape and per identity dial, head pose, and for a track a timeline.")
    p.add_argument("source", metavar="MODEL.npz|TRACK.npz")
    p.add_argument("--out", required=True, metavar="PAGE.html")
    p.add_argument("--model", metavar="M.npz", help="for a track: its model (default: the "
                   "default model, if the track was made with it)")
    p.add_argument("--neutral", metavar="FRAME|auto",
                   help="for a track: its activations measured from this frame's, as "
                   "`facetransfer export --neutral` (default: as tracked)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing page")
    p.set_defaults(func=run)


def _is_track(path) -> bool:
    import zipfile

    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            return "rotation" in z.files and "mode_names" in z.files
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return False  # write_viewer reports it


def run(args: argparse.Namespace) -> int:
    from ..export.viewer import write_viewer
    from ..io.atomic import check_output_path

    check_output_path(args.out, overwrite=args.overwrite)
    model = None
    if args.model:
        from ..model import load_model

        model = load_model(args.model)
    elif _is_track(args.source):
        from ..track import Track
        from .export import default_model_for

        model = default_model_for(Track.load(args.source))
    path = write_viewer(args.source, args.out, model=model, overwrite=args.overwrite,
                        neutral=args.neutral)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0

"""``facetransfer view``: a self-contained HTML dial editor for a model or a track.

    facetransfer view [MODEL.npz] --out page.html                 # default: the default model
    facetransfer view TRACK.npz --out page.html [--model M.npz] [--neutral auto]
    facetransfer view TAKE.csv --out page.html [--model M.npz] [--neutral 0]   # a take
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
    p.add_argument("source", metavar="MODEL.npz|TRACK.npz|TAKE.csv", nargs="?",
                   help="a model, a track, or a Live Link Face take (its curves and head "
                   "rotation on the model's mean person); default: the default model")
    p.add_argument("--out", required=True, metavar="PAGE.html",
                   help="the page to write (.html), opened by any browser without network")
    p.add_argument("--model", metavar="M.npz", help="for a track: its model (default: the "
                   "default model, if the track was made with it)")
    p.add_argument("--neutral", metavar="FRAME|auto",
                   help="for a track or a take: its activations measured from this frame's "
                   "(numbered as its page does: a plate's track's as the plate's files), as "
                   "`facetransfer export --neutral` "
                   "(default: as tracked or recorded)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing page")
    p.set_defaults(func=run)


def _has_arrays(path, names: set) -> bool:
    """Whether ``path`` is an .npz archive holding the arrays ``names`` (else write_viewer
    says what it is)."""
    from ..io.npz import NOT_ARCHIVE_ERRORS, archive_names

    try:
        held = archive_names(path)
    except NOT_ARCHIVE_ERRORS:
        return False  # write_viewer reports it
    return held is not None and names <= held   # an .npy: said there


def _is_track(path) -> bool:
    return _has_arrays(path, {"rotation", "mode_names"})


def _take_page(args: argparse.Namespace):
    """The page of a Live Link Face take: the model's mean person performing it with its
    head's rotation (:func:`facetransfer.take.take_track`), on the track's timeline; with
    ``--neutral``, its activations measured from that frame's as ``export take.csv --neutral``
    measures them (:func:`facetransfer.export.neutral.with_neutral`; before, refused as "for
    a track")."""
    from pathlib import Path

    from ..errors import FaceTransferError
    from ..export.neutral import neutral_arg, with_neutral
    from ..export.viewer import viewer_page
    from ..io.atomic import write_text_atomic
    from ..take import take_track
    from .common import resolve_model

    if args.neutral is not None:
        neutral_arg(args.neutral)            # its word checked before a model is built
    if not Path(args.source).is_file():
        raise FaceTransferError(f"take {args.source} does not exist")
    model = resolve_model(args.model)
    track = take_track(args.source, model, model.weight_mean(model.mode_index("identity")))
    track = with_neutral(track, args.neutral, take=args.source)   # a frame past it: the take's
    page = viewer_page(model, track=track, title=Path(args.source).name)
    return write_text_atomic(args.out, page, overwrite=args.overwrite)


def _default_model_page(args: argparse.Namespace):
    """The page of the default model (``--model``'s, given one): no file to name."""
    from ..errors import FaceTransferError
    from ..export.viewer import viewer_page
    from ..io.atomic import write_text_atomic
    from .common import resolve_model

    if args.neutral is not None:
        raise FaceTransferError("--neutral is for a track; give the track to view")
    page = viewer_page(resolve_model(args.model), title="facetransfer: the default model"
                       if args.model is None else args.model)
    return write_text_atomic(args.out, page, overwrite=args.overwrite)


def run(args: argparse.Namespace) -> int:
    from ..errors import FaceTransferError
    from ..export.viewer import write_viewer
    from ..io.atomic import check_output_path
    from ..take import is_take
    from .common import check_output_name

    check_output_name(args.out, (".html", ".htm"), "the dial editor's page")
    check_output_path(args.out, overwrite=args.overwrite, inputs=(args.source, args.model))
    if args.source is None:
        path = _default_model_page(args)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
        return 0
    if is_take(args.source):
        path = _take_page(args)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
        return 0
    model = None
    if args.model and _has_arrays(args.source, {"core", "metadata"}):   # was ignored
        raise FaceTransferError(f"--model is a track's or a take's model; {args.source} is a "
                                "model itself: view it without --model")
    if args.model:
        from ..model import load_model

        model = load_model(args.model)
    elif _is_track(args.source):
        from ..track import Track
        from .common import default_model_for

        model = default_model_for(Track.load(args.source))
    path = write_viewer(args.source, args.out, model=model, overwrite=args.overwrite,
                        neutral=args.neutral)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0

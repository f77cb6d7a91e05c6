"""``facetransfer edit TRACK.npz|TAKE.csv``: a performance edited (Vlasic et al. 2005, Fig. 7E).

    facetransfer edit TRACK.npz [--model M.npz] --add frown@120-180 --scale smile=1.5 --out T2.npz
    facetransfer edit take.csv --scale jawOpen=2 --add "mouthSmile*0.5@10-40" --out take2.csv

A track's expression weights are edited by :func:`facetransfer.performance_edit.edit_track`
(and its identity moved along semantic dials, :func:`facetransfer.dials.dial_track`). An
animator's take from the iPhone app, exaggerated or given a curve and sent back to Unreal:
:func:`facetransfer.take.edit_take` (the curves edited as an ARKit track's are, everything else
of the file kept byte for byte). The command's parser, its checks common to a track and a take,
and each one's own are here.
"""

from __future__ import annotations

from ..errors import FaceTransferError
from .common import (DefaultsFormatter, check_track_name, default_model_for, frame_count,
                     option_with)


def register(sub) -> None:
    """Add ``edit`` to the facetransfer parser."""
    e = sub.add_parser(
        "edit", formatter_class=DefaultsFormatter,
        help="edit a tracked performance (Fig. 7E) or a Live Link Face take",
        description="Add a training expression over a frame range (with smooth ramps) or "
        "scale an expression's component, frame by frame (Vlasic et al. 2005, Fig. 7E). A Live "
        "Link Face take (TAKE.csv) is edited on its ARKit curves and written as a take, the "
        "rest of the file (timecodes, head and eye rotations, columns) kept as it was.")
    e.add_argument("track", metavar="TRACK.npz|TAKE.csv", help="the track or take to edit")
    e.add_argument("--model", metavar="M.npz",
                   help="the model the track was made with (default: the default model, if the "
                   "track was made with it); a take needs none")
    e.add_argument("--add", action="append", default=[], metavar="EXPR@START-END",
                   help="add EXPR (training weights minus neutral; an ARKit model's or a "
                   "take's: activation 1) on frames START..END (inclusive, 0-based; a plate's "
                   "track's numbered as the plate's files, 1001 on; a take's as view and "
                   "puppet number them); EXPR*0.5@... for half; repeatable")
    e.add_argument("--scale", action="append", default=[], metavar="EXPR=FACTOR",
                   help="scale the component of the expression along EXPR - neutral (an ARKit "
                   "model's or a take's: the EXPR curve times FACTOR, clipped to [0, 1], Live "
                   "Link Face's range; EXPR one of the 52 ARKit names, e.g. jawOpen or, as a "
                   "take's header spells it, JawOpen); repeatable")
    e.add_argument("--ramp", type=int, default=None,
                   help="frames over which an --add eases in before START and out after END "
                   "(0: none; the range itself is at full strength; default 8)")
    e.add_argument("--identity-dials", metavar="NAME=UNITS,...",
                   help="move the identity along semantic dials, e.g. width=+1.5,lip_fullness=1 "
                   "(a track's; a take has no identity)")
    e.add_argument("--out", required=True, metavar="TRACK2.npz|TAKE2.csv", type=str,
                   help="the edited track to write (.npz), for transfer --performance; of a "
                   "take, the edited take (.csv)")
    e.add_argument("--overwrite", action="store_true", help="replace an existing output")
    e.set_defaults(func=run_edit)


#: largest |factor| of ``edit --scale`` and |amount| of ``edit --add``: beyond it a face leaves
#: the space the model was trained on (weights of 1e307 were written before issue 16)
MAX_EDIT_FACTOR = 10.0


def _model_for_track(track, model_path):
    """``--model`` checked against the track, or without it the default model, built on first
    use as every other command builds it (before, edit asked to run `facetransfer demo`)."""
    from ..model import load_model

    if model_path is None:
        return default_model_for(track)
    model = load_model(model_path)
    track.check_model(model)
    return model


def run_edit(args) -> int:
    """Edit the track (or the take: :func:`run_take_edit`) ``args.track`` and write it."""
    from ..io.atomic import check_output_path
    from ..io.frame_numbers import frame_span, track_first_number
    from ..performance_edit import edit_track, parse_add, parse_scale
    from ..track import Track

    if not args.add and not args.scale and not args.identity_dials:
        raise FaceTransferError("nothing to do: give --add EXPR@START-END, --scale "
                                "EXPR=FACTOR and/or --identity-dials NAME=UNITS")
    from ..take import is_take

    check_edit_kind(args)      # a take's options, a track's output named as a take
    dial_values = None
    if args.identity_dials:
        from ..dials import parse_dial_values

        dial_values = parse_dial_values(args.identity_dials)
    adds = [parse_add(a) for a in args.add]
    scales = [parse_scale(s) for s in args.scale]
    for s, text in zip(scales, args.scale):
        if not abs(s.factor) <= MAX_EDIT_FACTOR:
            raise FaceTransferError(f"--scale {text}: the factor must lie in "
                                    f"[-{MAX_EDIT_FACTOR:g}, {MAX_EDIT_FACTOR:g}] (for an "
                                    f"ARKit model's activations [0, {MAX_EDIT_FACTOR:g}])")
    for a, text in zip(adds, args.add):
        if not abs(a.amount) <= MAX_EDIT_FACTOR:
            raise FaceTransferError(f"--add {text}: the amount must lie in "
                                    f"[-{MAX_EDIT_FACTOR:g}, {MAX_EDIT_FACTOR:g}]")
    args.ramp = option_with(args.ramp, 8, "--ramp", args.add, "--add")
    if args.ramp < 0:
        raise FaceTransferError(f"--ramp must be >= 0 frames, got {args.ramp}")
    if is_take(args.track):
        return run_take_edit(args, adds, scales)
    check_track_name(args.out)
    check_output_path(args.out, overwrite=args.overwrite, inputs=[args.track, args.model])
    track = Track.load(args.track)
    model = _model_for_track(track, args.model)
    first = track_first_number(track)     # a plate's track: ranges in the plate's numbers
    new = edit_track(track, model, add=adds, scale=scales, ramp=args.ramp, first=first)
    if dial_values:
        from ..dials import dial_track

        new = dial_track(new, model, dial_values)
    new.save(args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: {frame_count(new.n_frames)}"
          + (f" (numbered {frame_span(first, new.n_frames)} as the plate's files)" if first
             else "") + f", {len(adds)} addition(s), "
          f"{len(scales)} scaling(s)" + (f", dials {args.identity_dials}" if dial_values else ""))
    return 0


def check_edit_kind(args) -> None:
    """``edit``'s input and output of one kind: of a take (``args.track``, :func:`_check_take`),
    a take; of a track, a track (:func:`_check_track_out`)."""
    from ..take import is_take

    if is_take(args.track):
        _check_take(args)
    else:
        _check_track_out(args)


def _check_take(args) -> None:
    """``edit``'s options for a take (``args.track``), each wrong one a line: no identity to
    dial, no model to name, an output that is no take, there already (without
    ``--overwrite``) or the take itself."""
    from ..io.atomic import check_output_path
    from ..io.npz import check_input_file
    from .common import check_output_name

    take = args.track
    if args.identity_dials:
        raise FaceTransferError(f"--identity-dials: {take} is a Live Link Face take, which has "
                                "no identity to dial (a track of a video has one)")
    if args.model:
        raise FaceTransferError(f"--model: {take} is a Live Link Face take, whose ARKit curves "
                                "are edited without a model; leave --model out")
    check_input_file(take, "take")
    check_output_name(args.out, (".csv",), "an edited take",
                      hint=f" (an edit of the take {take} is a take; a track is made from "
                      "a video with `facetransfer track`)")
    check_output_path(args.out, overwrite=args.overwrite, inputs=[take])


def _check_track_out(args) -> None:
    """A track's edit named as a take (``--out X.csv``): one line pointing to ``export``."""
    from pathlib import Path

    if Path(args.out).suffix.lower() == ".csv":
        stem = Path(args.out).with_suffix(".npz")
        raise FaceTransferError(f"--out {args.out}: an edit of the track {args.track} is a "
                                f"track (.npz); write {stem}, then `facetransfer export {stem} "
                                f"--out {args.out}` turns it into a Live Link Face take")


def run_take_edit(args, adds: list, scales: list) -> int:
    """Edit the take (:func:`facetransfer.take.edit_take`) and say what was written."""
    from ..take import edit_take

    res = edit_take(args.track, args.out, add=adds, scale=scales, ramp=args.ramp,
                    overwrite=args.overwrite)
    print(f"wrote {res.path}: {res.n_rows} rows, {len(adds)} addition(s), {len(scales)} "
          f"scaling(s); curves changed: {', '.join(res.changed) or 'none'}")
    return 0

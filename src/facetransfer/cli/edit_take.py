"""``facetransfer edit TAKE.csv``: a Live Link Face take's ARKit curves edited, a take written.

    facetransfer edit take.csv --scale jawOpen=2 --add "mouthSmile*0.5@10-40" --out take2.csv

An animator's take from the iPhone app, exaggerated or given a curve and sent back to Unreal:
:func:`facetransfer.take.edit_take` (the curves edited as an ARKit track's are, everything else
of the file kept byte for byte). ``edit``'s parser and its checks common to a track and a take
are :mod:`.transfer`'s; these are the take's own (a module of its own: that one is near the
size a module may have).
"""

from __future__ import annotations

from ..errors import FaceTransferError


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
    from ..io.output_names import check_output_suffix

    take = args.track
    if args.identity_dials:
        raise FaceTransferError(f"--identity-dials: {take} is a Live Link Face take, which has "
                                "no identity to dial (a track of a video has one)")
    if args.model:
        raise FaceTransferError(f"--model: {take} is a Live Link Face take, whose ARKit curves "
                                "are edited without a model; leave --model out")
    check_input_file(take, "take")
    check_output_suffix(args.out, (".csv",), "an edited take",
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

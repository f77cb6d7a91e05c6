"""``facetransfer export``: a track's ARKit curves and head pose for animation tools.

    facetransfer export TRACK.npz --format livelink --out take.csv        # Live Link Face CSV
    facetransfer export TRACK.npz --format glb --out face.glb [--texture T.png|--texture-from V.mp4]
    facetransfer export TRACK.npz --format usd --out face.usd [--model M.npz]
    facetransfer export TRACK.npz --format json --out blendshapes.json    # MediaPipe layout
    facetransfer export TRACK.npz --format livelink --out take.csv --neutral auto  # calibrated
    facetransfer export TRACK.npz --out take.csv      # the format from the extension
    facetransfer export TRACK.npz --out take.csv --take-rate clip  # rows of a 25 fps clip's frames
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..export import FORMAT_SUFFIXES, FORMATS, GEOMETRY_FORMATS
from .common import (default_model_for, frame_count, option_with, progress_disabled,
                     resolve_model)


def register(sub) -> None:
    """Add ``facetransfer export``."""
    p = sub.add_parser(
        "export", help="write a track's ARKit blendshapes and head pose (Live Link CSV, glb, "
        "USD, MediaPipe JSON)",
        description="Export a track's ARKit activations and head pose: livelink (Live Link Face "
        "CSV), glb (glTF 2.0 with 52 morph targets and the animation), usd (UsdSkel), json "
        "(MediaPipe's blendshape layout).")
    p.add_argument("track", metavar="TRACK.npz",
                   help="the track to export (facetransfer track), or a Live Link Face take "
                   "(take.csv) as glb, usd or json: the model's mean person performing its "
                   "curves with its head's rotation, as `puppet take.csv` shows it")
    p.add_argument("--format", metavar="FMT",
                   help=f"one of {', '.join(FORMATS)} (default: the one --out's extension "
                   "names: " + ", ".join(f"{'/'.join(s)} {f}" for f, s in FORMAT_SUFFIXES.items())
                   + ")")
    p.add_argument("--out", required=True, metavar="FILE", help="file to write")
    p.add_argument("--model", metavar="M.npz",
                   help="the model the track was made with (default: the default model, if the "
                   "track was made with it); a track without ARKit activations (one recombined "
                   "in Python) has them made from its expression weights with it")
    p.add_argument("--texture", metavar="TEX.png",
                   help="base-colour texture in the template's UV layout: a square image, "
                   "as `texture default|lift` writes (glb only)")
    p.add_argument("--texture-from", metavar="VIDEO.mp4",
                   help="lift the texture from the tracked video instead (glb only)")
    p.add_argument("--texture-step", type=int, default=None, metavar="N",
                   help="with --texture-from: use every N-th frame (default 10)")
    p.add_argument("--neutral", metavar="FRAME|auto",
                   help="measure every activation from this frame's, as Live Link Face's "
                   "calibration does (the neutral frame exports 0, a full shape still 1; the gaze "
                   "as tracked); auto: the frame whose activations sum least (default: as "
                   "tracked). FRAME counts from 0, a plate's track's as the plate's files "
                   "(1001 on); a take's is numbered on its timeline, as view and puppet "
                   "number it")
    p.add_argument("--timecode", default="source", metavar="HH:MM:SS:FF|source|none",
                   help="livelink: the first row's timecode: the tracked video's start timecode "
                   "where it has one (source, the default: a take then lines up with the plate "
                   "in Unreal (or an editor, with --take-rate clip), and "
                   "`transfer --expression-from` places it back by "
                   "it), a timecode (';' before the frames of a drop-frame one), or none "
                   "(00:00:00:00). usd: source (the default) starts the time codes at the "
                   "first frame number of the image sequence tracked (a plate numbered from "
                   "1001: 1001), none at 0. usd, glb and json: source also records the tracked "
                   "video's start timecode in the file (customLayerData, extras, timecode; "
                   "a take's: its first row's). "
                   "source: as the track recorded them when it was tracked (a track made "
                   "before tracks recorded them: read from its clip, if still there)")
    p.add_argument("--take-rate", choices=("app", "clip"), default=None,
                   help="livelink: what the rows' timecodes count: app (default), frames of 30 "
                   "or 60 a second with thousandths, as the Live Link Face app writes them "
                   "(frame 1 of a 25 fps clip is 00:00:00:01.200): what Unreal's Live Link Face "
                   "importer reads right at every clip rate (it reads every take at 30 or 60 "
                   "fps); clip, the clip's own frames (a 25 fps clip's frame 1 is "
                   "00:00:00:01.000: frame for frame with a 24, 25 or 50 fps plate's timecode "
                   "in an editor). The same rows at 30 and 60 fps; `transfer --expression-from` "
                   "reads both")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def _start_timecode(args, track) -> tuple[str | None, str]:
    """The livelink take's first timecode (``--timecode``) and where it came from ("" for
    none)."""
    from ..export.livelink import source_timecode
    from ..io.video_display import checked_timecode

    if args.format != "livelink" or args.timecode == "none":
        return None, ""
    if args.timecode != "source":
        from ..errors import FaceTransferError
        from ..io.plate_header import exact_timecode

        try:
            return exact_timecode(checked_timecode(args.timecode), track.fps), "--timecode"
        except ValueError as exc:
            raise FaceTransferError(f"--timecode: {exc}") from None
    tc = source_timecode(track)
    return tc, (f"the start timecode of {track.source}" if tc else "")


def _lift(track, model, args):
    from tqdm import tqdm

    from ..export.gltf import lift_clip_texture

    with tqdm(total=(track.n_frames + args.texture_step - 1) // args.texture_step,
              desc="texture lift", unit="frame", disable=progress_disabled()) as bar:
        return lift_clip_texture(track, model, args.texture_from, step=args.texture_step,
                                 progress=bar.update)


def run(args: argparse.Namespace) -> int:
    from ..errors import FaceTransferError
    from ..export import export_track, format_of
    from ..io.atomic import check_output_path
    from ..track import Track

    if args.format is not None and args.format not in FORMATS:
        raise FaceTransferError(f"--format: unknown format {args.format!r}; choose one of "
                                f"{', '.join(FORMATS)}")
    if Path(args.out).is_dir():   # said as a folder, not as a name without an extension
        check_output_path(args.out)
    args.format = format_of(args.out, args.format)
    check_output_path(args.out, overwrite=args.overwrite,
                      inputs=(args.track, args.model, args.texture, args.texture_from))
    if args.texture and args.texture_from:
        raise FaceTransferError("give --texture or --texture-from, not both")
    if (args.texture or args.texture_from) and args.format != "glb":
        raise FaceTransferError(f"--texture/--texture-from: only glb files carry a texture, "
                                f"not {args.format}")
    if args.texture:                 # before the track is read: a square image, not a video
        from ..export.gltf import texture_image

        texture_image(args.texture).close()
    if args.timecode not in ("source", "none") and args.format != "livelink":
        raise FaceTransferError(
            f"--timecode {args.timecode}: a timecode of your own is written into livelink "
            f"takes only; {args.format} takes source (the tracked video's start timecode, "
            "recorded in the file) or none")
    if args.timecode not in ("source", "none"):     # its form, before the track is read
        from ..io.video_display import checked_timecode

        try:
            checked_timecode(args.timecode)
        except ValueError as exc:
            raise FaceTransferError(f"--timecode: {exc}") from None
    if args.take_rate is not None and args.format != "livelink":
        raise FaceTransferError(f"--take-rate {args.take_rate}: only livelink takes count "
                                f"their rows in timecodes, not {args.format}")
    args.texture_step = option_with(args.texture_step, 10, "--texture-step",
                                    args.texture_from, "--texture-from")
    if args.texture_step < 1:
        raise FaceTransferError(f"--texture-step must be >= 1, got {args.texture_step}")
    from ..take import is_take

    take = args.track if is_take(args.track) else None
    if args.neutral is not None:
        from ..export.neutral import neutral_arg

        neutral_arg(args.neutral)            # its word checked before a model is built
    if take is not None:
        track, model = _take_and_model(args)
    else:
        track, model = _track_and_model(Track.load(args.track), args)
    if args.timecode == "source" or track.lost.any():   # what the lines below say
        track = _clip_facts(track)
    if args.neutral is not None:
        from ..export.neutral import with_neutral

        # checked before a texture is lifted; a frame past a take's end named as the take's
        track = with_neutral(track, args.neutral, take=take)
    texture = args.texture
    if args.texture_from:
        from ..export.gltf import check_texture_video

        check_texture_video(track, args.texture_from)   # its one line, before any warning
        track.warn_other_video(args.texture_from,
                               "the texture is lifted through another face's motion")
        texture = _lift(track, model, args)
    timecode, said = _start_timecode(args, track)
    if args.format in ("usd", "glb", "json") and args.timecode == "source":
        timecode, said = "source", _source_said(track, args.format)
    path = export_track(track, args.format, args.out, model=model, overwrite=args.overwrite,
                        texture=texture, timecode=timecode, labels=args.take_rate)
    _say_written(args, track, path, timecode, said)
    return 0


def _take_and_model(args):
    """``(track, model)`` of a Live Link Face take: the model's (``--model``'s, else the
    default one's) mean person performing it with its head's rotation
    (:func:`facetransfer.take.take_track`, what ``puppet take.csv`` renders, the head turning
    in place: not moved to keep the face at the preview's centre); a take asked for as a take,
    or a texture lifted from a video it does not have, is one line."""
    from ..errors import FaceTransferError
    from ..take import take_track

    if args.format == "livelink":   # a Live Link file already: what it holds is said by probe
        raise FaceTransferError(f"{args.track} is a Live Link Face take already: export writes "
                                f"it as glb, usd or json; `facetransfer probe {args.track}` "
                                "describes the take")
    if args.texture_from:
        raise FaceTransferError(f"--texture-from lifts a tracked video's texture; {args.track} "
                                "is a take, of no video: give --texture TEX.png")
    from ..export.livelink import read_livelink

    if not len(read_livelink(args.track, lenient=True).timecodes):  # before a model is built
        raise FaceTransferError(f"the take {args.track} has no rows")
    model = resolve_model(args.model, progress=not args.no_progress)
    mean = model.weight_mean(model.mode_index("identity"))
    return take_track(args.track, model, mean, in_place=True), model


def _track_and_model(track, args):
    """``(track, model)``: the track with its activations (:func:`_activations` where it
    holds none) and ``--model``'s model, else the default model where the format needs the
    geometry (glb, usd), else None."""
    from ..export.common import require_activations

    model = None
    if args.model:
        from ..model import load_model

        model = load_model(args.model)
    if track.blendshapes is None:
        track, model = _activations(track, model, args)
    require_activations(track)
    if model is None and args.format in GEOMETRY_FORMATS:
        model = default_model_for(track)
    return track, model


def _activations(track, model, args):
    """``(track, model)``: a track without ARKit activations with them made from its
    expression weights (:func:`facetransfer.export.common.activations_from_weights`) with
    ``--model`` or the default model, and one line saying so; one line and exit status 2
    where they cannot be made."""
    from ..export.common import ExportError, activations_from_weights

    name = f"track {track.label}"
    if "expression" in track.weights and model is None:
        try:
            model = default_model_for(track)
        except ExportError:          # another model's track
            raise ExportError(f"{name} has no ARKit blendshape activations and was not made "
                              "with the default model (ict-arkit): give the model it was "
                              "tracked with (--model M.npz) to make them from its expression "
                              "weights") from None
    track = activations_from_weights(track, model)
    print(f"note: {name} holds no ARKit activations: made from its expression weights with "
          + (f"the model {args.model}" if args.model else "the default model (ict-arkit)"))
    return track, model


def _clip_facts(track):
    """The track with its clip's first frame number and start timecode, as it records them;
    an older track's read from its clip, if there, with a line saying where
    (:func:`facetransfer.export.common.with_clip_facts`)."""
    from ..export.common import with_clip_facts

    track, note = with_clip_facts(track)
    if note:
        print(f"note: {note}")
    return track


def _say_written(args, track, path, timecode, said: str) -> None:
    """The line of a written export (and a note of its lost frames)."""
    neutral = track.info.get("neutral_frame") if args.neutral is not None else None
    if neutral is not None:           # named as --neutral took it: a plate's by its number
        from ..io.frame_numbers import track_first_number

        neutral += track_first_number(track)
    if timecode and timecode != "source" and args.format == "livelink" \
            and _drop_frame(timecode, track.fps):
        said += f"; drop-frame: the rows count clock time, from {_first_row(path)}"
    rows = _rows_said(args, track)
    print(f"wrote {path}: {frame_count(track.n_frames)} ({args.format})"
          + (f", measured from the neutral frame {neutral}" if neutral is not None else "")
          + (f", from timecode {timecode} ({said})" if timecode and timecode != "source"
             else (f", {said}" if said else ""))
          + (f"; {rows}" if rows else ""))
    people = _identities(track) if args.format in GEOMETRY_FORMATS else 1
    if people > 1:
        print(f"note: the track's shots hold {people} people (a clip cut between them); the "
              "mesh is the first one's, the curves every shot's")
    note = lost_note(track, "their frames are left empty" if args.format == "json" else
                     "they hold the nearest tracked frame's values")
    if note:
        print(f"note: {note}")


def lost_note(track, held: str) -> str:
    """``"the face is lost in frames 68-104: <held>"``: the note of a track's lost frames (their
    runs, a plate's by its own numbers: 1001-1010, not 0-9), ``held`` saying what a result
    shows there; "" where no frame is lost. Said by ``track``, ``export`` and ``puppet``."""
    if not track.lost.any():
        return ""
    from ..export.usd import source_first_frame
    from ..io.frame_numbers import frames_said

    return f"the face is lost in {frames_said(track.lost, source_first_frame(track))}: {held}"


def _rows_said(args, track) -> str:
    """What a livelink take's rows count, where it differs from the clip's own frames (a clip
    at another rate than 30 or 60): the app's count (the default, what Unreal's Live Link Face
    importer reads right), or the clip's asked for, which that importer would misplace ("" at
    30 and 60 fps, for one row, and for other formats)."""
    from ..export.livelink import app_rate

    if args.format != "livelink":
        return ""
    rate, own = app_rate(track.fps), round(float(track.fps))
    if own == rate or track.n_frames < 2:    # the same rows either way; one row: at its time
        return ""
    if args.take_rate != "clip":
        return (f"rows counted at {rate} frames a second, as the Live Link Face app counts "
                f"them (--take-rate clip: the clip's own {own})")
    return (f"rows counted at the clip's {own} frames a second (Unreal's Live Link Face "
            f"importer counts 30 or 60 and would misplace them: for Unreal, the default "
            f"--take-rate app)")


def _drop_frame(timecode: str, fps: float) -> bool:
    """Whether ``timecode`` counts drop-frame at ``fps`` (``;`` or ``.`` at 29.97, 59.94)."""
    from ..io.plate_header import timecode_count

    try:
        return timecode_count(timecode, fps)[1]
    except ValueError:
        return False


def _first_row(path) -> str:
    """The timecode of a written take's first row (as an editor will read it)."""
    with open(path, encoding="utf-8") as fh:
        fh.readline()
        return fh.readline().split(",", 1)[0].strip()


def _source_said(track, fmt: str) -> str:
    """What a USD's time codes start from, where not 0 (:func:`facetransfer.export.usd.
    source_first_frame`), and the tracked video's start timecode the file records, if any."""
    from ..export.livelink import source_timecode
    from ..export.usd import source_first_frame

    first = source_first_frame(track) if fmt == "usd" else 0
    tc = source_timecode(track)
    said = [f"time codes from {first}, the first frame of {track.source}"] if first else []
    return ", ".join(said + ([f"the start timecode {tc} of {track.source} in its metadata"]
                             if tc else []))


def _identities(track) -> int:
    """How many identities a track's frames hold (one, save a clip edited from several
    people's shots: :mod:`facetransfer.track.shots`)."""
    import numpy as np

    w = track.weights.get("identity")
    return 1 if w is None or not len(w) else len(np.unique(np.asarray(w), axis=0))

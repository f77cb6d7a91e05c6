"""``facetransfer transfer``: the video rewrite of Vlasic et al. 2005, §6.

    facetransfer transfer --target T.mp4 [--target-track T.npz]
        (--expression-from S.mp4 [--source-track S.npz] [--viseme-from S2.mp4]
         | --identity-from V.mp4 | --identity-weights W | --identity-label L)
        [--pose-from P.mp4] [--model M.npz] [--align trim|loop|hold] [--max-frames N]
        [--mouth frame|function] [--codec h264|h265|prores] [--crf 18]
        [--meshes DIR] [--save-track OUT.npz] --out OUT.mp4|frames/%05d.png|OUT.png [--frame N]
        [--matte matte/%05d.png|matte/%05d.exr|M.mov|M.mkv...] [--overwrite]
    facetransfer transfer --target T.mp4 --target-track TRACK.npz --performance T2.npz ...
    facetransfer transfer --target portrait.jpg --expression-from S.mp4 --out OUT.mp4|OUT.png

A photo as the target performs its expression source: the video has the source's length, rate
and audio, the photo's head held (:func:`facetransfer.transfer_plan.held_frames`); a Live Link
Face take's rows at their rate (as ``view`` and ``puppet`` number them), no audio; one image
as ``--out`` is a one-frame result's frame, or ``--frame N``'s.

A performance edited first (``facetransfer edit``) is :mod:`.edit`'s; an identity performing a
video alone (``facetransfer puppet``) :mod:`.puppet`'s; the job on the default clips
(``facetransfer demo``, which takes this command's rewrite options) :mod:`.demo`'s.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
from pathlib import Path

from ..errors import FaceTransferError
from ..transfer import ALIGN_MODES
from ..rewrite_options import (BLEND_MODES, EYE_MODES, GAZE_MODES, JAW_MODES, LIP_COLOUR_MODES,
                               LIP_MODES, MOUTH_MODES, TEXTURE_MODES, RewriteOptions)
from ..track.presets import DEFAULT_SPEED, SPEED_PRESETS, TRACK_METHODS
from .common import (FACE_WHERE, MODEL_HELP, add_output, bar_factory, check_face,
                     check_landmarks_file, check_positive, check_track_name, frame_count,
                     resolve_model, start_tracker_loads, subcommand_parser, tracker_name,
                     video_options, video_out)
from .track import CAPTURE_HELP
from ..io.output_names import is_one_image

log = logging.getLogger(__name__)

ALIGN_HELP = ("how to fit a source of another length: trim (stop where the shorter ends), loop "
              "(repeat the source), hold (hold the source's last frame); default: trim when the "
              "source is at least as long as the target, hold when it is shorter (the output "
              "always has the target's frame rate)")


def add_rewrite_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``transfer`` and ``demo``: texture, blending and tracking (one
    definition; read back by :func:`rewrite_options`)."""
    p.add_argument("--texture", choices=TEXTURE_MODES, default="frame",
                   help="target face texture: lifted from each frame, or one for the clip")
    p.add_argument("--mouth", choices=MOUTH_MODES, default=None,
                   help="mouth texture (lips and mouth inside): frame (the mouth source's frame "
                   "at that time, warped through its tracked geometry) or function (the "
                   "texture function of §6: textures lifted from the mouth source's frames, "
                   "blended by nearest neighbours of the new expression/viseme weights; needs "
                   "a model with UVs); default: function with --performance, frame otherwise")
    p.add_argument("--blend", choices=BLEND_MODES, default="fast",
                   help="fast membrane blend, exact Poisson solve, or hard paste")
    p.add_argument("--eyes", choices=EYE_MODES, default="model",
                   help="model: the new performance's eyelids (blinks) rendered over an "
                   "open-eyed target frame; target: the target's own eyes show through the "
                   "mesh's eye holes, as in the paper")
    p.add_argument("--jaw", choices=JAW_MODES, default="closed",
                   help="closed: the chin and jaw skin textured from a target frame with the "
                   "mouth closed, so the target's own mouth opening does not show; frame: from "
                   "each target frame like the rest of the face")
    p.add_argument("--lips", choices=LIP_MODES, default="residual",
                   help="residual: the source's lips beyond what the model fits (the capture's "
                   "residual at the lip points): the mouth texture read where the source's lips "
                   "are detected and the new lips moved by it; model: the lips as fitted")
    p.add_argument("--lip-colour", choices=LIP_COLOUR_MODES, default="target",
                   help="target: the source's lips take the target's lip colour against its "
                   "skin (a target's lipstick stays); source: they keep the source's own, as "
                   "the paper pastes them (with --mouth frame)")
    p.add_argument("--gaze", choices=GAZE_MODES, default="performance",
                   help="performance: the eyes look where the new performance looks (its "
                   "eyeLook* activations); target: where the target looks in each of its own "
                   "frames (with --eyes model)")
    p.add_argument("--tracker", choices=TRACK_METHODS, default="auto", type=tracker_name,
                   help="tracking when no track file is given: auto or capture ("
                   + CAPTURE_HELP + "), flow (or klt, as track calls it: the optical-flow "
                   "tracker of §5, with --speed) or "
                   "landmarks (fitted to the clip's NAME.mediapipe478.npz points where it has "
                   "them, else to Face Landmarker's, detected frame by frame)")
    p.add_argument("--speed", choices=SPEED_PRESETS, default=DEFAULT_SPEED,
                   help="tracking preset when no track file is given: fast (the capture "
                   "tracker's detector shown every other frame of the target, every frame of "
                   "the sources; with --tracker flow one pass, two pyramid levels), balanced "
                   "(the detector on every frame; the flow tracker's defaults: two passes, "
                   "three levels) or quality (the capture tracker as balanced; the flow "
                   "tracker's three passes, for hard footage)")


#: What each source of a transfer is called where its lost face keeps target frames.
_ROLES = {"expression": "the expression source", "viseme": "the viseme source",
          "pose": "the pose source", "performance": "the performance"}


def _whose_lost(plan, first: int = 0, align: str | None = None) -> str:
    """``"the target's face is lost in frames 0-59"``, ``"the expression source's face is lost
    in frames 45-74"`` (both, joined by ``;``): why the frames a transfer keeps as they were
    (the new performance's lost ones, :func:`facetransfer.transfer.recombine`) are kept, and
    which, numbered as the result's frames are (from ``first``, :func:`_result_first`: a
    plate's rewrite by the plate's numbers, as a video too); a source's by its own numbers
    where they differ (:func:`_sources_lost`). Before, one clip's face lost for a second said
    ``face lost``, whose and where not; a plate's rewrite into a video, and a plate as the
    source, named its frames counted from 0."""
    import numpy as np

    from ..io.frame_numbers import frames_said

    new = np.asarray(plan.new_track.lost, bool)
    own = np.zeros_like(new)
    target = np.asarray(plan.target_track.lost, bool)[:len(new)]
    own[:len(target)] = target
    said = [f"the target's face is lost in {frames_said(own, first)}"] if own.any() else []
    others = new & ~own
    if others.any():
        said += _sources_lost(plan, others, first, align)
    return "; ".join(said) or "face lost"


def _sources_lost(plan, kept, first: int, align: str | None) -> list[str]:
    """Whose face (the performance's, or each source's) is lost in the result's frames where
    ``kept`` (n,) is True, and where: the result's frames numbered from ``first``; a source's
    also by its own numbers (a plate's as its files) where those name them otherwise
    (``"in its frames 1006-1008, the result's 4-6"``: a plate at another rate, or a result
    numbered otherwise)."""
    import numpy as np

    from ..io.frame_numbers import frame_runs, frames_said, track_first_number
    from ..transfer import source_frames_read, time_map

    if plan.performance:       # on the target's timeline, numbered as the result
        return [f"the performance's face is lost in {frames_said(kept, first)}"]
    said = []
    for role, tr in plan.source_tracks.items():
        if role not in _ROLES or tr is None or not np.asarray(tr.lost).any():
            continue
        tm = time_map(tr.n_frames, tr.fps, plan.target_track.n_frames, plan.fps, align=align)
        i0, i1 = (i[:len(kept)] for i in source_frames_read(tr, tm))
        mine = np.zeros_like(kept)
        mine[:len(i0)] = kept[:len(i0)] & (tr.lost[i0] | tr.lost[i1])
        if not mine.any():
            continue
        read = np.zeros(tr.n_frames, bool)
        read[np.r_[i0[mine[:len(i0)]], i1[mine[:len(i0)]]]] = True
        here, own = frame_runs(mine, first), frame_runs(read & tr.lost, track_first_number(tr))
        said.append(f"{_ROLES[role]}'s face is lost in {frames_said(mine, first)}"
                    if own == here else f"{_ROLES[role]}'s face is lost in its "
                    f"{frames_said(read & tr.lost, track_first_number(tr))}, the result's {here}")
    return said or [f"a source's face is lost in {frames_said(kept, first)}"]


def _result_first(out, target, first: int | None = None) -> int:
    """The number of the result's first frame, which its frames are named by: an output
    sequence's first (``--start-number``, else a plate target's own first number, else 0); a
    video's of a plate target, the plate's (its frames are the plate's, as the batch's mattes
    number them); else 0."""
    from ..io.frame_numbers import first_number
    from ..io.video import is_image_pattern

    if first is not None and is_image_pattern(out):
        return int(first)
    return first_number(target)


def _first_number(out, target, first: int | None = None) -> int | None:
    """The number of an output sequence's first frame: ``first`` (``--start-number``), else a
    plate's rewrite's, the plate's; None for a video."""
    from ..io.video import is_image_pattern
    from ..io.video_sequence import is_sequence

    if not is_image_pattern(out) or first is None and not is_sequence(target):
        return None
    return _result_first(out, target, first)


def _numbered(out, target, n: int, first: int | None = None) -> str:
    """How an output sequence is numbered: from ``first`` (``--start-number``), else a plate's
    rewrite as the plate; else ""."""
    first = _first_number(out, target, first)
    return "" if first is None else f" numbered {first}-{first + n - 1}"


def rewrite_options(args) -> RewriteOptions:
    """The :class:`~facetransfer.rewrite_options.RewriteOptions` of
    :func:`add_rewrite_options`' arguments."""
    return RewriteOptions(texture=args.texture, mouth=args.mouth, blend=args.blend,
                          speed=args.speed, track_method=args.tracker, eyes=args.eyes,
                          jaw=args.jaw, lips=args.lips, lip_colour=args.lip_colour,
                          gaze=args.gaze)


def register(sub) -> None:
    """Add ``transfer`` to the facetransfer parser."""
    p = subcommand_parser(
        sub, "transfer",
        "put expressions, visemes, identity or pose of other videos into target footage",
        "Video rewrite (Vlasic et al. 2005, §6, Fig. 1, Fig. 7): track the videos (or reuse "
        "track files), take each attribute from its chosen video, render the new face into "
        "the target footage with the target's texture and the source's mouth, blend, and keep "
        "the target's audio. A photo as the target performs the whole expression source (its "
        "length, rate and audio; a Live Link Face take's rows at their rate), the photo's "
        "head held. Interrupted (Ctrl-C, SIGTERM), it "
        "keeps its tracking and the frames it rendered in the user cache: the same command "
        "continues from them "
        "(FACETRANSFER_TRACK_CACHE=off, FACETRANSFER_RENDER_CACHE=off: nothing kept).")
    _add_sources(p)
    p.add_argument("--model", metavar="M.npz", help=MODEL_HELP)
    p.add_argument("--align", choices=ALIGN_MODES, default=None, help=ALIGN_HELP)
    # facetransfer.take.TAKE_SYNCS, spelt here: the parser imports no NumPy
    p.add_argument("--take-sync", choices=("timecode", "start"), default="timecode",
                   help="a Live Link Face take as --expression-from: placed by the target's "
                   "start timecode where the take's timecodes span it (clocks synced on set), "
                   "else from its first row (timecode, the default); or always from its first "
                   "row (start)")
    p.add_argument("--max-frames", type=int, default=None, help="use the first N target frames")
    p.add_argument("--frame", type=int, default=None, metavar="N",
                   help="with one image as --out (result.png, .jpg, .tif): write frame N of "
                   "the transfer (of a photo's, its expression source's frame N, or a take's "
                   "row N as `view take.csv` numbers it), numbered as the clip's frames: a "
                   "video's from 0, a plate's as its files (1001 on); default: a photo's first "
                   "frame, a one-frame clip's only one")
    add_rewrite_options(p)
    p.add_argument("--meshes", metavar="DIR", help="also write the new meshes as OBJ files")
    p.add_argument("--save-track", metavar="OUT.npz",
                   help="also write the new performance (marked as one: --performance, "
                   "export, view and puppet take it; not a track of the target: for a second "
                   "run leave --target-track out, the track cache keeps the target's track)")
    add_output(p, run_transfer, metavar="OUT.mp4", video=True,
                help="video to write (.mp4, .mov, .mkv...), image sequence (frames/%%05d.png) "
                "or one image (result.png, .jpg, .tif: a photo's or a one-frame clip's "
                "rewrite, or the frame --frame N)",
                overwrite_help="replace existing outputs")
    p.add_argument("--matte", metavar="MATTE", type=video_out,
                   help="also write the matte of the pixels the transfer changed, one grey "
                   "frame per output frame (0: the plate's own pixel, to the bit; 1: wholly "
                   "the new face; between on the feathered seam), numbered and timed as "
                   "--out: an image sequence, matte/%%05d.png or .tif (16-bit) or .exr "
                   "(float), or a video: .mov (PNG) or .mkv (FFV1), 16-bit grey, lossless; "
                   ".mp4: 8 bits in the output's codec, lossy (warned)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _add_sources(p) -> None:
    """``transfer``'s inputs: the target and, per attribute, a video and its track file."""
    p.add_argument("--target", required=True, metavar="T.mp4", help="footage to rewrite")
    p.add_argument("--target-track", metavar="T.npz",
                   help="track file of the target (reused): `facetransfer track T.mp4`'s, "
                   "not --save-track's performance")
    p.add_argument("--expression-from", metavar="S.mp4",
                   help="video whose expressions to use, or a Live Link Face take (S.csv: its "
                   "ARKit activations by its timecodes; the mouth's texture then comes from "
                   "the target)")
    p.add_argument("--source-track", metavar="S.npz", help="track file of --expression-from")
    p.add_argument("--viseme-from", metavar="S2.mp4",
                   help="video whose visemes to use (trilinear models)")
    p.add_argument("--viseme-track", metavar="S2.npz", help="track file of --viseme-from")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--identity-from", metavar="V.mp4", help="video whose identity to use")
    g.add_argument("--identity-weights", metavar="W",
                   help="identity weights, comma-separated numbers or a .npy file: "
                   "coordinates in the model's identity space (a training identity's row, a "
                   "track's identity), within 6 standard deviations of the training ones'")
    g.add_argument("--identity-label", metavar="L", help="a training identity of the model")
    p.add_argument("--identity-track", metavar="V.npz", help="track file of --identity-from")
    p.add_argument("--identity-dials", metavar="NAME=UNITS,...",
                   help="move the identity along semantic dials (`facetransfer model dials`), "
                   "e.g. width=+1.5,nose_length=-1; needs --identity-label, --identity-weights or "
                   "--target-track")
    p.add_argument("--pose-from", metavar="P.mp4",
                   help="video whose head pose to use (of another frame size or pixel "
                   "shape: its motion about the head's usual place, scaled by the heads' sizes)")
    p.add_argument("--pose-track", metavar="P.npz", help="track file of --pose-from")
    p.add_argument("--performance", metavar="NEW.npz",
                   help="render a ready performance on the target's timeline (e.g. the output "
                   "of `facetransfer edit`) instead of combining sources")
    for flag, role in (("--target-face", "in the target, the one to rewrite"),
                       ("--source-face", "in the source videos, the one to take")):
        p.add_argument(flag, metavar="WHERE", help=f"with several people {role}: {FACE_WHERE}")


def _prefetch_inputs(args):
    """The target and the expression source decoded on threads from now on, as the transfer
    will read them (:class:`facetransfer.io.prefetch.Prefetch`)."""
    from ..io.prefetch import Prefetch, frames_to_cover

    from ..take import is_take

    from ..io.video_sequence import is_still

    reads = [(args.target, args.max_frames)]
    if args.expression_from and not is_take(args.expression_from):
        reads.append((args.expression_from, args.max_frames if is_still(args.target) else
                      frames_to_cover(args.target, args.expression_from, args.max_frames)))
    return Prefetch(reads)


def run_transfer(args) -> int:
    vopt, to_track = _check_transfer_args(args)
    # decoded from now on, while the modules import and the model and MediaPipe load
    prefetch = _prefetch_inputs(args)
    loads = start_tracker_loads(to_track > 0 and args.tracker != "landmarks")
    try:
        from ..transfer_plan import TransferSources
        from ..video_transfer import transfer_video

        model = resolve_model(args.model, progress=not args.no_progress)
    finally:
        loads()
    sources = TransferSources.of(
        args.target, target_track=args.target_track, expression_from=args.expression_from,
        expression_track=args.source_track, viseme_from=args.viseme_from,
        viseme_track=args.viseme_track, identity=_chosen_identity(model, args),
        identity_from=args.identity_from, identity_track=args.identity_track,
        pose_from=args.pose_from, pose_track=args.pose_track, performance=args.performance,
        target_face=args.target_face, source_face=args.source_face,
        take_sync=args.take_sync)
    res = transfer_video(
        sources, args.out, model, options=rewrite_options(args),
        overwrite=args.overwrite, meshes_dir=args.meshes, save_track=args.save_track,
        progress_factory=bar_factory(), video_options=vopt,
        align=args.align, max_frames=args.max_frames, reader=prefetch.read_video,
        matte=args.matte, frame=args.frame)
    _say_transfer(args, res)
    return 0


def _say_transfer(args, res) -> None:
    """The lines of a written transfer: its frames numbered as the result's are (a plate's
    rewrite by the plate's numbers, :func:`_result_first`), a source's as its own."""
    from ..io.frame_numbers import track_first_number

    first = _result_first(args.out, args.target, args.start_number)
    if args.frame is not None or is_one_image(args.out):
        print(f"wrote {res.path}: one image, frame {getattr(args, 'frame_said', 0)} of the "
              "transfer"
              + (" (kept original: the face is lost there)" if not res.n_rewritten else ""))
        _said_also(args, 1)
        return
    kept = res.n_frames - res.n_rewritten
    for tr in res.plan.source_tracks.values():
        if tr is not None and tr.info.get("resumed"):
            print(f"continued an interrupted tracking of {tr.source} from frame "
                  f"{track_first_number(tr) + tr.info['resumed']['frame']}")
    if res.resumed:
        print(f"continued an interrupted render from frame {first + res.resumed}")
    print(f"wrote {res.path}: {frame_count(res.n_frames)}" + _numbered(args.out, args.target,
                                                              res.n_frames, args.start_number)
          + (f" ({kept} kept original: {_whose_lost(res.plan, first, args.align)})"
             if kept else "")
          + (f", {res.kept}" if res.kept else "")
          + ((", with the expression source's audio" if _held(args) else
              ", with the target's audio") if res.audio else
             ", no audio (a take has none)" if _take_on_photo(args) else ", no audio"))
    if args.matte:
        print(f"wrote the matte {args.matte}"
              + _numbered(args.matte, args.target, res.n_frames, args.start_number))
    _said_also(args, res.n_frames)


def _said_also(args, n_frames: int) -> None:
    """The lines of the track and meshes a transfer also wrote."""
    if args.save_track:
        print(f"wrote {args.save_track}")
    if args.meshes:
        print(f"wrote {n_frames} meshes to {args.meshes}")


def _held(args) -> bool:
    """Whether the target is a photo held over the expression source's frames (a video of
    the photo performing the source, with the source's audio:
    :func:`facetransfer.transfer_plan.held_frames`)."""
    from ..io.video_sequence import is_still
    from ..take import is_take

    return bool(is_still(args.target) and args.expression_from
                and not is_take(args.expression_from))


def _take_on_photo(args) -> bool:
    """Whether a photo target performs a Live Link Face take (its rows at their rate, the
    photo's head held, no audio: :func:`facetransfer.transfer_plan.performance_length`)."""
    from ..io.video_sequence import is_still
    from ..take import is_take

    return bool(is_still(args.target) and is_take(args.expression_from))


def _check_option_pairs(args) -> None:
    """Options that act only with another's value, given with another: ``--gaze target`` with
    the target's own eyes, ``--lip-colour source`` with the mouth's texture function (each
    would be ignored in silence)."""
    for flag, value, default, need, said in (
            ("--gaze", args.gaze, "performance", "--eyes", "model"),
            ("--lip-colour", args.lip_colour, "target", "--mouth", "frame")):
        other = getattr(args, need[2:])
        if value != default and other not in (None, said):
            raise FaceTransferError(f"{flag} {value} acts with {need} {said}, not {need} "
                                    f"{other}: give one of them")


def _check_transfer_outputs(args, inputs: list):
    """The outputs of ``transfer`` checked (``--out``, ``--matte``, ``--meshes``,
    ``--save-track``), none of them one of ``inputs``; the output's video options
    (``--start-number``: of whichever of ``--out`` and ``--matte`` is a sequence)."""
    from ..io.atomic import check_output_path
    from ..io.video import check_video_output, is_image_pattern

    vopt = video_options(args, next((o for o in (args.out, args.matte)
                                     if o and is_image_pattern(o)), args.out))
    if is_one_image(args.out) or args.frame is not None:
        _check_one_image(args, inputs)
    else:
        check_video_output(args.out, vopt, overwrite=args.overwrite, inputs=inputs)
    if args.matte:
        from ..io.matte import check_matte_output

        check_matte_output(args.matte, out=args.out, options=vopt, overwrite=args.overwrite,
                           inputs=inputs + [args.save_track, args.meshes])
    if args.meshes:
        from ..io.output_names import check_meshes_folder

        check_meshes_folder(args.meshes, overwrite=args.overwrite)
    if args.save_track:
        check_track_name(args.save_track, "--save-track")
        check_output_path(args.save_track, overwrite=args.overwrite, inputs=inputs + [args.out])
    return vopt


def _check_one_image(args, inputs: list) -> None:
    """``--out result.png`` (one image) and ``--frame N``, checked before any work: the
    transfer has that frame (without ``--frame``, one frame: a photo with no expression
    source, a clip of one frame); one line otherwise."""
    from ..io.frame_numbers import first_number, frame_span
    from ..io.output_names import check_one_image
    from ..io.video_sequence import is_still

    out, frame = args.out, args.frame
    if not is_one_image(out):
        raise FaceTransferError(f"--frame {frame} chooses the frame of one image as --out "
                                f"(result.png), not of {out}: for the first N frames give "
                                "--max-frames N")
    if args.matte:
        raise FaceTransferError(f"--matte {args.matte} is written beside a video or an image "
                                f"sequence, not beside the one image --out {out}")
    check_one_image(out, overwrite=args.overwrite, inputs=inputs)
    clip = args.expression_from if _held(args) else args.target
    n, whose = _one_image_count(args, clip)
    first = first_number(clip)     # a plate's frames by their numbers (1001 on), else from 0
    span = f"numbered {frame_span(first, n)} as the plate's files" if first else \
        frame_span(first, n)
    p = Path(out)
    seq = p.with_name(f"{p.stem}_%05d{p.suffix}")
    if frame is None and (_held(args) or n > 1 and is_still(args.target)):
        frame = args.frame = first     # a photo's rewrite: its first frame (the source's)
    if frame is None and n > 1:
        raise FaceTransferError(f"--out {out} is one image, but the transfer has {n} frames "
                                f"({whose}): choose one with --frame N ({span}), or write "
                                f"them all as {seq} or a video (.mp4)")
    if frame is not None and not 0 <= frame - first < n:
        raise FaceTransferError(f"--frame {frame}: the transfer has {n} frame"
                                f"{'s' if n != 1 else ''} ({whose}), {span}")
    args.frame_said = first if frame is None else frame     # the number, as the user knows it
    if frame is not None:
        args.frame = frame - first                          # the row the library renders


def _one_image_count(args, clip) -> tuple[int, str]:
    """How many frames the transfer has (of a photo target, its expression source's, or its
    ready performance's: :func:`facetransfer.transfer_plan.performance_length`), and whose."""
    from ..io.video import video_info
    from ..io.video_sequence import is_still
    from ..transfer_plan import performance_length

    held = performance_length(args.performance, args.max_frames) \
        if args.performance and is_still(args.target) else None
    if held is not None:
        return held[0], f"the performance {args.performance}'s"
    if _take_on_photo(args):
        from ..take import take_length

        _check_take(args)                 # its own lines first (a missing take, a bad one)
        n = take_length(args.expression_from, args.max_frames, warn=False)[0]
        return n, f"the take {args.expression_from}'s rows"
    n = video_info(clip).n_frames
    n = n if args.max_frames is None else min(n, args.max_frames)
    return n, (f"the expression source {clip}'s" if clip != args.target
               else f"the target {clip}'s")


def _check_transfer_args(args):
    """The arguments' one-line errors, the outputs and every input video checked before any
    work; ``(video options, how many videos are to be tracked)``."""
    from ..io.video import video_info

    check_positive(args.max_frames, "--max-frames")
    if not (args.expression_from or args.viseme_from or args.identity_from
            or args.identity_weights or args.identity_label or args.pose_from
            or args.performance or args.identity_dials):
        raise FaceTransferError("nothing to transfer: give --expression-from, --viseme-from, "
                                "--identity-from/--identity-weights/--identity-label, "
                                "--pose-from or --performance")
    for flag, dep, name in ((args.source_track, args.expression_from, "--source-track"),
                            (args.viseme_track, args.viseme_from, "--viseme-track"),
                            (args.identity_track, args.identity_from, "--identity-track"),
                            (args.pose_track, args.pose_from, "--pose-track")):
        if flag and not dep:
            raise FaceTransferError(f"{name} needs the video it belongs to")
    inputs = [args.target, args.target_track, args.expression_from, args.source_track,
              args.viseme_from, args.viseme_track, args.identity_from, args.identity_track,
              args.pose_from, args.pose_track, args.performance, args.model,
              args.identity_weights if args.identity_weights and
              args.identity_weights.endswith(".npy") else None]
    from ..take import is_take

    vopt = _check_transfer_outputs(args, inputs)   # first: a bad one is the only line said
    _probe_at_once([v for v in (args.target, args.expression_from, args.viseme_from,
                                args.identity_from, args.pose_from) if v and not is_take(v)])

    if is_take(args.expression_from):
        _check_take(args)
    if args.performance and is_take(args.performance):
        raise FaceTransferError(f"--performance {args.performance} is a Live Link Face take: "
                                f"give it as --expression-from {args.performance} (a "
                                "performance is a track file, TRACK.npz)")
    to_track = 0
    _check_option_pairs(args)
    for face, flag, track, tflag, role in (
            (args.target_face, "--target-face", args.target_track, "--target-track", "rewritten"),
            (args.source_face, "--source-face", args.source_track, "--source-track", "used")):
        if face and track:
            raise FaceTransferError(f"{flag} chooses the face to track, but {tflag} {track} is "
                                    f"tracked already (its face is the one {role}): give one "
                                    "of them")
    for k, (v, tr) in enumerate(((args.target, args.target_track),
                                 (args.expression_from, args.source_track),
                                 (args.viseme_from, args.viseme_track),
                                 (args.identity_from, args.identity_track),
                                 (args.pose_from, args.pose_track))):
        if v and k == 1 and is_take(v):
            continue                # read by _check_take; nothing to track
        if v:
            video_info(v)  # unreadable input: one line, before any work
            if not tr and not (v == args.target and args.performance):
                check_landmarks_file(v, args.tracker)
                check_face(*((args.target_face, v, "--target-face") if k == 0 else
                             (args.source_face, v, "--source-face")), args.tracker)
                to_track += 1
    return vopt, to_track


def _probe_at_once(videos) -> None:
    """Each video's :func:`facetransfer.io.video.video_info` asked at once, on threads: each
    is ffprobe run twice as a process (its description and its packets' times, 0.03-0.08 s of
    waiting each), which the transfer's checks and reads then find kept per file; asked one
    after the other they delayed the decoding, and so the tracking, by 0.1 s of a 10-second
    512² transfer. Errors are left to the checks that follow (the same call, in order)."""
    from concurrent.futures import ThreadPoolExecutor

    from ..io.video import video_info

    def probe(v):
        with contextlib.suppress(Exception):
            video_info(v)

    if len(videos) > 1:
        with ThreadPoolExecutor(max_workers=len(videos), thread_name_prefix="probe") as pool:
            list(pool.map(probe, videos))


def _check_take(args) -> None:
    """A Live Link Face take given as ``--expression-from``: readable, with rising timecodes,
    and not combined with what it cannot be (one line each, before any work)."""
    from ..export.common import ExportError
    from ..export.livelink import read_livelink
    from ..take import take_seconds

    path = args.expression_from
    for flag, given in (("--source-track", args.source_track), ("--viseme-from", args.viseme_from),
                        ("--identity-from", args.identity_from), ("--pose-from", args.pose_from),
                        ("--performance", args.performance),
                        ("--identity-weights", args.identity_weights),
                        ("--identity-label", args.identity_label),
                        ("--identity-dials", args.identity_dials),
                        ("--source-face", args.source_face)):
        if given:
            raise FaceTransferError(f"--expression-from {path} is a Live Link Face take, which "
                                    f"drives the target alone: {flag} cannot be added")
    if not Path(path).is_file():
        raise FaceTransferError(f"--expression-from {path} does not exist")
    try:
        take = read_livelink(path, lenient=True)
    except (ExportError, UnicodeDecodeError) as exc:
        raise FaceTransferError(f"--expression-from {path}: {exc}") from None
    if not take.timecodes:
        raise FaceTransferError(f"--expression-from {path}: the take has no rows")
    take_seconds(take.timecodes, warn=False, name=f"take {path}")


def _chosen_identity(model, args):
    """The identity weights of ``--identity-label`` / ``--identity-weights``, with
    ``--identity-dials`` applied; None: from the tracks."""
    from ..transfer import check_identity_weights, identity_from_label, parse_weights

    identity = None
    if args.identity_label:
        identity = identity_from_label(model, args.identity_label)
    elif args.identity_weights:
        identity = parse_weights(args.identity_weights,
                                 model.ranks[model.mode_index(model.identity_mode)])
        check_identity_weights(model, identity)
    if args.identity_dials:
        identity = _dialled_identity(model, identity, args)
    return identity


def _dialled_identity(model, identity, args):
    """``--identity-dials`` applied to the chosen identity (or the target track's)."""
    from ..dials import learn_dials, parse_dial_values
    from ..track import Track
    from ..transfer import constant_weights

    values = parse_dial_values(args.identity_dials)
    dials = learn_dials(model)
    for name in values:
        dials.get(name)
    bad = dials.unreliable(values)
    if bad:
        log.warning("--identity-dials %s: leave-one-out R2 <= 0 on this model (too few "
                    "identities): the face moves along a direction that does not measure what "
                    "the name says", ", ".join(bad))
    if identity is None:
        if not args.target_track or args.identity_from:
            raise FaceTransferError("--identity-dials needs the identity to move: "
                                    "--identity-label, --identity-weights or the target's "
                                    "(--target-track); not --identity-from")
        tt = Track.load(args.target_track)
        tt.check_model(model)
        identity = constant_weights(tt, dials.mode)
    return dials.apply(identity, values)


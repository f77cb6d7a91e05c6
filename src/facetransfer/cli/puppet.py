"""``facetransfer puppet``: an identity of the model performing a video, a take or a track
(puppetry: the abstract of Vlasic et al. 2005, §8 performance animation), rendered alone.

    facetransfer puppet VIDEO [--model M.npz] --identity LABEL --out OUT.mp4
    facetransfer puppet TAKE.csv --identity LABEL --out OUT.mp4
    facetransfer puppet TRACK.npz [--model M.npz] --out OUT.mp4

The video is tracked (or its ``--track`` reused) as ``transfer`` tracks its sources; the render
is :func:`facetransfer.puppet_video.puppet_video`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from ..errors import FaceTransferError
from ..track.presets import TRACK_METHODS
from .common import (FACE_WHERE, MODEL_HELP, add_output, bar_factory, check_face,
                     check_landmarks_file, check_positive, check_track_of, default_model_for,
                     frame_count, load_model_and_mediapipe, resolve_model, subcommand_parser,
                     tracker_name, video_options)

log = logging.getLogger(__name__)


def register(sub) -> None:
    """Add ``puppet`` to the facetransfer parser."""
    q = subcommand_parser(
        sub, "puppet", "drive a model identity from a video (puppetry)",
        "Track a video (or reuse its track) and render an identity of the model performing "
        "it, alone on a plain background (Vlasic et al. 2005, §5). A Live Link Face take "
        "(TAKE.csv) instead of a video: the identity performs its ARKit curves with its "
        "head's rotation (a preview of the take). A track file (TRACK.npz) instead: its "
        "performance, at its clip's size and rate, with that clip's audio if it is still there "
        "(and is that clip: of the track's size, at least its frames).")
    q.add_argument("video", metavar="VIDEO", help="the video to track, or a Live Link Face take "
                   "(TAKE.csv) or a track file (TRACK.npz)")
    q.add_argument("--model", metavar="M.npz", help=MODEL_HELP)
    q.add_argument("--identity", metavar="LABEL", help="training identity label (default: the "
                   "model's mean face)")
    q.add_argument("--track", metavar="TRACK.npz", help="track file of VIDEO (reused); a track "
                   "file alone as VIDEO is rendered at its frame size and rate")
    q.add_argument("--max-frames", type=int, default=None, help="use the first N frames")
    q.add_argument("--tracker", choices=TRACK_METHODS, default="auto", type=tracker_name,
                   help="tracking when no track file is given (flow or klt: the optical-flow "
                   "tracker)")
    q.add_argument("--face", metavar="WHERE",
                   help=f"with several people, the one whose performance drives the puppet: "
                   f"{FACE_WHERE}")
    add_output(q, run_puppet, metavar="OUT.mp4", video=True, carries_target=False,
                help="video (.mp4...) or image sequence (frames/%%05d.png)")


def _puppet_identity(model, label: str | None):
    """The puppet's identity weights ``(r,)``: the training identity ``label``, or the model's
    mean face where none is named."""
    from ..transfer import identity_from_label

    return model.weight_mean("identity") if label is None else identity_from_label(model, label)


def run_puppet(args) -> int:
    from ..io.video import check_video_output, read_video, video_info
    from ..io.video_like import like_video
    from ..track.obtain import done_tracking, obtain_track
    from ..track.video_detect import default_workers
    from ..puppet_video import puppet_video

    from ..take import is_take

    check_positive(args.max_frames, "--max-frames")
    vopt = video_options(args, args.out)
    check_video_output(args.out, vopt, overwrite=args.overwrite,
                       inputs=[args.video, args.model, args.track])
    if is_take(args.video):
        return _puppet_take(args, vopt)
    if Path(args.video).suffix.lower() == ".npz":
        return _puppet_track(args, vopt)
    video_info(args.video)
    if args.track and args.tracker != "auto":   # it was ignored
        raise FaceTransferError(f"--tracker {args.tracker} chooses how VIDEO is tracked, but "
                                f"--track {args.track} is tracked already: give one of them")
    if not args.track:
        check_landmarks_file(args.video, args.tracker)
        check_face(args.face, args.video, tracker=args.tracker)
    model = load_model_and_mediapipe(args.model,
                                     not args.track and args.tracker != "landmarks")
    wid = _puppet_identity(model, args.identity)
    frames, fps = read_video(args.video, max_frames=args.max_frames)
    track = obtain_track(args.video, model, frames=frames, fps=fps, track_file=args.track,
                         max_frames=len(frames), method=args.tracker,
                         progress_factory=bar_factory(), workers=default_workers(),
                         face=args.face)
    if args.track:   # a track of another video would drive the face with the wrong motion
        check_track_of(track, args.track, args.video, len(frames),
                       (frames.shape[2], frames.shape[1]), "to drive the puppet for those")
        track.warn_other_video(args.video, "the puppet does not move with this video's audio")
    if track.lost.all():
        raise FaceTransferError(f"no face found in {args.video}")
    frames = None
    done_tracking()                     # the capture's points: not needed in the render
    vopt = like_video(vopt, args.video)       # a plate's: its first number, as the result's
    audio, resumed = puppet_video(track, model, wid, args.out, video_options=vopt,
                                  audio_from=args.video, overwrite=args.overwrite,
                                  progress_factory=bar_factory())
    _say_resumed(resumed, vopt)
    print(f"wrote {args.out}: {frame_count(track.n_frames)} of "
          f"{args.identity or 'the mean face'}"
          + (", with the video's audio" if audio else ""))
    _say_lost(track)
    return 0


def _say_resumed(resumed: int, vopt) -> None:
    """The line of a render continued from frame ``resumed`` (0-based), numbered as the
    result's frames are (``vopt.first_number``: a plate's, or ``--start-number``)."""
    if resumed:
        print(f"continued an interrupted render from frame "
              f"{(vopt.first_number or 0) + resumed}")


def _say_lost(track) -> None:
    """The note ``export`` prints of the frames where ``track`` lost the face, which the puppet
    shows as its nearest tracked frame (:func:`facetransfer.puppet_video.puppet_frames`)."""
    from .export import lost_note

    note = lost_note(track, "the puppet holds the nearest tracked frame's head there")
    if note:
        print(f"note: {note}")


def _puppet_track(args, vopt) -> int:
    """``puppet TRACK.npz``: the identity performing a track file with no video beside it, at
    the track's frame size and rate (its pixels' aspect and its clip's start timecode kept);
    where the clip it was tracked from is still there (:func:`_track_clip`), as ``puppet
    VIDEO --track`` writes it: that clip's audio, pixels' aspect, colour and numbering."""
    import numpy as np

    from ..io.video import check_video_output
    from ..io.video_like import like_video
    from ..puppet_video import puppet_video
    from ..track.project import take_frames
    from ..track.result import Track

    for flag, given in (("--track", args.track), ("--face", args.face),
                        ("--tracker", args.tracker != "auto")):
        if given:
            raise FaceTransferError(f"{args.video} is a track file: {flag} is for a video")
    if not Path(args.video).is_file():
        raise FaceTransferError(f"track {args.video} does not exist")
    track = Track.load(args.video)
    model = (resolve_model(args.model, progress=not args.no_progress) if args.model
             else default_model_for(track))
    track.check_model(model)
    if args.max_frames is not None and args.max_frames < track.n_frames:
        track = take_frames(track, np.arange(args.max_frames))
    if track.lost.all():
        raise FaceTransferError(f"track {args.video} has no frame with a face")
    clip = _track_clip(track)
    if clip is not None:   # its audio is read: not replaced by the puppet (as puppet VIDEO)
        check_video_output(args.out, vopt, overwrite=args.overwrite, inputs=[clip])
    vopt = _track_video_options(vopt if clip is None else like_video(vopt, clip), track)
    audio_from = Path(clip) if clip is not None and Path(clip).is_file() else None  # no sequence
    wid = _puppet_identity(model, args.identity)
    audio, resumed = puppet_video(track, model, wid, args.out, video_options=vopt,
                                  audio_from=audio_from, overwrite=args.overwrite,
                                  progress_factory=bar_factory())
    _say_resumed(resumed, vopt)
    print(f"wrote {args.out}: {frame_count(track.n_frames)} of "
          f"{args.identity or 'the mean face'} performing the track {args.video}"
          + (f", with the audio of {audio_from.name}" if audio else ""))
    _say_lost(track)
    return 0


def _track_clip(track) -> str | None:
    """The clip ``track`` was made from (its ``source``: a video file or an image sequence's
    pattern) where it is still there and is that clip: frames of the track's size, at least as
    many as the track's (a track of its first frames, ``track --max-frames``), a video file's
    at its rate (a sequence's is a setting, ``--sequence-fps``); else None, said in the log
    where a clip of another size, rate or length has taken its place (its audio is not the
    performance's)."""
    from ..io.video import VideoError, video_info
    from ..io.video_sequence import is_sequence

    source = track.source
    if not source or not (Path(source).is_file() or is_sequence(source)):
        return None
    try:
        info = video_info(source)
    except (VideoError, OSError, ValueError):
        return None
    rate = is_sequence(source) or abs(info.fps - track.fps) < 1e-3
    if tuple(info.size) == tuple(track.frame_size) and rate and info.n_frames >= track.n_frames:
        return str(source)
    log.warning("track %s was made from %s, which is now %d frames of %dx%d at %g fps, the "
                "track %d of %dx%d at %g fps: another clip; its audio, timecode and pixels' "
                "aspect are not used", track.label, source, info.n_frames, *info.size, info.fps,
                track.n_frames, *track.frame_size, track.fps)
    return None


def _track_video_options(vopt, track):
    """``vopt`` for a puppet of ``track`` alone: its pixels' aspect and its clip's start
    timecode and first frame number (:attr:`Track.source_facts`) where ``vopt`` gives none."""
    import dataclasses

    from ..io.plate_header import usable_aspect

    changes = {}
    sar = usable_aspect(track.pixel_aspect)     # None where square
    if vopt.sar is None and sar is not None:
        changes["sar"] = sar
    facts = track.source_facts
    if facts is not None and vopt.timecode is None and facts.timecode:
        changes["timecode"] = facts.timecode
    if facts is not None and vopt.first_number is None and facts.first_frame:
        changes["first_number"] = facts.first_frame
    return dataclasses.replace(vopt, **changes) if changes else vopt


def _puppet_take(args, vopt) -> int:
    """``puppet take.csv``: the identity performing a Live Link Face take, with its head's
    rotation (:func:`facetransfer.take.take_track`), on a plain background."""
    from ..puppet_video import puppet_video
    from ..take import PREVIEW_SIZE, take_track

    for flag, given in (("--track", args.track), ("--face", args.face),
                        ("--tracker", args.tracker != "auto")):
        if given:
            raise FaceTransferError(f"{args.video} is a Live Link Face take: {flag} is for a "
                                    "video")
    if not Path(args.video).is_file():
        raise FaceTransferError(f"take {args.video} does not exist")
    model = resolve_model(args.model, progress=not args.no_progress)
    wid = _puppet_identity(model, args.identity)
    track = take_track(args.video, model, wid, max_frames=args.max_frames)
    if vopt.timecode is None:   # the take's own start, as a video's result keeps its
        import dataclasses

        vopt = dataclasses.replace(vopt, timecode=track.info.get("start_timecode"))
    _, resumed = puppet_video(track, model, wid, args.out, video_options=vopt,
                              overwrite=args.overwrite, progress_factory=bar_factory())
    _say_resumed(resumed, vopt)
    print(f"wrote {args.out}: {frame_count(track.n_frames)} of "
          f"{args.identity or 'the mean face'} performing the "
          f"take {args.video} ({track.fps:g} fps, {PREVIEW_SIZE[0]}x{PREVIEW_SIZE[1]})")
    return 0

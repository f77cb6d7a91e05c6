"""``facetransfer track``: track a face through a video with a multilinear model (§5).

    facetransfer track VIDEO.mp4 [--model MODEL.npz] --out TRACK.npz [--init auto|POINTS.json]
                       [--passes N] [--anchor] [--max-frames N] [--overlay OVERLAY.mp4]
                       [--codec h264|h265|prores] [--crf 18]
    facetransfer track VIDEO.mp4 [--model MODEL.npz] --from-track TRACK.npz --overlay OVERLAY.mp4

Without ``--model`` the default model is used (:mod:`facetransfer.default_model`).

``TRACK.npz`` holds per frame the weak-perspective pose, the weights of every mode, the 68
landmarks in pixels, a confidence and a lost flag (see :mod:`facetransfer.track.result`).
"""

from __future__ import annotations

import argparse
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from ..errors import FaceTransferError
from ..io.atomic import check_not_input, check_output_path
from .common import (FACE_WHERE, MODEL_HELP, DefaultsFormatter, add_video_options, check_face,
                     check_track_name, check_track_of, frame_count, number_in,
                     progress_disabled, resolve_model, video_options, video_out)


#: What the capture tracker does, for the help of every ``--tracker`` option.
CAPTURE_HELP = "the model fitted to MediaPipe's landmarks and their optical flow on every frame"


def partial_path(out) -> Path:
    """Where ``track --out OUT`` keeps the progress of an unfinished run."""
    p = Path(out)
    return p.with_name(p.stem + ".partial.npz")


def add_track_options(p) -> None:
    """The options that shape a track (``track`` and ``batch track``; defaults from the
    option classes)."""
    from ..track.options import TrackOptions

    d = TrackOptions()
    p.add_argument("--tracker", choices=("capture", "klt"), default=None,
                   type=lambda v: {"flow": "klt"}.get(v, v),   # transfer's name for it
                   help="default capture (klt when --init gives points): capture: "
                   + CAPTURE_HELP + ", identity from the whole clip, ARKit activations "
                   "(facetransfer.track.capture); klt (or flow, as transfer calls it): the "
                   "paper's model-based optical-flow tracker from the first frame (the options "
                   "marked [klt])")
    p.add_argument("--init", default="auto",
                   help='[klt] first-frame feature points: "auto" (MediaPipe) or a JSON file '
                   '{"points": {"36": [x, y], ...}} keyed by iBUG-68 number')
    p.add_argument("--passes", type=number_in(1, 100, integer=True), default=d.passes,
                   help="[klt] passes through the video")
    p.add_argument("--anchor", action="store_true",
                   help="[klt] add detected landmarks of every frame as an extra term (less "
                   "drift)")
    p.add_argument("--keyframe", type=number_in(0, 1e6), default=d.keyframe,
                   help="[klt] weight of the KLT term against the first frame (less drift; 0 = "
                   "the paper's frame-to-frame tracking only)")
    p.add_argument("--smooth", type=number_in(0, 1000), default=d.smooth,
                   help="zero-phase smoothing of pose and weights, sigma in frames (0 = off)")
    p.add_argument("--points", type=number_in(1, 1_000_000, integer=True), default=d.n_points,
                   help="[klt] tracked vertices per frame")
    p.add_argument("--scores", action=argparse.BooleanOptionalAction, default=True,
                   help="[capture] a second pass that reads Face Landmarker's own blendshape "
                   "scores of the jaw, lips and blinks (facetransfer.track.scores); "
                   "--no-scores: the landmarks and their flow only (a track that does not "
                   "depend on its blendshape model)")
    p.add_argument("--occluders", action=argparse.BooleanOptionalAction, default=False,
                   help="test each frame for a hand, a microphone or glasses over the mouth or "
                   "the eyes, and bridge that region's activations over the frames it is "
                   "covered (facetransfer.track.occlusion; the clip is read once more)")


def track_settings(args):
    """:class:`~facetransfer.track.settings.TrackerSettings` from :func:`add_track_options`'s
    arguments (validated)."""
    from ..track.capture import CaptureOptions
    from ..track.settings import TrackerSettings
    from ..track.options import TrackOptions

    klt = TrackOptions(passes=args.passes, anchor=args.anchor, smooth=args.smooth,
                       n_points=args.points, keyframe=args.keyframe)
    scores = CaptureOptions().scores if args.scores else 0.0
    return TrackerSettings(args.tracker, klt, CaptureOptions(smooth=args.smooth, scores=scores))


def register(sub) -> None:
    """Add ``track`` to the facetransfer parser."""
    p = sub.add_parser(
        "track", help="track a face in a video: pose and model weights per frame (§5)",
        description="Track a face through a video with a multilinear model (Vlasic et al. "
        "2005, §5.1-5.2): per frame the head pose and the weights of every mode, the identity "
        "once for the clip.", formatter_class=DefaultsFormatter)
    p.add_argument("video", metavar="VIDEO", help="input video")
    p.add_argument("--model", help=MODEL_HELP + " (with landmarks)")
    p.add_argument("--out", help="track file to write (.npz); needed unless --from-track "
                   "names the track an --overlay is drawn from")
    add_track_options(p)
    p.add_argument("--max-frames", type=int, default=None, help="track only the first N frames")
    p.add_argument("--workers", type=int, default=None,
                   help="[capture] processes that run Face Landmarker, each on its own part of "
                   "the clip (facetransfer.track.video_detect); default: 2 on a machine with two "
                   "or more CPUs, for a clip with at least 200 frames left to detect")
    p.add_argument("--overlay", type=video_out,
                   help="also write a video with the fitted mesh drawn (.mp4, or an image "
                   "sequence frames/%%05d.png or frames/#####.png)")
    add_video_options(p, what="--overlay", flag="--overlay", carries_target=False)
    p.add_argument("--face", metavar="WHERE",
                   help="[capture] with several people in the frame, the one to track: "
                   + FACE_WHERE)
    p.add_argument("--restart", action="store_true",
                   help="ignore the progress of an interrupted run (OUT with suffix "
                   ".partial.npz; by default tracking continues from it)")
    p.add_argument("--from-track", dest="from_track",
                   help="draw --overlay from an existing track file instead of tracking "
                   "(with --max-frames N: the clip's and the track's first N frames)")
    p.add_argument("--overwrite", action=argparse.BooleanOptionalAction, default=False,
                   help="replace existing outputs (an output is never one of the inputs)")
    p.set_defaults(func=run)


def _bar(desc: str, total: int):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", leave=False, dynamic_ncols=True,
                disable=progress_disabled())


def run(args) -> int:
    from ..io.video import video_info
    from ..track.result import Track
    from ..track.frames import frame_source

    vopt = _check_outputs(args)
    settings = track_settings(args)                                   # validates the options
    tracker = settings.choose(args.init)
    video_info(args.video)  # unreadable / empty video: one line, before any work
    if args.face is not None and args.from_track is None:
        if tracker != "capture":
            raise FaceTransferError(f"--face is for the capture tracker (--tracker capture, or "
                                    f"auto without --init points), not the {tracker} tracker, "
                                    "which follows the face found first")
        check_face(args.face, args.video)
    model = _model_meanwhile(args, tracker)
    if args.from_track is not None:
        track = Track.load(args.from_track)
        frames = frame_source(args.video, args.max_frames)
        if args.max_frames is not None and frames.n < track.n_frames:
            import numpy as np

            from ..track.project import take_frames     # the first N, as puppet and transfer

            track = take_frames(track, np.arange(frames.n))
        check_track_of(track, args.from_track, args.video, frames.n, frames.size,
                       "to draw the frames it covers")
        track.check_model(model)
    else:
        track, model = _track_and_save(args, model, settings, tracker)
    if args.overlay:
        _overlay(args, track, model, vopt)
    return 0


def _check_outputs(args):
    """The arguments' one-line errors and the outputs checked before any work (not an input,
    not existing without ``--overwrite``); returns the video options of ``--overlay``."""
    from ..io.video import check_video_output

    if args.from_track is None and not args.out:
        raise FaceTransferError("--out is required (the track file to write)")
    if args.from_track is not None and not args.overlay:
        raise FaceTransferError("--from-track needs --overlay (the video to draw)")
    if args.from_track is not None and args.occluders:     # before: ignored in silence
        raise FaceTransferError("--occluders tests the clip as it is tracked, and --from-track "
                                "tracks nothing: track again with --occluders --out T.npz")
    if args.max_frames is not None and args.max_frames < 1:
        raise FaceTransferError(f"--max-frames must be >= 1, got {args.max_frames}")
    if args.workers is not None and args.workers < 1:
        raise FaceTransferError(f"--workers must be >= 1, got {args.workers}")
    inputs = (args.video, args.model, args.from_track,
              None if args.init == "auto" else args.init)
    vopt = video_options(args, args.overlay)
    _check_codec_for_overlay(args)
    if args.overlay:
        check_video_output(args.overlay, vopt, overwrite=args.overwrite, inputs=inputs)
    if args.out:
        check_not_input(args.out, inputs)      # said first: it would destroy the video
        check_track_name(args.out, overlay=True)
        if args.overlay and not args.overwrite and Path(args.out).is_file() and \
                not Path(args.overlay).exists():   # a run stopped between the two
            _earlier_track(args)
        check_output_path(args.out, overwrite=args.overwrite, inputs=inputs)
        if args.overlay:
            check_not_input(args.overlay, [args.out, partial_path(args.out)])
        check_not_input(partial_path(args.out), inputs)
    return vopt


def _earlier_track(args) -> None:
    """The error for an ``--out`` track that exists where ``--overlay`` does not (a run
    stopped between the two?): the ``--from-track`` command that draws the overlay from it,
    with the ``--max-frames`` of the track's own frames (before: this run's, which the track
    did not have); a track of another clip, or none readable, is only said to exist."""
    from ..io.video import video_info
    from ..track.result import Track

    out = args.out
    try:
        track = Track.load(out)
    except (ValueError, OSError):
        return                                  # check_output_path says that it exists
    info = video_info(args.video)
    n = track.n_frames
    if tuple(track.frame_size) != tuple(info.size) or (info.n_frames and n > info.n_frames):
        raise FaceTransferError(
            f"output {out} exists, a track of another clip ({frame_count(n)} of "
            f"{track.frame_size[0]}x{track.frame_size[1]}; the video is {info.size[0]}x"
            f"{info.size[1]}): --overwrite replaces it")
    limit = "" if n == info.n_frames else f" --max-frames {n}"
    other = f"; for {frame_count(args.max_frames)}, --overwrite tracks again" \
        if args.max_frames is not None and args.max_frames != n else \
        "; --overwrite tracks again"
    raise FaceTransferError(f"output {out} exists (an earlier run's track of "
                            f"{frame_count(n)}?): `--from-track {out} --overlay "
                            f"{args.overlay}{limit}` draws the overlay from it{other}")


def _check_codec_for_overlay(args) -> None:
    """``--codec``, ``--crf`` or ``--preset`` (the ``--overlay`` video's) given without
    ``--overlay``: refused, as ``--start-number`` is (they were ignored in silence)."""
    from ..io.video import DEFAULT_CODEC, DEFAULT_PRESET

    if args.overlay:
        return
    given = [flag for flag, set_ in (("--codec", args.codec != DEFAULT_CODEC),
                                     ("--crf", args.crf is not None),
                                     ("--preset", args.preset != DEFAULT_PRESET)) if set_]
    if given:
        raise FaceTransferError(f"{given[0]} sets the --overlay video's encoding, and none is "
                                f"written here: give --overlay OVERLAY.mp4 or leave {given[0]} "
                                "out")


def _model_meanwhile(args, tracker: str):
    """The model, or a future of it: the capture tracker needs the model only after the
    detections, so a model file is loaded on a thread meanwhile (and MediaPipe imported: the
    detection waits for that import)."""
    if args.from_track is None and tracker == "capture" and _model_on_disk(args.model):
        from ..track.detect import preload_mediapipe

        preload_mediapipe()
        pool = ThreadPoolExecutor(max_workers=1)
        model = pool.submit(_checked_model, args.model)
        pool.shutdown(wait=False)
        return model
    return _checked_model(args.model)


def _track_and_save(args, model, settings, tracker: str):
    """Track the video with a progress bar per stage, write ``--out`` and say what it holds;
    ``(track, model)``."""
    bars: dict[str, object] = {}

    def progress(stage: str, done: int, total: int) -> None:
        bar = bars.get(stage)
        if bar is None:
            for b in bars.values():
                b.close()
            bar = bars[stage] = _bar(stage, total)
        bar.update(done - bar.n)

    if tracker == "capture":
        track, model = _capture(args, model, settings.capture, progress, bars)
    else:
        track = _track_klt(args, model, settings.klt, progress, bars)
    covered = None
    if getattr(args, "occluders", False):
        track, covered = _held_occluded(args, track, model)
    track = track.with_source_facts(args.video)   # the clip's numbering, before it can move
    track.save(args.out, overwrite=args.overwrite)
    partial_path(args.out).unlink(missing_ok=True)   # the progress of the run, if any
    n_lost = int(track.lost.sum())
    print(f"wrote {args.out}: {frame_count(track.n_frames)}, {track.frame_size[0]}x"
          f"{track.frame_size[1]}, mean confidence {track.confidence.mean():.2f}"
          + (f", {n_lost} lost" if n_lost else ""))
    _say_lost(track)
    if covered is not None:
        print(f"note: {covered}")
    if track.blendshapes is None:
        from ..arkit import arkit_shortfall

        print(f"note: the track has no ARKit blendshape activations: "
              f"{arkit_shortfall(model) or 'the model gives none'}")
    return track, model


def _held_occluded(args, track, model):
    """``--occluders``: the track with its covered regions' activations bridged, and the note
    of the frames each region was found covered in (a clip of fewer than ``MIN_RUN`` frames
    is not tested: ``occluded`` None, as the track key says: not tested)."""
    from ..file_facts import covered_note
    from ..io.frame_numbers import first_number
    from ..track.occlusion import with_occluders

    track = with_occluders(args.video, track, model)
    return track, covered_note(track, first_number(args.video))


def _say_lost(track) -> None:
    """The note of the frames where the face was lost (their runs, as ``export`` and ``puppet``
    name them), and what each command makes of them; nothing where no frame is lost."""
    from .export import lost_note

    note = lost_note(track, "marked lost (a transfer keeps those frames as they are, export "
                            "and puppet hold the nearest tracked frame)")
    if note:
        print(f"note: {note}")


def _overlay(args, track, model, vopt) -> None:
    """Write ``--overlay``: the track drawn over the video."""
    from ..track.overlay import write_overlay

    bar = _bar("overlay", track.n_frames)
    try:
        write_overlay(args.video, track, model, args.overlay, progress=bar.update,
                      overwrite=args.overwrite, options=vopt)
    finally:
        bar.close()
    print(f"wrote {args.overlay}")


def _model_on_disk(path) -> bool:
    """Whether the model is a file to read (not one to build first, with its own progress)."""
    if path is not None:
        return Path(path).is_file()
    from ..default_model import default_model_path

    return default_model_path().is_file()


def _checked_model(path):
    from ..track.init import require_landmarks

    model = resolve_model(path)
    require_landmarks(model)
    return model


def _capture(args, model, options, progress, bars):
    """The capture tracker; ``model`` may be a Future still loading. Returns (track, model).

    The detections and the fit resume from ``partial_path(args.out)``
    (:mod:`facetransfer.track.detect_checkpoint`, :mod:`facetransfer.track.fit_checkpoint`).
    """
    from ..track.capture import capture_detections
    from ..track.detect_checkpoint import DetectionCheckpoint, face_detector_id

    partial = partial_path(args.out)
    if args.restart and partial.exists():
        partial.unlink()
    ck = DetectionCheckpoint.for_video(partial, args.video, args.max_frames,
                                       face_detector_id(getattr(args, "face", None)))
    saved = ck.load()
    if saved is not None:
        from ..io.frame_numbers import first_number

        print(f"continued an interrupted run from frame "
              f"{first_number(args.video) + saved.detections.n_frames}")   # a plate's number
    try:
        det, fps, size, src = _capture_detect(args, saved, ck, progress)
        if isinstance(model, Future):
            model = model.result()
        try:
            return capture_detections(det, model, options=options, fps=fps, frame_size=size,
                                      progress=progress, source=src, checkpoint=ck), model
        except KeyboardInterrupt:
            ck.save(det, complete=True)                   # with the fit so far, if it began
            raise
    except KeyboardInterrupt as stop:
        _say_progress(stop, partial)
        raise
    finally:
        for b in bars.values():
            b.close()


def _say_progress(stop: KeyboardInterrupt, partial) -> None:
    """Note on ``stop`` (said in the CLI's one line, :func:`facetransfer.cli.main._run`) where
    the interrupted ``track``'s progress is, where any was saved (no file is named when the
    interrupt came before the first save wrote one)."""
    if partial.exists():
        stop.add_note(f"the progress is in {partial}: run the same command again to continue")
    else:
        stop.add_note("no progress was saved yet: the same command starts again")


def _capture_detect(args, saved, ck, progress):
    """The clip's detections, continued from ``saved``: (detections, fps, size, source)."""
    from ..io.video import video_info
    from ..track.video_detect import detect_video
    from ..track.video_detect import default_workers

    if saved is not None and saved.complete:
        info = video_info(args.video)
        return saved.detections, info.fps, info.size, str(args.video)
    workers = args.workers if args.workers is not None else default_workers()
    subject = None
    if getattr(args, "face", None) is not None:
        from ..track.face_crop import subject_point

        subject = subject_point(args.face, video_info(args.video).size)
    return detect_video(args.video, max_frames=args.max_frames, progress=progress,
                        source=str(args.video), checkpoint=ck, workers=workers,
                        resume=None if saved is None else saved.detections, subject=subject)


def _track_klt(args, model, opt, progress, bars):
    from ..track.aspect import warn_stored_fit
    from ..track.init import LazyDetector
    from ..track.tracker import track_video

    warn_stored_fit(args.video, "optical-flow tracker")
    # auto init and anchoring create MediaPipe themselves; with user points it is only
    # loaded if the face is lost (recovery)
    detector = None if (args.init == "auto" or args.anchor) else LazyDetector()
    partial = partial_path(args.out)
    if args.restart and partial.exists():
        partial.unlink()
    try:
        track = track_video(args.video, model, init=args.init, options=opt,
                            max_frames=args.max_frames, progress=progress,
                            source=str(args.video), detector=detector, checkpoint=partial)
    except KeyboardInterrupt as stop:
        _say_progress(stop, partial)
        raise
    finally:
        for b in bars.values():
            b.close()
        if detector is not None:
            detector.close()
    if track.info and track.info.get("resumed"):
        from ..io.frame_numbers import first_number

        r, first = track.info["resumed"], first_number(args.video)   # a plate's number
        print("continued an interrupted run from " + (f"pass {r['pass']}, " if "pass" in r
                                                      else "") + f"frame {first + r['frame']}")
    return track

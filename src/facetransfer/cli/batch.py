"""``facetransfer batch track | transfer | export``: many clips on Dask distributed.

    facetransfer batch track VIDEO... | --manifest clips.csv --out DIR [--workers N]
                             [--scheduler tcp://HOST:8786] [--chunk N [--overlap N]]
                             [--model M.npz] [--face WHERE] [--max-frames N] [--occluders]
                             [track options] [--overwrite]
    facetransfer batch transfer --manifest pairs.csv --out DIR [--model M.npz]
                                [--matte png|tiff|exr] [transfer options]
    facetransfer batch export TRACK... --format livelink|glb|usd|json --out DIR [--model M.npz]

One task per clip on an embedded ``LocalCluster`` (one single-threaded worker process per core)
or a running scheduler; ``DIR/NAME.<ext>`` per clip and ``DIR/summary.csv``. A rerun skips what
is done; Ctrl-C cancels what is pending and keeps what finished. Exit status 1 if a clip failed.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import FaceTransferError
from .common import (FACE_WHERE, add_video_options, integer_from, progress_disabled,
                     resolve_model, video_options)


def _cluster_options(p) -> None:
    g = p.add_argument_group("cluster")
    g.add_argument("--out", required=True, metavar="DIR", help="output folder")
    g.add_argument("--workers", type=int, default=None,
                   help="worker processes of the embedded cluster (default: one per core)")
    g.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="run on this Dask scheduler's workers instead (started with `dask "
                   "scheduler` and `dask worker`; they must see the inputs and DIR at the same "
                   "paths)")
    g.add_argument("--timeout", type=float, default=10.0,
                   help="seconds the scheduler has to answer (its host's lookup included)")
    g.add_argument("--overwrite", action="store_true",
                   help="redo every clip, replacing the output there as the run began "
                   "(default: skip clips whose output is complete); one another run writes "
                   "meanwhile is kept either way")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _track_options(p) -> None:
    """The options of ``facetransfer track`` that shape the track (the same definitions)."""
    from .track import add_track_options

    add_track_options(p.add_argument_group("tracking (as `facetransfer track`; a manifest's "
                                           "init column gives per-clip --init points, its "
                                           "occluders column (yes/no) per-clip --occluders: "
                                           "each clip tested whole, after its chunks are "
                                           "joined)"))


def register(sub) -> None:
    """Add ``batch track``, ``batch transfer`` and ``batch export`` to the parser."""
    from .common import DefaultsFormatter, add_command_group

    bs = add_command_group(sub, "batch", dest="batch_command", metavar="COMMAND",
                           help="many clips at once on Dask distributed (track, transfer, "
                           "export)", description="Run track, transfer or export over many "
                           "clips on an embedded Dask cluster or a real one; one output per "
                           "clip and DIR/summary.csv.")
    _register_track(bs, DefaultsFormatter)
    _register_transfer(bs, DefaultsFormatter)
    _register_export(bs, DefaultsFormatter)


def _register_track(bs, fmt) -> None:
    """``batch track``'s parser."""
    from ..batch.run import DEFAULT_OVERLAP

    t = bs.add_parser("track", formatter_class=fmt, help="track many clips: DIR/NAME.npz each",
                      description="Track every clip as `facetransfer track` does, one task per "
                      "clip; clips longer than --chunk frames in overlapping chunks joined at "
                      "the seams (one identity per clip).")
    t.add_argument("videos", nargs="*", metavar="VIDEO", help="videos to track")
    t.add_argument("--manifest", metavar="clips.csv",
                   help="CSV with a video column (and name, init, face, max_frames, "
                   "occluders); paths relative to it")
    t.add_argument("--model", metavar="M.npz", help="model (default: the default model)")
    t.add_argument("--chunk", type=int, default=0,
                   help="split clips longer than this many frames into overlapping chunks "
                   "tracked in parallel (0 = never)")
    t.add_argument("--overlap", type=integer_from(1), default=DEFAULT_OVERLAP,
                   help="frames shared by neighbouring chunks (cross-faded)")
    t.add_argument("--face", metavar="WHERE",
                   help=f"[capture] with several people in the frame, the one to track in "
                   f"every clip (a manifest's face column gives it per clip): {FACE_WHERE}; "
                   "each chunk of a --chunk clip starts on the face nearest it")
    t.add_argument("--max-frames", type=int, default=None,
                   help="track only the first N frames of every clip (a manifest's max_frames "
                   "column gives it per clip)")
    _track_options(t)
    _cluster_options(t)
    t.set_defaults(func=run_track)


def _register_transfer(bs, fmt) -> None:
    """``batch transfer``'s parser: ``transfer``'s rewrite and video options, ``--matte``."""
    from .transfer import ALIGN_HELP, add_rewrite_options

    r = bs.add_parser("transfer", formatter_class=fmt,
                      help="many transfers: DIR/NAME.mp4 each (.mov as ProRes)",
                      description="Run `facetransfer transfer` for every row of a pairs "
                      "manifest (columns target, expression_from, and the other sources: "
                      "viseme_from, identity_from, identity_label, identity_weights, pose_from, "
                      "performance, and track files target_track, source_track, viseme_track, "
                      "identity_track, pose_track; with several people, target_face and "
                      "source_face as --target-face / --source-face; name).")
    r.add_argument("--manifest", required=True, metavar="pairs.csv",
                   help="CSV with a target column and transfer's sources (expression_from: a "
                   "video or a Live Link Face take; the others as the description above says); "
                   "paths relative to it")
    r.add_argument("--model", metavar="M.npz", help="model (default: the default model)")
    r.add_argument("--align", choices=("trim", "loop", "hold"), default=None, help=ALIGN_HELP)
    r.add_argument("--max-frames", type=int, default=None, help="use the first N target frames")
    add_rewrite_options(r)
    add_video_options(r, what="each result (ProRes: DIR/NAME.mov)", sequences=False)
    r.add_argument("--matte", type=_matte_format, default=None, metavar="png|tiff|exr",
                   help="also write each result's matte of the pixels the rewrite changed "
                   "(as `transfer --matte`: 0 where the result is the target's pixel) as "
                   "DIR/NAME.matte/NAME.%%05d.png, numbered from 0 (of a plate target: from "
                   "its first number, as `transfer --matte`): png and tiff (.tif) 16-bit "
                   "grey, exr float; sequences only (`transfer --matte M.mov` writes a "
                   "lossless video matte of one transfer). A rerun with it does again "
                   "the pairs whose matte is not there whole in that format")
    _cluster_options(r)
    r.set_defaults(func=run_transfer)


def _register_export(bs, fmt) -> None:
    """``batch export``'s parser (its formats :data:`facetransfer.export.FORMATS`)."""
    from ..export import FORMATS

    e = bs.add_parser("export", formatter_class=fmt, help="export many tracks: DIR/NAME.<ext>",
                      description="Run `facetransfer export` for every track file.")
    e.add_argument("tracks", nargs="+", metavar="TRACK.npz", help="track files to export")
    e.add_argument("--format", required=True, choices=tuple(FORMATS),
                   help="livelink (DIR/NAME.csv), glb, usd or json, as `facetransfer export "
                   "--format`")
    e.add_argument("--model", metavar="M.npz",
                   help="the model of the tracks (default: the default model)")
    e.add_argument("--neutral", metavar="FRAME|auto",
                   help="measure each track's activations from this frame's, as `facetransfer "
                   "export --neutral` (a plate's track's numbered as the plate's files; "
                   "default: as tracked)")
    e.add_argument("--take-rate", choices=("app", "clip"), default=None,
                   help="livelink: the rows' timecodes as the Live Link Face app counts them "
                   "(app, the default: what Unreal reads right) or as the clip's timecode "
                   "counts its frames (clip), as `facetransfer export --take-rate`")
    _cluster_options(e)
    e.set_defaults(func=run_export)


def _matte_format(text: str) -> str:
    """``batch transfer --matte``'s value: a sequence's format (argparse names the option)."""
    import argparse

    from ..batch.jobs import MATTE_FORMATS

    if text not in MATTE_FORMATS:
        raise argparse.ArgumentTypeError(
            f"expected {', '.join(MATTE_FORMATS)} (an image sequence; `transfer --matte "
            f"M.mov` writes a lossless video matte of one transfer), got {text!r}")
    return text


def _run(args, what: str, n_jobs: int, call) -> int:
    """Open the cluster, run ``call(client, progress)``, report; exit 1 if a clip failed."""
    from tqdm import tqdm

    from ..batch import cluster

    if args.workers is not None and args.workers < 1:
        raise FaceTransferError(f"--workers must be >= 1, got {args.workers}")
    workers = args.workers if args.scheduler is not None else _workers(args.workers, n_jobs)
    bar, started, failed = None, False, 0

    def progress(row) -> None:
        nonlocal failed
        failed += row.status == "failed"
        if bar is not None:
            bar.update(1)
            if failed:
                bar.set_postfix(failed=failed)

    try:
        with cluster.open_client(workers=workers, scheduler=args.scheduler,
                                 timeout=args.timeout, verbose=args.verbose) as client:
            # the bar once the cluster is there (before, a scheduler that did not answer left
            # an empty bar above its one line)
            started = True
            bar = None if args.no_progress else tqdm(total=n_jobs, desc=what, unit="clip",
                                                     dynamic_ncols=True, file=sys.stderr,
                                                     disable=progress_disabled())
            res = call(client, progress)
    except KeyboardInterrupt as stop:
        if bar is not None:
            bar.close()
        if not started:   # while the cluster started or the scheduler was asked: nothing ran
            raise         # (before: "finished outputs are kept in DIR", of no DIR)
        from ..batch.ownership import remove_stale_claims

        # the embedded cluster is closed: the claims its workers held, left (a scheduler's
        # tasks still running keep theirs)
        remove_stale_claims(args.out)
        summary = Path(args.out) / "summary.csv"
        # said in the CLI's one line (facetransfer.cli.main._run); only a clip tracked whole
        # keeps a progress file (not a transfer, an export or a chunk)
        stop.add_note(f"finished outputs are kept in {args.out}"
                      + (f" (see {summary})" if summary.is_file() else "")
                      + "; run the same command again to continue"
                      + (" (a clip being tracked continues from its progress file)"
                         if what == "track" and not getattr(args, "chunk", 0) else ""))
        raise
    finally:
        if bar is not None:
            bar.close()
    for row in res.rows:
        if row.status == "failed":
            print(f"{row.clip}: failed: {row.error}", file=sys.stderr)
        elif row.note:     # a done row's note (its output taken from an earlier attempt)
            print(f"{row.clip}: note: {row.note}", file=sys.stderr)
    counts = ", ".join(f"{res.count(s)} {s}" for s in ("done", "skipped", "failed")
                       if res.count(s))
    n = len(res.rows)
    print(f"{what}: {n} clip{'' if n == 1 else 's'} ({counts}); wrote {res.summary}")
    return 1 if res.n_failed else 0


def _workers(asked: int | None, n_jobs: int) -> int:
    """The embedded cluster's workers: ``asked`` (default one per core), no more than the
    clips; more than the cores said (each worker tracks and renders on a core of its own: 100
    workers on 2 cores finished no clip in 2 minutes where 2 took 13.5 s)."""
    from ..batch.cluster import default_workers

    cores = default_workers()
    if asked is not None and asked > cores:
        print(f"note: --workers {asked} on {cores} cores: the workers share them, each clip "
              "slower", file=sys.stderr)
    return max(1, min(cores if asked is None else asked, n_jobs))


def run_track(args) -> int:
    from ..batch import batch_track, clip_jobs
    from ..track.init import require_landmarks
    from .track import track_settings

    if not args.videos and not args.manifest:
        raise FaceTransferError("give VIDEO files or --manifest clips.csv")
    # duplicate names are refused before anything runs
    jobs = clip_jobs(args.videos, args.manifest, init=args.init, face=args.face,
                     max_frames=args.max_frames, occluders=args.occluders)
    opt = track_settings(args)  # validates the options
    for job in jobs:
        if job.face is not None and opt.choose(job.init) != "capture":
            raise FaceTransferError(f"clip {job.name}: a face ({job.face!r}) is for the capture "
                                    "tracker (--tracker capture, or auto without --init points)")
    _check_cluster_args(args)
    model = resolve_model(args.model)
    require_landmarks(model)
    return _run(args, "track", len(jobs), lambda client, progress: batch_track(
        jobs, args.out, model, client=client, options=opt, chunk=args.chunk,
        overlap=args.overlap, overwrite=args.overwrite, progress=progress))


def transfer_settings(args) -> dict:
    """The settings of ``batch transfer`` (:func:`facetransfer.batch.jobs.transfer_pair`):
    the ``transfer`` options it shares."""
    return {"texture": args.texture, "blend": args.blend, "mouth": args.mouth,
            "align": args.align, "max_frames": args.max_frames,
            "track_method": args.tracker, "speed": args.speed, "eyes": args.eyes,
            "jaw": args.jaw, "lips": args.lips, "lip_colour": args.lip_colour,
            "gaze": args.gaze, "video": video_options(args)}


def run_transfer(args) -> int:
    from ..batch import batch_transfer, pair_jobs

    if args.max_frames is not None and args.max_frames < 1:
        raise FaceTransferError(f"--max-frames must be >= 1, got {args.max_frames}")
    settings = transfer_settings(args)   # a bad --crf fails before any work
    jobs = pair_jobs(args.manifest)
    if args.matte is not None:   # a name that cannot name its matte's frames: before any work
        from ..batch.run import matte_patterns

        matte_patterns(jobs, Path(args.out), args.matte)
    _check_cluster_args(args)
    model = resolve_model(args.model)
    return _run(args, "transfer", len(jobs), lambda client, progress: batch_transfer(
        jobs, args.out, model, client=client, settings=settings, overwrite=args.overwrite,
        progress=progress, matte=args.matte))


def run_export(args) -> int:
    from ..batch import batch_export, export_jobs
    from ..model import load_model

    jobs = export_jobs(args.tracks)
    _check_cluster_args(args)
    if args.take_rate is not None and args.format != "livelink":
        raise FaceTransferError(f"--take-rate {args.take_rate}: only livelink takes count "
                                f"their rows in timecodes, not {args.format}")
    if args.neutral is not None:  # checked before any clip runs
        from ..export.neutral import neutral_arg

        neutral_arg(args.neutral)
    model = load_model(args.model) if args.model else None  # None: export_track's default
    return _run(args, "export", len(jobs), lambda client, progress: batch_export(
        jobs, args.out, args.format, client=client, model=model, overwrite=args.overwrite,
        progress=progress, neutral=args.neutral, labels=args.take_rate))


def _check_cluster_args(args) -> None:
    """Bad cluster or output arguments fail before a model is loaded."""
    from ..batch.cluster import check_timeout
    from ..batch.run import check_out_dir

    if args.workers is not None and args.workers < 1:
        raise FaceTransferError(f"--workers must be >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        raise FaceTransferError("--workers sizes the embedded cluster; the workers of "
                                "--scheduler are the ones started with `dask worker`")
    check_timeout(args.timeout)       # inf, 1e12: a socket's deadline overflowed
    check_out_dir(args.out)

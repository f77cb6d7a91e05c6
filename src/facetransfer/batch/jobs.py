"""The tasks a batch run sends to the Dask workers, one concept each: track a clip, track a chunk,
join a clip's chunks, transfer a pair, export a track.

Each task is a module-level function (workers import it from the installed package) that reads
its inputs from paths the workers can see, writes its output atomically, and returns a small
:class:`~facetransfer.batch.summary.Row` (or, for a chunk, its track) to the client. The model
arrives as its file's :class:`~facetransfer.batch.model_ref.ModelRef`, loaded once by each
worker (:func:`~facetransfer.batch.model_ref.worker_model`; a model without a file: a future
scattered once to every worker), never pickled with the task.
A task raises on bad input; the client turns the exception into the clip's failed row.

A task replaces no file but those its run found and chose to redo, and holds its output while
it runs: :mod:`facetransfer.batch.ownership`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .manifest import BatchError
from .model_ref import worker_model
from .ownership import (OutputTaken, claimed, clear_leftover_matte, earlier_output,
                        matte_identity, own_output, still_planned)
from .summary import Row

log = logging.getLogger(__name__)

__all__ = ["partial_path", "track_row", "occluders_tested", "track_note", "track_clip",
           "ChunkResult", "track_chunk",
           "join_clip", "transfer_pair", "export_one", "count_frames", "EXPORT_EXTENSIONS",
           "MATTE_FORMATS", "matte_pattern", "RESULT_SUFFIXES", "other_result"]

#: The frame file of each ``batch transfer --matte`` format (image sequences only, one file a
#: frame: :mod:`facetransfer.io.matte`).
MATTE_FORMATS = {"png": ".png", "tiff": ".tif", "exr": ".exr"}

#: The suffixes of ``batch transfer``'s results: ``.mp4`` (H.264, H.265), ``.mov`` (ProRes).
RESULT_SUFFIXES = (".mp4", ".mov")

#: Seconds between the saves of a clip's tracking progress (``NAME.partial.npz``): a batch
#: stopped with Ctrl-C ends its workers, which cannot save on the way out, so a run continued
#: later redoes at most this much of each clip (the saves still take at most 5 % of the time,
#: :class:`facetransfer.track.detect_checkpoint.DetectionCheckpoint`).
SAVE_EVERY = 4.0

#: Format name -> the suffix of ``batch export``'s files: :data:`facetransfer.export.FORMATS`
#: (not imported here: a worker loads the exporters only when it exports; a test holds the
#: two equal).
EXPORT_EXTENSIONS = {"livelink": ".csv", "glb": ".glb", "usd": ".usd", "json": ".json"}


def partial_path(out, suffix: str = "") -> Path:
    """Where the tracking of ``out`` keeps its progress (the name ``facetransfer track`` uses)."""
    p = Path(out)
    return p.with_name(p.stem + suffix + ".partial.npz")


def track_row(name: str, track, out, seconds: float, status: str = "done",
              note: str = "") -> Row:
    """The summary row of a finished track."""
    return Row(clip=name, status=status, frames=track.n_frames, fps=track.fps, seconds=seconds,
               mean_confidence=float(np.mean(track.confidence)), output=str(out), note=note)


def occluders_tested(job, track, model):
    """The track of ``job`` tested for a covered mouth or eye where the job asks
    (``batch track --occluders``, a manifest's ``occluders`` cell) as ``track --occluders``
    tests it (:func:`facetransfer.track.occlusion.with_occluders`: on the whole clip, after
    its chunks are joined); as it is otherwise."""
    if not job.occluders:
        return track
    from ..track.occlusion import with_occluders

    return with_occluders(job.video, track, model)


def track_note(job, track, *more: str) -> str:
    """A track row's note: what ``track --occluders`` says of it where the job asks
    (:func:`facetransfer.file_facts.covered_note`), then ``more`` (the claim's), "; "-joined."""
    said = ()
    if job.occluders:
        from ..file_facts import covered_note
        from ..io.frame_numbers import first_number

        said = (covered_note(track, first_number(job.video)),)
    return "; ".join(n for n in said + more if n)


def _detector_for(init: str, options):
    """As ``facetransfer track``: automatic init and anchoring create MediaPipe themselves; with
    user points it is loaded only if the face is lost (recovery)."""
    from ..track.init import LazyDetector

    return None if (init == "auto" or options.anchor) else LazyDetector()


def _track(video, model, init: str, settings, *, source: str, checkpoint, fixed=None,
           tracker: str | None = None, view=None, face: str | None = None,
           max_frames: int | None = None, first_frame: int | None = None):
    """As ``facetransfer track``: the tracker ``settings`` choose for ``init`` (or ``tracker``);
    ``view``: how frames given as an array are shown (:class:`facetransfer.track.aspect.View`
    of their video); ``face``: of several people, the one the capture tracker follows;
    ``first_frame``: the number of the optical-flow tracker's first frame in what it says (a
    chunk's: its clip's number; default its ``source``'s first)."""
    from ..track.tracker import track_video

    if (tracker or settings.choose(init)) == "capture":
        from ..track.capture import capture_video

        subject = _subject(face, video, source)
        if checkpoint is not None and isinstance(video, (str, Path)):
            from ..track.detect_checkpoint import face_detector_id
            from ..track.obtain import capture_resuming

            return capture_resuming(video, model, checkpoint, options=settings.capture,
                                    source=source, fixed=fixed, subject=subject,
                                    detector_id=face_detector_id(face), save_every=SAVE_EVERY,
                                    max_frames=max_frames)
        return capture_video(video, model, options=settings.capture, source=source,
                             fixed=fixed, view=view, subject=subject, max_frames=max_frames)
    if face is not None:
        raise BatchError(f"{source}: face {face!r} is for the capture tracker (the clip is "
                         "tracked with the optical-flow tracker, which follows the face found "
                         "first)")
    detector = _detector_for(init, settings.klt)
    try:
        return track_video(video, model, init=init, options=settings.klt, source=source,
                           detector=detector, fixed=fixed, checkpoint=checkpoint,
                           checkpoint_every=SAVE_EVERY, max_frames=max_frames,
                           first_frame=first_frame)
    finally:
        if detector is not None:
            detector.close()


def _subject(face: str | None, video, source: str):
    """The point ``face`` names in the frames of ``video`` (a path, or decoded frames of the
    video ``source``), or None."""
    if face is None:
        return None
    from ..io.video import video_info
    from ..track.face_crop import subject_point

    return subject_point(face, video_info(source).size, what=f"{source}: face")


def track_clip(job, out: str, model, options, overwrite: bool = False,
               planned: str = "", owner: str = "") -> Row:
    """Track a whole clip exactly as ``facetransfer track VIDEO --out OUT`` does and write it.

    The job holds its output while it runs (:func:`.ownership.claimed`): another run's job of
    it then fails at its start (:class:`OutputTaken`), its progress file left to that run.

    Parameters
    ----------
    job : ClipJob
    out : str
        ``DIR/NAME.npz``.
    model : MultilinearModel
    options : TrackerSettings
    overwrite : bool
        Replace whatever ``out`` is there, even one another run wrote since this one was
        planned (the batch passes False: its ``--overwrite`` comes as ``planned``); without it,
        such an ``out`` is kept (:class:`OutputTaken`).
    planned : str
        Without ``overwrite``: the :func:`.ownership.output_identity` of the ``out`` the run
        found and does again (every one with the batch's ``--overwrite``), replaced while it is
        still that file (:func:`.ownership.still_planned`); "" (none found): an ``out``
        another run wrote meanwhile is kept.
    owner : str
        The run and the job's digest (:func:`.ownership.claimed`): a claim of the same
        ``owner`` is this run's earlier attempt of the job (Dask ran the task again, taking its
        worker for lost), waited for; the track it wrote is taken (the row's ``note`` says
        so), else the clip is tracked again.

    Returns
    -------
    Row
    """
    from ..io.video import video_info

    t0 = time.perf_counter()
    video_info(job.video)  # missing / not a video: one line naming the path
    model = worker_model(model)
    with claimed(out, owner) as claim:
        if earlier_output(out, planned, claim):
            return _taken_track(job, out, claim, t0)
        overwrite = overwrite or still_planned(out, planned)
        try:
            with own_output(out, overwrite):
                track = _track(str(job.video), model, job.init, options,
                               source=str(job.video), checkpoint=partial_path(out),
                               face=job.face, max_frames=job.max_frames)
                track = occluders_tested(job, track, model)
                track = track.with_source_facts(job.video)   # its numbering, before it moves
                track.save(out, overwrite=overwrite)
        except OutputTaken:   # the other run's track is whole: no progress to keep for it
            partial_path(out).unlink(missing_ok=True)
            raise
        partial_path(out).unlink(missing_ok=True)   # the capture tracker's progress, if any
    return track_row(job.name, track, out, time.perf_counter() - t0,
                     note=track_note(job, track, claim.note(False)))


def _taken_track(job, out: str, claim, t0: float, seconds: float = 0.0) -> Row:
    """The row of the track ``out`` this run's earlier attempt of the job wrote
    (:func:`.ownership.earlier_output`), taken as this attempt's; its progress file removed."""
    from ..track.result import Track

    track = Track.load(out)
    partial_path(out).unlink(missing_ok=True)
    return track_row(job.name, track, out, seconds + time.perf_counter() - t0,
                     note=track_note(job, track, claim.note(True)))


@dataclass(frozen=True, eq=False)
class ChunkResult:
    """The track of one chunk and the seconds it took."""

    track: object
    seconds: float


def track_chunk(job, chunk, out: str, model, options, first=None) -> ChunkResult:
    """Track frames ``chunk.start..chunk.stop`` of a clip.

    The first chunk starts from the clip's initial points (``job.init``) and solves the
    identity; every later chunk starts from detected landmarks with the identity of ``first``
    (the first chunk's result) held fixed; with the capture tracker, only where the chunk
    begins on that person (else its own: the clip cut to another one before it).

    Parameters
    ----------
    job : ClipJob
    chunk : Chunk
    out : str
        The clip's output (its progress files are named after it).
    model : MultilinearModel
    options : TrackerSettings
    first : ChunkResult, optional
        The first chunk's result (for every chunk but the first).

    Returns
    -------
    ChunkResult
        The chunk's track (frames of the chunk, the video's frame rate).
    """
    from ..io.video import read_video
    from ..track.aspect import View

    t0 = time.perf_counter()
    model = worker_model(model)
    frames, fps = read_video(job.video, start=chunk.start, stop=chunk.stop)
    fixed = None
    init = job.init
    tracker = options.choose(job.init)  # one tracker for every chunk of the clip
    if first is not None:
        if "identity" in first.track.weights:
            fixed = {"identity": first.track.weights["identity"][0]}
        init = "auto"  # the user's points are for the clip's first frame only
    if fixed is not None and tracker == "capture":
        track = _chunk_capture(frames, model, options, job, chunk, fixed["identity"])
    else:
        from ..io.frame_numbers import first_number

        track = _track(frames, model, init, options, source=str(job.video), fixed=fixed,
                       checkpoint=partial_path(out, f".chunk{chunk.index:03d}"),
                       tracker=tracker, view=View.of(job.video), face=job.face,
                       first_frame=first_number(str(job.video)) + chunk.start)
    return ChunkResult(dataclasses.replace(track, fps=fps), time.perf_counter() - t0)


def _chunk_capture(frames, model, options, job, chunk, identity):
    """A later chunk's capture: with the first chunk's ``identity`` held fixed where the
    chunk's first shot with a face is that person's
    (:func:`facetransfer.track.capture.held_identity`; a cut inside the chunk: its later shots
    are compared in the capture, :mod:`facetransfer.track.shots`), else with its own (the clip
    cut to another person in an earlier chunk, which this chunk cannot see)."""
    from ..track.aspect import View
    from ..track.capture import capture_detections, held_identity
    from ..track.video_detect import detect_video

    source = str(job.video)
    det, fps, size, src = detect_video(frames, source=source, view=View.of(job.video),
                                       subject=_subject(job.face, frames, source))
    from ..io.frame_numbers import first_number

    held = held_identity(det, model, options.capture, identity)
    first = first_number(source) + chunk.start   # the chunk's first frame by the clip's numbers
    if held is None and det.found.any():
        log.warning("%s: frames %d-%d begin on another face than the clip's first (a cut "
                    "before them): captured with their own identity", source,
                    first, first + chunk.stop - chunk.start - 1)
    return capture_detections(det, model, options=options.capture, fps=fps, frame_size=size,
                              source=src, fixed=held, first_frame=first)


def join_clip(job, out: str, model, chunks, results, overwrite: bool = False,
              planned: str = "", owner: str = "") -> Row:
    """Join a clip's chunk tracks (:func:`~facetransfer.batch.chunks.join_tracks`) and write
    ``out`` (``overwrite``, ``planned``, ``owner`` and its claim: as :func:`track_clip`'s)."""
    from .chunks import join_tracks

    t0 = time.perf_counter()
    spent = sum(r.seconds for r in results)
    model = worker_model(model)
    with claimed(out, owner) as claim:
        if earlier_output(out, planned, claim):
            return _taken_track(job, out, claim, t0, spent)
        overwrite = overwrite or still_planned(out, planned)
        with own_output(out, overwrite):
            track = join_tracks([r.track for r in results], chunks, model)
            track = occluders_tested(job, track, model)   # the whole clip: its own reference
            track = track.with_source_facts(job.video)
            track.save(out, overwrite=overwrite)
    return track_row(job.name, track, out, spent + time.perf_counter() - t0,
                     note=track_note(job, track, claim.note(False)))


def _identity(job, model):
    """Identity weights of a pair from ``identity_label`` / ``identity_weights``, or None."""
    from ..transfer import identity_from_label, parse_weights

    s = job.sources
    if s.get("identity_label"):
        return identity_from_label(model, s["identity_label"])
    if s.get("identity_weights"):
        idm = model.identity_mode
        return parse_weights(s["identity_weights"], model.ranks[model.mode_index(idm)])
    return None


def matte_pattern(out_dir, name: str, suffix: str) -> Path:
    """Where ``batch transfer --matte`` writes the matte of the job ``name``: a folder of its
    own beside the result, its frames named as the job, ``DIR/NAME.matte/NAME.%05d.png``
    (``suffix``: ``.png``, ``.tif`` or ``.exr``, :data:`MATTE_FORMATS`). No result
    (``DIR/NAME.mp4``) nor another job's matte can be one of its files."""
    return Path(out_dir) / f"{name}.matte" / f"{name}.%05d{suffix}"


def transfer_pair(job, out: str, model, settings: dict, matte: str | None = None, *,
                  overwrite: bool = False, planned: str = "", planned_matte: str = "",
                  owner: str = "") -> Row:
    """Rewrite one target as ``facetransfer transfer`` does
    (:func:`facetransfer.video_transfer.transfer_video`) and write ``out`` (and ``matte``).

    Parameters
    ----------
    job : PairJob
    out : str
        ``DIR/NAME.mp4`` (``.mov`` for ProRes).
    model : MultilinearModel
    settings : dict
        ``texture``, ``blend``, ``mouth``, ``align``, ``max_frames``, ``track_method``,
        ``speed``, ``eyes``, ``jaw``, ``lips``, ``lip_colour``, ``gaze`` as the ``transfer``
        options, and ``video``, its :class:`~facetransfer.io.video_options.VideoOptions`
        (absent: H.264, CRF 18).
    matte : str, optional
        Also write the matte of the pixels the rewrite changed, an image sequence
        (``DIR/NAME.matte/NAME.%05d.png``, as ``transfer --matte``), rendered and continued
        after an interrupt with ``out``. Once written, that folder's frames of an earlier
        render in another format (all of them, without ``matte``) are removed
        (:func:`_remove_other_mattes`).
    overwrite : bool
        Replace whatever ``out`` and ``matte`` are there (as :func:`track_clip`'s: the batch
        passes False, its ``--overwrite`` comes as ``planned``).
    planned : str
        Without ``overwrite``: the :func:`.ownership.output_identity` of the ``out`` the run
        found and chose to render again (its own result, redone for the matte asked; a file
        that does not decode; any, with the batch's ``--overwrite``), replaced, with its matte,
        while it is still that file, under the job's claim (:func:`.ownership.claimed`); ""
        (none found): an ``out`` or matte frames another run wrote meanwhile are kept
        (:class:`OutputTaken`).
    planned_matte : str
        Without ``overwrite``: the :func:`.ownership.matte_identity` of the frames of ``matte``
        the run found; beside no ``out`` (:func:`.ownership.clear_leftover_matte`) removed
        while they are still those, before the render.
    owner : str
        As :func:`track_clip`'s: the result (and matte) this run's earlier attempt of the
        pair rendered is taken; frames of a matte beside no result after it (killed between
        the two commits, past its checks) are its own, removed as the run's (no other run's
        job held the claim since: :func:`.ownership.earlier_output`).

    Returns
    -------
    Row
    """
    from ..video_transfer import transfer_video

    t0 = time.perf_counter()
    model = worker_model(model)
    sources = _pair_sources(job, model)
    options = rewrite_options(settings)
    with claimed(out, owner) as claim:
        if earlier_output(out, planned, claim):
            return _taken_video(job.name, out, matte, claim, t0)
        overwrite = overwrite or still_planned(out, planned)
        if not overwrite:
            # frames beside no result under this run's earlier attempt's claim, past its checks
            # (killed between the matte's commit and the result's): its, removed as the run's
            clear_leftover_matte(out, matte,
                                 matte_identity(matte) if claim.past_checks else planned_matte)
        with own_output(out, overwrite, matte):
            res = transfer_video(sources, out, model, overwrite=overwrite, options=options,
                                 progress_factory=None, align=settings["align"],
                                 max_frames=settings["max_frames"], parallel=False,
                                 video_options=settings.get("video"), matte=matte)
        if other_result(out) is None:   # else NAME.matte/ is that result's (batchfmt55)
            _remove_other_mattes(Path(out).parent, job.name, matte)
    conf = res.plan.target_track.confidence[:res.n_frames]
    return Row(clip=job.name, status="done", frames=res.n_frames, fps=res.plan.fps,
               seconds=time.perf_counter() - t0, mean_confidence=float(np.mean(conf)),
               output=str(out), matte="" if res.matte is None else str(res.matte),
               note=claim.note(False))


def _pair_sources(job, model):
    """The :class:`~facetransfer.transfer_plan.TransferSources` of the pair ``job``, its
    inputs checked (a missing or unreadable one fails the row, naming the path)."""
    from ..io.video import video_info
    from ..take import is_take
    from ..video_transfer import TransferSources

    s = job.sources
    for v in (job.target, s.get("expression_from"), s.get("viseme_from"),
              s.get("identity_from"), s.get("pose_from")):
        if v and not is_take(v):   # a take (Live Link Face CSV) is read by the plan
            video_info(v)  # a missing or unreadable input fails the row, naming the path
    return TransferSources.of(
        str(job.target), target_track=s.get("target_track"),
        expression_from=s.get("expression_from"),
        expression_track=s.get("source_track"), viseme_from=s.get("viseme_from"),
        viseme_track=s.get("viseme_track"), identity=_identity(job, model),
        identity_from=s.get("identity_from"), identity_track=s.get("identity_track"),
        pose_from=s.get("pose_from"), pose_track=s.get("pose_track"),
        performance=s.get("performance"), target_face=s.get("target_face"),
        source_face=s.get("source_face"))


def _taken_video(name: str, out: str, matte: str | None, claim, t0: float) -> Row:
    """The row of the result ``out`` (and ``matte``, committed before it) this run's earlier
    attempt of the pair rendered (:func:`.ownership.earlier_output`), taken as this one's."""
    from ..io.video import video_info

    info = video_info(out)
    return Row(clip=name, status="done", frames=info.n_frames, fps=info.fps,
               seconds=time.perf_counter() - t0, output=str(out),
               matte="" if matte is None else str(matte), note=claim.note(True))


def other_result(out) -> Path | None:
    """The result of the same pair in the other container beside ``out`` (``DIR/NAME.mov``
    beside ``DIR/NAME.mp4`` and the other way round: a run of another codec into the folder),
    None where there is none. Its matte folder ``DIR/NAME.matte/`` is then that result's: a
    render of ``out`` does not clear it (before, a ProRes run without ``--matte`` removed the
    H.264 results' mattes), and ``batch transfer`` does not render ``out`` with a matte there
    (:func:`facetransfer.batch.run._mattes_of_other_results`)."""
    o = Path(out)
    for suffix in RESULT_SUFFIXES:
        other = o.with_suffix(suffix)
        if suffix != o.suffix and other.is_file():
            return other
    return None


def _remove_other_mattes(out_dir: Path, name: str, matte: str | None) -> None:
    """Once pair ``name`` is rendered again: the frames in its matte folder
    (:func:`matte_pattern`) of the formats it did not write now (all of them without
    ``matte``), an earlier render's, which its row no longer names; the folder
    itself if that empties it. A compositor reading ``DIR/NAME.matte/`` then finds the matte of
    ``DIR/NAME.mp4`` or none, never two sequences (``NAME.00000.png`` beside
    ``NAME.00000.exr``) nor one of other options (after ``--overwrite``). Other files stay."""
    import re

    folder = matte_pattern(out_dir, name, "").parent
    if not folder.is_dir():
        return
    keep = None if matte is None else Path(matte).suffix
    stale = [s for s in MATTE_FORMATS.values() if s != keep]
    rx = re.compile(re.escape(name) + r"\.\d{5,}(" + "|".join(map(re.escape, stale)) + r")\Z")
    for f in folder.iterdir():
        if rx.match(f.name) and f.is_file():
            f.unlink(missing_ok=True)
    if matte is None:
        try:
            folder.rmdir()                # only if nothing else is in it
        except OSError:
            pass


def rewrite_options(settings: dict):
    """The :class:`~facetransfer.rewrite_options.RewriteOptions` of a batch transfer's
    settings (those of ``facetransfer transfer``; ``eyes``, ``jaw``, ``lips``,
    ``lip_colour`` and ``gaze`` default to its defaults)."""
    from ..rewrite_options import RewriteOptions

    return RewriteOptions(
        texture=settings["texture"], blend=settings["blend"], mouth=settings["mouth"],
        track_method=settings["track_method"], speed=settings["speed"],
        eyes=settings.get("eyes", "model"), jaw=settings.get("jaw", "closed"),
        lips=settings.get("lips", "residual"), lip_colour=settings.get("lip_colour", "target"),
        gaze=settings.get("gaze", "performance"))


@functools.lru_cache(maxsize=1)
def _default_model():
    """The default model and its hash, loaded once per worker process (not once per task)."""
    from ..default_model import load_default_model

    model = load_default_model()
    return model, model.content_hash


def export_one(job, fmt: str, out: str, model=None, texture=None, neutral=None,
               labels=None, overwrite: bool = False, planned: str = "", owner: str = "") -> Row:
    """Export one track file with :func:`facetransfer.export.export_track` to ``out``
    (``neutral``: its neutral frame, :mod:`facetransfer.export.neutral`; ``labels``: a
    livelink take's timecode labels, None the default; ``overwrite``: as
    :func:`track_clip`'s; ``planned``: as :func:`transfer_pair`'s, the take of an earlier
    version the run writes again, or any with the batch's ``--overwrite``; claimed as
    :func:`track_clip`'s output; ``owner``: as :func:`track_clip`'s, an export this run's
    earlier attempt of the job wrote is taken).

    Without ``model``, a track made with the default model gets the worker's cached copy of
    it; any other track is left to ``export_track``'s own check (``model=None``).
    """
    from ..export import GEOMETRY_FORMATS, export_track
    from ..track.result import Track

    t0 = time.perf_counter()
    track = Track.load(job.track)
    model = worker_model(model)
    if model is None and fmt in GEOMETRY_FORMATS:  # the others need no geometry
        from ..default_model import default_model_path

        if default_model_path().is_file():
            default, h = _default_model()
            model = default if track.model_hash == h else None
    with claimed(out, owner) as claim:
        taken = earlier_output(out, planned, claim)
        if not taken:
            overwrite = overwrite or still_planned(out, planned)
            with own_output(out, overwrite):
                out = export_track(track, fmt, out, model=model, overwrite=overwrite,
                                   texture=texture, neutral=neutral, labels=labels)
    return Row(clip=job.name, status="done", frames=track.n_frames, fps=track.fps,
               seconds=time.perf_counter() - t0,
               mean_confidence=float(np.mean(track.confidence)), output=str(out),
               note=claim.note(taken))



def count_frames(video, max_frames: int | None = None) -> int:
    """Frames of a video, counted by decoding as the tracker does (containers' counts can be
    approximate); no more than ``max_frames``.

    Raises
    ------
    VideoError
        Missing, unreadable or empty video (naming the path).
    """
    from ..errors import VideoError
    from ..io.video import iter_frames, video_info

    video_info(video)
    n = sum(1 for _ in iter_frames(video, stop=max_frames))
    if n == 0:
        raise VideoError(f"video {video} has no frames")
    return n

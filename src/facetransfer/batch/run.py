"""Batch runs on a Dask client: many clips tracked, transferred or exported, one task per clip.

Every run follows the same steps: check the output folder, refuse an output that is also an
input, skip the jobs an earlier run finished (their output is complete and valid), give the
model to the workers (its file, each worker loading it once: :mod:`.model_ref`), submit,
collect the rows as the clips finish (reporting each to ``progress``), and write
``DIR/summary.csv`` atomically (also every few seconds, and when the run is interrupted:
pending tasks are cancelled, finished outputs stay). A failed clip is a ``failed`` row while
the others go on; so is a clip whose output another run into the same
folder holds (its job's claim, :func:`.ownership.claimed`) or wrote meanwhile (kept, its row's
digest that run's where its summary says it, :data:`OTHER_RUN` otherwise,
:meth:`_Collector._adopted`).

:func:`~.digest.job_key` and :func:`~.digest.options_text` are :mod:`.digest`'s,
:data:`~.jobs.MATTE_FORMATS` and :func:`~.jobs.matte_pattern` :mod:`.jobs`'; they are importable
from here too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from ..io.atomic import same_file
from . import jobs as J
from . import ownership as O
from .chunks import MIN_CHUNK, plan_chunks
from .jobs import MATTE_FORMATS, matte_pattern
from .digest import (is_legacy, job_key, job_keys, legacy_job_key, options_text, same_job,
                     value_text)
from .manifest import BatchError
from .summary import Row, write_summary
from .track_submit import TrackSubmit

log = logging.getLogger(__name__)

__all__ = ["BatchResult", "check_out_dir", "prepare_out_dir", "batch_track", "batch_transfer",
           "batch_export", "job_key", "options_text", "SUMMARY_NAME", "DEFAULT_OVERLAP",
           "MATTE_FORMATS", "matte_pattern", "matte_patterns", "transfer_what"]

SUMMARY_NAME = "summary.csv"
#: Frames shared by neighbouring chunks (1.2 s at 25 fps).
DEFAULT_OVERLAP = 30
#: Seconds between rewrites of the summary while a run goes on.
SUMMARY_EVERY = 5.0

Progress = Callable[[Row], None]


@dataclass(frozen=True)
class BatchResult:
    """The rows of a run (in job order) and the summary file written."""

    rows: tuple[Row, ...]
    summary: Path

    @property
    def n_failed(self) -> int:
        return sum(r.status == "failed" for r in self.rows)

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.rows)


def check_out_dir(out_dir) -> Path:
    """The output folder checked, not made (a run that fails before its first clip, e.g. on a
    scheduler it cannot reach, leaves no empty folder behind).

    Raises
    ------
    BatchError
        The path is a file, or its parent folder does not exist.
    """
    p = Path(out_dir)
    if p.exists() and not p.is_dir():
        raise BatchError(f"output folder {p} is a file")
    if not p.is_dir() and not (p.parent if str(p.parent) else Path(".")).is_dir():
        raise BatchError(f"the folder {p.parent} of output folder {p} does not exist")
    return p


def prepare_out_dir(out_dir) -> Path:
    """The output folder (:func:`check_out_dir`), created if needed.

    Raises
    ------
    BatchError
        The path is a file, or its parent folder does not exist.
    """
    p = check_out_dir(out_dir)
    if not p.is_dir():
        try:
            p.mkdir()
        except OSError as exc:     # /sys, /proc, a read-only disk: said of the --out folder
            raise BatchError(f"cannot make the output folder {p}: "
                             f"{exc.strerror or exc}") from None
    return p


def _outputs(jobs, out_dir: Path, ext: str) -> dict[str, Path]:
    """``{name: DIR/NAME.ext}`` of the jobs (BatchError where one is the summary or an input);
    the claim files a killed run left in DIR removed (:func:`.ownership.remove_stale_claims`)."""
    O.remove_stale_claims(out_dir)
    outs = {}
    for job in jobs:
        out = out_dir / f"{job.name}{ext}"
        if out.name.casefold() == SUMMARY_NAME:   # the run's own table (before: overwritten)
            raise BatchError(f"output {out} of {job.name!r} is the batch's {SUMMARY_NAME}; "
                             "give the clip another name")
        for p in job.inputs:
            if same_file(Path(p), out):
                raise BatchError(f"output {out} of {job.name!r} is also one of its inputs")
        outs[job.name] = out
    return outs


#: What Dask's cancellation reasons mean for a clip (a task's key is no help to a user).
_CANCELLED = (("scheduler-connection-lost", "the scheduler was lost (stopped, or its machine "
               "gone); run the same command again when it is back"),
              ("already forgotten", "its worker died, more than once (out of memory, or a "
               "crash?): the clip was given up"))


def _error_line(exc: BaseException) -> str:
    msg = str(exc).strip()
    if type(exc).__name__ in ("FutureCancelledError", "CancelledError"):
        for reason, said in _CANCELLED:
            if reason in msg:
                return said
    if isinstance(exc, ValueError) and msg:
        return msg.splitlines()[0]
    return f"{type(exc).__name__}: {msg.splitlines()[0]}" if msg else type(exc).__name__


class _Collector:
    """Collects the rows as futures finish; writes the summary; cancels on Ctrl-C."""

    #: ``{name: output}`` of the run's jobs (a cancelled row names its output)
    outs: dict = {}

    def __init__(self, client, outs: dict, out_dir: Path, rows: dict,
                 progress: Progress | None, unfinished: dict | None = None):
        from dask.distributed import as_completed

        self.client, self.names, self.rows = client, list(outs), dict(rows)
        self.outs = outs
        self.summary = out_dir / SUMMARY_NAME
        # the earlier rows of outputs this run does not make: kept in the summary, so that
        # their digests are not forgotten by a run of some of the clips (before, a later run
        # of them all took a stale output for its own), nor by a run of another format or
        # codec into the folder (before, its rows replaced them: a rerun of the first
        # refused its own outputs, batchfmt55)
        earlier = _earlier_rows(out_dir)
        self.others = [r for r in earlier if not _about(r, outs)]
        self.before = _rows_about(earlier, outs)   # what the summary said as the run began
        # {clip: (digest of a cancelled row, of a failed row)}: what made its output (_unfinished)
        self.unfinished = dict(unfinished or {})
        self.progress = progress
        self.ac = as_completed(loop=client.loop)
        self.what: dict = {}       # future -> (kind, job)
        self.alive: list = []      # every future submitted (cancelled on interrupt)
        self.last_write = time.monotonic()
        self.model_ref = None      # the ModelRef the tasks receive (released at the run's end)

    def add(self, future, kind: str, job) -> None:
        self.what[future] = (kind, job)
        self.alive.append(future)
        self.ac.add(future)

    def finish(self, job, row: Row) -> None:
        self.rows[job.name] = row
        if self.progress is not None:
            self.progress(row)
        if time.monotonic() - self.last_write > SUMMARY_EVERY:
            self.write()

    def fail(self, job, exc: BaseException, out) -> None:
        log.info("%s failed: %s", job.name, exc)
        # an output another run wrote meanwhile is not this job's (before, the row had this
        # run's digest where the output was absent at the start: a rerun took it for its own)
        made = OTHER_RUN if isinstance(exc, O.OutputTaken) else \
            self.unfinished.get(job.name, ("", ""))[1]
        self.finish(job, Row(job.name, "failed", error=_error_line(exc), output=str(out),
                             job=made))

    def write(self) -> Path:
        rows = [self.rows.get(n) or Row(n, "cancelled", output=str(self.outs.get(n) or ""),
                                        job=self.unfinished.get(n, ("", ""))[0])
                for n in self.names]
        self.last_write = time.monotonic()
        return write_summary(self.summary, self._adopted(rows) + self.others)

    def _adopted(self, rows: list) -> list:
        """``rows`` with the failed rows of outputs another run wrote meanwhile
        (:data:`OTHER_RUN`) given that run's digest and matte where the summary now holds its
        row of that output, written since this run began (kept in ``self.rows`` for the
        writes after); else, where the summary said as the run began that a run stopped with
        the same job's task unfinished (a cancelled row of this job's digest: on a scheduler of
        its own the task went on), that job's; else the row keeps :data:`OTHER_RUN`, and a
        rerun of the same command skips the other run's output only if that run's summary was
        the one written last."""
        lost = {n for n, r in self.rows.items() if r.job == OTHER_RUN}
        if not lost:
            return rows
        for n in lost:   # (before, OTHER_RUN: the next run failed the clip, naming --overwrite)
            b = self.before.get(n)
            if b is not None and b.status == "cancelled" and b.job and \
                    b.job == self.unfinished.get(n, ("", ""))[0]:
                self.rows[n] = dataclasses.replace(self.rows[n], job=b.job)
        for r in _earlier_rows(self.summary.parent):
            if r.clip in lost and r.ok and r.job not in ("", OTHER_RUN, UNKNOWN_JOB) and \
                    r != self.before.get(r.clip) and \
                    Path(r.output).name == Path(self.rows[r.clip].output).name:
                self.rows[r.clip] = dataclasses.replace(self.rows[r.clip], job=r.job,
                                                        matte=r.matte)
        return [self.rows.get(r.clip, r) for r in rows]

    @contextlib.contextmanager
    def submitting(self) -> Iterator[None]:
        """The block that gives the workers the model and submits the run's tasks: a Ctrl-C
        there is the run's as in :meth:`run` (what was submitted cancelled, the summary
        written: the rows skipped or finished so far, the others cancelled with the digest of
        what made their output). Before, it ended the run with no summary (a batch of many
        clips submits for seconds, while the first ones run): an output written meanwhile had
        no row of this run to say its job (where the earlier summary's row named the job of
        other options, the next run refused it, "made from other inputs or options")."""
        try:
            yield
        except KeyboardInterrupt:
            self._interrupted()
            raise

    def _interrupted(self) -> None:
        self.client.cancel([f for f in self.alive if not f.done()], force=True)
        self.write()

    def run(self, on_done: Callable) -> BatchResult:
        """Iterate the futures as they finish, calling ``on_done(kind, job, future)``."""
        try:
            for fut in self.ac:
                kind, job = self.what.pop(fut)
                on_done(kind, job, fut)
        except KeyboardInterrupt:
            self._interrupted()
            raise
        if self.model_ref is not None:
            from .model_ref import release

            release(self.client, self.model_ref)
        # the claims its jobs left for a retry of theirs (.ownership.claimed's owner): none
        # runs now
        O.remove_stale_claims(self.summary.parent)
        path = self.write()
        return BatchResult(tuple(self.rows[n] for n in self.names), path)


def _model_future(client, model):
    """What the tasks receive for ``model``: its file's :class:`.model_ref.ModelRef` (each worker
    loads it once; nothing on the cluster that a lost worker takes with it), else (a model with
    no file as it was, a file some workers do not see, or None) the model scattered to every
    worker, as before: a worker lost may then lose every clip left (a warning says so)."""
    from .cluster import scatter_model
    from .model_ref import hosts_without, model_ref

    ref = None if model is None else model_ref(model)
    if ref is not None:
        blind = hosts_without(client, ref)
        if not blind:
            return ref
        log.warning("the workers on %s do not see the model file %s: it is sent to them "
                    "instead (a worker lost may then lose every clip left, where the "
                    "scheduler's active memory manager is on: give --model on a file system "
                    "every worker sees)", ", ".join(blind), ref.path)
    return scatter_model(client, model)


def _start(client, jobs, outs: dict, out_dir: Path, done: dict, progress: Progress | None,
           model, unfinished: dict | None = None):
    """The run's collector (the rows of ``done`` reported; ``unfinished``: the digests of the
    others' rows should they not finish, :func:`_unfinished`), the jobs left to do and the
    model scattered to the workers (None when nothing is left)."""
    col = _Collector(client, {j.name: outs[j.name] for j in jobs}, out_dir, done, progress,
                     unfinished)
    if progress is not None:
        for r in done.values():
            progress(r)
    todo = [j for j in jobs if j.name not in done]
    with col.submitting():
        mf = _model_future(client, model) if todo else None
    from .model_ref import ModelRef

    col.model_ref = mf if isinstance(mf, ModelRef) else None
    return col, todo, mf


def _done_track(out: Path, job, model_hash: str) -> Row | None:
    """The row of an output an earlier run finished (a track of this clip's video with this
    model: skipped), None where there is none (tracked now), or a failed row where ``out``
    holds something else: a file that is not a track, another video's track or another
    model's (replaced only with ``--overwrite``; atomic writes leave no half track, so such a
    file is not this run's)."""
    from ..errors import TrackError
    from ..track.result import Track

    if not out.is_file():
        return None
    why = None
    try:
        t = Track.load(out)
    except TrackError as exc:
        why = f"is not a track ({exc})"
    else:
        made = t.other_video(job.video)
        if made:
            why = f"holds a track of {made}, not of {Path(str(job.video)).name}"
        elif t.model_hash != model_hash:
            why = "holds a track made with another model"
        elif job.max_frames is not None and t.n_frames > job.max_frames:
            why = f"holds a track of {t.n_frames} frames, more than max_frames {job.max_frames}"
        else:
            why = _other_occluders(t, job) or _other_frames(t, job.video)
    if why is not None:
        return Row(job.name, "failed", error=f"{out} {why}; --overwrite replaces it",
                   output=str(out))
    return J.track_row(job.name, t, out, 0.0, status="skipped", note=J.track_note(job, t))


def _other_occluders(track, job) -> str | None:
    """Why ``track`` is not what ``job`` asks of its occluders (tested, or not), or None: a
    summary's digest says so too, but a folder without its summary has only the file."""
    from ..track.occlusion import MIN_RUN

    if job.occluders and track.occluded is None and track.n_frames >= MIN_RUN:
        return "holds a track not tested for occluders (tracked without --occluders)"
    if not job.occluders and track.occluded is not None:
        return "holds a track tested for occluders (--occluders), and this clip is asked without"
    return None


def _other_frames(track, video) -> str | None:
    """Why ``track`` is not of the frames ``video`` holds now (a clip replaced under the same
    name since: before, its track was kept as this run's), or None; a video that cannot be
    read now is the task's to say."""
    from ..io.video import video_info

    try:
        info = video_info(video)
    except (ValueError, OSError):
        return None
    size = (int(info.size[0]), int(info.size[1]))
    if tuple(track.frame_size) != size or abs(float(track.fps) - float(info.fps)) > 1e-3:
        return (f"holds a track of {track.frame_size[0]}x{track.frame_size[1]} frames at "
                f"{track.fps:g} fps; {video} is now {size[0]}x{size[1]} at {info.fps:g} fps")
    return None


def batch_track(jobs, out_dir, model, *, client, options=None, chunk: int = 0,
                overlap: int = DEFAULT_OVERLAP, overwrite: bool = False,
                progress: Progress | None = None) -> BatchResult:
    """Track many clips: ``DIR/NAME.npz`` per clip, as ``facetransfer track`` writes it.

    Parameters
    ----------
    jobs : list of ClipJob
    out_dir : path-like
    model : MultilinearModel
    client : distributed.Client
    options : TrackerSettings or TrackOptions, optional
        The tracker and its options (default: as ``facetransfer track``); bare
        ``TrackOptions`` are the klt tracker's, with the tracker chosen per clip.
    chunk : int
        Clips longer than this many frames are tracked in overlapping chunks in parallel and
        joined (:mod:`facetransfer.batch.chunks`); 0 = every clip in one task.
    overlap : int
        Frames shared by neighbouring chunks.
    overwrite : bool
        Track every clip again, replacing each output there as the run began, not one another
        run writes meanwhile (default: skip clips whose output is complete and valid).
    progress : callable(Row), optional
        Called as each clip finishes (or is skipped).

    Returns
    -------
    BatchResult
    """
    from ..track.options import TrackOptions
    from ..track.settings import TrackerSettings

    if not isinstance(options, TrackerSettings):
        options = TrackerSettings(klt=options or TrackOptions())
    if chunk < 0 or 0 < chunk < MIN_CHUNK:
        raise BatchError(f"--chunk must be 0 (never split) or at least {MIN_CHUNK} frames (a "
                         f"chunk is captured as a clip of its own), got {chunk}")
    if chunk:
        plan_chunks(chunk + 1, chunk, overlap)  # a bad overlap fails before anything runs
    out_dir = prepare_out_dir(out_dir)
    outs = _outputs(jobs, out_dir, ".npz")
    mhash = model.content_hash
    # a track file does not record its options: the summary's digest of them does (the job
    # holds the clip's frame limit: before, a rerun with another --max-frames was "skipped")
    what = (f"track {options_text(options)} chunk={chunk}"
            + (f" overlap={overlap}" if chunk else "") + f" {mhash}")
    keys = job_keys(jobs, what)
    by_name = {j.name: j for j in jobs}
    # (a summary of the format before never holds an --occluders job's track: no legacy key)
    done = {} if overwrite else _kept(jobs, outs, out_dir, keys, lambda out, name: _done_track(
        out, by_name[name], mhash), lambda job: "" if job.occluders else
        legacy_job_key(job, what))
    col, todo, mf = _start(client, jobs, outs, out_dir, done, progress, model,
                           _unfinished(jobs, outs, out_dir, keys))
    run = TrackSubmit(client, col, outs, mf, options, chunk, overlap, keys, _planned(outs),
                      _owners(keys))
    try:
        with col.submitting():
            for job in todo:
                run.submit(job)
        return col.run(run.on_done)
    finally:
        run.held.close()


def _owners(keys: dict) -> dict[str, str]:
    """``{name: owner}`` of a run's jobs (:func:`.ownership.claimed`): the run, by a name of
    its own, and the job's digest. A claim of the same owner is this run's other attempt of
    the job: Dask's scheduler runs a task again when it takes its worker for lost, while the
    first attempt may go on (before, the second failed "is being written by another run")."""
    run = uuid.uuid4().hex[:12]
    return {n: f"{run} {k}" for n, k in keys.items()}


def _earlier_rows(out_dir: Path) -> list[Row]:
    """The rows of the summary an earlier run of ``out_dir`` wrote (none where there is none,
    or it is not one)."""
    from .summary import read_summary

    try:
        return read_summary(out_dir / SUMMARY_NAME)
    except BatchError:                           # none, or not one: nothing is known
        return []


#: A digest standing for "made by a run whose options nobody recorded": an output that
#: finished after a Ctrl-C had cancelled its task (its row says cancelled, with no digest).
UNKNOWN_JOB = "unknown"
#: The digest of a failed row whose output another run wrote while this one went on (two
#: runs into one folder at once, :class:`~facetransfer.batch.ownership.OutputTaken`): made with
#: options this run does not know, so not taken by a rerun as its own.
OTHER_RUN = "another-run"


def _about(row: Row, outs: dict | None) -> bool:
    """Whether ``row`` of a summary is about one of ``outs`` (``{name: output}``; None: any
    output, each clip's last row): its clip's, and its output that file (by name: the project
    may have moved), or not said (a summary of a version before the ``output`` column). A clip exported in two formats, or transferred
    with two codecs, into one folder has a row per output (before, one: the run of the other
    format took it, and a rerun of the first refused its own outputs)."""
    if outs is None:
        return True
    out = outs.get(row.clip)
    return out is not None and (not row.output or Path(row.output).name == Path(out).name)


def _rows_about(rows, outs: dict | None) -> dict[str, Row]:
    """``{clip: row}`` of the ``rows`` about ``outs`` (:func:`_about`), one naming its output
    before one that does not."""
    found: dict[str, Row] = {}
    for r in rows:
        if _about(r, outs) and (r.clip not in found or r.output or outs is None):
            found[r.clip] = r
    return found


def _earlier(out_dir: Path, outs: dict | None = None) -> dict[str, str]:
    """``{clip: job digest}`` of the outputs ``outs`` an earlier run of ``out_dir`` made, kept or
    refused (:func:`_unfinished`: a failed row has the digest of the output it left, if any;
    a cancelled one without a digest :data:`UNKNOWN_JOB`: its output, if it appeared after
    all, was made with options nobody recorded, and is not taken as the next run's: before,
    it was, whatever that run's options)."""
    return {c: r.job or (UNKNOWN_JOB if r.status == "cancelled" else "")
            for c, r in _rows_about(_earlier_rows(out_dir), outs).items()
            if r.job or r.status == "cancelled"}


def _unfinished(jobs, outs: dict, out_dir: Path, keys: dict) -> dict[str, tuple[str, str]]:
    """``{clip: (digest of its row if cancelled, if failed)}``: of an output absent as the run
    starts, this run's digest (only this run's task can write it: a worker finishing it after
    a Ctrl-C or a lost scheduler; before, a cancelled row had none and the next run refused
    such an output, a clip tracked whole that was finishing as the run stopped); of an output
    there, none if cancelled (the task may have replaced it) and the earlier run's if failed
    (the output is that run's still; before, forgotten: the run after took it for its own)."""
    earlier = _earlier(out_dir, outs)
    return {j.name: ((keys[j.name], keys[j.name]) if not outs[j.name].exists()
                     else ("", earlier.get(j.name, ""))) for j in jobs}


#: The end of the line of an output another job made: before, only "--overwrite redoes it",
#: which redoes every clip of the run (a manifest's one changed row: all its clips again).
REDO = "remove it to redo this clip alone, or --overwrite redoes every clip"


def _kept(jobs, outs: dict, out_dir: Path, keys: dict, found,
          legacy: Callable | None = None, before: Callable | None = None) -> dict[str, Row]:
    """The rows of the outputs a rerun keeps: ``found(out, name)`` (a skipped row, or None),
    with this run's job digest; an output the summary says another job made (its inputs or
    options changed since) is a failed row naming ``--overwrite``, not this job's result.
    ``legacy(job)``: the job's digest of the format before; ``before(job)``: of this format
    with the options as a version before wrote them (:func:`.digest.same_job`: a summary an
    older version wrote still keeps what it finished; the row then gets the new digest)."""
    earlier, done = _earlier(out_dir, outs), {}
    said = {c: r for c, r in _rows_about(_earlier_rows(out_dir), outs).items() if r.ok}
    for j in jobs:
        r = found(outs[j.name], j.name)
        if r is None:
            continue
        made = earlier.get(j.name, keys[j.name])
        old = None if legacy is None else (lambda job=j: legacy(job))
        worded = None if before is None else (lambda job=j: before(job))
        if r.ok and not same_job(made, keys[j.name], old, worded):  # (a failed row: its why)
            r = _refused(j.name, outs[j.name], made)
        elif r.ok:
            r = _figures_said(r, said.get(j.name), outs[j.name])
        # a refused output keeps its maker's digest: a later run still knows it
        done[j.name] = dataclasses.replace(r, job=keys[j.name] if r.ok
                                           else earlier.get(j.name, ""))
    return done


def _figures_said(row: Row, earlier: Row | None, out: Path) -> Row:
    """``row`` (of an output kept, made by this job) with the frames, rate and mean confidence
    it does not know taken from ``earlier``, the earlier summary's done or skipped row of that
    output. A result video does not hold its target's confidence, a Live Link Face take or a
    glb its frames, rate or confidence: before, a rerun's summary (a run resumed after a
    Ctrl-C) left those cells empty for every output it kept (batch55)."""
    if earlier is None or Path(earlier.output).name != out.name:
        return row
    return dataclasses.replace(row, **{
        f: getattr(earlier, f) for f in ("frames", "fps", "mean_confidence")
        if getattr(row, f) is None})


def _refused(name: str, out: Path, made: str) -> Row:
    """The failed row of an output that job ``made`` made, not this run's job ``name``."""
    if made == UNKNOWN_JOB:
        why = "was finished after an interrupt, with options not recorded"
    elif made == OTHER_RUN:
        why = ("was written by another run into the folder at the same time, with options "
               "not recorded")
    else:
        why = f"was made from other inputs or options than {name}'s now"
        if is_legacy(made):   # (before this format, a moved folder was "other inputs" too)
            why += (" (or its files were moved or copied since: an older version's summary "
                    "recorded where they lay)")
    return Row(name, "failed", output=str(out), error=f"{out} {why}; {REDO}")


def _done_video(out: Path, name: str) -> Row | None:
    from ..errors import VideoError
    from ..io.video import video_info

    if not out.is_file():
        return None
    try:
        info = video_info(out)
    except VideoError:
        return None
    return Row(name, "skipped", frames=info.n_frames, fps=info.fps, output=str(out))


def matte_patterns(jobs, out_dir: Path, matte: str | None) -> dict[str, Path]:
    """``{name: matte_pattern}`` of the jobs (none without ``matte``).

    Raises
    ------
    BatchError
        ``matte`` is not one of :data:`MATTE_FORMATS`, or a job's name holds ``%`` or ``#``
        (read as the frame number of its matte's files)."""
    if matte is None:
        return {}
    if matte not in MATTE_FORMATS:
        raise BatchError(f"--matte must be one of {', '.join(MATTE_FORMATS)} (an image "
                         f"sequence), got {matte!r}")
    for j in jobs:
        if "%" in j.name or "#" in j.name:
            raise BatchError(f"{j.name!r} cannot name the frames of its matte (% and # are "
                             "a frame number's): give the pair another name (the manifest's "
                             "name column)")
    return {j.name: matte_pattern(out_dir, j.name, MATTE_FORMATS[matte]) for j in jobs}


def _whole_matte(pattern: Path, n_frames: int | None) -> bool:
    """Whether the matte sequence ``pattern`` holds ``n_frames`` frames, numbered one after
    the other (written by :mod:`facetransfer.io.sequence_parts`: all of them or none, each
    file whole)."""
    from ..io.video_sequence import sequence_files

    try:
        numbers = sorted(sequence_files(pattern))
    except (OSError, ValueError):           # no folder, or not one
        return False
    return bool(n_frames) and len(numbers) == n_frames and \
        numbers[-1] - numbers[0] == n_frames - 1


class _TransferOutputs:
    """The ``found`` of :func:`_kept` for ``batch transfer``: a result that decodes
    (:func:`_done_video`), its row naming the matte the earlier row named (the matte made by
    the job of that row's digest, which :func:`_kept` compares) where it is whole, and is the
    one asked for (``mattes``, ``{name: pattern}``; none asked: any)."""

    def __init__(self, out_dir: Path, mattes: dict, outs: dict) -> None:
        self.out_dir, self.mattes = out_dir, mattes
        self.earlier = {c: r.matte for c, r in _rows_about(_earlier_rows(out_dir), outs).items()
                        if r.matte}

    def __call__(self, out: Path, name: str) -> Row | None:
        r = _done_video(out, name)
        if r is None or name not in self.earlier:
            return r
        said = Path(self.earlier[name])    # where the project lies now (it may have moved)
        m = matte_pattern(self.out_dir, name, said.suffix)
        if said.parent.name != m.parent.name or said.name != m.name or \
                self.mattes.get(name, m) != m or not _whole_matte(m, r.frames):
            return r
        return dataclasses.replace(r, matte=str(m))


def batch_transfer(jobs, out_dir, model, *, client, settings: dict, overwrite: bool = False,
                   progress: Progress | None = None, matte: str | None = None) -> BatchResult:
    """Rewrite many targets as ``facetransfer transfer`` does: ``DIR/NAME.mp4`` per pair
    (``DIR/NAME.mov`` when ``settings["video"]`` writes ProRes).

    Parameters
    ----------
    jobs : list of PairJob
    out_dir : path-like
    model : MultilinearModel
    client : distributed.Client
    settings : dict
        See :func:`facetransfer.batch.jobs.transfer_pair`.
    overwrite : bool
        Redo every pair, replacing each result there as the run began, not one another run
        writes meanwhile (default: skip pairs whose video exists and decodes, and whose
        matte, if asked, is whole and named by the earlier row of the same job digest).
    progress : callable(Row), optional
    matte : {"png", "tiff", "exr"}, optional
        Also write each pair's matte (:func:`matte_pattern`, numbered as the result's frames
        from 0, a plate target's from its first number; :mod:`facetransfer.io.matte`). Not in
        the job digest (the result is the same with it or without): a pair whose result is
        kept but whose matte is not whole there is done again, result and matte.

    Returns
    -------
    BatchResult
    """
    mattes = matte_patterns(jobs, Path(out_dir), matte)   # a bad one: before any folder
    out_dir = prepare_out_dir(out_dir)
    prores = getattr(settings.get("video"), "codec", None) == "prores"
    outs = _outputs(jobs, out_dir, ".mov" if prores else ".mp4")
    what, worded = transfer_what(settings, model), _transfer_what_before(settings, model)
    keys = job_keys(jobs, what)
    done = {} if overwrite else _kept(jobs, outs, out_dir, keys,
                                      _TransferOutputs(out_dir, mattes, outs),
                                      lambda job: legacy_job_key(job, worded),
                                      lambda job: job_keys([job], worded)[job.name])
    # a result kept without the matte asked for: the pair done again (its render gives both)
    done = {n: r for n, r in done.items() if not (r.ok and n in mattes and not r.matte)}
    done.update(_mattes_of_other_results(jobs, outs, mattes, done))

    planned, owners = _planned(outs), _owners(keys)
    # a matte beside no result (a render stopped between their commits; the result removed to
    # redo the pair): frames the job removes while still these (before: the pair failed)
    planned_mattes = {n: O.matte_identity(m) for n, m in mattes.items()}

    def submit(job, mf):
        m = mattes.get(job.name)
        return client.submit(J.transfer_pair, job, str(outs[job.name]), mf, dict(settings),
                             None if m is None else str(m), planned=planned[job.name],
                             planned_matte=planned_mattes.get(job.name, ""),
                             owner=owners[job.name], pure=False)

    return _simple(client, jobs, out_dir, outs, done, progress, submit, model, keys)


def _mattes_of_other_results(jobs, outs: dict, mattes: dict, done: dict) -> dict[str, Row]:
    """The failed rows of the pairs to render with a matte (``mattes``; not in ``done``, kept or
    refused already) whose result in the other container is beside theirs
    (:func:`.jobs.other_result`: a run of another codec into the folder) with frames in their
    matte folder: it is that result's, neither replaced nor shared (before, the render cleared
    or rewrote it, and the other result's rerun rendered its pair again for the matte lost).
    Where that folder is absent or empty the other result has no matte, and the pair renders
    its own there (reread55a: it was refused, naming a matte that did not exist)."""
    refused = {}
    for j in jobs:
        other = J.other_result(outs[j.name]) if j.name in mattes else None
        folder = mattes[j.name].parent if other is not None else None
        if other is not None and j.name not in done and folder.is_dir() \
                and any(folder.iterdir()):       # the other result's mattes (none: free)
            refused[j.name] = Row(j.name, "failed", output=str(outs[j.name]), error=(
                f"{folder} is the matte folder of {other} (a run of another codec into "
                f"{other.parent}): give this run another --out folder, or no --matte"))
    return refused


def _planned(outs: dict) -> dict[str, str]:
    """``{name: which file its output is now}`` (:func:`.ownership.output_identity`, "" none):
    an output there that the run does again (every one with ``--overwrite``; without it, a
    result rendered again for its matte or that does not decode, a take of an earlier
    version) is replaced only while it is still that file; one absent is written only if
    still absent (before, the jobs replaced whatever was there as they finished: another
    run's output, unasked; with ``--overwrite``, until the fiftieth session, even one another
    run wrote after this one began). Its job claims it meanwhile (:func:`.ownership.claimed`)."""
    return {n: O.output_identity(o) for n, o in outs.items()}


def transfer_what(settings: dict, model) -> str:
    """The options and model of a ``batch transfer`` in its job digests: the rewrite's
    (:class:`~facetransfer.rewrite_options.RewriteOptions`) and every other setting but those
    that are None by :func:`.digest.options_text` (a dataclass's fields at their defaults left
    out, the video's :class:`~facetransfer.io.video_options.VideoOptions` too). A version that
    adds an option at its default thus leaves every earlier output this job's, as ``batch
    track``'s digest does; before, each setting's ``repr`` was in it
    (:func:`_transfer_what_before`): any option added made every output "made from other inputs
    or options", to be rendered again."""
    from dataclasses import fields

    from ..rewrite_options import RewriteOptions
    from .jobs import rewrite_options

    own = {f.name for f in fields(RewriteOptions)}
    rest = sorted(f"{k}={options_text(v)}" for k, v in settings.items()
                  if k not in own and v is not None)
    return (f"transfer {options_text(rewrite_options(settings))} {' '.join(rest)} "
            f"{model.content_hash}")


def _transfer_what_before(settings: dict, model) -> str:
    """:func:`transfer_what` as facetransfer wrote it before (the ``repr`` of every setting):
    the words of the digests in the summaries it wrote (:func:`.digest.same_job`). Kept as it
    was: do not change it."""
    return f"transfer {sorted((k, repr(v)) for k, v in settings.items())} {model.content_hash}"


def batch_export(jobs, out_dir, fmt: str, *, client, model=None, texture=None,
                 overwrite: bool = False, progress: Progress | None = None,
                 neutral=None, labels: str | None = None) -> BatchResult:
    """Export many track files with :func:`facetransfer.export.export_track`:
    ``DIR/NAME.<ext>`` per track (:data:`~facetransfer.batch.jobs.EXPORT_EXTENSIONS`).

    Parameters
    ----------
    jobs : list of ExportJob
    out_dir : path-like
    fmt : {"livelink", "glb", "usd", "json"}
    client : distributed.Client
    model : MultilinearModel, optional
        None: the default model (``export_track`` checks the tracks were made with it).
    texture : optional
        Passed to ``export_track``.
    overwrite : bool
        Redo every export, replacing each output there as the run began, not one another
        run writes meanwhile (default: skip existing outputs).
    neutral : int or "auto", optional
        Each track's activations measured from this frame's (``export_track``).
    labels : {"app", "clip"}, optional
        A livelink take's timecode labels (``export_track``); None: the default, the app's.
        A take an earlier version wrote, whose digest did not name its labels, is exported
        again (:func:`_without_unnamed_labels`).

    Returns
    -------
    BatchResult
    """
    if fmt not in J.EXPORT_EXTENSIONS:
        raise BatchError(f"--format must be one of {sorted(J.EXPORT_EXTENSIONS)}, got {fmt!r}")
    out_dir = prepare_out_dir(out_dir)
    outs = _outputs(jobs, out_dir, J.EXPORT_EXTENSIONS[fmt])
    keys = job_keys(jobs, _export_what(fmt, value_text(texture), neutral, model, labels))
    done = {} if overwrite else _kept(
        jobs, outs, out_dir, keys,
        lambda out, name: Row(name, "skipped", output=str(out)) if out.is_file() else None,
        lambda job: legacy_job_key(job, _export_what(fmt, repr(texture), neutral, model,
                                                     labels)))
    if fmt == "livelink":      # a take an earlier writer made (its digest's words): again
        done = _without_unnamed_labels(done, jobs, outs, out_dir, (
            _export_what_before(fmt, value_text(texture), neutral, model),
            _export_what_before(fmt, repr(texture), neutral, model)))
        done = _without_unnamed_labels(done, jobs, outs, out_dir, (
            _export_what_labelled(fmt, value_text(texture), neutral, model, labels),
            _export_what_labelled(fmt, repr(texture), neutral, model, labels)))
    planned = _planned(outs)   # a take written again (_without_unnamed_labels), --overwrite
    owners = _owners(keys)
    return _simple(client, jobs, out_dir, outs, done, progress,
                   lambda job, mf: client.submit(J.export_one, job, fmt, str(outs[job.name]), mf,
                                                 texture, neutral, labels,
                                                 planned=planned[job.name],
                                                 owner=owners[job.name], pure=False),
                   model, keys)


#: The signs of a take's head and eye angles in its digest: the app's (the fifty-fourth
#: session: the eyes' yaw, then the head's yaw and roll, turned to them). A take whose digest
#: lacks them was written with the signs before, and is written again.
_TAKE_ANGLES = "app"


def _export_what(fmt: str, texture: str, neutral, model, labels: str | None = None) -> str:
    """The options and model of a ``batch export`` in its digests (``texture``: as text, of the
    file's content, :func:`.digest.value_text`; in the format before, its ``repr``); a take's
    labels always, the default's named (:data:`~facetransfer.export.livelink.DEFAULT_LABELS`):
    a later change of the default is a change of the digest, not a take kept labelled as it
    was; and its angles' signs (:data:`_TAKE_ANGLES`: a take written with the signs before is
    not kept as this version's). The other formats' digests keep the words they had
    (:func:`_export_what_before`)."""
    if fmt != "livelink":
        return _export_what_before(fmt, texture, neutral, model)
    return (f"{_export_what_labelled(fmt, texture, neutral, model, labels)} "
            f"angles {_TAKE_ANGLES}")


def _export_what_labelled(fmt: str, texture: str, neutral, model,
                          labels: str | None = None) -> str:
    """:func:`_export_what` of a take as facetransfer wrote it from when a take's labels were
    named in it until its angles' signs were (before the fifty-fourth session's review: the
    eye yaw, head yaw and head roll turned against the app's). Kept as it was."""
    from ..export.livelink import DEFAULT_LABELS

    return (f"{_export_what_before(fmt, texture, neutral, model)} "
            f"labels {labels or DEFAULT_LABELS}")


def _export_what_before(fmt: str, texture: str, neutral, model) -> str:
    """:func:`_export_what` as facetransfer wrote it before a take's labels were named in it
    (takes counted in the clip's frames; for one version, the app's, unless ``clip`` was said,
    then named). Kept as it was: do not change it."""
    return f"export {fmt} {texture} {neutral!r} " + (
        "default" if model is None else model.content_hash)


def _without_unnamed_labels(done: dict, jobs, outs: dict, out_dir: Path,
                            words: tuple[str, str]) -> dict:
    """``done`` without the refused rows of takes this job wrote in a version whose digest did
    not name their labels, or (called again) their angles' signs (``words``: this job's
    options so worded, in the format of :data:`.digest.KEY_FORMAT` and in the one before it):
    such a take is exported again, with the labels asked for and the app's signs. Before, the
    old default's take (the clip's frames, which Unreal's importer misplaces) was skipped as
    the new default's, and a take of the signs before (its head turning against the app's) as
    this version's; whether such a take is of the clip's labels or the app's cannot be told
    from its digest, so it is not kept."""
    earlier, stale = _earlier(out_dir, outs), set()
    for j in jobs:
        r, made = done.get(j.name), earlier.get(j.name, "")
        if r is not None and not r.ok and made and same_job(
                made, "", lambda job=j: legacy_job_key(job, words[1]),
                lambda job=j: job_keys([job], words[0])[job.name]):
            stale.add(j.name)
    return {n: r for n, r in done.items() if n not in stale}


def _simple(client, jobs, out_dir, outs, done, progress, submit, model, keys) -> BatchResult:
    """A run of one independent task per job; each row records its job digest."""
    col, todo, mf = _start(client, jobs, outs, out_dir, done, progress, model,
                           _unfinished(jobs, outs, out_dir, keys))
    with col.submitting():
        for job in todo:
            col.add(submit(job, mf), "clip", job)

    def on_done(kind, job, fut) -> None:
        try:
            col.finish(job, dataclasses.replace(fut.result(), job=keys[job.name]))
        except Exception as exc:  # noqa: BLE001
            col.fail(job, exc, outs[job.name])

    return col.run(on_done)

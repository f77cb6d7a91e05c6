"""The tasks a batch run sends to the Dask workers, one concept each: track a clip, track a chunk,
join a clip's chunks, transfer a pair, export a track.

Each task is a module-level function (workers import it from the installed package) that reads
its inputs from paths the workers can see, writes its output atomically, and returns a small
:class:`~facetransfer.batch.summary.Row` (or, for a chunk, its track) to the client. The model
arrives as the value of a future scattered once to every worker, never pickled with the task.
A task raises on bad input; the client turns the exception into the clip's failed row.

A task replaces no file but those its run found and chose to redo (``planned``:
:func:`output_identity`, :func:`matte_identity`; every output there as the run began with
``--overwrite``): an output or matte frames another run into the same folder wrote meanwhile
are kept, and the task raises :class:`OutputTaken` (:func:`_own_output`). A task holds its
output while it runs (:func:`claimed`): another run's task of it fails at its start.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .manifest import BatchError
from .summary import Row

log = logging.getLogger(__name__)

__all__ = ["partial_path", "track_row", "track_clip", "ChunkResult", "track_chunk",
           "join_clip", "transfer_pair", "export_one", "count_frames", "EXPORT_EXTENSIONS",
           "MATTE_FORMATS", "matte_pattern", "OutputTaken", "output_identity",
           "matte_identity", "claimed", "claim_path", "remove_stale_claims"]

#: The frame file of each ``batch transfer --matte`` format (image sequences only, one file a
#: frame: :mod:`facetransfer.io.matte`).
MATTE_FORMATS = {"png": ".png", "tiff": ".tif", "exr": ".exr"}

#: Seconds between the saves of a clip's tracking progress (``NAME.partial.npz``): a batch
#: stopped with Ctrl-C ends its workers, which cannot save on the way out, so a run continued
#: later redoes at most this much of each clip (the saves still take at most 5 % of the time,
#: :class:`facetransfer.track.detect_checkpoint.DetectionCheckpoint`).
SAVE_EVERY = 4.0

#: File extension of each ``batch export`` format.
EXPORT_EXTENSIONS = {"livelink": ".csv", "glb": ".glb", "usd": ".usd", "json": ".json"}


def partial_path(out, suffix: str = "") -> Path:
    """Where the tracking of ``out`` keeps its progress (the name ``facetransfer track`` uses)."""
    p = Path(out)
    return p.with_name(p.stem + suffix + ".partial.npz")


def track_row(name: str, track, out, seconds: float, status: str = "done") -> Row:
    """The summary row of a finished track."""
    return Row(clip=name, status=status, frames=track.n_frames, fps=track.fps, seconds=seconds,
               mean_confidence=float(np.mean(track.confidence)), output=str(out))


def _detector_for(init: str, options):
    """As ``facetransfer track``: automatic init and anchoring create MediaPipe themselves; with
    user points it is loaded only if the face is lost (recovery)."""
    from ..track.init import LazyDetector

    return None if (init == "auto" or options.anchor) else LazyDetector()


class OutputTaken(BatchError):
    """A job's output was written by another run while this one went on (two runs into one
    folder at once): that run's file is kept, and the job's row fails (before, the job
    replaced it: both runs said "done", the later one's outputs left)."""


def output_identity(out) -> str:
    """Which file ``out`` is now (:func:`_shared_identity`), "" where there is none: what a
    run records of an output it plans to do again (:func:`transfer_pair`'s ``planned``)."""
    try:
        return _shared_identity(out) if os.path.isfile(out) else ""
    except OSError:
        return ""


def _shared_identity(path) -> str:
    """A file's inode, size and mtime in ns: which file it is, as every machine sharing its
    folder sees it. Not its device number (:func:`facetransfer.io.verified.file_identity`'s),
    each machine's own for a shared disk (NFS): before, a worker on another machine than the
    client's found every output its run planned to do again "written by another run"."""
    st = os.stat(path)
    return f"{st.st_ino}|{st.st_size}|{st.st_mtime_ns}"


def matte_identity(pattern) -> str:
    """Which frames the matte sequence ``pattern`` holds now (their names and
    :func:`_shared_identity`, hashed), "" where none (or no pattern):
    what a run records of a matte it finds beside no result (:func:`transfer_pair`'s
    ``planned_matte``)."""
    if pattern is None:
        return ""
    from ..io.video_sequence import sequence_files

    try:
        files = sorted(sequence_files(Path(pattern)).values())
        said = "\n".join(f"{f.name}|{_shared_identity(f)}" for f in files)
    except (OSError, ValueError):
        return ""
    return hashlib.sha256(said.encode()).hexdigest()[:16] if files else ""


def _taken(out, why: str = "while this run went on", *, frames=None) -> OutputTaken:
    """The error of a job whose output ``out`` (or, given, the matte ``frames`` beside it)
    another run wrote ``why``."""
    o = Path(out)
    what, kept, it = (f"the frames {frames}", "they are", "them") if frames else \
        (str(o), "that file is", "it")
    return OutputTaken(f"{what} {'were' if frames else 'was'} written by another run {why} "
                       f"(two runs into {o.parent} at once?): {kept} kept, this run's result "
                       f"not written; run again with --overwrite to replace {it}")


#: Seconds a job tries to take its output's claim that another process holds before it says
#: the output is being written by another run: longer than another run's check of it
#: (:func:`remove_stale_claims`), shorter than any job.
CLAIM_WAIT = 0.5


def claim_path(out) -> Path:
    """The claim file of the output ``out`` (:func:`claimed`): ``DIR/.NAME.EXT.claim``."""
    p = Path(out)
    return p.with_name(f".{p.name}.claim")


@contextlib.contextmanager
def claimed(out):
    """Hold the output ``out`` for the block: an exclusive ``flock`` on its claim file
    (:func:`claim_path`), which names this process, its host and the time; the file is removed
    on leaving. A job of another run that holds it (two runs into one folder at once, with
    ``--overwrite`` or redoing the same result) is said at once: :class:`OutputTaken` naming
    its process and host, before any work. Before, both jobs went on, and where both replaced
    the output (with ``--overwrite``, or both redoing one failed result) the later replaced the
    earlier's without a word. The lock goes with its process (SIGKILL, a crash; on a folder
    shared over NFS, with the lock's lease when its machine is gone), so the claim a dead run
    left is taken over, its file rewritten. Where each machine's locks are its own (an NFS
    mount with ``nolock`` or ``local_lock``: before, said to take no lock) a claim guards only
    against jobs of the same machine; where the file system refuses locks (``ENOLCK``), or
    not POSIX, the block runs without a claim."""
    try:
        import fcntl
    except ImportError:     # pragma: no cover (not POSIX)
        yield
        return
    path = claim_path(out)
    with _held_here(path, out) as key:
        fd = _claim(path, out, fcntl)
        _HELD[key] = -1 if fd is None else fd      # (a fork meanwhile: _forget_claims)
        try:
            yield
        finally:
            _HELD[key] = -1
            if fd is not None:
                _release(path, fd)


def _release(path: Path, fd: int) -> None:
    """Remove the claim file ``path`` this process holds (``fd``), while it is still the file
    locked (where locks are each machine's own, an NFS mount with ``local_lock`` or
    ``nolock``, a run on another one may have put its own there: before, removed held), and
    let go of it."""
    with contextlib.suppress(OSError):
        if os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False)):
            os.unlink(path)     # held: no other job has it open and locked
    os.close(fd)


#: The claim files (real paths) this process holds (:func:`_held_here`), each with its
#: locked descriptor (-1: none yet, or none), and their lock.
_HELD: dict[str, int] = {}
_HELD_LOCK = threading.Lock()


def _forget_claims() -> None:
    """In a child forked while this process held claims (the tracker's detector of a clip's
    second part, a render's processes): close its copies of their descriptors, so that a claim
    ends with its job's process (a ``flock`` is held while any copy is open). Before, a worker
    killed (SIGKILL, the OOM killer) left its claim held by such a child while it went on,
    and the next run's job was told a run that was gone was writing the output."""
    global _HELD_LOCK
    for fd in _HELD.values():
        if fd >= 0:
            with contextlib.suppress(OSError):
                os.close(fd)
    _HELD.clear()
    _HELD_LOCK = threading.Lock()     # (another thread may have held it as this one forked)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_claims)


@contextlib.contextmanager
def _held_here(path: Path, out):
    """Note the claim file ``path`` as held by this process for the block (which is given its
    key in :data:`_HELD`); :class:`OutputTaken` where a thread of it holds it already. Where
    a lock is the process's, not its open file's (``flock`` over NFS, which Linux makes a
    POSIX lock), another thread's lock of it would succeed, and its close let go of the
    first's: before, two jobs of one output in one process (a worker's threads) both held it.
    :func:`remove_stale_claims` keeps those noted."""
    key = os.path.realpath(path)
    with _HELD_LOCK:
        if key in _HELD:
            raise _busy(out, _words(path))
        _HELD[key] = -1
    try:
        yield key
    finally:
        with _HELD_LOCK:
            _HELD.pop(key, None)


def _words(path: Path) -> str:
    """The words of the claim file ``path`` (its holder), "" where none can be read."""
    try:
        with open(path, "rb") as f:
            return f.read(512).decode("utf-8", "replace").strip()
    except OSError:
        return ""


def _claim(path: Path, out, fcntl) -> int | None:
    """The descriptor of ``path`` opened and locked by this process (None where it cannot be
    locked); :class:`OutputTaken` where another process holds it for longer than
    :data:`CLAIM_WAIT` (another run's planning locks it for a moment to see whether it is
    held, :func:`remove_stale_claims`: before, a job making its claim then failed). A file
    removed or replaced between its opening and its lock (its holder finished) is opened
    again."""
    import socket

    deadline = time.monotonic() + CLAIM_WAIT
    for _ in range(200):
        fd = _open_claim(path)
        if fd is None:
            return None    # a folder that cannot be written: the write says so
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 512).decode("utf-8", "replace").strip()
            os.close(fd)
            if time.monotonic() < deadline:
                time.sleep(0.02)
                continue
            raise _busy(out, holder) from None
        except OSError:     # ENOLCK, EOPNOTSUPP: no locks here
            _drop_unlockable(path, fd)
            return None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False))
        except OSError:
            same = False
        if same:
            said = (f"pid {os.getpid()} on host {socket.gethostname()}, since "
                    f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
            with contextlib.suppress(OSError):   # (another user's claim left: read-only)
                os.ftruncate(fd, 0)
                os.write(fd, said.encode())
            return fd
        os.close(fd)
    return None     # pragma: no cover (a claim made and removed 200 times meanwhile)


def _drop_unlockable(path: Path, fd: int) -> None:
    """Close ``fd``, the claim file ``path`` that cannot be locked, and remove the file while
    it is that one, empty (made to be locked, by this job or another as unable to lock it;
    one with words is a holder's, where its machine can lock): before, every job there left
    its own, which no run could remove (:func:`remove_stale_claims` cannot lock it either)."""
    with contextlib.suppress(OSError):
        st = os.fstat(fd)
        if st.st_size == 0 and os.path.samestat(st, os.stat(path, follow_symlinks=False)):
            os.unlink(path)
    os.close(fd)


def remove_stale_claims(out_dir) -> list[Path]:
    """Remove the claim files (:func:`claimed`) in ``out_dir`` that no process holds: left by
    a run killed or stopped while its jobs ran (their workers ended without removing them).
    One held is kept (by another process, or by a job of this one, :func:`_held_here`); one
    made meanwhile by a job of another process not yet holding it is removed, and that job
    makes another (:func:`_claim`). Returns those removed."""
    try:
        import fcntl
    except ImportError:     # pragma: no cover (not POSIX)
        return []
    removed = []
    try:
        names = [n for n in os.listdir(out_dir) if n.startswith(".") and n.endswith(".claim")]
    except OSError:
        return removed
    for name in names:
        path = Path(out_dir) / name
        with _HELD_LOCK:    # (a job of this process claims it after the check, or before)
            if os.path.realpath(path) not in _HELD and _remove_unheld(path, fcntl):
                removed.append(path)
    return removed


def _remove_unheld(path: Path, fcntl) -> bool:
    """Remove the claim file ``path`` if no process holds it (and it is still the file
    locked); whether it was removed."""
    fd = _open_claim(path, create=False)
    if fd is None:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False)):
            os.unlink(path)
            return True
    except OSError:      # held (a job running), gone, or no locks here
        pass
    finally:
        os.close(fd)
    return False


def _open_claim(path: Path, create: bool = True) -> int | None:
    """``path`` opened (made if absent) for its lock: to write, else, where another user's
    run left it, to read (a lock needs no more); None where it cannot be opened."""
    for flags in (os.O_RDWR | (os.O_CREAT if create else 0), os.O_RDONLY):
        try:
            return os.open(path, flags | os.O_NOFOLLOW, 0o666)
        except PermissionError:
            continue
        except OSError:
            return None
    return None


def _busy(out, holder: str) -> OutputTaken:
    """The error of a job whose output ``out`` another run's job holds (``holder``: its claim
    file's words, its process, host and start; "" not yet written)."""
    o = Path(out)
    return OutputTaken(f"{o} is being written by another run ("
                       + (f"{holder}; " if holder else "")
                       + f"two runs into {o.parent} at once?): left to it, this run's result "
                       "not written; run the same command again once that run has ended")


def _frames_there(pattern) -> bool:
    """Whether the image sequence ``pattern`` (a matte) has frames (None: no pattern)."""
    if pattern is None:
        return False
    from ..io.video_sequence import sequence_files

    try:
        return bool(sequence_files(Path(pattern)))
    except (OSError, ValueError):
        return False


@contextlib.contextmanager
def _own_output(out, overwrite: bool, matte=None):
    """Guard the block that writes ``out`` (and the frames of ``matte``); it writes nothing
    itself. With ``overwrite`` the block may replace them. Without it, the run found no
    ``out`` when it planned the job (or, :func:`_still_planned`, no longer finds the one it
    planned to redo), so an ``out`` there now, or frames of ``matte`` that appeared during the
    block, are another run's (the block's write commits without replacing,
    :func:`facetransfer.io.atomic.atomic_path`): :class:`OutputTaken`, before the block runs
    or when its write is refused."""
    if overwrite:
        yield
        return
    if os.path.isfile(out):
        raise _taken(out, "since this run began")
    from ..errors import VideoError

    had_frames = _frames_there(matte)
    try:
        yield
    except (ValueError, OSError) as exc:
        # frames placed meanwhile refuse the matte's placement (VideoError), which comes
        # before the result's: frames of its own then, and a failed result, are not another's
        if os.path.isfile(out) or (isinstance(exc, VideoError) and not had_frames
                                   and _frames_there(matte)):
            raise _taken(out) from None
        raise


def _track(video, model, init: str, settings, *, source: str, checkpoint, fixed=None,
           tracker: str | None = None, view=None, face: str | None = None,
           max_frames: int | None = None):
    """As ``facetransfer track``: the tracker ``settings`` choose for ``init`` (or ``tracker``);
    ``view``: how frames given as an array are shown (:class:`facetransfer.track.aspect.View`
    of their video); ``face``: of several people, the one the capture tracker follows."""
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
                           checkpoint_every=SAVE_EVERY, max_frames=max_frames)
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
               planned: str = "") -> Row:
    """Track a whole clip exactly as ``facetransfer track VIDEO --out OUT`` does and write it.

    Parameters
    ----------
    job : ClipJob
    out : str
        ``DIR/NAME.npz``.
    model : MultilinearModel
    options : TrackerSettings
    overwrite : bool
        Replace whatever ``out`` is there; without it, an ``out`` that another run wrote since
        this one was planned is kept (:class:`OutputTaken`).
    planned : str
        Without ``overwrite``: the :func:`output_identity` of the ``out`` the run found and
        does again (the batch's ``--overwrite``), replaced while it is still that file
        (:func:`_still_planned`).

    The job holds its output while it runs (:func:`claimed`): another run's job of it then
    fails at its start (:class:`OutputTaken`), its progress file left to that run.

    Returns
    -------
    Row
    """
    from ..io.video import video_info

    t0 = time.perf_counter()
    video_info(job.video)  # missing / not a video: one line naming the path
    with claimed(out):
        overwrite = overwrite or _still_planned(out, planned)
        try:
            with _own_output(out, overwrite):
                track = _track(str(job.video), model, job.init, options,
                               source=str(job.video), checkpoint=partial_path(out),
                               face=job.face, max_frames=job.max_frames)
                track = track.with_source_facts(job.video)   # its numbering, before it moves
                track.save(out, overwrite=overwrite)
        except OutputTaken:   # the other run's track is whole: no progress to keep for it
            partial_path(out).unlink(missing_ok=True)
            raise
        partial_path(out).unlink(missing_ok=True)   # the capture tracker's progress, if any
    return track_row(job.name, track, out, time.perf_counter() - t0)


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
        track = _track(frames, model, init, options, source=str(job.video), fixed=fixed,
                       checkpoint=partial_path(out, f".chunk{chunk.index:03d}"),
                       tracker=tracker, view=View.of(job.video), face=job.face)
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
    held = held_identity(det, model, options.capture, identity)
    if held is None and det.found.any():
        log.warning("%s: frames %d-%d begin on another face than the clip's first (a cut "
                    "before them): captured with their own identity", source, chunk.start,
                    chunk.stop - 1)
    return capture_detections(det, model, options=options.capture, fps=fps, frame_size=size,
                              source=src, fixed=held)


def join_clip(job, out: str, model, chunks, results, overwrite: bool = False,
              planned: str = "") -> Row:
    """Join a clip's chunk tracks (:func:`~facetransfer.batch.chunks.join_tracks`) and write
    ``out`` (``overwrite``, ``planned`` and its claim: as :func:`track_clip`'s)."""
    from .chunks import join_tracks

    t0 = time.perf_counter()
    with claimed(out):
        overwrite = overwrite or _still_planned(out, planned)
        with _own_output(out, overwrite):
            track = join_tracks([r.track for r in results], chunks, model)
            track = track.with_source_facts(job.video)
            track.save(out, overwrite=overwrite)
    return track_row(job.name, track, out,
                     sum(r.seconds for r in results) + time.perf_counter() - t0)


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
                  overwrite: bool = False, planned: str = "", planned_matte: str = "") -> Row:
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
        Replace an existing ``out`` and ``matte`` (the batch's ``--overwrite``).
    planned : str
        Without ``overwrite``: the :func:`output_identity` of the ``out`` the run found and
        chose to render again (its own result, redone for the matte asked; a file that does
        not decode; any, with the batch's ``--overwrite``), replaced, with its matte, while it
        is still that file, under the job's claim (:func:`claimed`); "" (none found):
        an ``out`` or matte frames another run wrote meanwhile are kept (:class:`OutputTaken`).
    planned_matte : str
        Without ``overwrite``: the :func:`matte_identity` of the frames of ``matte`` the run
        found; beside no ``out`` (:func:`_clear_leftover_matte`) removed while they are still
        those, before the render.

    Returns
    -------
    Row
    """
    from ..io.video import video_info
    from ..take import is_take
    from ..video_transfer import TransferSources, transfer_video

    t0 = time.perf_counter()
    s = job.sources
    for v in (job.target, s.get("expression_from"), s.get("viseme_from"),
              s.get("identity_from"), s.get("pose_from")):
        if v and not is_take(v):   # a take (Live Link Face CSV) is read by the plan
            video_info(v)  # a missing or unreadable input fails the row, naming the path
    options = rewrite_options(settings)
    sources = TransferSources.of(
        str(job.target), target_track=s.get("target_track"),
        expression_from=s.get("expression_from"),
        expression_track=s.get("source_track"), viseme_from=s.get("viseme_from"),
        viseme_track=s.get("viseme_track"), identity=_identity(job, model),
        identity_from=s.get("identity_from"), identity_track=s.get("identity_track"),
        pose_from=s.get("pose_from"), pose_track=s.get("pose_track"),
        performance=s.get("performance"), target_face=s.get("target_face"),
        source_face=s.get("source_face"))
    with claimed(out):
        overwrite = overwrite or _still_planned(out, planned)
        if not overwrite:
            _clear_leftover_matte(out, matte, planned_matte)
        with _own_output(out, overwrite, matte):
            res = transfer_video(sources, out, model, overwrite=overwrite, options=options,
                                 progress_factory=None, align=settings["align"],
                                 max_frames=settings["max_frames"], parallel=False,
                                 video_options=settings.get("video"), matte=matte)
        _remove_other_mattes(Path(out).parent, job.name, matte)
    conf = res.plan.target_track.confidence[:res.n_frames]
    return Row(clip=job.name, status="done", frames=res.n_frames, fps=res.plan.fps,
               seconds=time.perf_counter() - t0, mean_confidence=float(np.mean(conf)),
               output=str(out), matte="" if res.matte is None else str(res.matte))


def _still_planned(out, planned: str) -> bool:
    """Whether ``out`` is still the file ``planned`` (:func:`output_identity`) the run chose to
    render again (may be replaced); False where none was planned or none is there now;
    :class:`OutputTaken` where another file is there now (another run's)."""
    if not planned:
        return False
    now = output_identity(out)
    if now and now != planned:
        raise _taken(out, "since this run began")
    return bool(now)


def _clear_leftover_matte(out, matte, planned: str) -> None:
    """Before a pair's render without ``--overwrite``: the frames of ``matte`` there beside no
    result ``out`` (a render stopped between the two commits, the matte's first; the result
    removed to redo the pair, as a failed row says) are removed if they are still the frames
    ``planned`` (:func:`matte_identity`) the run found: ``NAME.matte/`` holds the matte of
    ``NAME.mp4`` or none. Before, the render refused them ("pass --overwrite", which redoes
    every pair) and the pair failed at every rerun. Other frames there now are another run's
    (:class:`OutputTaken`); an ``out`` there is :func:`_own_output`'s to say."""
    now = matte_identity(matte)
    if not now or os.path.isfile(out):
        return
    if now != planned:
        raise _taken(out, "since this run began", frames=matte)
    from ..io.video_sequence import sequence_files

    for f in sequence_files(Path(matte)).values():
        f.unlink(missing_ok=True)


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
               labels=None, overwrite: bool = False, planned: str = "") -> Row:
    """Export one track file with :func:`facetransfer.export.export_track` to ``out``
    (``neutral``: its neutral frame, :mod:`facetransfer.export.neutral`; ``labels``: a
    livelink take's timecode labels, None the default; ``overwrite``: as
    :func:`track_clip`'s; ``planned``: as :func:`transfer_pair`'s, the take of an earlier
    version the run writes again, or any with the batch's ``--overwrite``; claimed as
    :func:`track_clip`'s output).

    Without ``model``, a track made with the default model gets the worker's cached copy of
    it; any other track is left to ``export_track``'s own check (``model=None``).
    """
    from ..export import export_track
    from ..track.result import Track

    t0 = time.perf_counter()
    track = Track.load(job.track)
    if model is None and fmt in ("glb", "usd"):  # livelink and json need no geometry
        from ..default_model import default_model_path

        if default_model_path().is_file():
            default, h = _default_model()
            model = default if track.model_hash == h else None
    with claimed(out):
        overwrite = overwrite or _still_planned(out, planned)
        with _own_output(out, overwrite):
            path = export_track(track, fmt, out, model=model, overwrite=overwrite,
                                texture=texture, neutral=neutral, labels=labels)
    return Row(clip=job.name, status="done", frames=track.n_frames, fps=track.fps,
               seconds=time.perf_counter() - t0,
               mean_confidence=float(np.mean(track.confidence)), output=str(path))



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

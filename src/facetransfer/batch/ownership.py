"""Which run owns a batch output: what a run records of the outputs it plans to redo, the claim a
job holds on its output while it writes it, and the error of an output another run took.

Two runs into one folder at once (the forty-ninth and fiftieth sessions, BENCHMARKS.md): a task
replaces no file but those its run found and chose to redo (``planned``: :func:`output_identity`,
:func:`matte_identity`; every output there as the run began with ``--overwrite``); an output or
matte frames another run wrote meanwhile are kept, and the task raises :class:`OutputTaken`
(:func:`own_output`). A task holds its output while it runs (:func:`claimed`): another run's
task of it fails at its start; a task of the same run's same job (Dask's scheduler ran it
again, taking the first attempt's worker for lost) waits for the first attempt and takes its
output (:class:`Claim`, :func:`earlier_output`). Used by the tasks of
:mod:`facetransfer.batch.jobs`, and by :func:`facetransfer.batch.run.batch_track` for the
chunks of a clip (``part="chunks"``).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from .manifest import BatchError

__all__ = ["OutputTaken", "output_identity", "matte_identity", "claimed", "claim_path",
           "remove_stale_claims", "own_output", "still_planned", "clear_leftover_matte",
           "Claim", "earlier_output", "RETRY_WAIT"]


class OutputTaken(BatchError):
    """A job's output is another run's (two runs into one folder at once): written by it
    while this one went on (:func:`own_output`, :func:`still_planned`), or being written by
    it, its claim held (:func:`claimed`). That run's file is kept, and the job's row fails
    (before, the job replaced it: both runs said "done", the later one's outputs left)."""


def output_identity(out) -> str:
    """Which file ``out`` is now (:func:`_shared_identity`), "" where there is none: what a
    run records of an output it plans to do again (:func:`~.jobs.transfer_pair`'s ``planned``)."""
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
    what a run records of a matte it finds beside no result (:func:`~.jobs.transfer_pair`'s
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

#: Seconds a job waits for this run's other attempt of the same job to let go of its output
#: (:func:`claimed`'s ``owner``): Dask's scheduler runs a task again on another worker when it
#: takes the first one's for lost (its heartbeat missed: a long call holding the GIL, a
#: paused or overloaded machine) while that attempt may still run. An embedded cluster's
#: nanny ends such a worker within seconds (4 s, Dask 2026.8); a worker without one may
#: finish the job.
RETRY_WAIT = 300.0


@dataclass(frozen=True)
class Claim:
    """What a job found as it took its output's claim (:func:`claimed`).

    Attributes
    ----------
    waited : float
        Seconds it waited for this run's other attempt of the job to let go of it.
    earlier : str
        The words (process, host, start) of this run's other attempt of the same job that
        held the claim (waited for) or left it (its worker killed); "" none: another run's,
        or no claim there.
    """

    waited: float = 0.0
    earlier: str = ""

    @property
    def past_checks(self) -> bool:
        """Whether that attempt had passed its checks (:data:`CHECKED`): what is there now
        that the run did not find may be its writing, none of another run's."""
        return CHECKED in self.earlier.splitlines()

    def note(self, taken: bool) -> str:
        """The note of a done row after such an attempt (its summary's ``note`` column, ""
        none): its output taken (``taken``) or made again."""
        if not self.earlier:
            return ""
        who = self.earlier.splitlines()[0]
        said = (f"this run's earlier attempt of the job ({who}; Dask ran it again, taking "
                "its worker for lost)")
        waited = f" after waiting {self.waited:.1f} s for it" if self.waited else ""
        return (f"{said} wrote the output: taken{waited}" if taken else
                f"{said} ended without the output: done again{waited}")


def earlier_output(out, planned: str, claim: Claim) -> bool:
    """Whether ``out`` is the output this run's earlier attempt of the job wrote
    (``claim.earlier``, :func:`claimed`): the file that attempt said it left as it ended
    ("done" and its :func:`output_identity`); where it did not end (killed) but had passed its
    checks ("checked", :func:`own_output`), there and another file than the one the run found
    (``planned``): between that attempt's claim and this one's no job of another run held it
    (it would have rewritten the claim's words), and a job writes its output only under its
    claim, past its checks. Killed before them, a file there that the run did not plan is
    not that attempt's (another run's, finished before it; a user's): not taken (before,
    taken, with this run's digest)."""
    if not claim.earlier:
        return False
    now = output_identity(out)
    said = [ln[5:] for ln in claim.earlier.splitlines() if ln.startswith("done ")]
    return bool(now) and (now == said[-1] if said else claim.past_checks and now != planned)


#: The line a job adds to its claim's words once it has passed its checks
#: (:func:`own_output`): what it writes from then on is its own (:func:`earlier_output`).
CHECKED = "checked"


def _say_checked(out) -> None:
    """Add :data:`CHECKED` to the words of the claim of ``out`` this process holds (none
    held: nothing)."""
    fd = _HELD.get(os.path.realpath(claim_path(out)), -1)
    if fd >= 0:
        with contextlib.suppress(OSError):
            os.pwrite(fd, f"\n{CHECKED}".encode(), os.fstat(fd).st_size)


def claim_path(out, part: str = "") -> Path:
    """The claim file of the output ``out`` (:func:`claimed`): ``DIR/.NAME.EXT.claim``
    (``part``: of that part of its work, ``DIR/.NAME.EXT.PART.claim``)."""
    p = Path(out)
    return p.with_name(f".{p.name}{'.' + part if part else ''}.claim")


@contextlib.contextmanager
def claimed(out, owner: str = "", part: str = ""):
    """Hold the output ``out`` for the block: an exclusive ``flock`` on its claim file
    (:func:`claim_path`), which names this process, its host and the time; the file is removed
    on leaving (with an ``owner``, after the block ran, kept for a retry: :func:`_release`).
    A job of another run that holds it (two runs into one folder at once, with
    ``--overwrite`` or redoing the same result) is said at once: :class:`OutputTaken` naming
    its process and host, before any work. Before, both jobs went on, and where both replaced
    the output (with ``--overwrite``, or both redoing one failed result) the later replaced the
    earlier's without a word. The lock goes with its process (SIGKILL, a crash; on a folder
    shared over NFS, with the lock's lease when its machine is gone), so the claim a dead run
    left is taken over, its file rewritten. Where each machine's locks are its own (an NFS
    mount with ``nolock`` or ``local_lock``: before, said to take no lock) a claim guards only
    against jobs of the same machine; where the file system refuses locks (``ENOLCK``), or
    not POSIX, the block runs without a claim.

    ``owner`` names the run and the job (its digest), written in the claim: a claim held by
    the same ``owner`` is this run's other attempt of the job (Dask ran the task again,
    taking its worker for lost), waited for up to :data:`RETRY_WAIT` seconds (a
    :class:`~.manifest.BatchError` after), not refused: before, the retry failed "is being
    written by another run" and the row said failed while the first attempt finished the
    output. The block is given a :class:`Claim` saying what was found (:func:`earlier_output`).
    ``part``: a claim of that part of the output's work (:func:`claim_path`), said so."""
    try:
        import fcntl
    except ImportError:     # pragma: no cover (not POSIX)
        yield Claim()
        return
    path = claim_path(out, part)
    with _held_here(path, out, owner, part) as (key, here):
        fd, found = _claim(path, out, fcntl, owner, part)
        _HELD[key] = -1 if fd is None else fd      # (a fork meanwhile: _forget_claims)
        done = ""
        try:
            yield Claim(here.waited + found.waited, found.earlier or here.earlier)
            done = f"done {output_identity(out)}" if owner and not part else ""
        finally:
            _HELD[key] = -1
            if fd is not None:
                _release(path, fd, done)


def _release(path: Path, fd: int, done: str = "") -> None:
    """Remove the claim file ``path`` this process holds (``fd``), while it is still the file
    locked (where locks are each machine's own, an NFS mount with ``local_lock`` or
    ``nolock``, a run on another one may have put its own there: before, removed held), and
    let go of it. ``done`` (a batch job's, :func:`claimed`'s ``owner``: "done" and the
    output's :func:`output_identity`): added to its words and the file kept, for a retry of
    the job that starts after this attempt ended (:func:`earlier_output`); the run removes
    it at its end (:func:`remove_stale_claims`), as does any run's planning."""
    if done:
        with contextlib.suppress(OSError):
            os.pwrite(fd, f"\n{done}".encode(), os.fstat(fd).st_size)
            os.close(fd)
            return
    with contextlib.suppress(OSError):
        if os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False)):
            os.unlink(path)     # held: no other job has it open and locked
    os.close(fd)


#: The claim files (real paths) this process holds (:func:`_held_here`), each with its
#: locked descriptor (-1: none yet, or none), their owners (:func:`claimed`) and words, and
#: their lock.
_HELD: dict[str, int] = {}
_OWNERS: dict[str, tuple[str, str]] = {}
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
    _OWNERS.clear()
    _HELD_LOCK = threading.Lock()     # (another thread may have held it as this one forked)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_claims)


@contextlib.contextmanager
def _held_here(path: Path, out, owner: str = "", part: str = ""):
    """Note the claim file ``path`` as held by this process for the block (which is given its
    key in :data:`_HELD` and a :class:`Claim`); :class:`OutputTaken` where a thread of it
    holds it already, but for the same ``owner`` (this run's other attempt of the job), waited
    for. Where a lock is the process's, not its open file's (``flock`` over NFS, which Linux
    makes a POSIX lock), another thread's lock of it would succeed, and its close let go of
    the first's: before, two jobs of one output in one process (a worker's threads) both held
    it. :func:`remove_stale_claims` keeps those noted."""
    key, t0, earlier = os.path.realpath(path), time.monotonic(), ""
    while True:
        with _HELD_LOCK:
            if key not in _HELD:
                _HELD[key] = -1
                _OWNERS[key] = (owner, _said())
                break
            theirs, words = _OWNERS.get(key, ("", ""))
        if not owner or theirs != owner:
            raise _busy(out, _words(path), part)
        earlier = words
        if time.monotonic() - t0 > RETRY_WAIT:
            raise _still_ours(out, words, time.monotonic() - t0)
        time.sleep(0.05)
    try:
        yield key, Claim(time.monotonic() - t0 if earlier else 0.0, earlier)
    finally:
        with _HELD_LOCK:
            _HELD.pop(key, None)
            _OWNERS.pop(key, None)


def _said() -> str:
    """The words of a claim made now: this process, its host and the time."""
    import socket

    return (f"pid {os.getpid()} on host {socket.gethostname()}, since "
            f"{time.strftime('%Y-%m-%d %H:%M:%S %Z')}")


def _owner_of(words: str) -> str:
    """The owner (:func:`claimed`) a claim file's ``words`` name ("" none: an older
    version's, or none given)."""
    return next((ln[4:] for ln in words.splitlines() if ln.startswith("job ")), "")


def _words(path: Path) -> str:
    """The words of the claim file ``path`` (its holder), "" where none can be read."""
    try:
        with open(path, "rb") as f:
            return f.read(512).decode("utf-8", "replace").strip()
    except OSError:
        return ""


def _claim(path: Path, out, fcntl, owner: str = "",
           part: str = "") -> tuple[int | None, Claim]:
    """The descriptor of ``path`` opened and locked by this process (None where it cannot be
    locked), and what was found (:class:`Claim`); :class:`OutputTaken` where another process
    holds it for longer than :data:`CLAIM_WAIT` (another run's planning locks it for a moment
    to see whether it is held, :func:`remove_stale_claims`: before, a job making its claim
    then failed), or, holding it for this run's same job (``owner``), for longer than
    :data:`RETRY_WAIT` (a :class:`~.manifest.BatchError`). A file removed or replaced
    between its opening and its lock (its holder finished) is opened again."""
    t0, earlier, waited, reopened = time.monotonic(), "", 0.0, 0
    while reopened < 200:
        fd = _open_claim(path)
        if fd is None:
            return None, Claim()   # a folder that cannot be written: the write says so
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 512, 0).decode("utf-8", "replace").strip()
            os.close(fd)
            ours = bool(owner) and _owner_of(holder) == owner
            if ours:
                earlier, waited = holder, time.monotonic() - t0
            if time.monotonic() - t0 < (RETRY_WAIT if ours else CLAIM_WAIT):
                time.sleep(0.05 if ours else 0.02)
                continue
            raise (_still_ours(out, holder, waited) if ours else _busy(out, holder, part)) \
                from None
        except OSError:     # ENOLCK, EOPNOTSUPP: no locks here
            _drop_unlockable(path, fd)
            return None, Claim()
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path, follow_symlinks=False))
        except OSError:
            same = False
        if same:
            left = os.pread(fd, 512, 0).decode("utf-8", "replace").strip()
            if owner and _owner_of(left) == owner:
                earlier = left         # left by this run's attempt of the job, killed
            said = _said() + (f"\njob {owner}" if owner else "")
            with contextlib.suppress(OSError):   # (another user's claim left: read-only)
                os.ftruncate(fd, 0)
                os.pwrite(fd, said.encode(), 0)
            return fd, Claim(time.monotonic() - t0 if waited else 0.0, earlier)
        os.close(fd)
        reopened += 1
    return None, Claim()     # pragma: no cover (a claim made and removed 200 times meanwhile)


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


def _busy(out, holder: str, part: str = "") -> OutputTaken:
    """The error of a job whose output ``out`` (or that ``part`` of its work, ``chunks``)
    another run's job holds (``holder``: its claim file's words, its process, host and start
    on their first line; "" not yet written)."""
    o = Path(out)
    holder = holder.splitlines()[0] if holder else ""
    what = f"{o}: its {part} are being tracked" if part else f"{o} is being written"
    return OutputTaken(f"{what} by another run ("
                       + (f"{holder}; " if holder else "")
                       + f"two runs into {o.parent} at once?): left to it, this run's result "
                       "not written; run the same command again once that run has ended")


def _still_ours(out, holder: str, waited: float) -> BatchError:
    """The error of a job whose output ``out`` this run's earlier attempt of the same job
    (``holder``: its claim's words) still held after ``waited`` seconds."""
    holder = holder.splitlines()[0] if holder else "its process"
    return BatchError(f"{out} is still being written by this run's earlier attempt of the job "
                      f"({holder}; Dask ran it again, taking its worker for lost) after "
                      f"{waited:.0f} s: left to it; run the same command again once it has "
                      "ended (a finished output is then kept)")


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
def own_output(out, overwrite: bool, matte=None):
    """Guard the block that writes ``out`` (and the frames of ``matte``); it writes nothing
    itself. With ``overwrite`` the block may replace them. Without it, the run found no
    ``out`` when it planned the job (or, :func:`still_planned`, no longer finds the one it
    planned to redo), so an ``out`` there now, or frames of ``matte`` that appeared during the
    block, are another run's (the block's write commits without replacing,
    :func:`facetransfer.io.atomic.atomic_path`): :class:`OutputTaken`, before the block runs
    or when its write is refused. Its checks passed, it says so in the output's claim
    (:data:`CHECKED`, held by this process: a batch job's)."""
    if overwrite:
        _say_checked(out)
        yield
        return
    if os.path.isfile(out):
        raise _taken(out, "since this run began")
    _say_checked(out)
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


def still_planned(out, planned: str) -> bool:
    """Whether ``out`` is still the file ``planned`` (:func:`output_identity`) the run chose to
    render again (may be replaced); False where none was planned or none is there now;
    :class:`OutputTaken` where another file is there now (another run's)."""
    if not planned:
        return False
    now = output_identity(out)
    if now and now != planned:
        raise _taken(out, "since this run began")
    return bool(now)


def clear_leftover_matte(out, matte, planned: str) -> None:
    """Before a pair's render without ``--overwrite``: the frames of ``matte`` there beside no
    result ``out`` (a render stopped between the two commits, the matte's first; the result
    removed to redo the pair, as a failed row says) are removed if they are still the frames
    ``planned`` (:func:`matte_identity`) the run found: ``NAME.matte/`` holds the matte of
    ``NAME.mp4`` or none. Before, the render refused them ("pass --overwrite", which redoes
    every pair) and the pair failed at every rerun. Other frames there now are another run's
    (:class:`OutputTaken`); an ``out`` there is :func:`own_output`'s to say."""
    now = matte_identity(matte)
    if not now or os.path.isfile(out):
        return
    if now != planned:
        raise _taken(out, "since this run began", frames=matte)
    from ..io.video_sequence import sequence_files

    for f in sequence_files(Path(matte)).values():
        f.unlink(missing_ok=True)

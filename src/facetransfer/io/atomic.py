"""Atomic output: write to an exclusive temporary file beside the target, then rename over it.

Guarantees, for every output written through :func:`atomic_path`:

* an existing output is never overwritten half-way: a failed or interrupted write (full disk,
  read-only folder, exception, SIGKILL) leaves the old file as it was;
* the temporary file is created with ``O_CREAT | O_EXCL`` (:func:`tempfile.mkstemp`) under a
  unique name, so a symlink planted in the folder is never followed and two writers of the same
  output never share a temporary file (the last rename wins; with ``overwrite=False`` the second
  one is refused);
* a temporary file left behind by a killed process (``.STEM.PID-RANDOM.partSUFFIX``) is removed
  by the next write of the same output, once its process is gone and its lock is free;
* a failed write raises :class:`~facetransfer.errors.OutputError` (a ``ValueError``) naming the
  output and the reason (no space left, read-only folder, permission denied);
* while a command runs (:func:`commit_checks`), no output is committed once an input it reads
  as it goes has changed under it (:func:`check_before_commit`: a model file written over in
  place, whose core is mapped, :func:`facetransfer.model.load_model`): the check's error,
  one line, and the old output kept.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import re
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Iterator

from ..errors import FaceTransferError, OutputError

log = logging.getLogger(__name__)

#: errno values of a write that failed because of where it writes, not what it writes
_WRITE_ERRNOS = {errno.ENOSPC: "no space left on the device",
                 errno.EDQUOT: "disk quota exceeded",
                 errno.EROFS: "the folder is on a read-only file system",
                 errno.EACCES: "permission denied (is the folder read-only?)",
                 errno.EPERM: "operation not permitted (is the folder read-only?)",
                 errno.EFBIG: "the file is too large for the file system",
                 errno.EIO: "input/output error"}


#: The checks of the :func:`commit_checks` scope running (None: none runs).
_CHECKS: list[Callable[[], None]] | None = None


@contextlib.contextmanager
def commit_checks() -> Iterator[None]:
    """A scope (a command's run: :func:`facetransfer.cli.main.main`) in which every output is
    committed only once the checks added to it (:func:`check_before_commit`) pass; the scope
    before it is restored at its end."""
    global _CHECKS
    outer, _CHECKS = _CHECKS, []
    try:
        yield
    finally:
        _CHECKS = outer


def check_before_commit(check: Callable[[], None]) -> None:
    """Run ``check()`` before each output of the running :func:`commit_checks` scope is put in
    place (a process it forks runs them too); to refuse the output it raises, and the output's
    temporary file is removed. Outside a scope (a library's caller), nothing is added."""
    if _CHECKS is not None:
        _CHECKS.append(check)


def run_commit_checks() -> None:
    """Run the running scope's checks (:func:`commit_checks`): before an output is put in place
    here, and by a writer that puts its files in place itself (an image sequence's frames,
    :func:`facetransfer.io.video.place_sequence`)."""
    for check in tuple(_CHECKS or ()):
        check()


def same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are one file (:func:`os.path.samefile`); where either cannot be
    looked at (not there yet), whether their absolute paths are the same."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def check_output_path(path: str | os.PathLike, *, overwrite: bool = True,
                      inputs: Iterable[str | os.PathLike | None] = ()) -> Path:
    """Validate an output path before any work is done.

    Parameters
    ----------
    path : path-like
        The output file.
    overwrite : bool
        With False, an existing ``path`` is refused.
    inputs : iterable of path-like or None
        Files the command reads; ``path`` naming one of them (also through a link) is refused.

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        The parent folder does not exist, is not a folder or cannot be written, ``path`` is
        a folder, ``path`` exists and ``overwrite`` is False, or ``path`` is also an input.
    """
    p = _checked_output(path, overwrite, inputs)
    probe_folder(p)
    return p


def check_not_folder_name(path) -> None:
    """OutputError where an output's name, as given, ends in ``/`` (a folder's name): a
    ``Path`` drops the slash, and ``--out sub.npz/`` wrote a file ``sub.npz``. Callers check
    the argument before making a Path of it."""
    text = os.fspath(path) if isinstance(path, os.PathLike) else str(path)
    if text.endswith(("/", os.sep)) and text.strip("/" + os.sep):
        raise OutputError(f"output {text} ends in '/', a folder's name; give a file name")


def _checked_output(path, overwrite: bool, inputs) -> Path:
    """:func:`check_output_path` but for trying the folder (:func:`atomic_path`'s own
    temporary file does that)."""
    check_not_folder_name(path)
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise OutputError(f"output folder {parent} does not exist (for {p})")
    if not parent.is_dir():
        raise OutputError(f"output folder {parent} is a file, not a folder (for {p})")
    if p.is_dir():
        raise OutputError(f"output {p} is a folder; give a file name")
    check_not_input(p, inputs)
    if not overwrite and (p.exists() or p.is_symlink()):
        raise OutputError(f"output {p} exists; pass --overwrite to replace it")
    return p


def probe_folder(p: Path) -> None:
    """Create and remove a temporary file beside the output ``p`` (:func:`_make_temp`), or in
    the folder above when ``p``'s own is yet to be made: a folder that cannot be written
    (read-only, ``/sys``, ``/proc``; root ignores permission bits, so only trying tells) is
    refused before a long job, not at its end (OutputError naming ``p``)."""
    p = Path(p)
    fd, tmp = _make_temp(p if p.parent.is_dir() else p.parent)
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def check_not_input(output: str | os.PathLike,
                    inputs: Iterable[str | os.PathLike | None]) -> None:
    """Refuse an output path that is also one of ``inputs`` (same file, or same path).

    Raises
    ------
    OutputError
        Naming the output and the input it would destroy.
    """
    p = Path(output)
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        q = Path(inp)
        if (p.exists() and q.exists() and same_file(p, q)) or \
                os.path.abspath(p) == os.path.abspath(q):
            raise OutputError(f"output {p} is also an input ({q}); choose another output name")


def _temp_pattern(p: Path) -> re.Pattern:
    return re.compile(rf"^\.{re.escape(p.stem)}\.(\d+)-[A-Za-z0-9_]+\.part{re.escape(p.suffix)}$")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # exists, another user's
        return True
    return True


def locked_elsewhere(path: str | os.PathLike) -> bool:
    """Whether another process holds an exclusive ``flock`` on the file ``path`` (a writer's
    lock; False when there is no such file)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)   # closing releases a lock taken here
    return False


def remove_stale_temps(path: str | os.PathLike) -> list[Path]:
    """Remove temporary files of ``path`` left by writers that were killed.

    A temporary file is stale when the process named in it is gone and no process holds its
    lock; files of live writers are never touched, nor anything that is not a regular file.

    Returns
    -------
    list of Path
        The files removed.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    pat = _temp_pattern(p)
    removed = []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        m = pat.match(name)
        if not m:
            continue
        q = parent / name
        try:
            if not q.is_file() or q.is_symlink():
                continue
            pid = int(m.group(1))
            if (pid != os.getpid() and _pid_alive(pid)) or locked_elsewhere(q):
                continue
            q.unlink()
        except OSError:
            continue
        removed.append(q)
        log.warning("removed %s, left by an interrupted write of %s", q, p)
    return removed


def write_error(exc: OSError, path: str | os.PathLike) -> OutputError:
    """An :class:`OutputError` naming ``path`` for an ``OSError`` raised while writing it."""
    reason = _WRITE_ERRNOS.get(exc.errno) or (exc.strerror or str(exc))
    return OutputError(f"cannot write {path}: {reason}")


def _is_write_failure(exc: OSError, tmp: Path) -> bool:
    """An OSError from writing ``tmp`` (not from reading some input inside the block)."""
    name = getattr(exc, "filename", None)
    if isinstance(name, (str, bytes, os.PathLike)) and \
            os.path.abspath(os.fsdecode(name)) != os.path.abspath(tmp):
        return False
    return exc.errno in _WRITE_ERRNOS or name is not None


def _make_temp(p: Path) -> tuple[int, Path]:
    parent = p.parent if str(p.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.stem}.{os.getpid()}-", suffix=f".part{p.suffix}",
                                   dir=parent)
    except OSError as exc:
        raise write_error(exc, p) from None
    with contextlib.suppress(OSError):   # best effort: some network file systems cannot lock
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)   # marks the temp as live
    return fd, Path(tmp)


def _commit(tmp: Path, p: Path, *, overwrite: bool) -> None:
    """Make ``tmp`` the output: durable on disk, usual permissions, then renamed in one step
    (once the running scope's checks pass: :func:`commit_checks`)."""
    run_commit_checks()
    st = os.lstat(tmp)   # FileNotFoundError / a link put in its place: the write is not ours
    if not os.path.isfile(tmp) or os.path.islink(tmp):
        raise OutputError(f"cannot write {p}: its temporary file {tmp} was replaced")
    fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW)
    try:
        os.fsync(fd)   # a full disk can surface only here (delayed allocation)
    finally:
        os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    if st.st_mode & 0o777 == 0o600:   # mkstemp's private mode: give the usual umask-based mode
        os.chmod(tmp, 0o666 & ~umask)
    if overwrite:
        os.replace(tmp, p)
        return
    try:
        os.link(tmp, p)   # no-clobber: fails if another writer created p meanwhile
    except FileExistsError:
        raise OutputError(f"output {p} exists; pass --overwrite to replace it") from None
    except OSError:       # file systems without hard links
        if p.exists():
            raise OutputError(f"output {p} exists; pass --overwrite to replace it") from None
        os.replace(tmp, p)
        return
    tmp.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = True,
                inputs: Iterable[str | os.PathLike | None] = ()) -> Iterator[Path]:
    """Yield an exclusive temporary path in the target's folder; rename it to ``path`` on success.

    The temporary file exists (empty) when yielded and keeps the target's suffix, so that writers
    choosing a format by extension (OpenCV, matplotlib, trimesh, numpy) behave as for the final
    name. On any error it is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : path-like
    overwrite : bool
        With False, an existing ``path`` is refused (also one created by another writer while this
        one was writing).
    inputs : iterable of path-like
        Files the job reads; ``path`` must not be one of them.

    Raises
    ------
    OutputError
        Bad output path (see :func:`check_output_path`), or the write failed: no space left,
        read-only folder, permission denied (the message names ``path``).

    Examples
    --------
    >>> with atomic_path("out/model.npz") as tmp:    # doctest: +SKIP
    ...     np.savez(tmp, a=1)
    """
    p = _checked_output(path, overwrite, inputs)  # its temporary file tries the folder
    remove_stale_temps(p)
    fd, tmp = _make_temp(p)
    try:
        yield tmp
        _commit(tmp, p, overwrite=overwrite)
    except OSError as exc:
        _discard(tmp)
        if _is_write_failure(exc, tmp):   # not an input the block was reading
            raise write_error(exc, p) from None
        raise
    except BaseException:
        _discard(tmp)
        raise
    finally:
        os.close(fd)


def _discard(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        if os.path.lexists(tmp):
            os.unlink(tmp)


def write_bytes_atomic(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, *, overwrite: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path."""
    return write_bytes_atomic(path, text.encode("utf-8"), overwrite=overwrite)


def write_image(path: str | os.PathLike, rgb, *, overwrite: bool = True) -> Path:
    """Write an ``(H, W, 3)`` uint8 RGB image atomically (format by extension, OpenCV); a
    uint16 one keeps its 16 bits (in a format that holds them: PNG, TIFF); an ``(H, W, 4)``
    RGBA one its straight alpha (PNG, TIFF).

    Raises
    ------
    FaceTransferError
        If OpenCV cannot write that format or file.
    """
    import cv2
    import numpy as np

    deep = getattr(rgb, "dtype", None) == np.uint16
    img = np.ascontiguousarray(rgb, dtype=np.uint16 if deep else np.uint8)
    with atomic_path(path, overwrite=overwrite) as tmp:
        try:
            ok = cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if img.ndim == 3
                                                    and img.shape[2] == 4 else cv2.COLOR_RGB2BGR))
        except cv2.error as exc:  # e.g. an extension OpenCV has no writer for
            raise FaceTransferError(f"cannot write image {path}: "
                                    f"{str(exc).strip().splitlines()[-1]}") from None
        if not ok:
            raise FaceTransferError(f"cannot write image {path}")
    return Path(path)


def save_figure(fig, path: str | os.PathLike, *, overwrite: bool = True, **savefig_kwargs) -> Path:
    """Save a matplotlib figure atomically and close it (``savefig_kwargs``: dpi, bbox_inches…)."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(path, overwrite=overwrite) as tmp:
            fig.savefig(tmp, **savefig_kwargs)
    finally:
        plt.close(fig)
    return Path(path)

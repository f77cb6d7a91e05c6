"""The memory a job may use, and decoded frames kept on disk where they would not fit in it.

A command that rewrites a video holds its decoded frames (and an expression source's) for the
whole job: the texture of the eye region, the mouth's source frames and the reference frame
are read from anywhere in the clip. At 1080p that is 6.2 MB a frame, 11 GB a minute; at 4K four
times as much. Past :func:`frame_budget` bytes a clip is decoded into a file instead
(:func:`frame_array`): an unnamed temporary file, its space reserved before the first frame is
written and freed when the last view of it goes, mapped into memory so that every consumer sees
an ordinary ``(F, H, W, 3) uint8`` array while the page cache keeps what fits.

Environment
-----------
FACETRANSFER_FRAME_MEMORY
    Most bytes of one clip's decoded frames held in memory (``512M``, ``4G``, a plain number of
    bytes); default :data:`FRAME_MEMORY_FRACTION` of the memory available when it is decoded.
FACETRANSFER_TMPDIR
    Folder of the frame files (default: the system's temporary folder).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile

import numpy as np

from ..errors import VideoError

__all__ = ["FRAME_MEMORY_FRACTION", "available_bytes", "available_memory", "cgroup_headroom",
           "first_frame_count", "frame_array", "frame_budget", "frame_disk_free", "grow_frames",
           "parse_bytes"]

#: Share of the available memory one clip's decoded frames may take (a transfer decodes two
#: clips at once, and tracks and renders beside them).
FRAME_MEMORY_FRACTION = 0.25

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def available_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` in bytes, or None where it cannot be read."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
        return None if text == "max" else int(text)
    except (OSError, ValueError):
        return None


def cgroup_headroom(proc_cgroup: str = "/proc/self/cgroup", root: str = "/sys/fs/cgroup"
                    ) -> int | None:
    """Bytes this process's control group may still take (its memory limit less its usage),
    or None without a limit: a container's limit, which ``/proc/meminfo`` does not show.
    Reads cgroup v2 (``memory.max``, ``memory.current``) and v1 (``memory.limit_in_bytes``,
    ``memory.usage_in_bytes``)."""
    try:
        with open(proc_cgroup) as fh:
            lines = fh.read().splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, path = (line.split(":", 2) + ["", ""])[:3]
        if controllers == "":
            files = (f"{root}{path}/memory.max", f"{root}{path}/memory.current")
        elif "memory" in controllers.split(","):
            files = (f"{root}/memory{path}/memory.limit_in_bytes",
                     f"{root}/memory{path}/memory.usage_in_bytes")
        else:
            continue
        limit, used = _read_int(files[0]), _read_int(files[1])
        if limit is not None and used is not None and limit < (1 << 60):
            return max(limit - used, 0)
    return None


def available_memory() -> int:
    """Bytes of memory available to a new job: the least of :func:`available_bytes` and
    :func:`cgroup_headroom`, else the physical memory, else (nothing readable) 2**62."""
    known = [b for b in (available_bytes(), cgroup_headroom()) if b is not None]
    if known:
        return min(known)
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def parse_bytes(text: str, what: str = "size") -> int:
    """``"512M"``, ``"4G"``, ``"1.5g"``, ``"100000"`` -> bytes (binary units).

    Raises
    ------
    VideoError
        Not a number with an optional unit K, M, G or T.
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)i?B?\s*", str(text), re.IGNORECASE)
    if m is None:
        raise VideoError(f"{what} must be a number of bytes with an optional unit K, M, G or T "
                         f"(e.g. 4G), got {text!r}")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def frame_budget() -> int:
    """Most bytes of one clip's decoded frames to hold in memory (module notes)."""
    env = os.environ.get("FACETRANSFER_FRAME_MEMORY")
    if env:
        return parse_bytes(env, "FACETRANSFER_FRAME_MEMORY")
    return int(FRAME_MEMORY_FRACTION * available_memory())


def _frame_dir() -> str:
    return os.environ.get("FACETRANSFER_TMPDIR") or tempfile.gettempdir()


def frame_disk_free() -> int:
    """Free bytes on the disk of the frame files (0 where that cannot be read)."""
    try:
        return int(shutil.disk_usage(_frame_dir()).free)
    except OSError:
        return 0


#: Most bytes :func:`first_frame_count` reserves when the container's frame count is beyond
#: what memory and disk could hold (a bogus count: some containers report billions).
_RESERVE_BYTES = 1 << 30


def first_frame_count(expect: int, frame_bytes: int, budget: int) -> int:
    """Frames to reserve before the first is decoded: the container's count ``expect``,
    unless it would fit neither in the frame budget nor on the frame files' disk (a bogus
    count): then what the old reservation held in memory (its pages touched only when decoded
    into), or 64 MB of a file (reserved on disk at once), doubled as decoded."""
    need = expect * frame_bytes
    if need <= budget or need <= frame_disk_free():   # the disk asked only past the budget
        return max(expect, 1)
    return max(1, min(_RESERVE_BYTES, max(budget, 1 << 26)) // max(frame_bytes, 1))


def _reserve(fh, nbytes: int, folder: str, what: str) -> None:
    """Give the file ``fh`` ``nbytes`` bytes of disk now (a mapped page written later on a
    full disk would kill the process); a clear error where the disk has not got them."""
    fh.truncate(nbytes)
    if not hasattr(os, "posix_fallocate"):
        return
    try:
        os.posix_fallocate(fh.fileno(), 0, nbytes)
    except OSError as exc:
        if exc.errno not in _NO_ROOM:     # a file system that cannot reserve: written as is
            return
        free = shutil.disk_usage(folder).free
        raise VideoError(f"{what} needs {nbytes / 2**30:.1f} GiB on disk for its frames and "
                         f"{folder} has {free / 2**30:.1f} GiB free "
                         f"({os.strerror(exc.errno)}); set FACETRANSFER_TMPDIR to a folder on "
                         f"a larger disk, or use fewer frames (--max-frames)") from None


#: ``posix_fallocate`` errors that mean the disk (or the user's quota) has no room
_NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def frame_array(n: int, shape: tuple, *, what: str, budget: int | None = None) -> np.ndarray:
    """An uninitialised ``(n, *shape) uint8`` array for decoded frames: in memory when it
    takes at most ``budget`` bytes (default :func:`frame_budget`), else mapped from an unnamed
    temporary file in ``FACETRANSFER_TMPDIR`` whose disk space is reserved now.

    Parameters
    ----------
    n : int
        Frames.
    shape : tuple of int
        One frame's shape, e.g. ``(H, W, 3)``.
    what : str
        The video, for the error message.
    budget : int, optional

    Raises
    ------
    VideoError
        The file's disk cannot hold it.
    """
    n = max(int(n), 1)
    shape = (n,) + tuple(int(s) for s in shape)
    nbytes = int(np.prod(shape))
    budget = frame_budget() if budget is None else int(budget)
    if nbytes <= budget:
        return _anonymous(shape)
    folder = _frame_dir()
    if not os.path.isdir(folder):
        raise VideoError(f"{what} is decoded into a file (its frames exceed the memory budget) "
                         f"but FACETRANSFER_TMPDIR {folder} is not a folder")
    with tempfile.TemporaryFile(dir=folder, prefix="facetransfer-frames-") as fh:
        _reserve(fh, nbytes, folder, what)
        # the map holds its own descriptor: closing the file here leaves it readable, and the
        # disk space goes back when the last view of the map does
        return np.memmap(fh, dtype=np.uint8, mode="r+", shape=shape)


def _anonymous(shape: tuple) -> np.ndarray:
    """An uninitialised ``shape`` uint8 array in a private anonymous mapping of its own, in
    ordinary pages (freed with the last view of it).

    NumPy asks the kernel to back arrays of 4 MB and more with huge pages (``madvise``
    ``MADV_HUGEPAGE``); where the kernel then compacts memory at the first touch of each 2 MB
    (its default ``transparent_hugepage/defrag`` of ``madvise``), a fresh process stalls in
    the kernel writing a clip's decoded frames: 2.0 s of system time for 560 MB of 1080p
    frames, against 0.3 s in ordinary pages (0.1 s when huge pages happen to be free). In
    ordinary pages a 10-second 512² transfer spends 1.5 CPU-s less (BENCHMARKS.md,
    "Twenty-fourth session").
    Frames are read a frame at a time, contiguously: huge pages gain them nothing.

    Private, not shared (Python's default for a map): a shared anonymous map is the kernel's
    shared memory, whose first touch of each page costs more, the more so with two clips
    decoded side by side (two 1080p clips of 300 frames: 2.4-3.0 -> 1.0-1.4 s of system time,
    3.3-3.5 -> 2.7-3.0 s; BENCHMARKS.md, "Thirty-fourth session"). A forked tracker only reads
    the frames, so it shares their pages all the same."""
    import mmap

    n = int(np.prod(shape))
    flags = mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS
    return np.frombuffer(mmap.mmap(-1, max(n, 1), flags=flags), np.uint8, count=n).reshape(shape)


def grow_frames(frames: np.ndarray | None, n: int, size: int, shape: tuple, *, what: str,
                budget: int | None = None) -> np.ndarray:
    """A ``(size, *shape)`` :func:`frame_array` holding the first ``n`` of ``frames`` (None:
    none)."""
    out = frame_array(size, shape, what=what, budget=budget)
    if frames is not None and n:
        out[:n] = frames[:n]
    return out

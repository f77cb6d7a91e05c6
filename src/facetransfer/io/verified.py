"""Checksums already verified, remembered by the file's identity on disk.

:func:`facetransfer.model.load_model` checks a model file's sha256 and scans it for NaN on
every load: 0.4 s of CPU for the default model (470 MB), paid by every command before its work
starts. A file whose device, inode, size and modification time (in ns) are those it had when it
last passed is not read whole again, as git and make trust a file's ``stat``: an altered,
truncated or replaced file has another size, time or inode and is checked in full. What this
cannot see is a file changed in place whose modification time was then set back by hand.

The records live in the user cache (:func:`facetransfer.assets.cache_dir`), one small JSON file
written atomically; the newest :data:`KEEP` are kept. A record that cannot be read or written
only costs the full check.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

log = logging.getLogger(__name__)

__all__ = ["KEEP", "RACY_SECONDS", "RECORD", "file_stamp", "remember_verified", "was_verified"]

#: The record file's name in the user cache.
RECORD = "verified-checksums.json"
#: Files remembered at most (the oldest record is dropped first).
KEEP = 64
#: A file modified less than this long ago is not recorded: file times advance in steps of a
#: few milliseconds, so a rewrite of the same size right after the check could keep its stamp
#: (git's "racily clean" entries).
RACY_SECONDS = 2.0


def _record_path() -> Path:
    from ..assets import cache_dir

    return cache_dir() / RECORD


def file_stamp(path: str | os.PathLike) -> str:
    """The file's identity on disk: resolved path, device, inode, size, mtime in ns (also the
    key of what is read from a file once per process, e.g.
    :func:`facetransfer.io.video_read.video_info`). OSError when it cannot be read."""
    p = Path(path).resolve()
    st = p.stat()
    return f"{p}|{st.st_dev}|{st.st_ino}|{st.st_size}|{st.st_mtime_ns}"


def _read() -> dict[str, str]:
    try:
        data = json.loads(_record_path().read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def was_verified(path: str | os.PathLike, checksum: str) -> bool:
    """True when ``path``, as it is on disk now, was recorded with ``checksum``
    (:func:`remember_verified`)."""
    try:
        stamp = file_stamp(path)
    except OSError:
        return False
    return _read().get(stamp) == checksum


def remember_verified(path: str | os.PathLike, checksum: str) -> None:
    """Record that ``path``, as it is on disk now, matched ``checksum`` (its content was
    hashed and compared by the caller); not if it was modified in the last
    :data:`RACY_SECONDS`."""
    from .atomic import write_text_atomic

    try:
        if time.time() - Path(path).stat().st_mtime < RACY_SECONDS:
            return
        stamp = file_stamp(path)
        records = _read()
        records.pop(stamp, None)
        records[stamp] = checksum                       # newest last
        kept = dict(list(records.items())[-KEEP:])
        write_text_atomic(_record_path(), json.dumps(kept, indent=0))
    except (OSError, ValueError) as exc:   # a read-only or full cache: the full check next time
        log.debug("cannot record the verified checksum of %s: %s", path, exc)

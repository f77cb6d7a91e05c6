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

A file's content digest (:func:`content_digest`: its size and the sha256 of its bytes, what a
batch run's job digest holds of each input) is remembered the same way, by the file's identity
without its path (:func:`file_identity`: a folder renamed or moved on its disk keeps it), in a
record of its own (:data:`DIGESTS`) that a caller reads and writes once
(:func:`remembered_digests`): a rerun does not read gigabytes of video again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from pathlib import Path
from typing import Iterator

log = logging.getLogger(__name__)

__all__ = ["KEEP", "RACY_SECONDS", "RECORD", "file_stamp", "remember_verified", "was_verified",
           "DIGESTS", "KEEP_DIGESTS", "file_identity", "content_digest", "remembered_digests",
           "remember_digest"]

#: The record file's name in the user cache.
RECORD = "verified-checksums.json"
#: Files remembered at most (the oldest record is dropped first).
KEEP = 64
#: A file modified less than this long ago is not recorded: file times advance in steps of a
#: few milliseconds, so a rewrite of the same size right after the check could keep its stamp
#: (git's "racily clean" entries).
RACY_SECONDS = 2.0
#: The record file of content digests (:func:`content_digest`) in the user cache.
DIGESTS = "content-digests.json"
#: Content digests remembered at most (one per input of a batch run; the least recently used
#: is dropped first).
KEEP_DIGESTS = 4096
#: Bytes read at a time when hashing a file.
_BLOCK = 1 << 20


def _record_path(name: str = RECORD) -> Path:
    from ..assets import cache_dir

    return cache_dir() / name


def file_stamp(path: str | os.PathLike) -> str:
    """The file's identity on disk: resolved path, device, inode, size, mtime in ns (also the
    key of what is read from a file once per process, e.g.
    :func:`facetransfer.io.video_read.video_info`). OSError when it cannot be read."""
    p = Path(path).resolve()
    return f"{p}|{file_identity(p)}"


def _read(name: str = RECORD) -> dict[str, str]:
    try:
        data = json.loads(_record_path(name).read_text())
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


def file_identity(path: str | os.PathLike) -> str:
    """The file's identity without its path: device, inode, size, mtime in ns (a file renamed
    or moved on its disk keeps it; a copy, an edit, a replacement has another). OSError when
    it cannot be read."""
    st = os.stat(path)
    return f"{st.st_dev}|{st.st_ino}|{st.st_size}|{st.st_mtime_ns}"


def _sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(_BLOCK):
            h.update(block)
    return h.hexdigest()


def content_digest(path: str | os.PathLike, memo: dict[str, str] | None = None) -> str:
    """``SIZE:SHA256`` of the file's bytes: of its content, not its name or place.

    Parameters
    ----------
    path : path-like
    memo : dict, optional
        Digests by :func:`file_identity` (:func:`remembered_digests`): the file's is taken
        from it if there, else computed and added (:func:`remember_digest`).

    Raises
    ------
    OSError
        The file cannot be read.
    """
    ident = file_identity(path)
    if memo is not None and ident in memo:
        return remember_digest(memo, ident, memo[ident])      # (the most recently used)
    digest = f"{os.stat(path).st_size}:{_sha256(path)}"
    if memo is not None and file_identity(path) == ident:    # not changed while read
        remember_digest(memo, ident, digest, os.stat(path).st_mtime)
    return digest


def remember_digest(memo: dict[str, str], key: str, digest: str,
                    mtime: float | None = None) -> str:
    """Put ``digest`` in ``memo`` under ``key`` as its newest entry, unless ``mtime`` (of the
    newest file it covers) is less than :data:`RACY_SECONDS` ago; returns ``digest``."""
    if mtime is None or time.time() - mtime >= RACY_SECONDS:
        memo.pop(key, None)
        memo[key] = digest
    return digest


@contextlib.contextmanager
def remembered_digests() -> Iterator[dict[str, str]]:
    """The content digests recorded in the user cache, as a dict to read and add to
    (:func:`content_digest`); written back atomically, the newest :data:`KEEP_DIGESTS`, where
    the block changed it, also when it raised (a record that cannot be read or written only
    costs the hashing)."""
    from .atomic import write_text_atomic

    memo = _read(DIGESTS)
    before = list(memo.items())
    try:
        yield memo
    finally:                  # (also after a Ctrl-C: what was hashed is not hashed again)
        if list(memo.items()) != before:
            kept = dict(list(memo.items())[-KEEP_DIGESTS:])
            try:
                write_text_atomic(_record_path(DIGESTS), json.dumps(kept, indent=0))
            except (OSError, ValueError) as exc:
                log.debug("cannot record the content digests: %s", exc)

"""The digest of a batch job (the summary's ``job`` column): what makes its output, not where its
files lie.

A key of the current format (:data:`KEY_FORMAT` and 16 hex digits, ``v2:3f9a0c...``) hashes

* the job's kind and labels (its name; a clip's face and frame limit; a pair's value columns),
* each input file by its role (``video``, ``init``, ``target``, ``expression_from``...) and its
  content (:func:`facetransfer.io.verified.content_digest`: its size and sha256, remembered by
  the file's identity on disk, so that a rerun does not read it again); an image sequence by
  its frames' numbers and contents and the rate said (``FACETRANSFER_SEQUENCE_FPS``); a file
  that cannot be read as missing (its task says why),
* the run's options and model (``what``).

No path is in it: a project folder moved or copied with its clips and its output folder keeps
its outputs, and a clip replaced by another file under the same name has another digest.

The format before it (:func:`legacy_job_key`, 16 hex digits alone) hashed the job's ``repr`` (its
inputs' absolute paths) and each input's :func:`~facetransfer.io.verified.file_stamp` (path,
inode, modification time). A summary of that format is still read (:func:`same_job`): such a
key is compared with this job's key computed the old way, and a run that keeps the output
records the new key in its place.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
from typing import Callable

__all__ = ["KEY_FORMAT", "job_keys", "job_key", "input_digest", "value_text", "legacy_job_key",
           "is_legacy", "same_job", "options_text", "MISSING"]

#: The prefix of a key of the current format.
KEY_FORMAT = "v2:"
#: An input that cannot be read, in a digest.
MISSING = "missing"
#: A key of the format before :data:`KEY_FORMAT` (16 hex digits).
_LEGACY = re.compile(r"[0-9a-f]{16}")


def job_keys(jobs, what: str) -> dict[str, str]:
    """``{job name: job_key(job, what)}``, the inputs' digests remembered in the user cache
    (:func:`facetransfer.io.verified.remembered_digests`) between runs."""
    from ..io.verified import remembered_digests

    with remembered_digests() as memo:
        return {j.name: job_key(j, what, memo) for j in jobs}


def job_key(job, what: str, memo: dict | None = None) -> str:
    """The digest of what makes ``job``'s output (see the module docstring).

    Parameters
    ----------
    job : ClipJob, PairJob or ExportJob
        Any object with ``name``, ``labels`` and ``roles`` as they have.
    what : str
        The run's options and model.
    memo : dict, optional
        Content digests by file identity (:func:`input_digest`).

    Returns
    -------
    str
        :data:`KEY_FORMAT` and 16 hex digits.
    """
    from ..track.obtain import landmarks_file

    h = hashlib.sha256(KEY_FORMAT.encode())
    h.update(f"{type(job).__name__}{tuple(job.labels)!r}".encode())
    for role, path in sorted(job.roles):        # (a manifest's columns in any order)
        h.update(f"|{role}={input_digest(path, memo)}".encode())
        side = landmarks_file(path)   # the precomputed points --tracker landmarks fits to
        if side is not None:
            h.update(f"|{role}.landmarks={input_digest(side, memo)}".encode())
    h.update(f"|{what}".encode())
    return KEY_FORMAT + h.hexdigest()[:16]


def input_digest(path, memo: dict | None = None) -> str:
    """An input's content in a digest: a file's size and sha256, an image sequence's frames
    (:func:`_sequence_digest`), or :data:`MISSING` where it cannot be read."""
    from ..io.verified import content_digest
    from ..io.video_sequence import is_sequence

    try:
        if is_sequence(path):
            return _sequence_digest(path, memo)
        return content_digest(path, memo)
    except (OSError, ValueError):          # none, a folder, unreadable: its task says why
        return MISSING


def _sequence_digest(path, memo: dict | None) -> str:
    """An image sequence's frames (number and content each) and the rate said, remembered
    under its :func:`~facetransfer.io.video_sequence.sequence_stamp` (every frame's name, size
    and time) rather than frame by frame."""
    from ..io.verified import content_digest, remember_digest
    from ..io.video_sequence import SEQUENCE_FPS_VARIABLE, sequence_files, sequence_stamp

    stamp = f"sequence|{sequence_stamp(path)}"
    if memo is not None and stamp in memo:
        return remember_digest(memo, stamp, memo[stamp])
    files = sequence_files(path)
    h = hashlib.sha256()
    for k in sorted(files):
        h.update(f"{k}={content_digest(files[k])};".encode())
    said = os.environ.get(SEQUENCE_FPS_VARIABLE, "").strip()
    digest = f"sequence:{len(files)}:{h.hexdigest()}:{said}"
    if memo is not None and f"sequence|{sequence_stamp(path)}" == stamp:  # not changed since
        newest = max((f.stat().st_mtime for f in files.values()), default=None)
        remember_digest(memo, stamp, digest, newest)
    return digest


def value_text(value) -> str:
    """An option of a run in its ``what``: a path by its file's content
    (:func:`input_digest`), an array by its bytes, anything else by its ``repr``."""
    import numpy as np

    if isinstance(value, (str, os.PathLike)):
        return input_digest(value)
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(value)
        return f"array{data.shape}{data.dtype}:{hashlib.sha256(data.tobytes()).hexdigest()}"
    return repr(value)


def legacy_job_key(job, what: str) -> str:
    """The key of the format before :data:`KEY_FORMAT`: a hash of the job's ``repr``, each
    input's :func:`~facetransfer.io.verified.file_stamp` and ``what``. Kept as it was, to read
    the summaries it wrote (:func:`same_job`): do not change it."""
    from ..io.verified import file_stamp

    h = hashlib.sha256(repr(job).encode())
    for p in job.inputs:
        try:
            h.update(file_stamp(p).encode())
        except OSError:
            h.update(b"missing")
    h.update(what.encode())
    return h.hexdigest()[:16]


def is_legacy(key: str) -> bool:
    """Whether ``key`` is of the format before :data:`KEY_FORMAT`."""
    return bool(_LEGACY.fullmatch(key or ""))


def same_job(made: str, key: str, legacy: Callable[[], str] | None = None,
             before: Callable[[], str] | None = None) -> bool:
    """Whether an output recorded as made by the job ``made`` is the output of the job of
    ``key``: the same key; a key of the format before equal to ``legacy()`` (this job's key
    computed that way); or a key of this format equal to ``before()`` (this job's key with its
    options in the words a version before wrote them: ``batch transfer``'s, which held every
    setting's ``repr``). Each is asked only then."""
    if made == key:
        return True
    if is_legacy(made):
        return legacy is not None and made == legacy()
    return before is not None and made.startswith(KEY_FORMAT) and made == before()


def options_text(options) -> str:
    """The text of a (frozen) dataclass of options in a job's digest: its fields that differ
    from its class's defaults, nested ones likewise; a version that adds an option (at its
    default) leaves it as it was, so that it does not make every earlier output another
    job's."""
    if not dataclasses.is_dataclass(options) or isinstance(options, type):
        return repr(options)
    try:
        default = type(options)()
    except TypeError:                           # fields without defaults: all of them
        return repr(options)
    changed = [f"{f.name}={options_text(getattr(options, f.name))}"
               for f in dataclasses.fields(options)
               if not _equal(getattr(options, f.name), getattr(default, f.name))]
    return f"{type(options).__name__}({', '.join(changed)})"


def _equal(a, b) -> bool:
    try:
        return bool(a == b)
    except (TypeError, ValueError):             # arrays: not said equal
        return False

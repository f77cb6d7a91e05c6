"""Tracks a transfer made, kept in the user cache: run again, the same command reuses them, and
an interrupted one continues its tracking where it stopped.

``facetransfer track`` writes its track where the user says and resumes from ``OUT.partial.npz``.
``transfer``, ``puppet`` and ``demo`` track their videos as a step of a longer job and write the
tracks nowhere themselves; so that a second run (with another ``--crf`` or texture option, say)
does not track both clips again and an interrupted one keeps its tracking,
:func:`facetransfer.track.obtain.obtain_track` keeps each track it makes under
``$XDG_CACHE_HOME/facetransfer/tracks`` (default ``~/.cache/facetransfer/tracks``) by a key of
everything the track depends on
(:func:`track_key`): the video file (resolved path, size, modification time), the frames
tracked, the tracker and its options, the model's content, what the readers make of the video
(:func:`reading_facts`: its count, timeline, turn, mirror), and the code, data and libraries
that make a track (:func:`code_fingerprint`: a changed tracker never reads an old track; its
docstrings and comments are not its code). The capture
tracker's progress (detections, then the fit) is saved beside it while it runs
(:mod:`facetransfer.track.detect_checkpoint`) and continued by the next run.

The cache keeps the :data:`KEEP` most recently used tracks. ``FACETRANSFER_TRACK_CACHE=off``
turns it off (nothing read or written).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
from pathlib import Path

from ..errors import OutputError

log = logging.getLogger(__name__)

__all__ = ["FRAME_READERS", "KEEP", "LAYOUT", "fingerprinted_files", "cache_enabled",
           "code_digest", "code_fingerprint", "reading_facts", "track_dir", "track_key", "holds",
           "cached_track", "store_track", "partial_path"]

#: The cache's layout: a change of what a key means (or of the trackers' results) changes it.
LAYOUT = "tracks-1"
#: Tracks kept (the least recently used beyond are removed when one is stored).
KEEP = 64


def cache_enabled() -> bool:
    """False when ``FACETRANSFER_TRACK_CACHE`` is ``off`` (or ``0``, ``no``, ``false``)."""
    from ..assets import switched_off

    return not switched_off("FACETRANSFER_TRACK_CACHE")


def track_dir() -> Path:
    """``$XDG_CACHE_HOME/facetransfer/tracks``."""
    from ..assets import cache_dir

    return cache_dir() / "tracks"


def track_key(video, n_frames: int, method: str, options, model) -> str | None:
    """The cache key of tracking the first ``n_frames`` frames of the file ``video`` with
    ``method`` and ``options`` (their ``repr``: frozen dataclasses) and ``model``; None where
    ``video`` is neither a file nor an image sequence (nothing to key by) or the cache is off."""
    from ..io.video_sequence import is_sequence

    if not cache_enabled() or video is None or not (os.path.isfile(os.fspath(video))
                                                   or is_sequence(video)):
        return None
    from .. import __version__
    from .checkpoint import video_identity

    what = {"layout": LAYOUT, "version": __version__, "code": code_fingerprint(),
            "video": video_identity(os.fspath(video)), "reading": reading_facts(video),
            "frames": int(n_frames), "method": str(method), "options": repr(options),
            "model": str(model.content_hash)}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:32]


def reading_facts(video) -> str | None:
    """What the readers make of ``video`` (:func:`facetransfer.io.video_read.video_info`): its
    frames' count, rate, size and pixel aspect, the steps of its timeline, its turn and mirror,
    and whether ffmpeg decodes it. In the key, a change of how a clip is read re-tracks that
    clip whatever made it: the readers' code (:data:`FRAME_READERS`, also digested), but also
    the ffmpeg binary, whose listing of a clip's packets decides a trimmed clip's frames and a
    variable-rate clip's timeline and is digested nowhere. None where it cannot be read."""
    from ..errors import VideoError
    from ..io.video_read import video_info

    try:
        info = video_info(video)
    except (VideoError, OSError):
        return None
    steps = None if info.steps is None else hashlib.sha256(
        json.dumps(list(info.steps)).encode()).hexdigest()[:16]
    return json.dumps([round(float(info.fps), 6), int(info.n_frames), list(info.size),
                       list(info.sar), steps, int(info.turn), bool(info.mirrored),
                       bool(info.piped)])


#: The video readers whose changes change a track (a clip's frames, their times, their turn):
#: a reader that came to read a phone's trimmed or mirrored clip right made the tracks cached
#: of it before wrong, and they were still taken.
FRAME_READERS = ("io/video_read.py", "io/video_timeline.py", "io/video_display.py",
                 "io/video_pipe.py")


def fingerprinted_files(root: Path) -> list[Path]:
    """The package's files (under its folder ``root``) that :func:`code_fingerprint` digests."""
    files = sorted((root / "track").glob("*.py")) + sorted((root / "data").glob("*.json"))
    return files + [root / n for n in ("arkit.py", "model.py", "tensor.py", *FRAME_READERS)]


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A digest of what makes a track besides its inputs: the code (not the docstrings and
    comments: :func:`_code_of`) of :mod:`facetransfer.track`, of the model and ARKit modules, of
    the readers that decide which frames a video gives and how they are turned
    (:data:`FRAME_READERS`), the package's data files (the landmark mappings), and the versions
    of MediaPipe (the detector) and OpenCV (the decoder and the point flow)."""
    from importlib import metadata

    import cv2

    root = Path(__file__).resolve().parent.parent
    return code_digest(root, fingerprinted_files(root),
                       f"mediapipe={metadata.version('mediapipe')} cv2={cv2.__version__}",
                       code_only=True)


def code_digest(root: Path, files, versions: str, *, code_only: bool = False) -> str:
    """A digest of ``files`` (their paths under ``root`` and contents; a missing one counts
    as empty) and of ``versions`` (the libraries' versions, as the caller names them): what a
    cache's key holds of the code that made an entry (also :mod:`facetransfer.render_cache`).
    ``code_only``: a Python file's code alone (:func:`_code_of`: its docstrings, comments and
    layout left out), so that a reworded docstring keeps every cached entry."""
    h = hashlib.sha256()
    memo = _load_memo() if code_only else {}
    known = len(memo)
    for f in files:
        h.update(str(Path(f).relative_to(root)).encode())
        data = f.read_bytes() if f.is_file() else b""
        h.update(_code_hash(data, memo).encode() if code_only and f.suffix == ".py" else data)
    h.update(versions.encode())
    if len(memo) != known:
        _save_memo(memo)
    return h.hexdigest()[:16]


#: :func:`_code_hash`'s memo in the user cache: a Python file's bytes' sha256 -> its code's
#: (:func:`_code_of`), so that a version of a file is parsed once, not at every command (the
#: track's fingerprint 0.46 CPU-s with the parses, 0.11 without); at most :data:`MEMO_LIMIT`.
CODE_MEMO, MEMO_LIMIT = "code-digests.json", 2048


def _code_hash(data: bytes, memo: dict) -> str:
    """The sha256 of :func:`_code_of` ``(data)``, looked up in (or added to) ``memo`` by the
    sha256 of ``data`` itself."""
    raw = hashlib.sha256(data).hexdigest()
    if raw not in memo:
        memo[raw] = hashlib.sha256(_code_of(data)).hexdigest()
    return memo[raw]


def _load_memo() -> dict:
    """:data:`CODE_MEMO`'s entries; none where it is missing or unreadable."""
    from ..assets import cache_dir

    try:
        memo = json.loads((cache_dir() / CODE_MEMO).read_text())
    except (OSError, ValueError):
        return {}
    return memo if isinstance(memo, dict) and len(memo) <= MEMO_LIMIT else {}


def _save_memo(memo: dict) -> None:
    """Write :data:`CODE_MEMO` atomically (two commands at once: the later's is kept, either
    right); a cache that cannot be written is left as it is."""
    from ..assets import cache_dir
    from ..io.atomic import write_text_atomic

    try:
        write_text_atomic(cache_dir() / CODE_MEMO, json.dumps(memo))
    except OSError:
        pass


def _code_of(source: bytes) -> bytes:
    """A Python file's syntax tree without its docstrings (``ast.dump``: no comments, no line
    numbers), or the file itself where it does not parse."""
    import ast

    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return source
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def _path(key: str) -> Path:
    return track_dir() / f"{key}.npz"


def partial_path(key: str) -> Path:
    """Where the capture tracker's progress for ``key`` is saved while it runs."""
    return track_dir() / f"{key}.partial.npz"


def holds(key: str | None) -> bool:
    """Whether the cache has a file under ``key`` (not read: :func:`cached_track` may still
    find it unreadable)."""
    if key is None:
        return False
    try:
        return _path(key).is_file()
    except OSError:                       # no cache folder can be made: nothing cached
        return False


def cached_track(key: str | None, model):
    """The cached track of ``key`` (its use recorded), or None: no key, none cached, or an
    unreadable or foreign file (removed, with a warning)."""
    from .result import Track

    if key is None:
        return None
    try:
        p = _path(key)
    except OSError:                       # no cache folder can be made: nothing cached
        return None
    if not p.is_file():
        return None
    try:
        tr = Track.load(p)
        tr.check_model(model)
    except (ValueError, OSError, EOFError) as exc:
        log.warning("removing unreadable cached track %s (%s)", p, exc)
        p.unlink(missing_ok=True)
        return None
    try:
        os.utime(p)                       # its use, for the pruning
    except OSError:
        pass
    return tr


def store_track(key: str | None, track) -> None:
    """Keep ``track`` under ``key`` (atomically), remove its progress file and the least
    recently used tracks beyond :data:`KEEP`. A cache that cannot be written is skipped with
    a warning: the job does not fail for it."""
    if key is None:
        return
    try:
        folder = track_dir()
        folder.mkdir(parents=True, exist_ok=True)
        track.save(_path(key), overwrite=True)
        partial_path(key).unlink(missing_ok=True)
        _prune(folder, KEEP)
    except (OSError, OutputError) as exc:  # a full disk is an OutputError (io.atomic)
        log.warning("could not keep the track in the cache (%s)", exc)


def _prune(folder: Path, keep: int) -> None:
    """Keep the ``keep`` most recently used tracks and the ``keep`` most recent progress files
    (an interrupted run never run again leaves one)."""
    def newest_first(paths):
        return sorted(paths, key=lambda p: p.stat().st_mtime, reverse=True)

    everything = list(folder.glob("*.npz"))
    partial = [p for p in everything if p.name.endswith(".partial.npz")]
    tracks = [p for p in everything if not p.name.endswith(".partial.npz")]
    for p in newest_first(tracks)[keep:] + newest_first(partial)[keep:]:
        p.unlink(missing_ok=True)

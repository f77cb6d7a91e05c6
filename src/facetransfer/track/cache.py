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
that make a track (:func:`code_fingerprint`: every module of the package the trackers can run,
found from their imports, so that a changed tracker never reads an old track; its docstrings
and comments are not its code). The capture
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

__all__ = ["FRAME_READERS", "KEEP", "LAYOUT", "TRACK_LIBRARIES", "fingerprinted_files",
           "cache_enabled", "code_fingerprint", "reading_facts", "track_dir", "track_key",
           "tracker_modules", "holds", "cached_track", "store_track", "partial_path"]

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
#: of it before wrong, and they were still taken. The trackers import them; they are named here
#: too, so that their reason to be digested does not hang on an import.
FRAME_READERS = ("io/video_read.py", "io/video_timeline.py", "io/video_display.py",
                 "io/video_pipe.py")
#: The libraries whose versions shape a track (their distributions' names): the arrays, the
#: solvers, the compiled kernels, the detector, ffmpeg (the decoder of what OpenCV cannot read).
TRACK_LIBRARIES = ("numpy", "scipy", "numba", "mediapipe", "imageio-ffmpeg")


def tracker_modules(root: Path) -> list[str]:
    """The modules a track's code starts from: every module of :mod:`facetransfer.track` (of
    the package in ``root``) and the :data:`FRAME_READERS`."""
    from ..code_digest import PACKAGE

    files = [*sorted((root / "track").glob("*.py")), *(root / n for n in FRAME_READERS)]
    names = [".".join((PACKAGE, *f.relative_to(root).with_suffix("").parts)) for f in files]
    return [n.removesuffix(".__init__") for n in names]


def fingerprinted_files(root: Path) -> list[Path]:
    """The package's files (under its folder ``root``) that :func:`code_fingerprint` digests:
    every file the tracker's code can run (:func:`facetransfer.code_digest.closure_files` of
    :func:`tracker_modules`: before, the files of ``track/`` and four more by name, while the
    trackers ran 40 more, ``geometry.py`` among them) and the data files it names."""
    from ..code_digest import closure_files

    return closure_files(tracker_modules(root), root=root)


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A digest of what makes a track besides its inputs: the code (not the docstrings and
    comments) of every module of the package the trackers can run and the data files they name
    (:func:`fingerprinted_files`), the versions of the libraries that shape a track
    (:data:`TRACK_LIBRARIES`, OpenCV's), and the detector's model file (Face Landmarker's
    ``.task``, by its registered sha256: the file is checked against it before it is used)."""
    import cv2

    from ..assets import REGISTRY
    from ..code_digest import PACKAGE_ROOT, closure_digest, library_versions

    landmarker = REGISTRY["face_landmarker"].files[0].sha256
    versions = (f"{library_versions(*TRACK_LIBRARIES)} cv2={cv2.__version__} "
                f"face_landmarker={landmarker}")
    return closure_digest(tracker_modules(PACKAGE_ROOT), versions, root=PACKAGE_ROOT)


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

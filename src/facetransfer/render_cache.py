"""Frames a transfer rendered, kept until its video is written: an interrupted ``transfer``
(or ``puppet``) continues its render where it stopped.

The tracks of a transfer are kept by :mod:`facetransfer.track.cache`; its render is the longer
step at high resolution (a minute of 1080p is about ten minutes of rendering on two cores), so
it is kept too: :func:`facetransfer.video_transfer.render_plan` encodes the frames into
parts (:mod:`facetransfer.io.video_parts`), or writes an image sequence's files
(:mod:`facetransfer.io.sequence_parts`), in a folder of
``$XDG_CACHE_HOME/facetransfer/renders`` named by a key of everything the frames depend on
(:func:`render_key`): the plan's frames (a digest of every frame's every 16th row), its tracks
and frame indices, the model's content, the render options, the codec options, and the package's
code and data (:func:`code_fingerprint`); a puppet video's by :func:`puppet_key`. The same
command run again finds the parts (:func:`parts_writer`) and renders
only the frames they do not hold; a finished video removes its folder. Folders of interrupted
renders never run again are removed beyond the :data:`KEEP` most recent.

``FACETRANSFER_RENDER_CACHE=off`` turns it off: the video is then encoded in one piece, and
an image sequence written beside its pattern.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["LAYOUT", "KEEP", "ROW_STEP", "cache_enabled", "render_dir", "render_key",
           "matte_key", "puppet_key", "code_fingerprint", "parts_writer", "parts_folder"]

#: The cache's layout: a change of what a key means changes it.
LAYOUT = "renders-1"
#: Folders of unfinished renders kept (the least recently used beyond are removed).
KEEP = 4
#: Rows of each frame in the key's digest of the footage (every ROW_STEP-th row).
ROW_STEP = 16


def cache_enabled() -> bool:
    """False when ``FACETRANSFER_RENDER_CACHE`` is ``off`` (or ``0``, ``no``, ``false``)."""
    from .assets import switched_off

    return not switched_off("FACETRANSFER_RENDER_CACHE")


def render_dir() -> Path:
    """``$XDG_CACHE_HOME/facetransfer/renders``."""
    from .assets import cache_dir

    return cache_dir() / "renders"


def _update_frames(h, frames) -> None:
    """Digest every frame of ``frames`` (F, H, W, 3) by its every :data:`ROW_STEP`-th row."""
    if frames is None:
        h.update(b"none")
        return
    h.update(repr((len(frames), np.asarray(frames[0]).shape)).encode())
    for f in frames:
        h.update(np.ascontiguousarray(np.asarray(f)[::ROW_STEP]).tobytes())


def _update_value(h, value) -> None:
    """Digest a track's field (arrays by their bytes, dicts by sorted key)."""
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, dict):
        for k in sorted(value):
            h.update(str(k).encode())
            _update_value(h, value[k])
    else:
        h.update(repr(value).encode())


def _update_track(h, track) -> None:
    """Digest a :class:`~facetransfer.track.result.Track` by every field but ``info`` (which
    holds timings) and ``made_by`` (what made a performance: no pixel depends on it)."""
    if track is None:
        h.update(b"none")
        return
    for f in dataclasses.fields(track):
        if f.name == "occluded" and track.occluded is None:
            continue            # a track not tested keys as before the field was added
        if f.name not in ("info", "made_by"):
            h.update(f.name.encode())
            _update_value(h, getattr(track, f.name))


def render_key(plan, model, options, video_options, *, images: bool = False) -> str | None:
    """The key of rendering ``plan`` (a :class:`~facetransfer.transfer_plan.TransferPlan`)
    with ``model``, ``options`` (:class:`~facetransfer.rewrite_options.RewriteOptions`) and
    ``video_options`` (:class:`~facetransfer.io.video.VideoOptions` or None) into a video, or
    (``images``) into an image sequence (:mod:`facetransfer.io.sequence_parts`); None when
    the cache is off."""
    if not cache_enabled():
        return None
    h = _keyed(model, video_options, plan.fps, images, options=repr(options),
               performance=bool(plan.performance))
    digested: dict[int, int] = {}  # a clip that is also another role is digested once
    for role, frames in enumerate((plan.target_frames, plan.mouth_frames, plan.texture_frames)):
        if frames is not None and id(frames) in digested:
            h.update(f"as {digested[id(frames)]}".encode())
            continue
        digested[id(frames)] = role
        _update_frames(h, frames)
    for tr in (plan.target_track, plan.new_track, plan.mouth_track, plan.texture_track):
        _update_track(h, tr)
    _update_value(h, np.asarray(plan.mouth_index))
    return h.hexdigest()[:32]


def matte_key(key: str | None, video_options, *, images: bool = False) -> str | None:
    """The key of the matte (``transfer --matte``, :mod:`facetransfer.io.matte`) of the
    render of ``key`` (:func:`render_key`), written with ``video_options`` into a video or
    (``images``) an image sequence: its own parts folder, continued as the output's is; None
    without ``key``."""
    if key is None:
        return None
    what = {"render": key, "matte": repr(_unnumbered(video_options)), "images": bool(images)}
    return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:32]


def puppet_key(track, model, identity, video_options, *, images: bool = False) -> str | None:
    """The key of a puppet video (:func:`facetransfer.puppet_video.puppet_frames`): ``track``
    driving the identity weights ``identity`` of ``model``, written with ``video_options``
    into a video or (``images``) an image sequence; None when the cache is off."""
    if not cache_enabled():
        return None
    h = _keyed(model, video_options, track.fps, images, kind="puppet")
    _update_track(h, track)
    _update_value(h, np.asarray(identity, np.float64))
    recorded = track.info.get("eye_gaze")  # a take's own eye angles (puppet_face.track_gaze)
    if recorded is not None:
        _update_value(h, np.asarray(recorded, np.float64))
    return h.hexdigest()[:32]


def _keyed(model, video_options, fps: float, images: bool, **what):
    """A sha256 of what every render's key holds (layout, package version and code, the
    model's content, the codec options, frame rate, part length, video or images) and
    ``what``, ready for the render's own frames and tracks."""
    from . import __version__
    from .io.video_parts import PART_FRAMES

    what.update(layout=LAYOUT, version=__version__, code=code_fingerprint(),
                model=str(model.content_hash), video=repr(_unnumbered(video_options)),
                fps=float(fps),
                parts=PART_FRAMES, images=bool(images))
    h = hashlib.sha256()
    h.update(json.dumps(what, sort_keys=True).encode())
    return h


def _unnumbered(video_options):
    """``video_options`` without an image sequence's first number: the frames rendered into
    the parts folder count from 0 whatever it is (it names them only when they are placed,
    :class:`~facetransfer.io.sequence_parts.SequenceWriter`), so an interrupted render is
    continued under another ``--start-number``."""
    if getattr(video_options, "first_number", None) is None:
        return video_options
    return dataclasses.replace(video_options, first_number=None)


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A digest of the package's sources and data files and of the libraries that shape a
    rendered frame or its encoding (NumPy, OpenCV, numba, imageio-ffmpeg's ffmpeg)."""
    from importlib import metadata

    import cv2
    import numba

    from .code_digest import code_digest

    root = Path(__file__).resolve().parent
    files = sorted(root.rglob("*.py")) + sorted((root / "data").glob("*.json"))
    return code_digest(root, files, f"numpy={np.__version__} cv2={cv2.__version__} "
                                    f"numba={numba.__version__} "
                                    f"imageio-ffmpeg={metadata.version('imageio-ffmpeg')}")


def parts_writer(key: str | None, out, fps: float, size: tuple[int, int], n_frames: int, *,
                 video_options=None, audio_from=None, overwrite: bool = False):
    """A writer of ``out`` into the parts folder of ``key`` that keeps what it wrote when
    interrupted: a :class:`~facetransfer.io.video_parts.PartsWriter` (a video of
    ``n_frames`` frames of ``size`` (W, H) at ``fps``) or a
    :class:`~facetransfer.io.sequence_parts.SequenceWriter` (an image sequence). Its ``done``
    frames are those an earlier, interrupted run kept (logged). None (the caller writes in one
    piece): no ``key`` (the cache is off), another process writes that folder now, or the
    cache cannot be written (warned, naming ``out``)."""
    from .io.sequence_parts import SequenceWriter
    from .io.video import is_image_pattern
    from .io.video_parts import PartsBusy, PartsWriter

    if key is None:
        return None
    try:
        if is_image_pattern(out):
            first = getattr(video_options, "first_number", None) or 0
            writer = SequenceWriter(parts_folder(key), out, size, n_frames=n_frames,
                                    overwrite=overwrite, first_number=first, fps=fps,
                                    timecode=getattr(video_options, "timecode", None),
                                    sar=getattr(video_options, "sar", None))
        else:
            writer = PartsWriter(parts_folder(key), out, fps, size, n_frames=n_frames,
                                 options=video_options, audio_from=audio_from,
                                 overwrite=overwrite)
    except PartsBusy as exc:
        log.warning("%s: writing %s without the render cache", exc, out)
        return None
    except OSError as exc:  # the cache cannot be written: the job does not fail for it
        log.warning("the render cache cannot be used (%s): writing %s without it", exc, out)
        return None
    if writer.done:
        log.info("%s: continuing an interrupted render from frame %d", out,  # a plate's number
                 (getattr(video_options, "first_number", None) or 0) + writer.done)
    return writer


def parts_folder(key: str) -> Path:
    """The parts folder of ``key`` (its use recorded); folders of other keys beyond the
    :data:`KEEP` most recently used are removed (:func:`_prune`)."""
    folder = render_dir() / key
    folder.mkdir(parents=True, exist_ok=True)
    try:
        os.utime(folder)
    except OSError:
        pass
    _prune(folder.parent, KEEP, current=folder)
    return folder


def _prune(root: Path, keep: int, current: Path) -> None:
    """Remove the folders of ``root`` beyond the ``keep`` most recently used, never
    ``current`` nor one another process is writing into."""
    from .io.video_parts import folder_in_use

    def mtime(p: Path) -> float:
        try:
            return p.stat().st_mtime
        except OSError:
            return 0.0

    folders = sorted((p for p in root.iterdir() if p.is_dir() and p != current), key=mtime,
                     reverse=True)
    for p in folders[max(0, keep - 1):]:
        if not folder_in_use(p):
            log.info("removing the unfinished render %s", p)
            shutil.rmtree(p, ignore_errors=True)

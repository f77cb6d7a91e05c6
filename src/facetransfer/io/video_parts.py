"""A video written in parts that outlive an interruption, joined into the output at the end.

A long render (``facetransfer transfer``: about 0.4 CPU-seconds a frame at 1080p) encodes its
frames into parts of :data:`PART_FRAMES` frames in a folder of its own
(:mod:`facetransfer.render_cache`). A part is a complete QuickTime file from the moment it is
listed in the folder's manifest. An interrupted run keeps every listed part and, on Ctrl-C,
the frames of the part it was writing too (ffmpeg runs in a session of its own, so the
interrupt reaches only Python, which then lets ffmpeg finish that part); a run killed outright
loses at most the part it was writing. The next run with the same folder starts at the first
frame no part holds (:attr:`PartsWriter.done`). When every frame is written, the parts are
joined by stream copy (ffmpeg's concat demuxer: no second encoding, the frames as the parts
hold them) with the audio into the output, atomically, and the folder is removed.

The price: every part starts with a key frame, where one encoding would place one every 250
frames anyway (x264's default), and the join is one more ffmpeg pass that copies the stream.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import shutil
import subprocess
import threading
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import OutputError, VideoError
from .atomic import atomic_path, locked_elsewhere, write_text_atomic
from .ffmpeg import exit_cause, ffmpeg_error
from .video import (VideoOptions, VideoWriter, WrittenVideo, _container_args, _fps_arg,
                    _require_ffmpeg, _stored_size, check_video_output, stored_frame_count,
                    warn_if_grown)
from .video_audio import audio_codecs, audio_input_args
from .video_options import VIDEO_SUFFIXES

log = logging.getLogger(__name__)

__all__ = ["PART_FRAMES", "Part", "PartsBusy", "kept_parts", "folder_in_use", "PartsWriter",
           "join_parts"]

#: Frames a part holds (the last one fewer): x264's default key-frame interval, so that one
#: encoding and the parts place about as many key frames.
PART_FRAMES = 250
#: The folder's list of finished parts (JSON), replaced atomically after each part.
MANIFEST = "parts.json"
_LOCK = "lock"
_SUFFIX = ".mov"  # QuickTime: H.264, H.265 and ProRes, exact frame timestamps when joined


class PartsBusy(VideoError):
    """Another process is writing into the same parts folder."""


@dataclass(frozen=True)
class Part:
    """One finished part: ``frames`` frames from frame ``start`` in the file ``name``;
    ``marked`` of them were marked by the writer's caller (e.g. a face rendered there)."""

    start: int
    frames: int
    marked: int
    name: str


def _read_manifest(folder: Path) -> list[Part]:
    try:
        items = json.loads((folder / MANIFEST).read_text())["parts"]
        return [Part(int(p["start"]), int(p["frames"]), int(p["marked"]), str(p["name"]))
                for p in items]
    except FileNotFoundError:
        return []
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring the unreadable list of parts in %s (%s)", folder, exc)
        return []


def _write_manifest(folder: Path, parts: list[Part]) -> None:
    write_text_atomic(folder / MANIFEST, json.dumps({"parts": [asdict(p) for p in parts]}))


def kept_parts(folder: str | os.PathLike, *, verify: bool = True) -> list[Part]:
    """The finished parts in ``folder`` that follow on from frame 0 without a gap, each file
    present and (``verify``) holding the frames listed (:func:`stored_frame_count`, ~20 ms a
    part). Files of parts beyond the first missing or damaged one are removed, as is
    anything else a killed writer left in the folder; the manifest is rewritten to match.
    Called with the folder's lock held (:class:`PartsWriter` takes it) or while no writer
    runs: it removes what a live writer would be writing."""
    folder = Path(folder)
    listed = _read_manifest(folder)
    good: list[Part] = []
    for p in listed:
        f = folder / p.name
        expected = good[-1].start + good[-1].frames if good else 0
        if p.start != expected or p.frames < 1 or not f.is_file() or Path(p.name).name != p.name:
            break
        if verify:
            try:
                if stored_frame_count(f) != p.frames:
                    break
            except VideoError:
                break
        good.append(p)
    keep = {p.name for p in good} | {MANIFEST, _LOCK}
    for f in folder.iterdir() if folder.is_dir() else ():
        if f.name not in keep:
            with contextlib.suppress(OSError):
                shutil.rmtree(f) if f.is_dir() and not f.is_symlink() else f.unlink()
    if good != listed:
        _write_manifest(folder, good)
    return good


def _lock(folder: Path) -> int:
    """An exclusive lock on ``folder`` (its file descriptor), or :class:`PartsBusy`."""
    fd = os.open(folder / _LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise PartsBusy(f"another process is writing the parts in {folder}") from None
    return fd


def folder_in_use(folder: str | os.PathLike) -> bool:
    """Whether a live process holds the lock of the parts folder ``folder``."""
    return locked_elsewhere(Path(folder) / _LOCK)


class PartsWriter:
    """Write ``n_frames`` RGB frames into the parts folder ``folder``, then join them into
    ``out`` (a video file; an image sequence is written by :class:`VideoWriter`).

    On creation the folder is locked (:class:`PartsBusy` if another process holds it) and
    its finished parts are taken up: the caller writes frames from :attr:`done` on.
    :meth:`close` with ``commit`` finishes the last part, joins every part with the audio of
    ``audio_from`` (:func:`join_parts`) and removes the folder; without ``commit`` (an
    exception, an interrupt) it keeps what was written: the part being written keeps the
    whole frames ffmpeg received (:meth:`VideoWriter.close` with ``prefix``).

    Parameters
    ----------
    folder : path-like
        The parts folder (created).
    out : path-like
        The output video, checked now (``overwrite``).
    fps : float
    size : (width, height)
    n_frames : int
        Frames of the whole video.
    options : VideoOptions, optional
    audio_from : path-like, optional
    overwrite : bool
        As :class:`~facetransfer.io.video.VideoWriter`'s: when False, an ``out`` there now is
        refused, and one another run writes meanwhile is kept (the join refused,
        :func:`join_parts`).
    """

    def __init__(self, folder: str | os.PathLike, out: str | os.PathLike, fps: float,
                 size: tuple[int, int], *, n_frames: int,
                 options: VideoOptions | None = None,
                 audio_from: str | os.PathLike | None = None, overwrite: bool = False) -> None:
        self.output = check_video_output(out, options, overwrite=overwrite)
        self.overwrite = bool(overwrite)
        if self.output.kind != "video":
            raise VideoError(f"{out}: an image sequence is not written in parts")
        self.folder, self.fps, self.size = Path(folder), float(fps), tuple(size)
        warn_if_grown(self.output.path, self.size, self.output.options.codec)
        self.n_frames, self.audio_from = int(n_frames), audio_from
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock_fd = _lock(self.folder)
        self.parts = kept_parts(self.folder)
        if self.parts and self.parts[-1].start + self.parts[-1].frames > self.n_frames:
            self.parts = []  # not this video's: start again
            _write_manifest(self.folder, self.parts)
            kept_parts(self.folder, verify=False)
        self.resumed = self._next = self.done
        self._writer: VideoWriter | None = None
        self._part_start, self._marks = self._next, []
        self._finisher: threading.Thread | None = None
        self._error: BaseException | None = None
        self.result: WrittenVideo | None = None

    @property
    def done(self) -> int:
        """Frames the finished parts hold (where the caller starts writing)."""
        return sum(p.frames for p in self.parts)

    @property
    def marked(self) -> int:
        """Frames marked in :meth:`write` and held by the finished parts (after
        :meth:`close`: every one marked, in this run and in the kept parts)."""
        return sum(p.marked for p in self.parts)

    @contextlib.contextmanager
    def _in_the_cache(self):
        """A failed write of a part (a full disk...) says where it was written and the way
        around it, besides what went wrong."""
        try:
            yield
        except (VideoError, OutputError) as exc:
            raise VideoError(f"{exc} (a part of {self.output.path} in the render cache; "
                             "FACETRANSFER_RENDER_CACHE=off writes the video in one piece)"
                             ) from None

    def write(self, frame: np.ndarray, *, marked: bool = False) -> None:
        """Append the next ``(H, W, 3) uint8`` frame (``marked``: counted in :attr:`marked`)."""
        with self._in_the_cache():
            self._write(frame, marked)

    def _write(self, frame: np.ndarray, marked: bool) -> None:
        if self._writer is None:
            if self._next >= self.n_frames:
                raise VideoError(f"{self.output.path}: all {self.n_frames} frames are written")
            # a part holds frames only: the join writes the start timecode once
            self._writer = VideoWriter(self.folder / f"{self._next:08d}{_SUFFIX}", self.fps,
                                       self.size, detached=True,
                                       options=replace(self.output.options, timecode=None))
            self._part_start, self._marks = self._next, []
        self._writer.write(frame)
        self._marks.append(bool(marked))
        self._next += 1
        if len(self._marks) == PART_FRAMES:
            self._hand_off()

    def _hand_off(self) -> None:
        """Finish the full part on a thread (ffmpeg encodes the frames it still holds) while
        the next part is written; one at a time, so the parts are listed in order."""
        self._wait()
        w, start, marks = self._writer, self._part_start, self._marks
        self._writer, self._marks = None, []
        self._finisher = threading.Thread(target=self._finish, args=(w, start, marks, False),
                                          name="finish-part", daemon=True)
        self._finisher.start()

    def _finish(self, w: VideoWriter, start: int, marks: list, prefix: bool,
                counted: bool = True) -> None:
        try:
            done = w.close(prefix=prefix, counted=counted)
            if done is not None:
                self.parts.append(Part(start, done.n_frames, sum(marks[:done.n_frames]),
                                       done.path.name))
                _write_manifest(self.folder, self.parts)
        except BaseException as exc:  # noqa: BLE001 - raised by _wait in the caller's thread
            self._error = exc

    def _wait(self) -> None:
        """Wait for the part being finished; raise what finishing it raised."""
        t, self._finisher = self._finisher, None
        if t is not None:
            t.join()
        err, self._error = self._error, None
        if err is not None:
            raise err

    def _finish_current(self, *, prefix: bool, counted: bool = True) -> None:
        self._wait()
        w, self._writer = self._writer, None
        if w is not None:
            self._finish(w, self._part_start, self._marks, prefix, counted)
            self._marks = []
            self._wait()

    def close(self, *, commit: bool = True) -> WrittenVideo | None:
        """Join the parts into the output (``commit``; every frame must have been written),
        else keep them for the next run. Returns what was written (None when kept), also
        kept as :attr:`result`."""
        if self._lock_fd is None:
            return self.result  # closed already
        try:
            if not commit:
                self._keep()
                return None
            # the last part is not read back on its own: the joined file is, and holds the
            # frames listed only if it does (every part before it was counted when finished,
            # or by kept_parts when taken up); a run kept for later counts it there (verify)
            with self._in_the_cache():
                self._finish_current(prefix=False, counted=False)
            if self.done != self.n_frames:
                raise VideoError(f"{self.output.path}: {self.done} frames were written, not "
                                 f"{self.n_frames}")
            self.result = join_parts(self.folder, self.parts, self.output.path, self.fps,
                                     self.size, audio_from=self.audio_from,
                                     options=self.output.options, overwrite=self.overwrite)
            shutil.rmtree(self.folder, ignore_errors=True)
            return self.result
        finally:
            if self.result is None and not self.parts:  # nothing to continue from
                shutil.rmtree(self.folder, ignore_errors=True)
            self._unlock()

    def _keep(self) -> None:
        try:
            self._finish_current(prefix=True)
        except (VideoError, OSError) as exc:  # the part being written is lost, no more
            log.warning("could not keep the last part of %s (%s)", self.output.path, exc)
            w, self._writer = self._writer, None
            if w is not None:
                w.close(commit=False)

    def _unlock(self) -> None:
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None:
            os.close(fd)

    def __enter__(self) -> "PartsWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def join_parts(folder: str | os.PathLike, parts: list[Part], out: str | os.PathLike,
               fps: float, size: tuple[int, int], *,
               audio_from: str | os.PathLike | None = None,
               options: VideoOptions | None = None, overwrite: bool = True) -> WrittenVideo:
    """Join ``parts`` (in ``folder``) of frames of ``size`` (width, height) into the video
    ``out`` by stream copy, with the audio of ``audio_from`` (copied where the container
    holds its codec, else AAC) cut to the frames' length; written atomically and checked to
    hold every frame. Without ``overwrite``, an ``out`` that another run wrote meanwhile is
    kept and this one refused.

    Raises
    ------
    VideoError
        ffmpeg failed, or the joined file does not hold the parts' frames.
    OutputError
        ``out`` exists and not ``overwrite``.
    """
    folder, out = Path(folder), Path(out)
    opt = options or VideoOptions()
    n = sum(p.frames for p in parts)
    listing = folder / "join.ffconcat"
    listing.write_text("ffconcat version 1.0\n" + "".join(f"file '{p.name}'\n" for p in parts))
    fmt = VIDEO_SUFFIXES[out.suffix.lower()]
    codecs = () if audio_from is None else audio_codecs(audio_from)
    audio = audio_input_args(audio_from, codecs, fmt, duration=n / fps) if codecs else []
    extra = _container_args(opt, out.suffix.lower())
    if fmt == "avi":  # a constant rate (else the parts' 1/15360 s ticks: "600 fps"), its tag
        extra += ["-r", _fps_arg(fps)] + (["-tag:v", "H264"] if opt.codec == "h264" else [])
    with atomic_path(out, overwrite=overwrite) as tmp:
        res = subprocess.run([_require_ffmpeg(), "-hide_banner", "-nostdin", "-loglevel", "error",
                              "-y", "-f", "concat", "-safe", "0", "-i", str(listing), *audio,
                              "-c:v", "copy", *extra, "-f", fmt, str(tmp)],
                             capture_output=True, text=True)
        if res.returncode != 0:   # how it ended said too (a file size limit says nothing)
            what = f"cannot join the parts of {out} (ffmpeg {exit_cause(res.returncode)})"
            raise ffmpeg_error(res.stderr, what) if res.stderr.strip() else VideoError(what)
        stored = stored_frame_count(tmp)
        if stored != n:
            raise VideoError(f"cannot write video {out}: its parts hold {n} frames, the joined "
                             f"file {stored}")
    with contextlib.suppress(OSError):
        listing.unlink()
    return WrittenVideo(out, n, _stored_size(size, opt.codec), bool(codecs))

"""An image sequence written frame by frame into a folder that outlives an interruption, moved
into place at the end.

The image-sequence counterpart of :mod:`facetransfer.io.video_parts`: ``facetransfer transfer
--out frames/%05d.png`` renders into a folder of its own in the render cache
(:mod:`facetransfer.render_cache`), one finished file per frame (each written under a temporary
name and renamed), then its mark appended to the folder's list of marks (one byte a frame: a
constant cost whatever the sequence's length). An interrupted run keeps every frame marked, a
run killed outright too (at most the frame being written is lost); the next run with the same
folder starts at the first frame not kept (:attr:`SequenceWriter.done`).
When every frame is written the files are moved beside the pattern (renamed, or copied from
another file system), frames of an older, longer sequence of the same pattern are removed, and
the folder is removed: a sequence that has been half-replaced never exists before the last
frame is rendered.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np

from ..errors import OutputError, VideoError
from .atomic import write_bytes_atomic, write_text_atomic
from .plate_header import written_header
from .video import (WrittenVideo, check_video_output, fits_output, place_sequence,
                    save_frame_image)
from .video_parts import _LOCK, _lock

log = logging.getLogger(__name__)

__all__ = ["SequenceWriter", "kept_frames"]

#: The folder's sequence (JSON: the pattern's name and the frame count), written when taken up.
MANIFEST = "frames.json"
#: One byte per frame written (``1``: marked, ``0``: not), appended after the frame's file.
MARKS = "marks"


def kept_frames(folder: str | os.PathLike, name: str, n_frames: int) -> list[bool]:
    """The frames kept in ``folder`` for the pattern ``name`` (e.g. ``%05d.png``) of a sequence
    of ``n_frames``: one mark per frame that follows on from frame 0 without a gap, marked and
    present as a file. Anything else (the frames of another pattern or length, files past the
    first missing or unmarked one, a killed writer's temporary file) is removed and the
    folder's records rewritten to match. Called with the folder's lock held."""
    folder = Path(folder)
    marks = _read_marks(folder, name, n_frames)
    kept = 0
    while kept < min(len(marks), n_frames) and (folder / (name % kept)).is_file():
        kept += 1
    marks = marks[:kept]
    keep = {name % i for i in range(kept)} | {MANIFEST, MARKS, _LOCK}
    for f in folder.iterdir() if folder.is_dir() else ():
        if f.name not in keep:
            with contextlib.suppress(OSError):
                shutil.rmtree(f) if f.is_dir() and not f.is_symlink() else f.unlink()
    write_text_atomic(folder / MANIFEST, json.dumps({"name": name, "n_frames": n_frames}))
    write_bytes_atomic(folder / MARKS, bytes(b"01"[m] for m in marks))
    return marks


def _read_marks(folder: Path, name: str, n_frames: int) -> list[bool]:
    """The marks recorded in ``folder`` for this sequence (none for another's, or unreadable
    records)."""
    try:
        rec = json.loads((folder / MANIFEST).read_text())
        if rec.get("name") != name or int(rec.get("n_frames", -1)) != n_frames:
            return []
        return [b == ord("1") for b in (folder / MARKS).read_bytes()]
    except FileNotFoundError:
        return []
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        log.warning("ignoring the unreadable record of frames in %s (%s)", folder, exc)
        return []


class SequenceWriter:
    """Write ``n_frames`` RGB frames of the image sequence ``out`` (``frames/%05d.png``)
    through the folder ``folder``, continuing what an interrupted run kept there.

    The interface of :class:`facetransfer.io.video_parts.PartsWriter`: on creation the folder
    is locked (:class:`~facetransfer.io.video_parts.PartsBusy` if another process holds it)
    and the caller writes frames from :attr:`done` on; :meth:`close` with ``commit`` moves the
    frames into place and removes the folder, without it keeps them for the next run.

    Parameters
    ----------
    folder : path-like
        The frames' folder (created).
    out : path-like
        The image-sequence pattern, checked now (``overwrite``).
    size : (width, height)
    n_frames : int
        Frames of the whole sequence.
    overwrite : bool
        As :class:`~facetransfer.io.video.VideoWriter`'s: when False, frames of ``out`` there
        now are refused, and those another run places meanwhile are kept (the commit refused,
        :func:`~facetransfer.io.video.place_sequence`; the frames here kept for a rerun).
    first_number : int
        Number of its first frame beside the pattern (in the folder they count from 0).
    fps, timecode, sar : float, str and (int, int), optional
        Its rate, first frame's timecode and pixel aspect, recorded in each DPX or OpenEXR
        frame made here (:func:`facetransfer.io.plate_header.written_header`).
    """

    def __init__(self, folder: str | os.PathLike, out: str | os.PathLike,
                 size: tuple[int, int], *, n_frames: int, overwrite: bool = False,
                 first_number: int = 0, fps: float | None = None,
                 timecode: str | None = None, sar: tuple[int, int] | None = None) -> None:
        self.output = check_video_output(out, None, overwrite=overwrite)
        self.overwrite = bool(overwrite)
        self.first_number = int(first_number)
        self.fps, self.timecode, self.sar = fps, timecode, sar
        if self.output.kind != "images":
            raise VideoError(f"{out}: not an image sequence (a video is written in parts by "
                             "facetransfer.io.video_parts)")
        self.folder, self.size, self.n_frames = Path(folder), tuple(size), int(n_frames)
        self.name = self.output.path.name
        self.folder.mkdir(parents=True, exist_ok=True)
        self._lock_fd = _lock(self.folder)
        self.marks = kept_frames(self.folder, self.name, self.n_frames)
        self.resumed = self.done
        self.result: WrittenVideo | None = None

    @property
    def done(self) -> int:
        """Frames kept (where the caller starts writing)."""
        return len(self.marks)

    @property
    def marked(self) -> int:
        """Frames marked in :meth:`write`, in this run and in the frames kept."""
        return sum(self.marks)

    def write(self, frame: np.ndarray, *, marked: bool = False) -> None:
        """Write the next ``(H, W, 3) uint8`` frame (``marked``: counted in :attr:`marked`; of a
        PNG sequence, ``(H, W, 4)`` RGBA too; of an OpenEXR sequence, float16 or
        float32 linear RGB)."""
        i = self.done
        if i >= self.n_frames:
            raise VideoError(f"{self.output.path}: all {self.n_frames} frames are written")
        if not fits_output(frame.shape, self.size, self.output.path):
            raise VideoError(f"frame of shape {frame.shape} does not match the size "
                             f"{self.size[0]}x{self.size[1]} of {self.output.path}")
        name = self.name % i
        tmp = self.folder / f".{name}.tmp"
        try:
            save_frame_image(frame, tmp, suffix=Path(name).suffix,
                             header=written_header(self.fps, self.timecode, i, self.sar))
            os.replace(tmp, self.folder / name)
            with open(self.folder / MARKS, "ab") as fh:  # after the frame: it counts from now
                fh.write(b"1" if marked else b"0")
            self.marks.append(bool(marked))
        except (OSError, ValueError, OutputError) as exc:  # full disk, unknown format
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise VideoError(f"cannot write frame {name} of {self.output.path} in the render "
                             f"cache ({exc}; FACETRANSFER_RENDER_CACHE=off writes the frames "
                             "beside the pattern)") from None

    def close(self, *, commit: bool = True) -> WrittenVideo | None:
        """Move every frame into place (``commit``; all must have been written), else keep them
        for the next run. Returns what was written (None when kept), also :attr:`result`."""
        if self._lock_fd is None:
            return self.result
        try:
            if commit:
                if self.done != self.n_frames:
                    raise VideoError(f"{self.output.path}: {self.done} frames were written, "
                                     f"not {self.n_frames}")
                place_sequence(self.folder, self.output.path, self.n_frames,
                               first=self.first_number, overwrite=self.overwrite)
                shutil.rmtree(self.folder, ignore_errors=True)
                self.result = WrittenVideo(self.output.path, self.n_frames, self.size, False,
                                           "images")
            return self.result
        finally:
            if self.result is None and not self.marks:  # nothing to continue from
                shutil.rmtree(self.folder, ignore_errors=True)
            fd, self._lock_fd = self._lock_fd, None
            os.close(fd)

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)

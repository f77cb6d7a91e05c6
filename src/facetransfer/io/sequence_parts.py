"""An image sequence written frame by frame into a folder that outlives an interruption, moved
into place at the end.

The image-sequence counterpart of :mod:`facetransfer.io.video_parts`: ``facetransfer transfer
--out frames/%05d.png`` renders into a folder of its own in the render cache
(:mod:`facetransfer.render_cache`), one finished file per frame (each written under a temporary
name and renamed), listed in the folder's manifest after it. An interrupted run keeps every
listed frame, a run killed outright too (at most the frame being written is lost); the next
run with the same folder starts at the first frame not listed (:attr:`SequenceWriter.done`).
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
from .atomic import write_text_atomic
from .video import WrittenVideo, _pattern_files, check_video_output, save_frame_image
from .video_parts import _LOCK, PartsBusy, _lock

log = logging.getLogger(__name__)

__all__ = ["SequenceWriter", "kept_frames"]

#: The folder's record of the frames written so far (JSON), replaced atomically after each.
MANIFEST = "frames.json"


def kept_frames(folder: str | os.PathLike, name: str, n_frames: int) -> list[bool]:
    """The frames kept in ``folder`` for the pattern ``name`` (e.g. ``%05d.png``) of a sequence
    of ``n_frames``: one mark per frame that follows on from frame 0 without a gap, listed in
    the manifest and present as a file. Anything else (a manifest of another pattern or
    length, files past the first missing one, a killed writer's temporary file) is removed
    and the manifest rewritten to match. Called with the folder's lock held."""
    folder = Path(folder)
    try:
        rec = json.loads((folder / MANIFEST).read_text())
        marks = [bool(m) for m in rec["marked"]] \
            if rec.get("name") == name and int(rec.get("n_frames", -1)) == n_frames else []
    except FileNotFoundError:
        marks = []
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring the unreadable list of frames in %s (%s)", folder, exc)
        marks = []
    kept = 0
    while kept < min(len(marks), n_frames) and (folder / (name % kept)).is_file():
        kept += 1
    marks = marks[:kept]
    keep = {name % i for i in range(kept)} | {MANIFEST, _LOCK}
    for f in folder.iterdir() if folder.is_dir() else ():
        if f.name not in keep:
            with contextlib.suppress(OSError):
                shutil.rmtree(f) if f.is_dir() and not f.is_symlink() else f.unlink()
    _write_manifest(folder, name, n_frames, marks)
    return marks


def _write_manifest(folder: Path, name: str, n_frames: int, marks: list[bool]) -> None:
    write_text_atomic(folder / MANIFEST, json.dumps({"name": name, "n_frames": n_frames,
                                                     "marked": [int(m) for m in marks]}))


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
    """

    def __init__(self, folder: str | os.PathLike, out: str | os.PathLike,
                 size: tuple[int, int], *, n_frames: int, overwrite: bool = False) -> None:
        self.output = check_video_output(out, None, overwrite=overwrite)
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
        """Write the next ``(H, W, 3) uint8`` frame (``marked``: counted in :attr:`marked`)."""
        i = self.done
        if i >= self.n_frames:
            raise VideoError(f"{self.output.path}: all {self.n_frames} frames are written")
        if frame.shape != (self.size[1], self.size[0], 3):
            raise VideoError(f"frame of shape {frame.shape} does not match the size "
                             f"{self.size[0]}x{self.size[1]} of {self.output.path}")
        name = self.name % i
        tmp = self.folder / f".{name}.tmp"
        try:
            save_frame_image(frame, tmp, suffix=Path(name).suffix)
            os.replace(tmp, self.folder / name)
            self.marks.append(bool(marked))
            _write_manifest(self.folder, self.name, self.n_frames, self.marks)
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
                self._move_into_place()
                shutil.rmtree(self.folder, ignore_errors=True)
                self.result = WrittenVideo(self.output.path, self.n_frames, self.size, False,
                                           "images")
            return self.result
        finally:
            if self.result is None and not self.marks:  # nothing to continue from
                shutil.rmtree(self.folder, ignore_errors=True)
            fd, self._lock_fd = self._lock_fd, None
            os.close(fd)

    def _move_into_place(self) -> None:
        """The frames beside the pattern (renamed, or moved across file systems) and the
        files of an older, longer sequence of the same pattern removed."""
        dest = self.output.path.parent
        dest.mkdir(parents=True, exist_ok=True)
        old = _pattern_files(self.output.path)
        names = [self.name % i for i in range(self.n_frames)]
        for name in names:
            shutil.move(self.folder / name, dest / name)
        keep = set(names)
        for q in old:
            if q.name not in keep:
                q.unlink()

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)

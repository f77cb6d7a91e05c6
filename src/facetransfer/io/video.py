"""Video input and output through OpenCV. Frames are ``(H, W, 3) uint8`` RGB.

Reading decodes lazily (:func:`iter_frames`) or all at once (:func:`read_video`); writing goes to a
temporary file renamed on success (:class:`VideoWriter`), so an interrupted job never leaves a
half-written video under the final name.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import VideoError
from .atomic import check_output_path


@dataclass(frozen=True)
class VideoInfo:
    """Basic facts about a video file.

    Attributes
    ----------
    path : Path
    fps : float
    n_frames : int
        As reported by the container (may be approximate for some codecs).
    size : (int, int)
        ``(width, height)`` in pixels.
    """

    path: Path
    fps: float
    n_frames: int
    size: tuple[int, int]


def _open(path: str | os.PathLike):
    import cv2

    p = Path(path)
    if not p.is_file():
        raise VideoError(f"video {p} does not exist")
    if p.stat().st_size == 0:
        raise VideoError(f"video {p} is empty")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        raise VideoError(f"cannot read video {p}: not a video OpenCV can decode")
    return cap


def video_info(path: str | os.PathLike) -> VideoInfo:
    """Read a video's frame rate, frame count and size without decoding it."""
    import cv2

    cap = _open(path)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 25.0
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    finally:
        cap.release()
    if size[0] <= 0 or size[1] <= 0:
        raise VideoError(f"video {path} has no frames")
    return VideoInfo(Path(path), fps, n, size)


def iter_frames(path: str | os.PathLike, *, start: int = 0,
                stop: int | None = None) -> Iterator[np.ndarray]:
    """Yield RGB frames ``(H, W, 3) uint8`` from ``start`` (inclusive) to ``stop`` (exclusive)."""
    import cv2

    cap = _open(path)
    try:
        if start:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        i = start
        while stop is None or i < stop:
            ok, bgr = cap.read()
            if not ok:
                break
            yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            i += 1
    finally:
        cap.release()


def read_video(path: str | os.PathLike, *, start: int = 0, stop: int | None = None,
               max_frames: int | None = None) -> tuple[np.ndarray, float]:
    """Decode frames into one array.

    Returns
    -------
    frames : (F, H, W, 3) uint8
    fps : float

    Raises
    ------
    VideoError
        Missing, unreadable or empty video.
    """
    info = video_info(path)
    if max_frames is not None:
        stop = start + max_frames if stop is None else min(stop, start + max_frames)
    frames = list(iter_frames(path, start=start, stop=stop))
    if not frames:
        raise VideoError(f"video {path} has no frames (from frame {start})")
    return np.stack(frames), info.fps


class VideoWriter:
    """Write RGB frames to a video atomically (``.mp4`` with the ``mp4v`` codec, or ``.avi`` MJPG).

    Use as a context manager; the file appears under its final name only when the block ends
    without error.

    Parameters
    ----------
    path : path-like
    fps : float
    size : (width, height)
    overwrite : bool
        Refuse to replace an existing file when False.
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], *,
                 overwrite: bool = True) -> None:
        import cv2

        self.path = check_output_path(path, overwrite=overwrite)
        if fps <= 0:
            raise VideoError(f"frame rate must be positive, got {fps}")
        self.size = (int(size[0]), int(size[1]))
        suffix = self.path.suffix.lower() or ".mp4"
        self.tmp = self.path.with_name(f".{self.path.stem}.part{suffix}")
        fourcc = cv2.VideoWriter_fourcc(*("MJPG" if suffix == ".avi" else "mp4v"))
        self._w = cv2.VideoWriter(str(self.tmp), fourcc, float(fps), self.size)
        if not self._w.isOpened():
            raise VideoError(f"cannot write video {self.path} (codec for {suffix} unavailable)")
        self.n_frames = 0

    def write(self, frame: np.ndarray) -> None:
        """Append one ``(H, W, 3) uint8`` RGB frame of the writer's size."""
        import cv2

        if frame.shape != (self.size[1], self.size[0], 3):
            raise VideoError(f"frame of shape {frame.shape} does not match video size "
                             f"{self.size[0]}x{self.size[1]}")
        self._w.write(cv2.cvtColor(np.ascontiguousarray(frame, dtype=np.uint8), cv2.COLOR_RGB2BGR))
        self.n_frames += 1

    def close(self, *, commit: bool = True) -> None:
        self._w.release()
        if commit and self.n_frames:
            os.replace(self.tmp, self.path)
        elif self.tmp.exists():
            self.tmp.unlink()

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def write_video(path: str | os.PathLike, frames, fps: float, *, overwrite: bool = True) -> Path:
    """Write an iterable of RGB frames atomically; the size is taken from the first frame."""
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise VideoError(f"no frames to write to {path}") from None
    with VideoWriter(path, fps, (first.shape[1], first.shape[0]), overwrite=overwrite) as w:
        w.write(first)
        for f in it:
            w.write(f)
    return Path(path)

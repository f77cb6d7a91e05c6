"""Video frames for the tracker: a video file streamed from disk or an ``(F, H, W, 3)`` array,
with sequential and random access."""

from __future__ import annotations

from typing import Iterator, Sequence

import numpy as np

from ..errors import VideoError

__all__ = ["FrameSource", "frame_source"]


class FrameSource:
    """Random and sequential access to video frames (a path streams, an array is indexed)."""

    def __init__(self, src, max_frames: int | None = None) -> None:
        self.path = None
        if isinstance(src, np.ndarray) or (isinstance(src, Sequence) and not isinstance(src, str)):
            arr = np.asarray(src)
            if arr.ndim != 4 or arr.shape[-1] != 3 or arr.shape[0] == 0:
                raise VideoError(f"frames must be (F, H, W, 3) RGB with F >= 1, got {arr.shape}")
            if max_frames is not None:
                arr = arr[:max_frames]
            self.array = arr
            self.n = arr.shape[0]
            self.size = (arr.shape[2], arr.shape[1])
            self.fps = 25.0
        else:
            from ..io.video import iter_frames, video_info

            info = video_info(src)
            self.path = str(src)
            self.array = None
            self.fps = info.fps
            self.size = info.size
            # the container's count can be approximate: count by decoding
            n = 0
            for _ in iter_frames(src, stop=max_frames):
                n += 1
            if n == 0:
                raise VideoError(f"video {src} has no frames")
            self.n = n

    def iterate(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        stop = self.n if stop is None else min(stop, self.n)
        if self.array is not None:
            yield from self.array[start:stop]
            return
        from ..io.video import iter_frames

        yield from iter_frames(self.path, start=start, stop=stop)

    def get(self, i: int) -> np.ndarray:
        return next(self.iterate(i, i + 1))


def frame_source(src, max_frames: int | None = None) -> FrameSource:
    """Wrap a video path or an ``(F, H, W, 3)`` array for the tracker."""
    return FrameSource(src, max_frames)

"""Videos decoded ahead of their use (a command's inputs, while it imports and loads).

:class:`Prefetch` starts :func:`facetransfer.io.video.read_video` of a command's inputs on
threads at its start; :func:`frames_to_cover` says how many frames of an expression source a
transfer needs beside its target.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from . import video
from .video import video_info

__all__ = ["Prefetch", "frames_covering", "frames_to_cover"]


def frames_covering(n_target: int, fps_target: float, fps_source: float) -> int:
    """Frames of a video at ``fps_source`` that cover ``n_target`` frames at ``fps_target``:
    up to the source's frame after the last target frame's time."""
    return int(np.ceil((n_target - 1) * fps_source / fps_target + 1e-9)) + 1


def frames_to_cover(target: str | os.PathLike, source: str | os.PathLike,
                    max_frames: int | None = None) -> int:
    """Frames of the video ``source`` to decode for the first ``max_frames`` frames of the
    video ``target`` (all: None): :func:`frames_covering` by the containers' frame counts and
    rates, and 8 more for a count that is a little short."""
    ti, si = video_info(target), video_info(source)
    n_est = ti.n_frames if max_frames is None else min(int(max_frames), ti.n_frames)
    return frames_covering(max(n_est, 1), ti.fps, si.fps) + 8


class Prefetch:
    """Videos decoded on background threads before they are needed, then handed out by
    :meth:`read_video` as :func:`~facetransfer.io.video.read_video` would return them.

    A command starts decoding its inputs first (OpenCV decodes without the interpreter lock)
    and meanwhile imports its modules and loads its model, which mostly hold it. A read that
    was not started here, or asked for more frames than were decoded before the clip's end, is
    done on the spot; an error of a background read (a damaged file) is raised by the
    :meth:`read_video` that asks for it.

    Parameters
    ----------
    reads : iterable of (path-like, int or None)
        Each video and how many frames to decode (None: all).
    """

    def __init__(self, reads) -> None:
        from concurrent.futures import ThreadPoolExecutor

        reads = [(Path(p), None if n is None else int(n)) for p, n in reads]
        self._pool = ThreadPoolExecutor(max_workers=max(1, len(reads)),
                                        thread_name_prefix="prefetch")
        self._jobs = {_key(p): (n, self._pool.submit(video.read_video, p, max_frames=n))
                      for p, n in reads}
        self._pool.shutdown(wait=False)

    def read_video(self, path: str | os.PathLike, *, max_frames: int | None = None
                   ) -> tuple[np.ndarray, float]:
        """:func:`~facetransfer.io.video.read_video` of the first ``max_frames`` frames
        (taken from a background read when it covers them; each is handed out once)."""
        n, job = self._jobs.pop(_key(path), (None, None))
        if job is not None:
            frames, fps = job.result()
            if n is None or len(frames) < n or (max_frames is not None and max_frames <= n):
                return (frames if max_frames is None else frames[:max_frames]), fps
        return video.read_video(path, max_frames=max_frames)


def _key(path) -> str:
    return os.path.realpath(os.fspath(path))

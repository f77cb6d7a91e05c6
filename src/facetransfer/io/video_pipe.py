"""Decoding through the ffmpeg binary the videos OpenCV cannot: interlaced pictures.

OpenCV's reader converts each decoded picture to BGR with libswscale, which refuses a picture
flagged interlaced ("Cannot convert interlaced to progressive frames or vice versa"); OpenCV
then reports the frame as read and returns its buffer unconverted: all zero, or whatever the
memory held (an interlaced ProRes here: black on one run, stray values on the next).
Interlaced H.264 (AVCHD camcorders, 1080i broadcast) thus read as a clip of black frames:
``track`` found no face in them, and a transfer would have had none to rewrite. The ffmpeg
binary's own conversion (its scale filter) takes them; :func:`piped_frames` decodes such a
video there, into the frames a progressive decoder shows: both fields woven, each row from its
own field, in RGB. Which videos: every interlaced one
(:func:`facetransfer.io.video_display.first_field`), so that its frames never depend on
whether OpenCV's conversion happened to work.
"""

from __future__ import annotations

import os
import subprocess
from typing import Iterator

import numpy as np

from ..errors import VideoError
from .ffmpeg import ffmpeg_exe

__all__ = ["piped_frames"]


def piped_frames(path: str | os.PathLike, size: tuple[int, int], *, start: int = 0,
                 stop: int | None = None) -> Iterator[np.ndarray]:
    """The stored frames ``start`` to ``stop`` of a video as ``(H, W, 3) uint8`` RGB, decoded
    by the ffmpeg binary (``rawvideo``, every stored frame in turn: ``-fps_mode
    passthrough``); ``size`` is ``(W, H)``. The frames before ``start`` are decoded and
    dropped (no seek: exact)."""
    exe = ffmpeg_exe()
    if exe is None:
        raise VideoError(f"video {path} is interlaced, which OpenCV decodes as black frames, "
                         "and no ffmpeg binary was found to decode it (install imageio-ffmpeg)")
    W, H = (int(v) for v in size)
    cmd = [exe, "-v", "error", "-nostdin", "-i", str(path), "-map", "0:v:0",
           "-fps_mode", "passthrough", "-f", "rawvideo", "-pix_fmt", "rgb24"]
    if stop is not None:
        cmd += ["-frames:v", str(int(stop))]
    proc = subprocess.Popen(cmd + ["-"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    try:
        i = 0
        while stop is None or i < stop:
            frame = _read_frame(proc.stdout, H, W)
            if frame is None:
                return
            if i >= start:
                yield frame
            i += 1
    finally:
        proc.stdout.close()
        proc.kill()
        proc.wait()


def _read_frame(pipe, H: int, W: int) -> np.ndarray | None:
    """One ``(H, W, 3)`` frame from ``pipe``, or None at its end (a partial frame too)."""
    frame = np.empty((H, W, 3), np.uint8)
    view, got = memoryview(frame).cast("B"), 0
    while got < frame.nbytes:
        n = pipe.readinto(view[got:])
        if not n:
            return None
        got += n
    return frame

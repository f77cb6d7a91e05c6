"""A video's frames decoded a second time, by the ffmpeg binary, in a form the 8-bit frames
the tools read (:mod:`facetransfer.io.video_read`) do not hold: its alpha plane
(:mod:`facetransfer.io.plate_alpha`), its colour in 16 bits (:mod:`facetransfer.io.video_depth`).

One ffmpeg process decodes the first video stream in order, every stored frame as it is
(``-fps_mode passthrough``), as raw 16-bit samples; frames are asked for by number, in any
order a few frames ahead (the rewrite's threads): the frames decoded and not yet asked for are
kept until they are. A still image (a photo held as a transfer's target over its expression
source's frames, :func:`facetransfer.transfer_plan.held_frames`) is decoded once, its one frame
given for every number. The numbers are the reader's: a video of variable frame rate is read on
its constant-rate timeline (:mod:`facetransfer.io.video_timeline`), so frame ``i`` is the
stored frame its step ``i`` shows (kept while a later step shows it again; stored frames no
step shows are passed over).
"""

from __future__ import annotations

import re
import subprocess
import threading
from pathlib import Path

import numpy as np

from ..errors import VideoError
from .ffmpeg import ffmpeg_exe
from .video_display import described_input
from .video_sequence import is_still

__all__ = ["DecodedPlanes", "stored_pixel_format"]


def stored_pixel_format(video) -> str | None:
    """The pixel format of a video file's first video stream as ffmpeg names it
    (``"yuv422p10le"``, ``"yuva444p10le"``), or None."""
    m = re.search(r"Stream #[^\n]*?: Video: [^\n]*?, ([a-z0-9]+)(?:\(|,)",
                  described_input(video))
    return m.group(1) if m else None


class DecodedPlanes:
    """``frame(i)``: frame ``i`` of a video decoded by ffmpeg as ``(H, W, C) uint16``.

    Parameters
    ----------
    video : path-like
    pix_fmt : {"gray16le", "rgb48le", "rgba64le"}
        The raw samples asked of ffmpeg (little-endian 16 bits; 1, 3 or 4 channels).
    what : str
        What the frames are, for errors ("the alpha of", "the 16-bit colour of").
    filters : str, optional
        An ffmpeg filter chain applied first (``"alphaextract"``).
    start : int
        The first frame that will be asked for (the frames before it are decoded and dropped).
    """

    _CHANNELS = {"gray16le": 1, "rgb48le": 3, "rgba64le": 4}

    def __init__(self, video, pix_fmt: str, what: str, *, filters: str | None = None,
                 start: int = 0) -> None:
        self.video, self.pix_fmt, self.what = Path(video), pix_fmt, what
        self._channels = self._CHANNELS[pix_fmt]
        self._filters = filters
        self._next, self._kept, self._size = 0, {}, None
        self._lock = threading.Lock()
        self._proc = None
        self._still = is_still(video)           # its one frame held, for every number
        self._start = 0 if self._still else int(start)
        self._steps, self._shown = None, None   # a variable rate's timeline (module notes)

    def _open(self) -> None:
        exe = ffmpeg_exe()
        if exe is None:
            raise VideoError(f"no ffmpeg binary found to read {self.what} {self.video}")
        from collections import Counter

        from .video_read import video_info

        info = video_info(self.video)
        self._size = info.size
        if info.steps is not None:   # each stored frame: how many steps from start show it
            self._steps = info.steps
            self._shown = Counter(info.steps[self._start:])
        vf = ["-vf", self._filters] if self._filters else []
        self._proc = subprocess.Popen(
            [exe, "-hide_banner", "-nostdin", "-loglevel", "error", "-i", str(self.video),
             "-map", "0:v:0", "-fps_mode", "passthrough", *vf, "-f", "rawvideo",
             "-pix_fmt", self.pix_fmt, "-"],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)

    def _read_next(self) -> np.ndarray:
        w, h = self._size
        n = w * h * self._channels * 2
        buf = self._proc.stdout.read(n)
        if len(buf) != n:
            raise VideoError(f"{self.what} {self.video} ends at frame {self._next}")
        return np.frombuffer(buf, "<u2").reshape(h, w, self._channels)

    def frame(self, i: int) -> np.ndarray:
        """``(H, W, C) uint16``: the video's frame ``i`` (``i`` at least ``start``, each asked
        for once; a still's one frame, read-only, for any ``i``)."""
        with self._lock:
            if self._proc is None:
                self._open()
            if self._still:
                if 0 not in self._kept:
                    self._kept[0], self._next = self._read_next(), 1
                return self._kept[0]
            s = self._stored(i)
            while self._next <= s:
                a = self._read_next()
                if self._wanted(self._next):
                    self._kept[self._next] = a
                self._next += 1
            if s not in self._kept:
                raise VideoError(f"{self.what} frame {i} of {self.video} was read already")
            if self._shown is None:
                return self._kept.pop(s)
            self._shown[s] -= 1
            return self._kept[s] if self._shown[s] > 0 else self._kept.pop(s)

    def _stored(self, i: int) -> int:
        """The stored frame that frame ``i`` shows."""
        if self._steps is None:
            return int(i)
        if not 0 <= i < len(self._steps):
            raise VideoError(f"{self.what} {self.video} ends at frame {len(self._steps)}")
        return int(self._steps[i])

    def _wanted(self, s: int) -> bool:
        """Whether stored frame ``s`` will be asked for (from ``start`` on)."""
        if self._shown is None:
            return s >= self._start
        return self._shown.get(s, 0) > 0

    def close(self) -> None:
        """Stop the decoder (also when not every frame was asked for)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            proc.kill()
            proc.wait()
            proc.stdout.close()

"""A video of more than 8 bits (ProRes 422 and 4444, 10-bit H.264 and HEVC, a phone's HDR
video, 16-bit PNG in a QuickTime file) rewritten in its own depth: as ProRes or H.265 (10 bits
in the file, ``--codec prores``, ``--codec h265``) or as a 16-bit PNG or TIFF sequence.

The tools see every video in 8 bits (:mod:`facetransfer.io.video_read`, OpenCV's decoder), so
a rewrite written from those frames would lose the levels below 8 bits of every pixel, the
face's surroundings included. Here the video is decoded a second time, by ffmpeg, in 16 bits
(:class:`~facetransfer.io.video_planes.DecodedPlanes`), and each output frame is that decode
moved by the rewrite's change (:func:`facetransfer.io.plate_depth.deep_frame`): where the
rewrite changed nothing, the video's own samples; elsewhere those samples plus the change.
The two decoders round differently (0.6 of an 8-bit level on average, up to 3-4 at sharp
colour edges), so the change, not the rewrite's value, is what is carried: the face meets its
surroundings without a step. A video's alpha plane is carried in 16 bits beside it (ProRes
4444, a PNG sequence; a TIFF sequence's alpha is written in 8 bits by
:mod:`facetransfer.io.plate_alpha`), its bits repeated below its depth as ffmpeg's own
``alphaextract`` gives them (``rgba64le`` leaves them 0: an opaque 12-bit alpha would read
65520, not 65535); into ProRes on the 10-bit grid its encoder takes back exactly, so the
output's alpha decodes as the target's did.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import VideoError
from .plate_alpha import video_has_alpha
from .plate_depth import DEPTH_OUTPUTS, deep_frame
from .video import is_image_pattern
from .video_options import DEEP_CODECS
from .video_planes import DecodedPlanes, stored_pixel_format
from .video_sequence import is_sequence

__all__ = ["VideoDepth", "keeps_depth", "pixel_format_bits", "video_bits", "video_depth"]

#: ffmpeg's pixel formats of 16-bit samples whose names carry no bit depth.
_SIXTEEN = re.compile(r"(rgb|bgr)48|(rgba|bgra)64|ya16")
#: The others name their depth after the planes' letters: yuv422p10le, gbrp12le, gray10le,
#: p010le, y210le, x2rgb10le.
_NAMED = re.compile(r"(?:p|gray|y2|x2rgb|x2bgr|xv)0?(9|10|12|14|16)(?:le|be)?$")


def pixel_format_bits(fmt: str | None) -> int:
    """The bits a sample of ffmpeg's pixel format ``fmt`` holds (8 unless its name says more;
    ``"yuv422p10le"``: 10, ``"rgb48le"``: 16, ``"v210"``: 10)."""
    if not fmt:
        return 8
    if _SIXTEEN.match(fmt):
        return 16
    if fmt in ("v210", "v410"):
        return 10
    m = _NAMED.search(fmt)
    return int(m.group(1)) if m else 8


def video_bits(video) -> int:
    """The bits a sample of a video file's first video stream holds (8 without ffmpeg)."""
    return pixel_format_bits(stored_pixel_format(video))


class VideoDepth:
    """``depth(i, shown, rewritten)``: output frame ``i`` of a video of more than 8 bits,
    ``(H, W, 3)`` RGB or, with ``alpha``, ``(H, W, 4)`` RGBA uint16 (module notes).

    Parameters
    ----------
    video : path-like
    bits : int
        Its bits a sample (said in :attr:`kept`).
    alpha : bool
        Carry its alpha plane (16 bits).
    start : int
        The first frame that will be asked for.
    written : int
        The bits a sample of the output (ProRes 10, a PNG or TIFF 16; said in :attr:`kept`).
    """

    def __init__(self, video, bits: int, alpha: bool = False, start: int = 0,
                 written: int = 16) -> None:
        self.video, self._bits, self._alpha = Path(video), int(bits), bool(alpha)
        self._written = int(written)
        self._planes = DecodedPlanes(video, "rgba64le" if alpha else "rgb48le",
                                     "the 16-bit colour of", start=start)
        depth = f"the target's {bits} bits" if written >= bits else \
            f"{written} of the target's {bits} bits"
        #: What the output keeps of the video (the transfer's summary line says it).
        self.kept = f"in {depth}" + (", with its alpha" if alpha else "")

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
        plane = self._planes.frame(i)
        if plane.shape[:2] != np.shape(rewritten)[:2]:
            raise VideoError(f"frame {i} of {self.video} decodes to {plane.shape[1]}x"
                             f"{plane.shape[0]} in 16 bits, the rewrite is "
                             f"{np.shape(rewritten)[1]}x{np.shape(rewritten)[0]}")
        out = deep_frame(plane, shown, rewritten)
        if self._alpha:
            out[..., 3] = _alpha_for(out[..., 3], self._bits, self._written)
        return out

    def close(self) -> None:
        """Stop the decoder (also when not every frame was asked for)."""
        self._planes.close()


def _alpha_for(a: np.ndarray, bits: int, written: int) -> np.ndarray:
    """A video's decoded alpha ``a`` (uint16, of a ``bits``-bit stream as ffmpeg's
    ``rgba64le`` gives it: ``v << (16 - bits)``) for an output of ``written`` bits: its bits
    repeated below its depth (as ffmpeg's ``alphaextract`` gives them: opaque is 65535); for
    ProRes (10), on the 10-bit grid as ``v10 << 6``, which ffmpeg's conversion to 10 bits
    (rounding) takes back to ``v10`` exactly: the output's alpha decodes as the target's."""
    a = a | (a >> bits) if 8 <= bits < 16 else a
    if written != 10:
        return a
    return (((a.astype(np.uint32) * 1023 + 32767) // 65535) << 6).astype(np.uint16)


def keeps_depth(out, video, codec: str) -> bool:
    """Whether the output ``out`` (a video written with ``codec``) of the video target
    ``video`` holds its samples beyond 8 bits: ProRes or H.265
    (:data:`~facetransfer.io.video_options.DEEP_CODECS`), a PNG, TIFF or DPX sequence (a PNG
    or DPX one only for a video with alpha: OpenCV writes no TIFF alpha tag)."""
    o = Path(out)
    if "%" not in o.name:
        return codec in DEEP_CODECS
    if o.suffix.lower() not in DEPTH_OUTPUTS:
        return False
    return o.suffix.lower() in (".png", ".dpx") or not video_has_alpha(video)


def video_depth(out, target, options=None, start: int = 0) -> VideoDepth | None:
    """The 16-bit decode of the video ``target`` of more than 8 bits, rewritten as ``out``:
    ProRes or H.265 (``options`` asking for it,
    :attr:`~facetransfer.io.video_options.VideoOptions.deep`, set by
    :func:`~facetransfer.io.video_like.like_video`; its alpha as ``options.alpha`` says) or a
    PNG or TIFF sequence (a PNG one with the video's alpha); None otherwise (an 8-bit video,
    H.264 written, a TIFF sequence of a video with alpha: written by
    :mod:`facetransfer.io.plate_alpha` in 8 bits with its alpha)."""
    if target is None or is_sequence(target) or not Path(target).is_file():
        return None
    if is_image_pattern(out):
        bits = video_bits(target)
        if bits <= 8 or not keeps_depth(out, target, ""):
            return None
        return VideoDepth(target, bits, video_has_alpha(target), start)
    if not getattr(options, "deep", False):
        return None
    return VideoDepth(target, video_bits(target), bool(options.alpha), start, written=10)

"""The matte of a rewrite (``facetransfer transfer --matte``): for every output frame, one grey
image of the fraction of each pixel the rewrite took from the new face
(:attr:`facetransfer.rewrite.RewriteFrame.matte`): 0 where the output is the plate's own pixel
to the bit, 1 where the plate's pixel was wholly replaced, between on the feathered seam.

Written as an image sequence of one channel, numbered as the output (``matte/%05d.png`` or
``.tif``/``.tiff``: 16-bit grey; ``.exr``: float32, one channel ``Y`` tagged as data, not
colour (``colorInteropID`` ``data``), with the frame's rate, timecode and pixel aspect in its
header), or as a video: ``.mov`` and ``.mkv`` lossless, one grey channel of 16 bits, the
sequence's levels exactly (:data:`LOSSLESS_MATTE_CODECS`); ``.mp4`` lossy, the grey in three
channels of 8 bits encoded as the output is (H.264 where the output is ProRes), said in a
warning. A pixel the rewrite touched is never 0 in the file: a fraction below the file's first
level is written as that level, so that the matte's zeros are exactly the plate's pixels (an
``.mp4`` matte's levels move: a 1 may decode as 0, a 0 above it). The output is not
premultiplied by the matte: ``out - plate * (1 - m)`` is the premultiplied foreground. The
frames go through the writers every output goes through
(:class:`~facetransfer.io.video.VideoWriter`, the render cache's
:mod:`facetransfer.io.sequence_parts` and :mod:`facetransfer.io.video_parts`), written
atomically; the output's audio is not put into it.
"""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import FaceTransferError, OutputError
from .output_names import suffix_list
from .video import VideoOptions, VideoOutput, check_video_output, is_image_pattern
from .video_sequence import same_sequence_files

log = logging.getLogger(__name__)

__all__ = ["MATTE_SEQUENCE_SUFFIXES", "MATTE_VIDEO_SUFFIXES", "LOSSLESS_MATTE_CODECS",
           "MatteError", "MatteWriter",
           "check_matte_output", "matte_frame", "matte_options"]

#: Frame files of a matte sequence: 16-bit grey PNG or TIFF, float OpenEXR.
MATTE_SEQUENCE_SUFFIXES = (".png", ".tif", ".tiff", ".exr")
#: Video files of a matte (``.mov``, ``.mkv``: 16-bit lossless; ``.mp4``: 8 bits, lossy).
MATTE_VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv")
#: The lossless codec of a video matte per container, 16-bit grey (``gray16``), exact to the
#: level: decoded back, 0 is 0 and 65535 is 65535, as in a 16-bit PNG sequence.
#:
#: - ``.mov``: QuickTime PNG (sample entry ``png ``; ffmpeg's png encoder, ``gray16be``), one
#:   PNG image a frame, each a key frame: a codec of Apple's QuickTime, decoded by FFmpeg's
#:   libavcodec, which Nuke's ``mov64`` Read is built on (Foundry, Nuke supported file
#:   formats). Not QuickTime Animation (``qtrle``): ffmpeg writes its grey in 8 bits (a ramp
#:   decoded back off by up to 368 of 65535, measured); not FFV1, which Apple's QuickTime
#:   framework does not decode. Not verified here in Nuke or Resolve themselves.
#: - ``.mkv``: FFV1 level 3 (ffmpeg's ffv1 encoder, ``gray16le``; intra only, ``-g 1``, so
#:   every frame decodes alone; a CRC per slice), the lossless codec Matroska archives hold
#:   (IETF CELLAR: RFC 9043 for versions 0 to 2, version 3 a draft): a third smaller than
#:   PNG and faster to write (512x480: 43 against 66 kB and 3 against 5 ms a frame).
#:
#: ``.mp4`` has none that players and compositors read (H.264 lossless is the High 4:4:4
#: Predictive profile, which Apple's decoders refuse): written lossy, as the output, with a
#: warning naming ``.mov``, ``.mkv`` and sequences.
LOSSLESS_MATTE_CODECS = {".mov": "png", ".mkv": "ffv1"}


class MatteError(OutputError):
    """A matte that cannot be written where asked (its kind, its name); names the path."""


def check_matte_output(matte: str | os.PathLike, *, out, options: VideoOptions | None = None,
                       overwrite: bool = False, inputs=()) -> VideoOutput:
    """Check the matte ``matte`` of the output ``out`` before any work: a sequence of
    :data:`MATTE_SEQUENCE_SUFFIXES` or a video of :data:`MATTE_VIDEO_SUFFIXES`, not ``out``
    itself (nor its frames), not one of ``inputs``, not existing unless ``overwrite``
    (:func:`facetransfer.io.video.check_video_output` with :func:`matte_options` of the
    output's ``options``).

    Raises
    ------
    MatteError
        Another kind of file, or ``out``'s name; or what
        :func:`~facetransfer.io.video.check_video_output` refuses (exists, an input, no such
        folder), its words after ``--matte:`` (the option named, as the CLI's one line).
    """
    p = Path(matte)
    suffix = p.suffix.lower()
    if is_image_pattern(p):
        if suffix not in MATTE_SEQUENCE_SUFFIXES:
            raise MatteError(f"--matte {p}: a matte sequence is written as "
                             f"{suffix_list(MATTE_SEQUENCE_SUFFIXES)} frames (16-bit grey or "
                             f"float), not {suffix or 'a name without extension'}")
    elif suffix not in MATTE_VIDEO_SUFFIXES:
        raise MatteError(f"--matte {p}: a matte is an image sequence (e.g. matte/%05d.png, "
                         f"16-bit) or a video ({suffix_list(MATTE_VIDEO_SUFFIXES)}), not "
                         f"{suffix or 'a name without extension'}")
    o = Path(out)
    if os.path.abspath(p) == os.path.abspath(o) or (
            is_image_pattern(p) and is_image_pattern(o) and same_sequence_files(p, o)):
        raise MatteError(f"--matte {p} is also --out: give the matte its own name")
    try:
        return check_video_output(p, matte_options(options, p), overwrite=overwrite,
                                  inputs=[q for q in inputs if q is not None])
    except FaceTransferError as exc:   # "output X exists": which of the outputs, said
        raise MatteError(f"--matte: {exc}") from exc


def matte_options(options: VideoOptions | None, matte) -> VideoOptions:
    """The :class:`VideoOptions` of the matte ``matte`` of an output written with
    ``options``: its first number, timecode and pixel aspect; for a ``.mov`` or ``.mkv``
    video the lossless grey codec of its container (:data:`LOSSLESS_MATTE_CODECS`); for an
    ``.mp4`` the output's codec (ProRes: H.264), quality, preset and fields. No colour beyond
    grey, no alpha; 16 bits in sequences and lossless videos."""
    opt = VideoOptions() if options is None else options
    kept = VideoOptions(first_number=opt.first_number, timecode=opt.timecode, sar=opt.sar)
    if is_image_pattern(matte):
        return kept
    lossless = LOSSLESS_MATTE_CODECS.get(Path(matte).suffix.lower())
    if lossless is not None:   # fields: each frame's matte is whole, as the sequence's
        return replace(kept, codec=lossless, colour_tags=False)
    codec = "h264" if opt.codec == "prores" else opt.codec   # (ProRes: .mov and .mkv only)
    return replace(kept, codec=codec, crf=opt.crf, preset=opt.preset,
                   field=None if codec == "h265" else opt.field)


def matte_frame(matte: np.ndarray | None, size: tuple[int, int], path) -> np.ndarray:
    """The frame the matte file ``path`` holds for ``matte`` (H, W) float in [0, 1] (None: a
    frame without a face, all 0) of ``size`` (W, H): ``(H, W)`` float32 of an OpenEXR
    sequence, ``(H, W)`` uint16 of a PNG or TIFF one or of a lossless video (``.mov``,
    ``.mkv``), ``(H, W, 3)`` uint8 grey of an ``.mp4``; a fraction above 0 is at least the
    file's first level above 0."""
    W, H = int(size[0]), int(size[1])
    a = np.zeros((H, W), np.float32) if matte is None else \
        np.clip(np.asarray(matte, np.float32), 0.0, 1.0)
    if a.shape != (H, W):
        raise MatteError(f"matte of shape {a.shape} does not match the size {W}x{H} of {path}")
    if Path(path).suffix.lower() == ".exr":
        return a
    deep = not _lossy(path)
    top = 65535.0 if deep else 255.0
    v = np.rint(a * np.float32(top)).astype(np.uint16 if deep else np.uint8)
    v[(v == 0) & (a > 0)] = 1       # touched: never the plate's 0
    return v if deep else np.repeat(v[..., None], 3, axis=2)


def _lossy(path) -> bool:
    """Whether the matte ``path`` is a video of 8 lossy bits (an ``.mp4``), not a sequence nor
    a lossless video (:data:`LOSSLESS_MATTE_CODECS`)."""
    return not is_image_pattern(path) and Path(path).suffix.lower() not in LOSSLESS_MATTE_CODECS


class MatteWriter:
    """Write the matte frames of an output through ``writer`` (a render cache's parts writer,
    which may hold the frames an interrupted run wrote, or a
    :class:`~facetransfer.io.video.VideoWriter`): frame ``i`` is written only from the
    frames the writer already holds on (:attr:`done`), so a render continued from an earlier
    frame for the output writes each matte frame once. A context manager: committed when the
    block ends without error, else kept (parts) or discarded (a writer in one piece).

    Parameters
    ----------
    writer : PartsWriter, SequenceWriter or VideoWriter
    path : path-like
        The matte (:func:`check_matte_output`).
    size : (width, height)
    """

    def __init__(self, writer, path, size: tuple[int, int]) -> None:
        self.writer, self.path, self.size = writer, Path(path), tuple(size)
        self.done = int(getattr(writer, "done", 0))
        if _lossy(self.path):
            log.warning("%s: an %s matte is lossy, 8 bits (its 0 may decode above 0, its 1 "
                        "below): for a matte to key on write a .mov or .mkv (16-bit lossless) "
                        "or a sequence (matte/%%05d.png, .tif, .exr)", self.path,
                        self.path.suffix.lower())

    def write(self, i: int, matte: np.ndarray | None) -> None:
        """Frame ``i``'s matte ((H, W) float in [0, 1], or None: all 0), in order."""
        if i >= self.done:
            self.writer.write(matte_frame(matte, self.size, self.path))

    def __enter__(self) -> "MatteWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.writer.close(commit=exc_type is None)

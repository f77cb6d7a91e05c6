"""How a video is encoded (:class:`VideoOptions`): codec, quality, speed, and what its header
says of the frames (pixel shape, colour, fields, start timecode), checked once, before any
work; the writer is :mod:`facetransfer.io.video`, whose names these are too."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import VideoError
from .video_display import checked_aspect, checked_colour_name, checked_timecode

__all__ = ["CODECS", "GREY_CODECS", "ENCODERS", "DEEP_CODECS", "DEFAULT_CODEC", "DEFAULT_CRF",
           "CRF_RANGE", "PRESETS", "DEFAULT_PRESET", "DEFAULT_X264_PARAMS", "VIDEO_SUFFIXES",
           "VideoOptions"]

#: Video containers by extension (the ffmpeg muxer of each).
VIDEO_SUFFIXES = {".mp4": "mp4", ".m4v": "mp4", ".mov": "mov", ".mkv": "matroska",
                  ".avi": "avi"}
#: Codec names of ``--codec`` and the ffmpeg encoder each needs.
CODECS = {"h264": "libx264", "h265": "libx265", "prores": "prores_ks"}
#: Lossless codecs of one 16-bit grey channel, a video matte's (:mod:`facetransfer.io.matte`;
#: not ``--codec`` choices): PNG (QuickTime's ``png `` in ``.mov``), FFV1 (``.mkv``).
GREY_CODECS = {"png": "png", "ffv1": "ffv1"}
#: The ffmpeg encoder of every codec.
ENCODERS = {**CODECS, **GREY_CODECS}
DEFAULT_CODEC = "h264"
#: Constant rate factor of H.264 / H.265 when none is given (x264: 18 is "visually lossless").
DEFAULT_CRF = 18
CRF_RANGE = (0, 51)  # x264 and x265, 8-bit
#: x264 / x265 speed presets, fastest first.
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
           "veryslow")
#: Codecs written from 16-bit frames (:attr:`VideoOptions.deep`), 10 bits in the file.
DEEP_CODECS = ("prores", "h265")
#: The default preset: x264's "faster" costs 64 % of the CPU of its own default, "medium",
#: for 0.07 dB less over the face of a transfer at CRF 18 (BENCHMARKS.md, "End to end").
DEFAULT_PRESET = "faster"
#: x264 settings the default preset is written with, on top of x264's own "faster" (H.264
#: only; any other ``--preset`` is x264's as it stands): B-frames' 8x8 partitions not searched
#: (x264's ``partitions`` with ``b8x8`` left out). On the 300 frames issue 13's transfer writes
#: (512x480, CRF 18) the encoder took 2.0-2.1 CPU-s instead of 2.5 (two runs of 3 rounds,
#: medians; 2.1 instead of 2.7 beside two busy processes), the file 0.5 % larger, 0.05 dB less
#: outside the face against the target file and 0.03 dB more against the target encoded alike
#: (the 45 dB bar); on three other clips 11-17 % less CPU, within 0.06 dB and 0.7 % in size.
#: Fewer threads, a shorter lookahead, ``ref=1``, ``subme=3`` or ``me=dia`` saved less or
#: cost more quality (BENCHMARKS.md, "Fiftieth session (helper x26450)";
#: ``benchmarks/bench_x264_params.py``).
DEFAULT_X264_PARAMS = "partitions=i4x4,i8x8,p8x8"


@dataclass(frozen=True)
class VideoOptions:
    """How to encode a video.

    Attributes
    ----------
    codec : {"h264", "h265", "prores", "png", "ffv1"}
        H.264 (libx264) and H.265 (libx265) are written as 8-bit 4:2:0 (``yuv420p``), what
        browsers and phones play; ProRes 422 HQ (prores_ks, 10-bit 4:2:2) for editing, in
        ``.mov`` or ``.mkv``. PNG and FFV1 (:data:`GREY_CODECS`, :attr:`grey`): one grey
        channel of 16 bits, lossless (frames ``(H, W) uint16``), a matte's, in ``.mov`` or
        ``.mkv``; no CRF, fields, alpha, colour tags.
    crf : int, optional
        Constant rate factor of H.264 / H.265, 0 (lossless in YUV) to 51; lower is better and
        bigger. Default :data:`DEFAULT_CRF`. ProRes has none.
    preset : str
        x264 / x265 speed preset (:data:`PRESETS`): faster ones cost less CPU for a little less
        quality or bigger files at the same CRF (figures in BENCHMARKS.md). The default,
        :data:`DEFAULT_PRESET`, whether asked for or not, is written by x264 with
        :data:`DEFAULT_X264_PARAMS` too (11-18 % less of the encoder's CPU, measured on four
        clips, for the same quality); every other preset is x264's own.
    sar : (int, int), optional
        The pixel aspect ratio written into the video's header (its sample aspect ratio), so
        that players show it at the shape of the video it rewrites (e.g. (15, 16): a 512x480
        video shown 480x480). None: square pixels, nothing written; the commands that rewrite a
        video take that video's (:func:`~facetransfer.io.video_like.like_video`, as the
        attributes below). Image sequences carry none.
    colour_tags : bool
        Name the colour matrix and range of the frames' conversion (``matrix``, limited) in the
        header. False leaves them unspecified, for a video that rewrites one which names none:
        a player then guesses alike for both.
    matrix : str
        The YCbCr matrix the RGB frames are converted by, as ffmpeg names it: BT.601
        (``"smpte170m"``), or for frames ffmpeg converts itself (ProRes, 16-bit frames) any it
        knows (``"bt709"``, ``"bt2020nc"``: a deep HDR video's, as
        :func:`~facetransfer.io.video_like.like_video` carries it).
    primaries, transfer : str, optional
        The colour primaries and transfer characteristic named in the header, as ffmpeg names
        them (``"bt709"``; HLG ``"arib-std-b67"``): a rewritten video's RGB values are those
        its input's decoding gave, so they are its input's. None: not named.
    field : {"top", "bottom"}, optional
        Interlaced video: the field shown first, written into the stream (H.264 and ProRes
        coded interlaced), so that players show a rewritten interlaced video as they showed
        it; not with H.265 (x265 writes progressive frames). None: progressive.
    first_number : int, optional
        An image sequence's number of its first frame. None: 0, but the commands that rewrite
        an image sequence number theirs as it is numbered (a plate's 1001 on), as
        :func:`~facetransfer.io.video_like.like_video` gives.
    timecode : str, optional
        The start timecode written into an MP4, QuickTime or Matroska file (``HH:MM:SS:FF``,
        ``;`` before the frames of a drop-frame one): a ``tmcd`` track, a tag. None: none; the
        commands that rewrite a video carry its own (its first frame is theirs), as
        :func:`~facetransfer.io.video_like.like_video` gives, so that an editor conforms the
        result where the shot was. AVI files and image sequences carry none.
    alpha : bool
        ProRes 4444 with an alpha plane (frames ``(H, W, 4)`` RGBA) instead of 422 HQ: what
        :func:`~facetransfer.io.video_like.like_video` asks for a video target with alpha
        written as ProRes by a command that carries it (:mod:`facetransfer.io.plate_alpha`).
    deep : bool
        Frames are given in 16 bits (``uint16``; 8-bit ones are taken as ``v * 257``) and
        reach the file's 10 bits without passing through 8: ProRes, or H.265 written as Main 10
        (``yuv420p10le``); what :func:`~facetransfer.io.video_like.like_video` asks for a
        video target of more than 8 bits written as either by a command that carries its depth
        (:mod:`facetransfer.io.video_depth`).
    """

    codec: str = DEFAULT_CODEC
    crf: int | None = None
    preset: str = DEFAULT_PRESET
    sar: tuple[int, int] | None = None
    colour_tags: bool = True
    primaries: str | None = None
    transfer: str | None = None
    field: str | None = None
    first_number: int | None = None
    timecode: str | None = None
    alpha: bool = False
    deep: bool = False
    matrix: str = "smpte170m"

    def __post_init__(self) -> None:
        if self.codec not in ENCODERS:
            raise VideoError(f"codec must be one of {', '.join(ENCODERS)}, got {self.codec!r}")
        if self.grey and (self.crf is not None or self.field or self.alpha or self.deep):
            raise VideoError(f"{self.codec} writes lossless grey frames: no CRF, fields, "
                             "alpha or deep colour")
        if self.preset not in PRESETS:
            raise VideoError(f"preset must be one of {', '.join(PRESETS)}, got {self.preset!r}")
        if self.crf is not None:
            if self.codec == "prores":
                raise VideoError("--crf applies to h264 and h265; prores has a fixed quality "
                                 "(profile HQ)")
            lo, hi = CRF_RANGE
            if isinstance(self.crf, bool) or int(self.crf) != self.crf or not lo <= self.crf <= hi:
                raise VideoError(f"--crf must be an integer from {lo} to {hi} (the constant rate "
                                 f"factor: lower is better; default {DEFAULT_CRF}), got "
                                 f"{self.crf}")
        if self.sar is not None:
            object.__setattr__(self, "sar", checked_aspect(self.sar))
        checked_colour_name(self.primaries, "primaries")
        checked_colour_name(self.transfer, "transfer")
        if self.field not in (None, "top", "bottom"):
            raise VideoError(f"field must be 'top', 'bottom' or None, got {self.field!r}")
        if self.field is not None and self.codec == "h265":
            raise VideoError("x265 writes progressive frames: an interlaced video (field "
                             f"{self.field!r}) needs codec h264 or prores")
        checked_timecode(self.timecode)
        if self.alpha and self.codec != "prores":
            raise VideoError(f"an alpha plane is written as ProRes 4444 only, not {self.codec}")
        if self.deep and self.codec not in DEEP_CODECS:
            raise VideoError(f"16-bit frames are written as ProRes or H.265 only, not "
                             f"{self.codec}")
        if checked_colour_name(self.matrix, "matrix") != "smpte170m" and not (
                self.deep or self.codec == "prores"):
            raise VideoError(f"frames converted by the {self.matrix} matrix are written as "
                             "ProRes or in 16 bits only (8-bit H.264 and H.265 by BT.601)")
        n = self.first_number
        if n is not None and (isinstance(n, bool) or int(n) != n or n < 0):
            raise VideoError(f"an image sequence's first frame number must be an integer >= 0, "
                             f"got {n!r}")

    @property
    def grey(self) -> bool:
        """Whether frames are one lossless 16-bit grey channel (:data:`GREY_CODECS`)."""
        return self.codec in GREY_CODECS

    @property
    def effective_crf(self) -> int | None:
        """The CRF used (None for ProRes and the lossless grey codecs)."""
        return None if self.codec == "prores" or self.grey else \
            int(DEFAULT_CRF if self.crf is None else self.crf)

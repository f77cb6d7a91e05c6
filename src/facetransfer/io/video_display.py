"""How a video is shown: its pixel aspect ratio and its colour (matrix, primaries, transfer),
read from a video's header and written into the header of the video that rewrites it.

A rewritten video keeps the pixels of the video it rewrites outside the face; it should also be
shown as that video is. Facts of the header decide that beside the pixels: the pixel (sample)
aspect ratio, e.g. a 512x480 video shown 480x480 (:attr:`VideoInfo.sar
<facetransfer.io.video_read.VideoInfo>`), the colour matrix by which players turn YCbCr into
RGB, and the primaries and transfer of that RGB (:class:`ColourTags`, read from ffmpeg's
description of the file), and the fields of interlaced video (:func:`first_field`).
:func:`facetransfer.io.video_like.like_video` makes the options of a video that keep them.
"""

from __future__ import annotations

import functools
import os
import re
import struct
import subprocess
from dataclasses import dataclass

from ..errors import VideoError
from .ffmpeg import ffmpeg_exe
from .verified import file_stamp
from .video_sequence import is_sequence

__all__ = ["HDR_TRANSFERS", "ColourTags", "checked_aspect", "pixel_aspect",
           "shown_width",
           "frame_args", "colour_named", "checked_colour_name", "described", "described_input",
           "video_colour",
           "colour_matrix", "field_named", "first_field", "container", "exact_seek", "EXACT_SEEK",
           "checked_timecode", "timecode_args", "timecode_of", "timecode_seconds",
           "display_mirrored"]


def pixel_aspect(num, den) -> tuple[int, int]:
    """A pixel aspect ratio ``num:den`` in lowest terms; (1, 1) when either is not a positive
    integer (a container that gives none reports 0:1)."""
    from math import gcd

    try:
        n, d = int(num), int(den)
    except (TypeError, ValueError, OverflowError):
        return (1, 1)
    if n <= 0 or d <= 0 or n != num or d != den:
        return (1, 1)
    g = gcd(n, d)
    return (n // g, d // g)


def shown_width(width: int, sar: tuple[int, int]) -> int:
    """The width in square pixels of ``width`` stored pixels of sample aspect ratio ``sar``
    ``(num, den)``: ``round(width num / den)``, at least 1."""
    n, d = (int(v) for v in sar)
    return max(1, int(round(int(width) * n / d)))


def checked_aspect(sar) -> tuple[int, int]:
    """``sar`` as two positive integers up to 65535 (H.264's bound) in lowest terms;
    VideoError otherwise."""
    try:
        n, d = (int(x) for x in sar)
        ok = (n, d) == tuple(sar) and 1 <= n <= 65535 and 1 <= d <= 65535
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise VideoError(f"a pixel aspect ratio must be two integers from 1 to 65535, e.g. "
                         f"(15, 16), got {sar!r}")
    return pixel_aspect(n, d)


def frame_args(sar: tuple[int, int] | None, primaries: str | None = None,
               transfer: str | None = None, field: str | None = None) -> list[str]:
    """ffmpeg arguments giving the frames the pixel aspect ratio ``sar``, the colour
    ``primaries`` and ``transfer``, and for interlaced video the ``field`` shown first
    (``"top"``, ``"bottom"``) (filters ``setsar``, ``setparams``: the encoder writes them into
    the stream, the container into its header; ffmpeg takes a frame's primaries and transfer
    over ``-color_primaries`` / ``-color_trc``); none for square, progressive pixels and no
    names."""
    chain = []
    if sar is not None and tuple(sar) != (1, 1):
        chain.append("setsar={}/{}".format(*sar))
    modes = {"top": "tff", "bottom": "bff"}
    named = [f"{k}={v}" for k, v in (("color_primaries", primaries), ("color_trc", transfer),
                                     ("field_mode", modes.get(field or ""))) if v]
    if named:
        chain.append("setparams=" + ":".join(named))
    return ["-vf", ",".join(chain)] if chain else []


@dataclass(frozen=True)
class ColourTags:
    """What a video's header says of its colour, as ffmpeg names it (None: nothing said).

    Attributes
    ----------
    matrix : str or None
        The YCbCr coefficients (``"bt709"``, ``"smpte170m"``, ``"bt2020nc"``, ...).
    primaries : str or None
        The RGB primaries (``"bt709"``, ``"bt2020"``, ...).
    transfer : str or None
        The transfer characteristic (``"bt709"``, ``"arib-std-b67"`` for HLG, ``"smpte2084"``
        for PQ, ...).
    """

    matrix: str | None = None
    primaries: str | None = None
    transfer: str | None = None

    @property
    def beyond_sdr(self) -> bool:
        """A transfer of high dynamic range (HLG or PQ) or BT.2020's wide gamut: what 8-bit SDR
        decoding does not show as a player does."""
        return self.transfer in HDR_TRANSFERS or self.primaries == "bt2020"


#: Transfer characteristics of high dynamic range: HLG (phones' default HDR) and PQ.
HDR_TRANSFERS = ("arib-std-b67", "smpte2084")


def colour_named(description: str) -> ColourTags:
    """The colour tags ffmpeg's description of a media file (``ffmpeg -i``'s output) gives its
    first video stream: the stream's pixel format lists range, ``matrix/primaries/transfer``
    (one name where the three are the same) and field order, e.g.
    ``yuv420p10le(tv, bt2020nc/bt2020/arib-std-b67, progressive)``."""
    for item in (x.strip() for x in _stream_details(description).split(",")):
        if "/" in item:
            names = [_said(n) for n in item.split("/")][:3]
            return ColourTags(*names)
        if item in _MATRICES:
            return ColourTags(item, item, item)
    return ColourTags()


#: The field shown first by the words of ffmpeg's description of a stream's field order (it
#: writes top-first frames as "top coded first", so the field coded first is taken).
_HEADER_FIELDS = (("top coded first", "top"), ("bottom coded first", "bottom"),
                  ("top first", "top"), ("bottom first", "bottom"))


def field_named(description: str) -> str | None:
    """The field an interlaced video shows first, ``"top"`` or ``"bottom"``, in
    :func:`described`'s text: the ``showinfo`` line of its first decoded frame (``i:T``,
    ``i:B``: the frame's own flag; a header may name no field order, as DV's), else the field
    order its header names (a stream whose first frame is progressive may hold interlaced ones
    later: broadcast captures, PAFF); None for neither."""
    found = re.search(r"showinfo[^\n]* i:([TBP])", description)
    frame = {"T": "top", "B": "bottom"}.get(found.group(1)) if found else None
    if frame is not None:
        return frame
    said = _stream_details(description)
    return next((field for words, field in _HEADER_FIELDS if words in said), None)


def _stream_details(description: str) -> str:
    """What ffmpeg's description gives in parentheses after the first video stream's pixel
    format: range, colour names, field order (``"tv, bt709, top first"``); "" for none."""
    found = re.search(r"Stream #[^\n]*?: Video: [^\n]*?, [a-z0-9_]+\(([^\n]*?)\)(?:,|$)",
                      description, re.MULTILINE)
    return found.group(1) if found else ""


def first_field(path: str | os.PathLike) -> str | None:
    """The field an interlaced video shows first (:func:`field_named`); None for progressive
    video or without ffmpeg."""
    return field_named(described(path))


#: ffmpeg's demuxers whose seeks OpenCV lands exactly on the frame asked (measured: MP4 and
#: QuickTime, Matroska and WebM, AVI); in others (MPEG transport streams of H.264, as AVCHD
#: camcorders write) it may land nowhere.
EXACT_SEEK = ("mov,mp4,m4a,3gp,3g2,mj2", "matroska,webm", "avi")


#: A SMPTE timecode as ffmpeg reads and writes it: ``HH:MM:SS:FF``, ``;`` (or ``.``) before
#: the frames of a drop-frame one (29.97 fps)
_TIMECODE = re.compile(r"\d{2}:[0-5]\d:[0-5]\d[:;.]\d{2,3}")


def timecode_of(path: str | os.PathLike) -> str | None:
    """A video's start timecode (the first it names in :func:`described_input`: a QuickTime /
    MP4 ``tmcd`` track's, a Matroska or MXF tag's), e.g. ``"01:00:00:00"``; an image
    sequence's, its first frame's header's (DPX, OpenEXR:
    :attr:`facetransfer.io.video_sequence.Sequence.timecode`); None without one (or without
    ffmpeg). A camera's or an editor's: what a conform matches shots by."""
    if is_sequence(path):
        from .video_sequence import sequence_timecode

        return sequence_timecode(path)
    found = re.search(r"^\s*timecode\s*:\s*(\S+)\s*$", described_input(path),
                      re.MULTILINE | re.IGNORECASE)
    if found is None or not _TIMECODE.fullmatch(found.group(1)):
        return None
    return found.group(1)


def checked_timecode(timecode) -> str | None:
    """``timecode`` (None or ``HH:MM:SS:FF``, ``;`` for drop frame) checked; VideoError
    otherwise (it becomes an ffmpeg argument)."""
    if timecode is None or (isinstance(timecode, str) and _TIMECODE.fullmatch(timecode)):
        return timecode
    raise VideoError(f"a timecode must read HH:MM:SS:FF (HH:MM:SS;FF for drop frame), got "
                     f"{timecode!r}")


def timecode_args(timecode: str | None, suffix: str) -> list[str]:
    """``-timecode`` of a file that holds one (MP4 and QuickTime: a ``tmcd`` track; Matroska:
    a tag); none for AVI or without a timecode."""
    if timecode is None or suffix not in (".mp4", ".m4v", ".mov", ".mkv"):
        return []
    return ["-timecode", timecode]


def timecode_seconds(timecode: str, fps: float) -> float:
    """A video's timecode (``HH:MM:SS:FF``; ``;`` before the frames of a drop-frame one) as
    seconds since midnight at its frame rate ``fps``: its frames counted
    (:func:`facetransfer.io.plate_header.timecode_count`: a drop-frame count's skipped frame
    numbers taken off) over the nominal rate ``round(fps)``, or over the true rate
    ``round(fps) * 1000 / 1001`` of a drop-frame one."""
    from .plate_header import timecode_count

    try:
        frames, drop = timecode_count(timecode, fps)
    except ValueError as exc:
        raise VideoError(str(exc)) from None
    rate = max(1, int(round(float(fps))))
    return frames / (rate * 1000.0 / 1001.0 if drop else rate)


def container(path: str | os.PathLike) -> str | None:
    """The demuxer ffmpeg reads a media file with, as it names it in :func:`described`
    (``"mov,mp4,m4a,3gp,3g2,mj2"``, ``"mpegts"``, ...); None without ffmpeg."""
    found = re.search(r"^Input #0, ([^ ]+), from", described(path), re.MULTILINE)
    return found.group(1) if found else None


def exact_seek(path: str | os.PathLike) -> bool:
    """Whether OpenCV's seek in a video's container is exact (:data:`EXACT_SEEK`, by
    :func:`container`); False without ffmpeg."""
    return container(path) in EXACT_SEEK


def _said(name: str) -> str | None:
    """An ffmpeg colour name, None for one that says nothing."""
    return None if name in ("unknown", "reserved", "unspecified", "") else name


def checked_colour_name(name, what: str) -> str | None:
    """``name`` (None or an ffmpeg colour name such as ``bt709``) checked; VideoError
    otherwise (it becomes an ffmpeg argument)."""
    if name is None or (isinstance(name, str) and re.fullmatch(r"[a-z0-9][a-z0-9_-]*", name)):
        return name
    raise VideoError(f"{what} must be an ffmpeg colour name such as 'bt709', got {name!r}")


#: ffmpeg's names of colour matrices (``AVColorSpace``) as they stand alone in its description.
_MATRICES = ("rgb", "bt709", "fcc", "bt470bg", "smpte170m", "smpte240m", "ycgco", "bt2020nc",
             "bt2020c", "smpte2085", "chroma-derived-nc", "chroma-derived-c", "ictcp", "ipt-c2",
             "ycgco-re", "ycgco-ro")


def described(path: str | os.PathLike) -> str:
    """ffmpeg's description of a media file (its container and streams) and of its first
    video frame decoded (``showinfo``: whether it is interlaced, :func:`field_named`), "" without
    ffmpeg; kept per file (:func:`facetransfer.io.verified.file_stamp`: its colour, audio,
    fields and container are asked of it); "" for an image sequence
    (:mod:`facetransfer.io.video_sequence`: no container, audio, fields or colour names)."""
    if is_sequence(path):
        return ""
    try:
        stamp = file_stamp(path)
    except OSError:         # missing: ffmpeg says so, nothing kept
        return _describe(str(path))
    return _kept_description(str(path), stamp)


def described_input(path: str | os.PathLike) -> str:
    """The part of :func:`described` that describes the file itself (its container and
    streams), not the decode of its first frame that follows (whose own output streams would
    otherwise be read as the file's)."""
    return described(path).split("Stream mapping:")[0]


@functools.lru_cache(maxsize=32)
def _kept_description(path: str, stamp: str) -> str:
    return _describe(path)


def _describe(path: str) -> str:
    exe = ffmpeg_exe()
    if exe is None:
        return ""
    return subprocess.run([exe, "-hide_banner", "-nostdin", "-i", path, "-map", "0:v:0?",
                           "-vf", "showinfo", "-frames:v", "1", "-f", "null", "-"],
                          capture_output=True, text=True).stderr


def video_colour(path: str | os.PathLike) -> ColourTags:
    """What a video's header says of its colour (:func:`colour_named`; nothing without
    ffmpeg)."""
    return colour_named(described(path))


def colour_matrix(path: str | os.PathLike) -> str | None:
    """The colour matrix a video's header names, as ffmpeg names it (``"bt709"``,
    ``"smpte170m"``, ...); None when it names none or without ffmpeg."""
    return video_colour(path).matrix


def display_mirrored(path: str | os.PathLike) -> bool:
    """Whether a QuickTime or MP4 file's display matrix mirrors its first video track (the
    determinant of its track header's matrix is negative: a front camera's clip written
    mirrored by its header, ``ffmpeg -display_hflip``). Players (and ffmpeg) show it
    mirrored back; OpenCV turns it by the matrix's rotation alone, so the readers mirror it
    (:func:`facetransfer.io.video_read.iter_frames`). False for any other file, or one that
    cannot be read."""
    if is_sequence(path):
        return False
    try:
        stamp = file_stamp(path)
    except OSError:
        return False
    return _kept_mirrored(str(path), stamp)


@functools.lru_cache(maxsize=32)
def _kept_mirrored(path: str, stamp: str) -> bool:
    try:
        with open(path, "rb") as f:
            moov = _box(f, b"moov", os.fstat(f.fileno()).st_size)
            return moov is not None and _video_matrix_mirrored(moov)
    except (OSError, struct.error, ValueError):
        return False


def _boxes(data: bytes):
    """``(type, payload)`` of the ISO-BMFF boxes laid one after another in ``data``."""
    at = 0
    while at + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[at:at + 8])
        head = 8
        if size == 1:
            size, head = struct.unpack(">Q", data[at + 8:at + 16])[0], 16
        elif size == 0:
            size = len(data) - at
        if size < head:
            return
        yield kind, data[at + head:at + size]
        at += size


def _box(f, kind: bytes, end: int) -> bytes | None:
    """The payload of the top-level box ``kind`` of an open file (the boxes before it skipped
    by their sizes, not read: a phone writes ``moov`` after gigabytes of ``mdat``)."""
    at = 0
    while at + 8 <= end:
        f.seek(at)
        head = f.read(16)
        if len(head) < 8:
            return None
        size, box = struct.unpack(">I4s", head[:8])
        start = 8
        if size == 1:
            size, start = struct.unpack(">Q", head[8:16])[0], 16
        elif size == 0:
            size = end - at
        if size < start:
            return None
        if box == kind:
            if size > 64 << 20:      # a header this large is no header
                return None
            f.seek(at + start)
            return f.read(size - start)
        at += size
    return None


def _video_matrix_mirrored(moov: bytes) -> bool:
    """Whether the first video track (handler ``vide``) of a ``moov`` payload has a track
    header matrix of negative determinant (``a d - b c < 0``, in 16.16 fixed point)."""
    for kind, trak in _boxes(moov):
        if kind != b"trak":
            continue
        parts = dict(_boxes(trak))
        mdia = dict(_boxes(parts.get(b"mdia", b"")))
        if mdia.get(b"hdlr", b"")[8:12] != b"vide" or b"tkhd" not in parts:
            continue
        tkhd = parts[b"tkhd"]
        at = 4 + (32 if tkhd[:1] == b"\x01" else 20) + 16   # version, times, layer ...
        a, b, _, c, d = struct.unpack(">5i", tkhd[at:at + 20])
        return a * d - b * c < 0
    return False

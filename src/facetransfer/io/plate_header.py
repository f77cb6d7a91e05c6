"""What a plate's frame headers say of its time and its pixels' shape: the frame rate, the SMPTE
timecode and the pixel aspect ratio of a DPX or OpenEXR frame, read where a plate is opened and
written where a sequence is made.

A film scan, a conform or a compositing package stores in each DPX frame the frame rate (the
film header's "frame rate of original", else the television header's temporal sampling rate:
SMPTE 268M) and the frame's SMPTE 12M timecode; in each OpenEXR frame the ``framesPerSecond``
and ``timeCode`` attributes. A sequence of such frames is read at its header's rate, not at
the default for sequences that store none (:mod:`facetransfer.io.video_sequence`), and starts
at its first frame's timecode, which results and exports carry as they carry a video's
(:func:`facetransfer.io.video_display.timecode_of`). A DPX or OpenEXR sequence written from
another target gets the rate and each frame's timecode (:func:`written_header`).

A plate shot with an anamorphic lens is stored squeezed: its header's pixel aspect ratio (DPX's
orientation header, as OpenImageIO's ``PixelAspectRatio``; OpenEXR's ``pixelAspectRatio``) says
how much wider than tall a pixel is shown (2 for a 2x squeeze). The plate is then read as a
video of that sample aspect ratio: the capture sees the face unsqueezed
(:mod:`facetransfer.track.aspect`), the rewrite is drawn in the stored pixels, and a video
written from it says the ratio, as DPX and OpenEXR frames written from a target of non-square
pixels do.

A timecode is written as ffmpeg writes one: ``HH:MM:SS:FF``, or ``HH:MM:SS;FF`` when it counts
drop-frame (at 29.97 and 59.94 frames a second two or four frame numbers are skipped at the
start of each minute but every tenth, so that the count keeps to the clock). The header holds
it packed as SMPTE 12M's 32-bit word: binary-coded decimal digits, frames in the low byte, the
drop-frame flag in bit 6.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

__all__ = ["FrameHeader", "frame_header", "timecode_text", "timecode_word", "timecode_count",
           "timecode_after", "exact_timecode", "written_header", "rate_fraction", "usable_rate",
           "usable_aspect"]

_TIMECODE = re.compile(r"(\d{2}):(\d{2}):(\d{2})([:;])(\d{2})")
#: A timecode as counted (:func:`timecode_count`): ``.`` too before a drop-frame count's frames
#: (as ffmpeg may write it), and three digits of frames at rates above 99.
_COUNTED = re.compile(r"(\d{2}):(\d{2}):(\d{2})([:;.])(\d{2,3})")
#: The digit fields of SMPTE 12M's time word: (shift, mask) of hours, minutes, seconds, frames
#: (each byte's tens in its upper bits: 2, 3, 3 and 2 of them).
_FIELDS = ((24, 0x3F), (16, 0x7F), (8, 0x7F), (0, 0x3F))
_DROP_BIT = 1 << 6


@dataclass(frozen=True)
class FrameHeader:
    """A frame's rate, timecode and pixel aspect as its file's header says them.

    Attributes
    ----------
    fps : float or None
        Frames a second (None: the header names none, or not a usable one).
    timecode : str or None
        The frame's ``HH:MM:SS:FF`` (``;`` before the frames of a drop-frame count).
    sar : (int, int) or None
        The pixels' aspect ratio, width to height, in lowest terms (None: not said, or square).
    """

    fps: float | None = None
    timecode: str | None = None
    sar: tuple[int, int] | None = None


#: The NTSC-family rates' nominal integers: a rate within :data:`_NTSC_WITHIN` of
#: ``n * 1000 / 1001`` is that rate (23.976 written as a header's float is 24000/1001).
_NTSC = (24, 30, 48, 60, 120)
_NTSC_WITHIN = 5e-4


def _ntsc(fps: float) -> Fraction | None:
    """``n * 1000 / 1001`` where ``fps`` is that NTSC-family rate to :data:`_NTSC_WITHIN`."""
    for nominal in _NTSC:
        if abs(fps - nominal * 1000 / 1001) < _NTSC_WITHIN:
            return Fraction(nominal * 1000, 1001)
    return None


def usable_rate(value) -> float | None:
    """``value`` as frames a second where it is one a header means (finite, in (0, 1000]; an
    NTSC-family rate written rounded, 23.976 or 29.97, as the exact ``n * 1000 / 1001``);
    else None (an unset DPX field reads as NaN or as all bits set)."""
    try:
        fps = float(value)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(fps) and 0 < fps <= 1000):
        return None
    exact = _ntsc(fps)
    return fps if exact is None else float(exact)


def usable_aspect(value) -> tuple[int, int] | None:
    """A header's pixel aspect ratio (a float) as a ratio of integers in lowest terms, the
    nearest of denominator at most 1000 (10:11, 40:33, 2:1, 4:3); None where it is square,
    unset, or beyond 1:4 to 4:1 (no lens or format squeezes more)."""
    try:
        ratio = float(value)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(ratio) or not 0.25 <= ratio <= 4.0:
        return None
    f = Fraction(ratio).limit_denominator(1000)
    return None if f == 1 else (f.numerator, f.denominator)


def timecode_text(word: int) -> str | None:
    """The ``HH:MM:SS:FF`` (``;FF`` of a drop-frame count) of SMPTE 12M's packed time word
    (binary-coded decimal, as DPX and OpenEXR store it); None where a digit or a field is out
    of range (an unset field: all bits set)."""
    word = int(word) & 0xFFFFFFFF
    values = []
    for shift, mask in _FIELDS:
        byte = (word >> shift) & mask
        tens, units = byte >> 4, byte & 0xF
        if units > 9:
            return None
        values.append(tens * 10 + units)
    hh, mm, ss, ff = values
    if hh > 23 or mm > 59 or ss > 59 or ff > 59:
        return None
    return f"{hh:02d}:{mm:02d}:{ss:02d}{';' if word & _DROP_BIT else ':'}{ff:02d}"


def _fields(timecode: str, pattern: re.Pattern = _COUNTED) -> tuple[int, int, int, str, int]:
    """``(hh, mm, ss, separator, ff)`` of ``timecode`` as ``pattern`` reads it; ValueError
    naming it where it is not such a timecode."""
    m = pattern.fullmatch(str(timecode).strip())
    if m is None:
        raise ValueError(f"timecode {timecode!r} is not HH:MM:SS:FF")
    hh, mm, ss, sep, ff = m.groups()
    return int(hh), int(mm), int(ss), sep, int(ff)


def timecode_word(timecode: str) -> int:
    """SMPTE 12M's packed time word of ``HH:MM:SS:FF`` (``;`` sets the drop-frame flag);
    the inverse of :func:`timecode_text`.

    Raises
    ------
    ValueError
        Not such a timecode (naming it).
    """
    hh, mm, ss, sep, ff = _fields(timecode, _TIMECODE)
    word = 0
    for (shift, _), value in zip(_FIELDS, (hh, mm, ss, ff)):
        word |= (((value // 10) << 4) | (value % 10)) << shift
    return word | (_DROP_BIT if sep == ";" else 0)


def _nominal(fps: float) -> int:
    return max(1, int(round(float(fps))))


def _skip(rate: int) -> int:
    """Frame numbers a drop-frame count skips a minute at the nominal ``rate`` (29.97: 2,
    59.94: 4, 119.88: 8; none at any other)."""
    return {30: 2, 60: 4, 120: 8}.get(rate, 0)


def _drops(fps: float) -> bool:
    """Whether ``fps`` has a drop-frame count: an NTSC rate (N * 1000/1001: 29.97, 59.94,
    119.88), not the integer rate of the same nominal (30 fps counts every frame number)."""
    ntsc = float(fps) * 1001.0 / 1000.0
    return _skip(_nominal(fps)) > 0 and abs(ntsc - round(ntsc)) < 1e-3


def timecode_count(timecode: str, fps: float) -> tuple[int, bool]:
    """Frames since midnight that ``timecode`` (``HH:MM:SS:FF``; ``;`` or ``.`` before the
    frames of a drop-frame one) counts at ``fps``, and whether it counts drop-frame: ``FF``
    counts frames of the nominal rate ``round(fps)``; a drop-frame count (29.97, 59.94,
    119.88) skips 2 (4, 8) frame numbers each minute but every tenth, so those are taken off.

    Raises
    ------
    ValueError
        Not such a timecode (naming it).
    """
    hh, mm, ss, sep, ff = _fields(timecode)
    rate = _nominal(fps)
    minutes = hh * 60 + mm
    count = (minutes * 60 + ss) * rate + ff
    drop = sep != ":" and _drops(fps)
    if drop:
        count -= _skip(rate) * (minutes - minutes // 10)
    return count, drop


def exact_timecode(timecode: str, fps: float) -> str:
    """``timecode`` (stripped) where it names a frame at ``fps``; ValueError otherwise: hours
    past 23, frames at or past the nominal rate (``01:00:00:30`` at 25 fps), a drop-frame
    separator where the rate has no drop-frame count (only 29.97, 59.94, 119.88 do), or a
    frame number a drop-frame count skips (``00:01:00;00``). Said of a timecode a person
    types (``export --timecode``); one read from a file is taken as it is."""
    t = str(timecode).strip()
    count, drop = timecode_count(t, fps)
    typed, named = _fields(t), _fields(_timecode(count, fps, drop))
    if typed[:3] + typed[4:] == named[:3] + named[4:] and (typed[3] != ":") == drop:
        return t
    rate = _nominal(fps)
    raise ValueError(f"timecode {t!r} names no frame at {fps:g} fps (hours 00-23, frames "
                     f"00-{rate - 1:02d}"
                     + (", ';' with the frame numbers a drop-frame count skips taken out)"
                        if _drops(fps) else "; no drop-frame count ';' at this rate)"))


def _timecode(count: int, fps: float, drop: bool) -> str:
    """The timecode of frame ``count`` since midnight (the inverse of :func:`timecode_count`),
    wrapping at 24 hours."""
    rate = _nominal(fps)
    if drop:
        skip = _skip(rate)
        per_ten = 600 * rate - 9 * skip               # frames of ten minutes
        per_minute = 60 * rate - skip                 # of a minute that drops
        tens, rest = divmod(count, per_ten)
        extra = 0 if rest < skip else skip * ((rest - skip) // per_minute)
        count += skip * 9 * tens + extra
    day = 24 * 3600 * rate
    secs, ff = divmod(count % day, rate)
    mins, ss = divmod(secs, 60)
    hh, mm = divmod(mins, 60)
    return f"{hh:02d}:{mm:02d}:{ss:02d}{';' if drop else ':'}{ff:02d}"


def timecode_after(timecode: str, frames: int, fps: float) -> str:
    """The timecode ``frames`` frames after ``timecode`` at ``fps``, counted as it counts
    (drop-frame at 29.97 and 59.94 where it says so), wrapping at midnight."""
    count, drop = timecode_count(timecode, fps)
    return _timecode(count + int(frames), fps, drop)


def written_header(fps: float | None, start: str | None, index: int,
                   sar: tuple[int, int] | None = None) -> FrameHeader:
    """Frame ``index``'s :class:`FrameHeader` of a sequence written at ``fps`` that starts at the
    timecode ``start`` (None: no timecode), of pixels of aspect ``sar`` (None: square)."""
    sar = None if sar is None or tuple(sar) == (1, 1) else (int(sar[0]), int(sar[1]))
    if start is None or fps is None:
        return FrameHeader(usable_rate(fps), None, sar)
    return FrameHeader(usable_rate(fps), timecode_after(start, index, fps), sar)


def rate_fraction(fps: float) -> Fraction:
    """``fps`` as OpenEXR's rational ``framesPerSecond``: the NTSC rates as n * 1000 / 1001
    (23.976 -> 24000/1001), any other as the nearest fraction of denominator at most 1001."""
    return _ntsc(fps) or Fraction(float(fps)).limit_denominator(1001)


def frame_header(path) -> FrameHeader:
    """The :class:`FrameHeader` a frame file's header says (a DPX or OpenEXR frame's; of any
    other kind of file, or one whose header cannot be read, nothing)."""
    suffix = Path(path).suffix.lower()
    try:
        if suffix == ".dpx":
            return _dpx_header(path)
        if suffix == ".exr":
            return _exr_header(path)
    except (OSError, ValueError, TypeError, AttributeError):
        return FrameHeader()
    return FrameHeader()


def _dpx_header(path) -> FrameHeader:
    """A DPX header's rate (the film header's, else the television header's: ffmpeg's order)
    and timecode, as OpenImageIO reads them."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        return FrameHeader()
    try:
        spec = inp.spec()
        fps = usable_rate(spec.getattribute("dpx:FrameRate")) or \
            usable_rate(spec.getattribute("dpx:TemporalFrameRate"))
        word = spec.getattribute("smpte:TimeCode")
        sar = usable_aspect(spec.getattribute("PixelAspectRatio"))
    finally:
        inp.close()
    return FrameHeader(fps, None if word is None else timecode_text(int(word[0])), sar)


def _exr_header(path) -> FrameHeader:
    """An OpenEXR header's ``framesPerSecond`` and ``timeCode`` (its first part)."""
    import OpenEXR

    with OpenEXR.File(str(path), header_only=True) as f:   # read before it closes
        header = f.header()
        rate, tc = header.get("framesPerSecond"), header.get("timeCode")
        sar = usable_aspect(header.get("pixelAspectRatio"))
        fields = None if tc is None else (tc.hours, tc.minutes, tc.seconds, tc.frame,
                                          bool(tc.dropFrame))
    fps = usable_rate(float(rate)) if rate is not None else None
    if fields is None or not all(0 <= v < 100 for v in fields[:4]):
        return FrameHeader(fps, None, sar)
    text = "{:02d}:{:02d}:{:02d}{}{:02d}".format(*fields[:3], ";" if fields[4] else ":",
                                                fields[3])
    return FrameHeader(fps, timecode_text(timecode_word(text)), sar)

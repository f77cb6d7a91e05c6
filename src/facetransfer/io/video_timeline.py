"""A video's frames on a constant-rate timeline, where its stored frames are unevenly spaced.

Phones and screen recorders write videos of variable frame rate: a frame's presentation time
is in the container, and the frames may stop for a while (a freeze, dropped frames in the dark)
and resume. Decoded one after another at the average rate, such a video's frames drift from its
audio: after a 1-second gap in the middle of an 11-second clip, frames shown up to 0.5 s away
from their sound. The commands write constant-rate videos with the input's audio, so where the
stored frames are uneven they read the video on a constant-rate timeline instead: step ``k``
(at ``k / fps`` seconds from the first frame) shows the last stored frame whose time rounds to
a step at or before it. Frames repeat across a gap and, where they come faster than the rate,
some are passed over. :func:`timeline` works it out from the packets' times in the container
(ffmpeg's ``framecrc`` muxer: no decoding); :func:`facetransfer.io.video_read.video_info` and
the readers use it. From the same times, :func:`on_rate_grid` says whether each stored frame
sits on its step of the rate, where OpenCV's seek (which numbers a frame by its time) lands on
the frame asked: a video can be even enough to read as stored and still drift off those steps.
"""

from __future__ import annotations

import functools
import logging
import os
import re
import subprocess
from fractions import Fraction

import numpy as np

from .ffmpeg import ffmpeg_exe
from .verified import file_stamp
from .video_sequence import is_sequence

log = logging.getLogger(__name__)

__all__ = ["UNEVEN", "SEEK_SLACK", "first_frame_time", "hidden_count", "on_rate_grid",
           "packet_times", "shown_count", "timeline"]

#: A video's frames are uneven when an interval between two of them is outside this range of
#: their median interval (a millisecond time base's 33/34 ms steps are even).
UNEVEN = (0.5, 1.5)

#: How far (in frames) a stored frame's time may sit from its step of the constant rate for
#: OpenCV's seek to land on it (:func:`on_rate_grid`; it numbers a frame by its time, rounded).
SEEK_SLACK = 0.4


def packet_times(path: str | os.PathLike) -> np.ndarray | None:
    """The presentation times (seconds, ascending) of the first video stream's packets, as the
    container stores them (ffmpeg's ``framecrc`` of a stream copy: nothing decoded); None
    without ffmpeg, or where a packet has no time."""
    text = _listing(path)
    return None if text is None else _framecrc_times(text)


def _listing(path: str | os.PathLike) -> str | None:
    """ffmpeg's ``framecrc`` listing of the first video stream's packets (a stream copy), None
    without ffmpeg or where it fails; of a file cut short (its index names packets past its
    end: ffmpeg's "partial file"), with a last line ``#partial`` (:data:`CUT_SHORT`)."""
    exe = ffmpeg_exe()
    if exe is None:
        return None
    res = subprocess.run([exe, "-hide_banner", "-nostdin", "-loglevel", "error", "-i",
                          str(path), "-map", "0:v:0", "-c", "copy", "-f", "framecrc", "-"],
                         capture_output=True, text=True)
    if res.returncode != 0:
        return None
    return res.stdout + (f"{CUT_SHORT}\n" if "partial file" in res.stderr else "")


#: The line :func:`_listing` adds to the listing of a file cut short.
CUT_SHORT = "#partial"


def _framecrc_times(text: str, column: int = 2) -> np.ndarray | None:
    """The sorted times in seconds of a ``framecrc`` listing of one stream (lines
    ``stream, dts, pts, duration, size, checksum[, F=0xFLAGS]``, time base ``#tb 0:
    num/den``): its presentation times (``column`` 2), or its decoding times (1), of the
    packets shown (:func:`_hidden`)."""
    tb = re.search(r"^#tb 0: (\d+)/(\d+)", text, re.M)
    if not tb or int(tb[2]) == 0:
        return None
    pts = []
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 4 or parts[0] != "0" or _hidden(parts):
            continue
        try:
            pts.append(int(parts[column]))
        except ValueError:
            return None
    if not pts or min(pts) <= -(1 << 62):      # AV_NOPTS_VALUE: a packet without a time
        return None
    try:                                        # numbers beyond a float's range: no times
        with np.errstate(over="ignore"):
            times = np.sort(np.asarray(pts, np.float64)) * float(Fraction(int(tb[1]),
                                                                          int(tb[2])))
    except OverflowError:
        return None
    return times if np.isfinite(times).all() else None


#: ffmpeg's flag of a packet its demuxer reads but no decoder shows (``AV_PKT_FLAG_DISCARD``).
DISCARD = 0x4


def _hidden(parts: list[str]) -> bool:
    """Whether a ``framecrc`` line (its fields) is of a packet outside the file's edit list:
    a clip trimmed without re-encoding (a phone's Photos app, an editor's stream copy) keeps
    the frames before its cut from the keyframe they need, flagged :data:`DISCARD`, and
    decoders drop them. Counted, they made a clip trimmed by 1 s read as 30 frames longer,
    uneven and cut short."""
    flags = parts[-1]
    if not flags.startswith("F=0x"):
        return False
    try:
        return bool(int(flags[4:], 16) & DISCARD)
    except ValueError:
        return False


def _packet_fields(text: str) -> list[list[str]]:
    """The fields of each packet line of the first stream of a ``framecrc`` listing."""
    return [[p.strip() for p in line.split(",")] for line in text.splitlines()
            if line.startswith("0,")]


def _count_hidden(text: str) -> int:
    """How many packets of a ``framecrc`` listing of one stream are :func:`_hidden`."""
    return sum(1 for parts in _packet_fields(text) if _hidden(parts))


def _spliced(text: str) -> bool:
    """Whether the shown packets of a ``framecrc`` listing whose edit list hides some do not
    decode in a strictly rising order: an edit list of two edits or more (a clip's pieces
    joined by reference, as an editor's stream copy keeps them), whose second piece ffmpeg's
    stream copy lists at times it made up (one decoding time repeated over dozens of packets,
    presentation times before the first piece's end). Their times are no timeline: read as
    one, a clip of two 1-second pieces took a 0.57 s gap at the join and held a frame there."""
    try:
        dts = [int(p[1]) for p in _packet_fields(text) if len(p) >= 4 and not _hidden(p)]
    except ValueError:
        return True
    return any(b <= a for a, b in zip(dts, dts[1:]))


@functools.lru_cache(maxsize=32)
def _cached_packets(path: str, stamp: str) -> tuple:
    """``(presentation times, decoding times)`` of the packets shown (:func:`_framecrc_times`;
    None where they are made up, :func:`_spliced`), how many are hidden by the edit list
    (:func:`_hidden`), and how many are shown (None where the file is cut short: its index's
    count is the one :mod:`facetransfer.io.video_facts` compares with the packets there).
    """
    text = _listing(path)
    if text is None:
        return None, None, 0, None
    hidden = _count_hidden(text)
    shown = sum(1 for p in _packet_fields(text) if len(p) >= 4 and not _hidden(p))
    if CUT_SHORT in text.splitlines():      # the frames it shows are not all there to count
        shown = None
    if hidden and _spliced(text):
        return None, None, hidden, shown
    return _framecrc_times(text), _framecrc_times(text, 1), hidden, shown


def _cached_times(path: str, stamp: str) -> np.ndarray | None:
    return _cached_packets(path, stamp)[0]


@functools.lru_cache(maxsize=32)
def _cached_timeline(path: str, stamp: str, n_frames: int):
    return _timeline(_cached_times(path, stamp), n_frames, path)


def hidden_count(path: str | os.PathLike) -> int:
    """How many packets of the first video stream its edit list hides (:func:`_hidden`: a
    trimmed clip's frames before the cut), which :func:`packet_count` and the times leave
    out and OpenCV's frame count includes; 0 where they cannot be read."""
    try:
        stamp = file_stamp(path)
    except OSError:
        return 0
    return int(_cached_packets(str(path), stamp)[2])


def shown_count(path: str | os.PathLike) -> int | None:
    """How many packets of the first video stream are shown: not hidden by its edit list
    (:func:`hidden_count`), counted even where their times are made up (:func:`_spliced`);
    None where they cannot be listed, or the file is cut short (ffmpeg's "partial file")."""
    try:
        stamp = file_stamp(path)
    except OSError:
        return None
    return _cached_packets(str(path), stamp)[3]


def packet_count(path: str | os.PathLike) -> int | None:
    """How many packets of the first video stream are shown (:func:`packet_times`, less
    those its edit list hides: :func:`hidden_count`; kept per file with the timeline's); None
    where they cannot be read."""
    try:
        stamp = file_stamp(path)
    except OSError:
        return None
    times = _cached_times(str(path), stamp)
    return None if times is None else int(len(times))


def first_frame_time(path: str | os.PathLike) -> float:
    """Seconds from a media file's start to its first video frame: where its picture starts on
    the timeline its audio is read on (ffmpeg counts both from the file's start, the earliest
    of its streams). 0.0 for most files; a phone's clip whose sound starts before its picture
    (an edit list, audio recorded first) gives the time the sound leads by. 0.0 where the
    packets cannot be read or the file has no video (kept per file, with the timeline's)."""
    if is_sequence(path):
        return 0.0
    try:
        stamp = file_stamp(path)
    except OSError:
        return 0.0
    times = _cached_times(str(path), stamp)
    if times is None or not len(times) or not np.isfinite(times[0]):
        return 0.0
    return max(0.0, float(times[0]))


def timeline(path: str | os.PathLike, n_frames: int) -> tuple[float, tuple[int, ...]] | None:
    """``(fps, steps)`` of a video whose ``n_frames`` stored frames are uneven in time
    (:data:`UNEVEN`): the constant rate (the reciprocal of their median interval) and, for each
    of its steps, the index of the stored frame shown then; None for an even video (or when the
    packets cannot be read, or their number is not ``n_frames``: read as it is stored). Kept per
    file (:func:`facetransfer.io.verified.file_stamp`); said once in a warning. An image
    sequence is even (:mod:`facetransfer.io.video_sequence`)."""
    if is_sequence(path):
        return None
    try:
        stamp = file_stamp(path)
    except OSError:
        return None
    return _cached_timeline(str(path), stamp, int(n_frames))


def _timeline(times: np.ndarray | None, n_frames: int, path: str):
    """:func:`timeline` of the packet ``times`` (seconds, sorted)."""
    if times is None or len(times) < 3 or len(times) != n_frames:
        return None
    gaps = np.diff(times)
    median = float(np.median(gaps))
    lo, hi = UNEVEN
    usual = (gaps >= lo * median) & (gaps <= hi * median)
    if median <= 0 or usual.all():
        return None
    step = float(gaps[usual].mean())    # a millisecond time base's 33, 34, 33 ms: 29.97 fps
    at = np.rint((times - times[0]) / step).astype(np.int64)   # each frame's step
    steps = np.searchsorted(at, np.arange(int(at[-1]) + 1), side="right") - 1
    worst = int(np.argmax(gaps))
    log.warning("%s has a variable frame rate (frames %d and %d are %.2f s apart, %.3f s "
                "usual): read at a constant %.3f fps, %d frames for its %d, so that it stays "
                "in step with its audio", path, worst, worst + 1, gaps[worst], step, 1 / step,
                len(steps), len(times))
    return round(1.0 / step, 6), tuple(int(i) for i in steps)


def on_rate_grid(path: str | os.PathLike, fps: float) -> bool:
    """Whether each stored frame ``k`` of the video ``path`` is shown within
    :data:`SEEK_SLACK` of ``k / fps`` seconds after its first: where OpenCV's seek, which
    numbers the frame it lands on by its time at ``fps`` (its rate), lands on the frame asked.

    A video whose rate drifts with every interval within :data:`UNEVEN` (a phone's 30 fps clip
    slowed to 25 for two seconds in the dark) is read as stored, but its frames' times leave the
    grid: there the seek landed frames away (2 after those two seconds). An AVI of B-frames
    stores no presentation times: its decoding times are asked (one a frame, in turn). False
    where neither can be read (kept per file, with the timeline's)."""
    try:
        stamp = file_stamp(path)
    except OSError:
        return False
    return _cached_on_grid(str(path), stamp, float(fps))


@functools.lru_cache(maxsize=32)
def _cached_on_grid(path: str, stamp: str, fps: float) -> bool:
    shown, decoded = _cached_packets(path, stamp)[:2]
    times = decoded if shown is None else shown
    if times is None or not fps > 0:
        return False
    off = (times - times[0]) * fps - np.arange(len(times))      # (F,) frames off the grid
    return bool(np.all(np.abs(off) < SEEK_SLACK))

"""The numbers a user knows a clip's frames by, in every message that names frames and in
the options that take a frame number (``transfer --frame``, ``edit --add NAME@START-END``).

An image sequence's frames (a plate's) are numbered as its files are: ``sh010.1001.exr`` is
frame 1001, the first of a plate numbered from 1001; a video's are counted from 0, and so are
a photo's and a Live Link Face take's rows. A track is numbered as the clip it was made from
(:attr:`facetransfer.track.result.Track.source_facts`, recorded when it was tracked).
Internally frames stay rows counted from 0: a clip's ``first`` number is added where a frame
is named (:func:`frame_runs`, :func:`frame_span`) and taken away where one is read
(:func:`frame_index`).
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import FaceTransferError

__all__ = ["first_number", "track_first_number", "frame_runs", "frames_said", "frame_span",
           "frame_index"]


def first_number(clip: str | os.PathLike | None) -> int:
    """The number of the first frame of ``clip``: an image sequence's lowest file number
    present (``plate/sh010.####.exr`` of files 1001-1100: 1001; 0 where it has none or its
    folder is gone); 0 for anything else (a video, a photo, a take, None)."""
    from .video_sequence import is_sequence, sequence_files

    if clip is None or not is_sequence(clip):
        return 0
    try:
        files = sequence_files(clip)
    except (OSError, ValueError):     # its folder gone: nothing to number by
        return 0
    return int(min(files)) if files else 0


def track_first_number(track) -> int:
    """The number of the first frame of the clip ``track`` was made from, as the track records
    it (its ``source_facts``: a plate's 1001 after the plate moved), else (a track made before
    tracks recorded it) its ``source``'s where that is still its clip, of the track's frame
    size (:func:`facetransfer.io.source_facts.track_source_facts`, the rule the exports number
    frames by: another plate now at the path, or none, numbers from 0); 0 for a track of a
    video, a take's or a synthetic one."""
    from .source_facts import track_source_facts
    from .video_sequence import is_sequence

    facts = getattr(track, "source_facts", None)
    if facts is not None:
        return int(facts.first_frame)
    source = getattr(track, "source", None)
    if not source or not is_sequence(source):     # a video's, a take's: 0, nothing to read
        return 0
    return int(track_source_facts(track)[0].first_frame)


def frame_runs(mask, first: int = 0, limit: int = 4) -> str:
    """``"1003-1007, 1012"``: the frames where ``mask`` (F,) is True as runs (the first
    ``limit``, then how many there are), numbered from ``first``; "" where none is."""
    idx = np.flatnonzero(np.asarray(mask, bool)) + int(first)
    if not idx.size:
        return ""
    cut = np.diff(idx) > 1
    starts = np.r_[idx[0], idx[1:][cut]]
    ends = np.r_[idx[:-1][cut], idx[-1]]
    runs = [f"{a}" if a == b else f"{a}-{b}" for a, b in zip(starts, ends)]
    return ", ".join(runs[:limit]) + (f", ... ({len(runs)} runs)" if len(runs) > limit else "")


def frames_said(mask, first: int = 0, limit: int = 4) -> str:
    """``"frame 1005"`` where ``mask`` (F,) marks one frame, ``"frames 1003-1007, 1012"``
    where it marks more (:func:`frame_runs`, numbered from ``first``); "" where none. A
    message naming one lost frame said "frames 23"."""
    runs = frame_runs(mask, first, limit)
    if not runs:
        return ""
    return f"{'frame' if int(np.count_nonzero(mask)) == 1 else 'frames'} {runs}"


def frame_span(first: int, n: int) -> str:
    """``"1001-1020"``: the numbers of ``n`` frames from ``first`` (``"1001"`` for one)."""
    first, n = int(first), int(n)
    return f"{first}" if n <= 1 else f"{first}-{first + n - 1}"


def frame_index(number: int, first: int, n: int, what: str) -> int:
    """The row (0-based) of the frame a user numbered ``number`` in a clip of ``n`` frames
    numbered from ``first`` (:func:`first_number`).

    Raises
    ------
    FaceTransferError
        ``number`` is none of the clip's frames: one line naming ``what`` (``"--frame 5"``) and
        the clip's numbers (``"the plate's frames are 1001-1020"``).
    """
    i = int(number) - int(first)
    if not 0 <= i < int(n):
        whose = "the plate's frames are" if first else "its frames are"
        raise FaceTransferError(f"{what}: no such frame; {whose} {frame_span(first, n)}"
                                + (" (an image sequence's frames are numbered as its files)"
                                   if first else ""))
    return i

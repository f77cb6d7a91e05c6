"""What the exports of a track read of the clip it was tracked from: the clip's first frame
number and its start timecode (:class:`SourceFacts`).

A track records them when it is made (``TRACK.npz`` keys ``source_first_frame`` and
``source_timecode``, :mod:`facetransfer.track.result`), so that a take's timecodes and a USD's
time codes stay the plate's after the clip moved, was deleted, or another clip took its
place. The track's frame rate and frame size are recorded already (``fps``, ``frame_size``):
nothing else an export needs comes from the clip.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

__all__ = ["SourceFacts", "read_source_facts"]


@dataclass(frozen=True)
class SourceFacts:
    """A tracked clip's numbering.

    Attributes
    ----------
    first_frame : int
        The number of the clip's first frame: an image sequence's first file's (1001 for a
        plate numbered from 1001), 0 for a video file.
    timecode : str or None
        The clip's start timecode (``HH:MM:SS:FF``, ``;`` before the frames of a drop-frame
        one): a video's ``tmcd`` track or tag, a DPX or OpenEXR plate's first header's; None
        where it has none.
    """

    first_frame: int = 0
    timecode: str | None = None

    def __post_init__(self) -> None:
        from .video_display import checked_timecode

        first = int(self.first_frame)
        if first < 0:
            raise ValueError(f"a clip's first frame number must be >= 0, got {first}")
        object.__setattr__(self, "first_frame", first)
        object.__setattr__(self, "timecode", checked_timecode(self.timecode or None))


def read_source_facts(path: str | os.PathLike) -> SourceFacts:
    """The first frame number and start timecode of the clip at ``path`` (a video file or an
    image sequence's pattern, ``plate.####.exr``); a clip that holds no timecode (or one
    ffmpeg cannot read) has None, a video file or a sequence of no frames first frame 0.

    Raises
    ------
    OSError, VideoError
        Where ``path`` names an image sequence whose folder cannot be listed.
    """
    from .video_display import timecode_of
    from .video_sequence import is_sequence, sequence_files

    first = 0
    if is_sequence(path):
        files = sequence_files(path)
        first = int(min(files)) if files else 0
    try:
        timecode = timecode_of(path)
    except ValueError:            # not a media file ffmpeg reads
        timecode = None
    return SourceFacts(first, timecode)

"""What the exports of a track read of the clip it was tracked from: the clip's first frame
number and its start timecode (:class:`SourceFacts`).

A track records them when it is made (``TRACK.npz`` keys ``source_first_frame`` and
``source_timecode``, :mod:`facetransfer.track.result`), so that a take's timecodes and a USD's
time codes stay the plate's after the clip moved, was deleted, or another clip took its
place. The track's frame rate and frame size are recorded already (``fps``, ``frame_size``):
nothing else an export needs comes from the clip. A track made before tracks recorded them has
them read from its clip where that is still its clip (:func:`track_source_facts`): the one
rule the exports (a take's timecodes, a USD's time codes) and every message that names a
track's frames (:func:`facetransfer.io.frame_numbers.track_first_number`) follow.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

__all__ = ["SourceFacts", "read_source_facts", "track_source_facts"]


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


def track_source_facts(track) -> tuple[SourceFacts, str]:
    """The first frame number and start timecode of the clip ``track`` was made from, and a
    note of where they come from.

    As the track records them (``source_facts``, read when it was tracked: note ""). A track
    made before tracks recorded them: read from the clip at its ``source`` where that is still
    a clip of the track's frame size (note: "read from PATH ..."); else none (first frame 0,
    no timecode; the note says why: the clip is not there, or another clip is: a plate of
    another size now at the path is not the track's, and does not number its frames).

    Returns
    -------
    (SourceFacts, str)
    """
    recorded = getattr(track, "source_facts", None)
    if recorded is not None:
        return recorded, ""
    src = str(getattr(track, "source", "") or "")
    if not src:
        return SourceFacts(), ""
    older = "the track records no first frame number or start timecode (made before tracks " \
            "recorded them)"
    if not _there(src):
        return SourceFacts(), f"{older} and its clip {src} is not there: numbered from 0, " \
            "no timecode"
    other = _other_clip(track, src)
    if other:
        return SourceFacts(), f"{older} and {other}: not read (numbered from 0, no timecode)"
    try:
        facts = read_source_facts(src)
    except (OSError, ValueError) as exc:
        return SourceFacts(), f"{older} and its clip {src} cannot be read ({exc})"
    return facts, f"{older}: read from its clip {src}"


def _there(src: str) -> bool:
    """Whether a clip is at ``src``: a file, or an image sequence with a frame."""
    from pathlib import Path

    from .video_sequence import is_sequence, sequence_files

    if not is_sequence(src):
        return Path(src).is_file()
    try:
        return bool(sequence_files(src))
    except (OSError, ValueError):     # its folder gone
        return False


def _other_clip(track, src: str) -> str:
    """Why the clip now at ``src`` is not the one an older ``track`` was made from ("" where
    it may be: of the track's frame size, unreadable clips left to the reader)."""
    import logging

    size = getattr(track, "frame_size", None)
    if size is None:
        return ""
    from .video import video_info

    quiet = logging.getLogger("facetransfer.io.video_sequence")   # its rate: not asked here
    mute = logging.Filter("-")                                     # (passes no record)
    quiet.addFilter(mute)
    try:
        found = tuple(video_info(src).size)
    except (OSError, ValueError):
        return ""
    finally:
        quiet.removeFilter(mute)
    if found == tuple(size):
        return ""
    return (f"the clip now at {src} is {found[0]}x{found[1]}, not the track's "
            f"{size[0]}x{size[1]} (another clip)")

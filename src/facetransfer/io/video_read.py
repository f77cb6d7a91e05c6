"""Video input: decoding a file into ``(H, W, 3) uint8`` RGB frames with OpenCV, lazily
(:func:`iter_frames`) or all at once (:func:`read_video`, into memory or, past the frame budget
of :mod:`facetransfer.io.memory`, into an unnamed file); a video of variable frame rate on a
constant-rate timeline (:mod:`facetransfer.io.video_timeline`); interlaced pictures OpenCV
returns black through the ffmpeg binary (:mod:`facetransfer.io.video_pipe`); an image sequence
(``plate/%04d.png``) frame by frame (:mod:`facetransfer.io.video_sequence`). Its names are
also those of :mod:`facetransfer.io.video`, the module of video input and output.
:func:`~facetransfer.io.video_display.pixel_aspect` is :mod:`facetransfer.io.video_display`'s,
importable from here too."""

from __future__ import annotations

import functools
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import VideoError
from .verified import file_stamp
from .video_display import (display_mirrored, exact_seek, first_field,  # noqa: F401
                            pixel_aspect)  # (pixel_aspect: API)
from .video_pipe import piped_frames
from .video_sequence import (IMAGE_SUFFIXES, is_sequence, is_still, open_sequence,
                             pattern_of_file, sequence_files, sequence_frames, sequence_stamp,
                             suggested_pattern)
from .video_timeline import on_rate_grid, timeline

log = logging.getLogger(__name__)

__all__ = ["VideoInfo", "video_info", "pixel_aspect", "iter_frames", "read_video"]


@dataclass(frozen=True)
class VideoInfo:
    """Basic facts about a video file.

    Attributes
    ----------
    path : Path
        The file, or an image sequence's pattern (``plate/%04d.png``).
    fps : float
        An image sequence's: :func:`facetransfer.io.video_sequence.sequence_fps`.
    n_frames : int
        As reported by the container (may be approximate for some codecs); for a video of
        variable frame rate, the steps of its constant-rate timeline; a still image's 1 (it
        is read as a clip of one frame).
    size : (int, int)
        ``(width, height)`` in pixels.
    sar : (int, int)
        The pixel (sample) aspect ratio ``(width, height)`` of a pixel, in lowest terms: (1, 1)
        for square pixels or none given; e.g. (15, 16) for a 512x480 video shown 480x480.
    steps : tuple of int, optional
        For a video of variable frame rate, the stored frame shown at each of its ``n_frames``
        steps of ``1 / fps`` seconds (:func:`facetransfer.io.video_timeline.timeline`): what
        the readers yield. None: every stored frame in turn.
    piped : bool
        Decoded by the ffmpeg binary (:mod:`facetransfer.io.video_pipe`): interlaced video,
        whose pictures OpenCV returns black (or as garbage).
    turn : {0, 90, 180, 270}
        Degrees clockwise the video's display matrix turns its stored pictures (a phone held
        upright or upside down): the frames are read turned, as a player shows them (OpenCV
        and ffmpeg both turn them), so ``size`` and ``sar`` are the turned frames' (a quarter
        turn swaps the stored width and height, and the pixel aspect ratio's terms).
    mirrored : bool
        The display matrix also mirrors the pictures
        (:func:`facetransfer.io.video_display.display_mirrored`): OpenCV turns them only, so
        its frames are mirrored back (rows for a turn of 0 or 180, columns for a quarter
        turn), as ffmpeg and players show them.
    """

    path: Path
    fps: float
    n_frames: int
    size: tuple[int, int]
    sar: tuple[int, int] = (1, 1)
    steps: tuple[int, ...] | None = field(default=None, repr=False)
    piped: bool = False
    turn: int = 0
    mirrored: bool = False


def _warn_frame_of_sequence(p: Path) -> None:
    """Say that the image file ``p``, read as a still (a video of one frame), is a frame of an
    image sequence beside it (``plate/sh010.1001.dpx`` of ``plate/sh010.%04d.dpx``), naming
    the pattern that reads the sequence (as itself: a DPX or OpenEXR plate's frames by their
    transfer, :mod:`facetransfer.io.video_sequence`); once a file."""
    pattern = pattern_of_file(p) if p.suffix.lower() in IMAGE_SUFFIXES else None
    if pattern is not None:
        _warn_once(str(p), str(pattern), len(sequence_files(pattern)))


@functools.lru_cache(maxsize=16)
def _warn_once(path: str, pattern: str, n: int) -> None:
    log.warning("%s is one frame of the image sequence %s (%d files) and is read as a still of "
                "one frame; give %s to read the sequence", path, pattern, n, pattern)


def _open(path: str | os.PathLike):
    import cv2

    p = Path(path)
    if p.is_dir():
        pattern = suggested_pattern(p)
        hint = "" if pattern is None else f" (its image sequence: give {pattern})"
        raise VideoError(f"video {p} is a folder, not a video file{hint}")
    if not p.is_file():
        raise VideoError(f"video {p} does not exist")
    if p.stat().st_size == 0:
        raise VideoError(f"video {p} is empty")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        if p.suffix.lower() == ".npz":   # a track or a model where a video belongs
            raise VideoError(f"{p} is an .npz archive, not a video; "
                             f"`facetransfer probe {p}` says what it holds")
        raise VideoError(f"cannot read video {p}: {why_not_video(p)}")
    return cap


#: The :func:`facetransfer.io.npz.content_kind` kinds :func:`why_not_video` names.
_NAMED_KINDS = ("a glTF", "a USD", "a Live Link", "an HTML", "a JSON")


def why_not_video(p: Path) -> str:
    """Why OpenCV cannot open the file ``p`` as a video, as far as its bytes and ffmpeg say:
    an MP4/MOV cut short (no ``moov`` index: a recording or copy that did not finish), a file
    with sound and no pictures, or no stream at all; one of the tool's own files by its first
    bytes (a Live Link Face take, a glb, a USD file, a page, a JSON file:
    :func:`facetransfer.io.npz.content_kind`), named as ``probe`` names it: an export or a take
    passed on where a video belongs (``track take.csv``, ``transfer --identity-from
    face.glb``); another text file; else that it is not a video OpenCV can decode."""
    from .npz import content_kind
    from .video_display import described_input

    try:
        with open(p, "rb") as fh:
            head = fh.read(512)
    except OSError:
        head = b""
    said = described_input(p)     # ffmpeg's words of the file ("" without ffmpeg)
    if head[4:8] == b"ftyp" and "moov atom not found" in said:
        return ("it is cut short: an MP4/MOV without its index (the moov box), as a recording "
                "or a copy that did not finish leaves")
    if " Audio: " in said and " Video: " not in said:
        return "it has sound and no video stream"
    if "Input #0" in said and "Stream #" not in said:
        return "it holds no stream at all (an empty recording)"
    kind = content_kind(p)
    if kind is not None and kind.startswith(_NAMED_KINDS):   # one of the tool's own files
        return f"it is {kind}, not a video"
    if head and all(b in b"\t\n\r" or 32 <= b < 127 for b in head.lstrip(b"\xef\xbb\xbf")):
        return "it is a text file, not a video"
    return "not a video OpenCV can decode"


def video_info(path: str | os.PathLike) -> VideoInfo:
    """Read a video's frame rate, frame count and size without decoding it (and, where its
    frames are uneven in time, its constant-rate timeline). Kept per file
    (:func:`facetransfer.io.verified.file_stamp`): a transfer asks a dozen times of each input,
    and every reader asks."""
    from dataclasses import replace

    try:
        stamp = sequence_stamp(path) if is_sequence(path) else file_stamp(path)
    except OSError:         # missing or unreadable: :func:`_open`'s error
        return _video_info(path)
    return replace(_kept_info(str(path), stamp), path=Path(path))


@functools.lru_cache(maxsize=64)
def _kept_info(path: str, stamp: str) -> VideoInfo:
    return _video_info(path)


def _video_info(path) -> VideoInfo:
    """:func:`video_info` read from the file."""
    import cv2

    if is_sequence(path):
        seq = open_sequence(path)
        return VideoInfo(Path(path), seq.fps, seq.n_frames, seq.size, seq.sar)
    cap = _open(path)
    _warn_frame_of_sequence(Path(path))
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 25.0
        n = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0)  # a still gives -2**63: none
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        sar = pixel_aspect(cap.get(cv2.CAP_PROP_SAR_NUM), cap.get(cv2.CAP_PROP_SAR_DEN))
        turn = display_turn(cap)
        piped = size[0] > 0 and size[1] > 0 and first_field(path) is not None
    finally:
        cap.release()
    if size[0] <= 0 or size[1] <= 0:
        if Path(path).suffix.lower() in IMAGE_SUFFIXES:   # before: "video X.png has no frames"
            raise VideoError(f"cannot read the image {path} (damaged, or not an image OpenCV "
                             "decodes)")
        raise VideoError(f"video {path} has no frames")
    if turn in (90, 270):      # the stream's ratio is of its stored pixels, turned with them
        sar = (sar[1], sar[0])
    if exif_orientation(path) in (5, 6, 7, 8):     # a phone's portrait photo, stored sideways
        size = (size[1], size[0])
    if piped:
        log.info("%s: interlaced; decoded by ffmpeg (OpenCV's frames would be black or "
                 "garbage)", path)
    if is_still(path):   # a clip of one frame: OpenCV counts a JPEG's 1, but a PNG's, TIFF's,
        n = 1            # BMP's or WebP's 0 (so a PNG photo was looked at once, --frame 0 refused)
    n = _counted(path, n)
    even = timeline(path, n)
    mirrored = display_mirrored(path)
    if even is None:
        return VideoInfo(Path(path), fps, n, size, sar, piped=piped, turn=turn,
                         mirrored=mirrored)
    return VideoInfo(Path(path), even[0], len(even[1]), size, sar, even[1], piped, turn,
                     mirrored)


#: Containers that store no frame count: OpenCV's is its duration times its rate (a
#: Matroska file of 20 frames said 22), so the stream's packets are counted instead.
UNCOUNTED = ("matroska,webm",)


def _counted(path, n: int) -> int:
    """The frames of a video whose container stores no count (:data:`UNCOUNTED`): its video
    packets (:func:`facetransfer.io.video_timeline.packet_count`); of one whose edit list hides
    frames (a phone's clip trimmed without re-encoding: :func:`facetransfer.io.video_timeline.
    hidden_count`), the packets shown (:func:`facetransfer.io.video_timeline.shown_count`),
    where OpenCV counts the track's samples (not its stored packets less the hidden ones: an
    edit list's index repeats and drops packets: a clip shown from frame 10 for 60 frames
    was counted 30); else ``n``, OpenCV's."""
    from .video_display import container
    from .video_timeline import hidden_count, packet_count, shown_count

    if container(path) not in UNCOUNTED:
        hidden = hidden_count(path)
        shown = shown_count(path) if hidden else None
        if shown is None and hidden and n > hidden:     # cut short: its trim's frames
            shown = n - hidden
        if shown == 0:
            raise VideoError(f"video {path} shows none of the frames it stores: its edit list "
                             "shows no time of them (an edit past their end, or of no length; "
                             "players show no picture)")
        if shown is not None and shown != n:
            log.info("%s: %d frames shown (its edit list hides %d stored packets)", path, shown,
                     hidden)
            return shown
        return n
    m = packet_count(path)
    if m and m != n:
        log.info("%s: %d frames (its packets; the container's duration said %d)", path, m, n)
        return m
    return n


def display_turn(cap) -> int:
    """Degrees clockwise (0, 90, 180 or 270) that an opened ``cv2.VideoCapture`` turns its
    frames by the video's display matrix (0 where OpenCV does not turn them)."""
    import cv2

    if not cap.get(cv2.CAP_PROP_ORIENTATION_AUTO):
        return 0
    meta = cap.get(cv2.CAP_PROP_ORIENTATION_META)
    if not np.isfinite(meta):
        return 0
    return int(round(meta / 90.0)) % 4 * 90


def iter_frames(path: str | os.PathLike, *, start: int = 0, stop: int | None = None,
                seek: bool = True) -> Iterator[np.ndarray]:
    """Yield RGB frames ``(H, W, 3) uint8`` from ``start`` (inclusive) to ``stop`` (exclusive):
    of a video of variable frame rate, the steps of its constant-rate timeline
    (:attr:`VideoInfo.steps`; each a frame of its own).

    ``seek=True`` reaches ``start`` by the container's seek only where OpenCV's lands on the
    frame asked (:func:`seeks_exactly`: its container, and its frames on their rate's steps),
    else, as ``seek=False`` always does, by decoding every frame before it (``grab``, no colour
    conversion). A video of variable frame rate (``steps``) is always decoded from its start.
    """
    if exif_orientation(path) != 1:     # a photo stored turned, read upright
        yield from _upright_still(path, start, stop)
        return
    steps = video_info(path).steps
    if steps is None:
        yield from _stored_frames(path, start=start, stop=stop, seek=seek)
        return
    stop = len(steps) if stop is None else min(stop, len(steps))
    if start >= stop:
        return
    stored = _stored_frames(path, start=steps[start], stop=steps[stop - 1] + 1, seek=False)
    shown, frame = steps[start] - 1, None
    for k in range(start, stop):
        while shown < steps[k]:
            frame = next(stored, None)
            shown += 1
            if frame is None:
                return
        yield frame.copy()


def _stored_frames(path, *, start: int, stop: int | None, seek: bool) -> Iterator[np.ndarray]:
    """The stored frames ``start`` to ``stop`` in turn (:func:`iter_frames` of an even
    video)."""
    import cv2

    info = video_info(path)
    if is_sequence(path):
        yield from sequence_frames(path, start=start, stop=stop)
        return
    if info.piped:
        yield from piped_frames(path, info.size, start=start, stop=stop)
        return
    n = 0
    for bgr in _decoded(path, start, stop, seek):
        yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        n += 1
    expect = max(int(info.n_frames) - start, 0)
    expect = expect if stop is None else min(expect, max(stop - start, 0))
    # none decoded where the header counts some (a count a frame or two high aside): before,
    # "the clip has no frames", naming no file
    if n == 0 and expect > 0 and (start == 0 or expect >= TRUNCATED_FRAMES):
        raise _undecoded(path, start, int(info.n_frames))
    if n and expect - n >= max(TRUNCATED_FRAMES, 0.02 * expect):
        _say_truncated(str(path), start + n - 1, int(info.n_frames))


def _undecoded(path, start: int, counted: int) -> VideoError:
    """The error of a video of which no frame from ``start`` decodes though its header counts
    ``counted``: damaged or cut short (an MP4 whose index comes first, copied in part)."""
    return VideoError(f"video {path}: no frame from frame {start} on decodes, though its "
                      f"header counts {counted} (damaged, or cut short)")


@functools.lru_cache(maxsize=16)
def _say_truncated(path: str, last: int, counted: int) -> None:
    """:func:`read_video`'s warning of a video that ends early, for frames read one by one
    (a track's: a file cut short is tracked as a shorter clip, and this says so); once a
    file."""
    log.warning("video %s ends after frame %d of the %d its header counts (truncated?): "
                "its frames to there are used", path, last, counted)


def read_video(path: str | os.PathLike, *, start: int = 0, stop: int | None = None,
               max_frames: int | None = None) -> tuple[np.ndarray, float]:
    """Decode frames into one array.

    Returns
    -------
    frames : (F, H, W, 3) uint8
    fps : float

    Raises
    ------
    VideoError
        Missing, unreadable or empty video.
    """
    from .memory import first_frame_count, frame_budget, grow_frames

    info = video_info(path)
    if max_frames is not None:
        stop = start + max_frames if stop is None else min(stop, start + max_frames)
    # decoded straight into one array sized by the container's count (grown if that was short):
    # no per-frame copies to stack, a third of the memory touched; on disk past the budget
    expect = max(int(info.n_frames) - start, 0)
    expect = expect if stop is None else min(expect, max(stop - start, 0))
    budget = frame_budget()
    if is_sequence(path):       # RGB, file by file
        source, put = sequence_frames(path, start=start, stop=stop), np.copyto
    elif exif_orientation(path) != 1:   # a photo stored turned: OpenCV's capture keeps it so
        source, put = iter_frames(path, start=start, stop=stop), np.copyto
    elif info.piped:            # RGB from ffmpeg (interlaced: OpenCV's are black)
        source, put = piped_frames(path, info.size, start=start, stop=stop), np.copyto
    elif info.steps is None:    # BGR buffers converted into place
        source, put = _decoded(path, start, stop), _bgr_to_rgb
    else:                       # the timeline's steps, RGB
        source, put = iter_frames(path, start=start, stop=stop), np.copyto
    out, n = None, 0
    for frame in source:
        if out is None or n == len(out):
            size = first_frame_count(expect, frame.size, budget) if out is None else 2 * n
            out = grow_frames(out, n, max(size, n + 1), frame.shape, what=f"video {path}",
                              budget=budget)
        put(out[n], frame)
        n += 1
    if n == 0:
        if expect > 0:
            raise _undecoded(path, start, int(info.n_frames))
        raise VideoError(f"video {path} has no frames (from frame {start})")
    if expect - n >= max(TRUNCATED_FRAMES, 0.02 * expect):
        _say_truncated(str(path), start + n - 1, int(info.n_frames))
    return out[:n], info.fps


def exif_orientation(path) -> int:
    """A JPEG photo's EXIF orientation (1: stored upright; 6: turned a quarter, as a phone
    stores a portrait; 2-8 as EXIF numbers them); 1 for anything else. OpenCV's capture, which
    reads a still as a clip of one frame, does not apply it (its ``imread`` does)."""
    if Path(path).suffix.lower() not in (".jpg", ".jpeg") or is_sequence(path):
        return 1
    from PIL import Image

    try:
        with Image.open(path) as im:
            value = im.getexif().get(0x0112, 1)
    except (OSError, ValueError, SyntaxError):
        return 1
    return int(value) if value in range(1, 9) else 1


def _upright_still(path, start: int, stop: int | None) -> Iterator[np.ndarray]:
    """A photo's one frame ``(H, W, 3) uint8`` RGB, its EXIF orientation applied (OpenCV's
    ``imread``), where ``start``-``stop`` holds frame 0."""
    import cv2

    if start > 0 or stop is not None and stop <= 0:
        return
    from .frame_file import read_image

    bgr = read_image(Path(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise VideoError(f"cannot read the image {path} (damaged, or not an image OpenCV "
                         "decodes)")
    yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


#: :func:`read_video` says a video ends early when it decodes at least this many frames (and
#: 2 % of them) fewer than its header counts (a header's count may be a frame or two off).
TRUNCATED_FRAMES = 3


def seeks_exactly(path: str | os.PathLike, fps: float) -> bool:
    """Whether OpenCV's seek lands on the frame asked in the video ``path`` (``fps``: OpenCV's
    rate of it): exact in its container (:func:`facetransfer.io.video_display.exact_seek`; in
    an MPEG transport stream of H.264 it lands nowhere) and its frames' times on that rate's
    steps (:func:`facetransfer.io.video_timeline.on_rate_grid`; else it lands frames away)."""
    return exact_seek(path) and on_rate_grid(path, fps)


def _at(cap, path, start: int, seek: bool) -> bool:
    """Put an opened capture at stored frame ``start``: by the container's seek where ``seek``
    and OpenCV's lands exactly (:func:`seeks_exactly`), else by decoding every frame before it
    (``grab``: no colour conversion). False where the clip ends before ``start``."""
    import cv2

    if not start:
        return True
    if seek and seeks_exactly(path, cap.get(cv2.CAP_PROP_FPS)):
        cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        return True
    return all(cap.grab() for _ in range(start))


def _bgr_to_rgb(dst: np.ndarray, bgr: np.ndarray) -> None:
    import cv2

    cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB, dst=dst)


def _decoded(path, start: int, stop: int | None, seek: bool = True) -> Iterator[np.ndarray]:
    """The stored frames ``start`` to ``stop`` as BGR, in one decoding buffer reused for each
    (reached by the container's seek to ``start`` where ``seek`` and it is exact, :func:`_at`);
    a mirrored video's mirrored back (:attr:`VideoInfo.mirrored`) into a second one."""
    import cv2

    info = video_info(path)
    mirror = None if not info.mirrored else 0 if info.turn in (0, 180) else 1  # cv2.flip code
    cap = _open(path)
    try:
        if not _at(cap, path, start, seek):
            return
        n, bgr, shown = 0, None, None
        while stop is None or start + n < stop:
            ok, bgr = cap.read(bgr)
            if not ok:
                break
            shown = bgr if mirror is None else cv2.flip(bgr, mirror, dst=shown)
            yield shown
            n += 1
    finally:
        cap.release()

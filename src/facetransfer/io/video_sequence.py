"""Image sequences read as videos: a plate of numbered frames (``plate/%04d.png`` or
``plate/####.png``, as compositing and 3-D packages write them) is an input wherever a video is.

A sequence starts at its lowest frame number present (0, 1, 1001, ...) and runs without a gap;
its frames are PNG, JPEG, TIFF or BMP files (8 or 16 bits a channel, grey or colour; an alpha
channel is set aside), given as ``(H, W, 3) uint8`` RGB (:mod:`facetransfer.io.frame_file`), or
OpenEXR files of scene-linear floats, shown through the sRGB curve (:mod:`facetransfer.io.exr`),
or DPX files of log, linear or video code values (:mod:`facetransfer.io.dpx`).
A sequence is read at the rate ``FACETRANSFER_SEQUENCE_FPS`` (the commands' ``--sequence-fps``)
gives, else at the one its first frame's header names (DPX, OpenEXR:
:mod:`facetransfer.io.plate_header`, which also gives its start timecode and its pixels'
aspect ratio: an anamorphic plate's), else at :data:`DEFAULT_SEQUENCE_FPS`. It has no audio
and no fields; its pixels are square unless its header says otherwise.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import VideoError
from .frame_file import read_frame_file

log = logging.getLogger(__name__)

__all__ = ["IMAGE_SUFFIXES", "FRAME_FIELD", "DEFAULT_SEQUENCE_FPS", "SEQUENCE_FPS_VARIABLE",
           "Sequence", "is_sequence", "percent_pattern", "sequence_fps", "sequence_stamp",
           "sequence_files", "open_sequence", "sequence_frames", "suggested_pattern",
           "pattern_of_file", "STILL_SUFFIXES", "is_still",
           "same_sequence_files"]

#: Image formats of a frame sequence, read and written (``frames/%05d.png``).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".dpx")
#: Image formats of plates that a sequence refuses by name: Cineon's own files (their header
#: is not DPX's) and Radiance's, whose pixels need the user's colour pipeline to become RGB.
_SCENE_SUFFIXES = (".cin", ".hdr")
#: A frame-number field: printf's ``%d``/``%05d``, or a run of ``#`` (one digit each).
FRAME_FIELD = re.compile(r"%0?\d*d|#+")
#: The frame rate of a sequence when none is given: film's and the compositing packages'.
DEFAULT_SEQUENCE_FPS = 24.0
#: The environment variable of the sequences' frame rate (set by ``--sequence-fps``).
SEQUENCE_FPS_VARIABLE = "FACETRANSFER_SEQUENCE_FPS"


@dataclass(frozen=True)
class Sequence:
    """An image sequence on disk.

    Attributes
    ----------
    pattern : Path
        The name as given (``%04d`` or ``####``).
    first : int
        Number of its first frame.
    n_frames : int
    size : (int, int)
        ``(width, height)`` of its first frame.
    fps : float
        The rate it is read at: ``--sequence-fps`` (:func:`sequence_fps`) where given, else
        its first frame's header's (a DPX or OpenEXR frame's:
        :func:`facetransfer.io.plate_header.frame_header`), else :data:`DEFAULT_SEQUENCE_FPS`.
    timecode : str or None
        Its first frame's SMPTE timecode, where its header has one (DPX, OpenEXR).
    rate_from : str
        Where :attr:`fps` came from: ``"said"``, ``"header"`` or ``"default"``.
    sar : (int, int)
        Its pixels' aspect ratio, as its first frame's header says it (an anamorphic plate's
        2:1; square where none is said).
    """

    pattern: Path
    first: int
    n_frames: int
    size: tuple[int, int]
    fps: float
    timecode: str | None = None
    rate_from: str = "default"
    sar: tuple[int, int] = (1, 1)

    def file(self, i: int) -> Path:
        """The file of frame ``i`` (0-based: the sequence's ``first + i``)."""
        return _numbered(self.pattern, self.first + i)


def is_sequence(path) -> bool:
    """Whether ``path`` names an image sequence to read: a frame-number field in its file name
    (:data:`FRAME_FIELD`) and an image's extension (or a scene-linear plate's, refused by
    :func:`open_sequence` with its reason)."""
    if path is None:
        return False
    p = Path(path)
    return bool(FRAME_FIELD.search(p.name)) and \
        p.suffix.lower() in IMAGE_SUFFIXES + _SCENE_SUFFIXES


#: The extensions of a still image read as a clip of one frame (beside :data:`IMAGE_SUFFIXES`).
STILL_SUFFIXES = IMAGE_SUFFIXES + (".ppm", ".pgm", ".webp")


def is_still(path) -> bool:
    """Whether ``path`` names one still image (a photo: ``portrait.jpg``), not a sequence's
    pattern nor a video; read as a clip of one frame, and as a transfer's target animated by
    its expression source's frames (:mod:`facetransfer.transfer_plan`)."""
    if path is None or not isinstance(path, (str, os.PathLike)) or is_sequence(path):
        return False
    return Path(path).suffix.lower() in STILL_SUFFIXES


def percent_pattern(path) -> Path:
    """``path`` with a ``#`` field written as printf's (``####`` -> ``%04d``)."""
    p = Path(path)
    return p.with_name(re.sub(r"#+", lambda m: f"%0{len(m.group(0))}d", p.name))


def _numbered(pattern: Path, k: int) -> Path:
    p = percent_pattern(pattern)
    return p.with_name(p.name % k)


def _rate_said() -> str:
    """What ``FACETRANSFER_SEQUENCE_FPS`` (``--sequence-fps``) says, ``""`` where nothing."""
    return os.environ.get(SEQUENCE_FPS_VARIABLE, "").strip()


def sequence_fps() -> float:
    """The rate image sequences are read at: ``FACETRANSFER_SEQUENCE_FPS``, else
    :data:`DEFAULT_SEQUENCE_FPS`.

    Raises
    ------
    VideoError
        The variable is not a number of frames a second in (0, 1000].
    """
    said = _rate_said()
    if not said:
        return DEFAULT_SEQUENCE_FPS
    try:
        fps = float(said)
    except ValueError:
        fps = float("nan")
    if not 0 < fps <= 1000:
        raise VideoError(f"{SEQUENCE_FPS_VARIABLE} (--sequence-fps) must be a frame rate in "
                         f"(0, 1000], got {said!r}")
    return fps


def sequence_files(pattern) -> dict[int, Path]:
    """The files of ``pattern``'s folder that its field matches (at least as many digits as
    the field is wide), by frame number.

    Raises
    ------
    VideoError
        Not exactly one frame-number field, or no such folder.
    """
    p = percent_pattern(pattern)
    fields = FRAME_FIELD.findall(p.name)
    if len(fields) != 1 or p.name.count("%") != 1:
        raise VideoError(f"image sequence {pattern}: the name needs exactly one frame-number "
                         "field like %04d or #### (e.g. plate/%04d.png)")
    m = FRAME_FIELD.search(p.name)
    width = int(m.group(0)[1:-1] or 0)
    rx = re.compile(re.escape(p.name[:m.start()]) + r"(\d+)" + re.escape(p.name[m.end():])
                    + r"\Z")
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise VideoError(f"image sequence {pattern}: folder {folder} does not exist")
    found = {}
    for q in folder.iterdir():
        hit = rx.match(q.name)
        if hit and len(hit.group(1)) >= width and q.is_file():
            found[int(hit.group(1))] = q
    return found


def sequence_stamp(path) -> str:
    """An image sequence's identity on disk and its rate: its folder, and every frame file's
    name, size and modification time (a frame replaced, added or removed changes it), and
    the rate said (``?`` where none is: its frames' headers' rate, or the default)."""
    h = hashlib.sha256()
    files = sequence_files(Path(path))
    for k in sorted(files):
        st = files[k].stat()
        h.update(f"{files[k].name}|{st.st_size}|{st.st_mtime_ns};".encode())
    folder = percent_pattern(path).parent.resolve()
    said = "" if _rate_said() else "?"          # else the header's rate, or the default
    return f"{folder}/{Path(path).name}|{len(files)}|{h.hexdigest()[:24]}|{sequence_fps()}{said}"


def sequence_timecode(path) -> str | None:
    """The start timecode in the header of an image sequence's first frame (DPX, OpenEXR),
    None without one or without frames: read without :func:`open_sequence`'s checks and its
    word on the rate (a track's or an export's look-up of its source's timecode)."""
    from .plate_header import frame_header

    files = sequence_files(Path(path))
    return frame_header(files[min(files)]).timecode if files else None


def open_sequence(path) -> Sequence:
    """The image sequence ``path`` names, checked: files present from its first number on
    without a gap, the first frame readable.

    Raises
    ------
    VideoError
        A scene-linear format, no matching file, a gap (naming the missing frame's file), an
        unreadable first frame, or a bad ``FACETRANSFER_SEQUENCE_FPS``.
    """
    p = Path(path)
    if p.suffix.lower() in _SCENE_SUFFIXES:
        raise VideoError(f"image sequence {p}: {p.suffix} frames are not read; write the "
                         "plate as DPX (log or video), OpenEXR (scene-linear), or PNG or "
                         "TIFF (8 or 16 bits, display-referred sRGB / Rec.709) first")
    return _opened(str(p), sequence_stamp(p))


@functools.lru_cache(maxsize=32)
def _opened(path: str, stamp: str) -> Sequence:
    p = Path(path)
    files = sequence_files(p)
    if not files:
        raise VideoError(f"image sequence {p}: no file matches it (e.g. "
                         f"{_numbered(p, 1).name} would)")
    first = min(files)
    n = 0
    while first + n in files:
        n += 1
    if len(files) > n:
        after = min(k for k in files if k > first + n)
        end = after
        while end + 1 in files:
            end += 1
        raise VideoError(f"image sequence {p}: frame {first + n} is missing "
                         f"({_numbered(p, first + n).name}): frames {_span(first, first + n - 1)}"
                         f" and {_span(after, end)} are present; a sequence runs without gaps")
    from .plate_header import frame_header

    image = read_frame_file(files[first], p)
    header = frame_header(files[first])
    fps, rate_from = _rate(p, header)
    return Sequence(p, first, n, (image.shape[1], image.shape[0]), fps, header.timecode,
                    rate_from, header.sar or (1, 1))


def _rate(pattern: Path, header) -> tuple[float, str]:
    """The rate a sequence is read at and where it came from (:attr:`Sequence.rate_from`):
    what ``--sequence-fps`` says, else what its first frame's ``header`` says
    (:class:`facetransfer.io.plate_header.FrameHeader`), else the default, said once."""
    said = bool(_rate_said())
    fps = sequence_fps()
    if said and header.fps is not None and abs(header.fps - fps) > 1e-3:
        log.warning("%s: its frames' headers say %g fps; read at %g fps as --sequence-fps "
                    "says", pattern, header.fps, fps)
    if said:
        return fps, "said"
    if header.fps is not None:
        return header.fps, "header"
    log.warning("%s: an image sequence stores no frame rate; read at %g fps "
                "(--sequence-fps to give its own)", pattern, fps)
    return fps, "default"


def _span(a: int, b: int) -> str:
    return str(a) if a == b else f"{a}-{b}"


def sequence_frames(path, *, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
    """Yield frames ``start`` (inclusive) to ``stop`` (exclusive; 0-based) of the image
    sequence ``path`` as ``(H, W, 3) uint8`` RGB.

    Raises
    ------
    VideoError
        A frame of another size than the first, or unreadable (naming its file).
    """
    seq = open_sequence(path)
    stop = seq.n_frames if stop is None else min(stop, seq.n_frames)
    W, H = seq.size
    for i, rgb in _decoded_ahead(seq, range(max(start, 0), stop)):
        if rgb.shape[:2] != (H, W):
            raise VideoError(f"image sequence {seq.pattern}: frame file {seq.file(i)} is "
                             f"{rgb.shape[1]}x{rgb.shape[0]}, its first frame {W}x{H}")
        yield rgb


#: Frame files decoded ahead of the one yielded, on threads (OpenCV's decoders release the
#: GIL): a PNG of 480x480 takes ~6 ms, a video frame ~1 ms.
_AHEAD = 6


def _decoded_ahead(seq: Sequence, frames: range) -> Iterator[tuple[int, np.ndarray]]:
    """``(i, RGB frame)`` for each of ``frames`` in turn, the next :data:`_AHEAD` files decoded
    meanwhile on threads (:func:`facetransfer.io.ahead.ordered_ahead`)."""
    from .ahead import ordered_ahead

    def read(i: int):
        return i, read_frame_file(seq.file(i), seq.pattern)

    yield from ordered_ahead(read, ((i,) for i in frames), ahead=_AHEAD)


def suggested_pattern(folder) -> Path | None:
    """The pattern of the numbered images in ``folder`` (the last run of digits of an image's
    name that others share, e.g. ``folder/sh010.%04d.png``), for a folder given where a video
    was expected: of the patterns, the one that reads the most files (before, the first name's:
    two stray ``notes1.png``, ``notes2.png`` beside a plate's 100 frames were proposed as the
    sequence); None when it holds no two images so numbered."""
    try:
        names = sorted(q.name for q in Path(folder).iterdir()
                       if q.suffix.lower() in IMAGE_SUFFIXES and "%" not in q.name)
    except OSError:
        return None
    reads = _frames_read([f for f in map(_numbered_as, names) if f is not None])
    ranked = sorted(reads, key=lambda f: (-reads[f], f))
    return next((Path(folder) / f"{a}%0{w}d{b}" for a, w, b in ranked if reads[(a, w, b)] > 1
                 and len(sequence_files(Path(folder) / f"{a}%0{w}d{b}")) > 1), None)


def _frames_read(fields: list) -> dict[tuple, int]:
    """``{(before, width, after): files it reads}`` of the frame-number fields of a folder's
    names (:func:`_numbered_as`, one a file): a field ``width`` wide reads the numbers of so
    many digits or more (:func:`sequence_files`), so an unpadded numbering's ``frame%01d.png``
    reads ``frame1 .. frame30``, where ``frame%02d.png``, of the most names, left 1-9 out."""
    from collections import Counter, defaultdict

    widths: dict = defaultdict(Counter)      # by the text around the field: linear in files
    for a, w, b in fields:
        widths[(a, b)][w] += 1
    return {(a, w, b): sum(c for w2, c in count.items() if w2 >= w)
            for (a, b), count in widths.items() for w in count}


def _numbered_as(name: str) -> tuple[str, int, str] | None:
    """A file name's last run of digits as a frame-number field: the text before it, its
    width and the text after (``("sh010.", 4, ".png")`` of ``sh010.1001.png``), None for a
    name without digits."""
    runs = list(re.finditer(r"\d+", Path(name).stem))
    if not runs:
        return None
    m = runs[-1]
    return name[:m.start()], len(m.group(0)), name[m.end():]


def pattern_of_file(path) -> Path | None:
    """The pattern of the image sequence whose frame the file ``path`` is (the last run of
    digits of its name, e.g. ``plate/sh010.%04d.dpx`` of ``plate/sh010.1001.dpx``), where other
    files share it; None for a numbered still or a name without digits."""
    p = Path(path)
    runs = list(re.finditer(r"\d+", p.stem))
    if not runs:
        return None
    m = runs[-1]
    pattern = p.with_name(f"{p.name[:m.start()]}%0{len(m.group(0))}d{p.name[m.end():]}")
    return pattern if len(sequence_files(pattern)) > 1 else None   # not a numbered still


def same_sequence_files(a, b) -> bool:
    """Whether the frame files of the sequences ``a`` and ``b`` can be the same files (same
    folder, and the same name around the frame number): writing one would replace or remove
    the other's frames."""
    pa, pb = percent_pattern(a), percent_pattern(b)
    if os.path.abspath(pa.parent) != os.path.abspath(pb.parent):
        return False

    def around(p: Path):
        m = FRAME_FIELD.search(p.name)
        return (p.name[:m.start()], p.name[m.end():].lower()) if m else None

    return around(pa) is not None and around(pa) == around(pb)

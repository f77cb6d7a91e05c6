"""Video input and output. Frames are ``(H, W, 3) uint8`` RGB.

Reading decodes with OpenCV, lazily (:func:`iter_frames`) or all at once (:func:`read_video`),
in :mod:`facetransfer.io.video_read` (its names are this module's too). Writing is one writer
for every command that writes video (:class:`VideoWriter`,
:func:`encode_video`): H.264 by default (libx264 through the ffmpeg binary of imageio-ffmpeg,
``yuv420p``, CRF 18), H.265 or ProRes (:class:`VideoOptions`), or an image sequence
(``frames/%05d.png``), with the audio of another file muxed in. It writes to a temporary file
renamed on success, checks ffmpeg's exit status and that the file holds the frames written,
and raises :class:`~facetransfer.errors.VideoError` otherwise, so a failed write (a full disk)
never leaves a broken video under the final name nor replaces a good one.

Names of :data:`__all__` that live elsewhere, importable from here too (one import for the
video API): :class:`VideoInfo`, :func:`video_info`, :func:`pixel_aspect`, :func:`iter_frames`,
:func:`read_video` (:mod:`.video_read`); :class:`VideoOptions`, ``CODECS``, ``DEFAULT_CODEC``,
``DEFAULT_CRF``, ``CRF_RANGE``, ``PRESETS``, ``DEFAULT_PRESET``, ``VIDEO_SUFFIXES``
(:mod:`.video_options`); ``IMAGE_SUFFIXES`` (:mod:`.video_sequence`); :func:`colour_matrix`,
:func:`video_colour` (:mod:`.video_display`); :func:`ffmpeg_exe` (:mod:`.ffmpeg`);
:func:`has_audio`, :func:`audio_codec`, :func:`audio_codecs`, :func:`mux_audio`
(:mod:`.video_audio`).
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import logging
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..errors import VideoError
from .atomic import (atomic_path, check_not_folder_name, check_output_path, probe_folder,
                     run_commit_checks)
from .ffmpeg import exit_cause, ffmpeg_error, ffmpeg_exe
from .frame_file import sixteen_bits
from .video_audio import audio_codec, audio_codecs, audio_input_args, has_audio, mux_audio
from .video_display import colour_matrix, frame_args, timecode_args, video_colour
from .video_options import (CODECS, CRF_RANGE, DEFAULT_CODEC, DEFAULT_CRF,  # noqa: F401 (API)
                            DEFAULT_PRESET, DEFAULT_X264_PARAMS, ENCODERS, GREY_CODECS, PRESETS,
                            VIDEO_SUFFIXES, VideoOptions)
from .video_read import (VideoInfo, iter_frames, pixel_aspect, read_video,  # noqa: F401 (API)
                         video_info)
from .video_sequence import (IMAGE_SUFFIXES, is_sequence, percent_pattern, same_sequence_files,
                             sequence_files)

log = logging.getLogger(__name__)

__all__ = ["VideoInfo", "video_info", "pixel_aspect", "iter_frames", "read_video", "CODECS",
           "DEFAULT_CODEC", "DEFAULT_CRF", "CRF_RANGE", "PRESETS", "DEFAULT_PRESET",
           "VIDEO_SUFFIXES", "IMAGE_SUFFIXES", "VideoOptions", "VideoOutput", "WrittenVideo",
           "colour_matrix", "video_colour", "ffmpeg_exe", "ffmpeg_encoders",
           "require_encoder", "is_image_pattern", "save_frame_image",
           "place_sequence", "check_video_output", "decoded_frame_count", "stored_frame_count",
           "has_audio", "audio_codec", "audio_codecs", "mux_audio", "warn_if_grown",
           "VideoWriter", "encode_video", "write_video", "write_video_with_audio"]


# ---------------------------------------------------------------------------------------------
# writing: one writer for every command (H.264 by default, H.265, ProRes, image sequences)
# ---------------------------------------------------------------------------------------------

_PATTERN = re.compile(r"%0?\d*d")


@dataclass(frozen=True)
class VideoOutput:
    """A checked output: a video file or an image sequence (``kind`` "video" or "images")."""

    path: Path
    kind: str
    options: VideoOptions


@dataclass(frozen=True)
class WrittenVideo:
    """What :func:`encode_video` / :meth:`VideoWriter.close` wrote.

    Attributes
    ----------
    path : Path
        The video, or the pattern of an image sequence.
    n_frames : int
        Frames written (for a video: also the number it holds).
    size : (int, int)
        ``(width, height)`` as stored (odd sizes grow by one pixel for 4:2:0).
    audio : bool
        Whether audio was muxed in.
    kind : str
        "video" or "images".
    """

    path: Path
    n_frames: int
    size: tuple[int, int]
    audio: bool
    kind: str = "video"


def _require_ffmpeg() -> str:
    exe = ffmpeg_exe()
    if exe is None:
        raise VideoError("no ffmpeg binary found to write video (pip install imageio-ffmpeg)")
    return exe


@functools.lru_cache(maxsize=4)
def ffmpeg_encoders(exe: str) -> frozenset[str]:
    """Names of the video encoders the ffmpeg binary ``exe`` has."""
    res = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True)
    names = set()
    for line in res.stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and len(parts[0]) == 6 and parts[0][0] == "V":
            names.add(parts[1])
    return frozenset(names)


def require_encoder(codec: str) -> str:
    """The ffmpeg binary, after checking that it has the encoder of ``codec``.

    Raises
    ------
    VideoError
        No ffmpeg, or one without that encoder (named).
    """
    exe = _require_ffmpeg()
    enc = ENCODERS[codec]
    if enc not in ffmpeg_encoders(exe):
        raise VideoError(f"the ffmpeg binary {exe} lacks the {enc} encoder needed for "
                         f"--codec {codec}; choose another --codec or install an ffmpeg with it")
    return exe


#: PIL's options per file type of an image sequence: PNG at zlib level 1 (PIL's default, 6,
#: took 67 ms a 512x480 frame, three times the render's own CPU; level 1 21 ms for 15 % more
#: bytes, measured), JPEG at quality 95 (PIL's default, 75, is a preview's).
_FRAME_SAVE = {".png": {"compress_level": 1}, ".jpg": {"quality": 95},
               ".jpeg": {"quality": 95}}


def save_frame_image(rgb: np.ndarray, path: str | os.PathLike, *,
                     suffix: str | None = None, header=None) -> None:
    """Write one frame of an image sequence, ``(H, W, 3) uint8`` RGB (or ``(H, W, 4)`` RGBA of a
    PNG or TIFF), to ``path`` in the file type of ``suffix`` (default: ``path``'s own; one of
    :data:`IMAGE_SUFFIXES`); a PNG or TIFF frame may also be uint16, grey ``(H, W)``, RGB or
    RGBA (:mod:`facetransfer.io.plate_depth`), an OpenEXR frame linear float RGB or an
    :class:`~facetransfer.io.exr.ExrImage` (:func:`facetransfer.io.exr.write_exr`), a DPX
    frame a :class:`~facetransfer.io.dpx.DpxImage` (:func:`facetransfer.io.dpx.write_dpx`).
    ``header``: the frame's :class:`~facetransfer.io.plate_header.FrameHeader` (rate,
    timecode, pixel aspect), recorded in a DPX or OpenEXR frame made here (a plate's frame
    keeps its own header)."""
    from PIL import Image

    suffix = (suffix or Path(path).suffix).lower()
    if suffix == ".exr":
        from .exr import write_exr

        write_exr(path, rgb, header)
        return
    if suffix == ".dpx":
        from .dpx import write_dpx

        write_dpx(path, rgb, header)
        return
    if rgb.dtype == np.uint16:
        _save_deep(rgb, path, suffix)
        return
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(
        path, format=Image.registered_extensions()[suffix], **_FRAME_SAVE.get(suffix, {}))


def _save_deep(img: np.ndarray, path, suffix: str) -> None:
    """A 16-bit grey, RGB or RGBA frame as a PNG or TIFF (OpenCV's encoder: Pillow writes no
    16-bit colour)."""
    import cv2

    if suffix not in (".png", ".tif", ".tiff"):
        raise VideoError(f"{path}: 16-bit frames are written as PNG or TIFF, not {suffix}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR if img.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    # a TIFF uncompressed, as Pillow writes the 8-bit ones (OpenCV's LZW: 21 ms a 480x480 frame
    # of grain for 0 % fewer bytes; uncompressed 0.3 ms)
    params = [cv2.IMWRITE_TIFF_COMPRESSION, 1] if suffix != ".png" else []
    ok, data = cv2.imencode(suffix, img, params)
    if not ok:
        raise VideoError(f"cannot encode the 16-bit frame {path}")
    Path(path).write_bytes(data.tobytes())


def _linear(frame, path) -> bool:
    """Whether ``frame`` is linear float RGB (an array, or a
    :class:`facetransfer.io.exr.ExrImage`) for an OpenEXR sequence ``path`` (written as it is,
    not as 8-bit RGB)."""
    return frame.dtype in (np.float16, np.float32) and Path(path).suffix.lower() == ".exr"


def fits_output(shape: tuple, size: tuple[int, int], path: str | os.PathLike,
                alpha: bool = False) -> bool:
    """Whether a frame of ``shape`` can be written into the output ``path`` of ``size``
    (W, H): ``(H, W, 3)`` colour, or ``(H, W, 4)`` RGBA (and ``(H, W)`` grey) into a PNG or TIFF
    sequence (:func:`facetransfer.io.plate_alpha.keeps_alpha`), ``(H, W)`` grey into an OpenEXR
    one (a matte, :mod:`facetransfer.io.matte`); a video written with an alpha plane
    (``alpha``: :attr:`VideoOptions.alpha`) takes RGBA only."""
    from .plate_alpha import keeps_alpha

    H, W = size[1], size[0]
    if alpha and not is_image_pattern(path):
        return tuple(shape) == (H, W, 4)
    if tuple(shape) == (H, W):   # a 16-bit grey plate's frame (facetransfer.io.plate_depth)
        return keeps_alpha(path) or (is_image_pattern(path)
                                     and Path(path).suffix.lower() == ".exr")
    return tuple(shape) == (H, W, 3) or (tuple(shape) == (H, W, 4) and keeps_alpha(path))


def is_image_pattern(path: str | os.PathLike) -> bool:
    """Whether ``path`` names an image sequence to write: a printf frame field in its name
    (``frames/%05d.png``), or an image's name with any ``%`` (whose field
    :func:`check_video_output` then asks for). A video's name may hold a ``%`` of its own
    (``take 100% final.mp4``)."""
    p = Path(path)
    return bool(_PATTERN.search(p.name)) or \
        ("%" in p.name and p.suffix.lower() in IMAGE_SUFFIXES)


def _pattern_files(pattern: Path) -> list[Path]:
    """Existing files of an image sequence (names matching the pattern exactly)."""
    if not pattern.parent.is_dir():
        return []
    return sorted(sequence_files(pattern).values())


def place_sequence(folder: str | os.PathLike, pattern: str | os.PathLike, n_frames: int, *,
                   first: int = 0, overwrite: bool = True) -> None:
    """Move the finished frames ``0 .. n_frames - 1`` of the image sequence ``pattern`` from
    ``folder`` beside the pattern (renamed; moved across file systems), numbered from ``first``
    there, and remove the files of an older, longer sequence of the same pattern, which would
    be mistaken for its frames.

    One process at a time places frames in the pattern's folder (a lock on the folder), so two
    runs writing the same sequence at once leave one run's frames, never a mix; without
    ``overwrite``, frames placed since the caller checked the output (another run's, finished
    first) are a :class:`VideoError` and stay as they are (``folder`` is left as it was).
    """
    pattern = Path(pattern)
    pattern.parent.mkdir(parents=True, exist_ok=True)
    run_commit_checks()    # as any output put in place (a model file written over meanwhile)
    with _folder_locked(pattern.parent):
        old = _pattern_files(pattern)
        if old and not overwrite:
            raise VideoError(f"output frames {pattern} were written meanwhile by another run "
                             f"({len(old)} files); pass --overwrite to replace them")
        names = [pattern.name % (first + i) for i in range(n_frames)]
        for i, name in enumerate(names):
            shutil.move(Path(folder) / (pattern.name % i), pattern.parent / name)
        keep = set(names)
        for q in old:
            if q.name not in keep:
                q.unlink(missing_ok=True)


@contextlib.contextmanager
def _folder_locked(folder: Path):
    """An exclusive ``flock`` on the folder itself while the block runs (waited for); where
    the file system or the platform (not POSIX) takes no lock on a folder, the block runs
    without it."""
    try:
        import fcntl
    except ImportError:     # not POSIX
        yield
        return
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        yield
        return
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)     # the lock goes with it


def check_video_output(path: str | os.PathLike, options: VideoOptions | None = None, *,
                       overwrite: bool = True, inputs=()) -> VideoOutput:
    """Validate where a video goes before any work: the kind of output, codec and container.

    ``path`` is a video (``.mp4``, ``.m4v``, ``.mov``, ``.mkv``, ``.avi``) or an image sequence
    whose name has one frame-number field (``frames/%05d.png``; ``.png``, ``.jpg``, ``.tif``,
    ``.bmp``; frame 0 is the first). A video naming one of ``inputs`` (paths or None) is
    refused (:func:`facetransfer.io.atomic.check_output_path`), and so is a sequence whose
    files could be an input sequence's (:func:`facetransfer.io.video_sequence.same_sequence_files`:
    its frames would be replaced, the rest removed).

    Raises
    ------
    VideoError
        Any other extension, an image name without ``%d``, a CRF for an image sequence, ProRes
        outside ``.mov``/``.mkv``, H.265 in ``.avi``, an encoder the ffmpeg binary lacks, or an
        existing output without ``overwrite``.
    """
    opt = options or VideoOptions()
    check_not_folder_name(path)        # before Path() drops the slash
    p = Path(path)
    suffix = p.suffix.lower()
    if is_image_pattern(p):
        fields = _PATTERN.findall(p.name)
        if suffix not in IMAGE_SUFFIXES:
            raise VideoError(f"output {p}: a frame pattern needs an image extension "
                             f"({', '.join(IMAGE_SUFFIXES)}), got {suffix or 'none'}")
        if len(fields) != 1 or p.name.count("%") != 1:
            raise VideoError(f"output {p}: an image-sequence pattern needs exactly one frame "
                             "number field like %05d (e.g. frames/%05d.png)")
        if opt.crf is not None:
            raise VideoError(f"output {p}: --crf sets a video's H.264/H.265 quality; an image "
                             f"sequence's frames are written as {suffix} files without it")
        same = next((q for q in inputs if is_sequence(q) and same_sequence_files(p, q)), None)
        if same is not None:
            raise VideoError(f"output {p} would write over the frames of the input {same}; "
                             "choose another name or folder")
        file = next((q for q in (p.parent, p.parent.parent) if q.is_file()), None)
        if file is not None:   # else mkdir at the writer's start: "File exists"
            raise VideoError(f"output folder {file} is a file, not a folder (for {p})")
        if not p.parent.parent.is_dir() and not p.parent.is_dir():
            raise VideoError(f"output folder {p.parent} does not exist (for {p})")
        if not overwrite and _pattern_files(p):
            raise VideoError(f"output frames {p} exist ({len(_pattern_files(p))} files); pass "
                             "--overwrite to replace them")
        probe_folder(p)
        return VideoOutput(p, "images", opt)
    if suffix in IMAGE_SUFFIXES and "#" in p.name:
        raise VideoError(f"output {p}: write an output sequence's frame number as "
                         f"{percent_pattern(p).name} (#### is read in input sequences only)")
    if suffix in IMAGE_SUFFIXES:
        raise VideoError(f"output {p} is an image: for an image sequence put a frame number "
                         f"in the name (e.g. {p.with_name(p.stem + '_%05d' + p.suffix)}); for "
                         "a video use .mp4")
    if suffix not in VIDEO_SUFFIXES:
        raise VideoError(f"output {p}: extension {suffix or '(none)'} is neither a video "
                         f"({', '.join(VIDEO_SUFFIXES)}) nor an image sequence "
                         "(e.g. frames/%05d.png)")
    if opt.codec == "prores" and suffix not in (".mov", ".mkv"):
        raise VideoError(f"output {p}: ProRes goes in a .mov or .mkv file, not {suffix}")
    if opt.codec == "h265" and suffix == ".avi":   # AVI has no standard HEVC tag: few play it
        raise VideoError(f"output {p}: H.265 goes in a .mp4, .mov or .mkv file, not .avi")
    if opt.grey and suffix not in (".mov", ".mkv"):
        raise VideoError(f"output {p}: {opt.codec} grey frames go in a .mov or .mkv file, "
                         f"not {suffix}")
    require_encoder(opt.codec)
    check_output_path(p, overwrite=overwrite, inputs=inputs)
    return VideoOutput(p, "video", opt)


def _encode_args(opt: VideoOptions, suffix: str) -> list[str]:
    """ffmpeg output arguments of a codec (libx264/libx265 4:2:0, ProRes 422 HQ or 4444 with
    alpha); H.264 at the default preset with :data:`DEFAULT_X264_PARAMS` too (the default's
    tuning: 11-18 % less of the encoder's CPU for the same quality)."""
    enc = ENCODERS[opt.codec]
    if opt.grey:   # one channel of 16 bits, lossless; data, so no colour tags
        fmt = ["-pix_fmt", "gray16be"] if opt.codec == "png" else \
            ["-level", "3", "-g", "1", "-slicecrc", "1", "-pix_fmt", "gray16le"]  # intra only
        return ["-c:v", enc, *fmt] + _container_args(opt, suffix)
    tags = ["-colorspace", opt.matrix, "-color_range", "tv"] if opt.colour_tags else []
    if opt.codec == "prores":  # 422 HQ, or 4444 with its alpha plane (stored in 16 bits)
        fmt = ["-profile:v", "4", "-pix_fmt", "yuva444p10le", "-alpha_bits", "16"] \
            if opt.alpha else ["-profile:v", "3", "-pix_fmt", "yuv422p10le"]
        return ["-c:v", enc, *fmt, "-vendor", "apl0", *tags,
                *(["-flags", "+ildct"] if opt.field else [])]
    args = ["-c:v", enc, "-preset", opt.preset, "-crf", str(opt.effective_crf),
            "-pix_fmt", "yuv420p10le" if opt.deep else "yuv420p", *tags]
    if opt.field:                           # interlaced coding (fields and frames adaptively)
        args += ["-flags", "+ildct+ilme"]
    if opt.codec == "h265":
        args += ["-x265-params", "log-level=error"]
    elif opt.preset == DEFAULT_PRESET:     # x264's own for every preset asked for otherwise
        args += ["-x264-params", DEFAULT_X264_PARAMS]
    return args + _container_args(opt, suffix)


def _container_args(opt: VideoOptions, suffix: str) -> list[str]:
    """ffmpeg output arguments an MP4 / QuickTime file asks of its video: HEVC tagged ``hvc1``
    (what Apple players expect) and the index at the front (``+faststart``); and the start
    timecode (:func:`~facetransfer.io.video_display.timecode_args`)."""
    tc = timecode_args(opt.timecode, suffix)
    if suffix not in (".mp4", ".m4v", ".mov"):
        return tc
    return (["-tag:v", "hvc1"] if opt.codec == "h265" else []) + ["-movflags", "+faststart"] + tc


def _stored_size(size: tuple[int, int], codec: str) -> tuple[int, int]:
    """``(width, height)`` as a codec stores frames of ``size``: 4:2:0 rounds both up to even,
    ProRes 4:2:2 the width only (edge pixels repeated), the grey codecs neither."""
    w, h = int(size[0]), int(size[1])
    if codec in GREY_CODECS:
        return w, h
    return w + w % 2, h + (h % 2 if codec != "prores" else 0)


def grown_size_of(stored: tuple[int, int], size: tuple[int, int]) -> bool:
    """Whether a video stored at ``stored`` (``(W, H)``) holds frames of the odd ``size`` grown
    to even sizes (:func:`_stored_size` of 4:2:0 or 4:2:2: the edge repeated): the frames are
    then the stored ones' top-left ``size`` (e.g. ``synth-video --size 63x47``'s clip, 64x48,
    beside its truth's 63x47)."""
    size = (int(size[0]), int(size[1]))
    return tuple(int(v) for v in stored) != size and tuple(int(v) for v in stored) in (
        _stored_size(size, "h264"), _stored_size(size, "prores"))


def warn_if_grown(path, size: tuple[int, int], codec: str) -> None:
    """Warn (once per output) that a video of ``size`` is stored larger than its frames: the
    frame of a plate of odd size grows by a column or row repeating its edge
    (:func:`_stored_size`), which a compositor laying the result over the plate must know."""
    stored = _stored_size(size, codec)
    if stored != (int(size[0]), int(size[1])):
        log.warning("%s: the frames' odd size %dx%d is stored as %dx%d, the edge repeated "
                    "(%s); an image sequence keeps %dx%d", path, size[0], size[1], *stored,
                    "4:2:0 holds even sizes only" if codec != "prores"
                    else "4:2:2 holds even widths only", size[0], size[1])


def decoded_frame_count(path: str | os.PathLike) -> int:
    """Decode every frame of a video with ffmpeg and return how many there are.

    Raises
    ------
    VideoError
        If ffmpeg cannot decode the file.
    """
    return _ffmpeg_frame_count(path, [], "does not decode")


def stored_frame_count(path: str | os.PathLike) -> int:
    """How many frames the first video stream of a file holds: its packets, read by ffmpeg's
    demuxer without decoding (a 10-second clip in about 20 ms, where decoding takes 0.25 s).

    Raises
    ------
    VideoError
        If ffmpeg cannot read the file.
    """
    return _ffmpeg_frame_count(path, ["-c", "copy"], "cannot be read")


def _ffmpeg_frame_count(path, args: list[str], failure: str) -> int:
    """The last ``frame=`` count ffmpeg reports while it reads the first video stream of
    ``path`` into the null muxer with the output ``args``."""
    exe = _require_ffmpeg()
    res = subprocess.run([exe, "-hide_banner", "-nostdin", "-v", "error", "-stats", "-i",
                          str(path), "-map", "0:v:0", *args, "-f", "null", "-"],
                         capture_output=True, text=True)
    found = re.findall(r"frame=\s*(\d+)", res.stderr)
    if res.returncode != 0 or not found:
        raise ffmpeg_error(res.stderr, f"video {path} {failure}")
    return int(found[-1])


def _stored_count_or_none(path) -> int | None:
    """:func:`stored_frame_count`, None when the file cannot be read."""
    try:
        return stored_frame_count(path)
    except VideoError:
        return None


def _fps_arg(fps: float) -> str:
    """A frame rate as ffmpeg's exact rational (29.97 -> 30000/1001)."""
    return str(Fraction(float(fps)).limit_denominator(100000))


#: ITU-R BT.601 chroma in limited range (Cb, Cr rows; RGB columns, then the offset), as
#: ffmpeg converts ``rgb24`` to ``yuv420p``.
_BT601_CHROMA = np.array([[-37.797, -74.203, 112.0, 128 * 255.0],
                          [112.0, -93.786, -18.214, 128 * 255.0]]) / 255.0


def _yuv420p(rgb: np.ndarray) -> np.ndarray:
    """The planar 8-bit 4:2:0 frame (Y, then U, then V; ``(3 H / 2, W)`` uint8) of an
    ``(H, W, 3)`` uint8 RGB frame of even size: ITU-R BT.601 in limited range, what ffmpeg's
    ``rgb24`` to ``yuv420p`` conversion gives (Y to within 1 level); each chroma sample is
    that of its 2x2 pixels' mean colour (OpenCV's own I420 takes the top-left pixel's)."""
    import cv2

    H, W = rgb.shape[:2]
    out = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
    mean = cv2.resize(rgb, (W // 2, H // 2), interpolation=cv2.INTER_AREA)
    uv = cv2.transform(mean, _BT601_CHROMA)            # (H/2, W/2, 2) uint8, rounded
    n = H * W
    planes = out.reshape(-1)
    planes[n:n + n // 4] = uv[..., 0].reshape(-1)
    planes[n + n // 4:] = uv[..., 1].reshape(-1)
    return out


def _deep(frame: np.ndarray) -> np.ndarray:
    """A frame as 16-bit samples (8-bit ones as ``v * 257``), little-endian, for ffmpeg's
    ``rgb48le`` / ``rgba64le``."""
    return np.ascontiguousarray(sixteen_bits(frame), dtype="<u2")


class VideoWriter:
    """Write RGB frames to a video (H.264 by default) or an image sequence, atomically.

    Frames are piped to the ffmpeg binary of imageio-ffmpeg (the library's own writer neither
    reports ffmpeg's exit status nor captures its messages, both of which this one needs),
    into a temporary file beside the output (:func:`facetransfer.io.atomic.atomic_path`).
    The audio of ``audio_from`` (copied, or encoded to AAC: :func:`mux_audio`) is written by
    the same ffmpeg process when the number of frames is known beforehand (``n_frames``), else
    muxed in a second pass after the encode.
    :meth:`close` checks ffmpeg's exit status and that the file holds as many frames as were
    written (:func:`stored_frame_count`) and only then renames the file into place; on any
    failure it raises :class:`~facetransfer.errors.VideoError` and an existing
    output is left untouched. An image sequence is written into a temporary folder beside the
    frames and each file is renamed into place at the end (surplus frames of an older, longer
    sequence are removed).

    Parameters
    ----------
    path : path-like
        ``OUT.mp4`` (``.m4v``, ``.mov``, ``.mkv``, ``.avi``) or ``frames/%05d.png``
        (see :func:`check_video_output`).
    fps : float
    size : (width, height)
    options : VideoOptions, optional
    audio_from : path-like, optional
        A media file whose audio goes into the video (none if it has no audio).
    audio_start : float
        Seconds into ``audio_from`` where the audio starts.
    overwrite : bool
        Replace an existing output. When False, one there now is refused, and one another
        run writes meanwhile is kept: this write is refused as it commits (:class:`OutputError`
        for a video, :class:`VideoError` for an image sequence, :func:`place_sequence`).
    n_frames : int, optional
        The frames that will be written. With audio, the audio is then cut to their length and
        encoded while the frames are (one pass); if another number is written, or without it,
        the audio is muxed after the encode.
    detached : bool
        Run ffmpeg in a session of its own: a Ctrl-C in the terminal reaches this process
        only, which may then keep the frames written so far (``close(prefix=True)``; a video
        written in parts, :mod:`facetransfer.io.video_parts`).

    Use as a context manager; the output appears only when the block ends without error.
    """

    def __init__(self, path: str | os.PathLike, fps: float, size: tuple[int, int], *,
                 options: VideoOptions | None = None, audio_from: str | os.PathLike | None = None,
                 audio_start: float = 0.0, overwrite: bool = True,
                 n_frames: int | None = None, detached: bool = False) -> None:
        if not (np.isfinite(fps) and fps > 0):
            raise VideoError(f"frame rate must be positive, got {fps}")
        if len(size) != 2 or min(int(size[0]), int(size[1])) < 1:
            raise VideoError(f"video size must be (width, height) >= 1, got {size}")
        self.output = check_video_output(path, options, overwrite=overwrite)
        self.path, self.options = self.output.path, self.output.options
        self._overwrite = bool(overwrite)
        if audio_from is not None and Path(audio_from).exists() and self.path.exists() \
                and os.path.samefile(audio_from, self.path):
            raise VideoError(f"output {self.path} is also the audio input; choose another --out")
        self.fps, self.size = float(fps), (int(size[0]), int(size[1]))
        self.audio_from, self.audio_start = audio_from, float(audio_start)
        self.n_frames = 0
        self.expected = None if n_frames is None else int(n_frames)
        self._inline_audio = False
        self._detached = bool(detached)
        self.result: WrittenVideo | None = None
        self._proc = None
        self._tmpdir: Path | None = None
        self._atomic = None
        if self.output.kind == "images":
            if audio_from is not None:
                log.info("an image sequence has no audio (%s not used)", audio_from)
            self.path.parent.mkdir(exist_ok=True)
            self._tmpdir = Path(tempfile.mkdtemp(prefix=".frames.", suffix=".part",
                                                 dir=self.path.parent))
            self.stored_size = self.size
        else:
            self._open_ffmpeg()

    def _open_ffmpeg(self) -> None:
        exe = require_encoder(self.options.codec)
        # 4:2:0 codecs get their planes from OpenCV (BT.601 limited range, as ffmpeg's own
        # conversion; chroma the mean of each 2x2 block): half the bytes through the pipe and
        # no scaler in ffmpeg (BENCHMARKS.md, "End to end")
        deep = self.options.deep                 # 16 bits a sample (io.video_depth)
        self._pipe_format = ("rgba64le" if deep else "rgba") if self.options.alpha else \
            "gray16le" if self.options.grey else "rgb48le" if deep else \
            "rgb24" if self.options.codec == "prores" else "yuv420p"
        self.stored_size = _stored_size(self.size, self.options.codec)
        if not self._detached:   # a part of a longer video: the parts' writer warns, once
            warn_if_grown(self.path, self.size, self.options.codec)
        # checked in __init__, and again as it is renamed: another run's since is kept
        self._atomic = atomic_path(self.path, overwrite=self._overwrite)
        self.tmp = self._atomic.__enter__()
        cmd = [exe, "-hide_banner", "-nostdin", "-loglevel", "error", "-y", "-f", "rawvideo",
               "-pix_fmt", self._pipe_format, "-s", "{}x{}".format(*self.stored_size),
               "-framerate", _fps_arg(self.fps), "-i", "-", *self._audio_input(),
               *frame_args(self.options.sar, self.options.primaries, self.options.transfer,
                           self.options.field),
               *_encode_args(self.options, self.path.suffix.lower()),
               "-f", VIDEO_SUFFIXES[self.path.suffix.lower()], str(self.tmp)]
        log.debug("ffmpeg: %s", " ".join(cmd))
        self._stderr = tempfile.TemporaryFile()
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE,
                                          stdout=subprocess.DEVNULL, stderr=self._stderr,
                                          start_new_session=self._detached)
        except OSError as exc:
            self._abort()
            raise VideoError(f"cannot start ffmpeg ({exe}) to write {self.path}: {exc}") from None

    def _audio_input(self) -> list[str]:
        """ffmpeg arguments adding the audio of ``audio_from`` to the encode (one pass): its
        stream from ``audio_start`` on, cut to the promised frames' length; none when the
        number of frames is unknown or the file has no audio (copied or encoded as
        :func:`mux_audio` says)."""
        codecs = () if self.audio_from is None or not self.expected \
            else audio_codecs(self.audio_from)
        if not codecs:
            return []
        self._inline_audio = True
        return audio_input_args(self.audio_from, codecs,
                                 VIDEO_SUFFIXES[self.path.suffix.lower()],
                                 start=self.audio_start, duration=self.expected / self.fps)

    def write(self, frame: np.ndarray) -> None:
        """Append one ``(H, W, 3) uint8`` RGB frame of the writer's size (of a PNG or TIFF
        sequence, ``(H, W, 4)`` RGBA and uint16 too; of a video written with alpha, RGBA; of one
        written in 16 bits (:attr:`VideoOptions.deep`), uint16 too; of an OpenEXR sequence,
        float16 or float32 linear RGB, or an :class:`~facetransfer.io.exr.ExrImage`:
        :func:`facetransfer.io.exr.write_exr`; of a video of a grey codec,
        :attr:`VideoOptions.grey`, ``(H, W) uint16`` only)."""
        if self.result is not None or (self._proc is None and self._tmpdir is None):
            raise VideoError(f"video {self.path} is already closed")
        if self.options.grey:
            self._write_grey(frame)
            return
        if not fits_output(frame.shape, self.size, self.path, self.options.alpha):
            raise VideoError(f"frame of shape {frame.shape} does not match video size "
                             f"{self.size[0]}x{self.size[1]} of {self.path}")
        if self._tmpdir is None and frame.dtype == np.uint16 and not self.options.deep:
            raise VideoError(f"{self.path}: 16-bit frames are written to PNG or TIFF sequences "
                             "(or to ProRes or H.265 with VideoOptions.deep)")
        if self._tmpdir is not None:
            self._write_image(frame if _linear(frame, self.path) or frame.dtype == np.uint16
                              else np.ascontiguousarray(frame, dtype=np.uint8))
            self.n_frames += 1
            return
        img = _deep(frame) if self.options.deep else np.ascontiguousarray(frame, dtype=np.uint8)
        pad = (self.stored_size[1] - self.size[1], self.stored_size[0] - self.size[0])
        if any(pad):
            img = np.pad(img, ((0, pad[0]), (0, pad[1]), (0, 0)), mode="edge")
        if self._pipe_format == "yuv420p":
            img = _yuv420p(img)
        try:
            self._proc.stdin.write(memoryview(img).cast("B"))
        except OSError:  # ffmpeg stopped (full disk, killed...): report why
            raise self._ffmpeg_failed() from None
        self.n_frames += 1

    def _write_grey(self, frame: np.ndarray) -> None:
        """Append one ``(H, W) uint16`` grey frame to a video of a grey codec."""
        if tuple(frame.shape) != (self.size[1], self.size[0]) or frame.dtype != np.uint16:
            raise VideoError(f"{self.path}: {self.options.codec} takes (H, W) uint16 grey "
                             f"frames of {self.size[0]}x{self.size[1]}, got {frame.shape} "
                             f"{frame.dtype}")
        try:
            self._proc.stdin.write(memoryview(np.ascontiguousarray(frame, "<u2")).cast("B"))
        except OSError:  # ffmpeg stopped (full disk, killed...): report why
            raise self._ffmpeg_failed() from None
        self.n_frames += 1

    def _write_image(self, img: np.ndarray) -> None:
        from .plate_header import written_header

        f = self._tmpdir / (self.path.name % self.n_frames)
        try:
            save_frame_image(img, f, header=written_header(
                self.fps, self.options.timecode, self.n_frames, self.options.sar))
        except (OSError, ValueError) as exc:  # full disk, unwritable folder, unknown format
            raise VideoError(f"cannot write frame {f.name} of {self.path}: {exc}") from None

    def _ffmpeg_failed(self) -> VideoError:
        proc, self._proc = self._proc, None
        with contextlib.suppress(OSError):
            proc.stdin.close()
        rc = proc.wait()
        self._stderr.seek(0)
        err = self._stderr.read().decode("utf-8", "replace")
        what = f"cannot write video {self.path} (ffmpeg {exit_cause(rc)})"
        return ffmpeg_error(err, what) if err.strip() else VideoError(what)

    def close(self, *, commit: bool = True, prefix: bool = False,
              counted: bool = True) -> WrittenVideo | None:
        """Finish the output (``commit``) or discard it; returns what was written.

        ``prefix``: a video whose last write may have been cut short (an interrupt in the
        middle of a frame) keeps the whole frames ffmpeg received, one fewer than written at
        most (``n_frames`` is then what the file holds; none: nothing written, None returned).
        ``counted=False``: a video without audio is not read back to count its frames (one
        ffmpeg run, 20-30 ms), for a caller that counts what it is copied into
        (:meth:`facetransfer.io.video_parts.PartsWriter.close`'s last part).

        Raises
        ------
        VideoError
            No frames, ffmpeg failed, the file does not decode to the frames written, or the
            audio could not be muxed. The output is then not written (an old one is kept).
        """
        if self.result is not None or (self._proc is None and self._tmpdir is None):
            return self.result  # written, or already discarded
        try:
            if not commit:
                self._abort()
                return None
            if self.n_frames == 0:
                if prefix:
                    self._abort()
                    return None
                raise VideoError(f"no frames to write to {self.path}")
            self.result = self._commit_images() if self._tmpdir is not None else \
                self._commit_video(prefix, counted)
            return self.result
        except BaseException:
            self._abort()
            raise

    def _commit_video(self, prefix: bool = False, counted: bool = True) -> WrittenVideo | None:
        proc = self._proc
        with contextlib.suppress(OSError):
            proc.stdin.close()
        if proc.wait() != 0:
            raise self._ffmpeg_failed()
        self._proc = None
        if prefix:  # a frame cut short in the pipe is dropped by ffmpeg's raw demuxer
            stored = _stored_count_or_none(self.tmp)
            if not stored or stored > self.n_frames:
                self._abort()
                return None
            self.n_frames = stored
        # the audio went in with the frames when as many were written as promised; else it is
        # muxed now, from the encoded video stream (the frames are counted in the muxed file)
        if self._inline_audio and self.n_frames == self.expected:
            self._check_count()
            audio = True
        else:
            audio = self.audio_from is not None and self._mux()
            if not audio and counted:
                self._check_count()
        atomic, self._atomic = self._atomic, None
        atomic.__exit__(None, None, None)  # rename into place
        self._close_stderr()
        return WrittenVideo(self.path, self.n_frames, self.stored_size, bool(audio))

    def _mux(self) -> bool:
        fd, name = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=".audio.part"
                                    + self.path.suffix, dir=self.path.parent)
        os.close(fd)
        tmp2 = Path(name)
        try:
            try:
                muxed = mux_audio(self.tmp, self.audio_from, tmp2, start=self.audio_start,
                                  duration=self.n_frames / self.fps,
                                  timecode=self.options.timecode)
            except VideoError:
                self._check_count()  # a damaged encode is named as such
                raise
            if not muxed:
                return False
            n = _stored_count_or_none(tmp2)
            if n != self.n_frames:
                self._check_count()  # the encoded file itself is short or damaged
                if n is None:
                    stored_frame_count(tmp2)  # raises: the muxed file cannot be read
                raise VideoError(f"cannot write video {self.path}: with the audio of "
                                 f"{self.audio_from} it holds {n} frames, not "
                                 f"{self.n_frames}")
            os.replace(tmp2, self.tmp)
            return True
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp2.unlink()

    def _check_count(self) -> None:
        """The encoded file holds the frames written (else VideoError)."""
        n = stored_frame_count(self.tmp)
        if n != self.n_frames:
            raise VideoError(f"cannot write video {self.path}: {self.n_frames} frames were "
                             f"written but the file holds {n}")

    def _commit_images(self) -> WrittenVideo:
        place_sequence(self._tmpdir, self.path, self.n_frames,
                       first=self.output.options.first_number or 0, overwrite=self._overwrite)
        self._tmpdir.rmdir()
        self._tmpdir = None
        return WrittenVideo(self.path, self.n_frames, self.size, False, "images")

    def _abort(self) -> None:
        proc, self._proc = self._proc, None
        if proc is not None:
            with contextlib.suppress(OSError):
                proc.kill()
            proc.wait()
            with contextlib.suppress(OSError):
                proc.stdin.close()
        self._close_stderr()
        atomic, self._atomic = self._atomic, None
        if atomic is not None:
            err = VideoError(f"writing {self.path} was abandoned")
            with contextlib.suppress(VideoError):
                atomic.__exit__(VideoError, err, None)
        if self._tmpdir is not None:
            shutil.rmtree(self._tmpdir, ignore_errors=True)
            self._tmpdir = None

    def _close_stderr(self) -> None:
        f = getattr(self, "_stderr", None)
        if f is not None:
            f.close()
            self._stderr = None

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(commit=exc_type is None)


def encode_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, *,
                 options: VideoOptions | None = None,
                 audio_from: str | os.PathLike | None = None, audio_start: float = 0.0,
                 overwrite: bool = True, progress: Callable[[int], None] | None = None,
                 n_frames: int | None = None) -> WrittenVideo:
    """Write an iterable of ``(H, W, 3) uint8`` RGB frames with :class:`VideoWriter`; the size
    is taken from the first frame, and the output is checked before the first frame is made.

    Parameters
    ----------
    progress : callable(int), optional
        Called with 1 per frame written.
    n_frames : int, optional
        How many frames ``frames`` gives (default: its length, when it has one); with audio,
        the audio is then encoded in the same pass (:class:`VideoWriter`).

    Returns
    -------
    WrittenVideo
    """
    check_video_output(path, options, overwrite=overwrite)
    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise VideoError(f"no frames to write to {path}") from None
    if n_frames is None and hasattr(frames, "__len__"):
        n_frames = len(frames)
    with VideoWriter(path, fps, (first.shape[1], first.shape[0]), options=options,
                     audio_from=audio_from, audio_start=audio_start, overwrite=overwrite,
                     n_frames=n_frames) as w:
        for f in itertools.chain([first], it):
            w.write(f)
            if progress is not None:
                progress(1)
    return w.result


def write_video(path: str | os.PathLike, frames, fps: float, *, overwrite: bool = True,
                options: VideoOptions | None = None,
                audio_from: str | os.PathLike | None = None) -> Path:
    """:func:`encode_video` returning only the path."""
    return encode_video(path, frames, fps, options=options, audio_from=audio_from,
                        overwrite=overwrite).path


def write_video_with_audio(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, *,
                           audio_from: str | os.PathLike | None = None, overwrite: bool = False,
                           audio_start: float = 0.0, options: VideoOptions | None = None,
                           n_frames: int | None = None) -> bool:
    """Write frames to ``path`` with the audio of ``audio_from`` when it has some
    (:func:`encode_video`, ``options`` a :class:`VideoOptions`, ``n_frames`` the frames
    ``frames`` gives, when known). Returns whether audio was muxed in."""
    return encode_video(path, frames, fps, options=options, audio_from=audio_from,
                        audio_start=audio_start, overwrite=overwrite, n_frames=n_frames).audio

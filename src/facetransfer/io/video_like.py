"""The options of a video written in place of another (:func:`like_video`): shown at its shape,
in its colour and with its fields, as the video it rewrites was."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

from ..errors import VideoError
from .video import VideoOptions, is_image_pattern, video_info
from .plate_alpha import keeps_alpha, sequence_alpha_kept, sequence_has_alpha, video_has_alpha
from .video_depth import keeps_depth, video_bits
from .video_display import first_field, timecode_of, video_colour
from .video_sequence import is_sequence, open_sequence

log = logging.getLogger(__name__)

__all__ = ["like_video", "plate_colour"]


def like_video(options: VideoOptions | None, video, out=None) -> VideoOptions:
    """``options`` (default :class:`VideoOptions`) for a video that rewrites the video file
    ``video``, to be shown as it is shown (:mod:`facetransfer.io.video_display`): its pixel
    aspect ratio when ``options`` give none (a video of pixels that are not square, e.g.
    512x480 shown 480x480, would otherwise play 7 % wider); colour tags only where ``video``
    names a colour matrix (:func:`~facetransfer.io.video_display.colour_matrix`; without
    one, OpenCV decoded it as BT.601 and players guess alike for both), with its primaries and
    transfer where ``options`` name none and they are those of SDR video (an HDR video is
    warned of once: decoded to 8-bit SDR without tone mapping, and OpenCV decodes
    BT.2020-tagged frames by other coefficients); and of an interlaced video the field shown
    first (H.264 and ProRes; warned of once for H.265, which writes progressive frames). Of an
    image sequence (:mod:`facetransfer.io.video_sequence`) its first frame number, for an
    output sequence numbered as it is, its first frame's header's timecode and pixel aspect
    ratio, and the colour its frames are shown in (:func:`plate_colour`); of a video with a
    start timecode (a camera's, an editor's), that timecode, where ``options`` give none
    (:attr:`VideoOptions.timecode`: the rewrite starts at its first frame). None or not a
    video: ``options`` as they are. A
    ``video`` with an alpha channel is warned of once unless the output ``out`` (given by a
    command that carries alpha) keeps it (:mod:`facetransfer.io.plate_alpha`): an RGBA PNG
    or TIFF plate or a video written as a PNG or TIFF sequence, a video written as ProRes
    (then 4444 with its alpha, :attr:`VideoOptions.alpha`). A video of more than 8 bits
    written as ProRes or H.265 by such a command is written from 16-bit frames, converted by
    its own matrix (:attr:`VideoOptions.deep`, :mod:`facetransfer.io.video_depth`); an HDR
    one then keeps its primaries and transfer (its values are its own outside the face) and
    is not warned of, nor is one written as a 16-bit image sequence; written otherwise (H.264,
    JPEG) by such a command, a deep video is warned of once."""
    from dataclasses import replace

    options = VideoOptions() if options is None else options
    if video is not None and is_sequence(video):
        return _like_sequence(options, video, out)
    if video is None or not Path(video).is_file():
        return options
    try:
        sar = video_info(video).sar
    except VideoError:  # not a video (e.g. a still): square pixels
        return options
    tags = video_colour(video)
    if video_has_alpha(video):
        if out is not None and options.codec == "prores" and not is_image_pattern(out):
            options = replace(options, alpha=True)
        elif out is None or not keeps_alpha(out):
            _warn_alpha(str(video))
    bits = video_bits(video) if out is not None else 8   # carried by this command?
    deep = bits > 8 and keeps_depth(out, video, options.codec)
    if deep and not is_image_pattern(out):   # its depth kept (io.video_depth), its matrix
        options = replace(options, deep=True, matrix=tags.matrix or options.matrix)
    if options.sar is None and sar != (1, 1):
        options = replace(options, sar=sar)
        _warn_square(str(video), sar, out)
    if options.colour_tags and tags.matrix is None:
        options = replace(options, colour_tags=False)
    if bits > 8 and not deep and not tags.beyond_sdr:
        _warn_depth(str(video), bits, _tiff_with_alpha(out, video))
    if tags.beyond_sdr and not deep:   # a command that carries depth could have kept it
        _warn_hdr(str(video), tags, bits > 8)
    elif options.primaries is None and options.transfer is None:
        options = replace(options, primaries=tags.primaries, transfer=tags.transfer)
    if options.timecode is None:
        options = replace(options, timecode=timecode_of(video))
        _warn_timecode(str(video), options.timecode, out)
    field = first_field(video)
    if field is not None and options.field is None:
        if options.codec == "h265":
            _warn_progressive(str(video))
        else:
            options = replace(options, field=field)
    return options


def _like_sequence(options: VideoOptions, video, out) -> VideoOptions:
    """:func:`like_video` of an image sequence ``video``: its first number, timecode, pixel
    aspect ratio and colour (:func:`plate_colour`) where ``options`` give none."""
    from dataclasses import replace

    seq = open_sequence(video)
    if sequence_has_alpha(seq) and not (out is not None and sequence_alpha_kept(out, video)):
        _warn_alpha(str(video), plate=True)
    _warn_exr_channels(seq.file(0), video, out)
    if options.first_number is None:
        options = replace(options, first_number=seq.first)
    if options.timecode is None:          # its first frame's header's (DPX, OpenEXR)
        options = replace(options, timecode=seq.timecode)
        _warn_timecode(str(video), seq.timecode, out)
    if options.sar is None and seq.sar != (1, 1):   # an anamorphic plate's
        options = replace(options, sar=seq.sar)
        _warn_square(str(video), seq.sar, out)
    if options.primaries is None and options.transfer is None:
        primaries, transfer = plate_colour(seq.file(0))
        options = replace(options, primaries=primaries, transfer=transfer)
    return options


#: DPX transfer characteristics (OpenImageIO's names) of Rec.709 video codes.
_DPX_REC709 = ("itu-r 709-4", "smpte 274m")


def plate_colour(first) -> tuple[str | None, str | None]:
    """The primaries and transfer (ffmpeg's names) of the frames read from a plate whose first
    frame is ``first``, for a video written from them to name: an OpenEXR plate's and a DPX
    plate's of log or linear light are shown through the sRGB curve in Rec.709's primaries
    (:mod:`facetransfer.io.exr`, :mod:`facetransfer.io.dpx`; an OpenEXR plate of other
    primaries is brought to them, :mod:`facetransfer.io.primaries`): ``("bt709",
    "iec61966-2-1")``; a DPX plate of Rec.709 video codes is shown as they are: ``("bt709",
    "bt709")``. Any other plate (PNG, TIFF, a DPX of another or no named transfer): nothing
    said, ``(None, None)``."""
    suffix = Path(first).suffix.lower()
    if suffix == ".exr":
        return "bt709", "iec61966-2-1"
    if suffix != ".dpx":
        return None, None
    from .dpx import dpx_header, transfer_kind

    try:
        transfer = dpx_header(first)[1] or ""
    except (OSError, ValueError):
        return None, None
    if transfer_kind(transfer) != "video":
        return "bt709", "iec61966-2-1"
    return ("bt709", "bt709") if transfer.strip().lower() in _DPX_REC709 else (None, None)


@functools.lru_cache(maxsize=16)
def _warn_alpha(video: str, plate: bool = False) -> None:
    """Say once that ``video``'s alpha is not carried into the rewrite, and which outputs
    carry it: a ``plate``'s (an image sequence's) only in image sequences."""
    log.warning("%s has an alpha channel; the result is written without one (colour only; "
                "transfer keeps %s)", video,
                "a plate's in a PNG, TIFF or DPX sequence, not in a video" if plate else
                "a video's in ProRes 4444, --codec prores, and in PNG, TIFF or DPX sequences")


def _warn_exr_channels(first: Path, video, out) -> None:
    """Say once that an OpenEXR plate's channels beyond its colour (alpha, depth: its first
    frame ``first``'s) are not in an output other than OpenEXR."""
    if out is None or first.suffix.lower() != ".exr" or Path(out).suffix.lower() == ".exr":
        return
    from .exr import read_exr_image

    other = tuple(sorted(read_exr_image(first).other))
    if other:
        _warn_exr_channels_once(str(video), ", ".join(other), Path(out).suffix.lower())


@functools.lru_cache(maxsize=16)
def _warn_exr_channels_once(video: str, channels: str, suffix: str) -> None:
    log.warning("%s has channels beyond its colour (%s); a %s result holds the colour only (an "
                ".exr sequence keeps them)", video, channels, suffix)


def _warn_timecode(video: str, timecode, out) -> None:
    """Say once that the output ``out`` holds no start timecode where ``video`` has one: an
    AVI file, a PNG, TIFF, JPEG or BMP sequence (not DPX or OpenEXR)."""
    if out is None or not timecode:
        return
    suffix = Path(out).suffix.lower()
    if suffix == ".avi" or _plain_sequence(out):
        _warn_timecode_once(video, str(timecode), suffix)


@functools.lru_cache(maxsize=16)
def _warn_timecode_once(video: str, timecode: str, suffix: str) -> None:
    log.warning("%s starts at timecode %s; %s files hold none, so the result does not say "
                "where it sits (a .mov, .mp4 or .mkv video, or a .dpx or .exr sequence, "
                "records it)", video, timecode, suffix)


def _warn_square(video: str, sar, out) -> None:
    """Say once that an image sequence ``out`` that stores no pixel aspect ratio (PNG, TIFF,
    JPEG, BMP: not DPX or OpenEXR) holds ``video``'s non-square pixels as square ones."""
    if out is not None and _plain_sequence(out):
        _warn_square_once(video, f"{sar[0]}:{sar[1]}", Path(out).suffix.lower())


def _plain_sequence(out) -> bool:
    """Whether ``out`` is an image sequence of files without a plate's header (PNG, TIFF,
    JPEG, BMP: no timecode, no pixel aspect ratio; DPX and OpenEXR have them)."""
    return is_image_pattern(out) and Path(out).suffix.lower() not in (".dpx", ".exr")


@functools.lru_cache(maxsize=16)
def _warn_square_once(video: str, sar: str, suffix: str) -> None:
    log.warning("%s has pixels %s (not square); %s files store no pixel aspect ratio, so the "
                "frames are written as stored and show stretched unless it is set where they "
                "are read (a .dpx or .exr sequence, or a video, records it)", video, sar, suffix)


@functools.lru_cache(maxsize=16)
def _warn_progressive(video: str) -> None:
    """Say once that an interlaced ``video`` is rewritten as progressive H.265."""
    log.warning("%s is interlaced; x265 writes progressive frames, so players show the "
                "result's fields woven (use --codec h264 or prores to keep them interlaced)",
                video)


@functools.lru_cache(maxsize=16)
def _warn_depth(video: str, bits: int, tiff_alpha: bool = False) -> None:
    """Say once that ``video``'s samples below 8 bits are not carried into the rewrite (a
    TIFF sequence of a video with alpha, ``tiff_alpha``, is what was asked: say why)."""
    log.warning("%s has %d bits a sample; the result is written in 8 (%s)", video, bits,
                "a TIFF sequence with alpha is written in 8 bits; --codec prores, or a PNG or "
                "DPX sequence, keeps them and the alpha" if tiff_alpha else "--codec prores "
                "or h265, or a 16-bit PNG, TIFF or DPX sequence, keeps them")


def _tiff_with_alpha(out, video) -> bool:
    """Whether ``out`` is a TIFF sequence and ``video`` has alpha (written in 8 bits)."""
    return (out is not None and is_image_pattern(out)
            and Path(out).suffix.lower() in (".tif", ".tiff") and video_has_alpha(video))


@functools.lru_cache(maxsize=16)
def _warn_hdr(video: str, tags, keepable: bool = False) -> None:
    """Say once that ``video`` is HDR (or wide-gamut) and read as 8-bit SDR (and, when
    ``keepable``, which outputs would have kept it: :mod:`facetransfer.io.video_depth`)."""
    log.warning("%s is HDR or wide-gamut video (primaries %s, transfer %s): it is decoded to "
                "8-bit SDR without tone mapping, so the result is SDR and looks flatter than "
                "the original does in an HDR player%s", video, tags.primaries, tags.transfer,
                " (--codec h265 or prores, or a 16-bit PNG or TIFF sequence, keeps its 10 bits "
                "and its colour)" if keepable else "")

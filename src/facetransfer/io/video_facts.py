"""What facetransfer sees of a video file, in one place (``facetransfer probe``): its stored and
shown size, its rate and timeline, its fields, colour and audio, and how it is decoded.

Footage from phones, camcorders and archives differs from the data folder's clips in ways that
change what the commands do: pixels that are not square (tracked resampled to square ones),
interlaced fields (decoded by ffmpeg, tracked on the field shown first, written back
interlaced), a variable frame rate (read on a constant-rate timeline), seeks that are not exact
(a container's, or those of frames off their rate's steps: decoded from its start), HDR colour
(decoded to SDR). :func:`video_facts` gathers them from :mod:`facetransfer.io.video_read` and
:mod:`facetransfer.io.video_display`; :func:`fact_lines` says them.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass

from .video_audio import audio_codecs
from .video_display import (ColourTags, container, first_field, shown_width,
                            timecode_of, video_colour)
from .plate_alpha import cmyk_still, sequence_has_alpha, video_has_alpha
from .video_depth import video_bits
from .video_planes import stored_pixel_format
from .video_read import TRUNCATED_FRAMES, seeks_exactly, video_info
from .video_timeline import first_frame_time, packet_count
from .frame_file import bit_depth
from .video_sequence import STILL_SUFFIXES, is_sequence, open_sequence

__all__ = ["VideoFacts", "video_facts", "fact_lines"]


@dataclass(frozen=True)
class VideoFacts:
    """A video file as facetransfer reads it.

    Attributes
    ----------
    path : str
    container : str or None
        ffmpeg's demuxer (``"mov,mp4,m4a,3gp,3g2,mj2"``, ``"mpegts"``, ...).
    size, shown_size : (int, int)
        ``(W, H)`` as read (stored, or turned upright: ``turn``), and as shown (the width
        times the pixel aspect ratio ``sar``).
    sar : (int, int)
        The pixel aspect ratio of the frames as read.
    fps : float
        The constant rate it is read at.
    n_frames : int
        Frames read (for a variable frame rate, the steps of its timeline).
    variable_rate : bool
    seconds : float
    field : {"top", "bottom"} or None
        Interlaced: the field shown first (the one tracked).
    decoder : {"OpenCV", "ffmpeg"}
    exact_seek : bool
        OpenCV's seek lands on the frame asked (else reading from a later frame decodes the
        frames before it).
    colour : ColourTags
    audio : str or None
        The audio streams' codecs, comma-separated (every one is kept in a rewrite).
    first_number : int or None
        An image sequence's first frame number (its container is ``"image sequence"``); None
        for a video file.
    turn : int
        Degrees clockwise the display matrix turns the stored pictures (the frames are read
        turned, as players show them): :attr:`facetransfer.io.video_read.VideoInfo.turn`.
    timecode : str or None
        Its start timecode (:func:`facetransfer.io.video_display.timecode_of`), which the
        results that rewrite it carry.
    alpha : bool
        It has an alpha channel (:mod:`facetransfer.io.plate_alpha`: kept where the output
        holds it).
    bits : int
        Its bits a sample: an image sequence's (16: kept in a PNG or TIFF sequence,
        :mod:`facetransfer.io.plate_depth`), a video's as ffmpeg decodes it (more than 8: kept
        in ProRes or a PNG or TIFF sequence, :mod:`facetransfer.io.video_depth`).
    rate_from : str or None
        Where an image sequence's rate came from (``"said"``, ``"header"``, ``"default"``:
        :attr:`facetransfer.io.video_sequence.Sequence.rate_from`); None for a video file.
    stored_frames : int or None
        A video file's frames as its packets count them (:func:`facetransfer.io.
        video_timeline.packet_count`, read once with its timeline): fewer than
        ``n_frames`` in a file cut short (said, as :func:`facetransfer.io.video.read_video`
        says it); None where not counted.
    pixel_format : str or None
        A video file's (or still's) pixel format as ffmpeg names it (``"yuvj420p"``,
        ``"gray"``, ``"pal8"``, ``"rgba"``): what a still's colour line says it stores
        (:func:`_still_colour`); None for an image sequence or without ffmpeg.
    """

    path: str
    container: str | None
    size: tuple[int, int]
    shown_size: tuple[int, int]
    sar: tuple[int, int]
    fps: float
    n_frames: int
    variable_rate: bool
    seconds: float
    field: str | None
    decoder: str
    exact_seek: bool
    colour: ColourTags
    audio: str | None
    first_number: int | None = None
    turn: int = 0
    timecode: str | None = None
    alpha: bool = False
    bits: int = 8
    rate_from: str | None = None
    stored_frames: int | None = None
    pixel_format: str | None = None
    picture_start: float = 0.0
    mirrored: bool = False

    def as_dict(self) -> dict:
        """The facts as JSON-ready values (the colour tags a dict of their own)."""
        return asdict(self)


def video_facts(path: str | os.PathLike) -> VideoFacts:
    """The :class:`VideoFacts` of a video file or image sequence (VideoError for a missing or
    unreadable one)."""
    info = video_info(path)
    W, H = info.size
    if is_sequence(path):
        seq = open_sequence(path)
        return VideoFacts(str(path), "image sequence", (W, H), (shown_width(W, info.sar), H),
                          info.sar, float(info.fps),
                          int(info.n_frames), False, float(info.n_frames / info.fps), None,
                          "OpenImageIO" if str(path).lower().endswith(".dpx") else "OpenCV", True,
                          ColourTags(), None, seq.first, timecode=seq.timecode,
                          alpha=sequence_has_alpha(seq), bits=bit_depth(seq.file(0)) or 8,
                          rate_from=seq.rate_from)
    return VideoFacts(str(path), container(path), (W, H), (shown_width(W, info.sar), H),
                      info.sar, float(info.fps),
                      int(info.n_frames), info.steps is not None,
                      float(info.n_frames / info.fps) if info.fps else 0.0, first_field(path),
                      "ffmpeg" if info.piped else "OpenCV", seeks_exactly(path, info.fps),
                      video_colour(path), ", ".join(audio_codecs(path)) or None, turn=info.turn,
                      timecode=timecode_of(path), alpha=video_has_alpha(path),
                      bits=video_bits(path), stored_frames=packet_count(path),
                      pixel_format=stored_pixel_format(path),
                      picture_start=first_frame_time(path) if audio_codecs(path) else 0.0,
                      mirrored=info.mirrored)


def fact_lines(f: VideoFacts) -> list[str]:
    """The facts as a few lines for a person, with what each means for the commands."""
    size = "{}x{}".format(*f.size)
    if f.turn or f.mirrored:
        stored = f.size if f.turn in (0, 180) else f.size[::-1]
        how = f"turned {f.turn} degrees clockwise" if f.turn else ""
        how += (" and " if f.turn else "") + "mirrored" if f.mirrored else ""
        size += (" upright (stored {}x{}, {} by its display matrix as players show it; "
                 "results written upright)").format(*stored, how)
    if f.shown_size != f.size:
        size += ("{}, shown {}x{} (pixels {}:{}: tracked resampled to square pixels, "
                 "results written with the same ratio)").format(
                     " stored" if f.turn == 0 else "", *f.shown_size, *f.sar)
    rate = f"{f.fps:.3f}".rstrip("0").rstrip(".")
    timing = f"{rate} fps, {f.n_frames} frame{'s' if f.n_frames != 1 else ''}, " \
        f"{f.seconds:.1f} s" if f.n_frames > 0 else \
        f"{rate} fps, its frame count not in its header (a still image?)"
    if f.variable_rate:
        timing += " (variable frame rate: read on this constant-rate timeline)"
    short = None if f.variable_rate or f.stored_frames is None else \
        f.n_frames - f.stored_frames        # a variable rate's timeline repeats frames
    if short is not None and short >= max(TRUNCATED_FRAMES, 0.02 * f.n_frames):
        timing += f"; the file holds {f.stored_frames} of them (cut short?)"
    fields = "progressive" if f.field is None else \
        (f"interlaced, {f.field} field first (decoded by {f.decoder}, tracked on that field, "
         "results written interlaced)")
    named = (f.colour.matrix, f.colour.primaries, f.colour.transfer)
    colour = "colour not named (read as BT.601)" if not any(named) else \
        "colour {} (matrix/primaries/transfer)".format("/".join(x or "?" for x in named)) + \
        (": HDR or wide gamut, decoded to 8-bit SDR" + (" (kept by a 10-bit output)"
                                                          if f.bits > 8 else "")
         if f.colour.beyond_sdr else "")
    reading = f"read by {f.decoder}; " + ("seeks exact" if f.exact_seek else
                                          "seeks not exact: a later frame is reached by "
                                          "decoding the ones before it")
    if f.first_number is not None:
        last = f.first_number + f.n_frames - 1
        return [f"{f.path}: {size}",
                f"  image sequence, frames {f.first_number}-{last}; read at {timing} "
                f"({_RATE_FROM[f.rate_from or 'default']})" + (
                    "" if f.timecode is None else
                    f"; timecode {f.timecode} (the results start at it)"),
                (f"  {_exr_kind(f)}" if str(f.path).lower().endswith(".exr") else
                 f"  {_dpx_kind(f)}" if str(f.path).lower().endswith(".dpx") else
                 f"  {_image_kind(f)}; no audio")]
    if f.n_frames <= 1 and os.path.splitext(str(f.path))[1].lower() in STILL_SUFFIXES:
        return [f"{f.path}: {size}", "  a still image: tracked as a clip of one frame; as a "
                "transfer's target, held over its expression source's frames",
                f"  {_still_colour(f)}; "
                f"{_depth_words(f) if f.bits > 8 else 'no audio'}"]
    return [f"{f.path}: {size}", f"  {timing}; {fields}",
            f"  {colour}; audio {f.audio or 'none'}" + _lead_words(f) + (
                "" if f.timecode is None else
                f"; timecode {f.timecode} (the results start at it)"),
            f"  container {f.container or '?'}; {reading}"] + (
                [f"  {f.bits} bits a sample, seen in 8: kept by transfer in ProRes or H.265 "
                 "(--codec prores or h265: 10 bits, an HDR video's colour too) or a 16-bit "
                 + ("PNG or DPX sequence (a TIFF one is 8-bit, with the alpha)" if f.alpha else
                    "PNG, TIFF or DPX sequence")] if f.bits > 8 else []) + (
                ["  alpha plane: kept by transfer in ProRes 4444 (--codec prores) or a PNG, "
                 "TIFF or DPX sequence"] if f.alpha else [])


def _lead_words(f: VideoFacts) -> str:
    """What :attr:`VideoFacts.picture_start` means, said where it is 10 ms or more."""
    if f.picture_start < 0.01 or not f.audio:
        return ""
    return (f" (starting {f.picture_start:.2f} s before the picture: results take it from the "
            "picture's first frame)")


#: A still's colour tags as ffmpeg names them, in words (:func:`_still_colour`).
_STILL_MATRIX = {"bt470bg": "BT.601", "smpte170m": "BT.601", "bt709": "BT.709"}
_STILL_WORDS = {"bt709": "Rec.709", "iec61966-2-1": "sRGB", "bt2020": "Rec.2020",
                "smpte432": "Display P3", "arib-std-b67": "HLG", "smpte2084": "PQ"}
#: The formats whose stills store YCbCr, by suffix (said as "as JPEG stores it").
_YCBCR_STILLS = {".jpg": "JPEG", ".jpeg": "JPEG", ".webp": "WebP"}


def _still_colour(f: VideoFacts) -> str:
    """A still image's colour in words: how its pixels are stored (:func:`_still_stored`),
    and its primaries and curve, or that it tags neither and is taken as sRGB (before:
    ffmpeg's ``gbr/?/? (matrix/primaries/transfer)``)."""
    c = f.colour
    if c.primaries is None and c.transfer is None:
        tags = "primaries and curve not tagged (taken as sRGB)"
    else:
        untagged = "not tagged (taken as sRGB's)"
        tags = "primaries {}, curve {}".format(
            _STILL_WORDS.get(c.primaries, c.primaries) if c.primaries else untagged,
            _STILL_WORDS.get(c.transfer, c.transfer) if c.transfer else untagged)
    hdr = ": HDR or wide gamut, seen as 8-bit SDR" if c.beyond_sdr else ""
    return f"colour {_still_stored(f)}, {tags}{hdr}"


def _still_stored(f: VideoFacts) -> str:
    """How a still stores its pixels, by its pixel format (``f.pixel_format``; without one,
    by its matrix tag): grey (a grey JPEG too, which holds no chroma), a palette of RGB, CMYK
    (a JPEG of four channels, as ffmpeg's ``gbrap``: its fourth is black, not alpha), YCbCr
    (JPEG's and lossy WebP's BT.601), else RGB, with an alpha plane where it has one."""
    fmt, c = f.pixel_format or "", f.colour
    suffix = os.path.splitext(str(f.path))[1].lower()
    alpha = " with alpha" if f.alpha else ""
    if fmt.startswith(("gray", "ya", "mono")):
        return f"grey{alpha}, read as RGB"
    if fmt == "pal8":
        return "RGB from a palette"
    if cmyk_still(f.path, fmt):
        return "stored as CMYK, read as RGB"
    if fmt.startswith("yuv") or (not fmt and c.matrix not in (None, "gbr")):
        how = _STILL_MATRIX.get(c.matrix, c.matrix or "matrix not tagged")
        if suffix in _YCBCR_STILLS and c.matrix in ("bt470bg", "smpte170m"):
            how += f", as {_YCBCR_STILLS[suffix]} stores it"
        return f"stored as YCbCr{' with alpha' if fmt.startswith('yuva') else ''} ({how}), " \
               "read as RGB"
    return f"RGB{alpha}"


#: How ``probe`` says where an image sequence's rate came from.
_RATE_FROM = {"said": "as --sequence-fps says",
              "header": "its frames' headers' rate; --sequence-fps gives another",
              "default": "it stores no rate: --sequence-fps gives it"}


def _exr_kind(f: VideoFacts) -> str:
    """What an OpenEXR plate's frames hold: their primaries where not Rec.709's
    (:mod:`facetransfer.io.primaries`), and what a rewrite keeps."""
    from .exr import read_exr_image
    from .primaries import named_chromaticities

    image = read_exr_image(open_sequence(f.path).file(0))
    primaries = ""
    if image.to_rec709 is not None:
        import OpenEXR

        chroma = named_chromaticities(image.header)
        name = getattr(OpenEXR, "chromaticitiesToColorInteropID", lambda _: None)(chroma)
        primaries = (f" in the primaries {name or 'its header names'} (brought to Rec.709's "
                     "first)")
    other = (f" and its other channels ({', '.join(sorted(image.other))}; only an .exr "
             "output holds them)" if image.other else "")
    return (f"OpenEXR, scene-linear{primaries}: shown through the sRGB curve (above 1 as "
            "white) to be tracked; a rewrite written as .exr keeps every float it does not "
            f"change{other}; no audio")


def _dpx_kind(f: VideoFacts) -> str:
    """What a DPX plate's frames hold (:func:`facetransfer.io.dpx.dpx_summary`)."""
    from .dpx import dpx_summary

    return dpx_summary(open_sequence(f.path).file(0))


def _image_kind(f: VideoFacts) -> str:
    """What an image sequence's frames hold and what a rewrite keeps of it."""
    return f"RGB images, {_depth_words(f)}"


def _depth_words(f: VideoFacts) -> str:
    """An image's bits and alpha and what a rewrite keeps of them (a still's line says its
    colour apart, :func:`_still_colour`: not "RGB images" for a grey one)."""
    depth = f"16 bits, seen in 8 ({_deep_kept(f)})" if f.bits == 16 else f"{f.bits} bits"
    alpha = ("; alpha: kept by transfer in a PNG, TIFF or DPX sequence" if f.alpha else "")
    return f"{depth}{alpha}"


def _deep_kept(f: VideoFacts) -> str:
    """Which sequences written from a 16-bit plate stay 16-bit (:func:`facetransfer.io.
    plate_depth.plate_depth`): with alpha, a PNG plate's PNG or DPX ones, else none."""
    if not f.alpha:
        return "a PNG, TIFF or DPX sequence written from it stays 16-bit"
    if str(f.path).lower().endswith(".png"):
        return "a PNG or DPX sequence written from it stays 16-bit, with its alpha; a TIFF one " \
               "is 8-bit"
    return "a sequence written from it is 8-bit, with its alpha"

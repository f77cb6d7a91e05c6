"""The alpha channel of a target carried into its rewrite: an RGBA PNG, TIFF or DPX plate (as
a compositing package or a keyer writes one) written as a PNG, TIFF or DPX sequence, and a
video with alpha (ProRes 4444, QuickTime PNG or Animation) written as ProRes 4444 (``--codec
prores``) or as a PNG, TIFF or DPX sequence. Each output frame is the rewritten colour with
the target frame's own alpha, unchanged (rounded to 8 bits).

The colour goes back as it was read: straight, beside the same alpha. A PNG's colour is
straight by its specification; a TIFF's is when its alpha is unassociated (what Pillow and
most tools write; :func:`facetransfer.io.frame_file.tiff_alpha_kind`), read as stored
(not through OpenCV, which premultiplies it); a video's colour is decoded apart from its alpha
plane. A TIFF with associated alpha (its colour stored premultiplied) keeps only its colour.
An OpenEXR plate keeps its alpha by :mod:`facetransfer.io.exr_plate`, a DPX plate written
as DPX by :mod:`facetransfer.io.dpx_plate`. Every other output
(H.264, H.265, JPEG) is written colour only (:func:`facetransfer.io.video_like.like_video`
says so).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import VideoError
from .dpx import dpx_header, read_dpx_image
from .frame_file import eight_bits, read_unchanged, tiff_alpha, tiff_alpha_kind, tiff_mode
from .video_planes import DecodedPlanes, stored_pixel_format
from .video_sequence import is_sequence, open_sequence

__all__ = ["ALPHA_SUFFIXES", "PlateAlpha", "VideoAlpha", "cmyk_still", "image_alpha",
           "keeps_alpha", "plate_alpha", "sequence_alpha_kept", "sequence_has_alpha",
           "video_has_alpha"]

#: Image-sequence outputs whose frames hold an alpha channel (RGBA, straight) and plates whose
#: alpha is carried into them (a DPX plate's: into DPX, by :mod:`facetransfer.io.dpx_plate`).
ALPHA_SUFFIXES = (".png", ".tif", ".tiff", ".dpx")


def _has_alpha(img: np.ndarray | None) -> bool:
    return img is not None and img.ndim == 3 and img.shape[2] in (2, 4)


def image_alpha(file) -> np.ndarray | None:
    """The alpha channel of an image file as stored, ``(H, W)`` uint8 or uint16 (of grey +
    alpha or RGBA, as OpenCV reads it), or None: the file has none, or OpenCV cannot read it."""
    return _stored_alpha(file, read_unchanged(file))


def _stored_alpha(file, img: np.ndarray | None) -> np.ndarray | None:
    """The alpha of ``file`` read by OpenCV as ``img`` (IMREAD_UNCHANGED), or None, where the
    file holds one: not a CMYK TIFF's, which OpenCV gives as BGRA with an opaque alpha the file
    does not hold (a blend's PNG gained it), and an 8-bit grey + alpha TIFF's, which OpenCV
    drops, read as stored (before: lost without a word)."""
    mode = tiff_mode(Path(file))
    if mode == "CMYK":
        return None
    if mode == "LA" and img is not None and not _has_alpha(img):
        return tiff_alpha(Path(file))
    return img[..., -1] if _has_alpha(img) else None


def sequence_has_alpha(seq) -> bool:
    """Whether an image sequence's first frame has an alpha channel (grey + alpha or RGBA, of
    a PNG or TIFF; RGBA of a DPX; not looked for in OpenEXR frames, whose channels
    :mod:`facetransfer.io.exr_plate` keeps)."""
    f = seq.file(0)
    if f.suffix.lower() == ".dpx":
        return dpx_header(f)[2] == 4
    return f.suffix.lower() != ".exr" and _stored_alpha(f, read_unchanged(f)) is not None


#: ffmpeg's pixel formats that carry an alpha plane (ProRes 4444, PNG, QuickTime RLE, VP9).
_ALPHA_FORMATS = re.compile(r"(yuva|rgba|bgra|argb|abgr|gbrap|ya8|ya16|rgba64|bgra64)")


def cmyk_still(path, fmt: str | None) -> bool:
    """Whether ``fmt``, the pixel format ffmpeg gives the file ``path``, is that of a CMYK JPEG:
    ``gbrap`` (or ``cmyk``) of a ``.jpg``/``.jpeg``, whose fourth channel is black, not alpha."""
    return bool(fmt and fmt.startswith(("gbrap", "cmyk"))
                and Path(path).suffix.lower() in (".jpg", ".jpeg"))


def video_has_alpha(video) -> bool:
    """Whether a video file's first video stream stores an alpha plane (its pixel format as
    ffmpeg describes it; a CMYK JPEG's fourth channel is black: :func:`cmyk_still`)."""
    fmt = stored_pixel_format(video)
    return bool(fmt and _ALPHA_FORMATS.match(fmt)) and not cmyk_still(video, fmt)


def keeps_alpha(out) -> bool:
    """Whether the output ``out`` holds alpha: an image sequence of :data:`ALPHA_SUFFIXES`."""
    p = Path(out)
    return "%" in p.name and p.suffix.lower() in ALPHA_SUFFIXES


class PlateAlpha:
    """``alpha(i, shown, rewritten)``: output frame ``i`` (the rewrite of the plate's frame
    ``i``) as ``(H, W, 4) uint8`` RGBA, the rewritten colour with the plate frame's alpha
    (16-bit alpha rounded to 8 bits; a frame without alpha, opaque).

    Parameters
    ----------
    plate : path-like
        The plate's pattern (``plate/sh010.%04d.png``).
    """

    #: What the output keeps of the plate (the transfer's summary line says it).
    kept = "with the plate's alpha"

    def __init__(self, plate) -> None:
        self.sequence = open_sequence(plate)

    def alpha(self, i: int) -> np.ndarray:
        """``(H, W) uint8``: the alpha of the plate's frame ``i`` (a DPX one's codes scaled to
        8 bits, rounded)."""
        f = self.sequence.file(i)
        if f.suffix.lower() == ".dpx":
            dpx = read_dpx_image(f)
            if dpx.codes.shape[2] != 4:
                return np.full(dpx.codes.shape[:2], 255, np.uint8)
            top = (1 << dpx.bits) - 1
            return ((dpx.codes[..., 3].astype(np.uint32) * 510 + top) // (2 * top)).astype(
                np.uint8)
        img = read_unchanged(f)
        if img is None:
            raise VideoError(f"cannot read frame {f} of the plate {self.sequence.pattern}")
        a = _stored_alpha(f, img)
        if a is None:
            return np.full(img.shape[:2], 255, np.uint8)
        return eight_bits(a) if a.dtype == np.uint16 else a

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
        """Output frame ``i`` (``shown``, the plate's frame as read, is not needed: the alpha is
        read from its file)."""
        return _beside(rewritten, self.alpha(i), f"frame {self.sequence.file(i)} of the plate")


class VideoAlpha:
    """``alpha(i, shown, rewritten)`` of a video with an alpha plane, as :class:`PlateAlpha`:
    output frame ``i`` as ``(H, W, 4) uint8``, the rewritten colour with the alpha of the
    video's stored frame ``i`` (ffmpeg's ``alphaextract``, 16 bits rounded to 8;
    :class:`facetransfer.io.video_planes.DecodedPlanes`).

    Parameters
    ----------
    video : path-like
    start : int
        The first frame that will be asked for.
    """

    #: What the output keeps of the video (the transfer's summary line says it).
    kept = "with the target's alpha"

    def __init__(self, video, start: int = 0) -> None:
        self.video = Path(video)
        self._planes = DecodedPlanes(video, "gray16le", "the alpha of", filters="alphaextract",
                                     start=start)

    def alpha(self, i: int) -> np.ndarray:
        """``(H, W) uint8``: the alpha of the video's frame ``i`` (``i`` at least ``start``,
        each asked for once)."""
        return eight_bits(self._planes.frame(i)[..., 0])

    def close(self) -> None:
        """Stop the decoder (also when not every frame was asked for)."""
        self._planes.close()

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
        """Output frame ``i`` (``shown`` is not needed)."""
        return _beside(rewritten, self.alpha(i), f"the alpha of {self.video}")


def _beside(rewritten: np.ndarray, a: np.ndarray, what: str) -> np.ndarray:
    """``(H, W, 4) uint8``: the rewritten colour with the alpha ``a`` (H, W); VideoError
    naming ``what`` the alpha is when it is of another size."""
    rgb = np.asarray(rewritten, np.uint8)
    if a.shape != rgb.shape[:2]:
        raise VideoError(f"{what} is {a.shape[1]}x{a.shape[0]}, the rewrite "
                         f"{rgb.shape[1]}x{rgb.shape[0]}")
    return np.dstack([rgb, a])


def sequence_alpha_kept(out, plate) -> bool:
    """Whether the alpha of the image-sequence plate ``plate`` is carried into the output
    ``out``: both hold alpha (:func:`keeps_alpha`), and a TIFF plate's is straight (an
    associated one, whose colour is stored premultiplied, would not match the straight alpha
    the output is written with: :func:`facetransfer.io.frame_file.tiff_alpha_kind`). The plate
    may be named either way (``%04d`` or ``####``)."""
    if not (keeps_alpha(out) and is_sequence(plate)
            and Path(plate).suffix.lower() in ALPHA_SUFFIXES):
        return False
    return tiff_alpha_kind(open_sequence(plate).file(0)) != "premultiplied"


def plate_alpha(out, target, options=None, start: int = 0):
    """The alpha of the target ``target`` for the rewrite written as ``out`` with the video
    options ``options``: a :class:`PlateAlpha` when ``out`` keeps alpha (:func:`keeps_alpha`)
    and ``target`` is a sequence of the same kind whose first frame has it
    (:func:`sequence_has_alpha`); a :class:`VideoAlpha` (from frame ``start`` on) of a video
    target with alpha written as a PNG sequence, or when ``options`` ask for it
    (:attr:`~facetransfer.io.video_options.VideoOptions.alpha`, set by
    :func:`~facetransfer.io.video_like.like_video` for one written as ProRes); else None."""
    if target is None:
        return None
    if not is_sequence(target):   # a video: written as ProRes 4444, or as a PNG sequence
        carried = getattr(options, "alpha", False) or (keeps_alpha(out)
                                                       and video_has_alpha(target))
        return VideoAlpha(target, start) if carried else None
    if not sequence_alpha_kept(out, target):
        return None
    return PlateAlpha(target) if sequence_has_alpha(open_sequence(target)) else None

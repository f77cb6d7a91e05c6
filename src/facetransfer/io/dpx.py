"""DPX plates (SMPTE ST 268): frames of 8 to 16-bit code values shown to the tracker as 8-bit
RGB, and a rewritten plate that keeps every code value the rewrite did not change.

Film scans and grading suites hand plates over as DPX sequences (``plate/sh010.%04d.dpx``),
most often 10 bits a sample. What a code value means is in the file's header, its *transfer
characteristic*:

- **printing density** or **logarithmic** (a film scan, Cineon log): the code ``c`` (in 10-bit
  units) is density, ``0.002`` a code, and light ``10 ** ((c - 685) * 0.002 / 0.6)`` relative
  to the white point, with code 95 black and code 685 white (Kodak's Cineon conventions:
  negative gamma 0.6, :data:`LOG_BLACK`, :data:`LOG_WHITE`): shown as that light, black
  subtracted, through the sRGB curve (:func:`facetransfer.io.exr.srgb_encode`; above white as
  white);
- **linear**: the code over its maximum is linear light, shown through the sRGB curve;
- any other (the video ones, ITU-R 709, SMPTE 274M, user-defined, unspecified): the code's
  place between black and white is the display value itself: full range, or between the
  header's reference low and high data codes where it gives them (video levels: 64 and 940 in
  10 bits; beyond them, as black and as white).

A rewrite written as DPX (``--out out/sh010_ft.%04d.dpx``) of a DPX plate goes back to the
plate's code values as :mod:`facetransfer.io.exr` goes back to an OpenEXR plate's floats: a
pixel the rewrite left unchanged (everything outside the face) is the plate's code, to the
bit; a changed one is the code of the rewritten level plus the plate's part below a level,
kept among the codes shown as the rewritten level, or where a channel lies beyond what is
shown (a log plate above white or below black) the code of the rewritten level alone
(:func:`graded_codes`); in the plate's bit depth, with its header
(timecode, transfer, film and television fields) and its alpha as they were. Of any other
target, a DPX frame holds the rewritten 8-bit RGB (or RGBA) as 10-bit code values of a video
transfer (ITU-R 709); a deep target's values (:mod:`facetransfer.io.plate_depth`), 16-bit.
The plate's frames are graded by :mod:`facetransfer.io.dpx_plate`. Files are read and written
by OpenImageIO (the Academy Software Foundation's
image library): RGB, RGBA or luma, 8, 10, 12 or 16 bits, the first image element.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import VideoError
from .exr import _curve

__all__ = ["DPX_SUFFIX", "LOG_BLACK", "LOG_WHITE", "DpxImage", "is_dpx", "read_dpx_image",
           "dpx_header", "dpx_summary",
           "shown_dpx", "write_dpx", "graded_codes", "transfer_kind"]

DPX_SUFFIX = ".dpx"
#: Kodak's Cineon conventions for a log plate, in 10-bit codes: black, white, density a code,
#: and the negative's gamma.
LOG_BLACK, LOG_WHITE, LOG_DENSITY, LOG_GAMMA = 95.0, 685.0, 0.002, 0.6
#: The header's transfer characteristics (OpenImageIO's names) read as log and as linear.
_LOG = ("printing density", "logarithmic")
_LINEAR = ("linear",)
_MAGICS = (b"SDPX", b"XPDS")


def is_dpx(path) -> bool:
    """Whether ``path`` (a file or a sequence's pattern) names DPX frames."""
    return Path(path).suffix.lower() == DPX_SUFFIX


def transfer_kind(transfer: str) -> str:
    """``"log"``, ``"linear"`` or ``"video"`` for a DPX header's transfer characteristic."""
    t = transfer.strip().lower()
    return "log" if t in _LOG else "linear" if t in _LINEAR else "video"


@dataclass(frozen=True, eq=False)
class DpxImage:
    """A DPX frame: its code values, and the rest of the file as it was.

    Attributes
    ----------
    codes : (H, W, C) uint16
        Code values of ``bits`` bits (0 to ``2**bits - 1``); C is 1 (luma), 3 (RGB) or 4
        (RGBA).
    bits : int
        Bits a sample.
    transfer : str
        The header's transfer characteristic (``"Printing density"``, ``"ITU-R 709-4"`` ...).
    spec : OpenImageIO.ImageSpec or None
        The file's description, written back with the codes (None: made here).
    """

    codes: np.ndarray
    bits: int
    transfer: str
    spec: object = None

    @property
    def shape(self) -> tuple[int, int, int]:
        """The frame's shape as RGB, ``(H, W, 3)`` (what a writer checks)."""
        return self.codes.shape[0], self.codes.shape[1], 3

    @property
    def dtype(self) -> np.dtype:
        return self.codes.dtype

    @property
    def kind(self) -> str:
        """:func:`transfer_kind` of :attr:`transfer`."""
        return transfer_kind(self.transfer)

    @property
    def coding(self) -> tuple[str, int, int, int]:
        """``(kind, bits, low, high)``: how a code is shown; ``low`` and ``high`` the codes of
        black and white of a video transfer (the header's reference low and high data codes
        where it gives a range within the bits, e.g. 64 and 940 of a 10-bit plate of video
        levels; else 0 and the largest code)."""
        top = (1 << self.bits) - 1
        low = high = None
        if self.spec is not None and self.kind == "video":
            low = self.spec.getattribute("dpx:LowData")
            high = self.spec.getattribute("dpx:HighData")
        if not (isinstance(low, int) and isinstance(high, int) and 0 <= low < high <= top):
            low, high = 0, top
        return self.kind, self.bits, low, high

    def rgb(self) -> np.ndarray:
        """``(H, W, 3)`` uint16 codes of the colour (luma repeated, alpha left out)."""
        c = self.codes
        return np.repeat(c, 3, axis=2) if c.shape[2] == 1 else c[..., :3]

    def with_rgb(self, rgb: np.ndarray) -> "DpxImage":
        """This image with the colour codes ``rgb`` (H, W, 3) uint16 (of a luma image, the
        first channel), its alpha and header as they were."""
        codes = self.codes.copy()
        if codes.shape[2] == 1:
            codes[..., 0] = rgb[..., 0]
        else:
            codes[..., :3] = rgb
        return DpxImage(codes, self.bits, self.transfer, self.spec)


def read_dpx_image(path) -> DpxImage:
    """A DPX file as :class:`DpxImage`: its pixels as OpenImageIO reads them, or, where it
    reads a layout wrong (:func:`_unpacked_here`), from the file's bytes here.

    Raises
    ------
    VideoError
        Not a DPX file, damaged, of samples other than 8, 10, 12 or 16 bits, or of another
        layout than luma, RGB or RGBA (naming the file).
    """
    import OpenImageIO as oiio

    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise VideoError(f"cannot read the DPX frame {path} ({exc.strerror})") from None
    if magic not in _MAGICS:
        raise VideoError(f"cannot read the DPX frame {path} ({Path(path).name} is not a DPX "
                         "file)")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise VideoError(f"cannot read the DPX frame {path} ({_why(oiio.geterror())})")
    try:
        spec = oiio.ImageSpec(inp.spec())
        bits = int(spec.get_int_attribute("oiio:BitsPerSample", 16)) or 16
        own = _unpacked_here(path, spec, bits)
        px = None if own is not None or bits not in (8, 10, 12, 16) or \
            spec.nchannels not in (1, 3, 4) else inp.read_image(0, 0, 0, spec.nchannels, "uint16")
        why = inp.geterror()
    finally:
        inp.close()
    if bits not in (8, 10, 12, 16):
        raise VideoError(f"cannot read the DPX frame {path} ({bits}-bit samples: 8, 10, 12 "
                         "and 16-bit codes are read; write the plate as 16-bit DPX or OpenEXR)")
    if own is None and not isinstance(px, np.ndarray):
        raise VideoError(f"cannot read the DPX frame {path} (" + (
            f"damaged: {_why(why)})" if why else
            f"{spec.nchannels} channels; luma, RGB or RGBA is read)"))
    codes = own() if own is not None else \
        _to_codes(px.reshape(spec.height, spec.width, spec.nchannels), bits)
    return DpxImage(codes, bits, spec.get_string_attribute("dpx:Transfer", ""), spec)


def _unpacked_here(path, spec, bits: int):
    """The reader of the codes of a layout OpenImageIO 3.2 reads wrong, ``() -> (H, W, C)
    uint16``, or None: 10-bit samples filled three to a word (method A) in rows of a number of
    samples not divisible by three (an RGBA frame of even width: its last sample of a row
    misread), and 8 or 16-bit lines that end on a 32-bit word (as ffmpeg writes them, and as
    the file's size then says; OpenImageIO's own files' lines end on their last sample)."""
    shape = (spec.height, spec.width, spec.nchannels)
    if spec.nchannels not in (1, 3, 4):
        return None
    if bits == 10 and (spec.width * spec.nchannels) % 3 and \
            spec.get_string_attribute("dpx:Packing", "").startswith("Filled, method A"):
        return lambda: _filled_10(path, shape, spec)
    line = spec.width * spec.nchannels * bits // 8
    if bits not in (8, 16) or line % 4 == 0:
        return None
    _, offset = _pixel_offset(path)
    size = Path(path).stat().st_size
    if not 0 < offset <= size or size - offset < (line + 3) // 4 * 4 * spec.height:
        return None
    return lambda: _word_lines(path, shape, bits)


def _word_lines(path, shape: tuple[int, int, int], bits: int) -> np.ndarray:
    """The ``shape`` (H, W, C) codes of an 8 or 16-bit file whose lines end on a 32-bit word,
    from its bytes."""
    h, w, c = shape
    raw = Path(path).read_bytes()
    order, offset = _pixel_offset(path, raw[:8])
    line = w * c * bits // 8
    stride = (line + 3) // 4 * 4
    rows = np.frombuffer(raw, np.uint8, count=stride * h, offset=offset).reshape(h, stride)
    rows = rows[:, :line]
    if bits == 16:
        rows = np.ascontiguousarray(rows).view(order + "u2")
    return rows.astype(np.uint16).reshape(h, w, c)


def _pixel_offset(path, head: bytes | None = None) -> tuple[str, int]:
    """``(byte order, offset of the pixels)`` of a DPX file from its first 8 bytes (``head``,
    else read): ``"<"`` or ``">"`` by its magic number, and the header's offset to the image
    data."""
    if head is None:
        with open(path, "rb") as fh:
            head = fh.read(8)
    order = "<" if head[:4] == b"XPDS" else ">"
    return order, int(np.frombuffer(head, order + "u4", count=1, offset=4)[0])


def _filled_10(path, shape: tuple[int, int, int], spec) -> np.ndarray:
    """10-bit codes packed three to a 32-bit word (filled, method A: bits 31-22, 21-12 and
    11-2), read from the file itself: OpenImageIO 3.2 reads the last sample of a row wrong
    where a row's samples are not a multiple of three (an RGBA frame of even width), which
    its own writer and ffmpeg store as this does.

    Returns
    -------
    (H, W, C) uint16
    """
    h, w, c = shape
    raw = Path(path).read_bytes()
    order, offset = _pixel_offset(path, raw[:8])
    words = (w * c + 2) // 3
    pad = int(spec.get_int_attribute("dpx:EndOfLinePadding", 0))
    stride = words + (pad // 4 if 0 < pad < 1 << 20 else 0)    # all ones: not given
    if offset + 4 * stride * h > len(raw):
        raise VideoError(f"cannot read the DPX frame {path} (its pixels are cut short)")
    d = np.frombuffer(raw, order + "u4", count=stride * h, offset=offset).reshape(h, stride)
    d = d[:, :words, None] >> np.array([22, 12, 2], np.uint32)
    return (d & 1023).astype(np.uint16).reshape(h, -1)[:, :w * c].reshape(h, w, c)


def dpx_header(path) -> tuple[int, str, int]:
    """``(bits a sample, transfer characteristic, channels)`` of a DPX file, from its header.

    Raises
    ------
    VideoError
        Unreadable (naming the file).
    """
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise VideoError(f"cannot read the DPX frame {path} ({_why(oiio.geterror())})")
    try:
        spec = inp.spec()
        return (int(spec.get_int_attribute("oiio:BitsPerSample", 16)) or 16,
                spec.get_string_attribute("dpx:Transfer", ""), int(spec.nchannels))
    finally:
        inp.close()


def dpx_summary(path) -> str:
    """One line of what a DPX plate's frames hold and how they are seen (``probe``)."""
    image = read_dpx_image(path)
    bits, transfer, channels = image.bits, image.transfer, image.codes.shape[2]
    _, _, low, high = image.coding
    full = (low, high) == (0, (1 << bits) - 1)
    how = {"log": "Cineon log (black 95, white 685): shown as light through the sRGB curve, "
                  "above white as white",
           "linear": "linear light: shown through the sRGB curve",
           "video": "display values: shown as they are" + (
               "" if full else f" between codes {low} (black) and {high} (white)")}[
        transfer_kind(transfer)]
    layout = {1: "luma", 3: "RGB", 4: "RGBA"}.get(channels, f"{channels} channels")
    return (f"DPX, {layout}, {bits} bits, transfer {transfer or 'not named'}: {how}; a "
            "rewrite written as .dpx keeps every code value it does not change; no audio")


def _why(message: str) -> str:
    return (message or "damaged").strip().splitlines()[-1]


def _to_codes(v16: np.ndarray, bits: int) -> np.ndarray:
    """OpenImageIO's 16-bit values as codes of ``bits`` bits: their top bits (it reads a code
    as the code scaled to 16 bits, rounded: ``c * 65535 / (2**bits - 1)`` keeps ``c`` there)."""
    v16 = np.ascontiguousarray(v16, np.uint16)
    return v16 if bits >= 16 else v16 >> np.uint16(16 - bits)


def _to_16(codes: np.ndarray, bits: int) -> np.ndarray:
    """Codes of ``bits`` bits (8 to 16) as 16-bit values that OpenImageIO writes back as the
    same codes: the code's bits repeated to fill 16 (within a 16-bit step of the code scaled,
    whether it rounds or cuts)."""
    codes = np.ascontiguousarray(codes, np.uint16)
    if bits >= 16:
        return codes
    return (codes << np.uint16(16 - bits)) | (codes >> np.uint16(2 * bits - 16))


def _log_light(c10: np.ndarray) -> np.ndarray:
    """Light relative to the white point, black subtracted, of 10-bit log codes (float64);
    the table of every code inverts it (:func:`_codes_of`)."""
    black = 10.0 ** ((LOG_BLACK - LOG_WHITE) * LOG_DENSITY / LOG_GAMMA)
    return (10.0 ** ((c10 - LOG_WHITE) * LOG_DENSITY / LOG_GAMMA) - black) / (1.0 - black)


@functools.lru_cache(maxsize=8)
def _levels_table(coding: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``(levels, shown)``: every code's display level (float64, 0 to 255, not rounded) and
    whether it lies within what is shown (not clipped), by code, for a
    :attr:`DpxImage.coding`."""
    kind, bits, low, high = coding
    top = (1 << bits) - 1
    code = np.arange(top + 1, dtype=np.float64)
    if kind == "video":
        return 255.0 * np.clip((code - low) / (high - low), 0.0, 1.0), \
            (code >= low) & (code <= high)
    x = code / top
    light = x if kind == "linear" else _log_light(x * 1023.0)
    inside = (light >= 0.0) & (light <= 1.0)
    return _curve(light).astype(np.float64), inside


def _codes_of(levels: np.ndarray, coding: tuple) -> np.ndarray:
    """The codes (uint16, rounded, within range) of display levels (float, 0 to 255): the
    inverse of :func:`_levels_table`'s levels, between two codes linear (a code's step is at
    most ~3 levels: within a thousandth of a code of the curve's own inverse)."""
    kind, _, low, high = coding
    if kind == "video":
        return np.rint(low + np.clip(levels, 0.0, 255.0) * ((high - low) / 255.0)).astype(
            np.uint16)
    table, inside = _levels_table(coding)
    codes = np.flatnonzero(inside)
    x = np.interp(levels, table[codes], codes.astype(np.float64))
    return np.rint(x).astype(np.uint16)


@functools.lru_cache(maxsize=8)
def _shown_table(coding: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(shown, first, last)``: every code's 8-bit level, and for each level the first and
    last code shown as it (``first > last`` where no code is: the darkest levels of a 10-bit
    linear plate)."""
    levels, _ = _levels_table(coding)
    table = np.clip(np.rint(levels), 0, 255).astype(np.uint8)    # never decreasing
    every = np.arange(256)
    return (table, np.searchsorted(table, every, "left"),
            np.searchsorted(table, every, "right") - 1)


def shown_dpx(image: DpxImage) -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB: a DPX frame as the tracker and the rewrite see it (module
    notes), by a table of its every code."""
    return _shown_table(image.coding)[0][image.rgb()]


def graded_codes(image: DpxImage, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
    """The rewritten frame in the plate's codes: the plate's where ``rewritten`` equals
    ``shown`` (both (H, W, 3) uint8: the plate shown by :func:`shown_dpx`, and its rewrite),
    else the code of the rewritten level plus the plate's part below a level (its unrounded
    level less ``shown``), kept among the codes shown as the rewritten level where there are
    any (so that the result is shown as the rewrite); in a channel beyond what is shown, the
    rewritten level's code.

    Returns
    -------
    (H, W, 3) uint16
    """
    out = image.rgb().copy()
    moved = rewritten != shown
    changed = moved[..., 0] | moved[..., 1] | moved[..., 2]    # a fifth of np.any's time
    p, r = out[changed], rewritten[changed]
    levels, inside = _levels_table(image.coding)
    detail = np.where(inside[p], levels[p] - shown[changed], 0.0)
    codes = _codes_of(r + detail, image.coding)
    _, first, last = _shown_table(image.coding)
    some = first[r] <= last[r]
    out[changed] = np.where(some, np.clip(codes, first[r], np.maximum(last[r], first[r])),
                            codes)
    return out


def write_dpx(path, frame, header=None) -> None:
    """Write a DPX file: a :class:`DpxImage` with its header, or an array as codes of a video
    transfer (ITU-R 709): ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA uint8 in 10 bits, or
    uint16 grey ``(H, W)``, RGB or RGBA in 16 (a deep target's values,
    :mod:`facetransfer.io.plate_depth`). ``header``: the frame's
    :class:`~facetransfer.io.plate_header.FrameHeader`, recorded in a header made here (the
    film and television headers' frame rates, the timecode, the pixel aspect); the header of a
    :class:`DpxImage` is kept as it is.

    Raises
    ------
    ValueError
        OpenImageIO could not write it (naming the file).
    """
    import OpenImageIO as oiio

    if not isinstance(frame, DpxImage):
        frame = _video_codes(np.asarray(frame))
    eight = frame.bits <= 8
    spec = _new_spec(frame, header) if frame.spec is None else oiio.ImageSpec(frame.spec)
    spec.set_format(oiio.TypeDesc("uint8" if eight else "uint16"))
    spec.attribute("oiio:BitsPerSample", int(frame.bits))
    data = frame.codes.astype(np.uint8) if eight else _to_16(frame.codes, frame.bits)
    out = oiio.ImageOutput.create("dpx")     # by name: a temporary file has another suffix
    ok = out is not None and out.open(str(path), spec)
    ok = ok and out.write_image(np.ascontiguousarray(data))
    why = oiio.geterror() if out is None else out.geterror()
    if out is not None:
        out.close()
    if not ok:
        raise ValueError(f"cannot write the DPX file {path} ({_why(why)})")


def _video_codes(img: np.ndarray) -> DpxImage:
    """An array (module :func:`write_dpx`) as a :class:`DpxImage` of ITU-R 709 codes."""
    if img.dtype == np.uint16:
        return DpxImage(img[..., None] if img.ndim == 2 else img, 16, "ITU-R 709-4")
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"a DPX frame is (H, W, 3|4) uint8 or uint16, not {img.shape} "
                         f"{img.dtype}")
    codes = ((img.astype(np.uint32) * 1023 * 2 + 255) // 510).astype(np.uint16)
    return DpxImage(codes, 10, "ITU-R 709-4")


def _new_spec(frame: DpxImage, header=None):
    """The OpenImageIO description of a DPX frame made here: its size, channels, bits and
    transfer characteristic (the colorimetric one the same), and where ``header`` gives them
    its frame rate (in the film and the television header), SMPTE timecode and pixel
    aspect."""
    import OpenImageIO as oiio

    from .plate_header import timecode_word

    h, w, c = frame.codes.shape
    spec = oiio.ImageSpec(w, h, c, "uint16")
    if frame.transfer:
        spec.attribute("dpx:Transfer", frame.transfer)
        spec.attribute("dpx:Colorimetric", frame.transfer)
    if header is not None and header.fps is not None:
        spec.attribute("dpx:FrameRate", float(header.fps))
        spec.attribute("dpx:TemporalFrameRate", float(header.fps))
    if header is not None and header.timecode is not None:
        spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"),
                       np.array([timecode_word(header.timecode), 0], np.uint32))
    if header is not None and header.sar is not None:
        spec.attribute("PixelAspectRatio", header.sar[0] / header.sar[1])
    return spec

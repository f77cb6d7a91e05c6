"""OpenEXR plates: scene-linear frames shown to the tracker through the sRGB curve, and a
rewritten plate that keeps every float the rewrite did not change.

A VFX plate is often a sequence of OpenEXR files (``plate/sh010.%04d.exr``) of scene-linear RGB
in half or single floats. The tracker, the texture and the rewrite work on display-referred
8-bit RGB, so an EXR frame is *shown* through the sRGB transfer curve (IEC 61966-2-1; the
linear values clipped to [0, 1]: highlights above 1 read as white) to become the frame every
other module sees (:func:`srgb_encode`); a frame is its display window, a data window cropped
to the content placed in it on black (:func:`read_exr`). A plate whose header names other
primaries than Rec.709's (ACES2065-1 or ACEScg: ``chromaticities``, ``colorInteropID``) is
brought to Rec.709's by a 3x3 matrix before the curve (:mod:`facetransfer.io.primaries`), so
that a face is seen, and drawn, in its own colours.

A rewrite written as EXR (``--out out/sh010.%04d.exr``) goes back to linear light. Of an EXR
plate, a pixel the rewrite left unchanged (``R == T``, ``R`` the rewritten and ``T`` the shown
pixel: everything outside the face) is the plate's float ``P``, bit for bit, values beyond
[0, 1] and NaN included; a changed one is ``dec(R + (enc(P) - T))``, ``enc`` the curve before
rounding and ``dec`` its inverse: the rewrite with the plate's detail finer than an 8-bit level
kept, or where a channel of ``P`` lies outside [0, 1] (clipped when shown) the rewrite's own
``dec(R)``, so that a face drawn over a highlight does not glow with it (of other primaries,
all of it in Rec.709's, the changed pixel then brought back: :func:`graded_frame`), in the
plate's own pixel type, with its header (timecode, chromaticities, compression, every other
attribute) and its other channels (alpha, depth) as they were (:class:`ExrImage`,
:mod:`facetransfer.io.exr_plate`). Of any other target, an EXR frame is the rewritten 8-bit
frame decoded to half floats, PIZ-compressed (lossless). OpenEXR files are read and written by
the OpenEXR project's own Python bindings (``OpenEXR``): RGB or grey channels, scanline or
tiled, the first part of a multi-part file.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import VideoError

__all__ = ["EXR_SUFFIX", "ExrImage", "srgb_encode", "srgb_decode", "shown_frame", "read_exr",
           "read_exr_image", "write_exr", "exr_pixel_type", "graded_frame", "is_exr"]

EXR_SUFFIX = ".exr"
_MAGIC = b"\x76\x2f\x31\x01"
#: The header attributes the bindings derive from the pixels a file is written with.
_DERIVED = ("channels",)


def is_exr(path) -> bool:
    """Whether ``path`` (a file or a sequence's pattern) names OpenEXR frames."""
    return Path(path).suffix.lower() == EXR_SUFFIX


def _curve(x: np.ndarray) -> np.ndarray:
    """The IEC 61966-2-1 curve of linear values clipped to [0, 1], in levels (0 to 255, not
    rounded): ``12.92 x`` up to 0.0031308, ``1.055 x^(1/2.4) - 0.055`` above."""
    x = np.clip(np.nan_to_num(np.asarray(x, np.float32), nan=0.0), 0.0, 1.0)  # NaN: black
    return 255.0 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _uncurve(v: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_curve`: levels (float, 0 to 255) to linear float32."""
    v = np.clip(np.asarray(v, np.float64), 0.0, 255.0) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (any shape, float) shown as 8-bit sRGB: clipped to [0, 1], the IEC 61966-2-1
    curve (:func:`_curve`), rounded."""
    return np.rint(_curve(linear)).astype(np.uint8)


@functools.lru_cache(maxsize=1)
def _half_table() -> np.ndarray:
    """:func:`srgb_encode` of every half float, indexed by its 16 bits (65,536 uint8)."""
    return srgb_encode(np.arange(65536, dtype=np.uint16).view(np.float16).astype(np.float32))


def shown_frame(image: "ExrImage") -> np.ndarray:
    """``(H, W, 3)`` uint8 RGB: an EXR frame's display window shown through the sRGB curve
    (:func:`srgb_encode` of :meth:`ExrImage.displayed`, brought to Rec.709's primaries first
    where its header names others: :attr:`ExrImage.to_rec709`; of half floats in Rec.709 by a
    table of every half value, the same levels a fifth of the time)."""
    matrix = image.to_rec709
    if matrix is not None:
        return srgb_encode(image.displayed() @ matrix.T.astype(np.float32))
    if image.rgb.dtype != np.float16:
        return srgb_encode(image.displayed())
    return image.placed(_half_table()[image.rgb.view(np.uint16)])


@functools.lru_cache(maxsize=1)
def _decode_table() -> np.ndarray:
    return _uncurve(np.arange(256, dtype=np.float64))


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """8-bit sRGB (any shape, uint8) back to linear float32 (the inverse of
    :func:`srgb_encode` on its 256 levels)."""
    return _decode_table()[np.asarray(encoded, np.uint8)]


@dataclass(frozen=True, eq=False)
class ExrImage:
    """An OpenEXR frame: its RGB, and the rest of the file as it was.

    Attributes
    ----------
    rgb : (h, w, 3) float16 or float32
        Linear RGB of the data window (a grey file's channel repeated).
    header : dict
        The file's attributes (OpenEXR's names: ``dataWindow``, ``displayWindow``,
        ``compression``, ``timeCode``, ...).
    other : dict
        Its other channels (alpha, depth ...), name -> (h, w) array.
    """

    rgb: np.ndarray
    header: dict = field(default_factory=dict)
    other: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int, int]:
        """The display window's frame shape, ``(H, W, 3)`` (what a writer checks)."""
        if "displayWindow" not in self.header:
            return self.rgb.shape[0], self.rgb.shape[1], 3
        (x0, y0), (x1, y1) = self.header["displayWindow"]
        return int(y1 - y0 + 1), int(x1 - x0 + 1), 3

    @property
    def dtype(self) -> np.dtype:
        return self.rgb.dtype

    @property
    def to_rec709(self) -> np.ndarray | None:
        """``(3, 3)``: its RGB to linear Rec.709 where its header names other primaries
        (``chromaticities``, ``colorInteropID``: ACES2065-1, ACEScg, ...); None where it is
        Rec.709's own (:func:`facetransfer.io.primaries.to_rec709`)."""
        from .primaries import named_chromaticities, to_rec709

        return to_rec709(named_chromaticities(self.header))

    def displayed(self) -> np.ndarray:
        """``(H, W, 3)`` float32 RGB of the display window: the data window placed in it, on
        black (compositing packages write a frame cropped to its content)."""
        return self.placed(np.asarray(self.rgb, np.float32))

    def placed(self, values: np.ndarray) -> np.ndarray:
        """``values`` (h, w, 3), any type, on the data window, placed in the display window
        (zero elsewhere); ``values`` itself where the two windows are one."""
        H, W, _ = self.shape
        if self._offset() == (0, 0) and values.shape[:2] == (H, W):
            return values
        out = np.zeros((H, W, 3), values.dtype)
        frame, data = self._overlap()
        out[frame] = values[data]
        return out

    def with_rgb(self, displayed: np.ndarray) -> "ExrImage":
        """This image with the RGB of ``displayed`` (H, W, 3), the display window's, where the
        data window shows it, in this image's pixel type; the data window's pixels beyond the
        display window (overscan) as they were."""
        rgb = self.rgb.copy()
        frame, data = self._overlap()
        rgb[data] = displayed[frame]
        return ExrImage(rgb, self.header, self.other)

    def _offset(self) -> tuple[int, int]:
        """The data window's top-left pixel in the display window's coordinates."""
        if "dataWindow" not in self.header or "displayWindow" not in self.header:
            return 0, 0
        (dx, dy), _ = self.header["dataWindow"]
        (sx, sy), _ = self.header["displayWindow"]
        return int(dx - sx), int(dy - sy)

    def _overlap(self):
        """The slices of the display window's frame and of the data window that show the same
        pixels (empty where they do not meet)."""
        x0, y0 = self._offset()
        h, w = self.rgb.shape[:2]
        H, W, _ = self.shape
        ax, ay = max(x0, 0), max(y0, 0)
        bx, by = max(min(x0 + w, W), ax), max(min(y0 + h, H), ay)
        return ((slice(ay, by), slice(ax, bx)),
                (slice(ay - y0, by - y0), slice(ax - x0, bx - x0)))


def read_exr_image(path) -> ExrImage:
    """An OpenEXR file as :class:`ExrImage` (its first part).

    Raises
    ------
    VideoError
        Not an OpenEXR file, damaged, or without RGB or grey channels (naming the file).
    """
    import OpenEXR

    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise VideoError(f"cannot read the OpenEXR frame {path} ({exc.strerror})") from None
    if magic != _MAGIC:
        raise VideoError(f"cannot read the OpenEXR frame {path} ({Path(path).name} is not an "
                         "OpenEXR file)")
    from .native_stdout import native_stdout_kept

    try:   # the bindings' note of a damaged file to stdout: not shown (the error says it)
        with native_stdout_kept(), OpenEXR.File(str(path)) as f:
            header = dict(f.header())
            channels = {k: np.asarray(c.pixels) for k, c in f.channels().items()}
    except Exception:  # noqa: BLE001 (the bindings raise several kinds)
        raise VideoError(f"cannot read the OpenEXR frame {path} (damaged, or not RGB "
                         "floats)") from None
    return _image(path, header, channels)


def _image(path, header: dict, channels: dict) -> ExrImage:
    """The :class:`ExrImage` of a file's channels as the bindings give them (``RGB`` or
    ``RGBA`` interleaved, the others by name)."""
    for name in ("RGB", "RGBA"):
        if name in channels:
            rgb = channels.pop(name)
            if name == "RGBA":
                channels["A"] = np.ascontiguousarray(rgb[..., 3])
            return ExrImage(np.ascontiguousarray(rgb[..., :3]), header, channels)
    grey = next((k for k in ("Y", "L", "G") if k in channels), None)
    if grey is None or channels[grey].dtype.kind != "f":
        raise VideoError(f"cannot read the OpenEXR frame {path} (no RGB or grey floats: "
                         f"channels {', '.join(sorted(channels)) or 'none'})")
    g = channels.pop(grey)
    return ExrImage(np.repeat(g[..., None], 3, axis=2), header, channels)


def read_exr(path) -> np.ndarray:
    """An OpenEXR frame as ``(H, W, 3)`` float32 linear RGB of its display window
    (:meth:`ExrImage.displayed`; grey expanded, alpha and other channels left out).

    Raises
    ------
    VideoError
        Unreadable (naming the file).
    """
    return read_exr_image(path).displayed()


def exr_pixel_type(path) -> str:
    """The pixel type of an OpenEXR file's RGB, ``"half"``, ``"float"`` or ``"uint"``.

    Raises
    ------
    VideoError
        Not an OpenEXR file, or unreadable.
    """
    kind = read_exr_image(path).rgb.dtype
    return {np.dtype(np.float16): "half", np.dtype(np.float32): "float"}.get(kind, "uint")


def write_exr(path, rgb, header=None) -> None:
    """Write an OpenEXR file: an :class:`ExrImage` with its header and other channels, or
    ``(H, W, 3)`` linear RGB, PIZ-compressed: float32 as single floats, float16 as half floats,
    uint8 (sRGB) decoded (:func:`srgb_decode`) to half floats (which hold each of its 256
    levels exactly enough to encode back to it), named linear Rec.709 (``colorInteropID``
    ``lin_rec709_scene``: a pipeline that works in ACEScg reads it as what it is); or
    ``(H, W)`` float, one channel ``Y`` of data, not colour (a matte,
    :mod:`facetransfer.io.matte`: ``colorInteropID`` ``data``, as the Color Interop Forum
    names channels no colour transform may touch); with
    ``header`` (the frame's :class:`~facetransfer.io.plate_header.FrameHeader`) as
    ``framesPerSecond``, ``timeCode`` and ``pixelAspectRatio``.

    Raises
    ------
    ValueError
        The bindings could not write it.
    """
    import OpenEXR

    if isinstance(rgb, ExrImage):
        attributes = {k: v for k, v in rgb.header.items() if k not in _DERIVED}
        channels = {"RGB": np.ascontiguousarray(rgb.rgb), **rgb.other}
    else:
        lin = srgb_decode(rgb).astype(np.float16) if rgb.dtype == np.uint8 else \
            np.ascontiguousarray(rgb, np.float16 if rgb.dtype == np.float16 else np.float32)
        attributes = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage,
                      "colorInteropID": "data" if lin.ndim == 2 else "lin_rec709_scene",
                      **_header_attributes(header)}
        channels = {"Y" if lin.ndim == 2 else "RGB": lin}
    try:
        with OpenEXR.File(attributes, channels) as f:
            f.write(str(path))
    except Exception as exc:  # noqa: BLE001 (the bindings raise several kinds)
        raise ValueError(f"cannot write the OpenEXR file {path} ({exc})") from None


def _header_attributes(said) -> dict:
    """OpenEXR's ``framesPerSecond``, ``timeCode`` and ``pixelAspectRatio`` of a
    :class:`~facetransfer.io.plate_header.FrameHeader` (those it gives)."""
    import OpenEXR

    from .plate_header import rate_fraction

    out = {}
    if said is None:
        return out
    if said.fps is not None:
        out["framesPerSecond"] = rate_fraction(said.fps)
    if said.timecode is not None:
        tc = OpenEXR.TimeCode()
        hh, mm, ss, ff = (int(v) for v in said.timecode.replace(";", ":").split(":"))
        tc.hours, tc.minutes, tc.seconds, tc.frame = hh, mm, ss, ff
        tc.dropFrame = ";" in said.timecode
        out["timeCode"] = tc
    if said.sar is not None:
        out["pixelAspectRatio"] = said.sar[0] / said.sar[1]
    return out


def graded_frame(plate: np.ndarray, shown: np.ndarray, rewritten: np.ndarray,
                 to_rec709: np.ndarray | None = None) -> np.ndarray:
    """The rewritten frame in the plate's linear light: ``plate`` (H, W, 3) float32 where
    ``rewritten`` equals ``shown`` (both (H, W, 3) uint8, the plate shown through
    :func:`srgb_encode` and its rewrite), else the rewritten level plus the plate's part
    below a level (its unrounded level less ``shown``, at most half a level), decoded; in a
    channel whose plate value lies outside [0, 1], ``rewritten`` decoded
    (:func:`srgb_decode`). A plate of other primaries (``to_rec709``, its RGB to Rec.709's:
    :attr:`ExrImage.to_rec709`) is graded in Rec.709 and its changed pixels brought back by
    the inverse matrix.

    Returns
    -------
    (H, W, 3) float32
    """
    out = np.array(plate, np.float32, copy=True)
    changed = np.any(rewritten != shown, axis=2)
    p = out[changed]
    if to_rec709 is not None:
        p = p @ to_rec709.T.astype(np.float32)
    detail = np.where((p >= 0.0) & (p <= 1.0), _curve(p) - shown[changed], 0.0)
    new = _uncurve(rewritten[changed] + detail)
    if to_rec709 is not None:
        new = new @ np.linalg.inv(to_rec709).T.astype(np.float32)
    out[changed] = new
    return out


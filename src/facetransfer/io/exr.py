"""OpenEXR plates: scene-linear frames shown to the tracker through the sRGB curve, and a
rewritten plate that keeps every float the rewrite did not change.

A VFX plate is often a sequence of OpenEXR files (``plate/sh010.%04d.exr``) of scene-linear RGB
in half or single floats. The tracker, the texture and the rewrite work on display-referred
8-bit RGB, so an EXR frame is *shown* through the sRGB transfer curve (IEC 61966-2-1; the
linear values clipped to [0, 1]: highlights above 1 read as white) to become the frame every
other module sees (:func:`srgb_encode`); a frame is its display window, a data window cropped
to the content placed in it on black (:func:`read_exr`).

A rewrite written as EXR (``--out out/sh010.%04d.exr``) goes back to linear light. Of an EXR
plate, a pixel the rewrite left unchanged (``R == T``, ``R`` the rewritten and ``T`` the shown
pixel: everything outside the face) is the plate's float ``P``, bit for bit, values beyond
[0, 1] and NaN included; a changed one is ``dec(R + (enc(P) - T))``, ``enc`` the curve before
rounding and ``dec`` its inverse: the rewrite with the plate's detail finer than an 8-bit level
kept, or where a channel of ``P`` lies outside [0, 1] (clipped when shown) the rewrite's own
``dec(R)``, so that a face drawn over a highlight does not glow with it
(:func:`graded_frame`). Of any other target, an EXR frame is the rewritten 8-bit frame decoded
to linear. EXR files are written in the plate's own pixel type (half or float,
:func:`exr_pixel_type`; half for a target of another kind), RGB, PIZ-compressed (lossless; for a
480x480 frame half ZIP's size, written four times faster); other header attributes (timecode,
chromaticities) and an alpha channel are not carried over.

OpenCV reads and writes OpenEXR only when ``OPENCV_IO_ENABLE_OPENEXR`` is set (its codec is off
by default for untrusted files); it is set here, before the first EXR file is touched, unless
the user set it.
"""

from __future__ import annotations

import functools
import os
import struct
from pathlib import Path

import numpy as np

from ..errors import VideoError

__all__ = ["EXR_SUFFIX", "srgb_encode", "srgb_decode", "read_exr", "write_exr",
           "exr_pixel_type", "graded_frame", "is_exr"]

EXR_SUFFIX = ".exr"
_MAGIC = b"\x76\x2f\x31\x01"
#: OpenEXR's channel pixel types (the ``chlist`` attribute).
_PIXEL_TYPES = {0: "uint", 1: "half", 2: "float"}


def is_exr(path) -> bool:
    """Whether ``path`` (a file or a sequence's pattern) names OpenEXR frames."""
    return Path(path).suffix.lower() == EXR_SUFFIX


def _cv2():
    """OpenCV with its OpenEXR codec enabled (unless the user said otherwise)."""
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    return cv2


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
def _decode_table() -> np.ndarray:
    return _uncurve(np.arange(256, dtype=np.float64))


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """8-bit sRGB (any shape, uint8) back to linear float32 (the inverse of
    :func:`srgb_encode` on its 256 levels)."""
    return _decode_table()[np.asarray(encoded, np.uint8)]


def _attributes(path) -> dict[str, tuple[bytes, bytes]]:
    """An OpenEXR file's header attributes, ``name -> (type, value bytes)`` (a single-part
    file's: the header ends at its first empty name).

    Raises
    ------
    VideoError
        Not an OpenEXR file.
    """
    with open(path, "rb") as fh:
        head = fh.read(65536)
    if head[:4] != _MAGIC:
        raise VideoError(f"{path} is not an OpenEXR file")
    out, at = {}, 8
    try:
        while at < len(head) and head[at] != 0:
            name_end = head.index(b"\0", at)
            type_end = head.index(b"\0", name_end + 1)
            size = struct.unpack_from("<i", head, type_end + 1)[0]
            value = type_end + 5
            out[head[at:name_end].decode("latin-1")] = (head[name_end + 1:type_end],
                                                         head[value:value + size])
            at = value + size
    except (ValueError, struct.error):
        raise VideoError(f"{path}: a damaged OpenEXR header") from None
    return out


def exr_pixel_type(path) -> str:
    """The pixel type of an OpenEXR file's first channel, ``"half"``, ``"float"`` or
    ``"uint"``, read from its header's ``channels`` attribute.

    Raises
    ------
    VideoError
        Not an OpenEXR file, or a header without channels.
    """
    kind, value = _attributes(path).get("channels", (b"", b""))
    if kind != b"chlist" or b"\0" not in value:
        raise VideoError(f"{path}: no channels in its OpenEXR header")
    ptype = struct.unpack_from("<i", value, value.index(b"\0") + 1)[0]
    return _PIXEL_TYPES.get(ptype, "float")


def _windows(path) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The file's data and display windows, each ``(x0, y0, x1, y1)`` inclusive."""
    attrs = _attributes(path)
    boxes = []
    for name in ("dataWindow", "displayWindow"):
        kind, value = attrs.get(name, (b"", b""))
        if kind != b"box2i" or len(value) != 16:
            raise VideoError(f"{path}: no {name} in its OpenEXR header")
        boxes.append(struct.unpack("<4i", value))
    return boxes[0], boxes[1]


def read_exr(path) -> np.ndarray:
    """An OpenEXR frame as ``(H, W, 3)`` float32 linear RGB of its display window (grey
    expanded, alpha dropped; a data window smaller than the display window, as compositing
    packages write a frame cropped to its content, placed in it on black).

    Raises
    ------
    VideoError
        Unreadable (naming the file).
    """
    cv2 = _cv2()
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.float32:
        raise VideoError(f"cannot read the OpenEXR frame {path} (damaged, or not RGB floats)")
    rgb = np.repeat(img[..., None], 3, axis=2) if img.ndim == 2 else \
        np.ascontiguousarray(img[..., 2::-1])
    data, shown = _windows(path)
    if data == shown:
        return rgb
    W, H = shown[2] - shown[0] + 1, shown[3] - shown[1] + 1
    out = np.zeros((H, W, 3), np.float32)
    x0, y0 = data[0] - shown[0], data[1] - shown[1]
    ax, ay = max(x0, 0), max(y0, 0)
    bx, by = min(x0 + rgb.shape[1], W), min(y0 + rgb.shape[0], H)
    if bx > ax and by > ay:
        out[ay:by, ax:bx] = rgb[ay - y0:by - y0, ax - x0:bx - x0]
    return out


def write_exr(path, rgb: np.ndarray) -> None:
    """Write ``(H, W, 3)`` linear RGB as an OpenEXR file, PIZ-compressed: float32 as single
    floats, float16 as half floats, uint8 (sRGB) decoded (:func:`srgb_decode`) to half floats
    (which hold each of its 256 levels exactly enough to encode back to it).

    Raises
    ------
    ValueError
        OpenCV could not write it.
    """
    cv2 = _cv2()
    half = rgb.dtype != np.float32
    lin = srgb_decode(rgb) if rgb.dtype == np.uint8 else np.asarray(rgb, np.float32)
    params = [cv2.IMWRITE_EXR_TYPE,
              cv2.IMWRITE_EXR_TYPE_HALF if half else cv2.IMWRITE_EXR_TYPE_FLOAT,
              cv2.IMWRITE_EXR_COMPRESSION, cv2.IMWRITE_EXR_COMPRESSION_PIZ]
    # encoded in memory: OpenCV chooses the format by the name's extension, and the writers
    # write under temporary names (.tmp)
    ok, buf = cv2.imencode(EXR_SUFFIX, np.ascontiguousarray(lin[..., ::-1]), params)
    if not ok:
        raise ValueError(f"OpenCV could not encode {path} as OpenEXR")
    Path(path).write_bytes(buf.tobytes())


def graded_frame(plate: np.ndarray, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
    """The rewritten frame in the plate's linear light: ``plate`` (H, W, 3) float32 where
    ``rewritten`` equals ``shown`` (both (H, W, 3) uint8, the plate shown through
    :func:`srgb_encode` and its rewrite), else the rewritten level plus the plate's part
    below a level (its unrounded level less ``shown``, at most half a level), decoded; in a
    channel whose plate value lies outside [0, 1], ``rewritten`` decoded
    (:func:`srgb_decode`).

    Returns
    -------
    (H, W, 3) float32
    """
    out = np.array(plate, np.float32, copy=True)
    changed = np.any(rewritten != shown, axis=2)
    p = out[changed]
    detail = np.where((p >= 0.0) & (p <= 1.0), _curve(p) - shown[changed], 0.0)
    out[changed] = _uncurve(rewritten[changed] + detail)
    return out


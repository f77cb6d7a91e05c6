"""One frame file of an image sequence as the tools see it, ``(H, W, 3) uint8`` RGB, whatever
its kind: 8 or 16 bits (16 seen as ``round(v / 257)``), grey or colour, with or without alpha
(the colour as stored: an RGBA TIFF of straight alpha through Pillow, since OpenCV's reader
premultiplies it), OpenEXR through the sRGB curve (:mod:`facetransfer.io.exr`), DPX by its
transfer characteristic (:mod:`facetransfer.io.dpx`). Used by
:mod:`facetransfer.io.video_sequence`; what a file holds beyond that (its bit depth, how its
alpha is stored) is read here for :mod:`facetransfer.io.plate_depth` and
:mod:`facetransfer.io.plate_alpha`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import VideoError

__all__ = ["read_frame_file", "read_image", "read_unchanged", "bit_depth", "eight_bits",
           "sixteen_bits", "shown_16", "tiff_alpha_kind", "straight_tiff_rgb", "tiff_mode",
           "tiff_alpha"]


def read_frame_file(file: Path, pattern: Path) -> np.ndarray:
    """One frame file as ``(H, W, 3) uint8`` RGB (16 bits rounded to 8, :func:`shown_16`; grey
    expanded, alpha dropped with the colour as stored, a JPEG's EXIF orientation applied;
    OpenEXR's linear floats shown through the sRGB curve,
    :func:`facetransfer.io.exr.shown_frame`; DPX's codes by their transfer,
    :func:`facetransfer.io.dpx.shown_dpx`)."""
    import cv2

    if file.suffix.lower() == ".exr":
        from .exr import read_exr_image, shown_frame

        return shown_frame(read_exr_image(file))
    if file.suffix.lower() == ".dpx":
        from .dpx import read_dpx_image, shown_dpx

        return shown_dpx(read_dpx_image(file))
    is_tiff = file.suffix.lower() in (".tif", ".tiff")
    tiff = _tiff_header(file) if is_tiff else None   # one look for both questions below
    if _alpha_kind(tiff) == "straight":
        straight = _straight_tiff(file)
        if straight is not None:
            return straight
    if ((tiff[0] if tiff else None) if is_tiff else bit_depth(file)) == 16:
        deep = read_image(file, cv2.IMREAD_UNCHANGED)
        if deep is not None and deep.dtype == np.uint16:
            return shown_16(deep)
    bgr = read_image(file, cv2.IMREAD_COLOR)
    if bgr is None:
        raise VideoError(f"image sequence {pattern}: cannot read frame file {file} (not an "
                         "image OpenCV decodes, or damaged)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_image(file: Path, flags: int) -> np.ndarray | None:
    """``cv2.imread(file, flags)``: None where OpenCV cannot decode it; VideoError naming the
    file where OpenCV refuses it (its own exception: e.g. a header claiming more pixels than
    OpenCV reads, ``CV_IO_MAX_IMAGE_PIXELS``)."""
    import cv2

    try:
        return cv2.imread(str(file), flags)
    except cv2.error as exc:
        why = str(exc).strip().splitlines()[-1] if str(exc).strip() else "refused"
        raise VideoError(f"cannot read image file {file} (OpenCV: {why})") from None


def read_unchanged(file) -> np.ndarray | None:
    """An image file as stored (every channel, its bit depth; OpenCV's channel order), or
    None where OpenCV cannot decode it (:func:`read_image`)."""
    import cv2

    return read_image(Path(file), cv2.IMREAD_UNCHANGED)


def bit_depth(file: Path) -> int | None:
    """Bits a sample of a PNG, TIFF or DPX frame file (from its header: PNG's IHDR, TIFF's
    BitsPerSample, DPX's bit size); None for other files or an unreadable header."""
    suffix = file.suffix.lower()
    if suffix == ".dpx":
        from .dpx import dpx_header

        try:
            return dpx_header(file)[0]
        except VideoError:
            return None
    if suffix in (".tif", ".tiff"):
        tiff = _tiff_header(file)
        return None if tiff is None else tiff[0]
    if suffix != ".png":
        return None
    try:
        with open(file, "rb") as fh:
            head = fh.read(25)
    except OSError:
        return None   # OpenCV's reader names the file
    return head[24] if len(head) == 25 and head[12:16] == b"IHDR" else None


def _tiff_header(file: Path) -> tuple[int | None, tuple, tuple, str] | None:
    """``(bits of the first sample, bits of every sample, ExtraSamples, Pillow's mode)`` of a
    TIFF, from its header (Pillow reads no pixels); None where the header cannot be read."""
    from PIL import Image

    try:
        with Image.open(file) as im:
            bits = im.tag_v2.get(258)
            return (int(bits[0]) if bits else None, tuple(bits or ()),
                    tuple(im.tag_v2.get(338) or ()), im.mode)
    except Exception:  # noqa: BLE001 - a damaged header (Pillow raises several kinds, and a
        return None     # DecompressionBombError for a huge frame): OpenCV's reader decides


def eight_bits(v: np.ndarray) -> np.ndarray:
    """16-bit values as 8-bit ones, ``round(v / 257)`` (65535 -> 255: the inverse of
    ``8-bit * 257``), uint8 of ``v``'s shape."""
    return ((np.asarray(v, np.uint32) * 2 + 257) // 514).astype(np.uint8)


def sixteen_bits(v: np.ndarray) -> np.ndarray:
    """8-bit values as 16-bit ones, ``v * 257`` (255 -> 65535: :func:`eight_bits` gives them
    back), uint16 of ``v``'s shape; 16-bit ones as they are."""
    v = np.asarray(v)
    return v if v.dtype == np.uint16 else v.astype(np.uint16) * np.uint16(257)


def shown_16(deep: np.ndarray) -> np.ndarray:
    """A 16-bit frame as OpenCV stores it (grey, grey + alpha, BGR, BGRA) as the ``(H, W, 3)
    uint8`` RGB the tools see: each value ``v`` as ``round(v / 257)`` (65535 -> 255, the
    inverse of ``8-bit * 257``), the alpha dropped."""
    eight = eight_bits(deep)
    if eight.ndim == 2:
        return np.repeat(eight[..., None], 3, axis=2)
    if eight.shape[2] <= 2:
        return np.repeat(eight[..., :1], 3, axis=2)
    return np.ascontiguousarray(eight[..., 2::-1])


def tiff_alpha_kind(file: Path) -> str | None:
    """How an 8-bit RGBA TIFF's alpha is stored: ``"straight"`` (unassociated, TIFF's
    ExtraSamples 2, what Pillow writes), ``"premultiplied"`` (associated, ExtraSamples 1);
    None for any other file (no alpha, another bit depth, unreadable)."""
    return _alpha_kind(_tiff_header(file) if file.suffix.lower() in (".tif", ".tiff")
                       else None)


def tiff_mode(file: Path) -> str | None:
    """Pillow's mode of a TIFF (``"RGBA"``, ``"LA"``, ``"CMYK"``, ...) from its header; None
    for another file or an unreadable header."""
    tiff = _tiff_header(file) if Path(file).suffix.lower() in (".tif", ".tiff") else None
    return None if tiff is None else tiff[3]


def tiff_alpha(file: Path) -> np.ndarray | None:
    """The stored alpha ``(H, W) uint8`` of an 8-bit grey + alpha TIFF (OpenCV's reader drops
    it), read by Pillow; None where Pillow cannot decode it."""
    from PIL import Image

    try:
        with Image.open(file) as im:
            return np.asarray(im.getchannel("A"))
    except Exception:  # noqa: BLE001 - damaged or huge: OpenCV's reader names what is wrong
        return None


def _alpha_kind(tiff) -> str | None:
    """:func:`tiff_alpha_kind` of a header read by :func:`_tiff_header` (None: not a TIFF)."""
    if tiff is None or tiff[1] != (8, 8, 8, 8) or tiff[3] not in ("RGBA", "RGBa"):
        return None
    return {(2,): "straight", (1,): "premultiplied"}.get(tiff[2])


def straight_tiff_rgb(file: Path) -> np.ndarray | None:
    """The stored RGB ``(H, W, 3) uint8`` of an 8-bit RGBA TIFF with straight alpha
    (:func:`tiff_alpha_kind`; OpenCV's reader gives its colour premultiplied); None for any
    other file, or where Pillow cannot decode it (OpenCV's reader then reads it or names what
    is wrong)."""
    file = Path(file)
    return _straight_tiff(file) if tiff_alpha_kind(file) == "straight" else None


def _straight_tiff(file: Path) -> np.ndarray | None:
    """An 8-bit RGBA TIFF with straight alpha (:func:`tiff_alpha_kind`) as its stored RGB,
    ``(H, W, 3) uint8`` (OpenCV's reader, libtiff's RGBA interface, returns that colour
    premultiplied by the alpha); None where Pillow cannot decode it (OpenCV then reads it or
    names what is wrong)."""
    from PIL import Image

    try:
        with Image.open(file) as im:
            return np.asarray(im.convert("RGB"))
    except Exception:  # noqa: BLE001 - damaged or huge (Pillow's DecompressionBombError):
        return None     # OpenCV's reader reads it or names what is wrong

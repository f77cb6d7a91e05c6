"""The alpha channel of an image-sequence plate (an RGBA PNG, as a compositing package or a
keyer writes one) carried into a rewrite written as a PNG sequence: each output frame the
rewritten colour with the plate frame's own alpha, unchanged.

A PNG's colour is straight (not premultiplied) by its specification and is read as stored
(OpenCV drops the alpha plane), so the rewrite's colour goes back beside the same alpha. An
OpenEXR plate keeps its alpha by :mod:`facetransfer.io.exr_plate`. A TIFF's alpha may be
associated or not, and OpenCV reads an unassociated one's colour premultiplied: a TIFF plate,
a video with alpha (ProRes 4444) and every other output are written colour only
(:func:`facetransfer.io.video_like.like_video` says so).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import VideoError
from .video_sequence import is_sequence, open_sequence

__all__ = ["ALPHA_SUFFIXES", "PlateAlpha", "keeps_alpha", "plate_alpha", "plate_output",
           "sequence_has_alpha"]

#: Image-sequence outputs whose frames hold an alpha channel (8-bit RGBA, straight) and plates
#: whose alpha is carried into them.
ALPHA_SUFFIXES = (".png",)


def _read_unchanged(path: Path) -> np.ndarray | None:
    """The image file as stored (every channel, its bit depth), or None if unreadable."""
    import cv2

    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


def _has_alpha(img: np.ndarray | None) -> bool:
    return img is not None and img.ndim == 3 and img.shape[2] in (2, 4)


def sequence_has_alpha(seq) -> bool:
    """Whether an image sequence's first frame has an alpha channel (grey + alpha or RGBA, of
    a PNG or TIFF; not looked for in OpenEXR frames, whose channels
    :mod:`facetransfer.io.exr_plate` keeps)."""
    f = seq.file(0)
    return f.suffix.lower() != ".exr" and _has_alpha(_read_unchanged(f))


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

    def __init__(self, plate) -> None:
        self.sequence = open_sequence(plate)

    def alpha(self, i: int) -> np.ndarray:
        """``(H, W) uint8``: the alpha of the plate's frame ``i``."""
        f = self.sequence.file(i)
        img = _read_unchanged(f)
        if img is None:
            raise VideoError(f"cannot read frame {f} of the plate {self.sequence.pattern}")
        if not _has_alpha(img):
            return np.full(img.shape[:2], 255, np.uint8)
        a = img[..., -1]
        if a.dtype == np.uint16:
            return ((a.astype(np.uint32) + 128) // 257).astype(np.uint8)
        return a

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
        """Output frame ``i`` (``shown``, the plate's frame as read, is not needed: the alpha is
        read from its file)."""
        a = self.alpha(i)
        rgb = np.asarray(rewritten, np.uint8)
        if a.shape != rgb.shape[:2]:
            raise VideoError(f"frame {self.sequence.file(i)} of the plate is "
                             f"{a.shape[1]}x{a.shape[0]}, the rewrite "
                             f"{rgb.shape[1]}x{rgb.shape[0]}")
        return np.dstack([rgb, a])


def plate_alpha(out, target) -> PlateAlpha | None:
    """The alpha of the image-sequence plate ``target`` for the rewrite written as ``out``:
    None unless ``out`` keeps alpha (:func:`keeps_alpha`) and ``target`` is a sequence of
    the same kind whose first frame has it (:func:`sequence_has_alpha`)."""
    if target is None or not keeps_alpha(out) or not keeps_alpha(target) \
            or not is_sequence(target):
        return None
    return PlateAlpha(target) if sequence_has_alpha(open_sequence(target)) else None


def plate_output(out, target):
    """How output frame ``i`` of a rewrite of ``target`` written as ``out`` is made from the
    rewritten colour beyond it: an OpenEXR plate's floats
    (:func:`~facetransfer.io.exr_plate.plate_grading`) or an RGBA PNG plate's alpha
    (:func:`plate_alpha`), as ``f(i, shown, rewritten)``; None: the colour alone."""
    from .exr_plate import plate_grading

    return plate_grading(out, target) or plate_alpha(out, target)

"""A 16-bit PNG or TIFF plate rewritten as a PNG or TIFF sequence in 16 bits: every pixel the
rewrite did not change is the plate's own value, to the bit, and a changed one is the plate's
value moved by the rewrite's change (its detail below 8 bits, its grain, kept).

The tracker and the rewrite see such a plate in 8 bits (each value ``v`` as ``round(v / 257)``,
:func:`facetransfer.io.frame_file.shown_16`), so an 8-bit result would lose the fine
levels of every pixel of the frame, the face's surroundings included. Here a changed sample is
``v + (rewritten - shown) * 257`` (clipped), which reads back as ``rewritten`` in 8 bits
(``shown`` is the frame the rewrite was made from, ``round(v / 257)``); an unchanged one is
``v``. :func:`deep_frame` is also how a video of more than 8 bits is rewritten
(:mod:`facetransfer.io.video_depth`), whose 8-bit frames come from another decoder: the change
is added to its 16-bit decode, so the face meets its surroundings without a step. Grey
plates stay grey; a PNG plate's 16-bit alpha is kept as it is (a TIFF plate with alpha, or a
grey one with alpha, is written in 8 bits, :mod:`facetransfer.io.plate_alpha`: OpenCV writes
no TIFF alpha tag, nor grey + alpha).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import VideoError
from .frame_file import read_unchanged
from .video_sequence import is_sequence, open_sequence

__all__ = ["DEPTH_SUFFIXES", "DEPTH_OUTPUTS", "PlateDepth", "plate_depth", "deep_frame"]

#: Image-sequence plates and outputs kept in 16 bits.
DEPTH_SUFFIXES = (".png", ".tif", ".tiff")
#: Image-sequence outputs written in 16 bits from a deep target: those, and DPX (16-bit codes
#: of a video transfer, :func:`facetransfer.io.dpx.write_dpx`).
DEPTH_OUTPUTS = DEPTH_SUFFIXES + (".dpx",)


def deep_frame(plate: np.ndarray, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
    """One output frame of a 16-bit plate (module notes): ``plate + (rewritten - shown) * 257``.

    Parameters
    ----------
    plate : (H, W), (H, W, 3) or (H, W, 4) uint16
        The plate's frame: grey, RGB or RGBA.
    shown : (H, W, 3) uint8
        The frame the rewrite was made from (RGB; of a plate, its values in 8 bits).
    rewritten : (H, W, 3) uint8
        The rewrite (RGB; of a grey plate, grey).

    Returns
    -------
    ndarray, the plate's shape, uint16
        The plate's value where the rewrite changed nothing, else moved by the rewrite's change
        (clipped to 0..65535); the alpha channel as the plate's.
    """
    rew = np.asarray(rewritten, np.uint8)
    shown = np.asarray(shown, np.uint8)
    plate = np.asarray(plate, np.uint16)
    colour = plate if plate.ndim == 2 else plate[..., :3]
    moved = rew.astype(np.int32)                         # the whole frame at once: 0.5 ms
    moved -= shown                                       # at 480x480 (12 ms picking the
    moved *= 257                                         # changed pixels out)
    moved = moved[..., 0] if plate.ndim == 2 else moved
    moved += colour                                      # a sample not changed stays itself
    np.clip(moved, 0, 65535, out=moved)
    if plate.ndim == 2 or plate.shape[2] == 3:
        return moved.astype(np.uint16)
    return np.dstack([moved.astype(np.uint16), plate[..., 3]])


class PlateDepth:
    """``depth(i, shown, rewritten)``: output frame ``i`` of a 16-bit plate (:func:`deep_frame`),
    grey ``(H, W)``, RGB ``(H, W, 3)`` or RGBA ``(H, W, 4)`` uint16.

    Parameters
    ----------
    plate : path-like
        The plate's pattern (``plate/sh010.%04d.tif``).
    alpha : bool
        Its frames are RGBA (said in :attr:`kept`).
    """

    def __init__(self, plate, alpha: bool = False) -> None:
        self.sequence = open_sequence(plate)
        #: What the output keeps of the plate (the transfer's summary line says it).
        self.kept = "in the plate's 16 bits" + (", with its alpha" if alpha else "")

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> np.ndarray:
        f = self.sequence.file(i)
        plate = read_unchanged(f)
        if plate is None or plate.dtype != np.uint16 or _channels(plate) not in (1, 3, 4):
            raise VideoError(f"frame {f} of the 16-bit plate {self.sequence.pattern} is not "
                             "16-bit grey, RGB or RGBA (its first frame is)")
        if plate.shape[:2] != np.shape(rewritten)[:2]:
            raise VideoError(f"frame {f} of the plate is {plate.shape[1]}x{plate.shape[0]}, "
                             f"the rewrite {np.shape(rewritten)[1]}x{np.shape(rewritten)[0]}")
        return deep_frame(_rgb_order(plate), shown, rewritten)


def _channels(img: np.ndarray) -> int:
    return 1 if img.ndim == 2 else int(img.shape[2])


def _rgb_order(img: np.ndarray) -> np.ndarray:
    """OpenCV's BGR / BGRA as RGB / RGBA (grey as it is)."""
    import cv2

    if img.ndim == 2:
        return img
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)


def plate_depth(out, target) -> PlateDepth | None:
    """The 16-bit grading of the plate ``target`` rewritten as ``out``: a PNG, TIFF or DPX
    sequence of a PNG or TIFF plate whose first frame is 16 bits (a TIFF one without alpha, and
    only a PNG or DPX one of an RGBA plate); else None."""
    if target is None or not is_sequence(target):
        return None
    p, o = Path(target), Path(out)
    if "%" not in o.name or o.suffix.lower() not in DEPTH_OUTPUTS \
            or p.suffix.lower() not in DEPTH_SUFFIXES:
        return None
    first = read_unchanged(open_sequence(target).file(0))
    if first is None or first.dtype != np.uint16 or _channels(first) not in (1, 3, 4):
        return None   # 8 bits, or grey + alpha: written in 8 bits
    if _channels(first) == 4 and (o.suffix.lower() not in (".png", ".dpx")
                                  or p.suffix.lower() != ".png"):
        return None   # written in 8 bits with its alpha (OpenCV writes no TIFF alpha tag)
    return PlateDepth(target, alpha=_channels(first) == 4)

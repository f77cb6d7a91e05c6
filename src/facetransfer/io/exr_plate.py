"""A rewrite of an OpenEXR plate written as OpenEXR, in the plate's own floats, pixel type,
header and other channels (:func:`facetransfer.io.exr.graded_frame` frame by frame)."""

from __future__ import annotations

import numpy as np

from .exr import ExrImage, graded_frame, is_exr, read_exr_image
from .video_sequence import is_sequence, open_sequence

__all__ = ["PlateGrading", "plate_grading"]


class PlateGrading:
    """The rewritten frames of an OpenEXR plate in its own linear light and pixel type
    (:func:`~facetransfer.io.exr.graded_frame`): ``grading(i, shown, rewritten)`` for output
    frame ``i``, which rewrites the plate's frame ``i``.

    Parameters
    ----------
    plate : path-like
        The plate's pattern (``plate/sh010.%04d.exr``).
    """

    #: What the output keeps of the plate (the transfer's summary line says it).
    kept = "in the plate's floats, with its other channels"

    def __init__(self, plate) -> None:
        self.sequence = open_sequence(plate)

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> ExrImage:
        """The plate's frame ``i`` with its RGB graded, in its pixel type, with its header
        and its other channels (alpha ...) as they were."""
        plate = read_exr_image(self.sequence.file(i))
        return plate.with_rgb(graded_frame(plate.displayed(), shown, rewritten,
                                           plate.to_rec709))


def plate_grading(out, target) -> PlateGrading | None:
    """The grading of a rewrite written as the OpenEXR sequence ``out`` of the OpenEXR plate
    ``target``; None for any other output or target (an 8-bit frame written as EXR is then
    decoded to linear by :func:`~facetransfer.io.exr.write_exr`)."""
    if target is None or not (is_exr(out) and is_exr(target) and is_sequence(target)):
        return None
    return PlateGrading(target)

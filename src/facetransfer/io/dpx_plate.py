"""A rewrite of a DPX plate written as DPX, in the plate's own codes, bit depth, header and
alpha (:func:`facetransfer.io.dpx.graded_codes` frame by frame)."""

from __future__ import annotations

import numpy as np

from .dpx import DpxImage, graded_codes, is_dpx, read_dpx_image
from .video_sequence import is_sequence, open_sequence

__all__ = ["DpxGrading", "dpx_grading"]


class DpxGrading:
    """The rewritten frames of a DPX plate in its own codes (:func:`graded_codes`):
    ``grading(i, shown, rewritten)`` for output frame ``i``, which rewrites the plate's frame
    ``i``.

    Parameters
    ----------
    plate : path-like
        The plate's pattern (``plate/sh010.%04d.dpx``).
    """

    #: What the output keeps of the plate (the transfer's summary line says it).
    kept = "in the plate's code values, with its header and alpha"

    def __init__(self, plate) -> None:
        self.sequence = open_sequence(plate)

    def __call__(self, i: int, shown: np.ndarray, rewritten: np.ndarray) -> DpxImage:
        plate = read_dpx_image(self.sequence.file(i))
        return plate.with_rgb(graded_codes(plate, shown, rewritten))


def dpx_grading(out, target) -> DpxGrading | None:
    """The grading of a rewrite written as the DPX sequence ``out`` of the DPX plate
    ``target``; None for any other output or target (an 8-bit frame written as DPX is then
    10-bit video codes, :func:`facetransfer.io.dpx.write_dpx`)."""
    if target is None or not (is_dpx(out) and is_dpx(target) and is_sequence(target)):
        return None
    return DpxGrading(target)

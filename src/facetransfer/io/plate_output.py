"""What an output frame keeps of its target beyond the rewritten colour: an OpenEXR plate's
floats (:mod:`facetransfer.io.exr_plate`), a DPX plate's codes (:mod:`facetransfer.io.dpx_plate`),
a 16-bit plate's values
(:mod:`facetransfer.io.plate_depth`), a video's samples of more than 8 bits
(:mod:`facetransfer.io.video_depth`), the target's alpha (:mod:`facetransfer.io.plate_alpha`).
"""

from __future__ import annotations

from .dpx_plate import dpx_grading
from .exr_plate import plate_grading
from .plate_alpha import plate_alpha
from .plate_depth import plate_depth
from .video_depth import video_depth

__all__ = ["plate_output"]


def plate_output(out, target, options=None, start: int = 0):
    """How output frame ``i`` of a rewrite of ``target`` written as ``out`` (with the video
    options ``options``, from frame ``start`` on) is made from the rewritten colour, as
    ``f(i, shown, rewritten)``: the first that applies of a DPX plate's grading, an OpenEXR
    plate's, a 16-bit
    plate's values (with a PNG's alpha), a deep video's (with its alpha) and the target's
    alpha; None: the colour alone."""
    return dpx_grading(out, target) or plate_grading(out, target) or plate_depth(out, target) \
        or video_depth(out, target, options, start) or plate_alpha(out, target, options, start)

"""How a video is shown: its pixel aspect ratio and its colour matrix, read from a video's
header and written into the header of the video that rewrites it.

A rewritten video keeps the pixels of the video it rewrites outside the face; it should also be
shown as that video is. Two facts of the header decide that beside the pixels: the pixel
(sample) aspect ratio, e.g. a 512x480 video shown 480x480 (:attr:`VideoInfo.sar
<facetransfer.io.video_read.VideoInfo>`), and the colour matrix by which players turn YCbCr into
RGB. :func:`facetransfer.io.video.like_video` makes the options of a video that keep both.
"""

from __future__ import annotations

import re

from ..errors import VideoError
from .video_read import pixel_aspect

__all__ = ["COLOUR_TAGS", "checked_aspect", "aspect_args", "matrix_named"]

#: ffmpeg arguments naming the colour of a video written
#: (:attr:`~facetransfer.io.video.VideoOptions.colour_tags`) in its header: the BT.601 matrix in
#: limited range, the conversion its frames had (``facetransfer.io.video._yuv420p``; ffmpeg's
#: own for ProRes). OpenCV decodes a video by the matrix its header names (e.g. BT.709): left
#: unspecified, the rewritten video would be guessed at by players, most taking BT.709 for HD
#: (reds and skin drawn a little off the target's).
COLOUR_TAGS = ["-colorspace", "smpte170m", "-color_range", "tv"]


def checked_aspect(sar) -> tuple[int, int]:
    """``sar`` as two positive integers up to 65535 (H.264's bound) in lowest terms;
    VideoError otherwise."""
    try:
        n, d = (int(x) for x in sar)
        ok = (n, d) == tuple(sar) and 1 <= n <= 65535 and 1 <= d <= 65535
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise VideoError(f"a pixel aspect ratio must be two integers from 1 to 65535, e.g. "
                         f"(15, 16), got {sar!r}")
    return pixel_aspect(n, d)


def aspect_args(sar: tuple[int, int] | None) -> list[str]:
    """ffmpeg arguments giving the frames the pixel aspect ratio ``sar`` (the encoder
    writes it into the stream, the container into its header); none for square pixels."""
    if sar is None or tuple(sar) == (1, 1):
        return []
    return ["-vf", "setsar={}/{}".format(*sar)]


def matrix_named(description: str) -> str | None:
    """The colour matrix (YCbCr coefficients) ffmpeg's description of a media file
    (``ffmpeg -i``'s output) names for its first video stream, as ffmpeg names it (``"bt709"``,
    ``"smpte170m"``, ``"bt470bg"``, ...); None when it names none. The stream's pixel format
    lists range, ``matrix[/primaries/transfer]`` and field order:
    ``yuv420p(tv, bt709, progressive)``."""
    found = re.search(r"Stream #[^\n]*?: Video: [^\n]*?, [a-z0-9_]+\(([^)]*)\)", description)
    if not found:
        return None
    for item in (x.strip() for x in found.group(1).split(",")):
        name = item.split("/")[0]
        if ("/" in item or name in _MATRICES) and name not in ("unknown", "reserved"):
            return name
    return None


#: ffmpeg's names of colour matrices (``AVColorSpace``) as they stand alone in its description.
_MATRICES = ("rgb", "bt709", "fcc", "bt470bg", "smpte170m", "smpte240m", "ycgco", "bt2020nc",
             "bt2020c", "smpte2085", "chroma-derived-nc", "chroma-derived-c", "ictcp", "ipt-c2",
             "ycgco-re", "ycgco-ro")

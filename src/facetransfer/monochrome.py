"""Black-and-white footage told from its frames; a monochrome target stays monochrome: its
rewritten face in grey (beyond the paper, §6).

Black-and-white footage (archive film, a grey security or infrared camera, a graded plate)
stores three equal channels (:func:`is_monochrome`, of a few frames spread over the clip:
:func:`monochrome_picks`, :func:`frame_is_monochrome`). The rewrite pastes textures of other
frames and of the source (the mouth's interior and lips from a colour source) into it; in such
a clip the pixels it changes are brought to grey (ITU-R BT.601 luma, OpenCV's ``RGB2GRAY``) and
every other pixel is left as it is, to the bit. The occlusion test of ``track --occluders``
(:mod:`facetransfer.track.occlusion`) compares lightness and texture where a clip has no
colour to compare.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MONO_LEVELS", "MONO_SAMPLES", "is_monochrome", "frame_is_monochrome",
           "monochrome_picks", "monochrome_changes"]

#: A frame is monochrome when the 99.9th percentile of its channels' differences from green
#: is at most this many levels (decoding and chroma subsampling leave 1-2 on grey footage).
MONO_LEVELS = 3
#: Frames sampled, spread through the clip, to decide whether it is monochrome.
MONO_SAMPLES = 8


def frame_is_monochrome(frame: np.ndarray) -> bool:
    """Whether ``frame`` (H, W, 3) uint8 holds (almost) equal channels, on every other pixel
    of every other row."""
    f = np.asarray(frame)[::2, ::2].astype(np.int16)
    d = np.maximum(np.abs(f[..., 0] - f[..., 1]), np.abs(f[..., 2] - f[..., 1]))
    return float(np.percentile(d, 99.9)) <= MONO_LEVELS


def is_monochrome(frames, n_frames: int | None = None) -> bool:
    """Whether a clip ``frames`` (a sequence of (H, W, 3) uint8) is monochrome: each of up to
    :data:`MONO_SAMPLES` frames spread over its first ``n_frames`` (default all)."""
    n = len(frames) if n_frames is None else min(int(n_frames), len(frames))
    if n <= 0:
        return False
    return all(frame_is_monochrome(frames[int(i)]) for i in monochrome_picks(n))


def monochrome_picks(n: int) -> np.ndarray:
    """The frames of an ``n``-frame clip :func:`is_monochrome` looks at: up to
    :data:`MONO_SAMPLES` spread over it, the first among them; (k,) int64, ascending."""
    if n <= 0:
        return np.zeros(0, np.int64)
    return np.unique(np.linspace(0, n - 1, min(MONO_SAMPLES, n)).round().astype(np.int64))


def monochrome_changes(image: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) uint8, the rewrite of ``frame``, with every pixel it changed brought
    to grey (BT.601 luma in all three channels); the pixels equal to ``frame``'s untouched."""
    import cv2

    changed = np.any(image != frame, axis=2)
    if not changed.any():
        return image
    out = np.array(image, copy=True)
    grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    out[changed] = grey[changed][:, None]
    return out

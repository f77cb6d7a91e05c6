"""A frame's background given as one colour or a whole image: the one parser the renderer and the
synthetic-footage generator share.

It sits beside :mod:`facetransfer.render` rather than in it so that any stage that composes frames
over a background (rendering, synthetic clips) can check one the same way without importing the
rasteriser; it imports nothing else from the package but its errors.
"""

from __future__ import annotations

import numpy as np

from .errors import FaceTransferError, ShapeError

__all__ = ["background_image"]


def background_image(background, width: int, height: int, *,
                     error: type[FaceTransferError] = ShapeError) -> np.ndarray:
    """A background as a new ``(H, W, 3) uint8`` image.

    Parameters
    ----------
    background : (3,) colour in 0..255, or (H, W, 3) uint8 image
    width, height : int
        Frame size in pixels.
    error : FaceTransferError subclass
        Raised for a background that is neither (the caller's error type).

    Returns
    -------
    (H, W, 3) uint8
        The colour everywhere, or a copy of the image.

    Raises
    ------
    FaceTransferError (``error``)
        A colour outside 0..255, or an image of another shape or dtype.
    """
    W, H = int(width), int(height)
    B = np.asarray(background)
    if B.shape == (3,):
        if not np.all((B >= 0) & (B <= 255)):
            raise error(f"background colour must be 3 values in 0..255, got {B}")
        return np.broadcast_to(B.astype(np.uint8), (H, W, 3)).copy()
    if B.shape != (H, W, 3) or B.dtype != np.uint8:
        raise error(f"background must be a colour (3,) or an ({H}, {W}, 3) uint8 image, "
                    f"got {B.shape} {B.dtype}")
    return B.copy()

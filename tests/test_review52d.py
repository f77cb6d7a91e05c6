"""Review52d: faults found reviewing fix52's eyeball fill and mouth gain range, each test
failing before its mend."""

import numpy as np


def _shaded_eye():
    """An eye's opening (an ellipse, 61 x 21 pixels, on skin) with its iris (radius 9) at
    column 60 against the upper lid, the sclera lit (230) on its wide left side and in shade
    (150) on its narrow right side: the median of the sclera is the lit side's."""
    yy, xx = np.mgrid[0:60, 0:100]
    img = np.zeros((60, 100, 3), np.uint8)
    img[:] = (170, 120, 100)
    opening = ((xx - 50) / 30.5) ** 2 + ((yy - 30) / 10.5) ** 2 <= 1.0
    img[opening & (xx < 60)] = 230
    img[opening & (xx >= 60)] = 150
    img[opening & (np.hypot(xx - 60, yy - 24) <= 9)] = (40, 30, 20)
    return img, opening


def test_the_eyeball_beyond_an_iris_is_the_sclera_on_its_own_side():
    """The hidden eyeball beyond the iris took one colour for the whole eye (the median of its
    lit sclera): where the sclera on that side of the iris is in shade, the fill was a light
    patch with a hard edge beside it (``make demo``'s pair, frame 29). Now it is the
    nearest sclera's: the shade on the shaded side, the lit on the lit side."""
    from facetransfer import eyeballs

    img, opening = _shaded_eye()
    out = eyeballs.extend_eyeballs(img, opening, grow=8)
    right = out[15:18, 70:73].reshape(-1, 3).astype(int)   # under the lid, right of the iris
    assert np.abs(right - 150).max() <= 3, right
    left = out[16:20, 45:50].reshape(-1, 3).astype(int)    # under the lid, left of the iris
    assert np.abs(left - 230).max() <= 3, left


def test_an_opening_without_a_long_axis_keeps_its_iris_under_the_lid():
    """A part of an eye's opening about as tall as it is wide (an eye nearly closed, or a piece
    of one, here 14 x 22 pixels) had its long axis put upright by its few pixels' spread, and
    the eyeball above its iris, under the upper lid, was taken for the eyeball beyond the iris
    along the eye: a white sclera cap over the iris, the iris continued sideways instead. Now
    such a part has no long axis and is filled from its nearest pixels (the iris above it)."""
    from facetransfer import eyeballs

    yy, xx = np.mgrid[0:60, 0:100]
    img = np.zeros((60, 100, 3), np.uint8)
    img[:] = (170, 120, 100)
    opening = ((xx - 50) / 6.5) ** 2 + ((yy - 30) / 10.5) ** 2 <= 1.0
    img[opening] = 230
    img[opening & (np.hypot(xx - 50, yy - 24) <= 5)] = (40, 30, 20)
    out = eyeballs.extend_eyeballs(img, opening, grow=6)
    above = out[15:19, 48:53].reshape(-1, 3).astype(int)   # over the iris, under the lid
    assert np.abs(above - (40, 30, 20)).max() == 0, above

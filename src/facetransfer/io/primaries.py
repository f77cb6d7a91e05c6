"""Linear RGB of a plate's own primaries as linear Rec.709, and back.

An OpenEXR plate holds scene-linear RGB in the primaries its header names: the
``chromaticities`` attribute (the x, y of its red, green and blue primaries and of its white,
CIE 1931) or the ``colorInteropID`` of newer files (``lin_ap0_scene`` for ACES2065-1, the
archive and interchange space of ACES deliveries; ``lin_ap1_scene`` for ACEScg, the working
space of many compositing pipelines; ``lin_p3d65_scene``, ``lin_rec2020_scene``, ...). A file
that names neither is Rec.709 / sRGB by OpenEXR's own default. The tracker, the texture and the
rewrite see display-referred sRGB (:mod:`facetransfer.io.exr`), so a plate of other primaries
is first brought to linear Rec.709 by one 3x3 matrix (:func:`to_rec709`): RGB to CIE XYZ by
its primaries, its white adapted to D65 by the Bradford transform (the ACES whites, about D60,
are not D65), XYZ to Rec.709. The rewrite's change goes back by the inverse.

The matrix of each primary set is the textbook construction (SMPTE RP 177): the primaries'
XYZ columns scaled so that RGB (1, 1, 1) is the white. Tests compare it with OpenColorIO's
ACES configuration (OpenImageIO's built-in ``ocio://default``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["REC709", "D65", "rgb_to_xyz", "bradford", "to_rec709", "named_chromaticities"]

#: ITU-R BT.709's primaries and D65 white: (rx, ry, gx, gy, bx, by, wx, wy).
REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: The white of Rec.709 and sRGB, x and y.
D65 = (0.3127, 0.3290)
#: Bradford's cone response matrix (Lam 1985, as ICC and ACES use it).
_BRADFORD = np.array([[0.8951, 0.2664, -0.1614],
                      [-0.7502, 1.7135, 0.0367],
                      [0.0389, -0.0685, 1.0296]])
#: How close (in x and y) a plate's chromaticities must be to Rec.709's to be taken as them.
_SAME = 1e-4


def _xyz(x: float, y: float) -> np.ndarray:
    """CIE XYZ of chromaticity ``(x, y)`` at luminance Y = 1."""
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def rgb_to_xyz(chromaticities) -> np.ndarray:
    """``(3, 3)``: linear RGB of the primaries and white ``chromaticities`` (8 numbers: red,
    green and blue x, y, then the white's) to CIE XYZ, the white at Y = 1."""
    c = [float(v) for v in chromaticities]
    prim = np.stack([_xyz(c[0], c[1]), _xyz(c[2], c[3]), _xyz(c[4], c[5])], axis=1)
    scale = np.linalg.solve(prim, _xyz(c[6], c[7]))
    return prim * scale


def bradford(source_white, target_white) -> np.ndarray:
    """``(3, 3)``: XYZ seen under ``source_white`` (x, y) to XYZ under ``target_white``, by
    Bradford's von Kries transform in its cone space."""
    src = _BRADFORD @ _xyz(*source_white)
    dst = _BRADFORD @ _xyz(*target_white)
    return np.linalg.solve(_BRADFORD, np.diag(dst / src) @ _BRADFORD)


def to_rec709(chromaticities) -> np.ndarray | None:
    """``(3, 3)``: linear RGB of ``chromaticities``' primaries to linear Rec.709 (D65); None
    where they are Rec.709's (within 1e-4) or not a usable set (the identity then)."""
    if chromaticities is None:
        return None
    try:
        c = np.array([float(v) for v in chromaticities], np.float64)
    except (TypeError, ValueError):
        return None
    if c.shape != (8,) or not np.all(np.isfinite(c)) or np.all(np.abs(c - REC709) < _SAME):
        return None
    try:
        m = rgb_to_xyz(c)
        out = np.linalg.solve(rgb_to_xyz(REC709), bradford(c[6:], D65) @ m)
    except (np.linalg.LinAlgError, ZeroDivisionError):
        return None
    return out if np.all(np.isfinite(out)) and abs(np.linalg.det(out)) > 1e-6 else None


def named_chromaticities(header: dict):
    """The chromaticities an OpenEXR header gives: its ``colorInteropID``'s (one of the six
    linear scene-referred IDs, by OpenEXR's own table) where it has one, else its
    ``chromaticities`` attribute; None where it gives neither (Rec.709 by OpenEXR's default)."""
    said = header.get("colorInteropID")
    if isinstance(said, str) and said:
        import OpenEXR

        named = getattr(OpenEXR, "colorInteropIDToChromaticities", lambda _: None)(said)
        if named is not None:
            return tuple(named)
    return header.get("chromaticities")

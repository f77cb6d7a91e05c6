"""The rendered face's pixels where the new face did not move: the target frame's own (issue 13,
"the result looks like footage").

A frame's face texture (``texture="frame"``, the default) is the target frame itself, looked up
through the target's tracked mesh (:func:`facetransfer.texture.face.frame_uvs`). A pixel ``p``
of the new face shows the frame's bilinear sample at ``p + delta(p)``, ``delta`` the
barycentric interpolation of each vertex's displacement from where the new face draws it
(``camera.project(V)``) to where the texture lifted it
(:func:`facetransfer.rim.lifted_positions`). Where the new face lies where the target's did
(the forehead, the nose, the cheeks the expression did not move; a self-transfer), ``delta`` is
a fraction of a pixel: the sample mixes the frame's neighbouring pixels (at half a pixel, two
of them equally) and the finest detail (pores, lashes, strands of hair over the cheek) is
softened, though nothing moved. There the frame's own pixel is kept instead
(:func:`unmoved_weight`, :func:`keep_unmoved`), with a weight falling from 1 where the vertices
moved at most :data:`D0` pixels to 0 where they moved :data:`D1` or more, interpolated over each
triangle from its corners. A kept pixel is what the texture showed there, shifted by less than
:data:`D0` (between :data:`D0` and :data:`D1`, mixed with it): never the target's own expression,
which moved the skin farther than that wherever it differs from the new one's.

It applies to the face texture only: the eye and jaw regions' textures and the source's mouth
are painted over it afterwards (:func:`facetransfer.rewrite._shade_frame`), and the blend adds
its smooth correction to the kept pixels as to the rest (the output there is the frame's
pixel plus the membrane's offset, which is 0 only where the blend's outline matches).
"""

from __future__ import annotations

import cv2
import numpy as np

from .render import interpolate_vertex_values

__all__ = ["D0", "D1", "unmoved_weight", "keep_unmoved"]

#: Pixels a vertex may have moved for the frame's own pixel to be kept wholly: a quarter of a
#: pixel, the shift below which a bilinear sample is mostly one pixel (3/4 of it) and a shifted
#: edge is not seen (``benchmarks/bench_unmoved.py``: the sharpness and error it gains).
D0 = 0.25
#: ... and from which on it is not kept at all: a pixel's shift, beyond which the kept pixel
#: would be another pixel's content (between, the two are mixed linearly in the distance).
D1 = 1.0


def unmoved_weight(raster, faces: np.ndarray, lifted: np.ndarray, drawn: np.ndarray, *,
                   d0: float = D0, d1: float = D1) -> np.ndarray | None:
    """How much of the frame's own pixel to keep at each pixel of the new face.

    Parameters
    ----------
    raster : Raster
        The new face's, of ``faces``, in the frame's (or the crop's) pixels.
    faces : (F, 3) int
    lifted : (n, 2) float
        Where the per-frame texture lifted each vertex (:func:`facetransfer.rim.
        lifted_positions`), in the raster's pixels.
    drawn : (n, 2) float
        Where the new face draws each vertex, in the raster's pixels.
    d0, d1 : float
        The weight is 1 at a displacement of at most ``d0`` pixels, 0 from ``d1`` on, linear
        between (``0 <= d0 < d1``).

    Returns
    -------
    (H, W) float32 in [0, 1] or None
        At a covered pixel the weight of the barycentric interpolation of the corners'
        displacements ``|drawn - lifted|``; 0 where nothing is. None where no vertex moved
        less than ``d1`` (nothing to keep).
    """
    if not 0.0 <= d0 < d1:
        raise ValueError(f"the weight's distances must satisfy 0 <= d0 < d1, got {d0}, {d1}")
    delta = np.asarray(drawn, np.float64) - np.asarray(lifted, np.float64)        # (n, 2)
    d = np.hypot(delta[:, 0], delta[:, 1])
    if not (d < d1).any():
        return None
    # the corners' distances as they are (not capped at d1: a triangle from an unmoved corner
    # to one moved 5 px moved 2.5 px half-way); the interpolation of the lengths is at least
    # the length of the interpolated displacement, so a pixel is never kept for less
    np.minimum(d, 1e6, out=d)
    d[np.isnan(d)] = 1e6
    dist = interpolate_vertex_values(raster, faces, d)                            # (H, W)
    w = (np.float32(d1) - dist) * np.float32(1.0 / (d1 - d0))
    np.clip(w, 0.0, 1.0, out=w)
    w[np.asarray(raster.tri_id) < 0] = 0.0  # interpolate gives 0 (unmoved) where nothing is
    return w


def keep_unmoved(face_img: np.ndarray, frame: np.ndarray, weight: np.ndarray) -> None:
    """``face_img`` (H, W, 3) uint8 mixed towards ``frame`` (H, W, 3) uint8 by ``weight``
    (H, W) float32 in [0, 1] (:func:`unmoved_weight`), in place: ``rint(f + w (t - f))``;
    the frame's pixel to the bit where ``w`` is 1, the face's where it is 0."""
    x, y, w, h = cv2.boundingRect((weight > 0).view(np.uint8))
    if not w:
        return
    box = (slice(y, y + h), slice(x, x + w))
    a = weight[box]
    face_img[box] = cv2.blendLinear(frame[box], face_img[box], a, 1.0 - a)

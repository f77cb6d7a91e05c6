"""The rendered face's pixels where the new face did not move: the target frame's own (issue 13,
"the result looks like footage").

A frame's face texture (``texture="frame"``, the default) is the target frame itself, looked up
through the target's tracked mesh (:func:`facetransfer.texture.face.frame_uvs`). A pixel ``p``
of the new face shows the frame's bilinear sample at ``p + delta(p)``, ``delta`` the
barycentric interpolation of each vertex's displacement from where the new face draws it
(``camera.project(V)``) to where the texture lifted it
(:func:`facetransfer.rim.lifted_positions`). At ``delta = 0`` (a self-transfer) that sample is
the frame's pixel already; but where the new face lies a fraction of a pixel off (the
forehead, the nose, the cheeks the new expression barely moves), the sample mixes the frame's
neighbouring pixels (at half a pixel, two of them equally): the finest detail (pores, lashes,
strands of hair over the face) is softened though nothing visibly moved, in bands that follow
the fraction across the face. There the frame's own pixel is kept instead
(:func:`keep_unmoved`), with a weight falling from 1 where the vertices moved at most
:data:`D0` pixels to 0 where they moved :data:`D1` or more (:func:`vertex_weights`),
interpolated over each triangle from its corners (:func:`unmoved_weight` draws it). A kept
pixel is the content the texture showed there shifted by less than :data:`D0` (between
:data:`D0` and :data:`D1`, mixed with it): never the target's own expression, which moved the
skin farther than that wherever it differs from the new one's.

It applies to the face texture only, under what is painted over it afterwards
(:func:`facetransfer.rewrite._shade_frame`: the eye and jaw regions' textures, the source's
mouth). The blend adds its smooth correction to the kept pixels as to the rest: the output
there is the frame's pixel plus the membrane's offset (small, not 0, where the blend's
outline differs from the frame: BENCHMARKS.md, "Forty-fourth session: the target's own pixels
where the new face did not move").
"""

from __future__ import annotations

import numpy as np

from .errors import ShapeError
from .render import interpolate_vertex_values
from .render.raster import _maybe_njit

__all__ = ["D0", "D1", "vertex_weights", "unmoved_weight", "keep_unmoved"]

#: Pixels a vertex may have moved for the frame's own pixel to be kept wholly: half a pixel, the
#: error of a nearest-pixel lookup. Kept, a pixel's content lies at most ``max_d w(d) d`` from
#: where the new face has it: 0.56 px with :data:`D1` (0.33 px for 0.25 and 1 px, which kept
#: 17 % of ``make demo``'s face texture wholly, not 37 %, and left its hair visibly softer:
#: BENCHMARKS.md, "Forty-fourth session: the target's own pixels where the new face did not
#: move"). The new expression's motions below half a pixel are not drawn there.
D0 = 0.5
#: ... and from which on it is not kept at all (between, the frame's pixel and the texture's
#: are mixed linearly in the distance: two copies of the detail at most 1.5 px apart, as soft
#: as the bilinear sample itself).
D1 = 1.5


def vertex_weights(lifted: np.ndarray, drawn: np.ndarray, *, d0: float = D0,
                   d1: float = D1) -> np.ndarray | None:
    """The weight of the frame's own pixel at each vertex, before clipping to [0, 1]:
    ``(d1 - d) / (d1 - d0)`` of its displacement ``d = |drawn - lifted|`` (pixels).

    Linear in ``d``, so that its barycentric interpolation at a pixel is the same function of
    the corners' interpolated displacement (then clipped: 1 at most ``d0``, 0 from ``d1``).
    The interpolation of the corners' lengths is at least the length of the interpolated
    displacement, so a pixel is never kept for less than it moved.

    Parameters
    ----------
    lifted : (n, 2) float
        Where the per-frame texture lifted each vertex (:func:`facetransfer.rim.
        lifted_positions`), in the raster's pixels.
    drawn : (n, 2) float
        Where the new face draws each vertex, in the same pixels.
    d0, d1 : float
        ``0 <= d0 < d1``.

    Returns
    -------
    (n,) float32 or None
        None where no vertex moved less than ``d1`` (nothing to keep).
    """
    if not 0.0 <= d0 < d1:
        raise ValueError(f"the weight's distances must satisfy 0 <= d0 < d1, got {d0}, {d1}")
    L = np.ascontiguousarray(lifted, dtype=np.float64)
    P = np.ascontiguousarray(drawn, dtype=np.float64)
    if L.ndim != 2 or L.shape[1] != 2 or P.shape != L.shape:
        raise ShapeError(f"lifted and drawn must be the same (n, 2), got {L.shape} and {P.shape}")
    out = np.empty(len(L), np.float32)
    return out if _weights_kernel(L, P, float(d0), float(d1), out) else None


def unmoved_weight(raster, faces: np.ndarray, values: np.ndarray) -> np.ndarray:
    """How much of the frame's own pixel :func:`keep_unmoved` keeps at each pixel of the new
    face: ``(H, W) float32`` in [0, 1], the barycentric interpolation of
    :func:`vertex_weights`' ``values`` (n,) over ``raster`` (the new face's, of ``faces``),
    clipped; 0 where nothing is."""
    w = interpolate_vertex_values(raster, faces, values)
    np.clip(w, 0.0, 1.0, out=w)
    return w


def keep_unmoved(face_img: np.ndarray, frame: np.ndarray, raster, faces: np.ndarray,
                 values: np.ndarray) -> None:
    """``face_img`` (H, W, 3) uint8 mixed towards ``frame`` (H, W, 3) uint8, in place, by
    :func:`unmoved_weight` ``w`` of ``values`` (:func:`vertex_weights`) over ``raster`` (of
    ``faces``, the same pixels): ``rint(f + w (t - f))``, the frame's pixel to the bit where
    ``w`` is 1, the face's where it is 0 (one pass, no map of the weights made)."""
    F = np.ascontiguousarray(faces, dtype=np.int64)
    v = np.ascontiguousarray(values, dtype=np.float32)
    if v.ndim != 1 or (F.size and v.shape[0] <= int(F.max())):
        raise ShapeError(f"values must be (n,) covering the faces' vertices, got {v.shape}")
    if face_img.shape != frame.shape or face_img.shape[:2] != raster.tri_id.shape:
        raise ShapeError(f"face image {face_img.shape}, frame {frame.shape} and raster "
                         f"{raster.tri_id.shape} must be the same pixels")
    if not _keep_kernel(np.asarray(raster.tri_id, np.int32), np.asarray(raster.bary, np.float32),
                        F, v, frame, face_img):
        raise ShapeError(f"the raster's triangles exceed the {len(F)} faces given")


def _weights_kernel_py(L, P, d0, d1, out):  # pragma: no cover (numba)
    """:func:`vertex_weights` into ``out`` (n,) float32; True if a vertex moved less than
    ``d1``. A far vertex (or one not drawn: NaN) is held finite at 10^6 pixels: its weight is
    far below 0 all the same."""
    near = False
    s = 1.0 / (d1 - d0)
    for i in range(L.shape[0]):
        dx = P[i, 0] - L[i, 0]
        dy = P[i, 1] - L[i, 1]
        d = np.sqrt(dx * dx + dy * dy)
        if not d < 1e6:  # (NaN too)
            d = 1e6
        if d < d1:
            near = True
        out[i] = (d1 - d) * s
    return near


_weights_kernel = _maybe_njit(_weights_kernel_py)


def _keep_kernel_py(tid, bary, F, values, frame, img):  # pragma: no cover (numba)
    """:func:`keep_unmoved` (numba): per covered pixel the interpolated weight (as
    :func:`facetransfer.render.interpolate_vertex_values`), clipped, then the mix; False (and
    stops) at a triangle index beyond ``F``. A triangle whose corners' weights are all at most
    0 keeps nothing, all at least 1 the frame's pixels (a convex combination of its corners'):
    only the others' pixels read their barycentrics (most of the face's are of the first)."""
    H, W = tid.shape
    n = F.shape[0]
    kind = np.empty(n, np.uint8)  # 0: nothing kept, 1: the frame's pixels, 2: mixed
    for f in range(n):
        a, b, c = values[F[f, 0]], values[F[f, 1]], values[F[f, 2]]
        if a <= 0 and b <= 0 and c <= 0:
            kind[f] = 0
        elif a >= 1 and b >= 1 and c >= 1:
            kind[f] = 1
        else:
            kind[f] = 2
    for iy in range(H):
        for ix in range(W):
            f = tid[iy, ix]
            if f < 0:
                continue
            if f >= n:
                return False
            k = kind[f]
            if k == 0:
                continue
            if k == 2:
                w = (bary[iy, ix, 0] * values[F[f, 0]] + bary[iy, ix, 1] * values[F[f, 1]]
                     + bary[iy, ix, 2] * values[F[f, 2]])
                if w <= 0:
                    continue
                if w < 1:
                    for c in range(3):
                        a = np.float32(img[iy, ix, c])
                        img[iy, ix, c] = np.uint8(
                            np.rint(a + w * (np.float32(frame[iy, ix, c]) - a)))
                    continue
            img[iy, ix, 0] = frame[iy, ix, 0]
            img[iy, ix, 1] = frame[iy, ix, 1]
            img[iy, ix, 2] = frame[iy, ix, 2]
    return True


_keep_kernel = _maybe_njit(_keep_kernel_py)

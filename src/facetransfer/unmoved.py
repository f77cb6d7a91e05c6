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
the fraction across the face.

There the texture looks the frame up where the new face draws it instead
(:func:`unmoved_uvs`): each vertex's texture position moves towards where it is drawn by a
weight (:func:`vertex_weights`) falling from 1 where it moved at most :data:`D0` pixels to 0
where it moved :data:`D1` or more. A pixel whose triangle's corners all moved at most
:data:`D0` is the frame's own pixel, to the bit (a bilinear sample at a pixel's centre); one
whose corners moved :data:`D1` or more is looked up as before; between, the displacement
shrinks smoothly (a warp, never two copies of the detail mixed). The shading's own
barycentric interpolation carries the weights to the pixels: nothing is added per pixel. A
kept pixel is the content the texture showed there moved by less than :data:`D1`: never the
target's own expression, which moved the skin farther than that wherever it differs from the
new one's.

It changes the face texture's coordinates only, under what is painted over it afterwards
(:func:`facetransfer.rewrite._shade_frame`: the eye and jaw regions' textures, the source's
mouth). The blend adds its smooth correction to the kept pixels as to the rest: the output
there is the frame's pixel plus the membrane's offset (0 to a level where the blend's outline
is kept too: BENCHMARKS.md, "Forty-fourth session: the target's own pixels where the new face
did not move"). Like :mod:`facetransfer.rim`, a rule of the rewrite's texturing (its
``_rewrite_crop`` calls it per crop) in a module of its own.
"""

from __future__ import annotations

import numpy as np

from .errors import ShapeError
from .render import interpolate_vertex_values
from .jit import maybe_njit as _maybe_njit

__all__ = ["D0", "D1", "vertex_weights", "unmoved_uvs", "unmoved_weight"]

#: Pixels a vertex may have moved for the frame's own pixels to be kept wholly around it: half
#: a pixel, the error of a nearest-pixel lookup. The content then lies at most ``max_d w(d) d``
#: from where the new face has it (0.56 px with :data:`D1`; 0.33 px for 0.25 and 1 px, which
#: kept 13 % of ``make demo``'s face texture outside its regions wholly, not 32 %, and left its
#: hair visibly softer: BENCHMARKS.md, "Forty-fourth session: the target's own pixels where
#: the new face did not move"). The new expression's motions below half a pixel are not drawn
#: there.
D0 = 0.5
#: ... and from which on the texture is looked up as before (between, the displacement shrinks
#: linearly in it).
D1 = 1.5


def vertex_weights(lifted: np.ndarray, drawn: np.ndarray, *, d0: float = D0,
                   d1: float = D1) -> np.ndarray:
    """How far each vertex's texture position moves towards where it is drawn.

    Parameters
    ----------
    lifted : (n, 2) float
        Where the per-frame texture lifted each vertex (:func:`facetransfer.rim.
        lifted_positions`), in the frame's (or a crop's) pixels.
    drawn : (n, 2) float
        Where the new face draws each vertex, in the same pixels.
    d0, d1 : float
        ``0 <= d0 < d1``.

    Returns
    -------
    (n,) float64 in [0, 1]
        1 where the displacement ``d = |drawn - lifted|`` is at most ``d0`` pixels, 0 from
        ``d1`` on (or where it is not finite), ``(d1 - d) / (d1 - d0)`` between.
    """
    if not 0.0 <= d0 < d1:
        raise ValueError(f"the weight's distances must satisfy 0 <= d0 < d1, got {d0}, {d1}")
    L = np.asarray(lifted, dtype=np.float64)
    P = np.asarray(drawn, dtype=np.float64)
    if L.ndim != 2 or L.shape[1] != 2 or P.shape != L.shape:
        raise ShapeError(f"lifted and drawn must be the same (n, 2), got {L.shape} and {P.shape}")
    delta = P - L                                                                 # (n, 2)
    d = np.hypot(delta[:, 0], delta[:, 1])
    d[np.isnan(d)] = np.inf
    w = (d1 - d) * (1.0 / (d1 - d0))
    np.clip(w, 0.0, 1.0, out=w)
    return w


def unmoved_uvs(uvs: np.ndarray, size: tuple[int, int], lifted: np.ndarray,
                drawn: np.ndarray, *, d0: float = D0, d1: float = D1) -> np.ndarray | None:
    """A per-frame texture's coordinates with each vertex moved towards where the new face
    draws it by :func:`vertex_weights`: ``lifted + w (drawn - lifted)`` in the frame's pixels.

    Parameters
    ----------
    uvs : (n, 2) float64
        The texture's coordinates (:func:`facetransfer.texture.face.frame_uvs` of the target's
        mesh), whose positions in the frame are ``lifted`` (up to a crop's offset).
    size : (W, H)
        The texture's (the frame's) size.
    lifted, drawn : (n, 2) float
        As :func:`vertex_weights`, in the same pixels (a crop's, or the frame's).
    d0, d1 : float

    Returns
    -------
    (n, 2) float64 or None
        New coordinates (the vertices of weight 0 keep theirs exactly); None where no vertex
        moved less than ``d1`` (nothing to keep).

    References
    ----------
    Vlasic et al. 2005, §6 (the face textured from the target video) and Eq. (7) (the
    weak-perspective projection giving ``lifted`` and ``drawn``, in the stored pixels of an
    anamorphic plate too: the texture is looked up in those).
    """
    if not 0.0 <= d0 < d1:
        raise ValueError(f"the weight's distances must satisfy 0 <= d0 < d1, got {d0}, {d1}")
    L = np.ascontiguousarray(lifted, dtype=np.float64)
    P = np.ascontiguousarray(drawn, dtype=np.float64)
    uv = np.ascontiguousarray(uvs, dtype=np.float64)
    if L.ndim != 2 or L.shape[1] != 2 or P.shape != L.shape or uv.shape != L.shape:
        raise ShapeError(f"uvs, lifted and drawn must be the same (n, 2), got {uv.shape}, "
                         f"{L.shape} and {P.shape}")
    W, H = size
    out = np.empty_like(uv)
    # (one pass: the numpy expression of vertex_weights and the step costs 0.3 ms a frame)
    moved = _uvs_kernel(uv, L, P, float(d0), float(d1), 1.0 / max(W - 1, 1),
                        1.0 / max(H - 1, 1), out)
    return out if moved else None


def _uvs_kernel_py(uv, L, P, d0, d1, sx, sy, out):  # pragma: no cover (numba)
    """:func:`unmoved_uvs` into ``out`` (n, 2): each vertex's ``uv`` plus its weighted step
    (:func:`vertex_weights`) in texture units (the inverse of :func:`facetransfer.texture.
    face.frame_uvs`' ``(x / (W - 1), 1 - y / (H - 1))``: ``sx = 1 / (W - 1)``, ``sy = 1 /
    (H - 1)``); a vertex of weight 0 copied bit for bit. True if one moved."""
    moved = False
    s = 1.0 / (d1 - d0)
    for i in range(uv.shape[0]):
        dx = P[i, 0] - L[i, 0]
        dy = P[i, 1] - L[i, 1]
        d = np.sqrt(dx * dx + dy * dy)
        w = (d1 - d) * s
        if not w > 0:  # (a displacement that is not a number too)
            out[i, 0] = uv[i, 0]
            out[i, 1] = uv[i, 1]
            continue
        moved = True
        if w > 1:
            w = 1.0
        out[i, 0] = uv[i, 0] + w * dx * sx
        out[i, 1] = uv[i, 1] - w * dy * sy
    return moved


_uvs_kernel = _maybe_njit(_uvs_kernel_py)


def unmoved_weight(raster, faces: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`vertex_weights` ``weights`` (n,) at each pixel of ``raster`` (the new face's, of
    ``faces``): ``(H, W) float32`` in [0, 1], their barycentric interpolation (1: the frame's
    own pixel; 0 where nothing is); for pictures and measures."""
    return interpolate_vertex_values(raster, faces, np.asarray(weights, np.float32))

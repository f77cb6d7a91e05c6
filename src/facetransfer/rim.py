"""The rendered face's outer band where it would draw the target's outline inside the target's
face (issue 13, "the result looks like footage").

A frame's face texture is the target frame itself, looked up through the target's tracked mesh
(:func:`facetransfer.texture.face.frame_uvs`). The tracked outline lies a few pixels off the
real one, so the texture's outermost band holds the target's own outline: the dark edge of the
hair or background beside the cheek and jaw, or a strand of hair that hangs over the jaw line.
Where the new face keeps the target's outline that band lands where the target has it. Where
the new face is narrower (a pucker, the source's narrower jaw) the band is drawn inside the
target's face, a dark line along the jaw with the target's own skin edge outside it (``make
demo`` frames 40 and 84); where the new jaw moves along its outline (lower, wider), the strand
at the target's jaw line is drawn a few pixels off it, a dark stroke inside the new face
(``make demo`` frame 52). In both, a pixel near the new outline shows texture lifted from the
target's outer band (:data:`RIM` of its size) while it lies deeper inside the target's
silhouette than that texture did. There the target's own pixels are kept instead
(:func:`drawn_inside`): the target's face, which the new face covers there anyway; only where
the pixel lies at most the band's width deeper (:data:`REACH`): deeper, the target's pixels
are what its own expression moved there. (Where the new face lies within half a pixel of where
the texture lifted it, anywhere on the face, the target's own pixels are shown too:
:mod:`facetransfer.unmoved`.)
"""

from __future__ import annotations

import cv2
import numpy as np

from .jit import maybe_njit as _maybe_njit
from .render.raster import coverage

__all__ = ["RIM", "MOVED", "REACH", "texture_positions", "lifted_positions", "lifted_depth",
           "drawn_inside"]

#: The band's width, a fraction of the face's size (the square root of its pixel area; 250-320
#: pixels for ``make demo``'s faces: 6-8 pixels, the width of the dark line it showed).
RIM = 0.025
#: Pixels by which a pixel must lie deeper inside the target's silhouette than the texture it
#: shows (lifted from the target's outer band) for the target's own pixel to be kept there.
MOVED = 1.5
#: ... and at most this many band widths: deeper, the target's pixels under it are no longer
#: the edge of its face but what its own expression moved there (the lower lip and the shadow
#: under it where the target's jaw is open and the new one closed).
REACH = 1.5
#: The new face's pixels deeper than this many band widths are taken to lie inside the target's
#: silhouette too (:func:`lifted_depth`'s ``core``: its triangles there are not drawn), well
#: beyond :data:`REACH` (how far in the rule looks).
CORE = 4
#: :func:`lifted_depth`'s grid: pixels per side of one of its cells (a coarser map costs less;
#: the rule compares depths a few pixels apart, read from the same map).
STEP = 2


def texture_positions(uvs: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The frame pixels ``(n, 2)`` that :func:`facetransfer.texture.face.frame_uvs` ``uvs`` of a
    ``size`` = ``(W, H)`` frame look up (its inverse)."""
    W, H = size
    return np.stack([uvs[:, 0] * max(W - 1, 1), (1.0 - uvs[:, 1]) * max(H - 1, 1)], axis=1)


def lifted_positions(face_texture, frame: np.ndarray) -> np.ndarray | None:
    """The pixels ``(n, 2)`` of ``frame`` where ``face_texture`` lifted its vertices, when that
    texture is the frame itself (a per-frame texture, its uvs the frame's pixels:
    :func:`facetransfer.texture.face.frame_uvs`); None for another texture (a clip's, whose
    uvs are no frame's pixels)."""
    if face_texture.image is not frame:
        return None
    return texture_positions(face_texture.uvs, (frame.shape[1], frame.shape[0]))


def lifted_depth(positions: np.ndarray, faces: np.ndarray, shape: tuple[int, int], *,
                 core: np.ndarray | None = None) -> np.ndarray:
    """How deep each pixel lies inside the silhouette of the mesh ``faces`` drawn at the
    lifted ``positions`` (n, 2) (its triangles that face the camera cover it): the distance
    to the nearest pixel outside it, in pixels, 0 outside; ``(ceil(H / s), ceil(W / s))``
    float32 for ``shape = (H, W)``, on a grid :data:`STEP` = ``s`` times coarser (its pixel
    ``(i, j)`` is the full-resolution point ``(s j + (s - 1) / 2, s i + (s - 1) / 2)``).

    ``core`` (that grid, bool): pixels known to lie inside the silhouette; the triangles
    whose corners all lie two cells inside it are not drawn (most of the face's, away from its
    outline: :func:`facetransfer.render.raster.coverage`'s ``known``)."""
    H, W = shape
    grid = (np.asarray(positions, np.float64) - (STEP - 1) / 2.0) / STEP
    mask = coverage(grid, faces, (-(-W // STEP), -(-H // STEP)), front=True, known=core)
    depth = cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, 3)
    # with no pixel outside (a face over the whole crop) OpenCV's distance is the float's
    # largest: held finite, so that differences of depths are numbers
    np.minimum(depth, np.float32(1e6), out=depth)
    depth *= np.float32(STEP)
    return depth


def _depth_at(depth: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """:func:`lifted_depth`'s map read (bilinear) at full-resolution points ``xy`` (m, 2)."""
    m = (np.asarray(xy, np.float32) - (STEP - 1) / 2.0) / STEP                 # (m, 2)
    return _remap_points(depth, np.ascontiguousarray(m[:, 0]), np.ascontiguousarray(m[:, 1]))


#: The most points :func:`_remap_points` reads in one ``cv2.remap`` (whose maps must have
#: fewer than ``SHRT_MAX`` = 32767 columns: a face more than half past the crop's edge put
#: its ~11,000 band triangles' 33,000 corners in one row, and OpenCV refused it).
REMAP_CHUNK = 32000


def _remap_points(depth: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
    """``depth`` (h, w) float32 read (bilinear, 0 beyond it) at the points ``(mx, my)`` (m,)
    float32 of its own grid: ``(m,)`` float32, by ``cv2.remap`` over at most
    :data:`REMAP_CHUNK` points at a time."""
    out = np.empty(mx.shape[0], np.float32)
    for i in range(0, mx.shape[0], REMAP_CHUNK):
        j = min(i + REMAP_CHUNK, mx.shape[0])
        out[i:j] = cv2.remap(depth, mx[None, i:j], my[None, i:j], cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)[0]
    return out


def drawn_inside(face_mask: np.ndarray, raster, faces: np.ndarray, lifted: np.ndarray,
                 drawn: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """``(H, W) bool``: the pixels of the rendered face whose texture was lifted from the
    target's outer band (the band :data:`RIM` of the face's size) while they lie more than
    :data:`MOVED` pixels (times ``scale``, :func:`facetransfer.face_scale.face_scale`: the
    tracked outline's error grows with the face), and at most :data:`REACH` band widths,
    deeper inside the target's silhouette than it did.

    Judged per triangle, by the means over its corners of each vertex's depths in
    :func:`lifted_depth`'s map of the target's silhouette, at ``lifted`` and at ``drawn``
    (triangles span a few pixels). ``raster``: the face's, of ``faces``; ``lifted`` (n, 2):
    where the target's texture lifted the vertices (:func:`lifted_positions`); ``drawn`` (n,
    2): where the new face draws them; both in the raster's pixels. (The per-triangle steps
    are numba kernels, the float32 arithmetic of the numpy expressions they replaced:
    :func:`_band_kernel`, :func:`_flag_kernel`.)"""
    k = max(2, int(round(RIM * np.sqrt(np.count_nonzero(face_mask)))))
    F = np.ascontiguousarray(faces, np.int64)
    tri_id = np.asarray(raster.tri_id)
    out = np.zeros(tri_id.shape, bool)
    depth = lifted_depth(lifted, F, face_mask.shape, core=_core(face_mask, CORE * k))
    at_texture = np.ascontiguousarray(_depth_at(depth, lifted))                 # (n,)
    P = np.ascontiguousarray(drawn, np.float64)
    # the triangles with a corner in the band, and their corners' places on the depth map
    cand, grid = np.empty(len(F), np.int64), np.empty((2, 3 * len(F)), np.float32)
    c = _band_kernel(at_texture, F, np.float32(k), P, np.float32((STEP - 1) / 2.0),
                     np.float32(STEP), cand, grid)
    if c == 0:
        return out
    tp = _remap_points(depth, grid[0, :3 * c], grid[1, :3 * c])                # (3 c,)
    per_tri = np.zeros(len(F) + 1, bool)
    xy = np.empty((3 * c, 2), np.float64)
    m = _flag_kernel(at_texture, F, cand[:c], tp, np.float32(k),
                     np.float32(MOVED * scale), np.float32(REACH * k), P, per_tri, xy)
    if m == 0:
        return out
    # the triangles' pixels, looked up on the box their corners span only
    x0, y0, x1, y1 = _box(xy[:3 * m], tri_id.shape)
    if x1 <= x0 or y1 <= y0:  # all past the crop's edge (a face cut by the frame)
        return out
    tb = np.ascontiguousarray(tri_id[y0:y1, x0:x1])
    kept = np.empty(tb.shape, np.uint8)
    _lookup_kernel(per_tri, tb, kept)
    # the triangles' sawtooth outline smoothed (5 x 5 median), on the face only
    _on_face_kernel(_median5(kept), tb, out, x0, y0)
    return out


def _median5(kept: np.ndarray) -> np.ndarray:
    """``cv2.medianBlur(kept, 5) != 0`` of a 0/1 image ``kept`` (h, w) uint8, as uint8 0/1:
    a 5 x 5 window's median is 1 where 13 or more of its 25 pixels are (the image's border
    replicated, as the median's), so the windows' sums (``cv2.boxFilter``) say it. The same
    pixels; on the small boxes here 0.014 against 0.19 ms a call (OpenCV's median pays a
    set-up on a few hundred pixels)."""
    s = cv2.boxFilter(kept, -1, (5, 5), normalize=False, borderType=cv2.BORDER_REPLICATE)
    return (s >= 13).view(np.uint8)


def _band_kernel_py(at, F, k, P, half, step, cand, grid):  # pragma: no cover (numba)
    """The triangles of ``F`` (f, 3) with a corner whose depth ``at`` (n,) float32 is below
    ``k`` (the band), in order, into ``cand`` (f,); their corners' drawn places ``P`` (n, 2)
    on the depth map (``(p - half) / step`` in float32, as :func:`_depth_at` has them) into
    ``grid`` (2, 3 f) float32 (x, y; three per triangle). Returns how many."""
    c = 0
    for f in range(F.shape[0]):
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        if not (at[i0] < k or at[i1] < k or at[i2] < k):
            continue
        cand[c] = f
        for j in range(3):
            i = F[f, j]
            grid[0, 3 * c + j] = (np.float32(P[i, 0]) - half) / step
            grid[1, 3 * c + j] = (np.float32(P[i, 1]) - half) / step
        c += 1
    return c


def _flag_kernel_py(at, F, cand, tp, k, moved, reach, P, per_tri, xy):  # pragma: no cover
    """:func:`drawn_inside`'s judgement of the band's triangles ``cand`` (c,): the means of
    their corners' depths at the texture (``at`` (n,)) and where drawn (``tp`` (3 c,)), all
    float32 (``q = (a + b + c) / 3``, ``d = (a' + b' + c') / 3 - q``); a triangle is kept
    where ``q < k``, ``d > moved`` and ``d <= reach``: ``per_tri[f + 1] = True`` and its
    corners' drawn places ``P`` into ``xy`` (3 m, 2), in order. Returns m (numba)."""
    three = np.float32(3.0)
    m = 0
    for j in range(cand.shape[0]):
        f = cand[j]
        q = (at[F[f, 0]] + at[F[f, 1]] + at[F[f, 2]]) / three
        d = (tp[3 * j] + tp[3 * j + 1] + tp[3 * j + 2]) / three - q
        if q < k and d > moved and d <= reach:
            per_tri[f + 1] = True
            for i in range(3):
                xy[3 * m + i, 0] = P[F[f, i], 0]
                xy[3 * m + i, 1] = P[F[f, i], 1]
            m += 1
    return m


def _lookup_kernel_py(per_tri, tri_id, kept):  # pragma: no cover (numba)
    """``kept = per_tri[tri_id + 1]`` as uint8 (0/1), ``tri_id`` (h, w) int32."""
    for y in range(tri_id.shape[0]):
        for x in range(tri_id.shape[1]):
            kept[y, x] = np.uint8(per_tri[tri_id[y, x] + 1])


def _on_face_kernel_py(med, tri_id, out, x0, y0):  # pragma: no cover (numba)
    """``out[y0:, x0:]`` (its box of ``tri_id``'s (h, w) shape) ``= (med != 0) & (tri_id >=
    0)``, in place (the whole ``out`` passed: one layout, one compiled kernel)."""
    for y in range(tri_id.shape[0]):
        for x in range(tri_id.shape[1]):
            out[y0 + y, x0 + x] = med[y, x] != 0 and tri_id[y, x] >= 0


_band_kernel = _maybe_njit(_band_kernel_py)
_flag_kernel = _maybe_njit(_flag_kernel_py)
_lookup_kernel = _maybe_njit(_lookup_kernel_py)
_on_face_kernel = _maybe_njit(_on_face_kernel_py)


def _core(face_mask: np.ndarray, margin: int) -> np.ndarray:
    """The rendered face's pixels deeper than ``margin`` pixels, on :func:`lifted_depth`'s grid
    (a cell by its top-left pixel): inside the target's silhouette too, whose outline lies
    within a few band widths of the new face's (:data:`CORE`)."""
    coarse = np.ascontiguousarray(face_mask[::STEP, ::STEP]).view(np.uint8)
    r = max(int(margin) // STEP, 1)
    return cv2.erode(coarse, np.ones((2 * r + 1, 2 * r + 1), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)


def _box(xy: np.ndarray, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` (end exclusive) of the pixels points ``xy`` (m, 2) span, a pixel
    beyond, clipped to ``shape = (H, W)``."""
    H, W = shape
    lo = np.floor(xy.min(axis=0)).astype(np.int64) - 1
    hi = np.ceil(xy.max(axis=0)).astype(np.int64) + 2
    return max(int(lo[0]), 0), max(int(lo[1]), 0), min(int(hi[0]), W), min(int(hi[1]), H)

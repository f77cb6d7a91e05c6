"""Merging lifted textures over frames and filling the texels no frame saw (§6).

:func:`merge_textures` is the weight-normalised mean ``Σ_f w_f tex_f / Σ_f w_f`` with the
weights (1) of :mod:`.lifting`; texels never seen are filled by push-pull interpolation
(:func:`fill_holes`; Gortler et al. 1996), per-vertex colours by harmonic interpolation over the
mesh (:func:`fill_vertex_colors`).

References
----------
S. Gortler, R. Grzeszczuk, R. Szeliski, M. Cohen. The Lumigraph. SIGGRAPH 1996 (push-pull).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterable
from typing import NamedTuple

import cv2
import numpy as np

from ..errors import ShapeError
from ..jit import maybe_njit as _maybe_njit
from .base import TextureError, texture_to_uint8

log = logging.getLogger(__name__)

__all__ = ["MergedTexture", "TextureSum", "merge_textures", "fill_holes", "fill_vertex_colors",
           "push_pull_points"]


class MergedTexture(NamedTuple):
    """Weighted mean of several lifted textures.

    Attributes
    ----------
    texture : (..., 3) float32
        Weighted mean colour (holes filled when requested).
    weight : (...,) float32
        Total weight per texel or vertex; 0 where nothing was seen.
    """

    texture: np.ndarray
    weight: np.ndarray


def _checked_pair(item, i: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """``lifted[i]`` as float32 ``(texture (..., 3), weight (...))``, checked (of ``shape``
    when given: the first texture's)."""
    if len(item) != 2:
        raise TextureError(f"lifted[{i}] must be a (texture, weight) pair")
    c = np.asarray(item[0], dtype=np.float32)
    w = np.asarray(item[1], dtype=np.float32)
    if c.shape[-1:] != (3,) or w.shape != c.shape[:-1]:
        raise ShapeError(f"lifted[{i}]: texture {c.shape} and weight {w.shape} must be "
                         "(..., 3) and (...)")
    if shape is not None and c.shape != shape:
        raise ShapeError(f"lifted[{i}] has shape {c.shape}, expected {shape} like lifted[0]")
    if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
        raise TextureError(f"lifted[{i}] weights must be finite and >= 0")
    return c, w


def stack_lifted(lifted) -> tuple[np.ndarray, np.ndarray]:
    """Validate (texture (..., 3), weight (...)) pairs of one shape and stack them: (F, ..., 3), (F, ...)."""
    if len(lifted) == 0:
        raise TextureError("need at least one lifted texture")
    cols, ws = [], []
    for i, item in enumerate(lifted):
        c, w = _checked_pair(item, i, cols[0].shape if cols else None)
        cols.append(c)
        ws.append(w)
    return np.stack(cols), np.stack(ws)


class TextureSum:
    """The sums of :func:`merge_textures`, ``Σ_f w_f tex_f`` and ``Σ_f w_f`` (float64), taken
    one lifted texture at a time: a clip's merge in the memory of one texture instead of all
    of them (a 512² texture lifted from each of 587 frames, all held, takes 5.6 GB;
    BENCHMARKS.md, "Fortieth session").

    Attributes
    ----------
    num : (..., 3) float64 or None
        ``Σ_f w_f tex_f`` (None before the first :meth:`add`).
    total : (...,) float64 or None
        ``Σ_f w_f``.
    count : int
        The textures added.
    """

    def __init__(self) -> None:
        self.num: np.ndarray | None = None      # (..., 3) float64
        self.total: np.ndarray | None = None    # (...,) float64
        self.count = 0

    def add(self, texture, weight) -> None:
        """Add one frame's ``texture`` (..., 3) with its ``weight`` (...)."""
        c, w = _checked_pair((texture, weight), self.count,
                             None if self.num is None else self.num.shape)
        if self.num is None:
            self.num = np.zeros(c.shape, np.float64)
            self.total = np.zeros(w.shape, np.float64)
        self.num += w[..., None] * c
        self.total += w
        self.count += 1

    def merged(self, *, fill: str = "auto", min_weight: float = 1e-6) -> MergedTexture:
        """:func:`merge_textures` of the textures added."""
        _check_fill(fill)
        if self.count == 0:
            raise TextureError("need at least one lifted texture")
        known = self.total > min_weight
        tex = np.zeros_like(self.num)
        tex[known] = self.num[known] / self.total[known][:, None]
        is_image = tex.ndim == 3
        if fill == "auto":
            fill = "pushpull" if is_image else "none"
        if fill != "none":
            if not is_image:
                raise TextureError(f"fill={fill!r} needs (T, T, 3) textures, got {tex.shape}; "
                                   "use fill_vertex_colors for per-vertex colours")
            tex = fill_holes(tex, known, method=fill)
        return MergedTexture(tex.astype(np.float32), self.total.astype(np.float32))


def _check_fill(fill: str) -> None:
    if fill not in ("auto", "pushpull", "inpaint", "none"):
        raise TextureError(f"fill must be 'auto', 'pushpull', 'inpaint' or 'none', got {fill!r}")


def merge_textures(lifted: Iterable, *, fill: str = "auto", min_weight: float = 1e-6) -> MergedTexture:
    """Weighted mean of lifted textures over frames, with holes filled.

    ``texture = Σ_f w_f tex_f / Σ_f w_f`` per texel (or vertex).

    Parameters
    ----------
    lifted : iterable of (texture (..., 3), weight (...)) pairs
        E.g. :class:`~.lifting.LiftedUVTexture` or :class:`~.lifting.LiftedTexture` results of
        several frames (summed one at a time: :class:`TextureSum`).
    fill : {"auto", "pushpull", "inpaint", "none"}, keyword-only
        How to fill texels whose total weight is below ``min_weight``: ``"auto"`` is push-pull
        for (T, T, 3) images and nothing for per-vertex colours (use :func:`fill_vertex_colors`).
    min_weight : float, keyword-only

    Returns
    -------
    MergedTexture
    """
    _check_fill(fill)
    sums = TextureSum()
    for item in lifted:
        if len(item) != 2:
            raise TextureError(f"lifted[{sums.count}] must be a (texture, weight) pair")
        sums.add(*item)
    return sums.merged(fill=fill, min_weight=min_weight)


def fill_holes(texture, known, *, method: str = "pushpull") -> np.ndarray:
    """Fill texels where ``known`` is False from the known ones.

    Parameters
    ----------
    texture : (T, T', 3) float (0..255)
    known : (T, T') bool
    method : {"pushpull", "inpaint"}, keyword-only
        ``"pushpull"``: pyramid push-pull (Gortler et al. 1996), smooth and fast.
        ``"inpaint"``: ``cv2.inpaint`` (Telea), on the uint8-rounded texture.

    Returns
    -------
    (T, T', 3) float32, equal to ``texture`` where ``known``.
    """
    tex = np.asarray(texture, dtype=np.float32)
    k = np.asarray(known)
    if tex.ndim != 3 or tex.shape[2] != 3 or k.shape != tex.shape[:2] or k.dtype != bool:
        raise ShapeError(f"texture (H, W, 3) and known (H, W) bool expected, got {tex.shape} "
                         f"and {k.shape} {k.dtype}")
    if method not in ("pushpull", "inpaint"):
        raise TextureError(f"method must be 'pushpull' or 'inpaint', got {method!r}")
    if k.all():
        return tex.copy()
    if not k.any():
        log.warning("fill_holes: nothing known; returning mid-grey")
        return np.full_like(tex, 128.0)
    if method == "inpaint":
        filled = cv2.inpaint(texture_to_uint8(tex), (~k).astype(np.uint8), 3, cv2.INPAINT_TELEA)
        out = filled.astype(np.float32)
        out[k] = tex[k]
        return out
    return _push_pull(tex, k)


def _push_pull(tex: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Push-pull: average known values down a pyramid, then fill holes from coarser levels.

    Pull: each level halves the previous one (odd sizes padded by an unknown row or column), a
    texel the mean of its known 2x2 children, known if one of them is (numba kernels, every
    level in one call). Push: from the coarsest level up, the unknown texels take the bilinear
    2x upsampling of the filled coarser level (``cv2.resize``, INTER_LINEAR), the known ones
    keep their value.

    Parameters
    ----------
    tex : (H, W, 3) float32
    known : (H, W) bool

    Returns
    -------
    (H, W, 3) float32
        Equal to ``tex`` where ``known``.
    """
    H, W = known.shape
    t = np.ascontiguousarray(tex, np.float32)
    if H * W <= 1:
        return t.copy()
    w = known.astype(np.float32)
    col, wgt, offsets, shapes = _pyramid(H, W)
    _pull_image(t, w, col, wgt, *_as_arrays(offsets, shapes))
    out = np.empty((H, W, 3), np.float32)
    _known_or_up(_push_levels(col, wgt, offsets, shapes), t, w, out)
    return out


def _pyramid(H: int, W: int) -> tuple[np.ndarray, np.ndarray, list, list]:
    """The pulled levels of an (H, W) image (H W > 1) down to 1x1 (each ``((h + 1) // 2,
    (w + 1) // 2)`` of the one before: level ``i`` is ``H`` and ``W`` over ``2^(i + 1)``,
    rounded up), one after the other in two flat buffers (not cleared): texels (3 N,) and
    weights (N,) float32; level ``i``, of shape ``(h, w) = shapes[i]``, starts at pixel
    ``offsets[i]`` (row-major, C-contiguous: :func:`_level`)."""
    shapes = [(((H - 1) >> i) + 1, ((W - 1) >> i) + 1)
              for i in range(1, max(H - 1, W - 1).bit_length() + 1)]
    offsets = [0, *itertools.accumulate([h * w for h, w in shapes])]
    N = offsets.pop()
    return np.empty(3 * N, np.float32), np.empty(N, np.float32), offsets, shapes


def _as_arrays(offsets: list, shapes: list) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_pyramid`'s layout as the kernels take it: offsets (L,), shapes (L, 2) int64."""
    return np.array(offsets, np.int64), np.array(shapes, np.int64)


def _push_levels(col: np.ndarray, wgt: np.ndarray, offsets: list, shapes: list) -> np.ndarray:
    """The push of :func:`_pyramid`'s pulled levels: from the coarsest (1x1) up, each level's
    unknown texels (weight 0) replaced by the bilinear 2x upsampling of the filled coarser
    level (``cv2.resize``, INTER_LINEAR, cut to the level's shape; :func:`_known_over`, in
    place); returns the upsampling of the filled first level, (2 h, 2 w, 3) float32, uncut:
    the finest level's to fill."""
    o = 3 * offsets[-1]
    filled = col[o:o + 3].reshape(1, 1, 3)
    for i in range(len(offsets) - 2, -1, -1):
        up = cv2.resize(filled, (2 * filled.shape[1], 2 * filled.shape[0]),
                        interpolation=cv2.INTER_LINEAR)
        h, w = shapes[i]
        _known_over(up, col, wgt, offsets[i], h, w)
        filled = up[:h, :w]
    return cv2.resize(filled, (2 * filled.shape[1], 2 * filled.shape[0]),
                      interpolation=cv2.INTER_LINEAR)


def push_pull_points(shape: tuple[int, int], ry: np.ndarray, rx: np.ndarray,
                     values: np.ndarray) -> np.ndarray:
    """:func:`fill_holes` (push-pull) of an image known only at a few pixels.

    The same texels as ``fill_holes(d, known)`` with ``d`` zero but ``d[ry, rx] = values``
    and ``known`` the pixels ``(ry, rx)``, without the dense finest level: its pull (each
    2x2 block's mean of its known pixels, summed in row-major order as the pull kernel
    does) is accumulated from the points, and its push writes ``values`` at the points.

    Parameters
    ----------
    shape : (H, W)
    ry, rx : (k,) int
        Distinct pixels in row-major order (e.g. ``np.nonzero`` of a mask).
    values : (k, 3) float32

    Returns
    -------
    (H, W, 3) float32
        C-contiguous; for an even ``W`` the first ``H`` rows of the finest push's upsampling
        (its rows are ``W`` wide: the points are written into it, no copy of the crop).
    """
    H, W = shape
    vals = np.ascontiguousarray(values, np.float32)
    if H * W <= 1 or ry.size in (0, H * W):  # nothing to pull, or nothing to fill
        d = np.zeros((H, W, 3), np.float32)
        d[ry, rx] = vals
        known = np.zeros((H, W), bool)
        known[ry, rx] = True
        return fill_holes(d, known)
    # (contiguous: one compiled layout of the kernels, whether the points are a view or not)
    ry, rx = np.ascontiguousarray(ry, np.int64), np.ascontiguousarray(rx, np.int64)
    col, wgt, offsets, shapes = _pyramid(H, W)
    _pull_from_points(ry, rx, vals, col, wgt, *_as_arrays(offsets, shapes))
    up = _push_levels(col, wgt, offsets, shapes)  # (2 ceil(H / 2), 2 ceil(W / 2), 3)
    if up.shape[1] == W:  # its first H rows are the crop's, C-contiguous: in place
        out = up[:H]
        _points(ry, rx, vals, out)
        return out
    out = np.empty((H, W, 3), np.float32)
    _points_over(up, ry, rx, vals, out)
    return out


def _pull_points_py(ry, rx, vals, coarse, wc):  # pragma: no cover (numba)
    """The finest pull step of :func:`_pull_kernel` from known pixels only: ``coarse``
    (Hc, Wc, 3) and ``wc`` (Hc, Wc) zero on entry; each point's values added to its 2x2
    block's sums in the points' (row-major) order, as the kernel adds a block's pixels (its
    unknown pixels add zeros, which change no sum), then the means and the weights clipped
    to 1."""
    for i in range(ry.shape[0]):
        y, x = ry[i] // 2, rx[i] // 2
        wc[y, x] += np.float32(1.0)
        coarse[y, x, 0] += vals[i, 0]
        coarse[y, x, 1] += vals[i, 1]
        coarse[y, x, 2] += vals[i, 2]
    Hc, Wc = wc.shape
    for y in range(Hc):
        for x in range(Wc):
            sw = wc[y, x]
            if sw > 0:
                coarse[y, x, 0] = coarse[y, x, 0] / sw
                coarse[y, x, 1] = coarse[y, x, 1] / sw
                coarse[y, x, 2] = coarse[y, x, 2] / sw
                wc[y, x] = min(sw, np.float32(1.0))


def _pull_kernel_py(tex, w, coarse, wc):  # pragma: no cover (numba)
    """One pull step: ``coarse`` (Hc, Wc, 3) the weighted mean of each 2x2 block of ``tex``
    (H, W, 3) (weights ``w`` (H, W), here 0 or 1; 0 where the block has no weight), ``wc``
    (Hc, Wc) the block's weight sum clipped to 1."""
    H, W = w.shape
    Hc, Wc = wc.shape
    for y in range(Hc):
        for x in range(Wc):
            s0 = np.float32(0.0)
            s1 = np.float32(0.0)
            s2 = np.float32(0.0)
            sw = np.float32(0.0)
            for yy in range(2 * y, min(2 * y + 2, H)):
                for xx in range(2 * x, min(2 * x + 2, W)):
                    a = w[yy, xx]
                    sw += a
                    s0 += a * tex[yy, xx, 0]
                    s1 += a * tex[yy, xx, 1]
                    s2 += a * tex[yy, xx, 2]
            if sw > 0:
                coarse[y, x, 0] = s0 / sw
                coarse[y, x, 1] = s1 / sw
                coarse[y, x, 2] = s2 / sw
            else:
                coarse[y, x, 0] = 0.0
                coarse[y, x, 1] = 0.0
                coarse[y, x, 2] = 0.0
            wc[y, x] = min(sw, np.float32(1.0))


_pull_kernel = _maybe_njit(_pull_kernel_py)
_pull_points = _maybe_njit(_pull_points_py)


def _level_py(col, wgt, o, h, w):  # pragma: no cover (numba, inlined)
    """Level ``(h, w)`` at pixel ``o`` of :func:`_pyramid`'s buffers as C-contiguous views:
    texels (h, w, 3), weights (h, w)."""
    return (col[3 * o:3 * (o + h * w)].reshape((h, w, 3)),
            wgt[o:o + h * w].reshape((h, w)))


_level = _maybe_njit(_level_py, inline=True)


def _pull_rest_py(col, wgt, offsets, shapes):  # pragma: no cover (numba)
    """The pulls (:func:`_pull_kernel`) of :func:`_pyramid`'s levels after the first, each
    from the one before, in the buffers ``col`` (3 N,) and ``wgt`` (N,); ``offsets`` (L,)
    and ``shapes`` (L, 2) int64 their layout."""
    for i in range(1, offsets.shape[0]):
        c, w = _level(col, wgt, offsets[i - 1], shapes[i - 1, 0], shapes[i - 1, 1])
        cc, wc = _level(col, wgt, offsets[i], shapes[i, 0], shapes[i, 1])
        _pull_kernel(c, w, cc, wc)


_pull_rest = _maybe_njit(_pull_rest_py)


def _pull_image_py(tex, w, col, wgt, offsets, shapes):  # pragma: no cover (numba)
    """Every pull of :func:`_push_pull` in one call: the first level from ``tex`` (H, W, 3)
    with weights ``w`` (H, W) float32 (:func:`_pull_kernel`), then the rest
    (:func:`_pull_rest`)."""
    cc, wc = _level(col, wgt, offsets[0], shapes[0, 0], shapes[0, 1])
    _pull_kernel(tex, w, cc, wc)
    _pull_rest(col, wgt, offsets, shapes)


def _pull_from_points_py(ry, rx, vals, col, wgt, offsets, shapes):  # pragma: no cover (numba)
    """Every pull of :func:`push_pull_points` in one call: the first level from the points
    (:func:`_pull_points`, on the level cleared first), then the rest (:func:`_pull_rest`)."""
    cc, wc = _level(col, wgt, offsets[0], shapes[0, 0], shapes[0, 1])
    cc[:] = 0.0
    wc[:] = 0.0
    _pull_points(ry, rx, vals, cc, wc)
    _pull_rest(col, wgt, offsets, shapes)


def _known_over_py(up, col, wgt, o, h, w):  # pragma: no cover (numba)
    """One push step in place: ``up[:h, :w]`` (the upsampled coarser level) takes the known
    texels (weight > 0) of the level ``(h, w)`` at pixel ``o`` of :func:`_pyramid`'s buffers
    (the ``cv2.copyTo`` of the known texels over the cut upsampling)."""
    for y in range(h):
        for x in range(w):
            i = o + y * w + x
            if wgt[i] > 0:
                up[y, x, 0] = col[3 * i]
                up[y, x, 1] = col[3 * i + 1]
                up[y, x, 2] = col[3 * i + 2]


def _known_or_up_py(up, tex, w, out):  # pragma: no cover (numba)
    """The finest push step of :func:`_push_pull`: ``out`` (H, W, 3) is ``tex`` where the
    weight ``w`` (H, W) is > 0, the upsampling ``up`` (its first H rows and W columns)
    elsewhere."""
    H, W = w.shape
    for y in range(H):
        for x in range(W):
            src = tex if w[y, x] > 0 else up
            out[y, x, 0] = src[y, x, 0]
            out[y, x, 1] = src[y, x, 1]
            out[y, x, 2] = src[y, x, 2]


def _points_over_py(up, ry, rx, vals, out):  # pragma: no cover (numba)
    """The finest push step of :func:`push_pull_points`: ``out`` (H, W, 3) the upsampling
    ``up`` (C-contiguous) cut to its shape (row by row on unsigned flat indices: a copy the
    compiler vectorises), then ``vals`` (k, 3) at the points ``(ry, rx)``."""
    H, W = out.shape[0], out.shape[1]
    uf, of = up.reshape(up.size), out.reshape(out.size)
    for y in range(H):
        u, o = np.uint64(3 * up.shape[1] * y), np.uint64(3 * W * y)
        for i in range(3 * W):
            j = np.uint64(i)
            of[o + j] = uf[u + j]
    _points(ry, rx, vals, out)


def _points_py(ry, rx, vals, out):  # pragma: no cover (numba)
    """``out[ry, rx] = vals``: ``vals`` (k, 3) at the points ``(ry, rx)`` of ``out`` (H, W,
    3), the last step of :func:`_points_over` (alone where the upsampling's rows are the
    crop's: :func:`push_pull_points`)."""
    for i in range(ry.shape[0]):
        out[ry[i], rx[i], 0] = vals[i, 0]
        out[ry[i], rx[i], 1] = vals[i, 1]
        out[ry[i], rx[i], 2] = vals[i, 2]


_pull_image = _maybe_njit(_pull_image_py)
_pull_from_points = _maybe_njit(_pull_from_points_py)
_known_over = _maybe_njit(_known_over_py)
_known_or_up = _maybe_njit(_known_or_up_py)
_points = _maybe_njit(_points_py)
_points_over = _maybe_njit(_points_over_py)


def fill_vertex_colors(colors, known, faces) -> np.ndarray:
    """Fill unknown per-vertex colours by harmonic interpolation over the mesh graph.

    Solves ``L c = 0`` at unknown vertices (graph Laplacian of the triangle edges) with the
    known colours fixed. Components with no known vertex get the mean known colour.

    Parameters
    ----------
    colors : (n, 3) float
    known : (n,) bool
    faces : (F, 3) int64

    Returns
    -------
    (n, 3) float32
    """
    import scipy.sparse as sp  # here: a transfer's default textures never solve
    import scipy.sparse.linalg as sla

    C = np.asarray(colors, dtype=np.float64)
    k = np.asarray(known)
    if C.ndim != 2 or C.shape[1] != 3 or k.shape != (C.shape[0],) or k.dtype != bool:
        raise ShapeError(f"colors (n, 3) and known (n,) bool expected, got {C.shape}, {k.shape}")
    n = C.shape[0]
    F = np.asarray(faces, dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3 or F.size and (F.min() < 0 or F.max() >= n):
        raise ShapeError(f"faces must be (F, 3) indices into {n} vertices, got {F.shape}")
    if k.all() or not k.any():
        out = C.copy() if k.any() else np.full_like(C, 128.0)
        return out.astype(np.float32)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A
    u = np.flatnonzero(~k)
    kk = np.flatnonzero(k)
    Luu = L[u][:, u].tocsc()
    rhs = -(L[u][:, kk] @ C[kk])
    # isolated unknown components make Luu singular: a tiny pull to the mean colour fixes that
    Luu = Luu + sp.identity(len(u), format="csc") * 1e-9
    rhs += 1e-9 * C[kk].mean(axis=0)
    out = C.copy()
    out[u] = sla.splu(Luu).solve(rhs)
    return out.astype(np.float32)

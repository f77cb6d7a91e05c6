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

import logging
from collections.abc import Iterable
from typing import NamedTuple

import cv2
import numpy as np

from ..errors import ShapeError
from ..render.raster import _maybe_njit
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
        E.g. :class:`LiftedUVTexture` or :class:`LiftedTexture` results of several frames
        (summed one at a time: :class:`TextureSum`).
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
    texel the mean of its known 2x2 children, known if one of them is (a numba kernel). Push:
    from the coarsest level up, the unknown texels take the bilinear 2x upsampling of the
    filled coarser level (``cv2.resize``, INTER_LINEAR), the known ones keep their value.

    Parameters
    ----------
    tex : (H, W, 3) float32
    known : (H, W) bool

    Returns
    -------
    (H, W, 3) float32
        Equal to ``tex`` where ``known``.
    """
    return _push_pull_levels([(np.ascontiguousarray(tex, np.float32), known.astype(np.float32))])


def _push_pull_levels(levels: list) -> np.ndarray:
    """:func:`_push_pull` from its finest level ``levels[0] = (texels (H, W, 3), weights (H, W))``
    float32 (0/1 weights): the pyramid pulled to 1x1 and pushed back; the filled finest level."""
    while levels[-1][1].shape[0] > 1 or levels[-1][1].shape[1] > 1:
        c, wl = levels[-1]
        Hc, Wc = (wl.shape[0] + 1) // 2, (wl.shape[1] + 1) // 2
        cc, wc = np.empty((Hc, Wc, 3), np.float32), np.empty((Hc, Wc), np.float32)
        _pull_kernel(c, wl, cc, wc)
        levels.append((cc, wc))
    filled = levels[-1][0]
    for c, wl in reversed(levels[:-1]):
        filled = _push(filled, wl.shape)
        cv2.copyTo(c, (wl > 0).view(np.uint8), filled)  # the known texels over it
    return filled


def _push(coarse: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The bilinear 2x upsampling (``cv2.resize``, INTER_LINEAR) of a filled level
    ``coarse`` (h, w, 3), cut to the finer level's ``shape = (H, W)``: a new C-contiguous
    (H, W, 3) float32 array."""
    H, W = shape
    up = cv2.resize(coarse, (2 * coarse.shape[1], 2 * coarse.shape[0]),
                    interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(up[:H, :W])


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
    """
    H, W = shape
    vals = np.ascontiguousarray(values, np.float32)
    if H * W <= 1 or ry.size in (0, H * W):  # nothing to pull, or nothing to fill
        d = np.zeros((H, W, 3), np.float32)
        d[ry, rx] = vals
        known = np.zeros((H, W), bool)
        known[ry, rx] = True
        return fill_holes(d, known)
    Hc, Wc = (H + 1) // 2, (W + 1) // 2
    cc, wc = np.zeros((Hc, Wc, 3), np.float32), np.zeros((Hc, Wc), np.float32)
    _pull_points(np.asarray(ry, np.int64), np.asarray(rx, np.int64), vals, cc, wc)
    filled = _push(_push_pull_levels([(cc, wc)]), (H, W))
    filled[ry, rx] = vals
    return filled


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

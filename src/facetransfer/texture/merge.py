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
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..errors import ShapeError
from .base import TextureError, texture_to_uint8

log = logging.getLogger(__name__)

__all__ = ["MergedTexture", "merge_textures", "fill_holes", "fill_vertex_colors"]


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


def stack_lifted(lifted) -> tuple[np.ndarray, np.ndarray]:
    """Validate (texture (..., 3), weight (...)) pairs of one shape and stack them: (F, ..., 3), (F, ...)."""
    if len(lifted) == 0:
        raise TextureError("need at least one lifted texture")
    cols, ws = [], []
    shape = None
    for i, item in enumerate(lifted):
        if len(item) != 2:
            raise TextureError(f"lifted[{i}] must be a (texture, weight) pair")
        c = np.asarray(item[0], dtype=np.float32)
        w = np.asarray(item[1], dtype=np.float32)
        if c.shape[-1:] != (3,) or w.shape != c.shape[:-1]:
            raise ShapeError(f"lifted[{i}]: texture {c.shape} and weight {w.shape} must be "
                             "(..., 3) and (...)")
        if shape is None:
            shape = c.shape
        elif c.shape != shape:
            raise ShapeError(f"lifted[{i}] has shape {c.shape}, expected {shape} like lifted[0]")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
            raise TextureError(f"lifted[{i}] weights must be finite and >= 0")
        cols.append(c)
        ws.append(w)
    return np.stack(cols), np.stack(ws)


def merge_textures(lifted: Sequence, *, fill: str = "auto", min_weight: float = 1e-6) -> MergedTexture:
    """Weighted mean of lifted textures over frames, with holes filled.

    ``texture = Σ_f w_f tex_f / Σ_f w_f`` per texel (or vertex).

    Parameters
    ----------
    lifted : sequence of (texture (..., 3), weight (...)) pairs
        E.g. :class:`LiftedUVTexture` or :class:`LiftedTexture` results of several frames.
    fill : {"auto", "pushpull", "inpaint", "none"}, keyword-only
        How to fill texels whose total weight is below ``min_weight``: ``"auto"`` is push-pull
        for (T, T, 3) images and nothing for per-vertex colours (use :func:`fill_vertex_colors`).
    min_weight : float, keyword-only

    Returns
    -------
    MergedTexture
    """
    if fill not in ("auto", "pushpull", "inpaint", "none"):
        raise TextureError(f"fill must be 'auto', 'pushpull', 'inpaint' or 'none', got {fill!r}")
    C, Wt = stack_lifted(lifted)
    total = Wt.sum(axis=0)
    num = np.einsum("f...,f...c->...c", Wt, C)
    known = total > min_weight
    tex = np.zeros_like(num)
    tex[known] = num[known] / total[known][:, None]
    is_image = tex.ndim == 3
    if fill == "auto":
        fill = "pushpull" if is_image else "none"
    if fill != "none":
        if not is_image:
            raise TextureError(f"fill={fill!r} needs (T, T, 3) textures, got {tex.shape}; use "
                               "fill_vertex_colors for per-vertex colours")
        tex = fill_holes(tex, known, method=fill)
    return MergedTexture(tex.astype(np.float32), total.astype(np.float32))


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
    else:
        out = _push_pull(tex, k.astype(np.float32))
    out[k] = tex[k]
    return out


def _push_pull(tex: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Push-pull: average known values down a pyramid, then fill holes from coarser levels."""
    H, W = w.shape
    if H <= 1 and W <= 1:
        return tex
    # pull (down): premultiplied 2x2 sums, weights clipped to 1 so that known texels dominate
    Hp, Wp = H + (H % 2), W + (W % 2)
    cp = np.zeros((Hp, Wp, 3), np.float32)
    wp = np.zeros((Hp, Wp), np.float32)
    cp[:H, :W] = tex * w[..., None]
    wp[:H, :W] = w
    # 2x2 block sums (an exact halving: INTER_AREA averages the blocks)
    c2 = cv2.resize(cp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    w2 = cv2.resize(wp, (Wp // 2, Hp // 2), interpolation=cv2.INTER_AREA) * np.float32(4)
    if c2.ndim == 2:  # a 1-pixel-wide level: cv2 drops the channel axis of (1, 1, 3)
        c2 = c2.reshape(Hp // 2, Wp // 2, 3)
    coarse = np.divide(c2, w2[..., None], out=np.zeros_like(c2), where=w2[..., None] > 0)
    coarse = _push_pull(coarse, np.minimum(w2, 1.0))
    # push (up): bilinear upsampling of the coarse level, blended in by missing weight
    up = cv2.resize(coarse, (Wp, Hp), interpolation=cv2.INTER_LINEAR)[:H, :W]
    a = np.clip(w, 0.0, 1.0)[..., None]
    return a * tex + (1.0 - a) * up


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

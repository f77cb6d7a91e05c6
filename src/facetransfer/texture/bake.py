"""Texture transfer between aligned meshes: a source colour map onto a target's UVs.

Used to carry the Lee Perry-Smith scan's colour map onto the template's UVs once the template is
fitted to the scan (§4.1–4.2): every covered texel of the target takes the colour of the closest
sample of the source surface.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .atlas import UVAtlas, uv_atlas
from .base import TextureError, check_uvs, check_vertices, texture_to_uint8
from .merge import fill_holes

__all__ = ["BakedTexture", "bake_texture"]


class BakedTexture(NamedTuple):
    """A texture carried from one mesh onto another's UV layout.

    Attributes
    ----------
    texture : (T, T, 3) uint8
        Holes (texels with no source point within ``max_distance``) filled by push-pull.
    distance : (T, T) float32
        Distance from each texel's surface point to the source sample used (model units);
        ``inf`` outside the target's UV charts.
    """

    texture: np.ndarray
    distance: np.ndarray


def bake_texture(vertices, faces, uvs, source_vertices, source_faces, source_uvs, source_image,
                 tex_size: int = 512, *, source_samples: int | None = None,
                 max_distance: float | None = None) -> BakedTexture:
    """Carry a source mesh's colour map onto a target mesh's UVs by closest surface points.

    Both meshes must already be aligned in 3D (e.g. the template fitted to a scan, §4.1–4.2).
    The source surface is sampled densely (the texel points of a ``source_samples``² UV atlas
    of the source, coloured from ``source_image``); every covered texel of the target's UV atlas
    takes the colour of the nearest source sample. Used to put the Lee Perry-Smith scan
    (credit :data:`~.lee_perry_smith.LEE_PERRY_SMITH_CREDIT`) on the template's UVs once the
    template is fitted.

    Parameters
    ----------
    vertices, faces, uvs : (n, 3) float64, (F, 3) int64, (n, 2) float64
        Target mesh (already aligned with the source) and its UVs.
    source_vertices, source_faces, source_uvs : (m, 3), (G, 3), (m, 2)
        Source mesh and its UVs (v up).
    source_image : (Hs, Ws, 3) uint8
        Source colour map (row 0 at the top, sampled like :func:`facetransfer.render.sample_texture`).
    tex_size : int
    source_samples : int, optional, keyword-only
        Side of the source sampling atlas; default ``max(Hs, Ws)``.
    max_distance : float, optional, keyword-only
        Texels farther than this from any source sample are holes (filled); default 5% of the
        target's bounding-box diagonal.

    Returns
    -------
    BakedTexture
    """
    from scipy.spatial import cKDTree

    from ..render import sample_texture

    V, F = check_vertices(vertices, faces)
    U = check_uvs(uvs, V.shape[0])
    Vs, Fs = check_vertices(source_vertices, source_faces)
    Us = check_uvs(source_uvs, Vs.shape[0])
    img = np.asarray(source_image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise TextureError(f"source_image must be an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
    S = int(source_samples) if source_samples is not None else int(max(img.shape[:2]))
    src = UVAtlas(Fs, Us, S)
    P_src = src.interpolate(Vs)
    C_src = sample_texture(img, src.interpolate(Us))
    dst = uv_atlas(F, U, tex_size)
    P = dst.interpolate(V)
    d, j = cKDTree(P_src).query(P, k=1)
    if max_distance is None:
        max_distance = 0.05 * float(np.linalg.norm(np.ptp(V, axis=0)))
    ok = d <= max_distance
    col = np.where(ok[:, None], C_src[j], 0.0)
    known = dst.scatter(ok)
    tex = fill_holes(dst.scatter(col.astype(np.float32)), known)
    dist = dst.scatter(d.astype(np.float32), fill=np.inf)
    return BakedTexture(texture_to_uint8(tex), dist)

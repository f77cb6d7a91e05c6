"""The default face texture of a UV layout: procedural skin, or the Lee Perry-Smith scan.

:func:`default_face_texture` paints a deterministic procedural skin texture (skin tone, smooth
variation, fine noise so that a KLT tracker finds gradients everywhere, darker lips, brows and
eyelids where the iBUG-68 landmarks fall in UV space), or returns the Lee Perry-Smith scan's colour
map on the ICT-FaceKit UVs (:mod:`.lee_perry_smith`; credit
:data:`~.lee_perry_smith.LEE_PERRY_SMITH_CREDIT`).
Texture images follow :func:`facetransfer.render.sample_texture` (v up).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ..errors import FaceTransferError, ShapeError
from .base import TextureError, texture_to_uint8
from .lee_perry_smith import lee_perry_smith_template_texture, uses_ict_uvs

log = logging.getLogger(__name__)

__all__ = ["default_face_texture"]


#: iBUG-68 landmark index groups used to place features on the procedural texture.
_LIPS_OUTER = list(range(48, 60))
_LIPS_INNER = list(range(60, 68))
_BROWS = (list(range(17, 22)), list(range(22, 27)))
_EYES = (list(range(36, 42)), list(range(42, 48)))


def default_face_texture(model_or_uvs, size: int = 512, seed: int = 0, *,
                         source: str = "procedural") -> np.ndarray:
    """The default face texture for a face mesh's UV layout.

    ``source="procedural"``: a plain procedural skin texture: skin tone with smooth
    low-frequency variation, fine noise (so that a KLT tracker finds gradients everywhere) and,
    where the landmarks can be located in UV space, darker red lips, darker brows and eyelid
    lines. Deterministic, fast, needs no asset.

    ``source="lee-perry-smith"``: the Lee Perry-Smith scan carried onto the ICT-FaceKit template
    UVs by template fitting (:func:`lee_perry_smith_template_texture`; first call about 15 s,
    then cached). Needs a mesh whose UVs are ICT-FaceKit's (e.g. a model built from the ICT
    data sets). Show it with the credit :data:`~.lee_perry_smith.LEE_PERRY_SMITH_CREDIT`.
    ``source="auto"``: Lee Perry-Smith where it applies and its assets are available, else
    procedural.

    Parameters
    ----------
    model_or_uvs : MultilinearModel, FaceDataset, Mesh or (n, 2) array
        Anything with ``uvs`` (and optionally ``landmarks``, iBUG-68 vertex indices, and
        ``vertex_subset``, indices into the ICT-FaceKit mesh), or the uvs.
    size : int
        Texture width and height ``T``.
    seed : int
        Seed of the noise (procedural only).
    source : {"procedural", "lee-perry-smith", "auto"}, keyword-only

    Returns
    -------
    (T, T, 3) uint8 RGB, in the convention of :func:`facetransfer.render.sample_texture`.
    """
    if source not in ("procedural", "lee-perry-smith", "auto"):
        raise TextureError(f"source must be 'procedural', 'lee-perry-smith' or 'auto', got {source!r}")
    if source != "procedural":
        tex = _lee_perry_smith_or_none(model_or_uvs, size, required=source == "lee-perry-smith")
        if tex is not None:
            return tex
    U, lm = _uvs_and_landmarks(model_or_uvs)
    T = int(size)
    if T != size or T < 8 or T > 8192:
        raise TextureError(f"size must be an integer in 8..8192, got {size!r}")
    tex = _skin(T, np.random.default_rng(seed))
    if lm is not None:
        L = np.asarray(lm, dtype=np.int64)
        if L.ndim == 1 and L.size == 68 and L.min() >= 0 and L.max() < U.shape[0]:
            tex = _paint_features(tex, U[L] * (T - 1) * [1, -1] + [0, T - 1], T)
        else:
            log.warning("default_face_texture: landmarks are not 68 valid vertex indices; "
                        "painting skin only")
    return texture_to_uint8(tex)


def _lee_perry_smith_or_none(model_or_uvs, size: int, *, required: bool) -> np.ndarray | None:
    """The Lee Perry-Smith texture for ICT-FaceKit UVs; None (logged) where it does not apply or
    its assets are missing, unless ``required`` (then the error propagates)."""
    try:
        if not uses_ict_uvs(model_or_uvs):
            raise TextureError("the Lee Perry-Smith texture is carried onto ICT-FaceKit UVs; "
                               "this mesh's UVs are not ICT-FaceKit's")
        return lee_perry_smith_template_texture(size)
    except (FaceTransferError, RuntimeError, OSError, ImportError) as exc:
        if required:
            raise
        log.info("default_face_texture: Lee Perry-Smith texture not available (%s); "
                 "using the procedural texture", exc)
    return None


def _uvs_and_landmarks(model_or_uvs) -> tuple[np.ndarray, object]:
    """The checked UVs ``(n, 2) float64`` of a model, data set, mesh or array, and its landmarks
    (or None)."""
    if isinstance(model_or_uvs, np.ndarray):
        uvs, lm = model_or_uvs, None
    else:
        uvs = getattr(model_or_uvs, "uvs", None)
        lm = getattr(model_or_uvs, "landmarks", None)
    if uvs is None:
        raise TextureError("default_face_texture needs texture coordinates; the model has none")
    U = np.asarray(uvs, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] != 2 or U.shape[0] == 0 or not np.all(np.isfinite(U)):
        raise ShapeError(f"uvs must be a finite (n, 2) array, got {U.shape}")
    return U, lm


def _skin(T: int, rng: np.random.Generator) -> np.ndarray:
    """Procedural skin ``(T, T, 3)`` float64 (0..255): a mid skin tone, slow brightness and redness
    variation, and fine noise (gradients everywhere for a KLT tracker)."""
    base = np.array([214.0, 164.0, 138.0])  # a mid skin tone, RGB
    low = cv2.GaussianBlur(rng.normal(size=(T, T, 2)).astype(np.float32), (0, 0), T / 24)
    low /= np.maximum(low.std(axis=(0, 1)), 1e-6)
    # brightness (7 levels) and redness (4 levels) vary slowly over the face
    low = low[..., :1] * 7.0 * np.array([1.0, 0.85, 0.8]) + low[..., 1:] * 4.0 * np.array([1.0, -0.3, -0.3])
    mid = cv2.GaussianBlur(rng.normal(size=(T, T)).astype(np.float32), (0, 0), T / 128)
    mid *= 6.0 / max(float(mid.std()), 1e-6)
    fine = rng.normal(scale=5.0, size=(T, T)).astype(np.float32)
    fine = cv2.GaussianBlur(fine, (0, 0), 0.7) * 1.6
    return base + low + (mid + fine)[..., None]


def _paint_features(tex: np.ndarray, pts: np.ndarray, T: int) -> np.ndarray:
    """Darken lips, brows and eyelids at landmark texel positions ``pts`` (68, 2) (col, row)."""
    scale = np.linalg.norm(pts[45] - pts[36])  # outer eye corners: the face's width in texels
    if not np.isfinite(scale) or scale < 2:
        return tex

    def layer(draw) -> np.ndarray:
        m = np.zeros((T, T), np.uint8)
        draw(m)
        return cv2.GaussianBlur(m.astype(np.float32) / 255.0, (0, 0), max(scale * 0.02, 0.8))

    def poly(idx):
        return np.rint(pts[idx] * 16).astype(np.int32).reshape(-1, 1, 2)

    lips = layer(lambda m: cv2.fillPoly(m, [poly(_LIPS_OUTER)], 255, cv2.LINE_AA, shift=4))
    mouth = layer(lambda m: cv2.fillPoly(m, [poly(_LIPS_INNER)], 255, cv2.LINE_AA, shift=4))
    thick = max(int(round(scale * 0.06)), 1)
    brows = layer(lambda m: [cv2.polylines(m, [poly(b)], False, 255, thick, cv2.LINE_AA, shift=4)
                             for b in _BROWS])
    lids = layer(lambda m: [cv2.polylines(m, [poly(e)], True, 255, max(thick // 2, 1),
                                          cv2.LINE_AA, shift=4) for e in _EYES])
    lip_col = np.array([170.0, 92.0, 90.0])
    tex = tex * (1 - lips[..., None]) + (lip_col + (tex - tex.mean((0, 1))) * 0.5) * lips[..., None]
    tex = tex * (1 - 0.5 * mouth[..., None])
    tex = tex * (1 - 0.55 * brows[..., None]) + np.array([60.0, 40.0, 30.0]) * 0.55 * brows[..., None]
    tex = tex * (1 - 0.35 * lids[..., None])
    return tex

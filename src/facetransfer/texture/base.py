"""What every texture module shares: the error type, input checks and the colour convention.

Colours are float32 on the 0..255 scale of the uint8 frames; :func:`texture_to_uint8` rounds them
back. The checks validate at the public boundary of :mod:`facetransfer.texture` and name the
shape they expected.
"""

from __future__ import annotations

import numpy as np

from ..errors import FaceTransferError, ShapeError

__all__ = ["TextureError", "check_square_texture", "texture_to_uint8"]


class TextureError(FaceTransferError):
    """Bad input to texture lifting, merging or the texture function."""


def check_frame(frame) -> np.ndarray:
    """The frame as an ``(H, W, 3) uint8`` RGB array, or :class:`ShapeError`."""
    f = np.asarray(frame)
    if f.ndim != 3 or f.shape[2] != 3 or f.shape[0] == 0 or f.shape[1] == 0 or f.dtype != np.uint8:
        raise ShapeError(f"frame must be an (H, W, 3) uint8 RGB image, got {f.shape} {f.dtype}")
    return f


def check_vertices(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Finite vertices ``(n, 3) float64`` and in-range faces ``(F, 3) int64``, both non-empty."""
    V = np.asarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0:
        raise ShapeError(f"vertices must be (n, 3) with n > 0, got {V.shape}")
    if not np.all(np.isfinite(V)):
        raise TextureError("vertices contain NaN or infinite coordinates")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or not np.issubdtype(F.dtype, np.integer):
        raise ShapeError(f"faces must be a non-empty (F, 3) integer array, got {F.shape} {F.dtype}")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= V.shape[0]:
        raise TextureError(f"faces index vertices {F.min()}..{F.max()} but there are {V.shape[0]}")
    return V, F


def check_uvs(uvs, n: int) -> np.ndarray:
    """Finite per-vertex texture coordinates ``(n, 2) float64``."""
    if uvs is None:
        raise TextureError("this mesh has no texture coordinates (uvs is None)")
    U = np.asarray(uvs, dtype=np.float64)
    if U.shape != (n, 2):
        raise ShapeError(f"uvs must be (n_vertices, 2) = ({n}, 2), got {U.shape}")
    if not np.all(np.isfinite(U)):
        raise TextureError("uvs contain NaN or infinite values")
    return U


def check_raster(raster, frame: np.ndarray):
    """``raster`` (a :class:`facetransfer.render.Raster` or None) if it matches the frame's size."""
    if raster is not None and raster.tri_id.shape != frame.shape[:2]:
        raise ShapeError(f"raster is {raster.tri_id.shape} (H, W) but the frame is {frame.shape[:2]}")
    return raster


def check_square_texture(size, what: str, error: type[ValueError] = TextureError) -> None:
    """Raise ``error`` (a ``ValueError``) naming ``what`` unless ``size`` ``(W, H)`` is square:
    the model's UVs are laid out on a square, as ``facetransfer texture default|lift`` write
    it (a contact sheet, a frame or a photo is no texture of them). ``export --texture`` and
    ``synth-video --texture`` check their image by it."""
    if size[0] != size[1]:
        raise error(f"{what} is {size[0]}x{size[1]}: a texture of the model's UVs is a "
                    "square image in their layout (as `facetransfer texture default` or "
                    "`texture lift` writes it, e.g. 512x512)")


def texture_to_uint8(texture) -> np.ndarray:
    """Round a float 0..255 texture (or colours) to uint8, clipping to the range."""
    return np.clip(np.rint(np.asarray(texture, dtype=np.float64)), 0, 255).astype(np.uint8)


def default_tol(V: np.ndarray) -> float:
    """Default depth tolerance of the visibility test: 1% of the bounding-box diagonal of ``V``."""
    return 0.01 * float(np.linalg.norm(np.ptp(V, axis=0)))

"""Similarity alignment from corresponding points (§4.2: "rigidly aligning the template and the
scan with Procrustes' alignment"), in closed form after Umeyama, "Least-squares estimation of
transformation parameters between two point patterns", IEEE PAMI 13(4), 1991.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FaceTransferError, ShapeError


@dataclass(frozen=True)
class Similarity:
    """``y = scale * rotation @ x + translation``.

    Attributes
    ----------
    scale : float
    rotation : (3, 3) float64, proper (det +1)
    translation : (3,) float64
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Map points ``(..., 3)``."""
        return self.scale * np.asarray(x) @ self.rotation.T + self.translation

    def inverse(self) -> "Similarity":
        """The inverse similarity."""
        r = self.rotation.T
        return Similarity(1.0 / self.scale, r, -(r @ self.translation) / self.scale)

    def compose(self, inner: "Similarity") -> "Similarity":
        """``self ∘ inner``: first ``inner``, then ``self``."""
        return Similarity(self.scale * inner.scale, self.rotation @ inner.rotation,
                          self.apply(inner.translation))

    @staticmethod
    def identity() -> "Similarity":
        return Similarity(1.0, np.eye(3), np.zeros(3))


def similarity_procrustes(src: np.ndarray, dst: np.ndarray, *, weights: np.ndarray | None = None,
                          with_scale: bool = True) -> Similarity:
    """Least-squares similarity mapping ``src`` onto ``dst``.

    Minimises ``Σ w_i |dst_i − (s R src_i + t)|²`` over scale ``s > 0``, rotation ``R`` (no
    reflection) and translation ``t`` (Umeyama 1991, Eqs. 40–42).

    Parameters
    ----------
    src, dst : (k, 3) float
        Corresponding points, ``k >= 3`` not collinear.
    weights : (k,) float, optional
        Non-negative weights.
    with_scale : bool
        ``False`` fixes ``s = 1`` (rigid).

    Returns
    -------
    Similarity
    """
    a = np.asarray(src, dtype=np.float64)
    b = np.asarray(dst, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape:
        raise ShapeError(f"src and dst must be matching (k, 3) arrays, got {a.shape} and {b.shape}")
    if len(a) < 3:
        raise FaceTransferError(f"Procrustes needs at least 3 point pairs, got {len(a)}")
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(a),) or np.any(w < 0) or w.sum() <= 0:
        raise ShapeError(f"weights must be ({len(a)},) non-negative with a positive sum")
    w = w / w.sum()
    ma, mb = w @ a, w @ b
    ac, bc = a - ma, b - mb
    cov = (bc * w[:, None]).T @ ac                       # Umeyama Eq. (38)
    u, d, vt = np.linalg.svd(cov)
    sgn = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:         # Eq. (39): avoid a reflection
        sgn[2] = -1.0
    r = u @ np.diag(sgn) @ vt                            # Eq. (40)
    var_a = float(w @ np.sum(ac ** 2, axis=1))
    if var_a <= 1e-300 or np.sort(d)[1] <= 1e-12 * max(d.max(), 1e-300):
        raise FaceTransferError("Procrustes points are coincident or collinear")
    s = float(d @ sgn) / var_a if with_scale else 1.0    # Eq. (42)
    t = mb - s * r @ ma                                  # Eq. (41)
    return Similarity(s, r, t)


def rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation (3, 3) by angle ``|w|`` about ``w``."""
    th = float(np.linalg.norm(w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx

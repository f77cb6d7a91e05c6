"""The performance-driven texture function (§6): nearest neighbours in attribute space.

"A simple performance-driven texture function can be obtained with the weighted sum of nearest
neighbors." :class:`TextureFunction` holds the lifted textures of the training frames and their
attribute vectors (:func:`attribute_vector`: the weights of every mode but identity).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import FaceTransferError, RewriteError, ShapeError
from ..io.atomic import atomic_path
from .base import TextureError
from .merge import MergedTexture, fill_vertex_colors, merge_textures, stack_lifted

__all__ = ["TextureFunction", "attribute_vector", "nearest_frames"]


class TextureFunction:
    """Performance-driven texture: weighted sum of nearest neighbours in attribute space (§6).

    Built from textures lifted from ``F`` tracked frames and the attribute vectors of those
    frames (e.g. expression and viseme weights concatenated). For a query attribute vector
    ``a`` with nearest training frames ``i = 1..k`` at distances ``d_i``, every texel is

        tex(a) = (Σ_i κ_i w_i tex_i + λ tex_all) / (Σ_i κ_i w_i + λ)                  (T1)

    with kernel weights ``κ_i`` (normalised to sum 1), the per-texel confidences ``w_i`` of
    Eq. (L1), and ``tex_all`` the merged texture of all frames (weight ``λ = prior * min_i κ_i``),
    which fills texels none of the neighbours saw. A query equal to a training vector returns that
    frame's texture wherever the frame saw it (the other neighbours fill the rest).

    Parameters
    ----------
    textures : (F, ..., 3) float
        Lifted textures (images (F, T, T, 3) or per-vertex colours (F, n, 3)), 0..255; kept
        as float16 if given so (half the memory), else as float32.
    weights : (F, ...) float
        Their confidences (Eq. (L1)); float16 kept likewise.
    attributes : (F, r) float
        Attribute vector of every frame.
    k : int
        Neighbours used (clipped to F).
    kernel : {"gaussian", "inverse"}
        ``exp(-d² / (2 h²))`` or ``1 / d²``.
    bandwidth : float, optional
        ``h`` of the Gaussian kernel; default the median distance from each training vector to
        its nearest other one (1 with a single frame).
    prior : float
        ``λ / min_i κ_i`` of Eq. (T1), > 0.
    faces : (F, 3) int64, optional
        For per-vertex colours: fill vertices no frame saw in ``tex_all`` by harmonic
        interpolation over the mesh (:func:`fill_vertex_colors`); otherwise they stay 0.

    Notes
    -----
    All lifted textures are held in memory, as float32 ``F * T * T * 16`` bytes (200 frames at
    T = 256 take 210 MB), or as float16 ``F * T * T * 8`` where given so; lift every few frames
    or use a smaller ``T`` for long clips. Eq. (T1) is evaluated in float64 whatever the storage.

    References
    ----------
    Vlasic et al. 2005, §6 ("the weighted sum of nearest neighbors").
    """

    def __init__(self, textures, weights, attributes, *, k: int = 4, kernel: str = "gaussian",
                 bandwidth: float | None = None, prior: float = 1e-6, faces=None):
        C, Wt = _stored(textures), _stored(weights)
        A = np.asarray(attributes, dtype=np.float64)
        if A.ndim != 2 or A.shape[0] == 0 or A.shape[1] == 0:
            raise ShapeError(f"attributes must be (F, r) with F, r > 0, got {A.shape}")
        if not np.all(np.isfinite(A)):
            raise TextureError("attributes contain NaN or infinite values")
        nF = A.shape[0]
        if C.shape[:1] != (nF,) or C.shape[-1] != 3 or Wt.shape != C.shape[:-1]:
            raise ShapeError(f"textures (F, ..., 3) and weights (F, ...) with F = {nF} expected, "
                             f"got {C.shape} and {Wt.shape}")
        if not (np.all(np.isfinite(Wt)) and np.all(Wt >= 0)) or not np.all(np.isfinite(C)):
            raise TextureError("textures must be finite and weights finite and >= 0")
        if kernel not in ("gaussian", "inverse"):
            raise TextureError(f"kernel must be 'gaussian' or 'inverse', got {kernel!r}")
        if int(k) != k or k < 1:
            raise TextureError(f"k must be an integer >= 1, got {k!r}")
        if not (np.isfinite(prior) and prior > 0):
            raise TextureError(f"prior must be a finite number > 0, got {prior}")
        self.textures = C
        self.weights = Wt
        self.attributes = A
        self.k = int(min(k, nF))
        self.kernel = kernel
        if bandwidth is None:
            bandwidth = _median_nn_distance(A)
        if not (np.isfinite(bandwidth) and bandwidth > 0):
            raise TextureError(f"bandwidth must be a finite number > 0, got {bandwidth}")
        self.bandwidth = float(bandwidth)
        self.prior = float(prior)
        fill = "pushpull" if C.ndim == 4 else "none"
        merged = merge_textures(list(zip(C, Wt)), fill=fill)
        if C.ndim == 3 and faces is not None:  # per-vertex colours: fill unseen vertices
            filled = fill_vertex_colors(merged.texture, merged.weight > 1e-6, faces)
            merged = MergedTexture(filled, merged.weight)
        self.merged = merged

    @classmethod
    def from_lifted(cls, lifted: Sequence, attributes, **kwargs) -> "TextureFunction":
        """Build from a sequence of (texture, weight) pairs, one per frame (see ``__init__``)."""
        C, Wt = stack_lifted(lifted)
        return cls(C, Wt, attributes, **kwargs)

    @property
    def n_frames(self) -> int:
        return int(self.attributes.shape[0])

    def neighbours(self, attributes) -> tuple[np.ndarray, np.ndarray]:
        """Indices (k,) of the nearest training frames and their kernel weights (k,), summing to 1."""
        a = np.asarray(attributes, dtype=np.float64)
        if a.shape != (self.attributes.shape[1],) or not np.all(np.isfinite(a)):
            raise ShapeError(f"attributes must be a finite ({self.attributes.shape[1]},) vector, "
                             f"got shape {a.shape}")
        d = np.linalg.norm(self.attributes - a, axis=1)
        idx = np.argsort(d, kind="stable")[: self.k]
        dk = d[idx]
        exact = dk <= 1e-12 * max(1.0, float(np.abs(a).max()))
        if self.kernel == "inverse":
            kappa = 1.0 / np.where(exact, 1.0, dk) ** 2
        else:
            kappa = np.exp(-0.5 * ((dk - dk[0]) / self.bandwidth) ** 2)  # shifted: no underflow
        if exact.any():
            # a query equal to training frames returns them; the other neighbours only fill
            # texels those frames did not see
            kappa = np.where(exact, 1.0, 1e-9 * kappa / kappa.max())
        return idx, kappa / kappa.sum()

    def __call__(self, attributes) -> np.ndarray:
        """Texture for one attribute vector (r,): Eq. (T1); shape like one training texture."""
        idx, kappa = self.neighbours(attributes)
        w = kappa.reshape((-1,) + (1,) * (self.weights.ndim - 1)) * self.weights[idx]  # (k, ...)
        lam = self.prior * float(kappa.min())  # λ of Eq. (T1), below every neighbour's kernel weight
        fb = self.merged.texture
        num = np.einsum("k...,k...c->...c", w, self.textures[idx]) + lam * fb
        den = (w.sum(axis=0) + lam)[..., None]
        out = np.divide(num, den, out=fb.astype(np.float64), where=den > 0)
        return out.astype(np.float32)

    def save(self, path, *, overwrite: bool = True) -> None:
        """Write to an ``.npz`` file (atomically; ``overwrite=False``: an existing one, also
        one another writer made meanwhile, is refused)."""
        with atomic_path(path, overwrite=overwrite) as tmp:
            np.savez_compressed(tmp, textures=self.textures, weights=self.weights,
                                attributes=self.attributes, k=self.k, kernel=self.kernel,
                                bandwidth=self.bandwidth, prior=self.prior)

    @classmethod
    def load(cls, path) -> "TextureFunction":
        """Read a file written by :meth:`save` (any damage one TextureError naming it: before,
        a truncated file was BadZipFile, an ``.npy`` a TypeError)."""
        from ..io.npz import read_npz

        z = read_npz(path, "texture function", TextureError)
        try:
            return cls(z["textures"], z["weights"], z["attributes"], k=int(z["k"]),
                       kernel=str(z["kernel"]), bandwidth=float(z["bandwidth"]),
                       prior=float(z["prior"]))
        except (OSError, KeyError, ValueError, TypeError, OverflowError) as exc:
            if isinstance(exc, FaceTransferError):
                raise
            raise TextureError(f"cannot read texture function {path}: {exc}") from None


def _stored(a) -> np.ndarray:
    """``a`` as float16 if it is so, else as float32 (the storage of :class:`TextureFunction`)."""
    a = np.asarray(a)
    return a if a.dtype == np.float16 else a.astype(np.float32, copy=False)


def _median_nn_distance(A: np.ndarray) -> float:
    if A.shape[0] < 2:
        return 1.0
    D = np.linalg.norm(A[:, None] - A[None], axis=2) if A.shape[0] <= 2000 else None
    if D is None:
        from scipy.spatial import cKDTree
        d, _ = cKDTree(A).query(A, k=2)
        nn = d[:, 1]
    else:
        np.fill_diagonal(D, np.inf)
        nn = D.min(axis=1)
    nn = nn[nn > 0]
    return float(np.median(nn)) if nn.size else 1.0


def attribute_vector(model, weights: dict) -> np.ndarray:
    """Concatenated weights of every mode but identity (the first mode): ``(..., Σ r_k)``.

    These are the coordinates of the texture function's nearest-neighbour search (§6: the
    texture varies with expression and viseme, not with the constant identity).
    """
    modes = list(model.mode_names[1:])
    if not modes:
        raise TextureError("the model has only an identity mode: no attributes to index by")
    missing = [m for m in modes if m not in weights]
    if missing:
        raise TextureError(f"weights lack the modes {missing}")
    return np.concatenate([np.asarray(weights[m], dtype=np.float64) for m in modes], axis=-1)


def nearest_frames(query: np.ndarray, bank: np.ndarray, valid: np.ndarray | None = None
                   ) -> np.ndarray:
    """For each query row the index of the nearest bank row (Euclidean), among ``valid`` ones.

    The performance-driven texture of §6 ("the weighted sum of nearest neighbors") with one
    neighbour: the frame of the texture video whose attributes are closest
    (:class:`TextureFunction` weighs ``k`` of them): a transfer's mouth frames
    (:mod:`facetransfer.transfer_plan`).

    Parameters
    ----------
    query : (n, r)
    bank : (m, r)
    valid : (m,) bool, optional

    Returns
    -------
    (n,) int64
    """
    Q = np.asarray(query, np.float64)
    B = np.asarray(bank, np.float64)
    if Q.ndim != 2 or B.ndim != 2 or Q.shape[1] != B.shape[1]:
        raise ShapeError(f"query and bank must be (n, r) and (m, r), got {Q.shape} and "
                         f"{B.shape}")
    ok = np.ones(B.shape[0], bool) if valid is None else np.asarray(valid, bool)
    if ok.shape != B.shape[:1]:
        raise ShapeError(f"valid must be ({B.shape[0]},) for a bank of {B.shape}, got "
                         f"{ok.shape}")
    if not ok.any():
        raise RewriteError("no frame to take a texture from (all lost)")
    idx = np.flatnonzero(ok)
    d = ((Q[:, None, :] - B[None, idx, :]) ** 2).sum(axis=-1)
    return idx[np.argmin(d, axis=1)]

"""Face regions for §4.4's imputation: separate mode covariances per soft region, fills blended.

Face regions
------------
The covariances are shared by all coordinates, so the mouth is predicted with statistics
dominated by the rest of the face (§4.4: "the averaging scheme seems to do a better job at keeping
the lips sealed ... We could obtain better results by preferentially weighting detail around the
mouth"). :func:`impute_tensor_regions` gives each soft region its own covariances (coordinates
weighted by membership) and blends the fills; ``regions="mouth"`` is the paper's suggestion.

References
----------
Vlasic, Brand, Pfister, Popović 2005, "Face Transfer with Multilinear Models", §4.4.
"""

from __future__ import annotations

import numpy as np

from ..datasets.base import FaceDataset
from ..errors import DatasetError, ShapeError
from .joint import TensorImputation, impute_tensor

__all__ = ["region_memberships", "dataset_regions", "impute_tensor_regions"]


def region_memberships(vertices: np.ndarray, *, regions: str | int = "mouth",
                       landmarks: np.ndarray | None = None, width: float = 0.3,
                       seed: int = 0) -> np.ndarray:
    """Soft face regions (a partition of unity over vertices) for region-wise covariances.

    §4.4 notes that a closed mouth is predicted badly because the mode covariances are dominated
    by the rest of the face, and suggests "preferentially weighting detail around the mouth".
    Each region gets its own mode covariances (from the coordinates weighted by its membership) and
    the fills are blended with the same memberships (:func:`impute_tensor_regions`).

    Parameters
    ----------
    vertices : (n, 3) float64
        A representative shape (e.g. the mean of the known meshes).
    regions : "mouth" or int
        ``"mouth"``: two regions, a Gaussian bump of radius ``width`` × (outer eye-corner distance)
        around the iBUG-68 mouth landmarks (48–67) and the rest; an int ``k``: ``k`` soft k-means
        clusters of the vertices.
    landmarks : (68,) int64, required for ``"mouth"``
    width : float
    seed : int, for the k-means initialisation

    Returns
    -------
    (R, n) float64, non-negative, columns summing to 1
    """
    V = np.asarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or not np.isfinite(V).all():
        raise ShapeError(f"vertices must be a finite (n, 3) array, got {V.shape}")
    if isinstance(regions, str):
        if regions != "mouth":
            raise ValueError(f"regions must be 'mouth' or a number of clusters, got {regions!r}")
        if landmarks is None or len(landmarks) != 68:
            raise DatasetError("mouth regions need the 68 iBUG landmark vertices of the data set")
        lm = np.asarray(landmarks, dtype=np.int64)
        eye = float(np.linalg.norm(V[lm[36]] - V[lm[45]]))
        d = np.linalg.norm(V - V[lm[48:68]].mean(axis=0), axis=1)
        m = np.exp(-0.5 * (d / (width * eye)) ** 2)
        return np.stack([m, 1.0 - m])
    k = int(regions)
    if not 1 <= k <= len(V):
        raise ValueError(f"number of regions must be between 1 and {len(V)}, got {k}")
    from scipy.cluster.vq import kmeans2

    cent, _ = kmeans2(V, k, seed=seed, minit="++")
    dist = np.linalg.norm(V[:, None] - cent[None], axis=2)  # (n, k)
    if k == 1:
        return np.ones((1, len(V)))
    cd = np.linalg.norm(cent[:, None] - cent[None], axis=2) + np.diag(np.full(k, np.inf))
    sig = max(float(np.median(cd.min(axis=1))) / 2, 1e-12)
    logw = -0.5 * (dist / sig) ** 2
    w = np.exp(logw - logw.max(axis=1, keepdims=True))
    return (w / w.sum(axis=1, keepdims=True)).T


def impute_tensor_regions(tensor: np.ndarray, mask: np.ndarray, memberships: np.ndarray,
                          **kw) -> TensorImputation:
    """:func:`impute_tensor` once per soft region, fills blended by the memberships.

    Parameters
    ----------
    tensor : (P, d_1, ..., d_K) array, P = 3 n (vertex-major coordinates)
    mask : (d_1, ..., d_K) bool
    memberships : (R, n) array, columns summing to 1 (:func:`region_memberships`)
    **kw : passed to :func:`impute_tensor` (not ``row_weights``)

    Returns
    -------
    TensorImputation
        ``history`` is the sum of the regions' objectives (each padded with its final value), so it
        never rises either.
    """
    Mb = np.asarray(memberships, dtype=np.float64)
    P = np.shape(tensor)[0]
    if Mb.ndim != 2 or 3 * Mb.shape[1] != P or (Mb < 0).any() \
            or not np.allclose(Mb.sum(axis=0), 1.0):
        raise ShapeError(f"memberships must be (R, {P // 3}) non-negative with columns summing "
                         f"to 1, got {Mb.shape}")
    out = None
    hists, its, conv, covs = [], 0, True, []
    for m in Mb:
        if not m.any():
            continue
        w = np.repeat(m, 3)
        r = impute_tensor(tensor, mask, row_weights=w, **kw)
        part = w.reshape((P,) + (1,) * (r.tensor.ndim - 1)) * r.tensor
        out = part if out is None else out + part
        hists.append(r.history)
        its, conv = max(its, r.iterations), conv and r.converged
        covs.extend(r.covariances)
    known = np.asarray(mask, dtype=bool)
    out[:, known] = np.asarray(tensor, dtype=np.float64)[:, known]  # exact, not re-blended
    L = max(len(h) for h in hists)
    hist = np.sum([np.concatenate([h, np.full(L - len(h), h[-1])]) if h else np.zeros(L)
                   for h in hists], axis=0) if L else np.zeros(0)
    return TensorImputation(out, tuple(float(x) for x in hist), its, conv, tuple(covs))


def dataset_regions(dataset: FaceDataset, regions: str | int) -> np.ndarray:
    """:func:`region_memberships` on the mean of a data set's known meshes, shape (R, n)."""
    mean = dataset.vertices[dataset.mask].mean(axis=0)
    return region_memberships(mean, regions=regions, landmarks=dataset.landmarks)

"""Feature-preserving mesh smoothing, the preprocessing step of §4.1 (Vlasic et al. 2005).

Implements the non-iterative bilateral filter of Jones, Durand & Desbrun, "Non-iterative,
feature-preserving mesh smoothing", SIGGRAPH 2003 (doi:10.1145/1201775.882367): every vertex
``p`` moves to a weighted mean of its projections ``Π_q(p)`` onto the tangent planes of nearby
triangles ``q``,

    p' = Σ_q Π_q(p) a_q f(|c_q − p|) g(|Π_q(p) − p|) / Σ_q a_q f(|c_q − p|) g(|Π_q(p) − p|)   (Jones Eq. 2)

with ``a_q`` the triangle area, ``c_q`` its centroid, ``f`` a spatial Gaussian (σ_f = ``sigma_c``)
and ``g`` an influence Gaussian (σ_g = ``sigma_s``) that discounts predictions from across a crease.
Triangle normals are "mollified" (computed after a spatial-only smoothing with σ_f/2, Jones §3.1)
so that noise does not corrupt the planes. An umbrella (uniform Laplacian) smoother is provided as
the baseline it is compared against.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import FaceTransferError, ShapeError
from .meshops import face_normals


def _check(vertices, faces):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ShapeError(f"vertices must be (n, 3) and faces (F, 3), got {v.shape} and {f.shape}")
    if len(f) == 0 or not np.all(np.isfinite(v)):
        raise FaceTransferError("smoothing needs a non-empty mesh with finite coordinates")
    return v, f


def mean_edge_length(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Mean length of the triangle edges (each edge counted once per triangle)."""
    v, f = vertices, faces
    e = np.concatenate([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]], v[f[:, 0]] - v[f[:, 2]]])
    return float(np.linalg.norm(e, axis=1).mean())


def bilateral_smooth(vertices: np.ndarray, faces: np.ndarray, *, sigma_c: float | None = None,
                     sigma_s: float | None = None,
                     progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Smooth a mesh with the non-iterative bilateral filter of Jones et al. (2003).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int
    sigma_c : float, optional
        Spatial σ_f (scan units); neighbourhoods extend to ``2 * sigma_c``.
        Default: 2 × the mean edge length.
    sigma_s : float, optional
        Influence σ_g (scan units): predictions moving a vertex much further than this are
        discounted (they come from across a feature). Default: ``sigma_c / 2``.
    progress : callable(done, total), optional
        Called after each chunk of vertices of each of the two passes (a 1.2-million-face
        scan: ~60 chunks, minutes).

    Returns
    -------
    (n, 3) float64
        Smoothed vertices; topology unchanged.

    References
    ----------
    Jones, Durand & Desbrun 2003, Eq. (2) and §3.1 (mollification); Vlasic et al. 2005, §4.1.
    """
    v, f = _check(vertices, faces)
    sc = 2.0 * mean_edge_length(v, f) if sigma_c is None else float(sigma_c)
    ss = 0.5 * sc if sigma_s is None else float(sigma_s)
    if not (sc > 0 and ss > 0):
        raise FaceTransferError(f"sigma_c and sigma_s must be positive, got {sc} and {ss}")
    cent = v[f].mean(axis=1)                              # (F, 3)
    _, area = face_normals(v, f)
    tree_c = cKDTree(cent)
    chunks = _vertex_chunks(v, tree_c, sc)
    # a scan in one chunk (the default sigma_c's usual case): its pairs found once, both passes
    once = _pairs(v, tree_c, 2.0 * sc) if len(chunks) == 1 else None

    def pairs(sl: slice):
        return once if once is not None else _pairs(v[sl], tree_c, 2.0 * sc)

    vm = v.copy()
    for n, sl in enumerate(chunks):
        vm[sl] = _mollified(v[sl], pairs(sl), cent, area, sc)
        if progress is not None:
            progress(n + 1, 2 * len(chunks))
    nq, _ = face_normals(vm, f)
    out = v.copy()
    for n, sl in enumerate(chunks):
        out[sl] = _predicted(v[sl], pairs(sl), cent, area, nq, sc, ss)
        if progress is not None:
            progress(len(chunks) + n + 1, 2 * len(chunks))
    return out


def _mollified(p: np.ndarray, pairs, cent: np.ndarray, area: np.ndarray, sc: float
               ) -> np.ndarray:
    """Jones §3.1: the vertices ``p`` smoothed by a spatial filter of width σ_f/2, whose
    faces' normals are the mollified ones (``pairs``: :func:`_pairs` of ``p``)."""
    i, q, d = pairs
    wm = area[q] * np.exp(-0.5 * (d / (0.5 * sc)) ** 2)
    return _weighted_mean(i, wm, cent[q], p)


def _predicted(p: np.ndarray, pairs, cent: np.ndarray, area: np.ndarray, nq: np.ndarray,
               sc: float, ss: float) -> np.ndarray:
    """Jones Eq. (2) for the vertices ``p``: their predictions Π_q(p) = p + ((c_q − p)·n_q) n_q
    onto the faces ``q`` near them (``pairs``), weighted by area, f and g."""
    i, q, d = pairs
    h = np.einsum("ij,ij->i", cent[q] - p[i], nq[q])
    pred = p[i] + h[:, None] * nq[q]
    w = area[q] * np.exp(-0.5 * (d / sc) ** 2) * np.exp(-0.5 * (h / ss) ** 2)
    return _weighted_mean(i, w, pred, p)


def _pairs(v: np.ndarray, tree_c: cKDTree, radius: float):
    """(vertex, face) pairs within ``radius``: local vertex indices, face indices, distances."""
    pairs = cKDTree(v).sparse_distance_matrix(tree_c, radius, output_type="coo_matrix")
    return pairs.row, pairs.col, pairs.data


def _weighted_mean(i: np.ndarray, w: np.ndarray, x: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Per vertex ``i`` the ``w``-weighted mean of the rows ``x``; ``keep``'s row where the
    weights vanish."""
    num = np.zeros_like(keep)
    np.add.at(num, i, w[:, None] * x)
    den = np.bincount(i, weights=w, minlength=len(keep))
    return np.where(den[:, None] > 1e-300, num / np.maximum(den, 1e-300)[:, None], keep)


#: Bytes :func:`bilateral_smooth` holds per (vertex, face) pair within ``2 sigma_c``: the
#: pair's indices and distance, its weights, heights and predictions (measured: 120 on an ICT
#: face at 5.8 and 19.9 million pairs).
PAIR_BYTES = 120

#: The most bytes of pairs one chunk of vertices holds (less where less memory is available).
CHUNK_BYTES = 1 << 30


def _vertex_chunks(v: np.ndarray, tree_c: cKDTree, sc: float) -> list[slice]:
    """Slices of the vertices whose (vertex, face) pairs take at most :data:`CHUNK_BYTES` (or
    an eighth of the memory available; a vertex whose own pairs take more is a chunk alone):
    the pairs of the whole scan at once took ~28 GiB for a 1.2-million-face scan at the
    default sigma_c, or for an ICT face at a sigma_c of its size (every vertex seeing every
    face). Each vertex's pairs are counted (a few percent of the smoothing's time; a count on
    a sample put the chunks of a denser part of a scan times over the budget). The result is
    the same in any chunks: each vertex's sums are its own."""
    from ..io.memory import available_memory

    budget = min(CHUNK_BYTES, available_memory() // 8) // PAIR_BYTES   # pairs a chunk holds
    held = np.zeros(len(v) + 1, np.int64)           # held[j]: the pairs of vertices 0..j-1
    np.cumsum(tree_c.query_ball_point(v, 2.0 * sc, return_length=True), out=held[1:])
    chunks, k = [], 0
    while k < len(v):
        end = max(k + 1, int(np.searchsorted(held, held[k] + budget, side="right")) - 1)
        chunks.append(slice(k, end))
        k = end
    return chunks


def laplacian_smooth(vertices: np.ndarray, faces: np.ndarray, *, iterations: int = 1,
                     lam: float = 0.5) -> np.ndarray:
    """Umbrella-operator smoothing: ``x ← x + λ (mean of neighbours − x)``, repeated.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int
    iterations : int
    lam : float in (0, 1]

    Returns
    -------
    (n, 3) float64
    """
    v, f = _check(vertices, faces)
    n = len(v)
    r = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    c = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    a = sp.coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)).tocsr()
    a.data[:] = 1.0
    deg = np.asarray(a.sum(axis=1)).ravel()
    m = sp.diags(1.0 / np.maximum(deg, 1)) @ a
    x = v.copy()
    for _ in range(int(iterations)):
        x = x + lam * (m @ x - x)
    return x

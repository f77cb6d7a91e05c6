"""Scan validation and repair, face normals, Laplacians and closest points on a triangle surface.

Everything here is plain array geometry: vertices ``(n, 3) float64``, triangles ``(F, 3) int64``.
Vertex normals are :func:`facetransfer.geometry.vertex_normals` (area-weighted, unit, zero on
vertices of no non-degenerate face).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import MeshError, ShapeError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScanMesh:
    """A cleaned scan: merged duplicate vertices, no degenerate or repeated faces, manifold edges.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64
    boundary : (n,) bool
        Vertices on a boundary edge (an edge used by one triangle: holes and the cropped rim).
    notes : tuple of str
        What the cleaning changed (merged vertices, dropped faces), for reports.
    """

    vertices: np.ndarray
    faces: np.ndarray
    boundary: np.ndarray
    notes: tuple = field(default_factory=tuple)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals ``(F, 3)`` and areas ``(F,)`` of triangles (zero normal for zero area)."""
    v = vertices
    cr = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    norm = np.linalg.norm(cr, axis=1)
    n = cr / np.maximum(norm, 1e-300)[:, None]
    return n, 0.5 * norm


def edge_use_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges of a triangle list.

    Returns
    -------
    edges : (E, 2) int64
        Unique sorted edges.
    counts : (E,) int64
        Number of triangles using each edge.
    face_edge : (F, 3) int64
        Index into ``edges`` of the edge opposite vertex ``k`` of each face.
    """
    opp = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)  # (F, 3, 2)
    e = np.sort(opp.reshape(-1, 2), axis=1)
    edges, inv, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    return edges, counts, inv.reshape(-1, 3)


def drop_nonmanifold_faces(vertices: np.ndarray, faces: np.ndarray
                           ) -> tuple[np.ndarray, int, int]:
    """Make every edge manifold: on an edge shared by more than two triangles keep the two
    largest and drop the others.

    One pass suffices: dropping faces only lowers the use count of other edges.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int

    Returns
    -------
    faces : (F', 3) int64
        Kept faces, in their original order.
    n_edges : int
        Non-manifold edges found.
    n_dropped : int
        Faces dropped.
    """
    f = np.asarray(faces, dtype=np.int64)
    _, counts, face_edge = edge_use_counts(f)
    bad = counts > 2
    if not bad.any():
        return f, 0, 0
    _, area = face_normals(np.asarray(vertices, np.float64), f)
    fe = face_edge.ravel()                       # (3F,) edge of each face corner
    fid = np.repeat(np.arange(len(f)), 3)
    sel = bad[fe]
    e, fi = fe[sel], fid[sel]
    order = np.lexsort((-area[fi], e))           # per edge, largest faces first
    e, fi = e[order], fi[order]
    start = np.r_[0, np.flatnonzero(np.diff(e)) + 1]
    rank = np.arange(len(e)) - np.repeat(start, np.diff(np.r_[start, len(e)]))
    drop = np.zeros(len(f), dtype=bool)
    drop[fi[rank >= 2]] = True
    return f[~drop], int(bad.sum()), int(drop.sum())


def clean_scan(vertices: np.ndarray, faces: np.ndarray, *, name: str = "scan",
               merge_tol: float | None = None) -> ScanMesh:
    """Validate and repair a scan: merge duplicate vertices, drop degenerate/repeated faces.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int
    name : str
        Used in messages (the file name).
    merge_tol : float, optional
        Vertices closer than this are merged; default ``1e-9`` × bounding-box diagonal.

    Returns
    -------
    ScanMesh
        Unreferenced vertices are removed, so vertex indices can differ from the input.

    Raises
    ------
    MeshError
        Empty, non-finite, bad face indices, or no valid triangle left.

    Notes
    -----
    Raw scans that were remeshed or decimated (vertex clustering) have non-manifold edges, shared
    by more than two triangles; on such an edge the two largest triangles are kept and the others
    dropped (:func:`drop_nonmanifold_faces`). Every repair is logged and listed in ``notes``.
    """
    v, f, diag = _checked_scan_arrays(vertices, faces, name)
    tol = 1e-9 * diag if merge_tol is None else float(merge_tol)
    v, f, notes = _merge_duplicate_vertices(v, f, tol, name)
    f, more = _drop_degenerate_faces(v, f, diag, name)
    notes += more
    f, more = _drop_repeated_faces(f, name)
    notes += more
    f, more = _drop_nonmanifold_edges(v, f, name)
    notes += more
    v, f, boundary = _drop_unused_vertices(v, f)
    return ScanMesh(v, f, boundary, tuple(notes))


def _checked_scan_arrays(vertices, faces, name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Vertices ``(n, 3) float64``, faces ``(F, 3) int64`` and the bounding-box diagonal of a scan;
    ShapeError or MeshError (naming ``name``) when it is empty, non-finite or badly indexed."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ShapeError(f"{name}: vertices must be (n, 3), got {v.shape}")
    if len(v) == 0:
        raise MeshError(f"{name}: scan has no vertices")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
        raise MeshError(f"{name}: {bad} scan vertices have NaN or infinite coordinates")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise MeshError(f"{name}: scan has no triangles (faces shape {f.shape}); a point cloud "
                        "cannot be fitted")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise MeshError(f"{name}: face indices outside 0..{len(v) - 1}")
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if diag <= 0:
        raise MeshError(f"{name}: all scan vertices coincide")
    return v, f, diag


def _merge_duplicate_vertices(v: np.ndarray, f: np.ndarray, tol: float, name: str
                              ) -> tuple[np.ndarray, np.ndarray, list]:
    """Merge vertices closer than ``tol`` (on a grid of that step); returns ``(v, f, notes)``."""
    key = np.round(v / tol).astype(np.int64) if tol > 0 else v
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    notes = []
    if len(first) < len(v):
        notes.append(f"merged {len(v) - len(first)} duplicate vertices")
        log.info("%s: merged %d duplicate vertices", name, len(v) - len(first))
    return v[first], inv[f], notes


def _drop_degenerate_faces(v: np.ndarray, f: np.ndarray, diag: float, name: str
                           ) -> tuple[np.ndarray, list]:
    """Drop faces with a repeated vertex or zero area; MeshError if none is left."""
    _, area = face_normals(v, f)
    degen = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2]) | (area <= 1e-14 * diag**2)
    notes = []
    if degen.any():
        notes.append(f"dropped {int(degen.sum())} degenerate faces")
        log.warning("%s: dropped %d degenerate (zero-area) faces", name, int(degen.sum()))
        f = f[~degen]
    if len(f) == 0:
        raise MeshError(f"{name}: every scan triangle is degenerate (zero area)")
    return f, notes


def _drop_repeated_faces(f: np.ndarray, name: str) -> tuple[np.ndarray, list]:
    """Keep the first of faces on the same three vertices, in their original order."""
    fs = np.sort(f, axis=1)
    _, uniq = np.unique(fs, axis=0, return_index=True)
    notes = []
    if len(uniq) < len(f):
        notes.append(f"dropped {len(f) - len(uniq)} repeated faces")
        log.warning("%s: dropped %d repeated faces", name, len(f) - len(uniq))
        f = f[np.sort(uniq)]
    return f, notes


def _drop_nonmanifold_edges(v: np.ndarray, f: np.ndarray, name: str) -> tuple[np.ndarray, list]:
    """:func:`drop_nonmanifold_faces`, with a note and a warning when it drops faces."""
    f, n_edges, n_dropped = drop_nonmanifold_faces(v, f)
    notes = []
    if n_dropped:
        notes.append(f"dropped {n_dropped} faces on {n_edges} non-manifold edges")
        log.warning("%s: %d non-manifold edges (shared by more than two triangles); dropped %d "
                    "faces on them", name, n_edges, n_dropped)
    return f, notes


def _drop_unused_vertices(v: np.ndarray, f: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Remove vertices no face uses (renumbering ``f``); also the boundary vertices ``(n,) bool``."""
    edges, counts, _ = edge_use_counts(f)
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    if not used.all():
        remap = np.cumsum(used) - 1
        f = remap[f]
        v = v[used]
        edges = remap[edges]
    boundary = np.zeros(len(v), dtype=bool)
    boundary[edges[counts == 1].ravel()] = True
    return v, f, boundary


def load_scan(path: str | os.PathLike) -> ScanMesh:
    """Read a scan in any format :func:`facetransfer.io.mesh.read_mesh` reads, then clean it."""
    from ..io.mesh import read_mesh

    m = read_mesh(path)
    return clean_scan(m.vertices, m.faces, name=str(path))


def mesh_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Row-normalised cotangent Laplacian ``L = I - D⁻¹W`` (n × n), weights clamped positive.

    ``(L x)_i = x_i - Σ_j w_ij x_j / Σ_j w_ij``; with cotangent weights it vanishes on linear
    functions over a flat patch, so affine parts of a deformation cost little.
    """
    n = len(vertices)
    v = vertices
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3], faces[:, k]
        a, b = v[i] - v[o], v[j] - v[o]
        cot = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-300)
        rows += [i, j]
        cols += [j, i]
        vals += [cot, cot]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n)).tocsr()
    w.data = np.clip(w.data * 0.5, 1e-2, 1e2)  # clamp: obtuse triangles give negative cotangents
    d = np.asarray(w.sum(axis=1)).ravel()
    dinv = np.where(d > 0, 1.0 / np.maximum(d, 1e-300), 0.0)
    return (sp.identity(n, format="csr") - sp.diags(dinv) @ w).tocsr()


def closest_point_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on triangles ``(a, b, c)`` to points ``p`` (all ``(m, 3)``), vectorised.

    Follows the Voronoi-region case analysis of Ericson, *Real-Time Collision Detection* (2005),
    §5.1.5. Returns the points ``(m, 3)`` and barycentric coordinates ``(m, 3)``.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    m = len(p)
    bary = np.zeros((m, 3))
    done = np.zeros(m, dtype=bool)

    def put(mask, u, v_, w):
        nonlocal done
        sel = mask & ~done
        bary[sel, 0], bary[sel, 1], bary[sel, 2] = u[sel], v_[sel], w[sel]
        done |= sel

    one, zero = np.ones(m), np.zeros(m)
    with np.errstate(divide="ignore", invalid="ignore"):
        put((d1 <= 0) & (d2 <= 0), one, zero, zero)                     # vertex a
        put((d3 >= 0) & (d4 <= d3), zero, one, zero)                    # vertex b
        t = d1 / (d1 - d3)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1 - t, t, zero)          # edge ab
        put((d6 >= 0) & (d5 <= d6), zero, zero, one)                    # vertex c
        t = d2 / (d2 - d6)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1 - t, zero, t)          # edge ac
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), zero, 1 - t, t)  # edge bc
        den = va + vb + vc
        vv, ww = vb / den, vc / den
        put(np.ones(m, dtype=bool), 1 - vv - ww, vv, ww)                # interior
    bary = np.nan_to_num(bary, nan=1.0 / 3.0)
    q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    return q, bary


@dataclass(frozen=True)
class ClosestPoints:
    """Result of :meth:`SurfaceQuery.closest`.

    Attributes
    ----------
    points : (m, 3) float64
        Closest points on the surface.
    distance : (m,) float64
    face : (m,) int64
        Triangle holding each closest point.
    normal : (m, 3) float64
        Unit normal of that triangle.
    on_boundary : (m,) bool
        The closest point lies on a boundary edge or boundary vertex (a hole or the rim):
        the true match is probably missing from the scan.
    """

    points: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    normal: np.ndarray
    on_boundary: np.ndarray


class SurfaceQuery:
    """Closest points on a fixed triangle surface; precomputes a k-d tree and adjacency once.

    Candidates for each query are the triangles around its ``k`` nearest surface vertices; for
    meshes of reasonable quality this finds the exact closest point.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, *, k: int = 6):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.k = int(min(k, len(self.vertices)))
        self.tree = cKDTree(self.vertices)
        self.normals, _ = face_normals(self.vertices, self.faces)
        n = len(self.vertices)
        fv = self.faces.ravel()
        order = np.argsort(fv, kind="stable")
        deg = np.bincount(fv, minlength=n)
        maxdeg = int(min(deg.max(), 16))
        start = np.concatenate([[0], np.cumsum(deg)[:-1]])
        slot = np.arange(len(fv)) - np.repeat(start, deg)
        vf = -np.ones((n, maxdeg), dtype=np.int64)
        keep = slot < maxdeg
        vf[fv[order][keep], slot[keep]] = (order // 3)[keep]
        self.vertex_faces = vf
        _, counts, face_edge = edge_use_counts(self.faces)
        self.edge_boundary = counts[face_edge] == 1  # (F, 3): edge opposite vertex k is a rim edge
        bv = np.zeros(n, dtype=bool)
        edges, _, _ = edge_use_counts(self.faces)
        bv[edges[counts == 1].ravel()] = True
        self.vertex_boundary = bv

    def moved(self, vertices: np.ndarray) -> "SurfaceQuery":
        """The same surface with its vertices moved (e.g. by a similarity): the topology tables
        are shared, only the k-d tree and the normals are rebuilt."""
        q = object.__new__(SurfaceQuery)
        q.vertices = np.asarray(vertices, dtype=np.float64)
        if q.vertices.shape != self.vertices.shape:
            raise ShapeError(f"moved surface needs vertices {self.vertices.shape}, got {q.vertices.shape}")
        q.faces, q.k = self.faces, self.k
        q.tree = cKDTree(q.vertices)
        q.normals, _ = face_normals(q.vertices, q.faces)
        q.vertex_faces, q.edge_boundary = self.vertex_faces, self.edge_boundary
        q.vertex_boundary = self.vertex_boundary
        return q

    def closest(self, points: np.ndarray) -> ClosestPoints:
        """Closest surface points to ``points`` ``(m, 3)``."""
        p = np.asarray(points, dtype=np.float64)
        _, nn = self.tree.query(p, k=self.k)
        nn = nn.reshape(len(p), -1)
        cand = self.vertex_faces[nn].reshape(len(p), -1)  # (m, k*maxdeg), -1 padded
        m, c = cand.shape
        valid = cand >= 0
        qi = np.repeat(np.arange(m), c)[valid.ravel()]
        fi = cand.ravel()[valid.ravel()]
        tri = self.faces[fi]
        q, bary = closest_point_on_triangles(p[qi], self.vertices[tri[:, 0]],
                                             self.vertices[tri[:, 1]], self.vertices[tri[:, 2]])
        d2 = np.sum((q - p[qi]) ** 2, axis=1)
        full = np.full(m * c, np.inf)
        full[np.flatnonzero(valid.ravel())] = d2
        best = np.argmin(full.reshape(m, c), axis=1)
        flat = np.flatnonzero(valid.ravel())
        pos = np.searchsorted(flat, np.arange(m) * c + best)
        face = fi[pos]
        bq, bb = q[pos], bary[pos]
        eps = 1e-6
        small = bb < eps
        tri_b = self.faces[face]
        on_edge = (small & self.edge_boundary[face]).any(axis=1)
        at_vertex = ((bb > 1 - eps) & self.vertex_boundary[tri_b]).any(axis=1)
        return ClosestPoints(bq, np.sqrt(full.reshape(m, c)[np.arange(m), best]), face,
                             self.normals[face], on_edge | at_vertex)

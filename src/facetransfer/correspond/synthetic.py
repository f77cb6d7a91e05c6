"""Synthetic scans with exact ground truth, for tests and benchmarks of template fitting.

A mesh in template topology (the "truth") is resampled into an unrelated triangulation: a jittered
grid of points in the template's UV chart is lifted to the surface by barycentric interpolation
and re-triangulated by Delaunay triangulation in UV space; then the rim is cropped, holes are cut,
Gaussian noise is added along the normals and a random similarity is applied. Feature points are
the true landmark vertices moved by a fixed distance in random directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import vertex_normals
from .features import FeaturePoints
from .meshops import ScanMesh, SurfaceQuery, clean_scan
from .procrustes import Similarity


@dataclass(frozen=True)
class SyntheticScan:
    """A synthetic scan and its ground truth.

    Attributes
    ----------
    scan : ScanMesh
        In scan coordinates (after the similarity).
    features : FeaturePoints
        Perturbed landmark positions, scan coordinates.
    similarity : Similarity
        Truth frame → scan frame.
    truth : (n, 3) float64
        The true template-topology vertices, truth frame (template units).
    observed : (n,) bool
        Vertices the scan shows faithfully: within ``observe_tol`` of the noise-free resampled
        surface, away from its boundary (excludes crops, holes, nostrils, ear folds, the mouth).
    """

    scan: ScanMesh
    features: FeaturePoints
    similarity: Similarity
    truth: np.ndarray
    observed: np.ndarray


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random proper rotation (3, 3)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def make_synthetic_scan(truth: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                        landmarks: np.ndarray, *, n_points: int = 30000, noise: float = 0.02,
                        n_holes: int = 2, hole_radius: float = 0.8, crop: bool = True,
                        feature_noise: float = 0.1, feature_ids=None, transform: bool | Similarity = True,
                        observe_tol: float = 0.05, rng: np.random.Generator | None = None) -> SyntheticScan:
    """Resample ``truth`` into a noisy, holed, cropped scan in a random pose.

    Parameters
    ----------
    truth : (n, 3) float
        Template-topology mesh (cm for ICT).
    faces : (F, 3) int
    uvs : (n, 2) float
        A valid UV chart of the mesh (no overlapping triangles).
    landmarks : (68,) int
    n_points : int
        Approximate number of scan vertices before cropping.
    noise : float
        Standard deviation of the noise along the normals (truth units).
    n_holes, hole_radius : int, float
        Holes cut around random surface points.
    crop : bool
        Crop the rim with an ellipse in the front view (x, y), removing forehead top, ears, neck.
    feature_noise : float
        Each feature point is moved by this distance in a random direction.
    feature_ids : sequence of int, optional
        iBUG numbers to give as features (default all 68).
    transform : bool or Similarity
        Apply a random similarity (rotation, scale in [0.3, 3], translation), or this one.
    rng : numpy Generator
    """
    import matplotlib.tri as mtri

    rng = np.random.default_rng(rng)
    truth = np.asarray(truth, dtype=np.float64)
    finder = mtri.Triangulation(uvs[:, 0], uvs[:, 1], faces).get_trifinder()
    uv, tv, bary = _sample_uv_chart(uvs, faces, finder, n_points, rng)
    pts = np.einsum("kj,kjd->kd", bary, truth[tv])
    keep = _cut_mask(pts, truth[landmarks], crop, n_holes, hole_radius, rng)
    uv, pts, tv, bary = uv[keep], pts[keep], tv[keep], bary[keep]
    sf, med = _triangulate(uv, pts, finder)
    sf, nrm = _orient_like_truth(sf, pts, bary, vertex_normals(truth, faces)[tv])
    clean = clean_scan(pts, sf, name="synthetic scan")
    cp = SurfaceQuery(clean.vertices, clean.faces).closest(truth)
    observed = (cp.distance < observe_tol) & ~cp.on_boundary
    pts = pts + rng.normal(0, noise, len(pts))[:, None] * nrm
    sim = _scan_pose(transform, rng)
    scan = clean_scan(sim.apply(pts), sf, name="synthetic scan")
    ids, fp = _perturbed_features(pts, truth, landmarks, feature_ids, feature_noise, 1.5 * med, rng)
    return SyntheticScan(scan, FeaturePoints(ids, sim.apply(fp)), sim, truth, observed)


def _sample_uv_chart(uvs: np.ndarray, faces: np.ndarray, finder, n_points: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About ``n_points`` jittered hexagonal-grid points in the UV chart.

    Returns ``uv (k, 2)``, the template triangle's vertices ``(k, 3)`` under each point and the
    point's barycentric coordinates in it ``(k, 3)``.
    """
    lo, hi = uvs.min(0), uvs.max(0)
    e1, e2 = uvs[faces[:, 1]] - uvs[faces[:, 0]], uvs[faces[:, 2]] - uvs[faces[:, 0]]
    area_uv = float(np.sum(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]))) / 2
    h = np.sqrt(area_uv / n_points)
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], h), np.arange(lo[1], hi[1], h * np.sqrt(3) / 2))
    gx = gx + (np.arange(gx.shape[0]) % 2)[:, None] * h / 2      # hexagonal-ish grid
    uv = np.stack([gx.ravel(), gy.ravel()], 1) + rng.uniform(-0.3, 0.3, (gx.size, 2)) * h
    fi = finder(uv[:, 0], uv[:, 1])
    uv, fi = uv[fi >= 0], fi[fi >= 0]
    tv = faces[fi]
    a, b, c = uvs[tv[:, 0]], uvs[tv[:, 1]], uvs[tv[:, 2]]
    m = np.stack([b - a, c - a], axis=2)                        # (k, 2, 2)
    lam = np.linalg.solve(m, (uv - a)[:, :, None])[:, :, 0]
    return uv, tv, np.column_stack([1 - lam.sum(1), lam])


def _cut_mask(pts: np.ndarray, lmp: np.ndarray, crop: bool, n_holes: int, hole_radius: float,
              rng: np.random.Generator) -> np.ndarray:
    """Points ``(k,) bool`` kept: inside the front-view crop ellipse (from the landmark
    positions ``lmp`` (68, 3)), outside ``n_holes`` balls around random kept points."""
    keep = np.ones(len(pts), dtype=bool)
    if crop:
        cx, cy = lmp[:, 0].mean(), lmp[:, 1].mean()
        ax = 0.95 * (lmp[16, 0] - lmp[0, 0]) / 2 + 0.5
        ay = 1.25 * (lmp[:, 1].max() - lmp[:, 1].min()) / 2 + 1.0
        keep &= ((pts[:, 0] - cx) / ax) ** 2 + ((pts[:, 1] - cy) / ay) ** 2 < 1.0
    for _ in range(n_holes):
        centre = pts[rng.choice(np.flatnonzero(keep))]
        keep &= np.linalg.norm(pts - centre, axis=1) > hole_radius
    return keep


def _triangulate(uv: np.ndarray, pts: np.ndarray, finder) -> tuple[np.ndarray, float]:
    """Delaunay triangles ``(F, 3)`` of the points in UV space, without those outside the chart
    or with an edge over 3 median edges; also the median edge length (3D)."""
    from scipy.spatial import Delaunay

    sf = Delaunay(uv).simplices.astype(np.int64)
    cen = uv[sf].mean(axis=1)
    ok = finder(cen[:, 0], cen[:, 1]) >= 0
    e = np.stack([np.linalg.norm(pts[sf[:, i]] - pts[sf[:, (i + 1) % 3]], axis=1) for i in range(3)], 1)
    med = np.median(e)
    ok &= e.max(axis=1) < 3.0 * med
    return sf[ok], med


def _orient_like_truth(sf: np.ndarray, pts: np.ndarray, bary: np.ndarray, corner_normals: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Flip Delaunay triangles to agree with the truth's normals; the unit truth normal at every
    point ``(k, 3)`` (``corner_normals`` (k, 3, 3): the truth's vertex normals of its triangle)."""
    cr = np.cross(pts[sf[:, 1]] - pts[sf[:, 0]], pts[sf[:, 2]] - pts[sf[:, 0]])
    nrm_at = np.einsum("kj,kjd->kd", bary, corner_normals)
    flip = np.einsum("ij,ij->i", cr, nrm_at[sf].mean(axis=1)) < 0
    sf[flip] = sf[flip][:, ::-1]
    return sf, nrm_at / np.linalg.norm(nrm_at, axis=1, keepdims=True)


def _scan_pose(transform: bool | Similarity, rng: np.random.Generator) -> Similarity:
    """Truth frame → scan frame: ``transform`` itself, a random similarity, or the identity."""
    if isinstance(transform, Similarity):
        return transform
    if transform:
        return Similarity(float(np.exp(rng.uniform(np.log(0.3), np.log(3)))), random_rotation(rng),
                          rng.normal(0, 20, 3))
    return Similarity.identity()


def _perturbed_features(pts: np.ndarray, truth: np.ndarray, landmarks: np.ndarray, feature_ids,
                        feature_noise: float, max_gap: float, rng: np.random.Generator
                        ) -> tuple[np.ndarray, np.ndarray]:
    """iBUG numbers ``(k,)`` and truth-frame points ``(k, 3)``: the landmark vertices the scan
    still shows (a scan point within ``max_gap``), moved ``feature_noise`` in random directions."""
    from scipy.spatial import cKDTree

    ids = np.arange(68) if feature_ids is None else np.asarray(sorted(feature_ids), dtype=np.int64)
    dirs = rng.normal(size=(len(ids), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # Only landmarks the scan still shows can be marked on it.
    gap, _ = cKDTree(pts).query(truth[landmarks[ids]])
    seen = gap < max_gap
    ids, dirs = ids[seen], dirs[seen]
    return ids, truth[landmarks[ids]] + feature_noise * dirs


def correspondence_error(fitted: np.ndarray, truth: np.ndarray, similarity: Similarity) -> np.ndarray:
    """Per-vertex distance ``(n,)`` between a fit (scan frame) and the truth (truth frame units)."""
    return np.linalg.norm(similarity.inverse().apply(fitted) - truth, axis=1)


def cluster_vertices(vertices: np.ndarray, faces: np.ndarray, cell: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Decimate a mesh by vertex clustering, as scan software does (Rossignac & Borrel 1993).

    Vertices in one cubic grid cell of side ``cell`` are replaced by their mean; triangles that
    collapse are dropped. The result is typically *non-manifold*: an edge can end up shared by
    three or more triangles, which is what raw, decimated scans look like.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int
    cell : float
        Grid cell size, mesh units (> 0).

    Returns
    -------
    vertices : (m, 3) float64
    faces : (F', 3) int64
        Repeated triangles (same three vertices) are kept once.

    References
    ----------
    J. Rossignac, P. Borrel, "Multi-resolution 3D approximations for rendering complex scenes",
    Modeling in Computer Graphics, 1993.
    """
    if not cell > 0:
        raise ValueError(f"cell must be > 0, got {cell}")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    key = np.floor(v / cell).astype(np.int64)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    sums = np.zeros((len(count), 3))
    np.add.at(sums, inv, v)
    vc = sums / count[:, None]
    fc = inv[f]
    keep = (fc[:, 0] != fc[:, 1]) & (fc[:, 1] != fc[:, 2]) & (fc[:, 0] != fc[:, 2])
    fc = fc[keep]
    _, first = np.unique(np.sort(fc, axis=1), axis=0, return_index=True)
    return vc, fc[np.sort(first)]

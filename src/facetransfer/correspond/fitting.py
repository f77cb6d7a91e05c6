"""Template fitting (§4.2): the smallest smooth deformation of a template that fits a scan.

Following Allen, Curless & Popović 2003 and Sumner & Popović 2004, with the deformation written as
per-vertex displacements ``d = x − x₀`` of the template ``x₀`` and, per stage, the energy

    E(x) = w_s ‖L (x − x₀)‖² + w_f Σ_l ‖x_{v(l)} − f_l‖² + w_c Σ_{i ∈ V} ‖x_i − c_i‖²
           + w_r ‖x − x₀‖²                                                          (F1)

* ``L``: the row-normalised cotangent Laplacian of the template, so the smoothness term
  penalises bending of the displacement field (affine changes are nearly free; the small
  ``w_r`` term, :attr:`FitStage.w_rest`, keeps them determined when the features cover only
  part of the face);
* ``f_l``: the scan's feature point for iBUG landmark ``l`` and ``v(l)`` its template vertex;
* ``c_i``: the closest point on the scan to vertex ``i``; pairs are rejected when the closest
  point is on a boundary (a hole or the cropped rim), further than ``max_distance``, or when the
  normals differ by more than ``max_angle`` degrees.

Eq. (F1) is quadratic with a diagonal data part, so each iteration solves one sparse symmetric
positive definite system ``(w_s LᵀL + W + w_r I) D = W (C − X₀)`` for all three coordinates
(normal equations, sparse LU). The closest points are recomputed a few times per stage. The schedule
first weighs the features heavily, then proximity, while the stiffness ``w_s`` is lowered
(the paper's protocol, §4.2; cf. the stiffness annealing of Amberg et al. 2007).

Before fitting, the template is aligned to the scan by a similarity from the feature points
(Procrustes, §4.2). With a shape prior (:mod:`.prior`; by default ICT-FaceKit's identity space for
the ICT template) the face space's coefficients and the pose are fitted next, and Eq. (F1) then
deforms that face (``x₀`` := the prior's best face) with :data:`PRIOR_SCHEDULE`. This goes beyond
the paper, which deforms the generic template: the smoothness energy alone lets the
correspondence slide along smooth regions (the jaw) by about a millimetre (BENCHMARKS.md).

With a ``reference`` (the cascade: closed-mouth scan → its subject's neutral fit, viseme → its
closed-mouth fit) the reference is rigidly aligned to the scan on the upper face
(ICP on the vertices nearest to brow, eye and nose landmarks) and then deformed as above.

All geometry is solved in a normalised frame where the template's landmark spread equals that of
ICT-FaceKit (5.94 cm), so the distances of the schedule are in centimetre-like units whatever the
scan's units.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import FaceTransferError, MeshError
from ..geometry import vertex_normals
from .features import FeatureError, FeaturePoints, validate_features_on_surface
from .meshops import ScanMesh, SurfaceQuery, face_normals, mesh_laplacian
from .prior import ShapePrior, fit_shape_prior, ict_prior
from .procrustes import Similarity, rotation_from_vector, similarity_procrustes

log = logging.getLogger(__name__)

#: RMS distance of the 68 ICT-FaceKit landmarks from their centroid (cm): the normalised frame.
REFERENCE_SPREAD = 5.94
#: iBUG landmarks of the upper face (brows, eyes, nose), used for rigid alignment on the upper face.
UPPER_LANDMARKS = tuple(range(17, 48))


class FitDivergedError(FaceTransferError):
    """The fit did not converge to the scan (distance too large or triangles folded)."""


@dataclass(frozen=True)
class FitStage:
    """One stage of the schedule of Eq. (F1).

    Attributes
    ----------
    name : str
    w_smooth, w_features, w_closest : float
        Weights of the three terms.
    iterations : int
        Closest-point recomputations (solves) in the stage.
    max_distance : float
        Closest-point pairs further than this (normalised cm) are rejected.
    w_rest : float
        Weight of ``‖x − x₀‖²`` per vertex: pins the near-affine null space of ``L`` when the
        features do not span the face (e.g. 18 lip points on a viseme).
    """

    name: str
    w_smooth: float
    w_features: float
    w_closest: float
    iterations: int = 3
    max_distance: float = 2.0
    w_rest: float = 0.01


#: Features first (heavily), then proximity with decreasing stiffness (§4.2).
DEFAULT_SCHEDULE: tuple[FitStage, ...] = (
    FitStage("features", 10000.0, 10.0, 0.0, 1),
    FitStage("features + proximity", 3000.0, 10.0, 0.2, 2, 2.0),
    FitStage("proximity, stiff", 1000.0, 3.0, 1.0, 2, 1.0),
    FitStage("proximity", 300.0, 1.0, 1.0, 2, 0.5),
    FitStage("proximity, fine", 100.0, 0.3, 1.0, 2, 0.3),
    FitStage("proximity, detail", 30.0, 0.3, 1.0, 2, 0.3),
)

#: After a shape prior has placed the face (:mod:`.prior`): proximity only, features lightly, from
#: stiff to the same final stiffness. The heavy feature stages are not needed and would pull the
#: landmark vertices toward the (noisy) feature points again.
PRIOR_SCHEDULE: tuple[FitStage, ...] = (
    FitStage("proximity, stiff", 1000.0, 1.0, 1.0, 2, 1.0),
    FitStage("proximity", 300.0, 0.3, 1.0, 2, 0.5),
    FitStage("proximity, fine", 100.0, 0.1, 1.0, 2, 0.3),
    FitStage("proximity, detail", 30.0, 0.1, 1.0, 2, 0.3),
)


@dataclass(frozen=True)
class Template:
    """A template mesh with iBUG-68 landmark vertices.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (F, 3) int64
    landmarks : (68,) int64
        Vertex of each iBUG-68 landmark, ``-1`` where the template has none.
    name : str
    prior : ShapePrior, optional
        The face space around the template (:mod:`.prior`) that :func:`fit_template` fits first
        by default: ICT-FaceKit's identity components for ``"ict"``, none for other templates.
    """

    vertices: np.ndarray
    faces: np.ndarray
    landmarks: np.ndarray
    name: str = "template"
    prior: ShapePrior | None = None


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_template`.

    Attributes
    ----------
    vertices : (n, 3) float64
        The fitted template in the scan's coordinates (template topology).
    faces : (F, 3) int64
    distance : (n,) float64
        Distance of each fitted vertex to the scan surface (scan units).
    covered : (n,) bool
        Vertices whose closest scan point is not on a boundary (the scan covers them).
    similarity : Similarity
        Template (or reference) frame → scan frame, from the features (and upper-face ICP).
    feature_residual : (k,) float64
        Distance from each used feature point to its fitted landmark vertex (scan units).
    stats : dict
        ``mean``, ``median``, ``p95``, ``max`` surface distance over covered vertices (scan units),
        ``n_covered``, ``seconds``, ``feature_rms``, ``flipped_fraction``.
    history : tuple of dict
        Per solve: stage, iteration, accepted closest-point pairs, their mean distance
        (normalised cm; ``None`` in the features-only stage).
    """

    vertices: np.ndarray
    faces: np.ndarray
    distance: np.ndarray
    covered: np.ndarray
    similarity: Similarity
    feature_residual: np.ndarray
    stats: dict
    history: tuple = field(default_factory=tuple)


def _spread(p: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))


def template_from_mesh(vertices: np.ndarray, faces: np.ndarray, landmarks, *,
                       name: str = "template") -> Template:
    """Build a :class:`Template`, validating the landmark table.

    Parameters
    ----------
    landmarks : (68,) int array (``-1`` = missing) or dict ``{ibug_number: vertex}``
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if isinstance(landmarks, dict):
        lm = -np.ones(68, dtype=np.int64)
        for k, vi in landmarks.items():
            try:
                k = int(k)
                vi = int(vi)
            except (TypeError, ValueError):
                raise MeshError(f"{name}: landmark entry {k!r}: {vi!r} is not an integer pair") from None
            if not 0 <= k <= 67:
                raise MeshError(f"{name}: landmark {k} outside the iBUG-68 range 0..67")
            lm[k] = vi
    else:
        lm = np.asarray(landmarks, dtype=np.int64).ravel()
        if lm.shape != (68,):
            raise MeshError(f"{name}: template landmarks must be 68 vertex indices, got {lm.shape}")
    if np.any(lm >= len(v)) or np.any(lm < -1):
        raise MeshError(f"{name}: template landmark vertices outside 0..{len(v) - 1}")
    if np.count_nonzero(lm >= 0) < 8:
        raise MeshError(f"{name}: template has {np.count_nonzero(lm >= 0)} landmarks, at least 8 needed")
    return Template(v, f, lm, name)


def load_template(spec: str | os.PathLike = "ict", *, landmarks: str | os.PathLike | None = None
                  ) -> Template:
    """Load a template.

    Parameters
    ----------
    spec : "ict", a model file ``*.npz`` or a mesh file
        ``"ict"``: ICT-FaceKit face area (vertices 0..9408, cm). A model file: its default face
        (``m.synthesize(m.default_weights())``) with ``m.faces`` and ``m.landmarks``. A mesh:
        needs ``landmarks``.
    landmarks : path, optional
        JSON with the template's landmark vertices: a list of 68 ints (``-1`` for none), or
        ``{"landmarks": [...]}``, or ``{"36": vertex, ...}``.
    """
    s = str(spec)
    if s == "ict":
        from ..datasets.ict import ict_template

        t = ict_template("face")
        tm = template_from_mesh(t.mesh.vertices, t.mesh.faces, t.landmarks, name="ict")
        return replace(tm, prior=ict_prior("identity", neutral=t.mesh.vertices))
    p = Path(s)
    if not p.is_file():
        raise MeshError(f"template {p} does not exist (expected 'ict', a model .npz or a mesh)")
    if p.suffix.lower() == ".npz":
        from ..model import load_model

        m = load_model(p)
        if m.landmarks is None:
            raise MeshError(f"model {p} has no landmarks; it cannot serve as a fitting template")
        v = np.asarray(m.synthesize(m.default_weights()), dtype=np.float64)
        # No prior by default: a model's identity mode is a weak face space (8 components from
        # the default model's 15 identities) and made fits worse (BENCHMARKS.md); pass
        # ``prior=model_identity_prior(m)`` to fit_template to use it anyway.
        return template_from_mesh(v, m.faces, m.landmarks, name=p.name)
    if landmarks is None:
        raise MeshError(f"template mesh {p} needs --template-landmarks (a JSON of 68 vertex indices)")
    import json

    from ..io.mesh import read_mesh

    m = read_mesh(p)
    try:
        data = json.loads(Path(landmarks).read_text())
    except (OSError, ValueError) as exc:
        raise MeshError(f"cannot read template landmarks {landmarks}: {exc}") from None
    if isinstance(data, dict) and "landmarks" in data:
        data = data["landmarks"]
    return template_from_mesh(m.vertices, m.faces, data, name=p.name)


def upper_face_vertices(vertices: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """Vertices whose nearest landmark is a brow, eye or nose landmark (the upper face).

    Returns ``(m,) int64`` vertex indices; the rest of the face moves with the mouth and jaw.
    """
    valid = np.flatnonzero(landmarks >= 0)
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(vertices[landmarks[valid]]).query(vertices)
    return np.flatnonzero(np.isin(valid[nearest], UPPER_LANDMARKS))


@dataclass(frozen=True, eq=False)
class _WorkFrame:
    """The scan in the normalised work frame (module docstring) and the closest-point rule.

    The template side stays put (``x₀`` is the regularisation target); every alignment moves the
    scan instead (:meth:`moved`).

    Attributes
    ----------
    to_work : Similarity
        Scan frame → work frame.
    query : SurfaceQuery
        The scan surface in work coordinates.
    scan_vertices : (m, 3) float64
        The scan, scan frame.
    features : (k, 3) float64
        The used feature points, scan frame.
    features_w : (k, 3) float64
        The same in work coordinates.
    faces : (F, 3) int64
        The template's triangles.
    max_angle : float
        Closest-point pairs whose normals differ more (degrees) are rejected.
    normal_sign : float
        ``±1``: the scan's winding relative to the template's (:func:`_normal_sign`).
    """

    to_work: Similarity
    query: SurfaceQuery
    scan_vertices: np.ndarray
    features: np.ndarray
    features_w: np.ndarray
    faces: np.ndarray
    max_angle: float
    normal_sign: float = 1.0

    @classmethod
    def start(cls, to_work: Similarity, query_scan: SurfaceQuery, features: np.ndarray,
              faces: np.ndarray, max_angle: float, x0: np.ndarray) -> "_WorkFrame":
        """The scan of ``query_scan`` and its ``features`` (k, 3) moved by ``to_work``, its normals
        oriented by agreement with the template ``x0`` (n, 3) (work frame)."""
        scan_vertices = query_scan.vertices
        query = query_scan.moved(to_work.apply(scan_vertices))
        return cls(to_work, query, scan_vertices, features, to_work.apply(features), faces,
                   max_angle, _normal_sign(query, x0, faces))

    def moved(self, motion: Similarity) -> "_WorkFrame":
        """The frame after the template side moved by ``motion``: the scan moves by its inverse."""
        to_work = motion.inverse().compose(self.to_work)
        return replace(self, to_work=to_work, query=self.query.moved(to_work.apply(self.scan_vertices)),
                       features_w=to_work.apply(self.features))

    def pairs(self, x: np.ndarray, max_distance: float, idx: np.ndarray | None = None):
        """Closest points of ``x`` (n, 3) (or of ``x[idx]``) and which pairs are accepted.

        Returns ``(cp, ok, cos)``: :class:`~.meshops.ClosestPoints`, ``(m,) bool`` and the
        normals' cosines.
        """
        vn = vertex_normals(x, self.faces)
        if idx is not None:
            x, vn = x[idx], vn[idx]
        cp = self.query.closest(x)
        cos = self.normal_sign * np.einsum("ij,ij->i", vn, cp.normal)
        ok = (~cp.on_boundary) & (cp.distance <= max_distance) \
            & (cos >= np.cos(np.radians(self.max_angle)))
        return cp, ok, cos


def _rigid_icp(work: _WorkFrame, x, idx, *, iterations, start_distance=5.0, end_distance=0.5,
               keep=0.8):
    """Trimmed point-to-plane rigid ICP of vertices ``idx`` of ``x`` to the surface.

    Each step linearises the rotation and minimises ``Σ (n·(R x + t − c))²`` over the closest
    pairs (Chen & Medioni 1992); the distance limit shrinks from ``start_distance`` to
    ``end_distance`` and only the closest ``keep`` fraction of pairs is used. Returns the rigid
    motion mapping ``x`` onto the surface.
    """
    total = Similarity.identity()
    cur = x
    for it in range(iterations):
        lim = max(end_distance, start_distance * 0.7 ** it)
        cp, ok, _ = work.pairs(cur, lim, idx=idx)
        sel = np.flatnonzero(ok)
        if len(sel) < 10:
            continue
        sel = sel[cp.distance[sel] <= np.quantile(cp.distance[sel], keep)]
        p, q, nrm = cur[idx[sel]], cp.points[sel], cp.normal[sel]
        c = p.mean(axis=0)
        a = np.hstack([np.cross(p - c, nrm), nrm])            # (m, 6)
        b = np.einsum("ij,ij->i", nrm, q - p)
        sol = np.linalg.lstsq(a, b, rcond=None)[0]
        r = rotation_from_vector(sol[:3])
        step = Similarity(1.0, r, c - r @ c + sol[3:])
        total = step.compose(total)
        cur = step.apply(cur)
        if np.linalg.norm(sol) < 1e-7:
            break
    return total


def _solve(a: sp.csc_matrix, rhs: np.ndarray, lu, guess: np.ndarray):
    """Solve the SPD system ``a d = rhs`` (n × 3 right-hand sides); returns ``(d, lu)``.

    Without ``lu``: sparse LU, returned for reuse. With the factorisation of an earlier
    iteration of the same stage (whose matrix differs only in the accepted closest-point
    weights on the diagonal): preconditioned conjugate gradients from ``guess``, which converge
    in a few steps; falls back to a fresh LU if they do not.
    """
    if lu is not None:
        m = spla.LinearOperator(a.shape, matvec=lu.solve, dtype=np.float64)
        out = np.empty_like(rhs)
        for c in range(rhs.shape[1]):
            sol, info = spla.cg(a, rhs[:, c], x0=guess[:, c], M=m, rtol=1e-10, maxiter=50)
            if info != 0:
                break
            out[:, c] = sol
        else:
            return out, lu
    lu = spla.splu(a, permc_spec="MMD_ATA")
    return lu.solve(rhs), lu


def choose_prior(residuals: Sequence[float], *, margin: float = 0.1) -> int:
    """Index of the prior to keep: candidates are ordered simplest first, and a later one wins
    only if its residual is lower than the current choice's by more than ``margin`` (a fraction).

    >>> choose_prior([1.0, 0.95]), choose_prior([1.0, 0.5]), choose_prior([0.4, 0.5, 0.2])
    (0, 1, 2)
    """
    best = 0
    for i, r in enumerate(residuals):
        if np.isfinite(r) and (not np.isfinite(residuals[best])
                               or r < (1.0 - margin) * residuals[best]):
            best = i
    return best


@dataclass(frozen=True, eq=False)
class _PriorPairs:
    """Closest-point pairs for :func:`.prior.fit_shape_prior`: vertices ``sub`` of the face, with a
    distance limit shrinking from 2 to 0.3 (normalised cm) over the iterations."""

    work: _WorkFrame
    sub: np.ndarray

    def __call__(self, x: np.ndarray, it: int):
        cp, ok, _ = self.work.pairs(x, max(0.3, 2.0 * 0.6 ** it), idx=self.sub)
        return self.sub[ok], cp.points[ok], cp.normal[ok]


def _prior_residual(work: _WorkFrame, pf, sub) -> float:
    """Median distance (work units) from a prior fit's posed face to the scan, over the sampled
    vertices that find a compatible closest point within 2 units."""
    x = pf.pose.apply(pf.face)
    cp, ok, _ = work.pairs(x, 2.0, idx=sub)
    return float(np.median(cp.distance[ok])) if ok.any() else float("inf")


def _prior_candidates(prior, template: Template, reference) -> list[ShapePrior]:
    """The face spaces to fit first (``prior`` of :func:`fit_template`), checked against the
    template; none with a ``reference``."""
    if isinstance(prior, str):
        if prior != "template":
            raise ValueError(f"prior must be a ShapePrior, 'template' or None, got {prior!r}")
        prior = template.prior
    if reference is not None:
        prior = None
    candidates = list(prior) if isinstance(prior, (list, tuple)) else [prior]
    candidates = [c for c in candidates if c is not None]
    for c in candidates:
        if c.basis.shape[1:] != template.vertices.shape:
            raise MeshError(f"shape prior {c.name} has basis {c.basis.shape}; the template "
                            f"{template.name} needs (K, {len(template.vertices)}, 3)")
    return candidates


def _base_vertices(template: Template, reference) -> np.ndarray:
    """The mesh to deform ``(n, 3)``: the template, or the reference fit of the cascade."""
    base = template.vertices if reference is None else np.asarray(reference, dtype=np.float64)
    if base.shape != template.vertices.shape or not np.all(np.isfinite(base)):
        raise MeshError(f"reference fit must be finite {template.vertices.shape}, got {base.shape}")
    return base


def _usable_features(features: FeaturePoints, template: Template, query_scan: SurfaceQuery,
                     tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Feature points on the scan that have a template landmark.

    Returns ``(ibug (k,), points (k, 3), template vertices (k,))``; at least 8, or FeatureError.
    """
    validate_features_on_surface(features, query_scan.closest(features.points).distance,
                                 rel_tol=tolerance, source="feature points")
    lmv = template.landmarks[features.indices]
    use = lmv >= 0
    if use.sum() < 8:
        raise FeatureError(f"only {int(use.sum())} feature points have a template landmark; "
                           "at least 8 needed")
    return features.indices[use], features.points[use], lmv[use]


def _normalisation(base: np.ndarray, landmarks: np.ndarray) -> Similarity:
    """Scale to the normalised frame: template landmark spread → :data:`REFERENCE_SPREAD`."""
    valid_lm = landmarks[landmarks >= 0]
    k = REFERENCE_SPREAD / _spread(base[valid_lm])
    return Similarity(k, np.eye(3), np.zeros(3))


def _normal_sign(query: SurfaceQuery, x0: np.ndarray, faces: np.ndarray) -> float:
    """Scan normals may be wound either way: ``±1`` orienting them by agreement with ``x0``."""
    cp0 = query.closest(x0)
    vn0 = vertex_normals(x0, faces)
    near = (~cp0.on_boundary) & (cp0.distance < 1.0)
    dots = np.einsum("ij,ij->i", vn0, cp0.normal)[near]
    return -1.0 if dots.size and np.median(dots) < 0 else 1.0


def _prior_info(candidates: list, residuals: list, pick: int, pf, margin: float) -> dict:
    """``stats["prior"]`` of :class:`FitResult`: the chosen face space and, with several, all."""
    prior = candidates[pick]
    info = {"name": prior.name, "n_components": prior.n_components,
            "coefficient_norm": float(np.linalg.norm(pf.coefficients)),
            "coefficients": [round(float(c), 6) for c in pf.coefficients],
            "residual": residuals[pick],
            # not the scan's units, in which the report's surface distances are
            "residual_units": "template units (cm for ICT-FaceKit): the work frame, the "
                              f"template's landmarks scaled to an RMS spread of {REFERENCE_SPREAD}"}
    if len(candidates) > 1:
        info["candidates"] = [{"name": c.name, "residual": r}
                              for c, r in zip(candidates, residuals)]
        info["chosen_by"] = (f"lowest median distance of the prior fit to the scan "
                             f"(a later candidate must be {100 * margin:g}% lower)")
        log.info("shape prior: %s (median distances %s)", prior.name,
                 ", ".join(f"{r:.4g}" for r in residuals))
    return info


def _fit_priors(work: _WorkFrame, candidates: list, x0: np.ndarray, scale: float,
                lmv: np.ndarray, *, iterations: int, lam: float, margin: float):
    """The shape-prior stage (:mod:`.prior`): fit every candidate, keep one (:func:`choose_prior`).

    Returns
    -------
    x0 : (n, 3) float64
        The chosen prior's face ``x₀ + B w`` (work frame), the new regularisation target.
    work : _WorkFrame
        Moved so that the scan lies on that face (the prior face is not moved).
    history : list of dict
    info : dict
        ``stats["prior"]``.
    """
    sub = np.arange(0, len(x0), max(1, len(x0) // 3000))  # 107 unknowns: 3000 pairs suffice
    pairs_fn = _PriorPairs(work, sub)
    fits = [fit_shape_prior(pairs_fn, x0, scale * c.basis, lmv, work.features_w,
                            iterations=iterations, lam=lam * len(sub) / len(x0))
            for c in candidates]
    residuals = [_prior_residual(work, pf, sub) for pf in fits]
    pick = choose_prior(residuals, margin=margin)
    pf = fits[pick]
    history = [{"stage": "shape prior", "iteration": i, **h} for i, h in enumerate(pf.history)]
    return pf.face, work.moved(pf.pose), history, _prior_info(candidates, residuals, pick, pf, margin)


def _data_terms(work: _WorkFrame, x: np.ndarray, lmv: np.ndarray, st: FitStage):
    """The diagonal data part of Eq. (F1) at the current fit ``x`` (n, 3).

    Returns ``(weights (n,), weighted targets (n, 3), accepted pairs, their mean distance)``:
    closest points with ``w_c`` and feature points with ``w_f``.
    """
    n = len(x)
    wdiag = np.zeros(n)
    target = np.zeros((n, 3))
    if st.w_closest > 0:
        cp, ok, _ = work.pairs(x, st.max_distance)
        wdiag[ok] += st.w_closest
        target[ok] += st.w_closest * cp.points[ok]
        n_ok = int(ok.sum())
        mean_d = float(cp.distance[ok].mean()) if ok.any() else None
    else:
        n_ok, mean_d = 0, None
    np.add.at(wdiag, lmv, st.w_features)
    np.add.at(target, lmv, st.w_features * work.features_w)
    return wdiag, target, n_ok, mean_d


def _deform(work: _WorkFrame, x0: np.ndarray, lmv: np.ndarray, schedule: Sequence[FitStage],
            progress, first: int, n_stages: int) -> tuple[np.ndarray, list]:
    """Minimise Eq. (F1) stage by stage: per solve, closest points, then one sparse SPD system.

    ``progress`` is called before each stage (numbered from ``first``) and once with ``"done"``.
    Returns the fit ``x`` (n, 3) (work frame) and the per-solve history.
    """
    n = len(x0)
    lap = mesh_laplacian(x0, work.faces)
    ltl = (lap.T @ lap).tocsc()
    eye = sp.identity(n, format="csc")
    x = x0.copy()
    history = []
    for si, st in enumerate(schedule):
        lu = None  # factorised at the stage's first solve
        if progress is not None:
            progress(si + first, n_stages, st.name)
        for it in range(max(1, st.iterations)):
            wdiag, target, n_ok, mean_d = _data_terms(work, x, lmv, st)
            a = (st.w_smooth * ltl + sp.diags(wdiag) + (st.w_rest + 1e-9) * eye).tocsc()
            rhs = target - wdiag[:, None] * x0                 # normal equations of Eq. (F1) in d
            d, lu = _solve(a, rhs, lu, x - x0)  # the stage's factorisation, once made
            x = x0 + d
            history.append({"stage": st.name, "iteration": it, "pairs": n_ok, "mean_distance": mean_d})
            log.info("stage %s it %d: %d pairs, mean distance %s", st.name, it, n_ok, mean_d)
            if st.w_closest == 0:
                break
    if progress is not None:
        progress(n_stages, n_stages, "done")
    return x, history


def _surface_stats(query_scan: SurfaceQuery, out: np.ndarray, x: np.ndarray, x0: np.ndarray,
                   faces: np.ndarray, resid: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """Distances ``(n,)`` of the fit ``out`` (scan frame) to the scan, coverage ``(n,) bool`` and
    the first :attr:`FitResult.stats` (scan units; flipped triangles between ``x0`` and ``x``)."""
    cp = query_scan.closest(out)
    covered = ~cp.on_boundary
    dist = cp.distance
    fn0, _ = face_normals(x0, faces)
    fn1, _ = face_normals(x, faces)
    flipped = float(np.mean(np.einsum("ij,ij->i", fn0, fn1) < 0))
    dc = dist[covered] if covered.any() else dist
    stats = {"mean": float(dc.mean()), "median": float(np.median(dc)),
             "p95": float(np.percentile(dc, 95)), "max": float(dc.max()),
             "n_covered": int(covered.sum()), "n_vertices": int(len(x)),
             "feature_rms": float(np.sqrt(np.mean(resid ** 2))), "flipped_fraction": flipped}
    return dist, covered, stats


def _check_converged(out: np.ndarray, stats: dict, scale_back: float, diverge_distance: float,
                     diverge_flipped: float) -> None:
    """Raise FitDivergedError when the fit is not finite, far from the scan or folded."""
    flipped = stats["flipped_fraction"]
    if not np.all(np.isfinite(out)) or stats["mean"] / scale_back > diverge_distance \
            or flipped > diverge_flipped:
        raise FitDivergedError(
            f"fit diverged: mean distance to the scan {stats['mean']:.4g} scan units "
            f"(limit {diverge_distance * scale_back:.4g}), {100 * flipped:.1f}% of triangles flipped "
            f"(limit {100 * diverge_flipped:.0f}%); check the feature points")


@dataclass(frozen=True, eq=False)
class _Alignment:
    """The used feature correspondences of one fit and its two frames.

    Attributes
    ----------
    query_scan : SurfaceQuery
        The scan, scan frame.
    ibug : (k,) int64
        iBUG-68 numbers of the used feature points.
    points : (k, 3) float64
        Their positions on the scan.
    vertices : (k,) int64
        Their template vertices.
    sim : Similarity
        Template (or reference) frame → scan frame, by Procrustes on the features (§4.2).
    norm : Similarity
        Template frame → normalised frame (:func:`_normalisation`).
    """

    query_scan: SurfaceQuery
    ibug: np.ndarray
    points: np.ndarray
    vertices: np.ndarray
    sim: Similarity
    norm: Similarity

    @classmethod
    def build(cls, scan: ScanMesh, features: FeaturePoints, template: Template, base: np.ndarray,
              *, with_scale: bool, tolerance: float) -> "_Alignment":
        query_scan = SurfaceQuery(scan.vertices, scan.faces)
        fidx, fpts, lmv = _usable_features(features, template, query_scan, tolerance)
        sim = similarity_procrustes(base[lmv], fpts, with_scale=with_scale)  # Procrustes (§4.2)
        return cls(query_scan, fidx, fpts, lmv, sim, _normalisation(base, template.landmarks))


def _place_face(al: _Alignment, work: _WorkFrame, x0: np.ndarray, candidates: list,
                template: Template, reference, progress, n_stages: int, **prior_options):
    """Before Eq. (F1): the shape prior's best face (:func:`_fit_priors`), or the reference
    aligned rigidly on the upper face (the cascade); the scan moves, not ``x0``.

    Returns ``(x0, work, history, stats["prior"])``.
    """
    history, prior_info = [], None
    if candidates:
        if progress is not None:
            progress(0, n_stages, "shape prior")
        x0, work, history, prior_info = _fit_priors(work, candidates, x0, al.norm.scale,
                                                    al.vertices, **prior_options)
    if reference is not None:
        upper = upper_face_vertices(x0, template.landmarks)
        work = work.moved(_rigid_icp(work, x0, upper, iterations=25))
    return x0, work, history, prior_info


def _checked_result(al: _Alignment, work: _WorkFrame, x: np.ndarray, x0: np.ndarray, history: list,
                    prior_info, t0: float, diverge_distance: float, diverge_flipped: float
                    ) -> FitResult:
    """The fit ``x`` (work frame) back in scan units, with its statistics; FitDivergedError if it
    is not finite, far from the scan or folded (:func:`_check_converged`)."""
    back = work.to_work.inverse()
    out = back.apply(x)
    resid = np.linalg.norm(out[al.vertices] - al.points, axis=1)
    dist, covered, stats = _surface_stats(al.query_scan, out, x, x0, work.faces, resid)
    stats.update({"scan_units_per_template_unit": float(al.sim.scale),
                  "seconds": time.perf_counter() - t0, "features_used": [int(i) for i in al.ibug],
                  "prior": prior_info})
    _check_converged(out, stats, 1.0 / work.to_work.scale, diverge_distance, diverge_flipped)
    return FitResult(out, work.faces, dist, covered, back.compose(al.norm), resid, stats,
                     tuple(history))


def fit_template(scan: ScanMesh, features: FeaturePoints, template: Template, *,
                 reference: np.ndarray | None = None,
                 prior: ShapePrior | Sequence[ShapePrior] | str | None = "template",
                 prior_iterations: int = 12, prior_lambda: float = 0.1, prior_margin: float = 0.1,
                 schedule: Sequence[FitStage] | None = None, max_angle: float = 60.0,
                 feature_tolerance: float = 0.2,
                 diverge_distance: float = 0.5, diverge_flipped: float = 0.05,
                 progress: Callable[[int, int, str], None] | None = None) -> FitResult:
    """Fit a template to a scan (§4.2).

    Parameters
    ----------
    scan : ScanMesh
        A cleaned scan (:func:`~facetransfer.correspond.meshops.clean_scan`), any units and pose.
    features : FeaturePoints
        At least 8 iBUG-68 points on the scan with template landmarks.
    template : Template
        Defines the output topology and the landmark vertices.
    reference : (n, 3) float, optional
        A previous fit of the same subject in ``template`` topology, in its own scan's coordinates
        (the cascade): it is aligned rigidly on the upper face and deformed instead of the template.
    prior : ShapePrior, "template" or None
        Fit this face space first (:func:`.prior.fit_shape_prior`) and deform its best face instead
        of the template; ``"template"`` (default): the template's own prior, if any. Not used with
        a ``reference`` (the reference already is the subject). A sequence of priors: each is
        fitted, and the one whose face lies closest to the scan is kept (:func:`choose_prior`);
        ``stats["prior"]`` names it and lists every candidate's residual.
    prior_iterations : int
        Closest-point iterations of the prior fit.
    prior_lambda : float
        Weight of the prior ``‖w‖²`` against the proximity of all template vertices at unit weight.
    prior_margin : float
        With several priors, a later (larger) one is chosen only if its residual is lower than the
        best earlier one's by more than this fraction.
    schedule : sequence of FitStage, optional
        Default :data:`PRIOR_SCHEDULE` after a prior, :data:`DEFAULT_SCHEDULE` without.
    max_angle : float
        Closest-point pairs whose normals differ more (degrees) are rejected.
    feature_tolerance : float
        Feature points further than this fraction of their spread from the scan are an error.
    diverge_distance : float
        Mean distance (normalised cm) above which the fit counts as diverged.
    diverge_flipped : float
        Fraction of flipped triangles above which the fit counts as diverged.
    progress : callable(stage_index, n_stages, stage_name), optional
        Called before each stage (the prior fit counts as one) and once with ``"done"``.

    Returns
    -------
    FitResult

    Raises
    ------
    FeatureError
        Too few usable features, or features off the scan.
    FitDivergedError
        The fit ended far from the scan or folded; nothing should be written.

    References
    ----------
    Vlasic et al. 2005, §4.2; Allen et al. 2003; Sumner & Popović 2004; Umeyama 1991.
    """
    t0 = time.perf_counter()
    candidates = _prior_candidates(prior, template, reference)
    if schedule is None:
        schedule = PRIOR_SCHEDULE if candidates else DEFAULT_SCHEDULE
    base = _base_vertices(template, reference)
    al = _Alignment.build(scan, features, template, base, with_scale=reference is None,
                          tolerance=feature_tolerance)
    x0 = al.norm.apply(base)
    work = _WorkFrame.start(al.norm.compose(al.sim.inverse()), al.query_scan, al.points,
                            template.faces, max_angle, x0)
    n_stages = len(schedule) + bool(candidates)
    x0, work, history, prior_info = _place_face(
        al, work, x0, candidates, template, reference, progress, n_stages,
        iterations=prior_iterations, lam=prior_lambda, margin=prior_margin)
    x, stage_history = _deform(work, x0, al.vertices, schedule, progress, bool(candidates), n_stages)
    return _checked_result(al, work, x, x0, history + stage_history, prior_info, t0,
                           diverge_distance, diverge_flipped)

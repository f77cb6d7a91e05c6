"""A linear shape prior for template fitting: start the deformation from the scan's nearest face
in a face space instead of from the generic template.

§4.2 fits a generic template with a smoothness energy alone. On a smooth, featureless region
(cheeks, jaw) that energy cannot tell where along the surface a template vertex belongs, so the
correspondence slides tangentially. A face space learned from corresponded faces (here
ICT-FaceKit's identity principal components) knows how faces vary: fitting its coefficients first
puts every vertex close to its place, and the smooth deformation of :mod:`.fitting`'s Eq. (F1) then only has to
explain what the face space misses (the morphable model of Blanz & Vetter 1999; model-based
registration such as FLAME's, Li et al. 2017, regularises with the model in the same spirit).

The stage solves, per closest-point iteration, the linear least-squares problem

    min_{Δw, ω, t, s}  Σ_i (n_iᵀ(y_i − q_i))² + w_p Σ_i ‖y_i − q_i‖²
                     + w_f Σ_l ‖y_{v(l)} − f_l‖² + λ ‖w + Δw‖²                           (P)

    with  y_i = x_i + B_i Δw + ω×(x_i − c) + t + s (x_i − c)

(``x``: the current face, ``q_i`` the closest scan point of vertex ``i`` with normal ``n_i``,
``f_l`` the feature points; point-to-plane proximity with a little point-to-point, features, and
a Gaussian prior on the coefficients ``w ~ N(0, I)``, the basis being scaled by its standard
deviations), together with a small similarity update of the face's pose (``ω, t, s`` linearised
about the centroid ``c``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError
from .procrustes import Similarity, rotation_from_vector


@dataclass(frozen=True)
class ShapePrior:
    """A linear face space around a template: ``x = x₀ + Σ_k w_k basis_k``, ``w ~ N(0, I)``.

    Attributes
    ----------
    basis : (K, n, 3) float64
        Offsets from the template's vertices, each scaled by its standard deviation (template
        units).
    name : str
    """

    basis: np.ndarray
    name: str = "prior"

    def __post_init__(self):
        b = np.asarray(self.basis, dtype=np.float64)
        if b.ndim != 3 or b.shape[2] != 3 or b.shape[0] < 1 or not np.all(np.isfinite(b)):
            raise MeshError(f"shape prior {self.name}: basis must be finite (K, n, 3), got {b.shape}")
        object.__setattr__(self, "basis", b)

    @property
    def n_components(self) -> int:
        return int(self.basis.shape[0])


@dataclass(frozen=True)
class PriorFit:
    """Result of :func:`fit_shape_prior`.

    Attributes
    ----------
    coefficients : (K,) float64
        ``w`` of the face space (standard deviations).
    pose : Similarity
        Work frame → work frame: moves the prior face onto the scan.
    face : (n, 3) float64
        The prior face ``x₀ + B w`` (the template's frame).
    history : tuple of dict
        Per iteration: accepted pairs and their mean distance.
    """

    coefficients: np.ndarray
    pose: Similarity
    face: np.ndarray
    history: tuple

    @property
    def vertices(self) -> np.ndarray:
        """``pose(x₀ + B w)``: the prior face on the scan, work frame ``(n, 3)``."""
        return self.pose.apply(self.face)


def _skew_rows(p: np.ndarray) -> np.ndarray:
    """``(m, 3, 3)`` matrices ``J`` with ``J ω = ω × p``."""
    z = np.zeros(len(p))
    return np.stack([np.stack([z, p[:, 2], -p[:, 1]], 1),
                     np.stack([-p[:, 2], z, p[:, 0]], 1),
                     np.stack([p[:, 1], -p[:, 0], z], 1)], 1)


def _jacobian(b_rows: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Jacobian ``(m, 3, K + 7)`` of Eq. (P)'s points w.r.t. ``(Δw, ω, t, s)``.

    ``b_rows (m, 3, K)``: the posed basis at those vertices; ``p (m, 3)``: their offsets from the
    centroid the rotation and scale act about.
    """
    eye = np.broadcast_to(np.eye(3), (len(p), 3, 3))
    return np.concatenate([b_rows, _skew_rows(p), eye, p[:, :, None]], axis=2)


def _normal_equations(x: np.ndarray, c: np.ndarray, pose: Similarity, bt: np.ndarray, pairs,
                      lmv: np.ndarray, fpts: np.ndarray, w_features: float, w_point: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The data part of one Gauss-Newton step of Eq. (P): ``(a (K+7, K+7), b (K+7,))``.

    ``x`` (n, 3) is the current face, ``c`` its centroid, ``bt`` (n, 3, K) the basis and
    ``pairs`` the accepted ``(idx (m,), points (m, 3), normals (m, 3))``: point-to-plane plus
    ``w_point`` point-to-point rows for the pairs, ``w_features`` point rows for the features.
    """
    idx, q, nrm = pairs
    kk = bt.shape[2]
    rows = np.concatenate([idx, lmv])
    b_rows = pose.scale * np.einsum("ij,njk->nik", pose.rotation, bt[rows])  # ∂x/∂w
    jac = _jacobian(b_rows, x[rows] - c)
    jp, jf = jac[:len(idx)], jac[len(idx):].reshape(-1, kk + 7)
    plane = np.einsum("md,mdk->mk", nrm, jp)                   # point-to-plane rows
    r_plane = np.einsum("md,md->m", nrm, q - x[idx])
    jpt = jp.reshape(-1, kk + 7)
    r_pt = (q - x[idx]).reshape(-1)
    r_f = (fpts - x[lmv]).reshape(-1)
    a = plane.T @ plane + w_features * jf.T @ jf + w_point * jpt.T @ jpt
    b = plane.T @ r_plane + w_features * jf.T @ r_f + w_point * jpt.T @ r_pt
    return a, b


def fit_shape_prior(pairs_fn, x0: np.ndarray, basis: np.ndarray, lmv: np.ndarray,
                    fpts: np.ndarray, *, iterations: int = 12, lam: float = 1.0,
                    w_features: float = 10.0, w_point: float = 0.05) -> PriorFit:
    """Fit the face space's coefficients and the pose to a scan (Eq. P), in the work frame.

    Gauss-Newton on Eq. (P): each iteration takes the current closest-point pairs, solves the
    ``(K + 7)``-unknown normal equations and composes the small similarity step onto the pose.

    Parameters
    ----------
    pairs_fn : callable(x (n, 3), iteration) -> (idx (m,), points (m, 3), normals (m, 3))
        Accepted closest-point pairs of the current face on the scan.
    x0 : (n, 3) float
        The template, work frame.
    basis : (K, n, 3) float
        The prior's basis in work-frame units.
    lmv : (k,) int
        Template vertices of the feature points; ``fpts`` their positions ``(k, 3)``.
    iterations : int
    lam : float
        Weight of ``‖w‖²`` against a unit-weight pair.
    w_features : float
        Weight of a feature point (point-to-point).
    w_point : float
        Weight of a point-to-point term added to each point-to-plane pair (keeps the tangential
        directions determined on flat regions).

    Returns
    -------
    PriorFit
    """
    x0 = np.asarray(x0, dtype=np.float64)
    n = len(x0)
    kk = basis.shape[0]
    if basis.shape[1:] != (n, 3):
        raise MeshError(f"shape prior basis {basis.shape} does not match the template ({n}, 3)")
    w = np.zeros(kk)
    pose = Similarity.identity()
    hist = []
    bt = np.ascontiguousarray(np.moveaxis(basis, 0, -1))          # (n, 3, K)
    for it in range(iterations):
        x = pose.apply(x0 + bt @ w)
        c = x.mean(axis=0)
        idx, q, nrm = pairs_fn(x, it)
        hist.append({"pairs": int(len(idx)),
                     "mean_distance": float(np.mean(np.linalg.norm(x[idx] - q, axis=1)))
                     if len(idx) else None})
        a, b = _normal_equations(x, c, pose, bt, (idx, q, nrm), lmv, fpts, w_features, w_point)
        a[:kk, :kk] += lam * np.eye(kk)
        b[:kk] -= lam * w
        a[kk:, kk:] += 1e-9 * np.eye(7)
        sol = np.linalg.solve(a, b)
        w = w + sol[:kk]
        om, t, s = sol[kk:kk + 3], sol[kk + 3:kk + 6], sol[kk + 6]
        r = rotation_from_vector(om)
        pose = Similarity(1.0 + s, r, c - (1.0 + s) * r @ c + t).compose(pose)
    return PriorFit(w, pose, x0 + bt @ w, tuple(hist))


#: Kinds of :func:`ict_prior`.
ICT_PRIORS = ("identity", "identity+expression")


def ict_prior(kind: str = "identity", *, region: str = "face", n_components: int = 100,
              expression_scale: float = 0.5, neutral: np.ndarray | None = None) -> ShapePrior:
    """A face space around ICT-FaceKit's generic neutral.

    Parameters
    ----------
    kind : {"identity", "identity+expression"}
        ``"identity"``: the identity principal components (already scaled by their standard
        deviations), for neutral scans. ``"identity+expression"`` adds the ARKit-named expression
        shapes, each scaled by ``expression_scale`` (a weight of about that size is typical), for
        a scan in an expression without a fitted neutral of the same person.
    n_components : int
        Leading identity components kept (1..100).
    neutral : (n, 3) array, optional
        The region's generic neutral, if already read (saves reading it again).
    """
    from ..datasets.ict import ict_expression_components, ict_identity_components

    if kind not in ICT_PRIORS:
        raise ValueError(f"unknown ICT prior {kind!r}; expected one of {', '.join(ICT_PRIORS)}")
    if not 1 <= n_components <= 100:
        raise ValueError(f"ICT prior: n_components must be 1..100, got {n_components}")
    b = ict_identity_components(region, neutral=neutral)[:n_components]
    name = f"ICT-FaceKit identity ({n_components} components)"
    if kind == "identity+expression":
        names, e = ict_expression_components(region, neutral=neutral)
        b = np.concatenate([b, expression_scale * e])
        name = f"ICT-FaceKit identity ({n_components}) + expression ({len(names)} shapes)"
    return ShapePrior(b, name)


def model_identity_prior(model, mode: str | int = "identity", *, min_variance: float = 1e-4
                         ) -> ShapePrior | None:
    """The identity space of a multilinear model around its default face, Eq. (9).

    With the other modes at their mean weights the model is linear in the identity weights,
    ``x = x̄ + M_id (w − w̄)``; the training identities' covariance ``C = V Λ Vᵀ`` gives the basis
    ``M_id V Λ^{1/2}`` (components with variance above ``min_variance`` of the largest).
    Returns ``None`` when the model has no such mode or its training items do not vary.
    """
    try:
        k = model.mode_index(mode)
    except (KeyError, ValueError, IndexError):
        return None
    w = model.default_weights()
    basis = model.mode_basis(k, w)                                  # (n, 3, r)
    lam, vec = np.linalg.eigh(model.weight_cov(k))
    keep = lam > min_variance * max(float(lam.max()), 1e-300)
    if float(lam.max()) <= 1e-12 or not keep.any():          # one training identity: no space
        return None
    order = np.argsort(lam[keep])[::-1]
    cols = vec[:, keep][:, order] * np.sqrt(lam[keep][order])
    b = np.einsum("ndr,rk->knd", basis, cols)
    return ShapePrior(b, f"{model.mode_names[k]} space of the model ({b.shape[0]} components)")

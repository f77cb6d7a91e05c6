"""The capture's model at its tracked points (:mod:`facetransfer.track.capture`).

:class:`Sampler` turns the model into one whose "vertices" are the tracked points (the iBUG-68
landmark vertices, then MediaPipe's dense surface points), and :class:`Shape` is the face at
those points as a linear function of one frame's parameters for a fixed identity and offset
(static, plus a part that follows the head's yaw: :meth:`Shape.at_view`): the person's ARKit rig with bounded activations, or the per-frame modes of another
model with their training priors (Vlasic et al. 2005, Eq. (5), (9)). ``Shape.solve`` fits those
parameters to a frame's 2-D targets at a fixed pose (Eq. (7)).
"""

from __future__ import annotations

import numpy as np

from ..arkit import ARKIT_NAMES, activation_basis, activation_prior_scale, expression_rig, \
    is_arkit_model
from .camera import Pose
from .fit2d import (Targets, gram_blocks, project_basis, rig_normal, rig_solve,
                    targets_normal)
from .gaze import GAZE_NAMES
from .lip_contact import lip_contact
from .solver import BasisCache, Prior

__all__ = ["Sampler", "sampler", "release", "Shape", "EYELID"]

#: ARKit shapes of the eyelids: fast (a blink closes and opens in 4-6 frames).
EYELID = ("eyeBlink", "eyeSquint", "eyeWide")


class Sampler:
    """The tracked points as a multilinear model of their own.

    Points are linear in the vertices (``points = S @ vertices``, ``S`` ``(P, n)`` sparse; rows
    0-67 are the iBUG landmark vertices, then the dense surface points), so applying ``S`` to
    the core once gives a model whose "vertices" are the tracked points: every Eq. (9) basis
    of the run is then a contraction of a small core. :func:`sampler` keeps the last few.
    """

    def __init__(self, model, dense=None) -> None:
        from scipy.sparse import csr_matrix

        from ..model import MultilinearModel

        lm = np.asarray(model.landmarks, np.int64)
        tris = np.zeros((0, 3), np.int64) if dense is None else dense.triangles
        P, n = 68 + len(tris), model.n_vertices
        rows = np.concatenate([np.arange(68), np.repeat(np.arange(68, P), 3)])
        vals = np.concatenate([np.ones(68), np.zeros(0) if dense is None else dense.bary.ravel()])
        S = csr_matrix((vals, (rows, np.concatenate([lm, tris.ravel()]))), shape=(P, n))
        core = model.core.reshape(n, -1)       # (n, 3 r_1 ... r_K): a view, rows read where used
        core = np.asarray(S @ core).reshape((3 * P,) + model.core.shape[1:])
        self.model = MultilinearModel(core=core, factors=model.factors,
                                      mode_names=model.mode_names, labels=model.labels,
                                      faces=np.zeros((0, 3), np.int64))
        self.mp_index = None if dense is None else dense.mp_index


#: The last samplers made (:func:`sampler`), by model and dense points.
_SAMPLERS: dict = {}


def sampler(model, dense=None) -> Sampler:
    """``Sampler(model, dense)``, reused while the model (its content hash) and the dense
    points are those of one of the last two calls (a sampler is never changed). The one made
    is returned, not read back: another thread's :func:`release` (a job of a ``batch`` worker
    whose tracks are in, beside one tracking) may empty the cache meanwhile."""
    key = (model.content_hash, None if dense is None else
           (dense.mp_index.tobytes(), dense.triangles.tobytes(), dense.bary.tobytes()))
    made = _SAMPLERS.get(key)
    if made is None:
        made = Sampler(model, dense)
        for old in list(_SAMPLERS)[:-1]:       # the last one made before this one is kept
            _SAMPLERS.pop(old, None)
        _SAMPLERS[key] = made
    return made


def release() -> None:
    """Drop the samplers :func:`sampler` keeps (the default model's with MediaPipe's dense
    points is 24.5 MB, its core read at the points): a command whose tracks are in
    (:func:`facetransfer.track.obtain.done_tracking`) held it through its whole render. The
    next fit makes it again: 0.015-0.02 CPU-s in the same process (the first, 0.1-0.15 CPU-s,
    also maps the core's pages from its file)."""
    _SAMPLERS.clear()


class Shape:
    """The face at the 68 landmark vertices as a linear function of per-frame parameters.

    For an ARKit model: ``X(a) = N + Σ_j a_j Δ_j`` (the person's rig, bounded ``a``); otherwise
    one block per per-frame mode with its training prior (Eq. (9), coordinate descent).
    """

    def __init__(self, model, identity: np.ndarray | None, sampler: Sampler,
                 opt, offset: np.ndarray | None = None,
                 view: np.ndarray | None = None):  # opt: capture.CaptureOptions
        self.model, self.opt = sampler.model, opt                           # points model
        P = sampler.model.n_vertices
        self.offset = np.zeros((P, 3)) if offset is None else offset        # (P, 3) static
        self.view = view                    # (P, 3): the offset's part times sin(yaw), or None
        # (the yaw of the capture angles, R = Rx(pitch) Ry(yaw) Rz(roll): sin(yaw) = R[0, 2])
        self.arkit = is_arkit_model(model)
        self.id_name = "identity" if "identity" in model.mode_names else None
        self.per_frame = tuple(m for m in model.mode_names if m != self.id_name)
        self.identity = identity
        if self.arkit:
            w = {self.id_name: identity} if self.id_name else {}
            rig = expression_rig(self.model, w | {"expression": np.zeros(model.ranks[
                model.mode_index("expression")])})
            self.used = np.flatnonzero(np.any(rig.deltas != 0, axis=(1, 2)))
            self.N = rig.neutral + self.offset                                 # (P, 3)
            self.D = rig.deltas[self.used]                                     # (K, P, 3)
            self.size = len(self.used)
            self.x0 = np.zeros(self.size)
            self.ridge = activation_prior_scale()[self.used]   # (K,) the prior's, per shape
            self.fast = np.array([n.startswith(EYELID) for n in ARKIT_NAMES])[self.used]
            self.u0, D = activation_basis(self.model)
            self.Du = D[self.used]                                             # (K, r)
            self.gaze_k = np.array([int(np.flatnonzero(self.used == ARKIT_NAMES.index(n))[0])
                                    if ARKIT_NAMES.index(n) in self.used else -1
                                    for n in GAZE_NAMES])                      # (8,) or -1
            self._flat = (self.D.reshape(self.size, -1), self.N.ravel())      # (K, 3P), (3P,)
            self._blocks: dict = {}                                            # nominal -> C
            self._zeros, self._ones = np.zeros(self.size), np.ones(self.size)  # the box
            # the lips' contact: the inner-lip gaps, linear in the activations (lip_contact)
            self.lips = lip_contact(rig.neutral, self.D) if opt.lip_contact else None
        else:
            self.priors = {m: Prior.from_model(model, m) for m in self.per_frame}
            self.precision = {m: p.Q @ p.inv_cov @ p.Q.T for m, p in self.priors.items()}
            # the identity is fixed for this shape: contracted into the core once (Eq. (5))
            self.cache = BasisCache(self.model, {self.id_name: identity} if self.id_name else {})
            self.sizes = [model.ranks[model.mode_index(m)] for m in self.per_frame]
            self.size = int(sum(self.sizes))
            self.x0 = np.concatenate([self.priors[m].mean for m in self.per_frame])
            self.lips = None                   # the lips' contact: ARKit activations only

    def offset_at(self, sin_yaw: float) -> np.ndarray:
        """The offset of the tracked points at a head yaw: ``offset + sin_yaw view``, (P, 3).

        ``sin_yaw`` is the sine of the yaw of the capture angles (``R = Rx(pitch) Ry(yaw)
        Rz(roll)``, so ``R[0, 2]``; :mod:`facetransfer.render.cameras`): about the model's y
        axis, positive with the face turned toward the image's right; no unit (a sine)."""
        return self.offset if self.view is None else self.offset + float(sin_yaw) * self.view

    def at_view(self, sin_yaw: float) -> "Shape":
        """The same shape with the offset at a head yaw (:meth:`offset_at`; ``sin_yaw`` as
        there, ``R[0, 2]``): itself without a view-dependent offset."""
        if self.view is None:
            return self
        other = self._copy()
        d = float(sin_yaw) * self.view
        if self.arkit:
            other.N = self.N + d
            other._flat = (self._flat[0], other.N.ravel())
        else:
            other.offset = self.offset + d
        other.view = None
        return other

    def with_options(self, opt) -> "Shape":
        """The same shape solved with other settings (e.g. the identity phase's priors)."""
        other = self._copy()
        other.opt = opt
        return other

    def _copy(self) -> "Shape":
        """A shallow copy (``copy.copy``'s, without its protocol lookups: :meth:`at_view`
        makes one at every pose step of the fit)."""
        other = type(self).__new__(type(self))
        other.__dict__.update(self.__dict__)
        return other

    def basis(self, mode: str, weights: dict) -> np.ndarray:
        """Eq. (9) at the tracked points: ``(r, P, 3)``."""
        if self.arkit:
            return np.moveaxis(self.model.mode_basis(mode, weights), 2, 0)
        return np.moveaxis(self.cache.basis(mode, weights), 2, 0)

    def identity_bases(self, X: np.ndarray, identity: np.ndarray) -> np.ndarray:
        """Eq. (9)'s identity basis for each frame's parameters ``X`` (F, size), the identity
        entry of the weights being ``identity``: ``(F, r, P, 3)`` (an ARKit model of identity
        and expression: the expression mode of every frame contracted in one product)."""
        m = self.model
        if self.arkit and set(m.mode_names) == {"identity", "expression"}:
            E = self.weights(X)["expression"]                                  # (F, r_e)
            B = np.tensordot(E, m.core, axes=([1], [m.mode_index("expression") + 1]))
            return np.moveaxis(B.reshape(len(E), -1, 3, B.shape[-1]), 3, 1)   # (F, 3P, r)
        out = []
        for x in X:
            w = self.weights(x)
            w[self.id_name] = identity
            out.append(self.basis(self.id_name, w))
        return np.stack(out)

    def weights(self, x: np.ndarray) -> dict:
        """Model weights of every per-frame mode for parameters ``x`` ``(..., size)``."""
        if self.arkit:
            return {"expression": self.u0 + x @ self.Du}                   # Eq. (A)
        out, i = {}, 0
        for m, r in zip(self.per_frame, self.sizes):
            out[m] = x[..., i:i + r]
            i += r
        return out

    def points(self, x: np.ndarray) -> np.ndarray:
        """The tracked points ``(P, 3)`` for parameters ``x`` (ARKit: ``N + Σ_j x_j Δ_j``)."""
        if self.arkit:
            D, N = self._flat
            return (x @ D + N).reshape(-1, 3)
        return self.cache.shape(self.weights(x)) + self.offset

    def blocks(self, nominal: np.ndarray) -> np.ndarray:
        """``gram_blocks(D, nominal)`` (ARKit), made once per nominal weights (a clip has two:
        detections alone, detections and flow)."""
        key = nominal.tobytes()
        if key not in self._blocks:
            if len(self._blocks) >= 4:
                self._blocks.clear()
            self._blocks[key] = gram_blocks(self.D, nominal)
        return self._blocks[key]

    def solve(self, pose: Pose, targets: Targets, iod: float, x: np.ndarray,
              prev: np.ndarray | None, fixed: np.ndarray | None = None,
              anchor: tuple | None = None, extra_ridge: np.ndarray | None = None) -> np.ndarray:
        """The per-frame parameters best explaining ``targets`` at ``pose`` (ARKit: the
        activations where ``fixed`` (K,) is finite held at its values, and, with ``anchor`` =
        ``(a, f)`` (K,) each, pulled with weight ``opt.scores · f`` toward ``a`` where it is
        finite: the mapped detector scores of :mod:`facetransfer.track.scores` and their lines'
        weights; ``extra_ridge`` (K,) added to the prior's ridge toward 0 (the funnel's where
        the lips are shut: :func:`~facetransfer.track.capture.funnel_ridges`); with
        ``opt.lip_contact``, where the box solution crosses the lips, solved again with the
        inner-lip gaps held:
        :mod:`facetransfer.track.lip_contact`)."""
        lam_p, lam_t = self.opt.expression_prior, (self.opt.temporal if prev is not None else 0.0)
        if self.arkit:
            lam_t = (np.where(self.fast, self.opt.temporal, self.opt.slow_temporal)
                     if prev is not None else 0.0)                           # (K,)
            ridge = lam_p * self.ridge + lam_t + 1e-9     # (K,): the prior's and the temporal
            if extra_ridge is not None:
                ridge = ridge + extra_ridge
            rhs = lam_t * prev if prev is not None else np.zeros(self.size)
            if anchor is not None:
                a, f = anchor
                ok = np.isfinite(a) & np.isfinite(f)
                lam_a = np.where(ok, self.opt.scores * f, 0.0)               # (K,)
                ridge = ridge + lam_a
                rhs = rhs + lam_a * np.where(ok, a, 0.0)
            lo, hi = self._zeros, self._ones
            if fixed is not None:
                ok = np.isfinite(fixed)
                lo, hi = np.where(ok, fixed, 0.0), np.where(ok, fixed, 1.0)
            blocks, base, rhs = self.blocks(targets.nominal), pose.project(self.N), \
                rhs - self.opt.sparsity
            x = rig_solve(self.D, blocks, pose, targets, base, iod, x, ridge=ridge, rhs=rhs,
                          lo=lo, hi=hi, tol=1e-5)                                 # Eq. (9)
            if self.lips is not None and self.lips.crossed(x):     # the lips cross: held apart
                G, h = rig_normal(self.D, blocks, targets.nominal, pose, targets.p, targets.w,
                                  base, iod)
                x = self.lips.solve(G + np.diag(ridge), h + rhs, x, lo, hi)
            return x
        return self._solve_modes(pose, targets, iod, x, prev, lam_p, lam_t)

    def _solve_modes(self, pose, targets, iod, x, prev, lam_p, lam_t):
        x = x.copy()
        offs = np.cumsum([0] + self.sizes)
        for k, m in enumerate(self.per_frame):
            w = self.weights(x)
            if self.id_name:
                w[self.id_name] = self.identity
            Y = project_basis(self.basis(m, w), pose)                     # Eq. (9)
            G, h = targets_normal(Y, pose.project(self.offset), list(zip(targets.p, targets.w)),
                                  iod)
            pr, P = self.priors[m], self.precision[m]
            G = G + lam_p * P + (lam_t + 1e-9) * np.eye(len(pr.mean))
            h = h + lam_p * P @ pr.mean
            if lam_t:
                h = h + lam_t * prev[offs[k]:offs[k + 1]]
            x[offs[k]:offs[k + 1]] = np.linalg.solve(G, h)
        return x

"""One frame pair of the paper's tracker (Vlasic et al. 2005, §5.1, Eq. (6)-(9)).

:class:`FaceTracker` holds what lasts between frames (the model, options, basis caches, the
vertex choice). :meth:`FaceTracker.track_pair` chooses about a thousand visible, well-textured
vertices at frame ``t``, stacks their symmetric KLT terms (Eq. (6)) against frame ``t + 1`` into
one system for the pose and one mode's weights (Eq. (7)-(9)) and solves it by Gauss-Newton,
coarse to fine over an image pyramid, cycling through the per-frame modes (coordinate descent).
It also returns the pair's reduced identity system, which the passes of
:mod:`facetransfer.track.tracker` accumulate and solve once per pass (§5.1).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import N_POSE, Pose, compose, pose_jacobian, project, so3_log
from .init import require_landmarks
from .klt import (Pyramid, build_pyramid, klt_terms_at, level_coords, robust_weights,
                  sample_windows, window_confidence, window_offsets)
from .landmarks import IBUG_WEIGHTS, eye_distance
from .options import TrackOptions
from .solver import (BasisCache, FrameState, Prior, flow_normal_equations, normal_equations,
                     point_terms, prior_terms, schur_reduce, solve_step, weight_jacobian)

__all__ = ["FaceTracker", "PairResult"]


@dataclass
class PairResult:
    """The solution of one frame pair: the state at ``t + 1``, its confidence in [0, 1], the
    pair's reduced identity system ``(S, c)`` (when accumulated) and the number of tracked
    vertices."""

    state: FrameState
    confidence: float
    identity_system: tuple | None
    n_points: int


@dataclass(frozen=True)
class _PairProblem:
    """What one pair's solve holds fixed: frame ``t + 1``, the model rows of the tracked
    vertices, the starting point and the anchor term."""

    pyr1: Pyramid
    cache: BasisCache
    guess: FrameState
    anchor: tuple | None


class FaceTracker:
    """The tracker's state between frames: the model, options, caches and the identity.

    Parameters
    ----------
    model : MultilinearModel
    frame_size : (W, H)
    options : TrackOptions
    detector : object with ``detect(frame) -> (68, 2) or None``, optional
    """

    def __init__(self, model, frame_size, options: TrackOptions | None = None, *,
                 detector=None, fixed: tuple[str, ...] = ()) -> None:
        self.model = model
        self.opt = options or TrackOptions()
        self.size = (int(frame_size[0]), int(frame_size[1]))
        self.detector = detector
        self.lm_vertices = require_landmarks(model)
        self.fixed = tuple(fixed)
        # clip-constant modes: the identity and any mode given by the caller
        self.constant = tuple(m for m in model.mode_names if m == "identity" or m in self.fixed)
        self.per_frame = tuple(m for m in model.mode_names if m not in self.constant)
        # constant modes solved once per pass (§5.1)
        self.accumulated = tuple(m for m in self.constant if m not in self.fixed)
        self.priors = {m: Prior.from_model(model, m) for m in model.mode_names}
        self.offsets, self.wwin = window_offsets(self.opt.half_window)
        Xl = model.synthesize(model.default_weights(), vertices=self.lm_vertices[[36, 45]])
        self.model_iod = float(np.linalg.norm(Xl[0] - Xl[1]))  # outer eye corners, model units
        self._cache: BasisCache | None = None
        self._cache_key = None
        self._selection: tuple | None = None  # (vertices, pose, pairs since) for `reselect`
        self.timings: dict[str, float] = {}
        self.counts: dict[str, int] = {}

    # ------------------------------------------------------------------ model evaluation
    def cache(self, weights: dict) -> BasisCache:
        key = tuple(np.asarray(weights[m]).tobytes() for m in self.constant)
        if self._cache is None or self._cache_key != key:
            self._cache = BasisCache(self.model, {m: weights[m] for m in self.constant})
            self._cache_key = key
        return self._cache

    def pyramid(self, frame: np.ndarray) -> Pyramid:
        return build_pyramid(frame, self.opt.levels)

    # ------------------------------------------------------------------ vertex selection
    def select_vertices(self, state: FrameState, pyr: Pyramid) -> tuple[np.ndarray, np.ndarray]:
        """Visible, well-textured vertices spread over the face at this state.

        Returns
        -------
        vertices : (k,) int64
        points : (k, 2) float64
            Their pixels in this frame.
        """
        from ..geometry import vertex_normals
        from ..render import WeakPerspective, vertex_visibility

        V = self.cache(state.weights).shape(state.weights)            # (n, 3)
        pose = state.pose
        W, H = self.size
        f = self.opt.visibility_scale
        sw, sh = max(int(round(W * f)), 8), max(int(round(H * f)), 8)
        fx, fy = sw / W, sh / H
        ff = min(fx, fy)
        cam = WeakPerspective(pose.scale * ff, pose.rotation,
                              (pose.translation + 0.5) * ff - 0.5)
        try:
            vis = vertex_visibility(V, self.model.faces, cam, (sw, sh))
        except ValueError:
            vis = np.zeros(V.shape[0], bool)
        N = vertex_normals(V, self.model.faces) @ pose.rotation[2]      # camera-facing part
        p = project(V, pose.rotation, pose.scale, pose.translation)
        cand = np.flatnonzero(vis & (N > 0.3) & self._inside(p))
        if cand.size == 0:
            return cand, np.zeros((0, 2))
        # texture strength: min eigenvalue of the structure tensor on level 1 (or 0)
        lv = min(1, pyr.n_levels - 1)
        img = pyr.levels[lv][..., 0]
        eig = cv2.cornerMinEigenVal(img, 5, 3)
        pl = level_coords(p[cand], lv)
        xi = np.clip(np.rint(pl[:, 0]).astype(int), 0, img.shape[1] - 1)
        yi = np.clip(np.rint(pl[:, 1]).astype(int), 0, img.shape[0] - 1)
        score = eig[yi, xi]
        k = self.opt.n_points
        if cand.size <= k:
            return cand, p[cand]
        chosen = cand[_spread(p[cand], score, k)]
        return chosen, p[chosen]

    def _inside(self, p: np.ndarray) -> np.ndarray:
        """(n,) bool: pixels (n, 2) whose KLT windows (with a margin) lie inside the frame."""
        W, H = self.size
        m = self.opt.half_window * 2 + 2
        return (p[:, 0] > m) & (p[:, 0] < W - 1 - m) & (p[:, 1] > m) & (p[:, 1] < H - 1 - m)

    def _reuse_selection(self, state: FrameState):
        """The last vertex choice re-projected at ``state`` (``TrackOptions.reselect``), or
        ``(None, None)`` when a new choice is due."""
        opt = self.opt
        last = self._selection
        if opt.reselect <= 1 or last is None:
            return None, None
        sel, pose, age = last
        if age + 1 >= opt.reselect or sel.size == 0:
            return None, None
        turn = np.degrees(np.linalg.norm(so3_log(state.pose.rotation @ pose.rotation.T)))
        if turn > opt.reselect_degrees or abs(np.log(state.pose.scale / pose.scale)) > 0.05:
            return None, None
        X = self.cache(state.weights).restrict(sel).shape(state.weights)
        p = project(X, state.pose.rotation, state.pose.scale, state.pose.translation)
        inside = self._inside(p)
        if inside.mean() < 0.9:  # the face is leaving the frame: choose again
            return None, None
        self._selection = (sel, pose, age + 1)
        return sel[inside], p[inside]

    # ------------------------------------------------------------------ one frame pair
    def track_pair(self, pyr0: Pyramid, pyr1: Pyramid, state0: FrameState, guess: FrameState, *,
                   anchor: np.ndarray | None = None, accumulate: bool = False,
                   key: tuple | None = None) -> PairResult:
        """Solve the pose and per-frame weights of the second frame of a pair (Eq. (6)-(9)).

        Parameters
        ----------
        pyr0, pyr1 : Pyramid
            Frames ``t`` (solved) and ``t + 1``.
        state0 : FrameState
            The solution at ``t``.
        guess : FrameState
            Starting point at ``t + 1``.
        anchor : (68, 2), optional
            Detector landmarks at ``t + 1`` (NaN where missing), an extra term.
        accumulate : bool
            Also return the identity's reduced system of this pair (§5.1).
        key : (Pyramid, FrameState), optional
            A key frame (the first tracked frame) and its solution: its windows give a second
            KLT term for the same vertices (weight ``keyframe``), against drift.
        """
        t0 = _now()
        sel, q = self._choose_vertices(state0, pyr0)
        self._tick("select", t0)
        if sel.size < 10:
            return PairResult(guess, 0.0, None, int(sel.size))
        prob = _PairProblem(pyr1, self.cache(guess.weights).restrict(sel), guess,
                            self._anchor_term(anchor))
        q_key = self._key_points(key, sel)
        pose = guess.pose
        weights = {k: np.asarray(v, float).copy() for k, v in guess.weights.items()}
        wi = None
        for lv in reversed(range(min(self.opt.levels, pyr0.n_levels))):   # coarse to fine
            t1 = _now()
            wi = sample_windows(pyr0.levels[lv], level_coords(q, lv), self.offsets)
            wk = (sample_windows(key[0].levels[lv], level_coords(q_key, lv), self.offsets)
                  if q_key is not None and lv <= 1 else None)
            self._tick("sample", t1)
            pose = self._solve_level(prob, lv, wi, wk, pose, weights)
        return self._finish_pair(prob, sel, wi, FrameState(pose, weights), accumulate, t0)

    def _choose_vertices(self, state0: FrameState, pyr0: Pyramid
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The tracked vertices (k,) and their pixels (k, 2) at ``t``: the last choice reused
        (``reselect``) or a new one."""
        sel, q = self._reuse_selection(state0)
        if sel is None:
            sel, q = self.select_vertices(state0, pyr0)
            self._selection = (sel, state0.pose, 0)
            self.counts["selections"] = self.counts.get("selections", 0) + 1
        return sel, q

    def _anchor_term(self, anchor: np.ndarray | None) -> tuple | None:
        """``(vertices, targets (k, 2), weights)`` of the detector landmarks given, or None."""
        if anchor is None or self.opt.anchor_weight <= 0:
            return None
        ok = np.all(np.isfinite(anchor), axis=1)
        if ok.sum() < 4:
            return None
        return self.lm_vertices[ok], np.asarray(anchor, float)[ok], IBUG_WEIGHTS[ok]

    def _key_points(self, key: tuple | None, sel: np.ndarray) -> np.ndarray | None:
        """Pixels (k, 2) of the tracked vertices in the key frame, or None (no key term)."""
        if key is None or self.opt.keyframe <= 0:
            return None
        kst = key[1]
        Xk = self.cache(kst.weights).restrict(sel).shape(kst.weights)
        return project(Xk, kst.pose.rotation, kst.pose.scale, kst.pose.translation)

    def _solve_level(self, prob: _PairProblem, lv: int, wi: np.ndarray, wk: np.ndarray | None,
                     pose: Pose, weights: dict) -> Pose:
        """Gauss-Newton on pyramid level ``lv``: up to ``iterations`` cycles through the
        per-frame modes; ``weights`` is updated in place, the new pose returned."""
        f = 0.5 ** lv
        for _ in range(self.opt.iterations):
            moved = 0.0
            for m in self.per_frame:
                pose, step = self._mode_step(prob, lv, wi, wk, pose, weights, m)
                moved = max(moved, step)
            if moved < self.opt.tolerance / f:  # converged on this level (rms pixel motion)
                break
        return pose

    def _mode_step(self, prob: _PairProblem, lv: int, wi: np.ndarray, wk: np.ndarray | None,
                   pose: Pose, weights: dict, m: str) -> tuple[Pose, float]:
        """One Gauss-Newton step for the pose and mode ``m`` (Eq. (8)); updates ``weights[m]``.

        Returns the new pose and the step's rms vertex motion (pixels of the finest level).
        """
        opt = self.opt
        f = 0.5 ** lv
        t1 = _now()
        B = prob.cache.basis(m, weights)                           # Eq. (9), (k, 3, r)
        X = B @ weights[m]
        p = project(X, pose.rotation, pose.scale, pose.translation)
        level = prob.pyr1.levels[lv]
        Z, e, wj = klt_terms_at(level, level_coords(p, lv), wi, self.offsets,
                                self.wwin)                         # Eq. (6), level units
        self._tick("terms", t1)
        t1 = _now()
        rw = robust_weights(wi[..., 0], wj, opt.robust)            # occlusion, mismatch
        if wk is not None:  # the key frame's view of the same vertices
            Zk, ek, wjk = klt_terms_at(level, level_coords(p, lv), wk, self.offsets, self.wwin)
            rk = opt.keyframe * robust_weights(wk[..., 0], wjk, 0.6)
            Z = rw[:, None, None] * Z + rk[:, None, None] * Zk
            e = rw[:, None] * e + rk[:, None] * ek
            rw = np.ones_like(rw)
        # level units -> full-resolution pixels: d_l = f d, so Z f², e f
        Z *= (f * f * rw)[:, None, None]
        e *= (f * rw)[:, None]
        A, b, G = self._flow_system(Z, e, X, B, pose, weights[m], m, prob.anchor, weights,
                                    prob.guess)
        d = _clip_step(solve_step(A, b), pose.scale)
        pose = compose(pose, d[:N_POSE])
        weights[m] = weights[m] + self.priors[m].Q @ d[N_POSE:]
        self._tick("solve", t1)
        # G is the mean JᵀJ: dᵀ G d is the mean squared pixel motion of the step
        return pose, float(np.sqrt(max(d @ G @ d, 0.0)))

    def _finish_pair(self, prob: _PairProblem, sel: np.ndarray, wi: np.ndarray,
                     state: FrameState, accumulate: bool, t0: float) -> PairResult:
        """The pair's confidence and, with ``accumulate``, its identity system, from the final
        windows on the finest level."""
        X = prob.cache.shape(state.weights)
        pose = state.pose
        p = project(X, pose.rotation, pose.scale, pose.translation)
        Z, e, wj = klt_terms_at(prob.pyr1.levels[0], p, wi, self.offsets, self.wwin)
        # confidence: zero-mean normalised cross-correlation of the final windows
        conf = window_confidence(wi[..., 0], wj)
        rw = robust_weights(wi[..., 0], wj, self.opt.robust)
        Z *= rw[:, None, None]
        e *= rw[:, None]
        ident = None
        if accumulate and self.accumulated:
            ident = self._identity_system(Z, e, X, sel, state, prob.anchor)
        self._tick("pair", t0)
        self.counts["points"] = self.counts.get("points", 0) + int(sel.size)
        return PairResult(state, conf, ident, int(sel.size))

    def _flow_system(self, Z, e, X, B, pose, w, mode, anc, weights, guess):
        """Normal equations of one Gauss-Newton step for (pose, mode ``mode``), Eq. (8).

        The flow term is normalised by ``Σ tr(Z) / 2`` (so it is a mean over well-textured
        points in squared pixels), then the temporal damping toward ``guess``, the anchor
        term and the prior are added. Returns ``(A, b, G)``, ``G`` the mean ``JᵀJ``.
        """
        Q = self.priors[mode].Q
        A, b, G = flow_normal_equations(X, B @ Q, pose, Z, e)   # Σ JᵀZJ, Σ Jᵀe, Σ JᵀJ
        G /= X.shape[0]
        norm = max(float(Z[:, 0, 0].sum() + Z[:, 1, 1].sum()) / 2.0, 1e-12)   # Σ tr(Z) / 2
        A /= norm
        b /= norm
        if self.opt.temporal > 0:
            # stay near the prediction in directions the flow leaves undetermined: each
            # parameter costs `temporal` per pixel (rms over the points) it moves the vertices
            D = self.opt.temporal * np.diag(G)
            r = np.concatenate([so3_log(pose.rotation @ guess.pose.rotation.T),
                                [np.log(pose.scale / guess.pose.scale)],
                                pose.translation - guess.pose.translation,
                                Q.T @ (w - guess.weights[mode])])
            A[np.diag_indices_from(A)] += D
            b -= D * r
        if anc is not None:
            Aa, ba = self._anchor_system(anc, pose, mode, weights, Q)
            A += self.opt.anchor_weight * Aa
            b += self.opt.anchor_weight * ba
        if self.opt.prior > 0:
            # squared pixels per unit of Mahalanobis distance, for a face 100 pixels between the
            # outer eye corners (so the balance does not change with the image resolution)
            lam = self.opt.prior * (pose.scale * self.model_iod / 100.0) ** 2
            Ap, bp = prior_terms(w, self.priors[mode], lam)
            A += Ap
            b += bp
        return A, b, G

    def _anchor_system(self, anc, pose, mode, weights, Q):
        v, T, pw = anc
        B = self.model.mode_basis(mode, weights, vertices=v)
        X = B @ weights[mode]
        p = project(X, pose.rotation, pose.scale, pose.translation)
        J = np.concatenate([pose_jacobian(X @ pose.rotation.T, pose.scale),
                            weight_jacobian(B @ Q, pose.rotation, pose.scale)], axis=2)
        Z, e = point_terms(p, T, pw / pw.sum())
        return normal_equations(J, Z, e)

    def _identity_system(self, Z, e, X, sel, state, anc):
        """Identity block of this pair's system, pose eliminated (Schur complement)."""
        m = self.accumulated[0]
        pose, weights = state.pose, state.weights
        Q = self.priors[m].Q
        B = self.model.mode_basis(m, weights, vertices=sel)
        J = np.concatenate([pose_jacobian(X @ pose.rotation.T, pose.scale),
                            weight_jacobian(B @ Q, pose.rotation, pose.scale)], axis=2)
        A, b = normal_equations(J, Z, e)
        norm = max(float(np.trace(Z.sum(0))) / 2.0, 1e-12)
        A /= norm
        b /= norm
        if anc is not None:
            Aa, ba = self._anchor_system(anc, pose, m, weights, Q)
            A += self.opt.anchor_weight * Aa
            b += self.opt.anchor_weight * ba
        return schur_reduce(A, b)

    def landmark_identity_system(self, state: FrameState, landmarks: np.ndarray, weight: float):
        """Identity block of the landmark fit at one frame (initialisation term)."""
        m = self.accumulated[0]
        ok = np.all(np.isfinite(landmarks), axis=1)
        anc = (self.lm_vertices[ok], np.asarray(landmarks, float)[ok], IBUG_WEIGHTS[ok])
        iod = eye_distance(landmarks)
        Q = self.priors[m].Q
        A, b = self._anchor_system(anc, state.pose, m, state.weights, Q)
        # landmark errors in units of the face size: comparable to the normalised flow term
        sc = (50.0 / max(iod, 1.0)) ** 2
        S, c = schur_reduce(A * sc, b * sc)
        return S * weight, c * weight

    def solve_identity(self, systems: list, weights: dict) -> tuple[np.ndarray, float]:
        """Solve the accumulated identity systems once (§5.1); returns (new w, scale factor)."""
        m = self.accumulated[0]
        w = np.asarray(weights[m], float)
        S = sum(s for s, _ in systems)
        c = sum(c for _, c in systems)
        Ap, bp = prior_terms(w, self.priors[m], self.opt.identity_prior * len(systems), 0)
        y = solve_step(S + Ap, c + bp)
        return w + self.priors[m].Q @ y, 1.0

    def _tick(self, name: str, t0: float) -> None:
        """Accumulate wall seconds since ``t0`` (from :func:`_now`) under ``name``."""
        self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0
        self.counts[name] = self.counts.get(name, 0) + 1


def _spread(p: np.ndarray, score: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` of the points (n, 2) spread over them: a grid over their bounding box
    with about ``k`` cells, the best-``score`` (n,) point of each cell first, then the second
    best of each, and so on."""
    lo, hi = p.min(0), p.max(0)
    area = max(float(np.prod(hi - lo)), 1.0)
    cell = max(np.sqrt(area / k) * 1.0, 1.0)
    gx = ((p[:, 0] - lo[0]) / cell).astype(np.int64)
    gy = ((p[:, 1] - lo[1]) / cell).astype(np.int64)
    cid = gy * (gx.max() + 1) + gx
    order = np.lexsort((-score, cid))
    cs = cid[order]
    first = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    rank = np.arange(cs.size) - np.repeat(first, np.diff(np.r_[first, cs.size]))
    # rank within the cell first, then score
    return order[np.lexsort((-score[order], rank))][:k]


def _now() -> float:
    return time.perf_counter()


def _clip_step(d: np.ndarray, scale: float, *, max_rot: float = 0.15, max_log_scale: float = 0.1,
               max_shift: float = 40.0) -> np.ndarray:
    """Trust region of one Gauss-Newton step: rotation (rad), log-scale, translation (pixels)."""
    d = d.copy()
    n = float(np.linalg.norm(d[:3]))
    if n > max_rot:
        d[:3] *= max_rot / n
    d[3] = np.clip(d[3], -max_log_scale, max_log_scale)
    n = float(np.linalg.norm(d[4:6]))
    if n > max_shift:
        d[4:6] *= max_shift / n
    return d

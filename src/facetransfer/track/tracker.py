"""Model-based face tracking through a video (Vlasic et al. 2005, §5.1, §5.2).

For every pair of neighbouring frames ``(t, t+1)`` about a thousand visible, well-textured
vertices are chosen at frame ``t``; their symmetric KLT terms (Eq. (6)) against frame ``t+1`` are
stacked into one system for the pose and one mode's weights (Eq. (7)-(9)) and solved by
Gauss-Newton, coarse to fine over an image pyramid, cycling through the per-frame modes
(coordinate descent). The clip-constant mode (identity) is accumulated over all frame pairs of a
pass and solved once per pass. Several passes run through the video; the first frames are
tracked back and forth first to let the initial alignment "snap" (§5.2).

Beyond the paper (each can be switched off in :class:`TrackOptions`): a second KLT term of the
same vertices against the first tracked frame (``keyframe``: less drift on long clips), optional
landmark anchoring (detector points as an extra weighted term beside the flow term, never
instead of it), per-point robust weights from the windows' correlation, damping toward the
predicted state, zero-phase temporal smoothing (no lag), a per-frame confidence (normalised
cross-correlation of the tracked windows) and recovery when the face is lost
(re-initialisation from the detector; the frames are marked). ``TrackOptions(keyframe=0,
robust=0)`` is the paper's frame-to-frame tracker.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, replace
from typing import Callable, Iterator, Sequence

import cv2
import numpy as np

from ..errors import TrackError, VideoError
from .camera import (N_POSE, Pose, compose, fit_affine_pose, orthonormalize, pose_jacobian,
                     project, so3_log)
from .init import check_init_points, fit_landmarks, points_to_array, require_landmarks
from .klt import (Pyramid, build_pyramid, klt_terms_at, level_coords, sample_windows,
                  window_offsets)
from .landmarks import IBUG_WEIGHTS
from .result import Track
from .solver import (BasisCache, FrameState, Prior, fit_points, flow_normal_equations,
                     normal_equations,
                     point_terms, prior_terms, schur_reduce, solve_step,
                     weight_jacobian)

log = logging.getLogger(__name__)

__all__ = ["TrackOptions", "FaceTracker", "track_video", "smooth_track", "frame_source"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TrackOptions:
    """Settings of :func:`track_video` (defaults defined once here; the CLI uses them).

    Attributes
    ----------
    passes : int
        Passes through the video (§5.1: "several passes").
    levels : int
        Pyramid levels (multi-scale).
    iterations : int
        Gauss-Newton iterations per level (each cycles through the per-frame modes).
    n_points : int
        Tracked vertices per frame pair (about a thousand in the paper).
    half_window : int
        KLT window half-size in pixels of each level (window ``2 h + 1`` square).
    prior : float
        Weight of the training-distribution prior in the per-frame solves (mean squared pixel
        error per unit of Mahalanobis distance, for a face 100 pixels between the outer eye
        corners; scaled with the face size).
    identity_prior : float
        Weight of the prior in the per-pass identity solve.
    init_prior : float
        Prior weight of the landmark fit at initialisation (see :func:`fit_landmarks`).
    init_weight : float
        Weight of the initial landmarks in the identity solve, in frame pairs.
    snap_frames : int
        Frames tracked back and forth to snap the initial alignment (0 = off).
    snap_rounds : int
    anchor : bool
        Add detector landmarks of every frame as an extra term (needs a detector).
    anchor_weight : float
        Weight of the anchor term relative to the flow term.
    robust : float
        Points whose window correlation between the frames is below this get no weight
        (occlusions, the mouth interior, the silhouette); full weight above ``robust + 0.3``.
        0 = off.
    tolerance : float
        A level's iterations stop when a cycle moves the vertices by less than this (rms, in
        pixels of that level).
    keyframe : float
        Weight of a second KLT term against the first tracked frame (on the two finest
        levels; beyond the paper, reduces drift; 0 = off).
    temporal : float
        Damping toward the predicted state (per pixel of rms vertex motion per parameter),
        stabilising directions the flow does not determine.
    smooth : float
        Sigma (frames) of the zero-phase Gaussian smoothing of pose and per-frame weights
        (0 = off).
    lost_threshold : float
        Frames with confidence below this are lost.
    recover : bool
        Re-initialise from the detector when the face is lost.
    visibility_scale : float
        Resolution factor of the visibility raster.
    reselect : int
        Choose the tracked vertices (visibility raster, texture strength, spread) anew every
        ``reselect`` frame pairs; in between the last choice is reused with its points
        re-projected, unless the head turned by more than ``reselect_degrees`` or the scale
        changed by more than 5 % since (1 = every pair, as in the paper).
    reselect_degrees : float
        Head rotation (degrees) since the last choice that forces a new one.
    """

    passes: int = 2
    levels: int = 3
    iterations: int = 3
    n_points: int = 1000
    half_window: int = 4
    prior: float = 0.02
    identity_prior: float = 0.5
    init_prior: float = 1.0
    init_weight: float = 10.0
    snap_frames: int = 8
    snap_rounds: int = 1
    anchor: bool = False
    anchor_weight: float = 0.05
    temporal: float = 0.02
    keyframe: float = 0.5
    tolerance: float = 0.02
    robust: float = 0.4
    smooth: float = 0.0
    lost_threshold: float = 0.3
    recover: bool = True
    visibility_scale: float = 0.25
    reselect: int = 1
    reselect_degrees: float = 3.0

    def __post_init__(self) -> None:
        for name in ("passes", "levels", "iterations", "n_points", "half_window", "reselect"):
            if int(getattr(self, name)) < 1:
                raise TrackError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("prior", "identity_prior", "init_prior", "init_weight", "anchor_weight",
                     "smooth", "snap_frames", "keyframe", "temporal", "robust",
                     "reselect_degrees"):
            if not getattr(self, name) >= 0:
                raise TrackError(f"{name} must be >= 0, got {getattr(self, name)}")


# ------------------------------------------------------------------------------------ frames
class _Frames:
    """Random and sequential access to video frames (a path streams, an array is indexed)."""

    def __init__(self, src, max_frames: int | None = None) -> None:
        self.path = None
        if isinstance(src, np.ndarray) or (isinstance(src, Sequence) and not isinstance(src, str)):
            arr = np.asarray(src)
            if arr.ndim != 4 or arr.shape[-1] != 3 or arr.shape[0] == 0:
                raise VideoError(f"frames must be (F, H, W, 3) RGB with F >= 1, got {arr.shape}")
            if max_frames is not None:
                arr = arr[:max_frames]
            self.array = arr
            self.n = arr.shape[0]
            self.size = (arr.shape[2], arr.shape[1])
            self.fps = 25.0
        else:
            from ..io.video import iter_frames, video_info

            info = video_info(src)
            self.path = str(src)
            self.array = None
            self.fps = info.fps
            self.size = info.size
            # the container's count can be approximate: count by decoding
            n = 0
            for _ in iter_frames(src, stop=max_frames):
                n += 1
            if n == 0:
                raise VideoError(f"video {src} has no frames")
            self.n = n

    def iterate(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        stop = self.n if stop is None else min(stop, self.n)
        if self.array is not None:
            yield from self.array[start:stop]
            return
        from ..io.video import iter_frames

        yield from iter_frames(self.path, start=start, stop=stop)

    def get(self, i: int) -> np.ndarray:
        return next(self.iterate(i, i + 1))


def frame_source(src, max_frames: int | None = None) -> _Frames:
    """Wrap a video path or an ``(F, H, W, 3)`` array for the tracker."""
    return _Frames(src, max_frames)


# ------------------------------------------------------------------------------------ tracker
@dataclass
class _PairResult:
    state: FrameState
    confidence: float
    identity_system: tuple | None
    n_points: int


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
        from ..render import WeakPerspective, vertex_normals, vertex_visibility

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
        m = self.opt.half_window * 2 + 2
        inside = (p[:, 0] > m) & (p[:, 0] < W - 1 - m) & (p[:, 1] > m) & (p[:, 1] < H - 1 - m)
        cand = np.flatnonzero(vis & (N > 0.3) & inside)
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
        # spread: a grid over the face, the best-textured vertices of each cell first
        lo, hi = p[cand].min(0), p[cand].max(0)
        area = max(float(np.prod(hi - lo)), 1.0)
        cell = max(np.sqrt(area / k) * 1.0, 1.0)
        gx = ((p[cand, 0] - lo[0]) / cell).astype(np.int64)
        gy = ((p[cand, 1] - lo[1]) / cell).astype(np.int64)
        cid = gy * (gx.max() + 1) + gx
        order = np.lexsort((-score, cid))
        cs = cid[order]
        first = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
        rank = np.arange(cs.size) - np.repeat(first, np.diff(np.r_[first, cs.size]))
        # rank within the cell first, then score
        order2 = order[np.lexsort((-score[order], rank))]
        chosen = cand[order2[:k]]
        return chosen, p[chosen]

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
        W, H = self.size
        m = opt.half_window * 2 + 2
        inside = (p[:, 0] > m) & (p[:, 0] < W - 1 - m) & (p[:, 1] > m) & (p[:, 1] < H - 1 - m)
        if inside.mean() < 0.9:  # the face is leaving the frame: choose again
            return None, None
        self._selection = (sel, pose, age + 1)
        return sel[inside], p[inside]

    # ------------------------------------------------------------------ one frame pair
    def track_pair(self, pyr0: Pyramid, pyr1: Pyramid, state0: FrameState, guess: FrameState, *,
                   anchor: np.ndarray | None = None, accumulate: bool = False,
                   key: tuple | None = None) -> _PairResult:
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
        opt = self.opt
        t0 = _now()
        sel, q = self._reuse_selection(state0)
        if sel is None:
            sel, q = self.select_vertices(state0, pyr0)
            self._selection = (sel, state0.pose, 0)
            self.counts["selections"] = self.counts.get("selections", 0) + 1
        self._tick("select", t0)
        if sel.size < 10:
            return _PairResult(guess, 0.0, None, int(sel.size))
        cache = self.cache(guess.weights).restrict(sel)    # model rows of the tracked vertices
        pose = guess.pose
        weights = {k: np.asarray(v, float).copy() for k, v in guess.weights.items()}
        anc = None
        if anchor is not None and opt.anchor_weight > 0:
            ok = np.all(np.isfinite(anchor), axis=1)
            if ok.sum() >= 4:
                anc = (self.lm_vertices[ok], np.asarray(anchor, float)[ok], IBUG_WEIGHTS[ok])
        wi = wj = None
        q_key = None
        if key is not None and opt.keyframe > 0:
            kst = key[1]
            Xk = self.cache(kst.weights).restrict(sel).shape(kst.weights)
            q_key = project(Xk, kst.pose.rotation, kst.pose.scale, kst.pose.translation)
        for lv in reversed(range(min(opt.levels, pyr0.n_levels))):
            f = 0.5 ** lv
            t1 = _now()
            wi = sample_windows(pyr0.levels[lv], level_coords(q, lv), self.offsets)
            wk = (sample_windows(key[0].levels[lv], level_coords(q_key, lv), self.offsets)
                  if q_key is not None and lv <= 1 else None)
            self._tick("sample", t1)
            for _ in range(opt.iterations):
                moved = 0.0
                for m in self.per_frame:
                    t1 = _now()
                    B = cache.basis(m, weights)                           # Eq. (9), (k, 3, r)
                    X = B @ weights[m]
                    p = project(X, pose.rotation, pose.scale, pose.translation)
                    Z, e, wj = klt_terms_at(pyr1.levels[lv], level_coords(p, lv), wi,
                                            self.offsets, self.wwin)      # Eq. (6), level units
                    self._tick("terms", t1)
                    t1 = _now()
                    rw = _robust_weights(wi[..., 0], wj, opt.robust)      # occlusion, mismatch
                    if wk is not None:  # the key frame's view of the same vertices
                        Zk, ek, wjk = klt_terms_at(pyr1.levels[lv], level_coords(p, lv), wk,
                                                   self.offsets, self.wwin)
                        rk = opt.keyframe * _robust_weights(wk[..., 0], wjk, 0.6)
                        Z = rw[:, None, None] * Z + rk[:, None, None] * Zk
                        e = rw[:, None] * e + rk[:, None] * ek
                        rw = np.ones_like(rw)
                    # level units -> full-resolution pixels: d_l = f d, so Z f², e f
                    Z *= (f * f * rw)[:, None, None]
                    e *= (f * rw)[:, None]
                    A, b, G = self._flow_system(Z, e, X, B, pose, weights[m], m, anc,
                                                weights, guess)
                    d = _clip_step(solve_step(A, b), pose.scale)
                    pose = compose(pose, d[:N_POSE])
                    weights[m] = weights[m] + self.priors[m].Q @ d[N_POSE:]
                    # G is the mean JᵀJ: dᵀ G d is the mean squared pixel motion of the step
                    moved = max(moved, float(np.sqrt(max(d @ G @ d, 0.0))))
                    self._tick("solve", t1)
                if moved < opt.tolerance / f:  # converged on this level (rms pixel motion)
                    break
        state = FrameState(pose, weights)
        # confidence: zero-mean normalised cross-correlation of the final windows (finest level)
        X = cache.shape(weights)
        p = project(X, pose.rotation, pose.scale, pose.translation)
        Z, e, wj = klt_terms_at(pyr1.levels[0], p, wi, self.offsets, self.wwin)
        conf = _confidence(wi[..., 0], wj)
        rw = _robust_weights(wi[..., 0], wj, opt.robust)
        Z *= rw[:, None, None]
        e *= rw[:, None]
        ident = None
        if accumulate and self.accumulated:
            ident = self._identity_system(Z, e, X, sel, state, anc)
        self._tick("pair", t0)
        self.counts["points"] = self.counts.get("points", 0) + int(sel.size)
        return _PairResult(state, conf, ident, int(sel.size))

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
        iod = _iod(landmarks)
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


def _now() -> float:
    return time.perf_counter()


def _iod(L: np.ndarray) -> float:
    L = np.asarray(L, float)
    if np.all(np.isfinite(L[[36, 45]])):
        return float(np.linalg.norm(L[36] - L[45]))
    ok = np.all(np.isfinite(L), axis=1)
    return float(np.ptp(L[ok], axis=0).max() / 2) if ok.any() else 1.0


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


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Zero-mean normalised cross-correlation of window pairs, (n, m) x (n, m) -> (n,)."""
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    return np.divide((a * b).sum(1), den, out=np.zeros(a.shape[0], np.float64), where=den > 1e-10)


def _robust_weights(a: np.ndarray, b: np.ndarray, level: float) -> np.ndarray:
    """Per-point weights in [0, 1] from the windows' correlation (1 above ``level + 0.3``)."""
    if level <= 0:
        return np.ones(a.shape[0])
    return np.clip((_ncc(a, b) - level) / 0.3, 0.0, 1.0)


def _confidence(a: np.ndarray, b: np.ndarray) -> float:
    """Median zero-mean normalised cross-correlation of window pairs, clipped to [0, 1]."""
    a = a - a.mean(1, keepdims=True)
    b = b - b.mean(1, keepdims=True)
    den = np.sqrt((a * a).sum(1) * (b * b).sum(1))
    ok = den > 1e-10
    if not ok.any():
        return 0.0
    ncc = (a * b).sum(1)[ok] / den[ok]
    return float(np.clip(np.median(ncc), 0.0, 1.0))


def _relative_guess(cur: FrameState, prev_a: FrameState, prev_b: FrameState) -> FrameState:
    """``cur`` moved by the motion ``prev_a -> prev_b`` of an earlier pass."""
    Rd = prev_b.pose.rotation @ prev_a.pose.rotation.T
    pose = Pose(orthonormalize(Rd @ cur.pose.rotation),
                cur.pose.scale * prev_b.pose.scale / prev_a.pose.scale,
                cur.pose.translation + prev_b.pose.translation - prev_a.pose.translation)
    w = {k: cur.weights[k] + (prev_b.weights[k] - prev_a.weights[k]) for k in cur.weights}
    return FrameState(pose, w)


def _velocity_guess(a: FrameState, b: FrameState) -> FrameState:
    """Constant-velocity prediction of the pose after ``b`` (weights held)."""
    Rd = b.pose.rotation @ a.pose.rotation.T
    pose = Pose(orthonormalize(Rd @ b.pose.rotation), b.pose.scale * b.pose.scale / a.pose.scale,
                2 * b.pose.translation - a.pose.translation)
    return FrameState(pose, b.weights)


# ------------------------------------------------------------------------------------ driver
def track_video(video, model, *, init="auto", options: TrackOptions | None = None,
                detector=None, max_frames: int | None = None, fixed: dict | None = None,
                progress: Progress | None = None, source: str | None = None,
                checkpoint: str | os.PathLike | None = None,
                checkpoint_every: float = 20.0) -> Track:
    """Track a face through a video with a multilinear model (Vlasic et al. 2005, §5).

    Parameters
    ----------
    video : path-like or (F, H, W, 3) uint8 array
    model : MultilinearModel
        Must have 68 landmark vertices.
    init : "auto", dict {ibug: (x, y)}, (68, 2) array (NaN = unknown), or path to POINTS.json
        First-frame feature points (§5.2); ``"auto"`` detects them (needs ``detector`` or
        MediaPipe from the asset registry).
    options : TrackOptions
    detector : object with ``detect(frame) -> (68, 2) | None``, optional
        Used for ``init="auto"``, anchoring and recovery. Created (MediaPipe) when
        ``init="auto"`` or anchoring needs one; otherwise, without a detector, lost frames stay
        lost (pass :class:`~facetransfer.track.init.LazyDetector` to recover on demand).
    max_frames : int, optional
    fixed : dict mode name -> (r,) weights, optional
        Modes whose weights are known (e.g. the identity from another track): held constant.
    progress : callable(stage, done, total), optional
    source : str, optional
        Recorded in the track (default: the video path).
    checkpoint : path-like, optional
        Progress file: the run saves what it has finished there every ``checkpoint_every``
        seconds and when interrupted, and a later call with the same video, model, options and
        initial points continues from it (:mod:`facetransfer.track.checkpoint`). Removed when
        the track is complete. A file of another run is ignored (and replaced).
    checkpoint_every : float
        Seconds between periodic saves (0 = after every frame).

    Returns
    -------
    Track

    Raises
    ------
    VideoError
        Unreadable/empty video; no face found (``init="auto"``).
    TrackError
        Bad init points, a model without landmarks.
    """
    opt = options or TrackOptions()
    require_landmarks(model)
    frames = frame_source(video, max_frames)
    src = source if source is not None else (frames.path or "")
    auto = isinstance(init, str) and init == "auto"
    if not auto:  # read and validated once (a file, a dict or an array of points)
        init = _init_array(init, frames.size)
    own_detector = None
    if detector is None and (auto or opt.anchor):
        from .init import MediaPipeDetector

        detector = own_detector = MediaPipeDetector()
    ck = None
    if checkpoint is not None:
        from .checkpoint import Checkpoint, checkpoint_key, video_identity

        vid = video_identity(frames.path) if frames.path else video_identity(
            None, frames.array[0], frames.array[-1])
        ck = Checkpoint(checkpoint, checkpoint_key(vid, frames.n, model.content_hash, opt, init,
                                                   fixed), model.mode_names,
                        every=checkpoint_every)
    try:
        track = _run(frames, model, init, opt, detector, progress, src, fixed, ck)
        if ck is not None:
            ck.remove()
        return track
    finally:
        if own_detector is not None:
            own_detector.close()


def _init_array(init, size) -> np.ndarray:
    """User initial points (POINTS.json path, dict or (68, 2) array) as a validated (68, 2)
    array in pixels, NaN where not given."""
    from .init import load_init_points

    if isinstance(init, str) or hasattr(init, "__fspath__"):
        return points_to_array(load_init_points(init, size))
    if isinstance(init, dict):
        return points_to_array(check_init_points(init, size))
    arr = np.asarray(init, dtype=np.float64)
    if arr.shape != (68, 2):
        raise TrackError(f"init landmarks must be (68, 2), got {arr.shape}")
    return points_to_array(check_init_points({i: arr[i] for i in range(68)
                                              if np.all(np.isfinite(arr[i]))}, size))


def _run(frames: _Frames, model, init, opt: TrackOptions, detector, progress, src,
         fixed: dict | None = None, checkpoint=None) -> Track:
    F = frames.n
    W, H = frames.size
    fixed = _check_fixed(model, fixed)
    tr = FaceTracker(model, (W, H), opt, detector=detector, fixed=tuple(fixed))
    prog = progress or (lambda stage, done, total: None)
    t_start = time.perf_counter()

    # -------- §5.2 initialisation: feature points of the first frame with a face
    detections: dict[int, np.ndarray | None] = {}

    def detect(i, frame=None):
        if i not in detections:
            if detector is None:
                detections[i] = None
            else:
                detections[i] = detector.detect(frames.get(i) if frame is None else frame)
        return detections[i]

    resume = checkpoint.load() if checkpoint is not None else None
    if resume is None:
        start = 0
        if isinstance(init, str) and init == "auto":
            if detector is None:
                raise TrackError("automatic initialisation needs a face detector")
            L0 = None
            for i, fr in enumerate(frames.iterate()):
                L0 = detect(i, fr)
                if L0 is not None:
                    start = i
                    break
            if L0 is None:
                raise VideoError(f"no face found in {src or 'the video'} (searched frames 0-{F - 1})")
        else:
            L0 = _init_array(init, (W, H))
        if start > 0:
            log.info("first face found at frame %d", start)
        start_state = None
        if fixed:
            w = {m: tr.priors[m].mean.copy() for m in model.mode_names}
            w.update(fixed)
            ok = np.all(np.isfinite(L0), axis=1)
            X = model.synthesize(w, vertices=tr.lm_vertices[ok])
            start_state = FrameState(fit_affine_pose(X, L0[ok]), w)
        state0 = fit_landmarks(model, L0, prior=opt.init_prior, state=start_state,
                               modes=tuple(m for m in model.mode_names if m not in fixed))
    else:  # an interrupted run of the same video, model and options
        start, L0, state0 = resume.start, np.asarray(resume.L0), resume.state0
        log.info("resuming from %s: pass %d, frame %d", checkpoint.path,
                 resume.pass_index + 1, resume.next_frame)
    t_init = time.perf_counter() - t_start

    states: list[FrameState | None] = [None] * F
    conf = np.zeros(F)
    lost = np.zeros(F, bool)
    lost[:start] = True
    reinit: list[int] = []
    id_name = tr.accumulated[0] if tr.accumulated else None

    def anchor_for(i, frame):
        if not opt.anchor:
            return None
        return detect(i, frame)

    def apply_identity(systems, ref_idx):
        """Solve identity; re-express the reference frame's 2-D vertex positions with it."""
        nonlocal state0
        if not systems or id_name is None:
            return
        w_new, fac = tr.solve_identity(systems, state0.weights)
        st = state0
        # targets: the current 2-D positions of many vertices at the start frame
        pyr = tr.pyramid(frames.get(ref_idx))
        sel, p = tr.select_vertices(st, pyr)
        if sel.size < 10:
            sel = tr.lm_vertices
            p = project(model.synthesize(st.weights, vertices=sel), st.pose.rotation,
                        st.pose.scale, st.pose.translation)
        w = dict(st.weights)
        w[id_name] = w_new
        start_st = FrameState(Pose(st.pose.rotation, st.pose.scale * fac, st.pose.translation), w)
        state0 = fit_points(model, sel, p, state=start_st, modes=tr.per_frame, prior=0.0,
                            iterations=5)

    # -------- §5.2 snap: track the first frames back and forth
    n_snap = min(int(opt.snap_frames), F - start - 1)
    if n_snap > 0 and resume is None:
        snap_frames = list(frames.iterate(start, start + n_snap + 1))
        pyrs = [tr.pyramid(f) for f in snap_frames]
        for rnd in range(int(opt.snap_rounds)):
            systems = []
            if id_name is not None:
                systems.append(tr.landmark_identity_system(state0, L0, opt.init_weight))
            st = state0
            order = list(range(1, n_snap + 1)) + list(range(n_snap - 1, -1, -1))
            cur = 0
            for j, nxt in enumerate(order):
                res = tr.track_pair(pyrs[cur], pyrs[nxt], st, st,
                                    anchor=anchor_for(start + nxt, snap_frames[nxt]),
                                    accumulate=id_name is not None)
                st = res.state
                if res.identity_system is not None:
                    systems.append(res.identity_system)
                cur = nxt
                prog("snap", rnd * len(order) + j + 1, len(order) * int(opt.snap_rounds))
            # the state reached back at the first frame is the snapped alignment
            state0 = st
            apply_identity(systems, start)

    def save(pass_index, next_frame, systems_, reinit_, prev_):
        checkpoint.save(start=start, L0=L0, state0=state0, pass_index=pass_index,
                        next_frame=next_frame, states=states, prev=prev_, conf=conf, lost=lost,
                        reinit=reinit_, systems=systems_)

    # -------- §5.1 passes
    prev: list[FrameState | None] | None = None
    first_pass = 0
    if resume is not None:
        first_pass, prev = resume.pass_index, resume.prev
        conf[:], lost[:] = resume.conf, resume.lost
        if first_pass >= int(opt.passes):  # every pass was done: only the assembly is left
            states[:] = prev
    elif checkpoint is not None:
        save(0, start + 1, [], [], None)
    for ps in range(first_pass, int(opt.passes)):
        last = ps == int(opt.passes) - 1
        if resume is not None and ps == resume.pass_index and resume.next_frame > start + 1:
            # continue the interrupted pass where it stopped
            systems, reinit = list(resume.systems), list(resume.reinit)
            base = prev if prev is not None else [None] * F
            states[:] = [r if r is not None else b for r, b in zip(resume.states, base)]
            i_next = resume.next_frame
            key = (tr.pyramid(frames.get(start)), state0)
            pyr0 = tr.pyramid(frames.get(i_next - 1))
            it = frames.iterate(i_next)
        else:
            systems = []
            reinit = []
            lost[start + 1:] = False
            if id_name is not None:
                systems.append(tr.landmark_identity_system(state0, L0, opt.init_weight)
                               if not lost[start] else None)
                systems = [s for s in systems if s is not None]
            states[start] = state0
            it = frames.iterate(start)
            first = next(it)
            pyr0 = tr.pyramid(first)
            key = (pyr0, state0)
            conf[start] = 1.0
            i_next = start + 1
        done = i_next  # the next frame to solve
        try:
            for i, fr in enumerate(it, start=i_next):
                pyr1 = tr.pyramid(fr)
                st_prev = states[i - 1]
                if prev is not None and prev[i] is not None and prev[i - 1] is not None:
                    guess = _relative_guess(st_prev, prev[i - 1], prev[i])
                elif (i - 2 >= start and not lost[i - 1] and not lost[i - 2]
                      and (i - 1) not in reinit):
                    guess = _velocity_guess(states[i - 2], st_prev)
                else:
                    guess = st_prev
                res = tr.track_pair(pyr0, pyr1, st_prev, guess, anchor=anchor_for(i, fr),
                                    accumulate=(id_name is not None and not last), key=key)
                st, c = res.state, res.confidence
                # once lost, frames stay lost until a re-initialisation (the flow may lock onto
                # the background with high confidence)
                is_lost = (c < opt.lost_threshold or not _face_in_image(model, tr, st, (W, H))
                           or bool(lost[i - 1]))
                if is_lost and opt.recover and detector is not None:
                    L = detect(i, fr)
                    if L is not None:
                        try:
                            st = fit_landmarks(model, L, state=st_prev, modes=tr.per_frame,
                                               prior=opt.init_prior)
                            reinit.append(i)
                            is_lost = False
                            c = max(c, opt.lost_threshold)
                        except TrackError:
                            log.debug("re-initialisation failed at frame %d", i)
                if is_lost and not _face_in_image(model, tr, st, (W, H)):
                    st = st_prev
                states[i] = st
                conf[i] = 0.0 if is_lost else c
                lost[i] = is_lost
                if res.identity_system is not None and not is_lost:
                    systems.append(res.identity_system)
                pyr0 = pyr1
                done = i + 1
                if checkpoint is not None and checkpoint.due():
                    save(ps, done, systems, reinit, prev)
                prog(f"pass {ps + 1}/{opt.passes}", i - start, F - 1 - start)
        except BaseException:
            if checkpoint is not None and done > i_next:  # keep what this pass finished
                save(ps, done, systems, reinit, prev)
            raise
        if not last and id_name is not None and len(systems) > 0:
            apply_identity(systems, start)
        prev = list(states)
        if checkpoint is not None:
            save(ps + 1, start + 1, [], reinit, prev)

    # frames before the first face hold the first tracked state
    for i in range(start):
        states[i] = states[start]
    t_track = time.perf_counter() - t_start
    track = _assemble(model, states, conf, lost, frames.fps, (W, H), src, opt)
    info = {"start_frame": start, "reinitialised": reinit, "timings": dict(tr.timings),
            "resumed": None if resume is None else {"pass": resume.pass_index + 1,
                                                    "frame": resume.next_frame},
            "counts": dict(tr.counts),
            "mean_points": tr.counts.get("points", 0) / max(tr.counts.get("pair", 0), 1),
            "seconds_init": t_init, "seconds_total": t_track, "n_frames": F}
    return replace(track, info=info)


def _check_fixed(model, fixed) -> dict:
    out = {}
    for name, w in (fixed or {}).items():
        k = model.mode_index(name)
        a = np.asarray(w, dtype=np.float64).ravel()
        if a.shape != (model.ranks[k],) or not np.all(np.isfinite(a)):
            raise TrackError(f"fixed weights of mode {name!r} must be {model.ranks[k]} finite "
                             f"numbers, got shape {np.shape(w)}")
        out[model.mode_names[k]] = a
    if len(out) == model.n_modes:
        raise TrackError("every mode is fixed: nothing left to track but the pose")
    return out


def _face_in_image(model, tr: FaceTracker, st: FrameState, size) -> bool:
    p = project(model.synthesize(st.weights, vertices=tr.lm_vertices), st.pose.rotation,
                st.pose.scale, st.pose.translation)
    c = p.mean(0)
    W, H = size
    span = np.ptp(p, axis=0).max()
    return bool(0 <= c[0] < W and 0 <= c[1] < H and 2.0 < span < 4 * max(W, H))


def smooth_track(rotation: np.ndarray, scale: np.ndarray, translation: np.ndarray,
                 weights: dict, sigma: float, *, constant: Sequence[str] = ()
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Zero-phase Gaussian smoothing of pose and per-frame weights (no lag).

    Rotations are smoothed as sign-aligned quaternions and renormalised; the scale in log space.

    Returns
    -------
    rotation (F, 3, 3), scale (F,), translation (F, 2), weights dict
    """
    from scipy.ndimage import gaussian_filter1d
    from scipy.spatial.transform import Rotation

    if sigma <= 0 or rotation.shape[0] < 3:
        return rotation, scale, translation, weights
    g = lambda a: gaussian_filter1d(a, sigma, axis=0, mode="nearest")  # noqa: E731
    q = Rotation.from_matrix(rotation).as_quat()
    for i in range(1, q.shape[0]):
        if q[i] @ q[i - 1] < 0:
            q[i] = -q[i]
    q = g(q)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = Rotation.from_quat(q).as_matrix()
    s = np.exp(g(np.log(scale)))
    t = g(translation)
    w = {k: (v if k in constant else g(v)) for k, v in weights.items()}
    return R, s, t, w


def _assemble(model, states, conf, lost, fps, size, src, opt: TrackOptions) -> Track:
    F = len(states)
    R = np.stack([s.pose.rotation for s in states])
    s = np.array([s_.pose.scale for s_ in states])
    t = np.stack([s_.pose.translation for s_ in states])
    w = {m: np.stack([np.asarray(s_.weights[m], float) for s_ in states])
         for m in model.mode_names}
    const = [m for m in model.mode_names if m == "identity"]
    for m in const:  # the final identity on every frame (re-expressed frames share it)
        w[m] = np.tile(w[m][-1], (F, 1))
    if opt.smooth > 0:
        R, s, t, w = smooth_track(R, s, t, w, opt.smooth, constant=const)
    X = model.synthesize(w, vertices=model.landmarks)                # (F, 68, 3)
    Y = np.einsum("fij,fnj->fni", R[:, :2], X) * s[:, None, None]
    Y[..., 1] *= -1
    L = Y + t[:, None, :]
    return Track(fps=fps, frame_size=size, rotation=R, scale=s, translation=t, weights=w,
                 landmarks2d=L, confidence=np.clip(conf, 0, 1), lost=lost,
                 model_hash=model.content_hash, mode_names=tuple(model.mode_names), source=src)

"""Performance capture: the model fitted to a whole clip's detections and point flow (§5, beyond).

The paper tracks with model-based optical flow from a first frame initialised by hand (§5.1,
§5.2); :mod:`facetransfer.track.tracker` implements that. This tracker keeps the paper's model and
its clip-constant identity accumulated over the clip (§5.1), and replaces the hand-made first
frame and the drifting flow by measurements taken on every frame:

1. **Detections** (:mod:`facetransfer.track.detect`): MediaPipe's landmarks as iBUG-68 points on
   every frame, and the Lucas-Kanade flow of those points between neighbouring frames.
2. **Identity from the whole clip**: ``identity_frames`` frames spread through the clip are fitted
   jointly: per frame, pose and expression; over all of them, one identity (Eq. (9) with the
   identity mode free, a Gaussian prior of the training identities); a few rounds.
3. **Tracking both ways** from the frame the model explains best: per frame, the weak-perspective
   pose (Eq. (7)) and the expression, fitted to the frame's detections (a robust term, per-point
   reliability) and to the previous frame's fit moved by the point flow (the flow term), with a
   temporal term toward the previous frame. For a model whose expressions are ARKit blendshapes
   (:mod:`facetransfer.arkit`) the expression is solved as activations in [0, 1] (a bounded
   least-squares step); for other models as the mode weights with their training prior. The
   eyeLook* activations follow MediaPipe's iris centres at the fitted pose
   (:mod:`facetransfer.track.gaze`): the model has no eyeballs.
4. **A second pass** (:mod:`facetransfer.track.scores`), for an ARKit model: MediaPipe's own
   blendshape scores of the jaw, the lips' funnel and pucker and the blinks, mapped per clip
   onto the first pass's activations, pull every frame's activations in a second run. In the
   pass whose activations are kept (the only one without scores), mouthFunnel is held toward 0
   where the detected lips are shut (:func:`funnel_ridges`, ``CaptureOptions.funnel_gate``).
5. Frames without a detection are lost (the nearest tracked state is held); the face may appear
   late: tracking starts where it is.
6. The track's pose has the head's pitch the detector shows too small restored
   (``CaptureOptions.pitch_gain``, :func:`restore_pitch`); its landmarks are the fitted points
   at that pose, and it keeps the detections it was fitted to (``Track.detections2d``: their
   difference at the lips is what :mod:`facetransfer.lips` carries into a transfer).

One frame's fit (its state, its points' weights and targets, pose and expression
alternated) is :mod:`facetransfer.track.capture_frame`; the model at the tracked points, and
one frame's solve at a fixed pose, are :mod:`facetransfer.track.capture_points`; the small
solvers are :mod:`facetransfer.track.fit2d`.

An interrupted fit resumes (:mod:`facetransfer.track.fit_checkpoint`): with a ``checkpoint``,
:func:`capture_detections` saves the identity phase and the frames fitted so far every few
seconds and when interrupted, and continues from there, exactly, when run again.

References
----------
Vlasic et al. 2005, §5.1 (Eq. (7)-(9), identity over the clip); MediaPipe Face Landmarker;
Lucas & Kanade 1981 (OpenCV's pyramidal implementation).

:func:`~facetransfer.track.video_detect.detect_video` (the detections of step 1) is
:mod:`.video_detect`'s, importable from here too.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from ..arkit import ARKIT_NAMES, is_arkit_model
from ..errors import TrackError, VideoError, plain_interrupts
from ..io.frame_numbers import first_number, frame_span
from .aspect import stored_pixels
from .camera import Pose
from . import capture_points
from .capture_frame import (FrameState, PointWeights, detection_targets, fit_frame, iris_of,
                            lips_gap, lips_gate, sin_yaw)
from .capture_points import Sampler, Shape
from .detect import ClipDetections
from .fit_checkpoint import SavedFit, fit_key
from .fit2d import (Targets, box_qp, gram_blocks, pose_gauss_newton, project_basis, rig_solve,
                    targets_normal)
from .gaze import IRIS_INDEX, frame_gaze_activations, usable_iris
from .init import require_landmarks
from .landmarks import IBUG_WEIGHTS, eye_distance
from .lip_contact import contact_qp
from .options import Progress
from .project import nearest_tracked
from .result import Track
from .scores import ScoreLine, fit_score_lines, score_targets
from .shots import joined_shots, shot_detections, shot_spans, shot_starts
from .smooth import smooth_track
from .solver import Prior
from .video_detect import _open, detect_video

log = logging.getLogger(__name__)

__all__ = ["CaptureOptions", "capture_video", "capture_detections", "detect_video",
           "load_kernels", "prepare_points"]

#: iBUG points of well-defined corners (outer and inner eye corners, nose tip, mouth corners):
#: any detector places them most consistently, so they weigh :data:`CORNER_WEIGHT` times more.
CORNERS = (36, 39, 42, 45, 30, 48, 54)
CORNER_WEIGHT = 3.0
#: iBUG points of the inner lips (60-67): the only measurement of the lips' contact, which the
#: outer-lip and the dense lip points hardly constrain. Weighed like them, combinations of the
#: lip shapes (rolls, presses, shrugs, pucker, jawOpen) wandered the inner-lip gap of a shut
#: mouth with the outer contour held, the lips passing through each other
#: (``benchmarks/bench_shut_mouth.py``, ``driving_d9``'s 527 shut frames: gap std 3.5 times the
#: reference's, on the fitted face 1.0 mm, down to -0.9 mm), so they weigh
#: :data:`INNER_LIP_WEIGHT` times more in the detection term (§5.1, Eq. (9)): 2.8 times, 0.8
#: mm, -0.6 mm (``bench_capture.py``: the real clips' mouth std ratio 0.82 -> 0.85, jawOpen's
#: 1.29 -> 1.25, the synthetic 7-point NME within ±0.02 points; 5 failed a synthetic test of
#: the clip's offset, 10 cost the synthetic jawOpen a tenth of its amplitude).
INNER_LIPS = tuple(range(60, 68))
INNER_LIP_WEIGHT = 3.0


#: Face Landmarker's head pitch over the true one, as the capture fit reads it
#: (``benchmarks/calibrate_pitch.py``, 16 calibration clips disjoint from the benchmark's: a
#: rigid fit of the true faces to the detector's points has a median slope of 0.84 against the
#: same fit to the true points, the capture's pitch 0.82 against its pitch on the true points;
#: this gain gives the smallest sum of the 7- and 51-point NME there, flat over 0.88-0.92).
DETECTOR_PITCH_GAIN = 0.92
#: The confidence of a frame the detector was not shown (its measurements interpolated,
#: :attr:`~facetransfer.track.detect.ClipDetections.shown`), times the fit's own: a texture's
#: reference frame (:func:`facetransfer.eyes.reference_frame`) is then one the detector saw.
UNSEEN_CONFIDENCE = 0.5


def capture_point_weights(inner_lips: float | None = None) -> np.ndarray:
    """The default reliability of the 68 iBUG points in the capture fit, (68,): the
    :data:`~facetransfer.track.landmarks.IBUG_WEIGHTS` with :data:`CORNERS` weighted up
    (``bench_capture.py``: 7-point NME 0 to -0.25 points on the synthetic clips, the real
    clips' correlations unchanged) and :data:`INNER_LIPS` by ``inner_lips`` (default
    :data:`INNER_LIP_WEIGHT`; 1: the rigid pivot of :func:`restore_pitch`, as calibrated)."""
    w = np.array(IBUG_WEIGHTS, float)
    w[list(CORNERS)] *= CORNER_WEIGHT
    w[list(INNER_LIPS)] *= INNER_LIP_WEIGHT if inner_lips is None else float(inner_lips)
    return w


@dataclass(frozen=True)
class CaptureOptions:
    """Settings of :func:`capture_video` (the defaults were chosen by ``benchmarks/bench_capture.py``).

    Attributes
    ----------
    identity_frames : int
        Frames spread through the clip for the joint identity fit.
    identity_rounds : int
        Alternations of per-frame fits and the identity solve.
    identity_prior : float
        Weight of the identity's training prior (per frame, per unit Mahalanobis distance).
    expression_prior : float
        Ridge on the activations (ARKit models) or weight of the expression prior (others).
    sparsity : float
        L1 weight on the activations (ARKit models: they are >= 0, so a linear term), which
        keeps shapes the 2-D points cannot tell apart switched off.
    temporal : float
        Weight pulling a frame's expression toward the previous frame's (for an ARKit model:
        the eyelid shapes', which blinks move within 2-3 frames).
    slow_temporal : float
        The same for every other ARKit shape (jaw, mouth, brows, cheeks: slower than a blink,
        and noisier in 2-D points); not used for other models.
    flow : float
        Weight of the flow term relative to the detection term (0 = detections only).
    iterations : int
        Pose/expression alternations per frame.
    smooth : float
        Sigma (frames) of a zero-phase smoothing of pose and expression afterwards (0 = off).
    point_weights : tuple of 68 float or None
        Reliability of each iBUG point (default :func:`capture_point_weights`).
    offset_prior : float
        Ridge of the clip's static offset: a 3-D displacement of every tracked point, constant
        over the clip, fitted with the identity. It takes up how this face (and where the
        detector puts its points on it) differs from everything the model's identity space
        can show, which would otherwise be explained by expressions held on all clip long.
        ``inf`` = off.
    identity_expression_prior : float
        Ridge on the activations while the identity and offset are fitted (stronger than
        ``expression_prior``: the clip's average face goes to identity and offset, not to
        expressions).
    dense : float
        Weight of MediaPipe's other mesh points (:mod:`facetransfer.track.dense`) relative to an
        iBUG point of weight 1 (0 = the 68 iBUG points only).
    gaze : bool
        For an ARKit model with MediaPipe's iris points: the eyeLook* activations follow the
        iris centres at each pose step of the fit (:mod:`facetransfer.track.gaze`), and the
        other shapes explain the lids given that gaze; a closing eye's gaze is bridged
        (:func:`~facetransfer.track.gaze.usable_iris`) and its lids are left to the blink
        (its vertical gaze is 0 in the fit, the bridged value after); frames without iris
        points fit eyeLook* from the lids as before.
    scores : float
        For an ARKit model with the detector's blendshape scores: weight of the second pass's
        ridge pulling each frame's activations of
        :data:`~facetransfer.track.scores.SCORED_SHAPES` toward the scores mapped onto the
        first pass (:mod:`facetransfer.track.scores`); 0 = one pass, points only.
    view_offset_prior : float
        Ridge of the offset's view-dependent part: a second 3-D field of the tracked points,
        times the sine of the head's yaw, fitted with the static one (the detector places its
        points on a face turned one way otherwise than on one turned the other way); the same
        ridge as ``offset_prior`` by default. ``inf`` = off (or with the offset off).
    pitch_gain : float
        The detector's head pitch over the head's (:data:`DETECTOR_PITCH_GAIN`): Face
        Landmarker's points show a head nodding up or down as one nodding less, and the fit,
        which follows them, inherits that; the track's pose has its pitch divided by this
        (:func:`restore_pitch`; the fit itself is unchanged). 1 = off (exact points).
    lip_contact : bool
        For an ARKit model: the model's upper inner lip is kept from passing below the lower
        one (:mod:`facetransfer.track.lip_contact`: the inner-lip gaps, linear in the
        activations, held >= 0, or at the neutral face's own gap where that is below 0, in
        each expression step where the box solution crosses them).
    funnel_gate : float
        For an ARKit model: an extra ridge on mouthFunnel, in units of ``expression_prior``,
        in the frames whose detected lips are shut (their gap at or below
        :data:`~facetransfer.track.capture_frame.LIPS_SHUT` of the eye-corner distance), ramped
        to 0 as they part (at :data:`~facetransfer.track.capture_frame.LIPS_APART`), in the
        pass whose activations are kept (the second when there is one: the first's funnel
        scales the detector's score line). ARKit's funnel rounds lips that are open; shut
        lips pushed out are a pucker. 0 = off.
    """

    identity_frames: int = 24
    identity_rounds: int = 4
    identity_prior: float = 2e-3
    expression_prior: float = 1e-2
    sparsity: float = 0.0
    temporal: float = 2e-3
    slow_temporal: float = 2e-2
    flow: float = 0.5
    iterations: int = 2
    smooth: float = 0.0
    point_weights: tuple | None = None
    offset_prior: float = 1e-4
    identity_expression_prior: float = 3e-2
    dense: float = 0.3
    gaze: bool = True
    scores: float = 1.0
    view_offset_prior: float = 1e-4
    pitch_gain: float = DETECTOR_PITCH_GAIN
    lip_contact: bool = True
    funnel_gate: float = 100.0

    def __post_init__(self) -> None:
        for name in ("identity_frames", "identity_rounds", "iterations"):
            if int(getattr(self, name)) < 1:
                raise TrackError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("identity_prior", "expression_prior", "sparsity", "temporal", "slow_temporal", "flow",
                     "smooth", "dense", "offset_prior", "identity_expression_prior", "scores",
                     "view_offset_prior", "funnel_gate"):
            if not float(getattr(self, name)) >= 0:
                raise TrackError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.5 <= float(self.pitch_gain) <= 2.0:
            raise TrackError(f"pitch_gain must be in [0.5, 2], got {self.pitch_gain}")
        if self.point_weights is not None and len(self.point_weights) != 68:
            raise TrackError(f"point_weights must have 68 entries, got {len(self.point_weights)}")


def _solve_identity(model, shape: Shape, frames: list, states: list, det: ClipDetections,
                    weights: np.ndarray, opt: CaptureOptions) -> np.ndarray:
    """One identity for the sampled frames (Eq. (9), identity mode free, training prior)."""
    prior = Prior.from_model(model, "identity")
    r = prior.mean.size
    G = np.zeros((r, r))
    h = np.zeros(r)
    bases = shape.identity_bases(np.stack([st.x for st in states]), prior.mean)  # (F, r, P, 3)
    for i, st, B in zip(frames, states, bases):
        p, w = detection_targets(det, i, weights)
        Y = project_basis(B, st.pose)                                        # (r, P, 2)
        g_, h_ = targets_normal(Y, st.pose.project(shape.offset_at(sin_yaw(st.pose))),
                                [(p, w)], eye_distance(p))
        G += g_
        h += h_
    P = prior.Q @ prior.inv_cov @ prior.Q.T
    lam = opt.identity_prior * len(frames)
    return np.linalg.solve(G + lam * P + 1e-9 * np.eye(r), h + lam * P @ prior.mean)


def _solve_offset(shape: "Shape", frames, states: list, det: ClipDetections, weights,
                  opt: CaptureOptions) -> tuple[np.ndarray, np.ndarray | None]:
    """The clip's offset of the tracked points: its static part ``o`` (P, 3) and, unless
    ``opt.view_offset_prior`` is infinite, its view-dependent part ``v`` (P, 3) (else None).

    Per point, ``min Σ_f w |r_f - s_f F R_f[:2] (o + sin(b_f) v)|² + λ |o|² + λ_v |v|²`` over
    the sampled frames (``b_f`` their yaw), residuals ``r_f`` of the fit without the offset (in
    eye distances)."""
    P = shape.offset.shape[0]
    k = 6 if np.isfinite(opt.view_offset_prior) else 3
    A = np.zeros((P, k, k))
    b = np.zeros((P, k))
    for i, st in zip(frames, states):
        p, w = detection_targets(det, i, weights)
        iod = eye_distance(det.points[i])
        q = st.pose.project(shape.points(st.x) - shape.offset)
        r = np.nan_to_num(p - q) / iod
        M = st.pose.scale / iod * st.pose.rotation[:2].copy()               # (2, 3)
        M[1] *= -1.0
        if k == 6:
            M = np.concatenate([M, sin_yaw(st.pose) * M], axis=1)            # (2, 6)
        A += w[:, None, None] * (M.T @ M)[None]
        b += w[:, None] * (r @ M)
    ridge = np.repeat([opt.offset_prior, opt.view_offset_prior], 3)[:k] * len(frames)
    u = np.linalg.solve(A + np.diag(ridge)[None], b[..., None])[..., 0]
    return u[:, :3], (u[:, 3:] if k == 6 else None)


def _sample_frames(found: np.ndarray, n: int) -> np.ndarray:
    idx = np.flatnonzero(found)
    if len(idx) <= n:
        return idx
    return idx[np.unique(np.linspace(0, len(idx) - 1, n).round().astype(int))]


def _clip_identity(model, det: ClipDetections, lm: Sampler, weights, opt: CaptureOptions,
                   fixed, prog) -> tuple[Shape, list, np.ndarray]:
    """Identity from frames spread through the clip; returns the shape, sample states, frames."""
    frames = _sample_frames(det.found, int(opt.identity_frames))
    has_id = "identity" in model.mode_names
    ident = None
    if has_id:
        ident = (np.asarray(fixed["identity"], float) if "identity" in fixed
                 else Prior.from_model(model, "identity").mean)
    shape = Shape(model, ident, lm, opt)
    solve_id = has_id and "identity" not in fixed
    use_offset = np.isfinite(opt.offset_prior)
    rounds = int(opt.identity_rounds) if solve_id else 0
    opt_id = replace(opt, expression_prior=opt.identity_expression_prior)
    states = _fit_sample(shape, det, frames, weights, opt_id, None)
    for rnd in range(rounds):  # identity first: it takes all it can explain
        ident = _solve_identity(model, shape, list(frames), states, det, weights, opt)
        shape = Shape(model, ident, lm, opt)
        states = _fit_sample(shape, det, frames, weights, opt_id, states)
        prog("identity", rnd + 1, rounds + 2 * use_offset)
    for rnd in range(2 if use_offset else 0):  # then the offset: what no identity shows
        shape = Shape(model, ident, lm, opt,
                      *_solve_offset(shape, frames, states, det, weights, opt))
        states = _fit_sample(shape, det, frames, weights, opt_id, states)
        prog("identity", rounds + rnd + 1, rounds + 2)
    states = _fit_sample(shape, det, frames, weights, opt, states)
    return shape, states, frames


def _fit_sample(shape: Shape, det: ClipDetections, frames, weights, opt, states) -> list:
    """Fit every sampled frame on its own (pose and expression), warm-started from ``states``."""
    shape = shape.with_options(opt)
    out = []
    for j, i in enumerate(frames):
        p, w = detection_targets(det, i, weights)
        st = None if states is None else states[j]
        out.append(fit_frame(shape, Targets.stack([(p, w)], weights.w), eye_distance(p),
                              None if st is None else st.pose,
                              shape.x0 if st is None else st.x, None, int(opt.iterations) + 1,
                              iris_of(weights, i)))
    return out


def _targets(det: ClipDetections, i: int, j: int, prev_q: np.ndarray | None, weights, opt,
             forward: bool) -> Targets:
    """Detection term of frame ``i`` and, from its tracked neighbour ``j``, the flow term."""
    p, w = detection_targets(det, i, weights)
    if opt.flow > 0 and prev_q is not None:
        q = prev_q[:68] + (det.flow[i] if forward else -det.flow[j])  # flow[t]: t-1 into t
        ok = np.isfinite(q).all(1)
        if ok.any():
            P = len(p)
            pt, wt = np.zeros((2, P, 2)), np.zeros((2, P))
            pt[0], wt[0] = np.where(w[:, None] > 0, p, 0.0), w
            pt[1, :68] = np.where(ok[:, None], q, 0.0)
            wt[1, :68] = np.where(ok, opt.flow * weights.w[:68], 0.0)     # dense points: no flow
            return Targets(pt, wt, weights.flow_nominal(opt.flow))
    return Targets.stack([(p, w)], weights.w)


def _track_run(shape: Shape, det: ClipDetections, order: list, seed: FrameState | None, weights,
               opt: CaptureOptions, states: list, prog, done0: int, seed_index: int | None = None,
               on_frame=None) -> int:
    """Track frames in ``order`` (consecutive, one direction) from the ``seed`` state (of the
    neighbouring frame ``seed_index``, when it was tracked in this run: then its flow and
    temporal terms apply too); ``on_frame(i)`` after each frame."""
    prev: FrameState | None = seed
    prev_i = seed_index if seed is not None else None
    done = done0
    found = det.found
    for i in order:
        if not found[i]:
            prev, prev_i = None, None
            done += 1
            if on_frame is not None:
                on_frame(i)
            continue
        q = None
        if prev is not None and prev_i is not None and abs(prev_i - i) == 1:
            q = prev.pose.project(shape.at_view(sin_yaw(prev.pose)).points(prev.x))
        forward = prev_i is not None and i > prev_i
        tg = _targets(det, i, prev_i if prev_i is not None else i, q, weights, opt, forward)
        st = fit_frame(shape, tg, eye_distance(det.points[i]), None if prev is None else prev.pose,
                        shape.x0 if prev is None else prev.x,
                        None if prev is None or prev_i is None else prev.x, int(opt.iterations),
                        iris_of(weights, i), weights.anchor(i), weights.extra_ridge(i))
        states[i] = st
        prev, prev_i = st, i
        done += 1
        if on_frame is not None:
            on_frame(i)
        prog("track", done, det.n_frames)
    return done


def capture_detections(det: ClipDetections, model, *, options: CaptureOptions | None = None,
                       fps: float = 30.0, frame_size: tuple[int, int] = (0, 0),
                       fixed: dict | None = None, progress: Progress | None = None,
                       source: str = "", checkpoint=None, first_frame: int | None = None
                       ) -> Track:
    """Fit the model to a clip's detections and flow (steps 2-5 of the module notes).

    Parameters
    ----------
    det : ClipDetections
    model : MultilinearModel
        With 68 landmark vertices.
    options : CaptureOptions
    fps : float
    frame_size : (W, H)
    fixed : dict, optional
        ``{"identity": (r,)}`` to keep a known identity.
    progress : callable(stage, done, total), optional
    source : str
    checkpoint : DetectionCheckpoint, optional
        Where the fit's progress is kept (:mod:`facetransfer.track.fit_checkpoint`): a fit it
        holds for this model and these options is continued; the progress is saved when
        ``checkpoint.due()`` and when the run is interrupted (``KeyboardInterrupt``). Any
        object with ``due()``, ``saved_fit(key)`` and ``save_fit(det, key, fit)`` will do.
    first_frame : int, optional
        The number a user knows the first of ``det``'s frames by, in what is said of a cut or of
        no face found (:mod:`facetransfer.io.frame_numbers`): a ``batch track --chunk`` chunk's
        is its clip's first number plus the chunk's start. Default: ``source``'s first number
        (a plate's, 1001 on; 0 for a video).

    Returns
    -------
    Track
        With ``blendshapes`` for an ARKit model.
    """
    from threadpoolctl import threadpool_limits

    n0 = first_number(source) if first_frame is None else int(first_frame)

    # small products: threads only cost; an interrupt in a compiled kernel as an interrupt
    with threadpool_limits(limits=1, user_api="blas"), plain_interrupts():
        spans = shot_spans(shot_starts(det), det.n_frames)
        if len(spans) == 1:
            return _capture_detections(det, model, options, fps, frame_size, fixed, progress,
                                       source, checkpoint, first=n0)
        return _capture_shots(det, spans, model, options, fps, frame_size, fixed, progress,
                              source, n0)


def _capture_shots(det, spans, model, options, fps, frame_size, fixed, progress,
                   source, n0: int = 0) -> Track:
    """A clip edited from several shots (:mod:`facetransfer.track.shots`), each captured on its
    own (its own identity, save the first one's person's later shots: :func:`held_identity`;
    no flow or smoothing across a cut), joined; a ``fixed`` identity is the first shot's with a
    face (the face the clip starts with, after any black opening); the fit's progress is not
    kept for such a clip. ``n0``: the number of ``det``'s first frame, as cuts are named."""
    subs = [shot_detections(det, a, b) for a, b in spans]
    faced = [a for (a, _), sub in zip(spans, subs) if sub.found.any()]
    if len(faced) > 1:  # a shot without a face (a clip that opens on black) is only lost
        log.warning("%s cuts to another shot at frame%s %s: each shot is captured on its own "
                    "(the first one's person's shots with its identity)", source or "the video",
                    "s" if len(faced) > 2 else "", ", ".join(str(n0 + a) for a in faced[1:]))
    if not faced:
        raise _no_face(source, det.n_frames, n0)
    tracks, first = [], None     # first: the identity of the first shot with a face
    for sub in subs:
        if not sub.found.any():
            tracks.append(None)
            continue
        seen = any(t is not None for t in tracks)
        held = held_identity(sub, model, options, first) if seen else fixed
        t = _capture_detections(sub, model, options, fps, frame_size, held, progress, source)
        if not seen and "identity" in t.weights:
            first = t.weights["identity"][0]
        tracks.append(t)
    return joined_shots(tracks, spans)


def held_identity(det, model, options, first: np.ndarray | None) -> dict | None:
    """The identity to hold fixed for the detections ``det`` of a later shot or a batch chunk:
    ``{"identity": first}`` where the identity of ``det``'s first shot with a face, from the
    identity phase alone (:func:`_clip_identity`), is that person's
    (:func:`facetransfer.track.shots.same_face`), so one person keeps one identity through a
    clip's cuts and chunks; another person's, no face, or no ``first``: None (its own is
    solved, or its capture says no face was found)."""
    from .shots import same_face

    if first is None:
        return None
    sub = next((s for s in (shot_detections(det, a, b) for a, b in
                            shot_spans(shot_starts(det), det.n_frames)) if s.found.any()), None)
    if sub is None:
        return None
    opt = options or CaptureOptions()
    weights, sampler = _point_weights(sub, model, opt)
    shape, _, _ = _clip_identity(model, sub, sampler, weights, opt, {},
                                 lambda stage, done, total: None)
    return {"identity": first} if same_face(model, shape.identity, first) else None


def _no_face(source, n_frames: int, first: int | None = None) -> VideoError:
    """``n_frames`` searched from the frame numbered ``first`` (default: ``source``'s first)."""
    n0 = first_number(source) if first is None else first
    return VideoError(f"no face found in {source or 'the video'} (searched frames "
                      f"{frame_span(n0, n_frames)})")


def _capture_detections(det, model, options, fps, frame_size, fixed, progress, source,
                        checkpoint=None, first: int | None = None) -> Track:
    opt = options or CaptureOptions()
    require_landmarks(model)
    fixed = dict(fixed or {})
    unknown = set(fixed) - {"identity"}
    if unknown:
        raise TrackError(f"capture can keep only the identity fixed, got {sorted(unknown)}")
    found = det.found
    if not found.any():
        raise _no_face(source, det.n_frames, first)
    prog = progress or (lambda stage, done, total: None)
    weights, sampler = _point_weights(det, model, opt)
    t0 = time.perf_counter()
    key = None if checkpoint is None else fit_key(model.content_hash, opt, fixed)
    saved = None if checkpoint is None else checkpoint.saved_fit(key)
    if saved is not None and len(saved.valid) == det.n_frames:
        run = _FitRun.restore(saved, model, sampler, opt)
        log.info("continued an interrupted fit (%d of %d frames fitted)", int(saved.valid.sum()),
                 det.n_frames)
    else:
        shape, sample_states, frames = _clip_identity(model, det, sampler, weights, opt, fixed,
                                                      prog)
        best = int(np.argmin([s.residual for s in sample_states]))
        run = _FitRun(shape, np.asarray(frames), int(frames[best]), sample_states[best],
                      [None] * det.n_frames, int(frames[best]), int(frames[best]) - 1)
    t_id = time.perf_counter() - t0

    def save(due_only: bool) -> None:
        if checkpoint is not None and (not due_only or checkpoint.due()):
            checkpoint.save_fit(det, key, run.saved())

    try:
        with plain_interrupts():     # the interrupt itself, where a compiled kernel wrapped it
            _track_passes(run, det, weights, opt, prog, lambda: save(due_only=True))
    except KeyboardInterrupt:
        save(due_only=False)
        raise
    track = _assemble(model, run.shape, run.states, fps, frame_size, source, opt)
    if det.shown is not None:      # a frame the detector did not see: half as sure
        track = replace(track, confidence=np.where(det.shown, 1.0, UNSEEN_CONFIDENCE)
                        * track.confidence)
    info = {"start_frame": run.start, "identity_frames": [int(i) for i in run.frames],
            "seconds_identity": t_id, "seconds_total": time.perf_counter() - t0,
            "tracker": "capture", "score_shapes": run.score_shapes()}
    # the detections themselves: the fit's residual at the lips carries the lips the model's
    # shapes cannot reach (facetransfer.lips); fitted in square pixels, told in stored ones
    return stored_pixels(replace(track, info=info, detections2d=det.points), det.pixel_aspect)


def _point_weights(det: ClipDetections, model, opt: CaptureOptions
                   ) -> tuple[PointWeights, Sampler]:
    """The tracked points (iBUG-68, then MediaPipe's dense points with ``opt.dense``), their
    reliabilities and the iris centres the gaze follows."""
    weights = np.asarray(opt.point_weights if opt.point_weights is not None
                         else capture_point_weights(), float)
    dense = _dense_points(model, opt) if det.points478 is not None else None
    if dense is not None:
        weights = np.concatenate([weights, np.full(len(dense.mp_index), float(opt.dense))])
    sampler = capture_points.sampler(model, dense)
    iris = closed = None
    if opt.gaze and is_arkit_model(model) and det.points478 is not None \
            and det.points478.shape[1] > max(IRIS_INDEX):
        iris, closed = usable_iris(det.points478)
    return PointWeights(weights, sampler.mp_index, iris, closed), sampler


def _dense_points(model, opt: CaptureOptions):
    """MediaPipe's dense points on ``model`` the fit follows with ``opt.dense`` (detections
    with MediaPipe's 478 points), or None."""
    if not opt.dense > 0:
        return None
    from .dense import mediapipe_correspondence

    return mediapipe_correspondence(model)


def prepare_points(model, options: CaptureOptions | None = None) -> None:
    """The capture's tracked points of ``model`` (its core read at them,
    :func:`.capture_points.sampler`, which keeps them) made now, as a fit with ``options`` of
    MediaPipe's detections makes them.

    Making them reads the model's core at the points (0.1-0.15 CPU-s, most of it the pages
    of a core mapped from its file). A command that tracks a second clip in a forked child
    (:func:`facetransfer.track.obtain.start_background_track`) calls this before the fork:
    the child inherits them instead of making them again. Nothing for a model without
    landmark vertices (whose tracking fails on them)."""
    if getattr(model, "landmarks", None) is None:
        return
    capture_points.sampler(model, _dense_points(model, options or CaptureOptions()))


def _track_passes(run: "_FitRun", det: ClipDetections, weights: PointWeights,
                  opt: CaptureOptions, prog, maybe_save) -> None:
    """Track the clip both ways (continuing ``run``); for an ARKit model with the detector's
    scores and ``opt.scores > 0`` then once more with each frame pulled toward its mapped
    scores (:mod:`facetransfer.track.scores`; progress stage ``"refine"``). The funnel's
    ridge where the lips are shut (:func:`funnel_ridges`) is in the last pass only: the
    first pass's funnel sets the score line's slope.
    """
    refine = opt.scores > 0 and det.scores is not None and run.shape.arkit
    final = replace(weights, extra_ridges=funnel_ridges(run.shape, det.points, opt))
    if run.lines is None:
        _track_both(run, det, weights if refine else final, opt, prog, maybe_save)
        if not refine:
            return
        run.begin_refine(_score_lines(run, det))
    anchors = score_targets(run.lines, det.scores)[:, run.shape.used]
    _track_both(run, det, replace(final, anchors=anchors,
                                  anchor_weights=run.lines.weight[run.shape.used]), opt,
                lambda stage, done, total: prog("refine", done, total), maybe_save)


def funnel_ridges(shape: Shape, points: np.ndarray, opt: CaptureOptions) -> np.ndarray | None:
    """The extra ridge of every frame's activations (F, K): on mouthFunnel
    ``opt.funnel_gate · opt.expression_prior`` times how shut the detected lips are
    (:func:`~facetransfer.track.capture_frame.lips_gate` of the iBUG ``points`` (F, 68, 2)),
    0 elsewhere (§5, Eq. (9)'s bounded least squares); None for a model without ARKit
    activations, without a funnel, or with the gate off."""
    name = ARKIT_NAMES.index("mouthFunnel")
    if not (shape.arkit and opt.funnel_gate > 0 and name in shape.used):
        return None
    ridges = np.zeros((len(points), shape.size))
    ridges[:, int(np.flatnonzero(shape.used == name)[0])] = \
        opt.funnel_gate * opt.expression_prior * lips_gate(lips_gap(points))
    return ridges


def _score_lines(run: "_FitRun", det: ClipDetections) -> ScoreLine:
    """The lines mapping the detector's scores onto the first pass's activations."""
    A = np.full((det.n_frames, len(ARKIT_NAMES)), np.nan)
    for i, st in enumerate(run.states):
        if st is not None:
            A[i, run.shape.used] = st.x
    return fit_score_lines(A, det.scores)


@dataclass
class _FitRun:
    """A fit in progress (mutable: the runs fill ``states`` and advance ``forward_next`` /
    ``backward_next``); :meth:`saved` and :meth:`restore` convert it for the progress file."""

    shape: Shape
    frames: np.ndarray
    start: int
    seed: FrameState
    states: list
    forward_next: int
    backward_next: int
    lines: ScoreLine | None = None   # of the second pass (then ``states`` are its), or None

    def begin_refine(self, lines: ScoreLine) -> None:
        """Start the second pass (:func:`_track_passes`) with the score ``lines``."""
        self.lines = lines
        self.states = [None] * len(self.states)
        self.forward_next, self.backward_next = self.start, self.start - 1

    def score_shapes(self) -> list[str]:
        """The ARKit shapes whose detector scores the fit read (none without a second pass)."""
        return [] if self.lines is None else [ARKIT_NAMES[k] for k in
                                              np.flatnonzero(self.lines.used())]

    def saved(self) -> SavedFit:
        F = len(self.states)
        ref = next((s for s in self.states if s is not None), self.seed)
        R, sc, t = np.zeros((F, 3, 3)), np.zeros(F), np.zeros((F, 2))
        x, r = np.zeros((F, len(ref.x))), np.zeros(F)
        valid = np.array([s is not None for s in self.states], bool)
        for i in np.flatnonzero(valid):
            st = self.states[i]
            R[i], sc[i], t[i], x[i], r[i] = (st.pose.rotation, st.pose.scale,
                                             st.pose.translation, st.x, st.residual)
        sd = self.seed
        offset = self.shape.offset if self.shape.view is None else \
            np.concatenate([self.shape.offset, self.shape.view], axis=1)
        return SavedFit(self.shape.identity, offset, self.frames, self.start,
                        (sd.pose.rotation, sd.pose.scale, sd.pose.translation, sd.x,
                         sd.residual), valid, R, sc, t, x, r, self.forward_next,
                        self.backward_next,
                        None if self.lines is None else np.stack([self.lines.offset,
                                                                  self.lines.slope,
                                                                  self.lines.weight]))

    @classmethod
    def restore(cls, fit: SavedFit, model, sampler: Sampler, opt: CaptureOptions) -> "_FitRun":
        o = np.asarray(fit.offset)                      # (P, 3) or, with the view, (P, 6)
        shape = Shape(model, fit.identity, sampler, opt, o[:, :3],
                      o[:, 3:] if o.shape[1] == 6 else None)
        R, sc, t, x, r = fit.seed
        states = [FrameState(Pose(fit.rotation[i], float(fit.scale[i]), fit.translation[i]),
                         fit.x[i], float(fit.residual[i])) if fit.valid[i] else None
                  for i in range(len(fit.valid))]
        lines = None if fit.lines is None else ScoreLine(*fit.lines)
        return cls(shape, fit.frames, fit.start, FrameState(Pose(R, sc, t), x, r), states,
                   fit.forward_next, fit.backward_next, lines)


def _track_both(run: _FitRun, det: ClipDetections, weights, opt: CaptureOptions, prog,
                maybe_save) -> None:
    """The forward run (``run.start`` to the end), then the backward one (to frame 0), each
    continued from where ``run`` stands; ``maybe_save()`` after every frame."""
    F = det.n_frames
    done = (run.forward_next - run.start) + (run.start - 1 - run.backward_next)

    def advanced(attr, step):
        def hook(i):
            setattr(run, attr, i + step)
            maybe_save()
        return hook

    if run.forward_next < F:
        j = run.forward_next - 1                        # the frame tracked before, if any
        seed, at = ((run.seed, None) if run.forward_next == run.start
                    else (run.states[j], j))
        done = _track_run(run.shape, det, list(range(run.forward_next, F)), seed, weights, opt,
                          run.states, prog, done, at, advanced("forward_next", 1))
    if run.backward_next >= 0:
        j = run.backward_next + 1
        seed, at = ((run.states[run.start], None) if run.backward_next == run.start - 1
                    else (run.states[j], j))
        _track_run(run.shape, det, list(range(run.backward_next, -1, -1)), seed, weights, opt,
                   run.states, prog, done, at, advanced("backward_next", -1))


def _fill_lost(states: list) -> tuple[list, np.ndarray]:
    """Lost frames take the nearest tracked state (earlier one on ties)."""
    ok = np.array([s is not None for s in states])
    return [states[j] for j in nearest_tracked(~ok)], ~ok   # held_lost's rule, one place


def _assemble(model, shape: Shape, states: list, fps, size, src, opt) -> Track:
    full, lost = _fill_lost(states)
    F = len(full)
    R = np.stack([s.pose.rotation for s in full])
    s = np.array([s_.pose.scale for s_ in full])
    t = np.stack([s_.pose.translation for s_ in full])
    X = np.stack([s_.x for s_ in full])
    if opt.smooth > 0:
        R, s, t, wx = smooth_track(R, s, t, {"x": X}, opt.smooth)
        X = wx["x"]
        if shape.arkit:
            X = np.clip(X, 0.0, 1.0)
    w = shape.weights(X)                                                  # (F, r) per mode
    if shape.id_name:
        w[shape.id_name] = np.tile(shape.identity, (F, 1))
    res = np.array([s_.residual for s_ in full])
    conf = np.where(lost, 0.0, np.clip(1.0 - res / 0.15, 0.0, 1.0))
    # the tracked landmarks: the model's landmark vertices plus the clip's static offset (rows
    # 0-67 of the tracked points), as the fit placed them on the detections
    Xl = model.synthesize(w, vertices=model.landmarks) + shape.offset[:68]  # (F, 68, 3)
    if shape.view is not None:                          # the offset at each frame's yaw
        Xl = Xl + np.clip(R[:, 0, 2], -1.0, 1.0)[:, None, None] * shape.view[:68]
    R, t = restore_pitch(R, s, t, Xl, capture_point_weights(1.0), opt.pitch_gain)
    Y = np.einsum("fij,fnj->fni", R[:, :2], Xl) * s[:, None, None]
    Y[..., 1] *= -1
    L = Y + t[:, None, :]
    blend = names = None
    if shape.arkit:
        blend = np.zeros((F, len(ARKIT_NAMES)), np.float32)
        blend[:, shape.used] = X
        names = ARKIT_NAMES
    W, H = size
    return Track(fps=fps, frame_size=(max(int(W), 1), max(int(H), 1)), rotation=R, scale=s,
                 translation=t, weights=w, landmarks2d=L, confidence=conf, lost=lost,
                 model_hash=model.content_hash, mode_names=tuple(model.mode_names), source=src,
                 blendshapes=blend, blendshape_names=names)


def restore_pitch(R: np.ndarray, s: np.ndarray, t: np.ndarray, X: np.ndarray, w: np.ndarray,
                  gain: float) -> tuple[np.ndarray, np.ndarray]:
    """The head's pose from one fitted to points that show its pitch ``gain`` times too small.

    With ``R = Rx(a) Ry(b) Rz(c)`` (pitch ``a`` about the camera's x axis after yaw ``b`` and
    roll ``c``), the pitch becomes ``a / gain``; the translation keeps the ``w``-weighted
    centroid of the points ``X`` where the fitted pose projects it (:class:`.camera.Pose`).

    Parameters
    ----------
    R : (F, 3, 3) float
    s : (F,) float
    t : (F, 2) float
    X : (F, P, 3) float
        Each frame's tracked points, model units.
    w : (P,) float
    gain : float
        1 returns ``R`` and ``t`` as they are.

    Returns
    -------
    R, t : (F, 3, 3), (F, 2) float
    """
    if float(gain) == 1.0:
        return R, t
    a = np.arctan2(-R[:, 1, 2], R[:, 2, 2])                                   # (F,)
    d = a / float(gain) - a
    Rx = np.zeros_like(R)
    Rx[:, 0, 0] = 1.0
    Rx[:, 1, 1] = Rx[:, 2, 2] = np.cos(d)
    Rx[:, 2, 1] = np.sin(d)
    Rx[:, 1, 2] = -Rx[:, 2, 1]
    R2 = Rx @ R
    c = np.einsum("p,fpk->fk", np.asarray(w, float) / np.sum(w), X)          # (F, 3)
    shift = np.einsum("fij,fj->fi", R[:, :2] - R2[:, :2], c) * np.asarray(s)[:, None]
    shift[:, 1] *= -1.0
    return R2, t + shift


def load_kernels() -> None:
    """Load the fit's compiled kernels (:mod:`.fit2d`, :func:`.gaze.frame_gaze_activations`)
    from numba's cache by running each once on a tiny problem (:func:`.lip_contact.contact_qp`'s
    Newton steps too; SciPy's optimiser, which it calls only where they fail, is not imported:
    0.17 s).

    numba starts up on the first compiled call of a process (about 0.25 s here). A command
    that tracks a second clip in a forked child
    (:func:`facetransfer.track.obtain.start_background_track`) calls this before the fork: the
    child then inherits the loaded kernels instead of starting numba again at its fit.
    """
    R, t = np.eye(3), np.zeros(2)
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    tg = [(X[:, :2] * 10.0, np.ones(3))]
    pose_gauss_newton(X, tg, Pose(R, 10.0, t), 10.0, iterations=1)
    box_qp(np.eye(2), np.ones(2), np.zeros(2))
    D = np.zeros((2, 3, 3))
    D[0, :, 0] = D[1, :, 1] = 1.0
    T = Targets.stack(tg)
    rig_solve(D, gram_blocks(D, T.nominal), Pose(R, 10.0, t), T, np.zeros((3, 2)), 10.0,
              np.zeros(2), ridge=np.full(2, 1e-3), rhs=np.zeros(2), lo=np.zeros(2),
              hi=np.ones(2))
    frame_gaze_activations(np.zeros((68, 3)) + np.arange(68)[:, None], np.zeros((2, 2)),
                           np.zeros(2, bool), R, 10.0, t)
    # the Newton steps' kernel, on a problem they solve (SciPy's optimiser is not imported)
    contact_qp(np.eye(2), np.full(2, 0.5), np.full(2, 0.5), np.zeros(2), np.ones(2),
               np.ones((1, 2)), np.array([1.5]))


def capture_video(video, model, *, options: CaptureOptions | None = None, detector=None,
                  detections: ClipDetections | None = None, max_frames: int | None = None,
                  fixed: dict | None = None, progress: Progress | None = None,
                  source: str | None = None, checkpoint=None, workers: int = 1,
                  view=None, subject=None, every: int = 1, eyes: bool = False) -> Track:
    """Capture a face's performance from a video (module notes): the default tracker.

    Parameters
    ----------
    video : path-like or (F, H, W, 3) uint8 array
    model : MultilinearModel
    options : CaptureOptions
    detector : object, optional
        ``detect478(frame)`` or ``detect(frame)`` in frame order; default MediaPipe in video mode.
    detections : ClipDetections, optional
        Reuse detections made before (the video is then read only for its size and rate).
    max_frames, fixed, progress, source
        As in :func:`facetransfer.track.track_video`.
    checkpoint : DetectionCheckpoint, optional
        The fit's progress (:func:`capture_detections`).
    workers : int
        Processes running the default detector (:func:`~.video_detect.detect_video`).
    view : facetransfer.track.aspect.View, optional
        How the detector is shown the frames (default: a file's own; an array as it is): in
        square pixels, the track told in the stored ones, and of interlaced video one field
        (:mod:`facetransfer.track.aspect`).
    subject : (x, y, 0), optional
        Of several people, follow the face nearest this point
        (:func:`facetransfer.track.face_crop.subject_point`).
    every : int
        Show the default detector one frame of ``every``, the frames between interpolated
        (:func:`facetransfer.track.detect.detect_clip`; a transfer's clips, issue 13).
    eyes : bool
        With ``every`` > 1, show it every frame where the eyes move too
        (:mod:`facetransfer.track.skip_rule`; a transfer's expression source).

    Returns
    -------
    Track
    """
    require_landmarks(model)
    if detections is None:
        detections, fps, size, src = detect_video(video, detector=detector,
                                                  max_frames=max_frames, progress=progress,
                                                  source=source, workers=workers,
                                                  view=view, subject=subject, every=every,
                                                  eyes=eyes)
    else:
        fps, size, src, _, n, _ = _open(video, max_frames, source)
        if n is not None and detections.n_frames != n:
            raise TrackError(f"detections have {detections.n_frames} frames, the video {n}")
    return capture_detections(detections, model, options=options, fps=fps, frame_size=size,
                              fixed=fixed, progress=progress, source=src, checkpoint=checkpoint)

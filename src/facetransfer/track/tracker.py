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

This module runs the passes (:func:`track_video`); one frame pair is solved by
:class:`~facetransfer.track.pair.FaceTracker` (:mod:`.pair`), the options are
:class:`~facetransfer.track.options.TrackOptions`, the frames come from :mod:`.frames` and the
smoothing from :mod:`.smooth`; ``TrackOptions``, ``FaceTracker``, ``frame_source`` and
``smooth_track``, which live there, are importable from here too.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import TrackError, VideoError, plain_interrupts
from ..io.frame_numbers import first_number, frame_span
from .camera import Pose, fit_affine_pose, orthonormalize, project
from .frames import FrameSource, frame_source
from .init import check_init_points, fit_landmarks, points_to_array, require_landmarks
from .options import Progress, TrackOptions
from .pair import FaceTracker
from .result import Track
from .smooth import smooth_track
from .solver import FrameState, fit_points

log = logging.getLogger(__name__)

# FaceTracker, TrackOptions, smooth_track and frame_source live in .pair, .options, .smooth and
# .frames; they stay importable from here.
__all__ = ["TrackOptions", "FaceTracker", "track_video", "smooth_track", "frame_source"]


# ------------------------------------------------------------------------------------ driver
def track_video(video, model, *, init="auto", options: TrackOptions | None = None,
                detector=None, max_frames: int | None = None, fixed: dict | None = None,
                progress: Progress | None = None, source: str | None = None,
                checkpoint: str | os.PathLike | None = None,
                checkpoint_every: float = 20.0, first_frame: int | None = None) -> Track:
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
    first_frame : int, optional
        The number a user knows the first of the frames by, in what is said of the first face
        found or of none (:mod:`facetransfer.io.frame_numbers`): a ``batch track --chunk``
        chunk's is its clip's first number plus the chunk's start. Default: ``source``'s
        first number (a plate's, 1001 on; 0 for a video).

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
    n0 = first_number(src) if first_frame is None else int(first_frame)
    auto = isinstance(init, str) and init == "auto"
    if not auto:  # read and validated once (a file, a dict or an array of points)
        init = _init_array(init, frames.size)
    own_detector = None
    if detector is None and (auto or opt.anchor):
        from .init import MediaPipeDetector

        detector = own_detector = MediaPipeDetector()
    ck = (None if checkpoint is None else
          _open_checkpoint(checkpoint, frames, model, opt, init, fixed, checkpoint_every))
    try:
        with plain_interrupts():    # an interrupt a compiled kernel wrapped: the interrupt
            track = _run(frames, model, init, opt, detector, progress, src, fixed, ck, n0)
        if ck is not None:
            ck.remove()
        return track
    finally:
        if own_detector is not None:
            own_detector.close()


def _open_checkpoint(path, frames: FrameSource, model, opt: TrackOptions, init, fixed,
                     every: float):
    """The run's :class:`~facetransfer.track.checkpoint.Checkpoint`, keyed by everything the run
    depends on (the video, the model, the options, the initial points, the fixed modes)."""
    from .checkpoint import Checkpoint, checkpoint_key, video_identity

    vid = video_identity(frames.path) if frames.path else video_identity(
        None, frames.array[0], frames.array[-1])
    return Checkpoint(path, checkpoint_key(vid, frames.n, model.content_hash, opt, init, fixed),
                      model.mode_names, every=every)


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


# ------------------------------------------------------------------------------------ run state
class _Detections:
    """Detector landmarks (68, 2) per frame index, each frame detected at most once."""

    def __init__(self, frames: FrameSource, detector) -> None:
        self.frames = frames
        self.detector = detector
        self.found: dict[int, np.ndarray | None] = {}

    def __call__(self, i: int, frame: np.ndarray | None = None) -> np.ndarray | None:
        if i not in self.found:
            if self.detector is None:
                self.found[i] = None
            else:
                self.found[i] = self.detector.detect(self.frames.get(i) if frame is None
                                                     else frame)
        return self.found[i]


@dataclass
class _Run:
    """What one run of the tracker carries between its steps (§5.2 initialisation and snap,
    §5.1 passes): the solution ``state0`` at the first frame with a face ``start``, its feature
    points ``L0`` (68, 2), and per frame the state, the confidence and the lost flag."""

    frames: FrameSource
    model: object
    tr: FaceTracker
    detect: _Detections
    checkpoint: object | None
    progress: Progress
    start: int
    L0: np.ndarray
    state0: FrameState
    states: list = field(init=False)
    conf: np.ndarray = field(init=False)
    lost: np.ndarray = field(init=False)
    reinit: list = field(default_factory=list)   # frames re-initialised in the current pass

    def __post_init__(self) -> None:
        F = self.frames.n
        self.states = [None] * F
        self.conf = np.zeros(F)
        self.lost = np.zeros(F, bool)
        self.lost[:self.start] = True

    @property
    def opt(self) -> TrackOptions:
        return self.tr.opt

    @property
    def id_name(self) -> str | None:
        """The clip-constant mode solved once per pass (§5.1), if any."""
        return self.tr.accumulated[0] if self.tr.accumulated else None

    def anchor_for(self, i: int, frame: np.ndarray) -> np.ndarray | None:
        """Detector landmarks of frame ``i`` when anchoring is on."""
        return self.detect(i, frame) if self.opt.anchor else None

    def save(self, pass_index: int, next_frame: int, systems: list, reinit: list,
             prev: list | None) -> None:
        """Write the checkpoint: what is finished up to ``next_frame`` of pass ``pass_index``."""
        self.checkpoint.save(start=self.start, L0=self.L0, state0=self.state0,
                             pass_index=pass_index, next_frame=next_frame, states=self.states,
                             prev=prev, conf=self.conf, lost=self.lost, reinit=reinit,
                             systems=systems)


@dataclass
class _Pass:
    """One pass in progress (§5.1): the identity systems accumulated so far, the key frame and
    the pyramid of the last solved frame, the frames left and the next frame to solve."""

    index: int
    last: bool
    systems: list
    key: tuple
    pyr0: object
    todo: object          # iterator over the frames from `next_frame` on
    next_frame: int


def _no_progress(stage: str, done: int, total: int) -> None:
    return None


def _run(frames: FrameSource, model, init, opt: TrackOptions, detector, progress, src,
         fixed: dict | None = None, checkpoint=None, n0: int = 0) -> Track:
    """Initialise, snap and run the passes (§5.2, §5.1); resume from ``checkpoint`` if it holds
    an interrupted run. ``n0``: the number of the first frame, as the messages name it."""
    fixed = _check_fixed(model, fixed)
    tr = FaceTracker(model, frames.size, opt, detector=detector, fixed=tuple(fixed))
    t_start = time.perf_counter()
    detect = _Detections(frames, detector)
    resume = checkpoint.load() if checkpoint is not None else None
    if resume is None:
        start, L0, state0 = _initialise(frames, model, tr, init, detect, src, fixed, n0)
    else:  # an interrupted run of the same video, model and options
        start, L0, state0 = resume.start, np.asarray(resume.L0), resume.state0
        log.info("resuming from %s: pass %d, frame %d", checkpoint.path,
                 resume.pass_index + 1, n0 + resume.next_frame)   # a plate's: its number
    t_init = time.perf_counter() - t_start
    run = _Run(frames, model, tr, detect, checkpoint, progress or _no_progress, start, L0,
               state0)
    if resume is None:
        _snap(run)
    _passes(run, resume)
    for i in range(start):  # frames before the first face hold the first tracked state
        run.states[i] = run.states[start]
    t_track = time.perf_counter() - t_start
    track = _assemble(model, run.states, run.conf, run.lost, frames.fps, frames.size, src, opt)
    info = {"start_frame": start, "reinitialised": run.reinit, "timings": dict(tr.timings),
            "resumed": None if resume is None else {"pass": resume.pass_index + 1,
                                                    "frame": resume.next_frame},
            "counts": dict(tr.counts),
            "mean_points": tr.counts.get("points", 0) / max(tr.counts.get("pair", 0), 1),
            "seconds_init": t_init, "seconds_total": t_track, "n_frames": frames.n}
    return replace(track, info=info)


# ------------------------------------------------------------------------------------ §5.2
def _initialise(frames: FrameSource, model, tr: FaceTracker, init, detect: _Detections, src,
                fixed: dict, n0: int = 0) -> tuple[int, np.ndarray, FrameState]:
    """§5.2 initialisation: the first frame with a face, its feature points (68, 2) and the
    model fitted to them (pose, identity and expression; ``fixed`` modes held); the frames
    numbered from ``n0`` in what is said."""
    start = 0
    if isinstance(init, str) and init == "auto":
        start, L0 = _first_face(frames, detect, src, n0)
    else:
        L0 = _init_array(init, frames.size)
    if start > 0:
        log.info("first face found at frame %d", n0 + start)
    start_state = None
    if fixed:
        w = {m: tr.priors[m].mean.copy() for m in model.mode_names}
        w.update(fixed)
        ok = np.all(np.isfinite(L0), axis=1)
        X = model.synthesize(w, vertices=tr.lm_vertices[ok])
        start_state = FrameState(fit_affine_pose(X, L0[ok]), w)
    state0 = fit_landmarks(model, L0, prior=tr.opt.init_prior, state=start_state,
                           modes=tuple(m for m in model.mode_names if m not in fixed))
    return start, L0, state0


def _first_face(frames: FrameSource, detect: _Detections, src, n0: int = 0
                ) -> tuple[int, np.ndarray]:
    """The first frame the detector finds a face in, and its landmarks (68, 2); the frames
    numbered from ``n0`` where none has one."""
    if detect.detector is None:
        raise TrackError("automatic initialisation needs a face detector")
    for i, fr in enumerate(frames.iterate()):
        L0 = detect(i, fr)
        if L0 is not None:
            return i, L0
    raise VideoError(f"no face found in {src or 'the video'} (searched frames "
                     f"{frame_span(n0, frames.n)})")   # a plate's: its numbers


def _snap(run: _Run) -> None:
    """§5.2 snap: track the first ``snap_frames`` frames forth and back (``snap_rounds``
    times); the state reached back at the first frame is the snapped alignment."""
    n_snap = min(int(run.opt.snap_frames), run.frames.n - run.start - 1)
    if n_snap <= 0:
        return
    snap_frames = list(run.frames.iterate(run.start, run.start + n_snap + 1))
    pyrs = [run.tr.pyramid(f) for f in snap_frames]
    order = list(range(1, n_snap + 1)) + list(range(n_snap - 1, -1, -1))
    for rnd in range(int(run.opt.snap_rounds)):
        systems = []
        if run.id_name is not None:
            systems.append(run.tr.landmark_identity_system(run.state0, run.L0,
                                                           run.opt.init_weight))
        st = run.state0
        cur = 0
        for j, nxt in enumerate(order):
            res = run.tr.track_pair(pyrs[cur], pyrs[nxt], st, st,
                                    anchor=run.anchor_for(run.start + nxt, snap_frames[nxt]),
                                    accumulate=run.id_name is not None)
            st = res.state
            if res.identity_system is not None:
                systems.append(res.identity_system)
            cur = nxt
            run.progress("snap", rnd * len(order) + j + 1, len(order) * int(run.opt.snap_rounds))
        run.state0 = st
        _apply_identity(run, systems)


def _apply_identity(run: _Run, systems: list) -> None:
    """Solve the identity from the accumulated systems (§5.1, once per pass) and re-express the
    first frame's 2-D vertex positions with it (a new ``run.state0``)."""
    if not systems or run.id_name is None:
        return
    tr, model, st = run.tr, run.model, run.state0
    w_new, fac = tr.solve_identity(systems, st.weights)
    # targets: the current 2-D positions of many vertices at the start frame
    pyr = tr.pyramid(run.frames.get(run.start))
    sel, p = tr.select_vertices(st, pyr)
    if sel.size < 10:
        sel = tr.lm_vertices
        p = project(model.synthesize(st.weights, vertices=sel), st.pose.rotation,
                    st.pose.scale, st.pose.translation)
    w = dict(st.weights)
    w[run.id_name] = w_new
    start_st = FrameState(Pose(st.pose.rotation, st.pose.scale * fac, st.pose.translation), w)
    run.state0 = fit_points(model, sel, p, state=start_st, modes=tr.per_frame, prior=0.0,
                            iterations=5)


# ------------------------------------------------------------------------------------ §5.1
def _passes(run: _Run, resume) -> None:
    """§5.1: ``passes`` passes through the video, each from the first frame (continuing an
    interrupted pass of ``resume``); the identity is solved after every pass but the last."""
    n_passes = int(run.opt.passes)
    prev: list | None = None
    first_pass = 0
    if resume is not None:
        first_pass, prev = resume.pass_index, resume.prev
        run.conf[:], run.lost[:] = resume.conf, resume.lost
        if first_pass >= n_passes:  # every pass was done: only the assembly is left
            run.states[:] = prev
    elif run.checkpoint is not None:
        run.save(0, run.start + 1, [], [], None)
    for ps in range(first_pass, n_passes):
        if resume is not None and ps == resume.pass_index and resume.next_frame > run.start + 1:
            pas = _resume_pass(run, ps, resume, prev)   # continue where it stopped
        else:
            pas = _begin_pass(run, ps)
        _track_frames(run, pas, prev)
        if not pas.last and run.id_name is not None and len(pas.systems) > 0:
            _apply_identity(run, pas.systems)
        prev = list(run.states)
        if run.checkpoint is not None:
            run.save(ps + 1, run.start + 1, [], run.reinit, prev)


def _begin_pass(run: _Run, ps: int) -> _Pass:
    """A fresh pass from the first frame: its state is ``run.state0``, its landmarks the first
    identity system."""
    run.reinit = []
    run.lost[run.start + 1:] = False
    systems = []
    if run.id_name is not None and not run.lost[run.start]:
        systems.append(run.tr.landmark_identity_system(run.state0, run.L0, run.opt.init_weight))
    run.states[run.start] = run.state0
    todo = run.frames.iterate(run.start)
    pyr0 = run.tr.pyramid(next(todo))
    run.conf[run.start] = 1.0
    return _Pass(ps, ps == int(run.opt.passes) - 1, systems, (pyr0, run.state0), pyr0, todo,
                 run.start + 1)


def _resume_pass(run: _Run, ps: int, resume, prev: list | None) -> _Pass:
    """The interrupted pass of ``resume``, from the first frame it had not solved."""
    run.reinit = list(resume.reinit)
    base = prev if prev is not None else [None] * run.frames.n
    run.states[:] = [r if r is not None else b for r, b in zip(resume.states, base)]
    i_next = resume.next_frame
    key = (run.tr.pyramid(run.frames.get(run.start)), run.state0)
    pyr0 = run.tr.pyramid(run.frames.get(i_next - 1))
    return _Pass(ps, ps == int(run.opt.passes) - 1, list(resume.systems), key, pyr0,
                 run.frames.iterate(i_next), i_next)


def _track_frames(run: _Run, pas: _Pass, prev: list | None) -> None:
    """Track the frames left in the pass, one pair at a time; checkpoint as due and, when
    interrupted, what the pass has finished."""
    done = pas.next_frame  # the next frame to solve
    F = run.frames.n
    try:
        for i, fr in enumerate(pas.todo, start=pas.next_frame):
            pyr1 = run.tr.pyramid(fr)
            _track_frame(run, pas, i, fr, pyr1, prev)
            pas.pyr0 = pyr1
            done = i + 1
            if run.checkpoint is not None and run.checkpoint.due():
                run.save(pas.index, done, pas.systems, run.reinit, prev)
            run.progress(f"pass {pas.index + 1}/{run.opt.passes}", i - run.start,
                         F - 1 - run.start)
    except BaseException:
        if run.checkpoint is not None and done > pas.next_frame:  # keep what this pass finished
            run.save(pas.index, done, pas.systems, run.reinit, prev)
        raise


def _track_frame(run: _Run, pas: _Pass, i: int, fr: np.ndarray, pyr1, prev: list | None) -> None:
    """Solve frame ``i`` from frame ``i - 1`` (the pair's solve), mark it lost or recover it, and
    keep its identity system."""
    tr, opt = run.tr, run.opt
    st_prev = run.states[i - 1]
    res = tr.track_pair(pas.pyr0, pyr1, st_prev, _guess(run, i, prev),
                        anchor=run.anchor_for(i, fr),
                        accumulate=(run.id_name is not None and not pas.last), key=pas.key)
    st, c = res.state, res.confidence
    # once lost, frames stay lost until a re-initialisation (the flow may lock onto the
    # background with high confidence)
    is_lost = (c < opt.lost_threshold or not _face_in_image(run.model, tr, st, run.frames.size)
               or bool(run.lost[i - 1]))
    if is_lost and opt.recover and tr.detector is not None:
        st, c, is_lost = _recover(run, i, fr, st_prev, st, c)
    if is_lost and not _face_in_image(run.model, tr, st, run.frames.size):
        st = st_prev
    run.states[i] = st
    run.conf[i] = 0.0 if is_lost else c
    run.lost[i] = is_lost
    if res.identity_system is not None and not is_lost:
        pas.systems.append(res.identity_system)


def _guess(run: _Run, i: int, prev: list | None) -> FrameState:
    """Starting point at frame ``i``: frame ``i - 1`` moved as in the previous pass, or at
    constant velocity, or frame ``i - 1`` itself."""
    st_prev = run.states[i - 1]
    if prev is not None and prev[i] is not None and prev[i - 1] is not None:
        return _relative_guess(st_prev, prev[i - 1], prev[i])
    if (i - 2 >= run.start and not run.lost[i - 1] and not run.lost[i - 2]
            and (i - 1) not in run.reinit):
        return _velocity_guess(run.states[i - 2], st_prev)
    return st_prev


def _recover(run: _Run, i: int, fr: np.ndarray, st_prev: FrameState, st: FrameState,
             c: float) -> tuple[FrameState, float, bool]:
    """Re-initialise a lost frame from the detector: ``(state, confidence, still lost)``."""
    L = run.detect(i, fr)
    if L is None:
        return st, c, True
    try:
        st = fit_landmarks(run.model, L, state=st_prev, modes=run.tr.per_frame,
                           prior=run.opt.init_prior)
    except TrackError:
        log.debug("re-initialisation failed at frame %d", i)
        return st, c, True
    run.reinit.append(i)
    return st, max(c, run.opt.lost_threshold), False


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
    from ..arkit import attach_activations

    # an ARKit model's expression weights as the 52 activations (Eq. (A) inverted, clipped to
    # [0, 1]): what export, view and edit read
    return attach_activations(
        Track(fps=fps, frame_size=size, rotation=R, scale=s, translation=t, weights=w,
              landmarks2d=L, confidence=np.clip(conf, 0, 1), lost=lost,
              model_hash=model.content_hash, mode_names=tuple(model.mode_names), source=src),
        model)

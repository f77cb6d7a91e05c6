"""The track of a video for a transfer (Vlasic et al. 2005, §5): read from a track file, or
tracked now by the capture tracker, the optical-flow tracker of §5.1 or a landmark-only fit
(§5.2), optionally in a forked background process (:func:`start_background_track`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
from pathlib import Path

import numpy as np

from ..errors import ShapeError, TrackError, VideoError
from ..errors import RewriteError
from .aspect import warn_stored_fit
from .cache import cached_track, holds, partial_path, store_track, track_key
from .presets import check_track_method
from .project import project_landmarks, take_frames
from .result import Track

log = logging.getLogger(__name__)

__all__ = ["capture_resuming", "done_tracking", "landmarks_file", "landmark_track",
           "obtain_track", "start_background_track"]


def landmarks_file(video: str | os.PathLike) -> Path | None:
    """``NAME.mediapipe478.npz`` next to ``NAME.mp4`` if it exists (precomputed landmarks)."""
    p = Path(video)
    cand = p.with_name(p.stem + ".mediapipe478.npz")
    return cand if cand.is_file() else None


def _detect_landmarks(frames, *, progress=None) -> np.ndarray:
    """iBUG-68 points per frame with MediaPipe, (F, 68, 2), NaN where no face."""
    from .init import MediaPipeDetector

    out = np.full((len(frames), 68, 2), np.nan)
    with MediaPipeDetector() as det:
        for i, f in enumerate(frames):
            pts = det.detect(np.asarray(f))
            if pts is not None:
                out[i] = pts[:, :2]
            if progress:
                progress(1)
    return out


def landmark_track(model, landmarks68: np.ndarray, *, fps: float, size: tuple[int, int],
                   source: str = "", identity_frames: int = 8, progress=None):
    """A track fitted to per-frame 2-D landmarks only (no optical flow): §5.2 on every frame.

    The identity is fitted jointly-by-averaging over up to ``identity_frames`` frames spread over
    the clip (all modes free), then every frame's pose and the varying modes are fitted with the
    identity fixed, starting from the previous frame. Frames without landmarks are lost.

    Parameters
    ----------
    model : MultilinearModel
    landmarks68 : (F, 68, 2) float
        iBUG-68 pixel positions, NaN where no face.
    fps : float
    size : (W, H)

    Returns
    -------
    Track
    """
    from .init import fit_landmarks

    L = np.asarray(landmarks68, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (68, 2):
        raise ShapeError(f"landmarks must be (F, 68, 2), got {L.shape}")
    n = L.shape[0]
    found = np.isfinite(L).all(axis=(1, 2))
    if not found.any():
        raise VideoError(f"no face found in any frame of {source or 'the video'}")
    idm = model.identity_mode
    good = np.flatnonzero(found)
    pick = good[np.linspace(0, good.size - 1, min(identity_frames, good.size)).round().astype(int)]
    ids = [fit_landmarks(model, L[i], iterations=12).weights[idm] for i in pick]
    wid = np.mean(ids, axis=0)
    R, s, t, W = _fit_frames(model, L, found, idm, wid, progress)
    tr = Track(fps=float(fps), frame_size=tuple(size), rotation=R, scale=s, translation=t,
               weights=W, landmarks2d=np.zeros((n, 68, 2)),
               confidence=found.astype(np.float64), lost=~found,
               model_hash=model.content_hash, mode_names=model.mode_names, source=str(source),
               info={"method": "landmarks"})
    return project_landmarks(tr, model)


def _fit_frames(model, L: np.ndarray, found: np.ndarray, idm: str, wid: np.ndarray, progress):
    """Pose (R (F, 3, 3), s (F,), t (F, 2)) and weights (mode -> (F, r)) of every frame fitted
    to its landmarks ``L`` (F, 68, 2) (§5.2) with the identity ``wid`` fixed, each frame
    starting from the previous one; frames without landmarks (``~found``) keep the previous
    frame's fit, frames before the first detection take its fit."""
    from .init import fit_landmarks

    n = L.shape[0]
    varying = tuple(m for m in model.mode_names if m != idm)
    R = np.tile(np.eye(3), (n, 1, 1))
    s = np.ones(n)
    t = np.zeros((n, 2))
    W = {m: np.tile(model.weight_mean(m), (n, 1)) for m in model.mode_names}
    W[idm][:] = wid
    state = None
    for i in range(n):
        if found[i]:
            if state is None:
                st = fit_landmarks(model, L[i], modes=varying, iterations=10)
                st = st.with_weights(idm, wid)
                state = fit_landmarks(model, L[i], state=st, modes=varying, iterations=8)
            else:
                state = fit_landmarks(model, L[i], state=state, modes=varying, iterations=4)
        if state is not None:
            R[i], s[i], t[i] = state.pose.rotation, state.pose.scale, state.pose.translation
            for m in varying:
                W[m][i] = state.weights[m]
        if progress:
            progress(1)
    first = int(np.flatnonzero(found)[0])  # frames before the first detection take its pose
    R[:first], s[:first], t[:first] = R[first], s[first], t[first]
    for m in varying:
        W[m][:first] = W[m][first]
    return R, s, t, W


class _StageBars:
    """A tracker's ``progress(stage, done, total)`` as one bar per stage (from
    ``progress_factory(desc, total)``, none without it); the bars close with the block."""

    def __init__(self, video, progress_factory) -> None:
        self.name, self.factory, self.bars = Path(video).name, progress_factory, {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.factory is None:
            return
        bar = self.bars.get(stage)
        if bar is None:
            self.close()
            bar = self.bars[stage] = self.factory(f"{self.name}: {stage}", total)
        bar.update(done - bar.n)

    def close(self) -> None:
        for b in self.bars.values():
            b.close()
        self.bars = {}

    def __enter__(self) -> "_StageBars":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _capture(video, model, frames, fps, max_frames, progress_factory, workers: int = 1,
             partial: Path | None = None, subject=None, every: int = 1, eyes: bool = False):
    """The capture tracker (:mod:`facetransfer.track.capture`) on decoded frames; with
    ``partial``, its progress saved there and continued from there (:func:`capture_resuming`);
    ``subject``: of several people, the face nearest this point; ``every``: the detector
    shown one frame of ``every`` (and with ``eyes`` every frame where the eyes move)."""
    from .aspect import View
    from .capture import capture_video

    with _StageBars(video, progress_factory) as stage_progress:
        if partial is None:
            tr = capture_video(frames, model, max_frames=max_frames, progress=stage_progress,
                               source=str(video), workers=workers, view=View.of(video),
                               subject=subject, every=every, eyes=eyes)
        else:
            tr = capture_resuming(video, model, partial, frames=frames[:max_frames],
                                  source=str(video), progress=stage_progress, workers=workers,
                                  best_effort=True,  # the track cache's: never fails the job
                                  subject=subject, detect_every=every, detect_eyes=eyes)
    return dataclasses.replace(tr, fps=float(fps))


def _depends(method: str, video, options, face=None, every: int = 1, eyes: bool = False):
    """What a track of ``method`` depends on beyond the video, frames and model (its cache
    key): the flow tracker's options, the landmark fit's precomputed points file, the capture
    tracker's ``face`` (of several people, which) and detector rate (``every``, and ``eyes``:
    the frames where the eyes move shown too, :mod:`facetransfer.track.skip_rule`)."""
    if method in ("auto", "capture"):
        parts = ([] if face is None else [f"face={face}"]) + \
            ([] if every == 1 else [f"every={int(every)}" + (",eyes" if eyes else "")])
        return ",".join(parts) or None
    if method == "flow":
        return options
    if method == "landmarks":
        from .checkpoint import video_identity

        lmf = landmarks_file(video)
        return None if lmf is None else video_identity(str(lmf))
    return None


def _partial(key: str | None) -> Path | None:
    """The capture's progress file of a cache key, or None (no key, or no cache folder)."""
    try:
        return None if key is None else partial_path(key)
    except OSError:
        return None


def capture_resuming(video, model, partial, *, frames=None, options=None, source=None,
                     fixed=None, progress=None, workers: int = 1, best_effort: bool = False,
                     subject=None, detector_id: str | None = None,
                     save_every: float | None = None, detect_every: int = 1,
                     detect_eyes: bool = False,
                     max_frames: int | None = None):
    """The capture tracker on the file ``video`` (or its decoded ``frames``) with its progress
    kept in ``partial`` (:mod:`facetransfer.track.detect_checkpoint`: the detections, then the
    fit), continued from there when it holds this run's: an interrupted run loses nothing.
    ``best_effort``: a progress file that cannot be written is a warning, not an error;
    ``subject``: of several people, the face nearest this point (the caller keys ``partial``
    by it: its path, or ``detector_id``, the key's detector part,
    :func:`facetransfer.track.detect_checkpoint.face_detector_id`); ``save_every``: seconds
    between the progress file's periodic saves (default the checkpoint's: where a run can be
    stopped only by killing it, e.g. a batch worker, a shorter period loses less);
    ``detect_every``: the detector shown one frame of it, and with ``detect_eyes`` every
    frame where the eyes move (the caller keys ``partial`` by both);
    ``max_frames``: the file's first frames only (``track --max-frames``; keys ``partial``)."""
    from .aspect import View
    from .capture import capture_video
    from .detect_checkpoint import DetectionCheckpoint
    from .video_detect import detect_video

    clip = video if frames is None else frames
    limit = max_frames if frames is None else None      # decoded frames: as many as given
    ck = DetectionCheckpoint.for_video(partial, video, limit if frames is None else len(frames),
                                       detector_id, best_effort=best_effort,
                                       **({} if save_every is None
                                          else {"every": float(save_every)}))
    view = View.of(video)
    saved = ck.load()
    if saved is not None:
        from ..io.frame_numbers import first_number

        log.info("%s: continued an interrupted run from frame %d", source,
                 first_number(video) + saved.detections.n_frames)   # a plate's: its number
    if saved is not None and saved.complete:
        det = saved.detections
    else:
        det = detect_video(clip, source=source, checkpoint=ck, progress=progress,
                           resume=None if saved is None else saved.detections,
                           workers=workers, view=view, subject=subject,
                           every=detect_every, eyes=detect_eyes, max_frames=limit)[0]
    try:
        tr = capture_video(clip, model, options=options, detections=det, source=source,
                           fixed=fixed, checkpoint=ck, progress=progress)
    except KeyboardInterrupt:
        ck.save(det, complete=True)                       # with the fit so far, if it began
        raise
    if saved is None:
        return tr        # said by the commands (info["resumed"]): the run lost nothing
    return dataclasses.replace(tr, info={**tr.info,
                                         "resumed": {"frame": saved.detections.n_frames}})


def obtain_track(video: str | os.PathLike, model, *, frames=None, fps: float | None = None,
                 track_file: str | os.PathLike | None = None, max_frames: int | None = None,
                 method: str = "auto", progress_factory=None, options=None, workers: int = 1,
                 cache: bool = True, face: str | None = None, detect_every: int = 1,
                 detect_eyes: bool = False):
    """The track of a video: read from ``track_file``, or from the track cache, or tracked now.

    ``method``: ``"auto"`` or ``"capture"`` use the capture tracker
    (:func:`facetransfer.track.capture.capture_video`: the model fitted to MediaPipe's points
    and their flow on every frame); ``"flow"`` the optical-flow tracker of §5.1
    (:func:`facetransfer.track.track_video`, configured by ``options``); ``"landmarks"`` fits
    landmarks (precomputed ``NAME.mediapipe478.npz`` next to the video, else MediaPipe).
    ``options`` (a :class:`~facetransfer.track.TrackOptions`, e.g. from
    :func:`facetransfer.track.presets.track_options`) configure the optical-flow tracker
    (default: its own defaults). ``workers``: processes detecting the face for the capture
    tracker (:func:`facetransfer.track.video_detect.detect_video`; 2 when nothing else runs
    beside this track). ``cache``: keep the track made in the user's track cache and reuse
    one kept there (:mod:`facetransfer.track.cache`; the capture tracker's progress is saved
    there too and continued by the next run). ``face``: of several people, the one the capture
    tracker follows (``"left"``, ``"right"``, ``"centre"`` or ``"X,Y"``,
    :func:`facetransfer.track.face_crop.subject_point`). ``detect_every``: the capture
    tracker's detector is shown one frame of it, the frames between interpolated
    (:func:`facetransfer.track.detect.detect_clip`), and with ``detect_eyes`` every frame where
    the eyes move (:mod:`facetransfer.track.skip_rule`); a track of the same clip made showing
    it every frame, if the cache holds one, is taken instead.

    Returns
    -------
    Track
        Of at most ``max_frames`` frames (a longer track file is cut).
    """
    check_track_method(method)
    _check_counts(max_frames, detect_every)
    if face is not None and method not in ("auto", "capture"):
        raise TrackError(f"a face to follow ({face!r}) is for the capture tracker, not the "
                         f"{method} tracker, which follows the face found first")
    if track_file is not None:
        tr = Track.load(track_file)
        tr.check_model(model)
        if max_frames is not None and tr.n_frames > max_frames:
            tr = take_frames(tr, np.arange(max_frames))
        return tr
    from ..io.video import read_video, video_info

    info = video_info(video)
    if frames is None:
        frames, fps = read_video(video, max_frames=max_frames)
    fps = info.fps if fps is None else fps
    n = len(frames) if max_frames is None else min(len(frames), int(max_frames))
    every = int(detect_every) if method in ("auto", "capture") else 1
    eyes = bool(detect_eyes) and every > 1
    key, tr = _kept(video, n, method, (options, face, every, eyes), model) if cache \
        else (None, None)
    if tr is not None:
        log.info("%s: the track of %d frames from the cache", video, n)
        bar = _bar(progress_factory, f"track {Path(video).name} (from the cache)", n)
        if bar is not None:
            bar.update(n)
        _close(bar)
        return dataclasses.replace(tr, fps=float(fps)).with_source_facts(video)
    if method in ("auto", "capture"):
        from .face_crop import subject_point

        subject = None if face is None else subject_point(face, info.size)
        tr = _capture(video, model, frames, fps, max_frames, progress_factory, workers,
                      _partial(key), subject, every, eyes)
    elif method == "flow":
        warn_stored_fit(video, "optical-flow tracker")
        tr = _flow(video, model, frames, fps, max_frames, progress_factory, options)
    else:
        warn_stored_fit(video, "landmark fit")
        size = (frames.shape[2], frames.shape[1]) if hasattr(frames, "shape") else info.size
        tr = _landmarks(video, model, frames, fps, size, progress_factory)
    tr = tr.with_source_facts(video)   # the clip's numbering, kept if the clip moves
    store_track(key, tr)
    return tr


def _kept(video, n: int, method: str, depends: tuple, model):
    """``(key, track)``: the track cache's key of a track of ``video``'s first ``n`` frames
    by ``method`` with :func:`_depends`'s ``(options, face, every, eyes)``, and the track kept
    under it or, for a detector shown fewer frames (``every`` > 1), the better track made
    showing it every frame where one was; None where none is kept."""
    key, every_frame = _keys(video, n, method, depends, model)
    tr = cached_track(every_frame, model)
    return key, (tr if tr is not None else cached_track(key, model))


def _keys(video, n: int, method: str, depends: tuple, model) -> tuple:
    """:func:`_kept`'s two keys: the track's, and for a detector shown fewer frames
    (``every`` > 1) that of the track made showing it every frame (else None)."""
    options, face, every, eyes = depends
    key = track_key(video, n, method, _depends(method, video, options, face, every, eyes), model)
    every_frame = None if every <= 1 else \
        track_key(video, n, method, _depends(method, video, options, face), model)
    return key, every_frame


def _check_counts(max_frames, detect_every) -> None:
    """:func:`obtain_track`'s ``max_frames`` (None or >= 1) and ``detect_every`` (>= 1): a
    ``max_frames`` of 0 was said as "video ... has no frames", a ``detect_every`` of 0 taken
    for 1."""
    if max_frames is not None and int(max_frames) < 1:
        raise TrackError(f"max_frames must be >= 1 (or None: every frame), got {max_frames}")
    if int(detect_every) < 1:
        raise TrackError(f"detect_every must be >= 1 (1: the detector sees every frame), got "
                         f"{detect_every}")


def _flow(video, model, frames, fps, max_frames, progress_factory, options):
    """The optical-flow tracker of §5.1 (:func:`facetransfer.track.track_video`) on decoded
    frames, at the frame rate ``fps`` (an array of frames carries none)."""
    try:
        from .tracker import track_video
    except ImportError:  # pragma: no cover - tracker not installed
        raise RewriteError("the optical-flow tracker (facetransfer.track.track_video) is "
                           "not available") from None
    with _StageBars(video, progress_factory) as stage_progress:
        tr = track_video(frames, model, max_frames=max_frames, progress=stage_progress,
                         source=str(video), options=options)
    if abs(tr.fps - fps) > 1e-9:
        tr = dataclasses.replace(tr, fps=float(fps))
    return tr


def _bar(progress_factory, desc: str, total: int):
    """A bar from ``progress_factory(desc, total)``, or None without a factory."""
    return progress_factory(desc, total) if progress_factory else None


def _close(bar) -> None:
    if bar is not None and hasattr(bar, "close"):
        bar.close()


def _landmarks(video, model, frames, fps, size, progress_factory):
    """A landmark-only fit (:func:`landmark_track`) to the precomputed MediaPipe points next
    to the video (:func:`landmarks_file`), else to MediaPipe's detections now."""
    n = len(frames)
    lmf = landmarks_file(video)
    if lmf is not None:
        from ..io.landmarks import read_mediapipe_landmarks
        from .landmarks import mediapipe_to_ibug

        P = read_mediapipe_landmarks(lmf, n)
        _check_landmarks_fit(lmf, P, n, size)
        L = mediapipe_to_ibug(P[..., :2])
        if L.shape[0] < n:
            L = np.concatenate([L, np.full((n - L.shape[0], 68, 2), np.nan)])
    else:
        cb = _bar(progress_factory, f"landmarks {Path(video).name}", n)
        L = _detect_landmarks(frames, progress=cb.update if cb is not None else None)
        _close(cb)
    cb = _bar(progress_factory, f"fit {Path(video).name}", n)
    try:
        return landmark_track(model, L, fps=fps, size=size, source=str(video),
                              progress=cb.update if cb is not None else None)
    finally:
        _close(cb)


def _check_landmarks_fit(path: Path, P: np.ndarray, n: int, size) -> None:
    """VideoError where the precomputed landmarks ``P`` (F, 478, 3) at ``path`` lie off the
    video's ``size`` ``(W, H)`` frames (by more than half a frame: another clip's, or not
    pixels; before, they were fitted into a wrong track, said nowhere); a warning where they
    cover fewer than the ``n`` frames read (the rest are taken as frames without a face)."""
    W, H = (float(v) for v in size)
    xy = P[..., :2][np.isfinite(P[..., :2]).all(axis=-1)]
    if xy.size and ((xy < [-0.5 * W, -0.5 * H]) | (xy > [1.5 * W, 1.5 * H])).any():
        raise VideoError(f"MediaPipe landmarks file {path} has points off the video's "
                         f"{W:.0f}x{H:.0f} frames (from x {xy[:, 0].min():.0f} to "
                         f"{xy[:, 0].max():.0f}, y {xy[:, 1].min():.0f} to "
                         f"{xy[:, 1].max():.0f}): made for another clip?")
    if len(P) < n:
        log.warning("MediaPipe landmarks file %s has %d frames of the %d read: the rest are "
                    "taken as frames without a face", path, len(P), n)


def done_tracking() -> None:
    """Release what this process keeps for tracking more clips, once a command's tracks are in
    (a transfer's render, a puppet's, needs none of it): the capture's point samplers
    (:func:`facetransfer.track.capture_points.release`, 24.5 MB for the default model, made
    before the fork by :func:`_prepare_child`). A later track in this process makes them
    again in 0.015-0.02 CPU-s (the first time, 0.1-0.15: the core's pages read from its file):
    a second transfer pays no more than the first. Nothing is imported for it (a command whose
    tracks were all read from files)."""
    points = sys.modules.get(f"{__package__}.capture_points")
    if points is not None:
        points.release()


# ---------------------------------------------------------------------------------------------
# a track computed in a forked child process while the parent tracks another video
# ---------------------------------------------------------------------------------------------

class _BackgroundTrack:
    """A track computed in a forked child process (:func:`start_background_track`)."""

    def __init__(self, pool, future, interruptible: bool = False) -> None:
        self._pool, self._future, self._interruptible = pool, future, interruptible

    def result(self):
        """The Track, or None when the child could not run (then the caller tracks itself).

        Errors of the tracking itself (e.g. no face in the video) are raised here."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            return self._future.result()
        except BrokenProcessPool as exc:
            log.warning("background tracking failed (%s); tracking in this process", exc)
            return None
        except BaseException as exc:  # e.g. Ctrl-C: do not wait for the child, or barely
            self.cancel(grace=grace_for(exc))
            raise
        finally:
            self._pool.shutdown(wait=True)

    def cancel(self, *, grace: float = 0.0) -> None:
        """Stop the child (it may be half-way through the video) by SIGKILL
        (:func:`facetransfer.signals.kill_forked`), after up to ``grace`` seconds for it to
        end by itself (:func:`grace_for`). With a grace, the child is sent the Ctrl-C first:
        one sent to this process alone (``kill -INT``, a job runner's stop) reached no child,
        which tracked on until killed, its progress lost; one that reached it already (the
        terminal's) is not taken twice (:func:`facetransfer.signals.interrupted_once`). A second
        interrupt before the kill was under way kills it at once (else this process's exit, and
        :meth:`result`'s, waited for the child's whole track)."""
        from ..signals import kill_forked

        try:
            kill_forked(self._pool, self._future, grace=grace, interrupt=self._interruptible)
        except BaseException:
            kill_forked(self._pool, self._future)
            raise


#: Seconds a background tracker cancelled for a Ctrl-C is given to end by itself before it is
#: killed: the Ctrl-C reached it too (or its parent sends it), and it saves its progress
#: (about 0.1 s) into the cache.
CTRL_C_GRACE = 3.0


def grace_for(exc: BaseException) -> float:
    """The ``grace`` of :meth:`_BackgroundTrack.cancel` for a parent stopped by ``exc``:
    :data:`CTRL_C_GRACE` for a Ctrl-C (which the terminal sent to the child as well, else
    :meth:`_BackgroundTrack.cancel` sends it), else 0 (a SIGTERM to the parent, an error: the
    child is not told to save, and is killed at once)."""
    return CTRL_C_GRACE if type(exc) is KeyboardInterrupt else 0.0


#: (model, video, max_frames, method, options, frames, face) handed to the forked child (not
#: pickled)
_BACKGROUND_JOB: tuple | None = None


def _run_background_job():
    """In the child: :func:`_background_track_job`, its Ctrl-C taken once (saved, not cut
    short by a second one: :func:`facetransfer.signals.interrupted_once`); ended if the parent
    goes (:func:`facetransfer.signals.ended_with_parent`)."""
    from ..signals import ended_with_parent, interrupted_once

    ended_with_parent()
    with interrupted_once():
        return _background_track_job()


def _background_track_job():
    from ..io.video import read_video

    model, video, max_frames, method, options, decoded, face, every, eyes = _BACKGROUND_JOB
    frames, fps = decoded if decoded is not None else read_video(video, max_frames=max_frames)
    return obtain_track(video, model, frames=frames, fps=fps, max_frames=len(frames),
                        method=method, options=options, face=face, detect_every=every,
                        detect_eyes=eyes)


def _prepare_child(video, model, n: int, method: str, depends: tuple) -> None:
    """What the child tracking ``video``'s first ``n`` frames with ``method`` (as
    :func:`obtain_track` with :func:`_kept`'s ``depends``) would make of the model, made here
    before the fork, unless the cache holds that track (the child then makes nothing): the
    capture's tracked points (:func:`facetransfer.track.capture.prepare_points`; this process,
    tracking the other clip the same way, then uses them too)."""
    if method in ("auto", "capture") and not any(holds(k) for k in _keys(video, n, method,
                                                                           depends, model)):
        prepare_fork(model, method)


def prepare_fork(model, method: str) -> None:
    """What :func:`start_background_track` makes of ``model`` before it forks a child tracking
    with ``method`` (the capture's tracked points, :func:`_prepare_child`), made now: by a
    caller whose main thread would otherwise wait, for the clips' decoding
    (:func:`facetransfer.transfer_plan.plan_sources`). The points are kept
    (:func:`facetransfer.track.capture_points.sampler`): the fork finds them made, and this
    process's own capture too. Nothing for the optical flow or the landmarks."""
    if method in ("auto", "capture"):
        from .capture import prepare_points

        prepare_points(model)


def start_background_track(video, model, max_frames: int, *, method: str, options,
                            parallel: bool | None, frames=None,
                            face: str | None = None, detect_every: int = 1,
                            detect_eyes: bool = False) -> _BackgroundTrack | None:
    """Track ``video`` in a forked child process; None when not worth it or not possible.

    ``frames``: its decoded ``(frames, fps)``, inherited by the child (else it decodes them);
    ``face``, ``detect_every`` and ``detect_eyes``: as :func:`obtain_track`'s."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    global _BACKGROUND_JOB
    if method == "landmarks":
        return None
    if parallel is None:
        parallel = (os.cpu_count() or 1) >= 2
    if not parallel or "fork" not in mp.get_all_start_methods():
        return None
    from ..signals import deferred_signals

    _prepare_child(video, model, len(frames[0]) if frames is not None else int(max_frames),
                   method, (options, face, int(detect_every),
                            bool(detect_eyes) and int(detect_every) > 1))
    _BACKGROUND_JOB = (model, video, int(max_frames), method, options, frames, face,
                       int(detect_every), bool(detect_eyes))
    fut, once = None, False
    try:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("fork"))
        # a Ctrl-C in the fork: raised below, not lost in it; the child takes one only
        with deferred_signals(interrupt_once=True) as once:
            fut = pool.submit(_run_background_job)  # forks now: the child sees the job
    except Exception as exc:  # noqa: BLE001 - cannot fork here (e.g. in a daemon process)
        log.info("no background tracking (%s)", exc)
        return None
    except BaseException:           # interrupted as it forked: the child stopped, not awaited
        if fut is not None:
            _BackgroundTrack(pool, fut).cancel()
        raise
    finally:
        _BACKGROUND_JOB = None
    return _BackgroundTrack(pool, fut, once)

"""Step 1 of the capture on a video: its detections, in one process or in two.

:func:`detect_video` decodes a video (a file or an array of frames) once and runs
:func:`facetransfer.track.detect.detect_clip` on it with Face Landmarker in video mode; it
needs no model (a caller may load the model meanwhile).

Face Landmarker runs on one core, and detecting every frame is most of what ``facetransfer
track`` does (:mod:`facetransfer.track.capture`). With ``workers=2`` the clip's frames from
``m`` on are detected by a forked child process while this process detects the frames before
``m``; the two parts are joined in order.

The child starts its own landmarker at frame ``m`` exactly as a resumed run does
(:func:`facetransfer.track.detect.detect_clip` with ``start=m``): it reads the frames before
``m`` and shows the last :attr:`~facetransfer.track.detect.VideoLandmarker.warmup_frames` of them
to the detector (the first of those reached by the container's seek where OpenCV's lands
exactly, :func:`facetransfer.io.video_read.seeks_exactly`: MP4, Matroska, AVI whose frames keep
to their rate; the same frames as decoded in turn, only those from the keyframe before them
decoded, not the whole first half again), so the points of frame ``m`` and after differ from
one process's by about as little as a resumed run's (the class notes measure 0.05 px on average;
up to ~1 px on a long clip). Frame ``m`` has no flow term: its flow would move the parent's
points of frame ``m - 1``, which the child does not have.

When the child cannot run or fails, the parent detects the rest itself (resuming from its own
part), so the result never depends on the fork. An interrupted run keeps only the parent's
frames in its progress file (:mod:`facetransfer.track.detect_checkpoint`): what the child had
detected is detected again when the run continues.
"""

from __future__ import annotations

import logging
import os
from typing import Callable

import numpy as np

from ..errors import ShapeError, TrackError, VideoError
from .aspect import View, to_shown_x
from .detect import ClipDetections, VideoLandmarker, between_detections, detect_clip
from .face_crop import FaceNotAtPoint, FacePoint, FollowingLandmarker, face_box, moved_away
from .options import Progress

log = logging.getLogger(__name__)

__all__ = ["SPLIT_MIN_FRAMES", "SplitDetection", "default_workers", "detect_video", "finish_split",
           "join_detections", "other_face", "split_frame"]

#: fewest frames left to detect for which a second process is worth its start-up (about 1 s:
#: the fork, a landmarker of its own, decoding up to its first frame)
SPLIT_MIN_FRAMES = 200


def default_workers() -> int:
    """Detection processes for a clip tracked with nothing else beside it: 2 on a machine with
    two or more CPUs, else 1."""
    return min(2, os.cpu_count() or 1)


def split_frame(done: int, total: int, workers: int) -> int | None:
    """Where the child's part starts, or None when the clip is detected in one process.

    Parameters
    ----------
    done : int
        Frames already detected (a resumed run's).
    total : int
        Frames of the clip (the container's count: may be approximate).
    workers : int
        Processes allowed (1: no split).
    """
    done, total = int(done), int(total)
    if workers < 2:
        return None
    first = total // 2           # where an uninterrupted run splits
    if total >= SPLIT_MIN_FRAMES and done < first:
        # a run resumed in this process's part: the same child as then, detecting the same
        # frames from the same one (halving the rest instead would show the frames between
        # the two splits with another tracking history, up to 1.1 px off on an 800-frame clip)
        return first
    if total >= SPLIT_MIN_FRAMES and done == first:
        # the first half done, the child's lost: this process continues as the child did (from
        # the same frame, the same warm-up), so those frames come out as they would have
        return None
    left = total - done
    return None if left < SPLIT_MIN_FRAMES else done + left // 2


def join_detections(first: ClipDetections, second: ClipDetections) -> ClipDetections:
    """The detections of two consecutive parts of a clip as one, in order (frames the detector
    was not shown interpolated again across the join: :func:`~.detect.between_detections`)."""
    def cat(a, b):
        if a is None and b is None:
            return None
        if a is None or b is None:
            raise ValueError("join_detections: one part has raw points or scores, the other not")
        return np.concatenate([a, b])

    if first.pixel_aspect != second.pixel_aspect:
        raise ValueError(f"join_detections: parts of pixel aspect {first.pixel_aspect} and "
                         f"{second.pixel_aspect}")
    P, flow = np.concatenate([first.points, second.points]), \
        np.concatenate([first.flow, second.flow])
    raw, S = cat(first.points478, second.points478), _nan_filled((first, second), "scores")
    shown = np.concatenate([np.ones(d.n_frames, bool) if d.shown is None else d.shown
                            for d in (first, second)])
    change = _nan_filled((first, second), "change")
    if not shown.all():
        P, raw, S = between_detections(P, flow, raw, np.full((len(P), 52), np.nan, np.float32)
                                       if S is None else S, ~shown, change)
        S = None if np.isnan(S).all() else S
    return ClipDetections(P, flow, raw, S, first.pixel_aspect, change, shown)


def _nan_filled(parts, name: str):
    """The parts' per-frame array ``name`` (scores, picture change) as one, NaN for a part
    without it; None when no part has it."""
    arrays = [getattr(d, name) for d in parts]
    like = next((a for a in arrays if a is not None), None)
    if like is None:
        return None
    return np.concatenate([np.full((d.n_frames,) + like.shape[1:], np.nan, np.float32)
                           if a is None else a for d, a in zip(parts, arrays)])


#: (video, start, stop, fps, counter, View, subject, every, eyes) handed to the forked child (not
#: pickled)
_JOB: tuple | None = None


def _child_job() -> ClipDetections:
    """In the child: detect frames ``start .. stop`` (or the clip's end) of the video; ended if
    the parent goes (:func:`facetransfer.signals.ended_with_parent`); its Ctrl-C taken inside
    the job only (:func:`facetransfer.signals.interrupted_once`)."""
    from ..signals import ended_with_parent, interrupted_once

    ended_with_parent()
    with interrupted_once():
        return _detect_part()


def _detect_part() -> ClipDetections:
    """:func:`_child_job`'s detection."""
    video, start, stop, fps, counter, view, subject, every, eyes = _JOB
    frames = _child_frames(video, start, stop)
    detector = _child_landmarker(fps, subject)

    def progress(done, total):
        counter.value = max(0, done - start)

    try:
        return detect_clip(view.frames(frames), detector, n_frames=stop, keep478=True,
                           start=start, progress=progress, pixel_aspect=view.aspect, every=every,
                           eyes=eyes)
    except ShapeError:          # the clip ends at ``start``: no frames left for this part
        return None
    finally:
        detector.close()


def _child_frames(video, start: int, stop: int | None):
    """The frames the child reads of ``video`` (a path or an (F, H, W, 3) array) for its part
    ``start .. stop``: frames ``0 .. stop - 1`` in order; of a path, None for those before the
    detector's warm-up (:data:`~.detect.VideoLandmarker.warmup_frames` frames before
    ``start``), which are not decoded where the container's seek is exact (module notes); of an
    array, every one as it is (in memory already)."""
    if isinstance(video, np.ndarray):
        return iter(video[:stop])
    from ..io.video import iter_frames

    warm = max(0, start - VideoLandmarker.warmup_frames)
    return _offset(iter_frames(video, start=warm, stop=stop, seek=True), warm)


def _child_landmarker(fps: float, subject=None) -> FollowingLandmarker:
    """The child's own detector (MediaPipe, video mode, with blendshape scores; a small face
    followed in a crop; of several, the one nearest ``subject``)."""
    return FollowingLandmarker(fps=fps, blendshapes=True, subject=subject)


def _offset(frames, k: int):
    """``frames`` preceded by ``k`` placeholders (never shown to the detector: detect_clip only
    shows the last ``warmup_frames`` frames before its start, and ``k`` leaves exactly those)."""
    for _ in range(k):
        yield None
    yield from frames


class SplitDetection:
    """The later part of a clip, detected in a forked child (:func:`start`)."""

    def __init__(self, pool, future, counter) -> None:
        self._pool, self._future, self._counter = pool, future, counter

    @classmethod
    def start(cls, video, start: int, stop: int | None, fps: float, view: View = View(),
              subject=None, every: int = 1, eyes: bool = False) -> "SplitDetection | None":
        """Fork the child that detects frames ``start .. stop`` of ``video`` (a path or an
        (F, H, W, 3) array), as ``view`` shows them (:class:`facetransfer.track.aspect.View`);
        None where the platform cannot fork. Call it before this process creates its own
        landmarker (MediaPipe's threads do not survive a fork)."""
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        from ..signals import deferred_signals
        from .detect import _import_mediapipe

        global _JOB
        if "fork" not in mp.get_all_start_methods():
            return None
        # imported here, before the fork, so that the child inherits it and imports nothing
        # while another thread of this process (e.g. a model loading) might hold an import lock
        _import_mediapipe()
        ctx = mp.get_context("fork")
        counter = ctx.Value("i", 0, lock=False)
        _JOB = (video, int(start), stop, float(fps), counter, view, subject, int(every),
                bool(eyes))
        pool = fut = None
        try:
            pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx)
            # a Ctrl-C in the fork: raised below, not lost in it; the child takes it inside its
            # job only: one that reached it while it waited for the job, or for the pool's end
            # after it, was raised in the pool's loop and printed its traceback ("Process
            # ForkProcess-1: ... KeyboardInterrupt", 1 of 48 Ctrl-Cs into a 240-frame track)
            with deferred_signals(interrupt_once=True):
                fut = pool.submit(_child_job)       # forks now: the child sees _JOB
        except Exception as exc:  # noqa: BLE001 - cannot fork here (e.g. a daemon process)
            log.info("detecting in one process (%s)", exc)
            return None
        except BaseException:       # interrupted as it forked: the child stopped, not awaited
            if fut is not None:
                cls(pool, fut, counter).cancel()
            raise
        finally:
            _JOB = None
        return cls(pool, fut, counter)

    @property
    def done(self) -> int:
        """Frames the child has detected so far."""
        return int(self._counter.value)

    def result(self, poll: Callable[[int], None] | None = None
               ) -> ClipDetections | None | bool:
        """The child's detections; None when its part had no frames (the clip ended before
        it); False when it failed (the caller then detects them itself).

        ``poll(done)`` is called about five times a second while waiting (a progress bar).
        """
        from concurrent.futures import TimeoutError as FutureTimeout

        try:
            while True:
                try:
                    return self._future.result(timeout=0.2)
                except FutureTimeout:
                    if poll is not None:
                        poll(self.done)
        except Exception as exc:  # noqa: BLE001 - Ctrl-C passes: the caller cancels the child
            log.warning("the second detection process failed (%s: %s); detecting its frames "
                        "here", type(exc).__name__, exc)
            return False
        finally:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def cancel(self) -> None:
        """Stop the child without waiting for it (by SIGKILL,
        :func:`facetransfer.signals.kill_forked`)."""
        from ..signals import kill_forked

        kill_forked(self._pool, self._future)


def finish_split(first: ClipDetections, child: SplitDetection, start: int,
                 redetect: Callable[[ClipDetections], ClipDetections],
                 poll: Callable[[int], None] | None = None, checkpoint=None,
                 first_frame: int = 0) -> ClipDetections:
    """The whole clip's detections from this process's part and the child's.

    Parameters
    ----------
    first : ClipDetections
        Frames ``0 .. start - 1``, detected here (fewer when the clip ended before ``start``).
    child : SplitDetection
        Detecting frames ``start ..``.
    redetect : callable(ClipDetections) -> ClipDetections
        Detects the rest of the clip here, resuming after ``first``, if the child failed or
        followed another face than this process (:func:`other_face`).
    poll : callable(frames done by the child), optional
    checkpoint : object with ``save(ClipDetections)``, optional
        Given ``first`` when interrupted while waiting for the child.
    first_frame : int
        The number of the clip's first frame (a plate's 1001:
        :func:`facetransfer.io.frame_numbers.first_number`), what the info line names the
        child's first frame by.
    """
    if first.n_frames < start:                      # the clip ended in this process's part
        child.cancel()
        return first
    try:
        rest = child.result(poll)
    except KeyboardInterrupt:
        if checkpoint is not None:
            checkpoint.save(first)
        raise
    if rest is False:
        return redetect(first)
    if rest is None:
        return first
    if other_face(first, rest):
        log.info("the second detection process followed another face from frame %d: "
                 "detecting its part again here", start + int(first_frame))
        return redetect(first)
    if poll is not None:
        poll(rest.n_frames)                         # the bar ends at the clip's last frame
    return join_detections(first, rest)


def other_face(first: ClipDetections, rest: ClipDetections) -> bool:
    """Whether the part ``rest`` starts on another face than ``first`` ends with: the face of
    its first frame farther from that of ``first``'s last frame than the face's size
    (:func:`facetransfer.track.face_crop.moved_away`; a clip with several people, whose second
    process chose another person). False where either frame has no face."""
    if not first.n_frames or not rest.n_frames:
        return False
    a, b = first.points[-1], rest.points[0]
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return False
    return moved_away(face_box(b), face_box(a))


def detect_video(video, *, detector=None, max_frames: int | None = None,
                 progress: Progress | None = None, source: str | None = None,
                 resume: ClipDetections | None = None, checkpoint=None, workers: int = 1,
                 view: View | None = None, subject=None, every: int = 1, eyes: bool = False
                 ) -> tuple[ClipDetections, float, tuple[int, int], str]:
    """Step 1 of the module notes on a video: its detections, frame rate, size and source name.

    Needs no model, so a caller may load the model meanwhile. ``resume`` and ``checkpoint``:
    as in :func:`facetransfer.track.detect.detect_clip`. ``workers``: processes running the
    default detector; with 2, the later half of a long enough clip is detected by a forked
    child meanwhile (ignored with ``detector``). ``view``: how the frames are shown to the
    detector (:class:`facetransfer.track.aspect.View`; default a file's own: resampled to
    square pixels, one field of interlaced video; an array as it is); the detections say
    their pixels' aspect (:attr:`~facetransfer.track.detect.ClipDetections.pixel_aspect`). The
    size returned is the stored frames'. ``subject``: of several faces, follow the one nearest
    this point ``(x, y, 0)`` in the stored pixels
    (:func:`facetransfer.track.face_crop.subject_point`; pixels said with no face at or
    near them where the face is chosen: a TrackError naming them, the file and the faces
    found). ``every``: the detector is shown one frame of ``every``, and with ``eyes`` every
    frame where the eyes move (:func:`facetransfer.track.detect.detect_clip`).
    """
    prog = progress or (lambda stage, done, total: None)
    fps, size, src, frames, n, total = _open(video, max_frames, source)
    view = View.of(video) if view is None else view
    subject = _shown_subject(subject, view, resume)
    done = 0 if resume is None else resume.n_frames
    m = split_frame(done, total, workers) if detector is None else None
    child = None if m is None else SplitDetection.start(
        video, m, n, fps, view, None if subject is None else tuple(subject), every, eyes)
    own = None

    def report(d, t):                      # this process's frames, and the child's so far
        d += child.done if child is not None else 0
        prog("detect", d, max(total, d))

    def report_child(c):                   # this process is done: the child's frames
        prog("detect", m + c, max(total, m + c))

    def redetect(first):
        again = view.frames(_open(video, max_frames, source)[3])
        return detect_clip(again, detector, n_frames=n, keep478=True,
                           progress=lambda d, t: prog("detect", d, max(total, d)),
                           resume=first, checkpoint=checkpoint, pixel_aspect=view.aspect,
                           every=every, eyes=eyes)

    try:    # the child cancelled on any interrupt from here, its landmarker's loading too
        if detector is None:
            detector = own = FollowingLandmarker(fps=fps, blendshapes=True, subject=subject,
                                                 still=total == 1)
        det = detect_clip(view.frames(frames), detector,
                          n_frames=n if child is None else m, keep478=True, progress=report,
                          resume=resume, checkpoint=checkpoint, pixel_aspect=view.aspect,
                          every=every, eyes=eyes)
        if child is not None:
            det = finish_split(det, child, m, redetect, report_child, checkpoint,
                               first_frame=_first_number(video))
    except BaseException as exc:
        if child is not None:
            child.cancel()
        if isinstance(exc, FaceNotAtPoint):
            raise TrackError(exc.line(src or "the frames", view.aspect)) from None
        raise
    finally:
        if own is not None:
            own.close()
    return det, fps, size, src


def _shown_subject(subject, view: View, resume: ClipDetections | None):
    """``subject`` (:func:`facetransfer.track.face_crop.subject_point`) in the pixels the
    detector is shown; pixels said kept as said (:class:`~.face_crop.FacePoint`: a face
    must lie there) only where no face is followed yet (the child's part, of a clip's middle,
    gets a plain point: :meth:`SplitDetection.start`; a run resumed after a face was found)."""
    if subject is None:
        return None
    x = float(to_shown_x(subject[0], view.aspect))
    followed = resume is not None and bool(np.isfinite(resume.points).any())
    return FacePoint(x, subject[1], "" if followed else getattr(subject, "said", ""))


def _first_number(video) -> int:
    """The number of ``video``'s first frame: a plate's own (1001), 0 for a video file or
    an array of frames."""
    if not isinstance(video, (str, os.PathLike)):
        return 0
    from ..io.frame_numbers import first_number

    return first_number(video)


def _open(video, max_frames, source):
    """``(fps, (W, H), source, frame iterator, frame count or None, count for a progress bar)``
    of a path (the container's count, maybe approximate) or an array."""
    if isinstance(video, np.ndarray) or (isinstance(video, (list, tuple))):
        arr = np.asarray(video)
        if arr.ndim != 4 or arr.shape[-1] != 3 or arr.shape[0] == 0:
            raise VideoError(f"frames must be (F, H, W, 3) RGB with F >= 1, got {arr.shape}")
        arr = arr[:max_frames] if max_frames is not None else arr
        n = arr.shape[0]
        return 25.0, (arr.shape[2], arr.shape[1]), source or "", iter(arr), n, n
    from ..io.video import iter_frames, video_info

    info = video_info(video)
    total = max_frames if max_frames is not None else max(int(info.n_frames), 0)
    return (info.fps, info.size, source if source is not None else str(video),
            iter_frames(video, stop=max_frames), max_frames, total)

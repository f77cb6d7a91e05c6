"""The plan of a video transfer (Vlasic et al. 2005, §5, §6, Fig. 1): the inputs read and
tracked (or their track files reused) and the new performance made on the target's timeline:
everything the render needs, before any frame is rendered.

* :class:`Source`, :class:`TransferSources`: the video (and optionally its track file, and the
  face to track of several) that gives each attribute of the new performance;
* :func:`plan_transfer` (keywords) and :func:`plan_sources` (:class:`TransferSources`) ->
  :class:`TransferPlan`: reading (:func:`facetransfer.io.video_read.read_video`; the target and the
  expression source decoded at the same time), tracking
  (:func:`facetransfer.track.obtain.obtain_track`; the expression source in a forked process
  while the target is tracked here, the renderer's modules imported and the model's parts of
  the regions made on a thread meanwhile, and the target's eye and jaw regions made for the
  render while the source's track is awaited), then recombining
  (:func:`facetransfer.transfer.recombine`, Fig. 1) or taking a ready performance (a track,
  or a Live Link Face take: :mod:`facetransfer.take`);
* where the mouth's texture comes from: the source of the mouth's motion (visemes, else
  expressions) resampled to the new timeline, the target itself without one, and for a ready
  performance the target's frame whose expression is nearest
  (:func:`facetransfer.texture.function.nearest_frames`).

Rendering a plan and writing the video is :mod:`facetransfer.video_transfer`.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import RewriteError, VideoError
from .io.video_sequence import is_still
from .texture.face import (MouthFunction, mouth_texture_function, resolve_mouth_mode,
                            timeline_mouth_function)
from .rewrite_options import RewriteOptions
from .topology import MeshTopology
from .track import obtain
from .track.presets import DEFAULT_SPEED, DETECT_EVERY, track_options
from .track.video_detect import default_workers
from .track.project import project_landmarks, take_frames
from .texture.function import nearest_frames
from .transfer import constant_weights, recombine, resample_track, time_map

log = logging.getLogger(__name__)

__all__ = [
    "Source",
    "TransferSources",
    "TransferPlan",
    "plan_transfer",
    "plan_sources",
]


# ---------------------------------------------------------------------------------------------
# the inputs: one video (and optionally its track file) per attribute
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Source:
    """One input video of a transfer and, optionally, its track file (reused, not tracked) and
    the face to track of several (``"left"``, ``"right"``, ``"centre"``, ``"X,Y"``;
    :func:`facetransfer.track.face_crop.subject_point`)."""

    video: object
    track: object = None
    face: str | None = None


@dataclass(frozen=True)
class TransferSources:
    """Where each attribute of the new performance comes from (§6, Fig. 1).

    Attributes
    ----------
    target : Source
        The footage rendered into (pose and identity by default).
    expression, viseme, identity, pose : Source or None
        Videos whose expression / viseme / identity / pose replace the target's.
    identity_weights : (r,) array or None
        Identity weights (instead of an identity video).
    performance : Track or path-like or None
        A ready new performance on the target's timeline instead of recombining.
    take_sync : {"timecode", "start"}
        Where an expression source that is a Live Link Face take starts on the target's
        timeline (:data:`facetransfer.take.TAKE_SYNCS`).
    """

    target: Source
    expression: Source | None = None
    viseme: Source | None = None
    identity: Source | None = None
    pose: Source | None = None
    identity_weights: object = None
    performance: object = None
    take_sync: str = "timecode"

    @classmethod
    def of(cls, target, *, target_track=None, expression_from=None, expression_track=None,
           viseme_from=None, viseme_track=None, identity=None, identity_from=None,
           identity_track=None, pose_from=None, pose_track=None, performance=None,
           target_face=None, source_face=None, take_sync: str = "timecode"
           ) -> "TransferSources":
        """The sources from the keywords of :func:`plan_transfer` (a track file without its
        video is ignored; ``source_face``: the face to track in every source video)."""
        if identity is not None and identity_from is not None:
            raise RewriteError("give the identity either as weights or as a video, not both")

        def src(video, track):
            return None if video is None else Source(video, track, source_face)

        from .take import TAKE_SYNCS

        if take_sync not in TAKE_SYNCS:
            raise RewriteError(f"take_sync must be one of {', '.join(TAKE_SYNCS)}, got "
                               f"{take_sync!r}")
        return cls(Source(target, target_track, target_face),
                   src(expression_from, expression_track),
                   src(viseme_from, viseme_track), src(identity_from, identity_track),
                   src(pose_from, pose_track), identity, performance, take_sync)


#: The option that gives each kind of :class:`TransferSources`' track file (the messages').
TRACK_FLAGS = {"target": "--target-track", "expression": "--source-track",
               "viseme": "--viseme-track", "identity": "--identity-track",
               "pose": "--pose-track"}


def check_given_tracks(sources: TransferSources) -> None:
    """RewriteError where a track file given for a clip (:data:`TRACK_FLAGS`) is a
    performance made by a transfer (:attr:`facetransfer.track.Track.made_by`, ``transfer
    --save-track``) rather than that clip's track: the source's expressions on the target's
    head, which taken as the target's made the transfer think the target never opened its
    mouth (a 512² target's mouths measured 0.006 open instead of 0.108, the take's closed
    mouth drawn as the target's open smile; fifty-sixth session). Read before any work; a
    file without the mark is a track as before."""
    for kind, flag in TRACK_FLAGS.items():
        src = getattr(sources, kind)
        if src is None or not isinstance(src.track, (str, os.PathLike)):
            continue
        line = performance_given(src.track, flag, kind, src.video)
        if line:
            raise RewriteError(line)


def performance_given(path, name: str, kind: str, video) -> str | None:
    """The line refusing the track file ``path``, given as ``name`` (an option,
    ``--target-track``, or a ``batch`` manifest's column, ``target_track``) for the ``kind``
    of clip ``video`` (``"target"``, ``"expression"``...), where it is a performance a
    transfer made (:func:`check_given_tracks`); None for a clip's track (a file without the
    mark, :func:`facetransfer.track.result.made_by_of`)."""
    from .track.result import made_by_of, made_by_words

    made = made_by_of(path)
    if not made:
        return None
    what = made_by_words(made)
    whose = "target" if kind == "target" else f"{kind} source"
    perf = "--performance" if name.startswith("--") else "performance"
    return (f"{name} {path} is {what}, not a track of the {whose} {video}: give the clip's own "
            f"track (`facetransfer track {video} --out TRACK.npz`) or leave {name} out (the "
            f"track cache keeps the first run's); to render the performance itself, give it "
            f"as {perf}")


@dataclass(frozen=True)
class TransferPlan:
    """Everything needed to render a transfer (built by :func:`plan_transfer`).

    Attributes
    ----------
    target_frames : (F, H, W, 3) uint8
    fps : float
        The target's frame rate (the output's).
    target_track : Track
    new_track : Track
        The recombined performance on the target's timeline (``n_frames`` <= F).
    mouth_frames : (Fs, Hs, Ws, 3) uint8
        Frames the mouth texture comes from (the expression/viseme source, else the target).
    mouth_track : Track
        Their track resampled to the new timeline.
    mouth_index : (n_frames,) int64
        The mouth frame shown at each output frame.
    source_tracks : dict
        The tracks of the inputs as tracked (``"target"``, ``"expression"``, ...).
    timings : dict
        Seconds spent reading and tracking.
    texture_frames : (Fm, Hm, Wm, 3) uint8 or None
        The clip the mouth texture function (``mouth="function"``) is lifted from: the
        viseme source, else the expression source, else the target; the target for a ready
        performance. None: ``mouth_frames``.
    texture_track : Track or None
        Its own track (one row per frame of ``texture_frames``, not resampled).
    performance : bool
        Whether the new track is a ready (edited) performance rather than a recombination.
    regions : RegionTextures or None
        The target's eye and jaw regions, made while the expression source was still tracked
        (:func:`facetransfer.region_views.region_textures`; the renderer makes them otherwise).
    """

    target_frames: np.ndarray
    fps: float
    target_track: object
    new_track: object
    mouth_frames: np.ndarray
    mouth_track: object
    mouth_index: np.ndarray
    source_tracks: dict
    timings: dict
    texture_frames: np.ndarray | None = None
    texture_track: object = None
    performance: bool = False
    regions: object = None

    def mouth_function(self, model, topo: MeshTopology | None = None, *,
                       progress: Callable[[int], None] | None = None, **kwargs) -> MouthFunction:
        """The mouth texture function lifted from :attr:`texture_frames`
        (:func:`facetransfer.texture.face.mouth_texture_function`; ``kwargs``: ``tex_size``,
        ``step``, ``max_frames``, ``k``, ``on_frames``). ``tex_size`` defaults to ``"auto"``:
        the mouth's square of the UV layout at the face's size in the frames
        (:class:`~facetransfer.texture.face.MouthLayout`), so a 1080p or 4K face's mouth is
        drawn as sharp as the footage (§6)."""
        kwargs.setdefault("tex_size", "auto")
        if self.texture_frames is None or self.texture_track is None:
            return timeline_mouth_function(model, self.mouth_frames, self.mouth_track,
                                           self.mouth_index, self.n_frames, topo,
                                           progress=progress, **kwargs)
        m = min(len(self.texture_frames), self.texture_track.n_frames)
        tr = self.texture_track
        if tr.n_frames > m:
            tr = take_frames(tr, np.arange(m))
        return mouth_texture_function(model, self.texture_frames, tr, topo, progress=progress,
                                      **kwargs)

    @property
    def n_frames(self) -> int:
        return int(self.new_track.n_frames)


def plan_transfer(target, model, *, target_track=None, expression_from=None,
                  expression_track=None, viseme_from=None, viseme_track=None, identity=None,
                  identity_from=None, identity_track=None, pose_from=None, pose_track=None,
                  performance=None, align: str | None = None, max_frames: int | None = None,
                  track_method: str = "auto", speed: str = DEFAULT_SPEED,
                  parallel: bool | None = None, progress_factory=None,
                  reader=None) -> TransferPlan:
    """Read and track the inputs and recombine the performance (§5, §6, Fig. 1, Fig. 7).

    The keywords make the :class:`TransferSources` and the tracking part of the
    :class:`~facetransfer.rewrite_options.RewriteOptions` of :func:`plan_sources`.

    Parameters
    ----------
    target : path-like
        The footage rendered into (pose and identity by default).
    model : MultilinearModel
    target_track, expression_track, viseme_track, identity_track, pose_track : path-like, optional
        Track files to reuse instead of tracking the corresponding video.
    expression_from, viseme_from, identity_from, pose_from : path-like, optional
        Videos whose expression / viseme / identity / pose replace the target's.
    identity : (r,) array, optional
        Identity weights (instead of ``identity_from``).
    performance : Track or path-like, optional
        A ready new performance on the target's timeline (e.g. from ``facetransfer edit``,
        Fig. 7E) instead of recombining; the mouth texture then comes from the target:
        its frame whose expression is nearest (:func:`nearest_frames`, ``mouth="frame"``) or
        the texture function lifted from its frames (``mouth="function"``).
    align : {"trim", "loop", "hold"} or None
        Time alignment of the sources (:func:`facetransfer.transfer.time_map`).
    max_frames : int, optional
        Use only the first N target frames.
    track_method : {"auto", "capture", "flow", "landmarks"}
        See :func:`facetransfer.track.obtain.obtain_track`.
    speed : {"fast", "balanced", "quality"}
        Tracking preset (:func:`facetransfer.track.presets.track_options`) for the videos
        tracked now.
    parallel : bool, optional
        Track the expression source in a second (forked) process while the target is tracked
        here. Default: when the machine has two or more CPUs and the platform can fork. The
        tracks do not depend on it.
    reader : callable(path, max_frames=...) -> (frames, fps), optional
        How videos are decoded: :func:`facetransfer.io.video_read.read_video` (default) or the
        :meth:`~facetransfer.io.prefetch.Prefetch.read_video` of reads started earlier.

    Returns
    -------
    TransferPlan
        The target's frames and track, the new performance on its timeline, where the mouth
        comes from, and the seconds spent reading and tracking; rendered and written by
        :func:`facetransfer.video_transfer.render_plan`.

    Raises
    ------
    VideoError
        No face in the target (or in a whole source); unreadable videos.
    TrackError, TransferError
        Mismatched frame sizes, track files of another model or video.
    """
    sources = TransferSources.of(
        target, target_track=target_track, expression_from=expression_from,
        expression_track=expression_track, viseme_from=viseme_from, viseme_track=viseme_track,
        identity=identity, identity_from=identity_from, identity_track=identity_track,
        pose_from=pose_from, pose_track=pose_track, performance=performance)
    options = RewriteOptions(speed=speed, track_method=track_method)  # before any work
    return plan_sources(sources, model, options=options, align=align, max_frames=max_frames,
                        parallel=parallel, progress_factory=progress_factory, reader=reader)


def plan_sources(sources: TransferSources, model, *, options: RewriteOptions | None = None,
                 align: str | None = None, max_frames: int | None = None,
                 parallel: bool | None = None, progress_factory=None,
                 reader=None) -> TransferPlan:
    """:func:`plan_transfer` for :class:`TransferSources`: read, track, recombine.

    ``options``: its ``speed`` and ``track_method`` shape the tracking of the videos tracked
    now (default :class:`~facetransfer.rewrite_options.RewriteOptions`); ``reader``: see
    :func:`plan_transfer`.
    """
    from .io.video import read_video

    if max_frames is not None and int(max_frames) < 1:
        raise RewriteError(f"max_frames must be >= 1, got {max_frames}")
    check_given_tracks(sources)                 # before any work
    sources = _take_as_performance(sources, align, model)
    options = RewriteOptions() if options is None else options
    planner = _Planner(model, options.track_method, track_options(options.speed),
                       progress_factory, {"read": 0.0, "track": 0.0}, reader or read_video,
                       DETECT_EVERY[options.speed])
    frames, fps, pre_read = planner.read_target(sources, max_frames, _before_fork(
        sources, model, options, parallel))
    # the expression source is tracked in a second (forked) process while this one tracks the
    # target; the child inherits the decoded frames (no second decoding, nothing pickled)
    early = None
    if pre_read is not None and sources.expression.track is None:
        early = obtain.start_background_track(
            sources.expression.video, model, len(pre_read[0]), frames=pre_read,
            method=options.track_method, options=planner.track_options, parallel=parallel,
            face=sources.expression.face, detect_every=planner.every, detect_eyes=True)
    setup = _setup_ahead(model, options) if early is not None else None
    try:
        tt = planner.target_track(sources.target, frames, fps, alone=early is None)
        regions = _regions_ahead(frames, tt, model, options, planner.timings,
                                 _made_ahead(setup)) if early is not None else None
    except BaseException as exc:
        try:
            if early is not None:
                early.cancel(grace=obtain.grace_for(exc))
        finally:    # ended before the error leaves (its rest: 0.45 CPU-s at most), as the
            if setup is not None:           # regions', also on a second interrupt meanwhile
                setup.wait_out()
        raise
    inputs = _Inputs(frames, float(fps), {"target": tt}, {}, planner.timings)
    if regions is None:
        return _planned(planner, inputs, sources, model, align, pre_read, early)
    try:
        plan = _planned(planner, inputs, sources, model, align, pre_read, early, regions.wait)
        _render_ahead(plan, model, options)            # while the regions are made
        return dataclasses.replace(plan, regions=regions.result())
    except BaseException:
        # raised once the regions' thread has ended: nothing of the plan goes on behind the
        # caller (its log lines at the interpreter's exit, its one BLAS thread, its timings),
        # also on a second interrupt meanwhile (Ahead.wait_out)
        regions.wait_out()
        raise


def _planned(planner: "_Planner", inputs: "_Inputs", sources: TransferSources, model, align,
             pre_read, early, quiet: Callable[[], None] | None = None) -> TransferPlan:
    """:func:`plan_sources`' sources read and tracked into ``inputs`` (``pre_read``, ``early``:
    the expression source's frames and forked track) and recombined; ``quiet``: called before
    a source is tracked here (:meth:`_Planner.read_and_track_source`)."""
    for kind in ("expression", "viseme", "pose", "identity"):
        src = getattr(sources, kind)
        if src is not None:
            planner.read_and_track_source(
                inputs, kind, src, pre_read if kind == "expression" else None,
                early if kind == "expression" else None, quiet)
    obtain.done_tracking()              # every track is in: nothing of it kept for the render
    if sources.performance is not None:
        return _performance_plan(inputs, sources, model)
    return _recombined_plan(inputs, sources, model, align)


def _before_fork(sources: TransferSources, model, options: RewriteOptions, parallel):
    """What :func:`plan_sources` makes while the clips decode (its main thread waits for them
    otherwise): what the fork of the expression source's tracker needs made of the model
    (:func:`facetransfer.track.obtain.prepare_fork`, 0.1 CPU-s for the default model, which
    came after the decoding), where that source is to be tracked; None otherwise. (Made for
    nothing where the track cache holds both clips' tracks: the key needs the decoded count.)"""
    import functools

    if sources.expression is None or sources.expression.track is not None or parallel is False:
        return None
    return functools.partial(obtain.prepare_fork, model, options.track_method)


#: The renderer's modules, which the forked tracker of the expression source does not need:
#: imported by :func:`plan_sources` on a thread of their own once it has forked (SciPy's
#: ndimage among them, 0.13-0.15 CPU-s), while this process tracks the target, rather than
#: before the fork, which they delayed (:mod:`facetransfer.video_transfer` imports them where
#: the frames are rendered).
RENDER_MODULES = ("facetransfer.rewrite_clip", "facetransfer.rewrite")


def _setup_ahead(model, options: RewriteOptions):
    """On a daemon thread from now on (:class:`facetransfer.threads.Ahead`), once the
    expression source's tracker is forked and while the target is tracked here: the
    :data:`RENDER_MODULES` imported, and what the target's region textures take of the model
    alone (:func:`_model_parts`), which they then find made (:func:`_regions_ahead`)."""
    from .threads import Ahead

    return Ahead(_render_setup, model, options, name="setup-ahead")


def _render_setup(model, options: RewriteOptions):
    """:func:`_setup_ahead`'s work: the imports, the regions' model parts (returned: ``(topo,
    rig)``, :func:`_model_parts`) and the CIELAB tables (:func:`_lab_tables`)."""
    import importlib

    for name in RENDER_MODULES:
        importlib.import_module(name)
    made = _model_parts(model, options)
    _lab_tables(model, options)
    return made


def _lab_tables(model, options: RewriteOptions) -> None:
    """OpenCV's tables of the CIELAB conversion that the lip colour reads with
    (:func:`facetransfer.lip_colour.rgb_to_lab`; made on a process's first conversion,
    0.05-0.09 s), made now where the render will convert: a mouth from another clip's frame
    (an expression source is tracked) with the target's lip colour. No value changes."""
    try:
        mouth = resolve_mouth_mode(options.mouth, model, performance=False)
    except RewriteError:                    # the render's to say
        return
    if mouth == "frame" and options.lip_colour == "target" and model.landmarks is not None:
        from .lip_colour import rgb_to_lab

        rgb_to_lab(np.zeros((1, 3)))


def _model_parts(model, options: RewriteOptions) -> tuple:
    """``(topo, rig)`` of :func:`facetransfer.region_views.region_textures` with ``options``:
    the model's :func:`facetransfer.topology.mesh_topology` (0.1 CPU-s for the default model:
    its mean face) and, for the eye or jaw region of an ARKit model, its mean person's
    expression rig (:func:`facetransfer.arkit.expression_rig`, 0.04-0.07 CPU-s); None where
    the regions make none."""
    from .arkit import expression_rig, is_arkit_model
    from .region_views import region_modes
    from .threads import one_blas_thread
    from .topology import mesh_topology

    eyes, jaw, _ = region_modes(options, options.texture != "constant")
    with one_blas_thread():               # as the regions' own (the other core is the child's)
        topo = mesh_topology(model)
        rig = expression_rig(model, model.default_weights()) \
            if (eyes or jaw) and is_arkit_model(model) else None
    return topo, rig


def _made_ahead(setup) -> tuple:
    """:func:`_setup_ahead`'s ``(topo, rig)`` once made (waited for: none of its work goes on
    at a later fork), ``(None, None)`` without it or where it failed (the regions then make
    them, and say their error)."""
    if setup is None:
        return None, None
    try:
        return setup.result()
    except Exception:  # noqa: BLE001 - made again by the regions, which raise it there
        return None, None


def _regions_ahead(frames, target_track, model, options: RewriteOptions, timings: dict,
                   made: tuple = (None, None)):
    """The target's eye and jaw region textures for the render with ``options``
    (:func:`facetransfer.region_views.region_textures`), made on a thread of their own
    (:class:`facetransfer.threads.Ahead`) while this one waits for the expression source's
    track from the forked process and recombines (a core idle otherwise; issue 13's 10 s).
    None for a target cut into shots (each its own)."""
    from .threads import Ahead

    if len(target_track.shot_starts):
        return None
    return Ahead(_region_textures, frames, target_track, model, options, timings, made,
                 name="regions-ahead")


def _region_textures(frames, target_track, model, options: RewriteOptions, timings: dict,
                     made: tuple = (None, None)):
    """:func:`_regions_ahead`'s work, timed into ``timings["regions"]``; ``made``: the
    ``(topo, rig)`` of :func:`_model_parts`, or None for either not made."""
    from .region_views import region_textures
    from .threads import one_blas_thread

    t = time.perf_counter()
    # one BLAS thread (as the CLI's commands have from their start, cli.main.SERIAL_POOLS):
    # the other core is the forked process's (0.56 CPU-s instead of 0.9 in the same time;
    # BENCHMARKS.md, "Fortieth session")
    with one_blas_thread():
        regions = region_textures(frames, target_track, model, options, len(frames),
                                  per_frame=options.texture != "constant", topo=made[0],
                                  rig=made[1])
    timings["regions"] = time.perf_counter() - t
    return regions


def _render_ahead(plan: "TransferPlan", model, options: RewriteOptions) -> None:
    """What the render's set-up would do first on the parent's path, done here while the
    region textures are made on their thread (:func:`_regions_ahead`), where it leaves the
    interpreter's lock to them: the model's core contracted with the mouth source's identity
    for the render's meshes of it (:class:`facetransfer.frame_meshes.FrameMeshes`; kept by the
    model, 0.1 s for the default model). It changes no value the render computes. (OpenCV's
    CIELAB tables, made here before, are made during the target's track: :func:`_lab_tables`.)"""
    from .frame_meshes import FrameMeshes

    try:
        mouth = resolve_mouth_mode(options.mouth, model, performance=plan.performance)
    except RewriteError:                    # the render's to say, as before
        return
    if mouth != "frame" or plan.mouth_frames is plan.target_frames:
        return
    FrameMeshes(model, {"source": plan.mouth_track}, plan.n_frames).basis("source")


def _take_as_performance(sources: TransferSources, align, model) -> TransferSources:
    """``sources`` with an expression source that is a Live Link Face take
    (:mod:`facetransfer.take`) as the ready performance it makes once the target is tracked;
    a take drives the target alone, a model of ARKit expressions (checked before any work)."""
    from .arkit import is_arkit_model
    from .take import Take, is_take

    if sources.expression is None or not is_take(sources.expression.video):
        return sources
    path = sources.expression.video
    if not is_arkit_model(model):
        raise RewriteError(f"a Live Link Face take ({path}) drives a model whose expressions "
                           "are ARKit blendshapes (the default model, 'ict-arkit')")
    beside = {"a viseme source": sources.viseme is not None,
              "an identity": sources.identity is not None or sources.identity_weights is not None,
              "a pose source": sources.pose is not None,
              "a ready performance": sources.performance is not None,
              "a source track": sources.expression.track is not None}
    for what, given in beside.items():
        if given:
            raise RewriteError(f"a Live Link Face take ({path}) drives the target's expression "
                               f"alone; it cannot be combined with {what}")
    from .io.video_display import timecode_of
    from .io.video_sequence import is_sequence

    start = None       # a photo has no timecode: it performs the take from its first row
    if sources.take_sync == "timecode" and not is_still(sources.target.video) and (
            Path(sources.target.video).is_file() or is_sequence(sources.target.video)):
        start = timecode_of(sources.target.video)
    return dataclasses.replace(sources, expression=None,
                               performance=Take(Path(path), align, start))


@dataclass(frozen=True)
class _Inputs:
    """The decoded inputs of a plan: the target's frames and frame rate, and per kind
    (``"target"``, ``"expression"``, ...) the track and (sources) the frames; the seconds
    spent reading and tracking."""

    frames: np.ndarray
    fps: float
    tracks: dict
    source_frames: dict
    timings: dict

    @property
    def size(self) -> tuple[int, int]:
        return self.frames.shape[2], self.frames.shape[1]


@dataclass(frozen=True)
class _Planner:
    """The reading and tracking steps of :func:`plan_sources`; ``timings`` accumulates the
    seconds spent reading and tracking; ``every``: the clips' detector is shown one frame of
    it (:data:`facetransfer.track.presets.DETECT_EVERY`), a source's also every frame where
    the eyes move (its blinks are the performance's)."""

    model: object
    track_method: str
    track_options: object
    progress_factory: object
    timings: dict
    reader: Callable
    every: int = 1

    def read_target(self, sources: TransferSources, max_frames,
                    meanwhile: Callable[[], None] | None = None):
        """``(frames, fps, pre_read)``: the target's frames and, with an expression source,
        that source's ``(frames, fps)`` decoded at the same time on a second thread and cut to
        the frames the target's timeline needs (else None); ``meanwhile``: called while they
        decode, with an expression source."""
        from .io.prefetch import frames_covering, frames_to_cover
        from .io.video import video_info

        read_video = self.reader
        t0 = time.perf_counter()
        target = sources.target.video
        if sources.expression is None:
            frames, fps = read_video(target, max_frames=max_frames)
            self.timings["read"] += time.perf_counter() - t0
            held = performance_length(sources.performance, max_frames) \
                if is_still(target) and len(frames) == 1 else None
            if held is not None:   # a photo performs a ready track (a take) at its rate
                return held_frames(frames[0], held[0]), held[1], None
            return frames, fps, None
        from concurrent.futures import ThreadPoolExecutor

        expression_from = sources.expression.video
        still = is_still(target)   # a photo: performs the whole source (its first max_frames)
        with ThreadPoolExecutor(max_workers=2) as pool:
            ft = pool.submit(read_video, target, max_frames=max_frames)
            fs = pool.submit(read_video, expression_from, max_frames=max_frames if still else
                             frames_to_cover(target, expression_from, max_frames))
            if meanwhile is not None:
                meanwhile()
            frames, fps = ft.result()
            sfr, sfps = fs.result()
        if still and len(frames) == 1:
            self.timings["read"] += time.perf_counter() - t0
            return held_frames(frames[0], len(sfr)), sfps, (sfr, sfps)
        si = video_info(expression_from)
        need = frames_covering(len(frames), fps, sfps)
        if len(sfr) < need and len(sfr) < si.n_frames:  # the containers' counts were short
            sfr, sfps = read_video(expression_from, max_frames=need)
        self.timings["read"] += time.perf_counter() - t0
        return frames, fps, (sfr[:need], sfps)

    def track(self, video, track_file, frames, fps, limit, *, alone: bool = False,
              face: str | None = None, every: int = 1, eyes: bool = False):
        """The track of ``video`` (:func:`facetransfer.track.obtain.obtain_track`, of several
        people the ``face``, its detector shown one frame of ``every`` and with ``eyes`` every
        frame where the eyes move), timed; ``alone``: nothing else is tracked meanwhile, so its
        detection may take two processes (:func:`facetransfer.track.video_detect.
        detect_video`)."""
        t = time.perf_counter()
        workers = default_workers() if alone else 1
        tr = obtain.obtain_track(video, self.model, frames=frames, fps=fps,
                                 track_file=track_file, max_frames=limit,
                                 method=self.track_method,
                                 progress_factory=self.progress_factory,
                                 options=self.track_options, workers=workers, face=face,
                                 detect_every=every, detect_eyes=eyes)
        self.timings["track"] += time.perf_counter() - t
        return tr

    def target_track(self, target: Source, frames, fps, *, alone: bool = False):
        """The target's track, checked against its frames (a face somewhere)."""
        n, H, W = frames.shape[:3]
        n_held = n if n > 1 and is_still(target.video) else 0  # the photo tracked once, held
        if n_held:
            frames, n = frames[:1], 1
        tt = self.track(target.video, target.track, frames, fps, n, alone=alone,
                        face=target.face, every=self.every)
        if target.track is not None:
            tt.check_video(n if tt.n_frames >= n else tt.n_frames, (W, H),
                           what=f"target {target.video}")
            _warn_other_source(tt, target.video, "target")
            if tt.n_frames < n:
                raise RewriteError(f"target track {target.track} has {tt.n_frames} frames, the "
                                   f"target video {n}: give --max-frames {tt.n_frames} to "
                                   "rewrite the frames it covers")
        if tt.lost.all():
            raise VideoError(f"no face found in the target {target.video}")
        return held_track(tt, n_held, fps) if n_held else tt

    def read_and_track_source(self, inputs: _Inputs, kind: str, src: Source, pre_read,
                              early, quiet: Callable[[], None] | None = None) -> None:
        """Read and track a source (``pre_read``: its decoded frames; ``early``: its track
        from the background process) into ``inputs``; ``quiet``: called before the source is
        tracked here, with nothing beside it (its detection forks a second process): the
        region textures' thread waited for (:func:`plan_sources`)."""
        from .io.prefetch import frames_covering
        from .io.video import video_info

        need = frames_covering(len(inputs.frames), inputs.fps, video_info(src.video).fps)
        t = time.perf_counter()
        fr, sfps = pre_read if pre_read is not None else self.reader(src.video, max_frames=need)
        self.timings["read"] += time.perf_counter() - t
        tr = None
        if early is not None:
            t = time.perf_counter()
            tr = early.result()  # None: the background job failed to run; track here
            self.timings["track"] += time.perf_counter() - t
            if tr is not None and len(fr) < tr.n_frames:
                tr = take_frames(tr, np.arange(len(fr)))
        if tr is None:                       # tracked here, after the target: nothing beside it
            if quiet is not None and src.track is None:     # a track file: read, no fork
                quiet()
            tr = self.track(src.video, src.track, fr, sfps, len(fr), alone=True,
                            face=src.face, every=self.every, eyes=True)
        checked = _checked_source(kind, src, fr, tr)     # a track of other frames: its error
        if src.track is not None:
            _warn_other_source(tr, src.video, kind)
        inputs.tracks[kind], inputs.source_frames[kind] = checked


def held_frames(frame: np.ndarray, n: int) -> np.ndarray:
    """A photo's frame ``(H, W, 3) uint8`` as the target's ``n`` frames ``(n, H, W, 3)``: one
    read-only view of it (no copy; 1008 frames of a 1080p photo would be 6.3 GB), so that a
    photo as the target performs the whole expression source, its own pixels in every frame
    (and its texture, lifted from each, the same)."""
    frame = np.asarray(frame)
    return np.broadcast_to(frame[None], (max(int(n), 1), *frame.shape))


def performance_length(performance, max_frames: int | None = None):
    """``(n_frames, fps)`` of a ready performance (a track file or
    :class:`~facetransfer.track.Track`: ``transfer --save-track`` of a photo's, edited; or a
    Live Link Face take, :class:`~facetransfer.take.Take`: its rows at their rate, as ``view``
    and ``puppet`` number them, :func:`facetransfer.take.take_length`) that a photo as the
    target performs, as it performs an expression source (:func:`held_frames`), its first
    ``max_frames``; None: none. (Before, a take onto a photo was one frame, its first row.)"""
    from .take import Take, take_length
    from .track import Track

    if performance is None:
        return None
    if isinstance(performance, Take):
        return take_length(performance.path, max_frames)
    perf = performance if isinstance(performance, Track) else Track.load(performance)
    n = perf.n_frames if max_frames is None else min(perf.n_frames, int(max_frames))
    return n, float(perf.fps)


def held_track(track, n: int, fps: float):
    """A photo's track of one frame held over ``n`` frames at ``fps`` (the expression
    source's rate): its pose, identity and expression in every frame of :func:`held_frames`
    (the expression is then the source's, :func:`facetransfer.transfer.recombine`)."""
    return dataclasses.replace(take_frames(track, np.zeros(int(n), np.int64)), fps=float(fps))


def _warn_other_source(track, video, role: str) -> None:
    """Say so when a given track was made from a video of another name than ``video`` (a
    renamed copy is fine; another clip of the same size would drive the wrong face)."""
    track.warn_other_video(video, "its motion drives the wrong face" if role in (
        "target", "performance") else "it drives the wrong head pose" if role == "pose"
        else "it does not follow that video's frames", role)


def _checked_source(kind: str, src: Source, fr, tr):
    """``(track, frames)`` of a source: a track file of another frame size refused, the
    frames cut to the track, a face somewhere (a pose source of another frame size is moved
    into the target's by :func:`facetransfer.transfer.recombine`)."""
    if src.track is not None and tuple(tr.frame_size) != (fr.shape[2], fr.shape[1]):
        raise RewriteError(f"{kind} track {src.track} is for {tr.frame_size[0]}x"
                           f"{tr.frame_size[1]} frames but {src.video} is "
                           f"{fr.shape[2]}x{fr.shape[1]}")
    if tr.n_frames < len(fr):
        fr = fr[:tr.n_frames]
    if tr.lost.all():
        raise VideoError(f"no face found in the {kind} source {src.video}")
    if tr.lost.any():
        log.info("%s source %s: face lost in %d frames (those keep the original frame)",
                 kind, src.video, int(tr.lost.sum()))
    return tr, fr


def _identity_weights(inputs: _Inputs, sources: TransferSources, model):
    """The new identity: the weights given, the identity source's (mean over its frames), or
    None (the target's)."""
    if "identity" not in inputs.tracks:
        return sources.identity_weights
    return constant_weights(inputs.tracks["identity"], model.identity_mode)


def _performance_plan(inputs: _Inputs, sources: TransferSources, model) -> TransferPlan:
    """The plan of a ready performance: the mouth from the target's frame whose expression is
    nearest (:func:`nearest_frames`)."""
    from .take import Take
    from .track import Track

    if set(inputs.tracks) != {"target"} or sources.identity_weights is not None:
        raise RewriteError("a ready performance (--performance) excludes the other sources")
    perf, tt, frames, n = sources.performance, inputs.tracks["target"], inputs.frames, \
        len(inputs.frames)
    if isinstance(perf, Take):
        new = perf.performance(tt, model)
    else:
        new = perf if isinstance(perf, Track) else Track.load(perf)
    new = _as_performance(new)
    new.check_model(model)
    W, H = inputs.size
    if tuple(new.frame_size) != (W, H):
        raise RewriteError(f"performance is for {new.frame_size[0]}x{new.frame_size[1]} "
                           f"frames, the target {sources.target.video} is {W}x{H}")
    if new.n_frames > n:
        new = take_frames(new, np.arange(n))
    elif new.n_frames < n and not isinstance(perf, Take):   # as a short --target-track
        raise RewriteError(f"performance {new.label} has {new.n_frames} frames, the target "
                           f"video {sources.target.video} {n}: give --max-frames "
                           f"{new.n_frames} to rewrite the frames it covers")
    if not isinstance(perf, Take):
        _warn_other_source(new, sources.target.video, "performance")
    varying = [m for m in model.mode_names if m != "identity"] or list(model.mode_names)
    q = np.concatenate([new.weights[m] for m in varying], axis=1)
    b = np.concatenate([tt.weights[m] for m in varying], axis=1)
    j = nearest_frames(q, b, ~tt.lost)
    mt = take_frames(tt, j)
    tex_frames, tex_track = _lifted_once(frames, tt, sources.target.video)
    # the chosen frames' geometry, seen by their own cameras (texture lookup)
    return TransferPlan(frames, inputs.fps, tt, new, frames, mt, j, inputs.tracks,
                        inputs.timings, texture_frames=tex_frames, texture_track=tex_track,
                        performance=True)


def _as_performance(track):
    """``track`` marked as a transfer's new performance (:attr:`facetransfer.track.Track.
    made_by`; one marked already keeps its mark): what ``--save-track`` writes is then told
    from a clip's track (:func:`check_given_tracks`)."""
    from .track.result import MADE_BY_TRANSFER

    return track if track.made_by else dataclasses.replace(track, made_by=MADE_BY_TRANSFER)


def _lifted_once(frames, target_track, target) -> tuple:
    """``(frames, track)`` the mouth's texture function of a ready performance is lifted from:
    the target's; of a photo held over ``n`` frames (:func:`held_frames`), its one frame
    (before, up to 120 copies of it were lifted, 27 of a 240-frame take's 44 s on a photo, for
    the texture of one picture)."""
    if len(frames) > 1 and is_still(target):
        return frames[:1], take_frames(target_track, np.zeros(1, np.int64))
    return frames, target_track


def _recombined_plan(inputs: _Inputs, sources: TransferSources, model, align) -> TransferPlan:
    """The plan of a recombination (:func:`facetransfer.transfer.recombine`, Fig. 1): the
    mouth texture from the source of the mouth's motion (visemes, else expressions), else the
    target's own mouth."""
    tracks, frames, fps, n = inputs.tracks, inputs.frames, inputs.fps, len(inputs.frames)
    tt = tracks["target"]
    new = recombine(tt, expression=tracks.get("expression"), viseme=tracks.get("viseme"),
                    identity=_identity_weights(inputs, sources, model), pose=tracks.get("pose"),
                    align=align)
    new = _as_performance(project_landmarks(new, model))
    mouth_kind = "viseme" if "viseme" in tracks else ("expression" if "expression" in tracks
                                                      else None)
    if mouth_kind is None:
        mouth_frames, mouth_track = frames, take_frames(tt, np.arange(new.n_frames))
        mouth_index = np.arange(new.n_frames)
        tex_frames, tex_track = frames, tt
    else:
        ms = tracks[mouth_kind]
        tm = time_map(ms.n_frames, ms.fps, n, fps, align=align)
        mouth_track = take_frames(resample_track(ms, tm), np.arange(new.n_frames))
        mouth_frames = inputs.source_frames[mouth_kind]
        mouth_index = tm.nearest[:new.n_frames]
        tex_frames, tex_track = mouth_frames, ms
    return TransferPlan(frames, fps, tt, new, mouth_frames, mouth_track,
                        np.asarray(mouth_index, np.int64), tracks, inputs.timings,
                        texture_frames=tex_frames, texture_track=tex_track)

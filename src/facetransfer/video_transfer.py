"""The video transfer job (Vlasic et al. 2005, §6, Fig. 7): a planned transfer rendered back
into the target footage and written with the target's audio.

* :func:`render_plan`: the frames of a :class:`~facetransfer.transfer_plan.TransferPlan`
  rewritten (:func:`facetransfer.rewrite_clip.rewrite_frames`) and written (through the render
  cache's parts, :func:`facetransfer.render_cache.parts_writer`, or
  :func:`facetransfer.io.video.write_video_with_audio`);
* :func:`transfer_video`: the outputs checked before any work, the plan made
  (:func:`facetransfer.transfer_plan.plan_sources`), rendered and written, and optionally the
  new track and its meshes saved, and the matte of the pixels the rewrite changed
  (:mod:`facetransfer.io.matte`) written beside the output.

The plan (reading, tracking, recombining) is :mod:`facetransfer.transfer_plan`;
:func:`~facetransfer.transfer_plan.plan_transfer`, :class:`~facetransfer.transfer_plan.TransferPlan`
and :class:`~facetransfer.transfer_plan.TransferSources` are importable from here too.

The writer goes through the render cache (:mod:`facetransfer.render_cache`): an interrupted
render continues where it stopped (as the puppet's of :mod:`facetransfer.puppet_video`).

The renderer's modules (:data:`facetransfer.transfer_plan.RENDER_MODULES`: SciPy's ndimage
among them) are imported where the frames are rendered, not with this module: a transfer
imports this one before it forks the expression source's tracker, which needs none of them
(:func:`facetransfer.transfer_plan.plan_sources` imports them on a thread after the fork).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import RewriteError
from .io.ahead import ordered_ahead
from .io.output_names import is_one_image
from .io.video_sequence import is_still
from .io.plate_output import plate_output
from .io.video_like import like_video
from .rewrite_options import RewriteOptions
from .texture.face import MouthFunction, resolve_mouth_mode
from .transfer_plan import TransferPlan, TransferSources, plan_sources, plan_transfer  # noqa: F401

log = logging.getLogger(__name__)

__all__ = [
    "TransferSources",
    "TransferPlan",
    "plan_transfer",
    "TransferResult",
    "RenderResult",
    "RenderTarget",
    "render_plan",
    "render_frame",
    "transfer_video",
    "write_mesh_sequence",
]


@dataclass(frozen=True)
class TransferResult:
    """What :func:`transfer_video` wrote.

    Attributes
    ----------
    path : Path
    n_frames : int
    n_rewritten : int
        Frames where the face was rendered (the others keep the original).
    audio : bool
        Whether the target's audio was muxed in.
    plan : TransferPlan
    timings : dict
        Seconds per stage (read, track, render, write).
    resumed : int
        Frames rendered by an interrupted run and taken up by this one.
    kept : str or None
        What the output kept of its target beyond the colour, as the summary line says it
        (``"with the plate's alpha"``, ...: :mod:`facetransfer.io.plate_output`); None: the
        colour alone.
    matte : Path or None
        The matte written (``matte``), or None.
    """

    path: Path
    n_frames: int
    n_rewritten: int
    audio: bool
    plan: TransferPlan
    timings: dict
    resumed: int = 0
    kept: str | None = None
    matte: Path | None = None


def write_mesh_sequence(folder: str | os.PathLike, track, model, *, overwrite: bool = True) -> int:
    """Write the performance's meshes as ``frame_00000.obj`` ... (model faces), atomically each."""
    from .io.mesh import write_mesh

    d = Path(folder)
    d.mkdir(parents=True, exist_ok=True)
    for i in range(track.n_frames):
        V = model.synthesize(track.weights_at(i))
        write_mesh(d / f"frame_{i:05d}.obj", V, np.asarray(model.faces), uvs=model.uvs,
                   overwrite=overwrite)
    return track.n_frames


@dataclass(frozen=True)
class RenderTarget:
    """The video a render writes (:func:`render_plan`): where, encoded how, and what it keeps
    of its target.

    Attributes
    ----------
    path : path-like
        The video or image sequence (``frames/%05d.png``) to write, atomically.
    audio_from : path-like, optional
        The target video: its audio is kept, and (without a ``compose`` of the render) its
        pixel aspect ratio and colour matrix (:func:`facetransfer.io.video_like.like_video`); an
        OpenEXR plate's floats, a 16-bit plate's values, its alpha
        (:mod:`facetransfer.io.plate_output`).
    video_options : VideoOptions, optional
        Codec and CRF (:class:`facetransfer.io.video.VideoOptions`; default H.264, CRF 18).
    overwrite : bool
        Replace an existing ``path`` (and ``matte``).
    matte : path-like, optional
        Also write the matte of the pixels the rewrite changed, frame by frame, as an image
        sequence (``matte/%05d.png``, ``.tif``, ``.exr``) or a video (``.mp4``, ``.mov``,
        ``.mkv``), numbered and timed as ``path`` (:mod:`facetransfer.io.matte`); the frames
        are rendered with it only when asked.
    sound_from : path-like, optional
        The video whose audio is kept instead of ``audio_from``'s: a photo's rewrite (a target
        without sound, performing its expression source's frames) keeps that source's.
    """

    path: object
    audio_from: object = None
    video_options: object = None
    overwrite: bool = False
    matte: object = None
    sound_from: object = None

    @property
    def sound(self):
        """The video whose audio is kept: ``sound_from``, else ``audio_from``."""
        return self.audio_from if self.sound_from is None else self.sound_from


@dataclass(frozen=True)
class RenderResult:
    """What :func:`render_plan` wrote.

    Attributes
    ----------
    timings : dict
        The plan's timings plus ``mouth`` (if lifted), ``render`` and ``write`` seconds.
    n_rewritten : int
        Frames where the face was rendered.
    audio : bool
        Whether audio was muxed in.
    resumed : int
        Frames an interrupted run had rendered and this one took up (``resume``).
    kept : str or None
        As :attr:`TransferResult.kept`.
    """

    timings: dict
    n_rewritten: int
    audio: bool
    resumed: int = 0
    kept: str | None = None


def render_plan(plan: TransferPlan, model, output: RenderTarget, *,
                options: RewriteOptions | None = None, progress_factory=None,
                compose: Callable | None = None, resume: bool = False) -> RenderResult:
    """Render a planned transfer into the video ``output`` (§6), timing each stage.

    Lifts the mouth texture function first when the mouth mode is ``"function"`` (from
    :attr:`TransferPlan.texture_frames`), then rewrites every frame
    (:func:`facetransfer.rewrite_clip.rewrite_frames`) and writes the video with the audio of
    ``output.audio_from`` as the frames come.

    Parameters
    ----------
    plan : TransferPlan
    model : MultilinearModel
    output : RenderTarget
        The video to write (atomically), its codec and its target.
    options : RewriteOptions, optional
        A mouth of None is :func:`facetransfer.texture.face.default_mouth_mode`'s.
    compose : callable(i, RewriteFrame) -> (H', W', 3) uint8, optional
        The frame to write for output frame ``i`` (default: the rewritten image).
    resume : bool
        Write the output (no ``compose``) through the render cache
        (:mod:`facetransfer.render_cache`) until it is complete: a video in parts, an image
        sequence frame by frame. A run interrupted here leaves them, and the same render run
        again continues after the last frame they hold (the output's or ``output.matte``'s,
        whichever holds fewer: each writes the frames it lacks).

    Returns
    -------
    RenderResult
    """
    if compose is not None and output.matte is not None:
        raise RewriteError(f"the matte {output.matte} is of a transfer's own frames: not "
                           "written with composed ones")
    options = RewriteOptions() if options is None else options
    options = options.with_(mouth=resolve_mouth_mode(options.mouth, model,
                                                     performance=plan.performance))
    out, audio_from, overwrite = output.path, output.audio_from, output.overwrite
    video_options = output.video_options
    if compose is None:
        video_options = like_video(video_options, audio_from, out)
    timings = dict(plan.timings)
    n = plan.n_frames
    key = _render_key(plan, model, out, options, video_options) \
        if resume and compose is None else None
    writer = _parts_writer(key, plan, out, video_options, output.sound, overwrite)
    start = skip = 0 if writer is None else writer.done
    with contextlib.ExitStack() as stack:
        if writer is not None:  # parts kept on an error or interrupt, joined on success
            stack.enter_context(writer)
        matte = None            # committed before the output (the stack's order)
        if output.matte is not None:
            matte = stack.enter_context(_matte_writer(key, plan, output.matte, video_options,
                                                      overwrite))
            start = min(start, matte.done)
        mouth_fn = None
        if options.mouth == "function" and start < n:
            t = time.perf_counter()
            mouth_fn = _lift_mouth(plan, model, progress_factory)
            timings["mouth"] = time.perf_counter() - t
        bar = progress_factory("render", n) if progress_factory else None
        if bar is not None:
            stack.callback(bar.close)
            bar.update(start)
        render = _Frames(plan, model, options, mouth_fn, compose, bar, start,
                         None if compose is not None else
                         plate_output(out, audio_from, video_options, start), matte)
        t0 = time.perf_counter()
        audio = _write_frames(stack, render, writer, skip, output, video_options)
    if writer is not None:
        audio, render.rewritten = writer.result.audio, writer.marked
    timings["render"] = render.seconds
    timings["write"] = time.perf_counter() - t0 - render.seconds
    return RenderResult(timings, render.rewritten, audio, start,
                        getattr(render.grading, "kept", None))


def _write_frames(stack: contextlib.ExitStack, render: "_Frames", writer, skip: int,
                  output: RenderTarget, video_options) -> bool | None:
    """Write the frames of ``render`` into ``output.path``: through ``writer`` (the render
    cache's) from frame ``skip`` on (a render continued from an earlier frame for the matte
    writes each frame once), else in one piece with the audio. Returns whether audio was
    muxed in (None: ``writer``'s, said when it is closed)."""
    if writer is None:
        from .io.video import write_video_with_audio

        frames = stack.enter_context(contextlib.closing(render()))
        return write_video_with_audio(output.path, frames, render.plan.fps,
                                      audio_from=output.sound, overwrite=output.overwrite,
                                      options=video_options, n_frames=render.plan.n_frames)
    # closed here on an error (its render threads joined), not by the collector
    frames = stack.enter_context(contextlib.closing(render.with_faces()))
    for i, (frame, face) in enumerate(frames, render.start):
        if i >= skip:
            writer.write(frame, marked=face)
    return None


@dataclass
class _Frames:
    """The rewritten frames of a plan from ``start`` on
    (:func:`~facetransfer.rewrite_clip.rewrite_frames`), timed and counted: ``seconds`` spent
    rendering, ``rewritten`` frames that show a face; with what
    each output frame keeps of its target beyond the colour (``grading``:
    :func:`facetransfer.io.plate_output.plate_output`); each frame's matte written by
    ``matte`` (:class:`facetransfer.io.matte.MatteWriter`), if given."""

    plan: TransferPlan
    model: object
    options: RewriteOptions
    mouth_fn: object
    compose: Callable | None
    bar: object
    start: int
    grading: object = None    # facetransfer.io.plate_output.plate_output's
    matte: object = None
    seconds: float = 0.0
    rewritten: int = 0

    def with_faces(self):
        """Yield ``(frame, whether a face was rendered)``."""
        from .rewrite_clip import MouthSource, RenderRun, rewrite_frame_parts, rewrite_frames

        p = self.plan
        if self.start >= p.n_frames:
            return
        mouth = MouthSource(p.mouth_frames, p.mouth_track, p.mouth_index, self.mouth_fn,
                            own=p.performance)
        run = RenderRun(progress=self.bar.update if self.bar is not None else None,
                        start=self.start)
        keywords = {"mouth_source": mouth, "options": self.options, "run": run,
                    "regions": p.regions}
        it = rewrite_frame_parts(p.target_frames, p.target_track, p.new_track, self.model,
                                 **keywords) if self._parts else \
            rewrite_frames(p.target_frames, p.target_track, p.new_track, self.model,
                           matte=self.matte is not None, **keywords)
        if self.grading is None:
            frames = ((frame, face) for _, frame, face in self._composed(it))
        else:                          # graded on threads, a few frames ahead of the writer
            frames = ordered_ahead(self._graded, self._composed(it), ahead=4, workers=2)
        try:
            for frame, face in frames:
                self.rewritten += face
                yield frame, face
        finally:
            # the render and grading threads joined here, not when the collector finds the
            # generators (a Ctrl-C while they end would be "Exception ignored in ...")
            try:
                frames.close()
                it.close()
            finally:                   # a video's alpha decoder (io.plate_alpha.VideoAlpha)
                getattr(self.grading, "close", lambda: None)()

    @property
    def _parts(self) -> bool:
        """Whether the frames are rendered as their face's boxes
        (:func:`~facetransfer.rewrite_clip.rewrite_frame_parts`) and only the composite is
        pasted into each: neither a ``compose`` nor the
        matte looks at the rest of a whole :class:`~facetransfer.rewrite.RewriteFrame`."""
        return self.compose is None and self.matte is None

    def _composed(self, it):
        """``(i, frame, face)`` of each output frame, the rendering timed."""
        from .rewrite import paste_image

        parts = self._parts
        for i in range(self.start, self.plan.n_frames):
            t = time.perf_counter()
            r = next(it)
            if parts:    # (box, crop) or None: the composite pasted, nothing else
                frame, face = paste_image(np.asarray(self.plan.target_frames[i]), r)
                self.seconds += time.perf_counter() - t
                yield i, frame, face
                continue
            frame = r.image if self.compose is None else self.compose(i, r)
            self.seconds += time.perf_counter() - t
            if self.matte is not None:
                self.matte.write(i, r.matte)
            yield i, frame, bool(r.face_mask.any())

    def _graded(self, i: int, frame, face: bool):
        return self.grading(i, np.asarray(self.plan.target_frames[i]), frame), face

    def __call__(self):
        """Yield the frames."""
        with contextlib.closing(self.with_faces()) as frames:
            for frame, _ in frames:
                yield frame


def _render_key(plan: TransferPlan, model, out, options, video_options) -> str | None:
    """The render cache's key of rendering ``plan`` into ``out``
    (:func:`facetransfer.render_cache.render_key`); None: the cache is off."""
    from .io.video import is_image_pattern
    from .render_cache import render_key

    return render_key(plan, model, options, video_options, images=is_image_pattern(out))


def _frame_size(plan: TransferPlan) -> tuple[int, int]:
    first = np.asarray(plan.target_frames[0])
    return first.shape[1], first.shape[0]


def _parts_writer(key: str | None, plan: TransferPlan, out, video_options, audio_from,
                  overwrite: bool):
    """A writer for ``out`` in the render cache's folder of ``key`` that keeps what it
    wrote when interrupted (:func:`facetransfer.render_cache.parts_writer`); None: no key
    (the cache is off), or another process renders the same frames now."""
    from .render_cache import parts_writer

    return parts_writer(key, out, plan.fps, _frame_size(plan), plan.n_frames,
                        video_options=video_options, audio_from=audio_from,
                        overwrite=overwrite)


def _matte_writer(key: str | None, plan: TransferPlan, matte, video_options, overwrite: bool):
    """The :class:`~facetransfer.io.matte.MatteWriter` of ``matte``, the matte of the output
    written with ``video_options``: through the render cache's folder of its own
    (:func:`facetransfer.render_cache.matte_key`) beside the output's of ``key``, else in one
    piece."""
    from .io.matte import MatteWriter, matte_options
    from .io.video import VideoWriter, is_image_pattern
    from .render_cache import matte_key, parts_writer

    opts, size = matte_options(video_options, matte), _frame_size(plan)
    writer = parts_writer(matte_key(key, opts, images=is_image_pattern(matte)), matte,
                          plan.fps, size, plan.n_frames, video_options=opts,
                          overwrite=overwrite)
    if writer is None:
        writer = VideoWriter(matte, plan.fps, size, options=opts, overwrite=overwrite,
                             n_frames=plan.n_frames)
    return MatteWriter(writer, matte, size)


def _lift_mouth(plan: TransferPlan, model, progress_factory) -> MouthFunction:
    """The plan's mouth texture function (:meth:`TransferPlan.mouth_function`), with a bar
    of the frames it lifts (made once their count is known: ``"auto"`` lifts fewer than
    :data:`~facetransfer.texture.face.MOUTH_MAX_FRAMES` of a large face; before, the bar's
    total was 120 for the 83 frames of a 4K mouth)."""
    if progress_factory is None:
        return plan.mouth_function(model)
    bars = []
    try:
        return plan.mouth_function(
            model, progress=lambda n: bars[0].update(n),
            on_frames=lambda total: bars.append(progress_factory("mouth texture", total)))
    finally:
        for bar in bars:
            bar.close()


def _check_outputs(out, *, video_options, save_track, meshes_dir, overwrite: bool,
                   matte=None, inputs=()) -> None:
    """The outputs of :func:`transfer_video` can be written (before any work)."""
    from .io.atomic import check_output_path
    from .io.output_names import check_one_image
    from .io.video import check_video_output

    named = [(n, Path(p).resolve()) for n, p in (("--out", out), ("--save-track", save_track),
                                                  ("--meshes", meshes_dir), ("--matte", matte))
             if p is not None]
    for i, (a, pa) in enumerate(named):   # one path for two outputs: found before any work
        for b, pb in named[i + 1:]:
            if pa == pb:
                raise RewriteError(f"{b} {pb} is also {a}: give each output its own name")
    if is_one_image(out):
        if matte is not None:
            raise RewriteError(f"the matte {matte} is written beside a video or an image "
                               f"sequence, not beside the one image {out}")
        check_one_image(out, overwrite=overwrite, inputs=inputs)
    else:
        check_video_output(out, video_options, overwrite=overwrite)
    if save_track is not None:
        check_output_path(save_track, overwrite=overwrite)
    if meshes_dir is not None:
        from .io.output_names import check_meshes_folder

        check_meshes_folder(meshes_dir, overwrite=overwrite)
    if matte is not None:
        from .io.matte import check_matte_output

        check_matte_output(matte, out=out, options=video_options, overwrite=overwrite,
                           inputs=inputs)


def _source_files(sources: TransferSources) -> list:
    """The files a transfer reads (videos, tracks, a performance's file)."""
    files = [sources.performance] if isinstance(sources.performance, (str, os.PathLike)) else []
    for s in (sources.target, sources.expression, sources.viseme, sources.identity,
              sources.pose):
        if s is not None:
            files += [p for p in (s.video, s.track) if isinstance(p, (str, os.PathLike))]
    return files


def _frames_for(out, frame: int | None, max_frames: int | None, still: bool) -> int | None:
    """The target frames a transfer into ``out`` plans: for one image of ``frame`` of a
    photo's (``still``), the source's up to it (not tracked further for one image); of a
    clip's, ``max_frames`` (its regions' frames chosen among them all, as the whole rewrite
    chooses them); ``frame`` refused for another output."""
    if frame is None or not still and is_one_image(out):
        return max_frames
    if not is_one_image(out):
        raise RewriteError(f"frame {frame} chooses the frame of one image (result.png), not "
                           f"of {out}: give max_frames for the first N frames")
    if int(frame) < 0 or max_frames is not None and int(frame) >= int(max_frames):
        raise RewriteError(f"frame {frame} is not among the first {max_frames} frames"
                           if max_frames is not None else f"frame must be >= 0, got {frame}")
    return int(frame) + 1


def render_frame(plan: TransferPlan, model, i: int, *, options: RewriteOptions | None = None,
                 progress_factory=None) -> tuple[np.ndarray, bool]:
    """Frame ``i`` of a planned transfer alone, rewritten as :func:`render_plan` rewrites it
    (the regions chosen among all the plan's frames): ``((H, W, 3) uint8, whether a face was
    rendered)``."""
    options = RewriteOptions() if options is None else options
    options = options.with_(mouth=resolve_mouth_mode(options.mouth, model,
                                                     performance=plan.performance))
    if not 0 <= int(i) < plan.n_frames:
        raise RewriteError(f"frame {i} is not one of the transfer's {plan.n_frames} frames")
    mouth_fn = _lift_mouth(plan, model, progress_factory) \
        if options.mouth == "function" else None
    render = _Frames(plan, model, options, mouth_fn, None, None, int(i))
    with contextlib.closing(render.with_faces()) as frames:
        frame, face = next(frames)
    return np.asarray(frame), bool(face)


def _one_image(plan: TransferPlan, model, out, frame: int | None, *, options, overwrite,
               save_track, meshes_dir, progress_factory) -> TransferResult:
    """The transfer written as the one image ``out``: its only frame, or ``frame`` (counted
    from 0; the plan's frames :func:`_frames_for`'s); the track and meshes of that frame."""
    from .io.atomic import write_image
    from .track.project import take_frames

    n, p = plan.n_frames, Path(out)
    if frame is None and n > 1:
        raise RewriteError(f"output {out} is one image, but the transfer has {n} frames: "
                           f"choose one (frame=0..{n - 1}), or write an image sequence "
                           f"({p.with_name(p.stem + '_%05d' + p.suffix)}) or a video")
    i = 0 if frame is None else int(frame)
    if i >= n or frame is not None and frame < 0:
        raise RewriteError(f"frame {i} is beyond the transfer's {n} frames (0-{n - 1})")
    t = time.perf_counter()
    image, face = render_frame(plan, model, i, options=options,
                               progress_factory=progress_factory)
    timings = dict(plan.timings, render=time.perf_counter() - t)
    write_image(out, image, overwrite=overwrite)
    one = take_frames(plan.new_track, np.array([i]))
    if save_track is not None:
        one.save(save_track, overwrite=overwrite)
    if meshes_dir is not None:
        write_mesh_sequence(meshes_dir, one, model)
    return TransferResult(p, 1, int(face), False, plan, timings)


def _sound_of(sources: TransferSources, plan: TransferPlan):
    """The video whose audio a transfer keeps where it is not the target's: a photo's (a
    target without sound held over its expression source's frames), that source's; None: the
    target's."""
    from .take import is_take

    if is_still(sources.target.video) and sources.expression is not None \
            and not is_take(sources.expression.video) and plan.n_frames > 1:
        return sources.expression.video
    return None


def transfer_video(sources: TransferSources, out, model, *,
                   options: RewriteOptions | None = None, overwrite: bool = False,
                   meshes_dir=None, save_track=None, progress_factory=None, video_options=None,
                   align: str | None = None, max_frames: int | None = None,
                   parallel: bool | None = None, reader=None, matte=None,
                   frame: int | None = None) -> TransferResult:
    """The whole video rewrite (§6): plan (read, track, recombine), render, write with audio.

    The inputs are ``sources`` (:class:`TransferSources`, e.g.
    ``TransferSources.of(target, expression_from=...)``), with the target's audio; how they
    are tracked and rendered is ``options``
    (:class:`~facetransfer.rewrite_options.RewriteOptions`). ``align``, ``max_frames``,
    ``parallel``, ``reader``: see :func:`plan_transfer`. The output video (and the
    optional track and meshes) appear only when everything succeeded; an existing ``out`` is
    replaced only with ``overwrite=True``. With the mouth mode ``"function"`` the function is
    lifted from :attr:`TransferPlan.texture_frames`. ``video_options``: codec and CRF of
    ``out`` (:class:`facetransfer.io.video.VideoOptions`); ``out`` may be an image sequence
    (``frames/%05d.png``), or one image (``result.png``, ``.jpg``, ``.tif``: a one-frame
    transfer's frame, or with ``frame`` that frame of the transfer, :func:`render_frame`). A
    photo as the target (``portrait.jpg``) with an expression source performs all the
    source's frames at its rate, with its audio
    (:func:`facetransfer.transfer_plan.held_frames`; a Live Link Face take's rows at their
    rate, without audio); a photo's one image is its frame 0 by
    default. A video file is rendered in parts kept in the render cache
    (:mod:`facetransfer.render_cache`): an interrupted transfer run again renders only the
    frames it had not. ``matte``: also write the matte of the pixels the rewrite changed
    (:attr:`RenderTarget.matte`), numbered, timed and continued as ``out``.

    Returns
    -------
    TransferResult
    """
    if not isinstance(sources, TransferSources):   # a path here failed as an AttributeError
        raise RewriteError(f"transfer_video takes a TransferSources as its sources, got "
                           f"{type(sources).__name__} {sources!r}: give "
                           "TransferSources.of(target, expression_from=...), or call "
                           "plan_transfer(target, model, ...) and render_plan")
    _check_outputs(out, video_options=video_options, save_track=save_track,
                   meshes_dir=meshes_dir, overwrite=overwrite, matte=matte,
                   inputs=_source_files(sources))  # before any work
    opts = RewriteOptions() if options is None else options
    resolve_mouth_mode(opts.mouth, model, performance=sources.performance is not None)
    still = is_still(sources.target.video)
    if frame is None and is_one_image(out) and still:
        frame = 0                      # a photo's rewrite: its first frame (the source's)
    max_frames = _frames_for(out, frame, max_frames, still)
    plan = plan_sources(sources, model, options=opts, align=align, max_frames=max_frames,
                        parallel=parallel, progress_factory=progress_factory, reader=reader)
    if is_one_image(out):
        return _one_image(plan, model, out, frame, options=opts, overwrite=overwrite,
                          save_track=save_track, meshes_dir=meshes_dir,
                          progress_factory=progress_factory)
    output = RenderTarget(out, sources.target.video, video_options, overwrite, matte,
                          sound_from=_sound_of(sources, plan))
    rendered = render_plan(plan, model, output, options=opts,
                           progress_factory=progress_factory, resume=True)
    if save_track is not None:
        plan.new_track.save(save_track, overwrite=overwrite)
    if meshes_dir is not None:
        write_mesh_sequence(meshes_dir, plan.new_track, model)
    return TransferResult(Path(out), plan.n_frames, rendered.n_rewritten, rendered.audio, plan,
                          rendered.timings, rendered.resumed, rendered.kept,
                          None if matte is None else Path(matte))

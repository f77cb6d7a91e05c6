"""Puppetry (Vlasic et al. 2005, the abstract and §8: "performance animation (puppetry)"): a
model identity driven by a track, written as a video or an image sequence through the render
cache (:mod:`facetransfer.render_cache`), so an interrupted render continues where it stopped."""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = ["puppet_video"]


def puppet_video(track, model, identity: np.ndarray, out, *, video_options=None,
                 audio_from=None, overwrite: bool = False,
                 progress_factory=None) -> tuple[bool, int]:
    """Write the puppet video (or image sequence) ``out`` of ``track`` driving the identity
    weights ``identity`` of ``model`` (:func:`facetransfer.transfer.puppet_frames`, the paper's
    puppetry) with the audio of ``audio_from``, through the render cache
    (:func:`facetransfer.render_cache.parts_writer`): an interrupted run keeps the frames
    written, and the same call renders only the rest.

    Returns
    -------
    (bool, int)
        Whether the audio was muxed in, and the frame an interrupted render continued from
        (0: rendered whole).
    """
    from .io.video import is_image_pattern, write_video_with_audio
    from .render_cache import parts_writer, puppet_key
    from .transfer import puppet_frames

    n = track.n_frames
    key = puppet_key(track, model, identity, video_options, images=is_image_pattern(out))
    writer = parts_writer(key, out, track.fps, tuple(track.frame_size), n,
                          video_options=video_options, audio_from=audio_from,
                          overwrite=overwrite)
    start = 0 if writer is None else writer.done
    frames = puppet_frames(track, model, identity, start=start)
    bar = progress_factory("render", n) if progress_factory else None
    with contextlib.ExitStack() as stack:
        if bar is not None:
            stack.callback(bar.close)
            bar.update(start)
        if writer is None:
            return write_video_with_audio(out, _counted(frames, bar), track.fps,
                                          audio_from=audio_from, overwrite=overwrite,
                                          options=video_options, n_frames=n), 0
        with writer:  # parts kept on an error or interrupt, joined on success
            for f in _counted(frames, bar):
                writer.write(f, marked=True)
    return writer.result.audio, start


def _counted(frames, bar):
    """Yield ``frames``, counting each on ``bar`` (a progress bar, or None) once taken."""
    for f in frames:
        yield f
        if bar is not None:
            bar.update(1)

"""Puppetry (Vlasic et al. 2005, the abstract and §8: "performance animation (puppetry)"): a
model identity driven by a track, rendered frame by frame (:func:`puppet_frames`: Eq. (5) seen
by the track's camera, its eyes and mouth painted by :mod:`facetransfer.puppet_face`) and
written as a video or an image sequence through the render cache
(:mod:`facetransfer.render_cache`, :func:`puppet_video`), so an interrupted render continues
where it stopped. ``facetransfer puppet`` writes it; the demo's take panel shows its frames."""

from __future__ import annotations

import contextlib
from typing import Iterator

import numpy as np

__all__ = ["puppet_frames", "puppet_video"]


def puppet_frames(track, model, identity: np.ndarray, *, size: tuple[int, int] | None = None,
                  background=(40, 40, 48), identity_mode: str = "identity",
                  color=None, start: int = 0) -> Iterator[np.ndarray]:
    """Drive a synthetic actor (an identity of the model) with a tracked performance.

    Each frame renders Eq. (5) with ``identity`` and the track's other weights, seen by the
    track's camera, Lambert-shaded on a plain background, with the mouth gap and eye holes
    closed: the eye holes show eyeballs turned by the frame's eyeLook* activations (straight
    ahead for a track without ARKit activations), an open mouth a dark cavity with the upper
    teeth, a shut eye or mouth a line (:mod:`facetransfer.puppet_face`), all occluded by the
    lids and lips. A frame where the face was lost shows its nearest tracked frame (the
    earlier on ties; :func:`facetransfer.track.project.held_lost`), as ``facetransfer export``
    writes it and the capture tracker stores it: not a KLT track's drifting state there.
    ``start``: yield frames ``start`` to the end only (those of a whole run: a render
    continued after an interrupt).

    Parameters
    ----------
    track : Track
    model : MultilinearModel
    identity : (r,) float64
    size : (W, H), optional
        Default: the track's frame size.
    background : (3,) colour
    color : (3,) colour, optional
        The skin's; default :data:`facetransfer.puppet_face.SKIN` (the previews' palette).

    Yields
    ------
    (H, W, 3) uint8
    """
    from .puppet_face import SKIN, paint_face, puppet_face, track_gaze
    from .render import render
    from .topology import close_mouth, mesh_topology
    from .track.project import nearest_tracked
    from .transfer import TransferError

    size = tuple(track.frame_size) if size is None else (int(size[0]), int(size[1]))
    r = model.ranks[model.mode_index(identity_mode)]
    wid = np.asarray(identity, dtype=np.float64).ravel()
    if wid.shape != (r,):
        raise TransferError(f"identity weights must have {r} values, got {wid.shape}")
    bg = np.broadcast_to(np.asarray(background, np.uint8), (size[1], size[0], 3)).copy()
    sx = size[0] / track.frame_size[0]
    sy = size[1] / track.frame_size[1]
    # a solid head: the mouth gap and the eye holes closed, their fills painted as a mouth
    # cavity and eyeballs (facetransfer.puppet_face)
    topo = mesh_topology(model, lips=False)
    # the identity drawn sets the eyes' shut gap (puppet_face.face_shut_gaps: the expression
    # is not read; a track has a frame at least, lost or not, its weights finite)
    face = puppet_face(model, topo, gaze=track_gaze(track),
                       weights={**track.weights_at(0), identity_mode: wid})
    n_all = topo.n_closed + len(topo.eye_loops)
    colors = np.broadcast_to(np.asarray(SKIN if color is None else color, np.float64),
                             (n_all, 3))

    def draw(i: int) -> np.ndarray:
        w = track.weights_at(i)
        w[identity_mode] = wid
        # the identity contracted once (model.py); the eye loops' centres appended
        V = face.vertices(close_mouth(model.synthesize(w), topo))
        cam = track.camera(i)
        if (sx, sy) != (1.0, 1.0):
            cam = type(cam)(cam.scale * np.sqrt(sx * sy), cam.rotation,
                            cam.translation * np.array([sx, sy]), cam.pixel_aspect)
        out = render(V, face.faces, cam, size, colors=colors, background=bg)
        paint_face(out.image, out.raster, V, cam, face, i)
        return out.image

    # a lost frame shows its nearest tracked one (held_lost's rule, as the exports write it,
    # whichever tracker), each drawn once for a run of lost frames around it
    near, shown = nearest_tracked(track.lost), (-1, bg)
    for i in range(max(0, int(start)), track.n_frames):
        if int(near[i]) != shown[0]:
            shown = (int(near[i]), draw(int(near[i])))
        yield shown[1]


def puppet_video(track, model, identity: np.ndarray, out, *, video_options=None,
                 audio_from=None, overwrite: bool = False,
                 progress_factory=None) -> tuple[bool, int]:
    """Write the puppet video (or image sequence) ``out`` of ``track`` driving the identity
    weights ``identity`` of ``model`` (:func:`puppet_frames`, the paper's
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

"""A clip rewritten (Vlasic et al. 2005, §6, Fig. 7): the rewrite of one frame
(:mod:`facetransfer.rewrite`) run over every frame of a target clip.

:func:`rewrite_frames` checks the clip and, for each shot of the target, builds a
:class:`_ClipRenderer` that holds what the frames share: the target's face texture for the whole
clip (``texture="constant"``) or the way to lift each frame's, the mouth's texture (the source's
frames or the texture function of §6), the eye and jaw regions' reference frames
(:mod:`facetransfer.region_views`), the meshes of the new performance, the target and the source
made a few frames at a time (:class:`facetransfer.frame_meshes.FrameMeshes`), the source's lip
residual (:mod:`facetransfer.lips`), the target's lip colour (:mod:`facetransfer.lip_colour`)
and the new gaze (:mod:`facetransfer.eyeballs`). The renderer rewrites frame ``i`` with
:func:`facetransfer.rewrite.rewrite_frame_part`, once per view of the eye and jaw regions, and
mixes the views. Frames are independent: they are rendered here, on threads or in forked
processes (each sends back the face's box only), and yielded in order.

The whole job (reading, tracking, recombining, writing) is :mod:`facetransfer.video_transfer`.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, §6, Fig. 7.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from .errors import RewriteError
from .eyeballs import track_gaze
from .region_views import RegionTextures, blend_renders, region_modes, region_textures, views_at
from .frame_meshes import FrameMeshes
from .eyes import EyeTexture
from .face_scale import shot_scale
from .jaw import JawTexture
from .lip_colour import SAMPLES as LIP_SAMPLES, LipTint, lip_ratio, lip_vertex_weights
from .lips import LipResidual, clip_lip_residual, displace_lips, mouth_width_ratio, warp_uvs
from .mouth import mouth_ring_faces
from .mouth_inside import DrawnInside, drawn_inside
from .monochrome import is_monochrome, monochrome_changes
from .texture.function import attribute_vector
from .texture.face import (FaceTexture, MouthFunction, constant_face_texture, frame_uvs,
                           merged_face_texture, mouth_texture_function, resolve_mouth_mode,
                           timeline_mouth_function)
from .rewrite import FrameTextures, RewriteFrame, paste_part, rewrite_frame_part
from .rewrite_options import RewriteOptions
from .topology import MeshTopology, close_mouth, mesh_topology

log = logging.getLogger(__name__)

__all__ = ["MouthSource", "RenderRun", "rewrite_frame_parts", "rewrite_frames"]


@dataclass(frozen=True)
class MouthSource:
    """Where the mouth of a rewritten clip is textured from (§6): the frames of the source of
    the mouth's motion seen through its own track, or the texture function of §6.

    Attributes
    ----------
    frames : sequence of (Hs, Ws, 3) uint8, optional
        The source's frames (the viseme source, else the expression source); without them (or
        without ``track``) the mouth is the target's unless the texture function is queried.
    track : Track, optional
        The source's track resampled to the new timeline (the new performance's frame count).
    index : (F,) int, optional
        The source frame shown at each output frame (default ``arange``).
    function : MouthFunction, optional
        With ``mouth="function"``: the texture function to query (default: lifted from
        ``frames``, else from the target's).
    own : bool
        The mouth's texture comes from the target's own frames, which show another performance
        than the new one (a ready performance, a Live Link Face take: ``frames`` are the
        target's, ``function`` lifted from them): where the new mouth opens wider than they
        ever show, its inside is drawn (:mod:`facetransfer.mouth_inside`). False: the frames
        are the source's, whose mouth opens as the new one does.
    """

    frames: object = None
    track: object = None
    index: np.ndarray | None = None
    function: MouthFunction | None = None
    own: bool = False


@dataclass(frozen=True)
class RenderRun:
    """How the frames of a clip are rendered: which frames, on how many workers, reported how;
    frame ``i`` is the same whatever these are.

    Attributes
    ----------
    workers : int, optional
        Threads or processes rendering frames in parallel (default: 2, or 1 on a single CPU;
        BLAS on one thread while they run, :func:`_render`).
    processes : bool, optional
        With ``workers > 1``: in forked processes where the platform can (each sends back
        the face's box), not threads; default threads (as fast on 2 cores: BENCHMARKS.md).
    progress : callable(int), optional
        Called with 1 after each frame.
    start : int
        The first frame to yield (a render continued).
    """

    workers: int | None = None
    processes: bool | None = None
    progress: Callable[[int], None] | None = None
    start: int = 0


def rewrite_frames(target_frames, target_track, new_track, model, *,
                   mouth_source: MouthSource | None = None, options: RewriteOptions | None = None,
                   topo: MeshTopology | None = None, run: RenderRun | None = None,
                   regions: RegionTextures | None = None, matte: bool = False
                   ) -> Iterator[RewriteFrame]:
    """Rewrite every target frame with the new performance (§6, Fig. 7); each shot of an
    edited target (``target_track.shot_starts``) as a clip of its own.

    Parameters
    ----------
    target_frames : (F, H, W, 3) uint8 or sequence of frames
    target_track : Track
        The target's own track (texture lifting).
    new_track : Track
        The new performance on the target's timeline (:func:`facetransfer.transfer.recombine`),
        at most ``F`` frames; its lost frames keep the original frame.
    model : MultilinearModel
    mouth_source : MouthSource, optional
        Where the mouth is textured from (default: no source, the target's own mouth or, with
        ``mouth="function"``, the texture function lifted from the target).
    options : RewriteOptions, optional
        Default :class:`RewriteOptions`. Its ``texture``: the target's face texture, the
        current frame's (default: it keeps the frame's own lighting; better on synthetic
        truth, ``benchmarks/bench_transfer.py``) or one for the whole clip (the paper's
        choice). Its ``mouth``: the mouth's texture (lips and the closed gap); None or
        ``"frame"``: the source frame shown at this time (``mouth_source.index``) warped
        through the source's own geometry (none without a source); ``"function"``: the
        texture function of §6 (:func:`facetransfer.texture.face.mouth_texture_function`)
        queried with the *new* performance's attribute vector at every frame; needs model UVs.
        Its ``blend``, ``feather``, ``erode``: :class:`~facetransfer.rewrite_options.
        BlendOptions` of :func:`facetransfer.rewrite.rewrite_frame`.
    topo : MeshTopology, optional
        The model's (default :func:`facetransfer.topology.mesh_topology`).
    run : RenderRun, optional
        The frames to yield and the workers that render them (default :class:`RenderRun`:
        every frame, two threads where there are two CPUs); the output does not depend on it.
    regions : RegionTextures, optional
        The region textures made ahead, if of the clip (:class:`RegionTextures`).
    matte : bool
        Give each frame's :attr:`~facetransfer.rewrite.RewriteFrame.matte` too (computed only
        when asked; all 0 where the face is lost).

    Yields
    ------
    RewriteFrame
        Frames ``run.start`` to ``new_track.n_frames - 1``.
    """
    return _rewrite(target_frames, target_track, new_track, model, mouth_source=mouth_source,
                    options=options, topo=topo, run=run, regions=regions, matte=matte)


def rewrite_frame_parts(target_frames, target_track, new_track, model, **keywords
                        ) -> Iterator[tuple | None]:
    """:func:`rewrite_frames`' frames (its arguments, but ``matte``) on the face's box only:
    ``(box, RewriteFrame)`` of each, or None (the frame unchanged; :meth:`_ClipRenderer.part`).
    What a caller that needs the composite alone pastes itself
    (:func:`facetransfer.rewrite.paste_image`), without the whole frame's rendered face and
    masks."""
    return _rewrite(target_frames, target_track, new_track, model, parts=True, **keywords)


def _rewrite(target_frames, target_track, new_track, model, *, mouth_source=None, options=None,
             topo=None, run=None, regions=None, matte: bool = False, parts: bool = False):
    """:func:`rewrite_frames` (``parts``: :func:`rewrite_frame_parts`), shot by shot."""
    opts = options or RewriteOptions()
    mouth_source = MouthSource() if mouth_source is None else mouth_source
    run = RenderRun() if run is None else run
    n, start = new_track.n_frames, int(run.start)
    if not 0 <= start <= n:
        raise RewriteError(f"start frame {start} is outside the {n} frames")
    from .track.shots import shots_from

    whole = (target_frames, target_track,
             np.arange(n) if mouth_source.index is None else mouth_source.index)
    for a, b, (frames, tt, new, st, si) in shots_from(start, n, target_frames, target_track,
                                                      new_track, mouth_source.track,
                                                      mouth_source.index):
        shot_mouth = dataclasses.replace(mouth_source, track=st, index=si)
        one = _ClipRenderer.build(frames, tt, new, model, opts, mouth_source=shot_mouth,
                                  regions=regions, topo=topo, whole=whole)
        if matte:
            one = dataclasses.replace(one, matte=True)
        yield from _render(one, frames, range(max(start, a) - a, b - a), run, parts)


def _render(one, target_frames, todo: range, run: RenderRun, parts: bool = False):
    """Yield ``one(i)`` (``parts``: ``one.part(i)``) for i in ``todo`` in order: here, on
    threads or in forked processes (:class:`RenderRun`'s ``workers`` and ``processes``), BLAS
    on one thread meanwhile.

    BLAS's own threads would spin beside the render's (:mod:`facetransfer.threads`)."""
    from .threads import one_blas_thread

    workers, progress = run.workers, run.progress
    workers = max(1, int(workers if workers is not None else min(2, os.cpu_count() or 1)))
    job = one.part if parts else one
    with one_blas_thread():
        if workers == 1 or len(todo) < 2:
            for i in todo:
                yield job(i)
                if progress:
                    progress(1)
            return
        import multiprocessing as mp

        if run.processes and "fork" in mp.get_all_start_methods():
            yield from _render_in_processes(one, target_frames, todo, workers, progress, parts)
        else:
            yield from _render_in_threads(job, todo, workers, progress)


def _check_clip(target_frames, target_track, new_track, source_track, with_mouth: bool
                ) -> np.ndarray:
    """Frame counts and sizes of a clip to rewrite; returns the first target frame."""
    n = new_track.n_frames
    if len(target_frames) < n:
        raise RewriteError(f"the new performance has {n} frames but the target only "
                           f"{len(target_frames)}")
    if target_track.n_frames < n:
        raise RewriteError(f"the target track has {target_track.n_frames} frames, fewer than the "
                           f"new performance's {n}")
    first = np.asarray(target_frames[0])
    size = (first.shape[1], first.shape[0])
    for what, tr in (("target", target_track), ("new", new_track)):
        if tuple(tr.frame_size) != size:
            raise RewriteError(f"{what} track is for {tr.frame_size[0]}x{tr.frame_size[1]} "
                               f"frames but the target video is {size[0]}x{size[1]}")
    if with_mouth and source_track.n_frames < n:
        raise RewriteError(f"the source track has {source_track.n_frames} frames, fewer than {n}")
    return first


def _clip_mouth_function(model, topo: MeshTopology, new_track, target_frames, target_track,
                         source_frames, source_track, sidx: np.ndarray, with_mouth: bool,
                         mouth_function: MouthFunction | None) -> MouthFunction | None:
    """The texture function of ``mouth="function"``: the given one (checked against the model
    and the mesh), else lifted from the source frames (or the target's without a source)."""
    n = new_track.n_frames
    if mouth_function is None and topo.mouth_faces.size:
        if with_mouth:
            mouth_function = timeline_mouth_function(model, source_frames, source_track, sidx,
                                                     n, topo)
        else:
            mouth_function = mouth_texture_function(model, target_frames, target_track, topo)
    if mouth_function is not None:

        n_attr = attribute_vector(model, new_track.weights_at(0)).shape[-1]
        if mouth_function.n_attributes != n_attr or \
                mouth_function.uvs.shape[0] != topo.n_closed:
            raise RewriteError(f"the mouth texture function is for {mouth_function.n_attributes} "
                               f"attributes and {mouth_function.uvs.shape[0]} vertices, the model "
                               f"has {n_attr} and {topo.n_closed}")
    return mouth_function


@dataclass(frozen=True)
class _ClipRenderer:
    """The per-frame work of :func:`rewrite_frames`: ``renderer(i) -> RewriteFrame``.

    Attributes
    ----------
    const_tex : FaceTexture or None
        The clip's face texture (``texture="constant"``); None: each frame's own.
    mouth_function : MouthFunction or None
        Queried at every frame (``mouth="function"``); None: the source's frame, if any.
    with_mouth : bool
        The mouth comes from ``source_frames`` (``mouth="frame"`` with a source).
    eye_tex : EyeTexture or None
        The eye region's texture (``eyes="model"``; ``topo`` then has its eye holes closed).
    jaw_tex : JawTexture or None
        The jaw region's texture (``jaw="closed"`` with the per-frame face texture).
    meshes : FrameMeshes
        ``"new"``, ``"target"``, ``"source"`` meshes, a few frames at a time; missing kinds
        are synthesised per frame.
    lips : LipResidual or None
        The source's residual at the lips (``lips="residual"`` with the source's frames and
        a track with detections, :mod:`facetransfer.lips`).
    ring : (F',) bool or None
        :func:`facetransfer.mouth.mouth_ring_faces` of ``topo``, when the mouth is textured.
    lip_tint : LipTint or None
        The target's lip colour for the source's lips (``lip_colour="target"`` with the
        source's frames as the mouth texture, :mod:`facetransfer.lip_colour`; the §6 texture
        function's atlas holds no skin around the mouth to compare with).
    gaze : (F, 2, 2) float64 or None
        The new performance's gaze per frame (its eyeLook* activations), where the eye region
        turns the reference frame's eyeballs to it (:mod:`facetransfer.eyeballs`).
    scale : float
        The factor of the rewrite's pixel settings for the shot's face, one for its frames
        (:func:`facetransfer.face_scale.shot_scale`).
    mono : bool
        The target is monochrome: the pixels the rewrite changes are brought to grey
        (:mod:`facetransfer.monochrome`).
    inside : DrawnInside or None
        The mouth's inside drawn where the new mouth opens wider than the target's frames show
        (:attr:`MouthSource.own`, :mod:`facetransfer.mouth_inside`).
    matte : bool
        Each frame with its matte (:attr:`facetransfer.rewrite.RewriteFrame.matte`).
    """

    target_frames: object
    target_track: object
    new_track: object
    model: object
    options: RewriteOptions
    topo: MeshTopology
    first: np.ndarray
    source_frames: object
    source_track: object
    sidx: np.ndarray
    const_tex: FaceTexture | None
    mouth_function: MouthFunction | None
    with_mouth: bool
    meshes: "FrameMeshes"
    eye_tex: EyeTexture | None = None
    jaw_tex: JawTexture | None = None
    lips: LipResidual | None = None
    ring: np.ndarray | None = None
    lip_tint: LipTint | None = None
    gaze: np.ndarray | None = None
    scale: float = 1.0
    mono: bool = False
    inside: DrawnInside | None = None
    matte: bool = False

    @classmethod
    def build(cls, target_frames, target_track, new_track, model, opts: RewriteOptions, *,
              mouth_source: MouthSource, topo, regions: RegionTextures | None = None,
              whole=None) -> "_ClipRenderer":
        """Check the clip, lift the textures (the region textures ``regions`` made ahead, if
        they are this clip's) and synthesise the meshes once. ``whole``: ``(frames, track,
        index)`` of the whole clip this shot is part of (the mouth source's ``index`` over it),
        where the drawn inside is measured (:meth:`_inside`)."""
        source_frames, source_track, source_index, mouth_function = (
            mouth_source.frames, mouth_source.track, mouth_source.index, mouth_source.function)
        mouth = resolve_mouth_mode(opts.mouth or "frame", model)
        n = new_track.n_frames
        with_mouth = source_frames is not None and source_track is not None
        first = _check_clip(target_frames, target_track, new_track, source_track, with_mouth)
        sidx = np.arange(n) if source_index is None else np.asarray(source_index, np.int64)
        if topo is None:
            topo = regions.open_topo if regions is not None else mesh_topology(model)
        fn = None
        if mouth == "function":
            fn = _clip_mouth_function(model, topo, new_track, target_frames, target_track,
                                      source_frames, source_track, sidx, with_mouth,
                                      mouth_function)
            with_mouth = with_mouth and fn is None  # else the source frames are not looked at
        const_tex = None
        if opts.texture == "constant" and not target_track.lost.all():
            const_tex = merged_face_texture(target_frames, target_track, model, topo) \
                if model.uvs is not None else constant_face_texture(target_frames, target_track,
                                                                   model, topo)
        # after the mouth function, which keeps the open topology (issue 13)
        modes = region_modes(opts, const_tex is None)
        if regions is None or regions.open_topo is not topo or \
                not regions.fits(target_track, n, modes):
            regions = region_textures(target_frames, target_track, model, opts, n, topo=topo,
                                      per_frame=const_tex is None)
        topo, eye_tex, jaw_tex = regions.topo, regions.eye_tex, regions.jaw_tex
        kinds = {"new": new_track}
        if const_tex is None:
            kinds["target"] = target_track
        if with_mouth:
            kinds["source"] = source_track
        lips = clip_lip_residual(model, topo, source_track) \
            if with_mouth and opts.lips == "residual" else None
        mono = is_monochrome(target_frames, n)
        renderer = cls(target_frames, target_track, new_track, model, opts, topo, first,
                       source_frames, source_track, sidx, const_tex, fn, with_mouth,
                       FrameMeshes(model, kinds, n), eye_tex, jaw_tex, lips,
                       mouth_ring_faces(topo) if with_mouth else None, mono=mono)
        renderer = dataclasses.replace(renderer, scale=renderer.shot_scale())
        if opts.lip_colour == "target" and with_mouth and model.landmarks is not None:
            tint = renderer.clip_lip_tint()
            renderer = dataclasses.replace(renderer, lip_tint=tint.grey() if mono and tint
                                           else tint)
        if eye_tex is not None and eye_tex.eyeballs is not None:
            renderer = dataclasses.replace(renderer, gaze=track_gaze(
                new_track if opts.gaze == "performance" else target_track))
        if mouth_source.own and (fn is not None or with_mouth):
            renderer = dataclasses.replace(renderer, inside=renderer._inside(
                fn, mouth_function is not None, whole))
        return renderer

    def _inside(self, fn, given: bool, whole) -> DrawnInside | None:
        """The drawn inside (:func:`facetransfer.mouth_inside.drawn_inside`) of the frames
        the mouth's texture comes from: the texture function's (``fn``; ``given``: lifted by
        the caller, over the whole clip) or the mouth source's index. Measured over the whole
        clip ``whole`` (:meth:`build`), whose frames those index, not this shot's: a shot's
        frames and track start at its own first frame (before, a target with cuts measured
        its later shots' frames at the whole clip's numbers, or none of them)."""
        frames, track, index = (self.target_frames, self.target_track, self.sidx) \
            if whole is None or (fn is not None and not given) else whole
        rows = fn.frames if fn is not None else index
        return drawn_inside(frames, track, self.model, self.topo, rows)

    def clip_lip_tint(self) -> LipTint | None:
        """The target's lip colour over the source's (:mod:`facetransfer.lip_colour`), read
        from up to :data:`facetransfer.lip_colour.SAMPLES` frames spread through the clip
        where neither face is lost, through the textures the frames are rendered with."""
        weights, lips = lip_vertex_weights(self.model, self.topo)
        skin = np.setdiff1d(np.unique(self.topo.faces[self.ring]), np.flatnonzero(weights > 0))
        n = self.new_track.n_frames  # the target's track may be longer (align="trim")
        ok = np.flatnonzero(~(self.new_track.lost | self.target_track.lost[:n]))
        if ok.size == 0 or lips.size == 0 or skin.size == 0:
            return None
        pick = ok[np.unique(np.linspace(0, ok.size - 1, min(LIP_SAMPLES, ok.size)).round()
                            .astype(np.int64))]
        Vt = self._meshes_at("target", self.target_track, pick)
        Vs = self._meshes_at("source", self.source_track, pick)
        target = (self.face_texture(np.asarray(self.target_frames[i]), int(i), V)
                  for i, V in zip(pick, Vt))
        source = (self.mouth_texture(int(i), V) for i, V in zip(pick, Vs))
        tr = lip_ratio(((t.image, t.uvs) for t in target), lips, skin)
        sr = lip_ratio(((t.image, t.uvs) for t in source), lips, skin)
        tint = LipTint.of(weights, tr, sr)
        log.info("lip colour: the target's lips over the source's %s (RGB)",
                 np.array2string(tint.tint, precision=2))
        return tint

    def shot_scale(self) -> float:
        """:func:`facetransfer.face_scale.shot_scale` over the frames :meth:`part` renders
        (neither track lost there), of the new face at the first of them."""
        n = self.new_track.n_frames
        shown = np.flatnonzero(~(np.asarray(self.new_track.lost[:n], bool)
                                 | np.asarray(self.target_track.lost[:n], bool)))
        if not shown.size:
            return 1.0
        return shot_scale(self.mesh("new", self.new_track, int(shown[0])), self.new_track,
                          self.topo.eye_loops, shown)

    def mesh(self, kind: str, track, i: int) -> np.ndarray:
        """The mesh (n_vertices, 3) of frame ``i`` of ``track`` (its ``kind`` in :attr:`meshes`)."""
        if kind in self.meshes:
            return self.meshes.frame(kind, i)
        return self.model.synthesize(track.weights_at(i))

    def _meshes_at(self, kind: str, track, frames: np.ndarray) -> np.ndarray:
        """The meshes ``(len(frames), n_vertices, 3)`` of some frames of ``track``: one
        product of the kind's clip basis (not a chunk of :attr:`meshes` per frame)."""
        if kind in self.meshes:
            return self.meshes.basis(kind).meshes(np.asarray(frames, np.int64))
        return np.stack([self.model.synthesize(track.weights_at(int(i))) for i in frames])

    def face_texture(self, frame: np.ndarray, i: int, mesh: np.ndarray | None = None
                     ) -> FaceTexture:
        """The target's face texture at frame ``i`` (``mesh``: the target's, if at hand)."""
        if self.const_tex is not None:
            return self.const_tex
        if mesh is None:
            mesh = self.mesh("target", self.target_track, i)
        Vt = close_mouth(mesh, self.topo)
        size = (frame.shape[1], frame.shape[0])
        return FaceTexture(frame, frame_uvs(Vt, self.target_track.camera(i), size), i)

    def mouth_texture(self, i: int, mesh: np.ndarray | None = None) -> FaceTexture | None:
        """The mouth texture at frame ``i``: the function's, the source frame's (``mesh``:
        the source's, if at hand), or None."""
        if self.mouth_function is not None:
            return self.mouth_function.face_texture(
                attribute_vector(self.model, self.new_track.weights_at(i)))
        if not self.with_mouth:
            return None
        j = int(self.sidx[i])
        sf = np.asarray(self.source_frames[j])
        if mesh is None:
            mesh = self.mesh("source", self.source_track, i)
        Vs = close_mouth(mesh, self.topo)
        size = (sf.shape[1], sf.shape[0])
        uvs = frame_uvs(Vs, self.source_track.camera(i), size)
        if self.lips is not None:  # the image's lips onto the mesh's (facetransfer.lips)
            uvs = warp_uvs(uvs, self.lips.warp, self.lips.texture[i], size)
        return FaceTexture(sf, uvs, j)

    def new_mesh(self, i: int) -> np.ndarray:
        """The new face at frame ``i`` (n_vertices, 3), with the source's lip residual added
        (:func:`facetransfer.lips.displace_lips`) when :attr:`lips` is set."""
        V = self.mesh("new", self.new_track, i)
        if self.lips is None:
            return V
        Vs = self.mesh("source", self.source_track, i)
        return displace_lips(V, self.lips.warp, self.lips.shape[i],
                             self.source_track.rotation[i], self.source_track.scale[i],
                             mouth_width_ratio(V, Vs, self.lips.warp))

    def __call__(self, i: int) -> RewriteFrame:
        """Frame ``i`` rewritten (:meth:`part` pasted into it)."""
        return paste_part(np.asarray(self.target_frames[i]), self.part(i), matte=self.matte)

    def part(self, i: int):
        """Frame ``i``'s rewrite on the face's box: ``(box, RewriteFrame)`` or None
        (:func:`facetransfer.rewrite.rewrite_frame_part`); the renders of its region views
        mixed there."""
        frame = np.asarray(self.target_frames[i])
        if frame.shape != self.first.shape:
            raise RewriteError(f"target frame {i} is {frame.shape}, frame 0 {self.first.shape}")
        if self.new_track.lost[i] or self.target_track.lost[i]:
            return None
        V, blending = self.new_mesh(i), self.options.blending
        textures = FrameTextures(self.face_texture(frame, i), self.mouth_texture(i),
                                 mouth_ring=self.ring, lip_tint=self.lip_tint,
                                 inside=self.inside)
        parts = [(rewrite_frame_part(
            frame, V, self.new_track.camera(i), self.topo,
            dataclasses.replace(textures, eyes=eye, jaw=jaw), blending=blending,
            matte=self.matte, scale=self.scale), we * wj)
            for eye, we in views_at(self.eye_tex, i, None if self.gaze is None else self.gaze[i])
            for jaw, wj in views_at(self.jaw_tex, i)]
        if parts[0][0] is None:       # the face outside the frame (the same box every view)
            return None
        box = parts[0][0][0]
        res = blend_renders([(part[1], w) for part, w in parts])
        if self.mono:
            x0, y0, x1, y1 = box
            res = dataclasses.replace(res, image=monochrome_changes(res.image,
                                                                    frame[y0:y1, x0:x1]))
        return box, _keep_covered(res, frame, box, self.target_track, i)


def _keep_covered(res: RewriteFrame, frame: np.ndarray, box, target_track, i: int
                  ) -> RewriteFrame:
    """``res`` (a rewrite on ``box``) with the target's own pixels kept over the regions its
    track found covered in frame ``i`` (a hand, a microphone, glasses: ``track --occluders``,
    :func:`facetransfer.track.occlusion.covered_alpha`); as it is for a track not tested."""
    if target_track.occluded is None or not target_track.occluded[i].any():
        return res
    from .track.occlusion import covered_alpha

    points = target_track.detections2d if target_track.detections2d is not None \
        else target_track.landmarks2d                             # as track_points, one frame
    alpha = covered_alpha(points[i], target_track.occluded[i], box)
    if alpha is None:
        return res
    x0, y0, x1, y1 = box
    a = alpha[..., None]
    image = res.image * (1.0 - a) + frame[y0:y1, x0:x1] * a
    matte = None if res.matte is None else (res.matte * (1.0 - alpha)).astype(np.float32)
    return dataclasses.replace(res, image=np.rint(image).astype(np.uint8), matte=matte)


def _render_in_threads(one, todo: range, workers: int, progress):
    """Yield ``one(i)`` for i in ``todo``, computed on ``workers`` threads, in order.

    Frames are independent: the rasteriser and most numpy kernels release the GIL; the
    look-ahead is bounded (twice the workers)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        nxt, n = todo.start, todo.stop
        while nxt < n or pending:
            while nxt < n and len(pending) < 2 * workers:
                pending.append(pool.submit(one, nxt))
                nxt += 1
            fut = pending.popleft()
            try:
                res = fut.result()
            except BaseException:
                for f in pending:
                    f.cancel()
                raise
            yield res
            if progress:
                progress(1)


def _crop_of(T: np.ndarray, frame: RewriteFrame):
    """``(box, crop result)`` of a rewritten frame: the inverse of
    :func:`facetransfer.rewrite.paste_part`, cropped to the pixels that differ from ``T`` or belong
    to the face (small to send between processes); None when nothing changed."""
    changed = frame.face_mask | frame.mouth_mask | (frame.image != T).any(axis=-1)
    changed |= frame.rendered.any(axis=-1)
    if frame.matte is not None:
        changed |= frame.matte > 0
    if not changed.any():
        return None
    ys = np.flatnonzero(changed.any(axis=1))
    xs = np.flatnonzero(changed.any(axis=0))
    y0, y1, x0, x1 = int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1
    sl = (slice(y0, y1), slice(x0, x1))
    return (x0, y0, x1, y1), RewriteFrame(frame.image[sl].copy(), frame.rendered[sl].copy(),
                                          frame.face_mask[sl].copy(),
                                          frame.mouth_mask[sl].copy(),
                                          None if frame.matte is None else
                                          frame.matte[sl].copy())


#: the per-frame function of :func:`rewrite_frames` handed to forked workers (not pickled)
_RENDER_JOB: Callable | None = None


def _render_job(i: int):
    """Frame ``i`` rendered in a worker process: its box only (the renderer's :meth:`part`,
    else the changed crop of the whole frame, :func:`_crop_of`)."""
    part = getattr(_RENDER_JOB, "part", None)
    if part is not None:
        return part(i)
    return _crop_of(np.asarray(_RENDER_FRAMES[i]), _RENDER_JOB(i))


_RENDER_FRAMES = None


def _render_in_processes(one, target_frames, todo: range, workers: int, progress,
                         parts: bool = False):
    """Yield ``one(i)`` for i in ``todo``, computed in ``workers`` forked processes, in order
    (``parts``: the face's box of each, as the workers send it).

    Workers send back only the face's box of each frame (the renderer's ``part``, else the
    changed crop, :func:`_crop_of`); if the pool breaks, the remaining frames are rendered
    here."""
    global _RENDER_JOB, _RENDER_FRAMES
    import multiprocessing as mp
    from collections import deque
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    _RENDER_JOB, _RENDER_FRAMES = one, target_frames
    nxt, n = todo.start, todo.stop
    try:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"))
        pending: deque = deque()
        try:
            pending.append(pool.submit(_render_job, nxt))  # forks the workers now
            nxt += 1
        finally:
            _RENDER_JOB, _RENDER_FRAMES = None, None
    except Exception as exc:  # noqa: BLE001 - cannot fork here (e.g. in a daemon process)
        log.info("no worker processes (%s): rendering here", exc)
        for i in todo:
            yield one.part(i) if parts else one(i)
            if progress:
                progress(1)
        return
    done = todo.start
    broken = False
    try:
        while done < n:
            if not broken:
                try:
                    while nxt < n and len(pending) < 4 * workers:
                        pending.append(pool.submit(_render_job, nxt))
                        nxt += 1
                    part = pending.popleft().result()
                    res = part if parts else paste_part(np.asarray(target_frames[done]), part,
                                                        matte=one.matte)
                except BrokenProcessPool as exc:
                    log.warning("render workers failed (%s); rendering here", exc)
                    broken = True
            if broken:
                res = one.part(done) if parts else one(done)
            yield res
            done += 1
            if progress:
                progress(1)
    finally:
        for f in pending:
            f.cancel()
        pool.shutdown(wait=True, cancel_futures=True)


"""The eye and jaw regions' reference frames by view (issue 13; §6's texture "constant
throughout the sequence", held per view of the head).

The eye region (lids, eyes, brows: :func:`facetransfer.eyes.eye_texture`) and the jaw region
(chin, jaw, cheeks: :func:`facetransfer.jaw.jaw_texture`) of every frame are textured from one
target frame each, the one facing the camera most squarely among those with the eyes open
(the brows quiet) or the mouth closed. A target whose head turns far from that view shows, in
its turned frames, a fringe that hangs elsewhere over the brows and skin lit from another
side: pasted from the frontal frame, the frontal frame's strands and highlights appear over
the brows and the cheeks (``make demo``'s turned frames 24-90, up to 32 degrees from its
reference frames 3 and 112). A frame's own texture would not carry them, but it carries the
target's own expression; a reference frame (eyes open and brows quiet, or mouth closed and no
smile) seen from near that side carries neither.

So a region takes up to :data:`MAX_VIEWS` reference frames: the frontal one, then, while
:data:`MIN_SHARE` of the frames are farther than :data:`VIEW_SPLIT` from every reference's head
rotation, the candidate that brings them nearest (:func:`view_references`); each frame is
rendered with the reference nearest its view (:func:`pick_views`, with :data:`HYSTERESIS`, so
that a head hovering between two views does not switch back and forth), cross-faded over
:data:`FADE_SECONDS` where it switches (:func:`fade_weights`, :func:`blend_renders`).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from .eyes import (BROW_SHAPES, eye_openness, eye_penalty, eye_texture, reference_candidates,
                   shape_activity)
from .io.frame_numbers import track_first_number
from .jaw import jaw_texture, mouth_closure
from .region_weights import EYE_POINTS, JAW_POINTS

log = logging.getLogger(__name__)

__all__ = ["VIEW_SPLIT", "MAX_VIEWS", "HYSTERESIS", "FADE_SECONDS", "RegionViews",
           "RegionTextures", "region_textures", "view_angles", "view_references", "pick_views",
           "fade_weights", "views_at", "blend_renders", "eye_texture_by_view",
           "jaw_texture_by_view"]

#: Degrees: a frame whose head rotation is farther than this from every reference frame's
#: calls for another reference (when a candidate brings it nearer).
VIEW_SPLIT = 12.0
#: At most this many reference frames a region (each costs one region texture's build: the
#: eye region's ~0.25 s for 120 frames of ``make demo``'s target).
MAX_VIEWS = 3
#: Degrees by which another reference must be nearer than the current one for a frame to
#: switch to it.
HYSTERESIS = 3.0
#: Seconds over which a frame's region passes from one reference's texture to the next's
#: (each frame of the passage rendered with both; a switch from one frame to the next showed
#: as a jump of the lids' and brows' look).
FADE_SECONDS = 0.3
#: Degrees of view a candidate's own expression counts as, per unit of its
#: ``0.5 * sum(activations)`` of :data:`COST_SHAPES` (:func:`facetransfer.eyes.open_eye_frame`'s
#: penalty): a turned frame with raised brows or a smile would bring them back. The eye
#: region's candidates pay :func:`facetransfer.eyes.eye_penalty` (their gaze too, if weighed).
EXPRESSION_COST = 20.0
#: The activations a region's candidate reference frames pay for.
COST_SHAPES = {"eyes": BROW_SHAPES, "jaw": ("mouthSmileLeft", "mouthSmileRight")}
#: A reference is added only if it removes at least this share of the frames' total angle
#: beyond :data:`VIEW_SPLIT` (a frame turned where no open-eyed frame looks from keeps the
#: nearest reference rather than a reference that only a few frames come nearer to).
MIN_GAIN = 0.3
#: ... and only when at least this share of the frames is beyond :data:`VIEW_SPLIT` (a few
#: turned frames are not worth a second texture and the switches to it).
MIN_SHARE = 0.1
#: The candidates' eyes are at least as open as, or their mouths at most as open as, this
#: quantile of the clip's (the first references': 0.75 and 0.25; a turned head's frames are
#: fewer).
CANDIDATE_QUANTILE = 0.5


@dataclass(frozen=True)
class RegionViews:
    """A region's textures over a clip, one per reference frame, and how much of each a frame
    takes.

    Attributes
    ----------
    textures : tuple of EyeTexture or JawTexture
        The first is the region's own (:func:`facetransfer.eyes.eye_texture`,
        :func:`facetransfer.jaw.jaw_texture`: the frontal reference).
    weights : (F, k) float32
        Per frame, the share of each texture (rows sum to 1): one texture, the nearest view's
        (:func:`pick_views`), except over :data:`FADE_SECONDS` around a switch, where the
        frame is rendered with each and the renders are mixed (:func:`blend_renders`).
    """

    textures: tuple
    weights: np.ndarray

    @property
    def eyeballs(self):
        """An eye region's first texture's eyeballs (all or none of them have them)."""
        return getattr(self.textures[0], "eyeballs", None)

    @property
    def frames(self) -> tuple[int, ...]:
        """The reference frames."""
        return tuple(t.frame for t in self.textures)

    def views_at(self, i: int, *args) -> list:
        """``[(texture, share), ...]`` of frame ``i``, each texture's ``at(i, *args)``."""
        w = self.weights[min(int(i), len(self.weights) - 1)]
        return [(self.textures[k].at(i, *args), float(w[k])) for k in np.flatnonzero(w > 0)]


def views_at(tex, i: int, *args) -> list:
    """``[(texture or None, share), ...]``: the region textures frame ``i`` is rendered with,
    of :class:`RegionViews`, one texture (its ``at(i, *args)``) or None (the frame's own)."""
    if tex is None:
        return [(None, 1.0)]
    if isinstance(tex, RegionViews):
        return tex.views_at(i, *args)
    return [(tex.at(i, *args), 1.0)]


def blend_renders(renders: list):
    """One rendered frame (:class:`facetransfer.rewrite.RewriteFrame`) from ``[(frame,
    share), ...]`` of the same frame rendered with each region texture: the images mixed by the
    shares (the masks are the same mesh's)."""
    if len(renders) == 1:
        return renders[0][0]
    img = sum(w * r.image.astype(np.float32) for r, w in renders)
    face = sum(w * r.rendered.astype(np.float32) for r, w in renders)
    return dataclasses.replace(renders[0][0], image=np.rint(img).astype(np.uint8),
                               rendered=np.rint(face).astype(np.uint8))


def view_angles(rotation: np.ndarray, rows) -> np.ndarray:
    """``(F, k)`` degrees: the angle of the rotation taking frame ``rows[j]``'s head rotation to
    each frame's (``rotation`` (F, 3, 3))."""
    R = np.asarray(rotation, np.float64)
    c = (np.einsum("fab,kab->fk", R, R[np.asarray(rows, np.int64)]) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _candidates(track, n: int, region: str) -> tuple[np.ndarray, np.ndarray]:
    """The frames (of the first ``n``, not lost) that could be a ``region``'s reference (eyes
    as open as :data:`CANDIDATE_QUANTILE` of the clip's or more; a mouth as closed or more), and
    their expression in degrees (:data:`EXPRESSION_COST`, :data:`COST_SHAPES`)."""
    eyes = region == "eyes"
    cand = reference_candidates(track, eye_openness(track) if eyes else mouth_closure(track), n,
                                CANDIDATE_QUANTILE, low=not eyes,
                                points=EYE_POINTS if eyes else JAW_POINTS)
    activity = eye_penalty(track) if eyes else shape_activity(track, COST_SHAPES[region])
    return cand, (np.zeros(cand.size) if activity is None
                  else EXPRESSION_COST * activity[cand])


def view_references(track, n: int, first: int, region: str = "eyes") -> list[int]:
    """The reference frames of a ``region`` ("eyes" or "jaw") over the first ``n`` frames of
    ``track``: ``first``, then greedily the candidate (:func:`_candidates`) that most lowers
    the frames' total angle beyond :data:`VIEW_SPLIT` from their nearest reference (a
    candidate's angles increased by its own expression, :data:`EXPRESSION_COST`), while
    :data:`MIN_SHARE` of the frames are beyond it and a candidate removes at least
    :data:`MIN_GAIN` of that total; at most :data:`MAX_VIEWS`."""
    refs = [int(first)]
    good = np.flatnonzero(~np.asarray(track.lost, bool)[:n])
    cand, cost = _candidates(track, n, region)
    if cand.size == 0:
        return refs
    A = view_angles(track.rotation, cand)[good] + cost[None, :]   # (good frames, candidates)
    near = view_angles(track.rotation, refs)[good, 0]
    excess = float(np.maximum(near - VIEW_SPLIT, 0.0).sum())
    while len(refs) < MAX_VIEWS and np.mean(near > VIEW_SPLIT) >= MIN_SHARE:
        left = np.maximum(np.minimum(near[:, None], A) - VIEW_SPLIT, 0.0).sum(axis=0)
        k = int(np.argmin(left))
        if left[k] > (1.0 - MIN_GAIN) * excess or int(cand[k]) in refs:
            break
        refs.append(int(cand[k]))
        near, excess = np.minimum(near, A[:, k]), float(left[k])
    return refs


def pick_views(rotation: np.ndarray, refs, lost: np.ndarray, n: int) -> np.ndarray:
    """``(n,) int``: per frame, the index in ``refs`` of the reference nearest its view; a frame
    keeps the previous frame's unless another is :data:`HYSTERESIS` nearer; lost frames keep
    the previous frame's (the first frames: the first found's)."""
    A = view_angles(np.asarray(rotation)[:n], refs)
    ok = ~np.asarray(lost, bool)[:n]
    pick = np.zeros(n, np.int64)
    if len(refs) == 1 or not ok.any():
        return pick
    cur = int(np.argmin(A[int(np.argmax(ok))]))
    for i in range(n):
        if ok[i]:
            best = int(np.argmin(A[i]))
            if A[i, best] < A[i, cur] - HYSTERESIS:
                cur = best
        pick[i] = cur
    return pick


def eye_texture_by_view(frames, track, model, topo, *, n_frames: int | None = None, rig=None):
    """:func:`facetransfer.eyes.eye_texture` with a reference frame per view (module notes):
    ``(closed topology, EyeTexture or RegionViews or None)``."""
    closed, tex = eye_texture(frames, track, model, topo, n_frames=n_frames, rig=rig)
    return closed, _by_view(tex, "eyes", frames, track, n_frames, lambda r: eye_texture(
        frames, track, model, topo, n_frames=n_frames, rig=rig, frame=r)[1])


def jaw_texture_by_view(frames, track, model, topo, *, n_frames: int | None = None, rig=None):
    """:func:`facetransfer.jaw.jaw_texture` with a reference frame per view (module notes):
    JawTexture, RegionViews or None."""
    tex = jaw_texture(frames, track, model, topo, n_frames=n_frames, rig=rig)
    return _by_view(tex, "jaw", frames, track, n_frames, lambda r: jaw_texture(
        frames, track, model, topo, n_frames=n_frames, rig=rig, frame=r))


def _by_view(tex, region: str, frames, track, n_frames, build):
    """``tex`` (a region's texture from its first reference frame, or None), or the
    :class:`RegionViews` of it and of ``build(frame)`` for each further reference."""
    if tex is None:
        return None
    n = len(frames) if n_frames is None else min(int(n_frames), len(frames))
    refs = view_references(track, n, tex.frame, region)
    if len(refs) == 1:
        return tex
    pick = pick_views(track.rotation, refs, track.lost, n)
    counts = np.bincount(pick, minlength=len(refs))
    n0 = track_first_number(track)      # a plate's frames by their numbers
    log.info("%s: a texture per view, from target frames %s, for %s frames", region,
             ", ".join(str(n0 + r) for r in refs), " / ".join(map(str, counts)))
    fade = max(1, int(round(FADE_SECONDS * float(track.fps))))
    return RegionViews((tex, *[build(r) for r in refs[1:]]),
                       fade_weights(pick, len(refs), fade))


def fade_weights(pick: np.ndarray, k: int, fade: int) -> np.ndarray:
    """``(F, k) float32``: the one-hot ``pick`` (F,) of ``k`` textures averaged over ``fade``
    frames centred on each (the edges held): a switch becomes a linear cross-fade of ``fade``
    frames; rows sum to 1."""
    from scipy.ndimage import uniform_filter1d

    onehot = np.eye(k, dtype=np.float64)[np.asarray(pick, np.int64)]
    w = uniform_filter1d(onehot, size=int(fade), axis=0, mode="nearest")
    w[w < 1e-6] = 0.0
    return (w / w.sum(axis=1, keepdims=True)).astype(np.float32)


@dataclass(frozen=True)
class RegionTextures:
    """The eye and jaw regions' textures of a target clip (:func:`region_textures`): made by
    the renderer, or ahead of it while a source is still tracked
    (:func:`facetransfer.transfer_plan.plan_sources`), then taken by the renderer when they
    are of its clip (:meth:`fits`).

    Attributes
    ----------
    target_track : Track
        The track they were lifted through (the renderer's must be this object).
    n_frames : int
        The frames of the clip they were chosen among.
    modes : (bool, bool, bool)
        ``(eyes, jaw, per_frame)``: the eye region from the model, the jaw region closed, the
        face textured from each frame (:class:`facetransfer.rewrite_options.RewriteOptions`).
    open_topo : MeshTopology
        :func:`facetransfer.topology.mesh_topology` of the model.
    topo : MeshTopology
        ``open_topo`` with the eye holes closed where the eye region is the model's.
    eye_tex, jaw_tex : EyeTexture, JawTexture, RegionViews or None
    """

    target_track: object
    n_frames: int
    modes: tuple
    open_topo: object
    topo: object
    eye_tex: object = None
    jaw_tex: object = None

    def fits(self, target_track, n_frames: int, modes: tuple) -> bool:
        """Whether these are the textures of ``target_track``'s first ``n_frames`` frames
        rendered with ``modes``."""
        return (self.target_track is target_track and self.n_frames == int(n_frames)
                and self.modes == tuple(modes))


def region_modes(opts, per_frame: bool = True) -> tuple:
    """``(eyes, jaw, per_frame)`` of :class:`RegionTextures` for rewrite options ``opts``."""
    return opts.eyes == "model", opts.jaw == "closed" and per_frame, bool(per_frame)


def region_textures(target_frames, target_track, model, opts, n: int, *, topo=None,
                    per_frame: bool = True, rig=None) -> RegionTextures:
    """The eye and jaw regions of a clip (:class:`RegionTextures`): the eye holes closed and the
    eye region lifted (``opts.eyes == "model"``, :func:`eye_texture_by_view`), the jaw region
    lifted for the final topology (``opts.jaw == "closed"`` with the per-frame face texture,
    :func:`jaw_texture_by_view`); one expression rig for both. ``topo``: the model's
    :func:`facetransfer.topology.mesh_topology`, if at hand; ``rig``: that rig, the model's
    mean person's (:func:`facetransfer.arkit.expression_rig` of its default weights), if at
    hand (an ARKit model's); ``n``: the frames rendered."""
    from .arkit import expression_rig, is_arkit_model
    from .topology import mesh_topology

    modes = region_modes(opts, per_frame)
    open_topo = mesh_topology(model) if topo is None else topo
    out = RegionTextures(target_track, int(n), modes, open_topo, open_topo)
    eyes, jaw, _ = modes
    if target_track.lost[:n].all() or not (eyes or jaw):
        return out
    if rig is None and is_arkit_model(model):
        rig = expression_rig(model, model.default_weights())
    closed, eye_tex = open_topo, None
    if eyes:
        closed, eye_tex = eye_texture_by_view(target_frames, target_track, model, open_topo,
                                              n_frames=n, rig=rig)
    jaw_tex = jaw_texture_by_view(target_frames, target_track, model, closed, n_frames=n,
                                  rig=rig) if jaw else None
    return dataclasses.replace(out, topo=closed, eye_tex=eye_tex, jaw_tex=jaw_tex)

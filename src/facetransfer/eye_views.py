"""The eye region's reference frames by view (issue 13, §6's texture "constant throughout the
sequence", held per view).

:func:`facetransfer.eyes.eye_texture` textures the eye region (lids, eyes, brows) of every
frame from one open-eyed target frame, the one facing the camera most squarely. A target whose
head turns far from that view shows, in its turned frames, a fringe that hangs elsewhere over
the brows and forehead and skin lit from another side: pasted from the frontal frame, the
frontal frame's strands and highlights appear over the brows (``make demo``'s turned frames
35-90, up to 32 degrees from its reference frame 3). A frame's texture from the same view
would not carry them, but it carries the target's own brows; an open-eyed frame *with quiet
brows* seen from near that side carries neither.

So a clip takes up to :data:`MAX_VIEWS` reference frames: the frontal one, then, while some
frame is farther than :data:`VIEW_SPLIT` from every reference's head rotation, the candidate
(eyes open, brows quiet, as :func:`facetransfer.eyes.open_eye_frame` chooses) that brings the
frames nearest to a reference; each frame is rendered with the reference nearest its view
(with :data:`HYSTERESIS`, so that a head hovering between two views does not switch back and
forth).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from .eyes import BROW_SHAPES, EyeTexture, eye_openness, eye_texture

log = logging.getLogger(__name__)

__all__ = ["VIEW_SPLIT", "MAX_VIEWS", "HYSTERESIS", "FADE_SECONDS", "EyeViews", "view_angles",
           "view_references", "pick_views", "fade_weights", "views_at", "blend_renders",
           "eye_texture_by_view"]

#: Degrees: a frame whose head rotation is farther than this from every reference frame's
#: calls for another reference (when a candidate brings it nearer).
VIEW_SPLIT = 12.0
#: At most this many reference frames a clip (each costs one eye texture's build, ~0.25 s for
#: 120 frames of ``make demo``'s target).
MAX_VIEWS = 3
#: Degrees by which another reference must be nearer than the current one for a frame to
#: switch to it.
HYSTERESIS = 3.0
#: Seconds over which a frame's eye region passes from one reference's texture to the next's
#: (each frame of the passage rendered with both; a switch from one frame to the next showed
#: as a jump of the lids' and brows' look).
FADE_SECONDS = 0.3
#: Degrees of view a candidate's brow activity counts as, per unit of
#: ``0.5 * sum(brow activations)`` (:func:`facetransfer.eyes.open_eye_frame`'s penalty).
BROW_COST = 20.0
#: A reference is added only if it removes at least this share of the frames' total angle
#: beyond :data:`VIEW_SPLIT` (a frame turned where no open-eyed frame looks from keeps the
#: nearest reference rather than a reference that only a few frames come nearer to).
MIN_GAIN = 0.3
#: ... and only when at least this share of the frames is beyond :data:`VIEW_SPLIT` (a few
#: turned frames are not worth a second texture and the switches to it).
MIN_SHARE = 0.1
#: The candidates' eyes are at least this quantile of the clip's openness (the first
#: reference's: 0.75; a turned head's frames are fewer and often narrower-eyed).
OPEN_QUANTILE = 0.5


@dataclass(frozen=True)
class EyeViews:
    """A clip's eye textures, one per reference frame, and how much of each a frame takes.

    Attributes
    ----------
    textures : tuple of EyeTexture
        The first is :func:`facetransfer.eyes.eye_texture`'s own (the frontal reference).
    weights : (F, k) float32
        Per frame, the share of each texture (rows sum to 1): one texture, the nearest view's
        (:func:`pick_views`), except over :data:`FADE_SECONDS` around a switch, where the
        frame is rendered with each and the renders are mixed (:func:`blend_renders`).
    """

    textures: tuple
    weights: np.ndarray

    @property
    def eyeballs(self):
        """The first texture's eyeballs (all or none of the textures have them)."""
        return self.textures[0].eyeballs

    @property
    def frames(self) -> tuple[int, ...]:
        """The reference frames."""
        return tuple(t.frame for t in self.textures)

    def views_at(self, i: int, gaze: np.ndarray | None = None) -> list:
        """``[(EyeTexture, share), ...]`` of frame ``i``, each at
        :meth:`facetransfer.eyes.EyeTexture.at` with the new gaze ``gaze`` (2, 2)."""
        w = self.weights[min(int(i), len(self.weights) - 1)]
        return [(self.textures[k].at(i, gaze), float(w[k])) for k in np.flatnonzero(w > 0)]


def views_at(eye_tex, i: int, gaze) -> list:
    """``[(EyeTexture or None, share), ...]``: the eye textures frame ``i`` is rendered with, of
    an :class:`EyeViews`, one :class:`~facetransfer.eyes.EyeTexture` or None (the target's
    eyes); ``gaze``: the new performance's (F, 2, 2) or None."""
    g = None if gaze is None else gaze[i]
    if eye_tex is None:
        return [(None, 1.0)]
    if isinstance(eye_tex, EyeViews):
        return eye_tex.views_at(i, g)
    return [(eye_tex.at(i, g), 1.0)]


def blend_renders(renders: list):
    """One rendered frame (:class:`facetransfer.rewrite.RewriteFrame`) from ``[(frame,
    share), ...]`` of the same frame rendered with each eye texture: the images mixed by the
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


def _candidates(track, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The frames (of the first ``n``, not lost) whose eyes are open as a reference's are, and
    their brow activity in degrees (:data:`BROW_COST`)."""
    good = np.flatnonzero(~np.asarray(track.lost, bool)[:n])
    op = eye_openness(track)[good]
    cand = good[op >= np.quantile(op, OPEN_QUANTILE)]
    cost = np.zeros(cand.size)
    if track.blendshapes is not None and track.blendshape_names is not None:
        names = list(track.blendshape_names)
        cols = [names.index(b) for b in BROW_SHAPES if b in names]
        if cols:
            b = np.asarray(track.blendshapes, np.float64)[cand][:, cols]
            cost = BROW_COST * 0.5 * b.sum(axis=1)
    return cand, cost


def view_references(track, n: int, first: int) -> list[int]:
    """The reference frames of the first ``n`` frames of ``track``: ``first``, then greedily the
    candidate that most lowers the frames' total angle beyond :data:`VIEW_SPLIT` from their
    nearest reference (a candidate's angles increased by its brow activity,
    :data:`BROW_COST`), while :data:`MIN_SHARE` of the frames are beyond it and a candidate
    removes at least :data:`MIN_GAIN` of that total; at most :data:`MAX_VIEWS`."""
    refs = [int(first)]
    good = np.flatnonzero(~np.asarray(track.lost, bool)[:n])
    cand, cost = _candidates(track, n) if good.size else (np.zeros(0, np.int64), None)
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
    ``(closed topology, EyeTexture or EyeViews or None)``."""
    closed, tex = eye_texture(frames, track, model, topo, n_frames=n_frames, rig=rig)
    if tex is None:
        return closed, tex
    n = len(frames) if n_frames is None else min(int(n_frames), len(frames))
    refs = view_references(track, n, tex.frame)
    if len(refs) == 1:
        return closed, tex
    more = [eye_texture(frames, track, model, topo, n_frames=n_frames, rig=rig, frame=r)[1]
            for r in refs[1:]]
    pick = pick_views(track.rotation, refs, track.lost, n)
    log.info("eyes: a texture per view, from target frames %s, for %s frames",
             ", ".join(map(str, refs)), " / ".join(map(str, np.bincount(pick, minlength=len(refs)))))
    fade = max(1, int(round(FADE_SECONDS * float(track.fps))))
    return closed, EyeViews((tex, *more), fade_weights(pick, len(refs), fade))


def fade_weights(pick: np.ndarray, k: int, fade: int) -> np.ndarray:
    """``(F, k) float32``: the one-hot ``pick`` (F,) of ``k`` textures averaged over ``fade``
    frames centred on each (the edges held): a switch becomes a linear cross-fade of ``fade``
    frames; rows sum to 1."""
    from scipy.ndimage import uniform_filter1d

    onehot = np.eye(k, dtype=np.float64)[np.asarray(pick, np.int64)]
    w = uniform_filter1d(onehot, size=int(fade), axis=0, mode="nearest")
    w[w < 1e-6] = 0.0
    return (w / w.sum(axis=1, keepdims=True)).astype(np.float32)

"""Per-vertex weights of a face region textured from one reference frame of the target.

The eye region (:mod:`facetransfer.eyes`) and the jaw region (:mod:`facetransfer.jaw`) of a
transfer take their texture from one target frame (Vlasic et al. 2005, §6: a texture "constant
throughout the sequence") rather than from each frame, which carries the target's own
expression. How much of that frame shows at each vertex, in each frame, is the product of
weights defined here, interpolated over the triangles (:func:`vertex_alpha`):

- :func:`moved_strengths`: where the target's own expression moved the skin from where the
  reference frame has it (elsewhere the current frame shows the same skin, lit as it is now);
- :func:`facing_weights`: where the reference frame sees the skin squarely, not edge-on;
- :func:`usual_weights`: where the reference frame shows what the clip usually shows there,
  not a strand of hair that lies elsewhere in the other frames; :func:`usual_weights_of`: the
  same for every frame, or each frame against the reference (a strand of the current frame's).
"""

from __future__ import annotations

import numpy as np

from .geometry import vertex_normals
from .render import project_frames

__all__ = ["FACING", "USUAL", "USUAL_SAMPLES", "facing_weights", "model_vertices",
           "moved_strengths", "usual_weights", "usual_weights_of", "vertex_alpha", "smoothstep",
           "EYE_POINTS", "JAW_POINTS", "in_picture", "seen_frames"]

#: :func:`facing_weights`' ramp: a vertex that a region's reference frame sees edge-on (its
#: normal's component toward the camera below the first value) keeps the current frame's
#: texture, one it sees squarely (above the second) takes the reference frame's. What a frame
#: shows of the skin it sees edge-on is the neck, hair or an outline a few pixels off (a pale
#: V under the chin of ``make demo``'s smiling frame, from the jaw's reference frame).
FACING = (0.1, 0.4)
#: :func:`usual_weights`' ramp: a vertex of the eye region (away from the lids) whose colour in
#: the reference frame differs from its median over the clip (after the two's overall gain) by
#: the first log ratio (in the channel that differs most) starts to keep the current frame's
#: texture, and keeps it fully from the second (a factor of 1.5-2): the reference frame shows
#: something else there than the clip usually does, most often a strand of the fringe
#: (``make demo``'s forehead carried frame 3's fringe into every frame). A ramp of 0.15-0.3
#: also took the reference frame's own expression (its smile's shading) for unusual, and the
#: target's brows came back: BENCHMARKS.md, "Eighteenth session".
USUAL = (0.4, 0.7)
#: Frames sampled for :func:`usual_weights`' median (evenly spread, not lost).
USUAL_SAMPLES = 24


def facing_weights(V: np.ndarray, faces: np.ndarray, rotation: np.ndarray, verts: np.ndarray,
                   ramp: tuple[float, float] = FACING) -> np.ndarray:
    """How squarely the reference frame sees each vertex, ``(m,)`` float32 in [0, 1]: the
    smoothstep from ``ramp[0]`` to ``ramp[1]`` of the component toward the camera of the
    unit normal (:func:`facetransfer.geometry.vertex_normals`) of ``V`` (n, 3), the mesh in
    the frame (no pose), turned by the frame's ``rotation`` (3, 3), at the vertices
    ``verts`` (m,)."""
    N = vertex_normals(V, faces)[verts] @ np.asarray(rotation, np.float64).T
    return smoothstep(N[:, 2], ramp).astype(np.float32)


def model_vertices(model, topo, select: np.ndarray) -> np.ndarray:
    """``(m,) int64``: the model's vertices of the triangles ``select`` (F',) bool of
    ``topo`` (without those a closed mouth adds)."""
    verts = np.unique(np.asarray(topo.faces)[select])
    return verts[verts < model.n_vertices].astype(np.int64)


def moved_strengths(model, track, verts: np.ndarray, reference: int, scale: float,
                    ramp: tuple[float, float]) -> np.ndarray:
    """How much of a reference frame's texture each vertex ``verts`` (m,) of a region takes in
    each frame: ``(F, m) float32`` in [0, 1].

    ``d``, the distance of a vertex of the target's face in frame ``i`` (Eq. 5: its identity
    and that frame's expression, no pose) from the same vertex in the ``reference`` frame,
    divided by ``scale``, goes through a smoothstep from ``ramp[0]`` to ``ramp[1]``: the skin
    the target's own expression moved takes the reference frame; the skin that stayed keeps
    its own frame's texture, lit as the frame is.

    Parameters
    ----------
    model : MultilinearModel
    track : Track
        The target's.
    verts : (m,) int64
        The region's vertices (:func:`model_vertices`).
    reference : int
        The frame the region is textured from.
    scale : float
        The distance (model units) the ramp is a fraction of.
    ramp : (float, float)
    """
    V = model.synthesize({m: track.weights[m] for m in track.mode_names}, vertices=verts)
    d = np.sqrt(((V - V[reference]) ** 2).sum(-1))
    d /= max(float(scale), 1e-12)
    return smoothstep(d, ramp).astype(np.float32)


def usual_weights(frames, track, model, verts: np.ndarray, reference: int,
                  n_frames: int | None = None, *, ramp: tuple[float, float] = USUAL,
                  samples: int = USUAL_SAMPLES) -> np.ndarray:
    """How usual the reference frame's texture is at each vertex ``verts`` (m,): ``(m,)``
    float32 in [0, 1], 1 where it shows what the clip usually shows there.

    Each vertex's colour is read (bilinearly) in ``samples`` frames spread over the clip (of
    the first ``n_frames``, not lost) through the target's tracked mesh (Eq. 5) and camera
    (Eq. 7); ``d`` is the largest over the channels of ``|log(c_ref + 8) - log(c_med + 8) -
    g|``, the reference frame's colour against the samples' median, ``g`` the channel's median
    of that difference over the vertices (the frames' overall exposure); the weight is ``1 -
    smoothstep(d, ramp)``.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8
    track : Track
        The target's.
    model : MultilinearModel
    verts : (m,) int64
        Vertices of the model (:func:`model_vertices`).
    reference : int
    n_frames : int, optional
    ramp : (float, float)
    samples : int
    """
    return usual_weights_of(frames, track, model, verts, [int(reference)], n_frames,
                            ramp=ramp, samples=samples)[0]


def usual_weights_of(frames, track, model, verts: np.ndarray, rows, n_frames: int | None = None,
                     *, ramp: tuple[float, float] = USUAL,
                     samples: int = USUAL_SAMPLES, against: int | None = None) -> np.ndarray:
    """:func:`usual_weights` of each frame of ``rows``: ``(k, m)`` float32 in [0, 1].

    Each frame's colours (as :func:`usual_weights` reads them) are compared with the median of
    ``samples`` frames of the clip, or with frame ``against``'s: how far what a frame shows at
    a vertex differs from what the clip usually shows there, or from what that frame shows.

    Parameters
    ----------
    frames, track, model, verts, n_frames, ramp, samples
        As :func:`usual_weights`.
    rows : (k,) int
        The frames judged; a lost one gets 1.
    against : int, optional
        The frame compared with instead of the clip's median.

    Returns
    -------
    (k, m) float32
        1 everywhere when fewer than 3 of the first ``n_frames`` frames are not lost.
    """
    verts = np.asarray(verts, np.int64)
    rows = np.asarray(rows, np.int64).reshape(-1)
    lost = np.asarray(track.lost, bool)
    out = np.ones((rows.size, verts.size), np.float32)
    good = np.flatnonzero(~lost[:n_frames])
    if good.size < 3 or verts.size == 0:
        return out
    pick = good[np.unique(np.linspace(0, good.size - 1, samples).round().astype(np.int64))]
    med = np.median(_vertex_colours(frames, track, model, verts, pick), axis=0) \
        if against is None else _vertex_colours(frames, track, model, verts,
                                                np.array([int(against)]))[0]
    test = np.flatnonzero(~lost[rows])
    for lo in range(0, test.size, 512):               # (512, m, 3) meshes at a time
        k = test[lo:lo + 512]
        diff = _vertex_colours(frames, track, model, verts, rows[k]) - med
        a = np.abs(diff - np.median(diff, axis=1, keepdims=True))
        # the largest channel (NumPy's max over a last axis of 3 is many times slower)
        d = np.maximum(np.maximum(a[..., 0], a[..., 1]), a[..., 2])
        out[k] = 1.0 - smoothstep(d, ramp)
    return out


def _vertex_colours(frames, track, model, verts: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``(k, m, 3)`` float32: ``log(c + 8)`` of the colour (bilinear) under each vertex
    ``verts`` (m,) of the target's tracked mesh (Eq. 5) and camera (Eq. 7) in each frame of
    ``rows`` (k,) (one product for the k meshes)."""
    import cv2

    V = model.synthesize({m: np.asarray(track.weights[m])[rows] for m in track.mode_names},
                         vertices=verts)
    V = V.reshape(len(rows), len(verts), 3)
    out = np.empty((len(rows), len(verts), 3), np.float32)
    P = _pixels_of(track, V, rows)
    for k, r in enumerate(rows.tolist()):
        img = np.asarray(frames[r])
        (x0, x1), (y0, y1) = (_span(P[k, :, j], img.shape[1 - j]) for j in (0, 1))
        crop = img[y0:y1, x0:x1].astype(np.float32)   # the points' box, not the whole frame
        out[k] = cv2.remap(crop, P[k, None, :, 0] - x0, P[k, None, :, 1] - y0,
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    return np.log(out + 8.0)


def _pixels_of(track, V: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``(k, m, 2)`` float32: the meshes ``V`` (k, m, 3) of the frames ``rows`` (k,) seen by
    their cameras, ``track.camera(r).project(V[k])`` of each (Eq. 7), bit for bit, in a few
    products for the k frames (:func:`facetransfer.render.project_frames`)."""
    rows = np.asarray(rows, np.int64)
    return project_frames(V, np.asarray(track.rotation, np.float64)[rows],
                          np.asarray(track.scale, np.float64)[rows],
                          np.asarray(track.translation, np.float64)[rows],
                          track.pixel_aspect).astype(np.float32)


def _span(x: np.ndarray, n: int) -> tuple[int, int]:
    """The pixels ``[lo, hi)`` of an axis of ``n`` that bilinear reads at the coordinates ``x``
    touch, with a margin, clipped to the axis (outside it the border replicates the same edge
    pixels, so remapping the span gives what remapping the whole axis does); the whole axis
    when no coordinate is finite."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0, n
    lo = max(0, min(int(np.floor(x.min())) - 2, n - 1))
    return lo, max(lo + 1, min(n, int(np.ceil(x.max())) + 3))


def vertex_alpha(n: int, verts: np.ndarray, strengths: np.ndarray, *,
                 rest: float | None = None) -> np.ndarray:
    """``(n,) float32``: ``strengths`` (m,) at ``verts`` (m,); the other vertices take ``rest``,
    by default the largest of ``strengths`` (those a region's triangles have beyond the
    model's, e.g. the closed mouth's)."""
    top = (float(strengths.max()) if strengths.size else 0.0) if rest is None else float(rest)
    alpha = np.full(n, top, np.float32)
    alpha[verts] = strengths
    return alpha


def smoothstep(x: np.ndarray, ramp: tuple[float, float]) -> np.ndarray:
    """``3 t² - 2 t³`` of ``t = (x - ramp[0]) / (ramp[1] - ramp[0])`` clipped to [0, 1]."""
    t = np.clip((x - ramp[0]) / max(ramp[1] - ramp[0], 1e-12), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


#: The iBUG-68 points of the eye region (brows, eyes) and of the jaw region (jaw line, lips):
#: a reference frame shows them inside the picture (:func:`in_picture`).
EYE_POINTS = tuple(range(17, 27)) + tuple(range(36, 48))
JAW_POINTS = tuple(range(0, 17)) + tuple(range(48, 68))


def in_picture(track, points) -> np.ndarray:
    """``(F,) bool``: the frames whose tracked ``points`` (iBUG-68 numbers) all lie inside the
    frame (``landmarks2d`` within ``frame_size``); every frame where the track has no such
    points or no frame size. A region textured from a frame that shows it cut by the frame's
    edge takes the edge's pixels, stretched (walk53's ``edge.mp4``: an eye half out of the
    picture became the eye region's reference for the frames turned that way, its lids
    streaked)."""
    L = np.asarray(track.landmarks2d, np.float64)
    size = getattr(track, "frame_size", None)
    if L.ndim != 3 or L.shape[1] != 68 or size is None:
        return np.ones(len(np.asarray(track.lost)), bool)
    W, H = (float(v) for v in size)
    P = L[:, list(points)]
    return ((P >= 0).all(2) & (P[..., 0] <= W - 1) & (P[..., 1] <= H - 1)).all(1)


def seen_frames(track, good: np.ndarray, points) -> np.ndarray:
    """``good`` (frame numbers) without those whose ``points`` leave the picture, unless that
    leaves none (a close-up that cuts the chin in every frame keeps its frames)."""
    if points is None or good.size == 0:
        return good
    kept = good[in_picture(track, points)[good]]
    return kept if kept.size else good

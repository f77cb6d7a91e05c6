"""Video rewrite: render a new performance back into the target footage (Vlasic et al. 2005, §6).

For every frame of the target video (§6, Fig. 7C–7E):

1. the new face geometry (Eq. (5) with the recombined weights) is posed with the target's camera
   (Eq. (7)) and rasterised;
2. the mouth gap of the mesh is closed for texturing, as the paper does ("the mouth shapes closed-
   off for texturing", Fig. 7A–C): the inner-lip boundary loop is triangulated as a fan around an
   added centre vertex (:func:`mouth_topology`, :func:`close_mouth`);
3. the face is textured with the target's face texture (``texture="constant"``: lifted from the
   target video, one texture for the whole clip, as in the paper; ``"frame"``, the default:
   lifted from the current target frame, which keeps that frame's lighting), the mouth (lips and
   the closed gap) with the *source* performance's mouth (the source frame warped through the
   source's own tracked geometry: the performance-driven texture of §6 with the nearest
   neighbour being the source's own frame);
4. the rendered face is blended into the target frame in the gradient domain (Pérez et al.
   2003): ``blend="poisson"`` solves the Poisson equation exactly
   (:func:`facetransfer.composite.composite_face`); ``"fast"`` (default, ~5x faster) adds a
   membrane correction interpolated from the region's outline (:func:`membrane_blend`). The
   blend region stays a few pixels inside the rendered silhouette, so its boundary lies on the
   target's own face. The mesh's eye holes are not part of the rendered mask, so the target's
   own eyes show through them (§6); outside the (feathered) face mask the output equals the
   target frame exactly. Frames where the face is lost keep the original frame.

Texture lookups are done in image space: a vertex's texture coordinate is its projection into the
frame the texture comes from, so a triangle of the new mesh shows the same triangle of the frame
(an affine warp per triangle).

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, §6, Fig. 7.
Pérez, Gangnet, Blake. Poisson image editing. SIGGRAPH 2003.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from .errors import FaceTransferError, ShapeError, VideoError
from .io.video import has_audio, mux_audio  # noqa: F401 - moved there, kept importable

log = logging.getLogger(__name__)

__all__ = [
    "RewriteError",
    "TEXTURE_MODES",
    "BLEND_MODES",
    "MeshTopology",
    "mesh_topology",
    "boundary_loops",
    "close_mouth",
    "frame_uvs",
    "FaceTexture",
    "constant_face_texture",
    "merged_face_texture",
    "MOUTH_MODES",
    "MOUTH_MAX_FRAMES",
    "MouthFunction",
    "mouth_texture_function",
    "default_mouth_mode",
    "resolve_mouth_mode",
    "membrane_blend",
    "RewriteFrame",
    "rewrite_frame",
    "rewrite_frames",
    "has_audio",
    "mux_audio",
    "write_video_with_audio",
    "landmark_track",
    "obtain_track",
    "nearest_frames",
    "SPEED_PRESETS",
    "track_options",
    "TransferPlan",
    "plan_transfer",
    "TransferResult",
    "render_plan",
    "transfer_video",
    "write_mesh_sequence",
]

TEXTURE_MODES = ("constant", "frame")
#: Where the mouth texture comes from: the mouth source's frame at the matched time
#: (``"frame"``) or the performance-driven texture function of §6 (``"function"``).
MOUTH_MODES = ("frame", "function")
#: The mouth texture function lifts at most this many (evenly spaced) frames: float32 textures
#: of ``T x T`` texels take ``16 T²`` bytes each (120 frames at T = 256: 126 MB).
MOUTH_MAX_FRAMES = 120
#: Ways to put the rendered face into the frame: Pérez et al.'s Poisson solve (exact), a
#: membrane (harmonic-like) correction interpolated by push-pull (fast), or a hard paste.
BLEND_MODES = ("fast", "poisson", "none")
#: Tracking presets of a transfer (:func:`track_options`), fastest first.
SPEED_PRESETS = ("fast", "balanced", "quality")
#: The preset of :func:`plan_transfer` and the CLI: as accurate as "balanced" on the synthetic
#: footage and the real clips measured (see :func:`track_options`), a third of its time.
DEFAULT_SPEED = "fast"


class RewriteError(FaceTransferError):
    """Frames, tracks or a model that cannot be rendered back into footage."""


# ---------------------------------------------------------------------------------------------
# mesh topology: boundary loops, the mouth gap, the eye holes
# ---------------------------------------------------------------------------------------------

def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary edges (edges of exactly one triangle) of a triangle mesh.

    Parameters
    ----------
    faces : (F, 3) int64

    Returns
    -------
    list of (k,) int64
        Vertex indices in loop order; longest first.
    """
    F = np.asarray(faces, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # directed half-edges
    key = np.sort(E, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    bnd = E[cnt[inv.ravel()] == 1]  # directed boundary half-edges (a -> b)
    nxt: dict[int, int] = {}
    for a, b in bnd:
        nxt.setdefault(int(a), int(b))
    loops, seen = [], set()
    for s in list(nxt):
        if s in seen:
            continue
        loop, cur = [], s
        while cur not in seen and cur in nxt:
            seen.add(cur)
            loop.append(cur)
            cur = nxt[cur]
        if len(loop) >= 3:
            loops.append(np.asarray(loop, dtype=np.int64))
    loops.sort(key=len, reverse=True)
    return loops


@dataclass(frozen=True)
class MeshTopology:
    """The model mesh prepared for texturing.

    Attributes
    ----------
    n_vertices : int
        Vertices of the model; the closed mesh appends one centre vertex of the mouth (index
        ``n_vertices``) when there is a mouth gap.
    faces : (F', 3) int64
        Model faces followed by the mouth-closing fan.
    mouth_loop : (k,) int64
        The inner-lip boundary loop (empty when the mesh has no mouth gap).
    mouth_faces : (m,) int64
        Indices into ``faces`` of the triangles textured from the source's mouth.
    eye_loops : tuple of (k,) int64
        The eye holes, left open so that the target's eyes show through (§6).
    """

    n_vertices: int
    faces: np.ndarray
    mouth_loop: np.ndarray
    mouth_faces: np.ndarray
    eye_loops: tuple

    @property
    def n_closed(self) -> int:
        """Vertices of the closed mesh."""
        return self.n_vertices + (1 if self.mouth_loop.size else 0)


def mesh_topology(model, *, mouth_rings: int = 1, lips: bool = True) -> MeshTopology:
    """Find the mouth gap and eye holes of the model's mesh and close the mouth (§6, Fig. 7A).

    Boundary loops are classified by the nearest iBUG-68 landmark group of the model's mean
    face: inner lips (60–67) for the mouth, eyes (36–41, 42–47). The mouth loop is closed by a
    fan around its centroid; the triangles of the fan, the ``mouth_rings`` rings of model
    triangles around the loop and (``lips``) the lips form the mouth region textured from the
    source.

    Parameters
    ----------
    model : MultilinearModel
    mouth_rings : int
        Rings of lip triangles around the gap that also take the source's mouth texture.
    lips : bool
        Also the triangles inside the outer lip contour (iBUG 48–59): the whole mouth, lips
        included, comes from the source (§6: "the mouth texture from the source video").

    Returns
    -------
    MeshTopology
    """
    F = np.asarray(model.faces, dtype=np.int64)
    n = int(model.n_vertices)
    loops = boundary_loops(F)
    empty = np.zeros(0, np.int64)
    if model.landmarks is None or len(loops) < 2:
        return MeshTopology(n, F, empty, empty, ())
    V = model.synthesize(model.default_weights())
    lm = V[np.asarray(model.landmarks)]
    centres = {"mouth": lm[60:68].mean(0), "eye_r": lm[36:42].mean(0), "eye_l": lm[42:48].mean(0)}
    size = float(np.linalg.norm(lm[36] - lm[45])) or 1.0  # outer eye corners: face scale
    best: dict[str, tuple[float, int]] = {}
    for li, loop in enumerate(loops[1:], start=1):  # loops[0] is the outer boundary
        c = V[loop].mean(0)
        for name, ctr in centres.items():
            d = float(np.linalg.norm(c - ctr))
            if d < 0.35 * size and (name not in best or d < best[name][0]):
                best[name] = (d, li)
    eyes = tuple(loops[best[k][1]] for k in ("eye_r", "eye_l") if k in best)
    if "mouth" not in best:
        log.info("the model mesh has no mouth gap; nothing to close")
        return MeshTopology(n, F, empty, empty, eyes)
    loop = loops[best["mouth"][1]]
    # fan around a new centre vertex n; orient like the adjacent triangles (loop is a boundary
    # traversed along its half-edges, so the fan (b, a, centre) continues the surface's winding)
    fan = np.stack([np.roll(loop, -1), loop, np.full_like(loop, n)], axis=1)
    faces = np.concatenate([F, fan])
    mouth = set(range(F.shape[0], faces.shape[0]))
    ring = set(int(v) for v in loop)
    for _ in range(int(mouth_rings)):
        touch = np.flatnonzero(np.isin(F, list(ring)).any(axis=1))
        mouth.update(int(t) for t in touch)
        ring.update(int(v) for v in F[touch].ravel())
    if lips:
        # the lips: triangles inside the outer lip contour (iBUG 48-59) seen from the front,
        # grown by 10% about its centre
        from matplotlib.path import Path as _Path

        poly = lm[48:60, :2]
        ctr = poly.mean(0)
        inside = _Path(ctr + 1.1 * (poly - ctr)).contains_points(V[:, :2])
        inside &= V[:, 2] > V[loop, 2].min() - 0.5 * size  # the front of the face only
        mouth.update(int(t) for t in np.flatnonzero(inside[F].all(axis=1)))
    return MeshTopology(n, faces, loop, np.asarray(sorted(mouth), dtype=np.int64), eyes)


def close_mouth(vertices: np.ndarray, topo: MeshTopology) -> np.ndarray:
    """Append the mouth's centre vertex (mean of the inner-lip loop) to each mesh.

    Parameters
    ----------
    vertices : (..., n_vertices, 3)
    topo : MeshTopology

    Returns
    -------
    (..., topo.n_closed, 3)
    """
    V = np.asarray(vertices, dtype=np.float64)
    if V.shape[-2:] != (topo.n_vertices, 3):
        raise ShapeError(f"vertices must be (..., {topo.n_vertices}, 3), got {V.shape}")
    if not topo.mouth_loop.size:
        return V
    c = V[..., topo.mouth_loop, :].mean(axis=-2, keepdims=True)
    return np.concatenate([V, c], axis=-2)


def frame_uvs(vertices: np.ndarray, camera, size: tuple[int, int]) -> np.ndarray:
    """Texture coordinates that look a mesh up in the frame it was tracked in.

    ``uv = (x / (W - 1), 1 - y / (H - 1))`` of each vertex's projection (Eq. (7)), so that
    :func:`facetransfer.render.sample_texture` with the frame as texture returns the frame's
    pixel under the vertex.

    Parameters
    ----------
    vertices : (n, 3)
    camera : WeakPerspective
    size : (W, H)

    Returns
    -------
    (n, 2) float64
    """
    W, H = size
    p = camera.project(vertices)
    return np.stack([p[:, 0] / max(W - 1, 1), 1.0 - p[:, 1] / max(H - 1, 1)], axis=1)


# ---------------------------------------------------------------------------------------------
# texture
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FaceTexture:
    """A texture image and the texture coordinates of the closed mesh's vertices.

    Attributes
    ----------
    image : (Ht, Wt, 3) uint8
    uvs : (n_closed, 2) float64
        ``(u, v)`` with v up (see :func:`frame_uvs`).
    frame : int
        The target frame it was lifted from (-1 if merged from several).
    """

    image: np.ndarray
    uvs: np.ndarray
    frame: int = -1


def _reference_frame(track, model, n_frames: int | None = None) -> int:
    """The target frame to lift the constant face texture from: not lost, facing the camera,
    mouth closest to neutral, most confident (among the first ``n_frames``)."""
    good = np.flatnonzero(~track.lost[:n_frames])
    if good.size == 0:
        raise RewriteError(f"the face is lost in every frame of {track.source or 'the target'}")
    facing = track.rotation[good, 2, 2]  # cos of the angle between the face's z and the view
    score = facing + 0.5 * track.confidence[good]
    if "expression" in track.weights:
        k = model.mode_index("expression")
        ref = model.training_weights(k, "neutral") if "neutral" in model.labels[k] \
            else model.weight_mean(k)
        dist = np.linalg.norm(track.weights["expression"][good] - ref, axis=1)
        score = score - 0.5 * dist / (dist.max() + 1e-12)
    return int(good[np.argmax(score)])


def constant_face_texture(frames, track, model, topo: MeshTopology, *,
                          frame: int | None = None) -> FaceTexture:
    """The target's face texture, constant over the clip (§6: "the face texture from the target
    video (constant throughout the sequence)").

    The texture is one reference frame of the target (facing the camera, near-neutral mouth,
    chosen by :func:`_reference_frame` unless ``frame`` is given) looked up through the target's
    tracked geometry in that frame.

    Parameters
    ----------
    frames : (F, H, W, 3) uint8 or sequence of frames
    track : Track
        The target's track (its own weights and pose).
    model : MultilinearModel
    topo : MeshTopology
    frame : int, optional

    Returns
    -------
    FaceTexture
    """
    i = _reference_frame(track, model, len(frames)) if frame is None else int(frame)
    V = close_mouth(model.synthesize(track.weights_at(i)), topo)
    img = np.asarray(frames[i])
    return FaceTexture(img, frame_uvs(V, track.camera(i), (img.shape[1], img.shape[0])), i)


def merged_face_texture(frames, track, model, topo: MeshTopology, *, n_samples: int = 8,
                        tex_size: int = 1024) -> FaceTexture:
    """The target's face texture merged over several frames in the model's UV layout (§6).

    ``n_samples`` frames spread over the clip (face not lost) are lifted into a UV texture
    (:func:`facetransfer.texture.lift_uv_texture`, each texel weighted by visibility and
    obliqueness) and merged (:func:`facetransfer.texture.merge_textures`): "the face texture
    from the target video (constant throughout the sequence)". The closing vertex of the mouth
    takes the mean UV of the inner-lip loop (the mouth itself is textured from the source).

    Returns
    -------
    FaceTexture
        ``frame = -1``.
    """
    from .texture import lift_uv_texture, merge_textures, texture_to_uint8, uv_atlas

    if model.uvs is None:
        raise RewriteError("the model has no UVs: use the reference-frame texture")
    n = min(len(frames), track.n_frames)
    good = np.flatnonzero(~track.lost[:n])
    if good.size == 0:
        raise RewriteError(f"the face is lost in every frame of {track.source or 'the target'}")
    pick = np.unique(good[np.linspace(0, good.size - 1, min(n_samples, good.size))
                          .round().astype(int)])
    faces = np.asarray(model.faces)
    atlas = uv_atlas(faces, model.uvs, tex_size)
    lifted = [lift_uv_texture(np.asarray(frames[i]), model.synthesize(track.weights_at(i)),
                              faces, model.uvs, track.camera(i), tex_size, atlas=atlas)
              for i in pick]
    img = texture_to_uint8(merge_textures(lifted).texture)
    uvs = np.asarray(model.uvs, np.float64)
    if topo.mouth_loop.size:
        uvs = np.vstack([uvs, uvs[topo.mouth_loop].mean(axis=0)])
    return FaceTexture(img, uvs, -1)


def _shade(raster, faces: np.ndarray, uvs: np.ndarray, texture: np.ndarray,
           select: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Texture the pixels of a raster: ``(image (H, W, 3) uint8, mask (H, W) bool)``.

    ``select`` (F',) bool restricts to some triangles (the rest stay black, outside the mask).
    One pass of :func:`facetransfer.render.shade_texture`.
    """
    from .render import shade_texture

    return shade_texture(raster, faces, uvs, np.asarray(texture, np.uint8), select)


# ---------------------------------------------------------------------------------------------
# the performance-driven mouth texture (§6)
# ---------------------------------------------------------------------------------------------

_NO_UVS = ("mouth='function' (the texture function of §6) needs a model with texture "
           "coordinates (UVs); this model has none: use mouth='frame'")


def _closed_uvs(model, topo: MeshTopology) -> np.ndarray:
    """The model's UVs for the closed mesh: the mouth's centre vertex takes the mean UV of the
    inner-lip loop (as in :func:`merged_face_texture`), ``(topo.n_closed, 2)``."""
    if model.uvs is None:
        raise RewriteError(_NO_UVS)
    uvs = np.asarray(model.uvs, np.float64)
    if topo.mouth_loop.size:
        uvs = np.vstack([uvs, uvs[topo.mouth_loop].mean(axis=0)])
    return uvs


class MouthFunction:
    """The performance-driven mouth texture of §6 in the model's UV layout.

    A :class:`facetransfer.texture.TextureFunction` over UV textures of the *closed* mesh (the
    mouth-closing fan included, so the mouth's inside is lifted too) lifted from tracked frames
    of the mouth source and indexed by their attribute vectors
    (:func:`facetransfer.texture.attribute_vector`: expression [+ viseme] weights). Build it
    with :func:`mouth_texture_function`; :meth:`face_texture` gives the mouth texture for a new
    attribute vector, ready for :func:`rewrite_frame`'s ``mouth_texture``.

    Attributes
    ----------
    function : TextureFunction
    uvs : (n_closed, 2) float64
        Texture coordinates of the closed mesh (v up).
    frames : (m,) int64
        The lifted frames (indices into the clip's frames).
    """

    def __init__(self, function, uvs: np.ndarray, frames: np.ndarray) -> None:
        self.function = function
        self.uvs = np.asarray(uvs, np.float64)
        self.frames = np.asarray(frames, np.int64)
        self._last: tuple[bytes, np.ndarray] | None = None

    @property
    def n_attributes(self) -> int:
        return int(self.function.attributes.shape[1])

    def texture(self, attributes: np.ndarray) -> np.ndarray:
        """The mouth texture for one attribute vector (r,): Eq. (2) of
        :class:`~facetransfer.texture.TextureFunction`, ``(T, T, 3) uint8``."""
        from .texture import texture_to_uint8

        a = np.asarray(attributes, np.float64)
        key = a.tobytes()
        last = self._last
        if last is not None and last[0] == key:  # consecutive frames often repeat a query
            return last[1]
        img = texture_to_uint8(self.function(a))
        self._last = (key, img)
        return img

    def face_texture(self, attributes: np.ndarray) -> FaceTexture:
        """:meth:`texture` with the closed mesh's UVs, as a :class:`FaceTexture` (frame -1)."""
        return FaceTexture(self.texture(attributes), self.uvs, -1)


def _even_pick(rows: np.ndarray, limit: int) -> np.ndarray:
    """At most ``limit`` entries of ``rows``, evenly spaced, first and last kept."""
    if rows.size <= limit:
        return rows
    return rows[np.unique(np.linspace(0, rows.size - 1, limit).round().astype(np.int64))]


def mouth_texture_function(model, frames, track, topo: MeshTopology | None = None, *,
                           frame_index: np.ndarray | None = None, tex_size: int = 256,
                           step: int = 1, max_frames: int = MOUTH_MAX_FRAMES, k: int = 4,
                           kernel: str = "inverse", bandwidth: float | None = None,
                           progress: Callable[[int], None] | None = None) -> MouthFunction:
    """Lift the mouth source's frames into a performance-driven texture function (§6).

    §6: "A simple performance-driven texture function can be obtained with the weighted sum of
    nearest neighbors" (in attribute space). Every used frame's closed mesh (Eq. (5), mouth
    closed as in :func:`close_mouth`) is posed with its camera (Eq. (7)) and a UV texture is
    lifted from the frame (:func:`facetransfer.texture.lift_uv_texture`, texels weighted by
    visibility and obliqueness); the textures and the frames' attribute vectors make a
    :class:`~facetransfer.texture.TextureFunction` with ``k`` neighbours and a Gaussian kernel.

    Memory: the lifted textures are float32, ``16 T²`` bytes per frame, so at most
    ``max_frames`` frames (default :data:`MOUTH_MAX_FRAMES` = 120, about 126 MB at T = 256) are
    lifted, evenly spaced over the usable ones (every ``step``-th, face not lost).

    Parameters
    ----------
    model : MultilinearModel
        Needs UVs and a mode besides identity (the attributes).
    frames : sequence of (H, W, 3) uint8
        The mouth source's frames.
    track : Track
        Row ``i`` is the pose and weights of ``frames[frame_index[i]]``.
    topo : MeshTopology, optional
        Default :func:`mesh_topology` of the model.
    frame_index : (track.n_frames,) int, optional
        Default ``arange``: row i of the track is frame i. Repeated frames are lifted once.
    tex_size : int
        ``T``, the texture's width and height in texels.
    step : int
        Use every ``step``-th track row.
    max_frames : int
        Cap on the lifted frames (memory, above).
    k : int
        Neighbours of the texture function.
    progress : callable(int), optional
        Called with 1 after each lifted frame.

    Returns
    -------
    MouthFunction

    Raises
    ------
    RewriteError
        No UVs, no attribute mode, bad ``step``/``max_frames``, or no usable frame.

    References
    ----------
    Vlasic et al. 2005, §6 (texture from video, the performance-driven texture function).
    """
    from .texture import TextureFunction, attribute_vector, lift_uv_texture, uv_atlas

    if len(model.mode_names) < 2:
        raise RewriteError("mouth='function' needs a model with an expression or viseme mode")
    topo = mesh_topology(model) if topo is None else topo
    uvs = _closed_uvs(model, topo)
    for name, val in (("step", step), ("max_frames", max_frames), ("tex_size", tex_size)):
        if int(val) != val or val < 1:
            raise RewriteError(f"{name} must be an integer >= 1, got {val!r}")
    n = int(track.n_frames)
    idx = np.arange(n) if frame_index is None else np.asarray(frame_index, np.int64)
    if idx.shape != (n,):
        raise RewriteError(f"frame_index must have one entry per track row ({n}), "
                           f"got shape {idx.shape}")
    if n and (idx.min() < 0 or idx.max() >= len(frames)):
        raise RewriteError(f"frame_index refers to frames outside 0..{len(frames) - 1}")
    rows = np.arange(0, n, int(step))
    rows = rows[~np.asarray(track.lost, bool)[rows]]
    _, first = np.unique(idx[rows], return_index=True)  # each frame once (its first row)
    rows = _even_pick(np.sort(rows[first]), int(max_frames))
    if rows.size == 0:
        raise RewriteError(f"no frame to lift a mouth texture from: the face is lost in every "
                           f"frame of {getattr(track, 'source', '') or 'the mouth source'}")
    faces = topo.faces
    atlas = uv_atlas(faces, uvs, int(tex_size))
    # texels of the mouth-closing fan (its triangles come after the model's)
    gap = atlas.texel_tri >= int(np.asarray(model.faces).shape[0])
    textures = np.empty((rows.size, int(tex_size), int(tex_size), 3), np.float32)
    weights = np.empty((rows.size, int(tex_size), int(tex_size)), np.float32)
    attrs = np.empty((rows.size, len(attribute_vector(model, track.weights_at(int(rows[0]))))))
    for j, r in enumerate(rows):
        w = track.weights_at(int(r))
        V = close_mouth(model.synthesize(w), topo)  # Eq. (5), mouth closed
        frame = np.asarray(frames[int(idx[r])])
        cam = track.camera(int(r))
        lifted = lift_uv_texture(frame, V, faces, uvs, cam, int(tex_size), atlas=atlas)
        textures[j], weights[j] = lifted.texture, lifted.weight
        if gap.any():
            _fill_closed_gap(textures[j], weights[j], frame, V, cam, atlas, gap)
        attrs[j] = attribute_vector(model, w)
        if progress:
            progress(1)
    log.info("mouth texture function: %d frames lifted at %dx%d", rows.size, tex_size, tex_size)
    fn = TextureFunction(textures, weights, attrs, k=k, kernel=kernel, bandwidth=bandwidth)
    return MouthFunction(fn, uvs, idx[rows])


def resolve_mouth_mode(mouth: str | None, model, *, performance: bool = False) -> str:
    """Validate ``mouth`` (None: :func:`default_mouth_mode`) against :data:`MOUTH_MODES` and the
    model (``"function"`` needs UVs; a default of ``"function"`` falls back to ``"frame"`` for
    a model without UVs)."""
    if mouth is None:
        mouth = default_mouth_mode(performance)
        if mouth == "function" and model.uvs is None:
            log.info("the model has no UVs: the mouth comes from the nearest frame")
            return "frame"
    if mouth not in MOUTH_MODES:
        raise RewriteError(f"mouth must be one of {', '.join(MOUTH_MODES)}, got {mouth!r}")
    if mouth == "function" and model.uvs is None:
        raise RewriteError(_NO_UVS)
    return mouth


#: weight of the closed gap's texels where a frame did not see them (:func:`_fill_closed_gap`)
_GAP_FLOOR = 1e-3


def _fill_closed_gap(texture: np.ndarray, weight: np.ndarray, frame: np.ndarray,
                     vertices: np.ndarray, camera, atlas, gap: np.ndarray) -> None:
    """Give the unseen texels of the mouth-closing fan the colour under their projection.

    With the mouth (nearly) closed the fan has (nearly) no area in the frame, so
    :func:`~facetransfer.texture.lift_uv_texture` sees none of it; left at weight 0, those
    texels of a closed-mouth neighbour would take the texture function's all-frame mean, i.e.
    the inside of the open mouths. Here they take the frame's colour where they project (the
    seam between the lips, as the ``"frame"`` mouth shows it) with the small weight
    :data:`_GAP_FLOOR`, so any neighbour that did see them still wins. In place.
    """
    from .render import sample_texture

    T = atlas.tex_size
    unseen = (gap & (weight < _GAP_FLOOR)).ravel()
    covered = atlas.mask.ravel()
    sel = unseen[covered]  # among the covered texels, row-major: atlas.interpolate's order
    if not sel.any():
        return
    P = atlas.interpolate(vertices)[sel]  # (m, 3) surface points of those texels
    H, W = frame.shape[:2]
    p = camera.project(P)
    uv = np.stack([p[:, 0] / max(W - 1, 1), 1.0 - p[:, 1] / max(H - 1, 1)], axis=1)
    flat = np.flatnonzero(unseen)
    texture.reshape(T * T, 3)[flat] = sample_texture(frame, uv).astype(np.float32)
    weight.reshape(T * T)[flat] = _GAP_FLOOR


def default_mouth_mode(performance: bool) -> str:
    """The default mouth mode: ``"function"`` for a ready (edited) performance, ``"frame"`` for
    a transfer.

    An edit asks for attributes no frame of the footage shows: on synthetic footage whose mouth
    texture changes with the expression, the function's in-between mouth is 6-12 dB closer to
    the truth than the nearest frame's (``tests/test_transfer_mouth.py``). In a transfer every
    output frame has the attributes of a source frame, so the function (then about that
    frame's own texture) measured only +0.2 dB on the face, +0.5 dB on the mouth
    (``benchmarks/bench_transfer.py`` part (a)) for ~50 ms of lifting per source frame (up to
    :data:`MOUTH_MAX_FRAMES`) and ~5 ms per output frame.
    """
    return "function" if performance else "frame"


# ---------------------------------------------------------------------------------------------
# blending
# ---------------------------------------------------------------------------------------------

def _extend(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``img`` inside ``mask``, its nearest inside pixel outside (no step across the outline)."""
    import scipy.ndimage as ndi

    if mask.all() or not mask.any():
        return img.copy()
    _, (iy, ix) = ndi.distance_transform_edt(~mask, return_indices=True)
    return img[iy, ix]


#: 4-connected structuring element (``scipy.ndimage``'s default for binary morphology)
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


def _erode(mask: np.ndarray, iterations: int) -> np.ndarray:
    """Binary erosion by the 4-connected cross, pixels beyond the image counting as outside
    (equal to ``scipy.ndimage.binary_erosion(mask, iterations=iterations)``)."""
    import cv2

    return cv2.erode(mask.astype(np.uint8), _CROSS, iterations=int(iterations),
                     borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


#: :func:`rewrite_frames` synthesises all of a clip's meshes up front below this many bytes
_MESH_CACHE_BYTES = 1 << 30

#: the mean of the 4 neighbours (a Jacobi sweep of Laplace's equation)
_FOUR_NEIGHBOURS = np.array([[0, 0.25, 0], [0.25, 0, 0.25], [0, 0.25, 0]], np.float32)


def membrane_blend(target: np.ndarray, source: np.ndarray, mask: np.ndarray, *,
                   feather: float = 2.0, margin: int = 8,
                   smooth_iterations: int = 10, outlier: float | None = 40.0) -> np.ndarray:
    """Seamless paste by a membrane correction (an approximation of Poisson blending).

    Poisson image editing with the source's own gradients as guidance (Pérez et al. 2003,
    Eq. (7)–(10)) gives ``f = source + h`` inside the mask, with ``h`` harmonic and equal to
    ``target − source`` on the outline. Here the outline is the region's own border (its pixels
    with a neighbour outside), so the source is only read inside the mask; ``h`` is interpolated
    into the region from the outline by pyramid push-pull (smooth, linear time) and a few
    Jacobi sweeps of Laplace's equation, instead of solving the sparse system; the seam is then
    feathered over ``feather`` pixels inside the mask. Outside the mask the result is ``target``
    exactly.

    Parameters
    ----------
    target, source : (H, W, 3) uint8
        ``source`` is read inside ``mask`` only.
    mask : (H, W) bool
    feather : float
        Width in pixels of the inside band where the result fades to the target.
    margin : int
        Pixels around the mask's bounding box in the working crop.
    smooth_iterations : int
        Jacobi sweeps of Laplace's equation applied to the push-pull membrane.
    outlier : float or None
        Outline pixels whose target-source difference exceeds this (0..255 scale, any channel)
        do not constrain the membrane (None: all do).

    Returns
    -------
    (H, W, 3) uint8
    """
    import cv2

    from .texture import fill_holes

    T = np.asarray(target)
    out = T.copy()
    mask = np.asarray(mask, bool)
    bx, by, bw, bh = cv2.boundingRect(mask.view(np.uint8))
    if bw == 0 or bh == 0:
        return out
    H, W = mask.shape
    y0, y1 = max(by - margin, 0), min(by + bh + margin, H)
    x0, x1 = max(bx - margin, 0), min(bx + bw + margin, W)
    m = mask[y0:y1, x0:x1]
    m8 = m.view(np.uint8)
    t = T[y0:y1, x0:x1].astype(np.float32)
    s = np.asarray(source)[y0:y1, x0:x1].astype(np.float32)
    # the outline: region pixels with one of their 8 neighbours outside (the crop's edge counts
    # as outside); the interior is the rest of the region
    interior = cv2.erode(m8, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                         borderValue=0).view(bool)
    ring = m & ~interior
    ry, rx = np.nonzero(ring)
    dr = t[ry, rx] - s[ry, rx]                       # target - source on the outline
    if outlier is not None:
        # outline pixels where target and source disagree wildly (the silhouette moved with
        # the new expression, or hair crosses it) would bleed into the face: leave them out
        ok = np.abs(dr).max(axis=-1) < float(outlier)
        if ok.sum() >= 0.25 * ok.size and not ok.all():
            ring[ry[~ok], rx[~ok]] = False
            interior = m & ~ring
            ry, rx, dr = ry[ok], rx[ok], dr[ok]
    d = np.zeros_like(t)
    d[ry, rx] = dr
    h = fill_holes(d, ring)  # (h, w, 3): the membrane, = target - source on the outline
    # Jacobi sweeps of Laplace's equation (the mean of the 4 neighbours, one 3x3 filter per
    # sweep) smooth the push-pull result towards harmonic; the outline keeps its values
    h = np.ascontiguousarray(h, dtype=np.float32)
    inner3 = np.repeat(interior[..., None], h.shape[2], axis=2)
    for _ in range(int(smooth_iterations)):
        np.copyto(h, cv2.filter2D(h, -1, _FOUR_NEIGHBOURS, borderType=cv2.BORDER_REPLICATE),
                  where=inner3)
    f = s + h
    if feather > 0:
        # distance to the nearest pixel outside the region (the crop's margin is outside)
        dist = cv2.distanceTransform(m8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        a = np.clip(dist / float(feather), 0.0, 1.0)[..., None]
        f = a * f + (1.0 - a) * t
    crop = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    out[y0:y1, x0:x1] = np.where(m[..., None], crop, T[y0:y1, x0:x1])
    return out


# ---------------------------------------------------------------------------------------------
# one frame
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RewriteFrame:
    """One rewritten frame.

    Attributes
    ----------
    image : (H, W, 3) uint8
        The composite.
    rendered : (H, W, 3) uint8
        The textured new face before blending (black outside ``face_mask``).
    face_mask : (H, W) bool
        Pixels covered by the closed new mesh (eye holes excluded).
    mouth_mask : (H, W) bool
        Pixels textured from the source's mouth.
    """

    image: np.ndarray
    rendered: np.ndarray
    face_mask: np.ndarray
    mouth_mask: np.ndarray


def rewrite_frame(target_frame: np.ndarray, vertices: np.ndarray, camera, topo: MeshTopology,
                  face_texture: FaceTexture, *, mouth_texture: FaceTexture | None = None,
                  blend: str = "fast", feather: float = 2.0, erode: int = 2,
                  mouth_feather: float = 3.0, color_match: bool = False) -> RewriteFrame:
    """Render the new face into one target frame (§6).

    Parameters
    ----------
    target_frame : (H, W, 3) uint8
    vertices : (n_vertices, 3) or (n_closed, 3)
        The new face (Eq. (5)) in model coordinates; the mouth is closed here if needed.
    camera : WeakPerspective
        The target's pose at this frame (Eq. (7)).
    topo : MeshTopology
    face_texture : FaceTexture
        The target's face texture (uvs for the closed mesh).
    mouth_texture : FaceTexture, optional
        The source's mouth for this frame; without it the face texture covers the mouth.
    blend : {"fast", "poisson", "none"}
        :func:`membrane_blend` (fast), Poisson blending
        (:func:`facetransfer.composite.composite_face`, exact sparse solve) or a hard paste.
    feather : float
        Soft-edge radius of the blend in pixels.
    erode : int
        The blend region is the rendered face mask eroded by this many pixels.
    mouth_feather : float
        Soft-edge width in pixels of the source's mouth inside the face (``blend="fast"``).
    color_match : bool
        Match the rendered face's colour statistics to the target's before the Poisson blend.

    Returns
    -------
    RewriteFrame
    """
    T = np.asarray(target_frame)
    if T.ndim != 3 or T.shape[2] != 3 or T.dtype != np.uint8:
        raise ShapeError(f"target frame must be (H, W, 3) uint8, got {T.shape} {T.dtype}")
    if blend not in BLEND_MODES:
        raise RewriteError(f"blend must be one of {', '.join(BLEND_MODES)}, got {blend!r}")
    H, W = T.shape[:2]
    V = np.asarray(vertices, dtype=np.float64)
    if V.shape[0] == topo.n_vertices:
        V = close_mouth(V, topo)
    if V.shape != (topo.n_closed, 3):
        raise ShapeError(f"vertices must be ({topo.n_vertices} or {topo.n_closed}, 3), "
                         f"got {V.shape}")
    # all per-frame work happens in the face's bounding box (plus a margin wider than any
    # filter below: erosion, outline ring, membrane margin, feathering); the rest is T
    box = _face_box(V, camera, (W, H), margin=int(erode) + int(np.ceil(feather)) + 16)
    if box is None:  # nothing of the face in the frame
        return _paste(T, None)
    x0, y0, x1, y1 = box
    cam = camera if box == (0, 0, W, H) else _shift_camera(camera, x0, y0)
    res = _rewrite_crop(T[y0:y1, x0:x1], V, cam, topo, face_texture, mouth_texture, blend,
                        feather, erode, mouth_feather, color_match)
    return _paste(T, (box, res))


def _paste(T: np.ndarray, part) -> RewriteFrame:
    """The full frame from ``(box, crop result)``; ``None``: the frame unchanged, no face."""
    H, W = T.shape[:2]
    if part is None:
        empty = np.zeros((H, W), bool)
        return RewriteFrame(T.copy(), np.zeros_like(T), empty, empty.copy())
    (x0, y0, x1, y1), res = part
    if (x0, y0, x1, y1) == (0, 0, W, H):
        return res

    def paste(crop, base):
        base[y0:y1, x0:x1] = crop
        return base

    return RewriteFrame(paste(res.image, T.copy()), paste(res.rendered, np.zeros_like(T)),
                        paste(res.face_mask, np.zeros((H, W), bool)),
                        paste(res.mouth_mask, np.zeros((H, W), bool)))


def _crop_of(T: np.ndarray, frame: RewriteFrame):
    """``(box, crop result)`` of a rewritten frame: the inverse of :func:`_paste`, cropped to
    the pixels that differ from ``T`` or belong to the face (small to send between
    processes); None when nothing changed."""
    changed = frame.face_mask | frame.mouth_mask | (frame.image != T).any(axis=-1)
    changed |= frame.rendered.any(axis=-1)
    if not changed.any():
        return None
    ys = np.flatnonzero(changed.any(axis=1))
    xs = np.flatnonzero(changed.any(axis=0))
    y0, y1, x0, x1 = int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1
    sl = (slice(y0, y1), slice(x0, x1))
    return (x0, y0, x1, y1), RewriteFrame(frame.image[sl].copy(), frame.rendered[sl].copy(),
                                          frame.face_mask[sl].copy(),
                                          frame.mouth_mask[sl].copy())


def _face_box(V: np.ndarray, camera, size: tuple[int, int], *, margin: int
              ) -> tuple[int, int, int, int] | None:
    """``(x0, y0, x1, y1)`` (end exclusive) of the mesh's projection grown by ``margin``
    pixels and clipped to the frame; the whole frame for cameras other than weak perspective;
    None when the projection misses the frame."""
    from .render import WeakPerspective

    W, H = size
    if not isinstance(camera, WeakPerspective):
        return 0, 0, W, H
    p = camera.project(V)
    p = p[np.isfinite(p).all(axis=1)]
    if p.size == 0:
        return None
    lo = np.floor(p.min(axis=0)).astype(np.int64) - margin
    hi = np.ceil(p.max(axis=0)).astype(np.int64) + margin + 1
    x0, y0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    x1, y1 = min(int(hi[0]), W), min(int(hi[1]), H)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _shift_camera(camera, x0: int, y0: int):
    """The camera of the crop whose top-left pixel is ``(x0, y0)`` of the frame."""
    import dataclasses

    t = np.asarray(camera.translation, np.float64) - np.array([x0, y0], np.float64)
    return dataclasses.replace(camera, translation=t)


def _rewrite_crop(T, V, camera, topo, face_texture, mouth_texture, blend, feather, erode,
                  mouth_feather, color_match) -> RewriteFrame:
    """:func:`rewrite_frame` on a crop ``T`` of the frame, ``camera`` shifted to the crop."""
    from .render import rasterize

    H, W = T.shape[:2]
    raster = rasterize(V, topo.faces, camera, (W, H))
    face_img, face_mask = _shade(raster, topo.faces, face_texture.uvs, face_texture.image)
    mouth_mask = np.zeros((H, W), bool)
    rendered = face_img
    mouth_img = None
    if mouth_texture is not None and topo.mouth_faces.size:
        sel = np.zeros(topo.faces.shape[0], bool)
        sel[topo.mouth_faces] = True
        mouth_img, mouth_mask = _shade(raster, topo.faces, mouth_texture.uvs, mouth_texture.image,
                                       sel)
        rendered = np.where(mouth_mask[..., None], mouth_img, face_img)
    if not face_mask.any():
        return RewriteFrame(T.copy(), rendered, face_mask, mouth_mask)
    # The blend region stays ``erode`` pixels inside the rendered silhouette, so its outline
    # (the Dirichlet boundary of the Poisson problem) lies on the target's own face, which
    # covers the same silhouette up to the change of expression, not on the background.
    region = _erode(face_mask, int(erode)) if erode > 0 else face_mask
    if not region.any():
        region = face_mask
    if blend == "none":
        out = np.where(region[..., None], rendered, T)
    elif blend == "fast":
        face = rendered
        if mouth_img is not None and mouth_mask.any():
            # the source's mouth first takes the colours of the face around it (same membrane;
            # every outline pixel counts: skin tones of two people are expected to differ)
            face = membrane_blend(np.where(face_mask[..., None], face_img, T), mouth_img,
                                  mouth_mask & region, feather=mouth_feather, outlier=None)
        out = membrane_blend(T, face, region, feather=feather)
    else:
        from .composite import composite_face

        # The guidance field on the region's outline is the source's difference across it, so
        # each source is extended beyond its mask by its nearest inside pixel (no step there).
        face_src = _extend(face_img, face_mask)
        if mouth_img is not None and (mouth_mask & region).any():
            mouth_src = _extend(mouth_img, mouth_mask)
            out = composite_face(T, face_src, region, mouth_source=mouth_src,
                                 mouth_mask=mouth_mask & region, color_match=color_match,
                                 feather=feather)
        else:
            out = composite_face(T, face_src, region, color_match=color_match,
                                 feather=feather)
    return RewriteFrame(np.ascontiguousarray(out, dtype=np.uint8), rendered, face_mask,
                        mouth_mask)


# ---------------------------------------------------------------------------------------------
# a clip
# ---------------------------------------------------------------------------------------------

def rewrite_frames(target_frames, target_track, new_track, model, *, source_frames=None,
                   source_track=None, source_index: np.ndarray | None = None,
                   texture: str = "frame", blend: str = "fast", feather: float = 2.0,
                   mouth: str = "frame", mouth_function: MouthFunction | None = None,
                   topo: MeshTopology | None = None, workers: int | None = None,
                   processes: bool | None = None,
                   progress: Callable[[int], None] | None = None) -> Iterator[RewriteFrame]:
    """Rewrite every target frame with the new performance (§6, Fig. 7).

    Parameters
    ----------
    target_frames : (F, H, W, 3) uint8 or sequence of frames
    target_track : Track
        The target's own track (texture lifting).
    new_track : Track
        The new performance on the target's timeline (:func:`facetransfer.transfer.recombine`),
        at most ``F`` frames; its lost frames keep the original frame.
    model : MultilinearModel
    source_frames : sequence of (Hs, Ws, 3) uint8, optional
        The expression source video (mouth texture).
    source_track : Track, optional
        The source's track resampled to the new timeline (same frame count as ``new_track``).
    source_index : (F,) int, optional
        The source frame shown at each output frame (default ``arange``).
    texture : {"frame", "constant"}
        The target's face texture: the current frame's (default: it keeps the frame's own
        lighting and measured better on synthetic footage with ground truth, see
        ``benchmarks/bench_transfer.py``) or one for the whole clip (the paper's choice).
    blend, feather
        See :func:`rewrite_frame`.
    mouth : {"frame", "function"}
        The mouth's texture (lips and the closed gap). ``"frame"``: the source frame shown at
        this time (``source_index``) warped through the source's own geometry (the
        performance-driven texture with one neighbour, the source's own frame; no mouth
        texture without a source). ``"function"``: the performance-driven texture function
        of §6 (:func:`mouth_texture_function`) queried with the *new* performance's attribute
        vector at every frame; needs model UVs.
    mouth_function : MouthFunction, optional
        With ``mouth="function"``: the texture function to query. Default: lifted here from
        the source frames (at most :data:`MOUTH_MAX_FRAMES`), or from the target's own frames
        when no source is given.
    workers : int, optional
        Threads or processes rendering frames in parallel (default: 2, or 1 on a single CPU);
        the output order and values do not depend on it.
    processes : bool, optional
        With ``workers > 1``: render in forked worker processes instead of threads (where the
        platform can fork). Default: threads (measured a little faster on 2 cores once the
        meshes are synthesised up front: the per-frame kernels mostly release the GIL).
    progress : callable(int), optional
        Called with 1 after each frame.

    Yields
    ------
    RewriteFrame
    """
    if texture not in TEXTURE_MODES:
        raise RewriteError(f"texture must be one of {TEXTURE_MODES}, got {texture!r}")
    mouth = resolve_mouth_mode(mouth, model)
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
    with_mouth = source_frames is not None and source_track is not None
    if with_mouth and source_track.n_frames < n:
        raise RewriteError(f"the source track has {source_track.n_frames} frames, fewer than {n}")
    sidx = np.arange(n) if source_index is None else np.asarray(source_index, np.int64)
    topo = mesh_topology(model) if topo is None else topo
    if mouth == "function" and mouth_function is None and topo.mouth_faces.size:
        if with_mouth:
            from .transfer import take_frames

            mouth_function = mouth_texture_function(
                model, source_frames, take_frames(source_track, np.arange(n)), topo,
                frame_index=sidx[:n])
        else:
            mouth_function = mouth_texture_function(model, target_frames, target_track, topo)
    if mouth_function is not None and mouth == "function":
        from .texture import attribute_vector

        n_attr = attribute_vector(model, new_track.weights_at(0)).shape[-1]
        if mouth_function.n_attributes != n_attr or \
                mouth_function.uvs.shape[0] != topo.n_closed:
            raise RewriteError(f"the mouth texture function is for {mouth_function.n_attributes} "
                               f"attributes and {mouth_function.uvs.shape[0]} vertices, the model "
                               f"has {n_attr} and {topo.n_closed}")
        with_mouth = False  # the source frames are not looked at any more
    const_tex = None
    if texture == "constant" and not target_track.lost.all():
        const_tex = merged_face_texture(target_frames, target_track, model, topo) \
            if model.uvs is not None else constant_face_texture(target_frames, target_track,
                                                               model, topo)
    names = model.mode_names
    # the meshes of every frame at once (Eq. (5) batched: one matrix product per track, no
    # linear algebra left in the per-frame work that runs in parallel), unless the clip is long
    meshes: dict = {}
    n_sets = 1 + (const_tex is None) + with_mouth
    if n * int(model.n_vertices) * 3 * 8 * n_sets <= _MESH_CACHE_BYTES:
        rows = np.arange(n)
        meshes["new"] = model.synthesize({m: new_track.weights[m][rows] for m in names})
        if const_tex is None:
            meshes["target"] = model.synthesize({m: target_track.weights[m][rows]
                                                 for m in target_track.mode_names})
        if with_mouth:
            meshes["source"] = model.synthesize({m: source_track.weights[m][rows]
                                                 for m in source_track.mode_names})

    def mesh(kind: str, track, i: int) -> np.ndarray:
        if kind in meshes:
            return meshes[kind][i]
        return model.synthesize(track.weights_at(i))

    def one(i: int) -> RewriteFrame:
        frame = np.asarray(target_frames[i])
        if frame.shape != first.shape:
            raise RewriteError(f"target frame {i} is {frame.shape}, frame 0 {first.shape}")
        if new_track.lost[i] or target_track.lost[i]:
            empty = np.zeros(frame.shape[:2], bool)
            return RewriteFrame(frame.copy(), np.zeros_like(frame), empty, empty)
        if const_tex is not None:
            tex = const_tex
        else:
            Vt = close_mouth(mesh("target", target_track, i), topo)
            tex = FaceTexture(frame, frame_uvs(Vt, target_track.camera(i), size), i)
        mouth_tex = None
        if mouth_function is not None and mouth == "function":
            mouth_tex = mouth_function.face_texture(
                np.concatenate([new_track.weights[m][i] for m in names[1:]]))
        elif with_mouth:
            j = int(sidx[i])
            sf = np.asarray(source_frames[j])
            Vs = close_mouth(mesh("source", source_track, i), topo)
            mouth_tex = FaceTexture(sf, frame_uvs(Vs, source_track.camera(i),
                                                  (sf.shape[1], sf.shape[0])), j)
        V = mesh("new", new_track, i)
        return rewrite_frame(frame, V, new_track.camera(i), topo, tex, mouth_texture=mouth_tex,
                             blend=blend, feather=feather)

    workers = max(1, int(workers if workers is not None else min(2, os.cpu_count() or 1)))
    if workers == 1 or n < 2:
        for i in range(n):
            yield one(i)
            if progress:
                progress(1)
        return
    import multiprocessing as mp

    if processes is None:
        processes = _RENDER_IN_PROCESSES and n >= 16  # worth a fork for longer clips only
    if processes and "fork" in mp.get_all_start_methods():
        yield from _render_in_processes(one, target_frames, n, workers, progress)
        return
    # frames are independent: render them on a few threads (the rasteriser and most numpy
    # kernels release the GIL), yielding in order with a bounded look-ahead
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        nxt = 0
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


#: default of ``rewrite_frames(processes=None)`` for clips of 16 frames or more
_RENDER_IN_PROCESSES = False

#: the per-frame function of :func:`rewrite_frames` handed to forked workers (not pickled)
_RENDER_JOB: Callable | None = None


def _render_job(i: int):
    frame = _RENDER_JOB(i)
    return _crop_of(np.asarray(_RENDER_FRAMES[i]), frame)


_RENDER_FRAMES = None


def _render_in_processes(one, target_frames, n: int, workers: int, progress):
    """Yield ``one(i)`` for i < n, computed in ``workers`` forked processes, in order.

    Workers send back only the changed crop of each frame (:func:`_crop_of`); if the pool
    breaks, the remaining frames are rendered here."""
    global _RENDER_JOB, _RENDER_FRAMES
    import multiprocessing as mp
    from collections import deque
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    _RENDER_JOB, _RENDER_FRAMES = one, target_frames
    try:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("fork"))
        pending: deque = deque()
        nxt = 0
        try:
            pending.append(pool.submit(_render_job, nxt))  # forks the workers now
            nxt += 1
        finally:
            _RENDER_JOB, _RENDER_FRAMES = None, None
    except Exception as exc:  # noqa: BLE001 - cannot fork here (e.g. in a daemon process)
        log.info("no worker processes (%s): rendering here", exc)
        for i in range(n):
            yield one(i)
            if progress:
                progress(1)
        return
    done = 0
    broken = False
    try:
        while done < n:
            if not broken:
                try:
                    while nxt < n and len(pending) < 4 * workers:
                        pending.append(pool.submit(_render_job, nxt))
                        nxt += 1
                    part = pending.popleft().result()
                    res = _paste(np.asarray(target_frames[done]), part)
                except BrokenProcessPool as exc:
                    log.warning("render workers failed (%s); rendering here", exc)
                    broken = True
            if broken:
                res = one(done)
            yield res
            done += 1
            if progress:
                progress(1)
    finally:
        for f in pending:
            f.cancel()
        pool.shutdown(wait=True, cancel_futures=True)


# ---------------------------------------------------------------------------------------------
# writing: the one video writer of facetransfer.io.video (audio muxed there)
# ---------------------------------------------------------------------------------------------

def write_video_with_audio(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, *,
                           audio_from: str | os.PathLike | None = None, overwrite: bool = False,
                           audio_start: float = 0.0, options=None) -> bool:
    """Write frames to ``path`` with the audio of ``audio_from`` when it has some
    (:func:`facetransfer.io.video.encode_video`, ``options`` a
    :class:`~facetransfer.io.video.VideoOptions`). Returns whether audio was muxed in."""
    from .io.video import encode_video

    return encode_video(path, frames, fps, options=options, audio_from=audio_from,
                        audio_start=audio_start, overwrite=overwrite).audio


# ---------------------------------------------------------------------------------------------
# tracking adapter: the tracker of §5 when available, else a landmark-only fit (§5.2)
# ---------------------------------------------------------------------------------------------

def landmarks_file(video: str | os.PathLike) -> Path | None:
    """``NAME.mediapipe478.npz`` next to ``NAME.mp4`` if it exists (precomputed landmarks)."""
    p = Path(video)
    cand = p.with_name(p.stem + ".mediapipe478.npz")
    return cand if cand.is_file() else None


def _detect_landmarks(frames, *, progress=None) -> np.ndarray:
    """iBUG-68 points per frame with MediaPipe, (F, 68, 2), NaN where no face."""
    from .track.init import MediaPipeDetector

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
    from .track import Track
    from .track.init import fit_landmarks
    from .transfer import project_landmarks

    L = np.asarray(landmarks68, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (68, 2):
        raise ShapeError(f"landmarks must be (F, 68, 2), got {L.shape}")
    n = L.shape[0]
    found = np.isfinite(L).all(axis=(1, 2))
    if not found.any():
        raise VideoError(f"no face found in any frame of {source or 'the video'}")
    idm = "identity" if "identity" in model.mode_names else model.mode_names[0]
    good = np.flatnonzero(found)
    pick = good[np.linspace(0, good.size - 1, min(identity_frames, good.size)).round().astype(int)]
    ids = [fit_landmarks(model, L[i], iterations=12).weights[idm] for i in pick]
    wid = np.mean(ids, axis=0)
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
                w0 = model.default_weights()
                w0[idm] = wid
                st = fit_landmarks(model, L[i], modes=varying, iterations=10)
                st = st.with_weights(idm, wid)
                state = fit_landmarks(model, L[i], state=st, modes=varying, iterations=8)
            else:
                state = fit_landmarks(model, L[i], state=state, modes=varying, iterations=4)
            R[i], s[i], t[i] = state.pose.rotation, state.pose.scale, state.pose.translation
            for m in varying:
                W[m][i] = state.weights[m]
        elif state is not None:
            R[i], s[i], t[i] = state.pose.rotation, state.pose.scale, state.pose.translation
            for m in varying:
                W[m][i] = state.weights[m]
        if progress:
            progress(1)
    first = int(good[0])  # frames before the first detection take its pose (they are lost)
    R[:first], s[:first], t[:first] = R[first], s[first], t[first]
    for m in varying:
        W[m][:first] = W[m][first]
    tr = Track(fps=float(fps), frame_size=tuple(size), rotation=R, scale=s, translation=t,
               weights=W, landmarks2d=np.zeros((n, 68, 2)),
               confidence=found.astype(np.float64), lost=~found,
               model_hash=model.content_hash, mode_names=model.mode_names, source=str(source),
               info={"method": "landmarks"})
    return project_landmarks(tr, model)


def track_options(speed: str = DEFAULT_SPEED):
    """Settings of the optical-flow tracker (§5.1) for a speed preset.

    ``"fast"`` (the default of the transfer, :data:`DEFAULT_SPEED`) makes a single pass (the
    identity comes from the snap of §5.2) on two pyramid levels with 500 tracked vertices, 7x7
    KLT windows, a shorter snap, and chooses the tracked vertices anew every 8 frame pairs
    (``TrackOptions.reselect``). ``"balanced"`` is the tracker's own default
    (:class:`facetransfer.track.TrackOptions`: two passes, three pyramid levels, a thousand
    vertices, the initial snap and the key-frame term) with a new choice of vertices every 4
    pairs; ``"quality"`` makes three passes and two snap rounds.

    Measured (``benchmarks/bench_transfer.py``, BENCHMARKS.md): ``"fast"`` tracks about four
    times faster than ``"balanced"`` with the same accuracy on the synthetic footage
    (landmark error 1.4 vs 1.5 px, face PSNR within 0.2 dB) and on four real clips (200
    frames each, landmark error against MediaPipe's 0.065 vs 0.066 of the eye distance).
    ``"balanced"`` and ``"quality"`` remain for harder footage (fast motion, where the third
    pyramid level helps; occlusions, where more points do).

    Parameters
    ----------
    speed : {"fast", "balanced", "quality"}

    Returns
    -------
    TrackOptions
    """
    from .track.tracker import TrackOptions

    if speed == "balanced":
        return TrackOptions(reselect=4)
    if speed == "fast":
        return TrackOptions(passes=1, levels=2, n_points=500, snap_frames=4, reselect=8,
                            half_window=3)
    if speed == "quality":
        return TrackOptions(passes=3, snap_rounds=2)
    raise RewriteError(f"speed must be one of {', '.join(SPEED_PRESETS)}, got {speed!r}")


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


def _capture(video, model, frames, fps, max_frames, progress_factory):
    """The capture tracker (:mod:`facetransfer.track.capture`) on decoded frames."""
    import dataclasses

    from .track.capture import capture_video

    with _StageBars(video, progress_factory) as stage_progress:
        tr = capture_video(frames, model, max_frames=max_frames, progress=stage_progress,
                           source=str(video))
    return dataclasses.replace(tr, fps=float(fps))


def obtain_track(video: str | os.PathLike, model, *, frames=None, fps: float | None = None,
                 track_file: str | os.PathLike | None = None, max_frames: int | None = None,
                 method: str = "auto", progress_factory=None, options=None):
    """The track of a video: read from ``track_file``, or tracked now.

    ``method``: ``"auto"`` or ``"capture"`` use the capture tracker
    (:func:`facetransfer.track.capture.capture_video`: the model fitted to MediaPipe's points
    and their flow on every frame); ``"flow"`` the optical-flow tracker of §5.1
    (:func:`facetransfer.track.track_video`, configured by ``options``); ``"landmarks"`` fits
    landmarks (precomputed ``NAME.mediapipe478.npz`` next to the video, else MediaPipe). ``options`` (a
    :class:`~facetransfer.track.TrackOptions`, e.g. from :func:`track_options`) configure the
    optical-flow tracker (default: its own defaults).

    Returns
    -------
    Track
        Of at most ``max_frames`` frames (a longer track file is cut).
    """
    from .track import Track
    from .transfer import take_frames

    if method not in ("auto", "capture", "flow", "landmarks"):
        raise RewriteError(f"tracking method must be auto, capture, flow or landmarks, got "
                           f"{method!r}")
    if track_file is not None:
        tr = Track.load(track_file)
        tr.check_model(model)
        if max_frames is not None and tr.n_frames > max_frames:
            tr = take_frames(tr, np.arange(max_frames))
        return tr
    from .io.video import read_video, video_info

    info = video_info(video)
    if frames is None:
        frames, fps = read_video(video, max_frames=max_frames)
    fps = info.fps if fps is None else fps
    size = (frames.shape[2], frames.shape[1]) if hasattr(frames, "shape") else info.size
    n = len(frames)

    def bar(desc, total):
        return progress_factory(desc, total) if progress_factory else None

    if method in ("auto", "capture"):
        return _capture(video, model, frames, fps, max_frames, progress_factory)
    if method == "flow":
        try:
            from .track.tracker import track_video
        except ImportError:  # pragma: no cover - tracker not installed
            track_video = None
        if track_video is None and method == "flow":
            raise RewriteError("the optical-flow tracker (facetransfer.track.track_video) is "
                               "not available")
        if track_video is not None:
            with _StageBars(video, progress_factory) as stage_progress:
                tr = track_video(frames, model, max_frames=max_frames, progress=stage_progress,
                                 source=str(video), options=options)
            if abs(tr.fps - fps) > 1e-9:  # an array of frames carries no frame rate
                import dataclasses

                tr = dataclasses.replace(tr, fps=float(fps))
            return tr
    lmf = landmarks_file(video)
    if lmf is not None:
        from .track.landmarks import mediapipe_to_ibug

        from .io.landmarks import read_mediapipe_landmarks

        P = read_mediapipe_landmarks(lmf, n)
        L = mediapipe_to_ibug(P[..., :2])
        if L.shape[0] < n:
            L = np.concatenate([L, np.full((n - L.shape[0], 68, 2), np.nan)])
    else:
        cb = bar(f"landmarks {Path(video).name}", n)
        L = _detect_landmarks(frames, progress=cb.update if cb is not None else None)
        if cb is not None and hasattr(cb, "close"):
            cb.close()
    cb = bar(f"fit {Path(video).name}", n)
    try:
        return landmark_track(model, L, fps=fps, size=size, source=str(video),
                              progress=cb.update if cb is not None else None)
    finally:
        if cb is not None and hasattr(cb, "close"):
            cb.close()


# ---------------------------------------------------------------------------------------------
# the job: tracks in or tracked now, recombined, rendered back, written with the target's audio
# ---------------------------------------------------------------------------------------------

class _BackgroundTrack:
    """A track computed in a forked child process (:func:`_start_background_track`)."""

    def __init__(self, pool, future) -> None:
        self._pool, self._future = pool, future

    def result(self):
        """The Track, or None when the child could not run (then the caller tracks itself).

        Errors of the tracking itself (e.g. no face in the video) are raised here."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            return self._future.result()
        except BrokenProcessPool as exc:
            log.warning("background tracking failed (%s); tracking in this process", exc)
            return None
        except BaseException:  # e.g. Ctrl-C: do not wait for the child
            self.cancel()
            raise
        finally:
            self._pool.shutdown(wait=True)

    def cancel(self) -> None:
        """Stop the child (it may be half-way through the video) without waiting for it."""
        self._future.cancel()
        procs = getattr(self._pool, "_processes", None) or {}
        for proc in list(procs.values()):
            try:
                proc.terminate()
            except Exception:  # noqa: BLE001 - already gone
                pass
        self._pool.shutdown(wait=False, cancel_futures=True)


#: (model, video, max_frames, method, options) handed to the forked child (not pickled)
_BACKGROUND_JOB: tuple | None = None


def _background_track_job():
    from .io.video import read_video

    model, video, max_frames, method, options, decoded = _BACKGROUND_JOB
    frames, fps = decoded if decoded is not None else read_video(video, max_frames=max_frames)
    return obtain_track(video, model, frames=frames, fps=fps, max_frames=len(frames),
                        method=method, options=options)


def _start_background_track(video, model, max_frames: int, *, method: str, options,
                            parallel: bool | None, frames=None) -> _BackgroundTrack | None:
    """Track ``video`` in a forked child process; None when not worth it or not possible.

    ``frames``: its decoded ``(frames, fps)``, inherited by the child (else it decodes them)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    global _BACKGROUND_JOB
    if method == "landmarks":
        return None
    if parallel is None:
        parallel = (os.cpu_count() or 1) >= 2
    if not parallel or "fork" not in mp.get_all_start_methods():
        return None
    _BACKGROUND_JOB = (model, video, int(max_frames), method, options, frames)
    try:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("fork"))
        fut = pool.submit(_background_track_job)  # forks now: the child sees _BACKGROUND_JOB
    except Exception as exc:  # noqa: BLE001 - cannot fork here (e.g. in a daemon process)
        log.info("no background tracking (%s)", exc)
        return None
    finally:
        _BACKGROUND_JOB = None
    return _BackgroundTrack(pool, fut)


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

    def mouth_function(self, model, topo: MeshTopology | None = None, *,
                       progress: Callable[[int], None] | None = None, **kwargs) -> MouthFunction:
        """The mouth texture function lifted from :attr:`texture_frames`
        (:func:`mouth_texture_function`; ``kwargs``: ``tex_size``, ``step``, ``max_frames``,
        ``k``)."""
        if self.texture_frames is None or self.texture_track is None:
            from .transfer import take_frames

            tr = take_frames(self.mouth_track, np.arange(self.n_frames))
            return mouth_texture_function(model, self.mouth_frames, tr, topo,
                                          frame_index=self.mouth_index[:self.n_frames],
                                          progress=progress, **kwargs)
        m = min(len(self.texture_frames), self.texture_track.n_frames)
        tr = self.texture_track
        if tr.n_frames > m:
            from .transfer import take_frames

            tr = take_frames(tr, np.arange(m))
        return mouth_texture_function(model, self.texture_frames, tr, topo, progress=progress,
                                      **kwargs)

    @property
    def n_frames(self) -> int:
        return int(self.new_track.n_frames)


def _frames_needed(n_target: int, fps_target: float, fps_source: float) -> int:
    """Source frames that cover ``n_target`` target frames (resampled by frame rate)."""
    return int(np.ceil((n_target - 1) * fps_source / fps_target + 1e-9)) + 1


def nearest_frames(query: np.ndarray, bank: np.ndarray, valid: np.ndarray | None = None
                   ) -> np.ndarray:
    """For each query row the index of the nearest bank row (Euclidean), among ``valid`` ones.

    The performance-driven texture of §6 ("the weighted sum of nearest neighbors") with one
    neighbour: the frame of the texture video whose attributes are closest.

    Parameters
    ----------
    query : (n, r)
    bank : (m, r)
    valid : (m,) bool, optional

    Returns
    -------
    (n,) int64
    """
    Q = np.asarray(query, np.float64)
    B = np.asarray(bank, np.float64)
    ok = np.ones(B.shape[0], bool) if valid is None else np.asarray(valid, bool)
    if not ok.any():
        raise RewriteError("no frame to take a texture from (all lost)")
    idx = np.flatnonzero(ok)
    d = ((Q[:, None, :] - B[None, idx, :]) ** 2).sum(axis=-1)
    return idx[np.argmin(d, axis=1)]


def plan_transfer(target, model, *, target_track=None, expression_from=None,
                  expression_track=None, viseme_from=None, viseme_track=None, identity=None,
                  identity_from=None, identity_track=None, pose_from=None, pose_track=None,
                  performance=None, align: str | None = None, max_frames: int | None = None,
                  track_method: str = "auto", speed: str = DEFAULT_SPEED,
                  parallel: bool | None = None, progress_factory=None) -> TransferPlan:
    """Read and track the inputs and recombine the performance (§5, §6, Fig. 1, Fig. 7).

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
    track_method : {"auto", "flow", "landmarks"}
        See :func:`obtain_track`.
    speed : {"fast", "balanced", "quality"}
        Tracking preset (:func:`track_options`) for the videos tracked now.
    parallel : bool, optional
        Track the expression source in a second (forked) process while the target is tracked
        here. Default: when the machine has two or more CPUs and the platform can fork. The
        tracks do not depend on it.

    Raises
    ------
    VideoError
        No face in the target (or in a whole source); unreadable videos.
    TrackError, TransferError
        Mismatched frame sizes, track files of another model or video.
    """
    import time

    from .io.video import read_video, video_info
    from .transfer import (take_frames, project_landmarks, recombine, resample_track, time_map,
                           constant_weights)

    if max_frames is not None and int(max_frames) < 1:
        raise RewriteError(f"max_frames must be >= 1, got {max_frames}")
    if identity is not None and identity_from is not None:
        raise RewriteError("give the identity either as weights or as a video, not both")
    options = track_options(speed)  # validates the preset before any work
    timings = {"read": 0.0, "track": 0.0}
    t0 = time.perf_counter()
    pre_read = None  # the expression source's frames, decoded with the target's
    if expression_from is None:
        frames, fps = read_video(target, max_frames=max_frames)
    else:
        # the two videos are decoded on two threads at once; the source is then cut to the
        # frames the target's timeline needs
        from concurrent.futures import ThreadPoolExecutor

        ti, si = video_info(target), video_info(expression_from)
        n_est = ti.n_frames if max_frames is None else min(int(max_frames), ti.n_frames)
        with ThreadPoolExecutor(max_workers=2) as pool:
            ft = pool.submit(read_video, target, max_frames=max_frames)
            fs = pool.submit(read_video, expression_from,
                             max_frames=_frames_needed(max(n_est, 1), ti.fps, si.fps) + 8)
            frames, fps = ft.result()
            sfr, sfps = fs.result()
        need = _frames_needed(len(frames), fps, sfps)
        if len(sfr) < need and len(sfr) < si.n_frames:  # the containers' counts were short
            sfr, sfps = read_video(expression_from, max_frames=need)
        pre_read = (sfr[:need], sfps)
    timings["read"] += time.perf_counter() - t0
    n, H, W = frames.shape[:3]

    def get_track(video, track_file, *, frames_=None, fps_=None, limit=None):
        t = time.perf_counter()
        tr = obtain_track(video, model, frames=frames_, fps=fps_, track_file=track_file,
                          max_frames=limit, method=track_method,
                          progress_factory=progress_factory, options=options)
        timings["track"] += time.perf_counter() - t
        return tr

    # the expression source is tracked in a second (forked) process while this one tracks the
    # target; the child inherits the decoded frames (no second decoding, nothing pickled)
    early = None
    if pre_read is not None and expression_track is None:
        early = _start_background_track(expression_from, model, len(pre_read[0]),
                                        frames=pre_read, method=track_method, options=options,
                                        parallel=parallel)
    try:
        tt = get_track(target, target_track, frames_=frames, fps_=fps, limit=n)
    except BaseException:
        if early is not None:
            early.cancel()
        raise
    if target_track is not None:
        tt.check_video(n if tt.n_frames >= n else tt.n_frames, (W, H), what=f"target {target}")
        if tt.n_frames < n:
            raise RewriteError(f"target track {target_track} has {tt.n_frames} frames, the "
                               f"target video {n}")
    if tt.lost.all():
        raise VideoError(f"no face found in the target {target}")
    tracks = {"target": tt}
    src_frames = {}

    def read_source(kind, video, track_file):
        info = video_info(video)
        need = _frames_needed(n, fps, info.fps)
        t = time.perf_counter()
        if kind == "expression" and pre_read is not None:
            fr, sfps = pre_read
        else:
            fr, sfps = read_video(video, max_frames=need)
        timings["read"] += time.perf_counter() - t
        tr = None
        if kind == "expression" and early is not None:
            t = time.perf_counter()
            tr = early.result()  # None: the background job failed to run; track here
            timings["track"] += time.perf_counter() - t
            if tr is not None and len(fr) < tr.n_frames:
                from .transfer import take_frames

                tr = take_frames(tr, np.arange(len(fr)))
        if tr is None:
            tr = get_track(video, track_file, frames_=fr, fps_=sfps, limit=len(fr))
        if track_file is not None and tuple(tr.frame_size) != (fr.shape[2], fr.shape[1]):
            raise RewriteError(f"{kind} track {track_file} is for {tr.frame_size[0]}x"
                               f"{tr.frame_size[1]} frames but {video} is "
                               f"{fr.shape[2]}x{fr.shape[1]}")
        if tr.n_frames < len(fr):
            fr = fr[:tr.n_frames]
        if tr.lost.all():
            raise VideoError(f"no face found in the {kind} source {video}")
        if tr.lost.any():
            log.info("%s source %s: face lost in %d frames (those keep the original frame)",
                     kind, video, int(tr.lost.sum()))
        tracks[kind] = tr
        src_frames[kind] = fr
        return tr

    ex = read_source("expression", expression_from, expression_track) \
        if expression_from is not None else None
    vi = read_source("viseme", viseme_from, viseme_track) if viseme_from is not None else None
    po = None
    if pose_from is not None:
        po = read_source("pose", pose_from, pose_track)
        if tuple(po.frame_size) != (W, H):
            raise RewriteError(f"pose source {pose_from} is {po.frame_size[0]}x{po.frame_size[1]}"
                               f", the target {W}x{H}: frame sizes must match")
    idw = identity
    if identity_from is not None:
        idm = "identity" if "identity" in model.mode_names else model.mode_names[0]
        it = read_source("identity", identity_from, identity_track)
        idw = constant_weights(it, idm)
    if performance is not None:
        from .track import Track

        if ex is not None or vi is not None or po is not None or idw is not None:
            raise RewriteError("a ready performance (--performance) excludes the other sources")
        new = performance if isinstance(performance, Track) else Track.load(performance)
        new.check_model(model)
        if tuple(new.frame_size) != (W, H):
            raise RewriteError(f"performance is for {new.frame_size[0]}x{new.frame_size[1]} "
                               f"frames, the target {target} is {W}x{H}")
        if new.n_frames > n:
            new = take_frames(new, np.arange(n))
        varying = [m for m in model.mode_names if m != "identity"] or list(model.mode_names)
        q = np.concatenate([new.weights[m] for m in varying], axis=1)
        b = np.concatenate([tt.weights[m] for m in varying], axis=1)
        j = nearest_frames(q, b, ~tt.lost)
        mt = take_frames(tt, j)
        # the chosen frames' geometry, seen by their own cameras (texture lookup)
        return TransferPlan(frames, float(fps), tt, new, frames, mt, j, tracks, timings,
                            texture_frames=frames, texture_track=tt, performance=True)
    new = recombine(tt, expression=ex, viseme=vi, identity=idw, pose=po, align=align)
    new = project_landmarks(new, model)
    # the mouth texture: from the source of the mouth's motion (visemes, else expressions),
    # else the target's own mouth
    mouth_kind = "viseme" if vi is not None else ("expression" if ex is not None else None)
    if mouth_kind is None:
        mouth_frames, mouth_track = frames, take_frames(tt, np.arange(new.n_frames))
        mouth_index = np.arange(new.n_frames)
        tex_frames, tex_track = frames, tt
    else:
        ms = tracks[mouth_kind]
        tm = time_map(ms.n_frames, ms.fps, n, fps, align=align)
        mouth_track = take_frames(resample_track(ms, tm), np.arange(new.n_frames))
        mouth_frames = src_frames[mouth_kind]
        mouth_index = tm.nearest[:new.n_frames]
        tex_frames, tex_track = mouth_frames, ms
    return TransferPlan(frames, float(fps), tt, new, mouth_frames, mouth_track,
                        np.asarray(mouth_index, np.int64), tracks, timings,
                        texture_frames=tex_frames, texture_track=tex_track)


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
    """

    path: Path
    n_frames: int
    n_rewritten: int
    audio: bool
    plan: TransferPlan
    timings: dict


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


def render_plan(plan: TransferPlan, model, out, *, audio_from=None, texture: str = "frame",
                blend: str = "fast", mouth: str = "frame", overwrite: bool = False,
                progress_factory=None, compose: Callable | None = None, video_options=None):
    """Render a planned transfer into the video ``out`` (§6), timing each stage.

    Lifts the mouth texture function first when ``mouth == "function"`` (from
    :attr:`TransferPlan.texture_frames`), then rewrites every frame (:func:`rewrite_frames`)
    and writes the video with the audio of ``audio_from`` as the frames come.

    Parameters
    ----------
    plan : TransferPlan
    model : MultilinearModel
    out : path-like
        The video to write (atomically).
    audio_from : path-like, optional
    texture, blend, mouth
        See :func:`rewrite_frames` (``mouth`` already resolved: "frame" or "function").
    compose : callable(i, RewriteFrame) -> (H', W', 3) uint8, optional
        The frame to write for output frame ``i`` (default: the rewritten image).
    video_options : VideoOptions, optional
        Codec and CRF (:class:`facetransfer.io.video.VideoOptions`; default H.264, CRF 18).

    Returns
    -------
    timings : dict
        The plan's timings plus ``mouth`` (if lifted), ``render`` and ``write`` seconds.
    n_rewritten : int
        Frames where the face was rendered.
    audio : bool
        Whether audio was muxed in.
    """
    import time

    timings = dict(plan.timings)
    n = plan.n_frames
    mouth_fn = None
    if mouth == "function":
        t = time.perf_counter()
        lift_bar = progress_factory("mouth texture", min(
            MOUTH_MAX_FRAMES, len(plan.texture_frames) if plan.texture_frames is not None
            else n)) if progress_factory else None
        try:
            mouth_fn = plan.mouth_function(
                model, progress=lift_bar.update if lift_bar is not None else None)
        finally:
            if lift_bar is not None:
                lift_bar.close()
        timings["mouth"] = time.perf_counter() - t
    bar = progress_factory("render", n) if progress_factory else None
    rewritten = [0]
    t_render = [0.0]

    def frames():
        it = rewrite_frames(plan.target_frames, plan.target_track, plan.new_track, model,
                            source_frames=plan.mouth_frames, source_track=plan.mouth_track,
                            source_index=plan.mouth_index, texture=texture, blend=blend,
                            mouth=mouth, mouth_function=mouth_fn,
                            progress=bar.update if bar is not None else None)
        for i in range(n):
            t = time.perf_counter()
            r = next(it)
            frame = r.image if compose is None else compose(i, r)
            t_render[0] += time.perf_counter() - t
            rewritten[0] += bool(r.face_mask.any())
            yield frame

    t0 = time.perf_counter()
    try:
        audio = write_video_with_audio(out, frames(), plan.fps, audio_from=audio_from,
                                       overwrite=overwrite, options=video_options)
    finally:
        if bar is not None:
            bar.close()
    timings["render"] = t_render[0]
    timings["write"] = time.perf_counter() - t0 - t_render[0]
    return timings, rewritten[0], audio


def transfer_video(target, out, model, *, overwrite: bool = False, texture: str = "frame",
                   blend: str = "fast", mouth: str | None = None, meshes_dir=None,
                   save_track=None, progress_factory=None, video_options=None,
                   **plan_kwargs) -> TransferResult:
    """The whole video rewrite (§6): plan (read, track, recombine), render, write with audio.

    ``plan_kwargs`` go to :func:`plan_transfer` (sources, track files, ``align``,
    ``max_frames``, ``track_method``, ``speed``). The output video (and the optional track and
    meshes) appear only when everything succeeded; an existing ``out`` is replaced only with
    ``overwrite=True``. ``mouth`` (see :func:`rewrite_frames`): None picks
    :func:`default_mouth_mode` (the texture function for a ready ``performance``, the source
    frame for a transfer); with ``"function"`` the function is lifted from
    :attr:`TransferPlan.texture_frames`. ``video_options``: codec and CRF of ``out``
    (:class:`facetransfer.io.video.VideoOptions`); ``out`` may be an image sequence
    (``frames/%05d.png``).

    Returns
    -------
    TransferResult
    """
    from .io.atomic import check_output_path
    from .io.video import check_video_output

    check_video_output(out, video_options, overwrite=overwrite)  # before any work
    if save_track is not None:
        check_output_path(save_track, overwrite=overwrite)
    if meshes_dir is not None:
        md = Path(meshes_dir)
        if not md.parent.is_dir():
            raise RewriteError(f"folder {md.parent} for --meshes does not exist")
        if not overwrite and md.is_dir() and any(md.glob("frame_*.obj")):
            raise RewriteError(f"{md} already holds meshes; pass --overwrite to replace them")
    if texture not in TEXTURE_MODES:
        raise RewriteError(f"texture must be one of {TEXTURE_MODES}, got {texture!r}")
    if blend not in BLEND_MODES:
        raise RewriteError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
    mouth = resolve_mouth_mode(mouth, model,
                               performance=plan_kwargs.get("performance") is not None)
    plan = plan_transfer(target, model, progress_factory=progress_factory, **plan_kwargs)
    timings, n_rewritten, audio = render_plan(plan, model, out, audio_from=target,
                                              texture=texture, blend=blend, mouth=mouth,
                                              overwrite=overwrite,
                                              progress_factory=progress_factory,
                                              video_options=video_options)
    if save_track is not None:
        plan.new_track.save(save_track, overwrite=overwrite)
    if meshes_dir is not None:
        write_mesh_sequence(meshes_dir, plan.new_track, model)
    return TransferResult(Path(out), plan.n_frames, n_rewritten, audio, plan, timings)

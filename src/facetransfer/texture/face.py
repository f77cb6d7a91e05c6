"""Face textures of the video rewrite (Vlasic et al. 2005, §6): the target's face texture and
the performance-driven mouth texture.

* :class:`FaceTexture`: a texture image and the texture coordinates of the closed mesh;
  :func:`frame_uvs` looks a mesh up in the frame it was tracked in (image-space lookups: a
  triangle of the new mesh shows the same triangle of the frame, an affine warp per triangle);
* :func:`constant_face_texture` / :func:`merged_face_texture`: "the face texture from the
  target video (constant throughout the sequence)";
* :class:`MouthFunction` / :func:`mouth_texture_function`: the performance-driven texture
  function of §6 ("the weighted sum of nearest neighbors" in attribute space) for the mouth,
  lifted into the whole UV atlas at a given size or, ``tex_size="auto"``, into the mouth's
  square of it at the face's size in the frames (:class:`MouthLayout`, :func:`mouth_layout`);
  :func:`resolve_mouth_mode` / :func:`default_mouth_mode` choose between it and the source's
  frame.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import RewriteError
from ..render import sample_texture
from ..rewrite_options import MOUTH_MODES, check_mode
from ..topology import MeshTopology, close_mouth, mesh_topology
from ..track.project import take_frames
from .atlas import uv_atlas
from .base import texture_to_uint8
from .function import TextureFunction, attribute_vector
from .lifting import lift_uv_texture
from .merge import merge_textures

log = logging.getLogger(__name__)

__all__ = [
    "frame_uvs",
    "FaceTexture",
    "constant_face_texture",
    "merged_face_texture",
    "MOUTH_MAX_FRAMES",
    "MOUTH_MAX_BYTES",
    "MouthLayout",
    "mouth_layout",
    "mouth_tex_size",
    "MouthFunction",
    "mouth_texture_function",
    "timeline_mouth_function",
    "default_mouth_mode",
    "resolve_mouth_mode",
]

#: The mouth texture function lifts at most this many (evenly spaced) frames: float32 textures
#: of ``T x T`` texels take ``16 T²`` bytes each (120 frames at T = 256: 126 MB).
MOUTH_MAX_FRAMES = 120

#: ``tex_size="auto"`` (:func:`mouth_layout`): the mouth's texture is made fine enough that one
#: texel spans at most this many screen pixels of the lifted frames' mouth ...
MOUTH_TEXEL_PIXELS = 1.0
#: ... within this side (texels) ...
MOUTH_MAX_TEX = 1024
#: ... and these bytes of lifted textures (float16 colour and weight: 8 bytes a texel; the
#: whole 256² atlas of 120 frames took 126 MB as float32) ...
MOUTH_MAX_BYTES = 128 * 2 ** 20
#: ... fewer frames lifted (down to this many) before the side shrinks.
MOUTH_MIN_FRAMES = 40
#: Texels per unit of UV the mouth never falls below (the whole atlas at 256², the old size).
MOUTH_MIN_DENSITY = 256
#: Rings of triangles around the mouth's that its texture covers (as
#: :data:`facetransfer.mouth.MOUTH_RING`, whose ring is drawn from it to fit the mouth's gain).
MOUTH_CROP_RINGS = 3
_AUTO_BYTES_PER_TEXEL = 8


def frame_uvs(vertices: np.ndarray, camera, size: tuple[int, int]) -> np.ndarray:
    """Texture coordinates that look a mesh up in the frame it was tracked in.

    ``uv = (x / (W - 1), 1 - y / (H - 1))`` of each vertex's projection (Eq. (7)), so that
    :func:`facetransfer.render.sample_texture` with the frame as texture returns the frame's
    pixel under the vertex. A mesh drawn a fraction of a pixel off those positions samples
    between the frame's pixels (a bilinear mix, which softens its finest detail); the rewrite
    moves those coordinates to where the mesh is drawn (:func:`facetransfer.unmoved.
    unmoved_uvs`), so that the frame's own pixels show there.

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
    uv = camera.project(vertices)  # a new (n, 2) array, turned into uvs in place
    uv[:, 0] /= max(W - 1, 1)
    np.divide(uv[:, 1], max(H - 1, 1), out=uv[:, 1])
    np.subtract(1.0, uv[:, 1], out=uv[:, 1])
    return uv


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

    _closed_uvs(model, topo, "the model has no UVs: use the reference-frame texture")
    n = min(len(frames), track.n_frames)
    good = np.flatnonzero(~track.lost[:n])
    if good.size == 0:
        raise RewriteError(f"the face is lost in every frame of {track.source or 'the target'}")
    pick = _even_pick(good, n_samples)
    faces = np.asarray(model.faces)
    atlas = uv_atlas(faces, model.uvs, tex_size)
    lifted = [lift_uv_texture(np.asarray(frames[i]), model.synthesize(track.weights_at(i)),
                              faces, model.uvs, track.camera(i), tex_size, atlas=atlas)
              for i in pick]
    img = texture_to_uint8(merge_textures(lifted).texture)
    return FaceTexture(img, _closed_uvs(model, topo), -1)


# ---------------------------------------------------------------------------------------------
# the performance-driven mouth texture (§6)
# ---------------------------------------------------------------------------------------------

_NO_UVS = ("mouth='function' (the texture function of §6) needs a model with texture "
           "coordinates (UVs); this model has none: use mouth='frame'")


def _closed_uvs(model, topo: MeshTopology, no_uvs: str | None = None) -> np.ndarray:
    """The model's UVs for the closed mesh: the mouth's centre vertex takes the mean UV of the
    inner-lip loop, ``(topo.n_closed, 2)``; ``no_uvs``: the message when the model has none."""
    if model.uvs is None:
        raise RewriteError(_NO_UVS if no_uvs is None else no_uvs)
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
    attribute vector, ready for :func:`facetransfer.rewrite.rewrite_frame`'s ``mouth_texture``.

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
        """The mouth texture for one attribute vector (r,): Eq. (T1) of
        :class:`~facetransfer.texture.TextureFunction`, ``(T, T, 3) uint8``."""

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


@dataclass(frozen=True)
class MouthLayout:
    """Where and how finely ``tex_size="auto"`` lifts the mouth's texture (§6).

    The mouth's triangles (and :data:`MOUTH_CROP_RINGS` rings around them) fill a square of the
    model's UV layout; only that square is lifted, at a side chosen from the size of the
    mouth in the lifted frames (:func:`mouth_layout`), so a 4K face's lips keep the footage's
    detail where the whole atlas at 256² spread one texel over ~6 screen pixels.

    Attributes
    ----------
    tex_size : int
        ``T``, the square's side in texels.
    origin : (2,) tuple of float
        ``(u, v)`` of the square's lowest corner in the model's UVs.
    side : float
        The square's side in UV units.
    max_frames : int
        Frames lifted at most (:data:`MOUTH_MAX_BYTES`).
    pixels_per_uv : float
        Screen pixels per UV unit of the lifted frames' mouth (median; 0 if unmeasured).
    """

    tex_size: int
    origin: tuple
    side: float
    max_frames: int
    pixels_per_uv: float

    @property
    def texel_pixels(self) -> float:
        """Screen pixels one texel spans at the mouth (linear)."""
        return self.pixels_per_uv * self.side / max(self.tex_size - 1, 1)

    def crop(self, uvs: np.ndarray) -> np.ndarray:
        """``uvs`` (n, 2) in the model's layout as coordinates of the square: (n, 2) float64,
        the mouth's in [0, 1]."""
        return (np.asarray(uvs, np.float64) - np.asarray(self.origin, np.float64)) / self.side


def mouth_tex_size(texels: float, n_frames: int, *, max_side: int = MOUTH_MAX_TEX,
                   max_bytes: int = MOUTH_MAX_BYTES, min_frames: int = MOUTH_MIN_FRAMES
                   ) -> tuple[int, int]:
    """``(T, frames)``: the side (a multiple of 32, 32..``max_side``) that gives ``texels``
    across the mouth's square and the frames (<= ``n_frames``) lifted at it, their textures
    within ``max_bytes`` (8 bytes a texel): fewer frames first (down to ``min_frames``), then a
    smaller side."""
    T = int(min(max(32, 32 * np.ceil(texels / 32)), max_side))
    frames = int(n_frames)
    per = T * T * _AUTO_BYTES_PER_TEXEL
    if frames * per > max_bytes:
        frames = max(int(max_bytes // per), min(int(min_frames), frames))
        while T > 32 and frames * T * T * _AUTO_BYTES_PER_TEXEL > max_bytes:
            T -= 32
    return T, max(frames, 1)


def _mouth_crop_faces(topo: MeshTopology, rings: int = MOUTH_CROP_RINGS) -> np.ndarray:
    """``topo.mouth_faces`` and ``rings`` vertex rings of triangles around them, ``(F',) bool``
    (a superset of :func:`facetransfer.mouth.mouth_ring_faces`' edge rings)."""
    sel = np.zeros(len(topo.faces), bool)
    sel[np.asarray(topo.mouth_faces, np.int64)] = True
    for _ in range(rings):
        touched = np.zeros(int(topo.faces.max()) + 1, bool)
        touched[topo.faces[sel].ravel()] = True
        sel = touched[topo.faces].any(axis=1)
    return sel


def _tri_area(P: np.ndarray, F: np.ndarray) -> float:
    """Summed area of triangles ``F`` (m, 3) of 2-D points ``P`` (n, 2)."""
    a, b, c = P[F[:, 0]], P[F[:, 1]], P[F[:, 2]]
    return float(0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                              - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])).sum())


def _mouth_pixels_per_uv(model, track, topo: MeshTopology, uvs: np.ndarray,
                         rows: np.ndarray) -> float:
    """Screen pixels per UV unit of the lips (the mouth's triangles but the closing fan), the
    median over up to 8 of ``rows``: ``sqrt(screen area / UV area)``; 0 without lips."""
    fan = np.zeros(len(topo.faces), bool)
    fan[topo.mouth_fan] = True
    mf = np.asarray(topo.mouth_faces, np.int64)
    lips = topo.faces[mf[~fan[mf]]]
    uv_area = _tri_area(uvs, lips) if lips.size else 0.0
    if uv_area <= 0:
        return 0.0
    scale = [np.sqrt(_tri_area(track.camera(int(r)).project(
        model.synthesize(track.weights_at(int(r)))), lips) / uv_area)
        for r in _even_pick(rows, 8)]
    return float(np.median(scale))


def mouth_layout(model, track, topo: MeshTopology, uvs: np.ndarray, rows: np.ndarray,
                 ) -> MouthLayout:
    """The :class:`MouthLayout` of ``tex_size="auto"`` for lifting track ``rows`` (§6).

    The square holds the UVs of the mouth's triangles and :data:`MOUTH_CROP_RINGS` rings
    around them (3 % margin); its side gives one texel per :data:`MOUTH_TEXEL_PIXELS` screen
    pixels of the frames' mouth (:func:`_mouth_pixels_per_uv`), never coarser than
    :data:`MOUTH_MIN_DENSITY` texels per UV unit, within :func:`mouth_tex_size`'s bounds.

    Parameters
    ----------
    model : MultilinearModel
    track : Track
    topo : MeshTopology
    uvs : (n_closed, 2) float64
        The closed mesh's UVs (:func:`_closed_uvs`).
    rows : (m,) int64
        The track rows to lift.
    """
    # a mesh without a mouth gap: the whole layout (the texture is not drawn)
    sel = _mouth_crop_faces(topo) if topo.mouth_faces.size else np.ones(len(topo.faces), bool)
    box = uvs[np.unique(topo.faces[sel])]
    lo, hi = box.min(axis=0), box.max(axis=0)
    side = float((hi - lo).max())
    if not side > 0:
        raise RewriteError(f"the mouth's triangles have no area in the model's UVs "
                           f"(UV box {lo} - {hi})")
    margin = 0.03 * side
    lo, side = lo - margin, side + 2 * margin
    ppu = _mouth_pixels_per_uv(model, track, topo, uvs, rows)
    texels = max(ppu / MOUTH_TEXEL_PIXELS, MOUTH_MIN_DENSITY) * side
    T, frames = mouth_tex_size(texels, len(rows))
    return MouthLayout(T, (float(lo[0]), float(lo[1])), side, frames, ppu)


def _even_pick(rows: np.ndarray, limit: int) -> np.ndarray:
    """At most ``limit`` entries of ``rows``, evenly spaced, first and last kept."""
    if rows.size <= limit:
        return rows
    return rows[np.unique(np.linspace(0, rows.size - 1, limit).round().astype(np.int64))]


def mouth_texture_function(model, frames, track, topo: MeshTopology | None = None, *,
                           frame_index: np.ndarray | None = None, tex_size: int | str = 256,
                           step: int = 1, max_frames: int = MOUTH_MAX_FRAMES, k: int = 4,
                           kernel: str = "inverse", bandwidth: float | None = None,
                           progress: Callable[[int], None] | None = None,
                           on_frames: Callable[[int], None] | None = None) -> MouthFunction:
    """Lift the mouth source's frames into a performance-driven texture function (§6).

    §6: "A simple performance-driven texture function can be obtained with the weighted sum of
    nearest neighbors" (in attribute space). Every used frame's closed mesh (Eq. (5), mouth
    closed as in :func:`close_mouth`) is posed with its camera (Eq. (7)) and a UV texture is
    lifted from the frame (:func:`facetransfer.texture.lift_uv_texture`, texels weighted by
    visibility and obliqueness); the textures and the frames' attribute vectors make a
    :class:`~facetransfer.texture.TextureFunction` with ``k`` neighbours and ``kernel``.

    Memory: float32 textures, ``16 T²`` bytes a frame: at most ``max_frames`` frames (default
    :data:`MOUTH_MAX_FRAMES` = 120, ~126 MB at T = 256), evenly spaced over the usable ones.
    ``tex_size="auto"`` lifts only the mouth's square of the UV layout (:func:`mouth_layout`)
    at a side that follows the face's size in the frames (a texel per screen pixel, up to
    :data:`MOUTH_MAX_TEX`), as float16 (8 bytes a texel), within :data:`MOUTH_MAX_BYTES`.

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
    tex_size : int or "auto"
        ``T``, the texture's width and height in texels (the whole UV layout); ``"auto"``:
        the mouth's square at the face's size (:class:`MouthLayout`).
    step : int
        Use every ``step``-th track row.
    max_frames : int
        Cap on the lifted frames (memory, above).
    k : int
        Neighbours of the texture function.
    progress : callable(int), optional
        Called with 1 after each lifted frame; ``on_frames`` first with their count (fewer
        than ``max_frames`` where ``"auto"`` keeps within :data:`MOUTH_MAX_BYTES`).

    Returns
    -------
    MouthFunction

    Raises
    ------
    RewriteError
        No UVs, no attribute mode, bad ``step``/``max_frames``/``tex_size``, no usable frame.

    References
    ----------
    Vlasic et al. 2005, §6 (texture from video, the performance-driven texture function).
    """

    if len(model.mode_names) < 2:
        raise RewriteError("mouth='function' needs a model with an expression or viseme mode")
    topo = mesh_topology(model) if topo is None else topo
    uvs = _closed_uvs(model, topo)
    if isinstance(tex_size, str) and tex_size != "auto":
        raise RewriteError(f"tex_size must be an integer >= 1 or 'auto', got {tex_size!r}")
    for name, val in (("step", step), ("max_frames", max_frames)) + (
            () if tex_size == "auto" else (("tex_size", tex_size),)):
        if int(val) != val or val < 1:
            raise RewriteError(f"{name} must be an integer >= 1, got {val!r}")
    idx, rows = _mouth_rows(track, len(frames), frame_index, int(step), int(max_frames))
    rows, uvs, T, dtype = _lift_layout(model, track, topo, uvs, rows, tex_size)
    if on_frames is not None:
        on_frames(int(rows.size))
    textures, weights, attrs = _lift_mouth_textures(model, frames, track, topo, uvs, idx, rows,
                                                    T, progress, dtype)
    log.info("mouth texture function: %d frames lifted at %dx%d", rows.size, T, T)
    fn = TextureFunction(textures, weights, attrs, k=k, kernel=kernel, bandwidth=bandwidth)
    return MouthFunction(fn, uvs, idx[rows])


def _lift_layout(model, track, topo: MeshTopology, uvs: np.ndarray, rows: np.ndarray,
                 tex_size: int | str) -> tuple[np.ndarray, np.ndarray, int, type]:
    """``(rows, uvs, T, dtype)`` :func:`mouth_texture_function` lifts: as given at
    ``tex_size`` in float32, or for ``"auto"`` the :func:`mouth_layout`'s frames, square
    (its UVs) and side in float16."""
    if tex_size != "auto":
        return rows, uvs, int(tex_size), np.float32
    layout = mouth_layout(model, track, topo, uvs, rows)
    T = layout.tex_size
    log.info("mouth texture: the mouth's UV square at %dx%d, %.2f screen pixels a texel "
             "(%.0f pixels per UV unit)", T, T, layout.texel_pixels, layout.pixels_per_uv)
    return _even_pick(rows, layout.max_frames), layout.crop(uvs), T, np.float16


def timeline_mouth_function(model, frames, track, index: np.ndarray, n: int,
                            topo: MeshTopology | None = None, **kwargs) -> MouthFunction:
    """:func:`mouth_texture_function` of a mouth source resampled to a new timeline: row ``i``
    (< ``n``) of ``track`` is the pose and weights shown at output frame ``i``, whose frame is
    ``frames[index[i]]`` (``kwargs``: ``tex_size``, ``step``, ``max_frames``, ``k``,
    ``progress``, ``on_frames``)."""

    return mouth_texture_function(model, frames, take_frames(track, np.arange(n)), topo,
                                  frame_index=np.asarray(index)[:n], **kwargs)


def _mouth_rows(track, n_frames: int, frame_index, step: int, max_frames: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """``(idx, rows)``: the frame of every track row (``frame_index``, default ``arange``) and
    the rows to lift (every ``step``-th, face not lost, each frame once, at most
    ``max_frames`` evenly spaced) for :func:`mouth_texture_function`."""
    n = int(track.n_frames)
    idx = np.arange(n) if frame_index is None else np.asarray(frame_index, np.int64)
    if idx.shape != (n,):
        raise RewriteError(f"frame_index must have one entry per track row ({n}), "
                           f"got shape {idx.shape}")
    if n and (idx.min() < 0 or idx.max() >= n_frames):
        raise RewriteError(f"frame_index refers to frames outside 0..{n_frames - 1}")
    rows = np.arange(0, n, step)
    rows = rows[~np.asarray(track.lost, bool)[rows]]
    _, first = np.unique(idx[rows], return_index=True)  # each frame once (its first row)
    rows = _even_pick(np.sort(rows[first]), max_frames)
    if rows.size == 0:
        raise RewriteError(f"no frame to lift a mouth texture from: the face is lost in every "
                           f"frame of {getattr(track, 'source', '') or 'the mouth source'}")
    return idx, rows


def _lift_mouth_textures(model, frames, track, topo: MeshTopology, uvs: np.ndarray,
                         idx: np.ndarray, rows: np.ndarray, tex_size: int, progress,
                         dtype=np.float32):
    """The UV textures (m, T, T, 3), their texel weights (m, T, T), both of ``dtype``, and the
    attribute vectors (m, r) of the closed meshes of track ``rows`` (frames ``idx[rows]``)."""

    from ..io.ahead import ordered_ahead

    faces = topo.faces
    atlas = uv_atlas(faces, uvs, tex_size)
    # texels of the mouth-closing fan (its triangles come after the model's)
    gap = atlas.texel_tri >= int(np.asarray(model.faces).shape[0])
    textures = np.empty((rows.size, tex_size, tex_size, 3), dtype)
    weights = np.empty((rows.size, tex_size, tex_size), dtype)
    attrs = np.empty((rows.size, len(attribute_vector(model, track.weights_at(int(rows[0]))))))

    def lift(j: int, r: int) -> None:                 # frame j's texture, weights, attributes
        w = track.weights_at(r)
        V = close_mouth(model.synthesize(w), topo)  # Eq. (5), mouth closed
        frame = np.asarray(frames[int(idx[r])])
        cam = track.camera(r)
        tex, wt = lift_uv_texture(frame, V, faces, uvs, cam, tex_size, atlas=atlas)
        if gap.any():
            _fill_closed_gap(tex, wt, frame, V, cam, atlas, gap)
        textures[j], weights[j] = tex, wt
        attrs[j] = attribute_vector(model, w)

    # two frames at a time: NumPy's gathers and the raster kernel release the GIL
    for _ in ordered_ahead(lift, ((j, int(r)) for j, r in enumerate(rows)), ahead=2,
                           workers=LIFT_THREADS):
        if progress:
            progress(1)
    return textures, weights, attrs


def resolve_mouth_mode(mouth: str | None, model, *, performance: bool = False) -> str:
    """Validate ``mouth`` (None: :func:`default_mouth_mode`) against :data:`MOUTH_MODES` and the
    model (``"function"`` needs UVs; a default of ``"function"`` falls back to ``"frame"`` for
    a model without UVs)."""
    if mouth is None:
        mouth = default_mouth_mode(performance)
        if mouth == "function" and model.uvs is None:
            log.info("the model has no UVs: the mouth comes from the nearest frame")
            return "frame"
    check_mode("mouth", mouth, MOUTH_MODES)
    if mouth == "function" and model.uvs is None:
        raise RewriteError(_NO_UVS)
    return mouth


#: weight of the closed gap's texels where a frame did not see them (:func:`_fill_closed_gap`)
_GAP_FLOOR = 1e-3


#: Frames lifted at once by :func:`mouth_texture_function` (threads; the result does not
#: depend on it)
LIFT_THREADS = min(2, os.cpu_count() or 1)


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

    T = atlas.tex_size
    unseen = (gap & (weight < _GAP_FLOOR)).ravel()
    covered = atlas.mask.ravel()
    sel = unseen[covered]  # among the covered texels, row-major: atlas.interpolate's order
    if not sel.any():
        return
    P = atlas.interpolate(vertices)[sel]  # (m, 3) surface points of those texels
    uv = frame_uvs(P, camera, (frame.shape[1], frame.shape[0]))
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



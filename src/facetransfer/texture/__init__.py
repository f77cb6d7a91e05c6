"""Texture from video and the performance-driven texture function (Vlasic et al. 2005, §6).

§6: "Once we obtain the 3D geometry, we can lift the texture from the video by assigning pixel
colors to the corresponding mesh vertices. A simple performance-driven texture function can be
obtained with the weighted sum of nearest neighbors."

Pipeline, per tracked frame (pose and mesh known), one module per stage:

1. :mod:`.lifting` — :func:`lift_vertex_colors` / :func:`lift_uv_texture`: sample the frame where
   each vertex (or each texel's surface point) projects, with a confidence weight

       weight = visible * max(0, n_c . d)^p                                          (1)

   where ``n_c`` is the unit surface normal in camera coordinates, ``d`` the unit direction from
   the surface towards the camera (``(0, 0, 1)`` for the weak-perspective camera of §5.1, Eq. (7))
   and ``visible`` the z-buffer test of :mod:`facetransfer.render`. Samples seen obliquely (near
   the silhouette) or hidden get little or no weight. :func:`lift_track` runs it over a clip
   (:func:`lift_merged`: merged as the frames come, in the memory of one texture).
   Texels map to surface points through a :class:`UVAtlas` (:mod:`.atlas`).
2. :mod:`.merge` — :func:`merge_textures`: the weight-normalised mean over frames (its sums
   taken one texture at a time, :class:`TextureSum`); texels never seen are filled by push-pull
   interpolation (:func:`fill_holes`).
3. :mod:`.function` — :class:`TextureFunction`: the texture for an attribute vector (e.g.
   expression and viseme weights concatenated, :func:`attribute_vector`) is the weighted sum of
   the lifted textures of the ``k`` training frames nearest in attribute space, each texel weighted
   by kernel weight times its weight (1); :func:`nearest_frames`, one neighbour (the frame),
   the rows' indices alone: a transfer's mouth frames.

Default textures: :mod:`.default` (:func:`default_face_texture`, procedural until the template is
fitted to the Lee Perry-Smith scan); :mod:`.lee_perry_smith` then carries the scan's colour map
onto the template's UVs by closest points (:mod:`.bake`, :func:`bake_texture`); credit
:data:`LEE_PERRY_SMITH_CREDIT` wherever it is shown.

The rewrite's face textures (the target's, per frame or constant, and the performance-driven
mouth: :class:`~facetransfer.texture.face.MouthFunction`) are :mod:`.face`; the error, input
checks and colour convention every module here shares are :mod:`.base`.

Colours are float32 on the 0..255 scale of the uint8 frames. Texture images follow
:func:`facetransfer.render.sample_texture`: texel ``(col, row) = (u (T - 1), (1 - v) (T - 1))``
with v up, so a lifted texture renders back with :func:`facetransfer.render.render` directly.

References
----------
Vlasic, Brand, Pfister, Popović. Face Transfer with Multilinear Models. SIGGRAPH 2005, §6.
S. Gortler, R. Grzeszczuk, R. Szeliski, M. Cohen. The Lumigraph. SIGGRAPH 1996 (push-pull).
"""

from __future__ import annotations

from .atlas import UVAtlas, uv_atlas
from .bake import BakedTexture, bake_texture
from .base import TextureError, texture_to_uint8
from .default import default_face_texture
from .function import TextureFunction, attribute_vector, nearest_frames
from .lee_perry_smith import (LEE_PERRY_SMITH_CREDIT, lee_perry_smith_template_texture,
                              lee_perry_smith_texture, load_lee_perry_smith)
from .lifting import (LiftedTexture, LiftedTrack, LiftedUVTexture, lift_merged, lift_track,
                      lift_uv_texture, lift_vertex_colors, obliqueness_weight)
from .merge import MergedTexture, TextureSum, fill_holes, fill_vertex_colors, merge_textures

__all__ = [
    "TextureError",
    "LiftedTexture",
    "LiftedUVTexture",
    "MergedTexture",
    "UVAtlas",
    "uv_atlas",
    "obliqueness_weight",
    "lift_vertex_colors",
    "lift_uv_texture",
    "merge_textures",
    "TextureSum",
    "fill_holes",
    "fill_vertex_colors",
    "TextureFunction",
    "LiftedTrack",
    "lift_track",
    "lift_merged",
    "attribute_vector",
    "nearest_frames",
    "default_face_texture",
    "bake_texture",
    "BakedTexture",
    "load_lee_perry_smith",
    "lee_perry_smith_texture",
    "lee_perry_smith_template_texture",
    "LEE_PERRY_SMITH_CREDIT",
    "texture_to_uint8",
]

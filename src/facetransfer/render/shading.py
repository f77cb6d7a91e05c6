"""Colour for rasterised pixels (paper §6): texture sampling, and the numba kernels that shade a
:class:`~facetransfer.render.raster.Raster` from per-vertex colours or a UV texture, optionally
Lambert-lit (by :func:`facetransfer.geometry.vertex_normals`)."""

from __future__ import annotations

import numpy as np

from ..errors import AssetError, RenderError, ShapeError
from ..geometry import vertex_normals
from ..jit import maybe_njit as _maybe_njit, read_only
from .raster import Raster

__all__ = ["sample_texture", "shade_texture", "shade_layers", "MAX_LAYERS",
           "interpolate_vertex_values", "interpolate_vertex_pair"]


def _check_texture(texture) -> np.ndarray:
    if texture is None:
        raise AssetError("texture is missing (None)")
    T = np.asarray(texture)
    if T.ndim != 3 or T.shape[2] != 3 or T.dtype != np.uint8 or T.shape[0] < 1 or T.shape[1] < 1:
        raise AssetError(f"texture must be an (H, W, 3) uint8 RGB image, got {T.shape} {T.dtype}")
    return T


def _check_colors(colors, n: int) -> np.ndarray:
    C = np.asarray(colors)
    if C.shape != (n, 3):
        raise ShapeError(f"colors must be (n_vertices, 3) = ({n}, 3), got {C.shape}")
    if C.dtype == np.uint8:
        return C.astype(np.float64)
    C = C.astype(np.float64)
    if not np.all(np.isfinite(C)):
        raise ShapeError("colors contain NaN or infinite values")
    # float colours: 0..1 if they all fit, otherwise 0..255
    return C * 255.0 if C.max(initial=0.0) <= 1.0 else C


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup, ``uv`` (m, 2) with v up -> (m, 3) float64 in 0..255.

    Texel ``(col, row) = (u (Wt - 1), (1 - v) (Ht - 1))``; coordinates are clamped to the image.
    """
    T = _check_texture(texture)
    Ht, Wt = T.shape[:2]
    u = np.clip(uv[:, 0], 0.0, 1.0) * (Wt - 1)
    v = (1.0 - np.clip(uv[:, 1], 0.0, 1.0)) * (Ht - 1)
    c0 = np.minimum(np.floor(u).astype(np.intp), Wt - 1)
    r0 = np.minimum(np.floor(v).astype(np.intp), Ht - 1)
    c1 = np.minimum(c0 + 1, Wt - 1)
    r1 = np.minimum(r0 + 1, Ht - 1)
    fu = (u - c0)[:, None]
    fv = (v - r0)[:, None]
    Tf = T.astype(np.float32) if T.size <= 4096 * 4096 * 3 else T
    top = Tf[r0, c0] * (1 - fu) + Tf[r0, c1] * fu
    bot = Tf[r1, c0] * (1 - fu) + Tf[r1, c1] * fu
    return top * (1 - fv) + bot * fv


def _texel_at_py(Ht, Wt, u, v):  # pragma: no cover (numba, inlined)
    """The bilinear footprint of texture coordinates ``(u, v)`` (v up, clamped to [0, 1]) in a
    ``(Ht, Wt)`` texture: rows ``r0, r1``, columns ``c0, c1`` and weights ``fu, fv`` of texel
    ``(col, row) = (u (Wt - 1), (1 - v) (Ht - 1))``, as :func:`sample_texture`."""
    u = min(max(u, 0.0), 1.0) * (Wt - 1)
    v = (1.0 - min(max(v, 0.0), 1.0)) * (Ht - 1)
    c0 = min(int(np.floor(u)), Wt - 1)
    r0 = min(int(np.floor(v)), Ht - 1)
    return r0, min(r0 + 1, Ht - 1), c0, min(c0 + 1, Wt - 1), u - c0, v - r0


_texel_at = _maybe_njit(_texel_at_py, inline=True)


def _texel_py(tex, u, v):  # pragma: no cover (numba)
    """Bilinear sample (r, g, b) of ``tex`` at texture coordinates ``(u, v)``
    (:func:`_texel_at`)."""
    r0, r1, c0, c1, fu, fv = _texel_at(tex.shape[0], tex.shape[1], u, v)
    out0 = (tex[r0, c0, 0] * (1.0 - fu) + tex[r0, c1, 0] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 0] * (1.0 - fu) + tex[r1, c1, 0] * fu) * fv
    out1 = (tex[r0, c0, 1] * (1.0 - fu) + tex[r0, c1, 1] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 1] * (1.0 - fu) + tex[r1, c1, 1] * fu) * fv
    out2 = (tex[r0, c0, 2] * (1.0 - fu) + tex[r0, c1, 2] * fu) * (1.0 - fv) \
        + (tex[r1, c0, 2] * (1.0 - fu) + tex[r1, c1, 2] * fu) * fv
    return out0, out1, out2


_texel = _maybe_njit(_texel_py)


#: The 256 values of a uint8 as float64 (a texel's conversion as a table look-up, in L1)
_U8_AS_FLOAT = np.arange(256, dtype=np.float64)


def _footprint_py(tex, uvs, i0, i1, i2, b0, b1, b2, rows, weights, x, k):  # pragma: no cover
    """The bilinear footprint (:func:`_texel_at`) in ``tex`` (Ht, Wt, 3) of the barycentric
    interpolation ``b0 uvs[i0] + b1 uvs[i1] + b2 uvs[i2]``, stored for pixel ``x`` of a row and
    layer ``k``: ``rows[x, k] = (r0, r1, c0, c1)``, ``weights[x, k] = (fu, fv)`` (numba,
    inlined)."""
    r0, r1, c0, c1, fu, fv = _texel_at(tex.shape[0], tex.shape[1],
                                       b0 * uvs[i0, 0] + b1 * uvs[i1, 0] + b2 * uvs[i2, 0],
                                       b0 * uvs[i0, 1] + b1 * uvs[i1, 1] + b2 * uvs[i2, 1])
    rows[x, k, 0] = r0
    rows[x, k, 1] = r1
    rows[x, k, 2] = c0
    rows[x, k, 3] = c1
    weights[x, k, 0] = fu
    weights[x, k, 1] = fv


_footprint = _maybe_njit(_footprint_py, inline=True)


def _sample_py(tex, rows, weights, x, k, image, iy):  # pragma: no cover (numba, inlined)
    """``image[iy, x]`` = the bilinear sample of ``tex`` (Ht, Wt, 3) uint8 over the footprint
    ``rows[x, k]``, ``weights[x, k]`` (:func:`_footprint`), rounded and clipped to 0..255: the
    arithmetic of :func:`_texel` (hence of :func:`sample_texture`), the texels addressed by
    unsigned indices (clamped to the image already: no negative-index wrapping) and converted
    by :data:`_U8_AS_FLOAT`."""
    fu, fv = weights[x, k, 0], weights[x, k, 1]
    gu = 1.0 - fu
    gv = 1.0 - fv
    a0, a1 = np.uint64(rows[x, k, 0]), np.uint64(rows[x, k, 1])
    d0, d1 = np.uint64(rows[x, k, 2]), np.uint64(rows[x, k, 3])
    lut = _U8_AS_FLOAT
    for c in range(3):
        cc = np.uint64(c)
        v = (lut[tex[a0, d0, cc]] * gu + lut[tex[a0, d1, cc]] * fu) * gv \
            + (lut[tex[a1, d0, cc]] * gu + lut[tex[a1, d1, cc]] * fu) * fv
        image[iy, x, c] = min(max(np.rint(v), 0.0), 255.0)


_sample = _maybe_njit(_sample_py, inline=True)


def _shade_layers_kernel_py(tid, bary, y0, x0, F, flags, uv0, tex0, img0, uv1, tex1, img1,
                            uv2, tex2, img2, uv3, tex3, img3, labels, rows, weights, row_flags
                            ):  # pragma: no cover (numba)
    """Unlit texture shading of up to four layers in one pass over a raster's box.

    The box is ``labels``' shape at ``(x0, y0)`` of the whole raster ``tid``, ``bary`` (one
    layout, one compiled kernel). At its pixel ``(iy, ix)``, covered by triangle ``f``:
    ``labels[iy, ix] = flags[f]``, and layer ``k``'s
    image ``img<k>`` takes the bilinear sample of ``tex<k>`` at the barycentric interpolation
    of ``uv<k>`` where bit ``1 << k`` of ``flags[f]`` is set (layers are separate arguments: a
    tuple indexed per pixel is several times slower in numba). Row by row, in two passes: the
    texel footprints of the row's samples (:func:`_footprint`, into the scratch ``rows`` (W, 4,
    4) int64, ``weights`` (W, 4, 2) float64, ``row_flags`` (W,) uint8), then the texels
    (:func:`_sample`): each pass's chain of dependent loads (triangle, vertices, uvs; texels,
    table) is short enough for the processor to overlap several pixels' (15 % faster than one
    pass). Returns False (and stops) at a triangle index beyond ``F``."""
    H, W = labels.shape
    n = F.shape[0]
    for iy in range(H):
        by = np.uint64(y0 + iy)  # unsigned: no negative-index wrapping per read
        for ix in range(W):
            bx = np.uint64(x0 + ix)
            f = tid[by, bx]
            if f >= n:
                return False
            fl = np.uint8(0)
            if f >= 0:
                fl = flags[f]
                labels[iy, ix] = fl
            row_flags[ix] = fl
            if (fl & 15) == 0:
                continue
            i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
            b0, b1, b2 = float(bary[by, bx, 0]), float(bary[by, bx, 1]), float(bary[by, bx, 2])
            if fl & 1:
                _footprint(tex0, uv0, i0, i1, i2, b0, b1, b2, rows, weights, ix, 0)
            if fl & 2:
                _footprint(tex1, uv1, i0, i1, i2, b0, b1, b2, rows, weights, ix, 1)
            if fl & 4:
                _footprint(tex2, uv2, i0, i1, i2, b0, b1, b2, rows, weights, ix, 2)
            if fl & 8:
                _footprint(tex3, uv3, i0, i1, i2, b0, b1, b2, rows, weights, ix, 3)
        for ix in range(W):
            fl = row_flags[ix]
            if fl & 1:
                _sample(tex0, rows, weights, ix, 0, img0, iy)
            if fl & 2:
                _sample(tex1, rows, weights, ix, 1, img1, iy)
            if fl & 4:
                _sample(tex2, rows, weights, ix, 2, img2, iy)
            if fl & 8:
                _sample(tex3, rows, weights, ix, 3, img3, iy)
    return True


_shade_layers_kernel = _maybe_njit(_shade_layers_kernel_py)

#: Layers :func:`shade_layers` shades in one pass.
MAX_LAYERS = 4


def shade_layers(raster: Raster, faces: np.ndarray, layers, flags: np.ndarray,
                 box: tuple[slice, slice] | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Texture the pixels of a raster with several textures in one pass (numba), unlit.

    Layer ``k`` is shaded at the pixels whose triangle has bit ``1 << k`` of ``flags`` set:
    each such pixel takes the bilinear texture sample (:func:`sample_texture`) at the
    barycentric interpolation of the layer's uvs. The higher bits of ``flags`` (4 to 7) only
    label pixels: ``labels`` is ``flags`` of each covered pixel's triangle (0 where nothing
    is), so any set of triangles yields its pixels (``labels & bit``) without another pass
    over the raster.

    Parameters
    ----------
    raster : Raster
        Of a mesh with faces ``faces``.
    faces : (F, 3) int
    layers : sequence of (uvs (n, 2) float, texture (Ht, Wt, 3) uint8) or None
        At most :data:`MAX_LAYERS`; the uvs (v up) are of the mesh's vertices. None: a slot
        not used (no flag may select it).
    flags : (F,) uint8
        Per triangle: the layers that shade it (bits 0-3) and labels (bits 4-7).
    box : (slice, slice), optional
        ``(rows, columns)`` of the raster to shade (default: all of it), with unit steps.

    Returns
    -------
    images : list of (h, w, 3) uint8 or None
        One per layer, black where the layer is not shaded (None for an unused slot); ``(h,
        w)`` the box's size.
    labels : (h, w) uint8
    """
    Fa = np.ascontiguousarray(faces, dtype=np.int64)
    fl = np.ascontiguousarray(flags, dtype=np.uint8)
    if fl.shape != (len(Fa),):
        raise ShapeError(f"flags must be ({len(Fa)},) uint8, got {fl.shape}")
    if not 1 <= len(layers) <= MAX_LAYERS:
        raise ShapeError(f"shade_layers takes 1 to {MAX_LAYERS} layers, got {len(layers)}")
    n_given = len(layers)
    layers = list(layers) + [None] * (MAX_LAYERS - n_given)
    unused = sum(1 << k for k, layer in enumerate(layers) if layer is None)
    if fl.size and int(np.bitwise_or.reduce(fl)) & unused:
        raise ShapeError("flags select a layer that is not given")
    tid, bary = _whole(raster)
    y0, x0, H, W = _box_of(box, tid.shape)
    n_vertices = int(Fa.max()) + 1 if Fa.size else 0
    args, images = [], []
    for layer in layers:
        if layer is None:  # no flag selects it: never read or written
            args += [_DUMMY_UV, read_only(_DUMMY_TEX), _DUMMY_TEX]  # a texture, an image
            images.append(None)
            continue
        images.append(np.zeros((H, W, 3), np.uint8))
        args += [_check_uvs(layer[0], n_vertices),
                 read_only(np.ascontiguousarray(_check_texture(layer[1]))), images[-1]]
    labels = np.zeros((H, W), np.uint8)
    scratch = (np.empty((W, MAX_LAYERS, 4), np.int64), np.empty((W, MAX_LAYERS, 2)),
               np.empty(W, np.uint8))  # a row's texel footprints
    if not _shade_layers_kernel(tid, bary, y0, x0, Fa, fl, *args, labels, *scratch):
        raise ShapeError(f"the raster's triangles exceed the {len(Fa)} faces given")
    return images[:n_given], labels


def _whole(raster: Raster) -> tuple[np.ndarray, np.ndarray]:
    """The raster's ``tri_id`` (H, W) int32 and ``bary`` (H, W, 3) float32, C-contiguous (a
    raster's own arrays as they are; a view of another's copied): the kernels take whole
    arrays and a box's offset, one layout, so one compiled kernel each (a second layout is
    loaded from numba's cache mid-clip, ~10 ms with the interpreter held)."""
    return (np.ascontiguousarray(raster.tri_id, np.int32),
            np.ascontiguousarray(raster.bary, np.float32))


def _box_of(box: tuple[slice, slice] | None, shape: tuple[int, ...]
            ) -> tuple[int, int, int, int]:
    """``(y0, x0, h, w)`` of the box ``(rows, columns)`` (unit steps) of an array of
    ``shape`` (H, W, ...), as numpy slices it (clipped to the array); the whole array for
    None."""
    H, W = shape[:2]
    if box is None:
        return 0, 0, H, W
    rows, cols = box
    (y0, y1, sy), (x0, x1, sx) = rows.indices(H), cols.indices(W)
    if sy != 1 or sx != 1:
        raise ShapeError(f"box must have unit steps, got {box}")
    return y0, x0, max(y1 - y0, 0), max(x1 - x0, 0)


def interpolate_vertex_values(raster: Raster, faces: np.ndarray, values: np.ndarray,
                              box: tuple[slice, slice] | None = None) -> np.ndarray:
    """A per-vertex scalar at the pixels of a raster, barycentrically interpolated.

    Parameters
    ----------
    raster : Raster
        Of a mesh with faces ``faces``.
    faces : (F, 3) int
    values : (n,) float
        One value per vertex the faces index.
    box : (slice, slice), optional
        ``(rows, columns)`` of the raster to interpolate over (default: all of it), with
        unit steps.

    Returns
    -------
    (h, w) float32
        At a covered pixel, ``sum_k bary[k] * values[faces[tri, k]]``; 0 where nothing is.
    """
    Fa = np.ascontiguousarray(faces, dtype=np.int64)
    v = np.ascontiguousarray(values, dtype=np.float32)
    if v.ndim != 1 or (Fa.size and v.shape[0] <= int(Fa.max())):
        raise ShapeError(f"values must be (n,) covering the faces' vertices, got {v.shape}")
    tid, bary = _whole(raster)
    y0, x0, h, w = _box_of(box, tid.shape)
    out = np.zeros((h, w), np.float32)
    if not _interpolate_kernel(tid, bary, y0, x0, Fa, v, out):
        raise ShapeError(f"the raster's triangles exceed the {len(Fa)} faces given")
    return out


def interpolate_vertex_pair(raster: Raster, faces: np.ndarray, values: np.ndarray,
                            more: np.ndarray, box: tuple[slice, slice] | None = None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`interpolate_vertex_values` of two per-vertex scalars over the same raster and
    box in one pass: the same bits as two calls, the raster's triangles and barycentrics read
    once (the jaw region's two alphas, :func:`facetransfer.jaw.paint_shaded_jaw`: 0.65 -> 0.45 ms
    a frame of issue 13's pair).

    Parameters
    ----------
    raster : Raster
        Of a mesh with faces ``faces``.
    faces : (F, 3) int
    values, more : (n,) float
        One value per vertex the faces index, each.
    box : (slice, slice), optional
        ``(rows, columns)`` of the raster (default: all of it), with unit steps.

    Returns
    -------
    (h, w) float32, (h, w) float32
        ``values`` and ``more`` interpolated; 0 where nothing is.
    """
    Fa = np.ascontiguousarray(faces, dtype=np.int64)
    top = int(Fa.max()) if Fa.size else -1
    vs = []
    for v in (values, more):
        v = np.ascontiguousarray(v, dtype=np.float32)
        if v.ndim != 1 or v.shape[0] <= top:
            raise ShapeError(f"values must be (n,) covering the faces' vertices, got {v.shape}")
        vs.append(v)
    tid, bary = _whole(raster)
    y0, x0, h, w = _box_of(box, tid.shape)
    out, out2 = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    if not _interpolate_pair_kernel(tid, bary, y0, x0, Fa, vs[0], vs[1], out, out2):
        raise ShapeError(f"the raster's triangles exceed the {len(Fa)} faces given")
    return out, out2


def _interpolate_pair_kernel_py(tid, bary, y0, x0, F, values, more, out,
                                out2):  # pragma: no cover (numba)
    """:func:`_interpolate_kernel` of ``values`` into ``out`` and of ``more`` into ``out2``
    (both (h, w) float32) in one pass, each sum in its order. A second kernel on purpose: one
    kernel over ``k`` stacked scalars (a loop of a run-time length per pixel) took the single
    interpolation from 0.23 to 0.41 ms on the default model's face box, and the pair to 0.60
    against this one's 0.35 (fifty-second session)."""
    H, W = out.shape
    n = F.shape[0]
    for iy in range(H):
        y = np.uint64(y0 + iy)  # unsigned: no negative-index wrapping per read
        for ix in range(W):
            x = np.uint64(x0 + ix)
            f = tid[y, x]
            if f < 0:
                continue
            if f >= n:
                return False
            b0, b1, b2 = bary[y, x, 0], bary[y, x, 1], bary[y, x, 2]
            i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
            out[iy, ix] = b0 * values[i0] + b1 * values[i1] + b2 * values[i2]
            out2[iy, ix] = b0 * more[i0] + b1 * more[i1] + b2 * more[i2]
    return True


def _interpolate_kernel_py(tid, bary, y0, x0, F, values, out):  # pragma: no cover (numba)
    """:func:`interpolate_vertex_values` into ``out`` (h, w) float32, the box of that shape
    at ``(x0, y0)`` of the whole raster ``tid``, ``bary``; False (and stops) at a triangle
    index beyond ``F``."""
    H, W = out.shape
    n = F.shape[0]
    for iy in range(H):
        y = np.uint64(y0 + iy)  # unsigned: no negative-index wrapping per read
        for ix in range(W):
            x = np.uint64(x0 + ix)
            f = tid[y, x]
            if f < 0:
                continue
            if f >= n:
                return False
            out[iy, ix] = (bary[y, x, 0] * values[F[f, 0]] + bary[y, x, 1] * values[F[f, 1]]
                           + bary[y, x, 2] * values[F[f, 2]])
    return True


_interpolate_kernel = _maybe_njit(_interpolate_kernel_py)
_interpolate_pair_kernel = _maybe_njit(_interpolate_pair_kernel_py)


def _check_uvs(uvs, n_vertices: int) -> np.ndarray:
    """``uvs`` as a C-contiguous (n, 2) float64 array of at least ``n_vertices`` rows (the
    vertices the faces index)."""
    U = np.ascontiguousarray(uvs, dtype=np.float64)
    if U.ndim != 2 or U.shape[1] != 2 or n_vertices > U.shape[0]:
        raise ShapeError(f"uvs must be (n, 2) covering the faces' vertices, got {U.shape}")
    return U


def shade_texture(raster: Raster, faces: np.ndarray, uvs: np.ndarray, texture: np.ndarray,
                  select: np.ndarray | None = None, box: tuple[slice, slice] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Texture the pixels of a raster without lighting, in one pass (numba).

    Every pixel covered by a (selected) triangle takes the bilinear texture sample
    (:func:`sample_texture`) at the barycentric interpolation of its triangle's ``uvs``
    (:func:`shade_layers` with one layer).

    Parameters
    ----------
    raster : Raster
        Of a mesh with faces ``faces``.
    faces : (F, 3) int
    uvs : (n, 2) float
        Texture coordinates (v up) of the mesh's vertices.
    texture : (Ht, Wt, 3) uint8
    select : (F,) bool, optional
        Shade only these triangles (the others stay black and outside the mask).
    box : (slice, slice), optional
        ``(rows, columns)`` of the raster to shade (default: all of it), with unit steps.

    Returns
    -------
    image : (h, w, 3) uint8
        Black where nothing is shaded; ``(h, w)`` the box's size.
    mask : (h, w) bool
        The shaded pixels.
    """
    n = len(faces)
    sel = np.ones(n, np.uint8) if select is None else \
        np.ascontiguousarray(select, dtype=bool).view(np.uint8)
    if sel.shape != (n,):
        raise ShapeError(f"select must be ({n},) bool, got {sel.shape}")
    (image,), labels = shade_layers(raster, faces, [(uvs, texture)], sel, box)
    return image, labels.view(bool)


def check_shading(shading: str, ambient: float) -> None:
    """RenderError unless ``shading`` is "lambert" or "none" and ``ambient`` is in [0, 1]."""
    if shading not in ("lambert", "none"):
        raise RenderError(f"shading must be 'lambert' or 'none', got {shading!r}")
    if not 0.0 <= float(ambient) <= 1.0:
        raise RenderError(f"ambient must be in [0, 1], got {ambient}")


def check_textured(texture, uvs, n: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The texture (Ht, Wt, 3) uint8 and the uvs (n, 2) float64 checked, or ``(None, None)``
    when neither is given (one without the other is an error)."""
    if texture is None and uvs is None:
        return None, None
    T = _check_texture(texture)
    UV = np.asarray(uvs, dtype=np.float64) if uvs is not None else None
    if UV is None or UV.shape != (n, 2):
        raise ShapeError(f"uvs must be (n_vertices, 2) = ({n}, 2) with a texture, got "
                         f"{None if UV is None else UV.shape}")
    return T, UV


def _light_direction(light) -> np.ndarray:
    """Unit (3,) direction towards the light."""
    L = np.asarray(light, dtype=np.float64)
    if L.shape != (3,) or not np.linalg.norm(L) > 0:
        raise ShapeError(f"light must be a non-zero (3,) direction, got {L}")
    return L / np.linalg.norm(L)


def shade_image(image: np.ndarray, raster: Raster, V: np.ndarray, F: np.ndarray,
                rotation: np.ndarray, *, texture: np.ndarray | None, uvs: np.ndarray | None,
                colors: np.ndarray | None, lambert: bool, light, ambient: float) -> None:
    """Colour the covered pixels of ``image`` (H, W, 3) uint8 in place (numba).

    The colour is the bilinear ``texture`` sample at the interpolated ``uvs`` (n, 2) if a
    texture is given, else the interpolated per-vertex ``colors`` (n, 3) in 0..255, else grey
    200; with ``lambert`` it is multiplied by ``ambient + (1 - ambient) max(0, n . light)``,
    ``n`` the interpolated vertex normal of the mesh ``V`` (n, 3), ``F`` (F, 3) turned into
    camera space by ``rotation`` (3, 3).
    """
    n = V.shape[0]
    if texture is not None:
        src, uv_arr, tex_arr, col_arr = 1, uvs, np.ascontiguousarray(texture), _DUMMY_COLORS
    elif colors is not None:
        src, uv_arr, tex_arr, col_arr = 0, _DUMMY_UV, _DUMMY_TEX, colors
    else:
        src, uv_arr, tex_arr, col_arr = 0, _DUMMY_UV, _DUMMY_TEX, np.full((n, 3), 200.0)
    if lambert:
        L = _light_direction(light)
        Nc = np.ascontiguousarray(vertex_normals(V, F) @ rotation.T)  # camera space
    else:
        L, Nc = np.zeros(3), _DUMMY_COLORS
    _shade_kernel(raster.tri_id, raster.bary, F, src, col_arr, uv_arr, tex_arr, lambert, Nc, L,
                  ambient, image)


_DUMMY_COLORS = np.zeros((1, 3))
_DUMMY_UV = np.zeros((1, 2))
_DUMMY_TEX = np.zeros((1, 1, 3), np.uint8)


def _shade_kernel_py(tid, bary, F, src, colors, uvs, tex, lambert, normals, light, ambient,
                     image):  # pragma: no cover
    """Colour every covered pixel: interpolated vertex colour (src 0) or bilinear texture
    sample at the interpolated uv (src 1), times ``ambient + (1 - ambient) max(0, n . l)``."""
    H, W = tid.shape
    for iy in range(H):
        for ix in range(W):
            f = tid[iy, ix]
            if f < 0:
                continue
            i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
            b0, b1, b2 = float(bary[iy, ix, 0]), float(bary[iy, ix, 1]), float(bary[iy, ix, 2])
            if src == 1:
                cr, cg, cb = _texel(tex, b0 * uvs[i0, 0] + b1 * uvs[i1, 0] + b2 * uvs[i2, 0],
                                    b0 * uvs[i0, 1] + b1 * uvs[i1, 1] + b2 * uvs[i2, 1])
            else:
                cr = b0 * colors[i0, 0] + b1 * colors[i1, 0] + b2 * colors[i2, 0]
                cg = b0 * colors[i0, 1] + b1 * colors[i1, 1] + b2 * colors[i2, 1]
                cb = b0 * colors[i0, 2] + b1 * colors[i1, 2] + b2 * colors[i2, 2]
            if lambert:
                nx = b0 * normals[i0, 0] + b1 * normals[i1, 0] + b2 * normals[i2, 0]
                ny = b0 * normals[i0, 1] + b1 * normals[i1, 1] + b2 * normals[i2, 1]
                nz = b0 * normals[i0, 2] + b1 * normals[i1, 2] + b2 * normals[i2, 2]
                nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                cos = 0.0
                if nn > 0:
                    cos = max((nx * light[0] + ny * light[1] + nz * light[2]) / nn, 0.0)
                g = ambient + (1.0 - ambient) * cos
                cr *= g
                cg *= g
                cb *= g
            image[iy, ix, 0] = min(max(np.rint(cr), 0.0), 255.0)
            image[iy, ix, 1] = min(max(np.rint(cg), 0.0), 255.0)
            image[iy, ix, 2] = min(max(np.rint(cb), 0.0), 255.0)


_shade_kernel = _maybe_njit(_shade_kernel_py)


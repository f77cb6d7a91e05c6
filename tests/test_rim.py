"""The rendered face's outer band where its outline moved inside the target's
(:mod:`facetransfer.rim`)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facetransfer import rim
from facetransfer.errors import MeshError
from facetransfer.render import WeakPerspective, rasterize
from facetransfer.rewrite import FrameTextures, rewrite_frame
from facetransfer.rewrite_options import BlendOptions
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology

from conftest import mean_person_track

SIZE = 512
SKIN, EDGE, BACK = (200, 150, 120), (30, 25, 20), (120, 160, 120)


def test_texture_positions_invert_frame_uvs():
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    P = 50.0 + 10.0 * np.stack([np.cos(t), np.sin(t)], axis=1)
    uv = frame_uvs(np.c_[P, np.zeros(12)], _Identity(), (101, 81))
    np.testing.assert_allclose(rim.texture_positions(uv, (101, 81)), P, atol=1e-9)
    frame = np.zeros((81, 101, 3), np.uint8)
    np.testing.assert_allclose(rim.lifted_positions(FaceTexture(frame, uv, 0), frame), P,
                               atol=1e-9)
    assert rim.lifted_positions(FaceTexture(frame.copy(), uv, 0), frame) is None


def _grid(n: int, xs: tuple[float, float], ys: tuple[float, float]):
    """``(points (n², 2), faces)``: an ``n`` x ``n`` grid of points over the rectangle ``xs`` x
    ``ys`` (pixels), cut into triangles that all face the camera (rasterize's sense)."""
    g = np.stack(np.meshgrid(np.linspace(*xs, n), np.linspace(*ys, n)), -1).reshape(-1, 2)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    faces = np.concatenate([np.c_[a, a + n, a + 1], np.c_[a + 1, a + n, a + n + 1]])
    e1, e2 = g[faces[:, 1]] - g[faces[:, 0]], g[faces[:, 2]] - g[faces[:, 0]]
    flip = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0
    faces[flip] = faces[flip][:, ::-1]
    return g, faces


def test_lifted_depth_is_the_distance_to_the_silhouettes_outline():
    """A square of side 60 px drawn as a grid of small triangles: at its centre the depth is
    half the side, at a point 5 px inside its edge 5 px (to the half-resolution map's ~1 px),
    outside it 0; with its middle given as ``core`` the map is the same."""
    g, faces = _grid(31, (20, 80), (10, 70))
    depth = rim.lifted_depth(g, faces, (90, 100))
    assert depth.shape == (45, 50)
    at = rim._depth_at(depth, np.array([[50.0, 40.0], [25.0, 40.0], [10.0, 40.0]]))
    np.testing.assert_allclose(at, [30.0, 5.0, 0.0], atol=1.5)
    core = np.zeros((45, 50), bool)
    core[10:26, 15:35] = True
    np.testing.assert_array_equal(rim.lifted_depth(g, faces, (90, 100), core=core), depth)


class _Identity:
    """A camera that projects (x, y, z) to (x, y)."""

    @staticmethod
    def project(V):
        return np.array(V[:, :2], np.float64)


@pytest.fixture(scope="module")
def narrower(arkit_model):
    """The mean face at scale 25 (the target, ~270 px across) and at 24 and 19 (new faces 4 %
    and 24 % narrower), the same centre; the target frame: skin inside the target's
    silhouette with a dark edge 4 px wide just inside it (the hair beside a cheek the track's
    outline takes in), background out."""
    model = arkit_model
    topo = mesh_topology(model)
    zeros = np.zeros((1, 52), np.float32)
    target = mean_person_track(model, zeros, size=SIZE, scale=25.0)
    new = {k: mean_person_track(model, zeros, size=SIZE, scale=k) for k in (24.0, 19.0)}
    Vc = close_mouth(model.synthesize(target.weights_at(0)), topo)
    mask = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE)).mask
    from facetransfer.composite import erode_mask

    frame = np.empty((SIZE, SIZE, 3), np.uint8)
    frame[:] = BACK
    frame[mask] = EDGE
    frame[erode_mask(mask, 4)] = SKIN
    tex = FaceTexture(frame, frame_uvs(Vc, target.camera(0), (SIZE, SIZE)), 0)
    return model, topo, new, frame, tex, Vc


def test_a_narrower_face_keeps_the_targets_pixels_where_its_outline_was_drawn(narrower,
                                                                             monkeypatch):
    """The new face is 4 % narrower (its outline 4-6 px inside the target's): its outer
    band's texture is the target's dark edge. With the rule the band shows the target's own
    pixels (its skin, softly mixed over a pixel or two at the rule's edge); without it (:data:`facetransfer.rim.MOVED` out of reach) the dark edge
    is drawn inside the face. 24 % narrower, the outline moved farther in than the rule looks
    (:data:`facetransfer.rim.REACH` band widths, ~10 px here, against ~30): the band is left
    as rendered (what lies under it is no longer the edge of the target's face)."""
    model, topo, new, frame, tex, Vc = narrower

    def render(scale):
        V = model.synthesize(new[scale].weights_at(0))
        return rewrite_frame(frame, V, new[scale].camera(0), topo, FrameTextures(tex),
                             blending=BlendOptions("none")).image

    on, far = render(24.0), render(19.0)
    monkeypatch.setattr(rim, "MOVED", np.inf)
    off, far_off = render(24.0), render(19.0)
    kept = (on != off).any(axis=-1)
    assert kept.sum() > 500
    # the target's own pixels (a soft edge of ~2 px mixes the two at the rule's outline)
    assert np.mean((on[kept] == frame[kept]).all(axis=-1)) > 0.85
    # the band (~7 px) is wider than the dark edge (4 px)
    assert np.mean(np.abs(off[kept].astype(int) - EDGE).max(axis=1) < 40) > 0.6
    assert np.mean(np.abs(on[kept].astype(int) - SKIN).max(axis=1) < 10) > 0.8
    assert (far != far_off).any(axis=-1).sum() < 0.05 * kept.sum()


def test_an_outline_sliding_along_itself_keeps_the_targets_pixels(narrower, monkeypatch):
    """The new face is the target's own, turned 5 degrees in the image plane about the head:
    its outline slides along itself (as a jaw that drops moves along the jaw line, ``make
    demo`` frame 52), nowhere much nearer the centre, and its outer band takes the target's
    dark edge from a few pixels along the outline, where the target shows its skin. With the
    rule those pixels keep the target's skin; without it the dark edge is drawn there."""
    model, topo, new, frame, tex, Vc = narrower
    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    cam = target.camera(0)
    a = np.deg2rad(5.0)
    roll = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    turned = WeakPerspective(cam.scale, roll @ cam.rotation, cam.translation)
    from facetransfer.composite import erode_mask

    skin = erode_mask((frame == SKIN).all(axis=-1), 2)  # 2 px of the rule's tolerance (MOVED)
    skin[:16] = skin[-16:] = False  # the head and the neck cut by the frame: no outline there

    def dark_on_skin():
        out = rewrite_frame(frame, Vc, turned, topo, FrameTextures(tex),
                            blending=BlendOptions("none")).image
        return int(((np.abs(out.astype(int) - EDGE).max(axis=-1) < 40) & skin).sum())

    on = dark_on_skin()
    monkeypatch.setattr(rim, "MOVED", np.inf)
    off = dark_on_skin()
    assert off > 400
    assert on < 0.25 * off


def test_the_same_outline_keeps_its_band(narrower):
    """The new face drawn where the target's texture lifted it: nothing lies deeper than its
    texture, so nothing is kept from the target; drawn 4 px nearer the centre than lifted
    (a narrower face), the pixels of its outer band are (and a texture that is not the frame
    itself is never judged so)."""
    model, topo, new, frame, tex, Vc = narrower
    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    r = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE))
    lifted = rim.lifted_positions(tex, frame)
    assert rim.lifted_positions(FaceTexture(frame.copy(), tex.uvs, 0), frame) is None
    assert not rim.drawn_inside(r.mask, r, topo.faces, lifted, lifted).any()
    c = lifted.mean(axis=0)
    inward = lifted - 4.0 * (lifted - c) / np.linalg.norm(lifted - c, axis=1, keepdims=True)
    kept = rim.drawn_inside(r.mask, r, topo.faces, lifted, inward)
    from facetransfer.composite import erode_mask

    k = max(2, int(round(rim.RIM * np.sqrt(r.mask.sum()))))
    band = r.mask & ~erode_mask(r.mask, k)
    assert kept.sum() > 0.5 * band.sum()
    assert not (kept & erode_mask(r.mask, 3 * k)).any()   # only near the outline
    # drawn beyond the frame's edge (the raster as before): nothing to keep, no error
    assert not rim.drawn_inside(r.mask, r, topo.faces, lifted, inward + [SIZE, 0]).any()


def test_triangles_judged_beyond_the_crops_edge_keep_nothing(narrower, monkeypatch):
    """The triangles the rule picks may all lie past the crop's edge (a face cut by the frame's
    bottom: ``bench_inputs.py``'s transposed source, where OpenCV's median raised on the empty
    box): nothing is kept, and no error."""
    model, topo, new, frame, tex, Vc = narrower
    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    r = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE))
    lifted = rim.lifted_positions(tex, frame)
    c = lifted.mean(axis=0)
    inward = lifted - 4.0 * (lifted - c) / np.linalg.norm(lifted - c, axis=1, keepdims=True)
    assert rim.drawn_inside(r.mask, r, topo.faces, lifted, inward).any()
    monkeypatch.setattr(rim, "_box", lambda xy, shape: (0, shape[0], shape[1], shape[0]))
    assert not rim.drawn_inside(r.mask, r, topo.faces, lifted, inward).any()


def _grid_face_anywhere(dx, dy, scale, lx, ly, W, H):
    """A 9x9 grid face drawn at ``scale`` and offset ``(dx, dy)`` into a crop of ``(W, H)``,
    its texture's positions offset ``(lx, ly)``: ``(raster, faces, lifted, drawn)``, None
    where nothing of it lies in the crop."""
    g, faces = _grid(9, (0, 40), (0, 40))
    drawn = g * scale + [dx, dy]
    lifted = g + [lx, ly]
    pixels = WeakPerspective(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(2))
    try:
        r = rasterize(np.c_[drawn, np.zeros(len(g))], faces, pixels, (W, H))
    except MeshError:
        return None
    return r, faces, lifted, drawn


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.floats(-80, 80), st.floats(-80, 80), st.floats(0.5, 2.0), st.floats(-60, 60),
       st.floats(-60, 60), st.integers(8, 90), st.integers(8, 90))
def test_the_rule_never_fails_on_a_face_anywhere(dx, dy, scale, lx, ly, W, H):
    """A grid face drawn anywhere (partly or wholly past a crop of any size, shrunk or grown)
    against its texture's positions anywhere: the rule gives a mask of the crop's shape, only
    on the face's pixels, and no error or warning (``bench_inputs.py`` found a face cut by the
    frame's edge that failed; a face over the whole crop overflowed the depth)."""
    case = _grid_face_anywhere(dx, dy, scale, lx, ly, W, H)
    if case is None:  # nothing of it in the crop
        return
    r, faces, lifted, drawn = case
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow where the face covers the whole crop
        kept = rim.drawn_inside(r.mask, r, faces, lifted, drawn)
    assert kept.shape == (H, W) and kept.dtype == bool
    assert not (kept & ~r.mask).any()


def _drawn_inside_numpy(face_mask, raster, faces, lifted, drawn):
    """:func:`facetransfer.rim.drawn_inside` as numpy expressions (before its kernels, the
    forty-fifth session): the reference its kernels must equal bit for bit."""
    import cv2

    k = max(2, int(round(rim.RIM * np.sqrt(np.count_nonzero(face_mask)))))
    F = np.asarray(faces, np.int64)
    tri_id = np.asarray(raster.tri_id)
    out = np.zeros(tri_id.shape, bool)
    depth = rim.lifted_depth(lifted, F, face_mask.shape, core=rim._core(face_mask, rim.CORE * k))
    at_texture = rim._depth_at(depth, lifted)
    band = at_texture < k
    cand = np.flatnonzero(band[F[:, 0]] | band[F[:, 1]] | band[F[:, 2]])
    if cand.size == 0:
        return out
    corners = F[cand]
    xy = np.asarray(drawn)[corners.ravel()]
    tq = at_texture[corners]
    tp = rim._depth_at(depth, xy).reshape(-1, 3)
    q = (tq[:, 0] + tq[:, 1] + tq[:, 2]) / 3.0
    d = (tp[:, 0] + tp[:, 1] + tp[:, 2]) / 3.0 - q
    flag = (q < k) & (d > rim.MOVED) & (d <= rim.REACH * k)
    if not flag.any():
        return out
    per_tri = np.zeros(len(F) + 1, bool)
    per_tri[cand[flag] + 1] = True
    x0, y0, x1, y1 = rim._box(xy.reshape(-1, 3, 2)[flag].reshape(-1, 2), tri_id.shape)
    if x1 <= x0 or y1 <= y0:
        return out
    kept = per_tri[tri_id[y0:y1, x0:x1] + 1].view(np.uint8)
    out[y0:y1, x0:x1] = cv2.medianBlur(kept, 5).view(bool) & (tri_id[y0:y1, x0:x1] >= 0)
    return out


def test_the_rules_kernels_equal_its_numpy_expressions(narrower):
    """:func:`facetransfer.rim.drawn_inside` (numba kernels) against the numpy expressions it
    replaced, pixel for pixel: the mean face drawn where lifted, shrunk towards its centre by
    0 to 8 px and jittered at random (a third of its vertices 0-3 px), and cut by a crop
    (whose vertices past its edge all lie in the band: ~35,000 corners, more than one
    ``cv2.remap`` reads, which raised before :data:`facetransfer.rim.REMAP_CHUNK`)."""
    model, topo, new, frame, tex, Vc = narrower
    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    r = rasterize(Vc, topo.faces, target.camera(0), (SIZE, SIZE))
    lifted = rim.lifted_positions(tex, frame)
    c = lifted.mean(axis=0)
    unit = (lifted - c) / np.linalg.norm(lifted - c, axis=1, keepdims=True)
    rng = np.random.default_rng(45)
    some = 0
    for step in (0.0, 2.0, 4.0, 8.0):
        drawn = lifted - step * unit
        drawn[rng.random(len(drawn)) < 0.33] += rng.uniform(-3, 3, (1, 2))
        for where in (r, _crop(r, 150, 300)):
            dr = drawn - ((150, 0) if where is not r else (0, 0))
            li = lifted - ((150, 0) if where is not r else (0, 0))
            want = _drawn_inside_numpy(where.mask, where, topo.faces, li, dr)
            np.testing.assert_array_equal(
                rim.drawn_inside(where.mask, where, topo.faces, li, dr), want)
            some += int(want.sum())
    assert some > 1000


def _crop(r, x0: int, x1: int):
    """The raster ``r``'s columns ``x0:x1``."""
    from facetransfer.render import Raster

    return Raster(*(np.ascontiguousarray(a[:, x0:x1]) for a in (r.depth, r.tri_id, r.bary,
                                                                   r.mask)))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.floats(-80, 80), st.floats(-80, 80), st.floats(0.5, 2.0), st.floats(-60, 60),
       st.floats(-60, 60), st.integers(8, 90), st.integers(8, 90))
def test_the_rules_kernels_equal_it_on_a_face_anywhere(dx, dy, scale, lx, ly, W, H):
    """The same as :func:`test_the_rules_kernels_equal_its_numpy_expressions` on
    :func:`test_the_rule_never_fails_on_a_face_anywhere`'s grid faces anywhere."""
    case = _grid_face_anywhere(dx, dy, scale, lx, ly, W, H)
    if case is None:
        return
    r, faces, lifted, drawn = case
    np.testing.assert_array_equal(rim.drawn_inside(r.mask, r, faces, lifted, drawn),
                                  _drawn_inside_numpy(r.mask, r, faces, lifted, drawn))


def test_a_face_mostly_past_the_frames_edge_renders(narrower):
    """The target's face and the new one four fifths past the frame's right edge, the texture
    the frame's own: the vertices past the crop lie in the band (their depth reads 0), more
    than 10,922 triangles (32,767 corners, one ``cv2.remap``'s most, which raised before
    :data:`facetransfer.rim.REMAP_CHUNK`): the frame is rewritten, the same where no face
    is."""
    model, topo, new, frame, tex, Vc = narrower
    target = mean_person_track(model, np.zeros((1, 52), np.float32), size=SIZE, scale=25.0)
    cam = target.camera(0)
    far = WeakPerspective(cam.scale, cam.rotation, cam.translation + [0.8 * SIZE, 0.0])
    edge = FaceTexture(frame, frame_uvs(Vc, far, (SIZE, SIZE)), 0)
    lifted = rim.lifted_positions(edge, frame)
    grid = (lifted - (rim.STEP - 1) / 2.0) / rim.STEP
    assert (grid[:, 0] > SIZE / rim.STEP).mean() > 0.6
    out = rewrite_frame(frame, Vc * [1.0, 0.97, 1.0], far, topo, FrameTextures(edge),
                        blending=BlendOptions("none"))
    assert out.face_mask.any() and not out.face_mask[:, :SIZE // 2].any()
    np.testing.assert_array_equal(out.image[~out.face_mask], frame[~out.face_mask])


def test_median5_is_opencvs_median_of_a_binary_image():
    """:func:`facetransfer.rim._median5` (the 5 x 5 windows' sums of a 0/1 image, 13 or
    more) is ``cv2.medianBlur(kept, 5) != 0`` pixel for pixel: sparse, half and dense random
    images from one pixel to wider than OpenCV's vector width, the border replicated."""
    import cv2

    rng = np.random.default_rng(3)
    for h, w in [(1, 1), (1, 7), (6, 1), (2, 3), (4, 4), (5, 5), (13, 40), (44, 25), (70, 131)]:
        for p in (0.1, 0.5, 0.9):
            kept = (rng.random((h, w)) < p).astype(np.uint8)
            got = rim._median5(kept)
            assert got.dtype == np.uint8 and got.shape == (h, w)
            np.testing.assert_array_equal(got, (cv2.medianBlur(kept, 5) != 0).view(np.uint8))

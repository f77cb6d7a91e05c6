"""A jaw that transfers (issue 13): the chin and jaw textured from a closed-mouth target frame."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer import jaw, region_weights
from facetransfer.arkit import ARKIT_NAMES
from facetransfer.render import rasterize
from facetransfer.rewrite import FrameTextures, rewrite_frame
from facetransfer.rewrite_options import BlendOptions, RewriteOptions
from facetransfer.errors import RewriteError
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology
from facetransfer.track.result import Track

from conftest import jaw_open_track

SIZE = 256
SKIN, SHADOW = (200, 150, 120), (150, 105, 85)  # a shadow 1.3-1.45x darker than SKIN_LIT
HAIR = (40, 30, 25)  # hair over the jaw line in the reference frame: another thing
SKIN_LIT = (220, 165, 132)  # the same skin 10% brighter (another frame's exposure)


@pytest.fixture(scope="module")
def setup(arkit_model):
    return arkit_model, mesh_topology(arkit_model)


def _track(model, jaw_open) -> Track:
    """A frontal track of ``model``'s mean person with the given jawOpen per frame."""
    return jaw_open_track(model, jaw_open, size=SIZE)


def _region_pixels(model, topo, track, i: int, select: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of the triangles ``select`` in frame ``i`` (z-buffered)."""
    V = close_mouth(model.synthesize(track.weights_at(i)), topo)
    r = rasterize(V, topo.faces, track.camera(i), (SIZE, SIZE))
    return np.isin(r.tri_id, np.flatnonzero(select))


def test_region_holds_the_chin_not_the_eyes_nor_the_mouth(setup):
    model, topo = setup
    sel = jaw.jaw_region(model, topo)
    lm = np.asarray(model.landmarks)
    tri_vertices = np.unique(topo.faces[sel])
    assert np.isin(lm[[6, 8, 10]], tri_vertices).all()  # chin and jaw line
    assert not np.isin(lm[[19, 24, 27, 37, 44]], tri_vertices).any()  # brows, bridge, lids
    assert not sel[np.asarray(topo.mouth_faces)].any()  # the mouth shows the source's


def test_a_model_without_arkit_names_keeps_the_per_frame_jaw(quick_model):
    topo = mesh_topology(quick_model)
    assert jaw.jaw_region(quick_model, topo) is None
    frames = [np.zeros((SIZE, SIZE, 3), np.uint8)]
    assert jaw.jaw_texture(frames, None, quick_model, topo) is None


def test_closed_reference_frame():
    class T:  # the fields the frame choice reads
        lost = np.array([False, True, False, False, False, False])
        rotation = np.tile(np.eye(3), (6, 1, 1))
        confidence = np.ones(6)
        blendshape_names = ARKIT_NAMES
        landmarks2d = np.zeros((6, 68, 2))
        source = "t.mp4"
    b = np.zeros((6, 52), np.float32)
    b[:, ARKIT_NAMES.index("jawOpen")] = [0.6, 0.0, 0.05, 0.1, 0.5, 0.02]
    T.blendshapes = b
    T.rotation = T.rotation.copy()
    T.rotation[2] = [[0.8, 0, 0.6], [0, 1, 0], [-0.6, 0, 0.8]]  # turned away
    # frame 1 (closed) is lost; of the closed frames 2 and 5, frame 2 is turned
    assert jaw.closed_jaw_frame(T) == 5
    assert jaw.closed_jaw_frame(T, 5) == 2  # among the first five only
    # without activations: the landmarks' lip gap
    T.blendshapes = None
    L = np.zeros((6, 68, 2))
    L[:, 36], L[:, 45] = (0, 0), (10, 0)
    L[:, 66, 1] = [4, 0, 3, 0.1, 2, 1]
    T.landmarks2d = L
    np.testing.assert_allclose(jaw.mouth_closure(T), [0.4, 0, 0.3, 0.01, 0.2, 0.1])
    assert jaw.closed_jaw_frame(T) == 3
    T.lost = np.ones(6, bool)
    with pytest.raises(RewriteError, match="lost in every frame"):
        jaw.closed_jaw_frame(T)


def test_the_targets_open_mouth_shading_does_not_show_on_a_closed_jaw(setup):
    """Synthetic truth: the target opens its jaw in frame 1, where the lower part of its jaw
    region is in shadow and the exposure is 10% brighter; frame 0 has the mouth closed and no
    shadow. A closed new jaw rendered into frame 1 takes the shadow from frame 1's texture
    (before); with the jaw texture (from frame 0) it shows the skin at frame 1's exposure
    (the gain is measured around the region, where the shadow is not)."""
    model, topo = setup
    target = _track(model, [0.0, 1.0])
    sel = jaw.jaw_region(model, topo)
    opened = _region_pixels(model, topo, target, 1, sel)
    rows = np.flatnonzero(opened.any(axis=1))
    band = opened & (np.arange(SIZE)[:, None] > np.quantile(rows, 0.6))
    assert 0.15 < band.sum() / opened.sum() < 0.45
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8),
              np.full((SIZE, SIZE, 3), SKIN_LIT, np.uint8)]
    frames[1][band] = SHADOW
    tex = jaw.jaw_texture(frames, target, model, topo)
    assert tex.frame == 0 and tex.select.sum() == sel.sum()
    cam = target.camera(1)
    face_tex = FaceTexture(frames[1], frame_uvs(close_mouth(model.synthesize(
        target.weights_at(1)), topo), cam, (SIZE, SIZE)), 1)
    V = model.synthesize(_track(model, [0.0]).weights_at(0))  # the new jaw: closed
    region = _region_pixels(model, topo, _track(model, [0.0]), 0, sel)
    inner = region & np.roll(region, 2, 0) & np.roll(region, -2, 0) & \
        np.roll(region, 2, 1) & np.roll(region, -2, 1)
    assert inner.sum() > 100

    def share(img, colour):
        return np.mean(np.all(np.abs(img[inner].astype(int) - colour) < 8, axis=-1))

    paste = BlendOptions("none", erode=0)
    before = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex), blending=paste)
    after = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex, jaw=tex),
                          blending=paste)
    assert share(before.image, SHADOW) > 0.15  # the target's shading on the closed jaw
    assert share(after.image, SHADOW) < 0.01  # (the region's feathered outline aside)
    assert share(after.image, SKIN_LIT) > 0.95
    # at half strength on every vertex (JawTexture.at: where the target's own skin moved
    # half-way from the reference frame's) the region is the even mix of the two, to rounding
    halved = dataclasses.replace(tex, alpha=np.full(len(tex.uvs), 0.5, np.float32))
    half = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex, jaw=halved),
                         blending=paste)
    mid = (before.image[inner].astype(float) + after.image[inner]) / 2
    assert np.abs(half.image[inner] - mid).max() <= 1.0
    # only the jaw region changed: elsewhere the same frame
    np.testing.assert_array_equal(after.image[~region], before.image[~region])
    # hair over part of the jaw in the reference frame (5x darker than the skin the current
    # frame shows there) is not pasted: those pixels keep the current frame's texture
    hair = [f.copy() for f in frames]
    hair[0][band] = HAIR
    tex_h = jaw.jaw_texture(hair, target, model, topo)
    plain = [np.full((SIZE, SIZE, 3), SKIN_LIT, np.uint8)] * 2
    face_h = FaceTexture(plain[1], face_tex.uvs, 1)
    out = rewrite_frame(plain[1], V, cam, topo, FrameTextures(face_h, jaw=tex_h),
                        blending=BlendOptions("none", erode=0))
    assert share(out.image, HAIR) < 0.01 and share(out.image, SKIN_LIT) > 0.95
    # the hair's soft edge (2 px a quarter hair: 1.3x darker than the skin, not unlike enough
    # by itself) goes with the hair: the current frame's skin, not a grey outline
    import cv2

    edge = cv2.dilate(band.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool) & ~band
    soft = tuple(int(0.75 * a + 0.25 * b) for a, b in zip(SKIN_LIT, HAIR))
    hair[0][edge] = soft
    tex_s = jaw.jaw_texture(hair, target, model, topo)
    out = rewrite_frame(plain[1], V, cam, topo, FrameTextures(face_h, jaw=tex_s),
                        blending=BlendOptions("none", erode=0))
    shown = inner & edge
    assert shown.sum() > 20
    assert np.mean(np.all(np.abs(out.image[shown].astype(int) - SKIN_LIT) < 8, axis=-1)) > 0.9


def test_strength_follows_the_targets_own_skin_away_from_the_reference_frame(setup):
    """jaw_strengths on the mean person, whose region moves with jawOpen alone: a vertex's
    distance from the reference frame is the activation times that vertex's share of the
    jawOpen shape (its displacement over the shape's RMS over the region), so its strength is
    JAW_BLEND's smoothstep of that; 0 everywhere in the reference frame and near it (no
    paste: JawTexture.at gives None and the frame keeps its own texture); at full opening the
    chin takes the reference frame and the skin jawOpen hardly moves keeps its own."""
    model, topo = setup
    opening = np.array([0.0, 0.01, 0.3, 1.0])
    target = _track(model, opening)
    sel = jaw.jaw_region(model, topo)
    verts, s = jaw.jaw_strengths(model, target, topo, sel, 0)
    full = model.synthesize(target.weights_at(3))[verts] - model.synthesize(
        target.weights_at(0))[verts]
    share = np.linalg.norm(full, axis=1) / np.sqrt((full ** 2).sum(1).mean())
    lo, hi = jaw.JAW_BLEND
    t = np.clip((opening[:, None] * share[None] - lo) / (hi - lo), 0, 1)
    np.testing.assert_allclose(s, t * t * (3 - 2 * t), atol=1e-5)
    assert s.shape == (len(opening), verts.size) and s.dtype == np.float32
    assert s[0].max() == 0 and s[1].max() == 0
    assert 0.3 < np.mean(s[3] == 1) < 1 and np.mean(s[3] == 0) > 0.02  # chin; by the ear
    assert np.all(s[3] >= s[2])
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8)] * len(opening)
    tex = jaw.jaw_texture(frames, target, model, topo)
    assert tex.frame == 0
    np.testing.assert_array_equal(tex.verts, verts)
    assert tex.at(0) is None and tex.at(1) is None
    a = tex.at(3).alpha
    assert a.shape == (len(tex.uvs),)
    np.testing.assert_array_equal(a[verts], tex.strengths[3])
    assert dataclasses.replace(tex, strengths=None).at(0).alpha is None  # fully opaque


def _closed_jaw_in(model, topo, frame1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed new jaw rendered into ``frame1`` (frame 1 of a target opening its jaw, frame 0
    of plain SKIN the reference): ``(image, inner)``, the result and the region's pixels at
    least 3 px inside it."""
    target = _track(model, [0.0, 1.0])
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8), frame1]
    tex = jaw.jaw_texture(frames, target, model, topo)
    assert tex.frame == 0 and tex.at(1).alpha.max() == 1.0
    cam = target.camera(1)
    face_tex = FaceTexture(frame1, frame_uvs(close_mouth(model.synthesize(
        target.weights_at(1)), topo), cam, (SIZE, SIZE)), 1)
    closed = _track(model, [0.0])
    region = _region_pixels(model, topo, closed, 0, jaw.jaw_region(model, topo))
    inner = region & np.roll(region, 3, 0) & np.roll(region, -3, 0) & \
        np.roll(region, 3, 1) & np.roll(region, -3, 1)
    assert inner.sum() > 100
    out = rewrite_frame(frame1, model.synthesize(closed.weights_at(0)), cam, topo,
                        FrameTextures(face_tex, jaw=tex.at(1)),
                        blending=BlendOptions("none", erode=0))
    return out.image, inner


def test_another_colour_around_the_region_does_not_tint_it(setup):
    """One gain for the three channels (the geometric mean of the ring's), and a hue field
    that leaves out what is unlike skin: a current frame whose ring around the region shows
    another thing (here lipstick red; in ``make demo`` a smile's blush, lips or hair) leaves
    the pasted skin's hue the reference frame's (a per-channel gain reddened it)."""
    model, topo = setup
    target = _track(model, [0.0, 1.0])
    red = np.full((SIZE, SIZE, 3), (200, 60, 60), np.uint8)
    red[_region_pixels(model, topo, target, 1, jaw.jaw_region(model, topo))] = SKIN
    img, inner = _closed_jaw_in(model, topo, red)
    px = img[inner].astype(float)
    np.testing.assert_allclose(np.median(px[:, 1] / px[:, 0]), SKIN[1] / SKIN[0], atol=0.02)
    np.testing.assert_allclose(np.median(px[:, 2] / px[:, 0]), SKIN[2] / SKIN[0], atol=0.02)


def test_the_region_takes_the_current_frames_hue_of_the_same_skin(setup):
    """Where the current frame shows the same skin in another hue (here 13 % greener all
    over: another light, another head pose; the orange cheek of ``make demo``'s turned
    open-mouth frame), the region takes that hue (JAW_HUE_SIGMA), at the brightness of the
    one gain."""
    model, topo = setup
    tint = (200, 170, 120)
    img, inner = _closed_jaw_in(model, topo, np.full((SIZE, SIZE, 3), tint, np.uint8))
    px = img[inner].astype(float)
    np.testing.assert_allclose(np.median(px[:, 1] / px[:, 0]), tint[1] / tint[0], atol=0.02)
    np.testing.assert_allclose(np.median(px[:, 2] / px[:, 0]), tint[2] / tint[0], atol=0.02)
    grey = np.exp(np.log(px + 1).mean(axis=1)) - 1
    np.testing.assert_allclose(np.median(grey), np.prod(tint) ** (1 / 3), rtol=0.03)


def test_jaw_option():
    assert RewriteOptions().jaw == "closed"
    assert RewriteOptions(jaw="frame").jaw == "frame"
    with pytest.raises(RewriteError, match="jaw must be one of closed, frame"):
        RewriteOptions(jaw="open")


def test_what_the_reference_frame_sees_edge_on_keeps_the_current_frames_texture(setup):
    """region_weights.facing_weights: on the mean person seen from the front, the chin's front
    (its normal toward the camera) weighs 1 and the skin under the chin (seen edge-on or from
    behind) 0; turning the head down brings the skin under the chin into view; the strengths of a
    jaw texture are jaw_strengths times these."""
    model, topo = setup
    target = _track(model, [0.0, 1.0])
    sel = jaw.jaw_region(model, topo)
    V = close_mouth(model.synthesize(target.weights_at(0)), topo)
    verts, s = jaw.jaw_strengths(model, target, topo, sel, 0)
    w = region_weights.facing_weights(V, topo.faces, np.eye(3), verts)
    assert w.dtype == np.float32 and w.shape == verts.shape
    # against trimesh's vertex normals (another implementation): the smoothstep of their
    # component toward the camera (+z: depth grows toward the camera)
    import trimesh

    n = trimesh.Trimesh(V, topo.faces, process=False).vertex_normals[verts]
    lo, hi = region_weights.FACING
    t = np.clip((n[:, 2] - lo) / (hi - lo), 0, 1)
    assert np.mean(np.abs(w - t * t * (3 - 2 * t)) < 0.05) > 0.95
    front, under = n[:, 2] > 0.8, n[:, 1] < -0.8  # the chin's front; under the chin
    assert front.sum() > 50 and under.sum() > 20
    assert np.all(w[front] == 1) and w[under].mean() < 0.3
    c, si = np.cos(-0.5), np.sin(-0.5)  # turned about x: the camera sees under the chin
    turned = region_weights.facing_weights(
        V, topo.faces, np.array([[1, 0, 0], [0, c, -si], [0, si, c]]), verts)
    assert turned[under].mean() > w[under].mean() + 0.4
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8)] * 2
    tex = jaw.jaw_texture(frames, target, model, topo)
    np.testing.assert_allclose(tex.strengths, s * w[None], atol=1e-6)


def test_only_the_skin_that_moved_takes_the_reference_frame(setup):
    """Per vertex (JawTexture.at's alpha, interpolated over the pixels): rendered into a frame
    whose skin shows fine detail (a checker) over a plain reference frame, the pixels whose
    vertices the target's own opening did not move (alpha 0) keep the frame's texture to the
    level, and those it moved fully (alpha 1) take the reference frame's plain skin."""
    from facetransfer.render import interpolate_vertex_values

    model, topo = setup
    target = _track(model, [0.0, 0.3])
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    checker = np.where(((yy // 2) + (xx // 2)) % 2 == 0, 15, -15)[..., None]
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8),
              np.clip(np.array(SKIN) + checker, 0, 255).astype(np.uint8)]
    tex = jaw.jaw_texture(frames, target, model, topo)
    at = tex.at(1)
    assert at is not None and at.alpha.min() == 0 and at.alpha.max() == 1
    cam = target.camera(1)
    V = model.synthesize(target.weights_at(1))  # the new face: the target's own, here
    Vc = close_mouth(V, topo)
    face_tex = FaceTexture(frames[1], frame_uvs(Vc, cam, (SIZE, SIZE)), 1)
    paste = BlendOptions("none", erode=0)
    before = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex), blending=paste)
    after = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex, jaw=at),
                          blending=paste)
    r = rasterize(Vc, topo.faces, cam, (SIZE, SIZE))
    alpha = interpolate_vertex_values(r, topo.faces, at.alpha)
    region = _region_pixels(model, topo, target, 1, tex.select)
    inner = region.copy()
    for ax in (0, 1):
        for d in (-5, 5):
            inner &= np.roll(region, d, ax)
    still, moved = inner & (alpha == 0), inner & (alpha == 1)
    assert still.sum() > 30 and moved.sum() > 200
    diff = np.abs(after.image.astype(int) - before.image.astype(int)).max(axis=-1)
    assert diff[still].max() <= 1
    # the checker (std 15 levels per channel) gone: what is left is the gain's smooth plane
    g_before, g_after = before.image[..., 1][moved], after.image[..., 1][moved]
    assert np.std(g_before) > 12 and np.std(g_after) < 0.25 * np.std(g_before)


def test_paint_jaw_alone_is_what_the_rewrite_paints(setup):
    """The public :func:`facetransfer.jaw.paint_jaw` (the region on its own, its own shading
    pass) gives the pixels the rewrite's one-pass shading gives (``rewrite._shade_frame`` with
    the jaw texture only)."""
    from facetransfer.render import shade_layers
    from facetransfer.rewrite import _shade_frame

    model, topo = setup
    target = _track(model, [0.0, 1.0])
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8),
              np.full((SIZE, SIZE, 3), SKIN_LIT, np.uint8)]
    frames[1][SIZE // 2:] = SHADOW
    tex = jaw.jaw_texture(frames, target, model, topo).at(1)
    cam = target.camera(1)
    face_tex = FaceTexture(frames[1], frame_uvs(close_mouth(model.synthesize(
        target.weights_at(1)), topo), cam, (SIZE, SIZE)), 1)
    V = close_mouth(model.synthesize(_track(model, [0.2]).weights_at(0)), topo)
    r = rasterize(V, topo.faces, cam, (SIZE, SIZE))
    (face_img,), labels = shade_layers(r, topo.faces, [(face_tex.uvs, face_tex.image)],
                                       np.ones(len(topo.faces), np.uint8))
    alone = jaw.paint_jaw(r, topo.faces, face_img, labels != 0, tex)
    together = _shade_frame(r, V, topo, FrameTextures(face_tex, jaw=tex))[0]
    assert np.array_equal(alone, together) and not np.array_equal(alone, face_img)

"""A jaw that transfers (issue 13): the chin and jaw textured from a closed-mouth target frame."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer import jaw
from facetransfer.arkit import ARKIT_NAMES
from facetransfer.render import rasterize
from facetransfer.rewrite import rewrite_frame
from facetransfer.rewrite_options import RewriteOptions
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

    before = rewrite_frame(frames[1], V, cam, topo, face_tex, blend="none", erode=0)
    after = rewrite_frame(frames[1], V, cam, topo, face_tex, jaw_texture=tex, blend="none",
                          erode=0)
    assert share(before.image, SHADOW) > 0.15  # the target's shading on the closed jaw
    assert share(after.image, SHADOW) < 0.01  # (the region's feathered outline aside)
    assert share(after.image, SKIN_LIT) > 0.95
    # at half strength (JawTexture.at: a frame whose own jaw is half-way from the reference's)
    # the region is the even mix of the two, to rounding
    half = rewrite_frame(frames[1], V, cam, topo, face_tex, blend="none", erode=0,
                         jaw_texture=dataclasses.replace(tex, strength=0.5))
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
    out = rewrite_frame(plain[1], V, cam, topo, face_h, jaw_texture=tex_h, blend="none", erode=0)
    assert share(out.image, HAIR) < 0.01 and share(out.image, SKIN_LIT) > 0.95
    # the hair's soft edge (2 px a quarter hair: 1.3x darker than the skin, not unlike enough
    # by itself) goes with the hair: the current frame's skin, not a grey outline
    import cv2

    edge = cv2.dilate(band.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool) & ~band
    soft = tuple(int(0.75 * a + 0.25 * b) for a, b in zip(SKIN_LIT, HAIR))
    hair[0][edge] = soft
    tex_s = jaw.jaw_texture(hair, target, model, topo)
    out = rewrite_frame(plain[1], V, cam, topo, face_h, jaw_texture=tex_s, blend="none", erode=0)
    shown = inner & edge
    assert shown.sum() > 20
    assert np.mean(np.all(np.abs(out.image[shown].astype(int) - SKIN_LIT) < 8, axis=-1)) > 0.9


def test_strength_follows_the_targets_own_jaw_away_from_the_reference_frame(setup):
    """jaw_strength on the mean person, whose region moves with jawOpen alone: the distance is
    the activation itself (relative to the jawOpen shape), so the strength is JAW_BLEND's
    smoothstep of it; 0 in the reference frame and near it (no paste: JawTexture.at gives
    None and the frame keeps its own texture), 1 from the ramp's end."""
    model, topo = setup
    opening = np.array([0.0, 0.03, 0.1, 0.13, 0.2, 1.0])
    target = _track(model, opening)
    sel = jaw.jaw_region(model, topo)
    s = jaw.jaw_strength(model, target, topo, sel, 0)
    lo, hi = jaw.JAW_BLEND
    t = np.clip((opening - lo) / (hi - lo), 0, 1)
    np.testing.assert_allclose(s, t * t * (3 - 2 * t), atol=1e-9)
    assert s[0] == s[1] == 0 and 0 < s[2] < s[3] < 1 and s[4] == s[5] == 1
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8)] * len(opening)
    tex = jaw.jaw_texture(frames, target, model, topo)
    assert tex.frame == 0
    np.testing.assert_array_equal(tex.strengths, s)
    assert tex.at(0) is None and tex.at(1) is None
    assert tex.at(2).strength == s[2] and tex.at(5).strength == 1.0
    assert dataclasses.replace(tex, strengths=None).at(0).strength == 1.0


def test_the_region_keeps_the_reference_frames_hue(setup):
    """The region is scaled by one gain for its three channels (the geometric mean of the
    ring's): a current frame whose skin around the region is tinted (here 13 % greener: in
    ``make demo`` a smile's blush, lips or hair in the ring) brightens the pasted skin without
    tinting it."""
    model, topo = setup
    target = _track(model, [0.0, 1.0])
    tint = (200, 170, 120)
    frames = [np.full((SIZE, SIZE, 3), SKIN, np.uint8), np.full((SIZE, SIZE, 3), tint, np.uint8)]
    tex = jaw.jaw_texture(frames, target, model, topo)
    assert tex.frame == 0 and tex.at(1).strength == 1.0
    cam = target.camera(1)
    face_tex = FaceTexture(frames[1], frame_uvs(close_mouth(model.synthesize(
        target.weights_at(1)), topo), cam, (SIZE, SIZE)), 1)
    closed = _track(model, [0.0])
    region = _region_pixels(model, topo, closed, 0, jaw.jaw_region(model, topo))
    inner = region & np.roll(region, 3, 0) & np.roll(region, -3, 0) & \
        np.roll(region, 3, 1) & np.roll(region, -3, 1)
    assert inner.sum() > 100
    out = rewrite_frame(frames[1], model.synthesize(closed.weights_at(0)), cam, topo, face_tex,
                        jaw_texture=tex.at(1), blend="none", erode=0)
    px = out.image[inner].astype(float)
    np.testing.assert_allclose(np.median(px[:, 1] / px[:, 0]), SKIN[1] / SKIN[0], atol=0.02)
    np.testing.assert_allclose(np.median(px[:, 0]), SKIN[0] * (170 / 150) ** (1 / 3), atol=3)


def test_jaw_option():
    assert RewriteOptions().jaw == "closed"
    assert RewriteOptions(jaw="frame").jaw == "frame"
    with pytest.raises(RewriteError, match="jaw must be one of closed, frame"):
        RewriteOptions(jaw="open")

"""A jaw that transfers (issue 13): the chin and jaw textured from a closed-mouth target frame."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import jaw
from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
from facetransfer.render import rasterize
from facetransfer.rewrite import rewrite_frame
from facetransfer.rewrite_options import RewriteOptions
from facetransfer.errors import RewriteError
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology
from facetransfer.track.result import Track

SIZE = 256
SKIN, SHADOW = (200, 150, 120), (70, 30, 30)
SKIN_LIT = (220, 165, 132)  # the same skin 10% brighter (another frame's exposure)


@pytest.fixture(scope="module")
def setup(arkit_model):
    return arkit_model, mesh_topology(arkit_model)


def _track(model, jaw_open) -> Track:
    """A frontal track of ``model``'s mean person with the given jawOpen per frame."""
    a = np.zeros((len(jaw_open), 52), np.float32)
    a[:, ARKIT_NAMES.index("jawOpen")] = jaw_open
    F = a.shape[0]
    k = model.mode_index("identity")
    return Track(fps=25.0, frame_size=(SIZE, SIZE), rotation=np.tile(np.eye(3), (F, 1, 1)),
                 scale=np.full(F, 20.0), translation=np.tile([SIZE / 2, SIZE / 2 - 40.0], (F, 1)),
                 weights={"identity": np.tile(model.weight_mean(k), (F, 1)),
                          "expression": activations_to_weights(model, a)},
                 landmarks2d=np.zeros((F, 68, 2)), confidence=np.ones(F),
                 lost=np.zeros(F, bool), model_hash=model.content_hash,
                 mode_names=model.mode_names, source="synthetic.mp4",
                 blendshapes=a, blendshape_names=ARKIT_NAMES)


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


def test_reference_frames_span_the_openings_and_face_the_camera():
    class T:  # the fields the frame choice reads
        lost = np.array([False, True, False, False, False, False, False, False])
        rotation = np.tile(np.eye(3), (8, 1, 1))
        confidence = np.ones(8)
        source = "t.mp4"
    T.rotation[2] = [[0.8, 0, 0.6], [0, 1, 0], [-0.6, 0, 0.8]]  # turned away
    opening = np.array([0.6, 0.0, 0.05, 0.1, 0.5, 0.02, 0.9, 0.51])
    # by opening: 5 2 3 | 4 7 | 0 6 (frame 1 is lost); frame 2 is turned, the rest ties (the
    # first wins)
    np.testing.assert_array_equal(jaw.jaw_frames(T, opening, k=3), [5, 4, 0])
    np.testing.assert_array_equal(jaw.jaw_frames(T, opening, 6, k=3), [5, 3, 0])  # 5 2 | 3 4 | 0
    # one share each; frame 7 lies within SAME_OPENING of frame 4 and counts once
    assert jaw.jaw_frames(T, opening, k=7).tolist() == [5, 2, 3, 4, 0, 6]
    T.lost = np.ones(8, bool)
    with pytest.raises(RewriteError, match="lost in every frame"):
        jaw.jaw_frames(T, opening)


def test_mix_cross_fades_between_the_bracketing_openings():
    tex = jaw.JawTexture((None,) * 3, np.zeros((3, 1, 2)), np.array([0.0, 0.4, 0.8]),
                         np.arange(3), np.zeros(1, bool))
    assert tex.mix(-0.1) == [(0, 1.0)] and tex.mix(0.9) == [(2, 1.0)]
    assert tex.mix(0.4) in ([(1, 1.0)], [(0, 0.0), (1, 1.0)], [(1, 1.0), (2, 0.0)])
    (k0, w0), (k1, w1) = tex.mix(0.6)
    assert (k0, k1) == (1, 2) and w0 == pytest.approx(0.5) and w1 == pytest.approx(0.5)
    (_, w0), (_, w1) = tex.mix(0.5)  # a smoothstep: nearer the closer frame than linear
    assert w0 + w1 == pytest.approx(1.0) and w0 > 0.75


def test_jaw_opening_reads_the_activation(setup):
    model, _ = setup
    np.testing.assert_allclose(jaw.jaw_opening(model, _track(model, [0.0, 0.3, 1.0])),
                               [0.0, 0.3, 1.0], atol=1e-6)


def test_the_targets_open_mouth_shading_does_not_show_on_a_closed_jaw(setup):
    """Synthetic truth: the target opens its jaw in frame 1, where the lower part of its jaw
    region is in shadow and the exposure is 10% brighter; frame 0 has the mouth closed and no
    shadow. A closed new jaw rendered into frame 1 takes the shadow from frame 1's texture
    (before); with the jaw texture it shows frame 0's skin at frame 1's exposure (the gain is
    measured around the region, where the shadow is not). An open new jaw shows frame 1's
    shading, the target's own at that opening."""
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
    assert tex.frames.tolist() == [0, 1] and tex.select.sum() == sel.sum()
    np.testing.assert_allclose(tex.openings, [0.0, 1.0], atol=1e-6)
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
    after = rewrite_frame(frames[1], V, cam, topo, face_tex, jaw_texture=tex, jaw_open=0.0,
                          blend="none", erode=0)
    assert share(before.image, SHADOW) > 0.15  # the target's shading on the closed jaw
    assert share(after.image, SHADOW) < 0.01  # (the region's feathered outline aside)
    assert share(after.image, SKIN_LIT) > 0.95
    # only the jaw region changed: elsewhere the same frame
    np.testing.assert_array_equal(after.image[~region], before.image[~region])
    # the new jaw as open as the target's in frame 1: its own texture there, shadow and all
    V1 = model.synthesize(target.weights_at(1))
    same = rewrite_frame(frames[1], V1, cam, topo, face_tex, blend="none", erode=0)
    matched = rewrite_frame(frames[1], V1, cam, topo, face_tex, jaw_texture=tex, jaw_open=1.0,
                            blend="none", erode=0)
    assert np.abs(matched.image.astype(int) - same.image).max() <= 2


def test_jaw_option():
    assert RewriteOptions().jaw == "matched"
    assert RewriteOptions(jaw="frame").jaw == "frame"
    with pytest.raises(RewriteError, match="jaw must be one of matched, frame"):
        RewriteOptions(jaw="open")

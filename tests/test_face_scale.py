"""The rewrite's pixel settings grown with the face (``facetransfer.face_scale``): a face 2.5
times larger is rewritten as the smaller one, its seams as wide for the face; the data folder's
faces (eyes up to FACE_SPAN apart) as before."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from facetransfer import face_scale, jaw, patch
from facetransfer.render import WeakPerspective, rasterize
from facetransfer.rewrite import FrameTextures, rewrite_frame
from facetransfer.rewrite_options import BlendOptions
from facetransfer.texture.face import FaceTexture, frame_uvs
from facetransfer.topology import close_mouth, mesh_topology

from conftest import jaw_open_track, mean_eye_span, record_scales

SKIN = (120, 90, 72)
LIT = tuple(int(1.6 * c) for c in SKIN)  # the closed frame's skin: beyond the gain's clip


@pytest.fixture(scope="module")
def setup(arkit_model):
    return arkit_model, mesh_topology(arkit_model)


def _jaw_paste(model, topo, px_per_cm: float, blending: BlendOptions | None = None):
    """The mean person's closed jaw rewritten into frame 1 of a clip whose frame 0 (mouth
    closed: the jaw region's reference frame) shows its skin 1.6 times brighter, beyond
    :data:`facetransfer.patch.GAIN_RANGE`: pasted, the region keeps a step of 1.12 at its
    outline, faded over the jaw's feather. At ``px_per_cm`` pixels per cm in a frame of 23 cm
    (the face's place in it the same at every size). Returns ``(image, region, face)``: the
    result, the region's pixels and the face's (H, W) bool. ``blending``: the rewrite's blend
    (default: a hard paste, no erosion)."""
    size = int(round(23 * px_per_cm))
    target = jaw_open_track(model, [0.0, 1.0], size=size, scale=px_per_cm)
    # the face's place in the frame as a share of the frame (conftest's 40 px: at 20 px per cm)
    c = (size - 1) / 2.0
    target = dataclasses.replace(target, translation=np.tile([c, c - 2.0 * px_per_cm], (2, 1)))
    frames = [np.full((size, size, 3), LIT, np.uint8), np.full((size, size, 3), SKIN, np.uint8)]
    tex = jaw.jaw_texture(frames, target, model, topo)
    cam = target.camera(1)
    face_tex = FaceTexture(frames[1], frame_uvs(close_mouth(model.synthesize(
        target.weights_at(1)), topo), cam, (size, size)), 1)
    V = close_mouth(model.synthesize(target.weights_at(0)), topo)   # the new jaw: closed
    out = rewrite_frame(frames[1], V, cam, topo, FrameTextures(face_tex, jaw=tex),
                        blending=BlendOptions("none", erode=0) if blending is None
                        else blending)
    r = rasterize(V, topo.faces, cam, (size, size))
    region = np.isin(r.tri_id, np.flatnonzero(tex.select))
    return out.image, region, r.tri_id >= 0


def test_a_larger_face_shows_the_jaw_regions_edge_as_the_smaller_one(setup):
    """The jaw region's paste is faded over a feather that grows with the face
    (``face_scale``): the same face at 2.5 times the pixels (eyes ~320 px apart), brought
    back to the smaller one's pixels, shows the region's outline as the smaller face does.
    Before, a 4-px feather at every size made the step across the outline 2.5 times as
    steep for the face (the step across the cheek on a 1280x1280 clip: BENCHMARKS.md,
    "Fifty-fourth session (helper large54)")."""
    model, topo = setup
    small, region, face = _jaw_paste(model, topo, 20.0)
    large, _, _ = _jaw_paste(model, topo, 50.0)
    back = cv2.resize(large, small.shape[1::-1], interpolation=cv2.INTER_AREA)
    grey = (lambda img: img.astype(np.float64).mean(axis=-1))
    # the region's outline inside the face, away from the face's own edge: 6 px either side
    inside = cv2.distanceTransform(region.view(np.uint8), cv2.DIST_L2, 5)
    outside = cv2.distanceTransform((~region).view(np.uint8), cv2.DIST_L2, 5)
    deep = cv2.erode(face.view(np.uint8), np.ones((17, 17), np.uint8)).view(bool)
    band = deep & (((inside > 0) & (inside <= 6)) | ((outside > 0) & (outside <= 6)))
    assert band.sum() > 300
    # the step is there at both sizes: the region 1.12 times the skin deep inside it
    core = deep & (inside > 8)
    assert np.median(grey(small)[core]) == pytest.approx(1.12 * np.mean(SKIN), abs=3)
    assert np.median(grey(back)[core]) == pytest.approx(1.12 * np.mean(SKIN), abs=3)
    err = np.abs(grey(back) - grey(small))[band]
    assert np.percentile(err, 95) < 3.0        # before: 6 levels (the step ~13 levels)
    # and the steepest rise across it, in levels per pixel of the smaller face
    gy, gx = np.gradient(grey(back))
    sy, sx = np.gradient(grey(small))
    assert np.percentile(np.hypot(gx, gy)[band], 99) < 1.25 * np.percentile(
        np.hypot(sx, sy)[band], 99)


def test_the_settings_grow_with_the_face_beyond_the_clips_they_were_chosen_on():
    """Up to :data:`facetransfer.face_scale.FACE_SPAN` (every data-folder clip's frames:
    their renders as before, bit for bit) the factor is 1; beyond, proportional; 1 where the
    span is unknown."""
    assert face_scale.face_scale(60.0) == face_scale.face_scale(face_scale.FACE_SPAN) == 1.0
    assert face_scale.face_scale(2.5 * face_scale.FACE_SPAN) == pytest.approx(2.5)
    assert face_scale.face_scale(float("nan")) == 1.0
    opts = BlendOptions(feather=2.0, erode=2, mouth_feather=3.0)
    assert opts.scaled(1.0) is opts
    big = opts.scaled(2.5)
    assert (big.feather, big.erode, big.mouth_feather) == (5.0, 5, 7.5)
    assert patch.ring_inset(1.0) == patch.RING_INSET and patch.ring_inset(2.5) == 5


def test_the_data_folders_faces_keep_their_settings_and_the_factor_rises_without_a_step():
    """Every frame of the data folder's clips as a target, their own tracks and their new ones
    with another clip's expressions (:func:`facetransfer.face_scale.face_span`, measured in the
    fifty-fifth session): ``driving_d6`` 102.1-122.2 px, ``driving_d9`` 106.1-113.4,
    ``WDA_KatieHill_000`` 107.9-114.9, ``face_2`` 129.6-137.0; all rewritten with the settings
    they were chosen with. Beyond :data:`~facetransfer.face_scale.FACE_SPAN` the factor rises
    from 1 without a step (the guarantee of the removed ``patch.shading_sigma`` tests, whose
    threshold was first set below ``face_2``'s frames); a span that is no size (infinite,
    zero, negative) keeps the settings."""
    for span in (102.1, 122.2, 129.6, 137.0):
        assert face_scale.face_scale(span) == 1.0
    edge = face_scale.FACE_SPAN
    assert face_scale.face_scale(edge) == 1.0
    assert 1.0 < face_scale.face_scale(edge + 0.01) < 1.0 + 1e-4
    for span in (float("inf"), float("-inf"), 0.0, -300.0):
        assert face_scale.face_scale(span) == 1.0


def test_a_face_at_the_threshold_is_rewritten_without_a_step(setup, monkeypatch):
    """A face at :data:`~facetransfer.face_scale.FACE_SPAN` is rewritten with the factor 1;
    just beyond, with 1 + 1e-6: every setting scaled (``BlendOptions.scaled`` no longer the
    options themselves, the feathers' windows one pixel wider, the whole pixels rounded as at
    1). The same frame rewritten both ways (the jaw region pasted, the membrane blend) differs
    by at most a level at a few pixels (here at none): no step where the settings start to
    grow. (An erosion rounded up instead, ``ceil(2 (1 + 1e-6))``, changes 96,000 pixels by up
    to 5 levels. The mesh itself moved by 1e-6 of its size can flip a pixel's triangle, 4
    levels at 37 pixels here, with the factor held at 1 too: the raster's, not the
    threshold's, so the test holds the mesh.)"""
    from facetransfer import rewrite

    model, topo = setup
    probe = jaw_open_track(model, [0.0], scale=1.0)
    V = close_mouth(model.synthesize(probe.weights_at(0)), topo)
    ppc = face_scale.FACE_SPAN / face_scale.face_span(V, probe.camera(0), topo.eye_loops)
    out = {}
    for factor in (1.0, 1.0 + 1e-6):
        monkeypatch.setattr(rewrite, "face_scale", lambda span, f=factor: f)
        out[factor] = _jaw_paste(model, topo, ppc, BlendOptions())[0].astype(int)
    step = np.abs(out[1.0 + 1e-6] - out[1.0])
    assert step.max() <= 1
    assert np.count_nonzero(step) <= 20


def test_the_face_span_is_the_eye_holes_distance_at_the_cameras_scale(setup):
    """Pixels between the centres of the two eye holes: the camera's scale times their
    distance in the model (a turned head's face is as large), or, for another camera, their
    projections' distance; NaN without two eye holes."""
    model, topo = setup
    V = model.synthesize(model.default_weights())
    c = [V[np.asarray(loop)].mean(axis=0) for loop in topo.eye_loops]
    d = float(np.linalg.norm(c[0] - c[1]))
    assert 5.5 < d < 7.0                                  # cm: a person's eyes
    R = np.eye(3)
    assert face_scale.face_span(V, WeakPerspective(20.0, R, np.zeros(2)), topo.eye_loops) \
        == pytest.approx(20.0 * d)
    turn = np.array([[np.cos(0.5), 0, np.sin(0.5)], [0, 1, 0], [-np.sin(0.5), 0, np.cos(0.5)]])
    assert face_scale.face_span(V, WeakPerspective(20.0, turn, np.zeros(2)), topo.eye_loops) \
        == pytest.approx(20.0 * d)

    class Flat:            # another camera: the projection, here an orthographic one
        def project(self, X):
            return 10.0 * np.asarray(X)[:, :2]

    assert face_scale.face_span(V, Flat(), topo.eye_loops) == pytest.approx(
        10.0 * np.hypot(*(c[0][:2] - c[1][:2])))
    assert np.isnan(face_scale.face_span(V, Flat(), ()))
    # a mesh that is no face (a NaN vertex: WeakPerspective itself refuses a scale that is
    # not > 0) gives no size, and the settings as they are
    bad = np.array(V, copy=True)
    bad[np.asarray(topo.eye_loops[0])[0]] = np.nan
    nan = face_scale.face_span(bad, WeakPerspective(20.0, R, np.zeros(2)), topo.eye_loops)
    assert np.isnan(nan) and face_scale.face_scale(nan) == 1.0


def test_a_larger_faces_eyeballs_are_continued_without_its_lashes(arkit_model):
    """The eye openings' rim redone before the eyeball is continued under the lids
    (``eyeballs.RIM``: lashes and the lid margin where the track's margin is a little off)
    grows with the eye (``eyeballs.RIM_WIDTH``): on a face 2.5 times the data folder's,
    lashes 2.5 px deep on the opening's rim (1 px at the smaller face) are not continued
    under the lids as the eyeball. Before, a 1-px rim left them, and the sclera uncovered by
    a turned iris was a flat grey-brown wedge (a 1280x1280 clip's frame 39: BENCHMARKS.md,
    "Fifty-fourth session (helper large54)")."""
    from facetransfer import eyeballs, eyes
    from conftest import mean_person_track

    model = arkit_model
    topo = mesh_topology(model)
    closed, fill = eyes.close_eyes(topo, model.synthesize(model.default_weights()))
    fill_eye = np.full(len(closed.faces), -1, np.int8)
    fill_eye[fill] = 0
    size = 23 * 50
    track = mean_person_track(model, np.zeros((1, 52), np.float32), size=size, scale=50.0)
    V = close_mouth(model.synthesize(track.weights_at(0)), closed)
    hole = np.isin(rasterize(V, closed.faces, track.camera(0), (size, size)).tri_id, fill)
    depth = cv2.distanceTransform(hole.view(np.uint8), cv2.DIST_L2, 5)
    img = np.empty((size, size, 3), np.uint8)
    img[:] = (200, 150, 120)
    img[hole] = (235, 235, 230)                  # sclera (no iris: the lashes alone matter)
    img[hole & (depth <= 2.5)] = (40, 30, 25)    # lashes on the opening's rim
    balls = eyeballs.eyeballs_of(img, track, 0, model, closed.faces, V, fill_eye)
    under = (cv2.distanceTransform((~hole).view(np.uint8), cv2.DIST_L2, 5) <= 4) & ~hole
    shown = balls.image[under].astype(float).mean(axis=-1)
    assert np.median(shown) > 200                # before: 31.7 (the lashes continued)


def test_a_clips_frames_take_one_factor_for_their_shot(arkit_model, monkeypatch):
    """A clip's frames are rewritten with one factor, their shot's
    (:func:`facetransfer.face_scale.shot_scale`: of the median of their faces' spans), not
    each its own: a face whose measure moves about a whole-pixel setting's step from frame
    to frame (the blend's erosion: 2 px at a factor of 1.249, 3 at 1.251) had its outline
    flicker (a 1280x1280 clip's frame 19: 1,097 pixels by more than 8 levels, up to 111)."""
    from facetransfer.rewrite_clip import RenderRun, rewrite_frames
    from facetransfer.rewrite_options import RewriteOptions
    from conftest import mean_person_track

    model = arkit_model
    topo, V, d = mean_eye_span(model)
    monkeypatch.setattr(face_scale, "FACE_SPAN", 50.0)      # the threshold at a small face
    factors = np.array([1.249, 1.251, 1.249, 1.251, 1.252])  # each frame's own measure
    track = mean_person_track(model, np.zeros((5, 52), np.float32), size=256, scale=10.0)
    track = dataclasses.replace(track, scale=factors * 50.0 / d)
    spans = [face_scale.face_span(V, track.camera(i), topo.eye_loops) for i in range(5)]
    assert [face_scale.face_scale(s) for s in spans] == pytest.approx(factors)
    assert face_scale.shot_scale(V, track, topo.eye_loops, range(5)) == pytest.approx(1.251)
    assert face_scale.shot_scale(V, track, topo.eye_loops, []) == 1.0
    seen = record_scales(monkeypatch)
    frames = [np.full((256, 256, 3), SKIN, np.uint8)] * 5
    out = list(rewrite_frames(frames, track, track, model, options=RewriteOptions(blend="none"),
                              run=RenderRun(workers=1)))
    assert len(out) == 5 and len(seen) >= 5
    assert seen == pytest.approx([1.251] * len(seen), abs=1e-3)

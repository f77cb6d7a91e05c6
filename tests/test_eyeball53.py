"""An eye looking aside takes the eyeball of a frame looking ahead (facetransfer.eyeballs,
eyeball53): the lids and brows stay the reference frame's."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import eyeballs, eyes
from facetransfer.arkit import ARKIT_NAMES
from facetransfer.topology import close_mouth, mesh_topology
from test_eyeballs import IRIS, SCLERA, SKIN, painted_frame
from test_eyes import SIZE, _acts, _track


def _painted(model, closed, fill, track, i):
    """Frame ``i`` of ``track`` painted (:func:`test_eyeballs.painted_frame`): the picture,
    the mesh and the irises' centres."""
    img, V, _, iris = painted_frame(model, closed, fill, track, i)
    return img, V, iris


@pytest.fixture(scope="module")
def clip(arkit_model):
    """Two frames of the mean person facing the camera: in frame 0 (the reference) the left
    eye looks hard out, in frame 1 both eyes look ahead."""
    model = arkit_model
    topo = mesh_topology(model)
    closed, fill = eyes.close_eyes(topo, model.synthesize(model.default_weights()))
    a = _acts(2, 0.0)
    a[0, ARKIT_NAMES.index("eyeLookOutLeft")] = 1.0
    track = _track(model, a)
    fill_eye = np.full(len(closed.faces), -1, np.int8)
    V0 = close_mouth(model.synthesize(model.default_weights()), closed)
    mid = V0[np.asarray(model.landmarks)[36:48], 0].mean()
    fill_eye[fill] = (V0[closed.faces[fill], 0].mean(axis=1) > mid).astype(np.int8)
    frames = [_painted(model, closed, fill, track, i) for i in (0, 1)]
    return model, closed, fill_eye, track, frames


def test_an_eye_looking_aside_takes_the_eyeball_of_a_frame_looking_ahead(clip, monkeypatch):
    model, closed, fill_eye, track, frames = clip
    monkeypatch.setattr(eyeballs, "LIFT", True)
    (img0, V0, iris0), (img1, _, iris1) = frames
    assert iris0[1, 0] > iris1[1, 0] + 3.0            # the left iris out (the image's right)
    np.testing.assert_array_equal(eyeballs.eyeball_frames(track, 0), [0, 1])
    base = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye)
    lift = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye,
                                frames=[img0, img1], n_frames=2, topo=closed)
    assert base.source is None and not base.lifted
    np.testing.assert_array_equal(lift.source, [0, 1])
    np.testing.assert_allclose(lift.angles[1], 0.0, atol=1e-12)   # frame 1's gaze
    np.testing.assert_array_equal(lift.angles[0], base.angles[0])
    # turned ahead, the eye shows frame 1's iris where it is (no shift), not the reference
    # frame's iris shifted back across the sclera filled beyond it
    ahead = np.zeros((2, 2))
    np.testing.assert_array_equal(lift.shift(ahead), 0.0)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    disk = (xx - iris1[1, 0]) ** 2 + (yy - iris1[1, 1]) ** 2 <= 2.0 ** 2
    assert np.abs(lift.image[disk].astype(int) - IRIS).max() <= 30
    assert np.abs(base.image[disk].astype(int) - IRIS).max() > 100
    # the right eye (looking ahead in both) and everything away from the left eye: unchanged
    right = (xx - iris0[0, 0]) ** 2 + (yy - iris0[0, 1]) ** 2 <= 12 ** 2
    np.testing.assert_array_equal(lift.image[right], base.image[right])
    changed = (lift.image != base.image).any(-1)
    assert changed[disk].all() and (xx[changed] > SIZE / 2).all()   # the image's right: left


def test_a_lifted_eyeball_is_shown_at_the_frames_own_gaze_too(clip, monkeypatch):
    """:meth:`EyeTexture.at`: a gaze equal to the lifted frame's (no shift) still shows the
    lifted eyeball (before, no shift meant the reference frame's own eye as it is)."""
    model, closed, fill_eye, track, frames = clip
    monkeypatch.setattr(eyeballs, "LIFT", True)
    (img0, V0, _), (img1, _, _) = frames
    lift = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye,
                                frames=[img0, img1], n_frames=2, topo=closed)
    tex = eyes.EyeTexture(img0, np.zeros((len(V0), 2)), np.zeros(len(closed.faces), bool), 0,
                          fill_eye, np.zeros((2, 2, 2), np.int64), np.ones(2), eyeballs=lift)
    np.testing.assert_array_equal(tex.at(0, np.zeros((2, 2))).gaze_shift, 0.0)
    np.testing.assert_array_equal(tex.at(0, np.full((2, 2), np.nan)).gaze_shift, 0.0)
    base = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye)
    plain = eyes.EyeTexture(img0, np.zeros((len(V0), 2)), np.zeros(len(closed.faces), bool), 0,
                            fill_eye, np.zeros((2, 2, 2), np.int64), np.ones(2), eyeballs=base)
    assert plain.at(0, base.angles).gaze_shift is None
    assert plain.at(0, np.full((2, 2), np.nan)).gaze_shift is None


def test_the_eyeball_frame_rules(arkit_model):
    """Another frame's eyeball only where it looks nearer ahead by EYEBALL_GAIN, its eye open
    (no blink), its head near the reference's view, the face found; none without eyeLook*."""
    a = _acts(4, 0.0)
    a[:, ARKIT_NAMES.index("eyeLookInRight")] = [0.8, 0.8, 0.8, 0.8]
    a[:, ARKIT_NAMES.index("eyeLookOutLeft")] = [0.3, 0.3 - eyeballs.EYEBALL_GAIN / 2, 0.0, 0.0]
    a[1, ARKIT_NAMES.index("eyeLookInRight")] = 0.0
    a[2, ARKIT_NAMES.index("eyeBlinkRight")] = 0.5   # the right eye half closed in frame 2
    a[3, ARKIT_NAMES.index("eyeBlinkRight")] = 0.5
    track = _track(arkit_model, a)
    # right eye: frame 1 (ahead); left: frames 2, 3 look ahead (their left eyes open)
    np.testing.assert_array_equal(eyeballs.eyeball_frames(track, 0), [1, 2])
    lost = track.__class__(**{**track.__dict__, "lost": np.array([False, True, False, False])})
    np.testing.assert_array_equal(eyeballs.eyeball_frames(lost, 0), [0, 2])
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    R = np.stack([np.eye(3), np.eye(3), [[c, 0, s], [0, 1, 0], [-s, 0, c]], np.eye(3)])
    turned = track.__class__(**{**track.__dict__, "rotation": R})
    np.testing.assert_array_equal(eyeballs.eyeball_frames(turned, 0), [1, 3])
    np.testing.assert_array_equal(eyeballs.eyeball_frames(track, 0, n_frames=1), [0, 0])
    bare = track.__class__(**{**track.__dict__, "blendshapes": None,
                              "blendshape_names": None})
    np.testing.assert_array_equal(eyeballs.eyeball_frames(bare, 0), [0, 0])


def test_a_lifted_eyeball_is_continued_as_an_eyeball_under_its_lids():
    """``extend_eyeballs(iris=True)`` (another frame's eyeball): a catchlight on the opening's
    rim is not drawn out into a bar over the iris, and the corner's shade beyond the sclera
    is not continued: the eyeball there is its sclera; without it, as before."""
    img = np.zeros((60, 80, 3), np.uint8)
    img[:] = SKIN
    opening = np.zeros((60, 80), bool)
    opening[25:35, 20:60] = True
    img[opening] = SCLERA
    img[25:35, 55:60] = (120, 110, 110)          # the outer corner in shade
    img[25:35, 34:46] = IRIS                     # an iris from lid to lid
    img[25:28, 38:40] = (255, 255, 255)          # a catchlight on its upper rim
    plain = eyeballs.extend_eyeballs(img, opening, grow=8)
    lifted = eyeballs.extend_eyeballs(img, opening, grow=8, iris=True)
    above = (slice(19, 24), slice(38, 40))       # over the catchlight, under the upper lid
    assert plain[above].min() >= 250                                  # a bar of it
    assert np.abs(lifted[above].astype(int) - IRIS).max() == 0        # the iris
    beyond = (slice(28, 32), slice(61, 66))      # beyond the shaded outer corner
    assert np.abs(plain[beyond].astype(int) - (120, 110, 110)).max() == 0
    assert np.abs(lifted[beyond].astype(int) - SCLERA).max() == 0
    core = np.zeros_like(opening)
    core[26:34, 21:59] = True
    np.testing.assert_array_equal(lifted[core], img[core])           # the opening kept


def test_the_lift_is_off_by_default_and_then_nothing_changes(clip):
    """:data:`facetransfer.eyeballs.LIFT` off (the judge's vertical gaze): the clip's frames
    given or not, the eyeballs are the reference frame's, to the bit."""
    model, closed, fill_eye, track, frames = clip
    (img0, V0, _), (img1, _, _) = frames
    assert eyeballs.LIFT is False
    base = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye)
    given = eyeballs.eyeballs_of(img0, track, 0, model, closed.faces, V0, fill_eye,
                                 frames=[img0, img1], n_frames=2, topo=closed)
    assert given.source is None
    np.testing.assert_array_equal(given.image, base.image)
    np.testing.assert_array_equal(given.angles, base.angles)

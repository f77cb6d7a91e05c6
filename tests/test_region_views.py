"""The eye and jaw regions' reference frames by view (:mod:`facetransfer.region_views`)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import region_views
from facetransfer.arkit import ARKIT_NAMES
from facetransfer.region_views import (RegionViews, blend_renders, fade_weights,
                                       pick_views, view_angles, view_references, views_at)
from facetransfer.track.result import Track

from conftest import mean_person_track

SIZE = 256
BROWS = ("browInnerUp", "browOuterUpLeft", "browOuterUpRight")


def _yaw(deg: float) -> np.ndarray:
    t = np.radians(deg)
    return np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])


def _track(model, yaws, acts=None) -> Track:
    """The model's mean person at the head yaws (degrees) ``yaws`` (F,), open eyes, with ARKit
    activations ``acts`` (F, 52) (default zeros)."""
    acts = np.zeros((len(yaws), 52), np.float32) if acts is None else acts
    return mean_person_track(model, acts, size=SIZE, rotation=np.stack([_yaw(y) for y in yaws]))


def test_view_angles_are_the_rotations_between_frames():
    R = np.stack([_yaw(0.0), _yaw(10.0), _yaw(-25.0)])
    A = view_angles(R, [0, 2])
    np.testing.assert_allclose(A, [[0.0, 25.0], [10.0, 35.0], [25.0, 0.0]], atol=1e-5)


def test_a_turned_half_takes_a_quiet_browed_frame_from_its_side(arkit_model):
    """Frames 20-39 turned 25 degrees from the reference (frame 0): the second reference is
    one of them, the first whose brows are quiet (20-29 raise theirs), and each half takes its
    own; a clip within :data:`facetransfer.region_views.VIEW_SPLIT`, or turned in fewer than
    :data:`facetransfer.region_views.MIN_SHARE` of its frames, keeps one reference."""
    yaws = np.r_[np.zeros(20), np.full(20, 25.0)]
    acts = np.zeros((40, 52), np.float32)
    acts[20:30, [ARKIT_NAMES.index(b) for b in BROWS]] = 1.0
    tr = _track(arkit_model, yaws, acts)
    refs = view_references(tr, 40, 0)
    assert refs == [0, 30]
    np.testing.assert_array_equal(pick_views(tr.rotation, refs, tr.lost, 40),
                                  np.r_[np.zeros(20), np.ones(20)])
    assert view_references(_track(arkit_model, np.r_[np.zeros(20), np.full(20, 10.0)]),
                           40, 0) == [0]
    few = np.zeros(40)
    few[10:13] = 25.0                                          # 3 of 40 frames: 7.5 %
    assert view_references(_track(arkit_model, few), 40, 0) == [0]


def test_a_turned_half_takes_a_frame_looking_ahead(arkit_model, monkeypatch):
    """Frames 20-39 turned 25 degrees, the eyes of 20-29 looking aside (eyeLookInRight and
    eyeLookOutLeft 0.7): the second reference is one looking ahead, as the first is
    (:func:`facetransfer.eyes.eye_penalty`; eyeref53: ``make demo``'s second reference looked
    hard aside), with the gaze weighed (:data:`facetransfer.eyes.GAZE_WEIGHT`); it was 20,
    the first of the turned frames."""
    from facetransfer import eyes

    monkeypatch.setattr(eyes, "GAZE_WEIGHT", 1.0)
    acts = np.zeros((40, 52), np.float32)
    acts[20:30, [ARKIT_NAMES.index(n) for n in ("eyeLookInRight", "eyeLookOutLeft")]] = 0.7
    tr = _track(arkit_model, np.r_[np.zeros(20), np.full(20, 25.0)], acts)
    assert view_references(tr, 40, 0) == [0, 30]


def test_a_head_hovering_between_two_views_does_not_switch_back_and_forth():
    """Two references 20 degrees apart: frames alternating 1 degree either side of half way
    keep the reference they have (the first frame's nearest to begin with); a frame
    :data:`facetransfer.region_views.HYSTERESIS` nearer the other switches; lost frames keep
    theirs."""
    yaws = [0.0, 20.0, 9.0, 11.0, 9.0, 11.0, 17.0, 18.0, 0.0, 0.0]
    R = np.stack([_yaw(y) for y in yaws])
    lost = np.zeros(10, bool)
    lost[8] = True
    np.testing.assert_array_equal(pick_views(R, [0, 1], lost, 10),
                                  [0, 1, 1, 1, 1, 1, 1, 1, 1, 0])
    R2 = np.stack([_yaw(y) for y in (9.0, 11.0, 9.0, 11.0, 0.0, 20.0)])
    np.testing.assert_array_equal(pick_views(R2, [4, 5], np.zeros(6, bool), 6),
                                  [0, 0, 0, 0, 0, 1])


def test_a_switch_becomes_a_cross_fade_of_the_fade_frames():
    pick = np.r_[np.zeros(6, np.int64), np.ones(6, np.int64)]
    w = fade_weights(pick, 2, 5)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(w[:, 1], [0, 0, 0, 0, 0.2, 0.4, 0.6, 0.8, 1, 1, 1, 1],
                               atol=1e-6)
    np.testing.assert_array_equal(fade_weights(pick, 2, 1), np.eye(2)[pick])


def test_renders_are_mixed_by_their_shares():
    from facetransfer.rewrite import RewriteFrame

    a = RewriteFrame(np.full((2, 2, 3), 10, np.uint8), np.full((2, 2, 3), 100, np.uint8),
                     np.ones((2, 2), bool), np.zeros((2, 2), bool))
    b = RewriteFrame(np.full((2, 2, 3), 20, np.uint8), np.full((2, 2, 3), 0, np.uint8),
                     np.ones((2, 2), bool), np.zeros((2, 2), bool))
    out = blend_renders([(a, 0.25), (b, 0.75)])
    assert (out.image == 18).all() and (out.rendered == 25).all()   # 17.5 -> 18, 25
    assert blend_renders([(a, 1.0)]) is a
    assert views_at(None, 3, None) == [(None, 1.0)]


@pytest.fixture(scope="module")
def turned_clip(arkit_model):
    """12 frames of skin, the head turned 25 degrees in frames 6-11, the eye holes coloured per
    frame, and its eye textures by view."""
    from facetransfer.render import rasterize
    from facetransfer.topology import close_mouth, mesh_topology

    model = arkit_model
    tr = _track(model, np.r_[np.zeros(6), np.full(6, 25.0)])
    topo = mesh_topology(model)
    frames = []
    for i in range(12):
        V = close_mouth(model.synthesize(tr.weights_at(i)), topo)
        r = rasterize(V, topo.faces, tr.camera(i), (SIZE, SIZE))
        img = np.empty((SIZE, SIZE, 3), np.uint8)
        img[:] = (200, 150, 120) if i < 6 else (170, 120, 100)   # the turned half lit otherwise
        img[r.tri_id < 0] = (40, 40, 40)
        frames.append(img)
    closed, tex = region_views.eye_texture_by_view(frames, tr, model, topo)
    return model, tr, topo, frames, closed, tex


def test_the_jaw_region_of_a_turned_clip_takes_a_reference_from_each_side(turned_clip):
    """The jaw region (closed mouths, no smile in any frame) of the clip turned in its second
    half: a reference frame from each half, each half rendered with its own."""
    model, tr, topo, frames, closed, _ = turned_clip
    jaw = region_views.jaw_texture_by_view(frames, tr, model, closed)
    assert isinstance(jaw, RegionViews)
    assert jaw.frames[0] < 6 <= jaw.frames[1]
    assert (jaw.weights[0] == [1, 0]).all() and (jaw.weights[11] == [0, 1]).all()
    assert [w for _, w in views_at(jaw, 0)] == [1.0]      # one texture (still: none shows)


def test_a_turned_clip_is_rendered_with_the_reference_of_each_frames_view(turned_clip,
                                                                          monkeypatch):
    """The clip's eye textures come from a frontal and a turned frame; a frame away from the
    switch is rendered as with its view's texture alone, a frame in the cross-fade as the mix
    of its renders with each."""
    import dataclasses

    import facetransfer.rewrite_clip as rc

    model, tr, topo, frames, closed, tex = turned_clip
    assert isinstance(tex, RegionViews) and tex.frames[0] < 6 <= tex.frames[1]
    w = tex.weights
    assert (w[0] == [1, 0]).all() and (w[11] == [0, 1]).all()
    mixed = np.flatnonzero((w[:, 1] > 0.2) & (w[:, 1] < 0.8))
    assert mixed.size

    def render(weights):
        views = dataclasses.replace(tex, weights=weights)
        monkeypatch.setattr(region_views, "eye_texture_by_view", lambda *a, **k: (closed, views))
        return [r.image for r in rc.rewrite_frames(
            frames, tr, tr, model, run=rc.RenderRun(workers=1, processes=False))]

    out = render(w)
    alone = [render(np.tile(np.eye(2, dtype=np.float32)[k], (12, 1))) for k in (0, 1)]
    for i in range(12):
        if w[i].max() == 1:
            np.testing.assert_array_equal(out[i], alone[int(np.argmax(w[i]))][i])
    for i in mixed:
        mix = w[i, 0] * alone[0][i].astype(float) + w[i, 1] * alone[1][i]
        assert np.abs(out[i] - mix).max() <= 1.0 + 1e-6        # two roundings
        assert np.abs(alone[0][i].astype(int) - alone[1][i]).max() > 10  # the two differ


def test_region_textures_made_ahead_are_taken_by_the_renderer_of_their_clip(turned_clip,
                                                                              monkeypatch):
    """The region textures made before the render (a transfer makes them while the source is
    tracked) are the renderer's own: the same frames rendered with them or without them are
    equal, and they are not made again; for another track or other modes they are made anew."""
    import dataclasses

    import facetransfer.rewrite_clip as rc
    from facetransfer.rewrite_options import RewriteOptions

    model, tr, topo, frames, _, _ = turned_clip
    opts = RewriteOptions()
    ahead = region_views.region_textures(frames, tr, model, opts, len(frames))
    assert ahead.open_topo is not ahead.topo and isinstance(ahead.eye_tex, RegionViews)
    assert ahead.fits(tr, 12, region_views.region_modes(opts))
    assert not ahead.fits(dataclasses.replace(tr), 12, region_views.region_modes(opts))
    assert not ahead.fits(tr, 11, region_views.region_modes(opts))
    one = rc.RenderRun(workers=1)
    plain = [r.image for r in rc.rewrite_frames(frames, tr, tr, model, run=one)]
    made = []
    real = region_views.region_textures

    def counted(*a, **k):
        made.append(1)
        return real(*a, **k)

    monkeypatch.setattr(rc, "region_textures", counted)
    taken = [r.image for r in rc.rewrite_frames(frames, tr, tr, model, run=one,
                                                regions=ahead)]
    assert made == []
    for a, b in zip(plain, taken):
        np.testing.assert_array_equal(a, b)
    list(rc.rewrite_frames(frames, tr, tr, model, run=one, options=RewriteOptions(eyes="target"),
                           regions=ahead))
    other = dataclasses.replace(tr)
    list(rc.rewrite_frames(frames, other, other, model, run=one, regions=ahead))
    assert made == [1, 1]


def test_region_textures_of_a_lost_clip_or_without_regions_are_none(turned_clip):
    import dataclasses

    from facetransfer.rewrite_options import RewriteOptions

    model, tr, topo, frames, _, _ = turned_clip
    lost = dataclasses.replace(tr, lost=np.ones(12, bool))
    for track, opts in ((lost, RewriteOptions()), (tr, RewriteOptions(eyes="target",
                                                                      jaw="frame"))):
        got = region_views.region_textures(frames, track, model, opts, 12, topo=topo)
        assert got.topo is topo and got.eye_tex is None and got.jaw_tex is None

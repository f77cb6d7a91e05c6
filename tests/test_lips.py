"""The lips the model cannot fit (issue 13): the capture's residual at the lips in a transfer."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer import lips
from facetransfer.errors import ShapeError, TrackError
from facetransfer.rewrite_clip import MouthSource, _ClipRenderer
from facetransfer.rewrite_options import RewriteOptions
from facetransfer.texture.face import frame_uvs
from facetransfer.topology import close_mouth, mesh_topology
from facetransfer.track.project import project_landmarks, take_frames
from facetransfer.track.result import Track
from facetransfer.transfer import resample_track, time_map

from conftest import jaw_open_track

SIZE = 256


@pytest.fixture(scope="module")
def setup(arkit_model):
    return arkit_model, mesh_topology(arkit_model)


def _track(model, jaw_open, *, scale=20.0, rotation=None) -> Track:
    """A track of ``model``'s mean person with the given jawOpen per frame, its landmarks
    projected (Eq. (7))."""
    return project_landmarks(jaw_open_track(model, jaw_open, size=SIZE, scale=scale,
                                            rotation=rotation), model)


# --- the spline --------------------------------------------------------------------------------

def test_tps_interpolates_its_control_points_and_reproduces_affine_maps():
    rng = np.random.default_rng(0)
    C = rng.uniform(-1, 1, (20, 2))
    X = rng.uniform(-1.5, 1.5, (50, 2))
    M = lips.tps_influence(C, X)
    d = rng.normal(size=(20, 3))
    assert np.allclose(lips.tps_influence(C, C) @ d, d, atol=1e-9)
    A, b = rng.normal(size=(2, 3)), rng.normal(size=3)
    assert np.allclose(M @ (C @ A + b), X @ A + b, atol=1e-9)   # an affine field is kept exactly
    # smoothing lets the spline miss its control points, but never an affine field
    Ms = lips.tps_influence(C, C, smoothing=1.0)
    assert not np.allclose(Ms @ d, d, atol=1e-3)
    assert np.allclose(Ms @ (C @ A + b), C @ A + b, atol=1e-9)


@pytest.mark.parametrize("smoothing", [0.0, 1e-3, 0.1])
def test_tps_is_scipys_thin_plate_spline(smoothing):
    """The reference: SciPy's RBFInterpolator with the thin-plate kernel ``r² log r`` and a linear
    polynomial, fitted to the identity's columns; its kernel is half of ours (``r² log r²``), so
    its smoothing is half of ours."""
    from scipy.interpolate import RBFInterpolator

    rng = np.random.default_rng(5)
    C = rng.uniform(-1, 1, (20, 2))
    X = rng.uniform(-1.5, 1.5, (300, 2))
    want = RBFInterpolator(C, np.eye(20), kernel="thin_plate_spline", smoothing=smoothing / 2,
                           degree=1)(X)
    np.testing.assert_allclose(lips.tps_influence(C, X, smoothing=smoothing), want, atol=1e-10)


@pytest.mark.parametrize("control, points", [(np.zeros((2, 2)), np.zeros((4, 2))),
                                             (np.zeros((5, 3)), np.zeros((4, 2))),
                                             (np.zeros((5, 2)), np.zeros(4))])
def test_tps_rejects_bad_shapes(control, points):
    with pytest.raises(ShapeError):
        lips.tps_influence(control, points)


def test_tps_rejects_negative_smoothing():
    with pytest.raises(ValueError):
        lips.tps_influence(np.eye(3, 2), np.zeros((1, 2)), smoothing=-1.0)


# --- residuals ---------------------------------------------------------------------------------

def test_residuals_are_detections_minus_landmarks_zero_where_unknown(setup):
    model, _ = setup
    tr = _track(model, [0.1, 0.2, 0.3])
    assert lips.lip_residuals(tr) is None  # no detections recorded
    D = tr.landmarks2d + 1.5
    D[1, 50] = np.nan                        # a point not detected
    tr = dataclasses.replace(tr, detections2d=D, lost=np.array([False, False, True]))
    res = lips.lip_residuals(tr)
    assert res.shape == (3, 20, 2)
    assert np.allclose(res[0], 1.5)
    assert np.allclose(res[1, 50 - 48], 0.0) and np.allclose(res[1, :2], 1.5)
    assert np.allclose(res[2], 0.0)          # a lost frame


def test_shape_residuals_drop_the_mouths_shift_and_the_clips_mean():
    rng = np.random.default_rng(1)
    shape = rng.normal(size=(4, 20, 2))
    shape -= shape.mean(axis=1, keepdims=True)
    shape -= shape.mean(axis=0)
    shift = rng.normal(size=(4, 1, 2)) * 5        # the whole mouth moves: the pose's
    static = rng.normal(size=(1, 20, 2))          # the same every frame: the person's
    S = lips.lip_shape_residuals(shift + static + shape, np.zeros(4, bool))
    assert np.allclose(S, shape, atol=1e-12)
    lost = np.array([False, False, False, True])
    S = lips.lip_shape_residuals(shift + static + shape, lost)
    assert np.allclose(S[3], 0.0)
    assert np.allclose(S[:3], shape[:3] - shape[:3].mean(axis=0), atol=1e-12)
    with pytest.raises(ShapeError):
        lips.lip_shape_residuals(np.zeros((4, 19, 2)), np.zeros(4, bool))


# --- the warp on the model ---------------------------------------------------------------------

def test_warp_moves_the_lip_vertices_onto_the_detected_lips(setup):
    model, topo = setup
    warp = lips.lip_warp(model, topo, smoothing=0.0)
    assert np.isin(warp.landmarks, warp.vertices).all()      # the lips are the mouth's
    tr = _track(model, [0.3])
    V = close_mouth(model.synthesize(tr.weights_at(0)), topo)
    uvs = frame_uvs(V, tr.camera(0), (SIZE, SIZE))
    res = np.random.default_rng(2).normal(scale=3.0, size=(20, 2))
    out = lips.warp_uvs(uvs, warp, res, (SIZE, SIZE))
    # the landmark vertices now read the frame where their detections are
    px = np.c_[out[:, 0] * (SIZE - 1), (1 - out[:, 1]) * (SIZE - 1)]
    assert np.allclose(px[warp.landmarks], tr.camera(0).project(V[warp.landmarks]) + res,
                       atol=1e-6)
    outside = np.setdiff1d(np.arange(len(uvs)), warp.vertices)
    assert np.array_equal(out[outside], uvs[outside])        # the rest of the face is not read


def test_displacement_is_the_residual_lifted_into_the_head(setup):
    model, topo = setup
    warp = lips.lip_warp(model, topo, smoothing=0.0)
    V = model.synthesize(_track(model, [0.2]).weights_at(0))
    a = 0.3                                                   # the source's head turned
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    res = np.random.default_rng(3).normal(scale=2.0, size=(20, 2))
    out = lips.displace_lips(V, warp, res, R, 20.0, ratio=1.5)
    d = out - V
    # seen by the source's camera, the lip landmarks moved by the residual (times the ratio)
    seen = np.stack([d[warp.landmarks] @ R[0], -(d[warp.landmarks] @ R[1])], axis=1) * 20.0
    assert np.allclose(seen, 1.5 * res, atol=1e-6)
    assert np.allclose(d[warp.landmarks] @ R[2], 0.0, atol=1e-9)   # in the image's plane
    assert np.array_equal(np.flatnonzero(np.abs(d).sum(1) > 0),
                          np.intersect1d(np.flatnonzero(np.abs(d).sum(1) > 0),
                                         warp.vertices))             # only the mouth moves
    with pytest.raises(ShapeError):
        lips.displace_lips(V[:-1], warp, res, R, 20.0)


# --- the track keeps its detections ------------------------------------------------------------

def test_track_detections_round_trip_and_follow_the_frames(setup, tmp_path):
    model, _ = setup
    tr = _track(model, [0.0, 0.1, 0.2, 0.3])
    D = tr.landmarks2d + np.arange(4)[:, None, None]
    D[2] = np.nan                                             # no face found
    tr = dataclasses.replace(tr, detections2d=D)
    back = Track.load(tr.save(tmp_path / "t.npz"))
    assert np.array_equal(back.detections2d, D, equal_nan=True)
    assert np.array_equal(take_frames(tr, np.array([3, 0])).detections2d, D[[3, 0]])
    # resampled: the nearest frame's detections, not a blend of two frames'
    r = resample_track(tr, time_map(4, 25.0, 5, 30.0))
    near = time_map(4, 25.0, 5, 30.0).nearest
    assert np.array_equal(r.detections2d, D[near], equal_nan=True)
    with pytest.raises(TrackError):
        dataclasses.replace(tr, detections2d=D[:, :60])
    with pytest.raises(TrackError):
        dataclasses.replace(tr, detections2d=np.full_like(D, np.inf))


# --- in the rewrite ----------------------------------------------------------------------------

def _renderer(model, source, *, lips_mode="residual"):
    """The rewrite of the target (the mean person, mouth shut) with the source's expression."""
    n = source.n_frames
    frames = np.full((n, SIZE, SIZE, 3), 128, np.uint8)
    target = _track(model, [0.0] * n)
    new = dataclasses.replace(target, weights=source.weights)
    return _ClipRenderer.build(frames, target, new, model, RewriteOptions(lips=lips_mode),
                               mouth_source=MouthSource(frames, source), topo=None)


def test_the_new_lips_close_where_the_sources_detected_lips_close(setup):
    """Frame 1 of the source has its lips detected shut while the model's stay apart (jawOpen
    0.3); frame 0 is detected as fitted. The residual's shape (the clip's mean removed) closes
    the new lips at frame 1 and parts them at frame 0; without detections, or with
    ``lips="model"``, the new mesh is the model's."""
    model, _ = setup
    src = _track(model, [0.3, 0.3])
    D = src.landmarks2d.copy()
    for up, lo in ((61, 67), (62, 66), (63, 65)):
        mid = (D[1, up] + D[1, lo]) / 2
        D[1, up] = D[1, lo] = mid
    src_det = dataclasses.replace(src, detections2d=D)
    L = np.asarray(model.landmarks)

    def gap(r, i):  # the inner lips' gap (iBUG 62-66) as the source's camera sees it, px
        P = src.camera(i).project(r.new_mesh(i)[L[[62, 66]]])
        return float(np.linalg.norm(P[0] - P[1]))

    plain = _renderer(model, src)                      # a track without detections
    assert plain.lips is None
    g = gap(plain, 0)
    assert g == pytest.approx(np.linalg.norm(D[0, 62] - D[0, 66]))   # as fitted
    assert gap(_renderer(model, src_det, lips_mode="model"), 1) == pytest.approx(g)
    r = _renderer(model, src_det)
    assert r.lips is not None
    # half the closing each way (the clip's mean removed), up to the spline's smoothing
    assert gap(r, 1) == pytest.approx(g / 2, rel=0.1)
    assert gap(r, 0) == pytest.approx(1.5 * g, rel=0.1)
    # the mouth texture reads the source frame where the detected lips are
    uv0 = plain.mouth_texture(1).uvs
    uv1 = r.mouth_texture(1).uvs
    moved = np.flatnonzero(np.abs(uv1 - uv0).sum(1) > 1e-9)
    assert np.isin(L[[62, 66]], moved).all() and np.isin(moved, r.lips.warp.vertices).all()


def test_lips_option_is_validated():
    from facetransfer.errors import RewriteError

    assert RewriteOptions().lips == "residual"
    with pytest.raises(RewriteError, match="lips must be one of residual, model"):
        RewriteOptions(lips="detected")

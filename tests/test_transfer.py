"""Tests of facetransfer.transfer: time alignment and recombination on tracks (exact); the
edits of a track (Fig. 7E) are tests/test_performance_edit.py's."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer.track import Track
from facetransfer.track.project import project_landmarks
from facetransfer.transfer import (TransferError, constant_weights, parse_weights, recombine,
                                   resample_track, time_map)


def make_track(n=10, *, r=(3, 4), fps=25.0, size=(64, 48), seed=0, model_hash="h",
               modes=("identity", "expression"), lost=None) -> Track:
    """A track with distinct, known values in every field."""
    rng = np.random.default_rng(seed)
    weights = {m: rng.normal(size=(n, k)) for m, k in zip(modes, r)}
    weights[modes[0]][:] = weights[modes[0]][0]  # identity constant over the clip
    return Track(fps=fps, frame_size=size, rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=1.0 + rng.random(n), translation=rng.normal(size=(n, 2)) * 5,
                 weights=weights, landmarks2d=rng.normal(size=(n, 68, 2)),
                 confidence=np.full(n, 0.9),
                 lost=np.zeros(n, bool) if lost is None else np.asarray(lost, bool),
                 model_hash=model_hash, mode_names=modes, source=f"clip{seed}.mp4")


# ------------------------------------------------------------------------------ time_map
def test_time_map_same_rate_same_length_is_identity():
    tm = time_map(10, 25, 10, 25)
    np.testing.assert_array_equal(tm.source_time, np.arange(10))
    assert tm.align == "trim"


def test_time_map_default_trims_longer_source_and_holds_shorter():
    longer = time_map(20, 25, 10, 25)
    assert longer.align == "trim" and longer.n_frames == 10
    np.testing.assert_array_equal(longer.source_time, np.arange(10))
    shorter = time_map(4, 25, 10, 25)
    assert shorter.align == "hold" and shorter.n_frames == 10
    np.testing.assert_array_equal(shorter.source_time, [0, 1, 2, 3, 3, 3, 3, 3, 3, 3])


def test_time_map_trim_loop_hold_exact():
    np.testing.assert_array_equal(time_map(4, 25, 10, 25, align="trim").source_time,
                                  [0, 1, 2, 3])
    np.testing.assert_array_equal(time_map(4, 25, 10, 25, align="loop").source_time,
                                  [0, 1, 2, 3, 0, 1, 2, 3, 0, 1])
    np.testing.assert_array_equal(time_map(4, 25, 6, 25, align="hold").source_time,
                                  [0, 1, 2, 3, 3, 3])
    # trim keeps the source's last frame for its own duration: 20 frames at 25 fps (0.8 s) on
    # a 30 fps target are 24 frames, as loop and hold play before they repeat (before: 23)
    trim = time_map(20, 25, 30, 30, align="trim").source_time
    assert len(trim) == 24 and trim[-1] == 19
    np.testing.assert_allclose(trim[:23], np.arange(23) * 25 / 30)


def test_time_map_loops_an_ntsc_source_from_its_first_frame():
    """A looped source at an NTSC rate on a target at another: where a repeat lands on a
    target frame, that frame reads the source's first frame (review48a). Before, the rates'
    ratio came out an ulp short (29.97 / 23.976 = 1.2499999999999998): a 5-frame source's
    repeat read 4.9999999 and showed its last frame; 69 of the 531 cases below."""
    from fractions import Fraction

    tm = time_map(5, 30000 / 1001, 10, 24000 / 1001, align="loop")
    np.testing.assert_allclose(tm.source_time, np.tile([0, 1.25, 2.5, 3.75], 3)[:10], atol=1e-9)
    rates = (Fraction(24000, 1001), Fraction(30000, 1001), Fraction(60000, 1001))
    for a in rates:
        for b in rates:
            for n in range(1, 60):
                got = time_map(n, float(a), 3 * n, float(b), align="loop").source_time
                exact = [min(float(j * a / b % n), n - 1) for j in range(3 * n)]
                np.testing.assert_allclose(got, exact, atol=1e-9, err_msg=f"{a} {b} {n}")


def test_time_map_resamples_frame_rate():
    # a 30 fps source on a 25 fps target: target frame j reads source frame 1.2 j
    tm = time_map(100, 30, 6, 25)
    np.testing.assert_allclose(tm.source_time, 1.2 * np.arange(6))
    np.testing.assert_array_equal(tm.nearest, [0, 1, 2, 4, 5, 6])
    # a 12.5 fps source is read at half steps
    np.testing.assert_allclose(time_map(3, 12.5, 5, 25).source_time, [0, 0.5, 1, 1.5, 2])


@pytest.mark.parametrize("args,kw,message", [
    ((0, 25, 5, 25), {}, r"frame counts must be >= 1, got source 0, target 5"),
    ((5, 0, 5, 25), {}, r"frame rates must be > 0, got source 0, target 25"),
    ((5, 25, 5, -1), {}, r"frame rates must be > 0, got source 25, target -1"),
    ((5, 25, 5, 25), {"align": "stretch"}, r"align must be one of trim, loop, hold, got 'stretch'"),
    ((40.7, 25, 5, 25), {}, r"frame counts are whole numbers, got source 40.7"),
    ((5, 25, True, 25), {}, r"frame counts are whole numbers, got target True")])
def test_time_map_bad_input(args, kw, message):
    with pytest.raises(TransferError, match=f"^{message}$"):
        time_map(*args, **kw)
    assert time_map(5.0, 25, np.int64(5), 25).n_frames == 5   # whole numbers of any type


def test_resample_track_interpolates_and_propagates_lost():
    tr = make_track(4, lost=[False, False, True, False])
    tm = time_map(4, 12.5, 7, 25)  # times 0, .5, 1, 1.5, 2, 2.5, 3
    rs = resample_track(tr, tm)
    assert rs.n_frames == 7
    w = tr.weights["expression"]
    np.testing.assert_allclose(rs.weights["expression"][1], 0.5 * (w[0] + w[1]))
    np.testing.assert_allclose(rs.weights["expression"][6], w[3])
    np.testing.assert_allclose(rs.scale[3], 0.5 * (tr.scale[1] + tr.scale[2]))
    np.testing.assert_array_equal(rs.lost, [False, False, False, True, True, True, False])


def test_a_resampled_tracks_cut_moves_with_it_and_no_frame_blends_two_shots():
    """A source edited from two shots (a cut at its frame 6) read at another rate and cut
    short: the cut lands on the first frame reading the second shot, the frame between the
    shots is the first shot's last, and a cut beyond the frames read is dropped (before: the
    source's numbering kept, "shot_starts must be increasing frames in 1..m")."""
    tr = dataclasses.replace(make_track(10), shot_starts=(6,))
    rs = resample_track(tr, time_map(10, 12.5, 9, 25))    # times 0, .5, ..., 4
    assert rs.shot_starts == ()                            # the cut is not reached
    rs = resample_track(tr, time_map(10, 20, 10, 25))     # times 0, .8, ..., 7.2
    t = np.arange(10) * 0.8                                # frame 7 reads 5.6: between shots
    assert rs.shot_starts == (8,)                          # 6.4 is the first in the second
    w = tr.weights["expression"]
    np.testing.assert_array_equal(rs.weights["expression"][7], w[5])
    np.testing.assert_allclose(rs.weights["expression"][8], w[6] + (w[7] - w[6]) * (t[8] - 6))
    np.testing.assert_allclose(rs.weights["expression"][6], w[4] + (w[5] - w[4]) * (t[6] - 4))


def test_resample_track_keeps_a_constant_identity_bit_for_bit():
    """Between two equal rows the interpolation is that row exactly (the render contracts a
    constant identity once; an ulp apart, it would take it for one that changes)."""
    tr = make_track(40, r=(40, 4), seed=3)
    tm = time_map(40, 29.97, 47, 25.0)
    rs = resample_track(tr, tm)
    a = tr.weights["identity"][0]
    assert (rs.weights["identity"] == a).all()
    f = np.asarray(tm.source_time) % 1
    assert (a * (1 - f[:, None]) + a * f[:, None] != a).any()  # what the other form gives


# ------------------------------------------------------------------------------ recombine
def test_recombine_expression_from_source_keeps_target_identity_and_pose():
    tgt, src = make_track(8, seed=1), make_track(8, seed=2)
    new = recombine(tgt, expression=src)
    np.testing.assert_array_equal(new.weights["expression"], src.weights["expression"])
    np.testing.assert_array_equal(new.weights["identity"], tgt.weights["identity"])
    np.testing.assert_array_equal(new.translation, tgt.translation)
    np.testing.assert_array_equal(new.scale, tgt.scale)
    assert new.fps == tgt.fps and new.frame_size == tgt.frame_size


def test_recombine_identity_pose_and_mixing_three_tracks():
    tgt, a, b = make_track(6, seed=1), make_track(6, seed=2), make_track(6, seed=3)
    b_lost = dataclasses.replace(b, lost=np.array([True] + [False] * 5))
    new = recombine(tgt, expression=a, identity=b_lost, pose=a)
    # identity: the mean over frames not lost (all rows equal here)
    np.testing.assert_allclose(new.weights["identity"], np.tile(b.weights["identity"][0], (6, 1)))
    np.testing.assert_array_equal(new.translation, a.translation)
    w = np.arange(3.0)
    np.testing.assert_array_equal(recombine(tgt, identity=w).weights["identity"],
                                  np.tile(w, (6, 1)))
    with pytest.raises(TransferError, match="3 finite numbers"):
        recombine(tgt, identity=np.zeros(5))


def test_recombine_lost_frames_and_alignment():
    tgt = make_track(6, seed=1, lost=[0, 0, 0, 0, 0, 1])
    src = make_track(3, seed=2, lost=[0, 1, 0])
    new = recombine(tgt, expression=src)  # shorter source: hold its last frame
    assert new.n_frames == 6
    np.testing.assert_array_equal(new.lost, [False, True, False, False, False, True])
    np.testing.assert_array_equal(new.weights["expression"][5], src.weights["expression"][2])
    assert recombine(tgt, expression=src, align="trim").n_frames == 3


def test_recombine_rejects_incompatible_tracks():
    tgt = make_track(4, seed=1)
    with pytest.raises(TransferError, match="different model"):
        recombine(tgt, expression=make_track(4, seed=2, model_hash="other"))
    with pytest.raises(TransferError, match="viseme"):
        recombine(tgt, viseme=make_track(4, seed=2))
    with pytest.raises(TransferError, match="weights"):
        recombine(tgt, expression=make_track(4, seed=2, r=(3, 5)))


@pytest.mark.parametrize("size, aspect", [((32, 32), 1.0), ((64, 48), 1.25), ((200, 90), 0.8)])
def test_a_pose_of_another_frame_moves_the_targets_head(size, aspect):
    """A pose track of another frame size or pixel shape (before: refused) drives the target's
    head: every projected model point, in shown pixels, moves about the target head's usual
    place as it moves about the pose source head's, scaled by the heads' sizes; the rotation
    is the source's. A track moved onto itself is unchanged."""
    import dataclasses

    from facetransfer.transfer import _placement, pose_about

    rng = np.random.default_rng(3)
    tgt = dataclasses.replace(make_track(4, seed=1), pixel_aspect=1.1)     # 64x48, a = 1.1
    src = dataclasses.replace(make_track(4, seed=2, size=size), pixel_aspect=aspect,
                              lost=np.array([False, False, True, False]))
    R = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(4)])
    src = dataclasses.replace(src, rotation=R * np.sign(np.linalg.det(R))[:, None, None])
    new = recombine(tgt, pose=src)
    assert new.frame_size == tgt.frame_size and new.pixel_aspect == 1.1
    (tp, sp), (tt, st) = _placement(src), _placement(tgt)
    assert sp == np.median(src.scale[[0, 1, 3]])                 # the lost frame left out
    X = rng.normal(size=(20, 3))
    for i in range(4):
        def shown(track):
            return track.camera(i).project(X)[:, :2] * (track.pixel_aspect, 1.0)
        np.testing.assert_allclose(shown(new) - tt, st / sp * (shown(src) - tp), atol=1e-9)
        np.testing.assert_allclose(new.rotation[i], src.rotation[i], atol=1e-12)
    same = pose_about(tgt, tgt)
    np.testing.assert_allclose(same.translation, tgt.translation, atol=1e-12)
    np.testing.assert_allclose(same.landmarks2d, tgt.landmarks2d, atol=1e-12)
    np.testing.assert_allclose(same.scale, tgt.scale, atol=1e-12)


def test_recombine_viseme_from_trilinear_tracks():
    modes = ("identity", "expression", "viseme")
    tgt = make_track(5, r=(3, 2, 2), modes=modes, seed=1)
    s1 = make_track(5, r=(3, 2, 2), modes=modes, seed=2)
    s2 = make_track(5, r=(3, 2, 2), modes=modes, seed=3)
    new = recombine(tgt, expression=s1, viseme=s2)
    np.testing.assert_array_equal(new.weights["expression"], s1.weights["expression"])
    np.testing.assert_array_equal(new.weights["viseme"], s2.weights["viseme"])
    np.testing.assert_array_equal(new.weights["identity"], tgt.weights["identity"])


def test_constant_weights_all_lost_raises():
    with pytest.raises(TransferError, match="lost in every frame"):
        constant_weights(make_track(3, lost=[1, 1, 1]), "identity")


def test_nearest_frames_refuses_rows_of_another_length():
    """Query and bank rows of different lengths raised numpy's broadcast error."""
    from facetransfer.errors import ShapeError
    from facetransfer.texture.function import nearest_frames

    with pytest.raises(ShapeError, match=r"got \(3, 4\) and \(5, 6\)"):
        nearest_frames(np.zeros((3, 4)), np.zeros((5, 6)))
    with pytest.raises(ShapeError, match=r"valid must be \(5,\)"):
        nearest_frames(np.zeros((3, 4)), np.zeros((5, 4)), np.ones(4, bool))
    bank = np.arange(10.0).reshape(5, 2)
    np.testing.assert_array_equal(nearest_frames(bank[[4, 0]] + 0.1, bank), [4, 0])


def test_parse_weights():
    np.testing.assert_array_equal(parse_weights("1,2,3", 3), [1, 2, 3])
    with pytest.raises(TransferError, match="expected 3"):
        parse_weights("1,2", 3)
    with pytest.raises(TransferError, match="^--identity-weights missing.npy: no such file$"):
        parse_weights("missing.npy", 3)


def test_a_npy_that_is_text_is_said_as_such(tmp_path):
    """A .npy of text: "not a NumPy array file" (before: numpy's advice on pickled data)."""
    (tmp_path / "w.npy").write_text("1 2 3")
    with pytest.raises(TransferError, match=r"not a NumPy array file \(np.save writes one\)\)$"):
        parse_weights(str(tmp_path / "w.npy"), 3)
    with pytest.raises(TransferError, match="could not convert string to float: 'x'"):
        parse_weights("1,x,3", 3)


def test_project_landmarks_matches_camera(quick_model, quick_track):
    tr = project_landmarks(quick_track, quick_model)
    i = 7
    V = quick_model.synthesize(tr.weights_at(i))
    np.testing.assert_allclose(tr.landmarks2d[i], tr.camera(i).project(V[quick_model.landmarks]),
                               atol=1e-9)


def test_puppet_meshes_are_eq5_per_frame(quick_model, quick_track, monkeypatch):
    """Every frame puppet_frames renders is Eq. (5) of that frame with the puppet's identity
    (by explicit mode products), its mouth closed: the model's single-frame path, with the
    identity contracted once for the clip, gives each frame's own mesh."""
    from facetransfer import render as render_module
    from facetransfer import tensor as tl
    from facetransfer.puppet_video import puppet_frames
    from facetransfer.topology import close_mouth, mesh_topology

    seen = []
    real = render_module.render

    def spy(V, *a, **k):
        seen.append(np.array(V))
        return real(V, *a, **k)

    monkeypatch.setattr(render_module, "render", spy)
    wid = quick_model.training_weights(0, quick_model.labels[0][1])
    frames = list(puppet_frames(quick_track, quick_model, wid))
    assert len(frames) == len(seen) == quick_track.n_frames
    topo = mesh_topology(quick_model, lips=False)
    for i in [0, 2, 3, 4, quick_track.n_frames - 1, 1]:
        w = quick_track.weights_at(i) | {"identity": wid}
        ref = tl.multi_mode_dot(quick_model.core, [None] + [w[m] for m in quick_model.mode_names])
        closed = close_mouth(ref.reshape(-1, 3), topo)
        np.testing.assert_allclose(seen[i][:len(closed)], closed, atol=1e-9)


def test_identity_weights_outside_the_models_identity_space_are_refused(arkit_model):
    """``--identity-weights`` are coordinates in the identity space: every training row and
    a blend of two pass; the zero vector, a one-hot vector and uniform weights (a face blown
    past the frame, or a traceback from the renderer, before) are refused naming the
    component."""
    from facetransfer.transfer import IDENTITY_LIMIT, check_identity_weights

    U = arkit_model.factors[arkit_model.mode_index("identity")]
    for w in list(U) + [0.5 * (U[0] + U[1])]:
        check_identity_weights(arkit_model, w)
    r = U.shape[1]
    for w in (np.zeros(r), np.eye(r)[0], np.full(r, 1.0 / r)):
        with pytest.raises(TransferError, match=r"--identity-weights: component \d+ .* "
                           rf"standard deviations .* \(at most {IDENTITY_LIMIT:g}\)"):
            check_identity_weights(arkit_model, w)

"""Chunks of long clips: the split, slerp, the cross-fade join and the seam measure
(:mod:`facetransfer.batch.chunks`). Exact identities and synthetic ground truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facetransfer.batch import BatchError, join_tracks, plan_chunks, seam_difference
from facetransfer.batch.chunks import Chunk, crossfade, slerp_rotations


# no health check on the drawing's speed: a busy machine (CI beside other jobs) is not a defect
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(1, 3000),
       sizes=st.integers(2, 400).flatmap(lambda c: st.tuples(st.just(c), st.integers(1, c // 2))))
def test_plan_chunks_covers_the_clip_with_the_fewest_chunks(n, sizes):
    chunk, overlap = sizes
    cs = plan_chunks(n, chunk, overlap)
    if n <= chunk:
        assert cs == (Chunk(0, 0, n),)
        return
    assert cs[0].start == 0 and cs[-1].stop == n
    assert [c.index for c in cs] == list(range(len(cs)))
    assert all(1 <= c.n_frames <= chunk for c in cs)
    # neighbours share `overlap` frames (fewer if the clip is too short); none lies in three
    k = len(cs)
    shared = {p.stop - c.start for p, c in zip(cs[:-1], cs[1:])}
    assert shared == {min(overlap, n // (k + 1))}
    assert all(c.start >= p.stop for p, c in zip(cs[:-2], cs[2:]))
    # one chunk fewer cannot cover the clip
    assert (k - 1) * chunk - (k - 2) * overlap < n


def test_plan_chunks_refuses_bad_sizes():
    with pytest.raises(BatchError, match="--overlap must be between 1 and --chunk/2 = 50"):
        plan_chunks(1000, 100, 60)
    with pytest.raises(BatchError, match="--overlap"):
        plan_chunks(1000, 100, 0)
    with pytest.raises(BatchError, match="--chunk must be >= 0"):
        plan_chunks(1000, -1, 10)
    assert plan_chunks(1000, 0, 10) == (Chunk(0, 0, 1000),)
    # the benchmark's clip: 1008 frames in 4 chunks of 282 frames sharing 40
    assert [(c.start, c.stop) for c in plan_chunks(1008, 282, 40)] == \
        [(0, 282), (242, 524), (484, 766), (726, 1008)]


def test_slerp_is_exact_on_one_axis_and_hits_the_ends():
    a = np.array([0.1, -0.4, 1.2])
    b = np.array([0.9, 0.3, 2.0])
    axis = np.array([0.0, 0.6, 0.8])
    Ra = Rotation.from_rotvec(np.outer(a, axis)).as_matrix()
    Rb = Rotation.from_rotvec(np.outer(b, axis)).as_matrix()
    alpha = np.array([0.0, 0.25, 1.0])
    R = slerp_rotations(Ra, Rb, alpha)
    want = Rotation.from_rotvec(np.outer(a + alpha * (b - a), axis)).as_matrix()
    np.testing.assert_allclose(R, want, atol=1e-12)


def test_crossfade_is_linear_and_open():
    np.testing.assert_allclose(crossfade(4), [0.2, 0.4, 0.6, 0.8])


def _truth_track(model, F: int, seed: int = 0):
    """A smooth synthetic performance (pose and weights known on every frame)."""
    from facetransfer.track import Track
    from facetransfer.track.project import project_landmarks

    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, F)
    rot = Rotation.from_rotvec(np.stack([0.2 * np.sin(3 * t), 0.3 * np.cos(2 * t),
                                         0.1 * t], 1)).as_matrix()
    w = {m: np.tile(model.factors[k].mean(0), (F, 1)) for k, m in enumerate(model.mode_names)}
    w["expression"] = w["expression"] + 0.3 * np.sin(np.outer(5 * t, rng.normal(size=w[
        "expression"].shape[1])))
    tr = Track(25.0, (320, 240), rot, 12 + np.sin(4 * t), np.stack([160 + 20 * t, 120 - 10 * t],
                                                                    1),
               w, np.zeros((F, 68, 2)), np.full(F, 0.9), np.zeros(F, bool),
               model.content_hash, model.mode_names, "clip.mp4")
    return project_landmarks(tr, model)


def _piece(track, c: Chunk, **changes):
    sl = slice(c.start, c.stop)
    arrays = {"rotation": track.rotation[sl], "scale": track.scale[sl],
              "translation": track.translation[sl], "landmarks2d": track.landmarks2d[sl],
              "confidence": track.confidence[sl], "lost": track.lost[sl],
              "weights": {m: w[sl] for m, w in track.weights.items()}}
    arrays.update(changes)
    return dataclasses.replace(track, **arrays)


def test_join_of_exact_pieces_is_the_whole(quick_model):
    whole = _truth_track(quick_model, 90)
    cs = plan_chunks(90, 40, 10)
    joined = join_tracks([_piece(whole, c) for c in cs], cs, quick_model)
    assert joined.n_frames == 90 and joined.fps == 25.0 and joined.source == "clip.mp4"
    np.testing.assert_allclose(joined.rotation, whole.rotation, atol=1e-12)
    np.testing.assert_allclose(joined.scale, whole.scale, rtol=1e-12)
    for m in whole.mode_names:
        np.testing.assert_allclose(joined.weights[m], whole.weights[m], atol=1e-12)
    np.testing.assert_allclose(joined.landmarks2d, whole.landmarks2d, atol=1e-9)
    rep = seam_difference(whole, joined, cs, radius=5)
    assert len(rep.seams) == len(cs) - 1 and max(rep.seam_px) < 1e-9 and rep.iod_px > 1


def test_join_cross_fades_a_disagreement_and_skips_lost_frames(quick_model):
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)  # two chunks, frames 25..34 shared
    assert [(c.start, c.stop) for c in cs] == [(0, 35), (25, 60)]
    a = _piece(whole, cs[0])
    shift = np.array([4.0, -2.0])
    expr = whole.weights["expression"][25:] + 0.5
    lost = np.zeros(35, bool)
    lost[-3:] = True  # the later chunk lost its last frames
    b = _piece(whole, cs[1], translation=whole.translation[25:] + shift, lost=lost,
               weights={"identity": whole.weights["identity"][25:], "expression": expr})
    a = dataclasses.replace(a, lost=np.r_[np.zeros(32, bool), np.ones(3, bool)])  # 32..34 lost
    joined = join_tracks([a, b], cs, quick_model)
    alpha = crossfade(10)
    alpha[7:] = 1.0  # frames 32..34: lost in the first chunk only -> the second's state
    np.testing.assert_allclose(joined.translation[25:35], whole.translation[25:35]
                               + alpha[:, None] * shift, atol=1e-12)
    np.testing.assert_allclose(joined.weights["expression"][25:35],
                               whole.weights["expression"][25:35] + 0.5 * alpha[:, None],
                               atol=1e-12)
    np.testing.assert_allclose(joined.translation[35:], whole.translation[35:] + shift)
    np.testing.assert_allclose(joined.translation[:25], whole.translation[:25])
    assert not joined.lost[:57].any() and joined.lost[57:].all()
    # one identity for the clip: the first chunk's
    assert np.ptp(joined.weights["identity"], axis=0).max() == 0


def test_join_keeps_the_chunks_own_landmarks(quick_model):
    """A capture's landmarks carry its clip's offset from the model's landmark vertices (the
    flow and the detections, not the weights alone): the join cross-fades the chunks' own
    landmarks as it does the pose, and does not re-project them from the joined weights (which
    lost the offset: 2 px of a 154 px eye distance on a real clip)."""
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)                       # (0, 35), (25, 60)
    off = [np.array([1.5, -0.5]), np.array([1.0, 0.5])]  # each chunk's own clip offset
    pieces = [_piece(whole, c, landmarks2d=whole.landmarks2d[c.start:c.stop] + o)
              for c, o in zip(cs, off)]
    joined = join_tracks(pieces, cs, quick_model)
    alpha = crossfade(10)[:, None, None]
    want = whole.landmarks2d + np.concatenate(
        [np.tile(off[0], (25, 68, 1)), np.tile((1 - alpha) * off[0] + alpha * off[1], (1, 68, 1)),
         np.tile(off[1], (25, 68, 1))])
    np.testing.assert_allclose(joined.landmarks2d, want, atol=1e-9)


def test_join_refuses_mismatched_pieces(quick_model):
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)
    with pytest.raises(BatchError, match="chunk 1 .* tracked to 30 frames, expected 35"):
        join_tracks([_piece(whole, cs[0]), _piece(whole, Chunk(1, 30, 60))], cs, quick_model)
    with pytest.raises(BatchError, match="1 chunk tracks for 2 chunks"):
        join_tracks([whole], cs, quick_model)


def test_seam_difference_sees_a_step(quick_model):
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)
    stepped = dataclasses.replace(whole, landmarks2d=whole.landmarks2d
                                  + np.r_[np.zeros(30), np.full(30, 3.0)][:, None, None])
    rep = seam_difference(whole, stepped, cs, radius=5)
    assert rep.seams == (30,)
    # frames 25..35 near the seam: 6 of 11 moved by 3 px in x and y (|d| = 3 sqrt 2)
    np.testing.assert_allclose(rep.seam_px[0], 6 / 11 * 3 * np.sqrt(2))
    np.testing.assert_allclose(rep.elsewhere_px, 24 / 49 * 3 * np.sqrt(2))  # frames 36..59
    # the step between frames 29 and 30 is the largest motion near the seam
    motion = np.linalg.norm(np.diff(whole.landmarks2d, axis=0), axis=2).mean(1)
    np.testing.assert_allclose(rep.whole_motion_px[0], motion[25:35].max())
    d = np.linalg.norm(np.diff(stepped.landmarks2d, axis=0), axis=2).mean(1)
    np.testing.assert_allclose(rep.motion_px[0], d[25:35].max())
    assert rep.motion_px[0] >= 3 * np.sqrt(2) - motion[29] > rep.whole_motion_px[0]


def test_join_keeps_the_detections_of_the_nearer_chunk(quick_model):
    """A capture track's detections (what the lips' residual reads) survive the join: outside
    the overlaps each frame's own, inside it the nearer chunk's, the other's where that one
    found no face; without detections in every chunk, none."""
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)                     # frames 25..34 shared
    rng = np.random.default_rng(3)
    dets = [rng.normal(100, 20, (c.n_frames, 68, 2)) for c in cs]
    dets[0][26] = np.nan                             # frame 26: the first chunk found no face
    dets[1][7] = np.nan                              # frame 32: the second chunk found none
    pieces = [_piece(whole, c, detections2d=d) for c, d in zip(cs, dets)]
    joined = join_tracks(pieces, cs, quick_model)
    D = joined.detections2d
    assert D.shape == (60, 68, 2) and not np.isnan(D).any()
    np.testing.assert_array_equal(D[:25], dets[0][:25])
    np.testing.assert_array_equal(D[35:], dets[1][10:])
    first, second = [25, 27, 28, 29], [30, 31, 33, 34]   # the halves of the overlap
    np.testing.assert_array_equal(D[first], dets[0][first])
    np.testing.assert_array_equal(D[second], dets[1][[f - 25 for f in second]])
    np.testing.assert_array_equal(D[26], dets[1][1])          # the first chunk's missing
    np.testing.assert_array_equal(D[32], dets[0][32])         # the second chunk's missing
    pieces[1] = _piece(whole, cs[1])
    assert join_tracks(pieces, cs, quick_model).detections2d is None


def test_join_keeps_each_shots_identity(quick_model):
    """Chunks of a clip edited from two shots: the cut (seen by both chunks where they overlap,
    or by one) is kept once, and each shot takes the identity of the chunk where it starts."""
    whole = _truth_track(quick_model, 60)
    cs = plan_chunks(60, 35, 10)                       # (0, 35), (25, 60)
    other = quick_model.training_weights("identity", "id02")
    for cut, seen_by in ((30, (0, 1)), (15, (0,)), (45, (1,))):
        pieces = []
        for k, c in enumerate(cs):
            ident = np.array([other if c.start + i >= cut else whole.weights["identity"][0]
                              for i in range(c.n_frames)])
            starts = (cut - c.start,) if k in seen_by else ()
            pieces.append(_piece(whole, c, weights={"identity": ident, "expression":
                                                    whole.weights["expression"][c.start:c.stop]},
                                 shot_starts=starts))
        joined = join_tracks(pieces, cs, quick_model)
        assert joined.shot_starts == (cut,)
        ident = joined.weights["identity"]
        assert np.array_equal(ident[:cut], np.tile(whole.weights["identity"][0], (cut, 1)))
        assert np.array_equal(ident[cut:], np.tile(other, (60 - cut, 1)))

"""The calibrated MediaPipe -> iBUG-68 correspondence (data file, loader, solver)."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pytest

from facetransfer.errors import FaceTransferError, ShapeError
from facetransfer.track.calibration import (calibrate_mapping, candidate_sets,
                                            solve_point_weights)
from facetransfer.track.landmarks import (CALIBRATION_FILE, IBUG_WEIGHTS, MP_TO_IBUG,
                                          calibrated_matrix, mapping_matrix, mediapipe_to_ibug,
                                          read_correspondence, table_matrix)


def _doc() -> dict:
    return json.loads((resources.files("facetransfer") / "data" / CALIBRATION_FILE).read_text())


def test_the_data_file_loads_with_rows_summing_to_one_and_provenance():
    doc = _doc()
    assert [r["ibug"] for r in doc["points"]] == list(range(68))
    for r in doc["points"]:
        assert len(r["mediapipe"]) == len(r["weights"]) >= 1
        assert all(0 <= j < 468 for j in r["mediapipe"])
        assert sum(r["weights"]) == pytest.approx(1.0, abs=1e-9)
    prov = doc["provenance"]
    assert prov["script"] == "benchmarks/calibrate_landmarks.py" and prov["frames"] > 0
    # the calibration identities are not the benchmark's
    assert not {c["index"] for c in prov["clips"]} & set(prov["benchmark_indices_excluded"])
    A = calibrated_matrix(478)
    assert A.shape == (68, 478) and np.allclose(A.sum(axis=1), 1.0)
    assert np.array_equal(mapping_matrix(478), A)
    assert np.all(IBUG_WEIGHTS[:17] == 0.2)           # the jaw keeps its low fitting weight


def test_mapping_matches_the_file_weights_computed_by_hand():
    rng = np.random.default_rng(0)
    P = rng.uniform(0, 500, size=(478, 2))
    out = mediapipe_to_ibug(P)
    for r in _doc()["points"]:
        expect = sum(w * P[j] for j, w in zip(r["mediapipe"], r["weights"]))
        np.testing.assert_allclose(out[r["ibug"]], expect, rtol=0, atol=1e-9)
    # affine weights: the mapping commutes with an affine map of the image
    M, b = np.array([[1.3, 0.2], [-0.4, 0.9]]), np.array([12.0, -7.0])
    np.testing.assert_allclose(mediapipe_to_ibug(P @ M.T + b), out @ M.T + b, atol=1e-9)


def test_a_missing_mediapipe_point_makes_only_its_ibug_points_unknown():
    P = np.ones((2, 478, 2))
    A = calibrated_matrix(478)
    j = int(np.flatnonzero(A[30])[0])
    P[1, j] = np.nan
    out = mediapipe_to_ibug(P)
    assert np.isfinite(out[0]).all()
    unknown = np.isnan(out[1]).any(axis=1)
    np.testing.assert_array_equal(unknown, A[:, j] != 0)


def test_the_table_stays_available_as_the_origin():
    T = table_matrix(478)
    assert T[17, 70] == T[17, 46] == 0.5 and T[36, 33] == 1.0
    assert np.allclose(T.sum(axis=1), 1.0)


@pytest.mark.parametrize("bad, match", [
    ({"points": []}, "68 iBUG"),
    ({"nope": 1}, "not a correspondence"),
    ({"points": [{"ibug": i, "mediapipe": [i], "weights": [0.9]} for i in range(68)]},
     "summing to 1"),
    ({"points": [{"ibug": i, "mediapipe": [500], "weights": [1.0]} for i in range(68)]},
     "0..477"),
    ({"points": [{"ibug": 0, "mediapipe": [1], "weights": [1.0]} for i in range(68)]},
     "appear once"),
])
def test_a_malformed_correspondence_file_is_refused_naming_it(tmp_path, bad, match):
    p = tmp_path / "c.json"
    p.write_text(json.dumps(bad))
    with pytest.raises(FaceTransferError, match=match) as exc:
        read_correspondence(p, 478)
    assert "c.json" in str(exc.value)


def test_solver_recovers_a_planted_affine_mapping():
    """Points made by known affine weights (some negative) are solved back exactly; a large
    ridge pulls the weights to the prior instead."""
    rng = np.random.default_rng(3)
    F, c = 200, 6
    X = rng.normal(0, 50, size=(F, c, 2)) + rng.uniform(0, 400, size=(F, 1, 2))
    w_true = np.array([0.7, 0.5, -0.3, 0.25, -0.05, -0.1])
    t = np.einsum("fcd,c->fd", X, w_true) + rng.normal(0, 1e-3, size=(F, 2))
    s = rng.uniform(80, 120, F)
    w0 = np.array([1.0, 0, 0, 0, 0, 0])
    w = solve_point_weights(X, t, s, w0, ridge=1e-10)
    np.testing.assert_allclose(w, w_true, atol=1e-4)
    assert w.sum() == pytest.approx(1.0)
    w_big = solve_point_weights(X, t, s, w0, ridge=1e6)
    np.testing.assert_allclose(w_big, w0, atol=1e-3)
    with pytest.raises(ShapeError):
        solve_point_weights(X, t[:-1], s, w0, ridge=1.0)


def test_calibrate_mapping_recovers_planted_weights_per_point():
    rng = np.random.default_rng(5)
    F, n = 60, 20
    P = rng.normal(0, 40, size=(F, n, 2))
    cand = [np.array([i % n, (i + 1) % n, (i + 7) % n]) for i in range(68)]
    W = np.zeros((68, n))
    prior = np.zeros((68, n))
    for i, cd in enumerate(cand):
        W[i, cd] = [0.6, 0.6, -0.2]
        prior[i, cd[0]] = 1.0
    T = np.einsum("im,fmd->fid", W, P)
    P[3, 0] = np.nan                                    # a frame without a face is skipped
    s = np.full(F, 100.0)
    res = calibrate_mapping(P, T, s, cand, prior, ridge=1e-12, fixed=(5,))
    for i, r in enumerate(res):
        np.testing.assert_array_equal(r.indices, cand[i])
        expect = prior[i, cand[i]] if i == 5 else W[i, cand[i]]
        np.testing.assert_allclose(r.weights, expect, atol=1e-8)


def test_candidate_sets_add_the_nearest_canonical_vertices():
    C = np.zeros((468, 3))
    C[:, 0] = np.arange(468)
    table = [(10,), (20, 22)] + [(0,)] * 66
    cs = candidate_sets(C, table, k=3)
    assert cs[0].tolist() == [10, 9, 11, 8]          # the table's first, then by distance
    assert cs[1].tolist() == [20, 22, 21, 19, 23]    # around the mean of the table's two
    assert len(cs) == 68 and all(len(set(c.tolist())) == len(c) for c in cs)
    assert len(MP_TO_IBUG) == 68


# ------------------------------------------------------------------------------------ dense
def test_best_triangle_point_recovers_a_planted_surface_point():
    """Detections made from a known barycentric point of one triangle (projected vertices
    moving over frames) pick that triangle and those coordinates among distractors."""
    from facetransfer.track.calibration import best_triangle_point

    rng = np.random.default_rng(7)
    F, n = 80, 12
    V2 = rng.uniform(0, 300, size=(1, n, 2)) + rng.normal(0, 8, size=(F, n, 2))
    tris = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]])
    b = np.array([0.2, 0.5, 0.3])
    m = np.einsum("fkd,k->fd", V2[:, tris[2]], b)
    k, w, rms = best_triangle_point(V2, m, np.full(F, 100.0), tris)
    assert k == 2 and rms < 1e-9
    np.testing.assert_allclose(w, b, atol=1e-9)
    # a point outside every triangle is clipped onto the best one's boundary, weights >= 0
    k, w, _ = best_triangle_point(V2, m + 40.0, np.full(F, 100.0), tris)
    assert w.min() >= 0 and w.sum() == pytest.approx(1.0)
    with pytest.raises(ShapeError):
        best_triangle_point(V2, m, np.full(F, 100.0), np.zeros((0, 3), int))


def test_calibrated_dense_file_matches_the_facekit_face_only(arkit_model):
    """The packaged dense correspondence is used for FaceKit-topology models (the test model
    has the FaceKit face's triangles) and ignored for any other topology."""
    from dataclasses import replace

    from facetransfer.track.dense import (DENSE_CALIBRATION_FILE, calibrated_correspondence,
                                          faces_hash, mediapipe_correspondence)

    doc = json.loads((resources.files("facetransfer") / "data" / DENSE_CALIBRATION_FILE)
                     .read_text())
    m = arkit_model
    assert doc["faces_sha256"] == faces_hash(m.faces) and doc["n_vertices"] == m.n_vertices
    dc = calibrated_correspondence(m)
    assert dc is not None and len(dc.mp_index) == len(doc["mp_index"]) > 400
    np.testing.assert_allclose(dc.bary.sum(axis=1), 1.0, atol=1e-5)
    assert dc.bary.min() >= 0 and dc.triangles.max() < m.n_vertices
    assert mediapipe_correspondence(m) is not None
    np.testing.assert_array_equal(mediapipe_correspondence(m).triangles, dc.triangles)
    other = replace(m, faces=m.faces[:, ::-1].copy())
    assert calibrated_correspondence(other) is None

"""Unit tests of the tracker's parts (Vlasic et al. 2005, §5.1 Eq. (6)-(9), §5.2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facetransfer.errors import TrackError
from facetransfer.render import rotation_from_euler
from facetransfer.track import Track
from facetransfer.track.camera import Pose, compose, fit_affine_pose, project, so3_exp, so3_log
from facetransfer.track.init import check_init_points, fit_landmarks, load_init_points
from facetransfer.track.klt import (build_pyramid, klt_terms, klt_terms_at, sample_windows,
                                    solve_flow, window_offsets)
from facetransfer.track.landmarks import (IBUG_WEIGHTS, MP_TO_IBUG, REQUIRED_IBUG,
                                          eye_distance, mediapipe_to_ibug, table_matrix)
from facetransfer.track.solver import (FrameState, Prior, fit_points, full_jacobian,
                                       normal_equations, project_to_gauge, schur_reduce)


# ------------------------------------------------------------------------------------ helpers
def smooth_noise_pair(shift, size=(480, 640), sigma=2.0, seed=0):
    """A band-limited random texture and the same texture moved by ``shift`` (exact, Fourier).

    ``J(x) = I(x - shift)``: a point at ``q`` in ``I`` is at ``q + shift`` in ``J``.
    """
    H, W = size
    rng = np.random.default_rng(seed)
    F = np.fft.fft2(rng.standard_normal((H, W)))
    ky = np.fft.fftfreq(H)[:, None]
    kx = np.fft.fftfreq(W)[None, :]
    F *= np.exp(-(kx ** 2 + ky ** 2) * (2 * np.pi * sigma) ** 2 / 2)
    I = np.real(np.fft.ifft2(F))
    J = np.real(np.fft.ifft2(F * np.exp(-2j * np.pi * (kx * shift[0] + ky * shift[1]))))
    lo, sc = I.min(), 200.0 / np.ptp(I)
    return (I - lo) * sc + 20, (J - lo) * sc + 20


# ------------------------------------------------------------------------------------ Eq. (6)
def test_symmetric_klt_recovers_known_subpixel_shift():
    d = np.array([2.3, -1.7])
    I, J = smooth_noise_pair(d)
    pi, pj = build_pyramid(I, 3), build_pyramid(J, 3)
    q = np.random.default_rng(1).uniform(60, 400, (300, 2))
    p = solve_flow(pi, pj, q)
    err = p - q - d
    # cv2.remap quantises positions to 1/32 pixel; the median is unbiased
    assert np.all(np.abs(np.median(err, axis=0)) < 0.01)
    assert np.mean(np.linalg.norm(err, axis=1)) < 0.05


def test_one_klt_system_gives_the_shift_to_first_order():
    d = np.array([0.3, -0.2])
    I, J = smooth_noise_pair(d, sigma=3.0)
    pi, pj = build_pyramid(I, 1, blur=0), build_pyramid(J, 1, blur=0)
    off, w = window_offsets(6)
    q = np.random.default_rng(2).uniform(60, 400, (200, 2))
    wi = sample_windows(pi.levels[0], q, off)
    Z, e, _ = klt_terms_at(pj.levels[0], q, wi, off, w)   # guess p0 = q
    est = np.linalg.solve(Z, e[..., None])[..., 0]         # Z d = e, Eq. (6)
    assert np.allclose(np.median(est, axis=0), d, atol=0.02)


def test_fast_klt_terms_equal_the_reference():
    rng = np.random.default_rng(0)
    img = rng.random((60, 80, 3)).astype(np.float32)
    off, w = window_offsets(3)
    pts = rng.uniform(5, 50, (40, 2)).round()          # integer positions: remap is exact there
    wi = rng.random((40, off.shape[0], 3)).astype(np.float32)
    Z1, e1 = klt_terms(wi, sample_windows(img, pts, off), w)
    Z2, e2, Jint = klt_terms_at(img, pts, wi, off, w)
    assert np.allclose(Z1, Z2, atol=1e-6) and np.allclose(e1, e2, atol=1e-6)
    assert np.allclose(Jint, sample_windows(img, pts, off)[..., 0], atol=1e-6)


def test_structure_tensor_of_an_edge_constrains_only_across_it():
    x = np.arange(64, dtype=float)
    I = np.tile(1.0 / (1 + np.exp(-(x - 32) / 2.0)), (48, 1)) * 200  # vertical edge
    pyr = build_pyramid(I, 1)
    off, w = window_offsets(4)
    wi = sample_windows(pyr.levels[0], np.array([[32.0, 24.0]]), off)
    Z, _ = klt_terms(wi, wi, w)
    assert Z[0, 0, 0] > 1e-4
    assert abs(Z[0, 1, 1]) < 1e-9 * Z[0, 0, 0] and abs(Z[0, 0, 1]) < 1e-9 * Z[0, 0, 0]


# ------------------------------------------------------------------------------------ Eq. (7)
def test_pose_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    pose = Pose(rotation_from_euler(20, 10, 5), 3.0, np.array([5.0, 7.0]))
    B = rng.normal(size=(6, 3, 4))
    w = rng.normal(size=4)
    X = B @ w
    J = full_jacobian(X, B, pose)
    p0 = pose.project(X)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        assert np.allclose((compose(pose, d).project(X) - p0) / h, J[:, :, k], atol=1e-4)
    for k in range(4):
        w2 = w.copy()
        w2[k] += h
        assert np.allclose((pose.project(B @ w2) - p0) / h, J[:, :, 6 + k], atol=1e-5)


def test_so3_exp_log_round_trip_and_affine_pose_fit():
    v = np.array([0.3, -0.2, 0.5])
    assert np.allclose(so3_log(so3_exp(v)), v, atol=1e-12)
    R = rotation_from_euler(25, -10, 8)
    X = np.random.default_rng(0).normal(size=(30, 3))
    p = project(X, R, 4.0, np.array([100.0, 50.0]))
    pose = fit_affine_pose(X, p)
    assert np.allclose(pose.rotation, R, atol=1e-9) and abs(pose.scale - 4.0) < 1e-9
    assert np.allclose(pose.translation, [100.0, 50.0], atol=1e-9)


def test_schur_complement_gives_the_same_solution():
    rng = np.random.default_rng(0)
    M = rng.normal(size=(12, 12))
    A = M @ M.T + np.eye(12)
    b = rng.normal(size=12)
    S, c = schur_reduce(A, b, 6)
    assert np.allclose(np.linalg.solve(S, c), np.linalg.solve(A, b)[6:], atol=1e-8)


def test_normal_equations_equal_the_stacked_sum():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(5, 2, 4))
    L = rng.normal(size=(5, 2, 2))
    Z = L @ np.swapaxes(L, 1, 2)
    e = rng.normal(size=(5, 2))
    A, b = normal_equations(J, Z, e)
    assert np.allclose(A, sum(J[i].T @ Z[i] @ J[i] for i in range(5)))
    assert np.allclose(b, sum(J[i].T @ e[i] for i in range(5)))


# ------------------------------------------------------------------------------------ Eq. (8), (9)
def _truth_on_gauge(model, seed):
    """Weights between a training row and the mean, scaled onto each mode's gauge plane."""
    rng = np.random.default_rng(seed)
    w, s = {}, 12.0
    for k in model.mode_names:
        U = model.factors[model.mode_index(k)]
        x = 0.7 * U[rng.integers(U.shape[0])] + 0.3 * U.mean(0)
        P = Prior.from_model(model, k)
        a = np.linalg.svd(P.Q, full_matrices=True)[0][:, -1]   # normal of the gauge plane
        c = (a @ P.mean) / (a @ x)
        w[k], s = c * x, s / c                                  # same image, weights on gauge
        assert np.allclose(project_to_gauge(w[k], P), w[k], atol=1e-12)
    return w, s


@pytest.mark.parametrize("seed", [1, 2])
def test_solver_recovers_pose_and_weights_from_exact_point_motion(quick_model, seed):
    w_true, s = _truth_on_gauge(quick_model, seed)
    pose = Pose(rotation_from_euler(15, -8, 5), s, np.array([320.0, 240.0]))
    v = np.random.default_rng(seed).choice(quick_model.n_vertices, 400, replace=False)
    T = project(quick_model.synthesize(w_true, vertices=v), pose.rotation, pose.scale,
                pose.translation)
    st = fit_points(quick_model, v, T, prior=0.0, iterations=200)
    for k in quick_model.mode_names:
        assert np.abs(st.weights[k] - w_true[k]).max() < 1e-6
    assert abs(st.pose.scale - s) < 1e-6 * s
    assert np.abs(st.pose.rotation - pose.rotation).max() < 1e-6
    assert np.abs(st.pose.translation - pose.translation).max() < 1e-6


def test_solver_single_mode_is_one_linear_solve(quick_model):
    """With the identity fixed (Eq. (9)) pose + expression converge from the mean face."""
    w_true, s = _truth_on_gauge(quick_model, 3)
    pose = Pose(rotation_from_euler(-10, 5, -3), s, np.array([200.0, 150.0]))
    v = np.arange(0, quick_model.n_vertices, 17)
    T = project(quick_model.synthesize(w_true, vertices=v), pose.rotation, pose.scale,
                pose.translation)
    start_w = {"identity": w_true["identity"], "expression": quick_model.weight_mean("expression")}
    start = FrameState(fit_affine_pose(quick_model.synthesize(start_w, vertices=v), T), start_w)
    st = fit_points(quick_model, v, T, state=start, modes=("expression",), prior=0.0,
                    iterations=50)
    assert np.abs(st.weights["expression"] - w_true["expression"]).max() < 1e-6
    assert np.array_equal(st.weights["identity"], w_true["identity"])


# ------------------------------------------------------------------------------------ §5.2
def test_init_from_perfect_landmarks_recovers_the_pose(quick_model):
    w_true, s = _truth_on_gauge(quick_model, 4)
    R = rotation_from_euler(12, -6, 4)
    t = np.array([330.0, 250.0])
    L = project(quick_model.synthesize(w_true, vertices=quick_model.landmarks), R, s, t)
    st = fit_landmarks(quick_model, L)
    dR = st.pose.rotation @ R.T
    angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    assert angle < 2.0
    assert abs(st.pose.scale / s - 1) < 0.05
    Lf = project(quick_model.synthesize(st.weights, vertices=quick_model.landmarks),
                 st.pose.rotation, st.pose.scale, st.pose.translation)
    iod = np.linalg.norm(L[36] - L[45])
    assert np.linalg.norm(Lf - L, axis=1).mean() < 0.03 * iod


def test_init_points_validation(tmp_path):
    good = {str(i): [100.0 + i, 100.0] for i in REQUIRED_IBUG}
    pts = check_init_points(good, (640, 480))
    assert sorted(pts) == sorted(REQUIRED_IBUG)
    with pytest.raises(TrackError, match="too few points; missing 54"):
        check_init_points({k: v for k, v in good.items() if k != "54"}, (640, 480))
    with pytest.raises(TrackError, match="outside the 640x480 image"):
        check_init_points({**good, "36": [700.0, 10.0]}, (640, 480))
    with pytest.raises(TrackError, match="outside iBUG-68"):
        check_init_points({**good, "70": [1.0, 1.0]}, (640, 480))
    with pytest.raises(TrackError, match="must be \\[x, y\\]"):
        check_init_points({**good, "30": [1.0]}, (640, 480))
    p = tmp_path / "p.json"
    p.write_text("{not json")
    with pytest.raises(TrackError, match="not valid JSON"):
        load_init_points(p, (640, 480))
    p.write_text(json.dumps({"pts": good}))
    with pytest.raises(TrackError, match='must hold'):
        load_init_points(p, (640, 480))
    p.write_text(json.dumps({"points": good}))
    assert len(load_init_points(p, (640, 480))) == 7
    with pytest.raises(TrackError, match="does not exist"):
        load_init_points(tmp_path / "missing.json", (640, 480))


# ------------------------------------------------------------------------------------ table
def test_mediapipe_to_ibug_table():
    assert len(MP_TO_IBUG) == 68 and IBUG_WEIGHTS.shape == (68,)
    assert all(0 <= j < 478 for idx in MP_TO_IBUG for j in idx)
    documented = {33: 36, 133: 39, 362: 42, 263: 45, 4: 30, 61: 48, 291: 54}
    for mp, ib in documented.items():
        assert MP_TO_IBUG[ib] == (mp,)
    P = np.arange(478 * 2, dtype=float).reshape(478, 2)
    assert mediapipe_to_ibug(P).shape == (68, 2)
    out = table_matrix(478) @ P                  # the table (the calibration's origin)
    assert np.array_equal(out[36], P[33]) and np.allclose(out[17], (P[70] + P[46]) / 2)
    assert mediapipe_to_ibug(np.full((3, 478, 3), np.nan)).shape == (3, 68, 3)
    with pytest.raises(ValueError, match="478"):
        mediapipe_to_ibug(np.zeros((68, 2)))


def test_eye_distance_is_the_outer_corners_else_half_the_points_extent():
    L = np.full((68, 2), np.nan)
    assert eye_distance(L) == 1.0                      # no point at all
    L[36], L[45] = (10.0, 20.0), (13.0, 24.0)
    assert eye_distance(L) == 5.0                      # |p_36 - p_45|
    L[45], L[30] = np.nan, (10.0, 60.0)
    assert eye_distance(L) == 20.0                     # a corner missing: box 0 x 40, half
    L[45] = (10.2, 20.0)
    assert eye_distance(L) == 20.0                     # corners a pixel apart: degenerate, box
    L[:] = (5.0, 5.0)
    assert eye_distance(L) == 1.0                      # every point at one place


# ------------------------------------------------------------------------------------ Track
def _track(F=4, **kw):
    args = dict(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (F, 1, 1)),
                scale=np.full(F, 2.0), translation=np.zeros((F, 2)),
                weights={"identity": np.ones((F, 3)), "expression": np.zeros((F, 2))},
                landmarks2d=np.zeros((F, 68, 2)), confidence=np.linspace(0, 1, F),
                lost=np.array([False, True] * (F // 2)), model_hash="abc",
                mode_names=("identity", "expression"), source="clip.mp4")
    args.update(kw)
    return Track(**args)


def test_track_save_load_round_trip(tmp_path):
    t = _track()
    p = t.save(tmp_path / "t.npz")
    u = Track.load(p)
    assert u.n_frames == 4 and u.frame_size == (64, 48) and u.fps == 25.0
    assert u.mode_names == ("identity", "expression") and u.model_hash == "abc"
    assert u.source == "clip.mp4"
    for name in ("rotation", "scale", "translation", "landmarks2d", "confidence", "lost"):
        assert np.array_equal(getattr(u, name), getattr(t, name))
    assert np.array_equal(u.weights["expression"], t.weights["expression"])
    with np.load(p) as z:
        assert {"fps", "frame_size", "rotation", "scale", "translation", "weights_identity",
                "weights_expression", "landmarks2d", "confidence", "lost", "model_hash",
                "mode_names", "source"} <= set(z.files)
    cam = u.camera(1)
    assert cam.scale == 2.0 and np.array_equal(cam.rotation, np.eye(3))
    assert np.array_equal(u.weights_at(2)["identity"], np.ones(3))
    with pytest.raises(TrackError, match="outside"):
        u.camera(7)


def test_every_key_a_track_file_holds_is_in_its_documented_layout(tmp_path):
    """The file-format table of facetransfer.track.result (the TRACK.npz layout a researcher
    reads) lacked ``shot_starts``, which save writes for a clip of several shots."""
    import re

    from facetransfer.track import result

    names = tuple(f"s{i}" for i in range(52))
    t = _track(F=4, shot_starts=(2,), blendshapes=np.zeros((4, 52), np.float32),
               blendshape_names=names, detections2d=np.zeros((4, 68, 2)))
    with np.load(t.save(tmp_path / "t.npz")) as z:
        keys = {re.sub(r"^weights_.*", "weights_<mode>", k) for k in z.files}
    documented = set(re.findall(r"^``([a-z0-9_<>]+)``", result.__doc__, re.M))
    assert "shot_starts" in keys and keys <= documented, keys - documented


def test_track_validation_and_bad_files(tmp_path):
    with pytest.raises(TrackError, match="rotation"):
        _track(rotation=np.zeros((4, 2, 3)))
    with pytest.raises(TrackError, match="confidence"):
        _track(confidence=np.full(4, 2.0))
    with pytest.raises(TrackError, match="scale"):
        _track(scale=np.zeros(4))
    with pytest.raises(TrackError, match="modes"):
        _track(weights={"identity": np.ones((4, 3))})
    with pytest.raises(TrackError, match="landmarks2d"):
        _track(landmarks2d=np.zeros((4, 5, 2)))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(TrackError, match=r"bad.npz is not a track file \(not an .npz archive\)"):
        Track.load(bad)
    bad.write_bytes(b"PK\x03\x04 cut short")                 # a zip's start: damaged
    with pytest.raises(TrackError, match="truncated or not a track file"):
        Track.load(bad)
    # another kind of file, from this tool or beside its tracks: named (before: "truncated")
    for head, kind in ((b"Timecode,BlendShapeCount,EyeBlinkLeft\n", "a Live Link Face take"),
                       (b"glTF\x02\x00\x00\x00", "a glTF binary"),
                       (b"\x00\x00\x00\x20ftypisom", "a video")):
        bad.write_bytes(head + bytes(64))
        with pytest.raises(TrackError, match=f"is not a track file: it is {kind}"):
            Track.load(bad)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(TrackError, match="not a track file"):
        Track.load(tmp_path / "other.npz")
    with pytest.raises(TrackError, match="does not exist"):
        Track.load(tmp_path / "nope.npz")
    t = _track()
    with pytest.raises(TrackError, match="frames of 64x48"):
        t.check_video(4, (65, 48))
    with pytest.raises(TrackError, match="has 4 frames"):
        t.check_video(5, (64, 48))
    t.check_video(4, (64, 48))


def test_solver_cycles_through_three_modes(quick_model):
    """A trilinear model (identity x expression x viseme): coordinate descent over all modes."""
    from facetransfer.model import MultilinearModel

    rng = np.random.default_rng(7)
    n = 300
    base = quick_model.synthesize(quick_model.default_weights())[:n]      # a face-like shape
    core = np.zeros((3 * n, 3, 3, 3))
    core[:, 0, 0, 0] = base.ravel()                                      # mean face
    core += 0.3 * rng.normal(size=core.shape) * (np.arange(27).reshape(3, 3, 3) > 0)
    factors = tuple(np.c_[np.ones(4), 0.3 * rng.normal(size=(4, 2))] for _ in range(3))
    m = MultilinearModel(core=core, factors=factors,
                         mode_names=("identity", "expression", "viseme"),
                         labels=tuple(tuple(f"{k}{i}" for i in range(4)) for k in "iev"),
                         faces=np.array([[0, 1, 2]]), landmarks=np.arange(68))
    w_true = {k: np.r_[1.0, 0.2 * rng.normal(size=2)] for k in m.mode_names}  # on the gauge
    for k in m.mode_names:
        assert np.allclose(project_to_gauge(w_true[k], Prior.from_model(m, k)), w_true[k])
    R, s, t = rotation_from_euler(10, 5, -4), 7.0, np.array([50.0, 60.0])
    v = np.arange(n)
    T = project(m.synthesize(w_true, vertices=v), R, s, t)
    st = fit_points(m, v, T, prior=0.0, iterations=300)
    for k in m.mode_names:
        assert np.abs(st.weights[k] - w_true[k]).max() < 1e-6
    assert np.abs(st.pose.rotation - R).max() < 1e-6 and abs(st.pose.scale - s) < 1e-5

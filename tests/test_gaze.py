"""Gaze from the iris centres (facetransfer.track.gaze) and its hook in the capture tracker."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from facetransfer.arkit import ARKIT_NAMES
from facetransfer.errors import ShapeError
from facetransfer.render import rotation_from_euler
from facetransfer.track.capture import CaptureOptions, capture_detections
from facetransfer.track.detect import ClipDetections
from facetransfer.track.gaze import (EYE_RADIUS, GAZE_NAMES, IRIS_INDEX, IRIS_REST, MP_CORNER_INDEX,
                                     MP_LID_INDEX, GazeOptions, running_median,
                                     usable_iris,
                                     eye_model, frame_gaze_activations, gaze_activations,
                                     gaze_angles, project_iris)


def _face68(rng=None) -> np.ndarray:
    """68 points with FaceKit's generic eye corners (cm) and the rest random."""
    rng = rng or np.random.default_rng(0)
    P = rng.normal(size=(68, 3)) * 3
    P[36], P[39] = [-4.459, 3.432, 8.603], [-1.844, 3.252, 9.196]
    P[45], P[42] = [4.459, 3.432, 8.603], [1.844, 3.252, 9.196]
    return P


def _poses(F, yaw, pitch, roll, rng):
    R = np.stack([rotation_from_euler(y, p, r) for y, p, r in zip(yaw, pitch, roll)])
    return R, rng.uniform(8, 14, F), rng.uniform(150, 350, (F, 2))


def test_eye_model_puts_the_iris_at_rest_in_front_of_the_corners():
    P = _face68()
    eyes = eye_model(P)
    rest = eyes.centre + eyes.radius[:, None] * np.array([0, 0, 1.0])
    mid = np.stack([(P[36] + P[39]) / 2, (P[45] + P[42]) / 2])
    np.testing.assert_allclose(rest - mid, [[-IRIS_REST[0], IRIS_REST[1], IRIS_REST[2]],
                                            IRIS_REST], atol=1e-3)   # FaceKit's own eye width
    np.testing.assert_allclose(eyes.radius, EYE_RADIUS, rtol=1e-3)
    # a face twice as large has eyes twice as large
    np.testing.assert_allclose(eye_model(2 * P).radius, 2 * eyes.radius)
    with pytest.raises(ShapeError, match=r"\(68, 3\)"):
        eye_model(P[:50])


def test_gaze_angles_invert_the_projection_exactly_on_turned_heads():
    rng = np.random.default_rng(1)
    F = 200
    eyes = eye_model(_face68(rng))
    ang = rng.uniform(-0.6, 0.6, (F, 2, 2))
    R, s, t = _poses(F, rng.uniform(-40, 40, F), rng.uniform(-25, 25, F), rng.uniform(-20, 20, F),
                     rng)
    # keep the cases where the iris faces the camera (the visible root)
    d = np.einsum("fij,fej->fei", R, np.stack([np.sin(ang[..., 0]) * np.cos(ang[..., 1]),
                                               np.sin(ang[..., 1]),
                                               np.cos(ang[..., 0]) * np.cos(ang[..., 1])], -1))
    keep = (d[..., 2] > 0.05).all(1)
    assert keep.sum() > 150
    iris = project_iris(eyes, ang, R, s, t)
    est = gaze_angles(eyes, iris[keep], R[keep], s[keep], t[keep])
    np.testing.assert_allclose(est, ang[keep], atol=1e-6)


def _naive_offset(P, iris, R, s, t):
    """The left iris's 2-D offset from its corners' midpoint along the eye axis / eye width."""
    Y = P @ R[:2].T * s
    Y[:, 1] *= -1
    Y += t
    o, i = Y[45], Y[42]
    w = np.linalg.norm(o - i)
    return float((iris - (o + i) / 2) @ (o - i) / w ** 2)


def test_a_turned_head_biases_the_2d_offset_but_not_the_angles():
    """Eyes straight ahead on a head turned 30°: in the image the iris moves along the eye
    axis by ~0.1 eye width, the angles stay 0."""
    P = _face68()
    eyes = eye_model(P)
    s, t = np.array([10.0]), np.array([[256.0, 256.0]])
    off = {}
    for yaw in (0.0, 30.0):
        R = rotation_from_euler(yaw, 0, 0)[None]
        iris = project_iris(eyes, np.zeros((1, 2, 2)), R, s, t)
        off[yaw] = _naive_offset(P, iris[0, 1], R[0], s[0], t[0])
        np.testing.assert_allclose(gaze_angles(eyes, iris, R, s, t), 0.0, atol=1e-9)
    assert abs(off[30.0] - off[0.0]) > 0.08


def test_activation_signs_follow_arkit():
    ang = np.zeros((3, 2, 2))
    ang[0, :, 0] = np.deg2rad(15)    # both eyes toward the subject's left
    ang[1, :, 1] = np.deg2rad(-50)    # both down, beyond the range
    ang[2] = np.nan
    opt = GazeOptions(horizontal=np.deg2rad(30), vertical=np.deg2rad(25))
    a = gaze_activations(ang, opt)
    assert set(a) == set(GAZE_NAMES) and set(GAZE_NAMES) <= set(ARKIT_NAMES)
    assert a["eyeLookOutLeft"][0] == pytest.approx(0.5)
    assert a["eyeLookInRight"][0] == pytest.approx(0.5)
    assert a["eyeLookInLeft"][0] == 0 and a["eyeLookOutRight"][0] == 0
    assert a["eyeLookUpLeft"][0] == 0 and a["eyeLookDownRight"][0] == 0
    assert a["eyeLookDownLeft"][1] == 1.0 and a["eyeLookDownRight"][1] == 1.0   # clipped
    assert a["eyeLookUpLeft"][1] == 0 and a["eyeLookOutLeft"][1] == 0
    assert all(np.isnan(v[2]) for v in a.values())
    # a closed eye keeps its horizontal gaze, its vertical one is left to the lids
    c = gaze_activations(ang, opt, closed=np.array([[True, False]] * 3))
    assert c["eyeLookInRight"][0] == a["eyeLookInRight"][0] and np.isnan(c["eyeLookDownRight"][1])
    assert c["eyeLookDownLeft"][1] == 1.0


def test_activation_gaze_inverts_gaze_activations():
    from facetransfer.track.gaze import activation_gaze

    rng = np.random.default_rng(3)
    ang = rng.uniform(-1, 1, (40, 2, 2)) * np.deg2rad([30.0, 24.0])  # inside the range
    opt = GazeOptions(horizontal=np.deg2rad(30), vertical=np.deg2rad(25))
    a = gaze_activations(ang, opt)
    A = np.zeros((40, len(ARKIT_NAMES)))
    for n, v in a.items():
        A[:, ARKIT_NAMES.index(n)] = v
    np.testing.assert_allclose(activation_gaze(A, opt), ang, atol=1e-12)
    with pytest.raises(ValueError, match=r"\(F, 52\)"):
        activation_gaze(A[:, :51])


def _iris_clip(model, gaze_of_frame, F=30):
    """Exact detections of a neutral training face on a turning head, with iris centres placed
    by the eye model of its own landmarks; returns detections and the true angles."""
    w = {"identity": model.training_weights("identity", "id02"),
         "expression": model.training_weights("expression", "neutral")}
    X = model.synthesize(w, vertices=model.landmarks)
    eyes = eye_model(X)
    rng = np.random.default_rng(3)
    t_ = np.arange(F)
    R, s, t = _poses(F, 25 * np.sin(t_ / 6), 5 * np.cos(t_ / 5), np.zeros(F), rng)
    s[:] = 9.0
    t[:] = [256.0, 240.0]
    ang = gaze_of_frame(t_)
    pts = np.einsum("fij,nj->fni", R[:, :2], X) * 9.0
    pts[..., 1] *= -1
    pts += t[:, None]
    mp = np.full((F, 478, 2), np.nan)
    mp[:, list(IRIS_INDEX)] = project_iris(eyes, ang, R, s, t)
    flow = np.full_like(pts, np.nan)
    flow[1:] = pts[1:] - pts[:-1]
    return ClipDetections(pts, flow, mp), ang


def test_capture_takes_eyelook_from_the_iris(arkit_model):
    def gaze(t):
        a = np.zeros((len(t), 2, 2))
        a[..., 0] = np.deg2rad(20) * np.sin(t / 4)[:, None]
        a[..., 1] = np.deg2rad(15) * np.cos(t / 3)[:, None]
        return a

    opt = CaptureOptions(dense=0.0, identity_frames=6, identity_rounds=2)
    det, ang = _iris_clip(arkit_model, gaze)
    on = capture_detections(det, arkit_model, options=opt)
    off = capture_detections(det, arkit_model, options=replace(opt, gaze=False))
    want = gaze_activations(ang)
    for n in GAZE_NAMES:
        k = ARKIT_NAMES.index(n)
        # the fitted face and pose are not exact: close, not equal
        assert np.abs(on.blendshapes[:, k] - want[n]).max() < 0.1, n
        assert np.abs(off.blendshapes[:, k] - want[n]).max() > 0.3, n   # the lids do not say it
    # the eyeLook shapes move the lids: the other shapes take that back, the eyes still fit
    eyes = np.arange(36, 48)
    iod = np.linalg.norm(det.points[:, 36] - det.points[:, 45], axis=1)
    err = np.linalg.norm(on.landmarks2d[:, eyes] - det.points[:, eyes], axis=2).mean(1) / iod
    assert np.median(err) < 0.02
    # without iris points (footage without MediaPipe's iris) the fit is the lids' alone
    none = ClipDetections(det.points, det.flow, np.where(np.isin(np.arange(478), IRIS_INDEX)[
        None, :, None], np.nan, det.points478))
    blind = capture_detections(none, arkit_model, options=opt)
    np.testing.assert_array_equal(blind.blendshapes, off.blendshapes)
    np.testing.assert_array_equal(blind.landmarks2d, off.landmarks2d)


def test_capture_leaves_models_without_arkit_names_alone(quick_model):
    det, _ = _iris_clip(quick_model, lambda t: np.full((len(t), 2, 2), 0.2), F=12)
    a = capture_detections(det, quick_model, options=CaptureOptions(dense=0.0))
    b = capture_detections(det, quick_model, options=CaptureOptions(dense=0.0, gaze=False))
    assert a.blendshapes is None
    for m in a.weights:
        np.testing.assert_array_equal(a.weights[m], b.weights[m])
    np.testing.assert_array_equal(a.landmarks2d, b.landmarks2d)


def test_usable_iris_bridges_closed_eyes():
    F = 40
    P = np.zeros((F, 478, 2))
    for (o, i), (u, lo), c in zip(MP_CORNER_INDEX, MP_LID_INDEX, IRIS_INDEX):
        P[:, o], P[:, i] = [0.0, 0.0], [30.0, 0.0]        # eye width 30 px
        P[:, u], P[:, lo] = [15.0, -5.0], [15.0, 5.0]     # lid gap 10 px
        P[:, c] = [15.0, 1.0]
    P[4, 468] = [17.0, 1.0]                               # the right eye turns a little...
    P[3, 159], P[3, 145] = [15.0, -1.0], [15.0, 1.0]      # ...after a blink in frame 3
    P[3, 468] = [15.0, 4.0]                               # where its iris slid down
    P[10:22, 386], P[10:22, 374] = [15.0, -1.0], [15.0, 1.0]   # the left eye shut 12 frames
    P[6] = np.nan                                         # no face in frame 6
    iris, closed = usable_iris(P, max_gap=3)
    assert closed[3].tolist() == [True, False] and closed[10:22, 1].all()
    assert closed.sum() == 13
    assert np.isnan(usable_iris(P, max_gap=0)[0][3, 0]).all()      # not bridged
    np.testing.assert_allclose(iris[3, 0], [16.0, 1.0])   # offset interpolated from 2 and 4
    np.testing.assert_allclose(iris[3, 1], [15.0, 1.0])
    assert np.isnan(iris[6]).all()
    np.testing.assert_allclose(iris[[10, 12, 19, 21], 1], [[15.0, 1.0]] * 4)
    assert np.isnan(iris[13:19, 1]).all()                  # too far from an open frame
    keep = np.setdiff1d(np.arange(F), [3, 6])
    np.testing.assert_array_equal(iris[keep, 0], P[keep, 468])
    with pytest.raises(ShapeError, match="478"):
        usable_iris(P[:, :468])


def test_running_median_is_scipys_median_filter_to_the_bit():
    """usable_iris' running median without scipy.ndimage: SciPy's nearest-mode median filter
    on windows odd and even, longer and shorter than the series, ties and all."""
    from scipy.ndimage import median_filter

    np.testing.assert_array_equal(running_median(np.array([5.0, 1.0, 4.0, 2.0, 3.0]), 3),
                                  [5.0, 4.0, 2.0, 3.0, 3.0])
    # an even window takes the upper middle value and sits a sample early, as SciPy's
    np.testing.assert_array_equal(running_median(np.array([1.0, 3.0, 2.0, 4.0]), 2),
                                  [1.0, 3.0, 3.0, 4.0])
    rng = np.random.default_rng(3)
    for n, size in [(1, 1), (1, 31), (7, 31), (40, 31), (300, 31), (50, 2), (50, 8), (9, 9)]:
        for x in (rng.normal(size=n), rng.integers(0, 3, n).astype(float)):
            np.testing.assert_array_equal(running_median(x, size),
                                          median_filter(x, size=size, mode="nearest"))
    with pytest.raises(ShapeError, match="window"):
        running_median(np.ones(5), 0)


def test_running_median_of_nothing_and_beside_a_nan():
    """An empty series is an empty result, as SciPy's median filter gives (it was NumPy's
    "can't extend empty axis 0" from the padding); a NaN ranks above every number, as the
    docstring says (SciPy's result there depends on the NaN's place: no reference)."""
    from scipy.ndimage import median_filter

    for x in (np.zeros(0), np.zeros(0, np.int64)):
        got = running_median(x, 31)
        want = median_filter(x, size=31, mode="nearest")
        assert got.shape == want.shape == (0,) and got.dtype == want.dtype
    np.testing.assert_array_equal(running_median(np.array([np.nan, 1.0, 2.0]), 3),
                                  [np.nan, 2.0, 2.0])
    np.testing.assert_array_equal(running_median(np.array([np.nan, 1.0, 2.0, 3.0]), 2),
                                  [np.nan, np.nan, 2.0, 3.0])


def test_the_capture_and_its_iris_leave_scipy_ndimage_unimported():
    """A tracking process (the capture, its kernels, usable_iris on a clip) does not import
    scipy.ndimage (0.06 CPU-s) for the lid gap's running median."""
    import subprocess
    import sys

    code = ("import sys; import numpy as np; from facetransfer.track.capture import load_kernels; "
            "from facetransfer.track.gaze import usable_iris; load_kernels(); "
            "usable_iris(np.random.default_rng(0).uniform(0, 99, (40, 478, 2))); "
            "print('scipy.ndimage' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_a_closing_eye_leaves_its_lids_to_the_blink(arkit_model):
    """The fit holds a closed eye's vertical gaze at 0 and writes its bridged value after."""
    from facetransfer.track.camera import Pose
    from facetransfer.track.capture_frame import gaze_fixed
    from facetransfer.track.capture_points import Sampler, Shape

    m = arkit_model
    shape = Shape(m, m.training_weights("identity", "id02"), Sampler(m), CaptureOptions())
    x = np.zeros(shape.size)
    eyes = eye_model(shape.points(x)[:68])
    pose = Pose(rotation_from_euler(20, 5, 0), 9.0, np.array([256.0, 240.0]))
    ang = np.deg2rad([[[10.0, -14.0], [10.0, -14.0]]])                 # left and down
    iris = project_iris(eyes, ang, pose.rotation[None], np.array([9.0]), pose.translation[None])
    held, after = gaze_fixed(shape, pose, x, (iris[0], np.array([True, False])))
    want = gaze_activations(ang)
    for n, k in zip(GAZE_NAMES, shape.gaze_k):
        assert after[k] == pytest.approx(want[n][0], abs=1e-9), n
        closed_vertical = n.endswith("Right") and ("Up" in n or "Down" in n)
        assert held[k] == (0.0 if closed_vertical else pytest.approx(want[n][0], abs=1e-9)), n
    assert want["eyeLookDownRight"][0] > 0.4 and want["eyeLookOutLeft"][0] > 0.2
    others = np.setdiff1d(np.arange(shape.size), shape.gaze_k)
    assert np.isnan(held[others]).all() and np.isnan(after[others]).all()


def test_frame_gaze_activations_match_the_vectorised_path():
    """The compiled one-frame path equals eye_model + gaze_angles + gaze_activations (closed
    eyes, unknown irises, irises off the eyeball's silhouette included)."""
    rng = np.random.default_rng(7)
    opt = GazeOptions(horizontal=0.5, vertical=0.4)
    for trial in range(60):
        P = _face68(rng)
        R = rotation_from_euler(*rng.uniform(-35, 35, 3))
        s, t = rng.uniform(5, 15), rng.normal(size=2) * 50 + 250
        eyes = eye_model(P)
        noise = 5.0 if trial % 3 == 0 else 0.05            # 5 px: beyond the silhouette
        iris = project_iris(eyes, rng.normal(size=(1, 2, 2)) * 0.4, R[None], np.array([s]),
                            t[None])[0] + rng.normal(size=(2, 2)) * noise
        if trial % 5 == 0:
            iris[trial % 2] = np.nan
        closed = rng.uniform(size=2) < 0.3
        ang = gaze_angles(eyes, iris[None], R[None], np.array([s]), t[None])
        free, held = frame_gaze_activations(P, iris, closed, R, s, t, opt)
        for got, want in ((free, gaze_activations(ang, opt)),
                          (held, gaze_activations(ang, opt, closed=closed[None]))):
            want = np.array([want[n][0] for n in GAZE_NAMES])
            np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
            # on the silhouette the depth is sqrt(1 - |q|^2) of |q| = 1 up to round-off
            np.testing.assert_allclose(got, want, atol=1e-6 if noise > 1 else 1e-12)
    with pytest.raises(ShapeError, match="68"):
        frame_gaze_activations(P[:60], iris, closed, R, s, t)

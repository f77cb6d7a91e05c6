"""Tests of facetransfer.synth: performance specs, clips with exact truth, clip files."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from facetransfer.datasets import FaceDataset
from facetransfer.errors import FaceTransferError
from facetransfer.model import build_model
from facetransfer.render import WeakPerspective, euler_from_rotation, rasterize
from facetransfer.synth import (
    SpecError,
    load_performance,
    load_truth,
    make_clip,
    performance_from_spec,
    procedural_background,
    procedural_skin_texture,
    procedural_vertex_colors,
    random_performance,
    synthesize_video,
    truth_path,
    write_clip,
)

EXPRESSIONS = ("neutral", "smile", "open", "frown")


def tiny_dataset(nr: int = 24, nc: int = 20, n_id: int = 4, seed: int = 0) -> FaceDataset:
    """A face-like cap (front facing +z, y up) with identity and expression variation."""
    rng = np.random.default_rng(seed)
    u = np.linspace(-1.1, 1.1, nc)
    v = np.linspace(-1.2, 1.2, nr)
    U, Vv = np.meshgrid(u, v)
    base = np.stack([np.sin(U) * np.cos(0.8 * Vv), 1.3 * np.sin(0.8 * Vv),
                     np.cos(U) * np.cos(0.8 * Vv)], -1).reshape(-1, 3) * 10.0
    i = (np.arange(nr - 1)[:, None] * nc + np.arange(nc - 1)[None]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + nc + 1], 1),
                            np.stack([i, i + nc + 1, i + nc], 1)])
    uvs = np.stack([(U.ravel() + 1.1) / 2.2, (Vv.ravel() + 1.2) / 2.4], 1)
    y = base[:, 1]
    x = base[:, 0]
    mouth = np.exp(-((y + 6) ** 2 + x ** 2) / 8.0)
    brow = np.exp(-((y - 6) ** 2) / 4.0)
    offsets = {"neutral": np.zeros_like(base),
               "smile": mouth[:, None] * np.stack([0.6 * np.sign(x), 0.8 + 0 * x, 0 * x], 1),
               "open": mouth[:, None] * np.array([0.0, -2.0, -0.5]),
               "frown": brow[:, None] * np.array([0.0, -1.0, 0.3])}
    ids = [base * (1 + 0.1 * rng.normal(size=3)) for _ in range(n_id)]
    verts = np.stack([np.stack([b + offsets[e] for e in EXPRESSIONS]) for b in ids])
    lm = np.sort(rng.choice(np.arange(nc * 3, nc * (nr - 3)), 68, replace=False))
    return FaceDataset(verts, np.ones((n_id, len(EXPRESSIONS)), bool), ("identity", "expression"),
                       (tuple(f"id{k}" for k in range(n_id)), EXPRESSIONS), faces, uvs, lm,
                       None, {"dataset": "tiny-cap", "seed": seed})


@pytest.fixture(scope="module")
def tiny_model():
    return build_model(tiny_dataset(), {"identity": 3, "expression": 4})


# ------------------------------------------------------------------------------- specs

def test_spec_keyframes_hit_training_rows_and_hold(tiny_model):
    m = tiny_model
    spec = {"n_frames": 30, "size": [96, 80], "identity": "id2",
            "tracks": {"expression": [[5, "smile"], [15, {"open": 0.5}], [25, "frown"]]}}
    perf = performance_from_spec(m, spec)
    W = perf.weights["expression"]
    assert W.shape == (30, 4) and perf.n_frames == 30 and perf.size == (96, 80)
    smile, frown = m.training_weights(1, "smile"), m.training_weights(1, "frown")
    neutral, opn = m.training_weights(1, "neutral"), m.training_weights(1, "open")
    np.testing.assert_allclose(W[:6], np.tile(smile, (6, 1)))  # held before the first key
    np.testing.assert_allclose(W[15], neutral + 0.5 * (opn - neutral))  # blend from neutral
    np.testing.assert_allclose(W[25:], np.tile(frown, (5, 1)))  # held after the last key
    np.testing.assert_allclose(W[10], 0.5 * (smile + W[15]))  # smoothstep(1/2) = 1/2
    np.testing.assert_allclose(perf.weights["identity"], np.tile(m.training_weights(0, "id2"),
                                                                 (30, 1)))
    # no pose: the same frontal camera in every frame
    np.testing.assert_allclose(perf.rotation, np.tile(np.eye(3), (30, 1, 1)), atol=1e-12)
    assert np.ptp(perf.scale) == 0 and np.ptp(perf.translation, axis=0).max() == 0


def test_spec_pose_oscillation_and_keys(tiny_model):
    perf = performance_from_spec(tiny_model, {"n_frames": 100, "fps": 25,
                                              "pose": {"yaw_deg": 10, "translate_px": 5,
                                                       "period_s": 4.0}})
    yaw = np.array([euler_from_rotation(R)[0] for R in perf.rotation])
    np.testing.assert_allclose(yaw, 10 * np.sin(2 * np.pi * np.arange(100) / 25 / 4.0),
                               atol=1e-9)
    keyed = performance_from_spec(tiny_model, {"pose": {"keys": [
        [0, {"yaw_deg": 0}], [10, {"yaw_deg": 20, "roll_deg": -5, "tx": 3, "scale": 1.1}]]}})
    assert keyed.n_frames == 11
    np.testing.assert_allclose(euler_from_rotation(keyed.rotation[10]), (20, 0, -5), atol=1e-9)
    assert keyed.scale[10] == pytest.approx(1.1 * keyed.scale[0])


def test_spec_from_json_file(tiny_model, tmp_path):
    p = tmp_path / "perf.json"
    p.write_text(json.dumps({"n_frames": 4, "identity": [0.5, 0.1, 0.0]}))
    perf = load_performance(tiny_model, p)
    np.testing.assert_array_equal(perf.weights["identity"][0], [0.5, 0.1, 0.0])
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(SpecError, match="not valid JSON"):
        load_performance(tiny_model, tmp_path / "bad.json")
    with pytest.raises(SpecError, match="does not exist"):
        load_performance(tiny_model, tmp_path / "missing.json")


@pytest.mark.parametrize("spec, match", [
    ({"tracks": {"viseme": [[0, "aa"]]}}, "unknown mode"),
    ({"tracks": {"expression": [[0, "grin"]]}}, "unknown expression"),
    ({"tracks": {"expression": [[0, [1.0, 2.0]]]}}, "4 finite weights"),
    ({"tracks": {"expression": [[-1, "smile"]]}}, ">= 0"),
    ({"tracks": {"expression": [["x", "smile"]]}}, "integer"),
    ({"tracks": {"expression": []}}, "non-empty"),
    ({"tracks": {"identity": [[0, "id0"]]}}, "constant"),
    ({"identity": "nobody"}, "unknown identity"),
    ({"colour": 1}, "unknown performance spec key"),
    ({"pose": {"wobble": 1}}, "unknown pose key"),
    ({"size": [0, 10]}, "size"),
    ({"fps": -1}, "fps"),
    ({"n_frames": 0}, "n_frames"),
    ([1, 2], "JSON object"),
    ({"fps": "fast"}, "fps must be a finite number"),
    ({"n_frames": 2.5}, "integer"),
    ({"pose": [1]}, "pose must be an object"),
    ({"pose": {"yaw_deg": "left"}}, "pose.yaw_deg"),
    ({"pose": {"keys": [[0, {"yaw_deg": None}]]}}, "yaw_deg"),
    ({"pose": {"keys": [[0, {"nod": 1}]]}}, "expected an object"),
    ({"pose": {"fill": 0}}, "fill"),
    # a blend's amount NaN or infinite: the spec passed and the clip failed later with
    # "vertices contain NaN" or "camera scale must be ... got nan", naming neither file nor key
    ({"tracks": {"expression": [[0, {"smile": float("nan")}]]}},
     r"tracks.expression frame 0: amount of 'smile' must be a finite number, got nan"),
    ({"tracks": {"expression": [[0, {"smile": float("inf")}]]}}, "finite number, got inf"),
    ({"identity": {"id1": float("nan")}}, r"identity: amount of 'id1' must be a finite"),
    ({"tracks": {"expression": [[0, {"smile": "lots"}]]}}, "amount of 'smile'"),
    # an identity of 1e300 (finite) failed late: "all 18461 triangles are degenerate (zero
    # area)", naming neither spec nor key; 1e308 overflowed the face
    ({"identity": {"id1": 1e300}}, r"identity: weights of mode 'identity' reach 6.74e\+299"),
    ({"identity": [1e300, 0.0, 0.0]}, r"identity: weights of mode 'identity'.*1000 times"),
    ({"tracks": {"expression": [[0, {"smile": 1e308}]]}},
     r"tracks.expression frame 0: weights of mode 'expression' reach"),
    # a keyframe at frame 1.5 was read as frame 1 without a word (NaN was refused)
    ({"tracks": {"expression": [[1.5, "smile"]]}}, r"frame must be an integer, got 1.5"),
    ({"pose": {"keys": [[2.5, {"yaw_deg": 1}]]}}, r"frame must be an integer, got 2.5"),
    # a keyframe at frame Infinity (JSON's) printed an OverflowError traceback
    ({"tracks": {"expression": [[float("inf"), "smile"]]}}, "frame must be an integer, got inf"),
])
def test_bad_specs_rejected(tiny_model, spec, match):
    with pytest.raises(SpecError, match=match) as err:
        performance_from_spec(tiny_model, spec)
    # where in the spec, said once (a blend's amount said "identity: identity: amount ...")
    assert not re.match(r"(.+?): \1:", str(err.value)), err.value



def test_the_spec_and_frames_share_one_limit(tiny_model):
    """The spec's n_frames was limited to 100000 and --frames to 1000000: a spec of 200000
    frames was refused that the command line wrote; a keyframe at frame 150000 (n_frames
    left to it) was refused with "n_frames must be between 1 and 100000"."""
    from facetransfer.synth import _spec_n_frames
    from facetransfer.synth_keys import MAX_FRAMES

    from facetransfer.cli import render

    assert render.MAX_FRAMES is MAX_FRAMES     # synth-video --frames' limit
    assert _spec_n_frames({"n_frames": 200_000}, -1) == 200_000
    assert _spec_n_frames({}, 149_999) == 150_000
    with pytest.raises(SpecError, match=f"between 1 and {MAX_FRAMES}"):
        _spec_n_frames({"n_frames": MAX_FRAMES + 1}, -1)


def test_random_performance_is_seeded_and_gentle(tiny_model):
    a = random_performance(tiny_model, 60, seed=3, size=(96, 80))
    b = random_performance(tiny_model, 60, seed=3, size=(96, 80))
    c = random_performance(tiny_model, 60, seed=4, size=(96, 80))
    for m in tiny_model.mode_names:
        np.testing.assert_array_equal(a.weights[m], b.weights[m])
    np.testing.assert_array_equal(a.rotation, b.rotation)
    assert not np.allclose(a.weights["expression"], c.weights["expression"])
    angles = np.array([euler_from_rotation(R) for R in a.rotation])
    assert np.all(np.abs(angles) <= [8.0 + 1e-9, 5.0 + 1e-9, 3.0 + 1e-9])
    # smooth: frame-to-frame changes are small compared to the range
    dw = np.abs(np.diff(a.weights["expression"], axis=0)).max()
    assert dw < 0.5 * np.ptp(a.weights["expression"], axis=0).max()
    # weights stay between the mode's base and its training rows (box of the training factor)
    U = tiny_model.factors[1]
    assert np.all(a.weights["expression"] >= U.min(axis=0) - 1e-9)
    assert np.all(a.weights["expression"] <= U.max(axis=0) + 1e-9)


# ------------------------------------------------------------------------------- clips

def test_truth_landmarks_are_projected_model_landmarks(tiny_model):
    m = tiny_model
    perf = random_performance(m, 6, seed=1, size=(96, 80))
    clip = make_clip(m, perf, seed=2)
    tr = clip.truth
    assert clip.frames.shape == (6, 80, 96, 3) and clip.frames.dtype == np.uint8
    assert tr.landmarks2d.shape == (6, 68, 2) and tr.visible.shape == (6, m.n_vertices)
    for f in range(6):
        V = m.synthesize({k: w[f] for k, w in tr.weights.items()})
        cam = WeakPerspective(tr.scale[f], tr.rotation[f], tr.translation[f])
        np.testing.assert_allclose(tr.landmarks2d[f], cam.project(V[m.landmarks]), atol=1e-9)
        np.testing.assert_allclose(tr.vertices2d[f], cam.project(V), atol=1e-9)
    assert tr.visible.mean() > 0.8  # a gently moving convex cap: most vertices visible


def test_frame_has_face_pixels_exactly_where_the_mesh_projects(tiny_model):
    m = tiny_model
    perf = performance_from_spec(m, {"n_frames": 1, "size": [120, 100],
                                     "pose": {"keys": [[0, {"yaw_deg": 15, "pitch_deg": -5}]]}})
    bg = (0, 0, 255)
    clip = make_clip(m, perf, background=bg, seed=0)
    V = m.synthesize(perf.frame_weights(0))
    mask = rasterize(V, m.faces, perf.camera(0), (120, 100)).mask
    img = clip.frames[0]
    assert mask.sum() > 2000
    assert np.all(img[~mask] == np.array(bg, np.uint8))
    assert np.all(np.any(img[mask] != np.array(bg, np.uint8), axis=1))
    # the procedural texture gives the face gradients (KLT needs them) but no aliasing
    face = img[mask].astype(float)
    assert 3.0 < face[:, 0].std() < 60.0


def test_vertex_colour_fallback_without_uvs(tiny_model):
    from dataclasses import replace

    m = replace(tiny_model, uvs=None)
    perf = performance_from_spec(m, {"n_frames": 1, "size": [64, 64]})
    clip = make_clip(m, perf, background=(0, 0, 0))
    assert clip.frames[0].any()
    cols = procedural_vertex_colors(m.synthesize(m.default_weights()), landmarks=m.landmarks)
    assert cols.shape == (m.n_vertices, 3) and cols.dtype == np.uint8 and cols.std() > 2
    with pytest.raises(SpecError, match="UVs"):
        make_clip(m, perf, texture=np.zeros((8, 8, 3), np.uint8))


def test_procedural_images_are_seeded():
    a = procedural_skin_texture(size=64, seed=1)
    assert a.shape == (64, 64, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, procedural_skin_texture(size=64, seed=1))
    assert not np.array_equal(a, procedural_skin_texture(size=64, seed=2))
    bg = procedural_background((50, 40), seed=0)
    assert bg.shape == (40, 50, 3) and bg.std() > 5


def test_write_clip_round_trip(tiny_model, tmp_path):
    import cv2

    perf = random_performance(tiny_model, 5, seed=0, size=(64, 48), fps=10)
    clip = make_clip(tiny_model, perf)
    video, tpath = write_clip(clip, tmp_path / "clip.mp4")
    assert tpath == tmp_path / "clip.truth.npz" == truth_path(video)
    cap = cv2.VideoCapture(str(video))
    n = 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        assert frame.shape == (48, 64, 3)
        n += 1
    cap.release()
    assert n == 5
    tr = load_truth(video)
    assert tr.fps == 10 and tr.frame_size == (64, 48)
    for name in ("rotation", "scale", "translation", "landmarks2d", "vertices2d", "visible"):
        np.testing.assert_array_equal(getattr(tr, name), getattr(clip.truth, name))
    assert list(tr.weights) == ["identity", "expression"]
    np.testing.assert_array_equal(tr.weights["expression"], clip.truth.weights["expression"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4", "clip.truth.npz"]


def test_synthesize_video_streams_same_truth(tiny_model, tmp_path):
    perf = random_performance(tiny_model, 4, seed=5, size=(64, 48))
    ticks = []
    truth = synthesize_video(tiny_model, perf, tmp_path / "s.mp4", seed=1, progress=ticks.append)
    assert ticks == [1, 1, 1, 1]
    ref = make_clip(tiny_model, perf, seed=1).truth
    np.testing.assert_array_equal(truth.visible, ref.visible)
    np.testing.assert_allclose(load_truth(tmp_path / "s.truth.npz").landmarks2d, ref.landmarks2d)


def test_bad_outputs_rejected(tiny_model, tmp_path):
    perf = random_performance(tiny_model, 2, seed=0, size=(32, 32))
    clip = make_clip(tiny_model, perf)
    with pytest.raises(FaceTransferError, match="does not exist"):
        write_clip(clip, tmp_path / "nope" / "clip.mp4")
    with pytest.raises(FaceTransferError, match="mp4"):
        synthesize_video(tiny_model, perf, tmp_path / "clip.png")
    with pytest.raises(FaceTransferError, match="does not exist"):
        load_truth(tmp_path / "missing.mp4")
    with pytest.raises(SpecError, match="background"):
        make_clip(tiny_model, perf, background=np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(SpecError, match="0..255"):
        make_clip(tiny_model, perf, background=(0, 300, 0))
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_real_face_model_frontal_landmarks_visible(quick_model):
    perf = performance_from_spec(quick_model, {"n_frames": 1, "size": [320, 240],
                                               "identity": "id01",
                                               "tracks": {"expression": [[0, "smile"]]}})
    clip = make_clip(quick_model, perf)
    tr = clip.truth
    assert tr.visible[0, quick_model.landmarks].all()
    # yawed 60 degrees (model +x turns away): the far jaw line (iBUG 12-16) and the far nose
    # wing (35) hide behind the face; the near jaw line (0-6) and the nose bridge (27-30) show
    side = performance_from_spec(quick_model, {"n_frames": 1, "size": [320, 240],
                                               "pose": {"keys": [[0, {"yaw_deg": 60}]]}})
    vis = make_clip(quick_model, side).truth.visible[0, quick_model.landmarks]
    assert vis[0:7].all() and vis[27:31].all()
    assert not vis[12:17].any() and not vis[35]


def test_truth_file_keys_are_a_tracks_and_older_files_still_read(tiny_model, tmp_path):
    """The truth names its weights as a track file does (``weights_<mode>``: before
    ``weights__<mode>``, so ``truth["weights_expression"]`` was a KeyError); a file written
    the old way still loads."""
    perf = random_performance(tiny_model, 3, seed=0, size=(48, 40))
    clip = make_clip(tiny_model, perf)
    _, tpath = write_clip(clip, tmp_path / "clip.mp4")
    with np.load(tpath) as z:
        keys = set(z.files)
        old = {(k.replace("weights_", "weights__") if k.startswith("weights_") else k): z[k]
               for k in z.files}
    assert {"weights_identity", "weights_expression"} <= keys
    np.savez(tmp_path / "old.truth.npz", **old)
    for p in (tpath, tmp_path / "old.truth.npz"):
        tr = load_truth(p)
        assert list(tr.weights) == ["identity", "expression"] and tr.path == str(p)
        np.testing.assert_array_equal(tr.weights["expression"], clip.truth.weights["expression"])


def test_truth_checks_the_model_it_is_used_with(tiny_model, tmp_path):
    """A truth file used with another model (modes, ranks, or the content hash) is refused
    naming the file (before: ``texture lift --track CLIP.truth.npz`` with such a model ended
    in a KeyError traceback or a shape error about weights)."""
    from facetransfer.errors import TrackError

    _, tpath = write_clip(make_clip(tiny_model, random_performance(tiny_model, 2, seed=0,
                                                                   size=(48, 40))),
                          tmp_path / "clip.mp4")
    tr = load_truth(tpath)
    tr.check_model(tiny_model)
    fewer = build_model(tiny_dataset(), {"identity": 2, "expression": 4})
    with pytest.raises(TrackError, match=rf"ground truth {tpath} was rendered with another "
                                         r"model \(modes and ranks \{'identity': 3"):
        tr.check_model(fewer)
    unrefined = build_model(tiny_dataset(), {"identity": 3, "expression": 4}, refine=False)
    assert unrefined.content_hash != tiny_model.content_hash
    with pytest.raises(TrackError, match="the same but another content hash"):
        tr.check_model(unrefined)


def test_the_truth_given_for_a_track_is_named_as_probe_names_it(tiny_model, tmp_path, capsys):
    """synth-video's ``CLIP.truth.npz`` given to ``edit``, ``export`` or ``puppet`` (which take
    a track): one line saying it is synth-video's ground truth and to give a track of the clip
    from ``facetransfer track`` (before: "not a track file (missing confidence, lost, ...)",
    the arrays a track has and it lacks)."""
    from facetransfer.cli.main import main
    from facetransfer.track.result import Track, TrackError

    perf = random_performance(tiny_model, 3, seed=0, size=(64, 48), fps=10)
    _, tpath = write_clip(make_clip(tiny_model, perf), tmp_path / "clip.mp4")
    said = (f"{tpath} is a synthetic clip's ground truth (synth-video's CLIP.truth.npz), not a "
            "track: give a track of the clip (`facetransfer track`)")
    with pytest.raises(TrackError) as err:
        Track.load(tpath)
    assert str(err.value) == said
    for args in (["edit", str(tpath), "--scale", "jawOpen=2", "--out", str(tmp_path / "e.npz")],
                 ["export", str(tpath), "--out", str(tmp_path / "e.glb")],
                 ["puppet", str(tpath), "--out", str(tmp_path / "p.mp4")]):
        assert main(args) == 2, args
        lines = capsys.readouterr().err.strip().splitlines()
        assert lines == [f"facetransfer {args[0]}: error: {said}"], lines
    # another archive still says what a track file lacks
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(TrackError, match=r"x.npz is not a track file \(missing fps, "):
        Track.load(tmp_path / "x.npz")

"""Visemes end to end (Vlasic et al. 2005, Fig. 1, Fig. 7D): a trilinear model (identity x
expression x viseme), actor A saying known visemes, actor C making expressions, and footage of
actor B; the rewrite of B's footage with C's expressions and A's visemes against the truth
rendering of B doing both."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from facetransfer import rewrite_clip as rc  # noqa: E402
from facetransfer.rewrite_options import RewriteOptions  # noqa: E402
from facetransfer import topology  # noqa: E402
from facetransfer.render import (WeakPerspective, look_at_weak_perspective, render,  # noqa: E402
                                 rotation_from_euler)
from facetransfer.track import Track  # noqa: E402
from facetransfer.track.project import project_landmarks  # noqa: E402
from facetransfer.transfer import recombine  # noqa: E402

SIZE = (128, 128)
EXPRESSIONS = {
    "neutral": {},
    "smile": {"mouthSmile_L": 1.0, "mouthSmile_R": 1.0},
    "browsup": {"browInnerUp_L": 1.0, "browInnerUp_R": 1.0, "browOuterUp_L": 0.8,
                "browOuterUp_R": 0.8},
    "frown": {"browDown_L": 1.0, "browDown_R": 1.0, "mouthFrown_L": 0.6, "mouthFrown_R": 0.6},
}
VISEMES = {
    "rest": {},
    "AA": {"jawOpen": 0.7, "mouthLowerDown_L": 0.3, "mouthLowerDown_R": 0.3},
    "OO": {"mouthPucker": 1.0, "mouthFunnel": 0.6, "jawOpen": 0.15},
    "EE": {"mouthStretch_L": 0.8, "mouthStretch_R": 0.8, "jawOpen": 0.2},
    "MM": {"mouthPress_L": 0.8, "mouthPress_R": 0.8, "mouthRollLower": 0.4},
}
#: A's visemes (the source of the mouth's motion), C's expressions, B's (target) poses
A_VISEMES = ["rest", "AA", "OO", "EE", "MM", "AA"]
C_EXPRESSIONS = ["neutral", "smile", "browsup", "smile", "frown", "neutral"]
B_YAWS = [-4, 0, 5, 9, 3, -2]


def _trilinear_dataset(data_dir: Path):
    """4 identities x 4 expressions x 5 visemes of the ICT face area, additive (blendshape
    offsets of expression and viseme summed on each identity)."""
    from facetransfer.datasets import FaceDataset
    from facetransfer.io.mesh import read_obj, read_obj_vertices

    root = data_dir / "ict-facekit" / "FaceXModel"
    full = read_obj(root / "generic_neutral_mesh.obj")
    n = 9409  # the face area
    faces = full.faces[(full.faces < n).all(axis=1)]
    landmarks = np.asarray(json.loads((root / "vertex_indices.json").read_text())
                           ["idx_to_landmark_verts"], dtype=np.int64)
    neutral = full.vertices[:n]
    rng = np.random.default_rng(11)
    comps = [read_obj_vertices(root / f"identity{k:03d}.obj")[:n] - neutral for k in range(8)]
    ids = [neutral] + [neutral + sum(w * c for w, c in zip(rng.normal(size=8), comps))
                       for _ in range(3)]
    cache: dict = {}

    def offset(recipe):
        out = np.zeros_like(neutral)
        for s, w in recipe.items():
            if s not in cache:
                cache[s] = read_obj_vertices(root / f"{s}.obj")[:n] - neutral
            out += w * cache[s]
        return out

    ex = [offset(r) for r in EXPRESSIONS.values()]
    vi = [offset(r) for r in VISEMES.values()]
    verts = np.stack([np.stack([np.stack([i + e + v for v in vi]) for e in ex]) for i in ids])
    return FaceDataset(verts, np.ones(verts.shape[:3], bool),
                       ("identity", "expression", "viseme"),
                       (tuple(f"id{k:02d}" for k in range(4)), tuple(EXPRESSIONS), tuple(VISEMES)),
                       faces, full.uvs[:n], landmarks, np.arange(n),
                       {"dataset": "test-trilinear-ict"})


@pytest.fixture(scope="module")
def tri_dataset(data_dir):
    return _trilinear_dataset(data_dir)


@pytest.fixture(scope="module")
def tri_model(tri_dataset):
    from facetransfer.model import build_model

    return build_model(tri_dataset, {"identity": 4, "expression": 4, "viseme": 5})


@pytest.fixture(scope="module")
def tri_topo(tri_model):
    return topology.mesh_topology(tri_model)


def render_clip(model, topo, texture, identity, expressions, visemes, yaws, *, seed):
    """Frames and truth track of ``identity`` with the given expression and viseme labels."""
    import cv2

    m = model
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur((rng.random((SIZE[1], SIZE[0], 3)) * 255).astype(np.uint8), (0, 0), 2)
    wid = m.training_weights("identity", identity)
    cam0 = look_at_weak_perspective(m.synthesize(m.default_weights()), SIZE, fill=0.75)
    uvs = np.vstack([m.uvs, m.uvs[topo.mouth_loop].mean(0)])
    we = np.array([m.training_weights("expression", e) for e in expressions])
    wv = np.array([m.training_weights("viseme", v) for v in visemes])
    frames, R = [], []
    for e, v, yaw in zip(we, wv, yaws):
        Rf = rotation_from_euler(yaw, 0, 0)
        V = topology.close_mouth(m.synthesize({"identity": wid, "expression": e, "viseme": v}), topo)
        frames.append(render(V, topo.faces, WeakPerspective(cam0.scale, Rf, cam0.translation),
                             SIZE, uvs=uvs, texture=texture, shading="none",
                             background=bg).image)
        R.append(Rf)
    k = len(frames)
    tr = Track(fps=25.0, frame_size=SIZE, rotation=np.array(R), scale=np.full(k, cam0.scale),
               translation=np.tile(cam0.translation, (k, 1)),
               weights={"identity": np.tile(wid, (k, 1)), "expression": we, "viseme": wv},
               landmarks2d=np.zeros((k, 68, 2)), confidence=np.ones(k), lost=np.zeros(k, bool),
               model_hash=m.content_hash, mode_names=m.mode_names, source="synthetic")
    return np.array(frames), project_landmarks(tr, m)


@pytest.fixture(scope="module")
def clips(tri_model, tri_topo):
    """A (id01) says A_VISEMES with a neutral face, C (id03) makes C_EXPRESSIONS with the mouth
    at rest, B (id02) is the target (neutral, rest); truth: B with C's expressions and A's
    visemes in B's poses and background."""
    from facetransfer.texture import default_face_texture

    m, topo = tri_model, tri_topo
    tex = default_face_texture(m, 256)
    k = len(A_VISEMES)
    fa, ta = render_clip(m, topo, tex, "id01", ["neutral"] * k, A_VISEMES,
                         [0, 5, -5, 8, 2, -3], seed=1)
    fc, tc = render_clip(m, topo, tex, "id03", C_EXPRESSIONS, ["rest"] * k,
                         [3, -6, 0, 4, -2, 6], seed=3)
    fb, tb = render_clip(m, topo, tex, "id02", ["neutral"] * k, ["rest"] * k, B_YAWS, seed=2)
    truth, tt = render_clip(m, topo, tex, "id02", C_EXPRESSIONS, A_VISEMES, B_YAWS, seed=2)
    return {"A": (fa, ta), "C": (fc, tc), "B": (fb, tb), "truth": (truth, tt)}


def psnr(a, b, mask) -> float:
    d = ((np.asarray(a, float) - np.asarray(b, float)) ** 2)[mask]
    return float(10 * np.log10(255.0 ** 2 / max(d.mean(), 1e-12)))


def test_trilinear_model_is_exact(tri_model, tri_dataset):
    """Full ranks: the training meshes are reproduced (Eq. (4))."""
    assert tri_model.mode_names == ("identity", "expression", "viseme")
    assert tri_model.ranks == (4, 4, 5)
    w = {"identity": tri_model.training_weights("identity", "id02"),
         "expression": tri_model.training_weights("expression", "smile"),
         "viseme": tri_model.training_weights("viseme", "AA")}
    V = tri_model.synthesize(w)
    np.testing.assert_allclose(V, tri_dataset.vertices[2, 1, 1], atol=1e-8)
    w["viseme"] = tri_model.training_weights("viseme", "rest")
    V0 = tri_model.synthesize(w)
    assert np.abs(V - V0).max() > 0.3  # the jaw opens (cm)


def test_recombine_takes_a_visemes_and_c_expressions(tri_model, clips):
    (_, ta), (_, tc), (_, tb) = clips["A"], clips["C"], clips["B"]
    new = recombine(tb, expression=tc, viseme=ta)
    np.testing.assert_array_equal(new.weights["viseme"], ta.weights["viseme"])
    np.testing.assert_array_equal(new.weights["expression"], tc.weights["expression"])
    np.testing.assert_array_equal(new.weights["identity"], tb.weights["identity"])
    np.testing.assert_array_equal(new.rotation, tb.rotation)
    # the truth track of B doing both has exactly these weights
    _, tt = clips["truth"]
    for mode in tri_model.mode_names:
        np.testing.assert_allclose(new.weights[mode], tt.weights[mode], atol=1e-12)


@pytest.mark.parametrize("mouth", ["frame", "function"])
def test_viseme_transfer_matches_truth(tri_model, tri_topo, clips, mouth):
    """B's footage rewritten with C's expressions and A's visemes, the mouth from A (the viseme
    source). Measured PSNR on the face region (6 frames, 128 px, default fast blend):
    untouched target 168 (frame 0 needs no change), 22.9, 24.8, 27.0, 30.4, 23.2 dB;
    mouth="frame" 36.1, 29.5, 33.0, 28.9, 34.3, 30.7; mouth="function" 36.1, 29.4, 33.0,
    29.5, 34.3, 30.4 dB."""
    (fa, ta), (_, tc), (fb, tb) = clips["A"], clips["C"], clips["B"]
    truth, _ = clips["truth"]
    new = recombine(tb, expression=tc, viseme=ta)
    outs = list(rc.rewrite_frames(fb, tb, new, tri_model, mouth_source=rc.MouthSource(fa, ta),
                                  options=RewriteOptions(mouth=mouth), topo=tri_topo))
    ours = [psnr(o.image, truth[i], o.face_mask) for i, o in enumerate(outs)]
    base = [psnr(fb[i], truth[i], o.face_mask) for i, o in enumerate(outs)]
    assert min(ours) > 27.5, (ours, base)
    # every frame that changes (a viseme other than rest or an expression) gains over the
    # untouched target: by 1.9 dB at least, 5.4 dB on average
    gains = [ours[i] - base[i] for i in range(1, len(outs))]
    assert min(gains) > 1.0 and np.mean(gains) > 4.0, (ours, base)
    assert all(o.mouth_mask.sum() > 20 for o in outs)  # pressed lips (MM): 27 pixels


def test_viseme_transfer_cli_with_track_files(tri_model, clips, tmp_path, capsys):
    """``facetransfer transfer`` with the three videos and their truth track files."""
    from facetransfer.cli.main import main
    from facetransfer.io.video import read_video, write_video

    paths = {}
    for key in ("A", "B", "C"):
        frames, track = clips[key]
        paths[key] = tmp_path / f"{key}.mp4"
        write_video(paths[key], frames, 25.0)
        track.save(tmp_path / f"{key}.npz")
    model_path = tmp_path / "tri.npz"
    tri_model.save(model_path)
    out = tmp_path / "out.mp4"
    argv = ["transfer", "--target", paths["B"], "--target-track", tmp_path / "B.npz",
            "--expression-from", paths["C"], "--source-track", tmp_path / "C.npz",
            "--viseme-from", paths["A"], "--viseme-track", tmp_path / "A.npz",
            "--model", model_path, "--mouth", "function", "--save-track",
            tmp_path / "new.npz", "--out", out, "--no-progress"]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err
    new = Track.load(tmp_path / "new.npz")
    np.testing.assert_allclose(new.weights["viseme"], clips["A"][1].weights["viseme"])
    np.testing.assert_allclose(new.weights["expression"], clips["C"][1].weights["expression"])
    frames, _ = read_video(out)
    truth, _ = clips["truth"]
    fb, tb = clips["B"]
    import scipy.ndimage as ndi

    ours, base = [], []
    for i in range(1, len(frames)):
        # the pixels the transfer has to change: where the truth differs from the target
        mask = ndi.binary_dilation(np.abs(truth[i].astype(int) - fb[i]).max(-1) > 20,
                                   iterations=2)
        ours.append(psnr(frames[i], truth[i], mask))
        base.append(psnr(fb[i], truth[i], mask))
    # measured (mp4v both ways): 23.0, 25.7, 23.3, 26.5, 23.7 dB against the untouched
    # target's 16.3, 19.1, 20.7, 22.2, 16.4 dB
    gains = np.subtract(ours, base)
    assert min(ours) > 21.0 and gains.min() > 1.5 and gains.mean() > 4.0, (ours, base)
    # bad input: a mouth mode that does not exist, one line, exit 2
    with pytest.raises(SystemExit) as exc:  # argparse's own exit
        main([str(a) for a in argv[:-3] + ["--mouth", "teeth", "--out", out]])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--mouth" in err and "invalid choice: 'teeth'" in err

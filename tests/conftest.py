"""Shared fixtures. ``FACETRANSFER_DATA_DIR`` must point at the offline asset mirror (CI sets it)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("MPLBACKEND", "Agg")
# the track cache off: each test tracks what it tracks (tests/test_track_cache.py turns it on);
# the render cache stays on, the default path of a transfer's video (a finished render leaves
# nothing in it; tests of an interrupted one give it a folder of their own)
os.environ["FACETRANSFER_TRACK_CACHE"] = "off"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The offline asset mirror; tests needing real assets skip only when it is not configured."""
    d = os.environ.get("FACETRANSFER_DATA_DIR")
    if not d:
        pytest.skip("FACETRANSFER_DATA_DIR is not set (CI sets it to the ../shared/data mirror)")
    return Path(d)


def _quick_ict_dataset(data_dir: Path, n_identities: int, expressions: dict[str, dict[str, float]],
                       seed: int = 0):
    """A small additive ICT-FaceKit data set (no deformation transfer) for tests of other stages."""
    from facetransfer.datasets import FaceDataset
    from facetransfer.io.mesh import read_obj, read_obj_vertices

    root = data_dir / "ict-facekit" / "FaceXModel"
    full = read_obj(root / "generic_neutral_mesh.obj")
    n = 9409  # FaceKit "full face area", vertices 0..9408
    keep = (full.faces < n).all(axis=1)
    faces = full.faces[keep]
    idx = json.loads((root / "vertex_indices.json").read_text())
    landmarks = np.asarray(idx["idx_to_landmark_verts"], dtype=np.int64)
    neutral = full.vertices[:n]
    rng = np.random.default_rng(seed)
    comps = [read_obj_vertices(root / f"identity{k:03d}.obj")[:n] - neutral for k in range(10)]
    ids = [neutral] + [neutral + sum(w * c for w, c in zip(rng.normal(size=10), comps))
                       for _ in range(n_identities - 1)]
    shapes = {}
    for recipe in expressions.values():
        for s in recipe:
            if s not in shapes:
                shapes[s] = read_obj_vertices(root / f"{s}.obj")[:n] - neutral
    offs = [sum((w * shapes[s] for s, w in r.items()), np.zeros_like(neutral))
            for r in expressions.values()]
    verts = np.stack([np.stack([i + o for o in offs]) for i in ids])
    return FaceDataset(verts, np.ones(verts.shape[:2], bool), ("identity", "expression"),
                       (tuple(f"id{k:02d}" for k in range(n_identities)), tuple(expressions)),
                       faces, full.uvs[:n] if full.uvs is not None else None, landmarks,
                       np.arange(n), {"dataset": "test-quick-ict", "seed": seed})


QUICK_EXPRESSIONS = {
    "neutral": {},
    "smile": {"mouthSmile_L": 1.0, "mouthSmile_R": 1.0},
    "open": {"jawOpen": 0.8},
    "frown": {"browDown_L": 1.0, "browDown_R": 1.0, "mouthFrown_L": 0.7, "mouthFrown_R": 0.7},
    "pucker": {"mouthPucker": 1.0, "mouthFunnel": 0.5},
    "surprise": {"browInnerUp_L": 1.0, "browInnerUp_R": 1.0, "eyeWide_L": 1.0, "eyeWide_R": 1.0,
                 "jawOpen": 0.4},
}


@pytest.fixture(scope="session")
def quick_ict_dataset(data_dir):
    """6 identities × 6 expressions of the ICT-FaceKit face area (9,409 vertices), additive."""
    return _quick_ict_dataset(data_dir, 6, QUICK_EXPRESSIONS)


@pytest.fixture(scope="session")
def quick_model(quick_ict_dataset, tmp_path_factory):
    """A bilinear model (identity rank 5, expression rank 5) of :func:`quick_ict_dataset`."""
    from facetransfer.model import build_model

    return build_model(quick_ict_dataset, {"identity": 5, "expression": 5})


@pytest.fixture(scope="module")
def quick_track(quick_model):
    """30 frames of :func:`quick_model`'s id02, expressions near neutral, a still camera: the
    track the transfer's and the edits' exact tests act on (test_transfer.py,
    test_performance_edit.py)."""
    from facetransfer.track import Track

    n = 30
    rng = np.random.default_rng(5)
    w = {"identity": np.tile(quick_model.training_weights("identity", "id02"), (n, 1)),
         "expression": quick_model.training_weights("expression", "neutral")
         + 0.1 * rng.normal(size=(n, quick_model.ranks[1]))}
    return Track(fps=25.0, frame_size=(64, 64), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.full(n, 2.0), translation=np.tile([32.0, 32.0], (n, 1)), weights=w,
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash=quick_model.content_hash,
                 mode_names=quick_model.mode_names)


@pytest.fixture(scope="session")
def quick_model_path(quick_model, tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("models") / "quick.npz"
    quick_model.save(p)
    return p


@pytest.fixture(scope="session")
def arkit_model(data_dir):
    """A small ARKit model: ``ict-arkit`` with 6 identities (rank 5) x 52 expressions (untruncated,
    so activations and expression weights convert exactly). Cached data set: ~25 s once."""
    from facetransfer.datasets.ict import build_ict_dataset
    from facetransfer.model import build_model

    ds = build_ict_dataset("ict-arkit", n_identities=6, use_cache=True)
    return build_model(ds, {"identity": 5, "expression": ds.shape[1]}, refine=False)


@pytest.fixture(scope="session")
def arkit_model_path(arkit_model, tmp_path_factory) -> Path:
    """:func:`arkit_model` saved as a model file (``--model``)."""
    p = tmp_path_factory.mktemp("models") / "arkit.npz"
    arkit_model.save(p)
    return p


@pytest.fixture(scope="session")
def arkit_model_full(data_dir):
    """:func:`arkit_model`'s data set with every identity kept (training meshes reproduce)."""
    from facetransfer.datasets.ict import build_ict_dataset
    from facetransfer.model import build_model

    ds = build_ict_dataset("ict-arkit", n_identities=6, use_cache=True)
    return build_model(ds, {"identity": ds.shape[0], "expression": ds.shape[1]}, refine=False)


def synthetic_arkit_track(model, n_frames: int = 12, *, seed: int = 0, identity: int = 1,
                          fps: float = 25.0):
    """A track of ``model`` with known activations, head angles (yaw, pitch, roll; radians) and
    translation. Returns (track, activations (F, 52) float32, angles (F, 3))."""
    from scipy.spatial.transform import Rotation

    from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
    from facetransfer.track.result import Track

    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1, (n_frames, 52)).astype(np.float32)
    a[:, ARKIT_NAMES.index("tongueOut")] = 0.0  # the FaceKit has no tongue shape
    ang = rng.uniform(-0.4, 0.4, (n_frames, 3))
    R = Rotation.from_euler("YXZ", ang).as_matrix()
    k = model.mode_index("identity")
    track = Track(fps=fps, frame_size=(640, 480), rotation=R,
                  scale=rng.uniform(8, 12, n_frames), translation=rng.uniform(200, 400, (n_frames, 2)),
                  weights={"identity": np.tile(model.factors[k][identity], (n_frames, 1)),
                           "expression": activations_to_weights(model, a)},
                  landmarks2d=np.zeros((n_frames, 68, 2)), confidence=np.ones(n_frames),
                  lost=np.zeros(n_frames, bool), model_hash=model.content_hash,
                  mode_names=model.mode_names, source="synthetic.mp4", blendshapes=a,
                  blendshape_names=ARKIT_NAMES)
    return track, a, ang


def mean_person_track(model, activations, *, size: int = 256, scale: float = 20.0,
                      rotation=None):
    """A track of ``model``'s mean person with the ARKit ``activations`` (F, 52), facing the
    camera (or turned by ``rotation``: (3, 3), or (F, 3, 3) a frame), centred 40 px above the
    middle of a ``size``² frame; landmarks zero (project them when needed)."""
    from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
    from facetransfer.track.result import Track

    a = np.asarray(activations, np.float32)
    F = a.shape[0]
    k = model.mode_index("identity")
    R = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    R = np.broadcast_to(R, (F, 3, 3)).copy()
    return Track(fps=25.0, frame_size=(size, size), rotation=R, scale=np.full(F, scale),
                 translation=np.tile([size / 2, size / 2 - 40.0], (F, 1)),
                 weights={"identity": np.tile(model.weight_mean(k), (F, 1)),
                          "expression": activations_to_weights(model, a)},
                 landmarks2d=np.zeros((F, 68, 2)), confidence=np.ones(F),
                 lost=np.zeros(F, bool), model_hash=model.content_hash,
                 mode_names=model.mode_names, source="synthetic.mp4",
                 blendshapes=a, blendshape_names=ARKIT_NAMES)


def jaw_open_track(model, jaw_open, *, size: int = 256, scale: float = 20.0, rotation=None):
    """:func:`mean_person_track` with the given jawOpen per frame and every other activation
    0."""
    from facetransfer.arkit import ARKIT_NAMES

    a = np.zeros((len(jaw_open), 52), np.float32)
    a[:, ARKIT_NAMES.index("jawOpen")] = jaw_open
    return mean_person_track(model, a, size=size, scale=scale, rotation=rotation)


@pytest.fixture(scope="session")
def make_arkit_track():
    """:func:`synthetic_arkit_track` as a fixture."""
    return synthetic_arkit_track


def clip_with_points(model, n: int, seed: int, folder, *, video: str = "clip.mp4",
                     points: str = "points.json"):
    """An ``n``-frame synthetic clip ``folder/video`` of ``model`` (320x240, 25 fps) and a
    POINTS.json of its first frame's landmarks 17-67 (what ``--init`` reads); returns
    (video path, points path, the clip with its truth)."""
    from facetransfer.io.video import write_video
    from facetransfer.synth import make_clip, random_performance

    perf = random_performance(model, n, seed=seed, size=(320, 240), fps=25, fill=0.8)
    clip = make_clip(model, perf, seed=seed)
    v = Path(folder) / video
    write_video(v, clip.frames, 25)
    L = clip.truth.landmarks2d[0]
    pts = Path(folder) / points
    pts.write_text(json.dumps({"points": {str(i): L[i].tolist() for i in range(17, 68)}}))
    return v, pts, clip


def still_track(model, n: int, *, source: str = ""):
    """A track of ``n`` frames of ``model`` at rest (no rotation, zero weights, all found):
    for tests of what is said or kept of a track, not of its values."""
    from facetransfer.track import Track

    return Track(fps=25.0, frame_size=(64, 64), rotation=np.tile(np.eye(3), (n, 1, 1)),
                 scale=np.ones(n), translation=np.zeros((n, 2)),
                 weights={m: np.zeros((n, r)) for m, r in zip(model.mode_names, model.ranks)},
                 landmarks2d=np.zeros((n, 68, 2)), confidence=np.ones(n),
                 lost=np.zeros(n, bool), model_hash=model.content_hash,
                 mode_names=model.mode_names, source=source)


def record_scales(monkeypatch):
    """The ``scale`` of each ``rewrite_frame_part`` call of the clip renderer, in order."""
    from facetransfer import rewrite_clip

    seen = []
    part = rewrite_clip.rewrite_frame_part

    def recorded(*args, **kw):
        seen.append(kw["scale"])
        return part(*args, **kw)

    monkeypatch.setattr(rewrite_clip, "rewrite_frame_part", recorded)
    return seen


@pytest.fixture(scope="session")
def d6_first_frames(data_dir, tmp_path_factory):
    """``driving_d6``'s first 3 frames as a clip (a short expression source)."""
    from facetransfer.io.video import read_video, write_video

    d = tmp_path_factory.mktemp("d6")
    frames, fps = read_video(data_dir / "video" / "driving_d6.mp4", max_frames=3)
    write_video(d / "d6.mp4", frames, fps)
    return d / "d6.mp4"


def transfer_onto_breakingbad(data_dir, source, out_dir, face: str) -> int:
    """``transfer --target stills/breakingbad.jpg --target-face FACE --expression-from
    SOURCE`` into ``out_dir`` as a PNG sequence; its exit status."""
    from facetransfer.cli.main import main

    return main(["transfer", "--target", str(data_dir / "stills" / "breakingbad.jpg"),
                 "--target-face", face, "--expression-from", str(source),
                 "--out", str(out_dir / "r_%03d.png"), "--no-progress"])


def mean_eye_span(model):
    """``(topology, V, d)``: ``model``'s mesh topology, its mean face's vertices ``V`` (V, 3)
    and the distance of its eyes' centres (the eye loops' means), model units."""
    from facetransfer.topology import mesh_topology

    topo = mesh_topology(model)
    V = model.synthesize(model.default_weights())
    c = [V[np.asarray(loop)].mean(axis=0) for loop in topo.eye_loops]
    return topo, V, float(np.linalg.norm(c[0] - c[1]))


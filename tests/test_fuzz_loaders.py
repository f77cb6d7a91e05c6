"""Property-based fuzzing of every loader (issue 16): damaged files give exactly one
:class:`~facetransfer.errors.FaceTransferError` (a ``ValueError``) naming the file, never another
exception; a progress file that cannot be used is ignored (``None``), never an error.

Damage: truncation, flipped bytes, zeroed or garbage tails, and for ``.npz`` files arrays replaced
by wrong dtypes, shapes, NaN and infinity (model files re-signed, so that the checksum does not
hide the deeper checks).
"""

from __future__ import annotations

import io
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facetransfer.errors import FaceTransferError

FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# ------------------------------------------------------------------------------ damage
@st.composite
def damaged_bytes(draw, data: bytes) -> bytes:
    """``data`` truncated, with flipped bytes, a zeroed tail, or garbage appended/prepended."""
    kind = draw(st.sampled_from(["truncate", "flip", "zero_tail", "garbage", "empty"]))
    n = len(data)
    if kind == "empty":
        return b""
    if kind == "truncate":
        return data[:draw(st.integers(0, max(0, n - 1)))]
    if kind == "flip":
        b = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, n - 1))
            b[i] ^= draw(st.integers(1, 255))
        return bytes(b)
    if kind == "zero_tail":
        k = draw(st.integers(1, max(1, n // 2)))
        return data[:n - k] + b"\0" * k
    junk = draw(st.binary(min_size=1, max_size=64))
    return junk + data if draw(st.booleans()) else data + junk


BAD_VALUES = ["nan", "inf", "-inf", "str", "empty", "extra_dim", "drop_dim", "scalar", "bool",
              "huge"]


def mutate_array(a: np.ndarray, how: str) -> np.ndarray:
    """A wrong version of ``a``: non-finite, text, empty, wrong rank or dtype."""
    a = np.asarray(a)
    if how in ("nan", "inf", "-inf"):
        if a.dtype.kind not in "fiub":   # text: a number where text belongs
            return np.full(a.shape, float(how))
        b = np.array(a, dtype=np.float64, copy=True).reshape(-1)
        if b.size == 0:
            b = np.zeros(1)
        b[0] = float(how)
        return b.reshape(a.shape) if a.size else b
    if how == "str":
        return np.full(a.shape if a.size else (1,), "abc")
    if how == "empty":
        return np.zeros((0,) + a.shape[1:], a.dtype)
    if how == "extra_dim":
        return a[..., None]
    if how == "drop_dim":
        return a.reshape(-1) if a.ndim > 1 else a.reshape(-1)[:0]
    if how == "scalar":
        return np.asarray(a.reshape(-1)[0] if a.size else 0)
    if how == "bool":
        return np.ones(a.shape, bool)
    return np.full(a.shape, 1e308) if a.dtype.kind == "f" else np.full(a.shape, 2**62)


def npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def check_loader(load, path: Path, *, ok=None):
    """``load(path)`` returns (then ``ok(result)``) or raises one FaceTransferError naming the
    file; any other exception fails."""
    try:
        result = load(path)
    except FaceTransferError as exc:
        msg = str(exc)
        assert path.name in msg or str(path.parent) in msg, f"message does not name {path}: {msg}"
        assert "\n" not in msg.strip() or msg.splitlines()[0], msg
        return None
    except Exception as exc:  # noqa: BLE001 - the property under test
        pytest.fail(f"{load.__qualname__}({path.name}) raised {exc.__class__.__name__}: {exc}")
    if ok is not None:
        ok(result)
    return result


@pytest.fixture(scope="module")
def work():
    d = Path(tempfile.mkdtemp(prefix="fuzz-"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _put(work: Path, name: str, data: bytes) -> Path:
    p = work / name
    p.write_bytes(data)
    return p


# ------------------------------------------------------------------------------ model
@pytest.fixture(scope="module")
def tiny_model_arrays(work):
    """The arrays and metadata of a small saved model (8 vertices, 3 x 2 cells)."""
    from facetransfer.datasets import FaceDataset
    from facetransfer.model import build_model

    rng = np.random.default_rng(0)
    v = rng.normal(size=(3, 2, 8, 3))
    faces = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6], [5, 6, 7]])
    ds = FaceDataset(v, np.ones((3, 2), bool), ("identity", "expression"),
                     (("a", "b", "c"), ("neutral", "smile")), faces, rng.random((8, 2)), None,
                     None, {"dataset": "fuzz"})
    p = work / "model.npz"
    build_model(ds, {"identity": 2, "expression": 2}).save(p)
    with np.load(p) as z:
        return p.read_bytes(), {k: z[k] for k in z.files}


def _resign(arrays: dict) -> dict:
    """Recompute the checksum of (mutated) model arrays, as a careful forger would."""
    from facetransfer.model import _content_hash

    data = {k: v for k, v in arrays.items() if k != "metadata"}
    meta = json.loads(str(arrays["metadata"]))
    meta.pop("sha256", None)
    meta["sha256"] = _content_hash(data, meta)
    return {**data, "metadata": np.array(json.dumps(meta))}


def _model_ok(m):
    assert np.all(np.isfinite(m.core)) and m.faces.dtype.kind in "iu"


@FUZZ
@given(data=st.data())
def test_model_loader_bytes(work, tiny_model_arrays, data):
    from facetransfer.model import load_model

    raw, _ = tiny_model_arrays
    p = _put(work, "m_bytes.npz", data.draw(damaged_bytes(raw)))
    check_loader(load_model, p, ok=_model_ok)


@FUZZ
@given(key=st.sampled_from(["core", "factor_0", "factor_1", "faces", "uvs", "eigenvalues_0"]),
       how=st.sampled_from(BAD_VALUES), resign=st.booleans())
def test_model_loader_arrays(work, tiny_model_arrays, key, how, resign):
    from facetransfer.model import load_model

    _, arrays = tiny_model_arrays
    bad = dict(arrays)
    bad[key] = mutate_array(arrays[key], how)
    p = _put(work, "m_arrays.npz", npz_bytes(_resign(bad) if resign else bad))
    m = check_loader(load_model, p, ok=_model_ok)
    if how in ("nan", "inf", "-inf", "str"):
        assert m is None, f"{key} with {how} was accepted"


def test_model_loader_rejects_other_files(work, tiny_model_arrays):
    """A PNG, a folder, an .npy array: one line naming the file, no numpy hint."""
    import cv2

    from facetransfer.errors import ModelFileError
    from facetransfer.model import load_model

    png = work / "face.png"
    cv2.imwrite(str(png), np.zeros((4, 4, 3), np.uint8))
    npy = work / "array.npy"
    np.save(npy, np.zeros(3))
    for p, words in ((png, "not a model file"), (work, "is a folder"), (npy, ".npz")):
        with pytest.raises(ModelFileError) as e:
            load_model(p)
        assert str(p) in str(e.value) and words in str(e.value) and "pickle" not in str(e.value)


# ------------------------------------------------------------------------------ track
@pytest.fixture(scope="module")
def track_arrays(work):
    from facetransfer.track.result import Track

    F = 3
    rng = np.random.default_rng(1)
    tr = Track(fps=25.0, frame_size=(64, 48), rotation=np.tile(np.eye(3), (F, 1, 1)),
               scale=np.ones(F), translation=rng.random((F, 2)),
               weights={"identity": np.ones((F, 2)), "expression": rng.random((F, 3))},
               landmarks2d=rng.random((F, 68, 2)), confidence=np.full(F, 0.9),
               lost=np.zeros(F, bool), model_hash="abc", mode_names=("identity", "expression"))
    p = tr.save(work / "track.npz")
    with np.load(p) as z:
        return p.read_bytes(), {k: z[k] for k in z.files}


def _track_ok(t):
    assert t.n_frames >= 1 and np.all(np.isfinite(t.scale)) and t.lost.dtype == bool


@FUZZ
@given(data=st.data())
def test_track_loader_bytes(work, track_arrays, data):
    from facetransfer.track.result import Track

    p = _put(work, "t_bytes.npz", data.draw(damaged_bytes(track_arrays[0])))
    check_loader(Track.load, p, ok=_track_ok)


@FUZZ
@given(key=st.sampled_from(["fps", "frame_size", "rotation", "scale", "translation",
                            "landmarks2d", "confidence", "lost", "mode_names",
                            "weights_expression", "format_version", "model_hash"]),
       how=st.sampled_from(BAD_VALUES))
def test_track_loader_arrays(work, track_arrays, key, how):
    from facetransfer.track.result import Track

    bad = dict(track_arrays[1])
    bad[key] = mutate_array(bad[key], how)
    p = _put(work, "t_arrays.npz", npz_bytes(bad))
    t = check_loader(Track.load, p, ok=_track_ok)
    if how in ("nan", "inf", "-inf") and key not in ("lost", "mode_names", "model_hash"):
        assert t is None, f"{key} with {how} was accepted"


def test_texture_cli_track_loader(work, track_arrays):
    """``texture lift`` reads a track or a truth file through the same checks."""
    from facetransfer.cli.texture import _load_track
    from facetransfer.errors import TrackError

    for name, data in (("empty.npz", b""), ("cut.npz", track_arrays[0][:100])):
        p = _put(work, name, data)
        with pytest.raises(TrackError, match=name):
            _load_track(str(p))


# ------------------------------------------------------------------------------ partial file
@pytest.fixture(scope="module")
def checkpoint_bytes(work):
    from facetransfer.track.camera import Pose
    from facetransfer.track.checkpoint import Checkpoint
    from facetransfer.track.solver import FrameState

    modes = ("identity", "expression")

    def state(k):
        return FrameState(Pose(np.eye(3), 1.0 + k, np.array([k, 2.0 * k])),
                          {"identity": np.ones(2), "expression": np.full(3, float(k))})

    states = [state(k) for k in range(4)]
    cp = Checkpoint(work / "t.partial.npz", "KEY", modes)
    cp.save(start=0, L0=np.zeros((68, 2)), state0=states[0], pass_index=0, next_frame=3,
            states=states, prev=None, conf=np.ones(4), lost=np.zeros(4, bool), reinit=[],
            systems=[(np.eye(2), np.zeros(2))])
    assert cp.load() is not None
    return cp.path.read_bytes()


@FUZZ
@given(data=st.data())
def test_partial_file_damage_means_start_afresh(work, checkpoint_bytes, data):
    from facetransfer.track.checkpoint import Checkpoint, Resume

    p = _put(work, "t.partial.npz", data.draw(damaged_bytes(checkpoint_bytes)))
    try:
        r = Checkpoint(p, "KEY", ("identity", "expression")).load()
    except Exception as exc:  # noqa: BLE001
        pytest.fail(f"Checkpoint.load raised {exc.__class__.__name__}: {exc}")
    assert r is None or isinstance(r, Resume)


@FUZZ
@given(key=st.sampled_from(["start", "L0", "pass_index", "next_frame", "conf", "lost",
                            "reinit", "has_prev", "n_systems", "sys_S", "cur_valid", "cur_R",
                            "cur_w_expression", "s0_t"]),
       how=st.sampled_from(BAD_VALUES))
def test_partial_file_bad_arrays_mean_start_afresh(work, checkpoint_bytes, key, how):
    from facetransfer.track.checkpoint import Checkpoint, Resume

    with np.load(io.BytesIO(checkpoint_bytes)) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[key] = mutate_array(arrays[key], how)
    p = _put(work, "t.partial.npz", npz_bytes(arrays))
    try:
        r = Checkpoint(p, "KEY", ("identity", "expression")).load()
    except Exception as exc:  # noqa: BLE001
        pytest.fail(f"Checkpoint.load raised {exc.__class__.__name__}: {exc}")
    assert r is None or isinstance(r, Resume)


@pytest.fixture(scope="module")
def detections_bytes(work):
    from facetransfer.track.detect import ClipDetections
    from facetransfer.track.detect_checkpoint import DetectionCheckpoint

    rng = np.random.default_rng(0)
    P = rng.normal(size=(3, 68, 2))
    det = ClipDetections(P, np.zeros_like(P), rng.normal(size=(3, 478, 2)).astype(np.float32))
    cp = DetectionCheckpoint(work / "d.partial.npz", "KEY")
    cp.save(det)
    assert cp.load() is not None
    return cp.path.read_bytes()


def _load_detections(p):
    from facetransfer.track.detect_checkpoint import DetectionCheckpoint, SavedDetections

    try:
        r = DetectionCheckpoint(p, "KEY").load()
    except Exception as exc:  # noqa: BLE001
        pytest.fail(f"DetectionCheckpoint.load raised {exc.__class__.__name__}: {exc}")
    assert r is None or isinstance(r, SavedDetections)


@FUZZ
@given(data=st.data())
def test_detections_progress_file_damage_means_start_afresh(work, detections_bytes, data):
    _load_detections(_put(work, "d.partial.npz", data.draw(damaged_bytes(detections_bytes))))


@FUZZ
@given(key=st.sampled_from(["points", "flow", "points478", "n_frames", "complete", "has478",
                            "layout"]),
       how=st.sampled_from(BAD_VALUES))
def test_detections_progress_file_bad_arrays_mean_start_afresh(work, detections_bytes, key, how):
    with np.load(io.BytesIO(detections_bytes)) as z:
        arrays = {k: z[k] for k in z.files}
    arrays[key] = mutate_array(arrays[key], how)
    _load_detections(_put(work, "d.partial.npz", npz_bytes(arrays)))


# ------------------------------------------------------------------------------ manifest
@pytest.fixture(scope="module")
def manifest(work):
    d = work / "manifest"
    d.mkdir()
    rows = ["path,identity,expression"]
    for i in range(2):
        for e in range(2):
            v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0 + e + i]])
            (d / f"m{i}{e}.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                                            + "f 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
            rows.append(f"m{i}{e}.obj,id{i},e{e}")
    (d / "m.csv").write_text("\n".join(rows) + "\n")
    return d


@FUZZ
@given(data=st.data())
def test_manifest_loader(manifest, data):
    from facetransfer.datasets.manifest import read_manifest

    raw = (manifest / "m.csv").read_bytes()
    p = _put(manifest, "fuzz.csv", data.draw(damaged_bytes(raw)))
    check_loader(read_manifest, p,
                 ok=lambda ds: (ds.vertices.ndim == 4 and ds.vertices.shape[-2:] == (4, 3)))


# ------------------------------------------------------------------------------ JSON points
JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6)
                           | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=5),
                           lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=3), inner, max_size=4),
                           max_leaves=12)


def _points_doc(draw, dim: int):
    """A feature/init file: a good one with some entries replaced by arbitrary JSON."""
    pts = {str(i): [float(i), float(i) / 2, 1.0][:dim] for i in range(17, 68)}
    for _ in range(draw(st.integers(0, 3))):
        pts[draw(st.sampled_from(list(pts) + ["abc", "-1", "99", "3.5"]))] = draw(JSON_VALUES)
    doc = {"points": pts} if draw(st.booleans()) else draw(JSON_VALUES)
    return json.dumps(doc, allow_nan=True).encode()


@FUZZ
@given(data=st.data())
def test_feature_points_loader(work, data):
    from facetransfer.correspond.features import read_features

    good = json.dumps({"points": {str(i): [i, i / 2, 1.0] for i in range(17, 68)}}).encode()
    raw = _points_doc(data.draw, 3) if data.draw(st.booleans()) else \
        data.draw(damaged_bytes(good))
    p = _put(work, "features.json", raw)
    check_loader(read_features, p,
                 ok=lambda fp: np.all(np.isfinite(fp.points)) and fp.points.shape[1] == 3)


@pytest.mark.parametrize("entry", ["", {}])
def test_init_points_entry_of_the_wrong_type(work, entry):
    from facetransfer.errors import TrackError
    from facetransfer.track.init import load_init_points

    pts = {str(i): [i, i / 2] for i in range(17, 68)}
    pts["30"] = entry
    p = _put(work, "init_bad.json", json.dumps({"points": pts}).encode())
    with pytest.raises(TrackError, match="init_bad.json"):
        load_init_points(p, (200, 200))


@FUZZ
@given(data=st.data())
def test_init_points_loader(work, data):
    from facetransfer.track.init import load_init_points

    good = json.dumps({"points": {str(i): [i, i / 2] for i in range(17, 68)}}).encode()
    raw = _points_doc(data.draw, 2) if data.draw(st.booleans()) else \
        data.draw(damaged_bytes(good))
    p = _put(work, "init.json", raw)
    check_loader(lambda q: load_init_points(q, (200, 200)), p,
                 ok=lambda pts: all(np.all(np.isfinite(v)) for v in pts.values()))


# ------------------------------------------------------------------------------ meshes
GOOD_OBJ = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
            "f 1/1 2/2 3/3\nf 1/1 2/2 4/4\nf 1/1 3/3 4/4\nf 2/2 3/3 4/4 1/1\n").encode()


def _mesh_ok(m):
    assert np.all(np.isfinite(m.vertices)) and m.vertices.shape[1] == 3
    assert m.faces.size == 0 or (m.faces.min() >= 0 and m.faces.max() < len(m.vertices))
    assert m.uvs is None or m.uvs.shape == (len(m.vertices), 2)


@FUZZ
@given(data=st.data())
def test_obj_loader(work, data):
    from facetransfer.io.mesh import read_mesh

    raw = data.draw(damaged_bytes(GOOD_OBJ))
    if data.draw(st.booleans()):   # a line replaced by a plausible but wrong one
        lines = GOOD_OBJ.decode().splitlines()
        lines[data.draw(st.integers(0, len(lines) - 1))] = data.draw(st.sampled_from(
            ["f 1 2 abc", "f 1 2", "f 0 1 2", "f 1/9 2/1 3/1", "v 1 2", "v nan 0 0", "vt x y",
             "v 1e999 0 0", "f -9 1 2", "vt 0", "f 1//1 2//2 3//3"]))
        raw = "\n".join(lines).encode()
    p = _put(work, "mesh.obj", raw)
    check_loader(read_mesh, p, ok=_mesh_ok)


@pytest.fixture(scope="module")
def ply_bytes(work):
    import trimesh

    m = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                        np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]), process=False)
    return m.export(file_type="ply")


@FUZZ
@given(data=st.data())
def test_ply_loader(work, ply_bytes, data):
    from facetransfer.io.mesh import read_mesh

    p = _put(work, "mesh.ply", data.draw(damaged_bytes(ply_bytes)))
    check_loader(read_mesh, p, ok=_mesh_ok)


# ------------------------------------------------------------------------------ MediaPipe npz
@FUZZ
@given(data=st.data(), how=st.sampled_from(BAD_VALUES + ["ok"]))
def test_mediapipe_landmarks_loader(work, data, how):
    from facetransfer.io.landmarks import read_mediapipe_landmarks

    good = np.random.default_rng(2).random((4, 478, 3)).astype(np.float32)
    good[1] = np.nan   # no face on frame 1: allowed
    if how == "ok":
        raw = data.draw(damaged_bytes(npz_bytes({"landmarks": good})))
    else:
        raw = npz_bytes({"landmarks": mutate_array(good, how)})
    p = _put(work, "clip.mediapipe478.npz", raw)
    a = check_loader(read_mediapipe_landmarks, p,
                     ok=lambda a: a.shape[1:] == (478, 3) and not np.isinf(a).any())
    if how in ("inf", "-inf", "str", "extra_dim", "drop_dim", "scalar"):
        assert a is None, f"landmarks with {how} were accepted"


# ------------------------------------------------------------------------------ texture image
@pytest.fixture(scope="module")
def png_bytes():
    import cv2

    img = (np.random.default_rng(3).random((16, 16, 3)) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


@FUZZ
@given(data=st.data())
def test_texture_image_loader(work, png_bytes, data):
    from facetransfer.synth import load_texture_image

    p = _put(work, "tex.png", data.draw(damaged_bytes(png_bytes)))
    check_loader(load_texture_image, p,
                 ok=lambda im: im.dtype == np.uint8 and im.ndim == 3 and im.shape[2] == 3)


# ------------------------------------------------------------------------------ Live Link take
@pytest.fixture(scope="module")
def take_bytes():
    """A Live Link Face take of 40 rows across a second, every column the app writes."""
    from facetransfer.export.livelink import LIVELINK_NAMES, POSE_COLUMNS

    head = ["Timecode", "BlendShapeCount", *LIVELINK_NAMES, *POSE_COLUMNS]
    rows = [",".join(head)]
    for i in range(40):
        cells = [f"{(i * j % 17) / 17:.4f}" for j in range(len(head) - 2)]
        rows.append(",".join([f"01:02:{3 + i // 30:02d}:{i % 30:02d}.{i * 7 % 1000:03d}", "61",
                              *cells]))
    return ("\n".join(rows) + "\n").encode()


#: cells a take's damage may put in place of one (text where numbers belong, timecodes that
#: are not, NUL)
TAKE_CELLS = ["", "nan", "inf", "-1e400", "abc", "01:02:03", "99:99:99:99", "00:00:00:00.5",
              " ", "\0"]


@FUZZ
@given(data=st.data(), lenient=st.booleans())
def test_live_link_take_loader(work, take_bytes, data, lenient):
    """A damaged take (bytes, or one cell replaced) is read with finite activations or gives
    one error naming it; its timecodes then give seconds or a TransferError (before: bytes
    that are not UTF-8 raised UnicodeDecodeError, not the library's error)."""
    from facetransfer.export.livelink import read_livelink
    from facetransfer.take import take_seconds

    raw = data.draw(damaged_bytes(take_bytes))
    lines = raw.decode("utf-8", "replace").split("\n")
    if data.draw(st.booleans()) and len(lines) > 2:
        k = data.draw(st.integers(0, len(lines) - 1))
        cells = lines[k].split(",")
        cells[data.draw(st.integers(0, len(cells) - 1))] = data.draw(st.sampled_from(TAKE_CELLS))
        lines[k] = ",".join(cells)
        raw = "\n".join(lines).encode()
    p = _put(work, "take.csv", raw)
    take = check_loader(lambda q: read_livelink(q, lenient=lenient), p,
                        ok=lambda t: np.isfinite(t.activations).all())
    if take is not None:
        try:
            take_seconds(take.timecodes, warn=False)
        except FaceTransferError:
            pass


# ------------------------------------------------------------------------------ MediaPipe JSON
def _blendshape_doc(n: int = 3) -> dict:
    """A blendshape document in MediaPipe's per-frame layout (frame 1 without a face)."""
    from facetransfer.export.mpjson import CATEGORY_NAMES

    cats = [{"index": i, "score": 0.5, "categoryName": c, "displayName": ""}
            for i, c in enumerate(CATEGORY_NAMES)]
    return {"fps": 30.0, "frames": [{"frameIndex": k, "faceBlendshapes": [] if k == 1 else
                                     [{"categories": cats}]} for k in range(n)]}


@FUZZ
@given(data=st.data())
def test_blendshape_json_loader(work, data):
    """Damaged bytes, or a frame's entry replaced by arbitrary JSON, give scores or one error
    naming the file (before: an entry of the wrong type raised AttributeError/KeyError)."""
    from facetransfer.export.mpjson import read_mediapipe_json

    doc = _blendshape_doc()
    if data.draw(st.booleans()):
        raw = data.draw(damaged_bytes(json.dumps(doc).encode()))
    else:
        where = data.draw(st.sampled_from(["frame", "faces", "category", "score"]))
        junk = data.draw(JSON_VALUES)
        if where == "frame":
            doc["frames"][0] = junk
        elif where == "faces":
            doc["frames"][2]["faceBlendshapes"] = junk
        elif where == "category":
            doc["frames"][0]["faceBlendshapes"][0]["categories"][3] = junk
        else:
            doc["frames"][2]["faceBlendshapes"][0]["categories"][5]["score"] = junk
        raw = json.dumps(doc, allow_nan=True).encode()
    p = _put(work, "shapes.json", raw)
    check_loader(read_mediapipe_json, p, ok=lambda a: a.ndim == 2 and a.shape[1] == 52)


# ------------------------------------------------------------------------------ batch CSVs
@FUZZ
@given(data=st.data())
def test_batch_summary_loader(work, data):
    from facetransfer.batch.summary import Row, read_summary, write_summary

    good = _put(work, "summary_good.csv", b"")
    write_summary(good, [Row("a", "done", 10, 30.0, 1.5, 0.9, "", "a.npz"),
                         Row("b", "failed", error="no face found in b.mp4")])
    p = _put(work, "summary.csv", data.draw(damaged_bytes(good.read_bytes())))
    check_loader(read_summary, p, ok=lambda rows: all(isinstance(r, Row) for r in rows))


@FUZZ
@given(data=st.data())
def test_batch_manifest_loader(work, data):
    from facetransfer.batch.manifest import read_manifest

    good = b"video,name,face\nclips/a.mp4,a,left\nb.mp4,,\n"
    p = _put(work, "clips.csv", data.draw(damaged_bytes(good)))
    check_loader(lambda q: read_manifest(q, required=("video",), allowed=("video", "name", "face"),
                                         paths=("video",)), p,
                 ok=lambda rows: rows and all(r.get("video") for r in rows))


# ------------------------------------------------------------------------------ plate frames
@pytest.fixture(scope="module")
def plate_frames():
    """A straight-alpha RGBA TIFF (Pillow's) and a 16-bit RGBA PNG, as bytes."""
    import cv2
    from PIL import Image

    rgba = np.random.default_rng(0).integers(0, 256, (16, 16, 4), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(rgba).save(buf, format="TIFF")
    ok, png = cv2.imencode(".png", rgba.astype(np.uint16) * 257)
    assert ok
    return {".tif": buf.getvalue(), ".png": png.tobytes()}


@pytest.mark.filterwarnings("ignore:Truncated File Read:UserWarning")  # Pillow's, true
@FUZZ
@given(data=st.data(), suffix=st.sampled_from([".tif", ".png"]))
def test_plate_frame_loader(work, plate_frames, data, suffix):
    """A damaged frame of a TIFF or 16-bit PNG plate: one error naming the plate, never
    Pillow's own (struct.error, TypeError, DecompressionBombError were found this way)."""
    from facetransfer.io.frame_file import read_frame_file

    p = _put(work, f"p.0001{suffix}", data.draw(damaged_bytes(plate_frames[suffix])))
    check_loader(lambda q: read_frame_file(q, work / f"p.%04d{suffix}"), p,
                 ok=lambda a: a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3)


def test_a_plate_frame_of_absurd_size_is_one_error(work, plate_frames):
    """A TIFF whose header claims a huge width (Pillow's DecompressionBombError when opened):
    one error naming the plate, not Pillow's."""
    import struct

    from facetransfer.io.frame_file import read_frame_file

    b = bytearray(plate_frames[".tif"])
    e = "<" if b[:2] == b"II" else ">"
    ifd = struct.unpack(e + "I", b[4:8])[0]
    for k in range(struct.unpack(e + "H", b[ifd:ifd + 2])[0]):
        at = ifd + 2 + 12 * k
        tag, typ = struct.unpack(e + "HH", b[at:at + 4])
        if tag in (256, 257):   # ImageWidth, ImageLength
            b[at + 8:at + 12] = struct.pack(e + ("H" if typ == 3 else "I"), 60000).ljust(4, b"\0")
    p = _put(work, "huge.0001.tif", bytes(b))
    with pytest.raises(FaceTransferError, match="huge"):
        read_frame_file(p, work / "huge.%04d.tif")

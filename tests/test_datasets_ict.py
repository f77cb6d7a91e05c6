"""ICT-FaceKit builder: regions, recipes, identities, deformation transfer, cache."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facetransfer import assets
from facetransfer.datasets import build_ict_dataset, ict_template, load_dataset, load_recipes
from facetransfer.datasets.deformation import deformation_gradients
from facetransfer.datasets.ict import _read_prefix_vertices, ict_cache_path
from facetransfer.errors import DatasetError
from facetransfer.io.mesh import read_obj_vertices

N_FACE = 9409


@pytest.fixture(scope="module")
def ict_cache(tmp_path_factory, data_dir):
    """Private cache folder for this module's builds."""
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("ictcache")))
    mp.setenv("FACETRANSFER_DATA_DIR", str(data_dir))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def bilinear(ict_cache):
    return build_ict_dataset("ict-bilinear", n_identities=3, seed=5)


@pytest.fixture(scope="module")
def trilinear(ict_cache):
    return build_ict_dataset("ict-trilinear", n_identities=2, seed=5)


def _generic(rel: str) -> np.ndarray:
    return read_obj_vertices(assets.asset_file("ict-facekit", rel))[:N_FACE]


def _recipe_offset(recipe: dict) -> np.ndarray:
    neutral = _generic("generic_neutral_mesh.obj")
    return sum((w * (_generic(f"{s}.obj") - neutral) for s, w in recipe.items()), np.zeros((N_FACE, 3)))


def test_fast_prefix_reader_matches_full_parser(ict_cache, tmp_path):
    for rel in ("identity007.obj", "jawOpen.obj"):
        p = assets.asset_file("ict-facekit", rel)
        np.testing.assert_array_equal(_read_prefix_vertices(p, N_FACE), read_obj_vertices(p)[:N_FACE])
    # another layout (v lines interleaved with vt) falls back to the full parser
    q = tmp_path / "x.obj"
    q.write_text("# c\nv 0 0 0\nvt 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    np.testing.assert_array_equal(_read_prefix_vertices(q, 2), [[0, 0, 0], [1, 0, 0]])
    with pytest.raises(DatasetError, match="fewer than the region"):
        _read_prefix_vertices(q, 5)


def test_template_face_region(ict_cache):
    t = ict_template("face")
    assert t.mesh.vertices.shape == (N_FACE, 3) and t.mesh.uvs.shape == (N_FACE, 2)
    assert t.mesh.faces.max() == N_FACE - 1 and len(t.mesh.faces) == 18461
    assert t.landmarks.shape == (68,) and t.landmarks.max() < N_FACE
    np.testing.assert_array_equal(t.vertex_subset, np.arange(N_FACE))
    full = json.loads(assets.asset_file("ict-facekit", "vertex_indices.json").read_text())
    np.testing.assert_array_equal(t.landmarks, full["idx_to_landmark_verts"])
    narrow = ict_template("narrow")
    assert narrow.mesh.vertices.shape == (6706, 3) and narrow.landmarks.max() < 6706
    with pytest.raises(DatasetError, match="unknown ICT region 'head'"):
        ict_template("head")


def test_bilinear_layout_and_provenance(bilinear):
    ds = bilinear
    assert ds.mode_names == ("identity", "expression")
    assert ds.vertices.shape == (3, 10, N_FACE, 3) and ds.mask.all()
    assert ds.labels[0] == ("generic", "id01", "id02")
    assert ds.labels[1][:7] == ("neutral", "smile", "frown", "surprise", "anger", "disgust", "sadness")
    assert np.all(np.isfinite(ds.vertices))
    p = ds.provenance
    assert p["seed"] == 5 and p["asset"]["commit"] == assets.ICT_COMMIT
    assert p["recipes"]["expressions"]["smile"]["mouthSmile_L"] == 1.0
    assert np.asarray(p["identity_weights"]).shape == (3, 100)


def test_generic_identity_reproduces_recipe_expressions(bilinear):
    """Transfer onto the generic neutral itself gives the generic expression (Sumner & Popović)."""
    rec = load_recipes()["expressions"]
    neutral = _generic("generic_neutral_mesh.obj")
    for e in ("smile", "surprise", "jaw_open"):
        expect = neutral + _recipe_offset(rec[e])
        got = bilinear.vertices[0, bilinear.labels[1].index(e)]
        rel = np.linalg.norm(got - expect) / np.linalg.norm(expect - neutral)
        assert rel < 1e-6, (e, rel)


def test_identities_follow_recorded_weights(bilinear):
    w = np.asarray(bilinear.provenance["identity_weights"])
    neutral = _generic("generic_neutral_mesh.obj")
    sel = bilinear.landmarks
    comps = [_read_prefix_vertices(assets.asset_file("ict-facekit", f"identity{c:03d}.obj"), N_FACE)
             for c in range(100)]
    expect = neutral[sel] + sum(w[2, c] * (comps[c][sel] - neutral[sel]) for c in range(100))
    np.testing.assert_allclose(bilinear.vertices[2, 0][sel], expect, atol=1e-8)
    # the neutral cell's own deformation gradients are the identity
    Q = deformation_gradients(bilinear.vertices[2, 0], bilinear.vertices[2, 0], bilinear.faces)
    np.testing.assert_allclose(Q, np.broadcast_to(np.eye(3), Q.shape), atol=1e-9)
    # and differ from another identity's neutral by centimetres
    assert np.abs(bilinear.vertices[1, 0] - bilinear.vertices[2, 0]).max() > 0.3


def test_identity_specific_offsets_differ(bilinear):
    """Without deformation transfer every identity would smile with the same displacements."""
    k = bilinear.labels[1].index("smile")
    off = bilinear.vertices[:, k] - bilinear.vertices[:, 0]  # (3, n, 3)
    scale = np.linalg.norm(off[0])
    d01 = np.linalg.norm(off[1] - off[0]) / scale
    d12 = np.linalg.norm(off[2] - off[1]) / scale
    assert d01 > 0.01 and d12 > 0.01, (d01, d12)
    # but it is still a smile: the offsets are strongly correlated
    cos = np.vdot(off[1], off[0]) / (np.linalg.norm(off[1]) * scale)
    assert cos > 0.9


def test_trilinear_cells_add_expression_and_viseme(trilinear):
    ds = trilinear
    assert ds.mode_names == ("identity", "expression", "viseme")
    assert ds.vertices.shape == (2, 5, 5, N_FACE, 3)
    assert ds.labels[1] == ("neutral", "smiling", "scowling", "surprised", "sad")
    assert ds.labels[2] == ("man", "car", "eel", "too", "she")
    rec = load_recipes()
    neutral = _generic("generic_neutral_mesh.obj")
    expect = neutral + _recipe_offset(rec["expressions"]["smiling"]) + _recipe_offset(rec["visemes"]["car"])
    got = ds.vertices[0, 1, 1]
    assert np.linalg.norm(got - expect) / np.linalg.norm(expect - neutral) < 1e-6


def test_cache_roundtrip(bilinear, ict_cache, monkeypatch):
    import facetransfer.datasets.deformation as deformation

    path = ict_cache_path("ict-bilinear", n_identities=3, seed=5)
    assert path.is_file()
    with monkeypatch.context() as mp:  # a cached build must not recompute anything
        mp.setattr(deformation, "DeformationTransfer", None)   # ict imports it as it builds
        again = build_ict_dataset("ict-bilinear", n_identities=3, seed=5)
    assert again.provenance == bilinear.provenance
    np.testing.assert_array_equal(again.vertices, bilinear.vertices)
    np.testing.assert_array_equal(again.faces, bilinear.faces)
    assert again.labels == bilinear.labels
    # other seeds or sizes have other cache files
    assert ict_cache_path("ict-bilinear", n_identities=3, seed=6) != path
    assert ict_cache_path("ict-bilinear", n_identities=4, seed=5) != path
    # a damaged cache file is rebuilt, not trusted
    path.write_bytes(b"garbage")
    rebuilt = load_dataset("ict-bilinear", n_identities=3, seed=5)
    np.testing.assert_allclose(rebuilt.vertices, bilinear.vertices, atol=1e-12)


def test_a_cache_of_an_older_build_gives_the_same_model(bilinear, ict_cache):
    """A cached data set written with its build's seconds in the provenance (before the
    fifty-first session) is read without them: its model's content hash is a fresh build's."""
    from facetransfer.model import build_model

    path = ict_cache_path("ict-bilinear", n_identities=3, seed=5)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    meta["provenance"]["build_seconds"] = 12.345
    arrays["meta"] = np.array(json.dumps(meta))
    older = path.with_name("older.npz")
    np.savez(older, **arrays)
    older.replace(path)
    cached = build_ict_dataset("ict-bilinear", n_identities=3, seed=5)
    assert "build_seconds" not in cached.provenance
    fresh = build_ict_dataset("ict-bilinear", n_identities=3, seed=5, use_cache=False)
    ranks = {"identity": 2, "expression": 4}
    assert (build_model(cached, ranks, refine=False).content_hash
            == build_model(fresh, ranks, refine=False).content_hash)


def test_bad_input(ict_cache):
    with pytest.raises(DatasetError, match="unknown ICT data set 'ict-quadrilinear'"):
        build_ict_dataset("ict-quadrilinear")
    with pytest.raises(DatasetError, match="at least 2"):
        build_ict_dataset("ict-bilinear", n_identities=1)
    with pytest.raises(DatasetError, match="unknown ICT region"):
        build_ict_dataset("ict-bilinear", n_identities=2, region="torso")
    rec = load_recipes()
    rec["expressions"]["smile"] = {"mouthGrin_L": 1.0}
    with pytest.raises(DatasetError, match="unknown ICT shape 'mouthGrin_L'"):
        build_ict_dataset("ict-bilinear", n_identities=2, recipes=rec, use_cache=False)


def test_recipe_file_validation(tmp_path):
    p = tmp_path / "r.json"
    p.write_text(json.dumps({"expressions": {"a": {"jawOpen": "lots"}}, "visemes": {}, "datasets": {}}))
    with pytest.raises(DatasetError, match="must map shape names to numbers"):
        load_recipes(p)
    p.write_text(json.dumps({"expressions": {}, "visemes": {},
                             "datasets": {"x": {"expressions": ["smile"]}}}))
    with pytest.raises(DatasetError, match="no recipe"):
        load_recipes(p)
    p.write_text("{not json")
    with pytest.raises(DatasetError, match="cannot read ICT recipe file"):
        load_recipes(p)

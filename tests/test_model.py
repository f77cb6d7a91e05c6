"""The multilinear model (§4.3): Eq. (4), (5), (9) and the model file."""

import json

import numpy as np
import pytest

from facetransfer.datasets import FaceDataset
from facetransfer.errors import DatasetError, ModelFileError, ShapeError
from facetransfer.model import FORMAT_VERSION, build_model, load_model


def random_dataset(d=(5, 4, 3), n=40, seed=0):
    rng = np.random.default_rng(seed)
    verts = rng.normal(size=d + (n, 3))
    names = ("identity", "expression", "viseme")[: len(d)]
    labels = tuple(tuple(f"{m[:2]}{i}" for i in range(k)) for m, k in zip(names, d))
    faces = np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]])
    return FaceDataset(verts, np.ones(d, bool), names, labels, faces, landmarks=np.arange(5),
                       provenance={"dataset": "random", "seed": seed})


def test_untruncated_model_reproduces_every_training_face():
    ds = random_dataset()
    m = build_model(ds, refine=False)
    assert m.ranks == (5, 4, 3) and m.n_vertices == 40
    for i, j, k in [(0, 0, 0), (4, 3, 2), (2, 1, 0)]:
        f = m.synthesize(m.like(identity=f"id{i}", expression=f"ex{j}", viseme=f"vi{k}"))
        assert np.allclose(f, ds.vertices[i, j, k], atol=1e-10)  # Eq. (5) with rows of Ǔ_k


def test_synthesize_batched_equals_loop():
    ds = random_dataset(seed=1)
    m = build_model(ds, {"identity": 3, "expression": 2}, refine=True)
    rng = np.random.default_rng(0)
    W = {n: rng.normal(size=(7, r)) for n, r in zip(m.mode_names, m.ranks)}
    batch = m.synthesize(W)
    assert batch.shape == (7, 40, 3)
    for b in range(7):
        single = m.synthesize({n: w[b] for n, w in W.items()})
        assert np.allclose(batch[b], single, atol=1e-12)
    # broadcast one identity against many expressions
    W2 = dict(W, identity=W["identity"][0])
    assert np.allclose(m.synthesize(W2)[3], m.synthesize({n: w[3] for n, w in W2.items()
                                                          if n != "identity"} | {"identity": W["identity"][0]}))


@pytest.mark.parametrize("constant", [(), ("identity",), ("viseme",), ("expression",),
                                      ("identity", "viseme"), ("identity", "expression",
                                                               "viseme")])
def test_synthesize_batch_with_modes_constant_over_the_batch(constant):
    """A mode whose weights repeat over the batch is contracted once (a clip's identity):
    every row still equals Eq. (5) by explicit mode products."""
    from facetransfer import tensor as tl

    ds = random_dataset(seed=4)
    m = build_model(ds, {"identity": 3, "expression": 2, "viseme": 2})
    rng = np.random.default_rng(5)
    W = {n: rng.normal(size=(6, r)) for n, r in zip(m.mode_names, m.ranks)}
    for n in constant:
        W[n] = np.tile(W[n][2], (6, 1))
    batch = m.synthesize(W)
    assert batch.shape == (6, 40, 3)
    for b in range(6):
        ref = tl.multi_mode_dot(m.core, [None] + [W[n][b] for n in m.mode_names])
        assert np.allclose(batch[b].ravel(), ref, atol=1e-12)
    sub = m.synthesize(W, vertices=np.array([3, 7]))
    assert np.allclose(sub, batch[:, [3, 7]], atol=1e-12)
    many = np.arange(1, 40, 3)  # an eighth of the vertices or more: the contracted identity
    assert np.allclose(m.synthesize(W, vertices=many), batch[:, many], atol=1e-12)


@pytest.mark.parametrize("many", [False, True])
def test_synthesize_vertices_from_the_contracted_identity(many):
    """A selection of vertices with one identity over the batch takes the rows of the core
    contracted with it (kept from a whole-mesh call, or made for a large selection): the same
    values as the whole mesh's rows, for one frame and a batch, whatever the memo holds."""
    from facetransfer import model as model_module

    ds = random_dataset(d=(5, 4), seed=6)
    m = build_model(ds, refine=False)
    rng = np.random.default_rng(7)
    ident, expr = rng.normal(size=5), rng.normal(size=(4, 4))
    W = {"identity": np.tile(ident, (4, 1)), "expression": expr}
    whole = m.synthesize(W)
    verts = np.arange(0, 40, 2) if many else np.array([9, 2, 31])
    model_module._FIRST_MODE.pop(m, None)
    cold = m.synthesize(W, vertices=verts)  # nothing kept: memo only for a large selection
    assert (m in model_module._FIRST_MODE) == many
    m.synthesize({"identity": ident, "expression": expr[0]})  # one frame keeps its identity
    warm = m.synthesize(W, vertices=verts)
    one = m.synthesize({"identity": ident, "expression": expr[1]}, vertices=verts)
    for got in (cold, warm):
        assert np.allclose(got, whole[:, verts], atol=1e-12)
    assert np.allclose(one, whole[1, verts], atol=1e-12)
    # another identity per row: the core's own rows, as before
    W2 = {"identity": rng.normal(size=(4, 5)), "expression": expr}
    assert np.allclose(m.synthesize(W2, vertices=verts), m.synthesize(W2)[:, verts], atol=1e-12)
    with pytest.raises(ShapeError, match="vertex indices"):
        m.synthesize(W, vertices=np.array([0, 40]))


def test_synthesize_matches_explicit_mode_products():
    from facetransfer import tensor as tl

    ds = random_dataset(seed=2)
    m = build_model(ds, {"identity": 2, "expression": 3, "viseme": 2})
    w = [np.array([0.3, -1.0]), np.array([1.0, 0.5, 0.2]), np.array([0.7, 0.1])]
    ref = tl.multi_mode_dot(m.core, [None] + w)  # M ×_2 w_2ᵀ ×_3 w_3ᵀ ×_4 w_4ᵀ
    assert np.allclose(m.synthesize(w).ravel(), ref, atol=1e-12)


def test_single_frames_with_recent_identities_are_eq5():
    """One frame at a time, identities alternating among four (more than the model keeps
    contracted): every frame still equals Eq. (5) by explicit mode products, and at most
    ``_FIRST_MODE_KEPT`` contracted cores are kept per model."""
    from facetransfer import model as model_module
    from facetransfer import tensor as tl

    ds = random_dataset(seed=6)
    m = build_model(ds, {"identity": 3, "expression": 2, "viseme": 2})
    rng = np.random.default_rng(7)
    ids = rng.normal(size=(4, 3))
    for t in range(12):
        w = [ids[[0, 1, 0, 2, 3, 0][t % 6]], rng.normal(size=2), rng.normal(size=2)]
        ref = tl.multi_mode_dot(m.core, [None] + w)
        assert np.allclose(m.synthesize(w).ravel(), ref, atol=1e-12)
        assert len(model_module._FIRST_MODE[m]) <= model_module._FIRST_MODE_KEPT
    assert len(model_module._FIRST_MODE[m]) == model_module._FIRST_MODE_KEPT


def test_batch_with_one_identity_shares_the_single_frames_contraction():
    """A batch whose identity alone is constant takes its contracted core from the memo of
    the single frames (the same product): its meshes equal the batch product over that core
    bit for bit, and no second core is kept for it."""
    from facetransfer import model as model_module

    ds = random_dataset(seed=8)
    m = build_model(ds, {"identity": 3, "expression": 2, "viseme": 2})
    rng = np.random.default_rng(9)
    wid = rng.normal(size=3)
    W = {"identity": np.tile(wid, (5, 1)), "expression": rng.normal(size=(5, 2)),
         "viseme": rng.normal(size=(5, 2))}
    m.synthesize({n: w[0] for n, w in W.items()})  # a single frame: the memo of wid
    assert len(model_module._FIRST_MODE[m]) == 1
    batch = m.synthesize(W)
    assert len(model_module._FIRST_MODE[m]) == 1
    core = model_module._contract_axis(m.core, 1, wid)
    kron = (W["expression"][:, :, None] * W["viseme"][:, None, :]).reshape(5, -1)
    want = (core.reshape(core.shape[0], -1) @ kron.T).T.reshape(5, -1, 3)
    np.testing.assert_array_equal(batch, want)


def test_a_large_core_contracted_in_halves_is_one_einsum_bit_for_bit(monkeypatch):
    """A core past ``_SPLIT_BYTES`` is contracted as two halves of its rows at once: every
    element is the sum one einsum computes (the same order), over any inner axis, for an odd
    number of rows too; the last axis and small cores take the single product."""
    from facetransfer import model as model_module

    rng = np.random.default_rng(13)
    monkeypatch.setattr(model_module, "_SPLIT_BYTES", 0)
    monkeypatch.setattr(model_module.os, "cpu_count", lambda: 2)
    for shape, axis in (((101, 7, 5), 1), ((64, 3, 4, 6), 2), ((9, 8, 3), 1)):
        T = rng.normal(size=shape)
        w = rng.normal(size=shape[axis])
        keep = [d for d in range(T.ndim) if d != axis]
        want = np.einsum(T, list(range(T.ndim)), w, [axis], keep)
        np.testing.assert_array_equal(model_module._contract_axis(T, axis, w), want)
    T = rng.normal(size=(11, 4, 3))
    np.testing.assert_allclose(model_module._contract_axis(T, 2, np.ones(3)), T.sum(2),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("mode", ["identity", "expression", "viseme"])
def test_mode_basis_is_eq9(mode):
    ds = random_dataset(seed=3)
    m = build_model(ds, {"identity": 4, "expression": 3, "viseme": 2})
    rng = np.random.default_rng(1)
    w = {n: rng.normal(size=r) for n, r in zip(m.mode_names, m.ranks)}
    vs = np.array([0, 7, 39])
    B = m.mode_basis(mode, w, vertices=vs)
    assert B.shape == (3, 3, m.ranks[m.mode_index(mode)])
    assert np.allclose(B @ w[mode], m.synthesize(w)[vs], atol=1e-12)
    # linear in w_m: a different w_m gives the face through the same basis
    w2 = dict(w, **{mode: rng.normal(size=len(w[mode]))})
    assert np.allclose(B @ w2[mode], m.synthesize(w2)[vs], atol=1e-12)
    assert np.allclose(m.mode_basis(mode, w)[vs], B)
    # the identity's contraction now kept (synthesize): the same basis from its rows
    assert np.allclose(m.mode_basis(mode, w, vertices=vs), B, atol=1e-12)


def test_truncated_model_reports_explained_variance_and_error():
    ds = random_dataset(seed=4)
    m = build_model(ds, {"identity": 2}, refine=True)
    errs = m.provenance["relative_errors"]
    assert errs[-1] <= errs[0] + 1e-12 and errs[-1] > 0
    # the reported error is the true relative error over every training face (measured 0.762)
    rec = np.stack([[[m.synthesize(m.like(identity=f"id{i}", expression=f"ex{j}",
                                          viseme=f"vi{k}")) for k in range(3)]
                     for j in range(4)] for i in range(5)])
    true = np.linalg.norm(rec - ds.vertices) / np.linalg.norm(ds.vertices)
    assert abs(errs[-1] - true) < 1e-10
    # eigenvalues: squared singular values of the data's identity-mode unfolding (§3)
    from facetransfer import tensor as tl

    T = np.moveaxis(ds.vertices.reshape(5, 4, 3, -1), -1, 0)
    s = np.linalg.svd(tl.unfold(T, 1), compute_uv=False)
    np.testing.assert_allclose(m.eigenvalues[0], s ** 2, rtol=1e-10)
    assert m.provenance["ranks"] == {"identity": 2, "expression": 4, "viseme": 3}


def test_weight_statistics():
    m = build_model(random_dataset(seed=5), refine=False)
    U = m.factors[1]
    assert np.allclose(m.weight_mean("expression"), U.mean(0))
    C = m.weight_cov("expression")
    assert C.shape == (4, 4) and np.all(np.linalg.eigvalsh(C) > 0)
    # the biased (1/n) covariance of the training rows plus a ridge of 1e-6 of its mean variance
    S = (U - U.mean(0)).T @ (U - U.mean(0)) / U.shape[0]
    np.testing.assert_allclose(C, S + 1e-6 * np.trace(S) / 4 * np.eye(4), rtol=1e-12, atol=1e-15)


def test_the_identity_mode_is_the_one_so_named_else_the_first():
    import dataclasses

    m = build_model(random_dataset(seed=5), refine=False)
    assert m.identity_mode == "identity"
    moved = dataclasses.replace(m, mode_names=("expression", "identity", "viseme"))
    assert moved.identity_mode == "identity"
    unnamed = dataclasses.replace(m, mode_names=("person", "expression", "viseme"))
    assert unnamed.identity_mode == "person"


def test_save_load_round_trip(tmp_path):
    m = build_model(random_dataset(seed=6), {"identity": 3})
    p = m.save(tmp_path / "m.npz")
    m2 = load_model(p)
    assert m2.content_hash == m.content_hash
    assert m2.labels == m.labels and m2.mode_names == m.mode_names
    assert np.array_equal(m2.core, m.core) and np.array_equal(m2.landmarks, m.landmarks)
    assert m2.provenance["dataset"] == "random"


def test_load_rejects_truncated_altered_newer_and_foreign_files(tmp_path):
    m = build_model(random_dataset(seed=7))
    p = m.save(tmp_path / "m.npz")
    data = p.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelFileError, match="truncated"):
        load_model(tmp_path / "trunc.npz")
    # altered: change one array, keep the stored checksum
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["core"] = arrays["core"] + 1e-9
    np.savez(tmp_path / "alt.npz", **arrays)
    with pytest.raises(ModelFileError, match="checksum"):
        load_model(tmp_path / "alt.npz")
    meta = json.loads(str(arrays["metadata"]))
    meta["format_version"] = FORMAT_VERSION + 1
    arrays["metadata"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "new.npz", **arrays)
    with pytest.raises(ModelFileError, match="newer"):
        load_model(tmp_path / "new.npz")
    np.savez(tmp_path / "foreign.npz", a=np.zeros(3))
    with pytest.raises(ModelFileError, match="not a facetransfer model"):
        load_model(tmp_path / "foreign.npz")
    with pytest.raises(ModelFileError, match="does not exist"):
        load_model(tmp_path / "nope.npz")


def test_a_verified_file_is_not_hashed_again_until_it_changes(tmp_path, monkeypatch):
    """The sha256 and NaN scan of a file as it is on disk are done once (io.verified); a
    rewrite of the same size with another modification time, or a file modified moments ago,
    is checked again."""
    import os

    from facetransfer import model as model_module

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    calls, scans = [], []
    real, scan = model_module._content_hash, model_module._all_finite
    monkeypatch.setattr(model_module, "_content_hash", lambda a, m: calls.append(1) or real(a, m))
    monkeypatch.setattr(model_module, "_all_finite", lambda a: scans.append(1) or scan(a))
    m = build_model(random_dataset(seed=3))
    p = m.save(tmp_path / "m.npz")
    want = m.content_hash
    calls.clear()                   # the save's and the model's own hashes
    load_model(p)
    load_model(p)
    assert len(calls) == 2          # modified moments ago: not recorded, hashed every time
    os.utime(p, (1.6e9, 1.6e9))
    assert load_model(p).content_hash == want and len(calls) == 3
    scans.clear()
    assert load_model(p).content_hash == want and len(calls) == 3   # remembered
    assert not scans                                                  # nor scanned for NaN
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["core"] = arrays["core"] + 1e-9           # same size, stored checksum kept
    np.savez(p, **arrays)
    assert p.stat().st_size == (tmp_path / "m.npz").stat().st_size
    os.utime(p, (1.6e9 + 1, 1.6e9 + 1))
    with pytest.raises(ModelFileError, match="checksum"):
        load_model(p)
    assert len(calls) == 4
    q = m.save(tmp_path / "q.npz")
    os.utime(q, (1.6e9, 1.6e9))
    record = tmp_path / "cache" / "facetransfer" / "verified-checksums.json"
    record.write_text("{not json")                  # a damaged record: the full check
    calls.clear()
    assert load_model(q).content_hash == want and load_model(q) and len(calls) == 1


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e308])
def test_load_rejects_a_core_with_nan_or_inf_even_with_a_matching_checksum(tmp_path, bad):
    """Finiteness is checked on the loaded (mapped) core, whatever the checksum says; huge
    finite values (whose sum overflows) are still accepted."""
    from facetransfer.model import MultilinearModel

    m = build_model(random_dataset(seed=7))
    core = m.core.copy()
    core[(0,) * core.ndim] = bad
    p = MultilinearModel(**{**m.__dict__, "core": core}).save(tmp_path / "bad.npz")
    if np.isfinite(bad):
        assert np.array_equal(load_model(p).core, core)
    else:
        with pytest.raises(ModelFileError, match="NaN or infinite"):
            load_model(p)


def test_save_is_atomic_and_refuses_overwrite(tmp_path):
    m = build_model(random_dataset(seed=8))
    p = m.save(tmp_path / "m.npz")
    before = p.read_bytes()
    from facetransfer.errors import FaceTransferError

    with pytest.raises(FaceTransferError, match="exists"):
        m.save(p, overwrite=False)
    assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["m.npz"]


def test_build_rejects_missing_cells_and_bad_ranks():
    ds = random_dataset(seed=9)
    mask = ds.mask.copy()
    mask[1, 2, 0] = False
    with pytest.raises(DatasetError, match="1 missing cells.*id1/ex2/vi0"):
        build_model(ds.with_vertices(ds.vertices, mask))
    with pytest.raises(ValueError, match="rank 9 for mode 'expression'"):
        build_model(ds, {"expression": 9})
    with pytest.raises(ValueError, match="unknown mode"):
        build_model(ds, {"age": 2})


def test_weight_validation():
    m = build_model(random_dataset(seed=10))
    with pytest.raises(ShapeError, match="mode 'expression' must end in 4"):
        m.synthesize({"identity": np.zeros(5), "expression": np.zeros(3), "viseme": np.zeros(3)})
    with pytest.raises(ValueError, match="unknown expression 'grin'"):
        m.like(expression="grin")
    with pytest.raises(ValueError, match="missing for mode"):
        m.synthesize({"identity": np.zeros(5)})



@pytest.mark.parametrize("bad, said", [
    (np.array([np.nan, 0, 0, 0]), "holds 1 NaN or infinite"),
    (np.array([np.inf, 0, 0, 0]), "holds 1 NaN or infinite"),
    (np.array([1j, 0, 0, 0]), "real numbers, got complex"),
    (np.array(["a", "b", "c", "d"]), "real numbers, got text"),
    ([[1, 2, 3, 4], [1]], "ragged"),
])
def test_weights_real_and_finite_naming_the_mode(bad, said):
    """NaN or infinite weights gave a NaN face with a RuntimeWarning only; complex ones their
    real part (a ComplexWarning); text or ragged ones numpy's message naming no mode."""
    m = build_model(random_dataset(seed=10))
    w = m.default_weights()
    w["expression"] = bad
    with pytest.raises(ShapeError, match=f"weights of mode 'expression'.*{said}|{said}"):
        m.synthesize(w)
    with pytest.raises(ShapeError, match="mode 'expression'"):
        m.synthesize(w)


def test_an_empty_batch_gives_no_faces():
    """Weights of no rows (a clip of no frames) raised numpy's broadcast error; numpy's rule
    for an empty batch is an empty result."""
    m = build_model(random_dataset(seed=10))
    w = {n: np.zeros((0, r)) for n, r in zip(m.mode_names, m.ranks)}
    assert m.synthesize(w).shape == (0, m.n_vertices, 3)
    assert m.synthesize(w, vertices=np.array([1, 2])).shape == (0, 2, 3)


def test_vertices_must_be_integer_indices():
    """A float selection was truncated (1.7 read as vertex 1) and a boolean mask read as the
    indices 0 and 1: synthesize returned the wrong vertices without a word."""
    m = build_model(random_dataset(seed=11))
    w = m.default_weights()
    with pytest.raises(ShapeError, match="integer vertex indices, got dtype float64"):
        m.synthesize(w, vertices=np.array([1.7, 2.2]))
    mask = np.zeros(m.n_vertices, bool)
    mask[[3, 7]] = True
    with pytest.raises(ShapeError, match=r"np.flatnonzero\(mask\)"):
        m.synthesize(w, vertices=mask)
    with pytest.raises(ShapeError, match="integer vertex indices"):
        m.mode_basis("expression", w, vertices=mask)
    sel = m.synthesize(w, vertices=np.flatnonzero(mask))
    np.testing.assert_allclose(sel, m.synthesize(w)[[3, 7]], atol=1e-12)
    assert m.synthesize(w, vertices=np.array([], np.int64)).shape == (0, 3)


def test_vertices_must_be_one_list_of_indices():
    """A (1, 2) selection was read flattened (the faces' shape not the selection's) and one
    index as a list of one, without a word; either is now refused, naming its shape."""
    m = build_model(random_dataset(seed=11))
    w = m.default_weights()
    for bad, shape in ((np.array([[1, 2]]), r"\(1, 2\)"), (np.int64(3), r"\(\)")):
        with pytest.raises(ShapeError, match=f"1-D array of vertex indices, got shape {shape}"):
            m.synthesize(w, vertices=bad)
        with pytest.raises(ShapeError, match="1-D array of vertex indices"):
            m.mode_basis("expression", w, vertices=bad)
    assert m.synthesize(w, vertices=[1, 2]).shape == (2, 3)


def test_batch_shapes_that_do_not_broadcast_name_the_modes():
    """Weights of 3 and of 4 frames raised numpy's broadcast ValueError (arg 0, arg 1), not a
    ShapeError naming the modes."""
    m = build_model(random_dataset(seed=12))
    W = {"identity": np.zeros((3, 5)), "expression": np.zeros((4, 4)), "viseme": np.zeros(3)}
    with pytest.raises(ShapeError, match=r"identity \(3, 5\), expression \(4, 4\)"):
        m.synthesize(W)
    with pytest.raises(ShapeError, match="do not broadcast"):
        m.clip_basis(W)


def test_quick_ict_model_separates_identity_and_expression(quick_model, quick_ict_dataset):
    # Real face data: the truncated model still reproduces training faces to sub-millimetre
    m, ds = quick_model, quick_ict_dataset
    f = m.synthesize(m.like(identity="id03", expression="smile"))
    err = np.abs(f - ds.vertices[3, 1]).max()
    # cm; ranks 5/5 of 6/6. Measured 0.042 cm (the smile is 1.05 cm from id03's neutral, 2.8 cm
    # from id02's smile)
    assert err < 0.1
    assert m.landmarks.shape == (68,)


def test_content_hash_is_the_sha256_of_the_arrays_bytes():
    # the hash reads the arrays' memory without copying it; it must equal the plain definition
    import hashlib
    import json

    from facetransfer.model import _content_hash

    rng = np.random.default_rng(0)
    arrays = {"a": rng.random((3, 4)), "b": np.arange(6).reshape(2, 3).T,
              "c": np.array(["ab", "c"]), "d": np.array(3.0), "e": np.zeros((0, 3)),
              "f": np.array([True, False]), "g": rng.random((4, 5)).astype(np.float32)[:, ::2]}
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        for part in (name.encode(), str(a.dtype).encode(), str(a.shape).encode(), a.tobytes()):
            h.update(part)
    h.update(json.dumps({"x": 1}, sort_keys=True).encode())
    assert _content_hash(arrays, {"x": 1}) == h.hexdigest()

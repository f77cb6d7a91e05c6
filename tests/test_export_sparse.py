"""The glb's morph targets stored sparsely: read back by a decoder written here from the glTF 2.0
specification (§3.6.2 Accessors: an accessor without ``bufferView`` is zeros; a ``sparse`` object
substitutes ``count`` elements at strictly increasing ``indices`` with ``values``), they are
exactly the dense deltas the exporter computes, bit for bit.

The default model's targets move nearly every vertex, so a real export is mostly dense; the
tests give the exporter a rig whose targets move a part of the face (a blink's lids), as an
artist's rig does, so that all three forms (zeros, sparse, dense) are in one file.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facetransfer.export import export_track
from facetransfer.export import gltf as glb
from facetransfer.export.common import identity_rig
from test_export import _validate

# glTF 2.0, Accessor Data Types: componentType -> numpy dtype (little endian); type -> components
COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _view_bytes(g, blob: bytes, view: int, offset: int | None, nbytes: int) -> bytes:
    bv = g.bufferViews[view]
    assert bv.byteStride is None  # tightly packed (the exporter writes no stride)
    start = bv.byteOffset + (offset or 0)
    assert start + nbytes <= bv.byteOffset + bv.byteLength
    return blob[start:start + nbytes]


def decode(g, i: int) -> np.ndarray:
    """Accessor ``i`` of the loaded pygltflib document ``g`` as the specification defines it:
    ``(count, components)`` in its component type."""
    acc, blob = g.accessors[i], g.binary_blob()
    dt, k = np.dtype(COMPONENTS[acc.componentType]), WIDTH[acc.type]
    if acc.bufferView is None:
        out = np.zeros((acc.count, k), dt)
    else:
        raw = _view_bytes(g, blob, acc.bufferView, acc.byteOffset, acc.count * k * dt.itemsize)
        out = np.frombuffer(raw, dt).reshape(acc.count, k).copy()
    sp = acc.sparse
    if sp is not None:
        idt = np.dtype(COMPONENTS[sp.indices.componentType])
        assert sp.indices.componentType in (5121, 5123, 5125)
        idx = np.frombuffer(_view_bytes(g, blob, sp.indices.bufferView, sp.indices.byteOffset,
                                        sp.count * idt.itemsize), idt).astype(np.int64)
        vals = np.frombuffer(_view_bytes(g, blob, sp.values.bufferView, sp.values.byteOffset,
                                         sp.count * k * dt.itemsize), dt).reshape(sp.count, k)
        assert sp.count >= 1 and np.all(np.diff(idx) > 0) and idx[-1] < acc.count
        out[idx] = vals
    return out


def localized(rig):
    """``rig`` with each target kept at a share of its vertices (those it moves most): none for
    target 0, then 1 %, 10 %, 50 % and all of them in turn."""
    deltas = np.array(rig.deltas, copy=True)
    keep = (0.0, 0.01, 0.1, 0.5, 1.0)
    for j, d in enumerate(deltas):
        share = 0.0 if j == 0 else keep[1 + (j - 1) % 4]
        size = np.linalg.norm(d, axis=1)
        if share < 1.0:
            d[size < np.quantile(size, 1.0 - share) if share else slice(None)] = 0.0
    return dataclasses.replace(rig, deltas=deltas)


def dense_deltas(rig, model, unit: float = glb.METRES_PER_UNIT):
    """What the dense file held: POSITION and NORMAL deltas ``(52, n, 3) float32`` each."""
    V = (rig.neutral * unit).astype(np.float32)
    faces = np.asarray(model.faces, np.int64)
    N = glb._normals(V, faces)
    P = np.stack([(d * unit).astype(np.float32) for d in rig.deltas])
    return P, np.stack([glb._normals(V + D, faces) - N for D in P])


@pytest.fixture(scope="module")
def case(arkit_model, make_arkit_track, tmp_path_factory):
    track, a, _ = make_arkit_track(arkit_model, 6)
    rig = localized(identity_rig(track, arkit_model))
    mp = pytest.MonkeyPatch()
    mp.setattr(glb, "identity_rig", lambda tr, m: rig)
    try:
        out = export_track(track, "glb", tmp_path_factory.mktemp("sparse") / "local.glb",
                           model=arkit_model)
    finally:
        mp.undo()
    return arkit_model, rig, out, track


def test_morph_encoding_picks_the_smallest_exact_form():
    a = np.zeros((100, 3), np.float32)
    assert glb.morph_encoding(a) == "zeros"
    a[7] = (-0.0, 0.0, -0.0)  # negative zero is zero
    assert glb.morph_encoding(a) == "zeros"
    a[7, 2] = 1e-30  # any nonzero component moves the vertex
    assert glb.morph_encoding(a) == "sparse"
    # 100 rows dense: 1200 bytes; k rows sparse: 14 k bytes (+2 padding when k is odd)
    a[:85] = 1.0
    assert glb.morph_encoding(a) == "sparse"  # 1190 + 2
    a[85] = 1.0
    assert glb.morph_encoding(a) == "dense"  # 1204
    # beyond 65536 vertices the indices are 4 bytes: 16 a row against 12
    b = np.zeros((70_000, 3), np.float32)
    b[:52_499] = 0.5
    assert glb.morph_encoding(b) == "sparse"  # 839 984 < 840 000
    b[52_499] = 0.5
    assert glb.morph_encoding(b) == "dense"


def test_sparse_targets_decode_to_the_dense_deltas_exactly(case):
    import pygltflib

    model, rig, out, track = case
    g = pygltflib.GLTF2().load(str(out))
    P, Nd = dense_deltas(rig, model)
    targets = g.meshes[0].primitives[0].targets
    assert len(targets) == 52
    forms = []
    for j, t in enumerate(targets):
        for acc, want in ((t["POSITION"], P[j]), (t["NORMAL"], Nd[j])):
            got = decode(g, acc)
            assert got.dtype == np.float32 and got.shape == want.shape
            np.testing.assert_array_equal(got, want)  # exact: no delta rounded or dropped
            a = g.accessors[acc]
            forms.append("zeros" if a.bufferView is None and a.sparse is None else
                         "sparse" if a.sparse is not None else "dense")
            assert forms[-1] == glb.morph_encoding(want)
            if a.sparse is not None:
                assert a.bufferView is None and a.sparse.indices.componentType == 5123
                assert a.sparse.count == np.count_nonzero((want != 0).any(axis=1))
                for v in (a.sparse.indices.bufferView, a.sparse.values.bufferView):
                    assert g.bufferViews[v].target is None  # Sparse Accessors: no target
        # POSITION's bounds over every vertex, the implied zeros too
        a = g.accessors[t["POSITION"]]
        assert a.min == P[j].min(axis=0).tolist() and a.max == P[j].max(axis=0).tolist()
    assert forms[:2] == ["zeros", "zeros"] and {"sparse", "dense"} <= set(forms)
    assert forms.count("sparse") >= 52  # 1 %, 10 %, 50 %: positions and normals
    issues = _validate(out)  # last: skips when node or the validator is absent
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_the_sparse_file_is_smaller_by_the_bytes_left_out(case, tmp_path, monkeypatch):
    """The same rig written densely (every accessor as before) is larger by exactly the
    dense bytes of each zeros/sparse accessor minus its sparse bytes."""
    from facetransfer.export.gltf_eyes import socket_cones

    model, rig, out, track = case
    P, Nd = dense_deltas(rig, model)
    V = (rig.neutral * glb.METRES_PER_UNIT).astype(np.float32)
    cones = [c[2] for c in (glb.mouth_cone(model, V, P), socket_cones(model, V, P)) if c]
    saved = 0
    for D in (*P, *Nd, *(d for c in cones for d in c)):   # the face's, the cavities' targets
        how = glb.morph_encoding(D)
        moved = int(np.count_nonzero((D != 0).any(axis=1)))
        saved += {"zeros": D.nbytes, "dense": 0,
                  "sparse": D.nbytes - moved * 14 - (-moved * 2) % 4}[how]
    monkeypatch.setattr(glb, "morph_encoding", lambda a: "dense")
    monkeypatch.setattr(glb, "identity_rig", lambda tr, m: rig)
    dense = export_track(track, "glb", tmp_path / "dense.glb", model=model)
    diff = dense.stat().st_size - out.stat().st_size
    print(f"dense {dense.stat().st_size} B, sparse {out.stat().st_size} B, saved {saved} B")
    assert saved > 0.3 * dense.stat().st_size
    # the rest is JSON: a sparse accessor's own object and one more buffer view, a zeros
    # accessor's missing view, the chunks' padding; under 200 bytes an accessor
    assert abs(diff - saved) < 200 * 104, (diff, saved)


def test_more_than_65536_vertices_take_4_byte_indices(tmp_path):
    import pygltflib

    n = 70_000
    a = np.zeros((n, 3), np.float32)
    rows = np.array([0, 3, 65_535, 65_536, 69_999])
    a[rows] = np.arange(15, dtype=np.float32).reshape(5, 3) - 7.5
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
    blob = glb._Blob(g)
    i = blob.morph_accessor(a, bounds=True)
    data = blob.buf.getvalue()
    data += b"\0" * ((-len(data)) % 4)
    g.buffers.append(pygltflib.Buffer(byteLength=len(data)))
    g.set_binary_blob(data)
    g.save_binary(str(tmp_path / "big.glb"))
    h = pygltflib.GLTF2().load(str(tmp_path / "big.glb"))
    acc = h.accessors[i]
    assert acc.sparse.indices.componentType == 5125 and acc.sparse.count == 5
    np.testing.assert_array_equal(decode(h, i), a)
    assert acc.min == [-7.5, -6.5, -5.5] and acc.max == [4.5, 5.5, 6.5]

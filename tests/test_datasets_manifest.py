"""Manifest CSV and FaceWarehouse readers on small generated meshes; the load_dataset dispatcher."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer.datasets import load_dataset, read_facewarehouse, read_manifest
from facetransfer.errors import DatasetError, MeshError
from facetransfer.io.mesh import write_mesh


def patch(n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([x.ravel(), y.ravel(), 0.1 * x.ravel() * y.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)


def cell_vertices(i: int, e: int, v: int = 0) -> np.ndarray:
    """Ground truth of cell (identity i, expression e, viseme v): exactly representable values."""
    V, _ = patch()
    return V * (1 + 0.25 * i) + np.array([0.0, 0.0, 0.125 * e + 0.5 * v]) * V[:, :1]


def make_manifest(root, cells, *, header="path,identity,expression", fmt="obj", extra_rows=()):
    _, F = patch()
    lines = [header]
    for cell in cells:
        i, e = cell[:2]
        name = f"m_{'_'.join(map(str, cell))}.{fmt}"
        sub = root / f"id{i}"
        sub.mkdir(parents=True, exist_ok=True)
        write_mesh(sub / name, cell_vertices(*cell), F)
        labels = [f"id{i}", f"ex{e}"] + ([f"vi{cell[2]}"] if len(cell) > 2 else [])
        lines.append(",".join([f"id{i}/{name}"] + labels))
    lines += list(extra_rows)
    p = root / "manifest.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_complete_manifest(tmp_path):
    cells = [(i, e) for i in range(3) for e in range(2)]
    ds = read_manifest(make_manifest(tmp_path, cells))
    assert ds.mode_names == ("identity", "expression")
    assert ds.labels == (("id0", "id1", "id2"), ("ex0", "ex1"))
    assert ds.mask.all() and ds.vertices.shape == (3, 2, 16, 3)
    for i, e in cells:
        np.testing.assert_allclose(ds.vertices[i, e], cell_vertices(i, e), atol=1e-6)
    assert ds.faces.shape == (18, 3) and ds.provenance["missing"] == []


def test_missing_cells_masked_and_reported(tmp_path):
    cells = [(0, 0), (0, 1), (1, 0), (2, 0), (2, 1)]
    ds = read_manifest(make_manifest(tmp_path, cells))
    assert ds.mask.tolist() == [[True, True], [True, False], [True, True]]
    assert np.isnan(ds.vertices[1, 1]).all() and np.isfinite(ds.vertices[ds.mask]).all()
    assert ds.missing_cells() == [("id1", "ex1")]
    assert ds.provenance["missing"] == [["id1", "ex1"]]


def test_trilinear_manifest_with_ply(tmp_path):
    cells = [(i, e, v) for i in range(2) for e in range(2) for v in range(3)]
    ds = read_manifest(make_manifest(tmp_path, cells, header="path,identity,expression,viseme",
                                     fmt="ply"))
    assert ds.mode_names == ("identity", "expression", "viseme") and ds.shape == (2, 2, 3)
    np.testing.assert_allclose(ds.vertices[1, 0, 2], cell_vertices(1, 0, 2), atol=1e-6)


def test_vertex_count_mismatch_names_file_and_counts(tmp_path):
    p = make_manifest(tmp_path, [(0, 0), (0, 1), (1, 0)])
    V, F = patch(3)
    write_mesh(tmp_path / "small.obj", V, F)
    p.write_text(p.read_text() + "small.obj,id1,ex1\n")
    with pytest.raises(DatasetError, match=r"small.obj has 9 vertices but .* has 16"):
        read_manifest(p)


@pytest.mark.parametrize("content, err, pattern", [
    ("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", MeshError, "NaN or infinite"),
    ("", MeshError, "is empty"),
    ("hello\n", MeshError, "no vertices"),
])
@pytest.mark.parametrize("first", [False, True])
def test_bad_mesh_files(tmp_path, content, err, pattern, first):
    p = make_manifest(tmp_path, [(0, 0), (1, 0)])
    (tmp_path / "bad.obj").write_text(content)
    head, *rows = p.read_text().splitlines()
    rows = ["bad.obj,id1,ex1"] + rows if first else rows + ["bad.obj,id1,ex1"]
    p.write_text("\n".join([head] + rows) + "\n")
    with pytest.raises(err, match=pattern) as ei:
        read_manifest(p)
    assert "bad.obj" in str(ei.value)


def test_missing_mesh_file(tmp_path):
    p = make_manifest(tmp_path, [(0, 0), (1, 0)], extra_rows=["nothere.obj,id1,ex1"])
    with pytest.raises(MeshError, match="nothere.obj does not exist"):
        read_manifest(p)


def test_manifest_errors(tmp_path):
    p = make_manifest(tmp_path, [(0, 0), (1, 0)], extra_rows=["id1/m_1_0.obj,id1,ex0"])
    with pytest.raises(DatasetError, match="line 4: duplicate cell .*id1.*ex0"):
        read_manifest(p)
    q = make_manifest(tmp_path / "b", [(0, 0), (1, 0)], header="path,identity,expression,mood")
    q.write_text(q.read_text().replace("\n", ",x\n").replace("mood,x", "mood"))
    with pytest.raises(DatasetError, match=r"unknown column\(s\) \['mood'\]"):
        read_manifest(q)
    r = make_manifest(tmp_path / "c", [(0, 0), (0, 1)])
    with pytest.raises(DatasetError, match="only one identity"):
        read_manifest(r)
    s = tmp_path / "empty.csv"
    s.write_text("")
    with pytest.raises(DatasetError, match="is empty"):
        read_manifest(s)
    t = tmp_path / "nopath.csv"
    t.write_text("identity,expression\na,b\n")
    with pytest.raises(DatasetError, match="missing column 'path'"):
        read_manifest(t)
    u = tmp_path / "short.csv"
    u.write_text("path,identity,expression\na.obj,x\n")
    with pytest.raises(DatasetError, match="line 2: 2 fields, expected 3"):
        read_manifest(u)


def _facewarehouse(root, testers=(1, 2, 10), shapes=(0, 1, 2, 11), drop=()):
    _, F = patch()
    for t in testers:
        d = root / f"Tester_{t}" / "Blendshape"
        d.mkdir(parents=True)
        for k in shapes:
            if (t, k) not in drop:
                write_mesh(d / f"shape_{k}.obj", cell_vertices(t, k), F)
    (root / f"Tester_{testers[0]}" / "Blendshape" / "readme.txt").write_text("not a shape")
    return root


def test_facewarehouse_layout(tmp_path):
    root = _facewarehouse(tmp_path / "fw", drop={(1, 11)})
    ds = read_facewarehouse(root)
    assert ds.labels == (("Tester_1", "Tester_2", "Tester_10"), ("shape_0", "shape_1", "shape_2", "shape_11"))
    np.testing.assert_allclose(ds.vertices[2, 3], cell_vertices(10, 11), atol=1e-6)
    np.testing.assert_allclose(ds.vertices[1, 2], cell_vertices(2, 2), atol=1e-6)
    assert ds.mask.sum() == 11 and not ds.mask[0, 3]
    assert ds.missing_cells() == [("Tester_1", "shape_11")]
    same = load_dataset(root)
    np.testing.assert_array_equal(same.mask, ds.mask)


def test_facewarehouse_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no Tester_N/Blendshape"):
        read_facewarehouse(tmp_path / "empty")
    with pytest.raises(DatasetError, match="does not exist"):
        read_facewarehouse(tmp_path / "nope")
    root = _facewarehouse(tmp_path / "one", testers=(3,))
    with pytest.raises(DatasetError, match="only one identity"):
        read_facewarehouse(root)


def test_load_dataset_dispatch(tmp_path):
    p = make_manifest(tmp_path, [(0, 0), (1, 0)])
    assert load_dataset(str(p)).shape == (2, 1)
    with pytest.raises(DatasetError, match="manifest .* does not exist"):
        load_dataset(tmp_path / "nothere.csv")
    (tmp_path / "plain").mkdir()
    with pytest.raises(DatasetError, match=r"not in the FaceWarehouse layout .*other meshes "
                       r"are listed in a manifest \.csv \(columns path, identity, expression"):
        load_dataset(tmp_path / "plain")
    (tmp_path / "plain" / "scans.csv").write_text("path,identity,expression\n")
    with pytest.raises(DatasetError, match="viseme]\\): it holds scans.csv$"):
        load_dataset(tmp_path / "plain")
    with pytest.raises(DatasetError, match="unknown data set 'ict-bogus'"):
        load_dataset("ict-bogus")

"""``facetransfer model build|info|synth|sheet`` end to end on small generated data sets."""

from __future__ import annotations

import sys
import types
from dataclasses import dataclass

import numpy as np
import pytest
from PIL import Image

from facetransfer.cli.main import main
from facetransfer.cli.model import parse_like, parse_ranks, parse_weights
from facetransfer.errors import FaceTransferError
from facetransfer.io.mesh import read_obj_vertices
from facetransfer.model import load_model

from test_datasets_manifest import cell_vertices, make_manifest


def run(capsys, *argv):
    code = main(list(map(str, argv)))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def manifest(tmp_path):
    return make_manifest(tmp_path / "data", [(i, e) for i in range(3) for e in range(3)])


@pytest.fixture
def model_path(manifest, tmp_path, capsys):
    out = tmp_path / "m.npz"
    code, o, err = run(capsys, "model", "build", "--dataset", manifest, "--out", out)
    assert code == 0, err
    return out


def test_parsers():
    assert parse_ranks("identity=9, expression=6") == {"identity": 9, "expression": 6}
    assert parse_ranks(None) == {}
    w = parse_weights("identity=0.5,-1;expression=2")
    np.testing.assert_array_equal(w["identity"], [0.5, -1.0])
    assert parse_like("identity=id03,expression=smile") == {"identity": "id03", "expression": "smile"}
    for bad in ("identity", "identity=0", "identity=x", "=3"):
        with pytest.raises(FaceTransferError, match="--ranks"):
            parse_ranks(bad)
    with pytest.raises(FaceTransferError, match="--weights"):
        parse_weights("identity=1,nan")
    with pytest.raises(FaceTransferError, match="--like"):
        parse_like("identity")



def test_a_mode_given_twice_is_refused():
    """``--weights 'identity=1,0,0;identity=0,1,0'`` wrote the second identity's face without
    a word (also --like and --ranks: the last of a mode was taken)."""
    for parse, flag, text in [(parse_weights, "--weights", "identity=1,0;identity=0,1"),
                              (parse_like, "--like", "identity=id01,identity=id02"),
                              (parse_ranks, "--ranks", "identity=2,identity=3")]:
        with pytest.raises(FaceTransferError, match=f"{flag} gives mode 'identity' twice"):
            parse(text)


def test_build_info_synth_like_reproduces_training_mesh(model_path, tmp_path, capsys):
    m = load_model(model_path)
    assert m.mode_names == ("identity", "expression") and m.ranks == (3, 3)
    code, out, _ = run(capsys, "model", "info", model_path)
    assert code == 0
    assert "mode identity: 3 training entries, rank 3" in out and "explained variance" in out
    assert "manifest.csv" in out  # provenance names the source
    face = tmp_path / "f.obj"
    code, _, err = run(capsys, "model", "synth", model_path, "--like", "identity=id2,expression=ex1",
                       "--out", face)
    assert code == 0, err
    np.testing.assert_allclose(read_obj_vertices(face), cell_vertices(2, 1), atol=2e-6)
    # explicit weights = the training rows give the same face
    wi = ",".join(repr(float(x)) for x in m.training_weights("identity", "id1"))
    we = ",".join(repr(float(x)) for x in m.training_weights("expression", "ex2"))
    face2 = tmp_path / "g.ply"
    code, _, err = run(capsys, "model", "synth", model_path, "--weights",
                       f"identity={wi};expression={we}", "--out", face2)
    assert code == 0, err
    import trimesh

    v = np.asarray(trimesh.load(face2, process=False).vertices)
    np.testing.assert_allclose(v, cell_vertices(1, 2), atol=1e-6)


def test_synth_bad_input(model_path, tmp_path, capsys):
    out = tmp_path / "x.obj"
    cases = [
        (["--weights", "identity=1,2"], "identity has 2 values; the model's identity rank is 3"),
        (["--like", "identity=nobody"], "unknown identity 'nobody'"),
        (["--like", "mood=happy"], "unknown mode 'mood'"),
        (["--like", "identity=id1", "--weights", "identity=1,2,3"], "not --weights and --like"),
    ]
    for extra, msg in cases:
        code, _, err = run(capsys, "model", "synth", model_path, *extra, "--out", out)
        assert code == 2 and msg in err and err.count("\n") == 1, err
        assert not out.exists()
    code, _, err = run(capsys, "model", "synth", model_path, "--out", tmp_path / "x.csv")
    assert code == 2 and ".obj, .ply, .stl, .off or .glb, not .csv; name it x.obj" in err
    assert not (tmp_path / "x.csv").exists()


def test_weights_beyond_the_model_are_refused_naming_them(model_path, tmp_path, capsys):
    """``--weights identity=1e308,...`` overflowed the face; the mesh writer then said "mesh
    x.obj has ... vertices with NaN or infinite coordinates", naming the output as if it were
    a bad input. Weights a thousand times beyond the training ones are now refused."""
    out = tmp_path / "x.obj"
    for big in ("1e308", "1e300", "1e9"):
        code, _, err = run(capsys, "model", "synth", model_path, "--weights",
                           f"identity={big},0,0", "--out", out)
        assert code == 2 and err.count("\n") == 1, err
        assert "--weights of mode 'identity'" in err and "1000 times" in err, err
        assert not out.exists()
    code, _, err = run(capsys, "model", "synth", model_path, "--weights", "identity=3,-2,1",
                       "--out", out)     # beyond the training faces, a researcher's choice
    assert code == 0, err


def test_build_bad_input_leaves_no_file(manifest, tmp_path, capsys):
    out = tmp_path / "bad.npz"
    code, _, err = run(capsys, "model", "build", "--dataset", manifest, "--ranks", "identity=5",
                       "--out", out)
    assert code == 2 and "identity=5 is larger than the 3" in err and not out.exists()
    code, _, err = run(capsys, "model", "build", "--dataset", tmp_path / "nope.csv", "--out", out)
    assert code == 2 and "does not exist" in err and not out.exists()
    code, _, err = run(capsys, "model", "build", "--dataset", manifest, "--out",
                       tmp_path / "nofolder" / "m.npz")
    assert code == 2 and "output folder" in err
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(b"PK\x03\x04 truncated")
    code, _, err = run(capsys, "model", "info", trunc)
    assert code == 2 and err.startswith("facetransfer model ") and err.count("\n") == 1


def test_missing_cells_error_lists_them(tmp_path, capsys):
    cells = [(i, e) for i in range(3) for e in range(3) if (i, e) not in {(1, 2), (2, 0)}]
    man = make_manifest(tmp_path / "d", cells)
    out = tmp_path / "m.npz"
    code, _, err = run(capsys, "model", "build", "--dataset", man, "--impute", "none", "--out", out)
    assert code == 2 and "2 missing cells" in err and "id1/ex2" in err and "id2/ex0" in err
    assert not out.exists()


@dataclass(frozen=True)
class _FakeImputation:
    dataset: object
    imputed: np.ndarray


def test_missing_cells_are_imputed_and_recorded(tmp_path, capsys, monkeypatch):
    """The CLI hands missing cells to facetransfer.impute and records what was filled."""
    calls = []

    def impute_dataset(ds, *, method, rng, progress=None):
        calls.append(method)
        v = ds.vertices.copy()
        mean = np.nanmean(v, axis=0)  # per-expression average over identities
        miss = ~ds.mask
        v[miss] = np.broadcast_to(mean, v.shape)[miss]
        return _FakeImputation(ds.with_vertices(v, np.ones_like(ds.mask)), miss)

    fake = types.ModuleType("facetransfer.impute")
    fake.impute_dataset = impute_dataset
    monkeypatch.setitem(sys.modules, "facetransfer.impute", fake)
    cells = [(i, e) for i in range(3) for e in range(3) if (i, e) != (1, 2)]
    man = make_manifest(tmp_path / "d", cells)
    out = tmp_path / "m.npz"
    code, _, err = run(capsys, "model", "build", "--dataset", man, "--impute", "average", "--out", out)
    assert code == 0, err
    assert calls == ["average"] and "imputed 1 missing cells (average)" in err
    m = load_model(out)
    assert m.imputed is not None and m.imputed.tolist() == [[False] * 3, [False, False, True], [False] * 3]
    assert m.provenance["imputed_cells"] == [["id1", "ex2"]]
    filled = m.synthesize(m.like(identity="id1", expression="ex2"))
    expect = (cell_vertices(0, 2) + cell_vertices(2, 2)) / 2
    np.testing.assert_allclose(filled, expect, atol=1e-6)


def test_sheet_writes_two_pictures(model_path, tmp_path, capsys):
    out = tmp_path / "sheet.png"
    code, _, err = run(capsys, "model", "sheet", model_path, "--out", out)
    assert code == 0, err
    a = np.asarray(Image.open(out))
    b = np.asarray(Image.open(tmp_path / "sheet_dials.png"))
    # 3 identity rows x 3 expression columns of 150x180 tiles plus headers
    assert a.shape == (36 + 3 * 180, 90 + 3 * 150, 3)
    # every tile shows a face (non-white pixels)
    for i in range(3):
        for j in range(3):
            tile = a[36 + i * 180: 36 + (i + 1) * 180, 90 + j * 150: 90 + (j + 1) * 150]
            assert (tile.min(axis=2) < 200).mean() > 0.05
    assert b.shape[1] == 90 + 5 * 150 and b.shape[0] > 36
    code, _, err = run(capsys, "model", "sheet", model_path, "--out", tmp_path / "s.jpg")
    assert code == 2 and ".png" in err


def test_build_ict_with_default_ranks(data_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    out = tmp_path / "ict.npz"
    code, o, err = run(capsys, "model", "build", "--dataset", "ict-bilinear", "--identities", "3",
                       "--no-refine", "--out", out)
    assert code == 0, err
    m = load_model(out)
    assert m.ranks == (3, 6) and m.shape == (3, 10)  # identity rank 9 clipped to 3 identities
    assert m.provenance["dataset"] == "ict-bilinear" and m.provenance["refine"] is False
    assert m.landmarks is not None and m.landmarks.shape == (68,)
    code, o, _ = run(capsys, "model", "info", out)
    assert "mode expression: 10 training entries, rank 6" in o


def test_fallback_painter_matches_renderer_silhouette(model_path):
    """The private matplotlib fallback draws the same face region as facetransfer.render."""
    from facetransfer.cli.model import TILE, _camera, _fallback_render, _render_tile

    m = load_model(model_path)
    v = m.synthesize(m.default_weights())
    cam = _camera(v, TILE)
    a = _render_tile(v, m.faces, cam, TILE)
    b = _fallback_render(v, m.faces, cam, TILE)
    assert a.shape == b.shape == (TILE[1], TILE[0], 3)
    ma, mb = a.min(axis=2) < 250, b.min(axis=2) < 250
    iou = (ma & mb).sum() / (ma | mb).sum()
    assert ma.sum() > 500 and iou > 0.85, iou


def test_missing_cells_with_real_imputation(tmp_path, capsys):
    pytest.importorskip("facetransfer.impute")
    cells = [(i, e) for i in range(4) for e in range(3) if (i, e) != (1, 2)]
    man = make_manifest(tmp_path / "d", cells)
    out = tmp_path / "m.npz"
    code, _, err = run(capsys, "model", "build", "--dataset", man, "--out", out)  # default ppca
    assert code == 0, err
    assert "imputed 1 missing cells (ppca)" in err
    m = load_model(out)
    assert m.imputed[1, 2] and m.imputed.sum() == 1
    # the generated data are exactly of multilinear rank (2, 2): the fill is the true mesh
    filled = m.synthesize(m.like(identity="id1", expression="ex2"))
    truth = cell_vertices(1, 2)
    assert np.linalg.norm(filled - truth) / np.linalg.norm(truth) < 1e-3


def test_console_script_freezes_the_collector_and_a_caller_keeps_it(model_path, capsys,
                                                                      monkeypatch):
    """The console script (``main()`` with no argv) freezes every live object when its command
    returns, which spares the interpreter's final collection; ``main(argv)`` called by a
    program that goes on leaves the collector as it was, and so does the console script once
    OpenImageIO was loaded (its bindings report frozen objects as leaked at the exit)."""
    import gc
    import types

    monkeypatch.delitem(sys.modules, "OpenImageIO", raising=False)  # another test's import
    gc.unfreeze()
    code, out, _ = run(capsys, "model", "info", model_path)
    assert code == 0 and gc.get_freeze_count() == 0
    monkeypatch.setattr(sys, "argv", ["facetransfer", "model", "info", str(model_path)])
    try:
        assert main() == 0
        assert gc.get_freeze_count() > 1000
        gc.unfreeze()
        monkeypatch.setitem(sys.modules, "OpenImageIO", types.ModuleType("OpenImageIO"))
        assert main() == 0
        assert gc.get_freeze_count() == 0
    finally:
        gc.unfreeze()
    assert capsys.readouterr().out == out + out


def test_model_info_is_read_by_a_person_and_whole_as_json(quick_model, quick_model_path, capsys):
    """Every line short (before, the provenance was one line of 2,000 characters of JSON, cut
    mid-value, and the per-component variances one of 600); ``--json`` holds it all."""
    import json

    code, out, _ = run(capsys, "model", "info", quick_model_path)
    assert code == 0 and max(len(line) for line in out.splitlines()) <= 110
    assert "  provenance (--json: all of it):" in out
    code, out, _ = run(capsys, "model", "info", quick_model_path, "--json")
    d = json.loads(out)
    assert d["ranks"] == list(quick_model.ranks) and d["mode_names"] == ["identity", "expression"]
    assert d["provenance"]["dataset"] == quick_model.provenance["dataset"]


def _paper_through_the_face(tile: np.ndarray) -> int:
    """White pixels (the sheet's paper) enclosed by a tile's face: its eye holes and mouth gap
    left open."""
    from scipy.ndimage import binary_fill_holes

    face = tile.min(axis=2) < 245
    return int((binary_fill_holes(face) & ~face).sum())


def test_sheets_draw_the_eyes_and_mouth_as_the_puppet(arkit_model_path, tmp_path, capsys):
    """``model sheet`` and ``model dials --out``: the tiles' eye holes and mouth gap showed the
    white paper (a face with blank eyes; an eyeLook* column looked like neutral); they are
    drawn as ``render`` and ``puppet`` draw them, the eyes turned by the column's gaze."""
    out = tmp_path / "sheet.png"
    code, _, err = run(capsys, "model", "sheet", arkit_model_path, "--out", out,
                       "--max-identities", "1")
    assert code == 0, err
    a = np.asarray(Image.open(out).convert("RGB"))
    names = load_model(arkit_model_path).labels[1]
    tiles = {n: a[36:36 + 180, 90 + j * 150: 90 + (j + 1) * 150] for j, n in enumerate(names)}
    assert max(_paper_through_the_face(t) for t in tiles.values()) < 5
    assert min((t.min(axis=2) < 245).mean() for t in tiles.values()) > 0.1   # faces drawn
    eyes = (slice(55, 95), slice(40, 110))       # the eyes' band of a tile
    gaze = np.abs(tiles["eyeLookInLeft"][eyes].astype(int) - tiles["neutral"][eyes]).max(axis=2)
    assert (gaze > 40).sum() > 5                 # an iris moved
    assert main(["model", "dials", str(arkit_model_path), "--out",
                 str(tmp_path / "dials.png")]) == 0
    d = np.asarray(Image.open(tmp_path / "dials.png").convert("RGB"))
    first = d[24:24 + 170, 130:130 + 3 * 140]    # the first dial's row of tiles
    assert sum(_paper_through_the_face(first[:, k * 140:(k + 1) * 140]) for k in range(3)) < 5

"""``facetransfer impute eval`` on a tiny generated manifest."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facetransfer.cli.main import main
from facetransfer.io.mesh import write_mesh

EXPRESSIONS = ("neutral", "smile", "open", "frown")


def _grid(n=7):
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    V = np.stack([x.ravel(), y.ravel(), 0.3 * np.exp(-(x ** 2 + y ** 2)).ravel()], axis=1)
    F = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            F += [[a, a + 1, a + n], [a + 1, a + n + 1, a + n]]
    return V, np.array(F, dtype=np.int64)


def write_manifest(folder, n_id=5, expressions=EXPRESSIONS, skip=(), seed=0):
    """Meshes of a bilinear toy face family and a manifest listing them (``skip``: cells not
    listed)."""
    rng = np.random.default_rng(seed)
    V, F = _grid()
    n = len(V)
    id_shapes = 0.1 * rng.normal(size=(n_id, n, 3))
    styles = 0.2 * rng.normal(size=(len(expressions), 2, n, 3))
    coef = np.stack([np.ones(n_id), 0.5 * rng.normal(size=n_id)], axis=1)
    rows = ["path,identity,expression"]
    for i in range(n_id):
        for e, name in enumerate(expressions):
            if (i, e) in skip:
                continue
            disp = 0 if e == 0 else np.einsum("k,kvc->vc", coef[i], styles[e])
            p = folder / f"id{i}_{name}.obj"
            write_mesh(p, V + id_shapes[i] + disp, F)
            rows.append(f"{p.name},id{i},{name}")
    csv = folder / "manifest.csv"
    csv.write_text("\n".join(rows) + "\n")
    return csv


def test_eval_writes_report_and_figures(tmp_path, capsys):
    csv = write_manifest(tmp_path)
    out = tmp_path / "eval"
    rc = main(["impute", "eval", "--dataset", str(csv), "--missing", "0.2,0.3", "--trials", "2",
               "--seed", "1", "--out", str(out)])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert len(rep["results"]) == 4 * 2
    for r in rep["results"]:
        assert set(r) >= {"method", "missing", "error_mean", "error_max", "relative_error_mean",
                          "seconds"}
        assert r["method"] in ("ppca", "average", "naive", "tensorly")
        assert r["missing"] in (0.2, 0.3)
        assert 0 <= r["error_mean"] <= r["error_max"]
        assert len(r["errors"]) == 2
    by = {(r["method"], r["missing"]): r for r in rep["results"]}
    # the toy family is bilinear: our scheme beats copying the mean displacement
    assert by[("ppca", 0.2)]["relative_error_mean"] < by[("average", 0.2)]["relative_error_mean"]
    for name in ("error_vs_missing.png", "fig4.png"):
        assert (out / name).stat().st_size > 1000
    assert not list(out.glob(".*part*"))  # no temporary files left
    said = capsys.readouterr().out
    assert "ppca" in said
    # every file written is named (before: only report.json)
    assert said.strip().splitlines()[-1] == (f"wrote {out / 'report.json'}, "
                                             f"{out / 'error_vs_missing.png'}, {out / 'fig4.png'}")


def test_eval_keeps_an_earlier_runs_results_unless_overwrite(tmp_path, capsys):
    """A second run into the same folder is refused before any work, naming the result it
    would replace, and the first run's files are left as they were; --overwrite replaces."""
    csv = write_manifest(tmp_path)
    out = tmp_path / "eval"
    argv = ["impute", "eval", "--dataset", str(csv), "--missing", "0.2", "--trials", "1",
            "--methods", "average", "--out", str(out), "--no-figures"]
    assert main(argv) == 0
    before = (out / "report.json").read_bytes()
    capsys.readouterr()
    assert main(argv[:-1] + ["--seed", "5", "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "report.json" in err[0] and "--overwrite" in err[0], err
    assert (out / "report.json").read_bytes() == before
    assert main(argv + ["--seed", "5", "--overwrite"]) == 0
    assert json.loads((out / "report.json").read_text())["seed"] == 5


def test_eval_on_a_manifest_with_missing_cells(tmp_path):
    csv = write_manifest(tmp_path, skip={(1, 2), (3, 1)})
    out = tmp_path / "eval"
    rc = main(["impute", "eval", "--dataset", str(csv), "--missing", "0.15", "--trials", "1",
               "--methods", "ppca,average", "--out", str(out), "--no-figures"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert {r["method"] for r in rep["results"]} == {"ppca", "average"}
    assert not (out / "fig4.png").exists()


@pytest.mark.parametrize("args, message", [
    (["--missing", "0.2,1.5"], "--missing fractions must be in (0, 1)"),
    (["--missing", "a,b"], "--missing must be comma-separated numbers"),
    (["--methods", "ppca,magic"], "unknown method 'magic'"),
    (["--trials", "0"], "--trials must be at least 1"),
    # given twice: run twice, every row printed and written twice (before)
    (["--missing", "0.1,0.2,0.1"], "--missing gives 0.1 twice: give each once"),
    (["--methods", "average,ppca,average"], "--methods gives 'average' twice"),
])
def test_eval_bad_options_exit_2(tmp_path, capsys, args, message):
    csv = write_manifest(tmp_path)
    rc = main(["impute", "eval", "--dataset", str(csv), "--out", str(tmp_path / "o")] + args)
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o" / "report.json").exists()


def test_eval_bad_data_exit_2(tmp_path, capsys):
    rc = main(["impute", "eval", "--dataset", str(tmp_path / "nope.csv"), "--out",
               str(tmp_path / "o")])
    assert rc == 2
    assert "nope.csv" in capsys.readouterr().err
    # an expression nobody performed cannot be imputed; too many held-out cells either
    csv = write_manifest(tmp_path, n_id=3, expressions=("neutral", "smile"))
    rc = main(["impute", "eval", "--dataset", str(csv), "--missing", "0.9", "--out",
               str(tmp_path / "o")])
    assert rc == 2
    assert "cannot hide" in capsys.readouterr().err

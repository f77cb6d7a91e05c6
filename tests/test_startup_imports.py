"""What a command's start-up imports: the transfer's modules stay clear of SciPy's sparse
solvers and of urllib, which only model building, the Poisson blend and downloads need
(BENCHMARKS.md, "Twelfth session")."""

from __future__ import annotations

import subprocess
import sys


def _imported(modules: list[str], probes: list[str]) -> dict[str, bool]:
    """Whether each of ``probes`` is in ``sys.modules`` of a fresh interpreter that imported
    ``modules``."""
    code = (f"import sys\nfor m in {modules!r}: __import__(m)\n"
            f"print(' '.join(str(p in sys.modules) for p in {probes!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    return dict(zip(probes, (v == "True" for v in out)))


def test_the_transfers_modules_do_not_import_solvers_or_urllib():
    seen = _imported(["facetransfer.model", "facetransfer.composite", "facetransfer.rewrite",
                      "facetransfer.video_transfer", "facetransfer.cli.transfer",
                      "facetransfer.assets"],
                     ["scipy.sparse.linalg", "scipy.sparse.csgraph", "urllib.request",
                      "facetransfer.datasets.deformation", "facetransfer.datasets.base"])
    assert seen == {"scipy.sparse.linalg": False, "scipy.sparse.csgraph": False,
                    "urllib.request": False, "facetransfer.datasets.deformation": False,
                    "facetransfer.datasets.base": True}


def test_the_datasets_builders_load_on_first_use():
    """The names of ``facetransfer.datasets`` still import from it, as before the change."""
    import facetransfer.datasets as ds

    from facetransfer.datasets import ICT_DATASETS, build_ict_dataset, deformation_gradients

    assert "ict-arkit" in ICT_DATASETS and callable(build_ict_dataset)
    assert deformation_gradients is ds.deformation.deformation_gradients
    assert {"load_recipes", "read_manifest", "DeformationTransfer"} <= set(dir(ds))
    try:
        ds.no_such_name
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:
        raise AssertionError("an unknown name must raise AttributeError")

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


def test_the_transfer_reaches_its_fork_without_the_renderers_modules():
    """What ``facetransfer transfer`` imports before it forks the expression source's tracker
    leaves the renderer's modules (and SciPy's ndimage, 0.13-0.15 CPU-s, which the tracker
    does not need) to the parent after the fork: they delayed the fork."""
    seen = _imported(["facetransfer.cli.transfer", "facetransfer.video_transfer",
                      "facetransfer.transfer_plan", "facetransfer.track.capture",
                      "facetransfer.track.detect", "facetransfer.track.obtain",
                      "facetransfer.io.prefetch"],
                     ["scipy.ndimage", "facetransfer.composite", "facetransfer.rewrite",
                      "facetransfer.rewrite_clip"])
    assert not any(seen.values()), seen


def test_the_plan_imports_the_renderers_modules_on_a_thread(arkit_model_path):
    """:func:`facetransfer.transfer_plan._setup_ahead` (started once the tracker is forked)
    imports every module of ``RENDER_MODULES`` on a thread of its own, and makes the model's
    parts of the regions there."""
    code = ("import sys, threading; from facetransfer import transfer_plan as tp\n"
            "from facetransfer.rewrite_options import RewriteOptions\n"
            "from facetransfer.model import load_model\n"
            f"m = load_model({str(arkit_model_path)!r})\n"
            "a = tp._setup_ahead(m, RewriteOptions())\n"
            "print(a._thread.name != threading.current_thread().name)\n"
            "topo, rig = tp._made_ahead(a); print(all(m in sys.modules for m in "
            "tp.RENDER_MODULES), 'scipy.ndimage' in sys.modules, topo is not None, "
            "rig is not None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["True"] * 5


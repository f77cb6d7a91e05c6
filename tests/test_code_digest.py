"""What a cache's key holds of the package's code (facetransfer.code_digest): the modules a
result's code can run, found from their imports, and the track cache's key built on them
(BENCHMARKS.md, "Fifty-fourth session (helper cache54)")."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import pytest

from facetransfer import code_digest
from facetransfer.track import cache


@pytest.fixture(autouse=True, scope="module")
def _own_memo(tmp_path_factory):
    """A user cache of this module's own: the memo of parsed files starts empty (the package
    is parsed once for all its tests)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("cache")))
        yield


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    """A package ``facetransfer`` of ``files`` (path -> source) in ``tmp_path``."""
    root = tmp_path / "pkg" / "facetransfer"
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(textwrap.dedent(text))
    return root


def test_the_closure_follows_every_kind_of_import(tmp_path):
    """Each way a module comes to run: a module-level and a function's own import, relative and
    absolute, a submodule named in ``from P import N``, a package's ``__init__`` run first, a
    lazy name's table (``lazy_names``), :func:`importlib.import_module` of a full name; the
    data files named. What nothing reaches stays out."""
    root = _package(tmp_path, {
        "__init__.py": '__version__ = "1"\n',
        "a.py": """
            from . import b
            import facetransfer.c

            def later():
                from .pkg import Lazy
                from .sub import inner
                return "table.json"
            """,
        "b.py": "X = 1\n",
        "c.py": 'import importlib\nimportlib.import_module("facetransfer.d")\n',
        "d.py": "import numpy\n",
        "pkg/__init__.py": 'from ..lazy import lazy_names\n'
                           '__getattr__, __dir__ = lazy_names(__name__, {"Lazy": "slow"})\n',
        "pkg/slow.py": "class Lazy: pass\n",
        "pkg/other.py": "Y = 2\n",
        "lazy.py": "def lazy_names(p, n): return None, None\n",
        "sub/__init__.py": "",
        "sub/inner.py": "Z = 3\n",
        "unreached.py": "import facetransfer.b\n",
        "data/table.json": "{}",
        "data/unnamed.json": "{}",
    })
    closure = code_digest.import_closure(["facetransfer.a"], root=root)
    assert list(closure) == ["facetransfer", "facetransfer.a", "facetransfer.b",
                             "facetransfer.c", "facetransfer.d", "facetransfer.lazy",
                             "facetransfer.pkg", "facetransfer.pkg.slow", "facetransfer.sub",
                             "facetransfer.sub.inner"]
    files = code_digest.closure_files(["facetransfer.a"], root=root)
    assert [str(f.relative_to(root)) for f in files] == [
        "__init__.py", "a.py", "b.py", "c.py", "d.py", "data/table.json", "lazy.py",
        "pkg/__init__.py", "pkg/slow.py", "sub/__init__.py", "sub/inner.py"]
    with pytest.raises(ValueError, match="facetransfer.nothing"):
        code_digest.import_closure(["facetransfer.nothing"], root=root)


def test_the_trackers_files_are_all_it_can_run_not_a_hand_list():
    """The track cache's key digests every module of the package the trackers can run: before,
    ``track/*.py``, four readers, ``arkit``, ``model`` and ``tensor`` by name, while the
    trackers ran ``geometry`` (the normals of KLT's visibility), ``jit`` (its kernels),
    ``render`` and the readers' helpers too, whose changes left old tracks in use."""
    root = code_digest.PACKAGE_ROOT
    files = {str(f.relative_to(root)) for f in cache.fingerprinted_files(root)}
    tracker = {f"track/{p.name}" for p in (root / "track").glob("*.py")}
    assert tracker <= files
    assert {"geometry.py", "jit.py", "render/raster.py", "io/video_read.py", "arkit.py",
            "model.py", "tensor.py", "data/mediapipe_ibug.json"} <= files
    # the closure, not the package: what the tracker never runs is not in its key
    assert not {"cli/main.py", "export/gltf.py", "rewrite.py", "batch/run.py"} & files


def _copy(tmp_path: Path) -> Path:
    root = tmp_path / "copy" / "facetransfer"
    shutil.copytree(code_digest.PACKAGE_ROOT, root,
                    ignore=shutil.ignore_patterns("__pycache__", "vendor"))
    return root


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_a_change_to_a_module_the_tracker_imports_changes_the_key(tmp_path, monkeypatch):
    """In a copy of the package: the track cache's fingerprint changes with the code of
    ``geometry.py`` (imported by ``track/pair.py`` inside a function; before, not digested:
    an upgrade that changed it kept every cached track), not with its docstrings, nor with a
    module the tracker never runs (``export/gltf.py``)."""
    root = _copy(tmp_path)
    monkeypatch.setattr(code_digest, "PACKAGE_ROOT", root)
    first = cache.code_fingerprint.__wrapped__()
    _edit(root / "geometry.py", '"""', '"""Reworded. ')
    _edit(root / "export" / "gltf.py", "\ndef ", "\ndef _new():\n    return 2\n\n\ndef ")
    assert cache.code_fingerprint.__wrapped__() == first
    _edit(root / "geometry.py", "\ndef ", "\ndef _new():\n    return 1\n\n\ndef ")
    assert cache.code_fingerprint.__wrapped__() != first


def test_the_key_holds_the_libraries_and_the_detectors_file(monkeypatch):
    """NumPy's, SciPy's, numba's, MediaPipe's and imageio-ffmpeg's versions and Face
    Landmarker's ``.task`` (by its registered sha256) change the fingerprint (before, only
    MediaPipe's and OpenCV's versions did)."""
    from facetransfer import assets

    first = cache.code_fingerprint.__wrapped__()
    assert "numba=" in code_digest.library_versions(*cache.TRACK_LIBRARIES)
    versions = code_digest.library_versions
    monkeypatch.setattr(code_digest, "library_versions",
                        lambda *names: versions(*names).replace("numba=", "numba=0.0+"))
    assert cache.code_fingerprint.__wrapped__() != first
    monkeypatch.setattr(code_digest, "library_versions", versions)
    asset = assets.REGISTRY["face_landmarker"]
    another = replace(asset, files=(replace(asset.files[0], sha256="0" * 64),))
    monkeypatch.setitem(assets.REGISTRY, "face_landmarker", another)
    assert cache.code_fingerprint.__wrapped__() != first


def test_the_key_is_the_same_in_every_run(tmp_path):
    """No change, no new key: two processes (other hash seeds, so another order of any set),
    the first parsing every file and the second reading the memo, give the fingerprint this
    one gives."""
    here = cache.code_fingerprint.__wrapped__()
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "other-cache"),
           "PYTHONPATH": str(code_digest.PACKAGE_ROOT.parent)}
    said = []
    for seed in ("1", "2"):
        run = subprocess.run([sys.executable, "-c", "from facetransfer.track import cache; "
                              "print(cache.code_fingerprint())"], capture_output=True,
                             text=True, env={**env, "PYTHONHASHSEED": seed}, check=True)
        said.append(run.stdout.strip())
    assert said == [here, here]
    assert (tmp_path / "other-cache" / "facetransfer" / code_digest.CODE_MEMO).is_file()

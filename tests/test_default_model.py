"""The default model: built once into the user cache, then read (facetransfer.default_model)."""

from __future__ import annotations

import numpy as np
import pytest

from facetransfer import default_model as dm


@pytest.fixture()
def small_default(monkeypatch, tmp_path, data_dir):
    """The default model's recipe on 3 identities, cached in a temporary folder."""
    import facetransfer.datasets as datasets
    from facetransfer.datasets import build_ict_dataset

    monkeypatch.setattr(dm, "default_model_path", lambda: tmp_path / "models" / "default.npz")
    calls = []

    def small(name, progress=None, **kw):
        calls.append(name)
        return build_ict_dataset(name, n_identities=3, progress=progress, use_cache=False)

    monkeypatch.setattr(datasets, "load_dataset", small)
    return calls


@pytest.fixture()
def fast_default(monkeypatch, tmp_path, quick_ict_dataset):
    """:func:`small_default` with the session's small data set for every build (a build is
    then the model's alone, not the data set's 7 s): for the tests of when it is rebuilt."""
    import facetransfer.datasets as datasets

    monkeypatch.setattr(dm, "default_model_path", lambda: tmp_path / "models" / "default.npz")
    calls = []

    def small(name, progress=None, **kw):
        calls.append(name)
        if progress is not None:
            progress(quick_ict_dataset.shape[0], quick_ict_dataset.shape[0])
        return quick_ict_dataset

    monkeypatch.setattr(datasets, "load_dataset", small)
    dm._recipe.cache_clear()                # the recipe of the package a test may change
    yield calls
    dm._recipe.cache_clear()


def test_built_once_then_read(small_default):
    said, steps = [], []
    m1 = dm.load_default_model(announce=said.append, progress=lambda d, t: steps.append(d))
    assert small_default == ["ict-arkit"] and len(said) == 1 and "ict-arkit" in said[0]
    assert steps[-1] == 3
    assert dm.is_default_model(m1)
    m2 = dm.load_default_model(announce=said.append)
    assert len(said) == 1 and small_default == ["ict-arkit"]  # no second build
    assert m2.content_hash == m1.content_hash
    assert m1.ranks == (3, 52)  # identity clipped to the 3 identities; expressions untruncated


def test_a_damaged_cache_is_rebuilt_as_the_same_model(small_default):
    """A damaged cache is rebuilt, and built again (a damaged or cleared cache, a colleague's
    machine) the default model has the same content hash, so its tracks and face files are
    still its own: before the fifty-first session, the data set's build time in its
    provenance made every build's hash differ, and a track of it was refused as "made with a
    different model"."""
    m1 = dm.load_default_model()
    path = dm.default_model_path()
    path.write_bytes(path.read_bytes()[:1000])
    m2 = dm.load_default_model()
    assert small_default == ["ict-arkit", "ict-arkit"]
    np.testing.assert_array_equal(m2.core, m1.core)
    assert m2.content_hash == m1.content_hash


def test_other_models_are_not_the_default(quick_model):
    assert not dm.is_default_model(quick_model)


def test_memory_is_estimated_before_building(monkeypatch):
    from facetransfer.datasets import ict
    from facetransfer.errors import DatasetError

    monkeypatch.setattr(ict, "_available_bytes", lambda: 8 * 2**30)
    with pytest.raises(DatasetError, match=r"needs about [0-9.]+ GiB"):
        ict.build_ict_dataset("ict-arkit", n_identities=1000, use_cache=False)
    assert ict.build_memory_bytes(50, 52, 9409) < 3 * 2**30


class _Stop(Exception):
    """Raised where a test has seen what it needs."""


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    return max((p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"),
               default=1)


def test_the_default_model_is_built_on_one_blas_thread_whatever_the_command(monkeypatch,
                                                                             tmp_path):
    """OpenBLAS orders its sums by its thread count: the default model built by a command
    whose BLAS had two threads (``probe``, ``export``) hashed 49fc4338eee2, by one that gives
    it one (``track``, ``demo``) 4bd74ef47e95, and a track made with one was refused by the
    other after a rebuild. The build holds BLAS at one thread, whatever the caller's."""
    import facetransfer.datasets as datasets
    from threadpoolctl import threadpool_limits

    seen = []

    def load(name, progress=None, **kw):
        seen.append(_blas_threads())
        raise _Stop                                # the build's start is all this needs

    monkeypatch.setattr(datasets, "load_dataset", load)
    with threadpool_limits(limits=2, user_api="blas"):
        if _blas_threads() < 2:
            pytest.skip("this machine's BLAS cannot have two threads")
        with pytest.raises(_Stop):
            dm._build(tmp_path / "default.npz", None, None)
    assert seen == [1]


def test_a_default_model_built_by_an_older_version_is_rebuilt_not_taken(fast_default):
    """A cached default model without the record of what built it (every one cached before
    the fifty-fourth session) is rebuilt, announced in one line with the progress shown, not
    taken as this version's; built again of the same bits, it keeps its content hash, so the
    tracks made with it stay its own. Before, any file at the path was taken."""
    m1 = dm.load_default_model()
    dm.recipe_path().unlink()                            # as an older version left it
    said, steps = [], []
    m2 = dm.load_default_model(announce=said.append, progress=lambda d, t: steps.append(d))
    assert fast_default == ["ict-arkit", "ict-arkit"] and steps[-1] == 6
    assert len(said) == 1 and said[0].startswith("rebuilding the default model (ict-arkit)")
    assert "built by another version of its recipe or code" in said[0]
    assert m2.content_hash == m1.content_hash
    dm.load_default_model(announce=said.append)          # recorded now: read, not built
    assert fast_default == ["ict-arkit", "ict-arkit"] and len(said) == 1


def test_a_default_model_replaced_by_another_build_is_rebuilt(fast_default, quick_model):
    """The record names the content hash of the file it describes: another model put at the
    path (a build of another version, or any other file) is not taken as the default model.
    Before, it was: ``track`` without ``--model`` used it."""
    m1 = dm.load_default_model()
    quick_model.save(dm.default_model_path())
    said = []
    m2 = dm.load_default_model(announce=said.append)
    assert fast_default == ["ict-arkit", "ict-arkit"] and len(said) == 1
    assert m2.content_hash == m1.content_hash != quick_model.content_hash


def _package_copy(tmp_path):
    import shutil

    from facetransfer import code_digest

    root = tmp_path / "copy" / "facetransfer"
    shutil.copytree(code_digest.PACKAGE_ROOT, root,
                    ignore=shutil.ignore_patterns("__pycache__", "vendor"))
    return root


def _edit(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_a_change_of_the_builders_code_or_recipes_rebuilds_the_default_model(
        fast_default, tmp_path, monkeypatch):
    """In a copy of the package: the default model is rebuilt once the code of a module its
    build runs (``datasets/deformation.py``) or the recipe file changes, not for a reworded
    docstring nor for a module the build never runs. Before, the model built first stayed in
    use whatever changed (``DEFAULT_MODEL_VERSION`` was bumped by hand, or not)."""
    from facetransfer import code_digest

    root = _package_copy(tmp_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))   # the memo of parses
    monkeypatch.setattr(code_digest, "PACKAGE_ROOT", root)
    dm.load_default_model()
    deformation = root / "datasets" / "deformation.py"
    _edit(deformation, '"""', '"""Reworded. ')
    _edit(root / "cli" / "main.py", "\ndef ", "\ndef _new():\n    return 2\n\n\ndef ")
    dm._recipe.cache_clear()                   # a new process, of the changed package
    dm.load_default_model()
    assert fast_default == ["ict-arkit"]
    _edit(deformation, "\ndef ", "\ndef _new():\n    return 1\n\n\ndef ")
    said = []
    dm._recipe.cache_clear()
    dm.load_default_model(announce=said.append)
    assert fast_default == ["ict-arkit"] * 2 and said[0].startswith("rebuilding")
    _edit(root / "data" / "ict_recipes.json", "{", '{"note": "a new recipe", ', )
    dm._recipe.cache_clear()
    dm.load_default_model()
    assert fast_default == ["ict-arkit"] * 3


def test_the_ict_data_sets_cache_keys_hold_their_builders_code(tmp_path, monkeypatch):
    """A cached ICT data set (and its component files) is keyed by the code its builder runs:
    a changed builder never reads what an older one made (before: only BUILDER_VERSION, bumped
    by hand, so a rebuilt default model was made again from the stale data set). Older keys
    are pruned beyond the newest :data:`~facetransfer.datasets.ict.KEEP_OTHERS` (a stale
    ``ict-arkit`` data set is 0.6 GB)."""
    import os

    from facetransfer import code_digest
    from facetransfer.datasets import ict

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    first = ict.ict_cache_path("ict-arkit")
    root = _package_copy(tmp_path)
    monkeypatch.setattr(code_digest, "PACKAGE_ROOT", root)
    ict.builder_code.cache_clear()
    assert ict.ict_cache_path("ict-arkit") == first                  # the same code
    _edit(root / "datasets" / "ict.py", "\ndef ", "\ndef _new():\n    return 1\n\n\ndef ")
    ict.builder_code.cache_clear()
    monkeypatch.setattr(ict, "builder_code", ict.builder_code)     # restored after the test
    assert ict.ict_cache_path("ict-arkit") != first
    ict.builder_code.cache_clear()
    stem = first.name[:-len(first.name.rsplit("-", 1)[1])]
    first.parent.mkdir(parents=True)
    for i, key in enumerate("abcd"):
        (first.parent / f"{stem}{key}.npz").write_bytes(b"x")
        os.utime(first.parent / f"{stem}{key}.npz", (i, i))
    (first.parent / "ict-bilinear-face-n15-s0-e.npz").write_bytes(b"x")
    ict._prune_others(first.parent / f"{stem}d.npz", stem)
    assert sorted(p.name for p in first.parent.iterdir()) == [
        f"{stem}b.npz", f"{stem}c.npz", f"{stem}d.npz", "ict-bilinear-face-n15-s0-e.npz"]


def test_another_versions_default_model_is_kept_beside_not_used(tmp_path, monkeypatch,
                                                                  quick_model,
                                                                  quick_ict_dataset):
    """The file is named by its recipe: another version's (here one named before the recipe
    was, as every default model cached so far) is not used, the rebuild names it, and it is
    kept beside this version's (two checkouts sharing a user cache do not rebuild it in turn);
    beyond :data:`~facetransfer.default_model.KEEP_OTHERS` of them, the oldest go."""
    import os

    import facetransfer.datasets as datasets

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))   # the real path's folder
    built = []
    monkeypatch.setattr(datasets, "load_dataset", lambda name, progress=None, **kw:
                        built.append(name) or quick_ict_dataset)
    dm._recipe.cache_clear()
    path = dm.default_model_path()
    assert path.name == f"ict-arkit-default-v1-{dm.build_recipe()}.npz"
    older = path.with_name("ict-arkit-default-v1.npz")
    older.parent.mkdir(parents=True)
    quick_model.save(older)
    said = []
    m = dm.load_default_model(announce=said.append)
    assert built == ["ict-arkit"] and m.content_hash != quick_model.content_hash
    assert said == [f"rebuilding the default model (ict-arkit) into {path}: the cached one "
                    "(ict-arkit-default-v1.npz) was built by another version of its recipe "
                    "or code"]
    assert older.is_file() and path.is_file() and dm.recipe_path().is_file()
    for i in range(3):
        other = path.with_name(f"ict-arkit-default-v1-other{i}.npz")
        other.write_bytes(b"x")
        os.utime(other, (i + 1, i + 1))
    os.utime(older, (0, 0))
    dm._prune_others(path)
    assert sorted(p.name for p in path.parent.glob("*.npz")) == sorted(
        [path.name, "ict-arkit-default-v1-other1.npz", "ict-arkit-default-v1-other2.npz"])
    dm._recipe.cache_clear()


def test_the_blas_loaded_by_the_build_itself_is_held_at_one_thread_too(tmp_path):
    """SciPy's own OpenBLAS is loaded by the deformation transfer, inside the build's
    one-thread block, where threadpoolctl's limit did not reach it: it ran on every core, so a
    build in a process that had not imported SciPy before (the CLI's: 5ef31ecd1964 here) and
    one that had (pytest's: ac4061d4553f) differed in their last bits. In a fresh process (the
    test's own has SciPy loaded), every BLAS library is at one thread while the data set is
    built."""
    import os
    import subprocess
    import sys

    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: BLAS has one thread anyway")
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "import facetransfer.datasets as datasets\n"
        "from facetransfer import default_model as dm\n"
        "def load(name, progress=None, **kw):\n"
        "    import facetransfer.datasets.deformation  # what the build loads: SciPy's solvers\n"
        "    from threadpoolctl import threadpool_info\n"
        "    print(sorted({p['num_threads'] for p in threadpool_info()\n"
        "                  if p['user_api'] == 'blas'}))\n"
        "    sys.exit(0)\n"
        "datasets.load_dataset = load\n"
        "dm._build(Path(sys.argv[1]), None, None)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS",
                                                            "OPENBLAS_NUM_THREADS")}
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "m.npz")], env=env,
                         capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "[1]"


def test_a_file_made_with_a_kept_older_default_model_is_refused_naming_that_file(
        tmp_path, monkeypatch, quick_model, quick_ict_dataset, quick_track):
    """After a rebuild gives the default model another hash, a track made with the one before
    is refused, rightly; the refusal said "give the model it was tracked with as --model", and
    that model is the kept older default model file, whose name the user did not know. Now the
    refusal names it (the track given a model, the export's default model); a batch worker
    that does not see the client's default model finds its own kept file of the run's model."""
    import facetransfer.datasets as datasets
    from facetransfer.batch.model_ref import ModelRef, _paths
    from facetransfer.errors import TrackError
    from facetransfer.export.common import ExportError, resolve_model

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(datasets, "load_dataset", lambda name, progress=None, **kw:
                        quick_ict_dataset)
    dm._recipe.cache_clear()
    older = dm.default_model_path().with_name("ict-arkit-default-v1.npz")
    older.parent.mkdir(parents=True)
    quick_model.save(older)               # the default model as a version before cached it
    now = dm.load_default_model()         # rebuilt: another hash
    assert now.content_hash != quick_model.content_hash
    hint = f"kept at {older}: give --model {older})"
    with pytest.raises(TrackError, match="another model") as err:   # its ranks, here
        quick_track.check_model(now)
    assert str(err.value).endswith(hint)
    with pytest.raises(ExportError, match="not made with the default model") as err:
        resolve_model(quick_track)
    assert str(err.value).endswith(hint)
    assert dm.kept_model("f" * 64) is None and dm.kept_model_hint("f" * 64) == ""
    ref = ModelRef(str(tmp_path / "elsewhere" / "m.npz"), quick_model.content_hash, True)
    assert _paths(ref)[-1] == older
    dm._recipe.cache_clear()


def test_a_command_started_while_another_builds_the_default_model_waits_and_takes_it(
        fast_default, monkeypatch):
    """Two commands started at once after an upgrade (which rebuilds the default model) built
    it side by side, 1.9 GB and 70 CPU-s each. Now a build holds a lock beside the file: the
    later command says it waits and, the lock free, takes the model the first one built. Here
    the lock is held by "another command" that builds while this one waits."""
    import fcntl

    real, path = fcntl.flock, dm.default_model_path()

    def flock(fd, op):
        if op == fcntl.LOCK_EX | fcntl.LOCK_NB:
            raise BlockingIOError("held by another command")
        if op == fcntl.LOCK_EX:              # the other command builds, then lets go
            dm._record(dm._build(path, None, None), dm._recipe())
        return real(fd, op)

    monkeypatch.setattr(fcntl, "flock", flock)
    said = []
    model = dm.load_default_model(announce=said.append)
    assert fast_default == ["ict-arkit"]      # the other command's build only
    assert said == [f"waiting for another command building the default model into "
                    f"{path.parent}"]
    assert model.provenance["default_model"] and dm._recorded(model) == dm._recipe()


def test_a_file_made_with_this_default_model_given_another_model_says_leave_out_model(
        tmp_path, monkeypatch, quick_model, quick_ict_dataset, quick_track):
    """A track made with the default model, exported with ``--model other.npz`` by mistake, was
    refused with "made with the default model of another version, kept at P: give --model P"
    wherever the cache kept an older recipe's file of the same model (a code change that does
    not change the model leaves one): the user was sent to a cache file for the model the
    command loads by itself. Now the refusal says to leave out --model; a kept file of another
    model is still named."""
    import dataclasses

    import facetransfer.datasets as datasets
    from facetransfer.errors import TrackError
    from facetransfer.model_hint import current_default_hash, model_hint

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setattr(datasets, "load_dataset", lambda name, progress=None, **kw:
                        quick_ict_dataset)
    dm._recipe.cache_clear()
    now = dm.load_default_model()
    older = dm.default_model_path().with_name("ict-arkit-default-v1.npz")
    older.write_bytes(dm.default_model_path().read_bytes())    # the same model, kept
    assert dm.kept_model(now.content_hash) == older
    mine = dataclasses.replace(quick_track, model_hash=now.content_hash)
    with pytest.raises(TrackError) as err:
        mine.check_model(quick_model)
    assert str(err.value).endswith(" (made with the default model: leave out --model)")
    assert "kept at" not in str(err.value)
    assert current_default_hash() == now.content_hash
    other = dm.default_model_path().with_name("ict-arkit-default-v1-0123456789abcdef.npz")
    quick_model.save(other)               # another version's default model, kept
    assert model_hint(quick_model.content_hash) == (
        f" (made with the default model of another version, kept at {other}: give --model "
        f"{other})")
    dm._recipe.cache_clear()

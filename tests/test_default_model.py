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

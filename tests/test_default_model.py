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

"""What the tests of the batch commands share: two track files compared array by array."""

from __future__ import annotations

import numpy as np


def assert_same_track_file(p, q) -> None:
    """The track files ``p`` and ``q`` hold the same keys and, under each, the same array to the
    bit (an AssertionError naming the first key that differs)."""
    with np.load(p) as a, np.load(q) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            assert np.array_equal(a[k], b[k]), k

"""facetransfer.allocator: freed memory is kept for reuse (glibc), so arrays do not fault again."""

from __future__ import annotations

import resource
import sys

import numpy as np
import pytest

from facetransfer.allocator import retain_freed_memory


def _faults_of_rounds(rounds: int, k: int, nbytes: int) -> int:
    """Minor page faults of ``rounds`` rounds of allocating and touching ``k`` arrays of
    ``nbytes`` at once, then freeing them (a frame's temporaries)."""
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        arrays = [np.ones(nbytes, np.uint8) for _ in range(k)]  # touches every page
        del arrays
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_retained_memory_does_not_fault_again():
    if not retain_freed_memory():
        pytest.skip("mallopt missing or refused (not glibc)")
    assert retain_freed_memory()  # idempotent
    k, nbytes = 6, 4 << 20  # 1024 pages of 4 KiB each, 24 MiB at once
    _faults_of_rounds(1, k, nbytes)  # the heap grows once
    # by default glibc gives the freed 24 MiB back every round (more than twice its mmap
    # threshold is free at the heap's top) and faults them in again: ~30,000 faults here
    assert _faults_of_rounds(10, k, nbytes) < 1024

"""The process's memory allocator: keep freed memory for reuse, so per-frame arrays do not fault.

Rewriting a frame (:mod:`facetransfer.rewrite`) allocates and frees about 10 MB of crop-sized
arrays (the raster, the shaded images, the membrane's pyramid and sweeps). glibc's ``malloc``
serves arrays above its mmap threshold (128 KiB at first, raised dynamically up to the largest
freed block) from fresh pages and gives the top of the heap back to the system whenever more
than twice that is free, so every frame pages its arrays in again: on the issue-13 demo pair
about 2,700 minor page faults per frame, a fifth of the render's CPU time (issue 13,
``BENCHMARKS.md``). :func:`retain_freed_memory` sets both thresholds once (``mallopt``), after
which those arrays reuse the heap's pages. The price: the heap keeps up to
``trim_threshold`` bytes of freed memory instead of returning it; blocks above
``mmap_threshold`` (whole clips of frames) are still mapped and unmapped on their own.

Elsewhere than Linux with glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import logging
import sys

log = logging.getLogger(__name__)

__all__ = ["retain_freed_memory"]

#: ``mallopt`` parameters (glibc ``malloc.h``)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: glibc's largest mmap threshold on 64-bit systems (``DEFAULT_MMAP_THRESHOLD_MAX``)
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 512 << 20

_done = False


def retain_freed_memory(*, mmap_threshold: int = MMAP_THRESHOLD,
                        trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Raise glibc's mmap and trim thresholds for this process (once; later calls do nothing).

    Parameters
    ----------
    mmap_threshold : int, keyword-only
        Blocks of at least this many bytes are mapped on their own (at most 32 MiB).
    trim_threshold : int, keyword-only
        The heap returns free memory at its top to the system beyond this many bytes.

    Returns
    -------
    bool
        True when the thresholds are set (now or by an earlier call); False where ``mallopt``
        is missing or refuses them (not glibc).
    """
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = (mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
          and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1)
    if ok:
        log.debug("malloc: mmap threshold %d, trim threshold %d bytes", mmap_threshold,
                  trim_threshold)
    _done = ok
    return ok

"""One BLAS thread while the project's own threads or processes share the cores.

The render (:func:`facetransfer.rewrite_clip.rewrite_frames`) runs its frames on threads of its
own beside the encoder, and a transfer tracks its two clips in two processes; OpenBLAS's
threads on top of them spin between products (issue 13's 300 frames rendered in 5.6 s with
them, 4.85 s without: BENCHMARKS.md, "Fortieth session"). The CLI gives OpenBLAS one thread
from its start (:data:`facetransfer.cli.main.SERIAL_POOLS`); :func:`one_blas_thread` does the
same for a program calling the library, while the work runs.

The limit is the process's (BLAS has one pool), so the holders are counted: the first to
enter sets it, the last to leave restores what was there, whatever order renders that run at
once (two generators, say) end in.
"""

from __future__ import annotations

import contextlib
import threading

__all__ = ["one_blas_thread"]

_lock = threading.Lock()
_holders = 0
_limiter = None   # threadpoolctl's limiter of the first holder, restored by the last


@contextlib.contextmanager
def one_blas_thread():
    """Hold the process's BLAS libraries at one thread each while the block runs."""
    global _holders, _limiter
    from threadpoolctl import threadpool_limits

    with _lock:
        if _holders == 0:
            _limiter = threadpool_limits(limits=1, user_api="blas")
        _holders += 1
    try:
        yield
    finally:
        with _lock:
            _holders -= 1
            if _holders == 0 and _limiter is not None:
                _limiter.restore_original_limits()
                _limiter = None

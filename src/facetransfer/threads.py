"""One BLAS thread while the project's own threads or processes share the cores; work done
ahead on a thread of its own (:class:`Ahead`).

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

__all__ = ["one_blas_thread", "Ahead"]

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


class Ahead:
    """``fn(*args)`` computed from now on, on a daemon thread of its own, while the caller goes
    on; :meth:`result` waits for it and gives its value or raises its error, :meth:`wait`
    only waits (a caller raising an error of its own waits so, not to leave the work going on
    behind it: its log lines at the interpreter's exit, a process-wide setting it holds).

    A thread per call, not a pool: a forked child inherits no pool's workers, and a caller
    interrupted again while it waits does not wait for the work at exit (a daemon thread).
    """

    def __init__(self, fn, *args, name: str = "ahead") -> None:
        self._value, self._error = None, None
        self._thread = threading.Thread(target=self._run, args=(fn, args), name=name,
                                        daemon=True)
        self._thread.start()

    def _run(self, fn, args) -> None:
        try:
            self._value = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - raised again by result()
            self._error = exc

    def done(self) -> bool:
        """Whether the work has ended (its value or its error is there)."""
        return not self._thread.is_alive()

    def wait(self) -> None:
        """Until the work has ended (its value or its error kept for :meth:`result`)."""
        self._thread.join()

    def result(self):
        """The value of ``fn(*args)`` once it is computed (its error raised here)."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value

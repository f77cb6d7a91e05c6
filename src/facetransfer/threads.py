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
    behind it: its log lines at the interpreter's exit, a process-wide setting it holds), and
    :meth:`wait_out` waits through interrupts.

    A thread per call, not a pool: a forked child inherits no pool's workers. The work's end
    is an event, not the thread's join: Python 3.11's ``Thread.join`` interrupted by a Ctrl-C
    takes the thread for ended (it releases the lock the running thread holds), so a wait
    after it returned at once, the work still running.
    """

    def __init__(self, fn, *args, name: str = "ahead") -> None:
        self._value, self._error = None, None
        self._ended = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(fn, args), name=name,
                                        daemon=True)
        self._thread.start()

    def _run(self, fn, args) -> None:
        try:
            self._value = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - raised again by result()
            self._error = exc
        finally:
            self._ended.set()

    def done(self) -> bool:
        """Whether the work has ended (its value or its error is there)."""
        return self._ended.is_set()

    def wait(self) -> None:
        """Until the work has ended (its value or its error kept for :meth:`result`)."""
        self._ended.wait()

    def wait_out(self) -> None:
        """:meth:`wait`, through interrupts: a Ctrl-C or SIGTERM meanwhile (raised in this
        thread, the main one) is raised once the work has ended. For a caller already leaving
        on an error or an interrupt: a second interrupt cut a plain :meth:`wait` short, and the
        work went on while the interpreter exited, where a thread still in native code (an
        import of SciPy's) aborted the process ("terminate called without an active
        exception", exit -6: 1 of 12 double Ctrl-Cs in a transfer's set-up). The work must be
        bounded: it is waited for whatever comes."""
        stop = None
        while True:
            try:
                self._ended.wait()
                break
            except KeyboardInterrupt as exc:  # the CLI's Terminated too
                stop = exc if stop is None else stop
        if stop is not None:
            raise stop

    def result(self):
        """The value of ``fn(*args)`` once it is computed (its error raised here)."""
        self._ended.wait()
        if self._error is not None:
            raise self._error
        return self._value

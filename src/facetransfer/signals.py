"""Ctrl-C and SIGTERM held while this process forks, then raised where the fork was asked for.

A signal whose Python handler raises while a fork runs the interpreter's at-fork hooks
(``logging``'s locks among them) raises inside a hook, where Python prints "Exception ignored"
and goes on: a Ctrl-C at that moment was lost with a traceback, and the command ran to its
end (a new user's walk, ``track`` of a 200-frame clip interrupted 0.7 s in). Inside
:func:`deferred_signals` the handlers only note the signal; on leaving, the first noted is
handed to its own handler there, in ordinary code, so the interrupt is raised where the
caller can stop what it started. A forked child starts with the parent's Ctrl-C handler and
SIGTERM's default (a forked worker dies of it). A parent that gives up on its forked workers
stops them by SIGKILL (:func:`kill_forked`): a signal that reaches a child in the fork's
first instants, while it still holds the noting handlers, is noted in the child and lost.
An interrupt raised elsewhere where Python ignores exceptions (a weak reference's callback, a
``__del__``) is sent again (:func:`interrupts_not_ignored`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

__all__ = ["deferred_signals", "interrupts_not_ignored", "kill_forked",
           "in_importlib", "send_later"]

#: The handlers replaced while a fork is under way (None: none), for the child to restore.
_SAVED: dict | None = None
_HOOKED = False


def _restore_in_child() -> None:
    """A forked child's handlers back to the parent's own (not the noting ones), but SIGTERM
    to its default: a forked worker dies of it (a ``kill`` of the process group, the
    executor's own ``terminate`` of a broken pool; :mod:`facetransfer.cli.main` does the same
    for every fork)."""
    global _SAVED
    saved, _SAVED = _SAVED, None
    if saved is not None and threading.current_thread() is threading.main_thread():
        for signum, handler in saved.items():
            signal.signal(signum, signal.SIG_DFL if signum == signal.SIGTERM else handler)


@contextlib.contextmanager
def deferred_signals(signums=(signal.SIGINT, signal.SIGTERM)):
    """Note SIGINT and SIGTERM instead of handling them inside the block (a fork), then hand
    the first one noted to its handler (which raises, e.g. ``KeyboardInterrupt``) on leaving.

    Only Python-level handlers are deferred, and only in the main thread (the only one whose
    handlers Python runs); elsewhere the block runs as it is."""
    global _SAVED, _HOOKED
    if threading.current_thread() is not threading.main_thread() or _SAVED is not None:
        yield
        return
    if not _HOOKED and hasattr(os, "register_at_fork"):
        os.register_at_fork(after_in_child=_restore_in_child)
        _HOOKED = True
    noted: list[int] = []
    saved = {s: signal.getsignal(s) for s in signums if callable(signal.getsignal(s))}
    _SAVED = saved
    try:
        for s in saved:      # inside the try: a signal between two of these is restored too
            signal.signal(s, lambda signum, frame: noted.append(signum))
        yield
    finally:
        _SAVED = None
        for s, handler in saved.items():
            signal.signal(s, handler)
        if noted:
            saved[noted[0]](noted[0], None)


def kill_forked(pool, future, *, grace: float = 0.0) -> None:
    """Stop the forked workers of the ``concurrent.futures.ProcessPoolExecutor`` ``pool`` (and
    ``future``, the job they run) without waiting for them (but ``grace`` seconds for a job
    running: one that got the same Ctrl-C ends by itself, saving its progress): by SIGKILL,
    not SIGTERM. A SIGTERM reaching a child in the fork's first instants, before its handlers
    are restored (:func:`deferred_signals`), was lost, and the child ran its whole job and then
    waited for ever to hand its result to a parent that had left (3 of 30 children cancelled
    right after the fork). A child killed while it writes leaves its temporary file
    (``.NAME.PID-XXXX.part.npz``), which the next write of that file removes once its process
    is gone (:mod:`facetransfer.io.atomic`): the background tracker saving its progress on the
    Ctrl-C it got too was killed so (1 of 7 Ctrl-Cs while tracking, its progress lost; so did
    SIGTERM's default), hence ``grace``. The fork context's semaphores and shared values are
    unlinked when made: nothing else is left."""
    from concurrent.futures import wait

    future.cancel()
    try:
        if grace > 0 and future.running():
            wait([future], timeout=grace)
    finally:                        # killed all the same, also on a second Ctrl-C meanwhile
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            try:
                proc.kill()
            except Exception:  # noqa: BLE001 - already gone
                pass
        pool.shutdown(wait=False, cancel_futures=True)


@contextlib.contextmanager
def interrupts_not_ignored(signals):
    """Inside the block, an interrupt that Python ignored is sent again: ``signals``, pairs
    ``(exception class, signal number)`` (the most specific first), says which signal's
    handler raised an exception of which class.

    A signal's handler runs between two bytecodes of the main thread, wherever it is; where
    that is a callback whose exceptions Python only prints ("Exception ignored in", through
    :func:`sys.unraisablehook`: a weak reference's callback, as importlib's module locks have,
    a ``__del__``), the interrupt it raised was lost and the command ran on (1 of 21 SIGTERMs
    0.8 s into a transfer). Such an exception is not printed; its signal is sent again
    (:func:`send_later`), and its handler runs in the code running then. Any other goes to the
    hook there was. Outside the main thread (a command run in a thread of a program, which
    sets no handler) the block runs as it is: the hook is the process's, and two blocks at
    once in threads put it back out of order, the first one's left for ever."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = sys.unraisablehook

    def hook(unraisable) -> None:
        kind = unraisable.exc_type
        signum = next((n for cls, n in signals if isinstance(kind, type)
                       and issubclass(kind, cls)), None)
        if signum is None or threading.current_thread() is not threading.main_thread():
            before(unraisable)
            return
        send_later(signum)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = before


def send_later(signum: int) -> None:
    """Send ``signum`` to the main thread again a moment later, from a thread of its own (sent
    by the main thread, its handler would run at once, where it was not to be raised)."""
    later = threading.Timer(0.01, _send_again, (signum,))
    later.daemon = True
    later.start()


def in_importlib(frame) -> bool:
    """Whether ``frame`` is importlib's own code (``importlib._bootstrap``), where the import
    locks are taken and given back. Its module-lock callback (``_get_module_lock``'s ``cb``,
    run when a module's lock is collected) and ``_get_module_lock`` itself take the global
    import lock before their ``try``, and ``_ModuleLock.acquire`` counts a module's lock as
    held before it returns to the ``with`` that gives it back: an interrupt raised there, right
    after the lock was taken, left it held by the main thread for ever, and every other
    thread's next import waited for it (a Ctrl-C 2 s into a transfer hung it, in ``cb``; a
    SIGTERM 0.6 s in, in ``_get_module_lock``, with the CLI's threads loading MediaPipe and the
    capture's kernels waiting for the lock and the main thread for them). A handler sends its
    signal again instead (:func:`send_later`): the code a module runs is its own frames, not
    importlib's, so the interrupt lands there or after the import."""
    return frame is not None and frame.f_globals.get("__name__") == "importlib._bootstrap"


def _send_again(signum: int) -> None:
    """Send ``signum`` to the main thread (a real signal: it wakes a wait there), while Python
    still handles it; where there is no ``pthread_kill`` (not POSIX), its handler is called
    there at its next bytecode (``_thread.interrupt_main``)."""
    if not callable(signal.getsignal(signum)):
        return
    if hasattr(signal, "pthread_kill"):
        signal.pthread_kill(threading.main_thread().ident, signum)
    else:
        import _thread

        _thread.interrupt_main(signum)

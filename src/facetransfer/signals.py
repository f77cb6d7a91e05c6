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

A forked child that saves its progress on a Ctrl-C (the background tracker) takes one
interrupt only (:func:`deferred_signals`' ``interrupt_once``, :func:`interrupted_once`): its
parent, interrupted alone (``kill -INT PID``, a job runner's stop), hands it the interrupt
(:func:`kill_forked`'s ``interrupt``), and where the terminal's Ctrl-C reached the child
already, that second one does not cut its save short.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

__all__ = ["deferred_signals", "ended_with_parent", "interrupted_once", "interrupts_not_ignored",
           "kill_forked", "send_later", "unsafe_to_raise_at"]

#: The handlers replaced while a fork is under way (None: none), for the child to restore.
_SAVED: dict | None = None
_HOOKED = False
#: Whether the child of the fork under way takes one Ctrl-C only (:class:`_InterruptOnce`).
_ONCE = False


class _InterruptOnce:
    """A forked child's Ctrl-C handler (``deferred_signals(interrupt_once=True)``): before its
    job begins (:func:`interrupted_once`) an interrupt is noted, and raised as the job begins;
    while it runs, the first one is handed to the parent's ``handler`` (which raises), any
    later one ignored (the job is saving its progress: a second ``KeyboardInterrupt`` there
    lost it); after it, ignored (the child only hands back its result)."""

    def __init__(self, handler) -> None:
        self.handler, self.state, self.noted = handler, "before", False

    def __call__(self, signum, frame) -> None:
        if self.state == "before":
            self.noted = True
        elif self.state == "running":
            try:
                self.handler(signum, frame)         # raises, or sends the signal again later
            except BaseException:
                self.state = "stopping"
                raise


@contextlib.contextmanager
def interrupted_once():
    """Run a forked child's job (forked inside ``deferred_signals(interrupt_once=True)``) with
    its Ctrl-C taken once (:class:`_InterruptOnce`): one noted before the job is raised here;
    elsewhere (no such handler) the block runs as it is."""
    handler = signal.getsignal(signal.SIGINT)
    if not isinstance(handler, _InterruptOnce):
        yield
        return
    handler.state = "running"
    try:
        if handler.noted:
            handler.state = "stopping"
            raise KeyboardInterrupt
        yield
    finally:
        handler.state = "done"


def _restore_in_child() -> None:
    """A forked child's handlers back to the parent's own (not the noting ones), but SIGTERM
    to its default: a forked worker dies of it (a ``kill`` of the process group, the
    executor's own ``terminate`` of a broken pool; :mod:`facetransfer.cli.main` does the same
    for every fork)."""
    global _SAVED, _ONCE
    saved, _SAVED, once, _ONCE = _SAVED, None, _ONCE, False
    if saved is not None and threading.current_thread() is threading.main_thread():
        for signum, handler in saved.items():
            if signum == signal.SIGINT and once:
                handler = _InterruptOnce(handler)
            signal.signal(signum, signal.SIG_DFL if signum == signal.SIGTERM else handler)


@contextlib.contextmanager
def deferred_signals(signums=(signal.SIGINT, signal.SIGTERM), *, interrupt_once: bool = False):
    """Note SIGINT and SIGTERM instead of handling them inside the block (a fork), then hand
    the first one noted to its handler (which raises, e.g. ``KeyboardInterrupt``) on leaving.

    Only Python-level handlers are deferred, and only in the main thread (the only one whose
    handlers Python runs); elsewhere the block runs as it is. Yields whether a child forked in
    the block takes one Ctrl-C only (``interrupt_once`` asked, and a Python-level Ctrl-C
    handler to wrap: :class:`_InterruptOnce`), to be interrupted by its parent
    (:func:`kill_forked`'s ``interrupt``) with no harm to its save."""
    global _SAVED, _HOOKED, _ONCE
    if threading.current_thread() is not threading.main_thread() or _SAVED is not None:
        yield False
        return
    if not _HOOKED and hasattr(os, "register_at_fork"):
        os.register_at_fork(after_in_child=_restore_in_child)
        _HOOKED = True
    noted: list[int] = []
    saved = {s: signal.getsignal(s) for s in signums if callable(signal.getsignal(s))}
    _SAVED, _ONCE = saved, interrupt_once and signal.SIGINT in saved
    try:
        for s in saved:      # inside the try: a signal between two of these is restored too
            signal.signal(s, lambda signum, frame: noted.append(signum))
        yield _ONCE
    finally:
        _SAVED, _ONCE = None, False
        for s, handler in saved.items():
            signal.signal(s, handler)
        if noted:
            saved[noted[0]](noted[0], None)


def kill_forked(pool, future, *, grace: float = 0.0, interrupt: bool = False) -> None:
    """Stop the forked workers of the ``concurrent.futures.ProcessPoolExecutor`` ``pool`` (and
    ``future``, the job they run) without waiting for them (but ``grace`` seconds for a job
    running: one that got the same Ctrl-C ends by itself, saving its progress; ``interrupt``:
    sent SIGINT first, for a Ctrl-C that reached the parent alone, which the workers take once
    only, :func:`interrupted_once`; before, the parent waited out the grace while its child
    tracked on, then killed it, its progress lost): by SIGKILL,
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
    manager = getattr(pool, "_executor_manager_thread", None)     # shutdown() forgets it
    try:
        if grace > 0 and future.running():
            if interrupt:
                _each_worker(pool, lambda proc: os.kill(proc.pid, signal.SIGINT))
            wait([future], timeout=grace)
    finally:                        # killed all the same, also on a second Ctrl-C meanwhile
        _each_worker(pool, lambda proc: proc.kill())
        pool.shutdown(wait=False, cancel_futures=True)
        if manager is not None and manager is not threading.current_thread():
            # its pipes closed before this process exits: Python 3.11 wakes every pool's
            # manager thread at the exit through a pipe such a thread may then be closing
            # ("Exception ignored ... Bad file descriptor", 1 of 10 Ctrl-Cs to the parent)
            manager.join(timeout=1.0)


def ended_with_parent(every: float = 0.5) -> None:
    """In a forked worker of a ``ProcessPoolExecutor`` (a background tracker, a detector):
    end this process at once (``os._exit``) when its parent has gone, checked every ``every``
    seconds on a daemon thread. A parent killed outright (``kill -9``, the kernel's
    out-of-memory killer) left its child tracking to the end, then waiting for ever to hand
    its result to no one (its own copy of the result pipe's reader kept it open), holding the
    clip's decoded frames. Nothing outside such a worker (no parent recorded)."""
    import multiprocessing
    import time

    parent = multiprocessing.parent_process()
    if parent is None or parent.pid is None:
        return

    def watch() -> None:
        while os.getppid() == parent.pid:
            time.sleep(every)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _each_worker(pool, do) -> None:
    """``do(process)`` for each worker process of ``pool`` (one already gone is skipped)."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        try:
            do(proc)
        except Exception:  # noqa: BLE001 - already gone
            pass


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
        _IN_HOOK[0] = True
        try:
            send_later(signum)
        finally:
            _IN_HOOK[0] = False

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = before


#: Whether :func:`interrupts_not_ignored`'s hook runs (in the main thread): a signal handled
#: there is ignored as the one it sends again was (its timer's signal can come before the
#: timer's ``start()`` returns, on a loaded machine), so :func:`unsafe_to_raise_at` says so.
_IN_HOOK = [False]


def send_later(signum: int) -> None:
    """Send ``signum`` to the main thread again a moment later, from a thread of its own (sent
    by the main thread, its handler would run at once, where it was not to be raised). A forked
    child's one Ctrl-C (:class:`_InterruptOnce`) lost so is taken again."""
    handler = signal.getsignal(signum)
    if isinstance(handler, _InterruptOnce) and handler.state == "stopping":
        handler.state = "running"
    later = threading.Timer(0.01, _send_again, (signum,))
    later.daemon = True
    later.start()


#: Modules whose own code takes a lock before the ``try`` that releases it (importlib's
#: ``_get_module_lock`` and its callback ``cb`` the global import lock, ``_ModuleLock.acquire``
#: a module's; logging's ``Handler.handle`` and ``_acquireLock`` theirs), and that never wait
#: long themselves (a module's own code runs in a frame of its own).
UNGUARDED_LOCKS = ("importlib._bootstrap", "logging")


def unsafe_to_raise_at(frame) -> bool:
    """Whether a signal handler must not raise in ``frame`` (the code the main thread was
    running): a frame of :data:`UNGUARDED_LOCKS`' modules, where an interrupt raised right
    after a lock was taken left it held by the main thread for ever, and every other thread
    waited for it at its next import or log line. The transfer's main thread, interrupted as
    it imported while the threads loading MediaPipe and the capture's kernels imported too,
    then waited for ever for them (a lone Ctrl-C 1.3-2.7 s into issue 13's transfer: 3 of 45
    runs hung, no line said; importlib's module-lock callback alone was guarded before). A
    handler sends its signal again instead (:func:`send_later`), taken in the code running
    a moment later. Nor while :func:`interrupts_not_ignored`'s hook runs (:data:`_IN_HOOK`):
    what it raises there is ignored. Nor while a thread is being started
    (:func:`_starting_thread`), nor while the main thread imports (:func:`_importing`)."""
    return _IN_HOOK[0] or (frame is not None
                           and (frame.f_globals.get("__name__") in UNGUARDED_LOCKS
                                or _starting_thread(frame) or _importing(frame)))


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import (importlib's frames below it: a module's own
    code, or a C extension's init importing others). C code that imports turns an interrupt
    raised inside into an error of its own: NumPy's ``_multiarray_umath``, whose import of
    ``datetime`` took a Ctrl-C, raised "ImportError: PyCapsule_Import could not import module
    'datetime'" (60 lines and exit 1, 1 of 48 Ctrl-Cs into ``puppet``, 0.2 s in, while the
    CLI's modules loaded). The interrupt is raised once the outermost import is done instead
    (the CLI's modules load one by one: a moment later)."""
    while frame is not None:
        if frame.f_globals.get("__name__") == "importlib._bootstrap":
            return True
        frame = frame.f_back
    return False


def _starting_thread(frame, depth: int = 4) -> bool:
    """Whether ``frame`` or one of the ``depth - 1`` frames it was called from is
    :meth:`threading.Thread.start` (which waits in ``Event.wait``, ``Condition.wait`` for the
    new thread to begin): an interrupt raised there left the thread running but unknown to
    whatever started it. A ``ThreadPoolExecutor``'s worker, started by ``submit`` but never
    recorded for the interpreter's exit to wake, waited for work for ever, and the process
    with it, after its one line (2 of about 200 runs given Ctrl-C 0.5-3.5 s into a transfer,
    killed after 30 and 60 s; BENCHMARKS.md, "Fifty-fourth session")."""
    start = threading.Thread.start.__code__
    for _ in range(depth):
        if frame is None:
            return False
        if frame.f_code is start:
            return True
        frame = frame.f_back
    return False


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

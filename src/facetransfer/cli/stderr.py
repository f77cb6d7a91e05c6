"""Keep native libraries' log lines off the terminal unless ``-v`` is given.

MediaPipe, TensorFlow Lite, absl and OpenEXR write their own log lines (``W0000 00:00:... file.cc:121]
...``, ``INFO: Created TensorFlow Lite XNNPACK delegate``) straight to file descriptor 2, from C++,
past Python's logging. :func:`filtered_stderr` points descriptor 2 at a pipe read by a thread
that forwards everything except those lines (fatal ``F`` lines still pass), so the tool's own
line is the first a person sees. Python's ``sys.stderr`` is moved to a copy of the original
descriptor, so progress bars still see the terminal (``isatty``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import threading
from typing import Iterator

#: native log lines to drop: glog/absl info, warning and error lines, TFLite's INFO lines.
#: The forked background tracker writes to the same descriptor, so one process's ``INFO: ``
#: may end up before the other's glog line, and its message on a line of its own.
NATIVE_LOG = re.compile(
    rb"^(?:(?:INFO: |WARNING: )*"  # a prefix may repeat: two processes' writes interleaved
    rb"(?:[IWE]\d{4} [\d:.]+ +\d+ [^\]]*\] .*"
    rb"|Created TensorFlow Lite.*|Initialized TensorFlow Lite.*"
    rb"|All log messages before absl::InitializeLog.*"
    rb"|Logging before InitGoogle\(\).*"
    rb"|.*\(EXR_ERR_[A-Z_]+\) .*)"  # OpenEXR's own report of a damaged file
    rb"|(?:INFO: |WARNING: )+)\r?\n?$")  # or a prefix whose message went elsewhere


_KEYWORDS = (b"INFO: ", b"WARNING: ", b"ERROR: ")


def _maybe_native(partial: bytes) -> bool:
    """Whether an unfinished line may become a native log line (C libraries often write the
    severity, the message and the newline in separate writes)."""
    if re.match(rb"^[IWE]\d{0,4}(?: |$)", partial):
        return True
    return any(partial.startswith(k) or k.startswith(partial) for k in _KEYWORDS)


def filter_native(data: bytes, after_native: bool = False) -> tuple[bytes, bytes, bool]:
    """Split ``data`` into what to forward now and an unfinished native log line to keep.

    A blank line right after a native log line (``after_native``: the last line of the chunk
    before was one) is dropped too: TensorFlow Lite writes its severity, its message and the
    newline in three writes, so two processes' lines interleaved leave one line of both
    messages and a newline alone (a blank line before the CLI's own, 3 of 48 interrupted
    240-frame ``track`` runs, whose detection's second process speaks too). Any other blank
    line passes.

    Returns
    -------
    forward : bytes
    rest : bytes
        A trailing partial line that starts like a native log line (kept for the next chunk).
    after_native : bool
        Whether the last whole line was a native log line (for the next chunk).
    """
    out = []
    lines = data.splitlines(keepends=True)
    rest = b""
    if lines and not lines[-1].endswith(b"\n") and _maybe_native(lines[-1]):
        rest = lines.pop()
    for ln in lines:
        blank = not ln.strip(b"\r\n")
        if not (NATIVE_LOG.match(ln) or (blank and after_native)):
            out.append(ln)
        after_native = not blank and bool(NATIVE_LOG.match(ln))
    return b"".join(out), rest, after_native


class CurrentStderrHandler(logging.StreamHandler):
    """A logging handler that writes to ``sys.stderr`` as it is when a record comes, not as it
    was when logging was configured: inside :func:`filtered_stderr` that is the copy of the
    original descriptor, so the tool's own warnings reach the terminal in order with its error
    line and progress bars (bound to descriptor 2, they went through the filter's pipe and
    thread, and a warning said before an error was often printed after it)."""

    def __init__(self) -> None:
        super().__init__()

    @property
    def stream(self):
        import sys

        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:   # StreamHandler's own assignments: always sys.stderr
        pass


@contextlib.contextmanager
def filtered_stderr(*, until_exit: bool = False) -> Iterator[None]:
    """Filter native log lines out of descriptor 2 for the duration of the block; with
    ``until_exit`` (a process that ends with the block: the console script), until the
    interpreter's exit, once its threads have ended (:mod:`atexit`). A command stopped while
    MediaPipe's landmarker was being made (its graph's threads log as they start) or a thread
    still loading it let their lines through after the CLI's one (3 of 192 Ctrl-Cs into
    ``track``, ``puppet`` and a 240-frame ``track``): the process's exit waited for them with
    descriptor 2 the terminal again."""
    try:
        saved = os.dup(2)
        r, w = os.pipe()
    except OSError:
        yield
        return

    def pump() -> None:
        rest, after_native = b"", False
        while True:
            try:
                chunk = os.read(r, 65536)
            except OSError:
                break
            if not chunk:
                break
            fwd, rest, after_native = filter_native(rest + chunk, after_native)
            if fwd:
                with contextlib.suppress(OSError):
                    os.write(saved, fwd)
        if rest and not NATIVE_LOG.match(rest):
            with contextlib.suppress(OSError):
                os.write(saved, rest)
        os.close(r)

    import io
    import sys

    t = threading.Thread(target=pump, name="stderr-filter", daemon=True)
    t.start()
    old = sys.stderr
    with contextlib.suppress(Exception):
        old.flush()
    os.dup2(w, 2)
    os.close(w)
    py_fd = os.dup(saved)
    sys.stderr = io.TextIOWrapper(io.FileIO(py_fd, "w"), encoding=getattr(old, "encoding", None)
                                  or "utf-8", errors="backslashreplace", line_buffering=True)
    def end() -> None:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
            sys.stderr.close()
        sys.stderr = old
        os.dup2(saved, 2)   # closes the pipe's last write end: the pump drains and stops
        _drained(t, saved)

    try:
        yield
    finally:
        if until_exit:
            import atexit

            atexit.register(end)    # after the interpreter has joined its threads
        else:
            end()


#: Seconds :func:`filtered_stderr` waits at its end for the pump to forward what is left. A
#: process that inherited the pipe (a Dask worker being shut down) keeps it open after the
#: command's work: the command then ends without waiting for it (it waited 2 s, and a Ctrl-C
#: in that wait printed a traceback).
DRAIN_SECONDS = 0.25


def _drained(pump: threading.Thread, saved: int) -> None:
    """Wait :data:`DRAIN_SECONDS` for the ``pump`` to end, then close ``saved`` (descriptor 2
    as it was) unless the pump still writes to it (then it is left open: closed, its number
    could be another file's by the pump's next write). A Ctrl-C in the wait ends it."""
    with contextlib.suppress(KeyboardInterrupt):
        pump.join(timeout=DRAIN_SECONDS)
    if not pump.is_alive():
        os.close(saved)

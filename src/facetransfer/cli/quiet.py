"""Keep third-party log lines off the terminal unless ``-v``.

MediaPipe and TensorFlow Lite log from C++ straight to file descriptor 2
(``W0000 00:00:… file.cc:181] …``, ``INFO: Created TensorFlow Lite XNNPACK delegate for CPU.``),
and before absl's logging is initialised no environment variable silences them
(GLOG_minloglevel and TF_CPP_MIN_LOG_LEVEL are set as well, for the builds that honour them).
So while a command runs, fd 2 goes through a pipe that drops those lines and passes everything
else on unchanged and at once, while Python's ``sys.stderr`` (our own messages, tqdm bars,
warnings) writes to the terminal directly. ffmpeg is run with ``-loglevel error`` and its output
captured (:mod:`facetransfer.io.video`).

Not a subcommand; :func:`facetransfer.cli.main.main` wraps every command in :func:`quiet_stderr`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import select
import sys
import threading
from typing import Iterator

#: Lines dropped: glog/absl (``W0000 00:00:1796.. 7910 file.cc:181] …``), their preamble, and
#: TensorFlow Lite's own ``INFO:`` lines.
NATIVE_LOG_LINE = re.compile(
    rb"(?:[IWEF]\d{4} \d+:\d+:\d+\.\d+ +\d+ [^ \]]+:\d+\]"
    rb"|WARNING: Logging before InitGoogle\(\) is written to STDERR"
    rb"|WARNING: All log messages before absl::InitializeLog\(\) is called are written to STDERR"
    rb"|INFO: Created TensorFlow Lite)")


def is_native_log_line(line: bytes) -> bool:
    """Whether one line (without its newline) has a third-party native log message."""
    return NATIVE_LOG_LINE.search(line) is not None


def _filter_line(line: bytes) -> bytes:
    """What to pass on of one complete line (without its newline): all of it with the newline,
    or, if it ends in a native log message (another thread's, perhaps glued after a progress
    bar's update), only what comes before that message."""
    m = NATIVE_LOG_LINE.search(line)
    return line + b"\n" if m is None else line[:m.start()]


def _pump(read_fd: int, write_fd: int) -> None:
    """Copy ``read_fd`` to ``write_fd`` until EOF, dropping native log lines.

    Complete lines are filtered; the unfinished end is passed on at once (tqdm's ``\r``
    updates), except a part after the last ``\r`` that may start a log line (``I``, ``W``,
    ``E``, ``F``): that is held until its newline, or 0.1 s without more data.
    """
    pending = b""
    with contextlib.suppress(OSError):
        while True:
            ready, _, _ = select.select([read_fd], [], [], 0.1)
            chunk = os.read(read_fd, 65536) if ready else None
            if chunk == b"":  # EOF
                break
            out = b""
            if chunk is None:  # quiet for 0.1 s: pass on whatever is held
                out, pending = pending, b""
            else:
                *lines, pending = (pending + chunk).split(b"\n")
                out = b"".join(_filter_line(ln) for ln in lines)
                head, sep, tail = pending.rpartition(b"\r")
                if tail[:1] in (b"I", b"W", b"E", b"F"):
                    out, pending = out + head + sep, tail
                else:
                    out, pending = out + pending, b""
            if out:
                os.write(write_fd, out)
        if pending:
            os.write(write_fd, _filter_line(pending)[:len(pending)])


@contextlib.contextmanager
def quiet_stderr(*, verbose: bool = False) -> Iterator[None]:
    """While the block runs, drop third-party native log lines from fd 2 (nothing if verbose).

    Sets GLOG_minloglevel / TF_CPP_MIN_LOG_LEVEL (unless already set), lowers absl's Python
    logging to errors, and filters fd 2 through a pipe read by a thread.
    """
    if verbose:
        yield
        return
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    logging.getLogger("absl").setLevel(logging.ERROR)
    try:
        sys.stderr.flush()
        saved = os.dup(2)
        r, w = os.pipe()
    except OSError:  # no fd 2 (a daemon, an embedded interpreter): nothing to filter
        yield
        return
    os.dup2(w, 2)
    os.close(w)
    thread = threading.Thread(target=_pump, args=(r, saved), name="quiet-stderr", daemon=True)
    thread.start()
    # Python's own writes (our messages, tqdm) go straight to the terminal: bars still see a tty
    py_stderr = sys.stderr
    try:
        swap = py_stderr.fileno() == 2  # not when a caller replaced it (pytest's capsys)
    except (AttributeError, OSError, ValueError):
        swap = False
    if swap:
        sys.stderr = open(os.dup(saved), "w", encoding=py_stderr.encoding or "utf-8",
                          errors="backslashreplace", buffering=1)
    try:
        yield
    finally:
        if swap:
            with contextlib.suppress(Exception):
                sys.stderr.flush()
                sys.stderr.close()
            sys.stderr = py_stderr
        os.dup2(saved, 2)  # closes the pipe's last write end: the thread sees EOF
        thread.join(timeout=5)
        if not thread.is_alive():  # else a child still holds the pipe: leave it to exit
            os.close(r)
            os.close(saved)

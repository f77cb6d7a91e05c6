"""Keep a native library's notes off standard output.

OpenEXR's Python bindings print ``Warning: Exception raised reading pixel data for part 0 -
...`` to ``sys.stdout`` when a file is damaged: a third-party line on the terminal before the
tool's own error, and in the output of ``probe --json`` piped to another program.
:func:`native_stdout_kept` puts a filter in front of ``sys.stdout`` while a reader runs: it
drops the lines a library is known to print (:data:`NOTES`) and passes everything else on at
once, in order (another thread's output meanwhile is neither lost nor delayed). Nested and
concurrent uses share one filter (the first in installs it, the last out removes it).
"""

from __future__ import annotations

import contextlib
import re
import sys
import threading
from typing import Iterator

__all__ = ["NOTES", "native_stdout_kept"]

#: The start of the line OpenEXR's bindings print of a damaged file.
_PREFIX = "Warning: Exception raised reading pixel data"
#: Lines native libraries print to standard output: OpenEXR's bindings of a damaged file.
NOTES = re.compile(re.escape(_PREFIX) + r".*\r?\n?$")


class _NoteFilter:
    """``sys.stdout`` less :data:`NOTES`: a line that may become one is held until it ends."""

    def __init__(self, out) -> None:
        self.out, self.held = out, ""

    def write(self, s: str) -> int:
        lines = (self.held + s).splitlines(keepends=True)
        self.held = ""
        if lines and not lines[-1].endswith("\n") and \
                (_PREFIX.startswith(lines[-1]) or lines[-1].startswith(_PREFIX)):
            self.held = lines.pop()
        for ln in lines:
            if not NOTES.match(ln):
                self.out.write(ln)
        return len(s)

    def release(self) -> None:
        """Pass on a held line that did not become a note."""
        if self.held and not NOTES.match(self.held):
            self.out.write(self.held)
        self.held = ""

    def __getattr__(self, name):
        return getattr(self.out, name)


_lock = threading.Lock()
_state: dict = {"depth": 0, "filter": None}


@contextlib.contextmanager
def native_stdout_kept() -> Iterator[None]:
    """Run the block with :data:`NOTES` dropped from ``sys.stdout``."""
    with _lock:
        if _state["depth"] == 0:
            _state["filter"] = _NoteFilter(sys.stdout)
            sys.stdout = _state["filter"]
        _state["depth"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["depth"] -= 1
            f = _state["filter"]
            if _state["depth"] == 0:
                f.release()
                if sys.stdout is f:       # not replaced by someone else meanwhile
                    sys.stdout = f.out
                _state["filter"] = None

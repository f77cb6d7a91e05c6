"""``python -m facetransfer`` and the ``facetransfer`` console script: the CLI
(:func:`facetransfer.cli.main.main`), with a Ctrl-C or a SIGTERM that comes while it loads said
in one line.

Loading the CLI (argparse, logging, zipfile and the CLI's own module) takes 0.15-0.2 s before
:func:`facetransfer.cli.main.main` sets its handlers, and the console script imported it before
any code of the project's ran: a Ctrl-C in that time printed the import's traceback (the one
0.05 s into a 30-frame transfer and into a puppet, and puppet's pairs 0.1 s in: 4 of 192
Ctrl-Cs into four commands; a new user's "wrong clip, stop" just after pressing Enter) and a SIGTERM killed the process with nothing
said. Here the CLI is loaded inside a ``try`` that says either in one line (exit status 130 or
143, as the CLI's own); this module imports nothing but the package (its docstring and
version) before that ``try`` (Python's ``signal`` inside it: with ``enum`` and ``functools``,
10-15 ms). Only the interpreter's own start (~20 ms, before any code of a
program runs) is left: a Ctrl-C there is Python's traceback, as for any Python program.
"""

from __future__ import annotations

import sys


def main() -> int:
    """Load the CLI and run it on ``sys.argv``; its exit status (130 or 143 for an interrupt
    before it began, said in one line)."""
    signal = None
    try:
        import signal      # inside the try: enum and functools come with it (10-15 ms)

        term = signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        if term:           # its default killed the process with nothing said
            signal.signal(signal.SIGTERM, _terminated)
        try:
            from .cli.main import main as cli
        finally:
            if term:       # the CLI sets its own
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
        return cli(process_ends=True)
    except KeyboardInterrupt as exc:
        if signal is not None and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, signal.SIG_IGN)     # nothing more to stop
        what, status = ("terminated", 143) if isinstance(exc, _Terminated) else \
            ("interrupted", 130)
        print(f"facetransfer: {what}", file=sys.stderr)
        return status


class _Terminated(KeyboardInterrupt):
    """SIGTERM while the CLI loads (the CLI's own :class:`facetransfer.cli.main.Terminated`
    is not loaded yet)."""


def _terminated(signum, frame):
    raise _Terminated


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``facetransfer`` console script.

Each subcommand lives in its own module with a ``register(subparsers)`` function that adds its
parser(s) and sets ``func`` to a handler ``handler(args) -> int``. Bad input raises a
:class:`ValueError` subclass in the library; here it becomes one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from .. import __version__

#: Subcommand modules, in help order. Each defines ``register(subparsers)``.
SUBCOMMAND_MODULES = ("model", "impute", "scan", "render", "texture", "track", "transfer",
                      "batch")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="facetransfer",
        description="Face Transfer with Multilinear Models (Vlasic et al. 2005): build multilinear "
        "face models, track faces in video, and transfer performances between videos.",
    )
    parser.add_argument("--version", action="version", version=f"facetransfer {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        module = importlib.import_module(f"{__package__}.{name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input or usage, 130 interrupted)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:  # every project error subclasses ValueError
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        print(f"facetransfer {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(f"facetransfer {args.command}: error: file not found: {exc.filename}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"facetransfer {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

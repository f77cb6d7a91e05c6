"""``facetransfer`` console script.

Each module of :data:`SUBCOMMAND_MODULES` has a ``register(subparsers)`` function that adds its
parser(s) and sets ``func`` to a handler ``handler(args) -> int``. A module is named after its
command or command group (``model build|info|...`` in :mod:`.model`), but for one that registers
two commands: :mod:`.render` registers ``render`` and ``synth-video``. Bad input raises a
:class:`ValueError` subclass in the library; here it becomes one line on stderr and exit
status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import functools
import importlib
import logging
import os
import re
import sys
import zipfile

from .. import __version__
from ..errors import interrupt_of

#: Subcommand modules, in help order. Each defines ``register(subparsers)``.
SUBCOMMAND_MODULES = ("model", "impute", "scan", "render", "texture", "track", "transfer",
                      "edit", "puppet", "demo", "export", "view", "batch", "probe")


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line, as every other bad input's.

    argparse's own error prints the command's whole usage first (25 lines for ``transfer``),
    so the one line that says what is wrong scrolls away among them; here it is the line, with
    where the options are listed, and exit status 2. Subcommands' parsers are of this class too
    (``add_subparsers`` makes its parsers of the parent's class).
    """

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (options: {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="facetransfer",
        description="Face Transfer with Multilinear Models (Vlasic et al. 2005): build multilinear "
        "face models, track faces in video, and transfer performances between videos.",
    )
    parser.add_argument("--version", action="version", version=f"facetransfer {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log progress details, and let third-party libraries (MediaPipe, "
                        "TensorFlow Lite) log too")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        module = importlib.import_module(f"{__package__}.{name}")
        module.register(sub)
    _describe_subcommands(parser)
    for leaf in _leaf_parsers(parser):
        if "--no-progress" not in leaf._option_string_actions:
            leaf.add_argument("--no-progress", action="store_true",
                              help="no progress bars (they are drawn only on a terminal)")
        # also after the command (``facetransfer track V --out T -v``); no default, so a -v
        # before the command is not undone by the command's parser
        leaf.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                          help="as facetransfer -v")
        if leaf.prog.split(" ", 1)[-1] in READING_COMMANDS:
            leaf.add_argument("--sequence-fps", type=_rate, metavar="FPS",
                              help="frame rate of image-sequence inputs (plate/%%04d.png, "
                              "plate/####.dpx); default: the rate a DPX or OpenEXR plate's "
                              "headers give, else 24; given, it overrides the headers")
    return parser


#: Commands that read videos, and so image sequences, whose rate ``--sequence-fps`` gives.
READING_COMMANDS = frozenset({"track", "transfer", "puppet", "demo", "export", "probe",
                              "texture lift", "batch track", "batch transfer"})


def _rate(text: str) -> float:
    """``--sequence-fps``'s value: frames a second in (0, 1000]."""
    try:
        fps = float(text)
    except ValueError:
        fps = float("nan")
    if not 0 < fps <= 1000:
        raise argparse.ArgumentTypeError(f"expected a frame rate in (0, 1000], got {text!r}")
    return fps


def use_sequence_rate(args, environ=os.environ) -> None:
    """Give ``--sequence-fps`` to the readers of image sequences, and to the processes this
    one starts (a forked tracker, Dask's local workers), through
    :data:`facetransfer.io.video_sequence.SEQUENCE_FPS_VARIABLE`."""
    fps = getattr(args, "sequence_fps", None)
    if fps is not None:
        from ..io.video_sequence import SEQUENCE_FPS_VARIABLE

        environ[SEQUENCE_FPS_VARIABLE] = repr(fps)


def command_parser(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.ArgumentParser:
    """The parser of the (sub)command ``argv`` runs (``edit``, ``model build``): the leaf
    whose command words begin ``argv``'s words that are not options, the longest such; the
    top parser when none does."""
    words = [a for a in argv if not a.startswith("-")]
    best, size = parser, 0
    for leaf in _leaf_parsers(parser):
        names = leaf.prog.split()[1:]
        if size < len(names) and words[:len(names)] == names:
            best, size = leaf, len(names)
    return best


_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")

#: A word that begins with a minus sign and is a value, not an option: a number argparse does
#: not take for one (``-1e5``, ``-inf``, ``-nan``), a list or a size that begins with one
#: (``-0.5,0.2``, ``-1x48``).
_DASHED_VALUE = re.compile(r"^-(\d|\.\d|inf|nan)", re.IGNORECASE)


def attached_values(leaf: argparse.ArgumentParser, words: list[str]) -> list[str]:
    """``words`` with each value that begins with a minus sign (:data:`_DASHED_VALUE`) joined
    to the option before it that takes one value: ``--identity-weights -0.5,0.2`` as
    ``--identity-weights=-0.5,0.2``. Argparse takes such a word for an option: before, negative
    identity coordinates were "unrecognized arguments: -0.5,0.2", ``--smooth -1e5`` "expected
    one argument", ``--crf -inf`` "unrecognized arguments", none naming what the option
    expects. The words after ``--`` are left as they are."""
    known, out, k = leaf._option_string_actions, [], 0
    while k < len(words):
        word = words[k]
        if word == "--":
            return out + words[k:]
        action = _option_named(known, word)
        if action is not None and action.nargs is None and k + 1 < len(words) and \
                _DASHED_VALUE.match(words[k + 1]) and words[k + 1] not in known:
            out.append(f"{word}={words[k + 1]}")
            k += 2
            continue
        out.append(word)
        k += 1
    return out


def _option_named(known: dict, word: str):
    """The action of the option ``word`` names: its own, or of the one long option it
    abbreviates (as argparse takes ``--backgr`` for ``--background``; before, ``--backgr
    -1,2,3`` was "unrecognized arguments: -1,2,3"); None for none or several."""
    if word in known or not word.startswith("--") or "=" in word:
        return known.get(word)
    named = {known[o] for o in known if o.startswith(word)}
    return next(iter(named)) if len(named) == 1 else None


def empty_option(leaf: argparse.ArgumentParser, args) -> str | None:
    """The first option of ``leaf`` given an empty value (``--identity-weights ''``), or None:
    the commands took an empty text for the option not given (the target's own identity, the
    model's mean face) without a word."""
    for action in leaf._actions:
        if not action.option_strings or action.nargs is not None:
            continue
        value = getattr(args, action.dest, None)
        if value == action.default:
            continue
        if any(isinstance(v, str) and not v.strip()
               for v in (value if isinstance(value, list) else [value])):
            return action.option_strings[-1]
    return None


def unknown_options(leaf: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """The options among ``argv``'s words after its command words that the command's parser
    ``leaf`` does not take (nor abbreviates, nor combines as short flags like ``-vv``);
    negative numbers and the words after ``--`` are values. None for the top parser."""
    names = leaf.prog.split()[1:]
    if not names:
        return []
    rest, k = list(argv), 0
    try:
        for name in names:                  # past the command words, in order
            k = rest.index(name, k) + 1
    except ValueError:                      # not typed as its parser names it: argparse's
        return []
    known = leaf._option_string_actions
    out = []
    for word in rest[k:]:
        if word == "--":
            break
        if not word.startswith("-") or word == "-" or _NUMBER.match(word):
            continue
        name = word.split("=", 1)[0]
        if name in known or (name.startswith("--") and any(o.startswith(name) for o in known)):
            continue
        if not name.startswith("--") and all(f"-{c}" in known for c in name[1:]):
            continue
        out.append(word)
    return out


def _describe_subcommands(parser: argparse.ArgumentParser) -> None:
    """Give every subcommand without a description its one-line help as one, so that its own
    ``--help`` says what it does (``model build --help``, ``scan fit --help`` and seven
    others showed only their usage and options)."""
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        for choice in action._choices_actions:
            child = action.choices[choice.dest]
            if not child.description and choice.help:
                text = choice.help[0].upper() + choice.help[1:]
                child.description = text if text.endswith(".") else text + "."
            _describe_subcommands(child)


def _leaf_parsers(parser: argparse.ArgumentParser):
    """The parsers of every command and subcommand (``model build``, ...) that has no
    subcommands of its own."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield parser
    for action in subs:
        for child in dict.fromkeys(action.choices.values()):  # aliases: one parser
            yield from _leaf_parsers(child)


#: environment that silences the C++ logs of MediaPipe / TensorFlow Lite / absl, of the
#: FFmpeg inside OpenCV (an interlaced picture it cannot convert, facetransfer.io.video_pipe)
#: and of OpenCV itself (a damaged frame file, which the tool's own line names), unless -v
QUIET_NATIVE_LOGS = {"GLOG_minloglevel": "2", "TF_CPP_MIN_LOG_LEVEL": "3",
                     "ABSL_MIN_LOG_LEVEL": "2", "OPENCV_FFMPEG_LOGLEVEL": "-8",
                     "OPENCV_LOG_LEVEL": "SILENT"}


def configure_logging(verbose: bool) -> None:
    """facetransfer's own warnings always; third-party log lines and warnings only with -v."""
    from .stderr import CurrentStderrHandler

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s",
                        handlers=[CurrentStderrHandler()])
    logging.getLogger("facetransfer").setLevel(logging.INFO if verbose else logging.WARNING)
    if verbose:
        return
    for k, v in QUIET_NATIVE_LOGS.items():
        os.environ.setdefault(k, v)
    logging.captureWarnings(True)       # third-party warnings become log records ...
    logging.getLogger("py.warnings").setLevel(logging.ERROR)   # ... shown only with -v
    root = logging.getLogger()
    root.setLevel(logging.ERROR)        # other libraries' loggers: errors only
    for name in ("trimesh", "matplotlib", "PIL", "numba", "distributed", "absl"):
        logging.getLogger(name).setLevel(logging.ERROR)


#: Commands that already keep every core busy on their own (a forked tracker or detector,
#: the render's threads, ffmpeg): OpenBLAS's and OpenCV's own threads only spin beside them.
SERIAL_BLAS_COMMANDS = frozenset({"track", "transfer", "edit", "puppet", "demo"})

#: The variables that give OpenBLAS and OpenCV's ``parallel_for_`` one thread each, read once
#: when each library loads.
SERIAL_POOLS = {"OPENBLAS_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}


def serial_blas(argv: list[str], environ=os.environ) -> bool:
    """Ask OpenBLAS and OpenCV for one thread (:data:`SERIAL_POOLS`) when ``argv``'s command
    is in :data:`SERIAL_BLAS_COMMANDS`.

    Both read their variable once, when NumPy (or SciPy) loads OpenBLAS and when ``cv2`` is
    imported, so this runs before the parser imports the subcommands; a value the user set
    is kept. Their worker threads busy-wait between calls (OpenCV's in ``sched_yield``): in a
    10-second transfer on 2 cores OpenBLAS's took 1.1-2 of the ~20 CPU-seconds (BENCHMARKS.md,
    "Fourteenth session") and OpenCV's ~0.4 of ~18 plus as much again in the kernel, while the
    tracker's and the render's own threads waited for the cores ("Thirtieth session").
    Returns whether the command is one of them.
    """
    command = next((a for a in argv if not a.startswith("-")), None)
    if command not in SERIAL_BLAS_COMMANDS:
        return False
    for name, value in SERIAL_POOLS.items():
        environ.setdefault(name, value)
    return True


def command_name(args) -> str:
    """The command as typed, with its action where it has some: ``model build``, ``batch
    track`` (the name usage errors give it too)."""
    action = getattr(args, f"{args.command}_command", None)
    return f"{args.command} {action}" if action else str(args.command)


def error_line(command: str, exc: BaseException) -> str:
    """The one line a failed command prints (no traceback)."""
    if isinstance(exc, ValueError):  # every project error subclasses ValueError
        msg = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
    elif isinstance(exc, MemoryError):
        msg = "out of memory (the job is too large for this machine; make it smaller)"
    elif isinstance(exc, OSError):
        what = os.strerror(exc.errno) if exc.errno else str(exc)
        if exc.errno == errno.ENOSPC:
            what = "no space left on the device"
        where = f": {os.fsdecode(exc.filename)}" if exc.filename is not None else ""
        msg = f"{what}{where}"
    else:  # EOFError, BadZipFile: an input file read without the project's loaders
        msg = f"an input file is truncated or damaged ({exc.__class__.__name__}: {exc})"
    return f"facetransfer {command}: error: {msg}"


def main(argv: list[str] | None = None, *, process_ends: bool = False) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input or usage, 130 interrupted by
    Ctrl-C, 143 terminated by SIGTERM, after keeping what an interrupt keeps).

    ``process_ends``: the process exits once this returns (the console script,
    :mod:`facetransfer.__main__`): native log lines stay filtered and Ctrl-C ignored until it
    has (:func:`_no_more_stops`).

    Called with no ``argv`` (the console script), native libraries' log lines are filtered out
    of stderr unless ``-v`` is given (:mod:`.stderr`), and the commands that run their own
    parallel work keep OpenBLAS and OpenCV to one thread each (:func:`serial_blas`). A Ctrl-C
    before the command began (while the subcommands' modules load: half a second) is one line
    and 130 as well (it printed the import's traceback); a SIGTERM then, one line and 143 (it
    killed the process by the signal, with nothing said). An interrupt raised where Python
    ignores exceptions is sent again (:func:`facetransfer.signals.interrupts_not_ignored`), and
    one that would be raised inside importlib's or logging's lock taking is sent again instead
    (:func:`_interrupted`, :func:`_terminated`).
    """
    import signal

    from ..signals import interrupts_not_ignored

    previous = {signal.SIGTERM: _catching_sigterm(), signal.SIGINT: _catching_sigint()}
    try:
        with interrupts_not_ignored(((Terminated, signal.SIGTERM),
                                     (KeyboardInterrupt, signal.SIGINT))):
            return _main(argv, process_ends)
    except KeyboardInterrupt as exc:     # the command's own are said by _run: not yet begun
        _no_more_stops()
        what, status = _stop_status(exc)
        print(f"facetransfer: {what}", file=sys.stderr)
        return status
    finally:
        for signum, handler in previous.items():
            if handler is not None:     # the console script's exit takes no more Ctrl-C
                exiting = process_ends and signum == signal.SIGINT
                signal.signal(signum, signal.SIG_IGN if exiting else handler)


def _stop_status(stop: KeyboardInterrupt) -> tuple[str, int]:
    """What a run stopped by ``stop`` says and its exit status: ``("terminated", 143)`` for a
    SIGTERM (:class:`Terminated`), ``("interrupted", 130)`` for a Ctrl-C."""
    return ("terminated", 143) if isinstance(stop, Terminated) else ("interrupted", 130)


def _main(argv: list[str] | None, process_ends: bool = False) -> int:
    """:func:`main`'s work: parse ``argv``, set up logging and stderr, run the command."""
    if argv is None:
        serial_blas(sys.argv[1:])
    parser = build_parser()
    words = sys.argv[1:] if argv is None else [str(a) for a in argv]
    leaf = command_parser(parser, words)
    words = attached_values(leaf, words)
    unknown = unknown_options(leaf, words)
    if unknown:  # before argparse's own checks: a misspelt --out is said, not "--out required"
        leaf.error(f"unrecognized arguments: {' '.join(unknown)}")
    args, extra = parser.parse_known_args(words)
    if extra:  # said by the command's own parser: its --help lists what it takes
        leaf.error(f"unrecognized arguments: {' '.join(extra)}")
    empty = empty_option(leaf, args)
    if empty:
        leaf.error(f"argument {empty}: expected a value, got ''")
    configure_logging(args.verbose)
    from .common import set_progress

    set_progress(not getattr(args, "no_progress", False))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    if argv is None:
        use_sequence_rate(args)
        if args.verbose:
            return _exiting(_run(args))
        from .stderr import filtered_stderr

        with filtered_stderr(until_exit=process_ends):
            return _exiting(_run(args))
    with _sequence_rate_kept():  # a caller's process goes on: the next command's rate is its own
        use_sequence_rate(args)
        return _run(args)


@contextlib.contextmanager
def _sequence_rate_kept():
    """The process's ``--sequence-fps`` variable as it was once the block ends (a command
    called in process, :func:`main` with ``argv``, gives its rate to its readers and children
    only; before, the next command in the process read image sequences at it)."""
    from ..io.video_sequence import SEQUENCE_FPS_VARIABLE

    before = os.environ.get(SEQUENCE_FPS_VARIABLE)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(SEQUENCE_FPS_VARIABLE, None)
        else:
            os.environ[SEQUENCE_FPS_VARIABLE] = before


def _exiting(status: int) -> int:
    """``status``, after moving every live object out of the garbage collector's reach.

    The console script's process ends right after its command: the interpreter's final
    collection would then walk every object the command's libraries made (numba's, SciPy's,
    MediaPipe's) only to free memory that the exit returns anyway; half a second of a
    10-second transfer (``benchmarks/bench_transfer_e2e.py``). Destructors that do not depend
    on the collector (open files, temporary outputs) still run. Only for the console script:
    a process that calls :func:`main` and goes on keeps its collector; nor after OpenImageIO
    was loaded (DPX frames, :mod:`facetransfer.io.dpx`): its bindings (nanobind) print a
    "leaked instances" report at the exit for every object of theirs left uncollected.
    """
    import gc

    if "OpenImageIO" not in sys.modules:
        gc.freeze()
    return status


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a scheduler's pre-emption, ``timeout``), raised where the command is,
    so that it keeps what an interrupt keeps (progress files, the caches' partial work, the
    video part being written) instead of dying where it stands."""


def _terminated(signum, frame):
    """The CLI's SIGTERM: :class:`Terminated`, raised as :func:`_raise_at` says."""
    _raise_at(frame, signum, Terminated)


def _interrupted(signum, frame):
    """The CLI's Ctrl-C: Python's own (KeyboardInterrupt), raised as :func:`_raise_at` says."""
    _raise_at(frame, signum, KeyboardInterrupt)


def _raise_at(frame, signum: int, stop: type[KeyboardInterrupt]) -> None:
    """Raise ``stop`` in ``frame`` (the code the main thread was running), but not where a lock
    taken before its ``try`` would be left held (importlib's, logging's:
    :func:`facetransfer.signals.unsafe_to_raise_at`): ``signum`` is sent again a moment later
    instead."""
    from ..signals import send_later, unsafe_to_raise_at

    if unsafe_to_raise_at(frame):
        send_later(signum)
        return
    raise stop


def _no_more_stops() -> None:
    """Ignore Ctrl-C and SIGTERM from here until :func:`main` restores the handlers there were
    (the console script's exit keeps ignoring Ctrl-C): the command has ended, or its stop is
    being said. A second Ctrl-C then (a user's, 10-200 ms after the first, while the command
    said its line and the process exited) printed a second line, or a traceback of the line's
    own ``print``, or of the interpreter's exit (joining threads), or killed the process by
    the signal (status -2, not 130: Python's exit puts a Python-level handler back to the
    default, not an ignored signal) (BENCHMARKS.md, "Fifty-fourth session"). Only where the
    handlers are the CLI's own (:func:`main` set them, in the main thread)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    for signum, ours in ((signal.SIGINT, _interrupted), (signal.SIGTERM, _terminated)):
        if signal.getsignal(signum) is ours:
            signal.signal(signum, signal.SIG_IGN)


def _catching_sigint():
    """:func:`_interrupted` for Ctrl-C where Python's own handler is (main thread only; a job
    started in the background ignores it, a caller's own handler is kept); returns the old
    handler to restore, or None."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return None
    return signal.signal(signal.SIGINT, _interrupted)


def _default_sigterm_in_child() -> None:
    """A forked child (a background tracker, a render worker) dies of SIGTERM (the default
    handler, not its parent's, which raises :class:`Terminated`): a SIGTERM to the process
    group, or the executor's ``terminate`` of a broken pool, ends it (its parent cancels it by
    SIGKILL, :func:`facetransfer.signals.kill_forked`)."""
    import signal

    if signal.getsignal(signal.SIGTERM) is _terminated:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@functools.cache
def _reset_sigterm_in_children() -> None:
    """Register :func:`_default_sigterm_in_child` for every later fork (once: a registration
    cannot be undone)."""
    os.register_at_fork(after_in_child=_default_sigterm_in_child)


def _catching_sigterm():
    """Route SIGTERM to :class:`Terminated` where its default is (main thread only; forked
    children keep the default; a caller's own handler or its ignoring is kept, as Ctrl-C's,
    :func:`_catching_sigint`); returns the old handler to restore, or None."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return None
    _reset_sigterm_in_children()
    return signal.signal(signal.SIGTERM, _terminated)


def _run(args) -> int:
    """Run the parsed command: its status, or that of the one line said of what stopped it
    (an error, a Ctrl-C, a SIGTERM: whose handler :func:`main` sets)."""
    from ..io.atomic import commit_checks

    before = {p: _file_id(p) for p in _outputs(args)}
    # a model file written over as the command runs: no output after (io.atomic); batch's
    # workers check it clip by clip (batch.model_ref) and the run's summary says which failed
    checks = contextlib.nullcontext() if args.command == "batch" else commit_checks()
    try:
        with checks:
            status = int(args.func(args) or 0)
        _no_more_stops()        # done: a Ctrl-C now has nothing left to stop
        sys.stdout.flush()      # what the command said, while a closed pipe can be caught here
        return status
    except (ValueError, OSError, MemoryError, EOFError, zipfile.BadZipFile) as exc:
        _no_more_stops()
        # bad input, a failed write or read (permissions, full disk), a job too large
        if isinstance(exc, BrokenPipeError) and _stdout_gone():
            return 141        # read by ``| head``, which stopped reading: nothing to say
        if args.verbose:
            logging.getLogger("facetransfer").exception("details")
        print(error_line(command_name(args), exc), file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as exc:
        stop = interrupt_of(exc)     # a compiled kernel's SystemError caused by the interrupt
        if stop is None:
            raise
        _no_more_stops()
        what, status = _stop_status(stop)
        written = [str(p) for p in _outputs(args)
                   if (now := _file_id(p)) is not None and now != before.get(p)]
        print(f"facetransfer {command_name(args)}: {what}{_noted(stop)}"
              f"{_kept(args.command, written)}", file=sys.stderr)
        return status


def _noted(stop: BaseException) -> str:
    """What the command noted on its interrupt (``stop.add_note``: where its progress is, what
    a batch kept), each after "; ", for its one line: ``track`` and ``batch`` printed a line of
    their own before the CLI's (two lines for one Ctrl-C: 18 and 24 of 48 Ctrl-Cs into a 30- and
    a 240-frame ``track``).
    The notes of an interrupt it stopped in the handling of (a second Ctrl-C meanwhile) too."""
    notes, seen = [], set()
    while stop is not None and id(stop) not in seen:
        seen.add(id(stop))
        notes[:0] = [n for n in getattr(stop, "__notes__", ()) if n not in notes]
        stop = stop.__context__
    return "".join(f"; {n}" for n in notes)


def _stdout_gone() -> bool:
    """Whether standard output's reader has gone (``facetransfer probe V | head -1``); if so,
    it is pointed at the null device so that the interpreter's last flush says nothing
    either (the exit status is then 141, a shell's for a command stopped by SIGPIPE)."""
    import select

    try:
        fd = sys.stdout.fileno()
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        if not any(ev & select.POLLERR for _, ev in poll.poll(0)):  # a pipe without reader
            return False
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, fd)
        os.close(null)
    except (OSError, ValueError, AttributeError):   # no file descriptor (captured output)
        return False
    return True


#: Commands whose tracking goes through the track cache (facetransfer.track.cache)
CACHED_TRACKING = ("transfer", "puppet", "demo")


#: Commands whose render goes through the render cache (facetransfer.render_cache)
CACHED_RENDERING = ("transfer", "puppet")


#: Arguments naming a command's outputs, and ``demo``'s files in its folder.
_OUTPUT_ARGS = ("out", "matte", "save_track", "meshes", "function")
_DEMO_FILES = ("demo.mp4", "demo.mov", "demo.png", "demo_track.npz")


def _outputs(args) -> list:
    """The files (and folders) a command writes, as its arguments name them (a pattern of an
    image sequence and a batch's folder are not among them: they are kept frame by frame,
    clip by clip)."""
    from pathlib import Path

    if args.command == "batch":
        return []
    if args.command == "demo":
        return [Path(args.out) / name for name in _DEMO_FILES]
    return [Path(v) for v in (getattr(args, n, None) for n in _OUTPUT_ARGS)
            if isinstance(v, (str, os.PathLike)) and "%" not in str(v)]


def _file_id(p) -> tuple | None:
    """Which file ``p`` is now (device, inode, size, modification time), None where it is none
    (a folder, a name too long or a path that cannot be looked at, never a traceback of its
    own): an output the command replaced (``--overwrite``) is another file, as a new one is."""
    import stat

    try:
        st = p.stat()
    except (OSError, ValueError):
        return None
    if not stat.S_ISREG(st.st_mode):
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _kept(command: str, written: list | None = None) -> str:
    """What an interrupted ``command`` keeps for the next run (the track cache's progress, the
    render cache's parts), and the outputs it had ``written`` before it stopped: the next run
    replaces them only with ``--overwrite``, so the line says so (the same command alone
    refuses them as existing)."""
    from ..render_cache import cache_enabled as rendering
    from ..track.cache import cache_enabled as tracking

    track = command in CACHED_TRACKING and tracking()
    render = command in CACHED_RENDERING and rendering()
    again = "the same command with --overwrite" if written else "the same command"
    said = ""
    if track and render:
        said = (f"; the tracking and the frames rendered so far are kept in the cache: {again} "
                "continues from them")
    elif track:
        said = (f"; the tracking done so far is kept in the track cache: {again} continues "
                "from it")
    elif render:
        said = (f"; the frames rendered so far are kept in the render cache: {again} "
                "continues from them")
    if written:
        said += (f"; it had written {', '.join(written)}"
                 + ("" if said else ": run it again with --overwrite to replace them"))
    return said


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""Ctrl-C at any moment of the console script's life is one line (``benchmarks/bench_interrupt.py``
sends it at every moment of real runs): while the CLI loads, while a command says its stop,
while the process exits. Each in a process of its own, as the console script runs, the signal
sent at a chosen point (an import, the line's making, an ``atexit`` callback)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _console(*code: str, args=("probe", "x.mp4"), timeout: float = 60
             ) -> subprocess.CompletedProcess:
    """Run ``code`` (pieces of Python, at their end the console script's entry run on
    ``args``) in a process of its own: its status and output (``timeout``: seconds before it
    is said to hang)."""
    code = "".join(textwrap.dedent(c) for c in code) + textwrap.dedent(f"""
        sys.argv = ["facetransfer", *{list(args)!r}]
        from facetransfer.__main__ import main
        sys.exit(main())
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "PYTHONPATH": SRC})


@pytest.mark.parametrize("signum,said", [("SIGINT", (130, "interrupted")),
                                          ("SIGTERM", (143, "terminated"))])
def test_a_stop_while_the_cli_loads_is_one_line(signum, said):
    """The console script imported the CLI (argparse, logging, zipfile, its own module: 0.15-
    0.2 s) before any of the project's code ran: a Ctrl-C then printed the import's traceback
    (4 of 192 Ctrl-Cs into four commands, 0.05-0.1 s in) and a SIGTERM killed the process
    with no line. The signal here comes as the CLI imports argparse."""
    r = _console(f"""
        import importlib.abc, os, signal, sys

        class Stop(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path, target=None):
                if name == "argparse":
                    os.kill(os.getpid(), signal.{signum})
                    sum(range(10000))                  # the handler runs here
                return None

        assert "argparse" not in sys.modules
        sys.meta_path.insert(0, Stop())
    """)
    assert (r.returncode, r.stderr.splitlines()) == (said[0], [f"facetransfer: {said[1]}"])


def test_python_m_facetransfer_is_the_cli():
    r = subprocess.run([sys.executable, "-m", "facetransfer", "--version"], capture_output=True,
                       text=True, timeout=60, env={**os.environ, "PYTHONPATH": SRC})
    assert (r.returncode, r.stdout.split()[0], r.stderr) == (0, "facetransfer", "")


#: A probe command that stops as a Ctrl-C does (``raise``) or ends (0).
COMMAND = """
    import atexit, os, signal, sys, time
    from facetransfer.cli import main as cli_main, probe

    def stopped(args):
        raise KeyboardInterrupt

    probe.run = stopped if STOP else (lambda args: 0)
"""


def test_a_second_ctrl_c_while_the_stop_is_said_is_ignored():
    """A second Ctrl-C while the command made its line (here: as it asks what the caches keep)
    was raised there: the command's line was lost and the CLI's "before the command began" one
    said instead (a traceback where it came during that line's ``print``)."""
    r = _console("STOP = True\n", COMMAND, """
    real = cli_main._kept

    def kept(*args):
        os.kill(os.getpid(), signal.SIGINT)
        sum(range(10000))                              # the handler runs here
        return real(*args)

    cli_main._kept = kept
    """)
    assert (r.returncode, r.stderr.splitlines()) == (130, ["facetransfer probe: interrupted"])


@pytest.mark.parametrize("stop,said", [(True, (130, ["facetransfer probe: interrupted"])),
                                       (False, (0, []))])
def test_a_ctrl_c_while_the_process_exits_is_ignored(stop, said):
    """A Ctrl-C after the command ended, while the interpreter exits (its ``atexit`` callbacks,
    its threads joined: a user's second Ctrl-C 10-200 ms after the first) printed
    "Exception ignored in atexit callback" and a traceback, or killed the process by the signal
    (status -2, not the command's). Ignored now: the command's status and line only."""
    r = _console(f"STOP = {stop}\n", COMMAND, """
    def exiting():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)                                # the handler runs here, if any

    atexit.register(exiting)
    """)
    assert (r.returncode, r.stderr.splitlines()) == said


def test_a_ctrl_c_while_a_thread_starts_is_taken_after_it():
    """A Ctrl-C raised while a ``ThreadPoolExecutor`` started its worker (``Thread.start``
    waiting for the thread to begin) left the worker running but unrecorded: the interpreter's
    exit never woke it, and the process hung for ever after its line (2 of about 200 runs
    given Ctrl-C 0.5-3.5 s into a transfer). Here the signal comes as the worker begins; it is
    raised a moment later, after ``start``, and the process ends."""
    r = _console("STOP = False\n", COMMAND, """
    import threading
    from concurrent.futures import ThreadPoolExecutor

    real = threading.Thread._bootstrap_inner

    def bootstrap(self):
        if self.name.startswith("ThreadPoolExecutor"):
            os.kill(os.getpid(), signal.SIGINT)        # the starting thread still waits
            time.sleep(0.2)
        real(self)

    threading.Thread._bootstrap_inner = bootstrap

    POOL = ThreadPoolExecutor(1)                       # kept, as a module's pool is

    def command(args):
        POOL.submit(time.sleep, 0)
        time.sleep(5)                                  # the Ctrl-C is raised here
        return 0

    probe.run = command
    """, timeout=20)
    assert (r.returncode, r.stderr.splitlines()) == (130, ["facetransfer probe: interrupted"])


def test_native_lines_after_a_stop_stay_filtered_until_the_process_exits():
    """A command stopped while MediaPipe's landmarker was being made (its graph's threads log
    as they start) or while a thread still loaded it: their lines came after the CLI's one (3
    of 192 Ctrl-Cs), the filter of native lines (:mod:`facetransfer.cli.stderr`) ended with
    the command while the process's exit still waited for them. Here a thread logs 0.3 s
    after the command stopped."""
    r = _console("STOP = True\n", COMMAND, """
    import threading

    def loading():
        time.sleep(0.3)
        os.write(2, b"W0000 00:00:1796628595.414419   30557 feedback.cc:121] Feedback\\n")
        os.write(2, b"INFO: Created TensorFlow Lite XNNPACK delegate for CPU.\\n")

    real = probe.run

    def command(args):
        threading.Thread(target=loading).start()
        real(args)

    probe.run = command
    """)
    assert (r.returncode, r.stderr.splitlines()) == (130, ["facetransfer probe: interrupted"])


def test_a_newline_left_of_two_processes_native_lines_is_dropped():
    """TensorFlow Lite writes its severity, message and newline in three writes: two
    processes' lines interleaved left a line of both and a newline alone, which passed as a
    blank line before the CLI's (3 of 48 Ctrl-Cs into a 240-frame track). Another blank line
    passes."""
    from facetransfer.cli.stderr import filter_native

    both = (b"INFO: INFO: Created TensorFlow Lite XNNPACK delegate for CPU.Created TensorFlow "
            b"Lite XNNPACK delegate for CPU.\n")
    assert filter_native(both + b"\n") == (b"", b"", False)
    assert filter_native(both) == (b"", b"", True)
    assert filter_native(b"\n", after_native=True) == (b"", b"", False)   # in the next read
    assert filter_native(b"own line\n\n") == (b"own line\n\n", b"", False)


def test_a_ctrl_c_in_an_import_is_taken_after_it(tmp_path):
    """C code that imports turns an interrupt raised inside into an error of its own: NumPy's
    multiarray, whose import of ``datetime`` took a Ctrl-C, raised "ImportError:
    PyCapsule_Import could not import module 'datetime'" (60 lines, exit 1; 1 of 48 Ctrl-Cs
    into ``puppet`` while the CLI's modules loaded). Here a module swallows it the same way;
    the interrupt is raised once the import is done."""
    (tmp_path / "victim.py").write_text("import os, signal\n"
                                        "os.kill(os.getpid(), signal.SIGINT)\n"
                                        "sum(range(100000))      # the handler runs here\n")
    (tmp_path / "swallow.py").write_text("try:\n    import victim\n"
                                         "except BaseException:    # as NumPy's C code does\n"
                                         "    raise ImportError('could not import victim')"
                                         " from None\n")
    r = _console("STOP = False\n", COMMAND, f"""
    sys.path.insert(0, {str(tmp_path)!r})

    def command(args):
        import swallow                                 # noqa: F401
        time.sleep(5)                                  # the Ctrl-C is raised here
        return 0

    probe.run = command
    """)
    assert (r.returncode, r.stderr.splitlines()) == (130, ["facetransfer probe: interrupted"])

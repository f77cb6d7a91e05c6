"""What every benchmark script does around its measurements: its command line (``--out``),
the ``facetransfer`` command it times and the CPU its child processes took, and writing its
JSON and its plot."""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path


def arguments(doc: str) -> argparse.ArgumentParser:
    """A parser described by the first line of the script's docstring, with ``--out``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    return ap


def save_json(report: dict, path: Path) -> None:
    """Write ``report`` to ``path`` as indented JSON, atomically."""
    import json

    from facetransfer.io.atomic import write_text_atomic

    write_text_atomic(path, json.dumps(report, indent=1))


def save_plot(fig, path: Path) -> None:
    """Lay ``fig`` out, write it to ``path`` atomically and close it."""
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def facetransfer_exe() -> str:
    """The console script of the running environment."""
    return str(Path(sys.executable).parent / "facetransfer")


def children_cpu() -> float:
    """CPU seconds (user + system) of every finished child process and its own children."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime

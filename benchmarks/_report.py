"""What every benchmark script does around its measurements: its command line (``--out``)
and writing its plot."""

from __future__ import annotations

import argparse
from pathlib import Path


def arguments(doc: str) -> argparse.ArgumentParser:
    """A parser described by the first line of the script's docstring, with ``--out``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    return ap


def save_plot(fig, path: Path) -> None:
    """Lay ``fig`` out, write it to ``path`` atomically and close it."""
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)

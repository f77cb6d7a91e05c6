"""The summary table of a batch run: ``DIR/summary.csv``, one row per output (a clip's; one
per format or codec where a folder holds several).

==================  ======================================================================
column              meaning
==================  ======================================================================
``clip``            the job's name (its output is ``DIR/NAME.<ext>``); a folder holding the
                    outputs of runs of several formats or codecs has a row per output,
                    ``clip`` and ``output`` together naming it
``frames``          frames of the output (empty when it failed)
``fps``             frame rate
``seconds``         compute seconds spent on the clip in this run (all its tasks; 0 if skipped)
``mean_confidence`` mean tracking confidence over the frames (empty if not known)
``status``          ``done``, ``skipped`` (already done by an earlier run), ``failed`` or
                    ``cancelled`` (the run was stopped before it finished)
``error``           one line: why it failed (empty unless failed)
``output``          the output's path
``job``             a digest of what made the output (the job's input files by their
                    content, its labels and options, the model: ``v2:`` and 16 hex
                    digits, :mod:`facetransfer.batch.digest`; 16 hex digits alone: an
                    older version's, of the files' paths and times): a rerun that finds
                    another one there has not made that output
``matte``           the matte the job made with its output (``batch transfer --matte``:
                    ``DIR/NAME.matte/NAME.%05d.png``), empty where it made none; a rerun
                    asking for a matte takes the one there as the job's only where the
                    row names it
``note``            one line: what happened on the way to a done row, empty mostly (its
                    output taken from the run's earlier attempt of the job, which Dask ran
                    again, or made again after it)
==================  ======================================================================
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

from ..io.atomic import write_text_atomic
from .manifest import BatchError

__all__ = ["Row", "SUMMARY_COLUMNS", "STATUSES", "write_summary", "read_summary"]

SUMMARY_COLUMNS = ("clip", "frames", "fps", "seconds", "mean_confidence", "status", "error",
                   "output", "job", "matte", "note")
STATUSES = ("done", "skipped", "failed", "cancelled")


@dataclass(frozen=True)
class Row:
    """One output's line of ``summary.csv`` (see the module docstring)."""

    clip: str
    status: str
    frames: int | None = None
    fps: float | None = None
    seconds: float = 0.0
    mean_confidence: float | None = None
    error: str = ""
    output: str = ""
    job: str = ""
    matte: str = ""
    note: str = ""

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"summary status must be one of {STATUSES}, got {self.status!r}")
        # one line, whatever the exception said
        object.__setattr__(self, "error", " ".join(str(self.error).split()))
        object.__setattr__(self, "note", " ".join(str(self.note).split()))

    @property
    def ok(self) -> bool:
        return self.status in ("done", "skipped")


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_summary(path: str | os.PathLike, rows) -> Path:
    """Write the rows to ``path`` (CSV with :data:`SUMMARY_COLUMNS`) atomically."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SUMMARY_COLUMNS)
    for r in rows:
        w.writerow([_cell(getattr(r, c)) for c in SUMMARY_COLUMNS])
    return write_text_atomic(path, buf.getvalue(), overwrite=True)


def read_summary(path: str | os.PathLike) -> list[Row]:
    """Read a ``summary.csv`` written by :func:`write_summary`; BatchError naming the file
    where it is not one (a column missing, a number that is not)."""
    def num(s, kind):
        return kind(s) if s != "" else None

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            return [Row(clip=r["clip"], status=r["status"], frames=num(r["frames"], int),
                        fps=num(r["fps"], float), seconds=float(r["seconds"] or 0),
                        mean_confidence=num(r["mean_confidence"], float), error=r["error"],
                        output=r.get("output") or "", job=r.get("job") or "",
                        matte=r.get("matte") or "", note=r.get("note") or "")
                    for r in csv.DictReader(fh)]
    except OSError as exc:
        raise BatchError(f"cannot read the batch summary {path} ({exc.strerror})") from None
    except (KeyError, TypeError, ValueError, csv.Error) as exc:
        raise BatchError(f"{path} is not a batch summary ({exc!r})") from None

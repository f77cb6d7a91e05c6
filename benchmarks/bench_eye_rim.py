"""The eye region pasted where the reference frame shows what the clip usually does (issue 13).

The eye region of a transfer (:mod:`facetransfer.eyes`) is textured from one open-eyed target
frame. Where that frame shows something the clip usually does not show there (most often a
strand of the fringe over the brow's tail or the forehead), pasting it into every frame puts a
patch of hair on the forehead. :func:`facetransfer.region_weights.usual_weights` keeps the current
frame's texture at such vertices (away from the lids).

Truth without a judge: a **self-transfer** (``benchmarks/_self_transfer.py``), the target's own
track as the new performance, must give back the target's frames. Each of the three target
clips of ``bench_transfer_judge.py`` is rewritten twice, with the rule (``usual``, the default)
and without it (``always``: the region pasted wherever the target's expression moved it, as
before). On the pixels where the two results differ, the mean absolute error of each against
the target frame (RGB levels), and each whole frame's PSNR.

The rule only ever shows more of the current frame, which a self-transfer rewards; whether the
target's own expression comes back with it is the judge's question
(``bench_transfer_judge.py``: brows and blinks ~ target).

Usage::

    python benchmarks/bench_eye_rim.py --out out/benchmarks

Writes ``OUT/eye_rim.json``, ``OUT/eye_rim.png`` (error per clip) and ``OUT/eye_rim_CLIP.png``
(target | always | usual at the frame where they differ most).
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import main, patched  # noqa: E402


def _always():
    """The eye region without the usual rules (as before them): every vertex usual, in the
    reference frame and, since the twentieth session, in each frame
    (:func:`facetransfer.region_weights.usual_weights_of`, the name :mod:`facetransfer.eyes`
    calls)."""
    return patched("facetransfer.eyes", "usual_weights_of",
                   lambda frames, track, model, verts, rows, *a, **k:
                   np.ones((len(rows), len(verts)), np.float32))


if __name__ == "__main__":
    sys.exit(main(__doc__, {"always": _always, "usual": contextlib.nullcontext}, "eye_rim",
                  "self-transfer: the pixels the rule changes, against the target frame"))

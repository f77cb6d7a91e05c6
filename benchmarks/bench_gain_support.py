"""The gain of a pasted region held where its compared pixels lie (issue 13).

The eye, jaw and mouth regions of a transfer are textured from other frames and brought to
the current frame's colours by a gain: a plane in the log ratio of the two frames, fitted in
least absolute deviations over a ring of pixels around the region
(:func:`facetransfer.patch.gain_field`). Where the ring lies almost wholly on one side of the
region, a few of its pixels on the other side set the plane's tilt: in ``make demo``'s
smiling, open-mouthed frames the jaw region's ring lies above the chin, and 4 % of its pixels,
on the neck shaded by the target's own opening, darkened the new chin by up to a quarter (a
grey lower face). The plane is now held constant beyond the middle of its samples' columns
and rows (:data:`facetransfer.patch.GAIN_SUPPORT`).

Truth without a judge: a **self-transfer** (``benchmarks/_self_transfer.py``) of the judge's
three target clips, with the plane extrapolated (``extrapolated``, as before) and held
(``held``, the default): the error against the target frame on the pixels where the two
differ, and each frame's PSNR.

Usage::

    python benchmarks/bench_gain_support.py --out out/benchmarks

Writes ``OUT/gain_support.json``, ``OUT/gain_support.png`` (error per clip) and
``OUT/gain_support_CLIP.png`` (target | extrapolated | held at the frame where they differ
most).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import switch_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_main(
        __doc__, "extrapolated", "facetransfer.patch", "GAIN_SUPPORT", 0.0, "held",
        "gain_support", "self-transfer: the pixels the gain's support changes"))

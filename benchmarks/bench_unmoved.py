"""The target's own pixels where the new face did not move (:mod:`facetransfer.unmoved`).

With the per-frame texture (the default) a pixel of the new face is the target frame's
bilinear sample where the target's tracked mesh lifted it; where the new face moved less than a
pixel from there, the sample mixes the frame's neighbouring pixels and softens the finest
detail (pores, lashes, hair over the cheek). The rule keeps the frame's own pixel there
(weight 1 up to :data:`facetransfer.unmoved.D0` pixels, 0 from :data:`facetransfer.unmoved.D1`).

Truth without a judge: a **self-transfer** (``benchmarks/_self_transfer.py``) of the judge's
three target clips without the rule (``resampled``) and with it (``own pixels``): the error
against the target frame on the pixels where the two differ, and each frame's PSNR. A
self-transfer draws the new face where its texture was lifted, so it measures what the rule
does at zero displacement; the real pairs (kept share, sharpness) are in BENCHMARKS.md.

Usage::

    python benchmarks/bench_unmoved.py --out out/benchmarks

Writes ``OUT/unmoved.json``, ``OUT/unmoved.png`` (error per clip) and
``OUT/unmoved_CLIP.png`` (target | resampled | own pixels at the frame where they differ
most).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import switch_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_main(
        __doc__, "resampled", "facetransfer.rewrite", "unmoved_uvs",
        lambda *args, **kwargs: None, "own pixels", "unmoved",
        "self-transfer: the pixels the target's own pixels change"))

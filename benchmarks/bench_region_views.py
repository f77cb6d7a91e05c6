"""The eye and jaw regions' reference frames by view (issue 13): a turned head's regions from
frames seen from its side.

The eye region of a transfer (lids, eyes, brows) is textured from an open-eyed target frame
(:mod:`facetransfer.eyes`), the jaw region (chin, jaw, cheeks) from a closed-mouth one
(:mod:`facetransfer.jaw`). ``make demo``'s target turns up to 32 degrees from those frames
(frames 24-90): there the frontal frame's fringe, which hangs elsewhere when the head turns,
was pasted over the brows as streaks of hair, its skin as bright patches on the forehead and
the cheek. With :mod:`facetransfer.region_views` (the default) a region whose frames turn
beyond :data:`facetransfer.region_views.VIEW_SPLIT` takes a second reference frame from their
side; each frame is rendered with the reference nearest its view, cross-faded over
:data:`facetransfer.region_views.FADE_SECONDS` where it switches.

Truth without a judge: a **self-transfer** (``benchmarks/_self_transfer.py``) of the judge's
three target clips with one reference a region (``one reference``) and by view (``by view``):
the error against the target frame on the pixels where the two differ, and each frame's PSNR.
Whether the target's own expression comes back is the judge's question
(``bench_transfer_judge.py``): the further references are chosen with quiet brows and no
smile, and nothing of the current frame is added.

Usage::

    python benchmarks/bench_region_views.py --out out/benchmarks

Writes ``OUT/region_views.json``, ``OUT/region_views.png`` (error per clip) and
``OUT/region_views_CLIP.png`` (target | one reference | by view at the frame where they differ
most).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import switch_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_main(
        __doc__, "one reference", "facetransfer.region_views", "MAX_VIEWS", 1, "by view",
        "region_views", "self-transfer: the pixels the references by view change"))

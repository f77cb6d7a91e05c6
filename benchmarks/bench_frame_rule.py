"""The eye region's frame rule: a strand of the fringe in the current frame only (issue 13).

The eye region of a transfer is textured from one open-eyed target frame (the reference,
:mod:`facetransfer.eyes`). Away from the lids, a vertex already keeps the current frame where
the reference frame shows what the clip usually does not (its own strand of the fringe:
:func:`facetransfer.region_weights.usual_weights`). In ``make demo``'s turned frames (35, 60,
71) it is the current frame whose fringe lies over a brow's tail, and the reference frame's
skin and strands were painted over it: a mottled patch with a hard edge in the hair. With
:data:`facetransfer.eyes.FRAME_RULE` (the default) every vertex of the region away from the
lids also keeps, per frame, the current frame where that frame's colour differs from the
reference frame's (:func:`facetransfer.region_weights.usual_weights_of` against it); within
:data:`facetransfer.eyes.BROW_KEEP` of the brows only where the target's expression did not
move the vertex from where the reference frame has it.

Truth without a judge: a **self-transfer** (``benchmarks/_self_transfer.py``) of the judge's
three target clips without the rule (``reference``) and with it (``frame rule``): the error
against the target frame on the pixels where the two differ, and each frame's PSNR. The rule
only ever shows more of the current frame, which a self-transfer rewards; whether the target's
own brows come back with it is the judge's question (``bench_transfer_judge.py``).

Usage::

    python benchmarks/bench_frame_rule.py --out out/benchmarks

Writes ``OUT/frame_rule.json``, ``OUT/frame_rule.png`` (error per clip) and
``OUT/frame_rule_CLIP.png`` (target | reference | frame rule at the frame where they differ
most).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import switch_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_main(
        __doc__, "reference", "facetransfer.eyes", "FRAME_RULE", False, "frame rule",
        "frame_rule", "self-transfer: the pixels the frame rule changes"))

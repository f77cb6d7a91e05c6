"""The jaw region's appearance rule on a self-transfer (issue 13).

:data:`facetransfer.jaw.JAW_LOOK` (:mod:`facetransfer.jaw_look`) has the jaw region also take
the closed-mouth reference frame near the mouth where the current frame's hue departs from
the reference frame's. Truth without a judge: a **self-transfer**
(``benchmarks/_self_transfer.py``) of the judge's three target clips without the rule
(``geometry``) and with it (``appearance``): the error against the target frame on the pixels
where the two differ, and each frame's PSNR. The rule shows more of the reference frame, which
a self-transfer can only lose on; it must not lose more than noise.

Usage::

    python benchmarks/bench_jaw_look_self.py --out out/benchmarks

Writes ``OUT/jaw_look_self.json``, ``OUT/jaw_look_self.png`` and
``OUT/jaw_look_self_CLIP.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from _self_transfer import switch_main  # noqa: E402

if __name__ == "__main__":
    sys.exit(switch_main(
        __doc__, "geometry", "facetransfer.jaw", "JAW_LOOK", None, "appearance",
        "jaw_look_self", "self-transfer: the pixels the jaw's appearance rule changes"))

"""What the caches' keys cost a command's start: the track cache's code fingerprint, the default
model's build recipe, the check of a mapped model file before an output (medians of fresh
processes; BENCHMARKS.md, "Fifty-fourth session (helper cache54)").

``python benchmarks/bench_cache_keys.py --out out/benchmarks [--runs 15] [--src SRC]
[--model-cache DIR]``: ``--src`` times another tree's package (``SRC/facetransfer``, e.g. an
older checkout's ``src``) by the same measures, where it has them. The user cache is a folder
of the script's own under ``--out`` (the memo of parsed files warmed by a first, unreported
run), but for the default model's measures, which need a built default model: the user's
cache, or ``--model-cache`` (an ``XDG_CACHE_HOME``). A default model there that this version
did not build is rebuilt by the first, unreported run (minutes).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import arguments, save_json  # noqa: E402

#: Each measure: the code a fresh process runs, printing the milliseconds. cv2, NumPy, numba,
#: the assets and the model module are imported first, as in every command that tracks.
MEASURES = {
    "track fingerprint": (
        "import time, cv2, numpy, numba, facetransfer.assets, facetransfer.model\n"
        "from facetransfer.track import cache\n"
        "t = time.perf_counter(); cache.code_fingerprint()\n"
        "print(1000 * (time.perf_counter() - t))"),
    "default model recipe": (
        "import time, facetransfer.assets, facetransfer.model\n"
        "from facetransfer import default_model as dm\n"
        "t = time.perf_counter(); dm.build_recipe()\n"
        "print(1000 * (time.perf_counter() - t))"),
    "default model load": (
        "import time, facetransfer.assets, facetransfer.model\n"
        "from facetransfer import default_model as dm\n"
        "t = time.perf_counter(); dm.load_default_model()\n"
        "print(1000 * (time.perf_counter() - t))"),
}


def _times(code: str, src: Path, cache: Path | None, runs: int) -> list[float] | None:
    """Milliseconds of ``code`` in ``runs`` fresh processes on the package in ``src`` (after one
    unreported run); None where that package has not what ``code`` measures."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    if cache is not None:
        env["XDG_CACHE_HOME"] = str(cache)
    out = []
    for _ in range(runs + 1):
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env=env)
        if run.returncode != 0:
            return None
        out.append(float(run.stdout.split()[-1]))
    return out[1:]


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--src", default=str(Path(__file__).resolve().parents[1] / "src"))
    ap.add_argument("--model-cache", help="XDG_CACHE_HOME of the default model's measures")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = {"src": args.src, "runs": args.runs, "measures": {}}
    for name, code in MEASURES.items():
        cache = out / "cache_keys_cache"
        if name.startswith("default model"):
            cache = args.model_cache and Path(args.model_cache)
        ms = _times(code, Path(args.src), cache, args.runs)
        if ms is None:
            print(f"{name}: not in {args.src}")
            continue
        report["measures"][name] = {"median_ms": statistics.median(ms), "min_ms": min(ms),
                                    "ms": ms}
        print(f"{name}: median {statistics.median(ms):.1f} ms, min {min(ms):.1f} ms")
    save_json(report, out / f"cache_keys_{Path(args.src).parent.name}.json")


if __name__ == "__main__":
    main()

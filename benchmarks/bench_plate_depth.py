"""A 16-bit plate through ``facetransfer transfer`` (facetransfer.io.plate_depth).

The first three seconds of ``driving_d6`` (the expressions of ``WDA_KatieHill_000``) as a
16-bit plate, as a scan or a grade leaves one: each frame's levels times 257 plus a smooth
detail below 8 bits of its own (a blurred noise field, -128..128), written as 16-bit TIFF and
PNG sequences; each rewritten as a sequence of its own kind in a fresh process. Judged against
the plate: the share of all pixels whose 16-bit value is the plate's to the bit, the largest
difference (16-bit levels) outside the rewritten face (the pixels whose 8-bit value the
rewrite left as shown), and the result's bit depth; with the command's seconds. Run against an
older tree (``PYTHONPATH=OLD/src``) to see what was written before.

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_plate_depth.py --out out/benchmarks

Writes ``OUT/plate_depth.json`` and ``OUT/plate_depth.png``.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _report import (clip_start, facetransfer_exe, out_and_data, save_json,  # noqa: E402
                     save_plot)

SECONDS = 3


def make_plates(data: Path, folder: Path) -> tuple[dict, list]:
    """16-bit TIFF and PNG plates of the clip's frames (module notes)."""
    import cv2

    _, frames = clip_start(data / "video" / "driving_d6.mp4", SECONDS, folder)
    rng = np.random.default_rng(0)
    plates, paths = [], {}
    for rgb in frames:
        fine = cv2.GaussianBlur(rng.normal(0, 1, rgb.shape).astype(np.float32), (0, 0), 4)
        fine = np.clip(np.rint(fine / (np.abs(fine).max() + 1e-9) * 128), -128, 128)
        plates.append(np.clip(rgb.astype(np.int64) * 257 + fine.astype(np.int64), 0, 65535)
                      .astype(np.uint16))
    for suffix in (".tif", ".png"):
        d = folder / f"plate{suffix}"
        d.mkdir()
        for i, p in enumerate(plates):
            assert cv2.imwrite(str(d / f"p.{1001 + i:04d}{suffix}"), p[..., ::-1])
        paths[suffix] = d / f"p.%04d{suffix}"
    return paths, plates


def judge(out: Path, plates: list, first: int = 1001) -> dict:
    import cv2

    same = total = 0
    worst = 0
    depth = None
    for i, plate in enumerate(plates):
        got = cv2.imread(str(out).replace("%04d", f"{first + i:04d}"), cv2.IMREAD_UNCHANGED)
        depth = 16 if got.dtype == np.uint16 else 8
        g = got[..., ::-1].astype(np.int64) * (1 if depth == 16 else 257)
        p = plate.astype(np.int64)
        shown = (p * 2 + 257) // 514
        kept = ((g * 2 + 257) // 514 == shown).all(axis=2)   # the rewrite left it as shown
        same += int((g == p).all(axis=2).sum())
        total += kept.size
        worst = max(worst, int(np.abs(g - p)[kept].max()))
    return {"bits": depth, "pixels_exact_share": round(same / total, 4),
            "largest_difference_outside_face": worst}


def plot(rows: list[dict], path: Path) -> None:
    """Each plate's share of pixels equal to the plate's to the bit and the largest difference
    outside the face, with the bits written."""
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(6.4, 2.8))
    names = [f"{r['plate']}\n({r.get('bits', '?')} bits written)" for r in rows]
    a.bar_label(a.bar(names, [100 * r.get("pixels_exact_share", 0.0) for r in rows]),
                fmt="%.1f", fontsize=7)
    a.set_ylabel("pixels equal to the plate's, %")
    worst = [r.get("largest_difference_outside_face", 0) for r in rows]
    b.bar_label(b.bar(names, worst), fontsize=7)
    b.set_ylim(0, max(1, *worst) * 1.2)
    b.set_ylabel("largest difference outside\nthe face, 16-bit levels")
    for ax in (a, b):
        ax.tick_params(axis="x", labelsize=7)
    fig.suptitle("a 16-bit plate through transfer", fontsize=9)
    save_plot(fig, path)


def main() -> int:
    out, data = out_and_data(__doc__)
    source = data / "video" / "WDA_KatieHill_000.mp4"
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths, plates = make_plates(data, folder)
        for suffix, plate in paths.items():
            res = folder / f"out{suffix}" / f"r.%04d{suffix}"
            res.parent.mkdir()
            t = time.perf_counter()
            run = subprocess.run([facetransfer_exe(), "transfer", "--target", str(plate),
                                  "--expression-from", str(source), "--out", str(res),
                                  "--no-progress", "--sequence-fps", "30"],
                                 capture_output=True, text=True)
            row = {"plate": f"16-bit {suffix[1:].upper()}", "status": run.returncode,
                   "seconds": round(time.perf_counter() - t, 2)}
            if run.returncode == 0:
                row |= judge(res, plates)
            rows.append(row)
            print(row, flush=True)
    ok = all(r["status"] == 0 and r.get("bits") == 16 and
             r.get("largest_difference_outside_face") == 0 for r in rows)
    save_json({"benchmark": "a 16-bit plate through transfer", "seconds_of_clip": SECONDS,
               "rows": rows, "all_ok": ok}, out / "plate_depth.json")
    plot(rows, out / "plate_depth.png")
    print(f"all ok: {ok}; wrote {out / 'plate_depth.json'} and {out / 'plate_depth.png'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

"""The jaw region's appearance rule: a tongue under the new lip (issue 13).

The jaw region of a transfer (chin, jaw, cheeks: :mod:`facetransfer.jaw`) is textured from a
closed-mouth target frame only where the target's own tracked expression moved the skin. What
the model does not explain (a tongue stuck out over the lower lip, the teeth, the mouth's dark
gap) barely moves the tracked geometry, so the region kept the frame's own texture there: on
the judge's ``open`` pair (``WDA_KatieHill_000`` -> ``driving_d6``), where the target sticks
out its tongue (frames ~75-95), a red-orange glow on the chin just under the new lower lip.
With :data:`facetransfer.jaw.JAW_LOOK` (the default) a vertex of the region also takes the
reference frame where the current frame's colour departs from the reference frame's in a way
lighting does not explain (:mod:`facetransfer.jaw_look`).

The open pair's first 120 frames (the judge's cached tracks in ``OUT/judge_pairs/``) are
rendered with the rule off (``geometry``) and on (``appearance``). MediaPipe Face Landmarker
finds the result's lower lip in each frame; the **band** is its outer contour (corner to
corner) moved down by :data:`BAND` of the outer eye corners' distance: the chin just under the
new lip. Its median CIELAB colour is compared (CIE76 ΔE) with the target's skin in the same
band of the jaw region's reference frame (MediaPipe on that target frame); so is the
:data:`TAIL`-th percentile of the band's pixels' ΔE (a stripe over a tenth of the band, which
the median does not see: the target's lower lip pressed out dark red under the new lip's
corner, frame 79, which the paste's rejection gave back).

Usage::

    python benchmarks/bench_jaw_appearance.py --out out/benchmarks [--frames 120]

Writes ``OUT/jaw_appearance.json``, ``OUT/jaw_appearance.png`` (ΔE per frame) and
``OUT/jaw_appearance_sheet.png`` (mouth and chin of frames 0, 40, 79, 100, 119: target |
geometry | appearance).
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from _report import arguments, save_json, save_plot, save_sheet  # noqa: E402
from _self_transfer import patched  # noqa: E402
from bench_transfer_judge import PAIRS, _track  # noqa: E402

#: MediaPipe's lower-lip outer contour, corner to corner.
LOWER_OUTER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291)
#: The band under the lower lip: from and to this fraction of the outer eye corners' distance
#: below the contour.
BAND = (0.03, 0.12)
SHEET = (0, 40, 79, 100, 119)
#: The percentile of the band's pixels' ΔE reported beside its median's (:func:`tail_de`).
TAIL = 95
VARIANTS = ("geometry", "appearance")


def band_mask(xy: np.ndarray, shape) -> np.ndarray:
    """``(H, W) bool``: the lower-lip outer contour of MediaPipe's points ``xy`` (478, 2)
    pixels moved down by :data:`BAND` of the eye corners' distance (the polygon between)."""
    import cv2

    eye = float(np.linalg.norm(xy[33] - xy[263]))
    c = xy[list(LOWER_OUTER)]
    poly = np.concatenate([c + (0, BAND[0] * eye), (c + (0, BAND[1] * eye))[::-1]])
    m = np.zeros(shape, np.uint8)
    cv2.fillPoly(m, [np.rint(poly).astype(np.int32)], 1)
    return m > 0


def band_lab(frames, fps: float) -> tuple[np.ndarray, np.ndarray, list]:
    """Per frame the band's median CIELAB (F, 3) (NaN where no face or under 20 pixels), the
    mouth-and-chin crop box (F, 4) ``x0, y0, x1, y1`` and the band's pixels' CIELAB (a list
    of (n_i, 3), empty where no median)."""
    from _mp_points import faces_in_pixels, frame_lab

    lab = np.full((len(frames), 3), np.nan)
    boxes = np.zeros((len(frames), 4), np.int64)
    pixels = [np.zeros((0, 3))] * len(frames)
    for i, f, xy in faces_in_pixels(frames, fps):
        m = band_mask(xy, f.shape[:2])
        if m.sum() >= 20:
            pixels[i] = frame_lab(f)[m]
            lab[i] = np.median(pixels[i], axis=0)
        eye = float(np.linalg.norm(xy[33] - xy[263]))
        cx, cy = xy[[61, 291, 17]].mean(0)
        boxes[i] = (int(cx - 0.8 * eye), int(cy - 0.5 * eye), int(cx + 0.8 * eye),
                    int(cy + 0.7 * eye))
    return lab, boxes, pixels


def tail_de(pixels: list, skin: np.ndarray, q: float = TAIL) -> np.ndarray:
    """Per frame the ``q``-th percentile (F,) of the band's pixels' CIE76 ΔE from ``skin`` (3,)
    (NaN where the band has none): a stripe over a tenth of the band, which its median does
    not see."""
    return np.array([np.percentile(np.linalg.norm(p - skin, axis=1), q) if len(p) else np.nan
                     for p in pixels])


def render(plan, model, variant: str) -> list:
    """The plan's frames rendered with the rule off (``geometry``) or on (``appearance``);
    the region textures made afresh under the variant."""
    import contextlib

    from facetransfer import video_transfer as vt

    imgs: list = []
    ctx = patched("facetransfer.jaw", "JAW_LOOK", None) if variant == "geometry" \
        else contextlib.nullcontext()
    with ctx, tempfile.TemporaryDirectory() as tmp:
        vt.render_plan(dataclasses.replace(plan, regions=None), model,
                       vt.RenderTarget(Path(tmp) / "r.mp4", overwrite=True),
                       compose=lambda i, r: imgs.append(r.image) or r.image)
    return imgs


def _stats(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    return {"median": float(np.median(x)), "p90": float(np.percentile(x, 90)),
            "max": float(x.max()), "frames": int(x.size)}


def run(out: Path, data: Path, n: int) -> tuple[dict, dict]:
    """Render and judge the open pair; ``(figures, panels)``."""
    from facetransfer import transfer_plan as tp
    from facetransfer.default_model import load_default_model
    from facetransfer.jaw import closed_jaw_frame
    from facetransfer.track.presets import DEFAULT_SPEED, DETECT_EVERY

    model = load_default_model()
    every = DETECT_EVERY[DEFAULT_SPEED]
    src, tgt = PAIRS["open"]
    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    plan = tp.plan_transfer(data / f"{tgt}.mp4", model, expression_from=data / f"{src}.mp4",
                            max_frames=n, target_track=_track(tgt, model, cache, data, every),
                            expression_track=_track(src, model, cache, data, every, True))
    n = plan.n_frames
    ref = closed_jaw_frame(plan.target_track, n)
    panels = {"target": [plan.target_frames[i] for i in range(n)]}
    for v in VARIANTS:
        panels[v] = render(plan, model, v)
    labs = {k: band_lab(p, plan.fps) for k, p in panels.items()}
    skin = labs["target"][0][ref]
    de = {k: np.linalg.norm(labs[k][0] - skin, axis=1) for k in panels}
    tail = {k: tail_de(labs[k][2], skin) for k in panels}
    res = {"pair": "open", "source": src, "target": tgt, "frames": n, "reference": ref,
           "reference_lab": skin.round(2).tolist(),
           "de_band": {k: _stats(v) for k, v in de.items()},
           "de_band_frames": {k: np.round(v, 2).tolist() for k, v in de.items()},
           "de_band_sheet": {k: {int(i): float(round(v[i], 2)) for i in SHEET if i < n}
                             for k, v in de.items()},
           f"de_band_p{TAIL}": {k: _stats(v) for k, v in tail.items()},
           f"de_band_p{TAIL}_frames": {k: np.round(v, 2).tolist() for k, v in tail.items()},
           f"de_band_p{TAIL}_sheet": {k: {int(i): float(round(v[i], 2)) for i in SHEET
                                          if i < n} for k, v in tail.items()}}
    return res, {"panels": panels, "boxes": labs["target"][1]}


def sheet(panels: dict, boxes: np.ndarray, path: Path) -> None:
    """Mouth and chin of the :data:`SHEET` frames: target | geometry | appearance."""
    import cv2

    rows, labels = [], []
    for i in SHEET:
        if i >= len(panels["target"]):
            continue
        x0, y0, x1, y1 = np.maximum(boxes[i], 0)
        tiles = [cv2.resize(np.asarray(panels[k][i])[y0:y1, x0:x1], (300, 225),
                            interpolation=cv2.INTER_CUBIC) for k in ("target", *VARIANTS)]
        rows.append(np.concatenate(tiles, axis=1))
        labels.append(f"open {i}: target | before (geometry) | after (appearance)")
    save_sheet(rows, labels, path)


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.8))
    for k, c in zip(("target", *VARIANTS), ("#999999", "#fc9272", "#3182bd")):
        ax.plot(res["de_band_frames"][k], color=c,
                label=f"{k} (median {res['de_band'][k]['median']:.1f})")
    ax.set_xlabel(f"frame of {res['target']}")
    ax.set_ylabel("CIE76 ΔE, band under the lower lip")
    ax.set_title(f"the chin under the new lip against the target's skin (frame {res['reference']})")
    ax.legend(fontsize=8)
    save_plot(fig, path)


def main() -> int:
    ap = arguments(__doc__)
    ap.add_argument("--frames", type=int, default=120)
    args = ap.parse_args()
    from facetransfer.assets import data_dir

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res, pics = run(out, Path(data_dir()) / "video", args.frames)
    sheet(pics["panels"], pics["boxes"], out / "jaw_appearance_sheet.png")
    save_json(res, out / "jaw_appearance.json")
    plot(res, out / "jaw_appearance.png")
    print("; ".join(f"{k}: ΔE median {v['median']:.2f}, p90 {v['p90']:.2f}, max {v['max']:.2f}"
                    for k, v in res["de_band"].items()))
    print("sheet frames:", res["de_band_sheet"])
    print(f"band pixels' p{TAIL} ΔE: " + "; ".join(
        f"{k}: median {v['median']:.2f}, p90 {v['p90']:.2f}, max {v['max']:.2f}"
        for k, v in res[f"de_band_p{TAIL}"].items()))
    print("sheet frames:", res[f"de_band_p{TAIL}_sheet"])
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The lips' colour of a transfer, judged by an independent detector (issue 13: identity).

The result's lips should carry the source's movement in the target's colour (a target's
lipstick is not an expression). On the three real pairs of ``bench_transfer_judge.py`` and a
fourth, ``pale`` (``face_2`` -> ``driving_d6``; 120 target frames each, the same cached tracks
in ``OUT/judge_pairs/``) the default transfer is rendered twice, ``--lip-colour source`` (the
source's lips against its skin, as §6 pastes them) and ``--lip-colour target``
(:mod:`facetransfer.lip_colour`). MediaPipe Face Landmarker finds the lips in the source (the
frame matched by time), the target and both results: the pixels between its outer and inner
lip contours, eroded by one pixel, and apart the upper and the lower lip (the contours split
at the mouth's corners). Their median colour in CIELAB (OpenCV's conversion of the 8-bit RGB
frame scaled to 0..1, L 0..100) is compared frame by frame:

- ``de_target``: CIE76 ΔE between the result's lips and the target's in the same frame
  (``de_target_upper``, ``de_target_lower``: each lip's);
- ``de_source``: between the result's lips and the source's;
- the floor: the target's lips in a frame against their median over the clip (the target's own
  variation: expression, light, the detector's contour);
- ``pressed``: in the frames where the source's lips are pressed shut (:data:`PRESSED_GAP`),
  ``de_target`` and ``de_ab`` (the a*, b* distance alone: a lipstick's red left, not the
  lips' shading), and ``de_ab_other`` in the other frames;
- ``counts``: cyan pixels (G and B both over R by more than 20 levels) on the lips and around
  them (the outer contour grown by :data:`AROUND` pixels, the opening left out), and whitish
  ones around them (chroma < 12, L > 55): what a tint too strong for a lipstick made.

Usage::

    python benchmarks/bench_lip_colour.py --out out/benchmarks [--pairs demo,fps,open,pale]
        [--modes source,target]

Writes ``OUT/lip_colour.json``, ``OUT/lip_colour.png`` (ΔE per pair) and
``OUT/lip_colour_PAIR.png`` (source | target | source colour | target colour, lips enlarged).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from bench_transfer_judge import PAIRS, _track, add_pair_options  # noqa: E402

#: MediaPipe face mesh's outer and inner lip contours, in order around the mouth.
OUTER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40,
         185)
INNER = (78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 415, 310, 311, 312, 13, 82, 81, 80,
         191)
MODES = ("source", "target")
#: The judge's pairs and a pale source onto pale lips.
LIP_PAIRS = {**PAIRS, "pale": ("face_2", "driving_d6")}


#: The upper and lower lip: the outer contour's half from corner to corner (61 -> 291) and the
#: inner contour's half back (308 -> 78).
UPPER = (61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291, 308, 415, 310, 311, 312, 13, 82, 81,
         80, 191, 78)
LOWER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 308, 324, 318, 402, 317, 14, 87,
         178, 88, 95, 78)
#: The ring around the lips where whitish and cyan pixels are counted: the outer contour grown
#: by this many pixels (a square), the mouth's opening left out.
AROUND = 13
PARTS = ("lips", "upper", "lower")
#: The source's lips are pressed shut where MediaPipe's inner-lip gap (points 13-14) is under
#: this fraction of its outer eye corners' distance (33-263): ``WDA_KatieHill_000``'s pressed
#: lips read 0.005-0.01 (BENCHMARKS.md, "the lips the model cannot fit").
PRESSED_GAP = 0.012


def _fill(shape, xy: np.ndarray, idx) -> np.ndarray:
    import cv2

    m = np.zeros(shape, np.uint8)
    cv2.fillPoly(m, [np.rint(xy[list(idx)]).astype(np.int32)], 1)
    return m


def lip_masks(xy: np.ndarray, shape) -> dict:
    """The lips' masks of a frame from MediaPipe's points ``xy`` (478, 2) pixels: ``lips``,
    ``upper``, ``lower`` (between the outer and inner contours, eroded by one pixel) and
    ``around`` (the outer contour dilated by :data:`AROUND` pixels, without the opening)."""
    import cv2

    k = np.ones((3, 3), np.uint8)
    inner = _fill(shape, xy, INNER)
    out = {"lips": cv2.erode(_fill(shape, xy, OUTER) * (1 - inner), k) > 0}
    out["upper"] = cv2.erode(_fill(shape, xy, UPPER), k) > 0
    out["lower"] = cv2.erode(_fill(shape, xy, LOWER), k) > 0
    around = cv2.dilate(_fill(shape, xy, OUTER), np.ones((AROUND, AROUND), np.uint8))
    out["around"] = (around * (1 - inner)) > 0
    return out


def cyan_whitish(img: np.ndarray, lab: np.ndarray, m: dict) -> tuple[int, int, int]:
    """``(cyan on the lips, cyan around them, whitish around them)``: cyan where G and B both
    exceed R by more than 20 levels; whitish where CIELAB chroma < 12 and L > 55."""
    p = np.asarray(img, np.int32)
    cy = (p[..., 1] - p[..., 0] > 20) & (p[..., 2] - p[..., 0] > 20)
    wh = (np.hypot(lab[..., 1], lab[..., 2]) < 12) & (lab[..., 0] > 55)
    return (int(cy[m["lips"]].sum()), int(cy[m["around"]].sum()),
            int(wh[m["around"]].sum()))


def lip_lab(frames, fps: float) -> dict:
    """The lips judged in each frame: ``lips``, ``upper``, ``lower`` (F, 3), the median CIELAB
    colour of each part (NaN where MediaPipe finds no face or fewer than 20 pixels of it);
    ``boxes`` (F, 4) the lips' box ``x0, y0, x1, y1``; ``counts`` (F, 3) of
    :func:`cyan_whitish`; ``gap`` (F,) the inner-lip gap over the eye corners' distance
    (:func:`_mp_points.measure`; NaN without a face)."""
    from _mp_points import MOUTH_OPEN, faces_in_pixels, frame_lab, measure

    n = len(frames)
    res = {k: np.full((n, 3), np.nan) for k in PARTS}
    res["boxes"] = np.zeros((n, 4), np.int64)
    res["counts"] = np.zeros((n, 3), np.int64)
    res["gap"] = np.full(n, np.nan)
    for i, f, xy in faces_in_pixels(frames, fps):
        m = lip_masks(xy, f.shape[:2])
        L = frame_lab(f)
        for k in PARTS:
            if m[k].sum() >= 20:
                res[k][i] = np.median(L[m[k]], axis=0)
        res["counts"][i] = cyan_whitish(f, L, m)
        res["gap"][i] = measure(xy[None], MOUTH_OPEN)[0]
        o = xy[list(OUTER)]
        res["boxes"][i] = (*np.floor(o.min(0)).astype(int), *np.ceil(o.max(0)).astype(int))
    return res


def delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """CIE76 ΔE per row (NaN where either is)."""
    return np.linalg.norm(a - b, axis=-1)


def _stats(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    return {"median": float(np.median(x)), "p90": float(np.percentile(x, 90)),
            "frames": int(x.size)} if x.size else {"median": None, "p90": None, "frames": 0}


def run_pair(name: str, model, out: Path, data: Path, frames: int, modes=MODES
             ) -> tuple[dict, dict]:
    """Render one pair in ``modes`` and judge the lips; ``(figures, panels for the picture)``."""
    from facetransfer import transfer_plan as tp
    from facetransfer import video_transfer as vt
    from facetransfer.rewrite_options import RewriteOptions

    src, tgt = LIP_PAIRS[name]
    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    plan = tp.plan_transfer(data / f"{tgt}.mp4", model, expression_from=data / f"{src}.mp4",
                            max_frames=frames, target_track=_track(tgt, model, cache, data),
                            expression_track=_track(src, model, cache, data))
    n = plan.n_frames
    panels = {"source": [plan.mouth_frames[plan.mouth_index[i]] for i in range(n)],
              "target": [plan.target_frames[i] for i in range(n)]}
    for mode in modes:
        imgs: list[np.ndarray] = []
        with tempfile.TemporaryDirectory() as tmp:
            vt.render_plan(plan, model, vt.RenderTarget(Path(tmp) / "r.mp4", overwrite=True),
                           options=RewriteOptions(lip_colour=mode),
                           compose=lambda i, r: imgs.append(r.image) or r.image)
        panels[f"result_{mode}"] = imgs
    lab = {k: lip_lab(v, plan.fps) for k, v in panels.items()}
    T, S = lab["target"]["lips"], lab["source"]["lips"]
    res = {"source": src, "target": tgt, "frames": n,
           "floor": _stats(delta_e(T, np.nanmedian(T, axis=0))),
           "source_vs_target": _stats(delta_e(S, T)),
           "lab": {k: np.nanmedian(v["lips"], axis=0).round(2).tolist() for k, v in lab.items()},
           "target_counts": lab["target"]["counts"].sum(0).tolist()}
    gap = lab["source"]["gap"]
    pressed, other = gap < PRESSED_GAP, gap >= PRESSED_GAP
    res["pressed_frames"] = np.flatnonzero(pressed).tolist()
    for mode in modes:
        R = lab[f"result_{mode}"]
        de_ab = delta_e(R["lips"][:, 1:], T[:, 1:])
        res[f"lip_colour_{mode}"] = {
            "pressed": {"de_target": _stats(delta_e(R["lips"], T)[pressed]),
                        "de_ab": _stats(de_ab[pressed]), "de_ab_other": _stats(de_ab[other]),
                        "lab": np.nanmedian(R["lips"][pressed], axis=0).round(2).tolist()
                        if pressed.any() else None},
            "de_target": _stats(delta_e(R["lips"], T)), "de_source": _stats(delta_e(R["lips"], S)),
            **{f"de_target_{k}": _stats(delta_e(R[k], lab["target"][k]))
               for k in ("upper", "lower")},
            "lab": {k: np.nanmedian(R[k], axis=0).round(2).tolist() for k in PARTS},
            "counts": dict(zip(("cyan_lips", "cyan_around", "whitish_around"),
                               R["counts"].sum(0).tolist()))}
    res["lab_target"] = {k: np.nanmedian(lab["target"][k], axis=0).round(2).tolist()
                         for k in PARTS}
    return res, {"panels": panels, "boxes": lab["target"]["boxes"]}


def picture(name: str, panels: dict, boxes: np.ndarray, path: Path) -> None:
    """Four frames: source | target | source colour | target colour, around the target's
    lips (the same box in every panel but the source's, which has its own size)."""
    import cv2

    from _report import save_sheet

    n = len(panels["target"])
    rows, labels = [], []
    for i in np.linspace(0, n - 1, 4).round().astype(int):
        x0, y0, x1, y1 = boxes[i]
        if x1 <= x0:
            continue
        w, h = x1 - x0, y1 - y0
        H, W = panels["source"][i].shape[:2]
        tiles = [panels["source"][i][H // 2:, W // 4: 3 * W // 4]]  # its own lower face
        tiles += [panels[k][i][max(y0 - h, 0): y1 + h, max(x0 - w // 2, 0): x1 + w // 2]
                  for k in ("target", "result_source", "result_target") if k in panels]
        tiles = [cv2.resize(np.asarray(t), (240, 180), interpolation=cv2.INTER_CUBIC)
                 for t in tiles]
        rows.append(np.concatenate(tiles, axis=1))
        labels.append(f"{name} {i}: source | target | --lip-colour source | target")
    save_sheet(rows, labels, path)


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    pairs = list(res)
    x = np.arange(len(pairs))
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for j, (key, label, c) in enumerate(
            ((("lip_colour_source", "de_target"), "--lip-colour source: result ~ target",
              "#fcbba1"),
             (("lip_colour_target", "de_target"), "--lip-colour target: result ~ target",
              "#a50f15"),
             (("lip_colour_source", "de_source"), "--lip-colour source: result ~ source",
              "#9ecae1"),
             (("lip_colour_target", "de_source"), "--lip-colour target: result ~ source",
              "#08519c"))):
        if all(key[0] in res[p] for p in pairs):
            ax.bar(x - 0.3 + 0.2 * j, [res[p][key[0]][key[1]]["median"] for p in pairs], 0.2,
                   color=c, label=label)
    ax.scatter(x, [res[p]["floor"]["median"] for p in pairs], marker="_", s=600, color="k",
               label="floor: the target's lips against their clip median", zorder=3)
    ax.set_xticks(x, [f"{p}\n{res[p]['source']} -> {res[p]['target']}" for p in pairs],
                  fontsize=8)
    ax.set_ylabel("median CIE76 ΔE of the lips")
    ax.legend(fontsize=7)
    ax.set_title("the lips' colour judged by MediaPipe's lip contours")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _line(name: str, r: dict) -> str:
    """One pair's figures for people."""
    def med(d: dict) -> str:
        return f"{d['median']:.2f} (p90 {d['p90']:.1f})" if d["median"] is not None else "–"

    parts = [f"{name}: floor {r['floor']['median']:.1f}; source~target "
             f"{r['source_vs_target']['median']:.1f}"]
    for m in MODES:
        if f"lip_colour_{m}" in r:
            q = r[f"lip_colour_{m}"]
            c = q["counts"]
            p = q["pressed"]
            parts.append(f"--lip-colour {m}: ~target {med(q['de_target'])}, upper "
                         f"{med(q['de_target_upper'])}, lower {med(q['de_target_lower'])}, "
                         f"~source {q['de_source']['median']:.2f}; cyan {c['cyan_lips']} / "
                         f"{c['cyan_around']}, whitish {c['whitish_around']}; pressed "
                         f"({p['de_ab']['frames']} frames) ~target {med(p['de_target'])}, "
                         f"a*b* {med(p['de_ab'])} (other frames {med(p['de_ab_other'])})")
    return "; ".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    add_pair_options(ap)
    ap.set_defaults(pairs=",".join(LIP_PAIRS))
    ap.add_argument("--modes", default=",".join(MODES), help="of source, target")
    args = ap.parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(data_dir()) / "video"
    model = load_default_model()
    res = {}
    for name in args.pairs.split(","):
        res[name], pics = run_pair(name, model, out, data, args.frames,
                                   tuple(args.modes.split(",")))
        picture(name, pics["panels"], pics["boxes"], out / f"lip_colour_{name}.png")
        print(_line(name, res[name]), flush=True)
    with atomic_path(out / "lip_colour.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps({"pairs": res}, indent=2))
    plot(res, out / "lip_colour.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The target's own pixels where the new face did not move (:mod:`facetransfer.unmoved`).

With the per-frame texture (the default) a pixel of the new face is the target frame's
bilinear sample where the target's tracked mesh lifted it; where the new face lies a fraction
of a pixel from there, the sample mixes the frame's neighbouring pixels and softens the finest
detail (pores, lashes, hair over the face). The rule looks the frame up where the new face
draws it instead (weight 1 up to :data:`facetransfer.unmoved.D0` pixels, 0 from
:data:`facetransfer.unmoved.D1`).

Real pairs (``--pairs``, default the judge's ``demo`` and ``fps``: ``bench_transfer_judge.py``,
its cached tracks in ``OUT/judge_pairs/``), 120 frames, each rendered without the rule
(``resampled``), with ``d0, d1 = 0.25, 1 px`` and with the default: the share of the face's
pixels kept wholly (every corner of their triangle within ``d0``) and in part, and, against the
target frame on the face texture's own pixels (the face eroded by 6 px, outside the eye, jaw
and mouth regions and their rims, which are painted over it), the PSNR and the sharpness (the
variance of the Laplacian, the result's over the target's, per frame), and how far the result's
change from the frame before departs from the target's there (mean absolute levels, per frame:
a pixel that pops in and out of the kept set would raise it). ``--judge``: Face
Landmarker on source, target and each result (``bench_transfer_judge.compare``).

``--self``: a **self-transfer** (``benchmarks/_self_transfer.py``) of the judge's three target
clips without and with the rule. It draws the new face where its texture was lifted, where the
lookup already is the frame's own pixel: it shows that the rule changes nothing there.

Usage::

    python benchmarks/bench_unmoved.py --out out/benchmarks [--pairs demo,fps] [--judge] [--self]

Writes ``OUT/unmoved.json`` and ``OUT/unmoved_PAIR.png`` (target | resampled | default, 3x,
on the forehead's hair, frames 10, 40 and 84); with ``--self`` ``OUT/unmoved_self.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import bench_transfer_judge as bj  # noqa: E402

#: Label bits of ``facetransfer.rewrite``'s shading painted over the face texture (eyes, jaw,
#: mouth, the eye region's rim, the jaw region and its ring, the mouth's ring).
PAINTED = 2 | 4 | 8 | 16 | 32 | 64 | 128
FRAMES = 120


@contextlib.contextmanager
def _variant(d, capture: list):
    """The rewrite with ``unmoved_uvs`` at ``d = (d0, d1)`` (None: switched off), each crop's
    ``(frame, box, labels, weight map)`` appended to ``capture`` (frames rendered in turn)."""
    import facetransfer.rewrite as rw
    import facetransfer.rewrite_clip as rc
    from facetransfer import unmoved

    saved = rc._ClipRenderer.part, rc.rewrite_frame_part, rw.shade_layers, rw.unmoved_uvs, \
        rw._shade_frame
    part, frame_part, shade, uvs_of, shade_frame = saved
    cur = {}

    def one(self, i):
        cur["i"] = i
        return part(self, i)

    def crop(*a, **k):
        res = frame_part(*a, **k)
        if res is not None:
            capture.append((cur["i"], res[0], cur.pop("labels"), cur.pop("w", None)))
        return res

    def layers(*a, **k):
        out = shade(*a, **k)
        cur["labels"] = out[1].copy()
        return out

    def uvs(u, size, lifted, drawn):
        cur["weights"] = unmoved.vertex_weights(lifted, drawn, **({} if d is None else
                                                                  {"d0": d[0], "d1": d[1]}))
        return None if d is None else uvs_of(u, size, lifted, drawn, d0=d[0], d1=d[1])

    def shaded(raster, V, topo, textures, own=None):
        if "weights" in cur:
            cur["w"] = unmoved.unmoved_weight(raster, topo.faces, cur.pop("weights"))
        return shade_frame(raster, V, topo, textures, own)

    rc._ClipRenderer.part, rc.rewrite_frame_part, rw.shade_layers, rw.unmoved_uvs, \
        rw._shade_frame = one, crop, layers, uvs, shaded
    try:
        yield
    finally:
        rc._ClipRenderer.part, rc.rewrite_frame_part, rw.shade_layers, rw.unmoved_uvs, \
            rw._shade_frame = saved


def _render(plan, model, d):
    """The plan's frames rewritten (default options, one worker) at ``d``; and per frame its
    crops' ``(box, labels, weight map)``."""
    from facetransfer.rewrite_clip import MouthSource, RenderRun, rewrite_frames

    capture: list = []
    with _variant(d, capture):
        images = [r.image for r in rewrite_frames(
            plan.target_frames, plan.target_track, plan.new_track, model,
            mouth_source=MouthSource(plan.mouth_frames, plan.mouth_track, plan.mouth_index),
            run=RenderRun(workers=1, processes=False), regions=plan.regions)]
    crops: dict = {}
    for i, box, labels, w in capture:
        crops.setdefault(i, []).append((box, labels, w))
    return images, crops


def _masks(crops, shape):
    """``(face, texture's own pixels, weight)`` (H, W) of one frame from its crops."""
    import cv2

    face, painted = np.zeros(shape, bool), np.zeros(shape, bool)
    w = np.zeros(shape, np.float32)
    for (x0, y0, x1, y1), labels, wc in crops:
        face[y0:y1, x0:x1] |= labels != 0
        painted[y0:y1, x0:x1] |= (labels & PAINTED) != 0
        if wc is not None:
            w[y0:y1, x0:x1] = np.maximum(w[y0:y1, x0:x1], wc)
    core = cv2.erode(face.view(np.uint8), np.ones((13, 13), np.uint8)).view(bool)
    painted = cv2.dilate(painted.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool)
    return face, core & ~painted, w


def _laplacian_var(image, mask) -> float:
    import cv2

    g = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(cv2.Laplacian(g, cv2.CV_32F, ksize=1)[mask].var())


def _psnr(a, b, mask) -> float:
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask]) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def measure_pair(name: str, model, out: Path, data: Path, judge: bool) -> dict:
    """:func:`_render` of each variant on pair ``name``, measured (module docstring)."""
    from facetransfer import transfer_plan as tp
    from facetransfer import unmoved
    from facetransfer.track.presets import DEFAULT_SPEED, DETECT_EVERY

    src, tgt = bj.PAIRS[name]
    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    plan = tp.plan_transfer(
        data / f"{tgt}.mp4", model, expression_from=data / f"{src}.mp4", max_frames=FRAMES,
        target_track=bj._track(tgt, model, cache, data, DETECT_EVERY[DEFAULT_SPEED]),
        expression_track=bj._track(src, model, cache, data, DETECT_EVERY[DEFAULT_SPEED],
                                    True))
    targets = [np.asarray(plan.target_frames[i]) for i in range(plan.n_frames)]
    variants = {"resampled": None, "0.25-1 px": (0.25, 1.0),
                "default": (unmoved.D0, unmoved.D1)}
    res, images = {}, {}
    for v, d in variants.items():
        images[v], crops = _render(plan, model, d)
        rows, before = [], None
        for i, t in enumerate(targets):
            if i not in crops:
                before = None
                continue
            face, own, w = _masks(crops[i], t.shape[:2])
            w = w if d is not None else np.zeros_like(w)
            rows.append([np.mean(w[face] >= 1), np.mean(w[face] > 0), np.mean(w[own] >= 1),
                         np.mean(w[own] > 0), _psnr(images[v][i], t, own),
                         _laplacian_var(images[v][i], own) / _laplacian_var(t, own), np.nan])
            if before is not None:  # the result's change from the last frame against the plate's
                m = own & before
                r, r0, t0 = images[v][i][m], images[v][i - 1][m], targets[i - 1][m]
                rows[-1][6] = np.abs((r.astype(np.float64) - r0) - (t[m].astype(np.float64) - t0)
                                     ).mean()
            before = own
        m = np.nanmean(rows, axis=0)
        res[v] = {"kept_face": m[0], "in_part_face": m[1], "kept_texture": m[2],
                  "in_part_texture": m[3], "psnr_texture_db": m[4], "sharpness_ratio": m[5],
                  "temporal_levels": m[6],
                  "temporal_levels_max": float(np.nanmax(np.asarray(rows)[:, 6]))}
        print(f"{name} {v}: " + ", ".join(f"{k} {x:.3f}" for k, x in res[v].items()),
              flush=True)
    if judge:
        res["judge"] = _judge(plan, targets, images, data / f"{src}.mp4", data / f"{tgt}.mp4")
    _picture(name, targets, images, out / f"unmoved_{name}.png")
    return res


def _judge(plan, targets, images, source_video: Path, target_video: Path) -> dict:
    """Face Landmarker's correlations per variant (``bench_transfer_judge.compare``; frames
    seen at their shown shape, as the judge sees them)."""
    from facetransfer.export.common import head_euler
    from facetransfer.io.video import video_info

    n = len(targets)
    sar_s, sar_t = video_info(source_video).sar, video_info(target_video).sar
    source = [plan.mouth_frames[plan.mouth_index[i]] for i in range(n)]
    S, T = bj.scores(source, plan.fps, sar_s), bj.scores(targets, plan.fps, sar_t)
    pose = np.degrees(head_euler(plan.target_track.rotation[:n])[:, [1, 0]])
    return {v: bj.compare(S, T, bj.scores(im, plan.fps, sar_t), pose)
            for v, im in images.items()}


def _picture(name: str, targets, images, path: Path) -> None:
    """target | resampled | default, 3x (nearest), the forehead's hair of frames 10, 40, 84."""
    import cv2

    from _report import save_sheet

    rows, labels = [], []
    for i in (10, 40, 84):
        if i >= len(targets):
            continue
        H, W = targets[i].shape[:2]
        y0, x0 = H // 8, W // 2 - W // 16  # (the demo target's fringe over the forehead)
        tiles = [cv2.resize(im[y0:y0 + H // 6, x0:x0 + W // 5], None, fx=3, fy=3,
                            interpolation=cv2.INTER_NEAREST)
                 for im in (targets[i], images["resampled"][i], images["default"][i])]
        rows.append(np.concatenate(tiles, axis=1))
        labels.append(f"{name} {i}: target | resampled | own pixels")
    save_sheet(rows, labels, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--pairs", default="demo,fps", help=f"of {', '.join(bj.PAIRS)}")
    ap.add_argument("--judge", action="store_true", help="Face Landmarker on each result")
    ap.add_argument("--self", action="store_true", help="the self-transfer too")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    data = Path(data_dir()) / "video"
    model = load_default_model()
    res = {p: measure_pair(p, model, out, data, args.judge) for p in args.pairs.split(",") if p}
    with atomic_path(out / "unmoved.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(res, indent=2, default=float))
    if args.self:
        from _self_transfer import patched, run

        run(out, {"resampled": functools.partial(patched, "facetransfer.rewrite", "unmoved_uvs",
                                                 lambda *a, **k: None),
                  "own pixels": contextlib.nullcontext}, "unmoved_self",
            "self-transfer: the pixels the target's own pixels change")
    return 0


if __name__ == "__main__":
    sys.exit(main())

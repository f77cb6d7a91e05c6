"""Where the demo's brows are lost: browInnerUp along the transfer's chain against Face Landmarker.

The judge (``bench_transfer_judge.py``) correlates Face Landmarker's browInnerUp on the result
with its browInnerUp on the source frame shown (matched by time). This splits that chain for
one pair (default the demo's, ``driving_d6`` -> ``WDA_KatieHill_000``), each link's series
correlated over the judged frames with the one before and with Face Landmarker on the source
(``FL(S)``), with its standard deviation's ratio:

(a) ``capture``: the capture's browInnerUp activation of the source frame shown;
(b) ``plan``: the new performance's (``plan.new_track``, the result frames' activations);
(c) ``mesh``: the inner brows' height in the new performance's projected landmarks (iBUG 21/22
    over the upper lids 38/43, over the eye corners 36-45), what the renderer moves; and
    ``FL(R)``, Face Landmarker on the rendered result (the judge), with its partial
    correlation with the target (``FL(T)`` and the target's own activation) once the plan's
    activation is partialled out;
(d) the other brow shapes (browOuterUp, browDown; the means of left and right) on both sides;

and what else ``FL(R)`` follows once the plan's browInnerUp is regressed out (the plan's and the
target's activations, the target's head pose: :func:`residual_drivers`).

The tracks are the judge's (``--tracks``: its ``judge_pairs`` folder, made afresh otherwise);
the result is rendered once with the default options (``after``). ``--brow-keep`` and the like
are not offered: variants are tried by editing the tree.

Usage::

    python benchmarks/bench_brow_chain.py --out out/brow_chain [--pair demo]
        [--tracks out/benchmarks/judge_pairs]

Writes ``OUT/brow_chain_PAIR.json`` and ``OUT/brow_chain_PAIR.png`` (the series over frames).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_transfer_judge as bj  # noqa: E402
from _mp_video import filtered_stderr  # noqa: E402

#: Brow measures compared on both sides: name -> ARKit/MediaPipe names averaged.
BROW = {"browInnerUp": ("browInnerUp",),
        "browOuterUp": ("browOuterUpLeft", "browOuterUpRight"),
        "browDown": ("browDownLeft", "browDownRight")}


def _columns(A: np.ndarray, names, which) -> np.ndarray:
    """The mean of the columns ``which`` of ``A`` (F, K) named by ``names``."""
    return np.mean([A[:, list(names).index(n)] for n in which], axis=0).astype(np.float64)


def mesh_brow_height(track, model) -> np.ndarray:
    """``(F,)``: the inner brows' height in ``track``'s projected landmarks (iBUG 21 over 38,
    22 over 43, mean) over the outer eye corners' distance (36-45)."""
    from facetransfer.track.project import project_landmarks

    P = project_landmarks(track, model).landmarks2d.astype(np.float64)
    span = np.linalg.norm(P[:, 36] - P[:, 45], axis=1)
    h = (np.linalg.norm(P[:, 21] - P[:, 38], axis=1) + np.linalg.norm(P[:, 22] - P[:, 43],
                                                                      axis=1)) / 2
    return h / np.maximum(span, 1e-9)


def link(x: np.ndarray, ref: np.ndarray) -> dict:
    """``r`` of ``x`` with ``ref`` and the ratio of their standard deviations."""
    from facetransfer.fidelity import correlation

    return {"r": correlation(x, ref), "std_ratio": float(np.nanstd(x) / max(np.nanstd(ref),
                                                                            1e-12))}


def series(pair: str, model, data: Path, tracks: Path, frames: int) -> dict:
    """The chain's series (each (F,)) of one pair, and the judge's result frames rendered."""
    from facetransfer import transfer_plan as tp
    from facetransfer import video_transfer as vt
    from facetransfer.arkit import ARKIT_NAMES, MEDIAPIPE_NAMES, attach_activations
    from facetransfer.export.common import head_euler
    from facetransfer.io.video import video_info
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer.track.presets import DEFAULT_SPEED, DETECT_EVERY

    every = DETECT_EVERY[DEFAULT_SPEED]
    src, tgt = bj.PAIRS[pair]
    tracks.mkdir(parents=True, exist_ok=True)
    with filtered_stderr():
        plan = tp.plan_transfer(data / f"{tgt}.mp4", model, expression_from=data / f"{src}.mp4",
                                max_frames=frames,
                                target_track=bj._track(tgt, model, tracks, data, every),
                                expression_track=bj._track(src, model, tracks, data, every, True))
    n, idx = plan.n_frames, np.asarray(plan.mouth_index[:plan.n_frames])
    rendered: list[np.ndarray] = []
    with tempfile.TemporaryDirectory() as tmp:
        vt.render_plan(plan, model, vt.RenderTarget(Path(tmp) / "r.mp4", overwrite=True),
                       options=RewriteOptions(eyes="model"),
                       compose=lambda i, r: rendered.append(r.image) or r.image)
    sar = {c: video_info(data / f"{c}.mp4").sar for c in (src, tgt)}
    fl = {"S": bj.scores([plan.mouth_frames[i] for i in idx], plan.fps, sar[src]),
          "T": bj.scores([plan.target_frames[i] for i in range(n)], plan.fps, sar[tgt]),
          "R": bj.scores(rendered, plan.fps, sar[tgt])}
    act = {"capture": attach_activations(plan.source_tracks["expression"], model).blendshapes[idx],
           "resampled": attach_activations(plan.mouth_track, model).blendshapes[:n],
           "plan": attach_activations(plan.new_track, model).blendshapes[:n],
           "target": attach_activations(plan.target_track, model).blendshapes[:n]}
    out = {}
    for b, names in BROW.items():
        for k, (A, _) in fl.items():
            out[f"FL({k}) {b}"] = _columns(A, MEDIAPIPE_NAMES, names)
        for k, A in act.items():
            out[f"{k} {b}"] = _columns(np.asarray(A), ARKIT_NAMES, names)
    for k, (_, G) in fl.items():
        out[f"FL({k}) brow height"] = (G["brow_height_left"] + G["brow_height_right"]) / 2
    out["mesh brow height"] = mesh_brow_height(plan.new_track, model)[:n]
    out["target mesh brow height"] = mesh_brow_height(plan.target_track, model)[:n]
    pose = np.degrees(head_euler(plan.target_track.rotation[:n]))[:, [1, 0, 2]]
    drivers = residual_drivers(out["FL(R) browInnerUp"], out["plan browInnerUp"],
                               {"plan": act["plan"], "target": act["target"]}, pose)
    return {"src": src, "tgt": tgt, "fps": plan.fps, "mouth_index": idx.tolist(),
            "series": out, "residual_drivers": drivers}


def residual_drivers(r: np.ndarray, plan: np.ndarray, acts: dict, pose: np.ndarray,
                     top: int = 12) -> dict:
    """What else the result's reading ``r`` (F,) follows: the correlation of its residual
    once the plan's browInnerUp ``plan`` (F,) is regressed out with every activation of
    ``acts`` (name -> (F, 52)) and the target's head ``pose`` (F, 3: pitch, yaw, roll in
    degrees); the ``top`` largest in size, name -> r."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.fidelity import correlation

    X = np.column_stack([np.ones(len(r)), plan])
    ok = np.isfinite(r) & np.isfinite(plan)
    e = np.full(len(r), np.nan)
    e[ok] = r[ok] - X[ok] @ np.linalg.lstsq(X[ok], r[ok], rcond=None)[0]
    cols = {f"{k} {n}": np.asarray(A, np.float64)[:, j] for k, A in acts.items()
            for j, n in enumerate(ARKIT_NAMES)}
    cols.update({f"target {n}": pose[:, j] for j, n in enumerate(("pitch", "yaw", "roll"))})
    rs = {k: correlation(v, e) for k, v in cols.items()}
    rs = {k: v for k, v in rs.items() if np.isfinite(v)}
    return dict(sorted(rs.items(), key=lambda kv: -abs(kv[1]))[:top])


def chain(s: dict) -> dict:
    """The table's figures from :func:`series`' ``series``."""
    s = {k: np.asarray(v, np.float64) for k, v in s.items()}
    fs = s["FL(S) browInnerUp"]
    out = {"a capture ~ FL(S)": link(s["capture browInnerUp"], fs),
           "b plan ~ capture": link(s["plan browInnerUp"], s["capture browInnerUp"]),
           "b plan ~ FL(S)": link(s["plan browInnerUp"], fs),
           "c mesh height ~ plan": link(s["mesh brow height"], s["plan browInnerUp"]),
           "c FL(R) ~ plan": link(s["FL(R) browInnerUp"], s["plan browInnerUp"]),
           "c FL(R) ~ FL(S) (judge)": link(s["FL(R) browInnerUp"], fs),
           "c FL(R) brow height ~ FL(S) brow height": link(s["FL(R) brow height"],
                                                           s["FL(S) brow height"]),
           "c FL(R) brow height ~ mesh height": link(s["FL(R) brow height"],
                                                     s["mesh brow height"]),
           "c FL(R) ~ FL(T)": link(s["FL(R) browInnerUp"], s["FL(T) browInnerUp"]),
           "c FL(T) ~ FL(S) (chance)": link(s["FL(T) browInnerUp"], fs)}
    r, plan = s["FL(R) browInnerUp"], s["plan browInnerUp"]
    out["c partial FL(R) ~ FL(T) | plan"] = bj._partial(r, s["FL(T) browInnerUp"], [plan])
    out["c partial FL(R) ~ target act | plan"] = bj._partial(r, s["target browInnerUp"], [plan])
    out["c partial FL(R) ~ target mesh height | plan"] = bj._partial(
        r, s["target mesh brow height"], [plan])
    out["c partial FL(R) ~ FL(S) | plan"] = bj._partial(r, fs, [plan])
    X = np.column_stack([np.ones(len(r)), plan, s["FL(T) browInnerUp"]])
    ok = np.isfinite(X).all(axis=1) & np.isfinite(r)
    coef = np.linalg.lstsq(X[ok], r[ok], rcond=None)[0]
    out["c FL(R) = a + b plan + c FL(T)"] = [float(c) for c in coef]
    for b in ("browOuterUp", "browDown"):
        out[f"d FL(S) {b} ~ FL(S) browInnerUp"] = link(s[f"FL(S) {b}"], fs)
        out[f"d capture {b} ~ FL(S) {b}"] = link(s[f"capture {b}"], s[f"FL(S) {b}"])
        out[f"d plan {b} ~ capture {b}"] = link(s[f"plan {b}"], s[f"capture {b}"])
        out[f"d FL(R) {b} ~ FL(S) {b}"] = link(s[f"FL(R) {b}"], s[f"FL(S) {b}"])
        out[f"d FL(R) {b} ~ FL(T) {b}"] = link(s[f"FL(R) {b}"], s[f"FL(T) {b}"])
        out[f"d FL(R) browInnerUp ~ plan {b}"] = link(r, s[f"plan {b}"])
    return out


def plot(res: dict, path: Path) -> None:
    """The brow series over frames, each standardised."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    s = res["series"]
    fig, axes = plt.subplots(2, 1, figsize=(12, 6.5), sharex=True)
    for ax, keys in zip(axes, (("FL(S) browInnerUp", "capture browInnerUp", "plan browInnerUp",
                                "FL(R) browInnerUp"),
                               ("FL(R) browInnerUp", "FL(T) browInnerUp", "mesh brow height",
                                "FL(R) brow height"))):
        for k in keys:
            v = np.asarray(s[k], np.float64)
            ax.plot((v - np.nanmean(v)) / max(np.nanstd(v), 1e-9), label=k, lw=1.2)
        ax.legend(fontsize=8, ncol=4, loc="upper left")
        ax.set_ylabel("standardised")
    axes[-1].set_xlabel("result frame")
    fig.suptitle(f"browInnerUp along the chain: {res['src']} -> {res['tgt']}")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/brow_chain")
    ap.add_argument("--pair", default="demo", choices=list(bj.PAIRS))
    ap.add_argument("--tracks", default=None, help="the judge's judge_pairs folder")
    ap.add_argument("--frames", type=int, default=bj.FRAMES)
    args = ap.parse_args()
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tracks = Path(args.tracks) if args.tracks else out / "judge_pairs"
    res = series(args.pair, load_default_model(), Path(data_dir()) / "video", tracks,
                 args.frames)
    res["chain"] = chain(res["series"])
    for k, v in res["chain"].items():
        text = (f"r {v['r']:+.2f}  std ratio {v['std_ratio']:.2f}" if isinstance(v, dict)
                else " ".join(f"{x:+.2f}" for x in np.atleast_1d(v)))
        print(f"{k:45s} {text}")
    for k, v in res["residual_drivers"].items():
        print(f"FL(R)'s residual ~ {k:26s} {v:+.2f}")
    res["series"] = {k: [float(x) for x in v] for k, v in res["series"].items()}
    with atomic_path(out / f"brow_chain_{args.pair}.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps(res, indent=1))
    plot(res, out / f"brow_chain_{args.pair}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

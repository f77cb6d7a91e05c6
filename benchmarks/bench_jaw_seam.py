"""The jaw region's seam (issue 13): the colour step across its outline, this tree against another.

The rewrite textures the chin and jaw from a closed-mouth target frame (:mod:`facetransfer.jaw`).
Seen under another head pose and light, that texture showed as patches with seams in ``make
demo``'s contact sheet (an orange cheek on a turned open-mouth frame, a pale V under the chin
of a smiling one). This script puts a number on it. On the demo pair (``WDA_KatieHill_000`` as
the target, the expressions of ``driving_d6``, 120 frames, default model and options), each
tree renders every frame in a fresh process (``--base-rev REV``: a git revision of this
repository, extracted to a temporary folder); then, per frame, over the jaw region's outline
in the new face (the region's pixels rasterised from the new mesh, the mouth's excluded):

* the **step**: the CIELAB colour difference (ΔE76) between the mean colour of the region's
  pixels and of the face's pixels outside it, each within 5 px of the outline, compared
  locally (Gaussian-weighted means, σ 6 px, at every outline pixel), its mean over the
  outline;
* the **floor**: the same on the target frame itself, with the same masks (how much the skin's
  own colour changes across that line).

A seam is a step well above the floor: the figures are over the frames where the jaw layer is
pasted (``pasted``), the step and its excess over the floor frame by frame (median, 90th
percentile, largest). Lower is better.

    python benchmarks/bench_jaw_seam.py --out out/benchmarks --base-rev 72eeed3

Writes ``OUT/jaw_seam.json`` and ``OUT/jaw_seam.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from _revision import extract_src, rewrite_plan  # benchmarks/ is on sys.path

FRAMES = 120
BAND = 5
SIGMA = 6.0


def worker(tracks: Path, save: Path) -> None:
    """Render the demo pair here (the tree on ``sys.path``), saving the result frames."""
    from facetransfer.default_model import load_default_model
    from facetransfer.demo import default_inputs
    from facetransfer.rewrite_options import RewriteOptions
    from facetransfer.texture.face import resolve_mouth_mode
    from facetransfer.video_transfer import plan_transfer

    model = load_default_model()
    source, target = default_inputs()
    tt, et = tracks / "target.npz", tracks / "expression.npz"
    plan = plan_transfer(target, model, expression_from=source, max_frames=FRAMES,
                         target_track=tt if tt.exists() else None,
                         expression_track=et if et.exists() else None)
    if not tt.exists():  # tracked once, for every later run
        tracks.mkdir(parents=True, exist_ok=True)
        plan.source_tracks["target"].save(tt)
        plan.source_tracks["expression"].save(et)
    opts = RewriteOptions()
    opts = opts.with_(mouth=resolve_mouth_mode(opts.mouth, model, performance=plan.performance))
    it = rewrite_plan(plan, model, opts, workers=1)  # this tree's call or an older one's
    np.save(save, np.stack([r.image for r in it]))


def render(src: Path, tracks: Path, save: Path) -> np.ndarray:
    """:func:`worker` in a fresh process with ``src`` first on its path."""
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1")
    subprocess.run([sys.executable, __file__, "--worker", "--tracks", str(tracks), "--save",
                    str(save)], env=env, check=True, capture_output=True, text=True)
    return np.load(save)


def region_masks(tracks: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(region, face, pasted, target)``: per frame the jaw region's pixels and the face's
    (the new mesh's, the mouth's triangles excluded) (F, H, W) bool, whether the jaw layer
    is pasted in that frame (F,) bool (this tree's :class:`facetransfer.jaw.JawTexture`),
    and the target frames (F, H, W, 3) uint8."""
    from facetransfer.arkit import expression_rig
    from facetransfer.default_model import load_default_model
    from facetransfer.demo import default_inputs
    from facetransfer.eyes import eye_texture
    from facetransfer.jaw import jaw_region, jaw_texture
    from facetransfer.render import rasterize
    from facetransfer.topology import mesh_topology
    from facetransfer.video_transfer import plan_transfer

    model = load_default_model()
    source, target = default_inputs()
    plan = plan_transfer(target, model, expression_from=source, max_frames=FRAMES,
                         target_track=tracks / "target.npz",
                         expression_track=tracks / "expression.npz")
    rig = expression_rig(model, model.default_weights())
    topo, _ = eye_texture(plan.target_frames, plan.target_track, model, mesh_topology(model),
                          n_frames=FRAMES, rig=rig)
    sel = jaw_region(model, topo, rig=rig)
    tex = jaw_texture(plan.target_frames, plan.target_track, model, topo, n_frames=FRAMES,
                      rig=rig)
    mouth = np.zeros(len(topo.faces), bool)
    mouth[np.asarray(topo.mouth_faces, np.int64)] = True
    H, W = plan.target_frames.shape[1:3]
    region, face = np.zeros((2, FRAMES, H, W), bool)
    from facetransfer.topology import close_mouth

    for i in range(FRAMES):
        V = close_mouth(model.synthesize(plan.new_track.weights_at(i)), topo)
        r = rasterize(V, topo.faces, plan.new_track.camera(i), (W, H))
        tid = r.tri_id
        ok = tid >= 0
        region[i] = ok & sel[np.maximum(tid, 0)]
        face[i] = ok & ~mouth[np.maximum(tid, 0)]
    pasted = np.array([tex.at(i) is not None for i in range(FRAMES)])
    return region, face, pasted, np.asarray(plan.target_frames[:FRAMES])


def step(image: np.ndarray, region: np.ndarray, face: np.ndarray) -> float:
    """Mean ΔE76 over the region's outline between the locally weighted mean CIELAB colours
    of the region's pixels and of the face's pixels outside it, within :data:`BAND` px."""
    import cv2

    lab = cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)
    k = np.ones((2 * BAND + 1, 2 * BAND + 1), np.uint8)
    r8 = region.view(np.uint8)
    inner = region & ~cv2.erode(r8, k).view(bool)
    outer = face & ~region & cv2.dilate(r8, k).view(bool)
    line = region & cv2.dilate(outer.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    if line.sum() < 20:
        return float("nan")
    means = []
    for m in (inner, outer):
        w = cv2.GaussianBlur(m.astype(np.float32), (0, 0), SIGMA)
        s = cv2.GaussianBlur(lab * m[..., None], (0, 0), SIGMA)
        means.append(s[line] / np.maximum(w[line], 1e-6)[:, None])
    return float(np.linalg.norm(means[0] - means[1], axis=1).mean())


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.8))
    for name, steps in res["steps"].items():
        ax.plot(steps, label=f"{name} (median {res['median'][name]:.2f})", lw=1)
    ax.set_xlabel("frame of the demo pair")
    ax.set_ylabel("ΔE76 across the jaw region's outline")
    ax.set_ylim(bottom=0)
    ax.legend()
    fig.suptitle("jaw region: colour step at its outline (lower: no seam)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    ap.add_argument("--base-rev", help="a git revision of this repository to compare with")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--tracks", help=argparse.SUPPRESS)
    ap.add_argument("--save", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        worker(Path(a.tracks), Path(a.save))
        return 0
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    tracks = out / "jaw_seam_tracks"
    trees = {"this tree": Path(__file__).resolve().parents[1] / "src"}
    if a.base_rev:
        trees[f"base {a.base_rev}"] = extract_src(a.base_rev, "bench_jaw_seam_")
    images = {name: render(src, tracks, out / f"jaw_seam_{i}.npy")
              for i, (name, src) in enumerate(trees.items())}
    region, face, pasted, target = region_masks(tracks)
    steps = {name: [step(img[i], region[i], face[i]) for i in range(FRAMES)]
             for name, img in images.items()}
    steps["floor (the target frame)"] = [step(target[i], region[i], face[i])
                                         for i in range(FRAMES)]
    med = {k: float(np.nanmedian(np.asarray(v)[pasted])) for k, v in steps.items()}
    p90 = {k: float(np.nanpercentile(np.asarray(v)[pasted], 90)) for k, v in steps.items()}
    floor = np.asarray(steps["floor (the target frame)"])
    excess = {k: np.asarray(steps[k])[pasted] - floor[pasted] for k in images}
    res = {"frames": FRAMES, "pasted": int(pasted.sum()), "band_px": BAND, "sigma_px": SIGMA,
           "median": med, "p90": p90,
           "excess_median": {k: float(np.nanmedian(v)) for k, v in excess.items()},
           "excess_p90": {k: float(np.nanpercentile(v, 90)) for k, v in excess.items()},
           "excess_max": {k: float(np.nanmax(v)) for k, v in excess.items()}, "steps": steps}
    (out / "jaw_seam.json").write_text(json.dumps(res, indent=1))
    plot(res, out / "jaw_seam.png")
    for k in steps:
        more = "" if k not in excess else (
            f"; above the floor: median {res['excess_median'][k]:.2f}, p90 "
            f"{res['excess_p90'][k]:.2f}, max {res['excess_max'][k]:.2f}")
        print(f"{k}: ΔE across the outline, median {med[k]:.2f}, p90 {p90[k]:.2f}{more} "
              f"(over the {int(pasted.sum())} frames the jaw layer is pasted)")
    print(f"wrote {out / 'jaw_seam.json'} and {out / 'jaw_seam.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

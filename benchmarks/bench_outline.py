"""The target's outline drawn inside the new face (issue 13), this tree against another revision.

A frame's face texture is the target frame looked up through the target's tracked mesh, whose
outline lies a few pixels off the real one: the texture's outer band holds the target's own
outline (hair beside a cheek, a strand over the jaw line). :mod:`facetransfer.rim` keeps the
target's own pixels where the new face would draw that band inside the target's face. Two
measures, each tree in a fresh process (``--base-rev REV``: a git revision of this repository,
extracted to a temporary folder):

* **Synthetic truth.** The default model's mean face (the target) in a frame whose silhouette
  has a dark edge 4 px wide just inside it (the hair the tracked outline takes in), skin
  inside, background outside; new faces: the same face turned in the image plane by 2-8
  degrees (its outline slides along itself) and with its jaw dropped (``jawOpen`` 0.3-1.0, the
  mouth textured by the target's own frame), hard paste. The count of the dark edge's pixels
  drawn on the target's skin (2 px inside it, away from the frame's edges), with the rule as
  the tree has it and switched off (``rim.MOVED`` out of reach): lower is better.
* **make demo's frames** (``WDA_KatieHill_000`` as the target, the expressions of
  ``driving_d6``, 120 frames, default options): each tree's ``facetransfer demo``; per frame,
  the pixels whose colour differs by more than 30 levels between the trees, and a picture of
  the three frames that differ most (target | base | this tree).

    python benchmarks/bench_outline.py --base-rev b9e4686 --out out/benchmarks

Writes ``OUT/outline.json``, ``OUT/outline.png`` (the synthetic counts) and
``OUT/outline_frames.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _revision import extract_src, hard_paste  # noqa: E402

SIZE = 512
SKIN, EDGE, BACK = (200, 150, 120), (30, 25, 20), (120, 160, 120)
ROLLS, JAWS = (2.0, 4.0, 6.0, 8.0), (0.3, 0.6, 1.0)


def _track(model, jaw_open: float):
    """One frame of the model's mean person facing the camera, ``jawOpen`` the given value and
    every other activation 0, ~270 px across in the middle of a ``SIZE``² frame."""
    from facetransfer.arkit import ARKIT_NAMES, activations_to_weights
    from facetransfer.track.result import Track

    a = np.zeros((1, 52), np.float32)
    a[0, ARKIT_NAMES.index("jawOpen")] = jaw_open
    k = model.mode_index("identity")
    return Track(fps=25.0, frame_size=(SIZE, SIZE), rotation=np.eye(3)[None],
                 scale=np.full(1, 25.0), translation=np.array([[SIZE / 2, SIZE / 2 - 40.0]]),
                 weights={"identity": model.weight_mean(k)[None],
                          "expression": activations_to_weights(model, a)},
                 landmarks2d=np.zeros((1, 68, 2)), confidence=np.ones(1),
                 lost=np.zeros(1, bool), model_hash=model.content_hash,
                 mode_names=model.mode_names, source="synthetic.mp4")


def _scene():
    """``(model, topo, frame, texture, Vc, camera, skin)`` of the synthetic target."""
    from facetransfer.cli.common import resolve_model
    from facetransfer.composite import erode_mask
    from facetransfer.render import rasterize
    from facetransfer.texture.face import FaceTexture, frame_uvs
    from facetransfer.topology import close_mouth, mesh_topology

    model = resolve_model(None, progress=False)
    topo = mesh_topology(model)
    track = _track(model, 0.0)
    cam = track.camera(0)
    Vc = close_mouth(model.synthesize(track.weights_at(0)), topo)
    mask = rasterize(Vc, topo.faces, cam, (SIZE, SIZE)).mask
    frame = np.empty((SIZE, SIZE, 3), np.uint8)
    frame[:] = BACK
    frame[mask] = EDGE
    frame[erode_mask(mask, 4)] = SKIN
    skin = erode_mask((frame == SKIN).all(axis=-1), 2)  # 2 px of the rule's tolerance
    skin[:16] = skin[-16:] = False                  # the head cut by the frame: no outline
    tex = FaceTexture(frame, frame_uvs(Vc, cam, (SIZE, SIZE)), 0)
    return model, topo, frame, tex, Vc, cam, skin


def _new_faces(model, cam):
    """``{label: (vertices or None (the target's), camera)}``: the turned faces and the
    dropped jaws."""
    from facetransfer.render import WeakPerspective

    out = {}
    for deg in ROLLS:
        a = np.deg2rad(deg)
        roll = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
        out[f"turned {deg:g} deg"] = (None, WeakPerspective(cam.scale, roll @ cam.rotation,
                                                            cam.translation))
    for j in JAWS:
        out[f"jawOpen {j:g}"] = (model.synthesize(_track(model, j).weights_at(0)), cam)
    return out


def worker() -> None:
    """Print the synthetic counts of the tree on the path, as JSON."""
    from facetransfer import rim

    paste = hard_paste()
    model, topo, frame, tex, Vc, cam, skin = _scene()
    res = {}
    for label, (V, c) in _new_faces(model, cam).items():
        V = Vc if V is None else V
        row = {}
        for rule, moved in (("on", rim.MOVED), ("off", np.inf)):
            saved, rim.MOVED = rim.MOVED, moved
            try:
                out = paste(frame, V, c, topo, tex).image
            finally:
                rim.MOVED = saved
            row[rule] = int(((np.abs(out.astype(int) - EDGE).max(axis=-1) < 40) & skin).sum())
        res[label] = row
    print(json.dumps(res))


def synthetic(src: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1")
    res = subprocess.run([sys.executable, __file__, "--worker"], check=True, env=env,
                         capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def demo(src: Path, out: Path) -> str:
    """The fidelity line of ``facetransfer demo`` of the tree ``src`` into ``out``."""
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1")
    code = ("import sys\nfrom facetransfer.cli.main import main\n"
            f"sys.exit(main(['demo', '--out', {str(out)!r}, '--overwrite', '--no-progress']))")
    res = subprocess.run([sys.executable, "-c", code], check=True, env=env, capture_output=True,
                         text=True)
    return next((ln for ln in res.stdout.splitlines() if ln.startswith("fidelity")), "")


def frames_picture(base: Path, new: Path, path: Path) -> dict:
    """Per frame the pixels (of the result panel) differing by more than 30 levels; a picture of
    the three frames that differ most (target | base | this tree, around the change)."""
    import cv2

    from facetransfer.io.video import read_video

    a, _ = read_video(base / "demo.mp4")
    b, _ = read_video(new / "demo.mp4")
    w = a.shape[2] // 3
    ra, rb = a[:, :, 2 * w:].astype(np.int16), b[:, :, 2 * w:].astype(np.int16)
    diff = np.abs(ra - rb).max(axis=-1) > 30
    counts = diff.sum(axis=(1, 2))
    top = [int(i) for i in np.argsort(-counts)[:3]]
    rows = []
    for i in top:
        ys, xs = np.nonzero(diff[i])
        y0, y1 = max(ys.min() - 24, 0), min(ys.max() + 24, a.shape[1])
        x0, x1 = max(xs.min() - 24, 0), min(xs.max() + 24, w)
        panels = [a[i, y0:y1, w + x0:w + x1], a[i, y0:y1, 2 * w + x0:2 * w + x1],
                  b[i, y0:y1, 2 * w + x0:2 * w + x1]]
        row = np.concatenate([cv2.resize(p, (2 * (x1 - x0), 2 * (y1 - y0))) for p in panels], 1)
        cv2.putText(row, f"frame {i}: target | base | this tree", (6, 22),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
        rows.append(row)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0))) for r in rows]
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(rows, 0), cv2.COLOR_RGB2BGR))
    return {"changed_pixels_median": float(np.median(counts)), "changed_pixels_max":
            int(counts.max()), "frames_most_changed": top}


def plot(res: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    labels = list(res["new"]["synthetic"])
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(8, 4))
    for k, (tree, rule, colour) in enumerate((("base", "on", "tab:orange"),
                                              ("new", "on", "tab:blue"),
                                              ("new", "off", "tab:grey"))):
        ax.bar(x + (k - 1) * 0.27, [res[tree]["synthetic"][lb][rule] for lb in labels], 0.27,
               color=colour, label=f"{tree}, rule {rule}")
    ax.set_xticks(x, labels, rotation=20)
    ax.set_ylabel("dark edge pixels on the target's skin")
    ax.set_title("The target's outline drawn inside its face (synthetic truth)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-rev", default="HEAD~1")
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker()
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    trees = {"base": extract_src(args.base_rev), "new": Path(__file__).resolve().parents[1] / "src"}
    res: dict = {"base_rev": args.base_rev}
    with tempfile.TemporaryDirectory(prefix="bench_outline_") as tmp:
        for name, src in trees.items():
            res[name] = {"synthetic": synthetic(src),
                         "demo_fidelity": demo(src, Path(tmp) / name)}
            print(name, json.dumps(res[name], indent=1))
        res["demo_frames"] = frames_picture(Path(tmp) / "base", Path(tmp) / "new",
                                            out / "outline_frames.png")
    print(json.dumps(res["demo_frames"]))
    (out / "outline.json").write_text(json.dumps(res, indent=2))
    plot(res, out / "outline.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

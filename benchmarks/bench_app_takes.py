"""Takes the Live Link Face app wrote, against what facetransfer reads and writes of them.

A take holds the 52 ARKit curves and, per row, each eye's rotation (``LeftEyeYaw``,
``LeftEyePitch``, ``RightEyeYaw``, ``RightEyePitch``; radians). Per take given:

* the app's own relation between the two: each eye column fitted by least squares against its
  eye's curves (yaw against ``EyeLookIn - EyeLookOut``, pitch against ``EyeLookDown -
  EyeLookUp``): slope, constant, correlation;
* ours: the eye columns ``export`` writes from the same curves
  (:func:`facetransfer.export.livelink.eye_angles`) fitted against the app's columns (slope
  +1: the app's sign and scale; -1: turned);
* read back: whether the take is read at all (:func:`facetransfer.take.take_track`; the app's
  curves pass 1 a little), and the correlation of the yaw the puppet turns its eyes by (the
  take's recorded columns, :func:`facetransfer.puppet_face.track_gaze`) with the yaw its own
  curves say (:func:`facetransfer.track.gaze.activation_gaze`): +1 where the two agree.

Public takes measured in BENCHMARKS.md (fifty-fourth session): ``MySlate_1_iPhone.csv`` of
github.com/dwskillman/BlendFiles, ``anim/alex_rom_3.csv`` and ``anim/alex_rom_4.csv`` of
github.com/alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder (not shipped here).

Usage::

    python benchmarks/bench_app_takes.py TAKE.csv [TAKE.csv ...] --out out/benchmarks

Writes ``OUT/app_takes.json`` and ``OUT/app_takes.png`` (each take's ``LeftEyeYaw``: the
app's against ours).
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from _report import arguments, save_json  # noqa: E402

EYES = (("Left", 3, 4, 1), ("Right", 6, 7, 0))   # name, yaw and pitch column, gaze's eye


def _fit(x: np.ndarray, y: np.ndarray) -> dict:
    slope, const = np.polyfit(x, y, 1)
    return {"slope": round(float(slope), 4), "constant": round(float(const), 4),
            "correlation": round(float(np.corrcoef(x, y)[0, 1]), 4)}


def measure(path: Path, model) -> tuple[dict, np.ndarray | None, np.ndarray | None]:
    """One take's report, its ``LeftEyeYaw`` column and ours (None: the take refused)."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.export.livelink import eye_angles, read_livelink

    try:
        take = read_livelink(path, lenient=True)  # (refused a curve past 1.001, before)
    except ValueError as exc:
        return {"refused": str(exc)}, None, None
    a, pose, ours = take.activations, take.pose, eye_angles(take.activations)
    col = {n: a[:, ARKIT_NAMES.index(n)] for n in ARKIT_NAMES}
    rep = {"rows": len(a), "largest curve": round(float(a.max()), 4)}
    for eye, yaw, pitch, _ in EYES:
        inward = col[f"eyeLookIn{eye}"] - col[f"eyeLookOut{eye}"]
        down = col[f"eyeLookDown{eye}"] - col[f"eyeLookUp{eye}"]
        rep[f"app {eye}EyeYaw per In-Out"] = _fit(inward, pose[:, yaw])
        rep[f"app {eye}EyePitch per Down-Up"] = _fit(down, pose[:, pitch])
        rep[f"ours {eye}EyeYaw per the app's"] = _fit(pose[:, yaw], ours[:, yaw - 3])
    rep["puppet yaw vs the curves' (left, right)"] = _puppet(path, model)
    return rep, pose[:, 3], ours[:, 0]


def _puppet(path: Path, model) -> list | str:
    from facetransfer.puppet_face import track_gaze
    from facetransfer.take import take_track
    from facetransfer.track.gaze import activation_gaze

    try:
        t = take_track(path, model, model.weight_mean("identity"))
    except ValueError as exc:
        return f"refused: {exc}"
    rec, cur = track_gaze(t), activation_gaze(t.blendshapes)
    return [round(float(np.corrcoef(rec[:, k, 0], cur[:, k, 0])[0, 1]), 4)
            for _, _, _, k in EYES]


def main() -> int:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.default_model import load_default_model

    ap = arguments(__doc__)
    ap.add_argument("takes", nargs="+", type=Path)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    logging.disable(logging.WARNING)
    model, report = load_default_model(), {}
    fig, ax = plt.subplots(figsize=(5, 5))
    for p in args.takes:
        report[p.name], app, ours = measure(p, model)
        if app is not None:
            ax.plot(app, ours, ".", ms=2, label=p.name)
    ax.set(xlabel="the app's LeftEyeYaw (rad)", ylabel="ours from its curves (rad)")
    ax.axline((0, 0), slope=1, color="k", lw=0.5)
    ax.legend()
    fig.savefig(out / "app_takes.png", dpi=100)
    save_json(report, out / "app_takes.json")
    print(__import__("json").dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

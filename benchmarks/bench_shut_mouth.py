"""A shut mouth on real clips (issue 12): how still are our lips, jaw and lip activations where
the reference's mouth is shut, beside Face Landmarker's own points and scores on the same frames?

For each real clip of ``$FACETRANSFER_DATA_DIR/video/`` and its stored MediaPipe-478 reference:

1. the **shut segments**: runs of at least ``--min-frames`` frames where the reference's mouth
   opening (points 13-14 / the outer eye corners 33-263, :mod:`_mp_points`) is below
   ``--shut``, less ``--trim`` frames at each end (the opening and closing themselves);
2. the clip is tracked by the default capture (``bench_capture.run_ours``'s call: detection,
   both passes) and Face Landmarker runs on it in VIDEO mode (the peer, cached);
3. per segment and pooled over a clip's segments (deviations from each segment's own mean):
   the **std** of each signal, its **jitter** (frame to frame: the std of its first difference
   / sqrt 2, the std of white noise) and its **wander** (the std of the signal smoothed by a
   Gaussian of 3 frames: what moves slower than the jitter), of
   - the mouth opening: ours (iBUG 62-66 of the tracked points), the reference's and Face
     Landmarker's (13-14), / the eye-corner distance; ours also in pixels and, on the fitted
     3-D face, in mm (upper minus lower inner-lip vertex along the face's up axis: negative =
     the lips pass through each other) and its lowest value, and the frames where the least
     of the gaps 61-67, 62-66, 63-65 is negative (the whole clip's and the shut ones);
   - the activations :data:`SHAPES`, ours and Face Landmarker's scores;
4. the whole clip: the correlation and std ratio of our mouth opening with the reference's,
   and of our jawOpen with Face Landmarker's (the open-mouth amplitude must stay).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_shut_mouth.py --out out/shut
        [--clips driving_d9,driving_d6]

Writes ``OUT/shut_mouth.json`` and ``OUT/shut_mouth.png`` and prints a table.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import _mp_points as mp  # noqa: E402
import _report as rep  # noqa: E402
import bench_capture as bc  # noqa: E402
from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402

log = logging.getLogger("bench_shut_mouth")

CLIPS = ("driving_d9", "driving_d6", "face_2", "WDA_KatieHill_000")
SHAPES = ("jawOpen", "mouthClose", "mouthRollLower", "mouthRollUpper", "mouthPressLeft",
          "mouthPressRight", "mouthShrugLower", "mouthShrugUpper", "mouthFunnel", "mouthPucker")
#: the Gaussian (frames) separating jitter from wander
WANDER_SIGMA = 3.0


# ------------------------------------------------------------------------------ measures
def shut_segments(opening: np.ndarray, shut: float, min_frames: int, trim: int) -> list:
    """``[(a, b), ...]``: runs ``a:b`` of ``opening`` (F,) below ``shut`` (NaN ends a run) of at
    least ``min_frames`` frames, each less ``trim`` frames at both ends."""
    below = np.nan_to_num(np.asarray(opening, float), nan=np.inf) < shut
    edges = np.flatnonzero(np.diff(np.concatenate([[0], below.astype(int), [0]])))
    return [(int(a) + trim, int(b) - trim) for a, b in zip(edges[::2], edges[1::2])
            if b - a >= min_frames and b - a - 2 * trim >= 3]


def stillness(x: np.ndarray, segments: list) -> dict:
    """Pooled over ``segments`` of ``x`` (F,): ``std`` (about each segment's mean), ``jitter``
    (std of the first difference / sqrt 2), ``wander`` (std of the Gaussian-smoothed signal
    about its mean), ``mean`` and ``min``; None where ``x`` has no finite value there."""
    from scipy.ndimage import gaussian_filter1d

    dev, dif, slow, vals = [], [], [], []
    for a, b in segments:
        s = np.asarray(x[a:b], float)
        if not np.isfinite(s).all():
            continue
        sm = gaussian_filter1d(s, WANDER_SIGMA, mode="nearest")
        dev.append(s - s.mean())
        dif.append(np.diff(s))
        slow.append(sm - sm.mean())
        vals.append(s)
    if not vals:
        return {k: None for k in ("std", "jitter", "wander", "mean", "min")}
    rms = lambda parts: float(np.sqrt(np.mean(np.concatenate(parts) ** 2)))  # noqa: E731
    v = np.concatenate(vals)
    return {"std": rms(dev), "jitter": rms(dif) / np.sqrt(2.0), "wander": rms(slow),
            "mean": float(v.mean()), "min": float(v.min())}


def model_lip_gap_mm(model, track) -> tuple[np.ndarray, np.ndarray]:
    """(F,) twice: the fitted face's inner-lip gap, upper (iBUG 62) minus lower (66) lip vertex
    along the face's up axis (from the chin 8 to the nose bridge 27), in mm (model units: cm),
    and the least of the gaps 61-67, 62-66, 63-65 the same way."""
    lm = np.asarray(model.landmarks)
    out, low = np.full(track.n_frames, np.nan), np.full(track.n_frames, np.nan)
    for i in range(track.n_frames):
        V = model.synthesize(track.weights_at(i))[lm]
        up = V[27] - V[8]
        g = 10.0 * (V[[61, 62, 63]] - V[[67, 66, 65]]) @ (up / np.linalg.norm(up))
        out[i], low[i] = g[1], g.min()
    return out, low


def _ratio(a, b):
    return None if a is None or b is None or b <= 0 else a / b


def clip_measures(name: str, vdir: Path, cache: Path, model, args) -> dict:
    """Track one clip, run the peer, and measure its shut segments (module notes)."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.capture import capture_video

    video = vdir / f"{name}.mp4"
    with np.load(vdir / f"{name}.mediapipe478.npz") as z:
        ref = np.asarray(z["landmarks"], float)[..., :2]
    with filtered_stderr(True):
        pts, shapes = cached_landmarker(video, cache, shown=True)
        t0 = time.perf_counter()
        tr = capture_video(str(video), model)
    sec = time.perf_counter() - t0
    F = tr.n_frames
    ref, pts, shapes = ref[:F], np.asarray(pts, float)[:F, :, :2], np.asarray(shapes, float)[:F]
    ro, fo = mp.measure(ref, mp.MOUTH_OPEN), mp.measure(pts, mp.MOUTH_OPEN)
    oo = bc.openings(tr.landmarks2d)["mouth_open"]
    iod_px = np.linalg.norm(ref[:, mp.EYE_CORNERS[0]] - ref[:, mp.EYE_CORNERS[1]], axis=1)
    gap_mm, low_mm = model_lip_gap_mm(model, tr)
    segs = shut_segments(ro, args.shut, args.min_frames, args.trim)
    A = np.asarray(tr.blendshapes, float)
    out = {"frames": F, "seconds": round(sec, 1), "segments": segs,
           "shut_frames": int(sum(b - a for a, b in segs)),
           "iod_px": float(np.nanmedian(iod_px)),
           "mouth": {"reference": stillness(ro, segs), "face_landmarker": stillness(fo, segs),
                     "ours": stillness(oo, segs), "ours_px": stillness(oo * iod_px, segs),
                     "ours_model_mm": stillness(gap_mm, segs)},
           "crossed_frames": int(np.sum(low_mm < 0)),
           "crossed_shut_frames": int(sum(np.sum(low_mm[a:b] < 0) for a, b in segs)),
           "lowest_gap_mm": float(np.nanmin(low_mm)),
           "shapes": {}, "whole": {
               "r_mouth": bc.corr(oo, ro), "sr_mouth": bc.std_ratio(oo, ro),
               "r_jawOpen": bc.corr(A[:, ARKIT_NAMES.index("jawOpen")],
                                    shapes[:, ARKIT_NAMES.index("jawOpen")]),
               "sr_jawOpen": bc.std_ratio(A[:, ARKIT_NAMES.index("jawOpen")],
                                          shapes[:, ARKIT_NAMES.index("jawOpen")])}}
    for n in SHAPES:
        k = ARKIT_NAMES.index(n)
        out["shapes"][n] = {"ours": stillness(A[:, k], segs),
                            "face_landmarker": stillness(shapes[:, k], segs)}
    m = out["mouth"]
    out["ratios"] = {f"mouth_{q}_vs_reference": _ratio(m["ours"][q], m["reference"][q])
                     for q in ("std", "jitter", "wander")}
    j = out["shapes"]["jawOpen"]
    out["ratios"] |= {f"jawOpen_{q}_vs_face_landmarker": _ratio(j["ours"][q],
                                                                j["face_landmarker"][q])
                      for q in ("std", "jitter", "wander")}
    out["series"] = {"reference": ro, "face_landmarker": fo, "ours": oo,
                     "jaw_ours": A[:, ARKIT_NAMES.index("jawOpen")],
                     "jaw_face_landmarker": shapes[:, ARKIT_NAMES.index("jawOpen")]}
    return out


# ------------------------------------------------------------------------------ report
def _f(x, k=4):
    return "–" if x is None else f"{x:.{k}f}"


def print_table(res: dict) -> None:
    """Per clip: the mouth opening's and the jaw's stillness, ours / Face Landmarker /
    reference on the same shut frames."""
    print("shut segments: std / jitter / wander (mouth opening in eye-corner distances)")
    for name, c in res["clips"].items():
        m, s = c["mouth"], c["shapes"]
        print(f"{name}: {len(c['segments'])} segments, {c['shut_frames']} frames, "
              f"whole clip r mouth {_f(c['whole']['r_mouth'], 3)} sr "
              f"{_f(c['whole']['sr_mouth'], 2)}, r jawOpen {_f(c['whole']['r_jawOpen'], 3)} "
              f"sr {_f(c['whole']['sr_jawOpen'], 2)}; lips crossed on {c['crossed_frames']} "
              f"frames ({c['crossed_shut_frames']} shut), lowest gap "
              f"{_f(c['lowest_gap_mm'], 2)} mm")
        if not c["segments"]:
            continue
        for label, key in (("mouth ours", "ours"), ("mouth Face Landmarker", "face_landmarker"),
                           ("mouth reference", "reference"), ("mouth ours, px", "ours_px"),
                           ("mouth ours, model mm", "ours_model_mm")):
            q = m[key]
            print(f"  {label:24s} {_f(q['std'])} / {_f(q['jitter'])} / {_f(q['wander'])}"
                  f"  mean {_f(q['mean'])} min {_f(q['min'])}")
        for n, q in s.items():
            o, p = q["ours"], q["face_landmarker"]
            print(f"  {n:24s} ours {_f(o['std'])} / {_f(o['jitter'])} / {_f(o['wander'])}"
                  f"  FL {_f(p['std'])} / {_f(p['jitter'])} / {_f(p['wander'])}")
        print("  ratios " + ", ".join(f"{k} {_f(v, 2)}" for k, v in c["ratios"].items()))


def plot(res: dict, path: Path) -> None:
    """Per clip: the mouth opening (ours, Face Landmarker, reference) with the shut segments
    shaded, and jawOpen (ours, Face Landmarker's score)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    clips = res["clips"]
    fig, axes = plt.subplots(2 * len(clips), 1, figsize=(13, 3.2 * len(clips)), squeeze=False)
    for r, (name, c) in enumerate(clips.items()):
        s = c["series"]
        a0, a1 = axes[2 * r, 0], axes[2 * r + 1, 0]
        for key, lab in (("ours", "ours 62-66"), ("face_landmarker", "Face Landmarker 13-14"),
                         ("reference", "reference 13-14")):
            a0.plot(s[key], lw=0.8, label=lab)
        a1.plot(s["jaw_ours"], lw=0.8, label="ours jawOpen")
        a1.plot(s["jaw_face_landmarker"], lw=0.8, label="Face Landmarker jawOpen")
        for a, b in c["segments"]:
            for ax in (a0, a1):
                ax.axvspan(a, b, color="0.85", zorder=0)
        a0.set_ylim(0, 0.06)
        a1.set_ylim(0, 0.25)
        a0.set_title(f"{name}: mouth opening / eye-corner distance (shut segments grey)",
                     fontsize=9)
        a1.set_title(f"{name}: jawOpen", fontsize=9)
        a0.legend(fontsize=7, loc="upper right")
        a1.legend(fontsize=7, loc="upper right")
    rep.save_plot(fig, path)


def _jsonable(res: dict) -> dict:
    out = {k: v for k, v in res.items() if k != "clips"}
    out["clips"] = {n: {k: v for k, v in c.items() if k != "series"}
                    for n, c in res["clips"].items()}
    return out


def main(argv=None) -> int:
    ap = rep.arguments(__doc__)
    ap.add_argument("--clips", default=",".join(CLIPS))
    ap.add_argument("--shut", type=float, default=0.012,
                    help="the reference's mouth opening (/ eye corners) below which it is shut")
    ap.add_argument("--min-frames", type=int, default=15)
    ap.add_argument("--trim", type=int, default=3)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s",
                        datefmt="%H:%M:%S")
    from facetransfer.default_model import load_default_model

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vdir = bc._data_dir() / "video"
    model = load_default_model()
    res = {"benchmark": "shut mouth (issue 12)", "date": time.strftime("%Y-%m-%d %H:%M:%S"),
           "settings": {"shut": args.shut, "min_frames": args.min_frames, "trim": args.trim,
                        "wander_sigma": WANDER_SIGMA}, "clips": {}}
    for name in [c for c in args.clips.split(",") if c]:
        if not (vdir / f"{name}.mp4").is_file():
            log.warning("clip %s missing; skipped", name)
            continue
        res["clips"][name] = clip_measures(name, vdir, out / "cache", model, args)
        log.info("%s: %s", name, res["clips"][name]["ratios"])
    rep.save_json(_jsonable(res), out / "shut_mouth.json")
    plot(res, out / "shut_mouth.png")
    print_table(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())

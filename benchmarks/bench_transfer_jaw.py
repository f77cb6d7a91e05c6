"""Why the judge's jawOpen missed on the open-mouth pair (issue 13): ceiling, geometry, timing.

``bench_transfer_judge.py`` found MediaPipe's jawOpen of the result following the source's with
r +0.53 only on ``WDA_KatieHill_000`` -> ``driving_d6`` (mouth opening +0.94). This script
measures where that comes from, per frame, with MediaPipe Face Landmarker (VIDEO mode,
blendshapes, the 478 points) on the source (the frame matched by time), the target and the
result of the default transfer:

* **geometry**: besides jawOpen, the inner lip gap (points 13-14) and the chin drop (chin 152 to
  the nose tip 4), both over the outer eye-corner distance (33-263), of each panel, and their
  correlations result ~ source; MediaPipe's jawOpen regressed on a panel's own lip gap and chin
  drop (how much of the learned score the geometry explains, per clip);
* **ceiling**: self-reenactment, the source transferred onto itself (``self``: target = source
  = ``WDA_KatieHill_000``, tracks as for the pairs: what the model fit and the re-render lose)
  and onto its own earlier frames (``self_late``: ``WDA_KatieHill_000`` from frame 100 on onto
  its first 100 frames, and ``self_early`` the other way round: the same face, the target's
  own head pose kept, as in any transfer; ``self_early`` has the open pair's source frames);
* **source segment**: ``open_late``, the open-mouth pair with the source's frames 100-199
  (where its head does not turn) onto ``driving_d6``; ``open_shift``, the pair's source onto
  ``driving_d6`` from its frame 300 on (whether a disagreement stays with the source's
  time or moves with the target's);
* **head turn**: MediaPipe's jawOpen of the source fitted by its lip gap and its head turn
  (nose tip offset), and the ``source_turn`` variant (the source's head rotation added to the
  target's: what the judge gives when the result turns its head with the source);
* **source only**: on the source's own frames, MediaPipe's jawOpen against the capture
  tracker's jawOpen and against MediaPipe's lip gap and chin drop;
* **timing**: correlations at frame lags -4..4 (a 25 -> 30 fps mismatch would peak off 0);
* variants of the render (``--variants``): ``default`` (the rewrite's default: the chin and
  jaw textured from a closed-mouth target frame, :mod:`facetransfer.jaw`), ``jaw_frame`` (the
  jaw textured from each target frame, as before that), and probes of ``jaw_frame``:
  ``mouth_function`` (the §6 texture function for the mouth), ``no_mouth`` (the mouth
  textured from the target like the rest of the face: what the source's mouth pixels add),
  ``source_turn`` (see above), ``mp_mouth`` (the jaw and lip activations of the new
  performance replaced by MediaPipe's scores of the source: whether the capture's split of a
  mouth opening into jaw and lips is what the judge disagrees with) and ``constant_texture``
  (one face texture for the clip);
* the target's share: the result's score regressed on the source's and the target's
  (standardised), since source and target can correlate by chance (``source_target``).

Usage::

    python benchmarks/bench_transfer_jaw.py --out out/benchmarks [--pairs open,self,demo,fps]

Writes ``OUT/transfer_jaw.json``, ``OUT/transfer_jaw.png`` (time series of jawOpen, lip gap and
chin drop of source / target / result per pair) and caches the MediaPipe outputs of each
rendered variant in ``OUT/jaw_cache/`` (``--fresh`` recomputes); tracks are shared with
``bench_transfer_judge.py`` in ``OUT/judge_pairs/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _mp_video import filtered_stderr  # noqa: E402  (the benchmarks folder)

#: name -> (source clip, target clip)
PAIRS = {"open": ("WDA_KatieHill_000", "driving_d6"),
         "self": ("WDA_KatieHill_000", "WDA_KatieHill_000"),
         "self_late": ("WDA_KatieHill_000@100", "WDA_KatieHill_000"),
         "self_early": ("WDA_KatieHill_000", "WDA_KatieHill_000@100"),
         "open_late": ("WDA_KatieHill_000@100", "driving_d6"),
         "open_shift": ("WDA_KatieHill_000", "driving_d6@300"),
         "demo": ("driving_d6", "WDA_KatieHill_000"),
         "fps": ("driving_d9", "face_2")}
FRAMES = 120
#: pairs judged on fewer frames (the source clip's remaining length)
PAIR_FRAMES = {"self_late": 100, "self_early": 100, "open_late": 118}
LAGS = range(-4, 5)
#: MediaPipe points: inner lips, chin, nose tip, outer eye corners
LIP_UP, LIP_LO, CHIN, NOSE, EYE_R, EYE_L = 13, 14, 152, 4, 33, 263
#: MediaPipe's nose bridge between the eyes (the upper end of the 3-D jaw measure)
BRIDGE = 6


def landmarker(frames, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """MediaPipe's blendshapes ``(F, 51)`` and points ``(F, 478, 3)`` of frames in VIDEO mode
    (:func:`facetransfer.fidelity.landmarker_scores`)."""
    from facetransfer.fidelity import landmarker_scores

    return landmarker_scores(frames, fps)


def geometry(pts: np.ndarray, size: tuple[int, int]) -> dict:
    """Lip gap, chin drop and head turn ``(F,)`` of MediaPipe points ``(F, 478, 2)``
    (normalised coordinates of frames ``size`` = (W, H)), over the outer eye-corner distance;
    the turn is the nose tip's horizontal offset from the eye corners' midpoint (a yaw of
    about 20 degrees moves it by about 0.25); ``jaw_3d`` the 3-D distance of the chin (152)
    from the nose bridge (6) over the 3-D eye-corner distance (MediaPipe's depth included: no
    change with the head's rotation, unlike the 2-D chin drop)."""
    P = pts[..., :2] * np.asarray(size, float)
    eye = np.linalg.norm(P[:, EYE_R] - P[:, EYE_L], axis=1)
    mid = (P[:, EYE_R] + P[:, EYE_L]) / 2
    Q = pts * np.asarray([size[0], size[1], size[0]], float)
    eye3 = np.linalg.norm(Q[:, EYE_R] - Q[:, EYE_L], axis=1)
    return {"lip_gap": np.linalg.norm(P[:, LIP_UP] - P[:, LIP_LO], axis=1) / eye,
            "chin_drop": np.linalg.norm(P[:, CHIN] - P[:, NOSE], axis=1) / eye,
            "jaw_3d": np.linalg.norm(Q[:, CHIN] - Q[:, BRIDGE], axis=1) / eye3,
            "turn": (P[:, NOSE, 0] - mid[:, 0]) / eye}


def corr(a, b) -> float:
    from facetransfer.fidelity import correlation

    return correlation(np.asarray(a, float), np.asarray(b, float))


def lagged(a: np.ndarray, b: np.ndarray) -> dict:
    """Correlation of ``a[t]`` with ``b[t - lag]`` for each lag in :data:`LAGS`."""
    out = {}
    n = len(a)
    for k in LAGS:
        if k >= 0:
            out[k] = corr(a[k:], b[:n - k])
        else:
            out[k] = corr(a[:n + k], b[-k:])
    return out


def explained(jaw: np.ndarray, geo: dict) -> float:
    """r of MediaPipe's jawOpen with its least-squares fit from the same panel's lip gap and
    chin drop (how much of the learned score this clip's geometry explains)."""
    X = np.column_stack([geo["lip_gap"], geo["chin_drop"], np.ones_like(jaw)])
    ok = np.isfinite(X).all(1) & np.isfinite(jaw)
    if ok.sum() < 5:
        return float("nan")
    coef = np.linalg.lstsq(X[ok], jaw[ok], rcond=None)[0]
    return corr(X[ok] @ coef, jaw[ok])


# ---------------------------------------------------------------------------------------------
# rendering and judging one pair
# ---------------------------------------------------------------------------------------------

#: variant -> (RewriteOptions keywords, whether the source's mouth pixels are used)
#: the variants rendered per pair unless ``--variants`` is given
PAIR_VARIANTS = {"open": ("default", "jaw_frame", "mouth_function", "no_mouth", "source_turn",
                          "mp_mouth", "constant_texture")}
#: variant -> (RewriteOptions keywords, whether the source's mouth pixels are used). ``default``
#: is the rewrite's default (the jaw from a closed-mouth frame, :mod:`facetransfer.jaw`);
#: ``jaw_frame`` the jaw textured from each target frame as before; the probes are variants of
#: ``jaw_frame`` (what was measured to find the cause)
VARIANTS = {"default": ({}, True),
            "jaw_frame": ({"jaw": "frame"}, True),
            "mouth_function": ({"mouth": "function", "jaw": "frame"}, True),
            "no_mouth": ({"jaw": "frame"}, False),
            "source_turn": ({"jaw": "frame"}, True),
            "mp_mouth": ({"jaw": "frame"}, True),
            "constant_texture": ({"texture": "constant"}, True)}
#: the shapes the ``mp_mouth`` probe takes from MediaPipe's scores of the source
MP_MOUTH = ("jawOpen", "mouthClose", "mouthUpperUpLeft", "mouthUpperUpRight",
            "mouthLowerDownLeft", "mouthLowerDownRight")


def _clip(clip: str, out: Path, data: Path) -> tuple[Path, str]:
    """The video of a clip name and the name of its track; ``NAME@K``: the clip from its
    frame K on, written once (H.264 CRF 0) to ``OUT/jaw_clips/``."""
    if "@" not in clip:
        return data / f"{clip}.mp4", clip
    from facetransfer.io.video import VideoOptions, read_video, write_video

    base, k = clip.split("@")
    path = out / "jaw_clips" / f"{base}_from{k}.mp4"
    if not path.is_file():
        frames, fps = read_video(data / f"{base}.mp4", start=int(k), stop=int(k) + 200)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_video(path, frames, fps, options=VideoOptions(crf=0))
    return path, path.stem


def _plan(name: str, model, out: Path, data: Path, frames: int):
    from bench_transfer_judge import _track

    from facetransfer import transfer_plan as tp

    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    (src, sname), (tgt, tname) = (_clip(c, out, data) for c in PAIRS[name])
    return tp.plan_transfer(tgt, model, expression_from=src, max_frames=frames,
                            target_track=_track(tname, model, cache, tgt.parent),
                            expression_track=_track(sname, model, cache, src.parent))


def render(plan, model, variant: str, mp_source: np.ndarray | None = None) -> list[np.ndarray]:
    """The result frames of one variant (:data:`VARIANTS`), before encoding (``mp_source``:
    MediaPipe's ``(n, 51)`` scores of the time-matched source, for ``mp_mouth``)."""
    from facetransfer.rewrite_clip import MouthSource, rewrite_frames
    from facetransfer.rewrite_options import RewriteOptions

    kw, with_mouth = VARIANTS[variant]
    opts = RewriteOptions(**kw).with_(mouth=kw.get("mouth", "frame"))
    mouth = MouthSource(plan.mouth_frames, plan.mouth_track, plan.mouth_index) \
        if with_mouth else MouthSource()
    if opts.mouth == "function":
        mouth = dataclasses.replace(mouth, function=plan.mouth_function(model))
    new = {"source_turn": lambda: source_turned(plan),
           "mp_mouth": lambda: mp_mouth(plan, model, mp_source)}.get(variant,
                                                                     lambda: plan.new_track)()
    return [r.image for r in rewrite_frames(plan.target_frames, plan.target_track,
                                            new, model, mouth_source=mouth, options=opts)]


def mp_mouth(plan, model, mp_source: np.ndarray):
    """The new performance with the activations of :data:`MP_MOUTH` (jaw, lip closure, upper
    lip raise, lower lip drop) replaced by MediaPipe's scores of the source (a probe: the
    capture's split of a mouth opening into jaw and lips against MediaPipe's)."""
    import dataclasses

    from facetransfer.arkit import ARKIT_NAMES, activation_basis

    tr = plan.new_track
    idx = [ARKIT_NAMES.index(n) for n in MP_MOUTH]
    a = np.asarray(tr.blendshapes, float)
    mp = np.where(np.isfinite(mp_source[:, idx]), mp_source[:, idx], a[:, idx])
    _, D = activation_basis(model)
    w = dict(tr.weights)
    w["expression"] = w["expression"] + (mp - a[:, idx]) @ D[idx]
    b = a.copy()
    b[:, idx] = mp
    return dataclasses.replace(tr, weights=w, blendshapes=b.astype(np.float32))


def source_turned(plan):
    """The new performance with the source's head rotation on top of the target's: the
    source's rotation at each output frame relative to its mean rotation, composed with the
    target's (a probe of the judge: MediaPipe then sees the source's head turns too)."""
    import dataclasses

    from scipy.spatial.transform import Rotation

    Rs = Rotation.from_matrix(plan.mouth_track.rotation[:plan.n_frames])
    rel = Rs * Rs.mean().inv()
    Rt = Rotation.from_matrix(plan.new_track.rotation)
    return dataclasses.replace(plan.new_track, rotation=(rel * Rt).as_matrix())


def _judged(key: str, cache: Path, fresh: bool, frames_fn, fps: float, size):
    """MediaPipe's shapes and points of a frame sequence, cached as ``cache/key.npz``."""
    p = cache / f"{key}.v2.npz"
    if p.is_file() and not fresh:
        d = np.load(p)
        return d["shapes"], d["points"]
    from facetransfer.io.atomic import atomic_path

    shapes, pts = landmarker(frames_fn(), fps)
    cache.mkdir(parents=True, exist_ok=True)
    with atomic_path(p, overwrite=True) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, shapes=shapes, points=pts, size=np.asarray(size))
    return shapes, pts


def _panel(shapes: np.ndarray, pts: np.ndarray, size) -> dict:
    from facetransfer.arkit import MEDIAPIPE_NAMES

    return {"jawOpen": shapes[:, MEDIAPIPE_NAMES.index("jawOpen")], **geometry(pts, size)}


def measure_pair(name: str, model, out: Path, data: Path, frames: int, variants,
                 fresh: bool) -> dict:
    """All figures of one pair (see the module docstring)."""
    from facetransfer.arkit import ARKIT_NAMES

    t0 = time.perf_counter()
    plan = _plan(name, model, out, data, min(frames, PAIR_FRAMES.get(name, frames)))
    n = plan.n_frames
    cache = out / "jaw_cache" / f"{name}-{n}"
    tsize = plan.target_frames.shape[2], plan.target_frames.shape[1]
    ssize = plan.mouth_frames.shape[2], plan.mouth_frames.shape[1]
    S = _panel(*_judged("source", cache, fresh,
                        lambda: (plan.mouth_frames[plan.mouth_index[i]] for i in range(n)),
                        plan.fps, ssize), ssize)
    T = _panel(*_judged("target", cache, fresh, lambda: plan.target_frames[:n], plan.fps, tsize),
               tsize)
    # the source clip on its own timeline, for the source-only figures
    sfps = plan.source_tracks["expression"].fps
    m = min(len(plan.mouth_frames), plan.source_tracks["expression"].n_frames)
    Sown = _panel(*_judged("source_own", cache, fresh, lambda: plan.mouth_frames[:m], sfps,
                           ssize), ssize)
    cap = np.asarray(plan.source_tracks["expression"].blendshapes, float)[:m,
                                                                          ARKIT_NAMES.index("jawOpen")]
    cap_new = np.asarray(plan.new_track.blendshapes, float)[:n, ARKIT_NAMES.index("jawOpen")] \
        if plan.new_track.blendshapes is not None else np.full(n, np.nan)
    res = {"source": PAIRS[name][0], "target": PAIRS[name][1], "frames": n, "fps": plan.fps,
           "source_only": {
               "mp_jaw~capture_jaw": corr(Sown["jawOpen"], cap),
               "mp_jaw~mp_lip_gap": corr(Sown["jawOpen"], Sown["lip_gap"]),
               "mp_jaw~mp_chin_drop": corr(Sown["jawOpen"], Sown["chin_drop"]),
               "mp_lip_gap~mp_chin_drop": corr(Sown["lip_gap"], Sown["chin_drop"]),
               "mp_jaw~mp_jaw_3d": corr(Sown["jawOpen"], Sown["jaw_3d"]),
               "capture_jaw~mp_jaw_3d": corr(cap, Sown["jaw_3d"]),
               "mp_lip_gap~mp_jaw_3d": corr(Sown["lip_gap"], Sown["jaw_3d"]),
               "capture_jaw~mp_lip_gap": corr(cap, Sown["lip_gap"]),
               "capture_jaw~mp_chin_drop": corr(cap, Sown["chin_drop"]),
               "mp_jaw_explained_by_geometry": explained(Sown["jawOpen"], Sown),
               "frames": m},
           "target_only": {"mp_jaw~mp_lip_gap": corr(T["jawOpen"], T["lip_gap"]),
                           "mp_jaw~mp_jaw_3d": corr(T["jawOpen"], T["jaw_3d"]),
                           "mp_jaw~mp_chin_drop": corr(T["jawOpen"], T["chin_drop"]),
                           "mp_jaw_explained_by_geometry": explained(T["jawOpen"], T)},
           "variants": {}, "series": {"source": _lists(S), "target": _lists(T)}}
    mp_src = _judged("source", cache, False, None, plan.fps, ssize)[0]
    for v in variants:
        R = _panel(*_judged(f"result_{v}", cache, fresh, lambda: render(plan, model, v, mp_src),
                            plan.fps, tsize), tsize)
        res["variants"][v] = _compare(S, T, R, cap_new)
        res["series"][f"result_{v}"] = _lists(R)
    res["series"]["capture_new"] = [float(x) for x in cap_new]
    res["seconds"] = time.perf_counter() - t0
    return res


def _lists(P: dict) -> dict:
    return {k: [float(x) for x in v] for k, v in P.items()}


def _compare(S: dict, T: dict, R: dict, cap_new: np.ndarray) -> dict:
    """Result ~ source / ~ target for jawOpen, lip gap, chin drop and the 3-D jaw; source ~
    target (what the two clips share by chance); the amplitude ratio; the lags; the result's jawOpen against the source's geometry and the new capture jawOpen."""
    out = {}
    for k in ("jawOpen", "lip_gap", "chin_drop", "jaw_3d"):
        out[k] = {"result_source": corr(R[k], S[k]), "result_target": corr(R[k], T[k]),
                  "source_target": corr(S[k], T[k]),
                  "share": shares(R[k], S[k], T[k]),
                  "amplitude": float(np.nanstd(R[k]) / max(np.nanstd(S[k]), 1e-9)),
                  "lags": lagged(R[k], S[k])}
    out["cross"] = {"R_jaw~S_lip_gap": corr(R["jawOpen"], S["lip_gap"]),
                    "R_jaw~S_chin_drop": corr(R["jawOpen"], S["chin_drop"]),
                    "R_jaw~R_lip_gap": corr(R["jawOpen"], R["lip_gap"]),
                    "R_jaw~R_chin_drop": corr(R["jawOpen"], R["chin_drop"]),
                    "R_jaw~R_jaw_3d": corr(R["jawOpen"], R["jaw_3d"]),
                    "R_jaw~S_jaw_3d": corr(R["jawOpen"], S["jaw_3d"]),
                    "R_jaw~T_chin_drop": corr(R["jawOpen"], T["chin_drop"]),
                    "R_jaw~new_capture_jaw": corr(R["jawOpen"], cap_new),
                    "S_jaw~new_capture_jaw": corr(S["jawOpen"], cap_new),
                    "R_jaw_explained_by_R_geometry": explained(R["jawOpen"], R),
                    "S_jaw~S_turn": corr(S["jawOpen"], S["turn"]),
                    "R_jaw~R_turn": corr(R["jawOpen"], R["turn"]),
                    "R_turn~S_turn": corr(R["turn"], S["turn"])}
    out["turn"] = turn_share(S, R)
    out["frontal"] = frontal(S, R)
    return out


#: a source frame is "frontal" when its head turn (nose tip offset) is below this (about 6°)
FRONTAL = 0.08


def frontal(S: dict, R: dict, limit: float = FRONTAL) -> dict:
    """jawOpen and lip gap, result ~ source, over the frames where the source faces the camera
    (``|turn| < limit``) and over the others."""
    t = np.abs(S["turn"])
    out = {"limit": limit, "frames": int(np.sum(t < limit)), "turned_frames": int(np.sum(t >= limit))}
    for k in ("jawOpen", "lip_gap"):
        out[k] = corr(R[k][t < limit], S[k][t < limit])
        out[f"{k}_turned"] = corr(R[k][t >= limit], S[k][t >= limit])
    return out


def shares(r: np.ndarray, s: np.ndarray, t: np.ndarray) -> dict:
    """The result's series regressed on the source's and the target's, all standardised:
    ``{"source": b_s, "target": b_t}`` (the target's share of the result, with the source's
    held fixed: unlike ``result ~ target`` not hidden by a chance correlation of the two)."""
    z = [(x - np.nanmean(x)) / max(np.nanstd(x), 1e-12) for x in (r, s, t)]
    ok = np.isfinite(z[0]) & np.isfinite(z[1]) & np.isfinite(z[2])
    if ok.sum() < 5:
        return {"source": float("nan"), "target": float("nan")}
    b = np.linalg.lstsq(np.column_stack([z[1][ok], z[2][ok]]), z[0][ok], rcond=None)[0]
    return {"source": float(b[0]), "target": float(b[1])}


def turn_share(S: dict, R: dict) -> dict:
    """The head turn's share of the source's jawOpen: ``jawOpen ~ a lip_gap + b turn + c``
    fitted over the source's (time-matched) frames; the result's jawOpen against the source's
    score without its turn term, ``jawOpen - b turn``."""
    j, g, t = S["jawOpen"], S["lip_gap"], S["turn"]
    ok = np.isfinite(j) & np.isfinite(g) & np.isfinite(t)
    X = np.column_stack([g, t, np.ones_like(g)])
    a, b, c = np.linalg.lstsq(X[ok], j[ok], rcond=None)[0]
    X1 = np.column_stack([g, np.ones_like(g)])
    fit1 = X1[ok] @ np.linalg.lstsq(X1[ok], j[ok], rcond=None)[0]
    free = j - b * t
    return {"a_lip_gap": float(a), "b_turn": float(b), "c": float(c),
            "S_jaw~fit(lip_gap)": corr(fit1, j[ok]),
            "S_jaw~fit(lip_gap, turn)": corr(X[ok] @ (a, b, c), j[ok]),
            "S_jaw~S_jaw_without_turn": corr(j, free),
            "R_jaw~S_jaw_without_turn": corr(R["jawOpen"], free)}


def plot(res: dict, path: Path) -> None:
    """Per pair: jawOpen, lip gap and chin drop over frames of source, target and results."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    keys = ("jawOpen", "lip_gap", "chin_drop", "jaw_3d")
    fig, axes = plt.subplots(len(res), 4, figsize=(20, 2.8 * len(res)), squeeze=False)
    colours = {"source": "#08519c", "target": "#a50f15", "result_default": "k",
               "result_jaw_frame": "#fd8d3c"}
    for row, (p, r) in zip(axes, res.items()):
        for ax, k in zip(row, keys):
            for s, c in colours.items():
                if s in r["series"]:
                    v = r["variants"].get(s.removeprefix("result_"))
                    lab = s if v is None else f"{s} (r {v[k]['result_source']:+.2f})"
                    ax.plot(r["series"][s][k], color=c, lw=1.4 if s == "source" else 1,
                            label=lab)
            ax.set_title(f"{p}: {r['source']} -> {r['target']}: {k}", fontsize=9)
            ax.legend(fontsize=6)
        row[0].set_ylabel("MediaPipe")
    for ax in axes[-1]:
        ax.set_xlabel("target frame")
    fig.suptitle("MediaPipe on source (time-matched), target and result: jawOpen, inner lip gap "
                 "(13-14), chin drop (152-4) and 3-D jaw (152-6), over the eye-corner distance")
    fig.tight_layout(rect=(0, 0, 1, 0.985))
    save_figure(fig, path)
    plt.close(fig)


def _print(name: str, r: dict) -> None:
    so = "  ".join(f"{k} {v:+.2f}" for k, v in r["source_only"].items() if k != "frames")
    print(f"{name} source only ({r['source_only']['frames']} frames): {so}", flush=True)
    to = "  ".join(f"{k} {v:+.2f}" for k, v in r["target_only"].items())
    print(f"{name} target only: {to}", flush=True)
    for v, c in r["variants"].items():
        line = "  ".join(f"{k} {c[k]['result_source']:+.2f}/{c[k]['result_target']:+.2f}"
                         f" (s~t {c[k]['source_target']:+.2f}, share t "
                         f"{c[k]['share']['target']:+.2f}) "
                         f"x{c[k]['amplitude']:.2f}" for k in ("jawOpen", "lip_gap", "chin_drop", "jaw_3d"))
        lag = max(c["jawOpen"]["lags"].items(), key=lambda kv: np.nan_to_num(kv[1], nan=-9))
        cross = "  ".join(f"{k} {x:+.2f}" for k, x in {**c["cross"], **c["turn"]}.items())
        cross += "\n    frontal: " + "  ".join(f"{k} {x:+.2f}" if isinstance(x, float) else
                                           f"{k} {x}" for k, x in c["frontal"].items())
        print(f"{name} {v}: {line}  best jaw lag {lag[0]:+d} ({lag[1]:+.2f})\n    {cross}",
              flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--pairs", default=",".join(PAIRS), help=f"of {', '.join(PAIRS)}")
    ap.add_argument("--variants", help=f"of {', '.join(VARIANTS)} (default: all on open, "
                    "default and jaw_frame elsewhere)")
    ap.add_argument("--frames", type=int, default=FRAMES, help="target frames judged")
    ap.add_argument("--fresh", action="store_true", help="re-render and re-judge (no cache)")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model
    from facetransfer.io.atomic import atomic_path

    data = Path(data_dir()) / "video"
    model = load_default_model()
    res = {}
    for name in args.pairs.split(","):
        variants = (args.variants.split(",") if args.variants else
                    PAIR_VARIANTS.get(name, ("default", "jaw_frame")))
        with filtered_stderr():
            res[name] = measure_pair(name, model, out, data, args.frames, variants, args.fresh)
        _print(name, res[name])
    with atomic_path(out / "transfer_jaw.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps({"pairs": res}, indent=1))
    plot(res, out / "transfer_jaw.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

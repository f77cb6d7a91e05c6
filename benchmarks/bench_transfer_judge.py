"""Transfer fidelity by an independent judge (issue 13): MediaPipe on source, target and result.

Runs Face Landmarker (Tasks API, VIDEO mode, blendshapes) on the source (the frame matched by
time), the target and the result of ``facetransfer transfer`` (default model, capture tracker,
default settings) and correlates, over frames, the result's blendshapes (:data:`SHAPES`), the
distances of :data:`GEOMETRY` between its points over the outer eye corners 33-263 (mouth
opening 13-14, eye opening and brow height as ``bench_capture.py`` measures them on real clips)
and gaze (its eyeLook* scores, horizontal and vertical) with the source's and the target's,
with the ratio of their standard deviations (the result's amplitude over the source's). A
transfer carries the source when the result follows the source, at its amplitude, and not the
target.

Three real pairs of the data folder (``--pairs``, default all): the demo pair (``driving_d6``
30 fps onto ``WDA_KatieHill_000`` 25 fps), ``driving_d9`` (30 fps, 512x480) onto ``face_2``
(25 fps, 844²), and ``WDA_KatieHill_000`` onto ``driving_d6`` (the target talking with an open
mouth). Each pair is rendered three times from the same tracks: ``before`` (the eye holes open:
the target's own eyes show through, as before issue 13's eyes), ``after`` (:mod:`facetransfer.eyes`,
the default) and ``eyes_only`` (the eyes as after, the brows textured from each target frame as
before: which share of the brows' change is the texture's).
The result frames are judged as rendered (before encoding). Tracks are cached in
``OUT/judge_pairs/``.

The floor of the leak measures (session 49): a fourth render, ``pure`` (:data:`PURE`: the
new face only, one face texture for the clip and a hard paste, so no pixel of the target's
frames inside the face), is judged like the others. What it still shares with the target is
the target's head pose and the footage around the face, and Face Landmarker's scores follow
the pose beyond the linear pitch and yaw partialled out (the demo's eyeBlinkLeft goes with the
target's pitch, as the target lowers its lids while it looks down). Its partials are the
floor, what a render without the target's pixels scores: each measure of ``before``, ``after``
and ``eyes_only`` gets ``target_partial_floor`` and ``target_partial_pose_floor`` (the pure
render's partials) and ``target_leak`` / ``target_leak_pose``, its partial minus the floor
(what the per-frame texture and the blend, the target's pixels, add; :func:`add_floor`). A
difference of two renders, not a bound: it can be negative. ``--no-floor`` skips the render
(one more render and judging a pair, 20-45 s on two shared cores).

``--video V`` instead judges the three panels of a ``source | target | result`` video (what
``facetransfer demo`` writes).

Usage::

    python benchmarks/bench_transfer_judge.py --out out/benchmarks [--pairs demo,fps,open]
    python benchmarks/bench_transfer_judge.py --out out/benchmarks --no-floor  # no pure render
    python benchmarks/bench_transfer_judge.py --out out/benchmarks --video out/demo.mp4

Writes ``OUT/transfer_judge.json``, ``OUT/transfer_judge.png`` and one contact picture per pair
(``OUT/transfer_judge_PAIR.png``: source | target | before | after | pure at the frames where
the source's eyes are most closed and most open).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _mp_points as mp  # noqa: E402
from _mp_video import filtered_stderr  # noqa: E402

SHAPES = ("jawOpen", "mouthPucker", "mouthSmileLeft", "mouthSmileRight", "browInnerUp",
          "eyeBlinkLeft", "eyeBlinkRight", "eyeWideLeft", "eyeWideRight", "eyeSquintLeft",
          "eyeSquintRight", "browOuterUpLeft", "browOuterUpRight", "browDownLeft",
          "browDownRight")
#: name -> (source clip, target clip); target frames judged: FRAMES
PAIRS = {"demo": ("driving_d6", "WDA_KatieHill_000"),
         "fps": ("driving_d9", "face_2"),
         "open": ("WDA_KatieHill_000", "driving_d6")}
FRAMES = 120
#: The renders of a pair: name -> (the rewrite's options as keywords, the brows from the
#: open-eyed frame). ``pure`` (:data:`PURE`) is the floor's render.
RENDERS = {"before": ({"eyes": "target"}, False), "after": ({"eyes": "model"}, True),
           "eyes_only": ({"eyes": "model"}, False)}
#: The floor's render: the new face only, no pixel of the target's frames inside the face (one
#: face texture for the clip, a hard paste without a blend; leak49's ``pure``).
PURE = ({"eyes": "model", "texture": "constant", "blend": "none"}, True)
#: The partials that get a floor: key -> (the floor's key, the leak's key).
FLOOR_KEYS = {"target_partial": ("target_partial_floor", "target_leak"),
              "target_partial_pose": ("target_partial_pose_floor", "target_leak_pose")}


#: Distances between MediaPipe's points over the outer eye corners (33-263), the capture
#: benchmark's real-clip measures (issue 12; :mod:`_mp_points`): name -> pairs of points,
#: averaged.
GEOMETRY = {"mouth_opening": mp.MOUTH_OPEN,
            "eye_opening_right": mp.LIDS["Right"], "eye_opening_left": mp.LIDS["Left"],
            "brow_height_right": mp.BROWS["Right"], "brow_height_left": mp.BROWS["Left"]}


def scores(frames, fps: float, sar: tuple[int, int] = (1, 1)):
    """Face Landmarker's blendshapes ``(F, 51)`` and the :data:`GEOMETRY` measures
    ``{name: (F,)}`` of a frame sequence (:func:`facetransfer.fidelity.landmarker_scores`),
    seen at its shown shape: frames of a sample aspect ratio ``sar`` other than 1:1 resampled
    to square pixels here (as the tracker sees them; done by the script, so that it judges an
    older tree's results alike)."""
    from facetransfer.fidelity import landmarker_scores

    with filtered_stderr():                    # MediaPipe's native log lines
        shapes, P = landmarker_scores(_shown(frames, sar), fps)
    return shapes, {name: mp.measure(P, pairs) for name, pairs in GEOMETRY.items()}


def _shown(frames, sar: tuple[int, int]):
    """``frames`` resampled to square pixels (:func:`_mp_video.shown_frames`)."""
    from _mp_video import shown_frames

    return frames if tuple(sar) == (1, 1) else list(shown_frames(frames, sar))


def compare(S, T, R, pose: np.ndarray | None = None) -> dict:
    """Correlations of the result's scores with the source's and the target's, per measure,
    the amplitude ratio (the result's standard deviation over the source's), and the
    controls: ``source_target``, the source's with the target's (two clips' signals correlated
    by chance, which a result between them inherits); ``target_partial``, the result's with
    the target's once the source is partialled out; with the target's head ``pose`` (F, 2)
    (pitch, yaw in degrees), ``target_partial_pose``, once the pose is partialled out too
    (the result keeps the target's pose, and the detector's brows and gaze move with it)."""
    from facetransfer.arkit import MEDIAPIPE_NAMES
    from facetransfer.fidelity import gaze

    (S, Sg), (T, Tg), (R, Rg) = S, T, R
    out = {}
    for n in SHAPES:
        k = MEDIAPIPE_NAMES.index(n)
        out[n] = _measure(S[:, k], T[:, k], R[:, k], pose)
    for n in GEOMETRY:
        out[n] = _measure(Sg[n], Tg[n], Rg[n], pose)
    for j, name in enumerate(("gaze_horizontal", "gaze_vertical")):
        out[name] = _measure(gaze(S)[:, j], gaze(T)[:, j], gaze(R)[:, j], pose)
    return out


def _measure(s: np.ndarray, t: np.ndarray, r: np.ndarray, pose: np.ndarray | None = None
             ) -> dict:
    """One measure of :func:`compare` from its source, target and result series (F,)."""
    from facetransfer.fidelity import correlation as corr

    out = {"result_source": corr(r, s), "result_target": corr(r, t), "source_target": corr(s, t),
           "target_partial": _partial(r, t, [s]),
           "amplitude": float(np.nanstd(r) / max(np.nanstd(s), 1e-9))}
    if pose is not None:
        out["target_partial_pose"] = _partial(r, t, [s, *np.asarray(pose, np.float64).T])
    return out


def _partial(r: np.ndarray, t: np.ndarray, controls: list) -> float:
    """The correlation of ``r`` and ``t`` (F,) once the ``controls`` (each (F,)) and a constant
    are regressed out of both (least squares over the frames where all are finite); NaN where
    fewer than 8 frames are or a residual is constant."""
    X = np.column_stack([np.ones(len(r)), *controls]).astype(np.float64)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(r) & np.isfinite(t)
    if ok.sum() < 8:
        return float("nan")
    X, a, b = X[ok], np.asarray(r, np.float64)[ok], np.asarray(t, np.float64)[ok]
    ea = a - X @ np.linalg.lstsq(X, a, rcond=None)[0]
    eb = b - X @ np.linalg.lstsq(X, b, rcond=None)[0]
    den = np.sqrt((ea @ ea) * (eb @ eb))
    return float(ea @ eb / den) if den > 1e-12 else float("nan")


def add_floor(judged: dict, pure: dict) -> dict:
    """``judged`` (a render's measures, :func:`compare`) with the floor of each partial of
    :data:`FLOOR_KEYS` from ``pure`` (the pure render's measures): ``target_partial_floor``,
    ``target_partial_pose_floor``, and ``target_leak`` / ``target_leak_pose`` = the partial
    minus its floor (NaN where either is NaN). A new dict; the keys already there unchanged."""
    out = {}
    for name, m in judged.items():
        m = dict(m)
        for key, (floor_key, leak_key) in FLOOR_KEYS.items():
            if key in m and key in pure.get(name, {}):
                m[floor_key] = float(pure[name][key])
                m[leak_key] = float(m[key]) - m[floor_key]
        out[name] = m
    return out


def largest_leaks(judged: dict, key: str = "target_leak", top: int = 4) -> list:
    """The ``top`` measures of ``judged`` (:func:`add_floor`'s) with the largest ``key``, as
    ``(name, value)`` largest first; NaN left out."""
    rows = [(n, float(m[key])) for n, m in judged.items() if np.isfinite(m.get(key, np.nan))]
    return sorted(rows, key=lambda r: -r[1])[:top]


def judge_video(video: Path) -> dict:
    """The judge on the three panels of a ``source | target | result`` video."""
    from facetransfer.io.video import iter_frames, video_info

    info = video_info(video)
    w = info.size[0] // 3
    S, T, R = (scores((f[:, k * w:(k + 1) * w] for f in iter_frames(video)), info.fps)
               for k in range(3))
    return compare(S, T, R)


def _track(clip: str, model, cache: Path, data: Path, every: int = 1, eyes: bool = False
           ) -> Path:
    """The cached track file of ``clip`` (its first 150 frames, the capture tracker, its
    detector shown one frame of ``every``, with ``eyes`` the frames where the eyes move too,
    :mod:`facetransfer.track.skip_rule`; made afresh, not taken from the track cache)."""
    from facetransfer.track.obtain import obtain_track

    name = "" if every == 1 else f".every{every}" + ("eyes" if eyes else "")
    p = cache / f"{clip}{name}.track.npz"
    if not p.exists():
        tr = obtain_track(data / f"{clip}.mp4", model, max_frames=150, cache=False,
                          detect_every=every, detect_eyes=eyes)
        tr.save(p, overwrite=True)
    return p


@contextlib.contextmanager
def _brows(brows: bool):
    """The ablation ``eyes_only``: the brows textured from each target frame (as before), the
    eyes from the open-eyed frame (:func:`facetransfer.eyes.eye_texture` with ``brows=False``)."""
    import facetransfer.region_views as ev  # the name the rewrite's eye textures call

    original = ev.eye_texture
    if not brows:
        ev.eye_texture = functools.partial(original, brows=False)
    try:
        yield
    finally:
        ev.eye_texture = original


def _render(plan, model, options: dict, brows: bool) -> tuple[list, float]:
    """The frames of ``plan`` rendered with the rewrite's ``options`` (keywords of
    :class:`facetransfer.rewrite_options.RewriteOptions`; ``brows``: :func:`_brows`) as
    rendered (before encoding), and the seconds it took."""
    import tempfile

    from facetransfer import video_transfer as vt
    from facetransfer.rewrite_options import RewriteOptions

    frames: list[np.ndarray] = []
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, _brows(brows):
        vt.render_plan(plan, model, vt.RenderTarget(Path(tmp) / "r.mp4", overwrite=True),
                       options=RewriteOptions(**options),
                       compose=lambda i, r: frames.append(r.image) or r.image)
    return frames, time.perf_counter() - t


def judge_pair(name: str, model, out: Path, data: Path, frames: int = FRAMES,
               every: int | None = None, floor: bool = True) -> dict:
    """Render one pair as :data:`RENDERS` (and, with ``floor``, :data:`PURE`) and judge each;
    the clips tracked as the transfer tracks them (the detector shown one frame of ``every``,
    default the default speed preset's, :data:`facetransfer.track.presets.DETECT_EVERY`; the
    source's also where the eyes move). With ``floor`` the pure render's block ``pure`` and
    each other block's floor and leak (:func:`add_floor`)."""
    from facetransfer import transfer_plan as tp
    from facetransfer.export.common import head_euler
    from facetransfer.io.video import video_info
    from facetransfer.track.presets import DEFAULT_SPEED, DETECT_EVERY

    every = DETECT_EVERY[DEFAULT_SPEED] if every is None else int(every)
    src, tgt = PAIRS[name]
    cache = out / "judge_pairs"
    cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with filtered_stderr():                    # MediaPipe's native log lines
        plan = tp.plan_transfer(data / f"{tgt}.mp4", model,
                                expression_from=data / f"{src}.mp4", max_frames=frames,
                                target_track=_track(tgt, model, cache, data, every),
                                expression_track=_track(src, model, cache, data, every, True))
    n = plan.n_frames
    source = [plan.mouth_frames[plan.mouth_index[i]] for i in range(n)]
    target = [plan.target_frames[i] for i in range(n)]
    res, seconds = {}, {"plan": time.perf_counter() - t0}
    for kind, (options, brows) in {**RENDERS, **({"pure": PURE} if floor else {})}.items():
        res[kind], seconds[kind] = _render(plan, model, options, brows)
    t = time.perf_counter()
    sar = {c: video_info(data / f"{c}.mp4").sar for c in (src, tgt)}
    S, T = scores(source, plan.fps, sar[src]), scores(target, plan.fps, sar[tgt])
    pose = np.degrees(head_euler(plan.target_track.rotation[:n])[:, [1, 0]])  # pitch, yaw
    judged = {k: compare(S, T, scores(v, plan.fps, sar[tgt]), pose) for k, v in res.items()}
    if floor:
        judged.update({k: add_floor(v, judged["pure"]) for k, v in judged.items() if k in RENDERS})
    seconds["judge"] = time.perf_counter() - t
    _picture(name, source, target, res, S[0], out / f"transfer_judge_{name}.png")
    return {"source": src, "target": tgt, "frames": n, "fps": plan.fps, "seconds": seconds,
            **judged}


def _picture(name, source, target, res, S, path: Path) -> None:
    """source | target | before | after (| pure, if rendered) at the source's most closed and
    most open eyes."""
    import cv2

    from facetransfer.arkit import MEDIAPIPE_NAMES
    from facetransfer.io.atomic import atomic_path

    blink = np.nanmean(S[:, [MEDIAPIPE_NAMES.index("eyeBlinkLeft"),
                             MEDIAPIPE_NAMES.index("eyeBlinkRight")]], axis=1)
    blink = np.where(np.isfinite(blink), blink, 0.5)
    kinds = [k for k in ("before", "after", "pure") if k in res]
    rows = []
    for i in (int(np.argmax(blink)), int(np.argmin(blink))):
        h = 320
        tiles = [cv2.resize(np.asarray(f), (int(round(f.shape[1] * h / f.shape[0])), h),
                            interpolation=cv2.INTER_AREA)
                 for f in (source[i], target[i], *(res[k][i] for k in kinds))]
        row = np.concatenate(tiles, axis=1)
        cv2.putText(row, f"{name} frame {i}: " + " | ".join(["source", "target", *kinds]),
                    (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 2)
        rows.append(row)
    W = max(r.shape[1] for r in rows)
    img = np.concatenate([np.pad(r, ((0, 0), (0, W - r.shape[1]), (0, 0))) for r in rows])
    with atomic_path(path, overwrite=True) as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def decorate(ax, names, title: str, *, target_line: bool = True) -> None:
    """A judge's axes: the issue's lines (0.8 and 0.6 with the source; 0.3 with the target),
    the measures' ``names`` below their bars, r from -1 to 1."""
    ax.axhline(0.8, color="g", ls=":", lw=1)
    ax.axhline(0.6, color="g", ls="--", lw=0.8)
    if target_line:
        ax.axhline(0.3, color="r", ls=":", lw=1)
    ax.set_xticks(np.arange(len(names)), names, rotation=20, ha="right")
    ax.set_ylim(-1, 1)
    ax.set_ylabel("r over frames")
    ax.set_title(title)


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facetransfer.io.atomic import save_figure

    pairs = list(res)
    names = list(next(iter(res.values()))["after"])
    size = (max(11.0, 0.6 * len(names)), 3.2 * len(pairs))
    fig, axes = plt.subplots(len(pairs), 1, figsize=size, squeeze=False)
    x = np.arange(len(names))
    for ax, p in zip(axes[:, 0], pairs):
        for j, (kind, key, c) in enumerate((("before", "result_source", "#9ecae1"),
                                            ("after", "result_source", "#08519c"),
                                            ("before", "result_target", "#fcbba1"),
                                            ("after", "result_target", "#a50f15"))):
            ax.bar(x - 0.3 + 0.2 * j, [res[p][kind][n][key] for n in names], 0.2, color=c,
                   label=f"{kind}: result ~ {key.split('_')[1]}")
        _plot_floor(ax, x + 0.3, res[p]["after"], names)
        decorate(ax, names, f"{p}: {res[p]['source']} -> {res[p]['target']} "
                 f"({res[p]['frames']} frames)")
    axes[0, 0].legend(fontsize=7, ncol=3, loc="lower left")
    fig.suptitle("transfer fidelity judged by MediaPipe (targets: >= 0.8 / 0.6 with the source, "
                 "<= 0.3 with the target for jawOpen)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _plot_floor(ax, x, after: dict, names) -> None:
    """On the bars of after's result ~ target at ``x``: after's partial given the source (a
    cross) and, where judged, its floor (a dash: the pure render's, :func:`add_floor`)."""
    ax.plot(x, [after[n]["target_partial"] for n in names], "kx", ms=5,
            label="after: partial ~ target | source")
    if all("target_partial_floor" in after[n] for n in names):
        ax.plot(x, [after[n]["target_partial_floor"] for n in names], "_", color="0.45",
                ms=12, mew=2, label="its floor (pure render)")


def add_pair_options(ap: argparse.ArgumentParser) -> None:
    """``--pairs`` (of :data:`PAIRS`) and ``--frames`` (target frames judged)."""
    ap.add_argument("--pairs", default=",".join(PAIRS), help=f"of {', '.join(PAIRS)}")
    ap.add_argument("--frames", type=int, default=FRAMES, help="target frames judged")


def leak_line(name: str, after: dict, top: int = 4) -> str:
    """A pair's largest leaks over the floor (:func:`largest_leaks`), plain and with the pose:
    ``measure partial/floor=leak``."""
    parts = []
    for key, part, floor in (("target_leak", "target_partial", "target_partial_floor"),
                             ("target_leak_pose", "target_partial_pose",
                              "target_partial_pose_floor")):
        cells = "  ".join(f"{n} {after[n][part]:+.2f}/{after[n][floor]:+.2f}={v:+.2f}"
                          for n, v in largest_leaks(after, key, top))
        parts.append(f"{key}: {cells}")
    return f"{name} after, largest leaks over the floor (partial/floor=leak): " + "; ".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks")
    ap.add_argument("--video", help="judge the panels of a source | target | result video")
    ap.add_argument("--no-floor", dest="floor", action="store_false",
                    help="skip the pure render (the floor of the target partials)")
    ap.add_argument("--every", type=int, default=None,
                    help="the clips' detector shown one frame of N (default: as the "
                    "default transfer, DETECT_EVERY of the default speed)")
    add_pair_options(ap)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from facetransfer.io.atomic import atomic_path

    if args.video:
        res = {"video": args.video, "scores": judge_video(Path(args.video))}
        for n, r in res["scores"].items():
            print(f"{n:15s} result~source {r['result_source']:+.2f}  result~target "
                  f"{r['result_target']:+.2f}  amplitude {r['amplitude']:.2f}")
        with atomic_path(out / "transfer_judge_video.json", overwrite=True) as tmp:
            Path(tmp).write_text(json.dumps(res, indent=2))
        return 0
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model

    data = Path(data_dir()) / "video"
    model = load_default_model()
    res = {}
    for name in args.pairs.split(","):
        res[name] = judge_pair(name, model, out, data, args.frames, args.every, args.floor)
        for kind in ("before", "after", "eyes_only"):
            line = "  ".join(f"{n} {r['result_source']:+.2f}/{r['result_target']:+.2f}"
                             for n, r in res[name][kind].items())
            print(f"{name} {kind}: {line}", flush=True)
        if args.floor:
            print(leak_line(name, res[name]["after"]), flush=True)
    with atomic_path(out / "transfer_judge.json", overwrite=True) as tmp:
        Path(tmp).write_text(json.dumps({"pairs": res}, indent=2))
    plot(res, out / "transfer_judge.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

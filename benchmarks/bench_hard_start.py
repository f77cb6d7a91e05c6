"""A real clip started at a hard frame (issue 12: a track that follows a real face "from any
first frame"): does the default ``facetransfer track`` follow it as well as when the same frames
come later in the full clip?

``bench_capture.py --only real`` starts every clip at its own frame 0; its synthetic part starts
hard but on painted faces. Here, for each real clip of ``$FACETRANSFER_DATA_DIR/video/`` and its
stored MediaPipe-478 reference:

1. hard first frames are picked from the reference (frames 10 .. F - 60, so that a cut differs
   from the clip and keeps at least 60 frames): ``yaw`` and ``pitch``, the frame of the largest
   absolute head yaw / pitch (a similarity-rigid 3-D fit of MediaPipe's canonical face to the
   reference's points of the skull, :data:`bench_capture._SKULL`); ``blink``, the smallest lid gap
   of both eyes; ``mouth``, the widest-open mouth (13-14); and ``easy``, a control: the frame
   nearest the clip's median of all four, whose differences show what changing the first frame
   alone does (the noise of this comparison);
2. the clip is cut to start there, ``--frames`` frames (default 200) or to its end, losslessly
   (FFV1, RGB; its first frame is checked to be the clip's frame, pixel for pixel);
3. the cut and the full clip are tracked by the default ``facetransfer track`` (a process of this
   source tree, default model, ``--overwrite --restart``: no earlier progress is reused; a track is
   never taken from a cache), and Face Landmarker runs on the cut in VIDEO mode (the peer);
4. on the common frames, against the reference: the issue-12 measures (mouth opening, mouth width,
   eye opening, brow height: correlation and std ratio, :func:`bench_capture.openings`) and the
   activations jawOpen, eyeBlinkLeft/Right against Face Landmarker's blendshapes of the cut (the
   same numbers for both of our tracks), the 51- and 7-point NME of the 68 points against the
   reference mapped to iBUG (``mediapipe_to_ibug``; / the reference's outer eye-corner distance);
   the same on the first 10 frames and on frame 0 (is the start itself wrong?); and the cut's
   track against the full clip's (NME between them, correlation of their measures);
5. the summary: per figure, the median and the worst difference, cut minus full clip, over the
   hard starts and apart over the ``easy`` controls; a correlation whose reference is flat over
   the cut (:data:`FLAT`) is noise and is left out (and counted).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_hard_start.py --out out/hardstart
        [--frames 200] [--clips face_2,driving_d6] [--starts yaw,blink]

Writes ``OUT/hard_start.json`` and ``OUT/hard_start.png`` and prints a table.
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
import _revision  # noqa: E402
import bench_capture as bc  # noqa: E402
from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402

log = logging.getLogger("bench_hard_start")

STARTS = ("yaw", "pitch", "blink", "mouth", "easy")
#: a cut starts at frame >= MARGIN and keeps >= MIN_FRAMES frames
MARGIN, MIN_FRAMES = 10, 60
#: frames at the start of a cut judged on their own
FIRST = 10
SHAPES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")
MEASURES = ("mouth_open", "mouth_width", "eye_open", "brow")


# ------------------------------------------------------------------------------ hard frames
def canonical_face() -> np.ndarray:
    """MediaPipe's canonical face (468, 3) in image axes (x right, y down, z away)."""
    from facetransfer import assets
    from facetransfer.io.mesh import read_obj_vertices

    C = read_obj_vertices(assets.asset_file("canonical_face_model"))[:468].astype(np.float64)
    return C * np.array([1.0, -1.0, -1.0])


def head_angles(ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch (degrees, (F,) each) of the reference's points (F, 478, 3): the rotation
    of the best similarity (Umeyama 1991) taking the canonical face's skull points to the
    frame's (the reference's z is in the units of x: a relative depth); NaN where a frame has
    no points (before: SVD did not converge, on a reference with a frame missing)."""
    from facetransfer.track.dense import umeyama

    idx = list(bc._SKULL)
    C = canonical_face()[idx]
    yaw, pitch = [], []
    for Q in np.asarray(ref, np.float64)[:, idx]:
        if not np.isfinite(Q).all():
            yaw.append(np.nan)
            pitch.append(np.nan)
            continue
        R = umeyama(C, Q)[1]                             # Q ~ s R C + t
        yaw.append(np.degrees(np.arcsin(np.clip(R[0, 2], -1, 1))))
        pitch.append(np.degrees(np.arctan2(-R[1, 2], R[2, 2])))
    return np.array(yaw), np.array(pitch)


def hard_starts(ref: np.ndarray, starts=STARTS) -> dict:
    """``{start name: {"frame", "value"}}``: the hard first frames of a clip from its reference
    (F, 478, 3), among frames ``MARGIN .. F - MIN_FRAMES``; values: degrees (yaw, pitch), the
    lid gap and the lip gap / eye-corner distance, the control's largest deviation in MADs."""
    F = len(ref)
    ok = np.zeros(F, bool)
    ok[MARGIN:max(MARGIN, F - MIN_FRAMES + 1)] = True
    ok &= np.isfinite(ref).all(axis=(1, 2))
    if not ok.any():
        return {}
    yaw, pitch = head_angles(ref)
    eye = mp.measure(ref, mp.LIDS["Right"] + mp.LIDS["Left"])
    mouth = mp.measure(ref, mp.MOUTH_OPEN)
    cand = np.flatnonzero(ok)
    pick = lambda score: int(cand[np.argmax(score[cand])])  # noqa: E731
    dev = np.stack([np.abs(v - np.nanmedian(v)) / (np.nanmedian(np.abs(v - np.nanmedian(v)))
                                                   + 1e-9)
                    for v in (yaw, pitch, eye, mouth)]).max(axis=0)
    frames = {"yaw": (pick(np.abs(yaw)), yaw), "pitch": (pick(np.abs(pitch)), pitch),
              "blink": (pick(-eye), eye), "mouth": (pick(mouth), mouth),
              "easy": (pick(-dev), dev)}
    return {k: {"frame": f, "value": bc._r(v[f], 3)} for k, (f, v) in frames.items()
            if k in starts}


# ------------------------------------------------------------------------------ clips, tracks
def cut_clip(video: Path, start: int, n: int, folder: Path) -> tuple[Path, bool]:
    """Frames ``start .. start+n-1`` of ``video`` as ``read_video`` decodes them, written
    losslessly (FFV1, RGB) in ``folder``, and whether the cut read back gives its first frame
    pixel for pixel."""
    import imageio_ffmpeg

    from facetransfer.io.video import read_video

    frames, fps = read_video(video, start=start, stop=start + n)
    path = folder / f"{video.stem}-{start}-{n}.mkv"
    H, W = frames.shape[1:3]
    gen = imageio_ffmpeg.write_frames(str(path), (W, H), fps=fps, codec="ffv1",
                                      pix_fmt_in="rgb24", pix_fmt_out="bgr0",
                                      macro_block_size=1, ffmpeg_log_level="error")
    gen.send(None)
    for f in frames:
        gen.send(np.ascontiguousarray(f))
    gen.close()
    back = read_video(path, stop=1)[0][0]
    return path, bool(back.shape == frames[0].shape and np.array_equal(back, frames[0]))


def source_tree() -> Path:
    """The ``src`` folder of the ``facetransfer`` this process imports (``PYTHONPATH``)."""
    import facetransfer

    return Path(facetransfer.__file__).resolve().parents[1]


def track_cli(video: Path, out: Path) -> dict:
    """``facetransfer track VIDEO --out OUT`` of :func:`source_tree` in a fresh process (default
    model, ``--overwrite --restart``: an interrupted run's progress is not reused): the 68
    points, the ARKit activations (``ARKIT_NAMES`` order), the lost flags and the wall time."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.result import Track

    t0 = time.perf_counter()
    rc, err = _revision.run_command(["track", video, "--out", out, "--overwrite", "--restart"],
                                    source_tree())
    if rc != 0:
        raise RuntimeError(f"track {video.name} exited {rc}: {err}")
    tr = Track.load(out)
    A = None
    if tr.blendshapes is not None:
        names = list(tr.blendshape_names)
        A = np.asarray(tr.blendshapes, np.float64)[:, [names.index(n) for n in ARKIT_NAMES]]
    return {"landmarks": np.asarray(tr.landmarks2d, np.float64), "activations": A,
            "lost": np.asarray(tr.lost, bool), "seconds": round(time.perf_counter() - t0, 2)}


# ------------------------------------------------------------------------------ scores
def scores(L: np.ndarray, A: np.ndarray | None, ref: np.ndarray, shapes: np.ndarray) -> dict:
    """One tracker's 68 points ``L`` (n, 68, 2) and activations ``A`` (n, 52) against the
    reference (n, 478, 2) and Face Landmarker's blendshapes (n, 52) on the same frames: the
    measures' and the activations' correlation / std ratio, NME (median, and mean over the first
    :data:`FIRST` frames), the first frames' mean absolute error of the measures and shapes."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.landmarks import mediapipe_to_ibug

    ref68 = mediapipe_to_ibug(ref)
    mo, mr = bc.openings(L), bc.openings_mp(ref)
    n51, n7 = bc.nme(L, ref68, bc.INNER51), bc.nme(L, ref68, bc.KEY7)
    out = {"nme51": bc._r(np.nanmedian(n51)), "nme7": bc._r(np.nanmedian(n7)),
           "nme51_first": bc._r(np.nanmean(n51[:FIRST])),
           "nme7_first": bc._r(np.nanmean(n7[:FIRST])), "nme51_frame0": bc._r(n51[0])}
    for k in MEASURES:
        out[k] = versus(mo[k], mr[k])
    for name in SHAPES if A is not None else ():
        j = ARKIT_NAMES.index(name)
        out[name] = versus(A[:, j], shapes[:, j])
    return out


def versus(a: np.ndarray, b: np.ndarray) -> dict:
    """A signal ``a`` (n,) against its reference ``b`` (n,): correlation, std ratio, the
    reference's std (a flat reference's correlation is noise), the mean absolute error over the
    first :data:`FIRST` frames and on frame 0."""
    e = np.abs(a - b)
    return {"corr": bc._r(bc.corr(a, b)), "std_ratio": bc._r(bc.std_ratio(a, b)),
            "ref_std": bc._r(float(np.nanstd(b))), "first_abs": bc._r(np.nanmean(e[:FIRST])),
            "frame0_abs": bc._r(e[0])}


def agreement(cut: dict, full: dict, ref: np.ndarray) -> dict:
    """The cut's track against the full clip's on the same frames: NME between their 68 points
    (/ the reference's eye-corner distance; all frames and the first :data:`FIRST`), the
    correlation of their measures and activations, the mean absolute difference of the
    activations on the first frames and on the rest."""
    from facetransfer.arkit import ARKIT_NAMES
    from facetransfer.track.landmarks import mediapipe_to_ibug

    s = bc.iod(mediapipe_to_ibug(ref))
    d = np.linalg.norm(cut["landmarks"] - full["landmarks"], axis=2)
    e = d[:, bc.INNER51].mean(axis=1) / s
    out = {"nme51": bc._r(np.median(e)), "nme51_first": bc._r(np.mean(e[:FIRST])),
           "nme51_rest": bc._r(np.median(e[FIRST:]))}
    mc, mf = bc.openings(cut["landmarks"]), bc.openings(full["landmarks"])
    out.update({f"corr_{k}": bc._r(bc.corr(mc[k], mf[k])) for k in MEASURES})
    if cut["activations"] is not None and full["activations"] is not None:
        for name in SHAPES:
            j = ARKIT_NAMES.index(name)
            d = np.abs(cut["activations"][:, j] - full["activations"][:, j])
            out[f"corr_{name}"] = bc._r(bc.corr(cut["activations"][:, j],
                                                full["activations"][:, j]))
            out[f"absdiff_{name}"] = {"first": bc._r(d[:FIRST].mean()),
                                      "rest": bc._r(d[FIRST:].mean())}
    return out


def peer_scores(mp478: np.ndarray, shapes: np.ndarray, ref: np.ndarray) -> dict:
    """Face Landmarker on the cut against the reference, as :func:`scores` (its points
    mapped to iBUG by ``mediapipe_to_ibug``, its own blendshapes as activations)."""
    from facetransfer.track.landmarks import mediapipe_to_ibug

    out = scores(mediapipe_to_ibug(mp478), None, ref, shapes)
    a, b = bc.openings_mp(mp478), bc.openings_mp(ref)
    for k in MEASURES:      # its measures read from its own 478 points, as the reference's
        out[k] = versus(a[k], b[k])
    return out


# ------------------------------------------------------------------------------ run
def run_clip(name: str, vdir: Path, work: Path, n_frames: int, starts) -> dict:
    """Every hard start of one clip: the cut's track, the full clip's and the peer's scores."""
    with np.load(vdir / f"{name}.mediapipe478.npz") as z:
        ref3 = np.asarray(z["landmarks"], np.float64)
    video = vdir / f"{name}.mp4"
    full = track_cli(video, work / f"{name}-full.npz")
    out = {"frames": len(ref3), "full_seconds": full["seconds"], "starts": {}}
    picks = hard_starts(ref3, starts)
    for label, pick in picks.items():
        s = pick["frame"]
        n = min(n_frames, len(ref3) - s)
        done = next((k for k, v in out["starts"].items() if v["frame"] == s), None)
        if done is not None:                       # the same frame as an earlier start
            out["starts"][label] = out["starts"][done] | {"value": pick["value"],
                                                          "same_as": done}
            continue
        clip, same = cut_clip(video, s, n, work)
        cut = track_cli(clip, work / f"{name}-{s}.npz")
        with filtered_stderr():
            mp478, shapes = cached_landmarker(clip, work / "cache")
        ref = ref3[s:s + n, :, :2]
        window = {k: (v[s:s + n] if v is not None else None) for k, v in full.items()
                  if k in ("landmarks", "activations", "lost")}
        row = {"frame": s, "value": pick["value"], "frames": n, "first_frame_identical": same,
               "cut_seconds": cut["seconds"], "lost": {"cut": int(cut["lost"].sum()),
                                                       "full": int(window["lost"].sum())},
               "cut": scores(cut["landmarks"], cut["activations"], ref, shapes),
               "full": scores(window["landmarks"], window["activations"], ref, shapes),
               "peer": peer_scores(np.asarray(mp478, np.float64)[..., :2], shapes, ref),
               "cut_vs_full": agreement(cut, window, ref)}
        out["starts"][label] = row
        log.info("%s %s at %d: NME51 cut %s full %s peer %s", name, label, s,
                 row["cut"]["nme51"], row["full"]["nme51"], row["peer"]["nme51"])
    return out


KEYS = ("mouth_open", "mouth_width", "eye_open", "brow", "jawOpen", "eyeBlinkLeft",
        "eyeBlinkRight")


#: below this std over a cut, a reference is flat and its correlation is not counted: measures
#: (/ eye-corner distance) and Face Landmarker's scores
FLAT = {"measure": 0.01, "shape": 0.02}


def summary(clips: dict) -> dict:
    """Per figure, the median and the smallest (worst) cut-minus-full difference over every
    (clip, start), for the hard starts and for the ``easy`` control apart: correlations (those
    whose reference is flat, :data:`FLAT`, left out and counted) and NME (worst: largest)."""
    rows = [(lab, r) for c in clips.values() for lab, r in c["starts"].items()
            if "same_as" not in r]
    out = {}
    for group, rs in (("hard", [r for lab, r in rows if lab != "easy"]),
                      ("easy", [r for lab, r in rows if lab == "easy"])):
        if not rs:
            continue
        d = {"cases": len(rs), "flat_left_out": 0}
        for k in KEYS:
            floor = FLAT["shape" if k in SHAPES else "measure"]
            pairs = [(r["cut"][k]["corr"], r["full"][k]["corr"], r["cut"][k]["ref_std"])
                     for r in rs if k in r["cut"]]
            v = [c - f for c, f, sd in pairs if None not in (c, f) and sd >= floor]
            d["flat_left_out"] += len(pairs) - len(v)
            d[f"corr_{k}"] = [bc._r(np.median(v)), bc._r(min(v))] if v else None
        for k in ("nme51", "nme51_first", "nme51_frame0"):
            v = [r["cut"][k] - r["full"][k] for r in rs]
            d[k] = [bc._r(np.median(v)), bc._r(max(v))]
        out[group] = d
    return out


# ------------------------------------------------------------------------------ report
def print_table(res: dict) -> None:
    """Per clip and start: NME51 (all frames / first frames) and correlations, cut / full /
    peer; then the medians of cut minus full."""
    print(f"\n{'clip':18s} {'start':6s} {'frame':>5s} {'n':>4s}  NME51 % cut/full/peer   "
          f"first {FIRST}: cut/full/peer   r cut/full/peer: " + " ".join(k[:9] for k in KEYS))
    for name, c in res["clips"].items():
        for lab, r in c["starts"].items():
            if "same_as" in r:
                print(f"{name:18s} {lab:6s} {r['frame']:5d}  (= {r['same_as']})")
                continue
            f = lambda who, k: "-" if r[who].get(k) is None else f"{100 * r[who][k]:.1f}"  # noqa
            rr = lambda who, k: ("-" if k not in r[who] or r[who][k]["corr"] is None  # noqa
                                 else f"{r[who][k]['corr']:.2f}")
            cells = " ".join(f"{rr('cut', k)}/{rr('full', k)}/{rr('peer', k)}" for k in KEYS)
            print(f"{name:18s} {lab:6s} {r['frame']:5d} {r['frames']:4d}  "
                  f"{f('cut', 'nme51')}/{f('full', 'nme51')}/{f('peer', 'nme51')}"
                  f"{'':12s}{f('cut', 'nme51_first')}/{f('full', 'nme51_first')}/"
                  f"{f('peer', 'nme51_first')}{'':12s}{cells}")
    for group, d in res["summary"].items():
        print(f"cut - full over {d['cases']} {group} starts, median / worst "
              f"({d['flat_left_out']} correlations of a flat reference left out): "
              + ", ".join(f"{k} {v[0]:+.3f}/{v[1]:+.3f}" for k, v in d.items()
                          if isinstance(v, list)))


def plot(res: dict, path: Path) -> None:
    """NME51 over the cut and over its first frames (cut, full clip, peer), and each
    correlation of the cut's track against the full clip's on the same frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [(f"{n[:10]}\n{lab}@{r['frame']}", r) for n, c in res["clips"].items()
            for lab, r in c["starts"].items() if "same_as" not in r]
    fig, axes = plt.subplots(3, 1, figsize=(max(10, len(rows) * 0.8), 13))
    x = np.arange(len(rows))
    for ax, key, title in ((axes[0], "nme51", "51-point NME vs reference, median over the cut"),
                           (axes[1], "nme51_first", f"51-point NME, mean of the first {FIRST} "
                                                    "frames")):
        for k, (who, col) in enumerate((("cut", "tab:red"), ("full", "tab:blue"),
                                        ("peer", "tab:orange"))):
            ax.bar(x + (k - 1) * 0.27, [100 * (r[who][key] or np.nan) for _, r in rows], 0.27,
                   color=col, label={"cut": "ours, hard start", "full": "ours, full clip",
                                     "peer": "Face Landmarker on the cut"}[who])
        ax.set_xticks(x, [lab for lab, _ in rows], fontsize=7)
        ax.set_ylabel("% of eye-corner distance")
        ax.set_title(title)
        ax.legend(fontsize=8)
    ax = axes[2]
    for k in KEYS:
        floor = FLAT["shape" if k in SHAPES else "measure"]
        pts = [(r["full"][k]["corr"], r["cut"][k]["corr"], r["cut"][k]["ref_std"] < floor)
               for _, r in rows if k in r["cut"]]
        pts = [p for p in pts if None not in p[:2]]
        line = ax.scatter([p[0] for p in pts if not p[2]], [p[1] for p in pts if not p[2]],
                          s=18, label=k)
        flat = [p for p in pts if p[2]]
        if flat:
            ax.scatter([p[0] for p in flat], [p[1] for p in flat], s=18, facecolors="none",
                       edgecolors=line.get_facecolor())
    ax.plot([-0.2, 1], [-0.2, 1], "k--", lw=1)
    ax.set_xlabel("correlation with the reference, full clip's track (same frames)")
    ax.set_ylabel("the same, hard start's track")
    ax.set_title("correlation with the reference, cut against full clip (hollow: a flat "
                 "reference, noise)")
    ax.legend(fontsize=8, ncol=4)
    rep.save_plot(fig, path)


def main(argv=None) -> int:
    ap = rep.arguments(__doc__)
    ap.add_argument("--frames", type=int, default=200, help="frames per cut (at most)")
    ap.add_argument("--clips", default=",".join(bc.REAL_CLIPS), help="comma-separated clips")
    ap.add_argument("--starts", default=",".join(STARTS), help="comma-separated starts")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    out = Path(args.out)
    work = out / "work"
    work.mkdir(parents=True, exist_ok=True)
    vdir = bc._data_dir() / "video"
    starts = [s for s in args.starts.split(",") if s]
    t0 = time.perf_counter()
    res = {"benchmark": "hard start (issue 12)", "frames": args.frames, "first": FIRST,
           "source": str(source_tree()),
           "date": time.strftime("%Y-%m-%d %H:%M:%S"), "clips": {}}
    for name in [c for c in args.clips.split(",") if c]:
        res["clips"][name] = run_clip(name, vdir, work, args.frames, starts)
        res["summary"] = summary(res["clips"])
        rep.save_json(res, out / "hard_start.json")
    res["seconds"] = round(time.perf_counter() - t0, 1)
    rep.save_json(res, out / "hard_start.json")
    plot(res, out / "hard_start.png")
    print_table(res)
    print(f"\nwrote {out / 'hard_start.json'} and {out / 'hard_start.png'} "
          f"({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

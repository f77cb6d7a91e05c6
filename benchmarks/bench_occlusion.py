"""Occluders drawn on real clips, in colour and in black and white: what ``track --occluders``
finds (:mod:`facetransfer.track.occlusion`).

1. **Clean clips**: the data folder's ``driving_d6``, ``driving_d9``, ``face_2``,
   ``WDA_KatieHill_000``, and each brought to grey (BT.601 luma in three channels, H.264).
2. **Drawn occluders** on ``driving_d6``'s first 120 frames, placed by Face Landmarker's points
   of the clean frames (OpenCV): ``box`` (a hand-coloured box over the mouth, 30-59),
   ``skinbox`` (a box of the mouth ring's own median colour, 30-59: the limit), ``hand`` (a
   shaded, noisy palm with four fingers sliding in from the right: part of the mouth covered
   in 30-37 and 63-69, all of it in 38-62), ``bars`` (black bars over both eyes, 30-59),
   ``glasses`` (dark lenses with a glint and a bridge, 30-69), ``mic`` (a dark rod and grille
   at the chin, 30-89: the mouth seen), and two with nothing over the face: ``blur`` (30-59
   smeared sideways by 0.4 of the eyes' distance, a fast turn) and ``dim`` (30-59 at 55 % of
   their light); each in colour and brought to grey after drawing (a black-and-white camera
   filming a hand).
3. Each clip's points as ``track`` finds them (Face Landmarker on the clip itself, iBUG-68,
   :func:`facetransfer.track.video_detect.detect_video`; NaN where no face: the lost frames),
   cached in ``OUT/points``; then :func:`~facetransfer.track.occlusion.clip_occlusion`.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_occlusion.py --out out/occlusion

Prints, per clip and region, the frames flagged of the covered frames (recall), the frames
flagged in runs that touch no covered frame (false flags), those a covered run grew over
beyond its margin of 2 (beside), and the scores; writes ``OUT/occlusion.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

CLEAN = ("driving_d6", "driving_d9", "face_2", "WDA_KatieHill_000")
HAND = (195, 140, 100)
#: Per drawn clip: {region: covered frames}; the hand's wholly covered frames apart.
COVERED = {"box": {"mouth": range(30, 60)}, "skinbox": {"mouth": range(30, 60)},
           "hand": {"mouth": range(30, 70)}, "bars": {"right_eye": range(30, 60),
                                                     "left_eye": range(30, 60)},
           "glasses": {"right_eye": range(30, 70), "left_eye": range(30, 70)}, "mic": {},
           "blur": {}, "dim": {}}
WHOLE_HAND = range(38, 63)
N_DRAWN = 120


def _data() -> Path:
    return Path(os.environ["FACETRANSFER_DATA_DIR"]).expanduser() / "video"


def grey(frame: np.ndarray) -> np.ndarray:
    """A frame in BT.601 luma, three equal channels."""
    g = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)
    return np.repeat(g[..., None], 3, axis=2)


def detections(video: Path, cache: Path) -> np.ndarray:
    """(F, 68, 2) Face Landmarker's iBUG-68 points of ``video`` (NaN: no face), cached."""
    out = cache / (video.stem + ".npy")
    if out.is_file() and out.stat().st_mtime >= video.stat().st_mtime:
        return np.load(out)
    from facetransfer.track.video_detect import detect_video

    det = detect_video(str(video))[0]
    pts = np.array(det.points, np.float64)
    cache.mkdir(parents=True, exist_ok=True)
    np.save(out, pts)
    return pts


def _box(p: np.ndarray, grow: float) -> tuple[int, int, int, int]:
    lo, hi = p.min(0), p.max(0)
    pad = grow * (hi - lo).max()
    return (*(lo - pad).astype(int), *(hi + pad).astype(int))


def _skin_of(frames, points) -> tuple:
    """The median colour of the mouth's ring of skin over the clean frames."""
    from facetransfer.track import occlusion as oc

    got = []
    for f, p in zip(frames, points):
        if np.isfinite(p).all():
            ring = oc.region_points(p)[0][24:]
            xy = np.round(ring).astype(int)
            got.append(f[xy[:, 1], xy[:, 0]])
    return tuple(int(v) for v in np.median(np.concatenate(got), axis=0))


def draw(kind: str, frame: np.ndarray, p: np.ndarray, i: int, skin: tuple, rng) -> None:
    """Draw occluder ``kind`` on ``frame`` (in place) at frame ``i`` with points ``p``."""
    if i not in range(30, 90) or not np.isfinite(p).all():
        return
    eyes = float(np.linalg.norm(p[42:48].mean(0) - p[36:42].mean(0)))
    if kind in ("box", "skinbox") and i in COVERED[kind]["mouth"]:
        x0, y0, x1, y1 = _box(p[48:60], 0.25)
        cv2.rectangle(frame, (x0, y0), (x1, y1), HAND if kind == "box" else skin, -1)
    elif kind == "bars" and i in COVERED[kind]["left_eye"]:
        for eye in (p[36:42], p[42:48]):
            x0, y0, x1, y1 = _box(eye, 0.45)
            cv2.rectangle(frame, (x0, y0), (x1, y1), (10, 10, 10), -1)
    elif kind == "glasses" and i in COVERED[kind]["left_eye"]:
        _glasses(frame, p, eyes)
    elif kind == "hand" and i in COVERED[kind]["mouth"]:
        _hand(frame, p, i, eyes, rng)
    elif kind == "mic":
        _mic(frame, p, eyes)
    elif kind == "blur" and i < 60:              # a fast turn: the frame smeared sideways
        k = np.zeros((1, max(3, int(0.4 * eyes)) | 1), np.float32)
        k[:] = 1.0 / k.size
        frame[:] = cv2.filter2D(frame, -1, k)
    elif kind == "dim" and i < 60:               # the light turned down
        frame[:] = (frame * 0.55).astype(np.uint8)


def _glasses(frame, p, eyes) -> None:
    for eye, brow in ((p[36:42], p[17:22]), (p[42:48], p[22:27])):
        c = eye.mean(0)
        top = brow[:, 1].max()
        axes = (int(0.62 * eyes), int(max(0.42 * eyes, (c[1] - top) * 1.3)))
        cv2.ellipse(frame, (int(c[0]), int(c[1])), axes, 0, 0, 360, (25, 22, 28), -1)
        cv2.circle(frame, (int(c[0] - 0.2 * eyes), int(c[1] - 0.15 * eyes)),
                   max(2, int(0.06 * eyes)), (200, 200, 210), -1)
    a, b = p[39], p[42]
    cv2.line(frame, tuple(a.astype(int)), tuple(b.astype(int)), (25, 22, 28),
             max(2, int(0.08 * eyes)))


def _hand(frame, p, i, eyes, rng) -> None:
    """A palm and four fingers from the right, wholly over the mouth in WHOLE_HAND."""
    x0, y0, x1, y1 = _box(p[48:60], 0.35)
    w = x1 - x0
    if i < WHOLE_HAND.start:
        shift = int(w * (WHOLE_HAND.start - i) / 8 * 0.9)
    elif i >= WHOLE_HAND.stop:
        shift = int(w * (i - WHOLE_HAND.stop + 1) / 8 * 0.9)
    else:
        shift = 0
    wf = frame.shape[1]
    mask = np.zeros(frame.shape[:2], np.uint8)
    cv2.ellipse(mask, (x0 + shift + int(1.2 * w), (y0 + y1) // 2),
                (int(1.2 * w), (y1 - y0) // 2 + 6), 0, 0, 360, 1, -1)
    for k in range(4):
        y = y0 - int(0.5 * eyes) + k * int(0.32 * eyes)
        cv2.ellipse(mask, (x0 + shift + int(0.6 * w), y), (int(0.7 * w), int(0.13 * eyes)), 0,
                    0, 360, 1, -1)
    shade = np.linspace(0.85, 1.1, wf)[None, :, None] * np.array(HAND)[None, None]
    noise = rng.normal(0, 6, frame.shape)
    paint = np.clip(shade + noise, 0, 255).astype(np.uint8)
    m = mask.astype(bool)
    frame[m] = paint[m]


def _mic(frame, p, eyes) -> None:
    chin = p[8]
    head = (int(p[57][0] - 0.1 * eyes), int((p[57][1] + chin[1]) / 2 + 0.1 * eyes))
    cv2.line(frame, (head[0] - int(2 * eyes), head[1] + int(2.5 * eyes)), head, (30, 30, 30),
             max(3, int(0.25 * eyes)))
    r = max(4, int(0.35 * eyes))
    cv2.circle(frame, head, r, (60, 60, 60), -1)
    for d in range(-r, r, max(2, r // 4)):
        cv2.line(frame, (head[0] + d, head[1] - r), (head[0] + d, head[1] + r), (20, 20, 20), 1)


def make_clips(out: Path) -> dict[str, Path]:
    """The clean clips (as they are, and grey) and the drawn ones (colour and grey)."""
    from facetransfer.io.video import read_video, write_video

    clips = {}
    (out / "clips").mkdir(parents=True, exist_ok=True)
    for name in CLEAN:
        src = _data() / f"{name}.mp4"
        clips[name] = src
        g = out / "clips" / f"{name}_grey.mp4"
        if not g.is_file():
            frames, fps = read_video(src)
            write_video(g, [grey(f) for f in frames], fps)
        clips[f"{name}_grey"] = g
    base = _data() / "driving_d6.mp4"
    frames, fps = read_video(base, stop=N_DRAWN)
    pts = detections(base, out / "points")[:N_DRAWN]
    skin = _skin_of(frames[:30], pts[:30])
    for kind in COVERED:
        c, g = out / "clips" / f"occl_{kind}.mp4", out / "clips" / f"occl_{kind}_grey.mp4"
        if not g.is_file():
            rng = np.random.default_rng(0)
            drawn = [f.copy() for f in frames]
            for i, (f, p) in enumerate(zip(drawn, pts)):
                draw(kind, f, p, i, skin, rng)
            write_video(c, drawn, fps)
            write_video(g, [grey(f) for f in drawn], fps)
        clips[f"occl_{kind}"], clips[f"occl_{kind}_grey"] = c, g
    return clips


def measure(name: str, video: Path, cache: Path) -> dict:
    """Flagged covered frames and false flags per region of one clip."""
    from facetransfer.io.video import iter_frames
    from facetransfer.track import occlusion as oc

    pts = detections(video, cache)
    occ = oc.clip_occlusion(iter_frames(video, stop=len(pts)), pts)
    kind = name[len("occl_"):].removesuffix("_grey") if name.startswith("occl_") else None
    res = {}
    for r, region in enumerate(oc.REGIONS):
        cov = np.zeros(len(pts), bool)
        if kind is not None and region in COVERED[kind]:
            cov[list(COVERED[kind][region])] = True
        flag = occ.occluded[:, r]
        near = np.convolve(cov, np.ones(2 * oc.MARGIN + 1), "same") > 0   # the grown margin
        s = np.nan_to_num(occ.score[:, r])
        touching = np.zeros_like(flag)        # runs that overlap a covered frame
        for a, b in oc._runs(flag):
            touching[a:b] = cov[a:b].any()
        res[region] = {"covered": int(cov.sum()), "found": int((flag & cov).sum()),
                       "false": int((flag & ~touching).sum()),
                       "spill": int((flag & touching & ~near).sum()), "frames": len(pts),
                       "score_covered": float(np.median(s[cov])) if cov.any() else None,
                       "score_else_max": float(s[~near].max())}
        if kind == "hand" and region == "mouth":
            res[region]["found_whole"] = int(flag[list(WHOLE_HAND)].sum())
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/occlusion"))
    args = ap.parse_args(argv)
    clips = make_clips(args.out)
    report = {}
    for name, video in clips.items():
        report[name] = measure(name, video, args.out / "points")
        cells = [f"{r}: {v['found']}/{v['covered']} found, {v['false']} false"
                 + (f" (+{v['spill']} beside)" if v["spill"] else "") + ", "
                 f"max else {v['score_else_max']:.2f}" +
                 (f", median covered {v['score_covered']:.2f}" if v["covered"] else "")
                 for r, v in report[name].items()]
        print(f"{name:26s} " + " | ".join(cells), flush=True)
    (args.out / "occlusion.json").write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

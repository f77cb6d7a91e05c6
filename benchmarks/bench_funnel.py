"""Our mouthFunnel on real clips (issue 12's last amplitude band): where it fires while Face
Landmarker's score does not, and what the mouth does there.

For each real clip of ``$FACETRANSFER_DATA_DIR/video/`` and its stored MediaPipe-478 reference:

1. the clip is tracked by the default capture (``bench_capture.run_ours``: detection, both
   passes) and Face Landmarker runs on it in VIDEO mode (the peer, cached);
2. three groups of frames: **disputed** (our funnel above ``--ours``, the peer's below
   ``--peer``), **neutral** (ours below 0.05, the peer's funnel below 0.02 and its jawOpen below
   0.1) and **peer-high** (the peer's funnel above 0.2: a funnel the peer sees);
3. per group, the median of the reference's own mouth geometry (points in pixels, z as stored):
   the mouth's width (61-291) and inner-lip gap (13-14) over the eye-corner distance (33-263),
   and the lips' **protrusion** (points 0, 17, 37, 267, 84, 314 toward the camera, after each
   frame's similarity onto the clip's median face at its rigid points, over that face's
   eye-corner distance, about the clip's median): a funnel narrows the mouth and pushes the lips
   out; parted lips in speech do neither; and ours and the peer's funnel, pucker and jawOpen;
4. the rest level (median, 10th percentile) of both funnels, their std and correlation;
5. a contact sheet ``OUT/funnel_frames.png``: the mouth of the disputed frames (red), two
   neutral (green) and two peer-high (blue) frames of each clip, with both funnels and jaws.

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_funnel.py --out out/funnel
        [--clips face_2,driving_d6] [--ours 0.08] [--peer 0.05]

Writes ``OUT/funnel.json`` and ``OUT/funnel_frames.png`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("GLOG_minloglevel", "2")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import bench_capture as bc  # noqa: E402
from _mp_video import cached_landmarker, filtered_stderr  # noqa: E402

log = logging.getLogger("bench_funnel")

#: MediaPipe-478 points that move with the skull (eye corners, nose, forehead, face sides)
RIGID = (33, 133, 362, 263, 168, 6, 197, 195, 5, 4, 10, 151, 9, 8, 234, 454, 127, 356)
#: the outer lips' midline and the points beside it
LIPS = (0, 17, 37, 267, 84, 314)
GROUPS = ("disputed", "neutral", "peer_high")
#: a stored clip's pixel aspect (its reference is in stored pixels)
PIXEL_ASPECT = {"driving_d9": 15 / 16}


# ------------------------------------------------------------------------------ measures
def similarity_onto(Q: np.ndarray, ref: np.ndarray, idx=RIGID) -> np.ndarray:
    """``Q`` (N, 3) moved by the similarity (Umeyama, no reflection) that best fits its points
    ``idx`` onto those of ``ref`` (N, 3)."""
    a, b = Q[list(idx)], ref[list(idx)]
    am, bm = a.mean(0), b.mean(0)
    U, S, Vt = np.linalg.svd((a - am).T @ (b - bm))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float((S * np.diag(D)).sum() / ((a - am) ** 2).sum())
    return s * (Q - am) @ R + bm


def mouth_geometry(P: np.ndarray) -> dict[str, np.ndarray]:
    """The mouth of MediaPipe-478 points ``P`` (F, 478, 3) per frame (module notes, step 3):
    ``width``, ``gap`` and ``protrusion``, (F,) each, NaN where a frame has no face."""
    P = np.asarray(P, float)
    eye = np.linalg.norm(P[:, 33] - P[:, 263], axis=1)
    width = np.linalg.norm(P[:, 61] - P[:, 291], axis=1) / eye
    gap = np.linalg.norm(P[:, 13] - P[:, 14], axis=1) / eye
    med = np.nanmedian(P, axis=0)
    z = np.full(len(P), np.nan)
    for i, Q in enumerate(P):
        if np.isfinite(Q).all():
            z[i] = similarity_onto(Q, med)[list(LIPS), 2].mean()
    prot = -(z - np.nanmedian(z)) / np.linalg.norm(med[33] - med[263])   # z grows away
    return {"width": width, "gap": gap, "protrusion": prot}


def frame_groups(ours: np.ndarray, peer: np.ndarray, peer_jaw: np.ndarray, *,
                 high: float = 0.08, low: float = 0.05) -> dict[str, np.ndarray]:
    """(F,) bool masks of :data:`GROUPS` from our funnel, the peer's and the peer's jawOpen
    (module notes, step 2; ``high``, ``low``: ``--ours``, ``--peer``)."""
    ours, peer, peer_jaw = (np.asarray(x, float) for x in (ours, peer, peer_jaw))
    return {"disputed": (ours > high) & (peer < low),
            "neutral": (ours < 0.05) & (peer < 0.02) & (peer_jaw < 0.1),
            "peer_high": peer > 0.2}


def _median(x: np.ndarray, m: np.ndarray) -> float | None:
    v = np.asarray(x, float)[m]
    v = v[np.isfinite(v)]
    return round(float(np.median(v)), 4) if len(v) else None


def clip_study(ours: np.ndarray, peer: np.ndarray, ref: np.ndarray, args) -> tuple[dict, dict]:
    """One clip's figures (module notes, steps 2-4) from our activations and the peer's scores
    (F, 52) and the reference's points (F, 478, 3), and its :func:`frame_groups`."""
    from facetransfer.arkit import ARKIT_NAMES

    k = {n: ARKIT_NAMES.index(n) for n in ("mouthFunnel", "mouthPucker", "jawOpen")}
    of, pf = ours[:, k["mouthFunnel"]], peer[:, k["mouthFunnel"]]
    groups = frame_groups(of, pf, peer[:, k["jawOpen"]], high=args.ours, low=args.peer)
    geo = mouth_geometry(ref)
    ok = np.isfinite(of) & np.isfinite(pf)
    out = {"frames": int(len(of)),
           "rest": {"ours_median": _median(of, ok), "peer_median": _median(pf, ok),
                    "ours_p10": round(float(np.percentile(of[ok], 10)), 4),
                    "peer_p10": round(float(np.percentile(pf[ok], 10)), 4)},
           "std": {"ours": round(float(of[ok].std()), 4), "peer": round(float(pf[ok].std()), 4)},
           "corr": bc._r(bc.corr(of[ok], pf[ok]), 3)}
    for g, m in groups.items():
        row = {"frames": int(m.sum())} | {key: _median(v, m) for key, v in geo.items()}
        for n, j in k.items():
            row[f"ours_{n}"], row[f"peer_{n}"] = _median(ours[:, j], m), _median(peer[:, j], m)
        out[g] = row
    return out, groups


# ------------------------------------------------------------------------------ the sheet
def _picks(groups: dict, of: np.ndarray, pf: np.ndarray) -> list[tuple[str, int]]:
    d, n, h = (np.flatnonzero(groups[g]) for g in GROUPS)
    picks = [("disputed", int(i)) for i in d[np.argsort(pf[d] - of[d])][:6]]
    spread = np.linspace(0, len(n) - 1, min(2, len(n))).astype(int)
    picks += [("neutral", int(i)) for i in n[spread]]
    picks += [("peer_high", int(i)) for i in h[np.argsort(-pf[h])][:2]]
    return sorted(picks, key=lambda t: t[1])


def sheet_row(video: Path, ref: np.ndarray, picks, labels, size: int = 200) -> np.ndarray:
    """One clip's row of mouth crops (``picks``: (group, frame)) with ``labels[frame]`` lines."""
    import cv2

    colour = {"disputed": (0, 0, 200), "neutral": (0, 140, 0), "peer_high": (200, 0, 0)}
    cap, tiles = cv2.VideoCapture(str(video)), []
    for g, i in picks:
        cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, img = cap.read()
        if not ok:
            continue
        P = ref[i, :, :2]
        c, w = P[[61, 291, 0, 17]].mean(0), 0.75 * np.linalg.norm(P[33] - P[263])
        crop = img[max(int(c[1] - 0.8 * w), 0):int(c[1] + 1.2 * w),
                   max(int(c[0] - w), 0):int(c[0] + w)]
        band = np.full((62, size, 3), 255, np.uint8)
        for r, text in enumerate([f"{video.stem[:10]} f{i} {g}"] + labels[i]):
            cv2.putText(band, text, (3, 13 + 15 * r), cv2.FONT_HERSHEY_SIMPLEX, 0.38, colour[g],
                        1, cv2.LINE_AA)
        tiles.append(np.vstack([cv2.resize(crop, (size, size)), band]))
    tiles += [np.full((size + 62, size, 3), 240, np.uint8)] * (10 - len(tiles))
    return np.hstack(tiles[:10])


# ------------------------------------------------------------------------------ run
def run_clip(name: str, vdir: Path, cache: Path, model, args) -> tuple[dict, np.ndarray]:
    """Track one clip, run the peer, and study it; its contact-sheet row."""
    from facetransfer.arkit import ARKIT_NAMES

    video = vdir / f"{name}.mp4"
    with np.load(vdir / f"{name}.mediapipe478.npz") as z:
        ref = np.asarray(z["landmarks"], float)
    with filtered_stderr(True):
        _, peer = cached_landmarker(video, cache, shown=True)
    ours = bc.run_ours(video, model)["activations"]
    F = min(len(ours), len(peer), len(ref))
    ours, peer, ref = ours[:F], np.asarray(peer, float)[:F], ref[:F]
    square = ref.copy()
    square[..., 0] *= PIXEL_ASPECT.get(name, 1.0)
    res, groups = clip_study(ours, peer, square, args)
    f, j = ARKIT_NAMES.index("mouthFunnel"), ARKIT_NAMES.index("jawOpen")
    labels = {i: [f"funnel ours {ours[i, f]:.2f} FL {peer[i, f]:.2f}",
                  f"jaw ours {ours[i, j]:.2f} FL {peer[i, j]:.2f}"] for i in range(F)}
    return res, sheet_row(video, ref, _picks(groups, ours[:, f], peer[:, f]), labels)


def print_table(res: dict) -> None:
    print("\nmouthFunnel, ours vs Face Landmarker (FL); geometry of the reference's points "
          "(width, gap / eye corners; protrusion toward the camera)")
    print(f"{'clip':18s} {'group':10s} {'n':>4s} {'width':>6s} {'gap':>6s} {'prot':>7s} "
          f"{'funnel':>11s} {'pucker':>11s} {'jaw':>11s}")
    for name, c in res.items():
        for g in GROUPS:
            r = c[g]
            cell = lambda n: f"{r[f'ours_{n}']}/{r[f'peer_{n}']}"  # noqa: E731
            print(f"{name:18s} {g:10s} {r['frames']:4d} {r['width']!s:>6s} {r['gap']!s:>6s} "
                  f"{r['protrusion']!s:>7s} {cell('mouthFunnel'):>11s} "
                  f"{cell('mouthPucker'):>11s} {cell('jawOpen'):>11s}")
        print(f"{'':18s} rest ours {c['rest']['ours_median']} (p10 {c['rest']['ours_p10']}), "
              f"FL {c['rest']['peer_median']} (p10 {c['rest']['peer_p10']}); std ours "
              f"{c['std']['ours']}, FL {c['std']['peer']}; r {c['corr']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    ap.add_argument("--clips", default=",".join(bc.REAL_CLIPS), help="comma-separated clips")
    ap.add_argument("--ours", type=float, default=0.08, help="our funnel above this: disputed")
    ap.add_argument("--peer", type=float, default=0.05, help="... where the peer's is below this")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s",
                        datefmt="%H:%M:%S")
    from facetransfer.default_model import load_default_model
    import cv2

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vdir, model = bc._data_dir() / "video", load_default_model()
    res, rows = {}, []
    for name in [c for c in args.clips.split(",") if c]:
        res[name], row = run_clip(name, vdir, out / "capture_cache", model, args)
        rows.append(row)
        log.info("%s: %d disputed frames", name, res[name]["disputed"]["frames"])
    (out / "funnel.json").write_text(json.dumps(res, indent=1))
    cv2.imwrite(str(out / "funnel_frames.png"), np.vstack(rows))
    print_table(res)
    print(f"\nwrote {out / 'funnel.json'} and {out / 'funnel_frames.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

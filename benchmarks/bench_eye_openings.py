"""The mesh's eye openings against the eyes: the track's lid contours beside Face Landmarker's.

The transfer shows the new face's eyes through the model's eye holes (the lid contour
vertices, :attr:`facetransfer.topology.MeshTopology.eye_loops`, closed by fill triangles:
:func:`facetransfer.eyes.close_eyes`) placed by the track's pose and weights (Eq. (5), (7)).
This measures, per frame and eye, how far that opening lies from the eye's own opening in the
picture, as

* ``corner``: the opening's two corners against the reference's eye corners (mean);
* ``lid``: each of the reference's upper-lid (lower-lid) points against the opening's upper
  (lower) edge; ``upper_dy`` / ``lower_dy`` the signed vertical part (image y: + = the
  opening's edge lies below the reference's lid);

in pixels and in % of the reference's eye width (its corners' distance), mean and max over
frames and eyes. The openings measured:

* ``loop``: the hole's boundary (its corners the loop's vertices of least and greatest model
  x, as :func:`facetransfer.eyes.fill_loop` splits it);
* ``shown``: the outline of the fill's pixels the z-buffer shows (rendered 80 px an eye
  about the reference's eye): the opening as the transfer's raster has it, the lids' front
  edges where they hang over the hole; every ``--every``-th frame;
* ``points``: the mesh's own Face Landmarker eye contours, the points of its surface the
  capture fit takes MediaPipe's eye rings for (:mod:`facetransfer.track.dense`), without the
  clip's offsets: the fit's share of the error (the tracker's);
* ``intrinsic``: ``shown`` against ``points``, the model's share (its hole is shorter than
  the eye at the inner corner: it ends at the caruncle, Face Landmarker's corner is the
  canthus);
* ``floor``: ``loop`` after the best 2-D affine map of each eye's loop onto the reference's
  contour (what no pose, scale or lid opening of this loop could remove).

References: the real clips (``FACETRANSFER_DATA_DIR/video``) against their stored MediaPipe
points (``NAME.mediapipe478.npz``, 16 points an eye), the track fitted to Face Landmarker's
own detections of the clip (``capture_detections``, the default model; the detections kept in
``OUT/detections/``); the photos (``stills/``) against the human iBUG-68 points (36-47), the
peer ``face_landmarker`` (its eye contours against the same human points), ``shown_vs_fl``
(our shown opening against Face Landmarker's contours) and ``per_eye`` (corner and lid px of
each eye).

    FACETRANSFER_DATA_DIR=... python benchmarks/bench_eye_openings.py --out out/eyes54
        [--clips driving_d6,...] [--no-photos] [--save-tracks DIR] [--every N]

Writes ``OUT/eye_openings.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("FACETRANSFER_TRACK_CACHE", "off")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _mp_video import filtered_stderr  # noqa: E402
from _report import save_json  # noqa: E402
from facetransfer.track.landmarks import MP_EYE_CONTOURS  # noqa: E402

CLIPS = ("WDA_KatieHill_000", "face_2", "driving_d9", "driving_d6")
PHOTOS = ("einstein.jpg", "breakingbad.jpg", "takeo.ppm")
#: Face Landmarker's eye contours, per eye (the subject's right, then left): outer corner,
#: lower lid (outer to inner), inner corner, upper lid (inner to outer)
MP_EYES = tuple((r[0], r[1:8], r[8], r[9:]) for r in MP_EYE_CONTOURS)
#: the human iBUG points per eye: outer corner, lower lid, inner corner, upper lid
IBUG_EYES = ((36, (41, 40), 39, (38, 37)), (45, (46, 47), 42, (43, 44)))


class Opening:
    """The model's eye loops split into corners and chains (per eye: the subject's right,
    then left, as ``mesh_topology`` orders them)."""

    def __init__(self, model) -> None:
        from facetransfer.topology import mesh_topology

        V = model.synthesize(model.default_weights())
        self.model, self.eyes = model, []
        for L in mesh_topology(model).eye_loops:
            x = V[L, 0]
            i0, i1 = int(np.argmin(x)), int(np.argmax(x))
            k = L.size
            a = np.arange(i0, i0 + (i1 - i0) % k + 1) % k        # positions along the loop
            b = np.arange(i0, i0 - (i0 - i1) % k - 1, -1) % k
            up, low = (a, b) if V[L[a], 1].mean() > V[L[b], 1].mean() else (b, a)
            outer, inner = (i0, i1) if x.mean() < 0 else (i1, i0)  # model x: the subject's left
            self.eyes.append({"loop": L, "outer": outer, "inner": inner, "upper": up,
                              "lower": low})

    def pixels(self, track) -> list:
        """Per eye, the loop's projected points ``(F, k, 2)`` (the track's Eq. (7) with its
        pixels' aspect, as :func:`facetransfer.track.project.project_landmarks`)."""
        loops = np.concatenate([e["loop"] for e in self.eyes])
        X = self.model.synthesize({n: track.weights[n] for n in self.model.mode_names},
                                  vertices=loops)                             # (F, K, 3)
        Y = np.einsum("fij,fvj->fvi", track.rotation[:, :2], X)
        px = np.empty_like(Y)
        px[..., 0] = (track.scale[:, None] / track.pixel_aspect) * Y[..., 0] \
            + track.translation[:, None, 0]
        px[..., 1] = -track.scale[:, None] * Y[..., 1] + track.translation[:, None, 1]
        k = self.eyes[0]["loop"].size
        return [px[:, :k], px[:, k:]]

    def contour(self, track) -> np.ndarray:
        """The mesh's own Face Landmarker eye contours: the points of the model's surface the
        capture fit takes them for (:func:`facetransfer.track.dense.mediapipe_correspondence`,
        without the clip's offsets), projected like :meth:`pixels`, ``(F, 478, 2)`` (NaN for
        the other points)."""
        from facetransfer.track.dense import mediapipe_correspondence

        dc = mediapipe_correspondence(self.model)
        want = [k for e in MP_EYES for k in (e[0], *e[1], e[2], *e[3])]
        rows = [int(np.flatnonzero(dc.mp_index == k)[0]) for k in want]
        tri, bary = dc.triangles[rows], dc.bary[rows]
        verts = np.unique(tri)
        X = self.model.synthesize({n: track.weights[n] for n in self.model.mode_names},
                                  vertices=verts)                              # (F, u, 3)
        P = np.einsum("fpkc,pk->fpc", X[:, np.searchsorted(verts, tri)], bary)
        Y = np.einsum("fij,fvj->fvi", track.rotation[:, :2], P)
        out = np.full((track.n_frames, 478, 2), np.nan)
        out[:, want, 0] = (track.scale[:, None] / track.pixel_aspect) * Y[..., 0] \
            + track.translation[:, None, 0]
        out[:, want, 1] = -track.scale[:, None] * Y[..., 1] + track.translation[:, None, 1]
        return out

    def closed(self):
        """The eye-closed topology (:func:`facetransfer.eyes.close_eyes`), each triangle's
        eye (F',) int8 (-1: not a fill triangle) and the mesh topology."""
        from facetransfer.eyes import close_eyes, fill_loop
        from facetransfer.topology import mesh_topology

        if not hasattr(self, "_closed"):
            topo = mesh_topology(self.model)
            V0 = self.model.synthesize(self.model.default_weights())
            closed, fill = close_eyes(topo, V0)
            eye = np.full(len(closed.faces), -1, np.int8)
            n0 = len(fill_loop(topo.eye_loops[0], V0))
            eye[fill[:n0]], eye[fill[n0:]] = 0, 1
            self._closed = (closed, eye, topo)
        return self._closed

    def shown(self, track, frames: np.ndarray, refs: list) -> list:
        """Per frame of ``frames`` and eye, the outline ``(m, 2)`` (pixels) of the fill's
        pixels the z-buffer shows (the opening as the transfer's raster has it: the lids'
        front edges where they hang over the hole), rendered ``UPSAMPLE`` times finer about
        the reference's eye; None where nothing of it shows."""
        import cv2

        from facetransfer.render import WeakPerspective, rasterize
        from facetransfer.topology import close_mouth

        closed, eye_of, topo = self.closed()
        out = []
        for f, ref in zip(frames, refs):
            V = close_mouth(self.model.synthesize(track.weights_at(int(f))), topo)
            row = []
            for e in range(2):
                P = np.vstack([ref[e][0], ref[e][1], ref[e][2], ref[e][3]])
                w = max(float(np.linalg.norm(ref[e][0] - ref[e][2])), 4.0)
                k = float(np.clip(80.0 / w, 1.0, 8.0))
                x0, y0 = P.min(0) - w
                W_, H_ = (np.ptp(P, axis=0) + 2 * w) * k
                cam = WeakPerspective(float(track.scale[f]) * k, track.rotation[f],
                                      (track.translation[f] - [x0, y0]) * k, track.pixel_aspect)
                tid = rasterize(V, closed.faces, cam, (int(W_) + 1, int(H_) + 1)).tri_id
                mask = ((tid >= 0) & (eye_of[np.maximum(tid, 0)] == e)).astype(np.uint8)
                cs, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
                if not cs:
                    row.append(None)
                    continue
                c = max(cs, key=cv2.contourArea)[:, 0, :].astype(float)
                row.append(c / k + [x0, y0])
            out.append(row)
        return out


def _to_polyline(p: np.ndarray, line: np.ndarray) -> tuple[float, float]:
    """Distance of point ``p`` (2,) from the polyline ``line`` (m, 2), and the signed
    vertical offset of its nearest point (+: the line lies below ``p`` in the image)."""
    a, b = line[:-1], line[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d),
                                                            1e-12), 0.0, 1.0)
    q = a + t[:, None] * d
    r = np.linalg.norm(q - p, axis=1)
    j = int(np.argmin(r))
    return float(r[j]), float(q[j, 1] - p[1])


def eye_errors(loop: np.ndarray, eye: dict, ref: tuple) -> dict:
    """One eye's errors in one frame: the loop's projected points ``(k, 2)`` against the
    reference ``(outer (2,), lower (m, 2), inner (2,), upper (m, 2))``."""
    outer, lower, inner, upper = ref
    width = float(np.linalg.norm(outer - inner))
    c = [float(np.linalg.norm(loop[eye["outer"]] - outer)),
         float(np.linalg.norm(loop[eye["inner"]] - inner))]
    up = [_to_polyline(p, loop[eye["upper"]]) for p in upper]
    lo = [_to_polyline(p, loop[eye["lower"]]) for p in lower]
    lid = [d for d, _ in up + lo]
    return {"width": width, "corner": float(np.mean(c)), "outer": c[0], "inner": c[1],
            "lid": float(np.mean(lid)), "upper_dy": float(np.mean([s for _, s in up])),
            "lower_dy": float(np.mean([s for _, s in lo]))}


def outline_errors(outline: np.ndarray, ref: tuple) -> dict:
    """:func:`eye_errors` of an outline ``(m, 2)`` (a closed polygon, pixels): its corners its
    extreme points along the reference's corner-to-corner axis, its lids the polygon (signed
    vertical offsets at each lid point's column: the outline's top or bottom there)."""
    outer, lower, inner, upper = ref
    width = float(np.linalg.norm(outer - inner))
    u = (outer - inner) / max(width, 1e-9)
    s = outline @ u
    c = [float(np.linalg.norm(outline[int(np.argmax(s))] - outer)),
         float(np.linalg.norm(outline[int(np.argmin(s))] - inner))]
    poly = np.vstack([outline, outline[:1]])
    lid, dys = [], {"upper": [], "lower": []}
    for which, pts in (("upper", upper), ("lower", lower)):
        for p in pts:
            lid.append(_to_polyline(p, poly)[0])
            near = outline[np.abs(outline[:, 0] - p[0]) <= 0.75]
            if len(near):
                edge = near[:, 1].min() if which == "upper" else near[:, 1].max()
                dys[which].append(float(edge - p[1]))
            else:                  # the outline does not reach this column: its nearest end
                j = int(np.argmin(np.abs(outline[:, 0] - p[0])))
                dys[which].append(float(outline[j, 1] - p[1]))
    return {"width": width, "corner": float(np.mean(c)), "outer": c[0], "inner": c[1],
            "lid": float(np.mean(lid)), "upper_dy": float(np.mean(dys["upper"])),
            "lower_dy": float(np.mean(dys["lower"]))}


def affine_floor(loop: np.ndarray, eye: dict, ref: tuple) -> dict:
    """:func:`eye_errors` after the best 2-D affine map of the loop onto the reference (its
    corners and its lid points matched to the chains' points at the same share of the
    corner-to-corner chord), a few rounds of nearest points."""
    outer, lower, inner, upper = ref
    src = loop
    for _ in range(4):
        P, Q = [src[eye["outer"]], src[eye["inner"]]], [outer, inner]
        for pts, chain in ((upper, eye["upper"]), (lower, eye["lower"])):
            for p in pts:
                r = np.linalg.norm(src[chain] - p, axis=1)
                P.append(src[chain][int(np.argmin(r))])
                Q.append(p)
        P, Q = np.asarray(P), np.asarray(Q)
        A = np.c_[P, np.ones(len(P))]
        M, *_ = np.linalg.lstsq(A, Q, rcond=None)
        src = np.c_[src, np.ones(len(src))] @ M
    return eye_errors(src, eye, ref)


def mp_ref(points: np.ndarray, e: int) -> tuple:
    """Face Landmarker's eye ``e`` as ``(outer, lower, inner, upper)`` from (478, 2+)."""
    o, lo, i, up = MP_EYES[e]
    P = np.asarray(points, float)[:, :2]
    return P[o], P[list(lo)], P[i], P[list(up)]


def ibug_ref(points: np.ndarray, e: int) -> tuple:
    o, lo, i, up = IBUG_EYES[e]
    P = np.asarray(points, float)
    return P[o], P[list(lo)], P[i], P[list(up)]


def mp_as_loop(points: np.ndarray, e: int) -> tuple[np.ndarray, dict]:
    """Face Landmarker's eye contour as a loop for :func:`eye_errors` (the peer)."""
    o, lo, i, up = MP_EYES[e]
    idx = [o, *lo, i, *up]
    P = np.asarray(points, float)[idx, :2]
    n = len(lo)
    eye = {"outer": 0, "inner": n + 1, "lower": np.arange(0, n + 2),
           "upper": np.r_[np.arange(n + 1, 2 * n + 2), 0]}
    return P, eye


def summary(rows: list) -> dict:
    """Mean and max over frames and eyes of each error, px and % of the eye width."""
    out = {}
    for key in ("corner", "lid", "upper_dy", "lower_dy"):
        v = np.array([r[key] for r in rows])
        pc = 100 * v / np.array([r["width"] for r in rows])
        out[key] = {"mean_px": round(float(v.mean()), 2),
                    "max_px": round(float(np.abs(v).max()), 2),
                    "mean_pc": round(float(pc.mean()), 1),
                    "max_pc": round(float(np.abs(pc).max()), 1)}
    return out


def _detections(video: Path, cache: Path):
    from facetransfer.track.capture import detect_video

    path = cache / f"{video.stem}.pkl"
    if path.is_file():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    with filtered_stderr():
        got = detect_video(video, workers=1)
    cache.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        pickle.dump(got, fh)
    return got


def _track(det, model, fps, size, src):
    from facetransfer.track.capture import capture_detections

    return capture_detections(det, model, fps=fps, frame_size=size, source=src)


def measure_clip(name: str, data: Path, model, opening: Opening, cache: Path,
                 tracks: Path | None, every: int = 2) -> dict:
    """Every frame of a real clip: ours against its stored reference, and the floor."""
    video = data / "video" / f"{name}.mp4"
    with np.load(data / "video" / f"{name}.mediapipe478.npz") as z:
        ref = z["landmarks"]
    det, fps, size, src = _detections(video, cache)
    track = _track(det, model, fps, size, src)
    if tracks is not None:
        tracks.mkdir(parents=True, exist_ok=True)
        track.save(tracks / f"{name}.track.npz")
    px, own = opening.pixels(track), opening.contour(track)
    ours, floor, shown, points, intrinsic = [], [], [], [], []
    frames = [f for f in range(min(track.n_frames, len(ref)))
              if not track.lost[f] and np.isfinite(ref[f]).all()]
    for f in frames:
        for e in range(2):
            r = mp_ref(ref[f], e)
            ours.append(eye_errors(px[e][f], opening.eyes[e], r))
            floor.append(affine_floor(px[e][f], opening.eyes[e], r))
            points.append(eye_errors(*mp_as_loop(own[f], e), r))
    few = frames[::every]
    refs = [[mp_ref(ref[f], e) for e in range(2)] for f in few]
    for f, row, rr in zip(few, opening.shown(track, few, refs), refs):
        for e, (o, r) in enumerate(zip(row, rr)):
            if o is not None:
                shown.append(outline_errors(o, r))
                intrinsic.append(outline_errors(o, mp_ref(own[f], e)))
    return {"frames": len(frames), "shown_frames": len(few), "loop": summary(ours),
            "floor": summary(floor), "shown": summary(shown), "points": summary(points),
            "intrinsic": summary(intrinsic)}


def measure_photo(name: str, data: Path, model, opening: Opening) -> dict:
    """A photo: ours, Face Landmarker (the peer) and the floor against the human points."""
    from facetransfer.track.capture import detect_video

    photo = data / "stills" / name
    truth = np.loadtxt(photo.with_suffix(".pts"), skiprows=3, comments="}")
    with filtered_stderr():
        det, fps, size, src = detect_video(photo, workers=1)
    track = _track(det, model, fps, size, src)
    px, own = opening.pixels(track), opening.contour(track)[0]
    q = det.points478[0]
    rows = {"loop": [], "shown": [], "face_landmarker": [], "points": [], "floor": [],
            "shown_vs_fl": []}
    refs = [ibug_ref(truth, e) for e in range(2)]
    outlines = opening.shown(track, [0], [refs])[0]
    fl_outlines = opening.shown(track, [0], [[mp_ref(q, e) for e in range(2)]])[0]
    for e in range(2):
        r = refs[e]
        rows["loop"].append(eye_errors(px[e][0], opening.eyes[e], r))
        if outlines[e] is not None:
            rows["shown"].append(outline_errors(outlines[e], r))
            rows["shown_vs_fl"].append(outline_errors(fl_outlines[e], mp_ref(q, e)))
        rows["floor"].append(affine_floor(px[e][0], opening.eyes[e], r))
        rows["face_landmarker"].append(eye_errors(*mp_as_loop(q, e), r))
        rows["points"].append(eye_errors(*mp_as_loop(own, e), r))
    out = {k: summary(v) for k, v in rows.items() if v}
    out["per_eye"] = {k: [{m: round(r[m], 2) for m in ("corner", "lid", "width")} for r in v]
                      for k, v in rows.items() if len(v) == 2}
    return out


def _line(name: str, who: str, s: dict) -> str:
    c, lid = s["corner"], s["lid"]
    return (f"{name:18s} {who:16s} corner {c['mean_px']:6.2f} px ({c['mean_pc']:5.1f} %) max "
            f"{c['max_px']:6.2f} ({c['max_pc']:5.1f} %) | lid {lid['mean_px']:6.2f} px "
            f"({lid['mean_pc']:5.1f} %) max {lid['max_px']:6.2f} ({lid['max_pc']:5.1f} %) | dy "
            f"up {s['upper_dy']['mean_px']:+6.2f} low {s['lower_dy']['mean_px']:+6.2f}")


def main() -> int:
    from facetransfer.assets import data_dir
    from facetransfer.default_model import load_default_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/benchmarks", help="output folder")
    ap.add_argument("--clips", default=",".join(CLIPS), help="real clips ('' for none)")
    ap.add_argument("--no-photos", action="store_true", help="the clips only")
    ap.add_argument("--save-tracks", default=None, help="write each clip's track here")
    ap.add_argument("--every", type=int, default=2, help="the shown opening every Nth frame")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if data_dir() is None:
        raise SystemExit("set FACETRANSFER_DATA_DIR to the asset mirror")
    data = Path(data_dir())
    model = load_default_model()
    opening = Opening(model)
    report = {"clips": {}, "photos": {}}
    for name in filter(None, args.clips.split(",")):
        r = report["clips"][name] = measure_clip(
            name, data, model, opening, out / "detections",
            None if args.save_tracks is None else Path(args.save_tracks), args.every)
        for who in ("loop", "shown", "points", "intrinsic", "floor"):
            print(_line(name, who, r[who]), flush=True)
    for name in () if args.no_photos else PHOTOS:
        r = report["photos"][name] = measure_photo(name, data, model, opening)
        for who in r:
            if who != "per_eye":
                print(_line(name, who, r[who]), flush=True)
        print(f"{name:18s} per eye (subject's right, left): " + "; ".join(
            f"{who} " + " / ".join(f"{e['corner']:.1f} {e['lid']:.1f}" for e in v)
            for who, v in r["per_eye"].items()), flush=True)
    save_json(report, out / "eye_openings.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

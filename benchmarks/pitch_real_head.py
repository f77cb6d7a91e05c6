"""Does Face Landmarker show a *real* head's pitch too small, or only a painted one's? (issue 12)

``calibrate_pitch.py`` found that a rigid weak-perspective pose of the true 3-D face fitted to
Face Landmarker's points on the OpenCV-painted synthetic faces (``_cvpaint.py``: flat-shaded
polygons, per-vertex albedo) pitches only 0.84-0.91 times as much as the head, and
``CaptureOptions.pitch_gain = 0.92`` divides the tracked pitch by that. If the attenuation were
an artefact of the painted faces, the gain would make every real transfer nod 9 % too much.

This experiment repeats the measurement on a real 3-D scan with a photographic colour map, the
Lee Perry-Smith head (``$FACETRANSFER_DATA_DIR/lee-perry-smith/LeePerrySmith.glb``, CC-BY 3.0
Lee Perry-Smith / Infinite Realities; eyes closed, head and shoulders), rendered by a small
z-buffered per-pixel textured rasteriser written here (numpy / OpenCV only, not facetransfer's
renderer): 512x512, barycentric UV interpolation (screen space) with bilinear texture lookup,
Gouraud-interpolated Lambert shading from a light at the camera, 2x supersampling, plain grey
background, the face (MediaPipe 234-454) 45 % of the width. Cameras: orthographic and pinholes
at 40, 20, 12 and 8 model units from the head centre (the face is ~2.8 units wide, ~14 cm: about
200, 100, 60 and 40 cm; 20 is the painter's 100 cm in face widths). The same procedure is run on
painted synthetic faces (``_cvpaint.paint`` of the first calibration identities of
``calibrate_landmarks.py``, neutral expression, the painter's background and camera: the
benchmark's 1200 px focal at 100 cm, and 600 px at 50 cm), so all figures come from the same
fitting code.

Procedure, per face and camera:

1. render pitches -25..25 degrees in 2.5-degree steps at yaw 0, +20 and -20 (roll 0; the
   rotation is ``_cvpaint.rotation_ypr``: ``Rx(pitch) Ry(yaw)``, positive pitch chin down; the
   scan turns about its head centre, the painted faces about the FaceKit origin as in the
   benchmark's clips);
2. Face Landmarker (IMAGE mode, ``MediaPipeDetector.detect478``: pixels ``x W - 0.5``) on each;
3. correspondence: the 478 points detected on the frontal render (pitch 0, yaw 0) are cast onto
   the mesh with the known camera (front-most triangle containing the point in the image,
   barycentric coordinates) -> 478 surface points (a point no triangle covers, 2-7 of them on
   the face's outline, is left out);
4. per render, a rigid weak-perspective pose of these surface points fitted to the render's
   detections (``fit_affine_pose`` then 6 Gauss-Newton steps of ``pose_gauss_newton``: the fit of
   ``calibrate_pitch.rigid_pitch``), pitch ``atan2(-R12, R22)`` and yaw ``asin(R02)`` of
   ``R = Rx(a) Ry(b) Rz(c)``. Point sets: ``mp478`` (uniform weights), ``mp442_no_oval`` (without
   MediaPipe's face-oval points), ``ibug68`` / ``ibug68_capture_w`` / ``ibug51_capture_w`` (the
   surface points combined as ``mediapipe_to_ibug`` combines the 2-D points, uniform or
   ``capture_point_weights``, 51: without the jaw line) and, on the painted faces,
   ``true68_capture_w`` (the true landmark vertices: ``calibrate_pitch.py``'s own measure);
5. slope / intercept / r of the fitted pitch against the true pitch per yaw ("vs_true"), and
   against the same fit to the exact projections of the same 3-D points ("vs_exact", the
   detector's gain as ``calibrate_pitch.py`` defines it: under perspective a weak-perspective fit
   of exact points is itself off, 1.06 times the true pitch for the painted faces turning about
   the FaceKit origin at 100 cm); the same for yaw over all renders.

A detector that follows the surface gives slope 1; ``calibrate_pitch.py``'s attenuation gives
0.84 (median over its clips).

Usage::

    FACETRANSFER_DATA_DIR=... python benchmarks/pitch_real_head.py [--out out/pitch_real_head]
        [--cache out/benchmarks/capture_cache] [--painted 2] [--painted-distances 100,50]
        [--scan-distances 0,40,20,12,8] [--step 2.5]

Writes ``OUT/pitch_real_head.json``, ``OUT/pitch_real_head.png`` (fitted against true pitch,
``mp478``), ``OUT/renders_<face>.jpg`` (every second pitch with the detected points) and
``OUT/frontal_<face>.png``. About 7 minutes on one core (the scan's renders: ~1 s each).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _cvpaint as cvp  # noqa: E402

log = logging.getLogger("pitch_real_head")

SIZE = 512
YAWS = (0.0, 20.0, -20.0)
MP_EYE_CORNERS = (33, 263)       # MediaPipe outer eye corners (the fit's length unit)


# ------------------------------------------------------------------------------ angles
def pitch_of(R: np.ndarray) -> float:
    """Pitch ``a`` (degrees) of ``R = Rx(a) Ry Rz``."""
    return float(np.degrees(np.arctan2(-R[1, 2], R[2, 2])))


def yaw_of(R: np.ndarray) -> float:
    """Yaw ``b`` (degrees) of ``R = Rx(a) Ry(b) Rz``."""
    return float(np.degrees(np.arcsin(np.clip(R[0, 2], -1.0, 1.0))))


# ------------------------------------------------------------------------------ the scan
def load_scan(data_dir: Path):
    """The Lee Perry-Smith head: vertices (n, 3) (y up, face toward +z), faces (m, 3),
    UVs (n, 2) with v flipped from glTF's (texture row ``v H``; trimesh's glTF loader does the
    flip: the nose tip's raw v is 0.61, its row in ``Map-COL.jpg`` 0.39 H), vertex normals
    (n, 3), colour map (H, W, 3) RGB uint8."""
    import trimesh

    scene = trimesh.load(data_dir / "lee-perry-smith" / "LeePerrySmith.glb")
    mesh = scene.to_geometry() if hasattr(scene, "to_geometry") else scene
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    UV = np.asarray(mesh.visual.uv, np.float64)
    N = np.asarray(mesh.vertex_normals, np.float64)
    tex = cv2.imread(str(data_dir / "lee-perry-smith" / "Map-COL.jpg"), cv2.IMREAD_COLOR)
    if tex is None:
        raise FileNotFoundError("Map-COL.jpg")
    return V, F, UV, N, cv2.cvtColor(tex, cv2.COLOR_BGR2RGB)


_LIGHT = np.array([0.0, 0.25, 1.0]) / np.linalg.norm([0.0, 0.25, 1.0])


def rasterise(P: np.ndarray, depth: np.ndarray, F: np.ndarray, UV: np.ndarray,
              shade: np.ndarray, tex: np.ndarray, size: int, bg: float = 0.5,
              ss: int = 2) -> np.ndarray:
    """Z-buffered per-pixel textured rasteriser.

    ``P`` (n, 2) pixel positions of the vertices (pixel centres at integers, y down), ``depth``
    (n,) larger = nearer, ``UV`` (n, 2) (texture pixel ``(u W, v H)``, row 0 at the top),
    ``shade`` (n,) per-vertex shading factor (interpolated). Per pixel of a ``ss`` times larger
    grid: the nearest triangle covering the pixel centre, its barycentric UV and shade; the
    colour map sampled bilinearly; area-averaged down. Returns (size, size, 3) uint8 RGB.
    """
    S = size * ss
    Q = P * ss + (ss - 1) / 2.0
    zbuf = np.full((S, S), -np.inf)
    ubuf = np.zeros((S, S))
    vbuf = np.zeros((S, S))
    sbuf = np.zeros((S, S))
    tri = Q[F]                                                   # (m, 3, 2)
    lo = np.floor(tri.min(axis=1)).astype(int)
    hi = np.ceil(tri.max(axis=1)).astype(int)
    lo = np.clip(lo, 0, S - 1)
    hi = np.clip(hi, 0, S - 1)
    Ht, Wt = tex.shape[:2]
    tu = UV[:, 0] * Wt - 0.5
    tv = UV[:, 1] * Ht - 0.5
    for i in range(len(F)):
        x0, y0 = lo[i]
        x1, y1 = hi[i]
        if x1 < x0 or y1 < y0:
            continue
        a, b, c = tri[i]
        den = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(den) < 1e-12:
            continue
        ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        xs = xs.astype(np.float64)
        ys = ys.astype(np.float64)
        l0 = ((b[1] - c[1]) * (xs - c[0]) + (c[0] - b[0]) * (ys - c[1])) / den
        l1 = ((c[1] - a[1]) * (xs - c[0]) + (a[0] - c[0]) * (ys - c[1])) / den
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        if not inside.any():
            continue
        f = F[i]
        z = l0 * depth[f[0]] + l1 * depth[f[1]] + l2 * depth[f[2]]
        sub = zbuf[y0:y1 + 1, x0:x1 + 1]
        win = inside & (z > sub)
        if not win.any():
            continue
        sub[win] = z[win]
        ubuf[y0:y1 + 1, x0:x1 + 1][win] = (l0 * tu[f[0]] + l1 * tu[f[1]] + l2 * tu[f[2]])[win]
        vbuf[y0:y1 + 1, x0:x1 + 1][win] = (l0 * tv[f[0]] + l1 * tv[f[1]] + l2 * tv[f[2]])[win]
        sbuf[y0:y1 + 1, x0:x1 + 1][win] = (l0 * shade[f[0]] + l1 * shade[f[1]]
                                           + l2 * shade[f[2]])[win]
    col = cv2.remap(tex, ubuf.astype(np.float32), vbuf.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT).astype(np.float64)
    img = np.where(np.isfinite(zbuf)[..., None], col * sbuf[..., None], bg * 255.0)
    img = np.clip(img, 0, 255).astype(np.uint8)
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


class ScanFace:
    """The scan under an orthographic camera (``distance`` 0) or a pinhole ``distance`` model
    units in front of the head centre; rotation about the head centre, scale set so the face
    (MediaPipe 234-454) is 45 % of the width (:meth:`calibrate`)."""

    def __init__(self, data_dir: Path, distance: float = 0.0):
        self.V, self.F, self.UV, self.N, self.tex = load_scan(data_dir)
        self.distance = float(distance)
        self.name = "lee_perry_smith_" + (f"persp{distance:g}" if distance else "ortho")
        V = self.V
        # head centre: the mid-point of the head's top half (the bust's upper part)
        top = V[:, 1] > np.percentile(V[:, 1], 55)
        self.pivot = np.array([0.0, np.median(V[top, 1]), np.median(V[top, 2])])
        self.scale = 60.0                       # pixels per model unit (at the pivot's depth)
        self.centre = np.zeros(2)               # image position of the pivot (offset from mid)

    def _pixels(self, Xc: np.ndarray) -> np.ndarray:
        c = (SIZE - 1) / 2.0 + self.centre
        f = self.scale if not self.distance else self.scale * self.distance / (
            self.distance - Xc[:, 2])
        return np.stack([c[0] + f * Xc[:, 0], c[1] - f * Xc[:, 1]], axis=1)

    def camera_points(self, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertices' pixels (n, 2) and depth (n,) (larger nearer) at rotation ``R``."""
        Xc = (self.V - self.pivot) @ R.T
        return self._pixels(Xc), Xc[:, 2]

    def project_model(self, X: np.ndarray, R: np.ndarray) -> np.ndarray:
        return self._pixels((X - self.pivot) @ R.T)

    def render(self, R: np.ndarray) -> np.ndarray:
        P, z = self.camera_points(R)
        n = self.N @ R.T
        if self.distance:     # light from the camera's position
            L = np.array([0.0, 0.25 * self.distance, self.distance]) - (self.V - self.pivot) @ R.T
            L /= np.linalg.norm(L, axis=1, keepdims=True)
            shade = 0.3 + 0.8 * np.clip(np.einsum("nk,nk->n", n, L), 0.0, 1.0)
        else:
            shade = 0.3 + 0.8 * np.clip(n @ _LIGHT, 0.0, 1.0)
        return rasterise(P, z, self.F, self.UV, shade, self.tex, SIZE)

    def calibrate(self, detector) -> None:
        """Scale and centre so the face (MediaPipe 234-454) is ~45 % of the image width and
        centred, from a frontal render."""
        for _ in range(2):
            pts = detector.detect478(self.render(np.eye(3)))
            if pts is None:
                raise RuntimeError("no face on the frontal calibration render")
            width = float(np.linalg.norm(pts[234] - pts[454]))
            self.scale *= 0.45 * SIZE / width
            mid = pts[[234, 454, 10, 152]].mean(axis=0) - (SIZE - 1) / 2.0
            self.centre = (self.centre - mid) * 0.45 * SIZE / width
        pts = detector.detect478(self.render(np.eye(3)))
        log.info("scan: %.2f px per unit, face width %.0f px", self.scale,
                 np.linalg.norm(pts[234] - pts[454]))


class PaintedFace:
    """A calibration identity of ``calibrate_landmarks.py`` (neutral expression) painted by
    ``_cvpaint`` with its mild-perspective camera and background."""

    def __init__(self, fk, k: int, distance: float = 100.0):
        import _capture_data as cd
        from calibrate_landmarks import CALIB_INDEX0

        index = CALIB_INDEX0 + k
        self.name = f"painted_calib{k:02d}" + ("" if distance == 100.0 else f"_d{distance:g}")
        rng = np.random.default_rng([*cd.SEED_STREAM, int(index), 1])
        w = cd.identity_weights(index, fk.scale)
        self.V = fk.neutral + np.tensordot(w, fk.identity.astype(np.float64), axes=1)
        self.F = fk.faces
        alb, cull, amb = cd.albedo(fk, rng)
        self.scene = cvp.PaintScene(fk.faces, alb, cull, amb)
        # the benchmark's camera (focal 1200 px at 100 cm); other distances keep the scale
        self.cam = cvp.Camera(focal=12.0 * distance, distance=distance, size=(SIZE, SIZE))
        self.bg = cvp.background((SIZE, SIZE), rng)
        self.cull = cull
        self.landmarks = np.asarray(fk.landmarks)

    def camera_points(self, R):
        Xc = cvp.to_camera(self.V, R, np.zeros(3))
        return cvp.project(Xc, self.cam), Xc[:, 2]

    def project_model(self, X, R):
        return cvp.project(cvp.to_camera(X, R, np.zeros(3)), self.cam)

    def render(self, R):
        return cvp.paint(self.scene, cvp.to_camera(self.V, R, np.zeros(3)), self.cam, self.bg)

    def calibrate(self, detector) -> None:
        pass


# ------------------------------------------------------------------------------ procedure
def cast(q: np.ndarray, P: np.ndarray, depth: np.ndarray, F: np.ndarray, V: np.ndarray,
         chunk: int = 64) -> np.ndarray:
    """Surface points (k, 3) of ``V`` under 2-D points ``q`` (k, 2): the front-most triangle
    containing each point in the image (vertex pixels ``P``, ``depth`` larger nearer),
    barycentric in the image. NaN where no triangle covers the point."""
    tri = P[F]                                                   # (m, 3, 2)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    ok = np.abs(den) > 1e-12
    den = np.where(ok, den, 1.0)
    out = np.full((len(q), 3), np.nan)
    for s in range(0, len(q), chunk):
        x = q[s:s + chunk, 0][:, None]
        y = q[s:s + chunk, 1][:, None]
        l0 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / den
        l1 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / den
        l2 = 1.0 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9) & ok
        z = l0 * depth[F[:, 0]] + l1 * depth[F[:, 1]] + l2 * depth[F[:, 2]]
        z = np.where(inside, z, -np.inf)
        j = np.argmax(z, axis=1)
        hit = np.isfinite(z[np.arange(len(j)), j])
        r = np.arange(len(j))
        L = np.stack([l0[r, j], l1[r, j], l2[r, j]], axis=1)     # (k, 3)
        X = np.einsum("kt,ktd->kd", L, V[F[j]])
        X[~hit] = np.nan
        out[s:s + chunk] = X
    return out


def rigid_fit(X: np.ndarray, p: np.ndarray, w: np.ndarray, eyes: tuple[int, int]
              ) -> tuple[float, float]:
    """(pitch, yaw) of the weak-perspective pose of ``X`` (k, 3) best fitting ``p`` (k, 2) with
    weights ``w`` (k,) (``calibrate_pitch.rigid_pitch``'s fit; ``eyes``: the length unit)."""
    from facetransfer.track.camera import fit_affine_pose
    from facetransfer.track.fit2d import Targets, pose_gauss_newton

    use = w > 0
    pose = fit_affine_pose(X[use], p[use])
    pose = pose_gauss_newton(X, Targets.stack([(p, w)], w), pose,
                             float(np.linalg.norm(p[eyes[0]] - p[eyes[1]])), iterations=6)
    return pitch_of(pose.rotation), yaw_of(pose.rotation)


def line(x, y) -> dict:
    x, y = np.asarray(x, float), np.asarray(y, float)
    k, b = np.polyfit(x, y, 1)
    return {"slope": round(float(k), 4), "intercept": round(float(b), 3),
            "r": round(float(np.corrcoef(x, y)[0, 1]), 5), "n": int(len(x))}


#: MediaPipe's face-oval points (``FaceLandmarksConnections.FACE_LANDMARKS_FACE_OVAL``).
MP_OVAL = (10, 21, 54, 58, 67, 93, 103, 109, 127, 132, 136, 148, 149, 150, 152, 162, 172, 176,
           234, 251, 284, 288, 297, 323, 332, 338, 356, 361, 365, 377, 378, 379, 389, 397, 400,
           454)


def variants(face, X: np.ndarray) -> dict:
    """The point sets fitted: name -> (3-D points (k, 3), detections (478, 2) -> targets (k, 2),
    weights (k,), eye-corner indices). ``X``: the cast surface points (478, 3), NaN off mesh."""
    from facetransfer.track.capture import capture_point_weights
    from facetransfer.track.landmarks import mediapipe_to_ibug

    ok = np.isfinite(X).all(axis=1)
    X0 = np.where(ok[:, None], X, 0.0)
    X68 = mediapipe_to_ibug(X0)
    ok68 = np.abs(mediapipe_to_ibug(np.where(ok, 0.0, 1.0)[:, None]))[:, 0] < 1e-9
    cw = capture_point_weights()
    inner = np.ones(478, bool)
    inner[list(MP_OVAL)] = False
    i51 = np.arange(68) >= 17
    to68 = mediapipe_to_ibug
    out = {
        "mp478": (X0, lambda p: p, ok * 1.0, MP_EYE_CORNERS),
        "mp442_no_oval": (X0, lambda p: p, (ok & inner) * 1.0, MP_EYE_CORNERS),
        "ibug68": (X68, to68, ok68 * 1.0, (36, 45)),
        "ibug68_capture_w": (X68, to68, ok68 * cw, (36, 45)),
        "ibug51_capture_w": (X68, to68, ok68 * cw * i51, (36, 45)),
    }
    if getattr(face, "landmarks", None) is not None:      # calibrate_pitch.py's own measure
        out["true68_capture_w"] = (face.V[face.landmarks], to68, cw, (36, 45))
    return out


def run_face(face, detector, pitches, out: Path) -> dict:
    face.calibrate(detector)
    renders = []
    for yaw in YAWS:
        for pit in pitches:
            R = cvp.rotation_ypr(yaw, pit, 0.0)
            img = face.render(R)
            pts = detector.detect478(img)
            renders.append({"yaw": yaw, "pitch": pit, "R": R, "img": img, "pts": pts})
        log.info("%s: yaw %+g rendered and detected", face.name, yaw)
    missing = [(r["yaw"], r["pitch"]) for r in renders if r["pts"] is None]
    front = next(r for r in renders if r["yaw"] == 0 and r["pitch"] == 0)
    if front["pts"] is None:
        raise RuntimeError(f"{face.name}: no face on the frontal render")
    P, z = face.camera_points(front["R"])
    X = cast(front["pts"], P, z, face.F, face.V)
    miss = ~np.isfinite(X).all(axis=1)
    if miss.any():
        log.warning("%s: detected points %s miss the mesh (left out)", face.name,
                    np.flatnonzero(miss).tolist())
    sets = variants(face, X)
    rows = []
    for r in renders:
        if r["pts"] is None:
            continue
        row = {"yaw": r["yaw"], "pitch": r["pitch"]}
        for name, (X3, tgt, w, eyes) in sets.items():
            fit = rigid_fit(X3, tgt(r["pts"]), w, eyes)
            exact = rigid_fit(X3, face.project_model(X3, r["R"]), w, eyes)
            row[name] = {"fit": [round(v, 3) for v in fit], "exact": [round(v, 3) for v in exact]}
        rows.append(row)
    res = {"face": face.name, "renders": len(renders), "no_face": missing,
           "points_off_mesh": np.flatnonzero(miss).tolist(), "sets": {}, "rows": rows}
    for name in sets:
        d = {}
        for yaw in YAWS:
            rr = [q for q in rows if q["yaw"] == yaw]
            fit = [q[name]["fit"][0] for q in rr]
            exact = [q[name]["exact"][0] for q in rr]
            d[f"pitch_yaw{yaw:+g}"] = {"vs_true": line([q["pitch"] for q in rr], fit),
                                       "vs_exact": line(exact, fit),
                                       "exact_vs_true": line([q["pitch"] for q in rr], exact)}
        d["yaw_vs_true"] = line([q["yaw"] for q in rows], [q[name]["fit"][1] for q in rows])
        d["yaw_vs_exact"] = line([q[name]["exact"][1] for q in rows],
                                 [q[name]["fit"][1] for q in rows])
        res["sets"][name] = d
    contact_sheet(face.name, renders, pitches, out)
    return res


def contact_sheet(name: str, renders, pitches, out: Path) -> None:
    """Every second pitch per yaw, 128 px tiles with the detected points; full-size frontal."""
    tiles = []
    for yaw in YAWS:
        row = []
        for pit in pitches[::2]:
            r = next(q for q in renders if q["yaw"] == yaw and q["pitch"] == pit)
            im = cv2.cvtColor(r["img"], cv2.COLOR_RGB2BGR)
            if r["pts"] is not None:
                for x, y in r["pts"]:
                    cv2.circle(im, (int(round(x)), int(round(y))), 1, (0, 255, 0), -1)
            else:
                cv2.putText(im, "NO FACE", (20, 60), cv2.FONT_HERSHEY_SIMPLEX, 2, (0, 0, 255), 4)
            cv2.putText(im, f"y{yaw:+.0f} p{pit:+.1f}", (8, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.4,
                        (255, 255, 255), 3)
            row.append(cv2.resize(im, (160, 160), interpolation=cv2.INTER_AREA))
        tiles.append(np.concatenate(row, axis=1))
    cv2.imwrite(str(out / f"renders_{name}.jpg"), np.concatenate(tiles, axis=0))
    front = next(q for q in renders if q["yaw"] == 0 and q["pitch"] == 0)
    cv2.imwrite(str(out / f"frontal_{name}.png"), cv2.cvtColor(front["img"], cv2.COLOR_RGB2BGR))


def plot(results: list[dict], path: Path, name: str = "mp478") -> None:
    """Fitted (point set ``name``) against true pitch, one panel per face and camera."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nc = min(len(results), 4)
    nr = -(-len(results) // nc)
    fig, axes = plt.subplots(nr, nc, figsize=(4.0 * nc, 4.0 * nr), squeeze=False)
    for ax in axes.ravel()[len(results):]:
        ax.axis("off")
    for ax, res in zip(axes.ravel(), results):
        for yaw, col in zip(YAWS, ("k", "tab:red", "tab:blue")):
            rr = [q for q in res["rows"] if q["yaw"] == yaw]
            d = res["sets"][name][f"pitch_yaw{yaw:+g}"]
            ax.plot([q["pitch"] for q in rr], [q[name]["fit"][0] for q in rr], "o", ms=3,
                    color=col, label=f"yaw {yaw:+g}: slope {d['vs_true']['slope']:.3f} "
                                     f"(/exact fit {d['vs_exact']['slope']:.3f})")
        ax.plot([-25, 25], [-25, 25], "--", color="grey", lw=0.8, label="slope 1")
        ax.set_title(res["face"], fontsize=9)
        ax.set_xlabel("true pitch (deg)")
        ax.set_ylabel(f"rigid fit to Face Landmarker ({name}), deg", fontsize=8)
        ax.legend(fontsize=6.5)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/pitch_real_head")
    ap.add_argument("--painted", type=int, default=2, help="painted calibration identities")
    ap.add_argument("--painted-distances", default="100,50",
                    help="painter camera distances, cm (100: the benchmark's camera)")
    ap.add_argument("--step", type=float, default=2.5)
    ap.add_argument("--scan-distances", default="0,40,20,12,8",
                    help="scan camera distances in model units (0: orthographic; the face is "
                         "~2.8 units wide, so 20 is the painter's 100 cm for a 14 cm face)")
    ap.add_argument("--cache", default="out/benchmarks/capture_cache",
                    help="FaceKit cache of bench_capture / calibrate_landmarks")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s",
                        datefmt="%H:%M:%S")
    from _mp_video import filtered_stderr
    from facetransfer.track.init import MediaPipeDetector

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pitches = [round(float(v), 3) for v in np.arange(-25.0, 25.0 + 1e-9, args.step)]
    faces = [ScanFace(Path(os.environ["FACETRANSFER_DATA_DIR"]), float(d))
             for d in args.scan_distances.split(",")]
    if args.painted:
        import _capture_data as cd

        fk = cd.load_facekit(Path(args.cache))
        faces += [PaintedFace(fk, k, float(d)) for d in args.painted_distances.split(",")
                  for k in range(args.painted)]
    results = []
    with filtered_stderr(True), MediaPipeDetector() as det:
        for face in faces:
            results.append(run_face(face, det, pitches, out))
            for name, d in results[-1]["sets"].items():
                log.info("%s %s: pitch slope vs true %s, vs exact fit %s; yaw %.3f", face.name,
                         name, [d[f"pitch_yaw{y:+g}"]["vs_true"]["slope"] for y in YAWS],
                         [d[f"pitch_yaw{y:+g}"]["vs_exact"]["slope"] for y in YAWS],
                         d["yaw_vs_true"]["slope"])
    (out / "pitch_real_head.json").write_text(json.dumps(results, indent=1))
    plot(results, out / "pitch_real_head.png")
    summary = {r["face"]: {"no_face": r["no_face"]}
               | {name: {**{f"pitch_yaw{y:+g}": [d[f"pitch_yaw{y:+g}"]["vs_true"]["slope"],
                                                 d[f"pitch_yaw{y:+g}"]["vs_exact"]["slope"]]
                            for y in YAWS}, "yaw": d["yaw_vs_true"]["slope"]}
                  for name, d in r["sets"].items()}
               for r in results}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

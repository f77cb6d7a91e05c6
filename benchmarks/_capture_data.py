"""Synthetic capture clips for ``bench_capture.py``: faces outside the model's training set,
ARKit performances with blinks, painted by OpenCV (:mod:`_cvpaint`), with per-frame truth.

A clip is made in four steps:

1. a *fresh* identity: ``neutral + Σ_c w_c (identity_c - neutral)`` over the ICT-FaceKit's 100
   identity components with ``w ~ N(0, scale²)`` (``scale`` from the recipe file, as the data set
   builder) drawn from ``default_rng([20261201, 12, k])`` -- a seed stream the builder
   (``default_rng(seed)``) never uses; :func:`identity_distance` checks the draw against the
   model's training identities;
2. its ARKit blendshapes, made identity-specific exactly as ``facetransfer.datasets.ict`` does:
   the generic FaceKit offsets of ``arkit_facekit.json`` carried onto the identity's face by
   deformation transfer (Sumner & Popović 2004) with the builder's anchors; the parts outside the
   face area (back of the head, mouth interior, teeth, eyeballs) take the generic offsets;
3. a performance: smooth ARKit activation curves (fast blinks of 4-6 frames, jaw, smiles left and
   right, brows up and down, pucker and funnel, squint and widen) and head yaw / pitch up to
   ±30 degrees, with a "hard start" (turned head, open mouth, closed eyes) on frame 0;
4. painting every frame with a mild perspective camera, 512x512, 30 fps, H.264 (imageio-ffmpeg).

Truth per frame: the 68 iBUG landmarks in pixels (FaceKit ``vertex_indices.json``), the face-area
vertices (cm, model frame, before the pose), the 52 activations (``ARKIT_NAMES`` order,
``tongueOut`` = 0) and the pose (yaw, pitch, roll in degrees, rotation, camera shift).
Clips are cached in ``CACHE/synthetic-v{DATA_VERSION}-...`` and rebuilt only when
:data:`DATA_VERSION` or the clip's recipe changes.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import _cvpaint as cvp

log = logging.getLogger("bench_capture.data")

#: Bump when the generated clips change for the same recipe.
DATA_VERSION = 3
#: Seed stream of the fresh identities (the data set builder uses ``default_rng(seed)``).
SEED_STREAM = (20261201, 12)
FPS = 30.0
SIZE = (512, 512)

# FaceKit vertex ranges (upstream README; checked against the mesh's connected components).
FACE_END = 9409                      # 0..9408 full face area (the model's region "face")
HEAD = (9409, 11248)                 # head and neck
MOUTH = (11248, 13294)               # mouth socket
EYE_SOCKET = (13294, 14062)
GUMS = (14062, 17039)                # gums and tongue
TEETH = (17039, 21451)
EYEBALLS = ((22221, 23021), (23791, 24591))   # the spherical eyeball shells (left, right)
N_USED = 24591


@dataclass(frozen=True)
class ClipSpec:
    """Recipe of one synthetic clip (everything that determines it)."""

    name: str
    index: int                       # identity and performance seed
    n_frames: int = 120
    yaw0: float = 0.0                # head pose on frame 0 (degrees)
    pitch0: float = 0.0
    start: tuple = ()                # ((ARKit name, activation on frame 0), ...)

    def key(self) -> str:
        blob = json.dumps(asdict(self) | {"v": DATA_VERSION}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]


#: The benchmark's clips: each starts hard on frame 0.
CLIPS = (
    ClipSpec("turned", 1, yaw0=30.0, pitch0=-12.0),
    ClipSpec("mouth_open", 2, yaw0=-22.0, pitch0=18.0, start=(("jawOpen", 0.75),)),
    ClipSpec("eyes_closed", 3, yaw0=18.0, pitch0=-25.0,
             start=(("eyeBlinkLeft", 1.0), ("eyeBlinkRight", 1.0))),
    ClipSpec("smile_turned", 4, yaw0=-30.0, pitch0=8.0,
             start=(("mouthSmileLeft", 0.8), ("mouthSmileRight", 0.7), ("browInnerUp", 0.6))),
)


# ------------------------------------------------------------------------------ FaceKit parts
def _cache_array(path: Path, build) -> np.ndarray:
    if path.is_file():
        try:
            return np.load(path)
        except (OSError, ValueError):
            log.warning("rebuilding unreadable %s", path)
    arr = build()
    from facetransfer.io.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        np.save(tmp, arr)
    return arr


def _read_vertices(rel: str) -> np.ndarray:
    from facetransfer import assets
    from facetransfer.io.mesh import read_obj_vertices

    v = read_obj_vertices(assets.asset_file("ict-facekit", rel))
    if len(v) < N_USED:
        raise ValueError(f"ICT-FaceKit {rel} has {len(v)} vertices, expected >= {N_USED}")
    return v[:N_USED]


@dataclass(frozen=True)
class FaceKit:
    """The parts of the FaceKit head the benchmark paints, over vertices ``0..N_USED-1``.

    Attributes
    ----------
    neutral : (N_USED, 3) float64
    faces : (m, 3) int64
        Triangles of the painted parts.
    part : (m,) <U8
        Part of each triangle.
    identity : (100, N_USED, 3) float32
        Identity offsets (scaled by their std).
    generic : (52, N_USED, 3) float32
        Generic ARKit offsets in ``ARKIT_NAMES`` order (0 for ``tongueOut``).
    face_faces : (k, 3) int64
        Triangles of the face area (the data set builder's).
    landmarks : (68,) int64
    rigid : (r,) int64
    scale : float
        Identity weight std of the recipe file.
    """

    neutral: np.ndarray
    faces: np.ndarray
    part: np.ndarray
    identity: np.ndarray
    generic: np.ndarray
    face_faces: np.ndarray
    landmarks: np.ndarray
    rigid: np.ndarray
    scale: float


def _part_of(first: np.ndarray) -> np.ndarray:
    part = np.full(len(first), "", dtype="<U8")
    bounds = [("face", 0, FACE_END), ("head", *HEAD), ("mouth", *MOUTH), ("socket", *EYE_SOCKET),
              ("gums", *GUMS), ("teeth", *TEETH), ("eyeL", *EYEBALLS[0]), ("eyeR", *EYEBALLS[1])]
    for name, a, b in bounds:
        part[(first >= a) & (first < b)] = name
    return part


def load_facekit(cache: Path) -> FaceKit:
    """Read (or take from ``cache``) the FaceKit parts and offsets."""
    from facetransfer import assets
    from facetransfer.arkit import ARKIT_NAMES, load_facekit_mapping
    from facetransfer.datasets.ict import ict_template, load_recipes
    from facetransfer.io.mesh import read_obj

    full = read_obj(assets.asset_file("ict-facekit", "generic_neutral_mesh.obj"))
    neutral = full.vertices[:N_USED].astype(np.float64)
    faces = full.faces[(full.faces < N_USED).all(axis=1)]
    part = _part_of(faces.min(axis=1))
    keep = part != ""
    faces, part = faces[keep], part[keep]
    tag = assets.ICT_COMMIT[:12]
    identity = _cache_array(cache / f"facekit-identity-{tag}-{N_USED}.npy", lambda: np.stack(
        [_read_vertices(f"identity{c:03d}.obj") - neutral for c in range(100)]).astype(np.float32))
    mapping = load_facekit_mapping()["shapes"]

    def generic_offsets():
        files = sorted({f for m in mapping.values() for f in m})
        off = {f: _read_vertices(f"{f}.obj") - neutral for f in files}
        out = np.zeros((len(ARKIT_NAMES), N_USED, 3), np.float32)
        for j, name in enumerate(ARKIT_NAMES):
            for f, w in mapping.get(name, {}).items():
                out[j] += float(w) * off[f]
        return out

    mtag = hashlib.sha256(json.dumps(mapping, sort_keys=True).encode()).hexdigest()[:8]
    generic = _cache_array(cache / f"facekit-arkit-{tag}-{mtag}-{N_USED}.npy", generic_offsets)
    tmpl = ict_template("face")
    scale = float(load_recipes().get("identity", {}).get("scale", 1.0))
    return FaceKit(neutral, faces, part, identity, generic, tmpl.mesh.faces, tmpl.landmarks,
                   tmpl.rigid, scale)


# ------------------------------------------------------------------------------ identities
def identity_weights(index: int, scale: float) -> np.ndarray:
    """The fresh identity ``index``'s 100 weights (the benchmark's own seed stream), (100,)."""
    rng = np.random.default_rng([*SEED_STREAM, int(index)])
    return scale * rng.standard_normal(100)


def identity_distance(w: np.ndarray, training: np.ndarray | None) -> float | None:
    """Smallest Euclidean distance (in identity std units) from ``w`` to training weights.

    ``training``: (k, 100), e.g. the model's ``provenance["identity_weights"]``.
    """
    if training is None or len(training) == 0:
        return None
    T = np.asarray(training, dtype=np.float64)
    return float(np.linalg.norm(T - w, axis=1).min())


def identity_rig(fk: FaceKit, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The identity's neutral (N_USED, 3) and its 52 ARKit deltas (52, N_USED, 3).

    Face-area deltas by deformation transfer as in ``datasets.ict.build_ict_dataset`` (step 3);
    other parts take the generic offsets.
    """
    from facetransfer.datasets.deformation import (DeformationTransfer, component_anchors,
                                                   deformation_gradients)

    neutral = fk.neutral + np.tensordot(w, fk.identity.astype(np.float64), axes=1)
    n = FACE_END
    gen = fk.generic[:, :n].astype(np.float64)
    used = np.flatnonzero(np.abs(gen).reshape(len(gen), -1).max(axis=1) > 0)
    motion = np.linalg.norm(gen[used], axis=2).sum(axis=0)
    preferred = fk.rigid[np.argsort(motion[fk.rigid], kind="stable")]
    anchors = component_anchors(n, fk.face_faces, preferred)
    base = fk.neutral[:n]
    Q = deformation_gradients(base, base + gen[used], fk.face_faces)
    dt = DeformationTransfer(neutral[:n], fk.face_faces, anchors)
    P = neutral[:n][dt.fixed] + gen[used][:, dt.fixed, :]
    face = dt.solve(Q, P) - neutral[:n]                                     # (u, n, 3)
    deltas = fk.generic.astype(np.float64)
    deltas[used, :n] = face
    return neutral, deltas


# ------------------------------------------------------------------------------ performance
def _bump(n: int, start: float, attack: float, hold: float, release: float) -> np.ndarray:
    """0..1 raised-cosine pulse over frames 0..n-1."""
    t = np.arange(n, dtype=np.float64)
    up = np.clip((t - start) / max(attack, 1e-6), 0, 1)
    down = np.clip((t - start - attack - hold) / max(release, 1e-6), 0, 1)
    return 0.5 - 0.5 * np.cos(np.pi * up) - (0.5 - 0.5 * np.cos(np.pi * down))


_EVENTS = (  # (names, peak range, attack, hold, release frames)
    (("jawOpen",), (0.35, 0.85), (6, 12), (3, 10), (6, 12)),
    (("mouthSmileLeft", "mouthSmileRight"), (0.4, 0.9), (6, 10), (4, 12), (6, 10)),
    (("mouthSmileLeft",), (0.5, 0.9), (6, 10), (4, 10), (6, 10)),
    (("mouthSmileRight",), (0.5, 0.9), (6, 10), (4, 10), (6, 10)),
    (("browInnerUp", "browOuterUpLeft", "browOuterUpRight"), (0.5, 1.0), (4, 8), (4, 10), (5, 9)),
    (("browDownLeft", "browDownRight"), (0.5, 0.9), (4, 8), (4, 10), (5, 9)),
    (("mouthPucker",), (0.5, 0.9), (5, 9), (3, 8), (5, 9)),
    (("mouthFunnel",), (0.4, 0.8), (5, 9), (3, 8), (5, 9)),
    (("eyeSquintLeft", "eyeSquintRight"), (0.4, 0.8), (4, 8), (4, 8), (4, 8)),
    (("eyeWideLeft", "eyeWideRight"), (0.4, 0.8), (4, 8), (4, 8), (4, 8)),
)


def activation_curves(spec: ClipSpec, rng: np.random.Generator) -> np.ndarray:
    """Smooth ARKit activations with blinks, (F, 52) in [0, 1] (``ARKIT_NAMES`` order)."""
    from facetransfer.arkit import ARKIT_NAMES

    F = spec.n_frames
    col = {n: i for i, n in enumerate(ARKIT_NAMES)}
    A = np.zeros((F, len(ARKIT_NAMES)))
    # expression events: two overlapping layers (mouth and upper face) of random events
    for layer in ((0, 1, 2, 3, 6, 7), (4, 5, 8, 9)):
        t = rng.uniform(4, 14)
        while t < F:
            names, peak, att, hold, rel = _EVENTS[int(rng.choice(layer))]
            a, h, r = rng.uniform(*att), rng.uniform(*hold), rng.uniform(*rel)
            pulse = rng.uniform(*peak) * _bump(F, t, a, h, r)
            for n in names:
                A[:, col[n]] += pulse
            t += a + h + r + rng.uniform(2, 12)
    # blinks: 4-6 frames closing and opening, every 18-40 frames; one in five is a wink
    t = rng.uniform(8, 20)
    while t < F - 2:
        a, h = rng.uniform(1.5, 2.5), rng.integers(0, 2)
        r = rng.uniform(2.0, 3.0)
        pulse = _bump(F, t, a, h, r)
        wink = rng.uniform() < 0.2
        for n in (("eyeBlinkLeft",) if wink else ("eyeBlinkLeft", "eyeBlinkRight")):
            A[:, col[n]] = np.maximum(A[:, col[n]], pulse)
        t += rng.uniform(18, 40)
    # hard start: the start values held for 4-8 frames, then released over 6 frames
    hold = rng.uniform(4, 8)
    release = 0.5 + 0.5 * np.cos(np.pi * np.clip((np.arange(F) - hold) / 6.0, 0, 1))
    for n, v in spec.start:
        A[:, col[n]] = np.maximum(A[:, col[n]], v * release)
    return np.clip(A, 0.0, 1.0)


def pose_curves(spec: ClipSpec, rng: np.random.Generator) -> np.ndarray:
    """Yaw, pitch, roll (degrees) and shift x, y (cm) per frame, (F, 5); frame 0 is the start."""
    from scipy.interpolate import PchipInterpolator

    F = spec.n_frames
    knots = np.unique(np.r_[0, np.arange(24, F - 1, 24), F - 1]).astype(float)
    k = len(knots)
    yaw = np.r_[spec.yaw0, rng.uniform(-30, 30, k - 1)]
    pitch = np.r_[spec.pitch0, rng.uniform(-25, 25, k - 1)]
    roll = rng.uniform(-6, 6, k)
    sx, sy = rng.uniform(-1.2, 1.2, k), rng.uniform(-1.0, 1.0, k)
    t = np.arange(F, dtype=float)
    return np.stack([PchipInterpolator(knots, v)(t) for v in (yaw, pitch, roll, sx, sy)], axis=1)


# ------------------------------------------------------------------------------ painting
def albedo(fk: FaceKit, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-triangle albedo (m, 3), cull flags (m,) and ambient shares (m,)."""
    V = fk.neutral
    skin = np.array([0.87, 0.66, 0.54]) * rng.uniform(0.85, 1.1)
    col = np.tile(skin, (N_USED, 1))
    # texture: per-vertex noise plus a smooth mottling (both move with the skin)
    smooth = sum(np.sin(V @ rng.normal(0, 0.9, 3) + rng.uniform(0, 6.3)) for _ in range(6)) / 6
    col *= (1 + 0.10 * smooth[:, None] + 0.09 * rng.standard_normal((N_USED, 1)))
    col *= 1 + 0.03 * rng.standard_normal((N_USED, 3))
    L = V[fk.landmarks]
    xy = V[:FACE_END, :2]
    lips = _inside(xy, L[48:60, :2]) & (V[:FACE_END, 2] > L[33, 2] - 3.0)
    col[:FACE_END][lips] = col[:FACE_END][lips] * np.array([0.82, 0.55, 0.6])
    brow = np.zeros(FACE_END, bool)
    for a, b in ((17, 22), (22, 27)):
        d = _polyline_distance(xy, L[a:b, :2])
        brow |= (d < 0.42) & (V[:FACE_END, 2] > L[27, 2] - 2.5)
    col[:FACE_END][brow] = col[:FACE_END][brow] * np.array([0.38, 0.34, 0.32])
    plain = {"mouth": (0.30, 0.10, 0.12), "gums": (0.55, 0.22, 0.26),
             "teeth": (0.93, 0.91, 0.84), "socket": (0.70, 0.42, 0.42)}
    tri_col = col[fk.faces].mean(axis=1)
    for name, c in plain.items():
        tri_col[fk.part == name] = c
    for name, (a, b) in zip(("eyeL", "eyeR"), EYEBALLS):
        sel = fk.part == name
        tri_col[sel] = _eye_colours(V, fk.faces[sel], a, b)
    inner = np.isin(fk.part, ("mouth", "gums", "teeth", "socket"))
    ambient = np.where(inner, 0.75, np.where(np.char.startswith(fk.part, "eye"), 0.6, 0.3))
    return np.clip(tri_col, 0, 1), ~inner, ambient


def _eye_colours(V, faces, a, b) -> np.ndarray:
    ball = V[a:b]
    c = ball.mean(axis=0)
    front = ball[np.argmax(ball[:, 2])] - c
    front /= np.linalg.norm(front)
    d = V[faces].mean(axis=1) - c
    cosang = (d @ front) / np.linalg.norm(d, axis=1)
    out = np.tile([0.95, 0.94, 0.92], (len(faces), 1))
    out[cosang > np.cos(np.radians(34))] = (0.33, 0.22, 0.13)
    out[cosang > np.cos(np.radians(14))] = (0.03, 0.03, 0.03)
    return out


def _inside(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    import matplotlib.path as mpath

    return mpath.Path(poly).contains_points(p)


def _polyline_distance(p: np.ndarray, line: np.ndarray) -> np.ndarray:
    d = np.full(len(p), np.inf)
    for a, b in zip(line[:-1], line[1:]):
        ab = b - a
        t = np.clip(((p - a) @ ab) / (ab @ ab), 0, 1)
        d = np.minimum(d, np.linalg.norm(p - (a + t[:, None] * ab), axis=1))
    return d


# ------------------------------------------------------------------------------ clips
@dataclass(frozen=True)
class SyntheticClip:
    """A cached synthetic clip and its truth (see the module notes)."""

    name: str
    video: Path
    landmarks: np.ndarray            # (F, 68, 2) pixels
    vertices: np.ndarray             # (F, FACE_END, 3) float32, cm, model frame
    activations: np.ndarray          # (F, 52)
    pose: np.ndarray                 # (F, 5) yaw, pitch, roll (deg), shift x, y (cm)
    identity_weights: np.ndarray     # (100,)

    @property
    def n_frames(self) -> int:
        return len(self.landmarks)


def clip_dir(cache: Path, spec: ClipSpec) -> Path:
    return cache / f"synthetic-v{DATA_VERSION}-{spec.name}-{spec.n_frames}f-{spec.key()}"


def facekit_loader(cache: Path):
    """A function returning the FaceKit (:func:`load_facekit`), read on its first call only:
    for :func:`load_clip` over many clips, most of them already in the cache."""
    holder: dict = {}

    def fk() -> FaceKit:
        if "fk" not in holder:
            log.info("reading the ICT-FaceKit parts (first clip to make only)")
            holder["fk"] = load_facekit(cache)
        return holder["fk"]
    return fk


def load_clip(cache: Path, spec: ClipSpec, fk_loader=None, progress=None) -> SyntheticClip:
    """The clip from the cache, made first if needed (``fk_loader()`` gives the FaceKit)."""
    d = clip_dir(cache, spec)
    video, truth = d / "clip.mp4", d / "truth.npz"
    if not (video.is_file() and truth.is_file()):
        fk = fk_loader() if fk_loader is not None else load_facekit(cache)
        make_clip(fk, spec, d, progress=progress)
    with np.load(truth) as z:
        return SyntheticClip(spec.name, video, z["landmarks"], z["vertices"], z["activations"],
                             z["pose"], z["identity_weights"])


def make_clip(fk: FaceKit, spec: ClipSpec, d: Path, progress=None) -> None:
    """Paint the clip into ``d/clip.mp4`` and its truth into ``d/truth.npz``."""
    from facetransfer.io.atomic import atomic_path

    rng = np.random.default_rng([*SEED_STREAM, int(spec.index), 1])
    w = identity_weights(spec.index, fk.scale)
    neutral, deltas = identity_rig(fk, w)
    A = activation_curves(spec, rng)
    P = pose_curves(spec, rng)
    alb, cull, amb = albedo(fk, rng)
    scene = cvp.PaintScene(fk.faces, alb, cull, amb)
    cam = cvp.Camera(size=SIZE)
    bg = cvp.background(SIZE, rng)
    F = spec.n_frames
    lm2d = np.empty((F, 68, 2))
    verts = np.empty((F, FACE_END, 3), np.float32)
    d.mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(F):
        X = neutral + np.tensordot(A[i], deltas, axes=1)                    # (N_USED, 3)
        R = cvp.rotation_ypr(*P[i, :3])
        Xc = cvp.to_camera(X, R, np.array([P[i, 3], P[i, 4], 0.0]))
        frames.append(cvp.paint(scene, Xc, cam, bg))
        lm2d[i] = cvp.project(Xc[fk.landmarks], cam)
        verts[i] = X[:FACE_END]
        if progress is not None:
            progress(i + 1, F)
    with atomic_path(d / "clip.mp4") as tmp:
        write_mp4(tmp, frames, FPS)
    with atomic_path(d / "truth.npz") as tmp:
        np.savez_compressed(tmp, landmarks=lm2d, vertices=verts, activations=A.astype(np.float32),
                            pose=P, identity_weights=w,
                            spec=np.array(json.dumps(asdict(spec))))


def write_mp4(path: Path, frames, fps: float, *, crf: int = 16) -> None:
    """H.264 mp4 through imageio-ffmpeg (yuv420p), RGB frames (H, W, 3) uint8."""
    import imageio_ffmpeg

    frames = list(frames)
    H, W = frames[0].shape[:2]
    gen = imageio_ffmpeg.write_frames(str(path), (W, H), fps=fps, codec="libx264",
                                      pix_fmt_out="yuv420p", macro_block_size=1,
                                      output_params=["-crf", str(crf), "-preset", "fast"],
                                      ffmpeg_log_level="error")
    gen.send(None)
    for f in frames:
        gen.send(np.ascontiguousarray(f, dtype=np.uint8))
    gen.close()

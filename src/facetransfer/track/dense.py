"""Where MediaPipe's 468 face-mesh points lie on a model's surface (a dense 2-D/3-D correspondence).

MediaPipe Face Landmarker predicts the image positions of the 468 vertices of its canonical face
mesh. This module finds, once per model, the point of the model's mean face that each of them
stands for, so that the capture tracker (:mod:`facetransfer.track.capture`) can fit the model to
all of them and not only to the 68 iBUG points:

1. the canonical mesh (asset ``canonical_face_model``) is aligned to the model's mean face by a
   similarity transform (Umeyama) on the 51 inner iBUG points, placed on the canonical mesh by
   the same weights as :func:`facetransfer.track.landmarks.mediapipe_to_ibug` uses
   (:func:`~facetransfer.track.landmarks.mapping_matrix`, the calibrated correspondence) and
   whose model vertices are ``model.landmarks``;
2. the remaining misfit at those 51 points is interpolated over the mesh by a thin-plate spline
   (``scipy.interpolate.RBFInterpolator``);
3. each warped point is projected onto the nearest point of the model's surface (trimesh), kept as
   a triangle and barycentric coordinates; points farther than ``max_distance`` are dropped.

The result is cached in the user cache, keyed by the model's content hash and the iBUG weights.

For models with the ICT-FaceKit face's topology (the default model and every ``ict-*`` model:
same vertex count and triangles, checked by a hash), a *calibrated* correspondence ships with
the package (``data/mediapipe_facekit_dense.json``, :func:`calibrated_correspondence`): for each
of these MediaPipe points, the surface point within 1.2 cm of the geometric one whose
projections best matched MediaPipe's point on painted FaceKit faces with known geometry
(``benchmarks/calibrate_landmarks.py --dense``; held-out rms 3.0 -> 2.5 % of the eye distance,
median over the points). It is used instead of steps 1-3 unless ``calibrated=False``.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError
from .landmarks import mapping_matrix

log = logging.getLogger(__name__)

__all__ = ["DenseCorrespondence", "mediapipe_correspondence", "umeyama", "faces_hash",
           "calibrated_correspondence", "DENSE_CALIBRATION_FILE"]

#: The calibrated dense correspondence of FaceKit-topology models, in the package's data folder.
DENSE_CALIBRATION_FILE = "mediapipe_facekit_dense.json"

CACHE_VERSION = 2


@dataclass(frozen=True)
class DenseCorrespondence:
    """Model-surface points for MediaPipe's mesh vertices.

    Attributes
    ----------
    mp_index : (P,) int64
        MediaPipe point indices (0..467) that have a model point.
    triangles : (P, 3) int64
        Model vertex indices of the triangle holding each point.
    bary : (P, 3) float64
        Barycentric coordinates in that triangle.
    distance : (P,) float64
        Distance (model units) of the warped canonical point from the surface.
    """

    mp_index: np.ndarray
    triangles: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    def sample(self, vertices: np.ndarray) -> np.ndarray:
        """Points ``(..., P, 3)`` on a mesh with vertices ``(..., n, 3)`` of the model's topology."""
        V = np.asarray(vertices)
        return np.einsum("...pkc,pk->...pc", V[..., self.triangles, :], self.bary)


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``dst ≈ s R src + t`` by least squares (Umeyama 1991).

    Returns
    -------
    s : float, R : (3, 3), t : (3,)
    """
    mu_s, mu_d = src.mean(0), dst.mean(0)
    A, B = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(B.T @ A / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / max((A ** 2).sum() / len(src), 1e-300))
    return s, R, mu_d - s * R @ mu_s


def _canonical() -> np.ndarray:
    from ..assets import asset_path
    from ..io.mesh import read_obj_vertices

    V = read_obj_vertices(asset_path("canonical_face_model"))
    if V.shape != (468, 3):
        raise ShapeError(f"MediaPipe canonical face must have 468 vertices, got {V.shape}")
    return V


def _compute(model, max_distance: float, anchors: np.ndarray) -> DenseCorrespondence:
    import trimesh
    from scipy.interpolate import RBFInterpolator

    neutral = model.synthesize(model.default_weights())
    canon = _canonical()
    inner = range(17, 68)
    src = anchors[list(inner)] @ canon                                     # (51, 3)
    dst = neutral[model.landmarks[list(inner)]]
    s, R, t = umeyama(src, dst)
    warped = s * canon @ R.T + t
    aligned_src = s * src @ R.T + t
    rbf = RBFInterpolator(aligned_src, dst - aligned_src, kernel="thin_plate_spline",
                          smoothing=1e-3)
    warped = warped + rbf(warped)
    mesh = trimesh.Trimesh(neutral, model.faces, process=False)
    closest, dist, tri = trimesh.proximity.closest_point(mesh, warped)
    tris = model.faces[tri]
    bary = trimesh.triangles.points_to_barycentric(neutral[tris], closest)
    keep = dist < max_distance
    log.info("dense MediaPipe correspondence: %d of 468 points within %.2f model units",
             int(keep.sum()), max_distance)
    return DenseCorrespondence(np.flatnonzero(keep).astype(np.int64), tris[keep].astype(np.int64),
                               np.clip(bary[keep], 0.0, 1.0), dist[keep])


def faces_hash(faces: np.ndarray) -> str:
    """SHA-256 of a triangle array as int64 (identifies a topology)."""
    return hashlib.sha256(np.ascontiguousarray(faces, np.int64).tobytes()).hexdigest()


def calibrated_correspondence(model) -> DenseCorrespondence | None:
    """The calibrated dense correspondence of the package's ``mediapipe_facekit_dense.json``
    when the model has its topology (same vertex count and triangles), else None.

    The file (``benchmarks/calibrate_landmarks.py --dense``) holds, per MediaPipe point, the
    triangle and barycentric point of the FaceKit face whose projections best matched
    MediaPipe's point on painted faces with known geometry (searched within 1.2 cm of the
    geometric correspondence's point).
    """
    from importlib import resources

    path = resources.files("facetransfer") / "data" / DENSE_CALIBRATION_FILE
    try:
        doc = json.loads(path.read_text())
        if (int(doc["n_vertices"]) != int(model.n_vertices)
                or doc["faces_sha256"] != faces_hash(model.faces)):
            return None
        idx = np.asarray(doc["mp_index"], np.int64)
        tri = np.asarray(doc["triangles"], np.int64)
        bary = np.asarray(doc["bary"], np.float64)
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring unreadable %s (%s)", path, exc)
        return None
    if (idx.ndim != 1 or tri.shape != (len(idx), 3) or bary.shape != (len(idx), 3)
            or tri.min(initial=0) < 0 or tri.max(initial=0) >= model.n_vertices
            or not np.allclose(bary.sum(axis=1), 1.0, atol=1e-5)):
        log.warning("ignoring malformed %s", path)
        return None
    return DenseCorrespondence(idx, tri, bary, np.zeros(len(idx)))


def mediapipe_correspondence(model, *, max_distance: float = 0.8, use_cache: bool = True,
                             calibrated: bool = True) -> DenseCorrespondence:
    """The dense correspondence of a model (module notes), cached per model.

    Parameters
    ----------
    model : MultilinearModel
        With 68 landmarks and triangles.
    max_distance : float
        Canonical points farther than this from the surface after the warp are dropped (model
        units: cm for ICT models).
    calibrated : bool
        Use :func:`calibrated_correspondence` when the model has its topology (its ``distance``
        is then 0).
    """
    if calibrated:
        dc = calibrated_correspondence(model)
        if dc is not None:
            return dc
    from ..assets import cache_dir
    from ..io.atomic import atomic_path

    if model.landmarks is None:
        raise ShapeError("the model has no landmark vertices")
    anchors = mapping_matrix(468)                                          # (68, 468)
    tag = hashlib.sha256(np.ascontiguousarray(anchors).tobytes()).hexdigest()[:8]
    path = (cache_dir() / "correspondence" /
            f"mp468-{model.content_hash[:20]}-{max_distance:g}-v{CACHE_VERSION}-{tag}.npz")
    if use_cache and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                return DenseCorrespondence(z["mp_index"], z["triangles"], z["bary"],
                                           z["distance"])
        except (OSError, ValueError, KeyError) as exc:
            log.warning("ignoring unreadable %s (%s)", path, exc)
    dc = _compute(model, max_distance, anchors)
    if use_cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, mp_index=dc.mp_index, triangles=dc.triangles, bary=dc.bary,
                         distance=dc.distance)
    return dc

"""Automatic feature points on a scan: a face detector on renderings, lifted to the surface.

§4.2 of Vlasic et al. 2005 marks feature points on every scan by hand. Here the scan is rendered
(with its colour map when it has one, otherwise shaded) and MediaPipe's face landmarker finds
its 478 points, mapped to iBUG-68 (:func:`facetransfer.track.landmarks.mediapipe_to_ibug`); each
point is lifted back onto the surface through the z-buffer (the triangle under the point and
its barycentric coordinates in the projected triangle). Scans come in any pose: with
``view="auto"`` the scan is rendered from the six axis directions with four up directions each;
detections whose 3D points do not look like a face (the nose tip not in front of the eyes) are
dropped, the one whose nose tip most of the others agree with is kept, and the scan is rendered
once more looking straight at that face (the normal of the plane through the outer eye corners
and the mouth) and detected again.

The jaw contour (iBUG 0-16) is a silhouette in a frontal image, not a point of the surface, so
it is left out unless asked for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FaceTransferError
from ..geometry import barycentric_2d
from .features import FeaturePoints

#: iBUG-68 points kept by default: brows, nose, eyes, mouth (the jaw contour is a silhouette)
INNER_FEATURES = tuple(range(17, 68))
#: shaded colour of scans without a colour map (a skin tone: the detector is trained on faces)
SKIN = (205, 160, 135)


class FeatureDetectionError(FaceTransferError):
    """No face was found on any rendering of the scan."""


@dataclass(frozen=True)
class DetectedFeatures:
    """Result of :func:`detect_scan_features`.

    Attributes
    ----------
    features : FeaturePoints
        iBUG-68 numbers and points on the scan surface (scan coordinates).
    rotation : (3, 3) float64
        The view of the final rendering (weak-perspective rotation, :mod:`facetransfer.render`).
    image : (H, W, 3) uint8
        The final rendering.
    points2d : (k, 2) float64
        The detected points in ``image`` (pixels), one per feature.
    """

    features: FeaturePoints
    rotation: np.ndarray
    image: np.ndarray
    points2d: np.ndarray


def view_rotation(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The camera rotation (3, 3) that shows a face looking along ``forward`` (towards the
    camera) with ``up`` up: rows ``(up × forward, up, forward)``, ``up`` made orthogonal."""
    f = np.asarray(forward, np.float64)
    f = f / np.linalg.norm(f)
    u = np.asarray(up, np.float64) - f * float(np.dot(up, f))
    n = np.linalg.norm(u)
    if n < 1e-9:
        raise ValueError("up must not be parallel to forward")
    u = u / n
    return np.stack([np.cross(u, f), u, f])


def candidate_views() -> list[np.ndarray]:
    """24 axis-aligned views: each axis direction as forward, each perpendicular axis as up;
    the usual scan pose (facing +z, y up) first."""
    axes = [np.array(a, np.float64) for a in ((0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0),
                                              (0, 1, 0), (0, -1, 0))]
    ups = [np.array(a, np.float64) for a in ((0, 1, 0), (0, 0, 1), (1, 0, 0), (0, -1, 0),
                                             (0, 0, -1), (-1, 0, 0))]
    out = []
    for f in axes:
        for u in ups:
            if abs(float(np.dot(f, u))) < 0.5:
                out.append(view_rotation(f, u))
    return out


@dataclass(frozen=True, eq=False)
class _ScanRenderer:
    """How the scan is shown to the detector: with its colour map when it has one, otherwise
    shaded in :data:`SKIN`, framed on ``frame_vertices`` (default all) filling ``fill`` of a
    ``size`` x ``size`` image."""

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    texture: np.ndarray | None
    frame_vertices: np.ndarray | None
    size: int
    fill: float
    background: tuple

    def render(self, rotation: np.ndarray):
        """The weak-perspective camera and the :class:`facetransfer.render.RenderResult` of the
        view ``rotation`` (3, 3)."""
        from ..render import look_at_weak_perspective, render

        V, size = self.vertices, self.size
        cam = look_at_weak_perspective(V if self.frame_vertices is None else self.frame_vertices,
                                       (size, size), rotation=rotation, fill=self.fill)
        if self.texture is not None and self.uvs is not None:
            r = render(V, self.faces, cam, (size, size), uvs=self.uvs, texture=self.texture,
                       background=self.background)
        else:
            colors = np.tile(np.asarray(SKIN, np.uint8), (len(V), 1))
            r = render(V, self.faces, cam, (size, size), colors=colors, background=self.background)
        return cam, r


@dataclass(frozen=True, eq=False)
class _Detection:
    """One view's detection: the view, its camera and rendering, the iBUG-68 points in the image
    ``(68, 2)`` and lifted onto the surface ``(68, 3)`` (NaN where they miss it)."""

    rotation: np.ndarray
    camera: object
    rendering: object
    points2d: np.ndarray
    points3d: np.ndarray


def lift_points(points2d: np.ndarray, vertices: np.ndarray, faces: np.ndarray, camera,
                raster) -> tuple[np.ndarray, np.ndarray]:
    """Surface points under image points: ``(ok (k,) bool, points (ok.sum(), 3))``.

    The triangle seen at each point's pixel (z-buffer) and the point's barycentric coordinates
    in that triangle's projection (clamped to the triangle) give the 3D point.
    """
    H, W = raster.tri_id.shape
    xy = np.asarray(points2d, np.float64)
    ix, iy = np.rint(xy[:, 0]).astype(int), np.rint(xy[:, 1]).astype(int)
    inside = np.isfinite(xy).all(axis=1) & (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
    tri = np.full(len(xy), -1, np.int64)
    tri[inside] = raster.tri_id[iy[inside], ix[inside]]
    ok = tri >= 0
    Ft = faces[tri[ok]]
    b = barycentric_2d(camera.project(vertices[Ft.ravel()]).reshape(-1, 3, 2), xy[ok])
    # a point within half a pixel of an edge may fall in the neighbour of the triangle seen at
    # its pixel centre: clamp to the triangle so that it stays on the surface
    b = np.clip(b, 0.0, None)
    b /= b.sum(axis=1, keepdims=True)
    return ok, np.einsum("mk,mkc->mc", b, vertices[Ft])


#: Mouth points (of iBUG 48-67) on the surface that :func:`_frontal` needs: the outer lips'
#: (48-59) of a face whose inner lips lie over its mouth's hole.
MOUTH_POINTS = 8


def _frontal(P68: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Forward and up directions of a face from its 3D iBUG points (outer eye corners 36, 45
    and the mouth 48-67: those of them on the surface, at least :data:`MOUTH_POINTS`; the
    inner lips of an open mouth, or of a mesh with a mouth gap, fall into the hole), or None
    if they are missing."""
    mouth = P68[48:68][np.isfinite(P68[48:68]).all(axis=1)]
    if not np.all(np.isfinite(P68[[36, 45]])) or len(mouth) < MOUTH_POINTS:
        return None
    x = P68[45] - P68[36]                       # subject's right -> left: image right
    up = 0.5 * (P68[36] + P68[45]) - mouth.mean(axis=0)
    f = np.cross(x, up)
    if np.linalg.norm(f) < 1e-12:
        return None
    return f / np.linalg.norm(f), up


def _plausible(P68: np.ndarray) -> bool:
    """A detection lifted to 3D looks like a face: the nose tip (30) stands out in front of the
    eyes by at least a fifth of the eye-corner distance (a face "seen" on hair is flat)."""
    fr = _frontal(P68)
    if fr is None or not np.all(np.isfinite(P68[[30, 36, 45]])):
        return False
    iod = float(np.linalg.norm(P68[45] - P68[36]))
    depth = float(np.dot(P68[30] - 0.5 * (P68[36] + P68[45]), fr[0]))
    return depth > 0.2 * iod


def _consensus(P68s: list) -> int:
    """Index of the detection most others agree with (nose tips within half an eye-corner
    distance in 3D); ties go to the earlier view."""
    noses = np.array([P[30] for P in P68s])
    iod = np.array([np.linalg.norm(P[45] - P[36]) for P in P68s])
    d = np.linalg.norm(noses[:, None] - noses[None], axis=2)
    votes = (d < 0.5 * iod[:, None]).sum(axis=1)
    return int(np.argmax(votes))


def detect_scan_features(vertices: np.ndarray, faces: np.ndarray, *, uvs=None, texture=None,
                         view="auto", ids=INNER_FEATURES, size: int = 640, fill: float = 0.9,
                         frame_vertices: np.ndarray | None = None,
                         background=(90, 90, 90), detector=None) -> DetectedFeatures:
    """Feature points of a scan found on renderings of it (see the module docstring).

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (F, 3) int
    uvs : (n, 2) float, optional
        Texture coordinates (v up) of ``texture``.
    texture : (Ht, Wt, 3) uint8, optional
        The scan's colour map; without it the scan is shaded in a skin tone.
    view : "auto", "front" or (3, 3) rotation
        ``"front"``: the scan faces +z with y up; ``"auto"``: search (module docstring).
    ids : sequence of int
        iBUG-68 numbers to return (default 17-67).
    size : int
        Rendering size in pixels.
    fill : float
        Fraction of the image the framed vertices fill.
    frame_vertices : (m, 3) float, optional
        Vertices to frame (default all), e.g. the head of a bust.
    background : (3,) colour
    detector : object with ``detect(image) -> (68, 2) or None``, optional
        Default: MediaPipe (:class:`facetransfer.track.init.MediaPipeDetector`).

    Returns
    -------
    DetectedFeatures

    Raises
    ------
    FeatureDetectionError
        No face on any rendering, or fewer than 8 points on the surface.
    """
    ids = np.asarray(sorted(set(int(i) for i in ids)), np.int64)
    views = _views(view)
    scan = _ScanRenderer(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), uvs, texture,
                         frame_vertices, size, fill, background)
    own = None
    if detector is None:
        from ..track.init import MediaPipeDetector

        detector = own = MediaPipeDetector()
    try:
        best = _best_detection(scan, views, detector)
        if isinstance(view, str) and view == "auto":
            best = _look_straight(scan, best, detector)
        xy = best.points2d[ids]
        ok, P = lift_points(xy, scan.vertices, scan.faces, best.camera, best.rendering.raster)
        if ok.sum() < 8:
            raise FeatureDetectionError(f"only {int(ok.sum())} detected points lie on the scan "
                                        "surface; at least 8 are needed")
        return DetectedFeatures(FeaturePoints(ids[ok], P), best.rotation, best.rendering.image,
                                xy[ok])
    finally:
        if own is not None:
            own.close()


def _views(view) -> list[np.ndarray]:
    """The rotations (3, 3) to render for ``view`` ("front", "auto" or a rotation)."""
    if isinstance(view, str) and view == "front":
        return [np.eye(3)]
    if isinstance(view, str) and view == "auto":
        return candidate_views()
    if isinstance(view, str):
        raise FeatureDetectionError(f"view must be 'auto', 'front' or a rotation, got {view!r}")
    return [np.asarray(view, np.float64).reshape(3, 3)]


def _detect_view(scan: _ScanRenderer, rotation: np.ndarray, detector) -> _Detection | None:
    """Render one view, detect, lift the 68 points onto the surface; None if no face is found."""
    cam, r = scan.render(rotation)
    p68 = detector.detect(r.image)
    if p68 is None:
        return None
    ok, P = lift_points(p68, scan.vertices, scan.faces, cam, r.raster)
    P68 = np.full((68, 3), np.nan)
    P68[np.flatnonzero(ok)] = P
    return _Detection(rotation, cam, r, p68, P68)


def _best_detection(scan: _ScanRenderer, views: list, detector) -> _Detection:
    """The plausible detection most others agree with (:func:`_consensus`); with a single view,
    its detection. FeatureDetectionError if there is none."""
    cands = []
    for R in views:
        d = _detect_view(scan, R, detector)
        if d is not None and (len(views) == 1 or _plausible(d.points3d)):
            cands.append(d)
    if not cands:
        raise FeatureDetectionError(
            f"no face found on {len(views)} rendering(s) of the scan "
            f"({'searched the 24 axis views' if len(views) > 1 else 'the given view'}); "
            "place the feature points by hand")
    return cands[_consensus([c.points3d for c in cands])]


def _look_straight(scan: _ScanRenderer, best: _Detection, detector) -> _Detection:
    """Once more, looking straight at the face found; ``best`` if that finds no face."""
    fr = _frontal(best.points3d)
    if fr is None:
        return best
    R2 = view_rotation(*fr)
    cam2, r2 = scan.render(R2)
    q68 = detector.detect(r2.image)
    if q68 is None:
        return best
    return _Detection(R2, cam2, r2, q68, best.points3d)

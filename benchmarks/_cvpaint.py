"""A face renderer that is not facetransfer's: OpenCV polygons painted back to front.

Used by ``bench_capture.py`` so the synthetic benchmark does not score the tracker on footage made
by its own rasteriser (``facetransfer.render``). Every triangle is filled with one colour by
``cv2.fillConvexPoly`` in the order of its depth (painter's algorithm), at twice the output
resolution and then reduced with area averaging (anti-aliasing). The colour is Lambert shading
of a per-vertex albedo: a skin tone with per-vertex noise (texture for the optical flow), darker
lips and brows, white eyeballs with a dark iris and pupil, a dark mouth interior, off-white teeth.

Camera: mild perspective, a pinhole at ``distance`` cm in front of the model origin on its +z
axis, looking down -z; image y points down. Model units are the ICT-FaceKit's (cm, y up, the face
looks along +z).

Coordinates: pixel centres at integers, ``(x, y)``, as in ``facetransfer.track``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Camera", "PaintScene", "rotation_ypr", "project", "paint", "background"]


@dataclass(frozen=True)
class Camera:
    """Mild perspective camera.

    Attributes
    ----------
    focal : float
        Pixels (the scale at the model origin is ``focal / distance`` pixels per cm).
    distance : float
        Camera to model origin, cm.
    size : (int, int)
        ``(W, H)``.
    """

    focal: float = 1200.0
    distance: float = 100.0
    size: tuple[int, int] = (512, 512)


def rotation_ypr(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation ``Rz(roll) Rx(pitch) Ry(yaw)``, angles in degrees, (3, 3).

    Positive yaw turns the face toward the image's right (the subject's left), positive pitch
    tilts the chin down.
    """
    y, p, r = np.radians([yaw, pitch, roll])
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return Rz @ Rx @ Ry


def to_camera(X: np.ndarray, R: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Model points (n, 3) -> camera-frame points (n, 3): ``R X + shift`` (cm, z toward camera)."""
    return X @ R.T + shift


def project(Xc: np.ndarray, cam: Camera) -> np.ndarray:
    """Camera-frame points (n, 3) -> pixels (n, 2) (perspective, image y down)."""
    depth = cam.distance - Xc[:, 2]
    f = cam.focal / depth
    cx, cy = (cam.size[0] - 1) / 2.0, (cam.size[1] - 1) / 2.0
    return np.stack([cx + f * Xc[:, 0], cy - f * Xc[:, 1]], axis=1)


@dataclass(frozen=True)
class PaintScene:
    """What to paint: triangles, their albedo and whether back faces are culled.

    Attributes
    ----------
    faces : (m, 3) int64
        Triangles (indices into the vertex array given to :func:`paint`).
    albedo : (m, 3) float64
        RGB in [0, 1] per triangle.
    cull : (m,) bool
        Drop the triangle when it faces away from the camera.
    ambient : (m,) float64
        Ambient share of the shading (1 = unshaded).
    """

    faces: np.ndarray
    albedo: np.ndarray
    cull: np.ndarray
    ambient: np.ndarray


_LIGHT = np.array([-0.35, 0.45, 1.0]) / np.linalg.norm([-0.35, 0.45, 1.0])


def paint(scene: PaintScene, Xc: np.ndarray, cam: Camera, bg: np.ndarray, *,
          supersample: int = 2) -> np.ndarray:
    """Paint a scene over a background.

    Parameters
    ----------
    scene : PaintScene
    Xc : (n, 3) float64
        Vertices in the camera frame (:func:`to_camera`), cm.
    cam : Camera
    bg : (H, W, 3) uint8
        Background, RGB.
    supersample : int
        Painting resolution factor (then area-averaged down).

    Returns
    -------
    (H, W, 3) uint8 RGB
    """
    W, H = cam.size
    k = int(supersample)
    P = project(Xc, cam)                                                     # (n, 2)
    tri = Xc[scene.faces]                                                    # (m, 3, 3)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True) + 1e-12
    view = np.array([0.0, 0.0, cam.distance]) - tri.mean(axis=1)             # toward the camera
    facing = np.einsum("mk,mk->m", nrm, view) > 0
    keep = facing | ~scene.cull
    lam = np.abs(nrm @ _LIGHT)                                               # two-sided Lambert
    shade = scene.ambient + (1.0 - scene.ambient) * lam
    rgb = np.clip(scene.albedo * shade[:, None] * 255.0, 0, 255).astype(np.uint8)
    order = np.argsort(tri[:, :, 2].mean(axis=1), kind="stable")             # far to near
    order = order[keep[order]]
    shift = 3
    pts = np.round((P * k + (k - 1) / 2.0) * (1 << shift)).astype(np.int32)  # sub-pixel fixed point
    canvas = cv2.resize(bg, (W * k, H * k), interpolation=cv2.INTER_NEAREST)
    canvas = np.ascontiguousarray(canvas)
    tpts = pts[scene.faces]                                                  # (m, 3, 2)
    cols = rgb.tolist()
    for i in order.tolist():
        cv2.fillConvexPoly(canvas, tpts[i], cols[i], lineType=cv2.LINE_8, shift=shift)
    return cv2.resize(canvas, (W, H), interpolation=cv2.INTER_AREA)


def background(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A non-uniform background: a colour gradient plus blurred blobs, (H, W, 3) uint8."""
    W, H = size
    yy, xx = np.mgrid[0:H, 0:W] / max(W, H)
    c0, c1 = rng.uniform(0.25, 0.7, 3), rng.uniform(0.25, 0.7, 3)
    a = rng.uniform(0, 2 * np.pi)
    g = (np.cos(a) * xx + np.sin(a) * yy)[..., None]
    img = c0 * (1 - g) + c1 * g
    blobs = cv2.GaussianBlur(rng.standard_normal((H, W, 3)).astype(np.float32), (0, 0), 18)
    blobs /= np.abs(blobs).max() + 1e-9
    fine = cv2.GaussianBlur(rng.standard_normal((H, W, 3)).astype(np.float32), (0, 0), 2)
    fine /= np.abs(fine).max() + 1e-9
    img = img + 0.25 * blobs + 0.05 * fine
    return np.clip(img * 255, 0, 255).astype(np.uint8)

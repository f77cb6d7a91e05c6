"""The rendered face's outer band where its outline moved inside the target's (issue 13, "the
result looks like footage").

A frame's face texture is the target frame itself, looked up through the target's tracked mesh
(:func:`facetransfer.texture.face.frame_uvs`). The tracked outline lies a few pixels off the
real one, so the texture's outermost band holds the target's own outline: the dark edge of the
hair or background beside the cheek and jaw. Where the new face keeps the target's outline that
band lands where the target has it; where the new face is narrower (a pucker, the source's
narrower jaw) the band is drawn inside the face, a dark line along the jaw with the target's
own skin edge outside it (``make demo`` frames 40 and 84). There the target's own pixels are
kept instead (:func:`inward_rim`): the edge of the target's face, which the narrower new face
would have covered anyway; only where the outline moved in by at most the band's width
(:data:`REACH`): farther in, the target's pixels are what its own expression moved there.
"""

from __future__ import annotations

import cv2
import numpy as np

from .composite import _erode

__all__ = ["RIM", "MOVED", "REACH", "outward_shift", "texture_positions", "frame_shift",
           "inward_rim"]

#: The band's width, a fraction of the face's size (the square root of its pixel area; ~250
#: pixels for ``make demo``'s faces: 6 pixels, the width of the dark line it showed).
RIM = 0.025
#: Pixels by which a band pixel's texture must lie farther out from the face's centre than the
#: pixel itself for the target's own pixel to be kept there.
MOVED = 1.5
#: ... and at most this many band widths: farther in, the target's pixels under the band are no
#: longer the edge of its face but what its own expression moved there (the lower lip and the
#: shadow under it where the target's jaw is open and the new one closed).
REACH = 1.0


def outward_shift(P: np.ndarray, Q: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
    """``(n,) float32``: per vertex, how much farther from the ``centre`` (2,) (default: that
    of ``P``) its texture position ``Q`` lies than its own position ``P`` (both (n, 2)
    pixels): positive where the new outline lies inside the one the texture was lifted
    through."""
    c = P.mean(axis=0) if centre is None else centre
    return (np.hypot(Q[:, 0] - c[0], Q[:, 1] - c[1])
            - np.hypot(P[:, 0] - c[0], P[:, 1] - c[1])).astype(np.float32)


def texture_positions(uvs: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The frame pixels ``(n, 2)`` that :func:`facetransfer.texture.face.frame_uvs` ``uvs`` of a
    ``size`` = ``(W, H)`` frame look up (its inverse)."""
    W, H = size
    return np.stack([uvs[:, 0] * max(W - 1, 1), (1.0 - uvs[:, 1]) * max(H - 1, 1)], axis=1)


def frame_shift(V: np.ndarray, camera, face_texture, frame: np.ndarray):
    """:func:`outward_shift` of a new face ``V`` (n_closed, 3) seen by ``camera`` against its
    ``face_texture`` when that texture is the ``frame`` itself (a per-frame texture, its uvs
    the frame's pixels: :func:`facetransfer.texture.face.frame_uvs`), as a function of vertex
    indices ``(m,) -> (m,) float32`` (the outer band needs a few thousand of the mesh's
    vertices); None for another texture (a clip's, whose uvs are no frame's pixels)."""
    if face_texture.image is not frame:
        return None
    H, W = frame.shape[:2]
    c = camera.project(V[::16]).mean(axis=0)      # the face's centre (a sixteenth of it will do)

    def shift(idx: np.ndarray) -> np.ndarray:
        return outward_shift(camera.project(V[idx]),
                             texture_positions(face_texture.uvs[idx], (W, H)), c)

    return shift


def inward_rim(face_mask: np.ndarray, raster, faces: np.ndarray, shift) -> np.ndarray:
    """``(H, W) bool``: the pixels of the rendered face's outer band (:data:`RIM` of its size)
    whose texture lies more than :data:`MOVED` pixels, and at most :data:`REACH` band widths,
    farther out than they do (``shift``: :func:`frame_shift`'s function of vertex indices,
    asked for the band's vertices and interpolated over the raster of ``faces``)."""
    out = np.zeros(face_mask.shape, bool)
    k = max(2, int(round(RIM * np.sqrt(np.count_nonzero(face_mask)))))
    band = face_mask & ~_erode(face_mask, k)
    pts = cv2.findNonZero(band.view(np.uint8))                     # (m, 1, 2) x, y; or None
    if pts is None:
        return out
    flat = pts[:, 0, 1].astype(np.int64) * band.shape[1] + pts[:, 0, 0]
    tri = np.asarray(raster.tri_id).ravel()[flat]
    flat, tri = flat[tri >= 0], tri[tri >= 0]
    if tri.size == 0:
        return out
    corners = np.asarray(faces, np.int64)[tri]                                  # (m, 3)
    need = np.zeros(int(corners.max()) + 1, bool)
    need[corners] = True
    idx = np.flatnonzero(need)
    full = np.empty(need.size, np.float32)
    full[idx] = shift(idx)
    d = np.einsum("mk,mk->m", np.asarray(raster.bary).reshape(-1, 3)[flat], full[corners])
    out.ravel()[flat] = (d > MOVED) & (d <= REACH * k)
    return out

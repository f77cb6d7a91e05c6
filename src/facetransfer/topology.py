"""Mesh topology of the model for texturing (Vlasic et al. 2005, §6, Fig. 7A).

The boundary loops of the model's mesh, the mouth gap closed by a fan for texturing ("the mouth
shapes closed-off for texturing", Fig. 7A–C) and the eye holes, which stay open here so that the
target's own eyes show through (§6; the rewrite's ``eyes="target"``). The default
``eyes="model"`` closes them for its eye region (:func:`facetransfer.eyes.close_eyes`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .errors import ShapeError

log = logging.getLogger(__name__)

__all__ = ["MeshTopology", "mesh_topology", "boundary_loops", "close_mouth", "inside_polygon"]


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary edges (edges of exactly one triangle) of a triangle mesh.

    Parameters
    ----------
    faces : (F, 3) int64

    Returns
    -------
    list of (k,) int64
        Vertex indices in loop order; longest first.
    """
    F = np.asarray(faces, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # directed half-edges
    key = np.sort(E, axis=1)
    # an undirected edge as one integer (unique over rows sorts structured rows: 10x slower)
    code = key[:, 0] * (int(F.max(initial=-1)) + 1) + key[:, 1]
    _, inv, cnt = np.unique(code, return_inverse=True, return_counts=True)
    bnd = E[cnt[inv] == 1]  # directed boundary half-edges (a -> b)
    nxt: dict[int, int] = {}
    for a, b in bnd:
        nxt.setdefault(int(a), int(b))
    loops, seen = [], set()
    for s in list(nxt):
        if s in seen:
            continue
        loop, cur = [], s
        while cur not in seen and cur in nxt:
            seen.add(cur)
            loop.append(cur)
            cur = nxt[cur]
        if len(loop) >= 3:
            loops.append(np.asarray(loop, dtype=np.int64))
    loops.sort(key=len, reverse=True)
    return loops


@dataclass(frozen=True)
class MeshTopology:
    """The model mesh prepared for texturing.

    Attributes
    ----------
    n_vertices : int
        Vertices of the model; the closed mesh appends one centre vertex of the mouth (index
        ``n_vertices``) when there is a mouth gap.
    faces : (F', 3) int64
        Model faces followed by the mouth-closing fan.
    mouth_loop : (k,) int64
        The inner-lip boundary loop (empty when the mesh has no mouth gap).
    mouth_faces : (m,) int64
        Indices into ``faces`` of the triangles textured from the source's mouth.
    eye_loops : tuple of (k,) int64
        The eye holes, left open so that the target's eyes show through (§6).
    """

    n_vertices: int
    faces: np.ndarray
    mouth_loop: np.ndarray
    mouth_faces: np.ndarray
    eye_loops: tuple

    @property
    def n_closed(self) -> int:
        """Vertices of the closed mesh."""
        return self.n_vertices + (1 if self.mouth_loop.size else 0)

    @cached_property
    def mouth_fan(self) -> slice:
        """The mouth-closing fan's rows of ``faces``: ``mouth_loop.size`` triangles from the
        first one with the closed mesh's centre vertex ``n_vertices`` (empty without a mouth
        gap). Triangles appended later (the eyes' fill) come after it."""
        k = int(self.mouth_loop.size)
        f0 = int(np.argmax(self.faces[:, 2] == self.n_vertices)) if k else 0
        return slice(f0, f0 + k)


def mesh_topology(model, *, mouth_rings: int = 1, lips: bool = True) -> MeshTopology:
    """Find the mouth gap and eye holes of the model's mesh and close the mouth (§6, Fig. 7A).

    Boundary loops are classified by the nearest iBUG-68 landmark group of the model's mean
    face: inner lips (60–67) for the mouth, eyes (36–41, 42–47). The mouth loop is closed by a
    fan around its centroid; the triangles of the fan, the ``mouth_rings`` rings of model
    triangles around the loop and (``lips``) the lips form the mouth region textured from the
    source.

    Parameters
    ----------
    model : MultilinearModel
    mouth_rings : int
        Rings of lip triangles around the gap that also take the source's mouth texture.
    lips : bool
        Also the triangles inside the outer lip contour (iBUG 48–59): the whole mouth, lips
        included, comes from the source (§6: "the mouth texture from the source video").

    Returns
    -------
    MeshTopology
    """
    F = np.asarray(model.faces, dtype=np.int64)
    n = int(model.n_vertices)
    loops = boundary_loops(F)
    empty = np.zeros(0, np.int64)
    if model.landmarks is None or len(loops) < 2:
        return MeshTopology(n, F, empty, empty, ())
    V = model.synthesize(model.default_weights())
    lm = V[np.asarray(model.landmarks)]
    best = _classify_loops(V, lm, loops)
    eyes = tuple(loops[best[k][1]] for k in ("eye_r", "eye_l") if k in best)
    if "mouth" not in best:
        log.info("the model mesh has no mouth gap; nothing to close")
        return MeshTopology(n, F, empty, empty, eyes)
    loop = loops[best["mouth"][1]]
    # fan around a new centre vertex n; orient like the adjacent triangles (loop is a boundary
    # traversed along its half-edges, so the fan (b, a, centre) continues the surface's winding)
    fan = np.stack([np.roll(loop, -1), loop, np.full_like(loop, n)], axis=1)
    faces = np.concatenate([F, fan])
    mouth = _mouth_region(F, V, lm, loop, range(F.shape[0], faces.shape[0]),
                          mouth_rings=mouth_rings, lips=lips)
    return MeshTopology(n, faces, loop, mouth, eyes)


def _face_size(lm: np.ndarray) -> float:
    """The face's scale: the distance of the outer eye corners (iBUG 36, 45)."""
    return float(np.linalg.norm(lm[36] - lm[45])) or 1.0


def _classify_loops(V: np.ndarray, lm: np.ndarray, loops: list[np.ndarray]
                    ) -> dict[str, tuple[float, int]]:
    """``{"mouth" | "eye_r" | "eye_l": (distance, loop index)}``: the inner boundary loop
    nearest to each iBUG-68 group's centre of the mean face ``V`` (n, 3) with landmarks
    ``lm`` (68, 3), within 0.35 of the face's size; ``loops[0]`` is the outer boundary."""
    centres = {"mouth": lm[60:68].mean(0), "eye_r": lm[36:42].mean(0), "eye_l": lm[42:48].mean(0)}
    size = _face_size(lm)
    best: dict[str, tuple[float, int]] = {}
    for li, loop in enumerate(loops[1:], start=1):  # loops[0] is the outer boundary
        c = V[loop].mean(0)
        for name, ctr in centres.items():
            d = float(np.linalg.norm(c - ctr))
            if d < 0.35 * size and (name not in best or d < best[name][0]):
                best[name] = (d, li)
    return best


def _mouth_region(F: np.ndarray, V: np.ndarray, lm: np.ndarray, loop: np.ndarray, fan, *,
                  mouth_rings: int, lips: bool) -> np.ndarray:
    """Sorted indices of the triangles textured from the source's mouth: the ``fan``
    triangles, ``mouth_rings`` rings of model triangles ``F`` around the inner-lip ``loop``
    and (``lips``) the triangles inside the outer lip contour."""
    mouth = set(fan)
    ring = set(int(v) for v in loop)
    for _ in range(int(mouth_rings)):
        touch = np.flatnonzero(np.isin(F, list(ring)).any(axis=1))
        mouth.update(int(t) for t in touch)
        ring.update(int(v) for v in F[touch].ravel())
    if lips:
        # the lips: triangles inside the outer lip contour (iBUG 48-59) seen from the front,
        # grown by 10% about its centre
        poly = lm[48:60, :2]
        ctr = poly.mean(0)
        inside = inside_polygon(ctr + 1.1 * (poly - ctr), V[:, :2])
        inside &= V[:, 2] > V[loop, 2].min() - 0.5 * _face_size(lm)  # the front of the face
        mouth.update(int(t) for t in np.flatnonzero(inside[F].all(axis=1)))
    return np.asarray(sorted(mouth), dtype=np.int64)


def inside_polygon(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Which points lie inside a closed polygon (even-odd rule, crossings of a ray to +x).

    The test of ``matplotlib.path.Path(polygon).contains_points(points)`` (its crossing
    test with the same arithmetic, edge by edge in the polygon's order, the closing edge
    last), so points on an edge are decided as there, without importing matplotlib
    (0.2 s).

    Parameters
    ----------
    polygon : (k, 2) float
        Vertices in order; the last joins the first.
    points : (n, 2) float

    Returns
    -------
    (n,) bool
    """
    P = np.asarray(polygon, np.float64)
    tx, ty = (np.asarray(points, np.float64)[:, j] for j in (0, 1))
    inside = np.zeros(tx.shape, bool)
    for (x0, y0), (x1, y1) in zip(P, np.roll(P, -1, axis=0)):
        above0, above1 = y0 >= ty, y1 >= ty
        hit = ((y1 - ty) * (x0 - x1) >= (x1 - tx) * (y0 - y1)) == above1
        inside ^= (above0 != above1) & hit
    return inside


def close_mouth(vertices: np.ndarray, topo: MeshTopology) -> np.ndarray:
    """Append the mouth's centre vertex (mean of the inner-lip loop) to each mesh.

    Parameters
    ----------
    vertices : (..., n_vertices, 3)
    topo : MeshTopology

    Returns
    -------
    (..., topo.n_closed, 3)
    """
    V = np.asarray(vertices, dtype=np.float64)
    if V.shape[-2:] != (topo.n_vertices, 3):
        raise ShapeError(f"vertices must be (..., {topo.n_vertices}, 3), got {V.shape}")
    if not topo.mouth_loop.size:
        return V
    c = V[..., topo.mouth_loop, :].mean(axis=-2, keepdims=True)
    return np.concatenate([V, c], axis=-2)


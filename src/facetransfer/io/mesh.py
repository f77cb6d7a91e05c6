"""Mesh input and output.

Conventions: vertices ``(n_vertices, 3) float64``, triangles ``(n_faces, 3) int64``, UVs
``(n_vertices, 2) float64`` with v pointing up (OBJ convention). Quads are split into two triangles.
Vertex order is always kept exactly as in the file (``trimesh`` is called with ``process=False``),
because correspondence across a data set is by vertex index.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MeshError
from .atomic import atomic_path


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices : (n_vertices, 3) float64
    faces : (n_faces, 3) int64
    uvs : (n_vertices, 2) float64 or None
        Per-vertex texture coordinates, when the file has them and they are per-vertex
        (for OBJ files with separate UV indices, the UV of each vertex's first use).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None


def _check_vertices(v: np.ndarray, path: str | os.PathLike) -> np.ndarray:
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must be (n, 3), got {v.shape} in {path}")
    if v.shape[0] == 0:
        raise MeshError(f"mesh {path} has no vertices")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
        raise MeshError(f"mesh {path} has {bad} vertices with NaN or infinite coordinates")
    return v


def read_obj_vertices(path: str | os.PathLike) -> np.ndarray:
    """Read only the ``v`` lines of an OBJ file, fast (no faces, no processing).

    Parameters
    ----------
    path : path-like
        Wavefront OBJ file.

    Returns
    -------
    vertices : (n_vertices, 3) float64
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise MeshError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    lines = [ln[2:] for ln in data.split(b"\n") if ln.startswith(b"v ")]
    if not lines:
        raise MeshError(f"mesh {path} has no vertices")
    try:
        v = np.array([ln.split()[:3] for ln in lines], dtype=np.float64)
    except ValueError:
        raise MeshError(f"mesh {path} has malformed vertex lines") from None
    return _check_vertices(v.reshape(-1, 3), path)


def read_obj(path: str | os.PathLike) -> Mesh:
    """Read an OBJ file keeping vertex order; quads are split, UVs taken per vertex.

    Returns
    -------
    Mesh
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read().decode("utf-8", errors="replace")
    except OSError as exc:
        raise MeshError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    verts: list[str] = []
    uvs: list[str] = []
    tris: list[tuple[int, int, int]] = []
    tri_uv: list[tuple[int, int, int]] = []
    for line in data.splitlines():
        if line.startswith("v "):
            verts.append(line[2:])
        elif line.startswith("vt "):
            uvs.append(line[3:])
        elif line.startswith("f "):
            parts = line[2:].split()
            vi = [int(p.split("/")[0]) for p in parts]
            ti = [int(p.split("/")[1]) if p.count("/") >= 1 and p.split("/")[1] else 0 for p in parts]
            for k in range(1, len(parts) - 1):
                tris.append((vi[0], vi[k], vi[k + 1]))
                tri_uv.append((ti[0], ti[k], ti[k + 1]))
    if not verts:
        raise MeshError(f"mesh {path} has no vertices")
    try:
        v = np.array([[float(x) for x in s.split()[:3]] for s in verts], dtype=np.float64)
    except ValueError:
        raise MeshError(f"mesh {path} has malformed vertex lines") from None
    _check_vertices(v, path)
    n = len(v)
    f = np.array(tris, dtype=np.int64).reshape(-1, 3)
    f = np.where(f < 0, f + n, f - 1)  # OBJ is 1-based; negative indices count from the end
    if f.size and (f.min() < 0 or f.max() >= n):
        raise MeshError(f"mesh {path} has face indices outside 0..{n - 1}")
    uv = None
    if uvs:
        t = np.array([[float(x) for x in s.split()[:2]] for s in uvs], dtype=np.float64)
        ti = np.array(tri_uv, dtype=np.int64).reshape(-1, 3)
        if ti.size and ti.min() > 0:
            uv = np.zeros((n, 2))
            seen = np.zeros(n, dtype=bool)
            fv, tv = f.ravel(), ti.ravel() - 1
            first = np.unique(fv, return_index=True)
            uv[first[0]] = t[tv[first[1]]]
            seen[first[0]] = True
    return Mesh(v, f, uv)


def read_mesh(path: str | os.PathLike) -> Mesh:
    """Read any mesh trimesh can read (OBJ, PLY, STL, OFF, GLB …) without reordering vertices.

    Raises
    ------
    MeshError
        Unreadable, empty, non-finite, or not a mesh.
    """
    p = Path(path)
    if not p.is_file():
        raise MeshError(f"mesh file {p} does not exist")
    if p.stat().st_size == 0:
        raise MeshError(f"mesh file {p} is empty")
    if p.suffix.lower() == ".obj":
        return read_obj(p)
    import trimesh

    try:
        loaded = trimesh.load(p, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many kinds
        raise MeshError(f"cannot read mesh {p}: {exc}") from None
    v = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    _check_vertices(v, p)
    uv = None
    visual = getattr(loaded, "visual", None)
    if visual is not None and getattr(visual, "uv", None) is not None and len(visual.uv) == len(v):
        uv = np.asarray(visual.uv, dtype=np.float64)
    return Mesh(v, f, uv)


def write_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, *,
               uvs: np.ndarray | None = None, colors: np.ndarray | None = None,
               overwrite: bool = True) -> Path:
    """Write a mesh atomically; format by extension (``.obj`` written directly, others via trimesh).

    Parameters
    ----------
    vertices : (n_vertices, 3) float
    faces : (n_faces, 3) int
    uvs : (n_vertices, 2) float, optional (OBJ only)
    colors : (n_vertices, 3) uint8, optional (PLY via trimesh)
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _check_vertices(v, path)
    p = Path(path)
    with atomic_path(p, overwrite=overwrite) as tmp:
        if p.suffix.lower() == ".obj":
            with open(tmp, "w") as fh:
                fh.write("# written by facetransfer\n")
                np.savetxt(fh, v, fmt="v %.6f %.6f %.6f")
                if uvs is not None:
                    np.savetxt(fh, np.asarray(uvs, dtype=np.float64), fmt="vt %.6f %.6f")
                    np.savetxt(fh, np.repeat(f + 1, 2, axis=1), fmt="f %d/%d %d/%d %d/%d")
                else:
                    np.savetxt(fh, f + 1, fmt="f %d %d %d")
        else:
            import trimesh

            m = trimesh.Trimesh(v, f, process=False, vertex_colors=colors)
            m.export(tmp, file_type=p.suffix.lower().lstrip("."))
    return p
